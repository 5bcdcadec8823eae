// Gaussian slope statistics (paper 000 eq. 8-12): the slope-moment channel order of moment maps,
// the tangent-frame slope Gaussian, and the uv-to-tangent distortion. Shared by the moment
// textures (texture/slope_moments.h), the transfer filters and the Gaussian microfacet BSDFs.
#pragma once

namespace meso {

enum SlopeMoment { MomentX = 0, MomentY = 1, MomentXX = 2, MomentYY = 3, MomentXY = 4, SlopeMomentCount = 5 };

/// A Gaussian slope distribution in the macrosurface's tangent frame (paper 000 eq. 8-9):
/// mean slope (mx, my) and covariance [[sxx, sxy], [sxy, syy]].
struct SlopeGaussian {
    double mx = 0, my = 0, sxx = 0, syy = 0, sxy = 0;
};

/// Paper 000 eq. (9) and (12): filtered texture-space moments `m` (SlopeMoment order) to the
/// tangent-frame distribution, through the mapping distortion J = [[du/dx, dv/dx],
/// [du/dy, dv/dy]] (x, y: tangent-frame coordinates on the macrosurface), height scaling
/// `eta` (first moments times eta, second times eta^2) and a base roughness variance added
/// to both diagonal terms (LEAN's 1/s). Variances below zero (float round-off of
/// E[x^2] - E[x]^2) are clamped to 0; nothing else is regularised here.
SlopeGaussian slope_gaussian(const float m[SlopeMomentCount], double dudx, double dvdx, double dudy, double dvdy,
                             double eta = 1.0, double base_variance = 0.0);

/// The distortion J of slope_gaussian from the surface's dp/du, dp/dv and an orthonormal
/// tangent frame (t, b): the inverse of [[dpdu.t, dpdv.t], [dpdu.b, dpdv.b]]. False (and
/// zeros) for a degenerate parameterisation.
bool uv_per_tangent(const double dpdu[3], const double dpdv[3], const double t[3], const double b[3], double &dudx,
                    double &dvdx, double &dudy, double &dvdy);

}  // namespace meso
