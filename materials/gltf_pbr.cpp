// `gltf_pbr`: the glTF 2.0 metallic-roughness material (glTF 2.0 spec, Appendix B
// "BRDF Implementation": metal_brdf / dielectric_brdf / fresnel_mix).
//
// Model (per shading point; c = base_color, m = metallic, α = roughness²)
//   h    = normalize(wo + wi),  v = wo·h (= wi·h)
//   F0   = mix(0.04, c, m)                          (per channel)
//   F    = F0 + (1 − F0)(1 − v)^5                   (Schlick)
//   f    = F · D(h) G(wo, wi) / (4 cos θo cos θi)   (isotropic GGX, height-correlated Smith,
//                                                   bsdf/microfacet.h)
//        + (1 − F_d) · c (1 − m) / π                (Lambert, weighted by 1 − F_d)
//   F_d  = Schlick at max(1 − v, 1 − cos θo, 1 − cos θi)^5: the reference uses F (at v);
//          the max is symmetric and keeps the albedo <= 1 at grazing angles, where the
//          reference's diffuse + specular reaches 1.02 (white base, θo = 89°).
//   This is the spec's mix(dielectric_brdf, metal_brdf, m) written with one Fresnel term:
//   for a dielectric F0 = 0.04 and the specular is untinted, for a metal F0 = c.
//   F and F_d are symmetric in (wo, wi), so f(wo, wi) = f(wi, wo).
//   Energy: ∫ f cos θi ≤ 1 for c, m, roughness in [0, 1] (single scattering: no energy
//   is added; rough metals lose the multiple-scattering part, as in the reference).
//   Sampling: the specular lobe (GGX visible normals) with probability
//     p = S / (S + D),  S = mean(F0 + (1 − F0)(1 − cos θo)^5),
//                       D = mean(c (1 − m)) (1 − F_0.04(cos θo)),
//   clamped to [0.05, 0.95] while both lobes are non-zero (p = 1 when D = 0), else
//   cosine-weighted diffuse; pdf() is that mixture of the two solid-angle densities.
//
// Parameters
//   name        type           default  range / notes
//   base_color  texture        1        [0, 1] linear RGB (a glTF baseColorTexture is sRGB:
//                                       load it with a `bitmap` whose `raw` is false)
//   metallic    texture|float  1        [0, 1]; a texture is read as grey (mean of RGB):
//                                       glTF's blue channel via bitmap's "channel": "b"
//   roughness   texture|float  1        [0, 1] perceptual roughness, α = roughness², clamped
//                                       to >= 1e-4 (no delta lobe: roughness 0 is a very
//                                       sharp GGX lobe); glTF's green channel: "channel": "g"
// Normal maps: wrap the material in `normalmap`; emission: an area emitter on the shape.
#include <fmt/format.h>
#include <algorithm>
#include "bsdf/material.h"
#include "bsdf/microfacet.h"
#include "core/properties.h"
#include "core/registry.h"
#include "sampling/warp.h"
#include "texture/texture.h"

namespace meso {
namespace {

inline float schlick_weight(float cos_theta) {
    float x = 1.f - clamp(cos_theta, 0.f, 1.f);
    float x2 = x * x;
    return x2 * x2 * x;
}

class GltfPbr final : public Material {
public:
    GltfPbr(std::shared_ptr<Texture> base, std::shared_ptr<Texture> metallic, std::shared_ptr<Texture> roughness)
        : m_base(std::move(base)), m_metallic(std::move(metallic)), m_roughness(std::move(roughness)) {}

    /// The shading point's parameters (textures evaluated once).
    struct Point {
        Spectrum f0, diffuse;  ///< F0 = mix(0.04, c, m); diffuse albedo c (1 − m)
        MicrofacetDistribution dist;
        float p_spec;          ///< probability of sampling the specular lobe
    };

    Point point(const ShadingContext &ctx, float cos_o) const {
        Spectrum c = m_base->eval(ctx);
        float m = clamp(m_metallic->eval_float(ctx), 0.f, 1.f);
        float r = clamp(m_roughness->eval_float(ctx), 0.f, 1.f);
        float alpha = std::max(r * r, MicrofacetDistribution::kMinAlpha);
        Spectrum f0 = Spectrum(0.04f * (1.f - m)) + c * m;
        Spectrum diffuse = c * (1.f - m);
        float w = schlick_weight(cos_o);
        float s = (f0 + (Spectrum(1.f) - f0) * w).average();
        float d = diffuse.average() * (1.f - (0.04f + 0.96f * w));
        float p = 1.f;
        if (d > 0.f) p = clamp(s / (s + d), 0.05f, 0.95f);
        return Point{f0, diffuse, MicrofacetDistribution(MicrofacetType::GGX, alpha, alpha, true), p};
    }

