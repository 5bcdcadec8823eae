// Filtering non-linear transfer functions on Gaussian statistics (paper 001, Heitz et al.
// 2014): colour maps C applied to a Gaussian-distributed attribute a (a noise or grey texture
// value, a microsurface height, a slope) are filtered as the inner product <C, D> with the
// attribute's filtering distribution D approximated by a Gaussian (eq. 7, 13, 18, 29).
//
//   Ramp              a piecewise-linear, N-channel function of one variable (a colour map, or
//                     a height transfer function g), constant beyond its first and last stop.
//                     gaussian_average() is the exact <C, N(mean, sigma^2)> in closed form:
//                     over a segment [x0, x1] where C = alpha + beta v, with z = (v - mean)/sigma,
//                     int (alpha + beta v) N dv = (alpha + beta mean) [Phi(z1) - Phi(z0)]
//                                                + beta sigma [phi(z0) - phi(z1)].
//   PreconvolvedTable the paper's 2D table of [F * N(0, sigma^2)](mean) (eq. 9) indexed by
//                     (mean, sigma), bilinear, for any N-channel function F (built by
//                     quadrature; for a Ramp by the closed form). The sigma axis is quadratic
//                     (sigma_j = sigma_max (j / (n - 1))^2) so sigma -> 0 is resolved; sigma >
//                     sigma_max is clamped there (lookup() says so through its return value).
//
// Height-correlated colour (§5.1), Lambda = Lambda(wo) + Lambda(wi) (Smith, height-uncorrelated
// visibility P_h(h)^Lambda of eq. 2):
//   average_visibility(lo, li) = (1 + lo) / (1 + lo + li)                          (eq. 12)
//   D_h(h) = P_h(h)^Lambda p_h(h) (Lambda + 1)                                        (eq. 15)
//   height_filter_fit:  mu_d = a_mu sigma_h ln(b_mu Lambda + 1),
//                       sigma_d = sigma_h / (1 + a_s ln(b_s Lambda + 1))             (eq. 16-17)
//                       with the paper's a_mu = 0.39, b_mu = 4.75, a_s = 0.26, b_s = 1.13.
//   height_filter_exact: the mean and standard deviation of eq. 15 by quadrature. In the
//                       standardised height z = h / sigma_h, D_h is the density of the maximum
//                       of Lambda + 1 standard normals (for integer Lambda): e.g. Lambda = 1
//                       gives mu = 1/sqrt(pi) sigma_h, sigma = sqrt(1 - 1/pi) sigma_h (tested).
//   HeightFilterTable:  height_filter_exact tabulated over ln(1 + Lambda) (the "exact" option).
//   Lambda is clamped to [0, 1e8] so grazing and shadowed directions stay finite.
//
// Slope-correlated colour (§5.2). The supplement with the paper's derivation of D_s is not
// available; meso derives D_s from the visible-normal distribution of the Gaussian surface.
// The projected area towards wo of a micro-facet of slope s = (sx, sy), per unit macro area,
// is <wo, m> sqrt(1 + |s|^2) = wo.z (1 - s . t) with m = (-sx, -sy, 1)/sqrt(1 + |s|^2) and
// t = (wo.x, wo.y) / wo.z, so eq. 18's weight max(cos theta_o, 0) w_P dx becomes
//   D_s(s) = p_s(s) max(0, 1 - s . t) / M0,    M0 = (1 - tan(theta_o) mu)(1 + Lambda(wo)) with mu
// the mean slope along wo's azimuth and Lambda the paper-form GaussianSlopes::lambda (= 1 +
// Lambda_smith for a centred distribution; masking is height-only under Smith and cancels).
// Only the component u = s . t_hat along t's direction is reweighted: with u ~ N(m, v),
// a = |t|, c = 1/a, z = (c - m)/sqrt(v) and the truncated-normal moments
//   E[u^k 1{u<c}] (k = 0..3, closed forms with Phi(z), phi(z)),
//   M0 = E[(1 - a u) 1{u<c}], M1 = E[u (1 - a u) 1{u<c}], M2 = E[u^2 (1 - a u) 1{u<c}],
// the reweighted mean and variance of u are mu_u = M1/M0, var_u = M2/M0 - mu_u^2, and since
// s | u is Gaussian with mean s_bar + Sigma t_hat (u - m) / v and covariance
// Sigma - (Sigma t_hat)(Sigma t_hat)^T / v, the first two moments of D_s are exactly
//   mean = s_bar + Sigma t_hat (mu_u - m) / v
//   cov  = Sigma - (Sigma t_hat)(Sigma t_hat)^T (v - var_u) / v^2.
// D_s is approximated by the Gaussian with these moments (visible_slope_gaussian; verified
// against 2D quadrature of p_s (1 - s.t)+ in tests/test_transfer_filter.cpp). Where the view is
// more than 12 standard deviations below the mesosurface (z < -12; the closed forms hold to 1e-8
// down to z = -15) the reweighted u follows the
// limit c - Gamma(2, sqrt(v)/|z|): mean c - 2 sqrt(v)/|z|, variance 2 v / z^2.
//
// Expectations of arbitrary functions of the slope under a 2D Gaussian (slope colour maps that
// are not linear in s, irradiance environment maps of §5.3) use tensor Gauss-Hermite rules
// through the Cholesky factor (gaussian_expectation_2d).
//
// Height transfer functions (§7): h = g(f) with f ~ N(f_bar, sigma_f^2) inside the footprint.
// transfer_moments() gives g_bar, E[g^2], E[g'], E[g'^2] (eq. 21-22, 27-28) and
// transferred_statistics() the height mean / variance and the slope Gaussian of h from them and
// the slope moments of f (eq. 23-26: dh/dx = g'(f) df/dx with g'(f) and df/dx uncorrelated).
#pragma once
#include <array>
#include <functional>
#include <string>
#include <vector>
#include "core/vec.h"
#include "filter/slope_gaussian.h"

