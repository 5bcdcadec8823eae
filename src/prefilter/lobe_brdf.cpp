// The closed-form per-lobe f'_low ("--flow lobes"); the model and its derivation are in lobe_brdf.h.
#include "prefilter/lobe_brdf.h"
#include <algorithm>
#include <atomic>
#include <cstdint>
#include <cmath>
#include <cstring>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <smmintrin.h>
#include <tbb/parallel_for.h>
#include "core/error.h"
#include "core/float_trig.h"
#include "core/frame.h"
#include "core/properties.h"
#include "filter/vmf.h"
#include "sampling/rng.h"

namespace meso::prefilter {

namespace {
constexpr float kPiF = 3.14159265358979f;
constexpr double kPiD = 3.14159265358979323846;

/// C(t, κ) and H(t, κ) on a grid: t ∈ [−1, 1] in kT nodes (one at t = 0, where κ → ∞ kinks),
/// rows s = √κ / (√κ + kRowScale) ∈ [0, 1] in kK nodes (the last row is κ = ∞: max(0, t) and the
/// step; the one before κ ≈ 1.6e4, where the kinks are narrower than a column).
struct VmfTables {
    static constexpr int kT = 129, kK = 65;
    static constexpr double kRowScale = 2.0;
    std::vector<float> C, H;  ///< row-major [row * kT + column]
    /// ∫ from −1 to column i of row r's piecewise-linear C (trapezoids), row-major like C: the
    /// CDF that samples t exactly from the tabulated C (sample_t).
    std::vector<double> Ccum;
    /// Per row, kG cutpoints (Chen and Asau 1974): guide[row * kG + g] = the column holding the
    /// fraction g / kG of the row's mass (sample_t starts there).
    static constexpr int kG = 128;
    std::vector<uint8_t> guide;
    /// The bilinear cells of C, one 16-byte vector each: Cq[4 (r (kT − 1) + i) + {0, 1, 2, 3}] =
    /// C[r][i], C[r][i + 1], C[r + 1][i], C[r + 1][i + 1] (clamped_cosine4: one load a lane).
    std::vector<float> Cq;
    VmfTables() : C(size_t(kT) * kK), H(size_t(kT) * kK), Ccum(size_t(kT) * kK), guide(size_t(kG) * kK) {
        for (int r = 0; r < kK; ++r)
            for (int i = 0; i < kT; ++i) {
                const double t = std::clamp(-1.0 + 2.0 * i / (kT - 1), -1.0, 1.0);
                const size_t k = size_t(r) * kT + size_t(i);
                if (r == kK - 1) {
                    C[k] = float(std::max(0.0, t));
                    H[k] = t > 0.0 ? 1.f : t < 0.0 ? 0.f : 0.5f;
                    continue;
                }
                const double s = double(r) / (kK - 1), kappa = std::pow(kRowScale * s / (1.0 - s), 2.0);
                const Vec3 mu(float(std::sqrt(std::max(0.0, 1.0 - t * t))), 0.f, float(t));
                C[k] = float(vmf_projected_area(mu, kappa));
                H[k] = float(vmf_cap_mass(mu, kappa));
            }
        const double dt = 2.0 / (kT - 1);
        for (int r = 0; r < kK; ++r)
            for (int i = 1; i < kT; ++i) {
                const size_t k = size_t(r) * kT + size_t(i);
                Ccum[k] = Ccum[k - 1] + 0.5 * dt * (double(C[k - 1]) + double(C[k]));
            }
        Cq.resize(size_t(kK - 1) * (kT - 1) * 4);
        for (int r = 0; r + 1 < kK; ++r)
            for (int i = 0; i + 1 < kT; ++i) {
                float *q = &Cq[4 * (size_t(r) * (kT - 1) + size_t(i))];
                const size_t a = size_t(r) * kT + size_t(i), b = a + kT;
                q[0] = C[a], q[1] = C[a + 1], q[2] = C[b], q[3] = C[b + 1];
            }
        static_assert(kT - 2 <= 255, "guide entries are bytes");
        for (int r = 0; r < kK; ++r) {
            const double *cum = &Ccum[size_t(r) * kT];
            int col = 0;
            for (int g = 0; g < kG; ++g) {
                const double target = double(g) / kG * cum[kT - 1];
                while (col < kT - 2 && cum[col + 1] <= target) ++col;
                guide[size_t(r) * kG + size_t(g)] = uint8_t(col);
            }
        }
    }
    static float row(double kappa) {
        const double q = std::sqrt(std::max(0.0, kappa)), s = std::isinf(kappa) ? 1.0 : q / (q + kRowScale);
        return float(std::clamp(s, 0.0, 1.0) * (kK - 1));
    }
    /// ∫ C(t, row) dt over [−1, 1] of the bilinear table (so the sphere integral of C(μ·ω) is 2π
    /// times it; π for the exact C).
    double mass(float row) const {
        const int r = std::min(int(row), kK - 2);
        const double fy = double(row) - r;
        return (1.0 - fy) * Ccum[size_t(r) * kT + kT - 1] + fy * Ccum[size_t(r + 1) * kT + kT - 1];
    }
    /// t = μ·ω with density C(t, row) / mass(row) on [−1, 1], exactly as the bilinear table
    /// gives it (lookup): the table's row blend is a mixture of its two rows (one chosen with
    /// u, then u rescaled to the chosen row's share), each row piecewise linear in t (the column
    /// from its CDF, the position in the column by inverting the linear density's quadratic CDF).
    float sample_t(float row, float u) const {
        const int r0 = std::min(int(row), kK - 2);
        const double fy = double(row) - r0;
        const double w0 = (1.0 - fy) * Ccum[size_t(r0) * kT + kT - 1], w1 = fy * Ccum[size_t(r0 + 1) * kT + kT - 1];
        const double p0 = w0 / (w0 + w1);
        double v = std::clamp(double(u), 0.0, 1.0);
        const int r = v < p0 ? r0 : r0 + 1;
        v = v < p0 ? v / p0 : (v - p0) / (1.0 - p0);
        const double *cum = &Ccum[size_t(r) * kT];
        const float *c = &C[size_t(r) * kT];
        const double target = std::min(v, 1.0 - 1e-12) * cum[kT - 1];
        // The first column whose end is past the target: a column of zero mass is never chosen.
        // The column from the row's guide (the one holding target's share of the row, kG cells of
        // equal mass), then the few steps to it; the same column as std::upper_bound over cum[1 ..
        // kT), whose binary search over a table beyond L1 cost a cache access per step.
        const int g = cum[kT - 1] > 0.0 ? std::clamp(int(target / cum[kT - 1] * kG), 0, kG - 1) : 0;
        int col = guide[size_t(r) * kG + size_t(g)];
        while (col > 0 && cum[col] > target) --col;
        while (col < kT - 2 && cum[col + 1] <= target) ++col;
        const double dt = 2.0 / (kT - 1), a = c[col], b = c[col + 1], m = (target - cum[col]) / dt;
        // Density a + (b − a) x on x ∈ [0, 1] (times dt): a x + (b − a) x² / 2 = m.
        double x;
        if (std::abs(b - a) < 1e-9 * std::max(a, b)) x = a > 0.0 ? m / a : 0.5;
        else x = (std::sqrt(std::max(0.0, a * a + 2.0 * (b - a) * m)) - a) / (b - a);
        return float(std::clamp(-1.0 + (double(col) + std::clamp(x, 0.0, 1.0)) * dt, -1.0, 1.0));
    }
    static float lookup(const std::vector<float> &tab, float t, float row) {
        const float x = std::clamp((t + 1.f) * 0.5f * (kT - 1), 0.f, float(kT - 1));
        const int i = std::min(int(x), kT - 2), r = std::min(int(row), kK - 2);
        const float fx = x - float(i), fy = row - float(r);
        const float *a = &tab[size_t(r) * kT + size_t(i)], *b = a + kT;
        return (1.f - fy) * ((1.f - fx) * a[0] + fx * a[1]) + fy * ((1.f - fx) * b[0] + fx * b[1]);
    }
};

[[gnu::always_inline]] inline const VmfTables &vmf_tables() {  // the hot loops: no call for the guard check
    static const VmfTables t;
    return t;
}

/// e^x for x <= 0 in four lanes (Cephes' expf: 2^n times a degree-6 polynomial on
/// [−ln2/2, ln2/2]; relative error ~2e-7; 0 below −87). Used by eval AND pdf, so they agree.
inline __m128 exp_nonpositive(__m128 x) {
    const __m128 lo = _mm_set1_ps(-87.f);
    const __m128 under = _mm_cmplt_ps(x, lo);
    x = _mm_max_ps(x, lo);
    const __m128 n = _mm_floor_ps(_mm_add_ps(_mm_mul_ps(x, _mm_set1_ps(1.44269504088896341f)), _mm_set1_ps(0.5f)));
    const __m128 r = _mm_sub_ps(_mm_sub_ps(x, _mm_mul_ps(n, _mm_set1_ps(0.693359375f))),
                                _mm_mul_ps(n, _mm_set1_ps(-2.12194440e-4f)));
    // Horner written out: GCC kept a loop over the coefficients (reloaded from the stack each step).
    __m128 p = _mm_set1_ps(1.9875691500e-4f);
    p = _mm_add_ps(_mm_mul_ps(p, r), _mm_set1_ps(1.3981999507e-3f));
    p = _mm_add_ps(_mm_mul_ps(p, r), _mm_set1_ps(8.3334519073e-3f));
    p = _mm_add_ps(_mm_mul_ps(p, r), _mm_set1_ps(4.1665795894e-2f));
    p = _mm_add_ps(_mm_mul_ps(p, r), _mm_set1_ps(1.6666665459e-1f));
    p = _mm_add_ps(_mm_mul_ps(p, r), _mm_set1_ps(5.0000001201e-1f));
    p = _mm_add_ps(_mm_add_ps(_mm_mul_ps(_mm_mul_ps(p, r), r), r), _mm_set1_ps(1.f));
    const __m128i e = _mm_slli_epi32(_mm_add_epi32(_mm_cvtps_epi32(n), _mm_set1_epi32(127)), 23);
    return _mm_andnot_ps(under, _mm_mul_ps(p, _mm_castsi128_ps(e)));
}

/// Smith Λ of four lobes for directions at cosines z to μ: Walter et al. 2007's rational form for
/// Beckmann (eq. 27), the exact one for GGX. Lanes with z <= 0 give garbage (masked by the caller).
inline __m128 lambda4(bool ggx, __m128 alpha, __m128 a2, __m128 z) {
    const __m128 one = _mm_set1_ps(1.f), z2 = _mm_mul_ps(z, z);
    const __m128 s2 = _mm_max_ps(_mm_setzero_ps(), _mm_sub_ps(one, z2));
    if (ggx)
        return _mm_mul_ps(_mm_set1_ps(0.5f),
                          _mm_sub_ps(_mm_sqrt_ps(_mm_add_ps(one, _mm_div_ps(_mm_mul_ps(a2, s2), z2))), one));
    const __m128 a = _mm_div_ps(z, _mm_mul_ps(alpha, _mm_sqrt_ps(s2)));  // +inf at z = 1: Λ = 0 below
    const __m128 num = _mm_add_ps(_mm_sub_ps(one, _mm_mul_ps(_mm_set1_ps(1.259f), a)),
                                  _mm_mul_ps(_mm_set1_ps(0.396f), _mm_mul_ps(a, a)));
    const __m128 den = _mm_add_ps(_mm_mul_ps(_mm_set1_ps(3.535f), a), _mm_mul_ps(_mm_set1_ps(2.181f), _mm_mul_ps(a, a)));
    return _mm_and_ps(_mm_cmplt_ps(a, _mm_set1_ps(1.6f)), _mm_div_ps(num, den));
}

/// C(t_j, κ_j) of four lobes at cosines t (VmfTables::lookup, four lanes at once; each lane's
/// row and its fraction are the lobe's: crow = row · (kT − 1) and cfy). A lane's four corners
/// are one vector of the quad table Cq, the four vectors transposed into corner vectors.
inline __m128 clamped_cosine4(const int *crow, const float *cfy, __m128 t) {
    constexpr int kT = VmfTables::kT;
    const __m128 x = _mm_min_ps(_mm_max_ps(_mm_mul_ps(_mm_add_ps(t, _mm_set1_ps(1.f)), _mm_set1_ps(0.5f * (kT - 1))),
                                           _mm_setzero_ps()),
                                _mm_set1_ps(float(kT - 1)));
    const __m128i i = _mm_min_epi32(_mm_cvttps_epi32(x), _mm_set1_epi32(kT - 2));
    const __m128 fx = _mm_sub_ps(x, _mm_cvtepi32_ps(i)), fy = _mm_loadu_ps(cfy);
    alignas(16) int k[4];
    _mm_store_si128(reinterpret_cast<__m128i *>(k), _mm_add_epi32(i, _mm_loadu_si128(reinterpret_cast<const __m128i *>(crow))));
    const float *Cq = vmf_tables().Cq.data();
    __m128 a0 = _mm_loadu_ps(Cq + 4 * size_t(k[0])), a1 = _mm_loadu_ps(Cq + 4 * size_t(k[1]));
    __m128 b0 = _mm_loadu_ps(Cq + 4 * size_t(k[2])), b1 = _mm_loadu_ps(Cq + 4 * size_t(k[3]));
    _MM_TRANSPOSE4_PS(a0, a1, b0, b1);  // now C[r][i], C[r][i + 1], C[r + 1][i], C[r + 1][i + 1] by lane
    const __m128 one = _mm_set1_ps(1.f), gx = _mm_sub_ps(one, fx);
    return _mm_add_ps(_mm_mul_ps(_mm_sub_ps(one, fy), _mm_add_ps(_mm_mul_ps(gx, a0), _mm_mul_ps(fx, a1))),
                      _mm_mul_ps(fy, _mm_add_ps(_mm_mul_ps(gx, b0), _mm_mul_ps(fx, b1))));
}

/// The visible form's weights of four lobes at cosines lo = μ_j·ωo: c_j C(μ_j·ωo, κ_j) / C(μ_j,z, κ_j)
/// (view_weight); lanes with c = 0 give 0, and so do lanes with lo <= 0 where facing (microfacet
/// lobes, which need μ_j·ωo > 0; a Lambertian lobe's projected area is positive beyond it).
inline __m128 visible_weights(const float *c, const int *crow, const float *cfy, const float *inv_cz, __m128 lo,
                              bool facing = true) {
    const __m128 v = clamped_cosine4(crow, cfy, lo);
    const __m128 cv = _mm_load_ps(c);
    __m128 ok = _mm_cmpgt_ps(cv, _mm_setzero_ps());
    if (facing) ok = _mm_and_ps(ok, _mm_cmpgt_ps(lo, _mm_setzero_ps()));
    return _mm_and_ps(ok, _mm_mul_ps(_mm_mul_ps(cv, v), _mm_load_ps(inv_cz)));
}

inline float hsum(__m128 v) {
    v = _mm_add_ps(v, _mm_movehl_ps(v, v));
    v = _mm_add_ss(v, _mm_shuffle_ps(v, v, 1));
    return _mm_cvtss_f32(v);
}

/// The ωo side of one block of four microfacet lobes: lo = μ_j·ωo, the lanes' weights c towards
/// ωo (c_j, or its visible form; c [lo > 0] is the pdf's total) and Smith Λ(ωo) (lanes with lo <= 0
/// give garbage, masked by wi_terms). eval_batch computes it once per ωo for all its ωi.
struct WoTerms {
    __m128 lo, c, lam_o;
    __m128 c4lo;  ///< c / (4 lo): the ωo part of a lane's term (wi_terms), one division per ωo instead of per ωi
};
// (Templates on the block type: SvLobeBrdf::LobeBlock is private to the class.)
template <class Block>
inline WoTerms wo_terms(const Block &B, bool ggx, bool visible, __m128 ox, __m128 oy, __m128 oz) {
    const __m128 lo = _mm_add_ps(_mm_add_ps(_mm_mul_ps(_mm_load_ps(B.mx), ox), _mm_mul_ps(_mm_load_ps(B.my), oy)),
                                 _mm_mul_ps(_mm_load_ps(B.mz), oz));
    const __m128 c = visible ? visible_weights(B.c, B.crow, B.cfy, B.inv_cz, lo) : _mm_load_ps(B.c);
    return {lo, c, lambda4(ggx, _mm_load_ps(B.alpha), _mm_load_ps(B.a2), lo), _mm_div_ps(c, _mm_mul_ps(_mm_set1_ps(4.f), lo))};
}
/// Four lobe lanes' parameters and ωo side, as wi_terms reads them: a block's four lobes
/// (wi_terms), or one lobe broadcast against four ωi (eval_batch_microfacet).
struct LobeLanes {
    __m128 mx, my, mz, alpha, a2, inv_a2, d_norm;
    __m128 c, lam_o, c4lo;  ///< WoTerms' c, lam_o, c4lo
};
/// The ωi side of four lanes (ωi, half vector h): adds c D G / (4 μ_j·ωo) to sum and c D (μ_j·h)
/// to psum over the lanes of `facing` (μ_j·ωo > 0) whose lobe faces ωi and h. Lanes that fail a
/// condition are masked to 0 after the fact, so the infinities and NaNs of their divisions never
/// reach the sums; when no lane is left, nothing is added (the same as adding +0).
inline void lane_terms(const LobeLanes &L, __m128 facing, bool ggx, __m128 ix, __m128 iy, __m128 iz, __m128 hx,
                       __m128 hy, __m128 hz, __m128 &sum, __m128 &psum) {
    const __m128 zero = _mm_setzero_ps(), one = _mm_set1_ps(1.f);
    const __m128 li = _mm_add_ps(_mm_add_ps(_mm_mul_ps(L.mx, ix), _mm_mul_ps(L.my, iy)), _mm_mul_ps(L.mz, iz));
    const __m128 ch = _mm_add_ps(_mm_add_ps(_mm_mul_ps(L.mx, hx), _mm_mul_ps(L.my, hy)), _mm_mul_ps(L.mz, hz));
    const __m128 c2 = _mm_mul_ps(ch, ch);
    const __m128 ok = _mm_and_ps(_mm_and_ps(facing, _mm_cmpgt_ps(li, zero)),
                                 _mm_and_ps(_mm_cmpgt_ps(ch, zero), _mm_cmpgt_ps(c2, _mm_set1_ps(1e-12f))));
    if (_mm_movemask_ps(ok) == 0) return;
    __m128 D;
    if (ggx) {
        const __m128 d = _mm_add_ps(_mm_mul_ps(c2, _mm_sub_ps(L.a2, one)), one);
        D = _mm_div_ps(L.d_norm, _mm_mul_ps(d, d));
    } else {
        const __m128 t2 = _mm_div_ps(_mm_sub_ps(one, c2), c2);
        const __m128 x = _mm_mul_ps(_mm_sub_ps(zero, t2), L.inv_a2);
        // Every facing lane's exp underflows to exactly 0 (exp_nonpositive: x < -87): D = 0, and the
        // lanes would add exact zeros to both sums (x is finite on those lanes; the rest are masked).
        if (_mm_movemask_ps(_mm_and_ps(ok, _mm_cmpge_ps(x, _mm_set1_ps(-87.f)))) == 0) return;
        D = _mm_div_ps(_mm_mul_ps(L.d_norm, exp_nonpositive(x)), _mm_mul_ps(c2, c2));
    }
    D = _mm_and_ps(ok, D);
    psum = _mm_add_ps(psum, _mm_mul_ps(_mm_mul_ps(L.c, D), ch));
    // c D G / (4 μ_j·ωo) with G = 1 / (1 + Λ(ωo) + Λ(ωi)): one division (c / (4 lo) is per ωo).
    const __m128 term =
        _mm_div_ps(_mm_mul_ps(L.c4lo, D), _mm_add_ps(one, _mm_add_ps(L.lam_o, lambda4(ggx, L.alpha, L.a2, li))));
    sum = _mm_add_ps(sum, _mm_and_ps(ok, term));
}
/// The ωi side of one block of four lobes (lane_terms).
template <class Block>
inline void wi_terms(const Block &B, const WoTerms &o, bool ggx, __m128 ix, __m128 iy, __m128 iz, __m128 hx,
                     __m128 hy, __m128 hz, __m128 &sum, __m128 &psum) {
    const LobeLanes L{_mm_load_ps(B.mx),     _mm_load_ps(B.my),     _mm_load_ps(B.mz), _mm_load_ps(B.alpha),
                      _mm_load_ps(B.a2),     _mm_load_ps(B.inv_a2), _mm_load_ps(B.d_norm),
                      o.c,                   o.lam_o,               o.c4lo};
    lane_terms(L, _mm_cmpgt_ps(o.lo, _mm_setzero_ps()), ggx, ix, iy, iz, hx, hy, hz, sum, psum);
}

/// The ωo side of one patch's blocks, kept per thread for the last (model, patch, ωo) asked: a
/// path vertex asks eval_pdf (next-event), sample (the lobe choice, then eval_pdf at the sampled
/// direction) and sometimes pdf with the same ωo, and this side (the visible weights' table
/// lookups and Smith Λ(ωo)) is most of a pass. Keyed by the model's serial number (not its
/// address, which a later model may reuse) and ωo's bits: a hit returns exactly what a recompute
/// would. Patches of more than kMaxBlocks blocks are not cached.
/// The key of a per-thread ωo cache (WoCache, LambertWoCache): model serial, patch, ωo's bits.
struct WoKey {
    uint64_t serial = 0;  ///< 0: empty (serials start at 1)
    uint32_t patch = 0;
    float wx = 0.f, wy = 0.f, wz = 0.f;
    bool holds(uint64_t s, uint32_t p, const Vec3 &w) const {
        return serial == s && patch == p && std::memcmp(&wx, &w.x, sizeof(float)) == 0 &&
               std::memcmp(&wy, &w.y, sizeof(float)) == 0 && std::memcmp(&wz, &w.z, sizeof(float)) == 0;
    }
    void set(uint64_t s, uint32_t p, const Vec3 &w) { serial = s, patch = p, wx = w.x, wy = w.y, wz = w.z; }
};
struct WoCache {
    static constexpr uint32_t kMaxBlocks = 16;
    WoKey key;  ///< key.serial 0 while being filled
    float pt = 0.f;
    WoTerms terms[kMaxBlocks];
};
thread_local WoCache tl_wo_cache;
std::atomic<uint64_t> g_lobe_serial{0};

/// The ωo side of blocks B[0 .. nb) of patch `patch` of model `serial` (from the thread's cache
/// when it holds them) and pt, the sum of the weights towards ωo (eval_pdf's pdf total).
template <class Block>
const WoTerms *wo_side(const Block *B, uint32_t nb, uint64_t serial, uint32_t patch, bool ggx, bool visible,
                       const Vec3 &wo, float &pt) {
    WoCache &c = tl_wo_cache;
    const bool fits = nb <= WoCache::kMaxBlocks;
    if (fits && c.key.holds(serial, patch, wo)) {
        pt = c.pt;
        return c.terms;
    }
    thread_local std::vector<WoTerms> big;
    WoTerms *t = c.terms;
    if (!fits) big.resize(nb), t = big.data();
    c.key.serial = 0;  // invalid while being filled
    const __m128 ox = _mm_set1_ps(wo.x), oy = _mm_set1_ps(wo.y), oz = _mm_set1_ps(wo.z);
    __m128 ptot = _mm_setzero_ps();
    for (uint32_t b = 0; b < nb; ++b) {
        t[b] = wo_terms(B[b], ggx, visible, ox, oy, oz);
        ptot = _mm_add_ps(ptot, _mm_and_ps(_mm_cmpgt_ps(t[b].lo, _mm_setzero_ps()), t[b].c));
    }
    pt = hsum(ptot);
    if (fits) c.key.set(serial, patch, wo), c.pt = pt;
    return t;
}

/// The probe of make_lobe_base: wo and wi mirrored about z at cosine c (so h = z and ωi·h = c).
void mirrored_pair(double c, Vec3 &wo, Vec3 &wi) {
    const float s = float(std::sqrt(std::max(0.0, 1.0 - c * c)));
    wo = Vec3(s, 0.f, float(c));
    wi = Vec3(-s, 0.f, float(c));
}

/// The conductor's F(c) · specular_reflectance, from its eval at the mirrored pair (h = z).
std::vector<Spectrum> probe_fresnel(const Material &m, const MicrofacetDistribution &d, const std::string &where) {
    std::vector<Spectrum> F(LobeBase::kFresnelNodes);
    const Vec3 z(0.f, 0.f, 1.f);
    ShadingContext ctx, ctx2;
    ctx2.uv = Vec2(0.37f, 0.71f);
    for (int k = 1; k < LobeBase::kFresnelNodes; ++k) {
        const double c = double(k) / (LobeBase::kFresnelNodes - 1);
        Vec3 wo, wi;
        mirrored_pair(c, wo, wi);
        const double dg = double(d.D(z)) * d.G(wo, wi, z) / (4.0 * c);
        const Spectrum e = m.eval(ctx, wo, wi), e2 = m.eval(ctx2, wo, wi);
        if (!(dg > 0.0) || e.r != e2.r || e.g != e2.g || e.b != e2.b)
            throw MesoError(fmt::format("{}: --flow lobes needs a conductor whose reflectance is the same everywhere "
                                        "(no textured specular_reflectance)", where));
        F[size_t(k)] = e * float(1.0 / dg);
    }
    F[0] = F[1] * 2.f - F[2];  // extrapolated: the probe's G vanishes at grazing
    for (int q = 0; q < 3; ++q) F[0][q] = std::max(0.f, F[0][q]);
    return F;
}

/// The table must reproduce the base (isotropic Cook-Torrance with microfacet.h's D and G).
void check_microfacet_base(const LobeBase &lb, const MicrofacetDistribution &d, const std::string &where) {
    const Vec3 dirs[] = {normalize(Vec3(0.3f, 0.1f, 0.9f)), normalize(Vec3(-0.5f, 0.2f, 0.6f)),
                         normalize(Vec3(0.1f, -0.7f, 0.4f)), normalize(Vec3(-0.2f, -0.3f, 0.8f))};
    ShadingContext ctx;
    for (const Vec3 &wo : dirs)
        for (const Vec3 &wi : dirs) {
            const Vec3 h = normalize(wo + wi);
            const Spectrum e = lb.material->eval(ctx, wo, wi);
            const Spectrum p = lb.fresnel_at(dot(wi, h)) * float(double(d.D(h)) * d.G(wo, wi, h) / (4.0 * wo.z));
            for (int q = 0; q < 3; ++q)
                if (!(std::abs(e[q] - p[q]) <= 1e-3f * std::max(1e-3f, std::abs(e[q]))))
                    throw MesoError(fmt::format("{}: --flow lobes: the base does not evaluate as an isotropic rough "
                                                "conductor ({}): use --flow eq5",
                                                where, lb.material->to_string()));
        }
}

/// The Lambertian base's ρ/π (its eval at normal incidence) averaged over each patch of a w x h
/// grid of the tile (patch (i, j) = [i/w, (i+1)/w) x [j/h, (j+1)/h) in uv): jittered-stratified
/// points, kAlbedoStrataPerTile per tile axis (at least one per patch), a fixed seed per patch
/// (deterministic whatever the thread schedule). Exact for a nearest-filtered texture of up to
/// kAlbedoStrataPerTile texels aligned with the grid (a stratum lies inside one texel); finer
/// or unaligned textures get an unbiased estimate of the mean.
std::vector<Spectrum> patch_mean_lambert(const Material &base, int w, int h) {
    const int nu = std::max(1, (kAlbedoStrataPerTile + w - 1) / w), nv = std::max(1, (kAlbedoStrataPerTile + h - 1) / h);
    std::vector<Spectrum> out(size_t(w) * size_t(h));
    const Vec3 z(0.f, 0.f, 1.f);
    tbb::parallel_for(size_t(0), out.size(), [&](size_t k) {
        const int i = int(k % size_t(w)), j = int(k / size_t(w));
        PCG32 rng(k, 0x6a09e667f3bcc909ULL);
        double acc[3] = {0.0, 0.0, 0.0};
        ShadingContext ctx;
        for (int b = 0; b < nv; ++b)
            for (int a = 0; a < nu; ++a) {
                const double u = (double(i) + (a + double(rng.next_float())) / nu) / w;
                const double v = (double(j) + (b + double(rng.next_float())) / nv) / h;
                ctx.uv = Vec2(float(std::min(u, 0x1.fffffep-1)), float(std::min(v, 0x1.fffffep-1)));
                const Spectrum e = base.eval(ctx, z, z);
                for (int q = 0; q < 3; ++q) acc[q] += double(e[q]);
            }
        const double inv = 1.0 / (double(nu) * nv);
        out[k] = Spectrum(float(acc[0] * inv), float(acc[1] * inv), float(acc[2] * inv));
    });
    return out;
}
}  // namespace

double widened_alpha(double alpha, double kappa) {
    const double cap = std::max(alpha, kMaxWidenedAlpha);
    if (!(kappa > 2.0 / (cap * cap))) return cap;  // also κ = 0 and NaN
    return std::min(std::sqrt(alpha * alpha + 2.0 / kappa), cap);
}

float vmf_clamped_cosine(float t, double kappa) {
    return VmfTables::lookup(vmf_tables().C, t, VmfTables::row(kappa));
}
float vmf_cap_mass(float t, double kappa) { return VmfTables::lookup(vmf_tables().H, t, VmfTables::row(kappa)); }

Spectrum LobeBase::fresnel_at(float c) const {
    const float x = std::clamp(c, 0.f, 1.f) * float(kFresnelNodes - 1);
    const int i = std::min(int(x), kFresnelNodes - 2);
    const float f = x - float(i);
    return fresnel[size_t(i)] * (1.f - f) + fresnel[size_t(i) + 1] * f;
}

LobeBase make_lobe_base(std::shared_ptr<const Material> material, const nlohmann::json &json,
                        const std::string &where) {
    if (!material) throw MesoError(where + ": base material is null");
    const std::string type = json.is_object() && json.contains("type") && json["type"].is_string()
                                 ? json["type"].get<std::string>()
                                 : std::string();
    LobeBase lb;
    lb.material = std::move(material);
    if (type == "diffuse" && lb.material->flags() == BSDF_DiffuseReflection) {
        lb.kind = LobeBase::Kind::Lambertian;
        return lb;
    }
    if (type != "conductor")
        throw MesoError(fmt::format("{}: --flow lobes supports a \"diffuse\" or a rough \"conductor\" base given as "
                                    "an object, not {}: use --flow eq5",
                                    where, type.empty() ? json.dump() : "\"" + type + "\""));
    Properties p(json, where, std::make_shared<LoadContext>());
    const std::optional<MicrofacetDistribution> d = microfacet_from_properties(p, false, 0.f);
    if (!d) throw MesoError(where + ": --flow lobes needs a rough conductor (alpha >= 1e-4)");
    lb.kind = LobeBase::Kind::Microfacet;
    lb.type = d->type();
    lb.alpha = d->alpha_u();
    lb.fresnel = probe_fresnel(*lb.material, *d, where);
    check_microfacet_base(lb, *d, where);
    return lb;
}

// ---------------------------------------------------------------------------------------

SvLobeBrdf::SvLobeBrdf(LobeBase base, const std::vector<PatchNdf> &ndf, int width, int height, bool patch_mean_albedo,
                       bool visible_lambert, bool visible_microfacet)
    : m_base(std::move(base)),
      m_visible(m_base.kind == LobeBase::Kind::Lambertian ? visible_lambert : visible_microfacet), m_w(width),
      m_h(height), m_serial(++g_lobe_serial) {
    if (width < 1 || height < 1 || ndf.size() != size_t(width) * size_t(height))
        throw MesoError(fmt::format("lobes f'_low: {} patch NDFs for a {}x{} grid", ndf.size(), width, height));
    m_first.reserve(ndf.size() + 1);
    for (size_t k = 0; k < ndf.size(); ++k) {
        m_first.push_back(uint32_t(m_lobes.size()));
        const PatchNdf &P = ndf[k];
        if (!std::isfinite(P.amplitude) || P.amplitude < 0.0)
            throw MesoError(fmt::format("lobes f'_low: patch {}: NDF amplitude must be finite and >= 0, got {}", k,
                                        P.amplitude));
        for (size_t j = 0; j < P.lobes.size(); ++j) {
            const VmfLobe &v = P.lobes[j];
            const double ml = std::sqrt(double(v.mu.x) * v.mu.x + double(v.mu.y) * v.mu.y + double(v.mu.z) * v.mu.z);
            if (std::isnan(v.kappa) || v.kappa < 0.0 || !std::isfinite(v.weight) || v.weight < 0.0 || !(ml > 0.0) ||
                !std::isfinite(ml))
                throw MesoError(fmt::format("lobes f'_low: patch {}: invalid lobe {} (kappa {}, weight {}, |mu| {})", k,
                                            j, v.kappa, v.weight, ml));
            Lobe l;
            l.mu = Vec3(float(v.mu.x / ml), float(v.mu.y / ml), float(v.mu.z / ml));
            const double kappa = std::min(v.kappa, vmf::kMaxKappa);
            l.krow = VmfTables::row(kappa);
            l.hz = VmfTables::lookup(vmf_tables().H, l.mu.z, l.krow);
            l.cz = VmfTables::lookup(vmf_tables().C, l.mu.z, l.krow);
            // The visible form weights the lobe by its projected area towards ωo, A a_j C(μ_j·ωo, κ_j):
            // c_j = A a_j C(μ_j,z, κ_j) is that at the pole (view_weight: c_j C(μ_j·ωo) / C(μ_j,z)).
            l.c = float(P.amplitude * v.weight * (m_visible ? l.cz : l.hz));
            if (!(l.c > 0.f) || !(l.hz > 0.f) || !(l.cz > 0.f)) continue;
            const double a = widened_alpha(m_base.alpha, kappa);
            l.alpha = float(a);
            l.inv_a2 = float(1.0 / (a * a));
            l.d_norm = float(m_base.type == MicrofacetType::GGX ? a * a / kPiD : 1.0 / (kPiD * a * a));
            l.inv_mass = float(1.0 / (2.0 * kPiD * vmf_tables().mass(l.krow)));
            m_lobes.push_back(l);
        }
    }
    m_first.push_back(uint32_t(m_lobes.size()));
    if (m_visible) {
        m_visible_scale.assign(ndf.size(), 0.f);
        for (size_t k = 0; k < ndf.size(); ++k)
            for (uint32_t j = m_first[k]; j < m_first[k + 1]; ++j) m_visible_scale[k] += m_lobes[j].c;
    }
    if (m_base.kind == LobeBase::Kind::Lambertian && patch_mean_albedo)
        m_albedo = patch_mean_lambert(*m_base.material, m_w, m_h);
    // The same lobes by component, four per block.
    m_first_block.reserve(m_first.size());
    for (size_t k = 0; k + 1 < m_first.size(); ++k) {
        m_first_block.push_back(uint32_t(m_blocks.size()));
        for (uint32_t j = m_first[k]; j < m_first[k + 1]; ++j) {
            if ((j - m_first[k]) % 4 == 0) m_blocks.emplace_back();
            LobeBlock &B = m_blocks.back();
            const Lobe &l = m_lobes[j];
            const int q = int((j - m_first[k]) % 4);
            B.mx[q] = l.mu.x, B.my[q] = l.mu.y, B.mz[q] = l.mu.z, B.c[q] = l.c;
            B.alpha[q] = l.alpha, B.a2[q] = l.alpha * l.alpha, B.inv_a2[q] = l.inv_a2, B.d_norm[q] = l.d_norm;
            const int r = std::min(int(l.krow), VmfTables::kK - 2);
            B.crow[q] = r * (VmfTables::kT - 1), B.cfy[q] = l.krow - float(r), B.inv_cz[q] = 1.f / l.cz;
            B.inv_mass[q] = l.inv_mass;
        }
    }
    m_first_block.push_back(uint32_t(m_blocks.size()));
}

float SvLobeBrdf::view_weight(const Lobe &l, const Vec3 &wo) const {
    return l.c * std::min(1.f, VmfTables::lookup(vmf_tables().H, dot(l.mu, wo), l.krow) / l.hz);
}

size_t SvLobeBrdf::patch_index(Vec2 uv) const {
    const float u = uv.x - std::floor(uv.x), v = uv.y - std::floor(uv.y);
    const int i = std::clamp(int(u * float(m_w)), 0, m_w - 1), j = std::clamp(int(v * float(m_h)), 0, m_h - 1);
    return size_t(j) * size_t(m_w) + size_t(i);
}

void SvLobeBrdf::prefetch(Vec2 uv) const {
    const size_t patch = patch_index(uv);
    const char *p = reinterpret_cast<const char *>(m_blocks.data() + m_first_block[patch]);
    const size_t bytes = size_t(m_first_block[patch + 1] - m_first_block[patch]) * sizeof(LobeBlock);
    for (size_t o = 0; o < bytes; o += 64) _mm_prefetch(p + o, _MM_HINT_T0);
}

std::pair<const SvLobeBrdf::Lobe *, const SvLobeBrdf::Lobe *> SvLobeBrdf::lobes(size_t k) const {
    const Lobe *base = m_lobes.data();
    return {base + m_first[k], base + m_first[k + 1]};
}

Spectrum SvLobeBrdf::lambert(const ShadingContext &ctx, size_t patch) const {
    if (!m_albedo.empty()) return m_albedo[patch];
    const Vec3 z(0.f, 0.f, 1.f);
    return m_base.material->eval(ctx, z, z);
}

Spectrum SvLobeBrdf::microfacet_value(size_t patch, float s, float ps, float pt, float dwh, float cih,
                                      float *pdf) const {
    if (pdf) *pdf = pt > 0.f && std::isfinite(ps) ? ps / (pt * 4.f * dwh) : 0.f;
    if (!(s > 0.f) || !std::isfinite(s)) return Spectrum(0.f);
    // The visible form: the facing lobes' shares of what is seen from ωo, times the NDF's total
    // projected area (Σ_j c_j, 1 for a normalised NDF), as in eval_pdf_lambert.
    if (m_visible) return m_base.fresnel_at(cih) * (s * m_visible_scale[patch] / pt);
    return m_base.fresnel_at(cih) * s;
}

Spectrum SvLobeBrdf::eval_pdf_microfacet(size_t patch, const Vec3 &wo, const Vec3 &wi, float *pdf) const {
    const Vec3 h = normalize(wo + wi);
    const float dwh = dot(wo, h);
    if (!(dwh > 0.f)) return Spectrum(0.f);
    // Four lobes per step (SSE): the ωo side of every block (wo_side, cached per thread), then
    // their ωi side (wi_terms).
    const bool ggx = m_base.type == MicrofacetType::GGX;
    const uint32_t first = m_first_block[patch], nb = m_first_block[patch + 1] - first;
    float pt = 0.f;
    const WoTerms *t = wo_side(m_blocks.data() + first, nb, m_serial, uint32_t(patch), ggx, m_visible, wo, pt);
    const __m128 ix = _mm_set1_ps(wi.x), iy = _mm_set1_ps(wi.y), iz = _mm_set1_ps(wi.z);
    const __m128 hx = _mm_set1_ps(h.x), hy = _mm_set1_ps(h.y), hz = _mm_set1_ps(h.z);
    __m128 sum = _mm_setzero_ps(), psum = _mm_setzero_ps();
    for (uint32_t b = 0; b < nb; ++b) wi_terms(m_blocks[first + b], t[b], ggx, ix, iy, iz, hx, hy, hz, sum, psum);
    return microfacet_value(patch, hsum(sum), hsum(psum), pt, dwh, dot(wi, h), pdf);
}

void SvLobeBrdf::eval_batch_microfacet(size_t patch, const Vec3 &wo, const Vec3 *wi, int n, Spectrum *out) const {
    // eval_pdf_microfacet at every ωi, with the same values bit for bit, four ωi per step instead
    // of four lobes: a lobe is broadcast and each ωi is a lane (a patch of six lobes filled two
    // four-lobe blocks, two lanes idle; a lobe facing away from ωo is skipped once for all ωi).
    // Every lane runs wi_terms' operations in its order, and acc[q] adds the lobes of block
    // position q in block order, as wi_terms' lane q does, so hsum's (s0 + s2) + (s1 + s3) is
    // (acc0 + acc2) + (acc1 + acc3). Skipped lobes and masked lanes add +0, which changes no sum.
    const bool ggx = m_base.type == MicrofacetType::GGX;
    const uint32_t first = m_first_block[patch], nb = m_first_block[patch + 1] - first;
    float pt = 0.f;
    const WoTerms *t = wo_side(m_blocks.data() + first, nb, m_serial, uint32_t(patch), ggx, m_visible, wo, pt);
    // The lobes that face ωo (lane_terms masks the others), broadcast, in block order with their lane.
    struct Active {
        LobeLanes L;
        int q;
    };
    thread_local std::vector<Active> act;
    act.clear();
    for (uint32_t b = 0; b < nb; ++b) {
        const LobeBlock &B = m_blocks[first + b];
        alignas(16) float lo[4], c[4], lam[4], c4[4];
        _mm_store_ps(lo, t[b].lo), _mm_store_ps(c, t[b].c), _mm_store_ps(lam, t[b].lam_o), _mm_store_ps(c4, t[b].c4lo);
        for (int q = 0; q < 4; ++q)
            if (lo[q] > 0.f)
                act.push_back({{_mm_set1_ps(B.mx[q]), _mm_set1_ps(B.my[q]), _mm_set1_ps(B.mz[q]), _mm_set1_ps(B.alpha[q]),
                                _mm_set1_ps(B.a2[q]), _mm_set1_ps(B.inv_a2[q]), _mm_set1_ps(B.d_norm[q]),
                                _mm_set1_ps(c[q]), _mm_set1_ps(lam[q]), _mm_set1_ps(c4[q])},
                               q});
    }
    // The valid ωi (wi.z > 0 and ωo·h > 0) and their half vectors, as eval_pdf_microfacet computes them.
    thread_local std::vector<float> soa;
    thread_local std::vector<int> idx;
    soa.resize(size_t(8) * (size_t(n) + 4));
    idx.clear();
    float *ix = soa.data(), *iy = ix + n + 4, *iz = iy + n + 4, *hx = iz + n + 4, *hy = hx + n + 4, *hz = hy + n + 4,
          *dwh = hz + n + 4, *cih = dwh + n + 4;
    for (int k = 0; k < n; ++k) {
        out[k] = Spectrum(0.f);
        if (!(wi[k].z > 0.f)) continue;
        const Vec3 h = normalize(wo + wi[k]);
        const float d = dot(wo, h);
        if (!(d > 0.f)) continue;
        const size_t m = idx.size();
        ix[m] = wi[k].x, iy[m] = wi[k].y, iz[m] = wi[k].z, hx[m] = h.x, hy[m] = h.y, hz[m] = h.z;
        dwh[m] = d, cih[m] = dot(wi[k], h);
        idx.push_back(k);
    }
    const size_t m = idx.size();
    for (size_t j = m; j < m + 4 && m > 0; ++j)  // pad the last group with copies of the first ωi
        ix[j] = ix[0], iy[j] = iy[0], iz[j] = iz[0], hx[j] = hx[0], hy[j] = hy[0], hz[j] = hz[0];
    const __m128 zero = _mm_setzero_ps(), all = _mm_castsi128_ps(_mm_set1_epi32(-1));
    for (size_t g = 0; g < m; g += 4) {
        const __m128 vix = _mm_loadu_ps(ix + g), viy = _mm_loadu_ps(iy + g), viz = _mm_loadu_ps(iz + g);
        const __m128 vhx = _mm_loadu_ps(hx + g), vhy = _mm_loadu_ps(hy + g), vhz = _mm_loadu_ps(hz + g);
        __m128 acc[4] = {zero, zero, zero, zero}, pacc[4] = {zero, zero, zero, zero};
        for (const Active &a : act) lane_terms(a.L, all, ggx, vix, viy, viz, vhx, vhy, vhz, acc[a.q], pacc[a.q]);
        alignas(16) float s[4], ps[4];
        _mm_store_ps(s, _mm_add_ps(_mm_add_ps(acc[0], acc[2]), _mm_add_ps(acc[1], acc[3])));
        _mm_store_ps(ps, _mm_add_ps(_mm_add_ps(pacc[0], pacc[2]), _mm_add_ps(pacc[1], pacc[3])));
        for (size_t l = 0; l < 4 && g + l < m; ++l)
            out[idx[g + l]] = microfacet_value(patch, s[l], ps[l], pt, dwh[g + l], cih[g + l], nullptr);
    }
}

namespace {
/// The Lambertian lobes' view weights of one patch towards ωo, kept per thread for the last (model,
/// patch, ωo) as WoCache is for microfacet lobes: a vertex asks eval_pdf, sample (choose, then
/// eval_pdf) and pdf with one ωo, and the weights' table lookups were a third of each pass.
struct LambertWoCache {
    static constexpr uint32_t kMax = 64;
    WoKey key;  ///< key.serial 0 while being filled
    float v[kMax];
};
thread_local LambertWoCache tl_lambert_wo;
}  // namespace

const float *SvLobeBrdf::lambert_weights(size_t patch, const Vec3 &wo) const {
    LambertWoCache &c = tl_lambert_wo;
    if (c.key.holds(m_serial, uint32_t(patch), wo)) return c.v;
    c.key.serial = 0;  // invalid while being filled
    if (m_visible) {
        // Four lobes at a time from the patch's blocks (lane q of block k is lobe 4k + q; padding
        // lanes have c = 0 and give 0): view_weight's c_j C(μ_j·ωo, κ_j) / C(μ_j,z, κ_j), unmasked
        // where μ_j·ωo <= 0 (a Lambertian lobe's projected area towards ωo stays positive there).
        const uint32_t first = m_first_block[patch];
        const uint32_t nb = std::min<uint32_t>(m_first_block[patch + 1] - first, LambertWoCache::kMax / 4);
        const __m128 ox = _mm_set1_ps(wo.x), oy = _mm_set1_ps(wo.y), oz = _mm_set1_ps(wo.z);
        for (uint32_t k = 0; k < nb; ++k) {
            const LobeBlock &B = m_blocks[first + k];
            const __m128 lo = _mm_add_ps(_mm_add_ps(_mm_mul_ps(_mm_load_ps(B.mx), ox), _mm_mul_ps(_mm_load_ps(B.my), oy)),
                                         _mm_mul_ps(_mm_load_ps(B.mz), oz));
            _mm_storeu_ps(c.v + 4 * k, visible_weights(B.c, B.crow, B.cfy, B.inv_cz, lo, false));
        }
    } else {
        const auto [b, e] = lobes(patch);
        const size_t n = std::min<size_t>(size_t(e - b), LambertWoCache::kMax);
        for (size_t j = 0; j < n; ++j) c.v[j] = view_weight(b[j], wo);
    }
    c.key.set(m_serial, uint32_t(patch), wo);
    return c.v;
}

/// The sums of eval_pdf_lambert in the visible form, four lobes at a time (the weights vw in
/// lambert_weights' block order): Σ w_j C(μ_j·ωi, κ_j), Σ w_j C inv_mass_j and Σ w_j.
void SvLobeBrdf::lambert_sums(size_t patch, const float *vw, const Vec3 &wi, float &sum, float &psum,
                              float &ptot) const {
    const uint32_t first = m_first_block[patch];
    const uint32_t nb = std::min<uint32_t>(m_first_block[patch + 1] - first, LambertWoCache::kMax / 4);
    const __m128 ix = _mm_set1_ps(wi.x), iy = _mm_set1_ps(wi.y), iz = _mm_set1_ps(wi.z);
    __m128 s = _mm_setzero_ps(), ps = _mm_setzero_ps(), pt = _mm_setzero_ps();
    for (uint32_t k = 0; k < nb; ++k) {
        const LobeBlock &B = m_blocks[first + k];
        const __m128 li = _mm_add_ps(_mm_add_ps(_mm_mul_ps(_mm_load_ps(B.mx), ix), _mm_mul_ps(_mm_load_ps(B.my), iy)),
                                     _mm_mul_ps(_mm_load_ps(B.mz), iz));
        const __m128 v = _mm_loadu_ps(vw + 4 * k), vc = _mm_mul_ps(v, clamped_cosine4(B.crow, B.cfy, li));
        s = _mm_add_ps(s, vc);
        ps = _mm_add_ps(ps, _mm_mul_ps(vc, _mm_load_ps(B.inv_mass)));
        pt = _mm_add_ps(pt, v);
    }
    sum = hsum(s), psum = hsum(ps), ptot = hsum(pt);
}

Spectrum SvLobeBrdf::eval_pdf_lambert(const ShadingContext &ctx, size_t patch, const Vec3 &wo, const Vec3 &wi,
                                      float *pdf) const {
    const float *vw = lambert_weights(patch, wo);
    float sum = 0.f, psum = 0.f, ptot = 0.f;
    if (m_visible) {
        lambert_sums(patch, vw, wi, sum, psum, ptot);
    } else {
        const VmfTables &tab = vmf_tables();
        const auto [b, e0] = lobes(patch);
        const Lobe *e = b + std::min<ptrdiff_t>(e0 - b, LambertWoCache::kMax);
        for (const Lobe *l = b; l != e; ++l) {
            const float v = vw[l - b];
            if (!(v > 0.f)) continue;
            const float ti = dot(l->mu, wi);
            ptot += v;
            const float c = VmfTables::lookup(tab.C, ti, l->krow);
            sum += v * c;
            psum += v * c * l->inv_mass;
        }
    }
    if (pdf) *pdf = ptot > 0.f ? psum / ptot : 0.f;
    if (!(sum > 0.f)) return Spectrum(0.f);
    // The visible form: the lobes' shares of what is seen from ωo (Σ_j share_j = 1), times the
    // NDF's total projected area (Σ_j c_j = A Σ_j a_j C(μ_j,z, κ_j), 1 for a normalised NDF).
    if (m_visible) return lambert(ctx, patch) * (sum * m_visible_scale[patch] / ptot);
    return lambert(ctx, patch) * sum;
}

Spectrum SvLobeBrdf::eval_pdf_patch(const ShadingContext &ctx, size_t patch, const Vec3 &wo, const Vec3 &wi,
                                    float *pdf) const {
    if (pdf) *pdf = 0.f;
    if (!(wo.z > 0.f) || !(wi.z > 0.f)) return Spectrum(0.f);
    if (m_base.kind == LobeBase::Kind::Microfacet) return eval_pdf_microfacet(patch, wo, wi, pdf);
    return eval_pdf_lambert(ctx, patch, wo, wi, pdf);
}

Spectrum SvLobeBrdf::eval_pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi, float *pdf) const {
    return eval_pdf_patch(ctx, patch_index(ctx.uv), wo, wi, pdf);
}

