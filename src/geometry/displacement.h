// A shape's "displacement" block: a heightfield over the shape's uv parameterisation,
// traced exactly through a shell map (mode "shell") or refined into triangles with
// OpenSubdiv (mode "tessellate"). See docs/scene-format.md, "displacement".
#pragma once
#include <memory>
#include <string>
#include "core/vec.h"
#include "geometry/heightfield.h"

namespace meso {

class Properties;
struct TriangleMesh;

enum class DisplacementMode { Shell, Tessellate };
enum class SubdivScheme { Bilinear, CatmullClark };

/// Default limit on triangles of an explicitly tessellated shape, sized for 24 GB:
/// Embree's BVH plus meso's vertex and index buffers take about 150 bytes a triangle.
constexpr size_t kDefaultMaxTriangles = size_t(64) << 20;

struct Displacement {
    std::shared_ptr<const Heightfield> field;  ///< heights in world units (offset + scale * map)
    std::string source;                        ///< map file or generator, for messages and --plan
    float tiling_u = 1.f, tiling_v = 1.f;      ///< repeats of the map over uv [0,1]
    float scale = 1.f, offset = 0.f;           ///< field = offset + scale * map (for LoD maps in map units)
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

/// Reads the "displacement" object `p` (map | generator, scale, offset, tiling, mode,
/// scheme, level); `max_triangles` comes from the command line (--max-triangles).
Displacement parse_displacement(const Properties &p, size_t max_triangles);

}  // namespace meso
