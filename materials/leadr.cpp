// `leadr`: LEADR microfacet BRDFs (Dupuy et al. 2013, paper 000 §4.3-4.5) for a Gaussian
// slope distribution with arbitrary mean (a tilted mesonormal) and anisotropic, correlated
// covariance: specular microfacets (eq. 16-17) plus diffuse microfacets (eq. 21).
//
// Slope statistics (texture/slope_source.h): constant (`mean_slope`, `covariance`) or the
// slope moments of a `heightmap` read at the ray-differential footprint (LEADR mapping,
// eq. 9 and 12), plus the base roughness `alpha` (sigma^2 += alpha^2 / 2 on both variances,
// the LEAN/LEADR "offset of the covariance", §4.1). Without heightmap or covariance, alpha
// defaults to 0.3 (a plain isotropic Beckmann surface); with either, to 0.
//
// Model (local frame: z = the macronormal w_g; D, Lambda from bsdf/slope_distribution.h;
// n = the mesonormal of eq. 11; area = (n . wo) / (n . w_g); h = normalize(wo + wi))
//   specular  f |cos theta_i| = F(wi . h) ks D(h) G / (4 area)                   (eq. 16-17)
//   diffuse   f |cos theta_i| = rho / (pi area) G int <m, wo> <m, wi> / (m . w_g) P22 ds  (eq. 21)
//   G = 1 / (1 + Lambda(wo) + Lambda(wi))   shadowing "joint" (eq. 13, default)
//     = 1 / (1 + Lambda(wo))                shadowing "masking" (the paper's §6 option when
//                                           shadowing is neglected elsewhere)
//   wi below the mesosurface (Lambda(wi) = inf) gives 0 in both modes; wo below it (area <=
//   0) reflects nothing; wi.z <= 0 or wo.z <= 0 give 0 (reflection only).
//   The diffuse slope integral has no closed form: it is evaluated with the paper's N x N
//   grid (§5.1, bsdf/leadr_quadrature.h; N = `diffuse_quadrature`, lambda(N) = min(5, 0.4 +
//   1.2 ln N)), precomputed once for constant statistics. Default N = 12: RMS error 0.34%,
//   max 3.2% of the value at wi = normal against N = 128 over 1200 (wo, wi, moments)
//   configurations including an 80-degree tilt (N = 8: 0.7% / 6.6%; N = 16: 0.16% / 1.5%);
//   eval of both lobes costs 0.29 / 0.39 / 0.53 us at N = 8 / 12 / 16.
//   Specular alone, without F and Lambda(wi), integrates to one over the sphere of wi for
//   every wo above the mesosurface (tested in tests/test_leadr.cpp on this material's eval).
//   Energy: both lobes have albedo <= their reflectance (specular by the identity above with
//   G <= 1/(1+Lo); diffuse since int <m, wi> dwi <= pi); so albedo <= 1 when ks F + rho <= 1
//   (up to the diffuse grid's quadrature error). Not reciprocal: the renormalisation
//   1 / area depends on wo only (as in the paper).
//   Sampling: lobe chosen with probability mean(ks) : mean(rho) (texture means). Specular:
//   micro-normals from D(m) m.z (slopes from P22 by Cholesky), reflected, pdf = D(h) h.z /
//   (4 wo . h). Diffuse: 1/2 cosine about w_g + 1/2 cosine about n (directions with wi.z <= 0
//   fail), pdf = (wi.z + max(0, wi . n)) / (2 pi). pdf = the mixture, 0 outside the
//   domain where eval can be non-zero (wi shadowed by the mesosurface, wo masked).
//   Environment lighting by quadrature (Algorithms 1-3, bsdf/leadr_quadrature.h) for the
//   `path` integrator's `leadr_env_quadrature` option: env_quadrature and env_irradiance.
//
// Parameters
//   name                  type        default      notes
//   heightmap             object      -            slope moments of a displacement map (slope_source.h);
//   filter, max_anisotropy                          with its "filter" / "max_anisotropy"
//   mean_slope            [x, y]      [0, 0]       constant E[slope] (x along the tangent); not with heightmap
//   covariance            [xx, yy, xy] [0, 0, 0]   constant slope covariance; not with heightmap
//   alpha                 float       0.3 | 0      base Beckmann roughness, [0, 1000]: sigma^2 += alpha^2/2
//   material              string      "none"       conductor preset for F (Ag, Al, Au, Cr, Cu, Ni, W); none: F = 1
//   specular_reflectance  texture     1            ks, multiplies F; 0 = no specular lobe
//   diffuse_reflectance   texture     0            rho of the diffuse microfacets (eq. 21)
//   shadowing             string      "joint"      "joint" (eq. 13) | "masking" (1 / (1 + Lambda(wo)))
//   rational_lambda       bool        false        Walter's rational Lambda instead of the erfc form
//   diffuse_quadrature    int         12           N of the N x N grid for eq. 21, [1, 128]
//   env_quadrature        int         8            N of Algorithm 1 (specular, environment), [1, 128]
//   env_diffuse_quadrature int        5            N of Algorithm 3 (the paper's 5 x 5), [1, 128]
//   env_irradiance        string      "shadowed"   "shadowed" (eq. 20 per point) | "paper" (Algorithm 2) |
//                                                  "gaussian" (paper 001 §5.3: the unshadowed SH irradiance map
//                                                  E(n) filtered as a slope colour map, rho/pi <E, D_s>, D_s the
//                                                  Gaussian visible-slope distribution; env_diffuse_quadrature^2
//                                                  Gauss-Hermite nodes)
//   colormap              object|array -           colour correlated to the heights or slopes (paper 001 §5), below;
//                                                  an array combines several terms (§6)
//   colormap_combine      string      "sum"        "sum": sum of weight x term (the paper's linear combination
//                                                  kappa_0 C_0 + kappa_1 C_h + kappa_2 C_s); "product": product of
//                                                  weight x term (its non-linear C_0 C_h C_s)
//
// Colour maps on the Gaussian surface (paper 001 §5.1-5.2; filter/transfer_filter.h). The colour
// multiplies both lobes (the paper's assumption that colour and BRDF are uncorrelated). Keys of
// the "colormap" object:
//   ramp                  ramp        required     the colour map C (filter/ramp_parse.h)
//   weight                float       1            the term's weight kappa in a combination
//   texture               texture     -            instead of ramp/attribute: an uncorrelated term C_0 (§4, e.g. a
//                                                  `colormap` texture on noise); the BRDF's shadowing G carries
//                                                  the paper's V-bar factor of C_0 and C_s in the §6 sum
//   attribute             string      "height"     "height" | "slope_x" | "slope_y" | "steepness" (as `microcolormap`)
//   filter                string      "gaussian"   "gaussian": <C, D> with D the view- (and light-) dependent
//                                                  filtering distribution; "naive": C of the footprint's mean
//                                                  attribute (mean height / mean slope: texture filtering)
//   height_distribution   string      "fit"        "fit": D_h ~ N(mu_d, sigma_d) by the paper's eq. 16-17;
//                                                  "exact": mu_d, sigma_d of eq. 15 (tabulated quadrature)
//   noise_mean, noise_sigma float     0, 0         noise-perturbed heights C(h + r): mu_d += mu_r,
//                                                  sigma_d^2 += sigma_r^2 (§5.1)
//   height_mean, height_sigma float   -            height statistics for constant slope statistics (no heightmap)
//   sigma_max             float       ramp width   the preconvolved table's sigma range; beyond it the closed form
//   table_size            [n, m]      [512, 128]   the table's means x sigmas
// Height: h_bar and sigma_h^2 are the footprint-filtered E[h], E[h^2] - E[h]^2 of the heightmap
// (build_height_moments); Lambda = Lambda(wo) + Lambda(wi) of this material's distribution, so the
// shadowing G already carries eq. 12's average visibility (G / G1(wo)) and the colour is
// <C, N(h_bar + mu_d + mu_r, sigma_d^2 + sigma_r^2)>. In env_radiance the light term is dropped
// (Lambda = Lambda(wo)). Slopes: D_s = visible_slope_gaussian(distribution, wo); slope_x / slope_y
// read the preconvolved table with its marginal, steepness integrates C(|s|) against D_s
// (gaussian_average_steepness: closed-form radial integrals over 16-256 directions).
// Eval cost of a diffuse point (LeadrColormap.EvalCost, medians of 3 runs on 2 shared cores): 0.43 us
// without a colour map, 0.46-0.51 us with height (fit or exact) or slope_x, 3.4 us with steepness.
#include <cmath>
#include <optional>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "bsdf/fresnel.h"
#include "bsdf/leadr_quadrature.h"
#include "bsdf/material.h"
#include "bsdf/slope_distribution.h"
#include "texture/texture.h"
#include "filter/transfer_filter.h"
#include "filter/ramp_parse.h"
#include "sampling/warp.h"
#include "core/properties.h"
#include "core/registry.h"
#include "texture/slope_source.h"

