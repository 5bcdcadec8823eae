// The `prefiltered` material (materials/prefiltered.cpp, paper 004 eq. 13/14/18) and the LoD
// chain's `model` (scene_loader add_lod_levels) on a tiny model built here: a 16x16 fbm map,
// patch NDFs fitted for factors 2 and 4, scaling tables with known values (factor 4 with
// interreflection tables, factor 2 without), saved with PrefilteredModel::save. Checks: the
// model round trip, eval = T·S·f'_low against SvMultiLobe, the tables' lookups and the
// concentric map's inverse, χ² of the sampler (plain and in a macro frame tilted against the
// shading frame), the macro normal of the ShadingContext, bad input, a rendered scene. The
// stochastic estimator's tests are in test_prefiltered_stochastic.cpp (helpers: prefiltered_test_util.h).
#include <gtest/gtest.h>
#include "cli_capture.h"
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>
#include <array>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "geometry/heightfield.h"
#include "geometry/heightmap_gen.h"
#include "geometry/interaction.h"
#include "geometry/lod.h"
#include "geometry/shape.h"
#include "material_test_util.h"
#include "prefilter/model.h"
#include "prefilter/patch_ndf.h"
#include "render_test_util.h"
#include "bsdf/chi2.h"
#include "sampling/rng.h"
#include "sampling/warp.h"
#include "scratch_dir.h"
#include "prefiltered_test_util.h"

using meso::test::dir_deg;
using namespace meso::test::pf;  // also meso, meso::prefilter, make_material, fs

// ------------------------------------------------------------------ (a) the model on disk

TEST(PrefilteredModel, SaveLoadRoundTrip) {
    const TinyModel &t = tiny_model();
    const PrefilteredModel m = PrefilteredModel::load(t.dir);
    EXPECT_EQ(m.map_width, kMapSize);
    EXPECT_EQ(m.map_height, kMapSize);
    EXPECT_EQ(m.lobes, 6);
    EXPECT_EQ(m.base, t.model.base);
    EXPECT_EQ(m.quadrature.polar, 4);
    EXPECT_EQ(m.quadrature.azimuth, 6);
    ASSERT_EQ(m.levels.size(), 2u);
    for (size_t k = 0; k < 2; ++k) {
        const PrefilteredLevel &a = t.model.levels[k], &b = m.levels[k];
        EXPECT_EQ(a.factor, b.factor);
        EXPECT_EQ(a.h_low.width, b.h_low.width);
        EXPECT_EQ(a.h_low.h, b.h_low.h);  // float32 EXR: exact
        ASSERT_EQ(a.ndf.size(), b.ndf.size());
        for (size_t p = 0; p < a.ndf.size(); ++p) {
            ASSERT_EQ(a.ndf[p].lobes.size(), b.ndf[p].lobes.size()) << "patch " << p;
            EXPECT_NEAR(a.ndf[p].amplitude, b.ndf[p].amplitude, 1e-6 * a.ndf[p].amplitude);
            for (size_t j = 0; j < a.ndf[p].lobes.size(); ++j) {
                const VmfLobe &la = a.ndf[p].lobes[j], &lb = b.ndf[p].lobes[j];
                EXPECT_NEAR(la.mu.x, lb.mu.x, 1e-6f);
                EXPECT_NEAR(la.mu.y, lb.mu.y, 1e-6f);
                EXPECT_NEAR(la.mu.z, lb.mu.z, 1e-6f);
                EXPECT_NEAR(la.kappa, lb.kappa, 1e-6 * la.kappa + 1e-30);
                EXPECT_NEAR(la.weight, lb.weight, 1e-6 * la.weight);
            }
        }
        EXPECT_EQ(a.single.T.data, b.single.T.data);
        EXPECT_EQ(a.single.S.data, b.single.S.data);
        EXPECT_EQ(a.ir.empty(), b.ir.empty());
        if (!a.ir.empty()) {
            EXPECT_EQ(a.ir.T.data, b.ir.T.data);
            EXPECT_EQ(a.ir.S.data, b.ir.S.data);
        }
        EXPECT_EQ(b.stats["factor"], a.factor);
    }
}

TEST(PrefilteredModel, QuadratureWeightsAreRecorded) {
    // parameters.quadrature_weights: "share" (`meso prefilter` writes it now: the eq5 / visible
    // nodes weighted by their shares, multilobe_brdf.h); absent (models made before) the absolute
    // weights their tables were fitted to; anything else is refused, naming the key.
    EXPECT_TRUE(PrefilteredModel::load(tiny_model().dir).quadrature.absolute_weights);
    const fs::path root = fs::path(meso::test::scratch_dir("meso_prefiltered_test"));
    for (const char *value : {"share", "absolute", "shares"}) {
        PrefilteredModel m = tiny_model().model;
        m.manifest["parameters"]["quadrature_weights"] = value;
        const std::string d = (root / (std::string("model_weights_") + value)).string();
        m.save(d);
        if (std::string(value) == "shares") {
            try {
                PrefilteredModel::load(d);
                ADD_FAILURE() << "a bad quadrature_weights was accepted";
            } catch (const MesoError &e) {
                EXPECT_NE(std::string(e.what()).find("parameters.quadrature_weights"), std::string::npos) << e.what();
            }
            continue;
        }
        EXPECT_EQ(PrefilteredModel::load(d).quadrature.absolute_weights, std::string(value) == "absolute") << value;
    }
}

