// Deterministic quadrature for LEADR (paper 000 §5): the N x N slope grid (§5.1), the diffuse
// microfacet slope integral of eq. (21), and environment lighting by Algorithms 1-3.
//
// Grid (§5.1). N points p_j uniform on [-lambda, lambda] (p_j = -lambda + 2 lambda j / (N - 1);
// N = 1 is the single point 0), normalised Gaussian weights W_j = exp(-p_j^2/2) / sum_k
// exp(-p_k^2/2), the Cartesian product warped to P22 by the Cholesky factor of Sigma:
//   x = p_j sigma_x + E[x],  y = (r_xy p_j + sqrt(1 - r_xy^2) p_k) sigma_y + E[y],  W = W_j W_k.
// lambda(N) = min(5, 0.4 + 1.2 ln N) (lambda(1) = 1, only used for the sample area of Alg. 1).
// The paper picks lambda = 1.8 for N = 5 "for best results"; this rule comes from measuring
// the error of the diffuse slope integral (eq. 21, point light) against N = 1024, lambda = 8
// over 1600 configurations (wo, wi at 0-89 degrees, centred / anisotropic-correlated /
// non-centred / 80-degree-tilted moments, variances 0.01-2), error relative to the value
// at wi = normal: the best lambda per N was 0.9 (N=2), 1.6 (3), 2.3 (5), 3.0 (8), 3.5 (12),
// 3.6 (16), 4.0 (24), 4.8 (32), 4.9 (128), and the rule stays within 20% of the best RMS
// error for every N >= 3. Errors with the rule against N = 128 over the sweep of
// tests/test_leadr.cpp (LeadrGrid.DiffuseIntegralErrorAgainstN128, RMS / max): N=5 1.8e-2 /
// 1.2e-1, N=8 7.1e-3 / 6.6e-2, N=12 3.4e-3 / 3.2e-2, N=16 1.6e-3 / 1.5e-2, N=32 1.6e-4 /
// 9.6e-4 (N = 128 itself is within 2e-4 of N = 1024).
//
// Environment (the light is unoccluded: a distant environment seen by the whole hemisphere).
//   Algorithm 1 (specular, eq. 22): for each grid slope, the micro-normal w_n, the mirror
//   direction w_i = 2 (w_n . wo) w_n - wo (eq. 18), the weight W F(w_n . w_i) <w_n, wo> /
//   (w_n . w_g) G(wo, wi) and the prefiltered radiance at w_i, read at the level whose texel
//   solid angle matches alpha = J A, J = 4 |w_n . wo| |w_n . w_g|^3 (the slope -> w_i
//   Jacobian), A = (2 lambda max(sigma_x, sigma_y) / N)^2; the sum times (n . w_g)/(n . wo)
//   with n the mesonormal. G is 1/(1 + Lambda(wo) + Lambda(wi)) ("joint", eq. 13) or
//   1/(1 + Lambda(wo)) ("masking"), 0 when w_i is below the mesosurface. Mirror directions
//   below the macrosurface (w_i.z <= 0) contribute 0, as they do in the material's eval
//   (reflection-only), so the quadrature estimates exactly what a Monte Carlo integration
//   of the material against the environment converges to.
//   Algorithms 2-3 (diffuse, eq. 20-21 and 23): the irradiance map E(w_n) from nine SH
//   coefficients (Ramamoorthi & Hanrahan 2001), then I = (n . w_g)/(n . wo) rho / pi
//   sum W E(w_n) <w_n, wo> / (w_n . w_g) on an N x N grid (the paper uses 5 x 5).
//   Two ways to get the coefficients:
//     Paper     Algorithm 2 as published: L_lm of the environment projected once (full
//               resolution, world frame), divided by (1 + Lambda(wo)) per shading point.
//               Ignores the shadowing Lambda(wi) and the horizon: light from below the
//               macro/mesosurface reaches the microfacets.
//     Shadowed  per shading point, L_lm of L(w_i) G(wo, w_i) [w_i.z > 0] (the exact
//               integrand of eq. 20, shadowing and horizon included) projected from a
//               coarse level of the environment (at most 32 x 16 texels, ~256 above the
//               horizon): ~10 us a shading point.
//   Both keep the SH truncation of the irradiance (<= 9% worst case per the paper; far less
//   for smooth environments) and clamp E >= 0.
//
// Measured bias against converged Monte Carlo of eq. (19) / (21) (tests/test_leadr.cpp,
// LeadrEnvQuadrature.*: a smooth environment of broad blobs, four moment settings from a
// narrow centred lobe to variance 0.5 at wo = 70 degrees), max relative error over RGB:
//   Algorithm 1, prefiltered: N=5 0.2-11%, N=8 0.5-8.4%, N=16 0.2-4.5%, N=32 0.07-1.6%: the
//     prefiltered lookups blur the map over each sample's (deliberately overestimated) solid
//     angle, which dominates for rough lobes; without prefiltering (LeadrEnvOptions::prefilter
//     = false) the grid alone is within 0.3% from N = 12 on, but aliases on detailed maps.
//   Algorithms 2-3, shadowed: 0.6-0.8% from N = 8 on (SH truncation + the 32 x 16
//     projection), 0.7-3.4% at the paper's N = 5; paper's Algorithm 2: 4-25% (no shadowing,
//     light from below the horizon).
// Cost per shading point (2 cores' one thread, -O2): Algorithm 1 4.6 us (N=5), 11 us (N=8),
// 40 us (N=16), 140 us (N=32); Algorithms 2-3 shadowed 23 us (N=5), paper 0.8 us (N=5).
//
#pragma once
#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <memory>
#include <vector>
#include "core/frame.h"
#include "core/spectrum.h"
#include "core/transform.h"
#include "geometry/shading.h"
#include "bsdf/slope_distribution.h"
#include "lights/prefiltered_environment.h"
#include "texture/mipmap.h"

