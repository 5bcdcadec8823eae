// `meso material eval | albedo | chi2`: output format and error messages, run in-process
// through meso::run_cli.
#include <gtest/gtest.h>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>
#include "cli_capture.h"

namespace {

using meso::test::CliResult;
meso::test::CliResult run(std::vector<std::string> args) { return meso::test::run_cli_captured(std::move(args)); }

TEST(CmdMaterial, EvalPrintsValueAndPdf) {
    CliResult r = run({"material", "eval", R"({"type":"diffuse","reflectance":0.5})", "--wo", "0,0", "--wi", "60,45"});
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_EQ(r.out.rfind("{\"value\":[", 0), 0u) << r.out;  // key order as documented
    auto j = nlohmann::json::parse(r.out);
    ASSERT_EQ(j["value"].size(), 3u);
    EXPECT_NEAR(j["value"][1].get<double>(), 0.5 / M_PI * 0.5, 1e-6);
    EXPECT_NEAR(j["pdf"].get<double>(), 0.5 / M_PI, 1e-6);
    EXPECT_EQ(r.out.back(), '\n');
}

TEST(CmdMaterial, EvalBelowHorizonIsZero) {
    CliResult r = run({"material", "eval", R"({"type":"conductor","alpha":0.2})", "--wo", "30,0", "--wi", "120,180"});
    ASSERT_EQ(r.code, 0) << r.err;
    auto j = nlohmann::json::parse(r.out);
    EXPECT_EQ(j["value"][0].get<double>(), 0.0);
    EXPECT_EQ(j["pdf"].get<double>(), 0.0);
}

TEST(CmdMaterial, AlbedoOfWhiteDiffuseIsOne) {
    CliResult r = run({"material", "albedo", R"({"type":"diffuse","reflectance":1})", "--wo", "45,10", "--samples", "5000",
                       "--seed", "3"});
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_EQ(r.out.rfind("{\"albedo\":[", 0), 0u) << r.out;
    auto j = nlohmann::json::parse(r.out);
    for (int c = 0; c < 3; ++c) {
        EXPECT_NEAR(j["albedo"][c].get<double>(), 1.0, 1e-6);
        EXPECT_NEAR(j["stderr"][c].get<double>(), 0.0, 1e-6);
    }
}

TEST(CmdMaterial, AlbedoOfRoughGoldHasAnError) {
    CliResult r = run({"material", "albedo", R"({"type":"conductor","material":"Au","alpha":0.5})", "--wo", "60,0",
                       "--samples", "20000"});
    ASSERT_EQ(r.code, 0) << r.err;
    auto j = nlohmann::json::parse(r.out);
    double a = j["albedo"][0].get<double>(), se = j["stderr"][0].get<double>();
    EXPECT_GT(a, 0.5);
    EXPECT_LT(a, 1.0);
    EXPECT_GT(se, 0.0);
    EXPECT_LT(se, 0.01);
}

TEST(CmdMaterial, Chi2Passes) {
    CliResult r = run({"material", "chi2", R"({"type":"conductor","alpha":0.3})", "--wo", "40,10", "--samples", "100000",
                       "--seed", "7"});
    ASSERT_EQ(r.code, 0) << r.out << r.err;
    EXPECT_EQ(r.out.rfind("{\"p_value\":", 0), 0u) << r.out;
    auto j = nlohmann::json::parse(r.out);
    EXPECT_TRUE(j["passed"].get<bool>());
    EXPECT_GT(j["p_value"].get<double>(), 0.0);
    EXPECT_LE(j["p_value"].get<double>(), 1.0);
    EXPECT_EQ(j["samples"].get<int>(), 100000);
    EXPECT_EQ(j["weight_mismatch"].get<int>(), 0);
    EXPECT_EQ(j["domain"].get<std::string>(), "hemisphere");
}

TEST(CmdMaterial, MaterialFromFile) {
    auto path = std::filesystem::temp_directory_path() / "meso_test_cmd_material.json";
    {
        std::ofstream f(path);
        f << R"({"type": "dielectric", "int_ior": "bk7", "alpha": 0.2})";
    }
    CliResult r = run({"material", "chi2", path.string(), "--wo", "150,0", "--samples", "50000"});
    std::filesystem::remove(path);
    ASSERT_EQ(r.code, 0) << r.out << r.err;
    auto j = nlohmann::json::parse(r.out);
    EXPECT_TRUE(j["passed"].get<bool>());
    EXPECT_EQ(j["domain"].get<std::string>(), "sphere");
}

TEST(CmdMaterial, BadInputStopsWithOneLocatedLine) {
    CliResult r = run({"material", "eval", R"({"type":"diffuse",)", "--wo", "0,0", "--wi", "0,0"});
    EXPECT_EQ(r.code, 1);
    EXPECT_EQ(r.out, "");
    EXPECT_EQ(r.err.rfind("meso: error: <inline material>: invalid JSON: parse error at line 1, column 19", 0), 0u) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1);

    r = run({"material", "eval", R"({"type":"velvet"})", "--wo", "0,0", "--wi", "0,0"});
    EXPECT_EQ(r.code, 1);
    EXPECT_EQ(r.err.rfind("meso: error: <inline material>: type: unknown material type 'velvet' (known: ", 0), 0u) << r.err;

    r = run({"material", "albedo", "/nonexistent/dir/gold.json", "--wo", "0,0"});
    EXPECT_EQ(r.code, 1);
    EXPECT_EQ(r.err, "meso: error: /nonexistent/dir/gold.json: cannot open the material file (file not found)\n");

    r = run({"material", "eval", R"({"type":"conductor","alpha":0.1,"roughness":0.3})", "--wo", "0,0", "--wi", "0,0"});
    EXPECT_EQ(r.code, 1);
    EXPECT_EQ(r.err, "meso: error: <inline material>: roughness: unknown parameter 'roughness' for material 'conductor'\n");

    r = run({"material", "eval", R"({"type":"diffuse"})", "--wo", "abc", "--wi", "0,0"});
    EXPECT_EQ(r.code, 1);
    EXPECT_EQ(r.err, "meso: error: --wo: expected THETA,PHI in degrees, got 'abc'\n");

    r = run({"material", "eval", R"([1, 2])", "--wo", "0,0", "--wi", "0,0"});
    EXPECT_EQ(r.code, 1);
    EXPECT_EQ(r.err, "meso: error: <inline material>: expected a JSON object describing one material\n");
}

TEST(CmdMaterial, HelpForEachSubcommand) {
    for (const char *sub : {"eval", "albedo", "chi2"}) {
        CliResult r = run({"material", sub, "--help"});
        EXPECT_EQ(r.code, 0);
        EXPECT_NE(r.out.find("MATERIAL"), std::string::npos) << sub;
        EXPECT_NE(r.out.find("--wo"), std::string::npos) << sub;
    }
}

}  // namespace
