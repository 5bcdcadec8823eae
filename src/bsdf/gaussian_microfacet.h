// Microfacet reflection for a Gaussian slope distribution (non-centred, anisotropic,
// correlated) with SEPARABLE Smith masking: the BRDF of the `lean` and `clean` materials
// (Olano & Baker 2010; paper 003 part 2), in the form of J. Dupuy's LEAN reference
// implementation (dj_brdf). Local frame: z = the macronormal w_g; D and Lambda are those of
// bsdf/slope_distribution.h (paper 000 eq. 10, 14-15).
//
//   f(wo, wi) cos(theta_i) = F(wi . h) D(h) G1(wo) G1(wi) / (4 cos(theta_o)),  h = normalize(wo + wi)
//   G1(k) = min(1, cos(theta_k) / sigma(k)),   sigma(k) = (n . k) / (n . z) (1 + Lambda(k))
//
// with n the mesonormal (paper 000 eq. 11); sigma(k) is the projected area of the
// microsurface seen from k (int D(m) <m, k>+ dm = sigma(k), tested in
// test_slope_distribution.cpp). (n . k) / (n . z) = k.z - mx k.x - my k.y exactly, so it is
// formed from the slopes in double precision. k below the mesosurface (n . k <= 0, where
// Lambda = +inf) gives G1 = 0: fully masked / shadowed.
//
// Why the min(1, .): for a tilted mean, sigma(k) can be smaller than cos(theta_k) (a
// mesosurface facing k shows more than its macro footprint), so the plain Smith G1 would
// exceed 1. With the clamp, for every wo (F <= 1):
//   int f cos(theta_i) dwi = G1(wo) / cos(theta_o) int D(h) G1(wi) / 4 dwi
//                         <= max G1(wi) * G1(wo) / cos(theta_o) int D(h) (wo . h)+ dh   (dwi = 4 (wo . h) dh)
//                         <= 1 * min(1, cos(theta_o) / sigma(wo)) sigma(wo) / cos(theta_o) <= 1.
// (With Walter's rational Lambda the identity int D <m, k>+ = sigma(k) holds only up to the
// approximation's error, so the bound holds to that accuracy.)
//
// Difference from LEADR (materials/leadr.cpp, paper 000 eq. 16-17): LEADR uses the joint
// (height-correlated) 1 / (1 + Lambda(wo) + Lambda(wi)) and renormalises by
// (n . w_g) / (n . wo), which makes it integrate to one but depend on wo alone (not
// reciprocal). This form is symmetric in (wo, wi), hence reciprocal, and loses energy to
// masking like any Smith microfacet BRDF.
//
// Sampling: micro-normals m from D(m) m.z (slopes from P22 by Cholesky), wi = reflect(wo, m);
// pdf(wi) = D(h) h.z / (4 wo . h). sample() fails (and pdf() is 0) where the value is 0 by
// construction: wo or wi at or below the macrosurface or below the mesosurface, wo . m <= 0.
#pragma once
#include <memory>
#include <string>
#include "core/spectrum.h"
#include "core/vec.h"
#include "bsdf/material.h"
#include "bsdf/slope_distribution.h"
#include "texture/slope_source.h"

namespace meso {

class Properties;
class Texture;

class GaussianMicrofacet {
public:
    /// `g` is regularised by GaussianSlopes (variances >= min_variance, |rho| < 1).
    explicit GaussianMicrofacet(const SlopeGaussian &g, bool rational_lambda = false, double min_variance = 1e-8);

    const GaussianSlopes &slopes() const { return m_slopes; }
    /// (n . k) / (n . z) = k.z - mx k.x - my k.y (double precision).
    double meso_cos(const Vec3 &k) const;
    /// True when k is above the macrosurface and the mesosurface with a finite Lambda.
    bool visible(const Vec3 &k) const;
    /// sigma(k) = (n . k) / (n . z) (1 + Lambda(k)); 0 where !visible(k).
    double projected_area(const Vec3 &k) const;
    /// min(1, cos(theta_k) / sigma(k)); 0 where !visible(k).
    double G1(const Vec3 &k) const;
    /// f cos(theta_i) without Fresnel.
    double eval(const Vec3 &wo, const Vec3 &wi) const;
    /// Solid-angle density of sample().
    double pdf(const Vec3 &wo, const Vec3 &wi) const;
    /// Draws wi; false when the sample is unusable (see above).
    bool sample(const Vec3 &wo, Vec2 u, Vec3 &wi) const;

private:
    GaussianSlopes m_slopes;
    bool m_rational;
};

/// The scene parameters `lean` and `clean` share (materials/lean.cpp has the table).
struct GaussianMicrofacetParams {
    SlopeSource source;
    double base_variance = 0.0;  ///< 1/s (exponent) or alpha^2 / 2, added to both variances
    std::string base_desc;       ///< "exponent 100", "alpha 0.3" or "no base"
    Spectrum eta = Spectrum(0.f), k = Spectrum(1.f);  ///< conductor IOR (none: F = 1)
    std::string conductor = "none";
    std::shared_ptr<Texture> specular;
    bool rational = false;
};
GaussianMicrofacetParams parse_gaussian_microfacet(const Properties &p);

/// A material on GaussianMicrofacet whose slope distribution at a shading point is
/// `transform(source.eval(ctx), base_variance)` (LEAN: full covariance; CLEAN: isotropic).
/// Precomputed once when the source is constant.
class GaussianMicrofacetMaterial final : public Material {
public:
    using Transform = SlopeGaussian (*)(const SlopeGaussian &g, double base_variance);
    GaussianMicrofacetMaterial(std::string name, GaussianMicrofacetParams params, Transform transform);

    Spectrum eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override;
    float pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override;
    bool sample(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, BSDFSample &out) const override;
    uint32_t flags() const override { return BSDF_GlossyReflection; }
    Spectrum albedo_hint(const ShadingContext &ctx) const override;
    bool is_reciprocal() const override { return true; }
    std::string to_string() const override;

    /// The distribution used at ctx (after the transform and base roughness).
    SlopeGaussian distribution(const ShadingContext &ctx) const;

private:
    GaussianMicrofacet at(const ShadingContext &ctx) const;
    Spectrum fresnel(const ShadingContext &ctx, float cos_i) const;

    std::string m_name;
    GaussianMicrofacetParams m_p;
    Transform m_transform;
    std::unique_ptr<GaussianMicrofacet> m_const;  ///< when the source is constant
};

}  // namespace meso
