// All Embree calls live here (CONVENTIONS 10): one device, one scene, error callback,
// geometry IDs mapped back to shapes.
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
    RTCDevice m_device = nullptr;
    RTCScene m_scene = nullptr;
    std::vector<const Shape *> m_shapes;  // index = geomID
};

}  // namespace meso
