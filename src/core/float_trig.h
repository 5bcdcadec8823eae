// Float trigonometry for the light samplers' hot loops, without libm calls (glibc's sinf/cosf
// and atan2f are out-of-line calls with argument checks; the double ones cost several times
// more). Stated errors are absolute, over the whole stated domain, measured against the double
// functions in tests/test_light_sampling.cpp (FloatTrig.*).
//   atan2_approx(y, x)      any finite (y, x): A&S 4.4.49 polynomial on [0, 1] plus octant
//                           symmetries; within 4e-7 rad.
//   sincos_0_2pi(t, s, c)   t in [0, 2 pi]: Taylor polynomials of degree 11 / 12 on [-pi/2, pi/2]
//                           after two reflections; within 3e-7.
//   rsqrt(x)                1 / sqrt(max(x, FLT_MIN)) for x in [0, 1e38]: SSE's 12-bit estimate
//                           and one Newton step; within 4e-7 relative (FloatTrig.RsqrtWithinStatedError).
#pragma once
#include <xmmintrin.h>
#include <cfloat>
#include <cmath>
#include "core/math.h"

namespace meso {

/// atan2(y, x) in [-pi, pi]; 0 for (0, 0).
inline float atan2_approx(float y, float x) {
    const float ax = std::abs(x), ay = std::abs(y);
    const float hi = std::max(ax, ay), lo = std::min(ax, ay);
    if (!(hi > 0.f)) return 0.f;
    float r = atan_unit_interval(lo / hi);
    if (ay > ax) r = PiOver2 - r;
    if (x < 0.f) r = Pi - r;
    return std::copysign(r, y);
}

/// 1 / sqrt(x) for x in [FLT_MIN, 1e38] (smaller x, zero included, are taken as FLT_MIN): a
/// square root and a division in one dependent step of about a third of their latency, for the
/// chains of normalisations in the samplers. rsqrtss is within 1.5 * 2^-12 relative; one Newton
/// step y (3 - x y^2) / 2 squares that error (plus the step's rounding).
inline float rsqrt(float x) {
    x = std::max(x, FLT_MIN);
    const float y = _mm_cvtss_f32(_mm_rsqrt_ss(_mm_set_ss(x)));
    return y * (1.5f - 0.5f * x * y * y);
}

/// sin and cos of r in [-pi/2, pi/2] (sincos_0_2pi's polynomials, no reduction): within 3e-7
/// absolute, and sin keeps its relative accuracy as r goes to 0 (r + r z p(z)). T: float, or a
/// GCC vector of floats (__m128: lanes, each rounded as the float version).
template <class T>
inline void sincos_half_pi(T r, T &s, T &c) {
    // The Taylor polynomials in z = r^2 by Estrin's scheme (pairs of coefficients, then z^2 and
    // z^4): half the dependent multiply-adds of Horner's, same coefficients.
    const T z = r * r, z2 = z * z, z4 = z2 * z2;
    const T ps = (8.3333333e-3f * z - 1.6666667e-1f) + (2.7557319e-6f * z - 1.9841270e-4f) * z2 +
                     -2.5052108e-8f * z4;  // -1/6 + z/120 - ... - z^4/11!
    const T pc = (4.1666667e-2f * z - 0.5f) + (2.4801587e-5f * z - 1.3888889e-3f) * z2 +
                     (2.0876757e-9f * z - 2.7557319e-7f) * z4;  // -1/2 + z/24 - ... + z^5/12!
    s = r + r * z * ps;
    c = 1.f + z * pc;
}

/// sin and cos of t in [0, 2 pi] (values a little outside keep the same accuracy).
inline void sincos_0_2pi(float t, float &s, float &c) {
    // t - pi in [-pi, pi]: sin t = -sin(t - pi), cos t = -cos(t - pi). Pi as a float plus its
    // remainder keeps the reduction within 1 ulp.
    float r = (t - 3.14159274f) + 8.74227766e-8f;
    float sign_c = -1.f;
    if (r > PiOver2) {  // sin(pi - r) = sin r, cos(pi - r) = -cos r
        r = (3.14159274f - r) - 8.74227766e-8f;
        sign_c = 1.f;
    } else if (r < -PiOver2) {
        r = (-3.14159274f - r) + 8.74227766e-8f;
        sign_c = 1.f;
    }
    sincos_half_pi(r, s, c);
    s = -s;
    c *= sign_c;
}

}  // namespace meso
