#include "scene/default_scene.h"
#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>
#include "core/math.h"
#include "scene/mesh_file.h"

namespace meso {

using json = nlohmann::json;
namespace fs = std::filesystem;

json framing_camera(Vec3 bmin, Vec3 bmax) {
    if (!(bmin.x <= bmax.x && bmin.y <= bmax.y && bmin.z <= bmax.z) || !is_finite(bmin) || !is_finite(bmax))
        bmin = Vec3(-1, -1, -1), bmax = Vec3(1, 1, 1);
    const Vec3 c = (bmin + bmax) * 0.5f;
    const float r = std::max(1e-3f, length(bmax - bmin) * 0.5f);
    const float d = r / std::sin(radians(20.f)) * 1.05f;  // the bounding sphere fits the 40-degree view
    auto v = [](Vec3 p) { return json::array({p.x, p.y, p.z}); };
    return {{"type", "perspective"}, {"origin", v(c + Vec3(0, 0, d))}, {"target", v(c)},
            {"up", json::array({0, 1, 0})}, {"fov", 40}, {"fov_axis", "y"}, {"width", 640}, {"height", 480}};
}

namespace {
std::string lower_extension(const std::string &path) {
    std::string ext = fs::path(path).extension().string();
    for (char &ch : ext) ch = char(std::tolower(static_cast<unsigned char>(ch)));
    return ext;
}
}  // namespace

bool is_mesh_scene_path(const std::string &path) {
    const std::string ext = lower_extension(path);
    return ext == ".obj" || ext == ".ply";
}

json mesh_scene_to_json(const std::string &path) {
    const std::string kind = lower_extension(path) == ".obj" ? "obj" : "ply";
    MeshFile m = kind == "obj" ? load_obj_mesh(path) : load_ply_mesh(path);
    finish_mesh_file(m, path);
    Vec3 bmin(Infinity, Infinity, Infinity), bmax(-Infinity, -Infinity, -Infinity);
    for (const Vec3 &p : m.mesh.positions) bmin = vmin(bmin, p), bmax = vmax(bmax, p);
    json scene;
    scene["camera"] = framing_camera(bmin, bmax);
    scene["integrator"] = {{"type", "path"}};
    scene["sampler"] = {{"type", "independent"}, {"sample_count", 16}};
    // The file name relative to the scene "file" (the mesh itself), so relative paths resolve.
    scene["shapes"] = json::array({{{"type", kind},
                                    {"filename", fs::path(path).filename().string()},
                                    {"material", {{"type", "diffuse"}, {"reflectance", 0.5}}}}});
    scene["lights"] = json::array({{{"type", "constant"}, {"radiance", 0.6}},
                                   {{"type", "directional"}, {"direction", json::array({-0.4, -1.0, -0.6})},
                                    {"irradiance", 2.5}}});
    return scene;
}

}  // namespace meso
