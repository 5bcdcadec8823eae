#include "bsdf/chi2.h"
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fmt/format.h>
#include <fstream>
#include <nlohmann/json.hpp>
#include "bsdf/material.h"
#include "sampling/rng.h"

namespace meso {

// ---------------------------------------------------------------- incomplete gamma

static double gamma_series(double a, double x) {
    // P(a, x) = e^{-x} x^a / Γ(a) Σ x^n / (a (a+1) ... (a+n))   (NR 6.2.5)
    double ap = a, sum = 1.0 / a, del = sum;
    for (int n = 0; n < 10000; ++n) {
        ap += 1.0;
        del *= x / ap;
        sum += del;
        if (std::abs(del) < std::abs(sum) * 1e-16) break;
    }
    return sum * std::exp(-x + a * std::log(x) - std::lgamma(a));
}

static double gamma_cont_frac(double a, double x) {
    // Q(a, x) by the continued fraction (NR 6.2.7), modified Lentz.
    const double tiny = 1e-300;
    double b = x + 1.0 - a, c = 1.0 / tiny, d = 1.0 / b, h = d;
    for (int i = 1; i < 10000; ++i) {
        double an = -i * (i - a);
        b += 2.0;
        d = an * d + b;
        if (std::abs(d) < tiny) d = tiny;
        c = b + an / c;
        if (std::abs(c) < tiny) c = tiny;
        d = 1.0 / d;
        double del = d * c;
        h *= del;
        if (std::abs(del - 1.0) < 1e-16) break;
    }
    return std::exp(-x + a * std::log(x) - std::lgamma(a)) * h;
}

double gamma_p(double a, double x) {
    if (!(a > 0.0) || x <= 0.0) return 0.0;
    if (std::isinf(x)) return 1.0;
    return x < a + 1.0 ? gamma_series(a, x) : 1.0 - gamma_cont_frac(a, x);
}
double gamma_q(double a, double x) {
    if (!(a > 0.0) || x <= 0.0) return 1.0;
    if (std::isinf(x)) return 0.0;
    return x < a + 1.0 ? 1.0 - gamma_series(a, x) : gamma_cont_frac(a, x);
}
double chi2_p_value(double x, int dof) { return dof < 1 ? 1.0 : gamma_q(0.5 * dof, 0.5 * x); }
double sidak_alpha(double alpha, int tests) { return 1.0 - std::pow(1.0 - alpha, 1.0 / std::max(tests, 1)); }

// ---------------------------------------------------------------- grid & integration

namespace {

constexpr double kTwoPi = 6.28318530717958647692;

struct Grid {
    int n_phi, n_z;
    double z_min;
    double dz() const { return (1.0 - z_min) / n_z; }
    int cells() const { return n_phi * n_z; }
    /// Cell of direction w, or -1 when outside the domain.
    int cell(const Vec3 &w) const {
        double z = w.z;
        if (z < z_min) return -1;
        int iz = std::min(n_z - 1, std::max(0, int((z - z_min) / dz())));
        double phi = std::atan2(double(w.y), double(w.x));
        if (phi < 0.0) phi += kTwoPi;
        int ip = std::min(n_phi - 1, std::max(0, int(phi / kTwoPi * n_phi)));
        return iz * n_phi + ip;
    }
};

Grid make_grid(int res, bool sphere) {
    res = std::max(res, 1);
    return Grid{2 * res, sphere ? 2 * res : res, sphere ? -1.0 : 0.0};
}

/// Integrand pdf(wo, ω(θ, φ)) sin θ.
struct PdfIntegrand {
    const Material &mat;
    const ShadingContext &ctx;
    Vec3 wo;
    double operator()(double th, double ph) const {
        double st = std::sin(th), ct = std::cos(th);
        Vec3 wi(float(st * std::cos(ph)), float(st * std::sin(ph)), float(ct));
        double p = mat.pdf(ctx, wo, wi);
        return std::isfinite(p) && p > 0.0 ? p * st : 0.0;
    }
};

/// 3x3-node Simpson rule on a rectangle of area `area`; g is row-major [θ][φ].
inline double simpson3(const double *g, double area) {
    return area / 36.0 * (g[0] + g[2] + g[6] + g[8] + 4.0 * (g[1] + g[3] + g[5] + g[7]) + 16.0 * g[4]);
}

/// Adaptive 2D Simpson with Richardson extrapolation: compares the rule on the rectangle
/// with the rule on its four quarters and recurses where they disagree by more than the
/// (absolute) tolerance. `min_depth` forces refinement (to find lobes narrower than the
/// node spacing); `max_depth` bounds the cost along discontinuities.
double adaptive_rect(const PdfIntegrand &f, double t0, double t1, double p0, double p1, const double *g, double tol,
                     int depth, int min_depth, int max_depth) {
    double area = (t1 - t0) * (p1 - p0);
    double coarse = simpson3(g, area);
    double G[25];
    for (int a = 0; a < 5; ++a)
        for (int b = 0; b < 5; ++b) {
            if (a % 2 == 0 && b % 2 == 0) G[a * 5 + b] = g[(a / 2) * 3 + b / 2];
            else G[a * 5 + b] = f(t0 + (t1 - t0) * a / 4.0, p0 + (p1 - p0) * b / 4.0);
        }
    double child[4][9], fine = 0.0;
    for (int c = 0; c < 4; ++c) {
        int a0 = (c / 2) * 2, b0 = (c % 2) * 2;
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) child[c][i * 3 + j] = G[(a0 + i) * 5 + b0 + j];
        fine += simpson3(child[c], area / 4.0);
    }
    if ((depth >= min_depth && std::abs(fine - coarse) <= 15.0 * tol) || depth >= max_depth)
        return fine + (fine - coarse) / 15.0;
    double tm = 0.5 * (t0 + t1), pm = 0.5 * (p0 + p1), sum = 0.0;
    for (int c = 0; c < 4; ++c) {
        double ta = c / 2 ? tm : t0, tb = c / 2 ? t1 : tm, pa = c % 2 ? pm : p0, pb = c % 2 ? p1 : pm;
        sum += adaptive_rect(f, ta, tb, pa, pb, child[c], tol / 4.0, depth + 1, min_depth, max_depth);
    }
    return sum;
}

/// ∫ pdf over every cell, in (θ, φ) with dω = sin θ dθ dφ (θ rather than cos θ so that the
/// pole is resolved). First a composite Simpson rule with `sub` intervals per axis and cell
/// on a shared node grid; a cell is accepted when that agrees with the rule on every
/// second node to within its tolerance. Otherwise — or when the sampler put far more
/// (or fewer) samples in the cell than the estimate predicts, a sign of a lobe narrower
/// than the node spacing (grazing-angle lobes are squeezed by ~cos θo) — the cell is
/// integrated adaptively, rectangle by rectangle. The histogram only decides where to
/// work harder; the value is always the integral of pdf(). Tolerance per cell, in counts:
/// max(0.05, 0.02 sqrt(E)): an error δ adds about δ²/E ≤ 4e-4 to a cell's χ² term (whose
/// noise is ~1), so quadrature can never decide the test.
std::vector<double> integrate_cells(const Material &mat, const ShadingContext &ctx, const Vec3 &wo, const Grid &g,
                                    int sub, double samples, const std::vector<double> *observed) {
    sub = std::max(4, (sub + 3) / 4 * 4);  // multiple of 4: the half-resolution rule is Simpson too
    PdfIntegrand f{mat, ctx, wo};
    std::vector<double> out(g.cells(), 0.0);
    const int nj = g.n_phi * sub + 1;
    std::vector<double> row((sub + 1) * size_t(nj));
    auto weights = [](int n, int step) {
        std::vector<double> w(n + 1, 0.0);
        int m = n / step;
        for (int k = 0; k <= m; ++k) w[k * step] = (k == 0 || k == m) ? 1.0 : (k % 2 ? 4.0 : 2.0);
        return w;
    };
    std::vector<double> w1 = weights(sub, 1), w2 = weights(sub, 2);
    double hphi = kTwoPi / (g.n_phi * sub);
    for (int iz = 0; iz < g.n_z; ++iz) {
        double z0 = g.z_min + iz * g.dz(), z1 = g.z_min + (iz + 1) * g.dz();
        double th_top = std::acos(std::min(1.0, z1)), th_bot = std::acos(std::max(-1.0, z0));
        double hth = (th_bot - th_top) / sub;
        for (int k = 0; k <= sub; ++k)
            for (int j = 0; j < nj; ++j) row[k * size_t(nj) + j] = f(th_top + k * hth, j * hphi);
        for (int ip = 0; ip < g.n_phi; ++ip) {
            double fine = 0.0, coarse = 0.0;
            for (int k = 0; k <= sub; ++k)
                for (int jj = 0; jj <= sub; ++jj) {
                    double v = row[k * size_t(nj) + ip * sub + jj];
                    fine += w1[k] * w1[jj] * v;
                    coarse += w2[k] * w2[jj] * v;
                }
            fine *= (hth / 3.0) * (hphi / 3.0);
            coarse *= (2.0 * hth / 3.0) * (2.0 * hphi / 3.0);
            int cell = iz * g.n_phi + ip;
            double E = samples * std::abs(fine);
            double tol = std::max(0.02, 2e-3 * std::sqrt(E)) / samples;
            double O = observed ? (*observed)[cell] : E;
            bool suspicious = std::abs(O - E) > 4.0 * std::sqrt(E) + 4.0;
            if (!suspicious && std::abs(fine - coarse) <= 15.0 * tol) {
                out[cell] = fine;
                continue;
            }
            // Adaptive pass over the (sub/2)^2 rectangles of the cell.
            int nr = sub / 2;
            double rect_tol = tol / (double(nr) * nr), sum = 0.0;
            for (int a = 0; a < nr; ++a)
                for (int b = 0; b < nr; ++b) {
                    double gg[9];
                    for (int i = 0; i < 3; ++i)
                        for (int j = 0; j < 3; ++j) gg[i * 3 + j] = row[(2 * a + i) * size_t(nj) + ip * sub + 2 * b + j];
                    double t0 = th_top + 2 * a * hth, p0 = (ip * sub + 2 * b) * hphi;
                    sum += adaptive_rect(f, t0, t0 + 2 * hth, p0, p0 + 2 * hphi, gg, rect_tol, 0, suspicious ? 3 : 0, 6);
                }
            out[cell] = sum;
        }
    }
    return out;
}

double rel_err(double a, double b) {
    double m = std::max(std::abs(a), std::abs(b));
    if (m < 1e-30) return 0.0;
    return std::abs(a - b) / m;
}

}  // namespace

