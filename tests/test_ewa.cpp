// EWA (elliptically weighted average) texture filtering: MipMap::ewa against exact
// invariants (constants, zero footprint = bilinear, huge footprint = the mean, wrap modes),
// against trilinear on stripes (anisotropy keeps contrast along the major axis), against an
// independent brute-force Gaussian integral over the ellipse, on extreme inputs, and through
// the `bitmap` texture and a rendered scene. EwaTiming prints the cost per lookup.
#include <gtest/gtest.h>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <limits>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "core/math.h"
#include "image/image.h"
#include "texture/texture.h"
#include "cli_capture.h"
#include "render_test_util.h"
#include "sampling/rng.h"
#include "core/properties.h"
#include "core/registry.h"
#include "scratch_dir.h"
#include "texture/mipmap.h"

using namespace meso;
using json = nlohmann::json;

namespace {

constexpr double kTwoPi = 6.283185307179586;

/// w x h single-channel map of f(x, y) at texel (x, y).
template <typename F> MipMap make_map(int w, int h, F f, WrapMode wrap = WrapMode::Repeat) {
    std::vector<float> d(size_t(w) * h);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) d[size_t(y) * w + x] = float(f(x, y));
    return MipMap(w, h, 1, std::move(d), wrap);
}

MipMap random_map(int w, int h, uint64_t seed, WrapMode wrap = WrapMode::Repeat) {
    PCG32 rng(seed);
    return make_map(w, h, [&](int, int) { return rng.next_float(); }, wrap);
}

float ewa1(const MipMap &m, float u, float v, float dudx, float dudy, float dvdx, float dvdy, float aniso = 8.f) {
    float out = -1.f;
    m.ewa(u, v, dudx, dudy, dvdx, dvdy, &out, aniso);
    return out;
}

float trilinear1(const MipMap &m, float u, float v, float dudx, float dudy, float dvdx, float dvdy) {
    float out = -1.f;
    m.filtered(u, v, dudx, dudy, dvdx, dvdy, &out);
    return out;
}

}  // namespace

TEST(EwaMipMap, ConstantImageIsExactForEveryFootprint) {
    const float c[3] = {0.37f, 1.f / 3.f, 7.25f};
    for (WrapMode wrap : {WrapMode::Repeat, WrapMode::Clamp, WrapMode::Mirror})
        for (auto [w, h] : {std::pair{37, 23}, std::pair{64, 64}, std::pair{1, 5}}) {
            std::vector<float> d(size_t(w) * h * 3);
            for (size_t i = 0; i < d.size(); ++i) d[i] = c[i % 3];
            MipMap m(w, h, 3, d, wrap);
            PCG32 rng(w * 31 + h);
            for (int k = 0; k < 300; ++k) {
                // Footprints from 1e-4 to 1e3 of the image, any orientation and eccentricity.
                auto r = [&] { return (rng.next_float() - 0.5f) * std::pow(10.f, rng.next_float() * 7 - 4); };
                float u = rng.next_float() * 6 - 3, v = rng.next_float() * 6 - 3, out[3];
                m.ewa(u, v, r(), r(), r(), r(), out, 1.f + rng.next_float() * 20);
                for (int ch = 0; ch < 3; ++ch) ASSERT_EQ(out[ch], c[ch]) << w << "x" << h << " sample " << k;
            }
        }
}

TEST(EwaMipMap, ZeroFootprintIsBilinear) {
    MipMap m = random_map(29, 17, 5);
    PCG32 rng(9);
    for (int k = 0; k < 200; ++k) {
        float u = rng.next_float() * 3 - 1, v = rng.next_float() * 3 - 1, b;
        m.bilinear(0, u, v, &b);
        EXPECT_EQ(ewa1(m, u, v, 0, 0, 0, 0), b);
        EXPECT_EQ(ewa1(m, u, v, 0.f, -0.f, -0.f, 0.f), b);
    }
}

