// `colormap` texture: a colour map C (a piecewise-linear Ramp) applied to a grey driving
// function f, filtered over the ray-differential footprint (paper 001, Heitz et al. 2014, §4).
//
// Model. The footprint average of C(f) is the inner product <C, D_f> with the distribution D_f
// of f over the footprint (eq. 6-7). "gaussian" approximates D_f by N(f_bar, sigma_f^2) and reads
// <C, N(f_bar, sigma_f^2)> = [C * N(0, sigma_f^2)](f_bar) from the paper's preconvolved 2D table
// indexed by (f_bar, sigma_f) (eq. 9; filter/transfer_filter.h, PreconvolvedTable::of_ramp).
// The statistics of the two drivers:
//
//   image  f = offset + scale * (channel average of the texel). A 2-channel MIP pyramid holds
//          (f - c, (f - c)^2), c = the image mean of f (centring keeps the float difference
//          E[f^2] - E[f]^2 accurate); both moments are read with the same footprint filter
//          (MipMap trilinear or EWA) and sigma_f^2 = max(0, E[(f-c)^2] - E[f-c]^2) (§4.2, "the
//          first two moments at each level of detail"). In magnification (footprint width w < 1
//          level-0 texel, w = the larger axis as in MipMap::level_for_footprint) the pyramid's
//          variance is that of the bilinear blend of the texels around the point, not of the
//          smooth bilinear reconstruction inside the footprint; it is faded by w^2 (a linear f
//          varies by that order over a width-w window), so a zero footprint gives C(f(point)).
//
//   noise  a random-phase sum of K cosines (a Gaussian process for large K)
//              f(x) = mean + sum_k a_k cos(2 pi k_k . x + phi_k),   x = uv,
//          |k_k| log-uniform in [freq_min, freq_max] (cycles per unit uv), direction uniform,
//          phi_k uniform, a_k proportional to |k_k|^-beta, normalised so that
//          Var f = sum_k a_k^2 / 2 = sigma^2 exactly. Deterministic for a seed (PCG32).
//          Footprint window: the Gaussian w(d) = N(d; 0, S) in uv with S = J J^T / 4, where J has
//          the columns (dudx, dvdx) and (dudy, dvdy). This is the scale convention of
//          texture/mipmap.h: EWA's weight exp(-2 r^2) on the ellipse with semi-axes J is a
//          Gaussian of covariance J J^T / 4, and a trilinear lookup at level log2(w) (box of the
//          level's texel of width w convolved with the bilinear tent) has variance w^2/12 +
//          w^2/6 = w^2/4 per axis. Noise key "window": "box" takes S = J J^T / 12 instead, the
//          covariance of the parallelogram J [-1/2, 1/2]^2: a sample's share of a box-filtered
//          pixel (the camera's differentials scaled by max(1/8, 1/sqrt(spp)), render/differentials.h).
//          Measured on scenes/colormap/noise_plane.json at 4 spp (scripts/experiments/colormap_texture_gt): "box"
//          halves the relMSE of "gaussian" against the box-filtered reference where the footprint
//          is below a few periods (the MIP-map convention over-blurs by the window's extra spread);
//          "mipmap" stays the default so that the image and noise drivers mean the same window.
//          With the characteristic function E[exp(i 2 pi k.d)] = exp(-2 pi^2 k^T S k) =: g_k:
//              f_bar(x) = mean + sum_k a_k g_k cos(2 pi k_k . x + phi_k)              (exact)
//          and, with t_k the phase at x, c_kl = 4 pi^2 k_k^T S k_l (so g_{k-+l} = g_k g_l e^{+-c_kl}
//          for the Gaussian window), the exact windowed variance of the instance is
//              E_w[f^2] - f_bar^2 = sum_{k,l} a_k a_l g_k g_l [cos t_k cos t_l (cosh c_kl - 1)
//                                                           + sin t_k sin t_l sinh c_kl]      (O(K^2))
//          (computed as such, O(K^2), with noise key "variance": "exact"; g_k g_l e^{+-c_kl} =
//          exp(-(w_k -+ w_l)^T S (w_k -+ w_l) / 2) keeps every factor <= 1), and two O(K) estimates:
//          "process": its expectation over the random phases, which keeps k = l only:
//              sigma_f^2 = sum_k (a_k^2 / 2) (1 - g_k^2)
//            (the statistic of the process, as the paper uses for noise, §4.1 "approximate
//            solutions"; also the mean over x of the exact local variance: the law of total
//            variance, Var f = Var_x f_bar + E_x sigma_f^2 with Var_x f_bar = sum a_k^2 g_k^2 / 2).
//            It ignores where x is: at an extremum of f a small window holds almost no variance,
//            on a steep slope much more, and it gives both the average.
//          "local" (default): the exact diagonal (k = l) terms plus the off-diagonal terms to second
//            order in c_kl (sinh c ~ c, cosh c - 1 ~ c^2 / 2), which sum to quadratic forms in the
//            gradient G = sum_k a_k g_k sin t_k w_k and the Hessian H = sum_k a_k g_k cos t_k w_k w_k^T
//            of f_bar (w_k = 2 pi k_k; c_kl = w_k^T S w_l):
//              sigma_f^2 = sum_k a_k^2 [cos^2 t_k (1 - g_k^2)^2 / 2 + sin^2 t_k (1 - g_k^4) / 2]
//                          + G^T S G - sum_k a_k^2 g_k^2 sin^2 t_k c_kk
//                          + tr(H S H S) / 2 - sum_k a_k^2 g_k^2 cos^2 t_k c_kk^2 / 2
//            i.e. the variance of the second-order Taylor expansion of f_bar over the window, with
//            each frequency's own contribution exact. Exact in both limits: small footprints give
//            G^T S G (a locally linear f), large ones (g -> 0) the process value sum a_k^2 / 2; its
//            mean over x is the process value too (cross terms average out). It is >= 0: term by
//            term sinh x >= x and cosh x - 1 >= x^2 / 2, and both quadratic forms are >= 0.
//            Measured (tests/test_colormap_texture.cpp): 2-10x closer than "process" to the
//            instance's window variance while the window is below the dominant periods.
//            It may exceed sigma^2 at steep points of intermediate windows (sigma_max covers 1.25 sigma).
//          Both are O(K): K cosines, sines and exponentials per lookup.
//          A zero footprint gives f_bar = f(x), sigma_f = 0; a huge one f_bar -> mean,
//          sigma_f -> sigma. Non-finite uv gives the process statistics (mean, sigma).
//
// Filters:
//   gaussian        <C, N(f_bar, sigma_f^2)> from the preconvolved table (bilinear in f_bar and
//                   in sigma_f on the table's quadratic sigma axis; sigma_f > sigma_max is clamped)
//   gaussian_exact  the same inner product in closed form (Ramp::gaussian_average; the table's
//                   reference, slower by the number of stops)
//   naive           C(f_bar): the colour map of the filtered driver (the paper's baseline)
//   none            C(f(point)) (image: level-0 bilinear f): no filtering; the supersampled
//                   ground truth when rendered with many samples per pixel
//
// Cost per eval (ColormapTexture.EvalCost, 2 shared cores, loaded): noise with 64 components
// 3-5 us gaussian ("local"), 2.6-4 us naive, 1.4-2 us none; image 0.11-0.25 us gaussian,
// 0.1-0.2 us naive, 0.05-0.08 us none. Table (512 x 128 x 3 floats, 0.75 MB) built once.
//
// Parameters
//   name            type              default        notes
//   colormap        ramp              required       3-channel colour map (filter/ramp_parse.h syntax)
//   filename        string            -              grey image driver (channel average of RGB; alpha
//                                                    ignored); exactly one of filename / noise
//   noise           object            -              procedural driver: {mean 0, sigma 1, freq_min 1,
//                                                    freq_max 64, beta 1, components 64, seed 0,
//                                                    variance "local" | "process" | "exact",
//                                                    window "mipmap" (S = J J^T / 4) | "box" (/ 12)};
//                                                    sigma >= 0, 0 < freq_min <= freq_max <= 1e12, beta
//                                                    in [-8, 8], components in [1, 4096], seed >= 0
//   filter          string            "gaussian"     "gaussian" | "gaussian_exact" | "naive" | "none"
//   output          string            "color"        "color" | "statistics": (f_bar, sigma_f, f(point))
//                                                    as RGB (debugging, tests)
//   table_size      [n_mean, n_sigma] [512, 128]     each in [2, 65536], product <= 2^22 (gaussian only)
//   sigma_max       float             see below      > 0: the table's sigma range (gaussian only)
//   -- image driver only --
//   raw             bool              false          true: no sRGB decoding of 8/16-bit data
//   scale, offset   float             1, 0           f = offset + scale * texel (finite)
//   wrap_mode       string            "repeat"       "repeat" | "clamp" | "mirror"
//   tiling          number or [u, v]  1              repeats of the image over uv [0, 1], (0, 1e6]
//   footprint       string            "trilinear"    "trilinear" | "ewa": how both moments are read
//   max_anisotropy  float             8              ewa only, finite, >= 1 (as `bitmap`)
//
// sigma_max default: noise: sigma for "process" variance (sigma_f <= sigma for every footprint),
// 1.25 sigma for "local" and "exact" (the instance's window variance can exceed sigma^2).
// Image: 1.25 x the largest standard deviation of f over the pyramid's texels of levels >= 1
// (2x2 blocks and coarser, the whole image included), capped at half the range of f (no
// distribution on [min f, max f] has a larger one). Beyond sigma_max the lookup clamps sigma_f.
#include <algorithm>
#include <cmath>
#include <memory>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "core/math.h"
#include "image/image.h"
#include "texture/texture.h"
#include "image/image_param.h"
#include "filter/transfer_filter.h"
#include "sampling/rng.h"
#include "core/properties.h"
#include "core/registry.h"
#include "texture/mipmap.h"
#include "filter/ramp_parse.h"

