// `meso compare TEST REF [--json] [--error-image ERR.png|ERR.exr] [--error-range LO HI]`
//
// Prints MSE, relMSE, RMSE, PSNR (peak 1) and the mean-luminance ratio of TEST against
// REF (definitions in src/image/metrics.cpp), as aligned lines or, with --json, as one
// JSON object (non-finite numbers become null). NaN/Inf test pixels are counted and
// excluded. --error-image writes the per-pixel squared error e = Y((t - r)^2) (Rec. 709
// luminance of the squared RGB difference): a .exr gets e itself as float; anything
// else gets a PNG false-colour map of log10(e) with viridis (NaN/Inf pixels magenta).
// The log10 range is [log10 min e, log10 max e] over pixels with e > 0, narrowed to the
// top 8 decades, unless --error-range fixes it (use the same range to compare maps);
// the range used is printed.
#include <CLI/CLI.hpp>
#include <cmath>
#include <cstdio>
#include <fmt/format.h>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include "app/commands.h"
#include "core/error.h"
#include "core/output_set.h"
#include "image/false_colour.h"
#include "image/image.h"

namespace meso {
namespace {

struct CompareOptions {
    std::string test, ref, error_image;
    std::vector<double> error_range;
    bool json = false;
};

bool ends_with_exr(const std::string &p) {
    if (p.size() < 4) return false;
    std::string e = p.substr(p.size() - 4);
    for (char &c : e) c = char(std::tolower(static_cast<unsigned char>(c)));
    return e == ".exr";
}

struct ErrorImageInfo {
    std::string path;
    bool log_map = false;
    double log_lo = 0, log_hi = 0;
};

ErrorImageInfo write_error_image(const CompareOptions &o, const std::string &staged, const Image &test, const Image &ref) {
    ErrorImageInfo info;
    info.path = o.error_image;
    std::vector<double> e(size_t(test.width) * test.height);
    double emin = INFINITY, emax = 0;
    for (int y = 0; y < test.height; ++y)
        for (int x = 0; x < test.width; ++x) {
            Spectrum d = test.rgb(x, y) - ref.rgb(x, y);
            double v = (d * d).luminance();
            e[size_t(y) * test.width + x] = v;
            if (std::isfinite(v) && v > 0) emin = std::min(emin, v), emax = std::max(emax, v);
        }
    if (ends_with_exr(o.error_image)) {
        Image img(test.width, test.height, 1);
        for (size_t i = 0; i < e.size(); ++i) img.data[i] = float(e[i]);
        write_exr(staged, img);
        return info;
    }
    info.log_map = true;
    if (o.error_range.size() == 2) {
        info.log_lo = o.error_range[0];
        info.log_hi = o.error_range[1];
        if (!(info.log_hi > info.log_lo))
            throw UsageError(fmt::format("--error-range: LO ({}) must be below HI ({})", info.log_lo, info.log_hi));
    } else if (emax > 0) {
        info.log_hi = std::log10(emax);
        info.log_lo = std::max(std::log10(emin), info.log_hi - 8.0);
        if (info.log_hi - info.log_lo < 1e-3) info.log_lo = info.log_hi - 1.0;  // (near) constant error
    } else {
        info.log_lo = -8.0, info.log_hi = 0.0;  // no error anywhere: all pixels get the bottom colour
    }
    write_png(staged, false_colour_log(e, test.width, test.height, info.log_lo, info.log_hi));
    return info;
}

int run_compare(const CompareOptions &o) {
    // The error image may not replace either input; it is checked before anything is read.
    OutputSet set;
    set.add_input(o.test, "the test image");
    set.add_input(o.ref, "the reference");
    const std::string staged = o.error_image.empty() ? "" : set.add_output("--error-image", o.error_image);
    set.check();
    Image test = read_image(o.test), ref = read_image(o.ref);
    ImageMetrics m = compute_metrics(test, ref);  // checks the sizes first
    ErrorImageInfo err;
    if (!o.error_image.empty()) {
        err = write_error_image(o, staged, test, ref);
        set.commit();
    }

    if (o.json) {
        nlohmann::json j;
        j["test"] = o.test;
        j["ref"] = o.ref;
        j["width"] = test.width;
        j["height"] = test.height;
        j["mse"] = m.mse;  // nlohmann writes NaN/Inf as null
        j["relmse"] = m.relmse;
        j["rmse"] = m.rmse;
        j["psnr"] = m.psnr;
        j["mean_luminance_ratio"] = m.mean_luminance_ratio;
        j["nonfinite"] = m.nonfinite;
        if (!err.path.empty()) {
            nlohmann::json ej;
            ej["path"] = err.path;
            ej["quantity"] = "squared error luminance";
            if (err.log_map) {
                ej["colormap"] = "viridis";
                ej["log10_range"] = {err.log_lo, err.log_hi};
            }
            j["error_image"] = ej;
        }
        std::printf("%s\n", j.dump().c_str());
    } else {
        std::printf("%s", fmt::format("test:   {} ({}x{})\nref:    {} ({}x{})\n", o.test, test.width, test.height, o.ref,
                                      ref.width, ref.height).c_str());
        std::printf("%s", fmt::format("MSE:    {:.6e}\nrelMSE: {:.6e}\nRMSE:   {:.6e}\nPSNR:   {:.3f} dB (peak 1)\n",
                                      m.mse, m.relmse, m.rmse, m.psnr).c_str());
        std::printf("%s", fmt::format("mean luminance ratio (test/ref): {:.6f}\n", m.mean_luminance_ratio).c_str());
        if (m.nonfinite > 0) std::printf("nonfinite test pixels (excluded): %ld\n", m.nonfinite);
        if (!err.path.empty()) {
            if (err.log_map)
                std::printf("%s", fmt::format("error image: {} (squared error, log10 scale, viridis: "
                                              "{:.3g} (dark) .. {:.3g} (bright), log10 [{:.2f}, {:.2f}])\n",
                                              err.path, std::pow(10.0, err.log_lo), std::pow(10.0, err.log_hi),
                                              err.log_lo, err.log_hi).c_str());
            else
                std::printf("error image: %s (squared error, float)\n", err.path.c_str());
        }
    }
    std::fflush(stdout);
    return 0;
}

SubcommandRegistrar reg_compare{{"compare", "Error metrics (MSE, relMSE, RMSE, PSNR) of an image against a reference",
                                 [](CLI::App &app) -> std::function<int()> {
                                     auto o = std::make_shared<CompareOptions>();
                                     app.add_option("test", o->test, "Image to evaluate (EXR or any OIIO format)")
                                         ->required();
                                     app.add_option("reference", o->ref, "Reference image")->required();
                                     app.add_flag("--json", o->json, "Print one JSON object");
                                     app.add_option("--error-image", o->error_image,
                                                    "Write the per-pixel squared error: false-colour PNG "
                                                    "(log scale), or raw float if the name ends in .exr");
                                     app.add_option("--error-range", o->error_range,
                                                    "log10 range LO HI of the false-colour scale")
                                         ->expected(2);
                                     return [o] { return run_compare(*o); };
                                 }}};

}  // namespace
}  // namespace meso
