// The multi-lobe BRDF of paper 004 eq. 5 / eq. 11 by a fixed per-lobe quadrature of the patch
// NDF (see multilobe_brdf.h for the model, the quadrature and the sampling).
#include "prefilter/multilobe_brdf.h"
#include <fmt/format.h>
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include "core/error.h"
#include "core/quadrature.h"
#include "filter/vmf.h"

namespace meso::prefilter {

namespace {
constexpr double kPi = 3.14159265358979323846;

uint64_t next_instance_id() {
    static std::atomic<uint64_t> counter{1};
    return counter.fetch_add(1, std::memory_order_relaxed);
}


/// pick_node's per-thread record for the last (instance, wo): each node's weight (0 where it
/// faces away from wo) and the sums of those over blocks of kPickBlock consecutive nodes.
struct PickCache {
    uint64_t owner = 0;  ///< MultiLobeBrdf::m_id; 0: empty
    Vec3 wo;
    double total = 0.0;
    std::vector<double> w, block;
};
}


MultiLobeBrdf::MultiLobeBrdf(std::shared_ptr<const Material> base, const PatchNdf &ndf, const QuadratureOptions &opt)
    : m_base(std::move(base)), m_opt(opt), m_lobes(ndf.lobes.size()), m_id(next_instance_id()) {
    if (!m_base) throw MesoError("multilobe BRDF: base material is null");
    const uint32_t bf = m_base->flags();
    if (bf & (BSDF_Delta | BSDF_Transmission))
        throw MesoError(fmt::format("multilobe BRDF: base material must be reflection-only without delta lobes: {}",
                                    m_base->to_string()));
    if ((bf & BSDF_Smooth) == 0) throw MesoError("multilobe BRDF: base material has no smooth lobe");
    if (opt.polar < 1 || opt.polar > 64)
        throw MesoError(fmt::format("multilobe BRDF: polar node count must be in 1..64, got {}", opt.polar));
    if (opt.azimuth < 1 || opt.azimuth > 256)
        throw MesoError(fmt::format("multilobe BRDF: azimuth node count must be in 1..256, got {}", opt.azimuth));
    if (ndf.lobes.empty()) throw MesoError("multilobe BRDF: the patch NDF has no lobes");
    if (!std::isfinite(ndf.amplitude) || ndf.amplitude < 0.0)
        throw MesoError(fmt::format("multilobe BRDF: NDF amplitude must be finite and >= 0, got {}", ndf.amplitude));

    std::vector<double> gx, gw;
    gauss_legendre_01(opt.polar, gx, gw);
    for (size_t j = 0; j < ndf.lobes.size(); ++j) {
        const VmfLobe &l = ndf.lobes[j];
        const double mx = l.mu.x, my = l.mu.y, mz = l.mu.z, ml = std::sqrt(mx * mx + my * my + mz * mz);
        if (!std::isfinite(l.kappa) || l.kappa < 0.0 || !std::isfinite(l.weight) || l.weight < 0.0 ||
            !(ml > 0.0) || !std::isfinite(ml))
            throw MesoError(fmt::format("multilobe BRDF: invalid lobe {} (kappa {}, weight {}, |mu| {})", j, l.kappa,
                                        l.weight, ml));
        if (l.weight == 0.0) continue;
        const double kappa = std::min(l.kappa, vmf::kMaxKappa);
        const Vec3 mu(float(mx / ml), float(my / ml), float(mz / ml));
        if (kappa >= kCollapseKappa) {
            // A (near-)delta lobe, e.g. a planar facet family: every node of the rule would sit
            // within ~1/sqrt(κ) <= 3e-3 rad of μ; one node at μ carries the lobe (its mass below
            // the horizon is 0 unless μ is within that angle of it). Its weight keeps the lobe's
            // projected area (eq. 3): c μ_z = amplitude a_j P(μ, κ).
            if (mu.z > 0.f) {
                const double c = ndf.amplitude * l.weight * vmf_projected_area(mu, kappa) / double(mu.z);
                if (c > 0.0) {
                    m_nodes.push_back({Frame(mu), c, int(j)});
                    m_total += c;
                    m_projected += c * double(mu.z);
                }
            }
            continue;
        }
        Vec3 s, t;
        coordinate_system(mu, s, t);
        for (int a = 0; a < opt.polar; ++a) {
            // w = μ·ω at CDF value u (γ dω = du dφ / 2π), 1 − w without cancellation.
            double omw = 0.0;
            const double w = vmf::sample_cos(kappa, gx[size_t(a)], &omw);
            const double sin_t = std::sqrt(std::max(0.0, omw * (1.0 + w)));
            const double shift = (a % 2) ? 0.0 : 0.5;  // alternate rings interleave
            for (int b = 0; b < opt.azimuth; ++b) {
                const double phi = 2.0 * kPi * (b + shift) / opt.azimuth;
                const double cx = sin_t * std::cos(phi), cy = sin_t * std::sin(phi);
                double dx = cx * s.x + cy * t.x + w * mx / ml;
                double dy = cx * s.y + cy * t.y + w * my / ml;
                double dz = cx * s.z + cy * t.z + w * mz / ml;
                const double len = std::sqrt(dx * dx + dy * dy + dz * dz);
                dx /= len, dy /= len, dz /= len;
                if (!(dz > 0.0)) continue;  // D = 0 below the macro horizon (eq. 4)
                const Vec3 n{float(dx), float(dy), float(dz)};
                if (!(n.z > 0.f)) continue;
                const double c = ndf.amplitude * l.weight * gw[size_t(a)] / opt.azimuth;
                if (!(c > 0.0)) continue;
                m_nodes.push_back({Frame(n), c, int(j)});
                m_total += c;
                m_projected += c * dz;
            }
        }
    }
    // The normals and weights again, by blocks of kPickBlock, for pick_node's pass.
    // Padded to whole blocks of kPickBlock with zero normals and weights (they face nothing).
    const size_t padded = (m_nodes.size() + kPickBlock - 1) / kPickBlock * kPickBlock;
    m_blocks.assign(padded / kPickBlock, NodeBlock{});
    for (size_t q = 0; q < m_nodes.size(); ++q) {
        const NdfNode &k = m_nodes[q];
        NodeBlock &b = m_blocks[q / kPickBlock];
        const size_t j = q % kPickBlock;
        b.nx[j] = k.frame.n.x, b.ny[j] = k.frame.n.y, b.nz[j] = k.frame.n.z, b.c[j] = k.weight;
    }
}

double MultiLobeBrdf::selection_total(const Vec3 &wo) const {
    double total = 0.0;
    for (const NdfNode &k : m_nodes)
        if (const float z = k.frame.to_local(wo).z; z > 0.f) total += weight(k, z, wo.z);  // the test of pdf()
    return total;
}

Spectrum MultiLobeBrdf::eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const {
    if (!(wo.z > 0.f) || !(wi.z > 0.f)) return Spectrum(0.f);
    double r = 0.0, g = 0.0, b = 0.0, total = 0.0;
    for (const NdfNode &k : m_nodes) {
        const Vec3 lo = k.frame.to_local(wo);
        if (!(lo.z > 0.f)) continue;
        const double w = weight(k, lo.z, wo.z);
        total += w;
        const Vec3 li = k.frame.to_local(wi);
        if (!(li.z > 0.f)) continue;
        const Spectrum f = m_base->eval(ctx, lo, li);  // f · <ω_k, ωi>
        r += w * f.r, g += w * f.g, b += w * f.b;
    }
    const double s = view_scale(total);
    return Spectrum(float(s * r), float(s * g), float(s * b));
}

void MultiLobeBrdf::eval_batch(const ShadingContext &ctx, const Vec3 &wo, const Vec3 *wi, int n, Spectrum *out) const {
    thread_local std::vector<double> acc;
    acc.assign(size_t(n) * 3, 0.0);
    double total = 0.0;
    if (wo.z > 0.f) {
        for (const NdfNode &k : m_nodes) {
            const Vec3 lo = k.frame.to_local(wo);
            if (!(lo.z > 0.f)) continue;
            const double w = weight(k, lo.z, wo.z);
            total += w;
            for (int b = 0; b < n; ++b) {
                if (!(wi[b].z > 0.f)) continue;
                const Vec3 li = k.frame.to_local(wi[b]);
                if (!(li.z > 0.f)) continue;
                const Spectrum f = m_base->eval(ctx, lo, li);
                double *a = &acc[size_t(b) * 3];
                a[0] += w * f.r, a[1] += w * f.g, a[2] += w * f.b;
            }
        }
    }
    const double s = view_scale(total);
    for (int b = 0; b < n; ++b)
        out[b] = Spectrum(float(s * acc[size_t(b) * 3]), float(s * acc[size_t(b) * 3 + 1]), float(s * acc[size_t(b) * 3 + 2]));
}

Spectrum MultiLobeBrdf::eval_pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi, float *pdf_out) const {
    if (!pdf_out) return eval(ctx, wo, wi);
    *pdf_out = 0.f;
    if (!(wo.z > 0.f) || !(wi.z > 0.f)) return Spectrum(0.f);
    double r = 0.0, g = 0.0, b = 0.0, total = 0.0, sum = 0.0;
    for (const NdfNode &k : m_nodes) {
        const Vec3 lo = k.frame.to_local(wo);
        if (!(lo.z > 0.f)) continue;
        const double w = weight(k, lo.z, wo.z);
        total += w;
        const Vec3 li = k.frame.to_local(wi);
        if (!(li.z > 0.f)) continue;
        float p = 0.f;
        const Spectrum f = m_base->eval_pdf(ctx, lo, li, &p);
        r += w * f.r, g += w * f.g, b += w * f.b;
        sum += w * double(p);
    }
    *pdf_out = total > 0.0 ? float(sum / total) : 0.f;
    const double s = view_scale(total);
    return Spectrum(float(s * r), float(s * g), float(s * b));
}