namespace meso {
namespace {

constexpr double kPi = 3.14159265358979323846;

/// A ray-differential derivative as a finite double: NaN counts as 0, |d| > 1e30 as huge.
inline double clean_derivative(float d) { return std::isnan(d) ? 0.0 : double(clamp(d, -1e30f, 1e30f)); }

/// The grey driving function f: point values and footprint statistics.
class Driver {
public:
    virtual ~Driver() = default;
    /// f at the shading point (no filtering).
    virtual double point(const ShadingContext &ctx) const = 0;
    /// f_bar and sigma_f^2 over the footprint (var is left 0 unless want_var).
    virtual void footprint(const ShadingContext &ctx, double &mean, double &var, bool want_var = true) const = 0;
    /// Mean of f over the whole texture (the process mean for noise).
    virtual double global_mean() const = 0;
    /// Default sigma_max of the table (see the header comment).
    virtual double default_sigma_max() const = 0;
    /// Mean of C(f) over the whole texture.
    virtual void mean_color(const Ramp &ramp, double *out) const = 0;
    virtual std::string describe() const = 0;
};

struct NoiseParams {
    double mean = 0, sigma = 1, freq_min = 1, freq_max = 64, beta = 1;
    int components = 64;
    uint64_t seed = 0;
    enum class Variance { Process, Local, Exact } variance = Variance::Local;  ///< noise key "variance"
    bool box_window = false;                                                   ///< noise key "window"
};

class NoiseDriver final : public Driver {
public:
    explicit NoiseDriver(const NoiseParams &np)
        : m_p(np),
          m_local(np.variance == NoiseParams::Variance::Local),
          m_exact(np.variance == NoiseParams::Variance::Exact),
          m_window_half(np.box_window ? 1.0 / 24.0 : 1.0 / 8.0) {
        PCG32 rng(mix_bits(np.seed ^ 0x636f6c6f726d6170ULL), mix_bits(np.seed + 1));
        const int K = np.components;
        m_wx.resize(K), m_wy.resize(K), m_a.resize(K), m_phi.resize(K);
        double power = 0;
        const double log_ratio = std::log(np.freq_max / np.freq_min);
        for (int k = 0; k < K; ++k) {
            const double freq = np.freq_min * std::exp(log_ratio * rng.next_double());
            const double angle = 2.0 * kPi * rng.next_double();
            m_phi[k] = 2.0 * kPi * rng.next_double();
            // Angular frequencies w = 2 pi k (radians per unit uv).
            m_wx[k] = 2.0 * kPi * freq * std::cos(angle);
            m_wy[k] = 2.0 * kPi * freq * std::sin(angle);
            m_a[k] = std::pow(freq / np.freq_min, -np.beta);  // relative to freq_min: no overflow
            power += 0.5 * m_a[k] * m_a[k];
        }
        const double norm = power > 0 ? np.sigma / std::sqrt(power) : 0.0;
        for (double &a : m_a) a *= norm;
    }

