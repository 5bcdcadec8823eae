// Unidirectional path tracing with next-event estimation and multiple importance sampling
// (power heuristic), Russian roulette and a maximum depth. Shared by the `path` and
// `direct` integrator plugins (direct = max_depth 2, no roulette).
//
// max_depth counts path segments as in Mitsuba: 1 = emitters seen directly, 2 = direct
// illumination, -1 = unbounded (roulette ends paths).
#pragma once
#include <cstdlib>
#include "render/integrator.h"

namespace meso {

class PathTracer : public Integrator {
public:
    PathTracer(int max_depth, int rr_depth, bool hide_emitters, std::string name)
        : m_max_depth(max_depth), m_rr_depth(rr_depth), m_hide_emitters(hide_emitters), m_name(std::move(name)) {}
    Spectrum li(const Scene &scene, RayDifferential ray, Sampler &sampler, RenderStats &stats) const override;
    std::string to_string() const override;

private:
    /// One path. `level` < 0: the LoD level is chosen from the camera ray's first hit on an
    /// LoD shape (stochastically, or by tracing both neighbouring levels and blending);
    /// >= 0: every ray of the path sees that level (render/lod.h).
    Spectrum trace(const Scene &scene, RayDifferential ray, Sampler &sampler, RenderStats &stats, int level) const;
    int m_max_depth, m_rr_depth;
    bool m_hide_emitters;
    std::string m_name;
    /// Ray-differential footprints at every hit (textures and LoD read them). The
    /// environment variable MESO_NO_DIFFERENTIALS=1 turns them off, to measure their cost.
    bool m_differentials = std::getenv("MESO_NO_DIFFERENTIALS") == nullptr;
};

}  // namespace meso
