"""The single-precision solver (PbdStepper(precision="float32")): deterministic within its
precision, close to double precision where the motion is smooth, and refusing what it does not
run, by name.

float32 keeps the state in double between steps and rounds it to float for a step: positions,
velocities, predictions and the distance and bending constraints' data run in float, in twice
the SIMD lanes of double. Its bits are pinned here as double's are elsewhere (the same scene, the
same settings, the same bits on any thread count and instruction set), so a change that moves
either precision's results shows up as a failing digest, not as a silent drift."""

from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest

import csb
from csb import _core
from helpers import copies_here

K = _core.kernels


def cloth(n: int = 24, *, bending_compliance: float = 1e-2) -> csb.Model:
    """A 1 m cloth of n x n particles (0.2 kg), hanging from two corners: stretch and shear edges
    (compliance 0: rigid for XPBD; stiffness 1 for PBD) and dihedral bending."""
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, n, n, "xz", (0, 1, 0)), mass=0.2, stretch_stiffness=1.0,
                      bending_stiffness=0.1, bending_compliance=bending_compliance)
    b.pin(inst.nearest([-0.5, 1, -0.5]))
    b.pin(inst.nearest([0.5, 1, -0.5]))
    return b.build()


def digest(state: csb.State) -> str:
    return hashlib.sha256(np.ascontiguousarray(state.x).tobytes() +
                          np.ascontiguousarray(state.v).tobytes()).hexdigest()[:16]


def stepped(model, precision: str, *, method: str = "pbd", threads: int = 1, steps: int = 30, **settings):
    state = model.initial_state()
    stepper = csb.PbdStepper(method=method, substeps=10, iterations=1, threads=threads, precision=precision,
                             **settings)
    stepper.step(model, state, steps)
    return state, stepper


# Each variant the single-precision step runs differently: PBD; XPBD undamped and damped (its
# edges' multipliers with the bending elements, the damping term gathered); Jakobsen on the Verlet
# front end with the exact square root and with its approximation (plain blocks, no edge pairs).
VARIANTS = {
    "pbd": dict(method="pbd"),
    "xpbd": dict(method="xpbd"),
    "xpbd-damped": dict(method="xpbd", xpbd_damping=1e-3),
    "jakobsen": dict(method="jakobsen", verlet_drag=0.01),
    "jakobsen-approx": dict(method="jakobsen", sqrt_approximation=True),
}

# The digests of the 24 x 24 cloth after 30 steps (x and v): a result changes only on purpose.
PINNED = {
    ("pbd", "float64"): "3374e8d6251bbc10",
    ("pbd", "float32"): "ebabe9ecf3298872",
    ("xpbd", "float64"): "a25503b4e68c660a",
    ("xpbd", "float32"): "e67136e61d0c8e5d",
}


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_float32_gives_the_same_bits_on_any_thread_count_and_instruction_set(variant):
    """Two partitions of the cloth into parts (the threads' tasks) and every copy of the blocked
    kernels this processor runs: IEEE +, -, *, /, sqrt and selects give the same bits in any
    lane, and the order of every update is fixed by the colouring, so one digest."""
    model = cloth(40)  # 1,600 particles: two parts, so two threads share the sweep
    digests = set()
    try:
        for isa in copies_here():
            K.kernel_isa(isa)
            for threads in (1, 2):
                state, stepper = stepped(model, "float32", threads=threads, steps=10, **VARIANTS[variant])
                assert stepper.threads_used == threads
                assert np.isfinite(state.x).all()
                digests.add(digest(state))
    finally:
        K.kernel_isa("auto")
    assert len(digests) == 1, digests


@pytest.mark.parametrize("method", ["pbd", "xpbd"])
@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_each_precision_has_its_pinned_bits(method, precision):
    state, _ = stepped(cloth(), precision, method=method)
    assert digest(state) == PINNED[method, precision]


def test_float32_is_deterministic_from_step_to_step():
    """Stepping 30 steps at once or 30 single steps: the state goes back to double between steps,
    and float32 rounds it again to the same floats (a float widened to double and rounded back is
    the same float), so the same bits."""
    model = cloth()
    once, _ = stepped(model, "float32", method="xpbd")
    state = model.initial_state()
    stepper = csb.PbdStepper(method="xpbd", substeps=10, iterations=1, precision="float32")
    for _ in range(30):
        stepper.step(model, state, 1)
    assert digest(state) == digest(once)


