// `colormap` texture (paper 001 §4, src/texture/colormap_texture.cpp): footprint statistics of
// the image driver against direct texel statistics, of the noise driver against Monte-Carlo
// window averages; the filtered colour against independent quadrature of <C, N(f_bar, sigma_f^2)>
// (with a table-error bound derived from the ramp's kinks) and against brute-force averages of
// C(f) over the footprint; zero / huge / non-finite footprints; located errors.
#include <gtest/gtest.h>
#include <OpenImageIO/imageio.h>
#include <chrono>
#include <cmath>
#include <nlohmann/json.hpp>
#include <random>
#include "core/error.h"
#include "texture/texture.h"
#include "core/properties.h"
#include "core/registry.h"
#include "scratch_dir.h"
#include "texture_test_util.h"

using namespace meso;
using json = nlohmann::json;

namespace {

std::string tmp_dir() { return meso::test::scratch_dir("meso_test_colormap"); }

std::shared_ptr<Texture> make_texture(const json &j) { return meso::test::make_texture_in(tmp_dir(), j); }
std::string texture_error(const json &j) { return meso::test::texture_error_in(tmp_dir(), j); }

ShadingContext at(double u, double v, double dudx = 0, double dudy = 0, double dvdx = 0, double dvdy = 0) {
    return meso::test::uv_context(u, v, dudx, dudy, dvdx, dvdy);
}

/// A float EXR of w x h grey values.
std::string write_grey(const std::string &name, int w, int h, const std::vector<float> &v) {
    const std::string path = tmp_dir() + "/" + name;
    auto out = OIIO::ImageOutput::create(path);
    EXPECT_TRUE(out) << OIIO::geterror();
    OIIO::ImageSpec spec(w, h, 1, OIIO::TypeDesc::FLOAT);
    EXPECT_TRUE(out->open(path, spec));
    EXPECT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, v.data()));
    out->close();
    return name;
}

/// A piecewise-linear colour map kept independently of the Ramp class: stops x[i] with RGB
/// values, constant beyond the ends; `json()` gives the scene syntax.
struct TestRamp {
    std::vector<double> x;
    std::vector<std::array<double, 3>> c;

    json to_json() const {
        json j = json::array();
        for (size_t i = 0; i < x.size(); ++i) j.push_back({x[i], {c[i][0], c[i][1], c[i][2]}});
        return j;
    }
    std::array<double, 3> eval(double v) const {
        if (v <= x.front()) return c.front();
        if (v >= x.back()) return c.back();
        size_t i = 0;
        while (v > x[i + 1]) ++i;
        const double t = (v - x[i]) / (x[i + 1] - x[i]);
        return {c[i][0] + t * (c[i + 1][0] - c[i][0]), c[i][1] + t * (c[i + 1][1] - c[i][1]),
                c[i][2] + t * (c[i + 1][2] - c[i][2])};
    }
    /// Sum over the kinks of the largest |slope jump| over the channels (bounds |C''| mass).
    double kink_mass() const {
        double s = 0;
        for (size_t i = 0; i < x.size(); ++i) {
            double worst = 0;
            for (int k = 0; k < 3; ++k) {
                const double left = i > 0 ? (c[i][k] - c[i - 1][k]) / (x[i] - x[i - 1]) : 0.0;
                const double right = i + 1 < x.size() ? (c[i + 1][k] - c[i][k]) / (x[i + 1] - x[i]) : 0.0;
                worst = std::max(worst, std::abs(right - left));
            }
            s += worst;
        }
        return s;
    }
    double max_slope() const {
        double s = 0;
        for (size_t i = 0; i + 1 < x.size(); ++i)
            for (int k = 0; k < 3; ++k) s = std::max(s, std::abs(c[i + 1][k] - c[i][k]) / (x[i + 1] - x[i]));
        return s;
    }
    /// <C, N(m, s^2)> by the trapezoid rule on [m - 10 s, m + 10 s] (independent of Ramp).
    std::array<double, 3> gaussian_quadrature(double m, double s) const {
        if (!(s > 0)) return eval(m);
        const int n = 40000;
        const double a = m - 10 * s, h = 20 * s / n;
        std::array<double, 3> acc{0, 0, 0};
        double wsum = 0;
        for (int i = 0; i <= n; ++i) {
            const double v = a + i * h, z = (v - m) / s;
            const double w = std::exp(-0.5 * z * z) * (i == 0 || i == n ? 0.5 : 1.0);
            const auto cv = eval(v);
            for (int k = 0; k < 3; ++k) acc[k] += w * cv[k];
            wsum += w;
        }
        for (int k = 0; k < 3; ++k) acc[k] /= wsum;
        return acc;
    }
};

/// Narrow alternating bands: `n` stops from lo to hi, dark blue / bright orange / green.
TestRamp banded_ramp(double lo, double hi, int n) {
    TestRamp r;
    const std::array<double, 3> cols[3] = {{0.05, 0.08, 0.3}, {0.95, 0.6, 0.1}, {0.2, 0.8, 0.3}};
    for (int i = 0; i < n; ++i) {
        r.x.push_back(lo + (hi - lo) * i / (n - 1));
        r.c.push_back(cols[i % 3]);
    }
    return r;
}

std::array<double, 3> rgb(const Spectrum &s) { return {s.r, s.g, s.b}; }
double max_abs_diff(const std::array<double, 3> &a, const std::array<double, 3> &b) {
    return std::max({std::abs(a[0] - b[0]), std::abs(a[1] - b[1]), std::abs(a[2] - b[2])});
}

