// Shell-mapped displacement end to end: watertightness of closed displaced surfaces,
// memory independent of tiling, finite results under grazing rays and degenerate input,
// and clear errors for bad displacement blocks.
#include <gtest/gtest.h>
#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <fmt/format.h>
#include "cli_capture.h"
#include "core/error.h"
#include "geometry/embree_accel.h"
#include "geometry/heightmap.h"
#include "geometry/shell_shape.h"
#include "render_test_util.h"
#include "sampling/rng.h"
#include "sampling/warp.h"
#include "scratch_dir.h"

using namespace meso;
using namespace meso::test;

namespace {

/// A map for a uv sphere of 12 rings at tiling_v 1: within the first and last ring of
/// triangles (v < 1/12, v > 11/12) it does not vary along u, so the pole triangles, whose
/// pole corners have different u, agree on their shared faces and the displaced sphere
/// is closed (true of any displaced uv sphere, shell or tessellated).
std::string pole_safe_map(int w, int h) {
    HeightMap m(w, h);
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < w; ++i) {
            double u = double(i) / w, v = double(j) / h;
            double window = (v <= 1.0 / 8 || v >= 7.0 / 8) ? 0.0 : sqr(std::sin(Pi * (v - 1.0 / 8) / 0.75));
            m.at(i, j) = float(0.5 * std::sin(Pi * v) + window * (0.3 * std::sin(2 * Pi * 3 * u) * std::cos(2 * Pi * 2 * v) +
                                                                  0.2 * std::sin(2 * Pi * 7 * (u + v))));
        }
    std::string path = scratch_dir("meso_disp") + fmt::format("/pole_{}x{}.exr", w, h);
    write_height_map(path, m);
    return path;
}

std::string sphere_scene(const std::string &map, const std::string &extra_disp, const std::string &camera,
                         const std::string &lights) {
    return fmt::format(R"({{
      "camera": {},
      "integrator": {{"type": "path", "max_depth": 4}},
      "sampler": {{"type": "independent", "sample_count": 4}},
      "shapes": [{{"type": "uvsphere", "rings": 12, "segments": 24, "material": {{"type": "diffuse", "reflectance": 0.8}},
                  "displacement": {{"map": "{}", "scale": 0.15, "tiling": [3, 1] {}}}}}],
      "lights": {}
    }})",
                       camera, map, extra_disp, lights);
}

const char *kInsideCamera =
    R"({"type": "perspective", "origin": [0, 0, 0], "target": [0, 0, -1], "up": [0, 1, 0], "fov": 100, "width": 48, "height": 48})";

}  // namespace

// Rays from inside a closed displaced sphere in all directions, from random interior
// points, and aimed exactly along prism edges and at shared faces, all hit the surface.
TEST(Displacement, ClosedShellSphereHasNoLeaks) {
    std::string map = pole_safe_map(64, 32);
    auto scene = load_json_scene("disp_closed.json", sphere_scene(map, "", kInsideCamera, "[]"));
    const auto *shell = dynamic_cast<const ShellShape *>(scene->shapes[0].get());
    ASSERT_NE(shell, nullptr);
    // The base triangles are chords: their points lie between cos(15 deg) and 1 from the centre.
    const float r_in = 0.96f + shell->shell_min(), r_out = 1.f + shell->shell_max();
    PCG32 rng(7);
    long misses = 0, outside = 0, tested = 0;
    auto check = [&](Vec3 o, Vec3 d) {
        SurfaceInteraction si;
        ++tested;
        if (!scene->intersect(Ray(o, d), si)) {
            ++misses;
            return;
        }
        float r = length(si.p);
        if (r < r_in - 1e-3f || r > r_out + 1e-3f || !is_finite(si.ns)) ++outside;
    };
    for (int i = 0; i < 100000; ++i) {
        Vec3 d = square_to_uniform_sphere(Vec2(rng.next_float(), rng.next_float()));
        Vec3 o = square_to_uniform_sphere(Vec2(rng.next_float(), rng.next_float())) * (0.6f * rng.next_float());
        check(o, d);
    }
    // Along the base vertices' directions (prism edges shared by up to six prisms), edge
    // midpoints (shared side faces) and triangle centroids, from the centre.
    TriangleMesh base = make_uv_sphere(12, 24);
    for (size_t t = 0; t < base.triangle_count(); ++t) {
        Vec3 p[3];
        for (int k = 0; k < 3; ++k) p[k] = base.positions[base.indices[3 * t + k]];
        for (int k = 0; k < 3; ++k) {
            check(Vec3(), normalize(p[k]));
            check(Vec3(), normalize((p[k] + p[(k + 1) % 3]) * 0.5f));
            check(Vec3(), normalize(p[k] * 0.25f + p[(k + 1) % 3] * 0.75f));
        }
        check(Vec3(), normalize((p[0] + p[1] + p[2]) / 3.f));
    }
    EXPECT_EQ(misses, 0) << "of " << tested << " rays from inside";
    EXPECT_EQ(outside, 0) << "hits outside the shell";
}

