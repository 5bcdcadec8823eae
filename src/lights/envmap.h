// Image-based environment light (lat-long map), exposed so that tests and other modules
// (e.g. quadrature over the environment) can build one from an in-memory image and look
// up radiance by direction. Scene files create it as {"type": "envmap"}; see envmap.cpp
// for the model, the mapping convention and the parameters.
#pragma once
#include <string>
#include "core/transform.h"
#include "image/image.h"
#include "lights/light.h"
#include "sampling/distribution.h"

namespace meso {

class EnvMapLight final : public Light {
public:
    /// `img`: linear radiance, 1 (grey), 2 (grey + alpha), 3 or 4 (RGB[A]) channels, top row
    /// = +y. `to_world` must be a rotation (orthonormal 3x3; translation is ignored).
    /// Throws MesoError (without location) on an empty image, non-finite or negative
    /// pixels, or a to_world that is not a rotation.
    EnvMapLight(const Image &img, float scale, const Transform &to_world, std::string name = "");

    // Mapping of local directions to [0,1)^2 (Mitsuba 3 `envmap`):
    //   u = atan2(d.x, -d.z) / (2 pi)  (wrapped to [0,1)),  v = acos(d.y) / pi.
    static Vec2 direction_to_uv(Vec3 d_local);
    static Vec3 uv_to_direction(Vec2 uv);

    /// Radiance arriving from world direction `d` (pointing from the scene to the
    /// environment), bilinearly interpolated between texel centres (u wraps, v clamps).
    Spectrum radiance(Vec3 d_world) const;
    /// Bilinear radiance at texture coordinates (u, v) in [0,1)^2.
    Spectrum radiance_uv(Vec2 uv) const;
    /// ∫ L dω over the sphere, averaged over RGB (sr·W/m²/sr); power() = pi r^2 times this.
    double radiance_integral() const { return m_integral; }
    size_t memory_bytes() const;
    int width() const { return m_w; }
    int height() const { return m_h; }
    /// The texels (linear radiance × scale, row-major, top row first) and the rotation, for
    /// consumers that filter the map themselves (bsdf/leadr_quadrature.h).
    const std::vector<Spectrum> &texels() const { return m_texels; }
    const Transform &to_world() const { return m_to_world; }

    void preprocess(Vec3 scene_center, float scene_radius) override { m_radius = scene_radius; }
    bool sample(const LightSampleContext &ctx, Vec2 u, LightSample &out) const override;
    /// With ctx.defer_radiance, sample() prefetches the four texels and this reads them.
    Spectrum sampled_radiance(const LightSample &ls) const override { return ls.L_deferred ? radiance_uv(ls.uv) : ls.L; }
    float pdf(const LightSampleContext &ctx, const Vec3 &wi, const LightHit &hit) const override;
    /// w = -ray.d (as for area lights): returns radiance(-w), the environment seen along ray.d.
    Spectrum eval(const LightHit &hit, const Vec3 &w) const override;
    /// One atan2/acos and one lookup for both the radiance along -w and its pdf.
    Spectrum eval_pdf(const LightSampleContext &ctx, const LightHit &hit, const Vec3 &w, float *pdf) const override;
    bool is_infinite() const override { return true; }
    float power() const override;
    std::string to_string() const override;

private:
    float pdf_world(Vec3 wi) const;
    /// The solid-angle pdf of local direction d (unit) whose texture coordinates are uv.
    float pdf_local(Vec3 d, Vec2 uv) const;
    Spectrum texel(int x, int y) const;
    /// The bilinear lookup's texels at uv: columns x0, x1, rows y0, y1, weights fx, fy of x1, y1.
    void bilinear_texels(Vec2 uv, int &x0, int &x1, int &y0, int &y1, float &fx, float &fy) const;

    int m_w = 0, m_h = 0;
    std::vector<Spectrum> m_texels;  ///< linear radiance × scale, row-major, top row first
    Transform m_to_world;
    bool m_identity = true;  ///< to_world is the identity: skip the rotations
    Distribution2D m_distr;          ///< over (u, v), cell weights: luminance × sin(theta)
    double m_integral = 0;
    float m_radius = 1.f;
    float m_scale = 1.f;
    std::string m_name;
};

}  // namespace meso
