// `path` and `direct`: unidirectional path tracing with next-event estimation and multiple
// importance sampling (power heuristic), Russian roulette and a maximum depth; `direct` is the
// same algorithm restricted to two segments (emitters seen directly + one bounce), no roulette.
//
// Parameters (`path`; `direct` takes hide_emitters, differentials and lod_hints):
//   max_depth      int   maximum path segments, -1 = unbounded (Mitsuba semantics)  -1
//   rr_depth       int   depth at which Russian roulette starts, >= 1               5
//   hide_emitters  bool  emitters seen directly by the camera render black          false
//   differentials  bool  ray-differential footprints at every hit (textures and     true
//                        LoD read them; false measures their cost)
//   lod_hints      bool  LoD chains: trace the camera ray first at the level its     true
//                        pixel's hint guesses (trace_lod; false: always the coarsest
//                        level first, then the path's level: measures what they save)
//   leadr_env_quadrature  bool  at points whose material has an environment          false
//                         quadrature (Material::has_env_quadrature: `leadr`), the environment
//                         comes from it, unoccluded; no env NEE or env hits from there
//
// max_depth counts path segments as in Mitsuba: 1 = emitters seen directly, 2 = direct
// illumination, -1 = unbounded (roulette ends paths).
//
// leadr_env_quadrature (off by default): at shading points whose material can integrate the
// environment itself (Material::has_env_quadrature: `leadr`, paper 000 Algorithms 1-3), the whole
// direct contribution of every infinite light comes from that quadrature: env NEE is skipped
// there and a BSDF-sampled ray from that vertex that escapes adds no environment radiance
// (no double counting). Other lights and indirect bounces are unchanged. Approximation (as
// in the paper): the environment is not occluded by the scene at those points, so directions
// where other geometry blocks the sky get the environment and also (through the BSDF-sampled
// ray that hits that geometry) the light it reflects; and the geometric-normal test of NEE
// is not applied (the quadrature only sees wi.z > 0 in the shading frame). Exact for a lone
// convex object. Measured on scenes/ndf/filtering.json (180x120): the LEADR sphere alone
// agrees with 1024-spp path tracing to -1.7% (env_quadrature 8), -0.5% (16), +0.1% (32)
// noise-free at 16 spp; with its five neighbours it is 4% brighter (their occlusion).
#include <atomic>
#include <fmt/format.h>
#include <memory>
#include <optional>
#include <vector>
#include "bsdf/material.h"
#include "core/phase.h"
#include "core/properties.h"
#include "core/registry.h"
#include "geometry/lod.h"
#include "geometry/shape.h"
#include "lights/prefiltered_environment.h"
#include "render/camera.h"
#include "render/differentials.h"
#include "render/integrator.h"
#include "render/scene.h"
#include "sampling/sampler.h"
#include "sampling/warp.h"

