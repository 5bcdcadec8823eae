// Filtering non-linear transfer functions (paper 001, Heitz et al. 2014): every closed form of
// render/transfer_filter.h against an independent brute-force reference written here (composite
// Simpson rules split at every kink, a CDF-based formula for the moments of eq. 15, 2D Simpson
// of p_s(s) (1 - s.t)+ in a rotated frame, fixed-seed Monte Carlo). Tolerances are the
// reference's own error estimate (Simpson at n and 2n intervals: |Q_n - Q_2n| is ~15 times the
// error of Q_2n) plus a round-off floor proportional to the size of the terms summed, or a few
// Monte Carlo standard errors; none was widened to make a case pass.
//
// The fit of eq. 16-17 is measured against the exact moments and the table printed (it goes into
// the README); its assertion is a regression guard just above the measured error.
#include <gtest/gtest.h>
#include "material_test_util.h"
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <vector>
#include "core/error.h"
#include "render/slope_distribution.h"
#include "render/transfer_filter.h"
#include "sampling/rng.h"


using namespace meso;
using meso::test::dir_deg;

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kEps = std::numeric_limits<double>::epsilon();

// ------------------------------------------------------------------ reference quadrature

/// Composite Simpson on [a, b] with n (even) intervals.
template <typename F> double simpson(F f, double a, double b, int n) {
    if (!(b > a)) return 0.0;
    const double h = (b - a) / n;
    double s = f(a) + f(b);
    for (int k = 1; k < n; ++k) s += (k % 2 ? 4.0 : 2.0) * f(a + h * k);
    return s * h / 3.0;
}

/// A quadrature value and the estimate of its error (|Q_n - Q_2n|, ~15x the error of Q_2n).
struct Quad {
    double value = 0, err = 0;
};

/// Simpson over consecutive breakpoints (sorted), each piece with n and 2n intervals.
template <typename F> Quad piecewise_simpson(F f, std::vector<double> b, int n) {
    std::sort(b.begin(), b.end());
    double q1 = 0, q2 = 0;
    for (size_t i = 0; i + 1 < b.size(); ++i) {
        q1 += simpson(f, b[i], b[i + 1], n);
        q2 += simpson(f, b[i], b[i + 1], 2 * n);
    }
    return {q2, std::fabs(q2 - q1)};
}

double normal_pdf(double v, double mean, double sigma) {
    const double z = (v - mean) / sigma;
    return std::exp(-0.5 * z * z) / (sigma * std::sqrt(2 * kPi));
}
double Phi(double z) { return 0.5 * std::erfc(-z / std::sqrt(2.0)); }
double log_Phi(double z) {
    if (z > 0) return std::log1p(-0.5 * std::erfc(z / std::sqrt(2.0)));
    const double p = Phi(z);
    return p > 0 ? std::log(p) : -std::numeric_limits<double>::infinity();
}

// ---------------------------------------------------------------------- reference ramp

/// An independent piecewise-linear evaluation (not Ramp::eval): stop-major values.
struct RefRamp {
    std::vector<double> x, v;
    int ch = 1;
    double eval(double t, int c) const {
        const size_t n = x.size();
        if (n == 1 || t <= x[0]) return v[c];
        if (t >= x[n - 1]) return v[(n - 1) * ch + c];
        size_t i = 0;
        while (!(t < x[i + 1])) ++i;
        const double a = (t - x[i]) / (x[i + 1] - x[i]);
        return v[i * ch + c] + a * (v[(i + 1) * ch + c] - v[i * ch + c]);
    }
    double slope(double t, int c) const {  // open segments only (the quadrature never asks at a stop)
        const size_t n = x.size();
        if (n == 1 || t <= x[0] || t >= x[n - 1]) return 0.0;
        size_t i = 0;
        while (!(t < x[i + 1])) ++i;
        return (v[(i + 1) * ch + c] - v[i * ch + c]) / (x[i + 1] - x[i]);
    }
    double max_abs_value() const {
        double m = 0;
        for (double a : v) m = std::max(m, std::fabs(a));
        return m;
    }
    double max_abs_slope() const {
        double m = 0;
        for (size_t i = 0; i + 1 < x.size(); ++i)
            for (int c = 0; c < ch; ++c) m = std::max(m, std::fabs((v[(i + 1) * ch + c] - v[i * ch + c]) / (x[i + 1] - x[i])));
        return m;
    }
    /// Sum over all kinks (the two ends included) of |slope change|, per channel maximum.
    double total_kink() const {
        double best = 0;
        for (int c = 0; c < ch; ++c) {
            double prev = 0, sum = 0;
            for (size_t i = 0; i + 1 < x.size(); ++i) {
                const double s = (v[(i + 1) * ch + c] - v[i * ch + c]) / (x[i + 1] - x[i]);
                sum += std::fabs(s - prev);
                prev = s;
            }
            sum += std::fabs(prev);
            best = std::max(best, sum);
        }
        return best;
    }
    Ramp ramp() const { return Ramp(x, v, ch); }
};

