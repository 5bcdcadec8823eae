// Bad input through the real binary (issue 24): files that are not regular files or are too
// large, out-of-range scene values, unsupported formats, glTF files meso cannot honour, and
// command-line errors. Each must end quickly (a hang fails: every run is under `timeout`)
// with the documented exit code and one "meso: error: ..." line naming the file and JSON
// path or the option; no input file may change and nothing may be written.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <vector>
#include <nlohmann/json.hpp>
#include "scratch_dir.h"

namespace fs = std::filesystem;

namespace {

struct MesoRun {
    int code;
    std::string out;
};

std::string quoted(const std::string &s) {
    std::string q = "'";
    for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
    return q + "'";
}

/// `meso ARGS` in `dir`, stdout and stderr together; a run over 30 s is killed (code 124).
MesoRun run_meso(const std::string &dir, const std::vector<std::string> &args) {
    std::string cmd = "cd " + quoted(dir) + " && timeout 30 " + quoted(MESO_BINARY);
    for (const auto &a : args) cmd += " " + quoted(a);
    cmd += " 2>&1";
    MesoRun r{-1, ""};
    FILE *p = popen(cmd.c_str(), "r");
    if (!p) return r;
    char buf[4096];
    while (size_t n = fread(buf, 1, sizeof(buf), p)) r.out.append(buf, n);
    int st = pclose(p);
    r.code = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
    return r;
}

/// FNV-1a of a file's bytes (size and hash: enough to see any change).
std::string checksum(const fs::path &p) {
    std::ifstream f(p, std::ios::binary);
    uint64_t h = 1469598103934665603ull, n = 0;
    char c;
    while (f.get(c)) h = (h ^ uint64_t(uint8_t(c))) * 1099511628211ull, ++n;
    return std::to_string(n) + ":" + std::to_string(h);
}

/// Checksums of the regular files directly in `dir` (sparse giants by size only).
std::map<std::string, std::string> checksums(const fs::path &dir) {
    std::map<std::string, std::string> out;
    for (const auto &e : fs::directory_iterator(dir)) {
        if (!e.is_regular_file() || e.is_symlink()) continue;
        out[e.path().filename().string()] =
            e.file_size() > (uint64_t(64) << 20) ? std::to_string(e.file_size()) : checksum(e.path());
    }
    return out;
}

void write(const fs::path &p, const std::string &text) {
    std::ofstream f(p, std::ios::binary);
    f << text;
}

const char *kCamera = R"("camera": {"type": "perspective", "origin": [0, 0, 4], "target": [0, 0, 0], "width": 16, "height": 12},
 "sampler": {"type": "independent", "sample_count": 1})";

std::string scene(const std::string &shapes, const std::string &lights = R"([{"type": "point", "position": [0, 0, 3], "intensity": 10}])") {
    return std::string("{") + kCamera + ",\n \"shapes\": " + shapes + ",\n \"lights\": " + lights + "}\n";
}

/// A one-triangle .gltf whose top level gets `extra` (JSON members) and whose buffer is `uri`.
std::string triangle_gltf(const std::string &extra, const std::string &uri =
    "data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAAAAABAAIA") {
    nlohmann::json j = nlohmann::json::parse(R"({"asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
      "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
      "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 6}],
      "accessors": [{"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": 3, "min": [0,0,0], "max": [1,1,0]},
                    {"bufferView": 1, "componentType": 5123, "type": "SCALAR", "count": 3}]})");
    j["buffers"] = nlohmann::json::array({{{"byteLength", 42}, {"uri", uri}}});
    nlohmann::json e = nlohmann::json::parse("{" + extra + "}");
    for (auto it = e.begin(); it != e.end(); ++it) {
        if (it.key() == "asset") j["asset"] = it.value();
        else j[it.key()] = it.value();
    }
    return j.dump();
}

struct Case {
    std::vector<std::string> args;
    int code;
    std::vector<std::string> expect;  ///< substrings of the message: file, JSON path or option, what was expected
};