namespace meso {
namespace {

enum class ColorAttribute { Height, SlopeX, SlopeY, Steepness, Texture };

/// The "colormap" block (paper 001 §5).
struct LeadrColormap {
    bool on = false;
    double weight = 1.0;
    std::shared_ptr<Texture> texture;  ///< the uncorrelated term C_0 (§6), attribute Texture
    ColorAttribute attr = ColorAttribute::Height;
    std::string attr_name = "height";
    bool filtered = true, exact_height = false;
    double noise_mean = 0, noise_sigma = 0;
    Ramp ramp;
    std::shared_ptr<PreconvolvedTable> table;

    /// <C, N(mean, sigma^2)> from the table (the closed form beyond sigma_max).
    Spectrum smooth(double mean, double sigma) const {
        float t[3];
        if (table->lookup(mean, sigma, t)) return Spectrum(t[0], t[1], t[2]);
        double c[3];
        ramp.gaussian_average(mean, sigma, c);
        return Spectrum(float(c[0]), float(c[1]), float(c[2]));
    }
    Spectrum at(double v) const {
        double c[3];
        ramp.eval(v, c);
        return Spectrum(float(c[0]), float(c[1]), float(c[2]));
    }
};

struct LeadrParams {
    SlopeSource source;
    double base_variance = 0;  ///< alpha^2 / 2
    double alpha = 0;
    Spectrum eta{0.f}, k{1.f};
    std::string conductor = "none";
    std::shared_ptr<Texture> ks, kd;
    bool has_spec = true, has_diffuse = false;
    bool rational = false;
    LeadrShadowing shadowing = LeadrShadowing::Joint;
    int diffuse_n = 12;
    LeadrEnvOptions env_spec, env_diff;
    std::vector<LeadrColormap> cmaps;  ///< one or several (§6), combined by sum or product
    bool cmap_product = false;
};

class Leadr final : public Material {
public:
    explicit Leadr(LeadrParams p) : m_p(std::move(p)) {
        if (m_p.source.is_constant()) {
            m_const.emplace(with_base(m_p.source.eval(ShadingContext{})));
            if (m_p.has_diffuse) m_grid = LeadrDiffuseGrid(*m_const, m_p.diffuse_n);
        }
        const double sw = m_p.has_spec ? std::max(0.f, m_p.ks->mean().average()) : 0.0;
        const double dw = m_p.has_diffuse ? std::max(0.f, m_p.kd->mean().average()) : 0.0;
        m_spec_weight = (sw + dw > 0.0) ? float(sw / (sw + dw)) : (m_p.has_spec ? 1.f : 0.f);
    }

