// Height maps: file I/O (EXR exact, 16-bit PNG within one step, grey-only, finite-only),
// the generators (determinism, seamless wrap-around, the gaussian's exact slope
// covariance, exact facet slopes and facet-aligned albedo, weaves, relief from an image)
// and `meso genmap` run in-process (outputs, record, errors).
#include <gtest/gtest.h>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fmt/format.h>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>
#include "core/error.h"
#include "geometry/heightmap.h"
#include "geometry/heightmap_gen.h"
#include "image/image.h"
#include "sampling/rng.h"
#include "cli_capture.h"
#include "scratch_dir.h"

using namespace meso;
namespace fs = std::filesystem;
using Params = std::map<std::string, std::string>;
using meso::test::meso_error_of;
using meso::test::run_cli_captured;
using meso::test::CliResult;

namespace {

std::string tmp(const std::string &name) { return meso::test::scratch_dir("meso_test_genmap") + "/" + name; }

std::string gen_error(const std::string &kind, const Params &p) {
    return meso_error_of([&] { generate_height_map(kind, p, "maps[0]"); });
}

/// Mean slope and slope covariance of the cells, by finite differences written out here
/// (independent of height_map_stats): s_u = W (h10 + h11 - h00 - h01) / 2, etc.
struct Moments {
    double mu = 0, mv = 0, xx = 0, yy = 0, xy = 0;
};
Moments slope_moments(const HeightMap &m) {
    Moments r;
    double n = double(m.width) * m.height, uu = 0, vv = 0, uv = 0;
    for (int j = 0; j < m.height; ++j)
        for (int i = 0; i < m.width; ++i) {
            double h00 = m.wrapped(i, j), h10 = m.wrapped(i + 1, j), h01 = m.wrapped(i, j + 1), h11 = m.wrapped(i + 1, j + 1);
            double su = m.width * 0.5 * (h10 + h11 - h00 - h01), sv = m.height * 0.5 * (h01 + h11 - h00 - h10);
            r.mu += su, r.mv += sv, uu += su * su, vv += sv * sv, uv += su * sv;
        }
    r.mu /= n, r.mv /= n;
    r.xx = uu / n - r.mu * r.mu, r.yy = vv / n - r.mv * r.mv, r.xy = uv / n - r.mu * r.mv;
    return r;
}

/// Height differences between neighbours across the wrap-around seam (last to first column
/// and row) and inside the map: mean square and largest magnitude of each.
struct SeamStats {
    double seam_msd = 0, interior_msd = 0, seam_max = 0, interior_max = 0;
};
SeamStats seam_stats(const HeightMap &m) {
    SeamStats r;
    long ns = 0, ni = 0;
    auto add = [&](bool seam, double d) {
        (seam ? r.seam_msd : r.interior_msd) += d * d;
        double &mx = seam ? r.seam_max : r.interior_max;
        mx = std::max(mx, std::abs(d));
        ++(seam ? ns : ni);
    };
    for (int j = 0; j < m.height; ++j)
        for (int i = 0; i < m.width; ++i) {
            add(i == m.width - 1, m.wrapped(i + 1, j) - m.at(i, j));
            add(j == m.height - 1, m.wrapped(i, j + 1) - m.at(i, j));
        }
    r.seam_msd /= ns, r.interior_msd /= ni;
    return r;
}

const std::vector<std::string> kSeeded = {"fbm", "gaussian", "bumps"};
const std::vector<std::string> kSeamless = {"fbm", "gaussian", "bumps", "vgroove", "sawtooth", "twill", "satin"};

}  // namespace

// ---------------------------------------------------------------------------------------
// File I/O

TEST(HeightMapIO, ExrRoundTripIsExact) {
    HeightMap m(37, 21);
    PCG32 rng(5);
    for (float &v : m.h) v = (rng.next_float() - 0.5f) * 1e3f * rng.next_float();
    m.at(3, 4) = 1e-30f, m.at(5, 6) = -7.25e6f;
    write_height_map(tmp("rt.exr"), m);
    HeightMap r = read_height_map(tmp("rt.exr"));
    ASSERT_EQ(r.width, 37);
    ASSERT_EQ(r.height, 21);
    EXPECT_EQ(r.h, m.h);
    Image img = read_image(tmp("rt.exr"));
    EXPECT_EQ(img.channels, 1);  // single channel on disk
}

