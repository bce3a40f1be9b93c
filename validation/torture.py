#!/usr/bin/env python3
"""Study: cloth self-collision under torture, checked at every sub-step by an independent test.

Scenes (csb.studies.torture; XPBD, 1/60 s frames of sub-steps of one iteration):
twist (a 50 x 50 cloth whose held edges turn in opposite directions at π/3 rad/s for 10 s),
stack (ten 20 x 20 layers in one self-colliding group dropped on the ground), funnel (a 30 x 30
cloth drawn by its centre through a funnel whose hole is 6.7 times narrower), soft_drape and
soft_drape_sequential (cloth_sphere, bending compliance 1000 1/(N m), coloured and sequential
sweeps), rotating_sphere (a cloth on a sphere turning about the vertical).

Each scene is stepped one sub-step a call (a PbdStepper of substeps=1 and dt = the scene's
sub-step), and after every sub-step the IPC Toolkit (ipctk.has_intersections) says whether the
cloth intersects itself; where it does, csb's exact count of edge-triangle crossings says how
much. Also: the deepest contact penetration the stepper reports, the self-collision fail-safe
activations (contacts()["self_failsafe"] where the stepper has one), and the wall time of the
stepping alone per 1/60 s frame (median) with self-collision and without (the same scene as its
control, checked at frame ends). One MP4 per scene of its run with self-collision.

Writes torture.json, torture.md, torture.csv, torture_crossings.png and <scene>.mp4 with
its last frame <scene>_NNNNN.png.

    python validation/torture.py [--out out/validation] [--quick] [scene ...]
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

import csb
from csb.studies import torture as T
from csb.studies import write_csv


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="out/validation", help="output directory")
    parser.add_argument("--quick", action="store_true", help="small cloths, about a second each (the tests' sizes)")
    parser.add_argument("--no-video", action="store_true", help="no MP4s")
    parser.add_argument("--count", choices=("substep", "frame"), default="substep",
                        help="count the crossing pairs at every intersecting sub-step (default) or at frame ends only "
                             "(a count takes 0.1 s on the full-size scenes, ipctk's verdict 0.01 s)")
    parser.add_argument("--seconds", type=float, default=None,
                        help="simulate at most this long (s) in each scene (default: each scene's own time)")
    parser.add_argument("scenes", nargs="*", default=list(T.SCENES), help=f"of {', '.join(T.SCENES)}")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from csb.view import viewer_available

    video = not args.no_video and viewer_available() and shutil.which("ffmpeg") is not None
    start = time.time()
    rows, records, histories = [], [], {}
    for name in args.scenes:
        scene = T.build(name, quick=args.quick)
        if args.seconds is not None and args.seconds < scene.seconds:
            scene.description += f" (here its first {args.seconds:g} s)"
            scene.seconds = args.seconds
        began = time.time()
        r = T.measure(scene, record=video, count=args.count, progress=not args.quick)
        rows.append(T.row(r))
        histories[name] = r["history"]
        record = {k: v for k, v in r.items() if k not in ("frames", "final", "history", "frame_seconds")}
        record.update(description=scene.description, seconds=scene.seconds, substeps_per_frame=scene.substeps,
                      substep_s=scene.substep, settings={k: v for k, v in scene.settings.items()},
                      wall_seconds=time.time() - began)
        if video:
            v = T.render_video(scene, r["frames"], out)
            images = [Path(p) for p in v["images"]]
            for p in images[:-1]:
                p.unlink(missing_ok=True)   # the first frame; the last one stays as the scene's picture
            record.update(video=Path(v["video"]).name if v["video"] else None, video_note=v["video_note"])
        records.append(record)
        print(f"{name}: {scene.description}; {record['wall_seconds']:.0f} s", flush=True)

    (out / "torture.json").write_text(json.dumps(dict(tier="quick" if args.quick else "full", scenes=records,
                                                      seconds=time.time() - start), indent=1,
                                                 default=float), encoding="utf-8")
    table = T.markdown(rows)
    (out / "torture.md").write_text("# Self-collision torture scenes\n\n" + table + "\n", encoding="utf-8")
    if rows:
        write_csv(out / "torture.csv", rows)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4.2), constrained_layout=True)
    for name, h in histories.items():
        h = h[h["crossings"] >= 0]   # -1: intersecting, not counted (counted at frame ends only)
        if len(h):
            ax.plot(h["t"], h["crossings"], lw=0.8, label=name)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("edge-triangle crossings after the sub-step")
    ax.set_title("self-collision on: crossings at every sub-step", fontsize="medium")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="x-small")
    fig.savefig(out / "torture_crossings.png", dpi=110)

    print()
    print(table)
    print(f"\nmax penetration: the deepest contact violation (colliders and self-contacts, thickness included) "
          f"left at the end of a sub-step; fail-safe: contacts()['self_failsafe'] summed over the sub-steps "
          f"({'reported' if 'self_failsafe' in csb.PbdStepper(dt=T.FRAME).contacts() else 'not reported'} by this "
          f"build's stepper); ms/frame: the stepping alone, one sub-step a call, median over the frames")
    print(f"{'quick' if args.quick else 'full'} tier, {time.time() - start:.0f} s of wall time"
          f"{'' if video else ' (no videos: ' + ('--no-video' if args.no_video else 'no viewer or ffmpeg') + ')'}")


if __name__ == "__main__":
    main()
