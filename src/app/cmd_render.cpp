// `meso render SCENE`: load, build, render under a sample or time budget, write
// OUT.exr (float RGB), OUT.png (sRGB) and OUT.json (the run's record).
#include <CLI/CLI.hpp>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "app/commands.h"
#include "core/distributed.h"
#include "core/error.h"
#include "geometry/embree_accel.h"
#include "meso_version.h"
#include "render/renderer.h"
#include "geometry/shape.h"
#include "scene/scene.h"

namespace meso {
namespace {

struct RenderArgs {
    std::string scene, output, reference, convergence;
    int spp = 0, threads = 0;
    double time = 0;
    int64_t seed = -1;
    std::vector<std::string> defines;
    bool plan = false, quiet = false;
    size_t max_triangles = 0;
    float exposure = 0.f;
};

/// Writes `text` to `path` atomically (temporary file + rename).
void write_text_atomic(const std::string &path, const std::string &text) {
    std::string tmp = path + ".tmp";
    {
        std::ofstream f(tmp);
        if (!f) throw MesoError(fmt::format("cannot write '{}'", path));
        f << text;
        if (!f) throw MesoError(fmt::format("cannot write '{}'", path));
    }
    std::filesystem::rename(tmp, path);
}

int run_render(const RenderArgs &a) {
    auto t0 = std::chrono::steady_clock::now();
    auto since = [](auto t) { return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count(); };
    if (a.spp < 0) throw MesoError("--spp: expected a positive sample count");
    if (a.time < 0) throw MesoError("--time: expected a positive number of seconds");

    // Output names: OUT.exr -> OUT.png, OUT.json. Checked before any work.
    std::filesystem::path out = a.output.empty() ? std::filesystem::path(a.scene).stem().string() + ".exr" : a.output;
    if (out.extension() != ".exr") throw MesoError(fmt::format("-o {}: the output must be an .exr file", out.string()));
    auto out_dir = out.parent_path();
    if (!out_dir.empty() && !std::filesystem::is_directory(out_dir))
        throw MesoError(fmt::format("-o {}: directory '{}' does not exist", out.string(), out_dir.string()));

    Image reference;
    if (!a.reference.empty()) reference = read_image(a.reference);
    if (!a.convergence.empty() && a.reference.empty()) throw MesoError("--convergence needs --reference");

    std::unique_ptr<Scene> scene = load_scene(a.scene, a.defines, a.max_triangles);
    double load_s = since(t0);
    if (!a.reference.empty() && (reference.width != scene->camera->width() || reference.height != scene->camera->height()))
        throw MesoError(fmt::format("{}: reference is {}x{} but the camera renders {}x{}", a.reference, reference.width,
                                    reference.height, scene->camera->width(), scene->camera->height()));
    if (a.plan) {
        if (dist::rank() != 0) return 0;
        std::printf("plan for %s (nothing is built or rendered):\n", a.scene.c_str());
        for (auto &line : scene->plan()) std::printf("  %s\n", line.c_str());
        std::filesystem::path png = out, js = out;
        png.replace_extension(".png");
        js.replace_extension(".json");
        std::printf("  output: %s, %s, %s\n", out.string().c_str(), png.string().c_str(), js.string().c_str());
        return 0;
    }
    auto tb = std::chrono::steady_clock::now();
    scene->build();
    double build_s = since(tb);

    RenderOptions opts;
    opts.spp = a.spp;
    opts.time_budget_s = a.time;
    opts.threads = a.threads;
    if (a.seed >= 0) opts.seed = uint64_t(a.seed);
    opts.progress = !a.quiet;
    opts.reference = a.reference.empty() ? nullptr : &reference;
    opts.convergence_csv = a.convergence;
    RenderResult r = render(*scene, opts);
    // Under MPI only rank 0 holds the summed film; it alone writes (docs/cluster.md).
    if (dist::rank() != 0) return 0;

    nlohmann::json rec;
    rec["meso_version"] = MESO_VERSION;
    rec["scene"] = a.scene;
    rec["defines"] = a.defines;
    rec["width"] = scene->camera->width();
    rec["height"] = scene->camera->height();
    rec["integrator"] = scene->integrator->to_string();
    rec["sampler"] = scene->sampler->name();
    rec["seed"] = a.seed >= 0 ? a.seed : int64_t(scene->sampler->seed());
    rec["threads"] = r.threads;
    rec["ranks"] = r.ranks;
    rec["time_budget_s"] = a.time;
    rec["load_s"] = load_s;
    rec["build_s"] = build_s;
    rec["wall_s"] = r.wall_s;
    rec["spp"] = r.spp;
    rec["passes"] = r.passes;
    rec["rays"] = r.rays;
    rec["shadow_rays"] = r.shadow_rays;
    rec["rays_per_s"] = r.rays_per_s;
    rec["peak_rss_mb"] = peak_rss_mb();
    rec["nan_count"] = r.nan_count;
    // Geometry memory per shape (shell maps: prisms + heightfield, independent of tiling).
    size_t geometry_bytes = 0;
    nlohmann::json shapes = nlohmann::json::array();
    for (const auto &s : scene->shapes) {
        geometry_bytes += s->memory_bytes();
        shapes.push_back({{"shape", s->to_string()}, {"primitives", s->primitive_count()}, {"memory_bytes", s->memory_bytes()}});
    }
    rec["geometry_bytes"] = geometry_bytes;
    rec["shapes"] = shapes;
    if (!a.reference.empty()) {
        ImageMetrics m = compute_metrics(r.image, reference);
        rec["reference"] = a.reference;
        rec["mse"] = m.mse;
        rec["relmse"] = m.relmse;
        rec["rmse"] = m.rmse;
        rec["psnr"] = m.psnr;
        rec["mean_luminance_ratio"] = m.mean_luminance_ratio;
    }
    std::filesystem::path exr = out, png = out, js = out;
    png.replace_extension(".png");
    js.replace_extension(".json");
    write_exr(exr.string(), r.image);
    write_png(png.string(), r.image, a.exposure);
    write_text_atomic(js.string(), rec.dump(2) + "\n");

    std::printf("wrote %s, %s, %s\n", exr.string().c_str(), png.string().c_str(), js.string().c_str());
    std::printf("%dx%d, %d spp in %.3f s (%s%d threads): %.3g rays/s, peak %.0f MB, %ld NaN/Inf samples\n",
                scene->camera->width(), scene->camera->height(), r.spp, r.wall_s,
                r.ranks > 1 ? fmt::format("{} ranks x ", r.ranks).c_str() : "", r.threads, r.rays_per_s, peak_rss_mb(),
                r.nan_count);
    if (rec.contains("mse"))
        std::printf("vs %s: MSE %.6g, relMSE %.6g\n", a.reference.c_str(), rec["mse"].get<double>(),
                    rec["relmse"].get<double>());
    return 0;
}

SubcommandRegistrar reg({"render", "Render a scene (JSON or glTF) to EXR + PNG + JSON record", [](CLI::App &app) {
    auto a = std::make_shared<RenderArgs>();
    app.add_option("scene", a->scene, "scene file (.json or .gltf)")->required();
    app.add_option("-o,--output", a->output, "output EXR (PNG and JSON are written beside it); default <scene>.exr");
    auto spp = app.add_option("--spp", a->spp, "samples per pixel (default: the scene sampler's sample_count)");
    app.add_option("--time", a->time, "equal-time budget in seconds: render whole passes until it is spent")->excludes(spp);
    app.add_option("--threads", a->threads, "worker threads (default: all cores)");
    app.add_option("--seed", a->seed, "sampler seed (default: the scene's)");
    app.add_option("-D,--define", a->defines, "override a scene value: -D sampler.sample_count=64 -D shapes[0].material.alpha=0.1");
    app.add_option("--reference", a->reference, "reference EXR: report MSE and relMSE");
    app.add_option("--convergence", a->convergence, "CSV of elapsed time, spp and error after each pass (needs --reference)");
    app.add_option("--max-triangles", a->max_triangles,
                   "refuse explicit tessellation (displacement mode tessellate) beyond this many triangles per shape "
                   "(default 67108864, sized for 24 GB)");
    app.add_flag("--plan", a->plan, "print what the scene will load and build, with memory, and exit");
    app.add_flag("-q,--quiet", a->quiet, "no progress output");
    app.add_option("--exposure", a->exposure, "exposure in stops for the PNG");
    return [a] { return run_render(*a); };
}});

}  // namespace
}  // namespace meso
