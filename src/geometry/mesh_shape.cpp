#include "geometry/mesh_shape.h"
#include <fmt/format.h>
#include "core/error.h"
#include "geometry/shell_shape.h"
#include "geometry/tessellate.h"
#include "sampling/warp.h"
#include "core/properties.h"
#include "core/registry.h"
#include "core/transform_parse.h"

namespace meso {

MeshShape::MeshShape(TriangleMesh mesh, std::string name) : m_mesh(std::move(mesh)), m_name(std::move(name)) {
    m_mesh.validate(m_name);
    std::vector<float> areas(m_mesh.triangle_count());
    double total = 0;
    for (size_t i = 0; i < areas.size(); ++i) {
        areas[i] = m_mesh.triangle_area(i);
        if (!std::isfinite(areas[i])) areas[i] = 0.f;
        total += areas[i];
    }
    m_area = float(total);
    m_area_distr = Distribution1D(areas);
    m_has_normals = !m_mesh.normals.empty();
    m_has_uvs = !m_mesh.uvs.empty();
    m_vertices.assign(m_mesh.vertex_count() * Stride, 0.f);
    for (size_t i = 0; i < m_mesh.vertex_count(); ++i) {
        float *v = &m_vertices[i * Stride];
        v[0] = m_mesh.positions[i].x, v[1] = m_mesh.positions[i].y, v[2] = m_mesh.positions[i].z;
        if (m_has_normals) v[3] = m_mesh.normals[i].x, v[4] = m_mesh.normals[i].y, v[5] = m_mesh.normals[i].z;
        if (m_has_uvs) v[6] = m_mesh.uvs[i].x, v[7] = m_mesh.uvs[i].y;
    }
}

RTCGeometry MeshShape::build_embree(RTCDevice device) const {
    RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    // Shared buffers (no copy): Embree reads vertices in 16-byte loads, which stay inside
    // each 32-byte interleaved record, and the shape outlives the Embree scene.
    rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, m_vertices.data(), 0,
                               Stride * sizeof(float), m_mesh.vertex_count());
    rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, m_mesh.indices.data(), 0,
                               3 * sizeof(uint32_t), m_mesh.triangle_count());
    rtcCommitGeometry(geom);
    return geom;
}

void MeshShape::fill_interaction(const Ray &ray, float t, uint32_t prim, float bu, float bv,
                                 SurfaceInteraction &si) const {
    const uint32_t i0 = m_mesh.indices[3 * prim], i1 = m_mesh.indices[3 * prim + 1], i2 = m_mesh.indices[3 * prim + 2];
    const float *v0 = &m_vertices[i0 * Stride], *v1 = &m_vertices[i1 * Stride], *v2 = &m_vertices[i2 * Stride];
    const Vec3 p0(v0[0], v0[1], v0[2]), p1(v1[0], v1[1], v1[2]), p2(v2[0], v2[1], v2[2]);
    float b0 = 1.f - bu - bv;
    si.t = t;
    si.shape = this;
    si.prim = prim;
    // Interpolating the vertices is more accurate than o + t d; error bound as pbrt-v4
    // (gamma(7) * sum |b_i p_i|).
    si.p = p0 * b0 + p1 * bu + p2 * bv;
    Vec3 perr = vabs(p0 * b0) + vabs(p1 * bu) + vabs(p2 * bv);
    si.p_error = 4.2e-7f * max_component(perr) + 1e-9f;
    si.wo = -normalize(ray.d);

    Vec2 uv0(0, 0), uv1(1, 0), uv2(1, 1);
    if (m_has_uvs) {
        uv0 = Vec2(v0[6], v0[7]);
        uv1 = Vec2(v1[6], v1[7]);
        uv2 = Vec2(v2[6], v2[7]);
    }
    si.uv = uv0 * b0 + uv1 * bu + uv2 * bv;

    Vec3 ng = cross(p1 - p0, p2 - p0);
    float ng_len = length(ng);
    bool degenerate = !(ng_len > 0.f) || !std::isfinite(ng_len);
    ng = degenerate ? Vec3(0, 0, 0) : ng / ng_len;

    Vec3 ns = ng;
    if (m_has_normals) {
        Vec3 n = Vec3(v0[3], v0[4], v0[5]) * b0 + Vec3(v1[3], v1[4], v1[5]) * bu + Vec3(v2[3], v2[4], v2[5]) * bv;
        float l = length(n);
        if (l > 0.f && std::isfinite(l)) ns = n / l;
    }
    if (degenerate) ng = length_squared(ns) > 0.f ? ns : si.wo;  // zero-area triangle hit
    if (length_squared(ns) == 0.f) ns = ng;
    if (dot(ng, ns) < 0.f) ng = -ng;  // geometric normal on the side of the shading normal
    si.ng = ng;
    si.ns = ns;

    // dp/du, dp/dv from the triangle's uv parameterisation (in locals: stored once).
    Vec2 duv02 = uv0 - uv2, duv12 = uv1 - uv2;
    Vec3 dp02 = p0 - p2, dp12 = p1 - p2;
    float det = duv02.x * duv12.y - duv02.y * duv12.x;
    bool ok = std::abs(det) > 1e-12f;
    Vec3 dpdu, dpdv;
    if (ok) {
        float inv = 1.f / det;
        dpdu = (dp02 * duv12.y - dp12 * duv02.y) * inv;
        dpdv = (dp12 * duv02.x - dp02 * duv12.x) * inv;
        ok = is_finite(dpdu) && is_finite(dpdv) && length_squared(cross(dpdu, dpdv)) > 0.f;
    }
    if (!ok) coordinate_system(ng, dpdu, dpdv);
    if (!m_mesh.tangents.empty()) {
        Vec3 tg = m_mesh.tangents[i0] * b0 + m_mesh.tangents[i1] * bu + m_mesh.tangents[i2] * bv;
        if (length_squared(tg) > 0.f) dpdu = normalize(tg) * length(dpdu);
    }
    si.dpdu = dpdu;
    si.dpdv = dpdv;

    si.bary = Vec2(bu, bv);
    si.dndu = si.dndv = Vec3();  // fill_normal_derivatives, on demand
}

