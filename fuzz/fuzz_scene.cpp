// libFuzzer target for the scene loader (issue 24, docs/fuzzing.md): every input is one file
// handed to load_scene as a user would hand it to `meso render`, then built (BVH, lights) and
// rendered at 1 spp over a 4 x 4 crop, so the plugins' evaluation code runs on fuzzed values too.
//
// The file's kind is read from its bytes, so one corpus mixes all of them and mutations can
// cross between kinds:
//   "glTF" magic                -> SCENE_DIR/input.glb
//   EXR / PNG / Radiance / PFM  -> a map: written as SCENE_DIR/map.EXT and loaded by three fixed
//                                  scenes (displacement map, bitmap texture, envmap)
//   a JSON object with "asset"  -> SCENE_DIR/input.gltf
//   anything else               -> SCENE_DIR/input.json
// SCENE_DIR sits beside a private copy of scenes/assets, so "../assets/sky.hdr" in a seed scene
// resolves and nothing the loader might do can touch the repository.
//
// A MesoError is the expected answer to a bad input. Any other exception escaping the loader is
// a finding (abort), as are crashes, sanitizer reports, timeouts and out-of-memory (libFuzzer).
// Values that are valid but merely expensive (a 16384^2 generated map, a million-segment
// sphere) are clamped before loading, see kClamps: they cost time, not correctness.
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <fstream>
#include <string>
#include <system_error>
#include <OpenImageIO/imageio.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "image/image.h"
#include "render/renderer.h"
#include "render/scene.h"

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

/// Integer parameters whose cost grows with their value (map sizes, mesh resolution, counts):
/// a larger value is lowered to the cap. Keys anywhere in the document.
struct Clamp {
    const char *key;
    int64_t cap;
};
constexpr Clamp kClamps[] = {{"size", 128},     {"width", 128},  {"height", 128},    {"periods", 64},
                             {"yarns", 64},     {"grid", 64},    {"count", 256},     {"segments", 128},
                             {"rings", 128},    {"components", 16}, {"octaves", 8},  {"harness", 16},
                             {"level", 4},      {"levels", 4}};
constexpr size_t kMaxTriangles = 200000;
constexpr uint64_t kMaxMapValues = uint64_t(1) << 26;  // 64M floats (256 MB) a map image

bool g_verbose = false;  // MESO_FUZZ_VERBOSE=1: print each input's MesoError (replaying a reproducer)
fs::path g_root;       // private temporary directory
fs::path g_scene_dir;  // g_root/scene; g_root/assets is the copy of scenes/assets

void remove_root() {
    std::error_code ec;
    if (!g_root.empty()) fs::remove_all(g_root, ec);
}

bool clamp_costs(json &j) {
    bool changed = false;
    if (j.is_object()) {
        for (auto it = j.begin(); it != j.end(); ++it) {
            for (const Clamp &c : kClamps)
                if (it.key() == c.key && it->is_number() && it->get<double>() > double(c.cap)) {
                    *it = c.cap;
                    changed = true;
                }
            changed |= clamp_costs(*it);
        }
    } else if (j.is_array()) {
        for (json &e : j) changed |= clamp_costs(e);
    }
    return changed;
}

void write_file(const fs::path &path, const uint8_t *data, size_t size) {
    std::ofstream f(path, std::ios::binary | std::ios::trunc);
    f.write(reinterpret_cast<const char *>(data), std::streamsize(size));
    if (!f) {
        std::fprintf(stderr, "fuzz_scene: cannot write %s\n", path.c_str());
        std::abort();
    }
}

bool starts_with(const uint8_t *data, size_t size, const char *magic, size_t n) {
    return size >= n && std::equal(magic, magic + n, reinterpret_cast<const char *>(data));
}

/// ".exr", ".png", ".hdr" or ".pfm" when the bytes start like one of those images, else "".
const char *map_extension(const uint8_t *data, size_t size) {
    if (starts_with(data, size, "\x76\x2f\x31\x01", 4)) return ".exr";
    if (starts_with(data, size, "\x89PNG", 4)) return ".png";
    if (starts_with(data, size, "#?", 2)) return ".hdr";
    if (starts_with(data, size, "PF\n", 3) || starts_with(data, size, "Pf\n", 3)) return ".pfm";
    return "";
}

