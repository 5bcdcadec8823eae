// Filtering non-linear transfer functions (paper 001, Heitz et al. 2014): every closed form of
// filter/transfer_filter.h against an independent brute-force reference written here (composite
// Simpson rules split at every kink, a CDF-based formula for the moments of eq. 15, 2D Simpson
// of p_s(s) (1 - s.t)+ in a rotated frame, fixed-seed Monte Carlo). Tolerances are the
// reference's own error estimate (Simpson at n and 2n intervals: |Q_n - Q_2n| is ~15 times the
// error of Q_2n) plus a round-off floor proportional to the size of the terms summed, or a few
// Monte Carlo standard errors; none was widened to make a case pass.
//
// This file: ramps, the preconvolved table, Gauss-Hermite rules, the §7 moments. The height and
// slope filtering distributions are in test_transfer_filter_microsurface.cpp; the references in
// transfer_filter_test_util.h.
#include <gtest/gtest.h>
#include "material_test_util.h"
#include "transfer_filter_test_util.h"

using namespace meso;
using namespace meso::test::tf;
using meso::test::dir_deg;

// ============================================================================ 1. Ramp

TEST(TransferFilter, RampEvalAndDerivative) {
    const Ramp r = kRamp1.ramp();
    EXPECT_EQ(r.channels(), 1);
    EXPECT_EQ(r.stops(), 4);
    EXPECT_DOUBLE_EQ(r.x_min(), -1.0);
    EXPECT_DOUBLE_EQ(r.x_max(), 2.0);
    double o;
    // At the stops: exactly the stop values.
    const double xs[] = {-1.0, 0.0, 0.5, 2.0}, vs[] = {0.2, 1.0, -0.5, 0.7};
    for (int i = 0; i < 4; ++i) {
        r.eval(xs[i], &o);
        EXPECT_DOUBLE_EQ(o, vs[i]) << "stop " << i;
    }
    // Between: hand-computed linear interpolation.
    r.eval(-0.5, &o); EXPECT_NEAR(o, 0.6, 1e-15);
    r.eval(0.25, &o); EXPECT_NEAR(o, 0.25, 1e-15);
    r.eval(1.25, &o); EXPECT_NEAR(o, 0.1, 1e-15);
    // Beyond the ends: constant.
    r.eval(-7.0, &o); EXPECT_DOUBLE_EQ(o, 0.2);
    r.eval(1e300, &o); EXPECT_DOUBLE_EQ(o, 0.7);
    r.eval(-INFINITY, &o); EXPECT_DOUBLE_EQ(o, 0.2);
    r.eval(INFINITY, &o); EXPECT_DOUBLE_EQ(o, 0.7);
    // Derivative: the slope inside, the right derivative at a stop, 0 beyond (and at x_max).
    r.derivative(-0.5, &o); EXPECT_NEAR(o, 0.8, 1e-15);
    r.derivative(0.3, &o); EXPECT_NEAR(o, -3.0, 1e-15);
    r.derivative(1.0, &o); EXPECT_NEAR(o, 0.8, 1e-15);
    r.derivative(-1.0, &o); EXPECT_NEAR(o, 0.8, 1e-15);
    r.derivative(0.0, &o); EXPECT_NEAR(o, -3.0, 1e-15);
    r.derivative(0.5, &o); EXPECT_NEAR(o, 0.8, 1e-15);
    r.derivative(2.0, &o); EXPECT_EQ(o, 0.0);
    r.derivative(-1.0000001, &o); EXPECT_EQ(o, 0.0);
    r.derivative(5.0, &o); EXPECT_EQ(o, 0.0);
    r.derivative(NAN, &o); EXPECT_EQ(o, 0.0);
    // Three channels against the independent evaluation.
    const Ramp r3 = kRamp3.ramp();
    double o3[3];
    for (double v : {-1.0, 0.0, 0.1, 0.25, 0.4, 0.6, 0.99, 1.0, 3.0}) {
        r3.eval(v, o3);
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(o3[c], kRamp3.eval(v, c), 1e-15) << v << " ch " << c;
    }
    // One stop: a constant, derivative 0.
    const Ramp k({0.3}, {0.25, 0.5}, 2);
    double o2[2];
    k.eval(-10, o2); EXPECT_EQ(o2[0], 0.25); EXPECT_EQ(o2[1], 0.5);
    k.derivative(0.3, o2); EXPECT_EQ(o2[0], 0.0); EXPECT_EQ(o2[1], 0.0);
    k.gaussian_average(0.3, 2.0, o2); EXPECT_NEAR(o2[0], 0.25, 1e-15); EXPECT_NEAR(o2[1], 0.5, 1e-15);
}

