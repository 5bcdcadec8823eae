// core/f64_lanes.h: the E-step's e^x and ln x against libm, over their whole ranges.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include "core/f64_lanes.h"
#include "sampling/rng.h"

using namespace meso;

namespace {
/// |a − b| in units of b's last place.
double ulps(double a, double b) { return std::abs(a - b) / (std::nextafter(std::abs(b), INFINITY) - std::abs(b)); }
}  // namespace

TEST(F64Lanes, ExpIsLibm) {
    PCG32 rng(3);
    double worst = 0.0;
    for (int i = 0; i < 200000; ++i) {
        // Uniform in [-708, 0], and densely near 0 (where e^x ≈ 1 + x).
        const double a = -708.0 * rng.next_double(), b = -std::ldexp(rng.next_double(), -int(rng.next_bounded(60)));
        const lanes::F64x2 e = lanes::exp_nonpositive(lanes::F64x2{a, b});
        worst = std::max({worst, ulps(e[0], std::exp(a)), ulps(e[1], std::exp(b))});
    }
    std::printf("  exp_nonpositive: worst %.2f ulp\n", worst);
    EXPECT_LE(worst, 4.0);
    // The ends: e^0 = 1 exactly, e^−708 normal, below it exactly 0, −inf 0, NaN NaN.
    lanes::F64x2 e = lanes::exp_nonpositive(lanes::F64x2{0.0, -708.0});
    EXPECT_EQ(e[0], 1.0);
    EXPECT_LE(ulps(e[1], std::exp(-708.0)), 4.0);
    e = lanes::exp_nonpositive(lanes::F64x2{-708.5, -std::numeric_limits<double>::infinity()});
    EXPECT_EQ(e[0], 0.0);
    EXPECT_EQ(e[1], 0.0);
    e = lanes::exp_nonpositive(lanes::F64x2{std::nan(""), -1e300});
    EXPECT_TRUE(std::isnan(e[0]));
    EXPECT_EQ(e[1], 0.0);
}

TEST(F64Lanes, LogIsLibm) {
    PCG32 rng(4);
    double worst_rel = 0.0, worst_abs = 0.0;
    for (int i = 0; i < 200000; ++i) {
        // [1, 16] (the E-step's sums), and any normal magnitude.
        const double a = 1.0 + 15.0 * rng.next_double();
        const double b = i % 2 ? std::ldexp(0.5 + 0.5 * rng.next_double(), int(rng.next_bounded(2040)) - 1020)
                               : 0.5 + 1.5 * rng.next_double();
        const lanes::F64x2 v = lanes::log_positive(lanes::F64x2{a, b});
        for (int k = 0; k < 2; ++k) {
            const double x = k ? b : a, ref = std::log(x);
            if (std::abs(ref) <= 1.0) worst_abs = std::max(worst_abs, std::abs(v[k] - ref));  // near x = 1
            if (std::abs(ref) > 0.1) worst_rel = std::max(worst_rel, ulps(v[k], ref));
        }
    }
    std::printf("  log_positive: worst %.2f ulp (|ln x| > 0.1), %.3g absolute (|ln x| <= 1)\n", worst_rel, worst_abs);
    EXPECT_LE(worst_rel, 4.0);
    EXPECT_LE(worst_abs, 1e-15);
    const lanes::F64x2 v = lanes::log_positive(lanes::F64x2{1.0, 2.0});
    EXPECT_EQ(v[0], 0.0);
    EXPECT_NEAR(v[1], std::log(2.0), 2e-16);
}
