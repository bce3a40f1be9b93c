"""Continuous self-collision: the additive CCD kernel against an independent one (the IPC
Toolkit's Tight-Inclusion CCD, Wang et al. 2021), and a cloth that cannot pass through itself
even when one layer is thrown through the other within a sub-step."""

from __future__ import annotations

import numpy as np
import pytest

import csb
from csb.studies import collisions as cs


def _distance(kind: str, x: np.ndarray) -> float:
    """The pair's distance at x ((4, 3)), by dense sampling of the features (m)."""
    s = np.linspace(0, 1, 201)
    if kind == "edge-edge":
        a = x[0] + s[:, None] * (x[1] - x[0])
        b = x[2] + s[:, None] * (x[3] - x[2])
        return float(np.min(np.linalg.norm(a[:, None] - b[None], axis=2)))
    u, v = np.meshgrid(s, s)
    keep = u + v <= 1
    tri = x[1] + u[keep][:, None] * (x[2] - x[1]) + v[keep][:, None] * (x[3] - x[1])
    return float(np.min(np.linalg.norm(tri - x[0], axis=1)))


@pytest.mark.parametrize("kind", ["point-triangle", "edge-edge"])
def test_additive_ccd_never_misses_what_tight_inclusion_finds(kind):
    """400 random pairs, each moving so that its first feature ends beyond the second's far side
    (about half of them meet).
    Every pair the Tight-Inclusion CCD finds touching (its toi, with conservative rescaling off,
    within its tolerance 1e-6 of the first contact) is found by csb's additive CCD no later; and
    every impact csb reports is conservative: the pair is still at least s d(0) apart at the
    reported time (s = 0.1, to 1e-9 m of round-off). csb may report more: a pair whose distance
    falls below s d(0) without touching is an impact by definition."""
    ipctk = pytest.importorskip("ipctk", reason="the IPC Toolkit (pip install 'csb[test]') is the reference CCD")
    reference = ipctk.TightInclusionCCD(tolerance=1e-6, conservative_rescaling=1.0)
    rng = np.random.default_rng(7)
    theirs_hits = ours_hits = 0
    for _ in range(400):
        x0 = rng.uniform(-1, 1, (4, 3))
        dx = rng.uniform(-0.3, 0.3, (4, 3))
        if kind == "edge-edge":  # the first edge's middle to beyond the second's
            dx[:2] += 2 * (x0[2:].mean(axis=0) - x0[:2].mean(axis=0))
        else:  # the point to beyond the triangle's centroid
            dx[0] += 2 * (x0[1:].mean(axis=0) - x0[0])
        hit, toi = csb.kernels.additive_ccd(kind, x0, dx, 0.1)
        x1 = x0 + dx
        if kind == "edge-edge":
            ref_hit, ref_toi = reference.edge_edge_ccd(*x0, *x1)
        else:
            ref_hit, ref_toi = reference.point_triangle_ccd(*x0, *x1)
        theirs_hits += ref_hit
        ours_hits += hit
        if ref_hit:
            assert hit and toi <= ref_toi + 1e-6
        if hit:
            assert _distance(kind, x0 + toi * dx) >= 0.1 * _distance(kind, x0) - 1e-2 * 0.1 * _distance(kind, x0)
    assert 100 < theirs_hits <= ours_hits


def test_a_point_falling_onto_a_triangle():
    """The closed form: a point 1 m above a triangle moving 2 m down meets it at t = 1/2; the
    additive CCD stops where the distance is s d(0) = 0.1 m, t = 0.45, to its step rule's
    resolution (its last step is 0.9 of the distance left, so it lands within [0.45 - 0.05, 0.45])."""
    hit, toi = csb.kernels.additive_ccd("point-triangle", [[0.2, 1, 0.2], [0, 0, 0], [1, 0, 0], [0, 0, 1]],
                                        [[0, -2, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0]], 0.1)
    assert hit and 0.40 <= toi <= 0.45
    miss, _ = csb.kernels.additive_ccd("point-triangle", [[2, 1, 2], [0, 0, 0], [1, 0, 0], [0, 0, 1]],
                                       [[0, -2, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0]], 0.1)
    assert not miss
    with pytest.raises(csb.ParameterError, match="kind"):
        csb.kernels.additive_ccd("point-edge", np.zeros((4, 3)), np.zeros((4, 3)))


