// Effective BRDF estimators (paper 004, eq. 6-8, 15-17, 25): flat fields reproduce the base
// material, a symmetric V-groove matches its closed-form single-bounce value, interreflections
// add energy but conserve it (white furnace), the estimator is reciprocal in the paper's
// sense, bad input is rejected and grazing directions stay finite.
//
// Tolerances are z-scores of the estimators' own standard errors (fixed seeds), plus a small
// absolute slack for the 1e-4-cell ray offsets.
#include <gtest/gtest.h>
#include <tbb/global_control.h>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <string>
#include "core/error.h"
#include "geometry/heightfield.h"
#include "geometry/heightmap_gen.h"
#include "material_test_util.h"
#include "prefilter/effective_brdf.h"

using namespace meso;
using meso::prefilter::EffectiveBrdfEstimator;
using meso::prefilter::PatchRegion;
using meso::test::dir_deg;
using meso::test::make_material;

namespace {

constexpr double kPiD = 3.14159265358979323846;
constexpr double kZ = 4.5;  // z-score of every statistical comparison

/// A generated square map in tile units, turned into cell space (heights times the size, so
/// the slopes are kept: see effective_brdf.h, "Units").
Heightfield generated(const std::string &kind, std::map<std::string, std::string> params) {
    GeneratedMap g = generate_height_map(kind, params);
    return Heightfield(g.height, float(g.height.width), 0.f);
}

/// Closed-form single-bounce effective BRDF (eq. 6, macro cosine included) of the symmetric
/// V-groove of facet angle `alpha` (profile along x, constant along y), diffuse albedo rho.
/// 2D analysis: only the slope m = w.z / |w.x| of a direction's projection on the xz-plane
/// matters. A facet (normal tilted away from the direction's x side) is fully visible
/// unless the direction leans over the opposite facet of its groove; then, for m < tan(alpha),
/// the part above height z* is visible, z* / H = (t - m) / (t + m), i.e. the visible
/// fraction is 2m / (t + m). Masking and shadowing cut the same lower part of the facet, so
/// the jointly visible fraction is the smaller one. Each facet covers half the footprint.
double vgroove_single(double alpha, double rho, Vec3 wi, Vec3 wo) {
    const double t = std::tan(alpha), sa = std::sin(alpha), ca = std::cos(alpha);
    double sum = 0;
    for (int side : {+1, -1}) {  // +1: rising facet, normal (-sin, 0, cos); -1: its mirror image
        auto cosn = [&](Vec3 w) { return -side * w.x * sa + w.z * ca; };
        auto frac = [&](Vec3 w) {
            if (!(cosn(w) > 0)) return 0.0;
            const double wx = side * w.x;
            if (wx >= 0) return 1.0;
            const double m = w.z / -wx;
            return m >= t ? 1.0 : 2 * m / (t + m);
        };
        const double ci = cosn(wi), co = cosn(wo);
        if (ci <= 0 || co <= 0) continue;
        sum += 0.5 * rho / kPiD * ci * co / ca * std::min(frac(wi), frac(wo));
    }
    return sum / wo.z;
}

double combined(double a, double b) { return std::sqrt(a * a + b * b); }

}  // namespace

// ---------------------------------------------------------------------------------------
// 1. Flat: the effective BRDF is the base BRDF, with or without paths (nothing to bounce on).