// A camera inside the closed displaced sphere with all light outside sees exactly black.
TEST(Displacement, ClosedShellSphereLetsNoLightIn) {
    std::string map = pole_safe_map(64, 32);
    auto scene = load_json_scene(
        "disp_dark.json", sphere_scene(map, "", kInsideCamera,
                                       R"([{"type": "point", "position": [0, 3, 0.5], "intensity": 100},
                                           {"type": "constant", "radiance": 1}])"));
    RenderResult r = render_scene(*scene, 8);
    PixelStats s = pixel_stats(r.image, 1);
    EXPECT_EQ(s.max, 0.0);
    EXPECT_EQ(r.nan_count, 0);
}

// The same map tiled 1x1 and 200x200 costs the same geometry memory.
TEST(Displacement, MemoryIndependentOfTiling) {
    HeightMap m(1024, 1024);
    for (int j = 0; j < 1024; ++j)
        for (int i = 0; i < 1024; ++i) m.at(i, j) = float(std::sin(0.05 * i) * std::cos(0.03 * j));
    std::string path = scratch_dir("meso_disp") + "/big.exr";
    write_height_map(path, m);
    size_t bytes[2];
    int k = 0;
    for (int tiling : {1, 200}) {
        auto scene = load_scene(write_temp(fmt::format("disp_mem{}.json", tiling),
                                           fmt::format(R"({{"camera": {{"type": "perspective", "width": 8, "height": 8}},
              "shapes": [{{"type": "uvsphere", "rings": 32, "segments": 64,
                          "displacement": {{"map": "{}", "scale": 0.001, "tiling": {}}}}}]}})",
                                                       path, tiling)),
                                {});
        bytes[k++] = scene->shapes[0]->memory_bytes();
    }
    EXPECT_EQ(bytes[0], bytes[1]);
    // The heightfield (1024^2 heights + pyramid, about 4 + 8 * 4/3 MiB) dominates.
    EXPECT_GT(bytes[0], size_t(14) << 20);
    EXPECT_LT(bytes[0], size_t(20) << 20);
}

// Grazing views of displaced planes with zero, negative and offset heights: finite.
TEST(Displacement, GrazingAndDegenerateHeightsAreFinite) {
    for (const char *disp : {R"("scale": 0)", R"("scale": -0.05, "offset": -0.2)", R"("scale": 0.05, "offset": 0.3)"}) {
        std::string json = fmt::format(R"({{
          "camera": {{"type": "perspective", "origin": [0, 0.0015, 3], "target": [0, 0, -3], "up": [0, 1, 0],
                     "fov": 30, "width": 64, "height": 32}},
          "integrator": {{"type": "path", "max_depth": 5}},
          "shapes": [{{"type": "rectangle", "to_world": {{"scale": 4, "rotate": {{"axis": [1, 0, 0], "angle": -90}}}},
                      "material": {{"type": "conductor", "material": "Au", "alpha": 0.05}},
                      "displacement": {{"map": {{"generator": "fbm", "size": 64}}, "tiling": 20, {}}}}}],
          "lights": [{{"type": "constant", "radiance": 1}}]
        }})",
                                       disp);
        auto scene = load_json_scene("disp_grazing.json", json);
        RenderResult r = render_scene(*scene, 4);
        EXPECT_EQ(r.nan_count, 0) << disp;
        PixelStats s = pixel_stats(r.image, 0);
        EXPECT_TRUE(std::isfinite(s.mean)) << disp;
        EXPECT_GT(s.mean, 0.0) << disp;
    }
}

