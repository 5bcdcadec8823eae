// MIP pyramid construction (exact area-box downsampling, any size) and lookups.
// See mipmap.h for the conventions.
#include "texture/mipmap.h"
#include <algorithm>
#include <cmath>
#include "core/error.h"
#include "core/math.h"

namespace meso {

bool parse_wrap_mode(const std::string &s, WrapMode &out) {
    if (s == "repeat") out = WrapMode::Repeat;
    else if (s == "clamp") out = WrapMode::Clamp;
    else if (s == "mirror") out = WrapMode::Mirror;
    else return false;
    return true;
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

int MipMap::wrap_index(int i, int n) const {
    switch (m_wrap) {
        case WrapMode::Clamp: return clamp(i, 0, n - 1);
        case WrapMode::Mirror: {
            int p = 2 * n, m = ((i % p) + p) % p;
            return m < n ? m : p - 1 - m;
        }
        case WrapMode::Repeat:
        default: return ((i % n) + n) % n;
    }
}

float MipMap::level_for_footprint(float dudx, float dudy, float dvdx, float dvdy) const {
    float w = float(width(0)), h = float(height(0));
    float lx = std::sqrt(sqr(dudx * w) + sqr(dvdx * h));
    float ly = std::sqrt(sqr(dudy * w) + sqr(dvdy * h));
    float width_texels = std::max(lx, ly);
    if (!(width_texels > 1.f)) return 0.f;  // zero, sub-texel or NaN footprint
    float level = std::log2(width_texels);
    return std::min(level, float(levels() - 1));
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
    float tmp[64];
    std::vector<float> heap;
    float *b = tmp;
    if (m_channels > 64) {
        heap.resize(m_channels);
        b = heap.data();
    }
    bilinear(l0 + 1, u, v, b);
    for (int k = 0; k < m_channels; ++k) out[k] = (1.f - t) * out[k] + t * b[k];
}

void MipMap::filtered(float u, float v, float dudx, float dudy, float dvdx, float dvdy, float *out) const {
    trilinear(level_for_footprint(dudx, dudy, dvdx, dvdy), u, v, out);
}

size_t MipMap::memory_bytes() const {
    size_t b = 0;
    for (auto &L : m_levels) b += L.data.size() * sizeof(float);
    return b;
}

}  // namespace meso
