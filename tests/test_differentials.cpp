// Ray-differential footprints (issue 4): camera rays against the analytic footprint, exact
// transport through flat and curved mirrors and through refraction against finite
// differences of actually traced neighbouring rays, the camera-based approximation after
// rough scattering, and finiteness in grazing / degenerate cases.
#include <gtest/gtest.h>
#include <mutex>
#include <vector>
#include <fmt/format.h>
#include "geometry/interaction.h"
#include "render/camera.h"
#include "render/differentials.h"
#include "bsdf/material.h"
#include "render_test_util.h"

using namespace meso;
using namespace meso::test;

namespace {

constexpr float Deg = 3.14159265358979f / 180.f;

std::string str(Vec3 v) { return fmt::format("({:.6g}, {:.6g}, {:.6g})", v.x, v.y, v.z); }

double rel_err(Vec3 a, Vec3 b) { return length(a - b) / std::max(length(b), 1e-30f); }

RayDifferential camera_ray(const Scene &s, Vec2 film) {
    CameraSample cs;
    cs.film = film;
    cs.lens = Vec2(0.5f, 0.5f);
    RayDifferential r;
    s.camera->generate_ray(cs, r);
    return r;
}

/// A hit on an analytic plane (point P0, unit normal n, axes a, b for dp/du, dp/dv).
bool hit_plane(const Ray &r, Vec3 P0, Vec3 n, Vec3 a, Vec3 b, SurfaceInteraction &si) {
    float t = dot(n, P0 - r.o) / dot(n, r.d);
    if (!(t > 0.f) || !std::isfinite(t)) return false;
    si.p = r.o + r.d * t;
    si.t = t;
    si.ng = si.ns = n;
    si.dpdu = a;
    si.dpdv = b;
    si.wo = -normalize(r.d);
    return true;
}

Vec3 reflect_dir(Vec3 wo, Vec3 n) { return -wo + n * (2.f * dot(wo, n)); }

/// Snell refraction of wo (pointing away from the surface) with eta = eta_t / eta_i.
Vec3 refract_dir(Vec3 wo, Vec3 n, float eta) {
    float c = dot(wo, n);
    if (c < 0.f) {
        n = -n;
        c = -c;
    }
    float s2 = (1.f - c * c) / (eta * eta);
    float ct = std::sqrt(std::max(0.f, 1.f - s2));
    return -wo / eta + n * (c / eta - ct);
}

std::string camera_json(Vec3 o, Vec3 t, Vec3 up, float fov, int w, int h) {
    return fmt::format(R"("camera": {{"type": "perspective", "origin": [{}, {}, {}], "target": [{}, {}, {}],
                        "up": [{}, {}, {}], "fov": {}, "width": {}, "height": {}}})",
                       o.x, o.y, o.z, t.x, t.y, t.z, up.x, up.y, up.z, fov, w, h);
}

}  // namespace

// A camera ray hits a plane tilted by theta about the camera's x axis at distance d: the
// footprint is the pixel spacing at distance d, d * 2 tan(fov/2) / W, across the tilt and
// that divided by cos(theta) along it (first order; the exact one-pixel chord differs by
// O(pixel angle * tan theta), well below 1%).
TEST(DifferentialsCamera, PlaneFootprintMatchesAnalytic) {
    const float d = 4.f, fov = 40.f, theta = 50.f;
    const int W = 400, H = 300;
    auto s = load_json_scene("diff_plane.json", fmt::format(R"({{ {},
      "shapes": [{{"type": "rectangle", "material": {{"type": "diffuse"}},
                   "to_world": {{"scale": [10, 10, 1], "rotate": {{"axis": [1, 0, 0], "angle": {}}}}}}}]
    }})", camera_json(Vec3(0, 0, d), Vec3(0, 0, 0), Vec3(0, 1, 0), fov, W, H), theta));
    for (float scale : {1.f, 0.125f}) {
        RayDifferential r = camera_ray(*s, Vec2(W * 0.5f, H * 0.5f));
        r.scale_differentials(scale);
        SurfaceInteraction si;
        ASSERT_TRUE(s->intersect(r, si));
        si.compute_differentials(r, s->camera.get());
        const double pix = d * 2.0 * std::tan(fov * 0.5 * Deg) / W * scale;
        EXPECT_NEAR(length(si.dpdx), pix, 0.01 * pix) << scale;
        EXPECT_NEAR(length(si.dpdy), pix / std::cos(theta * Deg), 0.01 * pix / std::cos(theta * Deg)) << scale;
        // dp/dx runs along world x; dp/dy in the plane's tilted direction (y, z).
        EXPECT_LT(std::abs(si.dpdx.y) + std::abs(si.dpdx.z), 1e-3 * pix);
        EXPECT_LT(std::abs(si.dpdy.x), 1e-3 * pix);
        // The rectangle's uv span [0,1] over 20 units in each direction.
        EXPECT_NEAR(std::abs(si.dudx), pix / 20, 0.01 * pix / 20);
        EXPECT_NEAR(std::abs(si.dvdy), pix / 20 / std::cos(theta * Deg), 0.01 * pix / 20 / std::cos(theta * Deg));
        EXPECT_LT(std::abs(si.dvdx) + std::abs(si.dudy), 1e-3 * pix / 20);
    }
}

