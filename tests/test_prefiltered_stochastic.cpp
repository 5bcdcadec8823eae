// The `prefiltered` material's stochastic one-node estimator ("estimator": "stochastic"), on the
// tiny model of prefiltered_test_util.h.

#include <gtest/gtest.h>
#include "cli_capture.h"
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "geometry/heightfield.h"
#include "geometry/heightmap_gen.h"
#include "geometry/interaction.h"
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

// ------------------------------------------------------------------ (g) the stochastic estimator
//
// "estimator": "stochastic" (prefilter/multilobe_brdf.h, "Stochastic one-node estimator"): the
// one-node estimate of f'_low averages to the exact node sum over u, the one-node sample weights
// average to the exact ones, a path-traced, MIS-lit scene renders the same mean image as with the
// quadrature, nothing changes without ShadingContext::u_eval, and a bad value names the key.

namespace {

const char *kGlossy = R"({"type":"conductor","material":"Au","alpha":0.2})";

/// Some of the tiny model's fitted patch NDFs (eq. 4 fits of a real heightfield), both levels.
std::vector<const PatchNdf *> some_patches() {
    std::vector<const PatchNdf *> r;
    for (int F : {2, 4}) {
        const PrefilteredLevel *L = tiny_model().model.level_for_factor(F);
        for (size_t p = 0; p < L->ndf.size(); p += 7) r.push_back(&L->ndf[p]);
    }
    return r;
}

}  // namespace

// Unbiasedness, exactly: the estimate is piecewise constant in u (one value per node's interval
// of the choice), so its mean over u ∈ [0, 1) is the sum over nodes of (interval length) x (value
// at the interval's midpoint), which must be the exact eval (and Σ P_k pdf_k the exact pdf).
TEST(PrefilteredStochastic, OneNodeEstimateAveragesToTheExactEval) {
    const ShadingContext ctx;
    const std::vector<Vec3> wos = {dir_deg(0, 0), dir_deg(35, 20), dir_deg(70, 200), dir_deg(85, 120),
                                   dir_deg(89.5, 300)};
    const std::vector<Vec3> wis = {dir_deg(10, 180), dir_deg(50, 40), dir_deg(80, 250), dir_deg(89.5, 10)};
    int checked = 0, nonzero = 0;
    double worst = 0.0;
    for (const char *base_json : {kBase, kGlossy})
        for (bool projected : {false, true})
            for (const PatchNdf *ndf : some_patches()) {
                QuadratureOptions q;
                q.projected_area = projected;
                auto base = make_material(base_json);
                MultiLobeBrdf m(base, *ndf, q);
                for (const Vec3 &wo : wos) {
                    double total = 0.0;
                    for (const NdfNode &k : m.nodes()) total += m.node_weight(k, wo);
                    ASSERT_GT(total, 0.0);
                    for (const Vec3 &wi : wis) {
                        float p_exact = 0.f;
                        const Spectrum e = m.eval_pdf(ctx, wo, wi, &p_exact);
                        double mean[3] = {0.0, 0.0, 0.0}, pdf_mix = 0.0, cum = 0.0;
                        for (const NdfNode &k : m.nodes()) {
                            const double w = m.node_weight(k, wo);
                            if (!(w > 0.0)) continue;  // not visible from wo: never chosen
                            const double u = (cum + 0.5 * w) / total;
                            cum += w;
                            MultiLobeBrdf::NodePick pick;
                            ASSERT_TRUE(m.pick_node(wo, u, pick));
                            ASSERT_EQ(pick.node, &k);
                            EXPECT_NEAR(pick.u_rescaled, 0.5, 1e-6);
                            float p = 0.f;
                            const Spectrum s = m.eval_pdf_stochastic(ctx, wo, wi, u, &p);
                            for (int c = 0; c < 3; ++c) mean[c] += w / total * double(s[c]);
                            pdf_mix += w / total * double(p);
                            // the pdf returned is the node's own: the base's in the node frame
                            const Vec3 li = k.frame.to_local(wi);
                            const float pk = li.z > 0.f ? base->pdf(ctx, k.frame.to_local(wo), li) : 0.f;
                            EXPECT_NEAR(p, pk, 1e-6f * pk);
                        }
                        for (int c = 0; c < 3; ++c) {
                            EXPECT_NEAR(mean[c], e[c], 1e-5 * e[c] + 1e-10)
                                << base_json << (projected ? " projected_area" : "") << " channel " << c;
                            if (e[c] > 0.f) worst = std::max(worst, std::abs(mean[c] / e[c] - 1.0));
                        }
                        EXPECT_NEAR(pdf_mix, p_exact, 1e-5 * p_exact + 1e-10);
                        ++checked;
                        if (e.max() > 0.f) ++nonzero;
                    }
                }
            }
    std::printf("one-node estimate: %d (wo, wi) pairs (%d nonzero), worst relative error of the mean %.3g\n",
                checked, nonzero, worst);
    EXPECT_GT(nonzero, checked / 2);
}

