#include "render/differentials.h"
#include "core/math.h"
#include "geometry/interaction.h"
#include "render/camera.h"
#include "bsdf/material.h"

namespace meso {

Vec3 rotate_from_to(Vec3 a, Vec3 b, Vec3 v) {
    float c = dot(a, b);
    if (c < -0.999999f) {
        // Half-turn about any axis perpendicular to a.
        Vec3 m, unused;
        coordinate_system(a, m, unused);
        return m * (2.f * dot(m, v)) - v;
    }
    // R v = c v + k x v + k (k.v) / (1 + c), k = a x b  (= I + [k]x + [k]x^2 / (1 + c)).
    Vec3 k = cross(a, b);
    return v * c + cross(k, v) + k * (dot(k, v) / (1.f + c));
}

bool specular_differentials(const RayDifferential &in, const SurfaceInteraction &si, Vec3 n, Vec3 wi,
                            uint32_t flags, float eta, RayDifferential &out) {
    out.footprint_scale = in.footprint_scale;
    out.has_differentials = false;
    const bool reflect = (flags & BSDF_DeltaReflection) != 0, refract = (flags & BSDF_DeltaTransmission) != 0;
    if (!in.has_differentials || reflect == refract) return false;
    if (length_squared(si.dpdx) == 0.f && length_squared(si.dpdy) == 0.f) return false;

    // Shading-normal derivatives along the pixel steps; si.dndu/dndv refer to si.ns.
    Vec3 dndx = si.dndu * si.dudx + si.dndv * si.dvdx;
    Vec3 dndy = si.dndu * si.dudy + si.dndv * si.dvdy;
    if (dot(n, si.ns) < 0.f) {
        dndx = -dndx;
        dndy = -dndy;
    }
    const Vec3 wo = si.wo;
    float wn = dot(wo, n);
    if (refract && wn < 0.f) {  // Snell's law below needs n on the side of wo
        n = -n;
        dndx = -dndx;
        dndy = -dndy;
        wn = -wn;
    }
    const Vec3 dwodx = -in.rx_d - wo, dwody = -in.ry_d - wo;
    const float dwn_dx = dot(dwodx, n) + dot(wo, dndx);
    const float dwn_dy = dot(dwody, n) + dot(wo, dndy);

    if (reflect) {
        out.rx_d = wi - dwodx + (dndx * wn + n * dwn_dx) * 2.f;
        out.ry_d = wi - dwody + (dndy * wn + n * dwn_dy) * 2.f;
    } else {
        if (!(eta > 0.f) || !std::isfinite(eta)) return false;
        // cos_t -> 0 at the critical angle, where the true derivative diverges: cap the
        // 1/cos_t so the transported footprint grows large but stays finite.
        const float cos_t = std::max(-dot(wi, n), 1.f / MaxFootprintStretch);
        const float inv_eta = 1.f / eta;
        const float mu = wn * inv_eta - cos_t;
        const float dmu_factor = inv_eta - wn * inv_eta * inv_eta / cos_t;
        out.rx_d = wi - dwodx * inv_eta + dndx * mu + n * (dwn_dx * dmu_factor);
        out.ry_d = wi - dwody * inv_eta + dndy * mu + n * (dwn_dy * dmu_factor);
    }
    out.rx_o = si.p + si.dpdx;
    out.ry_o = si.p + si.dpdy;
    out.has_differentials = is_finite(out.rx_d) && is_finite(out.ry_d) && is_finite(out.rx_o) && is_finite(out.ry_o);
    return out.has_differentials;
}

// ---- Camera: the camera-based approximation (pbrt-v4 CameraBase) -------------------------

void Camera::find_minimum_differentials(Vec3 origin, const Frame &camera_to_world) {
    m_cam_origin = origin;
    m_cam_frame = camera_to_world;
    const Vec3 z(0, 0, 1);
    float best_pos_x = Infinity, best_pos_y = Infinity, best_dir_x = Infinity, best_dir_y = Infinity;
    m_min_pos_dx = m_min_pos_dy = m_min_dir_dx = m_min_dir_dy = Vec3();
    const int n = 17;
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) {
            CameraSample cs;
            cs.film = Vec2(float(i) / (n - 1) * m_width, float(j) / (n - 1) * m_height);
            cs.lens = Vec2(0.5f, 0.5f);
            RayDifferential r;
            generate_ray(cs, r);
            if (!r.has_differentials) continue;
            Vec3 dox = m_cam_frame.to_local(r.rx_o - r.o), doy = m_cam_frame.to_local(r.ry_o - r.o);
            if (length(dox) < best_pos_x) best_pos_x = length(m_min_pos_dx = dox);
            if (length(doy) < best_pos_y) best_pos_y = length(m_min_pos_dy = doy);
            // Direction differentials in the frame that rotates the ray onto +z.
            Vec3 d = normalize(m_cam_frame.to_local(r.d));
            Vec3 dx = rotate_from_to(d, z, normalize(m_cam_frame.to_local(r.rx_d))) - z;
            Vec3 dy = rotate_from_to(d, z, normalize(m_cam_frame.to_local(r.ry_d))) - z;
            if (length(dx) < best_dir_x) best_dir_x = length(m_min_dir_dx = dx);
            if (length(dy) < best_dir_y) best_dir_y = length(m_min_dir_dy = dy);
        }
    // Perpendicular parts (first order), in world space for approximate_dp_dxy.
    auto world_perp = [&](Vec3 v) { return m_cam_frame.to_world(Vec3(v.x, v.y, 0.f)); };
    m_min_pos_dx_world = world_perp(m_min_pos_dx);
    m_min_pos_dy_world = world_perp(m_min_pos_dy);
    m_min_dir_dx_world = world_perp(m_min_dir_dx);
    m_min_dir_dy_world = world_perp(m_min_dir_dy);
}

