// `diffuse`: Lambertian reflector.
//
// Model: f(wo, wi) = reflectance / π on the upper hemisphere (Lambert 1760), so
// eval = reflectance · cos θi / π. Sampling: cosine-weighted hemisphere (Shirley-Chiu
// concentric map), pdf = cos θi / π, weight = reflectance exactly; reflectance 1 is
// lossless (albedo 1 for every wo). Reciprocal.
//
// Parameters (Mitsuba 3 names)
//   name         type     default  range
//   reflectance  texture  0.5      [0, 1] per channel (albedo)
#include <fmt/format.h>
#include "bsdf/material.h"
#include "texture/texture.h"
#include "sampling/warp.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

class Diffuse final : public Material {
public:
    explicit Diffuse(std::shared_ptr<Texture> r) : m_reflectance(std::move(r)) {}

    uint32_t flags() const override { return BSDF_DiffuseReflection; }

    Spectrum eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        if (!(wo.z > 0.f) || !(wi.z > 0.f)) return Spectrum(0.f);
        return m_reflectance->eval(ctx) * (wi.z * InvPi);
    }

    float pdf(const ShadingContext &, const Vec3 &wo, const Vec3 &wi) const override {
        if (!(wo.z > 0.f) || !(wi.z > 0.f)) return 0.f;
        return wi.z * InvPi;
    }

    bool sample(const ShadingContext &ctx, const Vec3 &wo, float, Vec2 u, BSDFSample &out) const override {
        if (!(wo.z > 0.f)) return false;
        Vec3 wi = square_to_cosine_hemisphere(u);
        if (!(wi.z > 0.f)) return false;  // the rim of the disk: pdf 0
        out.wi = wi;
        out.pdf = wi.z * InvPi;
        out.weight = m_reflectance->eval(ctx);
        out.eta = 1.f;
        out.flags = BSDF_DiffuseReflection;
        return true;
    }

    Spectrum albedo_hint(const ShadingContext &ctx) const override { return m_reflectance->eval(ctx); }
    bool uses_footprint() const override { return any_varies({m_reflectance.get()}); }
    std::string to_string() const override { return fmt::format("diffuse[{}]", m_reflectance->to_string()); }

private:
    std::shared_ptr<Texture> m_reflectance;
};

MESO_REGISTER_MATERIAL("diffuse", "Lambertian reflector (cosine-sampled)", [](const Properties &p) -> std::shared_ptr<Material> {
    return std::make_shared<Diffuse>(p.get_texture("reflectance", Spectrum(0.5f)));
});

}  // namespace
}  // namespace meso
