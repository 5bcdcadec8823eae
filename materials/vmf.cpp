// `vmf`: joint MIP-mapping of BRDF and normal maps with vMF mixtures (paper 002, Xu et al.
// 2017). Each texel's effective specular BRDF is a mixture of vMF lobes of half vectors
// (the base BRDF convolved with the texel's NDF lobe, rotated by its normal); at a shading
// point the lobes under the ray-differential footprint are averaged through their
// characteristic vectors per cell of the sphere (texture/vmf_map.h: 1×1, 1×4, 2×4 and the
// adaptive choice of Algorithm 1), or filtered by a baseline method (`mode`).
//
// Model (local frame, z = the shading normal; wo, wi above it, h = (wo + wi)/|wo + wi|)
//   f cos θi = kd/π cos θi + Fs(wo·h) · Σ_j w_j G_j γ(h; μ_j, κ_j) / (4 wo·h)
// γ is the normalised vMF density of half vectors (eq. 6; render/vmf.h) and 1/(4 wo·h) the
// Jacobian dω_h/dω_i of reflection: the paper's ρ(ω_h) (which "includes the cosine") is a
// density of half vectors, and this is the BRDF whose cosine-weighted value is exactly the
// density of wi = reflect(wo, h) for h ~ Σ w_j γ_j — so the filtered BRDF is linear in the
// lobes as eq. 5 requires, the albedo is <= Σ w_j <= 1 and sampling is exact. Lobe mass on
// half vectors facing away from wo or reflecting wo below the surface is absorbed. Not
// reciprocal (f · cos θi is symmetric, f is not), like normal mapping.
//   Fs: "none" → ks; "schlick" → ks + (1 − ks)(1 − wo·h)^5 (ks = F0); a conductor preset →
//   ks · F_conductor(wo·h). G_j ("shadowing": "smith") = 1/(1 + Λ(wo) + Λ(wi)) with Λ of the
//   lobe's equivalent non-centred Gaussian slopes (vmf_lobe_slopes, render/slope_distribution);
//   "none" (default, as the paper): G = 1.
//   LEAN mode: one Gaussian of half-vector slopes, γ replaced by its density D(h) h.z.
// Sampling: diffuse (cosine) or specular with probability ∝ average(kd) : average(ks)
// (schlick: at least 0.25 for the specular lobe); specular: lobe j ∝ w_j, h ~ γ_j (stable
// vMF sampling), wi = reflect(wo, h); fails where wo·h <= 0 or wi.z <= 0. pdf = the mixture.
//
// Texels (the "instant BRDF map", §4). Normal n and its NDF lobe κ_N; base BRDF either a
// Blinn-Phong power s (one lobe along n, κ = s' + 1 with s' = κ_N s / (κ_N + s), eq. 11–14)
// or listed vMF lobes (μ in the texel's frame (s', t', n), κ convolved with the NDF:
// κ κ_N / (κ + κ_N)); each lobe → r = ‖r‖(κ) μ (eq. 8–9, exact root or the paper's
// 1024-entry table). All maps are resampled to the normal map's grid (texture values at its
// texel centres, uv in [0, 1]); without a normal map the grid is `resolution`.
//
// Parameters
//   name            type               default    notes
//   mode            string             adaptive   adaptive | single (1×1) | 1x4 | 2x4 | naive (average of μ, κ) |
//                                                 lean (slope moments) | direct (finest texel, no filtering)
//   epsilon0        float              0.95       Algorithm 1 threshold on ‖r‖ of the 1×1 lobe
//   epsilon1        float              0.85       threshold on ‖r‖ of each 1×4 lobe
//   r_solver        string             exact      exact (cubic root) | table (1024 entries, §4)
//   normals         string             -          tangent-space normal map (texture/normal_source.h)
//   heightmap       object             -          displacement-style block: per-texel average normals
//   uv_length       [Lu, Lv]           [1, 1]     heightmap only
//   tiling          number | [u, v]    1          repeats of the map over uv [0, 1] (inside "heightmap" for heightmaps)
//   filter          string             trilinear  trilinear | ewa | none (level 0 bilinear)
//   max_anisotropy  float              8          ewa only
//   resolution      [w, h]             [1, 1]     grid without a normal map
//   ndf_kappa       texture | "auto"   none       NDF lobe κ_N per texel; "auto": from the length of the
//                                                 heightmap's average normal (eq. 8); absent: no NDF
//   exponent        texture            100        Blinn-Phong power s >= 0 (not with lobes)
//   lobes           [{direction, kappa, weight}]  base BRDF as vMF lobes of half vectors (<= 8): direction in
//                                                 the texel frame (z = normal), [x, y, z] or a texture whose RGB is
//                                                 x, y, z (a BRDF map of lobes: values as stored, renormalised per
//                                                 texel, so use float images); kappa a texture >= 0; weight > 0
//                                                 (normalised to sum 1)
//   diffuse         texture            0          kd (linearly filtered by the texture itself)
//   specular        texture            1          ks
//   fresnel         string             none       none | schlick | conductor preset (Ag, Al, Au, Cr, Cu, Ni, W)
//   shadowing       string             none       none | smith
#include <cmath>
#include <fmt/format.h>
#include <memory>
#include <optional>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "bsdf/fresnel.h"
#include "bsdf/material.h"
#include "bsdf/slope_distribution.h"
#include "texture/texture.h"
#include "filter/vmf.h"
#include "sampling/warp.h"
#include "core/properties.h"
#include "core/registry.h"
#include "texture/normal_source.h"
#include "texture/vmf_map.h"