float SvLobeBrdf::pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const {
    float p = 0.f;
    eval_pdf(ctx, wo, wi, &p);
    return p;
}

const SvLobeBrdf::Lobe *SvLobeBrdf::choose(size_t patch, const Vec3 &wo, float u_lobe) const {
    const auto [b, e] = lobes(patch);
    const int n = int(std::min<ptrdiff_t>(e - b, LambertWoCache::kMax));
    const float *w = lambert_weights(patch, wo);
    float total = 0.f;
    for (int j = 0; j < n; ++j) total += w[j];
    if (!(total > 0.f)) return nullptr;
    float target = u_lobe * total;
    for (int j = 0; j < n; ++j) {
        if (w[j] > 0.f && (target < w[j] || j == n - 1)) return b + j;
        target -= w[j];
    }
    for (int j = n - 1; j >= 0; --j)  // round-off left the target past the end: the last one with weight
        if (w[j] > 0.f) return b + j;
    return nullptr;
}

bool SvLobeBrdf::choose_block(size_t patch, const Vec3 &wo, float u_lobe, uint32_t &bo, int &qo) const {
    // Block b's lanes' weights towards ωo, those eval_pdf_microfacet's pdf divides by: c_j [μ_j·ωo > 0],
    // or in the visible form c_j C(μ_j·ωo) / C(μ_j,z) (the cached ωo side; padding lanes have c = 0).
    const bool ggx = m_base.type == MicrofacetType::GGX;
    const uint32_t first = m_first_block[patch], nb = m_first_block[patch + 1] - first;
    float pt = 0.f;
    const WoTerms *t = wo_side(m_blocks.data() + first, nb, m_serial, uint32_t(patch), ggx, m_visible, wo, pt);
    auto weights = [&](uint32_t b, float *w) {
        _mm_storeu_ps(w, _mm_and_ps(_mm_cmpgt_ps(t[b].lo, _mm_setzero_ps()), t[b].c));
    };
    // Lobe by lobe in the patch's order (a padding lane adds +0), as choose does for Lambertian lobes.
    float total = 0.f;
    for (uint32_t b = 0; b < nb; ++b) {
        float w[4];
        weights(b, w);
        for (int q = 0; q < 4; ++q) total += w[q];
    }
    if (!(total > 0.f)) return false;
    float target = u_lobe * total;
    bool found = false;
    for (uint32_t b = 0; b < nb; ++b) {
        float w[4];
        weights(b, w);
        for (int q = 0; q < 4; ++q) {
            if (!(w[q] > 0.f)) continue;
            bo = first + b, qo = q, found = true;  // also the round-off fallback: the last lobe with weight
            if (target < w[q]) return true;
            target -= w[q];
        }
    }
    return found;
}

