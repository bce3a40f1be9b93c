"""The ``csb`` command: run scenes, benchmark, list scenes and formats."""

from __future__ import annotations

import argparse
import importlib.util
import math
import sys
from pathlib import Path

from . import _core


_FORMATS = ("usd", "gltf", "obj", "ply", "xdmf", "vtu", "csv", "plot")


def _overridden(scene, args: argparse.Namespace):
    """The scene with the command line's --method, --dt, --substeps, --iterations, --precision,
    --duration and --fps in place of its own; the stepper is made once so that an impossible combination is an
    error now, naming the setting."""
    import dataclasses

    solver = {k: getattr(args, k) for k in ("method", "dt", "substeps", "iterations", "precision")
              if getattr(args, k, None) is not None}
    if solver:
        scene = dataclasses.replace(scene, solver=dataclasses.replace(scene.solver, **solver))
        scene.solver.stepper()
    if args.duration is not None:
        scene = dataclasses.replace(scene, duration=args.duration)
    if args.fps is not None:
        scene = dataclasses.replace(scene, output=dataclasses.replace(scene.output, fps=args.fps))
    return scene


def _cmd_run(args: argparse.Namespace) -> int:
    from .scene import load_scene

    scene = _overridden(load_scene(args.scene), args)
    if args.format:
        import dataclasses

        chosen = set(args.format)
        if chosen & {"usd", "gltf", "obj", "ply"} and scene.tearing is not None:
            raise SystemExit(f"csb run: {scene.name} tears, and the file's mesh cannot follow a model that tears; "
                             "use --format vtu")
        scene = dataclasses.replace(scene, output=dataclasses.replace(
            scene.output, **{f: f in chosen for f in _FORMATS}))
    out = Path(args.out) if args.out else Path("out") / scene.name
    result = scene.run(out, progress=not args.quiet)
    print(result.summary())
    for f in result.files:
        if f.parent == out or f.suffix in (".pvd", ".xdmf", ".png", ".csv", ".usd"):
            print(f"  wrote {f}")
    for folder in sorted({f.parent for f in result.files if f.parent.parent == out and f.suffix in (".obj", ".ply")}):
        print(f"  wrote {folder}/ ({sum(1 for f in result.files if f.parent == folder)} files)")
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    if args.peers:
        from .bench import peers

        peers.main(sizes=args.sizes or peers.SIZES, frames=args.peer_frames, rounds=args.rounds,
                         min_time=peers.MIN_TIME if args.peer_min_time is None else args.peer_min_time,
                         sides=args.sides, pypbd_threads=args.pypbd_threads, newton_cold=not args.newton_cache,
                         hold_frames=args.hold_frames, jolt=args.jolt, jolt_threads=args.jolt_threads,
                         csb_variants=[(m, p) for m in args.csb_methods for p in args.csb_precisions])
        return 0
    from .bench import main

    main(sizes=args.sizes or [64, 128], iterations=args.iterations, substeps=args.substeps, steps=args.steps, rounds=args.rounds,
         parts=args.parts, front_end_sizes=args.front_end_sizes, self_collision_sizes=args.self_collision_sizes)
    return 0


def _cmd_study(args: argparse.Namespace) -> int:
    from .studies.study import run_study

    result = run_study(args.study, out=args.out, workers=args.workers, scheduler=args.scheduler,
                       retry_failed=args.retry_failed, progress=not args.quiet, extra_methods=args.add or (),
                       like=args.like)
    print(result.summary())
    for f in result.files:
        print(f"  wrote {f}")
    return 0


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels, e.g. 1280x800, got '{text}'") from None
    return w, h


def _camera(args: argparse.Namespace):
    from .view import CameraPose

    return CameraPose(yaw=args.yaw, pitch=args.pitch, zoom=args.zoom)


def _cmd_view(args: argparse.Namespace) -> int:
    from .view import view

    w, h = args.size
    try:
        frames = view(args.scene, frames=args.frames, width=w, height=h, method=args.method, camera=_camera(args),
                      paused=args.paused, wireframe=args.wireframe, particles=args.particles,
                      overlay=not args.no_overlay)
    except KeyboardInterrupt:  # Ctrl-C in the terminal: the window is closed, no traceback
        print("interrupted")
        return 130
    print(f"{frames} frames")
    return 0