// Zero-area base triangles are skipped; rays at them give finite hits or misses.
TEST(Displacement, ZeroAreaBaseTriangles) {
    TriangleMesh m = make_rectangle();
    // Append a degenerate triangle (two equal corners) and a collinear one.
    uint32_t n = uint32_t(m.positions.size());
    m.positions.insert(m.positions.end(), {Vec3(0, 0, 0), Vec3(0, 0, 0), Vec3(0.5f, 0.5f, 0), Vec3(1, 1, 0)});
    m.normals.insert(m.normals.end(), 4, Vec3(0, 0, 1));
    m.uvs.insert(m.uvs.end(), {Vec2(0.5f, 0.5f), Vec2(0.5f, 0.5f), Vec2(0.7f, 0.7f), Vec2(0.9f, 0.9f)});
    m.indices.insert(m.indices.end(), {n, n + 1, n + 2, n, n + 2, n + 3});
    HeightMap hm(8, 8);
    for (int j = 0; j < 8; ++j)
        for (int i = 0; i < 8; ++i) hm.at(i, j) = float((i * 3 + j * 5) % 7) / 7.f;
    Displacement d;
    d.field = std::make_shared<Heightfield>(hm, 0.05f, 0.f);
    d.tiling_u = d.tiling_v = 2;
    ShellShape shell(m, d, "degenerate");
    EXPECT_EQ(shell.prism_count(), 2u);      // only the rectangle's two triangles
    EXPECT_EQ(shell.primitive_count(), 1u);  // merged into one quad
    EmbreeAccel accel;
    accel.add(&shell);
    accel.commit();
    PCG32 rng(3);
    for (int i = 0; i < 20000; ++i) {
        Vec3 target(rng.next_float() * 2 - 1, rng.next_float() * 2 - 1, 0);
        Vec3 d = square_to_uniform_hemisphere(Vec2(rng.next_float(), rng.next_float()));
        // Only rays that come down through the top of the shell inside the footprint must
        // hit (others may pass under the open surface's edge).
        Vec3 top = target + d * (shell.shell_max() / d.z);
        if (std::abs(top.x) > 0.999f || std::abs(top.y) > 0.999f) continue;
        Vec3 o = target + d * 2.f;
        SurfaceInteraction si;
        ASSERT_TRUE(accel.intersect(Ray(o, -d), si)) << i;  // the footprint is covered: no false misses
        EXPECT_TRUE(is_finite(si.p) && is_finite(si.ns) && is_finite(si.dpdu) && is_finite(si.dpdv));
        EXPECT_NEAR(length(si.ns), 1.f, 1e-4f);
    }
}

