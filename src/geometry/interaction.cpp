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

}  // namespace meso
