// Height transfer functions (paper 001 §7): a displacement's "transfer" g makes the exact
// micro-geometry h = offset + scale * g(f); a slope source's "transfer_filter": "gaussian" keeps
// the pyramids of f and filters g on f's Gaussian statistics at each footprint (eq. 19-28). The
// exact reference is the MIP of g(f) itself ("transfer_filter": "exact", the default).
#include <gtest/gtest.h>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <deque>
#include <string>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "geometry/displacement.h"
#include "geometry/heightfield.h"
#include "geometry/heightmap_gen.h"
#include "geometry/shell_shape.h"
#include "render_test_util.h"
#include "render/scene.h"
#include "filter/transfer_filter.h"
#include "sampling/rng.h"
#include "core/properties.h"
#include "filter/ramp_parse.h"
#include "texture/slope_source.h"

using namespace meso;

namespace {

// A Gaussian surface: cell slopes of covariance (0.1, 0.06, 0.02) in tile units, correlation
// length 0.02 tile = 5.1 cells on 256^2, so heights have sigma_f = 0.02 sqrt(l1 / 2) = 0.0047
// (l1 = 0.109, the larger eigenvalue); the map holds ~2500 correlation areas.
const char *kGen =
    R"({"generator": "gaussian", "size": 256, "correlation": 0.02, "sxx": 0.1, "syy": 0.06, "sxy": 0.02, "seed": 3})";
// A "moss"-like non-linear g over f's range (about +-4 sigma_f = +-0.02): clipped to 0 below
// -0.004 (~ -0.85 sigma_f), a rise of slope 0.8, a plateau on [0, 0.0024], a rise of slope 1.83,
// clipped at 0.012 above 0.0072 (~ 1.5 sigma_f).
const char *kMoss = R"([[-0.004, 0.0], [0.0, 0.0032], [0.0024, 0.0032], [0.0072, 0.012]])";
constexpr double kSteepest = 0.0088 / 0.0048;
constexpr float kScale = 0.5f, kOffset = 0.1f, kTiling = 2.f;

GeneratedMap gen_map() {
    return generate_height_map("gaussian", {{"size", "256"},
                                            {"correlation", "0.02"},
                                            {"sxx", "0.1"},
                                            {"syy", "0.06"},
                                            {"sxy", "0.02"},
                                            {"seed", "3"}});
}

/// Properties keep a pointer to their JSON: the parsed documents live for the whole test binary.
Properties props(const std::string &json) {
    static std::deque<nlohmann::json> keep;
    keep.push_back(nlohmann::json::parse(json));
    return Properties(keep.back(), "material", std::make_shared<LoadContext>());
}

std::string heightmap_block(const std::string &transfer, float offset = kOffset) {
    std::string s = std::string(R"({"map": )") + kGen + R"(, "scale": )" + std::to_string(kScale) + R"(, "offset": )" +
                    std::to_string(offset) + R"(, "tiling": )" + std::to_string(kTiling);
    if (!transfer.empty()) s += R"(, "transfer": )" + transfer;
    return s + "}";
}

SlopeSource source(const std::string &transfer, const std::string &mode, const std::string &filter = "trilinear",
                   float offset = kOffset) {
    std::string j = R"({"heightmap": )" + heightmap_block(transfer, offset) + R"(, "filter": ")" + filter + "\"";
    if (!mode.empty()) j += R"(, "transfer_filter": ")" + mode + "\"";
    return SlopeSource::parse(props(j + "}"));
}

/// A unit plane (dp/du = x, dp/dv = y, frame = identity): eval() gives texture-space statistics.
ShadingContext at(double u, double v, double footprint_uv) {
    ShadingContext ctx;
    ctx.uv = Vec2(float(u), float(v));
    ctx.dpdu = Vec3(1, 0, 0), ctx.dpdv = Vec3(0, 1, 0);
    ctx.frame = Frame(Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1));
    ctx.dudx = float(footprint_uv), ctx.dvdy = float(footprint_uv);
    return ctx;
}

