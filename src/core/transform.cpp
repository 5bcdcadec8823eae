#include "core/transform.h"
#include "core/error.h"

namespace meso {

static bool invert4(const float a[4][4], float out[4][4]) {
    // Gauss-Jordan with partial pivoting in double precision.
    double m[4][8];
    for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 8; ++j) m[i][j] = j < 4 ? a[i][j] : (j - 4 == i ? 1.0 : 0.0);
    for (int c = 0; c < 4; ++c) {
        int piv = c;
        for (int r = c + 1; r < 4; ++r)
            if (std::abs(m[r][c]) > std::abs(m[piv][c])) piv = r;
        if (std::abs(m[piv][c]) < 1e-12) return false;
        if (piv != c)
            for (int j = 0; j < 8; ++j) std::swap(m[c][j], m[piv][j]);
        double d = m[c][c];
        for (int j = 0; j < 8; ++j) m[c][j] /= d;
        for (int r = 0; r < 4; ++r) {
            if (r == c) continue;
            double f = m[r][c];
            for (int j = 0; j < 8; ++j) m[r][j] -= f * m[c][j];
        }
    }
    for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j) out[i][j] = float(m[i][j + 4]);
    return true;
}

Transform Transform::from_matrix(const float rows[16]) {
    Transform t;
    for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j) t.m[i][j] = rows[i * 4 + j];
    if (!invert4(t.m, t.inv)) throw MesoError("transform matrix is singular");
    return t;
}

Transform Transform::translate(Vec3 d) {
    Transform t;
    t.m[0][3] = d.x; t.m[1][3] = d.y; t.m[2][3] = d.z;
    t.inv[0][3] = -d.x; t.inv[1][3] = -d.y; t.inv[2][3] = -d.z;
    return t;
}

Transform Transform::scale(Vec3 s) {
    if (s.x == 0.f || s.y == 0.f || s.z == 0.f) throw MesoError("scale has a zero component (singular transform)");
    Transform t;
    t.m[0][0] = s.x; t.m[1][1] = s.y; t.m[2][2] = s.z;
    t.inv[0][0] = 1.f / s.x; t.inv[1][1] = 1.f / s.y; t.inv[2][2] = 1.f / s.z;
    return t;
}

Transform Transform::rotate(Vec3 axis, float angle_deg) {
    Vec3 a = normalize(axis);
    if (length_squared(a) == 0.f) throw MesoError("rotation axis is zero");
    float s = std::sin(radians(angle_deg)), c = std::cos(radians(angle_deg));
    Transform t;
    t.m[0][0] = a.x * a.x + (1 - a.x * a.x) * c;
    t.m[0][1] = a.x * a.y * (1 - c) - a.z * s;
    t.m[0][2] = a.x * a.z * (1 - c) + a.y * s;
    t.m[1][0] = a.x * a.y * (1 - c) + a.z * s;
    t.m[1][1] = a.y * a.y + (1 - a.y * a.y) * c;
    t.m[1][2] = a.y * a.z * (1 - c) - a.x * s;
    t.m[2][0] = a.x * a.z * (1 - c) - a.y * s;
    t.m[2][1] = a.y * a.z * (1 - c) + a.x * s;
    t.m[2][2] = a.z * a.z + (1 - a.z * a.z) * c;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) t.inv[i][j] = t.m[j][i];  // orthonormal: inverse = transpose
    return t;
}

Transform Transform::look_at(Vec3 origin, Vec3 target, Vec3 up) {
    Vec3 dir = normalize(target - origin);
    if (length_squared(dir) == 0.f) throw MesoError("look_at: origin and target coincide");
    Vec3 left = normalize(cross(normalize(up), dir));
    if (length_squared(left) == 0.f) throw MesoError("look_at: 'up' is parallel to the viewing direction");
    Vec3 new_up = cross(dir, left);
    float rows[16] = {left.x, new_up.x, dir.x, origin.x,  //
                      left.y, new_up.y, dir.y, origin.y,  //
                      left.z, new_up.z, dir.z, origin.z,  //
                      0, 0, 0, 1};
    return from_matrix(rows);
}

static Vec3 mul_point(const float m[4][4], Vec3 p) {
    float x = m[0][0] * p.x + m[0][1] * p.y + m[0][2] * p.z + m[0][3];
    float y = m[1][0] * p.x + m[1][1] * p.y + m[1][2] * p.z + m[1][3];
    float z = m[2][0] * p.x + m[2][1] * p.y + m[2][2] * p.z + m[2][3];
    float w = m[3][0] * p.x + m[3][1] * p.y + m[3][2] * p.z + m[3][3];
    return w == 1.f ? Vec3(x, y, z) : Vec3(x, y, z) / w;
}
static Vec3 mul_vector(const float m[4][4], Vec3 v) {
    return {m[0][0] * v.x + m[0][1] * v.y + m[0][2] * v.z, m[1][0] * v.x + m[1][1] * v.y + m[1][2] * v.z,
            m[2][0] * v.x + m[2][1] * v.y + m[2][2] * v.z};
}

Vec3 Transform::apply_point(Vec3 p) const { return mul_point(m, p); }
Vec3 Transform::apply_vector(Vec3 v) const { return mul_vector(m, v); }
Vec3 Transform::apply_normal(Vec3 n) const {
    return {inv[0][0] * n.x + inv[1][0] * n.y + inv[2][0] * n.z, inv[0][1] * n.x + inv[1][1] * n.y + inv[2][1] * n.z,
            inv[0][2] * n.x + inv[1][2] * n.y + inv[2][2] * n.z};
}
Vec3 Transform::apply_inverse_point(Vec3 p) const { return mul_point(inv, p); }
Vec3 Transform::apply_inverse_vector(Vec3 v) const { return mul_vector(inv, v); }

Transform Transform::inverse() const {
    Transform t;
    std::memcpy(t.m, inv, sizeof(m));
    std::memcpy(t.inv, m, sizeof(m));
    return t;
}

bool Transform::is_identity() const {
    for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j)
            if (m[i][j] != (i == j ? 1.f : 0.f)) return false;
    return true;
}

float Transform::det3() const {
    return m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
           m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
}

Transform operator*(const Transform &a, const Transform &b) {
    Transform r;
    for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j) {
            float s = 0.f, si = 0.f;
            for (int k = 0; k < 4; ++k) {
                s += a.m[i][k] * b.m[k][j];
                si += b.inv[i][k] * a.inv[k][j];
            }
            r.m[i][j] = s;
            r.inv[i][j] = si;
        }
    return r;
}

}  // namespace meso