@pytest.mark.parametrize("method", ["pbd", "xpbd", "jakobsen"])
def test_float32_changes_the_result_far_less_than_the_discretisation_does(method):
    """A cloth hanging from two corners, released flat, 0.5 s at 10 sub-steps a step: float32 rounds
    the positions to 2^-24 relative at every sub-step, and the near-inextensible cloth passes the
    rounding on (its difference from float64 grows to about 0.5 mm). What the method itself gets
    wrong is far larger: halving the sub-step moves the same particles by about 8 cm. float32 must
    stay below a hundredth of that, so that no study's conclusion about a method can come from
    the precision it ran in (measured: about 1/150)."""
    model = cloth()
    s64, _ = stepped(model, "float64", method=method)
    s32, _ = stepped(model, "float32", method=method)
    finer = model.initial_state()
    csb.PbdStepper(method=method, substeps=20, iterations=1).step(model, finer, 30)
    rounding = np.abs(np.asarray(s32.x) - np.asarray(s64.x)).max()
    discretisation = np.abs(np.asarray(finer.x) - np.asarray(s64.x)).max()
    assert 0 < rounding < 0.01 * discretisation, (rounding, discretisation)


def test_float32_multipliers_follow_float64():
    """XPBD's multipliers (the constraint forces times h²) come back in the model's order,
    widened from float; on the same motion they agree with double's to 1 % of the largest (the
    positions differ by under 1 mm, see above)."""
    model = cloth()
    _, m64 = stepped(model, "float64", method="xpbd")
    _, m32 = stepped(model, "float32", method="xpbd")
    for kind in ("distance", "bending"):
        a, b = m64.multipliers()[kind], m32.multipliers()[kind]
        assert a.shape == b.shape and len(a) > 0
        scale = np.abs(a).max()
        assert scale > 0 and np.abs(a - b).max() < 1e-2 * scale, kind


def test_float32_memory_is_smaller_than_float64():
    model = cloth(64)
    _, s64 = stepped(model, "float64", method="xpbd", steps=1)
    _, s32 = stepped(model, "float32", method="xpbd", steps=1)
    assert s32.workspace_bytes < 0.85 * s64.workspace_bytes, (s32.workspace_bytes, s64.workspace_bytes)


def test_a_state_beyond_float_is_an_error_naming_the_particle_and_leaves_the_state():
    """A speed of 1e39 m/s is finite in double and infinite in float: the step says so, naming the
    particle, and the state stays where the step started (nothing is silently clamped)."""
    model = cloth(8)
    state = model.initial_state()
    v = np.zeros((model.num_particles, 3))
    v[5] = (0, 1e39, 0)
    state.v = v
    before = (np.asarray(state.x).copy(), np.asarray(state.v).copy())
    stepper = csb.PbdStepper(substeps=2, iterations=1, precision="float32", max_speed=math.inf)
    with pytest.raises(csb.SimulationError, match=r"single precision\): particle \d+ got a non-finite position"):
        stepper.step(model, state, 1)
    assert np.array_equal(state.x, before[0]) and np.array_equal(state.v, before[1])


@pytest.mark.parametrize("settings, words", [
    (dict(ordering="sequential"), "coloured Gauss-Seidel"),
    (dict(solver="jacobi"), "coloured Gauss-Seidel"),
    (dict(damping=0.1), "Müller's damping"),
])
def test_float32_refuses_settings_it_does_not_run(settings, words):
    with pytest.raises(csb.ParameterError, match=words):
        csb.PbdStepper(precision="float32", **settings)


def test_an_unknown_precision_is_refused_by_name():
    with pytest.raises(csb.ParameterError, match="precision must be 'float64' or 'float32', got 'half'"):
        csb.PbdStepper(precision="half")


