// csb viewer — an orbit camera: it looks at a target from a distance, at a yaw about the world's
// up axis (+y) and a pitch above the horizon. Orbit turns yaw and pitch, pan moves the target in
// the view plane, zoom scales the distance. Pixels count from the top-left corner of the image,
// x to the right and y down, as window systems report the cursor.
#pragma once

#include "csb/types.hpp"

#include <Eigen/Core>

namespace csb::viewer {

using Mat4 = Eigen::Matrix<double, 4, 4>;

struct Ray {
  Vec3 origin = Vec3::Zero();
  Vec3 direction = Vec3::UnitZ();  // unit
};

class Camera {
 public:
  Vec3 target = Vec3::Zero();    // m
  double distance = 3;           // m, > 0
  double yaw = 0;                // rad, 0: looking along -z
  double pitch = 0.35;           // rad, in (-π/2, π/2)
  double fov_y = 0.7854;         // rad, vertical field of view (45°)
  int width = 1280, height = 800;  // pixels of the image

  // Frames a bounding box (m): the target at its centre, far enough to see it whole.
  void frame(const Vec3& lo, const Vec3& hi);

  Vec3 eye() const;
  Vec3 forward() const;  // unit, from the eye to the target
  Vec3 right() const;    // unit
  Vec3 up() const;       // unit, the image's up
  Mat4 view() const;
  Mat4 projection() const;
  Mat4 view_projection() const { return projection() * view(); }

  // The ray through pixel (x, y) (fractional pixels allowed; the centre of pixel (i, j) is
  // (i + 0.5, j + 0.5)).
  Ray ray(double x, double y) const;
  // Where a world point lands in the image (pixels), and its depth along forward(); a point
  // behind the eye has depth <= 0.
  Eigen::Vector2d project(const Vec3& p, double* depth = nullptr) const;

  // Mouse gestures, in pixels of motion.
  void orbit(double dx, double dy);
  void pan(double dx, double dy);
  void zoom(double steps);  // > 0 moves closer

 private:
  double near_plane() const { return 0.01 * distance; }
  double far_plane() const { return 1000 * distance; }
};

}  // namespace csb::viewer
