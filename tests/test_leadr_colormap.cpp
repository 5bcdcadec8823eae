// Colour maps on Gaussian surfaces (paper 001 §5): the `leadr` material's "colormap" block, the
// `microcolormap` ground-truth texture, the micro-height of shell-mapped hits and the §5.3
// irradiance mode. The closed forms themselves are tested in test_transfer_filter.cpp; these
// tests check the wiring against independent quadratures of the paper's integrals.
#include <gtest/gtest.h>
#include <chrono>
#include <cmath>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "geometry/interaction.h"
#include "material_test_util.h"
#include "bsdf/leadr_quadrature.h"
#include "bsdf/slope_distribution.h"
#include "texture/texture.h"
#include "filter/transfer_filter.h"
#include "render_test_util.h"
#include "sampling/rng.h"
#include "render/scene.h"

using namespace meso;
using meso::test::dir_deg;
using meso::test::make_material;
using json = nlohmann::json;

namespace {

constexpr double kSigmaH = 0.01, kHMean = 0.002;
const char *kRamp = R"([[-0.02, [0.1, 0.2, 0.9]], [-0.004, [0.2, 0.8, 0.2]], [0.006, [0.9, 0.5, 0.1]], [0.02, [1, 1, 1]]])";
const double kRampX[] = {-0.02, -0.004, 0.006, 0.02};
const double kRampC[][3] = {{0.1, 0.2, 0.9}, {0.2, 0.8, 0.2}, {0.9, 0.5, 0.1}, {1, 1, 1}};

/// The ramp above, evaluated independently of Ramp.
double ramp_at(double v, int c) {
    if (v <= kRampX[0]) return kRampC[0][c];
    if (v >= kRampX[3]) return kRampC[3][c];
    for (int i = 0; i < 3; ++i)
        if (v <= kRampX[i + 1]) {
            const double t = (v - kRampX[i]) / (kRampX[i + 1] - kRampX[i]);
            return (1 - t) * kRampC[i][c] + t * kRampC[i + 1][c];
        }
    return kRampC[3][c];
}

std::string leadr_json(const std::string &colormap_extra, const std::string &cov = "[0.1, 0.1, 0]") {
    return R"({"type": "leadr", "covariance": )" + cov +
           R"(, "specular_reflectance": 0, "diffuse_reflectance": 1, "colormap": {"ramp": )" + kRamp +
           R"(, "height_mean": 0.002, "height_sigma": 0.01)" + colormap_extra + "}}";
}
std::string plain_json(const std::string &cov = "[0.1, 0.1, 0]") {
    return R"({"type": "leadr", "covariance": )" + cov + R"(, "specular_reflectance": 0, "diffuse_reflectance": 1})";
}

/// The colour factor: the material's value with the colour map over the value without it; -1
/// where the value is 0 (view masked by the mesosurface), after checking that both are 0 there.
Spectrum color_factor(const Material &with, const Material &without, Vec3 wo, Vec3 wi) {
    ShadingContext ctx;
    const Spectrum a = with.eval(ctx, wo, wi), b = without.eval(ctx, wo, wi);
    if (!(b.r > 0.f)) {
        EXPECT_EQ(a.r + a.g + a.b, 0.f);
        return Spectrum(-1.f);
    }
    return Spectrum(a.r / b.r, a.g / b.g, a.b / b.b);
}

/// <C, D_h> for D_h = (L + 1) P_h^L p_h (eq. 15), by a fine midpoint rule over heights.
double height_color_quadrature(double lambda_sum, int c) {
    const int n = 200000;
    const double a = kHMean - 10 * kSigmaH, b = kHMean + 14 * kSigmaH, h = (b - a) / n;
    double num = 0, den = 0;
    for (int k = 0; k < n; ++k) {
        const double x = a + (k + 0.5) * h, z = (x - kHMean) / kSigmaH;
        const double P = 0.5 * std::erfc(-z / std::sqrt(2.0));
        const double d = std::pow(P, lambda_sum) * std::exp(-0.5 * z * z);
        num += ramp_at(x, c) * d;
        den += d;
    }
    return num / den;
}

}  // namespace

