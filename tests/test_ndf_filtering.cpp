// NDF filtering materials (paper 003: LEAN, CLEAN, Toksvig; and plain normal mapping):
// relations between the models, the statistics they read from height maps, stiff inputs,
// and the perturbed normal of `normalmap` against the analytic normal of a displaced plane.
// (Sampling, energy, reciprocity and Jacobians are in the shared battery, test_materials.cpp.)
#include <gtest/gtest.h>
#include <cmath>
#include <nlohmann/json.hpp>
#include <string>
#include "geometry/heightfield.h"
#include "geometry/heightmap.h"
#include "geometry/heightmap_gen.h"
#include "image/image.h"
#include "bsdf/gaussian_microfacet.h"
#include "bsdf/material.h"
#include "sampling/rng.h"
#include "core/properties.h"
#include "core/registry.h"
#include "material_test_util.h"
#include "scratch_dir.h"
#include "texture/normal_source.h"
#include "texture/slope_source.h"

using namespace meso;

namespace {

constexpr double kPi = 3.14159265358979323846;

std::shared_ptr<Material> make(const std::string &json_text) { return test::make_material(json_text); }
using test::dir_deg;

Vec3 upper_dir(PCG32 &rng) {
    const float z = rng.next_float(), r = std::sqrt(std::max(0.f, 1.f - z * z)), ph = 2.f * float(kPi) * rng.next_float();
    return Vec3(r * std::cos(ph), r * std::sin(ph), z);
}

/// Albedo by sampling (weights), with its standard error.
double albedo(const Material &m, const ShadingContext &ctx, Vec3 wo, int n, double *se = nullptr) {
    PCG32 rng(7);
    double s = 0, s2 = 0;
    for (int i = 0; i < n; ++i) {
        BSDFSample bs;
        if (!m.sample(ctx, wo, rng.next_float(), {rng.next_float(), rng.next_float()}, bs)) continue;
        const double w = bs.weight.g;
        s += w, s2 += w * w;
    }
    const double mean = s / n;
    if (se) *se = std::sqrt(std::max(0.0, s2 / n - mean * mean) / (n - 1));
    return mean;
}

/// eval, pdf and samples finite and non-negative over a sweep including grazing and
/// below-horizon directions.
void expect_sane(const Material &m, const std::string &what, const ShadingContext &ctx = ShadingContext{}) {
    const Vec3 dirs[] = {dir_deg(0, 0),  dir_deg(30, 20), dir_deg(60, 200), dir_deg(89, 45), dir_deg(89.9, 10),
                         dir_deg(90, 0), dir_deg(90, 77), dir_deg(91, 33),  dir_deg(180, 0)};
    const Vec2 us[] = {{0.f, 0.f}, {0.5f, 0.5f}, {0.99999994f, 0.99999994f}, {1e-7f, 0.5f}, {0.25f, 0.75f}};
    for (const Vec3 &wo : dirs) {
        for (const Vec3 &wi : dirs) {
            const Spectrum v = m.eval(ctx, wo, wi);
            const float p = m.pdf(ctx, wo, wi);
            ASSERT_TRUE(v.is_finite() && v.r >= 0.f && v.g >= 0.f && v.b >= 0.f) << what << " eval " << wo.z << " " << wi.z;
            ASSERT_TRUE(std::isfinite(p) && p >= 0.f) << what << " pdf";
            if (!(wo.z > 0.f) || !(wi.z > 0.f)) {
                EXPECT_TRUE(v.is_black()) << what;
                EXPECT_EQ(p, 0.f) << what;
            }
        }
        for (const Vec2 &u : us) {
            BSDFSample bs;
            if (!m.sample(ctx, wo, 0.5f, u, bs)) continue;
            ASSERT_TRUE(bs.weight.is_finite() && bs.weight.g >= 0.f && std::isfinite(bs.pdf) && bs.pdf > 0.f) << what;
            ASSERT_TRUE(bs.wi.z > 0.f && std::abs(length(bs.wi) - 1.f) < 1e-3f) << what;
        }
    }
}

/// A heightfield file in the scratch directory (EXR), for scene-level "heightmap" blocks.
std::string write_map(const std::string &name, const HeightMap &map) {
    const std::string path = test::scratch_dir("meso_ndf") + "/" + name + ".exr";
    write_height_map(path, map);
    return path;
}

/// Periodic sum of sinusoids (integer frequencies), amplitude in map units.
HeightMap sinusoid_map(int w, int h, double amp) {
    HeightMap m(w, h);
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < w; ++i)
            m.at(i, j) = float(amp * (std::sin(2 * kPi * (2.0 * i / w)) + 0.6 * std::cos(2 * kPi * (3.0 * j / h + 1.0 * i / w)) +
                                      0.3 * std::sin(2 * kPi * (5.0 * i / w - 4.0 * j / h) + 0.4)));
    return m;
}

