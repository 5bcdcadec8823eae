// Alpha masks (a shape's "alpha" and "alpha_cutoff"; glTF alphaMode MASK): where the alpha
// texture is below the cutoff the surface is not there for camera rays, shadow rays and
// bounce rays (Embree filter functions), and a cut-out emitter emits only where it is there.
// Every scene is analytic: a 2 x 2 checker alpha over a lit or emitting background, black
// occluders, one directional light or one emitter, so the expected pixels are exact.
#include <gtest/gtest.h>
#include <cmath>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "image/image.h"
#include "lights/light.h"
#include "render_test_util.h"
#include "sampling/rng.h"
#include "scratch_dir.h"

using namespace meso;
using json = nlohmann::json;

namespace {

/// A grey float image of w x h texels with the given values (row 0 = v in [0, 1/h]).
std::string alpha_image(const std::string &name, int w, int h, const std::vector<float> &values) {
    const std::string path = meso::test::scratch_dir("meso_test_alpha") + "/" + name;
    Image img(w, h, 1);
    img.data = values;
    write_exr(path, img);
    return path;
}

/// The 2 x 2 checker alpha: texels (0, 0) and (1, 1) are 1, the others 0. On a `rectangle`
/// (u = (x + 1)/2, v = (y + 1)/2) seen from +z with +y up, the image's top-left and
/// bottom-right quadrants are cut out.
std::string checker_alpha() { return alpha_image("checker.exr", 2, 2, {1, 0, 0, 1}); }

json alpha_texture(const std::string &file) {
    return {{"type", "bitmap"}, {"filename", file}, {"filter_type", "nearest"}};
}

json black() { return {{"type", "diffuse"}, {"reflectance", 0}}; }

json camera(json origin, json target, json up, double fov) {
    return {{"type", "perspective"}, {"origin", origin}, {"target", target}, {"up", up},
            {"fov", fov}, {"width", 32}, {"height", 32}};
}

/// Mean of channel 0 over the 8 x 8 pixels at the centre of image quadrant (qx, qy).
double quadrant_centre(const Image &img, int qx, int qy) {
    double sum = 0;
    for (int y = 0; y < 8; ++y)
        for (int x = 0; x < 8; ++x) sum += img.at(16 * qx + 4 + x, 16 * qy + 4 + y, 0);
    return sum / 64.0;
}

RenderResult render(const std::string &name, const json &scene, int spp = 4) {
    auto s = meso::test::load_json_scene(name, scene.dump());
    return meso::test::render_scene(*s, spp);
}

}  // namespace

TEST(AlphaMask, CameraAndShadowRaysPassThroughTheCutQuadrants) {
    // A black checker-masked quad at z = 0 over a diffuse background (reflectance 0.5) at
    // z = −0.1, lit straight down by a directional light of irradiance 2, seen from z = 10.
    // Through the cut quadrants the camera sees the background, lit through the same cut
    // quadrants: 0.5 · 2 / π; the quadrants that are there are black (and shadow what lies
    // under them). A mask that stopped camera rays would give 0 everywhere; one that stopped
    // shadow rays would give 0 through the cut quadrants too.
    const json scene = {
        {"camera", camera({0, 0, 10}, {0, 0, 0}, {0, 1, 0}, 12)},
        {"integrator", {{"type", "direct"}}},
        {"shapes", {{{"type", "rectangle"}, {"material", black()}, {"alpha", alpha_texture(checker_alpha())}},
                    {{"type", "rectangle"}, {"material", {{"type", "diffuse"}, {"reflectance", 0.5}}},
                     {"to_world", {{"scale", {5, 5, 1}}, {"translate", {0, 0, -0.1}}}}}}},
        {"lights", {{{"type", "directional"}, {"direction", {0, 0, -1}}, {"irradiance", 2}}}}};
    RenderResult r = render("alpha_primary_shadow.json", scene);
    const double lit = 0.5 * 2 / Pi;
    EXPECT_NEAR(quadrant_centre(r.image, 0, 0), lit, 1e-4);  // top-left: cut out
    EXPECT_NEAR(quadrant_centre(r.image, 1, 1), lit, 1e-4);  // bottom-right: cut out
    EXPECT_NEAR(quadrant_centre(r.image, 1, 0), 0.0, 1e-6);  // top-right: there
    EXPECT_NEAR(quadrant_centre(r.image, 0, 1), 0.0, 1e-6);  // bottom-left: there

    // Without the mask the quad hides everything; "alpha": 1 (a constant at or above the
    // cutoff) is no mask at all, "alpha": 0 cuts the whole quad out.
    json opaque = scene, gone = scene;
    opaque["shapes"][0]["alpha"] = 1;
    gone["shapes"][0]["alpha"] = 0;
    RenderResult ro = render("alpha_opaque.json", opaque), rg = render("alpha_gone.json", gone);
    for (int q = 0; q < 4; ++q) {
        EXPECT_NEAR(quadrant_centre(ro.image, q % 2, q / 2), 0.0, 1e-6) << q;
        EXPECT_NEAR(quadrant_centre(rg.image, q % 2, q / 2), lit, 1e-4) << q;
    }
}