    double point(const ShadingContext &ctx) const override {
        const double u = ctx.uv.x, v = ctx.uv.y;
        if (!std::isfinite(u) || !std::isfinite(v)) return m_p.mean;
        double f = m_p.mean;
        for (size_t k = 0; k < m_a.size(); ++k) f += m_a[k] * std::cos(m_wx[k] * u + m_wy[k] * v + m_phi[k]);
        return f;
    }

    void footprint(const ShadingContext &ctx, double &mean, double &var, bool want_var) const override {
        const double u = ctx.uv.x, v = ctx.uv.y;
        if (!std::isfinite(u) || !std::isfinite(v)) {
            mean = m_p.mean, var = m_p.sigma * m_p.sigma;
            return;
        }
        const double ax = clean_derivative(ctx.dudx), ay = clean_derivative(ctx.dvdx);
        const double bx = clean_derivative(ctx.dudy), by = clean_derivative(ctx.dvdy);
        // S = J J^T / 4 ("mipmap") or / 12 ("box"); (sxx, sxy, syy) = S / 2, so that with w = 2 pi k
        // -ln g_k = 2 pi^2 k^T S k = w^T (S / 2) w.
        const double q = m_window_half;
        const double sxx = (ax * ax + bx * bx) * q, sxy = (ax * ay + bx * by) * q, syy = (ay * ay + by * by) * q;
        mean = m_p.mean, var = 0;
        // G = -grad f_bar, H = -Hessian f_bar and the k = l parts of G^T S G and tr(H S H S) / 2.
        double gx = 0, gy = 0, hxx = 0, hxy = 0, hyy = 0, diag1 = 0, diag2 = 0;
        for (size_t k = 0; k < m_a.size(); ++k) {
            const double wx = m_wx[k], wy = m_wy[k];
            const double e = std::max(0.0, wx * wx * sxx + 2.0 * wx * wy * sxy + wy * wy * syy);  // -ln g_k
            const double a2 = m_a[k] * m_a[k];
            if (e > 40.0) {  // g_k < 5e-18: the component is averaged out
                var += 0.5 * a2;
                continue;
            }
            const double g = std::exp(-e);
            const double one_minus_g2 = e < 0.25 ? -std::expm1(-2.0 * e) : 1.0 - g * g;  // no cancellation
            const double t = wx * u + wy * v + m_phi[k];
            const double c = std::cos(t);
            mean += m_a[k] * g * c;
            if (!want_var) continue;
            if (!m_local) {  // process (exact: replaced below)
                var += 0.5 * a2 * one_minus_g2;
                continue;
            }
            // Exact diagonal term: cos^2 t (1 - g^2)^2 / 2 + sin^2 t (1 - g^4) / 2.
            const double sn = std::sin(t), one_plus_g2 = 2.0 - one_minus_g2;
            var += 0.5 * a2 * one_minus_g2 * (c * c * one_minus_g2 + sn * sn * one_plus_g2);
            const double ags = m_a[k] * g * sn, agc = m_a[k] * g * c;
            gx += ags * wx, gy += ags * wy;
            hxx += agc * wx * wx, hxy += agc * wx * wy, hyy += agc * wy * wy;
            diag1 += ags * ags * 2.0 * e;      // c_kk = w_k^T S w_k = 2 e_k
            diag2 += agc * agc * 2.0 * e * e;  // c_kk^2 / 2
        }
        if (!want_var) {
            var = 0;
            return;
        }
        if (m_exact) var = exact_variance(u, v, sxx, sxy, syy);
        if (m_local) {
            // Off-diagonal coupling to second order: G^T S G + tr(H S H S) / 2 minus their k = l
            // parts; S = 2 (sxx, sxy, syy). Non-negative in total (header comment).
            const double Sxx = 2.0 * sxx, Sxy = 2.0 * sxy, Syy = 2.0 * syy;
            const double gsg = gx * gx * Sxx + 2.0 * gx * gy * Sxy + gy * gy * Syy;
            const double m00 = hxx * Sxx + hxy * Sxy, m01 = hxx * Sxy + hxy * Syy;  // M = H S
            const double m10 = hxy * Sxx + hyy * Sxy, m11 = hxy * Sxy + hyy * Syy;
            const double quad = 0.5 * (m00 * m00 + 2.0 * m01 * m10 + m11 * m11);
            var = std::max(0.0, var + (gsg - diag1) + (quad - diag2));
        }
    }

