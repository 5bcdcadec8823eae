// Helpers for tests that render small scenes given as JSON text.
#pragma once
#include <filesystem>
#include <fstream>
#include <string>
#include "render/renderer.h"
#include "render/scene.h"

namespace meso::test {

/// Writes `json` to a fresh temp file named `name` and returns its path.
inline std::string write_temp(const std::string &name, const std::string &text) {
    auto dir = std::filesystem::temp_directory_path() / "meso_tests";
    std::filesystem::create_directories(dir);
    auto p = dir / name;
    std::ofstream(p) << text;
    return p.string();
}

inline std::unique_ptr<Scene> load_json_scene(const std::string &name, const std::string &json) {
    auto s = load_scene(write_temp(name, json), {});
    s->build();
    return s;
}

inline RenderResult render_scene(const Scene &s, int spp, int threads = 0, uint64_t seed = 7) {
    RenderOptions o;
    o.spp = spp;
    o.threads = threads;
    o.seed = seed;
    o.progress = false;
    return render(s, o);
}

/// Mean and standard error of the mean over pixels (each pixel one estimate).
struct PixelStats {
    double mean = 0, sigma_pixel = 0, stderr_mean = 0, min = 1e30, max = -1e30;
};
inline PixelStats pixel_stats(const Image &img, int channel) {
    PixelStats s;
    double sum = 0, sum2 = 0;
    size_t n = size_t(img.width) * img.height;
    for (int y = 0; y < img.height; ++y)
        for (int x = 0; x < img.width; ++x) {
            double v = img.at(x, y, channel);
            sum += v;
            sum2 += v * v;
            s.min = std::min(s.min, v);
            s.max = std::max(s.max, v);
        }
    s.mean = sum / n;
    s.sigma_pixel = std::sqrt(std::max(0.0, sum2 / n - s.mean * s.mean));
    s.stderr_mean = s.sigma_pixel / std::sqrt(double(n));
    return s;
}

}  // namespace meso::test
