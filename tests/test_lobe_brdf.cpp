// The closed-form per-lobe f'_low (prefilter/lobe_brdf.h, `meso prefilter --flow lobes`): the
// widened roughness against a Monte Carlo of tilted Beckmann slopes, the C and H tables against
// their exact quadratures, χ² of the sampler against the pdf (conductor Beckmann and GGX, diffuse;
// grazing viewers), the κ → ∞ limit (the base itself), the closed form against the dense eq. 5
// quadrature for narrow and wide lobes (the difference is printed: the tables absorb it), white
// energy, extremes, eval_batch against eval, the Lambertian visible form's vectorised sums against
// the header's formula lobe by lobe, and the located errors of unsupported bases.
#include <gtest/gtest.h>
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "bsdf/chi2.h"
#include "core/error.h"
#include "multilobe_test_util.h"
#include "prefilter/lobe_brdf.h"
#include "sampling/rng.h"

using namespace meso::test::ml;
using meso::test::make_material;

namespace {

const char *kBeckmann = R"({"type":"conductor","material":"Au","distribution":"beckmann","alpha":0.25})";
const char *kGgx = R"({"type":"conductor","material":"Cu","distribution":"ggx","alpha":0.3})";

/// The lobes form of one patch with this NDF and base.
std::unique_ptr<SvLobeBrdf> lobe_form(const char *base_json, const PatchNdf &ndf) {
    const auto j = nlohmann::json::parse(base_json);
    return std::make_unique<SvLobeBrdf>(make_lobe_base(make_material(base_json), j, "base"),
                                        std::vector<PatchNdf>{ndf}, 1, 1);
}

PatchNdf one_lobe(Vec3 mu, double kappa) { return make_ndf({{mu, kappa, 1.0}}); }

}  // namespace

TEST(LobeBrdf, WidenedAlphaMatchesTiltedBeckmannSlopes) {
    // Micro-normals of a Beckmann(α) surface whose own normal is vMF(z, κ)-distributed: their
    // slope variance per axis must be α'²/2 = α²/2 + 1/κ (small angles). Monte Carlo with 2e5
    // samples: the variance estimate's relative standard error is ~0.5%; the small-angle
    // approximation adds O(1/κ + α²) relative.
    EXPECT_DOUBLE_EQ(widened_alpha(0.25, std::numeric_limits<double>::infinity()), 0.25);
    EXPECT_DOUBLE_EQ(widened_alpha(0.25, 1e300), 0.25);
    EXPECT_DOUBLE_EQ(widened_alpha(0.25, 0.0), kMaxWidenedAlpha);
    EXPECT_DOUBLE_EQ(widened_alpha(3.0, 0.5), 3.0);  // a base rougher than the cap keeps its α
    EXPECT_NEAR(widened_alpha(0.25, 200.0), std::sqrt(0.0625 + 0.01), 1e-12);
    struct Case {
        double alpha, kappa;
    };
    for (const Case c : {Case{0.1, 1000.0}, Case{0.05, 400.0}, Case{0.2, 5000.0}}) {
        MicrofacetDistribution d(MicrofacetType::Beckmann, float(c.alpha), float(c.alpha), false);
        PCG32 rng(7, 1);
        double sx2 = 0.0;
        const int n = 200000;
        for (int k = 0; k < n; ++k) {
            const Vec3 w = vmf::sample(Vec3(0.f, 0.f, 1.f), c.kappa, Vec2(rng.next_float(), rng.next_float()));
            float pdf = 0.f;
            const Vec3 ml = d.sample(Vec3(0.f, 0.f, 1.f), Vec2(rng.next_float(), rng.next_float()), &pdf);
            const Vec3 m = Frame(w).to_world(ml);
            const double sx = -double(m.x) / double(m.z);
            sx2 += sx * sx;
        }
        const double var = sx2 / n, a = widened_alpha(c.alpha, c.kappa);
        std::printf("alpha %.2f kappa %6.0f: slope variance %.5f, alpha'^2/2 = %.5f (ratio %.4f)\n", c.alpha, c.kappa,
                    var, a * a / 2, var / (a * a / 2));
        EXPECT_NEAR(var / (a * a / 2), 1.0, 0.03);
    }
}

