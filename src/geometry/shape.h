// Shapes: geometry + material + optional area emitter. Triangle meshes (rectangle, cube,
// disk, glTF meshes) and analytic spheres (Embree sphere primitives, exact normals).
#pragma once
#include <functional>
#include <memory>
#include <string>
#include <embree3/rtcore.h>
#include "geometry/interaction.h"
#include "geometry/mesh.h"

namespace meso {

class Material;
class Light;
struct LodGroup;

struct PositionSample {
    Vec3 p, n;
    Vec2 uv;
    float pdf_area = 0.f;  ///< density w.r.t. surface area
    uint32_t prim = 0;
};

/// A cut-out (glTF alphaMode MASK): where alpha(uv) < cutoff the surface is not there, for
/// every ray (camera, bounce, shadow; Embree filter functions in embree_accel.cpp) and for
/// an area emitter's light samples. alpha is a callback because the texture layer sits above
/// geometry (docs/architecture.md): the scene loader, which may include both, installs one
/// that evaluates a texture at uv (no footprint: level 0 of its MIP map).
struct AlphaMask {
    std::function<float(Vec2 uv)> alpha;
    float cutoff = 0.5f;
};

class Shape {
public:
    virtual ~Shape() = default;
    /// Creates and commits the Embree geometry (caller attaches it).
    virtual RTCGeometry build_embree(RTCDevice device) const = 0;
    /// Completes `si` from Embree's hit record (t, prim, barycentrics u, v; ray).
    virtual void fill_interaction(const Ray &ray, float t, uint32_t prim, float u, float v,
                                  SurfaceInteraction &si) const = 0;
    /// Fills si.dndu, si.dndv where fill_interaction leaves them to be computed on demand
    /// (meshes: only specular ray differentials read them). Call through
    /// SurfaceInteraction::compute_normal_derivatives.
    virtual void fill_normal_derivatives(SurfaceInteraction &si) const { (void)si; }
    virtual float surface_area() const = 0;
    /// Uniform-by-area position sample (u_prim picks the primitive, u the point in it).
    virtual PositionSample sample_area(float u_prim, Vec2 u) const = 0;
    virtual size_t primitive_count() const = 0;
    virtual size_t memory_bytes() const = 0;
    virtual std::string to_string() const = 0;
    /// The triangle mesh when the shape is one (area lights use it for solid-angle sampling).
    virtual const TriangleMesh *mesh() const { return nullptr; }
    /// Texels per unit uv of the shape's own full-resolution map (a displacement map with
    /// its tiling), for footprints and LoD; false when the shape has none.
    virtual bool texel_grid(double &width, double &height) const { return false; }
    /// World length of one unit of u and v (TriangleMesh::uv_world_length); false when unknown.
    virtual bool uv_world_length(double &lu, double &lv) const {
        const TriangleMesh *m = mesh();
        return m && m->uv_world_length(lu, lv);
    }
    /// Texture coordinates at Embree's barycentrics (u, v) of primitive `prim`, as
    /// fill_interaction computes them (alpha masks and textured emitters read them without a
    /// full interaction). Shapes that cannot carry an alpha mask (mesh() is null) return (u, v).
    virtual Vec2 uv_at(uint32_t prim, float u, float v) const {
        (void)prim;
        return Vec2(u, v);
    }
    /// True where the alpha mask removes the surface (never without a mask).
    bool cut_out(uint32_t prim, float u, float v) const {
        return alpha_mask && alpha_mask->alpha(uv_at(prim, u, v)) < alpha_mask->cutoff;
    }

    std::shared_ptr<Material> material;
    std::shared_ptr<Light> emitter;  ///< area light, or null
    std::shared_ptr<const AlphaMask> alpha_mask;  ///< cut-out, or null (set before Scene::build)
    /// LoD chain this shape is level `lod_level` of (null: no LoD; seen by every ray).
    std::shared_ptr<const LodGroup> lod;
    int lod_level = 0;
};

}  // namespace meso
