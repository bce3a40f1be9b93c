"""Graph colouring of the constraint batches, the coloured sweep on several threads,
and the memory report. Timings are the benchmark's business (`csb bench`), never asserted here."""

from __future__ import annotations

import hashlib
import os
import re
import subprocess
import sys
import time

import numpy as np
import pytest

import csb
from csb import _core
from csb.scene import SceneError

EPS = np.finfo(float).eps


def mixed_model(n: int = 96, cells: int = 6, compliance: float = 0.0):
    """A cloth (stretch and shear edges, dihedral bending, two attachments) beside a tet box
    (edges and volumes), a balloon and a spring between opposite corners of the cloth:
    every batch, in eight parts whose interiors and interfaces two threads really share, and a constraint across parts that are not neighbours
    (the groups' rest, shared colour by colour)."""
    b = csb.ModelBuilder()
    cloth = b.add_mesh(csb.cloth_grid(1.0, 1.0, n, n), mass=0.5, bending_stiffness=0.5,
                       stretch_compliance=compliance, bending_compliance=compliance)
    for corner in (0, n - 1):
        b.attach(cloth.first_particle + corner, b.position(cloth.first_particle + corner), stiffness=0.9,
                 compliance=compliance)
    b.add_tet_mesh(csb.tet_box((0.4, 0.4, 0.4), (cells, cells, cells), center=(0, -1, 0)), mass=1.0,
                   stretch_compliance=compliance, volume_compliance=compliance)
    ball = b.add_mesh(_octahedron(), mass=0.2, stretch_compliance=compliance)
    b.add_balloon(ball.triangles, pressure=1.2, compliance=compliance)
    b.add_distance(cloth.first_particle, cloth.first_particle + n * n - 1, compliance=compliance)
    return b.build()


def _octahedron() -> csb.Mesh:
    v = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float) * 0.2 + [0, -2, 0]
    f = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    return csb.Mesh(v, f, name="ball")


def check_colouring(particles: np.ndarray, colouring: dict, min_size: int = _core.MIN_COLOUR_SIZE,
                    by_particles: bool = False) -> None:
    """Every constraint exactly once; within a colour (serial colours aside) no particle twice
    and the constraints in increasing order; at most one serial colour per group, its last, in
    increasing order or, by_particles (the model's distance batch), in the order of the
    constraints' particle tuples, then of their index."""
    order = np.asarray(colouring["order"])
    offsets = np.asarray(colouring["colour_offsets"])
    assert offsets[0] == 0 and offsets[-1] == len(particles) and np.all(np.diff(offsets) > 0)
    assert np.array_equal(np.sort(order), np.arange(len(particles)))
    colours = len(offsets) - 1
    for k in range(colours):
        members = order[offsets[k]:offsets[k + 1]]
        if colouring["serial"][k]:
            keys = [tuple(particles[c]) + (c,) for c in members] if by_particles else list(members)
            assert keys == sorted(keys)
            continue
        assert np.all(np.diff(members) > 0)
        used = particles[members].ravel()
        assert len(np.unique(used)) == len(used), f"colour {k} has constraints sharing a particle"
        assert len(members) >= min_size


def test_every_batch_is_coloured_validly():
    model = mixed_model()
    assert model.num_parts > 1  # colours of parts and interfaces may be as small as MIN_TASK_COLOUR_SIZE
    for batch, key in (("distance", "particles"), ("bending", "particles"), ("volume", "particles")):
        particles = np.asarray(getattr(model, batch)[key])
        c = model.colouring(batch)
        check_colouring(particles, c, _core.MIN_TASK_COLOUR_SIZE, by_particles=batch == "distance")
        assert len(c["colour_offsets"]) > 2  # really coloured, not one overflow colour
    check_colouring(np.asarray(model.attachments["particle"])[:, None], model.colouring("attachments"), 1)
    with pytest.raises(csb.ParameterError, match="batch must be"):
        model.colouring("balloons")


