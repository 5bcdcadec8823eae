#include "filter/vmf.h"
#include <algorithm>
#include <cmath>
#include <limits>
#include "core/frame.h"

namespace meso {
namespace vmf {

namespace {
constexpr double kPi = 3.14159265358979323846;

/// κ / (−expm1(−2κ)), continuous at 0 (value 1/2).
double kappa_over_one_minus_exp(double kappa) {
    if (!(kappa > 1e-300)) return 0.5;
    return kappa / -std::expm1(-2.0 * kappa);
}
}  // namespace

double log_norm(double kappa) {
    kappa = std::max(0.0, kappa);
    // κ/(4π sinh κ) = κ/(2π(1 − e^{−2κ})) e^{−κ}
    return std::log(kappa_over_one_minus_exp(kappa) / (2.0 * kPi)) - kappa;
}

double pdf_cos(double kappa, double c) {
    if (!(kappa >= 0.0)) kappa = 0.0;
    c = std::clamp(c, -1.0, 1.0);
    if (kappa > kMaxKappa) kappa = kMaxKappa;
    return kappa_over_one_minus_exp(kappa) / (2.0 * kPi) * std::exp(kappa * (c - 1.0));
}

double pdf(Vec3 mu, double kappa, Vec3 w) {
    const double mx = mu.x, my = mu.y, mz = mu.z, wx = w.x, wy = w.y, wz = w.z;
    const double l2 = (mx * mx + my * my + mz * mz) * (wx * wx + wy * wy + wz * wz);
    if (!(l2 > 0.0)) return pdf_cos(kappa, 0.0);
    return pdf_cos(kappa, (mx * wx + my * wy + mz * wz) / std::sqrt(l2));
}

double pdf_cos_large_kappa(double kappa, double c) { return kappa / (2.0 * kPi) * std::exp(kappa * (c - 1.0)); }

double sample_cos(double kappa, double u, double *one_minus_w) {
    u = std::clamp(u, 0.0, 1.0);
    double omw;  // 1 − w
    if (!(kappa > 1e-300)) {
        omw = 2.0 * (1.0 - u);
    } else {
        kappa = std::min(kappa, kMaxKappa);
        const double x = (1.0 - u) * std::expm1(-2.0 * kappa);  // in (−1, 0]
        omw = x <= -1.0 ? 2.0 : -std::log1p(x) / kappa;
    }
    omw = std::clamp(omw, 0.0, 2.0);
    if (one_minus_w) *one_minus_w = omw;
    return 1.0 - omw;
}

Vec3 sample(Vec3 mu, double kappa, Vec2 u) {
    double omw;
    const double w = sample_cos(kappa, u.x, &omw);
    const double sin_t = std::sqrt(std::max(0.0, omw * (2.0 - omw)));
    const double phi = 2.0 * kPi * u.y;
    Vec3 s, t;
    coordinate_system(mu, s, t);
    const double a = sin_t * std::cos(phi), b = sin_t * std::sin(phi);
    return normalize(Vec3(float(a * s.x + b * t.x + w * mu.x), float(a * s.y + b * t.y + w * mu.y),
                          float(a * s.z + b * t.z + w * mu.z)));
}

double kappa_from_r(double r) {
    if (!(r > 0.0)) return 0.0;  // also NaN
    if (r >= 1.0) return kMaxKappa;
    const double e = 1.0 - r;
    // (3r − r³)/(1 − r²) with 1 − r² = e (2 − e) (no cancellation near r = 1 for exact e).
    const double k = r * (3.0 - r * r) / (e * (2.0 - e));
    return std::min(k, kMaxKappa);
}

double r_from_kappa_closed_form(double kappa) {
    if (!(kappa > 0.0)) return 0.0;
    // t = ‖r‖ solves t³ − κ t² − 3t + κ = 0. With t = x + κ/3: x³ + p x + q = 0,
    // p = −3 − κ²/3 = −3 m², q = −2κ³/27, m² = 1 + (κ/3)². Viète: three real roots
    // x_k = 2m cos(φ/3 − 2πk/3), cos φ = (3q / 2p) sqrt(−3/p) = (u/m)³, u = κ/3.
    // k = 1 is the root in [0, 1) (at κ = 0: roots √3, 0, −√3).
    const double u = kappa / 3.0, m = std::sqrt(1.0 + u * u);
    const double c = u / m;
    const double phi = std::acos(std::clamp(c * c * c, -1.0, 1.0));
    return u + 2.0 * m * std::cos(phi / 3.0 - 2.0 * kPi / 3.0);
}

double r_from_kappa(double kappa) {
    if (!(kappa > 0.0)) return 0.0;
    if (!std::isfinite(kappa)) return 1.0;
    if (kappa < 1.0) {
        // Small κ: ‖r‖ ≈ κ/3 is small, so solve for it directly (1 − e would lose its
        // relative precision): Newton on f(r) = r³ − κr² − 3r + κ, bracketed in [0, 1).
        double lo = 0.0, hi = 1.0, r = std::clamp(r_from_kappa_closed_form(kappa), 0.0, 1.0);
        for (int it = 0; it < 60; ++it) {
            const double f = ((r - kappa) * r - 3.0) * r + kappa;  // decreasing in r on [0, 1)
            if (f > 0.0) lo = r; else hi = r;
            if (f == 0.0) break;
            const double df = (3.0 * r - 2.0 * kappa) * r - 3.0;
            double rn = r - f / df;
            if (!(rn > lo && rn < hi)) rn = 0.5 * (lo + hi);
            if (std::abs(rn - r) <= 1e-17 * std::max(r, 1e-300)) { r = rn; break; }
            r = rn;
        }
        return r;
    }
    // Newton on g(e) = κ e (2 − e) − (1 − e)(2 + 2e − e²), e = 1 − ‖r‖ in (0, 1], bracketed.
    double lo = 0.0, hi = 1.0;
    double e = std::clamp(1.0 - r_from_kappa_closed_form(kappa), 0.0, 1.0);
    if (kappa > 1e3) e = 1.0 / kappa;  // the closed form cancels there; 1/κ is within O(1/κ²)
    for (int it = 0; it < 60; ++it) {
        const double g = kappa * e * (2.0 - e) - (1.0 - e) * (2.0 + 2.0 * e - e * e);
        if (g < 0.0) lo = e; else hi = e;
        if (g == 0.0) break;
        const double dg = 2.0 * kappa * (1.0 - e) + 3.0 * e * (2.0 - e);
        double en = e - g / dg;
        if (!(en > lo && en < hi)) en = 0.5 * (lo + hi);
        if (std::abs(en - e) <= 1e-17 * std::max(e, 1e-300)) { e = en; break; }
        e = en;
    }
    return 1.0 - e;
}

RTable::RTable() {
    for (int i = 0; i < kSize; ++i) {
        const double t = double(i) / (kSize - 1);
        m_r[i] = t >= 1.0 ? 1.0 : r_from_kappa(3.0 * t / (1.0 - t));
    }
}

double RTable::lookup(double kappa) const {
    if (!(kappa > 0.0)) return 0.0;
    const double t = std::isfinite(kappa) ? kappa / (kappa + 3.0) : 1.0;
    const double x = t * (kSize - 1);
    const int i = std::min(int(x), kSize - 2);
    const double f = x - i;
    return m_r[i] * (1.0 - f) + m_r[i + 1] * f;
}

const RTable &RTable::get() {
    static const RTable table;
    return table;
}

double convolve_kappa(double ka, double kb) {
    if (!(ka >= 0.0) || !(kb >= 0.0)) return 0.0;
    if (std::isinf(ka)) return kb;
    if (std::isinf(kb)) return ka;
    if (ka + kb <= 0.0) return 0.0;
    return ka * kb / (ka + kb);
}

double mean_cosine(double kappa) {
    if (!(kappa > 0.0)) return 0.0;
    if (kappa < 1e-3) return kappa / 3.0 - kappa * kappa * kappa / 45.0;
    // coth κ − 1/κ = (1 + e^{−2κ}) / (1 − e^{−2κ}) − 1/κ
    const double em = std::exp(-2.0 * kappa);
    return (1.0 + em) / -std::expm1(-2.0 * kappa) - 1.0 / kappa;
}

}  // namespace vmf
}  // namespace meso