namespace meso {
namespace {

enum class FresnelKind { None, Schlick, Conductor };

struct BaseLobe {
    std::shared_ptr<Texture> dir;  ///< RGB = the direction's x, y, z (renormalised per texel)
    std::shared_ptr<Texture> kappa;
    double weight = 1.0;
};

class Vmf final : public Material {
public:
    struct Config {
        std::optional<NormalSource> normals;  ///< absent: constant normal, own grid
        float tu = 1.f, tv = 1.f;             ///< tiling without a normal map
        FootprintFilter filter = FootprintFilter::Trilinear;
        float max_aniso = 8.f;
        std::shared_ptr<VmfMap> map;
        std::shared_ptr<Texture> kd, ks;
        FresnelKind fresnel = FresnelKind::None;
        std::string conductor;
        Spectrum eta, k;
        bool smith = false;
        std::string desc;
    };

    explicit Vmf(Config c) : m(std::move(c)) {}

    uint32_t flags() const override {
        return BSDF_GlossyReflection | (m.kd->is_constant() && m.kd->mean().max() == 0.f ? 0u : BSDF_DiffuseReflection);
    }
    bool is_reciprocal() const override { return false; }

    Spectrum eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        if (!(wo.z > 0.f) || !(wi.z > 0.f)) return Spectrum(0.f);
        const State s = state(ctx);
        Spectrum v = s.kd * (wi.z * InvPi);
        const Vec3 h = half(wo, wi);
        const float d = dot(wo, h);
        if (d > 0.f) v += fresnel(s, d) * float(spec_density(s, h, wo, wi, true) / (4.0 * d));
        return v;
    }

    float pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        if (!(wo.z > 0.f) || !(wi.z > 0.f)) return 0.f;
        const State s = state(ctx);
        return pdf_of(s, wo, wi);
    }

    bool sample(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, BSDFSample &out) const override {
        if (!(wo.z > 0.f)) return false;
        const State s = state(ctx);
        Vec3 wi;
        if (u_lobe < s.p_spec) {
            const float ul = u_lobe / s.p_spec;
            Vec3 h;
            if (s.look.gaussian) {
                h = GaussianSlopes(s.look.slopes).sample_normal(u);
            } else {
                if (!(s.wsum > 0.0)) return false;
                double acc = 0.0, target = double(ul) * s.wsum;
                int j = 0;
                for (; j < s.look.count - 1; ++j) {
                    acc += s.look.lobes[j].weight;
                    if (target < acc) break;
                }
                h = vmf::sample(s.look.lobes[j].mu, s.look.lobes[j].kappa, u);
            }
            const float d = dot(wo, h);
            if (!(d > 0.f)) return false;
            wi = normalize(h * (2.f * d) - wo);
            out.flags = BSDF_GlossyReflection;
        } else {
            wi = square_to_cosine_hemisphere(u);
            out.flags = BSDF_DiffuseReflection;
        }
        if (!(wi.z > 0.f)) return false;
        // The weight in double precision: at κ ~ 1e9 the density of a float direction can be
        // denormal in float, and a float ratio of denormals is not eval / pdf.
        const Vec3 h = half(wo, wi);
        const float d = dot(wo, h);
        double dens = 0.0, dens_g = 0.0;
        if (d > 0.f) {
            dens = spec_density(s, h, wo, wi, false);
            dens_g = m.smith ? spec_density(s, h, wo, wi, true) : dens;
        }
        const double pd = pdf_from(s, wi.z, d, dens);
        if (!(pd > 1e-30) || !std::isfinite(pd)) return false;
        const float p = float(pd);
        Spectrum v = s.kd * float(wi.z * InvPi / pd);
        if (d > 0.f) v += fresnel(s, d) * float(dens_g / (4.0 * d) / pd);
        out.wi = wi;
        out.pdf = p;
        out.weight = v;
        out.eta = 1.f;
        return true;
    }

