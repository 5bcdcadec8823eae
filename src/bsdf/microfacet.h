// Microfacet normal distributions (Beckmann, GGX/Trowbridge-Reitz; anisotropic) with
// Smith masking-shadowing and importance sampling, shared by every microfacet material.
//
//  * D(m): NDF normalised so that  ∫ D(m) m.z dm = 1  (Walter et al. 2007, eq. 33/34
//    in the anisotropic form of Heitz 2014 "Understanding the masking-shadowing function",
//    eq. 71/84).
//  * Lambda(w): Smith's Λ (Heitz 2014 eq. 72/86); G1 = χ+(w·m / w.z) / (1 + Λ(w)).
//  * G(wo, wi, m): the HEIGHT-CORRELATED Smith masking-shadowing (Heitz 2014 §6.2,
//    eq. 99 for reflection: 1/(1 + Λ(wo) + Λ(wi)); eq. 101 for transmission:
//    B(1 + Λ(wo), 1 + Λ(wi)), B the Beta function). Chosen over the separable G1·G1
//    (Mitsuba's choice) because it is exact for the Smith microsurface whenever heights
//    and slopes are uncorrelated, is never below the separable form (less spurious
//    darkening at grazing angles), and remains symmetric in (wo, wi), so reciprocity
//    holds exactly.
//  * sample(wo, u): visible normals D_wo(m) = G1(wo,m) max(0, wo·m) D(m) / wo.z
//    (Heitz 2018 "Sampling the GGX distribution of visible normals" for GGX;
//    Heitz & d'Eon 2014 slope sampling with pbrt-v3's numerically inverted CDF for
//    Beckmann, here solved in double precision to 1e-13 so that pdf() is exact),
//    or the full NDF  D(m) m.z  when sample_visible is false.
//
// All directions are in the local frame; Λ and G1 use |w.z| (the distribution is the
// same seen from either side), sample/pdf expect wo in the upper hemisphere (callers
// mirror it) and return m in the upper hemisphere.
//
// Numerics: roughness below kMinAlpha (1e-4) is treated by the materials as a smooth
// (delta) interface; rough lobes clamp each alpha to >= 1e-4. Everything is evaluated in
// double internally; results are finite for alpha in [1e-4, 1e3] and any direction,
// including exactly grazing ones (G1 -> 0).
#pragma once
#include <optional>
#include <string>
#include <vector>
#include "core/vec.h"

namespace meso {

class Properties;

enum class MicrofacetType { Beckmann, GGX };

class MicrofacetDistribution {
public:
    /// Below this, materials switch to their smooth (delta) variant.
    static constexpr float kMinAlpha = 1e-4f;

    MicrofacetDistribution(MicrofacetType type, float alpha_u, float alpha_v, bool sample_visible = true);

    MicrofacetType type() const { return m_type; }
    float alpha_u() const { return m_alpha_u; }
    float alpha_v() const { return m_alpha_v; }
    bool sample_visible() const { return m_sample_visible; }
    bool is_isotropic() const { return m_alpha_u == m_alpha_v; }

    /// Normal distribution D(m); 0 for m.z <= 0.
    float D(const Vec3 &m) const;
    /// Smith Λ(w) (uses |w.z|; +inf at w.z = 0).
    double lambda(const Vec3 &w) const;
    /// Smith G1 = χ+(w·m · w.z) / (1 + Λ(w)).
    float G1(const Vec3 &w, const Vec3 &m) const;
    /// Height-correlated masking-shadowing; reflection when wo.z * wi.z > 0, else
    /// transmission. Includes the χ+ side conditions for both directions.
    float G(const Vec3 &wo, const Vec3 &wi, const Vec3 &m) const;
    /// G with Λ(wo) given (lambda(wo)): the same value, for callers that hold one wo for many wi.
    float G(const Vec3 &wo, const Vec3 &wi, const Vec3 &m, double lambda_wo) const;

    /// D(m[k]) and Λ(w[k]) for k < n, two lanes at a time (the prefilter's next-event splat
    /// evaluates one wo against 225 ωi a vertex). e^x is core/f64_lanes.h's (within a few ulp of
    /// libm); Beckmann's erfc is a rational approximation with a relative error below 1.2e-7
    /// (Numerical Recipes' erfcc), so Λ is within 1.2e-7 · erfc(a) of lambda() and G within a
    /// float ulp or two; D is D()'s to a float ulp. Same degenerate cases as D() and lambda().
    void D_lambda_batch(const Vec3 *m, const Vec3 *w, int n, float *D, double *lambda) const;

