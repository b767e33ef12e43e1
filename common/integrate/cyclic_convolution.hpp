#pragma once
// Cyclic convolution of two real sequences of one length L by a radix-2 FFT (zero-padded
// unless L is a power of two): y[i] = sum_j c[(i - j) mod L] x[j], O(L log L). It exists
// for the fast component-by-component lattice constructions (lattice_rule.cpp): a prime
// n's circulant has length (n - 1) / 2, an embedded 2^m rule's 2^(q-2). (No
// packaged FFT library is a dependency of this project; the transform is 40 lines.)
#include <complex>
#include <vector>

namespace tally {

// Precomputes the transform of `c` once, for many convolutions with the same c.
class CyclicConvolution {
 public:
  explicit CyclicConvolution(const std::vector<double>& c);
  size_t length() const { return length_; }
  // y[i] = sum_j c[(i - j) mod L] x[j] for i < L; x.size() must be L.
  std::vector<double> apply(const std::vector<double>& x) const;

 private:
  size_t length_ = 0;
  size_t fft_size_ = 0;
  std::vector<std::complex<double>> c_hat_;
  std::vector<std::complex<double>> twiddles_;  // of fft_size_, computed once
};

// In-place radix-2 FFT of a power-of-two length (inverse: conjugate twiddles, no 1/N).
void fft_radix2(std::vector<std::complex<double>>& a, bool inverse);
// The same with the twiddles of a.size() precomputed: w = fft_twiddles(a.size()).
std::vector<std::complex<double>> fft_twiddles(size_t n);
void fft_radix2(std::vector<std::complex<double>>& a, const std::vector<std::complex<double>>& w, bool inverse);

}  // namespace tally
