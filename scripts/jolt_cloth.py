"""csb's benchmark cloth in Jolt Physics' soft bodies (XPBD): build, run, check, tabulate.

Usage (with csb's environment; Jolt is the user's own source tree, never csb's):

    python scripts/jolt_cloth.py --jolt /path/to/JoltPhysics --build /tmp/jolt-build
    python scripts/jolt_cloth.py --jolt ... --build ... --sizes 64 128 256 --threads 1 2

It configures and builds src/bench/jolt (Jolt from --jolt, Release; see its CMakeLists.txt) unless
--no-build, writes csb's cloth (``csb.bench.peers.cloth_arrays(n)``) to a file, runs
``jolt_cloth`` on it, checks that Jolt's own counts (particles, edge constraints, dihedral bend
constraints, read back after Optimize) equal csb's and that every constraint came through
unchanged, checks the final positions with ``csb.bench.peers.check_cloth`` (after the timed
frames, and after --hold frames), and prints a table of ms per frame: median and min-max over the
rounds, for dt = 1/60 s and 10 sub-steps x 1 iteration (Jolt's mNumIterations = 10: in Jolt each
iteration is one XPBD sub-step).

Threads: "1 (custom)" is SoftBodyMotionProperties::CustomUpdate on the calling thread; "T" is
PhysicsSystem::Update with Jolt's JobSystemThreadPool of T - 1 workers plus the calling thread,
the body being the only one in the system.

The cloth file format is documented at the top of src/bench/jolt/jolt_cloth.cpp. The binary this
builds is also a side of ``csb bench --peers`` (``--jolt <build dir>/jolt_cloth``), which runs it in
its serve mode and times it in turns with the other sides.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SOURCE = ROOT / "src" / "bench" / "jolt"
SUBSTEPS = 10  # 10 sub-steps x 1 iteration per frame of 1/60 s


def build(jolt: Path, build_dir: Path) -> Path:
    subprocess.run(["cmake", "-S", str(SOURCE), "-B", str(build_dir), f"-DJOLT_DIR={jolt}",
                    "-DCMAKE_BUILD_TYPE=Release"], check=True, stdout=subprocess.DEVNULL)
    subprocess.run(["cmake", "--build", str(build_dir), "-j2"], check=True, stdout=subprocess.DEVNULL)
    return build_dir / "jolt_cloth"


def run(exe: Path, cloth: Path, work: Path, mode: str, threads: int, args: argparse.Namespace) -> dict:
    x, xh = work / "x.bin", work / "xh.bin"
    cmd = [str(exe), str(cloth), "--mode", mode, "--threads", str(threads), "--substeps", str(SUBSTEPS),
           "--frames", str(args.frames), "--warmup", str(args.warmup), "--rounds", str(args.rounds),
           "--min-time", str(args.min_time), "--positions", str(x),
           "--hold", str(args.hold), "--hold-positions", str(xh)]
    out = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)
    out["x"] = np.fromfile(x, "<f8").reshape(-1, 3)
    out["xh"] = np.fromfile(xh, "<f8").reshape(-1, 3) if args.hold > 0 else None
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--jolt", type=Path, help="a Jolt Physics source tree (holding Jolt/ and Build/)")
    p.add_argument("--build", type=Path, default=Path("/tmp/jolt-build"), help="CMake build directory")
    p.add_argument("--no-build", action="store_true", help="use the jolt_cloth already in --build")
    p.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="PhysicsSystem threads")
    p.add_argument("--no-custom", action="store_true", help="skip the CustomUpdate (1 thread) row")
    p.add_argument("--frames", type=int, default=5, help="timed frames per round (from rest)")
    p.add_argument("--warmup", type=int, default=5)
    p.add_argument("--rounds", type=int, default=7, help="at least this many rounds ...")
    p.add_argument("--min-time", type=float, default=1.0, help="... and this many seconds of timed frames")
    p.add_argument("--hold", type=int, default=120, help="frames of the longer check (0: none)")
    args = p.parse_args()

    if args.no_build:
        exe = args.build / "jolt_cloth"
    else:
        if args.jolt is None:
            p.error("--jolt is required unless --no-build")
        exe = build(args.jolt.resolve(), args.build)

    # the cloth file is written as csb bench --peers writes it for its Jolt side
    from csb.bench.peers import check_cloth, cloth_arrays, write_jolt_cloth

    cases = ([("custom", 1)] if not args.no_custom else []) + [("system", t) for t in args.threads]
    rows, ok = [], True
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for n in args.sizes:
            a = cloth_arrays(n)
            cloth = work / f"cloth{n}.bin"
            write_jolt_cloth(a, cloth)
            csb_counts = (len(a["positions"]), len(a["distance"]), len(a["bending"]))
            for mode, threads in cases:
                r = run(exe, cloth, work, mode, threads, args)
                jolt_counts = (r["particles"], r["edge_constraints"], r["bend_constraints"])
                check = check_cloth(a, r["x"], args.frames)
                hold = check_cloth(a, r["xh"], args.hold) if r["xh"] is not None else None
                # the hold is reported, not judged (csb's peers driver holds only on request): at 128²
                # and more, 10 projections per frame let the cloth nearly free-fall before it snaps back
                good = (jolt_counts == csb_counts and r["other_constraints"] == 0 and r["constraints_identical"]
                        and r["iterations"] == SUBSTEPS and check["ok"])
                ok &= good
                rows.append((n, csb_counts, jolt_counts, mode, r, check, hold, good))
                print(f"# n={n} {mode} T={r['threads']}: {json.dumps({k: v for k, v in r.items() if k not in ('x', 'xh')})}",
                      file=sys.stderr)

    r0 = rows[0][4]
    print(f"Jolt {r0['jolt_version']} ({r0['simd']}), dt = {r0['dt']:.6g} s, {r0['iterations']} sub-steps x 1 "
          f"iteration (mNumIterations = {r0['iterations']}), {args.frames} timed frames from rest per round, "
          f"{args.warmup} warm-up frames, >= {args.rounds} rounds and >= {args.min_time:g} s")
    print(f"{'n':>4} {'particles':>10} {'edges':>13} {'bends':>13} {'threads':>11} {'ms/frame':>9} "
          f"{'min-max':>15} {'cpu/wall':>8} {'rounds':>6} {'max strain':>10} {'hold':>16} {'ok':>3}")
    for n, cc, jc, mode, r, check, hold, good in rows:
        same = lambda i: f"{jc[i]}" if jc[i] == cc[i] else f"{jc[i]}!={cc[i]}"
        label = "1 (custom)" if mode == "custom" else str(r["threads"])
        hs = ("-" if hold is None else "diverged" if not hold["finite"]
              else f"{'ok' if hold['ok'] else 'fails'} {hold['max_strain']:.3g}")
        print(f"{n:>4} {same(0):>10} {same(1):>13} {same(2):>13} {label:>11} {r['ms_per_frame']:>9.3f} "
              f"{r['ms_min']:>7.3f}-{r['ms_max']:<7.3f} {r['cpu_per_wall']:>8.2f} {r['rounds']:>6} {check['max_strain']:>10.3g} "
              f"{hs:>16} {'yes' if good else 'NO':>3}")
    print("counts are Jolt's, read back from its settings after Optimize (a != b: Jolt a, csb b); ok: counts, "
          "identical constraints and check_cloth after the timed frames; max strain: the largest edge strain then; "
          f"hold: check_cloth after {args.hold} frames from rest (its largest strain), reported, not judged; "
          "cpu/wall: CPU seconds of all threads per second of timed frames (near 1 with T = 2: the worker found "
          "no free core, and the figure is a 1-thread one)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
