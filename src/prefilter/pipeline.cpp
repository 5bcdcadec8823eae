// Paper 004's precomputation, stage by stage: see pipeline.h.
#include "prefilter/pipeline.h"
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <future>
#include <thread>
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <memory>
#include <nlohmann/json.hpp>
#include <tbb/parallel_for.h>
#include "core/distributed.h"
#include "core/error.h"
#include "core/output_set.h"
#include "core/progress.h"
#include "core/properties.h"
#include "core/registry.h"
#include "geometry/heightfield.h"
#include "geometry/heightmap_gen.h"
#include "meso_version.h"
#include "prefilter/least_squares.h"
#include "prefilter/level_error.h"
#include "prefilter/patch_ndf.h"
#include "prefilter/scaling.h"
#include "sampling/rng.h"

namespace meso::prefilter {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

/// Paper 004 §4.1's regulariser weight w (eq. 10), recorded in the manifest.
constexpr double kLsqW = 0.01;

std::string scales_text(const std::vector<int> &scales) { return fmt::format("{}", fmt::join(scales, ",")); }

/// The map, the base BRDF and the manifest's "input" record.
struct Inputs {
    HeightMap map;
    bool periodic = true;
    WrapMode wrap = WrapMode::Repeat;  ///< with clamp or mirror, `map` is the 2W x 2H extension
    std::shared_ptr<Material> base;
    nlohmann::json base_json;
    nlohmann::json record;
    std::string no_lobes;  ///< why --flow lobes cannot take this base (empty: it can)
};

/// Stage 1: the height map (a file or a generator) and the base BRDF, checked against the options.
Inputs load_inputs(const PipelineOptions &o) {
    Inputs in;
    if (!o.map.empty()) {
        in.map = read_height_map(o.map);
        in.record["map"] = fs::absolute(o.map).string();
    } else {
        GeneratedMap g = generate_height_map(o.generator, o.generator_params, "--generator " + o.generator);
        in.map = std::move(g.height);
        in.periodic = g.periodic;
        in.record["generator"] = {{"kind", o.generator}, {"params", g.params}};
    }
    const std::string wrap = o.wrap.empty() ? (in.periodic ? "repeat" : "clamp") : o.wrap;
    in.wrap = WrapMode(parse_choice("--wrap", wrap, {"repeat", "clamp", "mirror"}));
    if (!in.periodic && in.wrap == WrapMode::Repeat && dist::rank() == 0)
        std::fprintf(stderr, "prefilter: warning: the map does not tile and --wrap repeat treats it as periodic (seam included)\n");
    in.map = periodic_extension(in.map, in.wrap);
    in.record["wrap"] = wrap_mode_name(in.wrap);
    std::string base_dir;
    in.base = load_material_arg(o.base, in.base_json, &base_dir);
    if (in.base->is_delta_only() || in.base->has_transmission())
        throw MesoError("--base: the base BRDF must be reflection-only and not purely specular (diffuse, rough "
                        "conductor or plastic)");
    try {
        make_lobe_base(in.base, in.base_json, "--base");
    } catch (const MesoError &e) {
        if (o.flow_lobes) throw;  // --flow lobes refuses other bases before the work
        in.no_lobes = e.what();
    }
    const HeightMap &map = in.map;
    for (int f : o.scales)
        if (map.width % f || map.height % f || (map.width / f) % o.M || (map.height / f) % o.M)
            throw MesoError(fmt::format("--scales {}: factor {} must divide the map size {}x{} and leave a multiple "
                                        "of M = {} coarse cells",
                                        scales_text(o.scales), f, map.width, map.height, o.M));
    in.record["map_width"] = map.width;
    in.record["map_height"] = map.height;
    in.record["height_scale"] = o.height_scale;
    nlohmann::json samples = nlohmann::json::array();
    for (auto [i, j] : map_fingerprint_vertices(map.width, map.height)) samples.push_back(map.at(i, j));
    in.record["map_samples"] = samples;
    in.record["tile_size"] = o.tile_size * (in.wrap == WrapMode::Repeat ? 1 : 2);  // of the map prefiltered
    in.record["base"] = in.base_json;
    in.record["base_dir"] = base_dir.empty() ? fs::current_path().string() : fs::absolute(base_dir).string();
    in.record["periodic"] = in.periodic;
    return in;
}

/// Stage 2: the model without levels, its manifest holding every parameter.
PrefilteredModel empty_model(const PipelineOptions &o, const Inputs &in) {
    PrefilteredModel model;
    model.map_width = in.map.width;
    model.map_height = in.map.height;
    model.height_scale = o.height_scale;
    model.tile_size = o.tile_size;
    model.base = in.base_json;
    model.lobes = o.lobes;
    model.quadrature = {o.quad_polar, o.quad_azimuth, o.flow_projected_area && !o.flow_lobes, o.flow_lobes};
    model.manifest["meso_version"] = MESO_VERSION;
    model.manifest["input"] = in.record;
    model.manifest["parameters"] = {{"scales", o.scales}, {"M", o.M}, {"N", o.N}, {"lobes", o.lobes},
                                    {"interreflections", o.interreflections}, {"paths_per_bin", o.paths},
                                    {"low_paths_per_bin", o.low_paths}, {"low_nodes", o.low_nodes}, {"cv_lines", o.cv_lines}, {"shadow_roulette", o.shadow_roulette},
                                    {"allocate_lines", o.allocate_lines},
                                    {"reciprocity", o.cv_lines > 0 || o.reciprocity == 0 ? "off" : o.reciprocity == 1 ? "check" : "on"},
                                    {"directions", o.jitter_directions ? "jitter" : "centres"}, {"target_error", o.target_error},
                                    {"max_rounds", o.max_rounds}, {"max_seconds", o.max_seconds}, {"epsilon", o.epsilon}, {"seed", o.seed},
                                    {"ndf_samples_per_cell", o.samples_per_cell}, {"ndf_tolerance", o.ndf_tolerance},
                                    {"ndf_start", o.ndf_from_children ? "children" : "kmeans"},
                                    {"quadrature_polar", o.quad_polar}, {"quadrature_azimuth", o.quad_azimuth},
                                    {"flow_projected_area", o.flow_projected_area && !o.flow_lobes},
                                    {"flow", flow_name(model.quadrature)}, {"albedo", "patch_mean"}, {"lambert_view", "visible"},
                                    {"microfacet_view", "visible"}, {"quadrature_weights", "share"},
                                    {"lsq_w", kLsqW}};
    return model;
}

/// The original microgeometry in two units: cell space (Euclidean cells, effective_brdf.h) for
/// the paths, map units for the SVNDF fit.
struct OriginalFields {
    Heightfield cells, map_units;
};

/// §4.1: h_low by least squares of the slopes (eq. 9-10), as a float map, and its seconds.
struct LowStage {
    HeightMap h_low;
    double seconds = 0;
};
LowStage least_squares_stage(const HeightMap &map, int F) {
    const auto t0 = Clock::now();
    const LowResHeights low = downsample_least_squares(map, F, true, kLsqW);
    LowStage out{HeightMap(low.width, low.height), 0.0};
    for (size_t k = 0; k < low.h.size(); ++k) out.h_low.h[k] = float(low.h[k]);
    out.seconds = since(t0);
    return out;
}

/// §4.2: the patch NDFs (eq. 4) of the original, one per coarse cell.
/// With a finer level (`finer` at factor finer_F dividing F, and --ndf-start children), every
/// patch's EM starts from its children's lobes (fit_svndf_from).
std::vector<PatchNdf> svndf_stage(const PipelineOptions &o, const HeightMap &map, const Heightfield &map_units, int F,
                                  const std::vector<PatchNdf> *finer, int finer_F, nlohmann::json &timing) {
    const auto t0 = Clock::now();
    PatchNdfOptions nopt;
    nopt.samples_per_cell = o.samples_per_cell;
    nopt.height_scale = o.height_scale;
    nopt.cell_size = o.tile_size / map.width;
    nopt.em.lobes = o.lobes;
    nopt.em.exact_kappa = true;
    // Flat patches are deltas: with the EM's default cap (1e6) the lobe's 1e-3 rad spread
    // still cuts nodes off for ωo within 0.06° of the horizon; 1e9 (vmf.h's limit) makes
    // that 3e-5 rad.
    nopt.em.max_kappa = 1e9;
    nopt.em.tolerance = o.ndf_tolerance;
    const bool from = o.ndf_from_children && finer && finer_F > 0 && F % finer_F == 0;
    nopt.start_from_cells = o.ndf_from_children && !from;  // the first level: from its cells' normals
    std::vector<PatchNdf> ndf = from ? fit_svndf_from(map_units, F, *finer, finer_F, nopt) : fit_svndf(map_units, F, nopt);
    timing["svndf_fit_s"] = since(t0);
    timing["svndf_start"] =
        from ? fmt::format("x{} children", finer_F) : std::string(nopt.start_from_cells ? "cells" : "kmeans++");
    return ndf;
}

/// One level before and after its T / S: h_low, the SVNDF, f'_low, the field and the estimator.
struct LevelWork {
    PrefilteredLevel L;
    nlohmann::json timing;
    size_t converged = 0;
    double mean_it = 0, mean_ll = 0;  ///< the SVNDF fit's mean M-steps and log-likelihood a patch
    std::shared_ptr<SvMultiLobe> low_mat;
    std::unique_ptr<Heightfield> low_field;
    std::unique_ptr<ScalingEstimator> est;
};

ScalingOptions scaling_options(const PipelineOptions &o, uint64_t seed) {
    ScalingOptions sopt;
    sopt.M = o.M;
    sopt.N = o.N;
    sopt.interreflections = o.interreflections;
    sopt.orig_paths = o.paths;
    sopt.low_paths = o.low_paths;
    sopt.low_nodes = o.low_nodes;
    sopt.cv_lines = o.cv_lines;
    sopt.shadow_roulette = o.shadow_roulette;
    sopt.allocate_lines = o.allocate_lines;
    sopt.reciprocity = o.reciprocity == 2;
    sopt.check_reciprocity = o.reciprocity >= 1;
    sopt.jitter_directions = o.jitter_directions;
    sopt.epsilon = o.epsilon;
    sopt.target_error = o.target_error;
    sopt.seed = seed;
    return sopt;
}

/// §6: rounds of the T/S estimator (eq. 12, 20-24) for every level at once (the original's
/// lines shared, ScalingEstimator::add_round_group) until the median relative standard error of
/// every level's S tables reaches --target-error (only the ωo bins above it are traced again,
/// scaling.h "Stopping rule"), --max-rounds, or what is left of --max-seconds would be exceeded
/// by another round as long as the last; fills each level's tables, its stats into `st`.
void scaling_stage(const PipelineOptions &o, const Heightfield &orig, const Material &base,
                   std::vector<LevelWork> &levels, double seconds_budget, std::vector<ScalingStats> &st) {
    const bool ir = o.interreflections;
    std::string names;
    for (const LevelWork &w : levels) names += fmt::format("{}x{}", names.empty() ? "" : ",", w.L.factor);
    ScalingOptions sopt = scaling_options(o, hash_combine(o.seed, uint64_t(levels.front().L.factor)));
    Progress progress(!o.quiet && dist::rank() == 0, 1.0, "");
    const auto t_round = std::make_shared<Clock::time_point>(Clock::now());
    int round = 0;
    std::vector<ScalingEstimator *> group;
    for (LevelWork &w : levels) {
        w.est = std::make_unique<ScalingEstimator>(orig, base, *w.low_field, *w.low_mat, sopt);
        group.push_back(w.est.get());
    }
    group.front()->set_progress([&](double frac) {
        progress.update(frac, since(*t_round), fmt::format("{} T/S round {}", names, round + 1));
    });
    const auto t0 = Clock::now();
    double se = 0, last = 0;
    for (round = 0; round < std::max(1, o.max_rounds); ++round) {
        if (round > 0 && seconds_budget > 0 && since(t0) + last > seconds_budget) break;
        *t_round = Clock::now();
        const size_t traced = ScalingEstimator::add_round_group(group);
        last = since(*t_round);
        progress.finish(last);
        if (traced == 0) break;
        // Each level's check is a fit of its T and S (three channels in parallel): the levels'
        // fits run side by side, which keeps more than three cores busy.
        std::vector<double> level_se(group.size(), 0.0);
        tbb::parallel_for(size_t(0), group.size(), [&](size_t j) { level_se[j] = group[j]->current_S_rel_se(); });
        se = *std::max_element(level_se.begin(), level_se.end());
        if (dist::rank() == 0)
            std::fprintf(stderr, "  %s: round %d: %zu tasks, median relative std. error of S%s %.4f (%.1f s)\n",
                         names.c_str(), round + 1, traced,
                         ir ? " (single and ir, the larger; the worst level)" : " (the worst level)", se, since(t0));
        if (!(o.target_error > 0) || se <= o.target_error) break;
    }
    group.front()->set_progress(nullptr);
    st.assign(levels.size(), ScalingStats{});
    tbb::parallel_for(size_t(0), levels.size(), [&](size_t i) { levels[i].est->finish(levels[i].L.single, levels[i].L.ir, st[i]); });
}

nlohmann::json stats_json(const ScalingStats &s, bool ir) {
    nlohmann::json j = {{"orig_lines", s.orig_lines},
                        {"low_lines", s.low_lines},
                        {"orig_path_vertices", s.orig_vertices},
                        {"rejected_lines", s.rejected},
                        {"cv_lines", s.cv_lines},
                        {"leaked_lines", s.leaked},
                        {"rounds", s.rounds},
                        {"core_seconds_orig", s.core_seconds_orig},
                        {"core_seconds_low", s.core_seconds_low},
                        {"S_rel_std_error", {{"median", s.S_rel_se_median}, {"p90", s.S_rel_se_p90}, {"max", s.S_rel_se_max},
                                             {"median_outer_ring", s.S_rel_se_median_outer},
                                             {"median_at_paper_counts", s.S_rel_se_median_paper_counts}}},
                        {"T_rel_std_error_max", s.T_rel_se_max},
                        {"T_rel_std_error_median", s.T_rel_se_median},
                        {"tasks_traced", s.tasks_traced},
                        {"estimator_bytes", s.estimator_bytes},
                        {"reciprocity_check", s.reciprocity_check[0] > 0 || s.reciprocity_check[1] > 0
                                                  ? nlohmann::json{{"inner", s.reciprocity_check[0]},
                                                                   {"wi_outer_ring", s.reciprocity_check[1]},
                                                                   {"wo_outer_ring", s.reciprocity_check[2]}}
                                                  : nlohmann::json(nullptr)},
                        {"reciprocity_used", {{"single", s.reciprocity_used}, {"ir", s.reciprocity_used_ir}}},
                        {"rank1", {{"energy_sigma1_sq", s.rank1_energy},
                                   {"svd_rel_error", s.rank1_svd_rel_error},
                                   {"TS_rel_error", s.ts_rel_error}, {"paper_eq22_24_rel_error", s.paper_ts_rel_error},
                                   {"singular_values", s.singular_values}}}};
    if (ir) {
        j["S_ir_rel_std_error"] = {{"median", s.S_ir_rel_se_median}, {"p90", s.S_ir_rel_se_p90},
                                   {"median_outer_ring", s.S_ir_rel_se_median_outer},
                                   {"median_at_paper_counts", s.S_ir_rel_se_median_paper_counts}};
        j["T_ir_rel_std_error_max"] = s.T_ir_rel_se_max;
        j["T_ir_rel_std_error_median"] = s.T_ir_rel_se_median;
        j["rank1_ir"] = {{"energy_sigma1_sq", s.rank1_energy_ir},
                         {"svd_rel_error", s.rank1_svd_rel_error_ir},
                         {"TS_rel_error", s.ts_rel_error_ir}, {"paper_eq22_24_rel_error", s.paper_ts_rel_error_ir},
                         {"singular_values", s.singular_values_ir}};
    }
    return j;
}

/// One level's h_low, SVNDF and f'_low (factor F), before its T / S.
/// `finer`: the previous level (nullptr for the first), whose SVNDF may start this one's.
/// `low`: its h_low, solved on another thread meanwhile (the sparse solve is serial: it ran
/// beside the fits, which keep every core busy, instead of before them with one core idle).
LevelWork prepare_level(const PipelineOptions &o, int F, const Inputs &in, const OriginalFields &orig,
                        const QuadratureOptions &quadrature, const PrefilteredLevel *finer,
                        std::future<LowStage> &low) {
    LevelWork w;
    PrefilteredLevel &L = w.L;
    L.factor = F;
    L.ndf = svndf_stage(o, in.map, orig.map_units, F, finer ? &finer->ndf : nullptr, finer ? finer->factor : 0, w.timing);
    LowStage ls = low.get();
    L.h_low = std::move(ls.h_low);
    w.timing["least_squares_s"] = ls.seconds;
    double ll = 0;
    for (const auto &p : L.ndf) w.converged += p.converged, w.mean_it += p.iterations, ll += p.log_likelihood;
    w.mean_it /= double(std::max<size_t>(1, L.ndf.size()));
    w.mean_ll = ll / double(std::max<size_t>(1, L.ndf.size()));
    if (dist::rank() == 0) std::fprintf(stderr, "  x%d: h_low %dx%d (%.2f s), SVNDF %zu patches (%.2f s, from %s, %.0f EM iterations and log-likelihood %.4f on average)\n", F,
                 L.h_low.width, L.h_low.height, w.timing["least_squares_s"].get<double>(), L.ndf.size(),
                 w.timing["svndf_fit_s"].get<double>(), w.timing["svndf_start"].get<std::string>().c_str(), w.mean_it, w.mean_ll);
    const auto t0 = Clock::now();
    w.low_mat = std::make_shared<SvMultiLobe>(in.base, L.ndf, L.h_low.width, L.h_low.height, quadrature,
                                               in.base_json, "--base");
    w.timing["multilobe_build_s"] = since(t0);
    w.low_field = std::make_unique<Heightfield>(L.h_low, float(o.height_scale * double(L.h_low.width) / o.tile_size), 0.f);
    return w;
}

/// A level's manifest stats after its T / S (scaling_s: its share of the levels' shared rounds).
void finish_level(const PipelineOptions &o, LevelWork &w, const ScalingStats &st, double scaling_s, size_t shared) {
    const bool ir = o.interreflections;
    PrefilteredLevel &L = w.L;
    const int F = L.factor;
    w.timing["scaling_s"] = scaling_s;
    w.timing["scaling_shared_levels"] = shared;
    L.stats = stats_json(st, ir);
    L.stats["timing"] = w.timing;
    L.stats["svndf"] = {{"converged_patches", w.converged}, {"mean_em_iterations", w.mean_it},
                        {"mean_log_likelihood", w.mean_ll}, {"start", w.timing["svndf_start"]},
                        {"multilobe_memory_bytes", w.low_mat->memory_bytes()}};
    L.stats["storage_bytes"] = {{"h_low", L.h_low.memory_bytes()},
                                {"lobes", L.ndf.size() * size_t(5 * o.lobes + 1) * sizeof(float)},
                                {"T", size_t(o.M) * o.M * 3 * sizeof(float) * (ir ? 2 : 1)},
                                {"S", size_t(o.N) * o.N * o.N * o.N * 3 * sizeof(float) * (ir ? 2 : 1)}};
    if (dist::rank() == 0) std::fprintf(stderr,
                 "  x%d: S rel. std. error median %.4f (grazing ring %.4f; paper's counts: %.4f)%s; rank-1 energy %.4f, "
                 "|R - T S| / |R| = %.4f vs rank-1 SVD %.4f\n",
                 F, ir ? st.S_ir_rel_se_median : st.S_rel_se_median,
                 ir ? st.S_ir_rel_se_median_outer : st.S_rel_se_median_outer,
                 ir ? st.S_ir_rel_se_median_paper_counts : st.S_rel_se_median_paper_counts, ir ? " (ir)" : "",
                 ir ? st.rank1_energy_ir : st.rank1_energy, ir ? st.ts_rel_error_ir : st.ts_rel_error,
                 ir ? st.rank1_svd_rel_error_ir : st.rank1_svd_rel_error);
    if (dist::rank() == 0 && (st.reciprocity_check[0] > 0 || st.reciprocity_check[1] > 0))
        std::fprintf(stderr,
                     "  x%d: reciprocity check (single bounce; transposed / direct estimate, 1 = reciprocal): inner "
                     "%.4f, wi in the outer ring %.4f, wo in it %.4f; reciprocal average used: single %s, ir %s\n",
                     F, st.reciprocity_check[0], st.reciprocity_check[1], st.reciprocity_check[2],
                     st.reciprocity_used ? "yes" : "no", st.reciprocity_used_ir ? "yes" : "no");
}

/// The level's per-cell model error and the per-sample variance it removes (level_error.h), for
/// the renderer's level choice (geometry/lod.h); into the manifest as "lod_error".
void level_error_stage(const PipelineOptions &o, const Heightfield &orig, const Material &base, LevelWork &w) {
    const auto t0 = Clock::now();
    LevelErrorOptions eo;
    eo.seed = hash_combine(o.seed, 0x1e7e1e77ULL);
    const LevelError e = measure_level_error(orig, base, *w.low_field, *w.low_mat, w.L.factor, eo);
    w.L.stats["lod_error"] = {{"patch_error", e.patch_error}, {"removed_variance", e.removed_variance},
                              {"window_error", e.window_error},
                              {"cells", e.cells}, {"directions", e.directions}, {"lines", e.lines},
                              {"seconds", since(t0)}};
    if (dist::rank() == 0)
        std::fprintf(stderr, "  x%d: model error over 1, 2, 4, ... cells %s, removed variance per sample %.4g (relative; %.2f s)\n",
                     w.L.factor, fmt::format("{:.3g}", fmt::join(e.window_error, " ")).c_str(), e.removed_variance, since(t0));
}

}  // namespace

