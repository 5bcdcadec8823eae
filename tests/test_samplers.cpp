// Samplers: determinism (a sample is a pure function of pixel, index, seed, dimension),
// range, uniformity across pixels (chi^2), the (0, m, 2)-net property of the sobol
// sampler's dimension pairs, and its lower integration error than independent sampling.
#include <gtest/gtest.h>
#include <algorithm>
#include <cmath>
#include <memory>
#include <nlohmann/json.hpp>
#include <vector>
#include "sampling/owen.h"
#include "sampling/sampler.h"
#include "sampling/warp.h"
#include "core/properties.h"
#include "core/registry.h"

using namespace meso;

namespace {

std::shared_ptr<Sampler> make_sampler(const std::string &type, int seed = 0) {
    nlohmann::json j = {{"type", type}, {"seed", seed}};
    Properties p(j, "sampler", std::make_shared<LoadContext>());
    return create_sampler(p);
}

/// The first `dims` numbers of one pixel sample, drawn as 1D, 2D, 1D, 2D, ... requests.
std::vector<float> draw(Sampler &s, int px, int py, uint32_t index, int requests = 6) {
    s.start_pixel_sample(px, py, index);
    std::vector<float> v;
    for (int r = 0; r < requests; ++r) {
        if (r % 2 == 0) {
            v.push_back(s.get_1d());
        } else {
            Vec2 u = s.get_2d();
            v.push_back(u.x);
            v.push_back(u.y);
        }
    }
    return v;
}

/// Upper chi^2 quantile (Wilson-Hilferty), z = standard normal quantile of 1 - alpha.
double chi2_critical(int dof, double z) {
    double k = dof, a = 2.0 / (9.0 * k);
    return k * std::pow(1.0 - a + z * std::sqrt(a), 3.0);
}

class SamplerTest : public ::testing::TestWithParam<std::string> {};

}  // namespace

TEST_P(SamplerTest, DeterministicAndOrderIndependent) {
    auto a = make_sampler(GetParam(), 7), b = make_sampler(GetParam(), 7);
    EXPECT_EQ(a->name(), GetParam());
    EXPECT_EQ(a->seed(), 7u);
    // b visits other pixels and samples first, in a different order.
    draw(*b, 100, 3, 9);
    draw(*b, 5, 6, 2);
    std::vector<float> second = draw(*b, 5, 6, 1);
    std::vector<float> first = draw(*b, 5, 6, 0);
    EXPECT_EQ(draw(*a, 5, 6, 0), first);
    EXPECT_EQ(draw(*a, 5, 6, 1), second);
    // A clone (another thread) produces the same numbers.
    auto c = a->clone();
    EXPECT_EQ(c->name(), GetParam());
    EXPECT_EQ(c->seed(), 7u);
    EXPECT_EQ(draw(*c, 5, 6, 1), second);
    EXPECT_EQ(draw(*c, 5, 6, 0), first);
    // Restarting a sample restarts its dimensions.
    EXPECT_EQ(draw(*a, 5, 6, 0), first);
    // Other seeds, pixels and indices differ.
    auto d = make_sampler(GetParam(), 8);
    EXPECT_NE(draw(*d, 5, 6, 0), first);
    EXPECT_NE(draw(*a, 6, 5, 0), first);
    EXPECT_NE(draw(*a, 5, 6, 2), first);
}

TEST_P(SamplerTest, ValuesInUnitInterval) {
    auto s = make_sampler(GetParam(), 3);
    for (int p = 0; p < 64; ++p)
        for (uint32_t i = 0; i < 64; ++i)
            for (float v : draw(*s, p % 8 - 2, p / 8, i * 977u, 8)) {
                ASSERT_GE(v, 0.f);
                ASSERT_LT(v, 1.f);
            }
}

// For a fixed sample index and dimension, values over many pixels must be uniform.
TEST_P(SamplerTest, Get1DUniformAcrossPixelsChi2) {
    auto s = make_sampler(GetParam(), 11);
    const int bins = 32, w = 64, h = 64;
    const uint32_t indices[] = {0, 5, 255};
    // 3 indices x 2 dimensions x 2 samplers = 12 tests; z = 3.35 is alpha = 4e-4 each,
    // so the family-wise false-alarm rate is below 0.5%.
    for (uint32_t index : indices)
        for (int dim = 0; dim < 2; ++dim) {
            std::vector<int> hist(bins, 0);
            for (int y = 0; y < h; ++y)
                for (int x = 0; x < w; ++x) {
                    s->start_pixel_sample(x, y, index);
                    float v = s->get_1d();
                    if (dim == 1) v = s->get_1d();
                    hist[std::min(bins - 1, int(v * bins))]++;
                }
            double expected = double(w * h) / bins, chi2 = 0;
            for (int c : hist) chi2 += (c - expected) * (c - expected) / expected;
            EXPECT_LT(chi2, chi2_critical(bins - 1, 3.35)) << "index " << index << " dimension " << dim;
        }
}

