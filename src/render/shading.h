// What a material or texture sees at a shading point.
#pragma once
#include "core/frame.h"
#include "core/spectrum.h"

namespace meso {

/// Surface point as seen by materials and textures. Directions handed to materials are
/// in the local frame of `frame` (z = shading normal).
struct ShadingContext {
    Vec3 p;          ///< world position
    Vec2 uv;         ///< texture coordinates
    Frame frame;     ///< shading frame (s along dp/du where available)
    Vec3 ng;         ///< geometric normal (world, unit)
    // Ray-differential footprint on the surface (zero when unknown, e.g. in `meso material`).
    Vec3 dpdx, dpdy;
    float dudx = 0, dudy = 0, dvdx = 0, dvdy = 0;
    // Level of detail chosen for this path (LoD materials read it; others ignore it).
    int lod_level = 0;
    float lod_weight = 0.f;
};

}  // namespace meso
