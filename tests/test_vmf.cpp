// vMF lobes and the `vmf` material (paper 002): the density and its sampler at every κ, the
// characteristic-vector cubic (exact root and the paper's 1024-entry table, whose error is
// reported), the BRDF MIP-maps (cells, Algorithm 1, exact linear filtering), extreme inputs,
// and the filtered BRDF against the exact average of the finest-level BRDFs (eq. 5) for
// every filtering mode. (χ², weight = eval/pdf, albedo and Jacobians: test_materials.cpp.)
#include <gtest/gtest.h>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>
#include "bsdf/material.h"
#include "core/error.h"
#include "filter/vmf.h"
#include "sampling/rng.h"
#include "core/properties.h"
#include "core/registry.h"
#include "material_test_util.h"
#include "texture/vmf_map.h"

using namespace meso;

namespace {

constexpr double kPi = 3.14159265358979323846;

std::shared_ptr<Material> make(const std::string &json_text) { return test::make_material(json_text); }
using test::dir_deg;

/// ∫_{S²} γ dω = 2π ∫_0^2 pdf_cos(κ, 1 − t) dt on a geometric grid in t (the mass sits at t ~ 1/κ).
double integrate_density(double kappa) {
    const int n = 20000;
    const double t0 = 1e-14, t1 = 2.0, q = std::pow(t1 / t0, 1.0 / n);
    double s = 2.0 * kPi * vmf::pdf_cos(kappa, 1.0) * t0;  // [0, t0]
    double a = t0;
    for (int i = 0; i < n; ++i) {
        const double b = a * q, m = 0.5 * (a + b);
        // Simpson on [a, b]
        s += 2.0 * kPi * (b - a) / 6.0 *
             (vmf::pdf_cos(kappa, 1.0 - a) + 4.0 * vmf::pdf_cos(kappa, 1.0 - m) + vmf::pdf_cos(kappa, 1.0 - b));
        a = b;
    }
    return s;
}

}  // namespace

TEST(VmfMath, DensityIsNormalisedForEveryKappa) {
    for (double k : {0.0, 1e-12, 1e-6, 0.1, 1.0, 10.0, 128.0, 1e4, 1e6, 1e9}) {
        const double I = integrate_density(k);
        EXPECT_NEAR(I, 1.0, 1e-6) << "kappa " << k;
    }
}

TEST(VmfMath, DensityMatchesTextbookFormAndLargeKappaForm) {
    for (double k : {1e-3, 0.5, 1.0, 7.0, 50.0, 300.0}) {
        for (double c : {-1.0, -0.3, 0.0, 0.5, 0.99, 1.0}) {
            const long double ref = (long double)k / (4.0L * kPi * std::sinh((long double)k)) * std::exp((long double)k * c);
            EXPECT_NEAR(vmf::pdf_cos(k, c) / double(ref), 1.0, 1e-12) << k << " " << c;
        }
    }
    // κ -> 0: continuous to the uniform density; κ = 0 exactly is uniform.
    EXPECT_DOUBLE_EQ(vmf::pdf_cos(0.0, 0.3), 1.0 / (4.0 * kPi));
    EXPECT_NEAR(vmf::pdf_cos(1e-9, 1.0) * 4.0 * kPi, 1.0, 2e-9);
    // Eq. 7 differs by the factor 1 - exp(-2κ): negligible (below double rounding) for κ > 18.4.
    for (double k : {20.0, 128.0, 1e4}) EXPECT_DOUBLE_EQ(vmf::pdf_cos(k, 0.9), vmf::pdf_cos_large_kappa(k, 0.9));
    EXPECT_NEAR(vmf::pdf_cos_large_kappa(1.0, 0.2) / vmf::pdf_cos(1.0, 0.2), 1.0 - std::exp(-2.0), 1e-12);
    // Huge κ: finite everywhere (no sinh overflow), log-space normalisation consistent.
    for (double k : {1e6, 1e9, 1e300}) {
        EXPECT_TRUE(std::isfinite(vmf::pdf_cos(k, 1.0)));
        EXPECT_EQ(vmf::pdf_cos(k, 0.5), 0.0);
        EXPECT_TRUE(std::isfinite(vmf::log_norm(k)));
    }
    EXPECT_NEAR(vmf::log_norm(3.0), std::log(3.0 / (4.0 * kPi * std::sinh(3.0))), 1e-13);
    EXPECT_NEAR(vmf::log_norm(0.0), std::log(1.0 / (4.0 * kPi)), 1e-15);
}

