// Cameras generate primary rays with differentials for a film position.
#pragma once
#include <memory>
#include <string>
#include "core/frame.h"
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
    /// The same primary ray without differentials (has_differentials false; rx_*, ry_* not
    /// set), for render loops whose integrator reads none (Integrator::camera_differentials).
    /// Cameras override it to skip the two offset rays; the default drops them.
    virtual float generate_ray_no_differentials(const CameraSample &s, RayDifferential &ray) const {
        const float w = generate_ray(s, ray);
        ray.has_differentials = false;
        return w;
    }
    int width() const { return m_width; }
    int height() const { return m_height; }
    virtual std::string to_string() const = 0;

    /// Footprint (dp/dx, dp/dy) that a camera ray would have at surface point p with normal
    /// n: the smallest one-pixel differentials of this camera (find_minimum_differentials)
    /// transferred, to first order, to the tangent plane at p at p's distance from the
    /// camera, times `footprint_scale` (the ray's spp scale). pbrt-v4's
    /// CameraBase::Approximate_dp_dxy; used where a ray carries no differentials (after
    /// rough or diffuse scattering). Finite for any input: the 1/cos stretch of the tangent
    /// plane is capped at MaxFootprintStretch; zero when p is at the camera's centre.
    void approximate_dp_dxy(Vec3 p, Vec3 n, float footprint_scale, Vec3 &dpdx, Vec3 &dpdy) const;

protected:
    /// Derived constructors call this once generate_ray works: records the camera's
    /// placement (origin and camera-to-world frame) and the shortest one-pixel position and
    /// direction differentials over a 17x17 grid of film positions including the corners
    /// (pbrt-v4 FindMinimumDifferentials). Directions are measured in the frame obtained by
    /// rotating each ray's direction onto +z, so they are perpendicular offsets per pixel.
    void find_minimum_differentials(Vec3 origin, const Frame &camera_to_world);

    int m_width = 640, m_height = 480;
    Vec3 m_cam_origin;
    Frame m_cam_frame;
    Vec3 m_min_pos_dx, m_min_pos_dy, m_min_dir_dx, m_min_dir_dy;  ///< camera space, ray along +z
    Vec3 m_min_pos_dx_world, m_min_pos_dy_world, m_min_dir_dx_world, m_min_dir_dy_world;
};

}  // namespace meso
