"""The OpenGL viewer (src/viewer/), headless: offscreen through EGL with Mesa's software renderer,
and in a real GLFW window on an Xvfb display driven by xdotool. `./dev test` installs Xvfb,
xdotool and Mesa, builds the viewer and sets CSB_REQUIRE_VIEWER=1, so that these tests fail
rather than skip when the viewer is missing there.

What is checked is geometry, not taste: the cloth's pixels are where the camera projects the
simulated particles, a drag puts the held particle under the cursor, keys do what they say."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import csb

if not csb.viewer_available():
    if os.environ.get("CSB_REQUIRE_VIEWER") == "1":
        raise RuntimeError(f"CSB_REQUIRE_VIEWER=1 but the viewer is not available: {csb.viewer_missing()}")
    pytest.skip(f"the viewer is not available: {csb.viewer_missing()}", allow_module_level=True)

BACKGROUND = np.array([219, 224, 232])  # the clear colour, sRGB (0.86, 0.88, 0.91)
W, H = 320, 240


def covered(img: np.ndarray, tolerance: int = 12) -> np.ndarray:
    """Pixels that are not background."""
    return np.abs(img.astype(int) - BACKGROUND).max(axis=2) > tolerance


def projected(viewer, points: np.ndarray) -> np.ndarray:
    return np.array([viewer.camera.project(p)[:2] for p in points])


@pytest.fixture
def viewer_on():
    """Opens viewers (offscreen, no overlay or grid, unless asked) and closes them after the test,
    passed or failed, so that no window outlives the Xvfb server it is on."""
    opened = []

    def open_(scene="cloth_drop", **kw):
        kw.setdefault("offscreen", True)
        kw.setdefault("overlay", False)
        kw.setdefault("grid", False)
        kw.setdefault("samples", 0)
        kw.setdefault("width", W)
        kw.setdefault("height", H)
        opened.append(csb.open_viewer(scene, **kw))
        return opened[-1]

    yield open_
    for v in opened:
        v.close()


def test_the_build_reports_the_viewer():
    assert csb.build_info()["viewer"] == "built" and csb.viewer_missing() == ""


def test_screenshot_shows_the_cloth_where_the_simulation_says_it_is(viewer_on):
    v = viewer_on()
    for _ in range(20):  # 1/3 s: the cloth swings down from its two pinned corners
        v.frame()
    img = v.screenshot()
    assert img.shape == (H, W, 3) and img.dtype == np.uint8
    mask = covered(img)
    assert 0.03 < mask.mean() < 0.9, "blank or filled"
    x = np.array(v.state.x)
    px = projected(v, x)
    inside = (px[:, 0] >= 1) & (px[:, 0] < W - 1) & (px[:, 1] >= 1) & (px[:, 1] < H - 1)
    assert inside.all(), "the camera frames the whole cloth"
    ij = np.floor(px).astype(int)
    # Every particle's pixel (or a neighbour, for vertices on the silhouette) is covered ...
    hit = np.zeros(len(ij), bool)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            hit |= mask[ij[:, 1] + dy, ij[:, 0] + dx]
    assert hit.all(), f"{(~hit).sum()} particles fall on background"
    # ... in the cloth's colour (blue; the two pinned corners are red dots) ...
    rgb = img[ij[:, 1], ij[:, 0]].astype(int)
    assert (rgb[:, 2] > rgb[:, 0]).mean() > 0.95
    # ... and nothing else is drawn: the covered pixels lie within the particles' projection.
    ys, xs = np.nonzero(mask)
    pad = 6  # px: the pinned corners' dots are up to 9 px wide
    assert xs.min() >= px[:, 0].min() - pad and xs.max() <= px[:, 0].max() + pad
    assert ys.min() >= px[:, 1].min() - pad and ys.max() <= px[:, 1].max() + pad


def test_the_image_follows_the_simulation(viewer_on):
    v = viewer_on(paused=True)
    v.frame()
    before = covered(v.screenshot())
    v.paused = False
    for _ in range(30):
        v.frame()
    after = covered(v.screenshot())
    # The cloth hangs lower: its lowest covered row moved down the image.
    assert np.nonzero(after)[0].max() > np.nonzero(before)[0].max() + 10


def test_a_synthetic_drag_moves_the_grabbed_particle_under_the_cursor(viewer_on):
    v = viewer_on()
    for _ in range(10):
        v.frame()
    x = np.array(v.state.x)
    free = np.nonzero(np.array(v.model.inv_mass) > 0)[0]
    i = free[np.argmin(np.linalg.norm(x[free] - x[free].mean(axis=0), axis=1))]  # near the middle
    sx, sy, depth = v.camera.project(x[i])
    assert depth > 0
    v.mouse_button(0, True, sx, sy)
    held = v.held_particle
    assert held >= 0 and np.linalg.norm(x[held] - x[i]) < 0.1, "the click picks a particle at the cursor"
    before = v.screenshot()
    tx, ty = sx + 50, sy - 40
    v.mouse_move(tx, ty)
    for _ in range(5):
        v.frame()
    gx, gy, _ = v.camera.project(np.array(v.state.x)[held])
    assert abs(gx - tx) < 1.0 and abs(gy - ty) < 1.0, "a kinematic grab puts the particle under the cursor"
    after = v.screenshot()
    assert covered(after)[int(ty), int(tx)] and not covered(before)[int(ty), int(tx)], \
        "the cloth now covers the pixel it was dragged to"
    # The held particle is drawn as a yellow dot.
    r, g, b = after[int(ty), int(tx)].astype(int)
    assert r > 200 and g > 170 and b < 120
    v.mouse_button(0, False, tx, ty)
    assert v.held_particle == -1
    v.frame()  # released: it falls again
    for _ in range(20):
        v.frame()
    assert np.array(v.state.x)[held][1] < v.camera.ray(tx, ty)[0][1] + 10  # finite, still there
    assert np.isfinite(np.array(v.state.x)).all()


def test_dragging_off_the_mesh_orbits_and_the_wheel_zooms(viewer_on):
    v = viewer_on()
    v.frame()
    yaw, distance = v.camera.yaw, v.camera.distance
    v.mouse_button(0, True, 5, 5)  # a corner of the image: background
    assert v.held_particle == -1
    v.mouse_move(45, 5)
    v.mouse_button(0, False, 45, 5)
    assert v.camera.yaw != yaw
    v.scroll(2)
    assert v.camera.distance == pytest.approx(distance * 0.81)
    target = np.array(v.camera.target)
    v.mouse_button(1, True, 100, 100)
    v.mouse_move(120, 100)
    v.mouse_button(1, False, 120, 100)
    assert np.linalg.norm(np.array(v.camera.target) - target) > 0


def test_keys_pause_step_reset_and_switch_method(viewer_on):
    v = viewer_on()
    x0 = np.array(v.state.x).copy()
    dt = v.settings.dt
    v.frame()
    v.key("space")
    assert v.paused
    t = v.state.t
    x = np.array(v.state.x).copy()
    v.frame()
    assert v.state.t == t and np.array_equal(np.array(v.state.x), x), "paused: frames do not step"
    v.key("period")
    assert v.state.t == pytest.approx(t + dt) and v.paused, "one step, still paused"
    v.key("r")
    assert v.state.t == 0 and np.array_equal(np.array(v.state.x), x0), "reset: the initial state, exactly"
    assert v.method == "pbd" and v.method_switch
    names = [m.name for m in csb.methods()]  # the keys' order: 1 is the first, m the next
    v.key("m")
    assert v.method == names[1] == "xpbd"
    v.key(str(names.index("small-steps") + 1))
    assert v.method == "small-steps" and v.settings.method == "xpbd" and v.settings.iterations == 1
    v.key(str(names.index("jakobsen") + 1))
    assert v.method == "jakobsen" and v.settings.front_end == "verlet"
    v.key(str(names.index("xpbd") + 1))
    assert v.method == "xpbd" and v.settings.method == "xpbd" and v.settings.front_end == "euler"
    v.key("space")
    for _ in range(10):
        v.frame()
    assert np.isfinite(np.array(v.state.x)).all() and v.state.t > 0
    v.key("w")
    assert v.wireframe
    v.key("p")
    assert v.particles
    with pytest.raises(csb.ParameterError, match="unknown key"):
        v.key("F13")
    with pytest.raises(csb.ParameterError, match="method must be 'pbd', 'xpbd'.*got 'rk4'"):
        v.method = "rk4"


def test_switching_method_continues_from_the_same_state(viewer_on):
    """The switch keeps positions and velocities: one step after the switch equals one step of
    a fresh stepper of the new method from the same state."""
    v = viewer_on(paused=True)
    for _ in range(5):
        v.single_step()
    assert v.message == ""  # PBD reads cloth_drop's material as declared
    v.method = "xpbd"
    sim = csb.load_scene("cloth_drop").build()
    # cloth_drop declares its bending by a PBD stiffness only (0.05): XPBD reads compliance 0 and
    # makes it rigid. The viewer says so on the switch, a Python stepper with a MaterialWarning.
    note = (f"XPBD reads compliance, not stiffness: {sim.model.bending['stiffness'].size:,} bending constraints "
            "have stiffness 0.05 and compliance 0, so XPBD makes them rigid")
    assert note in v.message
    sim.state.x[:] = v.state.x
    sim.state.v[:] = v.state.v
    stepper = csb.PbdStepper(method="xpbd", dt=v.settings.dt, substeps=v.settings.substeps,
                             iterations=v.settings.iterations, damping=v.settings.damping)
    v.single_step()
    with pytest.warns(csb.MaterialWarning, match=note):
        stepper.step(sim.model, sim.state)
    assert np.array_equal(np.array(v.state.x), np.array(sim.state.x))


# A small hanging cloth whose constraints all have a compliance > 0, so that every built-in method
# can step it: the force-based and implicit ones read compliance and refuse compliance 0. Heavy
# (2 kg/m²) and sub-stepped (h = 0.5 ms) so that explicit Euler is stable over the test's steps:
# its stiffest mode, the bending, has ω h well below 1 there.
SOFT_CLOTH = """\
[scene]
name = "soft_cloth"
duration = 0.5

