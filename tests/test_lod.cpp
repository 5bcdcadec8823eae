// LoD chains: level selection from footprints, stochastic choice, validation.
#include <gtest/gtest.h>
#include <algorithm>
#include <cmath>
#include <limits>
#include "core/error.h"
#include "geometry/shape.h"
#include "geometry/lod.h"
#include "geometry/interaction.h"
#include "core/ray.h"
#include "render_test_util.h"
#include <fmt/format.h>
#include <cstdio>

using namespace meso;

TEST(LodChain, SelectsExactLevelsAtTheirFactors) {
    LodChain c({1.f, 8.f, 64.f});
    for (int i = 0; i < 3; ++i) {
        LodSelection s = c.select(c.factor(i));
        EXPECT_EQ(s.lo, i);
        EXPECT_EQ(s.hi, i);
        EXPECT_EQ(s.t, 0.f);
    }
    EXPECT_EQ(c.select(0.25f).lo, 0);
    EXPECT_EQ(c.select(0.f).hi, 0);
    EXPECT_EQ(c.select(1e6f).lo, 2);
    EXPECT_EQ(c.select(1e6f).hi, 2);
}

TEST(LodChain, LogLinearBetweenLevels) {
    // Factors at most 2 apart: log-linear over the whole interval.
    LodChain c({1.f, 2.f, 4.f, 8.f});
    LodSelection s = c.select(std::sqrt(2.f));
    EXPECT_EQ(s.lo, 0);
    EXPECT_EQ(s.hi, 1);
    EXPECT_NEAR(s.t, 0.5f, 1e-6f);
    s = c.select(3.f);
    EXPECT_EQ(s.lo, 1);
    EXPECT_EQ(s.hi, 2);
    EXPECT_NEAR(s.t, std::log(1.5f) / std::log(2.f), 1e-6f);
    // lod_bias scales the footprint.
    LodSelection b = c.select(3.f, 2.f), d = c.select(6.f);
    EXPECT_EQ(b.lo, d.lo);
    EXPECT_EQ(b.t, d.t);
}

// Factors more than 2 apart: the coarser level enters only in the octave below its factor
// (a level much coarser than the footprint is biased; lod.h), never below half its factor.
TEST(LodChain, TransitionsSpanAtMostTheOctaveBelowALevel) {
    LodChain c({1.f, 8.f, 64.f});
    for (float w : {1.5f, std::sqrt(8.f), 3.99f}) {  // below 8 / 2: the original alone
        LodSelection s = c.select(w);
        EXPECT_EQ(s.lo, 0) << w;
        EXPECT_EQ(s.hi, 0) << w;
        EXPECT_EQ(s.t, 0.f) << w;
    }
    LodSelection s = c.select(4.f * std::sqrt(2.f));  // the middle of the octave [4, 8]
    EXPECT_EQ(s.lo, 0);
    EXPECT_EQ(s.hi, 1);
    EXPECT_NEAR(s.t, 0.5f, 1e-5f);
    EXPECT_EQ(c.select(8.f).lo, 1);
    EXPECT_EQ(c.select(8.f).t, 0.f);
    EXPECT_EQ(c.select(31.f).hi, 1);  // below 64 / 2: level 1 alone
    EXPECT_NEAR(c.select(32.f * std::sqrt(2.f)).t, 0.5f, 1e-5f);
    EXPECT_EQ(c.select(32.f * std::sqrt(2.f)).hi, 2);
    // The expected factor never exceeds twice the footprint (the log-linear rule over [1, 8]
    // gave level 8 a weight of 1/3 at 2 texels).
    for (float w = 1.f; w < 200.f; w *= 1.03f) {
        LodSelection q = c.select(w);
        EXPECT_LE(c.factor(q.lo), w * 1.0001f) << w;
        if (q.t > 0.f) {
            EXPECT_LE(c.factor(q.hi), 2.f * w * 1.0001f) << w;
        }
    }
    // Zero, NaN and huge footprints: the first and the last level.
    EXPECT_EQ(c.select(0.f).hi, 0);
    EXPECT_EQ(c.select(std::numeric_limits<float>::quiet_NaN()).hi, 0);
    EXPECT_EQ(c.select(3e38f).lo, 2);
    EXPECT_EQ(c.select(std::numeric_limits<float>::infinity(), 1e-30f).lo, 2);
}

TEST(LodChain, PositionIsContinuousAndNonDecreasing) {
    for (const std::vector<float> &f : {std::vector<float>{1.f, 8.f, 64.f}, std::vector<float>{1.f, 2.f, 4.f, 32.f},
                                        std::vector<float>{1.f, 1.5f, 2.f, 100.f}}) {
        LodChain c(f);
        float prev = 0.f;  // position(0.5) = 0: below the first factor
        for (float w = 0.5f; w < 400.f; w *= 1.01f) {
            float p = c.position(w);
            EXPECT_GE(p, prev) << w;
            EXPECT_LE(p - prev, std::log(1.01f) / std::log(2.f / 1.5f) + 1e-4f) << w;  // no jumps (the closest factors: 1.5, 2)
            prev = p;
        }
        EXPECT_EQ(prev, float(c.levels() - 1));
    }
}

