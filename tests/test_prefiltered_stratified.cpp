// The `prefiltered` material's stratified node-set estimator ("estimator": "stratified";
// prefilter/multilobe_brdf.h, "Stratified node-set estimator"), on the tiny model of
// prefiltered_test_util.h: f_S and pdf_S average over the set's uniform to the exact eval and pdf
// (exactly, by the breakpoints of the piecewise-constant estimate), the sampler given a set has
// density pdf_S (χ²) and weight f_S / pdf_S, and the material's albedo with a random u_eval per
// sample equals the exact sampler's. The mean image of an MIS-lit render is checked in
// test_prefiltered_stochastic.cpp (AreaLitRenderMatchesTheQuadrature, both estimators).

#include <gtest/gtest.h>
#include <algorithm>
#include <cmath>
#include <memory>
#include <string>
#include <vector>
#include <fmt/format.h>
#include "bsdf/chi2.h"
#include "material_test_util.h"
#include "prefilter/patch_ndf.h"
#include "sampling/rng.h"
#include "prefiltered_test_util.h"

using meso::test::dir_deg;
using namespace meso::test::pf;  // also meso, meso::prefilter, make_material, fs

namespace {

const char *kGlossy = R"({"type":"conductor","material":"Au","alpha":0.2})";
const char *kPlastic = R"({"type":"plastic","alpha":0.1,"diffuse_reflectance":0.5})";

/// Some of the tiny model's fitted patch NDFs (eq. 4 fits of a real heightfield), both levels.
std::vector<const PatchNdf *> patches(size_t step) {
    std::vector<const PatchNdf *> r;
    for (int F : {2, 4}) {
        const PrefilteredLevel *L = tiny_model().model.level_for_factor(F);
        for (size_t p = 0; p < L->ndf.size(); p += step) r.push_back(&L->ndf[p]);
    }
    return r;
}

/// The BSDF (f_S, pdf_S) of one fixed node set S(u_set) as a Material, for the χ² test.
class FixedSet final : public Material {
public:
    FixedSet(const MultiLobeBrdf &f, double u_set, int m) : m_f(f), m_u(u_set), m_m(m) {}
    Spectrum eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        return m_f.eval_pdf_stratified(ctx, wo, wi, m_u, m_m, nullptr);
    }
    float pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        float p = 0.f;
        m_f.eval_pdf_stratified(ctx, wo, wi, m_u, m_m, &p);
        return p;
    }
    bool sample(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, BSDFSample &out) const override {
        return m_f.sample_stratified(ctx, wo, m_u, m_m, u_lobe, u, out);
    }
    uint32_t flags() const override { return m_f.flags(); }
    bool is_reciprocal() const override { return false; }
    std::string to_string() const override { return "FixedSet"; }

private:
    const MultiLobeBrdf &m_f;
    double m_u;
    int m_m;
};

}  // namespace

