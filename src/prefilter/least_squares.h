// Downsampled heights by least squares of the mesoscale slopes (paper 004, Wu et al. 2019,
// §4.1, eq. 9-10 and Appendix A): the alternative to Heightfield::box_downsampled.
//
// The coarse map h_low minimises
//     L(h_low) = sum_cells || s~(cell) - s~*(cell) ||^2 + w sum_vertices (Delta h_low)^2     (eq. 10)
// where s~ is the average slope of the coarse cell's bilinear patch (eq. 9, Appendix A):
//     s~ = ( (h11 + h10 - h01 - h00) / 2, (h11 + h01 - h10 - h00) / 2 ),
// s~* the reference average slope of the fine microsurface over the same region (eq. 1
// with a box kernel), and w = 0.01 the weight of the Laplacian regulariser.
//
// Conventions (and the ambiguities of the paper resolved here):
//   * Grids follow heightmap.h: a W x H map holds vertices; vertex (i, j) sits at cell-space
//     point (i, j); cell (i, j) is the bilinear patch over [i, i+1] x [j, j+1].
//   * factor F must divide both W and H (as for box_downsampled). The coarse map is
//     (W/F) x (H/F); coarse vertex (I, J) sits exactly on fine vertex (I F, J F), so coarse
//     cell (I, J) covers the F x F fine cells [I F, I F + F) x [J F, J F + F) and the coarse
//     map tiled over the same uv lines up with the fine one (box_downsampled instead averages
//     the block of vertices [I F, I F + F - 1], i.e. it is shifted by (F - 1) / 2 fine cells).
//   * Units (the paper leaves them open; w = 0.01 is only meaningful with a choice): both
//     terms are in coarse grid units. Slopes are height differences per coarse cell (the unit
//     patch of Appendix A), and Delta is the 5-point stencil with unit spacing,
//     Delta h(I,J) = h(I+1,J) + h(I-1,J) + h(I,J+1) + h(I,J-1) - 4 h(I,J). Both terms then
//     scale like the heights, so the solution is linear in the map, independent of the
//     height units and of the absolute resolution.
//   * Reference slope s~*: eq. (1) with the box kernel of the coarse cell. The fine surface is
//     bilinear per fine cell, so this is exactly F times the mean over the F x F fine cells
//     of their eq.-9 average slopes (F converts "per fine cell" to "per coarse cell").
//   * periodic = true (the map tiles): every coarse cell has a data term, including the cells
//     that wrap from the last vertex to vertex 0, and the Laplacian wraps.
//   * periodic = false (the wrap-around of the fine map is a seam): only the (W/F - 1) x
//     (H/F - 1) coarse cells that do not wrap have data terms (their fine cells never cross
//     the seam); the F - 1 fine columns/rows past the last coarse vertex lie in the coarse
//     seam cell and are not used. The Laplacian is evaluated at every vertex with the terms
//     of the axes along which it has both neighbours (the 1D second difference along an
//     edge, nothing at a corner): the boundary gets no spurious pull, and any bilinear
//     polynomial a + b x + c y + d x y has zero regulariser, so such a map is reproduced exactly.
//   * The objective only sees height differences: the null space is a constant offset (for
//     w > 0; with w = 0 also the checkerboard (-1)^(I+J), which no average slope can see -
//     that is why the regulariser is needed). The offset is fixed by pinning vertex 0 during
//     the solve (with w = 0 vertex 1 too, and the checkerboard component is then projected
//     out: the minimum-norm choice) and then shifting the result so that the mean height of the coarse bilinear
//     surface equals that of the fine bilinear surface over the same region: the plain vertex
//     means for periodic maps, trapezoid-weighted means over [0, (W/F - 1) F] x
//     [0, (H/F - 1) F] otherwise.
//   * Consequence worth knowing: with w > 0 even a fine map that is itself the bilinear
//     upsampling of a coarse map is not reproduced exactly unless that coarse map has zero
//     Laplacian (the regulariser pulls it by O(w)); as w -> 0 the solution tends to the
//     coarse map minus the part of its checkerboard component the slopes cannot see.
//   * Degenerate non-periodic sizes: no coarse cell (W/F == 1 or H/F == 1) -> a constant map
//     at the fine mean; a single 2 x 2 cell (no vertex has a Laplacian term) is treated like
//     w = 0: the planar solution, which matches the cell's reference slope exactly.
//
// Solver: the normal equations (A^T A + w D^T D) h = A^T s~* (A: slope operator, 2 rows per
// cell; D: Laplacian), symmetric positive definite after the pin, solved by Eigen's
// SimplicialLDLT (direct, exact to round-off; fill-in makes it slow beyond ~128^2 unknowns,
// periodic maps especially) or by incomplete-Cholesky preconditioned conjugate gradients
// warm-started from the fine heights sampled at the coarse vertices (relative residual
// 1e-10; falls back to the direct solver if it does not converge).
#pragma once
#include <string>
#include <vector>
#include "geometry/heightmap.h"

