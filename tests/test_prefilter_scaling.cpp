// The scaling function T S of paper 004 (§6) as prefilter/scaling.h estimates it: flat maps give
// R = 1, a known spatial factor is recovered as T, rank-1 on a small case (Fig. 6, 10),
// determinism and bad input; the fast estimator unbiased against brute force and its reported
// standard error against the spread over seeds. `meso prefilter` end to end and the white
// furnace: test_cmd_prefilter.cpp.
#include <gtest/gtest.h>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "cli_capture.h"
#include "core/error.h"
#include "geometry/heightfield.h"
#include "geometry/heightmap_gen.h"
#include "material_test_util.h"
#include "prefilter/effective_brdf.h"
#include "prefilter/least_squares.h"
#include "prefilter/model.h"
#include "prefilter/level_error.h"
#include "prefilter/patch_ndf.h"
#include "prefilter/scaling.h"
#include "sampling/rng.h"

using namespace meso;
using namespace meso::prefilter;
using meso::test::make_material;

namespace {

/// A level of a prefiltered model built in memory: h_low, SVNDF, f'_low, both heightfields in
/// cell space (map heights in tile units, as the generators make them).
struct Level {
    HeightMap fine, coarse;
    Heightfield orig, low;
    std::unique_ptr<SvMultiLobe> flow;
    /// lobes_base: the base's JSON for the closed-form f'_low (--flow lobes), null for eq. 5's quadrature.
    Level(const HeightMap &map, int F, std::shared_ptr<const Material> low_base, const char *lobes_base = nullptr)
        : fine(map) {
        LowResHeights l = downsample_least_squares(map, F, true, 0.01);
        coarse = HeightMap(l.width, l.height);
        for (size_t k = 0; k < l.h.size(); ++k) coarse.h[k] = float(l.h[k]);
        orig = Heightfield(fine, float(fine.width), 0.f);
        low = Heightfield(coarse, float(coarse.width), 0.f);
        PatchNdfOptions o;
        o.samples_per_cell = 2;
        o.cell_size = 1.0 / fine.width;
        o.em.exact_kappa = true;
        o.em.max_kappa = 1e9;  // as meso prefilter: flat patches are (nearly) deltas
        std::vector<PatchNdf> ndf = fit_svndf(Heightfield(fine, 1.f, 0.f), F, o);
        QuadratureOptions q;
        q.lobes = lobes_base != nullptr;
        flow = std::make_unique<SvMultiLobe>(std::move(low_base), ndf, coarse.width, coarse.height, q,
                                             lobes_base ? nlohmann::json::parse(lobes_base) : nlohmann::json());
    }
};

ScalingOptions small_options(int M, int N, int paths) {
    ScalingOptions o;
    o.M = M;
    o.N = N;
    o.orig_paths = paths;
    o.low_paths = paths;
    o.seed = 7;
    // No shadow-ray roulette: it perturbs the original's terms alone, so the exact cancellation
    // of the common random numbers on a flat map (and the variance comparisons below) would
    // not hold; the tests that want it set it (check_against_brute_force, the reported error).
    o.shadow_roulette = 0;
    return o;
}

}  // namespace

TEST(PrefilterScaling, FlatMapGivesUnitScaling) {
    // On a flat map the effective BRDF of both models is the base itself: R = 1 exactly in
    // expectation, and with common random numbers (same lines, same directions) the estimate
    // is 1 up to the f'_low quadrature of a delta NDF.
    for (const char *base_json : {R"({"type": "diffuse", "reflectance": 0.8})",
                                  R"({"type": "conductor", "material": "Au", "alpha": 0.3})"}) {
        auto base = make_material(base_json);
        Level L(HeightMap(32, 32, 0.f), 8, base);
        // M = 1: the patch is the whole period, no line is rejected, so both models see exactly
        // the same lines and directions (with M > 1, lines whose first hit leaves P are
        // rejected, differently on the two fields, and the jitter no longer cancels).
        ScalingOptions o = small_options(1, 5, 16);
        o.low_nodes = 0;  // the exact quadrature of f'_low (node sampling adds unbiased noise)
        ScalingEstimator est(L.orig, *base, L.low, *L.flow, o);
        est.add_round();
        ScalingTables single, ir;
        ScalingStats st;
        est.finish(single, ir, st);
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(single.T.at(0, 0, c), 1.0, 1e-6) << base_json;
        double worst = 0;
        for (int bo = 0; bo < 25; ++bo)
            for (int bi = 0; bi < 25; ++bi) {
                worst = std::max(worst, double(std::abs(single.S_bin(bi, bo)[1] - 1.f)));
                worst = std::max(worst, double(std::abs(ir.S_bin(bi, bo)[1] - 1.f)));
            }
        EXPECT_LT(worst, 2e-3) << base_json;
        EXPECT_EQ(st.leaked, 0u);
    }
}

