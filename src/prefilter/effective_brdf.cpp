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
#include "render/shading.h"
#include "sampling/rng.h"
#include "sampling/warp.h"

namespace meso::prefilter {
namespace {

/// Per-chunk sums (double, per channel) of the per-sample contributions of accepted samples.
struct Sums {
    size_t accepted = 0, leaked = 0, vertices = 0;
    double sum[3] = {0, 0, 0}, sum2[3] = {0, 0, 0};
};

/// Whether [a, b) spans a whole number (>= 1) of periods of length `period`.
bool whole_periods(double a, double b, int period) {
    const double n = (b - a) / double(period);
    const double r = std::round(n);
    return r >= 1 && std::abs(n - r) <= 1e-9 * r;
}

Vec3 checked_direction(Vec3 w, const char *name) {
    const double l = std::sqrt(double(w.x) * w.x + double(w.y) * w.y + double(w.z) * w.z);
    if (!std::isfinite(l) || !(l > 0))
        throw MesoError(fmt::format("effective BRDF: direction {} = ({}, {}, {}) is zero or not finite", name, w.x,
                                    w.y, w.z));
    return Vec3(float(w.x / l), float(w.y / l), float(w.z / l));
}

/// A point on the microsurface: integer cell offsets plus a small local part (the
/// intersector's convention), the micro-normal and its shading context.
struct Vertex {
    int64_t ox = 0, oy = 0;
    Vec3 p;  ///< local position: x, y in [0, 1) (plus round-off), z = height
    Vec3 n;  ///< unit micro-normal (upper side)
    ShadingContext ctx;
};

Vertex make_vertex(const Heightfield &hf, const HeightfieldHit &hit, int64_t ox, int64_t oy) {
    Vertex v;
    // Re-base: the integer part of the traced position moves into the offsets, so the
    // coordinates handed to the intersector stay small however far a path wanders.
    const float fx = std::floor(hit.x), fy = std::floor(hit.y);
    v.ox = ox + int64_t(fx);
    v.oy = oy + int64_t(fy);
    v.p = Vec3(hit.x - fx, hit.y - fy, hit.h);
    v.n = normalize(Vec3(-hit.dhdx, -hit.dhdy, 1.f));
    // s along the x tangent (1, 0, dh/dx) so that anisotropic bases line up with the map.
    v.ctx.frame = Frame::from_normal_tangent(v.n, Vec3(1.f, 0.f, hit.dhdx));
    v.ctx.ng = v.n;
    const double W = hf.width(), H = hf.height();
    const double ax = double(v.ox) + v.p.x, ay = double(v.oy) + v.p.y;
    v.ctx.p = Vec3(float(ax), float(ay), v.p.z);
    double u = ax / W - std::floor(ax / W), w = ay / H - std::floor(ay / H);
    v.ctx.uv = Vec2(float(std::min(u, 0.99999999)), float(std::min(w, 0.99999999)));
    v.ctx.dpdu = Vec3(float(W), 0.f, float(W) * hit.dhdx);
    v.ctx.dpdv = Vec3(0.f, float(H), float(H) * hit.dhdy);
    return v;
}

/// Origin of a ray leaving vertex v: pushed off the surface along the normal by a distance
/// relative to the coordinates' magnitude (float round-off of the hit point).
Vec3 spawn_origin(const Vertex &v) {
    const float eps = 1e-4f * (1.f + std::abs(v.p.z));
    return v.p + v.n * eps;
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
    const bool wrap_x = whole_periods(R.x0, R.x1, m_hf.width()), wrap_y = whole_periods(R.y0, R.y1, m_hf.height());
    const double zmin = m_hf.min_height(), zmax = m_hf.max_height();
    const double z_top = zmax + 1e-2 * (1 + (zmax - zmin));
    const double sx = double(wo.x) / wo.z, sy = double(wo.y) / wo.z;
    const double dz_lo = z_top - zmax, dz_hi = z_top - zmin;
    double qx0 = R.x0, qx1 = R.x1, qy0 = R.y0, qy1 = R.y1;
    if (!wrap_x) {
        qx0 += std::min(sx * dz_lo, sx * dz_hi);
        qx1 += std::max(sx * dz_lo, sx * dz_hi);
    }
    if (!wrap_y) {
        qy0 += std::min(sy * dz_lo, sy * dz_hi);
        qy1 += std::max(sy * dz_lo, sy * dz_hi);
    }
    const Vec3 d_view = -wo;

    // One line of sight plus its path; returns false when the first hit is not in P.
    auto sample_one = [&](PCG32 &rng, Spectrum &contrib, bool &leak, size_t &vertices) -> bool {
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
        const double qx = qx0 + (qx1 - qx0) * rng.next_double(), qy = qy0 + (qy1 - qy0) * rng.next_double();
        const double fqx = std::floor(qx), fqy = std::floor(qy);
        const int64_t ox = int64_t(fqx), oy = int64_t(fqy);
        const Vec3 o(float(qx - fqx), float(qy - fqy), float(z_top));
        HeightfieldHit hit;
        if (!m_hf.intersect(o, d_view, 0.f, Infinity, hit, ox, oy)) {
            leak = true;
            return false;
        }
        Vertex v = make_vertex(m_hf, hit, ox, oy);
        if (!wrap_x) {
            const double ax = double(ox) + double(hit.x);
            if (ax < R.x0 || ax >= R.x1) return false;
        }
        if (!wrap_y) {
            const double ay = double(oy) + double(hit.y);
            if (ay < R.y0 || ay >= R.y1) return false;
        }
        if (inv_pdf == 0.f) return true;  // the rim of the disk: a zero sample, still counted

        // The path (eq. 15-16): next-event terms towards wi at every vertex.
        Spectrum throughput(1.f), sum(0.f);
        Vec3 w_out = wo;  // towards the previous vertex (the viewer for x_1)
        for (int k = 1;; ++k) {
            ++vertices;
            const Frame &fr = v.ctx.frame;
            const Vec3 lwo = fr.to_local(w_out);
            if (!(lwo.z > 0.f)) break;  // round-off at a grazing hit: the path sees the back
            const Vec3 lwi = fr.to_local(wi);
            if (lwi.z > 0.f) {
                const Spectrum f = m_base.eval(v.ctx, lwo, lwi);
                if (!f.is_black() && !m_hf.occluded(spawn_origin(v), wi, 0.f, Infinity, v.ox, v.oy))
                    sum += throughput * f;
            }
            if (k >= max_bounces) break;
            // Continue by sampling the base material.
            const float u_lobe = rng.next_float(), u0 = rng.next_float(), u1 = rng.next_float();
            BSDFSample bs;
            if (!m_base.sample(v.ctx, lwo, u_lobe, Vec2(u0, u1), bs) || bs.weight.is_black() || !(bs.wi.z > 0.f))
                break;
            throughput *= bs.weight;
            if (m_opt.roulette_start > 0 && k >= m_opt.roulette_start) {
                const float q = std::min(1.f, throughput.max());
                if (!(rng.next_float() < q)) break;
                throughput *= 1.f / q;
            }
            const Vec3 dir = normalize(fr.to_world(bs.wi));
            if (!(dir.z > -1.f)) break;
            HeightfieldHit next;
            if (!m_hf.intersect(spawn_origin(v), dir, 0.f, Infinity, next, v.ox, v.oy)) break;  // escaped
            v = make_vertex(m_hf, next, v.ox, v.oy);
            w_out = -dir;
        }
        contrib = sum * inv_pdf;
        return true;
    };

    const size_t chunk = m_opt.chunk, n_chunks = (samples + chunk - 1) / chunk;
    std::vector<Sums> sums(n_chunks);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n_chunks), [&](const tbb::blocked_range<size_t> &r) {
        for (size_t c = r.begin(); c < r.end(); ++c) {
            PCG32 rng(hash_combine(seed, c), mix_bits(seed ^ 0x5eedULL));
            Sums &s = sums[c];
            const size_t n = std::min(chunk, samples - c * chunk);
            for (size_t i = 0; i < n; ++i) {
                Spectrum contrib;
                bool leak = false;
                if (!sample_one(rng, contrib, leak, s.vertices)) {
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
    est.accepted = tot.accepted;
    est.leaked = tot.leaked;

    // A(wo) = cos(theta_o) |Q| / |P| Pr(hit in P) (exactly cos(theta_o) over whole periods).
    const double cos_o = wo.z, ratio = (qx1 - qx0) * (qy1 - qy0) / R.area();
    if (wrap_x && wrap_y) {
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
