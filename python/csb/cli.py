"""The ``csb`` command: run scenes, benchmark, list scenes and formats."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from . import _core


def _cmd_run(args: argparse.Namespace) -> int:
    from .scene import load_scene

    scene = load_scene(args.scene)
    out = Path(args.out) if args.out else Path("out") / scene.name
    result = scene.run(out, progress=not args.quiet)
    print(result.summary())
    for f in result.files:
        if f.parent == out or f.suffix in (".pvd", ".xdmf", ".png", ".csv"):
            print(f"  wrote {f}")
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    if args.peers:
        from . import bench_peers

        bench_peers.main(sizes=args.sizes or bench_peers.SIZES, frames=args.peer_frames, rounds=args.rounds,
                         sides=args.sides, pypbd_threads=args.pypbd_threads, newton_cold=not args.newton_cache,
                         hold_frames=args.hold_frames)
        return 0
    from .bench import main

    main(sizes=args.sizes or [64, 128], iterations=args.iterations, substeps=args.substeps, steps=args.steps, rounds=args.rounds,
         parts=args.parts, front_end_sizes=args.front_end_sizes)
    return 0


def _cmd_scenes(args: argparse.Namespace) -> int:
    from .scene import bundled_scenes, load_scene

    for name, path in sorted(bundled_scenes().items()):
        s = load_scene(path)
        print(f"{name:12s} {s.duration:g} s  {s.description or ''}  ({path})")
    return 0


def _cmd_info(args: argparse.Namespace) -> int:
    for k, v in _core.build_info().items():
        print(f"{k:13s} {v}")
    print(f"{'mesh formats':13s} {' '.join(_core.readable_extensions())}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="csb", description="Cloth and soft-body dynamics with Position Based Dynamics.")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("run", help="step a scene and write its outputs")
    p.add_argument("scene", help="a scene file (.toml) or the name of a bundled scene (see 'csb scenes')")
    p.add_argument("--out", help="output directory (default: out/<scene name>)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser("bench", help="time the PBD step, its front ends and virtual dispatch (prints tables)")
    p.add_argument("--sizes", type=int, nargs="+", default=None,
                   help="particles per side (default: 64 128; with --peers 32 64 128 256)")
    p.add_argument("--iterations", type=int, default=10)
    p.add_argument("--substeps", type=int, default=1)
    p.add_argument("--steps", type=int, default=10, help="steps per timed round")
    p.add_argument("--rounds", type=int, default=7, help="timed rounds; the median is reported")
    p.add_argument("--parts", nargs="+", default=["step", "front-ends", "dispatch"],
                   choices=["step", "front-ends", "dispatch"], help="which tables to print (default: all)")
    p.add_argument("--front-end-sizes", type=int, nargs="+", default=[32, 128, 512],
                   help="cloth sizes (particles per side) for the front-end table (default: 32 128 512)")
    p.add_argument("--peers", action="store_true",
                   help="instead: the same cloth in csb, pypbd and newton (CPU), 10 substeps x 1 iteration and "
                        "1 x 10 (issue 7); a peer that is not installed is skipped (pip install 'csb[bench]')")
    p.add_argument("--sides", nargs="+", default=["csb", "pypbd", "newton"], choices=["csb", "pypbd", "newton"],
                   help="with --peers: which sides to run")
    p.add_argument("--pypbd-threads", type=int, nargs="+", default=[1, 2],
                   help="with --peers: OMP_NUM_THREADS values to run pypbd with (default: 1 2)")
    p.add_argument("--peer-frames", type=int, default=5,
                   help="with --peers: frames per timed round, each round from rest (default: 5)")
    p.add_argument("--hold-frames", type=int, default=0,
                   help="with --peers: also step each cloth this many frames from rest and check it (untimed)")
    p.add_argument("--newton-cache", action="store_true",
                   help="with --peers: use Warp's kernel cache (default: a fresh one, so that first-use "
                        "compilation is measured)")
    p.set_defaults(func=_cmd_bench)

    sub.add_parser("scenes", help="list the bundled scenes").set_defaults(func=_cmd_scenes)
    sub.add_parser("info", help="versions and readable mesh formats").set_defaults(func=_cmd_info)

    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except (_core.Error, FileNotFoundError) as e:
        print(f"csb: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