void Camera::approximate_dp_dxy(Vec3 p, Vec3 n, float footprint_scale, Vec3 &dpdx, Vec3 &dpdy) const {
    // Everything in world space: the rotation taking the camera's forward axis F onto the
    // view direction w to p (the same minimal rotation as pbrt's camera-space RotateFromTo)
    // carries the per-pixel offsets m_min_*_world (perpendicular to F) to perpendiculars of w.
    dpdx = dpdy = Vec3();
    const Vec3 v = p - m_cam_origin;
    const float r2 = length_squared(v);
    if (!(r2 > 0.f) || !std::isfinite(r2)) return;
    const float inv_r = 1.f / std::sqrt(r2), r = r2 * inv_r;
    const Vec3 w = v * inv_r, F = m_cam_frame.n;
    // Shading code passes unit normals; only renormalise (or replace) others.
    Vec3 nn = n;
    const float n2 = length_squared(n);
    if (!(std::abs(n2 - 1.f) < 1e-3f)) nn = n2 > 0.f && std::isfinite(n2) ? n / std::sqrt(n2) : -w;
    // 1/cos of the tangent plane as seen along w, capped at MaxFootprintStretch.
    float cos_v = dot(nn, w);
    if (std::abs(cos_v) < 1.f / MaxFootprintStretch) cos_v = std::copysign(1.f / MaxFootprintStretch, cos_v);
    const float inv_cos = 1.f / cos_v;
    const float c = dot(F, w);
    const Vec3 k = cross(F, w);
    const bool flip = c < -0.999999f;  // p behind the camera: half-turn instead
    const float inv_1pc = flip ? 0.f : 1.f / (1.f + c);
    auto transfer = [&](Vec3 pos, Vec3 dir) {
        Vec3 q0 = pos + dir * r;  // offset at distance r, perpendicular to F
        Vec3 q = flip ? rotate_from_to(F, w, q0) : q0 * c + cross(k, q0) + k * (dot(k, q0) * inv_1pc);
        q = q - w * dot(q, w);  // first order: perpendicular to the view direction
        // Slide along w onto the tangent plane: dp = q - w (n.q) / (n.w).
        return (q - w * (dot(nn, q) * inv_cos)) * footprint_scale;
    };
    dpdx = transfer(m_min_pos_dx_world, m_min_dir_dx_world);
    dpdy = transfer(m_min_pos_dy_world, m_min_dir_dy_world);
    if (!is_finite(dpdx) || !is_finite(dpdy)) dpdx = dpdy = Vec3();
}

// Declared in geometry/interaction.h; defined here because it falls back on the camera.
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

}  // namespace meso
