#include "prefilter/level_error.h"
#include <tbb/parallel_for.h>
#include <cmath>
#include <fmt/format.h>
#include <vector>
#include "core/error.h"
#include "sampling/rng.h"
#include "prefilter/effective_brdf.h"

namespace meso::prefilter {

namespace {

constexpr double kPi = 3.14159265358979323846;

/// Direction pair j of n: ωi at azimuth 0, ωo at a golden-ratio azimuth, both cosines spread
/// over [0.2, 0.95] (near-specular and off-specular pairs, no grazing extreme).
void direction_pair(int j, int n, Vec3 &wi, Vec3 &wo) {
    auto frac = [](double x) { return x - std::floor(x); };
    const double ci = 0.2 + 0.75 * (j + 0.5) / n;
    const double co = 0.2 + 0.75 * frac(0.5 + 0.6180339887 * j);
    const double phi = 2 * kPi * frac(0.7548776662 * j + 0.5);
    const double si = std::sqrt(1 - ci * ci), so = std::sqrt(1 - co * co);
    wi = Vec3(float(si), 0.f, float(ci));
    wo = Vec3(float(so * std::cos(phi)), float(so * std::sin(phi)), float(co));
}

/// The mean of the channels of an estimate's value and the per-line variance behind it.
struct Moments {
    double mean = 0, line_var = 0, mean_var = 0;
    bool ok = false;
};

Moments moments(const EffectiveBrdfEstimator::Estimate &e) {
    Moments m;
    if (e.accepted < 2) return m;
    m.mean = double(e.value.average());
    const double se = double(e.std_error.average());
    m.mean_var = se * se;
    m.line_var = m.mean_var * double(e.accepted);
    m.ok = std::isfinite(m.mean) && std::isfinite(m.line_var);
    return m;
}

}  // namespace

namespace {

/// E (level_error.h) over windows of `win` x `win` coarse cells, and V (within one cell: only
/// meaningful for win = 1): sums over direction pairs of the numerators and the normaliser.
struct WindowSums {
    double e = 0, v = 0, q = 0;
};

WindowSums window_sums(const EffectiveBrdfEstimator &est_orig, const EffectiveBrdfEstimator &est_low, int cw, int ch,
                       int F, int win, const LevelErrorOptions &opt) {
    const int nx = cw / win, ny = ch / win;  // whole windows, aligned to multiples of win cells
    const long long nwin = (long long)nx * ny;
    const int K = int(std::min<long long>(opt.cells, nwin));
    std::vector<int> at(static_cast<size_t>(K));
    PCG32 rng(hash_combine(hash_combine(opt.seed, uint64_t(F)), uint64_t(win)));
    for (int k = 0; k < K; ++k)  // every window when there are at most K; else K uniform draws
        at[size_t(k)] = K == nwin ? k : int(rng.next_double() * double(nwin)) % int(nwin);
    const int D = opt.directions;
    std::vector<Moments> g(size_t(D * K)), m(size_t(D * K));
    tbb::parallel_for(0, D * K, [&](int idx) {
        const int d = idx / K, k = idx % K;
        Vec3 wi, wo;
        direction_pair(d, D, wi, wo);
        const int x = (at[size_t(k)] % nx) * win, y = (at[size_t(k)] / nx) * win;
        const PatchRegion ro{double(x) * F, double(y) * F, double(x + win) * F, double(y + win) * F};
        const PatchRegion rl{double(x), double(y), double(x + win), double(y + win)};
        const uint64_t s = hash_combine(hash_combine(hash_combine(opt.seed, uint64_t(F)), uint64_t(win)), uint64_t(idx));
        g[size_t(idx)] = moments(est_orig.estimate(ro, wi, wo, size_t(opt.lines), hash_combine(s, 1)));
        m[size_t(idx)] = moments(est_low.estimate(rl, wi, wo, size_t(opt.lines), hash_combine(s, 2)));
    });
    WindowSums out;
    for (int d = 0; d < D; ++d) {
        double sg = 0, sm = 0;
        int n = 0;
        for (int k = 0; k < K; ++k) {
            const Moments &a = g[size_t(d * K + k)], &b = m[size_t(d * K + k)];
            if (a.ok && b.ok) sg += a.mean, sm += b.mean, ++n;
        }
        if (n < 2 || !(sg > 0) || !(sm > 0)) continue;  // nothing reflected in this pair
        const double scale = sg / sm;
        double e = 0, v = 0, q = 0;
        for (int k = 0; k < K; ++k) {
            const Moments &a = g[size_t(d * K + k)], &b = m[size_t(d * K + k)];
            if (!(a.ok && b.ok)) continue;
            const double diff = a.mean - scale * b.mean;
            e += diff * diff - a.mean_var - scale * scale * b.mean_var;
            v += a.line_var - scale * scale * b.line_var;
            q += a.mean * a.mean;
        }
        out.e += e / n, out.v += v / n, out.q += q / n;
    }
    return out;
}

}  // namespace

LevelError measure_level_error(const Heightfield &orig, const Material &base, const Heightfield &low,
                               const Material &low_material, int F, const LevelErrorOptions &opt) {
    if (opt.cells < 1 || opt.directions < 1 || opt.lines < 2 || F < 1)
        throw MesoError(fmt::format("level error: expected cells, directions >= 1, lines >= 2 and F >= 1 (got {}, {}, {}, {})",
                                    opt.cells, opt.directions, opt.lines, F));
    const int cw = low.width(), ch = low.height();
    if (cw * F != orig.width() || ch * F != orig.height())
        throw MesoError(fmt::format("level error: h_low is {}x{}, expected the {}x{} map / {}", cw, ch, orig.width(),
                                    orig.height(), F));
    EffectiveBrdfEstimator est_orig(orig, base);
    EffectiveBrdfEstimator::Options lo;
    lo.macro_frame = true;  // f'_low holds the patch's normals (prefilter/model.h)
    EffectiveBrdfEstimator est_low(low, low_material, lo);
    LevelError r;
    r.cells = opt.cells, r.directions = opt.directions, r.lines = opt.lines;
    // Windows of 1, 2, 4, ... cells while at least 4 fit in the map (a whole period's error is
    // the mean error, which the global scale k removes).
    for (int win = 1; win <= std::min(cw, ch) / 2; win *= 2) {
        const WindowSums w = window_sums(est_orig, est_low, cw, ch, F, win, opt);
        if (!(w.q > 0)) break;
        if (win == 1) r.removed_variance = w.v / w.q;
        r.window_error.push_back(std::max(0.0, w.e / w.q));
    }
    r.patch_error = r.window_error.empty() ? 0.0 : r.window_error[0];
    return r;
}

}  // namespace meso::prefilter