def two_sheets(speed: float, self_collision: bool, **material):
    """Two 8 x 8 squares of 0.3 m in one mesh (one self-colliding group), 5 cm apart: the lower one
    pinned at its corners, the upper one thrown down at it at `speed` m/s; `material` goes to
    add_mesh (compliances)."""
    sheet = csb.cloth_grid(0.3, 0.3, 8, 8)
    v = np.asarray(sheet.vertices, float)
    t = np.asarray(sheet.triangles)
    vertices = np.vstack([v, v + [0.01, 0.05, 0.013]])  # offset sideways too: no vertex meets a vertex
    triangles = np.vstack([t, t + len(v)])
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.Mesh(vertices, triangles, name="two sheets"), density=0.2, **material)
    corners = [i for i in range(len(v)) if abs(abs(v[i, 0]) - 0.15) < 1e-9 and abs(abs(v[i, 2]) - 0.15) < 1e-9]
    for i in corners:
        b.pin(inst.first_particle + i)
    if self_collision:
        b.enable_self_collision(inst.group, 0.004)
    model = b.build()
    state = model.initial_state()
    vel = np.array(state.v)
    vel[len(v):, 1] = -speed
    state.v = vel
    edges = np.unique(np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    return model, state, edges, triangles


def middle_height(state, *, upper: bool) -> float:
    """Mean height (m) of a sheet's particles over the middle of the lower sheet (|x|, |z| < 0.08 m)."""
    x = np.asarray(state.x)[64:] if upper else np.asarray(state.x)[:64]
    middle = (np.abs(x[:, 0]) < 0.08) & (np.abs(x[:, 2]) < 0.08)
    return float(x[middle, 1].mean())


@pytest.mark.parametrize("method", ["pbd", "xpbd", "jakobsen"])
def test_a_sheet_thrown_through_another_within_a_sub_step_stays_on_its_side(method):
    """At 30 m/s the upper sheet crosses the 5 cm gap in a fifth of a sub-step (1/120 s). The
    continuous test finds every pair that would meet, so no edge crosses a triangle at the end of
    any of 30 steps, the impacts are seen (continuous contacts made), and the thrown sheet ends on
    top. The control without self-collision passes straight through."""
    model, state, edges, triangles = two_sheets(30.0, True)
    stepper = csb.PbdStepper(method=method, dt=1 / 60, substeps=2, iterations=5)
    continuous = 0
    for _ in range(30):
        stepper.step(model, state)
        continuous += stepper.contacts()["self_continuous"] + stepper.contacts()["self_failsafe"]
        assert cs.self_intersections(np.asarray(state.x), edges, triangles) == 0
        assert np.all(np.isfinite(state.x))
    assert continuous > 0
    assert middle_height(state, upper=True) > middle_height(state, upper=False)  # still on top
    model, state, edges, triangles = two_sheets(30.0, False)
    stepper = csb.PbdStepper(method=method, dt=1 / 60, substeps=2, iterations=5)
    stepper.step(model, state, 30)
    assert middle_height(state, upper=True) < middle_height(state, upper=False) - 0.5  # went through


def test_continuous_self_collision_is_deterministic_on_any_thread_count():
    """The thrown sheet, 20 steps, on 1 and 2 threads and twice: bit-identical positions."""
    out = []
    for threads in (1, 2, 1):
        model, state, _, _ = two_sheets(30.0, True)
        csb.PbdStepper(method="xpbd", dt=1 / 60, substeps=2, iterations=5, threads=threads).step(model, state, 20)
        out.append(np.asarray(state.x).tobytes())
    assert out[0] == out[1] == out[2]


def test_the_threaded_self_collision_tests_give_the_same_bits():
    """The 1,600-particle cape of the benchmark (tens of thousands of candidate pairs: the tests
    run in chunks on the stepper's threads) after 20 steps: bit-identical on 1 and 2 threads."""
    from csb.bench import cape

    out = []
    for threads in (1, 2):
        model = cape()
        state = model.initial_state()
        stepper = csb.PbdStepper(method="xpbd", dt=1 / 60, substeps=2, iterations=5, threads=threads)
        stepper.step(model, state, 20)
        assert stepper.threads_used == threads
        out.append(np.asarray(state.x).tobytes())
    assert out[0] == out[1]


def soft_sheets(speed: float, self_collision: bool):
    """two_sheets with compliant stretch (1e-6 m/N) and bending (10 1/(N m)): the implicit methods
    model every constraint as a potential and need a compliance."""
    return two_sheets(speed, self_collision, stretch_compliance=1e-6, bending_compliance=10.0)


# backward Euler solved to convergence at 3 m/s: at 30 m/s the fail-safe's stops leave springs of
# 1e6 N/m strained beyond what Newton converges from in its 100 iterations (a SimulationError
# naming the step, as for any step it cannot converge).
@pytest.mark.parametrize("method,speed", [("implicit-euler", 30.0), ("projective-dynamics", 30.0), ("vbd", 30.0),
                                          ("backward-euler", 3.0)])
def test_the_implicit_methods_keep_a_thrown_sheet_from_passing_through(method, speed):
    """The implicit methods run self-collision as the layer after each sub-step's solve: the
    thrown sheet meets the other (continuous contacts made) and no edge crosses a triangle at the
    end of any of 30 steps; without self-collision the same throw passes through."""
    model, state, edges, triangles = soft_sheets(speed, True)
    stepper = csb.make_integrator(method, 1 / 60, substeps=2)
    continuous = 0
    for _ in range(30):
        stepper.step(model, state)
        continuous += stepper.self_collision["continuous"]
        assert cs.self_intersections(np.asarray(state.x), edges, triangles) == 0
        assert np.all(np.isfinite(state.x))
    assert continuous > 0
    model, state, _, _ = soft_sheets(speed, False)
    csb.make_integrator(method, 1 / 60, substeps=2).step(model, state, 30)
    assert middle_height(state, upper=True) < middle_height(state, upper=False) - 0.5  # went through


# VBD's adaptive initialisation reads the last step's acceleration (a history of its own); with
# the inertial one a VBD step depends on its state alone.
@pytest.mark.parametrize("method,options", [("implicit-euler", {}), ("projective-dynamics", {}),
                                            ("vbd", {"initialization": "inertia"})])
def test_an_implicit_step_with_self_collision_does_not_depend_on_the_steps_before(method, options):
    """The implicit methods' promise: a step's bits are those of a fresh stepper given the same
    state. The layer finds its candidate pairs afresh at each step's start, so it keeps it."""
    model, state, _, _ = soft_sheets(3.0, True)
    stepper = csb.make_integrator(method, 1 / 60, substeps=2, **options)
    stepper.step(model, state, 8)
    again = model.initial_state()
    again.x, again.v, again.t = np.array(state.x), np.array(state.v), state.t
    stepper.step(model, state)
    csb.make_integrator(method, 1 / 60, substeps=2, **options).step(model, again)
    assert np.asarray(state.x).tobytes() == np.asarray(again.x).tobytes()


def folded_strip(speed: float, self_collision: bool, *, companion: bool | None = None):
    """One connected strip, 0.15 m wide, folded into a U: a 0.4 m lower layer at y = 0, a bend of
    radius 2.5 cm, and a 0.4 m upper layer at y = 5 cm above it, the upper layer thrown down at
    `speed` m/s, the lower pinned at its four corners. The whole strip is one patch of the
    hierarchy's root, but not one whose normals share a side: its pairs across the fold are
    tested. With `companion`, a second cloth of more triangles (a 20 x 20 square of 0.6 m hanging
    from one edge, 2 m away), self-colliding in its own group if companion is True."""
    n_u, n_v, a, r, width = 48, 8, 0.4, 0.025, 0.15
    length = 2 * a + np.pi * r
    u = np.linspace(0.0, length, n_u + 1)
    v = np.linspace(0.0, width, n_v + 1)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    theta = np.clip((uu - a) / r, 0.0, np.pi)
    xs = np.where(uu < a, uu, np.where(uu <= a + np.pi * r, a + r * np.sin(theta), a - (uu - a - np.pi * r)))
    ys = np.where(uu < a, 0.0, r * (1 - np.cos(theta)))
    vertices = np.stack([xs, ys, vv], axis=-1).reshape(-1, 3) + [0.0, 0.0, 0.003]  # no vertex under a vertex
    vertices[(n_u + 1) // 2 * (n_v + 1):, 2] -= 0.006
    idx = np.arange((n_u + 1) * (n_v + 1)).reshape(n_u + 1, n_v + 1)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], axis=-1).reshape(-1, 4)
    triangles = np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    b = csb.ModelBuilder()
    inst = b.add_mesh(csb.Mesh(vertices, triangles, name="folded strip"), density=0.2)
    lower = np.where(uu.reshape(-1) < a)[0]
    for i in (idx[0, 0], idx[0, n_v]):
        b.pin(inst.first_particle + int(i))
    for i in lower[np.isclose(uu.reshape(-1)[lower], u[n_u // 2 - 8])]:
        b.pin(inst.first_particle + int(i))
    if self_collision:
        b.enable_self_collision(inst.group, 0.004)
    if companion is not None:
        square = csb.cloth_grid(0.6, 0.6, 20, 20)
        other = b.add_mesh(csb.Mesh(np.asarray(square.vertices) + [2.0, 0.0, 0.0], square.triangles, name="companion"),
                           density=0.2)
        for i in range(21):
            b.pin(other.first_particle + i)
        if companion:
            b.enable_self_collision(other.group, 0.004)
    model = b.build()
    state = model.initial_state()
    upper = np.where(uu.reshape(-1) > a + np.pi * r)[0]
    vel = np.array(state.v)
    vel[upper, 1] = -speed
    state.v = vel
    edges = np.unique(np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    return model, state, edges, triangles, lower, upper


def test_a_folded_strip_thrown_through_itself_stays_on_its_side():
    """The culling certifies patches whose motion cannot make them meet themselves; a connected
    strip folded into a U and thrown through itself at 30 m/s (a fifth of a sub-step to cross)
    is not such a patch. Its pairs across the fold are tested (impacts found), so no edge crosses
    a triangle at the end of any step; without self-collision the strip ends steps crossed."""
    model, state, edges, triangles, lower, upper = folded_strip(30.0, True)
    stepper = csb.PbdStepper(method="xpbd", dt=1 / 60, substeps=2, iterations=5)
    continuous = 0
    for _ in range(30):
        stepper.step(model, state)
        assert cs.self_intersections(np.asarray(state.x), edges, triangles) == 0
        assert np.all(np.isfinite(state.x))
        continuous += stepper.contacts()["self_continuous"] + stepper.contacts()["self_failsafe"]
    assert stepper.contacts()["self_tests"] > 0 and continuous > 0
    model, state, edges, triangles, _, _ = folded_strip(30.0, False)
    stepper = csb.PbdStepper(method="xpbd", dt=1 / 60, substeps=2, iterations=5)
    crossings = []
    for _ in range(30):
        stepper.step(model, state)
        crossings.append(cs.self_intersections(np.asarray(state.x), edges, triangles))
    assert max(crossings) > 0  # through itself


def test_one_groups_self_collision_does_not_depend_on_anothers():
    """Each self-colliding group keeps its own search boxes and hierarchy boxes: the folded strip
    thrown through itself (candidates searched, deferred and resumed, impacts) beside a larger
    cloth gives the same bits whether that cloth collides with itself too or not."""
    out = []
    for companion in (False, True):
        model, state, _, _, _, _ = folded_strip(30.0, True, companion=companion)
        stepper = csb.PbdStepper(method="xpbd", dt=1 / 60, substeps=2, iterations=5)
        impacts = 0
        for _ in range(20):
            stepper.step(model, state)
            impacts += stepper.contacts()["self_continuous"]
        assert impacts > 0
        out.append(np.asarray(state.x)[:441].tobytes())
    assert out[0] == out[1]


def test_a_smooth_swinging_cape_is_certified_and_its_pairs_culled():
    """A cape swinging on its bar stays a patch whose projection along its mean normal is one to
    one over each step's look-ahead and each sub-step: it is not searched inside and nothing is
    tested (the cape of the benchmark, 20 steps), while a strip folded onto itself has candidate
    pairs tested every sub-step."""
    from csb.bench import cape

    model = cape(20)
    state = model.initial_state()
    stepper = csb.PbdStepper(method="xpbd", dt=1 / 60, substeps=4, iterations=2)
    stepper.step(model, state, 20)
    c = stepper.contacts()
    assert c["self_searches"] >= 20 and c["self_candidates"] == 0 and c["self_tests"] == 0
    model, state, _, _, _, _ = folded_strip(0.0, True)
    stepper = csb.PbdStepper(method="xpbd", dt=1 / 60, substeps=4, iterations=2)
    stepper.step(model, state, 5)
    assert stepper.contacts()["self_candidates"] > 0 and stepper.contacts()["self_tests"] > 0


def test_a_cape_hanging_past_a_right_angle_keeps_few_pairs_and_never_crosses_itself():
    """The benchmark's 40 x 40 cape (XPBD, 10 x 1) hangs past 90 degrees after its fall, where
    no axis sees it whole: its root cannot be certified. Its nodes below are cut between rows of
    quads, so they can be; the unions of two nodes across a failed cut are certified too; and a
    particle's search box reaches at most four edges ahead. So the pairs it keeps stay a small
    part of its particles on every step (at most 0.13 a particle here; 19.8 with median cuts and
    neither of the others), and no edge crosses a triangle at any step's end."""
    from csb.bench import cape

    model = cape(40)
    triangles = np.asarray(model.triangles)
    edges = np.unique(np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    state = model.initial_state()
    stepper = csb.PbdStepper(method="xpbd", dt=1 / 60, substeps=10, iterations=1)
    most, folded = 0, 0
    for step in range(90):
        stepper.step(model, state)
        pairs = stepper.contacts()["self_candidates"]
        most, folded = max(most, pairs), folded + (pairs > 0)
        if step % 3 == 2:
            assert cs.self_intersections(np.asarray(state.x), edges, triangles) == 0
    assert folded > 0  # it does fold: some steps keep pairs
    assert most <= 0.5 * model.num_particles
    assert stepper.contacts()["self_unresolved"] == 0


def test_the_culling_gives_the_same_bits_with_the_sse2_avx2_and_avx512_copies():
    """The portable build runs the culling's passes in AVX2 lanes where the processor has them
    (the large nodes' particles projected across their axis and their triangles' 2D areas, each
    candidate pair's swept boxes), without fused multiply-adds: the same certifications and the
    same pairs, so the benchmark's 40 x 40 cape through its fold (90 steps; it keeps candidate
    pairs from the 76th) ends bit for bit the same with every copy."""
    from csb.bench import cape
    from helpers import copies_here

    isas = copies_here()
    if len(isas) < 2:
        pytest.skip(f"the kernels have one copy here ({isas[0]})")
    K = csb.kernels
    out = {}
    try:
        for isa in isas:
            assert K.kernel_isa(isa) == isa
            model = cape(40)
            state = model.initial_state()
            stepper = csb.PbdStepper(method="xpbd", dt=1 / 60, substeps=10, iterations=1)
            folded = 0
            for _ in range(90):
                stepper.step(model, state)
                folded += stepper.contacts()["self_candidates"] > 0
            assert folded > 0, isa
            out[isa] = np.asarray(state.x).tobytes() + np.asarray(state.v).tobytes()
    finally:
        K.kernel_isa("auto")
    assert len(set(out.values())) == 1, list(out)