// Kolmogorov–Smirnov test of w = μ·ω against the exact CDF P(1 − w <= t) =
// (1 − e^{−κt}) / (1 − e^{−2κ}), in the variable 1 − w returned without cancellation.
TEST(VmfMath, SamplerMatchesCdfAtEveryKappa) {
    const int n = 20000;
    const double crit = 1.95 / std::sqrt(double(n));  // KS 0.1% level, per κ
    for (double k : {0.0, 1e-8, 1.0, 128.0, 1e4, 1e6, 1e9}) {
        PCG32 rng(17);
        std::vector<double> t(n);
        for (int i = 0; i < n; ++i) vmf::sample_cos(k, rng.next_double(), &t[i]);
        std::sort(t.begin(), t.end());
        double D = 0.0;
        for (int i = 0; i < n; ++i) {
            const double F = k == 0.0 ? t[i] / 2.0 : -std::expm1(-k * t[i]) / -std::expm1(-2.0 * k);
            D = std::max({D, std::abs(F - double(i) / n), std::abs(F - double(i + 1) / n)});
        }
        EXPECT_LT(D, crit) << "kappa " << k;
    }
}

// At large κ the sampled directions keep their spread: E[κ θ² / 2] = 1 (θ ~ Rayleigh),
// which a sampler computing sin θ from 1 − w² would lose to cancellation.
TEST(VmfMath, SampledDirectionsKeepSpreadAtLargeKappa) {
    const Vec3 mu = normalize(Vec3(0.3f, -0.2f, 0.9f));
    for (double k : {1e2, 1e4, 1e6}) {
        PCG32 rng(5);
        const int n = 20000;
        double s = 0.0, s2 = 0.0;
        for (int i = 0; i < n; ++i) {
            const Vec3 w = vmf::sample(mu, k, {rng.next_float(), rng.next_float()});
            const double dx = double(w.x) - mu.x, dy = double(w.y) - mu.y, dz = double(w.z) - mu.z;
            const double chord2 = dx * dx + dy * dy + dz * dz;  // ≈ θ²
            const double v = k * chord2 / 2.0;
            s += v, s2 += v * v;
        }
        const double mean = s / n, se = std::sqrt((s2 / n - mean * mean) / n);
        EXPECT_NEAR(mean, 1.0, 5.0 * se + (k >= 1e6 ? 0.02 : 0.0)) << "kappa " << k;
        EXPECT_GT(se, 0.0);
    }
}

TEST(VmfMath, CubicRootIsExact) {
    for (int i = -60; i <= 90; ++i) {
        const double k = std::pow(10.0, i / 10.0);
        const double r = vmf::r_from_kappa(k);
        ASSERT_GE(r, 0.0);
        ASSERT_LT(r, 1.0);
        // Long-double bisection of the cubic in e = 1 - r on (0, 1].
        long double lo = 0.0L, hi = 1.0L;
        for (int it = 0; it < 200; ++it) {
            const long double e = 0.5L * (lo + hi);
            const long double g = (long double)k * e * (2.0L - e) - (1.0L - e) * (2.0L + 2.0L * e - e * e);
            (g < 0.0L ? lo : hi) = e;
        }
        const double e_ref = double(0.5L * (lo + hi));
        // r to double rounding (its e = 1 - r then carries r's absolute rounding, 1.1e-16, i.e.
        // a relative 1.1e-16 κ at large κ).
        EXPECT_NEAR(r, double(1.0L - (long double)e_ref), 2.3e-16) << "kappa " << k;
        EXPECT_NEAR((1.0 - r) / e_ref, 1.0, 1e-13 + 4e-16 * k) << "kappa " << k;
        // Eq. 8 inverts it.
        EXPECT_NEAR(vmf::kappa_from_r(r) / k, 1.0, 1e-12 + 4e-16 * k) << "kappa " << k;
        // The closed form alone agrees where it does not cancel.
        if (k <= 100.0) {
            EXPECT_NEAR(vmf::r_from_kappa_closed_form(k), r, 1e-12) << "kappa " << k;
        }
    }
    EXPECT_EQ(vmf::r_from_kappa(0.0), 0.0);
    EXPECT_EQ(vmf::r_from_kappa(-1.0), 0.0);
    EXPECT_EQ(vmf::r_from_kappa(INFINITY), 1.0);
}

