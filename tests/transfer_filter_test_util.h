// Brute-force references for the tests of filter/transfer_filter.h (paper 001): composite Simpson
// rules split at every kink, a CDF-based formula for the moments of eq. 15, 2D Simpson of
// p_s(s) (1 - s.t)+ in a rotated frame. Shared by test_transfer_filter.cpp (ramps, tables,
// Gauss-Hermite, §7 moments) and test_transfer_filter_microsurface.cpp (D_h, D_s, steepness).
#pragma once
#include <gtest/gtest.h>
#include "material_test_util.h"
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <vector>
#include "core/error.h"
#include "bsdf/slope_distribution.h"
#include "filter/transfer_filter.h"
#include "sampling/rng.h"

namespace meso::test::tf {
using namespace meso;
}

namespace meso::test::tf {

constexpr double kPi = 3.14159265358979323846;
constexpr double kEps = std::numeric_limits<double>::epsilon();

// ------------------------------------------------------------------ reference quadrature

/// Composite Simpson on [a, b] with n (even) intervals.
template <typename F> inline double simpson(F f, double a, double b, int n) {
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
template <typename F> inline Quad piecewise_simpson(F f, std::vector<double> b, int n) {
    std::sort(b.begin(), b.end());
    double q1 = 0, q2 = 0;
    for (size_t i = 0; i + 1 < b.size(); ++i) {
        q1 += simpson(f, b[i], b[i + 1], n);
        q2 += simpson(f, b[i], b[i + 1], 2 * n);
    }
    return {q2, std::fabs(q2 - q1)};
}

inline double normal_pdf(double v, double mean, double sigma) {
    const double z = (v - mean) / sigma;
    return std::exp(-0.5 * z * z) / (sigma * std::sqrt(2 * kPi));
}
inline double Phi(double z) { return 0.5 * std::erfc(-z / std::sqrt(2.0)); }
inline double log_Phi(double z) {
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
inline Quad ramp_reference(const RefRamp &r, int c, int kind, double mean, double sigma, int n = 400) {
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
inline RefHeight reference_height(double L, int n = 7000) {
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
inline double smith_lambda_iso(double theta, double s2) {
    if (theta <= 0) return 0;
    const double cot = 1.0 / std::tan(theta), nu = cot / std::sqrt(2 * s2);
    return std::exp(-nu * nu) / (2 * nu * std::sqrt(kPi)) - 0.5 * std::erfc(nu);
}
/// theta (degrees) with smith_lambda_iso(theta) = L, by bisection.
inline double theta_of_lambda(double L, double s2) {
    if (L <= 0) return 0.0;
    double lo = 0, hi = 0.5 * kPi;
    for (int it = 0; it < 200; ++it) {
        const double mid = 0.5 * (lo + hi);
        (smith_lambda_iso(mid, s2) < L ? lo : hi) = mid;
    }
    return 0.5 * (lo + hi) * 180 / kPi;
}

// ------------------------------------------------------------ reference visible slopes

inline SlopeGaussian make(double mx, double my, double sxx, double syy, double sxy) { return {mx, my, sxx, syy, sxy}; }


/// The moments of p_s(s) max(0, 1 - s.t) by 2D Simpson. The integrand is the plain 2D Gaussian
/// density times the weight, evaluated at s; only the grid is laid out in the frame (u, w) of
/// t's direction (rotation: Jacobian 1) so that the kink u = 1/|t| is the domain's edge and the
/// integrand is smooth inside. Densities are scaled by exp(q_min / 2) (q_min: the smallest
/// Mahalanobis distance on the visible half-plane); `log_scale` gives it back.
struct VisRef {
    double mass = 0, log_scale = 0;  // M0 = mass * exp(-log_scale)
    double mx = 0, my = 0, sxx = 0, syy = 0, sxy = 0;
};
inline VisRef visible_reference_n(const SlopeGaussian &p, double tx, double ty, int n) {
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
inline VisCompare visible_reference(const SlopeGaussian &p, const Vec3 &wo, int n = 160) {
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

}  // namespace meso::test::tf
