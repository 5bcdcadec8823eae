// Filtering distributions of colour maps on Gaussian microsurfaces (paper 001 §5.1-5.2): eq. 12,
// the exact moments of eq. 15 and the eq. 16-17 fit, the visible-slope Gaussian D_s and the
// steepness average, against the brute-force references of transfer_filter_test_util.h. The fit
// of eq. 16-17 is measured against the exact moments and the table printed (it goes into the
// README); its assertion is a regression guard just above the measured error.
#include <gtest/gtest.h>
#include "material_test_util.h"
#include "transfer_filter_test_util.h"

using namespace meso;
using namespace meso::test::tf;
using meso::test::dir_deg;
TEST(TransferFilter, AverageVisibilityMatchesQuadrature) {
    // int Phi(z)^L phi(z) dz in z = h / sigma_h (the ratio is scale-free), over [-14, 14].
    auto mass = [](double L) {
        std::vector<double> b = {-14.0, -4.0, 0.0, 4.0, 14.0};
        return piecewise_simpson(
            [&](double z) { return std::exp(L * log_Phi(z)) * normal_pdf(z, 0, 1); }, b, 4000);
    };
    const double pairs[][2] = {{0, 0},    {0, 1},   {1, 0},     {0.3, 2.7}, {5, 0.01},
                               {1e3, 1},  {1, 1e3}, {1e3, 1e3}, {0, 1e3},   {2.5, 0}};
    for (const auto &pr : pairs) {
        const double lo = pr[0], li = pr[1];
        const Quad num = mass(lo + li), den = mass(lo);
        const double ref = num.value / den.value;
        const double tol = ref * (num.err / num.value + den.err / den.value) + 8 * kEps;
        EXPECT_NEAR(average_visibility(lo, li), ref, tol) << "Lo " << lo << " Li " << li;
    }
    EXPECT_EQ(average_visibility(0.7, INFINITY), 0.0);
    EXPECT_EQ(average_visibility(0.0, INFINITY), 0.0);
    EXPECT_DOUBLE_EQ(average_visibility(0.0, 0.0), 1.0);
    EXPECT_DOUBLE_EQ(average_visibility(3.0, 0.0), 1.0);
    // Negative / NaN Lambdas count as 0.
    EXPECT_DOUBLE_EQ(average_visibility(-1.0, 1.0), 0.5);
    EXPECT_DOUBLE_EQ(average_visibility(NAN, 1.0), 0.5);
    EXPECT_TRUE(std::isfinite(average_visibility(INFINITY, 1.0)));
}

// ================================================================ 4. Eq. 15 exact

TEST(TransferFilter, HeightFilterExactMatchesQuadrature) {
    // The doc claims relative error < 1e-6; the reference (a different formula, via the CDF) has
    // its own Richardson error, far smaller.
    double worst_mu = 0, worst_s = 0;
    for (double L : {0.0, 1e-3, 0.01, 0.1, 0.5, 1.0, 2.0, 3.7, 10.0, 42.0, 100.0, 1e3, 1e4, 1e6, 1e8}) {
        const RefHeight ref = reference_height(L);
        const HeightFilter h = height_filter_exact(1.0, L);
        const double tol_mu = 1e-6 * std::max(ref.mu, ref.sigma) + ref.err;
        const double tol_s = 1e-6 * ref.sigma + ref.err;
        EXPECT_NEAR(h.mu, ref.mu, tol_mu) << "Lambda " << L;
        EXPECT_NEAR(h.sigma, ref.sigma, tol_s) << "Lambda " << L;
        worst_mu = std::max(worst_mu, std::fabs(h.mu - ref.mu) / ref.sigma);
        worst_s = std::max(worst_s, std::fabs(h.sigma - ref.sigma) / ref.sigma);
        // Scaling by sigma_h.
        const HeightFilter h3 = height_filter_exact(2.5, L);
        EXPECT_NEAR(h3.mu, 2.5 * h.mu, 1e-14 * (1 + std::fabs(h3.mu)));
        EXPECT_NEAR(h3.sigma, 2.5 * h.sigma, 1e-14 * h3.sigma);
    }
    std::printf("[height_filter_exact] max |error| / sigma_d vs CDF quadrature: mu %.3g, sigma %.3g\n", worst_mu,
                worst_s);
}

