#include "geometry/interaction.h"
#include "geometry/shape.h"

namespace meso {

void SurfaceInteraction::compute_normal_derivatives() {
    if (shape) shape->fill_normal_derivatives(*this);
}

}  // namespace meso
