"""The viewer and csb.render with moving colliders: the viewer steps a scene's collider motion and
attachments as ``Simulation.step`` (and so ``csb run``) does, and every frame draws each collider
at the pose the stepper reports for it (``PbdStepper.collider_pose``), not where it was declared.

Offscreen through EGL with Mesa's software renderer, as tests/test_viewer.py; skipped as it is
when the viewer was not built (and failing instead under CSB_REQUIRE_VIEWER=1)."""

from __future__ import annotations

import os

import numpy as np
import pytest

import csb

if not csb.viewer_available():
    if os.environ.get("CSB_REQUIRE_VIEWER") == "1":
        raise RuntimeError(f"CSB_REQUIRE_VIEWER=1 but the viewer is not available: {csb.viewer_missing()}")
    pytest.skip(f"the viewer is not available: {csb.viewer_missing()}", allow_module_level=True)

BACKGROUND = np.array([219, 224, 232])  # the clear colour, sRGB (0.86, 0.88, 0.91)
W, H = 320, 240

# A sphere of radius 0.1 m that moves 0.3 m along +x in 0.5 s (and back by 1 s), and a small cloth
# pinned along its top edge, hanging 0.5 m to the right of it, out of its way: the cloth widens the
# framing so that the sphere stays in the picture.
SCENE = """
[scene]
name = "moving_ball"
duration = 1.0

[solver]
method = "xpbd"
dt = 0.016666666666666666
substeps = 4
iterations = 2

[[mesh]]
name = "flag"
shape = "cloth"
size = [0.2, 0.2]
resolution = [5, 5]
plane = "xy"
translate = [0.9, 0.0, 0.0]
mass = 0.05
stretch = { compliance = 1e-6 }
pin = { near = [[0.8, 0.1, 0.0], [1.0, 0.1, 0.0]] }

[[collider]]
type = "sphere"
name = "ball"
center = [0.0, 0.0, 0.0]
radius = 0.1
motion = { times = [0.0, 0.5, 1.0], translation = [[0, 0, 0], [0.3, 0, 0], [0, 0, 0]] }
"""


@pytest.fixture
def ball(tmp_path):
    p = tmp_path / "moving_ball.toml"
    p.write_text(SCENE)
    return p


def collider_pixels(img: np.ndarray) -> np.ndarray:
    """The collider's pixels: not background, and grey (the collider colour, lit; the cloth is blue,
    the background bluish: its B - R is 13)."""
    rgb = img.astype(int)
    covered = np.abs(rgb - BACKGROUND).max(axis=2) > 12
    return covered & (np.abs(rgb[..., 0] - rgb[..., 2]) < 10) & (np.abs(rgb[..., 0] - rgb[..., 1]) < 10)


def centroid(mask: np.ndarray) -> np.ndarray:
    """Of the pixels' centres, in the camera's pixel coordinates (pixel (i, j) covers [i, i + 1) x
    [j, j + 1), as Camera.project counts)."""
    ys, xs = np.nonzero(mask)
    return np.array([xs.mean(), ys.mean()]) + 0.5


def open_offscreen(scene, **kw):
    kw.setdefault("grid", False)
    return csb.open_viewer(scene, offscreen=True, width=W, height=H, overlay=False, samples=0, **kw)


