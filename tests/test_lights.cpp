// Lights: delta lights against their closed forms; the constant environment; environment maps
// for mapping convention, pdf normalisation, sampling histograms (chi-square) and error
// messages. Area lights are in test_area_light.cpp, the float samplers and the choice between
// solid-angle and area sampling in test_light_sampling.cpp. Fixed seeds; tolerances are 5
// standard errors of the estimator unless stated otherwise.
#include <gtest/gtest.h>
#include "scratch_dir.h"
#include <OpenImageIO/imageio.h>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <unistd.h>
#include "core/error.h"
#include "core/transform.h"
#include "geometry/shape.h"
#include "lights/envmap.h"
#include "lights/spherical_triangle.h"
#include "lights/light.h"
#include "sampling/rng.h"
#include "sampling/warp.h"
#include "core/properties.h"
#include "core/registry.h"
#include "light_test_util.h"
#include "render_test_util.h"

using namespace meso;
using namespace meso::test;
using json = nlohmann::json;
namespace fs = std::filesystem;

// --------------------------------------------------------------------------------------
// Delta lights

TEST(PointLight, InverseSquareAndPower) {
    auto l = make_light({{"type", "point"}, {"position", {0, 2, 0}}, {"intensity", {4, 8, 12}}});
    LightSample ls;
    ASSERT_TRUE(l->sample({Vec3(0, 0, 0), Vec3(0, 1, 0)}, {0.3f, 0.7f}, ls));
    EXPECT_NEAR(ls.wi.y, 1.f, 1e-6f);
    EXPECT_FLOAT_EQ(ls.dist, 2.f);
    EXPECT_FLOAT_EQ(ls.L.r, 1.f);
    EXPECT_FLOAT_EQ(ls.L.b, 3.f);
    EXPECT_EQ(ls.pdf, 1.f);
    EXPECT_TRUE(ls.delta);
    EXPECT_TRUE(l->is_delta());
    EXPECT_EQ(l->pdf({}, Vec3(0, 1, 0), {}), 0.f);
    EXPECT_NEAR(l->power(), 4 * Pi * 8, 1e-3);
    // At the light's own position: no sample, no NaN.
    EXPECT_FALSE(l->sample({Vec3(0, 2, 0), Vec3()}, {0.5f, 0.5f}, ls));
}

TEST(SpotLight, FalloffAndPower) {
    json j = {{"type", "spot"}, {"position", {0, 0, 0}}, {"target", {0, 0, 5}}, {"intensity", 2},
              {"cutoff_angle", 30}, {"beam_width", 20}};
    auto l = make_light(j);
    auto at = [&](float deg, float d) {
        Vec3 p = Vec3(std::sin(radians(deg)), 0, std::cos(radians(deg))) * d;
        LightSample ls;
        bool ok = l->sample({p, Vec3()}, {0.5f, 0.5f}, ls);
        return ok ? ls.L.r : 0.f;
    };
    EXPECT_FLOAT_EQ(at(0, 2), 2.f / 4.f);    // on the axis: I / d^2
    EXPECT_FLOAT_EQ(at(19, 1), 2.f);         // inside the beam
    EXPECT_NEAR(at(25, 1), 2.f * 0.5f, 1e-5f);  // half way through the linear ramp
    EXPECT_EQ(at(30.5f, 1), 0.f);            // beyond the cutoff
    EXPECT_EQ(at(120, 1), 0.f);
    // Power = ∫ I falloff dω: quadrature in theta.
    double q = 0;
    const int n = 200000;
    for (int i = 0; i < n; ++i) {
        double th = (i + 0.5) * M_PI / n;
        double f = th <= radians(20) ? 1 : (th >= radians(30) ? 0 : (radians(30) - th) / radians(10));
        q += f * std::sin(th) * (M_PI / n);
    }
    EXPECT_NEAR(l->power(), 2 * 2 * M_PI * q, 1e-4 * l->power());
    // Defaults: beam = 3/4 cutoff = 15 deg.
    auto d = make_light({{"type", "spot"}, {"direction", {0, 0, 1}}, {"cutoff_angle", 20}});
    LightSample ls;
    ASSERT_TRUE(d->sample({Vec3(std::sin(radians(14.9f)), 0, std::cos(radians(14.9f))), Vec3()}, {0, 0}, ls));
    EXPECT_FLOAT_EQ(ls.L.r, 1.f);
    ASSERT_TRUE(d->sample({Vec3(std::sin(radians(17.5f)), 0, std::cos(radians(17.5f))), Vec3()}, {0, 0}, ls));
    EXPECT_NEAR(ls.L.r, 0.5f, 1e-4f);
    EXPECT_EQ(light_error({{"type", "spot"}, {"direction", {0, 0, 1}}, {"target", {0, 0, 1}}}),
              "lights[0].target: give either 'direction' or 'target', not both");
    EXPECT_EQ(light_error({{"type", "spot"}, {"cutoff_angle", 10}, {"beam_width", 12}}),
              "lights[0].beam_width: expected a number in [0, 10], got 12");
}