TEST(HeightMapIO, Png16RoundTripWithinOneStep) {
    HeightMap m(50, 30);
    PCG32 rng(9);
    for (float &v : m.h) v = -0.3f + 0.7f * rng.next_float();
    HeightRange range = write_height_map_png16(tmp("rt.png"), m);
    EXPECT_FLOAT_EQ(range.lo, *std::min_element(m.h.begin(), m.h.end()));
    EXPECT_FLOAT_EQ(range.hi, *std::max_element(m.h.begin(), m.h.end()));
    HeightMap r = read_height_map(tmp("rt.png"));
    ASSERT_EQ(r.width, 50);
    double span = double(range.hi) - range.lo, worst = 0;
    for (size_t k = 0; k < m.h.size(); ++k) {
        EXPECT_GE(r.h[k], 0.f);
        EXPECT_LE(r.h[k], 1.f);
        worst = std::max(worst, std::abs(range.lo + span * r.h[k] - m.h[k]) / span);
    }
    EXPECT_LE(worst, 0.5 / 65535 + 1e-6);  // rounding to the nearest of 65536 levels
    // A constant map is written as 0.
    HeightMap flat(4, 4, 2.5f);
    HeightRange fr = write_height_map_png16(tmp("flat.png"), flat);
    EXPECT_EQ(fr.lo, 2.5f);
    EXPECT_EQ(fr.hi, 2.5f);
    EXPECT_EQ(read_height_map(tmp("flat.png")).h, std::vector<float>(16, 0.f));
}

TEST(HeightMapIO, GreyStoredAsRgbIsAcceptedColourIsNot) {
    Image grey(4, 3, 4);  // RGBA with R = G = B, alpha ignored
    for (int y = 0; y < 3; ++y)
        for (int x = 0; x < 4; ++x) {
            for (int c = 0; c < 3; ++c) grey.at(x, y, c) = 0.1f * x + y;
            grey.at(x, y, 3) = 0.5f;
        }
    write_exr(tmp("grey_rgba.exr"), grey);
    HeightMap m = read_height_map(tmp("grey_rgba.exr"));
    EXPECT_FLOAT_EQ(m.at(3, 2), 2.3f);

    Image colour(4, 3, 3);
    colour.at(2, 1, 1) = 0.5f;
    write_exr(tmp("colour.exr"), colour);
    EXPECT_EQ(meso_error_of([&] { read_height_map(tmp("colour.exr")); }),
              tmp("colour.exr") + ": expected a grey height map (1 channel, or RGB with R = G = B), but pixel (2, 1) "
                                  "has R, G, B = 0, 0.5, 0");
}

TEST(HeightMapIO, NonFiniteAndMissingFilesAreErrors) {
    Image img(3, 2, 1);
    img.at(1, 1, 0) = std::numeric_limits<float>::quiet_NaN();
    write_exr(tmp("nan.exr"), img);
    EXPECT_EQ(meso_error_of([&] { read_height_map(tmp("nan.exr")); }),
              tmp("nan.exr") + ": pixel (1, 1) is nan: a height map needs finite values");
    img.at(1, 1, 0) = std::numeric_limits<float>::infinity();
    write_exr(tmp("inf.exr"), img);
    EXPECT_NE(meso_error_of([&] { read_height_map(tmp("inf.exr")); }).find("is inf"), std::string::npos);
    EXPECT_EQ(meso_error_of([&] { read_height_map(tmp("missing.exr")); }),
              tmp("missing.exr") + ": cannot read image: file does not exist");
    EXPECT_NE(meso_error_of([&] { write_height_map(tmp("empty.exr"), HeightMap()); }).find("empty height map"),
              std::string::npos);
    EXPECT_FALSE(fs::exists(tmp("empty.exr")));
}

// ---------------------------------------------------------------------------------------
// Generators

TEST(GenMap, ListsEveryGeneratorWithCommonParams) {
    std::vector<std::string> names;
    for (auto &g : height_map_generators()) {
        names.push_back(g.name);
        ASSERT_GE(g.params.size(), 4u);
        EXPECT_EQ(g.params[0].name, "size");
        EXPECT_EQ(g.params[3].name, "seed");
        for (auto &p : g.params) EXPECT_FALSE(p.help.empty()) << g.name << "." << p.name;
    }
    EXPECT_EQ(names, (std::vector<std::string>{"fbm", "gaussian", "bumps", "vgroove", "sawtooth", "twill", "satin",
                                               "relief"}));
}

