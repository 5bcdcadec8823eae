// glTF loading: meshes (node transforms, mirroring, strips, normalised texcoords,
// skipped modes), the `gltf` shape plugin, glTF files as scenes, and located errors.
// Fixtures: scenes/tests/quad.gltf, quad.glb, mixed.gltf (scenes/tests/make_gltf_fixtures.py).
#include <gtest/gtest.h>
#include <filesystem>
#include <fstream>
#include <random>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "geometry/shape.h"
#include "lights/light.h"
#include "scene/gltf.h"
#include "core/registry.h"
#include "render/scene.h"
#include "material_test_util.h"
#include "render_test_util.h"
#include "sampling/rng.h"

using namespace meso;
using json = nlohmann::json;
namespace fs = std::filesystem;

namespace {

std::string fixture(const std::string &name) { return std::string(MESO_SOURCE_DIR) + "/scenes/tests/" + name; }

class GltfTemp {
public:
    GltfTemp() {
        m_path = fs::temp_directory_path() / fmt::format("meso_gltf_{}", std::random_device{}());
        fs::create_directories(m_path);
    }
    ~GltfTemp() {
        std::error_code ec;
        fs::remove_all(m_path, ec);
    }
    std::string write(const std::string &name, const std::string &text) const {
        std::ofstream f(m_path / name, std::ios::binary);
        f << text;
        return (m_path / name).string();
    }

private:
    fs::path m_path;
};

std::string error_of(const std::function<void()> &f) {
    try {
        f();
    } catch (const MesoError &e) {
        return e.what();
    } catch (const std::exception &e) {
        ADD_FAILURE() << "not a MesoError: " << e.what();
        return e.what();
    }
    ADD_FAILURE() << "expected an error";
    return "";
}

Vec3 face_normal(const TriangleMesh &m, size_t tri) {
    Vec3 a = m.positions[m.indices[3 * tri]], b = m.positions[m.indices[3 * tri + 1]], c = m.positions[m.indices[3 * tri + 2]];
    return normalize(cross(b - a, c - a));
}

/// A .gltf with one triangle whose accessors are given (to test malformed files).
std::string triangle_gltf(const std::string &accessors, const std::string &primitive_extra = "") {
    // 3 float3 positions (36 bytes) + 3 uint16 indices (6 bytes) = 42 bytes, base64.
    return R"({"asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
  "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1)" + primitive_extra + R"(}]}],
  "buffers": [{"byteLength": 42, "uri": "data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAAAAABAAIA"}],
  "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 6}],
  "accessors": )" + accessors + "}";
}

const char *kGoodAccessors = R"([{"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": 3, "min": [0,0,0], "max": [1,1,0]},
  {"bufferView": 1, "componentType": 5123, "type": "SCALAR", "count": 3}])";

}  // namespace

TEST(Gltf, QuadMesh) {
    auto meshes = load_gltf_meshes(fixture("quad.gltf"));
    ASSERT_EQ(meshes.size(), 1u);
    const TriangleMesh &m = meshes[0];
    EXPECT_EQ(m.vertex_count(), 4u);
    EXPECT_EQ(m.triangle_count(), 2u);
    ASSERT_EQ(m.normals.size(), 4u);
    ASSERT_EQ(m.uvs.size(), 4u);
    EXPECT_TRUE(m.tangents.empty());
    for (size_t i = 0; i < 4; ++i) {
        EXPECT_FLOAT_EQ(m.positions[i].z, -1.f);  // node translation applied
        EXPECT_FLOAT_EQ(m.normals[i].z, 1.f);
    }
    EXPECT_FLOAT_EQ(m.positions[2].x, 1.f);
    EXPECT_FLOAT_EQ(m.uvs[1].x, 1.f);
    EXPECT_FLOAT_EQ(m.uvs[1].y, 1.f);
    EXPECT_NEAR(m.surface_area(), 4.f, 1e-5f);
    for (size_t t = 0; t < 2; ++t) EXPECT_NEAR(face_normal(m, t).z, 1.f, 1e-6f);  // counter-clockwise
    m.validate("quad");
}

TEST(Gltf, BinaryGlbMatchesGltf) {
    auto a = load_gltf_meshes(fixture("quad.gltf"));
    auto b = load_gltf_meshes(fixture("quad.glb"));
    ASSERT_EQ(a.size(), b.size());
    ASSERT_EQ(a[0].positions.size(), b[0].positions.size());
    for (size_t i = 0; i < a[0].positions.size(); ++i) {
        EXPECT_EQ(a[0].positions[i].x, b[0].positions[i].x);
        EXPECT_EQ(a[0].positions[i].z, b[0].positions[i].z);
    }
    EXPECT_EQ(a[0].indices, b[0].indices);
}

