#include "geometry/interaction.h"
#include "geometry/shape.h"
#include <cstdint>
#include <cstring>

namespace meso {

ShadingContext SurfaceInteraction::shading_context(bool two_sided) const {
    ShadingContext ctx;
    ctx.p = p;
    ctx.uv = uv;
    Vec3 n = ns, g = ng;
    if (two_sided && dot(wo, g) < 0.f) {
        n = -n;
        g = -g;
        ctx.side = -1.f;
    }
    ctx.frame = Frame::from_normal_tangent(n, dpdu);
    ctx.ng = g;
    if (length_squared(n_footprint) > 0.f) {
        ctx.n_macro = n_footprint * ctx.side;
        ctx.dpdu_macro = length_squared(dpdu_footprint) > 0.f ? dpdu_footprint : dpdu;
        ctx.dpdv_macro = length_squared(dpdv_footprint) > 0.f ? dpdv_footprint : dpdv;
    }
    ctx.micro_height = micro_height;
    ctx.dpdu = dpdu;
    ctx.dpdv = dpdv;
    ctx.dpdx = dpdx;
    ctx.dpdy = dpdy;
    ctx.dudx = dudx;
    ctx.dudy = dudy;
    ctx.dvdx = dvdx;
    ctx.dvdy = dvdy;
    return ctx;
}

void SurfaceInteraction::compute_normal_derivatives() {
    if (shape) shape->fill_normal_derivatives(*this);
}

namespace {

/// v moved by one ulp in the direction of off's sign (unchanged where off is 0): next_float_up(v)
/// for off > 0, -next_float_up(-v) for off < 0, bit for bit on finite values and infinities,
/// without branches (the offset's sign is as good as random from one vertex to the next).
inline float nudge(float v, float off) {
    uint32_t b, o;
    std::memcpy(&b, &v, 4);
    std::memcpy(&o, &off, 4);
    const uint32_t mag = b & 0x7fffffffu, dir = o & 0x80000000u;
    // Away from zero (the same sign): one more in magnitude, except an infinity stays; towards
    // zero: one less; from +-0: the smallest denormal on the offset's side.
    const bool away = (b & 0x80000000u) == dir;
    uint32_t r = away ? (mag == 0x7f800000u ? b : b + 1u) : b - 1u;
    r = mag == 0u ? (dir | 1u) : r;
    r = (o & 0x7fffffffu) == 0u ? b : r;
    float out;
    std::memcpy(&out, &r, 4);
    return out;
}

}  // namespace

Vec3 SurfaceInteraction::offset_origin(Vec3 w) const {
    // Move p off the surface along the geometric normal by its error bound, to the side of
    // w, then round away from p so float rounding cannot pull it back (pbrt-v4 OffsetRayOrigin).
    const float d = p_error * (std::abs(ng.x) + std::abs(ng.y) + std::abs(ng.z));
    const Vec3 offset = ng * (dot(w, ng) < 0.f ? -d : d);
    return Vec3(nudge(p.x + offset.x, offset.x), nudge(p.y + offset.y, offset.y), nudge(p.z + offset.z, offset.z));
}

Ray SurfaceInteraction::spawn_ray(Vec3 d) const { return Ray(offset_origin(d), d); }

Ray SurfaceInteraction::spawn_ray_to(Vec3 target) const {
    Vec3 o = offset_origin(target - p);
    Vec3 d = target - o;
    float dist = length(d);
    Ray r(o, dist > 0.f ? d / dist : d, dist * (1.f - 1e-4f));
    return r;
}

}  // namespace meso
