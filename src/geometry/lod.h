// Level-of-detail chains (paper 004 §7.2): a sparse, ordered list of models of one surface,
// each with its downsampling factor relative to the original (1 = the original map; e.g.
// 1, 8, 64). Every LoD material and displaced shape reads its level from here.
//
// Footprint: the width of a pixel's footprint in texels of the ORIGINAL, full effective map
// (tiling included): width = max(|(du/dx W, dv/dx H)|, |(du/dy W, dv/dy H)|) — the major
// axis, as MipMap::level_for_footprint (conservative: no aliasing along either axis).
// `lod_bias` scales the footprint before selection (> 1: coarser levels sooner).
//
// Selection is log-linear between neighbouring factors, over at most one octave: a footprint
// of w texels between levels i and i+1 gives level i+1 the weight
//     t = clamp(1 + (log w - log f_{i+1}) / min(log f_{i+1} - log f_i, log 2), 0, 1),
// i.e. t = (log w - log f_i) / (log f_{i+1} - log f_i) when the factors are at most 2 apart
// (1, 2, 4, ...), and otherwise level i alone up to half of f_{i+1}, then one octave of
// transition. A footprint equal to a level's factor selects exactly that level; below the
// first factor the first level is used alone, above the last the last. Why at most an octave:
// a level is biased at the pixel scale, and its squared bias grows faster than its factor
// (measured: x4, x8, x16 at a fixed footprint ~ 1 : 5 : 12, docs/bench.md "Level choice and
// bias"), so a stochastic choice between levels far apart, which carries t times the coarse
// level's whole bias (with 1, 16 and a footprint of 2.6 texels: 35% of the paths on patches 6
// times too wide), is far more biased than a level near the footprint.
//
// The footprint is the camera ray's, which the renderer scales by max(1/8, 1/sqrt(spp)) (the
// footprint of one sample, render/differentials.h): at 64 spp and more a level of factor F is
// chosen where a PIXEL covers about 8 F texels.
//
// Metric check (prefiltered models only). A model describes square cells of one world size c0
// (its --tile-size over its map width): the slopes of the detail a level removes are those of
// that metric. On a shape whose uv map stretches the cells (a uv sphere's tiles shrink along u
// like sin(theta) towards the poles; non-square tilings; sheared uvs), the removed detail has
// the model's heights over other widths: along a principal axis of the local metric, where one
// model texel measures lambda_i c0 (lambda_1 >= lambda_2 the singular values of
// [dp/du / (W c0), dp/dv / (H c0)], W x H the texel grid), its slopes are 1 / lambda_i times
// the model's, so the level's NDF and tables describe another surface. The distortion
//     D = max(lambda_1, 1 / lambda_2) >= 1
// (1: the model's metric) is held to the chain's own resolution: a cell stretched by 2 along an
// axis is, there, a cell of the next octave of factors, i.e. the level describes detail of
// another level's scale. Up to D = sqrt 2 (half an octave) the rule is unchanged; from sqrt 2
// to 2 the footprint the rule sees is moved log-linearly, in 2 log2 D - 1, down to half the
// first factor (where the rule takes the original alone), passing through the finer levels
// (which remove less detail, so their stretched slopes err less); at D >= 2, and where the
// metric is degenerate (dp/du = 0 at a pole, a zero-area or non-finite triangle), the path sees
// the original. The load-time check (lod/lod_build.cpp: the model's tile size lies between the
// shape's mean tile lengths) is global; this one is local, per camera hit. Measured on the ball
// bench scene, the pole cap (sin theta < 0.5, D > 1.8) held 70% of ours' bias².
//
// Blending: (a) trace the path on both levels and blend contributions with (1 - t, t);
// (b) pick one level per path with probability t of the coarser one (same expectation,
// about half the cost). A path must keep the level it picked for all its rays.
#pragma once
#include <string>
#include <vector>
#include "core/vec.h"