    uint32_t flags() const override {
        return (m_p.has_spec ? BSDF_GlossyReflection : 0u) | (m_p.has_diffuse ? BSDF_DiffuseReflection : 0u);
    }
    bool is_reciprocal() const override { return false; }

    Spectrum eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        Point pt;
        if (!point(ctx, pt) || !view(pt, wo) || !(wi.z > 0.f)) return Spectrum(0.f);
        const double li = pt.g->lambda(wi, m_p.rational);
        const double G = leadr_shadowing(pt.lo, li, m_p.shadowing);
        if (!(G > 0.0)) return Spectrum(0.f);
        return value(ctx, pt, wo, wi, G) * color(ctx, pt, wo, li);
    }

    float pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        Point pt;
        if (!point(ctx, pt) || !view(pt, wo) || !(wi.z > 0.f)) return 0.f;
        if (std::isinf(pt.g->lambda(wi, m_p.rational))) return 0.f;  // shadowed by the mesosurface
        return mixture_pdf(pt, wo, wi);
    }

    bool sample(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, BSDFSample &out) const override {
        Point pt;
        if (!point(ctx, pt) || !view(pt, wo)) return false;
        Vec3 wi;
        if (u_lobe < m_spec_weight) {
            const Vec3 m = pt.g->sample_normal(u);
            if (!(dot(wo, m) > 0.f) || !(m.z > 0.f)) return false;
            wi = normalize(reflect(wo, m));
            out.flags = BSDF_GlossyReflection;
        } else {
            const float ud = m_spec_weight < 1.f ? (u_lobe - m_spec_weight) / (1.f - m_spec_weight) : 0.5f;
            const Vec3 c = square_to_cosine_hemisphere(u);
            wi = ud < 0.5f ? c : normalize(Frame(pt.meso).to_world(c));
            out.flags = BSDF_DiffuseReflection;
        }
        if (!(wi.z > 0.f)) return false;
        const double li = pt.g->lambda(wi, m_p.rational);
        if (std::isinf(li)) return false;  // below the mesosurface: shadowed
        out.pdf = mixture_pdf(pt, wo, wi);
        if (!(out.pdf > 0.f) || !std::isfinite(out.pdf)) return false;
        out.wi = wi;
        out.eta = 1.f;
        const double G = leadr_shadowing(pt.lo, li, m_p.shadowing);
        out.weight = (G > 0.0 ? value(ctx, pt, wo, wi, G) * color(ctx, pt, wo, li) : Spectrum(0.f)) / out.pdf;
        return out.weight.is_finite();
    }

