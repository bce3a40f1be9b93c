"""A method written in Python is a csb.Integrator like the built-ins: the scene runner, csb.render
and the studies take it, its exceptions reach the caller as raised, and two of them, written in
numpy over the model's arrays in the built-ins' order of operations, give the built-ins' bits."""

from __future__ import annotations

import gc
import math
import os
import textwrap
import weakref

import numpy as np
import pytest

import csb
from csb.backward_euler import BackwardEulerStepper
from csb.studies import make_stepper, run_method


class SymplecticEuler(csb.Integrator):
    """v' = v + h a(x), x' = x + h v' over the distance constraints as springs of stiffness 1/α,
    gravity g (m/s²): ForceStepper(method="symplectic-euler")'s operations in its order (forces
    summed over the constraints in build order, each spring's on a then on b; a = F/m + g)."""

    def __init__(self, dt: float, gravity=(0.0, -9.81, 0.0)):
        super().__init__()
        self._dt = dt
        self.gravity = np.asarray(gravity, dtype=float)

    def name(self) -> str:
        return "python-symplectic-euler"

    def dt(self) -> float:
        return self._dt

    def step(self, model, state, steps=1, interrupt=None):
        d = model.distance
        a, b = np.asarray(d["particles"], dtype=np.int64).T
        k, rest = 1.0 / np.asarray(d["compliance"]), np.asarray(d["rest_length"])
        both = np.stack([a, b], axis=1).ravel()  # a spring's force on a, then on b
        m = np.asarray(model.mass)[:, None]
        free = np.asarray(model.inv_mass) > 0
        x, v, h = np.array(state.x), np.array(state.v), self._dt
        for _ in range(steps):
            e = x[a] - x[b]
            length = np.sqrt(e[:, 0] * e[:, 0] + e[:, 1] * e[:, 1] + e[:, 2] * e[:, 2])
            f = (-k * (length - rest))[:, None] * (e / length[:, None])
            force = np.zeros_like(x)
            np.add.at(force, both, np.stack([f, -f], axis=1).reshape(-1, 3))  # in order, as the loop adds
            acc = force / m + self.gravity - 0.0 * v  # the built-in's drag term, 0 here
            v[free] = v[free] + h * acc[free]
            x[free] = x[free] + h * v[free]
            state.t += h
            state.step += 1
        v[~free] = 0.0
        state.x, state.v = x, v


class SequentialPbd(csb.Integrator):
    """Müller 2007 Algorithm 1 over distance constraints and pins (inverse mass 0): predict,
    `iterations` Gauss-Seidel sweeps of the constraints in build order with the stiffness
    corrected for the iterations, velocities from the positions; PbdStepper(ordering=
    "sequential")'s operations in its order, in Python floats."""

    def __init__(self, dt: float, *, substeps: int = 1, iterations: int = 10, gravity=(0.0, -9.81, 0.0)):
        super().__init__()
        self._dt, self.substeps, self.iterations = dt, substeps, iterations
        self.gravity = np.asarray(gravity, dtype=float)

    def name(self) -> str:
        return "python-pbd"

    def dt(self) -> float:
        return self._dt

    def step(self, model, state, steps=1, interrupt=None):
        d = model.distance
        pairs = np.asarray(d["particles"]).tolist()
        rest, sense = np.asarray(d["rest_length"]).tolist(), np.asarray(d["sense"]).tolist()
        k = [csb.corrected_stiffness(s, self.iterations) for s in np.asarray(d["stiffness"]).tolist()]
        w = np.asarray(model.inv_mass)
        wl = w.tolist()
        h = self._dt / self.substeps
        a = np.where(w > 0, h, 0.0)[:, None]
        x, v = np.array(state.x), np.array(state.v)
        for _ in range(steps):
            for _ in range(self.substeps):
                v = v + a * self.gravity
                p = (x + h * v).tolist()
                for _ in range(self.iterations):
                    for c, (i, j) in enumerate(pairs):
                        p1, p2 = p[i], p[j]
                        dx, dy, dz = p1[0] - p2[0], p1[1] - p2[1], p1[2] - p2[2]
                        length = math.sqrt(dx * dx + dy * dy + dz * dz)
                        cc = length - rest[c]
                        violation = cc - sense[c] * max(sense[c] * cc, 0.0)
                        w1, w2 = wl[i], wl[j]
                        wsum = w1 + w2
                        if wsum <= 0 or length <= 0:
                            continue
                        s = k[c] * violation / (wsum * length)
                        p1[0] -= w1 * s * dx
                        p1[1] -= w1 * s * dy
                        p1[2] -= w1 * s * dz
                        p2[0] += w2 * s * dx
                        p2[1] += w2 * s * dy
                        p2[2] += w2 * s * dz
                p = np.array(p)
                v = (p - x) / h
                x = p
            state.step += 1
            state.t += self._dt
        state.x, state.v = x, v


