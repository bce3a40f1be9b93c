"""Hashes of the final state of a bending 64x64 cloth stepped 20 frames under 24 settings: PBD,
Jakobsen and XPBD; Gauss-Seidel and Jacobi; 1 and 2 threads; 10 sub-steps x 1 iteration and
2 x 5. A change meant to keep every result bit for bit (a faster kernel, another thread
schedule) must print the same line before and after it:

    python scripts/state_hashes.py > before.txt                     # the build before
    PYTHONPATH=build/other-site python scripts/state_hashes.py | cmp - before.txt
"""

import hashlib

import numpy as np

import csb


def state_hashes() -> list[str]:
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1.0, 1.0, 64, 64), mass=0.5, bending_stiffness=0.5)
    b.pin(0)
    model = b.build()
    out = []
    for method in ("pbd", "jakobsen", "xpbd"):
        for solver in ("gauss-seidel", "jacobi"):
            for threads in (1, 2):
                for substeps, iterations in ((10, 1), (2, 5)):
                    state = model.initial_state()
                    csb.PbdStepper(method=method, solver=solver, substeps=substeps, iterations=iterations,
                                   threads=threads, dt=1 / 60).step(model, state, 20)
                    data = np.asarray(state.x).tobytes() + np.asarray(state.v).tobytes()
                    out.append(hashlib.sha256(data).hexdigest()[:12])
    return out


if __name__ == "__main__":
    print(" ".join(state_hashes()))