TEST(TransferFilter, RampConstructorErrors) {
    EXPECT_THROW(Ramp({0.0, 0.0}, {1, 2}, 1), MesoError);                 // not strictly increasing
    EXPECT_THROW(Ramp({0.0, 1.0, 0.5}, {1, 2, 3}, 1), MesoError);         // decreasing
    EXPECT_THROW(Ramp({0.0, NAN}, {1, 2}, 1), MesoError);                 // NaN stop
    EXPECT_THROW(Ramp({0.0, INFINITY}, {1, 2}, 1), MesoError);            // infinite stop
    EXPECT_THROW(Ramp({0.0, 1.0}, {1, NAN}, 1), MesoError);               // NaN value
    EXPECT_THROW(Ramp({0.0, 1.0}, {1, 2, 3}, 1), MesoError);              // size mismatch
    EXPECT_THROW(Ramp({0.0, 1.0}, {1, 2, 3, 4, 5}, 3), MesoError);        // size mismatch, 3 channels
    EXPECT_THROW(Ramp({0.0, 1.0}, {1, 2}, 0), MesoError);                 // no channel
    EXPECT_THROW(Ramp({}, {}, 1), MesoError);                             // no stop
    EXPECT_NO_THROW(Ramp({0.0, 1.0}, {1, 2, 3, 4, 5, 6}, 3));
    double o;
    EXPECT_THROW(kRamp1.ramp().gaussian_average_derivative(0, 1, 3, &o), MesoError);
    EXPECT_THROW(kRamp1.ramp().gaussian_average_derivative(0, 1, 0, &o), MesoError);
}

TEST(TransferFilter, RampGaussianAveragesMatchQuadrature) {
    struct Case {
        double mean, sigma;
    };
    const Case cases[] = {{0.0, 0.01}, {0.25, 0.1}, {-0.7, 0.3}, {0.5, 1.0}, {1.3, 0.05}, {0.0, 3.0},
                          {-2.5, 0.5}, {4.0, 1.2},  {2.0, 1e-3}, {10.0, 2.0}, {0.0, 1e6}, {0.1, 50.0}};
    double worst = 0;
    for (const RefRamp *rr : {&kRamp1, &kRamp3}) {
        const Ramp r = rr->ramp();
        const int ch = rr->ch;
        const double vmax = rr->max_abs_value(), smax = rr->max_abs_slope();
        for (const Case &k : cases) {
            std::vector<double> avg(ch), sq(ch), d1(ch), d2(ch);
            r.gaussian_average(k.mean, k.sigma, avg.data());
            r.gaussian_average_square(k.mean, k.sigma, sq.data());
            r.gaussian_average_derivative(k.mean, k.sigma, 1, d1.data());
            r.gaussian_average_derivative(k.mean, k.sigma, 2, d2.data());
            const double *got[4] = {avg.data(), sq.data(), d1.data(), d2.data()};
            // Round-off floor: the closed form sums terms up to (|C| + sigma |C'|)^p in size
            // over the segments; 32 eps per term.
            const double term[4] = {vmax + k.sigma * smax, std::pow(vmax + k.sigma * smax, 2), smax, smax * smax};
            for (int c = 0; c < ch; ++c)
                for (int kind = 0; kind < 4; ++kind) {
                    // The C^2 closed form rounds as eps (beta sigma)^2: for sigma >> the stops'
                    // span it is checked in RampGaussianAverageSquareIllConditioned.
                    if (kind == 1 && k.sigma > 100) continue;
                    const Quad q = ramp_reference(*rr, c, kind, k.mean, k.sigma);
                    const double tol = q.err + 32 * kEps * term[kind] * rr->x.size();
                    EXPECT_NEAR(got[kind][c], q.value, tol)
                        << "ramp " << ch << "ch, channel " << c << ", kind " << kind << " (0 C, 1 C^2, 2 C', 3 C'^2)"
                        << ", mean " << k.mean << ", sigma " << k.sigma;
                    worst = std::max(worst, std::fabs(got[kind][c] - q.value));
                }
        }
    }
    std::printf("[ramp] max |closed form - quadrature| over all cases: %.3g\n", worst);
}

