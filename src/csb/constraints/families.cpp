// csb — the list of constraint families: one line per family header.
#include "csb/constraints/families.hpp"

#include "csb/constraints/tether.hpp"

namespace csb {

const std::vector<const FamilyInfo*>& families() {
  static const std::vector<const FamilyInfo*> list = {
      &family_info<Tether>(),
  };
  return list;
}

Index family_index(const std::string& name) {
  std::string known;
  const auto& list = families();
  for (std::size_t f = 0; f < list.size(); ++f) {
    if (list[f]->name == name) return static_cast<Index>(f);
    known += (known.empty() ? "'" : ", '") + list[f]->name + "'";
  }
  throw InvalidArgument("family must be one of " + known + ", got '" + name + "'");
}

}  // namespace csb