TEST(TransferFilter, HeightFilterExactOrderStatistics) {
    // Integer Lambda = n - 1: D_h is the density of the maximum of n standard normals.
    const double sp = std::sqrt(kPi);
    const HeightFilter h2 = height_filter_exact(1.0, 1.0);
    EXPECT_NEAR(h2.mu, 1.0 / sp, 1e-6);
    EXPECT_NEAR(h2.sigma, std::sqrt(1.0 - 1.0 / kPi), 1e-6);
    const HeightFilter h3 = height_filter_exact(1.0, 2.0);
    EXPECT_NEAR(h3.mu, 3.0 / (2.0 * sp), 1e-6);
    // E[max of 3 ^2] = 1 + sqrt(3) / (2 pi).
    EXPECT_NEAR(h3.sigma, std::sqrt(1.0 + std::sqrt(3.0) / (2 * kPi) - 9.0 / (4 * kPi)), 1e-6);
    // Lambda = 0: p_h itself.
    const HeightFilter h0 = height_filter_exact(0.8, 0.0);
    EXPECT_NEAR(h0.mu, 0.0, 1e-9);
    EXPECT_NEAR(h0.sigma, 0.8, 1e-7);
    // The reference agrees with the same identities (a check of the reference itself).
    const RefHeight r2 = reference_height(1.0);
    EXPECT_NEAR(r2.mu, 1.0 / sp, 1e-10);
    EXPECT_NEAR(r2.sigma, std::sqrt(1.0 - 1.0 / kPi), 1e-10);
}

TEST(TransferFilter, HeightFilterEdgeCases) {
    const HeightFilter big = height_filter_exact(1.0, 1e8);
    EXPECT_TRUE(std::isfinite(big.mu) && std::isfinite(big.sigma));
    EXPECT_GT(big.mu, 5.0);
    EXPECT_GT(big.sigma, 0.1);
    const HeightFilter inf = height_filter_exact(1.0, INFINITY);  // clamped to 1e8
    EXPECT_DOUBLE_EQ(inf.mu, big.mu);
    EXPECT_DOUBLE_EQ(inf.sigma, big.sigma);
    for (double L : {0.0, 1.0, 1e8}) {
        const HeightFilter z = height_filter_exact(0.0, L);
        EXPECT_EQ(z.mu, 0.0); EXPECT_EQ(z.sigma, 0.0);
        const HeightFilter n = height_filter_exact(-1.0, L);
        EXPECT_EQ(n.mu, 0.0); EXPECT_EQ(n.sigma, 0.0);
        const HeightFilter f = height_filter_fit(0.0, L);
        EXPECT_EQ(f.mu, 0.0); EXPECT_EQ(f.sigma, 0.0);
        const HeightFilter t = HeightFilterTable::instance().lookup(0.0, L);
        EXPECT_EQ(t.mu, 0.0); EXPECT_EQ(t.sigma, 0.0);
    }
    const HeightFilter nan = height_filter_exact(1.0, NAN);  // Lambda NaN -> 0
    EXPECT_NEAR(nan.mu, 0.0, 1e-9);
    EXPECT_NEAR(nan.sigma, 1.0, 1e-7);
    // The fit at Lambda = 0 is p_h exactly.
    const HeightFilter f0 = height_filter_fit(0.7, 0.0);
    EXPECT_EQ(f0.mu, 0.0);
    EXPECT_DOUBLE_EQ(f0.sigma, 0.7);
    // The fit's formula with the paper's constants, and custom ones.
    const HeightFilter f = height_filter_fit(2.0, 3.0);
    EXPECT_NEAR(f.mu, 0.39 * 2.0 * std::log(4.75 * 3.0 + 1.0), 1e-14);
    EXPECT_NEAR(f.sigma, 2.0 / (1.0 + 0.26 * std::log(1.13 * 3.0 + 1.0)), 1e-14);
    HeightFitParams p;
    p.a_mu = 1, p.b_mu = 1, p.a_sigma = 1, p.b_sigma = 1;
    const HeightFilter g = height_filter_fit(1.0, std::exp(1.0) - 1.0, p);
    EXPECT_NEAR(g.mu, 1.0, 1e-14);
    EXPECT_NEAR(g.sigma, 0.5, 1e-14);
}