TEST(LeadrColormap, HeightAtNormalIncidenceIsTheGaussianAverageOfTheRamp) {
    // Lambda(wo) = Lambda(wi) = 0: D_h = p_h, so the colour is <C, N(h_bar, sigma_h^2)>.
    auto with = make_material(leadr_json("")), without = make_material(plain_json());
    const Spectrum f = color_factor(*with, *without, Vec3(0, 0, 1), Vec3(0, 0, 1));
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(f[c], height_color_quadrature(0.0, c), 2e-3) << c;
    // and it is not the naive C(h_bar)
    auto naive = make_material(leadr_json(R"(, "filter": "naive")"));
    const Spectrum g = color_factor(*naive, *without, Vec3(0, 0, 1), Vec3(0, 0, 1));
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(g[c], ramp_at(kHMean, c), 1e-5) << c;
    EXPECT_GT(std::abs(f.r - g.r) + std::abs(f.g - g.g), 0.05);
}

TEST(LeadrColormap, HeightExactDistributionMatchesQuadratureOfEq15) {
    // With "exact", the colour is <C, N(mu_d, sigma_d)> with the true moments of eq. 15: against
    // the quadrature of <C, D_h> it differs only by D_h's non-Gaussianity and the table error.
    auto with = make_material(leadr_json(R"(, "height_distribution": "exact")"));
    auto fit = make_material(leadr_json(""));
    auto without = make_material(plain_json());
    GaussianSlopes g(SlopeGaussian{0, 0, 0.1, 0.1, 0});
    int tested = 0;
    for (double to : {30.0, 60.0, 80.0, 89.0})
        for (double ti : {0.0, 45.0, 85.0}) {
            const Vec3 wo = dir_deg(to, 0), wi = dir_deg(ti, 180);
            const double L = g.lambda(wo) + g.lambda(wi);
            const Spectrum f = color_factor(*with, *without, wo, wi);
            const Spectrum ff = color_factor(*fit, *without, wo, wi);
            if (f.r < 0.f) continue;
            ++tested;
            for (int c = 0; c < 3; ++c) {
                const double q = height_color_quadrature(L, c);
                // The Gaussian stand-in for D_h (exact moments) against the quadrature of eq. 15;
                // ignoring the view (L = 0) moves the colour by > 0.1 at 80 degrees (checked below).
                EXPECT_NEAR(f[c], q, 0.02) << "wo " << to << " wi " << ti << " channel " << c << " L " << L;
                EXPECT_NEAR(ff[c], q, 0.06) << "fit: wo " << to << " wi " << ti << " channel " << c;
                EXPECT_TRUE(std::isfinite(f[c]) && std::isfinite(ff[c]));
            }
        }
    EXPECT_GE(tested, 10);
    // The view dependence is real: at 80 degrees the colour moved towards the high stops.
    const Spectrum head = color_factor(*with, *without, dir_deg(0, 0), dir_deg(0, 0));
    const Spectrum graze = color_factor(*with, *without, dir_deg(80, 0), dir_deg(75, 180));
    EXPECT_GT(graze.r - head.r, 0.1);  // red grows with height
}