namespace meso {

struct SurfaceInteraction;

struct LodSelection {
    int lo = 0, hi = 0;  ///< neighbouring levels (equal at the ends of the chain)
    float t = 0.f;       ///< weight of `hi`; `lo` gets 1 - t
};

/// Footprint width in texels of a W x H effective map from uv derivatives (see above).
/// Non-finite or negative input gives 0 (the finest level).
float footprint_texels(float dudx, float dudy, float dvdx, float dvdy, double width, double height);

class LodChain {
public:
    LodChain() : m_factors{1.f} {}
    /// Factors must be finite, >= 1 and strictly increasing; throws MesoError otherwise
    /// (`where` prefixes the message).
    explicit LodChain(std::vector<float> factors, const std::string &where = "");

    int levels() const { return int(m_factors.size()); }
    float factor(int level) const { return m_factors[size_t(level)]; }
    const std::vector<float> &factors() const { return m_factors; }

    /// Levels and weight for a footprint of `texels` original texels, scaled by `bias`.
    LodSelection select(float texels, float bias = 1.f) const;
    /// Stochastic choice: `lo` with probability 1 - t, `hi` with probability t (u in [0,1)).
    int choose(float texels, float u, float bias = 1.f) const;
    /// Continuous level position (i + t), for false-colour output.
    float position(float texels, float bias = 1.f) const;

private:
    std::vector<float> m_factors;
    std::vector<float> m_log;  ///< log of each factor
};

enum class LodBlend { Stochastic, Blend };

/// The levels of one LoD shape (each level is its own Shape with `lod` pointing here and
/// `lod_level` = its index): the chain, the bias, how levels are combined, and the texel
/// grid of level 0 (the original map, tiling included) that footprints are measured in.
///
/// Which level a path sees (integrators/path.cpp, one level per path, used by all its rays,
/// as paper 004 picks one per pixel). A path's level is an index k into every chain: its rays
/// carry the Embree mask bit k and see level min(k, last) of each chain (a chain's last level
/// answers to bits last..31; geometry/embree_accel.h traces each level in its own scene).
///   1. The camera ray is traced first with bit 31, i.e. against the coarsest level of every
///      chain (the cheapest shells). (With the integrator's lod_hints, first at the level its
///      pixel's hint guesses, which saves this trace where the hit there picks that level again;
///      integrators/path.cpp, trace_lod.)
///   2. If it hits a level of an LoD shape, that shape's group picks the level from the
///      camera ray's per-sample footprint at the hit (select_path_level: the pixel's times
///      max(1/8, 1/sqrt(spp)), as texture filtering uses, so that a level's per-patch error,
///      averaged over about (footprint / factor)² patches a pixel, falls like the variance;
///      footprints are measured on the base surface, so every level gives the same one, up to
///      the level's height at the hit). With
///      LodBlend::Stochastic one level is drawn (probability t of `hi`); with LodBlend::Blend
///      the path is traced at both `lo` and `hi` and weighted (1 - t, t). A level at or past
///      the last level of every chain in the scene sees what bit 31 sees: the camera ray's
///      hit is kept; any finer level retraces the camera ray with its own bit (it may then
///      hit another surface, e.g. a finer level that stands out in front of the coarsest).
///   3. If it misses or hits a shape without LoD, the path keeps bit 31: every chain is seen
///      at its coarsest level. Such a path (a floor's or a wall's interreflections, a mirror's
///      reflection) has no footprint on the LoD shape; the coarsest level is the one whose
///      prefiltered material carries the least sub-pixel noise and costs least to trace.
/// With several chains, index k means a different factor in each; the chain that the camera
/// ray hits decides k. Scenes without LoD shapes do none of this.
struct LodGroup {
    LodChain chain;
    float bias = 1.f;
    LodBlend blend = LodBlend::Stochastic;
    double texel_w = 1, texel_h = 1;
    /// lod "rule": "mse" only. Per level (index 0, the original: empty / 0), the measured model
    /// error E over windows of 1, 2, 4, ... cells and the removed per-sample variance V of a
    /// prefiltered model (prefilter/level_error.h); empty: the per-sample footprint rule. See
    /// "Expected-MSE rule" below.
    std::vector<std::vector<float>> window_error;
    std::vector<float> removed_variance;
    /// World size of one texel of the map the levels' prefiltered model was made for (square
    /// cells: its tile_size over its map width); 0: the levels are not a model's (explicit
    /// materials, box-downsampled geometry), no metric check. See "Metric check" above.
    double model_texel = 0;
};

/// D of the metric check above for uv tangents dp/du, dp/dv (world per unit uv) on a texel grid
/// of texel_w x texel_h texels per unit uv and a model texel of world size `model_texel`.
/// Returns 1 when model_texel <= 0 (nothing to check), +infinity where the metric is
/// degenerate (a zero or non-finite tangent, parallel tangents).
double metric_distortion(const Vec3 &dpdu, const Vec3 &dpdv, double texel_w, double texel_h, double model_texel);

/// The footprint (texels, before `bias`) the level rule sees under distortion D: `texels`
/// itself up to D = sqrt 2, then moved log-linearly down to half the chain's first factor (over
/// `bias`) at D = 2 and beyond (never up: a footprint already below stays).
double metric_footprint(const LodChain &chain, double texels, double distortion, double bias = 1.0);

// Expected-MSE rule (lod "rule": "mse", a model that measured E and V for every level; opt-in:
// see docs/bench.md "Expected-MSE level choice" for why it is not the default). A pixel of
// footprint w texels rendered with n samples: level k of factor F, r = bias w / F cells across
// the pixel, changes the pixel's expected squared error (relative to the original, in units of
// the squared mean, level_error.h) by
//     J_k = E(r) - V / n                            (r >= 1: E(r) the model error averaged over
//                                                    windows of r x r cells, interpolated linearly
//                                                    in log r between the measured 1, 2, 4, ...,
//                                                    falling like 1 / r² past the last)
//     J_k = E(1) + V+ (1 - r²) - V r² / n           (r < 1: the pixel sees part of one cell; the
//                                                    cell's detail above the pixel scale, V+ =
//                                                    max(V, 0), is lost)
// and J_0 = 0. The path's level is the one of least J at the PIXEL footprint; over the octave
// [w / sqrt 2, w sqrt 2] the choice is blended: `hi` (the coarser) gets the fraction of that
// octave (in log w) where it is the best, so levels fade in without popping. No constant is
// fitted: E and V come from `meso prefilter`, n is the render's spp.
LodSelection select_mse_level(const LodChain &chain, const std::vector<std::vector<float>> &window_error,
                              const std::vector<float> &removed_variance, float pixel_texels, float spp,
                              float bias = 1.f);

/// The levels a path sees when its camera ray hits a shape of `g` with uv derivatives
/// (dudx, dudy, dvdx, dvdy) of a ray whose differentials are scaled by `footprint_scale` (the
/// per-sample factor; the pixel's footprint is the ray's / footprint_scale), in a render of
/// `spp` samples per pixel (<= 0: 1 / footprint_scale²). Paper 004 §7.2: one level per path.
/// With measured errors, the expected-MSE rule; else the per-sample footprint rule.
/// `distortion`: D of the metric check at the hit (1: none).
LodSelection select_path_level(const LodGroup &g, float dudx, float dudy, float dvdx, float dvdy,
                               float footprint_scale = 1.f, int spp = 0, double distortion = 1.0);

/// The same at a camera hit `si` on a shape of `g` whose differentials are computed: the uv
/// derivatives and, with a model (g.model_texel > 0), D from the base surface's tangents
/// (dpdu_footprint, dpdv_footprint where the hit is on microgeometry, else dpdu, dpdv).
LodSelection select_path_level(const LodGroup &g, const SurfaceInteraction &si, float footprint_scale, int spp);

}  // namespace meso