[solver]
method = "pbd"
dt = 0.01
substeps = 20
iterations = 5

[[mesh]]
name = "cloth"
shape = "cloth"
size = [0.5, 0.5]
resolution = [6, 6]
density = 2.0
stretch = { stiffness = 1.0, compliance = 0.1 }
bending = { stiffness = 0.1, compliance = 1.0 }
pin = { near = [[-0.25, 0.0, -0.25], [0.25, 0.0, -0.25]] }
"""

def soft_cloth(tmp_path, *, self_collision: bool = False):
    """SOFT_CLOTH, or the same cloth colliding with itself."""
    path = tmp_path / "soft_cloth.toml"
    text = SOFT_CLOTH
    if self_collision:
        text = text.replace("pin = {", "self_collision = { thickness = 0.005 }\npin = {")
    path.write_text(text)
    return csb.load_scene(path)


def made_by_name(sc, name):
    """The method as csb.make_integrator makes it from the scene's solver settings."""
    s = sc.solver
    return csb.make_integrator(name, s.dt, substeps=s.substeps, iterations=s.iterations, gravity=s.gravity)


def refusal(sc, name):
    """The csb.ParameterError's text with which the method refuses the scene's model, or None."""
    sim = sc.build()
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", csb.MaterialWarning)  # PBD's notes on the material: not a refusal
        try:
            made_by_name(sc, name).step(sim.model, sim.state)
        except csb.ParameterError as e:
            return str(e)
    return None