def _group_particles(model, g: int) -> np.ndarray:
    """The particles that group g's constraints touch, over every batch."""
    out = []
    for batch, key in (("distance", "particles"), ("bending", "particles"), ("volume", "particles"),
                       ("attachments", "particle")):
        particles = np.asarray(getattr(model, batch)[key]).reshape(len(np.asarray(getattr(model, batch)[key])), -1)
        c = model.colouring(batch)
        offsets, groups = np.asarray(c["colour_offsets"]), np.asarray(c["group_colours"])
        members = np.asarray(c["order"])[offsets[groups[g]]:offsets[groups[g + 1]]]
        out.append(particles[members].ravel())
    return np.unique(np.concatenate(out))


def test_the_groups_that_threads_sweep_at_once_share_no_particle():
    """The schedule of the threads (see Colouring): the parts' interiors share no particle, nor
    do the interfaces of one phase; every constraint is in exactly one group; the cloth's parts
    are thicker than its elements, so its interfaces make one phase and nothing is left over but
    the spring across the model."""
    model = mixed_model()
    parts = model.num_parts
    assert parts == 8
    interiors = [_group_particles(model, g) for g in range(parts)]
    for a in range(parts):
        for b in range(a + 1, parts):
            assert len(np.intersect1d(interiors[a], interiors[b])) == 0, (a, b)
    phases = model.interface_phases
    assert sorted(i for phase in phases for i in phase) == list(range(parts - 1)) and len(phases) == 1
    for phase in phases:
        touched = [_group_particles(model, parts + i) for i in phase]
        assert len(np.unique(np.concatenate(touched))) == sum(len(t) for t in touched)
    # Each constraint is in the group its particles' parts say; the spring across the cloth in the rest.
    part = np.asarray(model.particle_parts)
    for batch, key in (("distance", "particles"), ("bending", "particles"), ("volume", "particles")):
        particles = np.asarray(getattr(model, batch)[key])
        c = model.colouring(batch)
        offsets, groups = np.asarray(c["colour_offsets"]), np.asarray(c["group_colours"])
        assert len(groups) == 2 * parts + 1
        group = np.empty(len(particles), int)
        for g in range(2 * parts):
            group[np.asarray(c["order"])[offsets[groups[g]]:offsets[groups[g + 1]]]] = g
        lo, hi = part[particles].min(axis=1), part[particles].max(axis=1)
        expected = np.where(lo == hi, lo, np.where(hi == lo + 1, parts + lo, 2 * parts - 1))
        assert np.array_equal(group, expected), batch
    spring = len(np.asarray(model.distance["particles"])) - 1
    assert group_of_distance(model, spring) == 2 * parts - 1
    sizes = np.bincount(part, minlength=parts)
    assert len(sizes) == parts and sizes.max() - sizes.min() <= 1  # parts of equal count


def group_of_distance(model, c: int) -> int:
    col = model.colouring("distance")
    offsets, groups = np.asarray(col["colour_offsets"]), np.asarray(col["group_colours"])
    at = int(np.nonzero(np.asarray(col["order"]) == c)[0][0])
    colour = int(np.searchsorted(offsets, at, side="right") - 1)
    return int(np.searchsorted(groups, colour, side="right") - 1)


def test_the_greedy_colouring_is_first_fit_in_constraint_order():
    # A path 0-1-2-3-4: edges alternate between two colours.
    c = _core.colour_constraints(np.array([[0, 1], [1, 2], [2, 3], [3, 4]]), 5, 1)
    assert list(c["order"]) == [0, 2, 1, 3] and list(c["colour_offsets"]) == [0, 2, 4] and not any(c["serial"])


def test_small_colours_and_colours_past_the_limit_go_to_the_overflow_colour():
    # A star: every constraint shares particle 0, so each needs its own colour; the first
    # MAX_COLOURS get one, the rest (none free) go to the overflow colour.
    m = _core.MAX_COLOURS + 6
    star = np.stack([np.zeros(m, int), np.arange(1, m + 1)], axis=1)
    c = _core.colour_constraints(star, m + 1, 1)
    offsets = np.asarray(c["colour_offsets"])
    assert list(c["serial"]) == [False] * _core.MAX_COLOURS + [True]
    assert np.array_equal(np.diff(offsets), [1] * _core.MAX_COLOURS + [6])
    assert list(c["order"][-6:]) == list(range(_core.MAX_COLOURS, m))
    check_colouring(star, c, min_size=1)
    # With the default threshold every one of those colours is too small: all overflow, in order.
    c = _core.colour_constraints(star, m + 1)
    assert list(c["serial"]) == [True] and list(c["colour_offsets"]) == [0, m] and list(c["order"]) == list(range(m))


