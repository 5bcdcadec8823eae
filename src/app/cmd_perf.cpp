// `meso perf SCENE`: ray throughput of the path tracer against bare Embree in the same run.
//
// Bare Embree traces (rtcIntersect1, closest hit, no shading) the same kinds of rays the
// path tracer traces: primary camera rays, and incoherent secondary rays (from the primary
// hit points, cosine-distributed about the normal). The path tracer's rays are split into
// primary (pixels x spp) and the rest (extension + shadow rays, counted as incoherent);
// "bare-equivalent time" is the time bare Embree needs for that same mix, and the ratio
// bare-equivalent time / path time is the fraction of bare Embree's ray rate the whole
// path tracer keeps. Shadow rays are cheaper any-hit queries, so the ratio is conservative.
#include <CLI/CLI.hpp>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <thread>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "app/commands.h"
#include "core/error.h"
#include "core/phase.h"
#include "core/output_set.h"
#include "core/text_file.h"
#include "geometry/embree_accel.h"
#include "geometry/shape.h"
#include "meso_version.h"
#include "render/renderer.h"
#include "sampling/rng.h"
#include "sampling/warp.h"
#include "render/scene.h"

namespace meso {
namespace {

struct PerfArgs {
    std::string scene, json_out;
    int spp = 4, repeats = 3;
    std::vector<int> threads = {1, 2};
    std::vector<std::string> defines;
};

double seconds_since(std::chrono::steady_clock::time_point t) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

/// Traces `rays` with closest-hit queries on `threads` threads; returns seconds.
double trace_bare(const Scene &scene, const std::vector<Ray> &rays, int threads) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, size_t(threads));
    std::atomic<int> hits{0};
    auto t0 = std::chrono::steady_clock::now();
    tbb::parallel_for(tbb::blocked_range<size_t>(0, rays.size(), 4096), [&](const tbb::blocked_range<size_t> &r) {
        int h = 0;
        for (size_t i = r.begin(); i < r.end(); ++i) h += scene.intersect_t(rays[i]) < Infinity;
        hits += h;
    });
    return seconds_since(t0);
}

/// "trace 38.1%, interaction 9.7%, ... (N samples, +-1.2% at most)" from the sampler's counts; the
/// same numbers into `out`.
std::string phase_breakdown(const PhaseSampler &ps, nlohmann::json &out) {
    const auto counts = ps.counts();
    const double n = double(std::max<uint64_t>(1, ps.total()));
    std::string text;
    double worst = 0;
    for (int i = 0; i < kPhaseCount; ++i) {
        const double p = double(counts[size_t(i)]) / n;
        worst = std::max(worst, std::sqrt(p * (1 - p) / n));
        text += fmt::format("{}{} {:.1f}%", text.empty() ? "" : ", ", phase_name(Phase(i)), 100 * p);
        out[phase_name(Phase(i))] = p;
    }
    out["samples"] = ps.total();
    return fmt::format("{} ({} profiling samples; standard error at most {:.1f}%)", text, ps.total(), 100 * worst);
}

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
}

