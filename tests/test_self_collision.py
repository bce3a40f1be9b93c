"""Cloth self-collision (Müller 2007 §4.4): point-triangle contacts from a spatial hash, each
keeping a particle on the side of a triangle it was on at the start of the sub-step. Checked with
an exact edge-triangle crossing test over every pair whose boxes overlap (a uniform grid finds them:
csb.studies.collisions.self_intersections)."""

from __future__ import annotations

import re

import numpy as np
import pytest

import csb
from csb.studies import collisions as cs


def fold(method: str, self_collision: float | None, steps: int = 90) -> list[int]:
    model, edges = cs.folded_cloth(self_collision=self_collision)
    triangles = np.asarray(model.triangles)
    state = model.initial_state()
    stepper = csb.PbdStepper(method=method, dt=1 / 60, substeps=4, iterations=10)
    counts = []
    for _ in range(steps):
        stepper.step(model, state)
        counts.append(cs.self_intersections(state.x, edges, triangles))
    return counts


def test_the_exact_crossing_test():
    a, b, c = np.array([[0.0, 0, 0]]), np.array([[1.0, 0, 0]]), np.array([[0.0, 1, 0]])
    through = cs.segments_cross_triangles(np.array([[0.2, 0.2, -1]]), np.array([[0.2, 0.2, 1]]), a, b, c)
    beside = cs.segments_cross_triangles(np.array([[0.8, 0.8, -1]]), np.array([[0.8, 0.8, 1]]), a, b, c)
    short = cs.segments_cross_triangles(np.array([[0.2, 0.2, 0.1]]), np.array([[0.2, 0.2, 1]]), a, b, c)
    assert through[0] and not beside[0] and not short[0]


def brute_force_pairs(x, edges, triangles):
    """Every (edge, triangle) pair with overlapping boxes and no shared vertex: the broad phase's
    answer by the definition, over all edges x triangles."""
    lo_e, hi_e = np.minimum(x[edges[:, 0]], x[edges[:, 1]]), np.maximum(x[edges[:, 0]], x[edges[:, 1]])
    tx = x[triangles]
    overlap = np.all((lo_e[:, None] <= tx.max(axis=1)[None]) & (hi_e[:, None] >= tx.min(axis=1)[None]), axis=2)
    for k in range(3):
        for j in range(2):
            overlap &= edges[:, j][:, None] != triangles[:, k][None, :]
    return np.nonzero(overlap)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_broad_phase_finds_every_pair_a_brute_force_finds(seed):
    """A 12 x 12 cloth crumpled by random displacements of up to 3 edge lengths (hundreds of
    crossings): the grid's candidate pairs are exactly the brute force's, and so are the counts."""
    rng = np.random.default_rng(seed)
    mesh = csb.cloth_grid(1.0, 1.0, 12, 12)
    x = np.asarray(mesh.vertices) + rng.uniform(-0.27, 0.27, (144, 3))
    triangles = np.asarray(mesh.triangles)
    edges = np.unique(np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]),
                              axis=1), axis=0)
    e, t = cs.candidate_pairs(x, edges, triangles)
    be, bt = brute_force_pairs(x, edges, triangles)
    assert np.array_equal(e, be) and np.array_equal(t, bt)
    hits = cs.segments_cross_triangles(x[edges[be, 0]], x[edges[be, 1]], x[triangles[bt, 0]], x[triangles[bt, 1]],
                                       x[triangles[bt, 2]]).sum()
    assert cs.self_intersections(x, edges, triangles) == hits > 100


@pytest.mark.parametrize("method", ["pbd", "xpbd", "jakobsen"])
def test_a_cloth_folded_over_itself_never_passes_through(method):
    """The top layer of a folded strip falls onto the bottom one, which has landed on the ground:
    no edge crosses a triangle at the end of any of 90 steps (1.5 s, the cloth is at rest)."""
    counts = fold(method, 0.008)
    assert max(counts) == 0


def test_without_self_collision_the_same_fold_passes_through():
    """The control: the scene does need self-collision (the top layer falls through the bottom)."""
    counts = fold("pbd", None, steps=40)
    assert max(counts) > 50


def test_a_flat_cloth_falling_freely_has_no_self_contacts():
    """Neighbouring triangles are not contacts: a flat cloth (thickness below its edge length)
    falls exactly as without self-collision."""
    def run(enable: bool):
        b = csb.ModelBuilder()
        inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, 10, 10), mass=0.2, bending_stiffness=0.3)
        if enable:
            b.enable_self_collision(inst.group, 0.02)
        model = b.build()
        state = model.initial_state()
        stepper = csb.PbdStepper(dt=1 / 60, substeps=2)
        stepper.step(model, state, 30)
        return state, stepper.contacts()["self_count"]

    (a, na), (b, nb) = run(True), run(False)
    assert na == nb == 0 and np.array_equal(a.x, b.x)


def test_self_collision_is_per_group_and_deterministic():
    model, _ = cs.folded_cloth(n=10)
    assert model.self_collision_thickness[0] == 0.008 and not model.self_collision_thickness.flags.writeable
    states = []
    for _ in range(2):
        s = model.initial_state()
        stepper = csb.PbdStepper(dt=1 / 60, substeps=4)
        stepper.step(model, s, 40)
        assert stepper.contacts()["self_count"] > 0
        states.append(np.array(s.x))
    assert states[0].tobytes() == states[1].tobytes()


