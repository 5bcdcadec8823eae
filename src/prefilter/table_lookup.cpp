// The scaling tables' lookups in shading (paper 004 §6: T(x) and S(ωi, ωo), model.h): called
// twice per path vertex by the `prefiltered` material, so written for speed. S needs the
// square coordinates of two directions (hemisphere_to_square: θ = atan2(s, z) and the
// concentric map's angle); here both directions' four arctangents are one vector of four,
// evaluated by a polynomial in float (no atan2, no data-dependent branch), within 1e-6 of the
// exact double mapping that the pipeline bins with.
#include <algorithm>
#include <cmath>
#include <cstring>
#include "prefilter/model.h"

namespace meso::prefilter {

namespace {

// Four floats, with the GCC / Clang vector extension (SSE on x86-64, NEON on ARM, plain code
// elsewhere).
typedef float F4 __attribute__((vector_size(16)));

/// atan(x) for x in [0, 1], lane by lane, without a branch or a division: Abramowitz and
/// Stegun 4.4.49, x times a polynomial of degree 8 in x² (error 2e-8; in float 1e-7, tested
/// against std::atan), by Estrin's scheme (half Horner's chain of dependent operations).
inline F4 atan01(F4 x) { return atan_unit_interval(x); }

/// One direction's part of hemisphere_to_square_fast: the two ratios whose arctangents it needs.
struct SquareMap {
    float x, y, z, s;  ///< w.x, w.y, |w.z|, sqrt(x² + y²)
    bool ok;           ///< false: the pole, or not finite (the square's centre)
    explicit SquareMap(Vec3 w) : x(w.x), y(w.y), z(std::abs(w.z)) {
        const float s2 = x * x + y * y;
        ok = s2 > 0.f && std::isfinite(s2 + z);
        s = ok ? std::sqrt(s2) : 1.f;
    }
    /// θ = atan(s / z) for s <= z, else π/2 − atan(z / s): the ratio min / max, as its numerator
    /// and denominator (0 / 1 where !ok: the four ratios are one vector division).
    float polar_num() const { return ok ? std::min(s, z) : 0.f; }
    float polar_den() const { return ok ? std::max(s, z) : 1.f; }
    /// The concentric sector's angle: atan(min(|x|, |y|) / max(|x|, |y|)), likewise.
    float sector_num() const { return ok ? std::min(std::abs(x), std::abs(y)) : 0.f; }
    float sector_den() const { return ok ? std::max(std::abs(x), std::abs(y)) : 1.f; }
    /// The square coordinates from the two arctangents (selects as copysign and products with
    /// 0 / 1, which compilers do not turn into jumps: random directions defeat a predictor).
    Vec2 finish(float polar_atan, float sector_atan) const {
        if (!ok) return Vec2(0.5f, 0.5f);
        // θ / 90°, θ = π/4 − copysign(π/4 − a, z − s)
        const float rho = (0.78539816339744831f - std::copysign(0.78539816339744831f - polar_atan, z - s)) *
                          0.63661977236758134f;
        // Concentric sectors (Shirley and Chiu): where |x| >= |y| (right / left), ox = ±ρ and
        // oy = ±ρ atan(|y| / |x|) / (π/4) with the signs of x and y; elsewhere (top / bottom)
        // the same with x and y swapped.
        const float am = sector_atan * 1.27323954473516268f;                      // angle / (π/4)
        const float side = 0.5f + 0.5f * std::copysign(1.f, std::abs(x) - std::abs(y));  // 1: |x| >= |y|
        const float kx = side + (1.f - side) * am, ky = (1.f - side) + side * am;  // exact selects
        const float ox = std::copysign(rho * kx, x), oy = std::copysign(rho * ky, y);
        auto c = [](float v) { return std::min(std::max(0.5f * (v + 1.f), 0.f), 1.f); };
        return Vec2(c(ox), c(oy));
    }
};

/// Both directions' square coordinates: their four arctangents as one vector.
void hemisphere_pair_to_square(Vec3 a, Vec3 b, Vec2 &sa, Vec2 &sb) {
    const SquareMap ma(a), mb(b);
    const F4 num = {ma.polar_num(), ma.sector_num(), mb.polar_num(), mb.sector_num()};
    const F4 den = {ma.polar_den(), ma.sector_den(), mb.polar_den(), mb.sector_den()};
    const F4 t = atan01(num / den);
    sa = ma.finish(t[0], t[1]);
    sb = mb.finish(t[2], t[3]);
}

/// Four floats from an unaligned address.
inline F4 load4(const float *p) {
    F4 v;
    std::memcpy(&v, p, sizeof v);
    return v;
}

/// Image::rgb, inline (a table lookup reads 4 or 16 texels).
inline Spectrum texel(const Image &im, int x, int y) {
    const float *p = &im.data[(size_t(y) * im.width + x) * im.channels];
    return im.channels >= 3 ? Spectrum(p[0], p[1], p[2]) : Spectrum(p[0]);
}

/// Bin-centre interpolation along one axis of N bins: lower index and weight of the upper.
/// Between the outer bin centres and the square's border (the horizon, half a bin) the line
/// through the last two centres is EXTRAPOLATED (t in [-0.5, 0) or (1, 1.5]) instead of
/// clamped: S changes fastest there (shadowing and masking), and a clamp held the last centre's
/// value to the horizon (scripts/experiments/grazing_sweep; model.h "Angular bins").
inline void axis_lerp(float s, int N, int &i0, int &i1, float &t) {
    if (N < 2) {
        i0 = i1 = 0, t = 0.f;
        return;
    }
    const float x = std::clamp(s * float(N) - 0.5f, -0.5f, float(N) - 0.5f);
    i0 = std::clamp(int(std::floor(x)), 0, N - 2);
    i1 = i0 + 1;
    t = x - float(i0);
}

}  // namespace

Vec2 hemisphere_to_square_fast(Vec3 w) {
    Vec2 a, b;
    hemisphere_pair_to_square(w, w, a, b);
    return a;
}

Spectrum ScalingTables::eval_T(Vec2 x) const {
    if (M <= 0) return Spectrum(1.f);
    const double u = double(x.x) - std::floor(double(x.x)), v = double(x.y) - std::floor(double(x.y));
    const double fx = u * M - 0.5, fy = v * M - 0.5;                  // in [-0.5, M - 0.5)
    const int x0 = int(std::floor(fx)), y0 = int(std::floor(fy));  // in [-1, M - 1]
    const float tx = float(fx - x0), ty = float(fy - y0);
    // Periodic neighbours (x0 + 1 <= M).
    const int xa = x0 < 0 ? x0 + M : x0, xb = x0 + 1 >= M ? x0 + 1 - M : x0 + 1;
    const int ya = y0 < 0 ? y0 + M : y0, yb = y0 + 1 >= M ? y0 + 1 - M : y0 + 1;
    const Spectrum a = texel(T, xa, ya), b = texel(T, xb, ya);
    const Spectrum c = texel(T, xa, yb), d = texel(T, xb, yb);
    return (a * (1.f - tx) + b * tx) * (1.f - ty) + (c * (1.f - tx) + d * tx) * ty;
}

Spectrum ScalingTables::eval_S(Vec3 wi, Vec3 wo) const {
    if (N <= 0) return Spectrum(1.f);
    Vec2 si, so;
    hemisphere_pair_to_square(wi, wo, si, so);
    int ix[2], iy[2], ox[2], oy[2];
    float tix, tiy, tox, toy;
    axis_lerp(si.x, N, ix[0], ix[1], tix);
    axis_lerp(si.y, N, iy[0], iy[1], tiy);
    axis_lerp(so.x, N, ox[0], ox[1], tox);
    axis_lerp(so.y, N, oy[0], oy[1], toy);
    const float wix[2] = {1.f - tix, tix}, wiy[2] = {1.f - tiy, tiy}, wox[2] = {1.f - tox, tox},
                woy[2] = {1.f - toy, toy};
    if (S.channels != 3 || N < 2) {  // a grey table, or one bin (no pairs of texels)
        Spectrum s(0.f);
        for (int a = 0; a < 2; ++a)
            for (int b = 0; b < 2; ++b)
                for (int c = 0; c < 2; ++c)
                    for (int d = 0; d < 2; ++d)
                        s += texel(S, ox[a] * N + ix[c], oy[b] * N + iy[d]) * (wox[a] * woy[b] * wix[c] * wiy[d]);
        return Spectrum(std::max(s.r, 0.f), std::max(s.g, 0.f), std::max(s.b, 0.f));  // extrapolated: >= 0
    }
    // The 16 texels of the quadrilinear blend straight from the RGB data, without branches on
    // zero weights (the tables are finite, checked at load: a zero weight adds exactly 0). The
    // two texels of a row pair (ix, ix + 1) are 6 adjacent floats, read as two unaligned vectors
    // p[0..3] and p[2..5] (never past the pair): the first's lanes 0-2 are texel ix's RGB, the
    // second's lanes 1-3 texel ix + 1's. Four accumulators (one per ωo corner) keep the chains
    // of dependent additions short; the unused lanes are summed and dropped.
    const float *data = S.data.data();
    const size_t row = size_t(S.width) * 3;
    F4 acc_lo[4], acc_hi[4];
    for (int a = 0; a < 2; ++a)
        for (int bb = 0; bb < 2; ++bb) {
            const int k = 2 * a + bb;
            const float wo_w = wox[a] * woy[bb];
            const float wl = wo_w * wix[0], wh = wo_w * wix[1];
            const float *p0 = data + size_t(oy[bb] * N + iy[0]) * row + size_t(ox[a] * N + ix[0]) * 3;
            const float *p1 = p0 + row;  // iy[1] = iy[0] + 1
            acc_lo[k] = load4(p0) * (wl * wiy[0]) + load4(p1) * (wl * wiy[1]);
            acc_hi[k] = load4(p0 + 2) * (wh * wiy[0]) + load4(p1 + 2) * (wh * wiy[1]);
        }
    const F4 lo = (acc_lo[0] + acc_lo[1]) + (acc_lo[2] + acc_lo[3]);
    const F4 hi = (acc_hi[0] + acc_hi[1]) + (acc_hi[2] + acc_hi[3]);
    const float r = lo[0] + hi[1], g = lo[1] + hi[2], b = lo[2] + hi[3];
    return Spectrum(std::max(r, 0.f), std::max(g, 0.f), std::max(b, 0.f));  // extrapolated past the centres: >= 0
}

}  // namespace meso::prefilter