/// Bound on the bilinear interpolation error of the preconvolved table (paper eq. 9;
/// PreconvolvedTable: n_mean nodes over [x_min - 4 smax, x_max + 4 smax], sigma_j = smax (j/(n-1))^2)
/// at (m, s). G(m, s) = <C, N(m, s^2)> has d2G/dm2 = sum_i db_i phi(z_i) / s and, by the heat
/// equation, dG/ds = s d2G/dm2 = sum_i db_i phi(z_i), d2G/ds2 = sum_i db_i z_i^2 phi(z_i) / s
/// (z_i = (x_i - m) / s, db_i the slope jumps); |phi| <= 0.399 and |z^2 phi(z)| <= 0.108. The
/// bilinear error is at most h_m^2/8 max|G_mm| + h_s^2/8 max|G_ss| over the cell (s >= its lower node).
double table_error_bound(const TestRamp &r, double smax, int n_mean, int n_sigma, double s) {
    const double range = (r.x.back() - r.x.front()) + 8 * smax;
    const double hm = range / (n_mean - 1);
    const double y = std::sqrt(std::min(s, smax) / smax) * (n_sigma - 1);
    const int j0 = std::min(int(y), n_sigma - 2);
    const double s_lo = smax * std::pow(double(j0) / (n_sigma - 1), 2),
                 s_hi = smax * std::pow(double(j0 + 1) / (n_sigma - 1), 2);
    const double K = r.kink_mass();
    if (!(s_lo > 0)) return 1.0;  // first cell: not bounded this way
    return K * (hm * hm / 8 * 0.399 / s_lo + std::pow(s_hi - s_lo, 2) / 8 * 0.108 / s_lo) + 1e-5;
}

/// 64 x 64 iid N(0.5, 0.15^2) texels (fixed seed).
std::vector<float> gaussian_image(int w, int h, double mean, double sd, unsigned seed) {
    std::mt19937 gen(seed);
    std::normal_distribution<double> nd(mean, sd);
    std::vector<float> v(size_t(w) * h);
    for (float &x : v) x = float(nd(gen));
    return v;
}

json noise_texture(const TestRamp &r, const json &noise, const std::string &filter = "gaussian") {
    return {{"type", "colormap"}, {"colormap", r.to_json()}, {"noise", noise}, {"filter", filter}};
}

}  // namespace

// ---- image driver ----

// A footprint of exactly 2^l texels at the centre of a level-l texel reads that texel of both
// moment pyramids: f_bar and sigma_f must be the mean and (population) standard deviation of the
// 2^l x 2^l block of level-0 values (after scale/offset), computed directly.
TEST(ColormapTexture, ImageBlockStatisticsEqualDirectTexelStatistics) {
    const int N = 64;
    auto img = gaussian_image(N, N, 0.5, 0.15, 7);
    const std::string file = write_grey("block.exr", N, N, img);
    const double scale = 2.0, offset = -0.3;
    for (const char *fp : {"trilinear"}) {  // EWA weights texels with a Gaussian: not a box
        auto tex = make_texture({{"type", "colormap"},
                                 {"colormap", banded_ramp(0, 1, 5).to_json()},
                                 {"filename", file},
                                 {"scale", scale},
                                 {"offset", offset},
                                 {"output", "statistics"},
                                 {"footprint", fp}});
        for (int level : {1, 2, 3, 4}) {
            const int b = 1 << level;
            for (int by = 0; by < N / b; by += 3)
                for (int bx = 0; bx < N / b; bx += 2) {
                    double s = 0, s2 = 0;
                    for (int y = by * b; y < (by + 1) * b; ++y)
                        for (int x = bx * b; x < (bx + 1) * b; ++x) {
                            const double f = offset + scale * img[size_t(y) * N + x];
                            s += f, s2 += f * f;
                        }
                    const double mean = s / (b * b), sd = std::sqrt(std::max(0.0, s2 / (b * b) - mean * mean));
                    const double w = double(b) / N;  // footprint width: b texels
                    Spectrum st = tex->eval(at((bx + 0.5) * w, (by + 0.5) * w, w, 0, 0, w));
                    EXPECT_NEAR(st.r, mean, 2e-6) << "level " << level << " block " << bx << "," << by;
                    EXPECT_NEAR(st.g, sd, 1e-4 * (1 + sd) + 2e-6 / sd) << "level " << level;
                }
        }
    }
}

// At zero footprint all filters give C(f(point)) with f the level-0 bilinear value (the moment
// pyramid's interpolation variance is faded out in magnification); "gaussian" up to the table's
// sigma = 0 row, whose linear interpolation of a kinked C errs by at most kink_mass * h / 4.
TEST(ColormapTexture, ImageZeroFootprintIsPointColour) {
    const int N = 16;
    auto img = gaussian_image(N, N, 0.5, 0.15, 3);
    const std::string file = write_grey("zero.exr", N, N, img);
    const TestRamp r = banded_ramp(0.2, 0.8, 13);
    auto make = [&](const char *filter, const json &extra = json::object()) {
        json j = {{"type", "colormap"}, {"colormap", r.to_json()}, {"filename", file}, {"filter", filter}};
        j.update(extra);
        return make_texture(j);
    };
    auto none = make("none"), naive = make("naive"), gauss = make("gaussian"), exact = make("gaussian_exact");
    auto stats = make("gaussian", {{"output", "statistics"}});
    std::mt19937 gen(11);
    std::uniform_real_distribution<double> U(0, 1);
    for (int i = 0; i < 200; ++i) {
        const double u = U(gen), v = U(gen);
        const Spectrum st = stats->eval(at(u, v));
        ASSERT_EQ(st.g, 0.f);
        const auto c = r.eval(st.b);
        EXPECT_LT(max_abs_diff(rgb(none->eval(at(u, v))), c), 1e-5);
        EXPECT_LT(max_abs_diff(rgb(naive->eval(at(u, v))), c), 1e-5);
        EXPECT_LT(max_abs_diff(rgb(exact->eval(at(u, v))), c), 1e-5);
        // Default sigma_max for an image: <= half the range; h from the table's mean axis.
        double lo = 1e9, hi = -1e9;
        for (float x : img) lo = std::min(lo, double(x)), hi = std::max(hi, double(x));
        const double h = (r.x.back() - r.x.front() + 8 * 0.5 * (hi - lo)) / 511;
        EXPECT_LT(max_abs_diff(rgb(gauss->eval(at(u, v))), c), r.kink_mass() * h / 4 + 1e-5);
    }
}

