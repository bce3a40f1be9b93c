"""Deforming mesh colliders drawn where they are: the viewer and csb.render (what `csb render`
runs) draw a mesh collider the stepper deforms (PbdStepper.deform_collider, driven as
Simulation.step drives it) in the shape the stepper reports (PbdStepper.collider_vertices) every
frame, and leave a static mesh as uploaded; `csb run`'s snapshot.png draws a skinned collider in
its shape at the last step, not at t = 0.

Offscreen through EGL with Mesa's software renderer, as tests/test_viewer.py; the viewer tests are
skipped as it skips them when the viewer was not built (and fail instead under
CSB_REQUIRE_VIEWER=1). The snapshot tests need no viewer."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

import csb

needs_viewer = pytest.mark.skipif(not csb.viewer_available() and os.environ.get("CSB_REQUIRE_VIEWER") != "1",
                                  reason="the viewer was not built")

BACKGROUND = np.array([219, 224, 232])  # the clear colour, sRGB (0.86, 0.88, 0.91)
W, H = 320, 240
SPEED = 0.8  # m/s: how fast the sheet's top edge rises (0.4 m by 0.5 s)

# A 0.4 x 0.4 m sheet facing the camera (z = 0, from y = 0 to 0.4 m) whose top edge rises at
# SPEED while its bottom edge stays (deform_collider: a stretch no rigid pose can give), a static
# 0.2 x 0.4 m post to its left (a mesh collider that does not deform), and a small cloth pinned
# 0.6 m to the right, up to y = 0.8 m, so that the framing takes in where the top edge goes.
SHEET = np.array([[-0.2, 0.0, 0.0], [0.2, 0.0, 0.0], [0.2, 0.4, 0.0], [-0.2, 0.4, 0.0]])
POST = np.array([[-0.7, 0.0, 0.0], [-0.5, 0.0, 0.0], [-0.5, 0.4, 0.0], [-0.7, 0.4, 0.0]])
QUAD = np.array([[0, 1, 2], [0, 2, 3]])

SCENE = """
[scene]
name = "rising_sheet"
duration = 0.5

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
translate = [0.9, 0.7, 0.0]
mass = 0.05
stretch = { compliance = 1e-6 }
pin = { near = [[0.8, 0.8, 0.0], [1.0, 0.8, 0.0]] }

[[collider]]
type = "mesh"
name = "sheet"
file = "sheet.obj"

[[collider]]
type = "mesh"
name = "post"
file = "post.obj"
"""


def sheet_at(t: float) -> np.ndarray:
    """The sheet's vertices (m) at t (s): the top edge (vertices 2 and 3) raised by SPEED t."""
    v = SHEET.copy()
    v[2:, 1] += SPEED * t
    return v


@pytest.fixture
def scene_file(tmp_path):
    csb.save_mesh(csb.Mesh(SHEET, QUAD, name="sheet"), str(tmp_path / "sheet.obj"))
    csb.save_mesh(csb.Mesh(POST, QUAD, name="post"), str(tmp_path / "post.obj"))
    p = tmp_path / "rising_sheet.toml"
    p.write_text(SCENE)
    return p


def rising(scene_file) -> csb.Simulation:
    sim = csb.load_scene(scene_file).build()
    sim.collider_deformation["sheet"] = sheet_at
    return sim


def collider_pixels(img: np.ndarray) -> np.ndarray:
    """The colliders' pixels: not background, and grey (the collider colour, lit; the cloth is
    blue, the background bluish: its B - R is 13)."""
    rgb = img.astype(int)
    covered = np.abs(rgb - BACKGROUND).max(axis=2) > 12
    return covered & (np.abs(rgb[..., 0] - rgb[..., 2]) < 10) & (np.abs(rgb[..., 0] - rgb[..., 1]) < 10)


def rows(mask: np.ndarray, left: float, right: float) -> tuple[int, int]:
    """The first and one past the last row with a grey pixel in columns [left, right] (pixels)."""
    band = mask[:, int(np.ceil(left)):int(np.floor(right)) + 1]
    r = np.nonzero(band.any(axis=1))[0]
    assert len(r), "the collider is drawn in those columns"
    return int(r[0]), int(r[-1]) + 1


def open_offscreen(scene, **kw):
    kw.setdefault("grid", False)
    return csb.open_viewer(scene, offscreen=True, width=W, height=H, overlay=False, samples=0,
                           camera=csb.CameraPose(yaw=0.0, pitch=0.0), **kw)


