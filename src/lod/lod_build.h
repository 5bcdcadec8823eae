// LoD chains of a displaced shape from the "lod" block of a scene file (docs/scene-format.md):
// parse_lod_spec reads and checks the block into a LodSpec, build_lod_levels turns it into the
// chain's levels 1.. (level 0 is the shape itself). Every level is a shell shape seen only by
// rays of its level (geometry/lod.h: the path tracer picks one level per path), displaced by
//   - the least-squares heights h_low of a prefiltered model ("model": a `meso prefilter`
//     directory, paper 004 §4.1),
//   - the shape's map box-downsampled by the level's factor (the default), or, with a height
//     transfer g and "transfer_filter": "gaussian", the paper 001 §7 g-bar of each block's
//     Gaussian statistics of the untransferred map f, or
//   - the original map again ("same_model": levels differ only in their materials).
//
// Level materials. Explicit "materials" (one per level, level 0 included) win. Otherwise, with a
// model, level k gets the material of the JSON object
//   {"type": "prefiltered", "model": <resolved dir>, "level": f_k,
//    "tiling": [tiling_u, tiling_v] of the displacement, "scaling": ..., "estimator": ...}
// ("scaling"/"estimator" only when the lod block gives them): the paper 004 T·S·f'_low of that
// level. It is generated as JSON and created through the material registry, exactly as if the
// user had written it, rather than by calling the material's code directly, so that the
// `prefiltered` plugin stays the one place that reads a model's level (parameters, defaults,
// model cache) and its errors are the ones a hand-written material gives (located at the lod
// block's path). Without either, every level shares the shape's material.
#pragma once
#include <memory>
#include <string>
#include <vector>
#include "core/properties.h"
#include "geometry/lod.h"

namespace meso {

class Shape;

/// How the box-downsampled levels of a displacement with a height transfer g are made.
enum class LodTransferFilter {
    Exact,     ///< g(f) box-downsampled ("exact", the default)
    Gaussian,  ///< the paper 001 §7 g-bar of each block's mean and variance of f ("gaussian")
};

/// Everything a "lod" block says, read and checked (what does not depend on the shape).
struct LodSpec {
    explicit LodSpec(const Properties &block) : block(block) {}

    Properties block;                  ///< the "lod" object, for errors naming lod.<key>
    std::vector<float> factors;        ///< [1, f1, f2, ...]: level 0 is the original map
    LodChain chain;                    ///< built from `factors`
    float bias = 1.f;                  ///< footprint scale (> 1: coarser levels sooner)
    LodBlend blend = LodBlend::Stochastic;
    bool mse_rule = false;             ///< "rule": "mse" (geometry/lod.h, expected-MSE rule); else the footprint rule
    bool same_model = false;           ///< every level displaced by the original map
    LodTransferFilter transfer_filter = LodTransferFilter::Exact;
    std::string model_dir;             ///< the resolved prefiltered model directory; empty without "model"
    std::string scaling, estimator;    ///< for the generated prefiltered materials; empty: their defaults
    std::vector<Properties> materials; ///< explicit per-level materials (empty: none given)

    bool has_model() const { return !model_dir.empty(); }
};

/// Reads the shape's "lod" block; errors name the file, lod.<key> and what was expected.
/// Unknown keys are errors.
LodSpec parse_lod_spec(const Properties &lod);

/// The levels 1.. of `shape` (a shell-mapped displaced shape, else an error) as new shapes, with
/// their materials (see the header); sets the shape's own `lod`, `lod_level` = 0 and, with
/// explicit materials, its material. The caller adds the returned shapes to the scene.
std::vector<std::shared_ptr<Shape>> build_lod_levels(const LodSpec &spec, const std::shared_ptr<Shape> &shape);

}  // namespace meso