void MeshShape::fill_normal_derivatives(SurfaceInteraction &si) const {
    // dn/du, dn/dv of the unit interpolated normal, for ray differentials through curved
    // specular surfaces (only they read it, so it is computed on demand). The interpolated
    // normal N is linear in the barycentrics, so for a tangent vector w = a e1 + b e2
    // (e1 = p1 - p0, e2 = p2 - p0, least squares) dN = a (n1 - n0) + b (n2 - n0), and the unit
    // normal changes by (dN - ns (ns.dN)) / |N|. Mapping dp/du and dp/dv through this keeps
    // dn/du consistent with whatever dp/du ended up (tangent frames included). Zero without
    // vertex normals (flat) or for zero-area triangles.
    si.dndu = si.dndv = Vec3();
    if (!m_has_normals || si.shape != this) return;
    const uint32_t prim = si.prim;
    const float bu = si.bary.x, bv = si.bary.y, b0 = 1.f - bu - bv;
    const float *v0 = &m_vertices[m_mesh.indices[3 * prim] * Stride];
    const float *v1 = &m_vertices[m_mesh.indices[3 * prim + 1] * Stride];
    const float *v2 = &m_vertices[m_mesh.indices[3 * prim + 2] * Stride];
    const Vec3 p0(v0[0], v0[1], v0[2]), p1(v1[0], v1[1], v1[2]), p2(v2[0], v2[1], v2[2]);
    const Vec3 n0(v0[3], v0[4], v0[5]), n1(v1[3], v1[4], v1[5]), n2(v2[3], v2[4], v2[5]);
    const Vec3 N = n0 * b0 + n1 * bu + n2 * bv;
    const float len = length(N);
    const Vec3 e1 = p1 - p0, e2 = p2 - p0, dn1 = n1 - n0, dn2 = n2 - n0;
    const float g11 = dot(e1, e1), g12 = dot(e1, e2), g22 = dot(e2, e2);
    const float gdet = g11 * g22 - g12 * g12;
    const float ng_len = length(cross(e1, e2));
    if (!(ng_len > 0.f) || !std::isfinite(ng_len)) return;  // zero-area triangle
    if (!(len > 0.f) || !(gdet > 1e-12f * g11 * g22) || !std::isfinite(gdet)) return;
    const Vec3 ns = si.ns;
    auto dn_along = [&](Vec3 w) {
        float c1 = dot(e1, w), c2 = dot(e2, w);
        float a = (g22 * c1 - g12 * c2) / gdet, b = (g11 * c2 - g12 * c1) / gdet;
        Vec3 dN = dn1 * a + dn2 * b;
        return (dN - ns * dot(ns, dN)) / len;
    };
    si.dndu = dn_along(si.dpdu);
    si.dndv = dn_along(si.dpdv);
    if (!is_finite(si.dndu) || !is_finite(si.dndv)) si.dndu = si.dndv = Vec3();
}

Vec2 MeshShape::uv_at(uint32_t prim, float bu, float bv) const {
    // As fill_interaction: the vertex uvs, or (0, 0), (1, 0), (1, 1) without them.
    if (!m_has_uvs) return Vec2(bu + bv, bv);
    const float *v0 = &m_vertices[m_mesh.indices[3 * prim] * Stride + 6];
    const float *v1 = &m_vertices[m_mesh.indices[3 * prim + 1] * Stride + 6];
    const float *v2 = &m_vertices[m_mesh.indices[3 * prim + 2] * Stride + 6];
    const float b0 = 1.f - bu - bv;
    return Vec2(v0[0] * b0 + v1[0] * bu + v2[0] * bv, v0[1] * b0 + v1[1] * bu + v2[1] * bv);
}