def test_the_method_keys_step_with_every_registered_method(viewer_on, tmp_path):
    """m goes through csb.methods() in its order and back to the first; each method steps the
    state it is handed, as the registry makes it from the scene's solver settings."""
    sc = soft_cloth(tmp_path)
    v = viewer_on(sc, frame_time=sc.solver.dt)  # a step a frame
    x0 = np.array(v.state.x)
    names = [m.name for m in csb.methods()]
    assert v.method == names[0] == "pbd" and len(names) >= 8
    for info in csb.methods()[1:] + csb.methods()[:1]:
        step = v.state.step
        v.key("m")
        assert v.method == info.name, v.message
        assert v.message.startswith(f"method: {info.label}: {info.source}")
        assert v.stepper.name() == made_by_name(sc, info.name).name() and v.dt == sc.solver.dt
        assert v.position_based == isinstance(v.stepper, csb.PbdStepper)  # grabbing follows the method
        for _ in range(3):
            v.frame()
        assert v.state.step == step + 3 and not v.paused, f"{info.name}: {v.message}"
        x = np.array(v.state.x)
        # Finite and in the cloth's reach: its 4.9 N weight stretches its columns of 10 N/m
        # springs by about 0.5 m at rest; 2 m from where it started is a method gone wrong.
        assert np.isfinite(x).all() and np.linalg.norm(x - x0, axis=1).max() < 2.0, info.name


