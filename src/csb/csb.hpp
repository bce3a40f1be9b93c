// csb — cloth and soft-body dynamics with Position Based Dynamics. One header for everything.
#pragma once

#include "csb/build_info.hpp"
#include "csb/constraints/families.hpp"
#include "csb/io.hpp"
#include "csb/mesh.hpp"
#include "csb/metrics.hpp"
#include "csb/model.hpp"
#include "csb/material.hpp"
#include "csb/pbd.hpp"
#include "csb/reference.hpp"
#include "csb/force.hpp"
#include "csb/interaction/pick.hpp"
#include "csb/methods/registry.hpp"
#include "csb/tearing.hpp"
#include "csb/shapes.hpp"
#include "csb/tetmesh.hpp"
#include "csb/types.hpp"