// The paper's 1024-entry table (§4): its error, reported and bounded.
TEST(VmfMath, TableErrorIsReported) {
    const vmf::RTable &T = vmf::RTable::get();
    double max_dr = 0.0, max_dk = 0.0, k_at = 0.0;
    for (int i = -40; i <= 70; ++i) {
        for (int j = 0; j < 10; ++j) {
            const double k = std::pow(10.0, (i + j / 10.0 + 0.037) / 10.0);
            const double r = vmf::r_from_kappa(k), rt = T.lookup(k);
            max_dr = std::max(max_dr, std::abs(rt - r));
            const double dk = std::abs(vmf::kappa_from_r(rt) / k - 1.0);
            if (dk > max_dk) max_dk = dk, k_at = k;
        }
    }
    std::printf("[ vmf table ] 1024 entries: max |r_table - r| = %.3g, max relative kappa error = %.3g (at kappa %.3g)\n",
                max_dr, max_dk, k_at);
    RecordProperty("max_r_error", std::to_string(max_dr));
    RecordProperty("max_kappa_rel_error", std::to_string(max_dk));
    EXPECT_LT(max_dr, 2e-6);
    EXPECT_LT(max_dk, 3e-3);
    EXPECT_EQ(T.lookup(0.0), 0.0);
    EXPECT_EQ(T.lookup(INFINITY), 1.0);
}

TEST(VmfMath, KappaFromRExtremes) {
    EXPECT_EQ(vmf::kappa_from_r(0.0), 0.0);
    EXPECT_EQ(vmf::kappa_from_r(-0.5), 0.0);
    EXPECT_EQ(vmf::kappa_from_r(NAN), 0.0);
    EXPECT_EQ(vmf::kappa_from_r(1.0), vmf::kMaxKappa);
    EXPECT_EQ(vmf::kappa_from_r(1.5), vmf::kMaxKappa);
    double prev = 0.0;
    for (double e = 1.0 - 1e-6; e > 1e-18; e *= 0.7) {
        const double r = 1.0 - e;
        const double k = vmf::kappa_from_r(r);
        EXPECT_TRUE(std::isfinite(k));
        EXPECT_GE(k, prev);  // strictly until the clamp at kMaxKappa
        if (k < vmf::kMaxKappa && r < 1.0) {
            EXPECT_GT(k, prev);
        }
        prev = k;
    }
    EXPECT_NEAR(vmf::kappa_from_r(1e-9), 3e-9, 1e-20);  // κ ≈ 3r for small r
}

TEST(VmfMath, ConvolutionAndMeanCosine) {
    EXPECT_DOUBLE_EQ(vmf::convolve_kappa(100.0, 300.0), 75.0);
    EXPECT_DOUBLE_EQ(vmf::convolve_kappa(100.0, INFINITY), 100.0);
    EXPECT_DOUBLE_EQ(vmf::convolve_kappa(INFINITY, 7.0), 7.0);
    EXPECT_EQ(vmf::convolve_kappa(0.0, 0.0), 0.0);
    // A(κ) = E[μ·ω] by quadrature.
    for (double k : {1e-4, 0.5, 3.0, 40.0, 1e3}) {
        const int n = 200000;
        double s = 0.0, z = 0.0;
        for (int i = 0; i < n; ++i) {
            const double w = -1.0 + (i + 0.5) * 2.0 / n;
            const double p = vmf::pdf_cos(k, w);
            s += w * p, z += p;
        }
        EXPECT_NEAR(vmf::mean_cosine(k), s / z, 1e-6) << k;
    }
}

// ---- BRDF MIP-maps ----