def test_a_keyframed_sphere_is_drawn_where_the_stepper_has_moved_it(ball):
    """Frame 0 and frame 30 (0.5 s: the keyframe at +0.3 m along x). The centroid of the grey
    pixels moves by the camera's projection of the keyframed translation.

    Tolerance 1 px on each centroid: the silhouette's edge is quantised to whole pixels (a
    centroid over a disc of ~700 px moves by well under 0.5 px from that), and the perspective
    image of a sphere is an ellipse whose centre lies off the projected centre by about
    (distance from the image centre) x r²/d², here < 0.2 px (r = 0.1 m, d > 1 m, < 160 px off
    centre); the 48 x 24 facets are symmetric about the centre. The motion itself is ~60 px."""
    with open_offscreen(ball) as v:
        v.frame()
        assert v.state.t == pytest.approx(1 / 60)
        x0 = np.array(v.collider_poses()[0][1])
        assert x0 == pytest.approx([0.3 * (1 / 60) / 0.5, 0, 0], abs=1e-12), "pose at the frame's time"
        first = collider_pixels(v.screenshot())
        for _ in range(29):
            v.frame()
        assert v.state.t == pytest.approx(0.5)
        R, x1 = v.collider_poses()[0]
        assert np.array(x1) == pytest.approx([0.3, 0, 0], abs=1e-12) and np.array(R) == pytest.approx(np.eye(3))
        second = collider_pixels(v.screenshot())
        p0 = np.array(v.camera.project(x0)[:2])
        p1 = np.array(v.camera.project(np.array(x1))[:2])
    assert first.sum() > 300 and second.sum() > 300, "the sphere is drawn"
    assert np.linalg.norm(p1 - p0) > 40, "the translation is well resolved in pixels"
    c0, c1 = centroid(first), centroid(second)
    assert np.linalg.norm(c0 - p0) < 1.0, (c0, p0)
    assert np.linalg.norm(c1 - p1) < 1.0, (c1, p1)
    assert np.linalg.norm((c1 - c0) - (p1 - p0)) < 1.5, (c1 - c0, p1 - p0)


def ball_x(t: float) -> float:
    """The keyframed sphere's x (m) at t (s) up to 0.5 s."""
    return 0.3 * t / 0.5


def test_render_writes_frames_with_the_sphere_moving(ball, tmp_path):
    """csb.render (what `csb render` runs): frame k shows the state after k + 1 steps of 1/60 s,
    so frame 0 has the sphere at x = 0.01 m and frame 29 at 0.3 m; the PNGs' grey centroids move by
    the projection of that, within the tolerance above (1 px a centroid)."""
    import matplotlib.image as mpimg

    r = csb.render(ball, tmp_path / "out", frames=30, every=29, width=W, height=H, video=False, grid=False,
                   samples=0)
    assert [p.name for p in r.images] == ["frame_00000.png", "frame_00029.png"]
    imgs = [(mpimg.imread(p)[..., :3] * 255).round().astype(np.uint8) for p in r.images]
    c0, c1 = (centroid(collider_pixels(img)) for img in imgs)
    with open_offscreen(ball) as v:  # the same scene framed by the same camera
        p0 = np.array(v.camera.project([ball_x(1 / 60), 0, 0])[:2])
        p1 = np.array(v.camera.project([ball_x(30 / 60), 0, 0])[:2])
    assert np.linalg.norm(p1 - p0) > 40
    assert np.linalg.norm(c0 - p0) < 1.0 and np.linalg.norm(c1 - p1) < 1.0, (c0, p0, c1, p1)


def test_the_viewer_steps_the_scene_as_simulation_step_does():
    """cape_wave in the viewer: its cape attached to the torso, both capsules on their keyframes,
    the positions bit for bit those of Simulation.step (what `csb run` steps); after a reset the
    fresh stepper gets the attachments again and repeats the run exactly."""
    sim = csb.load_scene("cape_wave").build()
    sim.step(12)
    with open_offscreen("cape_wave") as v:
        for _ in range(12):
            v.frame()
        assert np.array_equal(np.array(v.state.x), np.array(sim.state.x))
        poses = v.collider_poses()
        for name, i in sim.colliders.items():
            R, t = sim.stepper.collider_pose(i)
            assert np.array_equal(np.array(poses[i][0]), R) and np.array_equal(np.array(poses[i][1]), t), name
        torso = np.array(poses[sim.colliders["torso"]][1])
        assert torso == pytest.approx([0, 0, 0.4 * 12 / 60], abs=1e-12), "walking at 0.4 m/s"
        v.key("r")
        for _ in range(12):
            v.frame()
        assert np.array_equal(np.array(v.state.x), np.array(sim.state.x))


