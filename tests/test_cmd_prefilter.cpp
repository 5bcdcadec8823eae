// `meso prefilter` end to end (src/app/cmd_prefilter.cpp, prefilter/pipeline.h): a complete
// model directory and its manifest, --wrap clamp, a `lod` block refusing a model of another
// surface, bad input named by option, and the white furnace of a built model (paper 004 Fig. 13).
#include <gtest/gtest.h>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "cli_capture.h"
#include "core/error.h"
#include "geometry/heightfield.h"
#include "geometry/heightmap_gen.h"
#include "material_test_util.h"
#include "prefilter/effective_brdf.h"
#include "prefilter/model.h"
#include "scratch_dir.h"

using namespace meso;
using namespace meso::prefilter;
using meso::test::make_material;

namespace {

/// Runs `meso prefilter` into a scratch directory (once per configuration).
std::string make_model(const std::string &name, const std::vector<std::string> &extra) {
    const std::string dir = meso::test::scratch_dir("prefilter_" + name) + "/model";
    std::vector<std::string> args{"prefilter", "-q", "-o", dir};
    args.insert(args.end(), extra.begin(), extra.end());
    meso::test::CliResult r = meso::test::run_cli_captured(args);
    EXPECT_EQ(r.code, 0) << r.err;
    return dir;
}

}  // namespace

TEST(CmdPrefilter, WritesACompleteModel) {
    const std::string dir = make_model("complete", {"--generator", "fbm", "--size", "64", "-p", "amplitude=0.02",
                                                    "--scales", "8,16", "-M", "2", "-N", "5", "--paths", "9",
                                                    "--low-paths", "9", "--seed", "5"});
    namespace fs = std::filesystem;
    for (const char *f : {"manifest.json", "level_8/h_low.exr", "level_8/lobes.exr", "level_8/T.exr", "level_8/S.exr",
                          "level_8/T_ir.exr", "level_8/S_ir.exr", "level_16/S_ir.exr"})
        EXPECT_TRUE(fs::exists(dir + "/" + f)) << f;
    PrefilteredModel m = PrefilteredModel::load(dir);
    ASSERT_EQ(m.levels.size(), 2u);
    EXPECT_EQ(m.levels[0].factor, 8);
    EXPECT_EQ(m.levels[0].width(), 8);
    EXPECT_EQ(m.levels[1].width(), 4);
    EXPECT_EQ(m.levels[0].single.N, 5);
    EXPECT_FALSE(m.levels[0].ir.empty());
    const nlohmann::json &j = m.manifest;
    EXPECT_TRUE(j.contains("meso_version"));
    EXPECT_EQ(j["parameters"]["M"], 2);
    EXPECT_EQ(j["input"]["generator"]["kind"], "fbm");
    const nlohmann::json &l0 = j["levels"][0];
    for (const char *k : {"least_squares_s", "svndf_fit_s", "scaling_s"}) EXPECT_TRUE(l0["timing"].contains(k)) << k;
    // --ndf-start children (the default): x16's fit starts from x8's lobes, x8's from its cells.
    EXPECT_EQ(j["parameters"]["ndf_start"], "children");
    EXPECT_EQ(l0["svndf"]["start"], "cells");
    EXPECT_EQ(j["levels"][1]["svndf"]["start"], "x8 children");
    EXPECT_TRUE(std::isfinite(j["levels"][1]["svndf"]["mean_log_likelihood"].get<double>()));
    // --ndf-tolerance (default 1e-5) reaches the EM: 1e-9 takes more M-steps, to a likelihood
    // at least as high.
    EXPECT_EQ(j["parameters"]["ndf_tolerance"].get<double>(), 1e-5);
    {
        const std::string tight = make_model("tight", {"--generator", "fbm", "--size", "64", "-p", "amplitude=0.02",
                                                       "--scales", "8,16", "-M", "2", "-N", "5", "--paths", "9",
                                                       "--low-paths", "9", "--seed", "5", "--ndf-tolerance", "1e-9"});
        const nlohmann::json t = PrefilteredModel::load(tight).manifest;
        EXPECT_EQ(t["parameters"]["ndf_tolerance"].get<double>(), 1e-9);
        for (int l = 0; l < 2; ++l) {
            const nlohmann::json &a = j["levels"][l]["svndf"], &b = t["levels"][l]["svndf"];
            EXPECT_GT(b["mean_em_iterations"].get<double>(), a["mean_em_iterations"].get<double>()) << l;
            EXPECT_GE(b["mean_log_likelihood"].get<double>(), a["mean_log_likelihood"].get<double>() - 1e-9) << l;
        }
    }
    EXPECT_GT(l0["S_ir_rel_std_error"]["median"].get<double>(), 0.0);
    EXPECT_TRUE(l0.contains("rank1_ir"));
    EXPECT_TRUE(l0.contains("storage_bytes"));
    // T has mean 1 per channel.
    for (int c = 0; c < 3; ++c) {
        double mean = 0;
        for (int p = 0; p < 4; ++p) mean += m.levels[0].ir.T.at(p % 2, p / 2, c) / 4;
        EXPECT_NEAR(mean, 1.0, 1e-5);
    }
}