// "gaussian" returns <C, N(f_bar, sigma_f^2)> for the statistics the texture itself reports,
// checked against trapezoid quadrature of the test's own copy of C; "gaussian_exact" to 1e-5,
// the table within its interpolation bound.
TEST(ColormapTexture, GaussianEqualsQuadratureOfReportedStatistics) {
    const int N = 64;
    auto img = gaussian_image(N, N, 0.5, 0.15, 5);
    const std::string file = write_grey("quad.exr", N, N, img);
    const TestRamp r = banded_ramp(0.2, 0.8, 13);
    const double smax = 0.3;
    json base = {{"type", "colormap"}, {"colormap", r.to_json()}, {"filename", file}, {"sigma_max", smax}};
    json jn = noise_texture(r, {{"mean", 0.5}, {"sigma", 0.15}, {"freq_min", 4}, {"freq_max", 256}, {"seed", 3}});
    jn["sigma_max"] = smax;
    for (const json &j0 : {base, jn}) {
        json js = j0, jg = j0, je = j0;
        js["output"] = "statistics";
        je["filter"] = "gaussian_exact";
        auto stats = make_texture(js), gauss = make_texture(jg), exact = make_texture(je);
        std::mt19937 gen(2);
        std::uniform_real_distribution<double> U(0, 1);
        int checked = 0;
        for (int i = 0; i < 300; ++i) {
            const double w = std::pow(2.0, -8 + 8 * U(gen));  // footprint 1/256 .. 1 uv
            const ShadingContext ctx = at(U(gen), U(gen), w, 0.3 * w * U(gen), 0.2 * w * U(gen), w * (0.3 + U(gen)));
            const Spectrum st = stats->eval(ctx);
            const auto q = r.gaussian_quadrature(st.r, st.g);
            EXPECT_LT(max_abs_diff(rgb(exact->eval(ctx)), q), 1e-5) << "f_bar " << st.r << " sigma " << st.g;
            const double bound = table_error_bound(r, smax, 512, 128, st.g);
            if (bound < 0.05 && st.g <= smax) {
                EXPECT_LT(max_abs_diff(rgb(gauss->eval(ctx)), q), bound) << "f_bar " << st.r << " sigma " << st.g;
                ++checked;
            }
        }
        EXPECT_GT(checked, 100);
    }
}

// For an image of iid Gaussian texels and a footprint covering a 16 x 16 block, the brute-force
// average of C(texel) over the block is what filtering should give. "gaussian" (the Gaussian fit of
// the block's 256 values) must be within a few standard errors of it (sd(C) / 16 per block, RMS
// over blocks), and far closer than "naive" C(block mean) with this strongly non-linear map.
TEST(ColormapTexture, ImageGaussianBeatsNaiveAgainstBruteForce) {
    const int N = 128, b = 16;
    auto img = gaussian_image(N, N, 0.5, 0.15, 9);
    const std::string file = write_grey("brute.exr", N, N, img);
    const TestRamp r = banded_ramp(0.2, 0.8, 13);  // bands 0.05 wide, sd of f 0.15
    json j = {{"type", "colormap"}, {"colormap", r.to_json()}, {"filename", file}};
    json jn = j;
    jn["filter"] = "naive";
    auto gauss = make_texture(j), naive = make_texture(jn);
    double eg = 0, en = 0, var_c = 0;
    int blocks = 0;
    for (int by = 0; by < N / b; ++by)
        for (int bx = 0; bx < N / b; ++bx) {
            std::array<double, 3> brute{0, 0, 0}, sq{0, 0, 0};
            for (int y = by * b; y < (by + 1) * b; ++y)
                for (int x = bx * b; x < (bx + 1) * b; ++x) {
                    const auto c = r.eval(img[size_t(y) * N + x]);
                    for (int k = 0; k < 3; ++k) brute[k] += c[k] / (b * b), sq[k] += c[k] * c[k] / (b * b);
                }
            const double w = double(b) / N;
            const ShadingContext ctx = at((bx + 0.5) * w, (by + 0.5) * w, w, 0, 0, w);
            const auto g = rgb(gauss->eval(ctx)), n = rgb(naive->eval(ctx));
            for (int k = 0; k < 3; ++k) {
                eg += std::pow(g[k] - brute[k], 2);
                en += std::pow(n[k] - brute[k], 2);
                var_c += sq[k] - brute[k] * brute[k];
            }
            ++blocks;
        }
    const double rms_g = std::sqrt(eg / (3 * blocks)), rms_n = std::sqrt(en / (3 * blocks));
    const double se = std::sqrt(var_c / (3 * blocks) / (b * b));  // standard error of one block's brute force
    RecordProperty("rms_gaussian", std::to_string(rms_g));
    RecordProperty("rms_naive", std::to_string(rms_n));
    EXPECT_LT(rms_g, 3 * se) << "naive " << rms_n << " se " << se;
    EXPECT_LT(rms_g, 0.25 * rms_n) << "se " << se;
}