TEST(LeadrColormap, SlopeXMatchesTheVisibleSlopeDistribution) {
    // <C(s_x), D_s> with D_s = p_s (1 - s.t)+ / M0 by 2D quadrature, against the material's
    // Gaussian stand-in for D_s. Ramp over slopes this time.
    const std::string mat = R"({"type": "leadr", "covariance": [0.12, 0.05, 0.02], "mean_slope": [0.1, -0.05],
        "specular_reflectance": 0, "diffuse_reflectance": 1,
        "colormap": {"attribute": "slope_x", "ramp": [[-0.6, [1, 0, 0]], [0, [0, 1, 0]], [0.6, [0, 0, 1]]]}})";
    const std::string plain = R"({"type": "leadr", "covariance": [0.12, 0.05, 0.02], "mean_slope": [0.1, -0.05],
        "specular_reflectance": 0, "diffuse_reflectance": 1})";
    auto with = make_material(mat), without = make_material(plain);
    auto ramp = [](double v, int c) {
        const double x[3] = {-0.6, 0, 0.6};
        const double t = std::clamp((v - x[0]) / 0.6, 0.0, 2.0);
        const double cols[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
        const int i = std::min(1, int(t));
        const double u = t - i;
        return (1 - u) * cols[i][c] + u * cols[i + 1][c];
    };
    const double mx = 0.1, my = -0.05, sxx = 0.12, syy = 0.05, sxy = 0.02;
    const double det = sxx * syy - sxy * sxy;
    for (double to : {0.0, 40.0, 70.0, 85.0})
        for (double phi : {0.0, 135.0}) {
            const Vec3 wo = dir_deg(to, phi);
            const double tx = wo.x / wo.z, ty = wo.y / wo.z;
            double num[3] = {0, 0, 0}, den = 0;
            const int n = 600;
            const double r = 6.0, hx = 2 * r * std::sqrt(sxx) / n, hy = 2 * r * std::sqrt(syy) / n;
            for (int i = 0; i < n; ++i)
                for (int j = 0; j < n; ++j) {
                    const double x = mx - r * std::sqrt(sxx) + (i + 0.5) * hx, y = my - r * std::sqrt(syy) + (j + 0.5) * hy;
                    const double dx = x - mx, dy = y - my;
                    const double q = (syy * dx * dx - 2 * sxy * dx * dy + sxx * dy * dy) / det;
                    const double w = std::exp(-0.5 * q) * std::max(0.0, 1 - x * tx - y * ty);
                    den += w;
                    for (int c = 0; c < 3; ++c) num[c] += w * ramp(x, c);
                }
            const Spectrum f = color_factor(*with, *without, wo, dir_deg(20, 90));
            if (f.r < 0.f) continue;  // masked by the tilted mesosurface
            // The Gaussian stand-in for D_s (exact first two moments) leaves the skew of D_s out:
            // measured max 0.021 at 70 degrees on this kinked ramp, < 0.002 at 0 and 40 degrees.
            double err = 0, err_naive = 0;
            for (int c = 0; c < 3; ++c) {
                EXPECT_NEAR(f[c], num[c] / den, 0.03) << "theta " << to << " phi " << phi << " channel " << c;
                err += std::abs(f[c] - num[c] / den);
                err_naive += std::abs(ramp(mx, c) - num[c] / den);
            }
            if (to >= 40.0) { EXPECT_LT(err, 0.5 * err_naive) << "theta " << to << " phi " << phi; }
        }
}

TEST(LeadrColormap, SteepnessAndGrazingAreFinite) {
    const std::string mat = R"({"type": "leadr", "covariance": [0.3, 0.3, 0],
        "specular_reflectance": 0.5, "diffuse_reflectance": 0.5,
        "colormap": {"attribute": "steepness", "ramp": [[0, [0, 0, 1]], [0.5, [0, 1, 0]], [1.5, [1, 0, 0]]]}})";
    auto m = make_material(mat);
    ShadingContext ctx;
    for (double to : {0.0, 60.0, 89.9, 90.0})
        for (double ti : {0.0, 89.9}) {
            const Spectrum v = m->eval(ctx, dir_deg(to, 0), dir_deg(ti, 180));
            EXPECT_TRUE(v.is_finite()) << to << " " << ti;
            EXPECT_GE(std::min(v.r, std::min(v.g, v.b)), 0.f);
        }
    // Normal incidence: E[C(|s|)] for isotropic Gaussian slopes (|s| Rayleigh, sigma^2 = 0.3).
    const std::string plain = R"({"type": "leadr", "covariance": [0.3, 0.3, 0],
        "specular_reflectance": 0.5, "diffuse_reflectance": 0.5})";
    auto p = make_material(plain);
    const Spectrum f = color_factor(*m, *p, Vec3(0, 0, 1), dir_deg(30, 0));
    double e[3] = {0, 0, 0};
    const int n = 200000;
    for (int k = 0; k < n; ++k) {
        const double rr = (k + 0.5) * 8.0 / n, pdf = rr / 0.3 * std::exp(-rr * rr / 0.6) * 8.0 / n;
        const double x[3] = {0, 0.5, 1.5};
        double col[3];
        if (rr >= 1.5) col[0] = 1, col[1] = 0, col[2] = 0;
        else if (rr >= 0.5) { const double t = (rr - 0.5); col[0] = t, col[1] = 1 - t, col[2] = 0; }
        else { const double t = rr / 0.5; col[0] = 0, col[1] = t, col[2] = 1 - t; }
        (void)x;
        for (int c = 0; c < 3; ++c) e[c] += col[c] * pdf;
    }
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(f[c], e[c], 0.01) << c;  // 8 x 8 Gauss-Hermite vs a kinked ramp
}