TEST(EwaMipMap, LargeIsotropicFootprintApproachesTheMean) {
    // i.i.d. texels in [0, 1) (σ = 0.29): level l texels have σ / 2^l around the mean, and the
    // Gaussian over the ellipse averages a few of them further. A semi-axis of r image widths
    // selects level log2(64 r): r = 1/4 -> level 4 (4x4 texels, σ_l = 0.018), r = 1/2 ->
    // level 5 (2x2, 0.009), r >= 1 -> the 1x1 level, the mean itself.
    MipMap m = random_map(64, 64, 77);
    float mean;
    m.level_mean(0, &mean);
    PCG32 rng(3);
    for (int k = 0; k < 50; ++k) {
        float u = rng.next_float(), v = rng.next_float();
        EXPECT_NEAR(ewa1(m, u, v, 0.25f, 0, 0, 0.25f), mean, 3 * 0.018f);
        EXPECT_NEAR(ewa1(m, u, v, 0.5f, 0, 0, 0.5f), mean, 3 * 0.009f);
        EXPECT_FLOAT_EQ(ewa1(m, u, v, 1.f, 0, 0, 1.f), mean);
        EXPECT_FLOAT_EQ(ewa1(m, u, v, 0.75f, 0.75f, -0.75f, 0.75f), mean);  // rotated, semi-axes 1.06
        EXPECT_FLOAT_EQ(ewa1(m, u, v, 1e6f, 0, 0, 1e6f), mean);
    }
}

TEST(EwaMipMap, AnisotropyKeepsContrastAlongStripes) {
    // Stripes along u: texel rows alternate 0 / 1 (period 2 texels in v). A footprint 8 texels
    // long in u and half a texel in v lies along one stripe: EWA stays on level 0 (the minor
    // axis, widened to 8 / 8 = 1 texel, picks log2 1 = 0) and keeps most of the contrast;
    // trilinear sizes its box by the major axis (level 3) and returns 0.5 everywhere.
    const int N = 64;
    MipMap m = make_map(N, N, [](int, int y) { return float(y & 1); });
    const float along[4] = {8.f / N, 0.f, 0.f, 0.5f / N};  // dudx, dudy, dvdx, dvdy
    const float across[4] = {0.5f / N, 0.f, 0.f, 8.f / N};
    float lo = 1, hi = 0;
    for (int y = 10; y < 14; ++y) {
        float u = 0.3f, v = (y + 0.5f) / N;
        float e = ewa1(m, u, v, along[0], along[1], along[2], along[3]);
        float t = trilinear1(m, u, v, along[0], along[1], along[2], along[3]);
        lo = std::min(lo, e);
        hi = std::max(hi, e);
        EXPECT_NEAR(t, 0.5f, 1e-6f);
        EXPECT_EQ(e > 0.5f, (y & 1) == 1) << "row " << y;
        // Across the stripes the ellipse covers ~16 rows: the alternating rows cancel.
        float a = ewa1(m, u, v, across[0], across[1], across[2], across[3]);
        EXPECT_NEAR(a, 0.5f, 0.02f) << "row " << y;
    }
    std::printf("[ EWA stripes ] contrast along the stripes: EWA %.3f (rows %.3f / %.3f), trilinear 0\n", hi - lo,
                lo, hi);
    EXPECT_GT(hi - lo, 0.3f);
    // The same footprint rotated 90 degrees in the derivative order (x and y swapped) is the
    // same ellipse, and parallel axes along u (a segment) keep the contrast too.
    for (int y = 10; y < 12; ++y) {
        float v = (y + 0.5f) / N;
        EXPECT_NEAR(ewa1(m, 0.3f, v, 0.f, along[0], along[3], 0.f), ewa1(m, 0.3f, v, along[0], 0, 0, along[3]), 1e-6f);
        float seg = ewa1(m, 0.3f, v, 6.f / N, -3.f / N, 0.f, 0.f);
        EXPECT_EQ(seg > 0.5f, (y & 1) == 1) << "row " << y;
    }
}