TEST(Gltf, StripsMirroringInstancingAndSkippedModes) {
    auto prims = load_gltf_primitives(fixture("mixed.gltf"));
    // Two node instances x (strip + triangles); the POINTS primitive is skipped.
    ASSERT_EQ(prims->size(), 4u);
    const auto &strip = (*prims)[0], &tris = (*prims)[1], &strip2 = (*prims)[2];
    EXPECT_EQ(strip.name, "mesh 'mixed' primitive 0");
    EXPECT_EQ(tris.name, "mesh 'mixed' primitive 2");
    EXPECT_EQ(strip.material, 0);
    EXPECT_EQ(tris.material, 1);
    EXPECT_EQ(strip.mesh_index, 0);
    EXPECT_EQ(strip.mesh.triangle_count(), 2u);
    EXPECT_EQ(tris.mesh.triangle_count(), 1u);
    // Mirrored in x: positions flip, and the winding is swapped so the faces still face +z.
    EXPECT_FLOAT_EQ(strip.mesh.positions[1].x, -1.f);
    for (size_t t = 0; t < 2; ++t) EXPECT_NEAR(face_normal(strip.mesh, t).z, 1.f, 1e-6f);
    EXPECT_NEAR(face_normal(tris.mesh, 0).z, 1.f, 1e-6f);
    // Normalised uint8 texcoords.
    ASSERT_EQ(tris.mesh.uvs.size(), 3u);
    EXPECT_FLOAT_EQ(tris.mesh.uvs[1].x, 1.f);
    EXPECT_FLOAT_EQ(tris.mesh.uvs[2].y, 1.f);
    // The child node is translated by +3 in y, under its mirrored parent.
    EXPECT_FLOAT_EQ(strip2.mesh.positions[1].x, -1.f);
    EXPECT_FLOAT_EQ(strip2.mesh.positions[1].y, 3.f);
}

TEST(Gltf, ShapePluginInAJsonScene) {
    GltfTemp tmp;
    std::string scene = tmp.write("s.json", R"({"camera": {"type": "perspective"}, "shapes": [
        {"type": "gltf", "filename": ")" + fixture("mixed.gltf") + R"("},
        {"type": "gltf", "filename": ")" + fixture("quad.glb") + R"(", "to_world": {"translate": [0, 1, 0]}},
        {"type": "gltf", "filename": ")" + fixture("mixed.gltf") + R"(", "primitive": 1},
        {"type": "gltf", "filename": ")" + fixture("mixed.gltf") + R"(", "mesh": 0}]})");
    auto s = load_scene(scene, {});
    ASSERT_EQ(s->shapes.size(), 4u);
    ASSERT_TRUE(s->shapes[0]->mesh());
    EXPECT_EQ(s->shapes[0]->mesh()->triangle_count(), 6u);  // every primitive merged
    EXPECT_EQ(s->shapes[0]->mesh()->uvs.size(), 0u);        // not every primitive has uvs
    EXPECT_FLOAT_EQ(s->shapes[1]->mesh()->positions[0].y, 0.f);  // -1 + 1
    EXPECT_EQ(s->shapes[2]->mesh()->triangle_count(), 1u);
    EXPECT_EQ(s->shapes[3]->mesh()->triangle_count(), 6u);

    std::string bad = tmp.write("b.json", R"({"camera": {"type": "perspective"}, "shapes": [
        {"type": "gltf", "filename": ")" + fixture("mixed.gltf") + R"(", "primitive": 4}]})");
    EXPECT_EQ(error_of([&] { load_scene(bad, {}); }),
              bad + ": shapes[0].primitive: primitive 4 out of range (" + fixture("mixed.gltf") + " has 4 triangle primitives)");
    std::string bad2 = tmp.write("b2.json", R"({"camera": {"type": "perspective"}, "shapes": [
        {"type": "gltf", "filename": ")" + fixture("mixed.gltf") + R"(", "mesh": 3}]})");
    EXPECT_EQ(error_of([&] { load_scene(bad2, {}); }),
              bad2 + ": shapes[0].mesh: no triangle primitive of mesh 3 in " + fixture("mixed.gltf"));
}

TEST(Gltf, FileAsSceneTranslation) {
    json j = gltf_scene_to_json(fixture("quad.gltf"));
    const json &cam = j["camera"];
    EXPECT_EQ(cam["type"], "perspective");
    EXPECT_EQ(cam["origin"], json::parse("[0.0, 0.0, 5.0]"));
    EXPECT_EQ(cam["target"], json::parse("[0.0, 0.0, 4.0]"));
    EXPECT_EQ(cam["fov_axis"], "y");
    EXPECT_NEAR(cam["fov"].get<double>(), 0.6 * 180.0 / 3.14159265358979, 1e-4);
    EXPECT_EQ(cam["width"], 720);  // aspectRatio 1.5
    EXPECT_EQ(cam["height"], 480);
    ASSERT_EQ(j["shapes"].size(), 1u);
    EXPECT_EQ(j["shapes"][0]["type"], "gltf");
    EXPECT_EQ(j["shapes"][0]["filename"], "quad.gltf");
    EXPECT_EQ(j["shapes"][0]["material"], "red_plastic");
    const json &mat = j["materials"]["red_plastic"];
    EXPECT_EQ(mat["type"], "gltf_pbr");
    EXPECT_NEAR(mat["base_color"][0].get<double>(), 0.8, 1e-6);
    ASSERT_EQ(j["lights"].size(), 1u);
    EXPECT_EQ(j["lights"][0]["type"], "point");
    EXPECT_EQ(j["lights"][0]["position"], json::parse("[0.0, 3.0, 0.0]"));
    EXPECT_EQ(j["lights"][0]["intensity"], json::parse("[20.0, 20.0, 20.0]"));

    // No camera, no punctual lights, an emissive metal.
    json m = gltf_scene_to_json(fixture("mixed.gltf"));
    EXPECT_EQ(m["camera"]["target"], json::parse("[-0.5, 2.0, 0.5]"));  // centre of the bounds
    ASSERT_EQ(m["shapes"].size(), 4u);
    EXPECT_EQ(m["shapes"][0]["material"], "grey");
    EXPECT_EQ(m["materials"]["grey"]["type"], "gltf_pbr");
    EXPECT_EQ(m["materials"]["lamp"]["type"], "gltf_pbr");
    EXPECT_GT(m["materials"]["lamp"]["metallic"].get<double>(), 0.5);
    EXPECT_NEAR(m["materials"]["lamp"]["roughness"].get<double>(), 0.2, 1e-6);
    EXPECT_FALSE(m["shapes"][0].contains("emitter"));
    EXPECT_EQ(m["shapes"][1]["emitter"]["type"], "area");
    EXPECT_EQ(m["shapes"][1]["emitter"]["radiance"], json::parse("[4.0, 2.0, 1.0]"));  // x emissiveStrength 4
    EXPECT_TRUE(m["lights"].empty());  // emitters light it: no constant environment added
}

