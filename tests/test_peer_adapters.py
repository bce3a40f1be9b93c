"""The peers as csb methods (csb.bench.adapters): an adapter maps a csb Model onto the peer or says
what it cannot map, and the conformance check passes a faithful mapping and fails a wrong one.
The peers are the optional 'bench' extra: without pypbd these tests skip (and the missing-peer
message is tested by hiding it)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import csb
from csb.bench import adapters
from csb.bench.adapters import MujocoFlexIntegrator, PypbdIntegrator, conformance


def cloth(n: int) -> csb.Model:
    scene = csb.load_scene("cloth_grid")
    mesh = scene.meshes[0]
    mesh = dataclasses.replace(mesh, shape_args={**mesh.shape_args, "resolution": (n, n)})
    return dataclasses.replace(scene, meshes=(mesh,)).build().model


def test_a_missing_peer_names_the_extra(monkeypatch):
    monkeypatch.setattr(adapters.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(ImportError, match=r"'pypbd' is not installed: .* optional 'bench' extra"):
        PypbdIntegrator(1 / 60)


needs_pypbd = pytest.mark.skipif(adapters.importlib.util.find_spec("pypbd") is None,
                                 reason="pypbd (csb's optional 'bench' extra) is not installed")


@needs_pypbd
@pytest.mark.parametrize("substeps, iterations", [(1, 10), (10, 1), (4, 4)])
def test_pypbd_conforms_on_the_bundled_cloth(substeps, iterations):
    model = cloth(16)
    c = conformance(PypbdIntegrator(1 / 60, substeps=substeps, iterations=iterations), model)
    assert c.ok, str(c)
    assert c.figures["first_step_gap_m"] < 0.02 * c.figures["fall_m"]


@needs_pypbd
def test_pypbd_says_what_it_cannot_map():
    peer = PypbdIntegrator(1 / 60)
    soft = csb.load_scene("soft_cube_drop").build().model
    why = peer.unmappable(soft)
    assert any("volume constraints" in w for w in why) and any("colliders" in w for w in why)
    c = conformance(peer, soft)
    assert not c.ok and "cannot map" in str(c)
    with pytest.raises(csb.ParameterError, match="pypbd cannot simulate this model: .*volume constraints"):
        peer.step(soft, soft.initial_state())
    chain = csb.load_scene("chain").build().model
    assert any("no triangles" in w for w in peer.unmappable(chain))
    draped = csb.load_scene("cloth_sphere").build().model
    assert "self-collision" in peer.unmappable(draped) and "colliders" in peer.unmappable(draped)


@needs_pypbd
def test_a_wrong_mapping_does_not_conform():
    class Unpinned(PypbdIntegrator):
        """Gives the pinned particles a mass: the cloth falls away from its pins."""

        def _build(self, model):
            super()._build(model)
            for i in self.pinned:
                self._pd.setMass(i, 0.01)
            self.pinned = []

    c = conformance(Unpinned(1 / 60), cloth(8))
    assert not c.ok
    assert any(f.startswith("pins:") for f in c.failures)
    assert any("differs from csb's" in f for f in c.failures)


@needs_pypbd
def test_pypbd_steps_a_scene_through_the_runner(tmp_path):
    scene = csb.load_scene("cloth_grid")
    result = scene.run(None, stepper=PypbdIntegrator(1 / 60, iterations=10))
    assert result.stepper_given and np.all(np.isfinite(result.simulation.state.x))
    assert "pypbd" in result.summary()
    # The same method at the same iterations, hanging from its two pins: its largest strain within
    # half again of csb's (715 % against 676 %; PBD at 10 iterations stretches this cloth a lot).
    ours = csb.load_scene("cloth_grid").run(None).largest_strain
    assert 0.5 * ours < result.largest_strain < 1.5 * ours


def test_bad_settings_are_named():
    if adapters.importlib.util.find_spec("pypbd") is None:
        pytest.skip("pypbd (csb's optional 'bench' extra) is not installed")
    with pytest.raises(csb.ParameterError, match="dt must be"):
        PypbdIntegrator(0.0)
    with pytest.raises(csb.ParameterError, match="iterations must be"):
        PypbdIntegrator(1 / 60, iterations=0)
    with pytest.raises(csb.ParameterError, match="gravity"):
        PypbdIntegrator(1 / 60, gravity=(0, -1.62, 0))


needs_mujoco = pytest.mark.skipif(adapters.importlib.util.find_spec("mujoco") is None,
                                  reason="mujoco (csb's optional 'bench' extra) is not installed")


@needs_mujoco
@pytest.mark.parametrize("integrator", ["Euler", "implicitfast"])
def test_mujoco_flex_conforms_on_the_chain(integrator):
    from csb.studies import swinging_chain

    c = conformance(MujocoFlexIntegrator(1e-4, integrator=integrator), swinging_chain())
    assert c.ok, str(c)


@needs_mujoco
def test_mujoco_euler_is_csbs_symplectic_euler_to_round_off():
    """The same force-based method on the same springs: MuJoCo's semi-implicit Euler on a flex
    of stiffness 1/α and csb's symplectic Euler agree over 2000 steps to a few ulps of the
    positions (1.2e-15 m here; the forces are summed in another order)."""
    from csb.studies import swinging_chain

    model = swinging_chain()
    a, b = model.initial_state(), model.initial_state()
    MujocoFlexIntegrator(1e-5).step(model, a, 2000)
    csb.ForceStepper(method="symplectic-euler", dt=1e-5).step(model, b, 2000)
    assert np.max(np.abs(np.asarray(a.x) - np.asarray(b.x))) < 1e-13
    assert a.t == b.t and a.step == b.step == 2000


@needs_mujoco
def test_mujoco_flex_says_what_it_cannot_map_and_when_it_diverges(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    from csb.studies import swinging_chain

    peer = MujocoFlexIntegrator(1e-3, substeps=10)
    assert "hard distance constraints" in " ".join(peer.unmappable(cloth(4)))  # the bundled cloth is PBD's
    with pytest.raises(csb.ParameterError, match="MuJoCo's flex cannot simulate this model: hard distance"):
        peer.step(cloth(4), cloth(4).initial_state())
    # Explicit steps too long for these stiff springs: the peer diverges in its first step and the
    # check reports it, instead of comparing a state MuJoCo reset.
    c = conformance(peer, swinging_chain())
    assert not c.ok and "MuJoCo's flex diverged in step 1" in str(c)
    with pytest.raises(csb.ParameterError, match="integrator must be one of"):
        MujocoFlexIntegrator(1e-3, integrator="rk2")


@needs_mujoco
def test_mujoco_flex_conforms_on_the_hanging_cloth_and_follows_csb():
    """A cloth: its springs a 1-D flex, each bending hinge a 2-D flex of stiffness 1/α. MuJoCo's
    hinge bending is quadratic about the flat rest state, csb's θ²/(2α) is not, so the two agree
    to the fold's second order: 1e-7 m after 2000 steps of 1e-5 s (2.2 mm of fall)."""
    from csb.studies.study.schema import hanging_cloth

    model = hanging_cloth(n=6)
    peer = MujocoFlexIntegrator(1e-5)
    assert peer.unmappable(model) == []
    c = conformance(peer, model)
    assert c.ok, str(c)
    assert peer.counts["bending"] == len(np.asarray(model.bending["rest_angle"])) == 65
    a, b = model.initial_state(), model.initial_state()
    peer.step(model, a, 2000)
    csb.ForceStepper(method="symplectic-euler", dt=1e-5).step(model, b, 2000)
    x0 = np.asarray(model.rest_positions)
    assert np.max(np.abs(np.asarray(b.x) - x0)) > 2e-3
    assert np.max(np.abs(np.asarray(a.x) - np.asarray(b.x))) < 5e-7