def test_a_small_model_is_one_overflow_colour_in_build_order():
    b = csb.ModelBuilder()
    g = b.add_group("chain")
    for k in range(11):
        b.add_particle([k * 0.1, 0, 0], 0.1, g)
    for k in range(10):
        b.add_distance(k, k + 1)
    model = b.build()
    c = model.colouring("distance")
    assert model.num_parts == 1 and list(c["group_colours"]) == [0, 1, 1]  # the interior, an empty rest
    assert list(c["serial"]) == [True] and list(c["colour_offsets"]) == [0, 10] and list(c["order"]) == list(range(10))


def test_the_distance_colours_do_not_depend_on_the_build_order():
    """A mesh's edges are built in colour order (for the sequential sweep) and the distance batch
    is coloured in particle-pair order, so the coloured sweep sees the colours, and projects the
    serial colour in the order, of the index-ordered edges: the same constraints added in index
    order or reversed give the built model's bits."""
    b = csb.ModelBuilder()
    g = b.add_group("cloth")
    b.add_mesh(csb.cloth_grid(1.0, 1.0, 12, 12), group=g, mass=0.5)
    b.pin(0)
    built = b.build()
    pairs = np.asarray(built.distance["particles"])
    index = np.lexsort((pairs[:, 1], pairs[:, 0]))
    assert not np.array_equal(index, np.arange(len(pairs)))  # built in another order than index order
    hashes = []
    for sequence in (np.arange(len(pairs)), index, index[::-1]):
        b = csb.ModelBuilder()
        g = b.add_group("cloth")
        for x, m in zip(np.asarray(built.rest_positions), np.asarray(built.mass)):
            b.add_particle(x, float(m), g)
        for c in sequence:
            b.add_distance(int(pairs[c, 0]), int(pairs[c, 1]))
        b.pin(0)
        model = b.build()
        state = model.initial_state()
        csb.PbdStepper(dt=1 / 60, substeps=4, iterations=3).step(model, state, 30)
        hashes.append(state_hash(state))
    assert hashes[0] == hashes[1] == hashes[2]


def test_a_torn_model_is_coloured_again():
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1.0, 1.0, 20, 20), mass=0.5, bending_stiffness=0.5)
    model = b.build()
    state = model.initial_state()
    x = np.asarray(state.x)
    x[:, 0] *= np.where(x[:, 0] > 0, 1.5, 1.0)  # stretch the right half
    torn = csb.tear(model, state, max_strain=0.2, max_tears=5)
    assert torn["torn"] > 0
    for batch in ("distance", "bending"):
        check_colouring(np.asarray(getattr(torn["model"], batch)["particles"]), torn["model"].colouring(batch),
                        by_particles=batch == "distance")


def state_hash(state) -> str:
    return hashlib.sha256(np.ascontiguousarray(state.x).tobytes() + np.ascontiguousarray(state.v).tobytes()).hexdigest()


@pytest.mark.parametrize("method, solver", [("pbd", "gauss-seidel"), ("xpbd", "gauss-seidel"),
                                            ("jakobsen", "gauss-seidel"), ("pbd", "jacobi"), ("xpbd", "jacobi"),
                                            ("jakobsen", "jacobi")])
def test_the_result_does_not_depend_on_the_thread_count(method, solver):
    """The same bits with 1 and 2 threads, and in a second run with 2: distance, bending,
    volume, attachment and balloon constraints, four sub-steps of three iterations."""
    model = mixed_model(compliance=1e-6 if method == "xpbd" else 0.0)
    hashes = []
    for threads in (1, 2, 2):
        state = model.initial_state()
        stepper = csb.PbdStepper(method=method, solver=solver, dt=1 / 60, substeps=4, iterations=3, threads=threads)
        stepper.step(model, state, 20)
        assert stepper.threads_used == threads
        assert np.isfinite(state.x).all()
        hashes.append(state_hash(state))
    assert hashes[0] == hashes[1] == hashes[2]