PositionSample MeshShape::sample_area(float u_prim, Vec2 u) const {
    PositionSample ps;
    size_t tri = m_area_distr.sample_discrete(u_prim);
    Vec2 b = square_to_uniform_triangle(u);
    const uint32_t i0 = m_mesh.indices[3 * tri], i1 = m_mesh.indices[3 * tri + 1], i2 = m_mesh.indices[3 * tri + 2];
    const Vec3 &p0 = m_mesh.positions[i0], &p1 = m_mesh.positions[i1], &p2 = m_mesh.positions[i2];
    float b2 = 1.f - b.x - b.y;
    ps.p = p0 * b.x + p1 * b.y + p2 * b2;
    Vec3 ng = normalize(cross(p1 - p0, p2 - p0));
    if (!m_mesh.normals.empty()) {
        Vec3 ns = m_mesh.normals[i0] * b.x + m_mesh.normals[i1] * b.y + m_mesh.normals[i2] * b2;
        if (dot(ng, ns) < 0.f) ng = -ng;
    }
    ps.n = ng;
    if (!m_mesh.uvs.empty()) ps.uv = m_mesh.uvs[i0] * b.x + m_mesh.uvs[i1] * b.y + m_mesh.uvs[i2] * b2;
    ps.pdf_area = m_area > 0.f ? 1.f / m_area : 0.f;
    ps.prim = uint32_t(tri);
    return ps;
}

size_t MeshShape::memory_bytes() const {
    // Mesh arrays, the interleaved vertex buffer shared with Embree, and Embree's BVH
    // (about 64 B per triangle with high build quality).
    return m_mesh.memory_bytes() + m_vertices.size() * sizeof(float) + m_mesh.triangle_count() * 64 +
           m_area_distr.size() * 12;
}

std::string MeshShape::to_string() const {
    return fmt::format("{} ({} triangles, {} vertices, area {:.4g})", m_name, m_mesh.triangle_count(),
                       m_mesh.vertex_count(), m_area);
}

static std::shared_ptr<Shape> build_mesh_shape(TriangleMesh mesh, const Properties &p, const std::string &name) {
    Transform t = parse_transform(p);
    mesh.transform(t);
    if (p.get_bool("flip_normals", false)) {
        for (auto &n : mesh.normals) n = -n;
        for (size_t i = 0; i + 2 < mesh.indices.size(); i += 3) std::swap(mesh.indices[i + 1], mesh.indices[i + 2]);
    }
    if (auto dp = p.optional_child("displacement")) {
        Displacement d = parse_displacement(*dp, p.context().max_triangles);
        if (std::string why = wrap_range_problem(d, mesh.uvs); !why.empty()) dp->fail("wrap", why);
        if (d.mode == DisplacementMode::Shell) return std::make_shared<ShellShape>(mesh, std::move(d), name);
        TriangleMesh fine = tessellate_displaced(mesh, d, fmt::format("{}: {}", p.file(), p.path()));
        return std::make_shared<MeshShape>(std::move(fine), fmt::format("{}, displaced by '{}' (tessellated)", name, d.source));
    }
    return std::make_shared<MeshShape>(std::move(mesh), name);
}

std::shared_ptr<Shape> make_mesh_shape(TriangleMesh mesh, const Properties &p, const std::string &name) {
    try {
        return build_mesh_shape(std::move(mesh), p, name);
    } catch (const MesoError &e) {
        // The mesh checks name the shape ("shapes[2] (rectangle): ..."): add the scene file.
        const std::string msg = e.what();
        if (p.file().empty() || msg.rfind(p.file() + ": ", 0) == 0) throw;
        throw MesoError(fmt::format("{}: {}", p.file(), msg));
    }
}

// Procedural mesh shapes (Mitsuba 3 names and object-space extents).
MESO_REGISTER_SHAPE("rectangle", "[-1,1]^2 at z=0 facing +z (to_world, flip_normals)",
                    [](const Properties &p) { return make_mesh_shape(make_rectangle(), p, p.path() + " (rectangle)"); });
MESO_REGISTER_SHAPE("cube", "[-1,1]^3 with outward normals (to_world, flip_normals)",
                    [](const Properties &p) { return make_mesh_shape(make_cube(), p, p.path() + " (cube)"); });
MESO_REGISTER_SHAPE("disk", "unit disk at z=0 facing +z (to_world, flip_normals, segments)", [](const Properties &p) {
    int seg = p.get_int("segments", 64);
    if (seg < 3 || seg > 1 << 20) p.fail("segments", "expected an integer in [3, 1048576]");
    return make_mesh_shape(make_disk(seg), p, p.path() + " (disk)");
});
MESO_REGISTER_SHAPE("uvsphere", "tessellated unit sphere (to_world, rings, segments)", [](const Properties &p) {
    int rings = p.get_int("rings", 32), seg = p.get_int("segments", 64);
    if (rings < 2 || seg < 3 || size_t(rings) * seg > (size_t(1) << 26)) p.fail("expected rings >= 2, segments >= 3, rings*segments <= 2^26");
    return make_mesh_shape(make_uv_sphere(rings, seg), p, p.path() + " (uvsphere)");
});

}  // namespace meso