const RefRamp kRamp1{{-1.0, 0.0, 0.5, 2.0}, {0.2, 1.0, -0.5, 0.7}, 1};  // slopes 0.8, -3, 0.8
const RefRamp kRamp3{{0.0, 0.25, 0.6, 1.0},
                     {0.1, 0.0, 0.9, 1.0, 0.3, 0.2, 0.4, 1.0, 0.0, 0.9, 0.9, 0.6},
                     3};

/// <w(C), N(mean, sigma^2)> by Simpson split at the stops, over mean +- 14 sigma (the tail
/// beyond is 1.6e-44 of the mass). kind: 0 = C, 1 = C^2, 2 = C', 3 = C'^2.
Quad ramp_reference(const RefRamp &r, int c, int kind, double mean, double sigma, int n = 400) {
    std::vector<double> b = {mean - 14 * sigma, mean + 14 * sigma};
    for (double x : r.x)
        if (x > b[0] && x < b[1]) b.push_back(x);
    auto f = [&](double v) {
        double g;
        if (kind <= 1) {
            g = r.eval(v, c);
            if (kind == 1) g *= g;
        } else {
            g = r.slope(v, c);
            if (kind == 3) g *= g;
        }
        return g * normal_pdf(v, mean, sigma);
    };
    // The slope jumps at the stops, where Simpson's end nodes sit: take each piece's (constant)
    // slope at its midpoint.
    if (kind >= 2) {
        std::sort(b.begin(), b.end());
        double q1 = 0, q2 = 0;
        for (size_t i = 0; i + 1 < b.size(); ++i) {
            const double mid = 0.5 * (b[i] + b[i + 1]);
            double s = r.slope(mid, c);  // constant on the piece
            if (kind == 3) s *= s;
            auto g = [&](double v) { return s * normal_pdf(v, mean, sigma); };
            q1 += simpson(g, b[i], b[i + 1], n);
            q2 += simpson(g, b[i], b[i + 1], 2 * n);
        }
        return {q2, std::fabs(q2 - q1)};
    }
    return piecewise_simpson(f, b, n);
}

// -------------------------------------------------------------- reference height filter

/// Mean and standard deviation (in units of sigma_h) of eq. 15 from its CDF F(z) = Phi(z)^(L+1):
/// E[Z] = int_0^inf (1 - F) - int_-inf^0 F, E[Z^2] = int_0^inf 2z (1 - F) + int_-inf^0 2|z| F.
/// A different formula from the density quadrature of height_filter_exact.
struct RefHeight {
    double mu, sigma, err;
};
RefHeight reference_height(double L, int n = 7000) {
    auto F = [&](double z) { return std::exp((L + 1) * log_Phi(z)); };
    auto Fc = [&](double z) { return -std::expm1((L + 1) * log_Phi(z)); };  // 1 - F
    const double A = 14.0;
    auto e1 = [&](int m) {
        return simpson(Fc, 0, A, m) - simpson(F, -A, 0, m);
    };
    auto e2 = [&](int m) {
        return simpson([&](double z) { return 2 * z * Fc(z); }, 0, A, m) +
               simpson([&](double z) { return -2 * z * F(z); }, -A, 0, m);
    };
    const double m1a = e1(n), m1b = e1(2 * n), m2a = e2(n), m2b = e2(2 * n);
    const double sa = std::sqrt(m2a - m1a * m1a), sb = std::sqrt(m2b - m1b * m1b);
    return {m1b, sb, std::max(std::fabs(m1a - m1b), std::fabs(sa - sb))};
}

/// The paper's §3 Smith Lambda for an isotropic centred Beckmann slope variance s2.
double smith_lambda_iso(double theta, double s2) {
    if (theta <= 0) return 0;
    const double cot = 1.0 / std::tan(theta), nu = cot / std::sqrt(2 * s2);
    return std::exp(-nu * nu) / (2 * nu * std::sqrt(kPi)) - 0.5 * std::erfc(nu);
}
/// theta (degrees) with smith_lambda_iso(theta) = L, by bisection.
double theta_of_lambda(double L, double s2) {
    if (L <= 0) return 0.0;
    double lo = 0, hi = 0.5 * kPi;
    for (int it = 0; it < 200; ++it) {
        const double mid = 0.5 * (lo + hi);
        (smith_lambda_iso(mid, s2) < L ? lo : hi) = mid;
    }
    return 0.5 * (lo + hi) * 180 / kPi;
}

// ------------------------------------------------------------ reference visible slopes

SlopeGaussian make(double mx, double my, double sxx, double syy, double sxy) { return {mx, my, sxx, syy, sxy}; }


