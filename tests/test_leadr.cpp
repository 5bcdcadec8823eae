// LEADR (paper 000): the slope grid of §5.1 and its accuracy, the specular material's
// normalisation measured on its own eval, diffuse microfacets (eq. 21) through the same
// checks as the material battery (chi^2, weight = eval/pdf, albedo <= 1), the shadowing
// option, slope statistics from a heightmap, stiff parameters, and the environment
// quadratures (Algorithms 1-3) against converged Monte Carlo.
#include <gtest/gtest.h>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>
#include "image/image.h"
#include "lights/envmap.h"
#include "bsdf/fresnel.h"
#include "bsdf/leadr_quadrature.h"
#include "bsdf/material.h"
#include "bsdf/slope_distribution.h"
#include "render_test_util.h"
#include "bsdf/chi2.h"
#include "sampling/rng.h"
#include "sampling/warp.h"
#include "core/properties.h"
#include "core/registry.h"
#include "texture/slope_source.h"

using namespace meso;

namespace {

constexpr double kPi = 3.14159265358979323846;

std::shared_ptr<Material> make_material(const std::string &json_text) {
    return create_material(Properties(nlohmann::json::parse(json_text), "material", std::make_shared<LoadContext>()));
}

SlopeGaussian make(double mx, double my, double sxx, double syy, double sxy) {
    SlopeGaussian g;
    g.mx = mx, g.my = my, g.sxx = sxx, g.syy = syy, g.sxy = sxy;
    return g;
}

/// Direction from degrees (theta from the normal, phi from s); theta = 90 gives z = 0 exactly.
Vec3 dir_deg(double theta, double phi) {
    const double t = theta * kPi / 180.0, p = phi * kPi / 180.0;
    const double z = theta == 90.0 ? 0.0 : std::cos(t), s = theta == 0.0 ? 0.0 : std::sin(t);
    return Vec3(float(s * std::cos(p)), float(s * std::sin(p)), float(z));
}

std::string json_of(const SlopeGaussian &g) {
    return "\"mean_slope\":[" + std::to_string(g.mx) + "," + std::to_string(g.my) + "],\"covariance\":[" +
           std::to_string(g.sxx) + "," + std::to_string(g.syy) + "," + std::to_string(g.sxy) + "]";
}

const ShadingContext kCtx{};

// Moments used throughout: centred isotropic, anisotropic correlated, non-centred, and a
// mesonormal tilted 80 degrees (mean slope tan 80 = 5.67).
const SlopeGaussian kMoments[] = {
    make(0, 0, 0.1, 0.1, 0), make(0, 0, 0.3, 0.05, 0.08), make(0.5, -0.3, 0.04, 0.09, -0.03),
    make(5.67, 0, 0.1, 0.1, 0.05), make(0, 0, 0.01, 0.01, 0), make(0.3, -0.2, 0.04, 0.05, -0.01),
};

}  // namespace

// ------------------------------------------------------------------ the grid of §5.1

TEST(LeadrGrid, PatternIsSymmetricAndNormalised) {
    EXPECT_DOUBLE_EQ(leadr_grid_lambda(5), std::min(5.0, 0.4 + 1.2 * std::log(5.0)));
    EXPECT_DOUBLE_EQ(leadr_grid_lambda(128), 5.0);
    for (int n : {1, 2, 5, 12, 32, 128}) {
        const LeadrGrid1D &G = leadr_grid_1d(n);
        ASSERT_EQ(G.n, n);
        double sw = 0;
        for (int j = 0; j < n; ++j) {
            sw += G.w[j];
            EXPECT_NEAR(G.p[j], -G.p[n - 1 - j], 1e-12);
            EXPECT_NEAR(G.w[j], G.w[n - 1 - j], 1e-15);
        }
        EXPECT_NEAR(sw, 1.0, 1e-12);
        if (n > 1) { EXPECT_NEAR(G.p[n - 1], G.lambda, 1e-12); }
    }
    // The warp reproduces the mean and covariance up to the truncation of [-lambda, lambda]
    // (the second moment of the normalised 1D pattern, < 1).
    const SlopeGaussian g = GaussianSlopes(make(0.4, -0.1, 0.2, 0.05, 0.06)).params();
    double m[5] = {0, 0, 0, 0, 0};
    for_each_leadr_slope(g, 32, [&](double x, double y, double W) {
        m[0] += W * x, m[1] += W * y, m[2] += W * (x - g.mx) * (x - g.mx), m[3] += W * (y - g.my) * (y - g.my),
            m[4] += W * (x - g.mx) * (y - g.my);
    });
    const LeadrGrid1D &G = leadr_grid_1d(32);
    double v1 = 0;
    for (int j = 0; j < 32; ++j) v1 += G.w[j] * G.p[j] * G.p[j];
    EXPECT_NEAR(m[0], g.mx, 1e-12);
    EXPECT_NEAR(m[1], g.my, 1e-12);
    EXPECT_NEAR(m[2], g.sxx * v1, 1e-12);
    EXPECT_NEAR(m[3], g.syy * v1, 1e-12);
    EXPECT_NEAR(m[4], g.sxy * v1, 1e-12);
    EXPECT_GT(v1, 0.99);
}