TEST(DirectionalLight, IrradianceAndPower) {
    auto l = make_light({{"type", "directional"}, {"direction", {0, -2, 0}}, {"irradiance", 3}});
    LightSample ls;
    ASSERT_TRUE(l->sample({Vec3(5, 1, 2), Vec3(0, 1, 0)}, {0.1f, 0.9f}, ls));
    EXPECT_NEAR(ls.wi.y, 1.f, 1e-6f);
    EXPECT_EQ(ls.dist, Infinity);
    EXPECT_FLOAT_EQ(ls.L.g, 3.f);
    EXPECT_TRUE(ls.delta && l->is_delta());
    l->preprocess(Vec3(0, 0, 0), 2.f);
    EXPECT_NEAR(l->power(), Pi * 4 * 3, 1e-4);
    EXPECT_EQ(light_error({{"type", "directional"}, {"direction", {0, 0, 0}}}),
              "lights[0].direction: expected a direction (a vector of non-zero finite length), got [0, 0, 0]");
    EXPECT_EQ(light_error({{"type", "directional"}, {"irradiance", 1}, {"irradiance_typo", 1}}),
              "lights[0].irradiance_typo: unknown parameter 'irradiance_typo' for light 'directional'");
}

TEST(ConstantEnvLight, UniformSphere) {
    auto l = make_light({{"type", "constant"}, {"radiance", {1, 2, 3}}});
    EXPECT_TRUE(l->is_infinite());
    PCG32 rng(5);
    for (int i = 0; i < 100; ++i) {
        LightSample ls;
        ASSERT_TRUE(l->sample({Vec3(), Vec3()}, {rng.next_float(), rng.next_float()}, ls));
        EXPECT_NEAR(length(ls.wi), 1.f, 1e-5f);
        EXPECT_FLOAT_EQ(ls.pdf, l->pdf({}, ls.wi, {}));
        EXPECT_FLOAT_EQ(ls.pdf, 1.f / (4 * Pi));
        EXPECT_FLOAT_EQ(ls.L.g, 2.f);
    }
    l->preprocess(Vec3(), 1.f);
    EXPECT_NEAR(l->power(), 4 * Pi * Pi * 2, 1e-3);
}

// --------------------------------------------------------------------------------------
// Environment maps

namespace {

/// Smooth background with a hot spot (a procedural HDR sky), w x h.
Image hotspot_map(int w, int h, float hu, float hv) {
    Image img(w, h, 3);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            float u = (x + 0.5f) / w, v = (y + 0.5f) / h;
            float du = std::min(std::abs(u - hu), 1 - std::abs(u - hu)) * w, dv = (v - hv) * h;
            float spot = 30.f * std::exp(-(du * du + dv * dv) / (2 * 1.5f * 1.5f));
            float sky = 0.3f + 0.2f * std::sin(2 * Pi * u) * v;
            img.set_rgb(x, y, Spectrum(sky + spot, sky + 0.5f * spot, sky));
        }
    return img;
}

