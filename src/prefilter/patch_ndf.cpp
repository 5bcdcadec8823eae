// Patch NDFs fitted with vMF mixtures (paper 004 eq. 2–4, §4.2); see patch_ndf.h.
#include "prefilter/patch_ndf.h"
#include "core/quadrature.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <fmt/format.h>
#include "core/error.h"
#include "filter/vmf.h"

namespace meso::prefilter {

namespace {

constexpr double kPi = 3.14159265358979323846;

struct Gl8 {
    std::vector<double> x, w;
    Gl8() { gauss_legendre_01(8, x, w); }
};
const Gl8 &gl8() {
    static const Gl8 g;
    return g;
}

void validate(const Heightfield &hf, int factor, const PatchNdfOptions &opt) {
    if (hf.width() < 1 || hf.height() < 1) throw MesoError("patch NDF: empty heightfield");
    if (factor < 1 || hf.width() % factor != 0 || hf.height() % factor != 0)
        throw MesoError(fmt::format("patch NDF: factor {} must be >= 1 and divide the heightfield size {} x {}", factor,
                                    hf.width(), hf.height()));
    if (opt.samples_per_cell < 1 || opt.samples_per_cell > 32)
        throw MesoError(fmt::format("patch NDF: samples_per_cell must be in 1..32, got {}", opt.samples_per_cell));
    if (!std::isfinite(opt.height_scale))
        throw MesoError(fmt::format("patch NDF: height_scale must be finite, got {}", opt.height_scale));
    if (!(opt.cell_size > 0.0) || !std::isfinite(opt.cell_size))
        throw MesoError(fmt::format("patch NDF: cell_size must be finite and > 0, got {}", opt.cell_size));
    if (opt.threads < 0) throw MesoError(fmt::format("patch NDF: threads must be >= 0, got {}", opt.threads));
    if (opt.em.lobes < 1) throw MesoError(fmt::format("patch NDF: em.lobes must be >= 1, got {}", opt.em.lobes));
}

void validate_patch(const Heightfield &hf, int factor, int I, int J) {
    const int nx = hf.width() / factor, ny = hf.height() / factor;
    if (I < 0 || I >= nx || J < 0 || J >= ny)
        throw MesoError(fmt::format("patch NDF: patch ({}, {}) out of range: {} x {} patches at factor {}", I, J, nx,
                                    ny, factor));
}

/// patch_normals without validation; gl nodes/weights precomputed.
void patch_normals_impl(const Heightfield &hf, int factor, int I, int J, const PatchNdfOptions &opt,
                        const std::vector<double> &gx, const std::vector<double> &gw, std::vector<Vec3> &dirs,
                        std::vector<double> &weights) {
    const int n = int(gx.size());
    const double k = opt.height_scale / opt.cell_size;  // height per cell -> world slope
    const double inv_area = 1.0 / (double(factor) * double(factor));
    dirs.resize(size_t(factor) * factor * n * n);
    weights.resize(dirs.size());
    size_t q = 0;
    for (int jj = 0; jj < factor; ++jj)
        for (int ii = 0; ii < factor; ++ii) {
            const int64_t i = int64_t(I) * factor + ii, j = int64_t(J) * factor + jj;
            const double h00 = hf.vertex(i, j), h10 = hf.vertex(i + 1, j), h01 = hf.vertex(i, j + 1),
                         h11 = hf.vertex(i + 1, j + 1);
            // h(x, y) = h00 + e x + f y + g x y on the unit cell.
            const double e = h10 - h00, f = h01 - h00, g = h00 + h11 - h10 - h01;
            for (int b = 0; b < n; ++b)       // y node
                for (int a = 0; a < n; ++a) {  // x node
                    const double sx = (e + g * gx[size_t(b)]) * k, sy = (f + g * gx[size_t(a)]) * k;
                    const double len = std::sqrt(1.0 + sx * sx + sy * sy), inv = 1.0 / len;
                    dirs[q] = Vec3(float(-sx * inv), float(-sy * inv), float(inv));
                    weights[q] = gw[size_t(a)] * gw[size_t(b)] * inv_area * len;
                    ++q;
                }
        }
}

/// Patch (I, J)'s fit; from `start` when it is given (fit_vmf_mixture_from), else k-means++;
/// have_normals: dirs and weights already hold the patch's normals.
PatchNdf fit_impl(const Heightfield &hf, int factor, int I, int J, const PatchNdfOptions &opt,
                  const std::vector<double> &gx, const std::vector<double> &gw, std::vector<Vec3> &dirs,
                  std::vector<double> &weights, const std::vector<VmfLobe> *start = nullptr, bool have_normals = false) {
    if (!have_normals) patch_normals_impl(hf, factor, I, J, opt, gx, gw, dirs, weights);
    PatchNdf out;
    double area = 0.0;
    for (double w : weights) area += w;
    VmfMixture mix = start ? fit_vmf_mixture_from(dirs.data(), weights.data(), dirs.size(), *start, opt.em)
                           : fit_vmf_mixture(dirs.data(), weights.data(), dirs.size(), opt.em);
    out.lobes = std::move(mix.lobes);
    out.log_likelihood = mix.log_likelihood;
    out.iterations = mix.iterations;
    out.converged = mix.converged;
    out.area_ratio = area;
    const double p = mixture_projected_area(out.lobes);
    out.amplitude = p > 0.0 ? 1.0 / p : 0.0;
    out.projected_area_check = area * p;
    return out;
}

}  // namespace

void patch_normals(const Heightfield &hf, int factor, int I, int J, const PatchNdfOptions &opt,
                   std::vector<Vec3> &dirs, std::vector<double> &weights) {
    validate(hf, factor, opt);
    validate_patch(hf, factor, I, J);
    std::vector<double> gx, gw;
    gauss_legendre_01(opt.samples_per_cell, gx, gw);
    patch_normals_impl(hf, factor, I, J, opt, gx, gw, dirs, weights);
}

PatchNdf fit_patch_ndf(const Heightfield &hf, int factor, int I, int J, const PatchNdfOptions &opt) {
    validate(hf, factor, opt);
    validate_patch(hf, factor, I, J);
    std::vector<double> gx, gw;
    gauss_legendre_01(opt.samples_per_cell, gx, gw);
    std::vector<Vec3> dirs;
    std::vector<double> weights;
    return fit_impl(hf, factor, I, J, opt, gx, gw, dirs, weights);
}

namespace {
/// Lobes of an r x r block of children merged to em.lobes by reduce_vmf_lobes, as masses;
/// gather(a0, b0, size, out) appends the lobes of the size x size children at (a0, b0), weighted
/// by their masses, each child holding at most `per_child` lobes. For r a power of two the merge
/// goes up a quadtree (2 x 2 blocks of 4K lobes, then their parents), so its cost stays
/// O(r² K³) instead of O((r² K)³) (x8 -> x64: 384 lobes at once); other r merge at once up to 200
/// lobes, else there is no start (k-means++: an empty vector).
template <class Gather>
std::vector<VmfLobe> merged_start(const Gather &gather, int i0, int j0, int r, int per_child, const VmfEmOptions &em) {
    std::function<std::vector<VmfLobe>(int, int, int)> block = [&](int a0, int b0, int size) {
        std::vector<VmfLobe> in;
        if (size <= 2 || (size & (size - 1)) != 0) {
            gather(a0, b0, size, in);
        } else {
            const int h = size / 2;
            for (int q = 0; q < 4; ++q) {
                const std::vector<VmfLobe> sub = block(a0 + (q & 1) * h, b0 + (q >> 1) * h, h);
                in.insert(in.end(), sub.begin(), sub.end());
            }
        }
        double mass = 0;
        for (const VmfLobe &l : in) mass += l.weight > 0 && std::isfinite(l.weight) ? l.weight : 0.0;
        std::vector<VmfLobe> out = reduce_vmf_lobes(in, em.lobes, em);
        for (VmfLobe &l : out) l.weight *= mass;
        return out;
    };
    if ((r & (r - 1)) != 0 && size_t(r) * size_t(r) * size_t(per_child) > 200) return {};
    return block(i0, j0, r);
}

/// The start of a coarse patch from its r x r children in `finer` (fnx patches a row; the first
/// child at (i0, j0)): the children's lobes as masses (a child's weights sum to 1 over its own
/// normals, whose total weight is its area ratio), merged by merged_start.
std::vector<VmfLobe> children_start(const std::vector<PatchNdf> &finer, int fnx, int i0, int j0, int r,
                                    const VmfEmOptions &em) {
    auto gather = [&](int a0, int b0, int size, std::vector<VmfLobe> &out) {
        for (int b = b0; b < b0 + size; ++b)
            for (int a = a0; a < a0 + size; ++a) {
                const PatchNdf &c = finer[size_t(b) * size_t(fnx) + size_t(a)];
                for (VmfLobe l : c.lobes) l.weight *= c.area_ratio, out.push_back(l);
            }
    };
    return merged_start(gather, i0, j0, r, em.lobes, em);
}

/// The start of a patch of the finest fitted level (PatchNdfOptions::start_from_cells): each of
/// its F x F cells' micro-normals (n² consecutive entries of dirs, patch_normals' order) as one
/// moment-matched lobe of mass Σ W_q, merged by merged_start.
std::vector<VmfLobe> cells_start(const std::vector<Vec3> &dirs, const std::vector<double> &weights, int factor,
                                 const VmfEmOptions &em, std::vector<VmfLobe> &cells) {
    const size_t per = dirs.size() / (size_t(factor) * size_t(factor));
    cells.resize(size_t(factor) * size_t(factor));
    for (size_t c = 0; c < cells.size(); ++c)
        cells[c] = moment_matched_lobe(&dirs[c * per], &weights[c * per], per, em);
    auto gather = [&](int a0, int b0, int size, std::vector<VmfLobe> &out) {
        for (int b = b0; b < b0 + size; ++b)
            for (int a = a0; a < a0 + size; ++a) out.push_back(cells[size_t(b) * size_t(factor) + size_t(a)]);
    };
    return merged_start(gather, 0, 0, factor, 1, em);
}

/// fit_svndf, from the children's lobes in `finer` (factor finer_factor) when it is given.
std::vector<PatchNdf> fit_svndf_impl(const Heightfield &hf, int factor, const PatchNdfOptions &opt,
                                     const std::vector<PatchNdf> *finer, int finer_factor) {
    validate(hf, factor, opt);
    if (finer) {
        if (finer_factor < 1 || factor % finer_factor != 0)
            throw MesoError(fmt::format("patch NDF: the finer fit's factor {} must divide {}", finer_factor, factor));
        validate(hf, finer_factor, opt);
        const size_t want = size_t(hf.width() / finer_factor) * size_t(hf.height() / finer_factor);
        if (finer->size() != want)
            throw MesoError(fmt::format("patch NDF: the finer fit has {} patches, the map has {} at factor {}",
                                        finer->size(), want, finer_factor));
    }
    // Options fit_vmf_mixture would reject: fail once here rather than inside a TBB task.
    {
        const Vec3 z(0.f, 0.f, 1.f);
        const double one = 1.0;
        (void)fit_vmf_mixture(&z, &one, 1, opt.em);
    }
    const int nx = hf.width() / factor, ny = hf.height() / factor;
    std::vector<double> gx, gw;
    gauss_legendre_01(opt.samples_per_cell, gx, gw);
    std::vector<PatchNdf> out(size_t(nx) * ny);
    const int r = finer ? factor / finer_factor : 0, fnx = finer ? hf.width() / finer_factor : 0;
    auto run_range = [&](int begin, int end) {
        std::vector<Vec3> dirs;
        std::vector<double> weights;
        std::vector<VmfLobe> start, cells;
        for (int p = begin; p < end; ++p) {
            const int I = p % nx, J = p / nx;
            // Cells: only with at least 2K of them (one lobe a cell cannot split a cell's normals,
            // so fewer cells leave EM too few lobes to grow into).
            if (!finer && opt.start_from_cells && factor * factor >= 2 * opt.em.lobes) {
                patch_normals_impl(hf, factor, I, J, opt, gx, gw, dirs, weights);
                start = cells_start(dirs, weights, factor, opt.em, cells);
                out[size_t(p)] =
                    fit_impl(hf, factor, I, J, opt, gx, gw, dirs, weights, start.empty() ? nullptr : &start, true);
                continue;
            }
            if (!finer) {
                out[size_t(p)] = fit_impl(hf, factor, I, J, opt, gx, gw, dirs, weights);
                continue;
            }
            start = children_start(*finer, fnx, I * r, J * r, r, opt.em);
            out[size_t(p)] = fit_impl(hf, factor, I, J, opt, gx, gw, dirs, weights, start.empty() ? nullptr : &start);
        }
    };
    const int count = nx * ny;
    if (opt.threads == 1) {
        run_range(0, count);
    } else {
        auto body = [&] {
            tbb::parallel_for(tbb::blocked_range<int>(0, count, 1),
                              [&](const tbb::blocked_range<int> &r) { run_range(r.begin(), r.end()); });
        };
        if (opt.threads > 1) {
            tbb::task_arena arena(opt.threads);
            arena.execute(body);
        } else {
            body();
        }
    }
    return out;
}
}  // namespace

std::vector<PatchNdf> fit_svndf(const Heightfield &hf, int factor, const PatchNdfOptions &opt) {
    return fit_svndf_impl(hf, factor, opt, nullptr, 0);
}

std::vector<PatchNdf> fit_svndf_from(const Heightfield &hf, int factor, const std::vector<PatchNdf> &finer,
                                     int finer_factor, const PatchNdfOptions &opt) {
    return fit_svndf_impl(hf, factor, opt, &finer, finer_factor);
}

double patch_ndf_eval(const PatchNdf &ndf, Vec3 w) {
    if (!(w.z > 0.f)) return 0.0;
    double d = 0.0;
    for (const VmfLobe &l : ndf.lobes) d += l.weight * vmf::pdf(l.mu, l.kappa, w);
    return ndf.amplitude * d;
}

namespace {
/// ∫ γ(ω; μ, κ) g(ω_z) dω for g = max(0, ·) (cap = false: vmf_projected_area) or the step [· > 0]
/// (cap = true: vmf_cap_mass).
double plane_integral(Vec3 mu, double kappa, bool cap) {
    const double mx = mu.x, my = mu.y, mz = mu.z;
    const double ml = std::sqrt(mx * mx + my * my + mz * mz);
    if (!(ml > 0.0)) return 0.0;
    const double c = mz / ml, s = std::sqrt(mx * mx + my * my) / ml;  // cos, sin of μ's polar angle
    kappa = std::clamp(std::isnan(kappa) ? 0.0 : kappa, 0.0, vmf::kMaxKappa);
    // A lobe above the horizon whose mass beyond ψ1 = π/2 − θ_μ (the directions whose circle of
    // azimuths reaches the horizon: g(u) = u c and [·] = 1 closer to μ) is below e^{−κ(1 − cos ψ1)}
    // <= e^{−50}: P = c A₃(κ) and the cap mass 1, up to that mass (the quadrature below, 376 nodes,
    // was a sixth of a logo-sized SVNDF fit).
    // 1 − cos ψ1 = 1 − s = c² / (1 + s), without cancellation.
    if (c > 0.0 && kappa * (c * c / (1.0 + s)) > 50.0) return cap ? 1.0 : c * vmf::mean_cosine(kappa);

    // Lobe frame: ω = u μ + sqrt(1 − u²) (cos φ e1 + sin φ e2), ω_z = a + b cos φ with
    // a = u c, b = sqrt(1 − u²) s ≥ 0. Mean over φ of max(0, a + b cos φ):
    //   a ≥ b: a;  a ≤ −b: 0;  else (a arccos(−a/b) + sqrt(b² − a²)) / π   (C¹ in u);
    // of [a + b cos φ > 0]: 1, 0, else arccos(−a/b) / π (continuous in u).
    // u is the vMF's μ·ω; with v its CDF (u = vmf::sample_cos(κ, v)) P = ∫_0^1 g(u(v)) dv.
    auto g = [&](double v) {
        double omw;
        const double u = vmf::sample_cos(kappa, v, &omw);
        const double a = u * c, b = std::sqrt(std::max(0.0, omw * (2.0 - omw))) * s;
        if (a >= b) return cap ? 1.0 : a;
        if (a <= -b) return 0.0;
        const double arc = std::acos(std::clamp(-a / b, -1.0, 1.0));
        return cap ? arc / kPi : (a * arc + std::sqrt(std::max(0.0, b * b - a * a))) / kPi;
    };
    // v of a given 1 − u (the CDF), for the kinks of g.
    auto v_of = [&](double omw) {
        if (!(kappa > 1e-300)) return 1.0 - 0.5 * omw;
        return 1.0 - std::expm1(-kappa * omw) / std::expm1(-2.0 * kappa);
    };
    // Panels: graded geometrically towards v = 0 (u → −1, where u(v) ~ log v for large κ) and
    // v = 1 (u → 1), split at the kinks ψ = |π/2 − θ_μ| and π − |π/2 − θ_μ| (the circle of
    // directions at angle ψ from μ touching the horizon from above / below).
    double bp[64];
    int nb = 0;
    bp[nb++] = 0.0, bp[nb++] = 1.0;
    for (int k = 1; k <= 30; ++k) bp[nb++] = std::ldexp(1.0, -k);
    for (int k = 2; k <= 14; ++k) bp[nb++] = 1.0 - std::ldexp(1.0, -k);
    const double theta = std::atan2(s, c), psi1 = std::abs(0.5 * kPi - theta), psi2 = kPi - psi1;
    for (double psi : {psi1, psi2}) {
        const double omw = 2.0 * std::sin(0.5 * psi) * std::sin(0.5 * psi);  // 1 − cos ψ
        const double v = v_of(omw);
        if (v > 0.0 && v < 1.0) bp[nb++] = v;
    }
    std::sort(bp, bp + nb);
    const Gl8 &q = gl8();
    double sum = 0.0;
    for (int p = 0; p + 1 < nb; ++p) {
        const double lo = bp[p], hi = bp[p + 1], h = hi - lo;
        if (!(h > 0.0)) continue;
        double ps = 0.0;
        for (size_t i = 0; i < q.x.size(); ++i) ps += q.w[i] * g(lo + h * q.x[i]);
        sum += h * ps;
    }
    return sum;
}
}  // namespace

double vmf_projected_area(Vec3 mu, double kappa) { return plane_integral(mu, kappa, false); }
double vmf_cap_mass(Vec3 mu, double kappa) { return plane_integral(mu, kappa, true); }

double mixture_projected_area(const std::vector<VmfLobe> &lobes) {
    double p = 0.0;
    for (const VmfLobe &l : lobes) p += l.weight * vmf_projected_area(l.mu, l.kappa);
    return p;
}

}  // namespace meso::prefilter