TEST(PrefilterScaling, RecoversAKnownSpatialFactor) {
    // Flat map; the original base's albedo is a 2 x 2 checkerboard (0.2 / 0.8) and f'_low is
    // built on a uniform 0.5: R(P) = a(P) / 0.5 exactly, so T = a(P) / mean(a) = 0.4 / 1.6 and
    // S = mean(a) / 0.5 = 1 in every bin (up to the jitter of the lines rejected differently on
    // the two fields, ~1% in the grazing bins of this tiny case).
    auto orig_base = make_material(
        R"({"type": "diffuse", "reflectance": {"type": "checkerboard", "color0": 0.2, "color1": 0.8, "scale": 2}})");
    auto low_base = make_material(R"({"type": "diffuse", "reflectance": 0.5})");
    Level L(HeightMap(32, 32, 0.f), 8, low_base);
    ScalingOptions o = small_options(2, 5, 16);
    o.low_nodes = 0;
    ScalingEstimator est(L.orig, *orig_base, L.low, *L.flow, o);
    est.add_round();
    ScalingTables single, ir;
    ScalingStats st;
    est.finish(single, ir, st);
    const float t00 = single.T.at(0, 0, 1), t10 = single.T.at(1, 0, 1);
    EXPECT_NEAR(std::min(t00, t10), 0.4, 2e-3);
    EXPECT_NEAR(std::max(t00, t10), 1.6, 2e-3);
    EXPECT_NEAR(single.T.at(1, 1, 1), t00, 2e-3);
    EXPECT_NEAR(single.T.at(0, 1, 1), t10, 2e-3);
    for (int b = 0; b < 25; ++b) EXPECT_NEAR(single.S_bin(b, (b * 7) % 25)[1], 1.0, 0.02);
    // Exactly rank 1: all energy in the first singular value, T S reproduces R.
    EXPECT_GT(st.rank1_energy, 0.999);
    EXPECT_LT(st.ts_rel_error, 0.01);  // the ~1% jitter of S above; the rank is 1 exactly
}

TEST(PrefilterScaling, RankOneOnASmallCase) {
    // Paper 004 Fig. 6 / 10 on a small fbm case: the full sampled R (M² x N⁴) is tabulated by
    // the estimator; its first singular value carries most of the energy and the T S
    // factorisation is as good as the rank-1 SVD.
    std::map<std::string, std::string> p{{"size", "64"}, {"amplitude", "0.03"}, {"seed", "3"}};
    HeightMap map = generate_height_map("fbm", p).height;
    auto base = make_material(R"({"type": "conductor", "material": "Al", "alpha": 0.3})");
    Level L(map, 8, base);
    ScalingOptions o = small_options(4, 7, 64);
    ScalingEstimator est(L.orig, *base, L.low, *L.flow, o);
    est.add_round();
    ScalingTables single, ir;
    ScalingStats st;
    est.finish(single, ir, st);
    std::printf("rank-1 (single): energy %.4f, |R - T S|/|R| %.4f, rank-1 SVD %.4f, eq. 22-24 %.4f; "
                "(ir) energy %.4f, T S %.4f, SVD %.4f; S rel. std. error median %.4f\n",
                st.rank1_energy, st.ts_rel_error, st.rank1_svd_rel_error, st.paper_ts_rel_error, st.rank1_energy_ir,
                st.ts_rel_error_ir, st.rank1_svd_rel_error_ir, st.S_ir_rel_se_median);
    EXPECT_GT(st.rank1_energy, 0.95);
    EXPECT_GT(st.rank1_energy_ir, 0.95);
    EXPECT_LT(st.ts_rel_error, 1.1 * st.rank1_svd_rel_error + 0.01);
    EXPECT_LT(st.ts_rel_error_ir, 1.1 * st.rank1_svd_rel_error_ir + 0.01);
    ASSERT_EQ(st.singular_values.size(), 16u);
    EXPECT_GE(st.singular_values[0], st.singular_values[1]);
}

TEST(PrefilterScaling, DeterministicPerSeed) {
    std::map<std::string, std::string> p{{"size", "32"}, {"amplitude", "0.03"}};
    HeightMap map = generate_height_map("fbm", p).height;
    auto base = make_material(R"({"type": "diffuse", "reflectance": 0.7})");
    Level L(map, 8, base);
    auto run = [&](uint64_t seed) {
        ScalingOptions o = small_options(2, 5, 9);
        o.seed = seed;
        ScalingEstimator est(L.orig, *base, L.low, *L.flow, o);
        est.add_round();
        ScalingTables s, ir;
        ScalingStats st;
        est.finish(s, ir, st);
        return s.S.data;
    };
    EXPECT_EQ(run(3), run(3));
    EXPECT_NE(run(3), run(4));
}

// A LoD chain's levels estimated together (ScalingEstimator::add_round_group: the original's
// lines traced once for all) get exactly the tables each level gets alone with the same seed:
// sharing changes the cost, not the estimate. Mismatched estimators are refused.
TEST(PrefilterScaling, LevelsTracedTogetherMatchEachLevelAlone) {
    std::map<std::string, std::string> p{{"size", "32"}, {"amplitude", "0.03"}};
    HeightMap map = generate_height_map("fbm", p).height;
    auto base = make_material(R"({"type": "conductor", "alpha": 0.3, "material": "Au"})");
    Level L8(map, 8, base), L4(map, 4, base);
    ScalingOptions o = small_options(2, 5, 9);
    o.target_error = 1e-6;  // the stopping rule's second round traces the union of the active tasks
    auto tables = [](ScalingEstimator &e) {
        ScalingTables s, ir;
        ScalingStats st;
        e.finish(s, ir, st);
        return std::make_pair(s.S.data, ir.T.data);
    };
    ScalingEstimator a(L8.orig, *base, L8.low, *L8.flow, o), b(L8.orig, *base, L4.low, *L4.flow, o);
    for (int r = 0; r < 2; ++r) EXPECT_GT(ScalingEstimator::add_round_group({&a, &b}), 0u);
    for (auto [low, flow] : {std::pair{&L8.low, L8.flow.get()}, std::pair{&L4.low, L4.flow.get()}}) {
        ScalingEstimator alone(L8.orig, *base, *low, *flow, o);
        for (int r = 0; r < 2; ++r) alone.add_round();
        EXPECT_EQ(tables(alone), tables(low == &L8.low ? a : b));
    }
    EXPECT_EQ(a.stats().orig_lines, b.stats().orig_lines);
    EXPECT_NE(tables(a), tables(b));
    ScalingEstimator other_orig(L4.orig, *base, L4.low, *L4.flow, o);
    EXPECT_NE(meso::test::meso_error_of([&] { ScalingEstimator::add_round_group({&a, &other_orig}); })
                  .find("must share the original"), std::string::npos);
}

