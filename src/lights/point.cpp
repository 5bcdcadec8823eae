// `point` light: an isotropic point emitter (a delta light).
//
// Model: radiant intensity I (W/sr) in every direction; the radiance-like quantity
// returned by sample() is L = I / d^2 (pbrt-v4 PointLight, Mitsuba 3 `point`).
// Power: 4 pi I (averaged over the RGB channels, like every meso light's power()).
//
// Parameters (Mitsuba 3 names):
//   position    vec3      default [0,0,0]   world position
//   intensity   spectrum  default 1         radiant intensity, W/sr, >= 0
#include <fmt/format.h>
#include "lights/light.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

class PointLight final : public DeltaLight {
public:
    PointLight(Vec3 pos, Spectrum intensity) : m_pos(pos), m_intensity(intensity) {}

    bool sample(const LightSampleContext &ctx, Vec2, LightSample &out) const override {
        Vec3 d = m_pos - ctx.p;
        float d2 = length_squared(d);
        if (!(d2 > 0.f) || !std::isfinite(d2)) return false;
        float dist = std::sqrt(d2);
        out.wi = d / dist;
        out.dist = dist;
        out.L = m_intensity / d2;
        out.pdf = 1.f;
        out.delta = true;
        return true;
    }
    float power() const override { return 4.f * Pi * m_intensity.average(); }
    std::string to_string() const override {
        return fmt::format("point light at [{}, {}, {}], intensity [{}, {}, {}] W/sr", m_pos.x, m_pos.y, m_pos.z,
                           m_intensity.r, m_intensity.g, m_intensity.b);
    }

private:
    Vec3 m_pos;
    Spectrum m_intensity;
};

MESO_REGISTER_LIGHT("point", "isotropic point light (position, intensity W/sr)",
                    [](const Properties &p) -> std::shared_ptr<Light> {
                        Spectrum I = p.get_spectrum("intensity", Spectrum(1.f), Range::non_negative());
                        return std::make_shared<PointLight>(p.get_position("position", Vec3(0, 0, 0)), I);
                    });

}  // namespace
}  // namespace meso
