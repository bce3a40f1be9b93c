// csb._core: constraint families written in Python (csb.ConstraintFamily). The family gives C and
// ∇C, vectorised over numpy arrays; this batch holds its constraints and projects them with the
// corrections every compiled family uses (constraints/family.hpp), so PBD, XPBD and Jakobsen, the
// references and the metrics take it as they take the built-in ones.
//
// A Gauss-Seidel sweep must see each correction before the next projection. The constraints are
// therefore coloured as they are added (first fit: no two of a colour share a particle, 64
// colours, then one constraint at a time), and a sweep evaluates one colour per call into
// Python, then corrects its constraints in order: the sweep is Gauss-Seidel in the order colour by
// colour, index within a colour. A Jacobi sweep reads the positions at its start, so one call
// evaluates every constraint. The evaluations take the GIL; the stepper runs a model holding such
// a family on one thread (FamilyInfo::serial_only), so what the family raises reaches the caller.
#include "bindings.hpp"

#include "csb/constraints/family.hpp"

#include <cmath>

namespace csb::python {

namespace {

// The family's evaluate, shared by the batch's copies (the model's, the builder's, Projective
// Dynamics' local one) without touching the Python object's count; released with the GIL.
using Callable = std::shared_ptr<py::object>;
Callable hold(py::object o) {
  return Callable(new py::object(std::move(o)), [](py::object* p) {
    if (Py_IsInitialized()) {
      py::gil_scoped_acquire gil;
      delete p;
    } else {
      p->release();  // the interpreter is gone: nothing to release into
      delete p;
    }
  });
}

std::unique_ptr<FamilyBatch> make_python_family(const Callable& evaluate, const FamilyInfo& base);

class PythonFamilyBatch final : public FamilyBatch {
 public:
  PythonFamilyBatch(Callable evaluate, std::shared_ptr<const FamilyInfo> info)
      : evaluate_(std::move(evaluate)), info_(std::move(info)) {}

  const FamilyInfo& info() const override { return *info_; }
  const Index* particle_data() const override { return particles_.empty() ? nullptr : particles_.data(); }
  const Real* param_data() const override { return params_.data(); }
  std::string check(const Real*) const override { return ""; }  // csb.ConstraintFamily.check runs in Python first
  std::unique_ptr<FamilyBatch> clone() const override { return std::make_unique<PythonFamilyBatch>(*this); }
  std::size_t bytes() const override {
    return particles_.capacity() * sizeof(Index) + params_.capacity() * sizeof(Real) +
           (stiffness.capacity() + compliance.capacity()) * sizeof(Real) + used_.capacity() * sizeof(std::uint64_t);
  }

  void append(const Index* ids, const Real* values, Real k, Real alpha) override {
    const int n = info_->arity;
    const Index c = size();
    particles_.insert(particles_.end(), ids, ids + n);
    params_.insert(params_.end(), values, values + info_->num_params());
    stiffness.push_back(k);
    compliance.push_back(alpha);
    // First fit: the lowest of 64 colours none of its particles has; else the serial list.
    std::uint64_t taken = 0;
    for (int j = 0; j < n; ++j) {
      if (static_cast<std::size_t>(ids[j]) >= used_.size()) used_.resize(static_cast<std::size_t>(ids[j]) + 1, 0);
      taken |= used_[ids[j]];
    }
    int colour = 64;
    for (int b = 0; b < 64; ++b)
      if (!(taken >> b & 1)) {
        colour = b;
        break;
      }
    if (colour < 64)
      for (int j = 0; j < n; ++j) used_[ids[j]] |= std::uint64_t(1) << colour;
    if (static_cast<int>(colours_.size()) <= colour) colours_.resize(static_cast<std::size_t>(colour) + 1);
    colours_[colour].push_back(c);
  }

