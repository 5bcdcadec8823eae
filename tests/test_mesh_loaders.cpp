// OBJ and PLY meshes (issue 23): the `obj` and `ply` shapes and their loaders: counts, bounds,
// normals and uvs, fan-triangulated quads and polygons, ASCII and both binary byte orders, bad
// input (errors naming the file and the line or element; invalid faces dropped with one counted
// warning), and a rendered unit quad against its analytic value.
// Fixtures: scripts/assets/make_mesh_fixtures small, written at test time into a scratch dir.
#include <gtest/gtest.h>
#include <cmath>
#include <cstdlib>
#include <functional>
#include <fmt/format.h>
#include "core/error.h"
#include "geometry/shape.h"
#include "render_test_util.h"
#include "scene/mesh_file.h"
#include "scratch_dir.h"

using namespace meso;

namespace {

/// The fixture directory, written once per test process by the repository's script.
const std::string &fixtures() {
    static const std::string dir = [] {
        std::string d = test::scratch_dir("meso_mesh_loaders");
        std::string cmd = fmt::format("/usr/bin/python3 '{}/scripts/assets/make_mesh_fixtures' small '{}'", MESO_SOURCE_DIR, d);
        if (std::system(cmd.c_str()) != 0) ADD_FAILURE() << "failed: " << cmd;
        return d;
    }();
    return dir;
}

std::string fixture(const std::string &name) { return fixtures() + "/" + name; }

std::string error_of(const std::function<void()> &f) {
    try {
        f();
    } catch (const MesoError &e) {
        return e.what();
    }
    ADD_FAILURE() << "expected a MesoError";
    return "";
}

void expect_bounds(const TriangleMesh &m, Vec3 lo, Vec3 hi) {
    Vec3 a = m.positions[0], b = a;
    for (const Vec3 &p : m.positions) a = vmin(a, p), b = vmax(b, p);
    for (int k = 0; k < 3; ++k) {
        EXPECT_NEAR(a[k], lo[k], 1e-6) << "axis " << k;
        EXPECT_NEAR(b[k], hi[k], 1e-6) << "axis " << k;
    }
}

/// Every triangle faces +z (counter-clockwise seen from above) and the mesh covers `area`.
void expect_facing_up(const TriangleMesh &m, float area) {
    for (size_t t = 0; t < m.triangle_count(); ++t) {
        Vec3 a = m.positions[m.indices[3 * t]], b = m.positions[m.indices[3 * t + 1]], c = m.positions[m.indices[3 * t + 2]];
        EXPECT_GT(cross(b - a, c - a).z, 0.f) << "triangle " << t;
    }
    EXPECT_NEAR(m.surface_area(), area, 1e-5);
}

}  // namespace

TEST(MeshLoaders, ObjQuadsWithUvsAndNormals) {
    MeshFile m = load_obj_mesh(fixture("grid.obj"));
    EXPECT_EQ(m.faces, 4u);
    EXPECT_EQ(m.polygons, 4u);
    EXPECT_EQ(m.mesh.triangle_count(), 8u);
    EXPECT_EQ(m.mesh.vertex_count(), 9u);  // one per distinct v/vt/vn triple
    ASSERT_EQ(m.mesh.normals.size(), 9u);
    ASSERT_EQ(m.mesh.uvs.size(), 9u);
    EXPECT_TRUE(m.warnings.empty()) << m.warnings[0];  // mtllib of a missing file is skipped
    expect_bounds(m.mesh, {-1, -1, 0}, {1, 1, 0});
    expect_facing_up(m.mesh, 4.f);
    for (size_t i = 0; i < 9; ++i) {
        EXPECT_FLOAT_EQ(m.mesh.normals[i].z, 1.f);
        EXPECT_NEAR(m.mesh.uvs[i].x, (m.mesh.positions[i].x + 1) / 2, 1e-6);  // vt as written
        EXPECT_NEAR(m.mesh.uvs[i].y, (m.mesh.positions[i].y + 1) / 2, 1e-6);
    }
}

