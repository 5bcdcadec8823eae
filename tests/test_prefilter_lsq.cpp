// Least-squares downsampled heights (paper 004 §4.1, eq. 9-10, Appendix A): exactness on maps
// the method can represent, the w -> 0 limit, slope fidelity and its w-dependence, optimality
// against other coarse maps, mean preservation, errors, extreme inputs, direct vs CG.
#include <gtest/gtest.h>
#include <cstdlib>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <vector>
#include "core/error.h"
#include "geometry/heightfield.h"
#include "geometry/heightmap_gen.h"
#include "prefilter/least_squares.h"
#include "sampling/rng.h"

using namespace meso;
using namespace meso::prefilter;

namespace {

/// Random coarse heights: integers in [-64, 64] so that the bilinear upsampling by a power of
/// two is exact in float (the fine map stores floats).
std::vector<double> random_coarse(int w, int h, uint64_t seed) {
    std::vector<double> c(size_t(w) * h);
    PCG32 rng(seed);
    for (double &v : c) v = std::floor(rng.next_float() * 129.f) - 64.0;
    return c;
}

/// The fine map whose bilinear surface is the coarse map's: fine vertex (i, j) = coarse
/// surface at (i / F, j / F), wrapping across the coarse seam.
HeightMap upsample(const std::vector<double> &c, int wc, int hc, int F) {
    HeightMap m(wc * F, hc * F);
    for (int j = 0; j < m.height; ++j)
        for (int i = 0; i < m.width; ++i) {
            const int I = i / F, J = j / F, I1 = (I + 1) % wc, J1 = (J + 1) % hc;
            const double a = double(i % F) / F, b = double(j % F) / F;
            const double v = (1 - a) * (1 - b) * c[size_t(J) * wc + I] + a * (1 - b) * c[size_t(J) * wc + I1] +
                             (1 - a) * b * c[size_t(J1) * wc + I] + a * b * c[size_t(J1) * wc + I1];
            m.at(i, j) = float(v);
        }
    return m;
}

double max_abs(const std::vector<double> &v) {
    double m = 0;
    for (double x : v) m = std::max(m, std::abs(x));
    return m;
}

/// max |a - b - (a - b)[0]|: the difference up to a constant offset.
double diff_mod_const(const std::vector<double> &a, const std::vector<double> &b) {
    double m = 0;
    const double d0 = a[0] - b[0];
    for (size_t k = 0; k < a.size(); ++k) m = std::max(m, std::abs(a[k] - b[k] - d0));
    return m;
}

/// Laplacian of the header's convention (periodic 5-point; otherwise the axes with both neighbours).
std::vector<double> laplacian(const std::vector<double> &h, int w, int hh, bool periodic) {
    std::vector<double> out;
    for (int J = 0; J < hh; ++J)
        for (int I = 0; I < w; ++I) {
            double v = 0;
            bool any = false;
            auto at = [&](int i, int j) { return h[size_t((j + hh) % hh) * w + size_t((i + w) % w)]; };
            if (periodic || (I > 0 && I < w - 1)) v += at(I + 1, J) + at(I - 1, J) - 2 * at(I, J), any = true;
            if (periodic || (J > 0 && J < hh - 1)) v += at(I, J + 1) + at(I, J - 1) - 2 * at(I, J), any = true;
            if (any) out.push_back(v);
        }
    return out;
}

double dot(const std::vector<double> &a, const std::vector<double> &b) {
    double s = 0;
    for (size_t k = 0; k < a.size(); ++k) s += a[k] * b[k];
    return s;
}

/// Objective of eq. (10) for any coarse map (independent re-implementation for the optimality test).
double objective(const HeightMap &fine, int F, bool periodic, double w, const std::vector<double> &h) {
    const int wc = fine.width / F, hc = fine.height / F;
    const CellSlopes ref = reference_slopes(fine, F, periodic), got = bilinear_slopes(h, wc, hc, periodic);
    double e = 0;
    for (size_t k = 0; k < ref.sx.size(); ++k)
        e += (got.sx[k] - ref.sx[k]) * (got.sx[k] - ref.sx[k]) + (got.sy[k] - ref.sy[k]) * (got.sy[k] - ref.sy[k]);
    const std::vector<double> l = laplacian(h, wc, hc, periodic);
    return e + w * dot(l, l);
}

HeightMap fbm_map(int size, uint64_t seed, double amplitude = 0.05) {
    return generate_height_map("fbm", {{"size", std::to_string(size)},
                                       {"seed", std::to_string(seed)},
                                       {"amplitude", std::to_string(amplitude)}})
        .height;
}

std::string error_of(const std::function<void()> &f) {
    try {
        f();
    } catch (const MesoError &e) {
        return e.what();
    }
    return "";
}

}  // namespace