def _cmd_render(args: argparse.Namespace) -> int:
    from .scene import load_scene
    from .view import render

    scene = load_scene(args.scene)
    out = Path(args.out) if args.out else Path("out") / scene.name / "frames"
    w, h = args.size
    frames = args.frames if args.frames is not None else max(1, math.ceil(scene.duration * 60 - 1e-9))
    r = render(scene, out, frames=frames, every=args.every, width=w, height=h, video=not args.no_video,
               method=args.method, camera=_camera(args), overlay=args.overlay, wireframe=args.wireframe,
               particles=args.particles, prefix=args.prefix, progress=not args.quiet)
    print(f"{scene.name}: {frames} frames of {w}x{h}, {len(r.images)} written as PNG in {out} "
          f"({r.ms_per_frame:.1f} ms per frame: step, draw and read-back; {r.draw_ms_per_frame:.1f} ms to draw)")
    if r.video is not None:
        print(f"  wrote {r.video}")
    elif r.video_note:
        print(f"  {r.video_note}")
    return 0


def _cmd_scenes(args: argparse.Namespace) -> int:
    from .scene import bundled_scenes, load_scene

    for name, path in sorted(bundled_scenes().items()):
        s = load_scene(path)
        print(f"{name:12s} {s.duration:g} s  {s.description or ''}  ({path})")
    return 0


# What each copy of the blocked coloured kernels (bending; PBD distance) runs, by kernels.kernel_isa().
_KERNEL_ISA = {
    "avx512": "bending in AVX-512, distance in AVX2",
    "avx2": "AVX2",
    "sse2": "SSE2",
    "native": "the baseline's (a native build, or not x86-64)",
}


def _cmd_info(args: argparse.Namespace) -> int:
    for k, v in _core.build_info().items():
        if k == "simd":
            # The baseline the compiler targets for all code; the portable x86-64 build also carries
            # SSE2, AVX2 and AVX-512 copies of the blocked kernels and picks one for the processor.
            print(f"{'simd baseline':13s} {v} (compiled for all code)")
            isa = _core.kernels.kernel_isa()
            print(f"{'simd kernels':13s} {isa}: {_KERNEL_ISA.get(isa, isa)} (the blocked coloured kernels in use, "
                  "chosen at run time)")
        elif k == "viewer":
            from .view import viewer_missing

            print(f"{k:13s} {viewer_missing() or 'built, and it loads'}")
        else:
            print(f"{k:13s} {v}")
    print(f"{'mesh formats':13s} {' '.join(_core.readable_extensions())}")
    extras = []
    for extra, module, what in (("usd", "pxr", "USD export"), ("study", "dask.distributed", "studies on Dask"),
                                ("bench", "pypbd", "benchmark peers")):
        found = importlib.util.find_spec(module.split(".")[0]) is not None
        extras.append(f"{extra} ({what}): {'installed' if found else 'absent'}")
    print(f"{'extras':13s} {'; '.join(extras)}")
    return 0