namespace meso {

class Light;

constexpr int kLeadrMaxGrid = 128;

/// lambda(N) of the grid (see above); n in [1, kLeadrMaxGrid].
double leadr_grid_lambda(int n);

/// The 1D pattern of §5.1 for N points.
struct LeadrGrid1D {
    int n = 0;
    double lambda = 0;
    std::array<double, kLeadrMaxGrid> p{}, w{};
};
/// Cached patterns for n in [1, kLeadrMaxGrid] (n is clamped to that range).
const LeadrGrid1D &leadr_grid_1d(int n);

/// Calls f(x, y, W) for the N^2 grid slopes warped to `g` (already regularised, e.g.
/// GaussianSlopes::params()): Cholesky warp of §5.1, weights summing to 1.
template <typename F> void for_each_leadr_slope(const SlopeGaussian &g, int n, F &&f) {
    const LeadrGrid1D &G = leadr_grid_1d(n);
    const double sx = std::sqrt(g.sxx), sy = std::sqrt(g.syy);
    const double r = (sx > 0 && sy > 0) ? g.sxy / (sx * sy) : 0.0;
    const double rc = std::sqrt(std::max(0.0, 1.0 - r * r));
    for (int j = 0; j < G.n; ++j) {
        const double x = G.p[j] * sx + g.mx;
        for (int k = 0; k < G.n; ++k) {
            const double y = (r * G.p[j] + rc * G.p[k]) * sy + g.my;
            f(x, y, G.w[j] * G.w[k]);
        }
    }
}

/// The micro-normal of slope (x, y): (-x, -y, 1) / sqrt(1 + x^2 + y^2) (eq. 11).
inline Vec3 leadr_slope_normal(double x, double y) {
    const double l = std::sqrt(1.0 + x * x + y * y);
    return Vec3(float(-x / l), float(-y / l), float(1.0 / l));
}

/// The diffuse microfacet slope integral of eq. (21) for one light direction:
///   int <w_n, wo> <w_n, wi> / (w_n . w_g) P22(s) ds
///   = int max(0, wo.z - s.wo_xy) max(0, wi.z - s.wi_xy) / sqrt(1 + |s|^2) P22(s) ds
/// on the N x N grid. Finite for any input; 0 when either direction is at or below every
/// grid facet. `visible_area`, when given, receives the same grid's estimate of the projected
/// area int max(0, wo.z - s.wo_xy) P22(s) ds (= area (1 + Lambda(wo)) exactly), which the
/// material uses to keep the albedo <= rho where the grid overestimates it (grazing wo).
double leadr_diffuse_slope_integral(const GaussianSlopes &g, int n, const Vec3 &wo, const Vec3 &wi,
                                    double *visible_area = nullptr);

/// The same integral with the grid precomputed (constant statistics): N^2 x (x, y, W / sqrt(1 + |s|^2), W).
class LeadrDiffuseGrid {
public:
    LeadrDiffuseGrid() = default;
    LeadrDiffuseGrid(const GaussianSlopes &g, int n);
    double integral(const Vec3 &wo, const Vec3 &wi, double *visible_area = nullptr) const;
    bool empty() const { return m_pts.empty(); }

private:
    std::vector<std::array<double, 4>> m_pts;
};

enum class LeadrShadowing { Joint, Masking };

/// E[V(wo) V(wi)]: 1/(1 + lo + li) (joint, eq. 13) or 1/(1 + lo) (masking); 0 when li or lo
/// is infinite (below the mesosurface) or not a number. The erfc form of Lambda can round
/// to a tiny negative value for large nu (cancellation): negatives count as 0.
inline double leadr_shadowing(double lo, double li, LeadrShadowing mode) {
    if (std::isnan(lo) || std::isnan(li) || std::isinf(lo) || std::isinf(li)) return 0.0;
    lo = std::max(lo, 0.0), li = std::max(li, 0.0);
    return mode == LeadrShadowing::Joint ? 1.0 / (1.0 + lo + li) : 1.0 / (1.0 + lo);
}

/// Paper: Algorithm 2 as published; Shadowed: per-point shadowed projection; Gaussian: paper 001
/// §5.3, the unshadowed irradiance map as a slope colour map filtered with the Gaussian
/// visible-slope distribution (filter/transfer_filter.h): rho / pi <E, D_s>.
enum class LeadrIrradiance { Paper, Shadowed, Gaussian };

/// Options shared by the environment quadratures.
struct LeadrEnvOptions {
    int n = 8;                                  ///< grid size N (1..128)
    LeadrShadowing shadowing = LeadrShadowing::Joint;
    bool rational_lambda = false;
    LeadrIrradiance irradiance = LeadrIrradiance::Shadowed;  ///< diffuse only
    bool prefilter = true;                      ///< specular: false reads level 0 (for tests)
};

/// Algorithm 1 / eq. (22): outgoing radiance towards wo (local, z = w_g) of specular LEADR
/// microfacets lit by `env`; `frame` maps local to world; fresnel(cos) is F at the micro-
/// normal (times any reflectance). 0 when wo is at or below the macro- or mesosurface.
Spectrum leadr_env_specular(const GaussianSlopes &g, const Vec3 &wo, const Frame &frame,
                            const std::function<Spectrum(float)> &fresnel, const PrefilteredEnvironment &env,
                            const LeadrEnvOptions &opt);
/// Algorithms 2-3 / eq. (21), (23): outgoing radiance of diffuse LEADR microfacets with
/// albedo rho.
Spectrum leadr_env_diffuse(const GaussianSlopes &g, const Vec3 &wo, const Frame &frame, const Spectrum &rho,
                           const PrefilteredEnvironment &env, const LeadrEnvOptions &opt);

}  // namespace meso
