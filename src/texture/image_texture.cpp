// `bitmap` texture (alias `image`): an image file looked up by uv, MIP-mapped.
//
// Model: Mitsuba 3 `bitmap` with pbrt-style MIP mapping (Williams 1983). The image is read
// by read_image (EXR, PNG, or any format OpenImageIO reads); 8- and 16-bit files are
// sRGB-decoded to linear unless `raw` (float formats are always linear). uv (0,0) is the
// top-left corner of the image, v points down (glTF / Mitsuba convention; see
// texture/mipmap.h). Grey images give grey spectra; alpha is ignored.
//   nearest:   the level-0 texel containing uv
//   bilinear:  level-0 bilinear interpolation between texel centres
//   trilinear: the MIP level from the ray-differential footprint,
//              level = log2(footprint width in texels), blended between the two nearest
//              levels; zero footprint -> level-0 bilinear.
//   ewa:       elliptically weighted average (Heckbert 1989, as in pbrt-v4): the footprint
//              ellipse with semi-axes (dudx, dvdx), (dudy, dvdy), its minor axis widened to
//              at most max_anisotropy : 1, a truncated Gaussian over the texels of the two
//              levels around log2(minor axis); keeps detail along the major axis that
//              trilinear (which sizes its box by the major axis) blurs away.
//
// Parameters (Mitsuba 3 names):
//   filename     string  required      image file, relative to the scene
//   filter_type  string  "trilinear"   "nearest" | "bilinear" | "trilinear" | "ewa"
//   max_anisotropy float 8             ewa only: largest major/minor axis ratio, finite,
//                                      >= 1 (above 64 acts as 64, which bounds the cost)
//   wrap_mode    string  "repeat"      "repeat" | "clamp" | "mirror" (also "wrap", the displacement's name)
//   raw          bool    false         true: no sRGB decoding of 8/16-bit data (normal maps,
//                                      roughness, heights)
//   scale        float   1             multiplier, finite
//   offset       [u, v]  [0, 0]        added to uv after tiling and rotation
//   rotation     float   0             radians, [-1e6, 1e6]: uv' = T R S uv, glTF KHR_texture_transform's
//                                      order and sign, with S = diag(tiling), T the offset and
//                                      R = [[cos r, sin r], [-sin r, cos r]] (counter-clockwise in
//                                      the image, whose v runs down). The ray-differential footprint
//                                      goes through the same linear map R S.
//   channel      string  "rgb"         "rgb" | "r" | "g" | "b" | "a": one channel of the file as
//                                      a grey texture (glTF's metallicRoughnessTexture: "b"
//                                      metallic, "g" roughness); "rgb" keeps grey files grey
#include <cmath>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "image/image.h"
#include "texture/texture.h"
#include "image/image_param.h"
#include "core/properties.h"
#include "core/registry.h"
#include "texture/mipmap.h"

namespace meso {
namespace {

enum class Filter { Nearest, Bilinear, Trilinear, Ewa };

class BitmapTexture final : public Texture {
public:
    BitmapTexture(MipMap mip, Filter filter, float max_anisotropy, float scale, Vec2 tiling, float rotation,
                  Vec2 offset, std::string name)
        : m_mip(std::move(mip)), m_filter(filter), m_max_anisotropy(max_anisotropy), m_scale(scale),
          m_offset(offset), m_name(std::move(name)) {
        // A = R S; rotation 0 gives A = diag(tiling) exactly (sin 0 = 0, cos 0 = 1).
        const double c = std::cos(double(rotation)), s = std::sin(double(rotation));
        m_a[0][0] = float(c * tiling.x), m_a[0][1] = float(s * tiling.y);
        m_a[1][0] = float(-s * tiling.x), m_a[1][1] = float(c * tiling.y);
        float m[3] = {0, 0, 0};
        m_mip.level_mean(0, m);
        m_mean = to_spectrum(m) * m_scale;
    }

