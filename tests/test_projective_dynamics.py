"""csb.ProjectiveDynamics: Projective Dynamics (Bouaziz et al. 2014) with Wang 2015's optional
Chebyshev acceleration. Each sub-step minimises backward Euler's incremental potential with every
constraint's potential made projective, by local projections and a global solve with a matrix
factored once per model and sub-step length."""

from __future__ import annotations

import numpy as np
import pytest

import csb

from helpers import cloth_over_sphere

DT = 1.0 / 60.0


def springs_and_attachments() -> csb.Model:
    """A 6 x 6 cloth of soft stretch springs, one corner pinned, the other held by an attachment
    away from where it rests, and two inequality springs (a slack rope <= and a compressed strut >=,
    which pushes): where PD's projective energy is exactly backward Euler's."""
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, 6, 6), mass=0.2, stretch_compliance=1e-2)
    f = inst.first_particle
    b.pin(f)
    b.attach(f + 5, [0.6, 0.1, 0.0], compliance=1e-3)
    b.add_distance(f + 30, f + 35, rest_length=1.2, sense="<=", compliance=1e-2)
    b.add_distance(f + 6, f + 35, rest_length=1.5, sense=">=", compliance=1e-2)
    return b.build()


def bending_volumes_tethers() -> csb.Model:
    """A 6 x 6 cloth with compliant bending and tethers (a constraint family) above a box of 48 tets
    (edge springs, tet volumes) held by an attachment."""
    b = csb.ModelBuilder()
    cloth = b.add_mesh(csb.cloth_grid(1.0, 1.0, 6, 6), mass=0.2, stretch_compliance=1e-3, bending_stiffness=1.0,
                       bending_compliance=0.05)
    b.pin(cloth.first_particle)
    b.pin(cloth.first_particle + 5)
    box = b.add_tet_mesh(csb.tet_box([0.4, 0.4, 0.4], [2, 2, 2], center=[0, -1, 0]), mass=1.0,
                         stretch_compliance=1e-3, volume_compliance=1e-2)
    b.attach(box.first_particle, [0.0, -0.7, 0.0], compliance=1e-3)
    b.add_tethers(mode="euclidean", max_stretch=1.0, compliance=1e-4)
    return b.build()


def every_type() -> csb.Model:
    """Every constraint type csb has: a 4 x 4 cloth (stretch springs, bending, tethers, two corners
    pinned) above a box of 6 tets (edge springs, tet volumes, a balloon over its surface at 1.2 times
    its rest volume) with one corner pinned and another held by an attachment."""
    b = csb.ModelBuilder()
    cloth = b.add_mesh(csb.cloth_grid(1.0, 1.0, 4, 4), mass=0.2, stretch_compliance=1e-4, bending_stiffness=1.0,
                       bending_compliance=0.05)
    b.pin(cloth.first_particle)
    b.pin(cloth.first_particle + 3)
    tm = csb.tet_box([0.4, 0.4, 0.4], [1, 1, 1], center=[0, -1, 0])
    box = b.add_tet_mesh(tm, mass=1.0, stretch_compliance=1e-3, volume_compliance=1e-2)
    b.add_balloon(np.asarray(tm.surface()) + box.first_particle, pressure=1.2, compliance=1e-2)
    b.pin(box.first_particle + 7)
    b.attach(box.first_particle, [0.0, -0.7, 0.0], compliance=1e-3)
    b.add_tethers(mode="euclidean", max_stretch=1.0, compliance=1e-4)
    return b.build()


def cloth(n: int, *, bending: bool = True, tethers: bool = False) -> csb.Model:
    b = csb.ModelBuilder()
    kw = dict(bending_stiffness=1.0, bending_compliance=1e-2) if bending else {}
    inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, n, n), mass=0.2, stretch_compliance=1e-5, **kw)
    b.pin(inst.first_particle)
    b.pin(inst.first_particle + n - 1)
    if tethers:
        b.add_tethers(mode="euclidean", max_stretch=1.0, compliance=1e-5)
    return b.build()