// The sampler: the same directions as the exact one (same u), weights T·S·Σ g_k / pdf_k whose
// mean times a test function h equals the exact weights' (paired: E[stochastic − exact | ωi] = 0;
// and against an independent run of the exact sampler), within 4 standard errors. With the
// model's Lambertian base g_k / pdf_k = R for every node, so the one-node weight IS the exact one
// (Σ R); with a glossy base it is not.
TEST(PrefilteredStochastic, SampleWeightsAreUnbiased) {
    struct Setup {
        std::string json;
        Vec2 uv;
        bool tilted;
        double theta;
        bool weights_differ;  ///< glossy base: the one-node weights differ from the exact ones
    };
    const std::string glossy = fmt::format(R"(,"level":4,"base":{})", kGlossy);
    const std::vector<Setup> setups = {
        {R"(,"level":4)", {0.1f, 0.3f}, false, 0.0, false},  {R"(,"level":2)", {0.9f, 0.2f}, false, 88.0, false},
        {R"(,"level":2)", {0.4f, 0.7f}, true, 70.0, false},  {glossy, {0.3f, 0.6f}, false, 20.0, true},
        {glossy, {0.7f, 0.1f}, true, 60.0, true},            {glossy, {0.2f, 0.9f}, false, 85.0, true},
    };
    auto h = [](const Vec3 &w) { return 1.0 + 0.5 * w.x - 0.3 * w.y + double(w.z) * w.z; };
    const int N = 60000;
    int idx = 0;
    for (const Setup &s : setups) {
        auto mat = prefiltered(s.json + R"(,"estimator":"stochastic")");
        ShadingContext exact;
        exact.uv = s.uv;
        if (s.tilted) {  // shading frame of a micro-facet, macro normal (0, 0, 1): the rotated branch
            exact.frame = Frame::from_normal_tangent(normalize(Vec3(0.3f, -0.2f, 1.f)), Vec3(1.f, 0.f, 0.f));
            exact.n_macro = Vec3(0.f, 0.f, 1.f);
            exact.dpdu_macro = Vec3(1.f, 0.f, 0.f);
        }
        ShadingContext stoch = exact;
        stoch.u_eval = 0.5f;  // the integrator's declaration; sample() does not read its value
        const Vec3 wo = dir_deg(s.theta, 20.0);
        PCG32 rng(900 + idx), rng2(1900 + idx);
        double sd[3] = {}, sd2[3] = {}, ss[3] = {}, ss2[3] = {}, se[3] = {}, se2[3] = {};
        int ok = 0, ok_mismatch = 0, dir_mismatch = 0, differ = 0;
        for (int i = 0; i < N; ++i) {
            const float ul = rng.next_float();
            const Vec2 u(rng.next_float(), rng.next_float());
            BSDFSample be, bs, b2;
            const bool oe = mat->sample(exact, wo, ul, u, be), os = mat->sample(stoch, wo, ul, u, bs);
            const bool o2 = mat->sample(exact, wo, rng2.next_float(), Vec2(rng2.next_float(), rng2.next_float()), b2);
            if (oe != os) ++ok_mismatch;
            if (oe && os && !(be.wi.x == bs.wi.x && be.wi.y == bs.wi.y && be.wi.z == bs.wi.z)) ++dir_mismatch;
            if (os) {
                ++ok;
                EXPECT_TRUE(bs.weight.is_finite() && bs.pdf > 0.f && std::isfinite(bs.pdf));
            }
            for (int c = 0; c < 3; ++c) {
                const double xe = oe ? double(be.weight[c]) * h(be.wi) : 0.0;
                const double xs = os ? double(bs.weight[c]) * h(bs.wi) : 0.0;
                const double x2 = o2 ? double(b2.weight[c]) * h(b2.wi) : 0.0;
                const double d = xs - xe;
                sd[c] += d, sd2[c] += d * d, ss[c] += xs, ss2[c] += xs * xs, se[c] += x2, se2[c] += x2 * x2;
                if (c == 1 && std::abs(d) > 1e-6 * std::abs(xe)) ++differ;
            }
        }
        EXPECT_EQ(ok_mismatch, 0) << idx;
        EXPECT_EQ(dir_mismatch, 0) << idx;
        EXPECT_GT(ok, N / 2) << idx;
        if (s.weights_differ) EXPECT_GT(differ, N / 10) << idx;  // not the exact weights
        else EXPECT_EQ(differ, 0) << idx;
        auto stderr_of = [&](double sum, double sum2) {
            const double m = sum / N;
            return std::sqrt(std::max(0.0, sum2 / N - m * m) / (N - 1));
        };
        for (int c = 0; c < 3; ++c) {
            const double md = sd[c] / N, sed = stderr_of(sd[c], sd2[c]);
            const double ms = ss[c] / N, ses = stderr_of(ss[c], ss2[c]);
            const double me = se[c] / N, see = stderr_of(se[c], se2[c]);
            // + 2 float ulps of the mean: with the Lambertian base every one-node weight is the one
            // float Σ R (the base's sample weight R times Σ(wo)), so its rounding does not average
            // out as that of the exact weights (a ratio of two node sums per sample) does.
            EXPECT_LE(std::abs(md), 4.0 * sed + 0x1p-22 * std::abs(ms)) << idx << " channel " << c;
            EXPECT_LE(std::abs(ms - me), 4.0 * std::hypot(ses, see)) << idx << " channel " << c;
            if (c == 1)
                std::printf("setup %d (θo %.0f%s): E[w h] stochastic %.5f ± %.5f, exact (independent) %.5f ± %.5f, "
                            "paired difference %.2e ± %.2e\n",
                            idx, s.theta, s.tilted ? ", tilted" : "", ms, ses, me, see, md, sed);
        }
        ++idx;
    }
}