// Bad displacement blocks name the file, the key and what was expected.
TEST(Displacement, BadInputErrors) {
    auto expect_error = [](const std::string &disp, const std::string &needle, const std::string &extra = "") {
        std::string json = fmt::format(R"({{"camera": {{"type": "perspective", "width": 8, "height": 8}},
            "shapes": [{{"type": "rectangle", {} "displacement": {}}}]}})",
                                       extra, disp);
        try {
            load_scene(write_temp("disp_bad.json", json), {});
            ADD_FAILURE() << "no error for " << disp;
        } catch (const MesoError &e) {
            std::string msg = e.what();
            EXPECT_NE(msg.find(needle), std::string::npos) << msg;
            EXPECT_NE(msg.find("disp_bad.json"), std::string::npos) << msg;
        }
    };
    expect_error(R"({"scale": 1})", "map");
    expect_error(R"({"map": "missing.exr"})", "file not found");
    expect_error(R"({"map": {"generator": "fbm", "size": 16}, "mode": "explicit"})", "\"shell\" or \"tessellate\"");
    expect_error(R"({"map": {"generator": "fbm", "size": 16}, "scheme": "bilinear"})", "only applies");
    expect_error(R"({"map": {"generator": "fbm", "size": 16}, "tiling": 0})", "tiling");
    expect_error(R"({"map": {"generator": "fbm", "size": 16}, "tiling": [1, 2, 3]})", "tiling");
    expect_error(R"({"map": {"generator": "nope"}})", "nope");
    expect_error(R"({"map": {"generator": "fbm", "size": 16}, "scal": 1})", "scal");
    expect_error(R"({"map": 3})", "expected a file name or a generator object");
    expect_error(R"({"map": {"generator": "fbm", "size": 16}, "wrap": "wrap"})", "expected \"repeat\", \"clamp\" or \"mirror\"");
    expect_error(R"({"map": {"generator": "fbm", "size": 16}, "wrap": "clamp", "tiling": 2})",
                 "shapes[0].displacement.wrap: with \"wrap\": \"clamp\" the surface's uv x tiling must stay within");
    expect_error(R"({"map": {"generator": "fbm", "size": 16}})", "cannot be an area emitter",
                 R"("emitter": {"type": "area", "radiance": 1},)");
}

// Shell-mapped and explicitly tessellated displacement describe the same surface: renders
// of a displaced sphere and plane agree within the Monte Carlo noise, measured as the
// relMSE between two independent shell renders (different seeds) of the same scene: with
// equal geometry the cross relMSE has the same expectation (2 sigma^2); 4096 pixels
// estimate it to a few per cent, so 15% is a margin of several standard errors, and
// a 1% offset of the surface or one tessellation level too coarse exceed it.
namespace {

struct CrossCheck {
    double noise_relmse, cross_relmse;
};

/// `scene` has the placeholder @MODE@ inside its displacement block.
/// `level`: the tessellation level, finer than the automatic one (edges <= 1 cell) so
/// the triangles converge to the bilinear patches (at the automatic level the facet
/// normals still add ~10% to the relMSE of a glossy highlight; one level coarser, ~70%).
CrossCheck cross_check(const std::string &name, const std::string &scene, int spp, int level) {
    auto with = [&](const std::string &mode) {
        std::string s = scene;
        s.replace(s.find("@MODE@"), 6, mode);
        return s;
    };
    auto shell = load_json_scene(name + "_shell.json", with(R"("mode": "shell")"));
    auto tess = load_json_scene(name + "_tess.json", with(fmt::format(R"("mode": "tessellate", "level": {})", level)));
    RenderResult a = render_scene(*shell, spp, 0, 11), b = render_scene(*shell, spp, 0, 12), c = render_scene(*tess, spp, 0, 13);
    EXPECT_EQ(a.nan_count + b.nan_count + c.nan_count, 0);
    std::printf("%s: relMSE shell vs shell (noise) %.5f, shell vs tessellated %.5f\n", name.c_str(),
                compute_metrics(b.image, a.image).relmse, compute_metrics(c.image, a.image).relmse);
    return {compute_metrics(b.image, a.image).relmse, compute_metrics(c.image, a.image).relmse};
}

}  // namespace