namespace meso {

/// Standard normal density and cumulative distribution (stable for large |z|).
double std_normal_pdf(double z);
double std_normal_cdf(double z);

/// A piecewise-linear function with `channels` outputs through stops x[0] < x[1] < ...,
/// constant beyond the first and last stop. One stop makes a constant.
class Ramp {
public:
    Ramp() = default;
    /// values: x.size() * channels numbers, stop-major. MesoError unless x is strictly increasing
    /// and finite, channels >= 1 and the sizes agree.
    Ramp(std::vector<double> x, std::vector<double> values, int channels);

    int channels() const { return m_ch; }
    int stops() const { return int(m_x.size()); }
    bool empty() const { return m_x.empty(); }
    double x_min() const { return m_x.front(); }
    double x_max() const { return m_x.back(); }
    const std::vector<double> &x() const { return m_x; }
    const std::vector<double> &values() const { return m_v; }

    /// C(v) (out: channels() numbers).
    void eval(double v, double *out) const;
    /// The derivative C'(v) (piecewise constant; the right derivative at a stop, 0 beyond).
    void derivative(double v, double *out) const;
    /// <C, N(mean, sigma^2)> in closed form (sigma <= 0: C(mean)).
    void gaussian_average(double mean, double sigma, double *out) const;
    /// <(C')^k, N(mean, sigma^2)> for k = 1, 2 in closed form (the §7 moments of g').
    void gaussian_average_derivative(double mean, double sigma, int power, double *out) const;
    /// <C^2, N(mean, sigma^2)> in closed form (the §7 moment of g^2).
    void gaussian_average_square(double mean, double sigma, double *out) const;

    std::string to_string() const;

private:
    template <class Piece>
    void for_each_piece(double mean, double sigma, Piece piece) const;
    std::vector<double> m_x, m_v;
    int m_ch = 0;
};

/// 2D table of [F * N(0, sigma^2)](mean) over mean in [mean_min, mean_max] (clamped beyond)
/// and sigma in [0, sigma_max] (quadratic spacing), bilinear lookups.
class PreconvolvedTable {
public:
    using Function = std::function<void(double v, double sigma, double *out)>;  ///< <F, N(v, sigma^2)>
    PreconvolvedTable() = default;
    /// `average(v, sigma, out)` must return the Gaussian average of F (exact or by quadrature).
    PreconvolvedTable(int channels, double mean_min, double mean_max, double sigma_max, int n_mean, int n_sigma,
                      const Function &average);
    /// The table of a Ramp: means over [x_min - 4 sigma_max, x_max + 4 sigma_max].
    static PreconvolvedTable of_ramp(const Ramp &ramp, double sigma_max, int n_mean = 512, int n_sigma = 128);