double integrate_pdf(const Material &material, const ShadingContext &ctx, const Vec3 &wo, bool hemisphere, int res,
                     int sub) {
    Grid g = make_grid(res, !hemisphere);
    double s = 0.0;
    for (double v : integrate_cells(material, ctx, wo, g, sub, 1e7, nullptr)) s += v;
    return s;
}

// ---------------------------------------------------------------- the test

namespace {

/// A finite, non-negative weight, a positive finite pdf and a unit direction.
bool sample_is_valid(const BSDFSample &bs) {
    return !(!bs.weight.is_finite() || bs.weight.r < 0.f || bs.weight.g < 0.f || bs.weight.b < 0.f ||
             !std::isfinite(bs.pdf) || !(bs.pdf > 0.f) || !is_finite(bs.wi) || std::abs(length(bs.wi) - 1.f) > 1e-3f);
}

/// Compares a sample with the material's own eval and pdf at its direction: the sample's
/// pdf must be pdf(wi) and its weight eval(wi) / pdf(wi).
void check_against_eval(const Material &mat, const ShadingContext &ctx, const Vec3 &wo, const BSDFSample &bs,
                        const Chi2Options &opt, Chi2Result &r) {
    Spectrum ev = mat.eval(ctx, wo, bs.wi);
    double pd = mat.pdf(ctx, wo, bs.wi);
    double pe = rel_err(pd, bs.pdf);
    r.max_pdf_rel_error = std::max(r.max_pdf_rel_error, pe);
    if (pe > opt.rel_tolerance) r.pdf_mismatch++;
    double we = 0.0;
    for (int ch = 0; ch < 3; ++ch) we = std::max(we, rel_err(double(bs.weight[ch]) * pd, ev[ch]));
    r.max_weight_rel_error = std::max(r.max_weight_rel_error, we);
    if (we > opt.rel_tolerance) r.weight_mismatch++;
}

/// Step 1: the histogram of opt.samples sampled directions over the grid; every sample
/// counted by kind (failed, invalid, delta, outside, smooth) and the smooth ones checked.
std::vector<double> sample_histogram(const Material &mat, const ShadingContext &ctx, const Vec3 &wo, const Grid &g,
                                     const Chi2Options &opt, Chi2Result &r) {
    std::vector<double> observed(g.cells(), 0.0);
    PCG32 rng(opt.seed);
    for (uint64_t i = 0; i < opt.samples; ++i) {
        float u_lobe = rng.next_float();
        Vec2 u(rng.next_float(), rng.next_float());
        BSDFSample bs;
        if (!mat.sample(ctx, wo, u_lobe, u, bs)) {
            r.failed++;
            continue;
        }
        if (!sample_is_valid(bs)) {
            r.invalid++;
            continue;
        }
        if (bs.flags & BSDF_Delta) {
            r.delta++;
            continue;
        }
        int c = g.cell(bs.wi);
        if (c < 0) {
            r.outside++;
            continue;
        }
        observed[c] += 1.0;
        r.smooth++;
        check_against_eval(mat, ctx, wo, bs, opt, r);
    }
    return observed;
}

/// Step 3: Pearson's χ² = Σ (O - E)² / E over cells pooled, in order of increasing E,
/// until each pool expects at least opt.min_expected samples; dof = pools - 1. Returns the
/// samples that fell in cells whose expected count is 0.
uint64_t pooled_pearson_chi2(const std::vector<double> &expected, const std::vector<double> &observed,
                             double min_expected, Chi2Result &r) {
    std::vector<int> idx(expected.size());
    for (size_t i = 0; i < idx.size(); ++i) idx[i] = int(i);
    std::sort(idx.begin(), idx.end(), [&](int a, int b) { return expected[a] < expected[b]; });
    double pool_e = 0.0, pool_o = 0.0;
    uint64_t zero_cells_hit = 0;
    for (int i : idx) {
        if (expected[i] <= 0.0) {
            if (observed[i] > 0.0) zero_cells_hit += uint64_t(observed[i]);
            continue;
        }
        pool_e += expected[i];
        pool_o += observed[i];
        if (pool_e >= min_expected) {
            r.chi2 += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
            r.dof++;
            pool_e = pool_o = 0.0;
        }
    }
    if (pool_e > 0.0) {
        r.chi2 += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
        r.dof++;
    }
    r.dof -= 1;
    return zero_cells_hit;
}

/// The verdict: the χ² p-value against the corrected significance, and every structural
/// problem, joined into r.message.
void judge(uint64_t zero_cells_hit, Chi2Result &r) {
    std::vector<std::string> problems;
    if (r.invalid) problems.push_back(fmt::format("{} samples had a non-finite/negative weight or pdf", r.invalid));
    if (r.outside) problems.push_back(fmt::format("{} samples fell below the horizon of a reflector", r.outside));
    if (r.weight_mismatch)
        problems.push_back(fmt::format("{} sample weights differ from eval/pdf (max rel. error {:.3g})", r.weight_mismatch,
                                       r.max_weight_rel_error));
    if (r.pdf_mismatch)
        problems.push_back(fmt::format("{} sample pdfs differ from pdf(wi) (max rel. error {:.3g})", r.pdf_mismatch,
                                       r.max_pdf_rel_error));
    if (zero_cells_hit) problems.push_back(fmt::format("{} samples fell in cells where the pdf integrates to 0", zero_cells_hit));
    if (r.smooth == 0 && r.pdf_integral <= 1e-12) {
        // Nothing continuous to test (a delta-only material): the histogram is empty and
        // pdf() is 0 everywhere, which is what the contract asks for.
        r.p_value = 1.0;
        r.dof = 0;
        r.chi2_passed = true;
    } else if (r.dof < 1) {
        problems.push_back("too few populated cells for a χ² test (increase samples)");
    } else {
        r.p_value = chi2_p_value(r.chi2, r.dof);
        r.chi2_passed = r.p_value >= r.significance;
        if (!r.chi2_passed)
            problems.push_back(fmt::format("χ² = {:.2f} with {} dof: p = {:.3g} < {:.3g}", r.chi2, r.dof, r.p_value,
                                           r.significance));
    }
    for (size_t i = 0; i < problems.size(); ++i) r.message += (i ? "; " : "") + problems[i];
    r.passed = problems.empty();
}

/// Step 4: writes both histograms to dir/<name>.json (name made file-safe) for a look at a
/// failure; sets r.dump_path when written.
void dump_histograms(const char *dir, const Chi2Options &opt, const Vec3 &wo, const Grid &g,
                     const std::vector<double> &observed, const std::vector<double> &expected, Chi2Result &r) {
    nlohmann::json j;
    j["name"] = opt.name;
    j["wo"] = {wo.x, wo.y, wo.z};
    j["n_phi"] = g.n_phi;
    j["n_cos_theta"] = g.n_z;
    j["cos_theta_min"] = g.z_min;
    j["layout"] = "row-major [cos_theta][phi], cos_theta ascending, phi in [0, 2pi)";
    j["samples"] = opt.samples;
    j["p_value"] = r.p_value;
    j["chi2"] = r.chi2;
    j["dof"] = r.dof;
    j["message"] = r.message;
    j["observed"] = observed;
    j["expected"] = expected;
    std::error_code ec;
    std::filesystem::create_directories(dir, ec);
    std::string safe = opt.name;
    for (char &ch : safe)
        if (!(std::isalnum(static_cast<unsigned char>(ch)) || ch == '-' || ch == '_' || ch == '.')) ch = '_';
    std::string path = (std::filesystem::path(dir) / (safe + ".json")).string();
    std::ofstream f(path);
    if (f) {
        f << j.dump() << "\n";
        r.dump_path = path;
    }
}

}  // namespace

