#include "render/path_tracer.h"
#include <fmt/format.h>
#include "geometry/shape.h"
#include "render/material.h"
#include "sampling/sampler.h"
#include "sampling/warp.h"
#include "scene/scene.h"

namespace meso {

namespace {

/// Mirror-reflects the ray differentials of `ray` at `si` for the reflected direction
/// `wi` (Igehy 1999, pbrt-v3 SpecularReflect) treating the surface as locally flat
/// (dn/dx = 0: exact for planar mirrors). Other scattering drops the differentials.
void reflect_differentials(const RayDifferential &ray, const SurfaceInteraction &si, Vec3 n, Vec3 wi,
                           RayDifferential &out) {
    if (!ray.has_differentials || length_squared(si.dpdx) == 0.f) {
        out.has_differentials = false;
        return;
    }
    Vec3 wo = -ray.d;
    out.rx_o = si.p + si.dpdx;
    out.ry_o = si.p + si.dpdy;
    Vec3 dwodx = -ray.rx_d - wo, dwody = -ray.ry_d - wo;
    out.rx_d = wi - dwodx + n * (2.f * dot(dwodx, n));
    out.ry_d = wi - dwody + n * (2.f * dot(dwody, n));
    out.has_differentials = is_finite(out.rx_d) && is_finite(out.ry_d);
}

}  // namespace

Spectrum PathTracer::li(const Scene &scene, RayDifferential ray, Sampler &sampler, RenderStats &stats) const {
    Spectrum L(0.f), beta(1.f);
    bool specular_bounce = true;  // camera rays count as specular: no MIS for emitters seen directly
    float prev_pdf = 0.f;
    LightSampleContext prev_ctx;
    float eta_scale = 1.f;

    for (int depth = 0;; ++depth) {
        SurfaceInteraction si;
        ++stats.rays;
        bool hit = scene.intersect(ray, si);
        const bool count_emission = !(depth == 0 && m_hide_emitters);

        if (!hit) {
            if (count_emission)
                for (const Light *env : scene.infinite_lights) {
                    Spectrum Le = env->eval(LightHit{}, -ray.d);
                    if (Le.is_black()) continue;
                    float w = 1.f;
                    if (!specular_bounce) {
                        float lp = scene.light_pmf(env) * env->pdf(prev_ctx, ray.d, LightHit{});
                        w = power_heuristic(prev_pdf, lp);
                    }
                    L += beta * Le * w;
                }
            break;
        }

        if (si.shape->emitter && count_emission) {
            LightHit lh{si.p, si.ng, si.prim};
            Spectrum Le = si.shape->emitter->eval(lh, si.wo);
            if (!Le.is_black()) {
                float w = 1.f;
                if (!specular_bounce) {
                    float lp = scene.light_pmf(si.shape->emitter.get()) * si.shape->emitter->pdf(prev_ctx, ray.d, lh);
                    w = power_heuristic(prev_pdf, lp);
                }
                L += beta * Le * w;
            }
        }

        if (m_max_depth >= 0 && depth + 1 >= m_max_depth) break;
        const Material *mat = si.shape->material.get();
        if (!mat) break;
        const bool two_sided = !mat->has_transmission();
        si.compute_differentials(ray);
        ShadingContext ctx = si.shading_context(two_sided);
        const Vec3 wo = ctx.frame.to_local(si.wo);
        if (wo.z == 0.f && two_sided) break;

        // Next-event estimation: one light sample, MIS-weighted against BSDF sampling.
        if (mat->flags() & BSDF_Smooth) {
            float pmf;
            float ul = sampler.get_1d();
            Vec2 u2 = sampler.get_2d();
            const Light *light = scene.sample_light(ul, pmf);
            LightSample ls;
            if (light && pmf > 0.f && light->sample(LightSampleContext{si.p, ctx.ng}, u2, ls) && ls.pdf > 0.f &&
                !ls.L.is_black()) {
                Vec3 wi = ctx.frame.to_local(ls.wi);
                // Reflection-only surfaces cannot be lit from behind their geometric side.
                bool ok = two_sided ? dot(ls.wi, ctx.ng) > 0.f : true;
                Spectrum f = ok ? mat->eval(ctx, wo, wi) : Spectrum(0.f);
                if (!f.is_black()) {
                    Ray shadow = std::isinf(ls.dist) ? si.spawn_ray(ls.wi) : si.spawn_ray_to(si.p + ls.wi * ls.dist);
                    ++stats.rays;
                    ++stats.shadow_rays;
                    if (!scene.occluded(shadow)) {
                        float light_pdf = pmf * ls.pdf;
                        float w = ls.delta ? 1.f : power_heuristic(light_pdf, mat->pdf(ctx, wo, wi));
                        L += beta * f * ls.L * (w / light_pdf);
                    }
                }
            }
        } else {
            sampler.get_1d();  // keep dimensions aligned across materials
            sampler.get_2d();
        }

        // BSDF sampling for the next segment.
        BSDFSample bs;
        float ulobe = sampler.get_1d();
        Vec2 u = sampler.get_2d();
        if (!mat->sample(ctx, wo, ulobe, u, bs) || bs.weight.is_black() || !(bs.pdf > 0.f)) break;
        Vec3 wi = ctx.frame.to_world(bs.wi);
        // Reject directions on the wrong side of the geometric surface for reflection.
        if ((bs.flags & BSDF_Reflection) && two_sided && dot(wi, ctx.ng) <= 0.f) break;
        beta *= bs.weight;
        if (!beta.is_finite()) break;
        specular_bounce = (bs.flags & BSDF_Delta) != 0;
        prev_pdf = bs.pdf;
        prev_ctx = LightSampleContext{si.p, ctx.ng};
        if (bs.flags & BSDF_Transmission) eta_scale *= sqr(bs.eta);

        RayDifferential next(si.spawn_ray(wi));
        if (bs.flags & BSDF_DeltaReflection) reflect_differentials(ray, si, ctx.frame.n, wi, next);
        ray = next;

        // Russian roulette on the throughput (with the eta^2 factor removed, pbrt-v4).
        if (m_rr_depth >= 0 && depth + 1 >= m_rr_depth) {
            float q = std::min(0.95f, beta.max() * eta_scale);
            if (!(sampler.get_1d() < q)) break;
            beta = beta / q;
        }
    }
    return L;
}

std::string PathTracer::to_string() const {
    return fmt::format("{} (max_depth {}, rr_depth {}{})", m_name, m_max_depth, m_rr_depth,
                       m_hide_emitters ? ", hide_emitters" : "");
}

}  // namespace meso
