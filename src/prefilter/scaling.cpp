// Direct estimation of T and S (paper 004 §6) with splatted next-event terms: the rounds of traced
// lines that fill the estimator's sums (see scaling.h); the fit of T and S from them is in scaling_fit.cpp.
#include "prefilter/scaling.h"
#include "core/distributed.h"
#include <tbb/parallel_for.h>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <emmintrin.h>
#include <fmt/format.h>
#include <mutex>
#include "core/error.h"
#include "prefilter/micro_vertex.h"
#include "sampling/rng.h"
#include "sampling/warp.h"

namespace meso::prefilter {
using namespace detail;

namespace {

/// Lines of a task (all rounds) before the shadow-ray roulette has a bin mean to go by.
constexpr double kRouletteLines = 8;

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

/// s[q] += a[q] (b null) or s[q] += a[q] b[q], q < n, two doubles an SSE2 step (the compiler
/// leaves these loops scalar at -O2): each entry gets the same operations as the scalar loop.
void accumulate(double *s, const double *a, const double *b, size_t n) {
    size_t q = 0;
    if (b) {
        for (; q + 2 <= n; q += 2)
            _mm_storeu_pd(s + q, _mm_add_pd(_mm_loadu_pd(s + q), _mm_mul_pd(_mm_loadu_pd(a + q), _mm_loadu_pd(b + q))));
        for (; q < n; ++q) s[q] += a[q] * b[q];
    } else {
        for (; q + 2 <= n; q += 2) _mm_storeu_pd(s + q, _mm_add_pd(_mm_loadu_pd(s + q), _mm_loadu_pd(a + q)));
        for (; q < n; ++q) s[q] += a[q];
    }
}

/// x[q] *= f, q < n (as accumulate).
void scale_by(double *x, double f, size_t n) {
    size_t q = 0;
    const __m128d v = _mm_set1_pd(f);
    for (; q + 2 <= n; q += 2) _mm_storeu_pd(x + q, _mm_mul_pd(_mm_loadu_pd(x + q), v));
    for (; q < n; ++q) x[q] *= f;
}

/// The shadow-ray roulette (scaling.h, "Shadow-ray roulette") on next-event term c of a line of
/// weight q (|Q| / |P|), against ref_scale times the largest channel of its bin's running sum m:
/// a term below that reference survives with probability cm / ref (u = draw(), drawn only then)
/// and is weighted by the inverse, per channel in double (ref / cm may pass float's range; c's
/// channels <= c.max(), so the products stay <= ref / q). False: the term is dropped.
template <class Draw>
bool roulette_keeps(Spectrum &c, const double *m, double ref_scale, double q, Draw &&draw) {
    if (!(ref_scale > 0.0)) return true;
    const double ref = std::max({m[0], m[1], m[2]}) * ref_scale, cm = c.max() * q;
    if (!(cm < ref)) return true;
    if (!(draw() * ref < cm)) return false;  // traced with probability cm / ref
    for (int i = 0; i < 3; ++i) c[i] = float(double(c[i]) * (ref / cm));
    return true;
}

/// The strata of K lines over the shooting region Q (scaling.h, "Standard errors"): H = K / 2
/// cells of a near-square nx x ny grid (ny the largest divisor of H at most √H), two lines each
/// (lines 2h and 2h + 1 in cell h); an odd K's last line is unstratified.
struct Strata {
    int nx = 1, ny = 1, H = 0;
    explicit Strata(int K) : H(K / 2) {
        if (H < 1) return;
        ny = int(std::sqrt(double(H)));
        while (H % ny) --ny;
        nx = H / ny;
    }
    /// Line k's position in [0, 1)² from two uniforms.
    void place(int k, double rx, double ry, double &sx, double &sy) const {
        const int h = k / 2;
        if (h >= H) {
            sx = rx, sy = ry;
        } else {
            sx = (double(h % nx) + rx) / double(nx);
            sy = (double(h / nx) + ry) / double(ny);
        }
    }
};

/// Per-line contribution buffers of one task: a = single-bounce (or f'_low) terms of the line,
/// b = all bounces, c = the first vertex's terms without the shadow test (the control variate).
struct LineBuf {
    std::vector<double> a, b, c;  // N² x 3
    explicit LineBuf(int bins) : a(size_t(bins) * 3), b(size_t(bins) * 3), c(size_t(bins) * 3) {}
    /// Zeroes a, and b and c where asked: a line on h_low or of the control variate writes a
    /// alone, and c is written only with the control variate.
    void clear(bool with_b, bool with_c) {
        std::fill(a.begin(), a.end(), 0.0);
        if (with_b) std::fill(b.begin(), b.end(), 0.0);
        if (with_c) std::fill(c.begin(), c.end(), 0.0);
    }
};

}  // namespace

ScalingEstimator::ScalingEstimator(const Heightfield &orig, const Material &base, const Heightfield &low,
                                   const SvMultiLobe &low_material, const ScalingOptions &opt)
    : m_orig(orig), m_low(low), m_base(base), m_low_mat(low_material), m_opt(opt) {
    const int M = opt.M, N = opt.N;
    if (M < 1 || orig.width() % M || orig.height() % M || low.width() % M || low.height() % M)
        throw MesoError(fmt::format("scaling function: M = {} must be >= 1 and divide the original ({}x{}) and the "
                                    "downsampled ({}x{}) map sizes",
                                    M, orig.width(), orig.height(), low.width(), low.height()));
    if (N < 1 || N > 64) throw MesoError(fmt::format("scaling function: N = {} must be in [1, 64]", N));
    if (int64_t(orig.width()) * low.height() != int64_t(orig.height()) * low.width())
        throw MesoError("scaling function: the original and downsampled maps have different aspect ratios");
    if (opt.orig_paths < 1 || opt.low_paths < 1)
        throw MesoError("scaling function: orig_paths and low_paths must be at least 1");
    if (!(opt.epsilon > 0) || !std::isfinite(opt.epsilon))
        throw MesoError(fmt::format("scaling function: epsilon = {} must be positive", opt.epsilon));
    if (opt.max_bounces < 1) throw MesoError("scaling function: max_bounces must be >= 1");
    if (opt.cv_lines < 0) throw MesoError(fmt::format("scaling function: cv_lines = {} must be >= 0", opt.cv_lines));
    m_bins = N * N;
    m_round_lines = RoundLines{opt.orig_paths, opt.low_paths};
    m_low_bound = std::make_unique<const SlopeBound>(low);
    const size_t n = size_t(M) * M * m_bins * m_bins * 3;
    for (auto *v : {&m_n1, &m_n1sq, &m_d, &m_dsq, &m_n1x}) v->assign(n, 0.0);
    if (opt.interreflections)
        for (auto *v : {&m_nir, &m_nirsq, &m_nirx}) v->assign(n, 0.0);
    if (opt.cv_lines > 0)
        for (auto *v : {&m_cv, &m_cvsq}) v->assign(n, 0.0);
    const bool recip = (opt.reciprocity || opt.check_reciprocity) && opt.cv_lines == 0;
    if (recip) {
        for (auto *v : {&m_r1, &m_r1sq}) v->assign(n, 0.0);
        if (opt.interreflections)
            for (auto *v : {&m_rir, &m_rirsq}) v->assign(n, 0.0);
    }
    m_area.assign(size_t(M) * M * m_bins, 0.0);
    m_shot.assign(size_t(M) * M * m_bins, 0);
    m_count_cv.assign(size_t(M) * M * m_bins, 0);
    m_wsum_cv.assign(size_t(M) * M * m_bins, 0.0);
    m_wsum_low.assign(size_t(M) * M * m_bins, 0.0);
    m_stats.estimator_bytes = ((opt.interreflections ? 8 : 5) + (opt.cv_lines > 0 ? 2 : 0) +
                               (recip ? (opt.interreflections ? 4 : 2) : 0)) * n * sizeof(double) +
                              3 * size_t(M) * M * m_bins * sizeof(uint32_t) + m_low_bound->memory_bytes();
    m_count_orig.assign(size_t(M) * M * m_bins, 0);
    m_count_low.assign(size_t(M) * M * m_bins, 0);
}

const SlopeBound &ScalingEstimator::orig_bound() const {
    std::call_once(m_orig_bound_once, [this] { m_orig_bound = std::make_unique<const SlopeBound>(m_orig); });
    return *m_orig_bound;
}

/// One (patch P, ωo bin) task of a round (scaling.h, "Work"): its random stream, the ωi
/// directions of the current line of sight, the line's splat buffers and the task's counters.
/// Nested in ScalingEstimator, so it adds to the estimator's sums directly (each task owns its
/// slice of them).
struct ScalingEstimator::Task {
    ScalingEstimator &est;  ///< the original's lines (the group's first estimator)
    /// Every level traced with it (add_round_group; est first): each gets the original's terms
    /// and traces its own h_low lines.
    const std::vector<ScalingEstimator *> &group;
    const size_t task;
    const uint64_t round_seed;
    const int M, N, B;      ///< T's grid, S's grid per axis, N² bins
    const int pa, pb;       ///< patch P = (pa, pb) of the M x M grid
    const int box, boy;     ///< the ωo bin (box, boy) of the N x N square
    const size_t base_idx;  ///< this task's [bi][ch] slice of the sums
    const bool cv;          ///< the control variate (scaling.h) is on
    const bool recip;       ///< the reciprocal estimates are kept (scaling.h, "Reciprocity")
    PCG32 rng;              ///< the original's path continuations (lines and f'_low node sets have their own streams)
    PCG32 rr;               ///< the shadow-ray roulette's decisions (own stream: the paths do not change)
    std::vector<Vec3> wi;   ///< ωi of every bin for the current line (one random shift of the grid per line)
    int drawn_k = -1;       ///< the line of sight whose directions wi and wo_k hold (start_line)
    Vec3 wo_k;              ///< its ωo
    PCG32 lr_k;             ///< its stream after the draw
    std::vector<Spectrum> fl;  ///< f'_low(ωi of every bin, ωo) of the current line
    std::vector<int> up;       ///< the bins above the current original vertex's micro-facet ...
    std::vector<Vec3> lwi;     ///< ... their ωi in its frame ...
    std::vector<Spectrum> fo;  ///< ... and the base towards them
    std::vector<size_t> vis;   ///< f'_low's nodes facing ωo ...
    std::vector<double> vw;    ///< ... and their weights c_k
    size_t orig_lines = 0, vertices = 0, rejected = 0, leaked = 0;  ///< the original's lines
    double q_ratio = 0;      ///< |Q| / |P| of the last line shot (shoot)
    double area_orig = 0;    ///< Σ q_ratio over the accepted lines on the original (a_P, scaling.h "Reciprocity")
    uint32_t acc_orig = 0, acc_cv = 0;
    double w_cv = 0;  ///< Σ |Q| / |P| over the accepted cheap lines (scaling.h, "Weights")
    size_t cv_lines = 0;
    /// Per level of the group: accepted, traced, rejected and leaked h_low lines, thread time.
    std::vector<uint32_t> acc_low;
    std::vector<size_t> low_lines, low_rejected, low_leaked;
    std::vector<double> t_low;
    std::vector<double> w_low;  ///< per level: Σ |Q| / |P| over its accepted h_low lines
    std::vector<double> dx, dy; ///< add_pair's differences

