"""csb.VertexBlockDescent (Chen, Liu, Yang and Yuksel 2024): per-vertex Newton steps, colour by
colour, on the backward Euler step's incremental potential. With enough sweeps it is the converged
backward Euler step (csb.BackwardEuler); with few it is an approximation whose backward-Euler
residual (csb.backward_euler_residual) falls with the sweeps."""

from __future__ import annotations

import numpy as np
import pytest

import csb

from helpers import cloth_over_sphere
from test_implicit_euler import copy_state, every_type

G = np.array([0.0, -9.81, 0.0])
H = 1.0 / 60.0  # s


def cloth(n: int = 6, *, stretch: float = 1e-4, bending: float = 0.05) -> csb.Model:
    """An n x n cloth of 1 m, 0.2 kg: stretch springs (m/N) and bending (1/(N m)), two corners pinned."""
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, n, n), mass=0.2, stretch_compliance=stretch, bending_stiffness=1.0,
                      bending_compliance=bending)
    b.pin(inst.first_particle)
    b.pin(inst.first_particle + n - 1)
    return b.build()


def tet_block() -> csb.Model:
    """A box of 2 x 1 x 1 cells of 6 tets (edge springs, tet volumes) held by an attachment and
    tethered (euclidean tethers to the attached corner's pin)."""
    b = csb.ModelBuilder()
    box = b.add_tet_mesh(csb.tet_box([0.4, 0.2, 0.2], [2, 1, 1]), mass=1.0, stretch_compliance=1e-3,
                         volume_compliance=1e-2)
    b.attach(box.first_particle, [0.0, 0.1, 0.0], compliance=1e-3)
    b.pin(box.first_particle + 1)
    b.add_tethers(mode="euclidean", max_stretch=1.0, compliance=1e-4)
    return b.build()


MODELS = {"cloth": cloth, "tet_block": tet_block, "every_type": every_type}


def thrown(model: csb.Model, seed: int = 3):
    """The rest state with random velocities (m/s) on the free particles: every constraint strained."""
    s = model.initial_state()
    free = (np.asarray(model.inv_mass) > 0)[:, None]
    s.v = np.random.default_rng(seed).normal(0, 0.5, s.v.shape) * free
    return s


def one_step(model, start, stepper):
    s = copy_state(model, start)
    stepper.step(model, s)
    return s


def test_the_test_models_hold_every_constraint_type():
    m = every_type()
    assert len(m.distance["particles"]) and len(m.bending["particles"]) and len(m.volume["particles"])
    assert len(m.balloons["rest_volume"]) == 1 and len(m.attachments["particle"]) == 1
    assert len(m.tethers["particles"]) > 0
    t = tet_block()
    assert len(t.volume["particles"]) == 12 and len(t.attachments["particle"]) == 1 and len(t.tethers["particles"])


@pytest.mark.parametrize("name", sorted(MODELS))
@pytest.mark.parametrize("initialization", ["adaptive", "inertia", "previous"])
def test_many_sweeps_reach_the_converged_backward_euler_step(name, initialization):
    """4000 sweeps (the soft bending of these models converges slowly: 0.015 N is left after 500
    on the cloth) against csb.BackwardEuler from the same thrown state. Near the solution x*,
    ∇E(x) ≈ ∇²E(x*)(x - x*), so |x - x*|₂ <= (|r(x)|₂ + |r(x*)|₂)/λ_min(∇²E(x*)) to first order (r the
    backward-Euler residual, ∇²E from csb.IncrementalPotential, positive definite at this
    solution); a factor 2 covers the second-order term. The residual itself must be far below the
    step's force scale: the sweeps converged."""
    model = MODELS[name]()
    start = thrown(model)
    ref = one_step(model, start, csb.BackwardEuler(dt=H))
    vbd = csb.VertexBlockDescent(dt=H, iterations=4000, initialization=initialization)
    got = one_step(model, start, vbd)
    r_vbd = csb.backward_euler_residual(model, start, got, H)
    r_ref = csb.backward_euler_residual(model, start, ref, H)
    assert r_vbd.max <= 1e-6 * r_vbd.scale
    hess = csb.IncrementalPotential(model, start, H).hessian(ref.x)
    lam = np.linalg.eigvalsh(hess).min()
    assert lam > 0
    bound = 2 * (r_vbd.norm + r_ref.norm) / lam
    assert np.linalg.norm(got.x - ref.x) <= bound
    free = np.asarray(model.inv_mass) > 0
    assert np.linalg.norm(got.v[free] - ref.v[free]) <= bound / H  # v = (x - xⁿ)/h, the same xⁿ