def test_a_method_that_refuses_the_model_is_not_switched_to(viewer_on, tmp_path):
    """On cloth_drop (hard constraints: no compliance), a method that refuses the model leaves the
    viewer on its method, says why (the method's own words) and leaves the state as it was; the
    next m goes on past it."""
    for sc in (csb.load_scene("cloth_drop"),):
        reasons = {m.name: refusal(sc, m.name) for m in csb.methods()}
        refused = [n for n, r in reasons.items() if r is not None]
        assert refused and not reasons["pbd"] and not reasons["xpbd"], reasons
        v = viewer_on(sc, paused=True)
        v.single_step()
        on = v.method
        for info in csb.methods()[1:] + csb.methods()[:1]:
            x, t = np.array(v.state.x), v.state.t
            v.key("m")
            if reasons[info.name] is None:
                assert v.method == info.name, v.message
                on = info.name
                continue
            assert v.method == on and f"cannot step this model: {reasons[info.name]}" in v.message
            assert v.message.endswith(f"the method stays {on}")
            assert np.array_equal(np.array(v.state.x), x) and v.state.t == t, "the state is as it was"
            with pytest.raises(csb.ParameterError, match="cannot step this model"):
                v.method = info.name
            assert v.method == on
        assert v.method == "pbd"
        v.single_step()  # still steps
        assert np.isfinite(np.array(v.state.x)).all() and v.state.step == 2
    # A built-in handed to the viewer that refuses the model pauses at its first step, says why
    # and leaves the state as it was; the keys switch to a method that steps it.
    drop = csb.load_scene("cloth_drop")
    v = viewer_on(drop, stepper=made_by_name(drop, refused[0]))
    x = np.array(v.state.x)
    v.frame()
    assert v.paused and f"cannot step this model: {refusal(drop, refused[0])}" in v.message
    assert v.state.step == 0 and np.array_equal(np.array(v.state.x), x)
    v.key("1")
    v.paused = False
    v.frame()
    assert v.method == "pbd" and v.position_based and v.state.step == v.steps_per_frame


def test_a_method_given_by_name_or_as_a_stepper_at_start(viewer_on, tmp_path):
    sc = soft_cloth(tmp_path)
    for info in csb.methods():
        v = viewer_on(sc, method=info.name, frame_time=sc.solver.dt)
        assert v.method == info.name and v.stepper.name() == made_by_name(sc, info.name).name()
        v.frame()
        v.frame()
        assert v.state.step == 2 and np.isfinite(np.array(v.state.x)).all(), v.message
        v.close()
    v = viewer_on(sc, method="backward-euler", paused=True)
    assert not v.position_based and v.settings is None
    # The mouse does not grab with it, and says so.
    v.frame()
    sx, sy, _ = v.camera.project(np.array(v.state.x)[20])
    v.mouse_button(0, True, sx, sy)
    assert v.held_particle == -1 and "grab: position-based methods only" in v.message
    v.mouse_button(0, False, sx, sy)
    v.key("r")  # a fresh one of the same method
    assert v.method == "backward-euler" and v.state.step == 0
    # A method that cannot step the scene is refused at the start.
    hard = next(m.name for m in csb.methods() if refusal(csb.load_scene("cloth_drop"), m.name))
    with pytest.raises(csb.ParameterError, match="cannot step this model"):
        viewer_on("cloth_drop", method=hard)
    # A built-in stepper handed to the viewer: the keys switch from its settings, and back to it.
    given = made_by_name(sc, "symplectic-euler")
    v = viewer_on(sc, stepper=given, frame_time=sc.solver.dt)
    assert v.method_switch and v.method == "symplectic-euler" and v.stepper is given
    v.key("m")
    assert v.method == "velocity-verlet" and v.stepper.dt() == given.dt()
    v.frame()
    v.method = "symplectic-euler"
    assert v.stepper is given
    v.frame()
    assert v.state.step == 2
    # A scene whose solver is not position-based: its stepper, the keys from its settings.
    path = tmp_path / "implicit.toml"
    path.write_text(SOFT_CLOTH.replace('method = "pbd"', 'method = "backward-euler"'))
    v = viewer_on(csb.load_scene(path), frame_time=sc.solver.dt)
    scenes = v.stepper
    assert v.method_switch and v.method == "backward-euler" and not v.position_based
    v.key("1")
    assert v.method == "pbd" and (v.settings.substeps, v.settings.iterations) == (20, 5)
    v.frame()
    v.method = "backward-euler"
    assert v.stepper is scenes
    v.frame()
    assert v.state.step == 2 and np.isfinite(np.array(v.state.x)).all()