TEST(LeadrColormap, NoisePerturbedHeightsWidenTheDistribution) {
    // C(h + r): mu += mu_r, sigma^2 += sigma_r^2 (§5.1). At normal incidence the colour is then
    // <C, N(h_bar + mu_r, sigma_h^2 + sigma_r^2)>.
    auto with = make_material(leadr_json(R"(, "noise_mean": 0.003, "noise_sigma": 0.008)"));
    auto without = make_material(plain_json());
    const Spectrum f = color_factor(*with, *without, Vec3(0, 0, 1), Vec3(0, 0, 1));
    Ramp ramp({-0.02, -0.004, 0.006, 0.02}, {0.1, 0.2, 0.9, 0.2, 0.8, 0.2, 0.9, 0.5, 0.1, 1, 1, 1}, 3);
    double e[3];
    ramp.gaussian_average(kHMean + 0.003, std::sqrt(kSigmaH * kSigmaH + 0.008 * 0.008), e);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(f[c], e[c], 2e-3) << c;
}

TEST(LeadrColormap, BadInputErrorsNameTheKey) {
    auto expect_error = [](const std::string &text, const std::string &needle) {
        try {
            make_material(text);
            ADD_FAILURE() << "no error for " << text;
        } catch (const MesoError &e) {
            EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
        }
    };
    expect_error(leadr_json(R"(, "attribute": "colour")"), "colormap.attribute");
    expect_error(leadr_json(R"(, "filter": "mip")"), "colormap.filter");
    expect_error(leadr_json(R"(, "height_distribution": "table")"), "colormap.height_distribution");
    expect_error(leadr_json(R"(, "noise_sigma": -1)"), "colormap.noise_sigma");
    expect_error(leadr_json(R"(, "sigma_max": 0)"), "colormap.sigma_max");
    expect_error(leadr_json(R"(, "table_size": [1, 5])"), "colormap.table_size");
    expect_error(leadr_json(R"(, "wobble": 1)"), "wobble");
    expect_error(R"({"type": "leadr", "colormap": {"ramp": [[0, 1]]}})", "colormap.attribute");
    expect_error(R"({"type": "leadr", "colormap": {"ramp": [[0, 1], [0, 2]], "attribute": "slope_x"}})", "colormap.ramp");
    expect_error(R"({"type": "leadr", "colormap": {"ramp": [[0, [1, 2]]], "attribute": "slope_x"}})", "colormap.ramp");
}

TEST(MicroColormap, ReadsHeightAndSlopeOfTheMicroPoint) {
    auto tex = [](const std::string &attr) {
        json j = {{"type", "microcolormap"}, {"attribute", attr},
                  {"colormap", json::array({json::array({-1, json::array({0, 0, 0})}), json::array({1, json::array({2, 4, 6})})})}};
        return create_texture(Properties(j, "texture", std::make_shared<LoadContext>()));
    };
    ShadingContext ctx;
    ctx.micro_height = 0.25f;
    ctx.n_macro = Vec3(0, 0, 1);
    ctx.dpdu_macro = Vec3(2, 0, 0);
    ctx.frame = Frame(slope_to_normal(0.3, -0.2));
    // C(v) = (v + 1) * (1, 2, 3) on [-1, 1]
    EXPECT_NEAR(tex("height")->eval(ctx).g, 1.25f * 2, 1e-5);
    EXPECT_NEAR(tex("slope_x")->eval(ctx).r, 1.3f, 1e-5);
    EXPECT_NEAR(tex("slope_y")->eval(ctx).r, 0.8f, 1e-5);
    EXPECT_NEAR(tex("steepness")->eval(ctx).r, 1.0 + std::sqrt(0.13), 1e-5);
    ShadingContext flat;  // off microgeometry: height 0, slope 0
    EXPECT_NEAR(tex("height")->eval(flat).r, 1.f, 1e-6);
    EXPECT_NEAR(tex("slope_x")->eval(flat).r, 1.f, 1e-6);
    EXPECT_THROW(tex("normal"), MesoError);
}

TEST(MicroColormap, ShellHitsCarryTheirHeight) {
    // A displaced rectangle (normal +z, base at z = 0): the reported micro-height is the hit's z.
    const std::string scene = R"({
      "camera": {"type": "perspective", "origin": [0, 0, 3], "target": [0, 0, 0], "up": [0, 1, 0], "fov": 30,
                 "width": 8, "height": 8},
      "shapes": [{"type": "rectangle", "material": {"type": "diffuse"},
                  "displacement": {"map": {"generator": "gaussian", "size": 64, "correlation": 0.05, "seed": 3},
                                   "scale": 2, "tiling": 2, "mode": "shell"}}]})";
    auto s = meso::test::load_json_scene("micro_height.json", scene);
    PCG32 rng(5);
    int hits = 0;
    for (int k = 0; k < 200; ++k) {
        const Vec3 o(float(rng.next_float() * 1.6 - 0.8), float(rng.next_float() * 1.6 - 0.8), 2.f);
        const Vec3 d = normalize(Vec3(float(rng.next_float() * 0.6 - 0.3), float(rng.next_float() * 0.6 - 0.3), -1.f));
        SurfaceInteraction si;
        if (!s->intersect(Ray(o, d), si)) continue;
        ++hits;
        ASSERT_TRUE(std::isfinite(si.micro_height));
        EXPECT_NEAR(si.micro_height, si.p.z, 1e-4f + 1e-3f * std::abs(si.p.z));
        EXPECT_TRUE(std::isfinite(si.shading_context(true).micro_height));
    }
    EXPECT_GT(hits, 150);
}