TEST(ColormapTexture, ImageMeanIsAverageOfMappedTexels) {
    const int N = 32;
    auto img = gaussian_image(N, N, 0.5, 0.15, 1);
    const std::string file = write_grey("mean.exr", N, N, img);
    const TestRamp r = banded_ramp(0.2, 0.8, 7);
    auto tex = make_texture({{"type", "colormap"}, {"colormap", r.to_json()}, {"filename", file}});
    std::array<double, 3> m{0, 0, 0};
    for (float x : img) {
        const auto c = r.eval(x);
        for (int k = 0; k < 3; ++k) m[k] += c[k] / img.size();
    }
    EXPECT_LT(max_abs_diff(rgb(tex->mean()), m), 1e-5);
}

// ---- noise driver ----

// Window statistics of the noise against Monte-Carlo averages over the window N(x, J J^T / 4) (f
// from zero-footprint lookups), at 150 random points for three footprint sizes:
//  * f_bar is the exact window mean: within 4.5 standard errors at every point;
//  * "exact" sigma_f^2 is the instance's window variance (O(K^2) closed form): within 4.5 standard
//    errors of the Monte-Carlo variance at every point;
//  * "process" sigma_f^2 (the phase average, independent of x) equals the mean over points of the
//    exact window variance (within 4 standard errors of that mean);
//  * "local" has the same mean over points and follows the point-to-point changes: its squared
//    deviation from "exact" is below a quarter of the process one's while the window is smaller
//    than the dominant periods, and still below the process one's at the largest footprint.
TEST(ColormapTexture, NoiseWindowStatisticsMatchMonteCarlo) {
    const TestRamp r = banded_ramp(-1, 1, 9);
    auto make = [&](const char *variance) {
        return make_texture(
            {{"type", "colormap"},
             {"colormap", r.to_json()},
             {"noise",
              {{"mean", 0.25}, {"sigma", 0.8}, {"freq_min", 2}, {"freq_max", 64}, {"seed", 4}, {"variance", variance}}},
             {"output", "statistics"}});
    };
    auto local = make("local"), process = make("process"), exact = make("exact");
    std::mt19937 gen(17);
    std::uniform_real_distribution<double> U(0, 1);
    std::normal_distribution<double> Z(0, 1);
    for (double w : {0.02, 0.08, 0.25}) {
        const double J[2][2] = {{w, 0.4 * w}, {-0.3 * w, 0.7 * w}};  // columns (dudx, dvdx), (dudy, dvdy)
        const int P = 150, M = 600;
        double proc = 0, sum_x = 0, sum_x2 = 0, sum_d = 0, sum_d2 = 0, e_local = 0, e_process = 0;
        std::vector<double> f(M);
        for (int p = 0; p < P; ++p) {
            const double u = U(gen), v = U(gen);
            const ShadingContext ctx = at(u, v, J[0][0], J[0][1], J[1][0], J[1][1]);
            const Spectrum sp = process->eval(ctx), sl = local->eval(ctx), se = exact->eval(ctx);
            ASSERT_EQ(sp.r, sl.r);
            ASSERT_EQ(sp.r, se.r);
            proc = double(sp.g) * sp.g;
            const double loc = double(sl.g) * sl.g, ex = double(se.g) * se.g;
            double s = 0;
            for (int m = 0; m < M; ++m) {
                const double z1 = Z(gen), z2 = Z(gen);
                const double du = 0.5 * (J[0][0] * z1 + J[0][1] * z2), dv = 0.5 * (J[1][0] * z1 + J[1][1] * z2);
                f[m] = local->eval(at(u + du, v + dv)).b;
                s += f[m];
            }
            const double mc_mean = s / M;
            double q = 0, q2 = 0;  // squared deviations: their mean is the variance, their sd its error
            for (double x : f) q += std::pow(x - mc_mean, 2), q2 += std::pow(x - mc_mean, 4);
            const double mc_var = q / (M - 1), se_var = std::sqrt(std::max(0.0, q2 / M - std::pow(q / M, 2)) / M);
            EXPECT_NEAR(sp.r, mc_mean, 4.5 * std::sqrt(mc_var / M) + 1e-6) << "w " << w << " at " << u << "," << v;
            EXPECT_NEAR(ex, mc_var, 4.5 * se_var + 1e-6) << "w " << w << " at " << u << "," << v;
            sum_x += ex, sum_x2 += ex * ex;
            sum_d += loc - ex, sum_d2 += std::pow(loc - ex, 2);
            e_local += std::pow(loc - ex, 2), e_process += std::pow(proc - ex, 2);
        }
        const double mean_x = sum_x / P, sd_x = std::sqrt(std::max(0.0, sum_x2 / P - mean_x * mean_x));
        EXPECT_NEAR(proc, mean_x, 4 * sd_x / std::sqrt(P) + 1e-6) << "w " << w;
        const double mean_d = sum_d / P, sd_d = std::sqrt(std::max(0.0, sum_d2 / P - mean_d * mean_d));
        EXPECT_NEAR(mean_d, 0.0, 4 * sd_d / std::sqrt(P) + 1e-6) << "w " << w;
        EXPECT_LT(e_local, (w < 0.1 ? 0.25 : 1.0) * e_process)
            << "w " << w << ": rms local " << std::sqrt(e_local / P) << ", process " << std::sqrt(e_process / P);
        RecordProperty("rms_local_w" + std::to_string(w), std::to_string(std::sqrt(e_local / P)));
        RecordProperty("rms_process_w" + std::to_string(w), std::to_string(std::sqrt(e_process / P)));
        EXPECT_GT(proc, 0.02 * 0.64) << "w " << w;  // the footprint holds some variance
        EXPECT_LT(proc, 0.98 * 0.64) << "w " << w;  // ... and not all of it
    }
}