TEST(Gltf, FileAsScene) {
    auto s = load_scene(fixture("quad.gltf"), {});
    ASSERT_TRUE(s->camera);
    EXPECT_EQ(s->camera->width(), 720);
    EXPECT_EQ(s->camera->height(), 480);
    ASSERT_EQ(s->shapes.size(), 1u);
    EXPECT_TRUE(s->shapes[0]->material);
    ASSERT_EQ(s->lights.size(), 1u);
    EXPECT_TRUE(s->lights[0]->is_delta());
    EXPECT_EQ(s->spp, 16);

    auto g = load_scene(fixture("quad.glb"), {"sampler.sample_count=3", "camera.width=100"});
    EXPECT_EQ(g->spp, 3);
    EXPECT_EQ(g->camera->width(), 100);

    auto m = load_scene(fixture("mixed.gltf"), {});
    ASSERT_EQ(m->shapes.size(), 4u);
    ASSERT_EQ(m->lights.size(), 2u);  // the emissive primitive, instanced twice
    EXPECT_EQ(m->shapes[1]->emitter, m->lights[0]);
    EXPECT_TRUE(m->infinite_lights.empty());
    EXPECT_EQ(m->shapes[0]->material, m->shapes[2]->material);  // one meso material per glTF material
    m->build();
}

TEST(Gltf, NoLightsAddsConstantEnvironment) {
    GltfTemp tmp;
    std::string p = tmp.write("t.gltf", triangle_gltf(kGoodAccessors));
    json j = gltf_scene_to_json(p);
    ASSERT_EQ(j["lights"].size(), 1u);
    EXPECT_EQ(j["lights"][0], json::parse(R"({"type": "constant", "radiance": 1.0})"));
    auto s = load_scene(p, {});
    ASSERT_EQ(s->infinite_lights.size(), 1u);
}

TEST(Gltf, Errors) {
    GltfTemp tmp;
    std::string missing = tmp.write("x.txt", "") + ".gltf";
    EXPECT_EQ(error_of([&] { load_gltf_meshes(missing); }), missing + ": cannot open the glTF file (file not found)");
    EXPECT_EQ(error_of([&] { load_scene(missing, {}); }), missing + ": cannot open the scene file (file not found)");

    std::string garbage = tmp.write("garbage.gltf", "this is { not glTF");
    std::string msg = error_of([&] { load_gltf_meshes(garbage); });
    EXPECT_EQ(msg.substr(0, garbage.size() + 20), garbage + ": cannot load glTF: ") << msg;

    std::string badglb = tmp.write("bad.glb", std::string("glTF\x02\0\0\0\x10\0\0\0garbage!", 20));
    msg = error_of([&] { load_gltf_meshes(badglb); });
    EXPECT_EQ(msg.substr(0, badglb.size() + 20), badglb + ": cannot load glTF: ") << msg;

    // An accessor reaching past its buffer view.
    std::string overrun = tmp.write("overrun.gltf", triangle_gltf(
        R"([{"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": 4, "min": [0,0,0], "max": [1,1,0]},
            {"bufferView": 1, "componentType": 5123, "type": "SCALAR", "count": 3}])"));
    EXPECT_EQ(error_of([&] { load_gltf_meshes(overrun); }),
              overrun + ": mesh 0 primitive 0: POSITION: accessor data lies outside its buffer (48 bytes needed at offset 0, buffer has 42)");

    // A corrupt count is refused before anything is allocated.
    std::string huge = tmp.write("huge.gltf", triangle_gltf(
        R"([{"componentType": 5126, "type": "VEC3", "count": 2000000000, "min": [0,0,0], "max": [1,1,0]},
            {"bufferView": 1, "componentType": 5123, "type": "SCALAR", "count": 3}])"));
    EXPECT_EQ(error_of([&] { load_gltf_meshes(huge); }),
              huge + ": mesh 0 primitive 0: POSITION: accessor without data has 2000000000 elements");
    std::string huge2 = tmp.write("huge2.gltf", triangle_gltf(
        R"([{"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": 2000000000, "min": [0,0,0], "max": [1,1,0]},
            {"bufferView": 1, "componentType": 5123, "type": "SCALAR", "count": 3}])"));
    msg = error_of([&] { load_gltf_meshes(huge2); });
    EXPECT_NE(msg.find("accessor data lies outside its buffer"), std::string::npos) << msg;

    // An index beyond the vertices.
    std::string badindex = tmp.write("badindex.gltf", triangle_gltf(
        R"([{"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": 2, "min": [0,0,0], "max": [1,1,0]},
            {"bufferView": 1, "componentType": 5123, "type": "SCALAR", "count": 3}])"));
    EXPECT_EQ(error_of([&] { load_gltf_meshes(badindex); }),
              badindex + ": mesh 0 primitive 0: indices: index 2 = 2 is out of range (2 vertices)");

    // Integer positions are not allowed unless normalised.
    std::string intpos = tmp.write("intpos.gltf", triangle_gltf(
        R"([{"bufferView": 0, "componentType": 5125, "type": "VEC3", "count": 3, "min": [0,0,0], "max": [1,1,0]},
            {"bufferView": 1, "componentType": 5123, "type": "SCALAR", "count": 3}])"));
    EXPECT_EQ(error_of([&] { load_gltf_meshes(intpos); }),
              intpos + ": mesh 0 primitive 0: POSITION: integer components must be normalized");

    // Errors from the shape plugin are located in the scene file.
    std::string scene = tmp.write("s.json", R"({"camera": {"type": "perspective"}, "shapes": [{"type": "gltf", "filename": "overrun.gltf"}]})");
    EXPECT_EQ(error_of([&] { load_scene(scene, {}); }),
              scene + ": shapes[0].filename: " + overrun +
                  ": mesh 0 primitive 0: POSITION: accessor data lies outside its buffer (48 bytes needed at offset 0, buffer has 42)");
}