    double global_mean() const override { return m_p.mean; }
    double default_sigma_max() const override { return m_local || m_exact ? 1.25 * m_p.sigma : m_p.sigma; }
    void mean_color(const Ramp &ramp, double *out) const override { ramp.gaussian_average(m_p.mean, m_p.sigma, out); }
    std::string describe() const override {
        return fmt::format(
            "noise (mean {}, sigma {}, freq [{}, {}], beta {}, {} components, seed {}, {} window, {} variance)",
            m_p.mean, m_p.sigma, m_p.freq_min, m_p.freq_max, m_p.beta, m_p.components, m_p.seed,
            m_p.box_window ? "box" : "mipmap",
            m_exact   ? "exact"
            : m_local ? "local"
                      : "process");
    }

private:
    /// The exact windowed variance of the instance, O(K^2) (header comment); S2 = S / 2.
    double exact_variance(double u, double v, double sxx, double sxy, double syy) const {
        const size_t K = m_a.size();
        double var = 0;
        for (size_t k = 0; k < K; ++k) {
            const double tk = m_wx[k] * u + m_wy[k] * v + m_phi[k], ck = std::cos(tk), sk = std::sin(tk);
            for (size_t l = k; l < K; ++l) {
                const double tl = m_wx[l] * u + m_wy[l] * v + m_phi[l];
                // e_{k-l} = (w_k - w_l)^T S2 (w_k - w_l) = e_k + e_l - c_kl, e_{k+l} = e_k + e_l + c_kl.
                const double dx = m_wx[k] - m_wx[l], dy = m_wy[k] - m_wy[l];
                const double px = m_wx[k] + m_wx[l], py = m_wy[k] + m_wy[l];
                const double em = dx * dx * sxx + 2.0 * dx * dy * sxy + dy * dy * syy;
                const double ep = px * px * sxx + 2.0 * px * py * sxy + py * py * syy;
                const double es = 0.5 * (em + ep);      // e_k + e_l
                if (std::min(em, ep) > 40.0) continue;  // every factor below is < e^-40
                const double gm = std::exp(-em), gp = std::exp(-ep), gg = std::exp(-es);
                const double term = m_a[k] * m_a[l] *
                                    (ck * std::cos(tl) * (0.5 * (gm + gp) - gg) + sk * std::sin(tl) * 0.5 * (gm - gp));
                var += l == k ? term : 2.0 * term;
            }
        }
        return std::max(0.0, var);
    }