TEST(Displacement, ShellMatchesTessellationOnSphere) {
    std::string map = pole_safe_map(32, 16);
    for (const char *integrator : {R"({"type": "direct"})", R"({"type": "path", "max_depth": 5})"}) {
        std::string scene = fmt::format(R"({{
          "camera": {{"type": "perspective", "origin": [0.3, 2.6, 1.6], "target": [0, 0, 0], "up": [0, 0, 1],
                     "fov": 38, "width": 64, "height": 64}},
          "integrator": {},
          "shapes": [{{"type": "uvsphere", "rings": 12, "segments": 24,
                      "material": {{"type": "plastic", "diffuse_reflectance": [0.6, 0.4, 0.3], "alpha": 0.3}},
                      "displacement": {{"map": "{}", "scale": 0.2, "tiling": [3, 1], @MODE@}}}},
                     {{"type": "rectangle", "material": {{"type": "diffuse", "reflectance": 0.5}},
                      "to_world": {{"scale": 3, "translate": [0, 0, -1.3]}}}}],
          "lights": [{{"type": "point", "position": [2, 3, 4], "intensity": 40}}, {{"type": "constant", "radiance": 0.3}}]
        }})",
                                        integrator, map);
        CrossCheck r = cross_check("disp_x_sphere", scene, 16, 5);
        EXPECT_LT(r.cross_relmse, 1.15 * r.noise_relmse) << integrator << ": noise " << r.noise_relmse;
    }
}

TEST(Displacement, ShellMatchesTessellationOnPlane) {
    for (const char *integrator : {R"({"type": "direct"})", R"({"type": "path", "max_depth": 5})"}) {
        std::string scene = fmt::format(R"({{
          "camera": {{"type": "perspective", "origin": [0, 1.2, 1.6], "target": [0, 0, 0], "up": [0, 1, 0],
                     "fov": 45, "width": 64, "height": 64}},
          "integrator": {},
          "shapes": [{{"type": "rectangle", "to_world": {{"rotate": {{"axis": [1, 0, 0], "angle": -90}}}},
                      "material": {{"type": "conductor", "material": "Cu", "alpha": 0.25}},
                      "displacement": {{"map": {{"generator": "fbm", "size": 32, "octaves": 2, "frequency": 2,
                                                 "amplitude": 0.05}}, "scale": 2, "tiling": 2, @MODE@}}}}],
          "lights": [{{"type": "directional", "direction": [-0.4, -1, -0.3], "irradiance": 3}},
                     {{"type": "constant", "radiance": 0.3}}]
        }})",
                                        integrator);
        CrossCheck r = cross_check("disp_x_plane", scene, 16, 8);
        EXPECT_LT(r.cross_relmse, 1.15 * r.noise_relmse) << integrator << ": noise " << r.noise_relmse;
    }
}

// From the command line: --max-triangles refuses a too-fine tessellation with a message
// that suggests the shell mode, and the render record reports the geometry memory.
TEST(Displacement, CommandLineLimitAndRecord) {
    std::string scene = write_temp("disp_cli.json", R"({
      "camera": {"type": "perspective", "origin": [0, 2, 2], "target": [0, 0, 0], "up": [0, 1, 0], "width": 16, "height": 16},
      "shapes": [{"type": "rectangle", "to_world": {"rotate": {"axis": [1, 0, 0], "angle": -90}},
                  "displacement": {"map": {"generator": "fbm", "size": 64}, "scale": 0.5, "tiling": 4, "mode": "tessellate"}}],
      "lights": [{"type": "constant", "radiance": 1}]
    })");
    CliResult r = run_cli_captured({"render", scene, "--max-triangles", "1000", "--plan"});
    EXPECT_NE(r.code, 0);
    EXPECT_NE(r.err.find("--max-triangles"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("shell"), std::string::npos) << r.err;

    std::string out = scratch_dir("meso_disp") + "/cli.exr";
    r = run_cli_captured({"render", scene, "-o", out, "--spp", "1", "-q", "-D", "shapes[0].displacement.mode=\"shell\""});
    ASSERT_EQ(r.code, 0) << r.err;
    std::ifstream f(scratch_dir("meso_disp") + "/cli.json");
    nlohmann::json rec = nlohmann::json::parse(f);
    ASSERT_TRUE(rec.contains("geometry_bytes"));
    EXPECT_GT(rec["geometry_bytes"].get<size_t>(), size_t(64 * 64 * 4));  // at least the heights
    EXPECT_NE(rec["shapes"][0]["shape"].get<std::string>().find("shell map"), std::string::npos);
}

