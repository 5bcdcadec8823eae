// Scene file loading: exact error messages (Mitsuba's test_parser style), -D overrides,
// pay-only-for-use named objects, and a fuzz test (truncations, byte mutations, token
// deletions/duplications, value-type swaps) that must only ever produce MesoError.
#include <gtest/gtest.h>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <random>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "geometry/shape.h"
#include "lights/light.h"
#include "scene/overrides.h"
#include "core/registry.h"
#include "render/scene.h"

using namespace meso;
using json = nlohmann::json;
namespace fs = std::filesystem;

namespace {

/// A fresh directory under the system temp dir, removed at the end of the test.
class TempDir {
public:
    TempDir() {
        const auto *info = ::testing::UnitTest::GetInstance()->current_test_info();
        std::string name = fmt::format("meso_{}_{}_{}", info ? info->test_suite_name() : "x", info ? info->name() : "y",
                                       std::random_device{}());
        m_path = fs::temp_directory_path() / name;
        fs::create_directories(m_path);
    }
    ~TempDir() {
        std::error_code ec;
        fs::remove_all(m_path, ec);
    }
    std::string write(const std::string &name, const std::string &text) const {
        fs::path p = m_path / name;
        std::ofstream f(p, std::ios::binary);
        f << text;
        return p.string();
    }
    std::string path(const std::string &name) const { return (m_path / name).string(); }

private:
    fs::path m_path;
};

/// The message of the MesoError that loading `path` throws ("" and a failure if none).
std::string load_error(const std::string &path, const std::vector<std::string> &overrides = {}) {
    try {
        load_scene(path, overrides);
    } catch (const MesoError &e) {
        return e.what();
    } catch (const std::exception &e) {
        ADD_FAILURE() << "expected MesoError, got another exception: " << e.what();
        return e.what();
    }
    ADD_FAILURE() << "expected an error loading " << path;
    return "";
}

const char *kCamera = R"("camera": {"type": "perspective", "origin": [0, 1, 5], "target": [0, 0, 0], "width": 32, "height": 24})";

/// A scene with the given extra top-level members after the camera.
std::string scene_with(const std::string &rest) {
    return std::string("{\n  ") + kCamera + (rest.empty() ? "" : ",\n  " + rest) + "\n}\n";
}

template <typename T> std::string known_names(const PluginTable<T> &t) {
    std::string s;
    for (auto &kv : t.factories) s += (s.empty() ? "" : ", ") + kv.first;
    return s;
}

}  // namespace

// ------------------------------------------------------------------------------------------
// Reading and parsing

TEST(SceneParser, MissingFile) {
    TempDir dir;
    std::string p = dir.path("nope.json");
    EXPECT_EQ(load_error(p), p + ": cannot open the scene file (file not found)");
}

TEST(SceneParser, DirectoryIsNotASceneFile) {
    TempDir dir;
    std::string p = dir.path("");
    EXPECT_EQ(load_error(p), p + ": cannot open the scene file (it is a directory)");
}

TEST(SceneParser, InvalidJsonReportsLineAndColumn) {
    TempDir dir;
    std::string p = dir.write("bad.json", "{\n  \"camera\": {\"type\": \"perspective\",}\n}\n");
    EXPECT_EQ(load_error(p), p + ": cannot parse JSON at line 2, column 36: syntax error while parsing object key - "
                                 "unexpected '}'; expected string literal");
    std::string q = dir.write("trunc.json", "{\n  \"camera\": {\n");
    EXPECT_EQ(load_error(q), q + ": cannot parse JSON at line 3, column 1: syntax error while parsing object key - "
                                 "unexpected end of input; expected string literal");
    std::string r = dir.write("overflow.json", scene_with("\"shapes\": [{\"type\": \"sphere\",\n \"radius\": 1e400}]"));
    EXPECT_EQ(load_error(r), r + ": cannot parse JSON at line 4, column 12: number overflow parsing '1e400'");
}

TEST(SceneParser, CommentsAreAllowed) {
    TempDir dir;
    std::string p = dir.write("c.json", "// a comment\n{\n  /* block */ " + std::string(kCamera) + "\n}\n");
    auto scene = load_scene(p, {});
    EXPECT_TRUE(scene->camera);
}

