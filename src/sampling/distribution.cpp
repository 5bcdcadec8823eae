#include "sampling/distribution.h"
#include <algorithm>
#include <cmath>
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

void Distribution2D::build_row(const float *w, int n, float *cdf, uint32_t *guide) {
    // Accumulate in double, store in float: rounding keeps the CDF non-decreasing.
    double total = 0;
    for (int i = 0; i < n; ++i) total += (std::isfinite(w[i]) && w[i] > 0.f) ? double(w[i]) : 0.0;
    double acc = 0;
    cdf[0] = 0.f;
    for (int i = 0; i < n; ++i) {
        const double wi = (std::isfinite(w[i]) && w[i] > 0.f) ? double(w[i]) : 0.0;
        acc += total > 0 ? wi / total : 1.0 / n;
        cdf[i + 1] = float(acc);
    }
    cdf[n] = 1.f;
    // guide[k]: the cell holding t = 8k / n (the last i with cdf[i] <= t), k = 0 .. ceil(n/8).
    const int m = guide_size(n);
    int i = 0;
    for (int k = 0; k < m; ++k) {
        const float t = std::min(1.f, float(8.0 * k / n));
        while (i + 1 < n && cdf[i + 1] <= t) ++i;
        guide[k] = uint32_t(i);
    }
}

int Distribution2D::find(const float *cdf, const uint32_t *guide, int n, float u, float &frac) {
    // u in [8k/n, 8(k+1)/n): the answer lies in [guide[k], guide[k + 1]] (the cell holding
    // 8(k+1)/n is at or after it). Branchless binary search for the last cdf[i] <= u there.
    u = std::clamp(u, 0.f, OneMinusEpsilon);
    const int k = std::min(int(u * (float(n) * 0.125f)), guide_size(n) - 2);
    int lo = int(guide[k]), hi = int(guide[k + 1]);
    // Float rounding of u n / 8 against the guide's 8k / n can put k one off: widen (rarely).
    while (lo > 0 && cdf[lo] > u) --lo;
    while (hi + 1 < n && cdf[hi + 1] <= u) ++hi;
    for (int len = hi - lo + 1; len > 1;) {
        const int half = len / 2;
        lo = cdf[lo + half] <= u ? lo + half : lo;
        len -= half;
    }
    const float width = cdf[lo + 1] - cdf[lo];
    frac = width > 0.f ? std::min(OneMinusEpsilon, std::max(0.f, (u - cdf[lo]) / width)) : 0.f;
    return lo;
}

Distribution2D::Distribution2D(const std::vector<float> &func, int nu, int nv) : m_nu(nu), m_nv(nv) {
    if (nu <= 0 || nv <= 0) return;
    m_cdf.resize(size_t(nv) * (nu + 1));
    m_guide.resize(size_t(nv) * guide_size(nu));
    std::vector<float> marginal(nv);
    for (int v = 0; v < nv; ++v) {
        const float *row = func.data() + size_t(v) * nu;
        build_row(row, nu, m_cdf.data() + size_t(v) * (nu + 1), m_guide.data() + size_t(v) * guide_size(nu));
        // Marginal weight is the row's true integral (0 for black rows, even though the
        // conditional itself falls back to uniform).
        double sum = 0;
        for (int u = 0; u < nu; ++u) sum += (std::isfinite(row[u]) && row[u] > 0.f) ? row[u] : 0.f;
        marginal[v] = float(sum / nu);
    }
    m_marginal_cdf.resize(nv + 1);
    m_marginal_guide.resize(guide_size(nv));
    build_row(marginal.data(), nv, m_marginal_cdf.data(), m_marginal_guide.data());
}

Vec2 Distribution2D::sample_continuous(Vec2 u, float *pdf_out) const {
    float fy, fx;
    const int v = find(m_marginal_cdf.data(), m_marginal_guide.data(), m_nv, u.y, fy);
    const float *cdf = row_cdf(v);
    const int i = find(cdf, row_guide(v), m_nu, u.x, fx);
    if (pdf_out)
        *pdf_out = (m_marginal_cdf[v + 1] - m_marginal_cdf[v]) * float(m_nv) * (cdf[i + 1] - cdf[i]) * float(m_nu);
    return {in_cell(i, fx, m_nu), in_cell(v, fy, m_nv)};
}

float Distribution2D::in_cell(int i, float frac, int n) {
    // (i + frac) / n rounded into cell i as pdf() finds it (int(x n) == i), so that pdf() of the
    // sample reads the same cell even where rounding would cross a boundary.
    float x = std::min((float(i) + frac) / float(n), OneMinusEpsilon);
    while (x > 0.f && int(x * float(n)) > i) x = std::nextafter(x, 0.f);
    while (x < OneMinusEpsilon && int(x * float(n)) < i) x = std::nextafter(x, 1.f);
    return x;
}

float Distribution2D::pdf(Vec2 p) const {
    if (m_nu <= 0 || m_nv <= 0) return 0.f;
    const int v = clamp(int(p.y * float(m_nv)), 0, m_nv - 1), i = clamp(int(p.x * float(m_nu)), 0, m_nu - 1);
    const float *cdf = row_cdf(v);
    return (m_marginal_cdf[v + 1] - m_marginal_cdf[v]) * float(m_nv) * (cdf[i + 1] - cdf[i]) * float(m_nu);
}

size_t Distribution2D::memory_bytes() const {
    return (m_cdf.size() + m_marginal_cdf.size()) * sizeof(float) +
           (m_guide.size() + m_marginal_guide.size()) * sizeof(uint32_t);
}

}  // namespace meso
