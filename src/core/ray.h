// Rays with optional differentials (Igehy 1999) for texture footprints.
#pragma once
#include "core/vec.h"

namespace meso {

struct Ray {
    Vec3 o, d;
    float tmin = 0.f, tmax = Infinity;
    Ray() = default;
    Ray(Vec3 o_, Vec3 d_, float tmax_ = Infinity) : o(o_), d(d_), tmax(tmax_) {}
    Vec3 operator()(float t) const { return o + d * t; }
};

/// A ray plus the two offset rays of a one-pixel step in x and y on the image plane.
struct RayDifferential : Ray {
    bool has_differentials = false;
    Vec3 rx_o, rx_d, ry_o, ry_d;
    RayDifferential() = default;
    explicit RayDifferential(const Ray &r) : Ray(r) {}
    /// Scale the differential offsets (pbrt-v4: by max(1/8, 1/sqrt(spp)) for supersampling).
    void scale_differentials(float s) {
        rx_o = o + (rx_o - o) * s;
        ry_o = o + (ry_o - o) * s;
        rx_d = d + (rx_d - d) * s;
        ry_d = d + (ry_d - d) * s;
    }
};

}  // namespace meso
