// meso_microbench_trace (issue 22 item 2, "shell maps near triangle cost"): the cost of a ray on
// shell-mapped displacement against the same surface explicitly tessellated into triangles.
//
// Two scenes differ only in the displacement mode: a 2 x 2 plane (two base triangles) displaced
// by a generated fbm map (size --map, default 1024 as in scenes/displacement/plane_1k_*.json;
// amplitude 0.03, frequency 4, scale 2), "shell" (two prisms, one Embree primitive as a flat
// quad, traced by the heightfield intersector) or "tessellate" (2 map^2 triangles in Embree). The
// camera is that of plane_1k.
// Benchmarks (median CPU ns per ray, or per sample for path/):
//   hit/<mode>        Scene::intersect (closest hit + SurfaceInteraction) of 4096 camera rays,
//                     one a pixel through a 64 x 64 tile at the image centre in raster order (as
//                     a render visits a tile; --rays=random: random pixels of the whole image),
//                     all of which hit the surface in both scenes
//   hit_t/<mode>      the closest-hit distance only (no interaction)
//   occluded/<mode>   Scene::occluded of the same camera rays (every one is occluded)
//   shadow/<mode>     Scene::occluded of rays spawned at each scene's own camera hits towards
//                     4096 cosine-distributed directions about the macro normal (a next-event ray
//                     towards an environment: some blocked by the relief, most not)
//   field/<kernel>    the heightfield intersector alone on the scene's map, in the shell's cell
//                     space: 4096 rays, half from just above the slab going down, half leaving
//                     the surface going up (cosine-distributed), closest hit with the SIMD
//                     traversal (intersect) and the scalar reference (intersect_reference)
//   path/<mode>       one full path per sample: the scene rendered at 64 x 64, 1 spp, 1 thread
//                     (path tracer, depth 6, constant sky + sun), time / 4096 samples
// A table at the end gives the medians and shell / triangle. Defaults (overridable): 5
// repetitions, randomly interleaved, aggregates only. Not run by CTest. Run:
// build/bench/meso_microbench_trace [--map=256] [--rays=random] [--benchmark_filter=hit]
#include <benchmark/benchmark.h>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <vector>
#include <unistd.h>
#include <fmt/format.h>
#include "core/math.h"
#include "geometry/shell_shape.h"
#include "render/renderer.h"
#include "render/scene.h"
#include "median_reporter.h"

namespace {

using namespace meso;
namespace fs = std::filesystem;

constexpr size_t kRays = 4096;  // a power of two
int g_map = 1024;
bool g_random_pixels = false;  // --rays=random: camera rays through random pixels of the whole image

std::string scene_json(const char *mode, int width, int height) {
    return fmt::format(R"({{
  "camera": {{"type": "perspective", "origin": [0, 1.3, 1.9], "target": [0, 0, -0.1], "up": [0, 1, 0],
             "fov": 40, "width": {}, "height": {}}},
  "integrator": {{"type": "path", "max_depth": 6}},
  "sampler": {{"type": "sobol", "sample_count": 1, "seed": 1}},
  "shapes": [
    {{"type": "rectangle", "to_world": {{"rotate": {{"axis": [1, 0, 0], "angle": -90}}}},
     "material": {{"type": "conductor", "material": "Cu", "alpha": 0.12}},
     "displacement": {{"map": {{"generator": "fbm", "size": {}, "octaves": 6, "amplitude": 0.03, "frequency": 4}},
                      "scale": 2, "tiling": 1, "mode": "{}"}}}}
  ],
  "lights": [{{"type": "constant", "radiance": 0.6}},
             {{"type": "directional", "direction": [-0.4, -1.0, -0.6], "irradiance": 3}}]
}})",
                       width, height, g_map, mode);
}

std::unique_ptr<Scene> make_scene(const fs::path &dir, const char *mode, int width, int height) {
    const fs::path p = dir / fmt::format("{}_{}x{}.json", mode, width, height);
    std::ofstream(p) << scene_json(mode, width, height);
    auto s = load_scene(p.string(), {});
    s->build();
    return s;
}

struct Rays {
    std::vector<Ray> camera;                    ///< hit the surface in both scenes
    std::vector<Ray> shadow_tri, shadow_shell;  ///< from each scene's own hits
};