TEST(GenMap, DeterministicForASeed) {
    for (const std::string &kind : kSeamless) {
        Params p{{"size", "64"}, {"seed", "7"}};
        GeneratedMap a = generate_height_map(kind, p), b = generate_height_map(kind, p);
        EXPECT_EQ(a.height.h, b.height.h) << kind;
        EXPECT_EQ(a.albedo.data, b.albedo.data) << kind;
        for (float v : a.height.h) ASSERT_TRUE(std::isfinite(v)) << kind;
        EXPECT_EQ(a.params.at("width"), "64");
        EXPECT_EQ(a.params.at("seed"), "7");
    }
    for (const std::string &kind : kSeeded) {
        GeneratedMap a = generate_height_map(kind, {{"size", "64"}, {"seed", "7"}});
        GeneratedMap b = generate_height_map(kind, {{"size", "64"}, {"seed", "8"}});
        EXPECT_NE(a.height.h, b.height.h) << kind;
    }
}

TEST(GenMap, WrapAroundIsSeamless) {
    // Across the seam the heights change like they do inside: no step much larger than the
    // largest interior one (sizes that are not a multiple of the pattern sample it at other
    // phases there) and, for the random maps, a mean square of the interior's size.
    // A generator that ignored the period would jump by about the height range there.
    auto check = [](const std::string &kind, const Params &p) {
        GeneratedMap g = generate_height_map(kind, p);
        EXPECT_TRUE(g.periodic) << kind;
        SeamStats s = seam_stats(g.height);
        EXPECT_GT(s.interior_msd, 0) << kind;
        EXPECT_LE(s.seam_max, 1.25 * s.interior_max) << kind;  // sampling phase differs at the seam
        bool random = std::find(kSeeded.begin(), kSeeded.end(), kind) != kSeeded.end();
        if (random) { EXPECT_LT(s.seam_msd, 3 * s.interior_msd) << kind; }
    };
    for (const std::string &kind : kSeamless) check(kind, {{"size", "96"}, {"seed", "3"}});
    for (const std::string &kind : kSeeded) check(kind, {{"width", "90"}, {"height", "61"}, {"seed", "3"}});
    check("gaussian", {{"width", "90"}, {"height", "61"}, {"correlation", "0.08"}, {"sxy", "0.05"}});  // Bluestein DFT
    check("twill", {{"width", "100"}, {"height", "70"}, {"yarns", "9"}});
    check("sawtooth", {{"width", "100"}, {"height", "70"}, {"periods", "3"}});
}

TEST(GenMapGaussian, SlopeCovarianceMatchesTargetExactly) {
    struct Case {
        const char *w, *h, *sxx, *syy, *sxy, *corr;
    };
    const Case cases[] = {
        {"128", "128", "0.1", "0.1", "0", "0.05"},     // isotropic
        {"128", "128", "0.2", "0.02", "0", "0.05"},    // anisotropic
        {"128", "128", "0.1", "0.05", "0.05", "0.05"}, // correlated
        {"128", "128", "0.3", "0.1", "-0.12", "0.1"},  // negatively correlated, longer
        {"100", "72", "0.05", "0.2", "0.02", "0.06"},  // non-square, non-power-of-two
        {"128", "128", "0", "0.1", "0", "0.05"},       // degenerate: slopes along v only
        {"128", "128", "0.1", "0", "0", "0.05"},       // degenerate: along u only
        {"96", "96", "0.1", "0.1", "0.1", "0.05"},     // degenerate: along the diagonal
        {"96", "96", "0.1", "0.1", "-0.1", "0.05"},    // degenerate: along the anti-diagonal
        {"64", "64", "2.5", "1.5", "1", "0.1"},        // steep
        {"256", "256", "1", "0.25", "0.4995", "0.05"}, // correlation coefficient 0.999 (damped solve)
    };
    for (const Case &c : cases) {
        Params p{{"width", c.w}, {"height", c.h}, {"sxx", c.sxx}, {"syy", c.syy}, {"sxy", c.sxy}, {"correlation", c.corr}};
        GeneratedMap g = generate_height_map("gaussian", p);
        Moments m = slope_moments(g.height);
        double txx = std::stod(c.sxx), tyy = std::stod(c.syy), txy = std::stod(c.sxy);
        double scale = std::max(txx, tyy);
        std::string what = fmt::format("sxx {} syy {} sxy {} on {}x{}", c.sxx, c.syy, c.sxy, c.w, c.h);
        EXPECT_NEAR(m.xx, txx, 1e-4 * scale) << what;
        EXPECT_NEAR(m.yy, tyy, 1e-4 * scale) << what;
        EXPECT_NEAR(m.xy, txy, 1e-4 * scale) << what;
        EXPECT_NEAR(m.mu, 0, 1e-5) << what;
        EXPECT_NEAR(m.mv, 0, 1e-5) << what;
        HeightMapStats st = height_map_stats(g.height);
        EXPECT_NEAR(st.sxx, m.xx, 1e-9 * scale + 1e-12);
        EXPECT_NEAR(st.sxy, m.xy, 1e-9 * scale + 1e-12);
        EXPECT_NEAR(st.rms_slope, std::sqrt(txx + tyy), 1e-3 * std::sqrt(txx + tyy));
    }
    // A zero target is a flat map.
    GeneratedMap flat = generate_height_map("gaussian", {{"sxx", "0"}, {"syy", "0"}, {"size", "16"}, {"correlation", "0.1"}});
    EXPECT_EQ(flat.height.h, std::vector<float>(256, 0.f));
}

