#include "csb/material.hpp"
#include "csb/pbd.hpp"
#include "csb/methods/registry.hpp"

#include <algorithm>
#include <sstream>

namespace csb {

namespace {

// 2046 -> "2,046": counts are read by people.
std::string grouped(Index n) {
  std::string digits = std::to_string(n), out;
  for (std::size_t i = 0; i < digits.size(); ++i) {
    if (i > 0 && (digits.size() - i) % 3 == 0) out += ',';
    out += digits[i];
  }
  return out;
}

std::string number(Real v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

std::string range(Real lo, Real hi) { return lo == hi ? number(lo) : number(lo) + " to " + number(hi); }

// One family: the constraints whose declared form the method ignores, as a note (none: count 0).
MaterialNote check(const char* family, const char* label, const char* unit, const std::vector<Real>& stiffness,
                   const std::vector<Real>& compliance, Method method) {
  const bool reads_compliance = method == Method::Xpbd;
  MaterialNote note;
  note.family = family;
  note.used = reads_compliance ? 0 : 1;
  for (std::size_t c = 0; c < stiffness.size(); ++c) {
    const Real k = stiffness[c], a = compliance[c];
    const bool ignored = reads_compliance ? (k < 1 && a == 0) : (a > 0 && k == 1);
    if (!ignored) continue;
    const Real v = reads_compliance ? k : a;
    note.ignored_min = note.count == 0 ? v : std::min(note.ignored_min, v);
    note.ignored_max = note.count == 0 ? v : std::max(note.ignored_max, v);
    ++note.count;
  }
  if (note.count == 0) return note;
  const std::string name = method_label(method);
  const bool one = note.count == 1;
  std::ostringstream m;
  m << name << (reads_compliance ? " reads compliance, not stiffness: " : " reads stiffness, not compliance: ")
    << grouped(note.count) << " " << label << (one ? " constraint has " : " constraints have ");
  if (reads_compliance)
    m << "stiffness " << range(note.ignored_min, note.ignored_max) << " and compliance 0";
  else
    m << "compliance " << range(note.ignored_min, note.ignored_max) << " " << unit << " and stiffness 1";
  m << ", so " << name << " makes " << (one ? "it" : "them") << " rigid; ";
  if (reads_compliance)
    m << "give a compliance (" << unit << ") to choose " << name << "'s material";
  else
    m << "give a stiffness below 1 to choose " << name << "'s material";
  note.message = m.str();
  return note;
}

}  // namespace

const char* method_label(Method method) { return method_info(method).label.c_str(); }

std::vector<MaterialNote> material_notes(const Model& model, Method method) {
  std::vector<MaterialNote> notes;
  const auto add = [&](MaterialNote note) {
    if (note.count > 0) notes.push_back(std::move(note));
  };
  add(check("distance", "distance (stretch)", "m/N", model.distance.stiffness, model.distance.compliance, method));
  add(check("bending", "bending", "1/(N m)", model.bending.stiffness, model.bending.compliance, method));
  add(check("volume", "volume", "m⁶/J", model.volume.stiffness, model.volume.compliance, method));
  add(check("balloon", "balloon", "m⁶/J", model.balloons.stiffness, model.balloons.compliance, method));
  add(check("attachment", "attachment", "m/N", model.attachments.stiffness, model.attachments.compliance, method));
  for (const auto& f : model.families) {
    const FamilyInfo& info = f->info();
    add(check(info.name.c_str(), info.label.c_str(), info.compliance_unit.c_str(), f->stiffness, f->compliance, method));
  }
  return notes;
}

// PbdStepper's side (declared in pbd.hpp): each model is checked once per stepper.
std::vector<MaterialNote> PbdStepper::material_notes_to_report(const Model& model) const {
  if (reported_models_.count(model.id)) return {};
  return material_notes(model, settings_.method);
}

}  // namespace csb