TEST(TransferFilter, RampGaussianAverageLimits) {
    for (const RefRamp *rr : {&kRamp1, &kRamp3}) {
        const Ramp r = rr->ramp();
        const int ch = rr->ch;
        std::vector<double> o(ch), e(ch), d(ch);
        // sigma -> 0: the function itself. Away from the stops the Gaussian tails reach no kink
        // (exp(-huge)); at a stop the kink contributes at most |slope change| sigma phi(0).
        const double sig = 1e-9;
        for (double m = rr->x.front() - 0.5; m <= rr->x.back() + 0.5; m += 0.0371) {
            r.gaussian_average(m, sig, o.data());
            r.gaussian_average_square(m, sig, d.data());
            for (int c = 0; c < ch; ++c) {
                EXPECT_NEAR(o[c], rr->eval(m, c), 1e-14) << m;
                EXPECT_NEAR(d[c], rr->eval(m, c) * rr->eval(m, c), 1e-14) << m;
            }
            r.gaussian_average_derivative(m, sig, 1, o.data());
            r.gaussian_average_derivative(m, sig, 2, e.data());
            for (int c = 0; c < ch; ++c) {
                EXPECT_NEAR(o[c], rr->slope(m, c), 1e-14) << m;
                EXPECT_NEAR(e[c], rr->slope(m, c) * rr->slope(m, c), 1e-14) << m;
            }
        }
        for (double m : rr->x) {
            r.gaussian_average(m, sig, o.data());
            for (int c = 0; c < ch; ++c)
                EXPECT_NEAR(o[c], rr->eval(m, c), rr->total_kink() * sig * 0.3989423 + 1e-15) << "at stop " << m;
        }
        // sigma = 0 exactly, and negative: C(mean), C(mean)^2, C'(mean).
        for (double s : {0.0, -1.0}) {
            r.gaussian_average(0.123, s, o.data());
            r.gaussian_average_square(0.123, s, d.data());
            for (int c = 0; c < ch; ++c) {
                EXPECT_DOUBLE_EQ(o[c], rr->eval(0.123, c));
                EXPECT_DOUBLE_EQ(d[c], rr->eval(0.123, c) * rr->eval(0.123, c));
            }
        }
        // Huge sigma: the mean of the two end values. C differs from the step (v0 below the
        // centre x_c of the stops, vn above) only on [x0, xn], by at most 2 max|C|, and the
        // Gaussian density there is at most 1/(sigma sqrt(2 pi)); |mean - x_c| shifts the
        // step's average by at most |vn - v0| |mean - x_c| / (sigma sqrt(2 pi)).
        for (double big : {1e6, 1e9}) {
            const double mean = 0.3;
            r.gaussian_average(mean, big, o.data());
            const size_t n = rr->x.size();
            const double span = rr->x.back() - rr->x.front(), xc = 0.5 * (rr->x.back() + rr->x.front());
            for (int c = 0; c < ch; ++c) {
                const double v0 = rr->v[c], vn = rr->v[(n - 1) * ch + c];
                const double bound = (2 * rr->max_abs_value() * span + std::fabs(vn - v0) * std::fabs(mean - xc)) /
                                     (big * std::sqrt(2 * kPi));
                EXPECT_NEAR(o[c], 0.5 * (v0 + vn), bound + 1e-12) << "sigma " << big;
            }
            // The derivative's support is bounded: its average is at most max|C'| span phi(0)/sigma.
            r.gaussian_average_derivative(mean, big, 2, o.data());
            for (int c = 0; c < ch; ++c)
                EXPECT_NEAR(o[c], 0.0, rr->max_abs_slope() * rr->max_abs_slope() * span / (big * std::sqrt(2 * kPi)));
        }
        // Infinite sigma: exactly the mean of the ends.
        r.gaussian_average(0.0, INFINITY, o.data());
        const size_t n = rr->x.size();
        for (int c = 0; c < ch; ++c) EXPECT_DOUBLE_EQ(o[c], 0.5 * (rr->v[c] + rr->v[(n - 1) * ch + c]));
        // Mean far outside: the end value (the Gaussian mass reaching the stops is < 1e-300).
        for (double far : {-60.0, 60.0}) {
            r.gaussian_average(far, 1.0, o.data());
            r.gaussian_average_square(far, 1.0, d.data());
            r.gaussian_average_derivative(far, 1.0, 1, e.data());
            for (int c = 0; c < ch; ++c) {
                const double end = far < 0 ? rr->v[c] : rr->v[(n - 1) * ch + c];
                EXPECT_DOUBLE_EQ(o[c], end) << far;
                EXPECT_DOUBLE_EQ(d[c], end * end) << far;
                EXPECT_EQ(e[c], 0.0) << far;
            }
        }
        // Non-finite means stay finite.
        for (double m : {INFINITY, -INFINITY}) {
            r.gaussian_average(m, 1.0, o.data());
            r.gaussian_average_square(m, 1.0, d.data());
            r.gaussian_average_derivative(m, 1.0, 2, e.data());
            for (int c = 0; c < ch; ++c) {
                EXPECT_TRUE(std::isfinite(o[c]) && std::isfinite(d[c]) && std::isfinite(e[c])) << m;
                const double end = m < 0 ? rr->v[c] : rr->v[(n - 1) * ch + c];
                EXPECT_DOUBLE_EQ(o[c], end);
                EXPECT_DOUBLE_EQ(d[c], end * end);
            }
        }
    }
}

