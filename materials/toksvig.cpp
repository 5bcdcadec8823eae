// `toksvig`: Toksvig mapping (Toksvig 2004, "Mipmapping normal maps"; paper 003 part 3,
// "Direct variance estimation"): the length of the filtered average of unit normals N_a
// estimates their spread, which widens a Blinn-Phong lobe:
//   sigma^2 = (1 - |N_a|) / |N_a|,      s_hat = s / (1 + sigma^2 s)         (paper 003)
// and the surface is shaded with the normalised Blinn-Phong microfacet BRDF of power s_hat
// (the math of materials/blinnphong.cpp, bsdf/microfacet.h) around the mean normal
// n_a = N_a / |N_a| (normal mapping).
//
// Model (local frame: z = the macronormal)
//   wo', wi' = wo, wi in the frame (s', t', n_a), s' = s made orthogonal to n_a
//   f' cos(theta_i') = F(wi' . h) D(h) / (4 wo'.z (1 + Lambda(wo') + Lambda(wi'))) * specular_reflectance
//   D(h) = (s_hat + 2)/(2 pi) cos^s_hat(theta_h) (w.r.t. n_a), Lambda = the exact Smith Lambda
//   of this D (blinnphong_lambda; tabulated when N_a is constant), F = dielectric Fresnel
//   with `eta` if given, else 1.
//   eval returns f' cos(theta_i') with the cosine w.r.t. n_a (as the `normalmap` wrapper
//   does), so the lobe's albedo <= 1 in the local frame; 0 where wo or wi is below the
//   macrosurface (z <= 0) or below the perturbed one (wo'.z <= 0, wi'.z <= 0).
//   Not reciprocal unless n_a = z (the cosine is taken w.r.t. n_a, so f = eval / cos(theta_i)
//   is not symmetric); a constant N_a along z of length 1 is exactly `blinnphong` (tested).
//   |N_a| is clamped to <= 1 (round-off); |N_a| = 0 gives s_hat = 0 around the macronormal.
//   Sampling: half vectors from D(h) cos(theta_h) in the perturbed frame, reflected;
//   pdf = D(h) h'.z / (4 wo' . h); fails where the value is 0 by construction.
//
// Parameters
//   name                  type          default    notes
//   exponent              float         100        Blinn-Phong power s in [0, 1e7]
//   specular_reflectance  texture       1          [0, 1]
//   eta                   float         -          > 0: dielectric Fresnel; absent: F = 1
//   normals               string        -          tangent-space normal map (see texture/normal_source.h)
//   tiling                number|[u,v]  1          repeats of the normal map
//   heightmap             object        -          displacement-style block: per-cell average unit normals
//   uv_length             [Lu, Lv]      [1, 1]     world length of one unit of u, v (heightmap only)
//   filter                string        trilinear  trilinear | ewa | none
//   max_anisotropy        float         8          ewa only
//   average_normal        [x, y, z]     [0, 0, 1]  constant N_a (length in (0, 1], z > 0), not with a map
#include <cmath>
#include <fmt/format.h>
#include <memory>
#include "bsdf/fresnel.h"
#include "bsdf/material.h"
#include "bsdf/microfacet.h"
#include "texture/texture.h"
#include "core/properties.h"
#include "core/registry.h"
#include "texture/normal_source.h"

namespace meso {
namespace {

constexpr float kMaxExponent = 1e7f;
constexpr double kPi = 3.14159265358979323846;

/// sigma^2 = (1 - |N_a|)/|N_a| and s_hat = s / (1 + sigma^2 s) (paper 003), in the form
/// s |N_a| / (|N_a| + (1 - |N_a|) s), finite for |N_a| -> 0 and s -> inf.
double toksvig_exponent(double s, double len) {
    if (!(len > 0.0)) return 0.0;
    len = std::min(len, 1.0);
    const double v = s * len / (len + (1.0 - len) * s);
    return std::isfinite(v) ? v : 0.0;
}

class Toksvig final : public Material {
public:
    Toksvig(NormalSource source, float s, std::shared_ptr<Texture> ks, float eta)
        : m_source(std::move(source)), m_s(s), m_ks(std::move(ks)), m_eta(eta) {
        if (m_source.is_constant()) {
            m_const = std::make_unique<Lobe>(lobe_of(m_source.eval(ShadingContext{})));
            m_table = std::make_unique<BlinnPhongLambdaTable>(m_const->s_hat);
        }
    }

    uint32_t flags() const override { return BSDF_GlossyReflection; }
    bool is_reciprocal() const override {
        return m_const && m_const->frame.n.x == 0.f && m_const->frame.n.y == 0.f;
    }

    Spectrum eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        if (!(wo.z > 0.f) || !(wi.z > 0.f)) return Spectrum(0.f);
        const Lobe L = lobe(ctx);
        double v;
        value_pdf(L, L.frame.to_local(wo), L.frame.to_local(wi), &v, nullptr);
        return v > 0.0 ? m_ks->eval(ctx) * float(v) : Spectrum(0.f);
    }

    float pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        if (!(wo.z > 0.f) || !(wi.z > 0.f)) return 0.f;
        const Lobe L = lobe(ctx);
        double p;
        value_pdf(L, L.frame.to_local(wo), L.frame.to_local(wi), nullptr, &p);
        return float(p);
    }