@pytest.mark.parametrize("name", sorted(MODELS))
def test_the_residual_falls_with_the_sweeps(name):
    """One step from the same thrown state with 1, 4, 16 and 64 sweeps: the backward-Euler residual
    (largest component, N) falls each time; the stepper's residual() is the same figure."""
    model = MODELS[name]()
    start = thrown(model)
    res = []
    for n in (1, 4, 16, 64):
        vbd = csb.VertexBlockDescent(dt=H, iterations=n)
        got = one_step(model, start, vbd)
        r = csb.backward_euler_residual(model, start, got, H)
        assert vbd.residual(model).max == r.max
        res.append(r.max)
    assert all(b < a for a, b in zip(res, res[1:])), res
    assert res[-1] < 0.1 * res[0]


def test_acceleration_lowers_the_residual_of_a_cloth_at_64_sweeps():
    """Chebyshev (ρ = 0.9) against plain sweeps, 64 each, one step of a 10 x 10 cloth from a thrown
    state: it must pay off there (the measured ratio is reported with the method)."""
    model = cloth(10, stretch=1e-6, bending=1e-3)
    start = thrown(model)
    plain = csb.backward_euler_residual(model, start, one_step(model, start, csb.VertexBlockDescent(dt=H, iterations=64)), H)
    fast = csb.backward_euler_residual(
        model, start, one_step(model, start, csb.VertexBlockDescent(dt=H, iterations=64, acceleration=0.9)), H)
    assert fast.max < plain.max


@pytest.mark.parametrize("name", ["cloth", "every_type"])
def test_bit_identical_across_runs_and_thread_counts(name):
    """Ten steps (two sub-steps each, with acceleration): the same bits from a fresh stepper, and on
    1, 2 and 3 threads and the automatic count (a colour's vertices write only themselves and read
    only other colours)."""
    model = cloth(12) if name == "cloth" else every_type()
    start = thrown(model)
    results = []
    for threads in (1, 1, 2, 3, 0):
        vbd = csb.VertexBlockDescent(dt=H, substeps=2, iterations=6, acceleration=0.5, threads=threads)
        s = copy_state(model, start)
        vbd.step(model, s, 10)
        assert vbd.threads_used == threads if threads else vbd.threads_used >= 1
        results.append(s)
    for s in results[1:]:
        assert np.array_equal(s.x, results[0].x) and np.array_equal(s.v, results[0].v)


def test_the_adaptive_guess_keeps_its_history_only_for_the_state_it_left():
    """Ten steps in one call or in ten calls are the same bits (the state each call gets is the one
    the last left, so the previous sub-step's acceleration is used). A fresh stepper given the
    state after five steps has no history and starts from x̃, as does the stepper itself when the
    state was changed meanwhile: the two agree, and differ from the continued run."""
    model = cloth(8)
    start = thrown(model)
    one, many = copy_state(model, start), copy_state(model, start)
    a, b = csb.VertexBlockDescent(dt=H, iterations=5), csb.VertexBlockDescent(dt=H, iterations=5)
    a.step(model, one, 10)
    for _ in range(10):
        b.step(model, many)
    assert np.array_equal(one.x, many.x) and np.array_equal(one.v, many.v)
    mid = copy_state(model, start)
    c = csb.VertexBlockDescent(dt=H, iterations=5)
    c.step(model, mid, 5)
    continued, fresh, touched = copy_state(model, mid), copy_state(model, mid), copy_state(model, mid)
    c.step(model, continued)
    csb.VertexBlockDescent(dt=H, iterations=5).step(model, fresh)
    d = csb.VertexBlockDescent(dt=H, iterations=5)
    d.step(model, copy_state(model, start), 5)
    d.step(model, touched)  # its own history was of another state object with the same bits: kept
    assert np.array_equal(touched.x, continued.x)
    changed = copy_state(model, mid)
    changed.v[3, 0] += 1e-12
    d2 = csb.VertexBlockDescent(dt=H, iterations=5)
    d2.step(model, copy_state(model, start), 5)
    d2.step(model, changed)
    fresh_changed = copy_state(model, mid)
    fresh_changed.v[3, 0] += 1e-12
    csb.VertexBlockDescent(dt=H, iterations=5).step(model, fresh_changed)
    assert np.array_equal(changed.x, fresh_changed.x)
    assert not np.array_equal(fresh.x, continued.x)


