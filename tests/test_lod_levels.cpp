// Which LoD level a path sees (geometry/lod.h, LodGroup): the camera ray is traced against the
// coarsest level first; a path whose camera ray hits an LoD shape gets the footprint's level,
// every other path the coarsest level of every chain. Each path level has its own Embree
// scene (geometry/embree_accel.h).
#include <gtest/gtest.h>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <fmt/format.h>
#include "geometry/shape.h"
#include "image/image.h"
#include "render_test_util.h"

namespace {

std::string replaced(std::string s, const std::string &from, const std::string &to) {
    const size_t at = s.find(from);
    if (at == std::string::npos) ADD_FAILURE() << "no '" << from << "' in the scene";
    else s.replace(at, from.size(), to);
    return s;
}

}  // namespace

// A white diffuse floor fills the view; above the camera, out of its view and facing the floor,
// hang two LoD shapes with chains of different lengths. Their levels differ in colour: level 0
// red, level 1 of the 3-level chain green, each chain's LAST level blue. Every camera ray hits
// the floor (not an LoD shape), so every path must see the coarsest level of each chain: red
// and green then get exactly the same light (the white environment and white floor), only blue
// gets the shapes' reflection. If a path saw level 0 (the original, as it did before) red would
// exceed green by the shapes' share. The image must also equal the same scene with the shapes'
// last levels as plain shapes: these paths draw no extra random numbers, so with the same seed
// they are the same paths and the images agree far below their noise (seen with another seed).
//
// Run twice: with few primitives outside LoD (they go into every level's scene) and with a
// finely tessellated sphere under the floor (then they are one scene instanced into each).
TEST(LodLevels, PathsThatMissLodShapesSeeTheCoarsestLevel) {
    for (const char *extra : {"", R"(, {"type": "uvsphere", "rings": 64, "segments": 64,
                                        "to_world": {"translate": [0, 0, -5]}})"}) {
        SCOPED_TRACE(*extra ? "many primitives without LoD" : "few primitives without LoD");
        const std::string scene = replaced(R"({
          "camera": {"type": "perspective", "origin": [0, 0, 1], "target": [0, 0.4, 0], "up": [0, 1, 0],
                     "fov": 40, "width": 24, "height": 24},
          "integrator": {"type": "path", "max_depth": 3},
          "sampler": {"type": "independent", "sample_count": 16},
          "shapes": [
            {"type": "rectangle", "to_world": {"scale": [10, 10, 1]},
             "material": {"type": "diffuse", "reflectance": 0.8}},
            {"type": "rectangle", "to_world": {"scale": [1.1, 3, 1], "rotate": {"axis": [1, 0, 0], "angle": 180}, "translate": [-1.2, 0.5, 1.5]},
             "displacement": {"map": {"generator": "fbm", "size": 16}, "scale": 0, "tiling": 2},
             @A},
            {"type": "rectangle", "to_world": {"scale": [1.1, 3, 1], "rotate": {"axis": [1, 0, 0], "angle": 180}, "translate": [1.2, 0.5, 1.5]},
             "displacement": {"map": {"generator": "fbm", "size": 16}, "scale": 0, "tiling": 2},
             @B}@EXTRA],
          "lights": [{"type": "constant", "radiance": 1}]
        })", "@EXTRA", extra);
        const std::string red = R"({"type": "diffuse", "reflectance": [0.9, 0, 0]})",
                          green = R"({"type": "diffuse", "reflectance": [0, 0.9, 0]})",
                          blue = R"({"type": "diffuse", "reflectance": [0, 0, 0.9]})";
        const std::string lod_a = fmt::format(R"("lod": {{"factors": [1, 2, 4], "same_model": true, "materials": [{}, {}, {}]}})",
                                              red, green, blue),
                          lod_b = fmt::format(R"("lod": {{"factors": [1, 4], "same_model": true, "materials": [{}, {}]}})", red, blue);
        auto lod = meso::test::load_json_scene("lod_levels_floor.json",
                                               replaced(replaced(scene, "@A", lod_a), "@B", lod_b));
        auto plain = meso::test::load_json_scene(
            "lod_levels_floor_plain.json",
            replaced(replaced(scene, "@A", "\"material\": " + blue), "@B", "\"material\": " + blue));
        const meso::RenderResult l = meso::test::render_scene(*lod, 16, 0, 31), p1 = meso::test::render_scene(*plain, 16, 0, 31),
                                 p2 = meso::test::render_scene(*plain, 16, 0, 32);
        // Per pixel: |R - G| (zero unless a path saw level 0 or 1) and B - R (the last levels' light).
        double worst = 0, sum = 0, sum2 = 0;
        const int n = l.image.width * l.image.height;
        for (int y = 0; y < l.image.height; ++y)
            for (int x = 0; x < l.image.width; ++x) {
                const double r = l.image.at(x, y, 0), g = l.image.at(x, y, 1), b = l.image.at(x, y, 2);
                worst = std::max(worst, std::abs(r - g) / std::max(1e-6, g));
                sum += b - r;
                sum2 += (b - r) * (b - r);
            }
        const double blue_excess = sum / n, blue_stderr = std::sqrt(std::max(0.0, sum2 / n - blue_excess * blue_excess) / n);
        const double noise = meso::compute_metrics(p2.image, p1.image).relmse,
                     cross = meso::compute_metrics(l.image, p1.image).relmse;
        std::printf("mean B - R %.4f +- %.4f; worst |R - G| / G %.2g; relMSE plain vs plain %.5f, LoD vs plain %.5f\n",
                    blue_excess, blue_stderr, worst, noise, cross);
        EXPECT_LT(worst, 1e-5) << "a path that missed every LoD shape saw a level other than the last";
        EXPECT_GT(blue_excess, 6 * blue_stderr) << "the shapes' last levels must show in the floor";
        EXPECT_LT(cross, 1e-6 * noise);
        EXPECT_EQ(l.nan_count, 0);
    }
}

