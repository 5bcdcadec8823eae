// Perceptually uniform false-colour maps for error images (viridis, van der Walt & Smith,
// matplotlib 2015): monotone in lightness, readable in greyscale and by colour-blind
// viewers, unlike a rainbow/jet map.
#pragma once
#include "core/spectrum.h"
#include "image/image.h"

namespace meso {

/// Viridis colour of t in [0, 1] (clamped; NaN -> 0), *display* (sRGB-encoded) values,
/// interpolated piecewise-linearly between 17 control points sampled from matplotlib.
Spectrum viridis_srgb(float t);
/// Same colour as linear RGB (for writing through write_png, which encodes to sRGB).
Spectrum viridis_linear(float t);

/// Log-scaled false-colour map of `values` (width x height, row-major, >= 0): log10(v)
/// mapped linearly from [log_lo, log_hi] onto viridis (clamped; v = 0 gets the bottom
/// colour). NaN/Inf entries are drawn magenta so they stand out from the map.
Image false_colour_log(const std::vector<double> &values, int width, int height, double log_lo, double log_hi);

}  // namespace meso