TEST(LobeBrdf, TablesMatchTheExactIntegrals) {
    EXPECT_NEAR(vmf_clamped_cosine(0.3f, 0.0), 0.25, 1e-5);
    EXPECT_NEAR(vmf_cap_mass(-0.7f, 0.0), 0.5, 1e-5);
    EXPECT_NEAR(vmf_clamped_cosine(0.6f, std::numeric_limits<double>::infinity()), 0.6, 1e-6);
    double worst_c = 0.0, worst_h = 0.0, worst_h_away = 0.0;
    for (double kappa : {0.0, 0.3, 2.0, 7.5, 40.0, 300.0, 5e3, 1e5, 1e9})
        for (double t = -1.0; t <= 1.0; t += 0.0371) {
            const Vec3 mu(float(std::sqrt(std::max(0.0, 1.0 - t * t))), 0.f, float(t));
            const double c = vmf_projected_area(mu, kappa), h = vmf_cap_mass(mu, kappa);
            const float ct = vmf_clamped_cosine(float(t), kappa), ht = vmf_cap_mass(float(t), kappa);
            ASSERT_TRUE(std::isfinite(ct) && std::isfinite(ht) && ct >= 0.f && ht >= 0.f && ht <= 1.f);
            worst_c = std::max(worst_c, std::abs(ct - c));
            worst_h = std::max(worst_h, std::abs(ht - h));
            if (std::abs(t) > 0.05) worst_h_away = std::max(worst_h_away, std::abs(ht - h));
        }
    std::printf("C table: max abs error %.2e (values 0..1); H table: %.2e, %.2e for |t| > 0.05\n", worst_c, worst_h,
                worst_h_away);
    // Bilinear in a 129 x 65 grid: sharp only where κ is large and |t| < 1/sqrt(κ). H weighs the
    // lobes (the pdf uses the same table, so sampling stays exact); its κ → ∞ step is ramped over
    // one cell of t (1/64).
    EXPECT_LT(worst_c, 0.01);
    EXPECT_LT(worst_h, 0.5);
    EXPECT_LT(worst_h_away, 0.02);
}

TEST(LobeBrdf, Chi2SamplingMatchesPdf) {
    struct Case {
        const char *name, *base;
        PatchNdf ndf;
    };
    const Case cases[] = {{"beckmann_6", kBeckmann, six_lobes()},
                          {"ggx_6", kGgx, six_lobes()},
                          {"diffuse_6", kDiffuse, six_lobes()},
                          {"beckmann_2", kBeckmann, two_lobes()},
                          {"diffuse_wide", kDiffuse, one_lobe(unit(0.5, 0.2, 0.3), 0.7)}};
    const double thetas[] = {0.0, 40.0, 75.0, 89.0};
    Chi2Options opt;
    opt.test_count = int(std::size(cases) * std::size(thetas));
    opt.samples = 400000;
    for (const Case &c : cases) {
        auto f = lobe_form(c.base, c.ndf);
        for (double th : thetas) {
            opt.name = fmt::format("lobes_{}_{}", c.name, int(th));
            const Chi2Result r = chi2_material_test(*f, kCtx, dir_deg(th, 30.0), opt);
            EXPECT_TRUE(r.passed) << c.name << " theta " << th << ": " << r.message << " p " << r.p_value;
            EXPECT_LE(r.pdf_integral, 1.0 + 1e-3) << c.name << " theta " << th;
        }
    }
}

