// `conductor`: a metal, smooth (perfect mirror) or rough (microfacet), with the exact
// complex Fresnel reflectance.
//
// Model
//   smooth (alpha < 1e-4):  delta reflection, weight = F(cos θo) · specular_reflectance.
//   rough:  f(wo, wi) = F(wi·h) D(h) G(wo, wi, h) / (4 cos θo cos θi) · specular_reflectance
//           (Cook & Torrance 1982; Walter et al. 2007, eq. 20), h = normalize(wo + wi).
//   D: GGX or Beckmann, anisotropic (alpha_u along the shading frame's s axis);
//   G: height-correlated Smith (Heitz 2014, eq. 99) — see bsdf/microfacet.h for why.
//   F: unpolarised conductor Fresnel with complex relative IOR eta + i k
//      (bsdf/fresnel.h; presets from Tungsten's spectral-to-sRGB tables).
//   Sampling: visible normals (Heitz 2018 GGX, Heitz & d'Eon 2014 Beckmann) or the full
//   NDF; pdf(wi) = D_wo(h) / (4 wo·h). Directions below the horizon: sample() fails.
//   Single scattering only: rough conductors lose energy (albedo < F) at high roughness.
//
// Parameters (Mitsuba 3 names)
//   name                  type      default  range / notes
//   material              string    "none"   Ag, Al, Au, Cr, Cu, Ni, W, or "none" (F = 1:
//                                            eta = 0, k = 1, as in Mitsuba)
//   eta                   spectrum  0        >= 0, real part of the IOR (excludes "material")
//   k                     spectrum  1        >= 0, imaginary part (excludes "material")
//   specular_reflectance  texture   1        [0, 1], multiplies F
//   distribution          string    "ggx"    "ggx" | "beckmann"
//   alpha                 float     0        [0, 1e3]; < 1e-4 = smooth mirror
//   alpha_u, alpha_v      float     —        anisotropic alternative to alpha
//   sample_visible        bool      true     visible-normal sampling
#include <algorithm>
#include <fmt/format.h>
#include <optional>
#include <vector>
#include "bsdf/fresnel.h"
#include "bsdf/material.h"
#include "bsdf/microfacet.h"
#include "texture/texture.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

class Conductor final : public Material {
public:
    Conductor(std::optional<MicrofacetDistribution> dist, Spectrum eta, Spectrum k,
              std::shared_ptr<Texture> specular, std::string desc)
        : m_dist(std::move(dist)), m_eta(eta), m_k(k), m_specular(std::move(specular)), m_desc(std::move(desc)) {}

    uint32_t flags() const override { return m_dist ? BSDF_GlossyReflection : BSDF_DeltaReflection; }