TEST(GenMapGaussian, CorrelationLengthSetsTheHeightScale) {
    // Isotropic: sigma^2 = ell^2 * s / 2 (Gaussian autocorrelation, slope variance s per axis).
    GeneratedMap g = generate_height_map("gaussian", {{"size", "256"}, {"correlation", "0.04"}, {"sxx", "0.1"}, {"syy", "0.1"}});
    double var = 0;
    for (float v : g.height.h) var += double(v) * v;
    var /= g.height.h.size();
    EXPECT_NEAR(var / (0.04 * 0.04 * 0.1 / 2), 1.0, 0.25);  // one random realisation
}

TEST(GenMapGaussian, MeanSlopeIsARampAndBreaksPeriodicity) {
    GeneratedMap g = generate_height_map("gaussian", {{"size", "128"}, {"mx", "0.5"}, {"my", "-0.25"}});
    EXPECT_FALSE(g.periodic);
    ASSERT_FALSE(g.notes.empty());
    EXPECT_NE(g.notes[0].find("non-periodic"), std::string::npos);
    HeightMapStats st = height_map_stats(g.height, /*periodic=*/false);  // seam cells left out
    EXPECT_NEAR(st.mean_su, 0.5, 0.02);
    EXPECT_NEAR(st.mean_sv, -0.25, 0.02);
    SeamStats s = seam_stats(g.height);
    EXPECT_GT(s.seam_max, 10 * s.interior_max);  // the ramp's jump
    // The ramp is exact: the difference from the periodic map is mx (u - 1/2) + my (v - 1/2).
    GeneratedMap base = generate_height_map("gaussian", {{"size", "128"}});
    for (int j = 0; j < 128; j += 17)
        for (int i = 0; i < 128; i += 13)
            EXPECT_NEAR(g.height.at(i, j) - base.height.at(i, j), 0.5 * (i / 128.0 - 0.5) - 0.25 * (j / 128.0 - 0.5), 1e-6);
}

TEST(GenMapGaussian, RejectsImpossibleCovariances) {
    EXPECT_EQ(gen_error("gaussian", {{"sxx", "0.1"}, {"syy", "0.1"}, {"sxy", "0.2"}}),
              "maps[0]: sxy: expected |sxy| <= sqrt(sxx * syy) = 0.1 (a covariance is positive semi-definite), got 0.2");
    EXPECT_NE(gen_error("gaussian", {{"sxx", "0.1"}, {"syy", "0.4"}, {"sxy", "0.2"}}).find("maps[0]: sxy: a degenerate"),
              std::string::npos);
    EXPECT_EQ(gen_error("gaussian", {{"size", "64"}, {"correlation", "0.01"}}),
              "maps[0]: correlation: expected at least one cell (1 / 64 = 0.015625), got 0.01");
    EXPECT_EQ(gen_error("gaussian", {{"sxx", "-1"}}), "maps[0]: sxx: expected a number in [0, 1000000], got '-1'");
}

TEST(GenMapFacets, VGrooveSlopesAreTanAngle) {
    for (const char *axis : {"u", "v"}) {
        GeneratedMap g = generate_height_map("vgroove", {{"size", "64"}, {"periods", "4"}, {"angle", "30"}, {"axis", axis}});
        const double t = std::tan(30 * 3.14159265358979 / 180);
        bool along_u = std::string(axis) == "u";
        for (int j = 0; j < 64; ++j)
            for (int i = 0; i < 64; ++i) {
                double su, sv;
                cell_slope(g.height, i, j, su, sv);
                int k = along_u ? i : j;  // 16 cells per period: 8 rising, 8 falling
                double expect = (k % 16) < 8 ? t : -t;
                ASSERT_NEAR(along_u ? su : sv, expect, 1e-5 * t) << axis << " cell " << i << "," << j;
                ASSERT_NEAR(along_u ? sv : su, 0, 1e-6);
            }
        HeightMapStats st = height_map_stats(g.height);
        EXPECT_NEAR(st.max, t * 0.25 / 2, 1e-7);  // depth = tan(angle) * period / 2
        EXPECT_EQ(st.min, 0);
        EXPECT_TRUE(g.notes.empty());
    }
}

