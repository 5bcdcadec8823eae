// The `prefiltered` material on a model made with --flow lobes (prefilter/lobe_brdf.h): the form
// is recorded in the manifest and survives save / load, the material shades with T · S · the
// closed form, its sampler passes χ² with weight = eval / pdf, and a form that does not match the
// model is refused with a located error.
#include <gtest/gtest.h>
#include <string>
#include <fmt/format.h>
#include "prefiltered_test_util.h"

using meso::test::dir_deg;
using namespace meso::test::pf;  // also meso, meso::prefilter, make_material

namespace {

/// The tiny model of prefiltered_test_util.h saved again as a --flow lobes model.
const std::string &lobes_model_dir() {
    static const std::string dir = [] {
        PrefilteredModel m = tiny_model().model;
        m.quadrature.lobes = true;
        m.manifest["parameters"]["flow"] = "lobes";
        m.manifest["parameters"]["lambert_view"] = "visible";  // as `meso prefilter` writes it now
        m.manifest["parameters"]["microfacet_view"] = "visible";
        const std::string d = (fs::path(meso::test::scratch_dir("meso_prefiltered_test")) / "model_lobes").string();
        m.save(d);
        return d;
    }();
    return dir;
}

std::shared_ptr<Material> lobes_material(const std::string &extra) {
    return make_material(fmt::format(R"({{"type":"prefiltered","model":"{}"{}}})", lobes_model_dir(), extra));
}

}  // namespace

TEST(PrefilteredLobes, FormIsRecordedAndLoaded) {
    EXPECT_TRUE(PrefilteredModel::load(lobes_model_dir()).quadrature.lobes);
    EXPECT_FALSE(PrefilteredModel::load(tiny_model().dir).quadrature.lobes);  // older manifests: eq5
    // parameters.lambert_view: "visible" now; absent (models made before) the min(H, H) view weight.
    EXPECT_FALSE(PrefilteredModel::load(lobes_model_dir()).quadrature.cap_mass_lambert);
    EXPECT_TRUE(PrefilteredModel::load(tiny_model().dir).quadrature.cap_mass_lambert);
    // parameters.microfacet_view: "visible" now; absent (models made before) the lobes' area weights.
    EXPECT_FALSE(PrefilteredModel::load(lobes_model_dir()).quadrature.area_microfacet);
    EXPECT_TRUE(PrefilteredModel::load(tiny_model().dir).quadrature.area_microfacet);
}

TEST(PrefilteredLobes, EvalIsTimesSTimesTheClosedForm) {
    const PrefilteredModel m = PrefilteredModel::load(lobes_model_dir());
    const PrefilteredLevel *L = m.level_for_factor(4);
    const SvLobeBrdf ref(make_lobe_base(make_material(kBase), nlohmann::json::parse(kBase), "base"), L->ndf,
                         L->width(), L->height());
    auto mat = lobes_material(R"(,"level":4,"scaling":"ir")");
    PCG32 rng(5);
    for (int k = 0; k < 200; ++k) {
        ShadingContext ctx;
        ctx.uv = Vec2(rng.next_float(), rng.next_float());
        const Vec3 wo = dir_deg(85.0 * rng.next_float(), 360.0 * rng.next_float());
        const Vec3 wi = dir_deg(89.0 * rng.next_float(), 360.0 * rng.next_float());
        const Spectrum want = ref.eval(ctx, wo, wi) * L->ir.eval_T(ctx.uv) * L->ir.eval_S(wi, wo);
        expect_spectrum_near(mat->eval(ctx, wo, wi), want, 1e-5, fmt::format("sample {}", k));
        EXPECT_NEAR(mat->pdf(ctx, wo, wi), ref.pdf(ctx, wo, wi), 1e-6 * ref.pdf(ctx, wo, wi) + 1e-9);
    }
}

TEST(PrefilteredLobes, Chi2AndWeights) {
    int idx = 0;
    const double thetas[] = {0.0, 45.0, 80.0};
    for (double theta : thetas) {
        auto mat = lobes_material(R"(,"level":4)");
        ShadingContext ctx;
        ctx.uv = Vec2(0.3f + 0.2f * float(idx), 0.55f);
        Chi2Options opt;
        opt.samples = 200000;
        opt.seed = 300 + idx;
        opt.test_count = int(std::size(thetas));
        opt.name = fmt::format("prefiltered_lobes_{}", idx);
        const Chi2Result r = chi2_material_test(*mat, ctx, dir_deg(theta, 20.0), opt);
        EXPECT_TRUE(r.passed) << idx << ": " << r.message;
        EXPECT_EQ(r.weight_mismatch, 0u) << idx << " max rel. error " << r.max_weight_rel_error;
        EXPECT_EQ(r.pdf_mismatch, 0u) << idx;
        EXPECT_LE(r.pdf_integral, 1.0 + 1e-4) << idx;
        ++idx;
    }
}