struct Stats {
    double mean = 0, var = 0;
    SlopeGaussian s;
};
Stats stats(const SlopeSource &src, const ShadingContext &ctx) {
    Stats r;
    EXPECT_TRUE(src.height_moments(ctx, r.mean, r.var));
    r.s = src.eval(ctx);
    return r;
}

std::string error_of(const std::string &json) {
    try {
        SlopeSource::parse(props(json));
    } catch (const MesoError &e) {
        return e.what();
    }
    return "(no error)";
}

}  // namespace

TEST(HeightTransfer, DisplacementAppliesGToEveryMapValueBeforeScaleAndOffset) {
    const GeneratedMap g = gen_map();
    const Ramp moss = parse_ramp(props(std::string(R"({"t": )") + kMoss + "}"), "t", 1);
    Displacement d = parse_displacement(props(heightmap_block(kMoss)), 0);
    ASSERT_TRUE(d.transfer);
    EXPECT_FALSE(d.field_untransferred);
    ASSERT_EQ(d.field->width(), 256);
    int clipped_low = 0, plateau = 0, clipped_high = 0;
    for (int j = 0; j < 256; ++j)
        for (int i = 0; i < 256; ++i) {
            const double f = g.height.at(i, j);
            double gf;
            moss.eval(f, &gf);
            EXPECT_NEAR(d.field->vertex(i, j), kOffset + kScale * float(gf), 1e-6) << i << ", " << j;
            clipped_low += f <= -0.004;
            plateau += f >= 0.0 && f <= 0.0024;
            clipped_high += f >= 0.0072;
        }
    // The map actually reaches every non-linear feature of g.
    EXPECT_GT(clipped_low, 1000);
    EXPECT_GT(plateau, 1000);
    EXPECT_GT(clipped_high, 100);
    // The field's range is g's: clipped at both ends.
    EXPECT_NEAR(d.field->min_height(), kOffset, 1e-6);
    EXPECT_NEAR(d.field->max_height(), kOffset + kScale * 0.012, 1e-6);
    EXPECT_NE(d.source.find("transfer"), std::string::npos);

    // apply_transfer = false: the untransformed map in map units, g and scale / offset kept aside.
    Displacement raw = parse_displacement(props(heightmap_block(kMoss)), 0, false);
    EXPECT_TRUE(raw.field_untransferred);
    EXPECT_FLOAT_EQ(raw.scale, kScale);
    EXPECT_FLOAT_EQ(raw.offset, kOffset);
    for (int j = 0; j < 256; j += 17)
        for (int i = 0; i < 256; i += 13) EXPECT_EQ(raw.field->vertex(i, j), g.height.at(i, j));
    // Without a transfer, apply_transfer changes nothing.
    Displacement plain = parse_displacement(props(heightmap_block("")), 0, false);
    EXPECT_FALSE(plain.transfer);
    EXPECT_FALSE(plain.field_untransferred);
    EXPECT_FLOAT_EQ(plain.field->vertex(5, 7), kOffset + kScale * g.height.at(5, 7));
}