TEST(LobeBrdf, LambertianLobeIsSampledExactly) {
    // One Lambertian lobe is sampled from its own tabulated C: eval / pdf is the same constant for
    // every sampled direction (ρ · c_j · min(1, H(μ·ωo) / H(μ_z)) · π / ∫C: only float round-off
    // varies), and the sampled t = μ·ωi follow C (mean of t against the table's quadrature). A vMF
    // stand-in of the clamped cosine (the sampler before) spreads the weight by 10-40%.
    meso::PCG32 rng(7, 1);
    for (double kappa : {0.0, 0.5, 8.0, 200.0, 1e5}) {
        // Tilted lobes test the weights; the macro normal's lobe the distribution of t.
        const bool tilted = kappa < 100.0;
        const Vec3 mu = tilted ? unit(0.4, -0.2, 1.0) : Vec3(0.f, 0.f, 1.f);
        auto f = lobe_form(kDiffuse, one_lobe(mu, kappa));
        for (double th : {0.0, 60.0, 85.0}) {
            const Vec3 wo = dir_deg(th, 40.0);
            double lo = INFINITY, hi = 0.0, sum_t = 0.0;
            int n = 0;
            for (int k = 0; k < 20000; ++k) {
                BSDFSample s;
                if (!f->sample(kCtx, wo, rng.next_float(), Vec2(rng.next_float(), rng.next_float()), s)) continue;
                ASSERT_TRUE(std::isfinite(s.weight.g) && s.pdf > 0.f) << kappa << " " << th;
                lo = std::min(lo, double(s.weight.g)), hi = std::max(hi, double(s.weight.g));
                sum_t += dot(mu, s.wi), ++n;
            }
            ASSERT_GT(n, 1000) << "kappa " << kappa << " theta " << th;
            EXPECT_LT((hi - lo) / hi, 1e-4) << "kappa " << kappa << " theta " << th << ": weights " << lo << ".." << hi;
            // Directions below the macro horizon fail, so the mean of t is over the accepted ones
            // only: compared for the lobe at the macro normal (where none of a sharp lobe fails).
            if (!tilted) {
                double num = 0.0, den = 0.0;
                for (int i = 0; i <= 4000; ++i) {
                    const double t = -1.0 + 2.0 * i / 4000.0, c = vmf_clamped_cosine(float(t), kappa);
                    num += t * c, den += c;
                }
                EXPECT_NEAR(sum_t / n, num / den, 0.01) << "kappa " << kappa << " theta " << th;
            }
        }
    }
}

TEST(LobeBrdf, SampledWeightsIntegrateEval) {
    // E[weight] over sample() = ∫ eval dωi: the sampler's pdf is its exact density (each
    // microfacet lobe's full NDF, the tabulated C of Lambertian ones; a sample that fails counts
    // as 0), down to grazing viewers; against a fine deterministic quadrature of eval.
    meso::PCG32 rng(11, 3);
    for (const char *b : {kBeckmann, kGgx, kDiffuse})
        for (const PatchNdf &ndf : {six_lobes(), two_lobes()}) {
            auto f = lobe_form(b, ndf);
            for (double th : {0.0, 60.0, 80.0, 88.0}) {
                const Vec3 wo = dir_deg(th, 30.0);
                const int n = 200000;
                double s = 0.0, s2 = 0.0;
                for (int k = 0; k < n; ++k) {
                    BSDFSample smp;
                    double w = 0.0;
                    if (f->sample(kCtx, wo, rng.next_float(), Vec2(rng.next_float(), rng.next_float()), smp))
                        w = smp.weight.g;
                    ASSERT_TRUE(std::isfinite(w)) << b << " theta " << th;
                    s += w, s2 += w * w;
                }
                const double mean = s / n, se = std::sqrt(std::max(0.0, s2 / n - mean * mean) / n);
                const double q = hemisphere_albedo(*f, wo, 1024, 1024);
                EXPECT_NEAR(mean, q, 4.0 * se + 2e-3 * q) << b << " theta " << th << " se " << se;
            }
        }
}

TEST(LobeBrdf, SharpLobeIsTheBase) {
    // κ = 1e9 at μ = z: α' = α, the lobe's frame is the macro frame: the base up to the rational
    // Beckmann Λ (Walter et al. 2007: ~1% in G), the Fresnel table, and Lambertian C = A₃(κ) cos.
    for (const char *b : {kBeckmann, kGgx, kDiffuse}) {
        auto base = make_material(b);
        auto f = lobe_form(b, one_lobe(Vec3(0.f, 0.f, 1.f), 1e9));
        double worst = 0.0;
        for (auto [wo, wi] : direction_pairs()) {
            const double e = base->eval(kCtx, wo, wi).g, v = f->eval(kCtx, wo, wi).g;
            worst = std::max(worst, std::abs(v - e) / std::max(e, 0.05));
        }
        std::printf("%s: closed form at kappa 1e9 vs the base: %.2e relative\n", b, worst);
        EXPECT_LT(worst, 0.03) << b;
    }
}