/// The input files of every case, in `d`.
void make_inputs(const fs::path &d) {
    write(d / "s.json", scene(R"([{"type": "rectangle"}, {"type": "sphere", "radius": 0.5}])"));
    write(d / "map.json", scene(R"([{"type": "rectangle", "displacement": {"map": "/dev/zero", "scale": 0.1}}])"));
    write(d / "maplink.json", scene(R"([{"type": "rectangle", "displacement": {"map": "zero.exr", "scale": 0.1}}])"));
    fs::create_symlink("/dev/zero", d / "zero.exr");
    write(d / "env.json", scene(R"([{"type": "rectangle"}])", R"([{"type": "envmap", "filename": "/dev/zero"}])"));
    write(d / "bigenv.json", scene(R"([{"type": "rectangle"}])", R"([{"type": "envmap", "filename": "big.exr"}])"));
    { std::ofstream f(d / "big.exr"); }
    fs::resize_file(d / "big.exr", (uint64_t(4) << 30) + 1);  // sparse: nothing is written
    { std::ofstream f(d / "huge.json"); }
    fs::resize_file(d / "huge.json", (uint64_t(256) << 20) + 1);
    write(d / "deg.json", scene(R"([{"type": "rectangle", "to_world": {"scale": [1e-8, 1e-8, 1]},
      "displacement": {"map": {"generator": "fbm", "size": 16}, "scale": 0.1}}])"));
    write(d / "mat.json", R"({"type": "diffuse"})");
    write(d / "spot.json", scene(R"([{"type": "rectangle"}])", R"([{"type": "spot", "position": [0, 0, 3], "target": [0, 0, 0]}])"));
    write(d / "sun.json", scene(R"([{"type": "rectangle"}])", R"([{"type": "directional", "direction": [0, 0, -1]}])"));
    write(d / "disp.json", scene(R"([{"type": "rectangle", "displacement": {"map": {"generator": "fbm", "size": 16}, "scale": 0.1}}])"));
    write(d / "tex.json", scene(R"([{"type": "rectangle", "material": {"type": "diffuse", "reflectance": {"type": "bitmap", "filename": "hugemap.exr"}}}])"));
    fs::copy_file(fs::path(MESO_SOURCE_DIR) / "fuzz/regressions/exr_datawindow_16777023x64_allocates_4GB.exr", d / "hugemap.exr");
    for (const char *ext : {"obj", "dae"}) write(d / (std::string("tri.") + ext), "v 0 0 0\n");
    write(d / "draco.gltf", triangle_gltf(R"("extensionsUsed": ["KHR_draco_mesh_compression"],
                                             "extensionsRequired": ["KHR_draco_mesh_compression"])"));
    write(d / "v1.gltf", triangle_gltf(R"("asset": {"version": "1.0"})"));
    write(d / "zerobuf.gltf", triangle_gltf("", "zero.bin"));
    fs::create_symlink("/dev/zero", d / "zero.bin");
    write(d / "gltfshape.json", scene(R"([{"type": "gltf", "filename": "draco.gltf"}])"));
    ASSERT_EQ(mkfifo((d / "fifo.json").c_str(), 0600), 0);
}

