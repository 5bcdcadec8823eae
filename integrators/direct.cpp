// `direct`: direct illumination only (emitters seen directly + one light sample and one
// BSDF sample per hit, combined by MIS). The path tracer restricted to two segments.
//   hide_emitters  bool  emitters seen directly by the camera render black   false
#include "render/path_tracer.h"
#include "scene/properties.h"
#include "scene/registry.h"

namespace meso {

MESO_REGISTER_INTEGRATOR("direct", "direct illumination with MIS (emitters + one bounce)",
                         [](const Properties &p) -> std::shared_ptr<Integrator> {
                             return std::make_shared<PathTracer>(2, -1, p.get_bool("hide_emitters", false), "direct");
                         });

}  // namespace meso
