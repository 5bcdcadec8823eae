// `dielectric`: the interface between two dielectrics (glass, water), smooth or rough.
//
// Model
//   eta = int_ior / ext_ior; the normal (+z) points to the exterior. wo.z < 0 means the
//   viewer is inside; then the relative IOR seen by the ray is 1/eta (total internal
//   reflection included).
//   smooth (alpha < 1e-4): delta reflection with probability F(cos θo) and delta refraction
//     with probability 1 − F (Snell); weights specular_reflectance and
//     specular_transmission · (η_o/η_i)², see "radiance" below.
//   rough: Walter et al. 2007, "Microfacet models for refraction through rough surfaces":
//     reflection   f = F(wo·h) D(h) G / (4 |cos θo| |cos θi|)         (eq. 20)
//     transmission f = (1−F) D(h) G |wo·h||wi·h| / (|cos θo||cos θi| (wo·h + η wi·h)²)
//                  (eq. 21 with the η_t² factor removed, see below), where
//     η = η(wi side)/η(wo side) and h = ±normalize(wo + η wi) (generalised half vector,
//     eq. 16) oriented to +z; the Jacobian of refraction is
//     dω_h/dω_i = η² |wi·h| / (wo·h + η wi·h)²  (eq. 17).
//     Sampling: a microfacet normal from the visible (or full) NDF of the distribution as
//     seen from wo (mirrored into the upper hemisphere), then reflection with probability
//     F(wo·m), refraction otherwise; sample() fails if the result lands on the wrong side.
//     G is the height-correlated Smith term (reflection: 1/(1+Λo+Λi); transmission:
//     B(1+Λo, 1+Λi), Heitz 2014 eq. 99/101).
//   Rough with eta = 1 is a null interface and behaves as the smooth case.
//
// Radiance convention: meso transports radiance from the camera. Radiance crossing an
// interface is scaled by (η_wo side / η_wi side)² (L/η² is invariant), so transmission
// carries that factor — it is 1/η² for a camera outside looking into glass and η² from
// the inside (albedo > 1 there is correct, flux is conserved). This is Mitsuba 3's
// TransportMode::Radiance. Consequently f(wo,wi)/η_wo² = f(wi,wo)/η_wi² (generalised
// reciprocity) but not f(wo,wi) = f(wi,wo): is_reciprocal() is false; the test battery
// checks the generalised relation and plain reciprocity of the reflection lobe.
// BSDFSample::eta is η_wi side / η_wo side for refraction (1 for reflection).
//
// Parameters (Mitsuba 3 names)
//   name                   type          default    range / notes
//   int_ior                float|string  1.5046     > 0 or a name ("bk7", "water", ...)
//   ext_ior                float|string  1.000277   > 0 or a name ("air", "vacuum", ...)
//   eta                    float         —          > 0, int/ext directly (excludes the above)
//   specular_reflectance   texture       1          [0, 1]
//   specular_transmission  texture       1          [0, 1]
//   distribution           string        "ggx"      "ggx" | "beckmann"
//   alpha                  float         0          [0, 1e3]; < 1e-4 = smooth
//   alpha_u, alpha_v       float         —          anisotropic alternative to alpha
//   sample_visible         bool          true       visible-normal sampling
#include <fmt/format.h>
#include <optional>
#include "bsdf/fresnel.h"
#include "bsdf/material.h"
#include "bsdf/microfacet.h"
#include "texture/texture.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

class Dielectric final : public Material {
public:
    Dielectric(float eta, std::optional<MicrofacetDistribution> dist, std::shared_ptr<Texture> r,
               std::shared_ptr<Texture> t)
        : m_eta(eta), m_dist(std::move(dist)), m_refl(std::move(r)), m_trans(std::move(t)) {}

    uint32_t flags() const override {
        return m_dist ? (BSDF_GlossyReflection | BSDF_GlossyTransmission) : (BSDF_DeltaReflection | BSDF_DeltaTransmission);
    }
    bool is_reciprocal() const override { return false; }

