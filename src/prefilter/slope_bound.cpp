// A local bound on the slopes that can shadow a point of a periodic heightfield; see slope_bound.h.
#include "prefilter/slope_bound.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace meso::prefilter {

namespace {
constexpr int kSlopeLevels = 3;  // near squares of levels 0, 1, 2
inline int64_t wrap(int64_t a, int n) {
    const int64_t r = a % n;
    return r < 0 ? r + n : r;
}
}  // namespace

SlopeBound::SlopeBound(const Heightfield &hf) : m_hf(hf) {
    const int W = hf.width(), H = hf.height();
    // Level 0: each cell's largest |∇h| of the bilinear patch (attained at a corner).
    Level l0{W, H, {}, std::vector<float>(size_t(W) * H)};
    double g2 = 0;
    float top = -std::numeric_limits<float>::infinity();
    for (int j = 0; j < H; ++j)
        for (int i = 0; i < W; ++i) {
            const double h00 = hf.vertex(i, j), h10 = hf.vertex(i + 1, j), h01 = hf.vertex(i, j + 1),
                         h11 = hf.vertex(i + 1, j + 1);
            const double ax = h10 - h00, bx = h11 - h01, ay = h01 - h00, by = h11 - h10;
            const double L2 = std::max({ax * ax + ay * ay, ax * ax + by * by, bx * bx + ay * ay, bx * bx + by * by});
            g2 = std::max(g2, L2);
            // Rounded up to the next float: the bound must not fall below the true slope.
            l0.max_slope[size_t(j) * W + size_t(i)] =
                std::nextafter(float(std::sqrt(L2)), std::numeric_limits<float>::infinity());
            top = std::max(top, float(h00));
        }
    m_global = std::sqrt(g2);
    m_top = top;
    m_levels.push_back(std::move(l0));
    // Levels k >= 1 while 2^k divides both sizes: each node's highest vertex (level 1 from the
    // 3 x 3 vertices of its 2 x 2 cells) and, up to level 2, its cells' largest slope.
    for (int k = 1; W % (1 << k) == 0 && H % (1 << k) == 0; ++k) {
        const Level &f = m_levels.back();
        Level l{f.w / 2, f.h / 2, std::vector<float>(size_t(f.w / 2) * size_t(f.h / 2)), {}};
        if (k < kSlopeLevels) l.max_slope.resize(l.max_height.size());
        for (int b = 0; b < l.h; ++b)
            for (int a = 0; a < l.w; ++a) {
                float mh = -std::numeric_limits<float>::infinity(), ms = 0.f;
                if (k == 1) {
                    for (int dj = 0; dj <= 2; ++dj)
                        for (int di = 0; di <= 2; ++di) mh = std::max(mh, hf.vertex(2 * a + di, 2 * b + dj));
                }
                for (int dj = 0; dj < 2; ++dj)
                    for (int di = 0; di < 2; ++di) {
                        const size_t c = size_t(2 * b + dj) * size_t(f.w) + size_t(2 * a + di);
                        if (k > 1) mh = std::max(mh, f.max_height[c]);
                        if (k < kSlopeLevels) ms = std::max(ms, f.max_slope[c]);
                    }
                const size_t n = size_t(b) * size_t(l.w) + size_t(a);
                l.max_height[n] = mh;
                if (k < kSlopeLevels) l.max_slope[n] = ms;
            }
        m_levels.push_back(std::move(l));
    }
}

float SlopeBound::block_max(const Level &l, const std::vector<float> &v, int64_t a, int64_t b) {
    float m = -std::numeric_limits<float>::infinity();
    for (int64_t db = -1; db <= 1; ++db) {
        const size_t row = size_t(wrap(b + db, l.h)) * size_t(l.w);
        for (int64_t da = -1; da <= 1; ++da) m = std::max(m, v[row + size_t(wrap(a + da, l.w))]);
    }
    return m;
}

SlopeBound::Local SlopeBound::local(double x, double y, double z0) const {
    Local out;
    out.slope = m_global;
    if (!std::isfinite(x) || !std::isfinite(y) || !(double(m_hf.eval(x, y)) <= z0)) return out;
    out.x = x, out.y = y;
    const int J = int(m_levels.size());
    const int K = std::min(kSlopeLevels, J);
    double near[kSlopeLevels];
    double tail = -std::numeric_limits<double>::infinity();  // max of the ring terms from level K on
    for (int j = 0; j < J; ++j) {
        const double n = double(int64_t(1) << j);
        const double fa = std::floor(x / n), fb = std::floor(y / n);
        Square &sq = out.squares[j];
        sq = {(fa - 1.0) * n, (fa + 2.0) * n, (fb - 1.0) * n, (fb + 2.0) * n, 0.0};
        const double r = std::min({x - sq.x0, sq.x1 - x, y - sq.y0, sq.y1 - y});
        out.count = j + 1;
        if (j < K) near[j] = block_max(m_levels[size_t(j)], m_levels[size_t(j)].max_slope, int64_t(fa), int64_t(fb));
        // Beyond the level-j square: the level-(j + 1) squares' highest point, or the map's.
        const double beyond = (m_top - z0) / r;
        if (j >= K && beyond <= tail) {  // no farther ring can raise the tail: it covers them all
            sq.beyond = beyond;
            break;
        }
        double t = beyond;
        if (j + 1 < J) t = (double(block_max(m_levels[size_t(j) + 1], m_levels[size_t(j) + 1].max_height,
                                             int64_t(std::floor(x / (2.0 * n))), int64_t(std::floor(y / (2.0 * n))))) -
                            z0) / r;
        // Where the level-(j + 1) squares lie below z0, so does the near square: no slope bound.
        if (j < K && t <= 0.0) near[j] = 0.0;
        sq.beyond = t;
        if (j >= K) tail = std::max(tail, t);
        if (j >= K && tail >= m_global) {  // no better than the global slope anywhere
            out.count = 0;
            return out;
        }
    }
    // Suffix maxima: squares[j].beyond = the largest ring term outside square j.
    double best = m_global, sfx = -std::numeric_limits<double>::infinity();
    for (int j = out.count - 1; j >= 0; --j) {
        sfx = std::max(sfx, out.squares[j].beyond);
        out.squares[j].beyond = sfx;
        if (j < K) best = std::min(best, std::max(near[j], sfx));
    }
    out.slope = std::max(best, 0.0);
    return out;
}

float SlopeBound::reach(const Local &l, Vec3 w) {
    const double run = std::sqrt(double(w.x) * w.x + double(w.y) * w.y);
    if (!(run > 0.0) || !(w.z > 0.f)) return Infinity;
    for (int j = 0; j < l.count; ++j) {
        const Square &sq = l.squares[j];
        // Above every point outside square j (unoccluded_by_slope's margins): the ray can only
        // be blocked before it leaves the square.
        if (!(double(w.z) > sq.beyond * run * (1.0 + 1e-4) + 1e-6)) continue;
        double t = std::numeric_limits<double>::infinity();
        if (w.x != 0.f) t = std::min(t, ((w.x > 0.f ? sq.x1 : sq.x0) - l.x) / double(w.x));
        if (w.y != 0.f) t = std::min(t, ((w.y > 0.f ? sq.y1 : sq.y0) - l.y) / double(w.y));
        return float(t * (1.0 + 1e-4) + 1e-3);
    }
    return Infinity;
}

size_t SlopeBound::memory_bytes() const {
    size_t b = 0;
    for (const Level &l : m_levels) b += (l.max_height.size() + l.max_slope.size()) * sizeof(float);
    return b;
}

}  // namespace meso::prefilter
