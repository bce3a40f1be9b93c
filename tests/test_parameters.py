"""Integer parameters: a value outside its range (beyond the C++ type, negative where a count or an
index belongs, beyond any machine) is a csb.ParameterError naming the parameter and the range, from
every binding; in a scene file it is a SceneError naming file, line and key."""

from __future__ import annotations

import re
import textwrap

import numpy as np
import pytest

import csb
from csb import _core
from csb.mesh import icosphere

MAX = 2**31 - 1  # Index is int32


@pytest.fixture(scope="module")
def world():
    """A 3 x 3 cloth (soft enough for the force-based stepper), its state, and a builder of four particles."""
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1.0, 1.0, 3, 3), mass=1.0, stretch_compliance=1e-6)
    model = b.build()
    four = csb.ModelBuilder()
    g = four.add_group("g")
    for k in range(4):
        four.add_particle([0.1 * k, 0.1 * (k % 2), 0.1 * (k // 2)], 1.0, g)
    return {"model": model, "state": model.initial_state(), "builder": four, "stepper": csb.PbdStepper()}


def _tet():
    return csb.tet_box([1.0, 1.0, 1.0], [1, 1, 1])


# (name, call with the value, the message's parameter, its range)
CASES = [
    ("cloth_grid nx", lambda w, v: csb.cloth_grid(1.0, 1.0, v, 3), "cloth_grid: nx", (2, MAX)),
    ("cloth_grid ny", lambda w, v: csb.cloth_grid(1.0, 1.0, 3, v), "cloth_grid: ny", (2, MAX)),
    ("chain links", lambda w, v: csb.chain(v, 0.1), "chain: links", (1, MAX)),
    ("tet_box divisions", lambda w, v: csb.tet_box([1.0, 1.0, 1.0], [1, v, 1]), r"tet_box: divisions\[1\]", (1, MAX)),
    ("add_particle group", lambda w, v: csb.ModelBuilder().add_particle([0, 0, 0], 1.0, v), "add_particle: group", (0, MAX)),
    ("add_mesh group", lambda w, v: csb.ModelBuilder().add_mesh(csb.cloth_grid(1, 1, 2, 2), mass=1.0, group=v),
     "add_mesh: group", (-1, MAX)),
    ("add_tet_mesh group", lambda w, v: csb.ModelBuilder().add_tet_mesh(_tet(), mass=1.0, group=v),
     "add_tet_mesh: group", (-1, MAX)),
    ("add_distance i", lambda w, v: w["builder"].add_distance(v, 1), "add_distance: i", (0, MAX)),
    ("add_distance j", lambda w, v: w["builder"].add_distance(0, v), "add_distance: j", (0, MAX)),
    ("add_bending c", lambda w, v: w["builder"].add_bending(0, 1, v, 3, 1.0), "add_bending: c", (0, MAX)),
    ("add_tetrahedron d", lambda w, v: w["builder"].add_tetrahedron(0, 1, 2, v), "add_tetrahedron: d", (0, MAX)),
    ("pin", lambda w, v: w["builder"].pin(v), "pin: i", (0, MAX)),
    ("attach", lambda w, v: w["builder"].attach(v, [0, 0, 0]), "attach: i", (0, MAX)),
    ("set_thickness", lambda w, v: w["builder"].set_thickness(v, 0.01), "set_thickness: group", (0, MAX)),
    ("enable_self_collision", lambda w, v: w["builder"].enable_self_collision(v, 0.01),
     "enable_self_collision: group", (0, MAX)),
    ("PbdStepper substeps", lambda w, v: csb.PbdStepper(substeps=v), "substeps", (1, 10**6)),
    ("PbdStepper iterations", lambda w, v: csb.PbdStepper(iterations=v), "iterations", (1, 10**6)),
    ("PbdStepper threads", lambda w, v: csb.PbdStepper(threads=v), "threads", (0, 1024)),
    ("grab particle", lambda w, v: w["stepper"].grab(w["model"], w["state"], v, [0, 0, 0]), "grab: particle", (0, MAX)),
    ("move_grab handle", lambda w, v: w["stepper"].move_grab(v, [0, 0, 0]), "move_grab: handle", (0, MAX)),
    ("release handle", lambda w, v: w["stepper"].release(v), "release: handle", (0, MAX)),
    ("tear max_tears", lambda w, v: csb.tear(w["model"], w["state"], max_strain=0.1, max_tears=v),
     "tear: max_tears", (1, MAX)),
    ("ForceStepper substeps", lambda w, v: csb.ForceStepper(substeps=v), "substeps", (1, 10**6)),
    ("ForceStepper steps", lambda w, v: csb.ForceStepper().step(w["model"], w["state"].copy(), v),
     "steps", (0, 2**63 - 1)),
    ("PbdStepper steps", lambda w, v: csb.PbdStepper().step(w["model"], w["state"].copy(), v),
     "steps", (0, 2**63 - 1)),
    ("State.step", lambda w, v: setattr(w["state"].copy(), "step", v), "State.step", (0, 2**63 - 1)),
    ("icosphere subdivisions", lambda w, v: icosphere(0.5, v), "icosphere: subdivisions", (0, 13)),
    ("integrate_reference max_order",
     lambda w, v: csb.integrate_reference(w["model"], w["state"], [0.01], rtol=1e-6, max_order=v), "max_order", (1, 5)),
    ("integrate_reference max_steps",
     lambda w, v: csb.integrate_reference(w["model"], w["state"], [0.01], rtol=1e-6, max_steps=v),
     "max_steps", (1, 2**63 - 1)),
    ("corrected_stiffness iterations", lambda w, v: csb.corrected_stiffness(0.5, v), "iterations", (1, 10**6)),
    ("colour_constraints num_particles",
     lambda w, v: _core.colour_constraints(np.array([[0, 1]], dtype=np.int32), v), "num_particles", (0, MAX)),
    ("benchmark_dispatch sweeps", lambda w, v: _core.benchmark_dispatch(w["model"], w["state"].x, v, 1),
     "sweeps", (1, MAX)),
    ("benchmark_plain_distance repeats",
     lambda w, v: _core.benchmark_plain_distance(w["model"], w["state"].x, 1, v), "repeats", (1, MAX)),
]
if csb.viewer_available():  # the checks run before any window or context is made
    from csb.view import viewer_module

    Viewer = viewer_module().Viewer
    CASES += [
        ("Viewer width", lambda w, v: Viewer(w["model"], w["state"], csb.PbdStepper().settings, width=v,
                                                   offscreen=True), "viewer: width", (16, 16384)),
        ("Viewer samples", lambda w, v: Viewer(w["model"], w["state"], csb.PbdStepper().settings, samples=v,
                                                     offscreen=True), "viewer: samples", (0, 16)),
        ("Viewer tear_max_per_step",
         lambda w, v: Viewer(w["model"], w["state"], csb.PbdStepper().settings, tear_max_per_step=v,
                                   offscreen=True), "viewer: tear_max_per_step", (1, MAX)),
    ]


def _outside(lo, hi):
    """Values past the C++ type or the range on both sides (2**31, 2**40, 10**12, 2**64, lo - 1)."""
    return sorted({v for v in (2**31, 2**40, 10**12, 2**64) if v > hi} | {lo - 1, hi + 1})


@pytest.mark.parametrize("name, call, param, bounds", CASES, ids=[c[0] for c in CASES])
def test_an_integer_out_of_range_is_a_parameter_error_naming_it_and_its_range(world, name, call, param, bounds):
    lo, hi = bounds
    for value in _outside(lo, hi):
        with pytest.raises(csb.ParameterError,
                           match=rf"^{param} must be an integer in \[{lo}, {hi}\], got {value}$"):
            call(world, value)
    with pytest.raises(csb.ParameterError, match=rf"^{param} must be an integer in \[{lo}, {hi}\], got 2\.5$"):
        call(world, 2.5)


def test_integers_at_the_bounds_and_numpy_integers_are_accepted():
    assert csb.PbdStepper(substeps=10**6, iterations=10**6, threads=1024).settings.substeps == 10**6
    assert csb.PbdStepper(substeps=np.int64(3), iterations=np.uint8(2), threads=True).settings.iterations == 2
    assert csb.chain(np.int32(4), 0.1).num_vertices == 5
    assert csb.corrected_stiffness(0.5, 1) == 0.5


def test_the_bounds_are_exported():
    assert (_core.MAX_INDEX, _core.MAX_SUBSTEPS, _core.MAX_ITERATIONS, _core.MAX_THREADS) == (MAX, 10**6, 10**6, 1024)


SCENE = """\
[scene]
name = "tiny"
duration = 0.1

[solver]
dt = 0.01
substeps = 2
iterations = 5
threads = 1

[[mesh]]
name = "m"
shape = "cloth"
size = [1.0, 1.0]
resolution = [4, 4]
density = 0.2

[tearing]
max_strain = 0.5
max_per_step = 3
"""


@pytest.mark.parametrize(
    "edit, message",
    [
        (("iterations = 5", "iterations = 4294967295"),
         r"bad\.toml:8: solver\.iterations: must be an integer in \[1, 1000000\], got 4294967295"),
        (("substeps = 2", "substeps = 2147483648"),
         r"bad\.toml:7: solver\.substeps: must be an integer in \[1, 1000000\], got 2147483648"),
        (("threads = 1", "threads = 1000000"),
         r"bad\.toml:9: solver\.threads: must be an integer in \[0, 1024\], got 1000000"),
        (("resolution = [4, 4]", "resolution = [4, 1099511627776]"),
         rf"bad\.toml:15: mesh\[0\] \(m\)\.resolution: must be a list of integers in \[0, {MAX}\], "
         r"got \[4, 1099511627776\]"),
        (("max_per_step = 3", "max_per_step = 2147483648"),
         rf"bad\.toml:20: tearing\.max_per_step: must be an integer in \[1, {MAX}\], got 2147483648"),
    ],
)
def test_an_integer_out_of_range_in_a_scene_names_file_line_and_key(tmp_path, edit, message):
    path = tmp_path / "bad.toml"
    path.write_text(textwrap.dedent(SCENE).replace(*edit))
    with pytest.raises(csb.SceneError, match=message):
        csb.load_scene(path)


def test_the_scene_above_loads_as_given(tmp_path):
    path = tmp_path / "good.toml"
    path.write_text(SCENE)
    scene = csb.load_scene(path)
    assert (scene.solver.substeps, scene.solver.iterations, scene.solver.threads) == (2, 5, 1)
    assert re.fullmatch(r"good\.toml", scene.path.name)
