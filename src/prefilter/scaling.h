// The scaling function of paper 004 (Wu et al. 2019), §4.3, §5.2 and §6, estimated directly
// as its factors T(x) (M x M) and S(ωi, ωo) (N² x N², concentric bins, prefilter/model.h):
//
//   R(P, ωi, ωo) = f_eff(ωi, ωo; G_orig(P), f_orig) / f_eff(ωi, ωo; G_low(P), f'_low)   (eq. 12, 20)
//   R ≈ T(P) S(ωi, ωo),  T of mean 1                                                  (eq. 14, 21)
//
// with the numerator single-bounce (eq. 6, tables `single`) and with interreflections
// (eq. 17, tables `ir`) from the SAME traced paths (the first vertex's next-event terms are
// the single-bounce estimate), the denominator single-bounce on h_low with f'_low (eq. 20:
// the high-order terms of the low model are left to the path tracer, eq. 19).
//
// Bins, not points. num(P, bin_i, bin_o) and den(P, bin_i, bin_o) are INTEGRALS over the two
// angular cells (of f_eff·cos θi), estimated with ωo jittered uniformly in its cell of the
// square and ωi on a randomly shifted copy of the bin grid (one shift per line of sight).
//
// The factorisation. Eq. 22-24 average per-cell ratios num/den over patches (S) and over bins
// (T); every near-empty, noisy denominator then enters a mean unguarded (the paper adds ε and
// excludes θ > 75°). Here T and S are the rank-1 fit that MATCHES ENERGY (iterative
// proportional fitting, ~10 sweeps):
//     S_b = Σ_P num_Pb / Σ_P T_P den_Pb,     T_P = Σ_b num_Pb / Σ_b S_b den_Pb,
// i.e. T S f'_low on h_low reflects exactly the original's energy in every bin pair (summed
// over patches) and in every patch (summed over bin pairs). For an exactly rank-1 R it gives
// R's factors, the same as eq. 22-24 (tested); on sampled data it is a ratio of sums over 16
// patches or N⁴ bin pairs instead of a mean of ratios. ε (relative to the mean denominator)
// only steers genuinely empty cells to 1. ScalingStats reports the rank-1 check of the full
// sampled R (SVD) against both this fit and eq. 22-24.
//
// Grazing angles. Bins are equidistant in θ (prefilter/model.h): the outer ring is the last
// 2 x 90°/N (78°..90° at N = 15, centre 84°), not the 60°..90° of a cosine-weighted lift, and
// its cells are estimated like all others (the median error of the outer ring is reported
// separately). No direction is excluded.
//
// Splatting (the cost lever). A line of sight along -ωo and the path it starts do not depend
// on ωi, so every path vertex sends next-event terms towards ALL N² ωi bins: one traced path
// gives a sample to N² bins. Shadow rays rising faster than a local bound on the slopes that
// can shadow their origin are skipped exactly, and the others stop where nothing farther can
// block them (slope_bound.h: the steepest |∇h| around the origin and the heights of coarser
// rings; the logo's h_low shadow rays 121M -> 65M a round, its round 1.23x faster). On h_low,
// f'_low (a sum over ~144 nodes) is estimated per line from `low_nodes` nodes drawn by weight
// (unbiased), and line k on h_low reuses line k's ωo, ωi shift and position on the original
// (common random numbers).
//
// Work: for every patch P (M²) and ωo bin (N²), `orig_paths` lines of sight on G_orig
// (positions stratified, two lines a stratum: "Standard errors") and `low_paths` on G_low; (P, ωo bin)
// pairs run in parallel (TBB), each with its own PCG32 streams (hash of seed, round, task,
// line): results depend on (seed, options) only, not on the thread count. Rounds (add_round)
// can be added to reach a target standard error. Under MPI the tasks are dealt out to the ranks
// (task t to rank t mod ranks, every round) and exchanged after each round: the tables are
// bit-identical to a single process's (docs/cluster.md).
//
// Levels share the original (add_round_group). The numerator does not depend on the level:
// the levels of one model (a LoD chain) are estimated together, each line of sight on G_orig
// traced once for all of them, and only the h_low lines per level. A chain of n levels then
// costs one original's lines plus n h_low ones per round instead of n of each. The numerator's
// sums (and their pair terms) are accumulated in the lead level's arrays alone and copied to the
// others after each task (the same values: every level traces the same tasks every round).
//
// Standard errors (what the stopping rule and the manifest report). The lines of a task are
// taken in consecutive pairs, and each table entry keeps Σ over pairs of the squared difference
// of the pair's two values: with n lines Var(mean) ≈ Σ_pairs (x_a - x_b)² / n². The pairs are
// the strata: the shooting region Q is cut into n / 2 cells (a near-square grid) and lines 2h
// and 2h + 1 start at independent uniform points of cell h (an odd n's last line anywhere in Q),
// so the sum is the unbiased variance of the stratified mean (E (x_a - x_b)² = 2 σ_h²), which
// counts the stratification's gain. Measured (bench plane x32, one round, spread over 6 seeds of
// S's entries, median): 0.0386 unstratified -> 0.0365 (the reported error 0.0655 -> 0.0634);
// also stratifying ωo's jitter or the ωi grid's shift (2 x 2 each, position 4 x 4) gained less
// (0.0374-0.0376). Until session 39 positions were stratified only for a square n, one line a
// cell, and the pairs of neighbouring cells made the sum conservative. When the
// original and h_low trace the same number of lines, line k of both shares its random numbers
// and Σ_pairs (a_a - a_b)(d_a - d_b) gives the covariance of the numerator and denominator
// means: the delta method for the ratio then counts the correlation of the common random
// numbers. S and T take their standard errors from these by the delta method (T or S fixed).
//
// Stopping rule (add_round(target)): after the first round only the ωo bins whose median
// relative standard error of S (over ωi bins; single and ir, the larger) is above the target
// are traced again, for every patch; the others keep their sums. Each task's mean divides by its
// own line count, so unequal counts leave every estimate unbiased.
//
// Directions. The renderer reads S by bilinear interpolation between bin CENTRES (table_lookup.cpp),
// so a line's ωo and every ωi may sit at those centres (jitter_directions = false): each entry
// then estimates S at the point the lookup assumes, with about 8% less standard error (twill).
// The default stays the bin's average (ωo uniform in its bin, the ωi grid randomly shifted per
// line): at the centres, bins where f'_low nearly vanishes at the centre direction (silk's
// second ring along the yarns, θ ≈ 78°) got S ≈ 49 and the renders fireflies (bench silk
// ours_fixed MSE 30-60e-3 against 3.4e-3).
//
// Control variate (cv_lines > 0). Most of the numerator's noise is the first vertex's terms:
// which micro-normal a line hits and where ωo, ωi fall in their bins (a glossy lobe reaches few
// bins). Their unshadowed part c = f_base(ωo, ωi; m) at the first vertex (no shadow ray, no
// further bounce, no h_low line) is cheap. Every line of sight adds g - c (g its traced terms,
// single and ir: the difference is the shadowing and the interreflections), and `cv_lines`
// extra lines per task, drawn like the lines of sight (ωo, ωi shift, position; own streams),
// estimate E[c]: num = mean(g - c) + mean_cheap(c), unbiased whatever c is (both terms estimate
// the same E[c]); its variance is Var(g - c) / n + Var(c) / K, the two independent (the
// standard errors add both; S_rel_se_median_paper_counts scales both by the lines of sight).
// Measured (2 cores, one round, median rel. s.e. of S): it pays where shadowing is weak and
// loses where it is strong. `silk` (N = 15, M = 4, 32 lines): 0.304 plain, 0.212 with K = 128,
// 0.167 with K = 512; a cheap line costs about 1/10 of a line of sight (its h_low line
// included), so about 1.5x less variance at equal time with K ~ 5n (3 min, --target-error 0.03:
// 0.121 plain, 0.080 with K = 160, 7 rounds each). Tiny `plane` (steep
// twill): Var(c) is above Var(g) and Var(g - c) about half of it, a loss at every K.
//
// Weights. With M > 1 a line of sight is shot from Q(ωo), P widened by the drift of a line
// through the height range, and kept when its first hit is in P: it is kept with probability
// a_P(ωo) |P| / |Q(ωo)|. With ωo jittered in its bin, |Q| varies over the bin (at the outer ring,
// 78-90° at N = 15, tan θ from 4.7 to infinity), so the kept lines over-represented the less
// grazing part of a grazing bin: the plain mean over kept lines was not the bin's average.
// Every kept line is therefore weighted by |Q(ωo)| / |P| (its terms, and the divisor is the sum
// of the weights), which makes the mean the bin's average weighted by a_P(ωo), the patch's
// visible projected area (1 on average over the tile): on the original, on h_low and for the
// control variate's lines. With Q = P (M = 1, or a patch spanning whole periods) every weight
// is 1 and nothing changes. Found by the reciprocity check below (ωi in the outer ring: 1.22 at
// M = 4 with jitter; 1.00 with M = 1, or with the directions at the bins' centres).
//
// Reciprocity (on unless cv_lines > 0). Over the whole periodic tile the original's effective
// BRDF is reciprocal (paper 004 eq. 25; effective_brdf.h): f_eff(ωi, ωo) / cos θi =
// f_eff(ωo, ωi) / cos θo, single bounce and with interreflections. So a line of sight of task
// (P, bo) that splats g towards ωi (bin bi) also estimates the TRANSPOSED bin pair (ωo as the
// light, ωi as the viewer) with g cos θo / cos θi, and every bin pair gets two independent
// estimates: its own lines' and its transpose's. Per patch this holds only weighted by the
// patch's visible projected area a_P(ω) (the ratio of what P shows towards ω to its flat
// area: 1 on a stationary map, not on an emblem), so the combination is made on the tile:
// N(j) = Σ_P a_P(bo) num_P(j) / Σ_P a_P(bo) and R(j) the same from the transposed lines with
// a_P(bi); a_P(bo) = mean over the task's shot lines of accepted · |Q| / |P| (scaling.h's
// shooting region, eq. 7-8). The numerators of bin pair j are then scaled by
// (w N + (1 - w) R) / N in every patch (T keeps the patches' differences), w the share of bo's
// lines in those of bo and bi over the tile (½ with equal counts; with the stopping rule's
// unequal counts a fixed ½ kept a quarter of a stopped bin's variance in every pair it
// transposes: silk's worst S sat at 0.036), and the standard error of S counts both halves.
// Diagonal pairs (bi = bo: the same lines) are left as they are. The
// average loses half of the common random numbers' cancellation (exact on a flat map), so a
// table takes it only where it lowers S's median standard error (ScalingStats::reciprocity_used;
// one choice per table, so it biases no bin). Measured (docs/bench.md, "Reciprocity"): on the
// bench plane (twill, gold Beckmann 0.25, x16-x128, M = 4, one round) the median relative standard
// error of S goes 0.0857 -> 0.0665 for 11% more time. `check_reciprocity` alone keeps the transposed estimates and reports
// how they agree (ScalingStats::reciprocity_check; `meso prefilter --reciprocity check`): 1.00
// in every ring class with the weights above, 1.17-1.22 where ωi is grazing without them.
//
// Shadow-ray roulette (shadow_roulette = ε > 0, off with cv_lines > 0). A glossy base sends most
// of a vertex's next-event terms c = throughput · f towards bins far from its lobe: tiny, yet
// each needs a shadow ray. A term whose c (largest channel, times the line's weight |Q| / |P|)
// is below ref = ε · (the bin's mean term per line so far: the task's earlier rounds and this
// round's earlier lines, of the sum the term goes to; none before 8 lines) is traced with
// probability c / ref and then counts ref (c / probability): unbiased (the decision depends
// only on earlier lines), with at most ε · mean · c more variance per term, ε · mean² per line,
// against a per-line variance that is many mean² for a glossy base. Only terms that need a
// shadow ray take part (those that the slope test clears are added as they are: no ray to save).
// Measured (docs/bench.md, session 38): the bench plane's round
// 24.3 -> 20.7 s at ε = 1 with S's median error 0.0665 -> 0.0666; ε = 4 gains 0.5 s more and
// costs 0.0675, ε = 16 0.0778. On h_low the same rule (session 41; its reference the bin's mean
// denominator term per accepted h_low line of the level, its decisions from the line's own
// stream, the same for every level): a steep h_low (the logo's x4, 512²) traces a shadow ray
// for nearly every one of the N² terms of f'_low, most of them tiny. The logo's chain, two
// rounds: 62.7 -> 52.1 s (S 0.0582 -> 0.0594); the plane's one round 32.2 -> 27.8 s (S equal).
//
// Line allocation (allocate_lines; `meso prefilter --allocate-lines`). A level's S error per round
// is about A / Ko + D / Kl: A the original's variance per line (its relative error², the median
// over bin pairs, times the lines so far), D its h_low's, Ko and Kl the lines per task. The
// original's line serves every level of a chain; each level pays for its own h_low lines, and
// their noise differs: on the bench plane's chain (twill, one round of 256 original and 64 h_low
// lines against 32) D is 0.135 at x16 (h_low 32², still rough) and 0.012 at x64, against A 0.45.
// After the first round (equal counts, as given), every round chooses Ko and each Kl_j that
// minimise the largest level's A_j / Ko + D_j / Kl_j at the cost of the given counts, from the
// variances so far and the measured seconds per line (allocate_lines() below: a search over Ko,
// then the Kl_j that give every level the same error). Unequal counts lose the common random
// numbers' covariance for those lines (the delta method then omits it, which is conservative:
// the correlation is positive). The counts depend on timings, so tables are not reproducible
// to the bit from the seed (nor between MPI and one process) with it; without it they are.
//
// Units: both heightfields in cell space (effective_brdf.h); `low` covers the same tile with
// W_low = W / F cells (its heights in its own cell units). The low model's material (an
// SvMultiLobe) is evaluated in the MACRO frame; the original's base in the micro-normal frame.
#pragma once
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <vector>
#include "geometry/heightfield.h"
#include "prefilter/effective_brdf.h"
#include "prefilter/model.h"
#include "prefilter/slope_bound.h"
#include "bsdf/material.h"

