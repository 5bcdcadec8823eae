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

}  // namespace sphrect
}  // namespace meso