// ================================================================ 5. Eq. 16-17 fit error

TEST(TransferFilter, HeightFilterFitError) {
    const double s2 = 0.1;  // isotropic Beckmann slope variance for the angle column
    std::printf("\n[eq. 16-17 fit vs exact D_h, errors in units of sigma_h]\n");
    std::printf("  theta_1: one direction at theta with Lambda(theta) = Lambda, the other at normal incidence;\n"
                "  theta_2: both directions at theta with Lambda(theta) = Lambda / 2 (sigma_s^2 = %.2g, §3 Smith)\n",
                s2);
    std::printf("  %8s %8s %8s | %9s %9s %10s | %9s %9s %10s\n", "Lambda", "theta_1", "theta_2", "mu_exact", "mu_fit",
                "mu_err", "sd_exact", "sd_fit", "sd_err");
    for (double L : {0.0, 0.01, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0, 1e3}) {
        const RefHeight r = reference_height(L);
        const HeightFilter f = height_filter_fit(1.0, L);
        std::printf("  %8g %8.3f %8.3f | %9.5f %9.5f %+10.5f | %9.5f %9.5f %+10.5f\n", L, theta_of_lambda(L, s2),
                    theta_of_lambda(L / 2, s2), r.mu, f.mu, f.mu - r.mu, r.sigma, f.sigma, f.sigma - r.sigma);
        // The angle column uses the same formula as GaussianSlopes::lambda (centred, isotropic).
        if (L > 0) {
            const double th = theta_of_lambda(L, s2);
            const GaussianSlopes gs(make(0, 0, s2, s2, 0));
            const Vec3 w = dir_deg(th, 0);
            // Float directions (2^-24 relative per component) through d ln(Lambda) / d ln(cot)
            // = -(1 + 2 nu^2) + O(nu^-2) (< 4 here): 2e-6 relative.
            EXPECT_NEAR(gs.lambda(w), L, 2e-6 * L) << th;
        }
    }
    // Max over Lambda in [0, 100] on a dense grid in ln(1 + Lambda).
    double max_mu = 0, max_s = 0, at_mu = 0, at_s = 0;
    const int N = 400;
    for (int i = 0; i <= N; ++i) {
        const double L = std::expm1(std::log(101.0) * i / N);
        const RefHeight r = reference_height(L, 3000);
        const HeightFilter f = height_filter_fit(1.0, L);
        if (std::fabs(f.mu - r.mu) > max_mu) max_mu = std::fabs(f.mu - r.mu), at_mu = L;
        if (std::fabs(f.sigma - r.sigma) > max_s) max_s = std::fabs(f.sigma - r.sigma), at_s = L;
    }
    std::printf("  max |mu_fit - mu_exact| / sigma_h over Lambda in [0, 100]: %.4f (at Lambda = %.3g)\n", max_mu, at_mu);
    std::printf("  max |sd_fit - sd_exact| / sigma_h over Lambda in [0, 100]: %.4f (at Lambda = %.3g)\n\n", max_s, at_s);
    RecordProperty("fit_max_mu_error", std::to_string(max_mu));
    RecordProperty("fit_max_sigma_error", std::to_string(max_s));
    // Regression guard, not an accuracy requirement: the fit is the paper's (a_mu 0.39, b_mu
    // 4.75, a_s 0.26, b_s 1.13), and its measured error over Lambda in [0, 100] (this grid) is
    // 0.1309 sigma_h for mu (at Lambda ~0.57; it overshoots by ~2x for small Lambda, where its
    // slope a_mu b_mu = 1.85 is twice the exact 0.903) and 0.0281 sigma_h for sigma (at
    // Lambda ~13). The bounds sit just above, so a change of height_filter_fit, its constants
    // or the reference shows up here.
    EXPECT_LT(max_mu, 0.133);
    EXPECT_LT(max_s, 0.0285);
}

