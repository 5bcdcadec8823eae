#include "geometry/displacement.h"
#include <cmath>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "geometry/heightmap_gen.h"
#include "filter/transfer_filter.h"
#include "core/properties.h"
#include "filter/ramp_parse.h"

namespace meso {

namespace {

/// A generator's parameters from a JSON object: numbers and strings as text, [r,g,b]
/// arrays as "r,g,b", "image" resolved against the scene file's directory.
std::map<std::string, std::string> generator_params(const Properties &g) {
    std::map<std::string, std::string> params;
    for (const std::string &key : g.keys()) {
        if (key == "generator") continue;
        const nlohmann::json &v = g.raw(key);
        if (key == "image") {
            params[key] = g.get_file(key);
        } else if (v.is_number()) {
            params[key] = v.dump();
        } else if (v.is_string()) {
            params[key] = v.get<std::string>();
        } else if (v.is_array()) {
            std::string s;
            for (const auto &e : v) {
                if (!e.is_number()) g.fail(key, fmt::format("expected an array of numbers, got {}", json_type_name(e)));
                s += (s.empty() ? "" : ",") + e.dump();
            }
            params[key] = s;
        } else {
            g.fail(key, fmt::format("expected a number, a string or an array of numbers, got {}", json_type_name(v)));
        }
    }
    return params;
}

}  // namespace

Displacement parse_displacement(const Properties &p, size_t max_triangles, bool apply_transfer) {
    Displacement d;
    d.max_triangles = max_triangles ? max_triangles : kDefaultMaxTriangles;
    if (!p.has("map"))
        p.fail("expected a \"map\": a height-map file (EXR, 16-bit PNG/TIFF) or {\"generator\": \"fbm\", ...}");
    HeightMap map;
    bool periodic = true;
    const nlohmann::json &m = p.raw("map");
    if (m.is_string()) {
        std::string file = p.get_file("map");
        try {
            map = read_height_map(file);
        } catch (const MesoError &e) {
            p.fail("map", e.what());
        }
        d.source = file;
    } else if (m.is_object()) {
        Properties g = p.child("map");
        std::string kind = g.get_string("generator");
        std::map<std::string, std::string> params = generator_params(g);
        GeneratedMap gen = generate_height_map(kind, params, fmt::format("{}: {}", g.file(), g.path()));
        map = std::move(gen.height);
        periodic = gen.periodic;
        d.source = "generator " + kind;
    } else {
        p.fail("map", fmt::format("expected a file name or a generator object, got {}", json_type_name(m)));
    }

    d.wrap = parse_wrap_mode(p, "wrap", periodic ? WrapMode::Repeat : WrapMode::Clamp);
    map = periodic_extension(map, d.wrap);

    if (p.has("transfer")) {
        // parse_ramp names the key (and the stop) in its errors; one channel: a height per value.
        d.transfer = std::make_shared<const Ramp>(parse_ramp(p, "transfer", 1));
        d.source += " through transfer " + d.transfer->to_string();
        if (apply_transfer) {
            d.untransferred = std::make_shared<const HeightMap>(map);
            for (float &v : map.h) {
                double g;
                d.transfer->eval(double(v), &g);
                v = float(g);
            }
        }
    }

    d.scale = p.get_float("scale", 1.f, Range::coordinate());  // world units per map unit
    d.offset = p.get_float("offset", 0.f, Range::coordinate());
    std::tie(d.tiling_u, d.tiling_v) = p.get_tiling("tiling", d.tiling_u);
    if (d.wrap != WrapMode::Repeat) d.tiling_u *= 0.5f, d.tiling_v *= 0.5f;  // field is the 2W x 2H extension
    d.mode = p.get_enum<DisplacementMode>("mode", "shell",
                                          {{"shell", DisplacementMode::Shell}, {"tessellate", DisplacementMode::Tessellate}});
    if (d.mode == DisplacementMode::Shell) {
        for (const char *k : {"scheme", "level"})
            if (p.has(k)) p.fail(k, "only applies to \"mode\": \"tessellate\"");
    } else {
        d.scheme = p.get_enum<SubdivScheme>("scheme", "bilinear",
                                            {{"bilinear", SubdivScheme::Bilinear}, {"catmull-clark", SubdivScheme::CatmullClark}});
        d.level = p.get_int("level", -1);
        if (d.level < -1 || d.level > 15) p.fail("level", fmt::format("expected -1 (automatic) or 0..15, got {}", d.level));
    }
    try {
        if (d.transfer && !apply_transfer) {
            d.field = std::make_shared<Heightfield>(map, 1.f, 0.f);
            d.field_untransferred = true;
        } else {
            d.field = std::make_shared<Heightfield>(map, d.scale, d.offset);
        }
    } catch (const MesoError &e) {
        p.fail("map", e.what());
    }
    p.check_unused("displacement");
    return d;
}

std::string wrap_range_problem(const Displacement &d, const std::vector<Vec2> &uvs) {
    if (d.wrap != WrapMode::Clamp || uvs.empty()) return {};
    const int W = d.field->width() / 2, H = d.field->height() / 2;  // the map before its extension
    double xlo, xhi, ylo, yhi;
    clamp_extension_exact_range(W, xlo, xhi);
    clamp_extension_exact_range(H, ylo, yhi);
    Vec2 lo = uvs[0], hi = uvs[0];
    for (const Vec2 &t : uvs) lo = Vec2(std::min(lo.x, t.x), std::min(lo.y, t.y)), hi = Vec2(std::max(hi.x, t.x), std::max(hi.y, t.y));
    const double sx = double(d.field->width()) * d.tiling_u, sy = double(d.field->height()) * d.tiling_v;
    if (lo.x * sx >= xlo && hi.x * sx <= xhi && lo.y * sy >= ylo && hi.y * sy <= yhi) return {};
    return fmt::format("with \"wrap\": \"clamp\" the surface's uv x tiling must stay within [{:g}, {:g}] x [{:g}, {:g}] "
                       "of the map; its uvs span [{:g}, {:g}] x [{:g}, {:g}] (tiling {:g} x {:g}): use \"repeat\" or "
                       "\"mirror\", or a smaller tiling",
                       xlo / W, xhi / W, ylo / H, yhi / H, lo.x, hi.x, lo.y, hi.y, 2 * d.tiling_u, 2 * d.tiling_v);
}

HeightMap transfer_downsampled(const HeightMap &f, const Ramp &g, int factor) {
    if (factor < 1 || f.width % factor != 0 || f.height % factor != 0)
        throw MesoError(fmt::format("cannot downsample a {}x{} map by {} (the factor must divide both sizes)", f.width,
                                    f.height, factor));
    HeightMap out(f.width / factor, f.height / factor);
    const double n = double(factor) * factor;
    for (int j = 0; j < out.height; ++j)
        for (int i = 0; i < out.width; ++i) {
            double s = 0, s2 = 0;
            for (int b = 0; b < factor; ++b)
                for (int a = 0; a < factor; ++a) {
                    const double v = f.at(i * factor + a, j * factor + b);
                    s += v;
                    s2 += v * v;
                }
            const double mean = s / n, var = std::max(0.0, s2 / n - mean * mean);
            double gbar;
            g.gaussian_average(mean, std::sqrt(var), &gbar);
            out.at(i, j) = float(gbar);
        }
    return out;
}

}  // namespace meso