// (1a) A non-periodic map whose coarse heights are a bilinear polynomial has zero data
// residual and zero regulariser: it is reproduced exactly at the paper's w = 0.01.
TEST(PrefilterLsq, NonPeriodicBilinearPolynomialIsExact) {
    const int wc = 17, hc = 13, F = 4;
    std::vector<double> c(size_t(wc) * hc);
    for (int J = 0; J < hc; ++J)
        for (int I = 0; I < wc; ++I) c[size_t(J) * wc + I] = 3.0 - 2.0 * I + 5.0 * J + 0.5 * I * J;
    const HeightMap fine = upsample(c, wc, hc, F);
    for (LsqSolver solver : {LsqSolver::Direct, LsqSolver::CG}) {
        LsqOptions o;
        o.periodic = false;
        o.solver = solver;
        const LowResHeights r = downsample_least_squares(fine, F, o);
        ASSERT_EQ(r.width, wc);
        ASSERT_EQ(r.height, hc);
        double err = 0;
        for (size_t k = 0; k < c.size(); ++k) err = std::max(err, std::abs(r.h[k] - c[k]));
        EXPECT_LE(err, 1e-8 * max_abs(c)) << r.solver;
        EXPECT_LE(r.slope_rms_error, 1e-8 * r.slope_rms_reference);
    }
}

// (1b) Random coarse heights, bilinearly upsampled: the slopes are matched exactly by the true
// coarse map, so as w -> 0 the solution tends to it, except for the checkerboard component no
// average slope can see (periodic: removed; non-periodic: the amount that minimises the
// Laplacian). The error to that limit shrinks linearly with w and is at solver precision for
// small w.
TEST(PrefilterLsq, BilinearUpsampledMapTendsToTheCoarseMap) {
    const int F = 4;
    for (bool periodic : {true, false}) {
        const int wc = periodic ? 12 : 13, hc = periodic ? 10 : 11;
        const std::vector<double> c = random_coarse(wc, hc, periodic ? 3 : 4);
        const HeightMap fine = upsample(c, wc, hc, F);
        std::vector<double> cb(c.size());
        for (int J = 0; J < hc; ++J)
            for (int I = 0; I < wc; ++I) cb[size_t(J) * wc + I] = ((I + J) % 2) ? -1.0 : 1.0;
        double alpha;
        if (periodic) {
            alpha = -dot(c, cb) / dot(cb, cb);
        } else {
            const std::vector<double> lc = laplacian(c, wc, hc, false), lb = laplacian(cb, wc, hc, false);
            alpha = -dot(lc, lb) / dot(lb, lb);
        }
        std::vector<double> limit(c.size());
        for (size_t k = 0; k < c.size(); ++k) limit[k] = c[k] + alpha * cb[k];
        double prev = 1e300;
        for (double w : {1e-2, 1e-4, 1e-6, 1e-8}) {
            const LowResHeights r = downsample_least_squares(fine, F, periodic, w);
            const double err = diff_mod_const(r.h, limit) / max_abs(c);
            std::printf("periodic %d w %.0e: relative error to the w->0 limit %.3e, slope rms error %.3e\n", periodic,
                        w, err, r.slope_rms_error);
            EXPECT_LT(err, prev * 0.05) << "w " << w;  // ~linear in w (factor 100 per step)
            prev = err;
            if (w <= 1e-8) {
                EXPECT_LE(err, 1e-5);
            }
        }
        // At the paper's w this white-noise coarse map, full of near-Nyquist content that the
        // slopes barely see, keeps its slopes within ~11% rms (the regulariser's price).
        const LowResHeights r = downsample_least_squares(fine, F, periodic, 0.01);
        std::printf("periodic %d w 0.01: slope rms error %.3f of the reference rms\n", periodic,
                    r.slope_rms_error / r.slope_rms_reference);
        EXPECT_LE(r.slope_rms_error, 0.15 * r.slope_rms_reference);
        // w = 0 exactly: the data term alone, checkerboard component projected out: the coarse
        // map minus its checkerboard component, up to a constant, to round-off.
        const LowResHeights r0 = downsample_least_squares(fine, F, periodic, 0.0);
        std::vector<double> no_cb(c.size()), cbc = cb;  // checkerboard orthogonal to constants
        double cbm = 0;
        for (double v : cb) cbm += v / double(cb.size());
        for (double &v : cbc) v -= cbm;
        const double beta = dot(c, cbc) / dot(cbc, cbc);
        for (size_t k = 0; k < c.size(); ++k) no_cb[k] = c[k] - beta * cb[k];
        EXPECT_LE(diff_mod_const(r0.h, no_cb), 1e-8 * max_abs(c));
        EXPECT_LE(r0.slope_rms_error, 1e-8 * r0.slope_rms_reference);
    }
}