// Error of the diffuse slope integral (eq. 21) on the N x N grid against N = 128 over a sweep
// of wo, wi (0-89 degrees) and moments (80-degree tilt included), relative to the value at
// wi = normal. Prints the table; the bounds are the measured values of the lambda rule
// (bsdf/leadr_quadrature.h) with a small margin.
TEST(LeadrGrid, DiffuseIntegralErrorAgainstN128) {
    std::vector<Vec3> wos, wis;
    for (double t : {0.0, 30.0, 60.0, 80.0, 89.0})
        for (double p : {20.0, 200.0}) wos.push_back(dir_deg(t, p));
    for (double t : {0.0, 30.0, 60.0, 80.0, 89.0})
        for (double p : {0.0, 90.0, 160.0, 270.0}) wis.push_back(dir_deg(t, p));
    struct Bound {
        int n;
        double rms, max;
    };
    // Deterministic; bounds 1.3x the measured values (N=5 1.8e-2 / 1.2e-1, N=8 7.1e-3 / 6.6e-2,
    // N=12 3.4e-3 / 3.2e-2, N=16 1.6e-3 / 1.5e-2, N=32 1.6e-4 / 9.6e-4).
    const Bound bounds[] = {{5, 2.4e-2, 1.5e-1}, {8, 9e-3, 8.6e-2}, {12, 4.4e-3, 4.1e-2}, {16, 2.1e-3, 1.9e-2}, {32, 2.1e-4, 1.25e-3}};
    std::printf("  N   lambda   rms error   max error   (relative to the value at wi = normal, vs N = 128)\n");
    for (int n : {2, 3, 4, 5, 6, 8, 10, 12, 16, 20, 24, 32, 64}) {
        double s2 = 0, mx = 0;
        long count = 0;
        for (const SlopeGaussian &m : kMoments) {
            GaussianSlopes g(m);
            for (const Vec3 &wo : wos) {
                const double scale = std::max(leadr_diffuse_slope_integral(g, 128, wo, Vec3(0, 0, 1)), 1e-9);
                for (const Vec3 &wi : wis) {
                    const double e = std::abs(leadr_diffuse_slope_integral(g, n, wo, wi) -
                                              leadr_diffuse_slope_integral(g, 128, wo, wi)) / scale;
                    s2 += e * e, mx = std::max(mx, e), ++count;
                }
            }
        }
        const double rms = std::sqrt(s2 / count);
        std::printf("  %-3d %6.3f   %.2e    %.2e\n", n, leadr_grid_lambda(n), rms, mx);
        for (const Bound &b : bounds)
            if (b.n == n) {
                EXPECT_LT(rms, b.rms) << "N " << n;
                EXPECT_LT(mx, b.max) << "N " << n;
            }
    }
    // The precomputed grid equals the direct evaluation.
    GaussianSlopes g(kMoments[2]);
    LeadrDiffuseGrid grid(g, 12);
    for (const Vec3 &wo : wos)
        for (const Vec3 &wi : wis)
            EXPECT_NEAR(grid.integral(wo, wi), leadr_diffuse_slope_integral(g, 12, wo, wi), 1e-12);
}

// ------------------------------------------------------------------ environment quadrature

namespace {

/// A smooth synthetic environment (env-local direction): a vertical gradient and three broad
/// coloured Gaussian blobs.
Spectrum synthetic_env(const Vec3 &d) {
    Spectrum L = Spectrum(0.2f, 0.25f, 0.3f) + Spectrum(0.3f, 0.2f, 0.1f) * (0.5f * (d.y + 1.f));
    const struct {
        Vec3 c;
        float w;
        Spectrum a;
    } blobs[] = {{normalize(Vec3(0.3f, 0.8f, 0.5f)), 0.15f, Spectrum(3.f, 2.f, 1.f)},
                 {normalize(Vec3(-0.6f, 0.2f, 0.7f)), 0.25f, Spectrum(0.5f, 1.5f, 2.f)},
                 {normalize(Vec3(0.1f, -0.3f, -0.9f)), 0.3f, Spectrum(1.f, 1.f, 0.5f)}};
    for (const auto &b : blobs) L += b.a * std::exp((dot(d, b.c) - 1.f) / b.w);
    return L;
}

std::shared_ptr<PrefilteredEnvironment> synthetic_environment(int w = 256) {
    const int h = w / 2;
    std::vector<Spectrum> texels(size_t(w) * h);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
            texels[size_t(y) * w + x] = synthetic_env(EnvMapLight::uv_to_direction(Vec2((x + 0.5f) / w, (y + 0.5f) / h)));
    return std::make_shared<PrefilteredEnvironment>(w, h, texels, Transform());
}

struct McResult {
    Spectrum mean, se;
};

/// Converged Monte Carlo of eq. (19) (specular, F = 1) or eq. (21) (diffuse, rho = 1) with
/// the level-0 radiance: slopes from P22 (GaussianSlopes::sample_normal), and for the
/// diffuse case w_i cosine-distributed about the micro-normal.
McResult mc_reference(const GaussianSlopes &g, const Vec3 &wo, const Frame &frame, const PrefilteredEnvironment &env,
                      bool diffuse, LeadrShadowing mode, long n, uint64_t seed) {
    PCG32 rng(seed);
    const Vec3 nbar = g.mesonormal();
    const double area = dot(nbar, wo) / double(nbar.z), lo = g.lambda(wo);
    double s[3] = {0, 0, 0}, s2[3] = {0, 0, 0};
    for (long k = 0; k < n; ++k) {
        const Vec3 m = g.sample_normal(Vec2(rng.next_float(), rng.next_float()));
        const Vec2 u(rng.next_float(), rng.next_float());
        const double dmo = dot(m, wo);
        if (!(dmo > 0.0)) continue;
        const Vec3 wi = diffuse ? normalize(Frame(m).to_world(square_to_cosine_hemisphere(u))) : normalize(reflect(wo, m));
        if (!(wi.z > 0.f)) continue;
        const double G = leadr_shadowing(lo, g.lambda(wi), mode);
        if (!(G > 0.0)) continue;
        const Spectrum L = env.radiance(frame.to_world(wi));
        const double k2 = dmo / m.z * G / area;
        for (int c = 0; c < 3; ++c) {
            const double v = L[c] * k2;
            s[c] += v, s2[c] += v * v;
        }
    }
    McResult r;
    for (int c = 0; c < 3; ++c) {
        const double mean = s[c] / n;
        r.mean[c] = float(mean);
        r.se[c] = float(std::sqrt(std::max(0.0, s2[c] / n - mean * mean) / (n - 1)));
    }
    return r;
}

double max_rel(const Spectrum &a, const Spectrum &ref) {
    double e = 0;
    for (int c = 0; c < 3; ++c) e = std::max(e, std::abs(double(a[c]) - ref[c]) / std::max(1e-9, double(ref[c])));
    return e;
}

struct EnvCase {
    const char *name;
    SlopeGaussian g;
    double theta, phi;  ///< wo
};
const EnvCase kEnvCases[] = {
    {"centred iso 0.05, wo 30", make(0, 0, 0.05, 0.05, 0), 30, 20},
    {"mean + aniso corr, wo 60", make(0.3, -0.2, 0.09, 0.02, 0.03), 60, 200},
    {"tilted mean (1, 0.2), 0.02, wo 45", make(1.0, 0.2, 0.02, 0.02, 0.0), 45, 160},
    {"rough iso 0.5, wo 70", make(0, 0, 0.5, 0.5, 0), 70, 90},
};
const Frame kEnvFrame(normalize(Vec3(0.3f, 0.8f, 0.5f)));

}  // namespace

