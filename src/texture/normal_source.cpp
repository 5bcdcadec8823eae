#include "texture/normal_source.h"
#include <cmath>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "geometry/displacement.h"
#include "geometry/heightfield.h"
#include "image/image.h"
#include "core/properties.h"

namespace meso {

NormalSource::NormalSource(Vec3 constant) : m_const(constant) {}

NormalSource::NormalSource(std::shared_ptr<const MipMap> mip, Space space, float tiling_u, float tiling_v,
                           Filter filter, float max_anisotropy, std::string source)
    : m_const(0.f, 0.f, 1.f),
      m_mip(std::move(mip)),
      m_space(space),
      m_tu(tiling_u),
      m_tv(tiling_v),
      m_filter(filter),
      m_max_aniso(max_anisotropy),
      m_source(std::move(source)) {}

MipMap NormalSource::normal_map_mip(const Image &img, bool integer_encoded) {
    if (img.channels < 3)
        throw MesoError(fmt::format("a normal map needs 3 channels (x, y, z), this image has {}", img.channels));
    std::vector<float> data(size_t(img.width) * img.height * 3);
    for (int y = 0; y < img.height; ++y)
        for (int x = 0; x < img.width; ++x) {
            double n[3];
            for (int c = 0; c < 3; ++c) {
                const double v = img.at(x, y, c);
                n[c] = integer_encoded ? 2.0 * v - 1.0 : v;
            }
            const double l = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
            float *o = &data[(size_t(y) * img.width + x) * 3];
            if (!(l > 1e-12) || !std::isfinite(l)) {
                o[0] = 0.f, o[1] = 0.f, o[2] = 1.f;
            } else {
                for (int c = 0; c < 3; ++c) o[c] = float(n[c] / l);
            }
        }
    return MipMap(img.width, img.height, 3, std::move(data), WrapMode::Repeat);
}

MipMap NormalSource::bake_heightfield(const Heightfield &hf, double tiling_u, double tiling_v, double lu, double lv) {
    // 4-point Gauss-Legendre on [0, 1].
    static const double kNode[4] = {0.5 - 0.5 * 0.8611363115940526, 0.5 - 0.5 * 0.3399810435848563,
                                    0.5 + 0.5 * 0.3399810435848563, 0.5 + 0.5 * 0.8611363115940526};
    static const double kWeight[4] = {0.5 * 0.3478548451374538, 0.5 * 0.6521451548625461,
                                      0.5 * 0.6521451548625461, 0.5 * 0.3478548451374538};
    const int w = hf.width(), h = hf.height();
    const double kx = double(w) * tiling_u / lu, ky = double(h) * tiling_v / lv;  // per cell -> per world unit
    std::vector<float> data(size_t(w) * h * 3);
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < w; ++i) {
            const double h00 = hf.vertex(i, j), h10 = hf.vertex(i + 1, j), h01 = hf.vertex(i, j + 1),
                         h11 = hf.vertex(i + 1, j + 1);
            const double e = h10 - h00, f = h01 - h00, g = h00 + h11 - h10 - h01;
            double s[3] = {0, 0, 0};
            for (int b = 0; b < 4; ++b)
                for (int a = 0; a < 4; ++a) {
                    const double x = (e + g * kNode[b]) * kx, y = (f + g * kNode[a]) * ky;
                    const double inv = 1.0 / std::sqrt(1.0 + x * x + y * y), wt = kWeight[a] * kWeight[b];
                    s[0] += wt * (-x * inv), s[1] += wt * (-y * inv), s[2] += wt * inv;
                }
            float *o = &data[(size_t(j) * w + i) * 3];
            for (int c = 0; c < 3; ++c) o[c] = float(s[c]);
        }
    return MipMap(w, h, 3, std::move(data), WrapMode::Repeat);
}

