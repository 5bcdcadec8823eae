// T and S from the estimator's sums (paper 004 §6, eq. 12, 20-24): the means of one bin pair,
// the energy-matching rank-1 fit, the tables' standard errors, the rank-1 check and the
// stopping rule's per-ωo-bin medians; see scaling.h. The tracing that fills the sums is in
// scaling.cpp.
#include "prefilter/scaling.h"
#include <tbb/parallel_for.h>
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <memory>
#include <mutex>
#include <vector>

namespace meso::prefilter {

namespace {

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

double ScalingEstimator::denom_mean(int ch) const {
    double s = 0;
    size_t n = 0;
    const size_t tasks = size_t(m_opt.M) * m_opt.M * m_bins;
    for (size_t t = 0; t < tasks; ++t) {
        const double c = m_wsum_low[t];
        if (!(c > 0)) continue;
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
    const double no = m_area[t], nl = m_wsum_low[t];  // the weights' sums (scaling.h, "Weights")
    if (no > 0) {
        b.num = (ir ? m_nir[k] : m_n1[k]) / no;
        b.num_se = std::sqrt((ir ? m_nirsq[k] : m_n1sq[k])) / no;
        if (const double nc = m_wsum_cv[t]; nc > 0)
            b.num += m_cv[k] / nc, b.num_se = std::hypot(b.num_se, std::sqrt(m_cvsq[k]) / nc);
    }
    if (nl > 0) b.den = m_d[k] / nl, b.den_se = std::sqrt(m_dsq[k]) / nl;
    return b;
}

double ScalingEstimator::R(int patch, int bi, int bo, int ch, bool ir) const {
    const size_t t = size_t(patch) * m_bins + bo;
    const size_t k = (t * m_bins + bi) * 3 + ch;
    const double no = m_area[t], nl = m_wsum_low[t];
    const double eps = m_opt.epsilon * denom_mean(ch);
    const double nc = m_wsum_cv[t];
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
    size_t BB = 0;       ///< angular bin pairs (bo, bi), index bo B + bi
    int c0 = 0, nc = 3;  ///< the channels held: c0 .. c0 + nc - 1 (the stopping rule needs green alone)
    std::vector<double> num, den, vnum, vden, cov;
    size_t at(int p, size_t j, int c) const { return (size_t(p) * BB + j) * size_t(nc) + size_t(c - c0); }
};

/// The sums of one table set (numerator `sum`, its pair-difference squares `sq`, denominator
/// `dsum`/`dsq`, the cross terms `cross`) as means, variances and covariances of the means, of
/// channels c0 .. c0 + nc - 1, into m (its vectors keep their capacity: no new pages when reused).
void bin_pair_moments(const std::vector<double> &sum, const std::vector<double> &sq, const std::vector<double> &dsum,
                      const std::vector<double> &dsq, const std::vector<double> &cross,
                      const std::vector<double> &count_orig, const std::vector<double> &count_low,
                      const std::vector<double> &cv, const std::vector<double> &cvsq,
                      const std::vector<double> &count_cv, int P, int B, int c0, int nc, BinPairMoments &m) {
    m.BB = size_t(B) * B, m.c0 = c0, m.nc = nc;
    const size_t n_all = size_t(P) * m.BB * size_t(nc);
    m.num.resize(n_all), m.den.resize(n_all), m.vnum.resize(n_all), m.vden.resize(n_all), m.cov.resize(n_all);
    tbb::parallel_for(size_t(0), size_t(P) * B, [&](size_t t) {
        const double no = count_orig[t], nl = count_low[t], nc_ = cv.empty() ? 0.0 : count_cv[t];
        for (size_t e = t * B; e < (t + 1) * B; ++e)  // e = p BB + j: task t = p B + bo, j = bo B + bi
            for (int c = c0; c < c0 + nc; ++c) {
                const size_t k = e * 3 + size_t(c), o = e * size_t(nc) + size_t(c - c0);
                m.num[o] = (no > 0 ? sum[k] / no : 0.0) + (nc_ > 0 ? cv[k] / nc_ : 0.0);
                m.vnum[o] = (no > 0 ? sq[k] / (no * no) : 0.0) + (nc_ > 0 ? cvsq[k] / (nc_ * nc_) : 0.0);
                m.den[o] = nl > 0 ? dsum[k] / nl : 0.0;
                m.vden[o] = nl > 0 ? dsq[k] / (nl * nl) : 0.0;
                m.cov[o] = no > 0 && nl > 0 ? cross[k] / (no * nl) : 0.0;
            }
    });
}

/// The reciprocal half of S's numerators (scaling.h, "Reciprocity"): per bin pair j = (bo, bi),
/// bi != bo, and channel, the tile's numerator from j's own lines, N = Σ_P a_P(bo) num_P(j) /
/// Σ_P a_P(bo), and from the transposed pair's lines, R (rec_sum of task (P, bi) at ωi bin bo,
/// with a_P(bi)), averaged: C = w N + (1 - w) R with w = n(bo) / (n(bo) + n(bi)), n(b) the lines
/// shot for ωo bin b over all patches (½ while every bin has as many). The weights follow the
/// line counts, not the estimated variances: weights estimated from the same samples biased C low
/// by 2-7% in a test. With ½ whatever the counts, a pair whose transposed bin had stopped
/// (the stopping rule) kept ¼ of that bin's frozen variance however many lines its own bin
/// traced: the bench silk's median error sat at 0.0360-0.0354 over its last 9 rounds.
/// Every patch's num(j) is scaled by C / N, its variance so that the pooled relative error is
/// that of C, and its covariance with the denominator scaled by w (only N shares the
/// denominator's lines) and like the value. The averaged numerators lose
/// half of the common random numbers' cancellation, so finish() keeps them only where they lower
/// S's median standard error (ScalingStats::reciprocity_used).
struct Reciprocal {
    /// area: per task, Σ |Q| / |P| over its accepted lines, both a_P's numerator and the divisor
    /// of the transposed lines' means (the weights' sum, scaling.h "Weights").
    const std::vector<double> &sum, &sq, &area;
    const std::vector<uint32_t> &shot;
};
/// The reciprocity check (scaling.h, "Reciprocity"): Σ R / Σ N (green, the tile's two estimates
/// of the same bin pairs) over the pairs with both bins inside the outer ring, with ωi in it
/// (ωo inside), and with ωo in it (ωi inside); 1 where the estimator is reciprocal.
struct ReciprocityCheck {
    double n[3] = {0, 0, 0}, r[3] = {0, 0, 0};
    double ratio(int k) const { return n[k] > 0 ? r[k] / n[k] : 0.0; }
};
void apply_reciprocity(BinPairMoments &m, const Reciprocal &r, int P, int N, bool combine, ReciprocityCheck &check) {
    const int B = N * N;
    auto outer = [&](int b) { return b % N == 0 || b % N == N - 1 || b / N == 0 || b / N == N - 1; };
    std::vector<ReciprocityCheck> per_bo(static_cast<size_t>(B));
    std::vector<double> a(size_t(P) * B);  // a_P(b): the mean over task (P, b)'s shot lines of accepted · |Q| / |P|
    for (size_t t = 0; t < a.size(); ++t) a[t] = r.shot[t] > 0 ? r.area[t] / r.shot[t] : 0.0;
    std::vector<double> lines(static_cast<size_t>(B), 0.0);  // n(b): lines shot for ωo bin b, all patches
    for (size_t t = 0; t < a.size(); ++t) lines[t % size_t(B)] += double(r.shot[t]);
    tbb::parallel_for(0, B, [&](int bo) {
        for (int bi = 0; bi < B; ++bi) {
            if (bi == bo) continue;
            const size_t j = size_t(bo) * B + size_t(bi);
            for (int c = m.c0; c < m.c0 + m.nc; ++c) {
                double wn = 0, n = 0, vn = 0, wr = 0, rr = 0, vr = 0, pooled = 0, vpooled = 0;
                for (int p = 0; p < P; ++p) {
                    const size_t k = m.at(p, j, c);
                    const double ao = a[size_t(p) * B + bo], ai = a[size_t(p) * B + bi];
                    wn += ao, n += ao * m.num[k], vn += ao * ao * m.vnum[k];
                    pooled += m.num[k], vpooled += m.vnum[k];
                    const size_t tt = size_t(p) * B + size_t(bi);  // the transposed pair's task
                    if (const double cnt = r.area[tt]; cnt > 0) {
                        const size_t kr = (tt * B + size_t(bo)) * 3 + size_t(c);
                        wr += ai, rr += ai * r.sum[kr] / cnt, vr += ai * ai * r.sq[kr] / (cnt * cnt);
                    }
                }
                if (!(wn > 0) || !(wr > 0)) continue;  // one side has no accepted line: keep the direct one
                n /= wn, vn /= wn * wn, rr /= wr, vr /= wr * wr;
                if (c == 1 && N > 2) {
                    const int k = outer(bi) ? (outer(bo) ? -1 : 1) : (outer(bo) ? 2 : 0);
                    if (k >= 0) per_bo[size_t(bo)].n[k] += n, per_bo[size_t(bo)].r[k] += rr;
                }
                if (!combine) continue;
                const double nl = lines[size_t(bo)] + lines[size_t(bi)];
                const double w = nl > 0 ? lines[size_t(bo)] / nl : 0.5;
                const double comb = w * n + (1 - w) * rr, vcomb = w * w * vn + (1 - w) * (1 - w) * vr;
                if (n > 0 && pooled > 0) {
                    const double f = comb / n, target_rel2 = comb > 0 ? vcomb / (comb * comb) : 0.0;
                    const double kv = vpooled > 0 ? target_rel2 * (f * pooled) * (f * pooled) / vpooled : 0.0;
                    for (int p = 0; p < P; ++p) {
                        const size_t k = m.at(p, j, c);
                        m.num[k] *= f, m.vnum[k] *= kv, m.cov[k] *= w * f;
                    }
                } else if (comb > 0) {  // nothing from the direct lines: the transposed half alone, every patch
                    for (int p = 0; p < P; ++p) {
                        const size_t k = m.at(p, j, c);
                        m.num[k] = comb, m.vnum[k] = double(P) * vcomb, m.cov[k] = 0.0;
                    }
                }
            }
        }
    });
    for (const ReciprocityCheck &q : per_bo)
        for (int k = 0; k < 3; ++k) check.n[k] += q.n[k], check.r[k] += q.r[k];
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
    // Channel c's denominators, contiguous by patch (den[p BB + j]), and the sums of the
    // numerators that do not change between sweeps: over patches per bin pair (num_b) and over
    // bin pairs per patch (num_p). Every sum runs in the same order as a direct loop over
    // m.at(p, j, c) (p, then j ascending), so the factors do not depend on this layout.
    std::vector<double> den(size_t(P) * BB), num_b(BB, 0.0), num_p(size_t(P), 0.0), d_b(BB);
    double dtot = 0, ntot = 0;
    for (int p = 0; p < P; ++p)
        for (size_t j = 0; j < BB; ++j) {
            const double n = m.num[m.at(p, j, c)], d = m.den[m.at(p, j, c)];
            den[size_t(p) * BB + j] = d;
            dtot += d, ntot += n;
            num_b[j] += n, num_p[size_t(p)] += n;
        }
    std::vector<double> T(size_t(P), 1.0), S(BB, 1.0);
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
        std::fill(d_b.begin(), d_b.end(), 0.0);
        for (int p = 0; p < P; ++p) {
            const double t = T[size_t(p)], *dp = &den[size_t(p) * BB];
            for (size_t j = 0; j < BB; ++j) d_b[j] += t * dp[j];
        }
        double cap = 0;
        for (size_t j = 0; j < BB; ++j) {
            S[j] = (num_b[j] + eps_b * S_g) / (d_b[j] + eps_b);
            if (d_b[j] >= 0.1 * dtot / double(BB)) cap = std::max(cap, S[j]);
        }
        if (cap > 0)
            for (size_t j = 0; j < BB; ++j) S[j] = std::min(S[j], cap);
        f.S_cap[c] = cap;
        double change = 0;
        for (int p = 0; p < P; ++p) {
            // Σ_j S_j den_pj in four running sums: one sum was a chain of dependent additions
            // (their latency, not the loads, set the fit's pace: 225² terms a patch, 30 sweeps).
            const double *dp = &den[size_t(p) * BB];
            double d4[4] = {0, 0, 0, 0};
            size_t j = 0;
            for (; j + 4 <= BB; j += 4)
                for (int k = 0; k < 4; ++k) d4[k] += S[j + k] * dp[j + k];
            for (; j < BB; ++j) d4[0] += S[j] * dp[j];
            const double d = (d4[0] + d4[1]) + (d4[2] + d4[3]);
            const double t = (num_p[size_t(p)] + eps_p) / (d + eps_p);
            change = std::max(change, std::abs(t / T[size_t(p)] - 1.0));
            T[size_t(p)] = t;
        }
        if (change < 1e-7) break;
    }
    double mean = 0;
    for (int p = 0; p < P; ++p) mean += T[size_t(p)] / P;
    if (mean > 0) {
        for (int p = 0; p < P; ++p) T[size_t(p)] /= mean;
        for (size_t j = 0; j < BB; ++j) S[j] *= mean;
        f.T_mean[c] = mean;
    }
    for (int p = 0; p < P; ++p) f.T[size_t(p) * 3 + c] = T[size_t(p)];
    for (size_t j = 0; j < BB; ++j) f.S[j * 3 + c] = S[j];
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
    /// Medians over the bin pairs of the numerator's and the denominator's relative variance
    /// (va / a², vd / d² of S's delta method: the line allocation's A and D before per-line scaling).
    double rel_var_num = 0, rel_var_den = 0;
    double reciprocity[3] = {0, 0, 0};  ///< ReciprocityCheck's ratios (0: not checked)
    bool reciprocity_used = false;      ///< the tables are the reciprocal average's
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
    std::vector<double> s_rel, s_rel_outer, s_rel_paper, rv_num, rv_den;
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
            rv_num.push_back(va / (a * a)), rv_den.push_back(vd / (d * d));
        }
    }
    o.rel_var_num = median_of(rv_num), o.rel_var_den = median_of(rv_den);
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
/// Workspaces of the stopping rule's finish, reused across rounds and levels (their vectors keep
/// their capacity). A finish takes one for its duration: the levels' checks run in parallel and a
/// thread waiting in a finish's nested parallel loop may start another level's, so a workspace is
/// never shared (not per thread). The pool holds at most as many as ever ran at once.
class MomentsPool {
public:
    struct Work {
        BinPairMoments m, mr;
    };
    class Lease {
    public:
        explicit Lease(MomentsPool *pool) : m_pool(pool), m_work(pool ? pool->take() : std::make_unique<Work>()) {}
        ~Lease() {
            if (m_pool) m_pool->give(std::move(m_work));
        }
        Lease(const Lease &) = delete;
        Lease &operator=(const Lease &) = delete;
        Work &work() { return *m_work; }

