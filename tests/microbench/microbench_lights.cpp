// meso_microbench_lights: the cost of one light sample per light type (issue 22, "a Google
// Benchmark target covers ... light sample per light type").
//
// One light sample is what next-event estimation asks of a light at a path vertex:
// sample(ctx, u) and then pdf(ctx, wi, hit) of the sampled direction (what MIS asks when BSDF
// sampling finds the light; the path tracer makes that call for other directions, the cost is
// the same). Every benchmark walks the same 4096 shading points and uniforms (fixed seed).
// Lights (scene-file JSON through the registry, as a scene would build them):
//   point, spot, directional, constant      delta lights and the uniform environment
//   area_quad/room                          perf_area.json's ceiling quad (1 x 1 at y = 2.99),
//                                           points uniform in its 3 x 3 x 3 room (near and far)
//   area_quad/far                           the same quad, points 20 to 40 units away
//   area_mesh/room                          a 16 x 16 uvsphere emitter (radius 0.3) in the room
//   envmap                                  a 512 x 256 procedural sky with a sun (in memory)
// Defaults (overridable on the command line): 5 repetitions, randomly interleaved, aggregates
// only; a table of median ns per sample at the end. Not run by CTest (timings are no test).
#include <benchmark/benchmark.h>
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <vector>
#include <nlohmann/json.hpp>
#include "core/properties.h"
#include "core/registry.h"
#include "core/transform.h"
#include "geometry/shape.h"
#include "image/image.h"
#include "lights/envmap.h"
#include "lights/light.h"
#include "median_reporter.h"

namespace {

using namespace meso;
using json = nlohmann::json;

struct Input {
    Vec3 p;
    Vec2 u;
};
constexpr size_t kInputs = 4096;  // a power of two

std::vector<Input> make_inputs(Vec3 lo, Vec3 hi, uint32_t seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> U(0.f, 1.f);
    std::vector<Input> v(kInputs);
    for (Input &x : v) {
        x.p = Vec3(lo.x + (hi.x - lo.x) * U(rng), lo.y + (hi.y - lo.y) * U(rng), lo.z + (hi.z - lo.z) * U(rng));
        x.u = Vec2(std::min(U(rng), OneMinusEpsilon), std::min(U(rng), OneMinusEpsilon));
    }
    return v;
}

void light_sample(benchmark::State &state, const Light *light, const std::vector<Input> *in, uint32_t prims) {
    size_t i = 0, k = 0;
    for (auto _ : state) {
        const Input &x = (*in)[i];
        i = (i + 1) & (kInputs - 1);
        const LightSampleContext ctx{x.p, Vec3()};
        LightSample ls;
        const bool ok = light->sample(ctx, x.u, ls);
        float pdf = 0.f;
        if (ok && !ls.delta) {
            const LightHit hit{x.p + ls.wi * (std::isfinite(ls.dist) ? ls.dist : 1.f), -ls.wi, uint32_t(k++ % prims)};
            pdf = light->pdf(ctx, ls.wi, hit);
        }
        benchmark::DoNotOptimize(ls);
        benchmark::DoNotOptimize(pdf);
    }
}

std::shared_ptr<Light> light_from_json(const json &j) {
    return create_light(Properties(j, "lights[0]", std::make_shared<LoadContext>()));
}
std::shared_ptr<Shape> shape_from_json(const json &j) {
    return create_shape(Properties(j, "shapes[0]", std::make_shared<LoadContext>()));
}

/// A sky: blue gradient, brighter towards the horizon, and a 1-degree sun 10^4 times brighter.
Image sky(int w, int h) {
    Image img(w, h, 3);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const Vec3 d = EnvMapLight::uv_to_direction({(x + 0.5f) / w, (y + 0.5f) / h});
            const float t = std::max(d.y, 0.f);
            Spectrum s(0.4f + 0.6f * (1 - t), 0.5f + 0.4f * (1 - t), 1.f);
            if (dot(d, normalize(Vec3(0.3f, 0.6f, 0.5f))) > std::cos(0.5f * Pi / 180.f)) s = Spectrum(1e4f);
            img.set_rgb(x, y, d.y < 0.f ? Spectrum(0.1f) : s);
        }
    return img;
}


}  // namespace

