// Minimal 2D/3D vector math for the geodesic kernels (double precision).
#ifndef GEODESIC_CORE_BASE_VEC_H_
#define GEODESIC_CORE_BASE_VEC_H_

#include <cmath>

namespace geodesic {

struct Vec3 {
  double x = 0, y = 0, z = 0;
  Vec3 operator+(const Vec3& o) const { return {x + o.x, y + o.y, z + o.z}; }
  Vec3 operator-(const Vec3& o) const { return {x - o.x, y - o.y, z - o.z}; }
  Vec3 operator*(double s) const { return {x * s, y * s, z * s}; }
  bool operator==(const Vec3& o) const = default;
};
inline double Dot(const Vec3& a, const Vec3& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline Vec3 Cross(const Vec3& a, const Vec3& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline double Norm(const Vec3& a) { return std::sqrt(Dot(a, a)); }
inline double Distance(const Vec3& a, const Vec3& b) { return Norm(a - b); }

struct Vec2 {
  double x = 0, y = 0;
  Vec2 operator+(const Vec2& o) const { return {x + o.x, y + o.y}; }
  Vec2 operator-(const Vec2& o) const { return {x - o.x, y - o.y}; }
  Vec2 operator*(double s) const { return {x * s, y * s}; }
};
inline double Dot(const Vec2& a, const Vec2& b) { return a.x * b.x + a.y * b.y; }
inline double Cross(const Vec2& a, const Vec2& b) { return a.x * b.y - a.y * b.x; }
// Not std::hypot: its overflow-safe scaling costs several times a sqrt, and
// mesh coordinates are nowhere near the range where x * x overflows.
inline double Norm(const Vec2& a) { return std::sqrt(Dot(a, a)); }

// An angle taken modulo `period` (a cone angle, or 2*pi), in [0, period).
inline double WrapAngle(double a, double period) {
  a = std::fmod(a, period);
  return a < 0 ? a + period : a;
}

}  // namespace geodesic

#endif  // GEODESIC_CORE_BASE_VEC_H_