def copy_state(model: csb.Model, state) -> object:
    s = model.initial_state()
    s.x, s.v, s.t = np.array(state.x), np.array(state.v), state.t
    return s


def moving(model: csb.Model, steps: int = 5):
    """A state in motion: a few converged backward Euler steps from rest."""
    s = model.initial_state()
    csb.make_integrator("backward-euler", DT).step(model, s, steps)
    return s


def backward_euler_step(model: csb.Model, start):
    be = csb.BackwardEuler(dt=DT)
    s = copy_state(model, start)
    be.step(model, s)
    return s, be


def min_free_mass(model: csb.Model) -> float:
    return float(np.asarray(model.mass)[np.asarray(model.inv_mass) > 0].min())


def test_registered_with_its_settings():
    info = csb.method_info("pd")
    assert info.name == "projective-dynamics" and info.reads == "compliance" and info.iterates
    assert [s.name for s in info.settings] == ["chebyshev", "spectral_radius", "chebyshev_delay", "relaxation",
                                               "threads", "record_residuals"]


def test_springs_and_attachments_converge_to_backward_euler():
    """On distance springs (equalities and both inequalities) and attachments PD's energy is backward
    Euler's, so PD's fixed point is the converged backward-Euler step. Positions differ by the two
    solvers' residuals r (N) through E's Hessian H: |Δx| <= |r|/λ_min(H), and λ_min(H) >= m_min/h²
    where the springs' stiffness is positive semi-definite (taut); the factor 10 covers the
    compressed springs' negative geometric stiffness, which lowers λ_min."""
    model = springs_and_attachments()
    start = moving(model)
    ref, be = backward_euler_step(model, start)
    pd = csb.ProjectiveDynamics(dt=DT, iterations=2000, record_residuals=True)
    s = copy_state(model, start)
    pd.step(model, s)
    r = csb.backward_euler_residual(model, start, s, DT)
    assert pd.residual_history[-1] == pytest.approx(r.max, rel=1e-12)
    assert r.max < 1e-9 * r.scale  # converged as far as backward Euler's own stopping rule
    bound = 10 * (r.norm + np.sqrt(3 * model.num_particles) * be.tolerance) * DT**2 / min_free_mass(model)
    assert np.abs(np.asarray(s.x) - np.asarray(ref.x)).max() <= bound
    assert np.array_equal(np.asarray(s.v), (np.asarray(s.x) - np.asarray(start.x)) / DT)
    pinned = np.asarray(model.inv_mass) == 0
    assert np.array_equal(np.asarray(s.x)[pinned], np.asarray(start.x)[pinned])


@pytest.mark.parametrize("build", [bending_volumes_tethers, every_type])
def test_bending_volumes_balloons_and_families_reach_a_fixed_point_near_backward_euler(build):
    """With bending, tet volumes, balloons and tethers PD's energy is backward Euler's to first order only
    (w = |∇C(rest)|²/α, so (w/2) dist² = C²/(2α) |∇C(rest)|²/|∇C(x)|² + O(C³)): the residual in
    backward Euler's energy falls with the iterations to a floor, the force mismatch of the
    first-order materials, which is their forces times the relative change of |∇C| and of the
    projection's curvature over the step's deformation: well below 1 % of the step's force scale
    at these strains, but above backward Euler's own tolerance (the two steps are not the same).
    Positions then differ by at most that force over λ_min(H) >= m_min/h² (factor 10 as above). The
    balloon's global matrix is dense over its surface, applied through the Woodbury identity: a wrong
    solve would move the fixed point away from where backward Euler's gradient nearly vanishes."""
    model = build()
    start = moving(model)
    ref, be = backward_euler_step(model, start)
    pd = csb.ProjectiveDynamics(dt=DT, iterations=1000, chebyshev=True, spectral_radius=0.99, record_residuals=True)
    s = copy_state(model, start)
    pd.step(model, s)
    h = pd.residual_history
    assert len(h) == 1001
    assert h[1] < h[0] and h[10] < h[1] and h[100] < h[10]
    floor = h[-1]
    assert abs(h[-2] - floor) <= 1e-6 * floor  # a fixed point
    r = csb.backward_euler_residual(model, start, s, DT)
    assert be.tolerance < floor < 1e-2 * r.scale
    bound = 10 * r.norm * DT**2 / min_free_mass(model)
    assert np.abs(np.asarray(s.x) - np.asarray(ref.x)).max() <= bound