/// The moments of p_s(s) max(0, 1 - s.t) by 2D Simpson. The integrand is the plain 2D Gaussian
/// density times the weight, evaluated at s; only the grid is laid out in the frame (u, w) of
/// t's direction (rotation: Jacobian 1) so that the kink u = 1/|t| is the domain's edge and the
/// integrand is smooth inside. Densities are scaled by exp(q_min / 2) (q_min: the smallest
/// Mahalanobis distance on the visible half-plane); `log_scale` gives it back.
struct VisRef {
    double mass = 0, log_scale = 0;  // M0 = mass * exp(-log_scale)
    double mx = 0, my = 0, sxx = 0, syy = 0, sxy = 0;
};
VisRef visible_reference_n(const SlopeGaussian &p, double tx, double ty, int n) {
    const double a = std::hypot(tx, ty), ex = tx / a, ey = ty / a;
    const double det = p.sxx * p.syy - p.sxy * p.sxy;
    const double ixx = p.syy / det, iyy = p.sxx / det, ixy = -p.sxy / det;
    const double norm = 1.0 / (2 * kPi * std::sqrt(det));
    // Integration bounds only (not the integrand): statistics of u = s.e and w | u.
    const double mu = ex * p.mx + ey * p.my, mw = -ey * p.mx + ex * p.my;
    const double vu = ex * ex * p.sxx + ey * ey * p.syy + 2 * ex * ey * p.sxy;
    const double vw = ey * ey * p.sxx + ex * ex * p.syy - 2 * ex * ey * p.sxy;
    const double cuw = -ex * ey * p.sxx + ex * ey * p.syy + (ex * ex - ey * ey) * p.sxy;
    const double su = std::sqrt(vu), sw_cond = std::sqrt(std::max(vw - cuw * cuw / vu, 1e-300));
    const double c = 1.0 / a, z = (c - mu) / su;
    double u0, u1;
    if (z > -3) {
        u0 = mu - 10 * su;
        u1 = std::min(c, mu + 10 * su);
    } else {
        u0 = c - 40 * su / -z;
        u1 = c;
    }
    const double qmin = z < 0 ? z * z : 0.0;
    auto density = [&](double sx, double sy) {
        const double dx = sx - p.mx, dy = sy - p.my;
        const double q = ixx * dx * dx + iyy * dy * dy + 2 * ixy * dx * dy;
        return norm * std::exp(-0.5 * (q - qmin));
    };
    auto weight = [&](double sx, double sy) { return std::max(0.0, 1.0 - sx * tx - sy * ty); };
    auto integrate = [&](auto g) {  // int int g(sx, sy) density weight
        return simpson(
            [&](double u) {
                const double wc = mw + cuw / vu * (u - mu);
                return simpson(
                    [&](double w) {
                        const double sx = u * ex - w * ey, sy = u * ey + w * ex;
                        return g(sx, sy) * density(sx, sy) * weight(sx, sy);
                    },
                    wc - 10 * sw_cond, wc + 10 * sw_cond, n);
            },
            u0, u1, n);
    };
    VisRef r;
    r.log_scale = 0.5 * qmin;
    r.mass = integrate([](double, double) { return 1.0; });
    r.mx = integrate([](double sx, double) { return sx; }) / r.mass;
    r.my = integrate([](double, double sy) { return sy; }) / r.mass;
    const double mx = r.mx, my = r.my;
    r.sxx = integrate([&](double sx, double) { return (sx - mx) * (sx - mx); }) / r.mass;
    r.syy = integrate([&](double, double sy) { return (sy - my) * (sy - my); }) / r.mass;
    r.sxy = integrate([&](double sx, double sy) { return (sx - mx) * (sy - my); }) / r.mass;
    return r;
}

struct VisCompare {
    VisRef ref, err;  // err: |Q_n - Q_2n| of each number
};
VisCompare visible_reference(const SlopeGaussian &p, const Vec3 &wo, int n = 160) {
    const double tx = double(wo.x) / double(wo.z), ty = double(wo.y) / double(wo.z);
    const VisRef a = visible_reference_n(p, tx, ty, n), b = visible_reference_n(p, tx, ty, 2 * n);
    VisCompare c;
    c.ref = b;
    c.err.mass = std::fabs(a.mass - b.mass);
    c.err.mx = std::fabs(a.mx - b.mx);
    c.err.my = std::fabs(a.my - b.my);
    c.err.sxx = std::fabs(a.sxx - b.sxx);
    c.err.syy = std::fabs(a.syy - b.syy);
    c.err.sxy = std::fabs(a.sxy - b.sxy);
    return c;
}

/// Gaussian draws by Box-Muller from PCG32 (fixed seed).
struct Normal {
    PCG32 rng;
    explicit Normal(uint64_t seed) : rng(seed) {}
    double operator()() {
        const double u1 = 1.0 - rng.next_double(), u2 = rng.next_double();
        return std::sqrt(-2 * std::log(u1)) * std::cos(2 * kPi * u2);
    }
};

/// Running mean and standard error.
struct Stat {
    double n = 0, s = 0, s2 = 0;
    void add(double v) { n += 1, s += v, s2 += v * v; }
    double mean() const { return s / n; }
    double se() const { return std::sqrt(std::max(0.0, s2 / n - mean() * mean()) / n); }
};

}  // namespace

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