TEST(PrefilteredModel, FormChoicesAreRecordedAndBadValuesNamed) {
    // The other form choices a manifest records (model.cpp, fitted_before): each key's value now,
    // its value before (also the default, absent), and a bad value refused naming the key.
    const fs::path root = fs::path(meso::test::scratch_dir("meso_prefiltered_test"));
    const std::vector<std::array<const char *, 3>> choices = {
        {"albedo", "patch_mean", "point"}, {"lambert_view", "visible", "cap_mass"}, {"microfacet_view", "visible", "area"}};
    auto before_flag = [](const PrefilteredModel &m, const std::string &key) {
        if (key == "albedo") return m.quadrature.point_albedo;
        if (key == "lambert_view") return m.quadrature.cap_mass_lambert;
        return m.quadrature.area_microfacet;
    };
    for (const auto &[key, now, before] : choices) {
        for (const char *value : {now, before, "neither"}) {
            PrefilteredModel m = tiny_model().model;
            m.manifest["parameters"][key] = value;
            const std::string d = (root / (std::string("model_") + key + "_" + value)).string();
            m.save(d);
            if (std::string(value) == "neither") {
                try {
                    PrefilteredModel::load(d);
                    ADD_FAILURE() << "a bad " << key << " was accepted";
                } catch (const MesoError &e) {
                    EXPECT_NE(std::string(e.what()).find(std::string("parameters.") + key), std::string::npos) << e.what();
                }
                continue;
            }
            EXPECT_EQ(before_flag(PrefilteredModel::load(d), key), std::string(value) == before) << key << " " << value;
        }
    }
}

// ------------------------------------------------------------------ (b) eval = T·S·f'_low

TEST(PrefilteredMaterial, EvalIsTimesSTimesMultiLobe) {
    const PrefilteredModel m = PrefilteredModel::load(tiny_model().dir);
    const auto ref = reference_svbrdf(m, 4);
    const PrefilteredLevel *L = m.level_for_factor(4);
    auto none = prefiltered(R"(,"level":4,"scaling":"none","tiling":[2,3])");
    auto ir = prefiltered(R"(,"level":4,"tiling":[2,3])");  // default: ir (the level has it)
    auto single = prefiltered(R"(,"level":4,"scaling":"single","tiling":[2,3])");
    auto only_T = prefiltered(R"(,"level":4,"scaling":"T","tiling":[2,3])");
    auto only_S = prefiltered(R"(,"level":4,"scaling":"S","tiling":[2,3])");
    EXPECT_FALSE(ir->is_reciprocal());
    PCG32 rng(11);
    int nonzero = 0;
    for (int i = 0; i < 200; ++i) {
        ShadingContext ctx;
        // uv on a 1/64 grid: uv * tiling and its fraction are exact in float
        ctx.uv = Vec2(float(rng.next_u32() % 64) / 64.f, float(rng.next_u32() % 64) / 64.f);
        ShadingContext rc = ctx;
        rc.uv = Vec2(std::fmod(ctx.uv.x * 2.f, 1.f), std::fmod(ctx.uv.y * 3.f, 1.f));
        const Vec3 wo = dir_deg(85.0 * rng.next_float(), 360.0 * rng.next_float());
        const Vec3 wi = dir_deg(85.0 * rng.next_float(), 360.0 * rng.next_float());
        const Spectrum f = ref->eval(rc, wo, wi);
        const Spectrum T = L->ir.eval_T(rc.uv), S = L->ir.eval_S(wi, wo);
        const Spectrum S1 = L->single.eval_S(wi, wo);
        expect_spectrum_near(none->eval(ctx, wo, wi), f, 1e-6, "none");
        expect_spectrum_near(ir->eval(ctx, wo, wi), f * T * S, 1e-6, "ir");
        expect_spectrum_near(single->eval(ctx, wo, wi), f * S1, 1e-6, "single (T = 1)");
        expect_spectrum_near(only_T->eval(ctx, wo, wi), f * T, 1e-6, "T");
        expect_spectrum_near(only_S->eval(ctx, wo, wi), f * S, 1e-6, "S");
        EXPECT_NEAR(ir->pdf(ctx, wo, wi), ref->pdf(rc, wo, wi), 1e-6 * ref->pdf(rc, wo, wi));
        if (f.max() > 0.f) ++nonzero;
    }
    EXPECT_GT(nonzero, 150);
    // the patch is chosen from frac(uv * tiling): uv and uv + 1/tiling see the same patch
    ShadingContext a, b;
    a.uv = Vec2(0.125f, 0.25f);
    b.uv = Vec2(0.125f + 0.5f, 0.25f + 1.f / 3.f);
    const Vec3 wo = dir_deg(30, 20), wi = dir_deg(50, 200);
    expect_spectrum_near(ir->eval(a, wo, wi), ir->eval(b, wo, wi), 1e-5, "periodic in the tile");
}