TEST(LodChain, StochasticChoiceHasTheBlendWeightAsProbability) {
    LodChain c({1.f, 4.f});
    const float w = 2.5f;
    LodSelection s = c.select(w);
    const int n = 100000;
    int hi = 0;
    for (int k = 0; k < n; ++k) hi += c.choose(w, (k + 0.5f) / n) == s.hi;  // stratified u: exact
    EXPECT_NEAR(double(hi) / n, s.t, 1.0 / n + 1e-6);
}

TEST(LodChain, RejectsBadChains) {
    EXPECT_THROW(LodChain(std::vector<float>{}), MesoError);
    EXPECT_THROW(LodChain({0.5f}), MesoError);
    EXPECT_THROW(LodChain({1.f, 1.f}), MesoError);
    EXPECT_THROW(LodChain({1.f, 8.f, 4.f}), MesoError);
    EXPECT_THROW(LodChain({1.f, std::numeric_limits<float>::infinity()}), MesoError);
    try {
        LodChain({1.f, 8.f, 4.f}, "scene.json: shapes[0].lod");
        ADD_FAILURE();
    } catch (const MesoError &e) {
        EXPECT_NE(std::string(e.what()).find("shapes[0].lod: level 2"), std::string::npos) << e.what();
    }
}

TEST(LodChain, FootprintTexelsIsTheMajorAxisAndFinite) {
    // A footprint of 1/512 uv along x and 1/128 along y on a 1024 x 1024 map: 2 and 8 texels.
    EXPECT_NEAR(footprint_texels(1.f / 512, 0.f, 0.f, 1.f / 128, 1024, 1024), 8.f, 1e-5f);
    EXPECT_NEAR(footprint_texels(3e-3f, 0.f, 4e-3f, 0.f, 1000, 1000), 5.f, 1e-4f);
    const float inf = std::numeric_limits<float>::infinity(), nan = std::numeric_limits<float>::quiet_NaN();
    EXPECT_EQ(footprint_texels(nan, 0.f, 0.f, 0.f, 1024, 1024), 0.f);
    EXPECT_TRUE(std::isfinite(footprint_texels(inf, 0.f, 0.f, 0.f, 1024, 1024)));
    EXPECT_TRUE(std::isfinite(footprint_texels(1e30f, 1e30f, 1e30f, 1e30f, 2e5, 2e5)));
    LodChain c({1.f, 8.f});
    EXPECT_EQ(c.select(nan).lo, 0);
    EXPECT_EQ(c.select(inf).lo, 1);
}

// The aov integrator's footprint: a camera facing a (flat) shell-mapped plane at distance 2
// sees a pixel footprint of 2 d tan(fov/2) / width world units, i.e. that times the map's
// texels per world unit (64 texels x tiling 4 over a plane 2 units wide = 128 per unit).
TEST(LodAov, FootprintOfAPlaneFacingTheCamera) {
    const char *scene = R"({
      "camera": {"type": "perspective", "origin": [0, 0, 2], "target": [0, 0, 0], "up": [0, 1, 0],
                 "fov": 40, "width": 101, "height": 101},
      "integrator": {"type": "aov", "aov": "footprint"},
      "sampler": {"type": "independent", "sample_count": 1},
      "shapes": [{"type": "rectangle", "displacement": {"map": {"generator": "fbm", "size": 64}, "scale": 0, "tiling": 4}}]
    })";
    auto s = meso::test::load_json_scene("lod_aov.json", scene);
    meso::RenderResult r = meso::test::render_scene(*s, 1);
    const double expected = 2.0 * 2.0 * std::tan(20.0 * 3.14159265358979 / 180.0) / 101.0 * 128.0;
    EXPECT_NEAR(r.image.at(50, 50, 0), expected, 0.01 * expected);
    // Off-centre pixels see the plane obliquely: wider footprints, still finite.
    EXPECT_GT(r.image.at(2, 2, 0), r.image.at(50, 50, 0));
    EXPECT_TRUE(std::isfinite(r.image.at(0, 0, 0)));

    // Displaced (micro-facets tilted by up to ~30 degrees), seen at 60 degrees from the
    // normal: the footprint is measured on the base surface, so it equals the flat plane's
    // (heights move the hit by ~1% of the distance); projected onto the micro-facets it
    // would change by tens of per cent.
    auto oblique = [&](const char *scale) {
        std::string t = scene;
        auto swap = [&](const std::string &from, const std::string &to) { t.replace(t.find(from), from.size(), to); };
        swap("\"origin\": [0, 0, 2]", "\"origin\": [0, -1.732, 1]");
        swap("\"scale\": 0", scale);
        return meso::test::render_scene(*meso::test::load_json_scene("lod_aov2.json", t), 1).image;
    };
    meso::Image flat = oblique("\"scale\": 0"), disp = oblique("\"scale\": 0.5");
    double worst = 0;
    for (int y = 40; y <= 60; ++y)
        for (int x = 40; x <= 60; ++x) worst = std::max(worst, std::abs(disp.at(x, y, 0) / flat.at(x, y, 0) - 1.0));
    EXPECT_LT(worst, 0.03);
}