def test_bad_self_collision_input():
    b = csb.ModelBuilder()
    with pytest.raises(csb.ParameterError, match="group 0 does not exist"):
        b.enable_self_collision(0, 0.01)
    inst = b.add_mesh(csb.cloth_grid(1.0, 1.0, 4, 4), mass=0.1)
    for h in (0.0, -1.0, float("nan")):
        with pytest.raises(csb.ParameterError, match=r"enable_self_collision: group 0 .*thickness must be"):
            b.enable_self_collision(inst.group, h)
    g = b.add_group("loose")
    b.add_particle([0, 1, 0], 1.0, g)
    with pytest.raises(csb.ParameterError, match="no triangles"):
        b.enable_self_collision(g, 0.01)



@pytest.fixture(scope="module", params=["coloured", "sequential"])
def drape(request, tmp_path_factory) -> tuple[list[float], int]:
    """The bundled cloth_sphere scene (30 x 30 XPBD cloth, 30 sub-steps of one iteration, the soft
    bending of a drapier cloth, compliance 1000 1/(N m)): its kinetic + gravitational energy per
    frame over the first 0.75 s (falling, hitting the sphere, the hem folding at frames 16-30), and
    the edge-triangle crossings at the end; with the coloured sweep (the default) and the
    sequential one (the constraints in the order they were built)."""
    text = csb.bundled_scenes()["cloth_sphere"].read_text()
    text = re.sub(r"bending = \{ compliance = [0-9.e+-]+ \}", "bending = { compliance = 1000.0 }", text)
    text = re.sub(r"\[solver\]", f'[solver]\nordering = "{request.param}"', text)
    path = tmp_path_factory.mktemp("drape") / "soft_sphere.toml"
    path.write_text(text)
    sim = csb.load_scene(path).build()
    assert sim.stepper.settings.ordering == request.param
    energy = []
    for _ in range(45):
        sim.stepper.step(sim.model, sim.state)
        m = sim.measure()
        energy.append(m["kinetic_energy"] + m["gravitational_energy"])
        if energy[-1] > 50 * energy[0]:
            break  # exploded: stop before the cloth fills the hash cells
    triangles = np.asarray(sim.model.triangles)
    edges = np.unique(np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    return energy, cs.self_intersections(sim.state.x, edges, triangles)


def test_a_soft_cloth_draping_over_a_sphere_does_not_explode(drape):
    """Self-contacts only take away approach. Before, a particle that started a sub-step closer
    than h to a triangle (around the hem's sharp creases) was pushed out to h within the sub-step,
    at up to h/Δt = 18 m/s, and a sliver whose normal flipped pushed it through by up to 2h: the
    energy went from 1.41 J to 1800 J by frame 32. Tolerance: the same drape without
    self-collision already peaks at 3.1 E0 (frame 29, the hem whipping off the sphere at 46 %
    strain under the collider contacts and one iteration of hard stretch, not a self-contact
    matter); with self-collision it peaks at 2.9 E0 in the sequential sweep (inelastic
    self-contacts; 4.4 E0 when a contact's push was left as velocity), so 6 E0 bounds it with some
    margin while an explosion passes 50 E0. The coloured sweep has no whip (its peak is
    E0). By 0.75 s the cloth has settled below its starting energy."""
    energy, _ = drape
    assert len(energy) == 45 and max(energy) < 6 * energy[0] and energy[-1] < energy[0]


def test_a_soft_cloth_draping_over_a_sphere_does_not_pass_through_itself(drape):
    """No edge crosses a triangle at the end, in either sweep. The sequential sweep (one iteration,
    the rows in build order) whips the hem at 60 % strain at frames 27-29; with proximity contacts
    alone about 50 edges passed through triangles there and stayed through (34 at frame 45). The
    continuous test after the sweeps (point-triangle and edge-edge, with its fail-safe) allows no
    new crossing in any sub-step, so the count is exactly 0, not a small number."""
    _, crossings = drape
    assert crossings == 0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_crossing_test_agrees_with_ipc_toolkit(seed):
    """csb's edge-triangle crossing test against an independent one, the IPC Toolkit's
    (Ferguson et al., `ipctk` from PyPI, in the test extra): on every candidate pair of a crumpled
    12 x 12 cloth (random positions: no touching or coplanar pair, where the two may differ by
    convention) the two agree pair by pair, and ipctk's own broad phase and test find the mesh
    self-intersecting exactly when csb's count is not 0 (the flat cloth: neither)."""
    ipctk = pytest.importorskip("ipctk", reason="the IPC Toolkit (pip install 'csb[test]') checks csb's crossing test")
    rng = np.random.default_rng(seed)
    mesh = csb.cloth_grid(1.0, 1.0, 12, 12)
    triangles = np.asarray(mesh.triangles)
    edges = np.unique(np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]),
                              axis=1), axis=0)
    flat = np.asarray(mesh.vertices, float)
    for x, crumpled in ((flat + rng.uniform(-0.27, 0.27, flat.shape), True), (flat, False)):
        e, t = cs.candidate_pairs(x, edges, triangles)
        ours = cs.segments_cross_triangles(x[edges[e, 0]], x[edges[e, 1]], x[triangles[t, 0]], x[triangles[t, 1]],
                                           x[triangles[t, 2]])
        theirs = np.array([ipctk.is_edge_intersecting_triangle(x[edges[i, 0]], x[edges[i, 1]], x[triangles[j, 0]],
                                                               x[triangles[j, 1]], x[triangles[j, 2]])
                           for i, j in zip(e, t)], bool)
        assert np.array_equal(ours, theirs)
        collision_mesh = ipctk.CollisionMesh(np.asfortranarray(x), edges.astype(np.int32), triangles.astype(np.int32))
        assert ipctk.has_intersections(collision_mesh, np.asfortranarray(x)) == (cs.self_intersections(x, edges, triangles) > 0) == crumpled