// Algorithm 1 (eq. 22) against Monte Carlo of eq. (19): N x N grid with and without the
// prefiltered lookups. Prints N vs relative error; the bounds are the documented bias.
TEST(LeadrEnvQuadrature, SpecularMatchesMonteCarlo) {
    auto env = synthetic_environment();
    const auto one = [](float) { return Spectrum(1.f); };
    for (const EnvCase &ec : kEnvCases) {
        GaussianSlopes g(ec.g);
        const Vec3 wo = dir_deg(ec.theta, ec.phi);
        const McResult ref = mc_reference(g, wo, kEnvFrame, *env, false, LeadrShadowing::Joint, 2000000, 11);
        const double se = max_rel(ref.mean + ref.se, ref.mean);
        std::printf("  %s: MC %.4f %.4f %.4f (rel. s.e. %.1e)\n    N  rel.err prefiltered  level 0\n", ec.name,
                    ref.mean.r, ref.mean.g, ref.mean.b, se);
        for (int n : {2, 3, 5, 8, 12, 16, 24, 32}) {
            LeadrEnvOptions o;
            o.n = n;
            const double e = max_rel(leadr_env_specular(g, wo, kEnvFrame, one, *env, o), ref.mean);
            o.prefilter = false;
            const double e0 = max_rel(leadr_env_specular(g, wo, kEnvFrame, one, *env, o), ref.mean);
            std::printf("    %-3d %.2e           %.2e\n", n, e, e0);
            // Documented bias (bsdf/leadr_quadrature.h): the prefiltered lookups blur the
            // environment over each sample's solid angle (deliberately overestimated, §5.2):
            // up to 8.4% at N = 8 and 4.5% at N = 16 for the rough case, < 2% at N = 32;
            // without prefiltering the grid alone is within 3e-3 from N = 12 on.
            if (n == 8) { EXPECT_LT(e, 4.0 * se + 0.1) << ec.name; }
            if (n == 16) { EXPECT_LT(e, 4.0 * se + 0.05) << ec.name; }
            if (n >= 12) { EXPECT_LT(e0, 4.0 * se + 3e-3) << ec.name; }
            if (n == 32) { EXPECT_LT(e, 4.0 * se + 0.02) << ec.name; }
        }
    }
}

// Algorithms 2-3 (eq. 20-21, 23) against Monte Carlo of eq. (21).
TEST(LeadrEnvQuadrature, DiffuseMatchesMonteCarlo) {
    auto env = synthetic_environment();
    for (const EnvCase &ec : kEnvCases) {
        GaussianSlopes g(ec.g);
        const Vec3 wo = dir_deg(ec.theta, ec.phi);
        const McResult ref = mc_reference(g, wo, kEnvFrame, *env, true, LeadrShadowing::Joint, 2000000, 12);
        const double se = max_rel(ref.mean + ref.se, ref.mean);
        std::printf("  %s: MC %.4f %.4f %.4f (rel. s.e. %.1e)\n    N  rel.err shadowed  paper\n", ec.name, ref.mean.r,
                    ref.mean.g, ref.mean.b, se);
        for (int n : {2, 3, 5, 8, 12, 16, 32}) {
            LeadrEnvOptions o;
            o.n = n;
            const double e = max_rel(leadr_env_diffuse(g, wo, kEnvFrame, Spectrum(1.f), *env, o), ref.mean);
            o.irradiance = LeadrIrradiance::Paper;
            const double ep = max_rel(leadr_env_diffuse(g, wo, kEnvFrame, Spectrum(1.f), *env, o), ref.mean);
            std::printf("    %-3d %.2e        %.2e\n", n, e, ep);
            // Documented bias: the SH truncation of the irradiance and its projection from
            // the 32 x 16 level, ~0.7% here once N >= 8; 3.4% at the paper's N = 5 for the
            // rough case. The paper's Algorithm 2 (no shadowing, no horizon) is off by
            // 4-25% on these cases: it is only checked to be finite and positive.
            if (n == 5) { EXPECT_LT(e, 4.0 * se + 0.04) << ec.name; }
            if (n >= 8) { EXPECT_LT(e, 4.0 * se + 0.02) << ec.name; }
            EXPECT_TRUE(ep < 0.5) << ec.name;
        }
    }
}

// The prefiltered environment: level-0 lookups equal the bilinear radiance (EnvMapLight's),
// the level follows log4(solid angle / texel solid angle), huge footprints give the
// coarsest level, the SH projection reproduces a constant environment's irradiance (pi L).
TEST(LeadrEnvQuadrature, PrefilteredEnvironmentLookups) {
    auto env = synthetic_environment(256);
    PCG32 rng(3);
    const double texel_eq = (2 * kPi / 256) * (kPi / 128);  // at the equator
    for (int i = 0; i < 200; ++i) {
        const Vec3 d = square_to_uniform_sphere(Vec2(rng.next_float(), rng.next_float()));
        const Spectrum a = env->lookup(d, 1e-9), b = env->radiance(d);
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(a[c], b[c], 1e-6f);
        // bilinear level 0 against the analytic function (smooth): close
        const Spectrum f = synthetic_env(d);
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(b[c], f[c], 0.02f * f[c]);
        EXPECT_EQ(env->level_for(d, 1e3), float(env->levels() - 1));
    }
    const Vec3 eq = normalize(Vec3(1.f, 0.f, 0.2f));  // on the equator (y = 0)
    EXPECT_NEAR(env->level_for(eq, texel_eq), 0.f, 1e-3f);
    EXPECT_NEAR(env->level_for(eq, 4 * texel_eq), 1.f, 1e-3f);
    EXPECT_NEAR(env->level_for(eq, 64 * texel_eq), 3.f, 1e-3f);
    // Constant environment: E(n) = pi L for every n.
    std::vector<Spectrum> ones(64 * 32, Spectrum(1.f, 0.5f, 0.25f));
    PrefilteredEnvironment cenv(64, 32, ones, Transform());
    for (int i = 0; i < 50; ++i) {
        const Vec3 n = square_to_uniform_sphere(Vec2(rng.next_float(), rng.next_float()));
        const Spectrum E = sh9_irradiance(cenv.sh(), n);
        EXPECT_NEAR(E.r, kPi, 2e-3);
        EXPECT_NEAR(E.b, 0.25 * kPi, 1e-3);
    }
}

