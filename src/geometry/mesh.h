// Indexed triangle meshes in world space.
#pragma once
#include <cstdint>
#include <string>
#include <vector>
#include "core/transform.h"

namespace meso {

struct TriangleMesh {
    std::vector<Vec3> positions;
    std::vector<Vec3> normals;      ///< per vertex, optional (empty = flat shading)
    std::vector<Vec2> uvs;          ///< per vertex, optional
    std::vector<Vec3> tangents;     ///< per vertex, optional (glTF tangents, xyz)
    std::vector<float> tangent_signs;///< per vertex bitangent sign, optional
    std::vector<uint32_t> indices;  ///< 3 per triangle

    size_t triangle_count() const { return indices.size() / 3; }
    size_t vertex_count() const { return positions.size(); }
    void transform(const Transform &t);
    float triangle_area(size_t tri) const;
    float surface_area() const;
    /// World length of one unit of u and of v: the area-weighted mean of |dp/du| and |dp/dv|
    /// over the triangles with a non-degenerate uv parameterisation (a rectangle scaled by s:
    /// 2s each). False without uvs or when no triangle has one.
    bool uv_world_length(double &lu, double &lv) const;
    /// Memory held, in bytes (for `meso render --plan`).
    size_t memory_bytes() const;
    /// Throws MesoError naming `where` when indices are out of range or sizes disagree.
    void validate(const std::string &where) const;
};

/// For each vertex, the index of the first vertex within 1e-6 of the mesh's largest
/// bounding-box extent (per coordinate) — the representative all its copies share: welds
/// the duplicates that uv seams, split normals and poles create, so topology code (shell
/// prisms, subdivision) sees one vertex where the surface has one point.
std::vector<uint32_t> weld_vertices(const TriangleMesh &mesh);
/// Area-weighted (unnormalised cross product) vertex normals over the welded topology,
/// normalised; every copy of a welded vertex gets the same normal.
std::vector<Vec3> vertex_normals(const TriangleMesh &mesh, const std::vector<uint32_t> &weld);

/// Procedural meshes (all in object space, before to_world).
TriangleMesh make_rectangle();                 ///< [-1,1]^2 at z=0, normal +z, uv in [0,1]^2
TriangleMesh make_cube();                      ///< [-1,1]^3, outward normals, per-face uv
TriangleMesh make_disk(int segments = 64);     ///< unit disk at z=0, normal +z
TriangleMesh make_uv_sphere(int rings, int segments); ///< unit sphere, smooth normals

}  // namespace meso
