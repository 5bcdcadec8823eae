// `blinnphong`: normalised Blinn-Phong, read as a microfacet BRDF (paper 003, Baker &
// Hill 2012, "Rock-solid shading", part 1: "a normalized variant Blinn-Phong ... is no
// hack: microfacets").
//
// Model
//   D(h) = (s + 2)/(2π) cos^s θh   (normalised: ∫ D(h) cos θh dω_h = 1)
//   f    = F(wi·h) D(h) G(wo, wi) / (4 cos θo cos θi) · specular_reflectance
//          + diffuse_reflectance / π
//   G    = height-correlated Smith 1/(1 + Λ(wo) + Λ(wi)) with the EXACT Smith Λ of this D
//          (bsdf/microfacet.h, blinnphong_lambda: projected-area identity, quadrature;
//          tabulated once when the exponent is constant). The usual stand-in — Beckmann's
//          Λ at the equivalent roughness α = sqrt(2/(s + 2)) (Walter et al. 2007 §5.2; the
//          equivalence paper 003 uses to convert powers to LEAN moments) — agrees for large s
//          (< 0.2% at s = 1000) but underestimates Λ at small s (by half at s = 0, θ = 85°),
//          which made the albedo reach 1.65 at s = 0, θo = 89°: it is not energy conserving,
//          the exact Λ is (∫ G1 (wo·m)⁺ D dm = cos θo holds by construction).
//   F    = dielectric Fresnel with relative IOR `eta` if given, else 1.
//   Sampling: the specular lobe by the exact Blinn-Phong half-vector distribution
//   (cos θh = u1^{1/(s+2)}, φ = 2π u2, pdf_h = D(h) cos θh, pdf_wi = pdf_h / (4 wo·h));
//   the diffuse lobe by cosine; lobe probability ∝ mean(specular_reflectance) :
//   mean(diffuse_reflectance); pdf is the mixture.
//   Stability for huge exponents: cos^s θh is evaluated as exp(s/2 · log1p(−sin²θh)) with
//   sin²θh formed from the tangential components of the (unnormalised) half vector, and
//   the sampler uses sin²θh = −expm1(2 log(u1)/(s+2)); finite for s up to 1e6 and beyond.
//   Energy: the specular lobe has albedo ≤ 1 (D is normalised, G ≤ 1, F ≤ 1); the lobes
//   are simply added, so albedo ≤ 1 holds when specular_reflectance + diffuse_reflectance
//   ≤ 1 (as for Mitsuba's phong). Reciprocal.
//
// Parameters
//   name                  type           default  range / notes
//   exponent              texture|float  100      [0, 1e6] (values outside are clamped
//                                                 per lookup; a constant outside is an error)
//   specular_reflectance  texture        1        [0, 1]
//   diffuse_reflectance   texture        0        [0, 1]
//   eta                   float          —        > 0; absent = no Fresnel (F = 1)
#include <fmt/format.h>
#include <optional>
#include "bsdf/fresnel.h"
#include "bsdf/material.h"
#include "bsdf/microfacet.h"
#include "texture/texture.h"
#include "sampling/warp.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

constexpr float kMaxExponent = 1e6f;

class BlinnPhong final : public Material {
public:
    BlinnPhong(std::shared_ptr<Texture> exponent, std::shared_ptr<Texture> ks, std::shared_ptr<Texture> kd, float eta)
        : m_exponent(std::move(exponent)), m_ks(std::move(ks)), m_kd(std::move(kd)), m_eta(eta) {
        float s = m_ks->mean().average(), d = m_kd->mean().average();
        m_spec_weight = (s + d) > 0.f ? s / (s + d) : 1.f;
        if (!(d > 0.f)) m_spec_weight = 1.f;
        m_has_diffuse = d > 0.f;
        if (m_exponent->is_constant()) m_lambda.emplace(exponent_of_constant());
    }

    float exponent_of_constant() const { return clamp(m_exponent->mean().average(), 0.f, kMaxExponent); }

    uint32_t flags() const override {
        return BSDF_GlossyReflection | (m_has_diffuse ? BSDF_DiffuseReflection : 0u);
    }

    float exponent(const ShadingContext &ctx) const {
        float s = m_exponent->eval_float(ctx);
        return std::isfinite(s) ? clamp(s, 0.f, kMaxExponent) : 0.f;
    }

    /// log D(h) for the unnormalised half vector hu = wo + wi (z > 0).
    static double log_D(double s, const Vec3 &hu) {
        double t2 = double(hu.x) * hu.x + double(hu.y) * hu.y;
        double l2 = t2 + double(hu.z) * hu.z;
        double sin2 = t2 / l2;
        return std::log((s + 2.0) / (2.0 * 3.14159265358979323846)) + 0.5 * s * std::log1p(-std::min(sin2, 1.0));
    }