TEST(EffectiveBrdf, FlatEqualsBaseMaterial) {
    const Heightfield hf(HeightMap(16, 16, 0.f), 1.f, 0.3f);
    for (const char *json : {R"({"type":"diffuse","reflectance":0.7})",
                             R"({"type":"conductor","material":"Cu","alpha":0.3})"}) {
        auto mat = make_material(json);
        EffectiveBrdfEstimator est(hf, *mat);
        const ShadingContext ctx;
        const Vec3 dirs[][2] = {{dir_deg(0, 0), dir_deg(0, 0)},
                                {dir_deg(30, 10), dir_deg(45, 200)},
                                {dir_deg(60, 90), dir_deg(20, 80)},
                                {dir_deg(80, 0), dir_deg(75, 170)}};
        for (auto &d : dirs) {
            const Vec3 wi = d[0], wo = d[1];
            const Spectrum ref = mat->eval(ctx, wo, wi);
            for (int bounces : {1, 8}) {
                for (PatchRegion r : {PatchRegion::whole(hf), PatchRegion{2.5, -3.25, 7.5, 1.0}}) {
                    auto e = est.estimate(r, wi, wo, 2000, 7, bounces);
                    SCOPED_TRACE(std::string(json) + " bounces " + std::to_string(bounces));
                    EXPECT_EQ(e.leaked, 0u);
                    EXPECT_GT(e.accepted, 0u);
                    for (int c = 0; c < 3; ++c) {
                        EXPECT_NEAR(e.value[c], ref[c], 1e-5 * (1 + ref[c])) << "channel " << c;
                        EXPECT_NEAR(e.brdf[c], ref[c] / wi.z, 1e-4 * (1 + ref[c] / wi.z));
                    }
                    // Constant integrand: no variance; A(wo) = cos(theta_o).
                    EXPECT_LT(e.std_error.max(), 1e-5f);
                    EXPECT_NEAR(e.projected_area, wo.z, kZ * e.projected_area_std_error + 1e-12);
                }
            }
        }
    }
}

TEST(EffectiveBrdf, FlatWhiteFurnaceIsOne) {
    const Heightfield hf(HeightMap(8, 8, 0.f), 1.f, 0.f);
    auto mat = make_material(R"({"type":"diffuse","reflectance":1})");
    EffectiveBrdfEstimator est(hf, *mat);
    auto e = est.albedo(PatchRegion::whole(hf), dir_deg(40, 30), 4000, 3, 1);
    // eval / pdf is exactly 1 for a white Lambertian base under cosine-distributed wi.
    EXPECT_NEAR(e.value.r, 1.0, 1e-5);
    EXPECT_LT(e.std_error.r, 1e-5f);
}

// ---------------------------------------------------------------------------------------
// 2. V-groove: closed form for one bounce; interreflections add energy, conserve it.

TEST(EffectiveBrdf, VGrooveSingleBounceMatchesClosedForm) {
    // 64 cells, 4 periods: 16 cells per period, facet edges on vertices, slope +-1 (45 deg).
    const Heightfield hf = generated("vgroove", {{"size", "64"}, {"periods", "4"}, {"angle", "45"}});
    const double alpha = kPiD / 4, rho = 0.8;
    auto mat = make_material(R"({"type":"diffuse","reflectance":0.8})");
    EffectiveBrdfEstimator est(hf, *mat);
    struct Case {
        Vec3 wi, wo;
    };
    const Case cases[] = {
        {dir_deg(30, 0), dir_deg(60, 180)},   // opposite sides, in the profile plane
        {dir_deg(50, 0), dir_deg(50, 0)},     // retro-reflection: masking == shadowing
        {dir_deg(70, 20), dir_deg(10, 90)},   // out of plane
        {dir_deg(75, 180), dir_deg(40, 30)},  // strong shadowing
        {dir_deg(0, 0), dir_deg(0, 0)},       // normal incidence: rho / pi cos(alpha)
        {dir_deg(65, 0), dir_deg(55, 180)},   // each direction sees only the facet the other cannot: 0
        {dir_deg(70, 0), dir_deg(55, 0)},     // same side: shadowing hides more than masking
        {dir_deg(60, 180), dir_deg(80, 200)}, // same side, out of plane: masking hides more
        {dir_deg(80, 30), dir_deg(60, -20)},  // both grazing-ish, out of plane
    };
    // Whole periods (no rejection) and a sub-patch of exactly two groove periods placed off
    // the grid in x and y (rejection along both axes): both average the same profile.
    const PatchRegion regions[] = {PatchRegion::whole(hf), PatchRegion{5, 3, 37, 20.5}};
    int k = 0;
    for (const Case &c : cases) {
        const double ref = vgroove_single(alpha, rho, c.wi, c.wo);
        for (const PatchRegion &r : regions) {
            auto e = est.estimate(r, c.wi, c.wo, 120000, 100 + k++, 1);
            std::printf("[vgroove] wi=(%.3f %.3f %.3f) wo=(%.3f %.3f %.3f) est %.5f +- %.5f ref %.5f A %.4f (cos %.4f)\n",
                        c.wi.x, c.wi.y, c.wi.z, c.wo.x, c.wo.y, c.wo.z, e.value.r, e.std_error.r, ref,
                        e.projected_area, c.wo.z);
            EXPECT_EQ(e.leaked, 0u);
            EXPECT_NEAR(e.value.r, ref, kZ * e.std_error.r + 2e-4);
            EXPECT_NEAR(e.projected_area, c.wo.z, kZ * e.projected_area_std_error + 1e-9);
        }
    }
}

