"""csb.BackwardEuler, the same-step reference: backward Euler over every compliant constraint type,
each step's incremental potential E(x) = Σ m|x - x̃|²/(2h²) + Σ C²/(2α) minimised by Newton's
method; csb.IncrementalPotential (E, ∇E, ∇²E) and csb.backward_euler_residual, the residual
|∇E| of a step taken by any method."""

from __future__ import annotations

import numpy as np
import pytest

import csb
from csb.backward_euler import BackwardEulerStepper

G = np.array([0.0, -9.81, 0.0])


def every_type() -> csb.Model:
    """A 4 x 4 cloth (stretch springs, compliant bending, two corners pinned, a tether from every
    free particle to its nearest pin) and, below it, a box of 6 tets (edge springs, tet volumes, a
    balloon over its surface) held by an attachment: every constraint type csb has."""
    b = csb.ModelBuilder()
    cloth = b.add_mesh(csb.cloth_grid(1.0, 1.0, 4, 4), mass=0.2, stretch_compliance=1e-4, bending_stiffness=1.0,
                       bending_compliance=0.05)
    b.pin(cloth.first_particle)
    b.pin(cloth.first_particle + 3)
    tm = csb.tet_box([0.4, 0.4, 0.4], [1, 1, 1], center=[0, -1, 0])
    box = b.add_tet_mesh(tm, mass=1.0, stretch_compliance=1e-3, volume_compliance=1e-2)
    b.add_balloon(np.asarray(tm.surface()) + box.first_particle, pressure=1.2, compliance=1e-2)
    b.attach(box.first_particle, [0.0, -0.7, 0.0], compliance=1e-3)
    b.add_tethers(mode="euclidean", max_stretch=1.0, compliance=1e-4)
    return b.build()


def free_mask(model: csb.Model) -> np.ndarray:
    return (np.asarray(model.inv_mass) > 0)[:, None]


def chain(n: int = 10, *, link: float = 0.1, alpha: float = 1e-6) -> csb.Model:
    b = csb.ModelBuilder()
    g = b.add_group("chain")
    for i in range(n):
        b.add_particle([link * i, 0, 0], 0.1, g)
    for i in range(n - 1):
        b.add_distance(i, i + 1, compliance=alpha)
    b.pin(0)
    return b.build()


def spring_cloth(n: int = 8, alpha: float = 1e-4) -> csb.Model:
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, n, n), mass=0.2, stretch_compliance=alpha)
    b.pin(inst.first_particle)
    b.pin(inst.first_particle + n - 1)
    return b.build()


def copy_state(model: csb.Model, state) -> object:
    s = model.initial_state()
    s.x, s.v, s.t = np.array(state.x), np.array(state.v), state.t
    return s


def test_every_constraint_type_is_present_in_the_test_model():
    model = every_type()
    assert len(model.distance["particles"]) and len(model.bending["particles"]) and len(model.volume["particles"])
    assert len(model.balloons["rest_volume"]) == 1 and len(model.attachments["particle"]) == 1
    assert len(model.tethers["particles"]) > 0


@pytest.mark.parametrize("definite", [False, True])
def test_gradient_and_hessian_match_finite_differences_on_every_constraint_type(rng, definite):
    """∇E against central differences of E, ∇²E against central differences of ∇E (the exact
    Hessian), at a perturbed state where every constraint is violated (bending's curvature is
    itself a central difference of its analytic gradient). The Gauss-Newton form is symmetric and
    positive definite; it differs from the exact one only by curvature terms."""
    model = every_type()
    st = model.initial_state()
    st.v = rng.normal(0, 0.5, st.v.shape) * free_mask(model)
    h = 0.05
    P = csb.IncrementalPotential(model, st, h, gravity=G)
    x = np.array(st.x) + rng.normal(0, 0.02, st.x.shape) * free_mask(model)
    dyn = np.asarray(P.dynamic_particles)
    assert len(dyn) == model.num_particles - 2
    g = P.gradient(x)
    assert np.all(g[~free_mask(model)[:, 0]] == 0)
    eps = 1e-6
    gf = np.zeros_like(g)
    Hf = np.zeros((3 * len(dyn), 3 * len(dyn)))
    for s, i in enumerate(dyn):
        for k in range(3):
            xp, xm = x.copy(), x.copy()
            xp[i, k] += eps
            xm[i, k] -= eps
            gf[i, k] = (P.energy(xp) - P.energy(xm)) / (2 * eps)
            Hf[:, 3 * s + k] = ((P.gradient(xp) - P.gradient(xm)) / (2 * eps))[dyn].ravel()
    assert np.abs(gf - g).max() <= 1e-8 * np.abs(g).max()
    H = P.hessian(x, definite=definite)
    assert np.abs(H - H.T).max() <= 1e-12 * np.abs(H).max()
    mass_term = np.diag(np.repeat(np.asarray(model.mass)[dyn], 3)) / h**2
    if definite:
        assert np.linalg.eigvalsh(H).min() > 0
        assert np.abs(H - Hf).max() < 0.5 * np.abs(Hf - mass_term).max()  # curvature only
    else:
        assert np.abs(H - Hf).max() <= 1e-7 * np.abs(Hf - mass_term).max()