TEST(MeshLoaders, ObjPolygonFanAndPositionsOnly) {
    MeshFile m = load_obj_mesh(fixture("pentagon.obj"));
    EXPECT_EQ(m.mesh.triangle_count(), 3u);
    EXPECT_EQ(m.polygons, 1u);
    EXPECT_TRUE(m.mesh.normals.empty());
    EXPECT_TRUE(m.mesh.uvs.empty());
    expect_facing_up(m.mesh, 2.5f * std::sin(2 * float(M_PI) / 5));  // regular pentagon, circumradius 1
}

TEST(MeshLoaders, PlyAsciiLittleAndBigEndianAgree) {
    MeshFile a = load_ply_mesh(fixture("grid_ascii.ply"));
    for (const char *name : {"grid_ascii.ply", "grid_le.ply", "grid_be.ply"}) {
        SCOPED_TRACE(name);
        MeshFile m = load_ply_mesh(fixture(name));
        EXPECT_EQ(m.mesh.triangle_count(), 8u);
        EXPECT_EQ(m.mesh.vertex_count(), 9u);
        EXPECT_EQ(m.polygons, 4u);
        ASSERT_EQ(m.mesh.normals.size(), 9u);
        ASSERT_EQ(m.mesh.uvs.size(), 9u);  // from (s, t)
        expect_bounds(m.mesh, {-1, -1, 0}, {1, 1, 0});
        expect_facing_up(m.mesh, 4.f);
        EXPECT_EQ(m.mesh.indices, a.mesh.indices);  // the `flags` face property and `edge` element skipped
        for (size_t i = 0; i < 9; ++i) {
            for (int k = 0; k < 3; ++k) EXPECT_FLOAT_EQ(m.mesh.positions[i][k], a.mesh.positions[i][k]);
            EXPECT_FLOAT_EQ(m.mesh.uvs[i].x, (m.mesh.positions[i].x + 1) / 2);
            EXPECT_FLOAT_EQ(m.mesh.normals[i].z, 1.f);
        }
        ASSERT_EQ(m.warnings.size(), 1u);
        EXPECT_EQ(m.warnings[0], fixture(name) + ": vertex colours ignored (meso meshes carry none)");
    }
}

TEST(MeshLoaders, BrokenFilesNameTheFileAndWhere) {
    EXPECT_EQ(error_of([] { load_obj_mesh(fixture("bad_syntax.obj")); }),
              fixture("bad_syntax.obj") + ": Failed parse `f' line(e.g. zero value for face index. line 6.)");
    EXPECT_EQ(error_of([] { load_ply_mesh(fixture("truncated.ply")); }),
              fixture("truncated.ply") + ": element 'face' 2 of 4: the file ends early");
    EXPECT_EQ(error_of([] { load_ply_mesh(fixture("bad_format.ply")); }),
              fixture("bad_format.ply") +
                  ": header line 2: unknown format 'binary_middle_endian' (expected ascii, binary_little_endian or binary_big_endian)");
    EXPECT_EQ(error_of([] { load_ply_mesh(fixture("nothing.ply")); }), fixture("nothing.ply") + ": cannot open the PLY file");
    EXPECT_EQ(error_of([] { load_obj_mesh(fixture("nothing.obj")); }), fixture("nothing.obj") + ": cannot open the OBJ file");
    // Not a PLY, and an ASCII token that is not a number (line and element named).
    EXPECT_EQ(error_of([] { load_ply_mesh(fixture("grid.obj")); }), fixture("grid.obj") + ": not a PLY file (the first line is not 'ply')");
    std::string bad = test::write_temp("mesh_bad_token.ply",
                                       "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                                       "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 two\n");
    EXPECT_EQ(error_of([&] { load_ply_mesh(bad); }), bad + ": line 13, element 'face' 0: expected a number, got 'two'");
    // A scene names the shape too.
    std::string scene = test::write_temp("mesh_missing_scene.json", R"({"camera": {"type": "perspective"},
        "shapes": [{"type": "ply", "filename": ")" + fixture("truncated.ply") + R"("}]})");
    EXPECT_EQ(error_of([&] { load_scene(scene, {}); }),
              scene + ": shapes[0].filename: " + fixture("truncated.ply") + ": element 'face' 2 of 4: the file ends early");
}

