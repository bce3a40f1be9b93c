#!/usr/bin/env python3
"""Study: where the time of csb's XPBD step goes, and what stands between it and this machine's limits.

1. The machine: scripts/machine_limits.py, a standalone C++ program of known loops built with the
   system's g++ (its docstring says what each figure measures): per-core peaks of fused
   multiply-adds and of separate multiplies and additions (csb is built without FMA contraction),
   division and square-root throughput, STREAM triad bandwidths from L3 to DRAM. 7 repetitions
   of each figure (3 with --quick); medians.
2. csb: the bundled cloth_grid (stretch and shear edges, dihedral bending, two pinned corners,
   dt = 1/60 s) at 128² and 256² (--quick: 128²), XPBD at 10 sub-steps x 1 iteration on two
   threads, in float64 and float32 taking turns (csb.bench.precision_table's sides): ms per frame,
   the bending elements a frame projects (each carries the distance constraint on its edge), and
   the ns of a thread per element: two threads' frame over the elements.
3. The bounds on an element: the arithmetic it does, counted from the kernel's source
   (papers/benchmarks.md, "The final XPBD step, and the machine's limits": about 165 flops, 7
   divisions and 2 square roots an element with its edge), at the per-core multiply-add peak and
   at the division and square-root throughput of 256-bit vectors (which share one unit: their
   times add); and the stepper's workspace (the coloured batches, multipliers and particle arrays,
   each read about once a sub-step) moved at the two-thread DRAM and L3 triad bandwidths. The
   measured time over each bound says how far the step is from it.
4. The profile: `perf record -e cpu-clock` over the same frames (float64 and float32, 256²; --quick:
   128²), csb's samples by function, when perf is on PATH (Debian: linux-perf) and may profile;
   the build tree's unstripped libcsb.so is given to perf's build-id cache so that the functions
   have names. Without perf the section says so.

Writes machine_limits.json (the machine's figures), machine_limits_csb.csv (the frames and bounds)
and machine_limits_profile.txt (the profile, when taken).

    python validation/machine_limits.py [--out out/validation] [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from csb.bench import cloth_simulation, make_stepper, memory_report, precision_table
from csb.studies import write_csv

ROOT = Path(__file__).resolve().parent.parent
# An element with its edge, counted from the kernel's source (papers/benchmarks.md).
FLOPS, DIVISIONS, SQRTS = 165, 7, 2
SUBSTEPS, ITERATIONS, THREADS = 10, 1, 2


def machine(out: Path, reps: int) -> dict:
    """Runs scripts/machine_limits.py; its figures (medians) by name, and what it printed."""
    path = out / "machine_limits.json"
    run = subprocess.run([sys.executable, str(ROOT / "scripts" / "machine_limits.py"), "--reps", str(reps),
                          "--json", str(path)], capture_output=True, text=True, check=True)
    print(run.stdout)
    return {k: v["median"] for k, v in json.loads(path.read_text())["figures"].items()}


def frames(sizes: list[int], rounds: int) -> list[dict]:
    """XPBD frames in float64 and float32 taking turns, with the elements and the workspace bytes."""
    rows = []
    timed = precision_table(sizes, rounds=rounds, threads=THREADS)
    for n in sizes:
        row = next(r for r in timed if r["n"] == n and r["substeps"] == SUBSTEPS and r["iterations"] == ITERATIONS)
        sim = cloth_simulation(n, iterations=ITERATIONS, substeps=SUBSTEPS)
        elements = len(sim.model.bending["rest_angle"]) * SUBSTEPS * ITERATIONS
        for precision in ("float64", "float32"):
            stepper = make_stepper(sim, substeps=SUBSTEPS, iterations=ITERATIONS, threads=THREADS, method="xpbd",
                                   precision=precision)
            stepper.step(sim.model, sim.state, 1)
            rows.append(dict(n=n, precision=precision, ms=row[f"xpbd_{precision}"],
                             spread=row[f"xpbd_{precision}_spread"], elements=elements,
                             workspace=memory_report(sim.model, stepper)["workspace_bytes"]))
    return rows


def bounds(rows: list[dict], m: dict) -> list[dict]:
    out = []
    for r in rows:
        single = r["precision"] == "float32"
        kind = "float" if single else "double"
        ns = THREADS * r["ms"] * 1e6 / r["elements"]  # ns of a thread per element
        # ns at one core's multiply-add peak, and at its division and square-root throughput (a
        # processor without AVX2 has no such figures: no bound)
        nan = float("nan")
        flops = FLOPS / m.get(f"addmul_{kind}_avx2_gflops", nan)
        units = DIVISIONS / m.get(f"div_{kind}_avx2_per_ns", nan) + SQRTS / m.get(f"sqrt_{kind}_avx2_per_ns", nan)
        moved = SUBSTEPS * r["workspace"]
        dram = moved / (m["triad_dram_2threads_gbps"] * 1e6)  # ms a frame
        l3 = moved / (m["triad_l3_2threads_gbps"] * 1e6)
        out.append(dict(cloth=f"{r['n']}x{r['n']}", precision=r["precision"], ms_per_frame=round(r["ms"], 3),
                        ms_min=round(r["spread"][0], 3), ms_max=round(r["spread"][1], 3),
                        elements_per_frame=r["elements"], ns_per_element=round(ns, 2),
                        ns_flops_bound=round(flops, 2), ns_div_sqrt_bound=round(units, 2),
                        times_arithmetic_bound=round(ns / max(flops, units), 1),
                        workspace_mb=round(r["workspace"] / 1e6, 1), ms_at_dram=round(dram, 2),
                        ms_at_l3=round(l3, 2), times_dram_bound=round(r["ms"] / dram, 2)))
    return out


def profile(n: int, out: Path) -> str:
    """csb's samples by function over XPBD frames of the n x n cloth, or why there are none."""
    perf = shutil.which("perf")
    if not perf:
        return "no profile: perf is not on PATH (Debian: apt-get install linux-perf)"
    # The unstripped library of the build tree, for the names: added to perf's build-id cache, or
    # put in place of the installed (stripped) file an earlier `perf record` cached under the same
    # build-id (-u replaces only such an entry).
    for lib in ROOT.glob("build/*/src/csb/libcsb.so"):
        for flag in ("-a", "-u"):
            subprocess.run([perf, "buildid-cache", flag, str(lib)], capture_output=True)
    text = []
    for precision in ("float64", "float32"):
        with tempfile.TemporaryDirectory() as tmp:
            data, control = Path(tmp) / "perf.data", Path(tmp) / "control"
            os.mkfifo(control)
            # Sampling starts after the set-up (the model, the colouring, two steps): the child
            # enables it through perf's control fifo.
            code = (f"from csb.bench import cloth_simulation, make_stepper\n"
                    f"sim = cloth_simulation({n}, iterations={ITERATIONS}, substeps={SUBSTEPS})\n"
                    f"st = make_stepper(sim, substeps={SUBSTEPS}, iterations={ITERATIONS}, threads={THREADS}, "
                    f"method='xpbd', precision='{precision}')\n"
                    f"st.step(sim.model, sim.state, 2)\n"
                    f"open({str(control)!r}, 'w').write('enable\\n')\n"
                    f"st.step(sim.model, sim.state, {max(20, 80 * 128 * 128 // (n * n))})\n")
            try:  # (a perf that runs the child but never reads the fifo would leave it waiting)
                rec = subprocess.run([perf, "record", "-q", "-e", "cpu-clock", "-D", "-1", f"--control=fifo:{control}",
                                      "-o", str(data), sys.executable, "-c", code], capture_output=True, text=True,
                                     env={**os.environ, "OPENBLAS_NUM_THREADS": "1"}, timeout=600)
            except subprocess.TimeoutExpired:
                return "no profile: perf record did not finish within 600 s"
            if rec.returncode != 0:
                return f"no profile: perf record failed ({rec.stderr.strip().splitlines()[-1] if rec.stderr.strip() else rec.returncode})"
            rep = subprocess.run([perf, "report", "-i", str(data), "--dsos", "libcsb.so", "--percentage", "relative",
                                  "--sort", "sym", "--stdio"], capture_output=True, text=True)
        lines = [ln[:130] for ln in rep.stdout.splitlines() if ln.strip() and not ln.startswith("#")][:12]
        text.append(f"{n}x{n}, XPBD, {SUBSTEPS} x {ITERATIONS}, {THREADS} threads, {precision}: csb's samples "
                    f"by function (share of libcsb.so's)\n" + "\n".join(lines))
    result = "\n\n".join(text)
    (out / "machine_limits_profile.txt").write_text(result + "\n")
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/validation", help="output directory")
    parser.add_argument("--quick", action="store_true", help="128² only, 3 repetitions of the machine's figures")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    m = machine(out, 3 if args.quick else 7)
    sizes = [128] if args.quick else [128, 256]
    rows = bounds(frames(sizes, rounds=3 if args.quick else 7), m)
    write_csv(out / "machine_limits_csb.csv", rows)
    print(f"csb's XPBD frames ({SUBSTEPS} x {ITERATIONS}, {THREADS} threads, float64 and float32 taking turns) "
          f"against the machine: ns of a thread per bending element with its edge; the arithmetic bound "
          f"({FLOPS} flops at one core's multiply-add peak, or {DIVISIONS} divisions and {SQRTS} square roots "
          f"at the 256-bit units' throughput, the larger); the workspace moved once a sub-step at the "
          f"two-thread DRAM and L3 triad bandwidths")
    head = (f"{'cloth':>9} {'precision':>9} {'ms/frame':>9} {'(min-max)':>15} {'elements':>9} {'ns/elem':>8} "
            f"{'flops ns':>8} {'div+sqrt ns':>11} {'x arith':>7} {'MB':>6} {'ms @DRAM':>8} {'ms @L3':>7} {'x DRAM':>6}")
    print(head + "\n" + "-" * len(head))
    for r in rows:
        print(f"{r['cloth']:>9} {r['precision']:>9} {r['ms_per_frame']:>9.2f} {'(%.2f-%.2f)' % (r['ms_min'], r['ms_max']):>15} "
              f"{r['elements_per_frame']:>9} {r['ns_per_element']:>8.2f} {r['ns_flops_bound']:>8.2f} "
              f"{r['ns_div_sqrt_bound']:>11.2f} {r['times_arithmetic_bound']:>7.1f} {r['workspace_mb']:>6.1f} "
              f"{r['ms_at_dram']:>8.2f} {r['ms_at_l3']:>7.2f} {r['times_dram_bound']:>6.2f}")
    print()
    print(profile(sizes[-1], out))


if __name__ == "__main__":
    main()
