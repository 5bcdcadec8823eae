// `perspective` camera: pinhole or thin lens, with ray differentials for every ray that asks.
//   origin, target, up     vec3   camera placement (look-at)  [0,0,0], [0,0,-1], [0,1,0]
//                                 (origin and target coordinates within ±1e8)
//   fov                    float  field of view in degrees, (0, 180)   40
//   fov_axis               string "x" (default) or "y": the axis fov spans
//   width, height          int    film size in pixels, [1, 65536]      640, 480
//   aperture_radius        float  thin-lens radius (0 = pinhole), >= 0  0
//   focus_distance         float  distance of the plane in focus, > 0  |target - origin|
// Camera space: +z forward, +y up, +x left (Mitsuba's convention); raster (0,0) is the
// top-left corner.
#include <fmt/format.h>
#include "core/transform.h"
#include "render/camera.h"
#include "sampling/warp.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

class PerspectiveCamera final : public Camera {
public:
    explicit PerspectiveCamera(const Properties &p) {
        Vec3 origin = p.get_position("origin", Vec3(0, 0, 0));
        Vec3 target = p.get_position("target", Vec3(0, 0, -1));
        Vec3 up = p.get_direction("up", Vec3(0, 1, 0));
        try {
            m_to_world = Transform::look_at(origin, target, up);
        } catch (const std::exception &e) {
            p.fail(e.what());
        }
        m_fov = p.get_float("fov", 40.f, Range{0.0, 180.0, true, true});  // degrees
        std::string axis = p.get_string("fov_axis", "x");
        if (axis != "x" && axis != "y") p.fail("fov_axis", "expected \"x\" or \"y\"");
        m_width = p.get_int("width", 640, Range::closed(1, 65536));
        m_height = p.get_int("height", 480, Range::closed(1, 65536));
        m_aperture = p.get_float("aperture_radius", 0.f, Range::non_negative(kMaxSceneCoordinate));
        m_focus = p.get_float("focus_distance", length(target - origin), Range::positive());
        // Image-plane half extents at z = 1.
        float t = std::tan(radians(m_fov) * 0.5f);
        float aspect = float(m_width) / float(m_height);
        if (axis == "x") {
            m_half_w = t;
            m_half_h = t / aspect;
        } else {
            m_half_h = t;
            m_half_w = t * aspect;
        }
        // Camera placement and smallest pixel differentials for Camera::approximate_dp_dxy.
        find_minimum_differentials(m_to_world.apply_point(Vec3(0, 0, 0)),
                                   Frame(normalize(m_to_world.apply_vector(Vec3(1, 0, 0))),
                                         normalize(m_to_world.apply_vector(Vec3(0, 1, 0))),
                                         normalize(m_to_world.apply_vector(Vec3(0, 0, 1)))));
    }

    /// Camera-space direction (z = 1 plane) of a raster position.
    Vec3 plane_point(Vec2 raster) const {
        float x = (1.f - 2.f * raster.x / m_width) * m_half_w;  // +x is left
        float y = (1.f - 2.f * raster.y / m_height) * m_half_h;
        return {x, y, 1.f};
    }

    void make_ray(Vec2 raster, Vec2 lens, Vec3 &o, Vec3 &d) const {
        Vec3 pc = plane_point(raster);
        Vec3 oc(0, 0, 0), dc = normalize(pc);
        if (m_aperture > 0.f) {
            Vec2 l = square_to_uniform_disk_concentric(lens) * m_aperture;
            Vec3 focus = pc * m_focus;  // point on the plane of focus (z = focus)
            oc = Vec3(l.x, l.y, 0.f);
            dc = normalize(focus - oc);
        }
        o = m_to_world.apply_point(oc);
        d = normalize(m_to_world.apply_vector(dc));
    }

    float generate_ray(const CameraSample &s, RayDifferential &ray) const override {
        make_ray(s.film, s.lens, ray.o, ray.d);
        ray.tmin = 0.f;
        ray.tmax = Infinity;
        // Differentials: the same lens sample, one pixel over (exact for thin lenses too).
        make_ray(s.film + Vec2(1, 0), s.lens, ray.rx_o, ray.rx_d);
        make_ray(s.film + Vec2(0, 1), s.lens, ray.ry_o, ray.ry_d);
        ray.has_differentials = true;
        return 1.f;
    }

    float generate_ray_no_differentials(const CameraSample &s, RayDifferential &ray) const override {
        make_ray(s.film, s.lens, ray.o, ray.d);
        ray.tmin = 0.f;
        ray.tmax = Infinity;
        ray.has_differentials = false;
        return 1.f;
    }

    std::string to_string() const override {
        return fmt::format("perspective ({}x{}, fov {} deg{})", m_width, m_height, m_fov,
                           m_aperture > 0 ? fmt::format(", aperture {} focus {}", m_aperture, m_focus) : "");
    }

private:
    Transform m_to_world;
    float m_fov, m_aperture, m_focus, m_half_w, m_half_h;
};

MESO_REGISTER_CAMERA("perspective", "pinhole / thin-lens camera with ray differentials",
                     [](const Properties &p) -> std::shared_ptr<Camera> { return std::make_shared<PerspectiveCamera>(p); });

}  // namespace
}  // namespace meso