// (2) On random microgeometry the average slopes of h_low's cells match the reference to
// within what the regulariser allows: with h0 the (near) w -> 0 minimiser,
// E(w) <= L(h_w) <= L(h0) = E(h0) + w |Delta h0|^2, and E(w) decreases as w -> 0.
TEST(PrefilterLsq, SlopesMatchReferenceWithinRegulariserBound) {
    struct Case {
        const char *name;
        HeightMap map;
        bool periodic;
        int F;
    };
    std::vector<Case> cases;
    cases.push_back({"fbm 256 / 8", fbm_map(256, 11), true, 8});
    cases.push_back({"fbm 192x128 / 4", generate_height_map("fbm", {{"width", "192"}, {"height", "128"}, {"seed", "5"}}).height,
                     true, 4});
    cases.push_back({"gaussian ramp 256 / 8 (non-periodic)",
                     generate_height_map("gaussian", {{"size", "256"}, {"seed", "2"}, {"mx", "0.3"}, {"my", "-0.2"}}).height,
                     false, 8});
    for (const Case &cs : cases) {
        const LowResHeights h0 = downsample_least_squares(cs.map, cs.F, cs.periodic, 1e-9);
        double prev = 1e300;
        for (double w : {1.0, 0.1, 0.01, 0.001}) {
            const LowResHeights r = downsample_least_squares(cs.map, cs.F, cs.periodic, w);
            const double bound = h0.slope_sq_error + w * h0.laplacian_sq;
            std::printf("%s w %g: slope rms error %.4e (reference rms %.4e, relative %.3f), bound rms %.4e\n", cs.name,
                        w, r.slope_rms_error, r.slope_rms_reference, r.slope_rms_error / r.slope_rms_reference,
                        std::sqrt(bound / r.data_cells));
            EXPECT_LE(r.slope_sq_error, bound * (1 + 1e-9)) << cs.name << " w " << w;
            EXPECT_LE(r.slope_sq_error, prev * (1 + 1e-9)) << cs.name << " w " << w;
            EXPECT_GE(r.slope_sq_error, h0.slope_sq_error * (1 - 1e-6)) << cs.name << " w " << w;
            prev = r.slope_sq_error;
        }
        // At the paper's w the slopes are close to the reference on these smooth maps.
        const LowResHeights r = downsample_least_squares(cs.map, cs.F, cs.periodic, 0.01);
        EXPECT_LE(r.slope_rms_error, 0.25 * r.slope_rms_reference) << cs.name;
    }
}

