// Core math: frames, distributions.
#include <gtest/gtest.h>
#include "core/frame.h"
#include "sampling/distribution.h"
#include "sampling/rng.h"

using namespace meso;

TEST(Frame, RoundTripAndOrthonormal) {
    PCG32 rng(7);
    for (int i = 0; i < 1000; ++i) {
        Vec3 n = normalize(Vec3(rng.next_float() - 0.5f, rng.next_float() - 0.5f, rng.next_float() - 0.5f));
        if (i == 0) n = Vec3(0, 0, -1);  // the singular direction of naive constructions
        Frame f(n);
        EXPECT_NEAR(dot(f.s, f.t), 0.f, 1e-5f);
        EXPECT_NEAR(dot(f.s, f.n), 0.f, 1e-5f);
        EXPECT_NEAR(length(f.s), 1.f, 1e-5f);
        Vec3 v(0.3f, -0.2f, 0.9f);
        Vec3 r = f.to_world(f.to_local(v));
        EXPECT_NEAR(r.x, v.x, 1e-5f);
        EXPECT_NEAR(r.z, v.z, 1e-5f);
    }
}

TEST(Distribution1D, DiscreteMatchesWeights) {
    Distribution1D d({1.f, 0.f, 3.f, 0.f});
    PCG32 rng(1);
    int counts[4] = {0, 0, 0, 0};
    const int n = 100000;
    for (int i = 0; i < n; ++i) counts[d.sample_discrete(rng.next_float())]++;
    EXPECT_EQ(counts[1], 0);
    EXPECT_EQ(counts[3], 0);
    // Binomial standard deviation sqrt(n p (1-p)) ~ 137; allow 5 sigma.
    EXPECT_NEAR(counts[0], n * 0.25, 5 * 137);
    EXPECT_FLOAT_EQ(d.pmf(2), 0.75f);
    // u at the very end must not land in a zero-weight cell.
    EXPECT_EQ(d.sample_discrete(OneMinusEpsilon), 2u);
}

TEST(Distribution1D, AllZeroIsUniformAndNanSafe) {
    Distribution1D d({0.f, std::nanf(""), -1.f});
    EXPECT_NEAR(d.pmf(0), 1.f / 3.f, 1e-6f);
    float pdf;
    float x = d.sample_continuous(0.5f, &pdf);
    EXPECT_TRUE(std::isfinite(x));
    EXPECT_NEAR(pdf, 1.f, 1e-6f);
}

TEST(Distribution2D, PdfMatchesSampling) {
    std::vector<float> f = {1, 2, 0, 4, 0, 0, 5, 1};  // 4 x 2
    Distribution2D d(f, 4, 2);
    PCG32 rng(3);
    for (int i = 0; i < 1000; ++i) {
        float pdf;
        Vec2 p = d.sample_continuous({rng.next_float(), rng.next_float()}, &pdf);
        EXPECT_NEAR(pdf, d.pdf(p), 1e-4f * pdf);
        EXPECT_GT(pdf, 0.f);
    }
}

// Gauss–Legendre on [0, 1] (core/quadrature.h): exact for polynomials of degree <= 2n - 1.
#include "core/quadrature.h"
TEST(Quadrature, GaussLegendreIsExactToDegree2nMinus1) {
    for (int n : {1, 2, 3, 4, 7, 8, 16, 32}) {
        std::vector<double> x, w;
        meso::gauss_legendre_01(n, x, w);
        for (int d = 0; d <= 2 * n - 1; ++d) {
            double s = 0.0;
            for (int i = 0; i < n; ++i) s += w[i] * std::pow(x[i], d);
            EXPECT_NEAR(s, 1.0 / (d + 1), 1e-13) << "n " << n << " degree " << d;
        }
        for (int i = 1; i < n; ++i) EXPECT_LT(x[i - 1], x[i]);
    }
    std::vector<double> x, w;
    EXPECT_THROW(meso::gauss_legendre_01(0, x, w), std::exception);
}
