// `meso info`: version, Embree version/ISA, threads, and the compiled-in plugins.
// `meso info SCENE [--json FILE|-]`: what each shape of a scene is, in the units that prefiltering
// needs: the world length of one unit of uv, and for a displaced shape its map, tiling, wrap,
// height scale and the world size of one map tile and one cell (`meso bench` takes
// `meso prefilter --tile-size` from here, issue 21: no hidden conventions).
#include <CLI/CLI.hpp>
#include <cstdio>
#include <memory>
#include <tbb/info.h>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "app/commands.h"
#include "core/distributed.h"
#include "core/output_set.h"
#include "core/registry.h"
#include "core/text_file.h"
#include "geometry/embree_accel.h"
#include "geometry/shell_shape.h"
#include "meso_version.h"
#include "render/scene.h"

namespace meso {
namespace {

struct InfoArgs {
    std::string scene, json_out;
    std::vector<std::string> defines;
};

template <typename T> void list(const char *kind, const PluginTable<T> &t) {
    std::printf("%s:\n", kind);
    for (auto &[name, doc] : t.docs) std::printf("  %-14s %s\n", name.c_str(), doc.c_str());
}

int run_info() {
    std::printf("meso %s\n", MESO_VERSION);
    std::printf("%s\n", EmbreeAccel::version_string().c_str());
    std::printf("distribution: %s\n", dist::describe().c_str());
    std::printf("threads available: %d\n", tbb::info::default_concurrency());
    const Registry &r = registry();
    list("cameras", r.cameras);
    list("integrators", r.integrators);
    list("samplers", r.samplers);
    list("shapes", r.shapes);
    list("materials", r.materials);
    list("textures", r.textures);
    list("lights", r.lights);
    return 0;
}

/// The displacement of a shell shape in user units: the map before a clamp/mirror extension,
/// the tiling as written, and the world size of a tile and a cell from the uv lengths.
nlohmann::json displacement_json(const Displacement &d, const double *uv_len) {
    const int ext = d.wrap == WrapMode::Repeat ? 1 : 2;  // clamp and mirror trace a 2W x 2H extension
    const int w = d.field->width() / ext, h = d.field->height() / ext;
    const double tu = double(d.tiling_u) * ext, tv = double(d.tiling_v) * ext;
    nlohmann::json j = {{"source", d.source},      {"map", {w, h}},          {"tiling", {tu, tv}},
                        {"wrap", wrap_mode_name(d.wrap)}, {"scale", d.scale}, {"offset", d.offset},
                        {"mode", d.mode == DisplacementMode::Shell ? "shell" : "tessellate"}};
    if (uv_len) {
        const double tile_u = uv_len[0] / tu, tile_v = uv_len[1] / tv;
        j["tile_world"] = {tile_u, tile_v};
        j["cell_world"] = {tile_u / w, tile_v / h};
    }
    return j;
}

int run_scene_info(const InfoArgs &a) {
    OutputSet set;
    set.add_input(a.scene, "the scene file");
    const std::string tmp = a.json_out.empty() || a.json_out == "-" ? "" : set.add_output("--json", a.json_out, "", OutputKind::Record);
    set.check();
    std::unique_ptr<Scene> scene = load_scene(a.scene, a.defines);
    nlohmann::json out = {{"scene", a.scene}, {"meso_version", MESO_VERSION}, {"shapes", nlohmann::json::array()}};
    for (size_t i = 0; i < scene->shapes.size(); ++i) {
        const Shape &s = *scene->shapes[i];
        nlohmann::json j = {{"index", i}, {"description", s.to_string()}, {"primitives", s.primitive_count()}};
        double len[2];
        const bool has_len = s.uv_world_length(len[0], len[1]);
        j["uv_world_length"] = has_len ? nlohmann::json{len[0], len[1]} : nlohmann::json();
        if (auto *shell = dynamic_cast<const ShellShape *>(&s)) j["displacement"] = displacement_json(shell->displacement(), has_len ? len : nullptr);
        if (a.json_out.empty()) {
            std::printf("shape %zu: %s\n", i, j["description"].get<std::string>().c_str());
            if (has_len) std::printf("  one unit of uv: %.6g x %.6g world units\n", len[0], len[1]);
            if (j.contains("displacement") && j["displacement"].contains("tile_world"))
                std::printf("  displacement: one map tile %.6g x %.6g, one cell %.6g x %.6g world units\n",
                            j["displacement"]["tile_world"][0].get<double>(), j["displacement"]["tile_world"][1].get<double>(),
                            j["displacement"]["cell_world"][0].get<double>(), j["displacement"]["cell_world"][1].get<double>());
        }
        out["shapes"].push_back(j);
    }
    if (a.json_out == "-") std::printf("%s\n", out.dump(2).c_str());
    if (!tmp.empty()) {
        write_text_atomic(tmp, out.dump(2) + "\n");
        set.commit();
    }
    return 0;
}

SubcommandRegistrar reg({"info", "Version, Embree ISA and plugins; with a SCENE: its shapes' uv and displacement scales",
                         [](CLI::App &app) {
                             auto a = std::make_shared<InfoArgs>();
                             app.add_option("scene", a->scene, "a scene: print each shape's uv length and, when "
                                                               "displaced, its map tile and cell size in world units");
                             app.add_option("--json", a->json_out, "with a scene: write it as JSON to FILE (- : stdout)");
                             app.add_option("-D,--define", a->defines, "override a scene value (as for render)");
                             return [a] { return a->scene.empty() ? run_info() : run_scene_info(*a); };
                         }});

}  // namespace
}  // namespace meso
