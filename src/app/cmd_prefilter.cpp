// `meso prefilter (--map MAP | --generator KIND [-p key=value]...) --base MATERIAL
//                 [--scales 8,64] [-M 4] [-N 15] [--lobes 6] [--interreflections on|off]
//                 [--paths 64] [--low-paths 8] [--target-error E] [--max-rounds R] [--max-seconds T] [--seed S]
//                 -o MODEL_DIR`
//
// The flags of paper 004's precomputation: parsed and validated here, run by
// prefilter/pipeline.h (h_low, the vMF SVNDF, T and S per downsampling factor), which writes a
// model directory (prefilter/model.h) that the `prefiltered` material and `lod.model` read.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fmt/format.h>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>
#include "app/commands.h"
#include <tbb/global_control.h>
#include <tbb/info.h>
#include "core/distributed.h"
#include "core/error.h"
#include "core/interrupt.h"
#include "core/output_set.h"
#include "core/properties.h"
#include "prefilter/pipeline.h"

namespace meso {
namespace {

/// The flags as given (strings where they are parsed or checked in validate()).
struct PrefilterFlags {
    prefilter::PipelineOptions pipeline;
    std::string scales = "8,64", interreflections = "on", flow = "auto", reciprocity = "on";
    std::vector<std::string> params;
    int size = 0;
    int64_t gen_seed = -1;
    int threads = 0;  ///< 0: the node's cores / the MPI ranks on it
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
            if (!out.empty() && f <= out.back()) throw UsageError(fmt::format("--scales {}: factors must increase", s));
            out.push_back(f);
        } catch (const std::invalid_argument &) {
            throw UsageError(fmt::format("--scales {}: expected comma-separated integers >= 2, e.g. 8,64", s));
        } catch (const std::out_of_range &) {
            throw UsageError(fmt::format("--scales {}: factor out of range", s));
        }
    }
    if (out.empty()) throw UsageError("--scales: expected at least one factor, e.g. 8,64");
    return out;
}

/// The generator's parameters: -p key=value pairs, then --size and --map-seed.
std::map<std::string, std::string> generator_params(const PrefilterFlags &f) {
    std::map<std::string, std::string> params;
    for (const std::string &kv : f.params) {
        const size_t eq = kv.find('=');
        if (eq == std::string::npos || eq == 0) throw MesoError(fmt::format("-p {}: expected key=value", kv));
        params[kv.substr(0, eq)] = kv.substr(eq + 1);
    }
    if (f.size > 0) params["size"] = std::to_string(f.size);
    if (f.gen_seed >= 0) params["seed"] = std::to_string(f.gen_seed);
    return params;
}

/// Checks the flags and completes the pipeline's options from the string-valued ones.
prefilter::PipelineOptions validate(const PrefilterFlags &f) {
    prefilter::PipelineOptions o = f.pipeline;
    if (f.threads < 0) throw MesoError("prefilter: --threads: expected a positive count");
    if (o.output.empty()) throw MesoError("prefilter: -o/--output DIR is required");
    if (o.map.empty() == o.generator.empty())
        throw MesoError("prefilter: give exactly one of --map FILE and --generator KIND");
    o.interreflections = parse_choice("--interreflections", f.interreflections, {"on", "off"}) == 0;
    o.reciprocity = parse_choice("--reciprocity", f.reciprocity, {"off", "check", "on"});
    const int flow = parse_choice("--flow", f.flow, {"visible", "eq5", "lobes", "auto"});
    o.flow_projected_area = flow == 0;
    o.flow_lobes = flow == 2;
    o.flow_auto = flow == 3;
    if (!(o.height_scale > 0) || !std::isfinite(o.height_scale) || !(o.tile_size > 0) || !std::isfinite(o.tile_size))
        throw UsageError("--height-scale and --tile-size must be positive and finite");
    if (!(o.ndf_tolerance >= 0.0 && o.ndf_tolerance <= 1.0))
        throw UsageError("--ndf-tolerance must be a number in [0, 1], got " + std::to_string(o.ndf_tolerance));
    if (!o.wrap.empty()) parse_choice("--wrap", o.wrap, {"repeat", "clamp", "mirror"});
    o.scales = parse_scales(f.scales);
    if (o.M < 1 || o.N < 1 || o.N > 64 || o.lobes < 1 || o.lobes > 16)
        throw MesoError("prefilter: need M >= 1, 1 <= N <= 64, 1 <= lobes <= 16");
    if (!o.generator.empty()) o.generator_params = generator_params(f);
    return o;
}

