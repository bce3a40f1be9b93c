"""Tearing (Müller 2007 §4.6): an over-strained cloth edge splits a vertex and a crack opens."""

from __future__ import annotations

import numpy as np
import pytest

import csb


def grid(n=3, mass=0.9):
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1, 1, n, n), mass=mass, stretch_stiffness=1.0, bending_stiffness=0.5)
    return b.build()


def edges_of(triangles):
    return {tuple(sorted((t[a], t[b]))) for t in np.asarray(triangles) for a, b in ((0, 1), (1, 2), (2, 0))}


def test_a_strained_edge_splits_its_interior_vertex_along_the_crack():
    model = grid()
    state = model.initial_state()
    x = np.array(state.x)
    x[5] += [1.0, 0.0, 0.0]  # edge (4, 5): 0.5 m stretched to 1.5 m, 200 % strain
    state.x = x
    r = csb.tear(model, state, max_strain=0.5)
    assert r["torn"] == 1 and list(r["split"]) == [4]  # the interior end (6 triangles) splits, not 5 (2)
    torn, s2 = r["model"], r["state"]
    assert torn.num_particles == 10 and torn is not model
    # The given state is untouched; the new one has the new particle where 4 is, with its velocity.
    assert state.x.shape == (9, 3) and s2.x.shape == (10, 3)
    assert np.array_equal(s2.x[9], s2.x[4]) and np.array_equal(torn.rest_positions[9], model.rest_positions[4])
    # Mass is shared, not created: halves of the split particle's (exact in binary), the rest unchanged.
    assert torn.mass[4] == torn.mass[9] == model.mass[4] / 2 and torn.mass[4] + torn.mass[9] == model.mass[4]
    assert np.array_equal(np.delete(torn.mass, [4, 9]), np.delete(model.mass, 4))
    # The triangles on particle 5's side (centroid towards it) moved to the new particle.
    tris = np.asarray(torn.triangles)
    assert len(tris) == len(np.asarray(model.triangles))
    moved = [t for t in tris if 9 in t]
    centroid_x = [np.asarray(s2.x)[t].mean(axis=0)[0] for t in moved]
    assert len(moved) == 4 and min(centroid_x) > s2.x[4][0]
    assert not any(4 in t for t in moved)
    # Every distance constraint is still an edge of the surface; the crack's two edges exist twice
    # (one per side), so there are 2 more.
    pairs = {tuple(sorted(p)) for p in np.asarray(torn.distance["particles"])}
    assert pairs == edges_of(tris)
    assert len(torn.distance["rest_length"]) == len(model.distance["rest_length"]) + 2
    # Bending across the torn hinges is dropped; the rest follow their triangles.
    for q in np.asarray(torn.bending["particles"]):
        a, b, c, d = q
        assert {tuple(sorted((a, b, c))), tuple(sorted((a, b, d)))} <= {tuple(sorted(t)) for t in tris}
    assert len(torn.bending["rest_angle"]) < len(model.bending["rest_angle"])


def test_nothing_tears_below_the_threshold_and_the_same_objects_come_back():
    model = grid()
    state = model.initial_state()
    r = csb.tear(model, state, max_strain=0.01)
    assert r["torn"] == 0 and r["model"] is model and r["state"] is state


def test_a_cloth_pulled_apart_tears_and_its_halves_separate():
    """A strip pinned along its left edge, its right edge dragged away: with tearing after every
    step it tears through and the right part follows the hand while the left one stays; without
    tearing the same pull only stretches it."""
    def run(tearing: bool):
        b = csb.ModelBuilder()
        inst = b.add_mesh(csb.cloth_grid(1.0, 0.4, 11, 5, plane="xy"), mass=0.1, stretch_stiffness=1.0)
        left = [i for i in inst.particles if inst.vertices[i - inst.first_particle][0] < -0.49]
        right = [i for i in inst.particles if inst.vertices[i - inst.first_particle][0] > 0.49]
        for i in left:
            b.pin(i)
        model = b.build()
        state = model.initial_state()
        stepper = csb.PbdStepper(dt=1 / 60, substeps=4, iterations=5, gravity=(0, 0, 0))
        hands = [stepper.grab(model, state, i, state.x[i]) for i in right]
        tears = 0
        for k in range(1, 61):  # the hand moves 2 cm per step to the right: 1.2 m in 1 s
            for h, i in zip(hands, right):
                stepper.move_grab(h, model.rest_positions[i] + [0.02 * k, 0, 0])
            stepper.step(model, state)
            if tearing:
                r = csb.tear(model, state, max_strain=0.3, max_tears=5)
                tears += r["torn"]
                model, state = r["model"], r["state"]
        return model, state, tears

    model, state, tears = run(True)
    assert tears >= 5  # it tore through the 5 rows
    strain = np.abs(csb.distance_violations(model, state)) / np.asarray(model.distance["rest_length"])
    assert strain.max() < 0.3  # nothing is left over-stretched: the crack took it
    x = np.asarray(state.x)
    assert np.count_nonzero(x[:, 0] > 1.0) >= 5 and np.all(np.isfinite(x))  # the right part left with the hand
    untorn, ustate, _ = run(False)
    ustrain = np.abs(csb.distance_violations(untorn, ustate)) / np.asarray(untorn.distance["rest_length"])
    assert ustrain.max() > 1.0  # the same pull without tearing: stretched past 100 %
    # Deterministic.
    m2, s2, t2 = run(True)
    assert t2 == tears and np.array_equal(np.asarray(s2.x), x)


def test_tearing_errors():
    model = grid()
    state = model.initial_state()
    with pytest.raises(csb.ParameterError, match="max_strain must be a finite strain > 0"):
        csb.tear(model, state, max_strain=0)
    with pytest.raises(csb.ParameterError, match=r"tear: max_tears must be an integer in \[1, 2147483647\], got 0"):
        csb.tear(model, state, max_strain=0.1, max_tears=0)
    b = csb.ModelBuilder()
    b.add_tet_mesh(csb.tet_box([1, 1, 1], [1, 1, 1]), mass=1.0)
    solid = b.build()
    s = solid.initial_state()
    x = np.array(s.x)
    x[0] -= [2.0, 0, 0]
    s.x = x
    with pytest.raises(csb.ParameterError, match=r"particle \d+ belongs to a tetrahedron or a balloon"):
        csb.tear(solid, s, max_strain=0.5)


def test_a_scene_asks_for_tearing(tmp_path):
    result = csb.load_scene("cloth_tear").run(tmp_path)
    assert result.tears > 0 and "vertices torn" in result.summary()
    assert result.simulation.model.num_particles == 25 * 25 + result.tears
    # Frames follow the growing model (VTU); XDMF is off, and asking for it is an error.
    frames = sorted((tmp_path / "frames").glob("*.vtu"))
    import meshio

    assert len(meshio.read(frames[-1]).points) == 25 * 25 + result.tears
    assert not (tmp_path / "cloth_tear.xdmf").exists()
    text = (csb.bundled_scenes()["cloth_tear"]).read_text().replace("fps = 30 ", "fps = 30\nxdmf = true ")
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    with pytest.raises(csb.SceneError, match=r"output\.xdmf: an XDMF series cannot follow a model that tears"):
        csb.load_scene(bad)