// ------------------------------------------------------------------ the material

// Paper 000 after eq. (16): without Fresnel and shadowing, specular LEADR integrates to one
// over the sphere of wi for every wo above the mesosurface and all moments. Checked on the
// material's own eval (shadowing "masking", F = 1): eval(wo, wi) over wi, parameterised by
// the micro-normal's slope s (wi = reflect(wo, m(s)), |dwi/ds| = 4 (m . wo) m.z^3, paper
// §5.2) on a fine grid of +-8 standard deviations. eval is 0 where wi is below the
// macrosurface or the mesosurface (reflection only, fully shadowed); that lost part is
// integrated from the formula D / (4 area (1 + Lambda(wo))) and must close the sum to one.
// Where it is negligible, eval alone integrates to one. A plain (cos theta, phi) rule over
// the hemisphere cross-checks the broad cases without any change of variables.
namespace {
/// int eval(wo, wi) dwi through the slope parameterisation (see below); `lost` receives the
/// formula's integral over the wi where eval is 0 (below the macro- or mesosurface).
double slope_space_integral(const Material &mat, const GaussianSlopes &g, const Vec3 &wo, double &lost) {
    const SlopeGaussian &p = g.params();
    const double l00 = std::sqrt(p.sxx), l10 = p.sxy / l00, l11 = std::sqrt(p.syy - l10 * l10);
    const Vec3 nbar = g.mesonormal();
    const double area = dot(nbar, wo) / double(nbar.z), lo = g.lambda(wo);
    const int n = 800;
    const double zmax = 8.0, dz = 2 * zmax / n, ds = dz * dz * l00 * l11;
    double sum = 0;
    lost = 0;
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) {
            const double z0 = -zmax + (i + 0.5) * dz, z1 = -zmax + (j + 0.5) * dz;
            const double sx = p.mx + l00 * z0, sy = p.my + l10 * z0 + l11 * z1;
            const Vec3 m = leadr_slope_normal(sx, sy);
            const double dmo = dot(m, wo);
            if (!(dmo > 0.0)) continue;
            const Vec3 wi = normalize(reflect(wo, m));
            const double mz = m.z, J = 4.0 * dmo * mz * mz * mz;
            if (wi.z > 0.f && !std::isinf(g.lambda(wi)))
                sum += double(mat.eval(kCtx, wo, wi).g) * J * ds;
            else
                lost += g.p22(sx, sy) * dmo / (mz * area * (1.0 + lo)) * ds;
        }
    return sum;
}
}  // namespace

TEST(LeadrMaterial, SpecularIntegratesToOneWithoutFresnelAndShadowing) {
    std::vector<SlopeGaussian> moments(std::begin(kMoments), std::end(kMoments));
    moments.push_back(make(2.0, 1.0, 1.0, 0.5, 0.2));
    moments.push_back(make(0, 0, 4.0, 4.0, 0));
    std::printf("  moments (mx, my, sxx, syy, sxy)      theta_o  int eval   lost part   sum - 1\n");
    for (const SlopeGaussian &mg : moments) {
        auto mat = make_material("{\"type\":\"leadr\",\"shadowing\":\"masking\"," + json_of(mg) + "}");
        GaussianSlopes g(mg);
        const Vec3 nbar = g.mesonormal();
        for (double t : {0.0, 30.0, 60.0, 80.0, 89.0}) {
            const Vec3 wo = dir_deg(t, 20);
            if (!(dot(nbar, wo) / double(nbar.z) > 1e-3)) continue;  // wo (nearly) masked: nothing to normalise
            double lost;
            const double mat_sum = slope_space_integral(*mat, g, wo, lost);
            std::printf("  (%5.2f %5.2f %5.2f %5.2f %5.2f)  %5.1f    %.5f   %.2e    %+.1e\n", mg.mx, mg.my, mg.sxx, mg.syy,
                        mg.sxy, t, mat_sum, lost, mat_sum + lost - 1.0);
            EXPECT_NEAR(mat_sum + lost, 1.0, 1e-4) << "theta " << t << " mean " << mg.mx;
            if (lost < 1e-4) { EXPECT_NEAR(mat_sum, 1.0, 2e-4) << "theta " << t << " mean " << mg.mx; }
        }
    }
    // Hemisphere midpoint rule in (cos theta, phi), broad lobes only: the same integral.
    for (int k : {0, 2}) {
        auto mat = make_material("{\"type\":\"leadr\",\"shadowing\":\"masking\"," + json_of(kMoments[k]) + "}");
        GaussianSlopes g(kMoments[k]);
        for (double t : {0.0, 40.0}) {
            const Vec3 wo = dir_deg(t, 20);
            const int nt = 1000, np = 2000;
            double sum = 0, lost;
            for (int i = 0; i < nt; ++i) {
                const double ct = (i + 0.5) / nt, st = std::sqrt(1 - ct * ct);
                for (int j = 0; j < np; ++j) {
                    const double ph = 2 * kPi * (j + 0.5) / np;
                    sum += mat->eval(kCtx, wo, Vec3(float(st * std::cos(ph)), float(st * std::sin(ph)), float(ct))).g;
                }
            }
            sum *= (1.0 / nt) * (2 * kPi / np);
            EXPECT_NEAR(sum, slope_space_integral(*mat, g, wo, lost), 1e-3) << "moments " << k << " theta " << t;
        }
    }
}