Chi2Result chi2_material_test(const Material &mat, const ShadingContext &ctx, const Vec3 &wo, const Chi2Options &opt) {
    Chi2Result r;
    r.samples = opt.samples;
    r.significance = sidak_alpha(opt.alpha, opt.test_count);
    r.sphere = mat.has_transmission() || !(wo.z > 0.f);
    Grid g = make_grid(opt.res, r.sphere);

    // 1. histogram of sampled directions + per-sample consistency checks
    const std::vector<double> observed = sample_histogram(mat, ctx, wo, g, opt, r);

    // 2. expected counts
    std::vector<double> expected = integrate_cells(mat, ctx, wo, g, opt.sub, double(opt.samples), &observed);
    for (double &e : expected) {
        r.pdf_integral += e;
        e *= double(opt.samples);
    }

    // 3. Pearson's χ² with pooling of small cells, and the verdict
    const uint64_t zero_cells_hit = pooled_pearson_chi2(expected, observed, opt.min_expected, r);
    judge(zero_cells_hit, r);

    // 4. dump on failure
    const char *dir = std::getenv("MESO_CHI2_DUMP_DIR");
    if (!r.passed && dir && *dir) dump_histograms(dir, opt, wo, g, observed, expected, r);
    return r;
}

AlbedoEstimate estimate_albedo(const Material &mat, const ShadingContext &ctx, const Vec3 &wo, uint64_t samples,
                               uint64_t seed) {
    AlbedoEstimate a;
    a.samples = samples;
    if (samples == 0) return a;
    PCG32 rng(seed);
    double sum[3] = {0, 0, 0}, sum2[3] = {0, 0, 0};
    for (uint64_t i = 0; i < samples; ++i) {
        float u_lobe = rng.next_float();
        Vec2 u(rng.next_float(), rng.next_float());
        BSDFSample bs;
        if (!mat.sample(ctx, wo, u_lobe, u, bs)) continue;
        // flux, not radiance: undo the (η_o/η_i)² radiance scaling of a refracted sample
        const double k = (bs.flags & BSDF_Transmission) ? double(bs.eta) * bs.eta : 1.0;
        for (int c = 0; c < 3; ++c) {
            double w = bs.weight[c] * k;
            sum[c] += w;
            sum2[c] += w * w;
        }
    }
    double n = double(samples);
    for (int c = 0; c < 3; ++c) {
        double mean = sum[c] / n;
        double var = samples > 1 ? std::max(0.0, (sum2[c] - n * mean * mean) / (n - 1.0)) : 0.0;
        a.mean[c] = float(mean);
        a.stderr_[c] = float(std::sqrt(var / n));
    }
    return a;
}

}  // namespace meso