/// Load, build and render a 4 x 4 corner at 1 spp on one thread. A MesoError is a clean answer.
void load_build_render(const fs::path &file) {
    try {
        std::unique_ptr<meso::Scene> scene = meso::load_scene(file.string(), {}, kMaxTriangles);
        scene->plan();
        scene->build();
        meso::RenderOptions opts;
        opts.spp = 1;
        opts.threads = 1;
        opts.seed = 1;
        opts.progress = false;
        opts.crop = std::array<int, 4>{0, 0, std::min(4, scene->camera->width()), std::min(4, scene->camera->height())};
        meso::render(*scene, opts);
    } catch (const meso::MesoError &e) {
        // the expected answer to a bad input
        if (g_verbose) std::fprintf(stderr, "fuzz_scene: %s\n", e.what());
    } catch (const std::exception &e) {
        std::fprintf(stderr, "fuzz_scene: %s: an exception other than MesoError escaped: %s\n", file.c_str(), e.what());
        std::abort();
    }
}

/// The three fixed scenes that load SCENE_DIR/map.EXT (written per extension on first use).
/// A map whose header declares more than kMaxMapValues values is skipped: read_image refuses
/// sizes no codec reaches from the file's size (fuzz/regressions/exr_datawindow_16777023x64_allocates_4GB.exr)
/// but would still allocate a plausible large map, a cost, not a finding.
void load_map_scenes(const char *ext) {
    const std::string map = std::string("map") + ext;
    try {
        meso::check_exr_headers((g_scene_dir / map).string());  // before OpenImageIO reads the header
    } catch (const meso::MesoError &) {
        return;  // read_image refuses it the same way
    }
    if (auto in = OIIO::ImageInput::open((g_scene_dir / map).string())) {
        if (in->spec().image_pixels() * uint64_t(std::max(1, in->spec().nchannels)) > kMaxMapValues) return;
    } else {
        (void)OIIO::geterror();  // meso's own reader reports it below
    }
    const std::string camera = R"("camera": {"type": "perspective", "origin": [0, 2, 3], "target": [0, 0, 0], "up": [0, 1, 0],
        "fov": 40, "width": 8, "height": 8})";
    const std::string quad = R"({"type": "rectangle", "to_world": {"rotate": {"axis": [1, 0, 0], "angle": -90}})";
    const std::string scenes[] = {
        "{" + camera + R"(, "shapes": [)" + quad + R"(, "displacement": {"map": ")" + map +
            R"(", "scale": 0.05, "tiling": 4}}], "lights": [{"type": "constant", "radiance": 1}]})",
        "{" + camera + R"(, "shapes": [)" + quad + R"(, "material": {"type": "diffuse", "reflectance":
            {"type": "bitmap", "filename": ")" + map + R"("}}}], "lights": [{"type": "constant", "radiance": 1}]})",
        "{" + camera + R"(, "shapes": [)" + quad + R"(}], "lights": [{"type": "envmap", "filename": ")" + map + R"("}]})",
    };
    for (int k = 0; k < 3; ++k) {
        fs::path scene = g_scene_dir / (std::string("map_scene") + std::to_string(k) + ext + ".json");
        if (!fs::exists(scene)) {
            std::ofstream(scene) << scenes[k];
        }
        load_build_render(scene);
    }
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int *, char ***) {
    const char *verbose = std::getenv("MESO_FUZZ_VERBOSE");
    g_verbose = verbose && *verbose && *verbose != '0';
    const char *tmp = std::getenv("TMPDIR");
    std::string pattern = std::string(tmp && *tmp ? tmp : "/tmp") + "/meso-fuzz-XXXXXX";
    if (!mkdtemp(pattern.data())) {
        std::perror("fuzz_scene: mkdtemp");
        std::abort();
    }
    g_root = pattern;
    std::atexit(remove_root);
    g_scene_dir = g_root / "scene";
    fs::create_directories(g_scene_dir);
    const char *assets = std::getenv("MESO_FUZZ_ASSETS");
    fs::copy(assets && *assets ? fs::path(assets) : fs::path(MESO_SOURCE_DIR) / "scenes" / "assets", g_root / "assets",
             fs::copy_options::recursive);
    return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    if (starts_with(data, size, "glTF", 4)) {
        fs::path file = g_scene_dir / "input.glb";
        write_file(file, data, size);
        load_build_render(file);
        return 0;
    }
    if (const char *ext = map_extension(data, size); *ext) {
        write_file(g_scene_dir / (std::string("map") + ext), data, size);
        load_map_scenes(ext);
        return 0;
    }
    json doc = json::parse(data, data + size, nullptr, /*allow_exceptions=*/false, /*ignore_comments=*/true);
    bool gltf = doc.is_object() && doc.contains("asset");
    fs::path file = g_scene_dir / (gltf ? "input.gltf" : "input.json");
    if (!doc.is_discarded() && clamp_costs(doc)) {
        std::string text = doc.dump();
        write_file(file, reinterpret_cast<const uint8_t *>(text.data()), text.size());
    } else {
        write_file(file, data, size);  // as given: the parser's own errors are under test too
    }
    load_build_render(file);
    return 0;
}