/// Largest and RMS errors of `b` against `a` over random points at one footprint, in units of the
/// reference's whole-map statistics.
struct Errors {
    double mean = 0, var = 0, smean = 0, scov = 0;           // max
    double rmean = 0, rvar = 0, rsmean = 0, rscov = 0;       // rms
};
Errors compare(const SlopeSource &a, const SlopeSource &b, const Stats &ref, double footprint_uv, uint64_t seed) {
    const double sh = std::sqrt(ref.var), sdx = std::sqrt(ref.s.sxx), sdy = std::sqrt(ref.s.syy);
    Errors e;
    PCG32 rng(seed);
    const int n = 64;
    for (int k = 0; k < n; ++k) {
        const ShadingContext ctx = at(rng.next_double(), rng.next_double(), footprint_uv);
        const Stats x = stats(a, ctx), y = stats(b, ctx);
        const double dm = std::abs(x.mean - y.mean) / sh, dv = std::abs(x.var - y.var) / (sh * sh);
        const double ds = std::max(std::abs(x.s.mx - y.s.mx) / sdx, std::abs(x.s.my - y.s.my) / sdy);
        const double dc = std::max({std::abs(x.s.sxx - y.s.sxx) / (sdx * sdx), std::abs(x.s.syy - y.s.syy) / (sdy * sdy),
                                    std::abs(x.s.sxy - y.s.sxy) / (sdx * sdy)});
        e.mean = std::max(e.mean, dm), e.var = std::max(e.var, dv), e.smean = std::max(e.smean, ds);
        e.scov = std::max(e.scov, dc);
        e.rmean += dm * dm / n, e.rvar += dv * dv / n, e.rsmean += ds * ds / n, e.rscov += dc * dc / n;
    }
    e.rmean = std::sqrt(e.rmean), e.rvar = std::sqrt(e.rvar), e.rsmean = std::sqrt(e.rsmean), e.rscov = std::sqrt(e.rscov);
    return e;
}
void print(const char *what, double texels, const Errors &e) {
    std::printf("  %-22s %4.0f texels: max (rms) |dmean|/sigma_h %.4f (%.4f), |dvar|/sigma_h^2 %.4f (%.4f), "
                "|dslope|/sd %.4f (%.4f), |dcov|/var %.4f (%.4f)\n",
                what, texels, e.mean, e.rmean, e.var, e.rvar, e.smean, e.rsmean, e.scov, e.rscov);
}