def test_bending_curvature_against_richardson_differences(rng):
    """Bending's Hessian (its curvature a central difference of the analytic gradient inside csb)
    against a fourth-order difference of ∇E, one bending constraint alone, 20 random shapes."""
    b = csb.ModelBuilder()
    g = b.add_group("hinge")
    for p in ([0, 0, 0], [1, 0, 0], [0.5, 0.8, 0.1], [0.5, -0.7, 0.3]):
        b.add_particle(p, 1.0, g)
    b.add_bending(0, 1, 2, 3, stiffness=1.0, rest_angle=0.3, compliance=0.01)
    model = b.build()
    st = model.initial_state()
    P = csb.IncrementalPotential(model, st, 1.0, gravity=(0, 0, 0))
    worst, eps = 0.0, 1e-4
    for _ in range(20):
        x = np.array(st.x) + rng.normal(0, 0.05, (4, 3))
        H = P.hessian(x) - np.eye(12)
        Hf = np.zeros((12, 12))
        for s in range(4):
            for k in range(3):
                d = []
                for step in (eps, 2 * eps):
                    xp, xm = x.copy(), x.copy()
                    xp[s, k] += step
                    xm[s, k] -= step
                    d.append((P.gradient(xp) - P.gradient(xm)).ravel() / (2 * step))
                Hf[:, 3 * s + k] = (4 * d[0] - d[1]) / 3
        Hf -= np.eye(12)
        worst = max(worst, np.abs(H - Hf).max() / np.abs(Hf).max())
    assert worst < 1e-8


def test_newton_converges_quadratically_on_a_chain():
    """A stiff chain falling from horizontal: once near the solution, the residual's exponent
    doubles each Newton step (r_{k+1} ≈ C r_k²) until it meets the rounding floor."""
    model = chain(12, alpha=1e-7)
    st = model.initial_state()
    be = csb.BackwardEuler(dt=0.01, gravity=G, rtol=1e-14)
    orders = []
    for _ in range(5):
        be.step(model, st)
        hist = np.asarray(be.history) / be.history[0]
        assert be.residual <= be.tolerance and be.newton_iterations >= 2
        above = hist[hist > 1e3 * be.tolerance / be.history[0]]
        orders += [np.log(above[k + 1]) / np.log(above[k]) for k in range(len(above) - 1) if above[k] < 1e-2]
    assert orders and max(orders) > 1.8, orders


def test_agrees_with_the_numpy_stepper_on_a_distance_only_cloth():
    """The numpy BackwardEulerStepper (banded Cholesky, the same stopping rule) and the C++ one
    (sparse LDLᵀ) solve the same steps: 50 steps of a cloth agree to round-off."""
    model = spring_cloth(8)
    s1, s2 = model.initial_state(), model.initial_state()
    BackwardEulerStepper(dt=0.01, gravity=G).step(model, s1, 50)
    cpp = csb.BackwardEuler(dt=0.01, gravity=G)
    cpp.step(model, s2, 50)
    assert np.abs(np.asarray(s1.x) - np.asarray(s2.x)).max() < 1e-12
    assert np.abs(np.asarray(s1.v) - np.asarray(s2.v)).max() < 1e-10
    assert s1.t == s2.t and s1.step == s2.step == 50