def spring_cloth(n: int = 6, *, compliance: float = 1e-3) -> csb.Model:
    """An n x n cloth of 0.2 kg over 1 m², distance constraints only (compliance in m/N), pinned
    at two corners."""
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, n, n), mass=0.2, stretch_compliance=compliance)
    b.pin(inst.first_particle)
    b.pin(inst.first_particle + n - 1)
    return b.build()


def hard_cloth(n: int = 6, *, stiffness: float = 1.0) -> csb.Model:
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, n, n), mass=0.2, stretch_stiffness=stiffness)
    b.pin(inst.first_particle)
    b.pin(inst.first_particle + n - 1)
    return b.build()


def test_the_interface_and_the_registry():
    assert issubclass(csb.PbdStepper, csb.Integrator) and issubclass(csb.ForceStepper, csb.Integrator)
    assert issubclass(BackwardEulerStepper, csb.Integrator)
    names = [m.name for m in csb.methods()]
    assert names == ["pbd", "xpbd", "small-steps", "jakobsen", "vbd", "projective-dynamics", "implicit-euler",
                     "backward-euler", "explicit-euler", "symplectic-euler", "velocity-verlet"]
    info = {m.name: m for m in csb.methods()}
    assert info["xpbd"].reads == "compliance" and info["pbd"].reads == "stiffness" and info["pbd"].iterates
    assert not info["small-steps"].iterates and "Macklin" in info["xpbd"].source and info["xpbd"].label == "XPBD"
    for name in names:
        s = csb.make_integrator(name, 0.01, substeps=2, iterations=3, gravity=(0, -1, 0))
        assert isinstance(s, csb.Integrator) and s.dt() == 0.01
    assert isinstance(csb.make_integrator("pbd", 0.01), csb.PbdStepper)
    assert isinstance(csb.make_integrator("velocity-verlet", 0.01), csb.ForceStepper)
    assert csb.make_integrator("small-steps", 0.01, substeps=4).settings.iterations == 1
    assert csb.make_integrator("jakobsen", 0.01).settings.front_end == "verlet"
    with pytest.raises(ValueError, match="'pbd', 'xpbd', 'small-steps'.*got 'rk4'"):
        csb.make_integrator("rk4", 0.01)
    with pytest.raises(csb.ParameterError, match="substeps"):
        csb.make_integrator("pbd", 0.01, substeps=0)
    with pytest.raises(csb.ParameterError, match="dt"):
        csb.make_integrator("xpbd", -1.0)
    method = SymplecticEuler(1e-3)
    assert method.name() == "python-symplectic-euler" and method.dt() == 1e-3
    assert "SymplecticEuler 'python-symplectic-euler', dt = 0.001 s" in repr(method)


def test_the_made_steppers_are_the_ones_the_constructors_make():
    """make_integrator's steppers step as PbdStepper's and ForceStepper's constructors' (the
    studies' make_stepper now goes through it): the same bits."""
    model = spring_cloth()
    for name, direct in [("xpbd", csb.PbdStepper(method="xpbd", dt=0.01, substeps=2, iterations=4)),
                         ("small-steps", csb.PbdStepper(method="xpbd", dt=0.01, substeps=2, iterations=1)),
                         ("symplectic-euler", csb.ForceStepper(method="symplectic-euler", dt=0.01, substeps=2))]:
        made = csb.make_integrator(name, 0.01, substeps=2, iterations=4)
        s1, s2 = model.initial_state(), model.initial_state()
        made.step(model, s1, 5)
        direct.step(model, s2, 5)
        assert np.array_equal(s1.x, s2.x) and np.array_equal(s1.v, s2.v), name


