#include "common/lighting/environment_map.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "common/sampling/safe_math.hpp"

namespace tally {

namespace {

constexpr double kTwoPi = 2.0 * kPi;

const char* channel_name(size_t c) { return c == 0 ? "R" : (c == 1 ? "G" : "B"); }

}  // namespace

EnvironmentMap::EnvironmentMap(int width, int height, std::span<const float> rgb, double intensity,
                               double rotation_deg)
    : width_(width), height_(height) {
  if (!(height >= 1 && width == 2 * height)) {
    throw std::invalid_argument(fmt::format(
        "an equirectangular map must be twice as wide as high (2:1, at least 2x1); this one is {}x{}", width, height));
  }
  const size_t w = static_cast<size_t>(width), h = static_cast<size_t>(height);
  if (rgb.size() != 3 * w * h) {
    throw std::invalid_argument(fmt::format("{}x{} map with {} values (expected {})", width, height, rgb.size(), 3 * w * h));
  }
  if (!std::isfinite(intensity) || intensity < 0) {
    throw std::invalid_argument(fmt::format("intensity must be a finite number >= 0, got {}", intensity));
  }
  if (!std::isfinite(rotation_deg)) throw std::invalid_argument("rotation_deg must be finite");
  // Exact for the multiples of 90 degrees (so 0 leaves every direction bit for bit).
  const double turns = std::fmod(rotation_deg, 360.0);
  const double a = turns * (kPi / 180.0);
  if (turns == 0) {
    cos_rot_ = 1, sin_rot_ = 0;
  } else if (std::fabs(turns) == 180) {
    cos_rot_ = -1, sin_rot_ = 0;
  } else if (turns == 90 || turns == -270) {
    cos_rot_ = 0, sin_rot_ = 1;
  } else if (turns == -90 || turns == 270) {
    cos_rot_ = 0, sin_rot_ = -1;
  } else {
    cos_rot_ = std::cos(a), sin_rot_ = std::sin(a);
  }

  float largest = 0;
  for (const float f : rgb) {
    if (std::isfinite(f)) largest = std::max(largest, f);
  }
  const float floor = -kNegativeTexelTolerance * largest;
  texels_.resize(w * h);
  for (size_t i = 0; i < w * h; ++i) {
    double c3[3];
    for (size_t c = 0; c < 3; ++c) {
      const float f = rgb[3 * i + c];
      if (!std::isfinite(f)) {
        throw std::invalid_argument(fmt::format("texel (column {}, row {}) channel {} is {}: radiance must be finite",
                                                i % w, i / w, channel_name(c), f));
      }
      if (f < 0 && f < floor) {
        throw std::invalid_argument(fmt::format(
            "texel (column {}, row {}) channel {} is {}: radiance must be >= 0 (values down to {} x the map's "
            "largest, {}, are read as 0)",
            i % w, i / w, channel_name(c), f, -kNegativeTexelTolerance, largest));
      }
      if (f < 0) {
        ++negative_texels_;
        most_negative_ = std::min(most_negative_, f);
      }
      c3[c] = f < 0 ? 0.0 : static_cast<double>(f) * intensity;
    }
    texels_[i] = {c3[0], c3[1], c3[2]};  // finite: a float (< 3.5e38) times the spec's intensity (<= 1e12)
  }

  const bool all_equal = std::all_of(texels_.begin(), texels_.end(), [&](const Rgb& t) {
    return t.x == texels_[0].x && t.y == texels_[0].y && t.z == texels_[0].z;
  });
  if (all_equal) constant_ = texels_[0];

  // Cell weights luminance * sin(theta at the row's centre); the mean radiance weights
  // each texel by its exact solid angle (2 pi / W) (cos theta_top - cos theta_bottom).
  std::vector<double> weights(w * h);
  Rgb sum{};
  bool any = false;
  for (size_t iv = 0; iv < h; ++iv) {
    const double sin_c = std::sin(kPi * (static_cast<double>(iv) + 0.5) / static_cast<double>(h));
    const double omega = (kTwoPi / static_cast<double>(w)) *
                         (std::cos(kPi * static_cast<double>(iv) / static_cast<double>(h)) -
                          std::cos(kPi * static_cast<double>(iv + 1) / static_cast<double>(h)));
    for (size_t iu = 0; iu < w; ++iu) {
      const Rgb& t = texels_[iv * w + iu];
      weights[iv * w + iu] = luminance(t) * sin_c;
      any = any || weights[iv * w + iu] > 0;
      sum += t * omega;
    }
  }
  mean_ = sum / (4.0 * kPi);
  if (any) {
    double total = 0;
    for (double x : weights) total += x;
    if (!std::isfinite(total)) throw std::invalid_argument("the map's total luminance overflows");
    dist_.emplace(weights, w, h);
  }
}

Vec2 EnvironmentMap::to_uv(const Vec3& w) const {
  // Undo the rotation: d = R_y(-alpha) w.
  const Vec3 d{w.x * cos_rot_ - w.z * sin_rot_, w.y, w.x * sin_rot_ + w.z * cos_rot_};
  const double theta = std::acos(std::clamp(d.y, -1.0, 1.0));
  double phi = std::atan2(d.x, -d.z);
  if (phi < 0) phi += kTwoPi;
  return {std::min(phi / kTwoPi, 1.0), std::min(theta / kPi, 1.0)};
}

Vec3 EnvironmentMap::from_uv(Vec2 uv) const {
  const double theta = kPi * uv.y, phi = kTwoPi * uv.x;
  const double st = std::sin(theta);
  const Vec3 d{st * std::sin(phi), std::cos(theta), -st * std::cos(phi)};
  return {d.x * cos_rot_ + d.z * sin_rot_, d.y, -d.x * sin_rot_ + d.z * cos_rot_};
}

std::array<size_t, 2> EnvironmentMap::cell_of_uv(Vec2 uv) const {
  if (dist_) return dist_->cell_of(uv);
  const auto clampi = [](double t, int n) {
    return static_cast<size_t>(std::clamp(static_cast<long long>(std::floor(t * n)), 0LL, static_cast<long long>(n) - 1));
  };
  return {clampi(uv.x, width_), clampi(uv.y, height_)};
}

std::array<size_t, 2> EnvironmentMap::texel_of(const Vec3& w) const { return cell_of_uv(to_uv(w)); }

Rgb EnvironmentMap::radiance(const Vec3& w) const {
  if (constant_) return *constant_;
  const auto [iu, iv] = texel_of(w);
  return texel(iu, iv);
}

double EnvironmentMap::pdf(const Vec3& w) const {
  if (!dist_) return 0.0;
  const Vec2 uv = to_uv(w);
  // sin theta of the direction itself (rotation about y keeps it): |(w.x, w.z)|.
  const double sin_theta = std::hypot(w.x, w.z);
  if (!(sin_theta > 0)) return 0.0;
  const double pdf = dist_->pdf(uv) / (2.0 * kPi * kPi * sin_theta);
  return std::isfinite(pdf) ? pdf : 0.0;
}

EnvironmentMap::Sample EnvironmentMap::sample(Vec2 u) const {
  Sample out;
  if (!dist_) return out;
  const PiecewiseConstant2D::Sample s = dist_->sample(u);
  out.wi = from_uv(s.point);
  out.pdf = pdf(out.wi);
  if (!(out.pdf > 0)) {
    out.pdf = 0;
    return out;
  }
  out.le = radiance(out.wi);
  return out;
}

}  // namespace tally