TEST(Gltf, RefusesWhatItCannotRead) {
    GltfTemp tmp;
    // A required extension meso does not implement: refused, naming it (glTF 2.0, 3.12).
    std::string draco = tmp.write("draco.gltf", [] {
        json j = json::parse(triangle_gltf(kGoodAccessors));
        j["extensionsUsed"] = {"KHR_draco_mesh_compression"};
        j["extensionsRequired"] = {"KHR_draco_mesh_compression"};
        return j.dump();
    }());
    EXPECT_EQ(error_of([&] { load_gltf_meshes(draco); }),
              draco + ": extensionsRequired: the file requires the extension 'KHR_draco_mesh_compression', which meso "
                      "does not implement (meso implements KHR_lights_punctual and KHR_materials_emissive_strength)");
    // Required extensions that meso implements are fine.
    std::string lights = tmp.write("lights.gltf", [] {
        json j = json::parse(triangle_gltf(kGoodAccessors));
        j["extensionsUsed"] = {"KHR_lights_punctual"};
        j["extensionsRequired"] = {"KHR_lights_punctual"};
        return j.dump();
    }());
    EXPECT_EQ(load_gltf_meshes(lights).size(), 1u);
    // Only glTF 2.x.
    std::string v1 = tmp.write("v1.gltf", [] {
        json j = json::parse(triangle_gltf(kGoodAccessors));
        j["asset"]["version"] = "1.0";
        return j.dump();
    }());
    EXPECT_EQ(error_of([&] { load_gltf_meshes(v1); }), v1 + ": asset.version: expected a glTF 2.x file, got version \"1.0\"");
    // Morph targets are not applied: a warning names the mesh.
    std::string morph = tmp.write("morph.gltf", triangle_gltf(kGoodAccessors, R"(, "targets": [{"POSITION": 0}])"));
    testing::internal::CaptureStderr();
    auto meshes = load_gltf_meshes(morph);
    std::string err = testing::internal::GetCapturedStderr();
    EXPECT_EQ(meshes.size(), 1u);
    EXPECT_EQ(err, morph + ": warning: mesh 0 primitive 0: its 1 morph targets are ignored (meso renders the base shape)\n");
}

TEST(Gltf, ModeAndTransformEdgeCases) {
    GltfTemp tmp;
    // A zero scale makes the node transform singular: the primitive is skipped.
    std::string zero = tmp.write("zero.gltf", [] {
        json j = json::parse(triangle_gltf(kGoodAccessors));
        j["nodes"][0]["scale"] = {0, 1, 1};
        return j.dump();
    }());
    EXPECT_TRUE(load_gltf_meshes(zero).empty());
    // A node cycle is an error, not a stack overflow.
    std::string cycle = tmp.write("cycle.gltf", [] {
        json j = json::parse(triangle_gltf(kGoodAccessors));
        j["nodes"] = json::parse(R"([{"mesh": 0, "children": [1]}, {"children": [0]}])");
        return j.dump();
    }());
    std::string msg = error_of([&] { load_gltf_meshes(cycle); });
    EXPECT_NE(msg.find(cycle + ": "), std::string::npos) << msg;
    // Fan mode and no indices.
    std::string fan = tmp.write("fan.gltf", [] {
        json j = json::parse(triangle_gltf(kGoodAccessors, R"(, "mode": 6)"));
        j["meshes"][0]["primitives"][0].erase("indices");
        return j.dump();
    }());
    auto meshes = load_gltf_meshes(fan);
    ASSERT_EQ(meshes.size(), 1u);
    EXPECT_EQ(meshes[0].indices, (std::vector<uint32_t>{1, 2, 0}));
}