TEST(GenMapFacets, SawtoothAlbedoFollowsTheFacets) {
    // 96 cells, 3 periods: 32 cells per period; angles 30/60 make facet a 3/4 of it (24 cells).
    GeneratedMap g = generate_height_map("sawtooth", {{"width", "96"}, {"height", "8"}, {"periods", "3"}, {"angle_a", "30"},
                                                      {"angle_b", "60"}, {"albedo_a", "0.9,0.1,0.1"},
                                                      {"albedo_b", "0.1,0.1,0.9"}});
    ASSERT_EQ(g.albedo.width, 96);
    ASSERT_EQ(g.albedo.height, 8);
    const double ta = std::tan(3.14159265358979 / 6), tb = std::tan(3.14159265358979 / 3);
    int cells_a = 0;
    for (int j = 0; j < 8; ++j)
        for (int i = 0; i < 96; ++i) {
            double su, sv;
            cell_slope(g.height, i, j, su, sv);
            bool a = i % 32 < 24;
            ASSERT_NEAR(su, a ? ta : -tb, 1e-5) << i;
            Spectrum c = g.albedo.rgb(i, j);  // texel i covers cell i (vertices i..i+1)
            ASSERT_FLOAT_EQ(c.r, a ? 0.9f : 0.1f) << i;
            ASSERT_FLOAT_EQ(c.b, a ? 0.1f : 0.9f) << i;
            cells_a += a && j == 0;
        }
    EXPECT_EQ(cells_a, 72);
    // Facet edges inside cells: reported, and the albedo takes the facet with most of the cell.
    GeneratedMap s = generate_height_map("sawtooth", {{"size", "100"}, {"periods", "3"}});
    ASSERT_EQ(s.notes.size(), 1u);
    EXPECT_NE(s.notes[0].find("straddle"), std::string::npos);
    for (int i = 0; i < 100; ++i) {
        double su, sv;
        cell_slope(s.height, i, 0, su, sv);
        // A straddling cell's slope is the blend; more than halfway to facet a's slope = mostly a.
        bool mostly_a = su > 0.5 * (ta - tb);
        EXPECT_EQ(s.albedo.rgb(i, 0).r, mostly_a ? 0.8f : 0.2f) << i;
    }
    EXPECT_NE(gen_error("vgroove", {{"size", "16"}, {"periods", "9"}}).find("maps[0]: periods: expected every facet"),
              std::string::npos);
}

TEST(GenMapWeave, TwillAndSatinTileAndColourTheYarns) {
    GeneratedMap t = generate_height_map("twill", {{"size", "96"}, {"yarns", "12"}});
    GeneratedMap s = generate_height_map("satin", {{"size", "100"}, {"yarns", "10"}});
    for (GeneratedMap *g : {&t, &s}) {
        ASSERT_EQ(g->albedo.width, g->height.width);
        HeightMapStats st = height_map_stats(g->height);
        EXPECT_LT(st.min, st.max);
        int warp = 0;
        for (int k = 0; k < g->albedo.width * g->albedo.height; ++k) warp += g->albedo.data[3 * k] > 0.5f;
        double frac = double(warp) / (g->albedo.width * g->albedo.height);
        EXPECT_GT(frac, 0.3);  // warp-faced: most of the visible surface is warp
        EXPECT_LT(frac, 0.95);
    }
    // 2/1 twill: the pattern depends on (warp + weft) yarn index only, so moving one yarn
    // (8 texels) along u and one back along v gives the same surface: the diagonal.
    for (int i = 0; i < 96; ++i) EXPECT_NEAR(t.height.at(i, 20), t.height.wrapped(i + 8, 12), 1e-7) << i;
    EXPECT_EQ(gen_error("twill", {{"yarns", "16"}}),
              "maps[0]: yarns: expected a multiple of over + under = 3 so that the weave tiles, got 16");
    EXPECT_NE(gen_error("satin", {{"harness", "6"}, {"step", "2"}}).find("maps[0]: step: expected a step"), std::string::npos);
}