/// Camera rays through random pixels that hit both surfaces, and shadow rays from their hits.
Rays make_rays(const Scene &tri, const Scene &shell) {
    std::mt19937 rng(22);
    std::uniform_real_distribution<float> U(0.f, 1.f);
    Rays r;
    const Camera &cam = *tri.camera;
    for (int guard = 0; r.camera.size() < kRays && guard < 100 * int(kRays); ++guard) {
        CameraSample cs;
        // A 64 x 64 pixel tile at the image centre in raster order, one jittered ray a pixel
        // (coherent, as a render visits a tile), or random pixels over the image.
        const int k = int(r.camera.size()), px = cam.width() / 2 - 32 + k % 64, py = cam.height() / 2 - 32 + k / 64;
        cs.film = g_random_pixels ? Vec2(U(rng) * float(cam.width()), U(rng) * float(cam.height()))
                                  : Vec2(float(px) + U(rng), float(py) + U(rng));
        cs.lens = Vec2(0.5f, 0.5f);
        RayDifferential rd;
        cam.generate_ray(cs, rd);
        const Ray ray(rd.o, rd.d);
        SurfaceInteraction a, b;
        if (!tri.intersect(ray, a) || !shell.intersect(ray, b)) continue;
        // Cosine-distributed about the macro normal (+y).
        const float rr = std::sqrt(U(rng)), phi = 2.f * Pi * U(rng);
        const Vec3 dir(rr * std::cos(phi), std::sqrt(std::max(0.f, 1.f - rr * rr)), rr * std::sin(phi));
        r.camera.push_back(ray);
        r.shadow_tri.push_back(a.spawn_ray(dir));
        r.shadow_shell.push_back(b.spawn_ray(dir));
    }
    if (r.camera.size() < kRays) throw std::runtime_error("too few camera rays hit the surface");
    return r;
}

void bench_hit(benchmark::State &state, const Scene *s, const std::vector<Ray> *rays) {
    size_t i = 0;
    for (auto _ : state) {
        SurfaceInteraction si;
        bool hit = s->intersect((*rays)[i], si);
        benchmark::DoNotOptimize(hit);
        benchmark::DoNotOptimize(si.t);
        i = (i + 1) & (kRays - 1);
    }
}

/// intersect_t (occluded = false) or occluded per iteration: one float or bool of answer.
void bench_bare(benchmark::State &state, const Scene *s, const std::vector<Ray> *rays, bool occluded) {
    size_t i = 0;
    for (auto _ : state) {
        const Ray &r = (*rays)[i];
        float answer = occluded ? float(s->occluded(r)) : s->intersect_t(r);
        benchmark::DoNotOptimize(answer);
        i = (i + 1) & (kRays - 1);
    }
}

/// Rays in the heightfield's cell space as the shell gives them on this plane (cells are
/// width / 2 a world unit, heights are in world units): even ones from just above the slab,
/// cosine-distributed downwards; odd ones leaving the surface, cosine-distributed upwards (a
/// diffuse bounce, the long grazing walks through the slab).
struct FieldRays {
    std::vector<Vec3> o, d;
};

FieldRays make_field_rays(const Heightfield &hf) {
    std::mt19937 rng(23);
    std::uniform_real_distribution<double> U(0.0, 1.0);
    const double cells_per_unit = hf.width() / 2.0;
    FieldRays r;
    for (size_t k = 0; k < kRays; ++k) {
        const double u1 = U(rng), phi = 2 * 3.14159265358979 * U(rng), ct = std::sqrt(1 - u1), st = std::sqrt(u1);
        const bool up = k % 2 == 1;
        const float x = float(hf.width() * U(rng)), y = float(hf.height() * U(rng));
        r.d.push_back(Vec3(float(st * std::cos(phi) * cells_per_unit), float(st * std::sin(phi) * cells_per_unit),
                           float(up ? ct : -ct)));
        r.o.push_back(Vec3(x, y, up ? hf.eval(x, y) + 1e-5f : hf.max_height() + 1e-3f));
    }
    return r;
}

void bench_field(benchmark::State &state, const Heightfield *hf, const FieldRays *rays, bool reference) {
    size_t i = 0;
    for (auto _ : state) {
        HeightfieldHit h;
        bool hit = reference ? hf->intersect_reference(rays->o[i], rays->d[i], 0.f, Infinity, h)
                             : hf->intersect(rays->o[i], rays->d[i], 0.f, Infinity, h);
        benchmark::DoNotOptimize(hit);
        benchmark::DoNotOptimize(h.t);
        i = (i + 1) & (kRays - 1);
    }
}

