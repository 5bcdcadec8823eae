// A shape's "displacement" block: a heightfield over the shape's uv parameterisation,
// traced exactly through a shell map (mode "shell") or refined into triangles with
// OpenSubdiv (mode "tessellate"). See docs/scene-format.md, "displacement".
//
// Height transfer functions (paper 001 §7): "transfer": a one-channel ramp g (filter/ramp_parse.h)
// applied to every map value before scale and offset, field = offset + scale * g(map): the exact
// micro-geometry h = g(f) of a grey function f (noise, a generated map) reshaped by a non-linear
// curve (plateaus, clipping). g is piecewise linear, constant beyond its first and last stop.
#pragma once
#include <memory>
#include <string>
#include <vector>
#include "core/vec.h"
#include "geometry/heightfield.h"

namespace meso {

class Properties;
class Ramp;
struct TriangleMesh;

enum class DisplacementMode { Shell, Tessellate };
enum class SubdivScheme { Bilinear, CatmullClark };

/// Default limit on triangles of an explicitly tessellated shape, sized for 24 GB:
/// Embree's BVH plus meso's vertex and index buffers take about 150 bytes a triangle.
constexpr size_t kDefaultMaxTriangles = size_t(64) << 20;

struct Displacement {
    /// Heights in world units, offset + scale * g(map) (g the identity without "transfer"); from
    /// parse_displacement(..., apply_transfer = false) with a transfer: the untransformed map f
    /// itself (map units: scale 1, offset 0), see field_untransferred.
    std::shared_ptr<const Heightfield> field;
    std::shared_ptr<const Ramp> transfer;      ///< g of "transfer" (one channel), or null
    /// With a transfer applied to `field`: the map f before g (map units), for LoD levels displaced
    /// by the paper's g-bar (transfer_downsampled); null otherwise.
    std::shared_ptr<const HeightMap> untransferred;
    bool field_untransferred = false;          ///< field holds f in map units; world = offset + scale * g(f)
    std::string source;                        ///< map file or generator, for messages and --plan
    /// Repeats of `field` over uv [0,1]. With wrap clamp or mirror, field is the map's 2W x 2H
    /// periodic_extension and these are half the user's "tiling" (the uv -> map mapping is kept).
    float tiling_u = 1.f, tiling_v = 1.f;
    WrapMode wrap = WrapMode::Repeat;          ///< "wrap": how the map continues past its edges
    float scale = 1.f, offset = 0.f;           ///< field = offset + scale * g(map) (for LoD maps in map units)
    DisplacementMode mode = DisplacementMode::Shell;
    SubdivScheme scheme = SubdivScheme::Bilinear;
    int level = -1;                     ///< tessellation level; -1: to the map's resolution
    size_t max_triangles = kDefaultMaxTriangles;

    /// Cell-space coordinates of surface uv.
    Vec2 to_cell(Vec2 uv) const {
        return Vec2(uv.x * float(field->width()) * tiling_u, uv.y * float(field->height()) * tiling_v);
    }
    /// Height (world units) at surface uv.
    float height_at(Vec2 uv) const {
        return field->eval(double(uv.x) * field->width() * tiling_u, double(uv.y) * field->height() * tiling_v);
    }
};

/// Reads the "displacement" object `p` (map | generator, transfer, scale, offset, tiling, wrap,
/// mode, scheme, level). "wrap" defaults to "repeat", or "clamp" for a generated map that does not
/// tile (a mean-slope ramp); `max_triangles` comes from the command line (--max-triangles).
/// apply_transfer = false (for filtering g on the statistics of f, texture/slope_source.h): with a
/// "transfer", field is the map f itself in map units (scale 1, offset 0, g not applied) and
/// field_untransferred is set; without one it changes nothing.
Displacement parse_displacement(const Properties &p, size_t max_triangles, bool apply_transfer = true);

/// Empty when `uvs` stay where a clamped displacement's periodic extension is exact (uv x tiling
/// within [-0.5, 1.5) of the map, heightmap.h); otherwise what goes beyond. Repeat and mirror: empty.
std::string wrap_range_problem(const Displacement &d, const std::vector<Vec2> &uvs);

/// Paper 001 §7, "displaced geometry uses g-bar": a map `factor` times coarser whose vertex (i, j)
/// is E[g(f)] under N(f_bar, sigma_f^2), f_bar and sigma_f^2 the mean and variance of f over the
/// factor x factor block of vertices that box_downsampled averages (map units; eq. 21). With g the
/// identity it equals the box-downsampled f. MesoError unless factor divides both sizes.
HeightMap transfer_downsampled(const HeightMap &f, const Ramp &g, int factor);

}  // namespace meso
