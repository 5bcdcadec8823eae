// Patch NDFs of a fine heightfield fitted with vMF mixtures: the spatially varying NDF
// (SVNDF) of paper 004 (Wu et al. 2019), §3 "Normal mapping" eq. 2–4 and §4.2.
//
// Patches. As in prefilter/least_squares.h, coarse patch (I, J) of factor F is the F x F
// block of fine cells [I F, I F + F) x [J F, J F + F) (fine cell (i, j) is the bilinear patch
// over [i, i+1] x [j, j+1] of heightmap.h; cells wrap, so the block of the last column of a
// periodic map ends with the cell joining vertex W-1 to vertex 0). F must divide both sizes;
// there are (W/F) x (H/F) patches, stored row-major: index J * (W/F) + I.
//
// Units. The micro-normals are those of the bilinear surface z = height_scale * h(x, y) over
// the base plane, with the fine cell (x, y in cell units) of world size cell_size, in the
// frame (x along u, y along v, z = the macro normal ω_g = (0, 0, 1)):
//     s = height_scale / cell_size * (∂h/∂x, ∂h/∂y)     (slope per world unit)
//     ω_m = (−s_x, −s_y, 1) / sqrt(1 + |s|²)
// where h is the Heightfield's height (offset + scale * map). This is bake_heightfield's
// convention (texture/normal_source.cpp): a Displacement's field is in world units
// (height_scale = 1) and cell_size = uv_length / (width * tiling). For a generated map
// (heights in tile units, heightmap_gen.h) on Heightfield(map, 1, 0), cell_size = 1 / width
// (and height_scale = 1) gives the slopes "per tile" of the generators (vgroove: ±tan(angle)).
// Only the ratio height_scale / cell_size matters.
//
// Eq. 2 with the box kernel k_P = 1 / |P| (|P| = F² cells):
//     D(ω) = ∫_P δ(ω − ω_m(p)) / <ω_m(p), ω_g> k_P(p) dp
// is a sum of deltas: each fine cell is integrated with an n x n Gauss–Legendre rule
// (n = samples_per_cell) in its cell coordinates, and sample q
// (cell-space area weight A_q = w_a w_b / F², Σ_q A_q = 1) contributes
//     D ≈ Σ_q  W_q δ(ω − ω_q),      W_q = A_q / cos θ_q = A_q sqrt(1 + |s_q|²)
// (W_q is the microsurface area of the sample per unit base area). patch_normals returns
// these ω_q and W_q. They satisfy eq. 3 EXACTLY (to rounding): Σ_q W_q cos θ_q = Σ A_q = 1
// (the projected area of the microsurface onto ω_g equals the base area), and
//     Σ_q W_q = area_ratio  (microsurface area / base area, ≥ 1, up to the quadrature error
// of ∫ sqrt(1 + |s|²) over a bilinear cell: exact for planar cells).
//
// The fit. fit_vmf_mixture is run on (ω_q, W_q): the lobes are a DENSITY of directions
// (mixture weights a_j = VmfLobe::weight, Σ a_j = 1) proportional to the microsurface AREA
// with normal ω, i.e. to D itself. Eq. 4 is then
//     D(ω) ≈ amplitude · Σ_j a_j γ(ω; μ_j, κ_j)   for ω_z > 0,   0 below the horizon,
// (paper's α_j = amplitude · a_j), with amplitude chosen so that eq. 3 holds EXACTLY for
// the fitted mixture on the hemisphere with the clamped cosine:
//     amplitude = 1 / Σ_j a_j P(μ_j, κ_j),   P(μ, κ) = ∫_{H²} γ(ω; μ, κ) <ω, ω_g> dω
// (vmf_projected_area). projected_area_check = area_ratio · Σ_j a_j P_j is eq. 3's left side
// had the amplitude instead preserved the microsurface area (amplitude = area_ratio), so
// amplitude = area_ratio / projected_area_check. It is a fit diagnostic, and close to 1 for a
// reason: every M-step sets a_j A₃(κ_j) μ_j = R_j / Σ W (the lobe's weighted resultant), so
// with the exact κ (em.exact_kappa: A₃(κ_j) = r_j) Σ_j a_j A₃(κ_j) μ_j,z = Σ W_q cos θ_q / Σ W_q
// = 1 / area_ratio exactly (for the responsibilities of the last M-step; a lobe dropped for
// min_weight in that step perturbs it), and projected_area_check = 1 + area_ratio Σ_j a_j (mass of lobe j
// below the horizon, weighted by |ω_z|) ≥ 1 (tested: 1 + [−2e-9, 3e-6] on random maps). With
// Banerjee's κ (the default) A₃(κ_j) > r_j (κ overestimated by ~0.5), which makes it larger:
// 1 + [4e-5, 1.2e-3] on the same maps. The vMF blur thus never loses projected area; only
// mass below the horizon (cut off here, where D = 0) and the κ approximation move it.
//
// Determinism. Everything is sequential per patch in a fixed order and fit_vmf_mixture is
// deterministic, so results are bit-identical across runs and thread counts; fit_svndf runs
// patches in parallel (TBB) and writes each to its own slot.
//
// Cost: W·H·n² normals in all (independent of F), each costing O(K) exp per EM iteration
// (up to em.max_iterations; large patches converge more slowly), plus ~300 cheap evaluations
// per lobe for P. Measured (MESO_TIMING=1 meso_tests --gtest_filter=PatchNdf.TimingFbm1024, 2 shared cores, 6 lobes): a
// 1024² fbm map takes 35 s at F = 8 (16384 patches, 55 EM iterations on average) and 57 s at
// F = 64 (256 patches, 97 iterations, mostly not converged) with n = 4; 9 s and 13 s with n = 2.
// Those are plain EM; with SQUAREM (the default since session 35, bsdf/vmf_mixture.h) and the
// pipeline's EM options, `MESO_TIMING=1 meso_tests --gtest_filter=PatchNdf.TimingSquarem`
// (n = 2): F = 16 10.4 → 6.9 s (75.1 → 37.3 M-steps, 2569 → 3974 of 4096 patches converged),
// F = 64 12.5 → 9.9 s (97.0 → 60.3, 37 → 209 of 256), each with a higher mean likelihood.
#pragma once
#include <vector>
#include "core/vec.h"
#include "geometry/heightfield.h"
#include "bsdf/vmf_mixture.h"
#include "texture/vmf_map.h"

