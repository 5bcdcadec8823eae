// Sampling at the extremes (issue 24): for every registered material, over parameter sets
// spanning the extremes (alpha 1e-6 .. 10, anisotropy alpha_u / alpha_v = 1e-7, Blinn-Phong
// and Toksvig powers 0 .. 1e7, vMF kappa 0 .. 1e6, nearly horizontal average normals) and
// viewing angles theta_o = 0, 45, 89, 89.99 degrees (and the mirrored ones below the surface
// for transmissive materials), every sample drawn with fixed seeds must be finite and
//   * its pdf equal pdf(wo, wi) to 1e-4 relative,
//   * its weight equal eval(wo, wi) / pdf(wo, wi) to 1e-4 relative,
// and the flux albedo (estimate_albedo) stay at most 1 within 3 standard errors.
// Absolute floors: a pdf or eval product below 1e-30 counts as 0 (far below any value a
// float direction can resolve: a lobe that narrow has no finite-precision support).
#include <gtest/gtest.h>
#include <fmt/format.h>
#include <algorithm>
#include <cctype>
#include <cmath>
#include <map>
#include <set>
#include <string>
#include <vector>
#include <nlohmann/json.hpp>
#include "bsdf/chi2.h"
#include "bsdf/material.h"
#include "material_test_util.h"
#include "sampling/rng.h"

using namespace meso;
using meso::test::dir_deg;
using meso::test::make_material;