namespace {
VmfMap one_texel(std::vector<VmfLobe> lobes, VmfMode mode) {
    VmfMap::Params p;
    p.mode = mode;
    return VmfMap(1, 1, int(lobes.size()), [&](int, int, VmfLobe *o) {
        std::copy(lobes.begin(), lobes.end(), o);
        return int(lobes.size());
    }, p);
}
const float kH = 0.70710678f;
}  // namespace

TEST(VmfMap, CellsFollowTheTangentAxes) {
    EXPECT_EQ(VmfMap::cell_of(Vec3(0, 0, 1)), 0);
    EXPECT_EQ(VmfMap::cell_of(Vec3(kH, 0, kH)), 0);
    EXPECT_EQ(VmfMap::cell_of(Vec3(0.9f, 0.1f, 0.42f)), 1);  // z <= 1/2: lower band
    EXPECT_EQ(VmfMap::cell_of(Vec3(0, kH, kH)) / 2, 1);
    EXPECT_EQ(VmfMap::cell_of(Vec3(-kH, 0, kH)) / 2, 2);
    EXPECT_EQ(VmfMap::cell_of(Vec3(0.1f, -0.9f, 0.3f)) / 2, 3);
    EXPECT_EQ(VmfMap::cell_of(Vec3(0, 0, -1)) % 2, 1);
}

TEST(VmfMap, OneLobeRoundTrips) {
    const Vec3 mu = normalize(Vec3(0.2f, -0.1f, 0.95f));
    for (double k : {0.5, 128.0, 1e4, 1e6}) {
        for (VmfMode m : {VmfMode::Adaptive, VmfMode::Single, VmfMode::Four, VmfMode::Eight, VmfMode::Naive, VmfMode::Direct}) {
            VmfMap map = one_texel({{mu, k, 1.0}}, m);
            VmfLookup L;
            map.lookup(FootprintFilter::Trilinear, 0.3f, 0.6f, 0, 0, 0, 0, 8.f, L);
            ASSERT_EQ(L.count, 1);
            EXPECT_NEAR(L.lobes[0].kappa / k, 1.0, 1e-4 + 1e-7 * k);  // float storage of r
            EXPECT_NEAR(dot(L.lobes[0].mu, mu), 1.f, 1e-6f);
            EXPECT_NEAR(L.lobes[0].weight, 1.0, 1e-6);
        }
    }
}

// The Tablecloth BRDF (two κ = 128 lobes at ±45°): one averaged lobe is far too wide
// (‖r‖ ≈ 0.70 < ε0), the 1×4 cells separate the lobes exactly.
TEST(VmfMap, AdaptiveSplitsTheTwoLobeBrdf) {
    const std::vector<VmfLobe> two = {{Vec3(kH, 0, kH), 128.0, 0.5}, {Vec3(-kH, 0, kH), 128.0, 0.5}};
    VmfLookup L;
    one_texel(two, VmfMode::Adaptive).lookup(FootprintFilter::Trilinear, 0.5f, 0.5f, 0, 0, 0, 0, 8.f, L);
    ASSERT_EQ(L.count, 2);
    EXPECT_EQ(L.cells, 4);
    for (int j = 0; j < 2; ++j) {
        EXPECT_NEAR(L.lobes[j].kappa, 128.0, 0.02);
        EXPECT_NEAR(L.lobes[j].weight, 0.5, 1e-6);
        EXPECT_NEAR(std::abs(L.lobes[j].mu.x), kH, 1e-6);
    }
    one_texel(two, VmfMode::Single).lookup(FootprintFilter::Trilinear, 0.5f, 0.5f, 0, 0, 0, 0, 8.f, L);
    ASSERT_EQ(L.count, 1);
    const double r = vmf::r_from_kappa(128.0) * kH;
    EXPECT_NEAR(L.lobes[0].kappa, vmf::kappa_from_r(r), 1e-3);
    EXPECT_NEAR(L.lobes[0].mu.z, 1.f, 1e-6f);
}

