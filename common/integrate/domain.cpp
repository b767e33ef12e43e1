#include "common/integrate/domain.hpp"

#include <cmath>
#include <numbers>
#include <span>

#include "common/integrate/integrand.hpp"
#include "common/sampling/ball_simplex.hpp"
#include "common/sampling/disk.hpp"

namespace tally {

namespace {

class BoxDomain final : public Domain {
 public:
  BoxDomain(std::vector<double> lo, std::vector<double> hi) {
    lower_ = std::move(lo);
    upper_ = std::move(hi);
    volume_ = 1.0;
    for (size_t k = 0; k < lower_.size(); ++k) volume_ *= upper_[k] - lower_[k];
  }
  std::string_view type() const override { return lower_.size() == 1 ? "interval" : "box"; }
  size_t dimensions() const override { return lower_.size(); }
  uint32_t uniforms() const override { return static_cast<uint32_t>(lower_.size()); }
  double measure() const override { return volume_; }
  bool is_box() const override { return true; }
  void map_uniform(const double* const* u, size_t n, double* const* x) const override {
    for (size_t k = 0; k < lower_.size(); ++k) {
      const double lo = lower_[k];
      const double w = upper_[k] - lower_[k];
      for (size_t i = 0; i < n; ++i) x[k][i] = lo + u[k][i] * w;
    }
  }
  bool contains(const double* p) const override {
    for (size_t k = 0; k < lower_.size(); ++k)
      if (p[k] < lower_[k] || p[k] > upper_[k]) return false;
    return true;
  }
  DomainInfo describe() const override {
    DomainInfo d;
    d.type = type();
    d.lower = lower_;
    d.upper = upper_;
    return d;
  }

 private:
  double volume_ = 1.0;
};

class DiskDomain final : public Domain {
 public:
  DiskDomain(double cx, double cy, double r) : cx_(cx), cy_(cy), r_(r) {
    lower_ = {cx - r, cy - r};
    upper_ = {cx + r, cy + r};
  }
  std::string_view type() const override { return "disk"; }
  size_t dimensions() const override { return 2; }
  uint32_t uniforms() const override { return 2; }
  double measure() const override { return std::numbers::pi * r_ * r_; }
  void map_uniform(const double* const* u, size_t n, double* const* x) const override {
    for (size_t i = 0; i < n; ++i) {
      const Vec2 p = sample_uniform_disk_concentric(Vec2{u[0][i], u[1][i]});
      x[0][i] = cx_ + r_ * p.x;
      x[1][i] = cy_ + r_ * p.y;
    }
  }
  bool contains(const double* p) const override {
    const double dx = p[0] - cx_, dy = p[1] - cy_;
    return dx * dx + dy * dy <= r_ * r_;
  }
  DomainInfo describe() const override {
    DomainInfo d;
    d.type = "disk";
    d.center = {cx_, cy_};
    d.radius = r_;
    return d;
  }

 private:
  double cx_, cy_, r_;
};

class BallDomain final : public Domain {
 public:
  BallDomain(std::vector<double> c, double r) : c_(std::move(c)), r_(r) {
    for (double v : c_) {
      lower_.push_back(v - r);
      upper_.push_back(v + r);
    }
  }
  std::string_view type() const override { return "ball"; }
  size_t dimensions() const override { return c_.size(); }
  uint32_t uniforms() const override { return ball_uniform_count(static_cast<uint32_t>(c_.size())); }
  double measure() const override {
    return unit_ball_volume(static_cast<uint32_t>(c_.size())) * std::pow(r_, static_cast<double>(c_.size()));
  }
  void map_uniform(const double* const* u, size_t n, double* const* x) const override {
    const size_t d = c_.size();
    std::vector<double> ui(uniforms()), xi(d);
    for (size_t i = 0; i < n; ++i) {
      for (size_t k = 0; k < ui.size(); ++k) ui[k] = u[k][i];
      sample_uniform_ball(ui, xi);
      for (size_t k = 0; k < d; ++k) x[k][i] = c_[k] + r_ * xi[k];
    }
  }
  bool contains(const double* p) const override {
    double s = 0.0;
    for (size_t k = 0; k < c_.size(); ++k) s += (p[k] - c_[k]) * (p[k] - c_[k]);
    return s <= r_ * r_;
  }
  DomainInfo describe() const override {
    DomainInfo d;
    d.type = "ball";
    d.center = c_;
    d.radius = r_;
    return d;
  }