TEST(GenMapBumps, HemispheresAndRejection) {
    GeneratedMap g = generate_height_map("bumps", {{"size", "128"}, {"grid", "4"}, {"radius", "0.1"}});
    // Grid bumps without jitter: centre of the first at (1/8, 1/8) = vertex (16, 16), height = r.
    EXPECT_NEAR(g.height.at(16, 16), 0.1, 1e-6);
    EXPECT_NEAR(g.height.at(16 + 8, 16), std::sqrt(0.01 - 0.0625 * 0.0625), 1e-6);
    EXPECT_EQ(g.height.at(0, 0), 0.f);
    GeneratedMap r = generate_height_map("bumps", {{"size", "64"}, {"count", "500"}, {"radius", "0.1"}, {"overlap", "reject"}});
    ASSERT_EQ(r.notes.size(), 1u);  // not all fit
    EXPECT_NE(r.notes[0].find("of 500 bumps"), std::string::npos);
    EXPECT_EQ(gen_error("bumps", {{"grid", "4"}, {"count", "3"}}),
              "maps[0]: count: expected no count with grid > 0 (the grid sets the number of bumps)");
    EXPECT_EQ(gen_error("bumps", {{"overlap", "sum"}}), "maps[0]: overlap: expected one of 'max', 'reject', got 'sum'");
}

TEST(GenMapRelief, CopiesTheImageAndAddsNoise) {
    Image img(20, 10, 3);
    for (int y = 0; y < 10; ++y)
        for (int x = 0; x < 20; ++x) img.set_rgb(x, y, Spectrum(float((x * 3 + y * 7) % 11) / 10.f));
    write_exr(tmp("relief.exr"), img);
    GeneratedMap g = generate_height_map("relief", {{"image", tmp("relief.exr")}, {"scale", "0.5"}});
    ASSERT_EQ(g.height.width, 20);  // the image's size by default
    ASSERT_EQ(g.height.height, 10);
    for (int y = 0; y < 10; ++y)
        for (int x = 0; x < 20; ++x) ASSERT_NEAR(g.height.at(x, y), 0.5 * img.at(x, y, 0), 1e-6);
    GeneratedMap big = generate_height_map("relief", {{"image", tmp("relief.exr")}, {"width", "40"}, {"height", "20"}});
    EXPECT_NEAR(big.height.at(2, 2), 0.05 * img.at(1, 1, 0), 1e-6);                                  // on a pixel
    EXPECT_NEAR(big.height.at(3, 2), 0.05 * 0.5 * (img.at(1, 1, 0) + img.at(2, 1, 0)), 1e-6);         // between two
    GeneratedMap noisy = generate_height_map("relief", {{"image", tmp("relief.exr")}, {"noise_amplitude", "0.01"}});
    EXPECT_NE(noisy.height.h, g.height.h);
    EXPECT_EQ(gen_error("relief", {}), "maps[0]: image: expected the path of a grey image (relief needs one)");
    EXPECT_EQ(gen_error("relief", {{"image", tmp("nope.png")}}), tmp("nope.png") + ": cannot read image: file does not exist");
}

TEST(GenMap, BadInputErrors) {
    EXPECT_EQ(gen_error("perlin", {}), "maps[0]: unknown height-map generator 'perlin' (expected one of: fbm, gaussian, "
                                       "bumps, vgroove, sawtooth, twill, satin, relief)");
    EXPECT_EQ(gen_error("fbm", {{"octave", "3"}}),
              "maps[0]: octave: unknown parameter of generator 'fbm' (expected one of: size, width, height, seed, "
              "octaves, lacunarity, gain, frequency, amplitude)");
    EXPECT_EQ(gen_error("fbm", {{"size", "1"}}), "maps[0]: size: expected an integer in [2, 16384], got '1'");
    EXPECT_EQ(gen_error("fbm", {{"width", "3.5"}}), "maps[0]: width: expected an integer in [2, 16384], got '3.5'");
    EXPECT_EQ(gen_error("fbm", {{"gain", "abc"}}), "maps[0]: gain: expected a number in [0, 1], got 'abc'");
    EXPECT_EQ(gen_error("fbm", {{"gain", "nan"}}), "maps[0]: gain: expected a number in [0, 1], got 'nan'");
    EXPECT_EQ(gen_error("vgroove", {{"albedo_a", "1,2"}}),
              "maps[0]: albedo_a: expected an RGB reflectance 'r,g,b' with values in [0, 1], got '1,2'");
    EXPECT_NE(gen_error("vgroove", {{"albedo_a", "0.1,0.2,0.3,"}}).find("albedo_a: expected an RGB"), std::string::npos);
    EXPECT_NE(gen_error("vgroove", {{"albedo_b", "0.1,1.5,0.3"}}).find("albedo_b: expected an RGB"), std::string::npos);
    EXPECT_EQ(generate_height_map("vgroove", {{"size", "16"}, {"periods", "2"}, {"albedo_a", "0.5"}}).albedo.rgb(0, 0).g, 0.5f);
    EXPECT_EQ(meso_error_of([] { generate_height_map("fbm", {{"seed", "-1"}}); }),
              "seed: expected an integer in [0, 9007199254740992], got '-1'");  // no location: no prefix
}

