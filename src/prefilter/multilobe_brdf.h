// The multi-lobe BRDF f'_low of paper 004 (Wu et al. 2019): eq. 5 (after Han et al. 2007),
// used as eq. 11 with the patch NDF D_uv of prefilter/patch_ndf.h (eq. 4):
//
//   ρ(ωi, ωo; D, f) = (1 / cos θi) ∫_{H²} f(R_ω(ωi), R_ω(ωo)) <ω, ωi> D(ω) dω          (eq. 5)
//
// f is an isotropic base Material, R_ω the rotation into the frame of the micro-normal ω, and
// D(ω) = amplitude Σ_j a_j γ(ω; μ_j, κ_j) on the upper hemisphere (0 below; patch_ndf_eval).
// meso's Material::eval returns the BRDF times |cos θi|, so eval here returns
//
//   ρ cos θi = ∫_{H²} f(R_ω ωi, R_ω ωo) <ω, ωi> D(ω) dω = ∫_{H²} base.eval(R_ω ωo, R_ω ωi) D(ω) dω
//
// because base.eval already includes the cosine w.r.t. ITS normal, ω, i.e. <ω, ωi>⁺. Terms with
// <ω, ωo> ≤ 0 or <ω, ωi> ≤ 0 are 0 (the base is reflection-only in its own frame), and the
// macro directions must be above the macro horizon (ωo.z > 0, ωi.z > 0).
//
// Modelling note. Eq. 5 is implemented as printed (up to one factor per ωo, the shares below):
// there is NO projected-area factor <ω, ωo> / <ω_g, ωo> (the area of micro-facet ω seen from the
// viewer per unit of base area seen from the viewer). Without it the microsurface area D dω (∫ D dω = area_ratio ≥ 1,
// patch_ndf.h) reflects as if every facet were fully visible and facing the viewer: for a
// white Lambertian base the directional albedo at normal incidence is ≈ ∫_{ωi·ω>0 region} D dω,
// i.e. up to area_ratio > 1, and at grazing ωo facets tilted towards the viewer are not
// weighted up. In paper 004 the scaling functions R / S·T (§4.3–§6) absorb this (they are
// fitted ratios of effective BRDFs), so f'_low alone need not conserve energy. Measured
// (MultiLobeBrdf.EnergyOfRealPatch: white Lambertian, gaussian map patch with area_ratio
// 1.0955): albedo 1.048 for θo ≤ 60° (+4.8%), 0.703 at 80°, 0.586 at 89° (facets facing away
// from ωo are cut off by <ω, ωo> > 0 and nothing re-weights the visible ones). (Those are the
// absolute weights of models made before the shares, below; with the shares: 0.957 for θo ≤ 60°,
// 0.947 at 89°.)
//
// View weights: the shares (manifest parameters.quadrature_weights = "share"). The renderer shades
// f'_low in the macro frame at hits on h_low, which are already spread over h_low by its own
// projected area towards ωo. Where h_low keeps the surface's tilt (a coarse facet of normal n),
// f'_low there must be the facet's own BRDF, i.e. total node weight 1; the weights of eq. 5 as
// printed give it c = 1 / n.z (a delta NDF's node: D dω = 1 / n.z per unit base area), those of the
// visible flow c <n, ωo> / ωo.z = <n, ωo> / (n.z ωo.z). A factor that differs from patch to patch
// at one (ωi, ωo), which no angular S can remove (paper 004 derives eq. 5 for a flat h_low, ω_g
// = the macro normal, where it is the same for every patch). Measured on tilted sawtooth facets
// at x4 against brute force of the original (tests/test_prefiltered_bias.cpp,
// QuadratureFlowsOnTiltedPatchesMatchBruteForce; rough conductor and rough plastic bases): eq5
// 1.054 and 1.414 (18.4° and 45° facets), visible 0.16 to 3.02 over four direction pairs. So each
// node weighs its share of the weight of the nodes facing ωo, times P = Σ_k c_k ω_k.z (eq. 3's
// projected area, 1 up to the quadrature; as lobe_brdf.h's lobes):
//   w_k(ωo) = v_k(ωo) P / Σ_{j: <ω_j, ωo> > 0} v_j(ωo),   v_k = c_k (eq5) or c_k <ω_k, ωo> (visible),
// exact for a tilted plane (1.0000 in that test). On a flat h_low it also takes eq5's excess area
// (Σ c ≈ area_ratio) and its cut-off at grazing ωo out of f'_low, and the visible flow's growth
// towards grazing ωo (its Σ_k c_k <ω_k, ωo>⁺ / ωo.z ≥ 1). The node choice (P_k ∝ v_k) is the same
// as before; only Σ(ωo) (NodePick::total, view_scale) changes. Models whose manifest has no
// parameters.quadrature_weights keep the absolute weights (absolute_weights): their tables were
// fitted to them.
//
// Deterministic quadrature. D is replaced by a fixed weighted set of nodes,
//   D(ω) dω ≈ Σ_k c_k δ(ω − ω_k),
// built once per PatchNdf: for every lobe j, in the lobe's frame (axis μ_j), the variable
// u ∈ [0, 1) is the vMF's CDF in w = μ·ω (w = vmf::sample_cos(κ, u)), so that γ dω = du dφ/(2π)
// exactly; u gets an n_u-point Gauss–Legendre rule and φ an n_φ-point uniform (midpoint) rule,
// shifted by half a step on alternate rings (better coverage of the lobe at no cost). Because u
// is the lobe's own CDF, the rule resolves the lobe for every κ in [0, 1e9] (κ = 0 is the
// uniform sphere); nodes with ω_k.z ≤ 0 are dropped (D = 0 there), which is how the
// hemisphere restriction of eq. 4 enters. c_k = amplitude · a_j · w_u · (1 / n_φ). Then
//
//   eval(ωo, ωi) = Σ_k c_k base.eval(F_k ωo, F_k ωi)              (F_k: to the frame of ω_k)
//
// deterministic, with a quadrature error that depends on how smooth the integrand is on the
// scale of the lobe (see the tests: kinks of the clamped cosines and of the horizon limit it
// for wide lobes; a glossy base narrower than the lobe is resolved only as n_u·n_φ discrete
// highlights — the price of a deterministic, exactly sampleable rule).
//
// Sampling. Node k is chosen with probability P_k(ωo) = c_k [F_k ωo .z > 0] / Σ, then the base
// is sampled in node k's frame; a direction below the macro horizon ends the path (sample
// returns false). The pdf is the exact mixture density of that procedure,
//   pdf(ωi) = [ωi.z > 0] Σ_k P_k(ωo) base.pdf(F_k ωo, F_k ωi),
// so the χ² test holds and weight = eval / pdf exactly. Its integral over the upper hemisphere
// is < 1 by the probability of sampling below the horizon.
//
// Reciprocity. eval(ωo, ωi) / cos θi = Σ c_k f <ω_k, ωi> / cos θi is not symmetric in
// (ωi, ωo) (the swap gives <ω_k, ωo> / cos θo), so is_reciprocal() is false.
//
// Scope. The base must be isotropic (the tangent of F_k is arbitrary), reflection-only and
// without delta lobes (smooth conductor, smooth plastic coat: rejected with MesoError).
//
// Cost: eval and pdf are O(N) base evaluations, N = Σ kept nodes ≤ lobes · n_u · n_φ (6 · 4 · 6 =
// 144 by default); sample is O(N) for the node choice plus one eval_pdf pass. The node choice's
// pass over the nodes (pick_node) reads only a compact copy of their normals and weights, four
// nodes at a time, and is shared by every call with the same wo (next-event estimation and BSDF
// sampling at one vertex).
//
// Stochastic one-node estimator (eval_pdf_stochastic, sample_stochastic; the `prefiltered`
// material's "estimator": "stochastic"). With g_k(ωo, ωi) = base.eval(F_k ωo, F_k ωi),
// w_k(ωo) = eval's weight of node k (the shares above, or with absolute_weights c_k, or c_k <ω_k, ωo> /
// ωo.z with projected_area) and Σ(ωo) = Σ_k w_k over
// the nodes visible from ωo (F_k ωo .z > 0; the others have g_k = 0),
//   eval(ωo, ωi) = Σ_k w_k g_k = Σ_k P_k(ωo) · Σ(ωo) g_k(ωo, ωi),     P_k = w_k / Σ (sample()'s choice),
// so picking ONE node k by P_k (a uniform u against the cumulative weights, the scan of sample())
// and returning Σ(ωo) g_k(ωo, ωi) is an unbiased estimate of eval: 1 base evaluation instead of N
// (plus the O(N) scan of cheap dot products for Σ and the choice). Its pdf is the node's own,
// pdf_k(ωi) = base.pdf(F_k ωo, F_k ωi), NOT the mixture. sample_stochastic draws k with u_lobe
// (its leftover goes to the base's lobe choice, as in sample()), samples the base in node k's
// frame (the same directions as sample(): pdf() stays the exact density of the directions) and
// returns pdf = pdf_k(ωi), weight = Σ(ωo) g_k(ωo, ωi) / pdf_k(ωi), both from the base's own sample
// record: 1 base sample, no base evaluation and no pass over the nodes beyond the choice. Given the direction, the node was k with probability
// P_k pdf_k(ωi) / pdf(ωi), so E[weight | ωi] = Σ_k w_k g_k / pdf(ωi) = eval / pdf: the exact
// weight is the conditional mean of the stochastic one.
//
// Why it stays unbiased inside an MIS path tracer (next-event estimation with light pdf p_L,
// power heuristic). For a FIXED node k, "light sample, value Σ g_k, MIS weight
// w_L^k = p_L² / (p_L² + pdf_k²)" and "BSDF sample from node k, weight Σ g_k / pdf_k, MIS
// weight w_B^k = pdf_k² / (p_L² + pdf_k²)" are an ordinary two-strategy MIS pair:
// w_L^k + w_B^k = 1 wherever g_k L ≠ 0 (w_L^k = 1 where pdf_k = 0, w_B^k = 1 where p_L = 0; the
// base's sampler covers its support). The next-event node and the BSDF-sample node are drawn
// independently from the same P_k(ωo), so the expected contribution of the vertex is
//   Σ_k P_k ∫ (Σ g_k) L w_L^k dωi + Σ_k P_k ∫ pdf_k (Σ g_k / pdf_k) L w_B^k dωi
//     = Σ_k ∫ w_k g_k L (w_L^k + w_B^k) dωi = ∫ eval(ωo, ωi) L dωi.
// This needs the integrator's emitter-hit MIS weight to use the pdf that sample_stochastic
// returned (pdf_k of the node that produced the direction) and the next-event weight the pdf that
// eval_pdf_stochastic returned. Exact (mixture) pdfs on one side and per-node ones on the other
// do NOT sum to 1, so the `prefiltered` material switches BOTH to the stochastic form, and only
// where the integrator hands it a uniform (ShadingContext::u_eval >= 0).
//
// Stratified node-set estimator (eval_pdf_stratified, sample_stratified; "estimator":
// "stratified"). The one-node estimator is noisy for a glossy base narrower than the lobes: the
// next-event value Σ g_k swings between 0 and many times eval from node to node. Measured on the
// tiny suite's `plane` (gold, Beckmann 0.25, twill; pixel variance per sample over the
// original's): one-node 1.29; this estimator with m = 1 (one node, but SHARED by next-event
// estimation and BSDF sampling) 1.27, so the MIS pairing of per-node pdfs is not the cause;
// m = 2, 4, 8, 16: 0.69, 0.30, 0.17, 0.14; the full quadrature 0.17 (the light and BSDF sampling
// noise left). The set estimator draws, from the vertex's ONE uniform u_eval, a set S of m nodes at the systematic positions (u_eval + j) / m of the
// cumulative choice (each marginally P_k; in node order, so the set spreads over the lobes and
// rings: stratified), and uses at that vertex the BSDF
//   f_S(ωo, ωi) = Σ(ωo) (1/m) Σ_{j<m} g_{k_j}(ωo, ωi),    E_S[f_S] = eval,
// sampled as a uniform mixture of its members (member floor(u_lobe m), the base in its frame),
// density pdf_S(ωi) = (1/m) Σ_j pdf_{k_j}(ωi). For a FIXED S, (f_S, pdf_S) is an ordinary BSDF
// with an exact sampler, so next-event estimation (value f_S, pdf pdf_S) and BSDF sampling
// (weight f_S / pdf_S, pdf pdf_S) are an exact MIS pair; both use the same S (the same u_eval at
// the vertex), so the vertex's expected contribution given S is ∫ f_S L dωi, and over S
// ∫ eval L dωi: unbiased, with the integrator unchanged. Cost: m base evaluations per eval_pdf,
// 1 base sample + (m − 1) evaluations per sample (members that are one node are evaluated once).
#pragma once
#include <memory>
#include <string>
#include <vector>
#include "core/frame.h"
#include "prefilter/patch_ndf.h"
#include "bsdf/material.h"