@needs_mujoco
def test_mujoco_flex_maps_a_cloth_without_bending_exactly():
    """Without bending a cloth is a spring network: MuJoCo's Euler is csb's symplectic Euler to
    round-off, as on the chain."""
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.cloth_grid(0.5, 0.5, 5, 5), density=0.2, stretch_compliance=1e-4, bending_stiffness=None)
    b.pin(inst.first_particle)
    model = b.build()
    x, y = model.initial_state(), model.initial_state()
    MujocoFlexIntegrator(1e-5).step(model, x, 1000)
    csb.ForceStepper(method="symplectic-euler", dt=1e-5).step(model, y, 1000)
    assert np.max(np.abs(np.asarray(x.x) - np.asarray(y.x))) < 1e-13


@needs_mujoco
def test_a_diverging_mujoco_step_is_an_error_not_a_silent_reset(tmp_path, monkeypatch):
    from csb.studies import swinging_chain

    monkeypatch.chdir(tmp_path)
    model = swinging_chain()
    state = model.initial_state()
    with pytest.raises(csb.SimulationError, match="MuJoCo's flex diverged in step"):
        MujocoFlexIntegrator(1e-3).step(model, state, 100)  # stiff springs, explicit steps
    assert np.all(np.isfinite(state.x)) and 0 <= state.step < 100
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


# ---------------------------------------------------------------------------------------------
# NVIDIA Newton (newton on warp, device "cpu"). Newton's first use compiles its kernels for the
# CPU (about 17 s for SolverXPBD's, 7 s for SolverVBD's, 4 s for the model's and Style3D's, once
# per machine: Warp keeps them in its kernel cache); with the cache these tests take a few seconds.


