#pragma once
// The estimators of the reflection equation
//   L_o(p, w_o) = L_e(p, w_o) + ∫_H f_r(p, w_i -> w_o) L_i(p, w_i) cos(theta_i) dw_i,
// with L_i expanded recursively up to max_depth bounces (max_depth 1 = direct light).
// At each vertex the strategy decides how w_i is drawn and which terms count:
//   uniform_hemisphere  p = 1/(2 pi); emission is gathered where the ray lands
//   cosine_hemisphere   p = cos/pi;   same
//   light_area          one light sample by area (next-event estimation) + a shadow
//                       ray; BSDF-sampled bounces carry indirect light only
//   mis                 one light sample and one BSDF sample, power heuristic (beta=2)
// Point/spot/directional lights are added deterministically by every strategy, each at
// every non-mirror vertex -- unless the plan has delta_light_tree (many point/spot
// lights): then one point or spot light per vertex is picked from the DeltaLightTree
// with probability pmf and its term divided by pmf (directional lights are still all
// added). A mirror is always followed in its one direction. Random numbers: dimensions
// dim0 + 6k .. + 5 at the k-th vertex: light choice, roulette, light point x2, direction
// x2 -- three 2-D pairs (dim0 is even), see common/lighting/pixel_sampler.hpp; the
// point/spot light choice at vertex k uses dimension dim0 + kDimDeltaLightChoice + k,
// past every vertex's (so scenes without the tree draw exactly what they drew before).
// `Rng` is SampleRng (independent) or SobolSample (RQMC); both are instantiated in
// path_tracer.cpp.
#include <cstdint>

#include "common/engine/counters.hpp"
#include "common/lighting/lighting_counters.hpp"
#include "common/lighting/accel.hpp"
#include "common/lighting/bsdf.hpp"
#include "common/lighting/delta_light_tree.hpp"
#include "common/lighting/light_set.hpp"
#include "common/lighting/planner.hpp"
#include "common/rng/counter_rng.hpp"

namespace tally {

struct Vertex {
  Vec3 p{};
  Vec3 n{};   // unit geometric normal on the side of wo (ray offsets, the horizon)
  Vec3 wo{};  // unit, away from the surface
  uint32_t material = 0;
  // Interpolated shading normal (meshes with vertex normals), flipped with n: the BSDF
  // and the cosines use it; directions below the geometric horizon get nothing.
  bool has_ns = false;
  Vec3 ns{};
  Vec2 uv{};  // texture coordinates (meshes with uvs): textured materials are looked up here
};

struct PathSettings {
  Strategy strategy = Strategy::mis;
  int max_depth = 1;
  bool russian_roulette = false;
};

class PathTracer {
 public:
  // `delta_tree`: the scene's point/spot light tree when plan.delta_light_tree (else
  // nullptr: every delta light is added at every vertex).
  PathTracer(const Scene& scene, const Accel& accel, const LightSet& lights, const Plan& plan,
             const DeltaLightTree* delta_tree = nullptr)
      : scene_(scene), accel_(accel), lights_(lights), plan_(plan), delta_tree_(delta_tree) {}

  // Reflected radiance at v towards v.wo (without v's own emission).
  template <class Rng>
  Rgb reflected(Vertex v, const PathSettings& s, const Rng& rng, uint32_t dim0, Counters& c) const;
  // Radiance along a camera ray (o, unit d); uses dimensions from dim0.
  template <class Rng>
  Rgb camera(const Vec3& o, const Vec3& d, const PathSettings& s, const Rng& rng, uint32_t dim0, Counters& c) const;

  // The shading vertex of a ray (direction d) hitting `hit`.
  Vertex vertex_at(const Hit& hit, const Vec3& d) const;

  static constexpr uint32_t kDimsPerVertex = 6;
  // Offsets inside a vertex's dimensions.
  static constexpr uint32_t kDimLightChoice = 0, kDimRoulette = 1, kDimLightPoint = 2, kDimDirection = 4;
  // The point/spot light choice of vertex k: dim0 + kDimDeltaLightChoice + k, after the
  // dimensions of kMaxVertices vertices (lighting_spec.cpp caps max_depth at 64).
  static constexpr uint32_t kMaxVertices = 64;
  static constexpr uint32_t kDimDeltaLightChoice = kDimsPerVertex * kMaxVertices;

 private:
  const Scene& scene_;
  const Accel& accel_;
  const LightSet& lights_;
  const Plan& plan_;
  const DeltaLightTree* delta_tree_;
};

}  // namespace tally