namespace {

/// Wraps a scene's integrator (its decisions included) and records the camera rays the
/// render loop hands it: how many carry differentials, whether those are a one-pixel step,
/// and the footprint scale.
class CameraRayProbe final : public Integrator {
public:
    explicit CameraRayProbe(std::shared_ptr<Integrator> inner) : m_inner(std::move(inner)) {}
    Spectrum li(const Scene &scene, RayDifferential ray, Sampler &sampler, RenderStats &stats) const override {
        std::lock_guard<std::mutex> lock(m_mutex);
        if (ray.has_differentials) {
            ++with;
            // Pinhole: the same origin, directions one pixel apart (2 tan(fov/2) / W at the
            // centre, down to cos^2 of the corner angle there), times the footprint scale.
            const float step = length(ray.rx_d - ray.d) / ray.footprint_scale;
            one_pixel_steps += length(ray.rx_o - ray.o) == 0.f && length(ray.ry_o - ray.o) == 0.f && step > 0.8f * pixel_angle &&
                               step < 1.01f * pixel_angle && length(ray.ry_d - ray.d) > 0.f;
        } else {
            ++without;
        }
        scales.push_back(ray.footprint_scale);
        return m_inner->li(scene, ray, sampler, stats);
    }
    void preprocess(const Scene &scene) override { m_inner->preprocess(scene); }
    bool camera_differentials(const Scene &scene) const override { return m_inner->camera_differentials(scene); }
    std::string to_string() const override { return "probe of " + m_inner->to_string(); }

    float pixel_angle = 0.f;
    mutable int with = 0, without = 0, one_pixel_steps = 0;
    mutable std::vector<float> scales;

private:
    std::shared_ptr<Integrator> m_inner;
    mutable std::mutex m_mutex;
};

/// Renders a 16 x 16 view of a rectangle (with `shape_extra` in its JSON: a material, an LoD
/// chain) at 4 spp through a CameraRayProbe.
std::shared_ptr<CameraRayProbe> probe_camera_rays(const std::string &integrator, const std::string &shape_extra) {
    auto s = load_json_scene("diff_need.json", fmt::format(R"({{ {},
      "integrator": {},
      "shapes": [{{"type": "rectangle", "to_world": {{"scale": 3}} {}}}],
      "lights": [{{"type": "constant", "radiance": 1}}]
    }})", camera_json(Vec3(0, 0, 4), Vec3(0, 0, 0), Vec3(0, 1, 0), 40, 16, 16), integrator, shape_extra));
    auto probe = std::make_shared<CameraRayProbe>(s->integrator);
    probe->pixel_angle = 2.f * std::tan(20.f * Deg) / 16.f;
    s->integrator = probe;
    RenderResult r = render_scene(*s, 4);
    EXPECT_EQ(r.nan_count, 0);
    return probe;
}

}  // namespace

