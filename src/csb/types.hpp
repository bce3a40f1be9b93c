// csb — basic types and the exceptions thrown at the API boundary.
//
// Units are SI throughout: metres, kilograms, seconds, radians.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace csb {

using Real = double;
using Index = std::int32_t;
using Vec3 = Eigen::Matrix<Real, 3, 1>;
using Mat3 = Eigen::Matrix<Real, 3, 3>;

// One column per particle, column-major: particle i's x, y, z are contiguous, which is both the
// gather a constraint kernel wants and the (N, 3) C-contiguous layout numpy views without a copy.
using Positions = Eigen::Matrix<Real, 3, Eigen::Dynamic>;

using Edge = std::array<Index, 2>;
using Triangle = std::array<Index, 3>;

// Base of every error csb raises on purpose. Messages name the file, element or parameter.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// An impossible parameter (dt <= 0, stiffness outside [0, 1], an index out of range, ...).
class InvalidArgument : public Error {
 public:
  using Error::Error;
};

// A mesh that cannot be used: corrupt, empty, non-finite coordinates, bad indices.
class MeshError : public Error {
 public:
  using Error::Error;
};

// A path that does not exist (becomes FileNotFoundError in Python).
class FileNotFound : public MeshError {
 public:
  using MeshError::MeshError;
};

// A simulation that produced a non-finite quantity; names the step and the particle.
class SimulationError : public Error {
 public:
  using Error::Error;
};

// An object used from two threads at once where it allows one (a stepper: see UseGuard).
class ConcurrentUse : public Error {
 public:
  using Error::Error;
};

// A step stopped because its caller asked (PbdStepper::step's interrupt: Ctrl-C in Python); the
// state is left at the end of the last completed sub-step.
class Interrupted : public Error {
 public:
  using Error::Error;
};

}  // namespace csb
