#include "bsdf/slope_distribution.h"
#include <algorithm>
#include <cmath>
#include <limits>

namespace meso {

namespace {
constexpr double kPi = 3.14159265358979323846;
}

GaussianSlopes::GaussianSlopes(const SlopeGaussian &g, double min_variance) : m_g(g) {
    auto finite_or = [](double v, double d) { return std::isfinite(v) ? v : d; };
    m_g.mx = finite_or(g.mx, 0.0);
    m_g.my = finite_or(g.my, 0.0);
    m_g.sxx = std::max(finite_or(g.sxx, min_variance), min_variance);
    m_g.syy = std::max(finite_or(g.syy, min_variance), min_variance);
    const double cmax = (1.0 - 1e-6) * std::sqrt(m_g.sxx * m_g.syy);
    m_g.sxy = std::clamp(finite_or(g.sxy, 0.0), -cmax, cmax);
    const double det = m_g.sxx * m_g.syy - m_g.sxy * m_g.sxy;
    m_inv[0] = m_g.syy / det;
    m_inv[1] = m_g.sxx / det;
    m_inv[2] = -m_g.sxy / det;
    m_norm = 1.0 / (2 * kPi * std::sqrt(det));
    m_l00 = std::sqrt(m_g.sxx);
    m_l10 = m_g.sxy / m_l00;
    m_l11 = std::sqrt(std::max(m_g.syy - m_l10 * m_l10, 0.0));
}

double GaussianSlopes::p22(double x, double y) const {
    const double dx = x - m_g.mx, dy = y - m_g.my;
    const double q = m_inv[0] * dx * dx + m_inv[1] * dy * dy + 2 * m_inv[2] * dx * dy;
    return m_norm * std::exp(-0.5 * q);
}

double GaussianSlopes::D(Vec3 m) const {
    if (!(m.z > 0.f)) return 0.0;
    const double z = m.z, z2 = z * z;
    return p22(-m.x / z, -m.y / z) / (z2 * z2);
}

Vec3 GaussianSlopes::mesonormal() const {
    return normalize(Vec3(float(-m_g.mx), float(-m_g.my), 1.f));
}

bool GaussianSlopes::nu_of(Vec3 w, double &nu, double &sigma, double &cot_theta, double &mu) const {
    const double sin_theta = std::sqrt(std::max(0.0, double(w.x) * w.x + double(w.y) * w.y));
    if (sin_theta == 0.0) {  // straight up: never masked (nu = +inf)
        nu = std::numeric_limits<double>::infinity();
        sigma = 1, cot_theta = nu, mu = 0;
        return true;
    }
    const double c = w.x / sin_theta, s = w.y / sin_theta;
    mu = c * m_g.mx + s * m_g.my;                                        // eq. (14)
    const double var = c * c * m_g.sxx + s * s * m_g.syy + 2 * c * s * m_g.sxy;  // eq. (15)
    sigma = std::sqrt(std::max(var, 1e-300));
    cot_theta = w.z / sin_theta;
    nu = (cot_theta - mu) / (sigma * std::sqrt(2.0));
    return true;
}

double GaussianSlopes::lambda(Vec3 w, bool rational) const {
    double nu, sigma, cot, mu;
    nu_of(w, nu, sigma, cot, mu);
    if (!(nu > 0.0)) return std::numeric_limits<double>::infinity();
    if (std::isinf(nu)) return 0.0;
    if (rational) {
        if (nu >= 1.6) return 0.0;
        return (1.0 - 1.259 * nu + 0.396 * nu * nu) / (3.535 * nu + 2.181 * nu * nu);
    }
    if (nu > 6.0) {
        // The two terms agree to ~1/(2 nu^2) relative: use the asymptotic series of erfc,
        // Lambda = exp(-nu^2) / (2 nu sqrt(pi)) (1/(2 nu^2) - 3/(4 nu^4) + 15/(8 nu^6) - 105/(16 nu^8) + 945/(32 nu^10)),
        // truncation below 6e-6 relative for nu > 6 (where Lambda < 2e-19 anyway).
        const double r = 1.0 / (nu * nu);
        const double series = r * (0.5 + r * (-0.75 + r * (1.875 + r * (-6.5625 + r * 29.53125))));
        return std::exp(-nu * nu) / (2 * nu * std::sqrt(kPi)) * series;
    }
    // Rounding can leave a tiny negative difference: Lambda >= 0.
    return std::max(0.0, std::exp(-nu * nu) / (2 * nu * std::sqrt(kPi)) - 0.5 * std::erfc(nu));
}

double GaussianSlopes::lambda_smith(Vec3 w) const {
    double nu, sigma, cot, mu;
    nu_of(w, nu, sigma, cot, mu);
    if (std::isinf(nu) && nu > 0) return 0.0;
    if (!(cot > 0.0)) return std::numeric_limits<double>::infinity();  // at or below the horizon
    // tan(theta) * sigma * [phi(z) - z (1 - Phi(z))], z = sqrt(2) nu.
    const double integral = sigma * (std::exp(-nu * nu) / std::sqrt(2 * kPi) - nu * std::erfc(nu) / std::sqrt(2.0));
    return integral / cot;
}

Vec3 GaussianSlopes::sample_normal(Vec2 u) const {
    // Box-Muller pair, then s = mean + L z.
    const double r = std::sqrt(-2.0 * std::log(std::max(1.0 - double(u.x), 1e-300)));
    const double a = 2 * kPi * double(u.y);
    const double z0 = r * std::cos(a), z1 = r * std::sin(a);
    const double sx = m_g.mx + m_l00 * z0, sy = m_g.my + m_l10 * z0 + m_l11 * z1;
    const double len = std::sqrt(1.0 + sx * sx + sy * sy);
    return Vec3(float(-sx / len), float(-sy / len), float(1.0 / len));
}

}  // namespace meso
