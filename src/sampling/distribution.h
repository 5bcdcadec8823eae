// Piecewise-constant 1D and 2D distributions (inverse-CDF sampling), used for light
// selection and environment-map importance sampling.
#pragma once
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

/// 2D piecewise-constant over [0,1]^2 from an nu x nv grid (row-major, v rows).
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
    int m_nu = 0, m_nv = 0;
    std::vector<Distribution1D> m_conditional;  ///< one per row v
    Distribution1D m_marginal;
};

}  // namespace meso
