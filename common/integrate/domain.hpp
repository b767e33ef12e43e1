#pragma once
// Integration domains. Each maps uniforms in (0,1)^k to uniformly distributed points
// (density 1/measure), knows its bounding box (for rejection sampling) and whether a
// point lies inside.
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace tally {

// What a domain is, for plans and results (common/protocol writes it as JSON). Fields
// not set are absent.
struct DomainInfo {
  std::string type;
  std::vector<double> lower, upper;  // interval, box
  std::vector<double> center;        // disk, ball, sphere, hemisphere
  std::optional<double> radius;
  std::optional<size_t> dimensions;  // simplex
};

class Domain {
 public:
  virtual ~Domain() = default;
  virtual std::string_view type() const = 0;
  virtual size_t dimensions() const = 0;  // coordinates of a point
  virtual uint32_t uniforms() const = 0;  // uniforms consumed by map_uniform per point
  virtual double measure() const = 0;     // volume, area or surface measure
  // u[k][i] for k < uniforms(), i < n  ->  x[j][i] for j < dimensions().
  virtual void map_uniform(const double* const* u, size_t n, double* const* x) const = 0;
  virtual bool contains(const double* point) const = 0;
  virtual bool is_box() const { return false; }
  // Surfaces (sphere, hemisphere) cannot be rejection-sampled from a box.
  virtual bool is_solid() const { return true; }
  const std::vector<double>& lower() const { return lower_; }
  const std::vector<double>& upper() const { return upper_; }
  virtual DomainInfo describe() const = 0;

 protected:
  std::vector<double> lower_, upper_;  // bounding box
};

std::unique_ptr<Domain> make_box(std::vector<double> lower, std::vector<double> upper);
std::unique_ptr<Domain> make_disk(double cx, double cy, double radius);
std::unique_ptr<Domain> make_ball(std::vector<double> center, double radius);
std::unique_ptr<Domain> make_sphere_surface(std::vector<double> center, double radius, bool upper_half);
std::unique_ptr<Domain> make_simplex(size_t dimensions);

}  // namespace tally
