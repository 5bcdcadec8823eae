// Two double lanes (GCC vector extensions, SSE2 on x86-64-v2) and the e^x and ln x that the
// vMF mixture's E-step needs per sample and lobe, without a libm call per value.
#pragma once

#include <cstdint>

namespace meso::lanes {

using F64x2 = double __attribute__((vector_size(16)));
using U64x2 = uint64_t __attribute__((vector_size(16)));

inline F64x2 splat(double v) { return F64x2{v, v}; }
inline F64x2 max(F64x2 a, F64x2 b) { return a > b ? a : b; }
inline double hsum(F64x2 a) { return a[0] + a[1]; }

/// 1.5 · 2^52: x + kMagic − kMagic rounds |x| < 2^51 to the nearest integer, and the low bits
/// of x + kMagic hold that integer.
constexpr double kMagic = 6755399441055744.0;

/// e^x per lane for x <= 0; 0 below −708 (e^−708 ≈ 3e-308, the last normal powers of two).
/// Cody–Waite reduction x = k ln2 + r, |r| <= ln2/2, then e^r by its Taylor polynomial to r^12
/// (truncation < 2.3e-16 relative): within a few ulp of std::exp (test F64Lanes.ExpIsLibm).
/// e^0 = 1 exactly. NaN stays NaN.
inline F64x2 exp_nonpositive(F64x2 x) {
    const F64x2 lo = splat(-708.0);
    const auto under = x < lo;
    x = under ? lo : x;
    const F64x2 t = x * splat(1.4426950408889634074) + splat(kMagic);
    const F64x2 k = t - splat(kMagic);
    const F64x2 r = (x - k * splat(0.693145751953125)) - k * splat(1.42860682030941723212e-6);
    // Σ r^n / n!, n = 0..12, by Estrin's scheme (short dependency chains).
    const F64x2 r2 = r * r, r4 = r2 * r2, r8 = r4 * r4;
    const F64x2 a0 = splat(1.0) + r, a1 = splat(0.5) + r * splat(1.66666666666666666667e-1),
                a2 = splat(4.16666666666666666667e-2) + r * splat(8.33333333333333333333e-3),
                a3 = splat(1.38888888888888888889e-3) + r * splat(1.98412698412698412698e-4),
                a4 = splat(2.48015873015873015873e-5) + r * splat(2.75573192239858906526e-6),
                a5 = splat(2.75573192239858906526e-7) + r * splat(2.50521083854417187751e-8);
    const F64x2 b0 = a0 + a1 * r2, b1 = a2 + a3 * r2, b2 = a4 + a5 * r2;
    const F64x2 p = (b0 + b1 * r4) + (b2 + splat(2.08767569878680989792e-9) * r4) * r8;
    const F64x2 scale = (F64x2)((((U64x2)t - (U64x2)splat(kMagic)) + 1023) << 52);
    return under ? splat(0.0) : p * scale;
}

/// ln s per lane for positive, normal, finite s: s = 2^e m with m in [√½, √2], ln m =
/// 2 atanh u, u = (m − 1)/(m + 1), |u| <= 0.1716, by its series to u^19 (truncation < 1e-17).
/// Within a few ulp of std::log (test F64Lanes.LogIsLibm).
inline F64x2 log_positive(F64x2 s) {
    const U64x2 b = (U64x2)s;
    const U64x2 e = (b >> 52) - 1023;
    F64x2 m = (F64x2)((b & 0x000FFFFFFFFFFFFFull) | 0x3FF0000000000000ull);
    const auto big = m > splat(1.41421356237309504880);
    m = big ? m * splat(0.5) : m;
    const U64x2 e2 = e - (U64x2)big;  // big is all ones (−1) where true
    const F64x2 ed = (F64x2)((U64x2)splat(kMagic) + e2) - splat(kMagic);
    const F64x2 u = (m - splat(1.0)) / (m + splat(1.0)), u2 = u * u;
    // Σ u2^k / (2k + 3), k = 0..8, by Estrin's scheme (short dependency chains).
    const F64x2 u4 = u2 * u2, u8 = u4 * u4;
    const F64x2 a0 = splat(1.0 / 3.0) + u2 * splat(1.0 / 5.0), a1 = splat(1.0 / 7.0) + u2 * splat(1.0 / 9.0),
                a2 = splat(1.0 / 11.0) + u2 * splat(1.0 / 13.0), a3 = splat(1.0 / 15.0) + u2 * splat(1.0 / 17.0);
    const F64x2 p = (a0 + a1 * u4) + ((a2 + a3 * u4) + splat(1.0 / 19.0) * u8) * u8;
    const F64x2 two_u = u + u;
    return ed * splat(0.693145751953125) + (two_u + (two_u * u2 * p + ed * splat(1.42860682030941723212e-6)));
}

}  // namespace meso::lanes
