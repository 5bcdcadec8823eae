// Integrator tests on analytic scenes (furnace, directional light, emitters seen directly),
// determinism across thread counts, equal-time budgets, and robustness of rays that start
// on surfaces. Tolerances come from the estimator's own per-pixel spread (5 sigma).
#include <gtest/gtest.h>
#include <fmt/format.h>
#include "geometry/embree_accel.h"
#include "geometry/shape.h"
#include "render_test_util.h"
#include "sampling/rng.h"
#include "sampling/warp.h"

using namespace meso;
using namespace meso::test;

namespace {

/// A sphere filling the view, under a constant environment of radiance 1.
std::string furnace_scene(const std::string &material, const std::string &integrator = R"({"type": "path"})",
                          const std::string &sampler = "independent") {
    return fmt::format(R"({{
      "camera": {{"type": "perspective", "origin": [0, 0, 4], "target": [0, 0, 0], "fov": 20, "width": 24, "height": 24}},
      "integrator": {},
      "sampler": {{"type": "{}", "sample_count": 16}},
      "shapes": [{{"type": "sphere", "radius": 1, "material": {}}}],
      "lights": [{{"type": "constant", "radiance": 1}}]
    }})",
                       integrator, sampler, material);
}

void expect_uniform(const Image &img, double expected, int spp, const char *what) {
    for (int c = 0; c < 3; ++c) {
        PixelStats s = pixel_stats(img, c);
        // The mean over pixels is within 5 standard errors (estimated from the pixel spread,
        // floored for zero-variance estimators at float round-off).
        double tol = 5 * s.stderr_mean + 1e-5;
        EXPECT_NEAR(s.mean, expected, tol) << what << " channel " << c;
        // Every single pixel within 6 sigma of its own estimator spread.
        EXPECT_LE(s.max - expected, 6 * s.sigma_pixel + 1e-4) << what;
        EXPECT_LE(expected - s.min, 6 * s.sigma_pixel + 1e-4) << what;
    }
}

}  // namespace

TEST(Furnace, DiffuseAlbedoOneRendersOne) {
    for (const char *sampler : {"independent", "sobol"}) {
        auto s = load_json_scene("furnace1.json", furnace_scene(R"({"type": "diffuse", "reflectance": 1})", R"({"type": "path"})", sampler));
        RenderResult r = render_scene(*s, 64);
        EXPECT_EQ(r.nan_count, 0);
        expect_uniform(r.image, 1.0, 64, sampler);
    }
}

TEST(Furnace, DiffuseAlbedoHalfRendersHalf) {
    // Convex sphere: one bounce reaches the environment, so L = 0.5 exactly in expectation.
    auto s = load_json_scene("furnace05.json", furnace_scene(R"({"type": "diffuse", "reflectance": 0.5})"));
    RenderResult r = render_scene(*s, 64);
    EXPECT_EQ(r.nan_count, 0);
    expect_uniform(r.image, 0.5, 64, "albedo 0.5");
}

TEST(Furnace, DirectIntegratorAlbedoHalf) {
    auto s = load_json_scene("furnace_direct.json",
                             furnace_scene(R"({"type": "diffuse", "reflectance": 0.5})", R"({"type": "direct"})"));
    RenderResult r = render_scene(*s, 64);
    expect_uniform(r.image, 0.5, 64, "direct");
}

TEST(Furnace, PerfectMirrorRendersOne) {
    // Conductor with Fresnel = 1 (preset "none"), smooth: a deterministic estimator.
    auto s = load_json_scene("furnace_mirror.json", furnace_scene(R"({"type": "conductor", "material": "none"})"));
    RenderResult r = render_scene(*s, 4);
    EXPECT_EQ(r.nan_count, 0);
    PixelStats st = pixel_stats(r.image, 1);
    EXPECT_NEAR(st.min, 1.0, 1e-5);
    EXPECT_NEAR(st.max, 1.0, 1e-5);
}

TEST(Furnace, GlassSphereIsLossless) {
    // A smooth dielectric sphere in a uniform environment: every path ends in the
    // environment with weight 1 (Fresnel choices are sampled, radiance scaling cancels on exit).
    auto s = load_json_scene("furnace_glass.json", furnace_scene(R"({"type": "dielectric"})"));
    RenderResult r = render_scene(*s, 16);
    EXPECT_EQ(r.nan_count, 0);
    PixelStats st = pixel_stats(r.image, 0);
    EXPECT_NEAR(st.mean, 1.0, 5 * st.stderr_mean + 1e-4);
}

