// `meso prefilter (--map MAP | --generator KIND [-p key=value]...) --base MATERIAL
//                 [--scales 8,64] [-M 4] [-N 15] [--lobes 6] [--interreflections on|off]
//                 [--paths 64] [--low-paths 8] [--target-error E] [--max-rounds R] [--seed S]
//                 -o MODEL_DIR`
//
// Paper 004's precomputation (src/prefilter/): per downsampling factor, h_low by least squares
// (§4.1), the 6-lobe vMF SVNDF (§4.2), and T / S of the scaling function (§6) estimated from
// paths on the original microgeometry; writes a model directory (prefilter/model.h) that the
// `prefiltered` material and `lod.model` read.
#include <CLI/CLI.hpp>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fmt/format.h>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include "app/commands.h"
#include <tbb/global_control.h>
#include <tbb/info.h>
#include "core/distributed.h"
#include "core/error.h"
#include "geometry/heightfield.h"
#include "geometry/heightmap_gen.h"
#include "meso_version.h"
#include "prefilter/least_squares.h"
#include "prefilter/model.h"
#include "prefilter/patch_ndf.h"
#include "prefilter/scaling.h"
#include "core/progress.h"
#include "sampling/rng.h"
#include "core/registry.h"

namespace meso {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

struct PrefilterOptions {
    std::string map, generator, base = R"({"type": "diffuse", "reflectance": 0.8})", output, scales = "8,64";
    std::vector<std::string> params;
    int size = 0;
    int64_t gen_seed = -1;
    double height_scale = 1.0, tile_size = 1.0;
    int M = 4, N = 15, lobes = 6, samples_per_cell = 2, paths = 64, low_paths = 64, low_nodes = 4, max_rounds = 8;
    int quad_polar = 3, quad_azimuth = 4;  // 12 nodes per lobe: render cost of f'_low (see README)
    std::string interreflections = "on", flow = "eq5";
    double target_error = 0, epsilon = 1e-2;
    uint64_t seed = 1;
    int threads = 0;  ///< 0: the node's cores / the MPI ranks on it
    bool quiet = false;
};

std::vector<int> parse_scales(const std::string &s) {
    std::vector<int> out;
    std::stringstream ss(s);
    std::string tok;
    while (std::getline(ss, tok, ',')) {
        try {
            size_t pos = 0;
            const int f = std::stoi(tok, &pos);
            if (pos != tok.size() || f < 2) throw std::invalid_argument("");
            if (!out.empty() && f <= out.back()) throw MesoError(fmt::format("--scales {}: factors must increase", s));
            out.push_back(f);
        } catch (const std::invalid_argument &) {
            throw MesoError(fmt::format("--scales {}: expected comma-separated integers >= 2, e.g. 8,64", s));
        } catch (const std::out_of_range &) {
            throw MesoError(fmt::format("--scales {}: factor out of range", s));
        }
    }
    if (out.empty()) throw MesoError("--scales: expected at least one factor, e.g. 8,64");
    return out;
}

nlohmann::json stats_json(const prefilter::ScalingStats &s, bool ir) {
    nlohmann::json j = {{"orig_lines", s.orig_lines},
                        {"low_lines", s.low_lines},
                        {"orig_path_vertices", s.orig_vertices},
                        {"rejected_lines", s.rejected},
                        {"leaked_lines", s.leaked},
                        {"rounds", s.rounds},
                        {"core_seconds_orig", s.core_seconds_orig},
                        {"core_seconds_low", s.core_seconds_low},
                        {"S_rel_std_error", {{"median", s.S_rel_se_median}, {"p90", s.S_rel_se_p90}, {"max", s.S_rel_se_max},
                                             {"median_outer_ring", s.S_rel_se_median_outer},
                                             {"median_at_paper_counts", s.S_rel_se_median_paper_counts}}},
                        {"T_rel_std_error_max", s.T_rel_se_max},
                        {"rank1", {{"energy_sigma1_sq", s.rank1_energy},
                                   {"svd_rel_error", s.rank1_svd_rel_error},
                                   {"TS_rel_error", s.ts_rel_error}, {"paper_eq22_24_rel_error", s.paper_ts_rel_error},
                                   {"singular_values", s.singular_values}}}};
    if (ir) {
        j["S_ir_rel_std_error"] = {{"median", s.S_ir_rel_se_median}, {"p90", s.S_ir_rel_se_p90},
                                   {"median_outer_ring", s.S_ir_rel_se_median_outer},
                                   {"median_at_paper_counts", s.S_ir_rel_se_median_paper_counts}};
        j["T_ir_rel_std_error_max"] = s.T_ir_rel_se_max;
        j["rank1_ir"] = {{"energy_sigma1_sq", s.rank1_energy_ir},
                         {"svd_rel_error", s.rank1_svd_rel_error_ir},
                         {"TS_rel_error", s.ts_rel_error_ir}, {"paper_eq22_24_rel_error", s.paper_ts_rel_error_ir},
                         {"singular_values", s.singular_values_ir}};
    }
    return j;
}

int run_prefilter(const PrefilterOptions &o) {
    const auto t_all = Clock::now();
    if (o.threads < 0) throw MesoError("prefilter: --threads: expected a positive count");
    const int threads = o.threads > 0 ? o.threads : std::max(1, tbb::info::default_concurrency() / dist::local_size());
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, size_t(threads));
    if (o.output.empty()) throw MesoError("prefilter: -o/--output DIR is required");
    if (o.map.empty() == o.generator.empty())
        throw MesoError("prefilter: give exactly one of --map FILE and --generator KIND");
    if (o.interreflections != "on" && o.interreflections != "off")
        throw MesoError(fmt::format("--interreflections {}: expected on or off", o.interreflections));
    if (!(o.height_scale > 0) || !std::isfinite(o.height_scale) || !(o.tile_size > 0) || !std::isfinite(o.tile_size))
        throw MesoError("--height-scale and --tile-size must be positive and finite");
    const bool ir = o.interreflections == "on";
    const std::vector<int> scales = parse_scales(o.scales);