// LoD selection in the path tracer. A flat shell-mapped plane (64-texel map tiled 4x over a
// plane 2 units wide: 128 texels per unit) faces the camera; level 0 is white-red, level 1
// white-green (reflectance 1 in one channel), so under a constant environment a pixel's
// green fraction is the weight of level 1. The footprint of the centre pixel at distance d
// is 2 d tan(20 deg) / 101 * 128 * max(1/8, 1/sqrt(spp)) texels; distances are chosen for
// footprints of 2, 2.83 and 4 texels, where the chain [1, 4] gives t = 0, 0.5 and 1.
namespace {

std::string lod_plane_scene(double distance, const char *blend, int spp, const char *extra = "") {
    return fmt::format(R"({{
      "camera": {{"type": "perspective", "origin": [0, 0, {}], "target": [0, 0, 0], "up": [0, 1, 0],
                 "fov": 40, "width": 101, "height": 101}},
      "integrator": {{"type": "path", "max_depth": 2}},
      "sampler": {{"type": "independent", "sample_count": {}}},
      "shapes": [{{"type": "rectangle",
                  "displacement": {{"map": {{"generator": "fbm", "size": 64}}, "scale": 0, "tiling": 4}},
                  "lod": {{"factors": [1, 4], "blend": "{}", "same_model": true {},
                          "materials": [{{"type": "diffuse", "reflectance": [1, 0, 0]}},
                                        {{"type": "diffuse", "reflectance": [0, 1, 0]}}]}}}}],
      "lights": [{{"type": "constant", "radiance": 1}}]
    }})",
                       distance, spp, blend, extra);
}

double green_fraction(const meso::Image &img) {
    double r = 0, g = 0;
    for (int y = 48; y <= 52; ++y)
        for (int x = 48; x <= 52; ++x) r += img.at(x, y, 0), g += img.at(x, y, 1);
    return g / (r + g);
}

}  // namespace

TEST(LodPath, LevelsSwitchAtTheExpectedDistances) {
    const int spp = 256;
    const double texels_per_unit_distance = 2.0 * std::tan(20.0 * 3.14159265358979 / 180.0) / 101.0 * 128.0 / 8.0;  // max(1/8, 1/sqrt(256))
    for (const char *blend : {"blend", "stochastic"}) {
        for (double w : {2.0, 2.0 * std::sqrt(2.0), 4.0}) {
            // The chain [1, 4]: level 1 enters in the octave [2, 4] (geometry/lod.h).
            const double d = w / texels_per_unit_distance, t = std::clamp(1.0 + std::log2(w / 4.0), 0.0, 1.0);
            auto s = meso::test::load_json_scene("lod_path.json", lod_plane_scene(d, blend, spp));
            meso::RenderResult r = meso::test::render_scene(*s, spp);
            std::printf("%s: footprint %.0f texels: level-1 weight %.4f (expected %.4f)\n", blend, w, green_fraction(r.image), t);
            EXPECT_NEAR(green_fraction(r.image), t, 0.03) << blend << " footprint " << w << " texels at distance " << d;
            EXPECT_EQ(r.nan_count, 0);
        }
    }
    // lod bias 2 makes the 2-texel distance select level 1 alone.
    auto s = meso::test::load_json_scene("lod_path.json", lod_plane_scene(2.0 / texels_per_unit_distance, "blend", spp, R"(, "bias": 2)"));
    EXPECT_NEAR(green_fraction(meso::test::render_scene(*s, spp).image), 1.0, 0.01);
}