    Spectrum albedo_hint(const ShadingContext &ctx) const override {
        Spectrum a(0.f);
        if (m_p.has_spec) a += fresnel_conductor(1.f, m_p.eta, m_p.k) * m_p.ks->eval(ctx);
        if (m_p.has_diffuse) a += m_p.kd->eval(ctx);
        if (!m_p.cmaps.empty()) {
            Point pt;
            point(ctx, pt);
            a *= combine(ctx, pt, [&](const LeadrColormap &c) { return naive_color(ctx, pt, c); });
        }
        return a;
    }

    bool has_env_quadrature() const override { return true; }
    Spectrum env_radiance(const ShadingContext &ctx, const Vec3 &wo, const PrefilteredEnvironment &env) const override {
        Point pt;
        if (!point(ctx, pt) || !view(pt, wo)) return Spectrum(0.f);
        Spectrum L(0.f);
        if (m_p.has_spec) {
            const Spectrum ks = m_p.ks->eval(ctx);
            L += leadr_env_specular(
                *pt.g, wo, ctx.frame, [&](float c) { return fresnel_conductor(c, m_p.eta, m_p.k) * ks; }, env,
                m_p.env_spec);
        }
        if (m_p.has_diffuse) L += leadr_env_diffuse(*pt.g, wo, ctx.frame, m_p.kd->eval(ctx), env, m_p.env_diff);
        return m_p.cmaps.empty() ? L : L * color(ctx, pt, wo, 0.0);
    }