HeightMap noise_map(int w, int h, uint64_t seed, double amp) {
    HeightMap m(w, h);
    PCG32 rng(seed);
    for (float &v : m.h) v = float(amp * (2.0 * rng.next_float() - 1.0));
    return m;
}

/// A shading context on a flat patch with the given parameterisation and a footprint of
/// `footprint` in u and v (0: a point).
ShadingContext patch_ctx(Vec3 dpdu, Vec3 dpdv, Vec2 uv, float footprint, float side = 1.f) {
    ShadingContext c;
    Vec3 n = normalize(cross(dpdu, dpdv));
    if (side < 0.f) n = -n;
    c.frame = Frame::from_normal_tangent(n, dpdu);
    c.ng = n;
    c.dpdu = dpdu, c.dpdv = dpdv;
    c.uv = uv;
    c.side = side;
    c.dudx = footprint, c.dvdy = footprint;
    return c;
}

}  // namespace

// ------------------------------------------------------------------ (a) CLEAN vs LEAN

TEST(NdfFiltering, CleanEqualsLeanForIsotropicCovariance) {
    auto lean = make(R"({"type":"lean","mean_slope":[0.2,-0.1],"covariance":[0.05,0.05,0],"exponent":100})");
    auto clean = make(R"({"type":"clean","mean_slope":[0.2,-0.1],"covariance":[0.05,0.05,0],"exponent":100})");
    // CLEAN of an anisotropic covariance = LEAN of the isotropic one with half its trace.
    auto clean_aniso = make(R"({"type":"clean","mean_slope":[0.2,-0.1],"covariance":[0.09,0.01,0.02],"exponent":100})");
    auto lean_aniso = make(R"({"type":"lean","mean_slope":[0.2,-0.1],"covariance":[0.09,0.01,0.02],"exponent":100})");
    PCG32 rng(1);
    int differs = 0, n = 0;
    const ShadingContext ctx;
    for (int i = 0; i < 2000; ++i) {
        const Vec3 wo = upper_dir(rng), wi = upper_dir(rng);
        const float a = lean->eval(ctx, wo, wi).g, b = clean->eval(ctx, wo, wi).g;
        EXPECT_EQ(a, b);
        EXPECT_EQ(lean->pdf(ctx, wo, wi), clean->pdf(ctx, wo, wi));
        EXPECT_NEAR(clean_aniso->eval(ctx, wo, wi).g, a, 1e-5f * a + 1e-12f);
        const float c = lean_aniso->eval(ctx, wo, wi).g;
        if (a > 1e-3f || c > 1e-3f) {
            ++n;
            if (std::abs(a - c) > 0.05f * std::max(a, c)) ++differs;
        }
    }
    EXPECT_GT(n, 100);
    EXPECT_GT(differs, n / 4) << "an anisotropic LEAN lobe must differ from its CLEAN version";
}

TEST(NdfFiltering, CleanIsHalfTheTraceOfLeanFromAHeightMap) {
    const std::string file = write_map("aniso", noise_map(32, 32, 5, 0.02));
    const std::string keys = R"("heightmap":{"map":")" + file + R"("},"filter":"none","exponent":400})";
    auto lean = make(R"({"type":"lean",)" + keys);
    auto clean = make(R"({"type":"clean",)" + keys);
    const auto *l = dynamic_cast<const GaussianMicrofacetMaterial *>(lean.get());
    const auto *c = dynamic_cast<const GaussianMicrofacetMaterial *>(clean.get());
    ASSERT_TRUE(l && c);
    const ShadingContext ctx = patch_ctx(Vec3(1, 0, 0), Vec3(0, 1, 0), Vec2(0.37f, 0.61f), 0.f);
    const SlopeGaussian gl = l->distribution(ctx), gc = c->distribution(ctx);
    EXPECT_GT(std::abs(gl.sxx - gl.syy) + std::abs(gl.sxy), 1e-3) << "the test map should be anisotropic here";
    EXPECT_DOUBLE_EQ(gc.mx, gl.mx);
    EXPECT_DOUBLE_EQ(gc.my, gl.my);
    EXPECT_NEAR(gc.sxx, 0.5 * (gl.sxx + gl.syy), 1e-12);
    EXPECT_NEAR(gc.syy, 0.5 * (gl.sxx + gl.syy), 1e-12);
    EXPECT_EQ(gc.sxy, 0.0);
}

