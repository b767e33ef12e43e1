#pragma once
// Small 3-vector and 2-vector types for sampling and lighting. Double precision by
// default: the estimator maths runs in double; Embree's float rays are converted at
// the boundary.
#include <algorithm>
#include <cmath>

namespace tally {

struct Vec2 {
  double x = 0, y = 0;
};

struct Vec3 {
  double x = 0, y = 0, z = 0;

  constexpr double operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
  constexpr Vec3 operator-() const { return {-x, -y, -z}; }
  constexpr Vec3& operator+=(const Vec3& o) { x += o.x; y += o.y; z += o.z; return *this; }
  constexpr Vec3& operator*=(double s) { x *= s; y *= s; z *= s; return *this; }
};

constexpr Vec3 operator+(const Vec3& a, const Vec3& b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
constexpr Vec3 operator-(const Vec3& a, const Vec3& b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
constexpr Vec3 operator*(const Vec3& a, double s) { return {a.x * s, a.y * s, a.z * s}; }
constexpr Vec3 operator*(double s, const Vec3& a) { return a * s; }
constexpr Vec3 operator*(const Vec3& a, const Vec3& b) { return {a.x * b.x, a.y * b.y, a.z * b.z}; }
constexpr Vec3 operator/(const Vec3& a, double s) { return {a.x / s, a.y / s, a.z / s}; }
constexpr double dot(const Vec3& a, const Vec3& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
constexpr Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline double length(const Vec3& a) { return std::sqrt(dot(a, a)); }
inline Vec3 normalize(const Vec3& a) { return a / length(a); }
constexpr double max_component(const Vec3& a) { return std::max(a.x, std::max(a.y, a.z)); }

// Orthonormal basis from a unit normal: Duff et al. 2017, "Building an Orthonormal
// Basis, Revisited" (no singularity near n = -z, unlike Frisvad's construction).
struct Frame {
  Vec3 t, b, n;

  static Frame from_normal(const Vec3& n) {
    const double sign = std::copysign(1.0, n.z);
    const double a = -1.0 / (sign + n.z);
    const double bb = n.x * n.y * a;
    return Frame{{1.0 + sign * n.x * n.x * a, sign * bb, -sign * n.x},
                 {bb, sign + n.y * n.y * a, -n.y},
                 n};
  }
  Vec3 to_world(const Vec3& v) const { return t * v.x + b * v.y + n * v.z; }
  Vec3 to_local(const Vec3& v) const { return {dot(v, t), dot(v, b), dot(v, n)}; }
};

}  // namespace tally