    /// Generalised half vector of (wo, wi) oriented to +z, with the relative IOR of the
    /// wi side; false when the configuration is impossible for a microfacet.
    bool half_vector(const Vec3 &wo, const Vec3 &wi, Vec3 &m, float &eta, bool &is_reflect) const {
        float co = wo.z, ci = wi.z;
        if (co == 0.f || ci == 0.f) return false;
        is_reflect = co * ci > 0.f;
        eta = co > 0.f ? m_eta : 1.f / m_eta;
        m = normalize(wo + wi * (is_reflect ? 1.f : eta));
        if (m.z < 0.f) m = -m;
        if (!(m.z > 0.f)) return false;
        // Both directions must see the microfacet from their own side.
        return dot(wo, m) * co > 0.f && dot(wi, m) * ci > 0.f;
    }

    /// f·|cos θi| and the sampling pdf at (wo, wi) for the rough interface (either may be null).
    void eval_pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi, Spectrum *value, float *pdf) const {
        if (value) *value = Spectrum(0.f);
        if (pdf) *pdf = 0.f;
        Vec3 m;
        float eta;
        bool is_reflect;
        if (!m_dist || !half_vector(wo, wi, m, eta, is_reflect)) return;
        double D = m_dist->D(m);
        if (D == 0.0) return;
        double dwo = dot(wo, m), dwi = dot(wi, m);
        // For a refraction pair F(wo·m) = F(wi·m); take the better-conditioned cosine (a
        // microfacet seen at grazing incidence from one side has a tiny cosine whose float
        // rounding would dominate 1 − F).
        double F = fresnel_dielectric_F(float(std::abs(dwo) >= std::abs(dwi) ? dwo : dwi), m_eta);
        double denom = dwo + eta * dwi;
        if (value) {
            double G = m_dist->G(wo, wi, m), v;
            if (is_reflect) v = F * D * G / (4.0 * std::abs(wo.z));
            else v = (1.0 - F) * D * G * std::abs(dwo * dwi) / (std::abs(wo.z) * denom * denom);
            if (std::isfinite(v) && v > 0.0) *value = (is_reflect ? m_refl : m_trans)->eval(ctx) * float(v);
        }
        if (pdf) {
            double pm = m_dist->pdf(wo.z > 0.f ? wo : -wo, m), p;
            // dω_h/dω_i: reflection 1/(4|wi·h|) = 1/(4|wo·h|) — wo·h is used so that it
            // cancels the wo·h of the visible-normal pdf even when h = normalize(wo + wi)
            // carries the cancellation error of grazing reflection; refraction
            // η²|wi·h| / (wo·h + η wi·h)² (Walter 2007 eq. 17).
            if (is_reflect) p = pm * F / (4.0 * std::abs(dwo));
            else p = pm * (1.0 - F) * eta * eta * std::abs(dwi) / (denom * denom);
            if (std::isfinite(p) && p > 0.0) *pdf = float(p);
        }
    }

    Spectrum eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        Spectrum v;
        eval_pdf(ctx, wo, wi, &v, nullptr);
        return v;
    }

    float pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        float p;
        eval_pdf(ctx, wo, wi, nullptr, &p);
        return p;
    }

    bool sample(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, BSDFSample &out) const override {
        float co = wo.z;
        if (co == 0.f || !std::isfinite(co)) return false;
        if (!m_dist) {
            FresnelDielectric fr = fresnel_dielectric(co, m_eta);
            if (u_lobe < fr.F) {
                out.wi = reflect_local(wo);
                out.pdf = fr.F;
                out.eta = 1.f;
                out.flags = BSDF_DeltaReflection;
                out.weight = m_refl->eval(ctx);
            } else {
                out.wi = normalize(refract_local(wo, fr.cos_theta_t, fr.eta_ti));
                out.pdf = 1.f - fr.F;
                out.eta = fr.eta_it;
                out.flags = BSDF_DeltaTransmission;
                out.weight = m_trans->eval(ctx) * (fr.eta_ti * fr.eta_ti);
            }
            return out.pdf > 0.f;
        }
        Vec3 wo_up = co > 0.f ? wo : -wo;
        float pm;
        Vec3 m = m_dist->sample(wo_up, u, &pm);
        if (!(pm > 0.f)) return false;
        float dwo = dot(wo, m);  // same sign as co
        if (!(dwo * co > 0.f)) return false;
        FresnelDielectric fr = fresnel_dielectric(dwo, m_eta);
        Vec3 wi;
        bool is_reflect = u_lobe < fr.F;
        if (is_reflect) {
            wi = normalize(reflect(wo, m));
            if (!(wi.z * co > 0.f)) return false;
        } else {
            wi = normalize(refract(wo, m, fr.cos_theta_t, fr.eta_ti));
            if (!(wi.z * co < 0.f)) return false;
        }
        // Value and pdf are re-evaluated at the returned direction through the same code as
        // eval()/pdf(), so that weight = eval/pdf and pdf = pdf(wi) hold to the last bit.
        // (Analytically weight = G2/G1(wo) [· (η_i/η_t)² for refraction] with visible
        // normals; near the critical angle the float direction wi is ill-conditioned and
        // the microfacet reconstructed from it differs from m by ~1e-3, so the analytic
        // form would disagree with pdf(wi) there.)
        Spectrum value;
        float p;
        eval_pdf(ctx, wo, wi, &value, &p);
        if (!(p > 0.f)) return false;
        out.wi = wi;
        out.pdf = p;
        out.eta = is_reflect ? 1.f : fr.eta_it;
        out.flags = is_reflect ? BSDF_GlossyReflection : BSDF_GlossyTransmission;
        out.weight = value / p;
        return out.weight.is_finite();
    }

    Spectrum albedo_hint(const ShadingContext &ctx) const override { return m_trans->eval(ctx); }

    bool uses_footprint() const override { return any_varies({m_refl.get(), m_trans.get()}); }
    std::string to_string() const override {
        return fmt::format("dielectric[eta={}, {}]", m_eta, m_dist ? m_dist->to_string() : "smooth");
    }