namespace meso::prefilter {

struct PatchNdfOptions {
    int samples_per_cell = 4;   ///< n: n x n Gauss–Legendre points per fine cell, 1..32
    double height_scale = 1.0;  ///< world height per Heightfield height unit (finite, may be 0 or negative)
    double cell_size = 1.0;     ///< world size of one fine cell (finite, > 0)
    VmfEmOptions em;            ///< the EM fit; em.lobes (default 6) is K
    int threads = 0;            ///< fit_svndf: 0 = TBB's default, 1 = serial on the calling thread
    /// fit_svndf: each patch's EM starts from its cells' normals, one moment-matched lobe a cell,
    /// merged to em.lobes (as fit_svndf_from merges a finer level's lobes) instead of k-means++;
    /// only where a patch has at least 2 em.lobes cells (k-means++ below: a cell's lobe does not
    /// split, and EM cannot add lobes).
    bool start_from_cells = false;
};

struct PatchNdf {
    std::vector<VmfLobe> lobes;         ///< mixture weights a_j sum to 1, sorted by decreasing weight
    double amplitude = 0.0;             ///< eq. 4 scale: D = amplitude Σ a_j γ_j, eq. 3 exact
    double area_ratio = 0.0;            ///< Σ W_q: microsurface area / base area of the patch (≥ 1)
    double projected_area_check = 0.0;  ///< area_ratio Σ a_j P_j (1 for a perfect fit)
    double log_likelihood = 0.0;        ///< of the EM fit (VmfMixture::log_likelihood)
    int iterations = 0;                 ///< EM M-steps
    bool converged = false;
};

/// Micro-normals ω_q (unit, z > 0) and their weights W_q of coarse patch (I, J) (see the header
/// comment), F² n² of each, ordered by fine row, fine column, GL row, GL column. Throws
/// MesoError on invalid input (empty field, F < 1 or not dividing both sizes, I or J out of
/// range, bad options).
void patch_normals(const Heightfield &hf, int factor, int I, int J, const PatchNdfOptions &opt,
                   std::vector<Vec3> &dirs, std::vector<double> &weights);

/// The vMF-mixture fit of the NDF of coarse patch (I, J).
PatchNdf fit_patch_ndf(const Heightfield &hf, int factor, int I, int J, const PatchNdfOptions &opt = {});

/// All (W/F) x (H/F) patches, index J * (W/F) + I, in parallel (opt.threads), deterministic.
std::vector<PatchNdf> fit_svndf(const Heightfield &hf, int factor, const PatchNdfOptions &opt = {});

/// fit_svndf with every patch's EM started from a finer fit of the same field (`finer`, its
/// patches at finer_factor, which must divide factor): coarse patch (I, J)'s start is its
/// (factor / finer_factor)² children's lobes, each weighted by its child's area ratio, merged to
/// at most em.lobes by reduce_vmf_lobes (up a quadtree of 2 x 2 blocks when the ratio is a power
/// of two; other ratios with more than 200 child lobes get k-means++) (fit_vmf_mixture_from), instead of em.init_restarts
/// k-means++ starts on its normals. The same EM and convergence test from another start: a local
/// maximum near the children's, found in fewer M-steps. Measured on the bench logo (2048², n = 2,
/// K = 6, 2 cores): x8 from x4 23.9 → 11.2 s, mean log-likelihood a patch 0.013 → 0.248; x16 from
/// x8 20.2 → 4.3 s, −0.036 → 0.166 (PatchNdf.FitFromChildrenMatchesKmeansInFewerSteps). Deterministic.
std::vector<PatchNdf> fit_svndf_from(const Heightfield &hf, int factor, const std::vector<PatchNdf> &finer,
                                     int finer_factor, const PatchNdfOptions &opt = {});

/// D(w) of eq. 4: amplitude Σ a_j γ(w; μ_j, κ_j) for w.z > 0 (w is normalised), 0 otherwise.
double patch_ndf_eval(const PatchNdf &ndf, Vec3 w);

/// P(μ, κ) = ∫_{H²} γ(ω; μ, κ) max(0, ω_z) dω, the projected area (onto z) of one
/// normalised vMF lobe restricted to the upper hemisphere. Computed in the lobe's frame: the
/// azimuthal mean of max(0, ω_z) at μ·ω = u is closed-form, the remaining 1D integral over u
/// is taken in the vMF's own CDF variable (vmf::sample_cos) by graded composite
/// Gauss–Legendre; accurate to ~1e-12 for every κ in [0, 1e9] and every μ (tested against the identity
/// P(μ) − P(−μ) = A₃(κ) μ_z and brute-force quadrature).
double vmf_projected_area(Vec3 mu, double kappa);
/// H(μ, κ) = ∫_{H²} γ(ω; μ, κ) dω: the lobe's mass above the horizon, by the same quadrature.
double vmf_cap_mass(Vec3 mu, double kappa);

/// Σ_j a_j P(μ_j, κ_j) of a set of lobes.
double mixture_projected_area(const std::vector<VmfLobe> &lobes);

}  // namespace meso::prefilter