// The footprint rule on a 3-level chain [1, 4, 16] (level colours red, green, blue) seen head-on
// by a 21 x 21 camera: the centre pixel's per-sample footprint is w = 2 d tan(20 deg) / 21 * 128
// * max(1/8, 1/sqrt(spp)) texels (a 64-texel map tiled 64x over 32 units; the camera scales its
// differentials by 1/8 at 256 spp, 1/4 at 16); a level fades in log-linearly over the octave
// below its factor (geometry/lod.h). Footprints up to 8 need a level below the coarsest (the
// camera ray is retraced), 16 and 32 the coarsest (its first hit is kept).
TEST(LodLevels, ThreeLevelChainFollowsTheFootprint) {
    for (const int spp : {256, 16}) {  // the per-sample footprint at either spp (differentials x 1/8, x 1/4)
        const double per_unit_distance =
            2.0 * std::tan(20.0 * 3.14159265358979 / 180.0) / 21.0 * 128.0 * std::max(0.125, 1.0 / std::sqrt(double(spp)));
        struct Case {
            double w, red, green, blue;
        };
        const double r2 = std::sqrt(2.0);
        const Case cases[] = {{1, 1, 0, 0},        {2, 1, 0, 0},  {2 * r2, 0.5, 0.5, 0}, {4, 0, 1, 0},
                              {8 * r2, 0, 0.5, 0.5}, {16, 0, 0, 1}, {32, 0, 0, 1}};
        for (const char *blend : {"blend", "stochastic"})
            for (const Case &c : cases) {
                if (spp < 256 && std::string(blend) != "blend") continue;  // blend weights are exact at any spp
                const std::string json = fmt::format(R"({{
                  "camera": {{"type": "perspective", "origin": [0, 0, {}], "target": [0, 0, 0], "up": [0, 1, 0],
                             "fov": 40, "width": 21, "height": 21}},
                  "integrator": {{"type": "path", "max_depth": 2}},
                  "sampler": {{"type": "independent", "sample_count": {}}},
                  "shapes": [{{"type": "rectangle", "to_world": {{"scale": [16, 16, 1]}},
                              "displacement": {{"map": {{"generator": "fbm", "size": 64}}, "scale": 0, "tiling": 64}},
                              "lod": {{"factors": [1, 4, 16], "blend": "{}", "same_model": true,
                                      "materials": [{{"type": "diffuse", "reflectance": [1, 0, 0]}},
                                                    {{"type": "diffuse", "reflectance": [0, 1, 0]}},
                                                    {{"type": "diffuse", "reflectance": [0, 0, 1]}}]}}}}],
                  "lights": [{{"type": "constant", "radiance": 1}}]
                }})",
                                                     c.w / per_unit_distance, spp, blend);
                const meso::RenderResult r = meso::test::render_scene(*meso::test::load_json_scene("lod_levels_3.json", json), spp);
                double sum[3] = {0, 0, 0};
                for (int y = 9; y <= 11; ++y)
                    for (int x = 9; x <= 11; ++x)
                        for (int k = 0; k < 3; ++k) sum[k] += r.image.at(x, y, k);
                const double total = sum[0] + sum[1] + sum[2];
                std::printf("%d spp, %s, footprint %g texels: weights %.3f %.3f %.3f (expected %g %g %g)\n", spp, blend, c.w,
                            sum[0] / total, sum[1] / total, sum[2] / total, c.red, c.green, c.blue);
                // Stochastic: 9 pixels x 256 samples, a weight of 0.5 has a standard error of 0.011;
                // blend at 16 spp: the two levels' lighting estimates differ by ~0.02 (measured).
                const double tol = 0.05;
                EXPECT_NEAR(sum[0] / total, c.red, tol) << blend << " w " << c.w;
                EXPECT_NEAR(sum[1] / total, c.green, tol) << blend << " w " << c.w;
                EXPECT_NEAR(sum[2] / total, c.blue, tol) << blend << " w " << c.w;
                EXPECT_EQ(r.nan_count, 0);
            }
    }
}