namespace meso::prefilter {

/// Lobes at least this concentrated (angular spread ~1/sqrt(κ) <= 3e-3 rad) get ONE node at μ
/// instead of the n_u x n_φ rule (flat facets of sawtooth, relief or twill maps: eq. 3's fit
/// gives κ up to 1e9): 12x fewer base evaluations there, a change far below any base BRDF's width.
constexpr double kCollapseKappa = 1e5;

struct QuadratureOptions {
    int polar = 4;    ///< n_u: Gauss–Legendre nodes in the vMF CDF variable per lobe, 1..64
    int azimuth = 6;  ///< n_φ: uniform azimuthal nodes per ring, 1..256
    /// Weight every facet by its projected area towards the viewer, <ω, ωo> / <ω_g, ωo>
    /// (the visible-normal form of microfacet theory, without masking), instead of eq. 5 as
    /// printed. Eq. 5 depends on ωo only through the switch <ω, ωo> > 0, so f'_low jumps where
    /// ωo crosses a facet family's plane (a sawtooth's steep facets: a hard line across a
    /// rendered plane) and its albedo at grazing ωo drops (0.59 at 89°, below); with the factor
    /// it is continuous and a white Lambertian base reflects 1 + (facets facing away) ≈ 1 at
    /// every ωo. But R = f_eff / f_eff(f'_low) then falls steeply towards grazing ωo (the
    /// 1 / cos θo of the projected area is no longer cancelled by masking), which the binned S
    /// resolves worse: in the white furnace of PrefilteredModel.WhiteFurnace (run on a model
    /// made with --flow visible) the albedo fell furthest from 1 at 75°, where eq. 5 stays
    /// within 1%. meso prefilter therefore defaults to eq. 5 (--flow eq5) and offers this as
    /// --flow visible. (Measured with the absolute weights; the shares, the header's "View
    /// weights", normalise the sum of the weights to P at every ωo: that white furnace then gives
    /// 1.003, 0.986, 0.971, 0.999 at 0, 30, 60, 75° with --flow visible, 1.001, 0.986, 0.973, 0.998
    /// with eq5; PrefilteredModel.WhiteFurnaceVisible.)
    bool projected_area = false;
    /// --flow lobes: f'_low is the closed-form per-lobe BRDF of prefilter/lobe_brdf.h (one widened
    /// base lobe per vMF lobe) instead of this quadrature (polar, azimuth and projected_area unused).
    bool lobes = false;
    /// --flow lobes with a Lambertian base: its reflectance at the shading point instead of the
    /// patch mean (lobe_brdf.h) — how models made before the patch mean were fitted (their
    /// manifest has no parameters.albedo); they keep shading the way their tables expect.
    bool point_albedo = false;
    /// --flow lobes with a Lambertian base: each lobe weighted towards ωo by min(H(μ_j,z), H(μ_j·ωo))
    /// instead of its projected area (lobe_brdf.h) — how models made before the visible form were
    /// fitted (their manifest has no parameters.lambert_view).
    bool cap_mass_lambert = false;
    /// --flow lobes with a microfacet base: each lobe weighted by its area A a_j H(μ_j,z) whatever
    /// ωo instead of its share of the projected area seen from ωo (lobe_brdf.h) — how models made
    /// before that were fitted (their manifest has no parameters.microfacet_view).
    bool area_microfacet = false;
    /// --flow eq5 / visible: each node weighted by its absolute weight (c_k, or c_k <ω_k, ωo> /
    /// <ω_g, ωo> with projected_area) instead of its share of the nodes facing ωo times Σ_k c_k ω_k.z
    /// (the header's "View weights") — how models made before the shares were fitted (their
    /// manifest has no parameters.quadrature_weights).
    bool absolute_weights = false;
};

/// One node of the quadrature of D: micro-normal ω_k (its frame) and weight c_k.
struct NdfNode {
    Frame frame;       ///< frame.n = ω_k (unit, z > 0)
    double weight;     ///< c_k
    int lobe;          ///< index of the lobe it comes from
};

class MultiLobeBrdf final : public Material {
public:
    /// Throws MesoError when base is null, has delta or transmission lobes, the NDF has no lobes
    /// or invalid ones (non-finite or negative κ or weight, zero μ, non-finite amplitude), or
    /// the options are out of range.
    MultiLobeBrdf(std::shared_ptr<const Material> base, const PatchNdf &ndf, const QuadratureOptions &opt = {});

