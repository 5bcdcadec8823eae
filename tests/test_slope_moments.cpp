// Slope-moment maps: exact per-cell moments of the bilinear patches against dense numerical
// integration of the heightfield's own derivatives, area-average mip levels, units.
#include <gtest/gtest.h>
#include <cmath>
#include "core/error.h"
#include "sampling/rng.h"
#include "texture/slope_moments.h"
#include <vector>

using namespace meso;

namespace {

HeightMap noise_map(int w, int h, uint64_t seed) {
    HeightMap m(w, h);
    PCG32 rng(seed);
    for (float &v : m.h) v = rng.next_float() * 2.f - 1.f;
    return m;
}

/// Moments of (dh/du, dh/dv) over [x0, x0 + nx] x [y0, y0 + ny] cells by an n x n midpoint
/// grid per cell on eval()'s analytic derivatives (independent of the closed forms).
void dense_moments(const Heightfield &hf, int x0, int y0, int nx, int ny, double su, double sv, double out[5]) {
    const int n = 64;
    for (int k = 0; k < 5; ++k) out[k] = 0;
    for (int cy = 0; cy < ny; ++cy)
        for (int cx = 0; cx < nx; ++cx)
            for (int b = 0; b < n; ++b)
                for (int a = 0; a < n; ++a) {
                    float dx, dy;
                    hf.eval(x0 + cx + (a + 0.5) / n, y0 + cy + (b + 0.5) / n, dx, dy);
                    const double x = dx * su, y = dy * sv;
                    out[0] += x, out[1] += y, out[2] += x * x, out[3] += y * y, out[4] += x * y;
                }
    for (int k = 0; k < 5; ++k) out[k] /= double(n) * n * nx * ny;
}

}  // namespace

TEST(SlopeMoments, CellsMatchDenseIntegration) {
    Heightfield hf(noise_map(13, 9, 5), 0.3f, 0.1f);
    const double tile_u = 0.25, tile_v = 0.5;  // tiling 4 x 2: slopes per uv = per cell * 52, * 18
    MipMap m = build_slope_moments(hf, tile_u, tile_v);
    ASSERT_EQ(m.channels(), 5);
    for (int j = 0; j < 9; ++j)
        for (int i = 0; i < 13; ++i) {
            double ref[5];
            dense_moments(hf, i, j, 1, 1, 13 / tile_u, 9 / tile_v, ref);
            const float *t = m.texel(0, i, j);
            const double scale = std::max(1.0, std::abs(ref[2]) + std::abs(ref[3]));
            // The n-point midpoint rule integrates (e + g b)^2 low by exactly g^2 / (12 n^2);
            // linear terms and the separable product x y it integrates exactly.
            const double g = double(hf.vertex(i, j)) + hf.vertex(i + 1, j + 1) - hf.vertex(i + 1, j) - hf.vertex(i, j + 1);
            const double bias[5] = {0, 0, sqr(g * 13 / tile_u) / (12.0 * 64 * 64), sqr(g * 9 / tile_v) / (12.0 * 64 * 64), 0};
            for (int k = 0; k < 5; ++k)
                EXPECT_NEAR(t[k], ref[k] + bias[k], 1e-5 * scale) << "cell " << i << "," << j << " moment " << k;
        }
}

