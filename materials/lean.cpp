// `lean`: LEAN mapping (Olano & Baker 2010; paper 003 part 2, "Mechanics of LEAN Mapping"):
// a Gaussian slope distribution with mean and full (anisotropic, correlated) covariance,
// read from the first and second slope moments of a height map filtered at the
// ray-differential footprint (or given as constants), plus a Blinn-Phong base power s
// "added as 1/s along the X^2 and Y^2 terms" (paper 003): Sigma += diag(1/s, 1/s).
//
// Model (local frame: z = the macronormal; bsdf/gaussian_microfacet.h has the details)
//   f cos(theta_i) = F(wi . h) D(h) G1(wo) G1(wi) / (4 cos(theta_o)),  D = paper 000 eq. 10
//   G1(k) = min(1, cos(theta_k) / sigma(k)), sigma(k) = (n . k)/(n . z) (1 + Lambda(k))
//   Walter et al. 2007 microfacet reflection with separable Smith masking, as in J. Dupuy's
//   LEAN reference (dj_brdf). Reciprocal; albedo <= 1 (proof in gaussian_microfacet.h).
//   Differs from `leadr` only in the masking term and the missing renormalisation: LEADR
//   uses 1/(1 + Lambda(wo) + Lambda(wi)) and divides by (n . wo)/(n . w_g).
//   Distribution at a point: mean (mx, my) and covariance (sxx, syy, sxy) from
//   SlopeSource::eval (texture-space moments mapped to the shading frame through dp/du,
//   dp/dv, paper 000 eq. 12), then sxx += b, syy += b with b = 1/s ("exponent") or
//   alpha^2 / 2 ("alpha"); neither given: b = 0 (the variance is regularised to >= 1e-8, so
//   a flat map without a base is a near-mirror). The 1/s base matches Blinn-Phong for large
//   s (Beckmann with alpha^2 = 2/s); for s < ~16 it responds differently (paper 003).
//   Sampling: micro-normals from D(m) m.z, reflected; pdf = D(h) h.z / (4 wo . h).
//
// Parameters
//   name                  type          default    notes
//   heightmap             object        -          displacement-style block (map, scale, offset, tiling):
//                                                  moments of its slopes at the footprint
//   filter                string        trilinear  trilinear | ewa | none (heightmap only)
//   max_anisotropy        float         8          ewa only
//   mean_slope            [x, y]        [0, 0]     constant mean slope (not with heightmap)
//   covariance            [xx, yy, xy]  [0, 0, 0]  constant slope covariance (not with heightmap)
//   exponent              float         -          Blinn-Phong base power s in (0, 1e7]: adds 1/s
//   alpha                 float         -          Beckmann base roughness in [0, 1000]: adds alpha^2/2 (not with exponent)
//   material              string        none       conductor preset for F (Ag, Al, Au, Cr, Cu, Ni, W); none: F = 1
//   specular_reflectance  texture       1          multiplies F
//   rational_lambda       bool          false      Walter's rational Lambda instead of the erfc form
#include "bsdf/gaussian_microfacet.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

SlopeGaussian lean_distribution(const SlopeGaussian &g, double base) {
    SlopeGaussian r = g;
    r.sxx += base;
    r.syy += base;
    return r;
}

MESO_REGISTER_MATERIAL("lean", "LEAN mapping: Gaussian slopes with mean and full covariance, separable Smith (paper 003)",
                       [](const Properties &p) -> std::shared_ptr<Material> {
                           return std::make_shared<GaussianMicrofacetMaterial>("lean", parse_gaussian_microfacet(p),
                                                                               lean_distribution);
                       });

}  // namespace
}  // namespace meso