    // Inputs: the map and the base material.
    nlohmann::json input;
    HeightMap map;
    bool periodic = true;
    if (!o.map.empty()) {
        map = read_height_map(o.map);
        input["map"] = fs::absolute(o.map).string();
    } else {
        std::map<std::string, std::string> params;
        for (const std::string &kv : o.params) {
            const size_t eq = kv.find('=');
            if (eq == std::string::npos || eq == 0) throw MesoError(fmt::format("-p {}: expected key=value", kv));
            params[kv.substr(0, eq)] = kv.substr(eq + 1);
        }
        if (o.size > 0) params["size"] = std::to_string(o.size);
        if (o.gen_seed >= 0) params["seed"] = std::to_string(o.gen_seed);
        GeneratedMap g = generate_height_map(o.generator, params, "--generator " + o.generator);
        map = std::move(g.height);
        periodic = g.periodic;
        input["generator"] = {{"kind", o.generator}, {"params", g.params}};
    }
    if (!periodic)
        if (dist::rank() == 0) std::fprintf(stderr, "prefilter: warning: the map does not tile; it is treated as periodic (seam included)\n");
    nlohmann::json base_json;
    std::string base_dir;
    std::shared_ptr<Material> base = load_material_arg(o.base, base_json, &base_dir);
    if (base->is_delta_only() || base->has_transmission())
        throw MesoError("--base: the base BRDF must be reflection-only and not purely specular (diffuse, rough "
                        "conductor or plastic)");
    for (int f : scales)
        if (map.width % f || map.height % f || (map.width / f) % o.M || (map.height / f) % o.M)
            throw MesoError(fmt::format("--scales {}: factor {} must divide the map size {}x{} and leave a multiple "
                                        "of M = {} coarse cells",
                                        o.scales, f, map.width, map.height, o.M));
    if (o.M < 1 || o.N < 1 || o.N > 64 || o.lobes < 1 || o.lobes > 16)
        throw MesoError("prefilter: need M >= 1, 1 <= N <= 64, 1 <= lobes <= 16");
    input["map_width"] = map.width;
    input["map_height"] = map.height;
    input["height_scale"] = o.height_scale;
    input["tile_size"] = o.tile_size;
    input["base"] = base_json;
    input["base_dir"] = base_dir.empty() ? fs::current_path().string() : fs::absolute(base_dir).string();
    input["periodic"] = periodic;

