// Issue 24: nothing lost. Every command that writes files refuses, before any work, an output that
// would replace one of its inputs (or a scene beside it), an output that is a directory and an
// unwritable output folder; the outputs of a run are written together or not at all; bad option
// values are refused naming the option and the range; a film larger than the machine is refused
// with --plan's figure; EXRs carry their provenance and `meso merge` checks it. Every case runs the
// real binary and checks the exit code, the message (file and option) and that the inputs'
// checksums did not change. Interruption (SIGINT) is the CTest Cli.InterruptedRenderKeepsPasses.
#include <gtest/gtest.h>
#include <unistd.h>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <regex>
#include <sstream>
#include "cli_capture.h"
#include "core/sha1.h"
#include "image/image.h"

namespace fs = std::filesystem;
using namespace meso;
using namespace meso::test;

namespace {

const char *kScene = R"({
  "camera": {"type": "perspective", "origin": [0, 0, 4], "target": [0, 0, 0], "fov": 30, "width": 32, "height": 24},
  "sampler": {"type": "independent", "sample_count": 4},
  "shapes": [{"type": "sphere", "material": {"type": "diffuse", "reflectance": 0.5}}],
  "lights": [{"type": "constant", "radiance": 1}]
})";

/// A fresh directory with scene.json in it.
fs::path fresh(const std::string &name) {
    fs::path d = fs::temp_directory_path() / ("meso_output_safety_" + std::to_string(::getpid())) / name;
    fs::remove_all(d);
    fs::create_directories(d);
    std::ofstream(d / "scene.json") << kScene;
    return d;
}

std::string q(const fs::path &p) { return "'" + p.string() + "'"; }

/// SHA-1 of every regular file under `d` (the inputs' checksums before and after a command).
std::map<std::string, std::string> checksums(const fs::path &d) {
    std::map<std::string, std::string> m;
    for (const auto &e : fs::recursive_directory_iterator(d))
        if (e.is_regular_file()) m[e.path().string()] = file_sha1(e.path().string());
    return m;
}

/// No staged temporary left anywhere under `d`.
bool no_temporaries(const fs::path &d) {
    for (const auto &e : fs::recursive_directory_iterator(d))
        if (e.path().filename().string().find(".meso-tmp-") != std::string::npos) return false;
    return true;
}

/// Runs `args`, expects exit `code` (1: an error; 2: a usage error of an option) with every needle in the message, no file changed or added, and
/// (with a huge --spp where it matters) an answer before any work.
void expect_refused(const fs::path &d, const std::string &args, const std::vector<std::string> &needles,
                    int code = 1) {
    const auto before = checksums(d);
    const auto t0 = std::chrono::steady_clock::now();
    CliResult r = run_binary(args, d.string());
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    EXPECT_EQ(r.code, code) << args << "\n" << r.out;
    EXPECT_EQ(r.out.rfind("meso: error: ", 0), 0u) << r.out;
    for (const auto &n : needles) EXPECT_NE(r.out.find(n), std::string::npos) << "missing '" << n << "' in: " << r.out;
    EXPECT_EQ(checksums(d), before) << args;
    EXPECT_TRUE(no_temporaries(d)) << args;
    EXPECT_LT(s, 20.0) << args << ": refused only after the work";
}

nlohmann::json read_json(const fs::path &p) {
    std::ifstream f(p);
    return nlohmann::json::parse(f);
}

std::string meta(const std::string &exr, const std::string &key) {
    for (const auto &[k, v] : read_image_metadata(exr))
        if (k == key) return v;
    return "(none)";
}

}  // namespace

TEST(OutputSafety, DefaultOutputNeverReplacesTheScene) {
    fs::path d = fresh("default");
    const std::string scene_sha = file_sha1((d / "scene.json").string());
    CliResult r = run_binary("render scene.json --spp 2 -q", d.string());
    ASSERT_EQ(r.code, 0) << r.out;
    EXPECT_EQ(file_sha1((d / "scene.json").string()), scene_sha);
    for (const char *f : {"scene_render.exr", "scene_render.png", "scene_render.json"}) EXPECT_TRUE(fs::exists(d / f)) << f;
    // The scene still loads (it was not replaced by the record), and a second run replaces the record.
    EXPECT_EQ(run_binary("render scene.json --spp 2 -q", d.string()).code, 0);
    EXPECT_EQ(file_sha1((d / "scene.json").string()), scene_sha);
    EXPECT_NE(run_binary("render --help").out.find("<scene stem>_render.exr"), std::string::npos);
}