def test_make_integrator_is_the_class_and_lists_its_settings():
    info = csb.method_info("vbd")
    assert csb.method_info("vertex-block-descent").name == "vbd"
    assert info.label == "VBD" and info.reads == "compliance" and info.iterates
    assert [s.name for s in info.settings] == ["initialization", "acceleration", "threads", "contact_stiffness"]
    model = every_type()
    start = thrown(model)
    a = csb.make_integrator("vbd", H, substeps=2, iterations=7, initialization="inertia", acceleration=0.3, threads=1)
    b = csb.VertexBlockDescent(dt=H, substeps=2, iterations=7, initialization="inertia", acceleration=0.3, threads=1)
    assert a.name() == "vbd" and isinstance(a, csb.VertexBlockDescent)
    assert a.initialization == "inertia" and a.acceleration == 0.3 and a.iterations == 7
    sa, sb = copy_state(model, start), copy_state(model, start)
    a.step(model, sa, 5)
    b.step(model, sb, 5)
    assert np.array_equal(sa.x, sb.x) and np.array_equal(sa.v, sb.v)
    with pytest.raises(csb.ParameterError, match="method 'vbd' has no setting 'omega'.*'acceleration'"):
        csb.make_integrator("vbd", H, omega=1.0)


def test_bad_settings_are_named():
    with pytest.raises(csb.ParameterError, match="acceleration"):
        csb.VertexBlockDescent(acceleration=1.5)
    with pytest.raises(csb.ParameterError, match="acceleration"):
        csb.VertexBlockDescent(acceleration=1.0)
    with pytest.raises(csb.ParameterError, match="setting 'acceleration'"):
        csb.make_integrator("vbd", H, acceleration=1.5)
    with pytest.raises(csb.ParameterError, match="iterations"):
        csb.VertexBlockDescent(iterations=0)
    with pytest.raises(csb.ParameterError, match="iterations"):
        csb.make_integrator("vbd", H, iterations=0)
    with pytest.raises(csb.ParameterError, match="substeps"):
        csb.VertexBlockDescent(substeps=0)
    with pytest.raises(csb.ParameterError, match="dt"):
        csb.VertexBlockDescent(dt=0.0)
    with pytest.raises(csb.ParameterError, match="threads"):
        csb.VertexBlockDescent(threads=-1)
    with pytest.raises(csb.ParameterError, match="initialization"):
        csb.VertexBlockDescent(initialization="zero")
    with pytest.raises(csb.ParameterError, match="setting 'initialization'"):
        csb.make_integrator("vbd", H, initialization="zero")