TEST(Analytic, DiffusePlaneUnderDirectionalLight) {
    // Radiance = rho / pi * E * cos(theta_light): exact, no noise (delta light, flat plane).
    const float rho = 0.6f, E = 3.f, angle = 40.f;
    Vec3 dir(0, -std::cos(radians(angle)), -std::sin(radians(angle)));
    auto s = load_json_scene("plane_dir.json", fmt::format(R"({{
      "camera": {{"type": "perspective", "origin": [0, 2, 0], "target": [0, 0, 0], "up": [0, 0, -1], "fov": 30, "width": 16, "height": 16}},
      "integrator": {{"type": "path", "max_depth": 2}},
      "shapes": [{{"type": "rectangle", "material": {{"type": "diffuse", "reflectance": {}}},
                   "to_world": {{"scale": 10, "rotate": {{"axis": [1, 0, 0], "angle": -90}}}}}}],
      "lights": [{{"type": "directional", "direction": [{}, {}, {}], "irradiance": {}}}]
    }})",
                                                           rho, dir.x, dir.y, dir.z, E));
    RenderResult r = render_scene(*s, 4);
    const double expected = rho / Pi * E * std::cos(radians(angle));
    PixelStats st = pixel_stats(r.image, 0);
    EXPECT_NEAR(st.min, expected, 1e-4 * expected);
    EXPECT_NEAR(st.max, expected, 1e-4 * expected);
}

TEST(Analytic, AreaLightSeenDirectly) {
    auto s = load_json_scene("emitter.json", R"({
      "camera": {"type": "perspective", "origin": [0, 0, 3], "target": [0, 0, 0], "fov": 10, "width": 16, "height": 16},
      "shapes": [{"type": "rectangle", "emitter": {"type": "area", "radiance": [2, 3, 4]}}]
    })");
    RenderResult r = render_scene(*s, 4);
    for (int c = 0; c < 3; ++c) {
        PixelStats st = pixel_stats(r.image, c);
        EXPECT_NEAR(st.min, 2.0 + c, 1e-5);
        EXPECT_NEAR(st.max, 2.0 + c, 1e-5);
    }
}

TEST(Analytic, DiffuseSphereUnderPointLight) {
    // Pixel at the image centre sees the sphere's nearest point, facing a point light on the
    // camera axis: L = rho/pi * I / d^2 (normal incidence). Thin field of view: every pixel
    // sees nearly the same point, so compare the centre pixel only.
    auto s = load_json_scene("pointlight.json", R"({
      "camera": {"type": "perspective", "origin": [0, 0, 5], "target": [0, 0, 0], "fov": 0.05, "width": 3, "height": 3},
      "integrator": {"type": "direct"},
      "shapes": [{"type": "sphere", "radius": 1, "material": {"type": "diffuse", "reflectance": 0.8}}],
      "lights": [{"type": "point", "position": [0, 0, 3], "intensity": 10}]
    })");
    RenderResult r = render_scene(*s, 4);
    const double expected = 0.8 / Pi * 10.0 / 4.0;
    EXPECT_NEAR(r.image.at(1, 1, 0), expected, 2e-4 * expected);
}

TEST(Render, ImageIndependentOfThreadCount) {
    auto s = load_json_scene("threads.json", furnace_scene(R"({"type": "diffuse", "reflectance": 0.7})"));
    RenderResult a = render_scene(*s, 8, 1), b = render_scene(*s, 8, 2);
    ASSERT_EQ(a.image.data.size(), b.image.data.size());
    EXPECT_EQ(a.image.data, b.image.data);  // bit-exact
    RenderResult c = render_scene(*s, 8, 2, 8);  // another seed differs
    EXPECT_NE(a.image.data, c.image.data);
}