// Camera rays carry differentials only where something reads a footprint (issue 22: pay only
// for what the scene uses): a material with a varying texture (at every hit), an LoD shape
// (its level comes from the camera ray's footprint, even under constant materials), an
// integrator that reports footprints (aov). Constant materials under `path`, or `path` with
// "differentials": false and no LoD, get rays without them. Either way the rays keep the
// per-sample footprint scale max(1/8, 1/sqrt(spp)) = 1/2 that the camera-based approximation
// after rough scattering reads.
TEST(DifferentialsCamera, CameraRaysCarryDifferentialsOnlyWhereSomethingReadsThem) {
    const std::string path = R"({"type": "path", "max_depth": 3})";
    const std::string textured = R"(, "material": {"type": "diffuse", "reflectance": {"type": "checkerboard"}})";
    const std::string lod = R"(, "material": {"type": "diffuse", "reflectance": 0.5},
        "displacement": {"map": {"generator": "fbm", "size": 64}, "scale": 0, "tiling": 4},
        "lod": {"factors": [1, 4], "same_model": true})";
    struct Case {
        const char *what;
        std::string integrator, shape;
        bool differentials;
    };
    const Case cases[] = {
        {"constant diffuse", path, R"(, "material": {"type": "diffuse", "reflectance": 0.5})", false},
        {"constant conductor", path, R"(, "material": {"type": "conductor", "material": "Au", "alpha": 0.2})", false},
        {"textured diffuse", path, textured, true},
        {"textured diffuse, differentials off", R"({"type": "path", "differentials": false})", textured, false},
        {"LoD shape, constant material", path, lod, true},
        {"LoD shape, differentials off", R"({"type": "path", "differentials": false})", lod, true},
        {"aov footprint, constant material", R"({"type": "aov", "aov": "footprint"})", "", true},
    };
    for (const Case &c : cases) {
        auto probe = probe_camera_rays(c.integrator, c.shape);
        const int n = 16 * 16 * 4;
        EXPECT_EQ(probe->with, c.differentials ? n : 0) << c.what;
        EXPECT_EQ(probe->without, c.differentials ? 0 : n) << c.what;
        EXPECT_EQ(probe->one_pixel_steps, probe->with) << c.what;
        for (float scale : probe->scales) ASSERT_EQ(scale, 0.5f) << c.what;
    }
}

// The footprint on a wall seen in a flat mirror equals the footprint of the unfolded camera
// (the mirror image of the camera) looking at the wall directly. The reflected camera is
// left-handed, so its raster x runs the other way: dp/dx flips sign.
TEST(DifferentialsSpecular, FlatMirrorEqualsUnfoldedCamera) {
    const int W = 320, H = 240;
    const Vec3 o(0, 1.5f, 0), target(0, 0, -3), up(0, 1, 0);
    auto mirror_y = [](Vec3 v) { return Vec3(v.x, -v.y, v.z); };  // mirror plane y = 0
    const std::string wall = R"({"type": "rectangle", "material": {"type": "diffuse"},
        "to_world": {"translate": [0, 0, -8], "rotate": {"axis": [0, 1, 0], "angle": 20}, "scale": [20, 20, 1]}})";
    auto mirrored = load_json_scene("diff_mirror.json", fmt::format(R"({{ {},
      "shapes": [{{"type": "rectangle", "material": {{"type": "conductor", "material": "Ag"}},
                   "to_world": {{"rotate": {{"axis": [1, 0, 0], "angle": -90}}, "scale": [20, 20, 1]}}}}, {}]
    }})", camera_json(o, target, up, 35, W, H), wall));
    auto unfolded = load_json_scene("diff_unfolded.json", fmt::format(R"({{ {}, "shapes": [{}] }})",
        camera_json(mirror_y(o), mirror_y(target), mirror_y(up), 35, W, H), wall));

    for (Vec2 film : {Vec2(W * 0.5f, H * 0.5f), Vec2(100.5f, 180.5f)}) {
        RayDifferential r = camera_ray(*mirrored, film);
        SurfaceInteraction m;
        ASSERT_TRUE(mirrored->intersect(r, m));
        ASSERT_NEAR(m.p.y, 0.f, 1e-4f);  // hit the mirror
        m.compute_differentials(r, mirrored->camera.get());
        Vec3 wi = reflect_dir(m.wo, m.ns);
        RayDifferential next(m.spawn_ray(wi));
        ASSERT_TRUE(specular_differentials(r, m, m.ns, wi, BSDF_DeltaReflection, 1.f, next));
        SurfaceInteraction a;
        ASSERT_TRUE(mirrored->intersect(next, a));
        a.compute_differentials(next, mirrored->camera.get());

        // Unfolded camera: the same path is its raster (W - x, y).
        RayDifferential u = camera_ray(*unfolded, Vec2(W - film.x, film.y));
        SurfaceInteraction b;
        ASSERT_TRUE(unfolded->intersect(u, b));
        ASSERT_LT(length(a.p - b.p), 1e-3f);
        b.compute_differentials(u, unfolded->camera.get());
        // Second-order terms differ (offsets at x+1 vs x-1): compare within 1%.
        EXPECT_LT(rel_err(a.dpdx, -b.dpdx), 0.01) << str(a.dpdx) << " " << str(b.dpdx);
        EXPECT_LT(rel_err(a.dpdy, b.dpdy), 0.01) << str(a.dpdy) << " " << str(b.dpdy);
        EXPECT_NEAR(a.dudx, -b.dudx, 0.01 * std::abs(b.dudx) + 1e-7);
        EXPECT_NEAR(a.dvdy, b.dvdy, 0.01 * std::abs(b.dvdy) + 1e-7);
    }
}

