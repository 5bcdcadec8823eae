// Linear RGB radiance/reflectance triple.
#pragma once
#include "core/math.h"

namespace meso {

struct Spectrum {
    float r = 0, g = 0, b = 0;
    constexpr Spectrum() = default;
    constexpr explicit Spectrum(float v) : r(v), g(v), b(v) {}
    constexpr Spectrum(float r_, float g_, float b_) : r(r_), g(g_), b(b_) {}
    constexpr float operator[](int i) const { return i == 0 ? r : (i == 1 ? g : b); }
    float &operator[](int i) { return i == 0 ? r : (i == 1 ? g : b); }
    Spectrum &operator+=(const Spectrum &o) { r += o.r; g += o.g; b += o.b; return *this; }
    Spectrum &operator*=(const Spectrum &o) { r *= o.r; g *= o.g; b *= o.b; return *this; }
    Spectrum &operator*=(float s) { r *= s; g *= s; b *= s; return *this; }
    bool is_black() const { return r == 0.f && g == 0.f && b == 0.f; }
    bool is_finite() const { return std::isfinite(r) && std::isfinite(g) && std::isfinite(b); }
    float max() const { return std::max(r, std::max(g, b)); }
    float average() const { return (r + g + b) * (1.f / 3.f); }
    /// Rec. 709 / sRGB-primaries luminance.
    float luminance() const { return 0.2126f * r + 0.7152f * g + 0.0722f * b; }
};
inline constexpr Spectrum operator+(Spectrum a, Spectrum b) { return {a.r + b.r, a.g + b.g, a.b + b.b}; }
inline constexpr Spectrum operator-(Spectrum a, Spectrum b) { return {a.r - b.r, a.g - b.g, a.b - b.b}; }
inline constexpr Spectrum operator*(Spectrum a, Spectrum b) { return {a.r * b.r, a.g * b.g, a.b * b.b}; }
inline constexpr Spectrum operator*(Spectrum a, float s) { return {a.r * s, a.g * s, a.b * s}; }
inline constexpr Spectrum operator*(float s, Spectrum a) { return {a.r * s, a.g * s, a.b * s}; }
inline constexpr Spectrum operator/(Spectrum a, float s) { return a * (1.f / s); }
inline Spectrum operator/(Spectrum a, Spectrum b) {
    return {b.r != 0 ? a.r / b.r : 0.f, b.g != 0 ? a.g / b.g : 0.f, b.b != 0 ? a.b / b.b : 0.f};
}
inline Spectrum sqrt(Spectrum a) { return {safe_sqrt(a.r), safe_sqrt(a.g), safe_sqrt(a.b)}; }
inline Spectrum exp(Spectrum a) { return {std::exp(a.r), std::exp(a.g), std::exp(a.b)}; }

}  // namespace meso
