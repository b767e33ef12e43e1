#include "common/lighting/accel.hpp"

#include <fmt/format.h>

#include <cmath>
#include <limits>
#include <stdexcept>

#include "common/lighting/embree_device.hpp"

namespace tally {

namespace {

constexpr float kFloatInf = std::numeric_limits<float>::infinity();

float to_f(double x) { return static_cast<float>(x); }
// Embree's single-precision origin and direction as the double-precision vectors the
// shapes' exact intersection works in.
Vec3 to_vec3(float x, float y, float z) {
  return {static_cast<double>(x), static_cast<double>(y), static_cast<double>(z)};
}

// Ray-sphere in double (Hearn & Baker's form: discriminant from the distance of the
// centre to the line, then the stable quadratic root). Returns t or +inf.
double sphere_hit_t(const Shape& s, const Vec3& o, const Vec3& d, double t_min, double t_max) {
  const Vec3 f = o - s.center;
  const double a = dot(d, d);
  const double b = dot(f, d);
  const Vec3 l = f - d * (b / a);
  const double disc = s.radius * s.radius - dot(l, l);
  if (disc < 0) return std::numeric_limits<double>::infinity();
  const double root = std::sqrt(a * disc);
  const double q = b > 0 ? -(b + root) : -(b - root);
  const double c = dot(f, f) - s.radius * s.radius;
  double t0 = q / a, t1 = q != 0 ? c / q : t0;
  if (t0 > t1) std::swap(t0, t1);
  if (t0 > t_min && t0 < t_max) return t0;
  if (t1 > t_min && t1 < t_max) return t1;
  return std::numeric_limits<double>::infinity();
}

double disk_hit_t(const Shape& s, const Vec3& o, const Vec3& d, double t_min, double t_max) {
  const double denom = dot(s.normal, d);
  if (denom == 0) return std::numeric_limits<double>::infinity();
  const double t = dot(s.center - o, s.normal) / denom;
  if (!(t > t_min && t < t_max)) return std::numeric_limits<double>::infinity();
  const Vec3 p = o + d * t - s.center;
  if (dot(p, p) > s.radius * s.radius) return std::numeric_limits<double>::infinity();
  return t;
}

double user_hit_t(const Shape& s, const Vec3& o, const Vec3& d, double t_min, double t_max) {
  return s.type == ShapeType::sphere ? sphere_hit_t(s, o, d, t_min, t_max)
                                     : disk_hit_t(s, o, d, t_min, t_max);
}

void user_bounds(const RTCBoundsFunctionArguments* args) {
  const Shape& s = *static_cast<const Shape*>(args->geometryUserPtr);
  // Padded by a float ulp-ish margin so that rounding never culls a true hit.
  const double r = s.radius * (1 + 1e-6) + 1e-6;
  RTCBounds* b = args->bounds_o;
  b->lower_x = to_f(s.center.x - r);
  b->lower_y = to_f(s.center.y - r);
  b->lower_z = to_f(s.center.z - r);
  b->upper_x = to_f(s.center.x + r);
  b->upper_y = to_f(s.center.y + r);
  b->upper_z = to_f(s.center.z + r);
}

// Only rtcIntersect1 / rtcOccluded1 are used, so N == 1 and the ray is an RTCRayHit/RTCRay.
void user_intersect(const RTCIntersectFunctionNArguments* args) {
  if (args->N != 1 || !args->valid[0]) return;
  const Shape& s = *static_cast<const Shape*>(args->geometryUserPtr);
  auto* rh = reinterpret_cast<RTCRayHit*>(args->rayhit);
  const Vec3 o = to_vec3(rh->ray.org_x, rh->ray.org_y, rh->ray.org_z);
  const Vec3 d = to_vec3(rh->ray.dir_x, rh->ray.dir_y, rh->ray.dir_z);
  const double t = user_hit_t(s, o, d, static_cast<double>(rh->ray.tnear), static_cast<double>(rh->ray.tfar));
  if (!std::isfinite(t)) return;
  const float tf = to_f(t);
  if (!(tf < rh->ray.tfar)) return;
  rh->ray.tfar = tf;
  rh->hit.u = 0;
  rh->hit.v = 0;
  rh->hit.Ng_x = 0;
  rh->hit.Ng_y = 0;
  rh->hit.Ng_z = 1;
  rh->hit.primID = args->primID;
  rh->hit.geomID = args->geomID;
  rh->hit.instID[0] = args->context->instID[0];
}

void user_occluded(const RTCOccludedFunctionNArguments* args) {
  if (args->N != 1 || !args->valid[0]) return;
  const Shape& s = *static_cast<const Shape*>(args->geometryUserPtr);
  auto* ray = reinterpret_cast<RTCRay*>(args->ray);
  const Vec3 o = to_vec3(ray->org_x, ray->org_y, ray->org_z);
  const Vec3 d = to_vec3(ray->dir_x, ray->dir_y, ray->dir_z);
  const double t = user_hit_t(s, o, d, static_cast<double>(ray->tnear), static_cast<double>(ray->tfar));
  if (std::isfinite(t)) ray->tfar = -kFloatInf;
}

void throw_if_error(const char* what) {
  if (auto e = take_embree_error()) throw std::runtime_error(fmt::format("{}: {}", what, *e));
}

}  // namespace

Accel::Accel(const Scene& scene) : scene_(scene) {
  RTCDevice device = embree_device();
  take_embree_error();
  rtc_ = rtcNewScene(device);
  rtcSetSceneFlags(rtc_, RTC_SCENE_FLAG_ROBUST);
  rtcSetSceneBuildQuality(rtc_, RTC_BUILD_QUALITY_HIGH);
  for (size_t i = 0; i < scene.shapes.size(); ++i) {
    const Shape& s = scene.shapes[i];
    RTCGeometry g = nullptr;
    if (s.type == ShapeType::mesh || s.type == ShapeType::quad) {
      g = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
      auto* vb = static_cast<float*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                             3 * sizeof(float), s.vertices.size()));
      auto* ib = static_cast<unsigned*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                                3 * sizeof(unsigned), s.triangles.size()));
      if (vb == nullptr || ib == nullptr) {
        if (g) rtcReleaseGeometry(g);
        throw_if_error("Embree buffer allocation");
        throw std::runtime_error("Embree buffer allocation failed");
      }
      for (size_t v = 0; v < s.vertices.size(); ++v) {
        vb[3 * v] = to_f(s.vertices[v].x);
        vb[3 * v + 1] = to_f(s.vertices[v].y);
        vb[3 * v + 2] = to_f(s.vertices[v].z);
      }
      for (size_t t = 0; t < s.triangles.size(); ++t) {
        for (size_t k = 0; k < 3; ++k) ib[3 * t + k] = s.triangles[t][k];
      }
    } else {
      g = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_USER);
      rtcSetGeometryUserPrimitiveCount(g, 1);
      rtcSetGeometryUserData(g, const_cast<Shape*>(&s));
      rtcSetGeometryBoundsFunction(g, user_bounds, nullptr);
      rtcSetGeometryIntersectFunction(g, user_intersect);
      rtcSetGeometryOccludedFunction(g, user_occluded);
    }
    rtcCommitGeometry(g);
    rtcAttachGeometryByID(rtc_, g, static_cast<unsigned>(i));
    rtcReleaseGeometry(g);
    throw_if_error(fmt::format("Embree geometry for {}", s.pointer).c_str());
  }
  rtcCommitScene(rtc_);
  throw_if_error("Embree scene build");
}