/// Regularised upper incomplete gamma Q(a, x) (Numerical Recipes gammq): chi-square p-values.
double gamma_q(double a, double x) {
    if (x <= 0) return 1;
    double gln = std::lgamma(a);
    if (x < a + 1) {
        double ap = a, sum = 1 / a, del = sum;
        for (int n = 0; n < 1000; ++n) {
            ap += 1;
            del *= x / ap;
            sum += del;
            if (std::abs(del) < std::abs(sum) * 1e-15) break;
        }
        return 1 - sum * std::exp(-x + a * std::log(x) - gln);
    }
    double b = x + 1 - a, c = 1 / 1e-300, d = 1 / b, h = d;
    for (int i = 1; i < 1000; ++i) {
        double an = -i * (i - a);
        b += 2;
        d = an * d + b;
        if (std::abs(d) < 1e-300) d = 1e-300;
        c = b + an / c;
        if (std::abs(c) < 1e-300) c = 1e-300;
        d = 1 / d;
        double del = d * c;
        h *= del;
        if (std::abs(del - 1) < 1e-15) break;
    }
    return std::exp(-x + a * std::log(x) - gln) * h;
}

/// Per-process scratch directory, removed at exit.
std::string tmp_dir() { return meso::test::scratch_dir("meso_test_lights"); }


}  // namespace

TEST(EnvMap, MappingConvention) {
    // Documented landmarks of the Mitsuba lat-long mapping (+y up).
    auto near = [](Vec3 a, Vec3 b) { return length(a - b) < 1e-5f; };
    EXPECT_TRUE(near(EnvMapLight::uv_to_direction({0.5f, 0.5f}), Vec3(0, 0, 1)));
    EXPECT_TRUE(near(EnvMapLight::uv_to_direction({0.25f, 0.5f}), Vec3(1, 0, 0)));
    EXPECT_TRUE(near(EnvMapLight::uv_to_direction({0.75f, 0.5f}), Vec3(-1, 0, 0)));
    EXPECT_TRUE(near(EnvMapLight::uv_to_direction({0.f, 0.5f}), Vec3(0, 0, -1)));
    EXPECT_TRUE(near(EnvMapLight::uv_to_direction({0.3f, 0.f}), Vec3(0, 1, 0)));
    EXPECT_TRUE(near(EnvMapLight::uv_to_direction({0.3f, 1.f}), Vec3(0, -1, 0)));
    PCG32 rng(2);
    for (int i = 0; i < 1000; ++i) {
        Vec2 uv(rng.next_float(), 0.01f + 0.98f * rng.next_float());
        Vec2 back = EnvMapLight::direction_to_uv(EnvMapLight::uv_to_direction(uv));
        EXPECT_NEAR(back.x, uv.x, 1e-5f);
        EXPECT_NEAR(back.y, uv.y, 1e-5f);
    }
}

TEST(EnvMap, BrightTexelLightsPredictedDirection) {
    const int W = 64, H = 32, X = 40, Y = 10;
    Image img(W, H, 3);
    img.set_rgb(X, Y, Spectrum(100.f, 50.f, 25.f));
    // Predicted local direction of the texel centre; the map is rotated 90 deg about +y.
    Vec3 local = EnvMapLight::uv_to_direction({(X + 0.5f) / W, (Y + 0.5f) / H});
    Transform rot = Transform::rotate(Vec3(0, 1, 0), 90.f);
    Vec3 world = normalize(rot.apply_vector(local));
    // Rotation about +y by +90 deg maps +x to -z (right-handed): check the convention used.
    EXPECT_NEAR(rot.apply_vector(Vec3(1, 0, 0)).z, -1.f, 1e-5f);
    EnvMapLight env(img, 2.f, rot, "bright");
    // The bilinear radiance at the texel centre is the texel value times scale.
    Spectrum L = env.radiance(world);
    EXPECT_NEAR(L.r, 200.f, 1e-2f);
    EXPECT_NEAR(L.b, 50.f, 1e-2f);
    // Every sample lands within one texel of it; the mean direction is the texel centre.
    PCG32 rng(9);
    Vec3 mean(0, 0, 0);
    int centre = 0;
    const int N = 20000;
    float texel_angle = Pi / H;
    for (int i = 0; i < N; ++i) {
        LightSample ls;
        ASSERT_TRUE(env.sample({Vec3(), Vec3()}, {rng.next_float(), rng.next_float()}, ls));
        Vec2 uv = EnvMapLight::direction_to_uv(normalize(rot.apply_inverse_vector(ls.wi)));
        int x = int(uv.x * W), y = int(uv.y * H);
        ASSERT_LE(std::abs(x - X), 1);
        ASSERT_LE(std::abs(y - Y), 1);
        centre += (x == X && y == Y);
        mean += ls.wi;
    }
    mean = normalize(mean);
    // Statistical spread ~0.01 texel; the rest is the (small) asymmetry of sin(theta) weights.
    EXPECT_LT(std::acos(std::min(1.f, dot(mean, world))), 0.1f * texel_angle);
    // Cell weights: (1/8, 3/4, 1/8) across, the same times ∫ sin(theta) of each row down.
    auto row = [&](int y) { return std::cos(M_PI * y / H) - std::cos(M_PI * (y + 1) / H); };
    double p_centre = 0.75 * 0.75 * row(Y) / (0.125 * row(Y - 1) + 0.75 * row(Y) + 0.125 * row(Y + 1));
    EXPECT_NEAR(centre / double(N), p_centre, 5 * std::sqrt(p_centre * (1 - p_centre) / N));
}