// A level chosen for every pixel renders what a scene holding only that level renders: the
// original (level 0, its box-downsampled coarser levels in the scene too; the camera ray, first
// traced on the coarsest, is retraced in level 0's scene) and the last level (the first hit
// is kept). The displaced plane fills the view, so every camera ray hits it (a ray that missed
// it would give its path the coarsest level). The paths at a fixed level draw no extra random
// numbers, so the same seed gives the same paths: the images agree far below their noise
// (measured with a second seed).
TEST(LodLevels, AFixedLevelRendersAsTheSceneWithOnlyThatLevel) {
    const std::string base = R"({
      "camera": {"type": "perspective", "origin": [0, 1.5, 1], "target": [0, 0, 0], "up": [0, 1, 0],
                 "fov": 40, "width": 48, "height": 48},
      "integrator": {"type": "path", "max_depth": 4},
      "sampler": {"type": "independent", "sample_count": 8},
      "shapes": [{"type": "rectangle", "to_world": {"scale": [2, 2, 1], "rotate": {"axis": [1, 0, 0], "angle": -90}},
                  "material": @MAT,
                  "displacement": {"map": {"generator": "fbm", "size": 64, "amplitude": 0.05}, "scale": 1, "tiling": 8}
                  @LOD}],
      "lights": [{"type": "directional", "direction": [-0.3, -1, -0.2], "irradiance": 3}, {"type": "constant", "radiance": 0.3}]
    })";
    const std::string copper = R"({"type": "conductor", "material": "Cu", "alpha": 0.2})",
                      diffuse = R"({"type": "diffuse", "reflectance": [0.2, 0.6, 0.3]})";
    auto scene = [&](const char *name, const std::string &material, const std::string &lod) {
        return meso::test::load_json_scene(name, replaced(replaced(base, "@MAT", material), "@LOD", lod));
    };
    auto plain = scene("lod_fixed_plain.json", copper, "");
    const meso::Image p1 = meso::test::render_scene(*plain, 8, 0, 41).image, p2 = meso::test::render_scene(*plain, 8, 0, 42).image;
    const double noise = meso::compute_metrics(p2, p1).relmse;
    // Level 0 of box-downsampled levels (a tiny bias: every footprint is below the first factor).
    auto fine = scene("lod_fixed_0.json", copper, R"(, "lod": {"factors": [1, 2, 8], "bias": 1e-6})");
    const double d0 = meso::compute_metrics(meso::test::render_scene(*fine, 8, 0, 41).image, p1).relmse;
    // The last level, here the original map again under a diffuse material (a huge bias), against
    // the plain shape with that material.
    auto coarse = scene("lod_fixed_last.json", copper,
                        fmt::format(R"(, "lod": {{"factors": [1, 2, 8], "same_model": true, "bias": 1e6, "materials": [{}, {}, {}]}})",
                                    copper, R"({"type": "diffuse", "reflectance": 1})", diffuse));
    auto plain_diffuse = scene("lod_fixed_plain_diffuse.json", diffuse, "");
    const meso::Image q1 = meso::test::render_scene(*plain_diffuse, 8, 0, 41).image;
    const double d_last = meso::compute_metrics(meso::test::render_scene(*coarse, 8, 0, 41).image, q1).relmse;
    std::printf("relMSE: plain seed 41 vs 42 %.4g; level 0 vs plain %.3g; last level vs plain %.3g\n", noise, d0, d_last);
    EXPECT_GT(noise, 0.0);
    EXPECT_LT(d0, 1e-6 * noise);
    EXPECT_LT(d_last, 1e-6 * noise);
}