    NoiseParams m_p;
    bool m_local, m_exact;
    double m_window_half;  ///< S / 2 = J J^T * m_window_half
    std::vector<double> m_wx, m_wy, m_a, m_phi;
};

class ImageDriver final : public Driver {
public:
    ImageDriver(int w, int h, const std::vector<double> &f, WrapMode wrap, Vec2 tiling, FootprintFilter filter,
                float max_anisotropy, std::string name)
        : m_tiling(tiling), m_filter(filter), m_max_anisotropy(max_anisotropy), m_name(std::move(name)) {
        const size_t n = size_t(w) * h;
        double sum = 0, lo = f[0], hi = f[0];
        for (double x : f) sum += x, lo = std::min(lo, x), hi = std::max(hi, x);
        m_center = sum / double(n);
        std::vector<float> data(2 * n);
        for (size_t i = 0; i < n; ++i) {
            const double d = f[i] - m_center;
            data[2 * i] = float(d);
            data[2 * i + 1] = float(d * d);
        }
        m_mip = MipMap(w, h, 2, std::move(data), wrap);
        // The largest texel standard deviation over levels >= 1 (see the header comment).
        double smax = 0;
        for (int l = 1; l < m_mip.levels(); ++l)
            for (int y = 0; y < m_mip.height(l); ++y)
                for (int x = 0; x < m_mip.width(l); ++x) {
                    const float *t = m_mip.texel(l, x, y);
                    smax = std::max(smax, double(t[1]) - double(t[0]) * t[0]);
                }
        m_sigma_max = std::min(1.25 * std::sqrt(std::max(smax, 0.0)), 0.5 * (hi - lo));
        m_f = f;  // kept for mean_color (level-0 texels)
    }

