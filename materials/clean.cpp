// `clean`: CLEAN mapping (paper 003 part 2, "CLEAN mapping": "5 values can be expensive:
// alternative, lose anisotropy"): LEAN with an isotropic covariance. CLEAN stores three
// channels, X, Y and M = (X^2 + Y^2)/2, filtered linearly; the slide's covariance matrix is
// garbled in the text, the consistent reading is the isotropic variance
//   sigma^2 = M - (X̄^2 + Ȳ^2)/2 = (Var X + Var Y)/2 = (sxx + syy)/2,
// i.e. half the trace of LEAN's covariance, with no correlation. Half the trace is
// invariant under rotations of the tangent frame, so taking it after SlopeSource has mapped
// the moments to the shading frame (dp/du, dp/dv) is the same as in texture space for a
// conformal parameterisation. Then the Blinn-Phong base 1/s (or alpha^2/2) is added.
//
// Model: exactly `lean` (materials/lean.cpp, bsdf/gaussian_microfacet.h) with
//   (sxx, syy, sxy) -> ((sxx + syy)/2 + b, (sxx + syy)/2 + b, 0),  mean unchanged.
// Equal to `lean` when the covariance is isotropic (tested), rounder highlights otherwise.
// Reciprocal; albedo <= 1.
//
// Parameters: the same as `lean`
//   heightmap | mean_slope + covariance, filter, max_anisotropy, exponent | alpha,
//   material, specular_reflectance, rational_lambda  (see materials/lean.cpp)
#include "bsdf/gaussian_microfacet.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

SlopeGaussian clean_distribution(const SlopeGaussian &g, double base) {
    SlopeGaussian r = g;
    const double iso = 0.5 * (g.sxx + g.syy);
    r.sxx = r.syy = iso + base;
    r.sxy = 0.0;
    return r;
}

MESO_REGISTER_MATERIAL("clean", "CLEAN mapping: LEAN with an isotropic slope variance, half the trace (paper 003)",
                       [](const Properties &p) -> std::shared_ptr<Material> {
                           return std::make_shared<GaussianMicrofacetMaterial>("clean", parse_gaussian_microfacet(p),
                                                                               clean_distribution);
                       });

}  // namespace
}  // namespace meso