// E_u[f_S] = eval and E_u[pdf_S] = pdf, exactly: the set S(u) changes only where one of its m
// positions (u + j) / m crosses a node's boundary in the cumulative choice, so the mean over
// u ∈ [0, 1) is the sum over those intervals of (length) x (value at the midpoint). Glossy
// conductor, rough plastic (two base lobes) and Lambertian bases, both weightings, m = 1, 3, 8,
// grazing directions included.
TEST(PrefilteredStratified, SetEstimateAveragesToTheExactEvalAndPdf) {
    const ShadingContext ctx;
    const std::vector<Vec3> wos = {dir_deg(0, 0), dir_deg(40, 20), dir_deg(80, 200), dir_deg(89.5, 300)};
    const std::vector<Vec3> wis = {dir_deg(10, 180), dir_deg(55, 40), dir_deg(89.5, 10)};
    int checked = 0, nonzero = 0;
    double worst = 0.0;
    for (const char *base_json : {kBase, kGlossy, kPlastic})
        for (bool projected : {false, true})
            for (const PatchNdf *ndf : patches(9)) {
                QuadratureOptions q;
                q.projected_area = projected;
                MultiLobeBrdf f(make_material(base_json), *ndf, q);
                for (const Vec3 &wo : wos) {
                    double total = 0.0;
                    std::vector<double> cuts;  // node boundaries in [0, 1] of the choice
                    for (const NdfNode &k : f.nodes()) {
                        total += f.node_weight(k, wo);
                        cuts.push_back(total);
                    }
                    ASSERT_GT(total, 0.0);
                    for (int m : {1, 3, 8}) {
                        std::vector<double> br = {0.0, 1.0};
                        for (double c : cuts)
                            for (int j = 0; j < m; ++j)
                                if (const double u = c / total * m - j; u > 0.0 && u < 1.0) br.push_back(u);
                        std::sort(br.begin(), br.end());
                        for (const Vec3 &wi : wis) {
                            float p_exact = 0.f;
                            const Spectrum e = f.eval_pdf(ctx, wo, wi, &p_exact);
                            double mean[3] = {0.0, 0.0, 0.0}, pdf_mean = 0.0;
                            for (size_t b = 0; b + 1 < br.size(); ++b) {
                                const double len = br[b + 1] - br[b];
                                if (!(len > 1e-12)) continue;
                                float p = 0.f;
                                const Spectrum s = f.eval_pdf_stratified(ctx, wo, wi, 0.5 * (br[b] + br[b + 1]), m, &p);
                                for (int c = 0; c < 3; ++c) mean[c] += len * double(s[c]);
                                pdf_mean += len * double(p);
                            }
                            for (int c = 0; c < 3; ++c) {
                                EXPECT_NEAR(mean[c], e[c], 1e-4 * e[c] + 1e-9)
                                    << base_json << (projected ? " projected" : "") << " m " << m << " ch " << c;
                                if (e[c] > 1e-6f) worst = std::max(worst, std::abs(mean[c] / e[c] - 1.0));
                            }
                            EXPECT_NEAR(pdf_mean, p_exact, 1e-4 * p_exact + 1e-9) << base_json << " m " << m;
                            ++checked;
                            if (e.max() > 0.f) ++nonzero;
                        }
                    }
                }
            }
    std::printf("node-set estimate: %d cases (%d nonzero), worst relative error of the mean %.3g\n", checked, nonzero,
                worst);
    EXPECT_GT(nonzero, checked / 2);
}

// Given a set S, sample_stratified's directions have the density pdf_S (χ², Šidák-corrected over
// all cases), its weight is f_S / pdf_S and its pdf is pdf_S at the direction (rel. 5e-3: the
// chosen member's value and pdf come from the base's sample record at the direction in the
// node's frame, before the float rotation to the macro frame; near the horizon that rounding
// moves the glossy base's value by up to 1.1e-3, measured at θo 85°).
TEST(PrefilteredStratified, SamplerOfAFixedSetHasDensityPdfS) {
    const ShadingContext ctx;
    const std::vector<const PatchNdf *> ps = patches(23);
    const double thetas[] = {0.0, 50.0, 85.0};
    const double usets[] = {0.13, 0.71};
    const int ms[] = {1, 4};
    const char *bases[] = {kGlossy, kPlastic};
    const int tests = int(ps.size() * std::size(thetas) * std::size(usets) * std::size(ms) * std::size(bases));
    int idx = 0;
    for (const char *base_json : bases)
        for (const PatchNdf *ndf : ps) {
            MultiLobeBrdf f(make_material(base_json), *ndf);
            for (double th : thetas)
                for (double us : usets)
                    for (int m : ms) {
                        FixedSet set(f, us, m);
                        Chi2Options opt;
                        opt.samples = 40000;
                        opt.rel_tolerance = 5e-3;
                        opt.seed = 300 + uint64_t(idx);
                        opt.test_count = tests;
                        opt.name = fmt::format("stratified_{}", idx++);
                        const Chi2Result r = chi2_material_test(set, ctx, dir_deg(th, 30.0), opt);
                        EXPECT_TRUE(r.passed) << base_json << " θ " << th << " u " << us << " m " << m << ": "
                                              << r.message;
                        EXPECT_EQ(r.invalid, 0u);
                        EXPECT_EQ(r.weight_mismatch, 0u) << "max rel " << r.max_weight_rel_error;
                        EXPECT_EQ(r.pdf_mismatch, 0u) << "max rel " << r.max_pdf_rel_error;
                    }
        }
}