// The Gaussian filter against exact MIPs of g(f) at coarse footprints. Two references:
//   vertices    the MIP of the displacement's own surface: g applied at the map's vertices, then
//               bilinear (what a shell map renders)
//   continuous  g applied to f bilinearly upsampled 4x (close to g(f(x)) of the bilinear f, the
//               surface §7's formulas describe: a kink of g inside a cell is resolved)
// They differ in the slope variance: the vertex surface replaces g'(f) inside a cell straddling a
// kink of g by the chord slope, whose square is smaller than the cell's average g'^2 (Jensen); with
// f changing by ~0.3 sigma_f per cell and g's pieces 0.5 to 1 sigma_f wide, most cells straddle
// one. Whole map, slope variance along u: vertices 0.0814, 4x 0.0935, 8x 0.0955 (-> ~0.0975
// extrapolated), Gaussian 0.1013; the last ~4% is the realisation (one map of ~2500 correlation
// areas: E[g'^2 (df/du)^2] does not factor exactly, f's histogram is not exactly Gaussian). The
// Gaussian filter's own
// approximations, seen against the continuous reference: f inside the footprint is taken as
// Gaussian (a footprint of a few correlation lengths holds a smooth patch, not a Gaussian sample;
// the trilinear blend of two texels is a mixture), and g'(f) as independent of df/dx (eq. 23: true
// pointwise for a Gaussian process, not inside a footprint whose mean height trends across it).
// Errors are in units of the reference's whole-map statistics (sigma_h, slope standard deviations,
// slope variances); the bounds sit above the measured maxima printed by the test (see the report).
TEST(HeightTransfer, GaussianFilterMatchesTheExactMipOfGOfFAtCoarseFootprints) {
    const SlopeSource exact = source(kMoss, "exact"), gauss = source(kMoss, "gaussian");
    EXPECT_TRUE(gauss.has_height_transfer());
    EXPECT_FALSE(exact.has_height_transfer());
    // g on f upsampled 4x (bilinear: the same piecewise-bilinear f, sampled finer).
    const GeneratedMap g = gen_map();
    const Ramp moss = parse_ramp(props(std::string(R"({"t": )") + kMoss + "}"), "t", 1);
    const Heightfield f_field(g.height, 1.f, 0.f);
    const int up = 4;
    HeightMap fine(256 * up, 256 * up);
    for (int j = 0; j < fine.height; ++j)
        for (int i = 0; i < fine.width; ++i) {
            double v;
            moss.eval(f_field.eval(double(i) / up, double(j) / up), &v);
            fine.at(i, j) = float(v);
        }
    const SlopeSource cont(Heightfield(fine, kScale, kOffset), kTiling, kTiling);

    const double tile_texels = 256.0 * kTiling;  // level-0 texels per unit uv
    const ShadingContext whole = at(0.3, 0.6, 300.0 / tile_texels);
    const Stats ref = stats(exact, whole), ref_c = stats(cont, whole), gw = stats(gauss, whole);
    ASSERT_GT(ref.var, 1e-8);
    ASSERT_GT(ref.s.sxx, 1e-3);
    std::printf("  whole map: sigma_h^2 %.4g (vertices) %.4g (continuous) %.4g (gaussian); slope cov (%.4g, %.4g, %.4g) "
                "(vertices) (%.4g, %.4g, %.4g) (continuous) (%.4g, %.4g, %.4g) (gaussian)\n",
                ref.var, ref_c.var, gw.var, ref.s.sxx, ref.s.syy, ref.s.sxy, ref_c.s.sxx, ref_c.s.syy, ref_c.s.sxy,
                gw.s.sxx, gw.s.syy, gw.s.sxy);
    struct Tol {
        double texels;
        Errors c, v;  // bounds against the continuous and the vertex reference (max only)
    };
    // footprint (texels), then |dmean| / sigma_h, |dvar| / sigma_h^2, |dslope mean| / sd, |dcov| / var
    const Tol tols[] = {
        {16, {0.20, 0.45, 0.18, 0.80}, {0.20, 0.45, 0.20, 1.00}},
        {32, {0.10, 0.30, 0.05, 0.45}, {0.11, 0.30, 0.05, 0.65}},
        {64, {0.035, 0.11, 0.025, 0.28}, {0.035, 0.10, 0.025, 0.50}},
        {128, {0.02, 0.04, 0.005, 0.15}, {0.022, 0.02, 0.005, 0.38}},
        {512, {0.003, 0.02, 0.001, 0.12}, {0.008, 0.003, 0.001, 0.35}},
    };
    for (const Tol &t : tols) {
        const Errors ec = compare(cont, gauss, ref_c, t.texels / tile_texels, 7);
        const Errors ev = compare(exact, gauss, ref, t.texels / tile_texels, 7);
        const Errors ee = compare(cont, exact, ref_c, t.texels / tile_texels, 7);
        print("gaussian - continuous", t.texels, ec);
        print("gaussian - vertices", t.texels, ev);
        print("vertices - continuous", t.texels, ee);
        EXPECT_LT(ec.mean, t.c.mean) << t.texels;
        EXPECT_LT(ec.var, t.c.var) << t.texels;
        EXPECT_LT(ec.smean, t.c.smean) << t.texels;
        EXPECT_LT(ec.scov, t.c.scov) << t.texels;
        EXPECT_LT(ev.mean, t.v.mean) << t.texels;
        EXPECT_LT(ev.var, t.v.var) << t.texels;
        EXPECT_LT(ev.smean, t.v.smean) << t.texels;
        EXPECT_LT(ev.scov, t.v.scov) << t.texels;
    }
    // The transfer matters: without it (h = offset + scale f) the statistics are far off.
    const SlopeSource plain = source("", "");
    const Stats p = stats(plain, whole);
    std::printf("  whole map, untransferred f: mean %.6g (g(f): %.6g) var %.4g cov (%.4g, %.4g, %.4g)\n", p.mean,
                ref.mean, p.var, p.s.sxx, p.s.syy, p.s.sxy);
    EXPECT_GT(std::abs(p.mean - ref.mean), 0.3 * std::sqrt(ref.var));
    EXPECT_GT(std::abs(p.var - ref.var), 0.3 * ref.var);
}