# Edges: without multisampling a pixel is the sheet's (flat-lit, one colour) when its centre is
# inside the projected triangle, so the first grey row r of an edge at image height y satisfies
# y - 0.5 <= r < y + 0.5; 1 px on each edge allows that and the rasteriser's sub-pixel snapping
# (1/256 px in Mesa). The rise over the 29 frames between the images is ~40 px.
EDGE_PX = 1.0


def edges(v, mask: np.ndarray, t: float) -> None:
    """The sheet's top edge at SPEED t above 0.4 m and its bottom edge at 0 in `mask`, within
    EDGE_PX; columns well inside the sheet (x from -0.15 to 0.15 m)."""
    cam = v.camera
    left, right = cam.project([-0.15, 0.2, 0.0])[0], cam.project([0.15, 0.2, 0.0])[0]
    top, bottom = rows(mask, left, right)
    assert top == pytest.approx(cam.project([0.0, 0.4 + SPEED * t, 0.0])[1], abs=EDGE_PX), t
    assert bottom == pytest.approx(cam.project([0.0, 0.0, 0.0])[1], abs=EDGE_PX), t


def post_columns(v) -> tuple[float, float]:
    return v.camera.project([-0.68, 0.2, 0.0])[0], v.camera.project([-0.52, 0.2, 0.0])[0]


@needs_viewer
def test_a_deforming_sheet_is_drawn_in_the_shape_the_stepper_reports(scene_file):
    """Frames 1 (t = 1/60 s) and 30 (0.5 s): Viewer.collider_vertices() is the sheet's
    deformation at the frame's time (the stepper's, exactly) and None for the static post; the
    poses stay the identity (the sheet moves by its vertices alone). In the images the sheet's top
    edge rises by the projection of SPEED t while its bottom edge stays, each within EDGE_PX, and
    the post's pixels are the same in both (its range of the colliders' buffer is left alone)."""
    sim = rising(scene_file)
    sheet, post = sim.colliders["sheet"], sim.colliders["post"]
    with open_offscreen(sim) as v:
        v.frame()
        t0 = v.state.t
        assert t0 == pytest.approx(1 / 60)
        drawn = v.collider_vertices()
        np.testing.assert_array_equal(drawn[sheet], sheet_at(t0))
        assert drawn[post] is None
        first = collider_pixels(v.screenshot())
        edges(v, first, t0)
        for _ in range(29):
            v.frame()
        t1 = v.state.t
        assert t1 == pytest.approx(0.5)
        np.testing.assert_array_equal(v.collider_vertices()[sheet], sheet_at(t1))
        for R, t in v.collider_poses():
            assert np.array_equal(np.array(R), np.eye(3)) and np.array_equal(np.array(t), np.zeros(3))
        second = collider_pixels(v.screenshot())
        edges(v, second, t1)
        rise = v.camera.project([0.0, 0.4 + SPEED * t0, 0.0])[1] - v.camera.project([0.0, 0.4 + SPEED * t1, 0.0])[1]
        assert rise > 20 * EDGE_PX, "the rise is well resolved in pixels"
        a, b = post_columns(v)
        cols = slice(int(np.floor(a)) - 2, int(np.ceil(b)) + 3)
        assert first[:, cols].sum() > 100, "the post is drawn"
        assert np.array_equal(first[:, cols], second[:, cols]), "the static post stays as declared"


@needs_viewer
def test_render_writes_frames_with_the_sheet_rising(scene_file, tmp_path):
    """csb.render: frame k shows the state after k + 1 steps of 1/60 s, so frame 0 has the top edge
    at 0.4 + SPEED/60 m and frame 29 at 0.4 + SPEED/2 m; the PNGs' edges are where the camera
    projects them, within EDGE_PX."""
    import matplotlib.image as mpimg

    r = csb.render(rising(scene_file), tmp_path / "out", frames=30, every=29, width=W, height=H, video=False,
                   grid=False, samples=0, camera=csb.CameraPose(yaw=0.0, pitch=0.0))
    assert [p.name for p in r.images] == ["frame_00000.png", "frame_00029.png"]
    imgs = [(mpimg.imread(p)[..., :3] * 255).round().astype(np.uint8) for p in r.images]
    with open_offscreen(rising(scene_file)) as v:  # the same scene framed by the same camera
        for img, t in zip(imgs, (1 / 60, 30 / 60)):
            edges(v, collider_pixels(img), t)