// Energy: with a fresh u_eval per sample the material's sample weights average to the exact
// material's albedo (independent runs, within 4 standard errors), also at grazing ωo and in the
// rotated macro-frame branch (a tilted shading frame over the macro normal).
TEST(PrefilteredStratified, AlbedoEqualsTheExactSamplers) {
    const std::string glossy = fmt::format(R"(,"level":4,"base":{})", kGlossy);
    struct Setup {
        std::string json;
        Vec2 uv;
        bool tilted;
        double theta;
    };
    const std::vector<Setup> setups = {{glossy, {0.3f, 0.6f}, false, 20.0},
                                       {glossy, {0.7f, 0.1f}, true, 60.0},
                                       {glossy, {0.2f, 0.9f}, false, 88.0},
                                       {R"(,"level":2)", {0.9f, 0.2f}, false, 75.0}};
    const int N = 40000;
    int idx = 0;
    for (const Setup &s : setups) {
        auto mat = prefiltered(s.json + R"(,"estimator":"stratified")");
        EXPECT_NE(mat->to_string().find("estimator stratified (8 nodes)"), std::string::npos) << mat->to_string();
        ShadingContext exact;
        exact.uv = s.uv;
        if (s.tilted) {
            exact.frame = Frame::from_normal_tangent(normalize(Vec3(0.3f, -0.2f, 1.f)), Vec3(1.f, 0.f, 0.f));
            exact.n_macro = Vec3(0.f, 0.f, 1.f);
            exact.dpdu_macro = Vec3(1.f, 0.f, 0.f);
        }
        const Vec3 wo = dir_deg(s.theta, 20.0);
        PCG32 rng(4100 + idx), rng2(5100 + idx);
        double ss[3] = {}, ss2[3] = {}, se[3] = {}, se2[3] = {};
        for (int i = 0; i < N; ++i) {
            ShadingContext st = exact;
            st.u_eval = rng.next_float();
            BSDFSample bs, be;
            const float ul = rng.next_float();
            const Vec2 u(rng.next_float(), rng.next_float());
            const bool os = mat->sample(st, wo, ul, u, bs);
            const bool oe = mat->sample(exact, wo, rng2.next_float(), Vec2(rng2.next_float(), rng2.next_float()), be);
            if (os) {
                EXPECT_TRUE(bs.weight.is_finite() && bs.pdf > 0.f && std::isfinite(bs.pdf));
            }
            for (int c = 0; c < 3; ++c) {
                const double xs = os ? double(bs.weight[c]) : 0.0, xe = oe ? double(be.weight[c]) : 0.0;
                ss[c] += xs, ss2[c] += xs * xs, se[c] += xe, se2[c] += xe * xe;
            }
        }
        auto stderr_of = [&](double sum, double sum2) {
            const double m = sum / N;
            return std::sqrt(std::max(0.0, sum2 / N - m * m) / (N - 1));
        };
        for (int c = 0; c < 3; ++c) {
            const double ms = ss[c] / N, me = se[c] / N;
            const double tol = 4.0 * std::hypot(stderr_of(ss[c], ss2[c]), stderr_of(se[c], se2[c]));
            EXPECT_LE(std::abs(ms - me), tol) << idx << " channel " << c;
            if (c == 1)
                std::printf("setup %d (θo %.0f%s): albedo stratified %.5f, exact %.5f (tol %.2e)\n", idx, s.theta,
                            s.tilted ? ", tilted" : "", ms, me, tol);
        }
        ++idx;
    }
}

// A set size out of range names the key.
TEST(PrefilteredStratified, BadNodeCountNamesTheKey) {
    const std::string dir = tiny_model().dir;
    const std::string e = error_of([&] {
        make_material(fmt::format(
            R"({{"type":"prefiltered","model":"{}","level":4,"estimator":"stratified","estimator_nodes":0}})", dir));
    });
    EXPECT_NE(e.find("estimator_nodes"), std::string::npos) << e;
}