def test_a_diverging_method_pauses_with_its_error(viewer_on, tmp_path):
    """Explicit Euler on stiff springs (1 µm/N, one step of 10 ms: ω h in the hundreds) grows
    by orders of magnitude a step until a position is no longer finite: the viewer pauses and
    shows the error, the state is the last finite one, and the keys go on."""
    sc = soft_cloth(tmp_path)
    path = tmp_path / "stiff.toml"
    path.write_text(SOFT_CLOTH.replace("compliance = 0.1", "compliance = 1e-6").replace("substeps = 20", "substeps = 1"))
    v = viewer_on(csb.load_scene(path), method="explicit-euler", frame_time=1.0)  # 100 steps a frame
    for _ in range(10):
        v.frame()
        if v.paused:
            break
    assert v.paused and "non-finite" in v.message and "paused" in v.message, v.message
    assert np.isfinite(np.array(v.state.x)).all()
    v.key("r")
    v.key("1")
    assert v.method == "pbd"
    v.paused = False
    v.frame()
    assert np.isfinite(np.array(v.state.x)).all() and not v.paused


def test_wireframe_and_overlay_change_the_image(viewer_on):
    v = viewer_on(paused=True)
    v.frame()
    plain = v.screenshot()
    v.wireframe = True
    v.redraw()
    wire = v.screenshot()
    assert (np.abs(wire.astype(int) - plain).max(axis=2) > 30).sum() > 200
    v.wireframe = False
    v.set_overlay(True)
    v.redraw()
    over = v.screenshot()
    corner = (slice(0, 60), slice(0, 150))  # the overlay sits in the top-left corner
    assert (np.abs(over[corner].astype(int) - plain[corner]).max(axis=2) > 30).mean() > 0.3


def test_soft_body_and_colliders_are_drawn(viewer_on):
    v = viewer_on("balloon_squeeze", grid=True)
    v.frame()
    img = v.screenshot()
    mask = covered(img)
    # The balloon (blue) between two grey plates.
    grey = (np.abs(img[..., 0].astype(int) - img[..., 2]) < 12) & mask & (img.sum(axis=2) < 500)
    blue = mask & (img[..., 2].astype(int) > img[..., 0] + 40)
    assert grey.sum() > 500 and blue.sum() > 500


def test_offscreen_render_writes_the_requested_frames(tmp_path):
    r = csb.render("cloth_drop", tmp_path, frames=7, every=3, width=W, height=H, video=False)
    assert [p.name for p in r.images] == ["frame_00000.png", "frame_00003.png", "frame_00006.png"]
    import matplotlib.image as mpimg

    for p in r.images:
        img = (mpimg.imread(p)[..., :3] * 255).round().astype(np.uint8)
        assert img.shape == (H, W, 3) and covered(img).mean() > 0.02
    assert r.video is None and r.ms_per_frame > 0


