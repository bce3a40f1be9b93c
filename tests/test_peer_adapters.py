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
    assert any("triangles" in w for w in peer.unmappable(cloth(4)))
    with pytest.raises(csb.ParameterError, match="MuJoCo's flex cannot simulate this model: triangles"):
        peer.step(cloth(4), cloth(4).initial_state())
    # Explicit steps too long for these stiff springs: the peer diverges in its first step and the
    # check reports it, instead of comparing a state MuJoCo reset.
    c = conformance(peer, swinging_chain())
    assert not c.ok and "MuJoCo's flex diverged in step 1" in str(c)
    with pytest.raises(csb.ParameterError, match="integrator must be one of"):
        MujocoFlexIntegrator(1e-3, integrator="rk2")


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