def total_energy(model: csb.Model, state, h: float) -> float:
    """Kinetic + gravitational + elastic (J); the elastic part is E(x) less its inertia term."""
    P = csb.IncrementalPotential(model, state, h, gravity=G)
    x = np.asarray(state.x)
    dyn = np.asarray(P.dynamic_particles)
    m = np.asarray(model.mass)
    inertia = np.sum(m[dyn, None] * (x[dyn] - P.inertial_positions) ** 2) / (2 * h * h)
    kinetic = 0.5 * np.sum(m[dyn, None] * np.asarray(state.v)[dyn] ** 2)
    return kinetic - np.sum(m[dyn] * (x[dyn] @ G)) + P.energy(x) - inertia


def test_backward_euler_dissipates_energy():
    """On a conservative scene (every constraint type, gravity, no damping) backward Euler's
    total energy never grows."""
    model = every_type()
    st = model.initial_state()
    h = 0.01
    be = csb.BackwardEuler(dt=h, gravity=G)
    energies = [total_energy(model, st, h)]
    for _ in range(60):
        be.step(model, st)
        energies.append(total_energy(model, st, h))
    e = np.array(energies)
    assert np.all(np.diff(e) <= 1e-9 * np.abs(e).max()), np.diff(e).max()
    assert e[-1] < e[0]


def test_residual_of_a_converged_step_is_zero_and_of_xpbd_falls_with_iterations():
    model = spring_cloth(8)
    h = 0.01
    be = csb.BackwardEuler(dt=h, gravity=G)
    st = model.initial_state()
    be.step(model, st, 20)
    prev = copy_state(model, st)
    nxt = copy_state(model, st)
    be.step(model, nxt)
    r = csb.backward_euler_residual(model, prev, nxt, h, G)
    assert r.max <= be.tolerance and r.max == pytest.approx(be.residual, rel=1e-9, abs=1e-12)
    assert r.norm == pytest.approx(be.residual_norm, rel=1e-9, abs=1e-12)
    assert r.max < 1e-8 * r.scale
    previous = np.inf
    for it in (1, 10, 100, 1000):
        nxt = copy_state(model, st)
        csb.PbdStepper(method="xpbd", dt=h, iterations=it).step(model, nxt)
        res = csb.backward_euler_residual(model, prev, nxt, h, G)
        assert res.max <= res.norm and res.norm < previous
        previous = res.norm
        if it == 1:
            assert res.max > 0.1 * res.scale  # far from the step: a tenth of the force scale or more


def test_the_registered_method():
    info = csb.method_info("backward-euler")
    assert info.reads == "compliance" and not info.iterates and info.aliases == []
    assert [k.name for k in info.settings] == ["rtol", "max_iterations", "contact_stiffness"]
    made = csb.make_integrator("backward-euler", 0.01, gravity=(0, -9.81, 0))
    assert isinstance(made, csb.BackwardEuler) and made.name() == "backward-euler" and made.dt() == 0.01
    model = every_type()
    s1, s2 = model.initial_state(), model.initial_state()
    csb.make_integrator("backward-euler", 0.02, substeps=2).step(model, s1, 3)
    csb.BackwardEuler(dt=0.01).step(model, s2, 6)
    assert np.array_equal(s1.x, s2.x) and np.array_equal(s1.v, s2.v)
    assert s1.step == 3 and s1.t == pytest.approx(0.06)


