// Slope-moment maps (LEAN, Olano & Baker 2010; LEADR, paper 000 §4): for every cell of a
// heightfield, the first and second moments of the slopes of its bilinear patch, exactly
// integrated over the cell, as a 5-channel MIP pyramid (box filter = exact area averages, so
// a coarse texel holds the moments of all the microgeometry under it, sub-texel slope
// variance included: Var = E[x^2] - E[x]^2 grows with the level).
//
// Slopes are texture-space: x = dh/du, y = dh/dv with u, v the surface's uv (h in the
// heightfield's units, world units for a Displacement), so x = (dh/dcell) * cells_per_u.
// For a cell with corner heights h00, h10, h01, h11 (paper 004 App. A): the slopes are
// x(a, b) = e + g b, y(a, b) = f + g a over (a, b) in [0,1]^2, e = h10 - h00, f = h01 - h00,
// g = h00 + h11 - h10 - h01, hence per cell
//   E[x] = e + g/2,  E[y] = f + g/2,
//   E[x^2] = e^2 + e g + g^2/3,  E[y^2] = f^2 + f g + g^2/3,
//   E[xy] = (e + g/2)(f + g/2)   (a and b are independent).
// Texel (i, j) of level 0 is cell (i, j): the MipMap convention (texel i covers
// [i/W, (i+1)/W] of one tile), so lookups at the surface uv times the tiling line up.
#pragma once
#include "geometry/heightfield.h"
#include "filter/slope_gaussian.h"
#include "texture/mipmap.h"

namespace meso {

/// The slope moments of `hf`'s cells, for a surface on which one tile spans `tile_u` by
/// `tile_v` in uv (1 / tiling): slopes are per unit uv.
MipMap build_slope_moments(const Heightfield &hf, double tile_u = 1.0, double tile_v = 1.0);

/// Height moments for colour maps on heights (paper 001 §5.1): per cell the exact E[h - center]
/// and E[(h - center)^2] of its bilinear patch, as a 2-channel MIP pyramid (so a coarse texel
/// holds the mean and second moment of all the heights under it). For corners h00, h10, h01,
/// h11 (centred): E[h] = (h00 + h10 + h01 + h11) / 4 and E[h^2] = (sum of squares) / 9 +
/// (products of edge neighbours h00 h10 + h00 h01 + h10 h11 + h01 h11) / 9 + (diagonal
/// products h00 h11 + h10 h01) / 18. `center` (e.g. the map's mean) keeps the float variance
/// E[h^2] - E[h]^2 free of cancellation.
MipMap build_height_moments(const Heightfield &hf, double center);

}  // namespace meso
