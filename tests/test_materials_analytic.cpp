// Analytic values of the shared Fresnel / microfacet math and of single materials (the
// eighth part of the material battery, test_materials.cpp).
#include <gtest/gtest.h>
#include <cmath>
#include <complex>
#include <string>
#include <vector>
#include <cstdio>
#include "bsdf/fresnel.h"
#include "bsdf/material.h"
#include "bsdf/microfacet.h"
#include "material_test_util.h"
#include "sampling/rng.h"
#include "sampling/warp.h"

using namespace meso;
using meso::test::dir_deg;
using meso::test::kCtx;
using meso::test::make_material;
// ------------------------------------------------------------------ 8: analytic values

TEST(MaterialAnalytic, DiffuseIsRhoOverPiCos) {
    auto m = make_material(R"({"type":"diffuse","reflectance":[0.2,0.5,0.8]})");
    Vec3 wo = dir_deg(25, 40), wi = dir_deg(60, 300);
    Spectrum v = m->eval(kCtx, wo, wi);
    EXPECT_NEAR(v.r, 0.2 / M_PI * 0.5, 1e-6);
    EXPECT_NEAR(v.b, 0.8 / M_PI * 0.5, 1e-6);
    EXPECT_NEAR(m->pdf(kCtx, wo, wi), 0.5 / M_PI, 1e-6);
    auto def = make_material(R"({"type":"diffuse"})");
    EXPECT_NEAR(def->eval(kCtx, wo, wi).g, 0.5 / M_PI * 0.5, 1e-6);
}

TEST(MaterialAnalytic, SmoothConductorNoneIsAPerfectMirror) {
    auto m = make_material(R"({"type":"conductor","material":"none"})");
    EXPECT_EQ(m->flags(), uint32_t(BSDF_DeltaReflection));
    for (double t : {0.0, 45.0, 89.0, 89.99}) {
        Vec3 wo = dir_deg(t, 33);
        BSDFSample bs;
        ASSERT_TRUE(m->sample(kCtx, wo, 0.3f, {0.1f, 0.9f}, bs));
        EXPECT_EQ(bs.flags, uint32_t(BSDF_DeltaReflection));
        EXPECT_FLOAT_EQ(bs.weight.r, 1.f);
        EXPECT_FLOAT_EQ(bs.weight.b, 1.f);
        EXPECT_FLOAT_EQ(bs.pdf, 1.f);
        EXPECT_FLOAT_EQ(bs.wi.x, -wo.x);
        EXPECT_FLOAT_EQ(bs.wi.y, -wo.y);
        EXPECT_FLOAT_EQ(bs.wi.z, wo.z);
        EXPECT_TRUE(m->eval(kCtx, wo, bs.wi).is_black());  // delta lobes are never evaluated
        EXPECT_EQ(m->pdf(kCtx, wo, bs.wi), 0.f);
    }
}

TEST(MaterialAnalytic, DielectricFresnel) {
    for (float eta : {1.5f, 1.333f, 2.4f}) {
        float r0 = sqr((eta - 1) / (eta + 1));
        EXPECT_NEAR(fresnel_dielectric(1.f, eta).F, r0, 1e-6);
        EXPECT_NEAR(fresnel_dielectric(-1.f, eta).F, r0, 1e-6);  // from inside: same at normal incidence
        // Brewster: p-polarised reflectance vanishes, F = Rs/2
        double tb = std::atan(eta), ci = std::cos(tb), ct = std::sqrt(1 - std::sin(tb) * std::sin(tb) / (eta * eta));
        double rs = sqr((ci - eta * ct) / (ci + eta * ct));
        EXPECT_NEAR(fresnel_dielectric(float(ci), eta).F, 0.5 * rs, 1e-5);
        // total internal reflection beyond the critical angle, from inside
        float cc = std::sqrt(1 - 1 / (eta * eta));
        EXPECT_EQ(fresnel_dielectric(-0.9f * cc, eta).F, 1.f);
        EXPECT_LT(fresnel_dielectric(-std::min(1.f, 1.1f * cc), eta).F, 1.f);
        // Snell
        FresnelDielectric f = fresnel_dielectric(0.6f, eta);
        EXPECT_NEAR(std::sqrt(1 - f.cos_theta_t * f.cos_theta_t), 0.8 / eta, 1e-6);
        EXPECT_LT(f.cos_theta_t, 0.f);
        EXPECT_FLOAT_EQ(f.eta_it, eta);
    }
    EXPECT_EQ(fresnel_dielectric(0.7f, 1.f).F, 0.f);  // index matched
    EXPECT_EQ(fresnel_dielectric(0.f, 1.5f).F, 1.f);  // grazing
}