// "window": "box" is the Gaussian with the covariance J J^T / 12 of the footprint parallelogram
// J [-1/2, 1/2]^2: f_bar and the "exact" variance against Monte-Carlo over N(x, J J^T / 12).
TEST(ColormapTexture, NoiseBoxWindowHasTheParallelogramsCovariance) {
    const TestRamp r = banded_ramp(-1, 1, 9);
    auto stats = make_texture({{"type", "colormap"},
                               {"colormap", r.to_json()},
                               {"noise",
                                {{"sigma", 1},
                                 {"freq_min", 2},
                                 {"freq_max", 32},
                                 {"seed", 5},
                                 {"window", "box"},
                                 {"variance", "exact"},
                                 {"components", 32}}},
                               {"output", "statistics"}});
    std::mt19937 gen(43);
    std::uniform_real_distribution<double> U(0, 1);
    std::normal_distribution<double> Z(0, 1);
    const double w = 0.1, J[2][2] = {{w, 0.3 * w}, {0.2 * w, 0.8 * w}}, k = 1.0 / std::sqrt(12.0);
    for (int p = 0; p < 30; ++p) {
        const double u = U(gen), v = U(gen);
        const Spectrum st = stats->eval(at(u, v, J[0][0], J[0][1], J[1][0], J[1][1]));
        const int M = 2000;
        std::vector<double> f(M);
        double s = 0;
        for (int m = 0; m < M; ++m) {
            const double z1 = Z(gen), z2 = Z(gen);
            f[m] = stats->eval(at(u + k * (J[0][0] * z1 + J[0][1] * z2), v + k * (J[1][0] * z1 + J[1][1] * z2))).b;
            s += f[m];
        }
        const double mean = s / M;
        double q = 0, q2 = 0;
        for (double x : f) q += std::pow(x - mean, 2), q2 += std::pow(x - mean, 4);
        const double var = q / (M - 1), se_var = std::sqrt(std::max(0.0, q2 / M - std::pow(q / M, 2)) / M);
        EXPECT_NEAR(st.r, mean, 4.5 * std::sqrt(var / M) + 1e-6);
        EXPECT_NEAR(double(st.g) * st.g, var, 4.5 * se_var + 1e-6);
    }
}

// Small footprints (a hundredth of the shortest period): f is linear over the window, so its
// values there are Gaussian with variance grad f^T S grad f, which "local" must give at every point
// (within 4 standard errors of the Monte-Carlo variance, sqrt(2 / (M - 1)) relative).
TEST(ColormapTexture, NoiseLocalVarianceIsLinearisedAtSmallFootprints) {
    const TestRamp r = banded_ramp(-1, 1, 9);
    auto stats = make_texture({{"type", "colormap"},
                               {"colormap", r.to_json()},
                               {"noise", {{"sigma", 1}, {"freq_min", 2}, {"freq_max", 32}, {"seed", 9}}},
                               {"output", "statistics"}});
    std::mt19937 gen(41);
    std::uniform_real_distribution<double> U(0, 1);
    std::normal_distribution<double> Z(0, 1);
    const double w = 1.0 / 32 / 100;
    for (int p = 0; p < 40; ++p) {
        const double u = U(gen), v = U(gen);
        const double J[2][2] = {{w, 0.5 * w * U(gen)}, {0.5 * w * U(gen), w}};
        const Spectrum st = stats->eval(at(u, v, J[0][0], J[0][1], J[1][0], J[1][1]));
        const int M = 2000;
        double s = 0, s2 = 0;
        for (int m = 0; m < M; ++m) {
            const double z1 = Z(gen), z2 = Z(gen);
            const double f =
                stats->eval(at(u + 0.5 * (J[0][0] * z1 + J[0][1] * z2), v + 0.5 * (J[1][0] * z1 + J[1][1] * z2))).b;
            s += f - st.r, s2 += double(f - st.r) * (f - st.r);  // centred: f varies by ~1e-2 around f_bar
        }
        const double mc_var = (s2 - s * s / M) / (M - 1);
        EXPECT_NEAR(double(st.g) * st.g, mc_var, 4 * mc_var * std::sqrt(2.0 / (M - 1)) + 1e-9)
            << "at " << u << "," << v;
    }
}