    prefilter::PrefilteredModel model;
    model.map_width = map.width;
    model.map_height = map.height;
    model.height_scale = o.height_scale;
    model.tile_size = o.tile_size;
    model.base = base_json;
    model.lobes = o.lobes;
    if (o.flow != "visible" && o.flow != "eq5") throw MesoError(fmt::format("--flow {}: expected visible or eq5", o.flow));
    model.quadrature = {o.quad_polar, o.quad_azimuth, o.flow == "visible"};
    model.manifest["meso_version"] = MESO_VERSION;
    model.manifest["input"] = input;
    model.manifest["parameters"] = {{"scales", scales}, {"M", o.M}, {"N", o.N}, {"lobes", o.lobes},
                                    {"interreflections", ir}, {"paths_per_bin", o.paths},
                                    {"low_paths_per_bin", o.low_paths}, {"low_nodes", o.low_nodes}, {"target_error", o.target_error},
                                    {"max_rounds", o.max_rounds}, {"epsilon", o.epsilon}, {"seed", o.seed},
                                    {"ndf_samples_per_cell", o.samples_per_cell},
                                    {"quadrature_polar", o.quad_polar}, {"quadrature_azimuth", o.quad_azimuth},
                                    {"flow_projected_area", o.flow == "visible"},
                                    {"lsq_w", 0.01}};

    // Cell-space heightfield of the original (Euclidean cells, see effective_brdf.h).
    const double cells_per_unit = double(map.width) / o.tile_size;
    const Heightfield orig(map, float(o.height_scale * cells_per_unit), 0.f);
    const Heightfield orig_map_units(map, 1.f, 0.f);
    if (dist::rank() == 0) std::fprintf(stderr, "prefilter: %dx%d map, base %s, scales %s, M = %d, N = %d, %d lobes, interreflections %s\n",
                 map.width, map.height, base->to_string().c_str(), o.scales.c_str(), o.M, o.N, o.lobes,
                 o.interreflections.c_str());