    double point(const ShadingContext &ctx) const override {
        float m[2];
        m_mip.bilinear(0, ctx.uv.x * m_tiling.x, ctx.uv.y * m_tiling.y, m);
        return m_center + m[0];
    }

    void footprint(const ShadingContext &ctx, double &mean, double &var, bool) const override {
        const float tu = m_tiling.x, tv = m_tiling.y;
        const float dudx = ctx.dudx * tu, dudy = ctx.dudy * tu, dvdx = ctx.dvdx * tv, dvdy = ctx.dvdy * tv;
        float m[2];
        m_mip.lookup(m_filter, ctx.uv.x * tu, ctx.uv.y * tv, dudx, dudy, dvdx, dvdy, m, m_max_anisotropy);
        mean = m_center + m[0];
        var = std::max(0.0, double(m[1]) - double(m[0]) * m[0]);
        // Magnification: fade the variance by the footprint width squared (header comment).
        var = m_mip.magnified_variance(var, dudx, dudy, dvdx, dvdy);
    }

    double global_mean() const override { return m_center; }
    double default_sigma_max() const override { return m_sigma_max; }
    void mean_color(const Ramp &ramp, double *out) const override {
        const int ch = ramp.channels();
        std::vector<double> acc(ch, 0.0), c(ch);
        for (double x : m_f) {
            ramp.eval(x, c.data());
            for (int k = 0; k < ch; ++k) acc[k] += c[k];
        }
        for (int k = 0; k < ch; ++k) out[k] = acc[k] / double(m_f.size());
    }
    std::string describe() const override {
        return fmt::format("image '{}' {}x{}, {} footprint, {} levels, {:.2f} MB", m_name, m_mip.width(),
                           m_mip.height(), m_filter == FootprintFilter::Ewa ? "ewa" : "trilinear", m_mip.levels(),
                           m_mip.memory_bytes() / 1048576.0);
    }

private:
    MipMap m_mip;
    std::vector<double> m_f;
    double m_center = 0, m_sigma_max = 0;
    Vec2 m_tiling;
    FootprintFilter m_filter;
    float m_max_anisotropy;
    std::string m_name;
};

enum class Filter { Gaussian, GaussianExact, Naive, None };
const char *filter_name(Filter f) {
    static const char *names[] = {"gaussian", "gaussian_exact", "naive", "none"};
    return names[int(f)];
}

class ColormapTexture final : public Texture {
public:
    ColormapTexture(Ramp ramp, std::unique_ptr<Driver> driver, Filter filter, bool statistics, double sigma_max,
                    int n_mean, int n_sigma)
        : m_ramp(std::move(ramp)),
          m_driver(std::move(driver)),
          m_filter(filter),
          m_statistics(statistics),
          m_sigma_max(sigma_max) {
        if (m_filter == Filter::Gaussian && !m_statistics)
            m_table = PreconvolvedTable::of_ramp(m_ramp, m_sigma_max, n_mean, n_sigma);
        if (m_statistics) {
            const float m = float(m_driver->global_mean());
            m_mean = Spectrum(m, float(m_sigma_max), m);
        } else {
            double c[3] = {0, 0, 0};
            m_driver->mean_color(m_ramp, c);
            m_mean = Spectrum(float(c[0]), float(c[1]), float(c[2]));
        }
    }

