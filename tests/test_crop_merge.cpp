// `meso render --crop` and `meso merge` (issue 10, docs/cluster.md "Very large images"), run
// in-process: a crop's pixels are bit-identical to the same pixels of a full render with the same
// seed and spp; merging crops that tile the image gives the full render bit for bit; bad windows
// and parts that do not belong together are clear errors that leave no output.
#include <gtest/gtest.h>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include "cli_capture.h"
#include "image/image.h"
#include "render_test_util.h"
#include "scratch_dir.h"

namespace fs = std::filesystem;
using namespace meso;
using namespace meso::test;
using nlohmann::json;

namespace {

// 40 x 30, a sphere on a plane under an environment and a point light (some pixels see the sky,
// so the image has edges and varied values); Sobol samples.
const char *kScene = R"({
  "camera": {"type": "perspective", "origin": [0, 1, 4], "target": [0, 0, 0], "fov": 40, "width": 40, "height": 30},
  "sampler": {"type": "sobol", "sample_count": 4},
  "shapes": [
    {"type": "sphere", "radius": 0.8, "material": {"type": "diffuse", "reflectance": [0.7, 0.4, 0.2]}},
    {"type": "sphere", "center": [0, -101, 0], "radius": 100, "material": {"type": "diffuse", "reflectance": 0.5}}
  ],
  "lights": [{"type": "constant", "radiance": 0.5}, {"type": "point", "position": [2, 3, 2], "intensity": 20}]
})";

std::string scene_path() {
    static std::string p = write_temp("crop_merge_scene.json", kScene);
    return p;
}

/// A fresh directory for one test.
fs::path dir(const std::string &name) {
    fs::path d = fs::path(scratch_dir("meso_crop_merge")) / name;
    fs::remove_all(d);
    fs::create_directories(d);
    return d;
}

CliResult render(const fs::path &out, int spp, int seed, const std::vector<std::string> &extra = {}) {
    std::vector<std::string> args = {"render", scene_path(), "-o", out.string(), "--spp", std::to_string(spp),
                                     "--seed", std::to_string(seed), "-q"};
    args.insert(args.end(), extra.begin(), extra.end());
    return run_cli_captured(args);
}

std::string crop_arg(const std::array<int, 4> &c) {
    return std::to_string(c[0]) + "," + std::to_string(c[1]) + "," + std::to_string(c[2]) + "," + std::to_string(c[3]);
}

json read_json(const fs::path &p) {
    std::ifstream f(p);
    return json::parse(f);
}

/// Number of values of `part` that differ bitwise from the window of `full` at (x0, y0).
size_t bit_differences(const Image &full, const Image &part, int x0, int y0) {
    size_t diff = 0;
    for (int y = 0; y < part.height; ++y)
        for (int x = 0; x < part.width; ++x)
            for (int c = 0; c < 3; ++c) {
                float a = full.at(x0 + x, y0 + y, c), b = part.at(x, y, c);
                diff += std::memcmp(&a, &b, sizeof(float)) != 0;
            }
    return diff;
}

bool no_outputs(const fs::path &exr) {
    fs::path png = exr, js = exr;
    png.replace_extension(".png");
    js.replace_extension(".json");
    return !fs::exists(exr) && !fs::exists(png) && !fs::exists(js) && !fs::exists(js.string() + ".tmp");
}

constexpr int kSpp = 8, kSeed = 11;

/// The full render every test compares against (rendered once).
const fs::path &full_render() {
    static fs::path p = [] {
        fs::path d = dir("full");
        CliResult r = render(d / "full.exr", kSpp, kSeed);
        EXPECT_EQ(r.code, 0) << r.err;
        return d / "full.exr";
    }();
    return p;
}

}  // namespace