TEST(AlphaMask, ShadowsFallOnlyBehindWhatIsThere) {
    // The shadow alone: a black quad at z = 1 whose left half (u < 0.5, x < 0) is there and
    // right half cut, a light travelling along (−2, 0, −1)/√5, which moves a point (x, y, 1)
    // of the quad to (x − 2, y, 0) on the receiver. The camera looks straight down at
    // x in [−3, −1], beside the quad: the left half of the view (x < −2) is in the shadow of
    // the part that is there, the right half gets the light through the cut part,
    // 0.5/π · 2 · cos θ with cos θ = 1/√5.
    const json scene = {
        {"camera", camera({-2, 0, 10}, {-2, 0, 0}, {0, 1, 0}, 2 * std::atan(0.1) * 180 / Pi)},
        {"integrator", {{"type", "direct"}}},
        {"shapes", {{{"type", "rectangle"}, {"material", black()}, {"to_world", {{"translate", {0, 0, 1}}}},
                     {"alpha", alpha_texture(alpha_image("half.exr", 2, 1, {1, 0}))}, {"alpha_cutoff", 0.25}},
                    {{"type", "rectangle"}, {"material", {{"type", "diffuse"}, {"reflectance", 0.5}}},
                     {"to_world", {{"scale", {5, 5, 1}}}}}}},
        {"lights", {{{"type", "directional"}, {"direction", {-2, 0, -1}}, {"irradiance", 2}}}}};
    RenderResult r = render("alpha_shadow.json", scene);
    const double lit = 0.5 / Pi * 2 / std::sqrt(5.0);
    for (int y = 8; y < 24; ++y) {
        for (int x = 2; x < 14; ++x) EXPECT_NEAR(r.image.at(x, y, 0), 0.0, 1e-6) << x << "," << y;
        for (int x = 18; x < 30; ++x) EXPECT_NEAR(r.image.at(x, y, 0), lit, 1e-4) << x << "," << y;
    }
}

TEST(AlphaMask, BounceRaysPassThroughTheCutQuadrants) {
    // The first test's view folded by a mirror: the camera at (−5, 0, 5) looks along +x at a
    // perfect mirror at (0, 0, 5) facing (−1, 0, −1)/√2, which sends the rays down onto the
    // checker-masked quad (path length 10, as from z = 10) over an emitter of radiance 2 at
    // z = −0.1. The mirror flips the view left to right: the cut quadrants show 2 at the
    // top-right and bottom-left, the others are black.
    const json scene = {
        {"camera", camera({-5, 0, 5}, {0, 0, 5}, {0, 1, 0}, 12)},
        {"integrator", {{"type", "path"}, {"max_depth", 4}}},
        {"shapes",
         {{{"type", "rectangle"}, {"material", {{"type", "conductor"}, {"material", "none"}}},
           {"to_world", {{"scale", {2, 2, 1}}, {"rotate", {{"axis", {0, 1, 0}}, {"angle", -135}}}, {"translate", {0, 0, 5}}}}},
          {{"type", "rectangle"}, {"material", black()}, {"alpha", alpha_texture(checker_alpha())}},
          {{"type", "rectangle"}, {"material", black()}, {"to_world", {{"scale", {5, 5, 1}}, {"translate", {0, 0, -0.1}}}},
           {"emitter", {{"type", "area"}, {"radiance", 2}}}}}}};
    RenderResult r = render("alpha_bounce.json", scene);
    EXPECT_NEAR(quadrant_centre(r.image, 1, 0), 2.0, 1e-4);  // top-right: the cut top-left, mirrored
    EXPECT_NEAR(quadrant_centre(r.image, 0, 1), 2.0, 1e-4);  // bottom-left
    EXPECT_NEAR(quadrant_centre(r.image, 0, 0), 0.0, 1e-6);
    EXPECT_NEAR(quadrant_centre(r.image, 1, 1), 0.0, 1e-6);
}