@pytest.fixture(scope="module")
def newton_installed():
    pytest.importorskip("warp", reason="warp-lang (csb's optional 'bench' extra) is not installed")
    pytest.importorskip("newton", reason="newton (csb's optional 'bench' extra) is not installed")


NEWTON = [adapters.NewtonXpbdIntegrator, adapters.NewtonVbdIntegrator, adapters.NewtonStyle3dIntegrator]


def test_a_missing_newton_names_the_extra(monkeypatch):
    monkeypatch.setattr(adapters.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(ImportError, match=r"'newton' is not installed: .* optional 'bench' extra"):
        adapters.NewtonVbdIntegrator(1 / 60)


def hanging(n: int = 6) -> csb.Model:
    from csb.studies.study.schema import hanging_cloth

    return hanging_cloth(n=n)


def test_newton_xpbd_is_csbs_summed_jacobi_xpbd(newton_installed):
    """Newton's XPBD sums the corrections of a sweep (Jacobi): csb's XPBD with solver
    "jacobi-summed" is the same method, and on the chain the two agree to float32 over 60 steps."""
    from csb.studies import swinging_chain

    model = swinging_chain(links=5, compliance=1e-6)
    peer = adapters.NewtonXpbdIntegrator(1 / 120, iterations=10)
    c = conformance(peer, model)
    assert c.ok, str(c)
    assert c.figures["first_step_gap_m"] < 1e-3 * c.figures["fall_m"]
    a, b = model.initial_state(), model.initial_state()
    peer.step(model, a, 60)
    peer.counterpart().step(model, b, 60)
    assert np.max(np.abs(np.asarray(a.x) - np.asarray(b.x))) < 1e-6
    assert a.step == b.step == 60 and a.t == pytest.approx(0.5)


def test_newton_xpbd_on_a_stiff_cloth_is_reported_not_compared(newton_installed):
    """Summed Jacobi diverges on the hanging cloth (α = 1e-4 m/N) at 1/30 s, in csb as in Newton:
    the check says it cannot compare, instead of comparing two diverged states."""
    c = conformance(adapters.NewtonXpbdIntegrator(1 / 30), hanging())
    assert not c.ok and "cannot check the first step: csb's xpbd diverges in it" in str(c)


@pytest.mark.parametrize("cls", NEWTON[1:], ids=["vbd", "style3d"])
def test_newton_implicit_solvers_conform_on_the_hanging_cloth(newton_installed, cls):
    c = conformance(cls(1 / 120, iterations=10), hanging())
    assert c.ok, str(c)
    assert c.figures["first_step_gap_m"] < 0.05 * c.figures["fall_m"]


def test_newton_vbd_conforms_on_the_chain(newton_installed):
    from csb.studies import swinging_chain

    c = conformance(adapters.NewtonVbdIntegrator(1 / 120), swinging_chain(links=5, compliance=1e-6))
    assert c.ok, str(c)
    assert c.figures["first_step_gap_m"] < 1e-3 * c.figures["fall_m"]


@pytest.mark.parametrize("cls", NEWTON, ids=["xpbd", "vbd", "style3d"])
def test_newton_free_fall_is_the_closed_form(newton_installed, cls):
    """A free cloth (no pins) falls as one body: after k sub-steps of h from rest every particle
    has fallen g h² (1 + 2 + ... + k) (semi-implicit and backward Euler alike), to float32.
    Style3D scales the velocity by 0.998 each step, and the closed form takes that in."""
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(0.5, 0.5, 4, 4), density=0.2, stretch_compliance=1e-4, bending_stiffness=1.0,
               bending_compliance=1.0)
    model = b.build()
    state = model.initial_state()
    dt, substeps, steps = 1 / 60, 2, 30
    cls(dt, substeps=substeps).step(model, state, steps)
    h, keep = dt / substeps, 0.998 if cls is adapters.NewtonStyle3dIntegrator else 1.0
    y = v = 0.0
    for _ in range(steps * substeps):
        dy = h * (v - 9.81 * h)
        y, v = y + dy, keep * dy / h
    x = np.asarray(state.x)
    assert np.max(np.abs(x - (np.asarray(model.rest_positions) + [0.0, y, 0.0]))) < 1e-5
    assert np.max(np.abs(np.asarray(state.v) - [0.0, v, 0.0])) < 1e-4
    assert state.step == steps