namespace {

/// The reference: ∫ f(c + p) w(pᵀ M⁻¹ p) dp / ∫ w over the ellipse pᵀ M⁻¹ p < 1 (p in level-0
/// texels), with w(r²) = exp(-2 r²) - exp(-2) evaluated exactly and f the level-0 bilinear
/// texture. Substituting p = L q (M = L Lᵀ) makes it an integral over the unit disc, done
/// with a G x G midpoint grid.
double brute_force_ellipse(const MipMap &m, double cu, double cv, double mxx, double mxy, double myy, int G = 192) {
    const double l11 = std::sqrt(mxx), l21 = mxy / l11, l22 = std::sqrt(std::max(0.0, myy - l21 * l21));
    const double W = m.width(), H = m.height();
    double acc = 0, wsum = 0;
    for (int i = 0; i < G; ++i)
        for (int j = 0; j < G; ++j) {
            double qx = -1 + 2 * (i + 0.5) / G, qy = -1 + 2 * (j + 0.5) / G, r2 = qx * qx + qy * qy;
            if (r2 >= 1) continue;
            double w = std::exp(-2 * r2) - std::exp(-2.0);
            double px = l11 * qx, py = l21 * qx + l22 * qy;
            float f;
            m.bilinear(0, float(cu + px / W), float(cv + py / H), &f);
            acc += w * f;
            wsum += w;
        }
    return acc / wsum;
}

}  // namespace

TEST(EwaMipMap, MatchesBruteForceGaussianOnSmoothImage) {
    // Smooth periodic image: three sinusoids of wavelength >= N / 2 texels (amplitude sum 0.45).
    const int N = 128;
    struct Wave {
        double a, kx, ky, phase;  // a · sin(2π (kx x + ky y) / N + phase)
    };
    const Wave waves[] = {{0.2, 1, 0, 0.3}, {0.15, 0, 2, 1.1}, {0.1, 1, 1, 2.0}};
    auto f = [&](int x, int y) {
        double s = 0.5;
        for (auto &wv : waves) s += wv.a * std::sin(kTwoPi * (wv.kx * (x + 0.5) + wv.ky * (y + 0.5)) / N + wv.phase);
        return s;
    };
    MipMap m = make_map(N, N, f);
    // The continuous definition EWA discretises: on level l (texel size s = 2^l level-0
    // texels) the ellipse has M = Σ + s² I (Σ = J Jᵀ, plus its one-texel reconstruction
    // filter), and the result blends levels floor(λ), floor(λ)+1 at λ = log2(minor semi-axis).
    // EWA departs from it in two ways, which set the tolerance:
    //  (1) it reads box-prefiltered texels: a wave (kx, ky) is scaled by
    //      P(s) = sinc(π s kx / N) sinc(π s ky / N) on level l, so the result moves by at most
    //      a (1 - P(s)) per wave, blended over the two levels like the result (the dominant
    //      term on levels >= 1: 1.6e-3 at level 2, where 1.5e-3 is measured);
    //  (2) it sums on the level's texel lattice instead of integrating. The kernel has
    //      σ >= 0.5 texel (M >= I), is continuous at its edge and the waves have >= 16
    //      texels per period on every level used here (<= 2); the lattice sum errs by ~0.1% of the
    //      amplitudes (the level-0 cases, where (1) is below 2e-4, measure up to 4.6e-4 for a
    //      total amplitude of 0.45): allowed 0.25% of the amplitude sum.
    // Plus 5e-5 for the reference's midpoint grid and the weight table's interpolation.
    // The measured maxima are printed.
    auto sinc = [](double x) { return x == 0 ? 1.0 : std::sin(x) / x; };
    auto prefilter_loss = [&](double s) {
        double loss = 0;
        for (auto &wv : waves) loss += wv.a * (1 - sinc(kTwoPi / 2 * s * wv.kx / N) * sinc(kTwoPi / 2 * s * wv.ky / N));
        return loss;
    };
    double amplitude_sum = 0;
    for (auto &wv : waves) amplitude_sum += wv.a;
    PCG32 rng(11);
    double worst_err = 0, worst_ratio = 0;
    for (int k = 0; k < 24; ++k) {
        // Semi-axes: minor 0.3 .. 4 texels, eccentricity 1 .. 6 (<= max_anisotropy 8, so no
        // widening), random orientation.
        double minor = 0.3 * std::pow(4 / 0.3, rng.next_float()), major = minor * (1 + 5 * rng.next_float());
        double th = kTwoPi * rng.next_float();
        double ax = major * std::cos(th), ay = major * std::sin(th), bx = -minor * std::sin(th), by = minor * std::cos(th);
        if (k % 2) std::swap(ax, bx), std::swap(ay, by);  // either derivative may be the major one
        float u = rng.next_float(), v = rng.next_float();
        float got = ewa1(m, u, v, float(ax / N), float(bx / N), float(ay / N), float(by / N));

        double sxx = ax * ax + bx * bx, sxy = ax * ay + bx * by, syy = ay * ay + by * by;
        double level = std::max(0.0, std::log2(minor));
        int l0 = int(std::floor(level));
        double t = level - l0;
        auto at_level = [&](int l) {
            double s2 = std::pow(4.0, l);
            return brute_force_ellipse(m, u, v, sxx + s2, sxy, syy + s2);
        };
        double ref = at_level(l0);
        if (t > 0) ref += t * (at_level(l0 + 1) - ref);

        double tol = (1 - t) * prefilter_loss(std::pow(2.0, l0)) + t * prefilter_loss(std::pow(2.0, l0 + 1)) +
                     0.0025 * amplitude_sum + 5e-5;
        double err = std::abs(got - ref);
        worst_err = std::max(worst_err, err);
        worst_ratio = std::max(worst_ratio, err / tol);
        EXPECT_NEAR(got, ref, tol) << "case " << k << " minor " << minor << " major " << major << " level " << level;
    }
    std::printf("[ EWA vs brute force ] max |EWA - reference| %.2e, max error / tolerance %.2f\n", worst_err, worst_ratio);
}

