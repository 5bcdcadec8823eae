#include "geometry/interaction.h"
#include "render/camera.h"

namespace meso {

void SurfaceInteraction::compute_differentials(const RayDifferential &ray, const Camera *camera) {
    dpdx = dpdy = Vec3();
    dudx = dudy = dvdx = dvdy = 0.f;
    bool ok = false;
    if (ray.has_differentials) {
        // Intersect the offset rays with the tangent plane at p (Igehy 1999; pbrt-v3 10.1.1).
        const bool macro = length_squared(n_footprint) > 0.f;
        const Vec3 n = macro ? n_footprint : ng;
        const float ddx = dot(n, ray.rx_d), ddy = dot(n, ray.ry_d);
        const float tx = dot(n, p - ray.rx_o) / ddx, ty = dot(n, p - ray.ry_o) / ddy;
        // A negative or infinite t means the offset ray is parallel to or leaves the plane.
        if (ddx != 0.f && ddy != 0.f && tx >= 0.f && ty >= 0.f && std::isfinite(tx) && std::isfinite(ty)) {
            dpdx = ray.rx_o + ray.rx_d * tx - p;
            dpdy = ray.ry_o + ray.ry_d * ty - p;
            // Grazing angles: cap the stretch against the footprint perpendicular to the ray
            // (the offset rays taken to p's distance along the ray).
            auto cap = [&](Vec3 &dp, Vec3 o, Vec3 d) {
                float t = dot(p - o, d) / std::max(length_squared(d), 1e-30f);
                Vec3 perp = o + d * t - p;
                float limit = MaxFootprintStretch * length(perp), l = length(dp);
                if (l > limit && l > 0.f) dp = dp * (limit / l);
            };
            cap(dpdx, ray.rx_o, ray.rx_d);
            cap(dpdy, ray.ry_o, ray.ry_d);
            ok = is_finite(dpdx) && is_finite(dpdy);
        }
    }
    if (!ok) {
        dpdx = dpdy = Vec3();
        if (!camera) return;
        camera->approximate_dp_dxy(p, length_squared(n_footprint) > 0.f ? n_footprint : ng, ray.footprint_scale, dpdx,
                                   dpdy);
    }
    // Huge footprints: keep |dp| representable (length_squared finite) for whoever reads it.
    auto limit = [](Vec3 &dp) {
        float m = max_component(vabs(dp));
        if (m > 1e15f) dp = dp * (1e15f / m);
    };
    limit(dpdx);
    limit(dpdy);
    // Least-squares solve of [dpdu dpdv] (du, dv)^T = dp (pbrt-v4 SurfaceInteraction).
    const bool macro_t = length_squared(n_footprint) > 0.f;
    const Vec3 dpdu = macro_t ? dpdu_footprint : this->dpdu, dpdv = macro_t ? dpdv_footprint : this->dpdv;
    float a00 = dot(dpdu, dpdu), a01 = dot(dpdu, dpdv), a11 = dot(dpdv, dpdv);
    float det = a00 * a11 - a01 * a01;
    // Degenerate (parallel or zero) dp/du, dp/dv: no uv footprint rather than a huge one.
    float inv = det > 1e-12f * a00 * a11 && std::isfinite(det) ? 1.f / det : 0.f;
    float b0x = dot(dpdu, dpdx), b1x = dot(dpdv, dpdx), b0y = dot(dpdu, dpdy), b1y = dot(dpdv, dpdy);
    auto sane = [](float v) { return std::isfinite(v) ? clamp(v, -1e8f, 1e8f) : 0.f; };
    dudx = sane((a11 * b0x - a01 * b1x) * inv);
    dvdx = sane((a00 * b1x - a01 * b0x) * inv);
    dudy = sane((a11 * b0y - a01 * b1y) * inv);
    dvdy = sane((a00 * b1y - a01 * b0y) * inv);
}

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