@pytest.mark.parametrize("cls", NEWTON, ids=["xpbd", "vbd", "style3d"])
def test_newton_says_what_it_cannot_map(newton_installed, cls):
    peer = cls(1 / 60)
    soft = csb.load_scene("soft_cube_drop").build().model
    why = peer.unmappable(soft)
    assert any("volume constraints" in w for w in why) and "colliders" in why
    with pytest.raises(csb.ParameterError, match=rf"Newton's {cls.SOLVER} cannot simulate this model: .*volume"):
        peer.step(soft, soft.initial_state())
    draped = csb.load_scene("cloth_sphere").build().model
    assert "self-collision" in peer.unmappable(draped)
    b = csb.ModelBuilder()
    b.add_mesh(csb.chain(3, 0.1), density=0.1)  # compliance 0: hard
    b.pin(0)
    hard = b.build()
    assert any(w.startswith("hard distance constraints") for w in peer.unmappable(hard))
    assert not conformance(peer, hard).ok


def test_newton_style3d_needs_a_flat_cloth_of_triangles(newton_installed):
    from csb.studies import swinging_chain

    peer = adapters.NewtonStyle3dIntegrator(1 / 60)
    with pytest.raises(csb.ParameterError, match="SolverStyle3D cannot simulate this model: no triangles"):
        peer.step(swinging_chain(), swinging_chain().initial_state())
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(0.5, 0.5, 4, 4), density=0.2, stretch_compliance=1e-4, bending_stiffness=None)
    cloth = b.build()
    assert peer.unmappable(cloth) == []
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(0.5, 0.5, 4, 4), density=0.2, stretch_stiffness=None)
    bare = b.build()  # triangles without distance constraints
    assert any("triangle edges without a distance constraint" in w for w in peer.unmappable(bare))


def test_a_wrong_newton_mapping_does_not_conform(newton_installed):
    class Unpinned(adapters.NewtonVbdIntegrator):
        """Gives the pinned particles a mass: the cloth falls away from its pins."""

        def _particles(self, builder, model):
            x = np.asarray(model.rest_positions, dtype=float)
            builder.add_particles(x.tolist(), [(0.0, 0.0, 0.0)] * len(x), np.asarray(model.mass).tolist(),
                                  radius=[0.0] * len(x))

    c = conformance(Unpinned(1 / 120), hanging())
    assert not c.ok
    assert any(f.startswith("pins:") for f in c.failures)
    assert any("differs from csb's" in f for f in c.failures)


@pytest.mark.parametrize("cls", NEWTON, ids=["xpbd", "vbd", "style3d"])
def test_newton_bad_settings_are_named(newton_installed, cls):
    for dt in (0.0, -1.0, float("nan"), "0.01"):
        with pytest.raises(csb.ParameterError, match="dt must be"):
            cls(dt)
    for substeps in (0, 1.5, True):
        with pytest.raises(csb.ParameterError, match="substeps must be"):
            cls(1 / 60, substeps=substeps)
    with pytest.raises(csb.ParameterError, match="iterations must be"):
        cls(1 / 60, iterations=0)
    with pytest.raises(csb.ParameterError, match="gravity must be"):
        cls(1 / 60, gravity=(0.0, float("inf"), 0.0))


def curved_cloth() -> csb.Model:
    """A cloth bent into a parabola at rest: its hinges' rest angles are not 0 (up to 0.17 rad)."""
    flat = csb.cloth_grid(0.5, 0.5, 4, 4)
    v = np.array(flat.vertices)
    v[:, 1] = 0.5 * v[:, 0] ** 2
    b = csb.ModelBuilder()
    b.add_mesh(csb.Mesh(v, np.asarray(flat.triangles)), density=0.2, stretch_compliance=1e-4, bending_stiffness=1.0,
               bending_compliance=1.0)
    return b.build()


@needs_mujoco
def test_mujoco_flex_takes_flat_rest_states_only():
    with pytest.raises(csb.ParameterError, match="bending rest angles other than 0"):
        model = curved_cloth()
        MujocoFlexIntegrator(1e-5).step(model, model.initial_state())


def test_newton_style3d_takes_flat_rest_states_only(newton_installed):
    why = adapters.NewtonStyle3dIntegrator(1 / 60).unmappable(curved_cloth())
    assert any(w.startswith("a cloth not flat at rest") for w in why)
    assert any(w.startswith("bending rest angles other than 0") for w in why)


@needs_mujoco
def test_mujoco_flex_bending_needs_mujoco_4(monkeypatch):
    from csb.studies.study.schema import hanging_cloth

    monkeypatch.setattr(MujocoFlexIntegrator, "_mujoco_version", staticmethod(lambda: "3.3.7"))
    why = MujocoFlexIntegrator(1e-5).unmappable(hanging_cloth(n=4))
    assert any("needs MuJoCo 4.0 or later" in w for w in why)