    Spectrum albedo_hint(const ShadingContext &ctx) const override { return m.kd->eval(ctx) + m.ks->eval(ctx); }

    std::string to_string() const override { return m.desc; }

private:
    struct State {
        VmfLookup look;
        double wsum = 0.0;
        Spectrum kd, ks;
        float p_spec = 1.f;
    };

    static Vec3 half(const Vec3 &wo, const Vec3 &wi) {
        const Vec3 h = wo + wi;
        const float l = length(h);
        return l > 0.f ? h / l : Vec3(0.f, 0.f, 1.f);
    }

    State state(const ShadingContext &ctx) const {
        State s;
        const float tu = m.normals ? m.normals->tiling_u() : m.tu, tv = m.normals ? m.normals->tiling_v() : m.tv;
        m.map->lookup(m.filter, ctx.uv.x * tu, ctx.uv.y * tv, ctx.dudx * tu, ctx.dudy * tu, ctx.dvdx * tv,
                      ctx.dvdy * tv, m.max_aniso, s.look);
        if (m.normals) {
            // Map frame -> local frame (sign flips only).
            const Vec3 sg = m.normals->to_local(ctx, Vec3(1.f, 1.f, 1.f));
            for (int j = 0; j < s.look.count; ++j) s.look.lobes[j].mu = m.normals->to_local(ctx, s.look.lobes[j].mu);
            if (s.look.gaussian) {
                s.look.slopes.mx *= sg.x;
                s.look.slopes.my *= sg.y;
                s.look.slopes.sxy *= sg.x * sg.y;
            }
        }
        for (int j = 0; j < s.look.count; ++j) s.wsum += s.look.lobes[j].weight;
        if (s.look.gaussian) s.wsum = 1.0;
        s.kd = m.kd->eval(ctx);
        s.ks = m.ks->eval(ctx);
        const float a_d = std::max(0.f, s.kd.average());
        float a_s = std::max(0.f, s.ks.average());
        if (m.fresnel == FresnelKind::Schlick) a_s = std::max(a_s, 0.25f);
        if (!(s.wsum > 0.0)) a_s = 0.f;
        s.p_spec = a_d + a_s > 0.f ? a_s / (a_d + a_s) : 1.f;
        return s;
    }

    Spectrum fresnel(const State &s, float d) const {
        switch (m.fresnel) {
            case FresnelKind::Schlick: {
                const float c = std::pow(std::max(0.f, 1.f - d), 5.f);
                return s.ks + (Spectrum(1.f) - s.ks) * c;
            }
            case FresnelKind::Conductor: return s.ks * fresnel_conductor(d, m.eta, m.k);
            default: return s.ks;
        }
    }

    /// Σ_j w_j (G_j) density_j(h); with_g = false: the sampling density (no G).
    double spec_density(const State &s, const Vec3 &h, const Vec3 &wo, const Vec3 &wi, bool with_g) const {
        if (s.look.gaussian) {
            const GaussianSlopes g(s.look.slopes);
            double v = g.pdf_normal(h);
            if (with_g && m.smith) v /= 1.0 + g.lambda(wo) + g.lambda(wi);
            return v;
        }
        double v = 0.0;
        for (int j = 0; j < s.look.count; ++j) {
            const VmfLobe &L = s.look.lobes[j];
            double t = L.weight * vmf::pdf(L.mu, L.kappa, h);
            if (with_g && m.smith && t > 0.0) {
                const GaussianSlopes g(vmf_lobe_slopes(L.mu, L.kappa));
                t /= 1.0 + g.lambda(wo) + g.lambda(wi);
            }
            v += t;
        }
        return v;
    }

