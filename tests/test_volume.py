"""Tetrahedral volume constraints: the kernel (Müller 2007 §3.3 general form, XPBD), tet meshes
(generation, meshio files, inverted and degenerate tets), the stepper and the reference."""

from __future__ import annotations

import re
import warnings

import meshio
import numpy as np
import pytest

import csb
from csb.studies.soft_bodies import hanging_tet_cube, tet_cantilever, total_volume, xpbd_error_against_reference

K = csb.kernels
EPS = np.finfo(float).eps
G = (0.0, -9.81, 0.0)


def random_tet(rng: np.random.Generator) -> np.ndarray:
    """Four points of a positively oriented tet, not too flat (V > 0.02 for unit-normal points)."""
    while True:
        P = rng.normal(size=(4, 3))
        if K.tet_volume(*P) < 0:
            P[[2, 3]] = P[[3, 2]]
        if K.tet_volume(*P) > 0.02:
            return P


def assert_momentum_free(P: np.ndarray, Q: np.ndarray, w: np.ndarray) -> None:
    """Σ m Δp = 0 and Σ m p × Δp = 0 for Δp = Q - P, as in tests/test_kernels.py: Δp is only seen
    as Q - P, exact to an ulp of |p| per component, so the sums may differ from 0 by ~eps Σ m |p|
    (2 eps Σ m |p|² with the cross product); the bounds allow twice that."""
    m = 1 / w
    dp = Q - P
    R = np.abs(P).max(axis=1)
    assert np.abs((m[:, None] * dp).sum(axis=0)).max() <= 4 * EPS * np.sum(m * R)
    assert np.abs((m[:, None] * np.cross(P, dp)).sum(axis=0)).max() <= 8 * EPS * np.sum(m * R * R)


# ------------------------------------------------------------------------------ kernel


def test_volume_gradient_matches_finite_differences(rng):
    for _ in range(50):
        P = random_tet(rng)
        g = K.tet_volume_gradient(*P)
        assert g.sum(axis=0) == pytest.approx(np.zeros(3), abs=1e-15)  # translation invariance
        fd = np.zeros((4, 3))
        h = 1e-6
        for i in range(4):
            for k in range(3):
                Pp, Pm = P.copy(), P.copy()
                Pp[i, k] += h
                Pm[i, k] -= h
                fd[i, k] = (K.tet_volume(*Pp) - K.tet_volume(*Pm)) / (2 * h)
        # V is cubic: central differences are exact up to h² ∂³V/∂x³ = 0 along one coordinate
        # (V is linear in each coordinate), so only round-off eps |V| / h ~ 1e-10 remains.
        np.testing.assert_allclose(g, fd, atol=1e-9)


def test_one_projection_removes_the_violation_to_second_order(rng):
    """V is cubic in the positions, so a k = 1 projection (a Newton step along ∇C) leaves a
    residual O(C²): measured |C1| / (C0²/V0) stays below 1 on random tets squeezed or stretched
    by up to 20 % (measured worst 0.3); the error then squares with each projection, and six
    reach round-off."""
    worst = 0.0
    for _ in range(200):
        P = random_tet(rng)
        w = rng.uniform(0.2, 3.0, 4)
        v = K.tet_volume(*P)
        v0 = v * rng.uniform(0.8, 1.2)
        *Q, c = K.project_volume(*P, w, v0, 1.0)
        assert c == pytest.approx(v - v0, abs=1e-15)
        c1 = K.tet_volume(*Q) - v0
        worst = max(worst, abs(c1) / (c**2 / v0))
        for _ in range(5):
            *Q, _c = K.project_volume(*Q, w, v0, 1.0)
        assert abs(K.tet_volume(*Q) - v0) <= 64 * EPS * v0 * np.abs(P).max() ** 3 / v
    print(f"worst |C1| / (C0²/V0) = {worst:.3f}")
    assert worst < 1.0


def test_volume_projection_conserves_linear_and_angular_momentum(rng):
    for _ in range(200):
        P = random_tet(rng)
        w = rng.uniform(0.2, 3.0, 4)
        v0 = K.tet_volume(*P) * rng.uniform(0.5, 1.5)
        Q = np.array(K.project_volume(*P, w, v0, rng.uniform(0.1, 1.0))[:4])
        assert_momentum_free(P, Q, w)
        out = K.project_volume_xpbd(*P, w, v0, rng.uniform(0, 1e-2))
        assert_momentum_free(P, np.array(out[:4]), w)