// The solution minimises eq. (10): no other coarse map (point samples, box filter, perturbed
// solutions) has a lower objective, and the reported objective is the independent one.
TEST(PrefilterLsq, SolutionMinimisesTheObjective) {
    const int F = 8;
    for (bool periodic : {true, false}) {
        const HeightMap fine = fbm_map(256, 21);
        const LowResHeights r = downsample_least_squares(fine, F, periodic);
        const int wc = r.width, hc = r.height;
        const double best = objective(fine, F, periodic, 0.01, r.h);
        EXPECT_NEAR(best, r.objective, 1e-9 * best);
        std::vector<double> point(r.h.size()), box(r.h.size());
        const HeightMap boxed = Heightfield(fine, 1.f, 0.f).box_downsampled(F);
        for (int J = 0; J < hc; ++J)
            for (int I = 0; I < wc; ++I) {
                point[size_t(J) * wc + I] = fine.at(I * F, J * F);
                box[size_t(J) * wc + I] = boxed.at(I, J);
            }
        const double op = objective(fine, F, periodic, 0.01, point), ob = objective(fine, F, periodic, 0.01, box);
        std::printf("periodic %d: objective lsq %.5e, point-sampled %.5e, box %.5e\n", periodic, best, op, ob);
        EXPECT_LT(best, op);
        EXPECT_LT(best, ob);
        PCG32 rng(9);
        for (int trial = 0; trial < 5; ++trial) {
            std::vector<double> p = r.h;
            for (double &v : p) v += 1e-4 * (rng.next_float() - 0.5);
            EXPECT_GE(objective(fine, F, periodic, 0.01, p), best * (1 - 1e-12));
        }
    }
}

// (3) The mean height is preserved: plain vertex means when periodic, the trapezoid-weighted
// bilinear-surface means over the represented region otherwise.
TEST(PrefilterLsq, MeanHeightIsPreserved) {
    const HeightMap fine = fbm_map(128, 8);
    {
        const LowResHeights r = downsample_least_squares(fine, 4, true);
        double mf = 0, mc = 0;
        for (float v : fine.h) mf += v;
        for (double v : r.h) mc += v;
        mf /= double(fine.h.size()), mc /= double(r.h.size());
        EXPECT_NEAR(mc, mf, 1e-12 + 1e-10 * std::abs(mf));
        EXPECT_NEAR(r.mean_height, mf, 1e-12 + 1e-10 * std::abs(mf));
    }
    {
        const int F = 4;
        const LowResHeights r = downsample_least_squares(fine, F, false);
        auto trap = [](int i, int n) { return (i == 0 || i == n - 1) ? 0.5 : 1.0; };
        const int fw = (r.width - 1) * F + 1, fh = (r.height - 1) * F + 1;
        double sf = 0, wf = 0, sc = 0, wcs = 0;
        for (int j = 0; j < fh; ++j)
            for (int i = 0; i < fw; ++i) sf += trap(i, fw) * trap(j, fh) * fine.at(i, j), wf += trap(i, fw) * trap(j, fh);
        for (int J = 0; J < r.height; ++J)
            for (int I = 0; I < r.width; ++I)
                sc += trap(I, r.width) * trap(J, r.height) * r.at(I, J), wcs += trap(I, r.width) * trap(J, r.height);
        EXPECT_NEAR(sc / wcs, sf / wf, 1e-12 + 1e-10 * std::abs(sf / wf));
    }
}