TEST(SceneParser, DuplicateKey) {
    TempDir dir;
    std::string p = dir.write("dup.json", scene_with(R"("materials": {"red": {"type": "diffuse", "reflectance": 0.5, "reflectance": 0.2}})"));
    EXPECT_EQ(load_error(p), p + ": materials.red: duplicate key 'reflectance'");
    std::string q = dir.write("dup2.json", scene_with(R"("shapes": [{"type": "sphere"}, {"type": "sphere", "radius": 1, "radius": 2}])"));
    EXPECT_EQ(load_error(q), q + ": shapes[1]: duplicate key 'radius'");
}

TEST(SceneParser, TopLevel) {
    TempDir dir;
    std::string p = dir.write("arr.json", "[1, 2]");
    EXPECT_EQ(load_error(p), p + ": expected a JSON object at the top level, got an array");
    std::string q = dir.write("unknown.json", scene_with(R"("shape": [])"));
    EXPECT_EQ(load_error(q), q + ": unknown top-level key 'shape' (expected camera, integrator, sampler, textures, "
                                 "materials, shapes, lights)");
    std::string r = dir.write("nocam.json", "{\"shapes\": []}");
    EXPECT_EQ(load_error(r), r + ": missing the required top-level key 'camera' (e.g. {\"type\": \"perspective\", ...})");
    std::string s = dir.write("mats.json", scene_with(R"("materials": [1])"));
    EXPECT_EQ(load_error(s), s + ": materials: expected an object mapping names to materials, got an array");
    std::string t = dir.write("shapes.json", scene_with(R"("shapes": {"type": "sphere"})"));
    EXPECT_EQ(load_error(t), t + ": shapes: expected an array of objects, got an object");
}

// ------------------------------------------------------------------------------------------
// Plugins and parameters

TEST(SceneParser, UnknownPluginType) {
    TempDir dir;
    std::string p = dir.write("t.json", scene_with(R"("shapes": [{"type": "sphere"}, {"type": "spheer"}])"));
    EXPECT_EQ(load_error(p), p + ": shapes[1].type: unknown shape type 'spheer' (known: " + known_names(registry().shapes) + ")");
    std::string q = dir.write("m.json", scene_with(R"("shapes": [{"type": "sphere", "material": {"type": "difuse"}}])"));
    EXPECT_EQ(load_error(q),
              q + ": shapes[0].material.type: unknown material type 'difuse' (known: " + known_names(registry().materials) + ")");
    std::string r = dir.write("i.json", scene_with(R"("integrator": {"type": 3})"));
    EXPECT_EQ(load_error(r), r + ": integrator.type: expected a string naming a plugin, got an integer");
}

