// Direct estimation of T and S (paper 004 §6) with splatted next-event terms: see scaling.h.
#include "prefilter/scaling.h"
#include "core/distributed.h"
#include <tbb/parallel_for.h>
#include <Eigen/Dense>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <fmt/format.h>
#include <mutex>
#include "core/error.h"
#include "prefilter/micro_vertex.h"
#include "sampling/rng.h"
#include "sampling/warp.h"

namespace meso::prefilter {
using namespace detail;

namespace {

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

int perfect_square_root(int k) {
    const int g = int(std::lround(std::sqrt(double(k))));
    return g * g == k ? g : 0;
}

/// Per-line contribution buffers of one task: a = single-bounce (or f'_low) terms of the line,
/// b = all bounces, c = the first vertex's terms without the shadow test (the control variate).
struct LineBuf {
    std::vector<double> a, b, c;  // N² x 3
    explicit LineBuf(int bins) : a(size_t(bins) * 3), b(size_t(bins) * 3), c(size_t(bins) * 3) {}
    void clear() {
        std::fill(a.begin(), a.end(), 0.0);
        std::fill(b.begin(), b.end(), 0.0);
        std::fill(c.begin(), c.end(), 0.0);
    }
};

double median_of(std::vector<double> v) {
    if (v.empty()) return 0.0;
    const size_t m = v.size() / 2;
    std::nth_element(v.begin(), v.begin() + m, v.end());
    return v[m];
}
double quantile_of(std::vector<double> v, double q) {
    if (v.empty()) return 0.0;
    const size_t m = std::min(v.size() - 1, size_t(q * double(v.size())));
    std::nth_element(v.begin(), v.begin() + m, v.end());
    return v[m];
}

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
    m_slope_orig = max_slope(orig);
    m_slope_low = max_slope(low);
    const size_t n = size_t(M) * M * m_bins * m_bins * 3;
    for (auto *v : {&m_n1, &m_n1sq, &m_d, &m_dsq, &m_n1x}) v->assign(n, 0.0);
    if (opt.interreflections)
        for (auto *v : {&m_nir, &m_nirsq, &m_nirx}) v->assign(n, 0.0);
    if (opt.cv_lines > 0)
        for (auto *v : {&m_cv, &m_cvsq}) v->assign(n, 0.0);
    m_count_cv.assign(size_t(M) * M * m_bins, 0);
    m_stats.estimator_bytes = ((opt.interreflections ? 8 : 5) + (opt.cv_lines > 0 ? 2 : 0)) * n * sizeof(double) +
                              3 * size_t(M) * M * m_bins * sizeof(uint32_t);
    m_count_orig.assign(size_t(M) * M * m_bins, 0);
    m_count_low.assign(size_t(M) * M * m_bins, 0);
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
    PCG32 rng;              ///< the original's path continuations (lines and f'_low node sets have their own streams)
    std::vector<Vec3> wi;   ///< ωi of every bin for the current line (one random shift of the grid per line)
    std::vector<Spectrum> fl;  ///< f'_low(ωi of every bin, ωo) of the current line
    std::vector<size_t> vis;   ///< f'_low's nodes facing ωo ...
    std::vector<double> vw;    ///< ... and their weights c_k
    size_t orig_lines = 0, vertices = 0, rejected = 0, leaked = 0;  ///< the original's lines
    uint32_t acc_orig = 0, acc_cv = 0;
    size_t cv_lines = 0;
    /// Per level of the group: accepted, traced, rejected and leaked h_low lines, thread time.
    std::vector<uint32_t> acc_low;
    std::vector<size_t> low_lines, low_rejected, low_leaked;
    std::vector<double> t_low;