// ------------------------------------------------------------------ (b) Toksvig

TEST(NdfFiltering, ToksvigWithUnitAverageNormalIsBlinnPhong) {
    for (const char *extra : {"", R"(,"eta":1.5)", R"(,"specular_reflectance":[0.9,0.5,0.2])"}) {
        auto t = make(std::string(R"({"type":"toksvig","exponent":100)") + extra + "}");
        auto t1 = make(std::string(R"({"type":"toksvig","exponent":100,"average_normal":[0,0,1])") + extra + "}");
        auto b = make(std::string(R"({"type":"blinnphong","exponent":100)") + extra + "}");
        EXPECT_TRUE(t->is_reciprocal());
        PCG32 rng(2);
        const ShadingContext ctx;
        for (int i = 0; i < 500; ++i) {
            const Vec3 wo = upper_dir(rng), wi = upper_dir(rng);
            const Spectrum a = t->eval(ctx, wo, wi), e = b->eval(ctx, wo, wi);
            EXPECT_EQ(a.r, e.r);
            EXPECT_EQ(a.b, e.b);
            EXPECT_EQ(t1->eval(ctx, wo, wi).g, e.g);
            EXPECT_EQ(t->pdf(ctx, wo, wi), b->pdf(ctx, wo, wi));
            BSDFSample sa, sb;
            const Vec2 u(rng.next_float(), rng.next_float());
            const bool oka = t->sample(ctx, wo, 0.5f, u, sa), okb = b->sample(ctx, wo, 0.f, u, sb);
            ASSERT_EQ(oka, okb);
            if (oka) {
                // (the same sample up to the round-off of mapping wi back from the perturbed frame)
                EXPECT_NEAR(sa.wi.x, sb.wi.x, 1e-6f);
                EXPECT_NEAR(sa.weight.g, sb.weight.g, 1e-3f * sb.weight.g);
                EXPECT_NEAR(sa.pdf, sb.pdf, 1e-3f * sb.pdf);
            }
        }
    }
}

TEST(NdfFiltering, ToksvigPowerFromTheAverageNormalLength) {
    // |N_a| = 0.8: sigma^2 = 0.25, s_hat = 200 / (1 + 0.25 * 200) = 200 / 51 (paper 003).
    const double s_hat = 200.0 / 51.0;
    auto t = make(R"({"type":"toksvig","exponent":200,"average_normal":[0,0,0.8]})");
    auto b = make(R"({"type":"blinnphong","exponent":)" + std::to_string(s_hat) + "}");
    // Tilted: the same lobe around N_a / |N_a| = normal mapping of that Blinn-Phong lobe.
    auto tt = make(R"({"type":"toksvig","exponent":200,"average_normal":[0.48,0,0.64]})");
    auto nb = make(R"({"type":"normalmap","normal":[0.6,0,0.8],"bsdf":{"type":"blinnphong","exponent":)" +
                   std::to_string(s_hat) + "}}");
    EXPECT_FALSE(tt->is_reciprocal());
    PCG32 rng(3);
    const ShadingContext ctx;
    int compared = 0;
    for (int i = 0; i < 1000; ++i) {
        const Vec3 wo = upper_dir(rng), wi = upper_dir(rng);
        const double a = t->eval(ctx, wo, wi).g, e = b->eval(ctx, wo, wi).g;
        EXPECT_NEAR(a, e, 1e-5 * e + 1e-9);
        EXPECT_NEAR(t->pdf(ctx, wo, wi), b->pdf(ctx, wo, wi), 1e-5 * b->pdf(ctx, wo, wi) + 1e-9);
        const double c = tt->eval(ctx, wo, wi).g, d = nb->eval(ctx, wo, wi).g;
        EXPECT_NEAR(c, d, 1e-4 * d + 1e-8);
        EXPECT_NEAR(tt->pdf(ctx, wo, wi), nb->pdf(ctx, wo, wi), 1e-4 * nb->pdf(ctx, wo, wi) + 1e-8);
        if (d > 0) ++compared;
    }
    EXPECT_GT(compared, 200);
    // The widened lobe really is wider: with the half vector 20 degrees off the normal the s = 200
    // lobe is ~0 while the Toksvig one is not.
    auto sharp = make(R"({"type":"blinnphong","exponent":200})");
    const Vec3 wo = dir_deg(30, 0), wi = dir_deg(70, 180);
    EXPECT_GT(t->eval(ctx, wo, wi).g, 100 * sharp->eval(ctx, wo, wi).g);
}

