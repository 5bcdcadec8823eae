// LoD chains: level selection from footprints, stochastic choice, validation.
#include <gtest/gtest.h>
#include <cmath>
#include <limits>
#include "core/error.h"
#include "render/lod.h"
#include "render_test_util.h"

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
    LodChain c({1.f, 8.f, 64.f});
    LodSelection s = c.select(std::sqrt(8.f));
    EXPECT_EQ(s.lo, 0);
    EXPECT_EQ(s.hi, 1);
    EXPECT_NEAR(s.t, 0.5f, 1e-6f);
    s = c.select(16.f);
    EXPECT_EQ(s.lo, 1);
    EXPECT_EQ(s.hi, 2);
    EXPECT_NEAR(s.t, 1.f / 3.f, 1e-6f);
    // lod_bias scales the footprint.
    LodSelection b = c.select(4.f, 2.f), d = c.select(8.f);
    EXPECT_EQ(b.lo, d.lo);
    EXPECT_EQ(b.t, d.t);
    // Position is continuous and non-decreasing in the footprint.
    float prev = 0.f;  // position(0.5) = 0: below the first factor
    for (float w = 0.5f; w < 200.f; w *= 1.01f) {
        float p = c.position(w);
        EXPECT_GE(p, prev);
        EXPECT_LE(p - prev, 0.02f) << w;  // no jumps
        prev = p;
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
