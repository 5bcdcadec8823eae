// Scene syntax of a Ramp (filter/transfer_filter.h): colour maps and height transfer functions.
//
//   "colormap": [[0.0, [0.1, 0.2, 0.6]], [0.5, [0.9, 0.8, 0.3]], [1.0, 1.0]]
//       stops [x, value], x strictly increasing; a value is a number (grey: every channel) or
//       an array of `channels` numbers (3 for colours, 1 for transfer functions)
//   "colormap": {"filename": "ramp.png", "range": [-0.05, 0.05], "raw": false}
//       an image whose middle row holds the map: texel i is the stop at
//       range[0] + (i + 0.5) / width * (range[1] - range[0]); sRGB PNG/JPEG are linearised
//       unless "raw" is true. One-channel images become grey colours.
// Errors name the file, the JSON path and what was expected.
#pragma once
#include <string>
#include "filter/transfer_filter.h"

namespace meso {

class Properties;

/// Reads p[key] as a Ramp with `channels` outputs (1 or 3).
Ramp parse_ramp(const Properties &p, const std::string &key, int channels);

}  // namespace meso