// On microgeometry the ShadingContext's macro frame (n_macro, dpdu_macro) is where the model
// is evaluated: rotating wo, wi and the shading frame together changes nothing, and directions
// below either horizon give 0.
TEST(PrefilteredMaterial, EvaluatesInTheMacroFrame) {
    auto ir = prefiltered(R"(,"level":4)");
    PCG32 rng(3);
    int checked = 0, below = 0;
    for (int i = 0; i < 300; ++i) {
        // a micro-facet frame tilted against the macro normal (0, 0, 1)
        const Vec3 nm = normalize(Vec3(0.6f * (rng.next_float() - 0.5f), 0.6f * (rng.next_float() - 0.5f), 1.f));
        ShadingContext micro;
        micro.uv = Vec2(rng.next_float(), rng.next_float());
        micro.frame = Frame::from_normal_tangent(nm, Vec3(1.f, 0.2f, 0.f));
        micro.n_macro = Vec3(0.f, 0.f, 1.f);
        micro.dpdu_macro = Vec3(2.f, 0.f, 0.f);
        ShadingContext macro;  // the plain frame is the macro frame: x along u
        macro.uv = micro.uv;
        const Vec3 wo_m = dir_deg(80.0 * rng.next_float(), 360.0 * rng.next_float());
        const Vec3 wi_m = dir_deg(80.0 * rng.next_float(), 360.0 * rng.next_float());
        const Vec3 wo = micro.frame.to_local(wo_m), wi = micro.frame.to_local(wi_m);
        if (wo.z <= 0.f || wi.z <= 0.f) {
            EXPECT_EQ(ir->eval(micro, wo, wi).max(), 0.f);
            EXPECT_EQ(ir->pdf(micro, wo, wi), 0.f);
            ++below;
            continue;
        }
        expect_spectrum_near(ir->eval(micro, wo, wi), ir->eval(macro, wo_m, wi_m), 2e-4, "rotated");
        EXPECT_NEAR(ir->pdf(micro, wo, wi), ir->pdf(macro, wo_m, wi_m), 2e-4 * ir->pdf(macro, wo_m, wi_m));
        ++checked;
    }
    EXPECT_GT(checked, 150);
    EXPECT_GT(below, 5);
    // above the shading horizon, below the macro one: 0
    ShadingContext micro;
    micro.frame = Frame::from_normal_tangent(normalize(Vec3(0.5f, 0.f, 1.f)), Vec3(1.f, 0.f, 0.f));
    micro.n_macro = Vec3(0.f, 0.f, 1.f);
    micro.dpdu_macro = Vec3(1.f, 0.f, 0.f);
    const Vec3 wi_m = normalize(Vec3(1.f, 0.f, -0.1f)), wo_m = dir_deg(20, 0);
    const Vec3 wi = micro.frame.to_local(wi_m), wo = micro.frame.to_local(wo_m);
    ASSERT_GT(wi.z, 0.f);
    EXPECT_EQ(ir->eval(micro, wo, wi).max(), 0.f);
    EXPECT_EQ(ir->pdf(micro, wo, wi), 0.f);
}

TEST(PrefilteredShadingContext, MacroNormalFollowsTheTwoSidedFlip) {
    SurfaceInteraction si;
    si.ng = si.ns = normalize(Vec3(0.2f, 0.f, 1.f));
    si.dpdu = Vec3(1.f, 0.f, -0.2f);
    si.dpdv = Vec3(0.f, 1.f, 0.f);
    si.wo = Vec3(0.f, 0.f, 1.f);
    ShadingContext plain = si.shading_context(true);
    EXPECT_EQ(plain.n_macro.x, 0.f);
    EXPECT_EQ(plain.n_macro.z, 0.f);  // not on microgeometry: zero
    si.n_footprint = Vec3(0.f, 0.f, 1.f);
    si.dpdu_footprint = Vec3(3.f, 0.f, 0.f);
    ShadingContext front = si.shading_context(true);
    EXPECT_EQ(front.side, 1.f);
    EXPECT_EQ(front.n_macro.z, 1.f);
    EXPECT_EQ(front.dpdu_macro.x, 3.f);
    si.wo = Vec3(0.f, 0.f, -1.f);  // seen from below: the two-sided integrator flips the frame
    ShadingContext back = si.shading_context(true);
    EXPECT_EQ(back.side, -1.f);
    EXPECT_EQ(back.n_macro.z, -1.f);
    EXPECT_EQ(si.shading_context(false).n_macro.z, 1.f);
    si.dpdu_footprint = Vec3();  // no macro tangent: the micro one
    EXPECT_EQ(si.shading_context(true).dpdu_macro.z, -0.2f);
}

// ------------------------------------------------------------------ (c) tables and bins

TEST(PrefilteredTables, SAtBinCentresIsTheBinAndContinuous) {
    const ScalingTables t = make_tables(true);
    auto centre = [&](int b) { return square_to_hemisphere(Vec2((b % kN + 0.5f) / kN, (b / kN + 0.5f) / kN)); };
    for (int bi = 0; bi < kN * kN; ++bi)
        for (int bo = 0; bo < kN * kN; ++bo)
            expect_spectrum_near(t.eval_S(centre(bi), centre(bo)), t.S_bin(bi, bo), 1e-5,
                                 fmt::format("bin ({}, {})", bi, bo));
    // continuity: small steps in both directions change S by O(step) (no jumps at bin edges,
    // at the concentric map's diagonals or around the pole)
    PCG32 rng(17);
    const float h = 1e-3f;
    double worst = 0.0;
    for (int i = 0; i < 20000; ++i) {
        const Vec3 wi = square_to_hemisphere(Vec2(rng.next_float(), rng.next_float()));
        const Vec3 wo = square_to_hemisphere(Vec2(rng.next_float(), rng.next_float()));
        const Vec3 d(rng.next_float() - 0.5f, rng.next_float() - 0.5f, rng.next_float() - 0.5f);
        Vec3 wi2 = normalize(wi + d * h), wo2 = normalize(wo - d * h);
        wi2.z = std::abs(wi2.z), wo2.z = std::abs(wo2.z);
        const double step = std::max(length(wi2 - wi), length(wo2 - wo)) + 1e-9;
        const Spectrum a = t.eval_S(wi, wo), b = t.eval_S(wi2, wo2);
        for (int c = 0; c < 3; ++c) worst = std::max(worst, std::abs(double(a[c]) - b[c]) / step);
    }
    // S varies by at most ~0.4 per unit of the square coordinates, which move by at most ~2
    // per unit of angle
    std::printf("S: max |dS| / |dω| = %.3g\n", worst);
    EXPECT_LT(worst, 3.0);  // a jump of one bin step (>= 0.008) over a step <= 0.9e-3 would give > 8
    // T: bilinear between the M x M centres, periodic: the centres give the values
    for (int y = 0; y < kM; ++y)
        for (int x = 0; x < kM; ++x)
            expect_spectrum_near(t.eval_T(Vec2((x + 0.5f) / kM, (y + 0.5f) / kM)), t.T.rgb(x, y), 1e-6, "T centre");
    expect_spectrum_near(t.eval_T(Vec2(0.f, 0.f)), t.eval_T(Vec2(1.f, 1.f)), 1e-6, "T periodic");
}