int run_perf(const PerfArgs &a) {
    const int max_threads = 4 * int(std::max(1u, std::thread::hardware_concurrency()));
    for (int t : a.threads)
        if (t < 1 || t > max_threads)
            throw UsageError(fmt::format("--threads {}: expected 1 to {} (4 x the {} cores)", t, max_threads, max_threads / 4));
    OutputSet set;  // --json is checked before any work and may not replace the scene
    set.add_input(a.scene, "the scene file");
    const std::string json_tmp = a.json_out.empty() ? "" : set.add_output("--json", a.json_out, "", OutputKind::Record);
    set.check();
    std::unique_ptr<Scene> scene = load_scene(a.scene, a.defines);
    auto tb = std::chrono::steady_clock::now();
    scene->build();
    double build_s = seconds_since(tb);
    size_t prims = 0;
    for (auto &s : scene->shapes) prims += s->primitive_count();
    const int W = scene->camera->width(), H = scene->camera->height();

    // Ray sets: primary rays (spp jittered rays per pixel) and incoherent secondary rays.
    std::vector<Ray> primary, secondary;
    PCG32 rng(1234);
    for (int s = 0; s < a.spp; ++s)
        for (int y = 0; y < H; ++y)
            for (int x = 0; x < W; ++x) {
                CameraSample cs{{x + rng.next_float(), y + rng.next_float()}, {rng.next_float(), rng.next_float()}};
                RayDifferential r;
                scene->camera->generate_ray(cs, r);
                primary.push_back(r);
                SurfaceInteraction si;
                if (scene->intersect(r, si)) {
                    Frame f(face_forward(si.ng, si.wo));
                    Vec3 d = f.to_world(square_to_cosine_hemisphere({rng.next_float(), rng.next_float()}));
                    secondary.push_back(si.spawn_ray(d));
                }
            }
    if (secondary.empty()) throw MesoError(fmt::format("{}: the camera sees no geometry; nothing to benchmark", a.scene));

    nlohmann::json rec;
    rec["meso_version"] = MESO_VERSION;
    rec["embree"] = EmbreeAccel::version_string();
    rec["scene"] = a.scene;
    rec["primitives"] = prims;
    rec["build_s"] = build_s;
    rec["width"] = W;
    rec["height"] = H;
    rec["spp"] = a.spp;
    rec["repeats"] = a.repeats;
    std::printf("%s: %zu primitives, %dx%d, %d spp, BVH build %.3f s; medians of %d runs\n", a.scene.c_str(), prims, W, H,
                a.spp, build_s, a.repeats);
    std::printf("%7s %14s %14s %14s %14s %8s\n", "threads", "bare primary", "bare incoh.", "path tracer", "bare-equiv", "ratio");
    double path_1 = 0;
    for (int t : a.threads) {
        std::vector<double> tp, ts, tr;
        uint64_t rays = 0;
        PhaseSampler phases;
        for (int k = 0; k < a.repeats; ++k) {
            tp.push_back(trace_bare(*scene, primary, t));
            ts.push_back(trace_bare(*scene, secondary, t));
            RenderOptions o;
            o.spp = a.spp;
            o.threads = t;
            o.progress = false;
            phases.start();
            RenderResult r = render(*scene, o);
            phases.stop();
            tr.push_back(r.wall_s);
            rays = r.rays;
        }
        double prim_rate = primary.size() / median(tp), sec_rate = secondary.size() / median(ts);
        double path_s = median(tr), path_rate = rays / path_s;
        double n_primary = double(W) * H * a.spp, n_other = double(rays) - n_primary;
        double bare_equiv = n_primary / prim_rate + n_other / sec_rate;
        double ratio = bare_equiv / path_s;
        if (t == a.threads.front()) path_1 = path_s;
        std::printf("%7d %11.3g r/s %11.3g r/s %11.3g r/s %12.3f s %7.1f%%\n", t, prim_rate, sec_rate, path_rate, bare_equiv,
                    100 * ratio);
        nlohmann::json row;
        row["threads"] = t;
        row["bare_primary_rays_per_s"] = prim_rate;
        row["bare_incoherent_rays_per_s"] = sec_rate;
        row["path_rays"] = rays;
        row["path_wall_s"] = path_s;
        row["path_rays_per_s"] = path_rate;
        row["bare_equivalent_s"] = bare_equiv;
        row["path_over_bare_ratio"] = ratio;
        row["speedup_vs_first"] = path_1 / path_s;
        const std::string by_phase = phase_breakdown(phases, row["phases"]);
        std::printf("        path tracer CPU time by phase: %s\n", by_phase.c_str());
        rec["runs"].push_back(row);
    }
    if (a.threads.size() > 1)
        std::printf("path tracer speed-up %d -> %d threads: %.2fx\n", a.threads.front(), a.threads.back(),
                    rec["runs"].back()["speedup_vs_first"].get<double>());
    if (!a.json_out.empty()) {
        write_text_atomic(json_tmp, rec.dump(2) + "\n");
        set.commit();
    }
    return 0;
}

SubcommandRegistrar reg({"perf", "Ray throughput: the path tracer against bare Embree on the same kinds of rays", [](CLI::App &app) {
    auto a = std::make_shared<PerfArgs>();
    app.add_option("scene", a->scene, "scene file")->required();
    app.add_option("--spp", a->spp, "samples per pixel for every measurement")->check(CLI::PositiveNumber);
    app.add_option("--threads", a->threads, "thread counts to measure (e.g. --threads 1 2)");
    app.add_option("--repeats", a->repeats, "runs per measurement (the median is reported)")->check(CLI::PositiveNumber);
    app.add_option("-D,--define", a->defines, "override a scene value (as for render)");
    app.add_option("--json", a->json_out, "write the measurements as JSON");
    return [a] { return run_perf(*a); };
}});

}  // namespace
}  // namespace meso