float MultiLobeBrdf::pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const {
    if (!(wo.z > 0.f) || !(wi.z > 0.f)) return 0.f;
    double total = 0.0, sum = 0.0;
    for (const NdfNode &k : m_nodes) {
        const Vec3 lo = k.frame.to_local(wo);
        if (!(lo.z > 0.f)) continue;  // the same test as selection_total (dot(wo, n) == lo.z)
        const double w = weight(k, lo.z, wo.z);
        total += w;
        const Vec3 li = k.frame.to_local(wi);
        if (!(li.z > 0.f)) continue;
        sum += w * double(m_base->pdf(ctx, lo, li));
    }
    return total > 0.0 ? float(sum / total) : 0.f;
}

namespace {
// Four floats, with the GCC / Clang vector extension (SSE on x86-64, NEON on ARM; plain code
// elsewhere): pick_weights' pass over the nodes, four at a time.
typedef float F4 __attribute__((vector_size(16)));
typedef int32_t I4 __attribute__((vector_size(16)));
typedef double D4 __attribute__((vector_size(32)));
typedef int64_t L4 __attribute__((vector_size(32)));
inline F4 load4(const float *p) {
    F4 v;
    std::memcpy(&v, p, sizeof v);
    return v;
}
}  // namespace

void MultiLobeBrdf::pick_weights(const Vec3 &wo, double *w, double *block) const {
    // F_k wo .z = dot(wo, ω_k) as Frame::to_local computes it (the test of pdf(), lane by lane
    // the same float expression), four nodes at a time, and the weights (double, as weight()
    // computes them) masked by it, without branches (whether a node faces wo is a coin flip for
    // a branch predictor). The arrays are padded to whole blocks with zero normals, which face
    // nothing. Everything is read into locals first: stores to w must not make the compiler
    // reload them.
    static_assert(kPickBlock == 8, "a block is two vectors of four");
    const size_t nb = m_blocks.size();
    const NodeBlock *blocks = m_blocks.data();
    const float ox = wo.x, oy = wo.y, oz = wo.z;
    const bool projected = m_opt.projected_area;
    const F4 zero = {0.f, 0.f, 0.f, 0.f};
    for (size_t b = 0; b < nb; ++b) {
        const NodeBlock &nb_ = blocks[b];
        D4 wq[2];
        for (size_t h = 0; h < 2; ++h) {
            const size_t j = 4 * h;
            const F4 z = ox * load4(nb_.nx + j) + oy * load4(nb_.ny + j) + oz * load4(nb_.nz + j);
            const L4 facing = __builtin_convertvector(z > zero, L4);  // all ones where the node faces wo
            D4 c;
            std::memcpy(&c, nb_.c + j, sizeof c);
            // weight(): c_k, or c_k <ω_k, ωo> / <ω_g, ωo> with projected_area
            if (projected) c = c * __builtin_convertvector(z, D4) / double(oz);
            wq[h] = (D4)((L4)c & facing);
            std::memcpy(w + b * kPickBlock + j, &wq[h], sizeof wq[h]);
        }
        const D4 s = wq[0] + wq[1];
        block[b] = (s[0] + s[1]) + (s[2] + s[3]);
    }
}

