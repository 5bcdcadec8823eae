// `microcolormap`: a colour map applied to an attribute of the exact microgeometry at the shading
// point: the ground truth of paper 001 §5 (colour maps on the heights and slopes of a surface).
// On a shell-mapped displacement (geometry/shell_shape.h) the hit lies on the micro-surface, so
// rendering many samples per pixel integrates C(attribute) over the footprint with the true
// visibility, masking and shadowing; the prefiltered counterpart is the `leadr` material's
// "colormap" block (materials/leadr.cpp).
//
// Attributes (slopes in the macro tangent frame: x along dp/du of the base surface, y = n x x,
// s = (-m . x, -m . y) / (m . n) for the micro-normal m and the macro normal n; the same frame
// and sign as the `leadr` material's slope distribution):
//   height     the displacement field's height at the hit (world units); 0 off microgeometry
//   slope_x    s.x
//   slope_y    s.y
//   steepness  |s| = tan(angle between micro- and macro normal)
// Off microgeometry (no macro frame) the slope is 0 (a flat surface).
//
// Parameters
//   name       type     default   notes
//   colormap   ramp     required  stops or an image (filter/ramp_parse.h), 3 channels
//   attribute  string   "height"  "height" | "slope_x" | "slope_y" | "steepness"
//   offset     texture  0         added to the attribute (its channel average): e.g. a grey noise
//                                 bitmap for the noise-perturbed heights C(h + r(x)) of §5.1
#include <cmath>
#include <fmt/format.h>
#include "texture/texture.h"
#include "filter/transfer_filter.h"
#include "core/properties.h"
#include "core/registry.h"
#include "filter/ramp_parse.h"

namespace meso {
namespace {

enum class MicroAttribute { Height, SlopeX, SlopeY, Steepness };

class MicroColormap final : public Texture {
public:
    MicroColormap(Ramp ramp, MicroAttribute attr, std::shared_ptr<Texture> offset, std::string attr_name)
        : m_ramp(std::move(ramp)), m_attr(attr), m_offset(std::move(offset)), m_name(std::move(attr_name)) {}

    Spectrum eval(const ShadingContext &ctx) const override {
        double a = attribute(ctx);
        if (m_offset) a += m_offset->eval_float(ctx);
        double c[3];
        m_ramp.eval(a, c);
        return Spectrum(float(c[0]), float(c[1]), float(c[2]));
    }
    Spectrum mean() const override {
        // The ramp's Gaussian average over its own range: a hint only.
        double c[3];
        m_ramp.gaussian_average(0.5 * (m_ramp.x_min() + m_ramp.x_max()), 0.25 * (m_ramp.x_max() - m_ramp.x_min()), c);
        return Spectrum(float(c[0]), float(c[1]), float(c[2]));
    }
    std::string to_string() const override {
        return fmt::format("microcolormap[{} of the microgeometry, {}{}]", m_name, m_ramp.to_string(),
                           m_offset ? ", offset " + m_offset->to_string() : "");
    }

private:
    double attribute(const ShadingContext &ctx) const {
        if (m_attr == MicroAttribute::Height) return std::isfinite(ctx.micro_height) ? ctx.micro_height : 0.0;
        const Vec3 n = ctx.n_macro;
        if (!(length_squared(n) > 0.f)) return 0.0;
        Vec3 x = ctx.dpdu_macro - n * dot(n, ctx.dpdu_macro);
        if (!(length_squared(x) > 0.f)) return 0.0;
        x = normalize(x);
        const Vec3 y = cross(n, x);
        const Vec3 m = ctx.frame.n;
        const double mn = std::max(1e-6, double(dot(m, n)));
        const double sx = -double(dot(m, x)) / mn, sy = -double(dot(m, y)) / mn;
        switch (m_attr) {
            case MicroAttribute::SlopeX: return sx;
            case MicroAttribute::SlopeY: return sy;
            default: return std::sqrt(sx * sx + sy * sy);
        }
    }

    Ramp m_ramp;
    MicroAttribute m_attr;
    std::shared_ptr<Texture> m_offset;
    std::string m_name;
};

std::shared_ptr<Texture> make_micro_colormap(const Properties &p) {
    Ramp ramp = parse_ramp(p, "colormap", 3);
    const MicroAttribute attr = p.get_enum<MicroAttribute>("attribute", "height",
                                                           {{"height", MicroAttribute::Height},
                                                            {"slope_x", MicroAttribute::SlopeX},
                                                            {"slope_y", MicroAttribute::SlopeY},
                                                            {"steepness", MicroAttribute::Steepness}});
    const std::string a = p.get_string("attribute", "height");  // the validated name, for to_string
    std::shared_ptr<Texture> offset = p.has("offset") ? p.get_texture("offset") : nullptr;
    return std::make_shared<MicroColormap>(std::move(ramp), attr, std::move(offset), a);
}

}  // namespace

MESO_REGISTER_TEXTURE("microcolormap",
                      "colour map of the microgeometry's height or slope at the hit (colormap, attribute, offset): "
                      "ground truth for paper 001",
                      make_micro_colormap);

}  // namespace meso