namespace {

/// Propagates the camera ray through `film` off the curved `shape` scene by reflection or
/// refraction (eta = ratio for entering) to a virtual plane `dist` along the continuation,
/// and compares the transported footprint with central finite differences of traced rays.
struct CurvedCase {
    double err_x, err_y;       ///< Igehy vs finite differences (relative)
    double flat_err;           ///< the same with dn/dx = 0 (shows the curvature matters)
    double widening;           ///< |dp/dx| at the plane over |dp/dx| with dn/dx = 0
};

CurvedCase curved_case(const Scene &s, Vec2 film, bool refract, float eta, float dist, bool require_same_prim) {
    const float eps = 0.25f;  // pixels; central differences, O(eps^2) error
    auto scatter = [&](const SurfaceInteraction &si, float &eta_rel) {
        if (!refract) {
            eta_rel = 1.f;
            return reflect_dir(si.wo, si.ns);
        }
        eta_rel = dot(si.wo, si.ns) > 0.f ? eta : 1.f / eta;
        return refract_dir(si.wo, si.ns, eta_rel);
    };
    RayDifferential r = camera_ray(s, film);
    r.scale_differentials(eps);
    SurfaceInteraction si;
    EXPECT_TRUE(s.intersect(r, si));
    si.compute_differentials(r, s.camera.get());
    si.compute_normal_derivatives();
    float eta_rel;
    Vec3 wi = scatter(si, eta_rel);
    RayDifferential next(Ray(si.p, wi));
    uint32_t flags = refract ? BSDF_DeltaTransmission : BSDF_DeltaReflection;
    EXPECT_TRUE(specular_differentials(r, si, si.ns, wi, flags, eta_rel, next));
    // Virtual plane across the continuation, tilted by 25 degrees.
    Vec3 a, b;
    coordinate_system(wi, a, b);
    Vec3 n = normalize(wi * std::cos(25 * Deg) + a * std::sin(25 * Deg));
    Vec3 pa = normalize(cross(n, b)), pb = cross(n, pa);
    Vec3 P0 = si.p + wi * dist;
    SurfaceInteraction pl;
    EXPECT_TRUE(hit_plane(next, P0, n, pa, pb, pl));
    pl.compute_differentials(next);

    // Flat approximation (dn = 0) for comparison.
    SurfaceInteraction flat_si = si;
    flat_si.dndu = flat_si.dndv = Vec3();
    RayDifferential flat_next(Ray(si.p, wi));
    specular_differentials(r, flat_si, si.ns, wi, flags, eta_rel, flat_next);
    SurfaceInteraction flat_pl;
    hit_plane(flat_next, P0, n, pa, pb, flat_pl);
    flat_pl.compute_differentials(flat_next);

    // Finite differences: trace the neighbouring camera rays for real.
    auto traced = [&](Vec2 f) {
        RayDifferential q = camera_ray(s, f);
        SurfaceInteraction h;
        EXPECT_TRUE(s.intersect(q, h));
        if (require_same_prim) {
            EXPECT_EQ(h.prim, si.prim) << "finite difference crosses a triangle";
        }
        float e;
        Vec3 w = scatter(h, e);
        SurfaceInteraction hp;
        EXPECT_TRUE(hit_plane(Ray(h.p, w), P0, n, pa, pb, hp));
        return hp.p;
    };
    Vec3 fdx = (traced(film + Vec2(eps, 0)) - traced(film - Vec2(eps, 0))) * 0.5f;
    Vec3 fdy = (traced(film + Vec2(0, eps)) - traced(film - Vec2(0, eps))) * 0.5f;
    CurvedCase c;
    c.err_x = rel_err(pl.dpdx, fdx);
    c.err_y = rel_err(pl.dpdy, fdy);
    c.flat_err = std::max(rel_err(flat_pl.dpdx, fdx), rel_err(flat_pl.dpdy, fdy));
    c.widening = length(pl.dpdx) / length(flat_pl.dpdx);
    return c;
}

/// Igehy vs traced finite differences within 1% at each film position; the flat (dn = 0)
/// answer off by more than `min_flat_err`.
void expect_curved_cases(const Scene &s, const std::vector<Vec2> &films, bool refract, float eta, float dist,
                         bool same_prim, double min_flat_err) {
    for (Vec2 film : films) {
        CurvedCase c = curved_case(s, film, refract, eta, dist, same_prim);
        EXPECT_LT(c.err_x, 0.01) << film.x << "," << film.y;
        EXPECT_LT(c.err_y, 0.01) << film.x << "," << film.y;
        EXPECT_GT(c.flat_err, min_flat_err) << film.x << "," << film.y;
        if (!refract) {
            EXPECT_GT(c.widening, 2.0);  // a convex mirror widens the footprint
        }
    }
}

std::string sphere_scene(const std::string &shape) {
    return fmt::format(R"({{ {}, "shapes": [{}] }})",
                       camera_json(Vec3(0, 0, 5), Vec3(0, 0, 0), Vec3(0, 1, 0), 30, 400, 400), shape);
}

}  // namespace