    Task(ScalingEstimator &e, const std::vector<ScalingEstimator *> &g, size_t t, uint64_t seed)
        : est(e), group(g), task(t), round_seed(seed), M(e.m_opt.M), N(e.m_opt.N), B(e.m_bins),
          pa(int(t / size_t(B)) % M), pb(int(t / size_t(B)) / M), box(int(t % size_t(B)) % N),
          boy(int(t % size_t(B)) / N), base_idx(t * size_t(B) * 3), cv(e.m_opt.cv_lines > 0), recip(!e.m_r1.empty()),
          rng(hash_combine(seed, uint64_t(t)), mix_bits(seed ^ 0x5ca1eULL)),
          rr(hash_combine(seed ^ 0x5add0ULL, uint64_t(t)), mix_bits(seed ^ 0x7711eULL)), wi(static_cast<size_t>(B)),
          fl(static_cast<size_t>(B)), lwi(static_cast<size_t>(B)), fo(static_cast<size_t>(B)), acc_low(g.size(), 0), low_lines(g.size(), 0), low_rejected(g.size(), 0),
          low_leaked(g.size(), 0), t_low(g.size(), 0.0), w_low(g.size(), 0.0) {}

    // Line k's own stream: its ωo, ωi shift and position in P are the same on G_orig and on
    // G_low (common random numbers: the two estimates of a bin are positively correlated).
    PCG32 line_rng(int k) const {
        return PCG32(hash_combine(hash_combine(round_seed, uint64_t(task)), uint64_t(k)), mix_bits(round_seed ^ 0x11e5ULL));
    }
    /// The offset of line k's f'_low node set on G_low: its own stream, the same for every level
    /// of a group, so that a level's tables do not depend on the other levels traced with it.
    double node_xi(int k) const {
        PCG32 r(hash_combine(hash_combine(round_seed ^ 0x70de5ULL, uint64_t(task)), uint64_t(k)),
                mix_bits(round_seed ^ 0x5eedULL));
        return r.next_double();
    }
    /// ωo in its bin and every ωi bin on one copy of the grid (fills `wi`): at the bin centres,
    /// or jittered (ScalingOptions::jitter_directions). The stream advances the same either way.
    void draw_directions(PCG32 &lr, Vec3 &wo) {
        const bool jitter = est.m_opt.jitter_directions;
        float j[4];
        for (float &x : j) {
            const float r = lr.next_float();
            x = jitter ? r : 0.5f;
        }
        wo = square_to_hemisphere(Vec2((float(box) + j[0]) / float(N), (float(boy) + j[1]) / float(N)));
        const float sa = j[2], sb = j[3];
        square_to_hemisphere_grid(N, sa, sb, wi.data());
    }
    /// Patch P of this task in a field's cell space.
    PatchRegion patch_of(const Heightfield &hf) const {
        const double cw = double(hf.width()) / M, ch = double(hf.height()) / M;
        return PatchRegion{pa * cw, pb * ch, (pa + 1) * cw, (pb + 1) * ch};
    }
    /// Shoots line k on field `hf` over patch R, its position in stratum st (lines 2h, 2h + 1 share one);
    /// the first vertex, or false (counted as leaked or rejected).
    bool shoot(PCG32 &lr, const Heightfield &hf, const PatchRegion &R, Vec3 wo, int k, const Strata &st, bool macro,
               Vertex &v) {
        const ShootingRegion Q = shooting_region(hf, R, wo);
        q_ratio = Q.area() / ((R.x1 - R.x0) * (R.y1 - R.y0));
        const double rx = lr.next_double(), ry = lr.next_double();
        double sx, sy;
        st.place(k, rx, ry, sx, sy);
        const double qx = Q.x0 + (Q.x1 - Q.x0) * sx, qy = Q.y0 + (Q.y1 - Q.y0) * sy;
        const double fqx = std::floor(qx), fqy = std::floor(qy);
        const int64_t ox = int64_t(fqx), oy = int64_t(fqy);
        HeightfieldHit hit;
        if (!hf.intersect(Vec3(float(qx - fqx), float(qy - fqy), float(Q.z_top)), -wo, 0.f, Infinity, hit, ox, oy)) {
            ++leaked;
            return false;
        }
        if (!Q.accepts(R, double(ox) + double(hit.x), double(oy) + double(hit.y))) {
            ++rejected;
            return false;
        }
        v = make_vertex(hf, hit, ox, oy, macro);
        return true;
    }
    /// Line k of K on field hf: its directions (same on both fields) and first vertex in P.
    /// Line k's directions are drawn once (into wo_k, wi) and reused by every field that traces
    /// line k (the original and each level's h_low): drawn_k is the line they belong to, lr_k
    /// its stream after the draw.
    bool start_line(const Heightfield &hf, const PatchRegion &R, int k, int K, bool macro, Vec3 &wo, Vertex &v,
                    size_t &lines) {
        if (drawn_k != k) {
            lr_k = line_rng(k);
            draw_directions(lr_k, wo_k);
            drawn_k = k;
        }
        PCG32 lr = lr_k;
        wo = wo_k;
        ++lines;
        return shoot(lr, hf, R, wo, k, Strata(K), macro, v);
    }

