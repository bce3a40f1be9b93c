"""CPU time per step of the same-step reference, csb.BackwardEuler(dt=1/60 s), on the study scenes,
and a digest of the positions and velocities it reaches (equal digests: the same bits).

    python scripts/backward_euler_timing.py [--runs 5] [--steps 20]
    PYTHONPATH=DIR python scripts/backward_euler_timing.py     # another build, installed in DIR

Per scene two rows: one stepper taking the steps one by one, as a study's backward-euler cell
does, and a fresh stepper for every step, as the same_step_error metric builds one. A row's
figure is the median (and range) over the runs of the process CPU time of its steps divided by
their number, from the scene's start state each run.
"""

from __future__ import annotations

import argparse
import hashlib
import time

import numpy as np

import csb
from csb.studies.literature import twisting_cloth
from csb.studies.study.schema import hanging_cloth


def with_start(model: csb.Model) -> tuple[csb.Model, csb.State]:
    return model, model.initial_state()


SCENES = {
    "hanging_cloth(n=32)": lambda: with_start(hanging_cloth(n=32)),
    "hanging_cloth(n=12)": lambda: with_start(hanging_cloth(n=12)),
    "twisting_cloth()": twisting_cloth,
}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--steps", type=int, default=20)
    args = ap.parse_args(argv)
    print(f"csb {csb.__file__}")
    for name, make in SCENES.items():
        model, start = make()
        for fresh in (False, True):
            per, digest = [], ""
            for _ in range(args.runs):
                state = model.initial_state()
                state.x, state.v, state.t = np.array(start.x), np.array(start.v), start.t
                kept = csb.BackwardEuler(dt=1 / 60)
                t0 = time.process_time()
                for _ in range(args.steps):
                    (csb.BackwardEuler(dt=1 / 60) if fresh else kept).step(model, state, 1)
                per.append((time.process_time() - t0) / args.steps * 1e3)
                digest = hashlib.sha256(np.ascontiguousarray(state.x).tobytes()
                                        + np.ascontiguousarray(state.v).tobytes()).hexdigest()[:12]
            how = "fresh stepper per step" if fresh else "one stepper"
            print(f"{name:20s} {how:22s} median {np.median(per):7.2f} ms/step, range {min(per):.2f}-{max(per):.2f} "
                  f"({args.runs} runs x {args.steps} steps)  state {digest}", flush=True)


if __name__ == "__main__":
    main()
