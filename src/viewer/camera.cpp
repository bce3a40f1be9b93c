#include "viewer/camera.hpp"

#include <algorithm>
#include <cmath>

namespace csb::viewer {

namespace {
constexpr double kPitchLimit = 1.55;  // rad, just short of the pole, where yaw would be undefined
}

void Camera::frame(const Vec3& lo, const Vec3& hi) {
  target = 0.5 * (lo + hi);
  const double radius = std::max(0.5 * (hi - lo).norm(), 1e-3);
  const double half = 0.5 * std::min(fov_y, fov_y * width / std::max(height, 1));
  distance = 1.15 * radius / std::sin(half);
}

Vec3 Camera::forward() const {
  return Vec3(-std::cos(pitch) * std::sin(yaw), -std::sin(pitch), -std::cos(pitch) * std::cos(yaw));
}

Vec3 Camera::eye() const { return target - distance * forward(); }

Vec3 Camera::right() const { return forward().cross(Vec3::UnitY()).normalized(); }

Vec3 Camera::up() const { return right().cross(forward()); }

Mat4 Camera::view() const {
  const Vec3 f = forward(), r = right(), u = up(), e = eye();
  Mat4 v = Mat4::Identity();
  v.block<1, 3>(0, 0) = r.transpose();
  v.block<1, 3>(1, 0) = u.transpose();
  v.block<1, 3>(2, 0) = -f.transpose();
  v(0, 3) = -r.dot(e);
  v(1, 3) = -u.dot(e);
  v(2, 3) = f.dot(e);
  return v;
}

Mat4 Camera::projection() const {
  const double aspect = double(width) / std::max(height, 1);
  const double t = 1.0 / std::tan(0.5 * fov_y);
  const double n = near_plane(), f = far_plane();
  Mat4 p = Mat4::Zero();
  p(0, 0) = t / aspect;
  p(1, 1) = t;
  p(2, 2) = -(f + n) / (f - n);
  p(2, 3) = -2 * f * n / (f - n);
  p(3, 2) = -1;
  return p;
}

Ray Camera::ray(double x, double y) const {
  const double aspect = double(width) / std::max(height, 1);
  const double t = std::tan(0.5 * fov_y);
  const double ndc_x = 2 * x / width - 1;
  const double ndc_y = 1 - 2 * y / height;
  Ray r;
  r.origin = eye();
  r.direction = (forward() + ndc_x * t * aspect * right() + ndc_y * t * up()).normalized();
  return r;
}

Eigen::Vector2d Camera::project(const Vec3& p, double* depth) const {
  const Vec3 d = p - eye();
  const double z = d.dot(forward());
  if (depth) *depth = z;
  const double aspect = double(width) / std::max(height, 1);
  const double t = std::tan(0.5 * fov_y);
  const double safe = std::abs(z) > 1e-300 ? z : 1e-300;
  const double ndc_x = d.dot(right()) / (safe * t * aspect);
  const double ndc_y = d.dot(up()) / (safe * t);
  return {0.5 * (ndc_x + 1) * width, 0.5 * (1 - ndc_y) * height};
}

void Camera::orbit(double dx, double dy) {
  const double radians_per_pixel = 2 * M_PI / std::max(width, 1) * 0.8;
  yaw -= dx * radians_per_pixel;
  pitch = std::clamp(pitch + dy * radians_per_pixel, -kPitchLimit, kPitchLimit);
}

void Camera::pan(double dx, double dy) {
  // The target moves with the cursor: a pixel is this many metres at the target's depth.
  const double metres_per_pixel = 2 * distance * std::tan(0.5 * fov_y) / std::max(height, 1);
  target += metres_per_pixel * (-dx * right() + dy * up());
}

void Camera::zoom(double steps) { distance = std::max(distance * std::pow(0.9, steps), 1e-4); }

}  // namespace csb::viewer