namespace {

struct DiffuseCase {
    const char *name;
    const char *json;
};
// The diffuse-microfacet configurations (eq. 21) that the shared battery should also run.
const DiffuseCase kDiffuseCases[] = {
    {"leadr_diffuse_iso", R"({"type":"leadr","specular_reflectance":0,"diffuse_reflectance":1,"alpha":0.5})"},
    {"leadr_diffuse_mean", R"({"type":"leadr","specular_reflectance":0,"diffuse_reflectance":0.8,"mean_slope":[0.3,-0.2],"covariance":[0.04,0.05,-0.01]})"},
    {"leadr_diffuse_tilt80", R"({"type":"leadr","specular_reflectance":0,"diffuse_reflectance":1,"mean_slope":[5.67,0],"covariance":[0.1,0.1,0.05]})"},
    {"leadr_diffuse_rough_masking", R"({"type":"leadr","specular_reflectance":0,"diffuse_reflectance":1,"covariance":[2,2,0],"shadowing":"masking"})"},
    {"leadr_mix_Cu", R"({"type":"leadr","material":"Cu","specular_reflectance":0.6,"diffuse_reflectance":[0.4,0.3,0.2],"covariance":[0.09,0.02,0.03]})"},
    {"leadr_mix_mean_masking", R"({"type":"leadr","specular_reflectance":0.5,"diffuse_reflectance":0.5,"mean_slope":[0.5,0.2],"alpha":0.3,"shadowing":"masking"})"},
};
const double kThetas[] = {0.0, 30.0, 60.0, 89.0};

}  // namespace

// The battery's checks 1-4 for the diffuse configurations: chi^2 of sample() against pdf()
// (Sidak-corrected over these tests), weight == eval/pdf and sample.pdf == pdf(wi) for every
// sample, int pdf == the fraction of samples returned, albedo <= 1 over a sweep of wo.
TEST(LeadrMaterial, DiffuseMicrofacetsPassTheBatteryChecks) {
    const int tests = int(std::size(kDiffuseCases) * std::size(kThetas));
    for (const DiffuseCase &dc : kDiffuseCases) {
        auto mat = make_material(dc.json);
        for (double t : kThetas) {
            Chi2Options opt;
            opt.samples = 200000;
            opt.seed = std::hash<std::string>()(dc.name) + uint64_t(t);
            opt.test_count = tests;
            opt.name = std::string(dc.name) + "_theta" + std::to_string(int(t));
            const Chi2Result r = chi2_material_test(*mat, kCtx, dir_deg(t, 20), opt);
            EXPECT_TRUE(r.passed) << dc.name << " theta " << t << ": " << r.message;
            EXPECT_EQ(r.invalid, 0u) << dc.name;
            EXPECT_EQ(r.weight_mismatch, 0u) << dc.name << " max rel. error " << r.max_weight_rel_error;
            EXPECT_EQ(r.pdf_mismatch, 0u) << dc.name << " max rel. error " << r.max_pdf_rel_error;
            const double n = double(r.samples), frac = double(r.smooth) / n;
            const double sigma = std::sqrt(std::max(frac * (1.0 - frac), 1.0 / n) / n);
            EXPECT_LE(r.pdf_integral, 1.0 + 1e-4) << dc.name;
            EXPECT_NEAR(r.pdf_integral, frac, 5.0 * sigma + 1e-4) << dc.name << " theta " << t;
        }
        for (double t : {0.0, 30.0, 60.0, 75.0, 85.0, 89.0}) {
            const AlbedoEstimate a = estimate_albedo(*mat, kCtx, dir_deg(t, 20), 40000, 1234 + uint64_t(t));
            for (int c = 0; c < 3; ++c) {
                EXPECT_LE(a.mean[c], 1.0 + 5.0 * a.stderr_[c] + 1e-6) << dc.name << " theta " << t;
                EXPECT_GE(a.mean[c], 0.0) << dc.name;
            }
        }
    }
}

// The diffuse lobe's albedo is at most rho (int <m, wi> dwi <= pi) and, for a smooth surface,
// Lambert's: rho at every wo (up to the masking of grazing wo, none for variance 1e-6).
TEST(LeadrMaterial, DiffuseLobeReducesToLambertWhenSmooth) {
    auto mat = make_material(R"({"type":"leadr","specular_reflectance":0,"diffuse_reflectance":0.7,"covariance":[1e-6,1e-6,0]})");
    PCG32 rng(5);
    for (int i = 0; i < 200; ++i) {
        const Vec3 wo = square_to_cosine_hemisphere(Vec2(rng.next_float(), rng.next_float()));
        const Vec3 wi = square_to_cosine_hemisphere(Vec2(rng.next_float(), rng.next_float()));
        if (wo.z < 0.05f || wi.z < 0.05f) continue;
        EXPECT_NEAR(mat->eval(kCtx, wo, wi).g, 0.7 / kPi * wi.z, 2e-3 * 0.7 / kPi) << wo.z << " " << wi.z;
    }
}

// "joint" and "masking" differ exactly by (1 + Lo + Li) / (1 + Lo) on both lobes, and both
// give exactly 0 when wi is below the mesosurface.
TEST(LeadrMaterial, ShadowingOption) {
    const std::string base = R"("type":"leadr","specular_reflectance":0.5,"diffuse_reflectance":0.5,"mean_slope":[2,0],"covariance":[0.1,0.05,0.02])";
    auto joint = make_material("{" + base + "}");
    auto mask = make_material("{" + base + R"(,"shadowing":"masking"})");
    GaussianSlopes g(make(2, 0, 0.1, 0.05, 0.02));
    PCG32 rng(9);
    int checked = 0, shadowed = 0;
    for (int i = 0; i < 2000; ++i) {
        Vec3 wo = square_to_cosine_hemisphere(Vec2(rng.next_float(), rng.next_float()));
        Vec3 wi = square_to_cosine_hemisphere(Vec2(rng.next_float(), rng.next_float()));
        const double lo = g.lambda(wo), li = g.lambda(wi);
        const Spectrum a = joint->eval(kCtx, wo, wi), b = mask->eval(kCtx, wo, wi);
        if (std::isinf(li) || std::isinf(lo)) {
            EXPECT_EQ(a.g, 0.f);
            EXPECT_EQ(b.g, 0.f);
            EXPECT_EQ(joint->pdf(kCtx, wo, wi), 0.f);
            ++shadowed;
            continue;
        }
        EXPECT_NEAR(a.g * (1 + lo + li), b.g * (1 + lo), 1e-4 * b.g * (1 + lo) + 1e-9);
        EXPECT_LE(a.g, b.g * (1 + 1e-6) + 1e-9);
        ++checked;
    }
    EXPECT_GT(checked, 200);
    EXPECT_GT(shadowed, 200);
    EXPECT_THROW(make_material(R"({"type":"leadr","shadowing":"separable"})"), std::exception);
    EXPECT_THROW(make_material(R"({"type":"leadr","diffuse_quadrature":0})"), std::exception);
    EXPECT_THROW(make_material(R"({"type":"leadr","env_irradiance":"sh"})"), std::exception);
}