// The `lod` aov on a shape with its own `lod` block reports the level the path tracer picks
// there (its chain, bias and per-sample footprint), not the aov's own `lod_factors`: at the
// footprints of LevelsSwitchAtTheExpectedDistances the centre pixels read t = 0, 0.5 and 1 of
// the chain [1, 4], where the aov's chain [1, 8, 64] would give 0 everywhere.
TEST(LodAov, LevelOnALodShapeIsThePathTracersChoice) {
    const int spp = 64;  // footprints scaled by max(1/8, 1/sqrt(64)), as in the path test
    const double texels_per_unit_distance = 2.0 * std::tan(20.0 * 3.14159265358979 / 180.0) / 101.0 * 128.0 / 8.0;
    auto centre = [](const meso::Image &img) {
        double sum = 0;
        for (int y = 48; y <= 52; ++y)
            for (int x = 48; x <= 52; ++x) sum += img.at(x, y, 0);
        return sum / 25.0;
    };
    auto aov_scene = [&](double d, const char *extra) {
        std::string t = lod_plane_scene(d, "stochastic", spp, extra);
        const std::string from = R"({"type": "path", "max_depth": 2})";
        t.replace(t.find(from), from.size(), R"({"type": "aov", "aov": "lod", "lod_factors": [1, 8, 64]})");
        return meso::test::load_json_scene("lod_aov_level.json", t);
    };
    for (double w : {2.0, 2.0 * std::sqrt(2.0), 4.0}) {
        const double d = w / texels_per_unit_distance, t = std::clamp(1.0 + std::log2(w / 4.0), 0.0, 1.0);
        meso::RenderResult r = meso::test::render_scene(*aov_scene(d, ""), spp);
        EXPECT_NEAR(centre(r.image), t, 0.03) << "footprint " << w << " texels";
        EXPECT_EQ(r.nan_count, 0);
    }
    // The block's bias 2 moves the 2-texel distance to level 1 alone.
    EXPECT_NEAR(centre(meso::test::render_scene(*aov_scene(2.0 / texels_per_unit_distance, R"(, "bias": 2)"), spp).image),
                1.0, 1e-3);
}

// With every level the original model, an LoD render equals the plain render within noise.
TEST(LodPath, SameModelLevelsAddNoBias) {
    const char *base = R"({
      "camera": {"type": "perspective", "origin": [0, 1.2, 2.2], "target": [0, 0, 0], "up": [0, 1, 0],
                 "fov": 45, "width": 64, "height": 64},
      "integrator": {"type": "path", "max_depth": 4},
      "sampler": {"type": "independent", "sample_count": 16},
      "shapes": [{"type": "rectangle", "to_world": {"rotate": {"axis": [1, 0, 0], "angle": -90}},
                  "material": {"type": "conductor", "material": "Cu", "alpha": 0.2},
                  "displacement": {"map": {"generator": "fbm", "size": 64, "amplitude": 0.05}, "scale": 1, "tiling": 4}
                  @LOD}],
      "lights": [{"type": "directional", "direction": [-0.3, -1, -0.2], "irradiance": 3}, {"type": "constant", "radiance": 0.3}]
    })";
    auto with = [&](const std::string &lod) {
        std::string s = base;
        s.replace(s.find("@LOD"), 4, lod);
        return meso::test::load_json_scene("lod_nobias.json", s);
    };
    auto plain = with(""), lod = with(R"(, "lod": {"factors": [1, 2, 8], "same_model": true})");
    meso::RenderResult a = meso::test::render_scene(*plain, 16, 0, 21), b = meso::test::render_scene(*plain, 16, 0, 22),
                       c = meso::test::render_scene(*lod, 16, 0, 23);
    double noise = meso::compute_metrics(b.image, a.image).relmse, cross = meso::compute_metrics(c.image, a.image).relmse;
    std::printf("relMSE plain vs plain %.5f, LoD (same model) vs plain %.5f\n", noise, cross);
    EXPECT_LT(cross, 1.15 * noise);
}

// Box-downsampled levels load, render finite, and bad chains are located errors.
TEST(LodPath, DownsampledLevelsAndErrors) {
    std::string json = lod_plane_scene(6.0, "stochastic", 4);
    json.replace(json.find(R"("same_model": true)"), 18, R"("same_model": false)");
    auto s = meso::test::load_json_scene("lod_down.json", json);
    EXPECT_EQ(s->shapes.size(), 2u);
    EXPECT_EQ(meso::test::render_scene(*s, 4).nan_count, 0);
    auto expect_error = [](std::string j, const std::string &from, const std::string &to, const std::string &needle) {
        j.replace(j.find(from), from.size(), to);
        try {
            meso::test::load_json_scene("lod_bad.json", j);
            ADD_FAILURE() << "no error for " << to;
        } catch (const meso::MesoError &e) {
            EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
        }
    };
    const std::string good = lod_plane_scene(6.0, "stochastic", 4);
    expect_error(good, R"("factors": [1, 4])", R"("factors": [2, 4])", "level 0 is the original");
    expect_error(good, R"("factors": [1, 4])", R"("factors": [1, 4, 3])", "increase");
    expect_error(good, R"("same_model": true)", R"("same_model": false, "bias": 0)", "bias");
    expect_error(good, R"("factors": [1, 4], "blend": "stochastic", "same_model": true)",
                 R"("factors": [1, 3], "blend": "stochastic", "same_model": false)", "must be an integer dividing");
    expect_error(good, R"("blend": "stochastic")", R"("blend": "both")", "\"stochastic\" or \"blend\"");
    expect_error(good, R"("scale": 0, "tiling": 4})", R"("scale": 0, "tiling": 4, "mode": "tessellate"})", "shell-mapped");
}