def test_float32_refuses_a_model_with_what_it_does_not_run_naming_it():
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, 8, 8, "xz", (0, 1, 0)), mass=0.2, stretch_stiffness=1.0)
    b.attach(inst.nearest([0, 1, 0]), (0, 1, 0))
    b.add_plane(point=(0, -1, 0))
    model = b.build()
    state = model.initial_state()
    with pytest.raises(csb.ParameterError, match=r"this model and stepper have 1 attachments, 1 colliders: use "
                                                 r"precision 'float64'"):
        csb.PbdStepper(precision="float32").step(model, state, 1)
    assert np.array_equal(state.x, model.initial_state().x)


def dragged(model, precision: str, *, substeps: int = 10, threads: int = 1, steps: int = 30):
    """The cloth with its far edge's middle particle held by a kinematic grab whose hand moves 1 cm
    up (y) and 0.5 cm along z a step; the state, the particle and the hand's last position."""
    state = model.initial_state()
    stepper = csb.PbdStepper(method="xpbd", substeps=substeps, iterations=1, threads=threads, precision=precision)
    i = int(np.argmin(np.linalg.norm(np.asarray(state.x) - [0.0, 1.0, 0.5], axis=1)))
    start = np.asarray(state.x)[i].copy()
    hand = stepper.grab(model, state, i, start)
    for k in range(1, steps + 1):
        target = start + k * np.array([0.0, 0.01, 0.005])
        stepper.move_grab(hand, target)
        stepper.step(model, state, 1)
    return state, i, target


def test_float32_drags_a_kinematic_grab_as_float64_does():
    """A kinematic grab (compliance 0) runs in float: the held particle ends each step at the hand,
    rounded once to float (half a unit in the last place: at most 2^-24 m for coordinates below
    2 m), the rest of the cloth follows double's to far less than the method's own error (halving
    the sub-step, as for the hanging cloth above: below a hundredth of it; measured about 1/200),
    and one and two threads give the same bits."""
    model = cloth()
    s64, i, target = dragged(model, "float64")
    s32, _, _ = dragged(model, "float32")
    s32b, _, _ = dragged(model, "float32", threads=2)
    finer, _, _ = dragged(model, "float64", substeps=20)
    assert np.abs(target).max() < 2 and np.abs(np.asarray(s32.x)[i] - target).max() <= 2.0 ** -24
    assert np.array_equal(s32.x, s32b.x) and np.array_equal(s32.v, s32b.v)
    rounding = np.abs(np.asarray(s32.x) - np.asarray(s64.x)).max()
    discretisation = np.abs(np.asarray(finer.x) - np.asarray(s64.x)).max()
    assert 0 < rounding < 0.01 * discretisation, (rounding, discretisation)


def test_float32_refuses_a_compliant_grab_naming_it():
    model = cloth(8)
    state = model.initial_state()
    stepper = csb.PbdStepper(precision="float32")
    stepper.grab(model, state, 10, (0, 2, 0), compliance=1e-3)
    with pytest.raises(csb.ParameterError, match=r"1 compliant grabs \(compliance > 0\)"):
        stepper.step(model, state, 1)


def test_a_scene_file_and_the_command_line_choose_the_precision(tmp_path):
    from csb.scene import SolverSpec

    assert SolverSpec(method="xpbd", precision="float32").stepper().settings.precision == "float32"
    assert SolverSpec().stepper().settings.precision == "float64"


def test_a_long_float32_step_stops_on_a_signal_between_its_forks_of_sub_steps():
    """A step of 3000 sub-steps runs in forks of 64, the state widened to double between them: a
    SIGINT from another thread stops it within a fraction of a second at the end of a fork, with
    a finite state, and stepping on from it works."""
    from test_threads import sigint_after

    model = cloth(32)
    state = model.initial_state()
    stepper = csb.PbdStepper(substeps=3000, iterations=1, precision="float32")
    h = 1 / 60 / 3000
    with sigint_after(0.2) as waited:
        stepper.step(model, state, 5)
    assert waited[0] < 2.0
    assert state.step < 5 and np.isfinite(state.x).all() and np.isfinite(state.v).all()
    done = round((state.t - state.step / 60) / h)
    assert state.t == pytest.approx(state.step / 60 + done * h, rel=1e-12) and done % 64 == 0
    steps = state.step
    stepper.step(model, state, 1)
    assert state.step == steps + 1
