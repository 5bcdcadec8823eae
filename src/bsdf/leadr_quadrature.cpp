#include "bsdf/leadr_quadrature.h"
#include "filter/transfer_filter.h"
#include <algorithm>
#include <cmath>
#include <mutex>

namespace meso {

namespace {
constexpr double kPi = 3.14159265358979323846;
}

double leadr_grid_lambda(int n) {
    if (n <= 1) return 1.0;
    return std::min(5.0, 0.4 + 1.2 * std::log(double(n)));
}

const LeadrGrid1D &leadr_grid_1d(int n) {
    static std::array<LeadrGrid1D, kLeadrMaxGrid + 1> grids;
    static std::once_flag once;
    std::call_once(once, [] {
        for (int m = 1; m <= kLeadrMaxGrid; ++m) {
            LeadrGrid1D &G = grids[m];
            G.n = m;
            G.lambda = leadr_grid_lambda(m);
            double sum = 0;
            for (int j = 0; j < m; ++j) {
                G.p[j] = m == 1 ? 0.0 : -G.lambda + 2.0 * G.lambda * j / (m - 1);
                G.w[j] = std::exp(-0.5 * G.p[j] * G.p[j]);
                sum += G.w[j];
            }
            for (int j = 0; j < m; ++j) G.w[j] /= sum;
        }
    });
    return grids[std::clamp(n, 1, kLeadrMaxGrid)];
}

double leadr_diffuse_slope_integral(const GaussianSlopes &g, int n, const Vec3 &wo, const Vec3 &wi,
                                    double *visible_area) {
    const double ox = wo.x, oy = wo.y, oz = wo.z, ix = wi.x, iy = wi.y, iz = wi.z;
    double sum = 0, area = 0;
    for_each_leadr_slope(g.params(), n, [&](double x, double y, double W) {
        const double a = oz - x * ox - y * oy, b = iz - x * ix - y * iy;
        if (a > 0.0) area += W * a;
        if (a > 0.0 && b > 0.0) sum += W * a * b / std::sqrt(1.0 + x * x + y * y);
    });
    if (visible_area) *visible_area = area;
    return std::isfinite(sum) ? sum : 0.0;
}

LeadrDiffuseGrid::LeadrDiffuseGrid(const GaussianSlopes &g, int n) {
    m_pts.reserve(size_t(n) * n);
    for_each_leadr_slope(g.params(), n, [&](double x, double y, double W) {
        m_pts.push_back({x, y, W / std::sqrt(1.0 + x * x + y * y), W});
    });
}

double LeadrDiffuseGrid::integral(const Vec3 &wo, const Vec3 &wi, double *visible_area) const {
    const double ox = wo.x, oy = wo.y, oz = wo.z, ix = wi.x, iy = wi.y, iz = wi.z;
    double sum = 0, area = 0;
    for (const auto &p : m_pts) {
        const double a = oz - p[0] * ox - p[1] * oy, b = iz - p[0] * ix - p[1] * iy;
        if (a > 0.0) area += p[3] * a;
        if (a > 0.0 && b > 0.0) sum += p[2] * a * b;
    }
    if (visible_area) *visible_area = area;
    return std::isfinite(sum) ? sum : 0.0;
}


// ------------------------------------------------------------------ Algorithms 1-3

namespace {
/// (n . wo) / (n . w_g) and Lambda(wo); false when wo is masked by the mesosurface.
bool view_terms(const GaussianSlopes &g, const Vec3 &wo, bool rational, double &area, double &lo) {
    if (!(wo.z > 0.f)) return false;
    const Vec3 nbar = g.mesonormal();
    area = dot(nbar, wo) / double(nbar.z);
    if (!(area > 0.0)) return false;
    lo = g.lambda(wo, rational);
    return std::isfinite(lo);
}
}  // namespace

Spectrum leadr_env_specular(const GaussianSlopes &g, const Vec3 &wo, const Frame &frame,
                            const std::function<Spectrum(float)> &fresnel, const PrefilteredEnvironment &env,
                            const LeadrEnvOptions &opt) {
    double area, lo;
    if (!view_terms(g, wo, opt.rational_lambda, area, lo)) return Spectrum(0.f);
    const SlopeGaussian &p = g.params();
    const int n = std::clamp(opt.n, 1, kLeadrMaxGrid);
    const double A = sqr(2.0 * leadr_grid_lambda(n) * std::sqrt(std::max(p.sxx, p.syy)) / n);
    double sum[3] = {0, 0, 0};
    for_each_leadr_slope(p, n, [&](double x, double y, double W) {
        const Vec3 m = leadr_slope_normal(x, y);
        const double dmo = dot(m, wo);
        if (!(dmo > 0.0)) return;
        const Vec3 wi = normalize(m * float(2.0 * dmo) - wo);  // eq. (18)
        if (!(wi.z > 0.f)) return;                              // below the macrosurface: 0 (as eval)
        const double G = leadr_shadowing(lo, g.lambda(wi, opt.rational_lambda), opt.shadowing);
        if (!(G > 0.0)) return;
        const double mz = m.z;
        const double alpha = 4.0 * dmo * mz * mz * mz * A;  // J A
        const Vec3 dw = frame.to_world(wi);
        const Spectrum L = opt.prefilter ? env.lookup(dw, alpha) : env.radiance(dw);
        const Spectrum F = fresnel(float(dmo));
        const double k = W * dmo / mz * G;
        for (int c = 0; c < 3; ++c) sum[c] += double(F[c]) * L[c] * k;
    });
    const Spectrum out(float(sum[0] / area), float(sum[1] / area), float(sum[2] / area));
    return out.is_finite() ? out : Spectrum(0.f);
}

Spectrum leadr_env_diffuse(const GaussianSlopes &g, const Vec3 &wo, const Frame &frame, const Spectrum &rho,
                           const PrefilteredEnvironment &env, const LeadrEnvOptions &opt) {
    double area, lo;
    if (!view_terms(g, wo, opt.rational_lambda, area, lo)) return Spectrum(0.f);
    if (opt.irradiance == LeadrIrradiance::Gaussian) {  // paper 001 §5.3
        const SlopeGaussian d = visible_slope_gaussian(g.params(), wo);
        double e[3];
        gaussian_expectation_2d(d, std::clamp(opt.n, 1, 64), 3, [&](double sx, double sy, double *o) {
            const Spectrum E = sh9_irradiance(env.sh(), frame.to_world(slope_to_normal(sx, sy)));
            for (int ch = 0; ch < 3; ++ch) o[ch] = std::max(0.0, double(E[ch]));
        }, e);
        const Spectrum out = rho * Spectrum(float(e[0] / kPi), float(e[1] / kPi), float(e[2] / kPi));
        return out.is_finite() ? out : Spectrum(0.f);
    }
    // Algorithm 2: the coefficients of L(w_i) E[V V] (eq. 20).
    std::array<Spectrum, 9> c{};
    const bool local = opt.irradiance == LeadrIrradiance::Shadowed;
    if (local) {
        for (const PrefilteredEnvironment::Texel &t : env.coarse_texels()) {
            const Vec3 d = frame.to_local(t.d);
            if (!(d.z > 0.f)) continue;
            const double G = leadr_shadowing(lo, g.lambda(d, opt.rational_lambda), opt.shadowing);
            if (G > 0.0) sh9_add(c, d, t.L * float(t.solid_angle * G));
        }
    } else {
        const float k = float(1.0 / (1.0 + lo));
        for (int i = 0; i < 9; ++i) c[i] = env.sh()[i] * k;
    }
    // Algorithm 3 / eq. (23).
    double sum[3] = {0, 0, 0};
    for_each_leadr_slope(g.params(), std::clamp(opt.n, 1, kLeadrMaxGrid), [&](double x, double y, double W) {
        const Vec3 m = leadr_slope_normal(x, y);
        const double dmo = dot(m, wo);
        if (!(dmo > 0.0)) return;
        const Spectrum E = sh9_irradiance(c, local ? m : frame.to_world(m));
        const double k = W * dmo / double(m.z);
        for (int ch = 0; ch < 3; ++ch) sum[ch] += std::max(0.0, double(E[ch])) * k;
    });
    const double s = 1.0 / (kPi * area);
    const Spectrum out = rho * Spectrum(float(sum[0] * s), float(sum[1] * s), float(sum[2] * s));
    return out.is_finite() ? out : Spectrum(0.f);
}

}  // namespace meso