    Spectrum eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        if (!m_dist || !(wo.z > 0.f) || !(wi.z > 0.f)) return Spectrum(0.f);
        return rough_value(wo, wi, [&](const Vec3 &h) { return m_dist->G(wo, wi, h); },
                           [&] { return m_specular->eval(ctx); });
    }

    /// eval at every wi with Λ(wo) and the specular texture's value computed once: the same values.
    void eval_batch(const ShadingContext &ctx, const Vec3 &wo, const Vec3 *wi, int n, Spectrum *out) const override {
        if (n <= 0) return;
        std::fill(out, out + n, Spectrum(0.f));
        if (!m_dist || !(wo.z > 0.f)) return;
        const double lo = m_dist->lambda(wo);
        if (!std::isfinite(lo)) return;  // G = 0 at every wi
        const Spectrum spec = m_specular->eval(ctx);
        // rough_value's steps with D(h) and Λ(wi) batched (D_lambda_batch: Λ within 1.2e-7 erfc(a)
        // of lambda(), so G within a float ulp or two of eval's): the upper wi, their half vectors.
        thread_local std::vector<Vec3> hv, wv;
        thread_local std::vector<int> idx;
        thread_local std::vector<float> Dv;
        thread_local std::vector<double> lv;
        hv.clear(), wv.clear(), idx.clear();
        for (int k = 0; k < n; ++k)
            if (wi[k].z > 0.f) hv.push_back(normalize(wo + wi[k])), wv.push_back(wi[k]), idx.push_back(k);
        const int m = int(idx.size());
        Dv.resize(size_t(m)), lv.resize(size_t(m));
        m_dist->D_lambda_batch(hv.data(), wv.data(), m, Dv.data(), lv.data());
        const double inv4 = 1.0 / (4.0 * wo.z);
        for (int q = 0; q < m; ++q) {
            const Vec3 &h = hv[size_t(q)], &w = wv[size_t(q)];
            const float D = Dv[size_t(q)];
            const double li = lv[size_t(q)];
            if (D == 0.f || !(dot(wo, h) * wo.z > 0.f) || !(dot(w, h) * w.z > 0.f) || !std::isfinite(li)) continue;
            const float G = float(1.0 / (1.0 + lo + li));
            const float s = float(double(D) * G * inv4);
            if (!std::isfinite(s) || s <= 0.f) continue;
            out[idx[size_t(q)]] = fresnel_conductor(dot(w, h), m_eta, m_k) * spec * s;
        }
    }

    /// eval and pdf sharing the half vector, D and Λ(wo) (the multi-lobe BRDF of prefiltered
    /// models calls this once per node): the same values as the two calls.
    Spectrum eval_pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi, float *pdf_out) const override {
        if (!pdf_out) return eval(ctx, wo, wi);
        *pdf_out = 0.f;
        if (!m_dist || !(wo.z > 0.f) || !(wi.z > 0.f)) return Spectrum(0.f);
        const Vec3 h = normalize(wo + wi);
        const float D = m_dist->D(h);
        if (D == 0.f) return Spectrum(0.f);
        const float dwh = dot(wo, h), diw = dot(wi, h);
        if (!(dwh > 0.f)) return Spectrum(0.f);  // both eval (G = 0) and pdf vanish
        const double lo = m_dist->lambda(wo), li = m_dist->lambda(wi);
        if (!std::isfinite(lo)) return Spectrum(0.f);
        // pdf: visible normals G1(wo) D (wo.h) / wo.z / (4 wo.h), or D h.z / (4 wo.h)
        double p = m_dist->sample_visible() ? double(D) / ((1.0 + lo) * 4.0 * wo.z) : double(D) * h.z / (4.0 * dwh);
        *pdf_out = std::isfinite(p) && h.z > 0.f ? float(p) : 0.f;
        if (!(diw > 0.f) || !std::isfinite(li)) return Spectrum(0.f);
        const float G = float(1.0 / (1.0 + lo + li));
        const float s = float(double(D) * G / (4.0 * wo.z));
        if (!std::isfinite(s) || s <= 0.f) return Spectrum(0.f);
        return fresnel_conductor(diw, m_eta, m_k) * m_specular->eval(ctx) * s;
    }

    float pdf(const ShadingContext &, const Vec3 &wo, const Vec3 &wi) const override {
        if (!m_dist || !(wo.z > 0.f) || !(wi.z > 0.f)) return 0.f;
        Vec3 h = normalize(wo + wi);
        float dwh = dot(wo, h);
        if (!(dwh > 0.f)) return 0.f;
        float p = float(double(m_dist->pdf(wo, h)) / (4.0 * dwh));
        return std::isfinite(p) ? p : 0.f;
    }

    bool sample(const ShadingContext &ctx, const Vec3 &wo, float, Vec2 u, BSDFSample &out) const override {
        if (!(wo.z > 0.f)) return false;
        if (!m_dist) {
            out.wi = reflect_local(wo);
            out.pdf = 1.f;
            out.eta = 1.f;
            out.flags = BSDF_DeltaReflection;
            out.weight = fresnel_conductor(wo.z, m_eta, m_k) * m_specular->eval(ctx);
            return true;
        }
        float pm;
        Vec3 m = m_dist->sample(wo, u, &pm);
        if (!(pm > 0.f)) return false;
        float dwm = dot(wo, m);
        if (!(dwm > 0.f)) return false;
        Vec3 wi = normalize(reflect(wo, m));
        if (!(wi.z > 0.f)) return false;
        // Value and pdf are re-evaluated at the returned (float) direction through eval_pdf, so
        // that pdf = pdf(wi) and weight = eval/pdf hold to rounding. The analytic forms (pdf
        // D_wo(m) / (4 wo·m), weight G2/G1(wo) F) differ from them at narrow lobes seen at
        // grazing angles: there the half vector normalize(wo + wi) rebuilt from the float wi
        // differs from m by the cancellation in wo + wi (~6e-8 / |wo + wi| in slope), which
        // moves D by percents at alpha 1e-3, theta_o 89.99 degrees (issue 24). D cancels in the
        // ratio, so the weight stays G2/G1(wo) F up to rounding.
        float p = 0.f;
        const Spectrum value = eval_pdf(ctx, wo, wi, &p);
        if (!(p > 0.f) || !std::isfinite(p) || !(value.max() > 0.f)) return false;  // shadowed: G = 0
        out.wi = wi;
        out.pdf = p;
        out.eta = 1.f;
        out.flags = BSDF_GlossyReflection;
        out.weight = value / p;
        return out.weight.is_finite();
    }

    Spectrum albedo_hint(const ShadingContext &ctx) const override {
        return fresnel_conductor(1.f, m_eta, m_k) * m_specular->eval(ctx);
    }

    bool uses_footprint() const override { return any_varies({m_specular.get()}); }
    std::string to_string() const override {
        return fmt::format("conductor[{}, {}]", m_desc, m_dist ? m_dist->to_string() : "smooth");
    }