TEST(LobeBrdf, ClosedFormAgainstEq5Quadrature) {
    // The difference is what T and S absorb when the model is fitted with this form: stated
    // here, bounded loosely (finite, the right order), never snapshotted.
    std::printf("closed form / dense eq. 5: ratio of the sums over 27 direction pairs, two lobes of equal kappa:\n");
    for (const char *b : {kBeckmann, kDiffuse})
        for (double kappa : {1e9, 1e4, 300.0, 30.0, 3.0, 1.0, 0.3, 0.0}) {
            auto base = make_material(b);
            const PatchNdf ndf = make_ndf({{unit(0.3, 0.1, 1.0), kappa, 0.7}, {unit(-0.5, 0.0, 1.0), kappa, 0.3}});
            auto f = lobe_form(b, ndf);
            double sum_f = 0.0, sum_q = 0.0;
            for (auto [wo, wi] : direction_pairs()) {
                const double q = brute_eq5(*base, ndf, wo, wi, 120, 128), v = f->eval(kCtx, wo, wi).g;
                ASSERT_TRUE(std::isfinite(v) && v >= 0.0);
                sum_f += v, sum_q += q;
            }
            const double ratio = sum_f / sum_q;
            std::printf("  %-9s kappa %8.1f: %.3f\n", nlohmann::json::parse(b)["type"].get<std::string>().c_str(), kappa,
                        ratio);
            // Measured: conductor 1.11-1.12 for κ >= 30, 0.70-0.80 below (eq. 5 weighs a lobe by its
            // area A a_j whatever ωo, the lobes by their share of the projected area seen from ωo:
            // lobe_brdf.h, microfacet_view; with the area weights it was 0.96-1.04 for κ >= 3);
            // diffuse 0.96-1.03 for κ >= 30 (eq. 5 has the step where a facet turns away, the lobes
            // their projected area towards ωo), 0.74 at κ = 3 down to 0.38 at κ = 0 (eq. 5 counts
            // every normal of the lobe facing ωo at full weight, the lobes weigh them by m·ωo).
            EXPECT_GT(ratio, kappa >= 30.0 ? 0.9 : b == kDiffuse ? 0.3 : 0.6) << b << " kappa " << kappa;
            EXPECT_LT(ratio, kappa >= 30.0 ? (b == kDiffuse ? 1.1 : 1.2) : 1.6) << b << " kappa " << kappa;
        }
}

TEST(LobeBrdf, LambertianAlbedoIsThePatchMean) {
    // A Lambertian base's reflectance enters f'_low averaged over the patch (uv area), like the
    // NDF: f'_low must not vary inside a patch however fine the base's texture (its value at the
    // shading point put the texture's sub-patch detail back into every sample: ours was 1.65x
    // noisier per sample than the original on the bench sawtooth). A checkerboard of 3 x 3
    // checks: one patch holds 5 of color0 and 4 of color1; a 3 x 3 grid, one check per patch.
    const char *checker =
        R"({"type":"diffuse","reflectance":{"type":"checkerboard","color0":[0.9,0.2,0.1],"color1":[0.1,0.3,0.8],"scale":3}})";
    const double c0[3] = {0.9, 0.2, 0.1}, c1[3] = {0.1, 0.3, 0.8};
    const PatchNdf ndf = two_lobes();
    auto grey = lobe_form(R"({"type":"diffuse","reflectance":1})", ndf);  // ρ = 1: the lobes alone
    const auto j = nlohmann::json::parse(checker);
    auto one = std::make_unique<SvLobeBrdf>(make_lobe_base(make_material(checker), j, "base"),
                                            std::vector<PatchNdf>{ndf}, 1, 1);
    auto nine = std::make_unique<SvLobeBrdf>(make_lobe_base(make_material(checker), j, "base"),
                                             std::vector<PatchNdf>(9, ndf), 3, 3);
    meso::PCG32 rng(5, 9);
    for (auto [wo, wi] : direction_pairs()) {
        const Spectrum g = grey->eval(kCtx, wo, wi);
        if (!(g.g > 1e-4f)) continue;
        for (int k = 0; k < 40; ++k) {
            ShadingContext ctx;
            ctx.uv = Vec2(rng.next_float(), rng.next_float());
            const Spectrum a = one->eval(ctx, wo, wi), b = nine->eval(ctx, wo, wi);
            const bool odd = (int(ctx.uv.x * 3.f) + int(ctx.uv.y * 3.f)) % 2 != 0;
            for (int q = 0; q < 3; ++q) {
                const double mean = (5.0 * c0[q] + 4.0 * c1[q]) / 9.0, check = odd ? c1[q] : c0[q];
                // The 1-patch mean comes from 1024² jittered strata, 2 · 1024 of them straddling an
                // edge: a relative error ~1e-4.
                EXPECT_NEAR(a[q], mean * g[q], 2e-3 * mean * g[q]) << "uv " << ctx.uv.x << "," << ctx.uv.y;
                EXPECT_NEAR(b[q], check * g[q], 1e-5 * g[q]) << "uv " << ctx.uv.x << "," << ctx.uv.y;
            }
        }
    }
    // albedo_hint follows the same patch mean.
    EXPECT_NEAR(one->albedo_hint(kCtx).r, (5.0 * 0.9 + 4.0 * 0.1) / 9.0, 2e-3);
}