    std::string to_string() const override {
        std::string s = fmt::format("leadr[{}, {}", m_p.conductor, m_p.source.to_string());
        if (m_p.alpha > 0) s += fmt::format(", base alpha {:.4g}", m_p.alpha);
        if (m_p.has_diffuse) s += fmt::format(", diffuse microfacets (N = {})", m_p.diffuse_n);
        if (!m_p.has_spec) s += ", no specular";
        if (m_p.shadowing == LeadrShadowing::Masking) s += ", masking only";
        if (m_p.rational) s += ", rational Lambda";
        for (const LeadrColormap &c : m_p.cmaps)
            s += fmt::format(", {}colormap on {} ({}{})", m_p.cmaps.size() > 1 ? fmt::format("{:.3g} x ", c.weight) : "",
                             c.attr_name, c.filtered ? "gaussian" : "naive",
                             c.attr == ColorAttribute::Height && c.filtered ? (c.exact_height ? ", exact D_h" : ", fitted D_h")
                                                                            : "");
        if (m_p.cmaps.size() > 1) s += m_p.cmap_product ? ", product" : ", sum";
        return s + "]";
    }

private:
    /// The distribution at one shading point (the constant one, or built from the source).
    struct Point {
        const GaussianSlopes *g = nullptr;
        std::optional<GaussianSlopes> local;
        Vec3 meso;
        double area = 0, lo = 0;
    };

    SlopeGaussian with_base(SlopeGaussian g) const {
        g.sxx += m_p.base_variance;
        g.syy += m_p.base_variance;
        return g;
    }
    bool point(const ShadingContext &ctx, Point &pt) const {
        if (m_const) {
            pt.g = &*m_const;
        } else {
            pt.local.emplace(with_base(m_p.source.eval(ctx)));
            pt.g = &*pt.local;
        }
        pt.meso = pt.g->mesonormal();
        return true;
    }
    /// area = (n . wo) / (n . w_g) and Lambda(wo); false when wo is masked.
    bool view(Point &pt, const Vec3 &wo) const {
        if (!(wo.z > 0.f)) return false;
        pt.area = dot(pt.meso, wo) / double(pt.meso.z);
        if (!(pt.area > 0.0)) return false;
        pt.lo = pt.g->lambda(wo, m_p.rational);
        return std::isfinite(pt.lo);
    }
    /// C of the footprint's mean attribute (the "naive" filter, texture filtering of the driver).
    Spectrum naive_color(const ShadingContext &ctx, const Point &pt, const LeadrColormap &c) const {
        const SlopeGaussian &g = pt.g->params();
        switch (c.attr) {
            case ColorAttribute::Texture: return c.texture->eval(ctx);
            case ColorAttribute::Height: {
                double mean, var;
                m_p.source.height_moments(ctx, mean, var);
                return c.at(mean + c.noise_mean);
            }
            case ColorAttribute::SlopeX: return c.at(g.mx);
            case ColorAttribute::SlopeY: return c.at(g.my);
            default: return c.at(std::sqrt(g.mx * g.mx + g.my * g.my));
        }
    }
    /// Sum (weights) or product (weights as exponents are not offered: plain product) of f(c).
    template <class F>
    Spectrum combine(const ShadingContext &, const Point &, F f) const {
        if (m_p.cmaps.empty()) return Spectrum(1.f);
        Spectrum acc = m_p.cmap_product ? Spectrum(1.f) : Spectrum(0.f);
        for (const LeadrColormap &c : m_p.cmaps) {
            if (m_p.cmap_product) acc *= f(c) * float(c.weight);
            else acc += f(c) * float(c.weight);
        }
        return acc;
    }
    /// The colour factor for view wo and light shadowing li = Lambda(wi) (paper 001 §5-6).
    Spectrum color(const ShadingContext &ctx, const Point &pt, const Vec3 &wo, double li) const {
        return combine(ctx, pt, [&](const LeadrColormap &c) { return color_one(ctx, pt, wo, li, c); });
    }
    Spectrum color_one(const ShadingContext &ctx, const Point &pt, const Vec3 &wo, double li,
                       const LeadrColormap &c) const {
        if (c.attr == ColorAttribute::Texture) return c.texture->eval(ctx);
        if (!c.filtered) return naive_color(ctx, pt, c);
        if (c.attr == ColorAttribute::Height) {
            double mean, var;
            m_p.source.height_moments(ctx, mean, var);
            const double L = pt.lo + li, sh = std::sqrt(var);
            const HeightFilter f =
                c.exact_height ? HeightFilterTable::instance().lookup(sh, L) : height_filter_fit(sh, L);
            return c.smooth(mean + f.mu + c.noise_mean, std::sqrt(f.sigma * f.sigma + c.noise_sigma * c.noise_sigma));
        }
        const SlopeGaussian d = visible_slope_gaussian(pt.g->params(), wo);
        if (c.attr == ColorAttribute::SlopeX) return c.smooth(d.mx, std::sqrt(d.sxx));
        if (c.attr == ColorAttribute::SlopeY) return c.smooth(d.my, std::sqrt(d.syy));
        double out[3];
        gaussian_average_steepness(c.ramp, d, out);
        return Spectrum(float(out[0]), float(out[1]), float(out[2]));
    }