// (4) Bad input gives a clear MesoError.
TEST(PrefilterLsq, BadInputThrows) {
    const HeightMap m = fbm_map(64, 1);
    EXPECT_NE(error_of([&] { downsample_least_squares(m, 3, true); }).find("divide"), std::string::npos);
    EXPECT_NE(error_of([&] { downsample_least_squares(m, 0, true); }).find(">= 1"), std::string::npos);
    EXPECT_NE(error_of([&] { downsample_least_squares(m, -2, false); }).find("factor"), std::string::npos);
    EXPECT_NE(error_of([&] { downsample_least_squares(m, 128, true); }).find("divide"), std::string::npos);
    EXPECT_NE(error_of([&] { downsample_least_squares(HeightMap(), 2, true); }).find("empty"), std::string::npos);
    EXPECT_NE(error_of([&] { downsample_least_squares(m, 2, true, -0.1); }).find("w must be"), std::string::npos);
    EXPECT_NE(error_of([&] { downsample_least_squares(m, 2, true, std::nan("")); }).find("w must be"),
              std::string::npos);
    HeightMap bad = m;
    bad.at(5, 7) = std::nanf("");
    EXPECT_NE(error_of([&] { downsample_least_squares(bad, 2, true); }).find("non-finite height at vertex (5, 7)"),
              std::string::npos);
    HeightMap malformed = m;
    malformed.h.pop_back();
    EXPECT_NE(error_of([&] { downsample_least_squares(malformed, 2, true); }).find("malformed"), std::string::npos);
    EXPECT_THROW(bilinear_slopes({1.0, 2.0}, 3, 1, true), MesoError);
}

// (5) Extreme inputs give finite, sensible results.
TEST(PrefilterLsq, ExtremeInputsAreFinite) {
    auto all_finite = [](const LowResHeights &r) {
        for (double v : r.h)
            if (!std::isfinite(v)) return false;
        return std::isfinite(r.slope_rms_error) && std::isfinite(r.objective);
    };
    for (bool periodic : {true, false}) {
        // Flat: exactly flat.
        const HeightMap flat(64, 64, 0.25f);
        const LowResHeights f = downsample_least_squares(flat, 4, periodic);
        ASSERT_TRUE(all_finite(f));
        for (double v : f.h) EXPECT_NEAR(v, 0.25, 1e-14);
        // Huge amplitude: finite and the same shape (the method is linear in the heights).
        const HeightMap small = fbm_map(64, 3, 1.0);
        HeightMap huge = small;
        for (float &v : huge.h) v *= 1e30f;
        const LowResHeights rs = downsample_least_squares(small, 4, periodic),
                            rh = downsample_least_squares(huge, 4, periodic);
        ASSERT_TRUE(all_finite(rh));
        const double ms = max_abs(rs.h);
        for (size_t k = 0; k < rs.h.size(); ++k) EXPECT_NEAR(rh.h[k] / 1e30, rs.h[k], 1e-6 * ms);
        // Tiny amplitude.
        HeightMap tiny = small;
        for (float &v : tiny.h) v *= 1e-30f;
        const LowResHeights rt = downsample_least_squares(tiny, 4, periodic);
        ASSERT_TRUE(all_finite(rt));
        for (size_t k = 0; k < rs.h.size(); ++k) EXPECT_NEAR(rt.h[k] / 1e-30, rs.h[k], 1e-5 * ms);
        // factor = size: one vertex at the mean.
        const LowResHeights one = downsample_least_squares(small, 64, periodic);
        ASSERT_EQ(one.width, 1);
        ASSERT_EQ(one.height, 1);
        ASSERT_TRUE(all_finite(one));
        double mean = 0;
        for (float v : small.h) mean += v;
        mean /= double(small.h.size());
        EXPECT_NEAR(one.h[0], mean, 1e-9);
        // factor = size / 2 (2 x 2 coarse: the smallest grid with a cell when non-periodic),
        // factor = 1 (no downsampling) and non-square maps.
        const LowResHeights two = downsample_least_squares(small, 32, periodic);
        ASSERT_TRUE(all_finite(two));
        EXPECT_EQ(two.width, 2);
        if (!periodic) {  // a lone cell: the planar solution, reference slopes matched exactly
            EXPECT_LE(two.slope_rms_error, 1e-9 * two.slope_rms_reference + 1e-15);
            EXPECT_NEAR(two.h[0] + two.h[3], two.h[1] + two.h[2], 1e-9 * max_abs(two.h));
            EXPECT_NEAR(0.25 * (two.h[0] + two.h[1] + two.h[2] + two.h[3]), two.mean_height, 1e-12);
        }
        const LowResHeights same = downsample_least_squares(small, 1, periodic);
        ASSERT_TRUE(all_finite(same));
        EXPECT_EQ(same.width, 64);
        const HeightMap rect = generate_height_map("fbm", {{"width", "96"}, {"height", "32"}, {"seed", "4"}}).height;
        const LowResHeights rr = downsample_least_squares(rect, 32, periodic);
        ASSERT_TRUE(all_finite(rr));
        EXPECT_EQ(rr.width, 3);
        EXPECT_EQ(rr.height, 1);
        // w = 0 (no regulariser): still solvable (the checkerboard is fixed by a tiny ridge).
        const LowResHeights w0 = downsample_least_squares(small, 4, periodic, 0.0);
        ASSERT_TRUE(all_finite(w0));
        EXPECT_LE(w0.slope_sq_error, rs.slope_sq_error * (1 + 1e-9));
    }
}

