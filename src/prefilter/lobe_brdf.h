// The closed-form per-lobe f'_low ("--flow lobes"): a cheap deterministic stand-in for the
// quadrature of paper 004's eq. 5 (prefilter/multilobe_brdf.h), for the `prefiltered` material's
// cost target (issue 21 item 3: eval + sample + pdf at most 1.5x the base's).
//
// Why an approximation is allowed. The scaling tables are ratios R = f_eff(original) /
// f_eff(h_low, f'_low) (prefilter/scaling.h): when `meso prefilter` fits T and S with THIS f'_low,
// and the renderer shades with the same f'_low, the approximation is part of the model and is
// absorbed by T and S like eq. 5's own modelling error. The form is therefore recorded in the
// model (manifest parameters.flow = "lobes") and the renderer refuses to mix forms.
//
// The form. Each vMF lobe j of the patch NDF (mean μ_j, concentration κ_j, weight a_j, amplitude
// A; patch_ndf.h) convolved with the base gives ONE base-like lobe in the frame of μ_j:
//
//   eval(ωo, ωi) = Σ_j w_j(ωo) g_j(ωo, ωi)
//
// with w_j(ωo) lobe j's share of the projected area seen from ωo (the visible form, below). Models
// made before it (no parameters.lambert_view / microfacet_view in the manifest) keep the weights
// they were fitted with: c_j = A a_j H(μ_j,z, κ_j) for microfacet lobes, with
// H(t, κ) = ∫ γ(ω; μ, κ) [ω·n > 0] dω for t = μ·n (the lobe's mass above a plane; here the macro
// horizon, which eq. 4 cuts off), so that Σ_j c_j is the limit of eq. 5's node weights.
//
// * Microfacet base (rough conductor, Beckmann or GGX, isotropic): the base's D and Smith G in
//   the frame of μ_j with the roughness widened by the lobe's spread. Derivation: for small
//   angles a vMF lobe is a Gaussian in the tangent-plane angle, γ ∝ exp(κ cos θ) ≈ e^κ
//   exp(−κ θ²/2), variance 1/κ per axis; Beckmann's D ∝ exp(−|s|²/α²) is a Gaussian in slope s
//   (≈ angle) with variance α²/2 per axis. The micro-normal of the base is tilted by the lobe's
//   normal, so the variances add: α'²/2 = α²/2 + 1/κ, i.e.
//       α'² = α² + 2/κ                                           (widened_alpha)
//   (not 1/(2κ): that is the spread of REFLECTED directions, twice the normal's angle). κ → ∞
//   gives the base (α' = α). κ → 0 (a uniform sphere of normals) would give α' → ∞, whose Beckmann
//   lobe puts its mass at the horizon and reflects almost nothing (0.22 of eq. 5 at κ = 0.3); the
//   widening stops at kMaxWidenedAlpha = 1 instead, where GGX's D is exactly the uniform 1/π and
//   Beckmann's matches it at the pole (a base rougher than that keeps its own α). GGX uses the
//   same α' (GGX's slope variance is infinite; α is its core width).
//       g_j = F(ωi·h) D_α'(h; μ_j) G_α'(ωo, ωi; μ_j) / (4 μ_j·ωo)       (μ_j·ωo, μ_j·ωi, μ_j·h > 0)
//   h = normalize(ωo + ωi) is frame-independent, so the Fresnel term F(ωi·h) (times the base's
//   specular_reflectance) is evaluated ONCE per (ωo, ωi), from a 64-entry table probed from the
//   base material itself at construction. G is the height-correlated Smith 1/(1 + Λ(ωo) + Λ(ωi))
//   of microfacet.h, with Walter et al. 2007's rational Λ for Beckmann (no erf) and the exact Λ
//   for GGX (one sqrt). The lobes are summed with the Lambertian form's view weights w_j(ωo) below
//   (the facing lobes' shares of the projected area seen from ωo, times Σ_k c_k = 1):
//       eval = Σ_j w_j(ωo) g_j,   w_j over the lobes with μ_j·ωo > 0 (g_j needs them)
//   Why: the radiance of a patch is its facets' radiance averaged over their projected area
//   towards the viewer; g_j is the radiance of lobe j's facets, so lobe j's weight is its share of
//   that area (Heitz 2014's D_ωo). The form before (models without parameters.microfacet_view,
//   which keep it) weighted lobe j by its area A a_j H(μ_j,z, κ_j) whatever ωo: 1 / cos(tilt) for
//   a tilted flat patch. At levels whose h_low keeps the tilt (the held-out copper's x4, x8: its
//   bumps are 4-5 coarse cells wide), h_low's facet adds its own projected-area weight, so every
//   patch came out 1 / cos(its tilt) too bright: a factor that changes from patch to patch at one
//   (ωi, ωo), which no angular S can remove (the pixel-scale bias of issue 21 on that scene; tests/
//   test_prefiltered_bias.cpp: 1.054 and 1.41 on facets tilted 18° and 45°, 1.00 now).
// * Lambertian base (`diffuse`, any reflectance texture, read through the base's own eval):
//       eval = ρ̄/π · Σ_j w_j(ωo) C(μ_j·ωi, κ_j),   w_j(ωo) = c_j v_j(ωo) / Σ_k c_k v_k(ωo) · Σ_k c_k,
//       c_j = A a_j C(μ_j,z, κ_j),   v_j(ωo) = C(μ_j·ωo, κ_j) / C(μ_j,z, κ_j)
//   i.e. the lobes weighted by their projected area towards the viewer, A a_j C(μ_j·ωo, κ_j) =
//   ∫ D_j(m) max(0, m·ωo) dm, normalised (the visible normals' distribution, D_ωo of Heitz 2014:
//   Σ_j w_j = Σ_j c_j, 1 for a normalised NDF), each lobe then the vMF-convolved clamped cosine
//   towards ωi. Continuous in ωo where a facet turns away from the viewer: its weight goes to 0
//   with its projected area. The form before (models without parameters.lambert_view, which keep
//   it: their tables were fitted to it) weighted lobe j by min(H(μ_j,z, κ_j), H(μ_j·ωo, κ_j)), a
//   STEP at μ_j·ωo = 0 for the sharp lobes of flat facets; S = original / f'_low then jumped there
//   (0.8 to 3.4 within one bin on the bench sawtooth), and S read between bin centres across the
//   step put energy into the neighbouring bins that the fit never put there: θo rings of the
//   bench sawtooth ±10% off their fitted energy, the render 1.2-2.3% too bright under the sky
//   (docs/performance.md; tests/test_prefiltered_bias.cpp against brute force of the original).
//   ρ̄ is the base's reflectance AVERAGED over the patch (uv area; patch_mean_lambert, computed
//   once at construction), not its value at the shading point: like the NDF, the albedo is
//   prefiltered over the patch. The point value put the map's sub-patch colour detail back into
//   every shading sample, uncorrelated with the lobes: on the bench `sawtooth` (red and blue
//   facets a texel wide, a patch of 32 x 32 texels) under the sky, ours' pixel variance per
//   sample was 1.65x the full-resolution original's; with ρ̄, 0.3x. The mean is unchanged for
//   tables fitted either way: T and S are ratios over bins of whole patches, and f'_low is
//   linear in ρ, so a bin's f_eff(h_low, f'_low) sees the same mean albedo — exactly where h_low is
//   flat over a patch, not quite at fine levels (the bench sawtooth's chain, a model fitted to
//   the point value and shaded with the mean: +3% in its near rows). So the manifest records it
//   (parameters.albedo = "patch_mean"), and models made before keep the point value.
//   C(t, κ) = ∫ γ(ω; μ, κ) max(0, ω·ωi) dω (t = μ·ωi) is the vMF-convolved clamped cosine,
//   exactly what eq. 5 gives for the ωi side; eq. 5's viewer cut [ω·ωo > 0] becomes the weight by
//   m·ωo (0.96-1.03 of eq. 5 for κ >= 30, 0.38 at κ = 0, where eq. 5 counts every normal facing
//   ωo at full weight: T and S absorb it). C and H are tabulated (vmf_clamped_cosine, vmf_cap_mass).
//
// Sampling: lobe j with probability P_j(ωo) = c_j v_j(ωo) / Σ_k c_k v_k(ωo) (v_j(ωo) above, and
// [μ_j·ωo > 0] for microfacet lobes: times v_j in the visible form, alone in the area form), then
//   microfacet: the FULL NDF D_α'(m; μ_j)(m·μ_j) in the frame of μ_j (closed form, no inverted
//     CDF), ωi = reflect(ωo, m); density D (m·μ_j) / (4 ωo·m) where μ_j·ωi > 0;
//   Lambertian: exactly the lobe's own C: t = μ_j·ωi drawn with density C(t, κ_j) / ∫C from the
//     bilinear C table itself (a mixture of its two rows, each piecewise linear in t: a column
//     from the row's CDF, then the inverted quadratic within it), the azimuth about μ_j uniform;
//     density C(μ_j·ωi, κ_j) / (2π ∫C dt) (≈ C / π, the density of "a normal from the lobe,
//     then a cosine-weighted direction about it"). With one lobe, weight = eval / pdf is then
//     constant in ωi; the vMF stand-in of the clamped cosine used before (κ_c = 2.133) left a
//     relative spread of 0.1–0.39 in the weight. Support: wherever C > 0, i.e. wherever eval > 0.
// Directions below the macro horizon fail (sample returns false). pdf is the exact density of
// that procedure (the mixture over j), so the χ² test holds and weight = eval / pdf exactly.
//
// Not reciprocal (neither is eq. 5). Cost: one pass over the patch's lobes (≤ 6 by default; the
// microfacet pass four lobes per SSE step, one vector exp for Beckmann), the Fresnel lookup once;
// sample adds one pass for the choice and one eval_pdf pass at the sampled direction. Measured
// (docs/performance.md): a `prefiltered` shading sample costs 0.9x a Beckmann conductor base's,
// 1.9x a GGX one's (the S lookups are most of the rest), 26x a Lambertian's.
#pragma once
#include <memory>
#include <string>
#include <vector>
#include <nlohmann/json_fwd.hpp>
#include "bsdf/material.h"
#include "bsdf/microfacet.h"
#include "prefilter/patch_ndf.h"