TEST(LeadrEnvGaussian, ConstantEnvironmentGivesTheAlbedo) {
    // §5.3 with a constant environment L: E(n) = pi L for every normal, so rho / pi <E, D_s> = rho L
    // whatever the view or the slope distribution (unshadowed, as in the paper).
    std::vector<Spectrum> texels(32 * 16, Spectrum(0.7f, 0.5f, 0.3f));
    PrefilteredEnvironment env(32, 16, texels, Transform());
    LeadrEnvOptions opt;
    opt.irradiance = LeadrIrradiance::Gaussian;
    opt.n = 6;
    for (double to : {0.0, 50.0, 75.0}) {
        GaussianSlopes g(SlopeGaussian{0.1, 0.05, 0.2, 0.1, 0.03});
        const Spectrum L = leadr_env_diffuse(g, dir_deg(to, 30), Frame(Vec3(0, 0, 1)), Spectrum(0.5f), env, opt);
        EXPECT_NEAR(L.r, 0.35, 0.35 * 0.02) << to;  // SH projection of a constant is exact up to the texel sums
        EXPECT_NEAR(L.b, 0.15, 0.15 * 0.02) << to;
    }
}

TEST(LeadrColormap, CombinationsAreSumsAndProductsOfTheTerms) {
    // §6: kappa_0 C_0 + kappa_1 C_h + kappa_2 C_s (sum) and C_0 C_h C_s (product), each term
    // filtered on its own; checked against materials with one term each.
    const std::string h = std::string(R"({"ramp": )") + kRamp + R"(, "height_mean": 0.002, "height_sigma": 0.01)";
    const std::string sl = R"({"attribute": "slope_x", "ramp": [[-0.5, [1, 0, 0]], [0.5, [0, 0, 1]]])";
    const std::string t0 = R"({"texture": [0.2, 0.4, 0.6])";
    auto one = [&](const std::string &term) {
        return make_material(R"({"type": "leadr", "covariance": [0.1, 0.1, 0], "specular_reflectance": 0,
            "diffuse_reflectance": 1, "colormap": )" + term + "}");
    };
    auto many = [&](const std::string &comb, const std::string &w) {
        return make_material(R"({"type": "leadr", "covariance": [0.1, 0.1, 0], "specular_reflectance": 0,
            "diffuse_reflectance": 1, "colormap_combine": ")" + comb + R"(", "colormap": [)" + t0 + ", \"weight\": " + w +
                             "}, " + h + ", \"weight\": " + w + "}, " + sl + ", \"weight\": " + w + "}]}");
    };
    auto without = make_material(plain_json());
    auto a = one(t0 + "}"), b = one(h + "}"), c = one(sl + "}");
    auto sum = many("sum", "0.3"), prod = many("product", "1");
    for (double to : {0.0, 60.0, 80.0}) {
        const Vec3 wo = dir_deg(to, 0), wi = dir_deg(40, 180);
        const Spectrum fa = color_factor(*a, *without, wo, wi), fb = color_factor(*b, *without, wo, wi),
                       fc = color_factor(*c, *without, wo, wi);
        const Spectrum fs = color_factor(*sum, *without, wo, wi), fp = color_factor(*prod, *without, wo, wi);
        for (int k = 0; k < 3; ++k) {
            EXPECT_NEAR(fs[k], 0.3 * (fa[k] + fb[k] + fc[k]), 1e-5) << to << " " << k;
            EXPECT_NEAR(fp[k], fa[k] * fb[k] * fc[k], 1e-5) << to << " " << k;
        }
    }
    try {
        make_material(R"({"type": "leadr", "covariance": [0.1, 0.1, 0], "colormap_combine": "max", "colormap": [)" + t0 + "}]}");
        ADD_FAILURE() << "no error";
    } catch (const MesoError &e) {
        EXPECT_NE(std::string(e.what()).find("colormap_combine"), std::string::npos) << e.what();
    }
}