// Filtering is linear in (Σ w r, Σ w): the coarsest level is the exact average of the
// texels' characteristic vectors per cell (eq. 10, 15).
TEST(VmfMap, CoarsestLevelIsTheExactAverage) {
    const int N = 8;
    PCG32 rng(3);
    std::vector<VmfLobe> texels(N * N);
    for (VmfLobe &l : texels) {
        l.mu = normalize(Vec3(0.4f * (rng.next_float() - 0.5f), 0.4f * (rng.next_float() - 0.5f), 1.f));
        l.kappa = 20.0 + 200.0 * rng.next_float();
        l.weight = 1.0;
    }
    VmfMap::Params p;
    p.mode = VmfMode::Single;
    VmfMap map(N, N, 1, [&](int x, int y, VmfLobe *o) { o[0] = texels[y * N + x]; return 1; }, p);
    double R[3] = {0, 0, 0};
    for (const VmfLobe &l : texels) {
        const double r = vmf::r_from_kappa(l.kappa);
        R[0] += r * l.mu.x / (N * N), R[1] += r * l.mu.y / (N * N), R[2] += r * l.mu.z / (N * N);
    }
    const double len = std::sqrt(R[0] * R[0] + R[1] * R[1] + R[2] * R[2]);
    VmfLookup L;
    map.lookup(FootprintFilter::Trilinear, 0.5f, 0.5f, 4.f, 0.f, 0.f, 4.f, 8.f, L);  // far beyond the map
    ASSERT_EQ(L.count, 1);
    EXPECT_NEAR(L.lobes[0].kappa / vmf::kappa_from_r(len), 1.0, 1e-4);
    EXPECT_NEAR(L.lobes[0].mu.z, R[2] / len, 1e-6);
    // Naive: plain averages of μ (renormalised) and κ.
    p.mode = VmfMode::Naive;
    VmfMap naive(N, N, 1, [&](int x, int y, VmfLobe *o) { o[0] = texels[y * N + x]; return 1; }, p);
    double K = 0;
    for (const VmfLobe &l : texels) K += l.kappa / (N * N);
    naive.lookup(FootprintFilter::Trilinear, 0.5f, 0.5f, 4.f, 0.f, 0.f, 4.f, 8.f, L);
    EXPECT_NEAR(L.lobes[0].kappa / K, 1.0, 1e-5);
    // Direct: the texel under the point, unfiltered.
    p.mode = VmfMode::Direct;
    VmfMap direct(N, N, 1, [&](int x, int y, VmfLobe *o) { o[0] = texels[y * N + x]; return 1; }, p);
    direct.lookup(FootprintFilter::Trilinear, (3 + 0.5f) / N, (5 + 0.2f) / N, 4.f, 0.f, 0.f, 4.f, 8.f, L);
    EXPECT_NEAR(L.lobes[0].kappa, texels[5 * N + 3].kappa, 1e-4 * texels[5 * N + 3].kappa);
}

TEST(VmfMap, LeanMomentsOfALobe) {
    const SlopeGaussian g = vmf_lobe_slopes(Vec3(0, 0, 1), 200.0);
    EXPECT_EQ(g.mx, 0.0);
    EXPECT_NEAR(g.sxx, 1.0 / 200.0, 1e-12);
    EXPECT_NEAR(g.syy, 1.0 / 200.0, 1e-12);
    // Tilted 45° along x: slope -1, variance along x (1/z² + x²/z⁴)/κ = 4/κ, along y 2/κ.
    const SlopeGaussian t = vmf_lobe_slopes(Vec3(kH, 0, kH), 100.0);
    EXPECT_NEAR(t.mx, -1.0, 1e-6);
    EXPECT_NEAR(t.sxx, 0.04, 1e-6);
    EXPECT_NEAR(t.syy, 0.02, 1e-6);
    // The moment-matched Gaussian of the two-lobe BRDF: mean 0, variance 1 + 4/κ along x.
    VmfLookup L;
    one_texel({{Vec3(kH, 0, kH), 128.0, 0.5}, {Vec3(-kH, 0, kH), 128.0, 0.5}}, VmfMode::Lean)
        .lookup(FootprintFilter::Trilinear, 0.5f, 0.5f, 0, 0, 0, 0, 8.f, L);
    ASSERT_TRUE(L.gaussian);
    EXPECT_NEAR(L.slopes.mx, 0.0, 1e-6);
    EXPECT_NEAR(L.slopes.sxx, 1.0 + 4.0 / 128.0, 1e-5);
    // Extremes: finite.
    for (double k : {0.0, 1e-9, 1e9})
        for (Vec3 mu : {Vec3(1, 0, 0), Vec3(0, 0, -1), Vec3(0, 0, 1)}) {
            const SlopeGaussian e = vmf_lobe_slopes(mu, k);
            EXPECT_TRUE(std::isfinite(e.mx + e.my + e.sxx + e.syy + e.sxy));
        }
}

