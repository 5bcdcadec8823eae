// Spherical EM for vMF mixtures; see vmf_mixture.h for the method and the degenerate cases.
#include "bsdf/vmf_mixture.h"
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <string>
#include "core/error.h"
#include "core/f64_lanes.h"
#include "filter/vmf.h"
#include "sampling/rng.h"

namespace meso {

namespace vmf {

namespace {
/// A₃'(κ) = 1/κ² − 1/sinh²κ, stable for all κ > 0 (series below 0.1, where the difference
/// cancels; 1/sinh² underflows harmlessly to 0 for large κ).
double mean_cosine_derivative(double k) {
    if (k < 0.1) {
        const double k2 = k * k;
        return 1.0 / 3.0 + k2 * (-1.0 / 15.0 + k2 * (2.0 / 189.0 - k2 / 675.0));
    }
    const double s = std::sinh(k);
    return 1.0 / (k * k) - 1.0 / (s * s);
}
}  // namespace

double kappa_from_mean_cosine(double r) {
    if (!(r > 0.0)) return 0.0;  // also NaN
    if (r >= 1.0) return kMaxKappa;
    // A₃ is increasing and concave on (0, ∞) with A₃(0) = 0, A₃(∞) = 1, so the root is unique.
    // Banerjee's approximation overestimates it (by ~κ³/135 for small κ, ~1/2 for large), so
    // Newton from there steps to the left of the root and then climbs monotonically; the
    // bracket [lo, hi] and bisection only guard against rounding.
    double lo = 0.0, hi = kMaxKappa;
    if (mean_cosine(hi) <= r) return kMaxKappa;
    double k = std::clamp(kappa_from_r(r), 0.0, hi);
    for (int it = 0; it < 200; ++it) {
        const double f = mean_cosine(k) - r;
        if (f == 0.0) break;
        if (f < 0.0) lo = k; else hi = k;
        const double df = mean_cosine_derivative(k);
        double kn = k - f / df;
        if (!(kn > lo && kn < hi)) kn = 0.5 * (lo + hi);
        if (std::abs(kn - k) <= 1e-15 * k || hi - lo <= 1e-15 * hi) { k = kn; break; }
        k = kn;
    }
    return k;
}

}  // namespace vmf

namespace {

/// 1 − x·c below which two unit directions count as the same (≈ 1.4e-6 rad; a float unit
/// vector is only resolved to ~6e-8 rad).
constexpr double kSameDirection = 1e-12;

/// The usable data: normalised directions and positive weights (rescaled by their maximum),
/// structure of arrays.
struct Data {
    std::vector<double> x, y, z, w;
    double total = 0.0;
    size_t size() const { return w.size(); }
};

Data prepare(const Vec3 *dirs, const double *weights, size_t n) {
    Data d;
    double wmax = 0.0;
    for (size_t i = 0; i < n; ++i) {
        const double wi = weights ? weights[i] : 1.0;
        if (!(wi > 0.0) || !std::isfinite(wi)) continue;
        const double x = dirs[i].x, y = dirs[i].y, z = dirs[i].z;
        const double l2 = x * x + y * y + z * z;
        if (!(l2 > 0.0) || !std::isfinite(l2)) continue;
        const double inv = 1.0 / std::sqrt(l2);
        d.x.push_back(x * inv);
        d.y.push_back(y * inv);
        d.z.push_back(z * inv);
        d.w.push_back(wi);
        wmax = std::max(wmax, wi);
    }
    for (double &wi : d.w) wi /= wmax;  // no overflow of the sums for any finite scale
    for (double wi : d.w) d.total += wi;
    return d;
}

struct Dir {
    double x = 0, y = 0, z = 1;
};

/// 1 − x_i·c = |x_i − c|²/2 for unit vectors (no cancellation for nearby directions).
inline double chord_half(const Data &d, size_t i, const Dir &c) {
    const double dx = d.x[i] - c.x, dy = d.y[i] - c.y, dz = d.z[i] - c.z;
    return 0.5 * (dx * dx + dy * dy + dz * dz);
}

/// Samples i and i + 1 in two lanes (lanes::F64x2); past the end (i + 1 = n) the second lane
/// repeats sample i with weight 0, so it adds nothing to any weighted sum.
struct Pair {
    lanes::F64x2 x, y, z, w;
};
inline Pair load_pair(const Data &d, size_t i) {
    const size_t k = i + 1 < d.size() ? i + 1 : i;
    return {lanes::F64x2{d.x[i], d.x[k]}, lanes::F64x2{d.y[i], d.y[k]}, lanes::F64x2{d.z[i], d.z[k]},
            lanes::F64x2{d.w[i], k > i ? d.w[k] : 0.0}};
}

/// chord_half of a pair.
inline lanes::F64x2 chord_half2(const Pair &a, const Dir &c) {
    using lanes::splat;
    const lanes::F64x2 dx = a.x - splat(c.x), dy = a.y - splat(c.y), dz = a.z - splat(c.z);
    return splat(0.5) * (dx * dx + dy * dy + dz * dz);
}

/// k-means++'s distance of sample i to centre c (chord_half, 0 within kSameDirection).
inline double seed_distance(const Data &d, size_t i, const Dir &c) {
    const double di = chord_half(d, i, c);
    return di < kSameDirection ? 0.0 : di;
}

/// k-means++'s potential of candidate centre c: Σ w_i min(D(i, c), dmin_i) (dmin nullptr: Σ w_i
/// D(i, c)), two samples a step in two running sums of two lanes.
double seed_potential(const Data &d, const Dir &c, const double *dmin) {
    using lanes::splat;
    lanes::F64x2 acc[2] = {splat(0.0), splat(0.0)};
    for (size_t i = 0; i < d.size(); i += 2) {
        const Pair a = load_pair(d, i);
        lanes::F64x2 di = chord_half2(a, c);
        di = di < splat(kSameDirection) ? splat(0.0) : di;
        if (dmin) {
            const lanes::F64x2 m{dmin[i], i + 1 < d.size() ? dmin[i + 1] : 0.0};
            di = di < m ? di : m;
        }
        acc[(i >> 1) & 1] += a.w * di;
    }
    return lanes::hsum(acc[0] + acc[1]);
}

/// Lobe parameters in double during the fit.
struct Lobe {
    Dir mu;
    double kappa = 0.0, weight = 0.0;
    int order = 0;  ///< creation index (tie-break of the final sort)
};

double kappa_of(double r, const VmfEmOptions &opt) {
    const double k = opt.exact_kappa ? vmf::kappa_from_mean_cosine(r) : vmf::kappa_from_r(r);
    return std::clamp(k, 0.0, opt.max_kappa);
}

/// Lobes from weighted resultants R_j and masses N_j (the M-step, also used for the hard
/// k-means clusters). A zero resultant keeps the previous μ and gives κ = 0.
void lobes_from_sums(std::vector<Lobe> &lobes, const std::vector<double> &N, const std::vector<Dir> &R,
                     const VmfEmOptions &opt) {
    double total = 0.0;
    for (double v : N) total += v;
    for (size_t j = 0; j < lobes.size(); ++j) {
        Lobe &l = lobes[j];
        l.weight = total > 0.0 ? N[j] / total : 0.0;
        const double len = std::sqrt(R[j].x * R[j].x + R[j].y * R[j].y + R[j].z * R[j].z);
        if (len > 0.0 && N[j] > 0.0) {
            l.mu = {R[j].x / len, R[j].y / len, R[j].z / len};
            l.kappa = kappa_of(std::min(1.0, len / N[j]), opt);
        } else {
            l.kappa = 0.0;
        }
    }
}

/// Drops lobes below min_weight (never the heaviest) and renormalises the weights. Returns
/// whether any lobe was dropped.
bool drop_light_lobes(std::vector<Lobe> &lobes, double min_weight) {
    if (lobes.empty()) return false;
    size_t heaviest = 0;
    for (size_t j = 1; j < lobes.size(); ++j)
        if (lobes[j].weight > lobes[heaviest].weight) heaviest = j;
    std::vector<Lobe> kept;
    for (size_t j = 0; j < lobes.size(); ++j)
        if (j == heaviest || (lobes[j].weight >= min_weight && lobes[j].weight > 0.0)) kept.push_back(lobes[j]);
    const bool dropped = kept.size() != lobes.size();
    double total = 0.0;
    for (const Lobe &l : kept) total += l.weight;
    for (Lobe &l : kept) l.weight = total > 0.0 ? l.weight / total : 1.0 / double(kept.size());
    lobes.swap(kept);
    return dropped;
}

/// Picks one index per sorted target t in [0, Σ v) by the cumulative sums of v (v ≥ 0);
/// only indices with v > 0 are returned.
std::vector<size_t> pick_by_cumulative(const std::vector<double> &v, std::vector<double> targets) {
    std::sort(targets.begin(), targets.end());
    std::vector<size_t> out;
    size_t last_positive = v.size();
    double cum = 0.0;
    size_t t = 0;
    for (size_t i = 0; i < v.size() && t < targets.size(); ++i) {
        if (!(v[i] > 0.0)) continue;
        last_positive = i;
        cum += v[i];
        while (t < targets.size() && targets[t] < cum) {
            out.push_back(i);
            ++t;
        }
    }
    if (last_positive == v.size())
        for (size_t i = 0; i < v.size(); ++i)
            if (v[i] > 0.0) last_positive = i;
    for (; t < targets.size() && last_positive < v.size(); ++t) out.push_back(last_positive);  // rounding
    return out;
}

/// Greedy weighted k-means++ on the sphere (header comment): at most K centres, fewer when
/// every direction coincides with a centre.
std::vector<Dir> kmeanspp(const Data &d, int K, uint64_t seed) {
    const size_t n = d.size();
    PCG32 rng(seed);
    const int candidates = 2 * (2 + int(std::log(double(K))));
    std::vector<Dir> centres;
    std::vector<double> dmin(n, 0.0), v(n), trial(n);
    for (int c = 0; c < K; ++c) {
        double potential = 0.0;
        if (c == 0) {
            v = d.w;
            potential = d.total;
        } else {
            double acc[4] = {0.0, 0.0, 0.0, 0.0};  // four running sums (one is a chain of additions)
            for (size_t i = 0; i < n; ++i) acc[i & 3] += (v[i] = d.w[i] * dmin[i]);
            potential = (acc[0] + acc[2]) + (acc[1] + acc[3]);
        }
        if (!(potential > 0.0)) break;  // every direction is a centre already
        // The first centre is a single draw ∝ w_i (choosing it by the potential would give
        // the medoid of ALL directions, between the clusters, a poor start).
        std::vector<double> targets(c == 0 ? 1 : candidates);
        for (double &t : targets) t = rng.next_double() * potential;
        std::vector<size_t> picks = pick_by_cumulative(v, targets);
        if (c > 0) {  // plus the farthest direction (first of equals): isolated sharp lobes
            size_t far = 0;
            for (size_t i = 1; i < n; ++i)
                if (dmin[i] > dmin[far]) far = i;
            picks.push_back(far);
        }
        double best = std::numeric_limits<double>::infinity();
        size_t best_i = picks.empty() ? 0 : picks[0];
        for (size_t p = 0; p < picks.size(); ++p) {
            if (std::find(picks.begin(), picks.begin() + p, picks[p]) != picks.begin() + p) continue;
            const Dir cand{d.x[picks[p]], d.y[picks[p]], d.z[picks[p]]};
            const double pot = seed_potential(d, cand, c == 0 ? nullptr : dmin.data());
            if (pot < best) {
                best = pot;
                best_i = picks[p];
            }
        }
        if (picks.empty()) break;
        const Dir chosen{d.x[best_i], d.y[best_i], d.z[best_i]};
        centres.push_back(chosen);
        for (size_t i = 0; i < n; ++i) {
            const double di = seed_distance(d, i, chosen);
            dmin[i] = c == 0 ? di : std::min(di, dmin[i]);
        }
    }
    return centres;
}

/// Spherical k-means (Lloyd) from the given centres; returns the hard-cluster lobes (empty
/// clusters removed).
std::vector<Lobe> spherical_kmeans(const Data &d, std::vector<Dir> centres, const VmfEmOptions &opt,
                                   double *objective) {
    const size_t n = d.size();
    double obj = 0.0;
    std::vector<int> assign(n, -1);
    std::vector<double> N;
    std::vector<Dir> R;
    for (int it = 0; it < 10; ++it) {
        const size_t K = centres.size();
        N.assign(K, 0.0);
        R.assign(K, Dir{0, 0, 0});
        bool changed = false;
        double objs[2] = {0.0, 0.0};  // two running sums (one is a chain of additions)
        auto assign_to = [&](size_t i, int best, double best_d) {
            if (assign[i] != best) changed = true;
            assign[i] = best;
            objs[i & 1] += d.w[i] * best_d;
            N[size_t(best)] += d.w[i];
            R[size_t(best)].x += d.w[i] * d.x[i];
            R[size_t(best)].y += d.w[i] * d.y[i];
            R[size_t(best)].z += d.w[i] * d.z[i];
        };
        for (size_t i = 0; i < n; i += 2) {  // the nearest centre of two samples at a time (first of equals)
            const Pair a = load_pair(d, i);
            lanes::F64x2 best_d = lanes::splat(std::numeric_limits<double>::infinity()), best = lanes::splat(0.0);
            for (size_t j = 0; j < K; ++j) {
                const lanes::F64x2 dj = chord_half2(a, centres[j]);
                const auto closer = dj < best_d;
                best_d = closer ? dj : best_d;
                best = closer ? lanes::splat(double(j)) : best;
            }
            assign_to(i, int(best[0]), best_d[0]);
            if (i + 1 < n) assign_to(i + 1, int(best[1]), best_d[1]);
        }
        obj = objs[0] + objs[1];
        // Remove empty clusters (renumbering the assignments), move the centres.
        std::vector<int> remap(K, -1);
        std::vector<Dir> next;
        std::vector<double> N2;
        std::vector<Dir> R2;
        for (size_t j = 0; j < K; ++j) {
            if (!(N[j] > 0.0)) continue;
            remap[j] = int(next.size());
            const double len = std::sqrt(R[j].x * R[j].x + R[j].y * R[j].y + R[j].z * R[j].z);
            next.push_back(len > 0.0 ? Dir{R[j].x / len, R[j].y / len, R[j].z / len} : centres[j]);
            N2.push_back(N[j]);
            R2.push_back(R[j]);
        }
        if (next.size() != K) {
            for (int &a : assign) a = remap[size_t(a)];
            changed = true;
        }
        N.swap(N2);
        R.swap(R2);
        // Lobes from the clusters of THESE assignments (centres = their resultants).
        const bool last = !changed || it == 9;
        centres.swap(next);
        if (last) break;
    }
    std::vector<Lobe> lobes(centres.size());
    for (size_t j = 0; j < lobes.size(); ++j) {
        lobes[j].mu = centres[j];
        lobes[j].order = int(j);
    }
    lobes_from_sums(lobes, N, R, opt);
    *objective = obj;  // of the last assignment
    return lobes;
}

/// One E-step: the mean log-likelihood of the lobes, and the responsibility sums N_j, R_j.
/// Two samples at a time (load_pair: a missing second sample has weight 0), e^x and ln x
/// from core/f64_lanes.h; each lane keeps its own sums, added at the end.
double e_step(const Data &d, const std::vector<Lobe> &lobes, std::vector<double> &N, std::vector<Dir> &R) {
    using lanes::F64x2;
    using lanes::splat;
    const size_t K = lobes.size(), n = d.size();
    // log a_j + log_norm(κ_j) + κ_j: the log density at μ·x = 1. (log_norm(κ) + κ re-adds the
    // −κ that log_norm subtracts; the rounding of that is ≤ ulp(κ) ≈ 1e-10 at κ = 1e6.)
    std::vector<double> c0(K), kh(K), mx(K), my(K), mz(K);
    for (size_t j = 0; j < K; ++j) {
        c0[j] = std::log(lobes[j].weight) + vmf::log_norm(lobes[j].kappa) + lobes[j].kappa;
        kh[j] = 0.5 * lobes[j].kappa;
        mx[j] = lobes[j].mu.x;
        my[j] = lobes[j].mu.y;
        mz[j] = lobes[j].mu.z;
    }
    std::vector<F64x2> l(K), sN(K, splat(0.0)), sX(K, splat(0.0)), sY(K, splat(0.0)), sZ(K, splat(0.0));
    F64x2 sL = splat(0.0);
    for (size_t i = 0; i < n; i += 2) {
        const Pair a = load_pair(d, i);
        const F64x2 &x = a.x, &y = a.y, &z = a.z, &w = a.w;
        F64x2 lmax = splat(-std::numeric_limits<double>::infinity());
        for (size_t j = 0; j < K; ++j) {
            const F64x2 dx = x - splat(mx[j]), dy = y - splat(my[j]), dz = z - splat(mz[j]);
            l[j] = splat(c0[j]) - splat(kh[j]) * (dx * dx + dy * dy + dz * dz);  // κ(μ·x − 1) = −κ|μ − x|²/2
            lmax = lanes::max(lmax, l[j]);
        }
        F64x2 s = splat(0.0);
        for (size_t j = 0; j < K; ++j) s += (l[j] = lanes::exp_nonpositive(l[j] - lmax));  // the max gives 1
        sL += w * (lmax + lanes::log_positive(s));
        const F64x2 scale = w / s;
        for (size_t j = 0; j < K; ++j) {
            const F64x2 g = l[j] * scale;  // w_i γ_ij
            sN[j] += g;
            sX[j] += g * x;
            sY[j] += g * y;
            sZ[j] += g * z;
        }
    }
    N.resize(K);
    R.resize(K);
    for (size_t j = 0; j < K; ++j) {
        N[j] = lanes::hsum(sN[j]);
        R[j] = Dir{lanes::hsum(sX[j]), lanes::hsum(sY[j]), lanes::hsum(sZ[j])};
    }
    return lanes::hsum(sL) / d.total;
}

/// Plain EM from the start `lobes` (header comment): E-step, convergence test, M-step.
void plain_em(const Data &d, std::vector<Lobe> &lobes, const VmfEmOptions &opt, std::vector<double> &N,
              std::vector<Dir> &R, VmfMixture &out) {
    double prev = -std::numeric_limits<double>::infinity();
    bool dropped = false;
    for (int it = 0;; ++it) {
        const double L = e_step(d, lobes, N, R);
        out.log_likelihood = L;
        if (it > 0 && !dropped && std::abs(L - prev) <= opt.tolerance * (1.0 + std::abs(L))) {
            out.converged = true;
            break;
        }
        if (it == opt.max_iterations) break;
        lobes_from_sums(lobes, N, R, opt);
        dropped = drop_light_lobes(lobes, opt.min_weight);
        prev = L;
        ++out.iterations;
    }
}

/// A lobe in SQUAREM's coordinates (a_j, μ_j, ln κ_j): ln κ keeps sharp lobes (κ up to 1e9)
/// and broad ones on one scale.
std::array<double, 5> coords(const Lobe &l) {
    return {l.weight, l.mu.x, l.mu.y, l.mu.z, std::log(std::max(l.kappa, 1e-12))};
}

/// θ0 − 2α r + α² v per lobe (r = θ1 − θ0, v = θ2 − 2θ1 + θ0) in coords, projected back:
/// weights clamped to >= 1e-12 and renormalised, μ normalised (θ2's where it collapses), κ
/// clamped to [0, max_kappa].
std::vector<Lobe> extrapolate(const std::vector<Lobe> &t0, const std::vector<Lobe> &t1, const std::vector<Lobe> &t2,
                              double alpha, const VmfEmOptions &opt) {
    std::vector<Lobe> out = t2;
    double total = 0.0;
    for (size_t j = 0; j < out.size(); ++j) {
        const std::array<double, 5> c0 = coords(t0[j]), c1 = coords(t1[j]), c2 = coords(t2[j]);
        double e[5];
        for (int c = 0; c < 5; ++c) e[c] = c0[c] - 2.0 * alpha * (c1[c] - c0[c]) + alpha * alpha * (c2[c] - 2.0 * c1[c] + c0[c]);
        Lobe &l = out[j];
        l.weight = std::max(1e-12, e[0]);
        total += l.weight;
        const double len = std::sqrt(e[1] * e[1] + e[2] * e[2] + e[3] * e[3]);
        if (len > 1e-6 && std::isfinite(len)) l.mu = {e[1] / len, e[2] / len, e[3] / len};
        const double k = std::exp(std::min(e[4], 700.0));
        if (std::isfinite(k)) l.kappa = std::clamp(k < 1e-9 ? 0.0 : k, 0.0, opt.max_kappa);  // else θ2's
    }
    for (Lobe &l : out) l.weight /= total;
    return out;
}

/// |r|² and |v|² of a SQUAREM cycle in coords.
void cycle_norms(const std::vector<Lobe> &t0, const std::vector<Lobe> &t1, const std::vector<Lobe> &t2, double &r2,
                 double &v2) {
    r2 = v2 = 0.0;
    for (size_t j = 0; j < t0.size(); ++j) {
        const std::array<double, 5> c0 = coords(t0[j]), c1 = coords(t1[j]), c2 = coords(t2[j]);
        for (int c = 0; c < 5; ++c) {
            const double r = c1[c] - c0[c], v = c2[c] - 2.0 * c1[c] + c0[c];
            r2 += r * r;
            v2 += v * v;
        }
    }
}

/// EM accelerated by SQUAREM (Varadhan and Roland 2008, scheme S3, with the monotone
/// safeguard). A cycle makes two EM steps θ0 → θ1 → θ2, then tries θ' = θ0 − 2α r + α² v with
/// α = −|r| / |v| (in [−64, −1]); θ' is kept when its likelihood is at least θ1's (so the
/// likelihood never falls), else the cycle ends at θ2. The convergence test is EM's, on the
/// plain step θ0 → θ1 of each cycle, and the lobes returned are always an M-step's (θ1 of the
/// last cycle), so every property of an M-step (header comment of prefilter/patch_ndf.h:
/// a_j A₃(κ_j) μ_j = R_j / Σ w) holds for the result as for plain EM. A cycle whose M-steps
/// drop a lobe, or that would leave fewer than three M-steps of max_iterations, is plain EM.
void squarem(const Data &d, std::vector<Lobe> &lobes, const VmfEmOptions &opt, std::vector<double> &N,
             std::vector<Dir> &R, VmfMixture &out) {
    double L = e_step(d, lobes, N, R);  // θ0's likelihood and sums
    out.log_likelihood = L;
    std::vector<double> Np;
    std::vector<Dir> Rp;
    while (out.iterations < opt.max_iterations) {
        std::vector<Lobe> t1 = lobes;
        lobes_from_sums(t1, N, R, opt);
        const bool drop1 = drop_light_lobes(t1, opt.min_weight);
        ++out.iterations;
        const double L1 = e_step(d, t1, N, R);
        const bool conv = !drop1 && std::abs(L1 - L) <= opt.tolerance * (1.0 + std::abs(L1));
        if (conv || drop1 || out.iterations + 3 > opt.max_iterations) {
            lobes.swap(t1);
            L = out.log_likelihood = L1;
            if (conv) {
                out.converged = true;
                return;
            }
            continue;
        }
        std::vector<Lobe> t2 = t1;
        lobes_from_sums(t2, N, R, opt);
        const bool drop2 = drop_light_lobes(t2, opt.min_weight);
        ++out.iterations;
        if (!drop2) {
            double r2, v2;
            cycle_norms(lobes, t1, t2, r2, v2);
            const double alpha = v2 > 0.0 ? std::clamp(-std::sqrt(r2 / v2), -64.0, -1.0) : -1.0;
            if (alpha < -1.0) {
                std::vector<Lobe> tp = extrapolate(lobes, t1, t2, alpha, opt);
                const double Lp = e_step(d, tp, Np, Rp);
                if (std::isfinite(Lp) && Lp >= L1) {
                    lobes.swap(tp);
                    N.swap(Np);
                    R.swap(Rp);
                    L = out.log_likelihood = Lp;
                    continue;
                }
            }
        }
        lobes.swap(t2);
        L = out.log_likelihood = e_step(d, lobes, N, R);
    }
}

void check_options(const VmfEmOptions &opt) {
    auto fail = [](const std::string &what) { throw MesoError("fit_vmf_mixture: " + what); };
    if (opt.lobes < 1) fail("lobes must be >= 1, got " + std::to_string(opt.lobes));
    if (opt.init_restarts < 1) fail("init_restarts must be >= 1, got " + std::to_string(opt.init_restarts));
    if (opt.max_iterations < 0) fail("max_iterations must be >= 0, got " + std::to_string(opt.max_iterations));
    if (!(opt.tolerance >= 0.0)) fail("tolerance must be >= 0");
    if (!(opt.min_weight >= 0.0 && opt.min_weight < 1.0)) fail("min_weight must be in [0, 1)");
    if (!(opt.max_kappa > 0.0) || std::isinf(opt.max_kappa)) fail("max_kappa must be positive and finite");
}


/// A fitted lobe as the output type (float direction).
VmfLobe to_vmf_lobe(const Lobe &l, double weight) {
    VmfLobe v;
    v.mu = Vec3(float(l.mu.x), float(l.mu.y), float(l.mu.z));
    v.kappa = l.kappa;
    v.weight = weight;
    return v;
}

/// EM from `lobes` (dropping the light ones first), then the output: lobes sorted by weight,
/// weights renormalised, in float directions.
VmfMixture em_from(const Data &d, std::vector<Lobe> lobes, const VmfEmOptions &opt) {
    VmfMixture out;
    drop_light_lobes(lobes, opt.min_weight);

    std::vector<double> N;
    std::vector<Dir> R;
    if (opt.accelerate)
        squarem(d, lobes, opt, N, R, out);
    else
        plain_em(d, lobes, opt, N, R, out);

    std::stable_sort(lobes.begin(), lobes.end(), [](const Lobe &a, const Lobe &b) {
        return a.weight != b.weight ? a.weight > b.weight : a.order < b.order;
    });
    double total = 0.0;
    for (const Lobe &l : lobes) total += l.weight;
    for (const Lobe &l : lobes) out.lobes.push_back(to_vmf_lobe(l, l.weight / total));
    return out;
}

/// The usable lobes of a start (finite weight > 0, non-zero finite μ, normalised; κ clamped to
/// [0, max_kappa], NaN as 0), in their order, weights as given.
std::vector<Lobe> usable_lobes(const std::vector<VmfLobe> &in, const VmfEmOptions &opt) {
    std::vector<Lobe> out;
    for (const VmfLobe &v : in) {
        const double x = v.mu.x, y = v.mu.y, z = v.mu.z, len = std::sqrt(x * x + y * y + z * z);
        if (!(v.weight > 0.0) || !std::isfinite(v.weight) || !(len > 0.0) || !std::isfinite(len)) continue;
        Lobe l;
        l.mu = {x / len, y / len, z / len};
        l.kappa = std::clamp(std::isnan(v.kappa) ? 0.0 : v.kappa, 0.0, opt.max_kappa);
        l.weight = v.weight;
        l.order = int(out.size());
        out.push_back(l);
    }
    return out;
}

}  // namespace

namespace {
/// N ℓ(|R| / N): the group's mass times the expected log-density of its moment-matched lobe,
/// ℓ(r) = log C(κ) + κ r (κ by Banerjee's rule, for speed); 0 for an empty group.
double group_value(double N, const Dir &R) {
    if (!(N > 0.0)) return 0.0;
    const double r = std::min(1.0, std::sqrt(R.x * R.x + R.y * R.y + R.z * R.z) / N);
    const double k = std::min(vmf::kappa_from_r(r), vmf::kMaxKappa);
    // log C(κ) + κ r = [log_norm(κ) + κ] − κ (1 − r), as e_step forms it (no −κ + κ r cancellation).
    return N * ((vmf::log_norm(k) + k) - k * (1.0 - r));
}
}  // namespace

std::vector<VmfLobe> reduce_vmf_lobes(const std::vector<VmfLobe> &in, int K, const VmfEmOptions &opt) {
    check_options(opt);
    if (K < 1) throw MesoError("reduce_vmf_lobes: K must be >= 1, got " + std::to_string(K));
    const std::vector<Lobe> l = usable_lobes(in, opt);
    // Groups: mass N = Σ w and mean direction vector R = Σ w A₃(κ) μ (a vMF lobe's); merged
    // greedily, cheapest first, where the cost is the loss of expected log-likelihood
    // N_a ℓ_a + N_b ℓ_b − N_ab ℓ_ab (>= 0): lobes that coincide merge for free, a sharp lobe and
    // a broad one around it stay apart (a merge by direction alone blurred flat patches' deltas
    // into their neighbours' broad lobes, and EM did not recover them).
    const size_t n = l.size();
    std::vector<double> N(n), V(n);
    std::vector<Dir> R(n);
    std::vector<bool> alive(n, true);
    for (size_t i = 0; i < n; ++i) {
        const double r = l[i].weight * vmf::mean_cosine(l[i].kappa);
        N[i] = l[i].weight;
        R[i] = {r * l[i].mu.x, r * l[i].mu.y, r * l[i].mu.z};
        V[i] = group_value(N[i], R[i]);
    }
    auto merged_R = [&](size_t a, size_t b) { return Dir{R[a].x + R[b].x, R[a].y + R[b].y, R[a].z + R[b].z}; };
    std::vector<double> cost(n * n, 0.0);
    auto set_cost = [&](size_t a, size_t b) {
        cost[a * n + b] = cost[b * n + a] = V[a] + V[b] - group_value(N[a] + N[b], merged_R(a, b));
    };
    for (size_t a = 0; a < n; ++a)
        for (size_t b = a + 1; b < n; ++b) set_cost(a, b);
    for (size_t groups = n; groups > size_t(K); --groups) {
        size_t ba = n, bb = n;
        for (size_t a = 0; a < n; ++a) {
            if (!alive[a]) continue;
            for (size_t b = a + 1; b < n; ++b)
                if (alive[b] && (ba == n || cost[a * n + b] < cost[ba * n + bb])) ba = a, bb = b;
        }
        R[ba] = merged_R(ba, bb);
        N[ba] += N[bb];
        V[ba] = group_value(N[ba], R[ba]);
        alive[bb] = false;
        for (size_t c = 0; c < n; ++c)
            if (alive[c] && c != ba) set_cost(ba, c);
    }
    std::vector<Lobe> g;
    std::vector<double> gN;
    std::vector<Dir> gR;
    for (size_t i = 0; i < n; ++i)
        if (alive[i]) g.push_back(l[i]), gN.push_back(N[i]), gR.push_back(R[i]);
    lobes_from_sums(g, gN, gR, opt);  // μ = R / |R| (μ kept where R = 0), κ by opt's rule
    std::vector<VmfLobe> out;
    for (const Lobe &x : g)
        if (x.weight > 0.0) out.push_back(to_vmf_lobe(x, x.weight));
    return out;
}

VmfLobe moment_matched_lobe(const Vec3 *dirs, const double *weights, size_t n, const VmfEmOptions &opt) {
    double N = 0.0, x = 0.0, y = 0.0, z = 0.0;
    for (size_t i = 0; i < n; ++i) {
        const double w = weights ? weights[i] : 1.0;
        if (!(w > 0.0) || !std::isfinite(w)) continue;
        N += w, x += w * dirs[i].x, y += w * dirs[i].y, z += w * dirs[i].z;
    }
    std::vector<Lobe> l(1);
    lobes_from_sums(l, {N}, {Dir{x, y, z}}, opt);
    const double len = std::sqrt(x * x + y * y + z * z);
    return to_vmf_lobe(l[0], len > 0.0 && N > 0.0 && std::isfinite(N) ? N : 0.0);
}

VmfMixture fit_vmf_mixture_from(const Vec3 *dirs, const double *weights, size_t n, const std::vector<VmfLobe> &start,
                                const VmfEmOptions &opt) {
    check_options(opt);
    std::vector<Lobe> lobes = usable_lobes(start, opt);
    if (lobes.empty()) return fit_vmf_mixture(dirs, weights, n, opt);
    if (int(lobes.size()) > opt.lobes)
        throw MesoError("fit_vmf_mixture_from: " + std::to_string(lobes.size()) + " start lobes, more than lobes = " +
                        std::to_string(opt.lobes));
    if (n == 0 || !dirs) return {};
    const Data d = prepare(dirs, weights, n);
    if (d.size() == 0 || !(d.total > 0.0)) return {};  // empty mixture (header comment)
    double total = 0.0;
    for (const Lobe &l : lobes) total += l.weight;
    for (Lobe &l : lobes) l.weight /= total;
    return em_from(d, std::move(lobes), opt);
}

VmfMixture fit_vmf_mixture(const Vec3 *dirs, const double *weights, size_t n, const VmfEmOptions &opt) {
    check_options(opt);
    VmfMixture out;
    if (n == 0 || !dirs) return out;
    const Data d = prepare(dirs, weights, n);
    if (d.size() == 0 || !(d.total > 0.0)) return out;  // empty mixture (header comment)

    // k-means++ and Lloyd from init_restarts streams; the lowest k-means objective wins (ties:
    // the first), a cheap guard against the local optima of a single greedy seeding.
    std::vector<Lobe> lobes;
    double best_obj = std::numeric_limits<double>::infinity();
    for (int r = 0; r < opt.init_restarts; ++r) {
        double obj = 0.0;
        std::vector<Lobe> l = spherical_kmeans(d, kmeanspp(d, opt.lobes, mix_bits(opt.seed + uint64_t(r))), opt, &obj);
        if (obj < best_obj || lobes.empty()) {
            best_obj = obj;
            lobes.swap(l);
        }
        if (!(obj > 0.0)) break;  // every direction is a centre: nothing to improve
    }
    return em_from(d, std::move(lobes), opt);
}

double mixture_pdf(const VmfMixture &mixture, Vec3 w) {
    double p = 0.0;
    for (const VmfLobe &l : mixture.lobes) p += l.weight * vmf::pdf(l.mu, l.kappa, w);
    return p;
}

}  // namespace meso
