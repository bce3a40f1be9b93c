// Integer parameters of the bindings. Python's int has no size, the C++ ones do (Index is 32 bits):
// a binding takes an integer parameter as an IntArg (whatever Python object was passed) and narrows
// it with in_range, so that 2**40 or -1 where a count belongs is a csb.ParameterError naming the
// parameter and its allowed range, never pybind11's TypeError (no overload matched) or a value
// wrapped round on the way to C++.
#pragma once

#include "csb/types.hpp"

#include <pybind11/pybind11.h>

#include <cstdint>
#include <limits>
#include <string>

namespace csb::python {

struct IntArg {
  pybind11::object value;
};

// The largest particle, constraint, group or element index and count (Index is int32).
inline constexpr long long kMaxIndex = std::numeric_limits<Index>::max();
inline constexpr long long kMaxInt64 = std::numeric_limits<std::int64_t>::max();

// v as an integer in [lo, hi] (int, bool, numpy integers: anything with __index__), else
// InvalidArgument "<name> must be an integer in [lo, hi], got <repr>". [lo, hi] must fit in T.
template <class T = Index>
T in_range(const IntArg& v, const std::string& name, long long lo, long long hi) {
  long long x = 0;
  bool ok = false;
  if (PyObject* i = PyNumber_Index(v.value.ptr())) {
    int overflow = 0;
    x = PyLong_AsLongLongAndOverflow(i, &overflow);
    ok = overflow == 0 && !(x == -1 && PyErr_Occurred());
    Py_DECREF(i);
  }
  PyErr_Clear();
  if (!ok || x < lo || x > hi)
    throw InvalidArgument(name + " must be an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) +
                          "], got " + std::string(pybind11::repr(v.value)));
  return static_cast<T>(x);
}

}  // namespace csb::python

namespace pybind11::detail {
// Any object loads (the range check, with the parameter's name, is in_range's); signatures show int.
template <>
struct type_caster<csb::python::IntArg> {
  PYBIND11_TYPE_CASTER(csb::python::IntArg, const_name("int"));
  bool load(handle src, bool) {
    if (!src) return false;
    value.value = reinterpret_borrow<object>(src);
    return true;
  }
  static handle cast(const csb::python::IntArg& v, return_value_policy, handle) { return v.value.inc_ref(); }
};
}  // namespace pybind11::detail