def _positive(text: str) -> float:
    """An argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def _at_least(low: float, kind: type = int):
    """An argparse type: a number of `kind` not below `low` (argparse names the option)."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {'an integer' if kind is int else 'a number'}, got {text!r}")
        if not value >= low:  # also rejects NaN
            raise argparse.ArgumentTypeError(f"must be at least {low:g}, got {text}")
        return value

    return parse


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="csb", description="Cloth and soft-body dynamics with Position Based Dynamics.")
    parser.add_argument("--version", action="version", version=f"csb {_core.build_info()['csb']}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("run", help="step a scene and write its outputs")
    p.add_argument("scene", help="a scene file (.toml) or the name of a bundled scene (see 'csb scenes')")
    p.add_argument("--out", help="output directory (default: out/<scene name>)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--method", choices=[n for m in _core.methods() for n in (m.name, *m.aliases)],
                   help="the scene's method replaced by this one (any of csb.methods())")
    p.add_argument("--duration", type=_positive, help="simulated time, s (default: the scene's)")
    p.add_argument("--dt", type=_positive, help="time step, s (default: the scene's)")
    p.add_argument("--substeps", type=_at_least(1), help="sub-steps per time step (default: the scene's)")
    p.add_argument("--iterations", type=_at_least(1), help="iterations per sub-step (default: the scene's)")
    p.add_argument("--precision", choices=("float64", "float32"),
                   help="the solver's scalar (default: the scene's); float32 runs distance and bending constraints "
                        "with pins, without contacts or grabs")
    p.add_argument("--fps", type=_positive, help="frames written per simulated second (default: the scene's)")
    p.add_argument("--format", nargs="+", choices=_FORMATS,
                   help="write these outputs instead of the scene's [output] choice: usd (<name>.usd, the meshes "
                        "as their files have them and the colliders, animated; needs the usd extra), gltf "
                        "(<name>.glb, morph-target animation for game engines), obj and ply (a file per frame), "
                        "xdmf, vtu, csv (metrics.csv), plot (summary.png, snapshot.png)")
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser("bench", help="time the PBD step, its front ends, virtual dispatch, the viewer's frames, "
                                     "colouring, threads, scaling, memory and the reference; --peers: against pypbd, "
                                     "newton, jolt and mujoco (prints tables)")
    p.add_argument("--sizes", type=_at_least(2), nargs="+", default=None,
                   help="particles per side (default: 64 128; with --peers 32 64 128 256)")
    p.add_argument("--iterations", type=_at_least(1), default=10)
    p.add_argument("--substeps", type=_at_least(1), default=1)
    p.add_argument("--steps", type=_at_least(1), default=10, help="steps per timed round")
    p.add_argument("--rounds", type=_at_least(1), default=7, help="timed rounds; the median is reported")
    parts = ["step", "front-ends", "dispatch", "viewer", "fps", "xpbd", "precision", "types", "threads", "busy", "particles",
             "memory", "big", "klu", "methods", "self-collision"]
    p.add_argument("--parts", nargs="+", default=parts, choices=parts,
                   help="which tables to print (default: all): the step, front ends, virtual dispatch, the viewer's "
                        "frame time; fps of 128x128 and 256x256 cloths, XPBD against PBD at equal work, "
                        "float64 against float32 (whole frames and the distance and bending kernels), "
                        "projections per second by type "
                        "against a plain loop, 1 against 2 threads, the same with a busy core, cost per particle "
                        "1k-1M, memory, a 1024x1024 cloth, the reference's KLU cost against size, every method "
                        "at equal iterations and at equal error, self-collision's cost on a 1,600-particle cape "
                        "and against the cape's size")
    p.add_argument("--front-end-sizes", type=_at_least(2), nargs="+", default=[32, 128, 512],
                   help="cloth sizes (particles per side) for the front-end table (default: 32 128 512)")
    p.add_argument("--self-collision-sizes", type=_at_least(2), nargs="+", default=[20, 28, 40, 56, 80],
                   help="cape sizes (particles per side) for the self-collision sweep that follows the self-collision "
                        "table (default: 20 28 40 56 80; 113 adds about 20 s a round, 160 half an hour or more)")
    p.add_argument("--peers", action="store_true",
                   help="instead: the same cloth in csb, pypbd, newton (CPU) and Jolt, 10 substeps x 1 iteration "
                        "and 1 x 10 (Jolt: 10 x 1 only), and, when named in --sides, MuJoCo's flex springs (a "
                        "different method, at its own stable sub-steps, in the 10 x 1 rows); a peer that is not "
                        "installed is skipped (pip install 'csb[bench]'; Jolt: --jolt)")
    p.add_argument("--sides", nargs="+", default=["csb", "pypbd", "newton", "jolt"],
                   choices=["csb", "pypbd", "newton", "jolt", "mujoco"],
                   help="with --peers: which sides to run (default: all but mujoco, MuJoCo's flex springs, a "
                        "different method that runs only when named: hundreds of sub-steps a frame, seconds a "
                        "frame from 128²)")
    p.add_argument("--pypbd-threads", type=_at_least(1), nargs="+", default=[1, 2],
                   help="with --peers: OMP_NUM_THREADS values to run pypbd with (default: 1 2)")
    p.add_argument("--jolt", metavar="PATH", default=None,
                   help="with --peers: a built jolt_cloth (default: $CSB_JOLT_CLOTH; build it with "
                        "scripts/jolt_cloth.py --jolt <Jolt tree> --build <dir>); none: Jolt is skipped")
    p.add_argument("--csb-methods", nargs="+", default=["pbd"], choices=["pbd", "xpbd", "jakobsen"],
                   help="with --peers: csb's methods, each a side of its own (default pbd, the ratios' base)")
    p.add_argument("--csb-precisions", nargs="+", default=["float64"], choices=["float64", "float32"],
                   help="with --peers: csb's precisions, each method in each (default float64)")
    p.add_argument("--jolt-threads", type=_at_least(1), nargs="+", default=[1, 2],
                   help="with --peers: thread counts to run Jolt with (default: 1 2)")
    p.add_argument("--peer-frames", type=_at_least(1), default=5,
                   help="with --peers: frames per timed round, each round from rest (default: 5)")
    p.add_argument("--peer-min-time", type=_at_least(0.0, float), default=None,
                   help="with --peers: seconds of timed frames per side and row; rounds are added beyond "
                        "--rounds until they add up to it (default: 1)")
    p.add_argument("--hold-frames", type=_at_least(0), default=0,
                   help="with --peers: also step each cloth this many frames from rest and check it (untimed)")
    p.add_argument("--newton-cache", action="store_true",
                   help="with --peers: use Warp's kernel cache (default: a fresh one, so that first-use "
                        "compilation is measured)")
    p.set_defaults(func=_cmd_bench)

    def view_options(p: argparse.ArgumentParser) -> None:
        p.add_argument("scene", help="a scene file (.toml) or the name of a bundled scene")
        p.add_argument("--method", choices=[n for m in _core.methods() for n in (m.name, *m.aliases)],
                       help="override the scene's method (any of csb.methods())")
        p.add_argument("--wireframe", action="store_true", help="draw the distance constraints")
        p.add_argument("--particles", action="store_true", help="draw every particle")
        p.add_argument("--yaw", type=float, help="camera yaw, rad (0 looks along -z)")
        p.add_argument("--pitch", type=float, help="camera pitch above the horizon, rad")
        p.add_argument("--zoom", type=float, default=1.0, help="camera distance over the framing one (default 1)")

    p = sub.add_parser("view", help="simulate a scene live in a window (needs a display)")
    view_options(p)
    p.add_argument("--size", type=_size, default=(1280, 800), help="window size WxH in pixels (default 1280x800)")
    p.add_argument("--frames", type=int, default=0, help="close after this many frames (default: when closed)")
    p.add_argument("--paused", action="store_true", help="start paused (space runs)")
    p.add_argument("--no-overlay", action="store_true", help="hide the fps/energy overlay (o toggles it)")
    p.set_defaults(func=_cmd_view)

    p = sub.add_parser("render", help="draw frames of a scene offscreen into PNG files (and MP4 with ffmpeg)")
    view_options(p)
    p.add_argument("--out", help="output directory (default: out/<scene name>/frames)")
    p.add_argument("--frames", type=int, help="frames to draw, each 1/60 s of simulated time (default: the scene's duration)")
    p.add_argument("--every", type=int, default=1, help="write every k-th frame (default 1)")
    p.add_argument("--size", type=_size, default=(960, 600), help="image size WxH in pixels (default 960x600)")
    p.add_argument("--overlay", action="store_true", help="draw the fps/energy overlay into the frames")
    p.add_argument("--no-video", action="store_true", help="no MP4 even if ffmpeg is installed")
    p.add_argument("--prefix", default="frame", help="file names: <prefix>_NNNNN.png, <prefix>.mp4 (default frame)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_render)

    p = sub.add_parser("study", help="run a study file: scenes x methods x parameter grids, on Dask, resumable")
    study = p.add_subparsers(dest="study_command", required=True)
    p = study.add_parser("run", help="compute the study's missing cells and write its table and chart")
    p.add_argument("study", help="a study file (.toml)")
    p.add_argument("--out", help="output directory (default: out/studies/<study name>); cells are stored in "
                                 "<out>/cells/<key>.json")
    p.add_argument("--workers", type=_at_least(0), default=None,
                   help="Dask worker processes of a local cluster (default: one per core, up to the cells); "
                        "0: in this process, without Dask")
    p.add_argument("--scheduler", help="address of a running Dask scheduler (tcp://host:port) instead of a local cluster")
    p.add_argument("--retry-failed", action="store_true", help="run the cells stored as failed again")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--with", dest="add", action="append", metavar="METHOD",
                   help="add a method the study file does not name: module:Class (a csb.Integrator subclass, "
                        "imported from the working directory) or the path of a plug-in's shared library; "
                        "it takes the grid of the --like method (may be given more than once)")
    p.add_argument("--like", metavar="LABEL", help="the study's method whose dt, substeps and iterations grid the "
                                                   "--with methods take (default: its first that takes a time step)")
    p.set_defaults(func=_cmd_study)

    sub.add_parser("scenes", help="list the bundled scenes").set_defaults(func=_cmd_scenes)
    sub.add_parser("info", help="versions, the SIMD kernels in use, readable mesh formats and the optional extras").set_defaults(func=_cmd_info)

    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except (_core.Error, FileNotFoundError, ImportError) as e:  # ImportError: an optional extra that is absent
        print(f"csb: error: {e}", file=sys.stderr)
        return 2


def view_main() -> None:
    """The `csb-view` command: a mesh file as a cloth in the viewer (`csb-view --help`)."""
    import signal

    from .view import viewer_module

    try:
        command = viewer_module().command
    except _core.Error as e:
        print(f"csb-view: error: {e}", file=sys.stderr)
        sys.exit(2)
    # The command runs in C++ without the interpreter: Ctrl-C ends it as it would the C++ program.
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    sys.exit(command(sys.argv[1:]))


if __name__ == "__main__":
    sys.exit(main())