def test_xpbd_multipliers_come_back_in_the_model_order():
    """Multipliers are kept in colour order and put back in the model's. One Jacobi sweep reads
    only the positions at its start, so each constraint's multiplier does not depend on the order:
    the coloured and the sequential sweeps give the same, constraint by constraint, to round-off
    (the coloured kernels multiply by precomputed reciprocals where the sequential ones divide)."""
    model = mixed_model(compliance=1e-5)
    out = {}
    for ordering in ("coloured", "sequential"):
        state = model.initial_state()
        state.v = np.random.default_rng(1).normal(size=(model.num_particles, 3))
        stepper = csb.PbdStepper(method="xpbd", solver="jacobi", dt=1 / 60, substeps=1, iterations=1, ordering=ordering)
        stepper.step(model, state, 1)
        out[ordering] = stepper.multipliers()
    for batch in ("distance", "bending", "volume", "attachment", "balloon"):
        a, b = out["coloured"][batch], out["sequential"][batch]
        assert a.shape == b.shape and np.abs(a).max() > 0
        assert np.abs(a - b).max() <= 1e-9 * np.abs(b).max(), batch


def _xpbd_fused_reference(model, x, v, h, gamma_distance, gamma_bending):
    """One XPBD Gauss-Seidel sweep of one sub-step (no gravity: p = x + h v) with csb.kernels'
    scalar projections, in the coloured order with each bending element carrying its edge: per
    group, the distance constraints no element carries, colour by colour, then the bending
    elements colour by colour, each projecting the first bilateral distance constraint on its
    edge (a, b), if not taken by an earlier element, just before itself."""
    K = csb.kernels
    p, start = x + h * v, x.copy()
    w = np.asarray(model.inv_mass)
    d, bend = model.distance, model.bending
    pairs, rest, sense = np.asarray(d["particles"]), np.asarray(d["rest_length"]), np.asarray(d["sense"])
    alpha_d = np.asarray(d["compliance"]) / h**2
    quads, theta0, alpha_b = np.asarray(bend["particles"]), np.asarray(bend["rest_angle"]), np.asarray(bend["compliance"]) / h**2
    dc, bc = model.colouring("distance"), model.colouring("bending")
    first = {}
    for o in range(len(pairs)):
        if sense[o] == 0:
            first.setdefault(tuple(sorted(pairs[o])), o)
    carried = {}
    for c in bc["order"]:
        o = first.get(tuple(sorted(quads[c][:2])))
        if o is not None and o not in carried.values():
            carried[c] = o

    def distance(o):
        i, j = pairs[o]
        p[i], p[j], _, _ = K.project_distance_xpbd(p[i], p[j], w[i], w[j], rest[o], alpha_d[o], 0.0, gamma_distance,
                                                  start[i], start[j])

    def bending(c):
        if c in carried:
            distance(carried[c])
        q = quads[c]
        out = K.project_bending_xpbd(p[q[0]], p[q[1]], p[q[2]], p[q[3]], w[q], theta0[c], alpha_b[c], 0.0,
                                     gamma_bending, start[q])
        for s in range(4):
            p[q[s]] = out[s]

    own = set(range(len(pairs))) - set(carried.values())
    for g in range(len(dc["group_colours"]) - 1):
        for k in range(dc["group_colours"][g], dc["group_colours"][g + 1]):
            for o in dc["order"][dc["colour_offsets"][k]:dc["colour_offsets"][k + 1]]:
                if o in own:
                    distance(o)
        for k in range(bc["group_colours"][g], bc["group_colours"][g + 1]):
            for c in bc["order"][bc["colour_offsets"][k]:bc["colour_offsets"][k + 1]]:
                bending(c)
    return p


