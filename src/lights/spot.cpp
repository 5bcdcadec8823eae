// `spot` light: a point light restricted to a cone, with a smooth edge (a delta light).
//
// Model (Mitsuba 3 `spot`): I(theta) = intensity · falloff(theta), theta the angle to the
// spot axis, with falloff = 1 for theta <= beam_width, 0 for theta >= cutoff_angle and the
// linear ramp (cutoff - theta) / (cutoff - beam) in between (continuous, so the edge has no
// hard line). sample() returns L = I(theta) / d^2, pdf 1.
// Power: 2 pi I ∫ falloff(theta) sin(theta) dtheta = 2 pi I (1 - (sin g - sin b)/(g - b))
// with b = beam_width, g = cutoff (radians); 2 pi I (1 - cos g) when b = g.
//
// Parameters (Mitsuba 3 names):
//   position      vec3      default [0,0,0]       world position
//   direction     vec3      default [0,0,1]       axis of the cone (mutually exclusive with target)
//   target        vec3      —                     point the axis passes through
//   intensity     spectrum  default 1             W/sr on the axis, >= 0
//   cutoff_angle  float     default 20            degrees, in (0, 180]: no light beyond
//   beam_width    float     default 3/4 cutoff    degrees, in [0, cutoff]: full intensity within
#include <fmt/format.h>
#include "core/frame.h"
#include "lights/light.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

class SpotLight final : public DeltaLight {
public:
    SpotLight(Vec3 pos, Vec3 dir, Spectrum I, float cutoff_deg, float beam_deg)
        : m_pos(pos), m_frame(normalize(dir)), m_intensity(I), m_cutoff(radians(cutoff_deg)),
          m_beam(radians(beam_deg)) {
        m_cos_cutoff = std::cos(m_cutoff);
        m_cos_beam = std::cos(m_beam);
    }

    /// Angular falloff for a unit direction (world) leaving the light.
    float falloff(Vec3 w) const {
        float cos_t = dot(w, m_frame.n);
        if (cos_t >= m_cos_beam) return 1.f;
        if (cos_t <= m_cos_cutoff) return 0.f;
        float theta = safe_acos(cos_t);
        return clamp((m_cutoff - theta) / (m_cutoff - m_beam), 0.f, 1.f);
    }

    bool sample(const LightSampleContext &ctx, Vec2, LightSample &out) const override {
        Vec3 d = m_pos - ctx.p;
        float d2 = length_squared(d);
        if (!(d2 > 0.f) || !std::isfinite(d2)) return false;
        float dist = std::sqrt(d2);
        out.wi = d / dist;
        float f = falloff(-out.wi);
        if (f <= 0.f) return false;
        out.dist = dist;
        out.L = m_intensity * (f / d2);
        out.pdf = 1.f;
        out.delta = true;
        return true;
    }
    float power() const override {
        double g = m_cutoff, b = m_beam;
        double solid = (g - b > 1e-6) ? 1.0 - (std::sin(g) - std::sin(b)) / (g - b) : 1.0 - std::cos(g);
        return float(2.0 * M_PI * solid) * m_intensity.average();
    }
    std::string to_string() const override {
        return fmt::format("spot light at [{}, {}, {}] towards [{}, {}, {}], intensity [{}, {}, {}] W/sr, cutoff {} deg, "
                           "beam {} deg",
                           m_pos.x, m_pos.y, m_pos.z, m_frame.n.x, m_frame.n.y, m_frame.n.z, m_intensity.r,
                           m_intensity.g, m_intensity.b, degrees(m_cutoff), degrees(m_beam));
    }

private:
    Vec3 m_pos;
    Frame m_frame;
    Spectrum m_intensity;
    float m_cutoff, m_beam, m_cos_cutoff, m_cos_beam;
};

MESO_REGISTER_LIGHT("spot", "spot light (position, direction/target, intensity, cutoff_angle, beam_width)",
                    [](const Properties &p) -> std::shared_ptr<Light> {
                        Vec3 pos = p.get_position("position", Vec3(0, 0, 0));
                        Vec3 dir(0, 0, 1);
                        if (p.has("direction") && p.has("target"))
                            p.fail("target", "give either 'direction' or 'target', not both");
                        if (p.has("direction")) {
                            dir = p.get_direction("direction");
                        } else if (p.has("target")) {
                            dir = p.get_position("target") - pos;
                            if (!(length_squared(dir) > 0.f)) p.fail("target", "must differ from 'position'");
                        }
                        Spectrum I = p.get_spectrum("intensity", Spectrum(1.f), Range::non_negative());
                        float cutoff = p.get_float("cutoff_angle", 20.f, Range::positive(180.0));
                        float beam = p.get_float("beam_width", cutoff * 0.75f, Range::closed(0.0, cutoff));
                        return std::make_shared<SpotLight>(pos, dir, I, cutoff, beam);
                    });

}  // namespace
}  // namespace meso