int main(int argc, char **argv) {
    std::vector<std::string> args = {argv[0], "--benchmark_repetitions=5", "--benchmark_enable_random_interleaving=true",
                                     "--benchmark_report_aggregates_only=true", "--benchmark_min_time=0.2"};
    for (int a = 1; a < argc; ++a) args.push_back(argv[a]);
    std::vector<char *> argp;
    for (std::string &s : args) argp.push_back(s.data());
    int n = int(argp.size());
    benchmark::Initialize(&n, argp.data());
    if (benchmark::ReportUnrecognizedArguments(n, argp.data())) return 1;

    const std::vector<Input> room = make_inputs({-1.5f, 0.f, -1.5f}, {1.5f, 2.9f, 1.5f}, 22);
    const std::vector<Input> far = make_inputs({-20.f, -40.f, -20.f}, {20.f, -20.f, 20.f}, 23);
    const std::vector<Input> sphere = make_inputs({-10.f, -10.f, -10.f}, {10.f, 10.f, 10.f}, 24);
    struct Entry {
        std::string name;
        std::shared_ptr<Light> light;
        std::shared_ptr<Shape> shape;
        const std::vector<Input> *in;
        uint32_t prims = 1;
    };
    std::vector<Entry> entries;
    try {
        entries.push_back({"point", light_from_json({{"type", "point"}, {"position", {0, 2.9, 0}}, {"intensity", 10}}), nullptr, &room});
        entries.push_back({"spot", light_from_json({{"type", "spot"}, {"position", {0, 2.9, 0}}, {"direction", {0, -1, 0}}, {"intensity", 10}}), nullptr, &room});
        entries.push_back({"directional", light_from_json({{"type", "directional"}, {"direction", {0.2, -1, 0.1}}, {"irradiance", 3}}), nullptr, &room});
        entries.push_back({"constant", light_from_json({{"type", "constant"}, {"radiance", 1}}), nullptr, &sphere});
        const json quad = {{"type", "rectangle"},
                           {"to_world", {{"scale", 0.5}, {"rotate", {{"axis", {1, 0, 0}}, {"angle", 90}}}, {"translate", {0, 2.99, 0}}}}};
        const json ball = {{"type", "uvsphere"}, {"rings", 16}, {"segments", 16},
                           {"to_world", {{"scale", 0.3}, {"translate", {0, 2.2, 0}}}}};
        for (auto [name, shape_json, in] : {std::tuple{"area_quad/room", quad, &room}, std::tuple{"area_quad/far", quad, &far},
                                           std::tuple{"area_mesh/room", ball, &room}}) {
            Entry e{name, light_from_json({{"type", "area"}, {"radiance", 12}}), shape_from_json(shape_json), in};
            e.light->set_shape(e.shape.get());
            e.light->preprocess(Vec3(), 3.f);
            e.prims = uint32_t(e.shape->primitive_count());
            entries.push_back(e);
        }
        entries.push_back({"envmap", std::make_shared<EnvMapLight>(sky(512, 256), 1.f, Transform()), nullptr, &sphere});
        for (Entry &e : entries) e.light->preprocess(Vec3(), 3.f);
    } catch (const std::exception &e) {
        std::fprintf(stderr, "meso_microbench_lights: setup failed: %s\n", e.what());
        return 1;
    }
    for (const Entry &e : entries)
        benchmark::RegisterBenchmark(("light_sample/" + e.name).c_str(), light_sample, e.light.get(), e.in, e.prims)
            ->Unit(benchmark::kNanosecond);
    meso::bench::MedianReporter rep;
    benchmark::RunSpecifiedBenchmarks(&rep);
    std::printf("\nMedian CPU ns per light sample (sample + pdf of the sampled direction)\n");
    for (const auto &[name, t] : rep.ns) std::printf("  %-28s %8.1f\n", name.c_str(), t);
    benchmark::Shutdown();
    return 0;
}