TEST(MaterialAnalytic, ConductorFresnelMatchesComplexFormula) {
    // Independent evaluation with complex arithmetic (Born & Wolf): n = eta + i k,
    // cos_t = sqrt(1 - sin_i^2 / n^2), rs = (ci - n ct)/(ci + n ct), rp = (n ci - ct)/(n ci + ct).
    auto reference = [](double ci, double eta, double k) {
        std::complex<double> n(eta, k), si2(1 - ci * ci, 0.0);
        std::complex<double> ct = std::sqrt(1.0 - si2 / (n * n));
        std::complex<double> rs = (ci - n * ct) / (ci + n * ct), rp = (n * ci - ct) / (n * ci + ct);
        return 0.5 * (std::norm(rs) + std::norm(rp));
    };
    Spectrum eta, k;
    ASSERT_TRUE(conductor_preset("Au", eta, k));
    for (double ci : {1.0, 0.9, 0.5, 0.2, 0.01})
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(fresnel_conductor(ci, eta[c], k[c]), reference(ci, eta[c], k[c]), 1e-9);
    // Normal incidence, textbook: ((n-1)^2 + k^2) / ((n+1)^2 + k^2). Gold is yellow: R > G > B.
    Spectrum r0 = fresnel_conductor(1.f, eta, k);
    for (int c = 0; c < 3; ++c)
        EXPECT_NEAR(r0[c], (sqr(eta[c] - 1) + sqr(k[c])) / (sqr(eta[c] + 1) + sqr(k[c])), 1e-6);
    EXPECT_GT(r0.r, r0.g);
    EXPECT_GT(r0.g, r0.b);
    EXPECT_LT(r0.b, 0.5);
    // Aluminium normal incidence ≈ 0.91-0.93 across the visible
    ASSERT_TRUE(conductor_preset("Al", eta, k));
    Spectrum al = fresnel_conductor(1.f, eta, k);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(al[c], 0.92, 0.015);
    EXPECT_EQ(fresnel_conductor(0.0, 0.2, 3.0), 1.0);  // grazing
    EXPECT_EQ(fresnel_conductor(0.7, 0.0, 1.0), 1.0);  // "none": eta 0, k 1 is a perfect mirror
    EXPECT_FALSE(conductor_preset("Unobtainium", eta, k));
}

// The spectral (three channels, single precision) conductor Fresnel against the complex
// formula in double, over every preset, metals beyond them (k up to 30, eta from 0 to 10) and
// cosines from normal to exactly grazing. Its a^2 = 2 eta^2 k^2 / (|n^2 - sin^2| - Re) form keeps
// the error at float round-off where the textbook form cancels (k >> eta).
TEST(MaterialAnalytic, ConductorFresnelSpectrumIsAccurate) {
    auto reference = [](double ci, double eta, double k) {
        if (eta == 0.0 && k == 0.0) return 1.0;
        std::complex<double> n(eta, k), si2(1 - ci * ci, 0.0);
        std::complex<double> ct = std::sqrt(1.0 - si2 / (n * n));
        std::complex<double> rs = (ci - n * ct) / (ci + n * ct), rp = (n * ci - ct) / (n * ci + ct);
        return ci == 0.0 ? 1.0 : 0.5 * (std::norm(rs) + std::norm(rp));
    };
    std::vector<std::pair<Spectrum, Spectrum>> cases;
    for (const char *name : {"Au", "Ag", "Al", "Cu", "Cr", "none"}) {
        Spectrum eta, k;
        if (conductor_preset(name, eta, k)) cases.push_back({eta, k});
    }
    ASSERT_GE(cases.size(), 5u);
    cases.push_back({Spectrum(0.01f, 1.f, 10.f), Spectrum(30.f, 0.f, 0.5f)});
    cases.push_back({Spectrum(0.f, 0.f, 1.5f), Spectrum(0.f, 5.f, 0.f)});
    double worst = 0;
    for (const auto &[eta, k] : cases)
        for (float ci : {1.f, 0.999f, 0.9f, 0.5f, 0.2f, 0.05f, 1e-3f, 1e-6f, 0.f, -0.7f}) {
            const Spectrum F = fresnel_conductor(ci, eta, k);
            for (int c = 0; c < 3; ++c) {
                const double ref = reference(std::min(1.0, std::abs(double(ci))), eta[c], k[c]);
                worst = std::max(worst, std::abs(F[c] - ref));
                EXPECT_NEAR(F[c], ref, 2e-6) << "cos " << ci << " eta " << eta[c] << " k " << k[c];
            }
        }
    std::printf("worst |F - F_complex| = %.2g\n", worst);
}

