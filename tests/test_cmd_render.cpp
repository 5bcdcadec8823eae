// End-to-end tests of `meso render` through the real binary: outputs and their record,
// --plan, --time, --reference/--convergence, and bad input (one-line error, non-zero exit,
// no output written).
#include <gtest/gtest.h>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <nlohmann/json.hpp>
#include "cli_capture.h"
#include "render_test_util.h"

namespace fs = std::filesystem;
using namespace meso::test;

namespace {

using CmdResult = CliResult;

CmdResult run(const std::string &args) { return run_binary(args); }

fs::path fresh_dir(const std::string &name) {
    fs::path d = fs::temp_directory_path() / "meso_cli" / name;
    fs::remove_all(d);
    fs::create_directories(d);
    return d;
}

const char *kSmallScene = R"({
  "camera": {"type": "perspective", "origin": [0, 0, 4], "target": [0, 0, 0], "fov": 30, "width": 32, "height": 24},
  "sampler": {"type": "independent", "sample_count": 4},
  "shapes": [{"type": "sphere", "material": {"type": "diffuse", "reflectance": 0.5}}],
  "lights": [{"type": "constant", "radiance": 1}]
})";

}  // namespace

TEST(CmdRender, WritesExrPngAndRecord) {
    fs::path d = fresh_dir("basic");
    std::string scene = write_temp("cli_small.json", kSmallScene);
    CmdResult r = run("render " + scene + " -o " + (d / "img.exr").string() + " --spp 8 -q");
    ASSERT_EQ(r.code, 0) << r.out;
    ASSERT_TRUE(fs::exists(d / "img.exr"));
    ASSERT_TRUE(fs::exists(d / "img.png"));
    std::ifstream f(d / "img.json");
    nlohmann::json rec = nlohmann::json::parse(f);
    for (const char *k : {"wall_s", "spp", "rays", "rays_per_s", "peak_rss_mb", "nan_count"}) EXPECT_TRUE(rec.contains(k)) << k;
    EXPECT_EQ(rec["spp"].get<int>(), 8);
    EXPECT_EQ(rec["nan_count"].get<int>(), 0);
    EXPECT_GT(rec["rays"].get<double>(), 32 * 24 * 8 - 1);

    // The same render as reference: MSE 0; a convergence CSV with one row per pass.
    r = run("render " + scene + " -o " + (d / "same.exr").string() + " --spp 8 -q --reference " + (d / "img.exr").string() +
            " --convergence " + (d / "conv.csv").string());
    ASSERT_EQ(r.code, 0) << r.out;
    std::ifstream j(d / "same.json");
    nlohmann::json rec2 = nlohmann::json::parse(j);
    EXPECT_DOUBLE_EQ(rec2["mse"].get<double>(), 0.0);
    EXPECT_TRUE(rec2.contains("relmse"));
    std::ifstream csv(d / "conv.csv");
    std::string header, row;
    std::getline(csv, header);
    EXPECT_EQ(header, "pass,elapsed_s,spp,mse,relmse");
    int rows = 0;
    while (std::getline(csv, row)) ++rows;
    EXPECT_GE(rows, 1);
}

TEST(CmdRender, OverridesAndTimeBudget) {
    fs::path d = fresh_dir("time");
    std::string scene = write_temp("cli_small2.json", kSmallScene);
    CmdResult r = run("render " + scene + " -o " + (d / "t.exr").string() + " --time 0.3 -q -D camera.width=16");
    ASSERT_EQ(r.code, 0) << r.out;
    std::ifstream f(d / "t.json");
    nlohmann::json rec = nlohmann::json::parse(f);
    EXPECT_EQ(rec["width"].get<int>(), 16);
    EXPECT_GE(rec["spp"].get<int>(), 1);
    EXPECT_LT(rec["wall_s"].get<double>(), 1.5);
}

TEST(CmdRender, PlanPrintsAndWritesNothing) {
    fs::path d = fresh_dir("plan");
    std::string scene = write_temp("cli_small3.json", kSmallScene);
    CmdResult r = run("render " + scene + " -o " + (d / "p.exr").string() + " --plan");
    ASSERT_EQ(r.code, 0) << r.out;
    EXPECT_NE(r.out.find("sphere"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("MB"), std::string::npos) << r.out;
    EXPECT_TRUE(fs::is_empty(d));
}

TEST(CmdRender, BadInputGivesOneLineErrorAndNoOutput) {
    fs::path d = fresh_dir("bad");
    std::string out = " -o " + (d / "x.exr").string() + " -q";
    struct Case {
        std::string scene_text, expect;
    };
    const Case cases[] = {
        {R"({"camera": {"type": "perspective"}, "shapes": [{"type": "spheer"}]})", "shapes[0].type: unknown shape type 'spheer'"},
        {R"({"camera": {"type": "perspective", "fov": "wide"}})", "camera.fov: expected a number, got a string"},
        {R"({"camera": {"type": "perspective"}, "lights": [{"type": "envmap", "filename": "nope.exr"}]})", "lights[0].filename: file not found"},
        {R"({"camera": {"type": "perspective"}, "shapes": [{"type": "sphere", "radus": 2}]})", "shapes[0].radus: unknown parameter 'radus'"},
    };
    int i = 0;
    for (const Case &c : cases) {
        std::string scene = write_temp("cli_bad" + std::to_string(i++) + ".json", c.scene_text);
        CmdResult r = run("render " + scene + out);
        EXPECT_NE(r.code, 0);
        EXPECT_NE(r.out.find("meso: error: " + scene + ": " + c.expect), std::string::npos) << r.out;
        EXPECT_EQ(std::count(r.out.begin(), r.out.end(), '\n'), 1) << r.out;
        EXPECT_TRUE(fs::is_empty(d)) << c.expect;
    }
    CmdResult r = run("render /nonexistent/scene.json" + out);
    EXPECT_NE(r.code, 0);
    EXPECT_NE(r.out.find("meso: error: /nonexistent/scene.json"), std::string::npos) << r.out;
    // A malformed EXR given as reference.
    std::ofstream(d.parent_path() / "garbage.exr") << "this is not an EXR";
    std::string scene = write_temp("cli_ok.json", kSmallScene);
    r = run("render " + scene + out + " --reference " + (d.parent_path() / "garbage.exr").string());
    EXPECT_NE(r.code, 0);
    EXPECT_NE(r.out.find("garbage.exr: cannot read image"), std::string::npos) << r.out;
    EXPECT_TRUE(fs::is_empty(d));
}

TEST(CmdInfo, ListsPluginsAndEmbree) {
    CmdResult r = run("info");
    ASSERT_EQ(r.code, 0);
    for (const char *k : {"Embree 3.", "path", "diffuse", "conductor", "envmap", "sobol", "perspective"})
        EXPECT_NE(r.out.find(k), std::string::npos) << k;
}
