// csb — the constraint families by name. Every family is one header in this folder (its C, ∇C and
// parameters, family.hpp) and one line in families.cpp's list; the Model holds one batch per
// family in the list's order, and the stepper, the references, the metrics, the material notes,
// the bindings and the scene files find them here.
#pragma once

#include "csb/constraints/family.hpp"

#include <string>
#include <vector>

namespace csb {

// Every family, in the order of families.cpp's list (the order of Model::families).
const std::vector<const FamilyInfo*>& families();
// Position in families() of the family of that name; InvalidArgument naming the known ones.
Index family_index(const std::string& name);

}  // namespace csb
