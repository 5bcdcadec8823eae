// Cameras generate primary rays with differentials for a film position.
#pragma once
#include <memory>
#include <string>
#include "core/ray.h"

namespace meso {

struct CameraSample {
    Vec2 film;  ///< continuous raster position (pixels; (0,0) = top-left corner)
    Vec2 lens;  ///< [0,1)^2 sample for the aperture
};

class Camera {
public:
    virtual ~Camera() = default;
    /// Primary ray with x/y differentials for a one-pixel step. Returns the ray weight.
    virtual float generate_ray(const CameraSample &s, RayDifferential &ray) const = 0;
    int width() const { return m_width; }
    int height() const { return m_height; }
    virtual std::string to_string() const = 0;

protected:
    int m_width = 640, m_height = 480;
};

}  // namespace meso