    int channels() const { return m_ch; }
    double sigma_max() const { return m_smax; }
    bool empty() const { return m_data.empty(); }
    /// Writes channels() floats; returns false when sigma > sigma_max was clamped.
    bool lookup(double mean, double sigma, float *out) const;
    size_t memory_bytes() const { return m_data.size() * sizeof(float); }

private:
    int m_ch = 0, m_nm = 0, m_ns = 0;
    double m_m0 = 0, m_m1 = 1, m_smax = 0;
    std::vector<float> m_data;
};

// ---- Height-correlated colour (§5.1) ----

/// Eq. (12): the average visibility of the light given the view, (1 + lo) / (1 + lo + li).
double average_visibility(double lambda_o, double lambda_i);

struct HeightFilter {
    double mu = 0, sigma = 0;  ///< mean and standard deviation of D_h
};
struct HeightFitParams {
    double a_mu = 0.39, b_mu = 4.75, a_sigma = 0.26, b_sigma = 1.13;  ///< the paper's fit
};
/// Eq. (16-17) for the height standard deviation sigma_h and Lambda = Lambda(wo) + Lambda(wi).
HeightFilter height_filter_fit(double sigma_h, double lambda_sum, const HeightFitParams &fit = {});
/// The mean and standard deviation of eq. (15) by quadrature (in z = h / sigma_h, ~2000
/// nodes over z in [-9, 12]; relative error < 1e-6 for Lambda in [0, 1e8]).
HeightFilter height_filter_exact(double sigma_h, double lambda_sum);

/// height_filter_exact for sigma_h = 1 tabulated over x = ln(1 + Lambda) in [0, ln(1 + 1e8)]
/// (256 nodes, linear interpolation; max error: sigma 1e-4 relative, mu 2e-4 sigma_h, tested).
class HeightFilterTable {
public:
    HeightFilterTable();
    HeightFilter lookup(double sigma_h, double lambda_sum) const;
    static const HeightFilterTable &instance();

private:
    std::vector<double> m_mu, m_sigma;
    double m_dx = 0;
};

// ---- Slope-correlated colour (§5.2) ----

/// D_s for view wo (local frame, z = macronormal) and slope distribution p: the Gaussian with the
/// exact first two moments of p_s(s) (1 - s . t)+ (see the header comment). `norm` (optional)
/// receives M0, the mass of p_s (1 - s . t)+. wo.z is clamped to >= 1e-6.
SlopeGaussian visible_slope_gaussian(const SlopeGaussian &p, const Vec3 &wo, double *norm = nullptr);

/// Probabilists' Gauss-Hermite rule for N(0, 1): n nodes (ascending) and weights summing to 1
/// (exact for polynomials of degree <= 2n - 1). n in [1, 64]; cached per n.
void gauss_hermite_normal(int n, std::vector<double> &x, std::vector<double> &w);

/// E[f(s)] for s ~ N(mean, Sigma) (a SlopeGaussian) by an n x n tensor Gauss-Hermite rule through
/// the Cholesky factor (a singular Sigma is handled: its zero directions collapse).
/// f writes `channels` numbers; out receives the expectation.
void gaussian_expectation_2d(const SlopeGaussian &g, int n, int channels,
                             const std::function<void(double sx, double sy, double *out)> &f, double *out);

/// E[C(|s|)] for s ~ N(mean, Sigma) and a Ramp C of the steepness |s| (paper 001 §5.2 with a
/// colour map on the slope's magnitude). C(|s|) has a cusp at s = 0 and kinks at the stops, on
/// which tensor Gauss-Hermite converges slowly (8 x 8: 4% error). When the spread is at least
/// 0.2 |mean| it integrates in polar coordinates about s = 0: along each direction the radial
/// integral of the piecewise-linear C against the Gaussian is closed-form (partial moments of phi
/// on every ramp piece), and the angle takes the trapezoid rule (periodic: spectral accuracy) with
/// 16-256 nodes by the distribution's angular width; normalised by the integrated mass.
/// Otherwise |s| is smooth over the distribution and 12 x 12 Gauss-Hermite is used. Within 2e-3
/// of brute-force quadrature (TransferFilter.SteepnessAverageMatchesBruteForce).
void gaussian_average_steepness(const Ramp &ramp, const SlopeGaussian &g, double *out);

/// The unit micro-normal of slope (sx, sy): (-sx, -sy, 1) / sqrt(1 + sx^2 + sy^2).
Vec3 slope_to_normal(double sx, double sy);

// ---- Height transfer functions (§7) ----

struct TransferMoments {
    double g = 0, g2 = 0, dg = 0, dg2 = 0;  ///< E[g], E[g^2], E[g'], E[g'^2] under N(f_bar, sigma_f^2)
};
/// Eq. (21-22), (27-28) in closed form for a one-channel Ramp g.
TransferMoments transfer_moments(const Ramp &g, double f_bar, double sigma_f);

struct TransferredStatistics {
    double h_mean = 0, h_var = 0;  ///< eq. (21) and E[g^2] - E[g]^2
    SlopeGaussian slopes;          ///< eq. (24-26): the slope mean and covariance of h
};
/// h = g(f): the height statistics from the transfer moments and the slope distribution of f
/// (mean and covariance, as SlopeGaussian). E[dh/dx] = E[g'] E[df/dx], E[(dh/dx)^2] = E[g'^2]
/// E[(df/dx)^2], E[dh/dx dh/dy] = E[g'^2] E[df/dx df/dy]; variances clamped at 0.
TransferredStatistics transferred_statistics(const TransferMoments &m, const SlopeGaussian &f_slopes);

}  // namespace meso
