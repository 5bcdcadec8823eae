// Discrete Fourier transforms of any length (shared math): iterative radix-2 for powers of
// two, Bluestein's chirp-z convolution otherwise. Unnormalised; sign -1 forward, +1 inverse.
#pragma once
#include <complex>
#include <vector>

namespace meso {

using Complex = std::complex<double>;

class Dft {
public:
    explicit Dft(int n);
    /// In place on n contiguous values; `scratch` is working memory (one per thread).
    void transform(Complex *x, int sign, std::vector<Complex> &scratch) const;

private:
    static std::vector<Complex> twiddles(int m);
    /// Forward radix-2 FFT of length m_m (or m_n when it is a power of two).
    void pow2(Complex *a) const;
    int m_n, m_m;
    std::vector<Complex> m_twiddle, m_chirp, m_kernel;
};

/// In-place 2D inverse DFT (sign +1, unnormalised) of an h x w row-major array (TBB-parallel).
void inverse_dft_2d(std::vector<Complex> &a, int w, int h);

}  // namespace meso
