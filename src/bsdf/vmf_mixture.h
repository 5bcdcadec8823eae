// Fitting a mixture of von Mises-Fisher lobes to weighted unit directions by spherical EM
// (Banerjee, Dhillon, Ghosh & Sra 2005, "Clustering on the unit hypersphere using von
// Mises-Fisher distributions", soft-moVMF, specialised to S²; as used by Han et al. 2007,
// "Frequency domain normal map filtering", for normal-map NDFs). Paper 004 (Wu et al. 2019,
// §4.2) fits the patch NDF D_uv (eq. 2, the distribution of the micro-normals of a patch,
// weighted by their area) with six vMF lobes (eq. 4); this is that fit.
//
// Model. p(ω) = Σ_j a_j γ(ω; μ_j, κ_j), γ the vMF density of filter/vmf.h, a_j > 0, Σ a_j = 1.
// Data: directions x_i (any non-zero length: they are normalised in double) with weights
// w_i ≥ 0 (nullptr: all 1). The fit maximises the weighted log-likelihood Σ_i w_i log p(x_i).
//
// E-step (log space). l_ij = log a_j + log_norm(κ_j) + κ_j μ_j·x_i is evaluated as
//   l_ij = log a_j + [log_norm(κ_j) + κ_j] − κ_j |μ_j − x_i|² / 2
// (μ·x − 1 = −|μ − x|²/2 for unit vectors, exact near μ = x), responsibilities
// γ_ij = exp(l_ij − LSE_i) with LSE_i = max_j l_ij + log Σ_j exp(l_ij − max_j l_ij), so κ up to
// 10⁶ (and beyond) never overflows and a point far from every lobe still has responsibilities
// summing to 1.
// M-step. N_j = Σ_i w_i γ_ij, R_j = Σ_i w_i γ_ij x_i; a_j = N_j / Σ_i w_i, μ_j = R_j / |R_j|,
// r_j = |R_j| / N_j, κ_j = (3r − r³)/(1 − r²) (Banerjee's approximation, vmf::kappa_from_r;
// default) or the exact root of A₃(κ) = coth κ − 1/κ = r (safeguarded Newton, exact_kappa),
// clamped to [0, max_kappa]. The approximation overestimates κ by about 0.5 (+3.7 % at κ = 10,
// +0.5 % at κ = 100, see kappa_banerjee_bias in the tests); the exact root is the maximum-
// likelihood κ. If R_j = 0 (directions cancelling exactly) μ_j keeps its previous value and
// κ_j = 0 (a uniform lobe).
// Convergence: the mean log-likelihood L = Σ w_i log p(x_i) / Σ w_i (non-decreasing under
// EM) changes by at most tolerance · (1 + |L|) between two E-steps, or max_iterations M-steps.
// Acceleration (accelerate, the default): SQUAREM (Varadhan and Roland 2008, Scand. J. Stat.
// 35, scheme S3). Each cycle makes two EM steps θ0 → θ1 → θ2 and tries the extrapolation
// θ0 − 2α r + α² v (r = θ1 − θ0, v = θ2 − 2θ1 + θ0, α = −|r|/|v| in [−64, −1], in the
// coordinates a_j, μ_j, ln κ_j, projected back onto valid lobes); it is kept only if its
// likelihood is at least θ1's, so L still never decreases. The convergence test is the plain
// step θ0 → θ1 of each cycle, and the result is always an M-step's. Where EM converges slowly
// (overlapping lobes, patch NDFs) it needs a quarter to two thirds of the M-steps for the same
// maximum (tests: VmfMixture.SquaremReachesEmsMaximumInFewerSteps, 137 → 33; the logo's x16
// SVNDF, 85.6 → 44.2 M-steps a patch on average, 13702 → 16104 of 16384 patches converged).
//
// Deterministic initialisation. Greedy weighted k-means++ on the sphere with the distance
// d(x, c) = 1 − x·c = |x − c|²/2 (the squared chord / 2, so this is k-means++'s D² sampling):
// the first centre is one draw ∝ w_i, each further centre the best (largest reduction of
// Σ w_i min_c d(x_i, c)) of 2(2 + ⌊ln K⌋) candidates drawn ∝ w_i d_i plus the direction
// farthest from all centres (which finds small isolated sharp lobes); then up to 10 Lloyd
// iterations of spherical k-means (hard assignment to the nearest centre, centre = normalised
// weighted resultant). This is done init_restarts times (PCG32 streams derived from
// VmfEmOptions::seed) and the start with the lowest k-means objective is kept: a single
// greedy seeding fell into a local optimum (a broad lobe split in two, two other lobes
// merged) in ~13 % of draws of the six-lobe test mixture, four restarts in 0 of 200. Its hard
// clusters give the initial a_j, μ_j, κ_j. Everything is sequential in a fixed order, so the
// same input and options give bit-identical output on every run. EM only finds a local
// maximum of the likelihood from there: lobes that k-means cannot separate (e.g. two sharp
// lobes closer together than the spread of a much heavier broad lobe) can still be merged.