def test_python_symplectic_euler_matches_the_built_in_bit_for_bit(rng):
    """50 steps of a springy cloth thrown with random velocities: the same floating-point
    operations in the same order (IEEE 754 +, -, *, / and sqrt are correctly rounded, numpy's
    ufuncs and Eigen's fixed-size expressions do them one at a time, the module is built with
    -ffp-contract=off, so no fused multiply-add), hence bit-equal positions and velocities:
    tolerance zero."""
    model = spring_cloth()
    start = model.initial_state()
    start.v = rng.normal(scale=0.5, size=start.v.shape) * (np.asarray(model.inv_mass) > 0)[:, None]
    dt = 5e-4
    mine, theirs = start.copy(), start.copy()
    SymplecticEuler(dt).step(model, mine, 50)
    csb.ForceStepper(method="symplectic-euler", dt=dt).step(model, theirs, 50)
    moved = np.abs(np.asarray(theirs.x) - np.asarray(start.x)).max()
    assert moved > 0.01  # the springs did work: 50 steps are 25 ms of a thrown cloth
    assert np.array_equal(mine.x, theirs.x) and np.array_equal(mine.v, theirs.v)
    assert mine.step == theirs.step == 50 and mine.t == theirs.t


@pytest.mark.parametrize("substeps, iterations, stiffness", [(1, 10, 1.0), (2, 5, 0.7)])
def test_python_pbd_matches_the_sequential_built_in_bit_for_bit(substeps, iterations, stiffness):
    """A cloth of distance constraints and two pins, 50 steps of 1/60 s: the Python
    Gauss-Seidel sweep in build order is PbdStepper(ordering="sequential")'s to the bit
    (tolerance zero, for the reasons above); the soft cloth checks the stiffness correction."""
    model = hard_cloth(stiffness=stiffness)
    dt = 1 / 60
    mine, theirs = model.initial_state(), model.initial_state()
    SequentialPbd(dt, substeps=substeps, iterations=iterations).step(model, mine, 50)
    csb.PbdStepper(method="pbd", dt=dt, substeps=substeps, iterations=iterations, ordering="sequential").step(
        model, theirs, 50)
    assert np.abs(np.asarray(theirs.x) - np.asarray(model.rest_positions)).max() > 0.1  # it fell and swung
    assert np.array_equal(mine.x, theirs.x) and np.array_equal(mine.v, theirs.v)
    assert mine.step == theirs.step == 50 and mine.t == theirs.t


SCENE = """\
[scene]
name = "hanging"
duration = 0.5

[solver]
method = "pbd"
dt = 0.01
substeps = 2
iterations = 5
ordering = "sequential"

[[mesh]]
name = "cloth"
shape = "cloth"
size = [1.0, 1.0]
resolution = [6, 6]
density = 0.2
stretch = { stiffness = 1.0 }
pin = { near = [[-0.5, 0.0, -0.5], [0.5, 0.0, -0.5]] }

[output]
fps = 20
"""


def scene(tmp_path):
    path = tmp_path / "hanging.toml"
    path.write_text(textwrap.dedent(SCENE))
    return csb.load_scene(path)