namespace meso {

/// A pixel's LoD hint (PathIntegrator::pixel_hint): lo | hi << 8 | round(t 65535) << 16 of its
/// LodSelection (levels < 32, so no hint equals the two markers), or one of the markers.
constexpr uint32_t kHintUnset = 0xFFFFFFFFu;  ///< not computed yet
constexpr uint32_t kHintNone = 0xFFFFFFFEu;   ///< the centre misses the LoD shapes, or sees the coarsest level
/// Images larger than this (4 bytes a pixel) trace without hints.
constexpr size_t kMaxHintPixels = size_t(1) << 26;

class PathIntegrator final : public Integrator {
public:
    PathIntegrator(int max_depth, int rr_depth, bool hide_emitters, bool differentials, bool env_quadrature,
                   bool lod_hints, std::string name)
        : m_max_depth(max_depth), m_rr_depth(rr_depth), m_hide_emitters(hide_emitters),
          m_differentials(differentials), m_leadr_env_quadrature(env_quadrature), m_lod_hints(lod_hints),
          m_name(std::move(name)) {}
    Spectrum li(const Scene &scene, RayDifferential ray, Sampler &sampler, RenderStats &stats) const override;
    std::string to_string() const override;
    /// Prefilters the infinite lights when leadr_env_quadrature is on.
    void preprocess(const Scene &scene) override;
    /// Camera differentials where a material reads footprints at every hit (and
    /// "differentials" is on), or where an LoD shape picks its level from the camera ray's.
    bool camera_differentials(const Scene &scene) const override {
        return m_use_differentials || scene.has_lod_shapes;
    }

private:
    /// The camera ray's closest hit, when it is already traced with the path's mask.
    struct FirstHit {
        bool hit = false;
        bool differentials = false;  ///< si's footprint is already computed from the ray
        SurfaceInteraction si;
    };
    /// One path; every ray of it has `ray.mask` (its LoD level, geometry/lod.h). `first`: the
    /// camera ray's hit if it is already known (nullptr: trace it).
    Spectrum trace(const Scene &scene, RayDifferential ray, Sampler &sampler, RenderStats &stats,
                   const FirstHit *first) const;
    /// A scene with LoD shapes: the level of the path from the camera ray (LodGroup's rule).
    Spectrum trace_lod(const Scene &scene, RayDifferential ray, Sampler &sampler, RenderStats &stats) const;
    /// The level selection of the sample's pixel (its hint: see trace_lod), made at the pixel's
    /// first sample; false where there is none (no pixel, or the hint is the coarsest level).
    bool pixel_hint(const Scene &scene, const RayDifferential &ray, const Sampler &sampler, RenderStats &stats,
                    LodSelection &out) const;
    /// The hint of pixel (x, y): the selection of the camera ray through its centre (lens centre,
    /// the sample's footprint scale) at its hit on the coarsest levels, encoded (see path.cpp).
    uint32_t centre_hint(const Scene &scene, int x, int y, float footprint_scale, RenderStats &stats) const;
    struct PathState;
    /// Environment radiance along an escaped ray, MIS-weighted against light sampling.
    void add_escaped(const Scene &scene, const RayDifferential &ray, PathState &st) const;
    /// Emission of an area light hit by the ray, MIS-weighted against light sampling.
    void add_emitted(const Scene &scene, const RayDifferential &ray, const SurfaceInteraction &si, PathState &st) const;
    /// Shades the hit (environment quadrature, next-event estimation) and samples the BSDF for
    /// the next segment into `ray`; false ends the path.
    bool scatter(const Scene &scene, RayDifferential &ray, SurfaceInteraction &si, const Material &mat,
                 Sampler &sampler, RenderStats &stats, PathState &st) const;
    /// Next-event estimation: one light sample and its shadow ray, power-heuristic MIS.
    void add_light_sample(const Scene &scene, const RayDifferential &ray, const SurfaceInteraction &si,
                          const ShadingContext &ctx, const Vec3 &wo, const Material &mat, bool env_by_quadrature,
                          Sampler &sampler, RenderStats &stats, PathState &st) const;
    int m_max_depth, m_rr_depth;
    bool m_hide_emitters;
    bool m_differentials;  ///< ray-differential footprints at every hit ("differentials")
    bool m_use_differentials = true;  ///< m_differentials and a material of the scene reads them (preprocess)
    bool m_leadr_env_quadrature;
    bool m_lod_hints;  ///< "lod_hints" (trace_lod)
    std::string m_name;
    /// The largest last level of the scene's LoD chains; -1: no LoD shape (no LoD bookkeeping).
    /// A path at level >= this sees what a ray with the coarsest mask sees (preprocess).
    int m_lod_last = -1;
    /// Per-pixel LoD hints (pixel_hint), camera width x height, kHintUnset until the pixel's
    /// first sample; null without LoD chains of two levels or more (or past kMaxHintPixels).
    std::shared_ptr<std::atomic<uint32_t>[]> m_hints;
    int m_hint_w = 0, m_hint_h = 0;
    /// The scene's infinite lights, prefiltered (leadr_env_quadrature only).
    std::vector<std::shared_ptr<const PrefilteredEnvironment>> m_envs;
};

void PathIntegrator::preprocess(const Scene &scene) {
    // Differentials only when a material reads the footprint (LoD selection at the camera hit
    // computes its own).
    m_use_differentials = m_differentials && scene.materials_read_footprints;
    m_lod_last = -1;
    for (const auto &shape : scene.shapes)
        if (shape->lod) m_lod_last = std::max(m_lod_last, shape->lod->chain.levels() - 1);
    m_hints.reset();
    m_hint_w = m_hint_h = 0;
    const size_t pixels = scene.camera ? size_t(scene.camera->width()) * size_t(scene.camera->height()) : 0;
    if (m_lod_hints && m_lod_last > 0 && pixels > 0 && pixels <= kMaxHintPixels) {
        m_hints.reset(new std::atomic<uint32_t>[pixels]);
        for (size_t i = 0; i < pixels; ++i) m_hints[i].store(kHintUnset, std::memory_order_relaxed);
        m_hint_w = scene.camera->width();
        m_hint_h = scene.camera->height();
    }
    m_envs.clear();
    if (m_leadr_env_quadrature)
        for (const Light *env : scene.infinite_lights) m_envs.push_back(PrefilteredEnvironment::from_light(*env));
}

Spectrum PathIntegrator::li(const Scene &scene, RayDifferential ray, Sampler &sampler, RenderStats &stats) const {
    if (m_lod_last < 0) return trace(scene, ray, sampler, stats, nullptr);  // no LoD shape: plain paths
    return trace_lod(scene, ray, sampler, stats);
}

/// The state a path carries from one vertex to the next.
struct PathIntegrator::PathState {
    Spectrum L{0.f};                ///< radiance gathered so far
    Spectrum beta{1.f};             ///< throughput
    bool specular_bounce = true;    ///< the last scattering was delta (camera rays count as such: no MIS)
    float prev_pdf = 0.f;           ///< solid-angle pdf of the BSDF sample that made the current ray
    LightSampleContext prev_ctx;    ///< where that sample was taken (for the light pdf of MIS)
    float eta_scale = 1.f;          ///< product of eta^2 over refractions (removed from roulette)
    bool env_by_quadrature = false; ///< the previous vertex took the environment from its quadrature
    bool si_differentials = false;  ///< the current hit's footprint is already computed (trace_lod)
};

Spectrum PathIntegrator::trace_lod(const Scene &scene, RayDifferential ray, Sampler &sampler,
                                   RenderStats &stats) const {
    // The level comes from the camera ray's hit on the coarsest level of every chain: the
    // footprint there is that of the base surface, the same for every level (ShellShape:
    // footprints are measured on the h = const plane), up to the level's height at the hit. A
    // miss or a shape without LoD leaves the path at the coarsest level. A path whose level is
    // finer must then retrace the camera ray at its level: two traces. So the camera ray is
    // traced first at the level its PIXEL's hint guesses (the selection of the ray through the
    // pixel's centre, made once per pixel and render: a function of the pixel alone, so renders
    // stay independent of threads, tiles, passes, crops and ranks), drawn with the same uniform
    // as the choice below; when the hit there selects that level again (nearly always: the
    // footprint varies little within a pixel), it is the path's first hit, and the coarsest
    // trace is saved. Otherwise the chosen level retraces; a guess that shows no LoD shape
    // falls back on the coarsest level. The choice then differs from the coarsest-first order
    // only by the footprint's dependence on the level's height at the hit (relative size:
    // height / distance) and where a finer level covers a pixel the coarsest does not (edges).
    float u = -1.f;  // the level's uniform, once drawn
    int traced = LodCoarsestLevel;
    LodSelection hint;
    if (pixel_hint(scene, ray, sampler, stats, hint)) {
        if (hint.hi != hint.lo) u = sampler.get_1d();
        const int guess = hint.hi != hint.lo && u < hint.t ? hint.hi : hint.lo;
        if (guess < m_lod_last) traced = guess;
    }
    FirstHit first;
    ray.mask = lod_ray_mask(traced);
    ++stats.rays;
    first.hit = scene.intersect(ray, first.si);
    if (traced != LodCoarsestLevel && !(first.hit && first.si.shape->lod)) {
        traced = LodCoarsestLevel;  // the guess shows no LoD shape: the coarsest level decides
        ray.mask = lod_ray_mask(traced);
        ++stats.rays;
        first = FirstHit();  // a fresh interaction: a shape's fill need not reset every field
        first.hit = scene.intersect(ray, first.si);
    }
    if (!first.hit || !first.si.shape->lod) return trace(scene, ray, sampler, stats, &first);
    // The footprint on the LoD shape picks the level (paper 004 §7.2); the whole path then sees
    // only that level. A level at or beyond every chain's last one sees the same geometry as the
    // coarsest mask. With a model's measured errors the level is the one of least expected pixel
    // MSE at the pixel's footprint and the render's spp; else the camera ray's per-sample
    // footprint picks it (the pixel's times max(1/8, 1/sqrt(spp)); geometry/lod.h has both rules,
    // and the metric check that keeps finer levels where the uv map stretches the model's cells).
    first.si.compute_differentials(ray, scene.camera.get());
    first.differentials = true;
    const LodGroup &g = *first.si.shape->lod;
    const LodSelection sel = select_path_level(g, first.si, ray.footprint_scale, samples_per_pixel());
    auto seen = [&](int level) { return std::min(level, m_lod_last); };
    auto at_level = [&](int level) {
        if (seen(level) == seen(traced)) return trace(scene, ray, sampler, stats, &first);
        RayDifferential r = ray;
        r.mask = lod_ray_mask(level >= m_lod_last ? LodCoarsestLevel : level);
        return trace(scene, r, sampler, stats, nullptr);
    };
    if (sel.hi != sel.lo && g.blend == LodBlend::Blend)
        return at_level(sel.lo) * (1.f - sel.t) + at_level(sel.hi) * sel.t;
    int chosen = sel.lo;
    if (sel.hi != sel.lo) {
        if (u < 0.f) u = sampler.get_1d();
        chosen = u < sel.t ? sel.hi : sel.lo;
    }
    return at_level(chosen);
}

bool PathIntegrator::pixel_hint(const Scene &scene, const RayDifferential &ray, const Sampler &sampler,
                                RenderStats &stats, LodSelection &out) const {
    const int x = sampler.pixel_x(), y = sampler.pixel_y();
    if (!m_hints || x < 0 || y < 0 || x >= m_hint_w || y >= m_hint_h) return false;
    // One pixel's samples are rendered by one thread at a time (a pass holds each pixel once,
    // passes are sequential); a race would only store the same value twice.
    std::atomic<uint32_t> &slot = m_hints[size_t(y) * size_t(m_hint_w) + size_t(x)];
    uint32_t h = slot.load(std::memory_order_relaxed);
    if (h == kHintUnset) {
        h = centre_hint(scene, x, y, ray.footprint_scale, stats);
        slot.store(h, std::memory_order_relaxed);
    }
    if (h == kHintNone) return false;
    out.lo = int(h & 0xFFu);
    out.hi = int((h >> 8) & 0xFFu);
    out.t = float(h >> 16) * (1.f / 65535.f);
    return true;
}

uint32_t PathIntegrator::centre_hint(const Scene &scene, int x, int y, float footprint_scale,
                                     RenderStats &stats) const {
    CameraSample cs;
    cs.film = Vec2(float(x) + 0.5f, float(y) + 0.5f);
    cs.lens = Vec2(0.5f, 0.5f);
    RayDifferential c;
    if (!(scene.camera->generate_ray(cs, c) > 0.f)) return kHintNone;
    c.scale_differentials(footprint_scale / c.footprint_scale);  // as the renderer scales the sample's
    c.mask = lod_ray_mask(LodCoarsestLevel);
    SurfaceInteraction si;
    ++stats.rays;
    if (!scene.intersect(c, si) || !si.shape->lod) return kHintNone;
    si.compute_differentials(c, scene.camera.get());
    const LodSelection s = select_path_level(*si.shape->lod, si, c.footprint_scale, samples_per_pixel());
    if (s.lo >= m_lod_last) return kHintNone;  // the coarsest level: traced first anyway
    const float t = std::clamp(s.t, 0.f, 1.f);
    return uint32_t(s.lo) | uint32_t(s.hi) << 8 | uint32_t(std::lround(t * 65535.f)) << 16;
}

Spectrum PathIntegrator::trace(const Scene &scene, RayDifferential ray, Sampler &sampler, RenderStats &stats,
                               const FirstHit *first) const {
    PathState st;
    for (int depth = 0;; ++depth) {
        SurfaceInteraction si;
        bool hit;
        if (depth == 0 && first) {
            hit = first->hit;
            if (hit) si = first->si;
            st.si_differentials = first->differentials;
        } else {
            ++stats.rays;
            hit = scene.intersect(ray, si);
        }
        const bool count_emission = !(depth == 0 && m_hide_emitters);
        if (!hit) {
            if (count_emission && !st.env_by_quadrature) add_escaped(scene, ray, st);
            break;
        }
        if (si.shape->emitter && count_emission) add_emitted(scene, ray, si, st);
        if (m_max_depth >= 0 && depth + 1 >= m_max_depth) break;
        const Material *mat = si.shape->material.get();
        if (!mat) break;
        if (!scatter(scene, ray, si, *mat, sampler, stats, st)) break;

        // Russian roulette on the throughput (with the eta^2 factor removed, pbrt-v4).
        if (m_rr_depth >= 0 && depth + 1 >= m_rr_depth) {
            float q = std::min(0.95f, st.beta.max() * st.eta_scale);
            if (!(sampler.get_1d() < q)) break;
            st.beta = st.beta / q;
        }
    }
    return st.L;
}

void PathIntegrator::add_escaped(const Scene &scene, const RayDifferential &ray, PathState &st) const {
    PhaseScope phase(Phase::Light);
    for (const Light *env : scene.infinite_lights) {
        float pdf = 0.f;
        Spectrum Le = env->eval_pdf(st.prev_ctx, LightHit{}, -ray.d, st.specular_bounce ? nullptr : &pdf);
        if (Le.is_black()) continue;
        float w = 1.f;
        if (!st.specular_bounce) w = power_heuristic(st.prev_pdf, scene.light_pmf(env) * pdf);
        st.L += st.beta * Le * w;
    }
}

void PathIntegrator::add_emitted(const Scene &scene, const RayDifferential &ray, const SurfaceInteraction &si,
                                 PathState &st) const {
    PhaseScope phase(Phase::Light);
    LightHit lh{si.p, si.ng, si.prim, si.uv};
    Spectrum Le = si.shape->emitter->eval(lh, si.wo);
    if (Le.is_black()) return;
    float w = 1.f;
    if (!st.specular_bounce) {
        float lp = scene.light_pmf(si.shape->emitter.get()) * si.shape->emitter->pdf(st.prev_ctx, ray.d, lh);
        w = power_heuristic(st.prev_pdf, lp);
    }
    st.L += st.beta * Le * w;
}

bool PathIntegrator::scatter(const Scene &scene, RayDifferential &ray, SurfaceInteraction &si, const Material &mat,
                             Sampler &sampler, RenderStats &stats, PathState &st) const {
    const bool two_sided = !mat.has_transmission();
    // Footprint at every bounce (exact transport after delta lobes, the camera-based
    // approximation after rough ones: render/differentials.h).
    std::optional<PhaseScope> phase(std::in_place, Phase::Interaction);
    if (m_use_differentials && !st.si_differentials) si.compute_differentials(ray, scene.camera.get());
    st.si_differentials = false;
    ShadingContext ctx = si.shading_context(two_sided);
    phase.reset();
    const Vec3 wo = ctx.frame.to_local(si.wo);
    if (wo.z == 0.f && two_sided) return false;

    // The whole unoccluded environment by the material's quadrature (leadr_env_quadrature).
    const bool quad = !m_envs.empty() && mat.has_env_quadrature();
    if (quad)
        for (const auto &env : m_envs) st.L += st.beta * mat.env_radiance(ctx, wo, *env);
    st.env_by_quadrature = quad;

    // A uniform for materials with a stochastic evaluation (ShadingContext::u_eval), drawn at
    // every vertex so that the sample dimensions stay aligned across materials. Such a
    // material returns from eval_pdf and sample per-strategy pdfs; the MIS below pairs them
    // (bsdf_pdf from eval_pdf here, prev_pdf = bs.pdf from sample at the emitter hit).
    ctx.u_eval = sampler.get_1d();

    if (mat.flags() & BSDF_Smooth) {
        add_light_sample(scene, ray, si, ctx, wo, mat, quad, sampler, stats, st);
    } else {
        sampler.get_1d();  // keep dimensions aligned across materials
        sampler.get_2d();
    }

    // BSDF sampling for the next segment.
    BSDFSample bs;
    float ulobe = sampler.get_1d();
    Vec2 u = sampler.get_2d();
    phase.emplace(Phase::Bsdf);
    if (!mat.sample(ctx, wo, ulobe, u, bs) || bs.weight.is_black() || !(bs.pdf > 0.f)) return false;
    phase.reset();
    Vec3 wi = ctx.frame.to_world(bs.wi);
    // Reject directions on the wrong side of the geometric surface for reflection.
    if ((bs.flags & BSDF_Reflection) && two_sided && dot(wi, ctx.ng) <= 0.f) return false;
    st.beta *= bs.weight;
    if (!st.beta.is_finite()) return false;
    st.specular_bounce = (bs.flags & BSDF_Delta) != 0;
    st.prev_pdf = bs.pdf;
    st.prev_ctx = LightSampleContext{si.p, ctx.ng};
    if (bs.flags & BSDF_Transmission) st.eta_scale *= sqr(bs.eta);

    if (m_use_differentials && (bs.flags & BSDF_Delta) && ray.has_differentials) {
        RayDifferential next(si.spawn_ray(wi));
        next.footprint_scale = ray.footprint_scale;
        next.mask = ray.mask;
        si.compute_normal_derivatives();
        specular_differentials(ray, si, ctx.frame.n, wi, bs.flags, bs.eta, next);
        ray = next;
        return true;
    }
    // The next segment written in place (footprint_scale and mask carry over): a copy of a
    // temporary RayDifferential reloaded its scalar stores as vectors (store-forwarding stalls).
    // Without differentials the offset rays are never read.
    ray.o = si.offset_origin(wi);
    ray.d = wi;
    ray.tmin = 0.f;
    ray.tmax = Infinity;
    ray.has_differentials = false;
    return true;
}

void PathIntegrator::add_light_sample(const Scene &scene, const RayDifferential &ray, const SurfaceInteraction &si,
                                      const ShadingContext &ctx, const Vec3 &wo, const Material &mat,
                                      bool env_by_quadrature, Sampler &sampler, RenderStats &stats,
                                      PathState &st) const {
    // Next-event estimation: one light sample, MIS-weighted against BSDF sampling.
    const bool two_sided = !mat.has_transmission();
    float pmf;
    float ul = sampler.get_1d();
    Vec2 u2 = sampler.get_2d();
    std::optional<PhaseScope> phase(std::in_place, Phase::Light);
    const Light *light = scene.sample_light(ul, pmf);
    LightSample ls;
    const bool by_quadrature = env_by_quadrature && light && light->is_infinite();  // already counted
    if (!light || !(pmf > 0.f) || by_quadrature || !light->sample(LightSampleContext{si.p, ctx.ng, true}, u2, ls) ||
        !(ls.pdf > 0.f) || (!ls.L_deferred && ls.L.is_black()))
        return;
    phase.emplace(Phase::Bsdf);
    Vec3 wi = ctx.frame.to_local(ls.wi);
    // Reflection-only surfaces cannot be lit from behind their geometric side.
    bool ok = two_sided ? dot(ls.wi, ctx.ng) > 0.f : true;
    float bsdf_pdf = 0.f;
    Spectrum f = ok ? mat.eval_pdf(ctx, wo, wi, ls.delta ? nullptr : &bsdf_pdf) : Spectrum(0.f);
    phase.reset();
    if (f.is_black()) return;
    Ray shadow = std::isinf(ls.dist) ? si.spawn_ray(ls.wi) : si.spawn_ray_to(si.p + ls.wi * ls.dist);
    shadow.mask = ray.mask;  // the path's LoD level
    ++stats.rays;
    ++stats.shadow_rays;
    if (scene.occluded(shadow)) return;
    float light_pdf = pmf * ls.pdf;
    float w = ls.delta ? 1.f : power_heuristic(light_pdf, bsdf_pdf);
    st.L += st.beta * f * light->sampled_radiance(ls) * (w / light_pdf);
}

std::string PathIntegrator::to_string() const {
    return fmt::format("{} (max_depth {}, rr_depth {}{}{}{}{})", m_name, m_max_depth, m_rr_depth,
                       m_hide_emitters ? ", hide_emitters" : "",
                       m_leadr_env_quadrature ? ", environment by material quadrature" : "",
                       m_differentials ? "" : ", no differentials", m_lod_hints ? "" : ", no LoD hints");
}

MESO_REGISTER_INTEGRATOR("path", "unidirectional path tracing, NEE + MIS, Russian roulette",
                         [](const Properties &p) -> std::shared_ptr<Integrator> {
                             int max_depth = p.get_int("max_depth", -1);
                             if (max_depth < -1 || max_depth == 0) p.fail("max_depth", "expected -1 (unbounded) or an integer >= 1");
                             const int rr = p.get_int("rr_depth", 5, Range::at_least(1));
                             return std::make_shared<PathIntegrator>(max_depth, rr, p.get_bool("hide_emitters", false),
                                                                     p.get_bool("differentials", true),
                                                                     p.get_bool("leadr_env_quadrature", false),
                                                                     p.get_bool("lod_hints", true), "path");
                         });

MESO_REGISTER_INTEGRATOR("direct", "direct illumination with MIS (emitters + one bounce)",
                         [](const Properties &p) -> std::shared_ptr<Integrator> {
                             return std::make_shared<PathIntegrator>(2, -1, p.get_bool("hide_emitters", false),
                                                                     p.get_bool("differentials", true), false,
                                                                     p.get_bool("lod_hints", true), "direct");
                         });

}  // namespace meso