TEST(PrefilteredTables, SIsExtrapolatedOverTheOuterHalfBins) {
    // S linear in ωi's square x coordinate: exact everywhere, also between the outer bin centres
    // and the horizon (the square's border), where a clamp held the last centre's value.
    const int N = 7;
    ScalingTables t;
    t.M = 1, t.N = N;
    t.T = Image(1, 1, 3);
    t.T.set_rgb(0, 0, Spectrum(1.f));
    t.S = Image(N * N, N * N, 3);
    const float a = 0.3f, b = 0.1f;  // S = a + b * (ix - 3) over the bins' x index ix
    for (int bi = 0; bi < N * N; ++bi)
        for (int bo = 0; bo < N * N; ++bo) t.set_S_bin(bi, bo, Spectrum(a + b * float(bi % N - 3)));
    const Vec3 wo(0.f, 0.f, 1.f);
    for (float u : {0.f, 0.03f, 0.5f / N, 0.3f, 0.5f, 0.9f, 1.f - 0.5f / N, 0.98f, 1.f}) {
        const Vec3 wi = square_to_hemisphere(Vec2(u, 0.5f));
        const float x = hemisphere_to_square(wi).x * N - 0.5f;  // continuous bin coordinate
        const float expect = std::max(0.f, a + b * (x - 3.f));
        EXPECT_NEAR(t.eval_S(wi, wo).g, expect, 2e-5f) << "u = " << u;
    }
    // at the +x horizon: half a bin beyond the last centre, a + b (6.5 - 3) = 0.65, not the clamp's 0.6
    EXPECT_NEAR(t.eval_S(Vec3(1.f, 0.f, 0.f), wo).g, a + b * 3.5f, 2e-5f);
    // extrapolation below 0 is clamped (the -x horizon: a + b (-0.5 - 3) = -0.05)
    EXPECT_EQ(t.eval_S(Vec3(-1.f, 0.f, 0.f), wo).g, 0.f);
    EXPECT_NEAR(t.eval_S(square_to_hemisphere(Vec2(0.5f / N, 0.5f)), wo).g, 0.f, 2e-5f);
}

TEST(PrefilteredTables, ConcentricInverse) {
    PCG32 rng(5);
    std::vector<Vec2> pts;
    for (int i = 0; i < 20000; ++i) pts.push_back(Vec2(rng.next_float(), rng.next_float()));
    for (int i = 0; i <= 200; ++i) {
        const float s = float(i) / 200.f;
        pts.push_back(Vec2(s, s));        // diagonals
        pts.push_back(Vec2(s, 1.f - s));
        pts.push_back(Vec2(s, 0.5f));     // axes
        pts.push_back(Vec2(0.5f, s));
        pts.push_back(Vec2(s, 0.f));      // the border
        pts.push_back(Vec2(1.f, s));
    }
    double worst = 0.0;
    for (Vec2 u : pts) {
        const Vec2 back = concentric_disk_to_square(square_to_uniform_disk_concentric(u));
        worst = std::max({worst, double(std::abs(back.x - u.x)), double(std::abs(back.y - u.y))});
        EXPECT_NEAR(back.x, u.x, 1e-5) << u.x << ", " << u.y;
        EXPECT_NEAR(back.y, u.y, 1e-5) << u.x << ", " << u.y;
        // and through the hemisphere
        const Vec2 h = hemisphere_to_square(square_to_hemisphere(u));
        EXPECT_NEAR(h.x, u.x, 1e-5);
        EXPECT_NEAR(h.y, u.y, 1e-5);
    }
    std::printf("concentric inverse: max error %.3g over %zu points\n", worst, pts.size());
}