TEST(TransferFilter, RampGaussianAverageSquareIllConditioned) {
    // <C^2, N(mean, sigma^2)> where a segment is narrow in units of sigma (sigma much larger than
    // the stops' span, or a near-step ramp as used for terraces in §7). The result must lie
    // within [min C^2, max C^2] and match the quadrature to float precision (1e-7 of max C^2,
    // the accuracy textures are stored at). For sigma >> span it also tends to the mean of the
    // squared end values (bound as for <C, N> in RampGaussianAverageLimits).
    for (const RefRamp *rr : {&kRamp1, &kRamp3}) {
        const Ramp r = rr->ramp();
        const int ch = rr->ch;
        const size_t n = rr->x.size();
        const double vmax = rr->max_abs_value(), span = rr->x.back() - rr->x.front();
        const double xc = 0.5 * (rr->x.back() + rr->x.front()), mean = 0.3;
        std::vector<double> d(ch);
        for (double big : {1e2, 1e3, 1e4, 1e5, 1e6, 1e9}) {
            r.gaussian_average_square(mean, big, d.data());
            for (int c = 0; c < ch; ++c) {
                const double v0 = rr->v[c], vn = rr->v[(n - 1) * ch + c];
                const double limit_bound = (2 * vmax * vmax * span + std::fabs(vn * vn - v0 * v0) * std::fabs(mean - xc)) /
                                           (big * std::sqrt(2 * kPi));
                const Quad q = ramp_reference(*rr, c, 1, mean, big);
                std::printf("[C^2 average, %dch ch %d, sigma %.0e] got %.12g, quadrature %.12g, limit %.12g\n", ch, c,
                            big, d[c], q.value, 0.5 * (v0 * v0 + vn * vn));
                EXPECT_NEAR(d[c], q.value, q.err + 1e-7 * vmax * vmax) << "sigma " << big << " channel " << c;
                EXPECT_NEAR(d[c], 0.5 * (v0 * v0 + vn * vn), limit_bound + 1e-7 * vmax * vmax)
                    << "sigma " << big << " channel " << c;
                EXPECT_LE(d[c], vmax * vmax) << "an average of C^2 above max C^2; sigma " << big;
            }
        }
    }
    // A near-step transfer function g (0 -> 1 over a width w), the §7 terrace case: E[g^2] and
    // the height variance E[g^2] - E[g]^2 (~1/4 at f_bar = 0) against quadrature.
    for (double w : {1e-3, 1e-5, 1e-7, 1e-9})
        for (double sf : {0.1, 1.0}) {
            const RefRamp step{{0.0, w}, {0.0, 1.0}, 1};
            const TransferMoments m = transfer_moments(step.ramp(), 0.0, sf);
            const Quad q1 = ramp_reference(step, 0, 0, 0.0, sf), q2 = ramp_reference(step, 0, 1, 0.0, sf);
            std::printf("[step width %.0e, sigma_f %.1f] E[g] %.10f (quadrature %.10f), E[g^2] %.10f (quadrature "
                        "%.10f), h_var %.6g (quadrature %.6g)\n",
                        w, sf, m.g, q1.value, m.g2, q2.value, m.g2 - m.g * m.g, q2.value - q1.value * q1.value);
            EXPECT_NEAR(m.g, q1.value, q1.err + 1e-7) << "step width " << w << " sigma_f " << sf;
            EXPECT_NEAR(m.g2, q2.value, q2.err + 1e-7) << "step width " << w << " sigma_f " << sf;
            EXPECT_LE(m.g2, 1.0) << "step width " << w << " sigma_f " << sf;
        }
}

// ================================================================ 2. PreconvolvedTable