private:
    float m_eta;
    std::optional<MicrofacetDistribution> m_dist;
    std::shared_ptr<Texture> m_refl, m_trans;
};

std::shared_ptr<Material> make_dielectric(const Properties &p) {
    float eta;
    if (p.has("eta")) {
        if (p.has("int_ior")) p.fail("int_ior", "give either \"eta\" or \"int_ior\"/\"ext_ior\", not both");
        if (p.has("ext_ior")) p.fail("ext_ior", "give either \"eta\" or \"int_ior\"/\"ext_ior\", not both");
        eta = p.get_float("eta");
        if (!(eta > 0.f)) p.fail("eta", fmt::format("relative index of refraction must be > 0, got {}", eta));
    } else {
        float int_ior = ior_from_properties(p, "int_ior", 1.5046f);
        float ext_ior = ior_from_properties(p, "ext_ior", 1.000277f);
        eta = int_ior / ext_ior;
    }
    auto dist = microfacet_from_properties(p, true, 0.f);
    if (eta == 1.f) dist.reset();  // index matched: a null interface, smooth pass-through
    auto r = p.get_texture("specular_reflectance", Spectrum(1.f));
    auto t = p.get_texture("specular_transmission", Spectrum(1.f));
    return std::make_shared<Dielectric>(eta, dist, r, t);
}

MESO_REGISTER_MATERIAL("dielectric", "glass-like interface: smooth or rough (Walter 2007) reflection + refraction",
                       [](const Properties &p) -> std::shared_ptr<Material> { return make_dielectric(p); });

}  // namespace
}  // namespace meso
