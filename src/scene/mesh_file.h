// Triangle meshes read from OBJ and PLY files, shared by the `obj` and `ply` shapes
// (scene/obj_shape.cpp, scene/ply_shape.cpp): fan triangulation, dropping invalid faces with
// one counted warning, and the common shape keys (face_normals, then make_mesh_shape's).
#pragma once
#include <cstdint>
#include <memory>
#include <string>
#include <vector>
#include "geometry/mesh.h"

namespace meso {

class Properties;
class Shape;

/// A mesh as read from a file, in object space.
struct MeshFile {
    TriangleMesh mesh;
    /// For each vertex, the vertex whose normal it shares when normals are computed (an OBJ
    /// vertex split by its uv or normal index shares its position's); empty: each its own.
    std::vector<uint32_t> weld;
    size_t file_vertices = 0;  ///< vertices (OBJ: `v` lines) in the file, for messages
    size_t faces = 0;        ///< faces in the file
    size_t polygons = 0;     ///< faces with more than 3 vertices (fan-triangulated)
    size_t short_faces = 0;  ///< faces with fewer than 3 vertices (dropped)
    /// What was dropped or ignored, one line each (empty: nothing); set by finish_mesh_file.
    std::vector<std::string> warnings;
};

/// Index that marks a face vertex the file refers to but does not have (out of range).
constexpr uint32_t MissingVertex = 0xffffffffu;

/// Reads an OBJ file (tinyobjloader). Errors name the file and, for syntax errors, the line.
MeshFile load_obj_mesh(const std::string &file);
/// Reads a PLY file: ASCII, binary little or big endian. Errors name the file, the header
/// line or the element (and its index) where the data is wrong or ends.
MeshFile load_ply_mesh(const std::string &file);

/// Appends the fan (v0, v_i, v_i+1) of one convex face of `n` vertices to `m.mesh.indices`,
/// counting the face; fewer than 3 vertices: counted in short_faces, nothing appended.
void add_face(MeshFile &m, const uint32_t *face, size_t n);

/// Drops triangles with an out-of-range index (>= vertex count, e.g. MissingVertex), a
/// repeated index or a vertex whose position is not finite, and the vertices only those used
/// when any is not finite; adds one warning counting what was dropped (and short faces).
/// Throws MesoError naming `file` when no triangle is left.
void finish_mesh_file(MeshFile &m, const std::string &file);

/// The shape of a mesh file: `face_normals` (drop normals: flat shading) or, when the file
/// has none, area-weighted vertex normals over `m.weld`; warnings printed with the scene
/// path; then make_mesh_shape (to_world, flip_normals, displacement).
std::shared_ptr<Shape> make_file_mesh_shape(MeshFile m, const Properties &p, const std::string &file,
                                            const std::string &kind);

}  // namespace meso