// --wrap (issue 23): a generated map that does not tile is prefiltered as a displacement with
// "wrap": "clamp" renders it, its 2W x 2H periodic extension; a LoD block uses the model only with
// the same wrap.
TEST(CmdPrefilter, WrapClampPrefiltersThePeriodicExtension) {
    const std::string dir = make_model("wrap", {"--generator", "gaussian", "--size", "32", "-p", "mx=0.5", "-p", "sxx=0.02",
                                                "-p", "syy=0.02", "--scales", "8", "-M", "2", "-N", "4", "--paths", "4",
                                                "--low-paths", "4", "--interreflections", "off", "--tile-size", "2"});
    PrefilteredModel m = PrefilteredModel::load(dir);
    EXPECT_EQ(m.wrap, WrapMode::Clamp);
    EXPECT_EQ(m.map_width, 64);
    EXPECT_EQ(m.manifest["input"]["wrap"], "clamp");
    EXPECT_DOUBLE_EQ(m.tile_size, 4.0);  // the extension spans two tiles of the default rectangle's 2
    auto scene_with = [&](const char *wrap) {
        const std::string path = meso::test::scratch_dir("prefilter_wrap") + "/lod_" + wrap + ".json";
        std::ofstream(path) << fmt::format(R"({{"camera": {{"type": "perspective", "width": 8, "height": 8}},
          "shapes": [{{"type": "rectangle", "material": {{"type": "diffuse", "reflectance": 0.8}},
            "displacement": {{"map": {{"generator": "gaussian", "size": 32, "mx": 0.5,
            "sxx": 0.02, "syy": 0.02}}, "wrap": "{}"}}, "lod": {{"factors": [1, 8], "model": "{}"}}}}]}})",
                                           wrap, dir);
        return meso::test::run_cli_captured({"render", path, "--plan"});
    };
    meso::test::CliResult ok = scene_with("clamp");
    EXPECT_EQ(ok.code, 0) << ok.err;
    meso::test::CliResult bad = scene_with("mirror");
    EXPECT_NE(bad.code, 0);
    EXPECT_NE(bad.err.find("was made with --wrap clamp, the displacement's \"wrap\" is \"mirror\""), std::string::npos) << bad.err;
}