TEST(EwaMipMap, WrapModes) {
    const int N = 64;
    MipMap rep = random_map(N, N, 21, WrapMode::Repeat);
    // Repeat: periodic (u, v exact in float, so the lattice offsets are identical) ...
    const float fp[4] = {3.f / N, 1.f / N, -2.f / N, 0.7f / N};
    float a = ewa1(rep, 1.f / 128, 0.25f, fp[0], fp[1], fp[2], fp[3]);
    EXPECT_EQ(ewa1(rep, 1.f + 1.f / 128, 0.25f, fp[0], fp[1], fp[2], fp[3]), a);
    EXPECT_EQ(ewa1(rep, -1.f + 1.f / 128, -1.75f, fp[0], fp[1], fp[2], fp[3]), a);
    // ... and across the u = 0 seam it reads the image's right edge: the same as the middle
    // of the image rolled by half its width.
    std::vector<float> rolled(N * N);
    for (int y = 0; y < N; ++y)
        for (int x = 0; x < N; ++x) rolled[y * N + (x + N / 2) % N] = *rep.texel(0, x, y);
    MipMap rol(N, N, 1, rolled, WrapMode::Repeat);
    EXPECT_EQ(ewa1(rol, 0.5f + 1.f / 128, 0.25f, fp[0], fp[1], fp[2], fp[3]), a);

    // Clamp: outside the left edge every fetch is column 0; a constant column gives it exactly
    // (semi-axes under a texel, so level 0 alone: coarser levels mix in column 1).
    MipMap cl = make_map(N, N, [](int x, int y) { return x == 0 ? 2.5f : float(x + y); }, WrapMode::Clamp);
    EXPECT_EQ(ewa1(cl, -0.3f, 0.4f, 0.8f / N, 0.3f / N, 0.f, 0.9f / N), 2.5f);
    EXPECT_EQ(ewa1(cl, -1e20f, 0.4f, 0.8f / N, 0.3f / N, 0.f, 0.9f / N), 2.5f);
    EXPECT_GT(ewa1(cl, 0.3f, 0.4f, 0.8f / N, 0.3f / N, 0.f, 0.9f / N), 10.f);
    // Mirror: symmetric about u = 0, so reflecting the position and the footprint's u
    // components gives the same value (summation order differs: float tolerance).
    MipMap mir = random_map(N, N, 22, WrapMode::Mirror);
    for (float u : {0.01f, 0.03f, 0.5f, 0.97f}) {
        float x = ewa1(mir, u, 0.4f, fp[0], fp[1], fp[2], fp[3]);
        float y = ewa1(mir, -u, 0.4f, -fp[0], -fp[1], fp[2], fp[3]);
        EXPECT_NEAR(x, y, 1e-5f) << "u " << u;
    }
    // The three modes differ near the seam (they read different texels there).
    MipMap cl2 = random_map(N, N, 21, WrapMode::Clamp), mir2 = random_map(N, N, 21, WrapMode::Mirror);
    float r = ewa1(rep, 0.f, 0.5f, 4.f / N, 0, 0, 1.f / N), c = ewa1(cl2, 0.f, 0.5f, 4.f / N, 0, 0, 1.f / N),
          mm = ewa1(mir2, 0.f, 0.5f, 4.f / N, 0, 0, 1.f / N);
    EXPECT_NE(r, c);
    EXPECT_NE(r, mm);
    EXPECT_NE(c, mm);
}

