// `plastic`: a diffuse base under a smooth or rough dielectric coat (Mitsuba's
// "plastic"/"roughplastic", after Weidlich & Wilkie 2007 and Mitsuba 3 roughplastic.cpp).
//
// Model
//   f = f_spec + f_diff
//   f_spec: the coat's specular reflection. Smooth coat (alpha < 1e-4): a delta lobe of
//     weight F(cos θo) · specular_reflectance. Rough coat: Walter et al. 2007 microfacet
//     reflection F(wi·h) D(h) G / (4 cos θo cos θi) · specular_reflectance (isotropic GGX or
//     Beckmann, height-correlated Smith G, see bsdf/microfacet.h).
//   f_diff = T(wo) T(wi) / η² · ρ' / π, where
//     T(μ)  = energy the coat lets through at cos θ = μ: 1 − F(μ, η) for a smooth coat;
//             1 − E_spec(μ) for a rough one, E_spec the coat's directional albedo
//             (specular_reflectance = 1), tabulated once per (distribution, alpha, η) at
//             64 cosines by midpoint quadrature of F·G2/G1 over visible normals, linearly
//             interpolated (Mitsuba 3's m_external_transmittance).
//     ρ'    = ρ / (1 − R_int)        (nonlinear = false, Mitsuba's default), or
//             ρ / (1 − ρ R_int)      (nonlinear = true: the diffuse base's own colour
//                                     saturates through repeated internal bounces);
//     R_int = internal diffuse reflectance of the coat, fixed by energy balance from the
//             cosine-weighted external one:  1 − R_int = (1 − R_ext)/η²,
//             R_ext = 2∫ (1 − T(μ)) μ dμ. For a smooth coat that is the classical identity
//             between the diffuse Fresnel reflectances (R_ext integrated numerically by
//             fresnel_diffuse_reflectance); for a rough one it is evaluated on the same
//             table the BRDF uses, which makes the diffuse albedo exactly T(wo) ρ (linear)
//             or T(wo) ρ(1−R_int)/(1−ρ R_int) (nonlinear).
//   Energy: albedo(wo) = E_spec(wo) + T(wo)·(≤ 1) ≤ 1 for ρ, specular_reflectance in
//   [0, 1]; with ρ = 1 and nonlinear (or ρ = 1 linear) the material is lossless up to the
//   rough coat's single-scattering loss, which T already accounts for (albedo ≈ 1).
//   Sampling (Mitsuba): specular with probability p = (1−T(wo)) w / ((1−T(wo)) w + T(wo)(1−w)),
//   w = mean(specular_reflectance) / (mean(specular_reflectance) + mean(diffuse_reflectance)),
//   else cosine-weighted diffuse; pdf is the mixture (the delta lobe contributes p as a
//   discrete probability). Reciprocal.
//
// Parameters (Mitsuba 3 names)
//   name                 type          default    range / notes
//   diffuse_reflectance  texture       0.5        [0, 1]
//   specular_reflectance texture       1          [0, 1]
//   int_ior              float|string  1.49       > 0 (polypropylene) or a preset name
//   ext_ior              float|string  1.000277   > 0 (air)
//   distribution         string        "ggx"      "ggx" | "beckmann"
//   alpha                float         0          [0, 1e3], isotropic; < 1e-4 = smooth coat
//   sample_visible       bool          true       visible-normal sampling of the coat
//   nonlinear            bool          false      see ρ' above
#include <fmt/format.h>
#include <map>
#include <mutex>
#include <optional>
#include <tuple>
#include <vector>
#include "bsdf/fresnel.h"
#include "bsdf/material.h"
#include "bsdf/microfacet.h"
#include "texture/texture.h"
#include "core/properties.h"
#include "core/registry.h"
#include "sampling/warp.h"