    Spectrum eval(const ShadingContext &ctx) const override {
        float v[3] = {0, 0, 0};
        lookup(ctx, v);
        return to_spectrum(v) * m_scale;
    }
    float eval_float(const ShadingContext &ctx) const override {
        float v[3] = {0, 0, 0};
        lookup(ctx, v);
        return (m_mip.channels() == 1 ? v[0] : (v[0] + v[1] + v[2]) * (1.f / 3.f)) * m_scale;
    }
    Spectrum mean() const override { return m_mean; }
    std::string to_string() const override {
        static const char *filters[] = {"nearest", "bilinear", "trilinear", "ewa"};
        return fmt::format("bitmap '{}' {}x{}x{}, {} filter, {} levels, {:.2f} MB", m_name, m_mip.width(),
                           m_mip.height(), m_mip.channels(), filters[int(m_filter)], m_mip.levels(),
                           m_mip.memory_bytes() / 1048576.0);
    }

private:
    Spectrum to_spectrum(const float *v) const {
        return m_mip.channels() == 1 ? Spectrum(v[0]) : Spectrum(v[0], v[1], v[2]);
    }
    void lookup(const ShadingContext &ctx, float *v) const {
        // uv' = A uv + offset with A = R S: without rotation the image repeats tiling.x times
        // along u and tiling.y along v (matching a displacement's tiling, so an albedo map stays
        // aligned with the micro-facets). The footprint's columns (du/dx, dv/dx) and
        // (du/dy, dv/dy) are tangent vectors in uv, so they map through A as well.
        const float(&a)[2][2] = m_a;
        const float u = a[0][0] * ctx.uv.x + a[0][1] * ctx.uv.y + m_offset.x;
        const float w = a[1][0] * ctx.uv.x + a[1][1] * ctx.uv.y + m_offset.y;
        if (m_filter == Filter::Nearest) return m_mip.nearest(0, u, w, v);
        if (m_filter == Filter::Bilinear) return m_mip.bilinear(0, u, w, v);
        const float dudx = a[0][0] * ctx.dudx + a[0][1] * ctx.dvdx, dudy = a[0][0] * ctx.dudy + a[0][1] * ctx.dvdy;
        const float dvdx = a[1][0] * ctx.dudx + a[1][1] * ctx.dvdx, dvdy = a[1][0] * ctx.dudy + a[1][1] * ctx.dvdy;
        if (m_filter == Filter::Trilinear) return m_mip.filtered(u, w, dudx, dudy, dvdx, dvdy, v);
        m_mip.ewa(u, w, dudx, dudy, dvdx, dvdy, v, m_max_anisotropy);
    }

    MipMap m_mip;
    Filter m_filter;
    float m_max_anisotropy;
    float m_scale;
    float m_a[2][2];  ///< R S: KHR_texture_transform's rotation times the tiling
    Vec2 m_offset;
    Spectrum m_mean;
    std::string m_name;
};

std::shared_ptr<Texture> create_bitmap(const Properties &p) {
    std::string file = p.get_file("filename");
    const Filter filter = p.get_enum<Filter>(
        "filter_type", "trilinear",
        {{"nearest", Filter::Nearest}, {"bilinear", Filter::Bilinear}, {"trilinear", Filter::Trilinear}, {"ewa", Filter::Ewa}});
    float max_anisotropy = p.get_float("max_anisotropy", 8.f, Range::at_least(1.0));
    const WrapMode wrap = parse_texture_wrap(p);
    bool raw = p.get_bool("raw", false);
    float scale = p.get_float("scale", 1.f);
    Vec2 tiling(1.f, 1.f);
    if (p.has("tiling")) {
        const auto [t0, t1] = p.get_tiling();
        tiling = Vec2(t0, t1);
    }

    Vec2 offset(0.f, 0.f);
    if (p.has("offset")) {
        std::vector<float> o = p.get_floats("offset");
        if (o.size() != 2 || !(std::abs(o[0]) <= 1e6f) || !(std::abs(o[1]) <= 1e6f))
            p.fail("offset", "expected [u, v], each finite with |value| <= 1e6");
        offset = Vec2(o[0], o[1]);
    }
    const float rotation = p.get_float("rotation", 0.f, Range::closed(-1e6, 1e6));
    const int channel = p.get_enum<int>("channel", "rgb", {{"rgb", -1}, {"r", 0}, {"g", 1}, {"b", 2}, {"a", 3}});

    const Image img = read_image_param(p, "filename", file, raw);
    // Keep 1 channel for grey (+alpha) images, RGB otherwise; `channel` picks one.
    int nc = img.channels <= 2 ? 1 : 3, first = 0;
    if (channel >= 0) {
        nc = 1;
        if (channel == 3) first = img.channels == 2 || img.channels == 4 ? img.channels - 1 : -1;
        else first = img.channels >= 3 ? channel : (img.channels <= 2 ? 0 : -1);
        if (first < 0)
            p.fail("channel", fmt::format("{}: the image has {} channel(s), no {}", file, img.channels,
                                          channel == 3 ? "alpha" : "such channel"));
    }
    std::vector<float> data(size_t(img.width) * img.height * nc);
    long bad = 0;
    for (size_t i = 0; i < size_t(img.width) * img.height; ++i)
        for (int c = 0; c < nc; ++c) {
            float x = img.data[i * img.channels + first + c];
            if (!std::isfinite(x)) {
                ++bad;
                x = 0.f;
            }
            data[i * nc + c] = x;
        }
    if (bad > 0) p.fail("filename", fmt::format("{}: {} texel value(s) are NaN or infinite", file, bad));
    MipMap mip(img.width, img.height, nc, std::move(data), wrap);
    return std::make_shared<BitmapTexture>(std::move(mip), filter, max_anisotropy, scale, tiling, rotation, offset, file);
}

MESO_REGISTER_TEXTURE("bitmap", "image texture, MIP-mapped (filename, filter_type, max_anisotropy, wrap_mode, raw, scale, tiling, offset, rotation, channel)",
                      create_bitmap);
MESO_REGISTER_TEXTURE("image", "alias of 'bitmap'", create_bitmap);

}  // namespace
}  // namespace meso
