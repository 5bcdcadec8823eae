// `meso render SCENE`: check the options and outputs, load, build, render under a sample or time
// budget, write OUT.exr (float RGB with provenance metadata), OUT.png (sRGB) and OUT.json (the
// run's record) together (core/output_set.h). Ctrl-C finishes the pass and writes what is done
// (exit 130). With --crop only a
// window of the image is rendered (its pixels exactly as in a full render; `meso merge`
// puts the windows together).
#include <CLI/CLI.hpp>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <thread>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "app/commands.h"
#include "core/distributed.h"
#include "core/error.h"
#include "core/input_file.h"
#include "core/interrupt.h"
#include "core/output_set.h"
#include "core/sha1.h"
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
    bool given_spp = false, given_time = false, given_seed = false, given_threads = false;
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
            throw UsageError(fmt::format("--crop '{}': expected X0,Y0,X1,Y1, four integers (the pixel window "
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

/// What the options leave to check before any work: ranges (each error names the option and the
/// allowed range). Crop windows are checked against the camera once the scene is loaded.
void check_ranges(const RenderArgs &a) {
    if (a.given_spp && a.spp < 1) throw UsageError(fmt::format("--spp {}: expected a sample count >= 1", a.spp));
    if (a.given_time && !(std::isfinite(a.time) && a.time > 0))
        throw UsageError(fmt::format("--time {}: expected a finite number of seconds > 0", a.time));
    if (a.given_seed && a.seed < 0) throw UsageError(fmt::format("--seed {}: expected a seed >= 0", a.seed));
    const int max_threads = 4 * int(std::max(1u, std::thread::hardware_concurrency()));
    if (a.given_threads && (a.threads < 1 || a.threads > max_threads))
        throw UsageError(fmt::format("--threads {}: expected 1 to {} (4 x the {} cores)", a.threads, max_threads, max_threads / 4));
    if (!std::isfinite(a.exposure)) throw UsageError(fmt::format("--exposure {}: expected a finite number of stops", a.exposure));
    if (!a.convergence.empty() && a.reference.empty()) throw UsageError("--convergence needs --reference");
    if (a.has_crop) parse_crop(a.crop);  // its syntax here; the window against the camera once loaded
}

/// The files a scene names (maps, meshes, models): every string of a JSON scene that resolves,
/// beside the scene, to an existing regular file. They are inputs an output must not replace.
std::vector<std::string> files_named_by(const std::string &scene) {
    std::vector<std::string> out;
    namespace fs = std::filesystem;
    std::error_code ec;
    if (fs::path(scene).extension() != ".json" || !fs::is_regular_file(scene, ec) || fs::file_size(scene, ec) > (64u << 20))
        return out;
    std::ifstream f(scene);
    const nlohmann::json j = nlohmann::json::parse(f, nullptr, false, true);
    const fs::path dir = fs::path(scene).parent_path();
    std::function<void(const nlohmann::json &)> walk = [&](const nlohmann::json &v) {
        if (v.is_structured())
            for (const auto &x : v) walk(x);
        else if (v.is_string() && !v.get<std::string>().empty() && v.get<std::string>().size() < 4096 &&
                 fs::is_regular_file(dir / v.get<std::string>(), ec))
            out.push_back((dir / v.get<std::string>()).string());
    };
    if (!j.is_discarded()) walk(j);
    return out;
}

/// The run's outputs, declared in `set` with the inputs they must not replace.
struct RenderOutputs {
    std::filesystem::path exr, png, json;
    std::string exr_tmp, png_tmp, json_tmp, csv_tmp;
};

RenderOutputs declare_outputs(const RenderArgs &a, OutputSet &set) {
    namespace fs = std::filesystem;
    // Default: <stem>_render.exr in the current directory, never the scene's own name.
    RenderOutputs o;
    o.exr = a.output.empty() ? fs::path(fs::path(a.scene).stem().string() + "_render.exr") : fs::path(a.output);
    if (o.exr.extension() != ".exr") throw MesoError(fmt::format("-o {}: the output must be an .exr file", o.exr.string()));
    o.png = fs::path(o.exr).replace_extension(".png");
    o.json = fs::path(o.exr).replace_extension(".json");
    set.add_input(a.scene, "the scene file");
    for (const std::string &f : files_named_by(a.scene)) set.add_input(f, "a file the scene names");
    set.add_input(a.reference, "the reference");
    const std::string opt = a.output.empty() ? "the default output" : "-o";
    o.exr_tmp = set.add_output(opt, o.exr.string(), o.exr.string());
    o.png_tmp = set.add_output(opt, o.png.string(), o.exr.string());
    o.json_tmp = set.add_output(opt, o.json.string(), o.exr.string(), OutputKind::Record);
    if (!a.convergence.empty()) o.csv_tmp = set.add_output("--convergence", a.convergence);
    set.check();
    return o;
}

/// The loaded scene with what the record needs about it.
struct Loaded {
    std::unique_ptr<Scene> scene;
    std::string scene_sha1;
    std::optional<std::array<int, 4>> crop;
    int full_w = 0, full_h = 0, img_w = 0, img_h = 0;
    Image reference;
    double load_s = 0;
};

Loaded load(const RenderArgs &a) {
    auto t0 = std::chrono::steady_clock::now();
    Loaded l;
    if (a.has_crop) l.crop = parse_crop(a.crop);
    if (!a.reference.empty()) l.reference = read_image(a.reference);
    l.scene = load_scene(a.scene, a.defines, a.max_triangles);
    l.scene_sha1 = file_sha1(a.scene);
    l.load_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    l.full_w = l.scene->camera->width(), l.full_h = l.scene->camera->height();
    if (l.crop) check_crop(*l.crop, l.full_w, l.full_h);
    l.img_w = l.crop ? (*l.crop)[2] - (*l.crop)[0] : l.full_w, l.img_h = l.crop ? (*l.crop)[3] - (*l.crop)[1] : l.full_h;
    if (!a.reference.empty()) {
        // With --crop the reference is either the full image (its window is compared) or the window's size.
        Image &ref = l.reference;
        if (l.crop && ref.width == l.full_w && ref.height == l.full_h)
            ref = crop_image(ref, *l.crop);
        else if (ref.width != l.img_w || ref.height != l.img_h)
            throw MesoError(l.crop ? fmt::format("{}: reference is {}x{} but --crop renders {}x{} of the {}x{} image "
                                                 "(the reference must be the full image or the window's size)",
                                                 a.reference, ref.width, ref.height, l.img_w, l.img_h, l.full_w, l.full_h)
                                   : fmt::format("{}: reference is {}x{} but the camera renders {}x{}", a.reference,
                                                 ref.width, ref.height, l.full_w, l.full_h));
    }
    return l;
}

/// --plan's estimate: the shapes' memory and the film, refused before anything is allocated if it
/// exceeds the machine's physical memory.
void check_memory(const RenderArgs &a, const Loaded &l) {
    size_t need = film_bytes(l.img_w, l.img_h);
    for (const auto &s : l.scene->shapes) need += s->memory_bytes();
    const size_t have = physical_memory_bytes();
    if (have > 0 && need > have)
        throw MesoError(fmt::format("{}: the render needs about {:.2f} MB ({}x{} film and geometry, as `meso render --plan` "
                                    "lists it) but this machine has {:.0f} MB of physical memory",
                                    a.scene, need / 1048576.0, l.img_w, l.img_h, have / 1048576.0));
}

void print_plan(const RenderArgs &a, const Loaded &l, const RenderOutputs &o) {
    std::printf("plan for %s (nothing is built or rendered):\n", a.scene.c_str());
    for (auto &line : l.scene->plan()) std::printf("  %s\n", line.c_str());
    if (l.crop)
        std::printf("  crop: [%d, %d) x [%d, %d), %dx%d of the %dx%d image\n", (*l.crop)[0], (*l.crop)[2], (*l.crop)[1],
                    (*l.crop)[3], l.img_w, l.img_h, l.full_w, l.full_h);
    std::printf("  output: %s, %s, %s\n", o.exr.string().c_str(), o.png.string().c_str(), o.json.string().c_str());
}

RenderResult render_scene(const RenderArgs &a, const Loaded &l, const RenderOutputs &o, double &build_s) {
    auto tb = std::chrono::steady_clock::now();
    l.scene->build();
    build_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - tb).count();
    RenderOptions opts;
    opts.spp = a.spp;
    opts.time_budget_s = a.time;
    opts.threads = a.threads;
    opts.crop = l.crop;
    if (a.seed >= 0) opts.seed = uint64_t(a.seed);
    opts.progress = !a.quiet;
    opts.reference = a.reference.empty() ? nullptr : &l.reference;
    opts.convergence_csv = o.csv_tmp;
    opts.stop = interrupt_requested;
    return render(*l.scene, opts);
}

nlohmann::json make_record(const RenderArgs &a, const Loaded &l, const RenderResult &r, double build_s) {
    const Scene &scene = *l.scene;
    nlohmann::json rec;
    rec["meso_version"] = MESO_VERSION;
    rec["scene"] = a.scene;
    rec["scene_sha1"] = l.scene_sha1;
    rec["defines"] = a.defines;
    rec["width"] = l.img_w;  // the image written (the window's size with --crop)
    rec["height"] = l.img_h;
    if (l.crop) {
        rec["crop"] = *l.crop;
        rec["full_width"] = l.full_w;
        rec["full_height"] = l.full_h;
    }
    rec["integrator"] = scene.integrator->to_string();
    rec["sampler"] = scene.sampler->name();
    rec["seed"] = a.seed >= 0 ? a.seed : int64_t(scene.sampler->seed());
    rec["threads"] = r.threads;
    rec["ranks"] = r.ranks;
    rec["time_budget_s"] = a.time;
    rec["load_s"] = l.load_s;
    rec["build_s"] = build_s;
    rec["wall_s"] = r.wall_s;
    rec["spp"] = r.spp;
    rec["interrupted"] = r.interrupted;
    if (r.interrupted && a.time <= 0) rec["spp_requested"] = a.spp > 0 ? a.spp : scene.spp;
    rec["passes"] = r.passes;
    rec["rays"] = r.rays;
    rec["shadow_rays"] = r.shadow_rays;
    rec["rays_per_s"] = r.rays_per_s;
    rec["peak_rss_mb"] = peak_rss_mb();
    rec["nan_count"] = r.nan_count;
    // Geometry memory per shape (shell maps: prisms + heightfield, independent of tiling).
    size_t geometry_bytes = 0;
    nlohmann::json shapes = nlohmann::json::array();
    for (const auto &s : scene.shapes) {
        geometry_bytes += s->memory_bytes();
        shapes.push_back({{"shape", s->to_string()}, {"primitives", s->primitive_count()}, {"memory_bytes", s->memory_bytes()}});
    }
    rec["geometry_bytes"] = geometry_bytes;
    rec["shapes"] = shapes;
    if (!a.reference.empty()) {
        ImageMetrics m = compute_metrics(r.image, l.reference);
        rec["reference"] = a.reference;
        rec["mse"] = m.mse;
        rec["relmse"] = m.relmse;
        rec["rmse"] = m.rmse;
        rec["psnr"] = m.psnr;
        rec["mean_luminance_ratio"] = m.mean_luminance_ratio;
    }
    return rec;
}

/// The EXR's provenance (`meso merge` checks it against the record and the other parts).
ImageMetadata provenance(const nlohmann::json &rec, const Loaded &l) {
    const std::array<int, 4> c = l.crop.value_or(std::array<int, 4>{0, 0, l.full_w, l.full_h});
    return {{"version", MESO_VERSION},
            {"scene_sha1", l.scene_sha1},
            {"defines", rec["defines"].dump()},
            {"seed", rec["seed"].dump()},
            {"spp", rec["spp"].dump()},
            {"crop", fmt::format("{},{},{},{}", c[0], c[1], c[2], c[3])},
            {"full_size", fmt::format("{}x{}", l.full_w, l.full_h)}};
}

void write_outputs(const RenderArgs &a, const Loaded &l, const RenderResult &r, const nlohmann::json &rec,
                   const RenderOutputs &o, OutputSet &set) {
    write_exr(o.exr_tmp, r.image, provenance(rec, l));
    write_png(o.png_tmp, r.image, a.exposure);
    write_text_atomic(o.json_tmp, rec.dump(2) + "\n");
    set.commit();
    std::printf("wrote %s, %s, %s%s\n", o.exr.string().c_str(), o.png.string().c_str(), o.json.string().c_str(),
                a.convergence.empty() ? "" : (", " + a.convergence).c_str());
    std::printf("%dx%d%s, %d spp in %.3f s (%s%d threads): %.3g rays/s, peak %.0f MB, %ld NaN/Inf samples%s\n", l.img_w,
                l.img_h, l.crop ? fmt::format(" (crop of {}x{})", l.full_w, l.full_h).c_str() : "", r.spp, r.wall_s,
                r.ranks > 1 ? fmt::format("{} ranks x ", r.ranks).c_str() : "", r.threads, r.rays_per_s, peak_rss_mb(),
                r.nan_count, r.interrupted ? " (interrupted)" : "");
    if (rec.contains("mse"))
        std::printf("vs %s: MSE %.6g, relMSE %.6g\n", a.reference.c_str(), rec["mse"].get<double>(),
                    rec["relmse"].get<double>());
}

/// parse/check -> outputs -> load -> plan -> render -> record -> write. Exit 130 if interrupted.
int run_render(const RenderArgs &a) {
    check_ranges(a);
    OutputSet set;
    const RenderOutputs o = declare_outputs(a, set);
    install_interrupt_handler(InterruptMode::Graceful);
    const Loaded l = load(a);
    if (a.plan) {
        if (dist::rank() == 0) print_plan(a, l, o);
        return 0;
    }
    check_memory(a, l);
    double build_s = 0;
    const RenderResult r = render_scene(a, l, o, build_s);
    // Under MPI only rank 0 holds the summed film; it alone writes (docs/cluster.md).
    if (dist::rank() != 0) return r.interrupted ? kInterruptedExitCode : 0;
    write_outputs(a, l, r, make_record(a, l, r, build_s), o, set);
    return r.interrupted ? kInterruptedExitCode : 0;
}

SubcommandRegistrar reg({"render", "Render a scene (JSON or glTF) to EXR + PNG + JSON record", [](CLI::App &app) {
    auto a = std::make_shared<RenderArgs>();
    app.add_option("scene", a->scene, "scene file (.json or .gltf)")->required();
    app.add_option("-o,--output", a->output,
                   "output EXR (PNG and JSON record are written beside it); default <scene stem>_render.exr in the "
                   "current directory. An output that would replace an input is refused; all three are written "
                   "together at the end");
    auto spp = app.add_option("--spp", a->spp, "samples per pixel, >= 1 (default: the scene sampler's sample_count)");
    auto time = app.add_option("--time", a->time, "equal-time budget in seconds (finite, > 0): render whole passes until it is spent")
                    ->excludes(spp);
    auto threads = app.add_option("--threads", a->threads, "worker threads, 1 to 4 x cores (default: all cores)");
    auto seed = app.add_option("--seed", a->seed, "sampler seed, >= 0 (default: the scene's)");
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
    return [a, crop, spp, time, threads, seed] {
        a->has_crop = crop->count() > 0;
        a->given_spp = spp->count() > 0, a->given_time = time->count() > 0;
        a->given_threads = threads->count() > 0, a->given_seed = seed->count() > 0;
        return run_render(*a);
    };
}});

}  // namespace
}  // namespace meso