    float pdf_of(const State &s, const Vec3 &wo, const Vec3 &wi) const {
        const Vec3 h = half(wo, wi);
        const float d = dot(wo, h);
        const double dens = d > 0.f && s.p_spec > 0.f && s.wsum > 0.0 ? spec_density(s, h, wo, wi, false) : 0.0;
        const double p = pdf_from(s, wi.z, d, dens);
        return p > 1e-30 ? float(p) : 0.f;
    }

    /// The mixture pdf from the specular sampling density Σ w_j γ_j(h) (no G).
    static double pdf_from(const State &s, float cos_i, float d, double dens) {
        double p = (1.0 - s.p_spec) * cos_i * InvPi;
        if (d > 0.f && s.p_spec > 0.f && s.wsum > 0.0) p += s.p_spec * dens / s.wsum / (4.0 * d);
        return p;
    }

    Config m;
};

/// Algorithm 1's mode and thresholds, and the ‖r‖ → κ solver (§4).
VmfMap::Params parse_map_params(const Properties &p) {
    VmfMap::Params params;
    params.mode = p.get_enum<VmfMode>("mode", "adaptive",
                                      {{"adaptive", VmfMode::Adaptive}, {"single", VmfMode::Single},
                                       {"1x1", VmfMode::Single}, {"1x4", VmfMode::Four}, {"2x4", VmfMode::Eight},
                                       {"naive", VmfMode::Naive}, {"lean", VmfMode::Lean}, {"direct", VmfMode::Direct}});
    params.eps0 = p.get_float("epsilon0", 0.95f);
    params.eps1 = p.get_float("epsilon1", 0.85f);
    for (const char *k : {"epsilon0", "epsilon1"}) {
        const double e = k[7] == '0' ? params.eps0 : params.eps1;
        if (!(e >= 0.0 && e <= 1.0)) p.fail(k, "expected a threshold on ||r|| in [0, 1]");
    }
    params.r_table = p.get_choice("r_solver", "exact", {"exact", "table"}) == "table";
    return params;
}

/// The texels' inputs to the instant BRDF map (§4), on the gw × gh grid.
struct TexelInputs {
    int gw = 1, gh = 1;
    std::vector<float> normals;        ///< level-0 average normals (3 per texel) when a map is given
    std::shared_ptr<Texture> ndf;      ///< κ_N per texel (absent: no NDF lobe)
    bool ndf_auto = false;             ///< κ_N from the length of the average normal (eq. 8)
    std::vector<BaseLobe> base;        ///< base BRDF as vMF lobes (weights normalised) ...
    std::shared_ptr<Texture> exponent; ///< ... or a Blinn-Phong power s
};

/// The grid: the normal map's (`normals` or `heightmap`), or `resolution` with its own
/// tiling and footprint filter.
void parse_grid(const Properties &p, Vmf::Config &c, TexelInputs &t) {
    if (p.has("normals") || p.has("heightmap")) {
        if (p.has("resolution")) p.fail("resolution", "the grid is the normal map's; give no resolution with a map");
        c.normals = NormalSource::parse(p, "normal", /*unit_constant=*/true, /*allow_heightmap=*/true);
        const MipMap *mip = c.normals->mip();
        t.gw = mip->width(0), t.gh = mip->height(0);
        t.normals.resize(size_t(t.gw) * t.gh * 3);
        for (int y = 0; y < t.gh; ++y)
            for (int x = 0; x < t.gw; ++x)
                for (int k = 0; k < 3; ++k) t.normals[(size_t(y) * t.gw + x) * 3 + k] = mip->texel(0, x, y)[k];
        c.filter = c.normals->filter();
        c.max_aniso = c.normals->max_anisotropy();
        return;
    }
    if (p.has("uv_length")) p.fail("uv_length", "only meaningful with a \"heightmap\"");
    if (p.has("resolution")) {
        const std::vector<float> r = p.get_floats("resolution");
        if (r.size() != 2 || !(r[0] >= 1.f && r[0] <= 16384.f) || !(r[1] >= 1.f && r[1] <= 16384.f) ||
            r[0] != std::floor(r[0]) || r[1] != std::floor(r[1]))
            p.fail("resolution", "expected [width, height], integers in [1, 16384]");
        t.gw = int(r[0]), t.gh = int(r[1]);
    }
    if (p.has("tiling")) std::tie(c.tu, c.tv) = p.get_tiling();
    c.filter = parse_footprint_filter(p, "filter");
    c.max_aniso = p.get_float("max_anisotropy", 8.f, Range::at_least(1.0));
}