TEST(OutputSafety, OutputsThatWouldReplaceAnInputAreRefused) {
    fs::path d = fresh("inputs");
    ASSERT_EQ(run_binary("render scene.json -o ref.exr --spp 2 -q", d.string()).code, 0);
    ASSERT_EQ(run_binary("render scene.json -o other.exr --spp 2 --seed 3 -q", d.string()).code, 0);
    const std::string big = " --spp 1000000 -q";
    expect_refused(d, "render scene.json -o scene.exr" + big,
                   {"-o scene.exr: the output scene.json would overwrite the input scene.json (the scene file)"});
    expect_refused(d, "render scene.json -o " + q(d / "scene.exr") + big, {(d / "scene.json").string(), "(the scene file)"});
    expect_refused(d, "render scene.json -o x.exr --reference scene.exr --convergence scene.json" + big,
                   {"--convergence scene.json: would overwrite the input scene.json (the scene file)"});
    expect_refused(d, "render scene.json -o ref.exr --reference ref.exr" + big,
                   {"-o ref.exr: would overwrite the input ref.exr (the reference)"});
    expect_refused(d, "render scene.json -o x.exr --reference ref.exr --convergence x.json" + big,
                   {"--convergence x.json: x.json is also written by -o x.exr"});
    expect_refused(d, "compare ref.png other.png --error-image ref.png",
                   {"--error-image ref.png: would overwrite the input ref.png (the test image)"});
    expect_refused(d, "compare ref.exr other.exr --error-image other.exr",
                   {"--error-image other.exr: would overwrite the input other.exr (the reference)"});
    expect_refused(d, "convert ref.exr ./ref.exr", {"output ./ref.exr: would overwrite the input ref.exr (the input image)"});
    expect_refused(d, "perf scene.json --json scene.json", {"--json scene.json: would overwrite the input scene.json"});
    expect_refused(d, "merge ref.exr ref.exr", {"output ref.exr: would overwrite the input ref.exr (a part)"});
    // A record may only replace a record: a scene beside a genmap or render output is safe.
    expect_refused(d, "genmap fbm --size 16 -o scene.exr",
                   {"-o scene.exr: would overwrite scene.json, which is not a meso record"});
    fs::create_directories(d / "sub");
    std::ofstream(d / "sub" / "other_scene.json") << kScene;
    expect_refused(d, "render scene.json -o sub/other_scene.exr" + big,
                   {"-o sub/other_scene.exr: would overwrite sub/other_scene.json, which is not a meso record"});
    // A file the scene names (a height map) is an input too.
    ASSERT_EQ(run_binary("genmap fbm --size 16 -o map.exr", d.string()).code, 0);
    std::ofstream(d / "displaced.json") << R"({
  "camera": {"type": "perspective", "origin": [0, 0, 4], "target": [0, 0, 0], "fov": 30, "width": 16, "height": 16},
  "shapes": [{"type": "rectangle", "displacement": {"map": "map.exr", "scale": 0.01},
              "material": {"type": "diffuse"}}],
  "lights": [{"type": "constant", "radiance": 1}]
})";
    expect_refused(d, "render displaced.json -o map.exr" + big, {"-o map.exr: would overwrite the input", "(a file the scene names)"});
}

