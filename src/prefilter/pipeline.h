// Paper 004's precomputation (Wu et al. 2019) as `meso prefilter` runs it: per downsampling
// factor F, h_low by least squares (§4.1, prefilter/least_squares.h), the vMF SVNDF (§4.2,
// prefilter/patch_ndf.h), and T / S of the scaling function (§6, prefilter/scaling.h)
// estimated from paths on the original microgeometry; the result is a model directory
// (prefilter/model.h) that the `prefiltered` material and `lod.model` read.
//
// Stages (pipeline.cpp): load the map and the base BRDF; per level the least squares, the
// SVNDF fit and the T/S rounds; the manifest; writing the model. The command line
// (app/cmd_prefilter.cpp) parses and validates the flags and fills PipelineOptions; the
// checks that need the loaded map or base material are made here. Error messages name the
// command-line option of a field (the fields mirror the flags).
#pragma once
#include <cstdint>
#include <map>
#include <string>
#include <vector>
#include "prefilter/model.h"

namespace meso::prefilter {

struct PipelineOptions {
    // Input: exactly one of `map` and `generator`.
    std::string map;                                      ///< --map: height map file (periodic, map units)
    std::string generator;                                ///< --generator: a `meso genmap` kind
    std::map<std::string, std::string> generator_params;  ///< -p key=value, --size, --map-seed
    double height_scale = 1.0;  ///< --height-scale: world height per map unit
    double tile_size = 1.0;     ///< --tile-size: world size of one map tile
    /// --wrap: how the map continues past its edges; "" = repeat, or clamp for a generated map that
    /// does not tile. Clamp and mirror prefilter the map's 2W x 2H periodic_extension (as a
    /// displacement with that "wrap" renders it), recorded as input.wrap and input.map_width.
    std::string wrap;
    std::string base = R"({"type": "diffuse", "reflectance": 0.8})";  ///< --base: inline JSON or a file
    std::string output;         ///< -o: model directory

    std::vector<int> scales = {8, 64};  ///< --scales: increasing factors, each >= 2
    int M = 4;                 ///< -M: spatial resolution of T
    int N = 15;                ///< -N: angular resolution of S
    int lobes = 6;             ///< --lobes: vMF lobes per patch NDF
    int samples_per_cell = 2;  ///< --ndf-samples
    /// --ndf-tolerance: each patch's EM stops once an iteration changes the mean log-likelihood
    /// per micro-normal by at most this times (1 + |L|) (VmfEmOptions::tolerance; 0: max iterations)
    double ndf_tolerance = 1e-5;
    /// --ndf-start children (true, default): a level whose factor is a multiple of the previous
    /// level's starts each patch's EM from its children's merged lobes (patch_ndf.h,
    /// fit_svndf_from); kmeans (false): k-means++ starts at every level
    bool ndf_from_children = true;
    bool interreflections = true;  ///< --interreflections on: also T_ir, S_ir
    int paths = 64, low_paths = 64, low_nodes = 4;  ///< --paths, --low-paths, --low-nodes
    bool jitter_directions = true;  ///< --directions jitter (true, default) or centres (scaling.h, "Directions")
    bool level_error = false;  ///< --level-error: measure each level's model error for lod "rule": "mse" (level_error.h)
    /// --reciprocity off (0) | check (1: report ScalingStats::reciprocity_check) | on (2, default:
    /// combine the transposed estimates and report the check; scaling.h, "Reciprocity")
    int reciprocity = 2;
    int cv_lines = 0;  ///< --cv-lines: the control variate's cheap lines (scaling.h, "Control variate")
    double shadow_roulette = 1;  ///< --shadow-roulette (scaling.h, "Shadow-ray roulette"; 0: off)
    bool allocate_lines = false;  ///< --allocate-lines (scaling.h, "Line allocation")
    double target_error = 0;   ///< --target-error (0: one round)
    int max_rounds = 8;        ///< --max-rounds
    double max_seconds = 0;    ///< --max-seconds: no new T/S round past this model build time (0: none)
    double epsilon = 1e-2;     ///< --epsilon: eq. 12's ε, relative to the mean denominator
    uint64_t seed = 1;         ///< --seed of the estimators
    int quad_polar = 3, quad_azimuth = 4;  ///< --quadrature, --quadrature-azimuth: f'_low nodes
    bool flow_projected_area = false;      ///< --flow visible (true) or eq5 (false)
    bool flow_lobes = false;               ///< --flow lobes: the closed form of lobe_brdf.h
    /// --flow auto (the command line's default): lobes where the base supports it (diffuse, rough
    /// isotropic conductor), else eq5; the manifest records the form chosen.
    bool flow_auto = false;
    bool quiet = false;        ///< -q: no progress bar
};

/// Every level of the model in memory (all MPI ranks hold the same tables); the manifest
/// includes the total time so far. Throws MesoError naming the option on bad input.
PrefilteredModel build_model(const PipelineOptions &options);
/// build_model, then rank 0 writes options.output and prints a one-line summary to stdout.
void run_pipeline(const PipelineOptions &options);

}  // namespace meso::prefilter
