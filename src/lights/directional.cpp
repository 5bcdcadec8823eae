// `directional` light: parallel light from infinitely far away (a delta light), e.g. the sun
// without its angular extent.
//
// Model: irradiance E (W/m^2) on a surface perpendicular to the travel direction; sample()
// returns wi = -direction, dist = Infinity, L = E, pdf = 1 (pbrt-v4 DistantLight, Mitsuba 3
// `directional`). Power: E · pi r^2 with r the scene's bounding-sphere radius (the flux
// through the scene's cross-section; needs preprocess()).
//
// Parameters (Mitsuba 3 names):
//   direction   vec3      default [0,0,1]   direction the light TRAVELS (need not be unit;
//                                           must be non-zero)
//   irradiance  spectrum  default 1         W/m^2, >= 0
#include <fmt/format.h>
#include "lights/light.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

class DirectionalLight final : public DeltaLight {
public:
    DirectionalLight(Vec3 dir, Spectrum E) : m_dir(normalize(dir)), m_irradiance(E) {}

    void preprocess(Vec3, float scene_radius) override { m_radius = scene_radius; }
    bool sample(const LightSampleContext &, Vec2, LightSample &out) const override {
        out.wi = -m_dir;
        out.dist = Infinity;
        out.L = m_irradiance;
        out.pdf = 1.f;
        out.delta = true;
        return true;
    }
    float power() const override { return Pi * m_radius * m_radius * m_irradiance.average(); }
    std::string to_string() const override {
        return fmt::format("directional light towards [{}, {}, {}], irradiance [{}, {}, {}] W/m^2", m_dir.x, m_dir.y,
                           m_dir.z, m_irradiance.r, m_irradiance.g, m_irradiance.b);
    }

private:
    Vec3 m_dir;
    Spectrum m_irradiance;
    float m_radius = 1.f;
};

MESO_REGISTER_LIGHT("directional", "parallel light (direction of travel, irradiance W/m^2)",
                    [](const Properties &p) -> std::shared_ptr<Light> {
                        Vec3 d = p.get_direction("direction", Vec3(0, 0, 1));
                        Spectrum E = p.get_spectrum("irradiance", Spectrum(1.f), Range::non_negative());
                        return std::make_shared<DirectionalLight>(d, E);
                    });

}  // namespace
}  // namespace meso