    /// Specular value f·cos and pdf of the specular sampler at (wo, wi).
    void spec_eval_pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi, float s, Spectrum *value,
                       float *pdf) const {
        Vec3 hu = wo + wi;
        if (!(hu.z > 0.f)) {
            if (value) *value = Spectrum(0.f);
            if (pdf) *pdf = 0.f;
            return;
        }
        Vec3 h = normalize(hu);
        double D = std::exp(log_D(s, hu));
        if (value) {
            // Height-correlated Smith G2 = 1/(1 + Λ(wo) + Λ(wi)) (both see h from the front:
            // wo·h = wi·h > 0 for a reflection pair in the upper hemisphere).
            double lo = m_lambda ? (*m_lambda)(wo.z) : blinnphong_lambda(s, wo.z);
            double li = m_lambda ? (*m_lambda)(wi.z) : blinnphong_lambda(s, wi.z);
            double G = (std::isfinite(lo) && std::isfinite(li)) ? 1.0 / (1.0 + lo + li) : 0.0;
            double F = m_eta > 0.f ? fresnel_dielectric_F(dot(wi, h), m_eta) : 1.0;
            double v = F * D * G / (4.0 * wo.z);
            *value = (std::isfinite(v) && v > 0.0) ? m_ks->eval(ctx) * float(v) : Spectrum(0.f);
        }
        if (pdf) {
            double dwh = dot(wo, h);
            double p = dwh > 0.0 ? D * h.z / (4.0 * dwh) : 0.0;
            *pdf = (std::isfinite(p) && p > 0.0) ? float(p) : 0.f;
        }
    }

    Spectrum eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        if (!(wo.z > 0.f) || !(wi.z > 0.f)) return Spectrum(0.f);
        Spectrum spec;
        spec_eval_pdf(ctx, wo, wi, exponent(ctx), &spec, nullptr);
        if (m_has_diffuse) spec += m_kd->eval(ctx) * (wi.z * InvPi);
        return spec;
    }

    float pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        if (!(wo.z > 0.f) || !(wi.z > 0.f)) return 0.f;
        float ps;
        spec_eval_pdf(ctx, wo, wi, exponent(ctx), nullptr, &ps);
        return m_spec_weight * ps + (1.f - m_spec_weight) * wi.z * InvPi;
    }

    bool sample(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, BSDFSample &out) const override {
        if (!(wo.z > 0.f)) return false;
        float s = exponent(ctx);
        Vec3 wi;
        if (u_lobe < m_spec_weight) {
            // cos θh = u^{1/(s+2)}; sin²θh = 1 − u^{2/(s+2)} without cancellation.
            double lu = std::log(std::max(double(u.x), 1e-300)) / (double(s) + 2.0);
            double cos_h = std::exp(lu), sin_h = std::sqrt(std::max(0.0, -std::expm1(2.0 * lu)));
            double phi = 2.0 * 3.14159265358979323846 * u.y;
            Vec3 h(float(sin_h * std::cos(phi)), float(sin_h * std::sin(phi)), float(cos_h));
            if (!(dot(wo, h) > 0.f)) return false;
            wi = normalize(reflect(wo, h));
            out.flags = BSDF_GlossyReflection;
        } else {
            wi = square_to_cosine_hemisphere(u);
            out.flags = BSDF_DiffuseReflection;
        }
        if (!(wi.z > 0.f)) return false;
        Spectrum spec;
        float ps;
        spec_eval_pdf(ctx, wo, wi, s, &spec, &ps);
        float p = m_spec_weight * ps + (1.f - m_spec_weight) * wi.z * InvPi;
        if (!(p > 0.f) || !std::isfinite(p)) return false;
        if (m_has_diffuse) spec += m_kd->eval(ctx) * (wi.z * InvPi);
        out.wi = wi;
        out.pdf = p;
        out.eta = 1.f;
        out.weight = spec / p;
        return out.weight.is_finite();
    }

    Spectrum albedo_hint(const ShadingContext &ctx) const override { return m_ks->eval(ctx) + m_kd->eval(ctx); }

    std::string to_string() const override {
        return fmt::format("blinnphong[exponent={}, eta={}]", m_exponent->to_string(), m_eta > 0.f ? m_eta : 0.f);
    }

private:
    std::shared_ptr<Texture> m_exponent, m_ks, m_kd;
    std::optional<BlinnPhongLambdaTable> m_lambda;  ///< Λ for a constant exponent
    float m_eta;  ///< <= 0: no Fresnel
    float m_spec_weight;
    bool m_has_diffuse;
};

std::shared_ptr<Material> make_blinnphong(const Properties &p) {
    auto exponent = p.get_texture("exponent", Spectrum(100.f));
    if (exponent->is_constant()) {
        float s = exponent->mean().average();
        if (!(s >= 0.f && s <= kMaxExponent))
            p.fail("exponent", fmt::format("exponent must be in [0, {:g}], got {}", kMaxExponent, s));
    }
    auto ks = p.get_texture("specular_reflectance", Spectrum(1.f));
    auto kd = p.get_texture("diffuse_reflectance", Spectrum(0.f));
    float eta = -1.f;
    if (p.has("eta")) {
        eta = p.get_float("eta");
        if (!(eta > 0.f)) p.fail("eta", fmt::format("relative index of refraction must be > 0, got {}", eta));
    }
    return std::make_shared<BlinnPhong>(exponent, ks, kd, eta);
}

MESO_REGISTER_MATERIAL("blinnphong", "normalised Blinn-Phong microfacet BRDF (paper 003) + optional Lambert",
                       [](const Properties &p) -> std::shared_ptr<Material> { return make_blinnphong(p); });

}  // namespace
}  // namespace meso
