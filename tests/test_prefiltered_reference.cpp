// The `prefiltered` material's fast paths (issue 21 item 3: a shading sample at most ~1.5x the
// base material's) against the straightforward formulas they replaced, kept here as the
// reference: the S lookup's float, atan2-free square mapping (prefilter/table_lookup.cpp)
// against hemisphere_to_square (double atan2); eval_S / eval_T against the quadrilinear /
// bilinear sums through Image::rgb with modulo wrapping; the node choice of the stochastic
// estimator (a vectorised, two-level running sum) against a plain sequential scan in double;
// and the material's eval, eval_pdf, pdf and sample (quadrature and stochastic) against
// T(x) S(ωi, ωo) Σ_k c_k base(F_k ωo, F_k ωi) summed node by node. Random texels and directions,
// grazing ones (θ up to 89.95°) included; agreement to 1e-4 relative (float round-off).
#include <gtest/gtest.h>
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>
#include <fmt/format.h>
#include "material_test_util.h"
#include "prefilter/model.h"
#include "prefiltered_test_util.h"
#include "sampling/rng.h"

using meso::test::dir_deg;
using namespace meso::test::pf;  // also meso, meso::prefilter, make_material

namespace {

const char *kGlossyBase = R"({"type":"conductor","material":"Au","distribution":"beckmann","alpha":0.2})";

// ------------------------------------------------------------------ the pre-optimisation formulas

void axis_lerp_ref(float s, int N, int &i0, int &i1, float &t) {
    if (N < 2) {
        i0 = i1 = 0, t = 0.f;
        return;
    }
    // between the bin centres, and linearly extrapolated over the outer half bins (session 33)
    const float x = std::clamp(s * float(N) - 0.5f, -0.5f, float(N) - 0.5f);
    i0 = std::clamp(int(std::floor(x)), 0, N - 2);
    i1 = i0 + 1;
    t = x - float(i0);
}

/// ScalingTables::eval_S as it was: the exact square mapping, 16 texels through Image::rgb.
Spectrum eval_S_ref(const ScalingTables &t, Vec3 wi, Vec3 wo) {
    const int N = t.N;
    const Vec2 si = hemisphere_to_square(wi), so = hemisphere_to_square(wo);
    int ix[2], iy[2], ox[2], oy[2];
    float tix, tiy, tox, toy;
    axis_lerp_ref(si.x, N, ix[0], ix[1], tix);
    axis_lerp_ref(si.y, N, iy[0], iy[1], tiy);
    axis_lerp_ref(so.x, N, ox[0], ox[1], tox);
    axis_lerp_ref(so.y, N, oy[0], oy[1], toy);
    const float wix[2] = {1.f - tix, tix}, wiy[2] = {1.f - tiy, tiy}, wox[2] = {1.f - tox, tox},
                woy[2] = {1.f - toy, toy};
    Spectrum s(0.f);
    for (int a = 0; a < 2; ++a)
        for (int b = 0; b < 2; ++b)
            for (int c = 0; c < 2; ++c)
                for (int d = 0; d < 2; ++d) {
                    const float w = wox[a] * woy[b] * wix[c] * wiy[d];
                    if (w != 0.f) s += t.S.rgb(ox[a] * N + ix[c], oy[b] * N + iy[d]) * w;
                }
    return Spectrum(std::max(s.r, 0.f), std::max(s.g, 0.f), std::max(s.b, 0.f));
}

/// ScalingTables::eval_T as it was (modulo wrapping).
Spectrum eval_T_ref(const ScalingTables &t, Vec2 x) {
    const int M = t.M;
    auto wrapi = [&](int i) { return ((i % M) + M) % M; };
    const double u = double(x.x) - std::floor(double(x.x)), v = double(x.y) - std::floor(double(x.y));
    const double fx = u * M - 0.5, fy = v * M - 0.5;
    const int x0 = int(std::floor(fx)), y0 = int(std::floor(fy));
    const float tx = float(fx - x0), ty = float(fy - y0);
    const Spectrum a = t.T.rgb(wrapi(x0), wrapi(y0)), b = t.T.rgb(wrapi(x0 + 1), wrapi(y0));
    const Spectrum c = t.T.rgb(wrapi(x0), wrapi(y0 + 1)), d = t.T.rgb(wrapi(x0 + 1), wrapi(y0 + 1));
    return (a * (1.f - tx) + b * tx) * (1.f - ty) + (c * (1.f - tx) + d * tx) * ty;
}

/// f'_low node by node (eq. 5 / 11 by the quadrature), in double: value, mixture pdf, Σ(wo).
struct NodeSum {
    double f[3] = {0, 0, 0}, pdf = 0, total = 0;
};
NodeSum node_sum_ref(const MultiLobeBrdf &m, const Material &base, const ShadingContext &ctx, Vec3 wo, Vec3 wi) {
    NodeSum r;
    double psum = 0.0;
    for (const NdfNode &k : m.nodes()) {
        const double w = m.node_weight(k, wo);
        if (!(w > 0.0)) continue;
        r.total += w;
        const Vec3 lo = k.frame.to_local(wo), li = k.frame.to_local(wi);
        if (!(li.z > 0.f)) continue;
        const Spectrum f = base.eval(ctx, lo, li);
        for (int c = 0; c < 3; ++c) r.f[c] += w * f[c];
        psum += w * double(base.pdf(ctx, lo, li));
    }
    r.pdf = r.total > 0.0 ? psum / r.total : 0.0;
    return r;
}

/// The node of the stochastic choice by a plain sequential running sum in double (the choice
/// as it was): the first visible k with u Σ < Σ_{j<=k} w_j; nullptr when none faces wo.
const NdfNode *pick_ref(const MultiLobeBrdf &m, Vec3 wo, double u, double *u_rescaled, double *total) {
    double sum = 0.0;
    for (const NdfNode &k : m.nodes()) sum += m.node_weight(k, wo);
    *total = sum;
    if (!(sum > 0.0)) return nullptr;
    const double target = u * sum;
    double cum = 0.0;
    const NdfNode *last = nullptr;
    for (const NdfNode &k : m.nodes()) {
        const double w = m.node_weight(k, wo);
        if (!(w > 0.0)) continue;
        last = &k;
        if (target < cum + w) {
            *u_rescaled = (target - cum) / w;
            return &k;
        }
        cum += w;
    }
    *u_rescaled = 1.0;
    return last;
}

/// Directions over the hemisphere with many grazing ones (θ up to 89.95°) and some on the axes
/// and the concentric map's diagonals.
Vec3 test_direction(PCG32 &rng, int i) {
    const double phi = (i % 7 == 0) ? 45.0 * double(rng.next_u32() % 8) : 360.0 * rng.next_float();
    const double theta = (i % 3 == 0) ? 80.0 + 9.95 * rng.next_float() : 89.0 * rng.next_float();
    return dir_deg(theta, phi);
}

double rel_err(double a, double b) { return std::abs(a - b) / std::max({std::abs(a), std::abs(b), 1e-12}); }

}  // namespace