def test_bad_input_names_the_parameter():
    hard = csb.ModelBuilder()
    g = hard.add_group("g")
    hard.add_particle([0, 0, 0], 1.0, g)
    hard.add_particle([1, 0, 0], 1.0, g)
    hard.add_distance(0, 1)
    hard.pin(0)
    hard = hard.build()
    with pytest.raises(csb.ParameterError, match="distance constraint 0 is hard.*compliance"):
        csb.BackwardEuler(dt=0.01).step(hard, hard.initial_state())
    with pytest.raises(csb.ParameterError, match="distance constraint 0 is hard"):
        csb.backward_euler_residual(hard, hard.initial_state(), hard.initial_state(), 0.01)
    model = spring_cloth(4)
    st = model.initial_state()
    bad = model.initial_state()
    x = np.array(bad.x)
    x[3, 1] = np.nan
    bad.x = x
    with pytest.raises(csb.ParameterError, match="state"):
        csb.BackwardEuler(dt=0.01).step(model, bad)
    with pytest.raises(csb.ParameterError, match="previous state"):
        csb.backward_euler_residual(model, bad, st, 0.01)
    with pytest.raises(csb.ParameterError, match="next state"):
        csb.backward_euler_residual(model, st, bad, 0.01)
    for kwargs, name in [(dict(dt=0.0), "dt"), (dict(dt=np.nan), "dt"), (dict(rtol=-1.0), "rtol"),
                         (dict(max_iterations=0), "max_iterations"), (dict(substeps=0), "substeps"),
                         (dict(gravity=(0, 1)), "gravity")]:
        with pytest.raises(csb.ParameterError, match=name):
            csb.BackwardEuler(**kwargs)
    with pytest.raises(csb.ParameterError, match="dt"):
        csb.backward_euler_residual(model, st, st, -0.01)
    with pytest.raises(csb.ParameterError, match="x must have shape"):
        csb.IncrementalPotential(model, st, 0.01).energy(np.zeros((3, 3)))
    with_floor = csb.ModelBuilder()
    inst = with_floor.add_mesh(csb.cloth_grid(1.0, 1.0, 3, 3), mass=0.1, stretch_compliance=1e-4)
    with_floor.pin(inst.first_particle)
    with_floor.enable_self_collision(inst.group, 0.005)
    with_floor = with_floor.build()
    folded = with_floor.initial_state()  # self-collision is the layer after the solve
    stepper = csb.BackwardEuler(dt=0.01)
    stepper.step(with_floor, folded)
    assert stepper.self_collision["searches"] == 1 and np.all(np.isfinite(folded.x))
    with pytest.raises(csb.ParameterError, match="contact_stiffness must be a finite stiffness > 0"):
        csb.BackwardEuler(dt=0.01, contact_stiffness=0.0)
    with pytest.raises(csb.SimulationError, match="max_iterations|Newton's residual"):
        csb.BackwardEuler(dt=0.01, max_iterations=1, rtol=1e-15).step(spring_cloth(6), spring_cloth(6).initial_state())


def test_the_state_is_kept_when_a_step_fails():
    model = spring_cloth(6)
    st = model.initial_state()
    csb.BackwardEuler(dt=0.01).step(model, st, 2)
    x0, v0 = np.array(st.x), np.array(st.v)
    with pytest.raises(csb.SimulationError):
        csb.BackwardEuler(dt=0.01, substeps=2, max_iterations=1, rtol=1e-15).step(model, st)
    assert np.array_equal(st.x, x0) and np.array_equal(st.v, v0) and st.step == 2


def test_xpbd_chain_claim_against_the_same_step_reference():
    """XPBD's §6.2 chain (quick: 1 m links, 30 frames): against backward Euler's own trajectory,
    from frame 10 on, 6.4 %, 2.1 %, 0.38 % at 50, 100, 1000 iterations (the paper: 6 %, 2 %,
    0.5 %); against backward Euler solved from XPBD's own state at each frame, the solver error
    alone, 64 %, 44 %, 0.46 %: 50 and 100 sweeps leave a fifth of the force scale in the residual."""
    from csb.studies.same_step import xpbd_chain_same_step
    rows = {r["iterations"]: r for r in xpbd_chain_same_step(link=1.0, frames=30)}
    assert rows[50]["trajectory_error_from_frame_10"] == pytest.approx(0.064, abs=0.002)
    assert rows[100]["trajectory_error_from_frame_10"] == pytest.approx(0.021, abs=0.001)
    assert rows[1000]["trajectory_error_from_frame_10"] == pytest.approx(0.0038, abs=0.0002)
    assert rows[50]["same_step_error"] > 0.5 and rows[100]["same_step_error"] > 0.35
    assert rows[1000]["same_step_error"] < 0.006
    assert rows[50]["residual_relative_max"] > rows[100]["residual_relative_max"] > 10 * rows[1000]["residual_relative_max"]
    assert all(r["newton_residual_max_N"] < 1e-4 for r in rows.values())