namespace meso::prefilter {

struct ScalingOptions {
    int M = 4;                     ///< spatial resolution of T (must divide both maps' sizes)
    int N = 15;                    ///< angular resolution of S (per axis of the concentric square)
    bool interreflections = true;  ///< also estimate the _ir tables (paths beyond one vertex)
    int orig_paths = 64;           ///< lines of sight per (patch, ωo bin) on G_orig, per round
    int low_paths = 64;            ///< lines of sight per (patch, ωo bin) on G_low, per round
    /// f'_low on G_low: 0 = its deterministic quadrature (all nodes), J > 0 = an unbiased
    /// estimate from J nodes per line of sight, stratified by node weight (cost / nodes·J)
    int low_nodes = 4;
    int max_bounces = kAllBounces; ///< path vertices on G_orig (with interreflections)
    int roulette_start = 4;        ///< Russian roulette from this vertex (effective_brdf.h)
    double epsilon = 1e-2;         ///< ε of eq. 12, relative to the mean denominator (see finish())
    uint64_t seed = 1;
    /// Stopping rule of add_round (pipeline: --target-error): 0 traces every task every round.
    double target_error = 0;
    /// Control variate (see "Control variate" above): cheap lines per (patch, ωo bin) per round
    /// that evaluate the first vertex's terms without shadow rays (0: no control variate).
    int cv_lines = 0;
    /// Reciprocity (see "Reciprocity" above): S's numerators also estimated from the lines of
    /// the transposed bin pair, and the two averaged (ignored with cv_lines > 0).
    bool reciprocity = true;
    /// Keep the transposed estimates and report their agreement with the direct ones
    /// (ScalingStats::reciprocity_check) without combining them; implied by `reciprocity`.
    bool check_reciprocity = false;
    /// Where a line's directions sit in their bins (see "Directions" above): false = at the bin
    /// centres, the points S's lookup interpolates between (table_lookup.cpp); true = jittered,
    /// ωo uniformly in its bin and all ωi bins on one random shift of the grid per line.
    bool jitter_directions = true;
    /// Shadow-ray roulette on G_orig (see "Shadow-ray roulette" above): a next-event term c
    /// below this times its bin's mean so far is traced with probability c / (that) and
    /// weighted by its inverse (0: every term traced; ignored with cv_lines > 0).
    double shadow_roulette = 1;
    /// Line allocation (see "Line allocation" above): after the first round, each round's lines on
    /// the original and on every level's h_low are chosen from the measured variances and costs
    /// per line, at the cost of orig_paths and low_paths lines (tables then depend on timings).
    bool allocate_lines = false;
    /// Called with the fraction of (patch, ωo bin) tasks of the current round done (any thread,
    /// serialised by the caller's responsibility: it is called under a mutex here).
    std::function<void(double)> progress;
};

/// What one level's estimate reached (all relative standard errors are of the green channel).
struct ScalingStats {
    size_t orig_lines = 0, low_lines = 0;      ///< lines of sight traced (all rounds)
    size_t orig_vertices = 0;                  ///< path vertices on G_orig (each sends N² shadow rays)
    size_t rejected = 0, leaked = 0;           ///< hits outside P (when M > 1), missed surfaces
    /// thread time spent on G_orig (the control variate's lines included) / G_low (summed over threads and rounds)
    double core_seconds_orig = 0, core_seconds_low = 0;
    double seconds = 0;                        ///< wall time of all rounds
    int rounds = 0;
    // Standard errors (delta method, numerator and denominator independent).
    double S_rel_se_median = 0, S_rel_se_p90 = 0, S_rel_se_max = 0;
    double S_rel_se_median_outer = 0;          ///< over ωo and ωi both in the outer ring of bins (grazing)
    double T_rel_se_max = 0, T_rel_se_median = 0, T_ir_rel_se_median = 0;
    size_t tasks_traced = 0;                   ///< (patch, ωo bin) tasks traced over all rounds
    size_t cv_lines = 0;                       ///< the control variate's cheap lines (all rounds)
    size_t estimator_bytes = 0;                ///< memory of the estimator's sums
    /// What the paper's sample counts (2500 paths per effective-BRDF estimate, §7.1) would give
    /// for the median of S with the per-line variances measured here: the noise target.
    double S_rel_se_median_paper_counts = 0, S_ir_rel_se_median_paper_counts = 0;
    double S_ir_rel_se_median = 0, S_ir_rel_se_p90 = 0, S_ir_rel_se_median_outer = 0, T_ir_rel_se_max = 0;
    // Rank-1 check of the sampled R (M² x (bin pairs with both centres at θ ≤ 75°), green
    // channel; §6 Fig. 6, 10; the paper excludes θ > 75° there too).
    double rank1_energy = 0;        ///< σ1² / Σ σk²
    double rank1_svd_rel_error = 0; ///< ||R - σ1 u1 v1ᵀ||_F / ||R||_F
    double ts_rel_error = 0;        ///< ||R - T ⊗ S||_F / ||R||_F (this factorisation)
    double paper_ts_rel_error = 0;  ///< the same for eq. 22-24's T', S' (means of R), for comparison
    double rank1_energy_ir = 0, rank1_svd_rel_error_ir = 0, ts_rel_error_ir = 0, paper_ts_rel_error_ir = 0;
    std::vector<double> singular_values, singular_values_ir;  ///< all M² of them, descending
    /// The reciprocity check of the single-bounce numerators (check_reciprocity; "Reciprocity"
    /// above): Σ R / Σ N over the bin pairs with both bins inside the outer ring, with ωi in it,
    /// with ωo in it (1 where the estimator is reciprocal; 0: not checked).
    double reciprocity_check[3] = {0, 0, 0};
    /// S and T (single; ir_used for ir) come from the reciprocal average: with `reciprocity` it
    /// is kept only where it lowers the table's median relative standard error.
    bool reciprocity_used = false, reciprocity_used_ir = false;
};

/// Accumulates the sums of one level over rounds, then produces T and S.
class ScalingEstimator {
public:
    /// Keeps references. `low_material` is evaluated in the macro frame (an SvMultiLobe).
    /// Throws MesoError when M or N are out of range (M ≥ 1 dividing both maps' sizes; N in
    /// [1, 64]), the maps' aspect ratios differ, or paths < 1.
    ScalingEstimator(const Heightfield &orig, const Material &base, const Heightfield &low,
                     const SvMultiLobe &low_material, const ScalingOptions &opt);

