// A shape made of one world-space triangle mesh (rectangle, cube, disk, glTF meshes).
#pragma once
#include "geometry/shape.h"
#include "sampling/distribution.h"

namespace meso {

class Properties;

class MeshShape : public Shape {
public:
    /// `mesh` must already be in world space; `name` appears in messages and --plan.
    MeshShape(TriangleMesh mesh, std::string name);
    RTCGeometry build_embree(RTCDevice device) const override;
    void fill_interaction(const Ray &ray, float t, uint32_t prim, float u, float v,
                          SurfaceInteraction &si) const override;
    void fill_normal_derivatives(SurfaceInteraction &si) const override;
    float surface_area() const override { return m_area; }
    PositionSample sample_area(float u_prim, Vec2 u) const override;
    size_t primitive_count() const override { return m_mesh.triangle_count(); }
    size_t memory_bytes() const override;
    std::string to_string() const override;
    const TriangleMesh *mesh() const override { return &m_mesh; }
    Vec2 uv_at(uint32_t prim, float u, float v) const override;

private:
    TriangleMesh m_mesh;
    /// Interleaved per-vertex position, normal, uv (8 floats), shared with Embree as its
    /// vertex buffer: one copy, and a hit reads one cache line per vertex.
    std::vector<float> m_vertices;
    static constexpr int Stride = 8;
    bool m_has_normals = false, m_has_uvs = false;
    std::string m_name;
    Distribution1D m_area_distr;
    float m_area = 0.f;
};

/// Reads the common mesh-shape keys ("to_world", "flip_normals") and builds the shape.
std::shared_ptr<Shape> make_mesh_shape(TriangleMesh mesh, const Properties &p, const std::string &name);

}  // namespace meso