TEST(EnvMap, PdfIntegratesToOne) {
    Image img = hotspot_map(32, 16, 0.3f, 0.35f);
    // (a) quadrature over the sphere in the map's own frame (pdf·sin(theta) is constant
    // per cell, so the midpoint rule on a refined grid is exact up to rounding).
    {
        EnvMapLight env(img, 1.f, Transform(), "q");
        const int nt = 16 * 16, np = 32 * 16;
        double sum = 0;
        for (int i = 0; i < nt; ++i)
            for (int j = 0; j < np; ++j) {
                Vec2 uv((j + 0.5f) / np, (i + 0.5f) / nt);
                Vec3 d = EnvMapLight::uv_to_direction(uv);
                double sin_t = std::sin(M_PI * uv.y);
                sum += env.pdf({}, d, {}) * sin_t * (M_PI / nt) * (2 * M_PI / np);
            }
        EXPECT_NEAR(sum, 1.0, 1e-4);
    }
    // (b) Monte Carlo with uniform sphere directions on a map rotated about an oblique axis.
    {
        EnvMapLight env(img, 1.f, Transform::rotate(Vec3(1, 2, 0.5f), 37.f), "mc");
        PCG32 rng(13);
        double s = 0, s2 = 0;
        const int N = 400000;
        for (int i = 0; i < N; ++i) {
            Vec3 w = square_to_uniform_sphere({rng.next_float(), rng.next_float()});
            double f = env.pdf({}, w, {}) * 4 * M_PI;
            s += f;
            s2 += f * f;
        }
        MeanStd r = mean_std(s, s2, N);
        EXPECT_NEAR(r.mean, 1.0, 5 * r.stderr_);
    }
}