TEST(PrefilterScaling, BadInput) {
    auto base = make_material(R"({"type": "diffuse"})");
    Level L(HeightMap(32, 32, 0.f), 8, base);
    auto err = [&](ScalingOptions o) {
        return meso::test::meso_error_of([&] { ScalingEstimator(L.orig, *base, L.low, *L.flow, o); });
    };
    EXPECT_NE(err(small_options(3, 5, 4)).find("M = 3"), std::string::npos);
    EXPECT_NE(err(small_options(2, 0, 4)).find("N = 0"), std::string::npos);
    EXPECT_NE(err(small_options(2, 5, 0)).find("paths"), std::string::npos);
    ScalingOptions o = small_options(2, 5, 4);
    o.epsilon = 0;
    EXPECT_NE(err(o).find("epsilon"), std::string::npos);
}

// --- the fast estimator (splatted next-event terms, line pairs, common random numbers, the
// stopping rule) against brute force and against its own spread -----------------------------

namespace {

/// Brute force for one (ωi bin, ωo bin): the mean over J (ωo, ωi) pairs of an independent
/// effective-BRDF estimate (effective_brdf.h) over the whole map (M = 1), green channel, with
/// its standard error over the J pairs; the pairs are the two bins' centres, or with `jitter`
/// drawn uniformly in the bins' cells of the square (ScalingOptions::jitter_directions).
std::pair<double, double> brute_force_bin(const EffectiveBrdfEstimator &e, const Heightfield &hf, int N, int bi, int bo,
                                          int max_bounces, uint64_t seed, bool jitter) {
    const int J = 96;
    PCG32 rng(seed, 3);
    double s = 0, s2 = 0;
    for (int j = 0; j < J; ++j) {
        auto dir = [&](int b) {
            const float ja = rng.next_float(), jb = rng.next_float();
            return square_to_hemisphere(Vec2((float(b % N) + (jitter ? ja : 0.5f)) / float(N),
                                             (float(b / N) + (jitter ? jb : 0.5f)) / float(N)));
        };
        const Vec3 wo = dir(bo), wi = dir(bi);
        const double v = e.estimate(PatchRegion::whole(hf), wi, wo, 512, seed * 1000 + uint64_t(j), max_bounces).value[1];
        s += v, s2 += v * v;
    }
    const double mean = s / J;
    return {mean, std::sqrt(std::max(0.0, s2 / J - mean * mean) / (J - 1))};
}

}  // namespace

