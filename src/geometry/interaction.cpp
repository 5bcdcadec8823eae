#include "geometry/interaction.h"

namespace meso {

void SurfaceInteraction::compute_differentials(const RayDifferential &ray) {
    dpdx = dpdy = Vec3();
    dudx = dudy = dvdx = dvdy = 0.f;
    if (!ray.has_differentials) return;
    // Intersect the offset rays with the tangent plane at p (Igehy 1999; pbrt-v3 10.1.1).
    Vec3 n = ng;
    float d = -dot(n, p);
    float ddx = dot(n, ray.rx_d), ddy = dot(n, ray.ry_d);
    if (ddx == 0.f || ddy == 0.f) return;
    float tx = (-dot(n, ray.rx_o) - d) / ddx;
    float ty = (-dot(n, ray.ry_o) - d) / ddy;
    if (!std::isfinite(tx) || !std::isfinite(ty)) return;
    dpdx = ray.rx_o + ray.rx_d * tx - p;
    dpdy = ray.ry_o + ray.ry_d * ty - p;
    // Least-squares solve of [dpdu dpdv] (du, dv)^T = dp (pbrt-v4 SurfaceInteraction).
    float a00 = dot(dpdu, dpdu), a01 = dot(dpdu, dpdv), a11 = dot(dpdv, dpdv);
    float det = a00 * a11 - a01 * a01;
    float inv = det != 0.f ? 1.f / det : 0.f;
    float b0x = dot(dpdu, dpdx), b1x = dot(dpdv, dpdx), b0y = dot(dpdu, dpdy), b1y = dot(dpdv, dpdy);
    auto sane = [](float v) { return std::isfinite(v) ? clamp(v, -1e8f, 1e8f) : 0.f; };
    dudx = sane((a11 * b0x - a01 * b1x) * inv);
    dvdx = sane((a00 * b1x - a01 * b0x) * inv);
    dudy = sane((a11 * b0y - a01 * b1y) * inv);
    dvdy = sane((a00 * b1y - a01 * b0y) * inv);
    if (!is_finite(dpdx) || !is_finite(dpdy)) dpdx = dpdy = Vec3();
}

ShadingContext SurfaceInteraction::shading_context(bool two_sided) const {
    ShadingContext ctx;
    ctx.p = p;
    ctx.uv = uv;
    Vec3 n = ns, g = ng;
    if (two_sided && dot(wo, g) < 0.f) {
        n = -n;
        g = -g;
    }
    ctx.frame = Frame::from_normal_tangent(n, dpdu);
    ctx.ng = g;
    ctx.dpdx = dpdx;
    ctx.dpdy = dpdy;
    ctx.dudx = dudx;
    ctx.dudy = dudy;
    ctx.dvdx = dvdx;
    ctx.dvdy = dvdy;
    return ctx;
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