    // --- the original microgeometry: paths, next-event towards every ωi bin -----------------
    /// Next-event terms of vertex v (seen from local lwo) towards every ωi bin: eq. 6's
    /// integrand at the first vertex (buf.a), eq. 17's at every vertex (buf.b).
    void splat_original_vertex(const Vertex &v, Vec3 lwo, const Spectrum &throughput, int depth, LineBuf &buf) {
        const Frame &fr = v.ctx.frame;
        const Vec3 org = spawn_origin(v);
        // The bins above the micro-facet, compacted (a base is never evaluated below it), then
        // the base towards all of them in one call: the wo side once (eval's values).
        up.clear();
        for (int b = 0; b < B; ++b) {
            const Vec3 l = fr.to_local(wi[size_t(b)]);
            if (l.z > 0.f) lwi[up.size()] = l, up.push_back(b);
        }
        est.m_base.eval_batch(v.ctx, lwo, lwi.data(), int(up.size()), fo.data());
        // The slope above which a direction cannot be shadowed from org (slope_bound.h).
        const SlopeBound::Local lb =
            est.orig_bound().local(double(v.ox) + double(org.x), double(v.oy) + double(org.y), org.z);
        // The roulette's reference: ε times the bin's mean term per line so far (this round's
        // lines before this one and the earlier rounds'), of the sum this vertex adds to.
        const double eps = cv ? 0.0 : est.m_opt.shadow_roulette;
        const double before = double(est.m_shot[task]) + double(orig_lines) - 1.0;
        const std::vector<double> &ref_sum = depth == 1 ? est.m_n1 : est.m_nir;
        const double ref_scale = eps > 0.0 && before >= kRouletteLines ? eps / before : 0.0;
        for (size_t u = 0; u < up.size(); ++u) {
            const int b = up[u];
            const Spectrum &f = fo[u];
            if (f.is_black()) continue;
            if (depth == 1 && cv) {
                double *pc = &buf.c[size_t(b) * 3];
                for (int q = 0; q < 3; ++q) pc[q] += f[q];
            }
            Spectrum c = throughput * f;
            const bool needs_ray = !unoccluded_by_slope(wi[size_t(b)], lb.slope);
            // A term without a shadow ray gains nothing from the roulette.
            if (needs_ray && !roulette_keeps(c, &ref_sum[base_idx + size_t(b) * 3], ref_scale, q_ratio,
                                             [this] { return rr.next_double(); }))
                continue;
            if (needs_ray &&
                est.m_orig.occluded(org, wi[size_t(b)], 0.f, SlopeBound::reach(lb, wi[size_t(b)]), v.ox, v.oy))
                continue;
            double *pir = &buf.b[size_t(b) * 3];
            for (int q = 0; q < 3; ++q) pir[q] += c[q];
            if (depth == 1) {
                double *p1 = &buf.a[size_t(b) * 3];
                for (int q = 0; q < 3; ++q) p1[q] += c[q];
            }
        }
    }
    /// The path's next vertex: samples the base, Russian roulette, traces; false when it ends.
    bool continue_path(Vertex &v, Vec3 &w_out, Spectrum &throughput, Vec3 lwo, int depth) {
        const Frame &fr = v.ctx.frame;
        const float u_lobe = rng.next_float(), u0 = rng.next_float(), u1 = rng.next_float();
        BSDFSample bs;
        if (!est.m_base.sample(v.ctx, lwo, u_lobe, Vec2(u0, u1), bs) || bs.weight.is_black() || !(bs.wi.z > 0.f))
            return false;
        throughput *= bs.weight;
        if (est.m_opt.roulette_start > 0 && depth >= est.m_opt.roulette_start) {
            const float q = std::min(1.f, throughput.max());
            if (!(rng.next_float() < q)) return false;
            throughput *= 1.f / q;
        }
        const Vec3 dir = normalize(fr.to_world(bs.wi));
        HeightfieldHit next;
        if (!est.m_orig.intersect(spawn_origin(v), dir, 0.f, Infinity, next, v.ox, v.oy)) return false;
        v = make_vertex(est.m_orig, next, v.ox, v.oy);
        w_out = -dir;
        return true;
    }
    /// Line k of K on G_orig with its path (eq. 15-17): the numerator terms into `out` (cleared
    /// by the caller); false when the line was rejected or leaked.
    bool trace_original_line(int k, int K, LineBuf &out) {
        const bool ir = est.m_opt.interreflections;
        const int max_vertices = ir ? est.m_opt.max_bounces : 1;
        Vec3 wo;
        Vertex v;
        if (!start_line(est.m_orig, patch_of(est.m_orig), k, K, false, wo, v, orig_lines)) return false;
        Spectrum throughput(1.f);
        Vec3 w_out = wo;
        for (int depth = 1;; ++depth) {
            ++vertices;
            const Vec3 lwo = v.ctx.frame.to_local(w_out);
            if (!(lwo.z > 0.f)) break;
            splat_original_vertex(v, lwo, throughput, depth, out);
            if (depth >= max_vertices) break;
            if (!continue_path(v, w_out, throughput, lwo, depth)) break;
        }
        return true;
    }