def test_xpbd_volume_step_is_macklins_formula(rng):
    P = random_tet(rng)
    w = np.array([1.0, 0.5, 2.0, 0.0])  # one pinned particle must not move
    v0 = 1.1 * K.tet_volume(*P)
    g = K.tet_volume_gradient(*P)
    c = K.tet_volume(*P) - v0
    alpha_tilde, lam = 0.3, 0.05
    *Q, viol, lam1 = K.project_volume_xpbd(*P, w, v0, alpha_tilde, lam)
    dl = (-c - alpha_tilde * lam) / (np.sum(w * np.sum(g * g, axis=1)) + alpha_tilde)
    assert viol == pytest.approx(c, rel=1e-14) and lam1 == pytest.approx(lam + dl, rel=1e-13)
    np.testing.assert_allclose(np.array(Q), P + w[:, None] * g * dl, atol=1e-15)
    assert np.array_equal(Q[3], P[3])
    # α̃ = 0 is PBD with k = 1.
    np.testing.assert_allclose(K.project_volume_xpbd(*P, w, v0, 0.0)[:4], K.project_volume(*P, w, v0, 1.0)[:4], atol=1e-15)


def test_collapsed_tet_is_left_alone_without_nan():
    line = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])
    for P in (line, np.zeros((4, 3))):
        *Q, c = K.project_volume(*P, [1.0] * 4, 0.1, 1.0)
        assert np.array_equal(np.array(Q), P) and c == pytest.approx(-0.1)


# ------------------------------------------------------------------------------ tet meshes


def test_tet_box_is_positively_oriented_and_its_surface_is_closed_and_outward():
    m = csb.tet_box([0.4, 0.2, 0.1], [4, 2, 3], center=[1, 2, 3])
    assert m.num_points == 5 * 3 * 4 and m.num_tets == 6 * 4 * 2 * 3
    v = m.volumes()
    assert v.min() > 0 and v.sum() == pytest.approx(0.4 * 0.2 * 0.1, rel=1e-13)
    s = m.surface()
    assert len(s) == 2 * 2 * (4 * 2 + 2 * 3 + 4 * 3)  # two triangles per boundary cell face
    assert csb.kernels.enclosed_volume(m.points, s) == pytest.approx(0.4 * 0.2 * 0.1, rel=1e-12)
    b = csb.ModelBuilder()
    inst = b.add_tet_mesh(m, mass=1.0)
    np.testing.assert_array_equal(inst.triangles, s)
    b.add_balloon(inst)  # closed and consistently wound, else this raises


def test_add_tet_mesh_constraints_masses_and_triangles():
    m = csb.tet_box([1.0, 1.0, 1.0], [2, 2, 2])
    b = csb.ModelBuilder()
    inst = b.add_tet_mesh(m, density=1000.0, stretch_compliance=1e-3, volume_compliance=1e-7)
    model = b.build()
    assert inst.num_volume == 48 and model.volume["particles"].shape == (48, 4)
    assert inst.num_distance == len({tuple(sorted((q[a], q[c]))) for q in m.tets for a in range(4) for c in range(a + 1, 4)})
    assert model.num_constraints == inst.num_distance + 48
    assert model.mass.sum() == pytest.approx(1000.0, rel=1e-13)  # density x 1 m³
    np.testing.assert_allclose(model.volume["rest_volume"], m.volumes())
    assert np.all(model.volume["compliance"] == 1e-7) and model.triangles.shape == (48, 3)
    b2 = csb.ModelBuilder()
    assert b2.add_tet_mesh(m, mass=2.0).num_particles == 27 and b2.build().mass.sum() == pytest.approx(2.0)
    b3 = csb.ModelBuilder()
    b3.add_tet_mesh(m, particle_mass=0.1, volume_stiffness=None, stretch_stiffness=None)
    assert b3.build().num_constraints == 0
    with pytest.raises(csb.ParameterError, match="exactly one of mass"):
        csb.ModelBuilder().add_tet_mesh(m, mass=1.0, density=2.0)


def test_inverted_tets_are_reoriented_with_a_warning():
    m = csb.tet_box([1.0, 1.0, 1.0], [1, 1, 1])
    tets = m.tets.copy()
    tets[[1, 4]] = tets[[1, 4]][:, [0, 1, 3, 2]]
    bad = csb.TetMesh(m.points, tets, name="inside_out.msh")
    assert (bad.volumes() < 0).sum() == 2
    b = csb.ModelBuilder()
    with pytest.warns(csb.MeshWarning, match=r"inside_out.msh: 2 inverted tets .*first: tet 1"):
        inst = b.add_tet_mesh(bad, mass=1.0)
    assert inst.flipped_tets == 2
    model = b.build()
    assert model.volume["rest_volume"].min() > 0
    np.testing.assert_allclose(np.sort(model.volume["rest_volume"]), np.sort(m.volumes()))