TEST(EwaMipMap, ExtremeInputsStayFiniteAndInRange) {
    // All weights are >= 0 and every level is an average, so results lie in [min, max] of the
    // image, whatever the input.
    auto pattern = [](int x, int y) { return 1.f + float((x * 7 + y * 3) % 11); };
    const MipMap maps[3] = {make_map(48, 20, pattern, WrapMode::Repeat), make_map(48, 20, pattern, WrapMode::Clamp),
                            make_map(48, 20, pattern, WrapMode::Mirror)};
    const MipMap &m = maps[0];
    const float inf = std::numeric_limits<float>::infinity(), nan = std::nanf("");
    const float vals[] = {0.f,   -0.f,   1e-30f, -1e-30f, 1e-38f * 0.01f, 1e-5f, 0.02f, -0.3f, 1.f,
                          1e3f, -1e30f, 1e30f, std::numeric_limits<float>::max(), inf, -inf, nan};
    const int n = int(std::size(vals));
    PCG32 rng(1);
    for (int k = 0; k < 4000; ++k) {
        float d[4], uv[2];
        for (float &x : d) x = vals[rng.next_bounded(uint32_t(n))];
        for (float &x : uv) x = vals[rng.next_bounded(uint32_t(n))];
        float aniso = (k % 5 == 0) ? vals[rng.next_bounded(uint32_t(n))] : 1.f + 100 * rng.next_float();
        float out = ewa1(maps[k % 3], uv[0], uv[1], d[0], d[1], d[2], d[3], aniso);
        ASSERT_TRUE(out >= 1.f && out <= 11.f) << out << " at " << uv[0] << "," << uv[1] << " d " << d[0] << " "
                                               << d[1] << " " << d[2] << " " << d[3] << " aniso " << aniso;
    }
    // Degenerate ellipses: parallel and antiparallel axes, one zero axis.
    for (auto [a, b] : {std::pair{0.1f, 0.1f}, std::pair{0.1f, -0.3f}, std::pair{0.2f, 0.f}, std::pair{1e-30f, 1e-30f}}) {
        float out = ewa1(m, 0.3f, 0.6f, a, b, 0.5f * a, 0.5f * b);
        EXPECT_TRUE(out >= 1.f && out <= 11.f) << a << " " << b;
    }
    // A huge footprint is the mean; an infinite one too.
    float mean;
    m.level_mean(0, &mean);
    EXPECT_FLOAT_EQ(ewa1(m, 0.3f, 0.6f, 1e30f, 0, 0, 1e30f), mean);
    EXPECT_FLOAT_EQ(ewa1(m, 0.3f, 0.6f, inf, nan, 0, inf), mean);
}

// --------------------------------------------------------------------------------------
// Through the `bitmap` texture and a scene

