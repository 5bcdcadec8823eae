// Effective BRDF estimators (paper 004, eq. 6-8 and 15-17): see effective_brdf.h for the
// normalisation, the shooting construction and the units.
#include "prefilter/effective_brdf.h"
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <algorithm>
#include <cmath>
#include <fmt/format.h>
#include <vector>
#include "core/error.h"
#include "core/frame.h"
#include "geometry/shading.h"
#include "sampling/rng.h"
#include "sampling/warp.h"
#include "prefilter/micro_vertex.h"

namespace meso::prefilter {
using namespace detail;
namespace {

/// Per-chunk sums (double, per channel) of the per-sample contributions of accepted samples.
struct Sums {
    size_t accepted = 0, leaked = 0, vertices = 0;
    double sum[3] = {0, 0, 0}, sum2[3] = {0, 0, 0};
};

Vec3 checked_direction(Vec3 w, const char *name) {
    const double l = std::sqrt(double(w.x) * w.x + double(w.y) * w.y + double(w.z) * w.z);
    if (!std::isfinite(l) || !(l > 0))
        throw MesoError(fmt::format("effective BRDF: direction {} = ({}, {}, {}) is zero or not finite", name, w.x,
                                    w.y, w.z));
    return Vec3(float(w.x / l), float(w.y / l), float(w.z / l));
}

}  // namespace

EffectiveBrdfEstimator::EffectiveBrdfEstimator(const Heightfield &hf, const Material &base, Options options)
    : m_hf(hf), m_base(base), m_opt(options) {
    if (hf.width() < 1 || hf.height() < 1) throw MesoError("effective BRDF: the heightfield is empty");
    if (m_opt.chunk == 0) m_opt.chunk = 4096;
}

EffectiveBrdfEstimator::Estimate EffectiveBrdfEstimator::estimate(const PatchRegion &region, Vec3 wi, Vec3 wo,
                                                                  size_t samples, uint64_t seed,
                                                                  int max_bounces) const {
    wi = checked_direction(wi, "wi");
    return run(region, &wi, wo, samples, seed, max_bounces);
}

EffectiveBrdfEstimator::Estimate EffectiveBrdfEstimator::albedo(const PatchRegion &region, Vec3 wo, size_t samples,
                                                                uint64_t seed, int max_bounces) const {
    return run(region, nullptr, wo, samples, seed, max_bounces);
}

namespace {

/// Lines of sight of EffectiveBrdfEstimator::run and their paths: shot along -wo from the
/// region Q over patch R (see the header), next-event terms towards wi at every vertex.
struct PathSampler {
    const Heightfield &hf;
    const Material &base;
    const EffectiveBrdfEstimator::Options &opt;
    const PatchRegion &R;
    const ShootingRegion Q;
    const Vec3 *wi_fixed;  ///< null: albedo mode (a cosine-distributed wi per line)
    const Vec3 wo;
    const int max_bounces;

    /// One line of sight plus its path; false when the first hit is not in P (`leak`: no hit).
    bool sample(PCG32 &rng, Spectrum &contrib, bool &leak, size_t &vertices) const {
        leak = false;
        contrib = Spectrum(0.f);
        Vec3 wi;
        float inv_pdf = 1.f;
        // Draw the light direction first (albedo mode) so that a sample's randomness is
        // laid out the same way whatever happens along its path.
        if (wi_fixed) {
            wi = *wi_fixed;
        } else {
            const float u0 = rng.next_float(), u1 = rng.next_float();
            wi = square_to_cosine_hemisphere(Vec2(u0, u1));
            const float pdf = square_to_cosine_hemisphere_pdf(wi);
            inv_pdf = pdf > 0.f ? 1.f / pdf : 0.f;
        }
        const double qx = Q.x0 + (Q.x1 - Q.x0) * rng.next_double(), qy = Q.y0 + (Q.y1 - Q.y0) * rng.next_double();
        const double fqx = std::floor(qx), fqy = std::floor(qy);
        const int64_t ox = int64_t(fqx), oy = int64_t(fqy);
        const Vec3 o(float(qx - fqx), float(qy - fqy), float(Q.z_top));
        HeightfieldHit hit;
        if (!hf.intersect(o, -wo, 0.f, Infinity, hit, ox, oy)) {
            leak = true;
            return false;
        }
        const Vertex v = make_vertex(hf, hit, ox, oy, opt.macro_frame);
        if (!Q.wrap_x) {
            const double ax = double(ox) + double(hit.x);
            if (ax < R.x0 || ax >= R.x1) return false;
        }
        if (!Q.wrap_y) {
            const double ay = double(oy) + double(hit.y);
            if (ay < R.y0 || ay >= R.y1) return false;
        }
        if (inv_pdf == 0.f) return true;  // the rim of the disk: a zero sample, still counted
        contrib = path_sum(rng, v, wi, vertices) * inv_pdf;
        return true;
    }