TEST(NdfFiltering, BakedAverageNormalsMatchDirectIntegration) {
    // Coarsest MIP level of the baked per-cell average unit normals = the average of the
    // unit normals over the whole map, by dense midpoint integration of the bilinear
    // patches' analytic derivatives (midpoint error ~1e-5 at 64^2 points a cell for these slopes).
    for (int which = 0; which < 2; ++which) {
        const HeightMap map = which == 0 ? sinusoid_map(16, 16, 0.05) : noise_map(16, 16, 9, 0.02);
        const Heightfield hf(map, 1.f, 0.f);
        const double tu = 2.0, tv = 1.0, lu = 1.5, lv = 0.7;
        const MipMap mip = NormalSource::bake_heightfield(hf, tu, tv, lu, lv);
        float top[3];
        mip.level_mean(mip.levels() - 1, top);
        const double kx = hf.width() * tu / lu, ky = hf.height() * tv / lv;
        const int n = 64;
        double sum[3] = {0, 0, 0};
        for (int cy = 0; cy < hf.height(); ++cy)
            for (int cx = 0; cx < hf.width(); ++cx)
                for (int b = 0; b < n; ++b)
                    for (int a = 0; a < n; ++a) {
                        float dx, dy;
                        hf.eval(cx + (a + 0.5) / n, cy + (b + 0.5) / n, dx, dy);
                        const double x = dx * kx, y = dy * ky, inv = 1.0 / std::sqrt(1 + x * x + y * y);
                        sum[0] -= x * inv, sum[1] -= y * inv, sum[2] += inv;
                    }
        const double cells = double(n) * n * hf.width() * hf.height();
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(top[c], sum[c] / cells, 3e-5) << "map " << which << " channel " << c;
        const double len = std::sqrt(double(top[0]) * top[0] + double(top[1]) * top[1] + double(top[2]) * top[2]);
        EXPECT_LT(len, 0.98) << "these maps are rough: |N_a| must show it";
        EXPECT_GT(len, 0.3);
        // Level 0 texels are unit-ish (one cell's spread only), coarser levels shorter.
        const float *t0 = mip.texel(0, 3, 5);
        EXPECT_LE(std::sqrt(t0[0] * t0[0] + t0[1] * t0[1] + t0[2] * t0[2]), 1.0 + 1e-6);
    }
}

TEST(NdfFiltering, ToksvigFromAHeightMapUsesTheFootprint) {
    const std::string file = write_map("sines", sinusoid_map(32, 32, 0.02));
    auto t = make(R"({"type":"toksvig","exponent":1000,"heightmap":{"map":")" + file + R"("}})");
    auto flat = make(R"({"type":"blinnphong","exponent":1000})");
    // A footprint covering the whole map: the coarsest level; N_a short -> a wide lobe.
    const ShadingContext wide = patch_ctx(Vec3(1, 0, 0), Vec3(0, 1, 0), Vec2(0.3f, 0.3f), 4.f);
    const Heightfield hf(sinusoid_map(32, 32, 0.02), 1.f, 0.f);
    const MipMap mip = NormalSource::bake_heightfield(hf, 1, 1, 1, 1);
    float top[3];
    mip.level_mean(mip.levels() - 1, top);
    const double len = std::sqrt(double(top[0]) * top[0] + double(top[1]) * top[1] + double(top[2]) * top[2]);
    const double s_hat = 1000.0 / (1.0 + (1.0 - len) / len * 1000.0);
    auto expect = make(R"({"type":"normalmap","normal":[)" + std::to_string(top[0] / len) + "," +
                       std::to_string(top[1] / len) + "," + std::to_string(top[2] / len) +
                       R"(],"bsdf":{"type":"blinnphong","exponent":)" + std::to_string(s_hat) + "}}");
    PCG32 rng(4);
    for (int i = 0; i < 300; ++i) {
        const Vec3 wo = upper_dir(rng), wi = upper_dir(rng);
        const double a = t->eval(wide, wo, wi).g, e = expect->eval(ShadingContext{}, wo, wi).g;
        EXPECT_NEAR(a, e, 2e-3 * e + 1e-6);
    }
    EXPECT_LT(s_hat, 100.0);
    // The albedo stays <= 1 and the lobe is no mirror any more.
    double se = 0;
    EXPECT_LE(albedo(*t, wide, dir_deg(40, 10), 20000, &se), 1.0 + 5 * se);
    const Vec3 wo = dir_deg(30, 0), wi = dir_deg(60, 180);
    EXPECT_GT(t->eval(wide, wo, wi).g, 1e3 * flat->eval(ShadingContext{}, wo, wi).g);
}

// ------------------------------------------------------------------ (c) LEAN moments of a height map