// At a point footprint (level 0, a texel centre) the height variance is faded to 0
// (MipMap::magnified_variance), so heights reduce to g(f_bar). g(bilinear f) is bilinear g(f) only
// where g is linear over the cell's values, so the slope check is on cells whose corners and
// f_bar +- 6 sigma_f (sigma_f: the spread of f over the cell) lie inside one linear piece g = a + b f:
// there both filters give the statistics of a + b f exactly (mean g(f_bar), variance b^2 var_f,
// slopes b s_f), the exact one up to the float rounding of its world heights (offset + scale
// g(f) ~ 0.1: ulp 7.5e-9, i.e. ~1e-5 per unit uv in a cell slope, which matters for the tiny
// in-cell slope variances). Across a kink only the means are bounded (g is Lipschitz).
TEST(HeightTransfer, PointFootprintsReduceToGAtThePoint) {
    const SlopeSource exact = source(kMoss, "exact", "none"), gauss = source(kMoss, "gaussian", "none");
    const GeneratedMap g = gen_map();
    // f itself in map units (no rounding at an offset): f_bar, sigma_f and f's slopes per unit uv.
    const Heightfield f_field(g.height, 1.f, 0.f);
    const SlopeSource fsrc(f_field, kTiling, kTiling, SlopeSource::Filter::None);
    const Ramp moss = parse_ramp(props(std::string(R"({"t": )") + kMoss + "}"), "t", 1);
    const std::vector<double> &xs = moss.x();
    auto piece = [&](double f) { return int(std::upper_bound(xs.begin(), xs.end(), f) - xs.begin()); };
    const double ds = 4 * 7.5e-9 * 256 * kTiling;  // slope rounding of the exact pyramid, per unit uv
    int linear_cells = 0, kinked_cells = 0;
    for (int j = 0; j < 256; j += 3)
        for (int i = 0; i < 256; i += 5) {
            const double c[4] = {g.height.wrapped(i, j), g.height.wrapped(i + 1, j), g.height.wrapped(i, j + 1),
                                 g.height.wrapped(i + 1, j + 1)};
            // Texel (i, j) centre of one tile (tiling 2: the first tile is uv [0, 0.5]).
            const ShadingContext ctx = at((i + 0.5) / 256.0 / kTiling, (j + 0.5) / 256.0 / kTiling, 0.0);
            const Stats a = stats(exact, ctx), b = stats(gauss, ctx), f = stats(fsrc, ctx);
            // A zero footprint sees no height variance (MipMap::magnified_variance); the cell's own
            // spread (exact for its bilinear patch) still decides which cells are safely linear.
            const double f_bar = f.mean;
            const double cm[4] = {c[0] - f_bar, c[1] - f_bar, c[2] - f_bar, c[3] - f_bar};
            const double cell_var = (cm[0] * cm[0] + cm[1] * cm[1] + cm[2] * cm[2] + cm[3] * cm[3]) / 9 +
                                    (cm[0] * cm[1] + cm[0] * cm[2] + cm[1] * cm[3] + cm[2] * cm[3]) / 9 +
                                    (cm[0] * cm[3] + cm[1] * cm[2]) / 18;
            const double sf = std::sqrt(std::max(0.0, cell_var));
            EXPECT_EQ(f.var, 0.0);
            EXPECT_NEAR(f_bar, (c[0] + c[1] + c[2] + c[3]) / 4, 1e-7);
            const int p = piece(c[0]);
            bool linear = piece(f_bar - 6 * sf) == p && piece(f_bar + 6 * sf) == p;
            for (double v : c) linear = linear && piece(v) == p;
            double gb, k;
            moss.eval(f_bar, &gb);
            const double h_point = kOffset + kScale * gb;
            if (linear) {
                ++linear_cells;
                moss.derivative(f_bar, &k);
                const double kw = kScale * k;  // dh/df, world units per map unit
                EXPECT_NEAR(a.mean, h_point, 2e-8);
                EXPECT_NEAR(b.mean, h_point, 1e-9);
                EXPECT_EQ(a.var, 0.0);  // zero footprint: magnification fades the variance to 0
                EXPECT_EQ(b.var, 0.0);
                // Per-axis: mean kw s_f, variance kw^2 var(s_f).
                const double mf[2] = {f.s.mx, f.s.my}, vf[2] = {f.s.sxx, f.s.syy};
                const double ma[2] = {a.s.mx, a.s.my}, mb[2] = {b.s.mx, b.s.my};
                const double va[2] = {a.s.sxx, a.s.syy}, vb[2] = {b.s.sxx, b.s.syy};
                // The Gaussian's tails beyond 6 sigma_f (mass 2e-9) reach the neighbouring pieces.
                const double tail = 2e-9 * kScale * kSteepest;
                for (int ax = 0; ax < 2; ++ax) {
                    const double m = kw * mf[ax], v = kw * kw * vf[ax], e2 = mf[ax] * mf[ax] + vf[ax];
                    EXPECT_NEAR(ma[ax], m, 1e-5 * std::abs(m) + 2 * ds);
                    EXPECT_NEAR(mb[ax], m, 1e-5 * std::abs(m) + tail * std::abs(mf[ax]) + 1e-12);
                    EXPECT_NEAR(va[ax], v, 1e-3 * v + 4 * std::sqrt(v) * ds + ds * ds);
                    // The moments are floats: E[x^2] - E[x]^2 loses ~1e-7 of E[x^2] = m^2 + v.
                    EXPECT_NEAR(vb[ax], v, 1e-4 * v + 1e-6 * (m * m + v) + tail * kSteepest * kScale * e2);
                }
                EXPECT_NEAR(b.s.sxy, kw * kw * f.s.sxy,
                            1e-6 * (std::abs(mb[0] * mb[1]) + kw * kw * std::sqrt(vf[0] * vf[1])) +
                                tail * kSteepest * kScale * std::sqrt((mf[0] * mf[0] + vf[0]) * (mf[1] * mf[1] + vf[1])));
            } else {
                ++kinked_cells;
                // |h - g(f_bar)| <= scale max|g'| (cell range of f + 6 sigma_f): both filters
                // average g over values within that reach of f_bar (the Gaussian's tails beyond
                // 6 sigma_f are negligible).
                const double range = *std::max_element(c, c + 4) - *std::min_element(c, c + 4) + 6 * sf;
                EXPECT_LE(std::abs(a.mean - h_point), kScale * kSteepest * range + 2e-8);
                EXPECT_LE(std::abs(b.mean - h_point), kScale * kSteepest * range + 1e-9);
            }
        }
    std::printf("  %d cells inside one linear piece of g, %d across a kink\n", linear_cells, kinked_cells);
    EXPECT_GT(linear_cells, 500);
    EXPECT_GT(kinked_cells, 100);
}