TEST(EnvMap, SamplingMatchesPdfChiSquare) {
    Image img = hotspot_map(32, 16, 0.3f, 0.35f);
    Transform rot = Transform::rotate(Vec3(1, 2, 0.5f), 37.f);
    EnvMapLight env(img, 1.f, rot, "chi2");
    // Sample; check that sample() reports pdf(wi) and eval; histogram in world (z, phi) bins.
    const int NZ = 12, NP = 24, N = 300000;
    std::vector<double> obs(NZ * NP, 0.0), expct(NZ * NP, 0.0);
    PCG32 rng(17);
    int pdf_mismatches = 0;
    for (int i = 0; i < N; ++i) {
        LightSample ls;
        ASSERT_TRUE(env.sample({Vec3(), Vec3()}, {rng.next_float(), rng.next_float()}, ls));
        if (i < 20000) {
            // sample() takes the pdf from the sampled cell, pdf() from the cell wi maps back to:
            // equal to float round-off, except where that round-off crosses a cell boundary.
            const float p = env.pdf({}, ls.wi, {});
            if (!(std::abs(ls.pdf - p) <= 1e-4f * p)) ++pdf_mismatches;
            // sample() looks up the radiance at the sampled uv, eval() at the uv re-derived from
            // wi: the bilinear lookup is continuous, so they agree to float round-off.
            ASSERT_NEAR(ls.L.r, env.eval({}, -ls.wi).r, 1e-5f * ls.L.r + 1e-7f);
            ASSERT_NEAR(length(ls.wi), 1.f, 1e-5f);
            ASSERT_EQ(ls.dist, Infinity);
        }
        float z = clamp(ls.wi.z, -1.f, 1.f);
        float phi = std::atan2(ls.wi.y, ls.wi.x);
        if (phi < 0) phi += 2 * Pi;
        int iz = std::min(NZ - 1, int((z + 1) * 0.5f * NZ)), ip = std::min(NP - 1, int(phi / (2 * Pi) * NP));
        obs[iz * NP + ip] += 1;
    }
    EXPECT_LE(pdf_mismatches, 20) << "of 20000 samples, sample() and pdf() disagree by more than 1e-4";
    // Expected counts: integrate pdf over each bin (uniform in z and phi: dω = dz dphi) on a
    // 24 x 24 sub-grid.
    const int S = 24;
    double total = 0;
    for (int iz = 0; iz < NZ; ++iz)
        for (int ip = 0; ip < NP; ++ip) {
            double acc = 0;
            for (int a = 0; a < S; ++a)
                for (int b = 0; b < S; ++b) {
                    double z = -1 + 2.0 * (iz + (a + 0.5) / S) / NZ;
                    double phi = 2 * M_PI * (ip + (b + 0.5) / S) / NP;
                    double r = std::sqrt(std::max(0.0, 1 - z * z));
                    acc += env.pdf({}, Vec3(float(r * std::cos(phi)), float(r * std::sin(phi)), float(z)), {});
                }
            double bin_area = (2.0 / NZ) * (2 * M_PI / NP);
            expct[iz * NP + ip] = acc / (S * S) * bin_area * N;
            total += expct[iz * NP + ip];
        }
    ASSERT_NEAR(total / N, 1.0, 2e-3);  // quadrature sanity
    // Chi-square over bins with expected >= 5 (the rest pooled), significance 1e-3.
    double chi2 = 0, pool_o = 0, pool_e = 0;
    int dof = -1;
    for (size_t k = 0; k < obs.size(); ++k) {
        if (expct[k] < 5) {
            pool_o += obs[k];
            pool_e += expct[k];
            continue;
        }
        chi2 += sqr(obs[k] - expct[k]) / expct[k];
        ++dof;
        EXPECT_NEAR(obs[k], expct[k], 5 * std::sqrt(expct[k]) + 5) << "bin " << k;
    }
    if (pool_e > 0) {
        chi2 += sqr(pool_o - pool_e) / pool_e;
        ++dof;
    }
    double pval = gamma_q(dof / 2.0, chi2 / 2.0);
    EXPECT_GT(pval, 1e-3) << "chi2 = " << chi2 << " dof = " << dof;
}