bool SvLobeBrdf::sample_microfacet(const Vec3 &mu, float alpha, const Vec3 &wo, Vec2 u, Vec3 &wi) const {
    // The full NDF D (m·μ) in the lobe's frame: tan²θ in closed form.
    const float ux = std::min(u.x, 0x1.fffffep-1f), a2 = alpha * alpha;
    const float tan2 = m_base.type == MicrofacetType::GGX ? a2 * ux / (1.f - ux) : -a2 * std::log1p(-ux);
    const float ct = 1.f / std::sqrt(1.f + tan2), st = std::sqrt(std::max(0.f, 1.f - ct * ct));
    float sp, cp;
    sincos_0_2pi(2.f * kPiF * u.y, sp, cp);  // polynomials, no libm call (core/float_trig.h)
    const Vec3 m = normalize(Frame(mu).to_world(Vec3(st * cp, st * sp, ct)));
    const float d = dot(wo, m);
    if (!(d > 0.f)) return false;
    wi = normalize(m * (2.f * d) - wo);
    return dot(mu, wi) > 0.f;  // outside the lobe's hemisphere: pdf counts it out
}

bool SvLobeBrdf::sample_direction(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, Vec3 &wi) const {
    if (!(wo.z > 0.f)) return false;
    const size_t patch = patch_index(ctx.uv);
    if (m_base.kind == LobeBase::Kind::Microfacet) {
        uint32_t b = 0;
        int q = 0;
        if (!choose_block(patch, wo, u_lobe, b, q)) return false;
        const LobeBlock &B = m_blocks[b];
        if (!sample_microfacet(Vec3(B.mx[q], B.my[q], B.mz[q]), B.alpha[q], wo, u, wi)) return false;
    } else {
        const Lobe *l = choose(patch, wo, u_lobe);
        if (!l) return false;
        // t = μ·ωi with density C(t, κ_j) / mass, the azimuth about μ uniform: the density of
        // ωi is the lobe's pdf term C(μ·ωi, κ_j) · inv_mass exactly (the vMF-convolved clamped
        // cosine: a normal drawn from the lobe, then a cosine-weighted direction about it).
        const float t = vmf_tables().sample_t(l->krow, u.x);
        const float st = std::sqrt(std::max(0.f, 1.f - t * t));
        float sp, cp;
        sincos_0_2pi(2.f * kPiF * u.y, sp, cp);
        wi = normalize(Frame(l->mu).to_world(Vec3(st * cp, st * sp, t)));
    }
    return wi.z > 0.f;
}