    /// One more round of opt.orig_paths / opt.low_paths lines per (patch, ωo bin); after the
    /// first round, with opt.target_error > 0, only for the ωo bins still above it (scaling.h,
    /// "Stopping rule"). Returns the number of tasks traced (0: every bin is below the target).
    size_t add_round();
    /// One round for several levels of ONE original (a LoD chain; the estimators share the
    /// original field and base objects, M, N, the line counts and their round count; the first
    /// one's seed draws the lines): each line of sight on the original is traced once and its
    /// terms go to every level's numerator sums, and each level traces its own h_low line k with
    /// line k's random numbers (common random numbers, as for one level). The stopping rule
    /// traces the union of the levels' active tasks, so every level gets the same lines. Each
    /// level's stats count the original's lines and an equal share of their time and of the
    /// round's wall time. Throws MesoError when the estimators do not match.
    static size_t add_round_group(const std::vector<ScalingEstimator *> &group);
    /// T and S (single and, with interreflections, ir) from the sums so far, and their stats.
    void finish(ScalingTables &single, ScalingTables &ir, ScalingStats &stats) const;
    /// The median relative standard error of S (the larger of single and ir) so far.
    double current_S_rel_se() const;
    /// Per ωo bin, the median over ωi bins of S's relative standard error (the larger of single
    /// and ir); 0 where nothing was estimated.
    std::vector<double> S_rel_se_per_wo_bin() const;
    /// The numerator (the original's f_eff·cos θi, ir or single bounce) and denominator (h_low
    /// with f'_low) of one (patch, ωi bin, ωo bin, channel) as means over the bins' directions
    /// and the patch's visible points, with their standard errors (tests, diagnostics).
    struct BinMoments {
        double num = 0, num_se = 0, den = 0, den_se = 0;
        uint32_t lines_orig = 0, lines_low = 0;
    };
    BinMoments bin_moments(int patch, int bi, int bo, int channel, bool ir) const;
    /// R(P, bin_i, bin_o) for one channel from the current sums (tests, diagnostics).
    double R(int patch, int bi, int bo, int channel, bool ir) const;
    const ScalingStats &stats() const { return m_stats; }
    /// Replaces ScalingOptions::progress (a group's rounds report through their first estimator).
    void set_progress(std::function<void(double)> f) { m_opt.progress = std::move(f); }

private:
    struct Task;  ///< one (patch, ωo bin) task of a round (scaling.cpp)
    void trace_task(const std::vector<ScalingEstimator *> &group, size_t task, uint64_t round_seed);
    size_t add_round_impl(const std::vector<ScalingEstimator *> &group);
    /// MPI: every rank's tasks of the round to every rank (add_round), counters summed.
    void share_round(const ScalingStats &before, const std::vector<size_t> &active);
    double denom_mean(int ch) const;
    /// finish(); with per_bo, also S_rel_se_per_wo_bin (and no rank-1 check: the stopping rule).
    /// rel_var (nullable, two entries): the median relative variances of S's numerator and denominator
    /// (of the table, single or ir, with the larger median error) for the line allocation.
    void finish_impl(ScalingTables &single, ScalingTables &ir, ScalingStats &stats, std::vector<double> *per_bo,
                     double *rel_var = nullptr) const;