namespace meso::prefilter {

/// Strata per tile axis of the patch-mean albedo of a Lambertian base (see the header).
constexpr int kAlbedoStrataPerTile = 1024;
/// Where widening stops (κ → 0): GGX with α = 1 is the uniform NDF D = 1/π.
constexpr double kMaxWidenedAlpha = 1.0;
/// α' = sqrt(α² + 2/κ) (see the header), at most max(α, kMaxWidenedAlpha); κ = 0 and κ = ∞ allowed.
double widened_alpha(double alpha, double kappa);
/// C(t, κ) = ∫ γ(ω; μ, κ) max(0, ω·n) dω for t = μ·n ∈ [−1, 1], κ ∈ [0, ∞]: bilinear in a table
/// of vmf_projected_area (exact at κ = 0: 1/4, and κ = ∞: max(0, t)).
float vmf_clamped_cosine(float t, double kappa);
/// H(t, κ) = ∫ γ(ω; μ, κ) [ω·n > 0] dω for t = μ·n: bilinear in a table (exact at κ = 0: 1/2,
/// κ = ∞: the step at t = 0, ramped over one table cell).
float vmf_cap_mass(float t, double kappa);
/// (The exact values are vmf_projected_area and vmf_cap_mass of patch_ndf.h at μ = (sqrt(1 − t²), 0, t).)

/// The base material as the lobes form uses it.
struct LobeBase {
    enum class Kind { Lambertian, Microfacet };
    Kind kind = Kind::Lambertian;
    MicrofacetType type = MicrofacetType::Beckmann;
    double alpha = 0.0;
    static constexpr int kFresnelNodes = 64;
    std::vector<Spectrum> fresnel;  ///< F(c) · specular_reflectance at c = k / (kFresnelNodes − 1)
    std::shared_ptr<const Material> material;
    /// F(ωi·h) · specular_reflectance, linear between the table's nodes.
    Spectrum fresnel_at(float c) const;
};

/// Recognises the base (`json` is its scene object, `where` names it in errors): "diffuse"
/// (Lambertian) or a rough isotropic "conductor" whose reflectance is constant over the surface;
/// the conductor's Fresnel table is probed from material->eval and checked against it. Throws
/// MesoError otherwise (plastic, gltf_pbr, anisotropic, textured specular_reflectance, ...).
LobeBase make_lobe_base(std::shared_ptr<const Material> material, const nlohmann::json &json,
                        const std::string &where);

/// The lobes-form f'_low of a whole level (one lobe list per patch), a Material in the MACRO
/// frame like SvMultiLobe: patch (I, J) = floor(frac(uv) (W/F, H/F)).
class SvLobeBrdf final : public Material {
public:
    /// One lobe of one patch (see the header).
    struct Lobe {
        Vec3 mu;              ///< μ_j (unit)
        float c = 0.f;        ///< c_j = A a_j H(μ_j,z, κ_j)
        float alpha = 0.f;    ///< α' (microfacet)
        float inv_a2 = 0.f;   ///< 1 / α'²
        float d_norm = 0.f;   ///< Beckmann 1 / (π α'²); GGX α'² / π
        float krow = 0.f;     ///< κ_j as a row coordinate of the C and H tables (Lambertian)
        float inv_mass = 0.f; ///< 1 / ∫ C(μ_j·ω, κ_j) dω of the tabulated C (≈ 1/π): the Lambertian sampler's normalisation
        float hz = 0.f;       ///< H(μ_j,z, κ_j) (> 0)
        float cz = 0.f;       ///< C(μ_j,z, κ_j) (> 0): the lobe's projected area at the pole, per unit A a_j
    };

