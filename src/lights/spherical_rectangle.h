// Uniform sampling of the solid angle subtended by a rectangle (a spherical rectangle).
//
// Model: Urena, Fajardo and King, "An Area-Preserving Parametrization for Spherical Rectangles",
// EGSR 2013 (Algorithm 1; also pbrt-v4's SampleSphericalRectangle). The rectangle is its corner s
// and two orthogonal edges ex, ey. In the frame (x, y, z) of the edges with the reference point
// o at the origin and the rectangle in the plane z = z0 < 0, the solid angle is
//     S = g0 + g1 + g2 + g3 - 2 pi,
// g_i the interior angles between the planes through o and consecutive edges. u.x picks the
// x-coordinate xu whose sub-rectangle [x0, xu] has solid angle u.x S (closed form), u.y a height
// on the segment at xu with the spherical-height parametrisation h = y / sqrt(y^2 + d^2)
// uniform. Every direction of the rectangle has density 1 / S. Double precision throughout, as
// in spherical_triangle.h: callers switch to area sampling for tiny or huge solid angles.
#pragma once
#include <algorithm>
#include <cmath>
#include "core/float_trig.h"
#include "lights/spherical_triangle.h"  // DVec3

namespace meso {
namespace sphrect {

using sphtri::DVec3;

/// The rectangle seen from a point, set up once for solid_angle() and sample().
struct SphericalRectangle {
    DVec3 o, x, y, z;                 ///< reference point and the rectangle's frame (z towards o)
    double x0 = 0, x1 = 0, y0 = 0, y1 = 0, z0 = 0;
    double b0 = 0, b1 = 0, k = 0, S = 0;  ///< the paper's b0, b1, k and the solid angle
    bool valid = false;

    SphericalRectangle() = default;
    /// Rectangle s + a ex + b ey (a, b in [0, 1]; ex and ey orthogonal) seen from o.
    SphericalRectangle(Vec3 o_, Vec3 s, Vec3 ex, Vec3 ey) : o(o_) {
        const DVec3 dex(ex), dey(ey);
        const double exl = sphtri::length(dex), eyl = sphtri::length(dey);
        if (!(exl > 0) || !(eyl > 0)) return;
        x = dex * (1 / exl);
        y = dey * (1 / eyl);
        z = sphtri::cross(x, y);
        const DVec3 d = DVec3(s) - o;
        x0 = sphtri::dot(d, x);
        y0 = sphtri::dot(d, y);
        z0 = sphtri::dot(d, z);
        if (z0 > 0) {  // the rectangle below o in the frame: flip z
            z0 = -z0;
            z = -z;
        }
        if (!(z0 < 0)) return;  // o in the rectangle's plane: no solid angle
        x1 = x0 + exl;
        y1 = y0 + eyl;
        const DVec3 v00(x0, y0, z0), v01(x0, y1, z0), v10(x1, y0, z0), v11(x1, y1, z0);
        const DVec3 n0 = sphtri::normalize(sphtri::cross(v00, v10)), n1 = sphtri::normalize(sphtri::cross(v10, v11));
        const DVec3 n2 = sphtri::normalize(sphtri::cross(v11, v01)), n3 = sphtri::normalize(sphtri::cross(v01, v00));
        auto angle = [](DVec3 a, DVec3 b) { return std::acos(std::clamp(-sphtri::dot(a, b), -1.0, 1.0)); };
        const double g0 = angle(n0, n1), g1 = angle(n1, n2), g2 = angle(n2, n3), g3 = angle(n3, n0);
        b0 = n0.z;
        b1 = n2.z;
        k = 2 * M_PI - g2 - g3;
        S = g0 + g1 - k;
        valid = std::isfinite(S) && S > 0;
    }