    /// f |cos theta_i| of both lobes for an unshadowed pair with shadowing term G > 0.
    Spectrum value(const ShadingContext &ctx, const Point &pt, const Vec3 &wo, const Vec3 &wi, double G) const {
        Spectrum v(0.f);
        if (m_p.has_spec) {
            // h must face wo (chi+(wo . h), as the pdf's wo . h > 0): at grazing wo a float wi
            // near the mirror direction leaves h = normalize(wo + wi) with ~1e-4 of rounding
            // in its tangent part, enough to tip wo . h <= 0 under a narrow lobe (issue 24).
            const Vec3 h = normalize(wo + wi);
            const double s = dot(wo, h) > 0.f ? pt.g->D(h) * G / (4.0 * pt.area) : 0.0;
            if (std::isfinite(s) && s > 0.0)
                v += fresnel_conductor(dot(wi, h), m_p.eta, m_p.k) * m_p.ks->eval(ctx) * float(s);
        }
        if (m_p.has_diffuse) {
            double Q = 0;  // the grid's projected area: exactly area (1 + Lambda(wo)) in the limit
            const double I = m_const ? m_grid.integral(wo, wi, &Q)
                                     : leadr_diffuse_slope_integral(*pt.g, m_p.diffuse_n, wo, wi, &Q);
            // Albedo <= rho needs Q <= area (1 + Lambda(wo)) (G <= 1/(1 + Lambda(wo)) and
            // int <m, wi> dwi <= pi per facet); the N x N grid overestimates Q at grazing wo
            // (+1.5% at alpha 0.01, theta_o 89.99 degrees: issue 24), so I is scaled down there.
            const double Q_exact = pt.area * (1.0 + pt.lo);
            const double scale = Q > Q_exact ? Q_exact / Q : 1.0;
            const double d = I * scale * G / (3.14159265358979323846 * pt.area);
            if (std::isfinite(d) && d > 0.0) v += m_p.kd->eval(ctx) * float(d);
        }
        return v;
    }
    /// The sampling density (wo unmasked, wi.z > 0 and not shadowed by the mesosurface).
    float mixture_pdf(const Point &pt, const Vec3 &wo, const Vec3 &wi) const {
        double p = 0;
        if (m_spec_weight > 0.f) {
            const Vec3 h = normalize(wo + wi);
            const double dwh = dot(wo, h);
            if (dwh > 0.0) p += m_spec_weight * pt.g->pdf_normal(h) / (4.0 * dwh);
        }
        if (m_spec_weight < 1.f)
            p += (1.0 - m_spec_weight) * (double(wi.z) + std::max(0.0, double(dot(wi, pt.meso)))) /
                 (2.0 * 3.14159265358979323846);
        return std::isfinite(p) ? float(p) : 0.f;
    }