// g = identity over the map's range (Ramp is constant beyond its ends: the stops reach far past
// f's +- 0.06) reproduces the untransferred statistics, exact and Gaussian alike.
TEST(HeightTransfer, IdentityTransferGivesTheUntransferredStatistics) {
    // Offset 0: with an offset the untransferred reference's float world heights round at
    // ulp(offset), which is the reference's imprecision, not the filter's (the Gaussian filter
    // works on f in map units and adds the offset in double).
    const std::string id = "[[-1, -1], [1, 1]]";
    const SlopeSource plain = source("", "", "trilinear", 0.f), exact = source(id, "exact", "trilinear", 0.f),
                      gauss = source(id, "gaussian", "trilinear", 0.f);
    PCG32 rng(5);
    for (double texels : {0.0, 1.0, 4.0, 30.0, 200.0, 600.0})
        for (int k = 0; k < 16; ++k) {
            const ShadingContext ctx = at(rng.next_double(), rng.next_double(), texels / (256.0 * kTiling));
            const Stats p = stats(plain, ctx);
            for (const SlopeSource *s : {&exact, &gauss}) {
                const Stats q = stats(*s, ctx);
                const double sd = std::sqrt(std::max(p.s.sxx, 1e-12));
                EXPECT_NEAR(q.mean, p.mean, 1e-6) << texels;
                EXPECT_NEAR(q.var, p.var, 1e-9 + 1e-4 * p.var) << texels;
                EXPECT_NEAR(q.s.mx, p.s.mx, 1e-5 * sd + 1e-6) << texels;
                EXPECT_NEAR(q.s.my, p.s.my, 1e-5 * sd + 1e-6) << texels;
                EXPECT_NEAR(q.s.sxx, p.s.sxx, 1e-4 * p.s.sxx + 1e-9) << texels;
                EXPECT_NEAR(q.s.syy, p.s.syy, 1e-4 * p.s.syy + 1e-9) << texels;
                EXPECT_NEAR(q.s.sxy, p.s.sxy, 1e-4 * std::sqrt(p.s.sxx * p.s.syy) + 1e-9) << texels;
            }
        }
    // moments() (texture space) and the whole-map mean agree too.
    float a[SlopeMomentCount], b[SlopeMomentCount];
    const ShadingContext ctx = at(0.2, 0.7, 10.0 / 512);
    plain.moments(ctx, a);
    gauss.moments(ctx, b);
    for (int c = 0; c < SlopeMomentCount; ++c) EXPECT_NEAR(b[c], a[c], 1e-4 * std::abs(a[c]) + 1e-6) << c;
    const SlopeGaussian ma = plain.mean_over_map(), mb = gauss.mean_over_map();
    EXPECT_NEAR(mb.sxx, ma.sxx, 1e-4 * ma.sxx);
    EXPECT_NEAR(mb.mx, ma.mx, 1e-6);
    EXPECT_NE(gauss.to_string().find("gaussian transfer"), std::string::npos);
}