TEST(TransferFilter, PreconvolvedTableMatchesClosedForm) {
    // Bound on the bilinear error (derived): with K = sum of |slope changes| of C (ends included),
    //  - along the mean (spacing dm): C * N is a convex mixture of shifted C's, each a piecewise
    //    linear function whose interpolation error is <= K dm / 4; also <= dm^2/8 max|F_mm|
    //    with F_mm = C'' * N <= K phi(0) / sigma. The row used is sigma_j0 (the smaller node).
    //  - along sigma (nodes sigma = smax t^2, linear in t, dt = 1/(n-1)): F_tt = F_mmmm (dtau/dt)^2
    //    + F_mm d2tau/dt2 with tau = sigma^2/2, |F_mmmm| <= K phi(0)/sigma^3, so |F_tt| <= 4 K smax
    //    and the error is <= dt^2 / 8 * 4 K smax.
    //  - float storage: 2^-24 relative of max|C|.
    for (const RefRamp *rr : {&kRamp1, &kRamp3}) {
        const Ramp r = rr->ramp();
        const int ch = rr->ch, n_mean = 512, n_sigma = 128;
        const double smax = 0.5;
        const PreconvolvedTable t = PreconvolvedTable::of_ramp(r, smax, n_mean, n_sigma);
        ASSERT_EQ(t.channels(), ch);
        EXPECT_EQ(t.sigma_max(), smax);
        EXPECT_EQ(t.memory_bytes(), size_t(n_mean) * n_sigma * ch * sizeof(float));
        const double m0 = rr->x.front() - 4 * smax, m1 = rr->x.back() + 4 * smax;
        const double dm = (m1 - m0) / (n_mean - 1), dt = 1.0 / (n_sigma - 1);
        const double K = rr->total_kink();
        std::vector<float> out(ch);
        std::vector<double> ref(ch);
        double max_err = 0, max_ratio = 0, err_at_s = 0, err_at_m = 0;
        const int NM = 2000, NS = 400;
        for (int j = 0; j <= NS; ++j) {
            // Half the sigmas on a quadratic grid (dense near 0), half linear.
            const double u = double(j) / NS;
            const double s = (j % 2 ? smax * u * u : smax * u);
            const int j0 = std::min(int(std::sqrt(s / smax) * (n_sigma - 1)), n_sigma - 2);
            const double s_lo = smax * std::pow(double(j0) / (n_sigma - 1), 2);
            const double mean_bound = s_lo > 0 ? std::min(K * dm / 4, dm * dm / 8 * K * 0.3989423 / s_lo) : K * dm / 4;
            const double bound = mean_bound + K * smax * dt * dt / 2 + rr->max_abs_value() * 0x1p-23;
            for (int i = 0; i <= NM; ++i) {
                const double m = m0 + (m1 - m0) * (i + 0.37 * (j % 3)) / NM;
                if (m > m1) continue;
                EXPECT_TRUE(t.lookup(m, s, out.data()));
                r.gaussian_average(m, s, ref.data());
                for (int c = 0; c < ch; ++c) {
                    const double e = std::fabs(double(out[c]) - ref[c]);
                    if (e > max_err) max_err = e, err_at_s = s, err_at_m = m;
                    max_ratio = std::max(max_ratio, e / bound);
                    ASSERT_LE(e, bound) << "mean " << m << " sigma " << s << " channel " << c;
                }
            }
        }
        std::printf("[preconvolved %dch, 512 x 128, sigma_max %.2g] max |table - closed form| = %.3g "
                    "(at mean %.4g, sigma %.4g); max error / derived bound = %.3f; K dm/4 = %.3g, "
                    "K smax dt^2/2 = %.3g\n",
                    ch, smax, max_err, err_at_m, err_at_s, max_ratio, K * dm / 4, K * smax * dt * dt / 2);
    }
}

TEST(TransferFilter, PreconvolvedTableClampsAndStaysFinite) {
    const Ramp r = kRamp3.ramp();
    const double smax = 0.3;
    const PreconvolvedTable t = PreconvolvedTable::of_ramp(r, smax);
    float a[3], b[3];
    for (double m : {-0.5, 0.2, 0.5, 0.77, 1.9}) {
        EXPECT_TRUE(t.lookup(m, smax, a)) << m;
        for (double over : {1.0001 * smax, 2 * smax, 1e9, double(INFINITY)}) {
            EXPECT_FALSE(t.lookup(m, over, b)) << m << " " << over;
            for (int c = 0; c < 3; ++c) EXPECT_EQ(a[c], b[c]) << "clamped to sigma_max: " << m << " " << over;
        }
    }
    // Non-finite inputs: finite outputs; a NaN or negative sigma is sigma = 0 (in range).
    const double bad[] = {NAN, INFINITY, -INFINITY, -1.0, 1e300, -1e300};
    for (double m : bad)
        for (double s : bad) {
            t.lookup(m, s, a);
            for (int c = 0; c < 3; ++c) EXPECT_TRUE(std::isfinite(a[c])) << m << " " << s;
        }
    EXPECT_TRUE(t.lookup(0.3, NAN, a));
    EXPECT_TRUE(t.lookup(0.3, -1.0, b));
    float z[3];
    t.lookup(0.3, 0.0, z);
    for (int c = 0; c < 3; ++c) {
        EXPECT_EQ(a[c], z[c]);
        EXPECT_EQ(b[c], z[c]);
    }
    // Beyond the mean range: clamped to the edge, which holds the end values.
    t.lookup(1e300, 0.1, a);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(a[c], kRamp3.v[9 + c], 1e-6);
    t.lookup(-INFINITY, 0.1, a);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(a[c], kRamp3.v[c], 1e-6);
    // Invalid construction.
    auto avg = [](double, double, double *o) { o[0] = 0; };
    EXPECT_THROW(PreconvolvedTable(1, 0, 1, 0.0, 8, 8, avg), MesoError);
    EXPECT_THROW(PreconvolvedTable(1, 1, 0, 1.0, 8, 8, avg), MesoError);
    EXPECT_THROW(PreconvolvedTable(1, 0, 1, 1.0, 1, 8, avg), MesoError);
    EXPECT_THROW(PreconvolvedTable(0, 0, 1, 1.0, 8, 8, avg), MesoError);
    EXPECT_THROW(PreconvolvedTable::of_ramp(Ramp(), 1.0), MesoError);
}