// A path at a level beyond a shorter chain still sees that chain's last level; each level
// of a chain is seen only by its own rays otherwise.
TEST(LodPath, ShorterChainsAreSeenAtTheirLastLevel) {
    auto s = meso::test::load_json_scene("lod_masks.json", R"({
      "camera": {"type": "perspective", "width": 8, "height": 8},
      "shapes": [{"type": "rectangle", "to_world": {"translate": [-2, 0, 0]},
                  "displacement": {"map": {"generator": "fbm", "size": 16}, "scale": 0.1},
                  "lod": {"factors": [1, 2, 4]}},
                 {"type": "rectangle", "to_world": {"translate": [2, 0, 0]},
                  "displacement": {"map": {"generator": "fbm", "size": 16}, "scale": 0.1},
                  "lod": {"factors": [1, 2]}}]
    })");
    for (float x : {-2.f, 2.f})
        for (int level = 0; level < 3; ++level) {
            meso::Ray r(meso::Vec3(x, 0.1f, 5.f), meso::Vec3(0, 0, -1));
            r.mask = meso::lod_ray_mask(level);
            meso::SurfaceInteraction si;
            ASSERT_TRUE(s->intersect(r, si)) << x << " level " << level;
            const int expected = x > 0 && level > 1 ? 1 : level;
            EXPECT_EQ(si.shape->lod_level, expected) << x << " level " << level;
        }
}

// Expected-MSE rule (geometry/lod.h): analytic switch points of J_k = E(r) - V / n.
namespace {
using Windows = std::vector<std::vector<float>>;
/// E(r) of independent cell errors: e / r² at r = 1, 2, 4, ... (the measured windows).
std::vector<float> independent(float e, int windows) {
    std::vector<float> w;
    for (int j = 0; j < windows; ++j) w.push_back(e / float(1 << (2 * j)));
    return w;
}
}  // namespace

TEST(LodMse, TwoLevelsSwitchWhereBiasEqualsTheVarianceRemoved) {
    // Factors 1, 8; E(r) = e / r², V = v: level 1 wins where e F² / w² < v / n, i.e. past
    // w* = F sqrt(e n / v) = 64 at e = v, n = 64; the octave around w* is shared half and half.
    LodChain c({1.f, 8.f});
    const Windows E{{}, independent(0.5f, 8)};
    const std::vector<float> V{0.f, 0.5f};
    LodSelection s = select_mse_level(c, E, V, 16.f, 64.f);
    EXPECT_EQ(s.lo, 0);
    EXPECT_EQ(s.hi, 0);
    s = select_mse_level(c, E, V, 256.f, 64.f);
    EXPECT_EQ(s.lo, 1);
    EXPECT_EQ(s.hi, 1);
    s = select_mse_level(c, E, V, 64.f, 64.f);
    EXPECT_EQ(s.lo, 0);
    EXPECT_EQ(s.hi, 1);
    EXPECT_NEAR(s.t, 0.5f, 1e-3f);
    // A quarter octave above w*: level 1 is best over 3/4 of the octave.
    s = select_mse_level(c, E, V, 64.f * std::pow(2.f, 0.25f), 64.f);
    EXPECT_NEAR(s.t, 0.75f, 1e-3f);
    // Four times the samples: the variance removed counts a quarter, the switch moves to 2 w*.
    s = select_mse_level(c, E, V, 128.f, 256.f);
    EXPECT_NEAR(s.t, 0.5f, 1e-3f);
    // The bias scales the footprint.
    s = select_mse_level(c, E, V, 32.f, 64.f, 2.f);
    EXPECT_NEAR(s.t, 0.5f, 1e-3f);
}

TEST(LodMse, NoGainOrNoFootprintKeepsTheOriginal) {
    LodChain c({1.f, 4.f, 16.f});
    const Windows E{{}, {0.f}, {0.f}};
    // A level that removes no variance (or adds some: its own estimator's noise) is never used,
    // even without any model error.
    for (float w : {0.5f, 4.f, 100.f, 1e6f}) {
        LodSelection s = select_mse_level(c, E, {0.f, 0.f, -0.1f}, w, 16.f);
        EXPECT_EQ(s.hi, 0) << w;
    }
    const float nan = std::numeric_limits<float>::quiet_NaN();
    for (float w : {0.f, -1.f, nan, std::numeric_limits<float>::infinity()})
        EXPECT_EQ(select_mse_level(c, E, {0.f, 1.f, 2.f}, w, 16.f).hi, 0) << w;
    // Mismatched sizes fall back to the footprint rule.
    LodSelection s = select_mse_level(c, Windows{{}}, {0.f}, 16.f, 16.f);
    EXPECT_EQ(s.lo, 2);
}

