// `path`: unidirectional path tracer with next-event estimation, MIS and Russian roulette
// (see src/render/path_tracer.h).
//   max_depth      int   maximum path segments, -1 = unbounded (Mitsuba semantics)  -1
//   rr_depth       int   depth at which Russian roulette starts, >= 1               5
//   hide_emitters  bool  emitters seen directly by the camera render black          false
//   leadr_env_quadrature  bool  at `leadr` points the environment comes from the paper's  false
//                         quadrature (Algorithms 1-3), unoccluded; no env NEE or env hits
//                         from there (render/path_tracer.h)
#include "render/path_tracer.h"
#include "scene/properties.h"
#include "scene/registry.h"

namespace meso {

MESO_REGISTER_INTEGRATOR("path", "unidirectional path tracing, NEE + MIS, Russian roulette",
                         [](const Properties &p) -> std::shared_ptr<Integrator> {
                             int max_depth = p.get_int("max_depth", -1);
                             if (max_depth < -1 || max_depth == 0) p.fail("max_depth", "expected -1 (unbounded) or an integer >= 1");
                             int rr = p.get_int("rr_depth", 5);
                             if (rr < 1) p.fail("rr_depth", "expected an integer >= 1");
                             auto pt = std::make_shared<PathTracer>(max_depth, rr, p.get_bool("hide_emitters", false), "path");
                             pt->set_leadr_env_quadrature(p.get_bool("leadr_env_quadrature", false));
                             return pt;
                         });

}  // namespace meso