TEST(SlopeMoments, CoarseLevelsHoldTheMomentsOfEverythingBelow) {
    Heightfield hf(noise_map(32, 32, 9), 1.f, 0.f);
    MipMap m = build_slope_moments(hf);
    // Level 2 texel (1, 3) covers cells [4, 8) x [12, 16).
    double ref[5];
    dense_moments(hf, 4, 12, 4, 4, 32, 32, ref);
    const float *t = m.texel(2, 1, 3);
    // Midpoint bias of the squared terms: at most max g^2 / (12 n^2) (g <= 4 here, 32 cells/uv).
    const double bias_bound = sqr(4.0 * 32) / (12.0 * 64 * 64);
    for (int k = 0; k < 5; ++k) EXPECT_NEAR(t[k], ref[k], 1e-5 * (std::abs(ref[2]) + std::abs(ref[3])) + bias_bound) << k;
    // A periodic map has zero mean slope; the variance under a texel grows with the level.
    const float *top = m.texel(m.levels() - 1, 0, 0);
    EXPECT_NEAR(top[MomentX], 0.f, 1e-3f * std::sqrt(top[MomentXX]));
    EXPECT_NEAR(top[MomentY], 0.f, 1e-3f * std::sqrt(top[MomentYY]));
    double prev = 0;
    for (int l = 0; l < m.levels(); ++l) {
        double var = 0;
        for (int y = 0; y < m.height(l); ++y)
            for (int x = 0; x < m.width(l); ++x) {
                const float *q = m.texel(l, x, y);
                var += q[MomentXX] - double(q[MomentX]) * q[MomentX];
            }
        var /= double(m.width(l)) * m.height(l);
        EXPECT_GE(var, prev - 1e-6) << "level " << l;
        prev = var;
    }
}

TEST(SlopeMoments, TiltedPlaneHasItsSlopeAndNoVariance) {
    HeightMap ramp(16, 16);
    for (int j = 0; j < 16; ++j)
        for (int i = 0; i < 16; ++i) ramp.at(i, j) = 0.5f * i - 0.25f * j;
    Heightfield hf(ramp, 1.f, 0.f);
    MipMap m = build_slope_moments(hf);  // one tile over uv [0,1]: 16 cells per unit uv
    for (int j = 0; j < 15; ++j)
        for (int i = 0; i < 15; ++i) {  // the last row/column wraps onto the ramp's seam
            const float *t = m.texel(0, i, j);
            EXPECT_NEAR(t[MomentX], 8.f, 1e-4f);
            EXPECT_NEAR(t[MomentY], -4.f, 1e-4f);
            EXPECT_NEAR(t[MomentXX], 64.f, 1e-3f);
            EXPECT_NEAR(t[MomentYY], 16.f, 1e-3f);
            EXPECT_NEAR(t[MomentXY], -32.f, 1e-3f);
        }
}

TEST(SlopeMoments, BadTileSizes) {
    Heightfield hf(noise_map(4, 4, 1), 1.f, 0.f);
    EXPECT_THROW(build_slope_moments(hf, 0.0, 1.0), MesoError);
    EXPECT_THROW(build_slope_moments(hf, 1.0, std::nan("")), MesoError);
}

// Paper 000 eq. (12) is the moment form of the linear map x = u_x U + v_x V,
// y = u_y U + v_y V: applied to the empirical moments of samples it must give the empirical
// mean and covariance of the mapped samples (an identity, so the tolerance is round-off).
TEST(SlopeMoments, TangentFrameTransformIsTheLinearMapOfTheSlopes) {
    PCG32 rng(17);
    const int n = 20000;
    std::vector<double> U(n), V(n);
    for (int k = 0; k < n; ++k) {  // correlated, non-centred slopes
        double a = std::sqrt(-2 * std::log(1 - rng.next_float())) * std::cos(2 * 3.14159265 * rng.next_float());
        double b = std::sqrt(-2 * std::log(1 - rng.next_float())) * std::cos(2 * 3.14159265 * rng.next_float());
        U[k] = 0.3 + 0.5 * a;
        V[k] = -0.2 + 0.4 * a + 0.2 * b;
    }
    double m[5] = {0, 0, 0, 0, 0};
    for (int k = 0; k < n; ++k) m[0] += U[k], m[1] += V[k], m[2] += U[k] * U[k], m[3] += V[k] * V[k], m[4] += U[k] * V[k];
    float mf[5];
    for (int c = 0; c < 5; ++c) mf[c] = float(m[c] / n);
    const double ux = 0.7, vx = -0.4, uy = 0.25, vy = 1.3, eta = 1.5, base = 0.01;
    SlopeGaussian g = slope_gaussian(mf, ux, vx, uy, vy, eta, base);
    double sx = 0, sy = 0, sxx = 0, syy = 0, sxy = 0;
    for (int k = 0; k < n; ++k) {
        double x = eta * (ux * U[k] + vx * V[k]), y = eta * (uy * U[k] + vy * V[k]);
        sx += x, sy += y, sxx += x * x, syy += y * y, sxy += x * y;
    }
    sx /= n, sy /= n;
    EXPECT_NEAR(g.mx, sx, 1e-5);
    EXPECT_NEAR(g.my, sy, 1e-5);
    EXPECT_NEAR(g.sxx, sxx / n - sx * sx + base, 1e-4);
    EXPECT_NEAR(g.syy, syy / n - sy * sy + base, 1e-4);
    EXPECT_NEAR(g.sxy, sxy / n - sx * sy, 1e-4);
}

