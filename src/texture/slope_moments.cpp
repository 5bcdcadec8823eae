#include "texture/slope_moments.h"
#include <cmath>
#include <fmt/format.h>
#include "core/error.h"

namespace meso {

MipMap build_slope_moments(const Heightfield &hf, double tile_u, double tile_v) {
    if (!(tile_u > 0.0) || !(tile_v > 0.0) || !std::isfinite(tile_u) || !std::isfinite(tile_v))
        throw MesoError(fmt::format("slope moments: tile size in uv must be positive, got {} x {}", tile_u, tile_v));
    const int w = hf.width(), h = hf.height();
    // Cells per unit uv: slopes per cell times these are slopes per unit uv.
    const double su = double(w) / tile_u, sv = double(h) / tile_v;
    std::vector<float> data(size_t(w) * h * SlopeMomentCount);
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < w; ++i) {
            const double h00 = hf.vertex(i, j), h10 = hf.vertex(i + 1, j), h01 = hf.vertex(i, j + 1),
                         h11 = hf.vertex(i + 1, j + 1);
            const double e = (h10 - h00) * su, f = (h01 - h00) * sv;
            const double gx = (h00 + h11 - h10 - h01) * su, gy = (h00 + h11 - h10 - h01) * sv;
            float *m = &data[(size_t(j) * w + i) * SlopeMomentCount];
            m[MomentX] = float(e + gx / 2);
            m[MomentY] = float(f + gy / 2);
            m[MomentXX] = float(e * e + e * gx + gx * gx / 3);
            m[MomentYY] = float(f * f + f * gy + gy * gy / 3);
            m[MomentXY] = float((e + gx / 2) * (f + gy / 2));
        }
    return MipMap(w, h, SlopeMomentCount, std::move(data), WrapMode::Repeat);
}

MipMap build_height_moments(const Heightfield &hf, double center) {
    const int w = hf.width(), h = hf.height();
    std::vector<float> data(size_t(w) * h * 2);
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < w; ++i) {
            const double a = hf.vertex(i, j) - center, b = hf.vertex(i + 1, j) - center,
                         c = hf.vertex(i, j + 1) - center, d = hf.vertex(i + 1, j + 1) - center;
            float *m = &data[(size_t(j) * w + i) * 2];
            m[0] = float((a + b + c + d) / 4);
            // E[w_i w_k] over one axis: 1/3 for the same end, 1/6 for opposite ends.
            m[1] = float((a * a + b * b + c * c + d * d) / 9 + (a * b + a * c + b * d + c * d) / 9 + (a * d + b * c) / 18);
        }
    return MipMap(w, h, 2, std::move(data), WrapMode::Repeat);
}

}  // namespace meso
