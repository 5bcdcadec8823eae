// Piecewise-constant 1D and 2D distributions (inverse-CDF sampling), used for light
// selection and environment-map importance sampling.
#pragma once
#include <cstdint>
#include <vector>
#include "core/vec.h"

namespace meso {

class Distribution1D {
public:
    Distribution1D() = default;
    /// Non-negative weights; all-zero (or empty) input becomes uniform. NaN/negative -> 0.
    explicit Distribution1D(const std::vector<float> &weights);
    size_t size() const { return m_func.size(); }
    /// Discrete: index with probability weight/sum; `pmf` out; `u_remapped` reuses u.
    size_t sample_discrete(float u, float *pmf = nullptr, float *u_remapped = nullptr) const;
    float pmf(size_t i) const { return m_func_int > 0 ? m_func[i] / (m_func_int * size()) : 0.f; }
    /// Continuous on [0,1): returns x, density `pdf` (w.r.t. x), cell `offset`.
    float sample_continuous(float u, float *pdf = nullptr, size_t *offset = nullptr) const;
    /// Density of x in [0,1] for the continuous distribution.
    float pdf(float x) const;
    float integral() const { return m_func_int; }
    const std::vector<float> &func() const { return m_func; }

private:
    std::vector<float> m_func;  ///< sanitised weights
    std::vector<double> m_cdf;  ///< size()+1 entries, double for exactness on large maps
    /// Cutpoint guide table (Chen & Asau 1974): m_guide[k] = the cell containing k/n, so an
    /// inverse-CDF lookup starts next to its answer (expected O(1) instead of a binary search).
    std::vector<uint32_t> m_guide;
    size_t find_interval(double u) const;
    float m_func_int = 0.f;     ///< average of func (integral over [0,1])
};

/// 2D piecewise-constant over [0,1]^2 from an nu x nv grid (row-major, v rows), for
/// environment maps: O(1) expected inverse-CDF sampling with float tables laid out for the
/// cache. Each row's CDF (nu + 1 floats, one contiguous run; rows back to back, then the
/// marginal's nv + 1) and a cutpoint guide per 8 cells (Chen & Asau 1974: the cell holding k/m)
/// put a lookup within a cache line or two of its answer. A cell's probability is the
/// difference of its two float CDF entries, and both sample_continuous() and pdf() read it
/// there (two adjacent floats): the pdf is exactly that of the sampling, and it integrates to 1
/// exactly. Cells whose weight is below float resolution of their CDF (about 6e-8 of the row's
/// total) get probability 0 in both; they carry less than that share of the light.
class Distribution2D {
public:
    Distribution2D() = default;
    Distribution2D(const std::vector<float> &func, int nu, int nv);
    /// Returns (u, v) in [0,1)^2 and the density w.r.t. area on [0,1]^2.
    Vec2 sample_continuous(Vec2 u, float *pdf) const;
    float pdf(Vec2 p) const;
    int nu() const { return m_nu; }
    int nv() const { return m_nv; }
    size_t memory_bytes() const;

private:
    /// One sanitised row of weights into cdf[0..n] (0 .. 1; uniform when all zero) and its guide.
    static void build_row(const float *w, int n, float *cdf, uint32_t *guide);
    /// Cell i of the row with cdf[i] <= u < cdf[i + 1] (never a zero-width cell) and the remapped
    /// position (u - cdf[i]) / width in [0, 1).
    static int find(const float *cdf, const uint32_t *guide, int n, float u, float &frac);
    static float in_cell(int i, float frac, int n);
    static int guide_size(int n) { return (n + 7) / 8 + 1; }
    const float *row_cdf(int v) const { return m_cdf.data() + size_t(v) * (m_nu + 1); }
    const uint32_t *row_guide(int v) const { return m_guide.data() + size_t(v) * guide_size(m_nu); }

    int m_nu = 0, m_nv = 0;
    std::vector<float> m_cdf;       ///< nv conditional rows of nu + 1, then the marginal's nv + 1
    std::vector<uint32_t> m_guide;  ///< guide_size(nu) per row, then guide_size(nv)
    std::vector<float> m_marginal_cdf;
    std::vector<uint32_t> m_marginal_guide;
};

}  // namespace meso