TEST(PrefilteredReference, SquareMappingMatchesTheExactOne) {
    PCG32 rng(3);
    double worst = 0.0;
    std::vector<Vec3> dirs;
    for (int i = 0; i < 200000; ++i) dirs.push_back(test_direction(rng, i));
    for (int i = 0; i <= 1000; ++i) {  // the pole, the axes, the diagonals, below the horizon (mirrored)
        const double t = 90.0 * i / 1000.0;
        for (double phi : {0.0, 45.0, 90.0, 135.0, 180.0, 225.0, 270.0, 315.0}) dirs.push_back(dir_deg(t, phi));
        dirs.push_back(-dir_deg(t, 33.0));
    }
    dirs.push_back(Vec3(0.f, 0.f, 1.f));
    dirs.push_back(Vec3(1e-30f, -1e-30f, 1.f));
    dirs.push_back(Vec3(3.f, -4.f, 0.5f));  // not normalised: the same square point as normalised
    for (const Vec3 &w : dirs) {
        const Vec2 a = hemisphere_to_square_fast(w), b = hemisphere_to_square(w);
        worst = std::max({worst, double(std::abs(a.x - b.x)), double(std::abs(a.y - b.y))});
    }
    std::printf("square mapping: max |fast - exact| = %.3g over %zu directions\n", worst, dirs.size());
    EXPECT_LT(worst, 1e-6);
    // degenerate input: the square's centre, as hemisphere_to_square
    for (const Vec3 &w : {Vec3(0.f, 0.f, 0.f), Vec3(NAN, 0.f, 1.f), Vec3(INFINITY, 1.f, 1.f)}) {
        const Vec2 a = hemisphere_to_square_fast(w);
        EXPECT_EQ(a.x, 0.5f);
        EXPECT_EQ(a.y, 0.5f);
    }
}