    Task(ScalingEstimator &e, const std::vector<ScalingEstimator *> &g, size_t t, uint64_t seed)
        : est(e), group(g), task(t), round_seed(seed), M(e.m_opt.M), N(e.m_opt.N), B(e.m_bins),
          pa(int(t / size_t(B)) % M), pb(int(t / size_t(B)) / M), box(int(t % size_t(B)) % N),
          boy(int(t % size_t(B)) / N), base_idx(t * size_t(B) * 3), cv(e.m_opt.cv_lines > 0),
          rng(hash_combine(seed, uint64_t(t)), mix_bits(seed ^ 0x5ca1eULL)), wi(static_cast<size_t>(B)),
          fl(static_cast<size_t>(B)), acc_low(g.size(), 0), low_lines(g.size(), 0), low_rejected(g.size(), 0),
          low_leaked(g.size(), 0), t_low(g.size(), 0.0) {}

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
    /// ωo jittered in its bin; every ωi bin on one shifted copy of the grid (fills `wi`).
    void draw_directions(PCG32 &lr, Vec3 &wo) {
        wo = square_to_hemisphere(Vec2((float(box) + lr.next_float()) / float(N), (float(boy) + lr.next_float()) / float(N)));
        const float sa = lr.next_float(), sb = lr.next_float();
        for (int b = 0; b < B; ++b)
            wi[size_t(b)] = square_to_hemisphere(Vec2((float(b % N) + sa) / float(N), (float(b / N) + sb) / float(N)));
    }
    /// Patch P of this task in a field's cell space.
    PatchRegion patch_of(const Heightfield &hf) const {
        const double cw = double(hf.width()) / M, ch = double(hf.height()) / M;
        return PatchRegion{pa * cw, pb * ch, (pa + 1) * cw, (pb + 1) * ch};
    }
    /// Shoots line k of K (stratified when K is a perfect square) on field `hf` over patch R;
    /// the first vertex, or false (counted as leaked or rejected).
    bool shoot(PCG32 &lr, const Heightfield &hf, const PatchRegion &R, Vec3 wo, int k, int K, bool macro, Vertex &v) {
        const ShootingRegion Q = shooting_region(hf, R, wo);
        const int g = perfect_square_root(K);
        double sx, sy;
        if (g > 0) {
            sx = (double(k % g) + lr.next_double()) / g;
            sy = (double(k / g) + lr.next_double()) / g;
        } else {
            sx = lr.next_double();
            sy = lr.next_double();
        }
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
    bool start_line(const Heightfield &hf, const PatchRegion &R, int k, int K, bool macro, Vec3 &wo, Vertex &v,
                    size_t &lines) {
        PCG32 lr = line_rng(k);
        draw_directions(lr, wo);
        ++lines;
        return shoot(lr, hf, R, wo, k, K, macro, v);
    }

    // --- the original microgeometry: paths, next-event towards every ωi bin -----------------
    /// Next-event terms of vertex v (seen from local lwo) towards every ωi bin: eq. 6's
    /// integrand at the first vertex (buf.a), eq. 17's at every vertex (buf.b).
    void splat_original_vertex(const Vertex &v, Vec3 lwo, const Spectrum &throughput, int depth, LineBuf &buf) {
        const Frame &fr = v.ctx.frame;
        const Vec3 org = spawn_origin(v);
        for (int b = 0; b < B; ++b) {
            const Vec3 lwi = fr.to_local(wi[size_t(b)]);
            if (!(lwi.z > 0.f)) continue;
            const Spectrum f = est.m_base.eval(v.ctx, lwo, lwi);
            if (f.is_black()) continue;
            if (depth == 1 && cv) {
                double *pc = &buf.c[size_t(b) * 3];
                for (int q = 0; q < 3; ++q) pc[q] += f[q];
            }
            if (!unoccluded_by_slope(wi[size_t(b)], est.m_slope_orig) &&
                est.m_orig.occluded(org, wi[size_t(b)], 0.f, Infinity, v.ox, v.oy))
                continue;
            const Spectrum c = throughput * f;
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
            const float scale = float(total / J);
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
        for (int b = 0; b < B; ++b) {
            const Vec3 &w = wi[size_t(b)];
            const Spectrum &f = fl[size_t(b)];
            if (f.is_black() || !(dot(v.n, w) > 0.f)) continue;  // below the h_low facet: self-shadowed
            if (!unoccluded_by_slope(w, le.m_slope_low) && le.m_low.occluded(org, w, 0.f, Infinity, v.ox, v.oy))
                continue;
            double *p = &out.a[size_t(b) * 3];
            for (int q = 0; q < 3; ++q) p[q] += f[q];
        }
        return true;
    }

    /// Adds one line's terms to this task's slice of `sum`.
    void add_line(std::vector<double> &sum, const std::vector<double> &line) {
        for (size_t q = 0; q < size_t(B) * 3; ++q) sum[base_idx + q] += line[q];
    }
    /// Pair terms (scaling.h, "Standard errors") of lines x (numerator) and y (denominator):
    /// Σ (x0 - x1)² into sq, Σ (y0 - y1)² into dsq, Σ (x0 - x1)(y0 - y1) into cross; a null
    /// partner (the unpaired last line) counts as 0; null sq / dsq / cross skip that term.
    void add_pair(const std::vector<double> *x0, const std::vector<double> *x1, const std::vector<double> *y0,
                  const std::vector<double> *y1, std::vector<double> *sq, std::vector<double> *dsq,
                  std::vector<double> *cross) {
        for (size_t q = 0; q < size_t(B) * 3; ++q) {
            const double dx = x0 ? (*x0)[q] - (x1 ? (*x1)[q] : 0.0) : 0.0;
            const double dy = y0 ? (*y0)[q] - (y1 ? (*y1)[q] : 0.0) : 0.0;
            if (sq) (*sq)[base_idx + q] += dx * dx;
            if (dsq) (*dsq)[base_idx + q] += dy * dy;
            if (cross) (*cross)[base_idx + q] += dx * dy;
        }
    }
    /// Both fields' lines in consecutive pairs: sums, pair differences and, when both fields
    /// trace the same number of lines (line k shares its random numbers), the cross terms. Each
    /// line on the original is traced once and its terms go to every level of the group; each
    /// level traces its own h_low line k.
    void trace_lines(double &t_orig) {
        const int Ko = est.m_opt.orig_paths, Kl = est.m_opt.low_paths;
        const bool ir = est.m_opt.interreflections, paired = Ko == Kl;
        const size_t G = group.size();
        LineBuf o[2] = {LineBuf(B), LineBuf(B)};
        std::vector<LineBuf> l(2 * G, LineBuf(B));  // level j's pair: l[2 j], l[2 j + 1]
        for (int k = 0; k < std::max(Ko, Kl); ++k) {
            const int s = k & 1;
            if (k < Ko) {
                const auto t0 = Clock::now();
                o[s].clear();
                if (trace_original_line(k, Ko, o[s])) {
                    ++acc_orig;
                    if (cv)  // g - c (scaling.h, "Control variate")
                        for (size_t q = 0; q < size_t(B) * 3; ++q) o[s].a[q] -= o[s].c[q], o[s].b[q] -= o[s].c[q];
                    for (ScalingEstimator *e : group) {
                        add_line(e->m_n1, o[s].a);
                        if (ir) add_line(e->m_nir, o[s].b);
                    }
                }
                t_orig += seconds_since(t0);
            }
            for (size_t j = 0; j < G && k < Kl; ++j) {
                const auto t0 = Clock::now();
                LineBuf &lb = l[2 * j + size_t(s)];
                lb.clear();
                if (trace_low_line(*group[j], j, k, Kl, lb)) {
                    ++acc_low[j];
                    add_line(group[j]->m_d, lb.a);
                }
                t_low[j] += seconds_since(t0);
            }
            // A complete pair (k - 1, k) of a field, or its unpaired last line k (partner 0).
            const bool o_pair = k < Ko && (s == 1 || k == Ko - 1), l_pair = k < Kl && (s == 1 || k == Kl - 1);
            if (!o_pair && !l_pair) continue;
            const bool whole = s == 1;
            for (size_t j = 0; j < G; ++j) {
                ScalingEstimator &e = *group[j];
                const LineBuf &l0 = l[2 * j], &l1 = l[2 * j + 1];
                add_pair(o_pair ? &o[0].a : nullptr, o_pair && whole ? &o[1].a : nullptr, l_pair ? &l0.a : nullptr,
                         l_pair && whole ? &l1.a : nullptr, o_pair ? &e.m_n1sq : nullptr, l_pair ? &e.m_dsq : nullptr,
                         paired ? &e.m_n1x : nullptr);
                if (ir && o_pair)
                    add_pair(&o[0].b, whole ? &o[1].b : nullptr, paired ? &l0.a : nullptr, paired && whole ? &l1.a : nullptr,
                             &e.m_nirsq, nullptr, paired ? &e.m_nirx : nullptr);
            }
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
            c[s].clear();
            PCG32 lr(hash_combine(hash_combine(round_seed ^ 0xc0417a1eULL, uint64_t(task)), uint64_t(k)),
                     mix_bits(round_seed ^ 0xcfULL));
            Vec3 wo;
            draw_directions(lr, wo);
            Vertex v;
            ++cv_lines;
            if (shoot(lr, est.m_orig, R, wo, k, K, false, v)) {
                ++acc_cv;
                if (const Vec3 lwo = v.ctx.frame.to_local(wo); lwo.z > 0.f)
                    for (int b = 0; b < B; ++b) {
                        const Vec3 lwi = v.ctx.frame.to_local(wi[size_t(b)]);
                        if (!(lwi.z > 0.f)) continue;
                        const Spectrum f = est.m_base.eval(v.ctx, lwo, lwi);
                        for (int q = 0; q < 3; ++q) c[s].a[size_t(b) * 3 + size_t(q)] = f[q];
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
            e.m_count_orig[task] += acc_orig;
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
            eo.orig_paths != lo.orig_paths || eo.low_paths != lo.low_paths || eo.cv_lines != lo.cv_lines ||
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
    return active.size();
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
    for (std::vector<double> *a : {&m_n1, &m_n1sq, &m_nir, &m_nirsq, &m_d, &m_dsq, &m_n1x, &m_nirx, &m_cv, &m_cvsq})
        share(*a, per);
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

double ScalingEstimator::denom_mean(int ch) const {
    double s = 0;
    size_t n = 0;
    const size_t tasks = size_t(m_opt.M) * m_opt.M * m_bins;
    for (size_t t = 0; t < tasks; ++t) {
        const double c = m_count_low[t];
        if (c == 0) continue;
        for (int b = 0; b < m_bins; ++b) s += m_d[(t * m_bins + b) * 3 + ch] / c;
        n += size_t(m_bins);
    }
    return n ? s / double(n) : 0.0;
}

ScalingEstimator::BinMoments ScalingEstimator::bin_moments(int patch, int bi, int bo, int ch, bool ir) const {
    const size_t t = size_t(patch) * m_bins + bo;
    const size_t k = (t * m_bins + bi) * 3 + ch;
    BinMoments b;
    b.lines_orig = m_count_orig[t], b.lines_low = m_count_low[t];
    const double no = b.lines_orig, nl = b.lines_low;
    if (no > 0) {
        b.num = (ir ? m_nir[k] : m_n1[k]) / no;
        b.num_se = std::sqrt((ir ? m_nirsq[k] : m_n1sq[k])) / no;
        if (const double nc = m_count_cv[t]; nc > 0)
            b.num += m_cv[k] / nc, b.num_se = std::hypot(b.num_se, std::sqrt(m_cvsq[k]) / nc);
    }
    if (nl > 0) b.den = m_d[k] / nl, b.den_se = std::sqrt(m_dsq[k]) / nl;
    return b;
}

double ScalingEstimator::R(int patch, int bi, int bo, int ch, bool ir) const {
    const size_t t = size_t(patch) * m_bins + bo;
    const size_t k = (t * m_bins + bi) * 3 + ch;
    const double no = m_count_orig[t], nl = m_count_low[t];
    const double eps = m_opt.epsilon * denom_mean(ch);
    const double nc = m_count_cv[t];
    const double num = (no > 0 ? (ir ? m_nir[k] : m_n1[k]) / no : 0.0) + (nc > 0 ? m_cv[k] / nc : 0.0);
    const double den = nl > 0 ? m_d[k] / nl : 0.0;
    return (num + eps) / (den + eps);
}

namespace {

/// Per (patch P, bin pair j = bo B + bi, channel): the sample means of eq. 12's numerator
/// (the original's f_eff·cos θi, integrated over the two bins) and denominator (the same on
/// h_low with f'_low), the variances of those means and their covariance (scaling.h,
/// "Standard errors").
struct BinPairMoments {
    size_t BB = 0;  ///< angular bin pairs (bo, bi), index bo B + bi
    std::vector<double> num, den, vnum, vden, cov;
    size_t at(int p, size_t j, int c) const { return (size_t(p) * BB + j) * 3 + c; }
};

/// The sums of one table set (numerator `sum`, its pair-difference squares `sq`, denominator
/// `dsum`/`dsq`, the cross terms `cross`) as means, variances and covariances of the means.
BinPairMoments bin_pair_moments(const std::vector<double> &sum, const std::vector<double> &sq,
                                const std::vector<double> &dsum, const std::vector<double> &dsq,
                                const std::vector<double> &cross, const std::vector<uint32_t> &count_orig,
                                const std::vector<uint32_t> &count_low, const std::vector<double> &cv,
                                const std::vector<double> &cvsq, const std::vector<uint32_t> &count_cv, int P, int B) {
    BinPairMoments m;
    m.BB = size_t(B) * B;
    const size_t n_all = size_t(P) * m.BB * 3;
    m.num.resize(n_all), m.den.resize(n_all), m.vnum.resize(n_all), m.vden.resize(n_all), m.cov.resize(n_all);
    tbb::parallel_for(size_t(0), size_t(P) * B, [&](size_t t) {
        const double no = count_orig[t], nl = count_low[t], nc = cv.empty() ? 0.0 : count_cv[t];
        for (size_t k = t * B * 3; k < (t + 1) * B * 3; ++k) {
            m.num[k] = (no > 0 ? sum[k] / no : 0.0) + (nc > 0 ? cv[k] / nc : 0.0);
            m.vnum[k] = (no > 0 ? sq[k] / (no * no) : 0.0) + (nc > 0 ? cvsq[k] / (nc * nc) : 0.0);
            m.den[k] = nl > 0 ? dsum[k] / nl : 0.0;
            m.vden[k] = nl > 0 ? dsq[k] / (nl * nl) : 0.0;
            m.cov[k] = no > 0 && nl > 0 ? cross[k] / (no * nl) : 0.0;
        }
    });
    return m;
}

/// T (P x 3, mean 1 per channel) and S (BB x 3) of one table set, and per channel the
/// regularisation they were made with (the rank-1 check regularises R~ the same way).
struct Rank1Factors {
    std::vector<double> T, S;
    // Raw (before T's normalisation to mean 1) global ratio, cap and ε per channel.
    double S_global[3] = {1, 1, 1}, S_cap[3] = {0, 0, 0}, eps_bin[3] = {0, 0, 0}, T_mean[3] = {1, 1, 1};
};

/// Rank-1 factorisation of channel c by marginal matching (iterative proportional fitting):
///   S_b = Σ_P num_Pb / Σ_P T_P den_Pb,   T_P = Σ_b num_Pb / Σ_b S_b den_Pb,
/// so that T S f'_low reproduces the original's reflected energy in every bin pair (summed
/// over patches) and in every patch (summed over bin pairs). For an exactly rank-1 R it
/// returns R's factors; eq. 22-24 (means of per-bin ratios) are the same in that case but
/// divide by every noisy, near-empty denominator (see scaling.h).
void fit_rank1_channel(const BinPairMoments &m, int P, int c, double epsilon, Rank1Factors &f) {
    const size_t BB = m.BB;
    std::vector<double> &T = f.T, &S = f.S;
    double dtot = 0, ntot = 0;
    for (int p = 0; p < P; ++p)
        for (size_t j = 0; j < BB; ++j) dtot += m.den[m.at(p, j, c)], ntot += m.num[m.at(p, j, c)];
    // Regularisation (the ε of eq. 12, relative): a bin pair whose denominator is small
    // against eps_b is pulled towards the global ratio S_g = Σ num / Σ den, and S is
    // capped at the largest value of the bins whose denominator is reliable (≥ 10% of
    // the mean): where f'_low reflects (almost) nothing, S cannot restore the
    // original's light anyway, and an unbounded ratio would leak into the neighbouring
    // bins through the interpolation (e.g. grazing ωo where eq. 5 culls a facet family).
    const double S_g = dtot > 0 && ntot > 0 ? ntot / dtot : 1.0;
    const double eps_b = epsilon * dtot / double(BB);  // per bin pair, summed over patches
    // A patch sums over every bin pair: its total is never near zero unless the patch is
    // black; ε there only guards the division (a relative ε would bias T towards 1).
    const double eps_p = 1e-9 * dtot / double(P) + 1e-300;
    f.S_global[c] = S_g, f.eps_bin[c] = eps_b;
    for (int it = 0; it < 30; ++it) {
        double cap = 0;
        for (size_t j = 0; j < BB; ++j) {
            double a = 0, d = 0;
            for (int p = 0; p < P; ++p) a += m.num[m.at(p, j, c)], d += T[size_t(p) * 3 + c] * m.den[m.at(p, j, c)];
            S[j * 3 + c] = (a + eps_b * S_g) / (d + eps_b);
            if (d >= 0.1 * dtot / double(BB)) cap = std::max(cap, S[j * 3 + c]);
        }
        if (cap > 0)
            for (size_t j = 0; j < BB; ++j) S[j * 3 + c] = std::min(S[j * 3 + c], cap);
        f.S_cap[c] = cap;
        double change = 0;
        for (int p = 0; p < P; ++p) {
            double a = 0, d = 0;
            for (size_t j = 0; j < BB; ++j) a += m.num[m.at(p, j, c)], d += S[j * 3 + c] * m.den[m.at(p, j, c)];
            const double t = (a + eps_p) / (d + eps_p);
            change = std::max(change, std::abs(t / T[size_t(p) * 3 + c] - 1.0));
            T[size_t(p) * 3 + c] = t;
        }
        if (change < 1e-7) break;
    }
    double mean = 0;
    for (int p = 0; p < P; ++p) mean += T[size_t(p) * 3 + c] / P;
    if (mean > 0) {
        for (int p = 0; p < P; ++p) T[size_t(p) * 3 + c] /= mean;
        for (size_t j = 0; j < BB; ++j) S[j * 3 + c] *= mean;
        f.T_mean[c] = mean;
    }
}

/// T and S into the tables (M x M and N² x N² images, model.h's layout).
void write_tables(const Rank1Factors &f, int M, int N, ScalingTables &tab) {
    const int B = N * N, P = M * M;
    tab.M = M, tab.N = N;
    tab.T = Image(M, M, 3);
    tab.S = Image(N * N, N * N, 3);
    for (int p = 0; p < P; ++p)
        for (int c = 0; c < 3; ++c) tab.T.at(p % M, p / M, c) = float(f.T[size_t(p) * 3 + c]);
    for (size_t j = 0; j < size_t(B) * B; ++j) {
        const int bo = int(j / size_t(B)), bi = int(j % size_t(B));
        tab.set_S_bin(bi, bo, Spectrum(float(f.S[j * 3]), float(f.S[j * 3 + 1]), float(f.S[j * 3 + 2])));
    }
}

/// What one table set reached: ScalingStats' fields for `single` or `ir`.
struct TableStats {
    double med = 0, p90 = 0, mx = 0, med_outer = 0, med_paper = 0, t_max = 0, t_med = 0, energy = 0, svd_err = 0,
           ts_err = 0, paper_err = 0;
    std::vector<double> sv;
    std::vector<double> pair_rel;  ///< S's relative standard error per bin pair j (-1: not estimated)
};

/// Relative standard error of a / d (delta method) from the variances and covariance.
double ratio_rel_se(double a, double va, double d, double vd, double cov) {
    return std::sqrt(std::max(0.0, va / (a * a) + vd / (d * d) - 2.0 * cov / (a * d)));
}

/// Relative standard errors of S (per bin pair, T fixed) and T (per patch, S fixed), green;
/// and of S at the paper's counts (2500 paths per effective BRDF; numerator and denominator
/// independent there).
void standard_errors(const BinPairMoments &m, const Rank1Factors &f, const std::vector<uint32_t> &count_orig,
                     const std::vector<uint32_t> &count_low, int P, int N, TableStats &o) {
    const int B = N * N;
    const size_t BB = m.BB;
    std::vector<double> s_rel, s_rel_outer, s_rel_paper;
    o.pair_rel.assign(BB, -1.0);
    auto outer = [&](int b) { return b % N == 0 || b % N == N - 1 || b / N == 0 || b / N == N - 1; };
    for (size_t j = 0; j < BB; ++j) {
        const int bo = int(j / size_t(B)), bi = int(j % size_t(B));
        double a = 0, va = 0, d = 0, vd = 0, cv = 0, va_p = 0, vd_p = 0;
        for (int p = 0; p < P; ++p) {
            const double t = f.T[size_t(p) * 3 + 1];
            const size_t task = size_t(p) * B + size_t(bo), k = m.at(p, j, 1);
            a += m.num[k], va += m.vnum[k];
            d += t * m.den[k], vd += t * t * m.vden[k], cv += t * m.cov[k];
            va_p += m.vnum[k] * count_orig[task] / 2500.0;
            vd_p += t * t * m.vden[k] * count_low[task] / 2500.0;
        }
        if (a > 0 && d > 0) {
            const double rel = ratio_rel_se(a, va, d, vd, cv);
            o.pair_rel[j] = rel;
            s_rel_paper.push_back(std::sqrt(va_p / (a * a) + vd_p / (d * d)));
            s_rel.push_back(rel);
            if (outer(bi) && outer(bo)) s_rel_outer.push_back(rel);
        }
    }
    o.med = median_of(s_rel);
    o.p90 = quantile_of(s_rel, 0.9);
    o.mx = s_rel.empty() ? 0.0 : *std::max_element(s_rel.begin(), s_rel.end());
    o.med_outer = median_of(s_rel_outer);
    o.med_paper = median_of(s_rel_paper);
    std::vector<double> t_rel;
    for (int p = 0; p < P; ++p) {
        double a = 0, va = 0, d = 0, vd = 0, cv = 0;
        for (size_t j = 0; j < BB; ++j) {
            const double sj = f.S[j * 3 + 1];
            const size_t k = m.at(p, j, 1);
            a += m.num[k], va += m.vnum[k];
            d += sj * m.den[k], vd += sj * sj * m.vden[k], cv += sj * m.cov[k];
        }
        if (a > 0 && d > 0) t_rel.push_back(ratio_rel_se(a, va, d, vd, cv));
    }
    o.t_max = t_rel.empty() ? 0.0 : *std::max_element(t_rel.begin(), t_rel.end());
    o.t_med = median_of(t_rel);
}

/// The bin pairs whose centres are both at θ <= 75° (paper 004 excludes the others from its
/// rank-1 figures); all pairs when there is none.
std::vector<size_t> rank1_check_columns(int N) {
    const int B = N * N;
    const size_t BB = size_t(B) * B;
    std::vector<size_t> cols;
    for (size_t j = 0; j < BB; ++j) {
        const int bo = int(j / size_t(B)), bi = int(j % size_t(B));
        auto theta_ok = [&](int b) {
            const Vec3 w = square_to_hemisphere(Vec2((b % N + 0.5f) / N, (b / N + 0.5f) / N));
            return w.z >= std::cos(75.0 * Pi / 180.0) - 1e-6;
        };
        if (theta_ok(bo) && theta_ok(bi)) cols.push_back(j);
    }
    if (cols.empty())
        for (size_t j = 0; j < BB; ++j) cols.push_back(j);
    return cols;
}

/// Rank-1 check (green), as paper 004 Fig. 6: the sampled R~ per patch and bin pair,
/// regularised as S is (pulled towards S_g by eps_b / P, capped at S's cap), over
/// rank1_check_columns (for this diagnostic only); its SVD against this factorisation and
/// eq. 22-24's.
void rank1_check(const BinPairMoments &m, const Rank1Factors &f, int P, int N, TableStats &o) {
    const std::vector<size_t> cols = rank1_check_columns(N);
    Eigen::MatrixXd A(P, Eigen::Index(cols.size()));
    for (size_t c = 0; c < cols.size(); ++c) {
        const size_t j = cols[c];
        const double e = f.eps_bin[1] / P;
        for (int p = 0; p < P; ++p) {
            double r = (m.num[m.at(p, j, 1)] + e * f.S_global[1]) / (m.den[m.at(p, j, 1)] + e);
            if (f.S_cap[1] > 0) r = std::min(r, f.S_cap[1] * f.T[size_t(p) * 3 + 1] * f.T_mean[1]);
            A(p, Eigen::Index(c)) = r;
        }
    }
    // σk² = the eigenvalues of A Aᵀ (P x P: small).
    const Eigen::MatrixXd G = A * A.transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(G);
    std::vector<double> lam;
    for (int p = 0; p < P; ++p) lam.push_back(std::max(0.0, es.eigenvalues()(p)));
    std::sort(lam.rbegin(), lam.rend());
    double tot = 0;
    for (double l : lam) tot += l;
    o.sv.clear();
    for (double l : lam) o.sv.push_back(std::sqrt(l));
    o.energy = tot > 0 ? lam[0] / tot : 1.0;
    o.svd_err = tot > 0 ? std::sqrt(std::max(0.0, 1.0 - lam[0] / tot)) : 0.0;
    // Eq. 22-24 on the same R~: S' = mean over patches, T' = mean over bins / its mean.
    const size_t C = cols.size();
    std::vector<double> Sp(C, 0.0), Tp(size_t(P), 0.0);
    for (int p = 0; p < P; ++p)
        for (size_t c = 0; c < C; ++c) Sp[c] += A(p, Eigen::Index(c)) / P, Tp[size_t(p)] += A(p, Eigen::Index(c)) / double(C);
    double tm = 0;
    for (double t : Tp) tm += t / P;
    double e_ts = 0, e_paper = 0;
    for (int p = 0; p < P; ++p)
        for (size_t c = 0; c < C; ++c) {
            const double r = A(p, Eigen::Index(c));
            const double a = r - f.T[size_t(p) * 3 + 1] * f.S[cols[c] * 3 + 1], b = r - Tp[size_t(p)] / tm * Sp[c];
            e_ts += a * a, e_paper += b * b;
        }
    o.ts_err = tot > 0 ? std::sqrt(e_ts / tot) : 0.0;
    o.paper_err = tot > 0 ? std::sqrt(e_paper / tot) : 0.0;
}

}  // namespace

void ScalingEstimator::finish(ScalingTables &single, ScalingTables &ir_tab, ScalingStats &stats) const {
    finish_impl(single, ir_tab, stats, nullptr);
}

namespace {
/// Per ωo bin, the median over ωi bins of the per-pair relative standard errors (-1 entries
/// skipped; 0 when none).
void per_wo_bin_medians(const std::vector<double> &pair_rel, int B, std::vector<double> &out) {
    out.assign(size_t(B), 0.0);
    std::vector<double> v;
    for (int bo = 0; bo < B; ++bo) {
        v.clear();
        for (int bi = 0; bi < B; ++bi)
            if (const double r = pair_rel[size_t(bo) * B + bi]; r >= 0) v.push_back(r);
        out[size_t(bo)] = median_of(v);
    }
}
}  // namespace

void ScalingEstimator::finish_impl(ScalingTables &single, ScalingTables &ir_tab, ScalingStats &stats,
                                   std::vector<double> *per_bo) const {
    const int M = m_opt.M, N = m_opt.N, B = m_bins, P = M * M;
    stats = m_stats;
    // One table set: moments, rank-1 factors, tables, then the diagnostics of the fit.
    auto build = [&](bool use_ir, ScalingTables &tab, TableStats &o) {
        const BinPairMoments m = bin_pair_moments(use_ir ? m_nir : m_n1, use_ir ? m_nirsq : m_n1sq, m_d, m_dsq,
                                                  use_ir ? m_nirx : m_n1x, m_count_orig, m_count_low, m_cv, m_cvsq,
                                                  m_count_cv, P, B);
        Rank1Factors f;
        f.T.assign(size_t(P) * 3, 1.0);
        f.S.assign(m.BB * 3, 1.0);
        for (int c = 0; c < 3; ++c) fit_rank1_channel(m, P, c, m_opt.epsilon, f);
        write_tables(f, M, N, tab);
        standard_errors(m, f, m_count_orig, m_count_low, P, N, o);
        if (!per_bo) rank1_check(m, f, P, N, o);
    };
    TableStats o1;
    build(false, single, o1);
    stats.S_rel_se_median = o1.med, stats.S_rel_se_p90 = o1.p90, stats.S_rel_se_max = o1.mx;
    stats.S_rel_se_median_outer = o1.med_outer, stats.T_rel_se_max = o1.t_max, stats.T_rel_se_median = o1.t_med;
    stats.rank1_energy = o1.energy, stats.rank1_svd_rel_error = o1.svd_err, stats.ts_rel_error = o1.ts_err;
    stats.paper_ts_rel_error = o1.paper_err;
    stats.S_rel_se_median_paper_counts = o1.med_paper;
    stats.singular_values = o1.sv;
    if (per_bo) per_wo_bin_medians(o1.pair_rel, B, *per_bo);
    if (m_opt.interreflections) {
        TableStats o2;
        build(true, ir_tab, o2);
        stats.S_ir_rel_se_median = o2.med, stats.S_ir_rel_se_p90 = o2.p90;
        stats.S_ir_rel_se_median_outer = o2.med_outer, stats.T_ir_rel_se_max = o2.t_max;
        stats.T_ir_rel_se_median = o2.t_med;
        stats.rank1_energy_ir = o2.energy, stats.rank1_svd_rel_error_ir = o2.svd_err, stats.ts_rel_error_ir = o2.ts_err;
        stats.paper_ts_rel_error_ir = o2.paper_err;
        stats.S_ir_rel_se_median_paper_counts = o2.med_paper;
        stats.singular_values_ir = o2.sv;
        if (per_bo) {
            std::vector<double> ir_bo;
            per_wo_bin_medians(o2.pair_rel, B, ir_bo);
            for (int b = 0; b < B; ++b) (*per_bo)[size_t(b)] = std::max((*per_bo)[size_t(b)], ir_bo[size_t(b)]);
        }
    } else {
        ir_tab = ScalingTables{};
    }
}

double ScalingEstimator::current_S_rel_se() const {
    ScalingTables a, b;
    ScalingStats s;
    std::vector<double> per_bo;
    finish_impl(a, b, s, &per_bo);
    return m_opt.interreflections ? std::max(s.S_rel_se_median, s.S_ir_rel_se_median) : s.S_rel_se_median;
}

std::vector<double> ScalingEstimator::S_rel_se_per_wo_bin() const {
    ScalingTables a, b;
    ScalingStats s;
    std::vector<double> per_bo;
    finish_impl(a, b, s, &per_bo);
    return per_bo;
}

}  // namespace meso::prefilter
