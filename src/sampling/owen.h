// Base-2 Owen scrambling by hashing (Burley 2020, "Practical Hash-based Owen Scrambling",
// JCGT 9(4)) and the closed-form generator matrices of the first two Sobol dimensions.
// Shared by the sobol sampler and its tests.
//
// Owen scrambling flips every binary digit of a value in [0, 1) depending on the digits
// before it (the more significant ones). Laine and Karras noticed that, on the *bit-reversed*
// integer, that is exactly what a hash does in which each bit depends only on the bits
// below it (additions, multiplications by odd constants, x ^= x * even). We use Vegdahl's
// improved hash (psychopath.io, 2021; also pbrt-v4's FastOwenScrambler and Cycles), which
// scrambles high digits far better than Laine-Karras' original constants.
#pragma once
#include <cstdint>
#include "core/math.h"

namespace meso {

inline uint32_t reverse_bits32(uint32_t v) {
    v = __builtin_bswap32(v);  // bytes reversed; then the bits within each byte
    v = ((v >> 4) & 0x0f0f0f0fu) | ((v & 0x0f0f0f0fu) << 4);
    v = ((v >> 2) & 0x33333333u) | ((v & 0x33333333u) << 2);
    return ((v >> 1) & 0x55555555u) | ((v & 0x55555555u) << 1);
}

/// Owen scrambling of a bit-reversed value: bit b is flipped by a function of bits < b
/// and the seed (a bijection on 32-bit integers for every seed).
inline uint32_t reversed_bit_owen(uint32_t v, uint32_t seed) {
    v ^= v * 0x3d20adeau;
    v += seed;
    v *= (seed >> 16) | 1u;
    v ^= v * 0x05526c56u;
    v ^= v * 0x53a22864u;
    return v;
}

/// Nested uniform (Owen) scrambling of a 32-bit fixed-point value in [0, 1): bit b
/// (counted from the least significant) is flipped by a function of bits > b.
/// Applied to a sample *index* it shuffles the sequence: indices [0, 2^k) map one-to-one
/// onto an aligned block [c 2^k, (c+1) 2^k) (c depends on the seed only).
inline uint32_t nested_uniform_scramble(uint32_t v, uint32_t seed) {
    return reverse_bits32(reversed_bit_owen(reverse_bits32(v), seed));
}

/// Sobol dimension 0 (van der Corput): the identity generator matrix, i.e. the index's
/// bits reversed into a 32-bit fraction.
inline uint32_t sobol_dim0(uint32_t index) { return reverse_bits32(index); }

namespace owen_detail {
/// Sobol dimension 1's generator matrix applied to each byte of an index: the matrix is linear
/// over GF(2), so the point is the XOR of four byte lookups (4 KB). The shuffled index of the
/// sobol sampler has all 32 bits random, and the bit loop this replaces took 32 iterations
/// with an unpredictable branch each (8% of a render's time in `perf`).
struct Dim1Table {
    uint32_t t[4][256];
};
constexpr Dim1Table make_dim1_table() {
    Dim1Table d{};
    uint32_t dir[32] = {};
    dir[0] = 0x80000000u;  // v_0 = 2^31, v_{i+1} = v_i ^ (v_i >> 1)
    for (int i = 1; i < 32; ++i) dir[i] = dir[i - 1] ^ (dir[i - 1] >> 1);
    for (int b = 0; b < 4; ++b)
        for (int v = 0; v < 256; ++v) {
            uint32_t x = 0;
            for (int j = 0; j < 8; ++j)
                if (v & (1 << j)) x ^= dir[8 * b + j];
            d.t[b][v] = x;
        }
    return d;
}
inline constexpr Dim1Table kDim1 = make_dim1_table();
}  // namespace owen_detail

/// Sobol dimension 1: generator matrix = Pascal's triangle mod 2 (primitive polynomial
/// x + 1, all m_i = 1). Its direction numbers follow v_0 = 2^31, v_{i+1} = v_i ^ (v_i >> 1);
/// the point is the XOR of the direction numbers of the index's set bits, by bytes.
/// Together with dimension 0 this is a (0, 2)-sequence in base 2: every aligned block of
/// 2^m points is a (0, m, 2)-net.
inline uint32_t sobol_dim1(uint32_t index) {
    const auto &t = owen_detail::kDim1.t;
    return t[0][index & 0xffu] ^ t[1][(index >> 8) & 0xffu] ^ t[2][(index >> 16) & 0xffu] ^ t[3][index >> 24];
}

/// 32-bit fixed point -> float in [0, 1), truncated to 24 bits: exact, so a point never
/// rounds across a cell boundary and the net's stratification survives the conversion.
inline float fixed_to_float(uint32_t v) { return float(v >> 8) * 0x1p-24f; }

}  // namespace meso
