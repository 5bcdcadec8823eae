// `aov`: arbitrary output variables of the first hit, written as RGB.
//   aov   string  one of "normal" (shading normal, world, as-is in [-1,1]),
//                 "geo_normal", "position", "uv" (u, v, 0), "albedo" (material hint),
//                 "depth" (ray distance)                                         "normal"
// Misses give 0. Normals are not remapped to [0,1]: the EXR holds the true vectors.
#include <fmt/format.h>
#include "geometry/shape.h"
#include "render/integrator.h"
#include "render/material.h"
#include "scene/properties.h"
#include "scene/registry.h"
#include "scene/scene.h"

namespace meso {
namespace {

enum class Aov { Normal, GeoNormal, Position, UV, Albedo, Depth };

class AovIntegrator final : public Integrator {
public:
    AovIntegrator(Aov aov, std::string name) : m_aov(aov), m_name(std::move(name)) {}
    Spectrum li(const Scene &scene, RayDifferential ray, Sampler &, RenderStats &stats) const override {
        SurfaceInteraction si;
        ++stats.rays;
        if (!scene.intersect(ray, si)) return Spectrum(0.f);
        switch (m_aov) {
            case Aov::Normal: return {si.ns.x, si.ns.y, si.ns.z};
            case Aov::GeoNormal: return {si.ng.x, si.ng.y, si.ng.z};
            case Aov::Position: return {si.p.x, si.p.y, si.p.z};
            case Aov::UV: return {si.uv.x, si.uv.y, 0.f};
            case Aov::Depth: return Spectrum(si.t);
            case Aov::Albedo: {
                if (!si.shape->material) return Spectrum(0.f);
                si.compute_differentials(ray);
                return si.shape->material->albedo_hint(si.shading_context(true));
            }
        }
        return Spectrum(0.f);
    }
    std::string to_string() const override { return fmt::format("aov ({})", m_name); }

private:
    Aov m_aov;
    std::string m_name;
};

MESO_REGISTER_INTEGRATOR("aov", "first-hit AOVs: normal, geo_normal, position, uv, albedo, depth",
                         [](const Properties &p) -> std::shared_ptr<Integrator> {
                             std::string a = p.get_string("aov", "normal");
                             static const std::pair<const char *, Aov> names[] = {
                                 {"normal", Aov::Normal}, {"geo_normal", Aov::GeoNormal}, {"position", Aov::Position},
                                 {"uv", Aov::UV},         {"albedo", Aov::Albedo},        {"depth", Aov::Depth}};
                             for (auto &[n, v] : names)
                                 if (a == n) return std::make_shared<AovIntegrator>(v, a);
                             p.fail("aov", fmt::format("unknown aov '{}' (expected normal, geo_normal, position, uv, albedo or depth)", a));
                         });

}  // namespace
}  // namespace meso