TEST(LobeBrdf, WhiteLambertianFlatLobeConservesEnergy) {
    // A flat patch (one lobe at z, κ = 1e9) with a white Lambertian base: albedo 1 at every ωo.
    auto f = lobe_form(R"({"type":"diffuse","reflectance":1})", one_lobe(Vec3(0.f, 0.f, 1.f), 1e9));
    for (double th : {0.0, 45.0, 80.0}) {
        const double a = hemisphere_albedo(*f, dir_deg(th, 0.0));
        EXPECT_NEAR(a, 1.0, 5e-3) << th;
    }
}

TEST(LobeBrdf, ExtremeInputsAreFinite) {
    const Vec3 grazing = dir_deg(89.99, 10.0), up(0.f, 0.f, 1.f);
    for (const char *b : {kBeckmann, kGgx, kDiffuse, R"({"type":"conductor","material":"Au","alpha":1e-4})",
                          R"({"type":"conductor","material":"Au","alpha":10})"})
        for (double kappa : {0.0, 1e-8, 1.0, 1e4, 1e9})
            for (Vec3 mu : {up, unit(1.0, 0.0, 1e-4), unit(0.3, 0.2, -0.5)}) {
                auto f = lobe_form(b, make_ndf({{mu, kappa, 0.8}, {up, 50.0, 0.2}}));
                for (Vec3 wo : {grazing, up, dir_deg(60.0, 200.0)})
                    for (Vec3 wi : {grazing, up, dir_deg(89.9, 190.0)}) {
                        float p = -1.f;
                        const Spectrum e = f->eval_pdf(kCtx, wo, wi, &p);
                        ASSERT_TRUE(e.is_finite() && e.r >= 0.f && std::isfinite(p) && p >= 0.f)
                            << b << " kappa " << kappa;
                    }
                PCG32 rng(3, 4);
                for (int k = 0; k < 200; ++k) {
                    BSDFSample s;
                    if (f->sample(kCtx, grazing, rng.next_float(), Vec2(rng.next_float(), rng.next_float()), s)) {
                        ASSERT_TRUE(s.weight.is_finite() && s.pdf > 0.f && std::isfinite(s.pdf)) << b;
                    }
                }
            }
}

TEST(LobeBrdf, BatchEvalIsEval) {
    // eval_batch (the prefilter's next-event splat: the ωo side once per call) against eval one
    // direction at a time, on two patches with different lobes (the batch must read the patch
    // of ctx.uv), viewers from the pole to below the horizon, ωi over the sphere.
    PCG32 rng(11, 12);
    std::vector<Vec3> wi;
    for (int k = 0; k < 300; ++k) {
        const float z = 2.f * rng.next_float() - 1.f, phi = 2.f * meso::Pi * rng.next_float();
        const float r = std::sqrt(std::max(0.f, 1.f - z * z));
        wi.push_back(Vec3(r * std::cos(phi), r * std::sin(phi), z));
    }
    wi.push_back(dir_deg(89.99, 40.0));
    wi.push_back(Vec3(0.f, 0.f, 1.f));
    const PatchNdf tilted = make_ndf({{unit(0.6, -0.2, 0.7), 20.0, 0.7}, {unit(0.0, 0.0, 1.0), 300.0, 0.3}});
    for (const char *b : {kBeckmann, kGgx, kDiffuse}) {
        const auto j = nlohmann::json::parse(b);
        const SvLobeBrdf f(make_lobe_base(make_material(b), j, "base"), {six_lobes(), tilted}, 2, 1);
        for (float u : {0.25f, 0.75f}) {
            ShadingContext ctx = kCtx;
            ctx.uv = Vec2(u, 0.5f);
            for (Vec3 wo : {Vec3(0.f, 0.f, 1.f), dir_deg(40.0, 30.0), dir_deg(75.0, 200.0), dir_deg(89.9, 300.0),
                            dir_deg(100.0, 10.0)}) {
                std::vector<Spectrum> out(wi.size());
                f.eval_batch(ctx, wo, wi.data(), int(wi.size()), out.data());
                for (size_t k = 0; k < wi.size(); ++k) {
                    const Spectrum e = f.eval(ctx, wo, wi[k]);
                    ASSERT_TRUE(out[k].r == e.r && out[k].g == e.g && out[k].b == e.b)
                        << b << " u " << u << " wo.z " << wo.z << " wi " << k << ": " << out[k].g << " vs " << e.g;
                }
            }
        }
    }
}

