// Height-map files: reading any grey image read_image knows (without sRGB decoding: an
// 8/16-bit file holds heights in [0,1] linearly), writing float32 EXR (through write_exr, one
// channel "Y") and 16-bit PNG normalised to the map's range (through write_png16_grey).
#include <algorithm>
#include <cmath>
#include <fmt/format.h>
#include "core/error.h"
#include "geometry/heightmap.h"
#include "image/image.h"

namespace meso {

namespace {

[[noreturn]] void map_error(const std::string &path, const std::string &why) {
    throw MesoError(fmt::format("{}: {}", path, why));
}

/// Colour channels equal up to float rounding (a grey image stored as RGB).
bool same_grey(float a, float b) { return std::abs(a - b) <= 1e-6f * std::max(1.f, std::abs(a)); }

}  // namespace

HeightMap read_height_map(const std::string &path) {
    Image img = read_image(path, /*linearize_srgb=*/false);
    if (img.width <= 0 || img.height <= 0 || img.data.empty()) map_error(path, "the height map is empty");
    // 1: grey; 2: grey + alpha; 3: RGB; 4: RGBA. Alpha is ignored.
    if (img.channels > 4)
        map_error(path, fmt::format("expected a grey height map (1 channel, or RGB(A) with R = G = B), "
                                    "got {} channels",
                                    img.channels));
    const int colour = img.channels >= 3 ? 3 : 1;
    HeightMap map(img.width, img.height);
    for (int y = 0; y < img.height; ++y)
        for (int x = 0; x < img.width; ++x) {
            float v = img.at(x, y, 0);
            if (!std::isfinite(v))
                map_error(path, fmt::format("pixel ({}, {}) is {}: a height map needs finite values", x, y, v));
            if (colour == 3 && !(same_grey(v, img.at(x, y, 1)) && same_grey(v, img.at(x, y, 2))))
                map_error(path, fmt::format("expected a grey height map (1 channel, or RGB with R = G = B), but "
                                            "pixel ({}, {}) has R, G, B = {}, {}, {}",
                                            x, y, v, img.at(x, y, 1), img.at(x, y, 2)));
            map.at(x, y) = v;
        }
    return map;
}

void write_height_map(const std::string &path, const HeightMap &map) {
    if (map.empty() || map.h.size() != size_t(map.width) * map.height)
        throw MesoError(fmt::format("cannot write '{}': empty height map ({}x{})", path, map.width, map.height));
    Image img(map.width, map.height, 1);
    img.data = map.h;
    write_exr(path, img);
}

HeightRange write_height_map_png16(const std::string &path, const HeightMap &map) {
    if (map.empty() || map.h.size() != size_t(map.width) * map.height)
        throw MesoError(fmt::format("cannot write '{}': empty height map ({}x{})", path, map.width, map.height));
    HeightRange r;
    auto [lo, hi] = std::minmax_element(map.h.begin(), map.h.end());
    r.lo = *lo, r.hi = *hi;
    if (!std::isfinite(r.lo) || !std::isfinite(r.hi))
        throw MesoError(fmt::format("cannot write '{}': the height map has non-finite values", path));
    double span = double(r.hi) - double(r.lo);
    std::vector<uint16_t> px(map.h.size());
    for (size_t k = 0; k < px.size(); ++k)
        px[k] = span > 0 ? uint16_t(std::lround((double(map.h[k]) - r.lo) / span * 65535.0)) : 0;

    write_png16_grey(path, map.width, map.height, px);
    return r;
}

HeightMap periodic_extension(const HeightMap &map, WrapMode mode) {
    if (mode == WrapMode::Repeat || map.empty()) return map;
    const int64_t W = map.width, H = map.height;
    auto index = [mode](int64_t i, int64_t n) {
        if (mode == WrapMode::Mirror) return wrap_index(i, n, WrapMode::Mirror);
        return i < n + n / 2 ? std::min(i, n - 1) : int64_t(0);  // clamp, negative side past n + n/2
    };
    HeightMap out(int(2 * W), int(2 * H));
    for (int64_t j = 0; j < 2 * H; ++j) {
        const int64_t sj = index(j, H);
        for (int64_t i = 0; i < 2 * W; ++i) out.at(int(i), int(j)) = map.at(int(index(i, W)), int(sj));
    }
    return out;
}

}  // namespace meso
