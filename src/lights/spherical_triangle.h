// Uniform sampling of the solid angle subtended by a triangle (a spherical triangle).
//
// Model: Arvo, "Stratified sampling of spherical triangles", SIGGRAPH 1995, in the form
// of pbrt-v4 (SampleSphericalTriangle, sampling.cpp): choose the sub-triangle area A' = u0·A
// (A = alpha + beta + gamma - pi), which fixes the vertex c' on the arc a–c, then a point
// on the arc b–c' with cos theta uniform in [cos(b, c'), 1]. The solid angle used for the
// pdf is the Van Oosterom–Strackee formula (1983),
//     tan(Omega / 2) = |a · (b x c)| / (1 + a·b + b·c + c·a)   (a, b, c unit),
// which, unlike the angle excess alpha + beta + gamma - pi, stays accurate for tiny
// triangles. solid_angle() and sample() are evaluated in double precision: a float angle excess
// loses all digits below ~1e-4 sr, which is exactly where callers switch to area sampling.
// FloatSphericalTriangle (below) is the float form for triangles from 1e-2 sr.
#pragma once
#include <cmath>
#include <algorithm>
#include "core/vec.h"
#include "core/float_trig.h"

namespace meso {
namespace sphtri {

struct DVec3 {
    double x = 0, y = 0, z = 0;
    DVec3() = default;
    DVec3(double x_, double y_, double z_) : x(x_), y(y_), z(z_) {}
    explicit DVec3(Vec3 v) : x(v.x), y(v.y), z(v.z) {}
};
inline DVec3 operator+(DVec3 a, DVec3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
inline DVec3 operator-(DVec3 a, DVec3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
inline DVec3 operator-(DVec3 a) { return {-a.x, -a.y, -a.z}; }
inline DVec3 operator*(DVec3 a, double s) { return {a.x * s, a.y * s, a.z * s}; }
inline DVec3 operator*(double s, DVec3 a) { return {a.x * s, a.y * s, a.z * s}; }
inline double dot(DVec3 a, DVec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline DVec3 cross(DVec3 a, DVec3 b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
inline double length(DVec3 a) { return std::sqrt(dot(a, a)); }
inline DVec3 normalize(DVec3 a) {
    double l = length(a);
    return l > 0 ? a * (1.0 / l) : DVec3();
}
/// Angle between unit vectors, accurate near 0 and pi (pbrt's AngleBetween).
inline double angle_between(DVec3 a, DVec3 b) {
    if (dot(a, b) < 0) return M_PI - 2 * std::asin(std::min(1.0, length(a + b) / 2));
    return 2 * std::asin(std::min(1.0, length(b - a) / 2));
}
/// Component of v orthogonal to unit w, normalised.
inline DVec3 gram_schmidt(DVec3 v, DVec3 w) { return normalize(v - dot(v, w) * w); }

/// Solid angle (sr) of triangle (p0, p1, p2) seen from p; 0 when p is on a vertex.
inline double solid_angle(Vec3 p, Vec3 p0, Vec3 p1, Vec3 p2) {
    DVec3 o(p);
    DVec3 a = normalize(DVec3(p0) - o), b = normalize(DVec3(p1) - o), c = normalize(DVec3(p2) - o);
    if (dot(a, a) == 0 || dot(b, b) == 0 || dot(c, c) == 0) return 0.0;
    double num = std::abs(dot(a, cross(b, c)));
    double den = 1.0 + dot(a, b) + dot(b, c) + dot(c, a);
    double omega = 2.0 * std::atan2(num, den);
    return omega > 0 ? omega : 0.0;  // atan2 in [0, pi] for num >= 0: omega in [0, 2 pi]
}

/// Samples a direction uniformly inside the spherical triangle (p0, p1, p2) seen from p and
/// returns the barycentrics (b0, b1, b2) of the point where it meets the triangle. Returns
/// false for a degenerate configuration (p on the triangle's plane or on a vertex).
inline bool sample(Vec3 p, Vec3 p0, Vec3 p1, Vec3 p2, Vec2 u, double b[3]) {
    DVec3 o(p), v0(p0), v1(p1), v2(p2);
    DVec3 a = normalize(v0 - o), bb = normalize(v1 - o), c = normalize(v2 - o);
    DVec3 n_ab = cross(a, bb), n_bc = cross(bb, c), n_ca = cross(c, a);
    if (dot(n_ab, n_ab) == 0 || dot(n_bc, n_bc) == 0 || dot(n_ca, n_ca) == 0) return false;
    n_ab = normalize(n_ab);
    n_bc = normalize(n_bc);
    n_ca = normalize(n_ca);
    // Interior angles at the vertices.
    double alpha = angle_between(n_ab, -n_ca);
    double beta = angle_between(n_bc, -n_ab);
    double gamma = angle_between(n_ca, -n_bc);
    // Sub-triangle area A' = u0 A, written as A' + pi.
    double A_pi = alpha + beta + gamma;
    double Ap_pi = M_PI + double(u.x) * (A_pi - M_PI);
    double cos_alpha = std::cos(alpha), sin_alpha = std::sin(alpha);
    double sin_phi = -std::sin(Ap_pi) * cos_alpha + std::cos(Ap_pi) * sin_alpha;
    double cos_phi = -std::cos(Ap_pi) * cos_alpha - std::sin(Ap_pi) * sin_alpha;
    double k1 = cos_phi - cos_alpha;
    double k2 = sin_phi + sin_alpha * dot(a, bb);
    double den = (k2 * sin_phi + k1 * cos_phi) * sin_alpha;
    if (!(std::abs(den) > 0)) return false;
    double cos_bp = ((k2 * cos_phi - k1 * sin_phi) * cos_alpha - k2) / den;
    if (!std::isfinite(cos_bp)) return false;
    cos_bp = std::min(1.0, std::max(-1.0, cos_bp));
    // c' on the arc a-c, then w on the arc b-c'.
    double sin_bp = std::sqrt(std::max(0.0, 1 - cos_bp * cos_bp));
    DVec3 cp = cos_bp * a + sin_bp * gram_schmidt(c, a);
    double cos_t = 1 - double(u.y) * (1 - dot(cp, bb));
    double sin_t = std::sqrt(std::max(0.0, 1 - cos_t * cos_t));
    DVec3 w = cos_t * bb + sin_t * gram_schmidt(cp, bb);
    // Barycentrics of the ray (o, w) with the triangle's plane (Moller-Trumbore).
    DVec3 e1 = v1 - v0, e2 = v2 - v0;
    DVec3 s1 = cross(w, e2);
    double divisor = dot(s1, e1);
    if (divisor == 0 || !std::isfinite(divisor)) return false;
    double inv = 1.0 / divisor;
    DVec3 s = o - v0;
    double b1 = dot(s, s1) * inv;
    double b2 = dot(w, cross(s, e1)) * inv;
    b1 = std::min(1.0, std::max(0.0, b1));
    b2 = std::min(1.0, std::max(0.0, b2));
    if (b1 + b2 > 1) {
        double sum = b1 + b2;
        b1 /= sum;
        b2 /= sum;
    }
    b[0] = 1 - b1 - b2;
    b[1] = b1;
    b[2] = b2;
    return true;
}


/// The same sampler in float, with no libm call. The interior angles enter only through
/// e^{i alpha} etc.: with unit a, b, c and the edge-plane normals n_ab = a x b, ..., the angle
/// at a is that between n_ab and -n_ca, and |n_ab x n_ca| = |det(a, b, c)| = D, so
///     e^{i alpha} ~ (-n_ab . n_ca, D),  e^{i beta} ~ (-n_bc . n_ab, D),  e^{i gamma} ~ (-n_ca . n_bc, D)
/// (up to positive factors), e^{i A} = -e^{i (alpha + beta + gamma)} gives the area A with one
/// atan2_approx, and Arvo's e^{i (pi + u A)} = -e^{i u A} one sincos_0_2pi. Its A is within a few
/// float epsilons (absolute) of the double one (tests: FloatSphericalTriangle.*): callers use it
/// from 1e-2 sr, where that is 1e-4 relative, and the double sampler below.
struct FloatSphericalTriangle {
    Vec3 o, a, b, c;        ///< reference point and unit directions to the vertices
    Vec3 c_perp_a;          ///< gram_schmidt(c, a)
    float S = 0.f;          ///< solid angle (the spherical area A)
    float cos_alpha = 1.f, sin_alpha = 0.f, ab = 0.f;
    bool valid = false;

    FloatSphericalTriangle() = default;
    FloatSphericalTriangle(Vec3 p, Vec3 p0, Vec3 p1, Vec3 p2) : o(p) {
        a = p0 - p, b = p1 - p, c = p2 - p;
        const float la = std::sqrt(length_squared(a)), lb = std::sqrt(length_squared(b)), lc = std::sqrt(length_squared(c));
        if (!(la > 0.f) || !(lb > 0.f) || !(lc > 0.f)) return;
        // The normals from the unnormalised vertex vectors and the edges (a x b = a x (p1 - p0)
        // ...): no cancellation between nearly parallel directions, as for small triangles.
        const Vec3 e01 = p1 - p0, e12 = p2 - p1, e20 = p0 - p2;
        const Vec3 n_ab = cross(a, e01), n_bc = cross(b, e12), n_ca = cross(c, e20);
        const float D = std::abs(dot(a, cross(e01, -e20)));  // |det(a, b, c)|
        if (!(D > 0.f)) return;
        auto unit = [](float re, float im, float &ur, float &ui) {
            const float inv = 1.f / std::sqrt(re * re + im * im);
            ur = re * inv, ui = im * inv;
        };
        // |n_ab x n_ca| = |a| D etc. (the identity above with unnormalised vectors).
        float ar, ai, br, bi, gr, gi;
        unit(-dot(n_ab, n_ca), la * D, ar, ai);
        unit(-dot(n_bc, n_ab), lb * D, br, bi);
        unit(-dot(n_ca, n_bc), lc * D, gr, gi);
        a = a / la, b = b / lb, c = c / lc;
        const float pr = ar * br - ai * bi, pi = ar * bi + ai * br;
        const float qr = pr * gr - pi * gi, qi = pr * gi + pi * gr;  // e^{i (alpha + beta + gamma)}
        S = atan2_approx(-qi, -qr);
        if (S < 0.f) S += 2.f * Pi;
        cos_alpha = ar, sin_alpha = ai;
        ab = dot(a, b);
        const Vec3 cp = c - a * dot(c, a);
        const float lcp = length_squared(cp);
        if (!(lcp > 0.f)) return;
        c_perp_a = cp / std::sqrt(lcp);
        valid = std::isfinite(S) && S > 0.f && std::isfinite(ar + br + gr);
    }

    /// A direction uniform in the spherical triangle (density 1 / S) and the barycentrics of the
    /// point where it meets the triangle (p0, p1, p2) given to the constructor.
    bool sample(Vec3 p0, Vec3 p1, Vec3 p2, Vec2 u, float bary[3]) const {
        if (!valid) return false;
        float su, cu;
        sincos_0_2pi(u.x * S, su, cu);  // e^{i (pi + u A)} = -(cu, su)
        const float sin_phi = su * cos_alpha - cu * sin_alpha, cos_phi = cu * cos_alpha + su * sin_alpha;
        const float k1 = cos_phi - cos_alpha, k2 = sin_phi + sin_alpha * ab;
        const float den = (k2 * sin_phi + k1 * cos_phi) * sin_alpha;
        if (!(std::abs(den) > 0.f)) return false;
        float cos_bp = ((k2 * cos_phi - k1 * sin_phi) * cos_alpha - k2) / den;
        if (!std::isfinite(cos_bp)) return false;
        cos_bp = std::clamp(cos_bp, -1.f, 1.f);
        const float sin_bp = std::sqrt(std::max(0.f, 1.f - cos_bp * cos_bp));
        const Vec3 cp = a * cos_bp + c_perp_a * sin_bp;
        const float cos_t = 1.f - u.y * (1.f - dot(cp, b));
        const float sin_t = std::sqrt(std::max(0.f, 1.f - cos_t * cos_t));
        Vec3 t = cp - b * dot(cp, b);
        const float lt = length_squared(t);
        t = lt > 0.f ? t / std::sqrt(lt) : Vec3(0, 0, 0);
        const Vec3 w = b * cos_t + t * sin_t;
        // Barycentrics of the ray (o, w) with the triangle's plane (Moller-Trumbore).
        const Vec3 e1 = p1 - p0, e2 = p2 - p0, s1 = cross(w, e2);
        const float divisor = dot(s1, e1);
        if (divisor == 0.f || !std::isfinite(divisor)) return false;
        const float inv = 1.f / divisor;
        const Vec3 sv = o - p0;
        float b1 = std::clamp(dot(sv, s1) * inv, 0.f, 1.f), b2 = std::clamp(dot(w, cross(sv, e1)) * inv, 0.f, 1.f);
        if (b1 + b2 > 1.f) {
            const float sum = b1 + b2;
            b1 /= sum, b2 /= sum;
        }
        bary[0] = 1.f - b1 - b2, bary[1] = b1, bary[2] = b2;
        return true;
    }
};

}  // namespace sphtri
}  // namespace meso