    uint32_t flags() const override { return BSDF_DiffuseReflection | BSDF_GlossyReflection; }

    static Spectrum value(const Point &p, const Vec3 &wo, const Vec3 &wi) {
        Vec3 h = normalize(wo + wi);
        float v = dot(wi, h);
        if (!(v > 0.f)) return Spectrum(0.f);
        float w = schlick_weight(v);
        Spectrum F = p.f0 + (Spectrum(1.f) - p.f0) * w;
        // Diffuse weight 1 − max(F(v), F(cos θo), F(cos θi)): symmetric, and at grazing
        // angles it keeps the albedo <= 1 (the reference's 1 − F(v) adds ~2% at 89°).
        float wmax = std::max(w, std::max(schlick_weight(wo.z), schlick_weight(wi.z)));
        Spectrum Fd = p.f0 + (Spectrum(1.f) - p.f0) * wmax;
        Spectrum out = (Spectrum(1.f) - Fd) * p.diffuse * (wi.z * InvPi);
        double spec = double(p.dist.D(h)) * p.dist.G(wo, wi, h) / (4.0 * wo.z);
        if (std::isfinite(spec) && spec > 0.0) out += F * float(spec);
        return out;
    }

    static float mixture_pdf(const Point &p, const Vec3 &wo, const Vec3 &wi) {
        float pd = (1.f - p.p_spec) * wi.z * InvPi;
        Vec3 h = normalize(wo + wi);
        float dwh = dot(wo, h);
        if (!(dwh > 0.f)) return pd;
        double ps = double(p.dist.pdf(wo, h)) / (4.0 * dwh);
        return std::isfinite(ps) ? pd + p.p_spec * float(ps) : pd;
    }

    Spectrum eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        if (!(wo.z > 0.f) || !(wi.z > 0.f)) return Spectrum(0.f);
        return value(point(ctx, wo.z), wo, wi);
    }

    float pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        if (!(wo.z > 0.f) || !(wi.z > 0.f)) return 0.f;
        return mixture_pdf(point(ctx, wo.z), wo, wi);
    }

    Spectrum eval_pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi, float *pdf) const override {
        if (!(wo.z > 0.f) || !(wi.z > 0.f)) {
            if (pdf) *pdf = 0.f;
            return Spectrum(0.f);
        }
        Point p = point(ctx, wo.z);
        if (pdf) *pdf = mixture_pdf(p, wo, wi);
        return value(p, wo, wi);
    }

    bool sample(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, BSDFSample &out) const override {
        if (!(wo.z > 0.f)) return false;
        Point p = point(ctx, wo.z);
        Vec3 wi;
        if (!sample_glossy_or_diffuse(p.dist, wo, u_lobe, p.p_spec, u, wi, out.flags)) return false;
        out.wi = wi;
        out.eta = 1.f;
        out.pdf = mixture_pdf(p, wo, wi);
        if (!(out.pdf > 0.f)) return false;
        out.weight = value(p, wo, wi) / out.pdf;
        return out.weight.is_finite();
    }

    Spectrum albedo_hint(const ShadingContext &ctx) const override { return m_base->eval(ctx); }

    std::string to_string() const override {
        return fmt::format("gltf_pbr[base_color={}, metallic={}, roughness={}]", m_base->to_string(),
                           m_metallic->to_string(), m_roughness->to_string());
    }

private:
    std::shared_ptr<Texture> m_base, m_metallic, m_roughness;
};

MESO_REGISTER_MATERIAL("gltf_pbr", "glTF 2.0 metallic-roughness BRDF (GGX + Schlick + Lambert, glTF spec Appendix B)",
                       [](const Properties &p) -> std::shared_ptr<Material> {
                           return std::make_shared<GltfPbr>(p.get_texture("base_color", Spectrum(1.f)),
                                                            p.get_texture("metallic", Spectrum(1.f)),
                                                            p.get_texture("roughness", Spectrum(1.f)));
                       });

}  // namespace
}  // namespace meso