// The direct and the CG solver agree, and to_height_map() keeps the heights.
TEST(PrefilterLsq, DirectAndConjugateGradientsAgree) {
    const HeightMap fine = fbm_map(512, 17);
    for (bool periodic : {true, false}) {
        LsqOptions o;
        o.periodic = periodic;
        o.solver = LsqSolver::Direct;
        const LowResHeights d = downsample_least_squares(fine, 4, o);
        o.solver = LsqSolver::CG;
        const LowResHeights c = downsample_least_squares(fine, 4, o);
        EXPECT_EQ(d.solver, "direct");
        EXPECT_EQ(c.solver, "cg");
        EXPECT_GT(c.iterations, 0);
        double err = 0, range = 0;
        for (size_t k = 0; k < d.h.size(); ++k)
            err = std::max(err, std::abs(d.h[k] - c.h[k])), range = std::max(range, std::abs(d.h[k] - d.mean_height));
        std::printf("periodic %d: direct %.3fs, cg %.3fs (%d iterations), max difference %.3e of range %.3e\n",
                    periodic, d.solve_seconds, c.solve_seconds, c.iterations, err, range);
        EXPECT_LE(err, 1e-6 * range);
        const HeightMap hm = d.to_height_map();
        ASSERT_EQ(hm.width, d.width);
        EXPECT_FLOAT_EQ(hm.at(3, 5), float(d.at(3, 5)));
    }
}

// Timings (skipped unless MESO_TIMING is set): MESO_TIMING=1 build/tests/meso_tests --gtest_filter='PrefilterLsq.Timing'
TEST(PrefilterLsq, Timing) {
    if (!std::getenv("MESO_TIMING")) GTEST_SKIP() << "timing measurement, not a check: run with MESO_TIMING=1";
    for (int fine_size : {1024, 2048, 4096}) {
        const HeightMap fine = fbm_map(fine_size, 1);
        for (LsqSolver solver : {LsqSolver::Direct, LsqSolver::CG}) {
            if (solver == LsqSolver::Direct && fine_size > 2048) continue;  // fill-in: minutes
            LsqOptions o;
            o.solver = solver;
            const auto t0 = std::chrono::steady_clock::now();
            const LowResHeights r = downsample_least_squares(fine, 8, o);
            const double total = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
            std::printf("%d^2 -> %d^2 %-6s: assembly %.2fs, solve %.2fs, total %.2fs, iterations %d, slope rms error "
                        "%.3e (reference %.3e)\n",
                        fine_size, r.width, r.solver.c_str(), r.assembly_seconds, r.solve_seconds, total, r.iterations,
                        r.slope_rms_error, r.slope_rms_reference);
            std::fflush(stdout);
        }
    }
}