TEST(OutputSafety, UnwritableOrImpossibleOutputsAreFoundBeforeTheWork) {
    fs::path d = fresh("unwritable");
    const std::string big = " --spp 1000000 -q";
    expect_refused(d, "render scene.json -o nodir/x.exr" + big, {"-o nodir/x.exr: directory 'nodir' does not exist"});
    fs::create_directories(d / "x.png");
    expect_refused(d, "render scene.json -o x.exr" + big, {"-o x.exr: x.png is a directory"});
    std::ofstream(d / "model") << "not a directory";
    expect_refused(d, "prefilter --generator fbm --base '{\"type\":\"diffuse\"}' -o model",
                   {"-o model: model exists and is not a directory"});
    fs::create_directories(d / "photos");
    std::ofstream(d / "photos" / "keep.jpg") << "x";
    expect_refused(d, "prefilter --generator fbm --base '{\"type\":\"diffuse\"}' -o photos",
                   {"-o photos: photos is a directory that is neither empty nor a previous output"});
    expect_refused(d, "genmap fbm --size 16 -o nodir/m.exr", {"-o nodir/m.exr: directory 'nodir' does not exist"});
    expect_refused(d, "genmap fbm --size 16 -o m.exr --preview x.png", {"--preview x.png: x.png is a directory"});
    // A read-only folder (not testable as root, who may write anywhere).
    fs::create_directories(d / "ro");
    fs::permissions(d / "ro", fs::perms::owner_read | fs::perms::owner_exec);
    const bool writable = ::access((d / "ro").c_str(), W_OK) == 0;
    if (!writable) expect_refused(d, "render scene.json -o ro/x.exr" + big, {"-o ro/x.exr: directory 'ro' is not writable"});
    fs::permissions(d / "ro", fs::perms::owner_all);
    if (writable) std::printf("note: running as root, who may write to a read-only folder: that case is not checked\n");
}

TEST(OutputSafety, AFailedRunLeavesThePreviousSetIntact) {
    fs::path d = fresh("all_or_nothing");
    ASSERT_EQ(run_binary("render scene.json -o out.exr --spp 2 --seed 1 -q", d.string()).code, 0);
    // OUT.png is now a folder: the new run must not replace the EXR or the record either.
    fs::remove(d / "out.png");
    fs::create_directories(d / "out.png");
    expect_refused(d, "render scene.json -o out.exr --spp 2 --seed 2 -q", {"-o out.exr: out.png is a directory"});
    EXPECT_EQ(read_json(d / "out.json")["seed"], 1);
    EXPECT_EQ(meta((d / "out.exr").string(), "seed"), "1");
    // A successful run replaces all three together and leaves no temporary.
    fs::remove(d / "out.png");
    ASSERT_EQ(run_binary("render scene.json -o out.exr --spp 2 --seed 2 -q", d.string()).code, 0);
    EXPECT_EQ(read_json(d / "out.json")["seed"], 2);
    EXPECT_EQ(meta((d / "out.exr").string(), "seed"), "2");
    EXPECT_TRUE(no_temporaries(d));
}

TEST(OutputSafety, OptionRangesAreCheckedBeforeTheWork) {
    fs::path d = fresh("ranges");
    const std::string r = "render scene.json -o x.exr -q ";
    expect_refused(d, r + "--spp 0", {"--spp 0: expected a sample count >= 1"}, 2);
    expect_refused(d, r + "--time 0", {"--time 0: expected a finite number of seconds > 0"}, 2);
    expect_refused(d, r + "--time inf", {"--time inf: expected a finite number of seconds > 0"}, 2);
    expect_refused(d, r + "--time nan", {"--time nan: expected a finite number of seconds > 0"}, 2);
    expect_refused(d, r + "--spp 1000000 --seed -5", {"--seed -5: expected a seed >= 0"}, 2);
    expect_refused(d, r + "--spp 1000000 --threads -1", {"--threads -1: expected 1 to"}, 2);
    expect_refused(d, r + "--spp 1000000 --threads 100000", {"--threads 100000: expected 1 to", "x the"}, 2);
    expect_refused(d, r + "--spp 1000000 --exposure nan", {"--exposure nan: expected a finite number of stops"}, 2);
    expect_refused(d, r + "--spp 1000000 --crop 0,0,33,24", {"--crop 0,0,33,24: the window must lie in the 32x24 image"});
    expect_refused(d, r + "--spp 1000000 --crop 0,0,1", {"--crop '0,0,1': expected X0,Y0,X1,Y1"}, 2);
    expect_refused(d, "perf scene.json --threads 0", {"--threads 0: expected 1 to"}, 2);
    expect_refused(d, "convert scene.json y.png --exposure inf", {"--exposure inf: expected a finite number of stops"}, 2);
}