TEST(Render, TimeBudgetRendersWholePasses) {
    auto s = load_json_scene("timed.json", furnace_scene(R"({"type": "diffuse", "reflectance": 0.7})"));
    RenderOptions o;
    o.time_budget_s = 0.5;
    o.progress = false;
    RenderResult r = render(*s, o);
    EXPECT_GE(r.passes, 1);
    EXPECT_GT(r.spp, 0);
    EXPECT_LT(r.wall_s, 1.5);  // stops within about one pass of the budget
    // Timed passes are small (>= 8k samples) and the stop is predicted from the last pass, so an
    // equal-time comparison gets (nearly) all of its budget: here passes take milliseconds.
    EXPECT_GT(r.wall_s, 0.4);
    EXPECT_GT(r.rays, uint64_t(r.spp) * 24 * 24 / 2);
}

TEST(Robustness, RaysStartingOnSurfacesDoNotSelfIntersect) {
    // Rays leaving a surface point must not hit the surface at t ~ 0; rays entering a sphere
    // must hit its far side at the chord length.
    auto s = load_json_scene("robust.json", R"({
      "camera": {"type": "perspective", "origin": [0, 0, 50], "target": [0, 0, 0], "width": 4, "height": 4},
      "shapes": [{"type": "sphere", "center": [10, -3, 7], "radius": 2.5},
                 {"type": "uvsphere", "rings": 64, "segments": 128, "to_world": {"scale": 3, "translate": [-20, 4, 1]}},
                 {"type": "rectangle", "to_world": {"scale": 1000, "translate": [0, 0, -100]}}]
    })");
    PCG32 rng(11);
    int failures = 0, trials = 0;
    for (size_t k = 0; k < s->shapes.size(); ++k) {
        const Shape &shape = *s->shapes[k];
        for (int i = 0; i < 3000; ++i) {
            PositionSample ps = shape.sample_area(rng.next_float(), {rng.next_float(), rng.next_float()});
            // Find the surface through a ray towards it (so p carries the shape's error bound).
            Vec3 out = ps.n;
            Ray probe(ps.p + out * 1.0f, -out);
            SurfaceInteraction si;
            if (!s->intersect(probe, si) || si.shape != &shape) continue;
            Frame f(si.ng);
            Vec3 d = f.to_world(square_to_uniform_hemisphere({rng.next_float(), rng.next_float()}));
            if (d.z < 1e-3f && k == 2) continue;
            ++trials;
            SurfaceInteraction h;
            if (s->intersect(si.spawn_ray(d), h) && h.shape == &shape && h.t < 1e-2f) ++failures;
            // Inward rays into the closed sphere must reach the far side, not the entry point.
            if (k == 0) {
                SurfaceInteraction in;
                Vec3 din = -d;
                bool hit = s->intersect(si.spawn_ray(din), in);
                if (!hit || in.t < 1e-3f) ++failures;
            }
        }
    }
    EXPECT_GT(trials, 6000);
    EXPECT_EQ(failures, 0);
}

TEST(Robustness, ZeroAreaTrianglesAndGrazingCamerasStayFinite) {
    // A plane seen exactly edge-on, a disk squashed to the smallest scale a to_world accepts
    // (1e-8: smaller scales are refused as non-invertible) and an OBJ whose triangle has three
    // collinear vertices (zero area): no NaN anywhere.
    write_temp("degenerate.obj", "v 0 0 0\nv 0.5 0.5 0\nv 1 1 0\nv 0 1 0.2\nf 1 2 3\nf 1 3 4\n");
    auto s = load_json_scene("degenerate.json", R"({
      "camera": {"type": "perspective", "origin": [0, 0, 5], "target": [0, 0, 0], "fov": 60, "width": 32, "height": 32},
      "shapes": [{"type": "rectangle", "to_world": {"rotate": {"axis": [1, 0, 0], "angle": 90}}},
                 {"type": "disk", "segments": 3, "to_world": {"scale": [1, 1e-8, 1]}},
                 {"type": "obj", "filename": "degenerate.obj"},
                 {"type": "sphere", "radius": 0.5, "material": {"type": "conductor", "alpha": 1e-6}}],
      "lights": [{"type": "constant", "radiance": 1}, {"type": "point", "position": [0, 0, 0.5], "intensity": 1}]
    })");
    RenderResult r = render_scene(*s, 16);
    EXPECT_EQ(r.nan_count, 0);
    for (float v : r.image.data) ASSERT_TRUE(std::isfinite(v));
}
