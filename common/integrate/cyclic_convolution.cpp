#include "common/integrate/cyclic_convolution.hpp"

#include <cmath>
#include <numbers>
#include <stdexcept>
#include <utility>

namespace tally {

namespace {

// (a + ib)(c + id) without the NaN/Inf recovery of std::complex's operator* (a libgcc
// call per product when the compiler cannot rule out NaN; the inputs here are finite).
inline std::complex<double> mul(std::complex<double> x, std::complex<double> y) {
  return {x.real() * y.real() - x.imag() * y.imag(), x.real() * y.imag() + x.imag() * y.real()};
}

}  // namespace

std::vector<std::complex<double>> fft_twiddles(size_t n) {
  // Twiddles of the largest stage, computed directly (no drift from repeated products);
  // stage `len` uses every (n / len)-th.
  std::vector<std::complex<double>> w(n / 2);
  const double ang = -2.0 * std::numbers::pi / static_cast<double>(n);
  for (size_t k = 0; k < n / 2; ++k) w[k] = std::polar(1.0, ang * static_cast<double>(k));
  return w;
}

void fft_radix2(std::vector<std::complex<double>>& a, const std::vector<std::complex<double>>& w, bool inverse) {
  const size_t n = a.size();
  if (n == 0 || (n & (n - 1)) != 0) throw std::invalid_argument("fft_radix2: length is not a power of two");
  if (w.size() != n / 2) throw std::invalid_argument("fft_radix2: twiddles of another length");
  for (size_t i = 1, j = 0; i < n; ++i) {  // bit reversal
    size_t bit = n >> 1;
    for (; (j & bit) != 0; bit >>= 1) j ^= bit;
    j ^= bit;
    if (i < j) std::swap(a[i], a[j]);
  }
  for (size_t len = 2; len <= n; len <<= 1) {
    const size_t half = len / 2, step = n / len;
    for (size_t i = 0; i < n; i += len) {
      for (size_t k = 0; k < half; ++k) {
        const std::complex<double> wk = inverse ? std::conj(w[k * step]) : w[k * step];
        const std::complex<double> u = a[i + k], v = mul(a[i + k + half], wk);
        a[i + k] = u + v;
        a[i + k + half] = u - v;
      }
    }
  }
}

void fft_radix2(std::vector<std::complex<double>>& a, bool inverse) { fft_radix2(a, fft_twiddles(a.size()), inverse); }

CyclicConvolution::CyclicConvolution(const std::vector<double>& c) : length_(c.size()) {
  // The linear convolution of two length-L sequences has 2L - 1 terms; wrapping it at L
  // gives the cyclic one. A power-of-two L needs no padding: the FFT's product is cyclic.
  fft_size_ = 1;
  const bool power_of_two = length_ > 0 && (length_ & (length_ - 1)) == 0;
  while (fft_size_ < (power_of_two ? length_ : 2 * length_ - 1)) fft_size_ <<= 1;
  twiddles_ = fft_twiddles(fft_size_);
  c_hat_.assign(fft_size_, {0.0, 0.0});
  for (size_t i = 0; i < length_; ++i) c_hat_[i] = c[i];
  fft_radix2(c_hat_, twiddles_, false);
}

std::vector<double> CyclicConvolution::apply(const std::vector<double>& x) const {
  if (x.size() != length_) throw std::invalid_argument("CyclicConvolution: length mismatch");
  std::vector<std::complex<double>> a(fft_size_, {0.0, 0.0});
  for (size_t i = 0; i < length_; ++i) a[i] = x[i];
  fft_radix2(a, twiddles_, false);
  for (size_t i = 0; i < fft_size_; ++i) a[i] = mul(a[i], c_hat_[i]);
  fft_radix2(a, twiddles_, true);
  const double scale = 1.0 / static_cast<double>(fft_size_);
  std::vector<double> y(length_);
  for (size_t i = 0; i < length_; ++i) {
    const double wrapped = i + length_ < fft_size_ ? a[i + length_].real() : 0.0;
    y[i] = (a[i].real() + wrapped) * scale;
  }
  return y;
}

}  // namespace tally