// Degenerate inputs (all documented choices, all tested):
//  * n = 0, or total weight 0 (every w_i zero or ignored): an EMPTY mixture (no lobes,
//    log_likelihood 0, iterations 0); mixture_pdf of it is 0 everywhere. Not an error: a
//    patch can legitimately have no visible micro-normal, and the caller decides.
//  * Entries with a zero-length or non-finite direction, or a negative or non-finite weight,
//    are ignored (treated as weight 0). Weights are rescaled by their maximum internally, so
//    any finite positive scale works (the result does not depend on it).
//  * Fewer distinct directions than lobes: k-means++ stops adding centres once every
//    direction coincides with a centre (1 − x·c < 1e-12, i.e. within 1.4e-6 rad, below float
//    resolution of a unit vector), so m < K distinct directions give at most m lobes, each a
//    delta (κ = max_kappa) at its direction with the weight of its copies.
//  * All directions identical: one lobe, μ = that direction, κ = max_kappa, weight 1.
//  * A lobe whose weight a_j falls below min_weight after an M-step is DROPPED (not re-seeded:
//    re-seeding makes the likelihood non-monotone and can cycle); the remaining weights are
//    renormalised and EM continues. So the result can have fewer than K lobes.
//  * Antipodal / cancelling data (R_j = 0): κ_j = 0, see above.
// The returned lobes are sorted by decreasing weight (ties: by the order of their creation),
// and their weights sum to 1 (to rounding).
//
// Invalid options (lobes < 1, max_iterations < 0, tolerance < 0 or NaN, min_weight outside
// [0, 1), max_kappa ≤ 0 or NaN) throw MesoError.
//
// Cost: O(n K) per EM iteration (K exp per direction), single-threaded (fits of many patches
// are meant to be run in parallel by the caller), plus init_restarts × O(n K (ln K + 10)) for
// the k-means starts.
#pragma once
#include <cstddef>
#include <cstdint>
#include <vector>
#include "core/vec.h"
#include "texture/vmf_map.h"

namespace meso {

struct VmfMixture {
    std::vector<VmfLobe> lobes;   ///< sorted by decreasing weight; weights sum to 1
    double log_likelihood = 0.0;  ///< Σ w_i log p(x_i) / Σ w_i of the fitted parameters
    int iterations = 0;           ///< M-steps performed
    bool converged = false;       ///< the tolerance was met before max_iterations
};

struct VmfEmOptions {
    int lobes = 6;               ///< K, the most lobes returned (paper 004 and Han et al.: 6)
    int max_iterations = 100;    ///< EM iterations (M-steps); 0 returns the k-means start
    double tolerance = 1e-6;     ///< on the change of the mean log-likelihood, relative to 1 + |L|
    double min_weight = 1e-4;    ///< lobes whose weight falls below this are dropped
    double max_kappa = 1e6;      ///< κ is clamped to [0, max_kappa] (deltas become max_kappa)
    bool exact_kappa = false;    ///< κ from A₃(κ) = r (exact) instead of Banerjee's approximation
    bool accelerate = true;      ///< SQUAREM cycles (vmf_mixture.cpp, squarem); false: plain EM
    int init_restarts = 4;       ///< k-means++ / Lloyd starts; the lowest k-means objective is used
    uint64_t seed = 0x5eed0f5eedULL;  ///< PCG32 streams of the k-means++ initialisation
};

/// Fits a mixture of at most opt.lobes vMF lobes to the n directions dirs[i] with weights
/// weights[i] (weights may be nullptr: all 1). See the header comment for the details.
VmfMixture fit_vmf_mixture(const Vec3 *dirs, const double *weights, size_t n, const VmfEmOptions &opt = {});

/// fit_vmf_mixture's EM (SQUAREM or plain, the same convergence test and output rules) started
/// from `start` instead of the k-means++ starts: a good start (a finer patch's lobes merged by
/// reduce_vmf_lobes) needs fewer M-steps and skips k-means. Start lobes with a weight that is not
/// finite and > 0, or a zero μ, are ignored; the weights are renormalised. No usable start lobe:
/// fit_vmf_mixture. More usable start lobes than opt.lobes throws MesoError.
VmfMixture fit_vmf_mixture_from(const Vec3 *dirs, const double *weights, size_t n, const std::vector<VmfLobe> &start,
                                const VmfEmOptions &opt = {});

/// Merges weighted vMF lobes (weights need not sum to 1) into at most K: greedily, the pair whose
/// merge loses the least expected log-likelihood first (N_a ℓ_a + N_b ℓ_b − N_ab ℓ_ab, ℓ(r) =
/// log C(κ) + κ r of the moment-matched lobe), each group's lobe moment-matched (weight Σ w, mean
/// direction vector Σ w A₃(κ) μ / Σ w: μ, and κ by opt's rule; what an M-step gives on the
/// group's directions). Deterministic. Unusable lobes (as fit_vmf_mixture_from) are ignored;
/// the result's weights sum to 1, or it is empty.
std::vector<VmfLobe> reduce_vmf_lobes(const std::vector<VmfLobe> &lobes, int K, const VmfEmOptions &opt = {});

/// One lobe moment-matched to n weighted directions (weights nullptr: all 1): weight Σ w, μ the
/// mean direction, κ by opt's rule from its length (what one M-step gives them). A zero resultant
/// or mass gives weight 0 (an unusable start lobe).
VmfLobe moment_matched_lobe(const Vec3 *dirs, const double *weights, size_t n, const VmfEmOptions &opt = {});

/// The mixture density Σ a_j γ(w; μ_j, κ_j) (per steradian; 0 for an empty mixture).
double mixture_pdf(const VmfMixture &mixture, Vec3 w);

namespace vmf {
/// The exact inverse of the mean resultant length: κ ≥ 0 with A₃(κ) = coth κ − 1/κ = r, for r
/// in [0, 1) (r ≤ 0 gives 0; r ≥ 1 or no root below kMaxKappa gives kMaxKappa). Safeguarded
/// Newton from Banerjee's approximation, to ~1e-14 relative.
double kappa_from_mean_cosine(double r);
}  // namespace vmf

}  // namespace meso