    bool sample(const ShadingContext &ctx, const Vec3 &wo, float, Vec2 u, BSDFSample &out) const override {
        if (!(wo.z > 0.f)) return false;
        const Lobe L = lobe(ctx);
        const Vec3 wop = L.frame.to_local(wo);
        if (!(wop.z > 0.f)) return false;
        // cos(theta_h) = u^(1/(s+2)); sin^2 = 1 - u^(2/(s+2)) without cancellation (blinnphong.cpp).
        const double lu = std::log(std::max(double(u.x), 1e-300)) / (L.s_hat + 2.0);
        const double cos_h = std::exp(lu), sin_h = std::sqrt(std::max(0.0, -std::expm1(2.0 * lu)));
        const double phi = 2.0 * kPi * u.y;
        const Vec3 h(float(sin_h * std::cos(phi)), float(sin_h * std::sin(phi)), float(cos_h));
        if (!(dot(wop, h) > 0.f)) return false;
        const Vec3 wip = normalize(reflect(wop, h));
        if (!(wip.z > 0.f)) return false;
        const Vec3 wi = normalize(L.frame.to_world(wip));
        if (!(wi.z > 0.f) || !is_finite(wi)) return false;
        // Value and pdf exactly as eval() and pdf() compute them at wi.
        double v, p;
        value_pdf(L, wop, L.frame.to_local(wi), &v, &p);
        if (!(p > 0.0) || !(float(p) > 0.f)) return false;
        out.wi = wi;
        out.pdf = float(p);
        out.eta = 1.f;
        out.flags = BSDF_GlossyReflection;
        out.weight = m_ks->eval(ctx) * float(v / double(out.pdf));
        return out.weight.is_finite();
    }

    Spectrum albedo_hint(const ShadingContext &ctx) const override { return m_ks->eval(ctx); }

    std::string to_string() const override {
        return fmt::format("toksvig[exponent={}, {}, eta={}]", m_s, m_source.to_string(), m_eta > 0.f ? m_eta : 0.f);
    }

private:
    struct Lobe {
        Frame frame;       ///< (s', t', n_a) in local coordinates
        double s_hat = 0;  ///< Toksvig-adjusted power
    };

    Lobe lobe_of(Vec3 na) const {
        Lobe L;
        const double len = std::sqrt(double(na.x) * na.x + double(na.y) * na.y + double(na.z) * na.z);
        if (!(len > 1e-30) || !std::isfinite(len)) {
            L.s_hat = 0.0;  // no average direction at all: the widest lobe around the macronormal
            return L;
        }
        L.frame = perturbed_frame(Vec3(float(na.x / len), float(na.y / len), float(na.z / len)));
        L.s_hat = toksvig_exponent(m_s, len);
        return L;
    }
    Lobe lobe(const ShadingContext &ctx) const { return m_const ? *m_const : lobe_of(m_source.eval(ctx)); }

    double lambda(const Lobe &L, double cos_theta) const {
        return m_table ? (*m_table)(cos_theta) : blinnphong_lambda(L.s_hat, cos_theta);
    }

    /// f' cos(theta_i') (without specular_reflectance) and the sampling density, directions
    /// in the perturbed frame.
    void value_pdf(const Lobe &L, const Vec3 &wo, const Vec3 &wi, double *value, double *pdf) const {
        if (value) *value = 0.0;
        if (pdf) *pdf = 0.0;
        if (!(wo.z > 0.f) || !(wi.z > 0.f)) return;
        const Vec3 hu = wo + wi;
        const Vec3 h = normalize(hu);
        // log D for the unnormalised half vector (blinnphong.cpp: stable for huge powers).
        const double t2 = double(hu.x) * hu.x + double(hu.y) * hu.y, l2 = t2 + double(hu.z) * hu.z;
        const double sin2 = std::min(t2 / l2, 1.0);
        const double D = std::exp(std::log((L.s_hat + 2.0) / (2.0 * kPi)) + 0.5 * L.s_hat * std::log1p(-sin2));
        if (value) {
            const double lo = lambda(L, wo.z), li = lambda(L, wi.z);
            const double G = (std::isfinite(lo) && std::isfinite(li)) ? 1.0 / (1.0 + lo + li) : 0.0;
            const double F = m_eta > 0.f ? fresnel_dielectric_F(dot(wi, h), m_eta) : 1.0;
            const double v = F * D * G / (4.0 * wo.z);
            *value = (std::isfinite(v) && v > 0.0) ? v : 0.0;
        }
        if (pdf) {
            const double dwh = dot(wo, h);
            const double p = dwh > 0.0 ? D * h.z / (4.0 * dwh) : 0.0;
            *pdf = (std::isfinite(p) && p > 0.0) ? p : 0.0;
        }
    }

    NormalSource m_source;
    float m_s;
    std::shared_ptr<Texture> m_ks;
    float m_eta;  ///< <= 0: no Fresnel
    std::unique_ptr<Lobe> m_const;
    std::unique_ptr<BlinnPhongLambdaTable> m_table;  ///< Lambda for a constant s_hat
};

std::shared_ptr<Material> make_toksvig(const Properties &p) {
    const float s = p.get_float("exponent", 100.f);
    if (!(s >= 0.f && s <= kMaxExponent))
        p.fail("exponent", fmt::format("exponent must be in [0, {:g}], got {}", kMaxExponent, s));
    auto ks = p.get_texture("specular_reflectance", Spectrum(1.f));
    float eta = -1.f;
    if (p.has("eta")) {
        eta = p.get_float("eta");
        if (!(eta > 0.f)) p.fail("eta", fmt::format("relative index of refraction must be > 0, got {}", eta));
    }
    return std::make_shared<Toksvig>(NormalSource::parse(p, "average_normal", /*unit_constant=*/false), s, ks, eta);
}

MESO_REGISTER_MATERIAL("toksvig", "Toksvig mapping: Blinn-Phong power widened by the length of the average normal (paper 003)",
                       [](const Properties &p) -> std::shared_ptr<Material> { return make_toksvig(p); });

}  // namespace
}  // namespace meso
