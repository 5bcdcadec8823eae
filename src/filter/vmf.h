// von Mises-Fisher (vMF) lobes on the unit sphere S² and their characteristic vectors
// (paper 002, Xu et al. 2017, §3; shared by the `vmf` material and the prefiltered SVNDF of
// paper 004, whose lobes have the same definition, paper 004 eq. 4).
//
//   γ(ω; μ, κ) = κ / (4π sinh κ) · exp(κ μ·ω),      ∫_{S²} γ dω = 1           (paper 002 eq. 6)
//
// Numerics. The density is evaluated as
//   γ = κ / (2π (1 − e^{−2κ})) · exp(κ (μ·ω − 1)) = κ / (2π · (−expm1(−2κ))) · exp(κ (μ·ω − 1)),
// which is exact for every κ ≥ 0: no overflow of sinh for large κ, no 0/0 for small κ
// (κ / −expm1(−2κ) → 1/2 as κ → 0, so κ = 0 is the uniform density 1/(4π)). The large-κ
// form of eq. 7, κ/(2π) exp(κ(μ·ω − 1)) (eq. 7 as printed has a misplaced parenthesis),
// differs from it by the factor 1 − e^{−2κ}: a relative error e^{−2κ}, below double
// rounding (1.1e-16) for κ > 18.4 — so the exact form is used everywhere and eq. 7 is
// only what it reduces to (tested).
//
// Sampling (W. Jakob, "Numerically stable sampling of the von Mises Fisher distribution on
// S²", 2012): w = μ·ω = 1 + log(u + (1 − u) e^{−2κ}) / κ, written
//   1 − w = −log1p((1 − u) · expm1(−2κ)) / κ
// so that 1 − w (and sin θ = sqrt((1 − w)(1 + w))) has no cancellation at large κ and the
// small-κ limit (w = 2u − 1, uniform) is reached continuously.
//
// Characteristic vectors (eq. 8–9): a lobe is represented by r = ‖r‖ μ with
//   κ = (3‖r‖ − ‖r‖³) / (1 − ‖r‖²)      (Banerjee et al.'s approximation of A₃⁻¹)
// and averages of lobes by averages of r (eq. 10). For a given κ, ‖r‖ is the root in [0, 1)
// of the cubic ‖r‖³ − κ‖r‖² − 3‖r‖ + κ = 0 (the other two roots are < 0 and > 1 for every
// κ > 0, see r_from_kappa). In terms of e = 1 − ‖r‖ the cubic reads
//   g(e) = κ e (2 − e) − (1 − e)(2 + 2e − e²) = 0,   g(0) = −2 < 0,  g(1) = κ > 0,
//   g'(e) = 2κ(1 − e) + 3e(2 − e) > 0 on (0, 1),
// so the valid root is unique; it is computed in closed form (Viète's trigonometric
// solution) and polished by safeguarded Newton steps on g(e), which keeps full relative
// precision in e = 1 − ‖r‖ ~ 1/κ where the closed form cancels (κ ≫ 1).
#pragma once
#include <array>
#include "core/vec.h"

namespace meso {
namespace vmf {

/// Largest concentration the material code produces (‖r‖ → 1 maps here; finite densities
/// up to ~1.6e8 and half-vector spreads of ~3e-5 rad, far below any pixel).
constexpr double kMaxKappa = 1e9;

/// log of the normalisation κ / (4π sinh κ), finite for every κ ≥ 0.
double log_norm(double kappa);
/// The density γ at cos_angle = μ·ω (exact form above).
double pdf_cos(double kappa, double cos_angle);
/// The density at direction w for mean direction mu. Both are renormalised in double: a
/// float unit vector is off by up to ~6e-8 in length, which would scale the density by
/// e^{±6e-8 κ} (3e-4 at κ = 1e4) and break its normalisation.
double pdf(Vec3 mu, double kappa, Vec3 w);
/// Eq. 7 (large-κ form), for comparison only.
double pdf_cos_large_kappa(double kappa, double cos_angle);

/// Samples w = μ·ω for uniform u in [0, 1); also returns 1 − w without cancellation.
double sample_cos(double kappa, double u, double *one_minus_w = nullptr);
/// Samples a direction around the unit mean direction mu.
Vec3 sample(Vec3 mu, double kappa, Vec2 u);

/// κ of the characteristic vector length (eq. 8); r is clamped to [0, 1) and κ to kMaxKappa.
double kappa_from_r(double r_length);
/// The valid root ‖r‖ in [0, 1) of the cubic (eq. 9), to double precision.
double r_from_kappa(double kappa);
/// The closed-form (Viète) root alone, before the Newton polish (for tests).
double r_from_kappa_closed_form(double kappa);

/// The paper's 1024-entry lookup table of ‖r‖(κ) (§4), with linear interpolation. The
/// table is indexed by t = κ / (κ + 3) ∈ [0, 1] (uniform in t), which makes 1 − ‖r‖ ≈ 1/κ
/// linear in (1 − t) near t = 1, so the table is accurate for all κ in [0, ∞).
class RTable {
public:
    static constexpr int kSize = 1024;
    RTable();
    double lookup(double kappa) const;
    /// The process-wide table.
    static const RTable &get();

private:
    std::array<double, kSize> m_r;
};

/// Concentration of the convolution of two lobes (κ_a κ_b / (κ_a + κ_b), the Blinn-Phong
/// form of paper 002 eq. 13 and Han et al. 2007); infinite inputs mean "a delta".
double convolve_kappa(double ka, double kb);

/// The mean resultant length A₃(κ) = coth κ − 1/κ of a vMF (exact E[μ·ω]), stable for all κ.
double mean_cosine(double kappa);

}  // namespace vmf
}  // namespace meso