TEST(MaterialAnalytic, DiffuseFresnelReflectance) {
    // Energy balance of a smooth interface: 1 − F_dr(1/η) = (1 − F_dr(η)) / η².
    for (double eta : {1.1, 1.33, 1.5, 2.0, 2.4}) {
        double ext = fresnel_diffuse_reflectance(eta), in = fresnel_diffuse_reflectance(1.0 / eta);
        EXPECT_NEAR(1.0 - in, (1.0 - ext) / (eta * eta), 1e-6) << eta;
    }
    // η = 1.5: F_dr ≈ 0.0918 (external); internal ≈ 0.596 (d'Eon & Irving 2011, tables)
    EXPECT_NEAR(fresnel_diffuse_reflectance(1.5), 0.0918, 5e-4);
    EXPECT_NEAR(fresnel_diffuse_reflectance(1.0 / 1.5), 0.5963, 5e-4);
    EXPECT_EQ(fresnel_diffuse_reflectance(1.0), 0.0);
}

TEST(MaterialAnalytic, SmoothDielectricSplitsByFresnel) {
    auto m = make_material(R"({"type":"dielectric","int_ior":1.5,"ext_ior":1.0})");
    for (double t : {0.0, 40.0, 80.0, 140.0}) {
        Vec3 wo = dir_deg(t, 15);
        FresnelDielectric fr = fresnel_dielectric(wo.z, 1.5f);
        PCG32 rng(11);
        const int n = 100000;
        int refl = 0;
        for (int i = 0; i < n; ++i) {
            BSDFSample bs;
            ASSERT_TRUE(m->sample(kCtx, wo, rng.next_float(), {0.5f, 0.5f}, bs));
            if (bs.flags & BSDF_DeltaReflection) {
                ++refl;
                EXPECT_FLOAT_EQ(bs.weight.g, 1.f);
                EXPECT_FLOAT_EQ(bs.pdf, fr.F);
            } else {
                // Snell + radiance scaling (η_o/η_i)², η relative to the side of wo
                EXPECT_NEAR(bs.weight.g, fr.eta_ti * fr.eta_ti, 1e-6);
                EXPECT_NEAR(bs.eta, fr.eta_it, 1e-6);
                float sin_o = std::sqrt(1 - wo.z * wo.z), sin_i = std::sqrt(std::max(0.f, 1 - bs.wi.z * bs.wi.z));
                EXPECT_NEAR(sin_i * fr.eta_it, sin_o, 1e-5);
                EXPECT_LT(bs.wi.z * wo.z, 0.f);
            }
        }
        double sd = std::sqrt(n * fr.F * (1 - fr.F));
        EXPECT_NEAR(refl, n * fr.F, 5 * sd + 1) << "theta " << t;
    }
}