// Zero footprint: f_bar = f(point), sigma_f = 0. Huge footprint: f_bar -> mean, sigma_f -> sigma.
// The process variance is sigma^2: the spatial variance of f over a wide grid matches it (the
// cross terms of different frequencies average out over 100 x 100 uv, to well under 2%).
TEST(ColormapTexture, NoiseLimits) {
    const TestRamp r = banded_ramp(-1, 1, 9);
    const double mean = -0.4, sigma = 0.7;
    json noise = {{"mean", mean}, {"sigma", sigma}, {"freq_min", 1}, {"freq_max", 50}, {"beta", 0.5}, {"seed", 12}};
    auto stats =
        make_texture({{"type", "colormap"}, {"colormap", r.to_json()}, {"noise", noise}, {"output", "statistics"}});
    std::mt19937 gen(5);
    std::uniform_real_distribution<double> U(-50, 50);
    double s = 0, s2 = 0;
    const int n = 40000;
    for (int i = 0; i < n; ++i) {
        const ShadingContext ctx = at(U(gen), U(gen));
        const Spectrum st = stats->eval(ctx);
        EXPECT_EQ(st.g, 0.f);
        EXPECT_NEAR(st.r, st.b, 1e-6);
        s += st.b, s2 += double(st.b) * st.b;
    }
    const double m = s / n, var = s2 / n - m * m;
    EXPECT_NEAR(m, mean, 0.05 * sigma);
    EXPECT_NEAR(var, sigma * sigma, 0.05 * sigma * sigma);
    for (double w : {10.0, 1e3, 1e20}) {
        const Spectrum st = stats->eval(at(0.3, 0.7, w, 0, 0, w));
        EXPECT_NEAR(st.r, mean, 1e-6 * (1 + w));
        EXPECT_NEAR(st.g, sigma, 1e-6);
    }
    // Deterministic per seed; another seed is another instance.
    auto again =
        make_texture({{"type", "colormap"}, {"colormap", r.to_json()}, {"noise", noise}, {"output", "statistics"}});
    json noise2 = noise;
    noise2["seed"] = 13;
    auto other =
        make_texture({{"type", "colormap"}, {"colormap", r.to_json()}, {"noise", noise2}, {"output", "statistics"}});
    EXPECT_EQ(stats->eval(at(0.1, 0.2)).b, again->eval(at(0.1, 0.2)).b);
    EXPECT_NE(stats->eval(at(0.1, 0.2)).b, other->eval(at(0.1, 0.2)).b);
}

// Zero footprint: "none", "naive" and "gaussian_exact" give C(f(point)); "gaussian" within the
// sigma = 0 row's interpolation error kink_mass * h / 4.
TEST(ColormapTexture, NoiseZeroFootprintIsPointColour) {
    const TestRamp r = banded_ramp(-1, 1, 9);
    json noise = {{"sigma", 0.6}, {"freq_min", 1}, {"freq_max", 30}, {"seed", 2}};
    auto stats =
        make_texture({{"type", "colormap"}, {"colormap", r.to_json()}, {"noise", noise}, {"output", "statistics"}});
    std::shared_ptr<Texture> tex[4];
    const char *filters[] = {"none", "naive", "gaussian_exact", "gaussian"};
    for (int i = 0; i < 4; ++i) tex[i] = make_texture(noise_texture(r, noise, filters[i]));
    const double h = (r.x.back() - r.x.front() + 8 * 0.6) / 511;
    std::mt19937 gen(8);
    std::uniform_real_distribution<double> U(0, 1);
    for (int i = 0; i < 300; ++i) {
        const ShadingContext ctx = at(U(gen), U(gen));
        const auto c = r.eval(stats->eval(ctx).b);
        for (int f = 0; f < 3; ++f) EXPECT_LT(max_abs_diff(rgb(tex[f]->eval(ctx)), c), 2e-6) << filters[f];
        EXPECT_LT(max_abs_diff(rgb(tex[3]->eval(ctx)), c), r.kink_mass() * h / 4 + 1e-5);
    }
}

// The filtered colour against the brute-force Gaussian-window average of C(f(x)) (M samples,
// within 4 standard errors plus the table bound) for a footprint spanning many periods of the
// lowest frequency, where the window's distribution of f is the process's Gaussian; "naive" (the
// colour of the mean) is far off there. K = 256 equal-amplitude components (beta = 0) keep the
// marginal close to Gaussian (excess kurtosis -1.5/K).
TEST(ColormapTexture, NoiseFilteredColourMatchesBruteForceWindowAverage) {
    const TestRamp r = banded_ramp(-1.2, 1.2, 13);
    json noise = {{"mean", 0.1}, {"sigma", 0.5},      {"freq_min", 8}, {"freq_max", 64},
                  {"beta", 0},   {"components", 256}, {"seed", 21}};
    auto gauss = make_texture(noise_texture(r, noise, "gaussian"));
    auto naive = make_texture(noise_texture(r, noise, "naive"));
    auto none = make_texture(noise_texture(r, noise, "none"));
    std::mt19937 gen(23);
    std::uniform_real_distribution<double> U(0, 1);
    std::normal_distribution<double> Z(0, 1);
    const double w = 3.0;  // window sd 1.5 uv = 12 periods of freq_min along each axis
    double worst_naive = 0;
    for (int p = 0; p < 6; ++p) {
        const double u = U(gen), v = U(gen);
        const int M = 40000;
        std::array<double, 3> s{0, 0, 0}, s2{0, 0, 0};
        for (int m = 0; m < M; ++m) {
            const auto c = rgb(none->eval(at(u + 0.5 * w * Z(gen), v + 0.5 * w * Z(gen))));
            for (int k = 0; k < 3; ++k) s[k] += c[k], s2[k] += c[k] * c[k];
        }
        const auto g = rgb(gauss->eval(at(u, v, w, 0, 0, w))), n = rgb(naive->eval(at(u, v, w, 0, 0, w)));
        for (int k = 0; k < 3; ++k) {
            const double mean = s[k] / M, se = std::sqrt((s2[k] / M - mean * mean) / M);
            EXPECT_NEAR(g[k], mean, 4 * se + table_error_bound(r, 0.5, 512, 128, 0.5)) << "channel " << k;
            worst_naive = std::max(worst_naive, std::abs(n[k] - mean));
        }
    }
    EXPECT_GT(worst_naive, 0.1);
}