    Spectrum eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override;
    float pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override;
    bool sample(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, BSDFSample &out) const override;
    /// eval and pdf in one pass over the nodes.
    Spectrum eval_pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi, float *pdf) const override;
    uint32_t flags() const override;
    Spectrum albedo_hint(const ShadingContext &ctx) const override;
    bool is_reciprocal() const override { return false; }
    std::string to_string() const override;

    /// One node chosen for the viewer wo with probability P_k(wo) = weight(k) [k visible] / Σ
    /// (the choice of sample()), for the stochastic estimator.
    struct NodePick {
        const NdfNode *node = nullptr;
        Frame frame;               ///< node->frame
        Vec3 lo;                   ///< wo in the node's frame (lo.z > 0)
        double total = 0.0;        ///< Σ(wo): the sum of eval's weights over the nodes visible from wo
        double u_rescaled = 0.0;   ///< where u fell inside the node's interval, in [0, 1]
    };
    /// Chooses the node whose interval [Σ_{j<k} w_j, Σ_{j<=k} w_j) / Σ holds u ∈ [0, 1) (visible
    /// nodes in the order of nodes(); u >= 1 gives the last); false when wo is below the horizon or
    /// no node faces it. The visible nodes and their weights for the last (instance, wo) are kept
    /// per thread, so that next-event estimation and BSDF sampling at one vertex (same wo) pay
    /// for the O(N) pass once.
    bool pick_node(const Vec3 &wo, double u, NodePick &pick) const;
    /// Samples the base in the picked node's frame (the leftover of u_lobe picks the base's own
    /// lobe): wi in the macro frame and the base's flags (and, when base is not null, the base's
    /// sample record in the node's frame); false below either horizon.
    bool sample_base_in_node(const ShadingContext &ctx, const NodePick &pick, Vec2 u, Vec3 &wi, uint32_t &flags,
                             BSDFSample *base = nullptr) const;
    /// Σ(wo) · g_k(wo, wi) for the picked node (the one-node estimate of eval) and, when pdf is not
    /// null, pdf_k(wi) = base.pdf in the node's frame into *pdf (0 below either horizon).
    Spectrum eval_pdf_node(const ShadingContext &ctx, const NodePick &pick, const Vec3 &wo, const Vec3 &wi,
                           float *pdf) const;
    /// pick_node(wo, u) then eval_pdf_node: its mean over u ∈ [0, 1) is eval(ctx, wo, wi) (see the header).
    Spectrum eval_pdf_stochastic(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi, double u,
                                 float *pdf) const;
    /// The directions of sample() (same u_lobe, u), with out.pdf = pdf_k(wi) of the chosen node and
    /// out.weight = Σ(wo) g_k(wo, wi) / pdf_k(wi), both from the base's sample record (at the
    /// direction in the node's frame, before the rotation to the macro frame rounds it); the
    /// chosen node into *pick when not null.
    bool sample_stochastic(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, BSDFSample &out,
                           NodePick *pick = nullptr) const;