    Spectrum eval(const ShadingContext &ctx) const override {
        if (m_statistics) {
            double mean, var;
            footprint(ctx, mean, var);
            return Spectrum(float(mean), float(std::sqrt(var)), float(m_driver->point(ctx)));
        }
        double c[3] = {0, 0, 0};
        switch (m_filter) {
            case Filter::None:
                m_ramp.eval(finite_or_mean(m_driver->point(ctx)), c);
                break;
            case Filter::Naive: {
                double mean, var;
                footprint(ctx, mean, var, false);
                m_ramp.eval(mean, c);
                break;
            }
            case Filter::GaussianExact: {
                double mean, var;
                footprint(ctx, mean, var);
                m_ramp.gaussian_average(mean, std::sqrt(var), c);
                break;
            }
            case Filter::Gaussian: {
                double mean, var;
                footprint(ctx, mean, var);
                float t[3] = {0, 0, 0};
                m_table.lookup(mean, std::sqrt(var), t);
                return Spectrum(t[0], t[1], t[2]);
            }
        }
        return Spectrum(float(c[0]), float(c[1]), float(c[2]));
    }
    Spectrum mean() const override { return m_mean; }
    std::string to_string() const override {
        std::string table = m_table.empty() ? std::string()
                                            : fmt::format(", table sigma_max {:.4g}, {:.2f} MB", m_table.sigma_max(),
                                                          m_table.memory_bytes() / 1048576.0);
        return fmt::format("colormap({} stops on {}, filter {}{}{})", m_ramp.stops(), m_driver->describe(),
                           filter_name(m_filter), m_statistics ? ", output statistics" : "", table);
    }

private:
    double finite_or_mean(double f) const { return std::isfinite(f) ? f : m_driver->global_mean(); }
    /// Footprint statistics, kept finite whatever the inputs.
    void footprint(const ShadingContext &ctx, double &mean, double &var, bool want_var = true) const {
        m_driver->footprint(ctx, mean, var, want_var);
        if (!std::isfinite(mean)) mean = m_driver->global_mean();
        if (!(var >= 0.0)) var = 0.0;
        if (!std::isfinite(var)) var = m_sigma_max * m_sigma_max;
    }