// Statistics from a heightmap: the material equals the constant-statistics one built from
// SlopeSource::eval at the shading point plus the base roughness alpha^2/2 (both lobes).
TEST(LeadrMaterial, HeightmapSourcePlusBaseRoughness) {
    const char *hm = R"("heightmap":{"map":{"generator":"gaussian","size":32,"seed":3},"scale":0.05,"tiling":2})";
    auto mat = make_material(std::string("{\"type\":\"leadr\",") + hm + R"(,"alpha":0.2,"diffuse_reflectance":0.3,"specular_reflectance":0.7})");
    SlopeSource src = SlopeSource::parse(
        Properties(nlohmann::json::parse(std::string("{") + hm + "}"), "material", std::make_shared<LoadContext>()));
    ASSERT_FALSE(src.is_constant());
    PCG32 rng(4);
    for (int k = 0; k < 20; ++k) {
        ShadingContext ctx;
        ctx.uv = Vec2(rng.next_float(), rng.next_float());
        ctx.dpdu = Vec3(2.f, 0.f, 0.f);
        ctx.dpdv = Vec3(0.3f, 1.f, 0.f);
        ctx.dudx = 0.02f, ctx.dvdy = 0.03f;
        SlopeGaussian s = src.eval(ctx);
        s.sxx += 0.02, s.syy += 0.02;
        ASSERT_GT(s.sxx + s.syy, 0.04);
        auto ref = make_material(R"({"type":"leadr","diffuse_reflectance":0.3,"specular_reflectance":0.7,)" + json_of(s) + "}");
        for (int i = 0; i < 20; ++i) {
            const Vec3 wo = square_to_cosine_hemisphere(Vec2(rng.next_float(), rng.next_float()));
            const Vec3 wi = square_to_cosine_hemisphere(Vec2(rng.next_float(), rng.next_float()));
            const float a = mat->eval(ctx, wo, wi).g, b = ref->eval(kCtx, wo, wi).g;
            EXPECT_NEAR(a, b, 1e-4f * b + 1e-7f);
            EXPECT_NEAR(mat->pdf(ctx, wo, wi), ref->pdf(kCtx, wo, wi), 1e-4f * ref->pdf(kCtx, wo, wi) + 1e-7f);
        }
    }
    // alpha now combines with covariance too (base roughness on top of it)
    auto both = make_material(R"({"type":"leadr","covariance":[0.1,0.05,0.01],"alpha":0.4})");
    auto sum = make_material(R"({"type":"leadr","covariance":[0.18,0.13,0.01]})");
    const Vec3 wo = dir_deg(35, 10), wi = dir_deg(50, 170);
    EXPECT_NEAR(both->eval(kCtx, wo, wi).g, sum->eval(kCtx, wo, wi).g, 1e-6);
}

// ------------------------------------------------------------------ stiff parameters

namespace {
/// Finite, non-negative eval / pdf / sample weights over directions including theta = 90
/// exactly, below the surface, wo = wi and the mirror direction (the battery's check 7).
void expect_sane(const Material &m, const std::string &what) {
    std::vector<Vec3> dirs = {dir_deg(0, 0),     dir_deg(30, 20), dir_deg(60, 200), dir_deg(89, 45),
                              dir_deg(89.9, 10), dir_deg(90, 0),  dir_deg(90, 77),  dir_deg(91, 33),
                              dir_deg(120, 260), dir_deg(180, 0), Vec3(0.f, 0.f, 1.f), Vec3(0.f, 0.f, -1.f)};
    const Vec2 us[] = {{0.f, 0.f}, {0.5f, 0.5f}, {OneMinusEpsilon, OneMinusEpsilon}, {0.f, OneMinusEpsilon},
                       {0.25f, 0.75f}, {1e-7f, 0.5f}, {0.5f, 1e-7f}};
    for (const Vec3 &wo : dirs) {
        std::vector<Vec3> wis = dirs;
        wis.push_back(wo);
        wis.push_back(Vec3(-wo.x, -wo.y, wo.z));
        wis.push_back(-wo);
        for (const Vec3 &wi : wis) {
            const Spectrum v = m.eval(kCtx, wo, wi);
            const float p = m.pdf(kCtx, wo, wi);
            ASSERT_TRUE(v.is_finite() && v.r >= 0 && v.g >= 0 && v.b >= 0) << what << ": eval " << wo.z << " " << wi.z;
            ASSERT_TRUE(std::isfinite(p) && p >= 0) << what << ": pdf " << wo.z << " " << wi.z;
            if (!(wo.z > 0.f) || !(wi.z > 0.f)) {
                ASSERT_EQ(v.g, 0.f) << what;
                ASSERT_EQ(p, 0.f) << what;
            }
        }
        for (float ul : {0.f, 0.5f, OneMinusEpsilon})
            for (Vec2 u : us) {
                BSDFSample bs;
                if (!m.sample(kCtx, wo, ul, u, bs)) continue;
                ASSERT_GT(wo.z, 0.f) << what;
                ASSERT_TRUE(bs.weight.is_finite() && bs.weight.r >= 0 && bs.weight.g >= 0 && bs.weight.b >= 0) << what;
                ASSERT_TRUE(std::isfinite(bs.pdf) && bs.pdf > 0) << what;
                ASSERT_TRUE(is_finite(bs.wi) && std::abs(length(bs.wi) - 1.f) < 1e-3f && bs.wi.z > 0.f) << what;
            }
    }
}
}  // namespace