@pytest.mark.parametrize("damping", [0.0, 0.3])
def test_xpbd_bending_elements_carry_their_edge_in_gauss_seidel(damping):
    """XPBD's coloured Gauss-Seidel projects each bending element's edge inside the element's
    blocked kernel: the same as the scalar kernels in that order, to round-off (the blocked
    bending kernel is a few units in the last place from the scalar one; the order before this
    pairing was 6 mm away), with and without damping, whose motion p - x the element then reads
    after its edge's correction."""
    b = csb.ModelBuilder()
    # (a bending stiffness makes the bending constraints; XPBD reads their compliance)
    b.add_mesh(csb.cloth_grid(1.0, 1.0, 8, 8), mass=0.2, stretch_compliance=1e-5, bending_stiffness=0.5,
               bending_compliance=0.5)
    model = b.build()
    state = model.initial_state()
    state.v = np.random.default_rng(3).normal(scale=0.5, size=(model.num_particles, 3))
    x, v, h = np.asarray(state.x).copy(), np.asarray(state.v).copy(), 1 / 60
    csb.PbdStepper(method="xpbd", dt=h, substeps=1, iterations=1, gravity=(0, 0, 0), threads=1,
                   xpbd_damping=damping).step(model, state)
    (gamma_d,) = set(np.asarray(model.distance["compliance"]) * damping / h)  # γ = α β / h
    (gamma_b,) = set(np.asarray(model.bending["compliance"]) * damping / h)
    expected = _xpbd_fused_reference(model, x, v, h, gamma_d, gamma_b)
    assert np.abs(np.asarray(state.x) - x).max() > 0.01  # the sweep moved the cloth
    assert np.abs(np.asarray(state.x) - expected).max() <= 1e-13


def test_threads_and_ordering_are_validated():
    with pytest.raises(csb.ParameterError, match=r"threads must be an integer in \[0, 1024\], got -1"):
        csb.PbdStepper(threads=-1)
    with pytest.raises(csb.ParameterError, match="ordering must be 'coloured' or 'sequential'"):
        csb.PbdStepper(ordering="random")
    s = csb.PbdStepper(threads=3, ordering="sequential").settings
    assert s.threads == 3 and s.ordering == "sequential" and "threads=3" in repr(s)


def test_the_scene_solver_table_takes_threads_and_ordering(tmp_path):
    text = csb.bundled_scenes()["cloth_grid"].read_text().replace("[solver]", "[solver]\nthreads = 2\nordering = \"sequential\"")
    (tmp_path / "a.toml").write_text(text)
    stepper = csb.load_scene(tmp_path / "a.toml").build().stepper
    assert stepper.settings.threads == 2 and stepper.settings.ordering == "sequential"
    (tmp_path / "b.toml").write_text(text.replace("threads = 2", "threads = -1"))
    with pytest.raises(SceneError, match=r"solver.threads: must be an integer in \[0, 1024\], got -1"):
        csb.load_scene(tmp_path / "b.toml")


def test_memory_report_counts_the_arrays():
    """Model.memory is the capacity of its arrays: for a freshly built model exactly the bytes
    of the batch arrays Python sees plus the colouring; the stepper's workspace holds at least
    its positions and the coloured batches, and both grow linearly with the cloth."""
    per_particle = []
    for n in (16, 32):
        b = csb.ModelBuilder()
        b.add_mesh(csb.cloth_grid(1.0, 1.0, n, n), mass=0.5, bending_stiffness=0.5)
        model = b.build()
        mem = model.memory
        for batch in ("distance", "bending"):
            arrays = getattr(model, batch)
            colouring = model.colouring(batch)
            expected = sum(np.asarray(a).nbytes for a in arrays.values()) + sum(
                np.asarray(colouring[k]).nbytes for k in ("order", "colour_offsets", "serial", "group_colours"))
            assert mem[batch] == expected, batch
        N = model.num_particles
        assert mem["particles"] >= N * (3 * 8 + 8 + 8 + 4 + 4 + 8)
        assert mem["total"] == sum(v for k, v in mem.items() if k != "total")
        stepper = csb.PbdStepper()
        stepper.step(model, model.initial_state())
        d, bend = len(model.distance["rest_length"]), len(model.bending["rest_angle"])
        # p (24 B/particle); distance (each interior edge's with its bending element): i, j, rest,
        # sense, c_i, c_j; bending: q, rest, w, k, and its edge's rest, c_a, c_b
        assert stepper.workspace_bytes >= 24 * N + (d - bend) * (4 + 4 + 8 + 1 + 8 + 8) + bend * (16 + 8 + 32 + 8 + 24)
        per_particle.append((mem["total"] + stepper.workspace_bytes) / N)
    assert per_particle[1] == pytest.approx(per_particle[0], rel=0.1)


