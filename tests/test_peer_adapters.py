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
from csb.bench.adapters import PypbdIntegrator, conformance


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