def test_bad_models_and_states_are_named():
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1.0, 1.0, 3, 3), mass=0.1, stretch_compliance=0.0)
    hard = b.build()
    with pytest.raises(csb.ParameterError, match="distance constraint 0 is hard"):
        csb.VertexBlockDescent().step(hard, hard.initial_state())
    with pytest.raises(csb.ParameterError, match="contact_stiffness must be a finite stiffness > 0"):
        csb.VertexBlockDescent(contact_stiffness=-1.0)
    b = csb.ModelBuilder()
    sheet = b.add_mesh(csb.cloth_grid(1.0, 1.0, 3, 3), mass=0.1, stretch_compliance=1e-4)
    b.enable_self_collision(sheet.group, 0.01)
    folding = b.build()
    stepper = csb.VertexBlockDescent()  # self-collision is the layer after each sub-step's solve
    folded = folding.initial_state()
    stepper.step(folding, folded)
    assert stepper.self_collision["searches"] >= 1 and np.all(np.isfinite(folded.x))
    model = cloth(4)
    s = model.initial_state()
    s.x[5, 1] = np.nan
    with pytest.raises(csb.ParameterError, match="non-finite"):
        csb.VertexBlockDescent().step(model, s)
    s = model.initial_state()
    s.v[5] = [1e307, 0, 0]  # x̃ = x + h v: springs of 1.7e305 m, whose forces overflow
    with pytest.raises(csb.SimulationError, match=r"VBD: step 0: particle \d+ met a non-finite force"):
        csb.VertexBlockDescent().step(model, s)
    assert s.v[5, 0] == 1e307 and s.step == 0  # left at the start of the step
    other = cloth(5).initial_state()
    with pytest.raises(csb.ParameterError, match="particles"):
        csb.VertexBlockDescent().step(model, other)
    with pytest.raises(csb.ParameterError, match="has not stepped this model"):
        csb.VertexBlockDescent().residual(model)


def test_an_interrupt_leaves_the_state_at_the_end_of_a_step():
    model = cloth(4)
    s = model.initial_state()
    with pytest.raises(csb.Error, match="interrupted after 1 of 3 steps"):
        csb.VertexBlockDescent().step(model, s, 3, interrupt=lambda: True)
    ref = model.initial_state()
    csb.VertexBlockDescent().step(model, ref)
    assert s.step == 1 and np.array_equal(s.x, ref.x) and np.array_equal(s.v, ref.v)


def test_pinned_particles_stay_put_and_a_long_cloth_run_stays_bounded():
    """A 16 x 16 cloth (stretch 1e-6 m/N, bending 1e-3 1/(N m)) hanging from two corners, 600 steps
    of 1/60 s with one sub-step and 10 sweeps: the pins never move (exactly, zero velocity), every
    position stays finite and within twice the cloth's diagonal (√2 m) of the first pin, and no
    particle is faster than a free fall over that distance: the run is stable (not accurate: 10
    sweeps leave this stiff cloth stretched by up to 12 %, so the bound is not the diagonal)."""
    model = cloth(16, stretch=1e-6, bending=1e-3)
    s = model.initial_state()
    pinned = np.asarray(model.inv_mass) == 0
    x0 = np.array(s.x)
    vbd = csb.VertexBlockDescent(dt=H, iterations=10)
    for _ in range(60):
        vbd.step(model, s, 10)
        assert np.all(np.isfinite(s.x)) and np.all(np.isfinite(s.v))
        assert np.array_equal(s.x[pinned], x0[pinned]) and np.all(s.v[pinned] == 0)
        assert np.linalg.norm(s.x - x0[pinned][0], axis=1).max() <= 2 * np.sqrt(2)
        assert np.linalg.norm(s.v, axis=1).max() <= np.sqrt(2 * 9.81 * 2 * np.sqrt(2))
    assert s.step == 600 and s.t == pytest.approx(10.0)


# ------------------------------------------------------------------------------ contacts


def test_a_cloth_drapes_over_a_sphere_within_its_thickness():
    """A 12 x 12 cloth (1 cm thick) dropped on a sphere for 1 s, 10 sweeps a step: no particle goes
    past the sphere's surface plus the thickness by as much as the thickness (3.0 mm measured: the
    contacts are generated once per step from the prediction, and a particle its neighbours drag
    towards the sphere during the sweeps meets no contact), and threads 1 and 2 give the same
    bits."""
    model = cloth_over_sphere(12)
    ends = []
    for threads in (1, 2):
        s = model.initial_state()
        vbd = csb.make_integrator("vbd", 1 / 60, iterations=10, threads=threads)
        worst = 0.0
        for _ in range(60):
            vbd.step(model, s)
            worst = max(worst, 0.31 - np.min(np.linalg.norm(np.asarray(s.x) - [0, -0.4, 0], axis=1)))
        assert worst < 0.01, worst
        ends.append(np.array(s.x))
    assert np.array_equal(ends[0], ends[1])