TEST(NdfFiltering, LeanCoarseMomentsAreTheMapSlopeStatistics) {
    // At the coarsest level the distribution is that of every slope of the map: the mean
    // cell slope, and the covariance of the cell slopes (height_map_stats) plus the variance
    // inside each bilinear cell: x = e + g b with b uniform adds Var = g^2 / 12 (per cell,
    // times cells-per-unit^2), and x, y are independent inside a cell (x depends on b, y on a).
    const int W = 32, H = 16;
    const HeightMap map = noise_map(W, H, 11, 0.01);
    const HeightMapStats st = height_map_stats(map, true);
    double g2 = 0;
    for (int j = 0; j < H; ++j)
        for (int i = 0; i < W; ++i) {
            const double g = double(map.wrapped(i, j)) + map.wrapped(i + 1, j + 1) - map.wrapped(i + 1, j) - map.wrapped(i, j + 1);
            g2 += g * g;
        }
    g2 /= double(W) * H;
    const std::string file = write_map("lean_stats", map);
    auto lean = make(R"({"type":"lean","heightmap":{"map":")" + file + R"("},"exponent":50})");
    const auto *l = dynamic_cast<const GaussianMicrofacetMaterial *>(lean.get());
    ASSERT_TRUE(l);
    const ShadingContext ctx = patch_ctx(Vec3(1, 0, 0), Vec3(0, 1, 0), Vec2(0.2f, 0.7f), 8.f);
    const SlopeGaussian g = l->distribution(ctx);
    const double tol = 1e-5 * (st.sxx + st.syy);  // float moments
    EXPECT_NEAR(g.mx, st.mean_su, 1e-4);
    EXPECT_NEAR(g.my, st.mean_sv, 1e-4);
    EXPECT_NEAR(g.sxx, st.sxx + g2 * W * W / 12.0 + 1.0 / 50, tol + 1e-6);
    EXPECT_NEAR(g.syy, st.syy + g2 * H * H / 12.0 + 1.0 / 50, tol + 1e-6);
    EXPECT_NEAR(g.sxy, st.sxy, tol + 1e-6);
    // A point lookup (filter at level 0, zero footprint) sees one cell's patch only.
    const ShadingContext point = patch_ctx(Vec3(1, 0, 0), Vec3(0, 1, 0), Vec2((5 + 0.5f) / W, (7 + 0.5f) / H), 0.f);
    const SlopeGaussian g0 = l->distribution(point);
    double su, sv;
    cell_slope(map, 5, 7, su, sv);
    EXPECT_NEAR(g0.mx, su, 1e-4);
    EXPECT_NEAR(g0.my, sv, 1e-4);
    EXPECT_LT(g0.sxx, g.sxx);
}

// ------------------------------------------------------------------ (d) stiff inputs

TEST(NdfFiltering, LeanTinyVarianceTendsToAMirror) {
    auto m = make(R"({"type":"lean","covariance":[1e-12,1e-12,0]})");
    const ShadingContext ctx;
    expect_sane(*m, "lean 1e-12");
    for (double t : {0.0, 30.0, 70.0, 89.0}) {
        const Vec3 wo = dir_deg(t, 20), mirror(-wo.x, -wo.y, wo.z);
        PCG32 rng(5);
        int ok = 0;
        double sum = 0;
        for (int i = 0; i < 2000; ++i) {
            BSDFSample bs;
            if (!m->sample(ctx, wo, 0.5f, {rng.next_float(), rng.next_float()}, bs)) continue;
            ++ok;
            sum += bs.weight.g;
            EXPECT_LT(length(bs.wi - mirror), 2e-3f) << "theta " << t;  // sigma is regularised to 1e-4
        }
        EXPECT_GT(ok, 1900);
        // Energy: G1(wo) G1(wi) -> 1 for a mirror-like lobe away from grazing.
        if (t < 80) {
            EXPECT_NEAR(sum / ok, 1.0, 1e-3) << "theta " << t;
        }
        EXPECT_EQ(m->eval(ctx, wo, dir_deg(t + 2, 200)).g, 0.f);
    }
}

TEST(NdfFiltering, StiffGaussianSlopesStayFinite) {
    const char *cfgs[] = {
        R"({"type":"lean","covariance":[100,100,0]})",
        R"({"type":"lean","covariance":[0.1,0.1,0.1]})",
        R"({"type":"lean","covariance":[0.1,0.1,-0.0999999]})",
        R"({"type":"lean","mean_slope":[1000,0],"covariance":[0.1,0.1,0]})",
        R"({"type":"lean","mean_slope":[-700,700],"exponent":1e7})",
        R"({"type":"clean","mean_slope":[1000,0],"covariance":[100,1e-12,0],"rational_lambda":true})",
        R"({"type":"lean","alpha":1000,"material":"Au"})",
    };
    for (const char *c : cfgs) {
        auto m = make(c);
        expect_sane(*m, c);
        for (double t : {0.0, 45.0, 85.0}) {
            double se = 0;
            EXPECT_LE(albedo(*m, ShadingContext{}, dir_deg(t, 30), 20000, &se), 1.0 + 5 * se + 1e-6) << c << " " << t;
        }
    }
}