    /// The point of the rectangle in the direction sampled by u (density 1 / S in solid angle).
    bool sample(Vec2 u, Vec3 &p) const {
        if (!valid) return false;
        const double au = double(u.x) * S + k;
        const double sa = std::sin(au);
        if (!(std::abs(sa) > 0)) return false;
        const double fu = (std::cos(au) * b0 - b1) / sa;
        double cu = (fu > 0 ? 1.0 : -1.0) / std::sqrt(fu * fu + b0 * b0);
        cu = std::clamp(cu, -1.0, 1.0);
        const double s2 = 1 - cu * cu;
        double xu = s2 > 0 ? -(cu * z0) / std::sqrt(s2) : (cu > 0 ? x1 : x0);
        xu = std::clamp(std::isfinite(xu) ? xu : x0, x0, x1);
        const double dd = std::sqrt(xu * xu + z0 * z0);
        const double h0 = y0 / std::sqrt(dd * dd + y0 * y0), h1 = y1 / std::sqrt(dd * dd + y1 * y1);
        const double hv = h0 + double(u.y) * (h1 - h0), hv2 = hv * hv;
        double yv = hv2 < 1 - 1e-12 ? (hv * dd) / std::sqrt(1 - hv2) : y1;
        yv = std::clamp(yv, y0, y1);
        const DVec3 q = o + x * xu + y * yv + z * z0;
        p = Vec3(float(q.x), float(q.y), float(q.z));
        return std::isfinite(q.x) && std::isfinite(q.y) && std::isfinite(q.z);
    }
};

/// The rectangle's own frame, computed once per light: corner s, unit edge directions x, y,
/// z = x cross y, edge lengths lx, ly.
struct RectFrame {
    Vec3 s, x, y, z;
    float lx = 0.f, ly = 0.f;
    RectFrame() = default;
    RectFrame(Vec3 s_, Vec3 ex, Vec3 ey) : s(s_), lx(length(ex)), ly(length(ey)) {
        x = lx > 0.f ? ex / lx : Vec3(0, 0, 0);
        y = ly > 0.f ? ey / ly : Vec3(0, 0, 0);
        z = cross(x, y);
    }
};

/// The same sampler in float, with no libm call: Urena et al.'s interior angles g0..g3 enter
/// only through e^{i g} (the sampler needs sin and cos of u S + k, never an angle itself), and
/// in the rectangle's frame (o at the origin, the plane at height -h) each is a closed form,
///     e^{i g0} ~ (x1 y0, h r10),  e^{i g1} ~ (-x1 y1, h r11),
///     e^{i g2} ~ (x0 y1, h r01),  e^{i g3} ~ (-x0 y0, h r00),
/// r_ab the distance to corner (x_a, y_b): the dot and the cross product of consecutive edge-
/// plane normals (0, -h, -y0), (h, 0, x1), (0, h, y1), (-h, 0, -x0) (up to positive factors).
/// Then e^{i S} = prod e^{i g} (S = sum g - 2 pi in (0, 2 pi): one atan2_approx), e^{i k} =
/// conj(e^{i g2} e^{i g3}), and e^{i (u S + k)} = e^{i u S} e^{i k} (one sincos_0_2pi).
/// The absolute error of S is a few float epsilons (tests: FloatSphericalRectangle.*), so
/// callers use it only above MinFloatSolidAngle and take the double version below.
///
/// Everything is computed in the frame scaled by 1 / m, m the largest of |x0|, |x1|, |y0|, |y1|,
/// h (the angles do not depend on the scale): no square below underflows or overflows at any
/// distance. sample() inverts the parametrisation with five reciprocal square roots in its
/// dependent chain (rsqrt) instead of eleven square roots and divisions (see there).
struct FloatSphericalRectangle {
    Vec3 o, x, y, z;  ///< reference point and the frame (z towards o)
    float x0 = 0, x1 = 0, y0 = 0, y1 = 0, h = 0;
    float S = 0;
    float m = 0;                                     ///< the scale: a length is m times its scaled value
    float sx0 = 0, sx1 = 0, sy0 = 0, sy1 = 0, sh = 0;  ///< x0 .. h over m
    float ek_c = 1, ek_s = 0;                        ///< e^{i k} up to a positive factor
    bool valid = false;

    FloatSphericalRectangle() = default;
    FloatSphericalRectangle(Vec3 o_, const RectFrame &f)
        : FloatSphericalRectangle(o_, f, dot(f.s - o_, f.x), dot(f.s - o_, f.y), dot(f.s - o_, f.z)) {}
    /// The same, given the corner's coordinates (cx, cy, cz) = (f.s - o) in the frame (x, y, z).
    FloatSphericalRectangle(Vec3 o_, const RectFrame &f, float cx, float cy, float cz)
        : o(o_), x(f.x), y(f.y), z(f.z), x0(cx), y0(cy) {
        if (cz > 0.f) z = -z;  // the rectangle on the other side: flip z
        h = std::abs(cz);
        if (!(h > 0.f) || !(f.lx > 0.f) || !(f.ly > 0.f)) return;
        x1 = x0 + f.lx;
        y1 = y0 + f.ly;
        // Coordinates over the largest one keep the products below (i.e. e^{i g} of magnitude
        // at most 3, their product at most 81) far from float overflow and underflow.
        m = std::max(std::max(std::max(std::abs(x0), std::abs(x1)), std::max(std::abs(y0), std::abs(y1))), h);
        const float inv = 1.f / m;
        sx0 = x0 * inv, sx1 = x1 * inv, sy0 = y0 * inv, sy1 = y1 * inv, sh = h * inv;
        const float sh2 = sh * sh;
        const float r00 = std::sqrt(sx0 * sx0 + sy0 * sy0 + sh2), r10 = std::sqrt(sx1 * sx1 + sy0 * sy0 + sh2);
        const float r01 = std::sqrt(sx0 * sx0 + sy1 * sy1 + sh2), r11 = std::sqrt(sx1 * sx1 + sy1 * sy1 + sh2);
        // Products of the unnormalised e^{i g}: (a, b) (c, d) = (ac - bd, ad + bc).
        const float c0r = sx1 * sy0, c0i = sh * r10, c1r = -sx1 * sy1, c1i = sh * r11;
        const float c2r = sx0 * sy1, c2i = sh * r01, c3r = -sx0 * sy0, c3i = sh * r00;
        const float p01r = c0r * c1r - c0i * c1i, p01i = c0r * c1i + c0i * c1r;
        const float p23r = c2r * c3r - c2i * c3i, p23i = c2r * c3i + c2i * c3r;
        const float pr = p01r * p23r - p01i * p23i, pi = p01r * p23i + p01i * p23r;
        S = atan2_approx(pi, pr);
        if (S < 0.f) S += 2.f * Pi;
        ek_c = p23r, ek_s = -p23i;  // what only sample() needs (pdf() reads S alone) is finished there
        valid = std::isfinite(S) && S > 0.f && std::isfinite(p23r) && std::isfinite(p23i);
    }

