// Warps from [0,1)^2 to common domains, each with its pdf (Shirley-Chiu concentric map etc.).
#pragma once
#include "core/frame.h"

namespace meso {

/// sin and cos of x in [-pi/4, pi/4] by Taylor polynomials of degree 9 / 10 (truncation below
/// 2e-9: what is left is float rounding, within 1.2e-7 of the exact values; test
/// Warp.ConcentricDiskMatchesTheDoubleMap): no libm call. T: float, or a GCC vector of floats.
template <class T>
inline void sincos_quarter(T x, T &s, T &c) {
    const T z = x * x;
    s = x + x * z * (-1.6666667e-1f + z * (8.3333333e-3f + z * (-1.9841270e-4f + z * 2.7557319e-6f)));
    c = 1.f + z * (-0.5f + z * (4.1666667e-2f + z * (-1.3888889e-3f + z * (2.4801587e-5f + z * -2.7557319e-7f))));
}

/// Shirley and Chiu's concentric map; the angle, in [-pi/4, pi/4] from the nearer axis, by
/// sincos_quarter. Without branches on the octant (as good as random per sample): the two
/// cases differ only in which coordinate is the radius and in swapping sine and cosine.
inline Vec2 square_to_uniform_disk_concentric(Vec2 u) {
    const float ox = 2.f * u.x - 1.f, oy = 2.f * u.y - 1.f;
    // |ox| > |oy|: r = ox, theta = pi/4 oy / ox; otherwise r = oy, theta = pi/2 - pi/4 ox / oy.
    const bool x_major = std::abs(ox) > std::abs(oy);
    const float r = x_major ? ox : oy, other = x_major ? oy : ox;
    // r = 0 only at the centre (then other = 0 too): angle 0, the point (0, 0).
    const float q = r != 0.f ? other / r : 0.f;
    float s, c;
    sincos_quarter(PiOver4 * q, s, c);
    const float a = r * c, b = r * s;
    return x_major ? Vec2(a, b) : Vec2(b, a);
}

/// Cosine-weighted hemisphere (z up); pdf = cos(theta)/pi.
inline Vec3 square_to_cosine_hemisphere(Vec2 u) {
    Vec2 d = square_to_uniform_disk_concentric(u);
    float z = safe_sqrt(1.f - d.x * d.x - d.y * d.y);
    return {d.x, d.y, z};
}
inline float square_to_cosine_hemisphere_pdf(Vec3 v) { return v.z > 0.f ? v.z * InvPi : 0.f; }

inline Vec3 square_to_uniform_sphere(Vec2 u) {
    float z = 1.f - 2.f * u.x;
    float r = safe_sqrt(1.f - z * z);
    float phi = 2.f * Pi * u.y;
    return {r * std::cos(phi), r * std::sin(phi), z};
}
inline float square_to_uniform_sphere_pdf() { return Inv4Pi; }

inline Vec3 square_to_uniform_hemisphere(Vec2 u) {
    float z = u.x;
    float r = safe_sqrt(1.f - z * z);
    float phi = 2.f * Pi * u.y;
    return {r * std::cos(phi), r * std::sin(phi), z};
}
inline float square_to_uniform_hemisphere_pdf() { return Inv2Pi; }

/// Uniform direction in the cone of half-angle acos(cos_max) around +z.
inline Vec3 square_to_uniform_cone(Vec2 u, float cos_max) {
    float cos_t = (1.f - u.x) + u.x * cos_max;
    float sin_t = safe_sqrt(1.f - cos_t * cos_t);
    float phi = 2.f * Pi * u.y;
    return {std::cos(phi) * sin_t, std::sin(phi) * sin_t, cos_t};
}
inline float square_to_uniform_cone_pdf(float cos_max) { return 1.f / (2.f * Pi * (1.f - cos_max)); }

/// Uniform barycentrics (b0, b1) on a triangle (Heitz 2019 low-distortion map).
inline Vec2 square_to_uniform_triangle(Vec2 u) {
    float b0, b1;
    if (u.x < u.y) {
        b0 = u.x / 2.f;
        b1 = u.y - b0;
    } else {
        b1 = u.y / 2.f;
        b0 = u.x - b1;
    }
    return {b0, b1};
}

/// Power heuristic (beta = 2) for multiple importance sampling.
inline float power_heuristic(float pdf_a, float pdf_b) {
    float a = pdf_a * pdf_a, b = pdf_b * pdf_b;
    if (std::isinf(a)) return 1.f;
    return a + b > 0.f ? a / (a + b) : 0.f;
}

}  // namespace meso
