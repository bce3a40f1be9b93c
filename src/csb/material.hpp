// csb — which form of a constraint's material each method reads, and what a method would
// otherwise change without a word.
//
// Every constraint carries a PBD stiffness k ∈ [0, 1] (dimensionless) and a compliance α >= 0
// (m/N for distance constraints and attachments, 1/(N m) for bending, m⁶/J for volumes and
// balloons; model.hpp). PBD and Jakobsen read k only; XPBD (and small steps), the force-based
// integrators and the reference read α only. A material is declared in one form or in both:
//
//   k = 1, α = 0   rigid for every method;
//   k < 1, α > 0   both forms: each method reads its own, nothing to say;
//   k = 1, α > 0   compliance only: PBD and Jakobsen ignore α and make the constraint rigid;
//   k < 1, α = 0   stiffness only: XPBD ignores k and makes the constraint rigid (the reference
//                  and the force-based integrators refuse it by name: a hard constraint has no
//                  potential C²/(2α)).
//
// material_notes names, per constraint family, the constraints a position-based method would
// make rigid against what was declared; the Python binding turns each note into a
// csb.MaterialWarning the first time a stepper steps a model, the viewer shows it when the
// method is switched.
#pragma once

#include "csb/model.hpp"

#include <string>
#include <vector>

namespace csb {

enum class Method;  // pbd.hpp

struct MaterialNote {
  std::string family;   // "distance", "bending", "volume", "balloon", "attachment" or a family's name ("tethers")
  Index count = 0;      // constraints of the family whose declared form the method ignores
  Real ignored_min = 0, ignored_max = 0;  // range of the ignored values (k, or α in SI units)
  Real used = 0;        // the value read instead: k = 1 (PBD, Jakobsen) or α = 0 (XPBD)
  std::string message;  // one sentence naming the method, family, count, values and the remedy
};

// The method's name in messages: "PBD", "XPBD" or "Jakobsen".
const char* method_label(Method method);

// One note per constraint family (in the order distance, bending, volume, balloon, attachment,
// then Model::families)
// that has constraints `method` would make rigid against their declared material: for PBD and
// Jakobsen those with α > 0 and k = 1, for XPBD those with k < 1 and α = 0. Empty when the
// method reads every constraint as declared.
std::vector<MaterialNote> material_notes(const Model& model, Method method);

}  // namespace csb