    // --- the downsampled model: one bounce, f'_low in the macro frame -----------------------
    /// f'_low = Σ_k c_k base(F_k ωo, F_k ωi) (eq. 11) as an expectation over nodes: J nodes
    /// stratified in the CDF of c_k over the nodes that face ωo (the others add 0); into `fl`.
    /// xi: the stratification's offset in [0, 1), from line k's own stream (node_xi).
    void sample_f_low_nodes(const ScalingEstimator &le, const MultiLobeBrdf &fl_patch, const ShadingContext &ctx,
                            Vec3 wo, int J, double xi) {
        const Material &base_low = le.m_low_mat.base();
        const auto &nodes = fl_patch.nodes();
        vis.clear();
        vw.clear();
        double total = 0;
        for (size_t q = 0; q < nodes.size(); ++q)
            if (const double w = fl_patch.node_weight(nodes[q], wo); w > 0) vis.push_back(q), vw.push_back(w), total += w;
        std::fill(fl.begin(), fl.end(), Spectrum(0.f));
        if (!(total > 0)) return;
        size_t q = 0;
        double cum = 0;
        for (int j = 0; j < J; ++j) {
            const double target = (double(j) + xi) / J * total;
            while (q + 1 < vis.size() && cum + vw[q] <= target) cum += vw[q], ++q;
            const Frame &F = nodes[vis[q]].frame;
            const Vec3 lo = F.to_local(wo);
            const float scale = float(total * fl_patch.view_scale(total) / J);  // eval's weights sum to that
            for (int b = 0; b < B; ++b) {
                const Vec3 li = F.to_local(wi[size_t(b)]);
                if (!(li.z > 0.f) || !(wi[size_t(b)].z > 0.f)) continue;
                fl[size_t(b)] += base_low.eval(ctx, lo, li) * scale;
            }
        }
    }
    /// Line k of K on level j's G_low (estimator le) with f'_low, single bounce (eq. 20): the
    /// denominator terms into out.a (cleared by the caller); false when the line was rejected or
    /// leaked (counted for level j).
    bool trace_low_line(const ScalingEstimator &le, size_t j, int k, int K, LineBuf &out) {
        const size_t rej = rejected, leak = leaked;
        const bool ok = trace_low_line_impl(le, j, k, K, out);
        low_rejected[j] += rejected - rej, low_leaked[j] += leaked - leak;
        rejected = rej, leaked = leak;
        return ok;
    }
    bool trace_low_line_impl(const ScalingEstimator &le, size_t j, int k, int K, LineBuf &out) {
        const int J = le.m_opt.low_nodes;
        Vec3 wo;
        Vertex v;
        if (!start_line(le.m_low, patch_of(le.m_low), k, K, true, wo, v, low_lines[j])) return false;
        const Vec3 org = spawn_origin(v);
        if (const SvLobeBrdf *lf = le.m_low_mat.lobe_form())  // closed form: deterministic and cheap
            lf->eval_batch(v.ctx, wo, wi.data(), B, fl.data());
        else if (J == 0)
            le.m_low_mat.patch(v.ctx.uv).eval_batch(v.ctx, wo, wi.data(), B, fl.data());
        else
            sample_f_low_nodes(le, le.m_low_mat.patch(v.ctx.uv), v.ctx, wo, J, node_xi(k));
        // The shadow-ray roulette (scaling.h) on the terms that need a shadow ray: the reference
        // is ε times the bin's mean denominator term per accepted line so far (this level's).
        const double eps = cv ? 0.0 : le.m_opt.shadow_roulette;
        const double before = double(le.m_count_low[task]) + double(acc_low[j]);
        const double ref_scale = eps > 0.0 && before >= kRouletteLines ? eps / before : 0.0;
        PCG32 lrr;
        bool lrr_drawn = false;
        auto draw = [&] {
            if (!lrr_drawn) lrr = low_roulette_rng(k), lrr_drawn = true;
            return lrr.next_double();
        };
        const SlopeBound::Local lb =
            le.m_low_bound->local(double(v.ox) + double(org.x), double(v.oy) + double(org.y), org.z);
        for (int b = 0; b < B; ++b) {
            const Vec3 &w = wi[size_t(b)];
            Spectrum f = fl[size_t(b)];
            if (f.is_black() || !(dot(v.n, w) > 0.f)) continue;  // below the h_low facet: self-shadowed
            if (!unoccluded_by_slope(w, lb.slope) &&
                (!roulette_keeps(f, &le.m_d[base_idx + size_t(b) * 3], ref_scale, q_ratio, draw) ||
                 le.m_low.occluded(org, w, 0.f, SlopeBound::reach(lb, w), v.ox, v.oy)))
                continue;
            double *p = &out.a[size_t(b) * 3];
            for (int q = 0; q < 3; ++q) p[q] += f[q];
        }
        return true;
    }
    /// Line k's stream for the shadow-ray roulette on G_low: its own, the same for every level of
    /// a group (a level's tables do not depend on the levels traced with it).
    PCG32 low_roulette_rng(int k) const {
        return PCG32(hash_combine(hash_combine(round_seed ^ 0x10dd5ULL, uint64_t(task)), uint64_t(k)),
                     mix_bits(round_seed ^ 0x5151ULL));
    }