def test_capture_reports_its_progress_frame_by_frame(tmp_path, capsys):
    """capture(progress=f) calls f with the frames done after each frame (csb render's bar);
    render(progress=True) draws a bar on stderr and leaves the images as without it."""
    sim = csb.load_scene("cloth_drop").build()
    done = []
    with csb._viewer.Viewer(sim.model, sim.state, sim.stepper.settings, width=W, height=H, offscreen=True) as v:
        v.capture(frames=4, directory=str(tmp_path), png=False, video=False, progress=done.append)
    assert done == [1, 2, 3, 4]
    r = csb.render("cloth_drop", tmp_path / "bar", frames=3, width=W, height=H, video=False, progress=True)
    assert len(r.images) == 3 and "render:" in capsys.readouterr().err


def test_render_takes_a_model_and_state_built_in_python_and_any_stepper(tmp_path):
    """csb.render of a Model built in Python, from a State, with a user's own Integrator: its
    step is called once per frame, the cloth is drawn, and the result shows itself in a notebook
    (the last frame inline, no video asked)."""

    class Drop(csb.Integrator):
        def __init__(self):
            super().__init__()
            self.steps = 0

        def name(self):
            return "drop"

        def dt(self):
            return 1 / 60

        def step(self, model, state, steps=1, interrupt=None):
            self.steps += steps
            free = np.asarray(model.inv_mass) > 0
            for _ in range(steps):
                state.v[free] += (0.0, -9.81 / 60, 0.0)
                state.x[:] += state.v / 60
                state.t += 1 / 60

    b = csb.ModelBuilder()
    cloth = b.add_mesh(csb.cloth_grid(1.0, 1.0, 10, 10), density=0.2)
    b.pin(cloth.first_particle)
    model = b.build()
    state = model.initial_state()
    drop = Drop()
    r = csb.render(model, tmp_path, frames=4, width=W, height=H, video=False, state=state, stepper=drop)
    assert drop.steps == 4 and len(r.images) == 4
    import matplotlib.image as mpimg

    img = (mpimg.imread(r.images[-1])[..., :3] * 255).round().astype(np.uint8)
    assert covered(img).mean() > 0.02
    assert r._repr_html_().startswith('<img width="320" height="240" src="data:image/png;base64,')
    r = csb.render(model, tmp_path / "pbd", frames=2, width=W, height=H, video=False)  # default: a PbdStepper
    assert len(r.images) == 2
    with pytest.raises(csb.ParameterError, match="state has 4 particles, the model 100"):
        csb.render(model, tmp_path, frames=1, state=_four_particle_state())
    with pytest.raises(csb.ParameterError, match="state goes with a Model"):
        csb.render("cloth_drop", tmp_path, frames=1, state=state)


def _four_particle_state():
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1.0, 1.0, 2, 2), density=0.2)
    return b.build().initial_state()


@pytest.mark.skipif(shutil.which("ffmpeg") is None, reason="ffmpeg is not installed")
def test_offscreen_render_writes_an_mp4_with_ffmpeg(tmp_path):
    r = csb.render("cloth_drop", tmp_path, frames=12, every=5, width=W, height=H)
    assert len(r.images) == 4 and r.video is not None and r.video.stat().st_size > 1000  # 0, 5, 10, 11; all in the video
    probe = subprocess.run(["ffprobe", "-v", "error", "-count_frames", "-select_streams", "v:0", "-show_entries",
                            "stream=nb_read_frames,width,height", "-of", "csv=p=0", str(r.video)],
                           capture_output=True, text=True)
    assert probe.stdout.strip() == f"{W},{H},12"
    assert r._repr_html_().startswith(f'<video width="{W}" height="{H}" controls')  # a notebook plays it inline


def test_bad_viewer_parameters_are_named(viewer_on):
    sim = csb.load_scene("cloth_drop").build()
    with pytest.raises(csb.ParameterError, match=r"viewer: width must be an integer in \[16, 16384\], got 0"):
        csb._viewer.Viewer(sim.model, sim.state, sim.stepper.settings, width=0, offscreen=True)
    with pytest.raises(csb.ParameterError, match="frame_time"):
        csb._viewer.Viewer(sim.model, sim.state, sim.stepper.settings, frame_time=0.0, offscreen=True)
    with pytest.raises(csb.ParameterError, match="frames"):
        csb.render("cloth_drop", "unused", frames=0)
    with pytest.raises(csb.ParameterError, match="zoom"):
        viewer_on(camera=csb.CameraPose(zoom=0))