namespace {

std::string ewa_dir() { return meso::test::scratch_dir("meso_test_ewa"); }

void write_grey_exr(const std::string &path, int w, int h, const std::function<float(int, int)> &f) {
    Image img;
    img.width = w;
    img.height = h;
    img.channels = 3;
    img.data.resize(size_t(w) * h * 3);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
            for (int c = 0; c < 3; ++c) img.data[(size_t(y) * w + x) * 3 + c] = f(x, y);
    write_exr(path, img);
}

std::shared_ptr<Texture> bitmap(const json &extra) {
    auto ctx = std::make_shared<LoadContext>();
    ctx->file = "scene.json";
    ctx->base_dir = ewa_dir();
    json j = {{"type", "bitmap"}, {"filename", "stripes.exr"}};
    if (extra.is_object()) j.update(extra);
    return create_texture(Properties(j, "textures.tex", ctx));
}

std::string bitmap_error(const json &extra) {
    return meso::test::meso_error_of([&] { bitmap(extra); });
}

}  // namespace

TEST(EwaBitmap, FilterTypeAndMaxAnisotropy) {
    const int N = 32;
    write_grey_exr(ewa_dir() + "/stripes.exr", N, N, [](int, int y) { return float(y & 1); });
    auto ewa = bitmap({{"filter_type", "ewa"}});
    auto tri = bitmap({});
    EXPECT_NE(ewa->to_string().find("ewa filter"), std::string::npos) << ewa->to_string();
    ShadingContext ctx;
    ctx.uv = Vec2(0.3f, 11.5f / N);  // a "1" row
    ctx.dudx = 8.f / N;
    ctx.dvdy = 0.5f / N;
    EXPECT_GT(ewa->eval(ctx).g, 0.6f);
    EXPECT_NEAR(tri->eval(ctx).g, 0.5f, 1e-6f);
    // max_anisotropy 1: a circle of the major axis, as blurred as trilinear.
    EXPECT_NEAR(bitmap({{"filter_type", "ewa"}, {"max_anisotropy", 1}})->eval(ctx).g, 0.5f, 0.02f);
    // tiling scales uv and the derivatives: 2x tiling with half the footprint is the same lookup.
    ShadingContext half = ctx;
    half.uv = ctx.uv * 0.5f;
    half.dudx *= 0.5f;
    half.dvdy *= 0.5f;
    EXPECT_FLOAT_EQ(bitmap({{"filter_type", "ewa"}, {"tiling", 2}})->eval(half).g, ewa->eval(ctx).g);
    EXPECT_EQ(bitmap_error({{"filter_type", "ewa"}, {"max_anisotropy", 0.5}}),
              "scene.json: textures.tex.max_anisotropy: expected a number at least 1, got 0.5");
    EXPECT_EQ(bitmap_error({{"filter_type", "ewa"}, {"max_anisotropy", 1e39}}),
              "scene.json: textures.tex.max_anisotropy: expected a finite number of magnitude at most 3.4e38, got 1e+39");
    EXPECT_NE(bitmap_error({{"filter_type", "ewa"}, {"max_anisotropy", "high"}}).find("textures.tex.max_anisotropy"),
              std::string::npos);
}

