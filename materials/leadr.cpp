// `leadr`: the specular LEADR microfacet BRDF (Dupuy et al. 2013, paper 000 §4.4) for a
// Gaussian slope distribution with arbitrary mean (a tilted mesonormal) and anisotropic,
// correlated covariance.
//
// Model (local frame: z = the macronormal w_g; D, Lambda from render/slope_distribution.h)
//   f(wo, wi) |cos theta_i| = (n . w_g) / (n . wo) * F(wi . h) D(h) / (4 (1 + Lambda(wo) + Lambda(wi)))
//   with n the mesonormal (eq. 11), h = normalize(wo + wi) (eq. 16-17). Without F and
//   Lambda(wi) it integrates to one for every wo above the mesosurface (tested through the
//   projected-area identity in test_slope_distribution.cpp). wo below the mesosurface
//   (n . wo <= 0) reflects nothing; wi below it is fully shadowed (Lambda = inf).
//   Not reciprocal: the renormalisation depends on wo only (as in the paper).
//   Sampling: micro-normals from D(m) m.z (slopes from P22 by Cholesky), reflected:
//   pdf(wi) = D(h) h.z / (4 wo . h); weight = F (wo . h) / ((n . wo / n . w_g) h.z (1 + Lo + Li)).
//
// Parameters
//   name                  type        default  notes
//   mean_slope            [x, y]      [0, 0]   E[slope] in the local frame (x along the tangent)
//   covariance            [xx, yy, xy] -        slope covariance (excludes alpha)
//   alpha                 float       0.3      isotropic Beckmann roughness: sigma^2 = alpha^2 / 2
//   material              string      "none"   conductor preset for F (Ag, Al, Au, Cr, Cu, Ni, W); none: F = 1
//   specular_reflectance  texture     1        multiplies F
//   rational_lambda       bool        false    Walter's rational approximation instead of the erfc form
// Moments from a displacement map at the footprint's LoD level are the next step (issue 5).
#include <cmath>
#include <fmt/format.h>
#include "render/fresnel.h"
#include "render/material.h"
#include "render/slope_distribution.h"
#include "render/texture.h"
#include "scene/properties.h"
#include "scene/registry.h"

namespace meso {
namespace {

class Leadr final : public Material {
public:
    Leadr(const SlopeGaussian &g, Spectrum eta, Spectrum k, std::shared_ptr<Texture> spec, bool rational,
          std::string desc)
        : m_slopes(g), m_eta(eta), m_k(k), m_spec(std::move(spec)), m_rational(rational), m_desc(std::move(desc)) {
        m_meso = m_slopes.mesonormal();
    }

    uint32_t flags() const override { return BSDF_GlossyReflection; }
    bool is_reciprocal() const override { return false; }

    Spectrum eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        double s = value(wo, wi);
        if (!(s > 0.0)) return Spectrum(0.f);
        Vec3 h = normalize(wo + wi);
        return fresnel(ctx, dot(wi, h)) * float(s);
    }

    float pdf(const ShadingContext &, const Vec3 &wo, const Vec3 &wi) const override {
        if (!(wo.z > 0.f) || !(wi.z > 0.f)) return 0.f;
        // The directions sample() can return: wo above the mesosurface, wi not shadowed by it.
        if (!(dot(m_meso, wo) > 0.f) || std::isinf(m_slopes.lambda(wi, m_rational))) return 0.f;
        Vec3 h = normalize(wo + wi);
        const double dwh = dot(wo, h);
        if (!(dwh > 0.0)) return 0.f;
        const double p = m_slopes.pdf_normal(h) / (4.0 * dwh);
        return std::isfinite(p) ? float(p) : 0.f;
    }

    bool sample(const ShadingContext &ctx, const Vec3 &wo, float, Vec2 u, BSDFSample &out) const override {
        if (!(wo.z > 0.f)) return false;
        const double area = dot(m_meso, wo) / double(m_meso.z);
        if (!(area > 0.0)) return false;
        Vec3 m = m_slopes.sample_normal(u);
        const double dwm = dot(wo, m);
        if (!(dwm > 0.0) || !(m.z > 0.f)) return false;
        Vec3 wi = normalize(reflect(wo, m));
        if (!(wi.z > 0.f)) return false;
        if (std::isinf(m_slopes.lambda(wi, m_rational))) return false;  // below the mesosurface: shadowed
        // The pdf and weight use h = normalize(wo + wi), i.e. m up to round-off.
        out.pdf = pdf(ctx, wo, wi);
        if (!(out.pdf > 0.f)) return false;
        out.wi = wi;
        out.eta = 1.f;
        out.flags = BSDF_GlossyReflection;
        out.weight = eval(ctx, wo, wi) / out.pdf;
        return out.weight.is_finite();
    }