namespace {
/// Numerator (single bounce and with interreflections) and denominator of a few bin pairs,
/// grazing ones included, after three rounds of the stopping rule (later rounds trace only
/// some ωo bins: unequal line counts), against independent estimates of the same integrals;
/// with `cv_lines` > 0, with the control variate (scaling.h); with `lobes`, f'_low is the closed
/// form of --flow lobes (evaluated exactly per line instead of by sampled nodes); with `jitter`,
/// the directions are jittered in their bins (the bins' averages) instead of at their centres;
/// `roulette`: ScalingOptions::shadow_roulette (scaling.h, "Shadow-ray roulette"); `allocate`:
/// ScalingOptions::allocate_lines (rounds 2 and 3 with the allocation's unequal counts).
void check_against_brute_force(int cv_lines, bool lobes = false, bool jitter = false, double roulette = 1.0,
                               bool allocate = false, const char *amplitude = "0.05") {
    std::map<std::string, std::string> p{{"size", "32"}, {"amplitude", amplitude}, {"seed", "5"}};
    HeightMap map = generate_height_map("fbm", p).height;
    const char *base_json = R"({"type": "conductor", "material": "Al", "alpha": 0.3})";
    auto base = make_material(base_json);
    Level L(map, 8, base, lobes ? base_json : nullptr);
    const int N = 3;
    ScalingOptions o = small_options(1, N, 1600);
    o.cv_lines = cv_lines;
    o.jitter_directions = jitter;
    o.shadow_roulette = roulette;
    o.allocate_lines = allocate;
    // The target: the median over ωo bins of their errors after the first round (the same
    // first round: same seed), so that about half of the bins stop.
    {
        ScalingEstimator first(L.orig, *base, L.low, *L.flow, o);
        first.add_round();
        std::vector<double> per_bo = first.S_rel_se_per_wo_bin();
        std::nth_element(per_bo.begin(), per_bo.begin() + N * N / 2, per_bo.end());
        o.target_error = per_bo[size_t(N * N / 2)];
    }
    ScalingEstimator est(L.orig, *base, L.low, *L.flow, o);
    size_t traced = 0;
    for (int r = 0; r < 3; ++r) traced += est.add_round();
    EXPECT_LT(traced, size_t(3 * N * N)) << "the stopping rule traced every bin every round";
    EXPECT_GT(traced, size_t(N * N)) << "the stopping rule traced no bin after the first round";
    if (allocate) {
        EXPECT_NE(est.stats().orig_lines, est.stats().low_lines) << "the allocation kept the counts";
    }
    const EffectiveBrdfEstimator orig_bf(L.orig, *base);
    EffectiveBrdfEstimator::Options mo;
    mo.macro_frame = true;
    const EffectiveBrdfEstimator low_bf(L.low, *L.flow, mo);
    double chi2 = 0;
    int dof = 0;
    const std::pair<int, int> pairs[] = {{4, 4}, {0, 4}, {4, 8}, {1, 7}, {3, 5}, {8, 6}};  // (bi, bo); 4 = centre
    for (auto [bi, bo] : pairs) {
        for (bool ir : {false, true}) {
            const auto m = est.bin_moments(0, bi, bo, 1, ir);
            const auto [bf, bf_se] = brute_force_bin(orig_bf, L.orig, N, bi, bo, ir ? kAllBounces : 1, 11 + bi * 9 + bo, jitter);
            const double tol = 4.0 * std::hypot(m.num_se, bf_se);
            chi2 += (m.num - bf) * (m.num - bf) / (m.num_se * m.num_se + bf_se * bf_se), ++dof;
            EXPECT_NEAR(m.num, bf, tol) << "numerator bi " << bi << " bo " << bo << (ir ? " ir" : " single") << " se "
                                        << m.num_se << " / " << bf_se;
            EXPECT_GT(m.num, 0.0);
        }
        const auto m = est.bin_moments(0, bi, bo, 1, false);
        const auto [bf, bf_se] = brute_force_bin(low_bf, L.low, N, bi, bo, 1, 71 + bi * 9 + bo, jitter);
        EXPECT_NEAR(m.den, bf, 4.0 * std::hypot(m.den_se, bf_se)) << "denominator bi " << bi << " bo " << bo;
        chi2 += (m.den - bf) * (m.den - bf) / (m.den_se * m.den_se + bf_se * bf_se), ++dof;
    }
    // All 18 differences together (a common bias of a few percent shows here): chi-square with
    // 18 degrees of freedom, 42.3 its 0.999 quantile. (The single and ir numerators share their
    // first vertex, so they are correlated: the sum is a little wider than chi-square.)
    std::printf("cv lines %d: chi-square of the differences: %.1f (%d terms)\n", cv_lines, chi2, dof);
    EXPECT_LT(chi2, 42.3);
}
}  // namespace

TEST(PrefilterScalingEstimator, UnbiasedAgainstBruteForce) { check_against_brute_force(0); }
TEST(PrefilterScalingEstimator, ControlVariateUnbiasedAgainstBruteForce) { check_against_brute_force(1600); }
TEST(PrefilterScalingEstimator, LobesFormUnbiasedAgainstBruteForce) { check_against_brute_force(0, true); }
TEST(PrefilterScalingEstimator, JitteredDirectionsUnbiasedAgainstBruteForce) { check_against_brute_force(0, false, true); }
TEST(PrefilterScalingEstimator, NoShadowRouletteUnbiasedAgainstBruteForce) { check_against_brute_force(0, false, false, 0.0); }
TEST(PrefilterScalingEstimator, StrongShadowRouletteUnbiasedAgainstBruteForce) {
    check_against_brute_force(0, false, true, 16.0);  // most terms by roulette: its weights must be right
}
// A steep map whose h_low still shadows (its slope test clears few terms): the roulette on the
// denominator's shadow rays too, with the closed-form f'_low.
TEST(PrefilterScalingEstimator, StrongShadowRouletteOnSteepLowUnbiased) {
    check_against_brute_force(0, true, true, 16.0, false, "0.4");
}
TEST(PrefilterScalingEstimator, AllocatedLinesUnbiasedAgainstBruteForce) {
    check_against_brute_force(0, false, true, 1.0, true);  // rounds 2 and 3 with other counts per field
}

TEST(PrefilterScaling, LineAllocationIsTheOptimum) {
    // scaling.h, "Line allocation". One level: min A / Ko + D / Kl at Ko c_o + Kl c = budget has
    // Kl / Ko = √(D c_o / (A c)): A = D = 1, c_o = 1, c = 4 gives Kl = Ko / 2, Ko = 100 at 300.
    int Ko = 0;
    std::vector<int> Kl;
    allocate_lines({1.0}, {1.0}, 1.0, {4.0}, 300.0, 2, 400, 1000, Ko, Kl);
    ASSERT_EQ(Kl.size(), 1u);
    EXPECT_NEAR(Ko, 100, 4);
    EXPECT_NEAR(Kl[0], 50, 3);
    // Two levels, one with a noisy h_low: both reach the same error, below the equal split's worst.
    allocate_lines({1.0, 1.0}, {4.0, 0.25}, 1.0, {1.0, 1.0}, 300.0, 2, 400, 1000, Ko, Kl);
    ASSERT_EQ(Kl.size(), 2u);
    const double v0 = 1.0 / Ko + 4.0 / Kl[0], v1 = 1.0 / Ko + 0.25 / Kl[1];
    EXPECT_NEAR(v0, v1, 0.05 * v0);
    EXPECT_LT(std::max(v0, v1), 1.0 / 100 + 4.0 / 100);
    EXPECT_LE(Ko + Kl[0] + Kl[1], 300 + 2);
    // A level whose h_low has no noise gets the fewest lines; nothing is ever below a pair.
    allocate_lines({1.0, 1.0}, {1.0, 0.0}, 1.0, {1.0, 1.0}, 300.0, 2, 400, 1000, Ko, Kl);
    EXPECT_EQ(Kl[1], 2);
    EXPECT_GE(Kl[0], 2);
}