bool MultiLobeBrdf::pick_node(const Vec3 &wo, double u, NodePick &pick) const {
    pick = NodePick();
    if (!(wo.z > 0.f)) return false;
    // Node choice with probability P_k = w_k / Σ, w_k = weight(k) [F_k wo .z > 0], by the
    // running sum of the w_k in node order: the first k with target = u Σ < Σ_{j<=k} w_j (a
    // node facing away has w_k = 0 and is never the first). Two levels (the block where the
    // running sum of block sums passes target, then the node within it), so that the O(N)
    // pass has no chain of dependent additions; it equals the plain running sum up to double
    // rounding. The weights are reused while the instance and wo (bit for bit) stay the same
    // (next-event estimation and BSDF sampling at one vertex).
    thread_local PickCache cache;
    const size_t n = m_nodes.size(), nb = m_blocks.size();
    if (cache.owner != m_id || cache.wo.x != wo.x || cache.wo.y != wo.y || cache.wo.z != wo.z) {
        if (cache.w.size() < nb * kPickBlock) cache.w.resize(nb * kPickBlock), cache.block.resize(nb);
        pick_weights(wo, cache.w.data(), cache.block.data());
        double sum = 0.0;
        for (size_t b = 0; b < nb; ++b) sum += cache.block[b];
        cache.total = sum;
        cache.owner = m_id;
        cache.wo = wo;
    }
    const double *w = cache.w.data(), *block = cache.block.data();
    const double total = cache.total;
    if (!(total > 0.0)) return false;
    const double target = u * total;
    double cum = 0.0;
    size_t b = 0;
    for (; b + 1 < nb && !(target < cum + block[b]); ++b) cum += block[b];
    size_t chosen = n;
    double u_rescaled = 1.0;
    for (size_t q = b * kPickBlock; q < (b + 1) * kPickBlock; ++q) {
        if (target < cum + w[q]) {  // w[q] > 0 here: target >= cum
            chosen = q;
            u_rescaled = (target - cum) / w[q];
            break;
        }
        cum += w[q];
    }
    // Rounding (block sums add in another order) or u >= 1 left target beyond the block: the last node
    // facing wo in it or before it; u_rescaled 1.
    if (chosen == n)
        for (size_t q = (b + 1) * kPickBlock; chosen == n && q-- > 0;)
            if (w[q] > 0.0) chosen = q;
    if (chosen >= n) return false;
    pick.node = &m_nodes[chosen];
    // The node's frame from its normal in the scan's arrays (as the constructor built it:
    // Frame(ω_k)), so that a pick touches no NdfNode.
    const NodeBlock &cb = m_blocks[chosen / kPickBlock];
    const size_t cj = chosen % kPickBlock;
    pick.frame = Frame(Vec3(cb.nx[cj], cb.ny[cj], cb.nz[cj]));
    pick.lo = pick.frame.to_local(wo);
    pick.total = total * view_scale(total);  // Σ(wo) of eval's weights
    pick.u_rescaled = u_rescaled;
    return true;
}