INSTANTIATE_TEST_SUITE_P(All, SamplerTest, ::testing::Values("independent", "sobol"));

TEST(Sobol, ClosedFormGeneratorsMatchDirectionNumbers) {
    // Sobol' dimension 1 (primitive polynomial x + 1, m_1 = 1): direction numbers
    // v_k = m_k / 2^k with m_k = 2 m_{k-1} xor m_{k-1} (Bratley & Fox 1988, Joe & Kuo).
    uint32_t m = 1;
    for (int k = 1; k <= 32; ++k) {
        if (k > 1) m = (m << 1) ^ m;
        EXPECT_EQ(sobol_dim1(1u << (k - 1)), m << (32 - k)) << k;
        EXPECT_EQ(sobol_dim0(1u << (k - 1)), 1u << (32 - k)) << k;
    }
    // The byte-table form equals the bit loop (XOR of the direction numbers of the set bits) and
    // bit reversal equals the bit-by-bit definition, on indices with every bit pattern.
    uint64_t state = 0x853c49e6748fea9bULL;
    for (int n = 0; n < 100000; ++n) {
        state = state * 6364136223846793005ULL + 1442695040888963407ULL;
        const uint32_t i = uint32_t(state >> 32);
        uint32_t x = 0, v = 0x80000000u, r = 0;
        for (uint32_t k = i; k; k >>= 1, v ^= v >> 1)
            if (k & 1u) x ^= v;
        for (int b = 0; b < 32; ++b) r |= ((i >> b) & 1u) << (31 - b);
        ASSERT_EQ(sobol_dim1(i), x) << i;
        ASSERT_EQ(reverse_bits32(i), r) << i;
    }
    // Natural-order points of dimension 1: x_i = XOR of v_k over the set bits of i.
    const double expect1[8] = {0, 0.5, 0.75, 0.25, 0.625, 0.125, 0.375, 0.875};
    for (uint32_t i = 0; i < 8; ++i) EXPECT_DOUBLE_EQ(sobol_dim1(i) * 0x1p-32, expect1[i]) << i;
    // Nested uniform scrambling is a bijection that keeps aligned blocks together.
    for (uint32_t seed : {0u, 1u, 0xdeadbeefu}) {
        std::vector<uint32_t> img;
        for (uint32_t i = 0; i < 64; ++i) img.push_back(nested_uniform_scramble(i, seed));
        uint32_t block = img[0] >> 6;
        std::vector<bool> seen(64, false);
        for (uint32_t v : img) {
            EXPECT_EQ(v >> 6, block);
            EXPECT_FALSE(seen[v & 63]);
            seen[v & 63] = true;
        }
    }
}

// (0, m, 2)-net: for N = 2^m samples of a pixel, every elementary interval
// [a 2^-k, (a+1) 2^-k) x [b 2^-(m-k), (b+1) 2^-(m-k)) holds exactly one point, for every
// dimension pair (the shuffle and Owen scrambling preserve this); 1D: N strata.
TEST(Sobol, PowerOfTwoPrefixesAreNets) {
    auto s = make_sampler("sobol", 5);
    for (int m : {2, 4, 6, 8}) {  // N = 4, 16, 64, 256 = 4^k
        const int n = 1 << m;
        for (int pixel = 0; pixel < 4; ++pixel) {
            // points[slot] = 2D point of request `slot` (requests: 1D, 2D, 1D, 2D).
            std::vector<std::vector<Vec2>> pts(2);
            std::vector<std::vector<float>> ones(2);
            for (int i = 0; i < n; ++i) {
                s->start_pixel_sample(pixel * 13, pixel * 7 + 1, uint32_t(i));
                ones[0].push_back(s->get_1d());
                pts[0].push_back(s->get_2d());
                ones[1].push_back(s->get_1d());
                pts[1].push_back(s->get_2d());
            }
            for (int slot = 0; slot < 2; ++slot) {
                for (int k = 0; k <= m; ++k) {
                    std::vector<int> count(n, 0);
                    for (Vec2 p : pts[slot]) {
                        int cx = int(p.x * float(1 << k)), cy = int(p.y * float(1 << (m - k)));
                        count[size_t(cy) * (1 << k) + cx]++;
                    }
                    for (int c = 0; c < n; ++c)
                        ASSERT_EQ(count[c], 1) << "N=" << n << " pixel " << pixel << " slot " << slot << " shape 2^"
                                               << k << " x 2^" << (m - k);
                }
                std::vector<int> count(n, 0);
                for (float v : ones[slot]) count[int(v * float(n))]++;
                for (int c = 0; c < n; ++c) ASSERT_EQ(count[c], 1) << "1D N=" << n << " slot " << slot;
            }
        }
    }
}

