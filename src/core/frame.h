// Orthonormal frame (s, t, n): converts between world space and the local shading frame
// in which materials work (z = normal).
#pragma once
#include "core/vec.h"

namespace meso {

/// Builds s, t perpendicular to a unit n (Duff et al. 2017, branchless, no singularity).
inline void coordinate_system(Vec3 n, Vec3 &s, Vec3 &t) {
    float sign = std::copysign(1.f, n.z);
    float a = -1.f / (sign + n.z);
    float b = n.x * n.y * a;
    s = Vec3(1.f + sign * n.x * n.x * a, sign * b, -sign * n.x);
    t = Vec3(b, sign + n.y * n.y * a, -n.y);
}

struct Frame {
    Vec3 s{1, 0, 0}, t{0, 1, 0}, n{0, 0, 1};
    Frame() = default;
    explicit Frame(Vec3 n_) : n(n_) { coordinate_system(n, s, t); }
    Frame(Vec3 s_, Vec3 t_, Vec3 n_) : s(s_), t(t_), n(n_) {}
    /// Frame with normal n whose s axis follows tangent dpdu (Gram-Schmidt); falls back to an
    /// arbitrary frame when dpdu is degenerate or parallel to n.
    static Frame from_normal_tangent(Vec3 n, Vec3 dpdu) {
        Vec3 s = dpdu - n * dot(n, dpdu);
        float l2 = length_squared(s);
        if (!(l2 > 1e-20f)) return Frame(n);
        s = s / std::sqrt(l2);
        return Frame(s, cross(n, s), n);
    }
    Vec3 to_local(Vec3 v) const { return {dot(v, s), dot(v, t), dot(v, n)}; }
    Vec3 to_world(Vec3 v) const { return s * v.x + t * v.y + n * v.z; }

    // Local-frame trigonometry helpers (v must be unit length, in the local frame).
    static float cos_theta(Vec3 v) { return v.z; }
    static float cos2_theta(Vec3 v) { return v.z * v.z; }
    static float sin2_theta(Vec3 v) { return std::max(0.f, 1.f - v.z * v.z); }
    static float sin_theta(Vec3 v) { return std::sqrt(sin2_theta(v)); }
    static float tan_theta(Vec3 v) { return sin_theta(v) / v.z; }
    static float tan2_theta(Vec3 v) { return sin2_theta(v) / (v.z * v.z); }
    static float cos_phi(Vec3 v) {
        float st = sin_theta(v);
        return st == 0.f ? 1.f : clamp(v.x / st, -1.f, 1.f);
    }
    static float sin_phi(Vec3 v) {
        float st = sin_theta(v);
        return st == 0.f ? 0.f : clamp(v.y / st, -1.f, 1.f);
    }
};

}  // namespace meso
