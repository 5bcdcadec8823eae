// Reading the formats meso does not read itself (Radiance .hdr, PFM, JPEG, TIFF, ...) through
// the OpenImageIO module (image/oiio_abi.h), dlopen()ed on the first such file and kept loaded.
// meso does not link OpenImageIO: a run that only reads and writes EXR and PNG never loads it.
#include <dlfcn.h>
#include <unistd.h>
#include <algorithm>
#include <climits>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <fmt/format.h>
#include "core/error.h"
#include "image/image_formats.h"
#include "meso_oiio_module_path.h"

namespace meso {

namespace fs = std::filesystem;

std::vector<std::string> oiio_module_candidates() {
    std::vector<std::string> v;
    // The environment first (an explicit choice overrides), then next to the executable, then the
    // build tree this binary was built in.
    if (const char *env = std::getenv("MESO_OIIO_MODULE"); env && *env) v.push_back(env);
    std::error_code ec;
    const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
    if (!ec) v.push_back((exe.parent_path() / MESO_OIIO_MODULE_NAME).string());
    v.push_back(MESO_OIIO_MODULE_BUILD_PATH);
    for (size_t i = 1; i < v.size(); ++i)  // build/meso: next to the executable is the build tree
        if (std::find(v.begin(), v.begin() + long(i), v[i]) != v.begin() + long(i)) v.erase(v.begin() + long(i--));
    return v;
}

const MesoOiioApi *load_oiio_module(const std::vector<std::string> &candidates, std::string &problem) {
    problem.clear();
    for (const std::string &file : candidates) {
        std::string why;
        std::error_code ec;
        if (!fs::exists(file, ec)) {
            why = "not found";
        } else if (void *handle = dlopen(file.c_str(), RTLD_NOW | RTLD_LOCAL); !handle) {
            const char *e = dlerror();
            why = e ? e : "dlopen failed";
        } else if (auto fn = reinterpret_cast<MesoOiioApiFn>(dlsym(handle, "meso_oiio_api")); !fn) {
            why = "it has no meso_oiio_api";  // the handle stays open: unloading libraries is not worth the risk
        } else if (const MesoOiioApi *api = fn(); !api || api->abi_version != kMesoOiioAbiVersion) {
            why = fmt::format("interface version {}, meso needs {}", api ? api->abi_version : 0, int(kMesoOiioAbiVersion));
        } else {
            return api;
        }
        problem += fmt::format("{}{} ({})", problem.empty() ? "" : ", ", file, why);
    }
    if (problem.empty()) problem = "no place to look";
    return nullptr;
}

namespace {

/// The format of a file meso does not read itself, for messages: by its first bytes, or else
/// its extension.
std::string format_name(const std::string &path) {
    std::ifstream f(path, std::ios::binary);
    char b[11] = {};
    f.read(b, 10);
    const auto starts = [&](const char *m, size_t n) { return std::memcmp(b, m, n) == 0; };
    if (starts("#?RADIANCE", 10) || starts("#?RGBE", 6)) return "Radiance HDR";
    if (starts("PF\n", 3) || starts("Pf\n", 3) || starts("PF\r", 3) || starts("Pf\r", 3)) return "PFM";
    if (starts("\xff\xd8\xff", 3)) return "JPEG";
    if (starts("II*\0", 4) || starts("MM\0*", 4)) return "TIFF";
    const std::string ext = fs::path(path).extension().string();
    return ext.empty() ? std::string("this file's format") : fmt::format("'{}'", ext);
}

/// The module, loaded by the first call (thread-safe); read_error naming the file, its format
/// and every module path tried when it cannot be loaded.
const MesoOiioApi &oiio_module(const std::string &path) {
    static std::string problem;
    static const MesoOiioApi *api = load_oiio_module(oiio_module_candidates(), problem);
    if (!api)
        image_read_error(path, fmt::format("{} files are read through OpenImageIO, and its module could not be "
                                           "loaded: tried {}; set MESO_OIIO_MODULE to libmeso_oiio.so's path",
                                           format_name(path), problem));
    return *api;
}

/// An open file of the module, closed on every path.
struct ModuleFile {
    const MesoOiioApi &api;
    MesoOiioFile *file = nullptr;
    ~ModuleFile() {
        if (file) api.close(file);
    }
};

}  // namespace

DecodedImage read_oiio_file(const std::string &path, bool pixels) {
    const MesoOiioApi &api = oiio_module(path);
    char err[512] = "";
    MesoOiioInfo info{};
    ModuleFile f{api, api.open(path.c_str(), &info, err, sizeof err)};
    if (!f.file) image_read_error(path, one_line(err, "unknown format"));
    if (info.depth > 1)
        image_read_error(path, fmt::format("unsupported image size {}x{}x{} with {} channels", info.width, info.height,
                                           info.depth, info.channels));
    check_declared_size(path, info.width, info.height, info.channels, info.bytes_per_value);
    DecodedImage d;
    set_header_size(d, info.width, info.height, info.channels);
    d.sample = SampleType(info.sample_type);
    d.says_linear = info.says_linear != 0;
    d.alpha_channel = info.alpha_channel;
    for (int c = 0; c < info.channels; ++c) d.channel_names.emplace_back(api.channel_name(f.file, c));
    const char *name = nullptr, *value = nullptr;
    for (int i = 0; api.string_attribute(f.file, i, &name, &value); ++i)
        if (std::strncmp(name, "meso:", 5) == 0) d.meta.emplace_back(name + 5, value);
    if (!pixels) return d;
    d.image = Image(info.width, info.height, info.channels);
    if (!api.read_float(f.file, d.image.data.data(), err, sizeof err)) image_read_error(path, one_line(err, "read failed"));
    return d;
}

}  // namespace meso