// Issue 21 ("no hidden conventions", bad input): a LoD block refuses a model made for another
// surface than the shape's, naming both: another map of the same size (the model records heights
// at 64 spread vertices), another height scale, another world size of a tile, another base BRDF
// (compared by value). The consistent scene loads.
TEST(CmdPrefilter, LodRefusesAModelOfAnotherSurface) {
    const std::string dir = make_model("surface", {"--generator", "fbm", "--size", "32", "--map-seed", "3", "--scales", "8",
                                                   "-M", "2", "-N", "4", "--paths", "4", "--low-paths", "4",
                                                   "--interreflections", "off", "--height-scale", "0.05", "--tile-size", "0.5"});
    EXPECT_EQ(PrefilteredModel::load(dir).map_samples.size(), size_t(kMapFingerprintSize));
    // A 2-unit rectangle with tiling 4: tiles of 0.5 world units.
    // The model's base is `meso prefilter`'s default, diffuse 0.8.
    auto scene_with = [&](const std::string &name, int seed, double scale, const std::string &tiling,
                          const char *material = R"({"type": "diffuse", "reflectance": 0.8})") {
        const std::string path = meso::test::scratch_dir("prefilter_surface") + "/" + name + ".json";
        std::ofstream(path) << fmt::format(R"({{"camera": {{"type": "perspective", "width": 8, "height": 8}},
          "shapes": [{{"type": "rectangle", "material": {}, "displacement": {{"map": {{"generator": "fbm", "size": 32, "seed": {}}},
            "scale": {}, "tiling": {}}}, "lod": {{"factors": [1, 8], "model": "{}"}}}}]}})",
                                           material, seed, scale, tiling, dir);
        return meso::test::run_cli_captured({"render", path, "--plan"});
    };
    meso::test::CliResult ok = scene_with("same", 3, 0.05, "4");
    EXPECT_EQ(ok.code, 0) << ok.err;
    meso::test::CliResult map = scene_with("map", 4, 0.05, "4");
    EXPECT_NE(map.code, 0);
    EXPECT_NE(map.err.find("shapes[0].lod.model: the model '" + dir + "' was made from another map"), std::string::npos) << map.err;
    EXPECT_NE(map.err.find("the displacement's (generator fbm"), std::string::npos) << map.err;
    meso::test::CliResult hs = scene_with("height", 3, 0.1, "4");
    EXPECT_NE(hs.code, 0);
    EXPECT_NE(hs.err.find("was made with --height-scale 0.05 but the displacement's scale is 0.1"), std::string::npos) << hs.err;
    meso::test::CliResult tile = scene_with("tile", 3, 0.05, "8");
    EXPECT_NE(tile.code, 0);
    EXPECT_NE(tile.err.find("was made with --tile-size 0.5 (world size of one tile of its map), but on this shape one tile "
                            "of the displacement's map is 0.25 x 0.25 world units"),
              std::string::npos)
        << tile.err;
    // Tiles that are not square (0.5 x 1): a model's cells are square, any size between the two fits.
    meso::test::CliResult oblong = scene_with("oblong", 3, 0.05, "[4, 2]");
    EXPECT_EQ(oblong.code, 0) << oblong.err;
    meso::test::CliResult oblong_small = scene_with("oblong_small", 3, 0.05, "[8, 16]");
    EXPECT_NE(oblong_small.err.find("one tile of the displacement's map is 0.25 x 0.125 world units"), std::string::npos)
        << oblong_small.err;
    // The same BRDF written differently is the same base; another BRDF is not.
    EXPECT_EQ(scene_with("base_same", 3, 0.05, "4", R"({"reflectance": [0.8, 0.8, 0.8], "type": "diffuse"})").code, 0);
    meso::test::CliResult base = scene_with("base", 3, 0.05, "4", R"({"type": "conductor", "material": "Au", "alpha": 0.3})");
    EXPECT_NE(base.code, 0);
    EXPECT_NE(base.err.find("was made with base material {\"reflectance\":0.8,\"type\":\"diffuse\"} but the shape's "
                            "material is another BRDF"),
              std::string::npos)
        << base.err;
}