TEST(EffectiveBrdf, VGrooveInterreflectionsAddEnergyWithinFurnaceBound) {
    const Heightfield hf = generated("vgroove", {{"size", "64"}, {"periods", "4"}, {"angle", "45"}});
    auto grey = make_material(R"({"type":"diffuse","reflectance":0.8})");
    auto white = make_material(R"({"type":"diffuse","reflectance":1})");
    EffectiveBrdfEstimator est(hf, *grey), est_white(hf, *white);
    const PatchRegion whole = PatchRegion::whole(hf);

    // A fixed pair: the second bounce lights the facet hidden from wi.
    const Vec3 wi = dir_deg(30, 0), wo = dir_deg(60, 180);
    auto one = est.estimate(whole, wi, wo, 100000, 11, 1);
    auto many = est.estimate(whole, wi, wo, 100000, 12, prefilter::kAllBounces);
    std::printf("[vgroove ir] single %.5f +- %.5f, all bounces %.5f +- %.5f\n", one.value.r, one.std_error.r,
                many.value.r, many.std_error.r);
    EXPECT_GT(many.value.r - one.value.r, kZ * combined(one.std_error.r, many.std_error.r));

    for (double theta_o : {0.0, 60.0}) {
        const Vec3 w = dir_deg(theta_o, 0);
        auto a1 = est.albedo(whole, w, 100000, 21, 1);
        auto a8 = est.albedo(whole, w, 100000, 22, prefilter::kAllBounces);
        auto aw = est_white.albedo(whole, w, 100000, 23, prefilter::kAllBounces);
        std::printf("[vgroove albedo] theta_o %.0f: single %.4f +- %.4f, rho=0.8 all %.4f +- %.4f, white all %.4f +- "
                    "%.4f\n",
                    theta_o, a1.value.r, a1.std_error.r, a8.value.r, a8.std_error.r, aw.value.r, aw.std_error.r);
        EXPECT_GT(a8.value.r - a1.value.r, kZ * combined(a1.std_error.r, a8.std_error.r));
        // Every bounce keeps at most rho of the energy: the effective albedo is <= rho.
        EXPECT_LE(a8.value.r, 0.8 + kZ * a8.std_error.r);
        // White furnace: a lossless base loses nothing to interreflections.
        EXPECT_NEAR(aw.value.r, 1.0, 0.02);
        EXPECT_NEAR(aw.value.r, 1.0, kZ * aw.std_error.r + 2e-3);
    }
}

// ---------------------------------------------------------------------------------------
// 3. Reciprocity (eq. 25): f_eff(wi, wo) A(wo) = f_eff(wo, wi) A(wi).