Accel::~Accel() {
  if (rtc_) rtcReleaseScene(rtc_);
}

std::optional<Hit> Accel::intersect(const Vec3& o, const Vec3& d, double t_max) const {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRayHit rh;
  rh.ray.org_x = to_f(o.x);
  rh.ray.org_y = to_f(o.y);
  rh.ray.org_z = to_f(o.z);
  rh.ray.tnear = 0.0f;
  rh.ray.dir_x = to_f(d.x);
  rh.ray.dir_y = to_f(d.y);
  rh.ray.dir_z = to_f(d.z);
  rh.ray.time = 0.0f;
  rh.ray.tfar = std::isfinite(t_max) ? to_f(t_max) : kFloatInf;
  rh.ray.mask = 0xFFFFFFFFu;
  rh.ray.id = 0;
  rh.ray.flags = 0;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.primID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(rtc_, &ctx, &rh);
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return std::nullopt;
  Hit h;
  h.shape = rh.hit.geomID;
  h.prim = rh.hit.primID;
  h.t = static_cast<double>(rh.ray.tfar);
  const Shape& s = scene_.shapes[h.shape];
  const Vec3 of{static_cast<double>(rh.ray.org_x), static_cast<double>(rh.ray.org_y), static_cast<double>(rh.ray.org_z)};
  const Vec3 df{static_cast<double>(rh.ray.dir_x), static_cast<double>(rh.ray.dir_y), static_cast<double>(rh.ray.dir_z)};
  switch (s.type) {
    case ShapeType::sphere: {
      const Vec3 q = of + df * h.t - s.center;
      const double len = length(q);
      h.n = len > 0 ? q / len : -normalize(df);
      h.p = s.center + h.n * s.radius;  // re-projected onto the surface
      break;
    }
    case ShapeType::disk: {
      Vec3 p = of + df * h.t;
      p = p - s.normal * dot(p - s.center, s.normal);
      h.p = p;
      h.n = s.normal;
      break;
    }
    default: {
      const auto& tri = s.triangles[h.prim];
      const Vec3& a = s.vertices[tri[0]];
      const Vec3& b = s.vertices[tri[1]];
      const Vec3& c = s.vertices[tri[2]];
      const double u = static_cast<double>(rh.hit.u), v = static_cast<double>(rh.hit.v);
      h.p = a * (1.0 - u - v) + b * u + c * v;  // barycentric: error ~ ulp of the vertices
      const Vec3 n = cross(b - a, c - a);
      const double len = length(n);
      h.n = len > 0 ? n / len : -normalize(df);  // degenerate: face the ray, never NaN
      const double w = 1.0 - u - v;
      if (!s.normals.empty()) {
        const Vec3 ns = s.normals[tri[0]] * w + s.normals[tri[1]] * u + s.normals[tri[2]] * v;
        const double nl = length(ns);
        if (nl > 0 && std::isfinite(nl)) {
          h.has_ns = true;
          h.ns = ns / nl;
        }
      }
      if (!s.uvs.empty()) {
        const Vec2 &ta = s.uvs[tri[0]], &tb = s.uvs[tri[1]], &tc = s.uvs[tri[2]];
        h.uv = {ta.x * w + tb.x * u + tc.x * v, ta.y * w + tb.y * u + tc.y * v};
      }
      break;
    }
  }
  return h;
}

bool Accel::occluded(const Vec3& o, const Vec3& d, double t_max) const {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRay ray;
  ray.org_x = to_f(o.x);
  ray.org_y = to_f(o.y);
  ray.org_z = to_f(o.z);
  ray.tnear = 0.0f;
  ray.dir_x = to_f(d.x);
  ray.dir_y = to_f(d.y);
  ray.dir_z = to_f(d.z);
  ray.time = 0.0f;
  ray.tfar = std::isfinite(t_max) ? to_f(t_max) : kFloatInf;
  ray.mask = 0xFFFFFFFFu;
  ray.id = 0;
  ray.flags = 0;
  rtcOccluded1(rtc_, &ctx, &ray);
  return ray.tfar == -kFloatInf;
}

}  // namespace tally