TEST(MaterialAnalytic, RoughConductorEvalFormula) {
    // Hand-evaluated Cook-Torrance at one configuration: GGX α = 0.3, F = 1.
    auto m = make_material(R"({"type":"conductor","alpha":0.3})");
    Vec3 wo = dir_deg(30, 0), wi = dir_deg(50, 180);
    Vec3 h = normalize(wo + wi);
    double a2 = 0.09, c2 = h.z * h.z;
    double D = 1.0 / (M_PI * a2 * sqr(c2 + (1 - c2) / a2) * 1.0);  // = 1/(π α² cos⁴ (1 + tan²/α²)²)
    D = 1.0 / (M_PI * a2 * sqr(c2) * sqr(1 + (1 - c2) / c2 / a2));
    auto lambda = [&](Vec3 w) { double t2 = (1 - w.z * w.z) / (w.z * w.z); return (-1 + std::sqrt(1 + a2 * t2)) / 2; };
    double G = 1.0 / (1 + lambda(wo) + lambda(wi));
    double expected = D * G / (4 * wo.z);
    EXPECT_NEAR(m->eval(kCtx, wo, wi).g / expected, 1.0, 1e-5);
}

TEST(MaterialAnalytic, MicrofacetNormalisation) {
    // ∫ D(m) m.z dm = 1 and ∫ D_wo(m) dm = 1 (visible normals, Heitz 2014 eq. 10) —
    // midpoint rule in (θ, φ), with θ substituted by tan θ = α t to resolve the lobe.
    for (MicrofacetType type : {MicrofacetType::GGX, MicrofacetType::Beckmann})
        for (auto [au, av] : {std::pair<float, float>{0.3f, 0.3f}, {0.1f, 0.5f}, {1.0f, 1.0f}}) {
            MicrofacetDistribution d(type, au, av, true);
            Vec3 wo = dir_deg(70, 30);
            double s1 = 0, s2 = 0;
            const int nt = 2000, np = 360;
            const double tmax = M_PI / 2;
            for (int i = 0; i < nt; ++i) {
                double th = (i + 0.5) / nt * tmax;
                for (int j = 0; j < np; ++j) {
                    double ph = (j + 0.5) / np * 2 * M_PI;
                    Vec3 m(float(std::sin(th) * std::cos(ph)), float(std::sin(th) * std::sin(ph)), float(std::cos(th)));
                    double w = std::sin(th) * (tmax / nt) * (2 * M_PI / np);
                    s1 += d.D(m) * m.z * w;
                    s2 += d.pdf(wo, m) * w;
                }
            }
            EXPECT_NEAR(s1, 1.0, 3e-3) << int(type) << " " << au << " " << av;
            EXPECT_NEAR(s2, 1.0, 3e-3) << int(type) << " " << au << " " << av;
        }
}

TEST(MaterialAnalytic, SmithHeightCorrelatedProperties) {
    MicrofacetDistribution d(MicrofacetType::GGX, 0.4f, 0.4f);
    Vec3 wo = dir_deg(60, 0), wi = dir_deg(70, 170), m = normalize(wo + wi);
    double g1o = d.G1(wo, m), g1i = d.G1(wi, m), g = d.G(wo, wi, m);
    EXPECT_GE(g, g1o * g1i - 1e-7);  // never darker than the separable form
    EXPECT_LE(g, std::min(g1o, g1i) + 1e-7);
    EXPECT_NEAR(d.G(wi, wo, m), g, 1e-7);  // symmetric
    EXPECT_EQ(d.G1(dir_deg(90, 0), Vec3(0, 0, 1)), 0.f);  // exactly grazing: fully masked
    // Transmission form: B(1+Λo, 1+Λi) equals 1/(1+Λo+Λi)·... only when one Λ is 0.
    Vec3 below = dir_deg(140, 180);
    Vec3 mt = Vec3(0.f, 0.f, 1.f);
    EXPECT_NEAR(d.G(Vec3(0, 0, 1), below, mt), 1.0 / (1.0 + d.lambda(below)), 1e-6);
    // erfinv
    for (double y : {-0.999999, -0.7, 0.0, 0.3, 0.99, 0.9999999999})
        EXPECT_NEAR(std::erf(erfinv(y)), y, 1e-14 + 1e-12 * (1 - std::abs(y)));
}

