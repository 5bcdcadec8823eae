// All Embree calls live here (CONVENTIONS 10): one device, error callback, geometry IDs
// mapped back to shapes.
//
// Without LoD shapes there is one scene. With them (geometry/lod.h) there is one scene per
// path level k = 0 .. L-1 (L: the longest chain): scene k holds level min(k, last) of every
// chain and every shape without LoD, and a ray is traced in the scene of its mask's level bit
// (lod_ray_mask; a bit past L-1 means L-1). A ray then walks a BVH of only what it can see,
// as in a scene without LoD: no BVH nodes of other levels (one scene with ray masks visits
// all of them, overlapping, and rejects them primitive by primitive) and no instance on its
// way (identity instances of level scenes measured 5% slower on the bench twill's chain).
// The shapes without LoD are attached to every level scene (their geometry is shared; each
// scene has its own BVH over them) unless they outnumber the LoD levels' primitives: then
// they get one scene of their own, instanced into every level scene (identity transform),
// so their BVH is built once. A ray's mask must hold one level bit; geometry masks are set
// too (level k of a chain: bit k; its last level: bits k..31).
#pragma once
#include <memory>
#include <vector>
#include <embree3/rtcore.h>
#include "geometry/interaction.h"

namespace meso {

class Shape;

class EmbreeAccel {
public:
    EmbreeAccel();
    ~EmbreeAccel();
    EmbreeAccel(const EmbreeAccel &) = delete;
    EmbreeAccel &operator=(const EmbreeAccel &) = delete;

    void add(const Shape *shape);
    /// Builds the BVH; returns the build time in seconds.
    double commit();
    bool intersect(const Ray &ray, SurfaceInteraction &si) const;
    bool occluded(const Ray &ray) const;
    /// Closest hit distance only (for bare-Embree benchmarks): returns t or Infinity.
    float intersect_t(const Ray &ray) const;
    void bounds(Vec3 &lo, Vec3 &hi) const;
    RTCDevice device() const { return m_device; }
    /// "Embree 3.13.5, ISA: AVX2" etc.
    static std::string version_string();

private:
    /// The shapes of one Embree scene, by geomID.
    using ShapeTable = std::vector<const Shape *>;
    /// The scene a ray of `mask` is traced in, and its shapes.
    RTCScene scene_for(uint32_t mask, const ShapeTable *&shapes) const;
    /// The shape hit in `shapes`' scene: its own geometry, or the instanced shared one.
    const Shape *hit_shape(const ShapeTable &shapes, unsigned inst_id, unsigned geom_id) const;
    /// commit() with LoD shapes: the level scenes (see the top of this file).
    void build_level_scenes(int levels);

    RTCDevice m_device = nullptr;
    std::vector<std::pair<const Shape *, RTCGeometry>> m_pending;  ///< added, until commit()
    std::vector<RTCScene> m_scenes;        ///< one per path level (one without LoD)
    std::vector<ShapeTable> m_shapes;      ///< per scene, index: geomID
    RTCScene m_shared = nullptr;           ///< the shapes without LoD, when instanced
    ShapeTable m_shared_shapes;            ///< m_shared's shapes, index: geomID
};

}  // namespace meso