/// The NDF lobe κ_N: a texture, or "auto" from a heightmap's average normals.
void parse_ndf(const Properties &p, const Vmf::Config &c, TexelInputs &t) {
    if (!p.has("ndf_kappa")) return;
    if (p.raw("ndf_kappa").is_string() && p.raw("ndf_kappa").get<std::string>() == "auto") {
        if (!c.normals || c.normals->space() != NormalSource::Space::UV)
            p.fail("ndf_kappa", "\"auto\" derives kappa_N from a heightmap's average normals; give a heightmap");
        t.ndf_auto = true;
    } else {
        t.ndf = p.get_texture("ndf_kappa");
    }
}

/// `lobes`: 1 to kMaxTexelLobes vMF lobes of half vectors, weights normalised to sum 1.
std::vector<BaseLobe> parse_lobes(const Properties &p) {
    const std::vector<Properties> lp = p.children("lobes");
    if (lp.empty() || lp.size() > size_t(kMaxTexelLobes)) p.fail("lobes", "expected 1 to 8 lobes");
    std::vector<BaseLobe> base;
    double wsum = 0.0;
    for (const Properties &l : lp) {
        BaseLobe b;
        b.dir = l.get_texture("direction");
        if (b.dir->is_constant()) {
            const Spectrum d = b.dir->mean();
            const float len = length(Vec3(d.r, d.g, d.b));
            if (!(len > 0.f) || !std::isfinite(len))
                l.fail("direction", "expected a non-zero, finite [x, y, z] (or a texture of directions)");
        }
        b.kappa = l.get_texture("kappa");
        b.weight = l.get_float("weight", 1.f);
        if (!(b.weight > 0.0) || !std::isfinite(b.weight)) l.fail("weight", "expected a positive, finite weight");
        if (b.kappa->is_constant()) {
            const float k = b.kappa->mean().average();
            if (!(k >= 0.f) || !std::isfinite(k)) l.fail("kappa", "expected a finite concentration >= 0");
        }
        l.check_unused("vmf lobe");
        wsum += b.weight;
        base.push_back(b);
    }
    for (BaseLobe &b : base) b.weight /= wsum;
    return base;
}

/// The base BRDF: `lobes` or a Blinn-Phong `exponent` (not both).
void parse_base_brdf(const Properties &p, TexelInputs &t) {
    if (p.has("lobes")) {
        if (p.has("exponent")) p.fail("exponent", "give either \"exponent\" (Blinn-Phong) or \"lobes\", not both");
        t.base = parse_lobes(p);
    } else {
        t.exponent = p.get_texture("exponent", Spectrum(100.f));
        if (t.exponent->is_constant()) {
            const float s = t.exponent->mean().average();
            if (!(s >= 0.f) || !std::isfinite(s)) p.fail("exponent", "expected a finite Blinn-Phong power >= 0");
        }
    }
}

/// kd, ks, the Fresnel factor Fs and the shadowing G of the model above.
void parse_shading(const Properties &p, Vmf::Config &c) {
    c.kd = p.get_texture("diffuse", Spectrum(0.f));
    c.ks = p.get_texture("specular", Spectrum(1.f));
    std::vector<std::string> fresnels = {"none", "schlick"};
    for (const std::string &n : conductor_preset_names())
        if (n != "none") fresnels.push_back(n);
    const std::string fr = p.get_choice("fresnel", "none", fresnels);
    if (fr == "none") {
        c.fresnel = FresnelKind::None;
    } else if (fr == "schlick") {
        c.fresnel = FresnelKind::Schlick;
    } else {
        conductor_preset(fr, c.eta, c.k);  // one of conductor_preset_names(): known
        c.fresnel = FresnelKind::Conductor;
        c.conductor = fr;
    }
    c.smith = p.get_choice("shadowing", "none", {"none", "smith"}) == "smith";
}