namespace {
/// out = (wi, pdf p, weight f / p, flags); false where p is not a positive finite density.
bool sample_record(const Vec3 &wi, const Spectrum &f, float p, uint32_t flags, BSDFSample &out) {
    if (!(p > 0.f) || !std::isfinite(p)) return false;
    out.wi = wi;
    out.pdf = p;
    out.weight = Spectrum(f.r / p, f.g / p, f.b / p);
    out.eta = 1.f;
    out.flags = flags;
    return true;
}
}  // namespace

bool MultiLobeBrdf::sample_base_in_node(const ShadingContext &ctx, const NodePick &pick, Vec2 u, Vec3 &wi,
                                        uint32_t &flags, BSDFSample *base) const {
    // The remaining fraction of u_lobe is handed to the base for its own lobe choice.
    const float ub = std::min(std::max(float(pick.u_rescaled), 0.f), 0x1.fffffep-1f);
    BSDFSample bs;
    if (!m_base->sample(ctx, pick.lo, ub, u, bs)) return false;
    if (bs.flags & BSDF_Delta) return false;  // excluded in the constructor; defensive
    wi = normalize(pick.frame.to_world(bs.wi));
    flags = bs.flags;
    if (base) *base = bs;
    return wi.z > 0.f;  // below the macro horizon: the path ends (pdf excludes it)
}