TEST(CropMerge, CropPixelsAreThoseOfTheFullRender) {
    Image full = read_image(full_render().string());
    ASSERT_EQ(full.width, 40);
    ASSERT_EQ(full.height, 30);
    fs::path d = dir("crops");
    const std::array<int, 4> crops[] = {{0, 0, 40, 30}, {3, 5, 20, 17}, {39, 29, 40, 30}, {0, 0, 1, 30},
                                        {17, 0, 40, 13}, {11, 7, 12, 29}, {8, 9, 37, 28}};
    int i = 0;
    for (const auto &c : crops) {
        fs::path out = d / ("crop" + std::to_string(i++) + ".exr");
        CliResult r = render(out, kSpp, kSeed, {"--crop", crop_arg(c)});
        ASSERT_EQ(r.code, 0) << crop_arg(c) << ": " << r.err;
        Image part = read_image(out.string());
        ASSERT_EQ(part.width, c[2] - c[0]) << crop_arg(c);
        ASSERT_EQ(part.height, c[3] - c[1]) << crop_arg(c);
        EXPECT_EQ(bit_differences(full, part, c[0], c[1]), 0u) << crop_arg(c);
        json rec = read_json(fs::path(out).replace_extension(".json"));
        EXPECT_EQ(rec["crop"], json(c)) << crop_arg(c);
        EXPECT_EQ(rec["full_width"], 40);
        EXPECT_EQ(rec["full_height"], 30);
        EXPECT_EQ(rec["width"], c[2] - c[0]);
        EXPECT_EQ(rec["height"], c[3] - c[1]);
        EXPECT_EQ(rec["spp"], kSpp);
        EXPECT_EQ(rec["seed"], kSeed);
        for (const char *k : {"wall_s", "rays", "rays_per_s", "peak_rss_mb", "nan_count", "scene", "defines"})
            EXPECT_TRUE(rec.contains(k)) << k;
        EXPECT_TRUE(fs::exists(fs::path(out).replace_extension(".png")));
    }
    // A full render's record has no crop.
    json rec = read_json(fs::path(full_render()).replace_extension(".json"));
    EXPECT_FALSE(rec.contains("crop"));
    EXPECT_FALSE(rec.contains("full_width"));
}

TEST(CropMerge, CropIsExactAcrossPassSizesAndThreads) {
    // 64 spp: the full 40x30 image takes two passes (55 spp each), a 5x4 window one; 1 vs 2 threads.
    auto scene = load_json_scene("crop_merge_api.json", kScene);
    RenderResult full = render_scene(*scene, 64, 2, 5);
    RenderOptions o;
    o.spp = 64;
    o.seed = 5;
    o.threads = 1;
    o.progress = false;
    o.crop = std::array<int, 4>{30, 20, 35, 24};
    RenderResult part = render(*scene, o);
    EXPECT_GT(full.passes, part.passes);
    ASSERT_EQ(part.image.width, 5);
    ASSERT_EQ(part.image.height, 4);
    EXPECT_EQ(part.spp, 64);
    EXPECT_EQ(bit_differences(full.image, part.image, 30, 20), 0u);
    // The renderer checks the window too.
    o.crop = std::array<int, 4>{0, 0, 41, 30};
    EXPECT_NE(meso_error_of([&] { render(*scene, o); }).find("--crop"), std::string::npos);
}