    Ramp m_ramp;
    std::unique_ptr<Driver> m_driver;
    Filter m_filter;
    bool m_statistics;
    double m_sigma_max;
    PreconvolvedTable m_table;
    Spectrum m_mean;
};

double get_number(const Properties &p, const std::string &key, double def) {
    if (!p.has(key)) return def;
    const nlohmann::json &v = p.raw(key);
    if (!v.is_number()) p.fail(key, fmt::format("expected a number, got {}", json_type_name(v)));
    const double d = v.get<double>();
    if (!std::isfinite(d)) p.fail(key, "expected a finite number");
    return d;
}

std::unique_ptr<Driver> make_noise(const Properties &p) {
    const Properties n = p.child("noise");
    NoiseParams np;
    np.mean = get_number(n, "mean", 0.0);
    np.sigma = get_number(n, "sigma", 1.0);
    if (!(np.sigma >= 0.0)) n.fail("sigma", fmt::format("expected a number >= 0, got {}", np.sigma));
    np.freq_min = get_number(n, "freq_min", 1.0);
    if (!(np.freq_min > 0.0 && np.freq_min <= 1e12))
        n.fail("freq_min", fmt::format("expected a number in (0, 1e12] (cycles per unit uv), got {}", np.freq_min));
    np.freq_max = get_number(n, "freq_max", std::max(64.0, np.freq_min));
    if (!(np.freq_max >= np.freq_min && np.freq_max <= 1e12))
        n.fail("freq_max",
               fmt::format("expected a number in [freq_min, 1e12] = [{}, 1e12], got {}", np.freq_min, np.freq_max));
    np.beta = get_number(n, "beta", 1.0);
    if (!(np.beta >= -8.0 && np.beta <= 8.0))
        n.fail("beta", fmt::format("expected a number in [-8, 8], got {}", np.beta));
    np.components = n.get_int("components", 64);
    if (np.components < 1 || np.components > 4096)
        n.fail("components", fmt::format("expected an integer in [1, 4096], got {}", np.components));
    const int seed = n.get_int("seed", 0);
    if (seed < 0) n.fail("seed", fmt::format("expected an integer >= 0, got {}", seed));
    np.seed = uint64_t(seed);
    using Variance = NoiseParams::Variance;
    np.variance = n.get_enum<Variance>(
        "variance", "local", {{"local", Variance::Local}, {"process", Variance::Process}, {"exact", Variance::Exact}});
    np.box_window = n.get_enum<bool>("window", "mipmap", {{"mipmap", false}, {"box", true}});
    n.check_unused("colormap noise");
    return std::make_unique<NoiseDriver>(np);
}

std::unique_ptr<Driver> make_image(const Properties &p) {
    const std::string file = p.get_file("filename");
    const bool raw = p.get_bool("raw", false);
    const double scale = get_number(p, "scale", 1.0), offset = get_number(p, "offset", 0.0);
    const WrapMode wrap = parse_texture_wrap(p);
    Vec2 tiling(1.f, 1.f);
    if (p.has("tiling")) {
        const auto [t0, t1] = p.get_tiling();
        tiling = Vec2(t0, t1);
    }
    const FootprintFilter filter = p.get_enum<FootprintFilter>(
        "footprint", "trilinear", {{"trilinear", FootprintFilter::Trilinear}, {"ewa", FootprintFilter::Ewa}});
    const float max_anisotropy = p.get_float("max_anisotropy", 8.f, Range::at_least(1.0));

    const Image img = read_image_param(p, "filename", file, raw);
    // Grey: channel 0 of 1- and 2-channel (grey + alpha) images, the RGB average otherwise.
    const int nc = img.channels <= 2 ? 1 : 3;
    std::vector<double> f(size_t(img.width) * img.height);
    long bad = 0;
    for (size_t i = 0; i < f.size(); ++i) {
        double s = 0;
        for (int c = 0; c < nc; ++c) s += img.data[i * img.channels + c];
        f[i] = offset + scale * (s / nc);
        if (!std::isfinite(f[i])) ++bad;
    }
    if (bad > 0)
        p.fail("filename", fmt::format("{}: {} texel value(s) are NaN or infinite (after scale/offset)", file, bad));
    return std::make_unique<ImageDriver>(img.width, img.height, f, wrap, tiling, filter, max_anisotropy, file);
}

std::shared_ptr<Texture> create_colormap(const Properties &p) {
    const bool has_image = p.has("filename"), has_noise = p.has("noise");
    if (has_image && has_noise)
        p.fail("noise", "expected exactly one driver, 'filename' (a grey image) or 'noise', got both");
    if (!has_image && !has_noise)
        p.fail("expected exactly one driver: 'filename' (a grey image) or 'noise' (a procedural noise object)");
    if (has_noise)
        for (const char *k : {"raw", "scale", "offset", "wrap_mode", "tiling", "footprint", "max_anisotropy"})
            if (p.has(k)) p.fail(k, "applies to the image driver ('filename') only");

    Ramp ramp = parse_ramp(p, "colormap", 3);
    const Filter filter = p.get_enum<Filter>("filter", "gaussian",
                                             {{"gaussian", Filter::Gaussian},
                                              {"gaussian_exact", Filter::GaussianExact},
                                              {"naive", Filter::Naive},
                                              {"none", Filter::None}});
    const bool statistics = p.get_enum<bool>("output", "color", {{"color", false}, {"statistics", true}});
    int n_mean = 512, n_sigma = 128;
    if (p.has("table_size")) {
        const std::vector<float> t = p.get_floats("table_size");
        if (t.size() != 2 || t[0] != std::floor(t[0]) || t[1] != std::floor(t[1]) || !(t[0] >= 2 && t[0] <= 65536) ||
            !(t[1] >= 2 && t[1] <= 65536) || double(t[0]) * t[1] > double(1 << 22))
            p.fail("table_size", "expected [n_mean, n_sigma], integers in [2, 65536] with n_mean * n_sigma <= 2^22");
        n_mean = int(t[0]), n_sigma = int(t[1]);
    }
    double sigma_max = -1;
    if (p.has("sigma_max")) {
        sigma_max = get_number(p, "sigma_max", 1.0);
        if (!(sigma_max > 0.0)) p.fail("sigma_max", fmt::format("expected a number > 0, got {}", sigma_max));
    }

    std::unique_ptr<Driver> driver = has_noise ? make_noise(p) : make_image(p);
    if (sigma_max <= 0) {
        sigma_max = driver->default_sigma_max();
        // A constant driver still needs a table with a sigma axis.
        if (!(sigma_max > 0.0)) sigma_max = 1e-6 * std::max(1.0, ramp.x_max() - ramp.x_min());
    }
    return std::make_shared<ColormapTexture>(std::move(ramp), std::move(driver), filter, statistics, sigma_max,
                                             n_mean, n_sigma);
}

MESO_REGISTER_TEXTURE("colormap",
                      "colour map of a grey image or Gaussian noise filtered with Gaussian statistics, paper 001 §4 "
                      "(colormap, filename | noise, filter, output, table_size, sigma_max, raw, scale, offset, "
                      "wrap_mode, tiling, footprint, max_anisotropy)",
                      create_colormap);

}  // namespace
}  // namespace meso