TEST(SlopeMoments, DistortionFromTheParameterisation) {
    // Stretched and sheared: x = 2u + 0.5v, y = 0.5v (dp/du = (2,0,0), dp/dv = (0.5,0.5,0)).
    const double dpdu[3] = {2, 0, 0}, dpdv[3] = {0.5, 0.5, 0}, t[3] = {1, 0, 0}, b[3] = {0, 1, 0};
    double ux, vx, uy, vy;
    ASSERT_TRUE(uv_per_tangent(dpdu, dpdv, t, b, ux, vx, uy, vy));
    // J * M = I with M = [[2, 0.5], [0, 0.5]].
    EXPECT_NEAR(ux * 2 + uy * 0, 1.0, 1e-12);
    EXPECT_NEAR(ux * 0.5 + uy * 0.5, 0.0, 1e-12);
    EXPECT_NEAR(vx * 2 + vy * 0, 0.0, 1e-12);
    EXPECT_NEAR(vx * 0.5 + vy * 0.5, 1.0, 1e-12);
    // A slope of 1 per unit u on a surface stretched 2x along x is 0.5 per unit x.
    const float m[5] = {1, 0, 1, 0, 0};
    EXPECT_NEAR(slope_gaussian(m, 0.5, 0, 0, 1).mx, 0.5, 1e-12);
    const double zero[3] = {0, 0, 0};
    EXPECT_FALSE(uv_per_tangent(zero, dpdv, t, b, ux, vx, uy, vy));
    EXPECT_EQ(ux, 0.0);
}

// ---- SlopeSource: the moments read at a shading point ------------------------------------

#include <nlohmann/json.hpp>
#include "geometry/heightmap_gen.h"
#include "core/properties.h"
#include "texture/slope_source.h"

namespace {

ShadingContext plane_context(Vec3 dpdu, Vec3 dpdv, Vec2 uv, float footprint_uv) {
    ShadingContext ctx;
    ctx.uv = uv;
    ctx.dpdu = dpdu, ctx.dpdv = dpdv;
    ctx.frame = Frame(Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1));
    ctx.dudx = footprint_uv, ctx.dvdy = footprint_uv;
    return ctx;
}

SlopeSource parse_source(const std::string &json) {
    return SlopeSource::parse(Properties(nlohmann::json::parse(json), "material", std::make_shared<LoadContext>()));
}

}  // namespace

TEST(SlopeSource, WholeMapFootprintGivesTheMapsWorldSlopeStatistics) {
    // A Gaussian surface with a known cell-slope covariance (tile units), tiled 4 x 2 over a
    // plane whose uv square is 3 x 5 world units: world slopes = tile slopes * scale * tiling / length.
    std::map<std::string, std::string> params{{"size", "128"}, {"sxx", "0.1"}, {"syy", "0.05"}, {"sxy", "0.02"},
                                              {"correlation", "0.1"}};
    GeneratedMap g = generate_height_map("gaussian", params);
    HeightMapStats st = height_map_stats(g.height);
    const float scale = 0.7f;
    Heightfield hf(g.height, scale, 0.f);
    SlopeSource src(hf, 4.f, 2.f);
    ShadingContext ctx = plane_context(Vec3(3, 0, 0), Vec3(0, 5, 0), Vec2(0.3f, 0.6f), 10.f);  // coarsest level
    SlopeGaussian s = src.eval(ctx);
    const double kx = scale * 4.0 / 3.0, ky = scale * 2.0 / 5.0;
    // The moment MIP also holds the variance inside each bilinear cell, which the cell-average
    // statistics leave out: a few per cent for a correlation length of ~13 cells.
    EXPECT_NEAR(s.mx, st.mean_su * kx, 1e-4);
    EXPECT_NEAR(s.my, st.mean_sv * ky, 1e-4);
    EXPECT_NEAR(s.sxx, st.sxx * kx * kx, 0.04 * st.sxx * kx * kx);
    EXPECT_NEAR(s.syy, st.syy * ky * ky, 0.04 * st.syy * ky * ky);
    EXPECT_NEAR(s.sxy, st.sxy * kx * ky, 0.04 * std::sqrt(st.sxx * st.syy) * kx * ky);
    // A point footprint reads one cell: no more than the cell's own variance, less than the map's.
    SlopeGaussian c = src.eval(plane_context(Vec3(3, 0, 0), Vec3(0, 5, 0), Vec2(0.3f, 0.6f), 0.f));
    EXPECT_LT(c.sxx, 0.2 * s.sxx);
}

