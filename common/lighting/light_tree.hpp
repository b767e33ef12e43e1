#pragma once
// A light hierarchy for many-light sampling (pbrt-v4's BVHLightSampler; Conty & Kulla
// 2018): a binary tree over emitters, each node holding the bounds, the total power
// (phi) and the cone of emission directions of the emitters below it. At a shading
// point p the traversal goes left with probability I(left) / (I(left) + I(right)), where
// I is pbrt-v4's LightBounds::Importance without the receiver's normal:
//   I = phi * cos(theta') / max(d^2, |diagonal| / 2),  theta' = max(0, theta_w - theta_o - theta_b),
//   and I = 0 when cos(theta') <= cos(theta_e),
// with d the distance from p to the bounds' centre, theta_w the angle between the cone
// axis and the direction from the centre to p, theta_o the cone's spread, theta_b the
// half-angle the bounding sphere subtends at p and theta_e the emission spread past the
// normals (90 degrees for area lights). The bound is conservative: a light that can
// send light to p never has importance 0 on its path.
//
// Where neither child of a node can light p (a parent's bound is looser than its
// children's), the walk goes by power instead, so the pmf is a distribution over all
// leaves at every p (sums to 1): such a sample is wasted (the light sends nothing to p),
// never biased. pmf(p, leaf) walks the same path with the same arithmetic in the same order, so it is
// bit for bit the probability sample(p, u) reports for that leaf (MIS needs exactly
// this). The build is deterministic: splits at the centroid median of the longest axis,
// ties broken by leaf index. Immutable after construction; every method is const and
// pure, so all threads share one tree.
#include <cstddef>
#include <cstdint>
#include <optional>
#include <vector>

#include "common/math/vec3.hpp"

namespace tally {

// How next-event estimation chooses among the area lights: by power (one alias table,
// the same choice everywhere) or by the light tree (depends on the shading point).
enum class LightSelection { power, tree };

// The planner switches the tree on for scenes with more than this many emitter entries
// (emissive shapes, a mesh counting one per triangle): below it power selection is
// cheaper per sample and nearly as good.
inline constexpr size_t kLightTreeMinEmitters = 64;

struct LightBounds {
  Vec3 lo{}, hi{};      // axis-aligned bounds of the emitter(s)
  double phi = 0.0;     // power (the light set's weight)
  Vec3 w{0, 0, 1};      // unit axis of the cone of normals
  double cos_o = 1.0;   // cosine of the cone's half-angle (-1: all directions)
  double cos_e = 0.0;   // cosine of the emission spread beyond the normals (area lights: cos 90°)
  bool two_sided = false;
};

// pbrt-v4's importance of `b` at p (no receiver normal); 0 when no emitter in b can
// light p.
double light_importance(const LightBounds& b, const Vec3& p);
// The bounds of the union (bounds, phi summed, the smallest cone holding both cones).
LightBounds merge_light_bounds(const LightBounds& a, const LightBounds& b);

class LightTree {
 public:
  // Leaf i stands for `leaves[i]`; leaves with phi <= 0 are never picked.
  explicit LightTree(const std::vector<LightBounds>& leaves);

  struct Pick {
    uint32_t leaf = 0;
    double pmf = 0.0;
  };
  // Walks from the root with u in [0, 1); nullopt only for an empty tree.
  std::optional<Pick> sample(const Vec3& p, double u) const;
  // The probability that sample(p, .) picks `leaf` (0 if it never does).
  double pmf(const Vec3& p, uint32_t leaf) const;

  size_t node_count() const { return nodes_.size(); }

 private:
  struct Node {
    LightBounds b;
    int32_t left = -1, right = -1;  // children; both -1 at a leaf
    int32_t parent = -1;
    uint32_t leaf = 0;  // leaves only
  };
  // What light_importance derives from a node's bounds before it looks at p (centre,
  // bounding radius, sin of the cone's spread), computed once per node with the same
  // arithmetic, so the importances are bit for bit light_importance's. The traversal
  // reads only these (a third of a many-light render's time was light_importance
  // recomputing them).
  struct Importance {
    Vec3 centre{};
    double radius = 0.0, radius2 = 0.0;
    double phi = 0.0;
    Vec3 w{0, 0, 1};
    double cos_o = 1.0, sin_o = 0.0, cos_e = 0.0;
    bool two_sided = false;
  };
  static Importance prepare(const LightBounds& b);
  static double importance(const Importance& b, const Vec3& p);
  friend double light_importance(const LightBounds& b, const Vec3& p);
  int32_t build(std::vector<uint32_t>& ids, size_t begin, size_t end, const std::vector<LightBounds>& leaves,
                int32_t parent);
  // Probability of going to the left child of `n` at p (importance ratio; power ratio
  // when both importances are 0).
  double left_probability(const Node& n, const Vec3& p) const;

  std::vector<Node> nodes_;
  std::vector<Importance> importance_;  // per node, as nodes_
  std::vector<int32_t> node_of_leaf_;  // -1: not in the tree (phi <= 0)
  int32_t root_ = -1;
};

}  // namespace tally