  void sweep(const FamilySweep& s) const override {
    py::gil_scoped_acquire gil;
    const int n = info_->arity;
    std::vector<Real> c;
    std::vector<Vec3> g;
    if (s.jacobi) {
      evaluate_at(s.read, every(), c, g);
      std::vector<Real> local(static_cast<std::size_t>(3 * n));
      for (Index k = 0; k < size(); ++k) {
        for (int j = 0; j < n; ++j)
          for (int e = 0; e < 3; ++e) local[3 * j + e] = s.read[3 * static_cast<std::size_t>(particle(k, j)) + e];
        const Real om = correct(s, k, local.data(), c[static_cast<std::size_t>(k)], g.data() + static_cast<std::size_t>(k) * n);
        for (int j = 0; j < n; ++j) {
          const std::size_t i = static_cast<std::size_t>(particle(k, j));
          for (int e = 0; e < 3; ++e) s.out[3 * i + e] += om * (local[3 * j + e] - s.read[3 * i + e]);
          if (s.count) s.count[i] += 1;
        }
      }
      return;
    }
    for (std::size_t colour = 0; colour < colours_.size(); ++colour) {
      const std::vector<Index>& list = colours_[colour];
      // The serial list (colour 64) one constraint at a time: its constraints may share particles.
      const std::size_t step = colour == 64 ? 1 : list.size();
      for (std::size_t first = 0; first < list.size(); first += step) {
        const std::vector<Index> part(list.begin() + first, list.begin() + std::min(list.size(), first + step));
        evaluate_at(s.out, part, c, g);
        for (std::size_t q = 0; q < part.size(); ++q) correct(s, part[q], nullptr, c[q], g.data() + q * n);
      }
    }
  }

  void evaluate(const Real* x, Real* c, Real* grad) const override {
    std::vector<Real> cs;
    std::vector<Vec3> gs;
    evaluate_all(x, cs, gs);
    std::copy(cs.begin(), cs.end(), c);
    for (std::size_t k = 0; k < gs.size(); ++k)
      for (int e = 0; e < 3; ++e) grad[3 * k + e] = gs[k][e];
  }
  void violations(const Real* x, Real* v) const override {
    std::vector<Real> cs;
    std::vector<Vec3> gs;
    evaluate_all(x, cs, gs);
    for (std::size_t k = 0; k < cs.size(); ++k) v[k] = violation(cs[k]);
  }
  Real energy(const Real* x) const override {
    std::vector<Real> cs;
    std::vector<Vec3> gs;
    evaluate_all(x, cs, gs);
    Real e = 0;
    for (std::size_t k = 0; k < cs.size(); ++k)
      if (compliance[k] > 0) e += violation(cs[k]) * violation(cs[k]) / (2 * compliance[k]);
    return e;
  }
  void add_forces(const Real* x, Real* f) const override {
    std::vector<Real> cs;
    std::vector<Vec3> gs;
    evaluate_all(x, cs, gs);
    const int n = info_->arity;
    for (std::size_t k = 0; k < cs.size(); ++k) {
      const Real v = violation(cs[k]);
      if (!(compliance[k] > 0) || v == 0) continue;
      for (int j = 0; j < n; ++j)
        for (int e = 0; e < 3; ++e)
          f[3 * static_cast<std::size_t>(particle(static_cast<Index>(k), j)) + e] -= v / compliance[k] * gs[k * n + j][e];
    }
  }
  // The Gauss-Newton term -(1/α) ∇_i C ∇_j Cᵀ (a family written in Python gives no Hessian).
  void stiffness_blocks(const Real* x, Real* blocks) const override {
    std::vector<Real> cs;
    std::vector<Vec3> gs;
    evaluate_all(x, cs, gs);
    const int n = info_->arity;
    const std::size_t per = static_cast<std::size_t>(n) * n * 9;
    std::fill(blocks, blocks + per * cs.size(), 0.0);
    for (std::size_t k = 0; k < cs.size(); ++k) {
      if (!(compliance[k] > 0) || (info_->unilateral && !(cs[k] > 0))) continue;
      Real* out = blocks + per * k;
      for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j)
          for (int r = 0; r < 3; ++r)
            for (int q = 0; q < 3; ++q)
              out[(i * n + j) * 9 + 3 * r + q] = -gs[k * n + i][r] * gs[k * n + j][q] / compliance[k];
    }
  }

