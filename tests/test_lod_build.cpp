// LodSpec parsing (lod/lod_build.h) and the one model-directory resolver (prefilter/model.h):
// what a "lod" block parses to, and that its errors name the key and what was expected.
// Building levels from a spec is covered by the scene-level tests (test_lod.cpp,
// test_prefiltered_material.cpp, test_height_transfer.cpp).
#include <gtest/gtest.h>
#include <filesystem>
#include <memory>
#include <string>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "core/properties.h"
#include "lod/lod_build.h"
#include "prefilter/model.h"
#include "scratch_dir.h"

using namespace meso;
namespace fs = std::filesystem;

namespace {

std::shared_ptr<LoadContext> context(const std::string &base_dir = "") {
    auto ctx = std::make_shared<LoadContext>();
    ctx->file = "scene.json";
    ctx->base_dir = base_dir;
    return ctx;
}

std::string parse_error(const std::string &block, const std::string &base_dir = "") {
    const nlohmann::json j = nlohmann::json::parse(block);
    try {
        parse_lod_spec(Properties(j, "shapes[0].lod", context(base_dir)));
    } catch (const MesoError &e) {
        return e.what();
    }
    return "(no error)";
}

}  // namespace

TEST(LodBuild, ParsesDefaults) {
    const nlohmann::json j = nlohmann::json::parse(R"({"factors": [1, 4, 16]})");
    const LodSpec s = parse_lod_spec(Properties(j, "lod", context()));
    EXPECT_EQ(s.factors, (std::vector<float>{1.f, 4.f, 16.f}));
    EXPECT_EQ(s.chain.levels(), 3);
    EXPECT_EQ(s.bias, 1.f);
    EXPECT_EQ(s.blend, LodBlend::Stochastic);
    EXPECT_FALSE(s.same_model);
    EXPECT_EQ(s.transfer_filter, LodTransferFilter::Exact);
    EXPECT_FALSE(s.has_model());
    EXPECT_TRUE(s.materials.empty());
}

TEST(LodBuild, ParsesEveryKey) {
    const nlohmann::json j = nlohmann::json::parse(
        R"({"factors": [1, 2], "bias": 2.5, "blend": "blend", "transfer_filter": "gaussian",
            "materials": [{"type": "diffuse"}, {"type": "diffuse", "reflectance": 0.2}]})");
    const LodSpec s = parse_lod_spec(Properties(j, "lod", context()));
    EXPECT_EQ(s.bias, 2.5f);
    EXPECT_EQ(s.blend, LodBlend::Blend);
    EXPECT_EQ(s.transfer_filter, LodTransferFilter::Gaussian);
    ASSERT_EQ(s.materials.size(), 2u);
    EXPECT_EQ(s.materials[1].path(), "lod.materials[1]");
}

TEST(LodBuild, ErrorsNameTheKeyAndTheChoices) {
    EXPECT_NE(parse_error(R"({"factors": [1, 4], "blend": "both"})")
                  .find("scene.json: shapes[0].lod.blend: expected \"stochastic\" or \"blend\", got \"both\""),
              std::string::npos);
    EXPECT_NE(parse_error(R"({"factors": [1, 4], "transfer_filter": "box"})")
                  .find("shapes[0].lod.transfer_filter: expected \"exact\" or \"gaussian\", got \"box\""),
              std::string::npos);
    EXPECT_NE(parse_error(R"({"factors": [1, 4], "same_model": true, "transfer_filter": "gaussian"})")
                  .find("box-downsampled levels only"),
              std::string::npos);
    EXPECT_NE(parse_error(R"({"factors": [1, 4], "scaling": "ir"})").find("lod.scaling: only applies with a prefiltered"),
              std::string::npos);
    EXPECT_NE(parse_error(R"({"factors": [1, 4], "materials": [{"type": "diffuse"}]})")
                  .find("lod.materials: expected one material per level (2), got 1"),
              std::string::npos);
    EXPECT_NE(parse_error(R"({"factors": [1, 4], "bais": 2})").find("lod.bais: unknown parameter 'bais' for lod"),
              std::string::npos);
    EXPECT_NE(parse_error(R"({"factors": [2, 4]})").find("lod.factors: expected [1, f1, f2, ...]"), std::string::npos);
}

TEST(LodBuild, ModelDirectoryResolvesAgainstTheSceneDirectory) {
    const fs::path base = meso::test::scratch_dir("meso_lod_build_test");
    fs::create_directories(base / "models" / "m");
    const nlohmann::json j = nlohmann::json::parse(R"({"model": "models/m"})");
    EXPECT_EQ(prefilter::resolve_model_dir(Properties(j, "lod", context(base.string()))),
              fs::weakly_canonical(base / "models" / "m").string());
    const std::string missing = parse_error(R"({"factors": [1, 4], "model": "nowhere"})", base.string());
    EXPECT_NE(missing.find("shapes[0].lod.model: model directory not found"), std::string::npos) << missing;
    EXPECT_NE(missing.find("meso prefilter"), std::string::npos) << missing;
    EXPECT_NE(parse_error(R"({"factors": [1, 4], "model": "models/m", "same_model": true})", base.string())
                  .find("lod.same_model: cannot be combined with \"model\""),
              std::string::npos);
}
