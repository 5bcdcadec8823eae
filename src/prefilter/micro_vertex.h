// A vertex on a periodic heightfield's microsurface as the effective-BRDF estimators of
// paper 004 use it (prefilter/effective_brdf.cpp, prefilter/scaling.cpp): integer cell
// offsets plus a small local part (the intersector's convention), the micro-normal and a
// shading context. Internal to src/prefilter.
#pragma once
#include <cmath>
#include <cstdint>
#include <algorithm>
#include "core/frame.h"
#include "geometry/heightfield.h"
#include "geometry/shading.h"
#include "prefilter/effective_brdf.h"

namespace meso::prefilter::detail {

/// A point on the microsurface: integer cell offsets plus a small local part (the
/// intersector's convention), the micro-normal and its shading context.
struct Vertex {
    int64_t ox = 0, oy = 0;
    Vec3 p;  ///< local position: x, y in [0, 1) (plus round-off), z = height
    Vec3 n;  ///< unit micro-normal (upper side)
    ShadingContext ctx;
};

inline Vertex make_vertex(const Heightfield &hf, const HeightfieldHit &hit, int64_t ox, int64_t oy, bool macro_frame = false) {
    Vertex v;
    // Re-base: the integer part of the traced position moves into the offsets, so the
    // coordinates handed to the intersector stay small however far a path wanders.
    const float fx = std::floor(hit.x), fy = std::floor(hit.y);
    v.ox = ox + int64_t(fx);
    v.oy = oy + int64_t(fy);
    v.p = Vec3(hit.x - fx, hit.y - fy, hit.h);
    v.n = normalize(Vec3(-hit.dhdx, -hit.dhdy, 1.f));
    // s along the x tangent (1, 0, dh/dx) so that anisotropic bases line up with the map.
    // macro_frame: the macro tangent frame (x, y, z) instead (prefiltered models shade in it).
    v.ctx.frame = macro_frame ? Frame(Vec3(1.f, 0.f, 0.f), Vec3(0.f, 1.f, 0.f), Vec3(0.f, 0.f, 1.f))
                              : Frame::from_normal_tangent(v.n, Vec3(1.f, 0.f, hit.dhdx));
    v.ctx.ng = v.n;
    const double W = hf.width(), H = hf.height();
    const double ax = double(v.ox) + v.p.x, ay = double(v.oy) + v.p.y;
    v.ctx.p = Vec3(float(ax), float(ay), v.p.z);
    double u = ax / W - std::floor(ax / W), w = ay / H - std::floor(ay / H);
    v.ctx.uv = Vec2(float(std::min(u, 0.99999999)), float(std::min(w, 0.99999999)));
    v.ctx.dpdu = Vec3(float(W), 0.f, float(W) * hit.dhdx);
    v.ctx.dpdv = Vec3(0.f, float(H), float(H) * hit.dhdy);
    return v;
}

/// Origin of a ray leaving vertex v: pushed off the surface along the normal by a distance
/// relative to the coordinates' magnitude (float round-off of the hit point).
inline Vec3 spawn_origin(const Vertex &v) {
    const float eps = 1e-4f * (1.f + std::abs(v.p.z));
    return v.p + v.n * eps;
}

/// Whether [a, b) spans a whole number (>= 1) of periods of length `period`.
inline bool whole_periods(double a, double b, int period) {
    const double n = (b - a) / double(period);
    const double r = std::round(n);
    return r >= 1 && std::abs(n - r) <= 1e-9 * r;
}

/// The region Q of the base plane (at height z_top above the field) from which lines of sight
/// along -wo are shot so that their first hits cover patch R (effective_brdf.h): R itself
/// along axes where R spans whole periods (wrap: no hit is rejected), else R widened by the
/// largest horizontal drift of a line of sight through the height range.
struct ShootingRegion {
    double x0, y0, x1, y1, z_top;
    bool wrap_x, wrap_y;
    double area() const { return (x1 - x0) * (y1 - y0); }
    /// Whether a first hit at unwrapped cell position (ax, ay) lies in R.
    bool accepts(const PatchRegion &R, double ax, double ay) const {
        return (wrap_x || (ax >= R.x0 && ax < R.x1)) && (wrap_y || (ay >= R.y0 && ay < R.y1));
    }
};

inline ShootingRegion shooting_region(const Heightfield &hf, const PatchRegion &R, Vec3 wo) {
    ShootingRegion Q{R.x0, R.y0, R.x1, R.y1, 0.0, whole_periods(R.x0, R.x1, hf.width()),
                     whole_periods(R.y0, R.y1, hf.height())};
    const double zmin = hf.min_height(), zmax = hf.max_height();
    Q.z_top = zmax + 1e-2 * (1 + (zmax - zmin));
    const double sx = double(wo.x) / wo.z, sy = double(wo.y) / wo.z;
    const double dz_lo = Q.z_top - zmax, dz_hi = Q.z_top - zmin;
    if (!Q.wrap_x) {
        Q.x0 += std::min(sx * dz_lo, sx * dz_hi);
        Q.x1 += std::max(sx * dz_lo, sx * dz_hi);
    }
    if (!Q.wrap_y) {
        Q.y0 += std::min(sy * dz_lo, sy * dz_hi);
        Q.y1 += std::max(sy * dz_lo, sy * dz_hi);
    }
    return Q;
}

/// A ray leaving a point ON the surface with rise/run above a slope L that bounds the surface's
/// rise along every horizontal line from there (SlopeBound: the largest |∇h| around the point,
/// and the heights farther away) can never meet the surface again, so its shadow test is skipped
/// exactly. This tells whether direction w (unit) rises faster than L, with a relative margin
/// for rounding.
inline bool unoccluded_by_slope(Vec3 w, double L) {
    const double run = std::sqrt(double(w.x) * w.x + double(w.y) * w.y);
    return double(w.z) > L * run * (1.0 + 1e-4) + 1e-6;
}

}  // namespace meso::prefilter::detail