std::vector<Case> cases() {
    const std::string al = R"({"type": "diffuse"})";
    return {
        // Inputs that are not regular files, or too large: refused before reading.
        {{"render", "/dev/zero"}, 1, {"/dev/zero", "scene file", "character device, not a regular file"}},
        {{"render", "fifo.json"}, 1, {"fifo.json", "named pipe, not a regular file"}},
        {{"render", "huge.json"}, 1, {"huge.json", "268435457 bytes, more than the 256 MiB limit for scene files"}},
        {{"render", "map.json"}, 1, {"map.json: shapes[0].displacement.map", "/dev/zero", "not a regular file"}},
        {{"render", "maplink.json"}, 1, {"maplink.json: shapes[0].displacement.map", "zero.exr", "not a regular file"}},
        {{"render", "env.json"}, 1, {"env.json: lights[0].filename", "/dev/zero", "not a regular file"}},
        {{"render", "bigenv.json"}, 1, {"bigenv.json: lights[0].filename", "big.exr", "4294967297 bytes, more than the 4 GiB limit for images"}},
        {{"render", "zerobuf.gltf"}, 1, {"zerobuf.gltf", "zero.bin", "glTF buffer", "not a regular file"}},
        {{"material", "albedo", "/dev/zero", "--wo", "0,0"}, 1, {"/dev/zero", "material file", "not a regular file"}},
        // Range-checked scene values, located by file and JSON path.
        {{"render", "s.json", "-D", "shapes[1].radius=1e39"}, 1, {"s.json: shapes[1].radius", "at most 3.4e38"}},
        {{"render", "s.json", "-D", "shapes[1].radius=1e30"}, 1, {"s.json: shapes[1].radius", "expected a number in (0, 1e+08]"}},
        {{"render", "s.json", "-D", "shapes[1].radius=-1"}, 1, {"s.json: shapes[1].radius", "expected a number in (0, 1e+08]"}},
        {{"render", "s.json", "-D", "shapes[0].to_world.scale=1e300"}, 1, {"s.json: shapes[0].to_world.scale", "at most 3.4e38"}},
        {{"render", "s.json", "-D", "shapes[0].to_world.scale=1e30"}, 1, {"s.json: shapes[0].to_world.scale", "[1e-08, 1e+08]"}},
        {{"render", "s.json", "-D", "shapes[0].to_world.translate=[0,0,1e20]"}, 1, {"s.json: shapes[0].to_world.translate", "[-1e+08, 1e+08]"}},
        {{"render", "s.json", "-D", "shapes[0].to_world.matrix=[1e30,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1]"}, 1,
         {"s.json: shapes[0].to_world.matrix", "element 0"}},
        {{"render", "s.json", "-D", "camera.origin=[1e39,0,0]"}, 1, {"s.json: camera.origin", "at most 3.4e38"}},
        {{"render", "s.json", "-D", "camera.origin=[1e20,0,0]"}, 1, {"s.json: camera.origin", "[-1e+08, 1e+08]"}},
        {{"render", "s.json", "-D", "camera.target=[0,0,1e9]"}, 1, {"s.json: camera.target", "[-1e+08, 1e+08]"}},
        // Values read by lights, cameras, samplers and maps (issue 24: every scene value range-checked).
        {{"render", "s.json", "-D", "lights[0].position=[0,0,1e20]"}, 1, {"s.json: lights[0].position", "[-1e+08, 1e+08]"}},
        {{"render", "s.json", "-D", "lights[0].intensity=-1"}, 1, {"s.json: lights[0].intensity", "expected a number at least 0, got -1"}},
        {{"render", "spot.json", "-D", "lights[0].target=[0,0,3]"}, 1, {"spot.json: lights[0].target", "must differ from 'position'"}},
        {{"render", "spot.json", "-D", "lights[0].cutoff_angle=0"}, 1, {"spot.json: lights[0].cutoff_angle", "in (0, 180]"}},
        {{"render", "spot.json", "-D", "lights[0].beam_width=90"}, 1, {"spot.json: lights[0].beam_width", "in [0, 20]"}},
        {{"render", "sun.json", "-D", "lights[0].direction=[0,0,0]"}, 1, {"sun.json: lights[0].direction", "non-zero finite length"}},
        {{"render", "sun.json", "-D", "lights[0].irradiance=[1,-2,1]"}, 1, {"sun.json: lights[0].irradiance", "got -2 at index 1"}},
        {{"render", "s.json", "-D", "camera.up=[0,0,0]"}, 1, {"s.json: camera.up", "non-zero finite length"}},
        {{"render", "s.json", "-D", "camera.fov=180"}, 1, {"s.json: camera.fov", "in (0, 180)"}},
        {{"render", "s.json", "-D", "camera.width=0"}, 1, {"s.json: camera.width", "in [1, 65536]"}},
        {{"render", "s.json", "-D", "sampler.seed=-5"}, 1, {"s.json: sampler.seed", "at least 0, got -5"}},
        {{"render", "s.json", "-D", "sampler.sample_count=0"}, 1, {"s.json: sampler.sample_count", "at least 1, got 0"}},
        {{"render", "disp.json", "-D", "shapes[0].displacement.scale=1e30"}, 1, {"disp.json: shapes[0].displacement.scale", "[-1e+08, 1e+08]"}},
        {{"render", "disp.json", "-D", "shapes[0].displacement.tiling=[1,0]"}, 1, {"disp.json: shapes[0].displacement.tiling", "(0, 1e+06], got 0 at index 1"}},
        {{"render", "tex.json"}, 1, {"tex.json: shapes[0].material.reflectance.filename", "hugemap.exr", "16777023x64", "corrupt or truncated"}},
        {{"render", "deg.json"}, 1, {"deg.json: shapes[0]", "the displaced mesh has no triangle with an area"}},
        // A bare mesh is a scene (framed, grey, lit), but this one has no face; formats meso does not read.
        {{"render", "tri.obj"}, 1, {"tri.obj: no faces"}},
        {{"render", "tri.dae"}, 1, {"tri.dae: unsupported scene format '.dae' (meso reads .json, .gltf, .glb, .obj, .ply and Mitsuba 3 .xml)"}},
        {{"render", "draco.gltf"}, 1, {"draco.gltf: extensionsRequired", "'KHR_draco_mesh_compression'", "does not implement"}},
        {{"render", "gltfshape.json"}, 1, {"gltfshape.json: shapes[0].filename", "KHR_draco_mesh_compression"}},
        {{"render", "v1.gltf"}, 1, {"v1.gltf: asset.version", "expected a glTF 2.x file"}},
        // Command-line errors: exit code 2, the option named.
        {{"render", "s.json", "--bogus"}, 2, {"render: ", "--bogus", "meso render --help"}},
        {{"render", "s.json", "--spp", "abc"}, 2, {"render: ", "--spp", "abc"}},
        {{"render", "s.json", "--spp"}, 2, {"render: ", "--spp"}},
        {{"render"}, 2, {"render: ", "scene is required"}},
        {{"frobnicate"}, 2, {"unknown command 'frobnicate'", "render"}},
        {{"material", "albedo", al, "--wo", "0,0", "--samples", "-5"}, 2, {"material albedo: --samples", "-5", "not in range 1 to"}},
        {{"material", "albedo", al, "--wo", "0,0", "--samples", "0"}, 2, {"material albedo: --samples", "not in range 1 to"}},
        {{"material", "chi2", al, "--wo", "0,0", "--samples", "-1"}, 2, {"material chi2: --samples", "not in range 1 to"}},
        {{"material", "albedo", "mat.json", "--wo", "0,0", "--seed", "-5"}, 2, {"material albedo: --seed", "not in range 0 to"}},
    };
}

}  // namespace