// The coarsest mask (bit 31, what a path that missed every LoD shape carries) sees the last
// level of every chain, whatever its length; bit 0 sees level 0. With few or many (then
// instanced) primitives outside LoD.
TEST(LodLevels, TheCoarsestMaskSeesEveryChainsLastLevel) {
    for (const char *extra : {"", R"(, {"type": "uvsphere", "rings": 64, "segments": 64,
                                        "to_world": {"translate": [0, -9, 0]}})"}) {
        SCOPED_TRACE(*extra ? "many primitives without LoD" : "few primitives without LoD");
        auto s = meso::test::load_json_scene("lod_levels_masks.json", replaced(R"({
          "camera": {"type": "perspective", "width": 8, "height": 8},
          "shapes": [{"type": "rectangle", "to_world": {"translate": [-2, 0, 0]},
                      "displacement": {"map": {"generator": "fbm", "size": 16}, "scale": 0.1},
                      "lod": {"factors": [1, 2, 4, 8]}},
                     {"type": "rectangle", "to_world": {"translate": [2, 0, 0]},
                      "displacement": {"map": {"generator": "fbm", "size": 16}, "scale": 0.1},
                      "lod": {"factors": [1, 2]}},
                     {"type": "rectangle", "to_world": {"translate": [0, 3, 0]}}@EXTRA]
        })", "@EXTRA", extra));
        struct Case {
            float x, y;
            int bit, level;  // level -1: the shape without LoD
        };
        for (const Case c : {Case{-2, 0, 31, 3}, Case{2, 0, 31, 1}, Case{-2, 0, 0, 0}, Case{2, 0, 0, 0}, Case{-2, 0, 2, 2},
                             Case{2, 0, 2, 1}, Case{0, 3, 31, -1}, Case{0, 3, 0, -1}}) {
            meso::Ray r(meso::Vec3(c.x, c.y + 0.1f, 5.f), meso::Vec3(0, 0, -1));
            r.mask = meso::lod_ray_mask(c.bit);
            meso::SurfaceInteraction si;
            ASSERT_TRUE(s->intersect(r, si)) << c.x << " bit " << c.bit;
            EXPECT_EQ(si.shape->lod ? si.shape->lod_level : -1, c.level) << c.x << ", " << c.y << " bit " << c.bit;
            EXPECT_EQ(s->occluded(r), true);
        }
    }
}

