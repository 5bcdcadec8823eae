// Scalar math helpers shared by every module: constants, clamps and numerically
// safe forms (safe_sqrt, safe_acos) that keep grazing-angle and degenerate inputs finite.
#pragma once
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

namespace meso {

constexpr float Pi = 3.14159265358979323846f;
constexpr float InvPi = 0.31830988618379067154f;
constexpr float Inv2Pi = 0.15915494309189533577f;
constexpr float Inv4Pi = 0.07957747154594766788f;
constexpr float PiOver2 = 1.57079632679489661923f;
constexpr float PiOver4 = 0.78539816339744830961f;
constexpr float Sqrt2 = 1.41421356237309504880f;
constexpr float Infinity = std::numeric_limits<float>::infinity();
constexpr float OneMinusEpsilon = 0x1.fffffep-1f;  // largest float below 1

template <typename T> constexpr T sqr(T x) { return x * x; }
template <typename T> constexpr T clamp(T v, T lo, T hi) { return v < lo ? lo : (v > hi ? hi : v); }
template <typename T> constexpr T lerp(float t, T a, T b) { return (1 - t) * a + t * b; }

inline float safe_sqrt(float x) { return std::sqrt(std::max(x, 0.f)); }
inline double safe_sqrt(double x) { return std::sqrt(std::max(x, 0.0)); }
inline float safe_acos(float x) { return std::acos(clamp(x, -1.f, 1.f)); }
inline float safe_asin(float x) { return std::asin(clamp(x, -1.f, 1.f)); }
inline float radians(float deg) { return deg * (Pi / 180.f); }
inline float degrees(float rad) { return rad * (180.f / Pi); }
inline bool is_finite(float x) { return std::isfinite(x); }

/// Next representable float towards +inf / -inf (used for robust ray offsets).
inline float next_float_up(float v) {
    if (std::isinf(v) && v > 0.f) return v;
    if (v == -0.f) v = 0.f;
    uint32_t ui;
    std::memcpy(&ui, &v, sizeof(float));
    ui = (v >= 0) ? ui + 1 : ui - 1;
    std::memcpy(&v, &ui, sizeof(float));
    return v;
}

/// Integer log2 rounded down; 0 for v <= 1.
inline int log2_int(uint32_t v) { return v <= 1 ? 0 : 31 - __builtin_clz(v); }

/// atan(a) for a in [0, 1] (Abramowitz and Stegun 4.4.49: a times a polynomial of degree 8 in
/// z = a^2, error 2e-8 in exact arithmetic, about 1e-7 in float), the polynomial by Estrin's
/// scheme: pairs of coefficients, then powers z^2, z^4, z^8, in about half the dependent
/// multiply-adds of Horner's (the samplers' set-ups and the S lookup wait on it). T: float, or a
/// float vector type (GCC vector extension) evaluated lane by lane.
template <class T> inline T atan_unit_interval(T a) {
    const T z = a * a, z2 = z * z, z4 = z2 * z2, z8 = z4 * z4;
    const T q0 = -0.3333314528f * z + 1.f, q1 = -0.1420889944f * z + 0.1999355085f;
    const T q2 = -0.0752896400f * z + 0.1065626393f, q3 = -0.0161657367f * z + 0.0429096138f;
    const T p = (q0 + q1 * z2) + (q2 + q3 * z2) * z4 + 0.0028662257f * z8;
    return a * p;
}

}  // namespace meso