// ---------------------------------------------------------------------------------------
// The command

TEST(GenMapCli, WritesMapRecordAlbedoAndPreview) {
    std::string out = tmp("cli_saw.exr");
    CliResult r = run_cli_captured({"genmap", "sawtooth", "--size", "64", "-p", "periods=2", "-o", out, "--albedo",
                           tmp("cli_saw_albedo.exr"), "--preview", tmp("cli_saw_preview.png")});
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_NE(r.out.find("genmap sawtooth: 64x64, min 0, max "), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("rms slope 1 (per tile)"), std::string::npos) << r.out;
    HeightMap m = read_height_map(out);
    EXPECT_EQ(m.h, generate_height_map("sawtooth", {{"size", "64"}, {"periods", "2"}}).height.h);
    EXPECT_EQ(read_image(tmp("cli_saw_albedo.exr")).width, 64);
    EXPECT_TRUE(fs::exists(tmp("cli_saw_preview.png")));
    std::ifstream f(tmp("cli_saw.json"));
    nlohmann::json rec = nlohmann::json::parse(f);
    EXPECT_EQ(rec["kind"], "sawtooth");
    EXPECT_EQ(rec["params"]["periods"], "2");
    EXPECT_EQ(rec["params"]["angle_a"], "30");  // defaults are recorded
    EXPECT_EQ(rec["seed"], 1);
    EXPECT_EQ(rec["periodic"], true);
    EXPECT_NEAR(rec["stats"]["rms_slope"].get<double>(), 1.0, 1e-5);
    EXPECT_EQ(rec["format"], "exr");
}

TEST(GenMapCli, PngOutputRecordsItsRange) {
    CliResult r = run_cli_captured({"genmap", "gaussian", "--size", "32", "--seed", "4", "-p", "correlation=0.1", "-p", "mx=0.2",
                           "-o", tmp("cli_g.png")});
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_NE(r.out.find("not periodic"), std::string::npos) << r.out;
    std::ifstream f(tmp("cli_g.json"));
    nlohmann::json rec = nlohmann::json::parse(f);
    EXPECT_EQ(rec["format"], "png16");
    EXPECT_EQ(rec["periodic"], false);
    EXPECT_EQ(rec["params"]["seed"], "4");
    GeneratedMap g = generate_height_map("gaussian", {{"size", "32"}, {"seed", "4"}, {"correlation", "0.1"}, {"mx", "0.2"}});
    double lo = rec["png_range"]["offset"], scale = rec["png_range"]["scale"];
    HeightMap back = read_height_map(tmp("cli_g.png"));
    for (size_t k = 0; k < back.h.size(); ++k) EXPECT_NEAR(lo + scale * back.h[k], g.height.h[k], scale / 65535);
}