def test_cape_wave_draws_the_torso_walking():
    """cape_wave seen from the side (yaw π/2, at the horizon), frames 0 and 29 (1/60 s and 0.5 s:
    the torso walked 0.4 m/s x 29/60 s along +z). The cape hangs behind the torso and the arm
    waves above its shoulder, so the check is on the torso's front edge between 0.85 and 1.15 m
    high, where only the torso is grey: per image row, the grey pixel farthest along the walk;
    their median moves by the projection of the walk, within 2 px: the edge is quantised to whole
    pixels in each image (up to 1 px on the difference), and the silhouette's tangent point of a
    capsule of radius r = 0.15 m seen from D = 2.6 m lies r³/(2 D³) rad = 0.03 px (at a focal
    length of 290 px) from the projected point at the radius; the rest is margin for the colour
    threshold at the edge (no multisampling)."""
    with open_offscreen("cape_wave", camera=csb.CameraPose(yaw=np.pi / 2, pitch=0.0)) as v:
        torso = 0  # the first collider of cape_wave.toml
        v.frame()
        first = collider_pixels(v.screenshot())
        z0 = v.collider_poses()[torso][1][2]
        for _ in range(29):
            v.frame()
        second = collider_pixels(v.screenshot())
        z1 = v.collider_poses()[torso][1][2]
        assert z0 == pytest.approx(0.4 / 60, abs=1e-12) and z1 == pytest.approx(0.4 * 30 / 60, abs=1e-12)
        # The front of the torso (radius 0.15 m) at 1 m high, in either frame, and the band of rows.
        f0 = np.array(v.camera.project([0, 1.0, z0 + 0.15])[:2])
        f1 = np.array(v.camera.project([0, 1.0, z1 + 0.15])[:2])
        top = int(np.ceil(v.camera.project([0, 1.15, z0])[1]))
        bottom = int(np.floor(v.camera.project([0, 0.85, z0])[1]))
    direction = np.sign(f1[0] - f0[0])
    assert abs(f1[0] - f0[0]) > 15, "the walk is resolved in pixels (ten times the tolerance)"
    assert abs(f1[1] - f0[1]) < 0.5, "seen from the side, at the horizon: the walk is along the rows"

    def front(mask):
        cols = [np.nonzero(mask[row])[0] for row in range(top, bottom + 1)]
        edge = [(c.max() + 1 if direction > 0 else c.min()) for c in cols if len(c)]
        assert len(edge) > 0.9 * (bottom - top + 1), "the torso is drawn in the band"
        return float(np.median(edge))

    moved = front(second) - front(first)
    assert abs(moved - (f1[0] - f0[0])) < 2.0, (moved, f1[0] - f0[0])


def test_a_window_draws_the_moving_sphere_as_offscreen_does(ball, monkeypatch):
    """The live viewer (a GLFW window on a private Xvfb display) draws the same frames: after 30
    frames the sphere's grey pixels in the window's image are where the offscreen image has them
    (the same renderer into the same kind of target: the centroids agree within 0.5 px)."""
    import shutil
    import subprocess

    if shutil.which("Xvfb") is None:
        if os.environ.get("CSB_REQUIRE_VIEWER") == "1":
            pytest.fail("Xvfb is needed (./dev test installs it)")
        pytest.skip("Xvfb is not installed")
    read, write = os.pipe()
    xvfb = subprocess.Popen(["Xvfb", "-displayfd", str(write), "-screen", "0", "1024x768x24", "-nolisten", "tcp"],
                            pass_fds=(write,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write)
    try:
        with os.fdopen(read) as f:
            number = f.readline().strip()
        assert number, "Xvfb did not start"
        monkeypatch.setenv("DISPLAY", f":{number}")
        with csb.open_viewer(ball, width=W, height=H, overlay=False, grid=False, samples=0, vsync=False,
                             title="csb-test-moving") as win, open_offscreen(ball) as off:
            for _ in range(30):
                win.frame()
                off.frame()
            assert np.array(win.collider_poses()[0][1]) == pytest.approx([0.3, 0, 0], abs=1e-12)
            a, b = collider_pixels(win.screenshot()), collider_pixels(off.screenshot())
            expected = np.array(off.camera.project([0.3, 0, 0])[:2])
    finally:
        xvfb.terminate()
        xvfb.wait(timeout=10)
    assert a.sum() > 300
    assert np.linalg.norm(centroid(a) - centroid(b)) < 0.5 and np.linalg.norm(centroid(a) - expected) < 1.0
