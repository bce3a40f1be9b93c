// csb._core's viewer bindings, compiled when the viewer is built.
#pragma once

#include <pybind11/pybind11.h>

void bind_viewer(pybind11::module_& m);