def test_a_non_finite_sub_step_is_reported_alike_on_any_thread_count():
    """Without contacts, grabs or damping the projection's threads also predict, check and update
    (the fused sub-step): a blow-up must still name the first particle and leave the state at the
    last finite sub-step, the same with 1 and 2 threads."""
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1.0, 1.0, 96, 96), mass=0.5, bending_stiffness=0.5)
    model = b.build()
    assert model.num_parts == 8
    out = []
    for threads in (1, 2):
        state = model.initial_state()
        stepper = csb.PbdStepper(dt=0.1, gravity=(0, -1e307, 0), substeps=2, threads=threads)
        with pytest.raises(csb.SimulationError, match=r"particle \d+ got a non-finite") as err:
            stepper.step(model, state, 100)
        assert np.isfinite(state.x).all() and np.isfinite(state.v).all()
        out.append((str(err.value), state_hash(state)))
    assert out[0] == out[1]


@pytest.mark.parametrize("method, front_end, substeps, iterations", [
    ("pbd", "euler", 10, 1), ("xpbd", "euler", 2, 5), ("jakobsen", "verlet", 3, 2)])
def test_a_fused_step_is_the_same_as_its_sub_steps_one_at_a_time(method, front_end, substeps, iterations):
    """A cloth's fused step updates and predicts each part's particles in the part's task and
    checks finiteness once, after its last sub-step; a step that fails is taken again one
    sub-step at a time from its start. Against the sub-steps taken one at a time throughout
    (forced by holding the pinned particle where it is: a kinematic grab that moves nothing), on
    1 and 2 threads: the same bits after 20 steps under gravity, and under absurd gravities, which
    blow the cloth up within 100 steps or not depending on the method, the same error (step,
    sub-step, particle) and the same state, left at the start of the failing sub-step; for every
    method at least one of them fails after the first sub-step of a step (so the state was
    restored and the step taken again part way)."""
    b = csb.ModelBuilder()
    # XPBD reads the compliance, 0 here: its bending is rigid, which stiffness 1 declares (a rigid
    # cloth blows up under these gravities after the first sub-step of a step, as the test needs).
    b.add_mesh(csb.cloth_grid(1.0, 1.0, 96, 96), mass=0.5, bending_stiffness=1.0 if method == "xpbd" else 0.5)
    b.pin(0)
    model = b.build()
    assert model.num_parts == 8
    later = 0
    for g, dt, steps in ((-9.81, 1 / 60, 20), (-1e63, 0.1, 100), (-1e65, 0.1, 100), (-1e74, 0.1, 100),
                         (-5e74, 0.1, 100), (-1e76, 0.1, 100), (-1e77, 0.1, 100)):
        out = []
        for threads in (1, 2):
            for held in (False, True):
                state = model.initial_state()
                stepper = csb.PbdStepper(method=method, front_end=front_end, substeps=substeps, iterations=iterations,
                                         threads=threads, dt=dt, gravity=(0, g, 0))
                if held:
                    stepper.grab(model, state, 0, state.x[0])
                message = "finished"
                try:
                    stepper.step(model, state, steps)
                except csb.SimulationError as err:
                    message = str(err)
                assert np.isfinite(state.x).all() and np.isfinite(state.v).all()
                out.append((message, state_hash(state), state.step))
        assert len(set(out)) == 1, out
        if g == -9.81:
            assert out[0][0] == "finished" and out[0][2] == 20
        elif out[0][0] != "finished":
            found = re.match(r"step (\d+) \(substep (\d+), t = .* s\): particle \d+ got a non-finite", out[0][0])
            assert found, out[0][0]
            assert int(found.group(1)) == out[0][2]
            later += int(found.group(2)) > 0
    assert later > 0


