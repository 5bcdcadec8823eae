#include "bsdf/microfacet.h"
#include <cmath>
#include <fmt/format.h>
#include "bsdf/material.h"
#include "core/f64_lanes.h"
#include "core/properties.h"
#include "sampling/warp.h"

namespace meso {

namespace {
constexpr double kPi = 3.14159265358979323846;
constexpr double kSqrtPi = 1.77245385090551602730;

struct D3 {
    double x, y, z;
};
inline D3 d3(const Vec3 &v) { return {v.x, v.y, v.z}; }
inline Vec3 normalized_f(double x, double y, double z) {
    double l = std::sqrt(x * x + y * y + z * z);
    if (!(l > 0.0) || !std::isfinite(l)) return Vec3(0.f, 0.f, 0.f);
    return Vec3(float(x / l), float(y / l), float(z / l));
}
}  // namespace

namespace {
/// Giles 2010, "Approximating the erfinv function": the single-precision approximation
/// (relative error below about 4e-7) for y in (-1, 1).
double erfinv_guess(double y) {
    double w = -std::log((1.0 - y) * (1.0 + y)), p;
    if (w < 5.0) {
        w -= 2.5;
        p = 2.81022636e-08;
        p = 3.43273939e-07 + p * w;
        p = -3.5233877e-06 + p * w;
        p = -4.39150654e-06 + p * w;
        p = 0.00021858087 + p * w;
        p = -0.00125372503 + p * w;
        p = -0.00417768164 + p * w;
        p = 0.246640727 + p * w;
        p = 1.50140941 + p * w;
    } else {
        w = std::sqrt(w) - 3.0;
        p = -0.000200214257;
        p = 0.000100950558 + p * w;
        p = 0.00134934322 + p * w;
        p = -0.00367342844 + p * w;
        p = 0.00573950773 + p * w;
        p = -0.0076224613 + p * w;
        p = 0.00943887047 + p * w;
        p = 1.00167406 + p * w;
        p = 2.83297682 + p * w;
    }
    return p * y;
}

/// erfinv by `steps` Newton steps in double from erfinv_guess. The residual erf(x) - y is formed
/// with erfc in the tails so that it keeps its relative precision when |y| -> 1. Newton's error
/// goes e -> x e² per step, so one step from the guess leaves about 2e-13 x³ (below float's
/// resolution of a sampled slope by six orders of magnitude) and three reach double rounding.
double erfinv_newton(double y, int steps) {
    if (y <= -1.0) return -INFINITY;
    if (y >= 1.0) return INFINITY;
    double x = erfinv_guess(y);
    for (int i = 0; i < steps; ++i) {
        double r;
        if (y > 0.5) r = (1.0 - y) - std::erfc(x);
        else if (y < -0.5) r = std::erfc(-x) - (1.0 + y);
        else r = std::erf(x) - y;
        double d = 2.0 / kSqrtPi * std::exp(-x * x);
        if (!(d > 0.0)) break;
        x -= r / d;
    }
    return x;
}
}  // namespace

double erfinv(double y) { return erfinv_newton(y, 3); }

MicrofacetDistribution::MicrofacetDistribution(MicrofacetType type, float alpha_u, float alpha_v, bool sample_visible)
    : m_type(type), m_alpha_u(std::max(alpha_u, kMinAlpha)), m_alpha_v(std::max(alpha_v, kMinAlpha)),
      m_sample_visible(sample_visible) {}

float MicrofacetDistribution::D(const Vec3 &mf) const {
    D3 m = d3(mf);
    if (!(m.z > 0.0)) return 0.f;
    double au = m_alpha_u, av = m_alpha_v;
    double x2 = m.x * m.x / (au * au), y2 = m.y * m.y / (av * av), z2 = m.z * m.z;
    double r;
    if (m_type == MicrofacetType::GGX) {
        double den = x2 + y2 + z2;  // = |m|^2 (1 + tan^2 term) cos^2 ...
        r = 1.0 / (kPi * au * av * den * den);
    } else {
        double e = (x2 + y2) / z2;
        r = std::exp(-e) / (kPi * au * av * z2 * z2);
    }
    return std::isfinite(r) ? float(r) : 0.f;
}

double MicrofacetDistribution::lambda(const Vec3 &wf) const {
    D3 w = d3(wf);
    double z2 = w.z * w.z;
    double a2t2_num = w.x * w.x * double(m_alpha_u) * m_alpha_u + w.y * w.y * double(m_alpha_v) * m_alpha_v;
    if (a2t2_num == 0.0) return 0.0;  // normal direction: no masking
    if (z2 == 0.0) return INFINITY;   // exactly grazing: fully masked
    double a2t2 = a2t2_num / z2;       // alpha(phi)^2 tan^2(theta)
    if (m_type == MicrofacetType::GGX) {
        // (-1 + sqrt(1 + a2t2)) / 2 without cancellation for small a2t2.
        return a2t2 / (2.0 * (1.0 + std::sqrt(1.0 + a2t2)));
    }
    double a = 1.0 / std::sqrt(a2t2);
    // Beckmann: (erf(a) - 1)/2 + exp(-a^2)/(2 a sqrt(pi)); erfc keeps the tail accurate.
    double l = 0.5 * (std::exp(-a * a) / (a * kSqrtPi) - std::erfc(a));
    return std::max(l, 0.0);
}

void MicrofacetDistribution::D_lambda_batch(const Vec3 *mf, const Vec3 *wf, int n, float *Dout, double *lout) const {
    using lanes::F64x2;
    using lanes::splat;
    const double au = m_alpha_u, av = m_alpha_v, iau2 = 1.0 / (au * au), iav2 = 1.0 / (av * av);
    const double au2 = au * au, av2 = av * av, norm = 1.0 / (kPi * au * av);
    const bool ggx = m_type == MicrofacetType::GGX;
    for (int k = 0; k < n; k += 2) {
        const int k1 = k + 1 < n ? k + 1 : k;
        const F64x2 mx{mf[k].x, mf[k1].x}, my{mf[k].y, mf[k1].y}, mz{mf[k].z, mf[k1].z};
        const F64x2 wx{wf[k].x, wf[k1].x}, wy{wf[k].y, wf[k1].y}, wz{wf[k].z, wf[k1].z};
        // D, as D(): x2 = m.x² / au² (here times 1 / au², the same to an ulp), z2 = m.z².
        const F64x2 x2 = mx * mx * splat(iau2), y2 = my * my * splat(iav2), z2 = mz * mz;
        F64x2 r;
        if (ggx) {
            const F64x2 den = x2 + y2 + z2;
            r = splat(norm) / (den * den);
        } else {
            F64x2 e = (x2 + y2) / z2;
            e = e == e ? e : splat(0.0);  // m.z = 0 (0 / 0): masked below
            r = lanes::exp_nonpositive(-e) * splat(norm) / (z2 * z2);
        }
        // Λ, as lambda(): a²t² = (w.x² au² + w.y² av²) / w.z².
        const F64x2 num = wx * wx * splat(au2) + wy * wy * splat(av2), wz2 = wz * wz;
        const F64x2 a2t2 = num / wz2;
        F64x2 l;
        if (ggx) {
            const F64x2 q{std::sqrt(1.0 + a2t2[0]), std::sqrt(1.0 + a2t2[1])};
            l = a2t2 / (splat(2.0) * (splat(1.0) + q));
        } else {
            // a = 1 / sqrt(a²t²) > 0; erfc(a) = t e^{−a² + P(t)}, t = 1 / (1 + a / 2) (erfcc).
            const F64x2 a{1.0 / std::sqrt(a2t2[0]), 1.0 / std::sqrt(a2t2[1])};
            const F64x2 ea = lanes::exp_nonpositive(-(a * a));
            const F64x2 t = splat(1.0) / (splat(1.0) + splat(0.5) * a);
            F64x2 p = splat(0.17087277);
            for (double c : {-0.82215223, 1.48851587, -1.13520398, 0.27886807, -0.18628806, 0.09678418, 0.37409196,
                             1.00002368, -1.26551223})
                p = p * t + splat(c);
            // P is in [−1.27, 0.01]: exp_nonpositive's reduction also holds for small positive x.
            const F64x2 erfc = t * lanes::exp_nonpositive(p - a * a);
            l = splat(0.5) * (ea / (a * splat(kSqrtPi)) - erfc);
            l = l > splat(0.0) ? l : splat(0.0);
        }
        for (int q = 0; q < 2 && k + q < n; ++q) {
            const double d = mz[q] > 0.0 ? r[q] : 0.0;
            Dout[k + q] = std::isfinite(d) ? float(d) : 0.f;
            lout[k + q] = num[q] == 0.0 ? 0.0 : wz2[q] == 0.0 ? INFINITY : l[q];
        }
    }
}

float MicrofacetDistribution::G1(const Vec3 &w, const Vec3 &m) const {
    if (!(dot(w, m) * w.z > 0.f)) return 0.f;
    double l = lambda(w);
    return std::isfinite(l) ? float(1.0 / (1.0 + l)) : 0.f;
}

float MicrofacetDistribution::G(const Vec3 &wo, const Vec3 &wi, const Vec3 &m) const {
    if (!(dot(wo, m) * wo.z > 0.f) || !(dot(wi, m) * wi.z > 0.f)) return 0.f;
    return G(wo, wi, m, lambda(wo));
}

float MicrofacetDistribution::G(const Vec3 &wo, const Vec3 &wi, const Vec3 &m, double lo) const {
    if (!(dot(wo, m) * wo.z > 0.f) || !(dot(wi, m) * wi.z > 0.f)) return 0.f;
    const double li = lambda(wi);
    if (!std::isfinite(lo) || !std::isfinite(li)) return 0.f;
    if (wo.z * wi.z > 0.f) return float(1.0 / (1.0 + lo + li));
    // Transmission: ∫ C(h)^Λo (1 - C(h))^Λi dC = B(1 + Λo, 1 + Λi)  (Heitz 2014 eq. 101).
    double g = std::exp(std::lgamma(1.0 + lo) + std::lgamma(1.0 + li) - std::lgamma(2.0 + lo + li));
    return std::isfinite(g) ? float(std::min(g, 1.0)) : 0.f;
}

float MicrofacetDistribution::pdf(const Vec3 &wo, const Vec3 &m) const {
    if (!(m.z > 0.f)) return 0.f;
    if (!m_sample_visible) return D(m) * m.z;
    if (!(wo.z > 0.f)) return 0.f;
    float dwm = dot(wo, m);
    if (!(dwm > 0.f)) return 0.f;
    double r = double(G1(wo, m)) * dwm * D(m) / wo.z;
    return std::isfinite(r) ? float(r) : 0.f;
}

Vec3 MicrofacetDistribution::sample(const Vec3 &wo, Vec2 u, float *pdf_out) const {
    Vec3 m = !m_sample_visible ? sample_full(u)
             : (m_type == MicrofacetType::GGX ? sample_visible_ggx(wo, u) : sample_visible_beckmann(wo, u));
    float p = pdf(wo, m);
    if (!(p > 0.f) || !std::isfinite(p)) p = 0.f;
    *pdf_out = p;
    return m;
}

Vec3 MicrofacetDistribution::sample_full(Vec2 u) const {
    // Azimuth: tan(phi) = (alpha_v / alpha_u) tan(2 pi u2), quadrant kept by atan2 (the
    // inverse CDF of the azimuthal marginal, identical for Beckmann and GGX).
    double au = m_alpha_u, av = m_alpha_v;
    double phi0 = 2.0 * kPi * u.y;
    double phi = std::atan2(av * std::sin(phi0), au * std::cos(phi0));
    double cp = std::cos(phi), sp = std::sin(phi);
    double alpha2 = 1.0 / (cp * cp / (au * au) + sp * sp / (av * av));
    double ux = std::min(double(u.x), 1.0 - 1e-12);
    double tan2 = m_type == MicrofacetType::GGX ? alpha2 * ux / (1.0 - ux) : -alpha2 * std::log1p(-ux);
    double cos_t = 1.0 / std::sqrt(1.0 + tan2);
    double sin_t = std::sqrt(tan2) * cos_t;
    return normalized_f(sin_t * cp, sin_t * sp, cos_t);
}

Vec3 MicrofacetDistribution::sample_visible_ggx(const Vec3 &wo, Vec2 u) const {
    // Heitz 2018, "Sampling the GGX Distribution of Visible Normals", listing 1.
    double au = m_alpha_u, av = m_alpha_v;
    D3 v = d3(wo);
    double vx = au * v.x, vy = av * v.y, vz = v.z;
    double vl = std::sqrt(vx * vx + vy * vy + vz * vz);
    vx /= vl, vy /= vl, vz /= vl;
    double lensq = vx * vx + vy * vy;
    double t1x = 1, t1y = 0;
    if (lensq > 0.0) {
        double il = 1.0 / std::sqrt(lensq);
        t1x = -vy * il;
        t1y = vx * il;
    }
    // T2 = cross(Vh, T1) with T1 = (t1x, t1y, 0)
    double t2x = -vz * t1y, t2y = vz * t1x, t2z = vx * t1y - vy * t1x;
    double r = std::sqrt(double(u.x)), phi = 2.0 * kPi * u.y;
    double p1 = r * std::cos(phi), p2 = r * std::sin(phi);
    double s = 0.5 * (1.0 + vz);
    p2 = (1.0 - s) * std::sqrt(std::max(0.0, 1.0 - p1 * p1)) + s * p2;
    double pz = std::sqrt(std::max(0.0, 1.0 - p1 * p1 - p2 * p2));
    double nx = p1 * t1x + p2 * t2x + pz * vx;
    double ny = p1 * t1y + p2 * t2y + pz * vy;
    double nz = p2 * t2z + pz * vz;
    return normalized_f(au * nx, av * ny, std::max(0.0, nz));
}

namespace {
/// Heitz & d'Eon 2014 visible-slope sampling for the unit-roughness isotropic Beckmann
/// distribution seen from elevation theta (cos_t, sin_t). The x-slope has the CDF
///   C(x) = (1 + erf(x) + tan(t)/sqrt(pi) exp(-x^2)) / (1 + erf(cot t) + tan(t)/sqrt(pi) exp(-cot^2 t))
/// on (-inf, cot t], inverted by safeguarded Newton in double precision to |C − u| < 1e-13
/// (initial guess: pbrt-v3's fit in the erf domain); the y-slope is an independent
/// normal of variance 1/2: erfinv(2 u2 − 1), one Newton step from Giles' guess (erfinv_newton).
void beckmann_sample11(double cos_t, double sin_t, double u1, double u2, double &sx, double &sy) {
    u1 = clamp(u1, 1e-12, 1.0 - 1e-12);
    u2 = clamp(u2, 1e-12, 1.0 - 1e-12);
    double tan_t = sin_t / cos_t;
    double cot_t = cos_t / sin_t;  // +inf at normal incidence: handled by the erf/exp limits
    double c = std::erf(cot_t);
    double theta = std::atan2(sin_t, cos_t);
    double fit = 1.0 + theta * (-0.876 + theta * (0.4265 - 0.0594 * theta));
    double b0 = c - (1.0 + c) * std::pow(1.0 - u1, fit);
    double tail_c = (sin_t > 0.0) ? tan_t / kSqrtPi * std::exp(-cot_t * cot_t) : 0.0;
    double norm = 1.0 / (1.0 + c + tail_c);
    double lo = -30.0, hi = std::min(cot_t, 30.0);
    // The guess only starts the safeguarded Newton below: Giles' approximation without refinement.
    double x = clamp(erfinv_guess(clamp(b0, -1.0 + 1e-15, 1.0 - 1e-15)), lo, hi);
    for (int it = 0; it < 100; ++it) {
        double e = std::exp(-x * x);
        // 1 + erf(x) = erfc(-x): keeps precision in the left tail (u1 -> 0)
        double value = norm * (std::erfc(-x) + (sin_t > 0.0 ? tan_t / kSqrtPi * e : 0.0)) - u1;
        if (std::abs(value) < 1e-13) break;
        if (value > 0.0) hi = x;
        else lo = x;
        double deriv = norm * (2.0 / kSqrtPi) * e * (1.0 - x * tan_t);
        double xn = deriv > 0.0 ? x - value / deriv : 0.5 * (lo + hi);
        if (!(xn > lo && xn < hi)) xn = 0.5 * (lo + hi);
        if (xn == x || hi - lo < 1e-15) break;
        x = xn;
    }
    sx = x;
    sy = erfinv_newton(2.0 * u2 - 1.0, 1);
}
}  // namespace

Vec3 MicrofacetDistribution::sample_visible_beckmann(const Vec3 &wo, Vec2 u) const {
    double au = m_alpha_u, av = m_alpha_v;
    D3 v = d3(wo);
    // 1. stretch to the unit-roughness configuration
    double sx_ = au * v.x, sy_ = av * v.y, sz_ = v.z;
    double l = std::sqrt(sx_ * sx_ + sy_ * sy_ + sz_ * sz_);
    sx_ /= l, sy_ /= l, sz_ /= l;
    double sin_t = std::sqrt(sx_ * sx_ + sy_ * sy_), cos_t = sz_;
    // 2. sample slopes for the isotropic unit distribution
    double slope_x, slope_y;
    beckmann_sample11(cos_t, sin_t, u.x, u.y, slope_x, slope_y);
    // 3. rotate into the azimuth of the stretched direction
    double cp = sin_t > 0.0 ? sx_ / sin_t : 1.0, sp = sin_t > 0.0 ? sy_ / sin_t : 0.0;
    double tmp = cp * slope_x - sp * slope_y;
    slope_y = sp * slope_x + cp * slope_y;
    slope_x = tmp;
    // 4. unstretch and convert slopes to a normal
    slope_x *= au;
    slope_y *= av;
    if (!std::isfinite(slope_x) || !std::isfinite(slope_y)) return Vec3(0.f, 0.f, 0.f);
    return normalized_f(-slope_x, -slope_y, 1.0);
}

std::string MicrofacetDistribution::to_string() const {
    return fmt::format("{}(alpha_u={}, alpha_v={}, {})", m_type == MicrofacetType::GGX ? "ggx" : "beckmann",
                       m_alpha_u, m_alpha_v, m_sample_visible ? "visible normals" : "full NDF");
}

std::optional<MicrofacetDistribution> microfacet_from_properties(const Properties &p, bool allow_anisotropic,
                                                                 float default_alpha) {
    const MicrofacetType type =
        p.get_enum<MicrofacetType>("distribution", "ggx", {{"ggx", MicrofacetType::GGX}, {"beckmann", MicrofacetType::Beckmann}});
    bool visible = p.get_bool("sample_visible", true);
    float au = default_alpha, av = default_alpha;
    bool has_u = p.has("alpha_u"), has_v = p.has("alpha_v");
    if (has_u || has_v) {
        if (!allow_anisotropic) p.fail(has_u ? "alpha_u" : "alpha_v", "this material is isotropic: use \"alpha\"");
        if (p.has("alpha")) p.fail("alpha", "give either \"alpha\" or \"alpha_u\"/\"alpha_v\", not both");
        if (!has_u) p.fail("alpha_v", "\"alpha_v\" needs \"alpha_u\" as well");
        if (!has_v) p.fail("alpha_u", "\"alpha_u\" needs \"alpha_v\" as well");
        au = p.get_float("alpha_u");
        av = p.get_float("alpha_v");
        if (au < 0.f) p.fail("alpha_u", fmt::format("roughness must be >= 0, got {}", au));
        if (av < 0.f) p.fail("alpha_v", fmt::format("roughness must be >= 0, got {}", av));
    } else {
        au = av = p.get_float("alpha", default_alpha);
        if (au < 0.f) p.fail("alpha", fmt::format("roughness must be >= 0, got {}", au));
    }
    const float kMaxAlpha = 1e3f;
    if (au > kMaxAlpha || av > kMaxAlpha)
        p.fail(has_u ? "alpha_u" : "alpha", fmt::format("roughness must be <= {}", kMaxAlpha));
    if (std::max(au, av) < MicrofacetDistribution::kMinAlpha) return std::nullopt;
    return MicrofacetDistribution(type, au, av, visible);
}

// ---------------------------------------------------------------- Blinn-Phong Smith Λ

namespace {
struct GaussLegendre32 {
    double x[32], w[32];  // nodes and weights on [0, 1]
    GaussLegendre32() {
        const int n = 32;
        for (int i = 0; i < n; ++i) {
            double z = std::cos(kPi * (i + 0.75) / (n + 0.5)), pp = 0.0;
            for (int it = 0; it < 100; ++it) {
                double p1 = 1.0, p2 = 0.0;
                for (int j = 1; j <= n; ++j) {
                    double p3 = p2;
                    p2 = p1;
                    p1 = ((2.0 * j - 1.0) * z * p2 - (j - 1.0) * p3) / j;
                }
                pp = n * (z * p1 - p2) / (z * z - 1.0);
                double dz = p1 / pp;
                z -= dz;
                if (std::abs(dz) < 1e-15) break;
            }
            x[i] = 0.5 * (1.0 - z);
            w[i] = 1.0 / ((1.0 - z * z) * pp * pp);  // = (2/((1-z²)P'²)) / 2 on [0, 1]
        }
    }
};
const GaussLegendre32 &gauss_legendre32() {
    static const GaussLegendre32 gl;
    return gl;
}
}  // namespace

double blinnphong_lambda(double s, double cos_theta) {
    double mu = std::abs(cos_theta);
    if (!(mu < 1.0)) return 0.0;
    if (!(mu > 0.0)) return INFINITY;
    s = std::max(s, 0.0);
    double sin_o = std::sqrt(std::max(0.0, 1.0 - mu * mu));
    double th_c = 0.5 * kPi - std::acos(mu);  // back-facing microfacets have θm > th_c
    double alpha = std::sqrt(2.0 / (s + 2.0));
    double th_hi = std::min(0.5 * kPi, 8.0 * alpha);
    if (th_c >= th_hi) return 0.0;
    double L = th_hi - th_c, norm = (s + 2.0) / (2.0 * kPi), sum = 0.0;
    const GaussLegendre32 &gl = gauss_legendre32();
    for (int k = 0; k < 32; ++k) {
        double t = gl.x[k], th = th_c + L * t * t;
        double st = std::sin(th), ct = std::cos(th);
        double a = sin_o * st, b = mu * ct;
        if (!(a > b)) continue;
        double h = 2.0 * (std::sqrt(a * a - b * b) - b * std::acos(b / a));
        double D = s == 0.0 ? norm : (ct > 0.0 ? norm * std::exp(s * std::log(ct)) : 0.0);
        sum += gl.w[k] * D * st * h * 2.0 * L * t;
    }
    return std::max(sum, 0.0) / mu;
}

namespace {
constexpr int kLambdaTableSize = 512;
}

BlinnPhongLambdaTable::BlinnPhongLambdaTable(double s) : m_alpha(std::sqrt(2.0 / (std::max(s, 0.0) + 2.0))) {
    m_y.resize(kLambdaTableSize);
    for (int i = 0; i < kLambdaTableSize; ++i) {
        double x = double(i) / (kLambdaTableSize - 1);
        if (i == kLambdaTableSize - 1) {
            m_y[i] = 0.0;  // a = ∞: normal incidence, Λ = 0
            continue;
        }
        double a = std::max(x / (1.0 - x), 1e-9);  // a = 0 (grazing): the finite limit of Λ·a
        double cot = a * m_alpha, mu = cot / std::sqrt(1.0 + cot * cot);
        m_y[i] = blinnphong_lambda(s, mu) * a;
    }
}

double BlinnPhongLambdaTable::operator()(double cos_theta) const {
    double mu = std::abs(cos_theta);
    if (!(mu < 1.0)) return 0.0;
    if (!(mu > 0.0)) return INFINITY;
    double a = mu / (m_alpha * std::sqrt(std::max(0.0, 1.0 - mu * mu)));
    double x = a / (1.0 + a) * (kLambdaTableSize - 1);
    int i = std::min(int(x), kLambdaTableSize - 2);
    double f = x - i;
    double y = (1.0 - f) * m_y[i] + f * m_y[i + 1];
    return std::max(y, 0.0) / a;
}

bool sample_glossy_or_diffuse(const MicrofacetDistribution &dist, const Vec3 &wo, float u_lobe, float p_glossy,
                              Vec2 u, Vec3 &wi, uint32_t &flags) {
    if (u_lobe < p_glossy) {
        float pm;
        Vec3 m = dist.sample(wo, u, &pm);
        if (!(pm > 0.f) || !(dot(wo, m) > 0.f)) return false;
        wi = normalize(reflect(wo, m));
        flags = BSDF_GlossyReflection;
    } else {
        wi = square_to_cosine_hemisphere(u);
        flags = BSDF_DiffuseReflection;
    }
    return wi.z > 0.f;
}

}  // namespace meso