    Spectrum albedo_hint(const ShadingContext &ctx) const override { return fresnel(ctx, 1.f); }

    std::string to_string() const override {
        const SlopeGaussian &g = m_slopes.params();
        return fmt::format("leadr[{}, mean slope ({:.4g}, {:.4g}), covariance ({:.4g}, {:.4g}, {:.4g}){}]", m_desc, g.mx,
                           g.my, g.sxx, g.syy, g.sxy, m_rational ? ", rational Lambda" : "");
    }

private:
    /// f |cos theta_i| without Fresnel (eq. 16-17).
    double value(const Vec3 &wo, const Vec3 &wi) const {
        if (!(wo.z > 0.f) || !(wi.z > 0.f)) return 0.0;
        const double area = dot(m_meso, wo) / double(m_meso.z);  // (n . wo) / (n . w_g)
        if (!(area > 0.0)) return 0.0;
        const double li = m_slopes.lambda(wi, m_rational);
        if (std::isinf(li)) return 0.0;
        const double lo = m_slopes.lambda(wo, m_rational);
        if (!std::isfinite(lo)) return 0.0;
        Vec3 h = normalize(wo + wi);
        const double v = m_slopes.D(h) / (4.0 * area * (1.0 + lo + li));
        return std::isfinite(v) ? v : 0.0;
    }
    Spectrum fresnel(const ShadingContext &ctx, float cos_i) const {
        return fresnel_conductor(cos_i, m_eta, m_k) * m_spec->eval(ctx);
    }

    GaussianSlopes m_slopes;
    Vec3 m_meso;
    Spectrum m_eta, m_k;
    std::shared_ptr<Texture> m_spec;
    bool m_rational;
    std::string m_desc;
};

std::shared_ptr<Material> make_leadr(const Properties &p) {
    SlopeGaussian g;
    if (p.has("mean_slope")) {
        std::vector<float> m = p.get_floats("mean_slope");
        if (m.size() != 2 || !std::isfinite(m[0]) || !std::isfinite(m[1]))
            p.fail("mean_slope", "expected [x, y], finite");
        g.mx = m[0], g.my = m[1];
    }
    if (p.has("covariance")) {
        if (p.has("alpha")) p.fail("alpha", "give either \"alpha\" or \"covariance\", not both");
        std::vector<float> c = p.get_floats("covariance");
        if (c.size() != 3 || !(c[0] >= 0.f) || !(c[1] >= 0.f) || !std::isfinite(c[0]) || !std::isfinite(c[1]) ||
            !std::isfinite(c[2]))
            p.fail("covariance", "expected [sigma_x^2, sigma_y^2, c_xy] with finite, non-negative variances");
        if (double(c[2]) * c[2] > double(c[0]) * c[1] * (1 + 1e-6))
            p.fail("covariance", "expected |c_xy| <= sqrt(sigma_x^2 sigma_y^2) (a covariance matrix)");
        g.sxx = c[0], g.syy = c[1], g.sxy = c[2];
    } else {
        const float a = p.get_float("alpha", 0.3f);
        if (!(a >= 0.f) || !(a <= 1e3f)) p.fail("alpha", "expected a roughness in [0, 1000]");
        g.sxx = g.syy = 0.5 * double(a) * a;
    }
    Spectrum eta(0.f), k(1.f);
    std::string desc = p.get_string("material", "none");
    if (desc != "none" && !conductor_preset(desc, eta, k)) {
        std::string known;
        for (auto &n : conductor_preset_names()) known += (known.empty() ? "" : ", ") + n;
        p.fail("material", fmt::format("unknown conductor '{}' (known: {})", desc, known));
    }
    auto spec = p.get_texture("specular_reflectance", Spectrum(1.f));
    return std::make_shared<Leadr>(g, eta, k, spec, p.get_bool("rational_lambda", false), desc);
}

MESO_REGISTER_MATERIAL("leadr", "LEADR specular microfacets: Gaussian slopes with mean and covariance (paper 000)",
                       [](const Properties &p) -> std::shared_ptr<Material> { return make_leadr(p); });

}  // namespace
}  // namespace meso