TEST(HeightTransfer, ErrorsNameTheKey) {
    // A transfer with three-channel values.
    const std::string bad_ch = heightmap_block(R"([[0, [0.1, 0.2, 0.3]], [1, 1]])");
    std::string e = error_of(R"({"heightmap": )" + bad_ch + "}");
    EXPECT_NE(e.find("transfer"), std::string::npos) << e;
    EXPECT_NE(e.find("1 numbers"), std::string::npos) << e;
    // transfer_filter without a transfer in the heightmap.
    e = error_of(R"({"heightmap": )" + heightmap_block("") + R"(, "transfer_filter": "gaussian"})");
    EXPECT_NE(e.find("transfer_filter"), std::string::npos) << e;
    EXPECT_NE(e.find("\"transfer\""), std::string::npos) << e;
    // An unknown transfer_filter value.
    e = error_of(R"({"heightmap": )" + heightmap_block(kMoss) + R"(, "transfer_filter": "box"})");
    EXPECT_NE(e.find("transfer_filter"), std::string::npos) << e;
    EXPECT_NE(e.find("\"box\""), std::string::npos) << e;
    // transfer_filter with constant statistics.
    e = error_of(R"({"covariance": [0.1, 0.1, 0], "transfer_filter": "gaussian"})");
    EXPECT_NE(e.find("transfer_filter"), std::string::npos) << e;
    // A bad transfer in a shape's displacement block is located too.
    try {
        parse_displacement(props(heightmap_block(R"([[0, 1], [0, 2]])")), 0);
        ADD_FAILURE() << "no error";
    } catch (const MesoError &x) {
        EXPECT_NE(std::string(x.what()).find("transfer"), std::string::npos) << x.what();
    }
}