TEST(EffectiveBrdf, ReciprocityOnGaussianSurface) {
    const Heightfield hf =
        generated("gaussian", {{"size", "64"}, {"seed", "5"}, {"sxx", "0.3"}, {"syy", "0.2"}, {"sxy", "0.05"},
                               {"correlation", "0.08"}});
    auto mat = make_material(R"({"type":"diffuse","reflectance":0.6})");
    auto metal = make_material(R"({"type":"conductor","alpha":0.4})");
    EffectiveBrdfEstimator est(hf, *mat), est_metal(hf, *metal);
    const PatchRegion whole = PatchRegion::whole(hf), part{10, 7, 30, 40};
    struct Case {
        Vec3 a, b;
        int bounces;
        const EffectiveBrdfEstimator *e;
        PatchRegion r;
    };
    const Case cases[] = {
        {dir_deg(20, 0), dir_deg(70, 120), 1, &est, whole},  {dir_deg(45, 30), dir_deg(60, 250), 1, &est, whole},
        {dir_deg(80, 90), dir_deg(10, 0), 1, &est, whole},   {dir_deg(50, 10), dir_deg(75, 10), 1, &est, part},
        {dir_deg(30, 45), dir_deg(65, 200), 1, &est_metal, whole},
        {dir_deg(40, 0), dir_deg(70, 150), 4, &est, whole},
    };
    int k = 0;
    for (const Case &c : cases) {
        auto ab = c.e->estimate(c.r, c.a, c.b, 150000, 300 + k, c.bounces);  // wi = a, wo = b
        auto ba = c.e->estimate(c.r, c.b, c.a, 150000, 400 + k, c.bounces);
        ++k;
        const double l = ab.value.r * ab.projected_area, r = ba.value.r * ba.projected_area;
        // Error of a product: relative errors add in quadrature.
        const double sl = l * combined(ab.std_error.r / std::max(1e-30f, ab.value.r),
                                       ab.projected_area_std_error / ab.projected_area);
        const double sr = r * combined(ba.std_error.r / std::max(1e-30f, ba.value.r),
                                       ba.projected_area_std_error / ba.projected_area);
        std::printf("[reciprocity] case %d (%d bounces): f(a,b)A(b) %.5f +- %.5f, f(b,a)A(a) %.5f +- %.5f\n", k,
                    c.bounces, l, sl, r, sr);
        EXPECT_GT(l, 0);
        EXPECT_NEAR(l, r, kZ * combined(sl, sr)) << "case " << k;
    }
}

// ---------------------------------------------------------------------------------------
// 4. Bad input and grazing directions.

TEST(EffectiveBrdf, BadInputIsRejectedOrZero) {
    const Heightfield hf = generated("vgroove", {{"size", "32"}, {"periods", "2"}, {"angle", "30"}});
    auto mat = make_material(R"({"type":"diffuse","reflectance":0.5})");
    EffectiveBrdfEstimator est(hf, *mat);
    const PatchRegion whole = PatchRegion::whole(hf);
    const Vec3 up = dir_deg(20, 0);
    EXPECT_THROW(est.estimate(PatchRegion{1, 1, 1, 5}, up, up, 100, 1), MesoError);   // empty
    EXPECT_THROW(est.estimate(PatchRegion{3, 0, 2, 5}, up, up, 100, 1), MesoError);   // inverted
    EXPECT_THROW(est.estimate(PatchRegion{0, 0, NAN, 5}, up, up, 100, 1), MesoError);
    EXPECT_THROW(est.estimate(whole, up, up, 0, 1), MesoError);
    EXPECT_THROW(est.estimate(whole, up, up, 100, 1, 0), MesoError);
    EXPECT_THROW(est.estimate(whole, Vec3(0, 0, 0), up, 100, 1), MesoError);
    EXPECT_THROW(est.estimate(whole, up, Vec3(NAN, 0, 1), 100, 1), MesoError);
    try {
        est.estimate(PatchRegion{1, 1, 1, 5}, up, up, 100, 1);
    } catch (const MesoError &e) {
        EXPECT_STREQ(e.what(), "effective BRDF: empty or non-finite patch [1, 1) x [1, 5)");
    }
    // Below or on the horizon: zero, not an error.
    for (auto [wi, wo] : {std::pair{dir_deg(100, 0), up}, std::pair{up, dir_deg(120, 40)},
                          std::pair{dir_deg(90, 0), up}, std::pair{up, dir_deg(90, 0)}}) {
        auto e = est.estimate(whole, wi, wo, 100, 1, 4);
        EXPECT_TRUE(e.value.is_black());
        EXPECT_TRUE(e.brdf.is_black());
        EXPECT_EQ(e.accepted, 0u);
    }
    EXPECT_EQ(est.estimate(whole, up, dir_deg(95, 0), 100, 1).projected_area, 0.0);
    // Non-unit directions are normalised.
    auto a = est.estimate(whole, up * 3.f, dir_deg(40, 10) * 0.5f, 1000, 9);
    auto b = est.estimate(whole, up, dir_deg(40, 10), 1000, 9);
    EXPECT_NEAR(a.value.r, b.value.r, 1e-6);
}

