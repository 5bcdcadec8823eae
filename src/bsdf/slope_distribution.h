// Gaussian slope distributions (paper 000 §4.1, §4.3): the non-centred anisotropic Beckmann
// NDF shared by the LEAN and LEADR materials. Local frame: z = the macronormal w_g.
//
//   P22(s) = exp(-(s - mean)^T Sigma^-1 (s - mean) / 2) / (2 pi sqrt|Sigma|)        (eq. 8)
//   D(m)   = P22(-m.x / m.z, -m.y / m.z) / m.z^4,  int D(m) m.z dm = 1              (eq. 10)
//   mesonormal = (-E[x], -E[y], 1) / sqrt(1 + E[x]^2 + E[y]^2)                         (eq. 11)
//   Lambda(w): nu = (cot theta - mu(phi)) / (sigma(phi) sqrt 2) with mu, sigma^2 the mean and
//   variance of the slope along w's azimuth (eq. 14-15), then the centred Smith form
//   exp(-nu^2) / (2 nu sqrt pi) - erfc(nu) / 2, or Walter et al.'s rational approximation
//   (1 - 1.259 nu + 0.396 nu^2) / (3.535 nu + 2.181 nu^2) for nu < 1.6, 0 above. nu <= 0
//   (w below the mesosurface) gives +infinity: fully shadowed.
//
// Note: for a non-zero mean, the paper's Lambda shifts nu by the mean slope but keeps the
// centred prefactor; the exact Smith integral tan(theta) int_{cot theta} (x - cot theta)
// P2(x) dx (lambda_smith()) differs from it by the factor (cot theta - mu) / cot theta.
// The paper's form is the consistent one with its renormalisation: int D(m) <m, wo> dm =
// (n_meso . wo) / (n_meso . w_g) (1 + lambda(wo)) holds for it (tested), so eq. (16)
// integrates to one; lambda_smith() is kept for comparison only.
//
// Degenerate covariances are regularised: variances at least `min_variance`, and the
// correlation clamped to |rho| <= 1 - 1e-6, so Sigma is always invertible.
#pragma once
#include "core/vec.h"
#include "texture/slope_moments.h"

namespace meso {

class GaussianSlopes {
public:
    explicit GaussianSlopes(const SlopeGaussian &g, double min_variance = 1e-8);

    double p22(double x, double y) const;
    /// Eq. (10) for a unit micro-normal m; 0 for m.z <= 0.
    double D(Vec3 m) const;
    Vec3 mesonormal() const;
    /// Eq. (14-15) with the exact erfc form, or Walter's rational approximation.
    double lambda(Vec3 w, bool rational = false) const;
    /// The exact Smith integral for a non-centred Gaussian (see the note above).
    double lambda_smith(Vec3 w) const;
    /// A micro-normal with density D(m) m.z (slopes drawn from P22 by Cholesky).
    Vec3 sample_normal(Vec2 u) const;
    double pdf_normal(Vec3 m) const { return m.z > 0.f ? D(m) * m.z : 0.0; }

    const SlopeGaussian &params() const { return m_g; }

private:
    /// nu of eq. (14-15) for direction w and the slope-variance sigma along its azimuth.
    bool nu_of(Vec3 w, double &nu, double &sigma, double &cot_theta, double &mu) const;
    SlopeGaussian m_g;                  ///< regularised
    double m_inv[3] = {0, 0, 0};        ///< Sigma^-1: xx, yy, xy
    double m_norm = 0;                  ///< 1 / (2 pi sqrt|Sigma|)
    double m_l00 = 0, m_l10 = 0, m_l11 = 0;  ///< Cholesky factor of Sigma
};

}  // namespace meso