TEST(PrefilteredReference, TableLookupsMatchTheStraightforwardSums) {
    // tables of random (not smooth) contents, several sizes, RGB and grey
    PCG32 rng(8);
    double worst_S = 0.0, worst_T = 0.0;
    for (int N : {1, 2, 5, 15}) {
        for (int channels : {3, 1}) {
            ScalingTables t;
            t.M = N == 1 ? 1 : N - 1;
            t.N = N;
            t.T = Image(t.M, t.M, channels);
            t.S = Image(N * N, N * N, channels);
            for (float &v : t.T.data) v = 0.2f + 2.f * rng.next_float();
            for (float &v : t.S.data) v = 0.2f + 2.f * rng.next_float();
            for (int i = 0; i < 20000; ++i) {
                const Vec3 wi = test_direction(rng, i), wo = test_direction(rng, i + 1);
                const Spectrum a = t.eval_S(wi, wo), b = eval_S_ref(t, wi, wo);
                const Vec2 x(rng.next_float(), rng.next_float());
                const Spectrum ta = t.eval_T(x), tb = eval_T_ref(t, x);
                for (int c = 0; c < 3; ++c) {
                    // S: relative to the table's scale (~1): past the outer centres the lookup
                    // extrapolates (weights -0.5 .. 1.5), so a value can cancel to near 0.
                    const double err_S = std::abs(double(a[c]) - b[c]) / std::max(1.0, std::abs(double(b[c])));
                    worst_S = std::max(worst_S, err_S);
                    worst_T = std::max(worst_T, rel_err(ta[c], tb[c]));
                    ASSERT_LT(err_S, 1e-4) << "N " << N << " channels " << channels;
                    ASSERT_LT(rel_err(ta[c], tb[c]), 1e-6) << "M " << t.M;
                }
            }
        }
    }
    std::printf("table lookups: worst relative difference S %.3g, T %.3g\n", worst_S, worst_T);
}

