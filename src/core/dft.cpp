#include "core/dft.h"
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <algorithm>
#include <cmath>
#include <cstdint>

namespace meso {

namespace {
constexpr double kPi = 3.14159265358979323846;
}

Dft::Dft(int n) : m_n(n) {
    if ((n & (n - 1)) == 0) {
        m_m = n;
        m_twiddle = twiddles(n);
        return;
    }
    m_m = 1;
    while (m_m < 2 * n - 1) m_m *= 2;
    m_twiddle = twiddles(m_m);
    m_chirp.resize(n);
    for (int64_t k = 0; k < n; ++k) {  // exp(-i pi k^2 / n), k^2 reduced mod 2n for accuracy
        double a = kPi * double((k * k) % (2 * int64_t(n))) / n;
        m_chirp[k] = Complex(std::cos(a), -std::sin(a));
    }
    m_kernel.assign(m_m, Complex(0));
    for (int k = 0; k < n; ++k) m_kernel[k] = m_kernel[(m_m - k) % m_m] = std::conj(m_chirp[k]);
    pow2(m_kernel.data());
}

void Dft::transform(Complex *x, int sign, std::vector<Complex> &scratch) const {
    if (m_chirp.empty()) {
        if (sign > 0)
            for (int k = 0; k < m_n; ++k) x[k] = std::conj(x[k]);
        pow2(x);
        if (sign > 0)
            for (int k = 0; k < m_n; ++k) x[k] = std::conj(x[k]);
        return;
    }
    scratch.assign(m_m, Complex(0));
    for (int k = 0; k < m_n; ++k) scratch[k] = (sign > 0 ? std::conj(x[k]) : x[k]) * m_chirp[k];
    pow2(scratch.data());
    for (int k = 0; k < m_m; ++k) scratch[k] = std::conj(scratch[k] * m_kernel[k]);
    pow2(scratch.data());  // conj(FFT(conj(.))) = inverse FFT, unnormalised
    for (int k = 0; k < m_n; ++k) {
        Complex v = std::conj(scratch[k]) * m_chirp[k] / double(m_m);
        x[k] = sign > 0 ? std::conj(v) : v;
    }
}

std::vector<Complex> Dft::twiddles(int m) {
    std::vector<Complex> t(std::max(1, m / 2));
    for (int k = 0; k < m / 2; ++k) t[k] = std::polar(1.0, -2 * kPi * k / m);
    return t;
}

void Dft::pow2(Complex *a) const {
    int m = m_m;
    for (int i = 1, j = 0; i < m; ++i) {
        int bit = m >> 1;
        for (; j & bit; bit >>= 1) j ^= bit;
        j ^= bit;
        if (i < j) std::swap(a[i], a[j]);
    }
    for (int len = 2; len <= m; len <<= 1) {
        int step = m / len;
        for (int i = 0; i < m; i += len)
            for (int k = 0; k < len / 2; ++k) {
                Complex u = a[i + k], v = a[i + k + len / 2] * m_twiddle[size_t(k) * step];
                a[i + k] = u + v;
                a[i + k + len / 2] = u - v;
            }
    }
}

void inverse_dft_2d(std::vector<Complex> &a, int w, int h) {
    Dft rows(w), cols(h);
    tbb::parallel_for(tbb::blocked_range<int>(0, h), [&](const tbb::blocked_range<int> &r) {
        std::vector<Complex> scratch;
        for (int j = r.begin(); j < r.end(); ++j) rows.transform(&a[size_t(j) * w], +1, scratch);
    });
    tbb::parallel_for(tbb::blocked_range<int>(0, w), [&](const tbb::blocked_range<int> &r) {
        std::vector<Complex> col(h), scratch;
        for (int i = r.begin(); i < r.end(); ++i) {
            for (int j = 0; j < h; ++j) col[j] = a[size_t(j) * w + i];
            cols.transform(col.data(), +1, scratch);
            for (int j = 0; j < h; ++j) a[size_t(j) * w + i] = col[j];
        }
    });
}


}  // namespace meso
