// All Embree calls live here (CONVENTIONS 10): one device, one top scene, error callback,
// geometry IDs mapped back to shapes.
//
// LoD levels (geometry/lod.h) are not in the top scene: the levels that rays see through the
// same Embree mask (level k of a chain: bit k; a chain's last level: bits k..31) share one
// scene of their own, attached to the top scene as an instance with the identity transform
// and that mask. A ray's mask then rejects a whole level at its instance, in the top BVH,
// instead of walking the level's BVH down to primitives that the mask rejects one by one.
// Shapes without LoD stay in the top scene: a scene without LoD has no instance.
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
    /// The LoD levels seen through one mask (see the top of this file): one scene, one instance.
    struct LevelScene {
        uint32_t mask;
        RTCScene scene;
        ShapeTable shapes;
    };
    /// The shape hit: top-level geometry, or geometry `geom_id` of the level instance `inst_id`.
    const Shape *hit_shape(unsigned inst_id, unsigned geom_id) const;

    RTCDevice m_device = nullptr;
    RTCScene m_scene = nullptr;
    ShapeTable m_shapes;                   ///< top-level geometry (index: geomID)
    std::vector<LevelScene> m_levels;      ///< one per LoD mask
    std::vector<int> m_instance_level;     ///< index: an instance's geomID in the top scene; -1: not an instance
};

}  // namespace meso