// square_to_hemisphere (polynomial sine and cosine, no libm) against the map in double: unit,
// within 1e-6 rad of it, and strictly above the horizon on the whole square, its border included.
TEST(PrefilteredMaterial, SquareToHemisphereIsTheDoubleMap) {
    PCG32 rng(5, 6);
    double worst = 0.0;
    for (int i = 0; i < 200000; ++i) {
        Vec2 u(rng.next_float(), rng.next_float());
        if (i < 4000) u = Vec2(float(i % 2000) / 2000.f, i < 2000 ? 0.9999999f : 1e-7f);  // the outer ring
        const Vec2 d = square_to_uniform_disk_concentric(u);
        const double rho = std::max(std::abs(2.0 * u.x - 1.0), std::abs(2.0 * u.y - 1.0));
        const double len = std::sqrt(double(d.x) * d.x + double(d.y) * d.y);
        const Vec3 w = square_to_hemisphere(u);
        ASSERT_GT(w.z, 0.f) << u.x << ", " << u.y;
        EXPECT_NEAR(length(w), 1.f, 3e-7f);
        if (!(len > 0)) continue;
        const double th = rho * meso::Pi / 2, st = std::sin(th);
        const double ex = st * d.x / len, ey = st * d.y / len, ez = std::cos(th);
        const double dot = (ex * w.x + ey * w.y + ez * w.z) / std::sqrt(double(length_squared(w)));
        const double cross = std::sqrt(std::max(0.0, (ex - w.x) * (ex - w.x) + (ey - w.y) * (ey - w.y) + (ez - w.z) * (ez - w.z)));
        worst = std::max(worst, cross);
        ASSERT_LT(cross, 1e-6) << u.x << ", " << u.y << " (dot " << dot << ")";
        EXPECT_NEAR(w.z, ez, 3e-7 + 3e-6 * ez) << u.x << ", " << u.y;  // relative at grazing angles
    }
    std::printf("square_to_hemisphere: max distance %.3g from the double map\n", worst);
}

TEST(PrefilteredMaterial, SquareToHemisphereGridIsTheScalarMap) {
    // The four-lane grid (the prefilter's ωi bins of a line) against the scalar map, bit for bit:
    // odd and even N, shifts at the cell corners and centres (N odd with shift 0.5: the centre,
    // straight up), random shifts.
    PCG32 rng(7, 8);
    for (int N : {1, 2, 3, 4, 5, 15, 16, 64}) {
        std::vector<Vec3> g(size_t(N) * N);
        for (int t = 0; t < 40; ++t) {
            float sa = rng.next_float(), sb = rng.next_float();
            if (t == 0) sa = sb = 0.f;
            if (t == 1) sa = sb = 0.5f;
            if (t == 2) sa = 0.99999994f, sb = 0.f;
            square_to_hemisphere_grid(N, sa, sb, g.data());
            for (int b = 0; b < N * N; ++b) {
                const Vec3 w = square_to_hemisphere(Vec2((float(b % N) + sa) / float(N), (float(b / N) + sb) / float(N)));
                ASSERT_EQ(std::memcmp(&w, &g[size_t(b)], sizeof(Vec3)), 0)
                    << "N " << N << " bin " << b << " shift " << sa << ", " << sb << ": " << g[size_t(b)].x << " "
                    << g[size_t(b)].y << " " << g[size_t(b)].z << " against " << w.x << " " << w.y << " " << w.z;
            }
        }
    }
}

// ------------------------------------------------------------------ (d) sampling

TEST(PrefilteredMaterial, Chi2AndWeights) {
    struct Setup {
        const char *json;
        Vec2 uv;
        bool tilted;
        double theta;
    };
    const std::vector<Setup> setups = {
        {R"(,"level":4)", {0.1f, 0.3f}, false, 0.0},   {R"(,"level":4)", {0.6f, 0.8f}, false, 45.0},
        {R"(,"level":4)", {0.35f, 0.55f}, false, 80.0}, {R"(,"level":2)", {0.9f, 0.2f}, false, 30.0},
        {R"(,"level":4)", {0.1f, 0.3f}, true, 30.0},    {R"(,"level":2)", {0.4f, 0.7f}, true, 70.0},
    };
    int idx = 0;
    for (const Setup &s : setups) {
        auto mat = prefiltered(s.json);
        ShadingContext ctx;
        ctx.uv = s.uv;
        if (s.tilted) {  // shading frame of a micro-facet, macro normal (0, 0, 1)
            ctx.frame = Frame::from_normal_tangent(normalize(Vec3(0.3f, -0.2f, 1.f)), Vec3(1.f, 0.f, 0.f));
            ctx.n_macro = Vec3(0.f, 0.f, 1.f);
            ctx.dpdu_macro = Vec3(1.f, 0.f, 0.f);
        }
        const Vec3 wo = dir_deg(s.theta, 20.0);
        Chi2Options opt;
        opt.samples = 100000;
        opt.seed = 100 + idx;
        opt.test_count = int(setups.size());
        opt.name = fmt::format("prefiltered_{}", idx);
        const Chi2Result r = chi2_material_test(*mat, ctx, wo, opt);
        EXPECT_TRUE(r.passed) << idx << ": " << r.message;
        EXPECT_EQ(r.invalid, 0u) << idx;
        EXPECT_EQ(r.weight_mismatch, 0u) << idx << " max rel. error " << r.max_weight_rel_error;
        EXPECT_EQ(r.pdf_mismatch, 0u) << idx << " max rel. error " << r.max_pdf_rel_error;
        const double n = double(r.samples), frac = double(r.smooth) / n;
        EXPECT_LE(r.pdf_integral, 1.0 + 1e-4) << idx;
        EXPECT_NEAR(r.pdf_integral, frac, 5.0 * std::sqrt(frac * (1 - frac) / n + 1.0 / (n * n)) + 3e-3) << idx;
        EXPECT_GT(frac, 0.5) << idx;
        ++idx;
    }
}