TEST(EwaBitmap, SceneWithEwaTextureRenders) {
    // A diffuse plane under a directional light, its reflectance a constant-0.6 bitmap with
    // EWA filtering: radiance rho / pi * E * cos exactly (as the constant-reflectance test in
    // test_integrators), then a grazing view of fine stripes renders without NaNs.
    // Next to the scene files that load_json_scene writes.
    const std::string base = (std::filesystem::temp_directory_path() / "meso_tests").string();
    std::filesystem::create_directories(base);
    write_grey_exr(base + "/ewa_const.exr", 16, 16, [](int, int) { return 0.6f; });
    write_grey_exr(base + "/ewa_stripes.exr", 64, 64, [](int, int y) { return float(y & 1); });
    const float E = 3.f, angle = 40.f;
    Vec3 dir_l(0, -std::cos(radians(angle)), -std::sin(radians(angle)));
    auto scene = [&](const char *file, const char *origin) {
        return fmt::format(R"({{
      "camera": {{"type": "perspective", "origin": {}, "target": [0, 0, 0], "up": [0, 0, -1], "fov": 30, "width": 24, "height": 24}},
      "integrator": {{"type": "path", "max_depth": 2}},
      "shapes": [{{"type": "rectangle", "material": {{"type": "diffuse", "reflectance":
                     {{"type": "bitmap", "filename": "{}", "filter_type": "ewa", "max_anisotropy": 16, "tiling": 20}}}},
                   "to_world": {{"scale": 10, "rotate": {{"axis": [1, 0, 0], "angle": -90}}}}}}],
      "lights": [{{"type": "directional", "direction": [{}, {}, {}], "irradiance": {}}}]
    }})",
                           origin, file, dir_l.x, dir_l.y, dir_l.z, E);
    };
    auto s = meso::test::load_json_scene("ewa_const.json", scene("ewa_const.exr", "[0, 2, 0]"));
    RenderResult r = meso::test::render_scene(*s, 4);
    const double expected = 0.6 / Pi * E * std::cos(radians(angle));
    auto st = meso::test::pixel_stats(r.image, 0);
    EXPECT_EQ(r.nan_count, 0);
    EXPECT_NEAR(st.min, expected, 1e-4 * expected);
    EXPECT_NEAR(st.max, expected, 1e-4 * expected);

    auto g = meso::test::load_json_scene("ewa_stripes.json", scene("ewa_stripes.exr", "[0, 0.5, 6]"));
    RenderResult rg = meso::test::render_scene(*g, 4);
    EXPECT_EQ(rg.nan_count, 0);
    auto sg = meso::test::pixel_stats(rg.image, 0);
    EXPECT_TRUE(std::isfinite(sg.mean));
    EXPECT_GE(sg.min, 0.0);
    EXPECT_LE(sg.max, 1.0 / Pi * E + 1e-4);
}

// --------------------------------------------------------------------------------------
// Cost (prints, does not assert)

TEST(EwaTiming, CostPerLookup) {
    const int N = 1024;
    PCG32 rng(5);
    std::vector<float> d(size_t(N) * N * 3);
    for (auto &x : d) x = rng.next_float();
    MipMap m(N, N, 3, std::move(d));
    const int K = 200000;
    struct Case {
        const char *name;
        float major, minor;  // semi-axes in texels
    };
    const Case cases[] = {{"isotropic 4 texels", 4, 4}, {"anisotropy 4 (16 x 4)", 16, 4}, {"anisotropy 8 (32 x 4)", 32, 4},
                          {"anisotropy 16 clamped to 8", 64, 4}, {"magnification 0.5 texel", 0.5f, 0.5f}};
    for (const Case &c : cases) {
        std::vector<float> q(size_t(K) * 6);
        for (int k = 0; k < K; ++k) {
            float th = float(kTwoPi) * rng.next_float();
            float *p = &q[size_t(k) * 6];
            p[0] = rng.next_float();
            p[1] = rng.next_float();
            p[2] = c.major * std::cos(th) / N;   // dudx
            p[3] = -c.minor * std::sin(th) / N;  // dudy
            p[4] = c.major * std::sin(th) / N;   // dvdx
            p[5] = c.minor * std::cos(th) / N;   // dvdy
        }
        float out[3], sink = 0;
        auto time = [&](auto &&lookup) {
            auto t0 = std::chrono::steady_clock::now();
            for (int k = 0; k < K; ++k) {
                const float *p = &q[size_t(k) * 6];
                lookup(p, out);
                sink += out[0];
            }
            return std::chrono::duration<double, std::nano>(std::chrono::steady_clock::now() - t0).count() / K;
        };
        double tri = time([&](const float *p, float *o) { m.filtered(p[0], p[1], p[2], p[3], p[4], p[5], o); });
        double ewa = time([&](const float *p, float *o) { m.ewa(p[0], p[1], p[2], p[3], p[4], p[5], o); });
        std::printf("[ EWA timing ] %-28s trilinear %6.1f ns   ewa %7.1f ns   (x%.1f)%s\n", c.name, tri, ewa, ewa / tri,
                    sink == 12345.f ? " " : "");
    }
}