TEST(SceneParser, WrongValueType) {
    TempDir dir;
    std::string p = dir.write("t.json", scene_with(R"("lights": [{"type": "point", "intensity": "bright"}])"));
    EXPECT_EQ(load_error(p), p + ": lights[0].intensity: expected a number or an [r, g, b] array, got a string");
    std::string q = dir.write("t2.json", scene_with(R"("lights": [{"type": "point", "intensity": [1, 2]}])"));
    EXPECT_EQ(load_error(q), q + ": lights[0].intensity: expected a number or an [r, g, b] array, got an array");
    std::string r = dir.write("t3.json", scene_with(R"("materials": {"red": {"type": "diffuse", "reflectance": true}},
        "shapes": [{"type": "sphere", "material": "red"}])"));
    EXPECT_EQ(load_error(r), r + ": materials.red.reflectance: expected a number, an [r, g, b] array, a texture object or "
                                 "a texture name, got a boolean");
    std::string s = dir.write("t4.json", scene_with(R"("shapes": [{"type": "sphere", "radius": "big"}])"));
    EXPECT_EQ(load_error(s), s + ": shapes[0].radius: expected a number, got a string");
    std::string t = dir.write("t5.json", scene_with(R"("sampler": {"type": "independent", "sample_count": 2.5})"));
    EXPECT_EQ(load_error(t), t + ": sampler.sample_count: expected an integer, got a number");
    std::string u = dir.write("t6.json", scene_with(R"("sampler": {"type": "independent", "sample_count": 0})"));
    EXPECT_EQ(load_error(u), u + ": sampler.sample_count: expected an integer at least 1, got 0");
}

TEST(SceneParser, UnknownParameter) {
    TempDir dir;
    std::string p = dir.write("t.json", scene_with(R"("shapes": [{"type": "sphere", "radus": 2}])"));
    EXPECT_EQ(load_error(p), p + ": shapes[0].radus: unknown parameter 'radus' for shape 'sphere'");
    std::string q = dir.write("t2.json", scene_with(R"("shapes": [{"type": "sphere", "material": {"type": "diffuse", "albedo": 0.5}}])"));
    EXPECT_EQ(load_error(q), q + ": shapes[0].material.albedo: unknown parameter 'albedo' for material 'diffuse'");
    std::string r = dir.write("t3.json", scene_with(R"("integrator": {"type": "path", "maxdepth": 3})"));
    EXPECT_EQ(load_error(r), r + ": integrator.maxdepth: unknown parameter 'maxdepth' for integrator 'path'");
}

TEST(SceneParser, MissingReferencedFile) {
    TempDir dir;
    std::string p = dir.write("t.json", scene_with(R"("lights": [{"type": "envmap", "filename": "nothere.exr"}])"));
    EXPECT_EQ(load_error(p), p + ": lights[0].filename: file not found: '" + dir.path("nothere.exr") + "'");
    std::string q = dir.write("g.json", scene_with(R"("shapes": [{"type": "gltf", "filename": "nothere.gltf"}])"));
    EXPECT_EQ(load_error(q), q + ": shapes[0].filename: file not found: '" + dir.path("nothere.gltf") + "'");
}

TEST(SceneParser, MalformedExr) {
    TempDir dir;
    // The OpenEXR magic number, then garbage.
    static const char garbage[] = "\x76\x2f\x31\x01 this is not an OpenEXR file \xff\xfe\x00\x01";
    dir.write("garbage.exr", std::string(garbage, sizeof(garbage) - 1));
    std::string p = dir.write("t.json", scene_with(R"("lights": [{"type": "envmap", "filename": "garbage.exr"}])"));
    std::string msg = load_error(p);
    // The envmap plugin owns the rest of the message (it comes from OpenImageIO).
    std::string prefix = p + ": lights[0].filename: ";
    EXPECT_EQ(msg.substr(0, prefix.size()), prefix) << msg;
    EXPECT_NE(msg.find("garbage.exr"), std::string::npos) << msg;
    EXPECT_EQ(msg.find('\n'), std::string::npos) << "one line: " << msg;
}

TEST(SceneParser, NamedMaterials) {
    TempDir dir;
    std::string p = dir.write("t.json", scene_with(R"("shapes": [{"type": "sphere", "material": "blue"}])"));
    EXPECT_EQ(load_error(p), p + ": shapes[0].material: no material named 'blue' (declare it in the top-level \"materials\" object)");
    std::string q = dir.write("t2.json", scene_with(R"("materials": {"red": {"type": "diffuse", "reflectance": "checks"}},
        "shapes": [{"type": "sphere", "material": "red"}])"));
    EXPECT_EQ(load_error(q), q + ": materials.red.reflectance: no texture named 'checks' (declare it in the top-level \"textures\" object)");
    // A name refers to one shared object, built once.
    std::string r = dir.write("t3.json", scene_with(R"("textures": {"checks": {"type": "checkerboard"}},
        "materials": {"red": {"type": "diffuse", "reflectance": "checks"}},
        "shapes": [{"type": "sphere", "material": "red"}, {"type": "sphere", "center": [3, 0, 0], "material": "red"}])"));
    auto scene = load_scene(r, {});
    ASSERT_EQ(scene->shapes.size(), 2u);
    EXPECT_TRUE(scene->shapes[0]->material);
    EXPECT_EQ(scene->shapes[0]->material, scene->shapes[1]->material);
}

TEST(SceneParser, UnusedNamedObjectsAreNeverBuilt) {
    // Pay only for what is used: an unreferenced declaration is not built, so even an
    // invalid one (unknown type, unknown parameter, missing file) costs nothing and is not
    // reported.
    TempDir dir;
    std::string p = dir.write("t.json", scene_with(R"("textures": {"env": {"type": "bitmap", "filename": "missing.exr"}},
        "materials": {"unused": {"type": "diffuse", "bogus": 1}, "typo": {"type": "nosuchmaterial"},
                      "used": {"type": "diffuse"}},
        "shapes": [{"type": "sphere", "material": "used"}])"));
    auto scene = load_scene(p, {});
    EXPECT_EQ(scene->shapes.size(), 1u);
}

TEST(SceneParser, Defaults) {
    TempDir dir;
    std::string p = dir.write("t.json", scene_with(R"("shapes": [{"type": "sphere"}])"));
    auto scene = load_scene(p, {});
    EXPECT_EQ(scene->file, p);
    ASSERT_TRUE(scene->camera);
    EXPECT_EQ(scene->camera->width(), 32);
    EXPECT_TRUE(scene->integrator);
    EXPECT_TRUE(scene->sampler);
    EXPECT_EQ(scene->spp, 16);
    ASSERT_EQ(scene->shapes.size(), 1u);
    EXPECT_TRUE(scene->shapes[0]->material);  // the default diffuse
    EXPECT_TRUE(scene->lights.empty());
}

TEST(SceneParser, EmittersAndLights) {
    TempDir dir;
    std::string p = dir.write("t.json", scene_with(R"("sampler": {"type": "sobol", "sample_count": 8},
        "shapes": [{"type": "rectangle", "emitter": {"type": "area", "radiance": [10, 10, 10]}}, {"type": "sphere", "center": [5, 0, 0]}],
        "lights": [{"type": "point", "position": [0, 3, 0], "intensity": 5}, {"type": "constant", "radiance": 0.5}])"));
    auto scene = load_scene(p, {});
    EXPECT_EQ(scene->spp, 8);
    ASSERT_EQ(scene->shapes.size(), 2u);
    ASSERT_TRUE(scene->shapes[0]->emitter);
    EXPECT_FALSE(scene->shapes[1]->emitter);
    ASSERT_EQ(scene->lights.size(), 3u);
    EXPECT_EQ(scene->lights[0], scene->shapes[0]->emitter);
    EXPECT_TRUE(scene->lights[1]->is_delta());
    ASSERT_EQ(scene->infinite_lights.size(), 1u);
    EXPECT_EQ(scene->infinite_lights[0], scene->lights[2].get());

    // The loaded scene builds and traces (a ray down onto the rectangle at z = 0).
    scene->build();
    SurfaceInteraction si;
    Ray ray(Vec3(0.2f, 0.1f, 3.f), Vec3(0, 0, -1));
    ASSERT_TRUE(scene->intersect(ray, si));
    EXPECT_NEAR(si.p.z, 0.f, 1e-4f);

    std::string q = dir.write("t2.json", scene_with(R"("shapes": [{"type": "sphere", "emitter": {"type": "point"}}])"));
    EXPECT_EQ(load_error(q), q + ": shapes[0].emitter.type: light type 'point' cannot be the emitter of a shape (use an 'area' light)");
    std::string r = dir.write("t3.json", scene_with(R"("lights": [{"type": "area", "radiance": 1}])"));
    EXPECT_EQ(load_error(r), r + ": lights[0].type: light type 'area' must be attached to a shape (as its \"emitter\")");
}

// ------------------------------------------------------------------------------------------
// -D overrides

TEST(Override, SetCreateAndParseValues) {
    json j = json::parse(R"({"camera": {"type": "perspective", "fov": 40}, "shapes": [{"type": "sphere"}, {"type": "cube"}]})");
    apply_override(j, "camera.fov=30");
    EXPECT_EQ(j["camera"]["fov"], 30);
    apply_override(j, "shapes[1].to_world.translate=[0, 1, 0]");  // creates to_world
    EXPECT_EQ(j["shapes"][1]["to_world"]["translate"], json::parse("[0, 1, 0]"));
    apply_override(j, "shapes[0].type=rectangle");  // not JSON: a string
    EXPECT_EQ(j["shapes"][0]["type"], "rectangle");
    apply_override(j, "shapes[0].name=\"42\"");  // a quoted JSON string stays a string
    EXPECT_EQ(j["shapes"][0]["name"], "42");
    apply_override(j, "shapes[0].flip_normals=true");
    EXPECT_EQ(j["shapes"][0]["flip_normals"], true);
    apply_override(j, "integrator={\"type\": \"direct\"}");
    EXPECT_EQ(j["integrator"]["type"], "direct");
    apply_override(j, "a.b.c=x=y");  // only the first '=' separates
    EXPECT_EQ(j["a"]["b"]["c"], "x=y");
    apply_override(j, "camera.label=");
    EXPECT_EQ(j["camera"]["label"], "");
}

TEST(Override, Errors) {
    json j = json::parse(R"({"camera": {"fov": 40}, "shapes": [{"type": "sphere"}, {"type": "cube"}, {"type": "disk"}]})");
    auto err = [&](const std::string &a) -> std::string {
        try {
            apply_override(j, a);
        } catch (const MesoError &e) {
            return e.what();
        }
        return "no error";
    };
    EXPECT_EQ(err("shapes[9].material=red"), "-D shapes[9].material: index 9 out of range (shapes has 3 elements)");
    EXPECT_EQ(err("camera.fov.x=1"), "-D camera.fov.x: cannot set 'x': camera.fov is a number, not an object");
    EXPECT_EQ(err("camera[0]=1"), "-D camera[0]: cannot index camera: it is an object, not an array");
    EXPECT_EQ(err("shapes.type=x"), "-D shapes.type: cannot set 'type': shapes is an array, not an object");
    EXPECT_EQ(err("camera.fov"), "-D camera.fov: expected key=value");
    EXPECT_EQ(err("=3"), "-D : empty key (expected -D path.to.key=value)");
    EXPECT_EQ(err("camera..fov=3"), "-D camera..fov: empty key name");
    EXPECT_EQ(err("shapes[x]=3"), "-D shapes[x]: expected an array index in [], got '[x]'");
    EXPECT_EQ(err("shapes[0=3"), "-D shapes[0: missing ']'");
    EXPECT_EQ(err("[0]=3"), "-D [0]: expected a key name before '['");
    EXPECT_EQ(err("camera.=3"), "-D camera.: empty key name at the end");
    // Nothing was changed by the failed assignments.
    EXPECT_EQ(j, json::parse(R"({"camera": {"fov": 40}, "shapes": [{"type": "sphere"}, {"type": "cube"}, {"type": "disk"}]})"));
}

TEST(Override, AppliedByLoadScene) {
    TempDir dir;
    std::string p = dir.write("t.json", scene_with(R"("sampler": {"type": "independent", "sample_count": 4},
        "shapes": [{"type": "rectangle"}, {"type": "sphere"}])"));
    auto scene = load_scene(p, {"sampler.sample_count=7", "shapes[0].to_world.translate=[0, 2, 0]"});
    EXPECT_EQ(scene->spp, 7);
    ASSERT_TRUE(scene->shapes[0]->mesh());
    for (const Vec3 &v : scene->shapes[0]->mesh()->positions) EXPECT_FLOAT_EQ(v.y > 2.f ? v.y - 2.f : 2.f - v.y, 1.f);
    EXPECT_EQ(load_error(p, {"shapes[5].type=cube"}), "-D shapes[5].type: index 5 out of range (shapes has 2 elements)");
    // Overridden values are checked like written ones.
    EXPECT_EQ(load_error(p, {"shapes[1].radius=big"}), p + ": shapes[1].radius: expected a number, got a string");
    EXPECT_EQ(load_error(p, {"shapes[1].radus=2"}), p + ": shapes[1].radus: unknown parameter 'radus' for shape 'sphere'");
}

// ------------------------------------------------------------------------------------------
// Fuzz: load_scene on mangled scene files must succeed or throw MesoError, nothing else.

namespace {

std::vector<std::string> fuzz_base_scenes() {
    std::string quad = std::string(MESO_SOURCE_DIR) + "/scenes/tests/quad.gltf";
    return {
        R"({
  "camera": {"type": "perspective", "origin": [0, 1, 5], "target": [0, 0, 0], "up": [0, 1, 0], "fov": 40, "width": 64, "height": 48},
  "integrator": {"type": "path", "max_depth": 8},
  "sampler": {"type": "sobol", "sample_count": 4},
  "textures": {"checks": {"type": "checkerboard", "color0": 0.2, "color1": 0.8}},
  "materials": {"red": {"type": "diffuse", "reflectance": [0.8, 0.1, 0.1]}, "gold": {"type": "conductor", "material": "Au", "alpha": 0.2}},
  "shapes": [
    {"type": "rectangle", "material": "red", "to_world": {"scale": [5, 5, 1], "rotate": {"axis": [1, 0, 0], "angle": -90}}},
    {"type": "sphere", "center": [0, 1, 0], "radius": 0.5, "material": "gold"},
    {"type": "rectangle", "emitter": {"type": "area", "radiance": [10, 10, 10]}, "material": {"type": "diffuse", "reflectance": 0},
     "to_world": {"translate": [0, 3, 0], "rotate": {"axis": [1, 0, 0], "angle": 90}}}
  ],
  "lights": [{"type": "constant", "radiance": 0.1}]
})",
        R"({
  "camera": {"type": "perspective", "origin": [3, 3, 3], "target": [0, 0, 0], "fov": 30, "fov_axis": "y", "width": 32, "height": 32},
  "integrator": {"type": "direct"},
  "sampler": {"type": "independent", "sample_count": 2, "seed": 3},
  "materials": {"floor": {"type": "diffuse", "reflectance": {"type": "checkerboard", "color0": [0.1, 0.1, 0.1], "color1": 0.9}}},
  "shapes": [
    {"type": "cube", "material": "floor", "to_world": {"matrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]}},
    {"type": "gltf", "filename": ")" + quad + R"(", "material": {"type": "dielectric", "eta": 1.5}, "flip_normals": true},
    {"type": "disk", "to_world": {"scale": 2, "translate": [0, -1, 0]}}
  ],
  "lights": [{"type": "point", "position": [0, 4, 0], "intensity": [5, 5, 5]},
             {"type": "directional", "direction": [0, -1, 0], "irradiance": 2},
             {"type": "spot", "position": [1, 4, 0], "target": [0, 0, 0], "intensity": 10, "cutoff_angle": 30, "beam_width": 20}]
})",
        R"({"camera": {"type": "perspective", "width": 16, "height": 16},
  "shapes": [{"type": "sphere"}, {"type": "gltf", "filename": ")" + quad + R"(", "primitive": 0, "to_world": {"rotate": [{"axis": [0, 1, 0], "angle": 30}]}}],
  "lights": [{"type": "constant"}]})",
    };
}

/// JSON-ish tokens: strings, numbers/literals, punctuation.
std::vector<std::pair<size_t, size_t>> tokenize(const std::string &s) {
    std::vector<std::pair<size_t, size_t>> t;
    size_t i = 0;
    while (i < s.size()) {
        char c = s[i];
        if (std::isspace(static_cast<unsigned char>(c))) { ++i; continue; }
        size_t b = i;
        if (c == '"') {
            ++i;
            while (i < s.size() && s[i] != '"') i += s[i] == '\\' ? 2 : 1;
            i = std::min(i + 1, s.size());
        } else if (std::string("{}[]:,").find(c) != std::string::npos) {
            ++i;
        } else {
            while (i < s.size() && !std::isspace(static_cast<unsigned char>(s[i])) && std::string("{}[]:,\"").find(s[i]) == std::string::npos) ++i;
        }
        t.push_back({b, i - b});
    }
    return t;
}

std::string mutate(const std::string &base, std::mt19937 &rng, int kind) {
    static const char *values[] = {"0", "-1", "1e30", "-1e-30", "1e400", "\"x\"", "\"\"", "true", "null", "[]", "{}",
                                   "[1, 2, 3]", "[[1]]", "{\"type\": 1}", "2147483648", "-0", "0.5", "\"Au\"", "[0, 0, 0]",
                                   "\"../../../../etc/passwd\"", "{\"type\": \"sphere\"}", "\"\\u0000\""};
    static const char bytes[] = "{}[]:,\"\\0123456789.-+eE tfn\x01\xff";
    std::string s = base;
    auto pick = [&](size_t n) { return n ? size_t(rng() % n) : 0; };
    switch (kind) {
        case 0:  // truncation
            return s.substr(0, pick(s.size()));
        case 1: {  // a few random byte mutations
            int n = 1 + int(rng() % 4);
            for (int k = 0; k < n && !s.empty(); ++k) {
                size_t i = pick(s.size());
                int op = int(rng() % 3);
                char b = rng() % 2 ? bytes[pick(sizeof(bytes) - 1)] : char(rng() & 0xff);
                if (op == 0) s[i] = b;
                else if (op == 1) s.insert(s.begin() + long(i), b);
                else s.erase(i, 1);
            }
            return s;
        }
        case 2:
        case 3: {  // delete or duplicate a token
            auto t = tokenize(s);
            auto [b, n] = t[pick(t.size())];
            if (kind == 2) return s.erase(b, n);
            return s.insert(b, s.substr(b, n) + " ");
        }
        case 4: {  // replace a number by an extreme or degenerate one (these often load)
            static const char *numbers[] = {"0", "-1", "1e30", "-1e30", "1e-30", "1e-45", "0.001", "1e6", "3", "-0.5", "1e38", "100000"};
            auto t = tokenize(s);
            for (int tries = 0; tries < 50; ++tries) {
                auto [b, n] = t[pick(t.size())];
                char c = s[b];
                if (!(std::isdigit(static_cast<unsigned char>(c)) || c == '-')) continue;
                return s.replace(b, n, numbers[pick(sizeof(numbers) / sizeof(numbers[0]))]);
            }
            return s;
        }
        default: {  // swap a value (a string, number or literal token) for one of another type
            auto t = tokenize(s);
            for (int tries = 0; tries < 20; ++tries) {
                auto [b, n] = t[pick(t.size())];
                char c = s[b];
                if (std::string("{}[]:,").find(c) != std::string::npos) continue;
                return s.replace(b, n, values[pick(sizeof(values) / sizeof(values[0]))]);
            }
            return s;
        }
    }
}

}  // namespace

TEST(SceneFuzz, MangledScenesOnlyEverThrowMesoError) {
    TempDir dir;
    auto bases = fuzz_base_scenes();
    // Every base scene itself loads and builds.
    for (size_t i = 0; i < bases.size(); ++i) {
        std::string p = dir.write(fmt::format("base{}.json", i), bases[i]);
        try {
            load_scene(p, {})->build();
        } catch (const std::exception &e) {
            FAIL() << "base scene " << i << " does not load: " << e.what();
        }
    }
    std::mt19937 rng(20240611u);
    const int variants = 2000;
    int ok = 0, meso_errors = 0;
    auto t0 = std::chrono::steady_clock::now();
    // The input being tried is kept in a file so that a crash leaves it behind.
    std::string last = dir.path("current.json");
    for (int v = 0; v < variants; ++v) {
        const std::string &base = bases[size_t(v) % bases.size()];
        std::string text = mutate(base, rng, int(rng() % 6));
        {
            std::ofstream f(last, std::ios::binary);
            f << text;
        }
        auto t1 = std::chrono::steady_clock::now();
        try {
            auto scene = load_scene(last, {});
            scene->build();  // an accepted scene must also build
            ok++;
        } catch (const MesoError &e) {
            meso_errors++;
            std::string msg = e.what();
            EXPECT_EQ(msg.find('\n'), std::string::npos) << "multi-line message for variant " << v << ": " << msg;
        } catch (const std::exception &e) {
            ADD_FAILURE() << "variant " << v << " threw a non-MesoError: " << e.what() << "\n--- input ---\n" << text;
        } catch (...) {
            ADD_FAILURE() << "variant " << v << " threw a non-exception\n--- input ---\n" << text;
        }
        double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
        EXPECT_LT(dt, 2.0) << "variant " << v << " took " << dt << " s\n--- input ---\n" << text;
    }
    double total = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("[ fuzz    ] %d variants: %d loaded, %d MesoError, %.2f s\n", variants, ok, meso_errors, total);
    EXPECT_EQ(ok + meso_errors, variants);
    EXPECT_GT(ok, 50);  // the mutations are not all fatal: accepted scenes were exercised too
    EXPECT_GT(meso_errors, 500);
}
