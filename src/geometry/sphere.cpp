// `sphere`: an analytic sphere traced by Embree's sphere primitive (exact normals, no
// tessellation), as Mitsuba's `sphere`.
//   center        vec3   [0,0,0]
//   radius        float  1        (0, 1e8]; center coordinates within ±1e8
//   flip_normals  bool   false    normals point inwards
#include <fmt/format.h>
#include "geometry/mesh_shape.h"
#include "geometry/shape.h"
#include "sampling/warp.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

class SphereShape final : public Shape {
public:
    SphereShape(Vec3 c, float r, bool flip) : m_center(c), m_radius(r), m_flip(flip) {}

    RTCGeometry build_embree(RTCDevice device) const override {
        RTCGeometry g = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_SPHERE_POINT);
        auto *v = static_cast<float *>(
            rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT4, 4 * sizeof(float), 1));
        v[0] = m_center.x;
        v[1] = m_center.y;
        v[2] = m_center.z;
        v[3] = m_radius;
        rtcCommitGeometry(g);
        return g;
    }

    void fill_interaction(const Ray &ray, float t, uint32_t prim, float, float, SurfaceInteraction &si) const override {
        si.t = t;
        si.shape = this;
        si.prim = prim;
        si.wo = -normalize(ray.d);
        Vec3 d = ray(t) - m_center;
        Vec3 n = normalize(d);
        if (length_squared(n) == 0.f) n = -si.wo;
        // Re-project onto the surface; the remaining error is a few ulps of |p| plus Embree's
        // single-precision root error, which grows with r (bound found by the
        // ray-starting-on-surface test).
        si.p = m_center + n * m_radius;
        si.p_error = 1e-6f * max_component(vabs(si.p)) + 2e-5f * m_radius;
        float theta = safe_acos(n.z), phi = std::atan2(n.y, n.x);
        if (phi < 0.f) phi += 2.f * Pi;
        si.uv = Vec2(phi * Inv2Pi, theta * InvPi);
        float st = std::sin(theta);
        si.dpdu = Vec3(-n.y, n.x, 0.f) * (2.f * Pi * m_radius);
        si.dpdv = Vec3(n.z * std::cos(phi), n.z * std::sin(phi), -st) * (Pi * m_radius);
        if (!(st > 1e-6f)) coordinate_system(n, si.dpdu, si.dpdv);
        si.ng = si.ns = m_flip ? -n : n;
        // The unit normal is (p - c) / r, so dn/du = (dp/du) / r (negated with the normal).
        const float inv_r = (m_flip ? -1.f : 1.f) / m_radius;
        si.dndu = si.dpdu * inv_r;
        si.dndv = si.dpdv * inv_r;
    }

    float surface_area() const override { return 4.f * Pi * m_radius * m_radius; }
    PositionSample sample_area(float, Vec2 u) const override {
        PositionSample ps;
        Vec3 n = square_to_uniform_sphere(u);
        ps.p = m_center + n * m_radius;
        ps.n = m_flip ? -n : n;
        ps.pdf_area = 1.f / surface_area();
        float phi = std::atan2(n.y, n.x);
        ps.uv = Vec2((phi < 0 ? phi + 2 * Pi : phi) * Inv2Pi, safe_acos(n.z) * InvPi);
        return ps;
    }
    size_t primitive_count() const override { return 1; }
    size_t memory_bytes() const override { return 16 + 64; }
    std::string to_string() const override {
        return fmt::format("sphere (center [{}, {}, {}], radius {})", m_center.x, m_center.y, m_center.z, m_radius);
    }

private:
    Vec3 m_center;
    float m_radius;
    bool m_flip;
};

MESO_REGISTER_SHAPE("sphere", "analytic sphere (center, radius, flip_normals; with displacement: a uv sphere of rings x segments)", [](const Properties &p) -> std::shared_ptr<Shape> {
    const float r = p.get_float("radius", 1.f, Range::positive());
    if (p.has("displacement")) {
        // Displacement needs a mesh with uvs: the sphere becomes a uv sphere (same uv layout).
        int rings = p.get_int("rings", 64), seg = p.get_int("segments", 128);
        if (rings < 2 || seg < 3 || size_t(rings) * seg > (size_t(1) << 26))
            p.fail("expected rings >= 2, segments >= 3, rings*segments <= 2^26");
        TriangleMesh mesh = make_uv_sphere(rings, seg);
        Vec3 c = p.get_position("center", Vec3());
        for (Vec3 &v : mesh.positions) v = c + v * r;
        return make_mesh_shape(std::move(mesh), p, p.path() + " (sphere as uv sphere)");
    }
    return std::make_shared<SphereShape>(p.get_position("center", Vec3()), r, p.get_bool("flip_normals", false));
});

}  // namespace
}  // namespace meso