TEST(OutputSafety, FilmBeyondPhysicalMemoryIsRefusedWithThePlanFigure) {
    fs::path d = fresh("memory");
    const std::string defines = " -D camera.width=65536 -D camera.height=65536";
    CliResult plan = run_binary("render scene.json --plan" + defines, d.string());
    ASSERT_EQ(plan.code, 0) << plan.out;
    std::smatch m;
    ASSERT_TRUE(std::regex_search(plan.out, m, std::regex("about ([0-9.]+) MB"))) << plan.out;
    expect_refused(d, "render scene.json -o big.exr -q" + defines,
                   {"scene.json: the render needs about " + m[1].str() + " MB", "65536x65536 film", "physical memory"});
}

TEST(OutputSafety, RenderedExrsCarryTheirProvenance) {
    EXPECT_EQ(sha1_hex("abc"), "a9993e364706816aba3e25717850c26c9cd0d89d");  // FIPS 180 test vector
    EXPECT_EQ(sha1_hex(""), "da39a3ee5e6b4b0d3255bfef95601890afd80709");
    fs::path d = fresh("provenance");
    ASSERT_EQ(run_binary("render scene.json -o p.exr --spp 3 --seed 9 --crop 4,2,20,12 -q", d.string()).code, 0);
    const std::string exr = (d / "p.exr").string();
    EXPECT_EQ(meta(exr, "scene_sha1"), file_sha1((d / "scene.json").string()));
    EXPECT_EQ(meta(exr, "seed"), "9");
    EXPECT_EQ(meta(exr, "spp"), "3");
    EXPECT_EQ(meta(exr, "crop"), "4,2,20,12");
    EXPECT_EQ(meta(exr, "full_size"), "32x24");
    EXPECT_NE(meta(exr, "version"), "(none)");
    EXPECT_EQ(read_json(d / "p.json")["scene_sha1"], meta(exr, "scene_sha1"));
    // convert keeps the metadata of an EXR.
    ASSERT_EQ(run_binary("convert p.exr c.exr", d.string()).code, 0);
    EXPECT_EQ(meta((d / "c.exr").string(), "scene_sha1"), meta(exr, "scene_sha1"));
}

TEST(OutputSafety, MergeRefusesAnExrSwappedInFromAnotherRender) {
    fs::path d = fresh("merge_swap");
    std::ofstream(d / "scene2.json") << std::regex_replace(kScene, std::regex("0\\.5"), "0.25");
    const std::string part = " --spp 2 -q --crop ";
    ASSERT_EQ(run_binary("render scene.json -o left.exr" + part + "0,0,16,24", d.string()).code, 0);
    ASSERT_EQ(run_binary("render scene.json -o right.exr" + part + "16,0,32,24", d.string()).code, 0);
    ASSERT_EQ(run_binary("render scene.json -o seed5.exr --seed 5" + part + "16,0,32,24", d.string()).code, 0);
    ASSERT_EQ(run_binary("render scene2.json -o other.exr" + part + "16,0,32,24", d.string()).code, 0);
    ASSERT_EQ(run_binary("merge ok.exr left.exr right.exr", d.string()).code, 0);
    fs::copy_file(d / "right.json", d / "right_record.json");
    EXPECT_EQ(meta((d / "ok.exr").string(), "crop"), "0,0,32,24");

    // Same crop, another seed: the EXR replaced, its side JSON kept.
    fs::copy_file(d / "seed5.exr", d / "right.exr", fs::copy_options::overwrite_existing);
    expect_refused(d, "merge m.exr left.exr right.exr",
                   {"right.exr: the EXR's metadata says seed = 5 but its record right.json says 0"});
    // Another scene, same seed and spp.
    fs::copy_file(d / "other.exr", d / "right.exr", fs::copy_options::overwrite_existing);
    expect_refused(d, "merge m.exr left.exr right.exr", {"right.exr: the EXR's metadata says scene_sha1 = "});
    // Both records swapped consistently with the EXR: the parts still disagree.
    fs::copy_file(d / "other.json", d / "right.json", fs::copy_options::overwrite_existing);
    expect_refused(d, "merge m.exr left.exr right.exr", {"right.exr: \"scene", "(the parts must come from one render)"});
    // An EXR without meso metadata.
    Image img(16, 24, 3);
    write_exr((d / "right.exr").string(), img);
    fs::copy_file(d / "right_record.json", d / "right.json", fs::copy_options::overwrite_existing);
    expect_refused(d, "merge m.exr left.exr right.exr", {"right.exr: the EXR has no meso:"});
}
