#include "sampling/distribution.h"
#include <algorithm>
#include <numeric>

namespace meso {

Distribution1D::Distribution1D(const std::vector<float> &weights) {
    m_func.resize(weights.size());
    for (size_t i = 0; i < weights.size(); ++i) {
        float w = weights[i];
        m_func[i] = (std::isfinite(w) && w > 0.f) ? w : 0.f;
    }
    size_t n = m_func.size();
    if (n == 0) return;
    m_cdf.assign(n + 1, 0.0);
    for (size_t i = 0; i < n; ++i) m_cdf[i + 1] = m_cdf[i] + double(m_func[i]) / double(n);
    double total = m_cdf[n];
    if (!(total > 0.0)) {
        std::fill(m_func.begin(), m_func.end(), 1.f);
        for (size_t i = 0; i <= n; ++i) m_cdf[i] = double(i) / double(n);
        m_func_int = 1.f;
    } else {
        m_func_int = float(total);
        for (size_t i = 1; i <= n; ++i) m_cdf[i] /= total;
        m_cdf[n] = 1.0;
    }
    m_guide.resize(n);
    size_t i = 0;
    for (size_t k = 0; k < n; ++k) {
        double t = double(k) / double(n);
        while (i + 1 < n && m_cdf[i + 1] <= t) ++i;
        m_guide[k] = uint32_t(i);
    }
}

size_t Distribution1D::find_interval(double u) const {
    // Cell i with cdf[i] <= u < cdf[i+1]. The guide entries of u's bucket and the next
    // bound it: cdf[lo] <= k/n <= u and cdf[hi+1] >= cdf[guide[k+1]+1] > (k+1)/n > u, so
    // the answer is the last index in [lo, hi] with cdf <= u, found by a branchless
    // binary search (no mispredictions; skewed rows such as a sun stay logarithmic).
    const size_t n = m_func.size();
    u = std::clamp(u, 0.0, std::nextafter(1.0, 0.0));
    const size_t k = std::min(n - 1, size_t(u * double(n)));
    const size_t lo = m_guide[k], hi = k + 1 < n ? std::min<size_t>(n - 1, m_guide[k + 1] + 1) : n - 1;
    const double *base = m_cdf.data() + lo;
    for (size_t len = hi - lo + 1; len > 1;) {
        size_t half = len / 2;
        base = base[half] <= u ? base + half : base;
        len -= half;
    }
    return size_t(base - m_cdf.data());
}

size_t Distribution1D::sample_discrete(float u, float *pmf_out, float *u_remapped) const {
    size_t i = find_interval(u);
    double width = m_cdf[i + 1] - m_cdf[i];
    if (pmf_out) *pmf_out = float(width);
    if (u_remapped) *u_remapped = width > 0 ? std::min(OneMinusEpsilon, float((u - m_cdf[i]) / width)) : 0.f;
    return i;
}

float Distribution1D::sample_continuous(float u, float *pdf_out, size_t *offset) const {
    size_t i = find_interval(u);
    if (offset) *offset = i;
    double width = m_cdf[i + 1] - m_cdf[i];
    double du = width > 0 ? (double(u) - m_cdf[i]) / width : 0.0;
    if (pdf_out) *pdf_out = m_func_int > 0 ? m_func[i] / m_func_int : 0.f;
    float x = float((double(i) + std::clamp(du, 0.0, 1.0)) / double(size()));
    return std::min(x, OneMinusEpsilon);
}

float Distribution1D::pdf(float x) const {
    if (m_func.empty() || !(m_func_int > 0)) return 0.f;
    size_t i = std::min(size() - 1, size_t(std::max(0.f, x) * size()));
    return m_func[i] / m_func_int;
}

Distribution2D::Distribution2D(const std::vector<float> &func, int nu, int nv) : m_nu(nu), m_nv(nv) {
    m_conditional.reserve(nv);
    std::vector<float> marginal(nv);
    for (int v = 0; v < nv; ++v) {
        std::vector<float> row(func.begin() + size_t(v) * nu, func.begin() + size_t(v + 1) * nu);
        m_conditional.emplace_back(row);
        // Marginal weight is the row's true integral (0 for black rows, even though the
        // conditional itself falls back to uniform).
        double s = 0;
        for (float w : row) s += (std::isfinite(w) && w > 0.f) ? w : 0.f;
        marginal[v] = float(s / nu);
    }
    m_marginal = Distribution1D(marginal);
}

Vec2 Distribution2D::sample_continuous(Vec2 u, float *pdf_out) const {
    float pdf_v, pdf_u;
    size_t v;
    float y = m_marginal.sample_continuous(u.y, &pdf_v, &v);
    float x = m_conditional[v].sample_continuous(u.x, &pdf_u);
    if (pdf_out) *pdf_out = pdf_u * pdf_v;
    return {x, y};
}

float Distribution2D::pdf(Vec2 p) const {
    int iv = clamp(int(p.y * m_nv), 0, m_nv - 1);
    return m_marginal.pdf(p.y) * m_conditional[iv].pdf(p.x);
}

size_t Distribution2D::memory_bytes() const {
    size_t b = (m_marginal.size()) * (sizeof(float) + sizeof(double));
    for (auto &c : m_conditional) b += c.size() * (sizeof(float) + sizeof(double));
    return b;
}

}  // namespace meso