TEST(TransferFilter, HeightFilterTableMatchesExact) {
    // The table: height_filter_exact at 256 nodes x_i = i dx of x = ln(1 + Lambda), linear in x.
    // (a) At the nodes and between them it is exactly the linear interpolation of
    //     height_filter_exact at the two nodes (checks the indexing; 1e-12).
    // (b) Its error against height_filter_exact is the interpolation error, bounded per interval
    //     by dx^2/8 max|f''|; f'' dx^2 is estimated by the nodes' second differences (the larger
    //     of the two centred on the interval's ends); f'' varies by less than 25% between
    //     neighbouring nodes here (the printed ratio shows how close the error comes).
    const HeightFilterTable &T = HeightFilterTable::instance();
    const int n = 256;
    const double xmax = std::log1p(1e8), dx = xmax / (n - 1), sh = 1.7;
    std::vector<double> nm(n), ns(n);
    for (int i = 0; i < n; ++i) {
        const HeightFilter e = height_filter_exact(1.0, std::expm1(dx * i));
        nm[i] = e.mu, ns[i] = e.sigma;
    }
    auto d2 = [&](const std::vector<double> &f, int j) {
        j = std::clamp(j, 1, n - 2);
        return std::fabs(f[j - 1] - 2 * f[j] + f[j + 1]);
    };
    double max_rel_mu = 0, max_rel_s = 0, max_abs_mu = 0, at_mu = 0, at_s = 0, at_abs = 0, ratio = 0;
    for (int i = 0; i < n - 1; ++i)
        for (double f : {0.0, 0.25, 0.5, 0.75}) {
            const double x = dx * (i + f), L = std::expm1(x);
            const HeightFilter e = height_filter_exact(sh, L), t = T.lookup(sh, L);
            const double tt = x / dx - i;  // the fraction as the table computes it
            EXPECT_NEAR(t.mu, sh * ((1 - tt) * nm[i] + tt * nm[i + 1]), 1e-12 * sh * (1 + nm[i + 1])) << L;
            EXPECT_NEAR(t.sigma, sh * ((1 - tt) * ns[i] + tt * ns[i + 1]), 1e-12 * sh) << L;
            const double bm = 1.25 * std::max(d2(nm, i), d2(nm, i + 1)) / 8 * sh + 1e-12 * sh;
            const double bs = 1.25 * std::max(d2(ns, i), d2(ns, i + 1)) / 8 * sh + 1e-12 * sh;
            EXPECT_LE(std::fabs(t.mu - e.mu), bm) << "Lambda " << L;
            EXPECT_LE(std::fabs(t.sigma - e.sigma), bs) << "Lambda " << L;
            ratio = std::max({ratio, std::fabs(t.mu - e.mu) / bm * 1.25, std::fabs(t.sigma - e.sigma) / bs * 1.25});
            const double rm = std::fabs(t.mu - e.mu) / std::max(e.mu, 1e-300), rs = std::fabs(t.sigma - e.sigma) / e.sigma;
            if (std::fabs(t.mu - e.mu) / sh > max_abs_mu) max_abs_mu = std::fabs(t.mu - e.mu) / sh, at_abs = L;
            if (e.mu > 0.01 * sh && rm > max_rel_mu) max_rel_mu = rm, at_mu = L;
            if (rs > max_rel_s) max_rel_s = rs, at_s = L;
        }
    std::printf("[HeightFilterTable, 256 nodes in ln(1 + Lambda)] max |mu error| / sigma_h %.3g (at Lambda %.3g); "
                "max relative error: sigma %.3g (at Lambda %.3g), mu %.3g (at Lambda %.3g, where mu > 0.01 sigma_h); "
                "max error / (dx^2/8 |f''|) = %.3f\n",
                max_abs_mu, at_abs, max_rel_s, at_s, max_rel_mu, at_mu, ratio);
    // The header documents "max relative error ~1e-4": true of sigma (and of mu in units of
    // sigma_h, 1.9e-4); mu's relative error grows to ~1% as Lambda -> 0 where mu -> 0.
    EXPECT_LT(max_rel_s, 1e-4);
    EXPECT_LT(max_abs_mu, 2e-4);
    // Beyond the range: clamped at 1e8.
    const HeightFilter a = T.lookup(1.0, 1e12), b = height_filter_exact(1.0, 1e8);
    EXPECT_NEAR(a.mu, b.mu, 1e-9);
    EXPECT_NEAR(a.sigma, b.sigma, 1e-9);
}