    /// Stratified node-set estimator (the `prefiltered` material's "estimator": "stratified"; see the
    /// header's "Stratified node-set estimator"). At most this many nodes per set.
    static constexpr int kMaxSetNodes = 32;
    /// The set S(u) of m nodes at the systematic positions (u + j) / m, j < m, of sample()'s
    /// cumulative choice (each one marginally distributed by P_k(wo)) into picks[0..m); false
    /// when wo is below the horizon or no node faces it. 1 <= m <= kMaxSetNodes.
    bool pick_set(const Vec3 &wo, double u, int m, NodePick *picks) const;
    /// f_S(wo, wi) = Σ(wo) (1/m) Σ_j g_{k_j}(wo, wi) (its mean over u is eval) and, when pdf is not
    /// null, pdf_S(wi) = (1/m) Σ_j pdf_{k_j}(wi): the density of sample_set's directions given S.
    Spectrum eval_pdf_set(const ShadingContext &ctx, const NodePick *picks, int m, const Vec3 &wo, const Vec3 &wi,
                          float *pdf) const;
    /// eval_pdf_set for the set S(u_set) (pick_set).
    Spectrum eval_pdf_stratified(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi, double u_set, int m,
                                 float *pdf) const;
    /// Given S(u_set): member j = floor(u_lobe m) (the rest of u_lobe m goes to the base's own lobe
    /// choice), the base sampled in its frame; out.pdf = pdf_S(wi), out.weight = f_S(wi) / pdf_S(wi)
    /// (member j's value and pdf from the base's sample record, the others evaluated at wi).
    bool sample_stratified(const ShadingContext &ctx, const Vec3 &wo, double u_set, int m, float u_lobe, Vec2 u,
                           BSDFSample &out) const;