TEST(LeadrStiff, FiniteEverywhere) {
    const char *stats[] = {
        R"("covariance":[1e-12,1e-12,0])",           // sigma -> 0 (regularised to 1e-8)
        R"("covariance":[100,100,0])",               // sigma^2 = 100
        R"("covariance":[100,1e-12,1e-5])",          // extreme anisotropy, rho = 1
        R"("covariance":[0.1,0.1,0.1])",             // |rho| = 1: degenerate, regularised
        R"("covariance":[0.1,0.4,-0.2])",            // rho = -1
        R"("mean_slope":[1000,0],"covariance":[0.1,0.1,0])",   // mean slope 1e3
        R"("mean_slope":[-700,700],"covariance":[1e-12,1e-12,0])",
        R"("mean_slope":[1000,-1000],"covariance":[100,100,0])",
        R"("alpha":1000)", R"("alpha":1e-6)", R"("alpha":0)",
    };
    const char *lobes[] = {R"("material":"Au")", R"("specular_reflectance":0,"diffuse_reflectance":1)",
                           R"("specular_reflectance":0.5,"diffuse_reflectance":0.5,"shadowing":"masking")",
                           R"("diffuse_reflectance":0.5,"rational_lambda":true,"diffuse_quadrature":1)"};
    for (const char *s : stats)
        for (const char *l : lobes) {
            const std::string json = std::string("{\"type\":\"leadr\",") + s + "," + l + "}";
            expect_sane(*make_material(json), json);
        }
}

// sigma -> 0: the specular lobe converges to the mirror direction and its energy to F.
TEST(LeadrStiff, VanishingRoughnessIsAMirror) {
    auto mat = make_material(R"({"type":"leadr","material":"Au","covariance":[1e-12,1e-12,0]})");
    Spectrum eta, k;
    ASSERT_TRUE(conductor_preset("Au", eta, k));
    for (double t : {0.0, 30.0, 60.0, 80.0}) {
        const Vec3 wo = dir_deg(t, 20);
        const AlbedoEstimate a = estimate_albedo(*mat, kCtx, wo, 2000, 7);
        const Spectrum F = fresnel_conductor(wo.z, eta, k);
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(a.mean[c], F[c], 2e-3) << "theta " << t;
        // every sample is (within 1e-3 rad) the mirror direction
        PCG32 rng(1);
        for (int i = 0; i < 100; ++i) {
            BSDFSample bs;
            ASSERT_TRUE(mat->sample(kCtx, wo, 0.5f, Vec2(rng.next_float(), rng.next_float()), bs));
            EXPECT_GT(dot(bs.wi, reflect_local(wo)), std::cos(1e-3));
        }
    }
}

// Light below the mesosurface (nu < 0, Lambda(wi) = inf) gives exactly 0, for both lobes and
// both shadowing modes; wo below it reflects nothing and samples nothing.
TEST(LeadrStiff, BelowTheMesosurfaceIsExactlyZero) {
    for (const char *l : {"", R"(,"shadowing":"masking")"})
        for (const char *lobe : {R"("material":"Cu")", R"("specular_reflectance":0,"diffuse_reflectance":1)"}) {
            auto mat = make_material(std::string(R"({"type":"leadr","mean_slope":[2,0],"covariance":[0.05,0.05,0],)") +
                                     lobe + l + "}");
            GaussianSlopes g(make(2, 0, 0.05, 0.05, 0));
            // mesonormal (-2, 0, 1)/sqrt 5: tilted 63 degrees towards -x
            const Vec3 wo = dir_deg(30, 180), below = dir_deg(70, 0), masked = dir_deg(80, 0);
            ASSERT_TRUE(std::isinf(g.lambda(below)));
            EXPECT_EQ(mat->eval(kCtx, wo, below).g, 0.f);
            EXPECT_EQ(mat->pdf(kCtx, wo, below), 0.f);
            EXPECT_GT(mat->eval(kCtx, wo, dir_deg(40, 150)).g, 0.f);
            for (const Vec3 &wi : {dir_deg(30, 180), dir_deg(10, 0), below}) EXPECT_EQ(mat->eval(kCtx, masked, wi).g, 0.f);
            BSDFSample bs;
            EXPECT_FALSE(mat->sample(kCtx, masked, 0.5f, Vec2(0.3f, 0.6f), bs));
            PCG32 rng(2);
            for (int i = 0; i < 1000; ++i)
                if (mat->sample(kCtx, wo, rng.next_float(), Vec2(rng.next_float(), rng.next_float()), bs)) {
                    EXPECT_FALSE(std::isinf(g.lambda(bs.wi)));
                }
        }
}

// The environment quadratures on the same stiff inputs: finite, non-negative; sigma -> 0
// gives the mirror direction's radiance (times F).
TEST(LeadrStiff, EnvQuadratureFinite) {
    auto env = synthetic_environment(64);
    const auto one = [](float) { return Spectrum(1.f); };
    const SlopeGaussian stats[] = {make(0, 0, 1e-12, 1e-12, 0), make(0, 0, 100, 100, 0), make(0, 0, 100, 1e-12, 1e-5),
                                   make(0, 0, 0.1, 0.1, 0.1),   make(1000, 0, 0.1, 0.1, 0), make(-700, 700, 1e-12, 1e-12, 0),
                                   make(2, 0, 0.05, 0.05, 0)};
    for (const SlopeGaussian &s : stats) {
        GaussianSlopes g(s);
        for (double t : {0.0, 45.0, 89.0, 89.99, 90.0, 120.0})
            for (double ph : {0.0, 180.0})
                for (LeadrIrradiance irr : {LeadrIrradiance::Shadowed, LeadrIrradiance::Paper})
                    for (int n : {1, 5, 32}) {
                        LeadrEnvOptions o;
                        o.n = n;
                        o.irradiance = irr;
                        const Vec3 wo = dir_deg(t, ph);
                        const Spectrum a = leadr_env_specular(g, wo, kEnvFrame, one, *env, o);
                        const Spectrum b = leadr_env_diffuse(g, wo, kEnvFrame, Spectrum(1.f), *env, o);
                        ASSERT_TRUE(a.is_finite() && a.r >= 0 && a.g >= 0 && a.b >= 0) << s.mx << " " << s.sxx << " " << t;
                        ASSERT_TRUE(b.is_finite() && b.r >= 0 && b.g >= 0 && b.b >= 0) << s.mx << " " << s.sxx << " " << t;
                        if (!(wo.z > 0.f)) { EXPECT_TRUE(a.is_black() && b.is_black()); }
                    }
    }
    GaussianSlopes mirror(make(0, 0, 1e-12, 1e-12, 0));
    for (double t : {0.0, 30.0, 60.0}) {
        const Vec3 wo = dir_deg(t, 20);
        LeadrEnvOptions o;
        const Spectrum a = leadr_env_specular(mirror, wo, kEnvFrame, one, *env, o);
        const Spectrum L = env->radiance(kEnvFrame.to_world(reflect_local(wo)));
        EXPECT_LT(max_rel(a, L), 1e-3) << t;
    }
}

