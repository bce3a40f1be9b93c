"""Makes the viewer's images in docs/images/: the README's picture with the offscreen mode (EGL,
no display), and screenshots of a real window on a private Xvfb display driven by xdotool (a
click-and-drag of the cloth, then the wireframe under XPBD). Run it from the repository after
./dev setup:

    .venv/bin/python scripts/viewer_images.py

Prints where each image went and the frame times it saw.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import numpy as np

import csb

OUT = Path(__file__).resolve().parents[1] / "docs" / "images"


def readme_image() -> None:
    r = csb.render("cloth_sphere", OUT, frames=96, every=95, width=960, height=540, video=False, prefix="cloth_sphere",
                   overlay=True, camera=csb.CameraPose(pitch=0.45, zoom=0.8))
    final = OUT / "cloth_sphere.png"
    r.images[-1].replace(final)
    for p in r.images[:-1]:
        p.unlink()
    print(f"offscreen: {final} ({r.size[0]}x{r.size[1]}, {r.ms_per_frame:.1f} ms per frame)")


def xdotool(*args) -> str:
    return subprocess.run(["xdotool", *map(str, args)], check=True, capture_output=True, text=True).stdout


def window_screenshots() -> None:
    read, write = os.pipe()
    xvfb = subprocess.Popen(["Xvfb", "-displayfd", str(write), "-screen", "0", "1280x800x24", "-nolisten", "tcp"],
                            pass_fds=(write,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write)
    with os.fdopen(read) as f:
        os.environ["DISPLAY"] = ":" + f.readline().strip()
    out = OUT / "viewer"
    out.mkdir(parents=True, exist_ok=True)
    try:
        with csb.open_viewer("cloth_drop", width=800, height=500, vsync=False, title="csb-images") as v:
            for _ in range(45):
                v.frame()
            v.save_png(str(out / "window_hanging.png"))
            window = xdotool("search", "--sync", "--name", "csb-images").split()[0]
            x = np.array(v.state.x)
            i = int(np.argmin(np.linalg.norm(x - x.mean(axis=0), axis=1)))
            sx, sy, _ = v.camera.project(x[i])
            xdotool("mousemove", "--window", window, round(sx), round(sy))
            v.frame()
            xdotool("mousedown", 1)
            v.frame()
            held = v.held_particle
            for k in range(1, 31):  # drag towards the viewer's upper right over half a second
                xdotool("mousemove", "--window", window, round(sx + 6 * k), round(sy - 5 * k))
                v.frame()
            v.save_png(str(out / "window_dragging.png"))
            gx, gy, _ = v.camera.project(np.array(v.state.x)[held])
            print(f"window: held particle {held}, cursor at ({sx + 180:.0f}, {sy - 150:.0f}) px, particle drawn at "
                  f"({gx:.1f}, {gy:.1f}) px")
            xdotool("mouseup", 1)
            xdotool("key", "2")  # XPBD
            xdotool("key", "w")  # wireframe
            for _ in range(30):
                v.frame()
            v.save_png(str(out / "window_xpbd_wireframe.png"))
            s = v.stats
            print(f"window: {s['fps']:.1f} fps, {s['frame_ms']:.2f} ms per frame, {s['step_ms']:.3f} ms per step "
                  f"(Xvfb, Mesa llvmpipe)")
        for name in ("window_hanging", "window_dragging", "window_xpbd_wireframe"):
            print(f"window: {out / (name + '.png')}")
    finally:
        xvfb.terminate()
        xvfb.wait()


if __name__ == "__main__":
    if not csb.viewer_available():
        raise SystemExit(f"the viewer was not built: {csb.viewer_missing()}")
    OUT.mkdir(parents=True, exist_ok=True)
    readme_image()
    if shutil.which("Xvfb") and shutil.which("xdotool"):
        window_screenshots()
    else:
        print("no Xvfb/xdotool: window screenshots skipped")