def test_factorises_once_per_model_and_substep_length():
    model, other = cloth(8), cloth(6)
    pd = csb.ProjectiveDynamics(dt=DT, iterations=5)
    s = model.initial_state()
    pd.step(model, s, 20)
    assert pd.factorizations == 1 and pd.factorization_time > 0
    pd.step(model, s, 5)
    assert pd.factorizations == 1
    pd.step(other, other.initial_state(), 3)
    assert pd.factorizations == 2
    # a new dt (another stepper: dt is a stepper's setting) factors for its own sub-step once
    pd2 = csb.ProjectiveDynamics(dt=DT / 2, substeps=2, iterations=5)
    pd2.step(model, model.initial_state(), 10)
    assert pd2.factorizations == 1


def test_substeps_are_steps_of_the_substep_length():
    """A step of dt in 2 sub-steps is 2 steps of dt/2, to the bit (the same h, x̃ and iterations)."""
    model = cloth(8)
    a, b = model.initial_state(), model.initial_state()
    csb.ProjectiveDynamics(dt=DT, substeps=2, iterations=6, chebyshev=True, chebyshev_delay=2).step(model, a, 3)
    csb.ProjectiveDynamics(dt=DT / 2, iterations=6, chebyshev=True, chebyshev_delay=2).step(model, b, 6)
    assert np.asarray(a.x).tobytes() == np.asarray(b.x).tobytes()
    assert np.asarray(a.v).tobytes() == np.asarray(b.v).tobytes()


def test_chebyshev_lowers_the_residual_at_equal_iterations():
    """Wang 2015: at 50 iterations on a moving cloth (stretch and bending) the accelerated iteration,
    its spectral radius measured from its first 10 iterations, leaves a lower residual."""
    model = cloth(16)
    start = moving(model)
    out = {}
    for cheb in (False, True):
        pd = csb.ProjectiveDynamics(dt=DT, iterations=50, chebyshev=cheb, record_residuals=True)
        pd.step(model, copy_state(model, start))
        out[cheb] = pd.residual_history[-1]
        if cheb:
            assert 0 < pd.spectral_radius_used < 1
    assert out[True] < out[False]


@pytest.mark.parametrize("chebyshev", [False, True])
@pytest.mark.parametrize("build", [lambda: cloth(32, tethers=True), every_type])
def test_bit_identical_across_runs_and_thread_counts(build, chebyshev):
    model = build()
    results = []
    for threads in (1, 2, 2, 3):
        pd = csb.ProjectiveDynamics(dt=DT, iterations=8, chebyshev=chebyshev, chebyshev_delay=3, threads=threads)
        s = model.initial_state()
        pd.step(model, s, 3)
        assert pd.threads_used == threads
        results.append((np.asarray(s.x).tobytes(), np.asarray(s.v).tobytes()))
    assert all(r == results[0] for r in results)


def test_make_integrator_is_the_class():
    model = cloth(6)
    a = csb.make_integrator("projective-dynamics", DT, substeps=2, iterations=7, chebyshev=True,
                            spectral_radius=0.95, chebyshev_delay=3, relaxation=0.8, record_residuals=True)
    b = csb.ProjectiveDynamics(dt=DT, substeps=2, iterations=7, chebyshev=True, spectral_radius=0.95,
                               chebyshev_delay=3, relaxation=0.8, record_residuals=True)
    assert isinstance(a, csb.ProjectiveDynamics) and isinstance(a, csb.Integrator)
    sa, sb = model.initial_state(), model.initial_state()
    a.step(model, sa, 4)
    b.step(model, sb, 4)
    assert np.asarray(sa.x).tobytes() == np.asarray(sb.x).tobytes()
    assert a.residual_history == b.residual_history and len(a.residual_history) == 8