// A convex mirror (analytic sphere) spreads the reflected rays: Igehy's transport with dn/dx
// matches the traced finite differences; the flat approximation does not.
TEST(DifferentialsSpecular, CurvedMirrorMatchesTracedRays) {
    auto s = load_json_scene("diff_sphere.json", sphere_scene(R"({"type": "sphere", "radius": 1,
        "material": {"type": "conductor", "material": "Ag"}})"));
    // Curvature dominates: the flat answer is far off.
    expect_curved_cases(*s, {Vec2(250.5f, 230.5f), Vec2(200.5f, 120.5f), Vec2(300.5f, 290.5f)}, false, 1.f, 3.f,
                        false, 0.5);
}

// Same with the tessellated sphere: dn/du, dn/dv from the interpolated vertex normals.
TEST(DifferentialsSpecular, CurvedMeshMirrorMatchesTracedRays) {
    auto s = load_json_scene("diff_uvsphere.json", sphere_scene(R"({"type": "uvsphere", "rings": 48, "segments": 96,
        "material": {"type": "conductor", "material": "Ag"}})"));
    // Pixels whose +-0.25 px neighbours hit the same triangle (the normal's derivative jumps
    // across edges, where finite differences mean nothing).
    auto prim_at = [&](Vec2 f) {
        SurfaceInteraction h;
        RayDifferential q = camera_ray(*s, f);
        return s->intersect(q, h) ? int(h.prim) : -1;
    };
    std::vector<Vec2> films;
    for (float y = 120.5f; y < 300 && films.size() < 4; y += 7)
        for (float x = 130.5f; x < 290 && films.size() < 4; x += 11) {
            Vec2 f(x, y);
            int p = prim_at(f);
            if (p >= 0 && prim_at(f + Vec2(0.25f, 0)) == p && prim_at(f - Vec2(0.25f, 0)) == p &&
                prim_at(f + Vec2(0, 0.25f)) == p && prim_at(f - Vec2(0, 0.25f)) == p)
                films.push_back(f);
        }
    ASSERT_EQ(films.size(), 4u);
    expect_curved_cases(*s, films, false, 1.f, 3.f, true, 0.5);
}

// Refraction into a glass sphere (eta 1.5), to a virtual plane inside it.
TEST(DifferentialsSpecular, RefractionMatchesTracedRays) {
    auto s = load_json_scene("diff_glass.json", sphere_scene(R"({"type": "sphere", "radius": 1,
        "material": {"type": "dielectric"}})"));
    expect_curved_cases(*s, {Vec2(250.5f, 230.5f), Vec2(200.5f, 120.5f), Vec2(290.5f, 200.5f)}, true, 1.5f, 1.f,
                        false, 0.1);
}

// Refraction through both surfaces of the glass sphere, traced with the scene: the exit
// (from inside, n flipped, eta 1/1.5) transported footprint against finite differences.
TEST(DifferentialsSpecular, RefractionThroughSphereMatchesTracedRays) {
    auto s = load_json_scene("diff_glass2.json", sphere_scene(R"({"type": "sphere", "radius": 1,
        "material": {"type": "dielectric"}})"));
    const float eps = 0.25f, eta = 1.5f;
    // Follows a camera ray through entry and exit; returns the final ray (and differentials).
    auto through = [&](Vec2 film, bool diffs, RayDifferential &out) {
        RayDifferential r = camera_ray(*s, film);
        r.scale_differentials(eps);
        for (int k = 0; k < 2; ++k) {
            SurfaceInteraction si;
            EXPECT_TRUE(s->intersect(r, si));
            if (diffs) si.compute_differentials(r, s->camera.get());
            si.compute_normal_derivatives();
            float e = dot(si.wo, si.ns) > 0.f ? eta : 1.f / eta;
            Vec3 wi = refract_dir(si.wo, si.ns, e);
            RayDifferential next(si.spawn_ray(wi));
            if (diffs) {
                EXPECT_TRUE(specular_differentials(r, si, si.ns, wi, BSDF_DeltaTransmission, e, next));
            }
            r = next;
        }
        out = r;
    };
    const Vec3 P0(0, 0, -4), n(0, 0.2f, 1), pa(1, 0, 0);
    const Vec3 nn = normalize(n), pb = cross(nn, pa);
    for (Vec2 film : {Vec2(230.5f, 215.5f), Vec2(190.5f, 175.5f)}) {
        RayDifferential r;
        through(film, true, r);
        SurfaceInteraction pl;
        ASSERT_TRUE(hit_plane(r, P0, nn, pa, pb, pl));
        pl.compute_differentials(r);
        auto traced = [&](Vec2 f) {
            RayDifferential q;
            through(f, false, q);
            SurfaceInteraction h;
            EXPECT_TRUE(hit_plane(q, P0, nn, pa, pb, h));
            return h.p;
        };
        Vec3 fdx = (traced(film + Vec2(eps, 0)) - traced(film - Vec2(eps, 0))) * 0.5f;
        Vec3 fdy = (traced(film + Vec2(0, eps)) - traced(film - Vec2(0, eps))) * 0.5f;
        EXPECT_LT(rel_err(pl.dpdx, fdx), 0.01) << str(pl.dpdx) << " vs " << str(fdx);
        EXPECT_LT(rel_err(pl.dpdy, fdy), 0.01) << str(pl.dpdy) << " vs " << str(fdy);
    }
}