// Medium footprints (a few periods): the instance's window distribution is only approximately the
// process Gaussian; "gaussian" must still be several times closer than "naive" to the brute force.
TEST(ColormapTexture, NoiseGaussianBeatsNaiveAtMediumFootprints) {
    const TestRamp r = banded_ramp(-1.2, 1.2, 13);
    json noise = {{"sigma", 0.5}, {"freq_min", 4}, {"freq_max", 128}, {"seed", 31}};
    auto gauss = make_texture(noise_texture(r, noise, "gaussian"));
    auto naive = make_texture(noise_texture(r, noise, "naive"));
    auto none = make_texture(noise_texture(r, noise, "none"));
    std::mt19937 gen(29);
    std::uniform_real_distribution<double> U(0, 1);
    std::normal_distribution<double> Z(0, 1);
    for (double w : {0.03, 0.1, 0.3}) {
        double eg = 0, en = 0;
        for (int p = 0; p < 40; ++p) {
            const double u = U(gen), v = U(gen);
            const int M = 4000;
            std::array<double, 3> s{0, 0, 0};
            for (int m = 0; m < M; ++m) {
                const auto c = rgb(none->eval(at(u + 0.5 * w * Z(gen), v + 0.5 * w * Z(gen))));
                for (int k = 0; k < 3; ++k) s[k] += c[k] / M;
            }
            const auto g = rgb(gauss->eval(at(u, v, w, 0, 0, w))), n = rgb(naive->eval(at(u, v, w, 0, 0, w)));
            for (int k = 0; k < 3; ++k) eg += std::pow(g[k] - s[k], 2), en += std::pow(n[k] - s[k], 2);
        }
        EXPECT_LT(eg, 0.25 * en) << "footprint " << w << ": rms gaussian " << std::sqrt(eg / 120) << " naive "
                                 << std::sqrt(en / 120);
    }
}

// ---- robustness and errors ----

TEST(ColormapTexture, ExtremeInputsGiveFiniteColoursInsideTheMapsRange) {
    const int N = 8;
    const std::string file = write_grey("extreme.exr", N, N, gaussian_image(N, N, 0.5, 0.3, 4));
    const TestRamp r = banded_ramp(0, 1, 7);
    std::vector<json> textures;
    for (const char *f : {"gaussian", "gaussian_exact", "naive", "none"}) {
        textures.push_back(noise_texture(r, {{"sigma", 1}, {"freq_max", 1e6}}, f));
        textures.push_back(
            noise_texture(r, {{"sigma", 1}, {"freq_max", 1e6}, {"variance", "exact"}, {"components", 16}}, f));
        textures.push_back(noise_texture(r, {{"sigma", 1}, {"freq_max", 1e6}, {"variance", "process"}}, f));
        textures.push_back({{"type", "colormap"}, {"colormap", r.to_json()}, {"filename", file}, {"filter", f}});
        textures.push_back(
            {{"type", "colormap"}, {"colormap", r.to_json()}, {"filename", file}, {"filter", f}, {"footprint", "ewa"}});
    }
    // sigma far beyond sigma_max (clamped in the table).
    textures.push_back(
        {{"type", "colormap"}, {"colormap", r.to_json()}, {"noise", {{"sigma", 50}}}, {"sigma_max", 1e-3}});
    textures.push_back({{"type", "colormap"}, {"colormap", r.to_json()}, {"noise", {{"sigma", 0}}}});
    const float inf = std::numeric_limits<float>::infinity(), nan = std::numeric_limits<float>::quiet_NaN();
    const std::vector<ShadingContext> ctxs = {at(0.5, 0.5, 1e30, 1e30, -1e30, 1e30),
                                              at(0.5, 0.5, inf, 0, 0, -inf),
                                              at(0.5, 0.5, nan, nan, nan, nan),
                                              at(nan, inf, 0.1, 0, 0, 0.1),
                                              at(1e7, -1e7, 1e-30, 0, 0, 1e-30),
                                              at(0.2, 0.3, 1e3, 1e-3, 0, 0),
                                              at(-inf, 0.5, 0, 0, 0, 0)};
    for (const json &j : textures) {
        auto tex = make_texture(j);
        for (const ShadingContext &c : ctxs) {
            const Spectrum s = tex->eval(c);
            ASSERT_TRUE(s.is_finite()) << j.dump() << " at " << c.uv.x << "," << c.uv.y << " d " << c.dudx;
            for (int k = 0; k < 3; ++k) {
                EXPECT_GE(s[k], 0.05f - 1e-4f) << j.dump();
                EXPECT_LE(s[k], 0.95f + 1e-4f) << j.dump();
            }
        }
        EXPECT_TRUE(tex->mean().is_finite());
        EXPECT_NE(tex->to_string().find("colormap"), std::string::npos);
    }
}