    /// patch_mean_albedo false: a Lambertian base's reflectance at the shading point (models made
    /// before the patch mean; QuadratureOptions::point_albedo).
    /// visible_lambert false: a Lambertian lobe's view weight min(H(μ_j,z), H(μ_j·ωo)) (models made
    /// before the visible form; QuadratureOptions::cap_mass_lambert).
    /// visible_microfacet false: a microfacet lobe's weight c_j = A a_j H(μ_j,z, κ_j) whatever ωo
    /// (models made before its visible form; QuadratureOptions::area_microfacet).
    SvLobeBrdf(LobeBase base, const std::vector<PatchNdf> &ndf, int width, int height, bool patch_mean_albedo = true,
               bool visible_lambert = true, bool visible_microfacet = true);

    Spectrum eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        return eval_pdf(ctx, wo, wi, nullptr);
    }
    float pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override;
    Spectrum eval_pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi, float *pdf) const override;
    bool sample(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, BSDFSample &out) const override;
    /// sample's direction alone (the lobe choice and the draw, no eval_pdf): false where sample
    /// fails before its eval_pdf. For a caller that evaluates at another direction anyway (the
    /// `prefiltered` material on microgeometry, after the rotation back to the shading frame).
    bool sample_direction(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, Vec3 &wi) const;
    uint32_t flags() const override;
    Spectrum albedo_hint(const ShadingContext &ctx) const override;
    bool is_reciprocal() const override { return false; }
    std::string to_string() const override;

    /// Starts loading the lobes of the patch holding uv into the cache (a shading point's first
    /// look at its patch misses it on fine levels: call early, with the work before eval_pdf).
    void prefetch(Vec2 uv) const;
    /// eval(ctx, wo, wi[b]) for b < n into out[b] (the prefilter's next-event splat).
    void eval_batch(const ShadingContext &ctx, const Vec3 &wo, const Vec3 *wi, int n, Spectrum *out) const override;
    /// Patch k's lobes [begin, end).
    std::pair<const Lobe *, const Lobe *> lobes(size_t k) const;
    const LobeBase &base() const { return m_base; }
    size_t memory_bytes() const {
        return m_lobes.size() * sizeof(Lobe) + m_blocks.size() * sizeof(LobeBlock) + m_albedo.size() * sizeof(Spectrum) +
               m_visible_scale.size() * sizeof(float) +
               (m_first.size() + m_first_block.size()) * sizeof(uint32_t);
    }

