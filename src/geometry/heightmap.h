// Height maps: a W x H grid of heights at grid VERTICES, periodic in both directions.
//
// Conventions (shared by the shell-map intersector, explicit tessellation, the
// generators and the prefiltering code):
//   * Cell space: x = u * W * tiling_u, y = v * H * tiling_v (uv as everywhere in meso:
//     (0,0) top-left, v down, so row 0 of the map is at v = 0). Vertex (i, j) of the map
//     sits at cell-space point (i, j) and repeats every W cells in x and H in y.
//   * The surface between vertices is piecewise bilinear: cell (i, j) covers
//     [i, i+1] x [j, j+1] and interpolates the heights of its four corners
//     (paper 004, Appendix A). It wraps across tiles: cell W-1 joins vertex W-1 to vertex 0.
//   * A map is dimensionless; a Displacement turns it into world units
//     (height = offset + scale * map value).
#pragma once
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>
#include "image/wrap_mode.h"

namespace meso {

struct HeightMap {
    int width = 0, height = 0;
    std::vector<float> h;  ///< width * height, row-major, row 0 at v = 0

    HeightMap() = default;
    HeightMap(int w, int hgt, float value = 0.f) : width(w), height(hgt), h(size_t(w) * hgt, value) {}
    float &at(int i, int j) { return h[size_t(j) * width + i]; }
    float at(int i, int j) const { return h[size_t(j) * width + i]; }
    /// Wrapped access for any integer i, j.
    float wrapped(int64_t i, int64_t j) const {
        int64_t a = i % width, b = j % height;
        if (a < 0) a += width;
        if (b < 0) b += height;
        return h[size_t(b) * width + size_t(a)];
    }
    size_t memory_bytes() const { return h.size() * sizeof(float); }
    bool empty() const { return h.empty(); }
};

/// The periodic map that equals `map` under `mode` (image/wrap_mode.h) wherever a surface reads it:
/// repeat: the map itself. mirror: the 2W x 2H map of vertex (wrap_index(i, W), wrap_index(j, H)),
/// exact everywhere (mirroring has period 2W). clamp: 2W x 2H, vertex i < W + W/2 is clamp(i) and
/// the rest is vertex 0 (the clamp of i - 2W), so it equals the clamped map for cell x in
/// [-(W - W/2), W + W/2), i.e. uv x tiling within [-0.5, 1.5) for W even: far enough for a
/// surface whose uvs span [0, 1] (ShellShape / tessellation check the actual range).
/// Callers keep the uv -> cell map by halving the tiling (Displacement does).
HeightMap periodic_extension(const HeightMap &map, WrapMode mode);
/// The cell range [lo, hi) in x (n = W) or y (n = H) where periodic_extension(clamp) is exact.
inline void clamp_extension_exact_range(int n, double &lo, double &hi) {
    lo = -double(n - n / 2);
    hi = double(n + n / 2);
}

/// Reads a height map: single-channel EXR (float), or 8/16-bit PNG/TIFF (values in [0,1],
/// no sRGB decoding), or any image OpenImageIO reads. Images with several channels are
/// accepted only when all colour channels are equal (a grey image stored as RGB); alpha
/// is ignored. Throws MesoError naming the file on failure or on non-finite values.
HeightMap read_height_map(const std::string &path);
/// Writes a single-channel float32 EXR (atomic, like write_exr).
void write_height_map(const std::string &path, const HeightMap &map);

/// Writes a 16-bit grey PNG of the map normalised to [0,1]: value = (h - lo) / (hi - lo)
/// with lo, hi the map's min and max (a constant map is written as 0). Returns {lo, hi};
/// reading it back gives h within (hi - lo) / 65535 after h = lo + (hi - lo) * value.
/// Atomic like write_height_map. Lossy: prefer EXR.
struct HeightRange {
    float lo = 0, hi = 0;
};
HeightRange write_height_map_png16(const std::string &path, const HeightMap &map);

}  // namespace meso