TEST(ColormapTexture, BadInputErrorsNameTheKey) {
    const json ramp = banded_ramp(0, 1, 3).to_json();
    auto noise = [&](const json &n) { return json{{"type", "colormap"}, {"colormap", ramp}, {"noise", n}}; };
    struct Case {
        json j;
        std::string expect;
    };
    const std::vector<Case> cases = {
        {{{"type", "colormap"}, {"colormap", ramp}},
         "scene.json: textures.tex: expected exactly one driver: 'filename' (a grey image) or 'noise'"},
        {{{"type", "colormap"}, {"colormap", ramp}, {"noise", json::object()}, {"filename", "x.exr"}},
         "textures.tex.noise: expected exactly one driver, 'filename' (a grey image) or 'noise', got both"},
        {{{"type", "colormap"}, {"colormap", ramp}, {"noise", json::object()}, {"filter", "box"}},
         "textures.tex.filter: expected \"gaussian\", \"gaussian_exact\", \"naive\" or \"none\", got \"box\""},
        {{{"type", "colormap"}, {"colormap", ramp}, {"noise", json::object()}, {"output", "rgb"}},
         "textures.tex.output: expected"},
        {noise({{"sigma", -1}}), "textures.tex.noise.sigma: expected a number >= 0, got -1"},
        {noise({{"freq_min", 0}}), "textures.tex.noise.freq_min: expected a number in (0, 1e12]"},
        {noise({{"freq_min", 4}, {"freq_max", 2}}),
         "textures.tex.noise.freq_max: expected a number in [freq_min, 1e12]"},
        {noise({{"components", 0}}), "textures.tex.noise.components: expected an integer in [1, 4096], got 0"},
        {noise({{"seed", -3}}), "textures.tex.noise.seed: expected an integer >= 0"},
        {noise({{"beta", 100}}), "textures.tex.noise.beta: expected a number in [-8, 8]"},
        {noise({{"window", "pixel"}}), "textures.tex.noise.window: expected \"mipmap\" or \"box\", got \"pixel\""},
        {noise({{"variance", "full"}}),
         "textures.tex.noise.variance: expected \"local\", \"process\" or \"exact\", got \"full\""},
        {noise({{"sigmaa", 1}}), "sigmaa"},
        {noise(3), "textures.tex.noise"},
        {{{"type", "colormap"}, {"colormap", ramp}, {"noise", json::object()}, {"wrap_mode", "clamp"}},
         "textures.tex.wrap_mode: applies to the image driver ('filename') only"},
        {{{"type", "colormap"}, {"colormap", ramp}, {"noise", json::object()}, {"table_size", {1, 8}}},
         "textures.tex.table_size: expected"},
        {{{"type", "colormap"}, {"colormap", ramp}, {"noise", json::object()}, {"sigma_max", 0}},
         "textures.tex.sigma_max: expected a number > 0"},
        {{{"type", "colormap"}, {"colormap", json::array()}, {"noise", json::object()}}, "textures.tex.colormap"},
        {{{"type", "colormap"}, {"noise", json::object()}}, "colormap"},
        {{{"type", "colormap"}, {"colormap", ramp}, {"filename", "missing.exr"}}, "textures.tex.filename"},
        {{{"type", "colormap"}, {"colormap", ramp}, {"filename", "missing.exr"}, {"footprint", "box"}}, "filename"},
        {{{"type", "colormap"}, {"colormap", ramp}, {"noise", json::object()}, {"unknown_key", 1}}, "unknown_key"},
    };
    for (const Case &c : cases) {
        const std::string e = texture_error(c.j);
        EXPECT_NE(e.find(c.expect), std::string::npos) << c.j.dump() << "\n  got: " << e;
    }
    // The image's own key errors once the file exists.
    const std::string file = write_grey("err.exr", 4, 4, std::vector<float>(16, 0.5f));
    EXPECT_NE(texture_error({{"type", "colormap"}, {"colormap", ramp}, {"filename", file}, {"footprint", "box"}})
                  .find("textures.tex.footprint: expected \"trilinear\" or \"ewa\", got \"box\""),
              std::string::npos);
    EXPECT_NE(texture_error({{"type", "colormap"}, {"colormap", ramp}, {"filename", file}, {"tiling", {0, 1}}})
                  .find("textures.tex.tiling"),
              std::string::npos);
}

// Cost of one eval (printed; recorded as test properties, nothing asserted beyond finiteness).
TEST(ColormapTexture, EvalCost) {
    const TestRamp r = banded_ramp(-1, 1, 9);
    const int N = 256;
    const std::string file = write_grey("cost.exr", N, N, gaussian_image(N, N, 0.0, 0.5, 6));
    for (const char *f : {"gaussian", "naive", "none"}) {
        for (int drv = 0; drv < 2; ++drv) {
            json j = drv == 0
                         ? noise_texture(r, {{"sigma", 0.5}, {"freq_max", 256}}, f)
                         : json{{"type", "colormap"}, {"colormap", r.to_json()}, {"filename", file}, {"filter", f}};
            auto tex = make_texture(j);
            std::mt19937 gen(1);
            std::uniform_real_distribution<double> U(0, 1);
            const int n = 200000;
            std::vector<ShadingContext> ctx;
            for (int i = 0; i < 1024; ++i)
                ctx.push_back(at(U(gen), U(gen), 0.01 * U(gen), 0.001, 0.002, 0.01 * U(gen)));
            Spectrum acc(0.f);
            auto t0 = std::chrono::steady_clock::now();
            for (int i = 0; i < n; ++i) acc += tex->eval(ctx[i & 1023]);
            const double ns =
                std::chrono::duration<double, std::nano>(std::chrono::steady_clock::now() - t0).count() / n;
            EXPECT_TRUE(acc.is_finite());
            std::printf("[ cost     ] colormap %s %s: %.0f ns/eval\n", drv == 0 ? "noise(64)" : "image", f, ns);
        }
    }
}