// Without u_eval (meso material, the χ² tests, the prefilter tools) the stochastic material is the
// quadrature one, bit for bit; with it, eval and pdf stay exact.
TEST(PrefilteredStochastic, ExactWithoutUEval) {
    auto quad = prefiltered(R"(,"level":4,"tiling":3)");
    auto stoch = prefiltered(R"(,"level":4,"tiling":3,"estimator":"stochastic")");
    EXPECT_NE(stoch->to_string().find("estimator stochastic"), std::string::npos) << stoch->to_string();
    EXPECT_NE(quad->to_string().find("estimator quadrature"), std::string::npos) << quad->to_string();
    PCG32 rng(21);
    int differ = 0;
    for (int i = 0; i < 500; ++i) {
        ShadingContext ctx;
        ctx.uv = Vec2(rng.next_float(), rng.next_float());
        if (i % 2) {
            ctx.frame = Frame::from_normal_tangent(normalize(Vec3(0.4f * (rng.next_float() - 0.5f), 0.4f * (rng.next_float() - 0.5f), 1.f)),
                                                   Vec3(1.f, 0.f, 0.f));
            ctx.n_macro = Vec3(0.f, 0.f, 1.f);
            ctx.dpdu_macro = Vec3(1.f, 0.f, 0.f);
        }
        const Vec3 wo = dir_deg(85.0 * rng.next_float(), 360.0 * rng.next_float());
        const Vec3 wi = dir_deg(85.0 * rng.next_float(), 360.0 * rng.next_float());
        float pq = 0.f, ps = 0.f;
        const Spectrum q = quad->eval_pdf(ctx, wo, wi, &pq), s = stoch->eval_pdf(ctx, wo, wi, &ps);
        EXPECT_EQ(pq, ps);
        for (int c = 0; c < 3; ++c) EXPECT_EQ(q[c], s[c]);
        const float ul = rng.next_float();
        const Vec2 u(rng.next_float(), rng.next_float());
        BSDFSample a, b;
        const bool oa = quad->sample(ctx, wo, ul, u, a), ob = stoch->sample(ctx, wo, ul, u, b);
        ASSERT_EQ(oa, ob);
        if (oa) {
            EXPECT_EQ(a.pdf, b.pdf);
            for (int c = 0; c < 3; ++c) EXPECT_EQ(a.weight[c], b.weight[c]);
        }
        // with u_eval: eval and pdf are still the exact ones, eval_pdf is the one-node estimate
        ShadingContext with = ctx;
        with.u_eval = rng.next_float();
        for (int c = 0; c < 3; ++c) EXPECT_EQ(stoch->eval(with, wo, wi)[c], q[c]);
        EXPECT_EQ(stoch->pdf(with, wo, wi), pq);
        const Spectrum one = stoch->eval_pdf(with, wo, wi, &ps);
        if (one.r != q.r || one.g != q.g || one.b != q.b) ++differ;
    }
    EXPECT_GT(differ, 100);
}