def test_the_scene_runner_steps_a_python_method(tmp_path):
    sc = scene(tmp_path)
    built_in = sc.run()
    mine = sc.run(stepper=SequentialPbd(0.01, substeps=2, iterations=5))
    assert mine.simulation.stepper.name() == "python-pbd" and mine.stepper_given
    assert mine.steps == built_in.steps == 50 and len(mine.rows) == len(built_in.rows) == 11
    assert np.array_equal(mine.simulation.state.x, built_in.simulation.state.x)
    assert mine.rows == built_in.rows
    summary = mine.summary()
    assert "hanging: 50 steps of 10 ms (python-pbd), 36 particles" in summary, summary
    assert "memory: model" in summary and "CHECK" not in summary
    # The run's length follows the method's dt, and the outputs are written as for the scene's solver.
    out = tmp_path / "out"
    r = sc.run(out, stepper=SequentialPbd(0.02, iterations=5))
    assert r.steps == 25 and r.simulation.state.t == pytest.approx(0.5)
    assert {p.name for p in r.files} >= {"metrics.csv", "summary.png", "snapshot.png", "hanging.xdmf"}
    # A built-in made by name is a method given to the run too.
    xpbd = sc.run(stepper=csb.make_integrator("xpbd", 0.01, substeps=2, iterations=5))
    assert "50 steps of 10 ms (xpbd)" in xpbd.summary()
    with pytest.raises(csb.ParameterError, match="stepper must be a csb.Integrator"):
        sc.run(stepper=object())

    class NoStep(SequentialPbd):
        def dt(self):
            return 0.0

    with pytest.raises(csb.ParameterError, match=r"dt\(\) must be a time step > 0 s"):
        sc.run(stepper=NoStep(0.01))


def test_exceptions_from_a_python_step_reach_the_caller_unchanged(tmp_path):
    class Failing(SequentialPbd):
        def step(self, model, state, steps=1, interrupt=None):
            raise KeyError("no such particle: 7")

    with pytest.raises(KeyError, match="no such particle: 7"):
        scene(tmp_path).run(stepper=Failing(0.01))
    model = hard_cloth()
    times = np.arange(3) * 0.01
    with pytest.raises(KeyError, match="no such particle: 7"):
        run_method(model, model.initial_state(), times, Failing(0.01))
    # Through C++ (csb.Integrator.step, the binding the viewer's stepping goes through) as well.
    with pytest.raises(KeyError, match="no such particle: 7"):
        csb.Integrator.step(Failing(0.01), model, model.initial_state())


def test_a_method_without_step_says_what_is_missing():
    class Half(csb.Integrator):
        def name(self):
            return "half"

        def dt(self):
            return 0.01

    model = hard_cloth()
    with pytest.raises(NotImplementedError, match=r"Half does not define step\(model, state, steps=1, interrupt=None\)"):
        Half().step(model, model.initial_state())

    class Nameless(csb.Integrator):
        pass

    with pytest.raises(NotImplementedError, match=r"Nameless does not define name\(\)"):
        Nameless().name()
    with pytest.raises(NotImplementedError, match=r"Nameless does not define dt\(\)"):
        Nameless().dt()

    class Forgot(csb.Integrator):
        def __init__(self):  # no Integrator.__init__: pybind11 refuses the object
            pass

    with pytest.raises(TypeError, match="__init__"):
        Forgot()


def test_a_study_runs_a_python_method(rng):
    model = spring_cloth()
    start = model.initial_state()
    times = np.arange(6) * 0.005  # 5 samples, 10 steps of 0.5 ms apart
    reference = SymplecticEuler(5e-4)
    ref_state, ref_x = start.copy(), [np.asarray(start.x).copy()]
    for _ in times[1:]:
        reference.step(model, ref_state, 10)
        ref_x.append(np.asarray(ref_state.x).copy())
    built_in = run_method(model, start, times, make_stepper("symplectic-euler", dt=5e-4), reference_x=np.array(ref_x))
    assert not built_in["blew_up"] and built_in["error"] == 0.0  # the same bits
    mine = run_method(model, start, times, make_stepper(SymplecticEuler, dt=5e-4), reference_x=np.array(ref_x),
                      positions=True)
    assert not mine["blew_up"] and mine["error"] == 0.0
    assert np.array_equal(mine["x"], np.array(ref_x))  # the positions at the times, kept on request
    assert make_stepper(reference, dt=5e-4) is reference
    with pytest.raises(csb.ParameterError, match="dt"):
        make_stepper(reference, dt=1e-3)
    # A Python method that blows up is measured as blown up, as a built-in is.
    unstable = run_method(model, start, np.arange(3) * 0.5, SymplecticEuler(0.05), positions=True)
    assert unstable["blew_up"] and unstable["error"] == math.inf and unstable["x"] is None