TEST(NdfFiltering, LightBelowTheMesosurfaceIsBlack) {
    // Mean slope 1 along x: the mesosurface is tilted 45 degrees towards -x; a direction 60
    // degrees towards +x is below it (n . w = cos 105 < 0): fully shadowed / masked.
    auto m = make(R"({"type":"lean","mean_slope":[1,0],"covariance":[0.05,0.05,0]})");
    const ShadingContext ctx;
    const Vec3 below = dir_deg(60, 0), above = dir_deg(30, 180);
    EXPECT_TRUE(m->eval(ctx, above, below).is_black());
    EXPECT_TRUE(m->eval(ctx, below, above).is_black());
    EXPECT_EQ(m->pdf(ctx, above, below), 0.f);
    BSDFSample bs;
    EXPECT_FALSE(m->sample(ctx, below, 0.5f, {0.3f, 0.3f}, bs));
    EXPECT_GT(m->eval(ctx, above, dir_deg(20, 180)).g, 0.f);
    // Grazing: exactly 90 degrees gives 0, never NaN.
    EXPECT_TRUE(m->eval(ctx, dir_deg(90, 180), above).is_black());
    EXPECT_TRUE(m->eval(ctx, above, dir_deg(90, 180)).is_black());
    const GaussianMicrofacet g(SlopeGaussian{1, 0, 0.05, 0.05, 0});
    EXPECT_EQ(g.G1(below), 0.0);
    EXPECT_GT(g.G1(above), 0.0);
    EXPECT_LE(g.G1(above), 1.0);
    // Seen from the side the mesosurface leans away from, it shows less than the macro
    // footprint: sigma < cos theta, and the unclamped Smith G1 would exceed 1.
    const Vec3 facing = dir_deg(20, 0);
    EXPECT_GT(facing.z / g.projected_area(facing), 1.0);
    EXPECT_EQ(g.G1(facing), 1.0);
}

TEST(NdfFiltering, TiltedLeanAlbedoAtMostOneAllAround) {
    // Where the mesosurface leans away from wo, sigma(wo) < cos(theta_o) and the plain Smith
    // G1 exceeds 1; the min(1, .) clamp keeps the albedo <= 1 (bsdf/gaussian_microfacet.h).
    for (const char *c : {R"({"type":"lean","mean_slope":[0.6,0],"covariance":[0.01,0.01,0]})",
                          R"({"type":"clean","mean_slope":[0,-1.2],"covariance":[0.05,0.01,0]})"}) {
        auto m = make(c);
        for (double t : {10.0, 30.0, 50.0, 70.0, 85.0})
            for (double phi : {0.0, 90.0, 180.0, 270.0}) {
                double se = 0;
                const double a = albedo(*m, ShadingContext{}, dir_deg(t, phi), 20000, &se);
                EXPECT_LE(a, 1.0 + 5 * se + 1e-6) << c << " theta " << t << " phi " << phi;
            }
    }
}

TEST(NdfFiltering, StiffToksvigStaysFinite) {
    const char *cfgs[] = {
        R"({"type":"toksvig","exponent":1e7})",
        R"({"type":"toksvig","exponent":0})",
        R"({"type":"toksvig","exponent":1e7,"average_normal":[0,0,1e-9]})",
        R"({"type":"toksvig","exponent":100,"average_normal":[1e-9,0,1e-9]})",
        R"({"type":"toksvig","exponent":1e7,"average_normal":[0.7,0.7,0.01],"eta":1.5})",
    };
    for (const char *c : cfgs) {
        auto m = make(c);
        expect_sane(*m, c);
        for (double t : {0.0, 45.0, 89.0}) {
            double se = 0;
            EXPECT_LE(albedo(*m, ShadingContext{}, dir_deg(t, 30), 20000, &se), 1.0 + 5 * se + 1e-6) << c << " " << t;
        }
    }
    // |N_a| -> 0: s_hat -> 0, the widest lobe (Blinn-Phong with s = 0).
    auto t0 = make(R"({"type":"toksvig","exponent":1e7,"average_normal":[0,0,1e-9]})");
    auto b0 = make(R"({"type":"blinnphong","exponent":0})");
    const Vec3 wo = dir_deg(30, 10), wi = dir_deg(70, 250);
    EXPECT_NEAR(t0->eval(ShadingContext{}, wo, wi).g, b0->eval(ShadingContext{}, wo, wi).g,
                1e-3 * b0->eval(ShadingContext{}, wo, wi).g);
    // s = 1e7 at |N_a| = 1 is a near-mirror with finite peak.
    auto sharp = make(R"({"type":"toksvig","exponent":1e7})");
    const float p = sharp->pdf(ShadingContext{}, wo, Vec3(-wo.x, -wo.y, wo.z));
    EXPECT_TRUE(std::isfinite(p) && p > 1e5f);
}

