// Diagnostic (skipped unless MESO_PATCH_ERROR_MODEL names a model directory made from a
// generator map): the per-patch error of a level's f'_low on h_low against brute force of the
// original, patch by patch (issue 21 item 5; docs/performance.md, "A glossy lobe's weight").
//
// For K random coarse patches P and fixed direction pairs (ωi, ωo): g_P, the original's effective
// BRDF over P (prefilter/effective_brdf.h; single bounce, or every bounce with
// MESO_PATCH_ERROR_IR=1), and m_P, f'_low (no tables) on h_low over the same patch, once with the
// model's view weights and once with the other form (lobes: microfacet_view area / visible; eq5 and
// visible: quadrature_weights absolute / share). Printed
// per pair: k = Σ g / Σ m (the global scale an angular S can give) and the relative error that
// scale leaves, Σ_P [(g_P − k m_P)² − noise] / Σ_P g_P² (what T S cannot remove). Options:
// MESO_PATCH_ERROR_LEVEL (default 4), MESO_PATCH_ERROR_PATCHES (64), MESO_PATCH_ERROR_LINES (1024).
#include <gtest/gtest.h>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <string>
#include <vector>
#include <nlohmann/json.hpp>
#include "geometry/heightfield.h"
#include "geometry/heightmap_gen.h"
#include "material_test_util.h"
#include "prefilter/effective_brdf.h"
#include "prefilter/model.h"
#include "sampling/rng.h"

using namespace meso;
using namespace meso::prefilter;

namespace {

int env_int(const char *name, int fallback) {
    const char *v = std::getenv(name);
    return v ? std::atoi(v) : fallback;
}

Vec3 dir_deg(double theta, double phi) {
    const double t = theta * M_PI / 180, p = phi * M_PI / 180;
    return Vec3(float(std::sin(t) * std::cos(p)), float(std::sin(t) * std::sin(p)), float(std::cos(t)));
}

/// Value and variance of one estimate (green channel).
struct Value {
    double v = 0, var = 0;
};

Value value(const EffectiveBrdfEstimator::Estimate &e) { return {e.value[1], e.std_error[1] * e.std_error[1]}; }

/// k = Σ g / Σ m and the relative error it leaves (see the header).
std::pair<double, double> scaled_error(const std::vector<Value> &g, const std::vector<Value> &m) {
    double sg = 0, sm = 0, e = 0, q = 0;
    for (size_t k = 0; k < g.size(); ++k) sg += g[k].v, sm += m[k].v;
    const double s = sm > 0 ? sg / sm : 0.0;
    for (size_t k = 0; k < g.size(); ++k) {
        const double d = g[k].v - s * m[k].v;
        e += d * d - g[k].var - s * s * m[k].var;
        q += g[k].v * g[k].v;
    }
    return {s, q > 0 ? e / q : 0.0};
}

}  // namespace

TEST(PrefilteredPatchError, LevelAgainstBruteForce) {
    const char *dir = std::getenv("MESO_PATCH_ERROR_MODEL");
    if (!dir) GTEST_SKIP() << "set MESO_PATCH_ERROR_MODEL to a model directory";
    const int F = env_int("MESO_PATCH_ERROR_LEVEL", 4), K = env_int("MESO_PATCH_ERROR_PATCHES", 64);
    const size_t lines = size_t(env_int("MESO_PATCH_ERROR_LINES", 1024));
    const int bounces = env_int("MESO_PATCH_ERROR_IR", 0) ? kAllBounces : 1;
    const PrefilteredModel m = PrefilteredModel::load(dir);
    const nlohmann::json &gen = m.manifest["input"]["generator"];
    ASSERT_TRUE(gen.is_object()) << "the model must be made from a generator map";
    std::map<std::string, std::string> params;
    for (const auto &[k, v] : gen["params"].items()) params[k] = v.get<std::string>();
    if (params.count("grid") && params["grid"] != "0") params.erase("count");  // the manifest lists both
    const HeightMap fine = generate_height_map(gen["kind"].get<std::string>(), params).height;
    const Heightfield orig(fine, float(m.height_scale * fine.width / m.tile_size), 0.f);
    const PrefilteredLevel *L = m.level_for_factor(F);
    ASSERT_TRUE(L) << "the model has levels " << m.factor_list();
    const Heightfield low(L->h_low, float(m.height_scale * L->width() / m.tile_size), 0.f);
    auto base = meso::test::make_material(m.base.dump());
    QuadratureOptions other = m.quadrature;
    if (m.quadrature.lobes) other.area_microfacet = !other.area_microfacet;
    else other.absolute_weights = !other.absolute_weights;  // the quadrature flows (eq5 / visible)
    const SvMultiLobe own(base, L->ndf, L->width(), L->height(), m.quadrature, m.base, "base");
    const SvMultiLobe alt(base, L->ndf, L->width(), L->height(), other, m.base, "base");
    EffectiveBrdfEstimator::Options mo;
    mo.macro_frame = true;
    const EffectiveBrdfEstimator eo(orig, *base), e_own(low, own, mo), e_alt(low, alt, mo);
    PCG32 rng(7, 3);
    std::vector<int> cells(static_cast<size_t>(K));
    for (int &c : cells) c = int(rng.next_double() * L->width() * L->height()) % (L->width() * L->height());
    // (θo, θi, azimuth of ωi) in degrees, ωo at azimuth 0: near-specular pairs from normal to
    // grazing views, and off-specular ones.
    const double pairs[][3] = {{45, 66, 188}, {61, 60, 189}, {70, 50, 180}, {74, 37, 184},
                               {77, 15, 170}, {68, 57, 216}, {30, 30, 180}, {60, 20, 150}};
    std::printf("level x%d, %d patches, %zu lines, %s; forms: model's (%s) / other\n", F, K, lines,
                bounces == 1 ? "single bounce" : "every bounce",
                m.quadrature.lobes ? (m.quadrature.area_microfacet ? "lobes, area" : "lobes, visible")
                                   : (m.quadrature.absolute_weights ? "quadrature, absolute" : "quadrature, share"));
    for (const auto &p : pairs) {
        const Vec3 wo = dir_deg(p[0], 0), wi = dir_deg(p[1], p[2]);
        std::vector<Value> g(static_cast<size_t>(K)), a(static_cast<size_t>(K)), b(static_cast<size_t>(K));
        for (int k = 0; k < K; ++k) {
            const int I = cells[size_t(k)] % L->width(), J = cells[size_t(k)] / L->width();
            const uint64_t s = uint64_t(k) * 4 + uint64_t(p[0] * 1000 + p[1]) * 100000;
            g[size_t(k)] = value(eo.estimate({double(I) * F, double(J) * F, double(I + 1) * F, double(J + 1) * F}, wi, wo,
                                             lines, s + 1, bounces));
            const PatchRegion rl{double(I), double(J), double(I + 1), double(J + 1)};
            a[size_t(k)] = value(e_own.estimate(rl, wi, wo, lines, s + 2, 1));
            b[size_t(k)] = value(e_alt.estimate(rl, wi, wo, lines, s + 2, 1));
        }
        const auto [ka, ea] = scaled_error(g, a);
        const auto [kb, eb] = scaled_error(g, b);
        std::printf("  to %2.0f ti %2.0f dphi %3.0f: model's form k %.3f error %.4f | other k %.3f error %.4f\n", p[0], p[1],
                    p[2], ka, ea, kb, eb);
        EXPECT_TRUE(std::isfinite(ea) && std::isfinite(eb));
    }
}
