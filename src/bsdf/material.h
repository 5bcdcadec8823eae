// The material interface (one narrow contract for every BRDF/BSDF plugin).
//
//  * All directions are unit vectors in the LOCAL shading frame (z = normal) and point
//    away from the surface: wo towards the viewer, wi towards the light.
//  * eval(ctx, wo, wi) returns f(wo, wi) * |cos theta_i|  (the cosine is included).
//  * sample(ctx, wo, u_lobe, u) draws wi; weight = eval / pdf for non-delta lobes
//    (f * |cos| / pdf); pdf is the solid-angle density of the whole sampling strategy
//    (lobe choice included), equal to pdf(ctx, wo, wi).
//  * Delta lobes (perfect mirror / refraction) are flagged in BSDFSample::flags and
//    never evaluated: eval and pdf return 0 for them. Their sample() returns
//    pdf = probability of having chosen that lobe (discrete), weight = value / that prob.
//  * Reflection-only materials return 0 when wo.z <= 0 or wi.z <= 0; the integrator
//    makes non-transmissive surfaces two-sided by flipping the frame towards wo.
//  * The one exception to "sample's pdf = pdf()": where the integrator sets
//    ShadingContext::u_eval >= 0, a material with a stochastic evaluation (`prefiltered`,
//    "estimator": "stochastic") returns from eval_pdf and sample unbiased estimates of f and
//    f / pdf with the pdf of one sub-strategy (shading.h). eval and pdf stay exact, and without
//    u_eval (meso material, χ² tests, the prefilter tools) everything is exact.
#pragma once
#include <memory>
#include <string>
#include "core/vec.h"
#include "geometry/shading.h"
#include "texture/texture.h"

namespace meso {

class PrefilteredEnvironment;  // lights/prefiltered_environment.h

enum BSDFFlags : uint32_t {
    BSDF_None = 0,
    BSDF_DiffuseReflection = 1u << 0,
    BSDF_GlossyReflection = 1u << 1,
    BSDF_DeltaReflection = 1u << 2,
    BSDF_DiffuseTransmission = 1u << 3,
    BSDF_GlossyTransmission = 1u << 4,
    BSDF_DeltaTransmission = 1u << 5,
    BSDF_Reflection = BSDF_DiffuseReflection | BSDF_GlossyReflection | BSDF_DeltaReflection,
    BSDF_Transmission = BSDF_DiffuseTransmission | BSDF_GlossyTransmission | BSDF_DeltaTransmission,
    BSDF_Delta = BSDF_DeltaReflection | BSDF_DeltaTransmission,
    BSDF_Smooth = BSDF_DiffuseReflection | BSDF_GlossyReflection | BSDF_DiffuseTransmission | BSDF_GlossyTransmission,
};

struct BSDFSample {
    Vec3 wi;                  ///< sampled direction (local frame)
    Spectrum weight;          ///< f * |cos theta_i| / pdf
    float pdf = 0.f;          ///< solid-angle pdf (discrete lobe probability for delta lobes)
    float eta = 1.f;          ///< relative IOR crossed (1 for reflection)
    uint32_t flags = 0;       ///< the lobe that was sampled (one BSDFFlags bit)
};

/// Whether any of `textures` varies over the surface (a non-constant texture may filter by the
/// footprint): the usual Material::uses_footprint of a material whose parameters are textures.
inline bool any_varies(std::initializer_list<const Texture *> textures) {
    for (const Texture *t : textures)
        if (t && !t->is_constant()) return true;
    return false;
}

class Material {
public:
    virtual ~Material() = default;
    virtual Spectrum eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const = 0;
    virtual float pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const = 0;
    /// Returns false when no direction could be sampled (the path ends).
    virtual bool sample(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u,
                        BSDFSample &out) const = 0;
    /// eval and, when `pdf` is not null, pdf(ctx, wo, wi) into *pdf: the same values as the two
    /// calls (materials whose two passes share work, e.g. node sums, override it).
    virtual Spectrum eval_pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi, float *pdf) const {
        if (pdf) *pdf = this->pdf(ctx, wo, wi);
        return eval(ctx, wo, wi);
    }
    /// eval at n directions wi[0 .. n) seen from one wo: out[k] = eval(ctx, wo, wi[k]), the same
    /// values. Materials override it to share their wo side (the prefilter's next-event splat sends
    /// every path vertex towards all its ωi bins).
    virtual void eval_batch(const ShadingContext &ctx, const Vec3 &wo, const Vec3 *wi, int n, Spectrum *out) const {
        for (int k = 0; k < n; ++k) out[k] = eval(ctx, wo, wi[k]);
    }
    /// Union of the lobes this material can have.
    virtual uint32_t flags() const = 0;
    /// Approximate albedo for the `aov` integrator's albedo channel.
    virtual Spectrum albedo_hint(const ShadingContext &ctx) const { (void)ctx; return Spectrum(0.5f); }
    /// Whether f(wo,wi) = f(wi,wo) (the test battery checks it where true).
    virtual bool is_reciprocal() const { return true; }
    /// Whether shading reads the ray-differential footprint (ShadingContext's du/dv, filtered
    /// textures, NDF filtering). Integrators skip computing differentials when no material of
    /// the scene does (pay only for what is used); the default is the safe answer.
    virtual bool uses_footprint() const { return true; }

    /// Optional capability, environment quadrature: a material that can integrate a whole
    /// unoccluded environment at a point by itself (`leadr`, paper 000 Algorithms 1-3) says so
    /// here and returns in env_radiance the radiance leaving towards wo (local frame of ctx)
    /// due to `env`. Integrators that enable it (`path` with leadr_env_quadrature) then skip
    /// environment NEE and escaped BSDF rays at such points.
    virtual bool has_env_quadrature() const { return false; }
    virtual Spectrum env_radiance(const ShadingContext &ctx, const Vec3 &wo, const PrefilteredEnvironment &env) const {
        (void)ctx, (void)wo, (void)env;
        return Spectrum(0.f);
    }
    virtual std::string to_string() const = 0;

    bool has_transmission() const { return flags() & BSDF_Transmission; }
    bool is_delta_only() const { return (flags() & BSDF_Smooth) == 0; }
};

}  // namespace meso
