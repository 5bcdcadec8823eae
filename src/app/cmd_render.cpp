// `meso render SCENE`: load, build, render under a sample or time budget, write
// OUT.exr (float RGB), OUT.png (sRGB) and OUT.json (the run's record). With --crop only a
// window of the image is rendered (its pixels exactly as in a full render; `meso merge`
// puts the windows together).
#include <CLI/CLI.hpp>
#include <charconv>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "app/commands.h"
#include "core/distributed.h"
#include "core/error.h"
#include "core/text_file.h"
#include "geometry/embree_accel.h"
#include "meso_version.h"
#include "render/renderer.h"
#include "geometry/shape.h"
#include "render/scene.h"

namespace meso {
namespace {

struct RenderArgs {
    std::string scene, output, reference, convergence, crop;
    int spp = 0, threads = 0;
    double time = 0;
    int64_t seed = -1;
    std::vector<std::string> defines;
    bool plan = false, quiet = false, has_crop = false;
    size_t max_triangles = 0;
    float exposure = 0.f;
};

/// "X0,Y0,X1,Y1" -> {X0, Y0, X1, Y1} (four integers; the range is checked against the camera later).
std::array<int, 4> parse_crop(const std::string &text) {
    std::array<int, 4> c{};
    size_t pos = 0;
    for (int i = 0; i < 4; ++i) {
        size_t end = i < 3 ? text.find(',', pos) : text.size();
        if (end == std::string::npos) end = text.size();
        const char *b = text.data() + pos, *e = text.data() + end;
        auto [p, ec] = std::from_chars(b, e, c[i]);
        if (b == e || ec != std::errc() || p != e || (i < 3 && end == text.size()))
            throw MesoError(fmt::format("--crop '{}': expected X0,Y0,X1,Y1, four integers (the pixel window "
                                        "[X0, X1) x [Y0, Y1) of the full image)", text));
        pos = end + 1;
    }
    return c;
}

/// The window [x0, x1) x [y0, y1) of `img`.
Image crop_image(const Image &img, const std::array<int, 4> &c) {
    Image out(c[2] - c[0], c[3] - c[1], img.channels);
    for (int y = 0; y < out.height; ++y)
        for (int x = 0; x < out.width; ++x)
            for (int k = 0; k < img.channels; ++k) out.at(x, y, k) = img.at(x + c[0], y + c[1], k);
    return out;
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

    std::optional<std::array<int, 4>> crop;
    if (a.has_crop) crop = parse_crop(a.crop);
    Image reference;
    if (!a.reference.empty()) reference = read_image(a.reference);
    if (!a.convergence.empty() && a.reference.empty()) throw MesoError("--convergence needs --reference");

    std::unique_ptr<Scene> scene = load_scene(a.scene, a.defines, a.max_triangles);
    double load_s = since(t0);
    const int full_w = scene->camera->width(), full_h = scene->camera->height();
    if (crop) check_crop(*crop, full_w, full_h);
    const int img_w = crop ? (*crop)[2] - (*crop)[0] : full_w, img_h = crop ? (*crop)[3] - (*crop)[1] : full_h;
    if (!a.reference.empty()) {
        // With --crop the reference is either the full image (its window is compared) or the window's size.
        if (crop && reference.width == full_w && reference.height == full_h)
            reference = crop_image(reference, *crop);
        else if (reference.width != img_w || reference.height != img_h)
            throw MesoError(crop ? fmt::format("{}: reference is {}x{} but --crop renders {}x{} of the {}x{} image "
                                               "(the reference must be the full image or the window's size)",
                                               a.reference, reference.width, reference.height, img_w, img_h, full_w, full_h)
                                 : fmt::format("{}: reference is {}x{} but the camera renders {}x{}", a.reference,
                                               reference.width, reference.height, full_w, full_h));
    }
    if (a.plan) {
        if (dist::rank() != 0) return 0;
        std::printf("plan for %s (nothing is built or rendered):\n", a.scene.c_str());
        for (auto &line : scene->plan()) std::printf("  %s\n", line.c_str());
        if (crop)
            std::printf("  crop: [%d, %d) x [%d, %d), %dx%d of the %dx%d image\n", (*crop)[0], (*crop)[2], (*crop)[1],
                        (*crop)[3], img_w, img_h, full_w, full_h);
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
    opts.crop = crop;
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
    rec["width"] = img_w;  // the image written (the window's size with --crop)
    rec["height"] = img_h;
    if (crop) {
        rec["crop"] = *crop;
        rec["full_width"] = full_w;
        rec["full_height"] = full_h;
    }
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
    std::printf("%dx%d%s, %d spp in %.3f s (%s%d threads): %.3g rays/s, peak %.0f MB, %ld NaN/Inf samples\n",
                img_w, img_h, crop ? fmt::format(" (crop of {}x{})", full_w, full_h).c_str() : "", r.spp, r.wall_s,
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
    auto crop = app.add_option("--crop", a->crop,
                   "render only the pixel window X0,Y0,X1,Y1 ([X0, X1) x [Y0, Y1) of the full image; its pixels are "
                   "those of a full render with the same seed and spp): `meso merge` joins the windows");
    app.add_option("--reference", a->reference, "reference EXR: report MSE and relMSE (with --crop: the full image or the window's size)");
    app.add_option("--convergence", a->convergence, "CSV of elapsed time, spp and error after each pass (needs --reference)");
    app.add_option("--max-triangles", a->max_triangles,
                   "refuse explicit tessellation (displacement mode tessellate) beyond this many triangles per shape "
                   "(default 67108864, sized for 24 GB)");
    app.add_flag("--plan", a->plan, "print what the scene will load and build, with memory, and exit");
    app.add_flag("-q,--quiet", a->quiet, "no progress output");
    app.add_option("--exposure", a->exposure, "exposure in stops for the PNG");
    return [a, crop] {
        a->has_crop = crop->count() > 0;
        return run_render(*a);
    };
}});

}  // namespace
}  // namespace meso