// Mangled glTF files (value swaps, truncations, byte edits of the JSON, including the
// accessor/buffer-view numbers) must load (as meshes and as a scene) or throw MesoError:
// never crash or read out of bounds.
TEST(GltfFuzz, MangledFilesOnlyEverThrowMesoError) {
    GltfTemp tmp;
    std::vector<std::string> bases;
    for (const char *name : {"quad.gltf", "mixed.gltf"}) {
        std::ifstream f(fixture(name));
        bases.emplace_back(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
    }
    static const char *values[] = {"0", "1", "2", "3", "-1", "7", "100", "65536", "4294967295", "1e30", "0.5", "5120",
                                   "5121", "5123", "5125", "5126", "\"VEC2\"", "\"VEC4\"", "\"SCALAR\"", "\"MAT4\"",
                                   "null", "[]", "{}", "true", "\"x\""};
    std::mt19937 rng(7u);
    int ok = 0, errors = 0;
    for (int v = 0; v < 1000; ++v) {
        std::string s = bases[size_t(v) % bases.size()];
        int kind = int(rng() % 3);
        if (kind == 0) {
            s = s.substr(0, rng() % s.size());
        } else if (kind == 1) {
            for (int k = 0; k < 3; ++k) s[rng() % s.size()] = "0123456789[]{},:\"-"[rng() % 18];
        } else {
            // Replace a number or quoted word outside the base64 buffer by another value.
            for (int tries = 0; tries < 50; ++tries) {
                size_t i = rng() % s.size();
                if (!(std::isdigit(static_cast<unsigned char>(s[i])) || s[i] == '"')) continue;
                if (s.rfind("base64", i) != std::string::npos && s.find('"', s.rfind("base64", i)) > i) continue;
                size_t e = i + 1;
                if (s[i] == '"') e = s.find('"', i + 1) + 1;
                else while (e < s.size() && (std::isdigit(static_cast<unsigned char>(s[e])) || s[e] == '.' || s[e] == 'e')) ++e;
                s.replace(i, e - i, values[rng() % (sizeof(values) / sizeof(values[0]))]);
                break;
            }
        }
        std::string p = tmp.write("current.gltf", s);
        try {
            auto prims = load_gltf_primitives(p);
            for (const auto &g : *prims) g.mesh.validate(g.name);
            load_scene(p, {})->build();  // the file as a scene: camera, lights, materials
            ok++;
        } catch (const MesoError &) {
            errors++;
        } catch (const std::exception &e) {
            ADD_FAILURE() << "variant " << v << " threw a non-MesoError: " << e.what() << "\n--- input ---\n" << s;
        }
    }
    std::printf("[ fuzz    ] 1000 glTF variants: %d loaded, %d MesoError\n", ok, errors);
    EXPECT_EQ(ok + errors, 1000);
}

namespace {

/// Directional albedo at normal incidence of gltf_pbr with a constant base colour (metallic 0,
/// roughness 1), by sampling: what a quad of that colour reflects under a constant environment
/// of radiance 1 towards a camera on its normal.
Spectrum diffuse_pbr_albedo(const Spectrum &c) {
    auto m = test::make_material(fmt::format(R"({{"type":"gltf_pbr","base_color":[{},{},{}],"metallic":0,"roughness":1}})",
                                       c[0], c[1], c[2]));
    PCG32 rng(11);
    Spectrum sum(0.f);
    const int n = 200000;
    for (int i = 0; i < n; ++i) {
        BSDFSample bs;
        if (m->sample(ShadingContext{}, Vec3(0, 0, 1), rng.next_float(), {rng.next_float(), rng.next_float()}, bs))
            sum += bs.weight;
    }
    return sum / float(n);
}

}  // namespace

TEST(Gltf, TexturedMaterialTranslation) {
    json j = gltf_scene_to_json(fixture("textured.gltf"));
    const json &m = j["materials"]["checker"];
    EXPECT_EQ(m["type"], "gltf_pbr");
    EXPECT_EQ(m["base_color"]["type"], "bitmap");
    EXPECT_EQ(m["base_color"]["filename"], "checker.png");
    EXPECT_EQ(m["base_color"]["raw"], false);  // sRGB
    EXPECT_EQ(m["base_color"]["filter_type"], "nearest");
    EXPECT_EQ(m["base_color"]["wrap_mode"], "clamp");
    EXPECT_EQ(m["metallic"]["channel"], "b");
    EXPECT_EQ(m["roughness"]["channel"], "g");
    EXPECT_EQ(m["roughness"]["raw"], true);
}

TEST(Gltf, BaseColourTextureRendersInTheRightQuadrants) {
    // The checker quad (scenes/tests/make_gltf_fixtures.py) fills the view under the constant
    // environment the loader adds; its material is diffuse-like (metallic 0 and roughness 1
    // from the metallicRoughness texture's B and G channels). Each quadrant's centre must show
    // that texel's linear colour times the material's albedo at normal incidence (the camera
    // is 10 units away on the normal, fov 11.5 degrees: view directions within 6 degrees).
    const Spectrum texel[2][2] = {{Spectrum(1, 0, 0), Spectrum(0, 1, 0)},
                                  {Spectrum(0, 0, 1), Spectrum(0.50289f)}};  // sRGB 188 decoded
    for (const char *name : {"textured.gltf", "textured.glb"}) {
        SCOPED_TRACE(name);
        auto s = load_scene(fixture(name), {"camera.width=32", "camera.height=32"});
        s->build();
        RenderResult r = test::render_scene(*s, 16);
        EXPECT_EQ(r.nan_count, 0);
        for (int qy = 0; qy < 2; ++qy)
            for (int qx = 0; qx < 2; ++qx) {
                const Spectrum want = diffuse_pbr_albedo(texel[qy][qx]);
                for (int ch = 0; ch < 3; ++ch) {
                    double sum = 0;
                    for (int y = 0; y < 6; ++y)
                        for (int x = 0; x < 6; ++x) sum += r.image.at(16 * qx + 5 + x, 16 * qy + 5 + y, ch);
                    // Tolerance: well below the texel contrast and the sRGB/linear difference
                    // (0.74 vs 0.50), above the Monte Carlo noise and the view-angle spread
                    // of the Fresnel term (< 0.005).
                    EXPECT_NEAR(sum / 36.0, want[ch], 0.02) << "quadrant " << qx << "," << qy << " channel " << ch;
                }
            }
    }
}

TEST(Gltf, TextureFactorsEmbeddedImagesAndUnsupportedFeatures) {
    // The .glb's images live in bufferViews: written to the temporary directory and read back.
    json g = gltf_scene_to_json(fixture("textured.glb"));
    const std::string embedded = g["materials"]["checker"]["base_color"]["filename"];
    EXPECT_TRUE(fs::exists(embedded)) << embedded;
    EXPECT_EQ(fs::path(embedded).extension(), ".png");

    // A tinted base colour multiplies the texture; metallic/roughness factors scale the channels;
    // KHR_texture_transform becomes tiling, offset and rotation (also on the roughness, which
    // reads the metallic texture's green channel); a normal texture wraps the material in
    // normalmap with its scale; BLEND is MASK at 0.5 (checker.png has no alpha channel: the
    // alpha is the factor); unsupported features warn naming the material.
    std::ifstream in(fixture("textured.gltf"));
    json doc = json::parse(in);
    json &pbr = doc["materials"][0]["pbrMetallicRoughness"];
    pbr["baseColorFactor"] = json::array({0.5, 1.0, 1.0, 1.0});
    pbr["metallicFactor"] = 0.25;
    pbr["roughnessFactor"] = 0.5;
    pbr["baseColorTexture"]["extensions"] = {{"KHR_texture_transform", {{"scale", {2, 3}}, {"offset", {0.5, 0}}, {"rotation", 0.1}}},
                                             {"EXT_unknown", json::object()}};
    doc["materials"][0]["normalTexture"] = {{"index", 0}, {"scale", 0.5},
                                            {"extensions", {{"KHR_texture_transform", {{"scale", {2, 2}}, {"rotation", 0.3}}}}}};
    doc["materials"][0]["alphaMode"] = "BLEND";
    doc["materials"][0]["pbrMetallicRoughness"]["metallicRoughnessTexture"]["extensions"] = {
        {"KHR_texture_transform", {{"rotation", -0.5}}}};
    GltfTemp tmp;
    std::ifstream png(fixture("checker.png"), std::ios::binary), mr(fixture("mr.png"), std::ios::binary);
    tmp.write("checker.png", std::string(std::istreambuf_iterator<char>(png), {}));
    tmp.write("mr.png", std::string(std::istreambuf_iterator<char>(mr), {}));
    std::string p = tmp.write("t.gltf", doc.dump());
    testing::internal::CaptureStderr();
    json j = gltf_scene_to_json(p);
    const std::string err = testing::internal::GetCapturedStderr();
    const json &m = j["materials"]["checker"];
    ASSERT_EQ(m["type"], "normalmap");
    EXPECT_EQ(m["normals"], "checker.png");
    EXPECT_EQ(m["scale"], 0.5);
    EXPECT_EQ(m["tiling"], json::parse("[2.0, 2.0]"));  // the normal map's transform: its scale only
    const json &b = m["bsdf"];
    EXPECT_EQ(b["type"], "gltf_pbr");
    EXPECT_EQ(b["base_color"]["type"], "combine");
    EXPECT_EQ(b["base_color"]["op"], "product");
    EXPECT_NEAR(b["metallic"]["scale"].get<double>(), 0.25, 1e-6);
    EXPECT_NEAR(b["roughness"]["scale"].get<double>(), 0.5, 1e-6);
    EXPECT_EQ(b["base_color"]["terms"][0]["texture"]["tiling"], json::parse("[2.0, 3.0]"));  // KHR_texture_transform
    EXPECT_EQ(b["base_color"]["terms"][0]["texture"]["offset"], json::parse("[0.5, 0.0]"));
    EXPECT_NEAR(b["base_color"]["terms"][0]["texture"]["rotation"].get<double>(), 0.1, 1e-12);
    EXPECT_NEAR(b["metallic"]["rotation"].get<double>(), -0.5, 1e-12);
    EXPECT_NEAR(b["roughness"]["rotation"].get<double>(), -0.5, 1e-12);
    EXPECT_EQ(b["roughness"]["channel"], "g");
    EXPECT_EQ(j["shapes"][0]["alpha"], 1.0);
    EXPECT_EQ(j["shapes"][0]["alpha_cutoff"], 0.5);
    EXPECT_EQ(err.find("baseColorTexture: KHR_texture_transform"), std::string::npos) << err;
    EXPECT_EQ(err.find("normalTexture scale"), std::string::npos) << err;
    EXPECT_NE(err.find("material 'checker': normalTexture: KHR_texture_transform offset and rotation are not applied"),
              std::string::npos) << err;
    EXPECT_NE(err.find("material 'checker': baseColorTexture: extension EXT_unknown is not supported"), std::string::npos) << err;
    EXPECT_NE(err.find("material 'checker': alphaMode BLEND is rendered as MASK with alphaCutoff 0.5"), std::string::npos) << err;
    auto s = load_scene(p, {"camera.width=8", "camera.height=8"});
    s->build();
    EXPECT_EQ(test::render_scene(*s, 2).nan_count, 0);
}

namespace {

/// textured.gltf (its images copied into `tmp`) lit by a directional light of irradiance 3
/// coming from `degrees` off the quad's normal (+z) towards +y: a node rotated by −degrees
/// about x, so that the light's −z becomes (0, −sin, −cos).
json lit_textured_doc(const GltfTemp &tmp, double degrees) {
    std::ifstream in(fixture("textured.gltf"));
    json doc = json::parse(in);
    doc["extensionsUsed"] = {"KHR_lights_punctual"};
    doc["extensions"] = {{"KHR_lights_punctual", {{"lights", {{{"type", "directional"}, {"intensity", 3}}}}}}};
    doc["scenes"][0]["nodes"].push_back(2);
    const double half = -0.5 * degrees * Pi / 180.0;
    doc["nodes"].push_back({{"name", "sun"}, {"rotation", {std::sin(half), 0, 0, std::cos(half)}},
                            {"extensions", {{"KHR_lights_punctual", {{"light", 0}}}}}});
    for (const char *f : {"checker.png", "mr.png", "normal_up.png", "alpha_half.png"}) {
        std::ifstream png(fixture(f), std::ios::binary);
        tmp.write(f, std::string(std::istreambuf_iterator<char>(png), {}));
    }
    return doc;
}

/// `doc` with normal_up.png as its normal texture (scale omitted when 1).
json with_normal_up(json doc, double scale) {
    doc["images"].push_back({{"uri", "normal_up.png"}});
    doc["textures"].push_back({{"source", int(doc["images"].size()) - 1}, {"sampler", 0}});
    doc["materials"][0]["normalTexture"] = {{"index", int(doc["textures"].size()) - 1}};
    if (scale != 1.0) doc["materials"][0]["normalTexture"]["scale"] = scale;
    return doc;
}

/// Sum over the pixels and channels of a 16 x 16 direct-lighting render of `doc` (4 spp).
double render_sum(const GltfTemp &tmp, const json &doc, const std::string &name) {
    auto s = load_scene(tmp.write(name, doc.dump()), {"camera.width=16", "camera.height=16", "integrator.type=direct"});
    s->build();
    RenderResult r = test::render_scene(*s, 4);
    double sum = 0;
    for (int y = 0; y < 16; ++y)
        for (int x = 0; x < 16; ++x) sum += r.image.at(x, y, 0) + r.image.at(x, y, 1) + r.image.at(x, y, 2);
    return sum;
}

/// cos between the light from `degrees` off +z towards +y and normal_up.png's normal scaled
/// by `scale` as glTF says: normalize((2c − 1) · (scale, scale, 1)), c = (128, 220, 255) / 255.
double scaled_normal_up_cosine(double scale, double degrees) {
    const double a = degrees * Pi / 180.0;
    const double x = scale * (2 * 128 / 255.0 - 1), y = scale * (2 * 220 / 255.0 - 1), z = 1.0;
    return (y * std::sin(a) + z * std::cos(a)) / std::sqrt(x * x + y * y + z * z);
}

}  // namespace

TEST(Gltf, NormalTextureTiltsTowardsTheBitangent) {
    // glTF tangent space: red = +u (the tangent), green = the bitangent cross(N, T)·w, which on
    // the fixture quad (u along +x, v down the image = along −y) is +y. normal_up.png tilts the
    // normal to n' = (0.003, 0.587, 0.810). A directional light from (0, 1, 1)/√2 then gives
    // cos = n'·l = 0.987 instead of the flat 0.707 (a flipped green channel would give 0.157).
    // Ratio of the mapped to the flat render of the diffuse-like quad: ≈ 0.987/0.707 = 1.40,
    // up to the view-dependent Fresnel weights (a few %).
    GltfTemp tmp;
    const json doc = lit_textured_doc(tmp, 45.0);
    const double ratio = render_sum(tmp, with_normal_up(doc, 1.0), "mapped.gltf") / render_sum(tmp, doc, "flat.gltf");
    EXPECT_NEAR(ratio, 0.9873 / 0.7071, 0.1);
}

TEST(Gltf, NormalTextureScale) {
    // normalTexture.scale s: n' = normalize((2c − 1) · (s, s, 1)). The light comes from 70°
    // off the normal towards +y. s = 0 is no perturbation at all: the flat render to rounding
    // (one directional light and nothing else to hit: no noise). s = 1 and 2 must render as the
    // same material around the constant analytic n' (normalmap "normal"), to rounding; and n'·l
    // grows from 0.829 (s = 1, n' 36° off the normal) to 0.968 (s = 2, 55°): the s = 2 render
    // is brighter by that ratio, 1.168, up to the Fresnel weights of the diffuse lobe
    // (measured 1.153).
    GltfTemp tmp;
    const json doc = lit_textured_doc(tmp, 70.0);
    const double flat = render_sum(tmp, doc, "flat.gltf");
    ASSERT_GT(flat, 0.0);
    EXPECT_NEAR(render_sum(tmp, with_normal_up(doc, 0.0), "s0.gltf") / flat, 1.0, 1e-5);
    double mapped[3] = {0, 0, 0};
    for (int s : {1, 2}) {
        const std::string name = fmt::format("s{}.gltf", s);
        mapped[s] = render_sum(tmp, with_normal_up(doc, s), name);
        json scene = gltf_scene_to_json(tmp.write(name, with_normal_up(doc, s).dump()));
        json &m = scene["materials"]["checker"];
        ASSERT_EQ(m["type"], "normalmap");
        if (s == 1) EXPECT_FALSE(m.contains("scale"));
        else EXPECT_EQ(m["scale"], 2.0);
        m.erase("normals");
        m.erase("scale");
        m["normal"] = {s * (2 * 128 / 255.0 - 1), s * (2 * 220 / 255.0 - 1), 1.0};
        EXPECT_NEAR(mapped[s] / render_sum(tmp, scene, fmt::format("s{}.json", s)), 1.0, 1e-4) << "scale " << s;
    }
    const double want = scaled_normal_up_cosine(2, 70.0) / scaled_normal_up_cosine(1, 70.0);
    EXPECT_NEAR(mapped[2] / mapped[1], want, 0.03 * want);
}

namespace {

/// Mean of channel `ch` over the x0..x0+w-1, y0..y0+h-1 pixels of `img`.
double block_mean(const Image &img, int x0, int y0, int w, int h, int ch) {
    double sum = 0;
    for (int y = y0; y < y0 + h; ++y)
        for (int x = x0; x < x0 + w; ++x) sum += img.at(x, y, ch);
    return sum / (w * h);
}

}  // namespace

TEST(Gltf, EmissiveTextureGivesATexturedEmitter) {
    // emission = emissiveFactor × emissiveStrength × emissiveTexture (sRGB): factor (1, 0.5, 1),
    // strength 2, the checker texture. The quad emits that and nothing lights it (no punctual
    // lights, so no default environment either): each quadrant's centre shows
    // 2 · (1, 0.5, 1) · its texel's linear colour, exactly (nearest filter).
    GltfTemp tmp;
    json doc = lit_textured_doc(tmp, 45.0);
    doc.erase("extensions");
    doc["extensionsUsed"] = {"KHR_materials_emissive_strength"};
    doc["nodes"].erase(2);
    doc["scenes"][0]["nodes"] = {0, 1};
    json &m = doc["materials"][0];
    m["emissiveFactor"] = {1.0, 0.5, 1.0};
    m["emissiveTexture"] = {{"index", 0}};
    m["extensions"] = {{"KHR_materials_emissive_strength", {{"emissiveStrength", 2.0}}}};
    const std::string p = tmp.write("emissive.gltf", doc.dump());
    json j = gltf_scene_to_json(p);
    EXPECT_EQ(j["shapes"][0]["emitter"]["radiance"], "checker_emission");
    const json &e = j["textures"]["checker_emission"];
    EXPECT_EQ(e["type"], "combine");
    EXPECT_EQ(e["terms"][0]["texture"]["filename"], "checker.png");
    EXPECT_EQ(e["terms"][0]["texture"]["raw"], false);
    EXPECT_EQ(e["terms"][1]["texture"], json::parse("[2.0, 1.0, 2.0]"));
    EXPECT_EQ(j["lights"], json::array());

    auto s = load_scene(p, {"camera.width=32", "camera.height=32"});
    s->build();
    RenderResult r = test::render_scene(*s, 4);
    const Spectrum texel[2][2] = {{Spectrum(1, 0, 0), Spectrum(0, 1, 0)}, {Spectrum(0, 0, 1), Spectrum(0.50289f)}};
    const Spectrum factor(2.f, 1.f, 2.f);
    for (int qy = 0; qy < 2; ++qy)
        for (int qx = 0; qx < 2; ++qx)
            for (int ch = 0; ch < 3; ++ch)
                EXPECT_NEAR(block_mean(r.image, 16 * qx + 5, 16 * qy + 5, 6, 6, ch), (texel[qy][qx] * factor)[ch], 1e-4)
                    << "quadrant " << qx << "," << qy << " channel " << ch;
}

TEST(Gltf, AlphaMaskCutsTheSurfaceOut) {
    // alphaMode MASK: alpha = baseColorTexture.a × baseColorFactor[3] = (1, 0) × 0.8 for the
    // two texels of alpha_half.png (nearest filter), cutoff 0.3: the left half of the quad is
    // there, the right half is not. No lights: the default constant environment of radiance 1
    // fills the right half of the view exactly; the left half shows the quad lit by it: the
    // albedo of gltf_pbr with the texel's base colour, sRGB 188 = 0.503 (the factor's alpha
    // does not tint it), as in BaseColourTextureRendersInTheRightQuadrants.
    GltfTemp tmp;
    json doc = lit_textured_doc(tmp, 45.0);
    doc.erase("extensions");
    doc.erase("extensionsUsed");
    doc["nodes"].erase(2);
    doc["scenes"][0]["nodes"] = {0, 1};
    doc["images"].push_back({{"uri", "alpha_half.png"}});
    doc["textures"].push_back({{"source", 2}, {"sampler", 0}});
    json &m = doc["materials"][0];
    m["pbrMetallicRoughness"]["baseColorTexture"] = {{"index", 2}};
    m["pbrMetallicRoughness"]["baseColorFactor"] = {1.0, 1.0, 1.0, 0.8};
    m["alphaMode"] = "MASK";
    m["alphaCutoff"] = 0.3;
    const std::string p = tmp.write("mask.gltf", doc.dump());
    testing::internal::CaptureStderr();
    json j = gltf_scene_to_json(p);
    testing::internal::GetCapturedStderr();
    EXPECT_EQ(j["shapes"][0]["alpha"], "checker_alpha");
    EXPECT_NEAR(j["shapes"][0]["alpha_cutoff"].get<double>(), 0.3, 1e-12);
    const json &a = j["textures"]["checker_alpha"];
    EXPECT_EQ(a["filename"], "alpha_half.png");
    EXPECT_EQ(a["channel"], "a");
    EXPECT_EQ(a["raw"], true);
    EXPECT_NEAR(a["scale"].get<double>(), 0.8, 1e-12);

    testing::internal::CaptureStderr();
    auto s = load_scene(p, {"camera.width=32", "camera.height=32"});
    testing::internal::GetCapturedStderr();
    s->build();
    RenderResult r = test::render_scene(*s, 16);
    const Spectrum want = diffuse_pbr_albedo(Spectrum(0.50289f));
    for (int ch = 0; ch < 3; ++ch) {
        EXPECT_NEAR(block_mean(r.image, 2, 2, 12, 28, ch), want[ch], 0.02) << "channel " << ch;  // the quad
        EXPECT_NEAR(block_mean(r.image, 18, 2, 12, 28, ch), 1.0, 1e-5) << "channel " << ch;      // through it
    }

    // BLEND is MASK at 0.5, with a warning naming the material.
    m["alphaMode"] = "BLEND";
    testing::internal::CaptureStderr();
    json jb = gltf_scene_to_json(tmp.write("blend.gltf", doc.dump()));
    const std::string err = testing::internal::GetCapturedStderr();
    EXPECT_EQ(jb["shapes"][0]["alpha_cutoff"], 0.5);
    EXPECT_NE(err.find("material 'checker': alphaMode BLEND is rendered as MASK with alphaCutoff 0.5"), std::string::npos)
        << err;
}