def test_a_window_without_a_display_says_what_to_do():
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    code = "import csb\ntry:\n    csb.view('cloth_drop', frames=1)\nexcept csb.Error as e:\n    print(e)\n"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0 and "cannot open a window" in r.stdout and "offscreen" in r.stdout, r.stdout + r.stderr


# ------------------------------------------------------------------ a real window on Xvfb


@pytest.fixture(scope="module")
def display():
    """A private Xvfb server; its display name."""
    if shutil.which("Xvfb") is None or shutil.which("xdotool") is None:
        if os.environ.get("CSB_REQUIRE_VIEWER") == "1":
            pytest.fail("Xvfb and xdotool are needed (./dev test installs them)")
        pytest.skip("Xvfb or xdotool is not installed")
    read, write = os.pipe()
    proc = subprocess.Popen(["Xvfb", "-displayfd", str(write), "-screen", "0", "1024x768x24", "-nolisten", "tcp"],
                            pass_fds=(write,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write)
    with os.fdopen(read) as f:
        number = f.readline().strip()
    assert number, "Xvfb did not start"
    yield f":{number}"
    proc.terminate()
    proc.wait(timeout=10)


@pytest.fixture
def on_display(display, monkeypatch):
    monkeypatch.setenv("DISPLAY", display)
    return display


def xdotool(*args) -> str:
    r = subprocess.run(["xdotool", *map(str, args)], capture_output=True, text=True, timeout=30)
    assert r.returncode == 0, r.stderr
    return r.stdout


def test_window_draws_what_offscreen_draws(viewer_on, on_display):
    win = viewer_on(offscreen=False, vsync=False, title="csb-test-same")
    off = viewer_on()
    for _ in range(8):
        win.frame()
        off.frame()
    a, b = win.screenshot().astype(int), off.screenshot().astype(int)
    assert a.shape == b.shape
    # The same renderer into the same kind of target: at most a few pixels differ (rounding).
    assert (np.abs(a - b).max(axis=2) > 8).mean() < 0.002


def test_xdotool_drag_and_keys_in_a_real_window(viewer_on, on_display):
    title = f"csb-test-{os.getpid()}"
    v = viewer_on(offscreen=False, vsync=False, title=title)
    for _ in range(10):
        v.frame()
    window = xdotool("search", "--sync", "--name", title).split()[0]
    x = np.array(v.state.x)
    free = np.nonzero(np.array(v.model.inv_mass) > 0)[0]
    i = free[np.argmin(np.linalg.norm(x[free] - x[free].mean(axis=0), axis=1))]
    sx, sy, _ = v.camera.project(x[i])
    sx, sy = int(round(sx)), int(round(sy))
    xdotool("mousemove", "--window", window, sx, sy)
    v.frame()
    xdotool("mousedown", 1)
    v.frame()
    held = v.held_particle
    assert held >= 0, "the press over the cloth grabbed a particle"
    tx, ty = sx - 40, sy + 30
    xdotool("mousemove", "--window", window, tx, ty)
    for _ in range(6):
        v.frame()
    gx, gy, _ = v.camera.project(np.array(v.state.x)[held])
    assert abs(gx - tx) < 1.5 and abs(gy - ty) < 1.5
    xdotool("mouseup", 1)
    v.frame()
    assert v.held_particle == -1
    # Keys go to the window under the pointer (no window manager on Xvfb).
    xdotool("key", "space")
    v.frame()
    assert v.paused
    xdotool("key", "m")
    v.frame()
    assert v.method == "xpbd"
    xdotool("key", "q")
    assert not v.frame() and v.closed


def test_ctrl_c_stops_csb_view(on_display):
    """SIGINT (Ctrl-C in the terminal) ends `csb view`: the window closes and the command exits
    130, not held until someone closes the window."""
    import signal

    exe = Path(sys.executable).parent
    # A shell without job control starts background jobs with SIGINT ignored, and Python keeps an
    # inherited "ignore": the child gets the default disposition back, as a terminal's would have.
    with subprocess.Popen([exe / "csb", "view", "cloth_drop", "--size", "320x240"], stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True,
                          preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL)) as p:
        try:
            xdotool("search", "--sync", "--name", "csb - cloth_drop")  # the window is up and running
            p.send_signal(signal.SIGINT)
            out, err = p.communicate(timeout=30)
        finally:
            if p.poll() is None:
                p.kill()
                p.communicate()
    assert p.returncode == 130 and "interrupted" in out, (p.returncode, out, err)
    assert "Traceback" not in err


