// csb — moving colliders and attachments: the position-based stepper owns a rigid pose per
// collider (the Model stays immutable), interpolated over the sub-steps of a step like a kinematic
// grab's hand, and for a deforming mesh collider its vertices, interpolated linearly; contacts
// are generated along the particle's motion relative to the collider (collision.hpp), and
// attached particles follow the pose, or on a deforming mesh their triangle.
#include "csb/pbd.hpp"
#include "csb/format.hpp"
#include "csb/step/internal.hpp"

#include <cmath>

namespace csb {

using detail::str;

ColliderPose interpolate_pose(const ColliderPose& from, const ColliderPose& to, Real fraction) {
  if (fraction <= 0) return from;
  if (fraction >= 1) return to;
  ColliderPose out;
  out.translation = from.translation + fraction * (to.translation - from.translation);
  if (from.rotation == to.rotation) {
    out.rotation = from.rotation;
  } else {
    const Eigen::Quaternion<Real> a(from.rotation), b(to.rotation);
    out.rotation = a.normalized().slerp(fraction, b.normalized()).toRotationMatrix();
  }
  return out;
}

void validate_pose(const Mat3& rotation, const Vec3& translation, const std::string& what) {
  if (!rotation.allFinite()) throw InvalidArgument(what + ": rotation must be finite");
  if (!translation.allFinite()) throw InvalidArgument(what + ": translation must be finite (m), got " + str(translation));
  const Real orth = (rotation.transpose() * rotation - Mat3::Identity()).cwiseAbs().maxCoeff();
  const Real det = rotation.determinant();
  if (!(orth <= kRotationTolerance) || !(std::abs(det - 1) <= kRotationTolerance))
    throw InvalidArgument(what + ": rotation must be a rotation matrix (|RᵀR - I| and |det R - 1| at most " +
                          str(kRotationTolerance) + "), got |RᵀR - I| = " + str(orth) + ", det R = " + str(det));
}

bool generate_moving_contact(const Collider& c, const ColliderPose& A, const ColliderPose& B, Index collider_index,
                             Index i, const Vec3& x, const Vec3& p, Real r, Real margin, Real h,
                             std::vector<Contact>& out, std::vector<std::uint32_t>& stamps, std::uint32_t& stamp) {
  if (!generate_contact(c, collider_index, i, A.to_model(x), B.to_model(p), r, margin, h, out, stamps, stamp))
    return false;
  Contact& k = out.back();
  // Where the contact holds the particle, q + r n, in the model frame: a particle that does not
  // slide moves with this point of the collider's frame (with q instead, a cloth of thickness r
  // on a sphere of radius R turning at ω turned at ω R/(R + r)).
  const Vec3 held = k.point + k.thickness * k.normal;
  k.point = B.to_world(k.point);
  k.normal = B.rotation * k.normal;
  k.surface_motion = B.to_world(held) - A.to_world(held);
  return true;
}

namespace {

const Collider& collider_at(const Model& model, Index collider, const char* what) {
  const Index n = static_cast<Index>(model.colliders.size());
  if (collider < 0 || collider >= n)
    throw InvalidArgument(std::string(what) + ": collider " + std::to_string(collider) + " is out of range (the model has " +
                          std::to_string(n) + " colliders)");
  return model.colliders[collider];
}

}  // namespace

// The poses are sized to the model's colliders on first use; another model with a different
// number of colliders is an error (the poses would not mean anything for it).
void PbdStepper::size_collider_motion(const Model& model, const char* what) {
  const std::size_t n = model.colliders.size();
  if (collider_motion_.empty()) collider_motion_.resize(n);
  if (collider_motion_.size() != n)
    throw InvalidArgument(std::string(what) + ": this stepper holds poses for " + std::to_string(collider_motion_.size()) +
                          " colliders, but the model has " + std::to_string(n));
}

void PbdStepper::move_collider(const Model& model, Index collider, const Mat3& rotation, const Vec3& translation) {
  const UseGuard::Scope in_use(use_, "PbdStepper.move_collider");
  const Collider& c = collider_at(model, collider, "move_collider");
  validate_pose(rotation, translation, "move_collider: collider " + std::to_string(collider) + " ('" + c.name + "')");
  size_collider_motion(model, "move_collider");
  ColliderMotion& m = collider_motion_[collider];
  m.to.rotation = rotation;
  m.to.translation = translation;
}

void PbdStepper::deform_collider(const Model& model, Index collider, const Positions& vertices) {
  const UseGuard::Scope in_use(use_, "PbdStepper.deform_collider");
  const Collider& c = collider_at(model, collider, "deform_collider");
  const std::string what = "deform_collider: collider " + std::to_string(collider) + " ('" + c.name + "')";
  if (c.kind != ColliderKind::Mesh)
    throw InvalidArgument(what + " is a " + kind_name(c.kind) + ": only a mesh collider deforms (move_collider moves any collider rigidly)");
  validate_collider_vertices(*c.mesh, vertices, what);
  size_collider_motion(model, "deform_collider");
  DeformingMesh& d = collider_motion_[collider].deform;
  if (!d.active()) d.from = c.mesh->vertices;  // the first deformation starts from the model's shape
  d.to = vertices;
}

Positions PbdStepper::collider_vertices(const Model& model, Index collider) const {
  const Collider& c = collider_at(model, collider, "collider_vertices");
  if (c.kind != ColliderKind::Mesh)
    throw InvalidArgument("collider_vertices: collider " + std::to_string(collider) + " ('" + c.name + "') is a " +
                          kind_name(c.kind) + ", not a mesh");
  if (collider < static_cast<Index>(collider_motion_.size()) && collider_motion_[collider].deform.active())
    return collider_motion_[collider].deform.from;
  return c.mesh->vertices;
}

ColliderPose PbdStepper::collider_pose(Index collider) const {
  if (collider < 0) throw InvalidArgument("collider_pose: collider " + std::to_string(collider) + " is out of range");
  if (collider >= static_cast<Index>(collider_motion_.size())) return {};
  return collider_motion_[collider].from;
}

void PbdStepper::attach(const Model& model, const State& state, Index collider, const std::vector<Index>& particles) {
  const UseGuard::Scope in_use(use_, "PbdStepper.attach");
  const Collider& c = collider_at(model, collider, "attach");
  if (state.x.cols() != model.num_particles()) throw InvalidArgument("attach: the state does not belong to the model");
  size_collider_motion(model, "attach");
  for (std::size_t k = 0; k < particles.size(); ++k) {
    const Index i = particles[k];
    if (i < 0 || i >= model.num_particles())
      throw InvalidArgument("attach: particle " + std::to_string(i) + " is out of range (the model has " +
                            std::to_string(model.num_particles()) + " particles)");
    for (std::size_t j = 0; j < k; ++j)
      if (particles[j] == i) throw InvalidArgument("attach: particle " + std::to_string(i) + " is listed twice");
    for (const Grab& g : grabs_)
      if (g.particle == i)
        throw InvalidArgument("attach: particle " + std::to_string(i) + " is already held (" +
                              (g.handle < 0 ? "attached to a collider" : "grab " + std::to_string(g.handle)) + ")");
  }
  const ColliderPose& now = collider_motion_[collider].from;  // where the collider is in `state`
  const DeformingMesh& deform = collider_motion_[collider].deform;
  for (const Index i : particles) {
    ColliderAttachment a;
    a.collider = collider;
    a.particle = i;
    a.local = now.to_model(state.x.col(i));
    if (c.kind == ColliderKind::Mesh) {
      a.triangle = triangle_frame(deform.active() ? deform.from : c.mesh->vertices, c.mesh->triangles, a.local, a.frame);
      if (a.triangle < 0)
        throw InvalidArgument("attach: collider " + std::to_string(collider) + " ('" + c.name +
                              "'): every triangle of the mesh is degenerate now; no triangle to hold particle " +
                              std::to_string(i));
    }
    a.handle = next_attachment_--;
    Grab g;  // kinematic: inverse mass 0 while attached, as a grab of compliance 0
    g.handle = a.handle;
    g.particle = i;
    g.target = g.from = state.x.col(i);
    g.pinned = model.inv_mass[i] == 0;
    grabs_.push_back(g);
    attachments_.push_back(a);
  }
}

void PbdStepper::detach(Index collider, const std::vector<Index>& particles) {
  const UseGuard::Scope in_use(use_, "PbdStepper.detach");
  for (const Index i : particles) {
    bool found = false;
    for (const ColliderAttachment& a : attachments_) found = found || (a.collider == collider && a.particle == i);
    if (!found)
      throw InvalidArgument("detach: particle " + std::to_string(i) + " is not attached to collider " +
                            std::to_string(collider));
  }
  std::vector<ColliderAttachment> kept;
  for (const ColliderAttachment& a : attachments_) {
    const bool drop = a.collider == collider &&
                      (particles.empty() || std::find(particles.begin(), particles.end(), a.particle) != particles.end());
    if (!drop) {
      kept.push_back(a);
      continue;
    }
    for (std::size_t g = 0; g < grabs_.size(); ++g)
      if (grabs_[g].handle == a.handle) {
        if (grabs_[g].pinned) stop_.push_back(a.particle);
        grabs_.erase(grabs_.begin() + static_cast<std::ptrdiff_t>(g));
        break;
      }
  }
  attachments_ = std::move(kept);
}

// The poses at the start and end of sub-step `sub`, and the attached particles' predictions
// (after the grabs' targets, so an attachment overrides the straight line of its grab).
void PbdStepper::move_colliders(const Model& model, int sub) {
  if (collider_motion_.size() != model.colliders.size())
    throw InvalidArgument("step: this stepper holds poses for " + std::to_string(collider_motion_.size()) +
                          " colliders, but the model has " + std::to_string(model.colliders.size()));
  const Real s0 = Real(sub) / settings_.substeps, s1 = Real(sub + 1) / settings_.substeps;
  for (std::size_t c = 0; c < collider_motion_.size(); ++c) {
    ColliderMotion& m = collider_motion_[c];
    m.moving = !(m.from.identity() && m.to.identity());
    if (m.moving) {
      m.start = interpolate_pose(m.from, m.to, s0);
      m.end = interpolate_pose(m.from, m.to, s1);
    }
    if (m.deform.active()) deform_substep(model.colliders[c], m, sub, s0, s1);
  }
  for (const ColliderAttachment& a : attachments_) {
    if (a.particle >= model.num_particles())
      throw InvalidArgument("attachment of particle " + std::to_string(a.particle) + " to collider " +
                            std::to_string(a.collider) + ": this model has " + std::to_string(model.num_particles()) +
                            " particles");
    const ColliderMotion& m = collider_motion_[a.collider];
    if (m.deform.active())  // on the skin: its triangle's frame at the end of the sub-step
      p_.col(a.particle) = from_triangle_frame(m.deform.end, model.colliders[a.collider].mesh->triangles[a.triangle], a.frame);
    else
      p_.col(a.particle) = m.moving ? m.end.to_world(a.local) : a.local;
  }
}

namespace {

// A mesh's vertices `fraction` of the way from `from` to `to` (model frame), exactly `to` at 1,
// carried to the world by `pose` (if moved).
void deformed_vertices(const Positions& from, const Positions& to, Real fraction, bool moved, const ColliderPose& pose,
                       Positions& out) {
  if (fraction >= 1)
    out = to;
  else
    out = from + fraction * (to - from);
  if (moved)
    for (Index v = 0; v < out.cols(); ++v) out.col(v) = pose.to_world(Vec3(out.col(v)));
}

}  // namespace

// A deforming collider's vertices at the sub-step's start and end (world) and the grid over its
// swept triangles. Unless the pose turns, every vertex moves on one straight line over the whole
// step (interpolated vertices plus a linearly interpolated translation), so the grid over the
// triangles swept from the step's start to its end covers every sub-step: it is built at the
// first sub-step only. A turning pose bends the paths: the grid is then rebuilt each sub-step
// over the sub-step's sweep. (Its cost: docs/design.md.)
void PbdStepper::deform_substep(const Collider& c, ColliderMotion& m, int sub, Real s0, Real s1) {
  DeformingMesh& d = m.deform;
  deformed_vertices(d.from, d.to, s0, m.moving, m.start, d.start);
  deformed_vertices(d.from, d.to, s1, m.moving, m.end, d.end);
  const bool turning = m.moving && m.from.rotation != m.to.rotation;
  if (sub > 0 && !turning) return;
  const Positions* b = &d.end;
  if (!turning && settings_.substeps > 1) {
    deformed_vertices(d.from, d.to, 1, m.moving, m.to, d.step_end);
    b = &d.step_end;
  }
  const Positions& a = d.start;
  const std::vector<Triangle>& tris = c.mesh->triangles;
  deform_lo_.resize(tris.size());
  deform_hi_.resize(tris.size());
  for (std::size_t t = 0; t < tris.size(); ++t) {
    Vec3 lo = a.col(tris[t][0]), hi = lo;
    for (int k = 0; k < 3; ++k) {
      lo = lo.cwiseMin(a.col(tris[t][k])).cwiseMin(b->col(tris[t][k]));
      hi = hi.cwiseMax(a.col(tris[t][k])).cwiseMax(b->col(tris[t][k]));
    }
    deform_lo_[t] = lo;
    deform_hi_[t] = hi;
  }
  build_box_grid(deform_lo_, deform_hi_, d.grid);
}

// The end of a step: the poses reached become the next step's start. A collider can carry a
// particle at the speed of its frame there, and throw it at up to twice that (restitution 1), so
// the divergence guard counts the fastest speed of a moving collider's frame at the particles
// (m/s, over this step) with the speeds it started from.
void PbdStepper::end_collider_motion(const Model& model, const State& state) {
  Real fastest = 0;
  for (ColliderMotion& m : collider_motion_) {
    if (!(m.from.identity() && m.to.identity()))
      for (Index i = 0; i < model.num_particles(); ++i) {
        const Vec3 local = m.to.to_model(state.x.col(i));
        fastest = std::max(fastest, (m.to.to_world(local) - m.from.to_world(local)).norm());
      }
    DeformingMesh& d = m.deform;
    if (d.active()) {  // a deforming mesh's surface moves at most as fast as its fastest vertex
      for (Index v = 0; v < d.to.cols(); ++v)
        fastest = std::max(fastest, (m.to.to_world(Vec3(d.to.col(v))) - m.from.to_world(Vec3(d.from.col(v)))).norm());
      d.from = d.to;
    }
    m.from = m.to;
  }
  guard_v0_ = std::max(guard_v0_, 2 * fastest / settings_.dt);
}

}  // namespace csb
