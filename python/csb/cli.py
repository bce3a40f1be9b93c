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
    from .bench import main

    main(sizes=args.sizes, iterations=args.iterations, substeps=args.substeps, steps=args.steps, rounds=args.rounds,
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

    p = sub.add_parser("bench", help="time the PBD step, its front ends, virtual dispatch, colouring, threads, "
                                     "scaling, memory and the reference (prints tables)")
    p.add_argument("--sizes", type=int, nargs="+", default=[64, 128], help="particles per side (default: 64 128)")
    p.add_argument("--iterations", type=int, default=10)
    p.add_argument("--substeps", type=int, default=1)
    p.add_argument("--steps", type=int, default=10, help="steps per timed round")
    p.add_argument("--rounds", type=int, default=7, help="timed rounds; the median is reported")
    p.add_argument("--parts", nargs="+",
                   default=["step", "front-ends", "dispatch", "fps", "types", "threads", "busy", "particles", "memory",
                            "big", "klu"],
                   choices=["step", "front-ends", "dispatch", "fps", "types", "threads", "busy", "particles", "memory",
                            "big", "klu"],
                   help="which tables to print (default: all): the step, front ends, virtual dispatch; issue 7: fps "
                        "of 128x128 and 256x256 cloths, projections per second by type against a plain loop, 1 "
                        "against 2 threads, the same with a busy core, cost per particle 1k-1M, memory, a "
                        "1024x1024 cloth, the reference's KLU cost against size")
    p.add_argument("--front-end-sizes", type=int, nargs="+", default=[32, 128, 512],
                   help="cloth sizes (particles per side) for the front-end table (default: 32 128 512)")
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