// ================================================================ 3. Eq. 12

TEST(TransferFilter, GaussHermiteMoments) {
    std::vector<double> x, w;
    for (int n = 1; n <= 20; ++n) {
        gauss_hermite_normal(n, x, w);
        ASSERT_EQ(int(x.size()), n);
        ASSERT_EQ(int(w.size()), n);
        double sw = 0;
        for (int i = 0; i < n; ++i) {
            sw += w[i];
            EXPECT_GT(w[i], 0.0);
            if (i > 0) {
                EXPECT_LT(x[i - 1], x[i]);
            }
            EXPECT_NEAR(x[i], -x[n - 1 - i], 1e-13 * (1 + std::fabs(x[i])));
        }
        EXPECT_NEAR(sw, 1.0, 4 * kEps);
        for (int k = 0; k <= 2 * n - 1; ++k) {
            double s = 0, sa = 0;
            for (int i = 0; i < n; ++i) {
                const double t = w[i] * std::pow(x[i], k);
                s += t, sa += std::fabs(t);
            }
            double exact = 0;  // E[x^k] = (k - 1)!! for even k, 0 for odd
            if (k % 2 == 0) {
                exact = 1;
                for (int j = k - 1; j > 1; j -= 2) exact *= j;
            }
            // Relative to the sum of |terms|: the nodes and weights carry ~1e-15 relative error,
            // amplified k-fold by x^k.
            EXPECT_NEAR(s, exact, (k + 4) * 64 * kEps * sa) << "n " << n << " k " << k;
        }
        // Degree 2n is not integrated exactly (a check that the test can fail).
        if (n <= 10) {
            double s = 0, df = 1;
            for (int j = 2 * n - 1; j > 1; j -= 2) df *= j;
            for (int i = 0; i < n; ++i) s += w[i] * std::pow(x[i], 2 * n);
            EXPECT_GT(std::fabs(s - df), 1e-6 * df) << n;
        }
    }
    // Known values: n = 2 nodes +-1, n = 3 nodes 0, +-sqrt(3) with weights 2/3, 1/6.
    gauss_hermite_normal(2, x, w);
    EXPECT_NEAR(x[1], 1.0, 1e-14); EXPECT_NEAR(w[0], 0.5, 1e-14);
    gauss_hermite_normal(3, x, w);
    EXPECT_NEAR(x[2], std::sqrt(3.0), 1e-14); EXPECT_NEAR(w[1], 2.0 / 3, 1e-14); EXPECT_NEAR(w[0], 1.0 / 6, 1e-14);
    EXPECT_THROW(gauss_hermite_normal(0, x, w), MesoError);
    EXPECT_THROW(gauss_hermite_normal(65, x, w), MesoError);
    EXPECT_NO_THROW(gauss_hermite_normal(64, x, w));
    double s64 = 0;
    for (double v : w) s64 += v;
    EXPECT_NEAR(s64, 1.0, 4 * kEps);
    double m2 = 0;
    for (int i = 0; i < 64; ++i) m2 += w[i] * x[i] * x[i];
    EXPECT_NEAR(m2, 1.0, 1e-12);
}

