// A loaded scene: camera, integrator, sampler, shapes, lights, and the Embree BVH.
#pragma once
#include <memory>
#include <string>
#include <unordered_map>
#include <vector>
#include "geometry/interaction.h"
#include "render/camera.h"
#include "render/integrator.h"
#include "lights/light.h"
#include "sampling/sampler.h"

namespace meso {

class Shape;
class EmbreeAccel;
class Distribution1D;

class Scene {
public:
    Scene();
    ~Scene();

    std::string file;        ///< scene file as given
    std::shared_ptr<Camera> camera;
    std::shared_ptr<Integrator> integrator;
    std::shared_ptr<Sampler> sampler;
    int spp = 16;            ///< sampler's sample_count (overridden by --spp)
    std::vector<std::shared_ptr<Shape>> shapes;
    std::vector<std::shared_ptr<Light>> lights;           ///< all lights (area lights included)
    std::vector<const Light *> infinite_lights;           ///< subset: environment lights
    /// What of the scene reads a ray-differential footprint (set by build()): a material
    /// (Material::uses_footprint: filtered textures, NDF filtering) at every hit, or an LoD
    /// shape, whose level comes from the camera ray's footprint. Integrators ask for camera
    /// differentials only when something does (Integrator::camera_differentials).
    bool materials_read_footprints = true;
    bool has_lod_shapes = true;

    /// Builds the BVH, preprocesses lights, sets up light selection. Call once.
    void build();
    bool intersect(const Ray &ray, SurfaceInteraction &si) const;
    bool occluded(const Ray &ray) const;
    /// Closest-hit distance only (bare Embree, for benchmarks); Infinity on a miss.
    float intersect_t(const Ray &ray) const;
    /// Choose a light in proportion to its power; pmf returned. nullptr if no lights.
    const Light *sample_light(float u, float &pmf) const;
    float light_pmf(const Light *light) const;
    Vec3 bounds_min() const { return m_bmin; }
    Vec3 bounds_max() const { return m_bmax; }
    /// One line per item: what is built and its memory (for --plan).
    std::vector<std::string> plan() const;

private:
    std::unique_ptr<EmbreeAccel> m_accel;
    std::unique_ptr<Distribution1D> m_light_distr;
    std::unordered_map<const Light *, float> m_light_pmf;  ///< per light, for MIS on emitter hits
    Vec3 m_bmin, m_bmax;
};

/// Loads a JSON scene or a .gltf file. `overrides` are "json.path=value" strings (-D).
/// Errors: MesoError("file: json.path: what was expected").
/// `max_triangles` limits explicitly tessellated displacement (0: kDefaultMaxTriangles).
std::unique_ptr<Scene> load_scene(const std::string &path, const std::vector<std::string> &overrides,
                                  size_t max_triangles = 0);

}  // namespace meso