namespace {

/// The tiny model as a --flow lobes model with another base (a scene object), saved under `name`.
std::string lobes_model_with_base(const char *base, const std::string &name) {
    PrefilteredModel m = tiny_model().model;
    m.quadrature.lobes = true;
    m.base = nlohmann::json::parse(base);
    m.manifest["input"]["base"] = m.base;
    m.manifest["parameters"]["flow"] = "lobes";
    m.manifest["parameters"]["lambert_view"] = "visible";
    const std::string d = (fs::path(meso::test::scratch_dir("meso_prefiltered_test")) / name).string();
    m.save(d);
    return d;
}

}  // namespace

TEST(PrefilteredLobes, MicrogeometryFrameSamplesAgreeWithEvalAndPdf) {
    // On microgeometry (a shell-mapped level: the shading frame tilted against the macro frame)
    // sample draws the closed form's direction and evaluates value and pdf once, at the direction
    // the integrator sees after the rotation back. The sampler must still pass χ² with
    // weight = eval / pdf, and sample's pdf must be pdf() exactly, for diffuse, Beckmann and GGX
    // bases, and at grazing views (the lobe choice then keeps few lobes).
    const char *bases[] = {kBase, R"({"type":"conductor","material":"Au","distribution":"beckmann","alpha":0.25})",
                           R"({"type":"conductor","material":"Cu","distribution":"ggx","alpha":0.15})"};
    const double thetas[] = {10.0, 60.0, 80.0};
    const int tests = int(std::size(bases) * std::size(thetas));
    int idx = 0;
    for (size_t b = 0; b < std::size(bases); ++b) {
        const std::string dir = b == 0 ? lobes_model_dir() : lobes_model_with_base(bases[b], fmt::format("model_lobes_base{}", b));
        auto mat = make_material(fmt::format(R"({{"type":"prefiltered","model":"{}","level":4}})", dir));
        for (double theta : thetas) {
            ShadingContext ctx;
            ctx.uv = Vec2(0.15f + 0.1f * float(idx % 7), 0.6f - 0.05f * float(idx));
            ctx.frame = Frame::from_normal_tangent(normalize(Vec3(0.25f, -0.15f, 1.f)), Vec3(1.f, 0.f, 0.f));
            ctx.n_macro = Vec3(0.f, 0.f, 1.f);
            ctx.dpdu_macro = Vec3(1.f, 0.f, 0.f);
            const Vec3 wo = dir_deg(theta, 35.0);
            Chi2Options opt;
            opt.samples = 100000;
            opt.seed = 500 + idx;
            opt.test_count = tests;
            opt.name = fmt::format("prefiltered_lobes_micro_{}", idx);
            const Chi2Result r = chi2_material_test(*mat, ctx, wo, opt);
            EXPECT_TRUE(r.passed) << idx << ": " << r.message;
            EXPECT_EQ(r.weight_mismatch, 0u) << idx << " max rel. error " << r.max_weight_rel_error;
            EXPECT_LE(r.pdf_integral, 1.0 + 1e-4) << idx;
            PCG32 rng(40 + idx);
            int ok = 0;
            for (int k = 0; k < 2000; ++k) {
                BSDFSample bs;
                if (!mat->sample(ctx, wo, rng.next_float(), Vec2(rng.next_float(), rng.next_float()), bs)) continue;
                ++ok;
                const float p = mat->pdf(ctx, wo, bs.wi);
                ASSERT_EQ(p, bs.pdf) << idx << " sample " << k;
                const Spectrum e = mat->eval(ctx, wo, bs.wi);
                for (int c = 0; c < 3; ++c) EXPECT_NEAR(bs.weight[c], e[c] / p, 1e-6f * e[c] / p) << idx << " sample " << k;
            }
            EXPECT_GT(ok, 1000) << idx;
            ++idx;
        }
    }
}

