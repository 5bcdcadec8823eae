// `constant` environment light: the same radiance from every direction (an infinite light).
//
// Model: L(w) = radiance for all w; sampled uniformly over the sphere, pdf = 1 / (4 pi)
// (Mitsuba 3 `constant`, pbrt-v4 UniformInfiniteLight). eval(hit, w) ignores both arguments.
// Power: pi r^2 · 4 pi · mean(L) with r the scene's bounding-sphere radius (the flux such an
// environment sends through a disk of radius r, integrated over all directions; needs
// preprocess()).
//
// Parameters (Mitsuba 3 names):
//   radiance   spectrum  default 1   >= 0
#include <fmt/format.h>
#include "lights/light.h"
#include "sampling/warp.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

class ConstantEnvLight final : public Light {
public:
    explicit ConstantEnvLight(Spectrum L) : m_radiance(L) {}
    void preprocess(Vec3, float scene_radius) override { m_radius = scene_radius; }
    bool sample(const LightSampleContext &, Vec2 u, LightSample &out) const override {
        out.wi = square_to_uniform_sphere(u);
        out.dist = Infinity;
        out.L = m_radiance;
        out.pdf = Inv4Pi;
        out.delta = false;
        return !m_radiance.is_black();
    }
    float pdf(const LightSampleContext &, const Vec3 &, const LightHit &) const override { return Inv4Pi; }
    Spectrum eval(const LightHit &, const Vec3 &) const override { return m_radiance; }
    bool is_infinite() const override { return true; }
    float power() const override { return Pi * m_radius * m_radius * 4.f * Pi * m_radiance.average(); }
    std::string to_string() const override {
        return fmt::format("constant environment, radiance [{}, {}, {}]", m_radiance.r, m_radiance.g, m_radiance.b);
    }

private:
    Spectrum m_radiance;
    float m_radius = 1.f;
};

MESO_REGISTER_LIGHT("constant", "uniform environment light (radiance)", [](const Properties &p) -> std::shared_ptr<Light> {
    Spectrum L = p.get_spectrum("radiance", Spectrum(1.f), Range::non_negative());
    return std::make_shared<ConstantEnvLight>(L);
});

}  // namespace
}  // namespace meso