namespace {
/// One round of the estimator with options o, finished into single / ir; its stats.
template <class LevelT>
ScalingStats one_round(const LevelT &L, const Material &base, const ScalingOptions &o, ScalingTables &single,
                       ScalingTables &ir) {
    ScalingEstimator est(L.orig, base, L.low, *L.flow, o);
    est.add_round();
    ScalingStats st;
    est.finish(single, ir, st);
    return st;
}

/// The median over table entries (one vector of values over seeds each) of the relative
/// standard deviation over seeds (entries with a mean of 0 skipped).
double median_rel_spread(const std::vector<std::vector<double>> &per_entry) {
    std::vector<double> rel;
    for (const auto &v : per_entry) {
        const double n = double(v.size());
        double m = 0, m2 = 0;
        for (double x : v) m += x / n, m2 += x * x / n;
        if (m > 0) rel.push_back(std::sqrt(std::max(0.0, m2 - m * m) * n / (n - 1)) / m);
    }
    if (rel.empty()) return 0.0;
    std::nth_element(rel.begin(), rel.begin() + long(rel.size() / 2), rel.end());
    return rel[rel.size() / 2];
}
/// S of a reciprocity study over seeds, in two modes (0: the direct estimate, 1: the reciprocal
/// average): per mode the totals of S per ring class (both bins inside the outer ring, one in it,
/// both in it) and their second moments over seeds, every entry's values, and the reported
/// median errors.
struct TwoModeStudy {
    int N, B, seeds;
    double tot[2][3] = {}, tot2[2][3] = {};
    std::vector<std::vector<double>> S[2];
    std::vector<double> rep[2];
    TwoModeStudy(int n, int s) : N(n), B(n * n), seeds(s) {
        for (auto &v : S) v.resize(size_t(B) * B);
    }
    bool outer(int b) const { return b % N == 0 || b % N == N - 1 || b / N == 0 || b / N == N - 1; }
    void add(int mode, const ScalingTables &single, double reported) {
        rep[mode].push_back(reported);
        double t[3] = {};
        for (int bo = 0; bo < B; ++bo)
            for (int bi = 0; bi < B; ++bi) {
                const double v = single.S_bin(bi, bo)[1];
                S[mode][size_t(bo) * B + bi].push_back(v);
                t[outer(bi) ? (outer(bo) ? 2 : 1) : (outer(bo) ? 1 : 0)] += v;
            }
        for (int k = 0; k < 3; ++k) tot[mode][k] += t[k] / seeds, tot2[mode][k] += t[k] * t[k] / seeds;
    }
    double spread(int mode) const { return median_rel_spread(S[mode]); }
    double reported(int mode) const {
        std::vector<double> r = rep[mode];
        std::nth_element(r.begin(), r.begin() + long(r.size() / 2), r.end());
        return r[r.size() / 2];
    }
    /// The two modes' totals per ring class agree within 4 standard errors.
    void expect_equal_totals() const {
        for (int k = 0; k < 3; ++k) {
            double se2 = 0;
            for (int m = 0; m < 2; ++m) se2 += std::max(0.0, tot2[m][k] - tot[m][k] * tot[m][k]) / (seeds - 1);
            std::printf("class %d: S total direct %.4f, combined %.4f (+- %.4f)\n", k, tot[0][k], tot[1][k], std::sqrt(se2));
            EXPECT_NEAR(tot[1][k], tot[0][k], 4 * std::sqrt(se2) + 1e-9) << "class " << k;
        }
    }
};
}  // namespace

