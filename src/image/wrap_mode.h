// How a grid of samples (image texels, height-map vertices) continues outside its W x H extent:
// "repeat" (periodic), "clamp" (the edge sample extends) or "mirror" (reflected copies, period 2W:
// ..., 1, 0 | 0, 1, ..., W-1 | W-1, W-2, ...). Shared by MIP-mapped textures (texture/mipmap) and
// displacement maps (geometry/displacement: a clamped or mirrored map becomes a periodic one of
// twice the size, geometry/heightmap's periodic_extension).
#pragma once
#include <cstdint>
#include <string>

namespace meso {

enum class WrapMode { Repeat, Clamp, Mirror };

/// Index of sample `i` (any integer) in [0, n).
inline int64_t wrap_index(int64_t i, int64_t n, WrapMode mode) {
    switch (mode) {
        case WrapMode::Clamp: return i < 0 ? 0 : (i >= n ? n - 1 : i);
        case WrapMode::Mirror: {
            const int64_t p = 2 * n, m = ((i % p) + p) % p;
            return m < n ? m : p - 1 - m;
        }
        case WrapMode::Repeat:
        default: return i >= 0 && i < n ? i : ((i % n) + n) % n;  // in range (the common case): no division
    }
}

/// "repeat", "clamp" or "mirror".
const char *wrap_mode_name(WrapMode mode);

class Properties;
/// The wrap parameter `key` ("repeat", "clamp" or "mirror"; `def` when absent).
WrapMode parse_wrap_mode(const Properties &p, const std::string &key, WrapMode def = WrapMode::Repeat);
/// A texture's edge mode under either of its names: "wrap_mode" (Mitsuba 3's) or "wrap" (the
/// displacement's); giving both is an error.
WrapMode parse_texture_wrap(const Properties &p);

}  // namespace meso