// Cost of the pieces (printed, not checked): the material's eval with diffuse microfacets
// (N = 12 default vs 16) and the environment quadratures per shading point.
TEST(LeadrEnvQuadrature, Timings) {
    using clock = std::chrono::steady_clock;
    auto per_call_us = [](auto &&f, int reps) {
        const auto t0 = clock::now();
        for (int i = 0; i < reps; ++i) f(i);
        return std::chrono::duration<double, std::micro>(clock::now() - t0).count() / reps;
    };
    volatile float sink = 0;
    for (int n : {8, 12, 16}) {
        auto mat = make_material(R"({"type":"leadr","diffuse_reflectance":0.5,"specular_reflectance":0.5,"alpha":0.4,"diffuse_quadrature":)" +
                                 std::to_string(n) + "}");
        const double us = per_call_us([&](int i) { sink = sink + mat->eval(kCtx, dir_deg(30, 20), dir_deg(i % 80, 100)).g; }, 20000);
        std::printf("  eval, specular + diffuse (N = %d): %.3f us\n", n, us);
    }
    auto env = synthetic_environment();
    GaussianSlopes g(make(0.3, -0.2, 0.09, 0.02, 0.03));
    const auto one = [](float) { return Spectrum(1.f); };
    for (int n : {5, 8, 16, 32}) {
        LeadrEnvOptions o;
        o.n = n;
        const double a = per_call_us([&](int i) { sink = sink + leadr_env_specular(g, dir_deg(i % 60, 200), kEnvFrame, one, *env, o).g; }, 300);
        const double b = per_call_us([&](int i) { sink = sink + leadr_env_diffuse(g, dir_deg(i % 60, 200), kEnvFrame, Spectrum(1.f), *env, o).g; }, 300);
        o.irradiance = LeadrIrradiance::Paper;
        const double c = per_call_us([&](int i) { sink = sink + leadr_env_diffuse(g, dir_deg(i % 60, 200), kEnvFrame, Spectrum(1.f), *env, o).g; }, 300);
        std::printf("  N = %-2d  Algorithm 1: %.1f us   Algorithms 2-3 shadowed: %.1f us, paper: %.1f us\n", n, a, b, c);
    }
}

// ------------------------------------------------------------------ the path integrator option

// A LEADR sphere (specular Au + diffuse microfacets, tilted mean, anisotropic) under a smooth
// environment map: `path` with leadr_env_quadrature (noise-free apart from pixel jitter)
// against the plain path tracer at high spp. A lone convex sphere never occludes its own
// upper hemisphere, so the quadrature's "unoccluded environment" is exact here and the two
// agree up to Monte Carlo noise plus the quadrature bias (documented in
// bsdf/leadr_quadrature.h: a few % at N = 8 with prefiltering, ~1% SH error for the
// diffuse part).
TEST(LeadrIntegrator, EnvQuadratureMatchesPathTracing) {
    const int w = 128, h = 64;
    Image img(w, h, 3);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
            img.set_rgb(x, y, synthetic_env(EnvMapLight::uv_to_direction(Vec2((x + 0.5f) / w, (y + 0.5f) / h))));
    const std::string env = test::write_temp("leadr_env.exr", "");
    write_exr(env, img);
    auto scene_json = [&](bool quad, int spp) {
        return R"({
          "camera": {"type": "perspective", "origin": [0, 0.5, 4], "target": [0, 0, 0], "fov": 30, "width": 24, "height": 24},
          "integrator": {"type": "path", "hide_emitters": true, "leadr_env_quadrature": )" +
               std::string(quad ? "true" : "false") + R"(},
          "sampler": {"type": "independent", "sample_count": )" + std::to_string(spp) + R"(},
          "shapes": [{"type": "sphere", "radius": 1, "material": {"type": "leadr", "material": "Au",
              "specular_reflectance": 0.7, "diffuse_reflectance": 0.3, "mean_slope": [0.3, -0.2],
              "covariance": [0.05, 0.03, 0.01], "env_quadrature": 16}}],
          "lights": [{"type": "envmap", "filename": ")" + env + R"("}]
        })";
    };
    auto quad = test::load_json_scene("leadr_quad.json", scene_json(true, 16));
    auto plain = test::load_json_scene("leadr_plain.json", scene_json(false, 1024));
    const RenderResult rq = test::render_scene(*quad, 16), rp = test::render_scene(*plain, 1024);
    EXPECT_EQ(rq.nan_count, 0);
    EXPECT_EQ(rp.nan_count, 0);
    // The quadrature render traces no shadow rays towards the environment (its only light).
    EXPECT_EQ(rq.shadow_rays, 0u);
    for (int c = 0; c < 3; ++c) {
        const test::PixelStats q = test::pixel_stats(rq.image, c), p = test::pixel_stats(rp.image, c);
        // per-pixel difference: noise of the plain render (estimated from the pixel pairs) + bias
        double d = 0, d2 = 0;
        int n = 0;
        for (int y = 0; y < 24; ++y)
            for (int x = 0; x < 24; ++x) {
                const double a = rq.image.at(x, y, c), b = rp.image.at(x, y, c);
                if (b <= 0 && a <= 0) continue;
                d += a - b, d2 += (a - b) * (a - b), ++n;
            }
        const double mean_d = d / n, sd = std::sqrt(std::max(0.0, d2 / n - mean_d * mean_d));
        std::printf("  channel %d: image mean quadrature %.4f, path %.4f (rel. diff %+.2e), pixel rms diff %.3e\n", c,
                    q.mean, p.mean, (q.mean - p.mean) / p.mean, std::sqrt(d2 / n));
        EXPECT_NEAR(q.mean, p.mean, 5.0 * sd / std::sqrt(double(n)) + 0.03 * p.mean) << "channel " << c;
    }
}