TEST(CmdPrefilter, BadInputIsNamed) {
    auto err = [](std::vector<std::string> args) {
        args.insert(args.begin(), "prefilter");
        meso::test::CliResult r = meso::test::run_cli_captured(args);
        EXPECT_NE(r.code, 0);
        return r.err;
    };
    EXPECT_NE(err({"--generator", "fbm", "-o", "/tmp/x", "--map", "a.exr"}).find("exactly one of --map"), std::string::npos);
    EXPECT_NE(err({"--generator", "fbm", "--size", "64", "--scales", "7", "-o", "/tmp/x"}).find("factor 7"), std::string::npos);
    EXPECT_NE(err({"--generator", "fbm", "--scales", "8,4", "-o", "/tmp/x"}).find("increase"), std::string::npos);
    EXPECT_NE(err({"--generator", "fbm", "--interreflections", "maybe", "-o", "/tmp/x"})
                  .find(R"(--interreflections: expected "on" or "off", got "maybe")"),
              std::string::npos);
    EXPECT_NE(err({"--generator", "fbm", "--flow", "x", "-o", "/tmp/x"}).find(R"(--flow: expected "visible", "eq5", "lobes" or "auto", got "x")"),
              std::string::npos);
    EXPECT_NE(err({"--generator", "fbm", "--base", R"({"type": "conductor", "material": "Au", "alpha": 0})", "-o", "/tmp/x"})
                  .find("--base"),
              std::string::npos);
    EXPECT_NE(err({"--generator", "nosuch", "-o", "/tmp/x"}).find("nosuch"), std::string::npos);
    EXPECT_NE(err({"--generator", "fbm", "--reciprocity", "maybe", "-o", "/tmp/x"}).find(R"(--reciprocity: expected "off", "check" or "on", got "maybe")"),
              std::string::npos);
    EXPECT_NE(err({"--generator", "fbm", "--wrap", "tile", "-o", "/tmp/x"}).find(R"(--wrap: expected "repeat", "clamp" or "mirror", got "tile")"),
              std::string::npos);
    EXPECT_NE(err({"--generator", "fbm", "--shadow-roulette", "-1", "-o", "/tmp/x"}).find("--shadow-roulette"),
              std::string::npos);
    EXPECT_NE(err({"--generator", "fbm", "--ndf-tolerance", "nan", "-o", "/tmp/x"}).find("--ndf-tolerance"),
              std::string::npos);
    EXPECT_NE(err({"--generator", "fbm", "--ndf-tolerance", "2", "-o", "/tmp/x"}).find("--ndf-tolerance"),
              std::string::npos);
    EXPECT_NE(err({"--generator", "fbm"}).find("-o"), std::string::npos);
    EXPECT_NE(err({"--generator", "fbm", "--ndf-start", "nearest", "-o", "/tmp/x"}).find("--ndf-start"), std::string::npos);
}