// Issue 23, displacement edge modes: a map with a mean-slope ramp does not tile, so under
// "repeat" its last cell climbs back down to the first vertex (a cliff wall along the far
// edges). In every mode the shell-mapped and tessellated surfaces are the same bilinear
// surface, so their renders agree within the noise, with the camera looking at the far edges
// (u = 1 and v = 1) where the modes differ.
TEST(Displacement, ShellMatchesTessellationAtTheEdgesInEveryWrapMode) {
    for (const char *wrap : {"repeat", "clamp", "mirror"}) {
        std::string scene = fmt::format(R"({{
          "camera": {{"type": "perspective", "origin": [2.2, 1.4, 2.2], "target": [0.6, 0, 0.6], "up": [0, 1, 0],
                     "fov": 40, "width": 64, "height": 64}},
          "integrator": {{"type": "path", "max_depth": 4}},
          "shapes": [{{"type": "rectangle", "to_world": {{"rotate": {{"axis": [1, 0, 0], "angle": -90}}}},
                      "material": {{"type": "plastic", "diffuse_reflectance": [0.6, 0.5, 0.4], "alpha": 0.2}},
                      "displacement": {{"map": {{"generator": "gaussian", "size": 32, "correlation": 0.1, "sxx": 0.03,
                                                 "syy": 0.03, "mx": 0.5, "my": 0.3}},
                                       "scale": 1, "wrap": "{}", @MODE@}}}},
                     {{"type": "rectangle", "material": {{"type": "diffuse", "reflectance": 0.3}},
                      "to_world": {{"rotate": {{"axis": [1, 0, 0], "angle": -90}}, "scale": 4, "translate": [0, -0.3, 0]}}}}],
          "lights": [{{"type": "directional", "direction": [-0.5, -1, -0.2], "irradiance": 3}},
                     {{"type": "constant", "radiance": 0.3}}]
        }})",
                                        wrap);
        CrossCheck r = cross_check(std::string("disp_x_edge_") + wrap, scene, 16, 8);
        EXPECT_LT(r.cross_relmse, 1.15 * r.noise_relmse) << wrap << ": noise " << r.noise_relmse;
    }
}

// The periodic extension behind "wrap" (geometry/heightmap.h): mirror reflects with period 2W,
// clamp repeats the edge vertex up to W + W/2 and vertex 0 beyond (the negative side).
TEST(Displacement, PeriodicExtensionOfClampAndMirror) {
    HeightMap m(4, 3);
    for (int j = 0; j < 3; ++j)
        for (int i = 0; i < 4; ++i) m.at(i, j) = float(10 * j + i);
    const HeightMap r = periodic_extension(m, WrapMode::Repeat);
    EXPECT_EQ(r.width, 4);
    EXPECT_EQ(r.h, m.h);
    const HeightMap mi = periodic_extension(m, WrapMode::Mirror), cl = periodic_extension(m, WrapMode::Clamp);
    ASSERT_EQ(mi.width, 8);
    ASSERT_EQ(mi.height, 6);
    const int mirror_i[8] = {0, 1, 2, 3, 3, 2, 1, 0}, mirror_j[6] = {0, 1, 2, 2, 1, 0};
    const int clamp_i[8] = {0, 1, 2, 3, 3, 3, 0, 0}, clamp_j[6] = {0, 1, 2, 2, 0, 0};  // W + W/2 = 6, H + H/2 = 4
    for (int j = 0; j < 6; ++j)
        for (int i = 0; i < 8; ++i) {
            EXPECT_EQ(mi.at(i, j), m.at(mirror_i[i], mirror_j[j])) << i << "," << j;
            EXPECT_EQ(cl.at(i, j), m.at(clamp_i[i], clamp_j[j])) << i << "," << j;
        }
}

