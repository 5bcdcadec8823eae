// glTF 2.0 input (through tinygltf): triangle meshes for the `gltf` shape, and whole
// .gltf / .glb files as scenes.
//
// Meshes: every primitive of every mesh instanced by a node of the default scene, with
// the node transforms applied (world space). POSITION, NORMAL, TEXCOORD_0 and TANGENT
// are read from accessors of any component type (normalised integers included), indices
// of any unsigned type or none. TRIANGLES, TRIANGLE_STRIP and TRIANGLE_FAN become
// triangle lists; POINTS and LINES primitives are skipped with a warning on stderr.
// Images are never decoded here: textures become `bitmap` objects naming the image files
// (only an image's header is read, to know whether it has an alpha channel).
//
// Scenes: gltf_scene_to_json translates a glTF file into an ordinary meso scene JSON
// document (camera, textures, materials, shapes, lights) that then goes through the same
// plugin registry as a hand-written scene; docs/scene-format.md describes the mapping:
// metallic-roughness → `gltf_pbr` (normalTexture with its scale → `normalmap`,
// KHR_texture_transform → the bitmaps' tiling, rotation and offset), emission (factor ×
// strength × emissiveTexture) → an `area` emitter per shape, alphaMode MASK (BLEND as MASK)
// → the shapes' `alpha` / `alpha_cutoff`.
#pragma once
#include <memory>
#include <string>
#include <vector>
#include <nlohmann/json_fwd.hpp>
#include "geometry/mesh.h"

namespace meso {

/// One glTF primitive as instanced by one node, in world space.
struct GltfPrimitive {
    TriangleMesh mesh;
    int material = -1;    ///< glTF material index (-1: none)
    int mesh_index = -1;  ///< glTF mesh it came from
    std::string name;     ///< "mesh 'name' primitive k" (for messages)
};

/// All primitives of the file, world space, in node traversal order. Errors are
/// MesoError "path: message". Inside a GltfCacheScope a file is parsed only once.
std::shared_ptr<const std::vector<GltfPrimitive>> load_gltf_primitives(const std::string &path);

/// The meshes of load_gltf_primitives (one TriangleMesh per primitive instance).
std::vector<TriangleMesh> load_gltf_meshes(const std::string &path);

/// Translates a .gltf/.glb file into a meso scene JSON object. The shapes refer to the
/// file by its file name (relative to the file's own directory).
nlohmann::json gltf_scene_to_json(const std::string &path);

/// True for paths ending in .gltf or .glb (case-insensitive).
bool is_gltf_path(const std::string &path);

/// While one of these lives (load_scene holds one), parsed glTF files are cached, so a
/// scene whose shapes all come from one file parses it once. Nestable.
class GltfCacheScope {
public:
    GltfCacheScope();
    ~GltfCacheScope();
    GltfCacheScope(const GltfCacheScope &) = delete;
    GltfCacheScope &operator=(const GltfCacheScope &) = delete;
};

}  // namespace meso