TEST(SlopeSource, FlippedFrameSeesTheNegatedHeights) {
    HeightMap ramp(16, 16);
    for (int j = 0; j < 16; ++j)
        for (int i = 0; i < 16; ++i) ramp.at(i, j) = 0.5f * i - 0.25f * j;
    Heightfield hf(ramp, 1.f, 0.f);
    SlopeSource src(hf, 1.f, 1.f, SlopeSource::Filter::None);
    ShadingContext ctx = plane_context(Vec3(2, 0, 0), Vec3(0, 2, 0), Vec2(0.5f, 0.5f), 0.f);
    SlopeGaussian front = src.eval(ctx);
    EXPECT_NEAR(front.mx, 4.0, 1e-4);   // 8 per unit u over 2 world units
    EXPECT_NEAR(front.my, -2.0, 1e-4);
    // The two-sided integrator flips n (and t = n x s) towards a viewer below the surface:
    // the heights then point away from it, h' = -h, with y' = -y.
    ctx.frame = Frame(Vec3(1, 0, 0), Vec3(0, -1, 0), Vec3(0, 0, -1));
    ctx.side = -1.f;
    SlopeGaussian back = src.eval(ctx);
    EXPECT_NEAR(back.mx, -4.0, 1e-4);
    EXPECT_NEAR(back.my, -2.0, 1e-4);
    EXPECT_NEAR(back.sxx, front.sxx, 1e-6);
    // Degenerate parameterisation: flat, finite.
    ctx.dpdv = Vec3(0, 0, 0);
    SlopeGaussian flat = src.eval(ctx);
    EXPECT_EQ(flat.mx, 0.0);
    EXPECT_EQ(flat.sxx, 0.0);
}

TEST(SlopeSource, ParsesConstantsAndRejectsMixedOrBadKeys) {
    SlopeSource c = parse_source(R"({"mean_slope":[0.1,-0.2],"covariance":[0.04,0.09,0.01]})");
    EXPECT_TRUE(c.is_constant());
    SlopeGaussian g = c.eval(ShadingContext{});
    EXPECT_DOUBLE_EQ(g.mx, 0.1f);
    EXPECT_DOUBLE_EQ(g.syy, 0.09f);
    SlopeSource m = parse_source(R"({"heightmap":{"map":{"generator":"gaussian","size":32}},"filter":"ewa"})");
    EXPECT_FALSE(m.is_constant());
    EXPECT_NE(m.to_string().find("ewa"), std::string::npos);
    EXPECT_THROW(parse_source(R"({"heightmap":{"map":{"generator":"gaussian","size":32}},"covariance":[1,1,0]})"),
                 MesoError);
    EXPECT_THROW(parse_source(R"({"heightmap":{"map":{"generator":"gaussian","size":32}},"filter":"box"})"), MesoError);
    EXPECT_THROW(parse_source(R"({"filter":"ewa"})"), MesoError);
    EXPECT_THROW(parse_source(R"({"covariance":[0.1,0.1,0.5]})"), MesoError);
    EXPECT_THROW(parse_source(R"({"heightmap":{"scale":1}})"), MesoError);
}