private:
    /// The rough lobe's value D G F / (4 wo.z) at wi (both above the surface): G and the
    /// specular texture's value come from the callers (eval, eval_batch), so both give the same.
    template <class GFn, class SpecFn>
    Spectrum rough_value(const Vec3 &wo, const Vec3 &wi, const GFn &G_at, const SpecFn &specular) const {
        const Vec3 h = normalize(wo + wi);
        const float D = m_dist->D(h);
        if (D == 0.f) return Spectrum(0.f);
        const float G = G_at(h);
        const float s = float(double(D) * G / (4.0 * wo.z));
        if (!std::isfinite(s) || s <= 0.f) return Spectrum(0.f);
        return fresnel_conductor(dot(wi, h), m_eta, m_k) * specular() * s;
    }
    std::optional<MicrofacetDistribution> m_dist;
    Spectrum m_eta, m_k;
    std::shared_ptr<Texture> m_specular;
    std::string m_desc;
};

std::shared_ptr<Material> make_conductor(const Properties &p) {
    auto dist = microfacet_from_properties(p, true, 0.f);
    Spectrum eta(0.f), k(1.f);
    std::string desc = "none";
    if (p.has("material")) {
        if (p.has("eta")) p.fail("eta", "give either \"material\" or \"eta\"/\"k\", not both");
        if (p.has("k")) p.fail("k", "give either \"material\" or \"eta\"/\"k\", not both");
        desc = p.get_string("material");
        if (desc != "none" && !conductor_preset(desc, eta, k)) {
            const std::string known = conductor_preset_list();
            p.fail("material", fmt::format("unknown conductor '{}' (known: {})", desc, known));
        }
    } else if (p.has("eta") || p.has("k")) {
        eta = p.get_spectrum("eta", Spectrum(0.f));
        k = p.get_spectrum("k", Spectrum(1.f));
        for (int c = 0; c < 3; ++c) {
            if (!(eta[c] >= 0.f)) p.fail("eta", "must be >= 0");
            if (!(k[c] >= 0.f)) p.fail("k", "must be >= 0");
        }
        desc = fmt::format("eta=({}, {}, {}), k=({}, {}, {})", eta.r, eta.g, eta.b, k.r, k.g, k.b);
    }
    auto spec = p.get_texture("specular_reflectance", Spectrum(1.f));
    return std::make_shared<Conductor>(dist, eta, k, spec, desc);
}

MESO_REGISTER_MATERIAL("conductor", "metal: smooth mirror or GGX/Beckmann microfacets, complex Fresnel",
                       [](const Properties &p) -> std::shared_ptr<Material> { return make_conductor(p); });

}  // namespace
}  // namespace meso