TEST(PrefilteredLobes, MismatchesNameTheKey) {
    auto err = [&](const std::string &dir, const std::string &extra) {
        return error_of([&] { make_material(fmt::format(R"({{"type":"prefiltered","model":"{}"{}}})", dir, extra)); });
    };
    std::string e = err(lobes_model_dir(), R"(,"level":4,"flow":"eq5")");
    EXPECT_NE(e.find("material.flow: the model"), std::string::npos) << e;
    EXPECT_NE(e.find("was made with --flow lobes"), std::string::npos) << e;
    e = err(tiny_model().dir, R"(,"level":4,"flow":"lobes")");
    EXPECT_NE(e.find("material.flow:"), std::string::npos) << e;
    EXPECT_NE(e.find("--flow eq5"), std::string::npos) << e;
    EXPECT_EQ(err(lobes_model_dir(), R"(,"level":4,"flow":"lobes")"), "(no error)");
    // Nothing to estimate in the closed form: the estimators (meso bench passes one) are accepted and mean it.
    EXPECT_EQ(err(lobes_model_dir(), R"(,"level":4,"estimator":"stratified","estimator_nodes":4)"), "(no error)");
    e = err(lobes_model_dir(), R"(,"level":4,"base":{"type":"plastic","alpha":0.2})");
    EXPECT_NE(e.find("material.base"), std::string::npos) << e;
    EXPECT_NE(e.find("--flow lobes supports"), std::string::npos) << e;
}

TEST(PrefilteredLobes, DiffuseAlbedoIsThePatchMeanInModelsThatSaySo) {
    // A diffuse base with a checkerboard of 3 x 3 checks a patch (level x4: 4 x 4 patches, 12 x 12
    // checks a tile), f'_low alone ("scaling": "none"). A model made by `meso prefilter` now
    // (parameters.albedo = "patch_mean") shades every point of a patch with the patch's mean
    // reflectance, (5 c_even + 4 c_odd) / 9 with the corner check's colour counted 5 times; a
    // model without the key (made before: its tables fit the point value) with the check at the
    // point. The point value is the texture's sub-patch detail in every shading sample: 1.65x the
    // original's pixel variance per sample on the bench sawtooth under the sky, 0.29x without.
    const char *checker = R"({"type":"diffuse","reflectance":{"type":"checkerboard","color0":[0.9,0.2,0.1],)"
                          R"("color1":[0.1,0.3,0.8],"scale":12}})";
    const Spectrum c[2] = {Spectrum(0.9f, 0.2f, 0.1f), Spectrum(0.1f, 0.3f, 0.8f)};
    auto save = [&](bool patch_mean) {
        PrefilteredModel m = tiny_model().model;
        m.quadrature.lobes = true;
        m.base = nlohmann::json::parse(checker);
        m.manifest["input"]["base"] = m.base;
        m.manifest["parameters"]["flow"] = "lobes";
        if (patch_mean) m.manifest["parameters"]["albedo"] = "patch_mean";
        m.manifest["parameters"]["lambert_view"] = "visible";  // as the reference `lobes` below
        const std::string d = (fs::path(meso::test::scratch_dir("meso_prefiltered_test")) /
                               (patch_mean ? "model_lobes_checker_mean" : "model_lobes_checker_point"))
                                  .string();
        m.save(d);
        return d;
    };
    const std::string mean_dir = save(true), point_dir = save(false);
    EXPECT_FALSE(PrefilteredModel::load(mean_dir).quadrature.point_albedo);
    EXPECT_TRUE(PrefilteredModel::load(point_dir).quadrature.point_albedo);
    auto open = [](const std::string &d) {
        return make_material(fmt::format(R"({{"type":"prefiltered","model":"{}","level":4,"scaling":"none"}})", d));
    };
    auto mean_mat = open(mean_dir), point_mat = open(point_dir);
    const PrefilteredLevel *L = tiny_model().model.level_for_factor(4);
    const char *white = R"({"type":"diffuse","reflectance":1})";
    const SvLobeBrdf lobes(make_lobe_base(make_material(white), nlohmann::json::parse(white), "base"), L->ndf,
                           L->width(), L->height());
    PCG32 rng(17);
    for (int k = 0; k < 300; ++k) {
        ShadingContext ctx;
        ctx.uv = Vec2(rng.next_float(), rng.next_float());
        const Vec3 wo = dir_deg(80.0 * rng.next_float(), 360.0 * rng.next_float());
        const Vec3 wi = dir_deg(85.0 * rng.next_float(), 360.0 * rng.next_float());
        const Spectrum g = lobes.eval(ctx, wo, wi);
        const int pi = int(ctx.uv.x * 4.f), pj = int(ctx.uv.y * 4.f), ci = int(ctx.uv.x * 12.f), cj = int(ctx.uv.y * 12.f);
        const int corner = (pi + pj) % 2;
        const Spectrum patch_mean = (c[corner] * 5.f + c[1 - corner] * 4.f) * (1.f / 9.f);
        // 1024² jittered strata a tile, 2 · 256 of a patch's straddling a check edge: ~1e-3 relative.
        expect_spectrum_near(mean_mat->eval(ctx, wo, wi), patch_mean * g, 3e-3, fmt::format("patch mean, sample {}", k));
        expect_spectrum_near(point_mat->eval(ctx, wo, wi), c[(ci + cj) % 2] * g, 1e-5, fmt::format("point, sample {}", k));
    }
}