// The material's eval, eval_pdf, pdf and sample, quadrature and stochastic, against the node
// sums above, on random texels of both levels of the tiny model, with its Lambertian base and a
// glossy one.
TEST(PrefilteredReference, MaterialEqualsTheNodeByNodeFormula) {
    const PrefilteredModel &model = tiny_model().model;
    struct Case {
        int level;
        const char *base;  ///< nullptr: the model's own (Lambertian)
        bool ir;
    };
    const std::vector<Case> cases = {{4, nullptr, true}, {2, nullptr, false}, {4, kGlossyBase, true}, {2, kGlossyBase, false}};
    double worst = 0.0;
    int compared = 0, sampled = 0;
    for (const Case &cs : cases) {
        const std::string base_key = cs.base ? fmt::format(R"(,"base":{})", cs.base) : std::string();
        auto quad = prefiltered(fmt::format(R"(,"level":{}{})", cs.level, base_key));
        auto stoch = prefiltered(fmt::format(R"(,"level":{}{},"estimator":"stochastic")", cs.level, base_key));
        auto base = make_material(cs.base ? cs.base : kBase);
        const PrefilteredLevel *L = model.level_for_factor(cs.level);
        const ScalingTables &tab = cs.ir ? L->ir : L->single;
        SvMultiLobe f(base, L->ndf, L->width(), L->height(), model.quadrature);
        PCG32 rng(100 + cs.level);
        for (int i = 0; i < 3000; ++i) {
            ShadingContext ctx;
            ctx.uv = Vec2(rng.next_float(), rng.next_float());
            const MultiLobeBrdf &m = f.patch(ctx.uv);
            const Vec3 wo = test_direction(rng, i), wi = test_direction(rng, i + 5);
            const Spectrum ts = eval_T_ref(tab, ctx.uv) * eval_S_ref(tab, wi, wo);
            const NodeSum ref = node_sum_ref(m, *base, ctx, wo, wi);
            auto check = [&](double got, double want, const char *what) {
                const double e = std::abs(got - want) / std::max(std::abs(want), 1e-6);
                worst = std::max(worst, e);
                EXPECT_LT(e, 1e-4) << what << " level " << cs.level << " i " << i << ": " << got << " vs " << want;
            };
            float p = 0.f;
            const Spectrum e = quad->eval_pdf(ctx, wo, wi, &p), ev = quad->eval(ctx, wo, wi);
            for (int c = 0; c < 3; ++c) {
                check(e[c], ref.f[c] * ts[c], "eval_pdf value");
                check(ev[c], ref.f[c] * ts[c], "eval");
            }
            check(p, ref.pdf, "eval_pdf pdf");
            check(quad->pdf(ctx, wo, wi), ref.pdf, "pdf");
            // the stochastic one-node estimate for a node chosen by u_eval
            ShadingContext sc = ctx;
            sc.u_eval = rng.next_float();
            double u_resc = 0.0, total = 0.0;
            const NdfNode *k = pick_ref(m, wo, double(sc.u_eval), &u_resc, &total);
            float ps = 0.f;
            const Spectrum es = stoch->eval_pdf(sc, wo, wi, &ps);
            if (!k) {  // no node faces a grazing wo: nothing reflects
                EXPECT_TRUE(es.is_black() && ps == 0.f && e.is_black() && p == 0.f) << i;
                BSDFSample none;
                EXPECT_FALSE(stoch->sample(sc, wo, rng.next_float(), Vec2(0.5f, 0.5f), none));
                continue;
            }
            const Vec3 lo = k->frame.to_local(wo), li = k->frame.to_local(wi);
            const Spectrum g = li.z > 0.f ? base->eval(ctx, lo, li) : Spectrum(0.f);
            const float pk = li.z > 0.f ? base->pdf(ctx, lo, li) : 0.f;
            for (int c = 0; c < 3; ++c) check(es[c], total * g[c] * ts[c], "stochastic eval_pdf value");
            check(ps, pk, "stochastic eval_pdf pdf");
            ++compared;
            // sampling: the quadrature weight is eval / pdf at the returned direction; the
            // stochastic one is T S Σ g_k / pdf_k of the node chosen by u_lobe
            const float ul = rng.next_float();
            const Vec2 u(rng.next_float(), rng.next_float());
            BSDFSample bq, bs;
            if (quad->sample(ctx, wo, ul, u, bq)) {
                const Spectrum tq = eval_T_ref(tab, ctx.uv) * eval_S_ref(tab, bq.wi, wo);
                const NodeSum r = node_sum_ref(m, *base, ctx, wo, bq.wi);
                check(bq.pdf, r.pdf, "quadrature sample pdf");
                for (int c = 0; c < 3; ++c) check(bq.weight[c], r.f[c] * tq[c] / r.pdf, "quadrature sample weight");
                ++sampled;
            }
            if (stoch->sample(sc, wo, ul, u, bs)) {
                const NdfNode *ks = pick_ref(m, wo, double(ul), &u_resc, &total);
                ASSERT_NE(ks, nullptr);
                const Vec3 lis = ks->frame.to_local(bs.wi), los = ks->frame.to_local(wo);
                const Spectrum gs = base->eval(ctx, los, lis);
                const float pks = base->pdf(ctx, los, lis);
                const Spectrum tq = eval_T_ref(tab, ctx.uv) * eval_S_ref(tab, bs.wi, wo);
                check(bs.pdf, pks, "stochastic sample pdf");
                for (int c = 0; c < 3; ++c) check(bs.weight[c], total * gs[c] * tq[c] / pks, "stochastic sample weight");
            }
        }
    }
    std::printf("material vs node-by-node formula: %d (wo, wi) pairs, %d samples, worst relative difference %.3g\n",
                compared, sampled, worst);
    EXPECT_GT(sampled, 6000);
}