TEST(AlphaMask, CutOutEmitterEmitsOnlyWhereItIsThere) {
    // An emitter [−1, 1]² (radiance 1, facing +z) whose right half is cut out lights a point
    // above it like its left half alone: next-event estimates of the irradiance agree with
    // those of a constant emitter covering only [−1, 0] x [−1, 1] (5 standard errors).
    const std::string half = alpha_image("emit_half.exr", 2, 1, {1, 0});
    auto irradiance = [](const std::string &name, const json &emitter_shape, double *stderr_) {
        const json scene = {{"camera", camera({0, 0, 5}, {0, 0, 0}, {0, 1, 0}, 40)}, {"shapes", {emitter_shape}}};
        auto s = meso::test::load_json_scene(name, scene.dump());
        const Light &light = *s->lights.at(0);
        const Vec3 p(0.4f, 0.3f, 0.8f), n(0, 0, -1);
        PCG32 rng(9);
        double sum = 0, sum2 = 0;
        const int N = 200000;
        for (int i = 0; i < N; ++i) {
            LightSample ls;
            double f = 0;
            if (light.sample({p, n}, {rng.next_float(), rng.next_float()}, ls))
                f = ls.L.average() * std::max(0.f, dot(ls.wi, n)) / ls.pdf;
            sum += f, sum2 += f * f;
        }
        const double m = sum / N;
        *stderr_ = std::sqrt(std::max(0.0, sum2 / N - m * m) / N);
        return m;
    };
    double se_cut, se_half;
    const double cut = irradiance("emit_cut.json",
                                  {{"type", "rectangle"}, {"material", black()}, {"alpha", alpha_texture(half)},
                                   {"emitter", {{"type", "area"}, {"radiance", 1}}}},
                                  &se_cut);
    const double left = irradiance("emit_left.json",
                                   {{"type", "rectangle"}, {"material", black()},
                                    {"to_world", {{"scale", {0.5, 1, 1}}, {"translate", {-0.5, 0, 0}}}},
                                    {"emitter", {{"type", "area"}, {"radiance", 1}}}},
                                   &se_half);
    EXPECT_NEAR(cut, left, 5 * std::hypot(se_cut, se_half));
    EXPECT_GT(left, 0.05);
}

TEST(AlphaMask, LocatedErrors) {
    const std::string half = alpha_image("err_half.exr", 2, 1, {1, 0});
    auto error_of = [](const json &shape) {
        const json scene = {{"camera", camera({0, 0, 5}, {0, 0, 0}, {0, 1, 0}, 40)}, {"shapes", {shape}}};
        try {
            meso::test::load_json_scene("alpha_errors.json", scene.dump());
        } catch (const MesoError &e) {
            return std::string(e.what());
        }
        return std::string("(no error)");
    };
    const std::string file = meso::test::write_temp("alpha_errors.json", "");
    EXPECT_EQ(error_of({{"type", "sphere"}, {"alpha", alpha_texture(half)}}),
              file + ": shapes[0].alpha: an alpha mask needs a triangle-mesh shape (not an analytic sphere or a "
                     "shell-mapped displacement)");
    EXPECT_EQ(error_of({{"type", "rectangle"}, {"alpha_cutoff", 0.5}}),
              file + ": shapes[0].alpha_cutoff: only meaningful with an \"alpha\" texture");
    EXPECT_EQ(error_of({{"type", "rectangle"}, {"alpha", alpha_texture(half)}, {"alpha_cutoff", 1.5}}),
              file + ": shapes[0].alpha_cutoff: expected a number in [0, 1], got 1.5");
}
