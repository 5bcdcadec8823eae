#include "render/leadr_quadrature.h"
#include "render/transfer_filter.h"
#include <algorithm>
#include <cmath>
#include <mutex>
#include "lights/envmap.h"
#include "render/light.h"

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

double leadr_diffuse_slope_integral(const GaussianSlopes &g, int n, const Vec3 &wo, const Vec3 &wi) {
    const double ox = wo.x, oy = wo.y, oz = wo.z, ix = wi.x, iy = wi.y, iz = wi.z;
    double sum = 0;
    for_each_leadr_slope(g.params(), n, [&](double x, double y, double W) {
        const double a = oz - x * ox - y * oy, b = iz - x * ix - y * iy;
        if (a > 0.0 && b > 0.0) sum += W * a * b / std::sqrt(1.0 + x * x + y * y);
    });
    return std::isfinite(sum) ? sum : 0.0;
}

LeadrDiffuseGrid::LeadrDiffuseGrid(const GaussianSlopes &g, int n) {
    m_pts.reserve(size_t(n) * n);
    for_each_leadr_slope(g.params(), n, [&](double x, double y, double W) {
        m_pts.push_back({x, y, W / std::sqrt(1.0 + x * x + y * y)});
    });
}

double LeadrDiffuseGrid::integral(const Vec3 &wo, const Vec3 &wi) const {
    const double ox = wo.x, oy = wo.y, oz = wo.z, ix = wi.x, iy = wi.y, iz = wi.z;
    double sum = 0;
    for (const auto &p : m_pts) {
        const double a = oz - p[0] * ox - p[1] * oy, b = iz - p[0] * ix - p[1] * iy;
        if (a > 0.0 && b > 0.0) sum += p[2] * a * b;
    }
    return std::isfinite(sum) ? sum : 0.0;
}

// ------------------------------------------------------------------ spherical harmonics

void sh9_add(std::array<Spectrum, 9> &c, const Vec3 &d, const Spectrum &P) {
    const float x = d.x, y = d.y, z = d.z;
    c[0] += P * 0.282095f;
    c[1] += P * (0.488603f * y);
    c[2] += P * (0.488603f * z);
    c[3] += P * (0.488603f * x);
    c[4] += P * (1.092548f * x * y);
    c[5] += P * (1.092548f * y * z);
    c[6] += P * (0.315392f * (3.f * z * z - 1.f));
    c[7] += P * (1.092548f * x * z);
    c[8] += P * (0.546274f * (x * x - y * y));
}

Spectrum sh9_irradiance(const std::array<Spectrum, 9> &c, const Vec3 &n) {
    const float x = n.x, y = n.y, z = n.z;
    return c[8] * (0.429043f * (x * x - y * y)) + c[6] * (0.743125f * z * z) + c[0] * 0.886227f -
           c[6] * 0.247708f + (c[4] * (x * y) + c[7] * (x * z) + c[5] * (y * z)) * 0.858086f +
           (c[3] * x + c[1] * y + c[2] * z) * 1.023328f;
}

// ------------------------------------------------------------------ prefiltered environment