 private:
  std::vector<double> c_;
  double r_;
};

// The 2-sphere in R^3 (or its z >= 0 half), integrated against surface area.
class SphereSurfaceDomain final : public Domain {
 public:
  SphereSurfaceDomain(std::vector<double> c, double r, bool half) : c_(std::move(c)), r_(r), half_(half) {
    for (double v : c_) {
      lower_.push_back(v - r);
      upper_.push_back(v + r);
    }
  }
  std::string_view type() const override { return half_ ? "hemisphere" : "sphere"; }
  size_t dimensions() const override { return 3; }
  uint32_t uniforms() const override { return 2; }
  double measure() const override { return (half_ ? 2.0 : 4.0) * std::numbers::pi * r_ * r_; }
  bool is_solid() const override { return false; }
  void map_uniform(const double* const* u, size_t n, double* const* x) const override {
    for (size_t i = 0; i < n; ++i) {
      // z uniform in [-1,1] (or [0,1]) and an angle: Archimedes' hat-box map.
      const double z = half_ ? u[0][i] : 1.0 - 2.0 * u[0][i];
      const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
      const double phi = 2.0 * std::numbers::pi * u[1][i];
      x[0][i] = c_[0] + r_ * r * std::cos(phi);
      x[1][i] = c_[1] + r_ * r * std::sin(phi);
      x[2][i] = c_[2] + r_ * z;
    }
  }
  bool contains(const double* p) const override {
    double s = 0.0;
    for (size_t k = 0; k < 3; ++k) s += (p[k] - c_[k]) * (p[k] - c_[k]);
    return std::fabs(std::sqrt(s) - r_) <= 1e-9 * r_ && (!half_ || p[2] >= c_[2]);
  }
  DomainInfo describe() const override {
    DomainInfo d;
    d.type = type();
    d.center = c_;
    d.radius = r_;
    return d;
  }

 private:
  std::vector<double> c_;
  double r_;
  bool half_;
};

class SimplexDomain final : public Domain {
 public:
  explicit SimplexDomain(size_t d) : d_(d) {
    lower_.assign(d, 0.0);
    upper_.assign(d, 1.0);
  }
  std::string_view type() const override { return "simplex"; }
  size_t dimensions() const override { return d_; }
  uint32_t uniforms() const override { return simplex_uniform_count(static_cast<uint32_t>(d_)); }
  double measure() const override { return simplex_volume(static_cast<uint32_t>(d_)); }
  void map_uniform(const double* const* u, size_t n, double* const* x) const override {
    std::vector<double> ui(uniforms()), xi(d_);
    for (size_t i = 0; i < n; ++i) {
      for (size_t k = 0; k < ui.size(); ++k) ui[k] = u[k][i];
      sample_uniform_simplex(ui, xi);
      for (size_t k = 0; k < d_; ++k) x[k][i] = xi[k];
    }
  }
  bool contains(const double* p) const override {
    double s = 0.0;
    for (size_t k = 0; k < d_; ++k) {
      if (p[k] < 0.0) return false;
      s += p[k];
    }
    return s <= 1.0;
  }
  DomainInfo describe() const override {
    DomainInfo d;
    d.type = "simplex";
    d.dimensions = d_;
    return d;
  }

 private:
  size_t d_;
};

}  // namespace

std::unique_ptr<Domain> make_box(std::vector<double> lower, std::vector<double> upper) {
  return std::make_unique<BoxDomain>(std::move(lower), std::move(upper));
}
std::unique_ptr<Domain> make_disk(double cx, double cy, double radius) {
  return std::make_unique<DiskDomain>(cx, cy, radius);
}
std::unique_ptr<Domain> make_ball(std::vector<double> center, double radius) {
  return std::make_unique<BallDomain>(std::move(center), radius);
}
std::unique_ptr<Domain> make_sphere_surface(std::vector<double> center, double radius, bool upper_half) {
  return std::make_unique<SphereSurfaceDomain>(std::move(center), radius, upper_half);
}
std::unique_ptr<Domain> make_simplex(size_t dimensions) {
  return std::make_unique<SimplexDomain>(dimensions);
}

}  // namespace tally
