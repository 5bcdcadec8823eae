// `meso convert IN OUT [--exposure S]`
//
// Converts an image between formats: IN is anything OpenImageIO reads (float formats as
// linear, 8/16-bit files as stored); OUT by extension:
//   .exr  full-float EXR (channels kept)
//   .png  8-bit sRGB of the exposure-scaled, clamped linear RGB (as `meso render` writes)
//   .pfm  little-endian float PFM (RGB "PF", or grey "Pf" for one channel), bottom row
//         first as the format requires: scripts read it with numpy alone (no EXR library),
//         e.g. scripts/leadr_groundtruth.
#include <CLI/CLI.hpp>
#include <cmath>
#include <cstdio>
#include <fmt/format.h>
#include <memory>
#include <string>
#include "app/commands.h"
#include "core/error.h"
#include "core/output_set.h"
#include "image/image.h"

namespace meso {
namespace {

struct ConvertOptions {
    std::string in, out;
    float exposure = 0.f;
};

std::string lower_extension(const std::string &p) {
    const size_t dot = p.find_last_of('.');
    if (dot == std::string::npos) return "";
    std::string e = p.substr(dot);
    for (char &c : e) c = char(std::tolower(static_cast<unsigned char>(c)));
    return e;
}

/// Writes `path` directly: it is the output's staging file (core/output_set.h), renamed into place after.
void write_pfm(const std::string &path, const Image &img) {
    const bool grey = img.channels == 1;
    FILE *f = std::fopen(path.c_str(), "wb");
    if (!f) throw MesoError(fmt::format("{}: cannot write image", path));
    std::fprintf(f, "%s\n%d %d\n-1.0\n", grey ? "Pf" : "PF", img.width, img.height);
    std::vector<float> row(size_t(img.width) * (grey ? 1 : 3));
    bool ok = true;
    for (int y = img.height - 1; y >= 0 && ok; --y) {
        for (int x = 0; x < img.width; ++x) {
            if (grey) {
                row[x] = img.at(x, y, 0);
            } else {
                Spectrum s = img.rgb(x, y);
                row[3 * size_t(x)] = s.r, row[3 * size_t(x) + 1] = s.g, row[3 * size_t(x) + 2] = s.b;
            }
        }
        ok = std::fwrite(row.data(), sizeof(float), row.size(), f) == row.size();
    }
    ok = (std::fclose(f) == 0) && ok;
    if (!ok) {
        std::remove(path.c_str());
        throw MesoError(fmt::format("{}: cannot write image", path));
    }
}

int run_convert(const ConvertOptions &o) {
    const std::string ext = lower_extension(o.out);
    if (ext != ".exr" && ext != ".png" && ext != ".pfm")
        throw MesoError(fmt::format("{}: unsupported output format '{}' (expected .exr, .png or .pfm)", o.out, ext));
    if (!std::isfinite(o.exposure)) throw UsageError(fmt::format("--exposure {}: expected a finite number of stops", o.exposure));
    OutputSet set;
    set.add_input(o.in, "the input image");
    const std::string staged = set.add_output("output", o.out);
    set.check();
    Image img = read_image(o.in);
    if (ext == ".exr") write_exr(staged, img, read_image_metadata(o.in));  // provenance kept
    else if (ext == ".png") write_png(staged, img, o.exposure);
    else write_pfm(staged, img);
    set.commit();
    return 0;
}

SubcommandRegistrar reg_convert{{"convert", "Convert an image between formats (EXR, PNG, PFM for numpy scripts)",
                                 [](CLI::App &app) -> std::function<int()> {
                                     auto o = std::make_shared<ConvertOptions>();
                                     app.add_option("input", o->in, "image to read (any OIIO format)")->required();
                                     app.add_option("output", o->out, "image to write: .exr, .png or .pfm")->required();
                                     app.add_option("--exposure", o->exposure, "exposure in stops for .png output");
                                     return [o] { return run_convert(*o); };
                                 }}};

}  // namespace
}  // namespace meso