TEST(EnvMap, DeferredRadianceIsTheSampledRadiance) {
    // With ctx.defer_radiance, sample() leaves L to sampled_radiance() (read after the caller's
    // shadow ray): the same direction, pdf and, bit for bit, radiance as an immediate sample.
    // The deferred uv is the inverse CDF's: one row for a fixed u.y, non-decreasing in u.x
    // along it and in u.y across rows (Sobol strata stay contiguous).
    Image img = hotspot_map(37, 19, 0.3f, 0.35f);
    EnvMapLight env(img, 1.f, Transform::rotate(Vec3(1, 2, 0.5f), 37.f), "defer");
    PCG32 rng(23);
    for (int i = 0; i < 20000; ++i) {
        const Vec2 u(rng.next_float(), rng.next_float());
        LightSample a, b;
        const bool ok = env.sample({Vec3(), Vec3()}, u, a);
        ASSERT_EQ(env.sample({Vec3(), Vec3(), true}, u, b), ok);
        if (!ok) continue;
        ASSERT_FALSE(a.L_deferred);
        ASSERT_TRUE(b.L_deferred);
        ASSERT_TRUE(a.wi.x == b.wi.x && a.wi.y == b.wi.y && a.wi.z == b.wi.z && a.pdf == b.pdf);
        const Spectrum La = env.sampled_radiance(a), Lb = env.sampled_radiance(b);
        ASSERT_TRUE(La.r == a.L.r && La.g == a.L.g && La.b == a.L.b);
        ASSERT_TRUE(Lb.r == La.r && Lb.g == La.g && Lb.b == La.b) << i;
        ASSERT_NEAR(Lb.g, env.eval({}, -b.wi).g, 1e-5f * Lb.g + 1e-7f);
    }
    const int K = 2048;
    for (float fixed : {0.03f, 0.5f, 0.97f}) {
        Vec2 prev_row(-1.f, -1.f), prev_col(-1.f, -1.f);
        for (int k = 0; k < K; ++k) {
            const float t = (k + 0.5f) / K;
            LightSample r, c;
            ASSERT_TRUE(env.sample({Vec3(), Vec3(), true}, {t, fixed}, r));
            ASSERT_TRUE(env.sample({Vec3(), Vec3(), true}, {fixed, t}, c));
            ASSERT_GE(r.uv.x, prev_row.x) << "u.x " << t;
            if (k > 0) {
                ASSERT_EQ(r.uv.y, prev_row.y);
            }
            ASSERT_GE(c.uv.y, prev_col.y) << "u.y " << t;
            prev_row = r.uv;
            prev_col = c.uv;
        }
    }
}

TEST(EnvMap, PowerAndSceneFileErrors) {
    // Constant map: ∫ L dω = 4 pi L exactly; power = pi r^2 · 4 pi L.
    Image img(8, 4, 3);
    for (auto &x : img.data) x = 0.5f;
    std::string dir = tmp_dir();
    write_float_image(dir + "/const.exr", img);
    auto ctx = std::make_shared<LoadContext>();
    ctx->file = "scene.json";
    ctx->base_dir = dir;
    json j = {{"type", "envmap"}, {"filename", "const.exr"}, {"scale", 2},
              {"to_world", {{"rotate", {{"axis", {0, 1, 0}}, {"angle", 30}}}}}};
    auto l = make_light(j, ctx);
    ASSERT_TRUE(l->is_infinite());
    l->preprocess(Vec3(), 3.f);
    EXPECT_NEAR(l->power(), Pi * 9 * 4 * Pi * 1.0, 1e-3 * l->power());
    EXPECT_NE(l->to_string().find("MB"), std::string::npos);
    EXPECT_NEAR(l->eval({}, Vec3(0.3f, 0.4f, 0.866f)).g, 1.f, 1e-6f);

    // Missing file, malformed EXR, scale in to_world: errors name the file and the key.
    EXPECT_EQ(light_error({{"type", "envmap"}, {"filename", "nope.exr"}}, ctx),
              "scene.json: lights[0].filename: file not found: '" + dir + "/nope.exr'");
    {
        std::ofstream f(dir + "/broken.exr");
        f << "this is not an OpenEXR file";
    }
    std::string msg = light_error({{"type", "envmap"}, {"filename", "broken.exr"}}, ctx);
    EXPECT_EQ(msg.rfind("scene.json: lights[0].filename: ", 0), 0u) << msg;
    EXPECT_NE(msg.find("broken.exr"), std::string::npos) << msg;
    msg = light_error({{"type", "envmap"}, {"filename", "const.exr"}, {"to_world", {{"scale", 2}}}}, ctx);
    EXPECT_EQ(msg, "scene.json: lights[0].to_world: to_world of an environment map must be a rotation (no scale or shear)");
    // Non-finite texels are rejected with the file named.
    img.at(3, 2, 1) = std::nanf("");
    write_float_image(dir + "/nan.exr", img);
    msg = light_error({{"type", "envmap"}, {"filename", "nan.exr"}}, ctx);
    EXPECT_EQ(msg, "scene.json: lights[0].filename: " + dir +
                       "/nan.exr: environment map has 1 pixel(s) with negative, NaN or infinite values");
}