    private:
        MomentsPool *m_pool;
        std::unique_ptr<Work> m_work;
    };
    std::unique_ptr<Work> take() {
        std::lock_guard<std::mutex> lock(m_mutex);
        if (m_free.empty()) return std::make_unique<Work>();
        std::unique_ptr<Work> w = std::move(m_free.back());
        m_free.pop_back();
        return w;
    }
    void give(std::unique_ptr<Work> w) {
        std::lock_guard<std::mutex> lock(m_mutex);
        m_free.push_back(std::move(w));
    }

private:
    std::mutex m_mutex;
    std::vector<std::unique_ptr<Work>> m_free;
};
MomentsPool &moments_pool() {
    static MomentsPool pool;
    return pool;
}
}  // namespace

void ScalingEstimator::finish_impl(ScalingTables &single, ScalingTables &ir_tab, ScalingStats &stats,
                                   std::vector<double> *per_bo, double *rel_var) const {
    const int M = m_opt.M, N = m_opt.N, B = m_bins, P = M * M;
    stats = m_stats;
    // The stopping rule's finish (per_bo: every round, every level) needs S's standard errors,
    // which are the green channel's (standard_errors), and no tables: it fits channel 1 alone, and
    // its moments live in a workspace from a pool, reused from round to round (a new 100 MB a
    // table set each round had cost the plane chain about 2 s a round, mostly page faults).
    MomentsPool::Lease lease(per_bo ? &moments_pool() : nullptr);
    MomentsPool::Work &w = lease.work();
    const int c0 = per_bo ? 1 : 0, nc = per_bo ? 1 : 3;
    // One table set: moments, rank-1 factors, tables, then the diagnostics of the fit.
    auto build = [&](bool use_ir, ScalingTables &tab, TableStats &o) {
        BinPairMoments &m = w.m, &mr = w.mr;
        bin_pair_moments(use_ir ? m_nir : m_n1, use_ir ? m_nirsq : m_n1sq, m_d, m_dsq, use_ir ? m_nirx : m_n1x,
                         m_area, m_wsum_low, m_cv, m_cvsq, m_wsum_cv, P, B, c0, nc, m);
        auto fit = [&](const BinPairMoments &mm, Rank1Factors &f, TableStats &st) {
            f.T.assign(size_t(P) * 3, 1.0);
            f.S.assign(mm.BB * 3, 1.0);
            tbb::parallel_for(mm.c0, mm.c0 + mm.nc, [&](int c) { fit_rank1_channel(mm, P, c, m_opt.epsilon, f); });
            standard_errors(mm, f, m_count_orig, m_count_low, P, N, st);
        };
        Rank1Factors f;
        fit(m, f, o);
        if (!m_r1.empty()) {
            // The reciprocal average (scaling.h, "Reciprocity"), kept when it lowers S's median error.
            mr = m;  // copy-assignment keeps mr's capacity
            ReciprocityCheck check;
            apply_reciprocity(mr, Reciprocal{use_ir ? m_rir : m_r1, use_ir ? m_rirsq : m_r1sq, m_area, m_shot},
                              P, N, m_opt.reciprocity, check);
            double ratios[3];
            for (int k = 0; k < 3; ++k) ratios[k] = check.ratio(k);
            if (m_opt.reciprocity) {
                Rank1Factors fr;
                TableStats orr;
                fit(mr, fr, orr);
                if (orr.med < o.med) std::swap(m, mr), f = std::move(fr), o = std::move(orr), o.reciprocity_used = true;
            }
            for (int k = 0; k < 3; ++k) o.reciprocity[k] = ratios[k];
        }
        if (!per_bo) write_tables(f, M, N, tab), rank1_check(m, f, P, N, o);
    };
    TableStats o1;
    build(false, single, o1);
    stats.S_rel_se_median = o1.med, stats.S_rel_se_p90 = o1.p90, stats.S_rel_se_max = o1.mx;
    stats.S_rel_se_median_outer = o1.med_outer, stats.T_rel_se_max = o1.t_max, stats.T_rel_se_median = o1.t_med;
    stats.rank1_energy = o1.energy, stats.rank1_svd_rel_error = o1.svd_err, stats.ts_rel_error = o1.ts_err;
    stats.paper_ts_rel_error = o1.paper_err;
    stats.S_rel_se_median_paper_counts = o1.med_paper;
    stats.singular_values = o1.sv;
    for (int k = 0; k < 3; ++k) stats.reciprocity_check[k] = o1.reciprocity[k];
    stats.reciprocity_used = o1.reciprocity_used;
    if (per_bo) per_wo_bin_medians(o1.pair_rel, B, *per_bo);
    if (rel_var) rel_var[0] = o1.rel_var_num, rel_var[1] = o1.rel_var_den;
    if (m_opt.interreflections) {
        TableStats o2;
        build(true, ir_tab, o2);
        stats.S_ir_rel_se_median = o2.med, stats.S_ir_rel_se_p90 = o2.p90;
        stats.S_ir_rel_se_median_outer = o2.med_outer, stats.T_ir_rel_se_max = o2.t_max;
        stats.T_ir_rel_se_median = o2.t_med;
        stats.reciprocity_used_ir = o2.reciprocity_used;
        stats.rank1_energy_ir = o2.energy, stats.rank1_svd_rel_error_ir = o2.svd_err, stats.ts_rel_error_ir = o2.ts_err;
        stats.paper_ts_rel_error_ir = o2.paper_err;
        stats.S_ir_rel_se_median_paper_counts = o2.med_paper;
        stats.singular_values_ir = o2.sv;
        if (per_bo) {
            std::vector<double> ir_bo;
            per_wo_bin_medians(o2.pair_rel, B, ir_bo);
            for (int b = 0; b < B; ++b) (*per_bo)[size_t(b)] = std::max((*per_bo)[size_t(b)], ir_bo[size_t(b)]);
        }
        if (rel_var && o2.med > o1.med) rel_var[0] = o2.rel_var_num, rel_var[1] = o2.rel_var_den;
    } else {
        ir_tab = ScalingTables{};
    }
}

ScalingEstimator::SeCache ScalingEstimator::se_cache() const {
    // The sums change only in a round, so one finish_impl a round serves the pipeline's check
    // (current_S_rel_se) and the next round's stopping rule (S_rel_se_per_wo_bin): each was a
    // whole fit of T and S (0.7 s a level on the bench plane, twice a round).
    std::lock_guard<std::mutex> lock(m_se_mutex);
    if (m_se_cache.rounds != m_stats.rounds) {
        ScalingTables a, b;
        ScalingStats s;
        m_se_cache.per_bo.clear();
        finish_impl(a, b, s, &m_se_cache.per_bo, m_se_cache.rel_var);
        m_se_cache.median = m_opt.interreflections ? std::max(s.S_rel_se_median, s.S_ir_rel_se_median) : s.S_rel_se_median;
        m_se_cache.rounds = m_stats.rounds;
    }
    return m_se_cache;  // a copy, made under the lock
}

double ScalingEstimator::current_S_rel_se() const { return se_cache().median; }

std::vector<double> ScalingEstimator::S_rel_se_per_wo_bin() const { return se_cache().per_bo; }

}  // namespace meso::prefilter