TEST(PrefilterScalingEstimator, ReportedStandardErrorMatchesTheSpreadOverSeeds) {
    // The median relative standard error of S the estimator reports against the spread of S
    // over 16 seeds (median over bin pairs). Positions stratified two lines a cell (12 lines:
    // 3 x 2 cells, 16: 4 x 2): each pair is two independent samples of one stratum, so the pair
    // estimate is exact in expectation and counts the stratification's gain (it was conservative
    // when 16 lines sat one a cell and pairs spanned neighbouring cells).
    std::map<std::string, std::string> p{{"size", "32"}, {"amplitude", "0.05"}, {"seed", "5"}};
    HeightMap map = generate_height_map("fbm", p).height;
    auto base = make_material(R"({"type": "conductor", "material": "Al", "alpha": 0.3})");
    Level L(map, 8, base);
    // (lines of sight, control-variate lines): the control variate's two independent sums
    // (the cheap lines' pairs at independent positions: 12 a task) add up in the reported error.
    for (auto [paths, cv_lines] : {std::pair{12, 0}, std::pair{16, 0}, std::pair{12, 12}}) {
        const int seeds = 16, N = 3, B = N * N;
        std::vector<std::vector<double>> S(size_t(B) * B);
        std::vector<double> reported;
        for (int seed = 1; seed <= seeds; ++seed) {
            ScalingOptions o = small_options(2, N, paths);
            o.seed = uint64_t(seed);
            o.cv_lines = cv_lines;
            o.shadow_roulette = 1;  // the default: the reported error must count its variance too
            ScalingTables single, ir;
            const ScalingStats st = one_round(L, *base, o, single, ir);
            reported.push_back(st.S_rel_se_median);
            for (int bo = 0; bo < B; ++bo)
                for (int bi = 0; bi < B; ++bi) S[size_t(bo) * B + bi].push_back(single.S_bin(bi, bo)[1]);
        }
        std::nth_element(reported.begin(), reported.begin() + seeds / 2, reported.end());
        const double empirical = median_rel_spread(S), rep = reported[size_t(seeds / 2)];
        std::printf("paths %d, cv lines %d: reported median rel. std. error of S %.4f, spread over seeds %.4f\n", paths,
                    cv_lines, rep, empirical);
        EXPECT_GT(rep, 0.8 * empirical) << paths;
        EXPECT_LT(rep, 1.25 * empirical) << paths;
    }
}

TEST(PrefilterScalingEstimator, ReciprocityLowersTheVarianceWithoutBiasOnOneTile) {
    // scaling.h, "Reciprocity": with M = 1 (the whole periodic tile, where the effective BRDF is
    // exactly reciprocal) the combined S against the direct one over 12 seeds each: the totals
    // per ring class agree within 4 standard errors, the spread over seeds of S shrinks (median
    // over bin pairs, below 0.95x the direct one's: with ½ / ½ weights the gain is largest where
    // both halves are equally noisy; 0.75x in reported error on the bench plane) and the reported
    // error follows the spread.
    // The check mode reports Σ R / Σ N near 1 and leaves S as the direct estimate.
    std::map<std::string, std::string> p{{"size", "32"}, {"amplitude", "0.08"}, {"seed", "5"}};
    HeightMap map = generate_height_map("fbm", p).height;
    auto base = make_material(R"({"type": "conductor", "material": "Al", "alpha": 0.3})");
    Level L(map, 8, base);
    const int seeds = 12, N = 5;
    TwoModeStudy study(N, seeds);
    for (int mode = 0; mode < 2; ++mode)
        for (int seed = 1; seed <= seeds; ++seed) {
            ScalingOptions o = small_options(1, N, 64);
            o.low_paths = 128, o.low_nodes = 0;  // a quiet denominator: S's noise is the numerator's
            o.seed = uint64_t(seed + 50 * mode);
            o.reciprocity = mode == 1;
            o.check_reciprocity = mode == 0 && seed == 1;
            ScalingTables single, ir;
            const ScalingStats st = one_round(L, *base, o, single, ir);
            if (o.check_reciprocity) {
                std::printf("reciprocity check, M = 1: inner %.4f, wi outer %.4f, wo outer %.4f\n", st.reciprocity_check[0],
                            st.reciprocity_check[1], st.reciprocity_check[2]);
                for (int k = 0; k < 3; ++k) EXPECT_NEAR(st.reciprocity_check[k], 1.0, 0.08) << k;
            }
            study.add(mode, single, st.S_rel_se_median);
        }
    const double spread[2] = {study.spread(0), study.spread(1)}, reported[2] = {study.reported(0), study.reported(1)};
    std::printf("median rel. spread of S over seeds: direct %.4f, combined %.4f (reported %.4f, %.4f)\n", spread[0],
                spread[1], reported[0], reported[1]);
    EXPECT_LT(spread[1], 0.95 * spread[0]);
    EXPECT_GT(reported[1], 0.8 * spread[1]);
    EXPECT_LT(reported[1], 1.25 * spread[1]);
    study.expect_equal_totals();
}

TEST(PrefilterScalingEstimator, PatchesWithJitteredDirectionsAreReciprocal) {
    // scaling.h, "Weights": with M > 1 a kept line of sight is weighted by |Q(ωo)| / |P|, so that
    // a bin's mean is its average over ωo and not biased towards the ωo of the bin whose
    // shooting region is smallest (the less grazing part of a grazing bin). The reciprocity
    // check (transposed over direct single-bounce numerators) must then be 1 in every ring class
    // with patches as with one tile; without the weights the pairs with ωi in the outer ring
    // came out 1.17-1.22 on the bench twill (docs/bench.md, "Reciprocity").
    std::map<std::string, std::string> p{{"size", "32"}, {"amplitude", "0.1"}, {"seed", "5"}};
    HeightMap map = generate_height_map("fbm", p).height;
    auto base = make_material(R"({"type": "conductor", "material": "Al", "alpha": 0.3})");
    Level L(map, 8, base);
    for (int M : {1, 2}) {
        ScalingOptions o = small_options(M, 5, M == 1 ? 1024 : 256);
        o.check_reciprocity = true;
        ScalingTables single, ir;
        const ScalingStats st = one_round(L, *base, o, single, ir);
        std::printf("M = %d: reciprocity check inner %.4f, wi outer %.4f, wo outer %.4f\n", M, st.reciprocity_check[0],
                    st.reciprocity_check[1], st.reciprocity_check[2]);
        for (int k = 0; k < 3; ++k) EXPECT_NEAR(st.reciprocity_check[k], 1.0, 0.04) << "M " << M << " class " << k;
    }
}

