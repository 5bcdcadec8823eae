// Light interface. sample() returns incident radiance and the solid-angle pdf of the
// sampled direction as seen from the reference point; pdf() returns that same density
// for a direction that BSDF sampling found (for multiple importance sampling).
#pragma once
#include <memory>
#include <string>
#include "core/spectrum.h"
#include "core/vec.h"

namespace meso {

class Shape;

/// Reference point for light sampling.
struct LightSampleContext {
    Vec3 p;   ///< world position of the shading point
    Vec3 n;   ///< geometric normal there (zero if none); may be used to cull
    /// The caller reads the sample's radiance through Light::sampled_radiance(), after its shadow
    /// ray: a light may then leave LightSample::L for later (L_deferred) and only prefetch the
    /// data it needs, so that the miss overlaps the ray (the environment map's texels).
    bool defer_radiance = false;
};

struct LightSample {
    Vec3 wi;              ///< unit direction from p towards the light
    float dist = Infinity;///< distance to the sampled point (Infinity for infinite lights)
    Spectrum L;           ///< radiance (or intensity / dist^2 for point lights) arriving at p
    float pdf = 0.f;      ///< solid-angle pdf (1 for delta lights)
    bool delta = false;   ///< point, spot, directional
    bool L_deferred = false;  ///< L not set: Light::sampled_radiance() returns it (at uv)
    Vec2 uv{};                ///< where a light that deferred L reads it
};

/// The information pdf()/eval need about a point found on an area light by a ray.
struct LightHit {
    Vec3 p;          ///< hit point on the emitter
    Vec3 n;          ///< geometric normal at the hit point
    uint32_t prim = 0;  ///< primitive (triangle) index within the shape
    Vec2 uv{};          ///< texture coordinates of the hit (textured emitters read them)
};

class Light {
public:
    virtual ~Light() = default;
    /// Called once the scene is built; bounds of everything (infinite lights need them).
    virtual void preprocess(Vec3 scene_center, float scene_radius) { (void)scene_center; (void)scene_radius; }
    virtual bool sample(const LightSampleContext &ctx, Vec2 u, LightSample &out) const = 0;
    /// The radiance of a sample (out.L, or its deferred value: see defer_radiance).
    virtual Spectrum sampled_radiance(const LightSample &ls) const { return ls.L; }
    /// Solid-angle pdf that sample() would produce direction wi (towards `hit` for area
    /// lights; `hit` is ignored for infinite lights).
    virtual float pdf(const LightSampleContext &ctx, const Vec3 &wi, const LightHit &hit) const = 0;
    /// Radiance leaving an area light at `hit` towards -w (w points from the emitter to the
    /// viewer... i.e. w = -ray.d), or arriving from direction -ray.d for infinite lights.
    virtual Spectrum eval(const LightHit &hit, const Vec3 &w) const = 0;
    /// eval(hit, w) and, when `pdf` is not null, pdf(ctx, -w, hit) into *pdf: the same values as
    /// the two calls (an environment map shares the direction's lookup between them).
    virtual Spectrum eval_pdf(const LightSampleContext &ctx, const LightHit &hit, const Vec3 &w, float *pdf) const {
        if (pdf) *pdf = this->pdf(ctx, -w, hit);
        return eval(hit, w);
    }
    virtual bool is_delta() const { return false; }
    virtual bool is_infinite() const { return false; }
    /// Total emitted power estimate (used to choose lights in proportion to power).
    virtual float power() const = 0;
    virtual std::string to_string() const = 0;
    /// Area lights are bound to a shape by the scene loader.
    virtual void set_shape(const Shape *shape) { (void)shape; }
};

/// Base of lights that occupy no solid angle (point, spot, directional): BSDF sampling can
/// never hit them, so pdf() and eval() are 0 and they are sampled with pdf 1.
class DeltaLight : public Light {
public:
    float pdf(const LightSampleContext &, const Vec3 &, const LightHit &) const final { return 0.f; }
    Spectrum eval(const LightHit &, const Vec3 &) const final { return Spectrum(0.f); }
    bool is_delta() const final { return true; }
};

}  // namespace meso
