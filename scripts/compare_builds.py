"""Times the same steps in two builds of csb, in alternating turns, and prints their ratios.

    python scripts/compare_builds.py --before DIR [--after DIR] [--rounds N] [--quick]

DIR is a directory holding an installed `csb` package (e.g. `pip install --target DIR <checkout>`);
without --after, the csb this Python imports. Each build runs in its own worker process (two
builds of one extension module cannot share a process); this process drives both and, for every
row, times one round in each build in turn, alternating which goes first, so that a slow spell
of the shared machine falls on both sides. A row's figure is the median ms per step over its
rounds in each build; the ratio is after / before of those medians, and its spread the range of
the per-round ratios. The rows use only what both builds have: the bundled scenes and
`_core.PbdStepper`.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

# The worker: reads one JSON request a line ({"row": {...}, "steps": k}) and answers the ms per
# step of k steps of that row's simulation (built once per row, stepped on from where it was).
WORKER = r"""
import dataclasses, json, sys, time, warnings
warnings.simplefilter("ignore")  # a scene stepped with a method other than its own says so; timed, not read
import csb
from csb import _core

cache = {}

def build(row):
    scene = csb.load_scene(row["scene"])
    if "n" in row:
        mesh = scene.meshes[0]
        mesh = dataclasses.replace(mesh, shape_args={**mesh.shape_args, "resolution": (row["n"], row["n"])})
        scene = dataclasses.replace(scene, meshes=(mesh,))
    sim = scene.build()
    stepper = _core.PbdStepper(method=row["method"], dt=row.get("dt", 1 / 60), substeps=row["substeps"],
                               iterations=row["iterations"], ordering=row.get("ordering", "coloured"),
                               solver=row.get("solver", "gauss-seidel"), threads=row.get("threads", 1),
                               gravity=tuple(sim.gravity))
    stepper.step(sim.model, sim.state, 3)  # warm-up: workspace, coloured batches, caches
    return sim, stepper

print(json.dumps({"csb": csb.__file__}), flush=True)
for line in sys.stdin:
    req = json.loads(line)
    key = json.dumps(req["row"], sort_keys=True)
    if key not in cache:
        cache[key] = build(req["row"])
    sim, stepper = cache[key]
    t0 = time.perf_counter()
    stepper.step(sim.model, sim.state, req["steps"])
    ms = 1e3 * (time.perf_counter() - t0) / req["steps"]
    print(json.dumps({"ms": ms}), flush=True)
"""

# The rows: the benchmark's step table (cloth_grid at 64 and 128, one thread), the same cloth
# with XPBD, Jakobsen, the sequential ordering, averaged Jacobi, small steps and two threads,
# and scenes with contacts (a cloth on a sphere) and a soft body (tets on the ground).
ROWS = [
    ("cloth 64, PBD 1x10", dict(scene="cloth_grid", n=64, method="pbd", substeps=1, iterations=10), 20),
    ("cloth 128, PBD 1x10", dict(scene="cloth_grid", n=128, method="pbd", substeps=1, iterations=10), 10),
    ("cloth 128, XPBD 1x10", dict(scene="cloth_grid", n=128, method="xpbd", substeps=1, iterations=10), 10),
    ("cloth 128, Jakobsen 1x10", dict(scene="cloth_grid", n=128, method="jakobsen", substeps=1, iterations=10), 10),
    ("cloth 128, XPBD 10x1 (small steps)", dict(scene="cloth_grid", n=128, method="xpbd", substeps=10, iterations=1), 10),
    ("cloth 128, PBD 1x10, 2 threads",
     dict(scene="cloth_grid", n=128, method="pbd", substeps=1, iterations=10, threads=2), 10),
    ("cloth 64, PBD 1x10, sequential",
     dict(scene="cloth_grid", n=64, method="pbd", substeps=1, iterations=10, ordering="sequential"), 10),
    ("cloth 64, XPBD 1x10, Jacobi",
     dict(scene="cloth_grid", n=64, method="xpbd", substeps=1, iterations=10, solver="jacobi"), 10),
    ("cloth on a sphere, PBD 4x4 (contacts)",
     dict(scene="cloth_sphere", method="pbd", substeps=4, iterations=4), 40),
    ("soft cube drop, XPBD 4x4 (tets, ground)",
     dict(scene="soft_cube_drop", method="xpbd", substeps=4, iterations=4), 100),
]


class Worker:
    def __init__(self, site: str | None):
        env = dict(os.environ)
        if site:
            env["PYTHONPATH"] = site + os.pathsep + env.get("PYTHONPATH", "")
        self.proc = subprocess.Popen([sys.executable, "-c", WORKER], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     text=True, env=env)
        self.where = json.loads(self.proc.stdout.readline())["csb"]

    def time(self, row: dict, steps: int) -> float:
        self.proc.stdin.write(json.dumps({"row": row, "steps": steps}) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"the worker of {self.where} ended")
        return json.loads(line)["ms"]

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(timeout=60)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--before", required=True, help="directory holding the earlier build's csb package")
    ap.add_argument("--after", default=None, help="directory holding the later build's csb (default: the installed one)")
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--quick", action="store_true", help="the first three rows, 3 rounds")
    args = ap.parse_args(argv)
    rows = ROWS[:3] if args.quick else ROWS
    rounds = 3 if args.quick else args.rounds
    before, after = Worker(args.before), Worker(args.after)
    print(f"before: {before.where}\nafter:  {after.where}")
    print(f"median ms per step over {rounds} rounds, the two builds timed in alternating turns\n")
    print(f"{'row':42} {'before ms':>10} {'after ms':>10} {'after/before':>13} {'per-round range':>17}")
    try:
        for name, row, steps in rows:
            b, a = [], []
            for r in range(rounds):
                if r % 2 == 0:
                    b.append(before.time(row, steps))
                    a.append(after.time(row, steps))
                else:
                    a.append(after.time(row, steps))
                    b.append(before.time(row, steps))
            ratios = [x / y for x, y in zip(a, b)]
            mb, ma = statistics.median(b), statistics.median(a)
            print(f"{name:42} {mb:10.3f} {ma:10.3f} {ma / mb:13.3f} {min(ratios):8.3f}-{max(ratios):.3f}", flush=True)
    finally:
        before.close()
        after.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
