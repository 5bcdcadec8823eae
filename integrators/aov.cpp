// `aov`: arbitrary output variables of the first hit, written as RGB.
//   aov   string  one of "normal" (shading normal, world, as-is in [-1,1]),
//                 "geo_normal", "position", "uv" (u, v, 0), "albedo" (material hint),
//                 "depth" (ray distance), "footprint" (pixel footprint width in
//                 texels, issue 4: major axis of the ray-differential footprint in the
//                 shape's full-resolution map, tiling included, or `resolution` texels
//                 per unit uv for shapes without a map), "lod" (continuous level i + t of
//                 the chain `lod_factors` for that footprint, scaled by `lod_bias`; on a
//                 shape with its own `lod` block, the level the path tracer picks there:
//                 that block's chain and rule, the metric check, the per-sample footprint),
//                 "footprint_color" / "lod_color" (the same as viridis false colour:
//                 log2 footprint over [0, log2 `max_texels`]; level over [0, levels-1])  "normal"
//   resolution   float  texels per unit uv where the shape has no map               1024
//   lod_factors  [f..]  LoD chain (increasing downsampling factors, first >= 1)      [1, 8, 64]
//   lod_bias     float  footprint scale                                              1
//   max_texels   float  top of the footprint colour scale                            4096
// Misses give 0. Normals are not remapped to [0,1]: the EXR holds the true vectors.
#include <fmt/format.h>
#include <algorithm>
#include <cmath>
#include "core/error.h"
#include "core/ray.h"
#include "geometry/shape.h"
#include "image/false_colour.h"
#include "geometry/lod.h"
#include "render/integrator.h"
#include "bsdf/material.h"
#include "core/properties.h"
#include "core/registry.h"
#include "render/scene.h"

namespace meso {
namespace {

enum class Aov { Normal, GeoNormal, Position, UV, Albedo, Depth, Footprint, Lod, FootprintColor, LodColor };

struct FootprintParams {
    double resolution = 1024;
    LodChain chain{{1.f, 8.f, 64.f}};
    float bias = 1.f, max_texels = 4096.f;
};

class AovIntegrator final : public Integrator {
public:
    AovIntegrator(Aov aov, std::string name, FootprintParams fp)
        : m_aov(aov), m_name(std::move(name)), m_fp(std::move(fp)) {}
    Spectrum li(const Scene &scene, RayDifferential ray, Sampler &, RenderStats &stats) const override {
        SurfaceInteraction si;
        ++stats.rays;
        // The level aovs look at LoD shapes as the path tracer's camera ray does: at the coarsest
        // level, whose hit picks the level (integrators/path.cpp). Other aovs see the original.
        if (m_aov == Aov::Lod || m_aov == Aov::LodColor) ray.mask = lod_ray_mask(LodCoarsestLevel);
        if (!scene.intersect(ray, si)) return Spectrum(0.f);
        switch (m_aov) {
            case Aov::Normal: return {si.ns.x, si.ns.y, si.ns.z};
            case Aov::GeoNormal: return {si.ng.x, si.ng.y, si.ng.z};
            case Aov::Position: return {si.p.x, si.p.y, si.p.z};
            case Aov::UV: return {si.uv.x, si.uv.y, 0.f};
            case Aov::Depth: return Spectrum(si.t);
            case Aov::Footprint:
            case Aov::Lod:
            case Aov::FootprintColor:
            case Aov::LodColor: {
                si.compute_differentials(ray, scene.camera.get());
                double w = m_fp.resolution, h = m_fp.resolution;
                si.shape->texel_grid(w, h);
                const float texels = footprint_texels(si.dudx, si.dudy, si.dvdx, si.dvdy, w, h);
                float level = m_fp.chain.position(texels, m_fp.bias);
                int levels = m_fp.chain.levels();
                if (si.shape->lod && (m_aov == Aov::Lod || m_aov == Aov::LodColor)) {
                    // A shape with its own `lod` block: the level the renderer picks there, with
                    // the block's chain, bias and rule, the metric check and the per-sample scale.
                    const LodGroup &g = *si.shape->lod;
                    const LodSelection sel = select_path_level(g, si, ray.footprint_scale, samples_per_pixel());
                    level = float(sel.lo) + std::clamp(sel.t, 0.f, 1.f) * float(sel.hi - sel.lo);
                    levels = g.chain.levels();
                }
                switch (m_aov) {
                    case Aov::Footprint: return Spectrum(texels);
                    case Aov::Lod: return Spectrum(level);
                    case Aov::FootprintColor:
                        return viridis_linear(std::log2(std::max(texels, 1.f)) / std::log2(std::max(m_fp.max_texels, 2.f)));
                    default:
                        return viridis_linear(levels > 1 ? level / float(levels - 1) : 0.f);
                }
            }
            case Aov::Albedo: {
                if (!si.shape->material) return Spectrum(0.f);
                si.compute_differentials(ray, scene.camera.get());
                return si.shape->material->albedo_hint(si.shading_context(true));
            }
        }
        return Spectrum(0.f);
    }
    std::string to_string() const override { return fmt::format("aov ({})", m_name); }

private:
    Aov m_aov;
    std::string m_name;
    FootprintParams m_fp;
};

MESO_REGISTER_INTEGRATOR("aov", "first-hit AOVs: normal, geo_normal, position, uv, albedo, depth, footprint, lod, footprint_color, lod_color",
                         [](const Properties &p) -> std::shared_ptr<Integrator> {
                             std::string a = p.get_string("aov", "normal");
                             static const std::pair<const char *, Aov> names[] = {
                                 {"normal", Aov::Normal}, {"geo_normal", Aov::GeoNormal}, {"position", Aov::Position},
                                 {"uv", Aov::UV},         {"albedo", Aov::Albedo},        {"depth", Aov::Depth},
                                 {"footprint", Aov::Footprint}, {"lod", Aov::Lod},
                                 {"footprint_color", Aov::FootprintColor}, {"lod_color", Aov::LodColor}};
                             FootprintParams fp;
                             fp.resolution = p.get_float("resolution", 1024.f);
                             if (!(fp.resolution > 0.0) || !std::isfinite(fp.resolution))
                                 p.fail("resolution", "expected a positive number of texels per unit uv");
                             if (p.has("lod_factors")) {
                                 try {
                                     fp.chain = LodChain(p.get_floats("lod_factors"));
                                 } catch (const MesoError &e) {
                                     p.fail("lod_factors", e.what());
                                 }
                             }
                             fp.bias = p.get_float("lod_bias", 1.f);
                             if (!(fp.bias > 0.f) || !std::isfinite(fp.bias)) p.fail("lod_bias", "expected a positive number");
                             fp.max_texels = p.get_float("max_texels", 4096.f);
                             if (!(fp.max_texels > 1.f) || !std::isfinite(fp.max_texels)) p.fail("max_texels", "expected a number > 1");
                             for (auto &[n, v] : names)
                                 if (a == n) return std::make_shared<AovIntegrator>(v, a, fp);
                             p.fail("aov", fmt::format("unknown aov '{}' (expected normal, geo_normal, position, uv, albedo, depth, "
                                                       "footprint, lod, footprint_color or lod_color)", a));
                         });

}  // namespace
}  // namespace meso