TEST(PrefilteredMaterial, WeightIsEvalOverPdfAndExtremesAreFinite) {
    auto mat = prefiltered(R"(,"level":4,"scaling":"ir","tiling":7)");
    PCG32 rng(8);
    int ok = 0;
    for (double theta : {0.0, 30.0, 60.0, 85.0, 89.0, 89.99, 90.0, 95.0, 180.0}) {
        for (int i = 0; i < 500; ++i) {
            ShadingContext ctx;
            ctx.uv = Vec2(rng.next_float() * 3.f - 1.f, rng.next_float() * 100.f);
            if (i % 2) {
                ctx.frame = Frame::from_normal_tangent(normalize(Vec3(rng.next_float() - 0.5f, rng.next_float() - 0.5f, 1.f)),
                                                       Vec3(1.f, 0.f, 0.f));
                ctx.n_macro = Vec3(0.f, 0.f, 1.f);
                ctx.dpdu_macro = Vec3(0.f, 0.f, 0.f);  // degenerate tangent: still a frame
            }
            const Vec3 wo = dir_deg(theta, 360.0 * rng.next_float());
            BSDFSample bs;
            const bool s = mat->sample(ctx, wo, rng.next_float(), Vec2(rng.next_float(), rng.next_float()), bs);
            if (!(wo.z > 0.f)) {
                EXPECT_FALSE(s);
                EXPECT_EQ(mat->eval(ctx, wo, dir_deg(10, 0)).max(), 0.f);
                continue;
            }
            if (!s) continue;
            ++ok;
            EXPECT_GT(bs.wi.z, 0.f);
            EXPECT_TRUE(std::isfinite(bs.pdf) && bs.pdf > 0.f);
            const Spectrum e = mat->eval(ctx, wo, bs.wi);
            const float p = mat->pdf(ctx, wo, bs.wi);
            EXPECT_EQ(p, bs.pdf);
            for (int c = 0; c < 3; ++c) {
                EXPECT_TRUE(std::isfinite(bs.weight[c]) && bs.weight[c] >= 0.f);
                EXPECT_NEAR(bs.weight[c], e[c] / p, 1e-6f * e[c] / p);
            }
        }
    }
    EXPECT_GT(ok, 1500);
    EXPECT_NE(mat->to_string().find("level x4"), std::string::npos) << mat->to_string();
}

// ------------------------------------------------------------------ (e) bad input

TEST(PrefilteredMaterial, BadInputNamesTheKey) {
    const std::string dir = tiny_model().dir;
    auto err = [&](const std::string &json) { return error_of([&] { make_material(json); }); };
    std::string e = err(R"({"type":"prefiltered","model":"/nonexistent/model_dir","level":4})");
    EXPECT_NE(e.find("material.model: model directory not found: '/nonexistent/model_dir'"), std::string::npos) << e;
    e = err(fmt::format(R"({{"type":"prefiltered","model":"{}","level":8}})", dir));
    EXPECT_NE(e.find("material.level: the model"), std::string::npos) << e;
    EXPECT_NE(e.find("no level with factor 8 (it has 2, 4)"), std::string::npos) << e;
    e = err(fmt::format(R"({{"type":"prefiltered","model":"{}","level":4,"scaling":"both"}})", dir));
    EXPECT_NE(e.find("material.scaling: expected \"ir\", \"single\", \"none\", \"T\" or \"S\", got \"both\""),
              std::string::npos)
        << e;
    e = err(fmt::format(R"({{"type":"prefiltered","model":"{}","level":2,"scaling":"ir"}})", dir));
    EXPECT_NE(e.find("material.scaling: level x2"), std::string::npos) << e;
    EXPECT_NE(e.find("no interreflection tables"), std::string::npos) << e;
    e = err(fmt::format(R"({{"type":"prefiltered","model":"{}"}})", dir));
    EXPECT_NE(e.find("level"), std::string::npos) << e;
    e = err(fmt::format(R"({{"type":"prefiltered","model":"{}","level":4,"tiling":[1,2,3]}})", dir));
    EXPECT_NE(e.find("material.tiling: expected"), std::string::npos) << e;
    e = err(fmt::format(R"({{"type":"prefiltered","model":"{}","level":4,"base":{{"type":"conductor"}}}})", dir));
    EXPECT_NE(e.find("material.base:"), std::string::npos) << e;  // a delta base: MultiLobeBrdf refuses it
    e = err(fmt::format(R"({{"type":"prefiltered","model":"{}","level":4,"colour":1}})", dir));
    EXPECT_NE(e.find("unknown parameter 'colour'"), std::string::npos) << e;
    // a directory that is not a model
    const std::string empty = (fs::path(meso::test::scratch_dir("meso_prefiltered_test")) / "empty").string();
    fs::create_directories(empty);
    e = err(fmt::format(R"({{"type":"prefiltered","model":"{}","level":4}})", empty));
    EXPECT_NE(e.find("material.model: "), std::string::npos) << e;
    EXPECT_NE(e.find("manifest.json"), std::string::npos) << e;
}

