// `meso genmap KIND [-p key=value]... [--size N] [--seed S] -o MAP.exr|MAP.png
//              [--albedo ALBEDO.exr|.png] [--preview PREVIEW.png]` and `meso genmap --list`
//
// Runs a height-map generator (src/geometry/heightmap_gen.h; docs/genmap.md) and writes
// the map: .exr as single-channel float32 (exact), .png as 16-bit grey normalised to the
// map's [min, max] (lossy: the range is printed and recorded so a displacement can undo
// it with offset = min, scale = max - min). Beside it goes MAP.json, the record: kind,
// every parameter with the value used, periodicity, statistics and timing.
#include <CLI/CLI.hpp>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fmt/format.h>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include "app/commands.h"
#include "core/text_file.h"
#include "core/error.h"
#include "core/interrupt.h"
#include "core/output_set.h"
#include "geometry/heightmap_gen.h"
#include "meso_version.h"

namespace meso {
namespace {

namespace fs = std::filesystem;

struct GenmapOptions {
    std::string kind, output, albedo, preview;
    std::vector<std::string> params;
    int size = 0;
    int64_t seed = -1;
    bool list = false;
};

std::string lower_extension(const std::string &path) {
    std::string e = fs::path(path).extension().string();
    for (char &c : e) c = char(std::tolower(static_cast<unsigned char>(c)));
    return e;
}

/// Checks an output's extension before any work and declares it in `set`; returns its staging path.
std::string declare_output(OutputSet &set, const std::string &option, const std::string &path,
                           std::initializer_list<const char *> exts) {
    std::string e = lower_extension(path), list;
    bool ok = false;
    for (const char *x : exts) ok |= e == x, list += (list.empty() ? "" : " or ") + std::string(x);
    if (!ok) throw MesoError(fmt::format("{} {}: expected a {} file", option, path, list));
    return set.add_output(option, path);
}

void print_list() {
    for (const GeneratorInfo &g : height_map_generators()) {
        std::printf("%s: %s\n", g.name.c_str(), g.help.c_str());
        for (const GeneratorParam &p : g.params)
            std::printf("%s", fmt::format("    {:<17} {:<12} {}\n", p.name,
                                          p.default_value.empty() ? "-" : p.default_value, p.help).c_str());
    }
}

/// Grey Lambert shading of the surface lit from the top-left (azimuth of -u -v, 45 degrees
/// up), slopes from central differences in tile units times `exaggeration`.
Image shaded_relief(const HeightMap &m, double exaggeration) {
    Image img(m.width, m.height, 3);
    const double lx = -0.5, ly = -0.5, lz = std::sqrt(0.5);
    for (int j = 0; j < m.height; ++j)
        for (int i = 0; i < m.width; ++i) {
            double gu = 0.5 * m.width * (m.wrapped(i + 1, j) - m.wrapped(i - 1, j)) * exaggeration;
            double gv = 0.5 * m.height * (m.wrapped(i, j + 1) - m.wrapped(i, j - 1)) * exaggeration;
            double shade = (-gu * lx - gv * ly + lz) / std::sqrt(gu * gu + gv * gv + 1);
            img.set_rgb(i, j, Spectrum(float(std::max(0.0, shade))));
        }
    return img;
}

void write_record(const std::string &path, const nlohmann::json &rec) { write_text_atomic(path, rec.dump(2) + "\n"); }

int run_genmap(const GenmapOptions &o) {
    if (o.list) {
        print_list();
        return 0;
    }
    if (o.kind.empty()) throw MesoError("genmap: expected a generator KIND (see meso genmap --list)");
    if (o.output.empty()) throw MesoError("genmap: -o/--output is required");
    // Every output is checked (and staged) before any work; a record may only replace a record.
    OutputSet set;
    const std::string map_tmp = declare_output(set, "-o", o.output, {".exr", ".png"});
    const std::string json_path = fs::path(o.output).replace_extension(".json").string();
    const std::string json_tmp = set.add_output("-o", json_path, o.output, OutputKind::Record);
    const std::string albedo_tmp = o.albedo.empty() ? "" : declare_output(set, "--albedo", o.albedo, {".exr", ".png"});
    const std::string preview_tmp = o.preview.empty() ? "" : declare_output(set, "--preview", o.preview, {".png"});
    set.check();
    install_interrupt_handler(InterruptMode::Immediate);  // Ctrl-C: staged files deleted, exit 130

    std::map<std::string, std::string> params;
    for (const std::string &kv : o.params) {
        size_t eq = kv.find('=');
        if (eq == std::string::npos || eq == 0) throw MesoError(fmt::format("-p {}: expected key=value", kv));
        if (!params.emplace(kv.substr(0, eq), kv.substr(eq + 1)).second)
            throw MesoError(fmt::format("-p {}: '{}' is given twice", kv, kv.substr(0, eq)));
    }
    auto option_param = [&](const char *option, const char *key, const std::string &value) {
        if (!params.emplace(key, value).second)
            throw MesoError(fmt::format("{} and -p {}=... both set {}", option, key, key));
    };
    if (o.size > 0) option_param("--size", "size", std::to_string(o.size));
    if (o.seed >= 0) option_param("--seed", "seed", std::to_string(o.seed));

    auto t0 = std::chrono::steady_clock::now();
    GeneratedMap g = generate_height_map(o.kind, params, o.kind);
    double gen_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (!o.albedo.empty() && g.albedo.width == 0)
        throw UsageError(fmt::format("--albedo: generator '{}' makes no albedo map (vgroove, sawtooth, twill and "
                                    "satin do)",
                                    o.kind));
    HeightMapStats st = height_map_stats(g.height, g.periodic);

    nlohmann::json rec;
    rec["meso_version"] = MESO_VERSION;
    rec["kind"] = o.kind;
    rec["params"] = g.params;
    rec["seed"] = g.params.count("seed") ? std::stoll(g.params.at("seed")) : 0;
    rec["width"] = g.height.width;
    rec["height"] = g.height.height;
    rec["periodic"] = g.periodic;
    rec["notes"] = g.notes;
    rec["stats"] = {{"min", st.min},
                    {"max", st.max},
                    {"mean", st.mean},
                    {"rms_slope", st.rms_slope},
                    {"mean_slope", {st.mean_su, st.mean_sv}},
                    {"slope_covariance", {{"sxx", st.sxx}, {"syy", st.syy}, {"sxy", st.sxy}}}};
    rec["units"] = "tile: uv in [0,1]^2, heights and slopes per tile side";
    rec["output"] = o.output;

    // Everything is checked: write the outputs.
    if (lower_extension(o.output) == ".png") {
        HeightRange r = write_height_map_png16(map_tmp, g.height);
        rec["format"] = "png16";
        rec["png_range"] = {{"offset", r.lo}, {"scale", double(r.hi) - double(r.lo)}};
    } else {
        write_height_map(map_tmp, g.height);
        rec["format"] = "exr";
    }
    if (!o.albedo.empty()) {
        if (lower_extension(o.albedo) == ".exr") write_exr(albedo_tmp, g.albedo);
        else write_png(albedo_tmp, g.albedo);
        rec["albedo"] = o.albedo;
    }
    double exaggeration = 1;
    if (!o.preview.empty()) {
        // Exaggerate gentle maps so their relief shows: rms slope at least 0.5.
        if (st.rms_slope > 0 && st.rms_slope < 0.5) exaggeration = 0.5 / st.rms_slope;
        write_png(preview_tmp, shaded_relief(g.height, exaggeration));
        rec["preview"] = {{"path", o.preview}, {"slope_exaggeration", exaggeration}};
    }
    rec["time_s"] = gen_s;
    write_record(json_tmp, rec);
    set.commit();

    std::printf("%s", fmt::format("genmap {}: {}x{}, min {:.6g}, max {:.6g}, mean {:.6g}, rms slope {:.4g} (per tile), "
                                  "{:.3f} s\n",
                                  o.kind, g.height.width, g.height.height, st.min, st.max, st.mean, st.rms_slope, gen_s)
                          .c_str());
    if (!g.periodic) std::printf("not periodic: the map has a seam at the wrap-around\n");
    for (const std::string &n : g.notes) std::printf("note: %s\n", n.c_str());
    std::string wrote = o.output;
    if (rec.contains("png_range"))
        wrote += fmt::format(" (16-bit, heights = {:.9g} + {:.9g} * value)", rec["png_range"]["offset"].get<double>(),
                             rec["png_range"]["scale"].get<double>());
    if (!o.albedo.empty()) wrote += ", " + o.albedo;
    if (!o.preview.empty())
        wrote += ", " + o.preview + (exaggeration != 1 ? fmt::format(" (slopes x{:.3g})", exaggeration) : "");
    std::printf("wrote %s, %s\n", wrote.c_str(), json_path.c_str());
    std::fflush(stdout);
    return 0;
}

SubcommandRegistrar reg_genmap{
    {"genmap", "Generate a periodic height map (fbm, gaussian, bumps, vgroove, sawtooth, twill, satin, relief)",
     [](CLI::App &app) -> std::function<int()> {
         auto o = std::make_shared<GenmapOptions>();
         app.add_option("kind", o->kind, "generator (see --list)");
         app.add_option("-o,--output", o->output,
                        "height map: .exr (float32) or .png (16-bit, normalised to [min, max]); MAP.json goes beside it");
         app.add_option("--size", o->size, "vertices per side (same as -p size=N)")->check(CLI::Range(2, 16384));
         app.add_option("--seed", o->seed, "random seed (same as -p seed=S)")->check(CLI::NonNegativeNumber);
         app.add_option("-p,--param", o->params, "generator parameter key=value (repeatable; see --list)");
         app.add_option("--albedo", o->albedo, "write the generator's albedo map (.exr linear or .png sRGB)");
         app.add_option("--preview", o->preview, "write a shaded-relief preview PNG");
         app.add_flag("--list", o->list, "list the generators and their parameters, then exit");
         return [o] { return run_genmap(*o); };
     }}};

}  // namespace
}  // namespace meso