TEST(LodMse, ExactModelsTakeTheCoarsestLevelOnceItFitsInThePixel) {
    // E = 0: only the detail above the pixel scale counts against a coarse level (r < 1:
    // J = V (1 - r²) - V r² / n), so the coarsest level whose cell fits in the pixel wins.
    LodChain c({1.f, 4.f, 16.f, 64.f});
    const Windows E{{}, {0.f}, {0.f}, {0.f}};
    const std::vector<float> V{0.f, 0.2f, 0.5f, 0.9f};
    LodSelection s = select_mse_level(c, E, V, 40.f, 64.f);
    EXPECT_EQ(s.lo, 2);
    EXPECT_EQ(s.hi, 2);
    s = select_mse_level(c, E, V, 1000.f, 64.f);
    EXPECT_EQ(s.lo, 3);
}

TEST(LodMse, MiddleLevelWinsWhenTheCoarsestIsTooBiased) {
    // n = 16, w = 64: J_1 = 0.01 / 256 - 0.5 / 16 < 0, J_2 = 1 / 16 - 0.6 / 16 > 0.
    LodChain c({1.f, 4.f, 16.f});
    const Windows E{{}, independent(0.01f, 6), independent(1.f, 6)};
    LodSelection s = select_mse_level(c, E, {0.f, 0.5f, 0.6f}, 64.f, 16.f);
    EXPECT_EQ(s.lo, 1);
    EXPECT_EQ(s.hi, 1);
}

TEST(LodMse, StructuredErrorsThatDoNotAverageKeepFinerLevels) {
    // The same per-cell error, independent (falls like 1 / r²) or structured (constant over
    // the measured windows): at r = 8, 0.5 / 64 < 0.25 / 16 takes the level, 0.5 does not.
    LodChain c({1.f, 8.f});
    const std::vector<float> V{0.f, 0.25f};
    EXPECT_EQ(select_mse_level(c, {{}, independent(0.5f, 4)}, V, 64.f, 16.f).hi, 1);
    EXPECT_EQ(select_mse_level(c, {{}, {0.5f, 0.5f, 0.5f, 0.5f}}, V, 64.f, 16.f).hi, 0);
    // Past the last window the error falls like 1 / r².
    EXPECT_EQ(select_mse_level(c, {{}, {0.5f, 0.5f}}, V, 8.f * 16.f, 16.f).hi, 1);
}

TEST(LodMse, PathLevelUsesThePixelFootprintAndTheSpp) {
    // A camera ray scaled by 1/8 (64 spp): its footprint is 1/8 of the pixel's; the rule must see
    // the pixel's. Without errors the per-sample footprint rule applies unchanged.
    LodGroup g;
    g.chain = LodChain({1.f, 8.f});
    g.texel_w = g.texel_h = 1024;
    const float du = 64.f / 1024 / 8;  // a 64-texel pixel, per sample
    EXPECT_EQ(select_path_level(g, du, 0.f, 0.f, du).lo, 1);  // 8 texels: level 1 (footprint rule)
    g.window_error = {{}, independent(0.5f, 8)};
    g.removed_variance = {0.f, 0.5f};
    LodSelection s = select_path_level(g, du, 0.f, 0.f, du, 0.125f, 64);
    EXPECT_EQ(s.lo, 0);
    EXPECT_NEAR(s.t, 0.5f, 1e-3f);
    s = select_path_level(g, du, 0.f, 0.f, du, 0.125f, 0);  // spp unknown: 1 / scale² = 64
    EXPECT_NEAR(s.t, 0.5f, 1e-3f);
    s = select_path_level(g, du, 0.f, 0.f, du, 0.125f, 4);  // few samples: the coarse level
    EXPECT_EQ(s.lo, 1);
}

// Metric check (geometry/lod.h): a prefiltered model describes square cells of world size c0;
// D = max(lambda_1, 1 / lambda_2) of the local texel-to-model metric, and the footprint the rule
// sees moves to the original between D = sqrt 2 and 2.
namespace {

constexpr double kTexels = 256, kC0 = 0.01;  // 256 texels per unit uv, model texel 0.01 world

/// Tangents of a surface whose texels measure (su c0, sv c0) along directions at angle `alpha`,
/// rotated off the coordinate axes (the metric must not depend on the frame).
void stretched(double su, double sv, double alpha, Vec3 &dpdu, Vec3 &dpdv) {
    const Vec3 e1 = normalize(Vec3(0.6f, 0.8f, 0.f)), e2 = normalize(Vec3(-0.48f, 0.36f, 0.8f));
    const double L = kTexels * kC0;
    dpdu = e1 * float(su * L);
    dpdv = (e1 * float(std::cos(alpha)) + e2 * float(std::sin(alpha))) * float(sv * L);
}

double distortion(double su, double sv, double alpha = 1.5707963267948966) {
    Vec3 a, b;
    stretched(su, sv, alpha, a, b);
    return metric_distortion(a, b, kTexels, kTexels, kC0);
}

}  // namespace