PrefilteredModel build_model(const PipelineOptions &opts) {
    const auto t_all = Clock::now();
    const Inputs in = load_inputs(opts);
    PipelineOptions o = opts;
    if (in.wrap != WrapMode::Repeat) o.tile_size *= 2;  // the extension spans two tiles of the map
    if (o.flow_auto) {  // measured at least as accurate as eq5 and several times cheaper (lobe_brdf.h)
        o.flow_lobes = in.no_lobes.empty();
        o.flow_projected_area = false;
    }
    PrefilteredModel model = empty_model(o, in);
    const HeightMap &map = in.map;
    const double cells_per_unit = double(map.width) / o.tile_size;
    const OriginalFields orig{Heightfield(map, float(o.height_scale * cells_per_unit), 0.f), Heightfield(map, 1.f, 0.f)};
    if (dist::rank() == 0) std::fprintf(stderr, "prefilter: %dx%d map, base %s, scales %s, M = %d, N = %d, %d lobes, interreflections %s, f'_low %s%s\n",
                 map.width, map.height, in.base->to_string().c_str(), scales_text(o.scales).c_str(), o.M, o.N, o.lobes,
                 o.interreflections ? "on" : "off", flow_name(model.quadrature).c_str(),
                 opts.flow_auto && !o.flow_lobes ? " (--flow auto: the base has no closed form)" : "");
    std::vector<LevelWork> levels;
    // Every level's h_low in order on one thread, beside the SVNDF fits (prepare_level).
    std::vector<std::promise<LowStage>> lows(o.scales.size());
    std::vector<std::future<LowStage>> low_futures;
    for (auto &p : lows) low_futures.push_back(p.get_future());
    std::thread lsq([&] {
        for (size_t i = 0; i < o.scales.size(); ++i) {
            try {
                lows[i].set_value(least_squares_stage(map, o.scales[i]));
            } catch (...) {
                for (size_t j = i; j < lows.size(); ++j) lows[j].set_exception(std::current_exception());
                return;
            }
        }
    });
    struct Joiner {
        std::thread &t;
        ~Joiner() { t.join(); }
    } joiner{lsq};
    for (size_t i = 0; i < o.scales.size(); ++i)
        levels.push_back(prepare_level(o, o.scales[i], in, orig, model.quadrature,
                                       levels.empty() ? nullptr : &levels.back().L, low_futures[i]));
    // T / S of every level together (the original's lines shared); --max-seconds: what is left.
    const auto t_ts = Clock::now();
    std::vector<ScalingStats> st;
    scaling_stage(o, orig.cells, *in.base, levels,
                  o.max_seconds > 0 ? std::max(1e-3, o.max_seconds - since(t_all)) : 0.0, st);
    const double ts_s = since(t_ts);
    if (dist::rank() == 0) std::fprintf(stderr, "  T/S of %zu level(s): %.1f s\n", levels.size(), ts_s);
    for (size_t i = 0; i < levels.size(); ++i) {
        finish_level(o, levels[i], st[i], ts_s / double(levels.size()), levels.size());
        if (o.level_error) level_error_stage(o, orig.cells, *in.base, levels[i]);
        model.levels.push_back(std::move(levels[i].L));
    }
    model.manifest["total_seconds"] = since(t_all);
    // Under MPI every rank holds the same tables (ScalingEstimator::add_round); rank 0 writes.
    model.manifest["ranks"] = dist::size();
    return model;
}

void run_pipeline(const PipelineOptions &o) {
    const auto t_all = Clock::now();
    const PrefilteredModel model = build_model(o);
    if (dist::rank() != 0) return;
    // Staged in a hidden directory beside the target and renamed at the end: an interrupted or
    // failed run leaves no directory that looks like a complete model (and the old one intact).
    OutputSet set;
    model.save(set.add_output("-o", o.output, "", OutputKind::Directory, "manifest.json"));
    set.commit();
    std::printf("%s\n", fmt::format("prefilter: wrote {} ({} levels, {:.1f} s{})", o.output, model.levels.size(),
                                    since(t_all), dist::size() > 1 ? fmt::format(", {} ranks", dist::size()) : "")
                             .c_str());
}

}  // namespace meso::prefilter