    LeadrParams m_p;
    std::optional<GaussianSlopes> m_const;
    LeadrDiffuseGrid m_grid;
    float m_spec_weight = 1.f;
};

LeadrShadowing parse_shadowing(const Properties &p) {
    return p.get_enum<LeadrShadowing>("shadowing", "joint",
                                      {{"joint", LeadrShadowing::Joint}, {"masking", LeadrShadowing::Masking}});
}

int parse_grid(const Properties &p, const char *key, int def) {
    const int n = p.get_int(key, def);
    if (n < 1 || n > kLeadrMaxGrid) p.fail(key, fmt::format("expected a grid size in [1, {}]", kLeadrMaxGrid));
    return n;
}

LeadrColormap parse_colormap(const Properties &p, SlopeSource &source) {
    LeadrColormap c;
    c.on = true;
    c.weight = p.get_float("weight", 1.f);
    if (!std::isfinite(c.weight)) p.fail("weight", "expected a finite number");
    if (p.has("texture")) {  // the uncorrelated term C_0 of §6: any texture (e.g. a `colormap` texture)
        c.texture = p.get_texture("texture");
        c.attr = ColorAttribute::Texture;
        c.attr_name = "texture";
        p.check_unused("leadr colormap term");
        return c;
    }
    c.ramp = parse_ramp(p, "ramp", 3);
    c.attr = p.get_enum<ColorAttribute>("attribute", "height",
                                        {{"height", ColorAttribute::Height},
                                         {"slope_x", ColorAttribute::SlopeX},
                                         {"slope_y", ColorAttribute::SlopeY},
                                         {"steepness", ColorAttribute::Steepness}});
    c.attr_name = p.get_string("attribute", "height");  // the validated name, for to_string
    c.filtered = p.get_enum<bool>("filter", "gaussian", {{"gaussian", true}, {"naive", false}});
    c.exact_height = p.get_enum<bool>("height_distribution", "fit", {{"fit", false}, {"exact", true}});
    c.noise_mean = p.get_float("noise_mean", 0.f);
    c.noise_sigma = p.get_float("noise_sigma", 0.f);
    if (!std::isfinite(c.noise_mean)) p.fail("noise_mean", "expected a finite number");
    if (!(c.noise_sigma >= 0.0) || !std::isfinite(c.noise_sigma)) p.fail("noise_sigma", "expected a finite number >= 0");
    const bool hm = p.has("height_mean"), hs = p.has("height_sigma");
    if (hm || hs) {
        if (!source.is_constant())
            p.fail(hm ? "height_mean" : "height_sigma", "the heights come from the heightmap; give these only with "
                                                        "constant statistics (covariance / mean_slope)");
        const float mean = p.get_float("height_mean", 0.f), sigma = p.get_float("height_sigma", 0.f);
        if (!std::isfinite(mean)) p.fail("height_mean", "expected a finite number");
        if (!(sigma >= 0.f) || !std::isfinite(sigma)) p.fail("height_sigma", "expected a finite number >= 0");
        source.set_constant_height(mean, sigma);
    }
    if (c.attr == ColorAttribute::Height && !source.has_heights())
        p.fail("attribute", "a colour map on heights needs the material's \"heightmap\" or, with constant slope "
                            "statistics, \"height_mean\" and \"height_sigma\"");
    double smax = c.ramp.x_max() - c.ramp.x_min();
    if (!(smax > 0.0)) smax = 1.0;
    smax = p.get_float("sigma_max", float(smax));
    if (!(smax > 0.0) || !std::isfinite(smax)) p.fail("sigma_max", "expected a finite number > 0");
    int nm = 512, ns = 128;
    if (p.has("table_size")) {
        const std::vector<float> t = p.get_floats("table_size");
        if (t.size() != 2 || !(t[0] >= 2 && t[0] <= 8192) || !(t[1] >= 2 && t[1] <= 8192))
            p.fail("table_size", "expected [n_mean, n_sigma], each in [2, 8192]");
        nm = int(t[0]), ns = int(t[1]);
    }
    c.table = std::make_shared<PreconvolvedTable>(PreconvolvedTable::of_ramp(c.ramp, smax, nm, ns));
    p.check_unused("leadr colormap");
    return c;
}