TEST(LobeBrdf, ViewerSideCacheNeverServesAnotherModelOrPatch) {
    // The ωo side of a microfacet pass, and the Lambertian lobes' view weights, are kept per
    // thread for the last (model, patch, ωo) (lobe_brdf.cpp, WoCache and LambertWoCache). Interleaving two models with the same layout but different lobes,
    // two patches and a repeated ωo, every eval, pdf and sample must be what a model evaluated
    // alone (a fresh copy made after the others, so nothing it asks can be cached) gives.
    const PatchNdf tilted = make_ndf({{unit(0.6, -0.2, 0.7), 20.0, 0.7}, {unit(0.0, 0.0, 1.0), 300.0, 0.3}});
    const PatchNdf other = make_ndf({{unit(-0.5, 0.3, 0.8), 8.0, 0.4}, {unit(0.1, 0.1, 1.0), 60.0, 0.6}});
    const char *diffuse = R"({"type":"diffuse","reflectance":0.7})";
    for (const char *b : {kBeckmann, kGgx, diffuse}) {
        const auto j = nlohmann::json::parse(b);
        auto make = [&](const PatchNdf &second) {
            return std::make_unique<SvLobeBrdf>(make_lobe_base(make_material(b), j, "base"),
                                                std::vector<PatchNdf>{six_lobes(), second}, 2, 1);
        };
        const auto f1 = make(tilted), f2 = make(other);
        const Vec3 wo = dir_deg(50.0, 70.0), wi = dir_deg(35.0, 250.0);
        struct Ask {
            const SvLobeBrdf *f;
            float u;
        };
        std::vector<Spectrum> got;
        std::vector<float> pdfs;
        std::vector<Vec3> dirs;
        for (const Ask a : {Ask{f1.get(), 0.75f}, Ask{f2.get(), 0.75f}, Ask{f1.get(), 0.25f}, Ask{f1.get(), 0.75f},
                            Ask{f2.get(), 0.25f}, Ask{f2.get(), 0.75f}}) {
            ShadingContext ctx = kCtx;
            ctx.uv = Vec2(a.u, 0.5f);
            float p = 0.f;
            got.push_back(a.f->eval_pdf(ctx, wo, wi, &p));
            pdfs.push_back(p);
            BSDFSample bs;
            dirs.push_back(a.f->sample(ctx, wo, 0.6f, Vec2(0.3f, 0.8f), bs) ? bs.wi : Vec3(0.f, 0.f, 0.f));
        }
        size_t k = 0;
        for (const Ask a : {Ask{f1.get(), 0.75f}, Ask{f2.get(), 0.75f}, Ask{f1.get(), 0.25f}, Ask{f1.get(), 0.75f},
                            Ask{f2.get(), 0.25f}, Ask{f2.get(), 0.75f}}) {
            const auto fresh = make(a.f == f1.get() ? tilted : other);
            ShadingContext ctx = kCtx;
            ctx.uv = Vec2(a.u, 0.5f);
            float p = 0.f;
            const Spectrum e = fresh->eval_pdf(ctx, wo, wi, &p);
            BSDFSample bs;
            const Vec3 d = fresh->sample(ctx, wo, 0.6f, Vec2(0.3f, 0.8f), bs) ? bs.wi : Vec3(0.f, 0.f, 0.f);
            EXPECT_TRUE(e.r == got[k].r && e.g == got[k].g && e.b == got[k].b && p == pdfs[k])
                << b << " ask " << k << ": " << got[k].g << " vs " << e.g << ", pdf " << pdfs[k] << " vs " << p;
            EXPECT_TRUE(d.x == dirs[k].x && d.y == dirs[k].y && d.z == dirs[k].z) << b << " ask " << k;
            ++k;
        }
        // The two models' second patches differ, so a cache keyed by the layout alone would fail above.
        EXPECT_NE(got[1].g, got[3].g) << b;
    }
}