TEST(PrefilteredMaterial, BaseOverrideAndSharedLoads) {
    auto white = prefiltered(R"(,"level":4,"scaling":"none","base":{"type":"diffuse","reflectance":1})");
    auto own = prefiltered(R"(,"level":4,"scaling":"none")");
    ShadingContext ctx;
    ctx.uv = Vec2(0.3f, 0.6f);
    const Vec3 wo = dir_deg(30, 10), wi = dir_deg(40, 190);
    const Spectrum a = white->eval(ctx, wo, wi), b = own->eval(ctx, wo, wi);
    // diffuse: linear in the reflectance
    EXPECT_NEAR(b.r, 0.8f * a.r, 1e-5f * a.r);
    EXPECT_NEAR(b.g, 0.6f * a.g, 1e-5f * a.g);
    EXPECT_NEAR(b.b, 0.4f * a.b, 1e-5f * a.b);
}

// ------------------------------------------------------------------ (f) a LoD chain with a model


TEST(PrefilteredLod, ChainWithAModelRenders) {
    const std::string dir = tiny_model().dir;  // scratch/model: "model" relative to the scene file
    auto scene = load_scene(write_scene("lod_model.json", lod_scene(R"({"factors": [1, 4], "model": "model"})")), {});
    ASSERT_EQ(scene->shapes.size(), 2u);
    const Shape &level = *scene->shapes[1];
    EXPECT_EQ(level.lod_level, 1);
    EXPECT_NE(level.material->to_string().find("prefiltered["), std::string::npos) << level.material->to_string();
    EXPECT_NE(level.material->to_string().find("scaling ir"), std::string::npos) << level.material->to_string();
    EXPECT_NE(level.material->to_string().find("tiling 16x16"), std::string::npos) << level.material->to_string();
    scene->build();
    RenderResult r = meso::test::render_scene(*scene, 16);
    EXPECT_EQ(r.nan_count, 0);
    const auto st = meso::test::pixel_stats(r.image, 1);
    EXPECT_TRUE(std::isfinite(st.mean) && std::isfinite(st.max));
    EXPECT_GE(st.min, 0.0);
    const double c = centre_mean(r.image);
    std::printf("centre mean: %.4f (image mean %.4f)\n", c, st.mean);
    EXPECT_GT(c, 0.05);

    // The level really is seen: its material made black darkens the plane.
    auto black = load_scene(write_scene("lod_model_black.json",
                                        lod_scene(R"({"factors": [1, 4], "model": "model", "materials": [
                                            {"type": "diffuse", "reflectance": 0.8}, {"type": "diffuse", "reflectance": 0}]})")),
                            {});
    black->build();
    RenderResult rb = meso::test::render_scene(*black, 16);
    EXPECT_LT(centre_mean(rb.image), 0.2 * c);

    // scaling "none" (the ablation) also renders, differently
    auto none = load_scene(write_scene("lod_model_none.json",
                                       lod_scene(R"({"factors": [1, 4], "model": "model", "scaling": "none"})")),
                           {});
    none->build();
    RenderResult rn = meso::test::render_scene(*none, 16);
    EXPECT_EQ(rn.nan_count, 0);
    EXPECT_NE(centre_mean(rn.image), c);
    EXPECT_GT(centre_mean(rn.image), 0.05);
}

TEST(PrefilteredLod, BadChainsNameTheKey) {
    tiny_model();
    auto err = [&](const std::string &name, const std::string &lod) {
        return error_of([&] { load_scene(write_scene(name, lod_scene(lod)), {}); });
    };
    std::string e = err("bad1.json", R"({"factors": [1, 8], "model": "model"})");
    EXPECT_NE(e.find("shapes[0].lod.factors: level 1: factor 8 is not a level of the model"), std::string::npos) << e;
    e = err("bad2.json", R"({"factors": [1, 4], "model": "no_such_model"})");
    EXPECT_NE(e.find("shapes[0].lod.model: model directory not found"), std::string::npos) << e;
    e = err("bad3.json", R"({"factors": [1, 4], "model": "model", "scaling": "twice"})");
    EXPECT_NE(e.find("shapes[0].lod.scaling: expected"), std::string::npos) << e;
    e = err("bad4.json", R"({"factors": [1, 4], "scaling": "ir"})");
    EXPECT_NE(e.find("shapes[0].lod.scaling: only applies with a prefiltered \"model\""), std::string::npos) << e;
    e = err("bad5.json", R"({"factors": [1, 4], "model": "model", "same_model": true})");
    EXPECT_NE(e.find("shapes[0].lod.same_model: cannot be combined"), std::string::npos) << e;
    // the model's map must be the displacement's
    std::string text = lod_scene(R"({"factors": [1, 4], "model": "model"})");
    text.replace(text.find("\"size\": 16"), 10, "\"size\": 32");
    e = error_of([&] { load_scene(write_scene("bad6.json", text), {}); });
    EXPECT_NE(e.find("shapes[0].lod.model: the model"), std::string::npos) << e;
    EXPECT_NE(e.find("16x16 map"), std::string::npos) << e;
}