std::shared_ptr<Material> make_leadr(const Properties &p) {
    LeadrParams lp;
    const bool has_stats = p.has("covariance") || p.has("heightmap");
    lp.source = SlopeSource::parse(p);
    lp.alpha = p.get_float("alpha", has_stats ? 0.f : 0.3f);
    if (!(lp.alpha >= 0.0) || !(lp.alpha <= 1e3)) p.fail("alpha", "expected a roughness in [0, 1000]");
    lp.base_variance = 0.5 * lp.alpha * lp.alpha;
    lp.conductor = p.get_string("material", "none");
    if (lp.conductor != "none" && !conductor_preset(lp.conductor, lp.eta, lp.k)) {
        const std::string known = conductor_preset_list();
        p.fail("material", fmt::format("unknown conductor '{}' (known: {})", lp.conductor, known));
    }
    lp.ks = p.get_texture("specular_reflectance", Spectrum(1.f));
    lp.kd = p.get_texture("diffuse_reflectance", Spectrum(0.f));
    auto is_zero = [](const Texture &t) { return t.is_constant() && t.mean().max() <= 0.f; };
    lp.has_spec = !is_zero(*lp.ks);
    lp.has_diffuse = !is_zero(*lp.kd);
    if (!lp.has_spec && !lp.has_diffuse) lp.has_spec = true;  // black, but still a (glossy) reflector
    lp.rational = p.get_bool("rational_lambda", false);
    lp.shadowing = parse_shadowing(p);
    lp.diffuse_n = parse_grid(p, "diffuse_quadrature", 12);
    lp.env_spec.n = parse_grid(p, "env_quadrature", 8);
    lp.env_diff.n = parse_grid(p, "env_diffuse_quadrature", 5);
    lp.env_diff.irradiance = p.get_enum<LeadrIrradiance>("env_irradiance", "shadowed",
                                                         {{"shadowed", LeadrIrradiance::Shadowed},
                                                          {"paper", LeadrIrradiance::Paper},
                                                          {"gaussian", LeadrIrradiance::Gaussian}});
    if (p.has("colormap")) {
        if (p.raw("colormap").is_array()) {
            for (const Properties &c : p.children("colormap")) lp.cmaps.push_back(parse_colormap(c, lp.source));
            if (lp.cmaps.empty()) p.fail("colormap", "expected at least one colour map");
        } else {
            lp.cmaps.push_back(parse_colormap(p.child("colormap"), lp.source));
        }
        lp.cmap_product = p.get_enum<bool>("colormap_combine", "sum", {{"sum", false}, {"product", true}});
    } else if (p.has("colormap_combine")) {
        p.fail("colormap_combine", "only meaningful with \"colormap\"");
    }
    for (LeadrEnvOptions *o : {&lp.env_spec, &lp.env_diff}) {
        o->shadowing = lp.shadowing;
        o->rational_lambda = lp.rational;
    }
    return std::make_shared<Leadr>(std::move(lp));
}

MESO_REGISTER_MATERIAL("leadr",
                       "LEADR specular + diffuse microfacets: Gaussian slopes with mean and covariance, constant or "
                       "from a heightmap (paper 000)",
                       [](const Properties &p) -> std::shared_ptr<Material> { return make_leadr(p); });

}  // namespace
}  // namespace meso