namespace meso {
namespace {

constexpr int kTableRes = 64;   // cosines in the transmittance table
constexpr int kTableQuad = 48;  // midpoint quadrature points per axis for each entry

/// Directional albedo of the rough coat (specular_reflectance 1) at cos θo = mu:
/// E[F(wo·m) G2/G1(wo)] over visible normals, midpoint rule on the sample square.
double rough_coat_albedo(const MicrofacetDistribution &vis, float eta, double mu) {
    Vec3 wo(float(std::sqrt(std::max(0.0, 1.0 - mu * mu))), 0.f, float(mu));
    double sum = 0.0;
    for (int i = 0; i < kTableQuad; ++i)
        for (int j = 0; j < kTableQuad; ++j) {
            Vec2 u(float((i + 0.5) / kTableQuad), float((j + 0.5) / kTableQuad));
            float pm;
            Vec3 m = vis.sample(wo, u, &pm);
            if (!(pm > 0.f)) continue;
            float dwm = dot(wo, m);
            if (!(dwm > 0.f)) continue;
            Vec3 wi = normalize(reflect(wo, m));
            if (!(wi.z > 0.f)) continue;
            double g = double(vis.G(wo, wi, m)) / vis.G1(wo, m);
            if (std::isfinite(g)) sum += fresnel_dielectric_F(dwm, eta) * g;
        }
    return sum / (double(kTableQuad) * kTableQuad);
}

/// T(mu) at mu_i = i/(N-1), cached per (distribution, alpha, eta): building one costs a
/// few ms (Beckmann's visible-normal sampler inverts a CDF).
std::shared_ptr<const std::vector<float>> rough_transmittance_table(MicrofacetType type, float alpha, float eta) {
    static std::mutex mutex;
    static std::map<std::tuple<int, float, float>, std::shared_ptr<const std::vector<float>>> cache;
    auto key = std::make_tuple(int(type), alpha, eta);
    {
        std::lock_guard<std::mutex> lock(mutex);
        auto it = cache.find(key);
        if (it != cache.end()) return it->second;
    }
    MicrofacetDistribution vis(type, alpha, alpha, true);
    auto table = std::make_shared<std::vector<float>>(kTableRes);
    for (int i = 0; i < kTableRes; ++i) {
        double mu = std::max(double(i) / (kTableRes - 1), 1e-4);  // the mu = 0 node: its limit
        (*table)[i] = float(clamp(1.0 - rough_coat_albedo(vis, eta, mu), 0.0, 1.0));
    }
    std::lock_guard<std::mutex> lock(mutex);
    cache[key] = table;
    return table;
}

class Plastic final : public Material {
public:
    Plastic(std::shared_ptr<Texture> diffuse, std::shared_ptr<Texture> specular, float eta,
            std::optional<MicrofacetDistribution> dist, bool nonlinear)
        : m_diffuse(std::move(diffuse)), m_specular(std::move(specular)), m_eta(eta), m_dist(std::move(dist)),
          m_nonlinear(nonlinear) {
        m_inv_eta2 = 1.f / (eta * eta);
        double r_ext;
        if (m_dist) {
            m_table = rough_transmittance_table(m_dist->type(), m_dist->alpha_u(), eta);
            // R_ext = 2 ∫ (1 − T_lerp(mu)) mu dmu, exact for the piecewise-linear table.
            const auto &t = *m_table;
            double h = 1.0 / (kTableRes - 1), acc = 0.0;
            for (int i = 0; i + 1 < kTableRes; ++i) {
                double a = i * h, b = (i + 1) * h, ga = 1.0 - t[i], gb = 1.0 - t[i + 1];
                acc += h * (ga * (2 * a + b) + gb * (a + 2 * b)) / 6.0;
            }
            r_ext = 2.0 * acc;
        } else {
            r_ext = fresnel_diffuse_reflectance(eta);
        }
        m_r_int = float(1.0 - (1.0 - r_ext) / (double(eta) * eta));
        float s = m_specular->mean().average(), d = m_diffuse->mean().average();
        m_spec_weight = (s + d) > 0.f ? s / (s + d) : 0.5f;
    }

    uint32_t flags() const override {
        return BSDF_DiffuseReflection | (m_dist ? BSDF_GlossyReflection : BSDF_DeltaReflection);
    }

    /// Energy through the coat at cos θ = mu (see the header comment).
    float transmittance(float mu) const {
        if (!m_dist) return 1.f - fresnel_dielectric_F(mu, m_eta);
        float x = clamp(mu, 0.f, 1.f) * (kTableRes - 1);
        int i = std::min(int(x), kTableRes - 2);
        float f = x - i;
        return (1.f - f) * (*m_table)[i] + f * (*m_table)[i + 1];
    }

    float spec_probability(float cos_o) const {
        float r = 1.f - transmittance(cos_o);
        float ps = r * m_spec_weight, pd = (1.f - r) * (1.f - m_spec_weight);
        return (ps + pd) > 0.f ? ps / (ps + pd) : 0.5f;
    }