 private:
  Index particle(Index k, int j) const { return particles_[static_cast<std::size_t>(k) * info_->arity + j]; }
  Real violation(Real c) const { return info_->unilateral ? std::max(c, Real(0)) : c; }
  std::vector<Index> every() const {
    std::vector<Index> all(static_cast<std::size_t>(size()));
    for (Index k = 0; k < size(); ++k) all[static_cast<std::size_t>(k)] = k;
    return all;
  }
  // C and ∇C of every constraint at x, the GIL taken for the call (the references and metrics).
  void evaluate_all(const Real* x, std::vector<Real>& c, std::vector<Vec3>& g) const {
    py::gil_scoped_acquire gil;
    evaluate_at(x, every(), c, g);
  }

  // C and ∇C of the constraints `which` at positions x (3 per particle), from the family's
  // evaluate(x (M, arity, 3), params (M, P)) -> (C (M,), grad (M, arity, 3)). InvalidArgument,
  // naming the family and the constraint, for a result of the wrong shape or not finite.
  void evaluate_at(const Real* x, const std::vector<Index>& which, std::vector<Real>& c, std::vector<Vec3>& g) const {
    const int n = info_->arity, np = info_->num_params();
    const auto m = static_cast<py::ssize_t>(which.size());
    c.clear();
    g.clear();
    if (m == 0) return;
    py::array_t<Real> xs({m, py::ssize_t(n), py::ssize_t(3)});
    py::array_t<Real> ps({m, py::ssize_t(np)});
    Real* xd = xs.mutable_data();
    Real* pd = ps.mutable_data();
    for (py::ssize_t q = 0; q < m; ++q) {
      const Index k = which[static_cast<std::size_t>(q)];
      for (int j = 0; j < n; ++j)
        for (int e = 0; e < 3; ++e) xd[(q * n + j) * 3 + e] = x[3 * static_cast<std::size_t>(particle(k, j)) + e];
      for (int p = 0; p < np; ++p) pd[q * np + p] = params_[static_cast<std::size_t>(k) * np + p];
    }
    const std::string who = "constraint family '" + info_->name + "'";
    const py::object result = (*evaluate_)(xs, ps);
    py::tuple pair;
    if (!py::isinstance<py::tuple>(result) || (pair = result.cast<py::tuple>()).size() != 2)
      throw InvalidArgument(who + ": evaluate must return (C, grad), got " + py::repr(result).cast<std::string>());
    const auto ca = py::array_t<Real, py::array::c_style | py::array::forcecast>::ensure(pair[0]);
    const auto ga = py::array_t<Real, py::array::c_style | py::array::forcecast>::ensure(pair[1]);
    if (!ca || ca.ndim() != 1 || ca.shape(0) != m)
      throw InvalidArgument(who + ": evaluate must return C of shape (" + std::to_string(m) + ",) for " +
                            std::to_string(m) + " constraints");
    if (!ga || ga.ndim() != 3 || ga.shape(0) != m || ga.shape(1) != n || ga.shape(2) != 3)
      throw InvalidArgument(who + ": evaluate must return grad of shape (" + std::to_string(m) + ", " +
                            std::to_string(n) + ", 3) for " + std::to_string(m) + " constraints");
    c.assign(ca.data(), ca.data() + m);
    g.resize(static_cast<std::size_t>(m) * n);
    const Real* gd = ga.data();
    for (py::ssize_t q = 0; q < m * n; ++q) g[static_cast<std::size_t>(q)] = Vec3(gd[3 * q], gd[3 * q + 1], gd[3 * q + 2]);
    for (py::ssize_t q = 0; q < m; ++q) {
      bool finite = std::isfinite(c[static_cast<std::size_t>(q)]);
      for (int j = 0; j < n; ++j) finite = finite && g[static_cast<std::size_t>(q * n + j)].allFinite();
      if (!finite) {
        const Index k = which[static_cast<std::size_t>(q)];
        std::string ids;
        for (int j = 0; j < n; ++j) ids += (j ? ", " : "") + std::to_string(particle(k, j));
        throw InvalidArgument(who + ": " + info_->label + " " + std::to_string(k) + " (particles " + ids +
                              ") evaluated to a C or gradient that is not finite");
      }
    }
  }