TEST(MeshLoaders, InvalidFacesDroppedWithOneWarning) {
    MeshFile o = load_obj_mesh(fixture("bad_index.obj"));
    EXPECT_EQ(o.mesh.triangle_count(), 1u);
    ASSERT_EQ(o.warnings.size(), 1u);
    EXPECT_EQ(o.warnings[0], fixture("bad_index.obj") + ": dropped 1 of 2 triangles: 1 with a vertex index out of range (the file has 4 vertices)");

    MeshFile n = load_ply_mesh(fixture("nan.ply"));
    EXPECT_EQ(n.mesh.triangle_count(), 2u);
    EXPECT_EQ(n.mesh.vertex_count(), 4u);  // the NaN vertex is gone, not only its triangle
    for (const Vec3 &p : n.mesh.positions) EXPECT_TRUE(is_finite(p));
    EXPECT_NO_THROW(n.mesh.validate("nan.ply"));
    ASSERT_EQ(n.warnings.size(), 1u);
    EXPECT_EQ(n.warnings[0], fixture("nan.ply") + ": dropped 1 of 3 triangles: 1 with a NaN or infinite vertex position");

    MeshFile d = load_ply_mesh(fixture("degenerate.ply"));
    EXPECT_EQ(d.mesh.triangle_count(), 2u);
    ASSERT_EQ(d.warnings.size(), 1u);
    EXPECT_EQ(d.warnings[0], fixture("degenerate.ply") +
                                 ": dropped 2 of 4 triangles: 1 with a vertex index out of range (the file has 4 vertices), "
                                 "1 with a repeated vertex index");
    expect_facing_up(d.mesh, 1.f);

    // OBJ: tinyobjloader would read these as 0; a word is an error naming the line, NaN is dropped.
    std::string word = test::write_temp("mesh_word.obj", "v 0 0 0\nv 1 abc 0\nv 0 1 0\nf 1 2 3\n");
    EXPECT_EQ(error_of([&] { load_obj_mesh(word); }), word + ": line 2: expected a number, got 'abc'");
    std::string nan = test::write_temp("mesh_nan.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 nan 0\nf 1 2 3\nf 1 3 4\n");
    MeshFile on = load_obj_mesh(nan);
    EXPECT_EQ(on.mesh.triangle_count(), 1u);
    EXPECT_EQ(on.mesh.vertex_count(), 3u);
    ASSERT_EQ(on.warnings.size(), 1u);
    EXPECT_EQ(on.warnings[0], nan + ": dropped 1 of 2 triangles: 1 with a NaN or infinite vertex position");

    // Nothing left: refused.
    std::string none = test::write_temp("mesh_all_bad.obj", "v 0 0 0\nv 1 0 0\nf 1 2 2\n");
    EXPECT_EQ(error_of([&] { load_obj_mesh(none); }), none + ": no valid triangles (1 faces read)");
}