    /// Density of the microfacet normals that sample() produces (solid angle of m);
    /// wo must be in the upper hemisphere.
    float pdf(const Vec3 &wo, const Vec3 &m) const;
    /// Samples a microfacet normal m (upper hemisphere) for wo in the upper hemisphere.
    /// Writes its density to *pdf (0 if the sample is unusable).
    Vec3 sample(const Vec3 &wo, Vec2 u, float *pdf) const;

    std::string to_string() const;

private:
    Vec3 sample_visible_ggx(const Vec3 &wo, Vec2 u) const;
    Vec3 sample_visible_beckmann(const Vec3 &wo, Vec2 u) const;
    Vec3 sample_full(Vec2 u) const;

    MicrofacetType m_type;
    float m_alpha_u, m_alpha_v;
    bool m_sample_visible;
};

/// Reads the shared microfacet parameters of a material:
///   distribution   string  "ggx"   "ggx" | "beckmann"
///   alpha          float   default_alpha   isotropic roughness (RMS slope), >= 0
///   alpha_u/alpha_v float  —        anisotropic roughness along s / t (both required,
///                                   only when allow_anisotropic; excludes "alpha")
///   sample_visible bool    true     sample visible normals instead of the full NDF
/// Returns nullopt for a smooth interface (all alphas < kMinAlpha); otherwise alphas are
/// clamped to >= kMinAlpha. Errors are located (file: path.key: message).
std::optional<MicrofacetDistribution> microfacet_from_properties(const Properties &props, bool allow_anisotropic,
                                                                 float default_alpha);

/// Inverse error function in double precision (|x| < 1; ±inf at ±1).
double erfinv(double x);

/// Exact Smith Λ of the normalised Blinn-Phong NDF D(m) = (s+2)/(2π) cos^s θm for a
/// direction with cos θ = cos_theta, from the projected-area identity that defines it
/// (Heitz 2014, eq. 17/72):  1 + Λ(w) = ∫ max(0, w·m) D(m) dm / cos θ, i.e.
///   Λ(w) = (1/cos θ) ∫ max(0, −w·m) D(m) dm,
/// whose azimuthal integral is closed-form, 2[√(a² − b²) − b acos(b/a)] with
/// a = sin θ sin θm, b = cos θ cos θm; the remaining θm integral runs over the back-facing
/// band [π/2 − θ, min(π/2, 8α)] (α = √(2/(s+2)): beyond 8α, cos^s θm < e^-64) and is done
/// by 32-point Gauss-Legendre after θm = θc + L t² (removes the square-root edge).
/// Tends to the Beckmann Λ at α = √(2/(s+2)) for large s; at small s the Beckmann
/// stand-in underestimates Λ (×0.5 at s = 0, θ = 85°) and breaks energy conservation.
double blinnphong_lambda(double exponent, double cos_theta);

/// blinnphong_lambda for one fixed exponent, tabulated (512 nodes, linear in
/// x = a/(1+a), a = cot θ / α, storing Λ·a): error of 1 + Λ (hence of G1) < 1e-4,
/// ~30x faster.
class BlinnPhongLambdaTable {
public:
    explicit BlinnPhongLambdaTable(double exponent);
    double operator()(double cos_theta) const;

private:
    double m_alpha;
    std::vector<double> m_y;
};

/// One direction of a glossy-over-diffuse mixture (plastic, gltf_pbr): with u_lobe < p_glossy the
/// reflection of wo about a normal sampled from `dist` (flags BSDF_GlossyReflection), otherwise a
/// cosine-weighted direction (BSDF_DiffuseReflection). False when no direction above the surface
/// came out; the caller computes the mixture pdf and weight at the returned wi.
bool sample_glossy_or_diffuse(const MicrofacetDistribution &dist, const Vec3 &wo, float u_lobe, float p_glossy,
                              Vec2 u, Vec3 &wi, uint32_t &flags);

}  // namespace meso