TEST(GenMapCli, ListAndErrors) {
    CliResult r = run_cli_captured({"genmap", "--list"});
    ASSERT_EQ(r.code, 0);
    for (auto &g : height_map_generators()) EXPECT_NE(r.out.find(g.name + ": "), std::string::npos) << g.name;
    EXPECT_NE(r.out.find("correlation"), std::string::npos);

    r = run_cli_captured({"genmap", "fbm", "-o", tmp("cli_fbm.exr"), "--albedo", tmp("cli_fbm_albedo.exr")});
    EXPECT_EQ(r.code, 2);  // a usage error
    EXPECT_EQ(r.err, "meso: error: --albedo: generator 'fbm' makes no albedo map (vgroove, sawtooth, twill and satin do)\n");
    EXPECT_FALSE(fs::exists(tmp("cli_fbm.exr")));  // nothing written after an error

    r = run_cli_captured({"genmap", "fbm", "-o", tmp("cli_fbm.tif")});
    EXPECT_EQ(r.err, "meso: error: -o " + tmp("cli_fbm.tif") + ": expected a .exr or .png file\n");
    r = run_cli_captured({"genmap", "fbm", "-o", tmp("cli_fbm.exr"), "-p", "octaves=0"});
    EXPECT_EQ(r.err, "meso: error: fbm: octaves: expected an integer in [1, 24], got '0'\n");
    r = run_cli_captured({"genmap", "fbm", "-o", tmp("cli_fbm.exr"), "-p", "octaves"});
    EXPECT_EQ(r.err, "meso: error: -p octaves: expected key=value\n");
    r = run_cli_captured({"genmap", "fbm", "-o", tmp("cli_fbm.exr"), "--size", "32", "-p", "size=64"});
    EXPECT_EQ(r.err, "meso: error: --size and -p size=... both set size\n");
    r = run_cli_captured({"genmap", "-o", tmp("cli_fbm.exr")});
    EXPECT_EQ(r.err, "meso: error: genmap: expected a generator KIND (see meso genmap --list)\n");
    EXPECT_FALSE(fs::exists(tmp("cli_fbm.exr")));
    EXPECT_FALSE(fs::exists(tmp("cli_fbm.json")));
}

TEST(Genmap, FbmIsThePerlinSumItDocuments) {
    // fbm texel by texel against its definition, written out here without the generator's
    // gradient tables (which it builds for octaves whose lattice is smaller than the map, and
    // must read back as the same values): Σ_k amplitude gain^k noise_k(f_k (i / w, j / h)),
    // f_k = frequency lacunarity^k, Perlin gradient noise with unit gradients at angle 2π ·
    // (hash >> 11) 2^-53 per lattice point (periodic in f_k), quintic fade, scaled by √2.
    // Configurations where some octaves are tabulated and some are not; exact equality.
    struct Case { int size, frequency, lacunarity, octaves; uint64_t seed; };
    for (const Case c : {Case{64, 4, 2, 6, 1}, Case{48, 3, 3, 4, 7}, Case{40, 1, 2, 7, 12345}}) {
        const GeneratedMap g = generate_height_map("fbm", {{"size", std::to_string(c.size)}, {"frequency", std::to_string(c.frequency)},
                                                          {"lacunarity", std::to_string(c.lacunarity)}, {"octaves", std::to_string(c.octaves)},
                                                          {"gain", "0.5"}, {"amplitude", "0.02"}, {"seed", std::to_string(c.seed)}});
        const uint64_t seed = mix_bits(c.seed ^ 0x5eedf00dULL);
        auto noise = [&](double x, double y, int64_t p, uint64_t layer) {
            const double fx = std::floor(x), fy = std::floor(y), dx = x - fx, dy = y - fy;
            const int64_t i = int64_t(fx), j = int64_t(fy);
            const uint64_t key = hash_combine(seed, layer);
            auto grad = [&](int64_t a, int64_t b, double ox, double oy) {
                a = ((a % p) + p) % p, b = ((b % p) + p) % p;
                const double angle = double(hash_combine(key, uint64_t(a) * 0x100000001b3ULL ^ uint64_t(b)) >> 11) *
                                     0x1p-53 * 2 * 3.14159265358979323846;
                return std::cos(angle) * ox + std::sin(angle) * oy;
            };
            auto fade = [](double t) { return t * t * t * (t * (t * 6 - 15) + 10); };
            const double sx = fade(dx), sy = fade(dy);
            const double n00 = grad(i, j, dx, dy), n10 = grad(i + 1, j, dx - 1, dy);
            const double n01 = grad(i, j + 1, dx, dy - 1), n11 = grad(i + 1, j + 1, dx - 1, dy - 1);
            const double a = n00 + sx * (n10 - n00), b = n01 + sx * (n11 - n01);
            return double(Sqrt2) * (a + sy * (b - a));
        };
        int diff = 0;
        for (int j = 0; j < c.size; ++j)
            for (int i = 0; i < c.size; ++i) {
                double sum = 0, amp = 0.02;
                int64_t f = c.frequency;
                for (int k = 0; k < c.octaves; ++k, f *= c.lacunarity, amp *= 0.5)
                    sum += amp * noise(double(i) / c.size * f, double(j) / c.size * f, f, uint64_t(k));
                diff += g.height.at(i, j) != float(sum);
            }
        EXPECT_EQ(diff, 0) << "size " << c.size << " frequency " << c.frequency << " lacunarity " << c.lacunarity;
    }
}