private:
    /// ρ/π of a Lambertian base: averaged over the patch (m_albedo), or at ctx (point albedo).
    Spectrum lambert(const ShadingContext &ctx, size_t patch) const;
    /// eval_pdf at patch `patch` (found once per sample).
    Spectrum eval_pdf_patch(const ShadingContext &ctx, size_t patch, const Vec3 &wo, const Vec3 &wi, float *pdf) const;
    Spectrum eval_pdf_microfacet(size_t patch, const Vec3 &wo, const Vec3 &wi, float *pdf) const;
    /// eval_pdf_microfacet at n directions wi (wo.z > 0; 0 where wi[k].z <= 0), the ωo side computed once.
    void eval_batch_microfacet(size_t patch, const Vec3 &wo, const Vec3 *wi, int n, Spectrum *out) const;
    /// eval_pdf_microfacet's result from its sums (s: Σ c D G / 4 μ·ωo, ps: Σ c D μ·h, pt: Σ c over
    /// the lobes facing ωo), dwh = ωo·h and cih = ωi·h.
    Spectrum microfacet_value(size_t patch, float s, float ps, float pt, float dwh, float cih, float *pdf) const;
    size_t patch_index(Vec2 uv) const;
    Spectrum eval_pdf_lambert(const ShadingContext &ctx, size_t patch, const Vec3 &wo, const Vec3 &wi,
                              float *pdf) const;
    /// eval_pdf_lambert's sums in the visible form from the patch's blocks (lobe_brdf.cpp).
    void lambert_sums(size_t patch, const float *vw, const Vec3 &wi, float &sum, float &psum, float &ptot) const;
    /// A Lambertian lobe's weight towards ωo (P_j ∝ it) in models made before the visible form:
    /// c_j min(1, H(μ_j·ωo) / H(μ_j,z)) (the visible form's weights: lambert_weights' blocks).
    float view_weight(const Lobe &l, const Vec3 &wo) const;
    /// The weight of each Lambertian lobe of `patch` towards wo (the visible form's c_j C(μ_j·ωo) /
    /// C(μ_j,z) from the blocks, else view_weight), in the patch's order, from the
    /// thread's cache of the last (model, patch, ωo) when it holds them (the same values).
    const float *lambert_weights(size_t patch, const Vec3 &wo) const;
    /// The Lambertian lobe of `patch` chosen by u_lobe for wo (P_j of the header); null when none faces wo.
    const Lobe *choose(size_t patch, const Vec3 &wo, float u_lobe) const;
    /// The microfacet lobe chosen by u_lobe for wo (P_j of the header), from the patch's blocks
    /// (the data and weights eval_pdf_microfacet reads, so a vertex touches one lobe array): block b, lane q.
    bool choose_block(size_t patch, const Vec3 &wo, float u_lobe, uint32_t &b, int &q) const;
    /// The microfacet draw about lobe (μ, α') (see the header): false outside μ's hemisphere.
    bool sample_microfacet(const Vec3 &mu, float alpha, const Vec3 &wo, Vec2 u, Vec3 &wi) const;

    /// Four lobes of one patch by component (eval_pdf_microfacet's SSE pass); unused lanes have
    /// c = 0 and μ = 0 (they face nothing).
    struct alignas(16) LobeBlock {
        float mx[4] = {}, my[4] = {}, mz[4] = {}, c[4] = {}, alpha[4] = {}, a2[4] = {}, inv_a2[4] = {},
              d_norm[4] = {}, cfy[4] = {}, inv_cz[4] = {}, inv_mass[4] = {};
        int crow[4] = {};  ///< the C table's row of the lobe (visible form), times its cells a row (kT − 1)
    };

    LobeBase m_base;
    std::vector<Lobe> m_lobes;
    std::vector<uint32_t> m_first;  ///< patch k's lobes are m_lobes[m_first[k] .. m_first[k + 1])
    std::vector<LobeBlock> m_blocks;
    std::vector<uint32_t> m_first_block;  ///< patch k's blocks: m_blocks[m_first_block[k] .. [k + 1])
    /// Lambertian base: patch k's ρ/π, the base's averaged over the patch (patch_mean_lambert);
    /// empty otherwise, and with point albedo (then lambert() reads the base at the point).
    std::vector<Spectrum> m_albedo;
    bool m_visible = false;              ///< lobes weighted by their projected area towards ωo
    std::vector<float> m_visible_scale;  ///< visible form: patch k's Σ_j c_j
    int m_w = 0, m_h = 0;
    uint64_t m_serial = 0;  ///< unique per model (starts at 1): the key of the per-thread ωo cache (lobe_brdf.cpp)
};

}  // namespace meso::prefilter
