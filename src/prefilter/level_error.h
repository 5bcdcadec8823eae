// What one level of a prefiltered chain costs and gains in a pixel (issue 21: the level that
// minimises the pixel's expected MSE, geometry/lod.h). Measured by `meso prefilter` per level
// and stored in the model's manifest ("lod_error"), for coarse cells c (F x F texels of the
// original) and fixed direction pairs d = (ωi, ωo):
//
//   g_c(d)  the original's single-bounce effective BRDF over cell c (effective_brdf.h, eq. 6)
//           and the within-cell variance s²_c(d) of its integrand over the cell's visible
//           points (what one pixel sample on the original varies by inside the cell);
//   m_c(d)  the same on G_low with f'_low (the level as rendered, without T and S) and its
//           within-cell variance t²_c(d);
//   k(d)    Σ_c g_c / Σ_c m_c, the level's best global scale for that direction pair (what the
//           rank-1 T S does on average: the per-cell error below is what T S cannot remove).
//
//   patch_error     E = Σ_d [ mean_c (g_c - k m_c)² - noise ] / Σ_d mean_c(g_c)²
//                   the per-cell model error, zero-mean over cells: a pixel averaging P cells
//                   carries E / P of it as bias² (relative to the squared mean);
//   removed_variance V = Σ_d mean_c (s²_c - k² t²_c) / Σ_d mean_c(g_c)²
//                   the per-sample variance the level removes (it is negative when the level's
//                   own estimator is noisier than the detail it removes).
//
// `noise` is the Monte Carlo variance of g_c - k m_c (from each estimate's standard error), so E
// is unbiased up to the ratio k; both numbers are relative to the same squared mean, so the
// lighting's scale cancels in the level choice. Interreflections, T and S are not included: the
// measurement is of the level's spatial model error, not of the table noise.
#pragma once
#include <cstdint>
#include <vector>
#include "geometry/heightfield.h"
#include "bsdf/material.h"

namespace meso::prefilter {

struct LevelErrorOptions {
    int cells = 64;        ///< windows sampled per window size (every one when there are at most this many)
    int directions = 8;    ///< direction pairs (fixed, spread over the hemisphere)
    int lines = 256;       ///< lines of sight per window and direction pair, on each surface
    uint64_t seed = 1;
};

struct LevelError {
    double patch_error = 0;       ///< E (see above)
    double removed_variance = 0;  ///< V (see above)
    /// E over windows of 1, 2, 4, ... coarse cells (F, 2F, 4F, ... texels): the bias² of a pixel
    /// of that footprint; [0] = patch_error. Independent cell errors fall like 1 / cells; errors
    /// that follow the map's structure (the same mistake on every yarn) fall only beyond it.
    std::vector<double> window_error;
    int cells = 0, directions = 0, lines = 0;
};

/// E and V of level F: `orig` in cell space (one texel = 1), `low` the level's h_low in its own
/// cell space (one coarse cell = 1, W / F x H / F cells) with `low_material` in the macro frame.
/// Throws MesoError when the maps do not match (sizes not W / F x H / F) or options are < 1.
LevelError measure_level_error(const Heightfield &orig, const Material &base, const Heightfield &low,
                               const Material &low_material, int F, const LevelErrorOptions &opt);

}  // namespace meso::prefilter