// Integration error of a smooth, non-separable function over 256 samples per pixel,
// RMS over 20 pixels, for the first and a later (padded) dimension pair: Owen-scrambled
// Sobol converges like N^-1.5 vs N^-0.5, so at N = 256 it must be far (> 3x) better.
TEST(Sobol, LowerIntegrationErrorThanIndependent) {
    auto f = [](Vec2 u) { return std::exp(-(sqr(u.x - 0.3f) + sqr(u.y - 0.6f)) * 4.f) + std::sin(3.f * u.x * u.y); };
    // Reference value: midpoint rule on a 1024^2 grid (error ~ 1e-7).
    double ref = 0;
    const int g = 1024;
    for (int j = 0; j < g; ++j)
        for (int i = 0; i < g; ++i) ref += f(Vec2((i + 0.5f) / g, (j + 0.5f) / g));
    ref /= double(g) * g;

    auto rms_error = [&](const std::string &type, int slot) {
        auto s = make_sampler(type, 1);
        double sum_sq = 0;
        for (int pixel = 0; pixel < 20; ++pixel) {
            double est = 0;
            for (uint32_t i = 0; i < 256; ++i) {
                s->start_pixel_sample(pixel, 3, i);
                Vec2 u = s->get_2d();
                if (slot == 1) s->get_1d(), u = s->get_2d();
                est += f(u);
            }
            sum_sq += sqr(est / 256 - ref);
        }
        return std::sqrt(sum_sq / 20);
    };
    for (int slot = 0; slot < 2; ++slot) {
        double e_sobol = rms_error("sobol", slot), e_ind = rms_error("independent", slot);
        RecordProperty("rms_ratio_slot" + std::to_string(slot), std::to_string(e_ind / e_sobol));
        EXPECT_LT(3 * e_sobol, e_ind) << "slot " << slot << ": sobol " << e_sobol << " independent " << e_ind;
    }
}

// Padding: different dimension pairs of one pixel are shuffled independently, so they
// must not be correlated (an unshuffled Sobol would give x of pair 0 == x of pair 1).
TEST(Sobol, DimensionPairsUncorrelated) {
    auto s = make_sampler("sobol", 2);
    double sum_abs = 0;
    const int pixels = 20, n = 256;
    for (int pixel = 0; pixel < pixels; ++pixel) {
        double sa = 0, sb = 0, sab = 0, saa = 0, sbb = 0;
        for (int i = 0; i < n; ++i) {
            s->start_pixel_sample(pixel, 0, uint32_t(i));
            double a = s->get_2d().x, b = s->get_2d().x;
            sa += a, sb += b, sab += a * b, saa += a * a, sbb += b * b;
        }
        double cov = sab / n - sa / n * sb / n;
        double corr = cov / std::sqrt((saa / n - sqr(sa / n)) * (sbb / n - sqr(sb / n)));
        sum_abs += std::abs(corr);
    }
    // Independent shuffles: corr ~ N(0, 1/16), mean |corr| ~ 0.05.
    EXPECT_LT(sum_abs / pixels, 0.1);
}

// The concentric disk map computes its angle's sine and cosine by polynomials (sincos_quarter):
// within float rounding of the map in double precision with libm, everywhere on the square
// (edges, diagonals, the centre), and never outside the unit disk.
TEST(Warp, ConcentricDiskMatchesTheDoubleMap) {
    double worst = 0;
    for (double x = -0.7853981633974483; x <= 0.7853981633974484; x += 1.0 / 4096) {
        float s, c;
        sincos_quarter(float(x), s, c);
        worst = std::max({worst, std::abs(s - std::sin(double(float(x)))), std::abs(c - std::cos(double(float(x))))});
    }
    EXPECT_LT(worst, 1.2e-7);
    auto reference = [](Vec2 u) {
        const double ox = 2.0 * u.x - 1.0, oy = 2.0 * u.y - 1.0;
        if (ox == 0 && oy == 0) return std::pair<double, double>(0, 0);
        const bool xs = std::abs(ox) > std::abs(oy);
        const double r = xs ? ox : oy, th = xs ? M_PI / 4 * (oy / ox) : M_PI / 2 - M_PI / 4 * (ox / oy);
        return std::pair<double, double>(r * std::cos(th), r * std::sin(th));
    };
    const int n = 1024;
    worst = 0;
    for (int i = 0; i <= n; ++i)
        for (int j = 0; j <= n; ++j) {
            // Grid points (the centre, edges and both diagonals included) and one float step off them.
            for (float eps : {0.f, 6e-8f}) {
                const Vec2 u(std::min(OneMinusEpsilon, float(i) / n + eps), std::min(OneMinusEpsilon, float(j) / n));
                const Vec2 d = square_to_uniform_disk_concentric(u);
                const auto [rx, ry] = reference(u);
                worst = std::max({worst, std::abs(d.x - rx), std::abs(d.y - ry)});
                ASSERT_LE(double(d.x) * d.x + double(d.y) * d.y, 1.0 + 3e-7) << u.x << " " << u.y;
            }
        }
    EXPECT_LT(worst, 2.5e-7);
    const Vec3 w = square_to_cosine_hemisphere(Vec2(0.5f, 0.5f));
    EXPECT_EQ(w.z, 1.f);
}
