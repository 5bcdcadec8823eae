// 4x4 affine transforms for placing shapes, cameras and environment maps.
#pragma once
#include "core/vec.h"

namespace meso {

struct Transform {
    float m[4][4] = {{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}, {0, 0, 0, 1}};
    float inv[4][4] = {{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}, {0, 0, 0, 1}};

    static Transform translate(Vec3 t);
    static Transform scale(Vec3 s);
    /// Rotation by `angle_deg` degrees about `axis`.
    static Transform rotate(Vec3 axis, float angle_deg);
    /// Camera-to-world look-at (camera looks along +z, y up, x left-handed as in Mitsuba).
    static Transform look_at(Vec3 origin, Vec3 target, Vec3 up);
    /// From a row-major 4x4 matrix; throws MesoError if singular.
    static Transform from_matrix(const float rows[16]);

    Vec3 apply_point(Vec3 p) const;
    Vec3 apply_vector(Vec3 v) const;
    /// Normals transform by the inverse transpose.
    Vec3 apply_normal(Vec3 n) const;
    Vec3 apply_inverse_point(Vec3 p) const;
    Vec3 apply_inverse_vector(Vec3 v) const;
    Transform inverse() const;
    bool is_identity() const;
    /// Determinant of the upper 3x3 (negative for mirroring transforms).
    float det3() const;
};

/// a * b: apply b first, then a.
Transform operator*(const Transform &a, const Transform &b);

}  // namespace meso