// After rough scattering a ray has no differentials; the camera-based approximation gives
// the footprint of the camera's smallest one-pixel step (for a pinhole with fov < 90 degrees,
// at the film corner) at the point's distance, scaled by the ray's spp factor, stretched by
// 1/cos of the surface's tilt.
TEST(DifferentialsRough, CameraApproximationHasDocumentedSize) {
    const int W = 400, H = 300;
    const float fov = 40.f, scale = 0.125f;
    auto s = load_json_scene("diff_rough.json", fmt::format(R"({{ {}, "shapes": [{{"type": "sphere", "radius": 1}}] }})",
        camera_json(Vec3(0, 0, 5), Vec3(0, 0, 0), Vec3(0, 1, 0), fov, W, H)));
    // Smallest chord between unit directions one pixel apart, at the corners (z = 1 plane).
    const double hw = std::tan(fov * 0.5 * Deg), hh = hw * H / W, ax = 2 * hw / W, ay = 2 * hh / H;
    auto chord = [](double x0, double y0, double x1, double y1) {
        double l0 = std::sqrt(x0 * x0 + y0 * y0 + 1), l1 = std::sqrt(x1 * x1 + y1 * y1 + 1);
        double dx = x0 / l0 - x1 / l1, dy = y0 / l0 - y1 / l1, dz = 1 / l0 - 1 / l1;
        return std::sqrt(dx * dx + dy * dy + dz * dz);
    };
    double dmin_x = 1e30, dmin_y = 1e30;
    for (double sx : {-1.0, 1.0})
        for (double sy : {-1.0, 1.0}) {
            // Raster x + 1 moves camera-space x by -ax; y + 1 moves y by -ay.
            dmin_x = std::min(dmin_x, chord(sx * hw, sy * hh, sx * hw - ax, sy * hh));
            dmin_y = std::min(dmin_y, chord(sx * hw, sy * hh, sx * hw, sy * hh - ay));
        }
    for (float tilt : {0.f, 60.f}) {
        const float dist = 7.f;
        SurfaceInteraction si;
        si.p = Vec3(0.f, 0.f, 5.f) + normalize(Vec3(0.3f, -0.2f, -1.f)) * dist;
        Vec3 view = normalize(si.p - Vec3(0, 0, 5));
        // Normal facing the camera, tilted by `tilt` about an axis perpendicular to the view.
        Vec3 ax1, ax2;
        coordinate_system(view, ax1, ax2);
        si.ng = si.ns = normalize(-view * std::cos(tilt * Deg) + ax1 * std::sin(tilt * Deg));
        coordinate_system(si.ng, si.dpdu, si.dpdv);
        si.wo = -view;
        RayDifferential none(Ray(Vec3(0, 0, 0), Vec3(0, 0, 1)));  // e.g. after a diffuse bounce
        none.footprint_scale = scale;
        si.compute_differentials(none, s->camera.get());
        ASSERT_TRUE(is_finite(si.dpdx) && is_finite(si.dpdy));
        // Both footprints lie in the tangent plane; their projections perpendicular to the
        // view have the documented lengths; the area grows as 1/cos(tilt).
        EXPECT_LT(std::abs(dot(si.dpdx, si.ng)), 1e-5 * length(si.dpdx));
        auto perp = [&](Vec3 v) { return length(v - view * dot(v, view)); };
        EXPECT_NEAR(perp(si.dpdx), scale * dist * dmin_x, 0.01 * scale * dist * dmin_x) << tilt;
        EXPECT_NEAR(perp(si.dpdy), scale * dist * dmin_y, 0.01 * scale * dist * dmin_y) << tilt;
        double area = length(cross(si.dpdx, si.dpdy));
        double expect_area = scale * scale * dist * dist * dmin_x * dmin_y / std::cos(tilt * Deg);
        EXPECT_NEAR(area, expect_area, 0.02 * expect_area) << tilt;
        EXPECT_GT(std::abs(si.dudx) + std::abs(si.dvdx), 0.f);
    }
}

