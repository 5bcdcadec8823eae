// Rays with optional differentials (Igehy 1999) for texture footprints.
#pragma once
#include <cstdint>
#include "core/vec.h"

namespace meso {

/// Largest stretch of a footprint by the 1/cos of a grazing tangent plane: the transfer of
/// differentials onto a surface (and the camera approximation) caps 1/|cos theta| here, so
/// footprints stay finite at grazing angles (the cap corresponds to cos theta = 1e-3).
constexpr float MaxFootprintStretch = 1e3f;

/// Embree ray mask of a ray that sees LoD level `level` (0..31): shapes without LoD are
/// seen by every ray, level k of an LoD chain only by rays with bit k (geometry/lod.h).
constexpr uint32_t lod_ray_mask(int level) { return 1u << level; }
/// The mask bit of a ray at the coarsest level of every chain: a chain's last level k is seen by
/// mask bits k..31 (geometry/embree_accel.cpp), so bit 31 sees every chain's last level.
constexpr int LodCoarsestLevel = 31;

struct Ray {
    Vec3 o, d;
    float tmin = 0.f, tmax = Infinity;
    uint32_t mask = lod_ray_mask(0);  ///< which LoD level this ray sees (default: the original)
    Ray() = default;
    Ray(Vec3 o_, Vec3 d_, float tmax_ = Infinity) : o(o_), d(d_), tmax(tmax_) {}
    Vec3 operator()(float t) const { return o + d * t; }
};

/// A ray plus the two offset rays of a one-pixel step in x and y on the image plane.
/// `footprint_scale` remembers the factor the camera differentials were scaled by (the
/// per-sample footprint); it travels with the path so that the camera-based approximation
/// after rough scattering (Camera::approximate_dp_dxy) uses the same scale.
struct RayDifferential : Ray {
    bool has_differentials = false;
    float footprint_scale = 1.f;
    Vec3 rx_o, rx_d, ry_o, ry_d;
    RayDifferential() = default;
    explicit RayDifferential(const Ray &r) : Ray(r) {}
    /// Scale the differential offsets (pbrt-v4: by max(1/8, 1/sqrt(spp)) for supersampling).
    void scale_differentials(float s) {
        footprint_scale *= s;
        rx_o = o + (rx_o - o) * s;
        ry_o = o + (ry_o - o) * s;
        rx_d = d + (rx_d - d) * s;
        ry_d = d + (ry_d - d) * s;
    }
};

}  // namespace meso