    Spectrum diffuse_value(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const {
        Spectrum rho = m_diffuse->eval(ctx), d;
        for (int c = 0; c < 3; ++c) d[c] = rho[c] / (1.f - (m_nonlinear ? rho[c] : 1.f) * m_r_int);
        return d * (transmittance(wo.z) * transmittance(wi.z) * m_inv_eta2 * InvPi * wi.z);
    }

    Spectrum spec_value(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const {
        Vec3 h = normalize(wo + wi);
        float D = m_dist->D(h);
        if (D == 0.f) return Spectrum(0.f);
        double v = double(fresnel_dielectric_F(dot(wi, h), m_eta)) * D * m_dist->G(wo, wi, h) / (4.0 * wo.z);
        if (!std::isfinite(v) || v <= 0.0) return Spectrum(0.f);
        return m_specular->eval(ctx) * float(v);
    }

    float spec_pdf(const Vec3 &wo, const Vec3 &wi) const {
        Vec3 h = normalize(wo + wi);
        float dwh = dot(wo, h);
        if (!(dwh > 0.f)) return 0.f;
        double p = double(m_dist->pdf(wo, h)) / (4.0 * dwh);
        return std::isfinite(p) ? float(p) : 0.f;
    }

    Spectrum eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        if (!(wo.z > 0.f) || !(wi.z > 0.f)) return Spectrum(0.f);
        Spectrum v = diffuse_value(ctx, wo, wi);
        if (m_dist) v += spec_value(ctx, wo, wi);
        return v;
    }

    float pdf(const ShadingContext &, const Vec3 &wo, const Vec3 &wi) const override {
        if (!(wo.z > 0.f) || !(wi.z > 0.f)) return 0.f;
        float ps = spec_probability(wo.z);
        float p = (1.f - ps) * wi.z * InvPi;
        if (m_dist) p += ps * spec_pdf(wo, wi);
        return p;
    }

    bool sample(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, BSDFSample &out) const override {
        if (!(wo.z > 0.f)) return false;
        float ps = spec_probability(wo.z);
        out.eta = 1.f;
        if (!m_dist) {
            if (u_lobe < ps) {
                out.wi = reflect_local(wo);
                out.pdf = ps;
                out.flags = BSDF_DeltaReflection;
                out.weight = m_specular->eval(ctx) * (fresnel_dielectric_F(wo.z, m_eta) / ps);
                return true;
            }
            Vec3 wi = square_to_cosine_hemisphere(u);
            if (!(wi.z > 0.f)) return false;
            out.wi = wi;
            out.pdf = (1.f - ps) * wi.z * InvPi;
            out.flags = BSDF_DiffuseReflection;
            out.weight = diffuse_value(ctx, wo, wi) / out.pdf;
            return out.pdf > 0.f;
        }
        Vec3 wi;
        if (!sample_glossy_or_diffuse(*m_dist, wo, u_lobe, ps, u, wi, out.flags)) return false;
        out.wi = wi;
        out.pdf = pdf(ctx, wo, wi);
        if (!(out.pdf > 0.f)) return false;
        out.weight = eval(ctx, wo, wi) / out.pdf;
        return out.weight.is_finite();
    }

    Spectrum albedo_hint(const ShadingContext &ctx) const override { return m_diffuse->eval(ctx); }

    bool uses_footprint() const override { return any_varies({m_diffuse.get(), m_specular.get()}); }
    std::string to_string() const override {
        return fmt::format("plastic[eta={}, R_int={}, {}{}]", m_eta, m_r_int, m_dist ? m_dist->to_string() : "smooth",
                           m_nonlinear ? ", nonlinear" : "");
    }

    float internal_reflectance() const { return m_r_int; }

private:
    std::shared_ptr<Texture> m_diffuse, m_specular;
    float m_eta, m_inv_eta2, m_r_int, m_spec_weight;
    std::optional<MicrofacetDistribution> m_dist;
    std::shared_ptr<const std::vector<float>> m_table;
    bool m_nonlinear;
};

std::shared_ptr<Material> make_plastic(const Properties &p) {
    auto diffuse = p.get_texture("diffuse_reflectance", Spectrum(0.5f));
    auto specular = p.get_texture("specular_reflectance", Spectrum(1.f));
    float int_ior = ior_from_properties(p, "int_ior", 1.49f);
    float ext_ior = ior_from_properties(p, "ext_ior", 1.000277f);
    auto dist = microfacet_from_properties(p, false, 0.f);
    bool nonlinear = p.get_bool("nonlinear", false);
    return std::make_shared<Plastic>(diffuse, specular, int_ior / ext_ior, dist, nonlinear);
}

MESO_REGISTER_MATERIAL("plastic", "diffuse base under a smooth or rough dielectric coat (Mitsuba roughplastic)",
                       [](const Properties &p) -> std::shared_ptr<Material> { return make_plastic(p); });

}  // namespace
}  // namespace meso
