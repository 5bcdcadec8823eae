#include "geometry/lod.h"
#include <algorithm>
#include <cmath>
#include <fmt/format.h>
#include "core/error.h"
#include "geometry/interaction.h"

namespace meso {

float footprint_texels(float dudx, float dudy, float dvdx, float dvdy, double width, double height) {
    const double ax = std::hypot(double(dudx) * width, double(dvdx) * height);
    const double ay = std::hypot(double(dudy) * width, double(dvdy) * height);
    const double w = std::max(ax, ay);
    if (!(w >= 0.0) || !std::isfinite(w)) return 0.f;
    return float(std::min(w, 3.0e38));
}

LodChain::LodChain(std::vector<float> factors, const std::string &where) : m_factors(std::move(factors)) {
    auto fail = [&](const std::string &msg) {
        throw MesoError(where.empty() ? msg : where + ": " + msg);
    };
    if (m_factors.empty()) fail("a LoD chain needs at least one level");
    for (size_t i = 0; i < m_factors.size(); ++i) {
        float f = m_factors[i];
        if (!std::isfinite(f) || f < 1.f)
            fail(fmt::format("level {}: expected a downsampling factor >= 1, got {}", i, f));
        if (i > 0 && !(f > m_factors[i - 1]))
            fail(fmt::format("level {}: factors must increase strictly (got {} after {})", i, f, m_factors[i - 1]));
    }
    m_log.resize(m_factors.size());
    for (size_t i = 0; i < m_factors.size(); ++i) m_log[i] = std::log(m_factors[i]);
}

LodSelection LodChain::select(float texels, float bias) const {
    LodSelection s;
    const double w = double(texels) * double(bias);
    const int n = levels();
    if (!(w > double(m_factors[0])) || n == 1) return s;  // also NaN / zero footprints
    if (w >= double(m_factors[size_t(n - 1)])) {
        s.lo = s.hi = n - 1;
        return s;
    }
    const double lw = std::log(w);
    int i = int(std::upper_bound(m_factors.begin(), m_factors.end(), float(w)) - m_factors.begin()) - 1;
    i = std::clamp(i, 0, n - 2);
    s.lo = i;
    s.hi = i + 1;
    // The transition to `hi` spans at most the octave below its factor (see lod.h).
    const double span = std::min(double(m_log[size_t(i + 1)]) - m_log[size_t(i)], std::log(2.0));
    s.t = float(std::clamp((lw - m_log[size_t(i + 1)]) / span + 1.0, 0.0, 1.0));
    if (s.t == 0.f) s.hi = s.lo;
    return s;
}

int LodChain::choose(float texels, float u, float bias) const {
    LodSelection s = select(texels, bias);
    return u < s.t ? s.hi : s.lo;
}

float LodChain::position(float texels, float bias) const {
    LodSelection s = select(texels, bias);
    return float(s.lo) + (s.hi != s.lo ? s.t : 0.f);
}

namespace {

using Windows = std::vector<std::vector<float>>;

/// E(r) of lod.h: the error over windows of r x r cells (r >= 1) from the measured 1, 2, 4, ...
double window_error_at(const std::vector<float> &E, double r) {
    if (E.empty()) return 0.0;
    const double j = std::log2(std::max(1.0, r));
    const size_t last = E.size() - 1;
    if (j >= double(last)) {
        const double beyond = std::exp2(double(last)) / r;
        return double(E[last]) * beyond * beyond;
    }
    const size_t i = size_t(j);
    const double t = j - double(i);
    return double(E[i]) * (1.0 - t) + double(E[i + 1]) * t;
}

/// J_k of lod.h's expected-MSE rule for level k at pixel footprint w (bias applied).
double mse_change(const LodChain &c, const Windows &E, const std::vector<float> &V, int k, double w, double n) {
    if (k == 0) return 0.0;
    const double r = w / double(c.factor(k)), v = V[size_t(k)];
    if (r >= 1.0) return window_error_at(E[size_t(k)], r) - v / n;
    // The detail lost above the pixel scale is the original's (V when the level removes any).
    return window_error_at(E[size_t(k)], 1.0) + std::max(v, 0.0) * (1.0 - r * r) - v * r * r / n;
}

int best_level(const LodChain &c, const Windows &E, const std::vector<float> &V, double w, double n) {
    int best = 0;
    double jb = 0.0;
    for (int k = 1; k < c.levels(); ++k) {
        const double j = mse_change(c, E, V, k, w, n);
        if (j < jb) best = k, jb = j;
    }
    return best;
}

}  // namespace

LodSelection select_mse_level(const LodChain &chain, const std::vector<std::vector<float>> &patch_error,
                              const std::vector<float> &removed_variance, float pixel_texels, float spp, float bias) {
    LodSelection s;
    const int n = chain.levels();
    if (int(patch_error.size()) != n || int(removed_variance.size()) != n) return chain.select(pixel_texels, bias);
    const double w = double(pixel_texels) * double(bias);
    const double ns = std::max(1.0, double(spp));
    if (!(w > 0.0) || !std::isfinite(w) || n == 1) return s;  // no footprint: the original
    // The octave [w / sqrt 2, w sqrt 2]: the finer level at its lower end, the coarser at its
    // upper end, and the switch between them by bisection in log w.
    const double lo_w = w * std::sqrt(0.5), hi_w = w * std::sqrt(2.0);
    const int a = best_level(chain, patch_error, removed_variance, lo_w, ns);
    const int b = best_level(chain, patch_error, removed_variance, hi_w, ns);
    s.lo = std::min(a, b);
    s.hi = std::max(a, b);
    if (s.lo == s.hi) return s;
    double l0 = std::log(lo_w), l1 = std::log(hi_w);
    for (int it = 0; it < 16; ++it) {
        const double m = 0.5 * (l0 + l1);
        (best_level(chain, patch_error, removed_variance, std::exp(m), ns) == a ? l0 : l1) = m;
    }
    const double frac_b = (std::log(hi_w) - 0.5 * (l0 + l1)) / std::log(2.0);  // where b is best
    s.t = float(std::clamp(b == s.hi ? frac_b : 1.0 - frac_b, 0.0, 1.0));
    return s;
}

double metric_distortion(const Vec3 &dpdu, const Vec3 &dpdv, double texel_w, double texel_h, double model_texel) {
    if (!(model_texel > 0.0)) return 1.0;
    // Columns a, b: world length of one model texel's step along u and v, in units of the
    // model's texel c0. G = [a b]^T [a b]; lambda² its eigenvalues.
    const double su = 1.0 / (texel_w * model_texel), sv = 1.0 / (texel_h * model_texel);
    const double a[3] = {dpdu.x * su, dpdu.y * su, dpdu.z * su}, b[3] = {dpdv.x * sv, dpdv.y * sv, dpdv.z * sv};
    const double g11 = a[0] * a[0] + a[1] * a[1] + a[2] * a[2], g22 = b[0] * b[0] + b[1] * b[1] + b[2] * b[2];
    const double g12 = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    // det G = |a x b|², exact for nearly parallel tangents (g11 g22 - g12² would cancel).
    const double c0 = a[1] * b[2] - a[2] * b[1], c1 = a[2] * b[0] - a[0] * b[2], c2 = a[0] * b[1] - a[1] * b[0];
    const double det = c0 * c0 + c1 * c1 + c2 * c2;
    const double l1 = 0.5 * (g11 + g22 + std::sqrt((g11 - g22) * (g11 - g22) + 4.0 * g12 * g12));
    const double l2 = det / l1;  // the smaller eigenvalue, without cancellation
    if (!(l2 > 0.0) || !std::isfinite(l1) || !std::isfinite(l2)) return INFINITY;
    const double d = std::sqrt(std::max(l1, 1.0 / l2));
    return std::isfinite(d) ? d : INFINITY;
}

double metric_footprint(const LodChain &chain, double texels, double distortion, double bias) {
    constexpr double sqrt2 = 1.4142135623730951;
    if (!(distortion > sqrt2) || chain.levels() < 2) return texels;  // also D = NaN (not produced)
    // The rule takes the original alone below half the first factor (lod.h), bias applied.
    const double floor_w = 0.5 * double(chain.factor(1)) / (bias > 0.0 && std::isfinite(bias) ? bias : 1.0);
    if (!(texels > floor_w)) return texels;
    if (!(distortion < 2.0) || !std::isfinite(texels)) return floor_w;
    const double q = 2.0 * std::log2(distortion) - 1.0;  // 0 at sqrt 2, 1 at 2
    return std::exp((1.0 - q) * std::log(texels) + q * std::log(floor_w));
}

LodSelection select_path_level(const LodGroup &g, float dudx, float dudy, float dvdx, float dvdy,
                               float footprint_scale, int spp, double distortion) {
    const float w = footprint_texels(dudx, dudy, dvdx, dvdy, g.texel_w, g.texel_h);
    // The metric check moves the footprint each rule compares with the factors.
    auto checked = [&](float texels) { return float(metric_footprint(g.chain, texels, distortion, g.bias)); };
    if (g.window_error.empty()) return g.chain.select(checked(w), g.bias);
    const float scale = footprint_scale > 0.f && std::isfinite(footprint_scale) ? footprint_scale : 1.f;
    const float n = spp > 0 ? float(spp) : 1.f / (scale * scale);
    return select_mse_level(g.chain, g.window_error, g.removed_variance, checked(w / scale), n, g.bias);
}

LodSelection select_path_level(const LodGroup &g, const SurfaceInteraction &si, float footprint_scale, int spp) {
    double d = 1.0;
    if (g.model_texel > 0.0) {
        const bool micro = length_squared(si.n_footprint) > 0.f;
        d = metric_distortion(micro ? si.dpdu_footprint : si.dpdu, micro ? si.dpdv_footprint : si.dpdv, g.texel_w,
                              g.texel_h, g.model_texel);
    }
    return select_path_level(g, si.dudx, si.dudy, si.dvdx, si.dvdy, footprint_scale, spp, d);
}

}  // namespace meso
