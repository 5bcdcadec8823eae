// PCG32 (O'Neill 2014): small, fast, statistically strong; the independent sampler and
// every test draw from it. Streams are selected by hashing (pixel, sample index, seed).
#pragma once
#include <cstdint>
#include "core/math.h"

namespace meso {

/// 64-bit mix (splitmix64 finaliser); turns structured integers into well-spread seeds.
inline uint64_t mix_bits(uint64_t v) {
    v ^= v >> 31;
    v *= 0x7fb5d329728ea185ULL;
    v ^= v >> 27;
    v *= 0x81dadef4bc2dd44dULL;
    v ^= v >> 33;
    return v;
}
inline uint64_t hash_combine(uint64_t a, uint64_t b) { return mix_bits(a ^ (b + 0x9e3779b97f4a7c15ULL + (a << 6) + (a >> 2))); }

class PCG32 {
public:
    PCG32() { seed(0x853c49e6748fea9bULL, 0xda3e39cb94b95bdbULL); }
    PCG32(uint64_t seq_index, uint64_t offset = 0x853c49e6748fea9bULL) { seed(offset, seq_index); }
    void seed(uint64_t init_state, uint64_t init_seq) {
        m_state = 0u;
        m_inc = (init_seq << 1u) | 1u;
        next_u32();
        m_state += init_state;
        next_u32();
    }
    uint32_t next_u32() {
        uint64_t old = m_state;
        m_state = old * 0x5851f42d4c957f2dULL + m_inc;
        uint32_t xorshifted = uint32_t(((old >> 18u) ^ old) >> 27u);
        uint32_t rot = uint32_t(old >> 59u);
        return (xorshifted >> rot) | (xorshifted << ((~rot + 1u) & 31));
    }
    /// Uniform in [0, 1).
    float next_float() { return std::min(OneMinusEpsilon, float(next_u32()) * 0x1p-32f); }
    double next_double() { return (double(next_u32()) * 0x1p-32 + double(next_u32())) * 0x1p-32; }
    uint32_t next_bounded(uint32_t bound) {
        uint32_t threshold = (~bound + 1u) % bound;
        for (;;) {
            uint32_t r = next_u32();
            if (r >= threshold) return r % bound;
        }
    }

private:
    uint64_t m_state, m_inc;
};

}  // namespace meso
