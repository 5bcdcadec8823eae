// glTF 2.0 materials to meso material JSON: the metallic-roughness model, textures (with
// KHR_texture_transform and samplers), alpha modes, normal maps and emission. Internal to the
// glTF loader (gltf.cpp); see docs/scene-format.md, "glTF files as scenes".
#pragma once
#include <cstdio>
#include <string>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <tiny_gltf.h>
#include "core/vec.h"

namespace meso::gltf_detail {

using json = nlohmann::json;

/// "FILE: warning: MSG" on stderr.
inline void warn(const std::string &path, const std::string &msg) { fmt::print(stderr, "{}: warning: {}\n", path, msg); }

inline json vec3_json(Vec3 v) { return json::array({v.x, v.y, v.z}); }

/// A `bitmap` texture for a glTF textureInfo, or null (with a warning) when it cannot be read.
json texture_json(const std::string &path, const tinygltf::Model &model, int tex, int texcoord,
                  const tinygltf::ExtensionMap &exts, const std::string &mat, const char *what, bool raw,
                  const char *channel);
/// factor x texture as a meso texture value (the factor alone without a texture).
json scaled(json tex, json factor);
/// The meso material of glTF material `m`; `alpha`, when given, receives the shape keys of
/// its alpha mode (null for OPAQUE).
json map_material(const std::string &path, const tinygltf::Model &model, const tinygltf::Material &m, json *alpha);
/// emissiveFactor x KHR_materials_emissive_strength (zero when not finite or negative).
Vec3 emission(const tinygltf::Material &m);

}  // namespace meso::gltf_detail