    for (size_t li = 0; li < scales.size(); ++li) {
        const int F = scales[li];
        prefilter::PrefilteredLevel L;
        L.factor = F;
        nlohmann::json timing;
        // §4.1: h_low.
        auto t0 = Clock::now();
        prefilter::LowResHeights low = prefilter::downsample_least_squares(map, F, true, 0.01);
        L.h_low = HeightMap(low.width, low.height);
        for (size_t k = 0; k < low.h.size(); ++k) L.h_low.h[k] = float(low.h[k]);
        timing["least_squares_s"] = since(t0);
        // §4.2: the SVNDF.
        t0 = Clock::now();
        prefilter::PatchNdfOptions nopt;
        nopt.samples_per_cell = o.samples_per_cell;
        nopt.height_scale = o.height_scale;
        nopt.cell_size = o.tile_size / map.width;
        nopt.em.lobes = o.lobes;
        nopt.em.exact_kappa = true;
        // Flat patches are deltas: with the EM's default cap (1e6) the lobe's 1e-3 rad spread
        // still cuts nodes off for ωo within 0.06° of the horizon; 1e9 (vmf.h's limit) makes
        // that 3e-5 rad.
        nopt.em.max_kappa = 1e9;
        L.ndf = prefilter::fit_svndf(orig_map_units, F, nopt);
        timing["svndf_fit_s"] = since(t0);
        size_t converged = 0;
        double mean_it = 0;
        for (const auto &p : L.ndf) converged += p.converged, mean_it += p.iterations;
        if (dist::rank() == 0) std::fprintf(stderr, "  x%d: h_low %dx%d (%.2f s), SVNDF %zu patches (%.2f s, %.0f EM iterations on average)\n", F,
                     low.width, low.height, timing["least_squares_s"].get<double>(), L.ndf.size(),
                     timing["svndf_fit_s"].get<double>(), mean_it / double(L.ndf.size()));
        // §6: T and S.
        t0 = Clock::now();
        auto low_mat = std::make_shared<prefilter::SvMultiLobe>(base, L.ndf, low.width, low.height, model.quadrature);
        timing["multilobe_build_s"] = since(t0);
        const Heightfield low_field(L.h_low, float(o.height_scale * double(low.width) / o.tile_size), 0.f);
        prefilter::ScalingOptions sopt;
        sopt.M = o.M;
        sopt.N = o.N;
        sopt.interreflections = ir;
        sopt.orig_paths = o.paths;
        sopt.low_paths = o.low_paths;
        sopt.low_nodes = o.low_nodes;
        sopt.epsilon = o.epsilon;
        sopt.seed = hash_combine(o.seed, uint64_t(F));
        Progress progress(!o.quiet && dist::rank() == 0, 1.0, "");
        const auto t_round = std::make_shared<Clock::time_point>(Clock::now());
        int round = 0;
        sopt.progress = [&](double frac) {
            progress.update(frac, since(*t_round), fmt::format("x{} T/S round {}", F, round + 1));
        };
        prefilter::ScalingEstimator est(orig, *base, low_field, *low_mat, sopt);
        t0 = Clock::now();
        double se = 0;
        for (round = 0; round < std::max(1, o.max_rounds); ++round) {
            *t_round = Clock::now();
            est.add_round();
            progress.finish(since(*t_round));
            se = est.current_S_rel_se();
            if (dist::rank() == 0) std::fprintf(stderr, "  x%d: round %d: median relative std. error of S%s %.4f (%.1f s)\n", F, round + 1,
                         ir ? "_ir" : "", se, since(t0));
            if (!(o.target_error > 0) || se <= o.target_error) break;
        }
        prefilter::ScalingStats st;
        est.finish(L.single, L.ir, st);
        timing["scaling_s"] = since(t0);
        L.stats = stats_json(st, ir);
        L.stats["timing"] = timing;
        L.stats["svndf"] = {{"converged_patches", converged}, {"mean_em_iterations", mean_it / double(L.ndf.size())},
                            {"multilobe_memory_bytes", low_mat->memory_bytes()}};
        L.stats["storage_bytes"] = {{"h_low", L.h_low.memory_bytes()},
                                    {"lobes", L.ndf.size() * size_t(5 * o.lobes + 1) * sizeof(float)},
                                    {"T", size_t(o.M) * o.M * 3 * sizeof(float) * (ir ? 2 : 1)},
                                    {"S", size_t(o.N) * o.N * o.N * o.N * 3 * sizeof(float) * (ir ? 2 : 1)}};
        if (dist::rank() == 0) std::fprintf(stderr,
                     "  x%d: T/S %.1f s; S rel. std. error median %.4f (grazing ring %.4f; paper's counts: %.4f)%s; rank-1 energy %.4f, "
                     "|R - T S| / |R| = %.4f vs rank-1 SVD %.4f\n",
                     F, timing["scaling_s"].get<double>(), ir ? st.S_ir_rel_se_median : st.S_rel_se_median,
                     ir ? st.S_ir_rel_se_median_outer : st.S_rel_se_median_outer,
                     ir ? st.S_ir_rel_se_median_paper_counts : st.S_rel_se_median_paper_counts, ir ? " (ir)" : "",
                     ir ? st.rank1_energy_ir : st.rank1_energy, ir ? st.ts_rel_error_ir : st.ts_rel_error,
                     ir ? st.rank1_svd_rel_error_ir : st.rank1_svd_rel_error);
        model.levels.push_back(std::move(L));
    }
    model.manifest["total_seconds"] = since(t_all);
    // Under MPI every rank holds the same tables (ScalingEstimator::add_round); rank 0 writes.
    model.manifest["ranks"] = dist::size();
    if (dist::rank() != 0) return 0;
    model.save(o.output);
    std::printf("%s\n", fmt::format("prefilter: wrote {} ({} levels, {:.1f} s{})", o.output, scales.size(),
                                    since(t_all), dist::size() > 1 ? fmt::format(", {} ranks", dist::size()) : "")
                             .c_str());
    return 0;
}