// §7 "displaced geometry uses g-bar": transfer_downsampled's vertex = E[g] under the block's
// Gaussian statistics of f. Checked against the exact block average of g(f) (the box-downsampled
// transferred map, an independent path): at factor 1 they agree exactly; at coarse factors the
// Gaussian stand-in for the block's histogram of f is the only approximation (measured below).
TEST(HeightTransfer, GBarDownsamplingMatchesTheBlockAverageOfGOfF) {
    const GeneratedMap m = gen_map();
    Ramp g = parse_ramp(props(std::string(R"({"t": )") + kMoss + "}"), "t", 1);
    Ramp identity({-1.0, 1.0}, {-1.0, 1.0}, 1);
    HeightMap gf = m.height;
    for (float &v : gf.h) {
        double x;
        g.eval(v, &x);
        v = float(x);
    }
    const Heightfield gf_field(gf, 1.f, 0.f), f_field(m.height, 1.f, 0.f);
    // factor 1: g at each vertex
    const HeightMap one = transfer_downsampled(m.height, g, 1);
    for (size_t k = 0; k < one.h.size(); ++k) ASSERT_NEAR(one.h[k], gf.h[k], 1e-6f);
    // identity g: the box-downsampled f
    const HeightMap id8 = transfer_downsampled(m.height, identity, 8), box8 = f_field.box_downsampled(8);
    for (size_t k = 0; k < id8.h.size(); ++k) ASSERT_NEAR(id8.h[k], box8.h[k], 1e-6f);
    // coarse factors: |g-bar - mean of g(f)| relative to the range of g (0.012)
    for (int factor : {8, 32, 128}) {
        const HeightMap gbar = transfer_downsampled(m.height, g, factor), exact = gf_field.box_downsampled(factor);
        double worst = 0, rms = 0, naive_rms = 0;
        const HeightMap fbox = f_field.box_downsampled(factor);
        for (size_t k = 0; k < gbar.h.size(); ++k) {
            const double e = std::abs(double(gbar.h[k]) - exact.h[k]);
            worst = std::max(worst, e);
            rms += e * e;
            double gn;
            g.eval(fbox.h[k], &gn);  // g of the mean f: what a naive coarse level would displace by
            naive_rms += (gn - exact.h[k]) * (gn - exact.h[k]);
        }
        rms = std::sqrt(rms / gbar.h.size());
        naive_rms = std::sqrt(naive_rms / gbar.h.size());
        std::printf("  g-bar x%d: max error %.2e, rms %.2e (g of the mean f: rms %.2e), g range 0.012\n", factor, worst,
                    rms, naive_rms);
        EXPECT_LT(rms, 0.5 * naive_rms) << factor;  // g-bar beats g(f-bar) clearly
        EXPECT_LT(worst, 0.12 * 0.012) << factor;   // within 12% of g's range everywhere
    }
    EXPECT_THROW(transfer_downsampled(m.height, g, 3), MesoError);
}

TEST(HeightTransfer, LodLevelsDisplaceByGBar) {
    auto scene_json = [](const std::string &lod) {
        return std::string(R"({"camera": {"type": "perspective", "origin": [0, 0, 3], "target": [0, 0, 0], "up": [0, 1, 0],
            "fov": 30, "width": 8, "height": 8},
          "shapes": [{"type": "rectangle", "material": {"type": "diffuse"},
                      "displacement": )") + heightmap_block(kMoss).substr(0, heightmap_block(kMoss).size() - 1) +
               R"(, "mode": "shell"}, "lod": )" + lod + "}]}";
    };
    auto s = meso::test::load_json_scene("lod_gbar.json", scene_json(R"({"factors": [1, 8], "transfer_filter": "gaussian"})"));
    ASSERT_EQ(s->shapes.size(), 2u);
    const auto *level = dynamic_cast<const ShellShape *>(s->shapes[1].get());
    ASSERT_NE(level, nullptr);
    const GeneratedMap m = gen_map();
    Ramp g = parse_ramp(props(std::string(R"({"t": )") + kMoss + "}"), "t", 1);
    const HeightMap gbar = transfer_downsampled(m.height, g, 8);
    const Heightfield &f = *level->displacement().field;
    ASSERT_EQ(f.width(), 32);
    for (int j = 0; j < 32; j += 5)
        for (int i = 0; i < 32; i += 3) EXPECT_NEAR(f.vertex(i, j), kOffset + kScale * gbar.at(i, j), 1e-5f);
    // errors name the key
    for (const char *bad : {R"({"factors": [1, 8], "transfer_filter": "mean"})",
                            R"({"factors": [1, 8], "transfer_filter": "gaussian", "same_model": true})"}) {
        try {
            meso::test::load_json_scene("lod_gbar_bad.json", scene_json(bad));
            ADD_FAILURE() << bad;
        } catch (const MesoError &e) {
            EXPECT_NE(std::string(e.what()).find("lod.transfer_filter"), std::string::npos) << e.what();
        }
    }
}