TEST(PrefilterScalingEstimator, ControlVariateIsUnbiased) {
    // The control variate (scaling.h) against the plain estimator, independent seeds, on a
    // steep glossy map (shadowing and interreflections: g - c is far from 0) with M = 2 (lines
    // rejected outside the patch, cheap ones too). Two statistics: (1) the numerators' total over
    // all patches, bin pairs and channels, single and ir, compared over 16 seeds each: its
    // standard error is below 0.75% of the total, so a bias of 3% is 4 standard errors or more;
    // (2) per (patch, bin pair), the difference over the two reported standard errors: a
    // chi-square per degree of freedom near 1 (also tests the reported errors).
    std::map<std::string, std::string> p{{"size", "32"}, {"amplitude", "0.12"}, {"seed", "9"}};
    HeightMap map = generate_height_map("fbm", p).height;
    auto base = make_material(R"({"type": "conductor", "material": "Al", "alpha": 0.2})");
    Level L(map, 8, base);
    const int N = 3, B = N * N, P = 4, seeds = 16;
    double chi2 = 0;
    int dof = 0;
    for (bool ir : {false, true}) {
        std::vector<double> tot[2];
        for (int seed = 1; seed <= seeds; ++seed) {
            const ScalingEstimator *e[2];
            ScalingOptions o = small_options(2, N, 192);
            o.seed = uint64_t(seed);
            ScalingEstimator plain(L.orig, *base, L.low, *L.flow, o);
            o.seed = uint64_t(100 + seed);
            o.cv_lines = 384;
            ScalingEstimator cv(L.orig, *base, L.low, *L.flow, o);
            e[0] = &plain, e[1] = &cv;
            plain.add_round(), cv.add_round();
            EXPECT_GT(cv.stats().cv_lines, size_t(0));
            for (int k = 0; k < 2; ++k) {
                double t = 0;
                for (int patch = 0; patch < P; ++patch)
                    for (int bo = 0; bo < B; ++bo)
                        for (int bi = 0; bi < B; ++bi)
                            for (int c = 0; c < 3; ++c) t += e[k]->bin_moments(patch, bi, bo, c, ir).num;
                tot[k].push_back(t);
            }
            if (seed == 1)
                for (int patch = 0; patch < P; ++patch)
                    for (int bo = 0; bo < B; ++bo)
                        for (int bi = 0; bi < B; ++bi) {
                            const auto a = plain.bin_moments(patch, bi, bo, 1, ir), b = cv.bin_moments(patch, bi, bo, 1, ir);
                            const double v = a.num_se * a.num_se + b.num_se * b.num_se;
                            if (v > 0) chi2 += (a.num - b.num) * (a.num - b.num) / v, ++dof;
                        }
        }
        double m[2], se2 = 0;
        for (int k = 0; k < 2; ++k) {
            double s1 = 0, s2 = 0;
            for (double x : tot[k]) s1 += x, s2 += x * x;
            m[k] = s1 / seeds;
            se2 += std::max(0.0, s2 / seeds - m[k] * m[k]) / (seeds - 1);
        }
        const double se = std::sqrt(se2);
        std::printf("%s numerator total: plain %.5f, control variate %.5f, difference %.2f%% +- %.2f%%\n", ir ? "ir" : "single",
                    m[0], m[1], 100 * (m[1] / m[0] - 1), 100 * se / m[0]);
        EXPECT_LT(se, 0.0075 * m[0]) << "the test could not see a 3% bias";
        EXPECT_NEAR(m[1], m[0], 4 * se) << (ir ? "ir" : "single");
    }
    // 2 x 4 x 81 terms (single and ir share their lines: the sum is a little wider than
    // chi-square); for 648 degrees of freedom, 1.2 per degree is beyond 3.5 standard deviations.
    std::printf("chi-square per degree of freedom: %.3f (%d terms)\n", chi2 / dof, dof);
    EXPECT_LT(chi2 / dof, 1.25);
    EXPECT_GT(chi2 / dof, 0.75);
}

TEST(PrefilterLevelError, FlatMapHasNoErrorAndRemovesNoVariance) {
    // A flat map: every cell of both surfaces reflects the same, and no line varies within a
    // cell (a diffuse base: the integrand is constant), so E and V are 0 up to f'_low's
    // quadrature of a delta NDF.
    auto base = make_material(R"({"type": "diffuse", "reflectance": 0.8})");
    Level L(HeightMap(32, 32, 0.f), 4, base);
    LevelErrorOptions o;
    o.cells = 16, o.directions = 4, o.lines = 32;
    const LevelError e = measure_level_error(L.orig, *base, L.low, *L.flow, 4, o);
    ASSERT_FALSE(e.window_error.empty());
    for (double w : e.window_error) EXPECT_LT(w, 1e-6);
    EXPECT_NEAR(e.removed_variance, 0.0, 1e-6);
    // Windows of 1, 2 cells (at least 4 fit in the 8 x 8 cells).
    EXPECT_EQ(e.window_error.size(), 3u);
}