// A path-traced scene lit by an area light (next-event estimation MIS-weighted against BSDF
// sampling: the per-node pdfs on both sides) through a LoD chain whose level is the prefiltered
// material on h_low (the rotated macro-frame branch): the mean image with the stochastic
// estimator equals the quadrature's within 4 standard errors, estimated from the per-pixel
// differences of two independent renders per estimator. The cost per sample is printed.
TEST(PrefilteredStochastic, AreaLitRenderMatchesTheQuadrature) {
    tiny_model();
    // the level's material with a glossy base (the model's is Lambertian, where the one-node
    // weights are the exact ones)
    auto scene_for = [&](const std::string &estimator) {
        std::string text = lod_scene(fmt::format(
            R"({{"factors": [1, 4], "model": "model", "materials": [{{"type": "diffuse", "reflectance": 0.8}},
                {{"type": "prefiltered", "model": "model", "level": 4, "tiling": 16, "estimator": "{}", "base": {}}}]}})",
            estimator, kGlossy));
        // an area light beside the view, facing the plane, instead of the directional light
        const std::string dl = R"({"type": "directional", "direction": [0.3, 0.5, -1], "irradiance": 2})";
        const size_t at = text.find(dl);
        EXPECT_NE(at, std::string::npos);
        text.replace(at, dl.size(), "");
        const std::string shapes = R"("shapes": [)";
        text.replace(text.find(shapes), shapes.size(),
                     shapes + R"({"type": "rectangle", "emitter": {"type": "area", "radiance": 20},
                                  "to_world": {"scale": 0.7, "rotate": {"axis": [0, 1, 0], "angle": 236},
                                               "translate": [3, 0, 2]}}, )");
        auto s = load_scene(write_scene("stochastic_" + estimator + ".json", text), {});
        s->build();
        return s;
    };
    auto quad = scene_for("quadrature"), stoch = scene_for("stochastic");
    ASSERT_EQ(stoch->shapes.size(), 3u);
    EXPECT_NE(stoch->shapes[2]->material->to_string().find("estimator stochastic"), std::string::npos)
        << stoch->shapes[2]->material->to_string();
    // the lod block passes "estimator" to the model's levels
    auto via_lod = load_scene(
        write_scene("stochastic_lod.json", lod_scene(R"({"factors": [1, 4], "model": "model", "estimator": "stochastic"})")),
        {});
    ASSERT_EQ(via_lod->shapes.size(), 2u);
    EXPECT_NE(via_lod->shapes[1]->material->to_string().find("estimator stochastic"), std::string::npos)
        << via_lod->shapes[1]->material->to_string();
    const int spp = 32;
    struct Pair {
        RenderResult a, b;
    };
    auto two = [&](const Scene &s, uint64_t seed) { return Pair{meso::test::render_scene(s, spp, 0, seed), meso::test::render_scene(s, spp, 0, seed + 1)}; };
    const Pair q = two(*quad, 11);
    for (const char *est : {"stochastic", "stratified"}) {
    std::unique_ptr<Scene> fresh = std::string(est) == "stochastic" ? nullptr : scene_for(est);
    const Pair st = two(fresh ? *fresh : *stoch, 21);
    for (const RenderResult *r : {&q.a, &q.b, &st.a, &st.b}) EXPECT_EQ(r->nan_count, 0);
    const Image &img = q.a.image;
    const double n = double(img.width) * img.height;
    for (int c = 0; c < 3; ++c) {
        // mean of (a + b) / 2 and its variance Σ_p (a_p − b_p)² / (4 n²) (pixels independent)
        auto stats = [&](const Pair &p, double &mean, double &var, double &pixel_var) {
            double sum = 0.0, d2 = 0.0;
            for (int y = 0; y < img.height; ++y)
                for (int x = 0; x < img.width; ++x) {
                    const double a = p.a.image.at(x, y, c), b = p.b.image.at(x, y, c);
                    sum += 0.5 * (a + b);
                    d2 += (a - b) * (a - b);
                }
            mean = sum / n;
            var = d2 / (4.0 * n * n);
            pixel_var = d2 / (2.0 * n);  // per-pixel variance of one render at spp samples
        };
        double mq, vq, pq, ms, vs, ps;
        stats(q, mq, vq, pq);
        stats(st, ms, vs, ps);
        const double tol = 4.0 * std::sqrt(vq + vs);
        EXPECT_GT(mq, 0.01) << "the area light reaches the plane";
        EXPECT_LE(std::abs(ms - mq), tol) << est << " channel " << c;
        const double tq = 0.5 * (q.a.wall_s + q.b.wall_s), ts = 0.5 * (st.a.wall_s + st.b.wall_s);
        if (c == 1)
            std::printf("area-lit render %dx%d, %d spp: mean quadrature %.5f ± %.5f, %s %.5f ± %.5f "
                        "(|diff| %.2e, tol %.2e); per-pixel variance %.3g vs %.3g (x%.2f); time %.3f s vs %.3f s "
                        "(x%.2f faster); efficiency (1 / (var · time)) x%.2f\n",
                        img.width, img.height, spp, mq, std::sqrt(vq), est, ms, std::sqrt(vs), std::abs(ms - mq), tol, pq,
                        ps, ps / pq, tq, ts, tq / ts, (pq * tq) / (ps * ts));
    }
    }  // estimators
}

TEST(PrefilteredStochastic, BadEstimatorNamesTheKey) {
    const std::string dir = tiny_model().dir;
    std::string e = error_of([&] {
        make_material(fmt::format(R"({{"type":"prefiltered","model":"{}","level":4,"estimator":"exact"}})", dir));
    });
    EXPECT_NE(e.find("material.estimator: expected \"quadrature\", \"stochastic\" or \"stratified\", got \"exact\""), std::string::npos)
        << e;
    e = error_of([&] {
        load_scene(write_scene("bad_est1.json", lod_scene(R"({"factors": [1, 4], "model": "model", "estimator": "fast"})")), {});
    });
    EXPECT_NE(e.find("shapes[0].lod.estimator: expected \"quadrature\", \"stochastic\" or \"stratified\", got \"fast\""),
              std::string::npos)
        << e;
    e = error_of([&] {
        load_scene(write_scene("bad_est2.json", lod_scene(R"({"factors": [1, 4], "estimator": "stochastic"})")), {});
    });
    EXPECT_NE(e.find("shapes[0].lod.estimator: only applies with a prefiltered \"model\""), std::string::npos) << e;
}