TEST(BadInput, EveryCaseFailsCleanlyAndChangesNothing) {
    const fs::path d = fs::path(meso::test::scratch_dir("meso_bad_input")) / "cases";
    fs::remove_all(d);
    fs::create_directories(d);
    make_inputs(d);
    const auto before = checksums(d);
    const fs::path out = d / "out";
    fs::create_directories(out);
    for (const Case &c : cases()) {
        std::vector<std::string> args = c.args;
        if (args[0] == "render") args.insert(args.end(), {"-o", (out / "o.exr").string(), "-q"});
        std::string label;
        for (const auto &a : c.args) label += a + " ";
        SCOPED_TRACE(label);
        MesoRun r = run_meso(d.string(), args);
        EXPECT_EQ(r.code, c.code) << r.out;
        EXPECT_EQ(r.out.rfind("meso: error: ", 0), 0u) << r.out;
        for (const auto &e : c.expect) EXPECT_NE(r.out.find(e), std::string::npos) << "missing '" << e << "' in: " << r.out;
        EXPECT_TRUE(fs::is_empty(out)) << "an output was written";
    }
    EXPECT_EQ(checksums(d), before) << "an input file changed";
}

TEST(BadInput, HelpAndVersionStillSucceed) {
    const std::string d = meso::test::scratch_dir("meso_bad_input");
    for (std::vector<std::string> args : {std::vector<std::string>{"--help"}, {"render", "--help"}, {"--version"},
                                          {"material", "albedo", "--help"}}) {
        MesoRun r = run_meso(d, args);
        EXPECT_EQ(r.code, 0) << r.out;
        EXPECT_EQ(r.out.find("meso: error"), std::string::npos) << r.out;
    }
}