def test_the_residual_study_writes_its_figure(tmp_path):
    import importlib.util
    from pathlib import Path
    path = Path(__file__).resolve().parents[1] / "validation" / "residual.py"
    spec = importlib.util.spec_from_file_location("residual_study", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.main(["--out", str(tmp_path), "--quick"])
    assert (tmp_path / "residual.png").stat().st_size > 10_000
    import csv
    with open(tmp_path / "residual.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    for scene in ("chain", "cloth"):
        gs = [float(r["residual_norm_N"]) for r in rows if r["scene"] == scene and r["solver"] == "gauss-seidel"]
        # Gauss-Seidel's residual falls with iterations: at the most it is below every fewer count's
        # (on the quick 12 x 12 cloth, each bending element projecting its edge just before itself,
        # it hardly moves over the first 10 iterations, 105 to 115 N, then falls: 64 N at 100).
        assert gs[-1] < min(gs[:-1])
        be = [float(r["residual_norm_N"]) for r in rows if r["scene"] == scene and r["method"] == "backward-euler"]
        assert be[0] < 1e-6 * gs[0]


def bending_cloth(n: int = 6) -> csb.Model:
    """A cloth flat in a plane, two corners pinned, with compliant bending: its Newton matrix's
    sparsity grows as it leaves the plane (entries that were exact zeros become non-zero)."""
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(0.5, 0.5, n, n), mass=0.1, stretch_compliance=1e-4, bending_stiffness=1.0,
                      bending_compliance=1.0)
    b.pin(inst.first_particle)
    b.pin(inst.first_particle + n - 1)
    return b.build()


def same_bits(a, b) -> bool:
    return np.array_equal(np.asarray(a.x), np.asarray(b.x)) and np.array_equal(np.asarray(a.v), np.asarray(b.v))


@pytest.mark.parametrize("substeps", [1, 2])
def test_a_stepper_kept_across_models_gives_the_bits_of_a_fresh_stepper_per_step(substeps):
    """A stepper keeps its Newton matrix's storage and the LDLᵀ's symbolic analyses between steps
    and models; a study's same-step metric builds a fresh stepper for every step. Both give the
    same bits: a stepper stepping model A, then B, then A again (and a model whose Hessian's
    sparsity changes, and the twisting cloth, whose Newton steps alternate between the exact and
    the Gauss-Newton matrix) against a fresh stepper for each step."""
    from csb.studies.literature import twisting_cloth
    twist, twist_start = twisting_cloth(n=6)
    models = {"every_type": (every_type(), None), "cloth": (bending_cloth(), None), "chain": (chain(), None),
              "twist": (twist, twist_start)}
    kept = csb.BackwardEuler(dt=1 / 60, gravity=G, substeps=substeps)
    states, fresh_states = {}, {}
    for name, (model, start) in models.items():
        states[name] = copy_state(model, start or model.initial_state())
        fresh_states[name] = copy_state(model, start or model.initial_state())
    fixes = 0
    for name in ["every_type", "cloth", "every_type", "chain", "twist", "cloth", "twist", "every_type"]:
        model = models[name][0]
        for _ in range(3):
            kept.step(model, states[name])
            fixes += kept.definiteness_fixes
            csb.BackwardEuler(dt=1 / 60, gravity=G, substeps=substeps).step(model, fresh_states[name])
            assert same_bits(states[name], fresh_states[name]), name
    assert fixes > 0 or substeps > 1  # the Gauss-Newton matrix was used too (counted for a step's last substep)
    assert not np.array_equal(np.asarray(states["cloth"].x), np.asarray(models["cloth"][0].initial_state().x))


def test_steppers_in_two_threads_share_a_model_and_one_stepper_is_refused_to_a_second_thread():
    """Two threads, each with its own stepper and State, step one Model in parallel and get the
    bits of one after the other. A stepper is used by one thread at a time: a second thread
    stepping it meanwhile gets csb.ConcurrentUseError."""
    import threading
    model = bending_cloth(10)
    alone = model.initial_state()
    csb.BackwardEuler(dt=1 / 60).step(model, alone, 20)
    states = [model.initial_state() for _ in range(2)]
    errors: list[Exception] = []

    def run(stepper, state, steps):
        try:
            stepper.step(model, state, steps)
        except Exception as e:  # noqa: BLE001 - reported below
            errors.append(e)

    threads = [threading.Thread(target=run, args=(csb.BackwardEuler(dt=1 / 60), s, 20)) for s in states]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert same_bits(states[0], alone) and same_bits(states[1], alone)

    shared = csb.BackwardEuler(dt=1 / 60)
    worker = threading.Thread(target=run, args=(shared, model.initial_state(), 400))
    worker.start()
    refused = []
    while worker.is_alive() and not refused:
        try:
            shared.step(model, model.initial_state(), 1)
        except csb.ConcurrentUseError as e:
            refused.append(str(e))
    worker.join()
    # Which of the two calls came second is the scheduler's choice: either is refused.
    messages = refused + [str(e) for e in errors]
    assert messages and all("in use by another thread" in m for m in messages)
    assert all(isinstance(e, csb.ConcurrentUseError) for e in errors)