// ------------------------------------------------------------------ (e) normalmap on a displaced plane

namespace {

/// The perturbed normal of a `normalmap` around a white diffuse material, recovered from
/// eval = max(0, wi . n') / pi at three directions (local frame).
Vec3 recovered_normal(const Material &m, const ShadingContext &ctx, Vec3 guess) {
    const Frame f(guess);
    Vec3 d[3] = {normalize(guess), normalize(guess + 0.3f * f.s), normalize(guess + 0.3f * f.t)};
    double A[3][3], b[3];
    for (int k = 0; k < 3; ++k) {
        A[k][0] = d[k].x, A[k][1] = d[k].y, A[k][2] = d[k].z;
        b[k] = m.eval(ctx, Vec3(0, 0, 1), d[k]).g * kPi;
    }
    // Cramer's rule.
    auto det = [](double M[3][3]) {
        return M[0][0] * (M[1][1] * M[2][2] - M[1][2] * M[2][1]) - M[0][1] * (M[1][0] * M[2][2] - M[1][2] * M[2][0]) +
               M[0][2] * (M[1][0] * M[2][1] - M[1][1] * M[2][0]);
    };
    const double D = det(A);
    double x[3];
    for (int c = 0; c < 3; ++c) {
        double M[3][3];
        for (int r = 0; r < 3; ++r)
            for (int k = 0; k < 3; ++k) M[r][k] = k == c ? b[r] : A[r][k];
        x[c] = det(M) / D;
    }
    return Vec3(float(x[0]), float(x[1]), float(x[2]));
}

}  // namespace

TEST(NdfFiltering, NormalMapOfADisplacedPlaneIsItsAnalyticNormal) {
    // Heights h = a i + b j on the grid: a plane with slopes a W per unit u and b H per unit v
    // (the wrap-around cells are far from the lookup point).
    const int W = 16, H = 16;
    const double a = 0.004, b = -0.006;
    HeightMap map(W, H);
    for (int j = 0; j < H; ++j)
        for (int i = 0; i < W; ++i) map.at(i, j) = float(a * i + b * j);
    const std::string file = write_map("plane", map);
    auto nm = make(R"({"type":"normalmap","heightmap":{"map":")" + file +
                   R"("},"filter":"none","bsdf":{"type":"diffuse","reflectance":1}})");
    const double hu = a * W, hv = b * H;  // dh/du, dh/dv
    // A tilted, sheared parameterisation and both sides.
    const Vec3 dpdu(2.f, 0.f, 0.3f), dpdv(0.4f, 1.5f, -0.2f);
    for (float side : {1.f, -1.f}) {
        const ShadingContext ctx = patch_ctx(dpdu, dpdv, Vec2(0.5f, 0.5f), 0.f, side);
        const Vec3 n0 = normalize(cross(dpdu, dpdv));
        // Displaced surface P = p + h n0: normal (dp/du + h_u n0) x (dp/dv + h_v n0), facing ctx's side.
        Vec3 N = normalize(cross(dpdu + float(hu) * n0, dpdv + float(hv) * n0));
        if (side < 0.f) N = -N;
        const Vec3 expected = ctx.frame.to_local(N);
        const Vec3 got = recovered_normal(*nm, ctx, expected);
        EXPECT_NEAR(got.x, expected.x, 2e-4) << "side " << side;
        EXPECT_NEAR(got.y, expected.y, 2e-4) << "side " << side;
        EXPECT_NEAR(got.z, expected.z, 2e-4) << "side " << side;
        EXPECT_GT(std::abs(expected.x) + std::abs(expected.y), 0.05f);
    }
    // The baked (u, v)-frame normals of toksvig's NormalSource agree on an orthogonal patch
    // whose uv lengths are given (v running along +t and along -t).
    for (float vy : {1.5f, -1.5f}) {
        nlohmann::json j = nlohmann::json::parse(R"({"heightmap":{"map":")" + file +
                                                 R"("},"filter":"none","uv_length":[2,1.5]})");
        const NormalSource src = NormalSource::parse(Properties(j, "material", std::make_shared<LoadContext>()),
                                                     "average_normal", false);
        const Vec3 du(2.f, 0.f, 0.f), dv(0.f, vy, 0.f);
        for (float side : {1.f, -1.f}) {
            const ShadingContext ctx = patch_ctx(du, dv, Vec2(0.5f, 0.5f), 0.f, side);
            const Vec3 n0 = normalize(cross(du, dv));
            Vec3 N = normalize(cross(du + float(hu) * n0, dv + float(hv) * n0));
            if (side < 0.f) N = -N;
            const Vec3 expected = ctx.frame.to_local(N), got = src.eval(ctx);
            EXPECT_NEAR(got.x, expected.x, 1e-5) << "vy " << vy << " side " << side;
            EXPECT_NEAR(got.y, expected.y, 1e-5) << "vy " << vy << " side " << side;
            EXPECT_NEAR(got.z, expected.z, 1e-5) << "vy " << vy << " side " << side;
        }
    }
}