    const Heightfield &m_orig, &m_low;
    const Material &m_base;
    const SvMultiLobe &m_low_mat;
    ScalingOptions m_opt;
    int m_bins = 0;  // N²
    // Flattened [patch][bo][bi][ch]: sums of the line values, Σ over line pairs of squared
    // differences (*sq) and of products of numerator and denominator differences (*x).
    std::vector<double> m_n1, m_n1sq, m_nir, m_nirsq, m_d, m_dsq, m_n1x, m_nirx;
    std::vector<uint32_t> m_count_orig, m_count_low;  // accepted lines per (patch, bo)
    // Control variate: Σ c over the cheap lines and Σ over their pairs of squared differences
    // (flattened as above), accepted cheap lines per (patch, bo).
    std::vector<double> m_cv, m_cvsq;
    std::vector<uint32_t> m_count_cv;
    // Reciprocity: every accepted line's terms times cos θo / cos θi (the transposed pair's
    // estimate, stored under the line's own task and ωi bin), their pair-difference squares,
    // and per (patch, bo) the lines shot and Σ |Q| / |P| over the accepted ones (a_P(ωo)).
    std::vector<double> m_r1, m_r1sq, m_rir, m_rirsq, m_area;
    std::vector<uint32_t> m_shot;
    // The means' divisors (see "Weights"): per (patch, bo), Σ |Q| / |P| over the accepted lines
    // on the original (m_area), on h_low and of the control variate.
    std::vector<double> m_wsum_low, m_wsum_cv;
    /// Local bounds on the slopes that can shadow a shadow ray's origin (slope_bound.h): h_low's
    /// built with the estimator, the original's on first use (only a group's lead traces it).
    std::unique_ptr<const SlopeBound> m_low_bound;
    mutable std::unique_ptr<const SlopeBound> m_orig_bound;
    mutable std::once_flag m_orig_bound_once;
    const SlopeBound &orig_bound() const;
    /// current_S_rel_se and S_rel_se_per_wo_bin of the sums after round `rounds` (se_cache).
    struct SeCache {
        int rounds = -1;
        double median = 0;
        std::vector<double> per_bo;
        double rel_var[2] = {0, 0};  ///< finish_impl's rel_var
    };
    mutable SeCache m_se_cache;
    mutable std::mutex m_se_mutex;
    SeCache se_cache() const;
    ScalingStats m_stats;
    /// Lines per (patch, ωo bin) of the next round (the options' counts, or the allocation's).
    struct RoundLines {
        int orig = 0, low = 0;
    };
    RoundLines m_round_lines;
    /// After a round of `group` (allocate_lines): the next round's counts for every level.
    static void allocate_next_round(const std::vector<ScalingEstimator *> &group);
};

/// The line allocation's optimum (ScalingOptions::allocate_lines): given per level j the
/// original's and h_low's variances per line of S's relative error (A_j, D_j) and the seconds per
/// line of the original (c_o, one line serves every level) and of level j's h_low (c_j), the
/// counts Ko, Kl_j that minimise max_j (A_j / Ko + D_j / Kl_j) at the cost Ko c_o + Σ Kl_j c_j =
/// budget; Ko in [ko_min, ko_max], each Kl_j in [2, kl_max].
void allocate_lines(const std::vector<double> &A, const std::vector<double> &D, double c_o, const std::vector<double> &c,
                    double budget, int ko_min, int ko_max, int kl_max, int &Ko, std::vector<int> &Kl);

}  // namespace meso::prefilter