// ================================================================ 6. D_s (§5.2)

namespace {
void expect_visible_matches(const SlopeGaussian &p, const Vec3 &wo, const char *what, double *worst = nullptr) {
    double norm = -1;
    const SlopeGaussian d = visible_slope_gaussian(p, wo, &norm);
    const VisCompare q = visible_reference(p, wo);
    const VisRef &r = q.ref;
    const double scale_m = std::max({std::fabs(r.mx), std::fabs(r.my), std::sqrt(r.sxx + r.syy)});
    const double scale_v = r.sxx + r.syy;
    // The reference's Richardson error plus round-off: the quadrature sums ~n^2 terms
    // (1e-12 relative), the closed forms cancel terms of size up to 1 / |t| in u.
    const double fm = 1e-11 * scale_m, fv = 1e-11 * (scale_v + scale_m * scale_m);
    const std::string ctx = std::string(what) + " p = (" + std::to_string(p.mx) + ", " + std::to_string(p.my) + "; " +
                            std::to_string(p.sxx) + ", " + std::to_string(p.syy) + ", " + std::to_string(p.sxy) +
                            ") wo = (" + std::to_string(wo.x) + ", " + std::to_string(wo.y) + ", " +
                            std::to_string(wo.z) + ")";
    EXPECT_NEAR(d.mx, r.mx, q.err.mx + fm) << ctx;
    EXPECT_NEAR(d.my, r.my, q.err.my + fm) << ctx;
    EXPECT_NEAR(d.sxx, r.sxx, q.err.sxx + fv) << ctx;
    EXPECT_NEAR(d.syy, r.syy, q.err.syy + fv) << ctx;
    EXPECT_NEAR(d.sxy, r.sxy, q.err.sxy + fv) << ctx;
    const double ref_norm = r.mass * std::exp(-r.log_scale);
    EXPECT_NEAR(norm, ref_norm, (q.err.mass / r.mass + 1e-12) * ref_norm + 1e-300) << ctx;
    if (worst) {
        *worst = std::max({*worst, std::fabs(d.mx - r.mx) / scale_m, std::fabs(d.my - r.my) / scale_m,
                           std::fabs(d.sxx - r.sxx) / scale_v, std::fabs(d.syy - r.syy) / scale_v,
                           std::fabs(d.sxy - r.sxy) / scale_v, std::fabs(norm - ref_norm) / ref_norm});
    }
}
}  // namespace

TEST(TransferFilter, VisibleSlopeGaussianMatchesQuadrature) {
    const SlopeGaussian dists[] = {
        make(0, 0, 0.1, 0.1, 0),              // isotropic
        make(0, 0, 0.3, 0.05, 0.08),          // anisotropic, correlated
        make(0.4, -0.25, 0.04, 0.09, -0.03),  // non-centred
        make(-0.2, 0.6, 0.2, 0.02, 0.05),     // non-centred, anisotropic, correlated
    };
    double worst = 0;
    for (const SlopeGaussian &p : dists)
        for (double th : {0.0, 30.0, 60.0, 80.0, 89.0, 89.9})
            for (double ph : {0.0, 37.0, 135.0, 250.0}) {
                const Vec3 wo = dir_deg(th, ph);
                if (th == 0.0) {  // t = 0: D_s = p_s, M0 = 1
                    double norm = -1;
                    const SlopeGaussian d = visible_slope_gaussian(p, wo, &norm);
                    EXPECT_EQ(norm, 1.0);
                    EXPECT_EQ(d.mx, p.mx); EXPECT_EQ(d.sxx, p.sxx); EXPECT_EQ(d.sxy, p.sxy);
                    continue;
                }
                expect_visible_matches(p, wo, "view", &worst);
            }
    std::printf("[visible_slope_gaussian] max relative deviation from 2D quadrature over %d cases: %.3g\n",
                4 * 5 * 4, worst);
}