def test_csb_view_and_render_commands(on_display, tmp_path):
    exe = Path(sys.executable).parent
    r = subprocess.run([exe / "csb", "view", "cloth_drop", "--frames", "5", "--size", "320x240"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "5 frames" in r.stdout, r.stderr
    r = subprocess.run([exe / "csb", "render", "soft_cube_drop", "--frames", "4", "--every", "2", "--size", "200x150",
                        "--out", tmp_path, "--no-video"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in tmp_path.glob("*.png")) == ["frame_00000.png", "frame_00002.png", "frame_00003.png"]
    r = subprocess.run([exe / "csb", "render", "no_such_scene"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "no_such_scene" in r.stderr


def test_the_cpp_viewer_opens_a_mesh_file(tmp_path):
    exe = Path(sys.executable).parent / "csb-view"
    mesh = Path(csb.__file__).parent / "scenes" / "meshes" / "cloth_panels.obj"
    r = subprocess.run([exe, mesh, "--offscreen", "3", "--out", tmp_path, "--size", "200x150"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "1089 particles" in r.stderr and "wrote 3 frames" in r.stdout
    assert len(list(tmp_path.glob("frame_*.png"))) == 3
    r = subprocess.run([exe, tmp_path / "missing.obj", "--offscreen", "1"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "missing.obj" in r.stderr
    r = subprocess.run([exe, mesh, "--method", "rk4"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "--method" in r.stderr
    r = subprocess.run([exe, "--help"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and all(f"  {m.name}" in r.stdout for m in csb.methods()), r.stdout
    # Any registered method: a compliant cloth (lying flat: pinned at one vertex, not along its top)
    # without the ground steps with backward Euler, ...
    r = subprocess.run([exe, mesh, "--method", "backward-euler", "--stretch-compliance", "1e-4", "--no-ground",
                        "--pin", "0", "--offscreen", "2", "--out", tmp_path / "be", "--size", "200x150"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "wrote 2 frames" in r.stdout, r.stderr
    # ... and small steps, a set-up of XPBD rather than a variant, from the sub-steps given, ...
    r = subprocess.run([exe, mesh, "--method", "small-steps", "--substeps", "4", "--offscreen", "1", "--out",
                        tmp_path / "ss", "--size", "200x150"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "wrote 1 frames" in r.stdout, r.stderr
    # ... but backward Euler refuses the default hard stretch, saying why.
    r = subprocess.run([exe, mesh, "--method", "backward-euler", "--no-ground", "--pin", "0", "--offscreen", "1",
                        "--out", tmp_path / "hard"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "--method backward-euler" in r.stderr and "compliance 0" in r.stderr, r.stderr


def test_the_frame_time_benchmark_times_whole_and_paused_frames():
    from csb.bench import format_frame_times, frame_times

    (row,) = frame_times(8, ((64, 48),), frames=3, warmup=1, samples=0)
    assert row["particles"] == 64 and row["triangles"] == 2 * 7 * 7
    assert row["frame_ms"] > 0 and row["draw_ms"] > 0 and row["fps"] == pytest.approx(1e3 / row["frame_ms"])
    assert "8x8" in format_frame_times([row])


def test_closing_a_window_twice_leaves_other_windows_open(on_display):
    """close() then the destructor: GLFW is shut down once, when the last window goes."""
    first = csb.open_viewer("cloth_drop", width=W, height=H, vsync=False, overlay=False)
    first.frame()
    first.close()
    with csb.open_viewer("cloth_drop", width=W, height=H, vsync=False, overlay=False) as second:
        del first  # its destructor closes again
        import gc

        gc.collect()
        assert second.frame() and covered(second.screenshot()).mean() > 0.02