def test_backward_euler_is_an_integrator_and_runs_in_a_study():
    b = csb.ModelBuilder()
    b.add_mesh(csb.chain(5, 0.1), density=0.1, stretch_compliance=1e-4)
    b.pin(0)
    model = b.build()
    stepper = BackwardEulerStepper(dt=0.01)
    assert stepper.name() == "backward-euler" and stepper.dt() == 0.01
    r = run_method(model, model.initial_state(), np.arange(4) * 0.05, stepper)
    assert not r["blew_up"] and r["wall_time"] > 0
    # Its interrupt: asked between steps, a csb.Error with the state left at the end of a step.
    state = model.initial_state()
    asked = []
    with pytest.raises(csb.Error, match="interrupted after 3 of 10 steps"):
        stepper.step(model, state, 10, interrupt=lambda: asked.append(1) or len(asked) == 3)
    assert state.step == 3 and state.t == pytest.approx(0.03)


def test_cpp_keeps_a_python_method_alive():
    """The viewer keeps a shared_ptr of the method it steps: a Python method handed to it lives,
    with its Python state, as long as the viewer, and goes with it."""
    if not csb.viewer_available():
        pytest.skip(f"the viewer is not available: {csb.viewer_missing()}")
    sc = csb.load_scene("pendulum")
    sim = sc.build()
    m = SequentialPbd(sc.solver.dt)
    m.notes = ["kept"]
    alive = weakref.ref(m)
    try:
        v = csb._viewer.Viewer(sim.model, sim.state, m, offscreen=True, width=64, height=64, overlay=False, grid=False,
                             samples=0)
    except csb.Error as e:  # no EGL here
        if os.environ.get("CSB_REQUIRE_VIEWER") == "1":
            raise
        pytest.skip(f"no offscreen context: {e}")
    del m
    gc.collect()
    assert alive() is not None and v.stepper.notes == ["kept"] and v.stepper is alive()
    v.frame()
    assert v.state.step == v.steps_per_frame > 0
    v.close()
    del v
    gc.collect()
    assert alive() is None


@pytest.fixture
def offscreen_viewer():
    """csb.open_viewer offscreen, small and plain, closed after the test; skips where the viewer
    was not built (fails instead under CSB_REQUIRE_VIEWER=1, as tests/test_viewer.py does)."""
    if not csb.viewer_available():
        if os.environ.get("CSB_REQUIRE_VIEWER") == "1":
            raise RuntimeError(f"CSB_REQUIRE_VIEWER=1 but the viewer is not available: {csb.viewer_missing()}")
        pytest.skip(f"the viewer is not available: {csb.viewer_missing()}")
    opened = []

    def open_(scene, **kw):
        kw = dict(offscreen=True, overlay=False, grid=False, samples=0, width=160, height=120) | kw
        opened.append(csb.open_viewer(scene, **kw))
        return opened[-1]

    yield open_
    for v in opened:
        v.close()


def test_the_viewer_steps_a_python_method(tmp_path, offscreen_viewer):
    sc = scene(tmp_path)
    mine = offscreen_viewer(sc, stepper=SequentialPbd(0.01, substeps=2, iterations=5), frame_time=0.02)
    theirs = offscreen_viewer(sc, frame_time=0.02)
    assert mine.method == "python-pbd" and not mine.position_based and mine.settings is None
    assert mine.dt == 0.01 and mine.steps_per_frame == 2
    for _ in range(5):
        mine.frame()
        theirs.frame()
    assert mine.state.step == theirs.state.step == 10
    assert np.array_equal(mine.state.x, theirs.state.x)  # the same bits through C++ and back
    assert mine.stats["kinetic_energy"] == theirs.stats["kinetic_energy"] > 0
    # Grabbing and the method switch are PbdStepper's: off here, and said so.
    with pytest.raises(csb.ParameterError, match="steps 'python-pbd'"):
        mine.method = "xpbd"
    mine.key("m")
    assert "method keys off: python-pbd" in mine.message
    x, y, _ = mine.camera.project(mine.state.x[20])
    mine.mouse_button(0, True, x, y)
    assert mine.held_particle == -1
    mine.mouse_button(0, False, x, y)
    mine.reset()
    assert mine.state.step == 0 and mine.method == "python-pbd"
    mine.frame()
    assert mine.state.step == 2