def test_degenerate_tet_is_an_error_naming_it():
    m = csb.tet_box([1.0, 1.0, 1.0], [1, 1, 1])
    # A seventh tet whose fourth point is the centroid of the other three: flat, volume 0.
    pts = np.vstack([m.points, (m.points[0] + m.points[1] + m.points[3]) / 3])
    tets = np.vstack([m.tets, [[0, 1, 3, 8]]])
    with pytest.raises(csb.MeshError, match=r"flat.msh: tet 6 is degenerate .*signed volume"):
        csb.ModelBuilder().add_tet_mesh(csb.TetMesh(pts, tets, name="flat.msh"), mass=1.0)
    b = csb.ModelBuilder()
    g = b.add_group("g")
    for p in ([0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 0, 1]):
        b.add_particle(p, 1.0, g)
    with pytest.raises(csb.ParameterError, match=r"volume constraint 0 .*degenerate"):
        b.add_tetrahedron(0, 1, 2, 3)
    with pytest.raises(csb.ParameterError, match=r"volume constraint 0 .*negative signed volume"):
        b.add_tetrahedron(0, 2, 1, 4)
    assert b.add_tetrahedron(0, 1, 2, 4, compliance=1e-6) == 0
    with pytest.raises(csb.ParameterError, match="rest volume must be"):
        b.add_tetrahedron(0, 1, 2, 4, rest_volume=-1.0)


def test_tet_mesh_validation_names_the_element():
    m = csb.tet_box([1.0, 1.0, 1.0], [1, 1, 1])
    pts = m.points.copy()
    pts[3, 1] = np.nan
    with pytest.raises(csb.MeshError, match=r"a.vtu: point 3 has a non-finite"):
        csb.TetMesh(pts, m.tets, name="a.vtu")
    with pytest.raises(csb.MeshError, match=r"b.vtu: tet 2 uses point 99, out of range"):
        csb.TetMesh(m.points, np.vstack([m.tets[:2], [[0, 1, 2, 99]]]), name="b.vtu")
    with pytest.raises(csb.MeshError, match=r"c.vtu: tet 0 uses point 1 twice"):
        csb.TetMesh(m.points, [[0, 1, 1, 2]], name="c.vtu")
    with pytest.raises(csb.MeshError, match="no tetrahedra"):
        csb.TetMesh(m.points, np.zeros((0, 4), dtype=int), name="d.vtu")


# ------------------------------------------------------------------------------ meshio files


@pytest.mark.parametrize(
    "name, fmt",
    [("box.msh", "gmsh22"), ("box4.msh", "gmsh"), ("box.vtu", None), ("box.vtk", None), ("box.mesh", "medit"),
     ("box.inp", "abaqus")],
)
def test_tet_mesh_files_round_trip(tmp_path, name, fmt):
    m = csb.tet_box([0.3, 0.2, 0.1], [3, 2, 1])
    path = tmp_path / name
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # meshio's own notes on the formats (e.g. gmsh physical tags)
        meshio.write(path, meshio.Mesh(m.points, [("tetra", m.tets)]), file_format=fmt, **({"binary": False} if fmt and fmt.startswith("gmsh") else {}))
    back = csb.load_tet_mesh(path)
    assert back.name == str(path) and back.num_points == m.num_points and back.num_tets == m.num_tets
    np.testing.assert_allclose(np.sort(back.volumes()), np.sort(m.volumes()), rtol=1e-6)  # text formats round coordinates
    assert back.volumes().sum() == pytest.approx(0.3 * 0.2 * 0.1, rel=1e-6)


def test_tetra10_is_reduced_to_corners_and_surface_cells_ignored(tmp_path):
    m = csb.tet_box([1.0, 1.0, 1.0], [1, 1, 1])
    mids = np.array([(m.points[q[a]] + m.points[q[c]]) / 2 for q in m.tets for a, c in
                     [(0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)]])
    pts = np.vstack([m.points, mids])
    t10 = np.hstack([m.tets, 8 + np.arange(6 * m.num_tets).reshape(-1, 6)])
    path = tmp_path / "quad.vtu"
    meshio.write(path, meshio.Mesh(pts, [("tetra10", t10), ("triangle", m.surface())]))
    with pytest.warns(csb.MeshWarning) as record:
        back = csb.load_tet_mesh(path)
    text = " ".join(str(r.message) for r in record)
    assert "6 quadratic tets (tetra10) reduced" in text and "36 points that no tet uses were dropped" in text
    assert back.num_points == 8 and back.volumes().sum() == pytest.approx(1.0, rel=1e-12)


