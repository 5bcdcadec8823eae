#include "geometry/interaction.h"
#include "geometry/shape.h"

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

Vec3 SurfaceInteraction::offset_origin(Vec3 w) const {
    // Move p off the surface along the geometric normal by its error bound, to the side of
    // w, then round away from p so float rounding cannot pull it back (pbrt-v4 OffsetRayOrigin).
    float d = p_error * (std::abs(ng.x) + std::abs(ng.y) + std::abs(ng.z));
    Vec3 offset = ng * d;
    if (dot(w, ng) < 0.f) offset = -offset;
    Vec3 po = p + offset;
    for (int i = 0; i < 3; ++i) {
        if (offset[i] > 0.f) po[i] = next_float_up(po[i]);
        else if (offset[i] < 0.f) po[i] = -next_float_up(-po[i]);
    }
    return po;
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
