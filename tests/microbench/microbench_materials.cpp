// meso_microbench: the cost of one shading sample per material (issue 21 item 3: "per shading
// sample, eval + sample + pdf of `prefiltered` costs at most 1.5x the base material's on the
// same flat surface").
//
// One shading sample is what a path vertex asks of its material: eval_pdf(wo, wi_light) (the
// next-event estimate) + sample(wo, u_lobe, u) (the continuation) + pdf(wo, wi_sampled)
// ("shade/..."); "vertex/..." leaves out the pdf call, which the path tracer does not make
// (sample returns the pdf). Every benchmark walks the same fixed set of 4096 inputs (wo
// cosine-distributed, wi_light uniform on the hemisphere, uv uniform over the map, uniforms for
// the lobe choice, the direction and u_eval), on a flat surface whose shading frame is the macro
// frame (no rotation). Materials:
//   <base>                             the base BRDF alone: diffuse, conductor (rough, Beckmann),
//                                      plastic (rough GGX coat)
//   prefiltered:<base>:quadrature      `prefiltered` on a model that `meso prefilter`'s pipeline
//   prefiltered:<base>:stochastic      builds here with that base (fbm map 128², level x8 =
//                                      16 x 16 patches, 6 lobes, 3 x 4 quadrature nodes per lobe,
//                                      N = 15, M = 4; few paths: the tables' noise does not
//                                      change the cost)
//   prefiltered:<base>:stratified<m>   the same with "estimator": "stratified", estimator_nodes m
//   prefiltered:<base>:lobes           a model of the same map and options made with --flow lobes (the
//                                      closed-form f'_low of prefilter/lobe_brdf.h; diffuse and conductor
//                                      bases: conductor = Beckmann, conductor_ggx = GGX)
//   prefiltered:<base>:lobes_area      that model loaded as one made before parameters.microfacet_view
//                                      (microfacet lobes weighted by their area, not their visible share)
//   the other materials (issue 22: "BSDF sample and eval per material"): rough dielectric,
//   blinnphong, gltf_pbr, leadr, lean, clean, toksvig, vmf (two lobes), normalmap, each at one
//   typical setting, listed in a second table
// "micro/<name>": eval_pdf + sample (a path vertex) on MICROGEOMETRY, as on a shell-mapped LoD
// level: the shading frame tilted by 14 degrees against the macro frame, which the context
// carries (n_macro, dpdu_macro), so `prefiltered` rotates its directions into the model's frame
// and back; for the lobes-form materials and their bases (which ignore the macro frame).
// uv: "--uv=random" (default) puts every input on a random texel of the map, so the model's
// per-texel data (≈ 1.5 KB of node weights and normals) and the S table (0.6 MB) are mostly out
// of the nearest caches, as for incoherent secondary rays; "--uv=one" keeps all on one texel
// (the S lookups still follow the random directions), a bound for coherent camera rays.
// At the end a table prints the median CPU ns per shading sample and the ratio prefiltered /
// base, from the same run. Defaults (overridable on the command line): 5 repetitions, randomly
// interleaved across benchmarks (the machine's speed drifts; medians compare like with like),
// aggregates only. Not run by CTest.
#include <benchmark/benchmark.h>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <vector>
#include <unistd.h>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "bsdf/material.h"
#include "core/math.h"
#include "core/properties.h"
#include "core/registry.h"
#include "prefilter/model.h"
#include "prefilter/pipeline.h"
#include "median_reporter.h"

