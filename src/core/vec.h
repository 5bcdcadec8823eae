// Small fixed-size vector types. Float precision throughout (it is what Embree traces
// with); directions point away from the surface; the local shading frame has z = normal.
#pragma once
#include "core/math.h"

namespace meso {

struct Vec2 {
    float x = 0, y = 0;
    constexpr Vec2() = default;
    constexpr Vec2(float x_, float y_) : x(x_), y(y_) {}
    constexpr float operator[](int i) const { return i == 0 ? x : y; }
    float &operator[](int i) { return i == 0 ? x : y; }
};
inline constexpr Vec2 operator+(Vec2 a, Vec2 b) { return {a.x + b.x, a.y + b.y}; }
inline constexpr Vec2 operator-(Vec2 a, Vec2 b) { return {a.x - b.x, a.y - b.y}; }
inline constexpr Vec2 operator*(Vec2 a, float s) { return {a.x * s, a.y * s}; }
inline constexpr Vec2 operator*(float s, Vec2 a) { return {a.x * s, a.y * s}; }

struct Vec3 {
    float x = 0, y = 0, z = 0;
    constexpr Vec3() = default;
    constexpr Vec3(float x_, float y_, float z_) : x(x_), y(y_), z(z_) {}
    constexpr float operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
    float &operator[](int i) { return i == 0 ? x : (i == 1 ? y : z); }
    Vec3 &operator+=(Vec3 b) { x += b.x; y += b.y; z += b.z; return *this; }
    Vec3 &operator-=(Vec3 b) { x -= b.x; y -= b.y; z -= b.z; return *this; }
    Vec3 &operator*=(float s) { x *= s; y *= s; z *= s; return *this; }
};
inline constexpr Vec3 operator+(Vec3 a, Vec3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
inline constexpr Vec3 operator-(Vec3 a, Vec3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
inline constexpr Vec3 operator-(Vec3 a) { return {-a.x, -a.y, -a.z}; }
inline constexpr Vec3 operator*(Vec3 a, float s) { return {a.x * s, a.y * s, a.z * s}; }
inline constexpr Vec3 operator*(float s, Vec3 a) { return {a.x * s, a.y * s, a.z * s}; }
inline constexpr Vec3 operator/(Vec3 a, float s) { return a * (1.f / s); }
inline constexpr Vec3 mul(Vec3 a, Vec3 b) { return {a.x * b.x, a.y * b.y, a.z * b.z}; }
inline constexpr float dot(Vec3 a, Vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline float absdot(Vec3 a, Vec3 b) { return std::abs(dot(a, b)); }
inline constexpr Vec3 cross(Vec3 a, Vec3 b) {
    return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline float length_squared(Vec3 a) { return dot(a, a); }
inline float length(Vec3 a) { return std::sqrt(dot(a, a)); }
/// Normalise; a zero vector stays zero (never NaN).
inline Vec3 normalize(Vec3 a) {
    float l = length(a);
    return l > 0.f ? a / l : Vec3{};
}
inline Vec3 vabs(Vec3 a) { return {std::abs(a.x), std::abs(a.y), std::abs(a.z)}; }
inline Vec3 vmin(Vec3 a, Vec3 b) { return {std::min(a.x, b.x), std::min(a.y, b.y), std::min(a.z, b.z)}; }
inline Vec3 vmax(Vec3 a, Vec3 b) { return {std::max(a.x, b.x), std::max(a.y, b.y), std::max(a.z, b.z)}; }
inline float max_component(Vec3 a) { return std::max(a.x, std::max(a.y, a.z)); }
inline bool is_finite(Vec3 a) { return std::isfinite(a.x) && std::isfinite(a.y) && std::isfinite(a.z); }
/// Mirror reflection of w about n (both pointing away from the surface).
inline Vec3 reflect(Vec3 w, Vec3 n) { return 2.f * dot(w, n) * n - w; }
/// Flip n to lie in the hemisphere of v.
inline Vec3 face_forward(Vec3 n, Vec3 v) { return dot(n, v) < 0.f ? -n : n; }

/// Direction from spherical angles in the local frame (theta from +z, phi from +x).
inline Vec3 spherical_direction(float theta, float phi) {
    float st = std::sin(theta);
    return {st * std::cos(phi), st * std::sin(phi), std::cos(theta)};
}

}  // namespace meso
