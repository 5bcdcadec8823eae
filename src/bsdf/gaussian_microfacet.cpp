#include "bsdf/gaussian_microfacet.h"
#include <algorithm>
#include <cmath>
#include <fmt/format.h>
#include "bsdf/fresnel.h"
#include "texture/texture.h"
#include "core/properties.h"

namespace meso {

// ------------------------------------------------------------------ the BRDF

GaussianMicrofacet::GaussianMicrofacet(const SlopeGaussian &g, bool rational_lambda, double min_variance)
    : m_slopes(g, min_variance), m_rational(rational_lambda) {}

double GaussianMicrofacet::meso_cos(const Vec3 &k) const {
    const SlopeGaussian &g = m_slopes.params();
    return double(k.z) - g.mx * double(k.x) - g.my * double(k.y);
}

bool GaussianMicrofacet::visible(const Vec3 &k) const {
    if (!(k.z > 0.f) || !(meso_cos(k) > 0.0)) return false;
    return std::isfinite(m_slopes.lambda(k, m_rational));
}

double GaussianMicrofacet::projected_area(const Vec3 &k) const {
    if (!(k.z > 0.f)) return 0.0;
    const double a = meso_cos(k);
    if (!(a > 0.0)) return 0.0;
    const double l = m_slopes.lambda(k, m_rational);
    if (!std::isfinite(l)) return 0.0;
    return a * (1.0 + l);
}

double GaussianMicrofacet::G1(const Vec3 &k) const {
    const double s = projected_area(k);
    if (!(s > 0.0) || !std::isfinite(s)) return 0.0;
    return std::min(1.0, double(k.z) / s);
}

double GaussianMicrofacet::eval(const Vec3 &wo, const Vec3 &wi) const {
    if (!(wo.z > 0.f) || !(wi.z > 0.f)) return 0.0;
    const double go = G1(wo);
    if (!(go > 0.0)) return 0.0;
    const double gi = G1(wi);
    if (!(gi > 0.0)) return 0.0;
    const Vec3 h = normalize(wo + wi);
    const double v = m_slopes.D(h) * go * gi / (4.0 * double(wo.z));
    return (std::isfinite(v) && v > 0.0) ? v : 0.0;
}

double GaussianMicrofacet::pdf(const Vec3 &wo, const Vec3 &wi) const {
    if (!visible(wo) || !visible(wi)) return 0.0;
    const Vec3 h = normalize(wo + wi);
    const double dwh = dot(wo, h);
    if (!(dwh > 0.0)) return 0.0;
    const double p = m_slopes.pdf_normal(h) / (4.0 * dwh);
    return (std::isfinite(p) && p > 0.0) ? p : 0.0;
}

bool GaussianMicrofacet::sample(const Vec3 &wo, Vec2 u, Vec3 &wi) const {
    if (!visible(wo)) return false;
    const Vec3 m = m_slopes.sample_normal(u);
    if (!(m.z > 0.f) || !(dot(wo, m) > 0.f)) return false;
    wi = normalize(reflect(wo, m));
    return is_finite(wi) && visible(wi);
}

// ------------------------------------------------------------------ parameters

GaussianMicrofacetParams parse_gaussian_microfacet(const Properties &p) {
    GaussianMicrofacetParams r;
    r.source = SlopeSource::parse(p);
    if (p.has("exponent") && p.has("alpha")) p.fail("alpha", "give either \"exponent\" or \"alpha\" as the base roughness, not both");
    if (p.has("exponent")) {
        const float s = p.get_float("exponent");
        if (!(s > 0.f) || !(s <= 1e7f)) p.fail("exponent", fmt::format("expected a Blinn-Phong power in (0, 1e7], got {}", s));
        r.base_variance = 1.0 / double(s);  // paper 003: "base specular power s added as 1/s"
        r.base_desc = fmt::format("exponent {}", s);
    } else if (p.has("alpha")) {
        const float a = p.get_float("alpha");
        if (!(a >= 0.f) || !(a <= 1e3f)) p.fail("alpha", fmt::format("expected a roughness in [0, 1000], got {}", a));
        r.base_variance = 0.5 * double(a) * a;  // Beckmann: sigma^2 = alpha^2 / 2
        r.base_desc = fmt::format("alpha {}", a);
    } else {
        r.base_desc = "no base roughness";
    }
    r.conductor = p.get_string("material", "none");
    if (r.conductor != "none" && !conductor_preset(r.conductor, r.eta, r.k)) {
        const std::string known = conductor_preset_list();
        p.fail("material", fmt::format("unknown conductor '{}' (known: {})", r.conductor, known));
    }
    r.specular = p.get_texture("specular_reflectance", Spectrum(1.f));
    r.rational = p.get_bool("rational_lambda", false);
    return r;
}

// ------------------------------------------------------------------ the material

GaussianMicrofacetMaterial::GaussianMicrofacetMaterial(std::string name, GaussianMicrofacetParams params,
                                                       Transform transform)
    : m_name(std::move(name)), m_p(std::move(params)), m_transform(transform) {
    if (m_p.source.is_constant())
        m_const = std::make_unique<GaussianMicrofacet>(distribution(ShadingContext{}), m_p.rational);
}

SlopeGaussian GaussianMicrofacetMaterial::distribution(const ShadingContext &ctx) const {
    return m_transform(m_p.source.eval(ctx), m_p.base_variance);
}

GaussianMicrofacet GaussianMicrofacetMaterial::at(const ShadingContext &ctx) const {
    if (m_const) return *m_const;
    return GaussianMicrofacet(distribution(ctx), m_p.rational);
}

Spectrum GaussianMicrofacetMaterial::fresnel(const ShadingContext &ctx, float cos_i) const {
    return fresnel_conductor(cos_i, m_p.eta, m_p.k) * m_p.specular->eval(ctx);
}

Spectrum GaussianMicrofacetMaterial::eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const {
    if (!(wo.z > 0.f) || !(wi.z > 0.f)) return Spectrum(0.f);
    const double v = at(ctx).eval(wo, wi);
    if (!(v > 0.0)) return Spectrum(0.f);
    return fresnel(ctx, dot(wi, normalize(wo + wi))) * float(v);
}

float GaussianMicrofacetMaterial::pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const {
    if (!(wo.z > 0.f) || !(wi.z > 0.f)) return 0.f;
    return float(at(ctx).pdf(wo, wi));
}

bool GaussianMicrofacetMaterial::sample(const ShadingContext &ctx, const Vec3 &wo, float, Vec2 u,
                                        BSDFSample &out) const {
    if (!(wo.z > 0.f)) return false;
    const GaussianMicrofacet brdf = at(ctx);
    Vec3 wi;
    if (!brdf.sample(wo, u, wi)) return false;
    // pdf and value at h = normalize(wo + wi), i.e. m up to round-off: exactly pdf() and eval().
    const double p = brdf.pdf(wo, wi);
    const double v = brdf.eval(wo, wi);
    if (!(p > 0.0) || !(float(p) > 0.f)) return false;
    out.wi = wi;
    out.pdf = float(p);
    out.eta = 1.f;
    out.flags = BSDF_GlossyReflection;
    out.weight = fresnel(ctx, dot(wi, normalize(wo + wi))) * float(v / double(out.pdf));
    return out.weight.is_finite();
}

Spectrum GaussianMicrofacetMaterial::albedo_hint(const ShadingContext &ctx) const { return fresnel(ctx, 1.f); }

std::string GaussianMicrofacetMaterial::to_string() const {
    return fmt::format("{}[{}, {}, F {}{}]", m_name, m_p.source.to_string(), m_p.base_desc, m_p.conductor,
                       m_p.rational ? ", rational Lambda" : "");
}

}  // namespace meso