TEST(LodMetric, DistortionIsTheLargerStretchOrShrinkOfTheModelsCells) {
    EXPECT_NEAR(distortion(1, 1), 1.0, 1e-5);
    EXPECT_NEAR(distortion(1.12, 1.12), 1.12, 1e-5);  // isotropic: the larger of lambda, 1 / lambda
    EXPECT_NEAR(distortion(0.8, 0.8), 1.25, 1e-5);
    // A uv sphere's tile at colatitude theta: u shrinks like sin(theta).
    for (double theta : {1.5, 0.7, 0.3, 0.05, 1e-4}) EXPECT_NEAR(distortion(std::sin(theta), 1), 1 / std::sin(theta), 1e-4 / std::sin(theta));
    EXPECT_NEAR(distortion(3, 1), 3.0, 1e-5);
    // Unit cells sheared to angle alpha: lambda² = 1 +- cos(alpha).
    for (double alpha : {1.2, 0.5, 0.01})
        EXPECT_NEAR(distortion(1, 1, alpha), 1 / std::sqrt(1 - std::cos(alpha)), 1e-3 / std::sqrt(1 - std::cos(alpha)));
    // No model: nothing to check.
    Vec3 a, b;
    stretched(0.1, 1, 1.57, a, b);
    EXPECT_EQ(metric_distortion(a, b, kTexels, kTexels, 0.0), 1.0);
}

TEST(LodMetric, DegenerateTangentsGiveTheOriginalAndFiniteSelections) {
    const Vec3 u(float(kTexels * kC0), 0.f, 0.f), v(0.f, float(kTexels * kC0), 0.f);
    const float nan = std::numeric_limits<float>::quiet_NaN(), inf = std::numeric_limits<float>::infinity();
    LodGroup g;
    g.chain = LodChain({1.f, 4.f, 16.f, 64.f});
    g.texel_w = g.texel_h = kTexels;
    g.model_texel = kC0;
    const float du = 64.f / float(kTexels);  // a 64-texel footprint: the coarsest level without the check
    EXPECT_EQ(select_path_level(g, du, 0.f, 0.f, du, 1.f, 0, metric_distortion(u, v, kTexels, kTexels, kC0)).lo, 3);
    const std::pair<Vec3, Vec3> cases[] = {
        {Vec3(0.f, 0.f, 0.f), v},                           // dp/du = 0 at a pole
        {u, u * 0.5f},                                      // a zero-area (collinear) triangle
        {Vec3(0.f, 0.f, 0.f), Vec3(0.f, 0.f, 0.f)},         // a point
        {Vec3(nan, 0.f, 0.f), v},                           // non-finite
        {Vec3(inf, 0.f, 0.f), v},
        {u * 1e30f, v * 1e30f},                             // huge
        {u * 1e-30f, v * 1e-30f},                           // tiny (stretched by 1e30)
        {u * 1e-3f, v},                                     // a cell 1000 times narrower
    };
    for (const auto &[a, b] : cases) {
        const double d = metric_distortion(a, b, kTexels, kTexels, kC0);
        EXPECT_FALSE(d < 2.0) << a.x << " " << b.x;  // also not NaN
        const LodSelection s = select_path_level(g, du, 0.f, 0.f, du, 1.f, 0, d);
        EXPECT_EQ(s.lo, 0);
        EXPECT_EQ(s.hi, 0);
        EXPECT_TRUE(std::isfinite(s.t));
    }
}