namespace {

using namespace meso;
namespace fs = std::filesystem;

struct Input {
    Vec3 wo, wl;
    Vec2 uv, u;
    float u_lobe, u_eval;
};

constexpr size_t kInputs = 4096;  // a power of two
constexpr int kSetNodes[] = {4, 8};  // "stratified" estimator_nodes measured
bool g_one_texel = false;         // --uv=one: every input on one texel (see the header)

const std::vector<Input> &inputs() {
    static const std::vector<Input> in = [] {
        std::mt19937 rng(21);
        std::uniform_real_distribution<float> U(0.f, 1.f);
        auto u01 = [&] { return std::min(U(rng), 0x1.fffffep-1f); };
        std::vector<Input> v(kInputs);
        for (Input &x : v) {
            // wo cosine-distributed (what a camera sees of a plane, roughly), wl uniform.
            const float r = std::sqrt(u01()), phi = 2.f * Pi * u01();
            x.wo = normalize(Vec3(r * std::cos(phi), r * std::sin(phi), std::sqrt(std::max(1e-4f, 1.f - r * r))));
            const float z = std::max(1e-3f, u01()), s = std::sqrt(1.f - z * z), p2 = 2.f * Pi * u01();
            x.wl = Vec3(s * std::cos(p2), s * std::sin(p2), z);
            x.uv = Vec2(u01(), u01());
            if (g_one_texel) x.uv = Vec2(0.3f, 0.6f);
            x.u = Vec2(u01(), u01());
            x.u_lobe = u01();
            x.u_eval = u01();
        }
        return v;
    }();
    return in;
}

std::shared_ptr<Material> material_from_json(const nlohmann::json &j) {
    return create_material(Properties(j, "material", std::make_shared<LoadContext>()));
}

struct Base {
    std::string name;
    const char *json;
    bool lobes = false;  ///< --flow lobes supports this base (prefilter/lobe_brdf.h)
};

const std::vector<Base> kBases = {
    {"diffuse", R"({"type": "diffuse", "reflectance": [0.75, 0.45, 0.3]})", true},
    {"conductor", R"({"type": "conductor", "material": "Au", "distribution": "beckmann", "alpha": 0.25})", true},
    {"conductor_ggx", R"({"type": "conductor", "material": "Au", "distribution": "ggx", "alpha": 0.2})", true},
    {"plastic", R"({"type": "plastic", "diffuse_reflectance": [0.5, 0.2, 0.1], "distribution": "ggx", "alpha": 0.2})"},
};
constexpr int kFactor = 8;

/// Every other registered material at one typical setting (issue 22's per-material cost).
const std::vector<Base> kOthers = {
    {"dielectric", R"({"type": "dielectric", "alpha": 0.2})"},
    {"blinnphong", R"({"type": "blinnphong", "exponent": 50, "specular_reflectance": 0.7, "diffuse_reflectance": 0.3})"},
    {"gltf_pbr", R"({"type": "gltf_pbr", "base_color": [0.8, 0.6, 0.4], "metallic": 0.3, "roughness": 0.5})"},
    {"leadr", R"({"type": "leadr", "material": "Cu", "covariance": [0.09, 0.02, 0.03]})"},
    {"lean", R"({"type": "lean", "covariance": [0.09, 0.02, 0.03]})"},
    {"clean", R"({"type": "clean", "covariance": [0.09, 0.01, 0.02], "exponent": 200})"},
    {"toksvig", R"({"type": "toksvig", "exponent": 300, "average_normal": [0, 0, 0.9]})"},
    {"vmf", R"({"type": "vmf", "lobes": [{"direction": [0.70710678, 0, 0.70710678], "kappa": 128},
                                        {"direction": [-0.70710678, 0, 0.70710678], "kappa": 128}]})"},
    {"normalmap", R"({"type": "normalmap", "normal": [0.3, 0.1, 0.9], "bsdf": {"type": "conductor", "material": "Au", "alpha": 0.2}})"},
};

/// A small model made by the prefilter pipeline with this base (see the header), written to dir;
/// lobes: with --flow lobes (the closed-form f'_low).
void build_small_model(const Base &b, const std::string &dir, bool lobes) {
    prefilter::PipelineOptions o;
    o.generator = "fbm";
    o.generator_params = {{"size", "128"}, {"amplitude", "0.03"}, {"frequency", "4"}};
    o.base = b.json;
    o.scales = {kFactor};
    o.M = 4;
    o.N = 15;
    o.interreflections = false;
    o.paths = o.low_paths = 4;
    o.quiet = true;
    o.flow_lobes = lobes;
    prefilter::build_model(o).save(dir);
}