TEST(CropMerge, CropWithReference) {
    fs::path d = dir("reference");
    const std::string full = full_render().string();
    // The reference as the full image (its window is compared) ...
    CliResult r = render(d / "a.exr", kSpp, kSeed, {"--crop", "5,6,25,20", "--reference", full});
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_EQ(read_json(d / "a.json")["mse"].get<double>(), 0.0);
    // ... or the window's size.
    r = render(d / "b.exr", kSpp, kSeed, {"--crop", "5,6,25,20", "--reference", (d / "a.exr").string()});
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_EQ(read_json(d / "b.json")["mse"].get<double>(), 0.0);
    // Anything else is an error.
    r = render(d / "c.exr", kSpp, kSeed, {"--crop", "5,6,24,20", "--reference", (d / "a.exr").string()});
    EXPECT_NE(r.code, 0);
    EXPECT_NE(r.err.find("20x14"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("--crop"), std::string::npos) << r.err;
    EXPECT_TRUE(no_outputs(d / "c.exr"));
}

TEST(CropMerge, BadCropIsAnErrorNamingTheOption) {
    fs::path d = dir("badcrop");
    fs::path out = d / "bad.exr";
    for (const char *bad : {"", "1,2,3", "a,b,c,d", "1,2,3,4,5", "1.5,0,3,4", "1,,3,4", " 1,2,3,4", "1,2,3,4,"}) {
        CliResult r = render(out, kSpp, kSeed, {"--crop", bad});
        EXPECT_NE(r.code, 0) << bad;
        EXPECT_NE(r.err.find("--crop"), std::string::npos) << bad << ": " << r.err;
        EXPECT_NE(r.err.find("X0,Y0,X1,Y1"), std::string::npos) << bad << ": " << r.err;
        EXPECT_TRUE(no_outputs(out)) << bad;
    }
    for (const char *bad : {"0,0,41,30", "0,0,40,31", "5,0,5,30", "6,0,5,30", "-1,0,10,10", "0,3,10,2", "40,0,41,1"}) {
        CliResult r = render(out, kSpp, kSeed, {"--crop", bad});
        EXPECT_NE(r.code, 0) << bad;
        EXPECT_NE(r.err.find("--crop"), std::string::npos) << bad << ": " << r.err;
        EXPECT_NE(r.err.find("40x30"), std::string::npos) << bad << ": " << r.err;
        EXPECT_TRUE(no_outputs(out)) << bad;
    }
}

namespace {

/// Renders the windows into d/part<i>.exr and returns the parts' paths.
std::vector<std::string> render_parts(const fs::path &d, const std::vector<std::array<int, 4>> &crops, int spp = kSpp,
                                      int seed = kSeed, const std::string &prefix = "part") {
    std::vector<std::string> parts;
    for (size_t i = 0; i < crops.size(); ++i) {
        fs::path out = d / (prefix + std::to_string(i) + ".exr");
        CliResult r = render(out, spp, seed, {"--crop", crop_arg(crops[i])});
        EXPECT_EQ(r.code, 0) << r.err;
        parts.push_back(out.string());
    }
    return parts;
}

CliResult merge(const fs::path &out, const std::vector<std::string> &parts) {
    std::vector<std::string> args = {"merge", out.string()};
    args.insert(args.end(), parts.begin(), parts.end());
    return run_cli_captured(args);
}

}  // namespace

TEST(CropMerge, MergeEqualsTheFullRender) {
    Image full = read_image(full_render().string());
    json full_rec = read_json(fs::path(full_render()).replace_extension(".json"));
    const std::vector<std::vector<std::array<int, 4>>> tilings = {
        {{0, 0, 17, 30}, {17, 0, 40, 30}},                                     // two columns
        {{0, 0, 40, 7}, {0, 7, 40, 8}, {0, 8, 40, 30}},                        // three rows, one a single row
        {{23, 11, 40, 30}, {0, 0, 23, 11}, {23, 0, 40, 11}, {0, 11, 23, 30}},  // quadrants, out of order
    };
    int t = 0;
    for (const auto &crops : tilings) {
        fs::path d = dir("merge" + std::to_string(t++));
        std::vector<std::string> parts = render_parts(d, crops);
        CliResult r = merge(d / "merged.exr", parts);
        ASSERT_EQ(r.code, 0) << r.err;
        Image m = read_image((d / "merged.exr").string());
        ASSERT_EQ(m.width, 40);
        ASSERT_EQ(m.height, 30);
        EXPECT_EQ(bit_differences(full, m, 0, 0), 0u) << "tiling " << t - 1;
        EXPECT_TRUE(fs::exists(d / "merged.png"));
        EXPECT_FALSE(fs::exists(d / "merged.json.tmp"));

        json rec = read_json(d / "merged.json");
        EXPECT_FALSE(rec.contains("crop"));
        EXPECT_FALSE(rec.contains("full_width"));
        EXPECT_EQ(rec["width"], 40);
        EXPECT_EQ(rec["height"], 30);
        for (const char *k : {"spp", "seed", "scene", "defines", "integrator", "sampler", "meso_version"})
            EXPECT_EQ(rec[k], full_rec[k]) << k;
        ASSERT_EQ(rec["parts"].size(), crops.size());
        uint64_t rays = 0;
        double wall = 0, wall_max = 0;
        for (size_t i = 0; i < crops.size(); ++i) {
            json pr = read_json(fs::path(parts[i]).replace_extension(".json"));
            rays += pr["rays"].get<uint64_t>();
            wall += pr["wall_s"].get<double>();
            wall_max = std::max(wall_max, pr["wall_s"].get<double>());
            EXPECT_EQ(rec["parts"][i]["file"], parts[i]);
            EXPECT_EQ(rec["parts"][i]["crop"], json(crops[i]));
        }
        EXPECT_EQ(rec["rays"].get<uint64_t>(), rays);
        EXPECT_DOUBLE_EQ(rec["wall_s"].get<double>(), wall);
        EXPECT_DOUBLE_EQ(rec["wall_s_max"].get<double>(), wall_max);
        // Every sample is a camera ray: the parts' rays add up to the full render's.
        EXPECT_EQ(rays, full_rec["rays"].get<uint64_t>());
    }
    // A full render alone is a (trivial) part.
    fs::path d = dir("merge_single");
    CliResult r = merge(d / "one.exr", {full_render().string()});
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_EQ(bit_differences(full, read_image((d / "one.exr").string()), 0, 0), 0u);
}

TEST(CropMerge, MergeErrorsLeaveNoOutput) {
    fs::path d = dir("merge_errors");
    std::vector<std::string> left = render_parts(d, {{0, 0, 20, 30}}, kSpp, kSeed, "left");
    std::vector<std::string> right = render_parts(d, {{20, 0, 40, 30}}, kSpp, kSeed, "right");
    std::vector<std::string> wide = render_parts(d, {{19, 0, 40, 30}}, kSpp, kSeed, "wide");
    std::vector<std::string> narrow = render_parts(d, {{21, 0, 40, 30}}, kSpp, kSeed, "narrow");
    std::vector<std::string> short_right = render_parts(d, {{20, 0, 40, 29}}, kSpp, kSeed, "short");
    std::vector<std::string> other_seed = render_parts(d, {{20, 0, 40, 30}}, kSpp, kSeed + 1, "seed");
    std::vector<std::string> other_spp = render_parts(d, {{20, 0, 40, 30}}, kSpp * 2, kSeed, "spp");
    fs::path out = d / "merged.exr";

    auto expect_error = [&](const std::vector<std::string> &parts, const std::vector<std::string> &needles) {
        CliResult r = merge(out, parts);
        EXPECT_NE(r.code, 0);
        for (const auto &n : needles) EXPECT_NE(r.err.find(n), std::string::npos) << "missing '" << n << "' in: " << r.err;
        EXPECT_TRUE(no_outputs(out)) << r.err;
    };
    // Sanity: the good pair merges (then the output is removed again for the error cases).
    ASSERT_EQ(merge(out, {left[0], right[0]}).code, 0);
    for (const char *ext : {".exr", ".png", ".json"}) fs::remove(fs::path(out).replace_extension(ext));

    expect_error({left[0], wide[0]}, {"overlap", left[0], wide[0], "(19, 0)"});
    expect_error({left[0], narrow[0]}, {"do not cover", "40x30", "(20, 0)"});
    expect_error({left[0], short_right[0]}, {"do not cover", "(20, 29)"});
    expect_error({left[0]}, {"do not cover", "(20, 0)"});
    expect_error({left[0], other_seed[0]}, {other_seed[0], "\"seed\"", "12", "11"});
    expect_error({left[0], other_spp[0]}, {other_spp[0], "\"spp\"", "16"});
    expect_error({left[0], left[0], right[0]}, {"overlap"});

    // A part without its record.
    fs::path orphan = d / "orphan.exr";
    fs::copy_file(right[0], orphan);
    expect_error({left[0], orphan.string()}, {orphan.string(), "missing record", "orphan.json"});
    // A record whose crop does not match the image.
    fs::path liar = d / "liar.exr";
    fs::copy_file(narrow[0], liar);
    fs::copy_file(fs::path(right[0]).replace_extension(".json"), fs::path(liar).replace_extension(".json"));
    expect_error({left[0], liar.string()}, {liar.string(), "19x30", "20x30"});
    // A record that is not JSON.
    fs::path broken = d / "broken.exr";
    fs::copy_file(right[0], broken);
    std::ofstream(fs::path(broken).replace_extension(".json")) << "{ not json";
    expect_error({left[0], broken.string()}, {"broken.json", "JSON"});
    // Missing part, bad output name, output over a part.
    expect_error({left[0], (d / "nothere.exr").string()}, {"nothere.exr"});
    CliResult r = merge(d / "merged.png", {left[0], right[0]});
    EXPECT_NE(r.code, 0);
    EXPECT_NE(r.err.find(".exr"), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(d / "merged.png"));
    r = merge(left[0], {left[0], right[0]});
    EXPECT_NE(r.code, 0);
    EXPECT_NE(r.err.find("overwrite"), std::string::npos) << r.err;
}