TEST(NdfFiltering, NormalMapImage) {
    // An 8-bit PNG normal map: c = (n + 1)/2, renormalised after decoding; a float EXR as is.
    const Vec3 n = normalize(Vec3(0.3f, -0.2f, 0.9f));
    Image img(4, 4, 3);
    for (int y = 0; y < 4; ++y)
        for (int x = 0; x < 4; ++x) img.set_rgb(x, y, Spectrum(n.x, n.y, n.z));
    const std::string exr = test::scratch_dir("meso_ndf") + "/normals.exr";
    write_exr(exr, img);
    auto m = make(R"({"type":"normalmap","normals":")" + exr + R"(","bsdf":{"type":"diffuse","reflectance":1}})");
    const Vec3 got = recovered_normal(*m, ShadingContext{}, n);
    EXPECT_NEAR(got.x, n.x, 1e-5);
    EXPECT_NEAR(got.y, n.y, 1e-5);
    EXPECT_NEAR(got.z, n.z, 1e-5);
    // Integer encoding: 2c - 1 and per-texel renormalisation.
    Image enc(2, 1, 3);
    enc.set_rgb(0, 0, Spectrum(0.5f * (n.x + 1), 0.5f * (n.y + 1), 0.5f * (n.z + 1)));
    enc.set_rgb(1, 0, Spectrum(0.5f, 0.5f, 0.5f));  // zero vector -> (0, 0, 1)
    const MipMap mip = NormalSource::normal_map_mip(enc, true);
    EXPECT_NEAR(mip.texel(0, 0, 0)[0], n.x, 1e-6);
    EXPECT_NEAR(mip.texel(0, 0, 0)[2], n.z, 1e-6);
    EXPECT_EQ(mip.texel(0, 1, 0)[2], 1.f);
    // Toksvig on a two-texel map of different unit normals: the coarse average is shorter.
    float mean[3];
    mip.level_mean(mip.levels() - 1, mean);
    EXPECT_LT(std::sqrt(mean[0] * mean[0] + mean[1] * mean[1] + mean[2] * mean[2]), 0.99f);
}

TEST(NdfFiltering, ParameterErrors) {
    auto fails = [](const std::string &json, const std::string &what) {
        try {
            make(json);
        } catch (const std::exception &e) {
            EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
            return;
        }
        ADD_FAILURE() << "no error for " << json;
    };
    fails(R"({"type":"lean","exponent":0})", "material.exponent");
    fails(R"({"type":"lean","exponent":10,"alpha":0.1})", "not both");
    fails(R"({"type":"clean","material":"Xx"})", "unknown conductor");
    fails(R"({"type":"toksvig","average_normal":[0,0,1.5]})", "length in (0, 1]");
    fails(R"({"type":"toksvig","average_normal":[0,0,1],"filter":"ewa"})", "only meaningful");
    fails(R"({"type":"toksvig","exponent":2e7})", "exponent must be in");
    fails(R"({"type":"normalmap","normal":[0,0,1]})", "\"bsdf\"");
    fails(R"({"type":"normalmap","bsdf":{"type":"diffuse"}})", "normal source");
    fails(R"({"type":"normalmap","normal":[0,0,1],"mean_slope":[0,0],"bsdf":{"type":"diffuse"}})", "not both");
    fails(R"({"type":"normalmap","normal":[0,0,-1],"bsdf":{"type":"diffuse"}})", "z > 0");
    fails(R"({"type":"normalmap","mean_slope":[0,0],"covariance":[1,1,0],"bsdf":{"type":"diffuse"}})", "mean slope only");
}