TEST(PrefilteredMaterial, LeftHandedUvMirrorsTheMapsY) {
    // A `rectangle`'s v runs down (dp/du x dp/dv = -n): the map's y axis, along which the
    // displacement and hence the patch NDFs are laid out, is then -t of the right-handed frame.
    // The material must read directions in the frame (dp/du, dp/dv, n) whatever its handedness.
    auto ir = prefiltered(R"(,"level":4)");
    PCG32 rng(5);
    for (int i = 0; i < 100; ++i) {
        ShadingContext left;  // shading frame = macro geometry, uv left-handed
        left.uv = Vec2(rng.next_float(), rng.next_float());
        left.n_macro = Vec3(0.f, 0.f, 1.f);
        left.dpdu_macro = Vec3(2.f, 0.f, 0.f);
        left.dpdv_macro = Vec3(0.f, -2.f, 0.f);
        ShadingContext plain;
        plain.uv = left.uv;
        const Vec3 wo = dir_deg(80.0 * rng.next_float(), 360.0 * rng.next_float());
        const Vec3 wi = dir_deg(80.0 * rng.next_float(), 360.0 * rng.next_float());
        const Vec3 wo_map(wo.x, -wo.y, wo.z), wi_map(wi.x, -wi.y, wi.z);
        expect_spectrum_near(ir->eval(left, wo, wi), ir->eval(plain, wo_map, wi_map), 1e-4, "left-handed");
        // ... and the same from a plain surface that carries the left-handed dp/dv itself
        ShadingContext plain_left = plain;
        plain_left.dpdu = Vec3(2.f, 0.f, 0.f);
        plain_left.dpdv = Vec3(0.f, -2.f, 0.f);
        expect_spectrum_near(ir->eval(plain_left, wo, wi), ir->eval(plain, wo_map, wi_map), 1e-4, "plain left-handed");
    }
}

TEST(PrefilteredLod, MseRuleReadsTheModelsLevelErrors) {
    // lod "rule": "mse" (geometry/lod.h) needs a model whose levels carry "lod_error"; a level that
    // removes no variance is never chosen, so the image is the original's (the footprint rule
    // with a tiny bias), pixel for pixel.
    const std::string dir = tiny_model().dir;
    std::string e = error_of([&] {
        load_scene(write_scene("mse_old.json", lod_scene(R"({"factors": [1, 4], "model": "model", "rule": "mse"})")), {});
    });
    EXPECT_NE(e.find("shapes[0].lod.rule: \"mse\": level x4 of the model"), std::string::npos) << e;
    e = error_of([&] { load_scene(write_scene("mse_none.json", lod_scene(R"({"factors": [1, 4], "rule": "mse"})")), {}); });
    EXPECT_NE(e.find("shapes[0].lod.rule: \"mse\" needs a prefiltered \"model\""), std::string::npos) << e;
    const fs::path mse_dir = fs::path(dir).parent_path() / "model_mse";
    fs::remove_all(mse_dir);
    fs::copy(dir, mse_dir, fs::copy_options::recursive);
    nlohmann::json man;
    std::ifstream(mse_dir / "manifest.json") >> man;
    for (auto &L : man["levels"]) L["lod_error"] = {{"window_error", {0.0}}, {"removed_variance", -1.0}};
    std::ofstream(mse_dir / "manifest.json") << man.dump();
    auto render_with = [&](const std::string &name, const std::string &lod) {
        auto scene = load_scene(write_scene(name, lod_scene(lod)), {});
        scene->build();
        return meso::test::render_scene(*scene, 4);
    };
    const RenderResult mse = render_with("mse.json", R"({"factors": [1, 4], "model": "model_mse", "rule": "mse"})");
    const RenderResult orig = render_with("mse_orig.json", R"({"factors": [1, 4], "model": "model", "bias": 1e-6})");
    ASSERT_EQ(mse.image.width, orig.image.width);
    for (int y = 0; y < 32; ++y)
        for (int x = 0; x < 32; ++x) ASSERT_EQ(mse.image.at(x, y, 1), orig.image.at(x, y, 1)) << x << "," << y;
}

// The metric check (geometry/lod.h): the model's cells are square, kLodTile / kMapSize wide. On
// a plane tiled 16 x 8 a tile is 0.125 x 0.25 (the load-time check accepts a tile size between
// the two), so D = 2 at every hit and every path sees the original: the LoD render equals the
// render without a LoD block sample for sample. With square tiles (D = 1) level 1 is seen.
TEST(PrefilteredLod, StretchedCellsSeeTheOriginal) {
    tiny_model();
    auto render = [](const std::string &name, const std::string &lod, const char *tiling) {
        std::string text = lod_scene(lod);
        if (lod == "null") {  // no LoD block: erase it with the comma before it
            const size_t at = text.find("\"lod\": null"), comma = text.rfind(',', at);
            text.erase(comma, at + 11 - comma);
        }
        text.replace(text.find("\"tiling\": 16"), 12, tiling);
        auto scene = load_scene(write_scene(name, text), {});
        if (lod != "null") {
            EXPECT_NEAR(scene->shapes[0]->lod->model_texel, kLodTile / kMapSize, 1e-12);
        }
        scene->build();
        return meso::test::render_scene(*scene, 16).image;
    };
    const std::string chain = R"({"factors": [1, 4], "model": "model"})";
    const Image stretched = render("metric_lod.json", chain, "\"tiling\": [16, 8]");
    const Image original = render("metric_orig.json", "null", "\"tiling\": [16, 8]");
    double worst = 0;
    for (int y = 0; y < 32; ++y)
        for (int x = 0; x < 32; ++x)
            for (int c = 0; c < 3; ++c) worst = std::max(worst, double(std::abs(stretched.at(x, y, c) - original.at(x, y, c))));
    EXPECT_LE(worst, 1e-6);
    // Square tiles: the prefiltered level is seen, so the image is not the original's.
    const Image square = render("metric_lod_sq.json", chain, "\"tiling\": 16");
    const Image square_orig = render("metric_orig_sq.json", "null", "\"tiling\": 16");
    EXPECT_GT(std::abs(centre_mean(square) - centre_mean(square_orig)), 1e-4);
}