TEST(MaterialAnalytic, BlinnPhongSmithLambda) {
    // The defining projected-area identity ∫ max(0, w·m) D(m) dm = cos θ (1 + Λ(w)),
    // checked by brute-force 2D quadrature, independent of the closed-form azimuth.
    for (double s : {0.0, 1.0, 7.0, 50.0})
        for (double t : {30.0, 70.0, 85.0, 89.0}) {
            double th_o = t * M_PI / 180, mu = std::cos(th_o), area = 0;
            const int nt = 3000, np = 720;
            for (int i = 0; i < nt; ++i) {
                double th = (i + 0.5) / nt * M_PI / 2, D = (s + 2) / (2 * M_PI) * std::pow(std::cos(th), s);
                for (int j = 0; j < np; ++j) {
                    double ph = (j + 0.5) / np * 2 * M_PI;
                    double c = std::sin(th_o) * std::sin(th) * std::cos(ph) + mu * std::cos(th);
                    if (c > 0) area += c * D * std::sin(th) * (M_PI / 2 / nt) * (2 * M_PI / np);
                }
            }
            double lambda = blinnphong_lambda(s, mu);
            EXPECT_NEAR(area, mu * (1 + lambda), 2e-4 * area) << "s " << s << " theta " << t;
            BlinnPhongLambdaTable table(s);
            // what matters is G1 = 1/(1 + Λ): relative error of 1 + Λ
            EXPECT_NEAR(table(mu), lambda, 1e-4 * (1 + lambda)) << "s " << s << " theta " << t;
        }
    // large exponents: the Beckmann Λ at α = sqrt(2/(s+2)) (Walter 2007 §5.2)
    for (double s : {1000.0, 1e6}) {
        MicrofacetDistribution beck(MicrofacetType::Beckmann, float(std::sqrt(2 / (s + 2))), float(std::sqrt(2 / (s + 2))));
        BlinnPhongLambdaTable table(s);
        for (double t : {80.0, 89.0, 89.9, 89.99}) {
            Vec3 w = dir_deg(t, 0);
            double lb = beck.lambda(w);
            EXPECT_NEAR(blinnphong_lambda(s, w.z), lb, 3e-3 * lb + 1e-7) << s << " " << t;
            EXPECT_NEAR(table(w.z), lb, 3e-3 * lb + 1e-7) << s << " " << t;
        }
    }
    EXPECT_EQ(blinnphong_lambda(10, 1.0), 0.0);
    EXPECT_TRUE(std::isinf(blinnphong_lambda(10, 0.0)));
}

TEST(MaterialAnalytic, BlinnPhongTexturedExponentMatchesConstant) {
    // A textured exponent takes the direct-quadrature Λ path, a constant one the table.
    auto tex = make_material(
        R"({"type":"blinnphong","exponent":{"type":"checkerboard","color0":5,"color1":50},"eta":1.5})");
    auto c5 = make_material(R"({"type":"blinnphong","exponent":5,"eta":1.5})");
    auto c50 = make_material(R"({"type":"blinnphong","exponent":50,"eta":1.5})");
    ShadingContext even, odd;
    even.uv = Vec2(0.1f, 0.1f);
    odd.uv = Vec2(0.6f, 0.1f);
    for (double t : {20.0, 70.0, 88.0}) {
        Vec3 wo = dir_deg(t, 0), wi = dir_deg(75, 170);
        EXPECT_NEAR(tex->eval(even, wo, wi).g, c5->eval(kCtx, wo, wi).g, 1e-4 * c5->eval(kCtx, wo, wi).g) << t;
        EXPECT_NEAR(tex->eval(odd, wo, wi).g, c50->eval(kCtx, wo, wi).g, 1e-4 * c50->eval(kCtx, wo, wi).g) << t;
        EXPECT_NEAR(tex->pdf(odd, wo, wi), c50->pdf(kCtx, wo, wi), 1e-5 * c50->pdf(kCtx, wo, wi)) << t;
    }
}