// Pixel hints (integrators/path.cpp, trace_lod): the camera ray is traced first at the level
// that the selection at its pixel's centre guesses, and the coarsest-first trace is left out
// where the hit there chooses that level again. On an oblique displaced plane whose footprints
// span the chain [1, 2, 4, 8] (one colour a level), with the same seed as without hints: fewer
// rays, an image that differs in few samples (far below the noise between two seeds), the same
// on 1 thread as on 2, and the same colours (level weights):
//   * levels of one geometry (same_model): the hit, so the footprint, is the same at every level,
//     and the hints change nothing in expectation: the mean per-pixel difference is noise (in
//     standard errors; measured over 60 seeds: 0.3);
//   * box-downsampled levels: the footprint is measured at the traced level's hit, whose height
//     differs (relative to the distance: ~1% here), which shifts the level weights by a little
//     (measured over 60 seeds: 4e-4 of the mean, red up) — bounded here at 0.5%.
TEST(LodLevels, PixelHintsSaveTheCoarsestTraceAndKeepTheImage) {
    const std::string base = R"({
      "camera": {"type": "perspective", "origin": [0, 0.35, 1.2], "target": [0, 0, -0.6], "up": [0, 1, 0],
                 "fov": 50, "width": 48, "height": 32},
      "integrator": {"type": "direct", "lod_hints": @HINTS},
      "sampler": {"type": "independent", "sample_count": 16},
      "shapes": [{"type": "rectangle", "to_world": {"scale": [3, 3, 1], "rotate": {"axis": [1, 0, 0], "angle": -90}},
                  "displacement": {"map": {"generator": "fbm", "size": 64, "amplitude": 0.05}, "scale": 0.2, "tiling": 24},
                  "lod": {"factors": [1, 2, 4, 8]@SAME, "materials": [{"type": "diffuse", "reflectance": [0.9, 0, 0]},
                          {"type": "diffuse", "reflectance": [0, 0.9, 0]}, {"type": "diffuse", "reflectance": [0, 0, 0.9]},
                          {"type": "diffuse", "reflectance": [0.45, 0.45, 0.45]}]}}],
      "lights": [{"type": "directional", "direction": [-0.3, -1, -0.2], "irradiance": 3}, {"type": "constant", "radiance": 0.3}]
    })";
    for (const bool same : {true, false}) {
        SCOPED_TRACE(same ? "same_model" : "box-downsampled levels");
        const std::string s = replaced(base, "@SAME", same ? R"(, "same_model": true)" : "");
        auto with = meso::test::load_json_scene("lod_hints_on.json", replaced(s, "@HINTS", "true"));
        auto without = meso::test::load_json_scene("lod_hints_off.json", replaced(s, "@HINTS", "false"));
        const meso::RenderResult on = meso::test::render_scene(*with, 16, 2, 5), on1 = meso::test::render_scene(*with, 16, 1, 5);
        const meso::RenderResult off = meso::test::render_scene(*without, 16, 2, 5),
                                 off2 = meso::test::render_scene(*without, 16, 2, 6);
        const double noise = meso::compute_metrics(off2.image, off.image).relmse,
                     cross = meso::compute_metrics(on.image, off.image).relmse;
        const int w = on.image.width, h = on.image.height, n = w * h;
        std::printf("%s: rays with hints %llu, coarsest first %llu (%.3fx); relMSE hints vs not %.3g, seed 5 vs 6 %.3g\n",
                    same ? "same_model" : "downsampled", (unsigned long long)on.rays, (unsigned long long)off.rays,
                    double(on.rays) / double(off.rays), cross, noise);
        for (int k = 0; k < 3; ++k) {
            double s1 = 0, s2 = 0, level = 0;  // per-pixel differences (pixels are independent)
            for (int y = 0; y < h; ++y)
                for (int x = 0; x < w; ++x) {
                    const double d = double(on.image.at(x, y, k)) - double(off.image.at(x, y, k));
                    s1 += d;
                    s2 += d * d;
                    level += off.image.at(x, y, k);
                }
            const double mean = s1 / n, se = std::sqrt(std::max(0.0, s2 / n - mean * mean) / n);
            std::printf("  channel %d: mean %.5f, hints - coarsest first %.3g (%.2f standard errors)\n", k, level / n,
                        mean, se > 0 ? mean / se : 0.0);
            EXPECT_GT(level / n, 0.01) << "every level must be seen: channel " << k;
            if (same) EXPECT_LE(std::abs(mean), 4.0 * se + 1e-7) << k;
            else EXPECT_LE(std::abs(mean), 5e-3 * level / n) << k;
        }
        EXPECT_GT(noise, 0.0);
        EXPECT_LT(cross, 0.05 * noise);
        EXPECT_LT(double(on.rays), 0.92 * double(off.rays));  // most camera samples choose a level below the last
        EXPECT_LT(meso::compute_metrics(on1.image, on.image).mse, 1e-30);  // 1 thread as 2
        EXPECT_EQ(on.nan_count, 0);
    }
}