/// One shading sample per iteration (see the header); with_pdf adds the pdf of the sampled
/// direction; micro: on microgeometry (the header's "micro/").
void shading_sample(benchmark::State &state, const Material *m, bool with_pdf, bool micro) {
    const std::vector<Input> &in = inputs();
    ShadingContext ctx;  // flat: identity frame, right-handed uv (dp/du = s, dp/dv = t)
    ctx.dpdu = Vec3(1.f, 0.f, 0.f);
    ctx.dpdv = Vec3(0.f, 1.f, 0.f);
    if (micro) {
        ctx.frame = Frame::from_normal_tangent(normalize(Vec3(0.2f, -0.15f, 1.f)), Vec3(1.f, 0.f, 0.f));
        ctx.n_macro = Vec3(0.f, 0.f, 1.f);
        ctx.dpdu_macro = Vec3(1.f, 0.f, 0.f);
        ctx.dpdv_macro = Vec3(0.f, 1.f, 0.f);
    }
    size_t i = 0;
    for (auto _ : state) {
        const Input &x = in[i];
        i = (i + 1) & (kInputs - 1);
        ctx.uv = x.uv;
        ctx.u_eval = x.u_eval;
        float p = 0.f;
        Spectrum f = m->eval_pdf(ctx, x.wo, x.wl, &p);
        BSDFSample bs;
        const bool ok = m->sample(ctx, x.wo, x.u_lobe, x.u, bs);
        float q = ok && with_pdf ? m->pdf(ctx, x.wo, bs.wi) : 0.f;
        benchmark::DoNotOptimize(f);
        benchmark::DoNotOptimize(p);
        benchmark::DoNotOptimize(bs);
        benchmark::DoNotOptimize(q);
    }
}

void print_summary(const std::map<std::string, double> &ns) {
    std::printf("\nMedian CPU ns per shading sample (ratio = prefiltered / base, same run; uv: %s)\n",
                g_one_texel ? "one texel" : "a random texel per sample");
    for (const char *kind : {"shade", "vertex", "micro"}) {
        const std::string k = kind;
        std::printf("%s: %s\n", kind,
                    k == "shade"    ? "eval_pdf + sample + pdf(sampled)"
                    : k == "vertex" ? "eval_pdf + sample"
                                    : "eval_pdf + sample on microgeometry (tilted shading frame)");
        std::printf("  %-10s %10s %14s %8s %14s %8s %14s %8s", "base", "base ns", "lobes ns", "ratio", "quadrature ns",
                    "ratio", "stochastic ns", "ratio");
        for (int nodes : kSetNodes) std::printf(" %13s%-2d %8s", "stratified", nodes, "ratio");
        std::printf("\n");
        for (const Base &b : kBases) {
            auto get = [&](const std::string &n) {
                auto it = ns.find(fmt::format("{}/{}", kind, n));
                return it == ns.end() ? -1.0 : it->second;
            };
            const double base = get(b.name), q = get("prefiltered:" + b.name + ":quadrature"),
                         s = get("prefiltered:" + b.name + ":stochastic"), l = get("prefiltered:" + b.name + ":lobes");
            if (base < 0) continue;
            auto ratio = [&](double v) { return v < 0 ? std::string("-") : fmt::format("{:.2f}x", v / base); };
            std::printf("  %-10s %10.1f %14.1f %8s %14.1f %8s %14.1f %8s", b.name.c_str(), base, l, ratio(l).c_str(), q,
                        ratio(q).c_str(), s, ratio(s).c_str());
            for (int nodes : kSetNodes) {
                const double v = get(fmt::format("prefiltered:{}:stratified{}", b.name, nodes));
                std::printf(" %15.1f %8s", v, ratio(v).c_str());
            }
            std::printf("\n");
        }
    }
    std::printf("Other materials, median CPU ns per shading sample (shade / vertex)\n");
    for (const Base &b : kOthers) {
        auto a = ns.find("shade/" + b.name), v = ns.find("vertex/" + b.name);
        if (a != ns.end() && v != ns.end()) std::printf("  %-10s %10.1f %10.1f\n", b.name.c_str(), a->second, v->second);
    }
}