// The whole path with footprints at every bounce (glass, mirror, a textured diffuse floor,
// up to 8 segments) renders without a single NaN/Inf sample.
TEST(DifferentialsRough, RenderThroughDiffuseAndGlassIsFinite) {
    auto s = load_json_scene("diff_render.json", fmt::format(R"({{ {},
      "integrator": {{"type": "path", "max_depth": 8}},
      "sampler": {{"type": "independent", "sample_count": 4}},
      "shapes": [
        {{"type": "sphere", "radius": 1, "material": {{"type": "dielectric"}}}},
        {{"type": "sphere", "radius": 0.5, "center": [1.6, 0, 0], "material": {{"type": "conductor", "material": "Au"}}}},
        {{"type": "rectangle", "material": {{"type": "diffuse", "reflectance": {{"type": "checkerboard"}}}},
          "to_world": {{"translate": [0, -1, 0], "rotate": {{"axis": [1, 0, 0], "angle": -90}}, "scale": [10, 10, 1]}}}}],
      "lights": [{{"type": "constant", "radiance": 1}}]
    }})", camera_json(Vec3(0, 0.3f, 5), Vec3(0, 0, 0), Vec3(0, 1, 0), 60, 64, 48)));
    RenderResult r = render_scene(*s, 4);
    EXPECT_EQ(r.nan_count, 0);
}