namespace meso::prefilter {

enum class LsqSolver {
    Auto,    ///< Direct up to LsqOptions::direct_max_unknowns unknowns, CG above
    Direct,  ///< Eigen::SimplicialLDLT on the normal equations
    CG,      ///< Eigen::ConjugateGradient (incomplete-Cholesky preconditioned)
};

struct LsqOptions {
    bool periodic = true;
    double w_reg = 0.01;               ///< paper 004's w; must be finite and >= 0
    LsqSolver solver = LsqSolver::Auto;
    int direct_max_unknowns = 4096;    ///< Auto: the direct solver up to this many coarse vertices
    double cg_tolerance = 1e-10;       ///< CG: relative residual |r| / |b|
    int cg_max_iterations = 0;         ///< CG: 0 = automatic (a few thousand)
};

struct LowResHeights {
    int width = 0, height = 0;  ///< coarse vertices (W/F x H/F)
    int factor = 1;
    bool periodic = true;
    double w_reg = 0.01;
    std::vector<double> h;  ///< width * height vertex heights, row-major, same conventions as HeightMap

    double at(int i, int j) const { return h[size_t(j) * size_t(width) + size_t(i)]; }
    /// The heights as a (float) HeightMap, ready for a Heightfield.
    HeightMap to_height_map() const;

    // Diagnostics (slopes in height per coarse cell).
    int data_cells = 0;                ///< coarse cells with a slope term
    double slope_rms_error = 0;        ///< sqrt(mean over data cells of |s~ - s~*|^2)
    double slope_max_error = 0;        ///< max over data cells of |s~ - s~*|
    double slope_rms_reference = 0;    ///< sqrt(mean |s~*|^2): scale for slope_rms_error
    double laplacian_rms = 0;          ///< sqrt(mean (Delta h_low)^2) over the regularised vertices
    double slope_sq_error = 0;         ///< sum over data cells of |s~ - s~*|^2 (first term of eq. 10)
    double laplacian_sq = 0;           ///< sum over vertices of (Delta h_low)^2 (second term, without w)
    double objective = 0;              ///< L(h_low) of eq. (10) = slope_sq_error + w * laplacian_sq
    double mean_height = 0;            ///< the (fine = coarse) mean height that was matched
    double assembly_seconds = 0;       ///< reference slopes + normal equations
    double solve_seconds = 0;          ///< factorisation / iterations
    int iterations = 0;                ///< CG iterations (0 for the direct solver)
    double cg_relative_residual = 0;   ///< CG: final |r| / |b|
    std::string solver;                ///< what solved it: "direct", "cg" or "trivial" (no cell)
};

/// Downsamples `fine` by `factor` (>= 1, dividing both sizes) with paper 004's least squares.
/// Throws MesoError for an empty map, a bad factor, a negative / non-finite w or non-finite
/// heights.
LowResHeights downsample_least_squares(const HeightMap &fine, int factor, const LsqOptions &options);
/// The brief's form: periodic when the map tiles, w = 0.01 by default.
LowResHeights downsample_least_squares(const HeightMap &fine, int factor, bool periodic, double w_reg = 0.01);

/// Per-cell average slopes on a coarse grid (height per coarse cell). Cells are indexed
/// (I, J) over cells_x x cells_y: all W/F x H/F coarse cells when periodic, the (W/F - 1) x
/// (H/F - 1) non-wrapping ones otherwise.
struct CellSlopes {
    int cells_x = 0, cells_y = 0;
    std::vector<double> sx, sy;  ///< row-major, cells_x * cells_y
};

/// s~* of eq. (10): the fine microsurface's average slope over each coarse cell (eq. 1, box kernel).
CellSlopes reference_slopes(const HeightMap &fine, int factor, bool periodic);
/// s~ of eq. (9) for a vertex grid (e.g. LowResHeights::h) with the same cell convention.
CellSlopes bilinear_slopes(const std::vector<double> &h, int width, int height, bool periodic);

}  // namespace meso::prefilter