// Cost of the colour factor (a measurement printed for the README and notes; the only check is
// that the values are finite): eval of a diffuse leadr point with and without each colormap.
TEST(LeadrColormap, EvalCost) {
    const std::string sl = R"({"attribute": "slope_x", "ramp": [[-0.5, [1, 0, 0]], [0.5, [0, 0, 1]]]})";
    const std::string st = R"({"attribute": "steepness", "ramp": [[0, [0, 0, 1]], [0.5, [0, 1, 0]], [1.5, [1, 0, 0]]]})";
    const std::pair<const char *, std::string> cases[] = {
        {"none", plain_json()},
        {"height (fit)", leadr_json("")},
        {"height (exact)", leadr_json(R"(, "height_distribution": "exact")")},
        {"slope_x", R"({"type": "leadr", "covariance": [0.1, 0.1, 0], "specular_reflectance": 0, "diffuse_reflectance": 1, "colormap": )" + sl + "}"},
        {"steepness", R"({"type": "leadr", "covariance": [0.1, 0.1, 0], "specular_reflectance": 0, "diffuse_reflectance": 1, "colormap": )" + st + "}"},
    };
    ShadingContext ctx;
    PCG32 rng(3);
    std::vector<std::pair<Vec3, Vec3>> dirs;
    for (int i = 0; i < 256; ++i)
        dirs.emplace_back(dir_deg(80.0 * rng.next_float(), 360.0 * rng.next_float()),
                          dir_deg(80.0 * rng.next_float(), 360.0 * rng.next_float()));
    for (const auto &[name, json] : cases) {
        auto m = make_material(json);
        Spectrum acc(0.f);
        for (const auto &d : dirs) acc += m->eval(ctx, d.first, d.second);  // warm-up (tables built once)
        const int n = 20000;
        const auto t0 = std::chrono::steady_clock::now();
        for (int i = 0; i < n; ++i) acc += m->eval(ctx, dirs[i & 255].first, dirs[i & 255].second);
        const double us = std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count() / n;
        EXPECT_TRUE(acc.is_finite());
        std::printf("[ cost     ] leadr diffuse eval, colormap %s: %.2f us\n", name, us);
    }
}

TEST(CombineTexture, WeightedSumAndProductOfTerms) {
    auto make = [](const json &j) { return create_texture(Properties(j, "texture", std::make_shared<LoadContext>())); };
    const json terms = json::array({{{"texture", json::array({0.2, 0.4, 0.6})}, {"weight", 0.5}},
                                    {{"texture", {{"type", "constant"}, {"value", 0.3}}}},
                                    {{"texture", {{"type", "microcolormap"}, {"attribute", "height"},
                                                  {"colormap", json::array({json::array({0, 0}), json::array({1, 1})})}}},
                                     {"weight", 2}}});
    ShadingContext ctx;
    ctx.micro_height = 0.25f;
    const Spectrum s = make({{"type", "combine"}, {"terms", terms}})->eval(ctx);
    const Spectrum p = make({{"type", "combine"}, {"op", "product"}, {"terms", terms}})->eval(ctx);
    const float want_s[3] = {0.1f + 0.3f + 0.5f, 0.2f + 0.3f + 0.5f, 0.3f + 0.3f + 0.5f};
    const float want_p[3] = {0.1f * 0.3f * 0.5f, 0.2f * 0.3f * 0.5f, 0.3f * 0.3f * 0.5f};
    for (int c = 0; c < 3; ++c) {
        EXPECT_NEAR(s[c], want_s[c], 1e-6f) << c;
        EXPECT_NEAR(p[c], want_p[c], 1e-6f) << c;
    }
    for (const auto &[bad, key] : std::vector<std::pair<json, std::string>>{
             {{{"type", "combine"}, {"op", "max"}, {"terms", terms}}, "texture.op"},
             {{{"type", "combine"}, {"terms", json::array()}}, "texture.terms"},
             {{{"type", "combine"}, {"terms", json::array({{{"weight", 1}}})}}, "texture.terms[0].texture"},
             {{{"type", "combine"}, {"terms", json::array({{{"texture", 1}, {"wieght", 1}}})}}, "wieght"}}) {
        try {
            make(bad);
            ADD_FAILURE() << bad.dump();
        } catch (const MesoError &e) {
            EXPECT_NE(std::string(e.what()).find(key), std::string::npos) << e.what();
        }
    }
}
