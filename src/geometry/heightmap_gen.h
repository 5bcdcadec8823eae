// Procedural height maps: the generators behind `meso genmap` and scene-file height maps.
//
// Every generator returns a periodic W x H HeightMap (heights at grid vertices, row 0 at
// v = 0, see heightmap.h) that tiles seamlessly, except where a parameter makes that
// impossible (gaussian with a non-zero mean slope; relief from an image that does not
// tile): GeneratedMap::periodic says which, and GeneratedMap::notes says why.
//
// Units: the tile spans [0,1]^2 in its own uv and heights are in units of the tile side,
// so a map slope dh/du is "per tile": a cell (i, j) of a W-wide map has slope
// W * (h[i+1] - h[i]) along u. Displacing a tile of world size L with displacement
// scale = L reproduces these slopes in world space.
//
// The generators and their parameters are listed by height_map_generators(); the full
// documentation with examples is docs/genmap.md.
#pragma once
#include <map>
#include <string>
#include <vector>
#include "geometry/heightmap.h"
#include "image/image.h"

namespace meso {

struct GeneratedMap {
    HeightMap height;
    Image albedo;  ///< empty (width 0) unless the generator makes one; texel (i, j) covers cell (i, j)
    bool periodic = true;                      ///< false: the wrap-around has a seam
    std::vector<std::string> notes;            ///< facts worth printing (seams, straddling cells ...)
    std::map<std::string, std::string> params; ///< every parameter with the value used (defaults filled in)
};

struct GeneratorParam {
    std::string name, default_value, help;
};
struct GeneratorInfo {
    std::string name, help;
    std::vector<GeneratorParam> params;  ///< the common ones (size, width, height, seed) first
};

/// Every generator with its parameters (names, defaults as text, help), in a fixed order.
const std::vector<GeneratorInfo> &height_map_generators();

/// Runs generator `kind`. params: key -> value text (numbers as text, RGB as "r,g,b").
/// Unknown kinds or keys, unparsable or out-of-range values throw MesoError with a message
/// "<where>: <key>: expected ..." (`where` may be empty). Deterministic for a given seed.
GeneratedMap generate_height_map(const std::string &kind, const std::map<std::string, std::string> &params,
                                 const std::string &where = "");

/// Average slope of the bilinear cell (i, j) in tile units (paper 004, eq. 9 / Appendix A,
/// times the map size): s_u = W * (h10 + h11 - h00 - h01) / 2, s_v = H * (h01 + h11 - h00 - h10) / 2.
/// Indices wrap, so cell W-1 joins vertex W-1 to vertex 0.
void cell_slope(const HeightMap &map, int i, int j, double &su, double &sv);

/// Summary statistics of a map. Slope moments are over cells; with periodic = false the
/// cells that cross the wrap-around seam (last row and column) are left out.
struct HeightMapStats {
    double min = 0, max = 0, mean = 0;
    double mean_su = 0, mean_sv = 0;      ///< mean cell slope
    double sxx = 0, syy = 0, sxy = 0;     ///< cell-slope covariance (about the mean)
    double rms_slope = 0;                 ///< sqrt(mean(su^2 + sv^2)), not centred
};
HeightMapStats height_map_stats(const HeightMap &map, bool periodic = true);

}  // namespace meso