// ---- the material ----

// The specular value is ks Σ w_j γ_j(h) / (4 wo·h) (the paper's half-vector BRDF with the
// reflection Jacobian).
TEST(VmfMaterial, TwoLobeValueMatchesTheFormula) {
    auto m = make(R"({"type":"vmf","lobes":[{"direction":[0.70710678,0,0.70710678],"kappa":128},
                     {"direction":[-0.70710678,0,0.70710678],"kappa":128,"weight":3}],"specular":0.8,"diffuse":0.1})");
    const ShadingContext ctx;
    for (auto [wo, wi] : {std::pair{dir_deg(45, 0), dir_deg(45, 0)}, {dir_deg(30, 180), dir_deg(60, 180)},
                          {dir_deg(10, 90), dir_deg(70, 0)}}) {
        const Vec3 h = normalize(wo + wi);
        const double spec = 0.25 * vmf::pdf(normalize(Vec3(kH, 0, kH)), 128.0, h) +
                            0.75 * vmf::pdf(normalize(Vec3(-kH, 0, kH)), 128.0, h);
        const double expect = 0.1 * wi.z / kPi + 0.8 * spec / (4.0 * dot(wo, h));
        EXPECT_NEAR(m->eval(ctx, wo, wi).g / expect, 1.0, 1e-4);  // float directions: κ dc ~ 128 * 1e-7
    }
}

// κ = 0 is the uniform lobe; κ -> 0 reaches it continuously; vectors cancelling exactly in
// one cell (single mode, lobes along ±x) give κ = 0 too; κ = 1e6 and ‖r‖ -> 1 stay finite.
TEST(VmfMaterial, ExtremesAreFiniteAndContinuous) {
    const ShadingContext ctx;
    const Vec3 wo = dir_deg(30, 10), wi = dir_deg(50, 200);
    const double uniform = 1.0 / (4.0 * kPi) / (4.0 * dot(wo, normalize(wo + wi)));
    auto k0 = make(R"({"type":"vmf","lobes":[{"direction":[0,0,1],"kappa":0}]})");
    auto ktiny = make(R"({"type":"vmf","lobes":[{"direction":[0,0,1],"kappa":1e-7}]})");
    EXPECT_NEAR(k0->eval(ctx, wo, wi).g / uniform, 1.0, 1e-5);
    EXPECT_NEAR(ktiny->eval(ctx, wo, wi).g / uniform, 1.0, 1e-5);
    auto cancel = make(R"({"type":"vmf","mode":"single","lobes":[{"direction":[1,0,0],"kappa":50},{"direction":[-1,0,0],"kappa":50}]})");
    EXPECT_NEAR(cancel->eval(ctx, wo, wi).g / uniform, 1.0, 1e-5);
    for (const char *j : {R"({"type":"vmf","lobes":[{"direction":[0,0,1],"kappa":1e6}]})",
                          R"({"type":"vmf","lobes":[{"direction":[0.3,0,1],"kappa":1e30}],"shadowing":"smith"})",
                          R"({"type":"vmf","exponent":1e12,"fresnel":"schlick","specular":0.04,"diffuse":0.5})",
                          R"({"type":"vmf","mode":"lean","lobes":[{"direction":[1,0,0.001],"kappa":0}],"shadowing":"smith"})",
                          R"({"type":"vmf","lobes":[{"direction":[0,0,-1],"kappa":5}],"fresnel":"Au"})"}) {
        auto m = make(j);
        PCG32 rng(1);
        for (int i = 0; i < 2000; ++i) {
            const Vec3 a = dir_deg(89.9 * rng.next_float(), 360 * rng.next_float());
            const Vec3 b = dir_deg(89.9 * rng.next_float(), 360 * rng.next_float());
            const Spectrum v = m->eval(ctx, a, b);
            const float p = m->pdf(ctx, a, b);
            ASSERT_TRUE(std::isfinite(v.r + v.g + v.b) && v.r >= 0.f && v.g >= 0.f && v.b >= 0.f) << j;
            ASSERT_TRUE(std::isfinite(p) && p >= 0.f) << j;
            BSDFSample s;
            if (m->sample(ctx, a, rng.next_float(), {rng.next_float(), rng.next_float()}, s)) {
                ASSERT_TRUE(std::isfinite(s.weight.r + s.weight.g + s.weight.b) && s.weight.r >= 0.f && s.weight.b >= 0.f) << j;
                ASSERT_TRUE(std::isfinite(s.pdf) && s.pdf > 0.f) << j;
            }
        }
    }
}