TEST(TransferFilter, VisibleSlopeGaussianBelowMesosurfaceHorizon) {
    // Mean slope 2 along x (mesonormal tilted 63 degrees away from +x): views towards +x beyond
    // atan(1/2) from the normal look at the back of the mesosurface. z = (1/|t| - m) / sqrt(v).
    const SlopeGaussian p = make(2.0, 0.3, 0.01, 0.02, 0.004);
    struct Case {
        double theta, phi;
    };
    // Along +x m = 2, sd = 0.1: theta = 45 gives c = 1, z = -10 (the far-tail branch); 35.8 deg
    // z = -6.15 (just inside it); 35.3 deg z = -5.88 (the truncated-normal branch where it
    // cancels most); 33 and 30 deg z = -4.6 and -2.7.
    for (const Case &k : {Case{45.0, 0.0}, Case{60.0, 10.0}, Case{80.0, 0.0}, Case{88.0, 5.0}, Case{35.8, 0.0},
                          Case{35.3, 0.0}, Case{33.0, 0.0}, Case{30.0, 0.0}}) {
        const Vec3 wo = dir_deg(k.theta, k.phi);
        const double tx = double(wo.x) / wo.z, ty = double(wo.y) / wo.z, a = std::hypot(tx, ty);
        const double ex = tx / a, ey = ty / a;
        const double m = ex * p.mx + ey * p.my, v = ex * ex * p.sxx + ey * ey * p.syy + 2 * ex * ey * p.sxy;
        const double z = (1 / a - m) / std::sqrt(v);
        double norm = -1;
        const SlopeGaussian d = visible_slope_gaussian(p, wo, &norm);
        EXPECT_TRUE(std::isfinite(d.mx) && std::isfinite(d.my) && std::isfinite(d.sxx) && std::isfinite(d.syy) &&
                    std::isfinite(d.sxy) && std::isfinite(norm))
            << k.theta;
        EXPECT_GE(norm, 0.0);
        // The visible mean lies on the visible side of the cutoff: mean . t < 1.
        EXPECT_LT(d.mx * tx + d.my * ty, 1.0) << "theta " << k.theta << " z " << z;
        EXPECT_GE(d.sxx, 0.0); EXPECT_GE(d.syy, 0.0);
        EXPECT_LE(d.sxy * d.sxy, d.sxx * d.syy * (1 + 1e-9) + 1e-300);
        const VisCompare q = visible_reference(p, wo);
        const VisRef &r = q.ref;
        // Report the along-t statistics of the visible u = s . t_hat: offset c - E[u] and Var[u].
        const double ref_off = 1 / a - (ex * r.mx + ey * r.my), got_off = 1 / a - (ex * d.mx + ey * d.my);
        const double ref_var = ex * ex * r.sxx + ey * ey * r.syy + 2 * ex * ey * r.sxy;
        const double got_var = ex * ex * d.sxx + ey * ey * d.syy + 2 * ex * ey * d.sxy;
        const double ref_norm = r.mass * std::exp(-r.log_scale);
        std::printf("[below horizon] theta %5.1f phi %4.1f z %7.2f: offset c - E[u] got %.5g ref %.5g (%+.2f%%), "
                    "Var[u] got %.5g ref %.5g (%+.2f%%), M0 got %.5g ref %.5g\n",
                    k.theta, k.phi, z, got_off, ref_off, 100 * (got_off / ref_off - 1), got_var, ref_var,
                    100 * (got_var / ref_var - 1), norm, ref_norm);
        if (z >= -6) {
            expect_visible_matches(p, wo, "z >= -6");
        } else {
            // The far-tail branch is the leading term of the asymptotic expansion in 1/z^2: with
            // kappa = |z|, x = c - u has density ~ x exp(-kappa x / sd - x^2 / (2 v)), whose
            // mean is 2 sd / kappa (1 - 3/kappa^2 + O(kappa^-4)) and variance 2 v / kappa^2
            // (1 - 9/kappa^2 + O(kappa^-4)). So the relative errors are bounded by ~3/z^2 and
            // ~9/z^2 (to leading order), checked with a factor 1.5 for the higher terms.
            EXPECT_NEAR(got_off, ref_off, 1.5 * 3 / (z * z) * ref_off) << k.theta;
            EXPECT_NEAR(got_var, ref_var, 1.5 * 9 / (z * z) * ref_var) << k.theta;
            EXPECT_NEAR(norm, ref_norm, (q.err.mass / r.mass + 1e-9) * ref_norm + 1e-300) << k.theta;
            // Across t: s_perp | u keeps its conditional covariance; the mean follows u.
        }
    }
}