void bench_path(benchmark::State &state, const Scene *s) {
    RenderOptions o;
    o.spp = 1;
    o.threads = 1;
    o.seed = 5;
    o.progress = false;
    for (auto _ : state) {
        RenderResult r = render(*s, o);
        benchmark::DoNotOptimize(r.image.data.data());
    }
}

void print_summary(const std::map<std::string, double> &ns) {
    std::printf("\nMedian CPU ns per ray (path: per sample), map %d^2, camera rays %s; ratio = shell / triangle, same "
                "run\n",
                g_map, g_random_pixels ? "through random pixels" : "through a 64 x 64 tile");
    std::printf("  %-10s %12s %12s %8s\n", "kind", "triangle", "shell", "ratio");
    if (ns.count("field/simd") && ns.count("field/reference"))
        std::printf("  heightfield alone: SIMD %.1f ns, scalar reference %.1f ns (%.2fx)\n", ns.at("field/simd"),
                    ns.at("field/reference"), ns.at("field/simd") / ns.at("field/reference"));
    for (const char *kind : {"hit", "hit_t", "occluded", "shadow", "path"}) {
        auto get = [&](const std::string &mode) {
            auto it = ns.find(fmt::format("{}/{}", kind, mode));
            return it == ns.end() ? -1.0 : it->second;
        };
        double t = get("triangle"), s = get("shell");
        if (t < 0 || s < 0) continue;
        const double per = std::string(kind) == "path" ? 64.0 * 64.0 : 1.0;
        std::printf("  %-10s %12.1f %12.1f %7.2fx\n", kind, t / per, s / per, s / t);
    }
}

}  // namespace

int main(int argc, char **argv) {
    const bool ok = bench::initialize(argc, argv, [](const std::string &arg) {
        if (arg.rfind("--map=", 0) == 0) g_map = std::max(2, std::atoi(arg.c_str() + 6));
        else if (arg == "--rays=random" || arg == "--rays=tile") g_random_pixels = arg == "--rays=random";
        else return false;
        return true;
    });
    if (!ok) return 1;

    const fs::path scratch = fs::temp_directory_path() / fmt::format("meso_microbench_trace_{}", ::getpid());
    fs::create_directories(scratch);
    std::unique_ptr<Scene> tri, shell, tri_small, shell_small;
    Rays rays;
    FieldRays field_rays;
    const Heightfield *field = nullptr;
    try {
        tri = make_scene(scratch, "tessellate", 512, 512);
        shell = make_scene(scratch, "shell", 512, 512);
        tri_small = make_scene(scratch, "tessellate", 64, 64);
        shell_small = make_scene(scratch, "shell", 64, 64);
        rays = make_rays(*tri, *shell);
        auto *shape = dynamic_cast<const ShellShape *>(shell->shapes.at(0).get());
        if (!shape) throw std::runtime_error("the shell scene's shape is no ShellShape");
        field = shape->displacement().field.get();
        field_rays = make_field_rays(*field);
    } catch (const std::exception &e) {
        std::fprintf(stderr, "meso_microbench_trace: setup failed: %s\n", e.what());
        return 1;
    }
    for (const auto &[mode, s, small, shadow] :
         {std::tuple{"triangle", tri.get(), tri_small.get(), &rays.shadow_tri},
          std::tuple{"shell", shell.get(), shell_small.get(), &rays.shadow_shell}}) {
        const std::string m = mode;
        benchmark::RegisterBenchmark(("hit/" + m).c_str(), bench_hit, s, &rays.camera)->Unit(benchmark::kNanosecond);
        benchmark::RegisterBenchmark(("hit_t/" + m).c_str(), bench_bare, s, &rays.camera, false)->Unit(benchmark::kNanosecond);
        benchmark::RegisterBenchmark(("occluded/" + m).c_str(), bench_bare, s, &rays.camera, true)
            ->Unit(benchmark::kNanosecond);
        benchmark::RegisterBenchmark(("shadow/" + m).c_str(), bench_bare, s, shadow, true)->Unit(benchmark::kNanosecond);
        benchmark::RegisterBenchmark(("path/" + m).c_str(), bench_path, small)->Unit(benchmark::kNanosecond);
    }
    for (bool reference : {false, true})
        benchmark::RegisterBenchmark(reference ? "field/reference" : "field/simd", bench_field, field, &field_rays, reference)
            ->Unit(benchmark::kNanosecond);
    return bench::run(print_summary, scratch);
}