  // Projects constraint k from its C and gradient g: in place on s.out (Gauss-Seidel, at = null) or
  // on `at` (Jacobi's local copy, 3 per particle). Returns its relaxation (XPBD's averaged Jacobi).
  Real correct(const FamilySweep& s, Index k, Real* at, Real c, const Vec3* g) const {
    const int n = info_->arity;
    std::vector<Real*> p(static_cast<std::size_t>(n));
    std::vector<const Real*> x0(static_cast<std::size_t>(n));
    std::vector<Real> w(static_cast<std::size_t>(n));
    for (int j = 0; j < n; ++j) {
      const std::size_t i = static_cast<std::size_t>(particle(k, j));
      p[j] = at ? at + 3 * j : s.out + 3 * i;
      x0[j] = s.x_start ? s.x_start + 3 * i : nullptr;
      w[j] = s.w[i];
    }
    const Real v = violation(c);
    if (!s.xpbd) {
      if (v != 0) family_correct_pbd(p.data(), w.data(), g, n, v, s.k[k]);
      return 1;
    }
    Real om = 1;
    if (s.relax)
      for (int j = 0; j < n; ++j) om = std::min(om, s.relax[particle(k, j)]);
    Real& lambda = s.lambda[k];
    if (info_->unilateral && v == 0 && lambda == 0) return om;  // slack, and nothing to give back
    const Real before = lambda;
    family_correct_xpbd(p.data(), x0.data(), w.data(), g, n, c, info_->unilateral, s.alpha[k], s.gamma[k], lambda);
    if (s.relax) lambda = before + om * (lambda - before);
    return om;
  }

  Callable evaluate_;
  std::shared_ptr<const FamilyInfo> info_;
  std::vector<Index> particles_;
  std::vector<Real> params_;
  std::vector<std::vector<Index>> colours_;  // constraint indices per colour; [64]: one at a time
  std::vector<std::uint64_t> used_;          // per particle: the colours it is in
};

// A family's empty batch; its info's make() gives another (Projective Dynamics' local copy).
std::unique_ptr<FamilyBatch> make_python_family(const Callable& evaluate, const FamilyInfo& base) {
  auto info = std::make_shared<FamilyInfo>(base);
  info->serial_only = true;
  info->has_hessian = false;
  info->make = [evaluate, base] { return make_python_family(evaluate, base); };
  return std::make_unique<PythonFamilyBatch>(evaluate, std::move(info));
}

}  // namespace

void bind_family(py::module_& m) {
  m.def("_add_python_family", [](ModelBuilder& b, py::object evaluate, const std::string& name, const std::string& label,
                                    int arity, const std::vector<std::string>& param_names,
                                    const std::vector<std::string>& param_units, bool unilateral,
                                    const std::string& compliance_unit) {
        if (arity < 1 || arity > 1 << 20) throw InvalidArgument("constraint family '" + name + "': arity must be >= 1");
        if (param_units.size() != param_names.size())
          throw InvalidArgument("constraint family '" + name + "': a unit per parameter");
        FamilyInfo info;
        info.name = name;
        info.label = label;
        info.arity = arity;
        info.param_names = param_names;
        info.param_units = param_units;
        info.unilateral = unilateral;
        info.compliance_unit = compliance_unit;
        b.add_family(make_python_family(hold(std::move(evaluate)), info));
      }, py::arg("builder"), py::arg("evaluate"), py::arg("name"), py::arg("label"), py::arg("arity"),
        py::arg("param_names"), py::arg("param_units"), py::arg("unilateral"), py::arg("compliance_unit"),
        "Registers a constraint family written in Python with the builder (csb.ModelBuilder.add_family).");
}

}  // namespace csb::python
