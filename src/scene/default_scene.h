// Scenes made up around a lone model, so that `meso render model.ply` (or .obj, .gltf/.glb
// without a camera) just works: a camera framing the model's bounding box, and for a bare mesh a
// grey diffuse material, a constant environment and a directional key light.
#pragma once
#include <string>
#include <nlohmann/json_fwd.hpp>
#include "core/vec.h"

namespace meso {

/// A 640 x 480 perspective camera (fov 40 degrees vertical) on +z of the box [bmin, bmax],
/// looking at its centre from a distance at which its bounding sphere fits the view. An empty or
/// non-finite box is treated as [-1, 1]^3.
nlohmann::json framing_camera(Vec3 bmin, Vec3 bmax);

/// True for the mesh files a scene can be made of: .obj and .ply (any case).
bool is_mesh_scene_path(const std::string &path);

/// The scene JSON for a bare mesh file (obj or ply shape with the file's name, grey diffuse
/// material 0.5, constant environment of radiance 0.6 and a directional light of irradiance 2.5
/// from above right, `path` integrator, 16 spp). The file is read once here for its bounds.
nlohmann::json mesh_scene_to_json(const std::string &path);

}  // namespace meso