TEST(EffectiveBrdf, GrazingDirectionsStayFinite) {
    const Heightfield rough = generated("gaussian", {{"size", "32"}, {"seed", "2"}, {"sxx", "0.2"}, {"syy", "0.2"},
                                                     {"correlation", "0.1"}});
    const Heightfield groove = generated("vgroove", {{"size", "32"}, {"periods", "2"}, {"angle", "45"}});
    auto mat = make_material(R"({"type":"diffuse","reflectance":0.5})");
    for (const Heightfield *hf : {&rough, &groove}) {
        EffectiveBrdfEstimator est(*hf, *mat);
        for (double th : {85.0, 87.0, 89.0}) {
            for (const PatchRegion &r : {PatchRegion::whole(*hf), PatchRegion{3, 4, 20, 11}}) {
                auto e1 = est.estimate(r, dir_deg(th, 0), dir_deg(th, 170), 4000, 5, 1);
                auto e2 = est.estimate(r, dir_deg(30, 0), dir_deg(th, 45), 4000, 6, 8);
                auto e3 = est.estimate(r, dir_deg(th, 60), dir_deg(20, 0), 4000, 7, 8);
                for (auto *e : {&e1, &e2, &e3}) {
                    EXPECT_TRUE(e->value.is_finite() && e->std_error.is_finite() && e->brdf.is_finite());
                    EXPECT_TRUE(std::isfinite(e->projected_area));
                    EXPECT_GE(e->value.r, 0.f);
                    EXPECT_EQ(e->leaked, 0u);
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------------------
// Determinism and throughput (reported, not asserted beyond sanity).

TEST(EffectiveBrdf, DeterministicAcrossThreadCounts) {
    const Heightfield hf = generated("gaussian", {{"size", "32"}, {"seed", "3"}});
    auto mat = make_material(R"({"type":"diffuse","reflectance":0.7})");
    EffectiveBrdfEstimator est(hf, *mat);
    auto run = [&] { return est.estimate(PatchRegion::whole(hf), dir_deg(40, 0), dir_deg(50, 100), 20000, 77, 8); };
    auto a = run();
    Spectrum b;
    {
        tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
        b = run().value;
    }
    EXPECT_EQ(a.value.r, b.r);
    EXPECT_EQ(a.value.g, b.g);
}

TEST(EffectiveBrdf, ThroughputOnFbm256) {
    const Heightfield fbm = generated("fbm", {{"size", "256"}, {"seed", "4"}});
    const Heightfield rough = generated("gaussian", {{"size", "256"}, {"seed", "4"}, {"sxx", "0.5"}, {"syy", "0.5"}});
    auto mat = make_material(R"({"type":"diffuse","reflectance":0.8})");
    tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
    for (auto [name, hf] : {std::pair{"fbm", &fbm}, std::pair{"gaussian rms slope 1", &rough}})
    for (int bounces : {1, 8}) {
        EffectiveBrdfEstimator est(*hf, *mat);
        const size_t n = 40000;
        auto t0 = std::chrono::steady_clock::now();
        auto e = est.estimate(PatchRegion::whole(*hf), dir_deg(35, 0), dir_deg(55, 160), n, 1, bounces);
        const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        std::printf("[throughput] %s 256^2, %d bounce(s), 1 thread: %.0f paths/s, %.3f vertices/path (value %.4f "
                    "+- %.4f)\n",
                    name, bounces, double(n) / s, e.mean_vertices, e.value.r, e.std_error.r);
        EXPECT_TRUE(e.value.is_finite());
        EXPECT_EQ(e.leaked, 0u);
    }
}