def test_render_draws_a_python_method_and_passes_its_errors(tmp_path, offscreen_viewer):
    offscreen_viewer("pendulum")  # skips here without the viewer
    r = csb.render(scene(tmp_path), tmp_path / "frames", frames=3, width=96, height=64, video=False,
                   stepper=SequentialPbd(0.01), frame_time=0.02)
    assert len(r.images) == 3 and all(p.exists() for p in r.images)

    class Failing(SequentialPbd):
        def step(self, model, state, steps=1, interrupt=None):
            if state.step >= 2:
                raise ZeroDivisionError("my method divided by zero")
            super().step(model, state, steps, interrupt)

    with pytest.raises(ZeroDivisionError, match="my method divided by zero"):
        csb.render(scene(tmp_path), tmp_path / "failing", frames=5, width=96, height=64, video=False,
                   stepper=Failing(0.01))
    v = offscreen_viewer(scene(tmp_path), stepper=Failing(0.01), frame_time=0.01)  # a step a frame
    v.frame()
    v.frame()
    with pytest.raises(ZeroDivisionError, match="my method divided by zero"):
        v.frame()
    with pytest.raises(ZeroDivisionError):
        v.run(3)
    with pytest.raises(csb.ParameterError, match="stepper must be a csb.Integrator"):
        offscreen_viewer(scene(tmp_path), stepper="pbd")


def test_the_documented_method_is_the_built_in_to_the_bit():
    """docs/your_own_method.md's MyPbd, run as printed (read from the checkout), on the bundled
    chain: PbdStepper(ordering="sequential")'s bits; its usage block at least compiles."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "your_own_method.md").read_text()
    method, usage = re.findall(r"```python\n(.*?)```", text, re.S)[:2]
    namespace: dict = {}
    exec(compile(method, "your_own_method.md", "exec"), namespace)
    compile(usage, "your_own_method.md", "exec")
    sim = csb.load_scene("chain").build()
    mine, theirs = sim.state.copy(), sim.state.copy()
    namespace["MyPbd"](0.0025, iterations=20).step(sim.model, mine, 40)
    csb.PbdStepper(method="pbd", dt=0.0025, iterations=20, ordering="sequential").step(sim.model, theirs, 40)
    assert np.array_equal(mine.x, theirs.x) and np.array_equal(mine.v, theirs.v) and mine.t == theirs.t
    with pytest.raises(csb.ParameterError, match="distance constraints"):
        namespace["MyPbd"](0.01).step(csb.load_scene("cloth_drop").build().model, mine)


@pytest.mark.parametrize("name", ["xpbd", "symplectic-euler"])
def test_every_integrator_takes_an_interrupt(name):
    """step(model, state, steps=1, interrupt=None) is the signature of every Integrator, the
    built-ins' too: a callable asked between (sub-)steps; True stops the step (csb.Error, the state
    at the end of a step), an exception it raises passes through."""
    model = spring_cloth()
    stepper = csb.make_integrator(name, 1e-3, substeps=2)
    state, asked = model.initial_state(), []
    with pytest.raises(csb.Error, match="interrupted"):
        stepper.step(model, state, 10, interrupt=lambda: asked.append(1) or len(asked) >= 3)
    assert 0 < state.step < 10
    with pytest.raises(ZeroDivisionError):
        stepper.step(model, model.initial_state(), 10, interrupt=lambda: 1 / 0)
    with pytest.raises(csb.ParameterError, match="interrupt must be None or a callable"):
        stepper.step(model, model.initial_state(), 1, interrupt=3)
    state = model.initial_state()
    stepper.step(model, state, 4, interrupt=lambda: False)
    assert state.step == 4
