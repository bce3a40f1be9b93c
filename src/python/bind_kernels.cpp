// csb._core.kernels: the constraint kernels on single constraints.
#include "bindings.hpp"

namespace csb::python {

void bind_kernels(py::module_& m) {
  // ---------------------------------------------------------------- kernels, one constraint at a time
  py::module_ k = m.def_submodule("kernels", "The constraint kernels on single constraints (for tests and teaching).");
  k.def("project_distance", [](py::handle p1, py::handle p2, double w1, double w2, double rest_length,
                               double stiffness, const std::string& sense) {
    Vec3 a = to_vec3(p1, "p1"), b = to_vec3(p2, "p2");
    const Real c = project_distance(a.data(), b.data(), w1, w2, rest_length, stiffness, parse_sense(sense));
    return py::make_tuple(vec3_array(a), vec3_array(b), c);
  }, py::arg("p1"), py::arg("p2"), py::arg("w1"), py::arg("w2"), py::arg("rest_length"), py::arg("stiffness") = 1.0,
     py::arg("sense") = "==",
     "PBD's distance projection (Müller et al. 2007, Eq. 9-10): C = |p1 - p2| - L, Δp1 = -w1/(w1 + w2) k C n, "
     "Δp2 = +w2/(w1 + w2) k C n, n = (p1 - p2)/|p1 - p2|; sense '<=' or '>=' projects only a violated "
     "inequality. Also Jakobsen's stick with square roots. Returns (p1', p2', violation before, m).");
  k.def("project_distance_xpbd", [](py::handle p1, py::handle p2, double w1, double w2, double rest_length,
                                    double alpha_tilde, double lambda, double gamma, py::handle x1, py::handle x2,
                                    const std::string& sense) {
    Vec3 a = to_vec3(p1, "p1"), b = to_vec3(p2, "p2");
    const Vec3 xa = x1.is_none() ? a : to_vec3(x1, "x1"), xb = x2.is_none() ? b : to_vec3(x2, "x2");
    const Real c = project_distance_xpbd(a.data(), b.data(), xa.data(), xb.data(), w1, w2, rest_length, alpha_tilde,
                                         gamma, lambda, parse_sense(sense));
    return py::make_tuple(vec3_array(a), vec3_array(b), c, lambda);
  }, py::arg("p1"), py::arg("p2"), py::arg("w1"), py::arg("w2"), py::arg("rest_length"), py::arg("alpha_tilde"),
     py::arg("lambda_") = 0.0, py::arg("gamma") = 0.0, py::arg("x1") = py::none(), py::arg("x2") = py::none(),
     py::arg("sense") = "==",
     "XPBD's distance projection (Macklin et al. 2016, Eq. 18 and 26): C = |p1 - p2| - L, "
     "Δλ = (-C - α̃λ - γ ∇C·(p - x)) / ((1 + γ)(w1 + w2) + α̃), Δp1 = w1 n Δλ, Δp2 = -w2 n Δλ, with α̃ = α/h² "
     "(kg⁻¹, α in m/N), γ = αβ/h the damping (x1, x2 the positions at the start of the sub-step; default p1, p2). "
     "sense '<=' or '>=' makes it an inequality (λ clamped to its sign). Returns (p1', p2', violation before, "
     "λ + Δλ); λ/h² is the force, N.");
  k.def("project_distance_jakobsen", [](py::handle p1, py::handle p2, double w1, double w2, double rest_length,
                                         double stiffness, const std::string& sense) {
    Vec3 a = to_vec3(p1, "p1"), b = to_vec3(p2, "p2");
    const Real c = project_distance_jakobsen(a.data(), b.data(), w1, w2, rest_length, stiffness, parse_sense(sense));
    return py::make_tuple(vec3_array(a), vec3_array(b), c);
  }, py::arg("p1"), py::arg("p2"), py::arg("w1"), py::arg("w2"), py::arg("rest_length"), py::arg("stiffness") = 1.0,
     py::arg("sense") = "==",
     "Jakobsen's stick without a square root (2001, §4): |d| ≈ (d·d + L²)/(2L), so the correction is "
     "(d·d - L²)/(d·d + L²) d shared by inverse mass and scaled by the stiffness. Returns (p1', p2', the "
     "approximate violation (d·d - L²)/(2L), m). (With square roots Jakobsen's stick is project_distance.)");
  k.def("project_bending", [](py::handle a, py::handle b, py::handle c, py::handle d, std::array<double, 4> w,
                              double rest_angle, double stiffness) {
    Vec3 p[4] = {to_vec3(a, "a"), to_vec3(b, "b"), to_vec3(c, "c"), to_vec3(d, "d")};
    const Real v = project_bending(p[0].data(), p[1].data(), p[2].data(), p[3].data(), w[0], w[1], w[2], w[3],
                                   rest_angle, stiffness);
    return py::make_tuple(vec3_array(p[0]), vec3_array(p[1]), vec3_array(p[2]), vec3_array(p[3]), v);
  }, py::arg("a"), py::arg("b"), py::arg("c"), py::arg("d"), py::arg("inv_mass"), py::arg("rest_angle"),
     py::arg("stiffness") = 1.0,
     "PBD's dihedral bending projection (Müller et al. 2007, Appendix A; the angle by atan2): C = θ - θ0 over "
     "the shared edge (a, b) with opposite vertices c and d, Δp_i = -k w_i C ∇_i C / Σ_j w_j |∇_j C|². "
     "Returns (a', b', c', d', violation before, rad).");
  k.def("project_bending_xpbd", [](py::handle a, py::handle b, py::handle c, py::handle d, std::array<double, 4> w,
                                   double rest_angle, double alpha_tilde, double lambda, double gamma, py::handle x) {
    Vec3 p[4] = {to_vec3(a, "a"), to_vec3(b, "b"), to_vec3(c, "c"), to_vec3(d, "d")};
    Vec3 x0[4] = {p[0], p[1], p[2], p[3]};
    if (!x.is_none()) {
      const auto rows = to_positions(x, "x");
      if (rows.cols() != 4) throw InvalidArgument("project_bending_xpbd: x must be the 4 start positions (4, 3), m");
      for (int k = 0; k < 4; ++k) x0[k] = rows.col(k);
    }
    const Real v = project_bending_xpbd(p[0].data(), p[1].data(), p[2].data(), p[3].data(), x0[0].data(), x0[1].data(),
                                        x0[2].data(), x0[3].data(), w[0], w[1], w[2], w[3], rest_angle, alpha_tilde,
                                        gamma, lambda);
    return py::make_tuple(vec3_array(p[0]), vec3_array(p[1]), vec3_array(p[2]), vec3_array(p[3]), v, lambda);
  }, py::arg("a"), py::arg("b"), py::arg("c"), py::arg("d"), py::arg("inv_mass"), py::arg("rest_angle"),
     py::arg("alpha_tilde"), py::arg("lambda_") = 0.0, py::arg("gamma") = 0.0, py::arg("x") = py::none(),
     "XPBD's dihedral bending projection: C = θ - θ0 over the shared edge (a, b) with opposite vertices c and d, "
     "Δλ = (-C - α̃λ - γ Σ ∇C·(p - x)) / ((1 + γ) Σ w |∇C|² + α̃), Δp_i = w_i ∇_i C Δλ; α̃ = α/h² (α in "
     "1/(N m)), γ the damping, x the (4, 3) start positions (default the given ones). Returns (a', b', c', d', "
     "violation before, rad, λ + Δλ).");
  k.def("project_attachment_xpbd", [](py::handle p, double w, py::handle target, double alpha_tilde, double lambda,
                                      double gamma, py::handle x) {
    Vec3 q = to_vec3(p, "p");
    const Vec3 t = to_vec3(target, "target"), x0 = x.is_none() ? q : to_vec3(x, "x");
    const Real v = project_attachment_xpbd(q.data(), x0.data(), w, t.data(), alpha_tilde, gamma, lambda);
    return py::make_tuple(vec3_array(q), v, lambda);
  }, py::arg("p"), py::arg("w"), py::arg("target"), py::arg("alpha_tilde"), py::arg("lambda_") = 0.0,
     py::arg("gamma") = 0.0, py::arg("x") = py::none(),
     "XPBD's attachment: C = |p - target|, Δλ = (-C - α̃λ - γ n·(p - x)) / ((1 + γ) w + α̃), Δp = w n Δλ; "
     "α̃ = α/h² (α in m/N). Returns (p', violation before, m, λ + Δλ).");
  k.def("project_attachment", [](py::handle p, double w, py::handle target, double stiffness) {
    Vec3 x = to_vec3(p, "p");
    const Vec3 t = to_vec3(target, "target");
    const Real v = project_attachment(x.data(), w, t.data(), stiffness);
    return py::make_tuple(vec3_array(x), v);
  }, py::arg("p"), py::arg("w"), py::arg("target"), py::arg("stiffness") = 1.0,
     "PBD's attachment (a particle held at a world point): C = |p - target|, Δp = -k C n for a particle that can "
     "move (w > 0). Returns (p', violation before, m).");
  k.def("additive_ccd", [](const std::string& kind, const Eigen::Matrix<double, 4, 3>& x,
                           const Eigen::Matrix<double, 4, 3>& dx, double separation, double thickness) {
    if (kind != "point-triangle" && kind != "edge-edge")
      throw InvalidArgument("additive_ccd: kind must be 'point-triangle' or 'edge-edge', got '" + kind + "'");
    if (!(separation > 0 && separation < 1)) throw InvalidArgument("additive_ccd: separation must be in (0, 1)");
    if (!(thickness >= 0) || !std::isfinite(thickness)) throw InvalidArgument("additive_ccd: thickness must be >= 0 m");
    if (!x.allFinite() || !dx.allFinite()) throw InvalidArgument("additive_ccd: x and dx must be finite");
    std::array<Vec3, 4> xs, ds;
    for (int i = 0; i < 4; ++i) xs[i] = x.row(i).transpose(), ds[i] = dx.row(i).transpose();
    const Impact m = additive_ccd(kind == "edge-edge" ? PairKind::EdgeEdge : PairKind::PointTriangle, xs, ds, separation,
                                  thickness);
    return py::make_tuple(m.hit, m.toi);
  }, py::arg("kind"), py::arg("x"), py::arg("dx"), py::arg("separation") = 0.1, py::arg("thickness") = 0.0,
     "Additive CCD (Li, Kaufman, Jiang 2021) of a pair moving from x to x + dx ((4, 3), m; point-triangle: the "
     "point then the triangle, edge-edge: the two edges' ends): (hit, toi), the first fraction of the motion at which "
     "the distance falls below thickness + separation (d(0) - thickness), conservatively.");
  k.def("tet_volume", [](py::handle a, py::handle b, py::handle c, py::handle d) {
    return tet_volume(to_vec3(a, "a"), to_vec3(b, "b"), to_vec3(c, "c"), to_vec3(d, "d"));
  }, py::arg("a"), py::arg("b"), py::arg("c"), py::arg("d"), "Signed volume (1/6)(b - a) x (c - a)·(d - a), m³.");
  k.def("tet_volume_gradient", [](py::handle a, py::handle b, py::handle c, py::handle d) {
    Vec3 g[4];
    tet_volume_gradient(to_vec3(a, "a"), to_vec3(b, "b"), to_vec3(c, "c"), to_vec3(d, "d"), g);
    py::array_t<double> out({4, 3});
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 3; ++j) out.mutable_at(i, j) = g[i][j];
    return out;
  }, py::arg("a"), py::arg("b"), py::arg("c"), py::arg("d"), "(4, 3) gradient of the signed volume, m².");
  k.def("project_volume", [](py::handle a, py::handle b, py::handle c, py::handle d, std::array<double, 4> w,
                             double rest_volume, double stiffness) {
    Vec3 p[4] = {to_vec3(a, "a"), to_vec3(b, "b"), to_vec3(c, "c"), to_vec3(d, "d")};
    const Real v = project_volume(p[0].data(), p[1].data(), p[2].data(), p[3].data(), w[0], w[1], w[2], w[3],
                                  rest_volume, stiffness);
    return py::make_tuple(vec3_array(p[0]), vec3_array(p[1]), vec3_array(p[2]), vec3_array(p[3]), v);
  }, py::arg("a"), py::arg("b"), py::arg("c"), py::arg("d"), py::arg("inv_mass"), py::arg("rest_volume"),
     py::arg("stiffness") = 1.0, "PBD: returns (a', b', c', d', violation V - V0 before projection, m³).");
  k.def("project_volume_xpbd", [](py::handle a, py::handle b, py::handle c, py::handle d, std::array<double, 4> w,
                                  double rest_volume, double alpha_tilde, double lambda) {
    Vec3 p[4] = {to_vec3(a, "a"), to_vec3(b, "b"), to_vec3(c, "c"), to_vec3(d, "d")};
    const Real v = project_volume_xpbd(p[0].data(), p[1].data(), p[2].data(), p[3].data(), p[0].data(), p[1].data(),
                                       p[2].data(), p[3].data(), w[0], w[1], w[2], w[3], rest_volume, alpha_tilde, 0,
                                       lambda);
    return py::make_tuple(vec3_array(p[0]), vec3_array(p[1]), vec3_array(p[2]), vec3_array(p[3]), v, lambda);
  }, py::arg("a"), py::arg("b"), py::arg("c"), py::arg("d"), py::arg("inv_mass"), py::arg("rest_volume"),
     py::arg("alpha_tilde"), py::arg("lambda_") = 0.0,
     "XPBD (no damping), α̃ = α/h² in m⁴/kg (α in m⁶/J): returns (a', b', c', d', violation, λ + Δλ).");
  k.def("enclosed_volume", [](py::handle points, py::handle triangles) {
    const Positions x = to_positions(points, "points");
    const auto tris = to_index_rows<3>(triangles, "triangles");
    std::vector<Index> ids(x.cols());
    for (Index i = 0; i < x.cols(); ++i) ids[i] = i;
    for (const auto& t : tris)
      for (Index i : t)
        if (i < 0 || i >= x.cols()) throw InvalidArgument("triangles: index " + std::to_string(i) + " out of range");
    return enclosed_volume(x.data(), ids.data(), tris.data(), static_cast<Index>(tris.size()));
  }, py::arg("points"), py::arg("triangles"), "(1/6) Σ (p_a x p_b)·p_c over the triangles, m³.");
  k.def("project_balloon", [](py::handle points, py::handle triangles, py::handle inv_mass, double target_volume,
                              double stiffness) {
    Positions x = to_positions(points, "points");
    const auto tris = to_index_rows<3>(triangles, "triangles");
    const auto wa = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(inv_mass);
    if (!wa || wa.ndim() != 1 || wa.shape(0) != x.cols())
      throw InvalidArgument("inv_mass must have shape (" + std::to_string(x.cols()) + ",), one entry (1/kg) per point");
    std::vector<Real> w(wa.data(), wa.data() + x.cols());
    std::vector<Index> ids(x.cols());
    for (Index i = 0; i < x.cols(); ++i) ids[i] = i;
    for (const auto& t : tris)
      for (Index i : t)
        if (i < 0 || i >= x.cols()) throw InvalidArgument("triangles: index " + std::to_string(i) + " out of range");
    std::vector<Vec3> grad(x.cols());
    const Index n = static_cast<Index>(x.cols());
    const Real v = project_balloon(x.data(), x.data(), nullptr, w.data(), ids.data(), n, tris.data(),
                                   static_cast<Index>(tris.size()), target_volume, stiffness, nullptr, 0, 0, nullptr,
                                   grad.data());
    py::array_t<double> out({static_cast<py::ssize_t>(n), py::ssize_t(3)});
    if (n) std::memcpy(out.mutable_data(), x.data(), sizeof(double) * 3 * n);
    return py::make_tuple(out, v);
  }, py::arg("points"), py::arg("triangles"), py::arg("inv_mass"), py::arg("target_volume"), py::arg("stiffness") = 1.0,
     "PBD balloon projection of a closed surface: returns (points', violation V - target before projection, m³).");
  k.def("atan2", [](py::handle y, py::handle x) {
    using A = py::array_t<double, py::array::c_style | py::array::forcecast>;
    const A ya = A::ensure(y), xa = A::ensure(x);
    if (!ya || !xa || ya.ndim() != 1 || xa.ndim() != 1 || ya.shape(0) != xa.shape(0))
      throw InvalidArgument("y and x must be 1-D arrays of one length");
    py::array_t<double> out(ya.shape(0));
    atan2_rational_array(ya.data(), xa.data(), out.mutable_data(), static_cast<Index>(ya.shape(0)));
    return out;
  }, py::arg("y"), py::arg("x"),
     "The coloured bending kernel's branch-free rational atan2 (csb/atan2.hpp), elementwise, rad.");
  k.def("kernel_isa", [](std::optional<std::string> isa) {
    if (isa) set_kernel_isa(*isa);
    return kernel_isa();
  }, py::arg("isa") = py::none(),
     "The instruction set of the blocked coloured kernels (bending; PBD distance): 'avx512', 'avx2' or 'sse2' (x86-64 "
     "portable build, the best the processor has; 'avx512' runs bending in AVX-512 and distance in AVX2), 'native' (a "
     "CSB_NATIVE build, or not x86-64). isa='sse2', 'avx2' or 'avx512' forces that copy (an error if the processor "
     "lacks it), 'auto' the processor's choice; returns the one in use.");
  k.def("project_bending_coloured", [](py::handle points, py::handle quads, py::handle inv_mass, py::handle rest_angle,
                                       py::handle stiffness, py::handle alpha_tilde, py::handle gamma, py::handle lambda_,
                                       py::handle start, bool independent) -> py::tuple {
    using A = py::array_t<double, py::array::c_style | py::array::forcecast>;
    Positions x = to_positions(points, "points");
    const Index n = static_cast<Index>(x.cols());
    ColouredFour b;
    b.q = to_index_rows<4>(quads, "quads");
    const std::size_t m = b.q.size();
    for (const auto& q : b.q)
      for (Index i : q)
        if (i < 0 || i >= n) throw InvalidArgument("quads: index " + std::to_string(i) + " out of range");
    if (n > kMostColouredParticles)
      throw InvalidArgument("points: " + std::to_string(n) + " of them; the coloured kernels address at most " +
                            std::to_string(kMostColouredParticles));
    for (auto& q : b.q)
      for (Index& i : q) i *= kStride<Real>;  // the batches' offsets (ColouredFourT::q)
    const auto column = [m](py::handle h, const char* what) {
      const A a = A::ensure(h);
      if (!a || a.ndim() != 1 || static_cast<std::size_t>(a.shape(0)) != m)
        throw InvalidArgument(std::string(what) + " must have shape (" + std::to_string(m) + ",)");
      return std::vector<Real>(a.data(), a.data() + m);
    };
    const A w = A::ensure(inv_mass);
    if (!w || w.ndim() != 2 || static_cast<std::size_t>(w.shape(0)) != m || w.shape(1) != 4)
      throw InvalidArgument("inv_mass must have shape (" + std::to_string(m) + ", 4)");
    b.w.resize(m);
    for (std::size_t c = 0; c < m; ++c)
      for (int s = 0; s < 4; ++s) b.w[c][s] = w.at(c, s);
    b.rest = column(rest_angle, "rest_angle");
    const bool xpbd = !alpha_tilde.is_none();
    Positions x0 = x;
    if (xpbd) {
      b.alpha = column(alpha_tilde, "alpha_tilde");
      b.gamma = gamma.is_none() ? std::vector<Real>(m, 0) : column(gamma, "gamma");
      b.lambda = lambda_.is_none() ? std::vector<Real>(m, 0) : column(lambda_, "lambda_");
      if (!start.is_none()) {
        x0 = to_positions(start, "start");
        if (x0.cols() != x.cols()) throw InvalidArgument("start must have the shape of points");
      }
    } else {
      b.k = stiffness.is_none() ? std::vector<Real>(m, 1) : column(stiffness, "stiffness");
    }
    project_bending_coloured(b, xpbd, independent, x.data(), x0.data());
    py::array_t<double> out({static_cast<py::ssize_t>(n), py::ssize_t(3)});
    if (n) std::memcpy(out.mutable_data(), x.data(), sizeof(double) * 3 * n);
    if (!xpbd) return py::make_tuple(out, py::none());
    return py::make_tuple(out, py::array_t<double>(static_cast<py::ssize_t>(m), b.lambda.data()));
  }, py::arg("points"), py::arg("quads"), py::arg("inv_mass"), py::arg("rest_angle"), py::arg("stiffness") = py::none(),
     py::arg("alpha_tilde") = py::none(), py::arg("gamma") = py::none(), py::arg("lambda_") = py::none(),
     py::arg("start") = py::none(), py::arg("independent") = true,
     "The stepper's coloured bending projection (csb/solver/coloured_bending.hpp) over quads (a, b, c, d) in order, "
     "Gauss-Seidel in place: SIMD blocks if independent (the quads must then share no point), else one at a time. "
     "PBD with stiffness (default 1), or XPBD if alpha_tilde is given (gamma, lambda_, start: damping, multipliers, "
     "sub-step start positions). Returns (points', lambda' or None).");
  k.def("dihedral_angle", [](py::handle a, py::handle b, py::handle c, py::handle d) {
    return dihedral_angle(to_vec3(a, "a"), to_vec3(b, "b"), to_vec3(c, "c"), to_vec3(d, "d"));
  }, py::arg("a"), py::arg("b"), py::arg("c"), py::arg("d"), "Signed dihedral angle across edge (a, b), rad.");
  k.def("dihedral_angle_gradient", [](py::handle a, py::handle b, py::handle c, py::handle d) -> py::object {
    Vec3 g[4];
    Real theta = 0;
    if (!dihedral_angle_and_gradient(to_vec3(a, "a"), to_vec3(b, "b"), to_vec3(c, "c"), to_vec3(d, "d"), theta, g))
      return py::none();
    py::array_t<double> out({4, 3});
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 3; ++j) out.mutable_at(i, j) = g[i][j];
    return std::move(out);
  }, py::arg("a"), py::arg("b"), py::arg("c"), py::arg("d"), "(4, 3) gradient, rad/m; None if degenerate.");
}

}  // namespace csb::python