/// Blinn-Phong base BRDF: one lobe along the texel normal n. The power s convolved with
/// the NDF lobe, s' = κ_N s / (κ_N + s) (eq. 13), is the lobe's κ = s' + 1 (eq. 14).
void blinn_phong_lobe(double s, double kappa_n, const Vec3 &n, VmfLobe &out) {
    s = std::isfinite(s) && s > 0.0 ? s : 0.0;
    const double sp = std::isinf(kappa_n) ? s : (kappa_n + s > 0.0 ? kappa_n * s / (kappa_n + s) : 0.0);  // eq. 13
    out.mu = n;
    out.kappa = std::min(sp + 1.0, vmf::kMaxKappa);  // eq. 14
    out.weight = 1.0;
}

/// The lobes of texel (x, y): its normal n and NDF lobe κ_N, then the base BRDF rotated
/// into the texel frame with κ convolved with κ_N. Returns the number of lobes.
int texel_lobes(const TexelInputs &t, int x, int y, VmfLobe *out) {
    ShadingContext tc;
    tc.uv = Vec2((x + 0.5f) / t.gw, (y + 0.5f) / t.gh);
    Vec3 n(0.f, 0.f, 1.f);
    double kn = INFINITY;
    if (!t.normals.empty()) {
        const float *a3 = &t.normals[(size_t(y) * t.gw + x) * 3];
        const Vec3 a(a3[0], a3[1], a3[2]);
        const float l = length(a);
        if (l > 1e-20f && std::isfinite(l)) n = a / l;
        if (t.ndf_auto) kn = vmf::kappa_from_r(l);
    }
    if (t.ndf) {
        const double v = t.ndf->eval_float(tc);
        kn = v >= 0.0 ? v : 0.0;
    }
    if (t.base.empty()) {
        blinn_phong_lobe(t.exponent->eval_float(tc), kn, n, out[0]);
        return 1;
    }
    const Frame F = n.z > 0.9999999f ? Frame(Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1)) : perturbed_frame(n);
    for (size_t i = 0; i < t.base.size(); ++i) {
        double k = t.base[i].kappa->eval_float(tc);
        k = std::isfinite(k) && k > 0.0 ? k : (std::isinf(k) ? vmf::kMaxKappa : 0.0);
        const Spectrum dv = t.base[i].dir->eval(tc);
        Vec3 d(dv.r, dv.g, dv.b);
        const float dl = length(d);
        d = dl > 0.f && std::isfinite(dl) ? d / dl : Vec3(0.f, 0.f, 1.f);
        out[i].mu = normalize(F.to_world(d));
        out[i].kappa = std::min(vmf::convolve_kappa(k, kn), vmf::kMaxKappa);
        out[i].weight = t.base[i].weight;
    }
    return int(t.base.size());
}

std::shared_ptr<Material> make_vmf(const Properties &p) {
    Vmf::Config c;
    const VmfMap::Params params = parse_map_params(p);
    TexelInputs t;
    parse_grid(p, c, t);
    parse_ndf(p, c, t);
    parse_base_brdf(p, t);
    if (t.ndf && t.ndf->is_constant()) {
        const float k = t.ndf->mean().average();
        if (!(k >= 0.f)) p.fail("ndf_kappa", "expected kappa_N >= 0 (or \"auto\")");
    }
    parse_shading(p, c);

    // The instant BRDF map.
    const int per_texel = t.base.empty() ? 1 : int(t.base.size());
    try {
        c.map = std::make_shared<VmfMap>(
            t.gw, t.gh, per_texel, [&](int x, int y, VmfLobe *out) { return texel_lobes(t, x, y, out); }, params);
    } catch (const MesoError &e) {
        p.fail(e.what());
    }
    static const char *modes[] = {"direct", "naive", "1x1", "1x4", "2x4", "adaptive", "lean"};
    c.desc = fmt::format("vmf[{} {}, {}x{} texels x {} lobe(s), {:.1f} MB{}]", modes[int(params.mode)],
                         c.normals ? c.normals->to_string() : std::string("constant normal"), t.gw, t.gh, per_texel,
                         c.map->memory_bytes() / 1048576.0, c.smith ? ", smith" : "");
    return std::make_shared<Vmf>(std::move(c));
}

MESO_REGISTER_MATERIAL("vmf", "vMF-mixture BRDF MIP-mapping of BRDF and normal maps (paper 002)",
                       [](const Properties &p) -> std::shared_ptr<Material> { return make_vmf(p); });

}  // namespace
}  // namespace meso