namespace {
/// Paper 004 Fig. 13: a non-absorbing (white Lambertian) base on a rough map. The original's
/// effective albedo with all bounces is 1; the prefiltered model (f'_low of --flow `flow`) on h_low
/// with T S f'_low, traced with every bounce on h_low (as a path tracer does), keeps it with
/// interreflections and loses energy visibly without (R single-bounce).
void white_furnace(const std::string &flow) {
    const std::string dir = make_model(
        "furnace_" + flow, {"--generator", "fbm", "--size", "64", "-p", "amplitude=0.06", "-p", "seed=2", "--base",
                            R"({"type": "diffuse", "reflectance": 1})", "--scales", "8", "-M", "1", "-N", "15", "--paths",
                            "256", "--low-paths", "256", "--seed", "3", "--flow", flow});
    PrefilteredModel m = PrefilteredModel::load(dir);
    // The model says its lobes form averages a diffuse base's reflectance over each patch.
    EXPECT_EQ(m.manifest["parameters"].value("albedo", std::string()), "patch_mean");
    EXPECT_FALSE(m.quadrature.point_albedo);
    const PrefilteredLevel &L = m.levels[0];
    const Heightfield low(L.h_low, float(L.width()), 0.f);
    std::map<std::string, std::string> p{{"size", "64"}, {"amplitude", "0.06"}, {"seed", "2"}};
    const HeightMap fine = generate_height_map("fbm", p).height;
    const Heightfield orig(fine, float(fine.width), 0.f);
    auto white = make_material(R"({"type": "diffuse", "reflectance": 1})");
    EffectiveBrdfEstimator::Options mo;
    mo.macro_frame = true;
    const size_t n = 40000;
    double worst_ir = 1e9, worst_single = 1e9, best_single = 0, mean_ir = 0;
    for (double theta_deg : {0.0, 30.0, 60.0, 75.0}) {
        const double t = theta_deg * M_PI / 180;
        const Vec3 wo(float(std::sin(t)), 0.f, float(std::cos(t)));
        const auto a_orig = EffectiveBrdfEstimator(orig, *white).albedo(PatchRegion::whole(orig), wo, n, 11, kAllBounces);
        double a[2];
        for (int k = 0; k < 2; ++k) {
            auto mat = make_material(fmt::format(R"({{"type": "prefiltered", "model": "{}", "level": 8, "scaling": "{}"}})",
                                                 dir, k == 0 ? "ir" : "single"));
            const auto e = EffectiveBrdfEstimator(low, *mat, mo).albedo(PatchRegion::whole(low), wo, n, 12, kAllBounces);
            a[k] = e.value[1];
            EXPECT_LT(e.std_error[1], 0.01);
        }
        auto mat_ir = make_material(fmt::format(R"({{"type": "prefiltered", "model": "{}", "level": 8, "scaling": "ir"}})", dir));
        const double a1 = EffectiveBrdfEstimator(low, *mat_ir, mo).albedo(PatchRegion::whole(low), wo, n, 12, 1).value[1];
        std::printf("white furnace (--flow %s) at %2.0f deg: original %.4f (+-%.4f), prefiltered with R_ir %.4f (one bounce on h_low %.4f), with R %.4f\n",
                    flow.c_str(), theta_deg, a_orig.value[1], a_orig.std_error[1], a[0], a1, a[1]);
        EXPECT_NEAR(a_orig.value[1], 1.0, 4 * a_orig.std_error[1] + 1e-3);
        worst_ir = std::min(worst_ir, a[0]);
        mean_ir += a[0] / 4;
        worst_single = std::min(worst_single, a[1]);
        best_single = std::max(best_single, a[1]);
        EXPECT_LT(a[0], 1.04);
    }
    // Paper 004 reports 0.988 (twill) and 0.999 (noise). Here (N = 15, 256 lines per wo bin),
    // eq5: 1.000, 0.971, 1.032, 1.015 at 0, 30, 60, 75 degrees (mean 1.005; earlier builds 0.985,
    // 0.979, 0.981, 1.006); the spread is the noise and the bin interpolation of S. lobes: 0.983,
    // 0.980, 0.979, 1.009 (mean 0.988). With the quadrature's node shares (multilobe_brdf.h, "View
    // weights"): eq5 1.001, 0.986, 0.973, 0.998 (mean 0.989); visible 1.003, 0.986, 0.971, 0.999.
    // With the SQUAREM NDF fit (session 35; same maximum, other rounding of every lobe) visible
    // 1.002, 0.987, 0.969, 1.000. The worst angle (60 deg) sits at 0.969-0.979 over the flows
    // and fits: the bound is 0.975 less 4 of the albedo estimate's standard errors (0.0035).
    EXPECT_GE(mean_ir, 0.98);
    EXPECT_GE(worst_ir, 0.96);
    EXPECT_LT(best_single, worst_ir);  // without interreflections energy is lost at every angle
}
}  // namespace

TEST(PrefilteredModel, WhiteFurnace) { white_furnace("eq5"); }
// The closed-form f'_low (prefilter/lobe_brdf.h): its approximation of eq. 5 is absorbed by T and S.
TEST(PrefilteredModel, WhiteFurnaceLobes) { white_furnace("lobes"); }
// --flow visible, whose absolute weights grew towards grazing ωo (multilobe_brdf.h, projected_area).
TEST(PrefilteredModel, WhiteFurnaceVisible) { white_furnace("visible"); }
