// MIP pyramid construction (exact area-box downsampling, any size) and lookups: nearest,
// bilinear, trilinear and EWA. See mipmap.h for the conventions.
#include "texture/mipmap.h"
#include <algorithm>
#include <cmath>
#include "core/error.h"
#include "core/math.h"
#include "core/properties.h"

namespace meso {

FootprintFilter parse_footprint_filter(const Properties &p, const std::string &key) {
    return p.get_enum<FootprintFilter>(
        key, "trilinear",
        {{"trilinear", FootprintFilter::Trilinear}, {"ewa", FootprintFilter::Ewa}, {"none", FootprintFilter::None}});
}

namespace {

/// Weights of the 1D box downsampling n -> m (m = max(1, n/2)): output i averages the input
/// interval [i n/m, (i+1) n/m); returns, per output, (first input index, weights...).
struct Taps {
    std::vector<int> first;
    std::vector<std::vector<float>> w;
};

Taps box_taps(int n, int m) {
    Taps t;
    t.first.resize(m);
    t.w.resize(m);
    double ratio = double(n) / m;
    for (int i = 0; i < m; ++i) {
        double a = i * ratio, b = (i + 1) * ratio;
        int j0 = int(std::floor(a)), j1 = std::min(n - 1, int(std::ceil(b)) - 1);
        t.first[i] = j0;
        for (int j = j0; j <= j1; ++j) {
            double overlap = std::min(b, double(j + 1)) - std::max(a, double(j));
            t.w[i].push_back(float(std::max(0.0, overlap) / ratio));
        }
    }
    return t;
}

/// n values for one lookup: on the stack up to 64 channels, on the heap beyond.
template <typename T> class ChannelScratch {
public:
    explicit ChannelScratch(int n) : m_ptr(m_stack) {
        if (n > 64) {
            m_heap.resize(n);
            m_ptr = m_heap.data();
        }
    }
    T *data() { return m_ptr; }

private:
    T m_stack[64];
    std::vector<T> m_heap;
    T *m_ptr;
};

/// Truncated Gaussian of the EWA filter, w(r²) = exp(-α r²) - exp(-α) on r² in [0, 1] (zero
/// at the ellipse's edge), α = 2 as in pbrt: σ is half the semi-axis. Tabulated at
/// kEwaLutSize + 1 points and interpolated linearly (relative error < 1e-4).
constexpr int kEwaLutSize = 128;
constexpr float kEwaAlpha = 2.f;

struct EwaWeights {
    float w[kEwaLutSize + 1];
    EwaWeights() {
        for (int i = 0; i <= kEwaLutSize; ++i)
            w[i] = float(std::exp(-double(kEwaAlpha) * i / kEwaLutSize) - std::exp(-double(kEwaAlpha)));
    }
    /// r2 in [0, 1).
    float operator()(float r2) const {
        float x = r2 * kEwaLutSize;
        int i = std::min(int(x), kEwaLutSize - 1);
        return w[i] + (x - float(i)) * (w[i + 1] - w[i]);
    }
};
const EwaWeights kEwaWeights;

}  // namespace

MipMap::MipMap(int width, int height, int channels, std::vector<float> data, WrapMode wrap)
    : m_channels(channels), m_wrap(wrap) {
    if (width <= 0 || height <= 0 || channels <= 0 || data.size() != size_t(width) * height * channels)
        throw MesoError("MipMap: image size and data do not match");
    m_levels.push_back(Level{width, height, std::move(data)});
    while (m_levels.back().w > 1 || m_levels.back().h > 1) {
        const Level &src = m_levels.back();
        int nw = std::max(1, src.w / 2), nh = std::max(1, src.h / 2);
        Taps tx = box_taps(src.w, nw), ty = box_taps(src.h, nh);
        // Separable: rows first (src.h x nw), then columns (nh x nw); accumulate in double.
        std::vector<double> tmp(size_t(src.h) * nw * channels, 0.0);
        for (int y = 0; y < src.h; ++y)
            for (int x = 0; x < nw; ++x)
                for (size_t k = 0; k < tx.w[x].size(); ++k) {
                    const float *s = &src.data[(size_t(y) * src.w + tx.first[x] + k) * channels];
                    double *d = &tmp[(size_t(y) * nw + x) * channels];
                    for (int c = 0; c < channels; ++c) d[c] += double(tx.w[x][k]) * s[c];
                }
        Level dst{nw, nh, std::vector<float>(size_t(nw) * nh * channels)};
        for (int y = 0; y < nh; ++y)
            for (int x = 0; x < nw; ++x)
                for (int c = 0; c < channels; ++c) {
                    double acc = 0;
                    for (size_t k = 0; k < ty.w[y].size(); ++k)
                        acc += double(ty.w[y][k]) * tmp[((size_t(ty.first[y]) + k) * nw + x) * channels + c];
                    dst.data[(size_t(y) * nw + x) * channels + c] = float(acc);
                }
        m_levels.push_back(std::move(dst));
    }
}

void MipMap::level_mean(int level, float *out) const {
    const Level &L = m_levels[level];
    std::vector<double> acc(m_channels, 0.0);
    for (size_t i = 0; i < size_t(L.w) * L.h; ++i)
        for (int c = 0; c < m_channels; ++c) acc[c] += L.data[i * m_channels + c];
    for (int c = 0; c < m_channels; ++c) out[c] = float(acc[c] / (double(L.w) * L.h));
}

int MipMap::wrap_index(int i, int n) const { return int(meso::wrap_index(i, n, m_wrap)); }

float MipMap::level_for_footprint(float dudx, float dudy, float dvdx, float dvdy) const {
    float w = float(width(0)), h = float(height(0));
    float lx = std::sqrt(sqr(dudx * w) + sqr(dvdx * h));
    float ly = std::sqrt(sqr(dudy * w) + sqr(dvdy * h));
    float width_texels = std::max(lx, ly);
    if (!(width_texels > 1.f)) return 0.f;  // zero, sub-texel or NaN footprint
    float level = std::log2(width_texels);
    return std::min(level, float(levels() - 1));
}

double MipMap::footprint_width(float dudx, float dudy, float dvdx, float dvdy) const {
    auto clean = [](float d) { return std::isnan(d) ? 0.0 : double(clamp(d, -1e30f, 1e30f)); };
    const double w = width(0), h = height(0);
    const double lx = std::hypot(clean(dudx) * w, clean(dvdx) * h), ly = std::hypot(clean(dudy) * w, clean(dvdy) * h);
    return std::max(lx, ly);
}

/// Texel coordinate of u on an n-texel axis, kept finite and in a safe integer range (the
/// wrap is periodic, so reducing u modulo 2 first changes nothing for repeat/mirror).
static float texel_coord(float u, int n, WrapMode wrap) {
    if (!std::isfinite(u)) u = 0.f;
    if (wrap == WrapMode::Clamp) u = clamp(u, -1.f, 2.f);
    else u = u - 2.f * std::floor(u * 0.5f);
    return u * n;
}

void MipMap::nearest(int level, float u, float v, float *out) const {
    level = clamp(level, 0, levels() - 1);
    const Level &L = m_levels[level];
    int x = wrap_index(int(std::floor(texel_coord(u, L.w, m_wrap))), L.w);
    int y = wrap_index(int(std::floor(texel_coord(v, L.h, m_wrap))), L.h);
    const float *t = texel(level, x, y);
    std::copy(t, t + m_channels, out);
}

void MipMap::bilinear(int level, float u, float v, float *out) const {
    level = clamp(level, 0, levels() - 1);
    const Level &L = m_levels[level];
    float x = texel_coord(u, L.w, m_wrap) - 0.5f, y = texel_coord(v, L.h, m_wrap) - 0.5f;
    float fx0 = std::floor(x), fy0 = std::floor(y);
    float fx = x - fx0, fy = y - fy0;
    int x0 = wrap_index(int(fx0), L.w), x1 = wrap_index(int(fx0) + 1, L.w);
    int y0 = wrap_index(int(fy0), L.h), y1 = wrap_index(int(fy0) + 1, L.h);
    const float *a = texel(level, x0, y0), *b = texel(level, x1, y0);
    const float *c = texel(level, x0, y1), *d = texel(level, x1, y1);
    for (int k = 0; k < m_channels; ++k)
        out[k] = (1.f - fy) * ((1.f - fx) * a[k] + fx * b[k]) + fy * ((1.f - fx) * c[k] + fx * d[k]);
}

void MipMap::trilinear(float level, float u, float v, float *out) const {
    if (!(level > 0.f)) return bilinear(0, u, v, out);
    if (level >= float(levels() - 1)) return bilinear(levels() - 1, u, v, out);
    int l0 = int(std::floor(level));
    float t = level - float(l0);
    bilinear(l0, u, v, out);
    if (t == 0.f) return;
    ChannelScratch<float> scratch(m_channels);
    float *b = scratch.data();
    bilinear(l0 + 1, u, v, b);
    for (int k = 0; k < m_channels; ++k) out[k] = (1.f - t) * out[k] + t * b[k];
}

void MipMap::lookup(FootprintFilter filter, float u, float v, float dudx, float dudy, float dvdx, float dvdy,
                    float *out, float max_anisotropy) const {
    switch (filter) {
        case FootprintFilter::None: bilinear(0, u, v, out); break;
        case FootprintFilter::Trilinear: filtered(u, v, dudx, dudy, dvdx, dvdy, out); break;
        case FootprintFilter::Ewa: ewa(u, v, dudx, dudy, dvdx, dvdy, out, max_anisotropy); break;
    }
}

void MipMap::filtered(float u, float v, float dudx, float dudy, float dvdx, float dvdy, float *out) const {
    trilinear(level_for_footprint(dudx, dudy, dvdx, dvdy), u, v, out);
}

void MipMap::ewa(float u, float v, float dudx, float dudy, float dvdx, float dvdy, float *out,
                 float max_anisotropy) const {
    // Semi-axes a = (dudx, dvdx), b = (dudy, dvdy) in level-0 texels, in double so that the
    // squares of any float stay finite; NaN counts as 0 and |d| > 1e30 is "huge" (far past
    // the coarsest level of any image that fits in memory).
    auto clean = [](float d) { return std::isnan(d) ? 0.0 : double(clamp(d, -1e30f, 1e30f)); };
    const double W = width(0), H = height(0);
    const double ax = W * clean(dudx), ay = H * clean(dvdx), bx = W * clean(dudy), by = H * clean(dvdy);
    // Σ = J Jᵀ, J = [a b]: the ellipse is { p : pᵀ Σ⁻¹ p <= 1 }.
    double sxx = ax * ax + bx * bx, sxy = ax * ay + bx * by, syy = ay * ay + by * by;
    const double half_trace = 0.5 * (sxx + syy);
    if (!(half_trace > 0.0)) return bilinear(0, u, v, out);  // zero footprint: magnification
    const double dev = std::hypot(0.5 * (sxx - syy), sxy);
    const double lmax = half_trace + dev;  // major semi-axis²
    const double cross = ax * by - ay * bx;
    double lmin = cross * cross / lmax;  // minor semi-axis² = det Σ / lmax (det Σ = det(J)²)

    // Widen the minor axis to major / max_anisotropy: Σ += δ e₂ e₂ᵀ along the minor
    // eigenvector e₂ (this also turns parallel axes, a segment, into an ellipse).
    float aniso = max_anisotropy >= 1.f ? std::min(max_anisotropy, kEwaMaxAnisotropy) : 1.f;
    const double lmin_clamped = lmax / sqr(double(aniso));
    if (lmin < lmin_clamped) {
        // Major eigenvector e₁: the larger of the two (equivalent) eigenvector formulas.
        double p1x = sxy, p1y = lmax - sxx, p2x = lmax - syy, p2y = sxy;
        double ex = p1x, ey = p1y;
        if (p2x * p2x + p2y * p2y > p1x * p1x + p1y * p1y) ex = p2x, ey = p2y;
        double n = std::hypot(ex, ey);
        double e2x = 1.0, e2y = 0.0;  // isotropic Σ: any direction
        if (n > 0.0) e2x = -ey / n, e2y = ex / n;
        double delta = lmin_clamped - lmin;
        sxx += delta * e2x * e2x;
        sxy += delta * e2x * e2y;
        syy += delta * e2y * e2y;
        lmin = lmin_clamped;
    }

    // Level from the minor semi-axis: on level floor(level) it spans 1-2 texels, so the
    // ellipse holds at most ~π (2·aniso + 1)·√5 texels there and a quarter on the next.
    const double minor = std::sqrt(lmin);
    const float level = minor > 1.0 ? float(std::log2(minor)) : 0.f;
    const int last = levels() - 1;
    if (level >= float(last)) {
        const float *t = texel(last, 0, 0);
        std::copy(t, t + m_channels, out);
        return;
    }
    const int l0 = int(std::floor(level));
    const float t = level - float(l0);
    ewa_level(l0, u, v, sxx, sxy, syy, out);
    if (t == 0.f) return;
    ChannelScratch<float> scratch(m_channels);
    float *b = scratch.data();
    ewa_level(l0 + 1, u, v, sxx, sxy, syy, b);
    for (int k = 0; k < m_channels; ++k) out[k] += t * (b[k] - out[k]);  // exact when equal
}

void MipMap::ewa_level(int level, float u, float v, double sxx, double sxy, double syy, float *out) const {
    const Level &L = m_levels[level];
    if (L.w == 1 && L.h == 1) {
        std::copy(L.data.begin(), L.data.begin() + m_channels, out);
        return;
    }
    // Σ in this level's texels, plus the unit reconstruction filter: M = D Σ D + I,
    // D = diag(w_l / w_0, h_l / h_0). r² = pᵀ M⁻¹ p = A x² + B x y + C y² (det M >= 1).
    const double fx = double(L.w) / width(0), fy = double(L.h) / height(0);
    const double mxx = sxx * fx * fx + 1.0, mxy = sxy * fx * fy, myy = syy * fy * fy + 1.0;
    const double det = mxx * myy - mxy * mxy;
    const float A = float(myy / det), B = float(-2.0 * mxy / det), C = float(mxx / det);
    // Texel centres are at integer coordinates after the -0.5 shift (as in bilinear()).
    const float cx = texel_coord(u, L.w, m_wrap) - 0.5f, cy = texel_coord(v, L.h, m_wrap) - 0.5f;
    const float ry = float(std::sqrt(myy));  // the ellipse's half-height
    const int y0 = int(std::ceil(cy - ry)), y1 = int(std::floor(cy + ry));

    ChannelScratch<double> scratch(m_channels);
    double *acc = scratch.data();
    std::fill(acc, acc + m_channels, 0.0);
    double wsum = 0.0;
    for (int y = y0; y <= y1; ++y) {
        // Row span: A x² + B y x + C y² < 1, solved for x around the row's centre.
        const float dy = float(y) - cy;
        const float disc = B * B * dy * dy - 4.f * A * (C * dy * dy - 1.f);
        if (!(disc > 0.f)) continue;
        const float xc = cx - B * dy / (2.f * A), hw = std::sqrt(disc) / (2.f * A);
        const int x0 = int(std::ceil(xc - hw)), x1 = int(std::floor(xc + hw));
        const float *row = &L.data[size_t(wrap_index(y, L.h)) * L.w * m_channels];
        for (int x = x0; x <= x1; ++x) {
            const float dx = float(x) - cx;
            const float r2 = A * dx * dx + B * dx * dy + C * dy * dy;
            if (!(r2 < 1.f)) continue;
            const float w = kEwaWeights(std::max(r2, 0.f));
            const int xi = x >= 0 && x < L.w ? x : wrap_index(x, L.w);
            const float *p = row + size_t(xi) * m_channels;
            // float x float products are exact in double, so a constant image stays exact.
            for (int k = 0; k < m_channels; ++k) acc[k] += double(w) * p[k];
            wsum += w;
        }
    }
    // The ellipse contains a unit disc, hence at least one texel centre; guard anyway.
    if (!(wsum > 0.0)) return bilinear(level, u, v, out);
    for (int k = 0; k < m_channels; ++k) out[k] = float(acc[k] / wsum);
}

size_t MipMap::memory_bytes() const {
    size_t b = 0;
    for (auto &L : m_levels) b += L.data.size() * sizeof(float);
    return b;
}

}  // namespace meso
