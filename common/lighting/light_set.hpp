#pragma once
// The lights that next-event estimation samples: emissive shapes ("area lights") and
// the constant sky. One is chosen in proportion to its power (an alias table; see
// light_power), then a point on it:
//   - quads, disks, triangle meshes: uniformly by area (meshes: each triangle is its own
//     entry of the alias table with its share of the mesh's power, so the mesh is
//     sampled uniformly by area), pdf converted to solid angle with d^2 / |cos theta_l|;
//   - spheres seen from outside: uniformly in the cone they subtend (exactly the
//     visible cap, so no sample is wasted on the far side); from inside: by area;
//   - the sky: cosine-weighted around the receiver's normal; an environment map by its
//     own importance sampler (environment_map.hpp: luminance x sin theta, all directions).
// With LightSelection::tree the area-light entries are chosen by a light hierarchy
// instead (light_tree.hpp: importance by power, distance and orientation at the shading
// point); the sky keeps its power share, the tree takes the rest. Every pdf then
// includes the tree's pmf at that point.
// Point, spot and directional lights are not here: a hemisphere sample can never hit
// them, so every estimator adds them deterministically (the path tracer), or, with many
// point/spot lights, picks one per vertex from their own tree (delta_light_tree.hpp).
// Lights of zero area are dropped (they emit no power) and listed in `dropped`.
#include <optional>
#include <string>
#include <vector>

#include "common/lighting/accel.hpp"
#include "common/lighting/light_tree.hpp"
#include "common/lighting/scene.hpp"
#include "common/sampling/alias_table.hpp"

namespace tally {

// Light points seen this close to edge-on are "no sample" (sample) and have light pdf 0
// (pdf_hit): the two must agree or MIS weights do not sum to 1 there.
inline constexpr double kMinLightCos = 1e-12;

struct LightSample {
  Vec3 wi{};        // unit direction from x towards the light
  double dist = 0;  // to the light point (inf for the sky)
  Vec3 p{}, n{};    // light point and its normal (area lights)
  Rgb le{};         // emitted radiance towards x (0 if the point faces away)
  double pdf = 0;   // solid angle, including the choice of the light; 0: no sample
  bool sky = false;
};

class LightSet {
 public:
  explicit LightSet(const Scene& scene, LightSelection selection = LightSelection::power);

  LightSelection selection() const { return tree_ ? LightSelection::tree : LightSelection::power; }
  // Emitter entries (the alias table's or the tree's leaves; the sky not counted).
  size_t emitter_entries() const { return entries_.size() - (sky_ ? 1 : 0); }
  // The probability that sample(x, ...) chooses the light of `shape`, triangle `prim` for
  // meshes (the point's choice probability as the pdfs include it).
  double choice_pmf(const Vec3& x, uint32_t shape, uint32_t prim) const;

  size_t sampled_count() const { return area_.size() + (sky_ ? 1 : 0); }
  bool empty() const { return sampled_count() == 0; }
  const std::vector<std::string>& dropped() const { return dropped_; }
  bool is_light(uint32_t shape) const { return light_of_shape_[shape] >= 0; }

  // u0 picks the light (and a triangle), (u1, u2) the point / direction.
  LightSample sample(const Vec3& x, const Vec3& n, double u0, double u1, double u2) const;
  // Solid-angle density at x (with the choice of light) with which sample(x, ...)
  // returns the point `hit` on an emissive shape; 0 where sample() gives no sample
  // (edge-on, cos < kMinLightCos), so MIS then gives the BSDF sample all the weight.
  double pdf_hit(const Vec3& x, const Hit& hit) const;
  // The same density for the *direction* wi from x, given that a ray leaving along wi
  // from a point near x (the offset ray origin) found `hit`: the emitter is intersected
  // again from x itself along wi and pdf_hit is taken there. This is what MIS must use
  // for a BSDF-sampled emitter hit: the light strategy's density of the direction that
  // the BSDF strategy actually sampled, both measured at x. pdf_hit(x, hit) is not that
  // when the receiver lies on the emitter: a hit found from the offset origin lies, seen
  // from x, in a different direction, and at grazing angles very much so.
  double pdf_dir(const Vec3& x, const Vec3& wi, const Hit& hit) const;
  double pdf_sky(const Vec3& n, const Vec3& wi) const;

  // Probability that power selection picks the light of `shape` (0 if it is not a
  // light) / the sky (either selection): what the pdfs above include as "the choice of
  // light" under power selection.
  double pick_pmf(uint32_t shape) const;
  double pick_pmf_sky() const { return sky_pick_; }

 private:
  struct AreaLight {
    uint32_t shape = 0;
    double area = 0;
    double pick = 0;  // probability of choosing this light
  };
  // One alias-table entry: an area light (meshes: one of its triangles) or the sky.
  struct Entry {
    uint32_t light = 0;     // index into area_, or area_.size() for the sky
    uint32_t triangle = 0;  // meshes
    double area = 0;        // of the entry (the triangle's for meshes)
  };
  // The entry of a point on `shape` (triangle `prim`), -1 if none.
  int64_t entry_of(uint32_t shape, uint32_t prim) const;
  // The choice probability of entry e at x under the selection in use.
  double entry_pmf(const Vec3& x, size_t e) const;
  const Scene& scene_;
  std::vector<AreaLight> area_;
  std::vector<int> light_of_shape_;
  bool sky_ = false;
  double sky_pick_ = 0;
  std::vector<Entry> entries_;
  std::optional<AliasTable> pick_;
  std::vector<std::string> dropped_;
  std::vector<uint32_t> first_entry_;           // per area light
  std::vector<std::vector<int32_t>> tri_entry_;  // per area light: entry of each triangle (meshes)
  std::optional<LightTree> tree_;               // leaf i = entries_[i]
};

// The weights lights are chosen by (pbrt's Phi): an area light emits pi A L (x2 when
// two-sided); the sky 4 pi * pi r^2 L with r the radius of the scene's bounding sphere
// (1 without shapes), L an environment map's mean radiance over the sphere. L is the luminance of the radiance (floored at 1e-3 of its largest
// channel so that a pure-blue light keeps a fair share).
double light_power_radiance(const Rgb& radiance);

// Emitted radiance of `shape` at a point with normal n towards direction w (unit), at
// texture coordinates uv (an emissive texture multiplies the emission there).
Rgb emitted(const Scene& scene, uint32_t shape, const Vec3& n, const Vec3& w, Vec2 uv = {});

}  // namespace tally