TEST(TransferFilter, VisibleSlopeGaussianDegenerate) {
    // Zero variance along t: the weight (1 - s.t) is constant on the support, D_s = p_s.
    const SlopeGaussian p = make(0.1, -0.2, 0.0, 0.3, 0.0);  // spread along y only
    const Vec3 wo = dir_deg(60, 0);                          // t along x
    double norm = -1;
    const SlopeGaussian d = visible_slope_gaussian(p, wo, &norm);
    const double tx = double(wo.x) / wo.z;
    EXPECT_NEAR(norm, 1.0 - tx * 0.1, 1e-12);
    EXPECT_DOUBLE_EQ(d.mx, p.mx); EXPECT_DOUBLE_EQ(d.my, p.my);
    EXPECT_DOUBLE_EQ(d.sxx, 0.0); EXPECT_DOUBLE_EQ(d.syy, 0.3); EXPECT_DOUBLE_EQ(d.sxy, 0.0);
    // A rank-1 covariance not aligned with the axes, with t along its null direction.
    const SlopeGaussian q = make(0.05, 0.05, 0.2, 0.2, -0.2);  // spread along (1, -1)
    const Vec3 w2 = normalize(Vec3(1.f, 1.f, 1.f));              // t along (1, 1)
    const SlopeGaussian d2 = visible_slope_gaussian(q, w2, &norm);
    EXPECT_NEAR(norm, 1.0 - (0.05 + 0.05), 1e-6);  // float direction: t = (1, 1) to 1e-7
    EXPECT_NEAR(d2.mx, q.mx, 1e-9); EXPECT_NEAR(d2.my, q.my, 1e-9);
    EXPECT_NEAR(d2.sxx, q.sxx, 1e-9); EXPECT_NEAR(d2.syy, q.syy, 1e-9); EXPECT_NEAR(d2.sxy, q.sxy, 1e-9);
    // A nearly degenerate one (variance 1e-10 along t) is continuous with it, and agrees with
    // the 2D quadrature's limit: only the along-t variance shrinks (times ~1).
    const SlopeGaussian e = make(0.1, -0.2, 1e-10, 0.3, 0.0);
    const SlopeGaussian de = visible_slope_gaussian(e, wo, &norm);
    EXPECT_NEAR(norm, 1.0 - tx * 0.1, 1e-9);
    EXPECT_NEAR(de.mx, 0.1, 1e-9); EXPECT_NEAR(de.my, -0.2, 1e-12); EXPECT_NEAR(de.syy, 0.3, 1e-12);
    EXPECT_NEAR(de.sxx, 1e-10, 1e-12);
    // All-zero covariance.
    const SlopeGaussian zz = visible_slope_gaussian(make(0.2, 0.1, 0, 0, 0), wo, &norm);
    EXPECT_NEAR(norm, 1.0 - tx * 0.2, 1e-12);
    EXPECT_EQ(zz.sxx, 0.0); EXPECT_EQ(zz.syy, 0.0);
    // Below the macrosurface horizon (wo.z <= 0): clamped, finite.
    for (const Vec3 &w : {Vec3(1.f, 0.f, 0.f), Vec3(0.6f, 0.f, -0.8f)}) {
        const SlopeGaussian b = visible_slope_gaussian(make(0, 0, 0.1, 0.1, 0), w, &norm);
        EXPECT_TRUE(std::isfinite(b.mx) && std::isfinite(b.sxx) && std::isfinite(b.syy) && std::isfinite(norm));
    }
}