TEST(TransferFilter, GaussianExpectation2D) {
    const SlopeGaussian gs[] = {make(0.3, -0.4, 0.5, 0.2, 0.1), make(0, 0, 1.0, 1.0, 0.0),
                                make(-1.0, 2.0, 0.04, 0.3, -0.09),
                                make(0.2, 0.1, 1.0, 4.0, 2.0),  // singular: rank 1
                                make(0.2, 0.1, 0.0, 0.5, 0.0)};  // sxx = 0
    for (const SlopeGaussian &g : gs)
        for (int n : {2, 5}) {
            double out[6];
            gaussian_expectation_2d(g, n, 6,
                                    [](double sx, double sy, double *o) {
                                        o[0] = 1, o[1] = sx, o[2] = sy, o[3] = sx * sx, o[4] = sx * sy;
                                        o[5] = sx * sx * sy;
                                    },
                                    out);
            const double tol = 1e-13 * (1 + std::fabs(out[5]));
            EXPECT_NEAR(out[0], 1.0, tol);
            EXPECT_NEAR(out[1], g.mx, tol);
            EXPECT_NEAR(out[2], g.my, tol);
            EXPECT_NEAR(out[3], g.sxx + g.mx * g.mx, tol);
            EXPECT_NEAR(out[4], g.sxy + g.mx * g.my, tol);
            // E[(mx + a)^2 (my + b)] = mx^2 my + my sxx + 2 mx sxy (odd central moments vanish).
            EXPECT_NEAR(out[5], g.mx * g.mx * g.my + g.my * g.sxx + 2 * g.mx * g.sxy, tol) << n;
            double yy, y3;
            gaussian_expectation_2d(g, n, 1, [](double, double sy, double *o) { o[0] = sy * sy; }, &yy);
            gaussian_expectation_2d(g, n, 1, [](double, double sy, double *o) { o[0] = sy * sy * sy; }, &y3);
            EXPECT_NEAR(yy, g.syy + g.my * g.my, tol);
            EXPECT_NEAR(y3, g.my * g.my * g.my + 3 * g.my * g.syy, 1e-13 * (1 + std::fabs(y3)));
        }
    // The singular case has no mass off its line: E[(2 (sx - mx) - (sy - my))^2] = 4 - 8 + 4 = 0.
    double r;
    const SlopeGaussian s = gs[3];
    gaussian_expectation_2d(s, 4, 1,
                            [&](double sx, double sy, double *o) {
                                const double d = 2 * (sx - s.mx) - (sy - s.my);
                                o[0] = d * d;
                            },
                            &r);
    EXPECT_NEAR(r, 0.0, 1e-13);
    // exp(a sx): E = exp(a mx + a^2 sxx / 2). With b = a sd, the n-node rule integrates x^k
    // exactly for k < 2n and underestimates E[x^k] = (k - 1)!! by at most E[x^k] above (the
    // error term n!/(2n)! f^(2n) >= 0), so 0 <= E - Q <= sum_{j >= n} (b^2/2)^j / j!
    // <= (b^2/2)^n / n! e^(b^2/2): relative error <= (b^2/2)^n / n!.
    auto rel_bound = [](double b, int n) {
        double t = 1;
        for (int j = 1; j <= n; ++j) t *= b * b / 2 / j;
        return t;
    };
    for (double a : {-1.5, 0.7, 2.0}) {
        const SlopeGaussian g = gs[0];
        gaussian_expectation_2d(g, 12, 1, [&](double sx, double, double *o) { o[0] = std::exp(a * sx); }, &r);
        const double e1 = std::exp(a * g.mx + a * a * g.sxx / 2);
        EXPECT_NEAR(r, e1, (rel_bound(a * std::sqrt(g.sxx), 12) + 64 * kEps) * e1) << a;
        EXPECT_LE(r, e1 * (1 + 64 * kEps)) << a;  // the rule underestimates
        double ry;
        gaussian_expectation_2d(g, 12, 1, [&](double sx, double sy, double *o) { o[0] = std::exp(a * (sx + sy)); },
                                &ry);
        // sx + sy = mx + my + (l00 + l10) x + l11 y: a product of two 1D expectations.
        const double var = g.sxx + g.syy + 2 * g.sxy, l00 = std::sqrt(g.sxx), l10 = g.sxy / l00;
        const double l11 = std::sqrt(g.syy - l10 * l10);
        const double e2 = std::exp(a * (g.mx + g.my) + a * a * var / 2);
        const double rb = rel_bound(a * (l00 + l10), 12) + rel_bound(a * l11, 12);
        EXPECT_NEAR(ry, e2, (rb + 64 * kEps) * e2) << a;
    }
    // slope_to_normal: unit, facing (-sx, -sy, 1).
    const Vec3 nrm = slope_to_normal(0.3, -0.4);
    EXPECT_NEAR(length(nrm), 1.0, 1e-6);
    EXPECT_NEAR(nrm.x / nrm.z, -0.3, 1e-6);
    EXPECT_NEAR(nrm.y / nrm.z, 0.4, 1e-6);
}

// ================================================================ 8. §7 transfer functions

TEST(TransferFilter, TransferMomentsMatchQuadrature) {
    const RefRamp g{{-0.5, 0.0, 0.2, 0.9, 1.5}, {0.0, 0.1, 0.6, 0.65, 1.2}, 1};
    const Ramp r = g.ramp();
    for (double fb : {-1.0, 0.0, 0.35, 0.8, 2.5})
        for (double sf : {1e-3, 0.05, 0.2, 0.7, 3.0}) {
            const TransferMoments m = transfer_moments(r, fb, sf);
            const double *got[4] = {&m.g, &m.g2, &m.dg, &m.dg2};
            const double vmax = g.max_abs_value(), smax = g.max_abs_slope();
            const double term[4] = {vmax + sf * smax, std::pow(vmax + sf * smax, 2), smax, smax * smax};
            for (int kind = 0; kind < 4; ++kind) {
                const Quad q = ramp_reference(g, 0, kind, fb, sf);
                EXPECT_NEAR(*got[kind], q.value, q.err + 32 * kEps * term[kind] * g.x.size())
                    << "kind " << kind << " f_bar " << fb << " sigma_f " << sf;
            }
        }
    EXPECT_THROW(transfer_moments(kRamp3.ramp(), 0, 1), MesoError);
}

