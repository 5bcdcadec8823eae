// `checkerboard` texture: two alternating values on a uv grid, box-filtered analytically.
//
// Model: Mitsuba 3 `checkerboard` values and names; with s = scale·u, t = scale·v the check
// (floor(s) + floor(t)) even shows color0, odd shows color1 (so with the default scale 2,
// [0, .5)^2 is color0, as in Mitsuba). Anti-aliasing: the pattern is integrated over an
// axis-aligned box the size of the ray-differential footprint,
//     half-widths ds = scale·max(|dudx|, |dudy|) / 2,  dt = scale·max(|dvdx|, |dvdy|) / 2,
// in closed form (pbrt-v3 Checkerboard2DTexture "AA_CLOSEDFORM"): the 1D step function
// c(x) = (floor(x) mod 2) has the integral I(x) = floor(x/2) + 2 max(x/2 - floor(x/2) - 1/2, 0),
// so the fraction of odd checks along s is fs = (I(s+ds) - I(s-ds)) / (2 ds), likewise ft,
// and the box covers odd total parity with fraction fs(1-ft) + ft(1-fs). The result is
// (1-f) color0 + f color1: exact for a box filter, -> (color0 + color1)/2 for huge footprints,
// and the point value for a zero footprint. (pbrt uses a box twice as wide.)
//
// Parameters (Mitsuba 3 names):
//   color0   texture/spectrum  default 0.4   value of the even checks
//   color1   texture/spectrum  default 0.2   value of the odd checks
//   scale    float             default 2     checks per unit of uv, > 0
#include <fmt/format.h>
#include "texture/texture.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

/// Integral over [0, x] of the 1D "odd cell" indicator floor(x) mod 2.
inline double bump_int(double x) {
    double h = std::floor(x * 0.5);
    return h + 2.0 * std::max(x * 0.5 - h - 0.5, 0.0);
}

/// Fraction of [x - d, x + d] covered by odd cells (point value when d = 0).
inline double odd_fraction(double x, double d) {
    if (!(d > 0.0)) return std::fmod(std::floor(x), 2.0) != 0.0 ? 1.0 : 0.0;
    if (d > 1e6 || !std::isfinite(d)) return 0.5;
    // Shift x into [0, 2) first: the pattern has period 2, and large |x| would lose the
    // digits of the difference below.
    double x0 = x - 2.0 * std::floor(x * 0.5);
    return clamp((bump_int(x0 + d) - bump_int(x0 - d)) / (2.0 * d), 0.0, 1.0);
}

class CheckerboardTexture final : public Texture {
public:
    CheckerboardTexture(std::shared_ptr<Texture> c0, std::shared_ptr<Texture> c1, float scale)
        : m_c0(std::move(c0)), m_c1(std::move(c1)), m_scale(scale) {}

    /// Fraction of color1 over the footprint.
    float weight1(const ShadingContext &ctx) const {
        double s = double(m_scale) * ctx.uv.x, t = double(m_scale) * ctx.uv.y;
        if (!std::isfinite(s) || !std::isfinite(t)) return 0.5f;
        double ds = 0.5 * m_scale * std::max(std::abs(ctx.dudx), std::abs(ctx.dudy));
        double dt = 0.5 * m_scale * std::max(std::abs(ctx.dvdx), std::abs(ctx.dvdy));
        double fs = odd_fraction(s, ds), ft = odd_fraction(t, dt);
        return float(fs * (1.0 - ft) + ft * (1.0 - fs));
    }
    Spectrum eval(const ShadingContext &ctx) const override {
        float w = weight1(ctx);
        if (w <= 0.f) return m_c0->eval(ctx);
        if (w >= 1.f) return m_c1->eval(ctx);
        return m_c0->eval(ctx) * (1.f - w) + m_c1->eval(ctx) * w;
    }
    Spectrum mean() const override { return (m_c0->mean() + m_c1->mean()) * 0.5f; }
    std::string to_string() const override {
        return fmt::format("checkerboard(scale {}, {}, {})", m_scale, m_c0->to_string(), m_c1->to_string());
    }

private:
    std::shared_ptr<Texture> m_c0, m_c1;
    float m_scale;
};

MESO_REGISTER_TEXTURE("checkerboard", "filtered checkerboard (color0, color1, scale)",
                      [](const Properties &p) -> std::shared_ptr<Texture> {
                          auto c0 = p.get_texture("color0", Spectrum(0.4f));
                          auto c1 = p.get_texture("color1", Spectrum(0.2f));
                          float scale = p.get_float("scale", 2.f);
                          if (!(scale > 0.f)) p.fail("scale", "must be positive");
                          return std::make_shared<CheckerboardTexture>(c0, c1, scale);
                      });

}  // namespace
}  // namespace meso
