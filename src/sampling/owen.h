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
    v = ((v >> 1) & 0x55555555u) | ((v & 0x55555555u) << 1);
    v = ((v >> 2) & 0x33333333u) | ((v & 0x33333333u) << 2);
    v = ((v >> 4) & 0x0f0f0f0fu) | ((v & 0x0f0f0f0fu) << 4);
    v = ((v >> 8) & 0x00ff00ffu) | ((v & 0x00ff00ffu) << 8);
    return (v >> 16) | (v << 16);
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

/// Sobol dimension 1: generator matrix = Pascal's triangle mod 2 (primitive polynomial
/// x + 1, all m_i = 1). Its direction numbers follow v_0 = 2^31, v_{i+1} = v_i ^ (v_i >> 1).
/// Together with dimension 0 this is a (0, 2)-sequence in base 2: every aligned block of
/// 2^m points is a (0, m, 2)-net.
inline uint32_t sobol_dim1(uint32_t index) {
    uint32_t x = 0, v = 0x80000000u;
    for (; index; index >>= 1, v ^= v >> 1)
        if (index & 1u) x ^= v;
    return x;
}

/// 32-bit fixed point -> float in [0, 1), truncated to 24 bits: exact, so a point never
/// rounds across a cell boundary and the net's stratification survives the conversion.
inline float fixed_to_float(uint32_t v) { return float(v >> 8) * 0x1p-24f; }

}  // namespace meso