// Grazing and degenerate inputs give finite footprints.
TEST(DifferentialsRobust, GrazingAndDegenerateAreFinite) {
    auto s = load_json_scene("diff_robust.json", fmt::format(R"({{ {}, "shapes": [{{"type": "sphere", "radius": 1}}] }})",
        camera_json(Vec3(0, 0, 5), Vec3(0, 0, 0), Vec3(0, 1, 0), 40, 64, 64)));
    const Camera *cam = s->camera.get();
    auto finite_si = [](const SurfaceInteraction &si) {
        return is_finite(si.dpdx) && is_finite(si.dpdy) && std::isfinite(si.dudx) && std::isfinite(si.dudy) &&
               std::isfinite(si.dvdx) && std::isfinite(si.dvdy);
    };
    auto plane_si = [] {
        SurfaceInteraction si;
        si.p = Vec3(0, 0, 0);
        si.ng = si.ns = Vec3(0, 0, 1);
        si.dpdu = Vec3(1, 0, 0);
        si.dpdv = Vec3(0, 1, 0);
        return si;
    };
    for (float cos_t : {1e-2f, 1e-4f, 1e-7f, 0.f}) {
        // A ray skimming the plane z = 0, its differentials offset sideways and up.
        Vec3 d = normalize(Vec3(std::sqrt(1 - cos_t * cos_t), 0, -cos_t));
        RayDifferential r(Ray(Vec3(-5, 0, 5 * cos_t), d));
        r.has_differentials = true;
        r.rx_o = r.o + Vec3(0, 1e-3f, 0);
        r.rx_d = d;
        r.ry_o = r.o;
        r.ry_d = normalize(d + Vec3(0, 0, 1e-3f));
        for (const Camera *c : {cam, static_cast<const Camera *>(nullptr)}) {
            SurfaceInteraction si = plane_si();
            si.wo = -d;
            si.compute_differentials(r, c);
            EXPECT_TRUE(finite_si(si)) << cos_t;
            // Stretch capped: at most MaxFootprintStretch times the perpendicular footprint (~5e-3).
            EXPECT_LE(length(si.dpdy), MaxFootprintStretch * 5.1e-3f + 1e-3f) << cos_t;
            // Specular transport from a grazing hit stays finite too.
            RayDifferential next(Ray(si.p, reflect_dir(si.wo, si.ns)));
            specular_differentials(r, si, si.ns, next.d, BSDF_DeltaReflection, 1.f, next);
            EXPECT_TRUE(!next.has_differentials || (is_finite(next.rx_d) && is_finite(next.ry_d)));
        }
    }
    // Degenerate parameterisations: zero and parallel dp/du, dp/dv give no uv footprint.
    for (int k = 0; k < 2; ++k) {
        SurfaceInteraction si = plane_si();
        si.dpdu = k == 0 ? Vec3() : Vec3(1, 0, 0);
        si.dpdv = k == 0 ? Vec3() : Vec3(2, 0, 0);
        RayDifferential r = camera_ray(*s, Vec2(32, 32));
        r.o = Vec3(0.1f, 0.2f, 3);
        si.compute_differentials(r, cam);
        EXPECT_TRUE(finite_si(si));
        if (k == 0) {
            EXPECT_EQ(si.dudx, 0.f);
        }
    }
    // Huge and non-finite differentials.
    for (float big : {1e30f, Infinity, std::nanf("")}) {
        SurfaceInteraction si = plane_si();
        RayDifferential r(Ray(Vec3(0, 0, 1), Vec3(0, 0, -1)));
        r.has_differentials = true;
        r.rx_o = Vec3(big, 0, 1);
        r.rx_d = Vec3(0, 0, -1);
        r.ry_o = Vec3(0, 0, 1);
        r.ry_d = Vec3(big, big, -1);
        si.wo = Vec3(0, 0, 1);
        si.compute_differentials(r, cam);
        EXPECT_TRUE(finite_si(si)) << big;
    }
    // Camera approximation: at the camera centre, with a normal perpendicular to the view,
    // or a zero / NaN normal.
    Vec3 dx, dy;
    cam->approximate_dp_dxy(Vec3(0, 0, 5), Vec3(0, 0, 1), 1.f, dx, dy);
    EXPECT_EQ(length(dx), 0.f);
    for (Vec3 n : {Vec3(1, 0, 0), Vec3(0, 0, 0), Vec3(std::nanf(""), 0, 0)}) {
        cam->approximate_dp_dxy(Vec3(0, 0, 0), n, 1.f, dx, dy);
        EXPECT_TRUE(is_finite(dx) && is_finite(dy));
        EXPECT_LE(length(dx), MaxFootprintStretch * 5 * 0.02f);
    }
    // Refraction at the critical angle (from inside glass, cos_t -> 0) stays finite.
    {
        SurfaceInteraction si = plane_si();
        si.dndu = Vec3(0.5f, 0, 0);
        float sin_c = 1 / 1.5f;
        Vec3 wo = normalize(Vec3(sin_c, 0, -std::sqrt(1 - sin_c * sin_c)));  // inside, below
        si.wo = wo;
        RayDifferential r(Ray(wo * 2.f, -wo));
        r.has_differentials = true;
        r.rx_o = r.o + Vec3(0, 1e-3f, 0);
        r.rx_d = r.d;
        r.ry_o = r.o;
        r.ry_d = normalize(r.d + Vec3(1e-3f, 0, 0));
        si.compute_differentials(r, cam);
        Vec3 wi = refract_dir(wo, si.ns, 1 / 1.5f);
        RayDifferential next(Ray(si.p, wi));
        specular_differentials(r, si, si.ns, wi, BSDF_DeltaTransmission, 1 / 1.5f, next);
        EXPECT_TRUE(!next.has_differentials || (is_finite(next.rx_d) && is_finite(next.ry_d)));
    }
}

// Shading-normal derivatives: the sphere's are dp/du / r; a mesh sphere's interpolated
// normals approximate them.
TEST(DifferentialsNormals, SphereAndMeshNormalDerivatives) {
    auto s = load_json_scene("diff_normals.json", sphere_scene(R"({"type": "sphere", "radius": 2, "center": [0, 0, 0]})"));
    RayDifferential r = camera_ray(*s, Vec2(230, 170));
    SurfaceInteraction si;
    ASSERT_TRUE(s->intersect(r, si));
    EXPECT_LT(rel_err(si.dndu, si.dpdu * 0.5f), 1e-5);
    EXPECT_LT(rel_err(si.dndv, si.dpdv * 0.5f), 1e-5);
    auto m = load_json_scene("diff_normals_mesh.json", sphere_scene(R"({"type": "uvsphere", "rings": 64, "segments": 128})"));
    SurfaceInteraction mi;
    ASSERT_TRUE(m->intersect(r, mi));
    EXPECT_EQ(length_squared(mi.dndu), 0.f);  // computed on demand only
    mi.compute_normal_derivatives();
    // On a unit sphere dn/du = dp/du up to the tessellation's error.
    EXPECT_LT(rel_err(mi.dndu, mi.dpdu), 0.05) << str(mi.dndu) << " " << str(mi.dpdu);
    EXPECT_LT(rel_err(mi.dndv, mi.dpdv), 0.05) << str(mi.dndv) << " " << str(mi.dpdv);
    // Tangent to the unit normal.
    EXPECT_LT(std::abs(dot(mi.dndu, mi.ns)), 1e-4 * length(mi.dndu));
}