@needs_viewer
def test_the_bundled_skinned_character_is_drawn_moving():
    """cape_skinned in the viewer: after 30 frames (0.5 s) the body's vertices drawn are the
    stepper's, which are the skinned animation's at that time and not its t = 0 shape (the body
    has walked 0.2 m); the body's grey pixels have moved."""
    sim = csb.load_scene("cape_skinned").build()
    body = sim.colliders["body"]
    deform = sim.collider_deformation["body"]
    with open_offscreen(sim) as v:
        v.frame()
        first = collider_pixels(v.screenshot())
        for _ in range(29):
            v.frame()
        drawn = v.collider_vertices()[body]
        np.testing.assert_array_equal(drawn, deform(v.state.t))
        assert np.abs(drawn - deform(0.0)).max() > 0.1
        second = collider_pixels(v.screenshot())
    assert first.sum() > 500 and second.sum() > 500
    assert (first != second).sum() > 0.1 * first.sum(), "the body is drawn where it has gone"


# ------------------------------------------------------------------ csb run's snapshot.png

# The bundled skinned character (it walks along +z at 0.4 m/s) and a 1 m cloth hung 0.6 m in front
# of it, out of its way for 0.5 s, that the snapshot's framing (around the cloth) takes the body in.

BODY_SCENE = """
[scene]
name = "skinned_snapshot"
duration = 0.5

[solver]
method = "xpbd"
dt = 0.016666666666666666
substeps = 4
iterations = 2

[[mesh]]
name = "flag"
shape = "cloth"
size = [1.0, 1.0]
resolution = [4, 4]
plane = "xy"
translate = [0.0, 1.0, 0.6]
mass = 0.05
stretch = { compliance = 1e-6 }
pin = { near = [[-0.5, 1.5, 0.6], [0.5, 1.5, 0.6]] }

[[collider]]
type = "mesh"
name = "body"
file = "{file}"
animation = true

[output]
xdmf = false
vtu = false
csv = false
"""


def test_the_snapshot_draws_a_skinned_collider_at_the_last_step(tmp_path, monkeypatch):
    """`csb run` (Scene.run) of a scene with the bundled skinned character as its collider for
    0.5 s: snapshot.png is drawn with the body's vertices at the last step (the stepper's, which
    are the skinned animation's at t = 0.5 s: the body has walked 0.2 m from its t = 0 shape) and
    the stepper's poses; drawn with those vertices the picture differs from the t = 0 shape's, and
    drawn with the declared vertices given explicitly it is the t = 0 picture, byte for byte (the
    vertices are what moves the drawing)."""
    from csb import output, runner

    gltf = Path(csb.__file__).parent / "scenes" / "meshes" / "waving_character.gltf"
    p = tmp_path / "skinned_snapshot.toml"
    p.write_text(BODY_SCENE.replace("{file}", gltf.as_posix()))
    calls = []
    real = output.plot_snapshot

    def spy(path, model, state, title, poses=None, vertices=None):
        calls.append((path, model, state, poses, vertices))
        return real(path, model, state, title, poses, vertices)

    monkeypatch.setattr(runner, "plot_snapshot", spy)
    result = csb.load_scene(p).run(tmp_path / "out")
    sim = result.simulation
    assert (tmp_path / "out" / "snapshot.png") in result.files
    (path, model, state, poses, vertices), = calls
    body = sim.colliders["body"]
    deform = sim.collider_deformation["body"]
    assert state.t == pytest.approx(0.5)
    np.testing.assert_array_equal(vertices[body], sim.stepper.collider_vertices(sim.model, body))
    np.testing.assert_array_equal(vertices[body], deform(state.t))
    declared = np.asarray(model.colliders[body]["vertices"])
    assert np.abs(vertices[body] - declared).max() > 0.1
    R, t = poses[body]
    assert np.array_equal(np.array(R), np.eye(3)) and np.array_equal(np.array(t), np.zeros(3))

    at_end = tmp_path / "end.png"
    as_declared = tmp_path / "declared.png"
    given_declared = tmp_path / "given_declared.png"
    real(at_end, model, state, "t", poses, vertices)
    real(as_declared, model, state, "t", poses, None)
    real(given_declared, model, state, "t", poses, [declared])
    import matplotlib.image as mpimg

    end, dec, given = (mpimg.imread(q) for q in (at_end, as_declared, given_declared))
    assert np.array_equal(dec, given)
    assert (np.abs(end - dec).max(axis=2) > 0.1).sum() > 500, "the body is drawn elsewhere"