namespace {

const ShadingContext kCtx{};

struct Extreme {
    std::string name, json;
};

/// The microfacet roughness settings shared by conductor, dielectric and plastic.
std::vector<std::string> roughness_sets(bool anisotropic) {
    std::vector<std::string> v;
    for (const char *a : {"1e-6", "1e-3", "0.1", "1", "10"}) v.push_back(std::string("\"alpha\":") + a);
    if (anisotropic) {
        v.push_back("\"alpha_u\":1e-6,\"alpha_v\":10");  // 1e7 (1e5 after the kMinAlpha clamp)
        v.push_back("\"alpha_u\":10,\"alpha_v\":1e-3");
        v.push_back("\"alpha_u\":1e-3,\"alpha_v\":0.1");
    }
    return v;
}

std::vector<Extreme> extreme_cases() {
    std::vector<Extreme> c;
    auto add = [&](std::string name, std::string json) { c.push_back({std::move(name), std::move(json)}); };
    for (const char *dist : {"ggx", "beckmann"}) {
        int i = 0;
        for (const std::string &r : roughness_sets(true)) {
            const std::string d = std::string("\"distribution\":\"") + dist + "\"," + r;
            add(fmt::format("conductor_{}_{}", dist, i), "{\"type\":\"conductor\",\"material\":\"Au\"," + d + "}");
            add(fmt::format("dielectric_{}_{}", dist, i), "{\"type\":\"dielectric\"," + d + "}");
            ++i;
        }
        i = 0;
        for (const std::string &r : roughness_sets(false)) {
            const std::string d = std::string("\"distribution\":\"") + dist + "\"," + r;
            add(fmt::format("plastic_{}_{}", dist, i), "{\"type\":\"plastic\",\"diffuse_reflectance\":1," + d + "}");
            ++i;
        }
    }
    int gi = 0;
    for (const char *r : {"0", "1e-3", "0.1", "1"})
        for (const char *m : {"0", "1"})
            add(fmt::format("gltf_pbr_{}", gi++),
                std::string(R"({"type":"gltf_pbr","base_color":1,"metallic":)") + m + ",\"roughness\":" + r + "}");
    add("conductor_fullndf", R"({"type":"conductor","alpha":1e-3,"sample_visible":false})");
    add("dielectric_eta_1", R"({"type":"dielectric","int_ior":1.0,"alpha":0.1})");
    add("dielectric_eta_below_1", R"({"type":"dielectric","int_ior":1.0,"ext_ior":1.5,"alpha":1e-3})");
    add("diffuse_white", R"({"type":"diffuse","reflectance":1})");
    for (const char *a : {"1e-3", "0.1", "1", "10"}) {
        add(fmt::format("leadr_spec_{}", a), std::string(R"({"type":"leadr","alpha":)") + a + "}");
        add(fmt::format("leadr_diffuse_{}", a),
            std::string(R"({"type":"leadr","specular_reflectance":0,"diffuse_reflectance":1,"alpha":)") + a + "}");
        add(fmt::format("lean_{}", a), std::string(R"({"type":"lean","alpha":)") + a + "}");
    }
    add("leadr_aniso", R"({"type":"leadr","covariance":[1e-12,1e-5,0],"diffuse_reflectance":0.5,"specular_reflectance":0.5})");
    add("lean_aniso", R"({"type":"lean","covariance":[1e-12,1e-5,0]})");
    add("clean_aniso", R"({"type":"clean","covariance":[1e-8,1e-1,0],"exponent":1e6})");
    for (const char *s : {"0", "1e3", "1e6"})
        add(fmt::format("blinnphong_{}", s), std::string(R"({"type":"blinnphong","exponent":)") + s + "}");
    for (const char *s : {"0", "1e3", "1e7"})
        add(fmt::format("toksvig_{}", s), std::string(R"({"type":"toksvig","exponent":)") + s + "}");
    add("toksvig_horizontal", R"({"type":"toksvig","average_normal":[0.999,0,0.001]})");
    add("toksvig_short", R"({"type":"toksvig","exponent":1e7,"average_normal":[0,0,1e-6]})");
    for (const char *k : {"0", "1e6"})
        add(fmt::format("vmf_{}", k), std::string(R"({"type":"vmf","lobes":[{"direction":[0.3,0.1,0.9],"kappa":)") + k + "}]}");
    add("normalmap_conductor", R"({"type":"normalmap","normal":[0.3,0.1,0.9],"bsdf":{"type":"conductor","alpha":1e-3}})");
    add("normalmap_grazing", R"({"type":"normalmap","normal":[1,0,1e-3],"bsdf":{"type":"diffuse","reflectance":1}})");
    return c;
}

void PrintTo(const Extreme &c, std::ostream *os) { *os << c.name; }

double rel_diff(double a, double b) {
    const double m = std::max(std::abs(a), std::abs(b));
    return m < 1e-30 ? 0.0 : std::abs(a - b) / m;
}

struct SweepStats {
    int n = 0, failed = 0, invalid = 0, pdf_bad = 0, weight_bad = 0;
    double max_pdf_err = 0, max_weight_err = 0;
    std::string first_bad;
};

/// Draws n samples at wo and checks each against eval and pdf.
SweepStats sweep(const Material &m, const Vec3 &wo, int n, uint64_t seed) {
    SweepStats s;
    PCG32 rng(seed);
    for (int i = 0; i < n; ++i) {
        const float ul = rng.next_float();
        const Vec2 u(rng.next_float(), rng.next_float());
        BSDFSample bs;
        ++s.n;
        if (!m.sample(kCtx, wo, ul, u, bs)) {
            ++s.failed;
            continue;
        }
        if (!bs.weight.is_finite() || !std::isfinite(bs.pdf) || !(bs.pdf > 0.f) || !is_finite(bs.wi) ||
            std::abs(length(bs.wi) - 1.f) > 1e-3f || std::min({bs.weight.r, bs.weight.g, bs.weight.b}) < 0.f) {
            ++s.invalid;
            continue;
        }
        if (bs.flags & BSDF_Delta) continue;
        const double p = m.pdf(kCtx, wo, bs.wi);
        const double pe = rel_diff(p, bs.pdf);
        const Spectrum f = m.eval(kCtx, wo, bs.wi);
        double we = 0;
        for (int ch = 0; ch < 3; ++ch) we = std::max(we, rel_diff(double(bs.weight[ch]) * p, f[ch]));
        s.max_pdf_err = std::max(s.max_pdf_err, pe);
        s.max_weight_err = std::max(s.max_weight_err, we);
        if (pe > 1e-4) ++s.pdf_bad;
        if (we > 1e-4) ++s.weight_bad;
        if ((pe > 1e-4 || we > 1e-4) && s.first_bad.empty())
            s.first_bad = fmt::format("wi ({}, {}, {}): sample pdf {} pdf() {}, weight*pdf {} eval {}", bs.wi.x, bs.wi.y,
                                      bs.wi.z, bs.pdf, p, double(bs.weight.g) * p, f.g);
    }
    return s;
}

class MaterialExtremesSweep : public testing::TestWithParam<Extreme> {};

TEST_P(MaterialExtremesSweep, SampleMatchesPdfAndEvalAlbedoAtMostOne) {
    const Extreme &c = GetParam();
    auto mat = make_material(c.json);
    std::vector<double> thetas = {0.0, 45.0, 89.0, 89.99};
    if (mat->has_transmission()) thetas.insert(thetas.end(), {135.0, 179.0, 90.01});
    uint64_t seed = 11;
    for (double t : thetas) {
        const Vec3 wo = dir_deg(t, 30.0);  // off the axes: anisotropy and float rounding in x and y
        const SweepStats s = sweep(*mat, wo, 4000, seed++);
        const std::string where = fmt::format("{} {} theta_o {}", c.name, c.json, t);
        EXPECT_EQ(s.invalid, 0) << where;
        EXPECT_EQ(s.pdf_bad, 0) << where << ": max rel. error " << s.max_pdf_err << "; " << s.first_bad;
        EXPECT_EQ(s.weight_bad, 0) << where << ": max rel. error " << s.max_weight_err << "; " << s.first_bad;
        const AlbedoEstimate a = estimate_albedo(*mat, kCtx, wo, 20000, seed++);
        for (int ch = 0; ch < 3; ++ch) {
            EXPECT_TRUE(std::isfinite(a.mean[ch])) << where;
            EXPECT_LE(a.mean[ch], 1.0 + 3.0 * a.stderr_[ch] + 1e-5) << where << " channel " << ch << " stderr "
                                                                      << a.stderr_[ch];
        }
    }
}

INSTANTIATE_TEST_SUITE_P(Extremes, MaterialExtremesSweep, testing::ValuesIn(extreme_cases()),
                         [](const testing::TestParamInfo<Extreme> &i) {
                             std::string n = i.param.name;
                             for (char &ch : n)
                                 if (!std::isalnum(static_cast<unsigned char>(ch))) ch = '_';
                             return n;
                         });

TEST(MaterialExtremesSweep, EveryRegisteredMaterialHasACase) {
    // `prefiltered` needs a model directory written by `meso prefilter`; its extreme inputs are
    // tested in test_prefiltered_material.cpp.
    const std::set<std::string> exempt = {"prefiltered"};
    std::set<std::string> covered;
    for (const Extreme &c : extreme_cases()) covered.insert(nlohmann::json::parse(c.json).at("type").get<std::string>());
    for (const auto &entry : registry().materials.factories)
        EXPECT_TRUE(covered.count(entry.first) || exempt.count(entry.first))
            << "material '" << entry.first << "' has no case in extreme_cases() (tests/test_material_extremes.cpp)";
}

}  // namespace