TEST(TransferFilter, TransferredStatisticsMatchMonteCarlo) {
    // h = g(f), f ~ N(f_bar, sigma_f^2); slopes of f (fx, fy) ~ N(mean, cov) independent of f;
    // dh/dx = g'(f) fx. Compared within 5 standard errors (estimated from the samples) of each
    // statistic; 2e6 draws, fixed seed.
    const RefRamp g{{-0.5, 0.0, 0.2, 0.9, 1.5}, {0.0, 0.1, 0.6, 0.65, 1.2}, 1};
    const Ramp r = g.ramp();
    struct Case {
        double fb, sf;
        SlopeGaussian fs;
    };
    const Case cases[] = {{0.3, 0.25, make(0.2, -0.1, 0.05, 0.08, 0.02)},
                          {0.0, 0.6, make(0.0, 0.0, 0.1, 0.1, 0.0)},
                          {1.0, 0.1, make(-0.5, 0.3, 0.02, 0.01, -0.01)},
                          {-0.4, 1.5, make(0.1, 0.4, 0.3, 0.05, 0.1)}};
    uint64_t seed = 7;
    for (const Case &k : cases) {
        const TransferredStatistics t = transferred_statistics(transfer_moments(r, k.fb, k.sf), k.fs);
        Normal rn(seed++);
        const double l00 = std::sqrt(k.fs.sxx), l10 = k.fs.sxy / l00, l11 = std::sqrt(k.fs.syy - l10 * l10);
        const int N = 2000000;
        std::vector<double> h(N), hx(N), hy(N);
        Stat sh, sx, sy;
        for (int i = 0; i < N; ++i) {
            const double f = k.fb + k.sf * rn();
            const double z0 = rn(), z1 = rn();
            const double fx = k.fs.mx + l00 * z0, fy = k.fs.my + l10 * z0 + l11 * z1;
            const double gp = g.slope(f, 0);
            h[i] = g.eval(f, 0), hx[i] = gp * fx, hy[i] = gp * fy;
            sh.add(h[i]), sx.add(hx[i]), sy.add(hy[i]);
        }
        Stat vh, vxx, vyy, vxy;
        for (int i = 0; i < N; ++i) {
            const double a = h[i] - sh.mean(), bx = hx[i] - sx.mean(), by = hy[i] - sy.mean();
            vh.add(a * a), vxx.add(bx * bx), vyy.add(by * by), vxy.add(bx * by);
        }
        const std::string ctx = "f_bar " + std::to_string(k.fb) + " sigma_f " + std::to_string(k.sf);
        EXPECT_NEAR(t.h_mean, sh.mean(), 5 * sh.se()) << ctx;
        EXPECT_NEAR(t.h_var, vh.mean(), 5 * vh.se()) << ctx;
        EXPECT_NEAR(t.slopes.mx, sx.mean(), 5 * sx.se()) << ctx;
        EXPECT_NEAR(t.slopes.my, sy.mean(), 5 * sy.se()) << ctx;
        EXPECT_NEAR(t.slopes.sxx, vxx.mean(), 5 * vxx.se()) << ctx;
        EXPECT_NEAR(t.slopes.syy, vyy.mean(), 5 * vyy.se()) << ctx;
        EXPECT_NEAR(t.slopes.sxy, vxy.mean(), 5 * vxy.se()) << ctx;
        std::printf("[transferred MC %s] h mean %.5f/%.5f var %.5f/%.5f, slope cov xx %.5f/%.5f yy %.5f/%.5f xy "
                    "%+.5f/%+.5f (closed form / MC)\n",
                    ctx.c_str(), t.h_mean, sh.mean(), t.h_var, vh.mean(), t.slopes.sxx, vxx.mean(), t.slopes.syy,
                    vyy.mean(), t.slopes.sxy, vxy.mean());
    }
    // A linear g = 2 f + 1 (over the whole support): h ~ N(2 f_bar + 1, 4 sigma_f^2), slopes
    // exactly 2 x those of f.
    const Ramp lin({-100.0, 100.0}, {-199.0, 201.0}, 1);
    const SlopeGaussian fs = make(0.1, -0.2, 0.05, 0.07, 0.01);
    const TransferredStatistics t = transferred_statistics(transfer_moments(lin, 0.3, 0.4), fs);
    EXPECT_NEAR(t.h_mean, 1.6, 1e-12);
    EXPECT_NEAR(t.h_var, 0.64, 1e-9);
    EXPECT_NEAR(t.slopes.mx, 0.2, 1e-12); EXPECT_NEAR(t.slopes.my, -0.4, 1e-12);
    EXPECT_NEAR(t.slopes.sxx, 0.2, 1e-12); EXPECT_NEAR(t.slopes.syy, 0.28, 1e-12);
    EXPECT_NEAR(t.slopes.sxy, 0.04, 1e-12);
}

// E[C(|s|)] (gaussian_average_steepness) against a brute-force 2D midpoint rule over +-8 sd, for
// centred, non-centred, anisotropic-correlated and concentrated (far from s = 0) distributions.