bool MultiLobeBrdf::sample(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, BSDFSample &out) const {
    NodePick pick;
    Vec3 wi;
    uint32_t flags = 0;
    if (!pick_node(wo, double(u_lobe), pick) || !sample_base_in_node(ctx, pick, u, wi, flags)) return false;
    float p = 0.f;
    const Spectrum f = eval_pdf(ctx, wo, wi, &p);
    if (!sample_record(wi, f, p, flags, out)) return false;
    return true;
}

Spectrum MultiLobeBrdf::eval_pdf_node(const ShadingContext &ctx, const NodePick &pick, const Vec3 &wo,
                                      const Vec3 &wi, float *pdf_out) const {
    if (pdf_out) *pdf_out = 0.f;
    if (!pick.node || !(wo.z > 0.f) || !(wi.z > 0.f)) return Spectrum(0.f);
    const Vec3 li = pick.frame.to_local(wi);
    if (!(li.z > 0.f)) return Spectrum(0.f);  // g_k = 0 (and pdf_k = 0: reflection-only base)
    const Spectrum f = m_base->eval_pdf(ctx, pick.lo, li, pdf_out);  // g_k = f · <ω_k, ωi>
    const double s = pick.total;  // c_k g_k / P_k = Σ g_k (weight() of the choice in both modes)
    return Spectrum(float(s * f.r), float(s * f.g), float(s * f.b));
}

Spectrum MultiLobeBrdf::eval_pdf_stochastic(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi, double u,
                                            float *pdf_out) const {
    if (pdf_out) *pdf_out = 0.f;
    if (!(wo.z > 0.f) || !(wi.z > 0.f)) return Spectrum(0.f);
    NodePick pick;
    if (!pick_node(wo, u, pick)) return Spectrum(0.f);
    return eval_pdf_node(ctx, pick, wo, wi, pdf_out);
}

bool MultiLobeBrdf::sample_stochastic(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u,
                                      BSDFSample &out, NodePick *pick_out) const {
    NodePick pick;
    Vec3 wi;
    uint32_t flags = 0;
    BSDFSample bs;
    // The same direction as sample() for the same (u_lobe, u).
    if (!pick_node(wo, double(u_lobe), pick) || !sample_base_in_node(ctx, pick, u, wi, flags, &bs)) return false;
    // Node k's value and pdf are the base's own sample record (pdf_k and g_k / pdf_k at the
    // direction in the node's frame): eval_pdf_node at wi would give them again up to the
    // rounding of the rotation out of the node's frame, for one more base evaluation.
    if (!(bs.pdf > 0.f) || !std::isfinite(bs.pdf)) return false;
    const double s = pick.total;  // Σ g_k / pdf_k
    out.wi = wi;
    out.pdf = bs.pdf;
    out.weight = Spectrum(float(s * bs.weight.r), float(s * bs.weight.g), float(s * bs.weight.b));
    out.eta = 1.f;
    out.flags = flags;
    if (pick_out) *pick_out = pick;
    return true;
}

bool MultiLobeBrdf::pick_set(const Vec3 &wo, double u, int m, NodePick *picks) const {
    if (m < 1 || m > kMaxSetNodes) throw MesoError(fmt::format("multilobe BRDF: node set size must be in 1..{}, got {}",
                                                               kMaxSetNodes, m));
    for (int j = 0; j < m; ++j)
        if (!pick_node(wo, (u + double(j)) / double(m), picks[j])) return false;
    return true;
}

namespace {
/// Σ over the members of a node set of the base's value and pdf at one direction; each distinct
/// node is evaluated once and counted with its multiplicity (systematic positions increase, so
/// equal members are consecutive).
struct SetSum {
    double r = 0.0, g = 0.0, b = 0.0, pdf = 0.0;
    /// Adds `count` members' value f and pdf p.
    void add(int count, const Spectrum &f, float p) {
        r += count * double(f.r), g += count * double(f.g), b += count * double(f.b), pdf += count * double(p);
    }
};

/// The set's members (picks[0..m), equal nodes adjacent) as runs of one node: fn(pick, count)
/// per run, so that a node drawn several times is evaluated once.
template <class Pick, class Fn> void for_each_node_run(const Pick *picks, int m, Fn fn) {
    for (int j = 0; j < m;) {
        int same = 1;
        while (j + same < m && picks[j + same].node == picks[j].node) ++same;
        fn(picks[j], same);
        j += same;
    }
}
}  // namespace