TEST(TransferFilter, VisibleSlopeNormIsSmithNormalisation) {
    // M0 = E[(1 - s.t)+]. With u = s.t_hat ~ N(mu, sigma^2), a = tan(theta_o):
    //   M0 = 1 - a mu + a E[(u - cot)+] = 1 - a mu + Lambda_smith(wo),
    // and, with the paper's Lambda (centred prefactor, shifted nu) = Lambda_smith / (1 - a mu),
    //   M0 = (1 - a mu)(1 + Lambda(wo)).
    // For a centred distribution (mu = 0), M0 = 1 + Lambda_smith = 1 + Lambda.
    const SlopeGaussian cases[] = {make(0, 0, 0.1, 0.1, 0), make(0, 0, 0.3, 0.05, 0.08),
                                   make(0.4, -0.25, 0.04, 0.09, -0.03), make(-0.2, 0.6, 0.2, 0.02, 0.05)};
    double worst_header_claim = 0;
    for (const SlopeGaussian &p : cases) {
        const GaussianSlopes gs(p);
        for (double th : {20.0, 45.0, 70.0, 85.0})
            for (double ph : {0.0, 100.0, 200.0}) {
                const Vec3 wo = dir_deg(th, ph);
                double norm = -1;
                visible_slope_gaussian(p, wo, &norm);
                const double st = std::hypot(double(wo.x), double(wo.y));
                const double a = st / wo.z, mu = (wo.x * p.mx + wo.y * p.my) / st;
                const double ls = gs.lambda_smith(wo), lp = gs.lambda(wo);
                // Rounding of the reference sum: its terms are O(1 + |a mu| + ls).
                const double tol = 1e-9 * norm + 16 * kEps * (1 + std::fabs(a * mu) + ls);
                EXPECT_NEAR(norm, 1 - a * mu + ls, tol) << th << " " << ph;
                if (1 - a * mu > 0) {  // above the mesosurface horizon (else the paper's Lambda is +inf)
                    EXPECT_NEAR(norm, (1 - a * mu) * (1 + lp), tol) << th << " " << ph;
                }
                if (p.mx == 0 && p.my == 0) {
                    EXPECT_NEAR(norm, 1 + ls, 1e-9 * norm) << th << " " << ph;
                }
                worst_header_claim = std::max(worst_header_claim, std::fabs(norm - (1 + ls)));
            }
    }
    // The header's "M0 = 1 + Lambda_smith(wo)" holds for centred distributions only.
    std::printf("[visible norm] max |M0 - (1 + Lambda_smith)| over the non-centred cases: %.3g "
                "(= |tan(theta) mu|; M0 = 1 - tan(theta) mu + Lambda_smith holds to 1e-9)\n",
                worst_header_claim);
}

// ================================================================ 7. Gauss-Hermite

TEST(TransferFilter, SteepnessAverageMatchesBruteForce) {
    const Ramp ramp({0.0, 0.2, 0.5, 1.5}, {0, 0, 1, 0, 1, 0, 1, 0.5, 0, 1, 0, 0}, 3);
    const SlopeGaussian cases[] = {make(0, 0, 0.3, 0.3, 0), make(0.3, -0.2, 0.12, 0.05, 0.02),
                                   make(0.8, 0.4, 0.02, 0.2, -0.04), make(1.2, 0.0, 0.004, 0.001, 0.0),
                                   make(0.05, 0.0, 1e-4, 1e-4, 0.0), make(-0.4, 0.6, 0.5, 0.01, 0.05)};
    for (const SlopeGaussian &g : cases) {
        double out[3];
        gaussian_average_steepness(ramp, g, out);
        const double det = g.sxx * g.syy - g.sxy * g.sxy, sx = std::sqrt(g.sxx), sy = std::sqrt(g.syy);
        const int n = 1200;
        double ref[3] = {0, 0, 0}, mass = 0;
        for (int i = 0; i < n; ++i)
            for (int j = 0; j < n; ++j) {
                const double x = g.mx + sx * (-8 + 16 * (i + 0.5) / n), y = g.my + sy * (-8 + 16 * (j + 0.5) / n);
                const double dx = x - g.mx, dy = y - g.my;
                const double w = std::exp(-0.5 * (g.syy * dx * dx - 2 * g.sxy * dx * dy + g.sxx * dy * dy) / det);
                double c[3];
                ramp.eval(std::sqrt(x * x + y * y), c);
                for (int k = 0; k < 3; ++k) ref[k] += w * c[k];
                mass += w;
            }
        for (int k = 0; k < 3; ++k)
            EXPECT_NEAR(out[k], ref[k] / mass, 2e-3) << "mean (" << g.mx << ", " << g.my << ") channel " << k;
    }
}