def test_unknown_setting_is_named():
    with pytest.raises(csb.ParameterError, match="'chebychev'"):
        csb.make_integrator("pd", DT, chebychev=True)


@pytest.mark.parametrize("kwargs, message", [
    (dict(spectral_radius=1.2), "spectral_radius"),
    (dict(spectral_radius=-0.1), "spectral_radius"),
    (dict(relaxation=0.0), "relaxation"),
    (dict(dt=0.0), "dt"),
    (dict(chebyshev=True, chebyshev_delay=1), "chebyshev_delay"),
])
def test_bad_settings_are_named(kwargs, message):
    with pytest.raises(csb.ParameterError, match=message):
        csb.ProjectiveDynamics(**kwargs)
    with pytest.raises(csb.ParameterError, match=message):
        dt = kwargs.pop("dt", DT)
        csb.make_integrator("projective-dynamics", dt, **kwargs)


def test_models_it_cannot_step_are_named():
    pd = csb.ProjectiveDynamics(dt=DT)
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, 4, 4), mass=0.2)  # hard stretch
    b.pin(inst.first_particle)
    hard = b.build()
    with pytest.raises(csb.ParameterError, match="distance constraint 0 is hard"):
        pd.step(hard, hard.initial_state())
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, 4, 4), mass=0.2, stretch_compliance=1e-4)
    b.enable_self_collision(inst.group, 0.005)
    folding = b.build()
    folded = folding.initial_state()  # self-collision is the layer after each sub-step's solve
    pd.step(folding, folded)
    assert pd.self_collision["searches"] >= 1 and np.all(np.isfinite(folded.x))
    b = csb.ModelBuilder()
    tm = csb.tet_box([0.4, 0.4, 0.4], [1, 1, 1])
    box = b.add_tet_mesh(tm, mass=1.0, stretch_compliance=1e-3, volume_compliance=1e-2)
    b.add_balloon(np.asarray(tm.surface()) + box.first_particle, pressure=1.2)  # hard
    balloon = b.build()
    with pytest.raises(csb.ParameterError, match="balloon constraint 0 is hard"):
        pd.step(balloon, balloon.initial_state())


def test_bad_states_are_named():
    model = cloth(4)
    pd = csb.ProjectiveDynamics(dt=DT)
    s = model.initial_state()
    x = np.array(s.x)
    x[3, 1] = np.nan
    s.x = x
    with pytest.raises(csb.ParameterError, match="non-finite"):
        pd.step(model, s)
    with pytest.raises(csb.ParameterError, match="particles"):
        pd.step(model, cloth(5).initial_state())


def test_a_diverging_step_is_a_simulation_error_naming_the_step():
    """Gravity of 1e308 m/s² over a 10 s step overflows x̃ = x + h v + h² g: the first iteration's
    positions are not finite; the state stays where the step started."""
    model = cloth(4, bending=False)
    pd = csb.ProjectiveDynamics(dt=10.0, gravity=(0, -1e308, 0))
    s = model.initial_state()
    before = np.array(s.x)
    with pytest.raises(csb.SimulationError, match="step 0"):
        pd.step(model, s)
    assert np.array_equal(np.asarray(s.x), before) and s.step == 0


# ------------------------------------------------------------------------------ contacts


def test_a_cloth_on_a_sphere_ends_every_step_outside_it():
    """A 12 x 12 cloth (1 cm thick) dropped on a sphere for 1 s, 10 iterations a step: no particle
    ends a step inside the sphere plus the thickness (the projection is exact; 1e-12 m covers the
    rounding of the normal's components), threads 1 and 2 give the same bits."""
    model = cloth_over_sphere(12)
    ends = []
    for threads in (1, 2):
        s = model.initial_state()
        pd = csb.make_integrator("projective-dynamics", 1 / 60, iterations=10, threads=threads)
        for _ in range(60):
            pd.step(model, s)
            assert np.min(np.linalg.norm(np.asarray(s.x) - [0, -0.4, 0], axis=1)) > 0.31 - 1e-12
        ends.append(np.array(s.x))
    assert np.array_equal(ends[0], ends[1])
