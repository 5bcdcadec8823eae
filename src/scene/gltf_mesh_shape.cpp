// `gltf` shape: triangle meshes from a glTF 2.0 file (.gltf or .glb), node transforms
// applied, then the shape's own to_world.
//
//   filename      string   required   the .gltf / .glb file (relative to the scene file)
//   primitive     integer  all        only this primitive instance (index in node
//                                     traversal order, as `meso` lists them)
//   mesh          integer  all        only the instances of this glTF mesh
//   to_world      transform identity  applied after the glTF node transforms
//   flip_normals  boolean  false      reverse normals and winding
//
// Without `primitive` or `mesh`, every primitive of the file becomes one merged shape.
#include <fmt/format.h>
#include "core/error.h"
#include "geometry/mesh_shape.h"
#include "scene/gltf.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

/// Appends `b` to `a`; per-vertex attributes present in only one of them are dropped
/// for the merged mesh (they cannot be interpolated across the seam otherwise).
void append(TriangleMesh &a, const TriangleMesh &b, bool first) {
    if (first) {
        a = b;
        return;
    }
    uint32_t offset = uint32_t(a.positions.size());
    auto merge = [&](auto &va, const auto &vb) {
        if (va.empty() || vb.empty()) va.clear();
        else va.insert(va.end(), vb.begin(), vb.end());
    };
    merge(a.normals, b.normals);
    merge(a.uvs, b.uvs);
    merge(a.tangents, b.tangents);
    merge(a.tangent_signs, b.tangent_signs);
    a.positions.insert(a.positions.end(), b.positions.begin(), b.positions.end());
    for (uint32_t i : b.indices) a.indices.push_back(i + offset);
}

std::shared_ptr<Shape> create_gltf_shape(const Properties &p) {
    std::string file = p.get_file("filename");
    if (p.has("primitive") && p.has("mesh")) p.fail("give either \"primitive\" or \"mesh\", not both");
    std::shared_ptr<const std::vector<GltfPrimitive>> prims;
    try {
        prims = load_gltf_primitives(file);
    } catch (const MesoError &e) {
        p.fail("filename", e.what());
    }
    TriangleMesh mesh;
    std::string what;
    if (p.has("primitive")) {
        int k = p.get_int("primitive");
        if (k < 0 || size_t(k) >= prims->size())
            p.fail("primitive", fmt::format("primitive {} out of range ({} has {} triangle primitives)", k, file, prims->size()));
        mesh = (*prims)[size_t(k)].mesh;
        what = (*prims)[size_t(k)].name;
    } else {
        int only = p.has("mesh") ? p.get_int("mesh") : -1;
        bool first = true;
        for (const auto &g : *prims) {
            if (only >= 0 && g.mesh_index != only) continue;
            append(mesh, g.mesh, first);
            first = false;
        }
        if (first) {
            if (only >= 0) p.fail("mesh", fmt::format("no triangle primitive of mesh {} in {}", only, file));
            p.fail("filename", fmt::format("{} has no triangle meshes", file));
        }
        what = only >= 0 ? fmt::format("mesh {}", only) : "all meshes";
    }
    if (mesh.positions.size() > 0xffffffffu) p.fail("filename", "too many vertices");
    return make_mesh_shape(std::move(mesh), p, fmt::format("{} (gltf {}, {})", p.path(), file, what));
}

MESO_REGISTER_SHAPE("gltf", "triangle meshes from a glTF 2.0 file (filename, primitive | mesh, to_world, flip_normals)",
                    create_gltf_shape);

}  // namespace
}  // namespace meso