    /// eval(ctx, wo, wi[b]) for b < n into out[b] (same values; wo's per-node transform and
    /// test are done once): the next-event splat of prefilter/scaling.cpp.
    void eval_batch(const ShadingContext &ctx, const Vec3 &wo, const Vec3 *wi, int n, Spectrum *out) const override;

    const std::vector<NdfNode> &nodes() const { return m_nodes; }
    /// Bytes of node data: the nodes and pick_node's compact copy of them.
    size_t node_bytes() const { return m_nodes.size() * sizeof(NdfNode) + m_blocks.size() * sizeof(NodeBlock); }
    /// Node k's weight for the viewer wo (0 when ω_k faces away), the weight of sample()'s node
    /// choice: eval's weights are these times view_scale(Σ_k node_weight(k, wo)).
    double node_weight(const NdfNode &k, const Vec3 &wo) const {
        const float z = k.frame.to_local(wo).z;
        return z > 0.f && wo.z > 0.f ? weight(k, z, wo.z) : 0.0;
    }
    /// The factor from node_weight to eval's weights, given their sum over the nodes facing wo:
    /// Σ_k c_k ω_k.z / facing_total (the shares, see the header), 1 with absolute_weights or when
    /// no node faces wo.
    double view_scale(double facing_total) const {
        return m_opt.absolute_weights || !(facing_total > 0.0) ? 1.0 : m_projected / facing_total;
    }
    /// Σ_k c_k: the quadrature of ∫_{H²} D dω (≈ area_ratio for a good fit).
    double total_weight() const { return m_total; }
    /// Σ_k c_k ω_k.z: the quadrature of eq. 3's left side (1 up to the quadrature error).
    double projected_area() const { return m_projected; }

private:
    /// The weight of node k for the viewer before view_scale: c_k, times <ω_k, ωo> / <ω_g, ωo> with
    /// projected_area.
    double weight(const NdfNode &k, float lo_z, float wo_z) const {
        return m_opt.projected_area ? k.weight * double(lo_z) / double(wo_z) : k.weight;
    }
    /// Nodes per block of pick_node's two-level running sum (block sums in pick_weights).
    static constexpr size_t kPickBlock = 8;
    /// w[k] = weight(k) where node k faces wo, else 0, for the padded node arrays, and block[b] =
    /// the sum of w over block b (pick_node's pass over the nodes).
    void pick_weights(const Vec3 &wo, double *w, double *block) const;
    /// Σ_k c_k [F_k wo .z > 0]: the normaliser of the node choice P_k(wo).
    double selection_total(const Vec3 &wo) const;

    std::shared_ptr<const Material> m_base;
    std::vector<NdfNode> m_nodes;
    /// m_nodes[k].frame.n by axis and m_nodes[k].weight for k in a block of kPickBlock nodes
    /// (pick_node's pass reads these only), padded with zeros (normals that face nothing).
    struct NodeBlock {
        float nx[kPickBlock] = {}, ny[kPickBlock] = {}, nz[kPickBlock] = {};
        double c[kPickBlock] = {};
    };
    std::vector<NodeBlock> m_blocks;
    QuadratureOptions m_opt;
    size_t m_lobes = 0;
    double m_total = 0.0, m_projected = 0.0;
    uint64_t m_id = 0;  ///< unique per instance: the key of pick_node's per-thread cache
};


}  // namespace meso::prefilter