TEST(MeshLoaders, ShapesInAScene) {
    std::string scene = test::write_temp("mesh_shapes.json", R"({"camera": {"type": "perspective"}, "shapes": [
        {"type": "obj", "filename": ")" + fixture("pentagon.obj") + R"("},
        {"type": "obj", "filename": ")" + fixture("pentagon.obj") + R"(", "face_normals": true},
        {"type": "ply", "filename": ")" + fixture("grid_be.ply") + R"(", "to_world": {"translate": [0, 0, 2]}, "flip_normals": true}]})");
    auto s = load_scene(scene, {});
    ASSERT_EQ(s->shapes.size(), 3u);
    const TriangleMesh *smooth = s->shapes[0]->mesh(), *flat = s->shapes[1]->mesh(), *ply = s->shapes[2]->mesh();
    ASSERT_TRUE(smooth && flat && ply);
    ASSERT_EQ(smooth->normals.size(), 5u);  // computed (Mitsuba: smooth unless face_normals)
    for (const Vec3 &nrm : smooth->normals) EXPECT_NEAR(nrm.z, 1.f, 1e-6);
    EXPECT_TRUE(flat->normals.empty());
    EXPECT_FLOAT_EQ(ply->positions[0].z, 2.f);
    EXPECT_FLOAT_EQ(ply->normals[0].z, -1.f);

    std::string typo = test::write_temp("mesh_typo.json", R"({"camera": {"type": "perspective"}, "shapes": [
        {"type": "ply", "filename": ")" + fixture("grid_le.ply") + R"(", "face_normal": true}]})");
    EXPECT_EQ(error_of([&] { load_scene(typo, {}); }), typo + ": shapes[0].face_normal: unknown parameter 'face_normal' for shape 'ply'");
}

// A unit quad from an OBJ (one 4-vertex face), diffuse with albedo 0.6, under a constant
// environment of radiance 1, covering the left half of the view: a diffuse plane that sees
// only the environment reflects L = albedo, so the left columns are 0.6 and the right ones 1.
TEST(MeshLoaders, RenderedQuadMatchesAlbedo) {
    for (const char *shape : {"obj", "ply"}) {
        SCOPED_TRACE(shape);
        // quad.obj spans [0,1]^2; grid_le.ply spans [-1,1]^2: both scaled to cover x in [-10, 0].
        std::string file = std::string(shape) == "obj" ? fixture("quad.obj") : fixture("grid_le.ply");
        std::string xf = std::string(shape) == "obj" ? R"({"scale": [10, 20, 1], "translate": [-10, -10, 0]})"
                                                     : R"({"scale": [5, 10, 1], "translate": [-5, 0, 0]})";
        auto s = test::load_json_scene(fmt::format("mesh_render_{}.json", shape), R"({
            "camera": {"type": "perspective", "origin": [0, 0, 1], "target": [0, 0, 0], "up": [0, 1, 0],
                       "fov": 40, "width": 16, "height": 8},
            "sampler": {"type": "independent", "sample_count": 64},
            "shapes": [{"type": ")" + std::string(shape) + R"(", "filename": ")" + file + R"(", "to_world": )" + xf + R"(,
                        "material": {"type": "diffuse", "reflectance": 0.6}}],
            "lights": [{"type": "constant", "radiance": 1}]})");
        RenderResult r = test::render_scene(*s, 64);
        double left = 0, right = 0;
        for (int y = 0; y < 8; ++y)
            for (int x = 0; x < 8; ++x) left += r.image.at(x, y, 1) / 64, right += r.image.at(x + 8, y, 1) / 64;
        EXPECT_NEAR(left, 0.6, 0.02);
        EXPECT_NEAR(right, 1.0, 1e-4);
        EXPECT_EQ(r.nan_count, 0);
    }
}

TEST(MeshLoaders, BareMeshFileIsAFramedLitScene) {
    // `meso render model.ply` just works: the framing camera looks at the mesh's bounding-box centre
    // from +z, the mesh fills the middle of the image with the grey material, lit (not black), and
    // the corners see the constant environment (radiance 0.6, directional light not seen directly).
    for (const char *name : {"quad.obj", "grid_le.ply"}) {
        SCOPED_TRACE(name);
        auto s = load_scene(fixture(name), {"camera.width=32", "camera.height=24"});
        s->build();
        RenderResult r = test::render_scene(*s, 16);
        EXPECT_EQ(r.nan_count, 0);
        const float centre = r.image.at(16, 12, 1), corner = r.image.at(0, 0, 1);
        EXPECT_NEAR(corner, 0.6f, 1e-4f);
        EXPECT_GT(centre, 0.1f);                       // the grey mesh, lit
        EXPECT_GT(std::abs(centre - corner), 0.01f);   // and not the background
    }
}