    /// The path from first vertex v (eq. 15-16): Σ_k throughput_k f(x_k) towards wi, unshadowed.
    Spectrum path_sum(PCG32 &rng, Vertex v, Vec3 wi, size_t &vertices) const {
        Spectrum throughput(1.f), sum(0.f);
        Vec3 w_out = wo;  // towards the previous vertex (the viewer for x_1)
        for (int k = 1;; ++k) {
            ++vertices;
            const Frame &fr = v.ctx.frame;
            const Vec3 lwo = fr.to_local(w_out);
            if (!(lwo.z > 0.f)) break;  // round-off at a grazing hit: the path sees the back
            const Vec3 lwi = fr.to_local(wi);
            if (lwi.z > 0.f && dot(v.n, wi) > 0.f) {
                const Spectrum f = base.eval(v.ctx, lwo, lwi);
                if (!f.is_black() && !hf.occluded(spawn_origin(v), wi, 0.f, Infinity, v.ox, v.oy))
                    sum += throughput * f;
            }
            if (k >= max_bounces) break;
            // Continue by sampling the base material.
            const float u_lobe = rng.next_float(), u0 = rng.next_float(), u1 = rng.next_float();
            BSDFSample bs;
            if (!base.sample(v.ctx, lwo, u_lobe, Vec2(u0, u1), bs) || bs.weight.is_black() || !(bs.wi.z > 0.f))
                break;
            throughput *= bs.weight;
            if (opt.roulette_start > 0 && k >= opt.roulette_start) {
                const float q = std::min(1.f, throughput.max());
                if (!(rng.next_float() < q)) break;
                throughput *= 1.f / q;
            }
            const Vec3 dir = normalize(fr.to_world(bs.wi));
            if (!(dir.z > -1.f) || !(dot(v.n, dir) > 0.f)) break;
            HeightfieldHit next;
            if (!hf.intersect(spawn_origin(v), dir, 0.f, Infinity, next, v.ox, v.oy)) break;  // escaped
            v = make_vertex(hf, next, v.ox, v.oy, opt.macro_frame);
            w_out = -dir;
        }
        return sum;
    }
};

/// `samples` lines of sight in chunks of `chunk`, one RNG stream per chunk (in parallel),
/// summed in chunk order: deterministic whatever the thread count.
Sums sum_samples(const PathSampler &ps, size_t samples, size_t chunk, uint64_t seed) {
    const size_t n_chunks = (samples + chunk - 1) / chunk;
    std::vector<Sums> sums(n_chunks);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n_chunks), [&](const tbb::blocked_range<size_t> &r) {
        for (size_t c = r.begin(); c < r.end(); ++c) {
            PCG32 rng(hash_combine(seed, c), mix_bits(seed ^ 0x5eedULL));
            Sums &s = sums[c];
            const size_t n = std::min(chunk, samples - c * chunk);
            for (size_t i = 0; i < n; ++i) {
                Spectrum contrib;
                bool leak = false;
                if (!ps.sample(rng, contrib, leak, s.vertices)) {
                    s.leaked += leak ? 1 : 0;
                    continue;
                }
                ++s.accepted;
                for (int ch = 0; ch < 3; ++ch) {
                    const double x = contrib[ch];
                    s.sum[ch] += x;
                    s.sum2[ch] += x * x;
                }
            }
        }
    });
    Sums tot;
    for (const Sums &s : sums) {  // chunk order: deterministic
        tot.accepted += s.accepted;
        tot.leaked += s.leaked;
        tot.vertices += s.vertices;
        for (int ch = 0; ch < 3; ++ch) tot.sum[ch] += s.sum[ch], tot.sum2[ch] += s.sum2[ch];
    }
    return tot;
}

}  // namespace

EffectiveBrdfEstimator::Estimate EffectiveBrdfEstimator::run(const PatchRegion &R, const Vec3 *wi_fixed, Vec3 wo,
                                                             size_t samples, uint64_t seed, int max_bounces) const {
    if (!std::isfinite(R.x0) || !std::isfinite(R.x1) || !std::isfinite(R.y0) || !std::isfinite(R.y1) ||
        !(R.x1 > R.x0) || !(R.y1 > R.y0))
        throw MesoError(fmt::format("effective BRDF: empty or non-finite patch [{}, {}) x [{}, {})", R.x0, R.x1,
                                    R.y0, R.y1));
    if (samples == 0) throw MesoError("effective BRDF: samples must be at least 1");
    if (max_bounces < 1) throw MesoError(fmt::format("effective BRDF: max_bounces must be >= 1, got {}", max_bounces));
    wo = checked_direction(wo, "wo");

    Estimate est;
    est.samples = samples;
    // Below the horizon the macro BRDF is zero (and nothing is visible from wo).
    if (!(wo.z > 0.f) || (wi_fixed && !(wi_fixed->z > 0.f))) return est;

    // The shooting region Q (see the header): whole periods need no rejection.
    const PathSampler ps{m_hf, m_base, m_opt, R, shooting_region(m_hf, R, wo), wi_fixed, wo, max_bounces};
    const ShootingRegion &Q = ps.Q;
    const Sums tot = sum_samples(ps, samples, m_opt.chunk, seed);
    est.accepted = tot.accepted;
    est.leaked = tot.leaked;

    // A(wo) = cos(theta_o) |Q| / |P| Pr(hit in P) (exactly cos(theta_o) over whole periods).
    const double cos_o = wo.z, ratio = (Q.x1 - Q.x0) * (Q.y1 - Q.y0) / R.area();
    if (Q.wrap_x && Q.wrap_y) {
        est.projected_area = cos_o;
    } else {
        const double pa = double(tot.accepted) / double(samples);
        est.projected_area = cos_o * ratio * pa;
        est.projected_area_std_error = cos_o * ratio * std::sqrt(pa * (1 - pa) / double(samples));
    }
    if (tot.accepted == 0) return est;
    const double n = double(tot.accepted);
    est.mean_vertices = double(tot.vertices) / n;
    for (int ch = 0; ch < 3; ++ch) {
        const double mean = tot.sum[ch] / n;
        const double var = n > 1 ? std::max(0.0, (tot.sum2[ch] - n * mean * mean) / (n - 1)) : 0.0;
        est.value[ch] = float(mean);
        est.std_error[ch] = float(std::sqrt(var / n));
    }
    if (wi_fixed) {
        est.brdf = est.value * (1.f / wi_fixed->z);
    } else {
        est.brdf = est.value;
    }
    return est;
}

}  // namespace meso::prefilter