def test_bad_tet_mesh_files_name_the_file(tmp_path):
    m = csb.tet_box([1.0, 1.0, 1.0], [1, 1, 1])
    tri = tmp_path / "surface_only.vtu"
    meshio.write(tri, meshio.Mesh(m.points, [("triangle", m.surface())]))
    with pytest.raises(csb.MeshError, match=re.escape(str(tri)) + r": no tetrahedra .*triangle x 12"):
        csb.load_tet_mesh(tri)
    nan = tmp_path / "nan.vtu"
    pts = m.points.copy()
    pts[5, 0] = np.nan
    meshio.write(nan, meshio.Mesh(pts, [("tetra", m.tets)]))
    with pytest.raises(csb.MeshError, match=re.escape(str(nan)) + ": point 5 has a non-finite"):
        csb.load_tet_mesh(nan)
    out_of_range = tmp_path / "range.mesh"
    out_of_range.write_text("MeshVersionFormatted 2\nDimension 3\nVertices\n4\n0 0 0 0\n1 0 0 0\n0 1 0 0\n0 0 1 0\n"
                            "Tetrahedra\n1\n1 2 3 9 0\nEnd\n")
    with pytest.raises(csb.MeshError, match=re.escape(str(out_of_range)) + r".*(out of range|could not read)"):
        csb.load_tet_mesh(out_of_range)
    corrupt = tmp_path / "corrupt.msh"
    corrupt.write_bytes(b"$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n\x00\xffgarbage\n")
    with pytest.raises(csb.MeshError, match=re.escape(str(corrupt)) + ": meshio could not read it"):
        csb.load_tet_mesh(corrupt)
    with pytest.raises(FileNotFoundError, match="missing.vtu"):
        csb.load_tet_mesh(tmp_path / "missing.vtu")


# ------------------------------------------------------------------------------ stepping


@pytest.mark.parametrize("method, solver, bound", [
    ("xpbd", "gauss-seidel", 0.01), ("pbd", "gauss-seidel", 0.001), ("pbd", "jacobi", 0.05), ("jakobsen", "gauss-seidel", 0.001)])
def test_hanging_soft_cube_keeps_its_volume(method, solver, bound):
    """A 0.2 m soft cube (bulk modulus 1e5 Pa for XPBD) falls and swings from one pinned corner for
    2 s. The total volume error stays below `bound`: measured 0.28 % for XPBD (a physical bulk
    modulus lets it breathe: ρ g L / K ~ 1e-2 at this size), < 0.01 % for the hard PBD and
    Jakobsen constraints, a few % for averaged Jacobi (slower convergence per iteration). The cube
    declares only compliances (stiffness 1): PBD and Jakobsen make its constraints hard, and say so."""
    model, _ = hanging_tet_cube()
    state = model.initial_state()
    v0 = total_volume(model, state)
    stepper = csb.PbdStepper(method=method, dt=1 / 60, substeps=4, iterations=10, solver=solver)
    worst = 0.0
    for k in range(120):
        if k == 0 and method != "xpbd":
            label = "PBD" if method == "pbd" else "Jakobsen"
            with pytest.warns(csb.MaterialWarning) as notes:
                stepper.step(model, state)
            assert [str(n.message).split(":")[1].split(" have ")[0] for n in notes] == [
                f" {model.distance['compliance'].size:,} distance (stretch) constraints",
                f" {model.volume['compliance'].size:,} volume constraints"]
            assert all(str(n.message).startswith(f"{label} reads stiffness, not compliance") for n in notes)
        else:
            stepper.step(model, state)
        worst = max(worst, abs(total_volume(model, state) / v0 - 1))
    assert worst < bound
    assert state.x[:, 1].min() < -0.1  # it did fall and deform
    if method == "xpbd":
        lam = stepper.multipliers()["volume"]
        assert lam.shape == (model.volume["particles"].shape[0],) and np.all(np.isfinite(lam)) and np.abs(lam).max() > 0


