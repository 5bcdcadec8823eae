// Unidirectional path tracing with next-event estimation and multiple importance sampling
// (power heuristic), Russian roulette and a maximum depth. Shared by the `path` and
// `direct` integrator plugins (direct = max_depth 2, no roulette).
//
// max_depth counts path segments as in Mitsuba: 1 = emitters seen directly, 2 = direct
// illumination, -1 = unbounded (roulette ends paths).
//
// leadr_env_quadrature (off by default): at shading points whose material can integrate the
// environment itself (EnvQuadratureShading: `leadr`, paper 000 Algorithms 1-3), the whole
// direct contribution of every infinite light comes from that quadrature: env NEE is skipped
// there and a BSDF-sampled ray from that vertex that escapes adds no environment radiance
// (no double counting). Other lights and indirect bounces are unchanged. Approximation (as
// in the paper): the environment is not occluded by the scene at those points, so directions
// where other geometry blocks the sky get the environment and also (through the BSDF-sampled
// ray that hits that geometry) the light it reflects; and the geometric-normal test of NEE
// is not applied (the quadrature only sees wi.z > 0 in the shading frame). Exact for a lone
// convex object. Measured on scenes/ndf/filtering.json (180x120): the LEADR sphere alone
// agrees with 1024-spp path tracing to -1.7% (env_quadrature 8), -0.5% (16), +0.1% (32)
// noise-free at 16 spp; with its five neighbours it is 4% brighter (their occlusion).
#pragma once
#include <cstdlib>
#include <memory>
#include <vector>
#include "render/integrator.h"

namespace meso {

class PrefilteredEnvironment;

class PathTracer : public Integrator {
public:
    PathTracer(int max_depth, int rr_depth, bool hide_emitters, std::string name)
        : m_max_depth(max_depth), m_rr_depth(rr_depth), m_hide_emitters(hide_emitters), m_name(std::move(name)) {}
    Spectrum li(const Scene &scene, RayDifferential ray, Sampler &sampler, RenderStats &stats) const override;
    std::string to_string() const override;
    /// Prefilters the infinite lights when leadr_env_quadrature is on.
    void preprocess(const Scene &scene) override;
    void set_leadr_env_quadrature(bool on) { m_leadr_env_quadrature = on; }

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
    bool m_leadr_env_quadrature = false;
    /// The scene's infinite lights, prefiltered (leadr_env_quadrature only).
    std::vector<std::shared_ptr<const PrefilteredEnvironment>> m_envs;
};

}  // namespace meso