/// The model directory is checked before any work: not an existing file, not a directory other
/// than a previous model, in a writable directory, not one of the inputs.
void check_output(const prefilter::PipelineOptions &o) {
    OutputSet set;
    set.add_input(o.map, "the height map");
    std::error_code ec;
    if (std::filesystem::is_regular_file(o.base, ec)) set.add_input(o.base, "the base material");
    set.add_output("-o", o.output, "", OutputKind::Directory, "manifest.json");
    set.check();
}

int run_prefilter(const PrefilterFlags &f) {
    const prefilter::PipelineOptions o = validate(f);
    check_output(o);
    install_interrupt_handler(InterruptMode::Immediate);  // Ctrl-C: exit 130, no model written
    const int threads = f.threads > 0 ? f.threads : std::max(1, tbb::info::default_concurrency() / dist::local_size());
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, size_t(threads));
    prefilter::run_pipeline(o);
    return 0;
}

SubcommandRegistrar reg_prefilter{
    {"prefilter", "Precompute a prefiltered LoD model of a displacement map (paper 004): h_low, vMF SVNDF, T and S",
     [](CLI::App &app) -> std::function<int()> {
         auto f = std::make_shared<PrefilterFlags>();
         prefilter::PipelineOptions *o = &f->pipeline;
         app.add_option("--map", o->map, "height map file (EXR/PNG; periodic, heights in map units)");
         app.add_option("--generator", o->generator, "or a generator of `meso genmap` (fbm, twill, sawtooth, ...)");
         app.add_option("-p,--param", f->params, "generator parameter key=value (repeatable)");
         app.add_option("--size", f->size, "generator: vertices per side")->check(CLI::Range(2, 16384));
         app.add_option("--map-seed", f->gen_seed, "generator: random seed")->check(CLI::NonNegativeNumber);
         app.add_option("--height-scale", o->height_scale, "world height per map unit (as the displacement's scale)")->capture_default_str();
         app.add_option("--tile-size", o->tile_size, "world size of one map tile (square cells)")->capture_default_str();
         app.add_option("--wrap", o->wrap,
                        "how the map continues past its edges, as the displacement's \"wrap\": repeat, clamp or mirror "
                        "(default: repeat; clamp for a generated map that does not tile)");
         app.add_option("--base", o->base, "base BRDF: inline JSON material or a JSON file")->capture_default_str();
         app.add_option("--scales", f->scales, "downsampling factors, comma-separated")->capture_default_str();
         app.add_option("-M", o->M, "spatial resolution of T (M x M)")->capture_default_str()->check(CLI::Range(1, 256));
         app.add_option("-N", o->N, "angular resolution of S (N² x N² bins)")->capture_default_str()->check(CLI::Range(1, 64));
         app.add_option("--lobes", o->lobes, "vMF lobes per patch NDF")->capture_default_str()->check(CLI::Range(1, 16));
         app.add_option("--interreflections", f->interreflections, "also estimate T_ir, S_ir (on|off)")->capture_default_str();
         app.add_option("--paths", o->paths, "lines of sight per (T patch, wo bin) per round on the original")->capture_default_str()
             ->check(CLI::Range(1, 1 << 20));
         app.add_option("--low-paths", o->low_paths, "lines of sight per (T patch, wo bin) per round on h_low")->capture_default_str()
             ->check(CLI::Range(1, 1 << 20));
         app.add_option("--low-nodes", o->low_nodes,
                        "f'_low nodes sampled per line on h_low (0: the full deterministic quadrature)")
             ->capture_default_str()
             ->check(CLI::Range(0, 4096));
         app.add_option("--cv-lines", o->cv_lines,
                        "control variate: lines per (T patch, wo bin) per round on the original without shadow rays, "
                        "interreflections or h_low; the lines of sight then trace only the difference (0: none)")
             ->capture_default_str()
             ->check(CLI::Range(0, 1 << 20));
         app.add_option("--shadow-roulette", o->shadow_roulette,
                        "shadow rays on the original and h_low: a next-event term below this times its bin's mean so far is "
                        "traced with probability term / (that), weighted by the inverse (unbiased; 0: trace all)")
             ->capture_default_str()
             ->check(CLI::Range(0.0, 1e6));
         app.add_flag("--allocate-lines", o->allocate_lines,
                      "after the first round, split each round's cost (that of --paths and --low-paths lines) between "
                      "the original's lines and every level's h_low lines by their measured noise and cost per line "
                      "(tables then depend on timings, not on the seed alone)");
         app.add_option("--reciprocity", f->reciprocity,
                        "the effective BRDF's reciprocity (paper 004 eq. 25): every line of sight also estimates the "
                        "transposed bin pair; on = average the two into S (less variance) and report how they agree per "
                        "ring class, check = only report, off; ignored with --cv-lines")
             ->capture_default_str();
         app.add_option("--directions", o->jitter_directions,
                        "where a line's wo and wi sit in their S bins: jitter (uniform in the bin: the bin's average) "
                        "or centres (the points S's lookup interpolates between; can spike where f'_low vanishes)")
             ->transform(CLI::CheckedTransformer(std::map<std::string, bool>{{"centres", false}, {"jitter", true}}))
             ->default_str("jitter");
         app.add_option("--target-error", o->target_error,
                        "rounds until the median relative std. error of every S table is below this, tracing only the wo bins "
                        "above it after the first round (0: one round)")->capture_default_str();
         app.add_option("--max-rounds", o->max_rounds, "at most this many rounds")->capture_default_str()->check(CLI::Range(1, 1000));
         app.add_option("--max-seconds", o->max_seconds,
                        "no new T/S round once a round as long as the last would end past this build time (0: no limit)")
             ->capture_default_str()
             ->check(CLI::NonNegativeNumber);
         app.add_option("--ndf-samples", o->samples_per_cell, "n x n micro-normals per fine cell for the NDF fit")->capture_default_str()
             ->check(CLI::Range(1, 32));
         app.add_option("--ndf-tolerance", o->ndf_tolerance,
                        "a patch's vMF EM stops once an iteration changes the mean log-likelihood per micro-normal by "
                        "at most this times (1 + |L|) (0: always the iteration limit)")
             ->capture_default_str()
             ->check(CLI::Range(0.0, 1.0));
         app.add_option("--ndf-start", o->ndf_from_children,
                        "where each patch's vMF EM starts: children (a level whose factor is a multiple of the previous "
                        "level's: its children's lobes, merged; the first level: its cells' normals, one lobe a cell, "
                        "merged; faster) or kmeans (k-means++ starts at every level)")
             ->transform(CLI::CheckedTransformer(std::map<std::string, bool>{{"kmeans", false}, {"children", true}}))
             ->default_str("children");
         app.add_option("--quadrature", o->quad_polar, "f'_low quadrature: nodes per lobe in the vMF CDF variable")->capture_default_str()
             ->check(CLI::Range(1, 64));
         app.add_option("--quadrature-azimuth", o->quad_azimuth, "f'_low quadrature: azimuthal nodes")->capture_default_str()
             ->check(CLI::Range(1, 256));
         app.add_option("--flow", f->flow,
                        "f'_low: visible (facets weighted by their projected area towards the viewer), eq5 "
                        "(paper 004 eq. 5 as printed), lobes (closed form: one widened base lobe per vMF lobe; "
                        "diffuse or rough conductor bases) or auto (lobes where the base allows it, else eq5)")
             ->capture_default_str();
         app.add_option("--epsilon", o->epsilon, "eq. 12's epsilon, relative to the mean denominator")->capture_default_str();
         app.add_option("--seed", o->seed, "random seed of the estimators")->capture_default_str();
         app.add_option("-o,--output", o->output, "model directory to write");
         app.add_flag("--level-error", o->level_error,
                      "measure each level's model error and removed variance into the manifest (lod_error) for the "
                      "experimental lod \"rule\": \"mse\" (about 0.2-2 s a level)");
        app.add_flag("-q,--quiet", o->quiet, "no progress bar");
         app.add_option("--threads", f->threads, "worker threads (default: all cores, shared among the MPI ranks on a node)");
         return [f] { return run_prefilter(*f); };
     }}};

}  // namespace
}  // namespace meso