TEST(PrefilterLevelError, BumpsAreRemovedVarianceAndMismatchesThrow) {
    // fbm bumps under a glossy base: a line's value varies within a cell (V > 0), by far more
    // than the cell means differ from the level's after its global scale (E < V).
    std::map<std::string, std::string> p{{"size", "64"}, {"amplitude", "0.03"}, {"seed", "3"}};
    HeightMap map = generate_height_map("fbm", p).height;
    auto base = make_material(R"({"type": "conductor", "material": "Al", "alpha": 0.3})");
    Level L(map, 8, base);
    LevelErrorOptions o;
    o.cells = 32, o.directions = 4, o.lines = 64;
    const LevelError e = measure_level_error(L.orig, *base, L.low, *L.flow, 8, o);
    EXPECT_GT(e.removed_variance, 0.01);
    EXPECT_LT(e.patch_error, e.removed_variance);
    EXPECT_THROW(measure_level_error(L.orig, *base, L.low, *L.flow, 4, o), MesoError);
    o.lines = 1;
    EXPECT_THROW(measure_level_error(L.orig, *base, L.low, *L.flow, 8, o), MesoError);
}

// The stopping rule's standard errors (current_S_rel_se, from a green-only fit in a per-thread
// workspace reused between estimators and rounds) are exactly those of the full finish(): two
// estimators of different sizes (M = 2, N = 3 and M = 1, N = 4) take turns, so the workspace is
// resized and reused, with reciprocity on and later rounds tracing some bins only.
TEST(PrefilterScalingEstimator, StoppingRuleErrorsMatchTheFinishedTables) {
    std::map<std::string, std::string> p{{"size", "32"}, {"amplitude", "0.05"}, {"seed", "3"}};
    HeightMap map = generate_height_map("fbm", p).height;
    auto base = make_material(R"({"type": "conductor", "material": "Al", "alpha": 0.3})");
    Level L(map, 8, base);
    ScalingOptions oa = small_options(2, 3, 16), ob = small_options(1, 4, 24);
    oa.target_error = ob.target_error = 0.05;
    ScalingEstimator a(L.orig, *base, L.low, *L.flow, oa), b(L.orig, *base, L.low, *L.flow, ob);
    for (int r = 0; r < 3; ++r)
        for (ScalingEstimator *e : {&a, &b}) {
            e->add_round();
            const double rule = e->current_S_rel_se();
            ScalingTables single, ir;
            ScalingStats st;
            e->finish(single, ir, st);
            EXPECT_GT(rule, 0.0);
            EXPECT_EQ(rule, std::max(st.S_rel_se_median, st.S_ir_rel_se_median)) << "round " << r;
        }
}

// scaling_fit.cpp, apply_reciprocity: with the stopping rule the ωo bins trace unequal line counts,
// and the reciprocal average weights each half by its bin's lines (w = n(bo) / (n(bo) + n(bi))).
// Over 12 seeds (a quarter of the bins stop after round 1, the rest trace up to six rounds), the combined S
// against the direct one (reciprocity off): totals per ring class within 4 standard errors, and
// the reported median error within 0.8-1.25x of the spread over seeds. Variances combined with
// other weights than the values' (½ in the variance, counts in the value, or the reverse) miss
// the spread.
TEST(PrefilterScalingEstimator, ReciprocityWithUnequalLineCountsIsUnbiasedAndCalibrated) {
    std::map<std::string, std::string> p{{"size", "32"}, {"amplitude", "0.08"}, {"seed", "5"}};
    HeightMap map = generate_height_map("fbm", p).height;
    auto base = make_material(R"({"type": "conductor", "material": "Al", "alpha": 0.3})");
    Level L(map, 8, base);
    const int seeds = 12, N = 5, B = N * N;
    TwoModeStudy study(N, seeds);
    for (int mode = 0; mode < 2; ++mode)
        for (int seed = 1; seed <= seeds; ++seed) {
            ScalingOptions o = small_options(1, N, 32);
            o.low_paths = 128, o.low_nodes = 0;  // a quiet denominator: S's noise is the numerator's
            o.seed = uint64_t(seed + 50 * mode);
            o.reciprocity = mode == 1;
            {
                ScalingEstimator first(L.orig, *base, L.low, *L.flow, o);
                first.add_round();
                std::vector<double> per_bo = first.S_rel_se_per_wo_bin();
                std::nth_element(per_bo.begin(), per_bo.begin() + B / 4, per_bo.end());
                o.target_error = per_bo[size_t(B / 4)];
            }
            ScalingEstimator est(L.orig, *base, L.low, *L.flow, o);
            for (int r = 0; r < 6; ++r) est.add_round();
            ScalingTables single, ir;
            ScalingStats st;
            est.finish(single, ir, st);
            if (mode == 1) {
                EXPECT_TRUE(st.reciprocity_used) << "seed " << seed;
            }
            study.add(mode, single, st.S_rel_se_median);
        }
    const double spread[2] = {study.spread(0), study.spread(1)}, reported[2] = {study.reported(0), study.reported(1)};
    std::printf("unequal counts: median rel. spread of S over seeds: direct %.4f, combined %.4f (reported %.4f, %.4f)\n",
                spread[0], spread[1], reported[0], reported[1]);
    EXPECT_GT(reported[1], 0.8 * spread[1]);
    EXPECT_LT(reported[1], 1.25 * spread[1]);
    // The gain over the direct estimate: 0.874x its spread with these seeds; ½ / ½ weights gave
    // 0.976x (a quarter of the stopped bins' variance stays in every pair they transpose).
    EXPECT_LT(spread[1], 0.93 * spread[0]);
    study.expect_equal_totals();
}