// Heights along the far edge of a ramp map (uv -> height through the displacement): repeat
// falls back to vertex 0 in the last cell, clamp stays at vertex W-1, mirror is symmetric about
// u = 1; inside the map all three agree.
TEST(Displacement, WrapModesAtTheFarEdge) {
    auto disp = [](const char *wrap) {
        const std::string json = fmt::format(R"({{"camera": {{"type": "perspective", "width": 8, "height": 8}},
            "shapes": [{{"type": "rectangle", "displacement": {{"map": {{"generator": "gaussian", "size": 16,
              "correlation": 0.1, "sxx": 0, "syy": 0, "mx": 1, "my": 0}}, "wrap": "{}"}}}}]}})",
                                             wrap);
        auto scene = load_scene(write_temp(std::string("disp_wrap_") + wrap + ".json", json), {});
        auto shell = std::dynamic_pointer_cast<ShellShape>(scene->shapes.at(0));
        EXPECT_TRUE(shell);
        return shell->displacement();
    };
    const Displacement rep = disp("repeat"), cla = disp("clamp"), mir = disp("mirror");
    EXPECT_EQ(cla.field->width(), 32);
    const float last = rep.height_at(Vec2(15.f / 16, 0.5f)), first = rep.height_at(Vec2(0.f, 0.5f));
    EXPECT_GT(last - first, 0.8f);  // the ramp: mx = 1 over the tile
    for (float u : {0.1f, 0.5f, 15.f / 16})
        for (const Displacement *d : {&cla, &mir}) EXPECT_NEAR(d->height_at(Vec2(u, 0.5f)), rep.height_at(Vec2(u, 0.5f)), 1e-5f) << u;
    EXPECT_NEAR(rep.height_at(Vec2(1.f, 0.5f)), first, 1e-5f);    // repeat: back to vertex 0 (the cliff)
    EXPECT_NEAR(cla.height_at(Vec2(1.f, 0.5f)), last, 1e-5f);     // clamp: vertex W-1 extends
    EXPECT_NEAR(cla.height_at(Vec2(1.4f, 0.5f)), last, 1e-5f);
    EXPECT_NEAR(cla.height_at(Vec2(-0.3f, 0.5f)), first, 1e-5f);
    const float axis = 1.f - 1.f / 32;  // vertex W reads W-1: the mirror line is half a cell before u = 1
    for (float d : {0.02f, 0.3f, 0.7f}) EXPECT_NEAR(mir.height_at(Vec2(axis + d, 0.5f)), mir.height_at(Vec2(axis - d, 0.5f)), 1e-5f) << d;
}

// `meso info SCENE --json -` reports the surface's own scales (issue 21: the bench takes the
// prefilter's tile size from here, not from the displacement's scale): a rectangle scaled by 3
// has uvs 6 world units long; tiled 4 times with a 32-vertex map, a tile is 1.5 and a cell
// 1.5 / 32, whatever the height scale.
TEST(Displacement, InfoReportsTileAndCellSizeInWorldUnits) {
    const std::string path = write_temp("disp_info.json", R"({"camera": {"type": "perspective", "width": 8, "height": 8},
        "shapes": [{"type": "rectangle", "to_world": {"scale": 3},
                    "displacement": {"map": {"generator": "fbm", "size": 32}, "scale": 0.2, "tiling": 4, "wrap": "mirror"}}]})");
    meso::test::CliResult r = meso::test::run_cli_captured({"info", path, "--json", "-"});
    ASSERT_EQ(r.code, 0) << r.err;
    const nlohmann::json j = nlohmann::json::parse(r.out);
    const nlohmann::json &s = j["shapes"][0];
    EXPECT_NEAR(s["uv_world_length"][0].get<double>(), 6.0, 1e-5);
    const nlohmann::json &d = s["displacement"];
    EXPECT_EQ(d["map"][0], 32);  // the map as given, not its mirrored extension
    EXPECT_NEAR(d["tiling"][0].get<double>(), 4.0, 1e-6);
    EXPECT_NEAR(d["tile_world"][1].get<double>(), 1.5, 1e-5);
    EXPECT_NEAR(d["cell_world"][0].get<double>(), 1.5 / 32, 1e-6);
    EXPECT_NEAR(d["scale"].get<double>(), 0.2, 1e-7);
    EXPECT_EQ(d["wrap"], "mirror");
}