Spectrum MultiLobeBrdf::eval_pdf_set(const ShadingContext &ctx, const NodePick *picks, int m, const Vec3 &wo,
                                     const Vec3 &wi, float *pdf_out) const {
    if (pdf_out) *pdf_out = 0.f;
    if (m < 1 || !(wo.z > 0.f) || !(wi.z > 0.f)) return Spectrum(0.f);
    SetSum s;
    for_each_node_run(picks, m, [&](const NodePick &pk, int same) {
        const Vec3 li = pk.frame.to_local(wi);
        if (!(li.z > 0.f)) return;  // g_k = 0 and pdf_k = 0 (reflection-only base)
        float p = 0.f;
        const Spectrum f = m_base->eval_pdf(ctx, pk.lo, li, &p);
        s.add(same, f, p);
    });
    const double k = picks[0].total / m;  // Σ(ωo) / m
    if (pdf_out) *pdf_out = float(s.pdf / m);
    return Spectrum(float(k * s.r), float(k * s.g), float(k * s.b));
}

Spectrum MultiLobeBrdf::eval_pdf_stratified(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi, double u_set,
                                            int m, float *pdf_out) const {
    if (pdf_out) *pdf_out = 0.f;
    if (!(wo.z > 0.f) || !(wi.z > 0.f)) return Spectrum(0.f);
    NodePick picks[kMaxSetNodes];
    if (!pick_set(wo, u_set, m, picks)) return Spectrum(0.f);
    return eval_pdf_set(ctx, picks, m, wo, wi, pdf_out);
}

bool MultiLobeBrdf::sample_stratified(const ShadingContext &ctx, const Vec3 &wo, double u_set, int m, float u_lobe,
                                      Vec2 u, BSDFSample &out) const {
    NodePick picks[kMaxSetNodes];
    if (!(wo.z > 0.f) || !pick_set(wo, u_set, m, picks)) return false;
    // Member j = floor(u_lobe m); the rest of u_lobe m picks the base's own lobe.
    const double um = double(u_lobe) * m;
    const int chosen = std::min(std::max(int(um), 0), m - 1);
    NodePick pick = picks[chosen];
    pick.u_rescaled = std::min(std::max(um - chosen, 0.0), 1.0);
    Vec3 wi;
    uint32_t flags = 0;
    BSDFSample bs;
    if (!sample_base_in_node(ctx, pick, u, wi, flags, &bs)) return false;
    if (!(bs.pdf > 0.f) || !std::isfinite(bs.pdf)) return false;
    // f_S and pdf_S at wi: the chosen node's from the base's record, the other nodes evaluated.
    SetSum s;
    for_each_node_run(picks, m, [&](const NodePick &pk, int same) {
        float p = 0.f;
        Spectrum f(0.f);
        if (pk.node == pick.node) {
            p = bs.pdf;
            f = Spectrum(bs.weight.r * bs.pdf, bs.weight.g * bs.pdf, bs.weight.b * bs.pdf);
        } else {
            const Vec3 li = pk.frame.to_local(wi);
            if (!(li.z > 0.f)) return;
            f = m_base->eval_pdf(ctx, pk.lo, li, &p);
        }
        s.add(same, f, p);
    });
    if (!(s.pdf > 0.0)) return false;
    const double k = picks[0].total / s.pdf;  // (Σ / m) Σ_j g / ((1/m) Σ_j pdf)
    out.wi = wi;
    out.pdf = float(s.pdf / m);
    out.weight = Spectrum(float(k * s.r), float(k * s.g), float(k * s.b));
    out.eta = 1.f;
    out.flags = flags;
    return out.pdf > 0.f && std::isfinite(out.pdf);
}

uint32_t MultiLobeBrdf::flags() const { return m_base->flags() & BSDF_Smooth & BSDF_Reflection; }

Spectrum MultiLobeBrdf::albedo_hint(const ShadingContext &ctx) const { return m_base->albedo_hint(ctx); }

std::string MultiLobeBrdf::to_string() const {
    return fmt::format("MultiLobeBrdf[base={}, lobes={}, nodes={} ({}x{} per lobe), sum c={:.6g}, sum c z={:.6g}]",
                       m_base->to_string(), m_lobes, m_nodes.size(), m_opt.polar, m_opt.azimuth, m_total,
                       m_projected);
}

}  // namespace meso::prefilter
