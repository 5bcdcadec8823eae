// Integrators estimate radiance along camera rays. The render loop (passes, tiles,
// budgets, progress, film) is shared in render/renderer.cpp; a plugin only implements li().
#pragma once
#include <memory>
#include <string>
#include "core/ray.h"
#include "core/spectrum.h"

namespace meso {

class Scene;
class Sampler;

/// Per-thread counters, summed into the render record.
struct RenderStats {
    uint64_t rays = 0;         ///< all rays traced (closest-hit and shadow)
    uint64_t shadow_rays = 0;
};

class Integrator {
public:
    virtual ~Integrator() = default;
    /// Radiance arriving along `ray` (a camera ray, with differentials when
    /// camera_differentials says so).
    virtual Spectrum li(const Scene &scene, RayDifferential ray, Sampler &sampler,
                        RenderStats &stats) const = 0;
    virtual std::string to_string() const = 0;
    /// Called once before rendering.
    virtual void preprocess(const Scene &scene) { (void)scene; }
    /// Whether li() reads the camera ray's differentials (asked after preprocess). When not,
    /// the render loop makes camera rays without them (two camera rays less per sample:
    /// pay only for what the scene uses). The default is the safe answer.
    virtual bool camera_differentials(const Scene &scene) const { (void)scene; return true; }
    /// The samples per pixel of the render about to run (set by the render loop before
    /// preprocess; 0: unknown). The LoD level choice weighs bias against variance with it.
    void set_samples_per_pixel(int spp) { m_spp = spp; }
    int samples_per_pixel() const { return m_spp; }

private:
    int m_spp = 0;
};

}  // namespace meso