TEST(LodMetric, FootprintMovesToTheOriginalOverTheHalfOctaveBelowTwo) {
    const LodChain c({1.f, 4.f, 16.f, 64.f});
    // Up to sqrt 2: unchanged, bit for bit (also with a bias).
    for (double d : {1.0, 1.2, 1.41421356})
        for (double w : {0.5, 3.0, 100.0}) {
            EXPECT_EQ(metric_footprint(c, w, d), w);
            EXPECT_EQ(metric_footprint(c, w, d, 2.0), w);
        }
    // From 2 on: half the first factor (the original alone), over the bias.
    EXPECT_NEAR(metric_footprint(c, 100.0, 2.0), 2.0, 1e-12);
    EXPECT_NEAR(metric_footprint(c, 100.0, 50.0, 2.0), 1.0, 1e-12);
    EXPECT_EQ(metric_footprint(c, 1.5, 3.0), 1.5);  // never up
    EXPECT_EQ(c.select(float(metric_footprint(c, 1e30, INFINITY))).hi, 0);
    // Between: log-linear in 2 log2 D - 1, continuous and non-increasing in D, through the finer
    // levels (at D = 2^0.75, halfway: sqrt(64 * 2) = 11.3 texels, between x4 and x16).
    EXPECT_NEAR(metric_footprint(c, 64.0, std::pow(2.0, 0.75)), std::sqrt(128.0), 1e-9);
    EXPECT_EQ(c.select(float(metric_footprint(c, 64.0, std::pow(2.0, 0.75)))).lo, 1);
    double prev = 64.0;
    for (double d = 1.4; d <= 2.1; d += 0.001) {
        const double w = metric_footprint(c, 64.0, d);
        EXPECT_LE(w, prev);
        EXPECT_LT(prev - w, 0.5);  // no jump
        prev = w;
    }
}

TEST(LodMetric, PathLevelReadsTheBaseSurfaceTangentsOfTheHit) {
    LodGroup g;
    g.chain = LodChain({1.f, 4.f, 16.f, 64.f});
    g.texel_w = g.texel_h = kTexels;
    SurfaceInteraction si;
    si.dudx = si.dvdy = 64.f / float(kTexels);  // 64 texels
    stretched(1, 1, 1.5707963267948966, si.dpdu, si.dpdv);
    Vec3 a, b;
    stretched(0.25, 1, 1.5707963267948966, a, b);  // the base surface: cells 4 times narrower along u
    si.dpdu_footprint = a;
    si.dpdv_footprint = b;
    si.n_footprint = normalize(cross(a, b));
    EXPECT_EQ(select_path_level(g, si, 1.f, 0).lo, 3);  // no model: no check
    g.model_texel = kC0;
    EXPECT_EQ(select_path_level(g, si, 1.f, 0).hi, 0);  // the base surface's stretch, not the micro-facet's
    si.n_footprint = Vec3();  // not on microgeometry: dp/du, dp/dv (unstretched)
    EXPECT_EQ(select_path_level(g, si, 1.f, 0).lo, 3);
    // The expected-MSE rule sees the same move: with errors that make the coarsest level best.
    si.n_footprint = normalize(cross(a, b));
    g.window_error = {{}, {0.f}, {0.f}, {0.f}};
    g.removed_variance = {0.f, 0.25f, 0.5f, 1.f};
    EXPECT_EQ(select_path_level(g, si, 1.f, 16).hi, 0);
    si.n_footprint = Vec3();
    EXPECT_GE(select_path_level(g, si, 1.f, 16).lo, 2);
}

// On a shell-mapped uv sphere, the tangents at a camera hit give the analytic stretch of its
// tiles: with square tiles at the equator (2 pi / 16 = pi / 8), D = 1 / sin(theta).
TEST(LodMetric, UvSphereTilesStretchLikeOneOverSinTheta) {
    const char *scene = R"({
      "camera": {"type": "perspective", "origin": [0, 0, 5], "target": [0, 0, 0], "up": [0, 1, 0], "width": 8, "height": 8},
      "integrator": {"type": "direct"},
      "shapes": [{"type": "uvsphere", "rings": 64, "segments": 128,
                  "displacement": {"map": {"generator": "fbm", "size": 64}, "scale": 0.001, "tiling": [16, 8]}}]
    })";
    auto s = meso::test::load_json_scene("lod_metric_sphere.json", scene);
    const double c0 = 3.14159265358979 / 8 / 64;
    for (double deg : {90.0, 60.0, 30.0, 10.0, 4.0, 0.5}) {
        const double th = deg * 3.14159265358979 / 180.0, ph = 0.3;
        const Vec3 n(float(std::sin(th) * std::cos(ph)), float(std::sin(th) * std::sin(ph)), float(std::cos(th)));
        Ray ray(n * 3.f, -n);
        SurfaceInteraction si;
        ASSERT_TRUE(s->intersect(ray, si)) << deg;
        double w = 0, h = 0;
        ASSERT_TRUE(si.shape->texel_grid(w, h));
        const double d = metric_distortion(si.dpdu_footprint, si.dpdv_footprint, w, h, c0);
        // The triangles are flat: their u length is the chord's, at the colatitude of their rings.
        const double ring = 3.14159265358979 / 64, lo = std::max(th - ring, 1e-9), hi = std::min(th + ring, 3.14159265358979 / 2);
        EXPECT_GE(d, 0.99 / std::sin(hi)) << deg;
        EXPECT_LE(d, 1.01 / std::sin(lo) + 0.01) << deg;
        std::printf("colatitude %5.1f deg: D = %.4f (1 / sin theta = %.4f)\n", deg, d, 1 / std::sin(th));
    }
}