TEST(LobeBrdf, UnsupportedBasesAreNamed) {
    auto err = [](const char *json) {
        try {
            make_lobe_base(make_material(json), nlohmann::json::parse(json), "m/manifest.json: input.base");
        } catch (const MesoError &e) {
            return std::string(e.what());
        }
        return std::string();
    };
    EXPECT_NE(err(R"({"type":"plastic","alpha":0.2})").find("m/manifest.json: input.base: --flow lobes supports"),
              std::string::npos);
    EXPECT_NE(err(R"({"type":"conductor","alpha_u":0.2,"alpha_v":0.1})").find("m/manifest.json: input.base"),
              std::string::npos);
    EXPECT_NE(err(R"({"type":"conductor","specular_reflectance":{"type":"checkerboard"},"alpha":0.2})")
                  .find("the same everywhere"),
              std::string::npos);
    EXPECT_EQ(err(kBeckmann), "");
    EXPECT_EQ(err(kDiffuse), "");
}

TEST(LobeBrdf, LambertianEvalAndPdfAreTheHeaderFormula) {
    // The Lambertian lobes' visible form (lobe_brdf.h), summed four lobes at a time from the
    // patch's blocks, against the header's formula lobe by lobe through vmf_clamped_cosine:
    //   eval = ρ/π Σ_j w_j C(μ_j·ωi, κ_j),  w_j = c_j v_j / Σ_k c_k v_k · Σ_k c_k,
    //   c_j = A a_j C(μ_j,z, κ_j),  v_j = C(μ_j·ωo, κ_j) / C(μ_j,z, κ_j),
    //   pdf = Σ_j P_j C(μ_j·ωi, κ_j) / (2π ∫C(t, κ_j) dt),  P_j = c_j v_j / Σ_k c_k v_k,
    // with seven lobes (a full block and a partial one), some facing away from the viewer.
    PatchNdf ndf = six_lobes();
    ndf.lobes.push_back({unit(-0.7, 0.5, 0.3), 0.5, 0.12});
    {
        double s = 0.0;
        for (const VmfLobe &l : ndf.lobes) s += l.weight;
        for (VmfLobe &l : ndf.lobes) l.weight /= s;
    }
    auto f = lobe_form(kDiffuse, ndf);
    auto mass = [](double kappa) {  // ∫ C(t, κ) dt over [-1, 1], fine trapezoids of the bilinear table
        double m = 0.0;
        const int n = 8192;
        for (int i = 0; i < n; ++i)
            m += 0.5 * (2.0 / n) *
                 (vmf_clamped_cosine(float(-1.0 + 2.0 * i / n), kappa) + vmf_clamped_cosine(float(-1.0 + 2.0 * (i + 1) / n), kappa));
        return m;
    };
    meso::PCG32 rng(11, 3);
    for (int k = 0; k < 200; ++k) {
        const Vec3 wo = dir_deg(89.5 * rng.next_double(), 360.0 * rng.next_double());
        const Vec3 wi = dir_deg(89.5 * rng.next_double(), 360.0 * rng.next_double());
        double ctot = 0.0, cv = 0.0, sum = 0.0, psum = 0.0;
        for (const VmfLobe &l : ndf.lobes) {
            const Vec3 mu = unit(l.mu.x, l.mu.y, l.mu.z);
            const double cz = vmf_clamped_cosine(mu.z, l.kappa), c = ndf.amplitude * l.weight * cz;
            const double v = vmf_clamped_cosine(dot(mu, wo), l.kappa) / cz, ci = vmf_clamped_cosine(dot(mu, wi), l.kappa);
            ctot += c, cv += c * v, sum += c * v * ci, psum += c * v * ci / (2.0 * kPi * mass(l.kappa));
        }
        float pdf = 0.f;
        const Spectrum e = f->eval_pdf(kCtx, wo, wi, &pdf);
        const double want = 0.8 / kPi * sum / cv * ctot;
        EXPECT_NEAR(e.g, want, 2e-4 * want) << "wo " << wo.x << " " << wo.y << " " << wo.z;
        EXPECT_NEAR(pdf, psum / cv, 1e-3 * psum / cv) << "wo " << wo.x << " " << wo.y << " " << wo.z;
    }
}