bool SvLobeBrdf::sample(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, BSDFSample &out) const {
    Vec3 wi;
    if (!sample_direction(ctx, wo, u_lobe, u, wi)) return false;
    float p = 0.f;
    const Spectrum f = eval_pdf_patch(ctx, patch_index(ctx.uv), wo, wi, &p);
    if (!(p > 0.f) || !std::isfinite(p)) return false;
    out.wi = wi;
    out.pdf = p;
    out.weight = f / p;
    out.eta = 1.f;
    out.flags = flags();
    return true;
}

uint32_t SvLobeBrdf::flags() const {
    return m_base.kind == LobeBase::Kind::Microfacet ? BSDF_GlossyReflection : BSDF_DiffuseReflection;
}

Spectrum SvLobeBrdf::albedo_hint(const ShadingContext &ctx) const {
    return m_base.kind == LobeBase::Kind::Microfacet ? m_base.fresnel_at(1.f) : lambert(ctx, patch_index(ctx.uv)) * kPiF;
}

std::string SvLobeBrdf::to_string() const {
    return fmt::format("SvLobeBrdf[{}x{} patches, {} lobes, base {}]", m_w, m_h, m_lobes.size(),
                       m_base.material->to_string());
}

void SvLobeBrdf::eval_batch(const ShadingContext &ctx, const Vec3 &wo, const Vec3 *wi, int n, Spectrum *out) const {
    const size_t patch = patch_index(ctx.uv);
    if (!(wo.z > 0.f)) {
        std::fill(out, out + n, Spectrum(0.f));
        return;
    }
    if (m_base.kind == LobeBase::Kind::Microfacet) return eval_batch_microfacet(patch, wo, wi, n, out);
    for (int k = 0; k < n; ++k) out[k] = eval_pdf_patch(ctx, patch, wo, wi[k], nullptr);
}

}  // namespace meso::prefilter