PrefilteredEnvironment::PrefilteredEnvironment(int w, int h, const std::vector<Spectrum> &texels,
                                               const Transform &to_world)
    : m_w(w), m_h(h), m_to_world(to_world), m_identity(to_world.is_identity()) {
    std::vector<float> data(size_t(w) * h * 3);
    for (size_t i = 0; i < size_t(w) * h; ++i)
        for (int c = 0; c < 3; ++c) data[i * 3 + c] = texels[i][c];
    m_mip = MipMap(w, h, 3, std::move(data), WrapMode::Repeat);

    // Algorithm 2's L_lm(environment): every level-0 texel, world frame.
    auto world_dir = [&](float u, float v) {
        Vec3 d = EnvMapLight::uv_to_direction(Vec2(u, v));
        return m_identity ? d : normalize(m_to_world.apply_vector(d));
    };
    for (int y = 0; y < h; ++y) {
        const double sa = (2 * kPi / w) * (std::cos(kPi * y / h) - std::cos(kPi * (y + 1) / h));
        for (int x = 0; x < w; ++x)
            sh9_add(m_sh, world_dir((x + 0.5f) / w, (y + 0.5f) / h), texels[size_t(y) * w + x] * float(sa));
    }
    // The coarse level for per-point projection: the first with at most 16 rows.
    int lc = 0;
    while (lc + 1 < m_mip.levels() && m_mip.height(lc) > 16) ++lc;
    const int cw = m_mip.width(lc), ch = m_mip.height(lc);
    m_coarse.reserve(size_t(cw) * ch);
    for (int y = 0; y < ch; ++y) {
        const double sa = (2 * kPi / cw) * (std::cos(kPi * y / ch) - std::cos(kPi * (y + 1) / ch));
        for (int x = 0; x < cw; ++x) {
            const float *t = m_mip.texel(lc, x, y);
            m_coarse.push_back({world_dir((x + 0.5f) / cw, (y + 0.5f) / ch), float(sa), Spectrum(t[0], t[1], t[2])});
        }
    }
}

std::shared_ptr<PrefilteredEnvironment> PrefilteredEnvironment::from_light(const Light &light, int res) {
    if (auto *env = dynamic_cast<const EnvMapLight *>(&light))
        return std::make_shared<PrefilteredEnvironment>(env->width(), env->height(), env->texels(), env->to_world());
    res = std::max(res, 2);
    const int w = res, h = std::max(1, res / 2);
    std::vector<Spectrum> texels(size_t(w) * h);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            Vec3 d = EnvMapLight::uv_to_direction(Vec2((x + 0.5f) / w, (y + 0.5f) / h));
            texels[size_t(y) * w + x] = light.eval(LightHit{}, -d);  // radiance arriving from d
        }
    return std::make_shared<PrefilteredEnvironment>(w, h, texels, Transform());
}

Vec3 PrefilteredEnvironment::to_local(const Vec3 &d) const {
    return normalize(m_identity ? d : m_to_world.apply_inverse_vector(d));
}

Spectrum PrefilteredEnvironment::bilinear(int level, float u, float v) const {
    const float hl = float(m_mip.height(level));
    v = std::clamp(v, 0.5f / hl, 1.f - 0.5f / hl);  // no blending across the poles
    float out[3];
    m_mip.bilinear(level, u, v, out);
    return Spectrum(out[0], out[1], out[2]);
}

Spectrum PrefilteredEnvironment::radiance(const Vec3 &d_world) const {
    Vec2 uv = EnvMapLight::direction_to_uv(to_local(d_world));
    return bilinear(0, uv.x, uv.y);
}

float PrefilteredEnvironment::level_for(const Vec3 &d_world, double solid_angle) const {
    return level_local(to_local(d_world), solid_angle);
}

float PrefilteredEnvironment::level_local(const Vec3 &d, double solid_angle) const {
    const double sin_theta = std::max(std::sqrt(std::max(0.0, 1.0 - double(d.y) * d.y)), std::sin(kPi / (2 * m_h)));
    const double texel = (2 * kPi / m_w) * (kPi / m_h) * sin_theta;
    if (!(solid_angle > texel)) return 0.f;
    const double level = 0.5 * std::log2(solid_angle / texel);
    return float(std::min(level, double(m_mip.levels() - 1)));
}

Spectrum PrefilteredEnvironment::lookup(const Vec3 &d_world, double solid_angle) const {
    const Vec3 d = to_local(d_world);
    const Vec2 uv = EnvMapLight::direction_to_uv(d);
    const float level = level_local(d, solid_angle);
    const int l0 = int(level);
    const float t = level - float(l0);
    if (l0 + 1 >= m_mip.levels() || t <= 0.f) return bilinear(l0, uv.x, uv.y);
    return bilinear(l0, uv.x, uv.y) * (1.f - t) + bilinear(l0 + 1, uv.x, uv.y) * t;
}

size_t PrefilteredEnvironment::memory_bytes() const {
    return m_mip.memory_bytes() + m_coarse.size() * sizeof(Texel);
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