// The filtered BRDF at a footprint covering the whole map against the exact average of the
// finest-level BRDFs over all texels (eq. 5), on a Gaussian normal map with the two-lobe
// Tablecloth BRDF: the adaptive mixture is closer than one lobe, naive MIP-mapping and LEAN.
TEST(VmfMaterial, AdaptiveIsClosestToTheTexelAverage) {
    const std::string base = R"("heightmap":{"map":{"generator":"gaussian","size":64,"correlation":0.05,"sxx":0.08,"syy":0.08,"seed":4}},
        "lobes":[{"direction":[0.70710678,0,0.70710678],"kappa":128},{"direction":[-0.70710678,0,0.70710678],"kappa":128}])";
    auto direct = make(R"({"type":"vmf","mode":"direct",)" + base + "}");
    std::vector<std::pair<Vec3, Vec3>> dirs;
    PCG32 rng(9);
    for (int i = 0; i < 200; ++i) {
        const Vec3 wo = dir_deg(75 * rng.next_float(), 360 * rng.next_float());
        const Vec3 wi = dir_deg(75 * rng.next_float(), 360 * rng.next_float());
        dirs.push_back({wo, wi});
    }
    // Exact average over the 64 x 64 texels (their centres, no footprint).
    std::vector<double> ref(dirs.size(), 0.0);
    const int N = 64;
    for (int y = 0; y < N; ++y)
        for (int x = 0; x < N; ++x) {
            ShadingContext c;
            c.uv = Vec2((x + 0.5f) / N, (y + 0.5f) / N);
            for (size_t i = 0; i < dirs.size(); ++i) ref[i] += direct->eval(c, dirs[i].first, dirs[i].second).g / (N * N);
        }
    ShadingContext wide;
    wide.uv = Vec2(0.5f, 0.5f);
    wide.dudx = wide.dvdy = 2.f;  // beyond the map: the coarsest (1 x 1) level
    double norm = 0.0;
    for (double r : ref) norm += r * r;
    auto error = [&](const std::string &mode) {
        auto m = make(R"({"type":"vmf","mode":")" + mode + R"(",)" + base + "}");
        double e = 0.0;
        for (size_t i = 0; i < dirs.size(); ++i) {
            const double d = m->eval(wide, dirs[i].first, dirs[i].second).g - ref[i];
            e += d * d;
        }
        return std::sqrt(e / norm);
    };
    const double adaptive = error("adaptive"), single = error("single"), naive = error("naive"), lean = error("lean"),
                 eight = error("2x4");
    std::printf("[ vmf filter ] relative L2 BRDF error vs texel average: adaptive %.4f  2x4 %.4f  1x1 %.4f  naive %.4f  lean %.4f\n",
                adaptive, eight, single, naive, lean);
    EXPECT_LT(adaptive, 0.5 * single);
    EXPECT_LT(adaptive, 0.5 * naive);
    EXPECT_LT(adaptive, 0.5 * lean);
    EXPECT_LT(adaptive, 0.25);
}