def test_automatic_threads_follow_the_parts():
    """threads=0: one thread for a model of one part (its phases have one task each), else at
    most the free cores and at most the parts."""

    def auto_threads(n: int) -> tuple[int, int]:
        b = csb.ModelBuilder()
        b.add_mesh(csb.cloth_grid(1.0, 1.0, n, n), mass=0.5)
        model = b.build()
        stepper = csb.PbdStepper(threads=0)
        stepper.step(model, model.initial_state())
        return model.num_parts, stepper.threads_used

    assert auto_threads(16) == (1, 1)
    parts, threads = auto_threads(32)
    assert parts == 2 and 1 <= threads <= min(2, os.cpu_count() or 1)


@pytest.mark.skipif(not sys.platform.startswith("linux") or (os.cpu_count() or 1) > 8,
                    reason="reads /proc/loadavg; keeps every other core busy")
def test_automatic_threads_leave_a_busy_core_alone():
    """With every core but one kept busy by other processes, automatic threads settle on one.
    (A lower free-core reading counts only once a second one 1.3 ms later agrees, so that a
    task runnable for microseconds does not cost a thread; a busy process is in both.)"""
    b = csb.ModelBuilder()
    b.add_mesh(csb.cloth_grid(1.0, 1.0, 64, 64), mass=0.5)
    model = b.build()
    assert model.num_parts > 1
    state = model.initial_state()
    stepper = csb.PbdStepper(threads=0, iterations=2)
    spinners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range((os.cpu_count() or 1) - 1)]
    try:
        time.sleep(0.2)  # the spinners are running
        used = []
        t_end = time.perf_counter() + 0.1  # 20 readings' worth of steps
        while time.perf_counter() < t_end:
            stepper.step(model, state)
            used.append(stepper.threads_used)
    finally:
        for p in spinners:
            p.kill()
            p.wait()
    assert used[-1] == 1, used
    assert np.isfinite(state.x).all()


@pytest.mark.parametrize("method", ["pbd", "jakobsen"])
def test_a_bending_element_projects_its_edge_just_before_itself(method):
    """PBD and Jakobsen with Gauss-Seidel: the distance constraint on a bending element's edge
    (a, b) is projected by the element's kernel, just before its bending constraint, and the other
    distance constraints come first (another Gauss-Seidel order than all distances, then all
    bending: the particles of an element move in and out of the kernel once). Two triangles
    folded along their shared edge, stretched, one sweep: the reference kernels applied in that
    order give the same positions to round-off (the coloured bending kernel's closed-form
    gradients, as in test_bending_simd.py), and the other order does not."""
    x0 = np.array([[0.0, 0.0, 0.0], [1.1, 0.0, 0.05], [0.5, 0.3, 0.9], [0.45, 0.25, -0.85]])
    mass = np.array([0.1, 0.2, 0.15, 0.12])
    edges = [(0, 2), (0, 1), (1, 2), (0, 3), (1, 3)]  # the element's edge (0, 1) second
    rest = [0.95, 1.0, 1.02, 0.9, 0.97]
    b = csb.ModelBuilder()
    group = b.add_group("folded")
    for p, m in zip(x0, mass):
        b.add_particle(p, m, group)
    for (i, j), r in zip(edges, rest):
        b.add_distance(i, j, stiffness=0.8, rest_length=r)
    b.add_bending(0, 1, 2, 3, stiffness=0.7, rest_angle=0.3)
    model = b.build()
    state = model.initial_state()
    csb.PbdStepper(method=method, dt=1 / 60, substeps=1, iterations=1, gravity=(0, 0, 0)).step(model, state, 1)
    w = 1 / mass

    def distance(p, k):
        (i, j), r = edges[k], rest[k]
        p[i], p[j], _ = csb.kernels.project_distance(p[i], p[j], w[i], w[j], r, 0.8)

    def bending(p):
        *p[:4], _ = csb.kernels.project_bending(*p[:4], w, 0.3, 0.7)

    fused, separate = x0.copy(), x0.copy()
    for k in (0, 2, 3, 4, 1):
        distance(fused, k)
    bending(fused)
    for k in range(5):
        distance(separate, k)
    bending(separate)
    assert np.abs(fused - separate).max() > 1e-3
    # 64 eps at the cloth's scale: the bound of test_bending_simd.py's tolerance()
    assert np.abs(np.asarray(state.x) - fused).max() <= 64 * np.finfo(float).eps * np.abs(fused).max()