NormalSource NormalSource::parse(const Properties &p, const std::string &constant_key, bool unit_constant,
                                 bool allow_heightmap) {
    const bool has_map = p.has("normals"), has_height = allow_heightmap && p.has("heightmap");
    if (has_map && has_height) p.fail("heightmap", "give either \"normals\" (an image) or \"heightmap\", not both");
    if (has_map || has_height) {
        if (p.has(constant_key))
            p.fail(constant_key, fmt::format("give either a map or a constant \"{}\", not both", constant_key));
        const Filter filter = parse_footprint_filter(p, "filter");
        const float aniso = p.get_float("max_anisotropy", 8.f, Range::at_least(1.0));
        if (has_map) {
            if (p.has("uv_length")) p.fail("uv_length", "only meaningful with a \"heightmap\"");
            const std::string file = p.get_file("normals");
            const auto [tu, tv] = p.get_tiling();
            std::shared_ptr<MipMap> mip;
            try {
                Image img = read_image(file, /*linearize_srgb=*/false);
                mip = std::make_shared<MipMap>(normal_map_mip(img, integer_encoded(stored_sample_type(file))));
            } catch (const MesoError &e) {
                p.fail("normals", e.what());
            }
            return NormalSource(mip, Space::Shading, tu, tv, filter, aniso, file);
        }
        if (p.has("tiling")) p.fail("tiling", "the heightmap's tiling goes inside its \"heightmap\" block");
        Displacement d = parse_displacement(p.child("heightmap"), 0);
        double lu = 1.0, lv = 1.0;
        if (p.has("uv_length")) {
            const auto [a, b] = p.get_pair("uv_length", Range::positive());  // world length of one unit of u, v
            lu = a, lv = b;
        }
        auto mip = std::make_shared<MipMap>(bake_heightfield(*d.field, d.tiling_u, d.tiling_v, lu, lv));
        return NormalSource(mip, Space::UV, d.tiling_u, d.tiling_v, filter, aniso,
                            fmt::format("average normals of {} (uv length {} x {})", d.source, lu, lv));
    }
    for (const char *k : {"filter", "max_anisotropy", "tiling", "uv_length"})
        if (p.has(k)) p.fail(k, "only meaningful with a \"normals\" map or a \"heightmap\"");
    if (!p.has(constant_key)) return NormalSource(Vec3(0.f, 0.f, 1.f));
    const std::vector<float> c = p.get_floats(constant_key);
    if (c.size() != 3 || !std::isfinite(c[0]) || !std::isfinite(c[1]) || !std::isfinite(c[2]))
        p.fail(constant_key, "expected [x, y, z], finite");
    const double l = std::sqrt(double(c[0]) * c[0] + double(c[1]) * c[1] + double(c[2]) * c[2]);
    if (!(c[2] > 0.f)) p.fail(constant_key, "expected z > 0 (a normal above the surface)");
    if (unit_constant) return NormalSource(Vec3(float(c[0] / l), float(c[1] / l), float(c[2] / l)));
    if (!(l <= 1.0 + 1e-6))
        p.fail(constant_key, fmt::format("expected an average of unit normals: length in (0, 1], got {}", l));
    return NormalSource(Vec3(c[0], c[1], c[2]));
}

Vec3 NormalSource::eval(const ShadingContext &ctx) const {
    if (!m_mip) return m_const;
    float n[3];
    lookup_same_grid(*m_mip, ctx, n);
    return to_local(ctx, Vec3(n[0], n[1], n[2]));
}

void NormalSource::lookup_same_grid(const MipMap &mip, const ShadingContext &ctx, float *out) const {
    const float u = ctx.uv.x * m_tu, v = ctx.uv.y * m_tv;
    mip.lookup(m_filter, u, v, ctx.dudx * m_tu, ctx.dudy * m_tu, ctx.dvdx * m_tv, ctx.dvdy * m_tv, out, m_max_aniso);
}

Vec3 NormalSource::to_local(const ShadingContext &ctx, Vec3 n) const {
    // Frame conventions: see the header.
    const float sx = ctx.side < 0.f ? -1.f : 1.f;
    float sy = 1.f;
    if (m_space == Space::UV) {
        // sign(t . dp/dv) of the unflipped frame (t flips with the frame).
        const float tv = dot(ctx.frame.t, ctx.dpdv) * sx;
        sy = tv < 0.f ? -1.f : 1.f;
    }
    return Vec3(sx * n.x, sy * n.y, n.z);
}

Vec3 NormalSource::mean_over_map() const {
    if (!m_mip) return m_const;
    float n[3];
    m_mip->level_mean(m_mip->levels() - 1, n);
    return Vec3(n[0], n[1], n[2]);
}

std::string NormalSource::to_string() const {
    if (!m_mip) return fmt::format("average normal ({:.4g}, {:.4g}, {:.4g})", m_const.x, m_const.y, m_const.z);
    static const char *filters[] = {"trilinear", "ewa", "none"};
    return fmt::format("normals of {} ({}x{}, tiling {}x{}, {} filter, {:.2f} MB)", m_source, m_mip->width(),
                       m_mip->height(), m_tu, m_tv, filters[int(m_filter)], m_mip->memory_bytes() / 1048576.0);
}

Frame perturbed_frame(Vec3 n) {
    // s' = s - (s . n) n with s = (1, 0, 0).
    Vec3 s(1.f - n.x * n.x, -n.x * n.y, -n.x * n.z);
    float l2 = length_squared(s);
    if (!(l2 > 1e-12f)) {  // n along s: use t = (0, 1, 0) instead
        Vec3 t(-n.y * n.x, 1.f - n.y * n.y, -n.y * n.z);
        t = normalize(t);
        return Frame(cross(t, n), t, n);
    }
    s = s / std::sqrt(l2);
    return Frame(s, cross(n, s), n);
}

}  // namespace meso