def test_dispatch_benchmark_agrees_with_volume_and_balloon_constraints():
    model, _ = hanging_tet_cube(volume_compliance=0.0)
    b = csb.ModelBuilder()
    inst = b.add_tet_mesh(csb.tet_box([0.2] * 3, [2, 2, 2]), mass=1.0, volume_stiffness=0.5)
    b.add_balloon(inst, pressure=1.2, stiffness=0.8)
    model = b.build()
    x = np.asarray(model.rest_positions) + 0.01 * np.random.default_rng(1).normal(size=(model.num_particles, 3))
    t = csb._core.benchmark_dispatch(model, x, sweeps=3, repeats=1)
    assert t["identical"]


# ------------------------------------------------------------------------------ reference


def test_reference_volume_jacobian_matches_finite_differences(rng):
    b = csb.ModelBuilder()
    inst = b.add_tet_mesh(csb.tet_box([0.3, 0.2, 0.2], [2, 1, 1]), mass=1.0, stretch_compliance=1e-2,
                          volume_compliance=1e-4)
    b.pin(inst.first_particle)
    model = b.build()
    net = csb.SpringNetwork(model, model.initial_state(), gravity=G)
    assert net.has_analytic_jacobian
    y = net.pack(model.initial_state()) + rng.normal(scale=0.02, size=net.size)
    indptr, indices, data = net.jacobian(y)
    J = np.zeros((net.size, net.size))
    for col in range(net.size):
        J[indices[indptr[col]:indptr[col + 1]], col] = data[indptr[col]:indptr[col + 1]]
    F = np.zeros_like(J)
    h = 1e-6
    for col in range(net.size):
        e = np.zeros(net.size)
        e[col] = h
        F[:, col] = (net.rhs(y + e) - net.rhs(y - e)) / (2 * h)
    # As in test_reference.py: truncation O(h²) and round-off O(eps |f| / h), far below 1e-7 |J|.
    np.testing.assert_allclose(J, F, atol=1e-7 * np.abs(J).max())


def test_reference_volume_force_is_minus_the_energy_gradient(rng):
    b = csb.ModelBuilder()
    g = b.add_group("t")
    for p in ([0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]):
        b.add_particle(p, 2.0, g)
    b.add_tetrahedron(0, 1, 2, 3, compliance=0.01, rest_volume=0.2)
    model = b.build()
    state = model.initial_state()
    state.x = state.x + rng.normal(scale=0.05, size=(4, 3))
    net = csb.SpringNetwork(model, state, gravity=(0, 0, 0))
    a = net.rhs(net.pack(state))[12:].reshape(4, 3)
    grad = np.zeros((4, 3))
    for i in range(4):
        for k in range(3):
            sp, sm = state.copy(), state.copy()
            sp.x[i, k] += 1e-6
            sm.x[i, k] -= 1e-6
            grad[i, k] = (csb.elastic_energy(model, sp) - csb.elastic_energy(model, sm)) / 2e-6
    np.testing.assert_allclose(2.0 * a, -grad, atol=1e-7 * np.abs(grad).max())


def test_hard_volume_constraint_is_an_error_for_the_reference():
    b = csb.ModelBuilder()
    b.add_tet_mesh(csb.tet_box([1.0] * 3, [1, 1, 1]), mass=1.0, stretch_compliance=1e-3)
    model = b.build()
    with pytest.raises(csb.ParameterError, match=r"volume constraint 0 is hard .*m⁶/J"):
        csb.integrate_reference(model, model.initial_state(), [0.1])


@pytest.mark.slow
def test_xpbd_tet_cantilever_converges_to_the_reference():
    """A 0.4 m beam of 192 tets (stretch 1e-4 m/N, bulk modulus 1e6 Pa, 4 kg) pinned at one end
    swings under gravity for 0.5 s. XPBD with one iteration and n substeps of 1/60 s: the largest
    particle distance to the reference over t = 0.1 .. 0.5 s measured 0.027, 0.0028, 0.0002 m for
    n = 16, 64, 256; each 4x more substeps must cut it by at least 4x, and n = 256 be within 1 mm."""
    model, tip = tet_cantilever()
    times = [0.1, 0.2, 0.3, 0.4, 0.5]
    ref = csb.integrate_reference(model, model.initial_state(), times)
    assert ref.stats["linear_solver"] == "klu"
    assert ref.x[:, tip, 1].mean(axis=1).min() < -0.03  # it bends
    errors = []
    for n in (16, 64, 256):
        errors.append(xpbd_error_against_reference(model, ref, times, n)[0])
    assert errors[1] < errors[0] / 4 and errors[2] < errors[1] / 4 and errors[2] < 1e-3
