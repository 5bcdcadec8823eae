#include "geometry/mesh.h"
#include <array>
#include <cmath>
#include <fmt/format.h>
#include <unordered_map>
#include "core/error.h"

namespace meso {

void TriangleMesh::transform(const Transform &t) {
    if (t.is_identity()) return;
    for (auto &p : positions) p = t.apply_point(p);
    for (auto &n : normals) n = normalize(t.apply_normal(n));
    for (auto &v : tangents) v = normalize(t.apply_vector(v));
    // A mirroring transform flips the winding-defined geometric normal: restore it.
    if (t.det3() < 0.f)
        for (size_t i = 0; i + 2 < indices.size(); i += 3) std::swap(indices[i + 1], indices[i + 2]);
}

float TriangleMesh::triangle_area(size_t tri) const {
    const Vec3 &a = positions[indices[3 * tri]], &b = positions[indices[3 * tri + 1]], &c = positions[indices[3 * tri + 2]];
    return 0.5f * length(cross(b - a, c - a));
}

float TriangleMesh::surface_area() const {
    double a = 0;
    for (size_t i = 0; i < triangle_count(); ++i) a += triangle_area(i);
    return float(a);
}

bool TriangleMesh::uv_world_length(double &lu, double &lv) const {
    if (uvs.size() != positions.size()) return false;
    double su = 0, sv = 0, area = 0;
    for (size_t t = 0; t < triangle_count(); ++t) {
        const uint32_t i0 = indices[3 * t], i1 = indices[3 * t + 1], i2 = indices[3 * t + 2];
        const Vec2 d1 = uvs[i1] - uvs[i0], d2 = uvs[i2] - uvs[i0];
        const double det = double(d1.x) * d2.y - double(d1.y) * d2.x;
        const double a = triangle_area(t);
        if (!(std::abs(det) > 1e-20) || !(a > 0)) continue;
        const Vec3 e1 = positions[i1] - positions[i0], e2 = positions[i2] - positions[i0];
        const Vec3 dpdu = (e1 * d2.y - e2 * d1.y) * float(1 / det), dpdv = (e2 * d1.x - e1 * d2.x) * float(1 / det);
        su += a * length(dpdu);
        sv += a * length(dpdv);
        area += a;
    }
    if (!(area > 0) || !std::isfinite(su) || !std::isfinite(sv)) return false;
    lu = su / area;
    lv = sv / area;
    return true;
}

size_t TriangleMesh::memory_bytes() const {
    return positions.size() * sizeof(Vec3) + normals.size() * sizeof(Vec3) + uvs.size() * sizeof(Vec2) +
           tangents.size() * sizeof(Vec3) + tangent_signs.size() * sizeof(float) + indices.size() * sizeof(uint32_t);
}

void TriangleMesh::validate(const std::string &where) const {
    if (indices.size() % 3 != 0) throw MesoError(fmt::format("{}: index count {} is not a multiple of 3", where, indices.size()));
    size_t nv = positions.size();
    auto check = [&](size_t n, const char *what) {
        if (n != 0 && n != nv)
            throw MesoError(fmt::format("{}: {} has {} entries, expected {} (one per vertex)", where, what, n, nv));
    };
    check(normals.size(), "normals");
    check(uvs.size(), "uvs");
    check(tangents.size(), "tangents");
    for (size_t i = 0; i < indices.size(); ++i)
        if (indices[i] >= nv) throw MesoError(fmt::format("{}: index {} = {} is out of range ({} vertices)", where, i, indices[i], nv));
    for (const Vec3 &p : positions)
        if (!is_finite(p)) throw MesoError(fmt::format("{}: vertex position is not finite", where));
}

TriangleMesh make_rectangle() {
    TriangleMesh m;
    m.positions = {{-1, -1, 0}, {1, -1, 0}, {1, 1, 0}, {-1, 1, 0}};
    m.normals = {{0, 0, 1}, {0, 0, 1}, {0, 0, 1}, {0, 0, 1}};
    m.uvs = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
    m.indices = {0, 1, 2, 0, 2, 3};
    return m;
}

TriangleMesh make_cube() {
    TriangleMesh m;
    // Each face: normal axis, and two tangent axes (u, v) with u x v = n.
    const Vec3 normals[6] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
    for (int f = 0; f < 6; ++f) {
        Vec3 n = normals[f], u, v;
        u = std::abs(n.x) > 0 ? Vec3(0, n.x, 0) : (std::abs(n.y) > 0 ? Vec3(0, 0, n.y) : Vec3(n.z, 0, 0));
        v = cross(n, u);
        uint32_t base = uint32_t(m.positions.size());
        const float c[4][2] = {{-1, -1}, {1, -1}, {1, 1}, {-1, 1}};
        for (auto &k : c) {
            m.positions.push_back(n + u * k[0] + v * k[1]);
            m.normals.push_back(n);
            m.uvs.push_back({0.5f * (k[0] + 1), 0.5f * (k[1] + 1)});
        }
        m.indices.insert(m.indices.end(), {base, base + 1, base + 2, base, base + 2, base + 3});
    }
    return m;
}

TriangleMesh make_disk(int segments) {
    TriangleMesh m;
    m.positions.push_back({0, 0, 0});
    m.normals.push_back({0, 0, 1});
    m.uvs.push_back({0.5f, 0.5f});
    for (int i = 0; i < segments; ++i) {
        float phi = 2.f * Pi * i / segments;
        m.positions.push_back({std::cos(phi), std::sin(phi), 0});
        m.normals.push_back({0, 0, 1});
        m.uvs.push_back({0.5f + 0.5f * std::cos(phi), 0.5f + 0.5f * std::sin(phi)});
    }
    for (int i = 0; i < segments; ++i)
        m.indices.insert(m.indices.end(), {0u, uint32_t(1 + i), uint32_t(1 + (i + 1) % segments)});
    return m;
}

TriangleMesh make_uv_sphere(int rings, int segments) {
    TriangleMesh m;
    for (int r = 0; r <= rings; ++r) {
        float theta = Pi * r / rings;
        for (int s = 0; s <= segments; ++s) {
            float phi = 2.f * Pi * s / segments;
            Vec3 p = spherical_direction(theta, phi);
            m.positions.push_back(p);
            m.normals.push_back(p);
            m.uvs.push_back({float(s) / segments, float(r) / rings});
        }
    }
    for (int r = 0; r < rings; ++r)
        for (int s = 0; s < segments; ++s) {
            uint32_t a = r * (segments + 1) + s, b = a + segments + 1;
            if (r != 0) m.indices.insert(m.indices.end(), {a, b, a + 1});
            if (r != rings - 1) m.indices.insert(m.indices.end(), {a + 1, b, b + 1});
        }
    return m;
}

std::vector<uint32_t> weld_vertices(const TriangleMesh &mesh) {
    // Tolerance: 1e-6 of the largest bounding-box extent (uv-sphere seams and poles agree
    // only up to the round-off of sin/cos). Vertices are binned on a grid of that size and
    // compared with the 27 neighbouring bins.
    const size_t n = mesh.vertex_count();
    std::vector<uint32_t> weld(n);
    if (n == 0) return weld;
    Vec3 lo = mesh.positions[0], hi = lo;
    for (const Vec3 &p : mesh.positions) lo = vmin(lo, p), hi = vmax(hi, p);
    const double tol = std::max(1e-6 * double(max_component(hi - lo)), 1e-30);
    auto cell = [&](float v, float l) { return int64_t(std::floor((double(v) - l) / tol)); };
    struct Hash {
        size_t operator()(const std::array<int64_t, 3> &k) const {
            uint64_t h = uint64_t(k[0]) * 0x9E3779B97F4A7C15ull ^ uint64_t(k[1]) * 0xC2B2AE3D27D4EB4Full ^
                         uint64_t(k[2]) * 0x165667B19E3779F9ull;
            return size_t(h ^ (h >> 31));
        }
    };
    std::unordered_map<std::array<int64_t, 3>, std::vector<uint32_t>, Hash> bins;
    bins.reserve(n);
    for (uint32_t i = 0; i < n; ++i) {
        const Vec3 &p = mesh.positions[i];
        const std::array<int64_t, 3> c = {cell(p.x, lo.x), cell(p.y, lo.y), cell(p.z, lo.z)};
        uint32_t rep = i;
        for (int dz = -1; dz <= 1 && rep == i; ++dz)
            for (int dy = -1; dy <= 1 && rep == i; ++dy)
                for (int dx = -1; dx <= 1 && rep == i; ++dx) {
                    auto it = bins.find({c[0] + dx, c[1] + dy, c[2] + dz});
                    if (it == bins.end()) continue;
                    for (uint32_t j : it->second) {
                        const Vec3 d = mesh.positions[j] - p;
                        if (std::abs(d.x) <= tol && std::abs(d.y) <= tol && std::abs(d.z) <= tol) {
                            rep = j;
                            break;
                        }
                    }
                }
        weld[i] = rep;
        if (rep == i) bins[c].push_back(i);
    }
    return weld;
}

std::vector<Vec3> vertex_normals(const TriangleMesh &mesh, const std::vector<uint32_t> &weld) {
    std::vector<Vec3> acc(mesh.vertex_count());
    for (size_t t = 0; t < mesh.triangle_count(); ++t) {
        const uint32_t *v = &mesh.indices[3 * t];
        Vec3 n = cross(mesh.positions[v[1]] - mesh.positions[v[0]], mesh.positions[v[2]] - mesh.positions[v[0]]);
        if (!is_finite(n)) continue;
        for (int k = 0; k < 3; ++k) acc[weld[v[k]]] += n;
    }
    std::vector<Vec3> out(mesh.vertex_count());
    for (size_t i = 0; i < out.size(); ++i) out[i] = normalize(acc[weld[i]]);
    return out;
}

}  // namespace meso