    /// The point of the rectangle in the direction sampled by u (density 1 / S in solid angle),
    /// and its coordinates (a, b) in [0, 1]^2 along the edges.
    bool sample(Vec2 u, Vec3 &p, Vec2 &ab) const { return sample(u, p, &ab); }
    /// The same; `ab`, the unit direction `wi` from o to p and the distance `dist` from o to p
    /// only where non-null (wi and dist from the frame coordinates: no p - o cancellation).
    ///
    /// Urena et al.'s inversion: with b0 = -y0 / sqrt(h^2 + y0^2), b1 = y1 / sqrt(h^2 + y1^2),
    /// (ca, sa) = e^{i (u S + k)} and n = ca b0 - b1, fu = n / sa, cu = sign(fu) / sqrt(fu^2 +
    /// b0^2) and xu = h cu / sqrt(1 - cu^2). As 1 - b0^2 = h^2 / (h^2 + y0^2), that is
    ///     xu = h sign(n) sa / sqrt(n^2 - sa^2 h^2 / (h^2 + y0^2)),
    /// one reciprocal square root; then h0, h1 = y / sqrt(xu^2 + h^2 + y^2) at y0, y1, hv their
    /// mix by u.y, yv = hv sqrt(xu^2 + h^2) / sqrt(1 - hv^2), and wi = (xu, yv, -h) / its length.
    bool sample(Vec2 u, Vec3 &p, Vec2 *ab = nullptr, Vec3 *wi = nullptr, float *dist = nullptr) const {
        if (!valid) return false;
        // Independent of each other and of the sincos: b0, b1 and e^{i k} normalised.
        const float sh2 = sh * sh, r0 = rsqrt(sh2 + sy0 * sy0), r1 = rsqrt(sh2 + sy1 * sy1);
        const float rk = rsqrt(ek_c * ek_c + ek_s * ek_s), kc = ek_c * rk, ks = ek_s * rk;
        const float b0 = -sy0 * r0, b1 = sy1 * r1;
        float su, cu;
        sincos_0_2pi(u.x * S, su, cu);
        const float ca = cu * kc - su * ks, sa = su * kc + cu * ks;  // e^{i (u S + k)}
        if (!(std::abs(sa) > 0.f)) return false;
        const float n = ca * b0 - b1, sgn_sa = n < 0.f ? -sa : sa;
        const float q = n * n - sa * sa * (sh2 * r0 * r0);  // (fu^2 - (1 - b0^2)) sa^2
        // q <= 0: |cu| >= 1 by rounding, xu at the side of sign(fu).
        float xu = q > 0.f ? sh * sgn_sa * rsqrt(q) : (sgn_sa > 0.f ? sx1 : sx0);
        xu = std::clamp(std::isfinite(xu) ? xu : sx0, sx0, sx1);
        const float dd2 = xu * xu + sh2, dd = std::sqrt(dd2);
        const float h0 = sy0 * rsqrt(dd2 + sy0 * sy0), h1 = sy1 * rsqrt(dd2 + sy1 * sy1);
        const float hv = h0 + u.y * (h1 - h0), hv2 = hv * hv;
        float yv = hv2 < OneMinusEpsilon ? hv * dd * rsqrt(1.f - hv2) : (hv > 0.f ? sy1 : sy0);
        yv = std::clamp(yv, sy0, sy1);
        const Vec3 d = x * xu + y * yv - z * sh;  // o to p, over m
        p = o + d * m;
        if (wi || dist) {
            const float l2 = dd2 + yv * yv, il = rsqrt(l2);
            if (wi) *wi = d * il;
            if (dist) *dist = m * (l2 * il);
        }
        if (ab) *ab = Vec2(std::clamp((xu - sx0) / (sx1 - sx0), 0.f, 1.f), std::clamp((yv - sy0) / (sy1 - sy0), 0.f, 1.f));
        return std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z);
    }
};

}  // namespace sphrect
}  // namespace meso