TEST(MaterialAnalytic, BlinnPhongBeckmannEquivalence) {
    // At s = 2/α² − 2, Blinn-Phong's D tends to Beckmann's for small α (Walter 2007 §5.2).
    double alpha = 0.05, s = 2 / (alpha * alpha) - 2;
    auto bp = make_material(R"({"type":"blinnphong","exponent":798})");
    auto be = make_material(R"({"type":"conductor","distribution":"beckmann","alpha":0.05})");
    (void)s;
    Vec3 wo = dir_deg(20, 0);
    for (double dt : {0.0, 2.0, 4.0}) {
        Vec3 wi = dir_deg(20 + dt, 180);
        double a = bp->eval(kCtx, wo, wi).g, b = be->eval(kCtx, wo, wi).g;
        EXPECT_NEAR(a / b, 1.0, 0.03) << dt;
    }
}

TEST(MaterialAnalytic, PlasticInternalReflectance) {
    // Smooth coat: R_int from energy balance equals the numerically integrated internal
    // diffuse Fresnel reflectance.
    auto m = make_material(R"({"type":"plastic","int_ior":1.5,"ext_ior":1.0})");
    EXPECT_NE(m->to_string().find("R_int=0.596"), std::string::npos) << m->to_string();
}

// ------------------------------------------------------------------ parameters

// D_lambda_batch (a rough conductor's eval_batch) against D() and lambda() one direction at a
// time: D to a float ulp, Λ within 1.2e-7 erfc(a) + 1e-15 relative (Beckmann's erfc is Numerical
// Recipes' erfcc; GGX's Λ has no approximation), for both distributions, isotropic and
// anisotropic, α from 1e-4 to 1e3, and the degenerate directions (normal, grazing, below, z = 0).
TEST(MaterialAnalytic, MicrofacetBatchMatchesScalar) {
    PCG32 rng(77);
    std::vector<Vec3> dirs;
    for (int i = 0; i < 301; ++i) dirs.push_back(square_to_uniform_sphere(Vec2(rng.next_float(), rng.next_float())));
    for (Vec3 d : {Vec3(0.f, 0.f, 1.f), Vec3(1.f, 0.f, 0.f), Vec3(0.f, 0.6f, -0.8f), normalize(Vec3(1.f, 1.f, 1e-6f)),
                   normalize(Vec3(0.f, 1.f, 1e-3f))})
        dirs.push_back(d);
    std::vector<float> D(dirs.size());
    std::vector<double> L(dirs.size());
    for (MicrofacetType t : {MicrofacetType::Beckmann, MicrofacetType::GGX})
        for (auto [au, av] : {std::pair{1e-4f, 1e-4f}, {0.05f, 0.05f}, {0.3f, 0.3f}, {0.2f, 0.7f}, {1.f, 1.f}, {1e3f, 1e3f}}) {
            const MicrofacetDistribution dist(t, au, av);
            for (int n : {int(dirs.size()), int(dirs.size()) - 1}) {  // even and odd counts
                std::vector<Vec3> w(dirs.begin(), dirs.begin() + n), m(w.rbegin(), w.rend());
                for (Vec3 &x : m) x = Vec3(x.x, x.y, std::abs(x.z));  // half vectors: some at z = 0
                dist.D_lambda_batch(m.data(), w.data(), n, D.data(), L.data());
                for (int k = 0; k < n; ++k) {
                    const float d = dist.D(m[size_t(k)]);
                    const double l = dist.lambda(w[size_t(k)]);
                    EXPECT_NEAR(D[size_t(k)], d, 1.2e-7f * d) << au << " " << av << " " << k;
                    if (std::isinf(l)) {
                        EXPECT_TRUE(std::isinf(L[size_t(k)])) << k;
                    } else {
                        const Vec3 &x = w[size_t(k)];
                        const double a2t2 = (double(x.x) * x.x * au * au + double(x.y) * x.y * av * av) / (double(x.z) * x.z);
                        const double ec = a2t2 > 0.0 ? std::erfc(1.0 / std::sqrt(a2t2)) : 0.0;
                        const double tol = t == MicrofacetType::GGX ? 1e-15 * l : 1.2e-7 * ec + 1e-13 * (l + ec) + 1e-300;  // e^x flushes below e^-708
                        EXPECT_NEAR(L[size_t(k)], l, tol) << au << " " << av << " " << k;
                    }
                    EXPECT_TRUE(std::isfinite(D[size_t(k)]) && D[size_t(k)] >= 0.f);
                }
            }
        }
}