// A BRDF map of lobes: directions and κ from textures, resampled to the grid's texel centres.
TEST(VmfMaterial, LobeMapsAreReadPerTexel) {
    // 2 x 2 grid: texel centres (0.25, 0.25), (0.75, 0.25), ... on a checkerboard of scale 2.
    auto m = make(R"({"type":"vmf","mode":"direct","resolution":[2,2],
        "lobes":[{"direction":{"type":"checkerboard","color0":[0,0,1],"color1":[1,0,1],"scale":2},
                  "kappa":{"type":"checkerboard","color0":50,"color1":500,"scale":2}}]})");
    const Vec3 wo = dir_deg(30, 0), wi = dir_deg(30, 180);  // h = z
    const Vec3 h(0.f, 0.f, 1.f);
    ShadingContext c;
    c.uv = Vec2(0.25f, 0.25f);  // check (0, 0): color0
    EXPECT_NEAR(m->eval(c, wo, wi).g, vmf::pdf(h, 50.0, h) / (4.0 * dot(wo, h)), 1e-3);
    c.uv = Vec2(0.75f, 0.25f);  // check (1, 0): color1, direction (1, 0, 1)/sqrt 2
    const Vec3 mu = normalize(Vec3(1.f, 0.f, 1.f));  // retro-reflection along mu: h = mu
    EXPECT_NEAR(m->eval(c, mu, mu).g / (vmf::pdf(mu, 500.0, mu) / 4.0), 1.0, 1e-3);
    EXPECT_LT(m->eval(c, wo, wi).g, 1e-30);  // h = z is 45 degrees off that lobe
}

TEST(VmfMaterial, BadInputIsRejected) {
    for (const char *j : {R"({"type":"vmf","mode":"fancy"})", R"({"type":"vmf","exponent":-1})",
                          R"({"type":"vmf","lobes":[]})", R"({"type":"vmf","lobes":[{"direction":[0,0,0],"kappa":1}]})",
                          R"({"type":"vmf","lobes":[{"direction":[0,0,1],"kappa":-2}]})",
                          R"({"type":"vmf","lobes":[{"direction":[0,0,1],"kappa":2,"weight":0}]})",
                          R"({"type":"vmf","lobes":[{"direction":[0,0,1],"kappa":2,"colour":1}]})",
                          R"({"type":"vmf","exponent":10,"lobes":[{"direction":[0,0,1],"kappa":2}]})",
                          R"({"type":"vmf","fresnel":"Unobtainium"})", R"({"type":"vmf","shadowing":"yes"})",
                          R"({"type":"vmf","epsilon0":1.5})", R"({"type":"vmf","ndf_kappa":"auto"})",
                          R"({"type":"vmf","resolution":[0,4]})", R"({"type":"vmf","r_solver":"newton"})"}) {
        EXPECT_THROW(make(j), std::exception) << j;
    }
}

// Enumerated parameters go through Properties::get_enum / get_choice: the error names the
// JSON path and every allowed value.
TEST(VmfMaterial, EnumeratedParametersNameTheChoices) {
    auto error_of = [](const std::string &json) -> std::string {
        try {
            make(json);
        } catch (const MesoError &e) {
            return e.what();
        }
        return "";
    };
    EXPECT_EQ(error_of(R"({"type":"vmf","mode":"fancy"})"),
              "material.mode: expected \"adaptive\", \"single\", \"1x1\", \"1x4\", \"2x4\", \"naive\", \"lean\" or "
              "\"direct\", got \"fancy\"");
    EXPECT_EQ(error_of(R"({"type":"vmf","r_solver":"newton"})"),
              "material.r_solver: expected \"exact\" or \"table\", got \"newton\"");
    EXPECT_EQ(error_of(R"({"type":"vmf","shadowing":"yes"})"),
              "material.shadowing: expected \"none\" or \"smith\", got \"yes\"");
    EXPECT_EQ(error_of(R"({"type":"vmf","filter":"box"})"),
              "material.filter: expected \"trilinear\", \"ewa\" or \"none\", got \"box\"");
    EXPECT_EQ(error_of(R"({"type":"vmf","fresnel":"Unobtainium"})"),
              "material.fresnel: expected \"none\", \"schlick\", \"Ag\", \"Al\", \"Au\", \"Cr\", \"Cu\", \"Ni\" or "
              "\"W\", got \"Unobtainium\"");
}