/// Registers shade/NAME and vertex/NAME for material m, and micro/NAME with `micro`.
void register_material(const std::string &name, const Material *m, bool micro = false) {
    for (bool with_pdf : {true, false})
        benchmark::RegisterBenchmark(fmt::format("{}/{}", with_pdf ? "shade" : "vertex", name).c_str(), shading_sample, m,
                                     with_pdf, false)
            ->Unit(benchmark::kNanosecond);
    if (micro)
        benchmark::RegisterBenchmark(fmt::format("micro/{}", name).c_str(), shading_sample, m, false, true)
            ->Unit(benchmark::kNanosecond);
}

}  // namespace

int main(int argc, char **argv) {
    const bool ok = bench::initialize(argc, argv, [](const std::string &arg) {
        if (arg != "--uv=one" && arg != "--uv=random") return false;
        g_one_texel = arg == "--uv=one";
        return true;
    });
    if (!ok) return 1;

    const fs::path scratch = fs::temp_directory_path() / fmt::format("meso_microbench_{}", ::getpid());
    std::vector<std::shared_ptr<Material>> keep;
    try {
        for (const Base &b : kBases) {
            const std::string dir = (scratch / b.name).string();
            build_small_model(b, dir, false);
            std::vector<std::pair<std::string, std::shared_ptr<Material>>> mats = {
                {b.name, material_from_json(nlohmann::json::parse(b.json))}};
            for (const char *est : {"quadrature", "stochastic"})
                mats.push_back({fmt::format("prefiltered:{}:{}", b.name, est),
                                material_from_json({{"type", "prefiltered"}, {"model", dir}, {"level", kFactor},
                                                    {"estimator", est}})});
            for (int nodes : kSetNodes)
                mats.push_back({fmt::format("prefiltered:{}:stratified{}", b.name, nodes),
                                material_from_json({{"type", "prefiltered"}, {"model", dir}, {"level", kFactor},
                                                    {"estimator", "stratified"}, {"estimator_nodes", nodes}})});
            if (b.lobes) {  // the same map and options with --flow lobes
                build_small_model(b, dir + "_lobes", true);
                mats.push_back({fmt::format("prefiltered:{}:lobes", b.name),
                                material_from_json({{"type", "prefiltered"}, {"model", dir + "_lobes"}, {"level", kFactor}})});
                // The same model as one made before parameters.microfacet_view: microfacet lobes with
                // their area weights (lobe_brdf.h), to price the visible form's view weights.
                prefilter::PrefilteredModel old = prefilter::PrefilteredModel::load(dir + "_lobes");
                old.manifest["parameters"].erase("microfacet_view");
                old.save(dir + "_lobes_area");
                mats.push_back({fmt::format("prefiltered:{}:lobes_area", b.name),
                                material_from_json({{"type", "prefiltered"}, {"model", dir + "_lobes_area"}, {"level", kFactor}})});
            }
            for (auto &[name, m] : mats) {
                keep.push_back(m);
                register_material(name, m.get(), b.lobes && (name == b.name || name.find(":lobes") != std::string::npos));
            }
        }
        for (const Base &b : kOthers) {
            keep.push_back(material_from_json(nlohmann::json::parse(b.json)));
            register_material(b.name, keep.back().get());
        }
    } catch (const std::exception &e) {
        std::fprintf(stderr, "meso_microbench: setup failed: %s\n", e.what());
        return 1;
    }
    return bench::run(print_summary, scratch);
}