SubcommandRegistrar reg_prefilter{
    {"prefilter", "Precompute a prefiltered LoD model of a displacement map (paper 004): h_low, vMF SVNDF, T and S",
     [](CLI::App &app) -> std::function<int()> {
         auto o = std::make_shared<PrefilterOptions>();
         app.add_option("--map", o->map, "height map file (EXR/PNG; periodic, heights in map units)");
         app.add_option("--generator", o->generator, "or a generator of `meso genmap` (fbm, twill, sawtooth, ...)");
         app.add_option("-p,--param", o->params, "generator parameter key=value (repeatable)");
         app.add_option("--size", o->size, "generator: vertices per side")->check(CLI::Range(2, 16384));
         app.add_option("--map-seed", o->gen_seed, "generator: random seed")->check(CLI::NonNegativeNumber);
         app.add_option("--height-scale", o->height_scale, "world height per map unit (as the displacement's scale)")->capture_default_str();
         app.add_option("--tile-size", o->tile_size, "world size of one map tile (square cells)")->capture_default_str();
         app.add_option("--base", o->base, "base BRDF: inline JSON material or a JSON file")->capture_default_str();
         app.add_option("--scales", o->scales, "downsampling factors, comma-separated")->capture_default_str();
         app.add_option("-M", o->M, "spatial resolution of T (M x M)")->capture_default_str()->check(CLI::Range(1, 256));
         app.add_option("-N", o->N, "angular resolution of S (N² x N² bins)")->capture_default_str()->check(CLI::Range(1, 64));
         app.add_option("--lobes", o->lobes, "vMF lobes per patch NDF")->capture_default_str()->check(CLI::Range(1, 16));
         app.add_option("--interreflections", o->interreflections, "also estimate T_ir, S_ir (on|off)")->capture_default_str();
         app.add_option("--paths", o->paths, "lines of sight per (T patch, wo bin) per round on the original")->capture_default_str()
             ->check(CLI::Range(1, 1 << 20));
         app.add_option("--low-paths", o->low_paths, "lines of sight per (T patch, wo bin) per round on h_low")->capture_default_str()
             ->check(CLI::Range(1, 1 << 20));
         app.add_option("--low-nodes", o->low_nodes,
                        "f'_low nodes sampled per line on h_low (0: the full deterministic quadrature)")
             ->capture_default_str()
             ->check(CLI::Range(0, 4096));
         app.add_option("--target-error", o->target_error,
                        "rounds until the median relative std. error of S is below this (0: one round)")->capture_default_str();
         app.add_option("--max-rounds", o->max_rounds, "at most this many rounds")->capture_default_str()->check(CLI::Range(1, 1000));
         app.add_option("--ndf-samples", o->samples_per_cell, "n x n micro-normals per fine cell for the NDF fit")->capture_default_str()
             ->check(CLI::Range(1, 32));
         app.add_option("--quadrature", o->quad_polar, "f'_low quadrature: nodes per lobe in the vMF CDF variable")->capture_default_str()
             ->check(CLI::Range(1, 64));
         app.add_option("--quadrature-azimuth", o->quad_azimuth, "f'_low quadrature: azimuthal nodes")->capture_default_str()
             ->check(CLI::Range(1, 256));
         app.add_option("--flow", o->flow,
                        "f'_low: visible (facets weighted by their projected area towards the viewer) or eq5 "
                        "(paper 004 eq. 5 as printed)")
             ->capture_default_str();
         app.add_option("--epsilon", o->epsilon, "eq. 12's epsilon, relative to the mean denominator")->capture_default_str();
         app.add_option("--seed", o->seed, "random seed of the estimators")->capture_default_str();
         app.add_option("-o,--output", o->output, "model directory to write");
         app.add_flag("-q,--quiet", o->quiet, "no progress bar");
         app.add_option("--threads", o->threads, "worker threads (default: all cores, shared among the MPI ranks on a node)");
         return [o] { return run_prefilter(*o); };
     }}};

}  // namespace
}  // namespace meso