    /// Adds one line's terms to this task's slice of `sum`.
    void add_line(std::vector<double> &sum, const std::vector<double> &line) {
        accumulate(sum.data() + base_idx, line.data(), nullptr, size_t(B) * 3);
    }
    /// Pair terms (scaling.h, "Standard errors") of lines x (numerator) and y (denominator):
    /// Σ (x0 - x1)² into sq, Σ (y0 - y1)² into dsq, Σ (x0 - x1)(y0 - y1) into cross; a null
    /// partner (the unpaired last line) counts as 0; null sq / dsq / cross skip that term. The
    /// differences first, then one `accumulate` per sum (no tests inside the loops); every entry
    /// gets the same operations as one fused loop would give it.
    void add_pair(const std::vector<double> *x0, const std::vector<double> *x1, const std::vector<double> *y0,
                  const std::vector<double> *y1, std::vector<double> *sq, std::vector<double> *dsq,
                  std::vector<double> *cross) {
        const size_t n = size_t(B) * 3;
        auto diff = [n](const std::vector<double> *a, const std::vector<double> *b, std::vector<double> &out) {
            out.resize(n);
            double *o = out.data();
            if (!a) {
                std::fill(o, o + n, 0.0);
            } else if (!b) {
                std::copy_n(a->data(), n, o);  // a - 0.0 is a, -0.0 included
            } else {
                const double *pa = a->data(), *pb = b->data();
                for (size_t q = 0; q < n; ++q) o[q] = pa[q] - pb[q];
            }
        };
        if (sq || cross) diff(x0, x1, dx);
        if (dsq || cross) diff(y0, y1, dy);
        const double *px = dx.data(), *py = dy.data();
        if (sq) accumulate(sq->data() + base_idx, px, px, n);
        if (dsq) accumulate(dsq->data() + base_idx, py, py, n);
        if (cross) accumulate(cross->data() + base_idx, px, py, n);
    }
    /// Both fields' lines in consecutive pairs: sums, pair differences and, when both fields
    /// trace the same number of lines (line k shares its random numbers), the cross terms. Each
    /// line on the original is traced once and its terms go to every level of the group; each
    /// level traces its own h_low line k.
    void trace_lines(double &t_orig) {
        // This round's counts (ScalingEstimator::m_round_lines: the options', or the allocation's).
        const int Ko = est.m_round_lines.orig;
        const bool ir = est.m_opt.interreflections;
        const size_t G = group.size();
        int Kmax = Ko;
        for (const ScalingEstimator *e : group) Kmax = std::max(Kmax, e->m_round_lines.low);
        LineBuf o[2] = {LineBuf(B), LineBuf(B)};
        LineBuf r[2] = {LineBuf(recip ? B : 0), LineBuf(recip ? B : 0)};  // the transposed pairs' terms
        std::vector<LineBuf> l(2 * G, LineBuf(B));  // level j's pair: l[2 j], l[2 j + 1]
        for (int k = 0; k < Kmax; ++k) {
            const int s = k & 1;
            if (k < Ko) {
                const auto t0 = Clock::now();
                o[s].clear(true, cv);
                if (trace_original_line(k, Ko, o[s])) {
                    ++acc_orig;
                    area_orig += q_ratio;
                    // The line's weight |Q(ωo)| / |P| (scaling.h, "Weights"): 1 when Q = P.
                    if (q_ratio != 1.0) {
                        scale_by(o[s].a.data(), q_ratio, o[s].a.size());
                        scale_by(o[s].b.data(), q_ratio, o[s].b.size());
                        if (cv) scale_by(o[s].c.data(), q_ratio, o[s].c.size());
                    }
                    if (cv)  // g - c (scaling.h, "Control variate")
                        for (size_t q = 0; q < size_t(B) * 3; ++q) o[s].a[q] -= o[s].c[q], o[s].b[q] -= o[s].c[q];
                    add_line(est.m_n1, o[s].a);  // the other levels copy the lead's sums (share_numerators)
                    if (ir) add_line(est.m_nir, o[s].b);
                }
                if (recip) {  // g cos θo / cos θi (a rejected line: 0, as o[s])
                    for (int b = 0; b < B; ++b) {
                        const double f = wi[size_t(b)].z > 0.f ? double(wo_k.z) / double(wi[size_t(b)].z) : 0.0;
                        for (size_t q = size_t(b) * 3; q < size_t(b) * 3 + 3; ++q)
                            r[s].a[q] = o[s].a[q] * f, r[s].b[q] = ir ? o[s].b[q] * f : 0.0;
                    }
                    add_line(est.m_r1, r[s].a);
                    if (ir) add_line(est.m_rir, r[s].b);
                }
                t_orig += seconds_since(t0);
            }
            for (size_t j = 0; j < G; ++j) {
                const int Kl = group[j]->m_round_lines.low;
                if (k >= Kl) continue;
                const auto t0 = Clock::now();
                LineBuf &lb = l[2 * j + size_t(s)];
                lb.clear(false, false);
                if (trace_low_line(*group[j], j, k, Kl, lb)) {
                    ++acc_low[j];
                    w_low[j] += q_ratio;
                    if (q_ratio != 1.0) scale_by(lb.a.data(), q_ratio, lb.a.size());
                    add_line(group[j]->m_d, lb.a);
                }
                t_low[j] += seconds_since(t0);
            }
            // A complete pair (k - 1, k) of a field, or its unpaired last line k (partner 0).
            const bool o_pair = k < Ko && (s == 1 || k == Ko - 1);
            const bool whole = s == 1;
            for (size_t j = 0; j < G; ++j) {
                ScalingEstimator &e = *group[j];
                const int Kl = e.m_round_lines.low;
                const bool l_pair = k < Kl && (s == 1 || k == Kl - 1), paired = Ko == Kl;
                if (!o_pair && !l_pair) continue;
                const bool lead = j == 0;  // the numerator-only sums: the lead's alone (share_numerators)
                const LineBuf &l0 = l[2 * j], &l1 = l[2 * j + 1];
                add_pair(o_pair ? &o[0].a : nullptr, o_pair && whole ? &o[1].a : nullptr, l_pair ? &l0.a : nullptr,
                         l_pair && whole ? &l1.a : nullptr, o_pair && lead ? &e.m_n1sq : nullptr,
                         l_pair ? &e.m_dsq : nullptr, paired ? &e.m_n1x : nullptr);
                if (ir && o_pair && (lead || paired))
                    add_pair(&o[0].b, whole ? &o[1].b : nullptr, paired ? &l0.a : nullptr, paired && whole ? &l1.a : nullptr,
                             lead ? &e.m_nirsq : nullptr, nullptr, paired ? &e.m_nirx : nullptr);
                if (recip && o_pair && lead) {
                    add_pair(&r[0].a, whole ? &r[1].a : nullptr, nullptr, nullptr, &e.m_r1sq, nullptr, nullptr);
                    if (ir) add_pair(&r[0].b, whole ? &r[1].b : nullptr, nullptr, nullptr, &e.m_rirsq, nullptr, nullptr);
                }
            }
        }
        share_numerators();
    }
    /// The numerator's sums do not depend on the level: trace_lines adds them (and their pair
    /// terms) to the lead's arrays alone, and this copies the task's slice to the other levels.
    /// Every level traces the same tasks every round (add_round_impl), so their slices were equal
    /// before and are equal after: the same values as adding to each.
    void share_numerators() {
        const size_t n = size_t(B) * 3;
        for (size_t j = 1; j < group.size(); ++j) {
            ScalingEstimator &e = *group[j];
            auto copy = [&](const std::vector<double> &from, std::vector<double> &to) {
                if (!from.empty()) std::copy_n(from.begin() + ptrdiff_t(base_idx), n, to.begin() + ptrdiff_t(base_idx));
            };
            copy(est.m_n1, e.m_n1), copy(est.m_n1sq, e.m_n1sq), copy(est.m_nir, e.m_nir), copy(est.m_nirsq, e.m_nirsq);
            copy(est.m_r1, e.m_r1), copy(est.m_r1sq, e.m_r1sq), copy(est.m_rir, e.m_rir), copy(est.m_rirsq, e.m_rirsq);
        }
    }
    /// The control variate's cheap lines (scaling.h): directions and positions drawn as for
    /// the lines of sight (own streams), the first vertex's terms without shadow rays into the
    /// sums, with the squared differences of consecutive pairs (a rejected line counts as 0).
    void trace_cv_lines() {
        const int K = est.m_opt.cv_lines;
        const PatchRegion R = patch_of(est.m_orig);
        const size_t rej = rejected, leak = leaked;
        LineBuf c[2] = {LineBuf(B), LineBuf(B)};
        for (int k = 0; k < K; ++k) {
            const int s = k & 1;
            c[s].clear(false, false);
            PCG32 lr(hash_combine(hash_combine(round_seed ^ 0xc0417a1eULL, uint64_t(task)), uint64_t(k)),
                     mix_bits(round_seed ^ 0xcfULL));
            Vec3 wo;
            draw_directions(lr, wo);
            drawn_k = -1;  // wi no longer holds a line of sight's directions
            Vertex v;
            ++cv_lines;
            if (shoot(lr, est.m_orig, R, wo, k, Strata(K), false, v)) {
                ++acc_cv;
                w_cv += q_ratio;
                if (const Vec3 lwo = v.ctx.frame.to_local(wo); lwo.z > 0.f)
                    for (int b = 0; b < B; ++b) {
                        const Vec3 lwi = v.ctx.frame.to_local(wi[size_t(b)]);
                        if (!(lwi.z > 0.f)) continue;
                        const Spectrum f = est.m_base.eval(v.ctx, lwo, lwi);
                        for (int q = 0; q < 3; ++q) c[s].a[size_t(b) * 3 + size_t(q)] = f[q] * q_ratio;
                    }
                for (ScalingEstimator *e : group) add_line(e->m_cv, c[s].a);
            }
            if (s == 1 || k == K - 1)
                for (ScalingEstimator *e : group)
                    add_pair(&c[0].a, s == 1 ? &c[1].a : nullptr, nullptr, nullptr, &e->m_cvsq, nullptr, nullptr);
        }
        rejected = rej, leaked = leak;  // the counters report the lines of sight
    }
    /// The task's line counts and the shared counters (under a lock: tasks run in parallel).
    /// Every level counts the original's lines (its numerator's) and is charged an equal share of
    /// their time.
    void commit(double t_orig) {
        static std::mutex mu;
        std::lock_guard<std::mutex> lock(mu);
        for (size_t j = 0; j < group.size(); ++j) {
            ScalingEstimator &e = *group[j];
            e.m_count_cv[task] += acc_cv;
            e.m_wsum_cv[task] += w_cv;
            e.m_wsum_low[task] += w_low[j];
            e.m_count_orig[task] += acc_orig;
            e.m_area[task] += area_orig;
            e.m_shot[task] += uint32_t(orig_lines);
            e.m_count_low[task] += acc_low[j];
            ScalingStats &st = e.m_stats;
            st.orig_lines += orig_lines;
            st.low_lines += low_lines[j];
            st.orig_vertices += vertices;
            st.rejected += rejected + low_rejected[j];
            st.leaked += leaked + low_leaked[j];
            st.core_seconds_orig += t_orig / double(group.size());
            st.core_seconds_low += t_low[j];
            st.cv_lines += cv_lines;
        }
    }
};

void ScalingEstimator::trace_task(const std::vector<ScalingEstimator *> &group, size_t task, uint64_t round_seed) {
    Task t(*this, group, task, round_seed);
    double t_orig = 0;
    if (t.cv) {
        const auto t0 = Clock::now();
        t.trace_cv_lines();
        t_orig += seconds_since(t0);
    }
    t.trace_lines(t_orig);
    t.commit(t_orig);
}

size_t ScalingEstimator::add_round() { return add_round_group({this}); }

size_t ScalingEstimator::add_round_group(const std::vector<ScalingEstimator *> &group) {
    if (group.empty()) return 0;
    ScalingEstimator &lead = *group.front();
    const ScalingOptions &lo = lead.m_opt;
    for (const ScalingEstimator *e : group) {
        const ScalingOptions &eo = e->m_opt;
        if (&e->m_orig != &lead.m_orig || &e->m_base != &lead.m_base || eo.M != lo.M || eo.N != lo.N ||
            eo.orig_paths != lo.orig_paths || eo.low_paths != lo.low_paths || eo.cv_lines != lo.cv_lines || eo.reciprocity != lo.reciprocity ||
            eo.check_reciprocity != lo.check_reciprocity ||
            eo.interreflections != lo.interreflections || e->m_stats.rounds != lead.m_stats.rounds)
            throw MesoError("scaling function: estimators traced together must share the original, the base, M, N, "
                            "the line counts and their rounds");
    }
    return lead.add_round_impl(group);
}

size_t ScalingEstimator::add_round_impl(const std::vector<ScalingEstimator *> &group) {
    const size_t tasks = size_t(m_opt.M) * m_opt.M * m_bins;
    // The stopping rule: after the first round, only the ωo bins still above the target (for
    // any level of the group: every level then gets the same lines, so their counts stay equal).
    std::vector<size_t> active;
    if (m_opt.target_error > 0 && m_stats.rounds > 0) {
        std::vector<char> on(tasks, 0);
        for (const ScalingEstimator *e : group) {
            const std::vector<double> per_bo = e->S_rel_se_per_wo_bin();
            for (size_t t = 0; t < tasks; ++t)
                if (per_bo[t % size_t(m_bins)] > e->m_opt.target_error) on[t] = 1;
        }
        for (size_t t = 0; t < tasks; ++t)
            if (on[t]) active.push_back(t);
    } else {
        for (size_t t = 0; t < tasks; ++t) active.push_back(t);
    }
    if (active.empty()) return 0;
    const uint64_t round_seed = hash_combine(m_opt.seed, uint64_t(m_stats.rounds) + 1);
    // MPI ranks (core/distributed.h, docs/cluster.md): the i-th active task belongs to rank
    // i mod ranks, so each sum is accumulated by one rank in the single-process order; after the
    // round the ranks exchange their tasks' slices (each entry has one non-zero contribution, so
    // the sum is exact) and every rank holds the same, single-process-identical arrays.
    const size_t ranks = size_t(dist::size()), rank = size_t(dist::rank());
    const size_t mine = ranks > 1 ? (active.size() + ranks - 1 - rank) / ranks : active.size();
    std::vector<ScalingStats> before;
    for (const ScalingEstimator *e : group) before.push_back(e->m_stats);
    std::atomic<size_t> done{0};
    std::mutex mu;
    const auto t0 = Clock::now();
    tbb::parallel_for(size_t(0), mine, [&](size_t i) {
        trace_task(group, active[ranks > 1 ? rank + i * ranks : i], round_seed);
        const size_t d = ++done;
        if (m_opt.progress && (d % 16 == 0 || d == mine)) {
            std::lock_guard<std::mutex> lock(mu);
            m_opt.progress(double(d) / double(mine));
        }
    });
    if (ranks > 1)
        for (size_t j = 0; j < group.size(); ++j) group[j]->share_round(before[j], active);
    const double secs = dist::allreduce_max(seconds_since(t0));
    for (ScalingEstimator *e : group) {
        e->m_stats.seconds += secs / double(group.size());  // each level's share of the shared round
        e->m_stats.tasks_traced += active.size();
        ++e->m_stats.rounds;
    }
    if (m_opt.allocate_lines) allocate_next_round(group);
    return active.size();
}

void allocate_lines(const std::vector<double> &A, const std::vector<double> &D, double c_o, const std::vector<double> &c,
                    double budget, int ko_min, int ko_max, int kl_max, int &Ko, std::vector<int> &Kl) {
    const size_t G = A.size();
    double best = Infinity;
    for (int ko = std::max(2, ko_min); ko <= ko_max; ko += std::max(1, ko / 32)) {
        const double rem = budget - double(ko) * c_o;
        if (!(rem > 0)) break;
        // cost(V): what the levels' h_low lines cost to reach error² V each (decreasing in V).
        double floor_v = 0;
        for (size_t j = 0; j < G; ++j) floor_v = std::max(floor_v, A[j] / ko);
        auto cost = [&](double V) {
            double t = 0;
            for (size_t j = 0; j < G; ++j)
                if (D[j] > 0) t += c[j] * D[j] / (V - A[j] / ko);
            return t;
        };
        double lo = floor_v, hi = floor_v > 0 ? 2 * floor_v : 1e-300;
        for (int i = 0; i < 2000 && cost(hi) > rem; ++i) hi *= 2;
        for (int i = 0; i < 100; ++i) {
            const double mid = 0.5 * (lo + hi);
            if (!(mid > lo && mid < hi)) break;
            (cost(mid) > rem ? lo : hi) = mid;
        }
        if (hi < best) {
            best = hi, Ko = ko;
            Kl.assign(G, 2);
            for (size_t j = 0; j < G; ++j)
                if (D[j] > 0) Kl[j] = int(std::clamp(std::ceil(D[j] / (hi - A[j] / ko)), 2.0, double(kl_max)));
        }
    }
}

void ScalingEstimator::allocate_next_round(const std::vector<ScalingEstimator *> &group) {
    const ScalingEstimator &lead = *group.front();
    const ScalingOptions &o = lead.m_opt;
    const size_t G = group.size();
    const double tasks = double(o.M) * o.M * lead.m_bins;
    // The levels' fits of this round's sums, side by side (the stopping rule's, cached for it).
    std::vector<SeCache> se(G);
    tbb::parallel_for(size_t(0), G, [&](size_t j) { se[j] = group[j]->se_cache(); });
    std::vector<double> A(G), D(G), c(G);
    double t_orig = 0;
    for (size_t j = 0; j < G; ++j) {
        const ScalingStats &st = group[j]->m_stats;
        t_orig += st.core_seconds_orig;  // each level holds an equal share
        A[j] = se[j].rel_var[0] * double(st.orig_lines) / tasks;
        D[j] = se[j].rel_var[1] * double(st.low_lines) / tasks;
        c[j] = st.low_lines > 0 ? st.core_seconds_low / double(st.low_lines) : 0.0;
    }
    const double c_o = lead.m_stats.orig_lines > 0 ? t_orig / double(lead.m_stats.orig_lines) : 0.0;
    bool ok = c_o > 0 && std::isfinite(c_o);
    double budget = double(o.orig_paths) * c_o;
    for (size_t j = 0; j < G; ++j) {
        ok = ok && A[j] > 0 && std::isfinite(A[j]) && D[j] >= 0 && std::isfinite(D[j]) && c[j] > 0 && std::isfinite(c[j]);
        budget += double(o.low_paths) * c[j];
    }
    if (!ok) return;  // nothing measured yet (or nothing to measure): the counts stay
    int Ko = o.orig_paths;
    std::vector<int> Kl(G, o.low_paths);
    allocate_lines(A, D, c_o, c, budget, 2, 4 * o.orig_paths, 8 * std::max(o.orig_paths, o.low_paths), Ko, Kl);
    for (size_t j = 0; j < G; ++j) group[j]->m_round_lines = RoundLines{Ko, Kl[j]};
}

void ScalingEstimator::share_round(const ScalingStats &before, const std::vector<size_t> &active) {
    const size_t ranks = size_t(dist::size()), rank = size_t(dist::rank());
    const size_t tasks = size_t(m_opt.M) * m_opt.M * m_bins, per = size_t(m_bins) * 3;
    // The owner of every task's slice this round: the rank that traced it, rank 0 for the tasks
    // nobody traced (every rank holds the same values for those).
    std::vector<size_t> owner(tasks, 0);
    for (size_t i = 0; i < active.size(); ++i) owner[active[i]] = i % ranks;
    auto share = [&](auto &a, size_t stride) {
        if (a.empty()) return;
        std::remove_reference_t<decltype(a)> c(a.size(), 0);
        for (size_t t = 0; t < tasks; ++t)
            if (owner[t] == rank) std::copy(a.begin() + t * stride, a.begin() + (t + 1) * stride, c.begin() + t * stride);
        dist::allreduce_sum(c.data(), c.size());
        a.swap(c);
    };
    for (std::vector<double> *a :
         {&m_n1, &m_n1sq, &m_nir, &m_nirsq, &m_d, &m_dsq, &m_n1x, &m_nirx, &m_cv, &m_cvsq, &m_r1, &m_r1sq, &m_rir, &m_rirsq})
        share(*a, per);
    share(m_area, 1);
    share(m_wsum_cv, 1);
    share(m_wsum_low, 1);
    share(m_shot, 1);
    share(m_count_cv, 1);
    share(m_count_orig, 1);
    share(m_count_low, 1);
    double d[8] = {double(m_stats.orig_lines - before.orig_lines), double(m_stats.low_lines - before.low_lines),
                   double(m_stats.orig_vertices - before.orig_vertices), double(m_stats.rejected - before.rejected),
                   double(m_stats.leaked - before.leaked), m_stats.core_seconds_orig - before.core_seconds_orig,
                   m_stats.core_seconds_low - before.core_seconds_low, double(m_stats.cv_lines - before.cv_lines)};
    dist::allreduce_sum(d, 8);
    m_stats.cv_lines = before.cv_lines + size_t(d[7]);
    m_stats.orig_lines = before.orig_lines + size_t(d[0]);
    m_stats.low_lines = before.low_lines + size_t(d[1]);
    m_stats.orig_vertices = before.orig_vertices + size_t(d[2]);
    m_stats.rejected = before.rejected + size_t(d[3]);
    m_stats.leaked = before.leaked + size_t(d[4]);
    m_stats.core_seconds_orig = before.core_seconds_orig + d[5];
    m_stats.core_seconds_low = before.core_seconds_low + d[6];
}

}  // namespace meso::prefilter
