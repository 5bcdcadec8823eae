#include "prefilter/least_squares.h"
#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <fmt/format.h>
#include "core/error.h"

// Eigen (header-only, Debian's libeigen3-dev) comes through Eigen3::Eigen in CMakeLists.txt.
#include <Eigen/IterativeLinearSolvers>
#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>

namespace meso::prefilter {

namespace {

using SpMat = Eigen::SparseMatrix<double, Eigen::ColMajor, int>;
using Triplet = Eigen::Triplet<double, int>;
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
}

/// The four corner vertex indices of coarse cell (I, J) (wrapping), in the order 00, 10, 01, 11.
inline void cell_corners(int I, int J, int w, int h, int64_t c[4]) {
    const int I1 = (I + 1) % w, J1 = (J + 1) % h;
    c[0] = int64_t(J) * w + I;
    c[1] = int64_t(J) * w + I1;
    c[2] = int64_t(J1) * w + I;
    c[3] = int64_t(J1) * w + I1;
}

/// Eq. (9) / Appendix A coefficients of the x and y average slopes on corners 00, 10, 01, 11.
constexpr double kSx[4] = {-0.5, 0.5, -0.5, 0.5};
constexpr double kSy[4] = {-0.5, -0.5, 0.5, 0.5};

/// One Laplacian row (the axes with both neighbours, see the header), as (index, coefficient)
/// pairs; returns the number of pairs (0: no term at this vertex). Duplicated indices (tiny
/// periodic grids) are left to the caller to sum.
int laplacian_row(int I, int J, int w, int h, bool periodic, int64_t idx[5], double coef[5]) {
    int n = 0;
    const int64_t self = int64_t(J) * w + I;
    double diag = 0;
    if (periodic || (I > 0 && I < w - 1)) {
        idx[n] = int64_t(J) * w + (I + 1) % w, coef[n++] = 1.0;
        idx[n] = int64_t(J) * w + (I + w - 1) % w, coef[n++] = 1.0;
        diag -= 2.0;
    }
    if (periodic || (J > 0 && J < h - 1)) {
        idx[n] = int64_t((J + 1) % h) * w + I, coef[n++] = 1.0;
        idx[n] = int64_t((J + h - 1) % h) * w + I, coef[n++] = 1.0;
        diag -= 2.0;
    }
    if (n == 0) return 0;
    idx[n] = self, coef[n++] = diag;
    return n;
}

/// Trapezoid weights of an n-vertex non-periodic axis (bilinear surface mean), plain for periodic.
std::vector<double> axis_weights(int n, bool periodic) {
    std::vector<double> wts(size_t(n), 1.0);
    if (!periodic && n > 1) wts.front() = wts.back() = 0.5;
    return wts;
}

}  // namespace

HeightMap LowResHeights::to_height_map() const {
    HeightMap m(width, height);
    for (size_t k = 0; k < h.size(); ++k) m.h[k] = float(h[k]);
    return m;
}

CellSlopes reference_slopes(const HeightMap &fine, int F, bool periodic) {
    const int W = fine.width, H = fine.height;
    const int Wc = W / F, Hc = H / F;
    CellSlopes s;
    s.cells_x = periodic ? Wc : std::max(Wc - 1, 0);
    s.cells_y = periodic ? Hc : std::max(Hc - 1, 0);
    s.sx.assign(size_t(s.cells_x) * s.cells_y, 0.0);
    s.sy.assign(s.sx.size(), 0.0);
    if (s.sx.empty()) return s;
    // Accumulate the eq.-9 slopes of the fine cells row by row (fine cells of rows that belong
    // to a data cell only); fine indices wrap only in the periodic case, where the last fine
    // cell of a row joins vertex W-1 to vertex 0.
    const int fine_rows = s.cells_y * F, fine_cols = s.cells_x * F;
    for (int j = 0; j < fine_rows; ++j) {
        const float *r0 = &fine.h[size_t(j) * W];
        const float *r1 = &fine.h[size_t((j + 1) % H) * W];
        double *ax = &s.sx[size_t(j / F) * s.cells_x];
        double *ay = &s.sy[size_t(j / F) * s.cells_x];
        for (int i = 0; i < fine_cols; ++i) {
            const int i1 = (i + 1 == W) ? 0 : i + 1;
            const double h00 = r0[i], h10 = r0[i1], h01 = r1[i], h11 = r1[i1];
            ax[i / F] += 0.5 * (h11 + h10 - h01 - h00);
            ay[i / F] += 0.5 * (h11 + h01 - h10 - h00);
        }
    }
    // Mean over the F x F fine cells (per fine cell) times F (per coarse cell) = sum / F.
    const double inv = 1.0 / double(F);
    for (size_t k = 0; k < s.sx.size(); ++k) s.sx[k] *= inv, s.sy[k] *= inv;
    return s;
}

CellSlopes bilinear_slopes(const std::vector<double> &h, int w, int hgt, bool periodic) {
    if (w < 1 || hgt < 1 || h.size() != size_t(w) * size_t(hgt))
        throw MesoError(fmt::format("bilinear_slopes: {} heights do not make a {}x{} grid", h.size(), w, hgt));
    CellSlopes s;
    s.cells_x = periodic ? w : w - 1;
    s.cells_y = periodic ? hgt : hgt - 1;
    s.sx.assign(size_t(s.cells_x) * s.cells_y, 0.0);
    s.sy.assign(s.sx.size(), 0.0);
    for (int J = 0; J < s.cells_y; ++J)
        for (int I = 0; I < s.cells_x; ++I) {
            int64_t c[4];
            cell_corners(I, J, w, hgt, c);
            double sx = 0, sy = 0;
            for (int k = 0; k < 4; ++k) sx += kSx[k] * h[size_t(c[k])], sy += kSy[k] * h[size_t(c[k])];
            s.sx[size_t(J) * s.cells_x + I] = sx;
            s.sy[size_t(J) * s.cells_x + I] = sy;
        }
    return s;
}

LowResHeights downsample_least_squares(const HeightMap &fine, int F, bool periodic, double w_reg) {
    LsqOptions o;
    o.periodic = periodic;
    o.w_reg = w_reg;
    return downsample_least_squares(fine, F, o);
}

namespace {

/// Throws MesoError for the inputs downsample_least_squares does not accept (see the header).
void check_lsq_input(const HeightMap &fine, int F, const LsqOptions &opt) {
    const int W = fine.width, H = fine.height;
    if (W < 1 || H < 1 || fine.h.size() != size_t(W) * size_t(H))
        throw MesoError(fmt::format("least-squares downsampling: the height map is empty or malformed ({}x{}, {} values)",
                                    W, H, fine.h.size()));
    if (F < 1 || W % F != 0 || H % F != 0)
        throw MesoError(fmt::format("least-squares downsampling: cannot downsample a {}x{} map by {} (the factor must "
                                    "be >= 1 and divide both sizes)",
                                    W, H, F));
    if (!std::isfinite(opt.w_reg) || opt.w_reg < 0)
        throw MesoError(fmt::format("least-squares downsampling: the regulariser weight w must be finite and >= 0, got {}",
                                    opt.w_reg));
    for (size_t k = 0; k < fine.h.size(); ++k)
        if (!std::isfinite(fine.h[k]))
            throw MesoError(fmt::format("least-squares downsampling: non-finite height at vertex ({}, {})",
                                        k % size_t(W), k / size_t(W)));
}

/// Mean height of the fine bilinear surface over the region the coarse map represents: all
/// vertices when no coarse cell has a slope term (`no_cells`), else the plain vertex mean
/// (periodic) or the trapezoid-weighted one over [0, (Wc - 1) F] x [0, (Hc - 1) F].
double fine_mean_height(const HeightMap &fine, int F, int Wc, int Hc, bool periodic, bool no_cells) {
    const int W = fine.width, H = fine.height;
    double sum = 0, wsum = 0;
    if (no_cells) {
        for (float v : fine.h) sum += v;
        wsum = double(fine.h.size());
    } else {
        const int fw = periodic ? W : (Wc - 1) * F + 1, fh = periodic ? H : (Hc - 1) * F + 1;
        const std::vector<double> wx = axis_weights(fw, periodic), wy = axis_weights(fh, periodic);
        for (int j = 0; j < fh; ++j) {
            double row = 0;
            for (int i = 0; i < fw; ++i) row += wx[size_t(i)] * fine.h[size_t(j) * W + i];
            sum += wy[size_t(j)] * row;
        }
        double sx = 0, sy = 0;
        for (double v : wx) sx += v;
        for (double v : wy) sy += v;
        wsum = sx * sy;
    }
    return sum / wsum;
}

/// A: the slope operator of eq. 9, two rows (s~x, s~y) per data cell of `ref`, on the
/// Wc x Hc coarse vertices.
SpMat slope_operator(const CellSlopes &ref, int Wc, int Hc) {
    const int64_t cells = int64_t(ref.cells_x) * ref.cells_y;
    SpMat A(int(2 * cells), int(int64_t(Wc) * Hc));
    std::vector<Triplet> t;
    t.reserve(size_t(cells) * 8);
    for (int J = 0; J < ref.cells_y; ++J)
        for (int I = 0; I < ref.cells_x; ++I) {
            int64_t c[4];
            cell_corners(I, J, Wc, Hc, c);
            const int row = 2 * (J * ref.cells_x + I);
            for (int k = 0; k < 4; ++k) {
                t.emplace_back(row, int(c[k]), kSx[k]);
                t.emplace_back(row + 1, int(c[k]), kSy[k]);
            }
        }
    A.setFromTriplets(t.begin(), t.end());
    return A;
}

/// D: the Laplacian of eq. 10's regulariser, one row per vertex that has a term (see the header).
SpMat laplacian_operator(int Wc, int Hc, bool periodic) {
    const int64_t N = int64_t(Wc) * Hc;
    int rows = 0;
    std::vector<Triplet> t;
    t.reserve(size_t(N) * 5);
    for (int J = 0; J < Hc; ++J)
        for (int I = 0; I < Wc; ++I) {
            int64_t idx[5];
            double coef[5];
            const int n = laplacian_row(I, J, Wc, Hc, periodic, idx, coef);
            if (n == 0) continue;
            for (int k = 0; k < n; ++k) t.emplace_back(rows, int(idx[k]), coef[k]);
            ++rows;
        }
    SpMat D;
    D.resize(rows, int(N));
    D.setFromTriplets(t.begin(), t.end());
    return D;
}

/// Eq. 10's normal equations (A^T A + w D^T D) h = A^T s~* in units of the reference slopes'
/// magnitude, with the null space pinned.
struct NormalEquations {
    SpMat M;
    Eigen::VectorXd b;
    double scale = 1.0;    ///< heights are solved in units of max |s~*| (1 for a flat map)
    int lap_rows = 0;      ///< vertices with a Laplacian term
    bool cb_free = false;  ///< the checkerboard (-1)^(I+J) is in the null space (pinned, projected out later)
};

NormalEquations normal_equations(const CellSlopes &ref, int Wc, int Hc, bool periodic, double w) {
    const int64_t cells = int64_t(ref.cells_x) * ref.cells_y, N = int64_t(Wc) * Hc;
    NormalEquations ne;
    const SpMat A = slope_operator(ref, Wc, Hc), D = laplacian_operator(Wc, Hc, periodic);
    ne.lap_rows = int(D.rows());
    Eigen::VectorXd s(2 * cells);
    for (int64_t k = 0; k < cells; ++k) s[2 * k] = ref.sx[size_t(k)], s[2 * k + 1] = ref.sy[size_t(k)];

    // Scale: solve for heights in units of the reference slopes' magnitude so that huge or tiny
    // maps behave like unit ones (the problem is linear in the heights).
    double smax = 0;
    for (int64_t k = 0; k < s.size(); ++k) smax = std::max(smax, std::abs(s[k]));
    ne.scale = smax > 0 ? smax : 1.0;
    ne.b = A.transpose() * (s / ne.scale);

    ne.M = SpMat(A.transpose() * A);
    if (w > 0 && ne.lap_rows > 0) ne.M += w * SpMat(D.transpose() * D);
    // Null space: a constant offset, plus the checkerboard (-1)^(I+J) when nothing but the
    // slopes acts on it (w == 0, or a lone non-periodic 2x2 cell) and it fits the grid
    // (always when non-periodic, even sizes when periodic). Pin vertex 0 (and vertex 1, on the
    // other sublattice, when the checkerboard is free): exact, as the objective ignores those
    // directions; the checkerboard is projected out and the mean set below.
    ne.cb_free = (w == 0 || ne.lap_rows == 0) && N >= 2 && (!periodic || (Wc % 2 == 0 && Hc % 2 == 0));
    ne.M.coeffRef(0, 0) += 1.0;
    if (ne.cb_free) ne.M.coeffRef(1, 1) += 1.0;
    ne.M.makeCompressed();
    return ne;
}

/// The pinned system by the solver `opt` asks for (Auto: direct up to direct_max_unknowns);
/// CG warm-starts from the fine heights and falls back to the direct solver. Records the
/// solver, iterations and residual in `out`.
Eigen::VectorXd solve_normal_equations(const NormalEquations &ne, const HeightMap &fine, int F, const LsqOptions &opt,
                                       LowResHeights &out) {
    const int W = fine.width, Wc = out.width, Hc = out.height;
    const int64_t N = int64_t(Wc) * Hc;
    Eigen::VectorXd x(N);
    LsqSolver which = opt.solver;
    if (which == LsqSolver::Auto) which = (N <= opt.direct_max_unknowns) ? LsqSolver::Direct : LsqSolver::CG;
    auto solve_direct = [&] {
        Eigen::SimplicialLDLT<SpMat, Eigen::Lower> ldlt;
        ldlt.compute(ne.M);
        if (ldlt.info() != Eigen::Success)
            throw MesoError(fmt::format("least-squares downsampling: the {}x{} normal equations could not be factorised",
                                        Wc, Hc));
        x = ldlt.solve(ne.b);
        out.solver = "direct";
    };
    if (which == LsqSolver::Direct) {
        solve_direct();
        return x;
    }
    // Warm start: the fine heights at the coarse vertices (pin-consistent: vertex 0 at 0).
    Eigen::VectorXd x0(N);
    const double h0 = fine.h[0];
    for (int J = 0; J < Hc; ++J)
        for (int I = 0; I < Wc; ++I)
            x0[int64_t(J) * Wc + I] = (double(fine.h[size_t(J) * F * W + size_t(I) * F]) - h0) / ne.scale;
    if (ne.cb_free) x0[1] = 0.0;
    Eigen::ConjugateGradient<SpMat, Eigen::Lower | Eigen::Upper, Eigen::IncompleteCholesky<double>> cg;
    cg.setTolerance(opt.cg_tolerance);
    cg.setMaxIterations(opt.cg_max_iterations > 0 ? opt.cg_max_iterations
                                                  : int(std::max<int64_t>(2000, 4 * (Wc + Hc))));
    cg.compute(ne.M);
    bool ok = cg.info() == Eigen::Success;
    if (ok) {
        x = cg.solveWithGuess(ne.b, x0);
        out.iterations = int(cg.iterations());
        out.cg_relative_residual = cg.error();
        ok = cg.info() == Eigen::Success && x.allFinite();
        out.solver = "cg";
    }
    if (!ok) solve_direct();  // preconditioner failure or no convergence: exact fallback
    return x;
}

/// Least-squares coefficient of x against the checkerboard (-1)^(I+J) made orthogonal to
/// constants (an odd x odd grid has one more +1 than -1), so that the pinned offset does not
/// leak in.
double checkerboard_coefficient(const Eigen::VectorXd &x, int Wc, int Hc) {
    const int64_t N = int64_t(Wc) * Hc;
    double cb_mean = 0;
    for (int J = 0; J < Hc; ++J)
        for (int I = 0; I < Wc; ++I) cb_mean += (I + J) % 2 ? -1.0 : 1.0;
    cb_mean /= double(N);
    double num = 0, den = 0;
    for (int J = 0; J < Hc; ++J)
        for (int I = 0; I < Wc; ++I) {
            const double c = ((I + J) % 2 ? -1.0 : 1.0) - cb_mean;
            num += c * x[int64_t(J) * Wc + I];
            den += c * c;
        }
    return den > 0 ? num / den : 0.0;
}

/// out.h from the solution x: the checkerboard removed where the objective leaves it free,
/// back to height units, and shifted so that its mean (plain vertex mean periodic, trapezoid
/// otherwise) is out.mean_height.
void set_heights(const Eigen::VectorXd &x, const NormalEquations &ne, LowResHeights &out) {
    const int Wc = out.width, Hc = out.height;
    out.h.resize(size_t(int64_t(Wc) * Hc));
    const double cb_coef = ne.cb_free ? checkerboard_coefficient(x, Wc, Hc) : 0.0;
    for (int J = 0; J < Hc; ++J)
        for (int I = 0; I < Wc; ++I) {
            const int64_t k = int64_t(J) * Wc + I;
            out.h[size_t(k)] = (x[k] - ((I + J) % 2 ? -cb_coef : cb_coef)) * ne.scale;
        }
    const std::vector<double> wx = axis_weights(Wc, out.periodic), wy = axis_weights(Hc, out.periodic);
    double sum = 0, wsum = 0;
    for (int J = 0; J < Hc; ++J)
        for (int I = 0; I < Wc; ++I) {
            const double wt = wx[size_t(I)] * wy[size_t(J)];
            sum += wt * out.h[size_t(J) * Wc + I];
            wsum += wt;
        }
    const double shift = out.mean_height - sum / wsum;
    for (double &v : out.h) v += shift;
}

/// The two terms of eq. 10 at the solution, and the slope errors against s~*.
void set_diagnostics(const CellSlopes &ref, int lap_rows, LowResHeights &out) {
    const int Wc = out.width, Hc = out.height;
    const CellSlopes got = bilinear_slopes(out.h, Wc, Hc, out.periodic);
    double e2 = 0, r2 = 0, emax = 0;
    for (size_t k = 0; k < got.sx.size(); ++k) {
        const double dx = got.sx[k] - ref.sx[k], dy = got.sy[k] - ref.sy[k];
        const double e = dx * dx + dy * dy;
        e2 += e;
        emax = std::max(emax, e);
        r2 += ref.sx[k] * ref.sx[k] + ref.sy[k] * ref.sy[k];
    }
    double l2 = 0;
    for (int J = 0; J < Hc; ++J)
        for (int I = 0; I < Wc; ++I) {
            int64_t idx[5];
            double coef[5];
            const int n = laplacian_row(I, J, Wc, Hc, out.periodic, idx, coef);
            double v = 0;
            for (int k = 0; k < n; ++k) v += coef[k] * out.h[size_t(idx[k])];
            l2 += v * v;
        }
    const double nc = double(std::max<int64_t>(int64_t(ref.cells_x) * ref.cells_y, 1));
    out.slope_rms_error = std::sqrt(e2 / nc);
    out.slope_max_error = std::sqrt(emax);
    out.slope_rms_reference = std::sqrt(r2 / nc);
    out.laplacian_rms = lap_rows > 0 ? std::sqrt(l2 / lap_rows) : 0.0;
    out.slope_sq_error = e2;
    out.laplacian_sq = l2;
    out.objective = e2 + out.w_reg * l2;
}

}  // namespace

LowResHeights downsample_least_squares(const HeightMap &fine, int F, const LsqOptions &opt) {
    const auto t_start = Clock::now();
    check_lsq_input(fine, F, opt);
    const bool periodic = opt.periodic;
    LowResHeights out;
    out.width = fine.width / F;
    out.height = fine.height / F;
    out.factor = F;
    out.periodic = periodic;
    out.w_reg = opt.w_reg;
    const int Wc = out.width, Hc = out.height;
    const int64_t N = int64_t(Wc) * Hc;
    if (N > int64_t(std::numeric_limits<int>::max() / 32))
        throw MesoError(fmt::format("least-squares downsampling: a {}x{} coarse map is too large", Wc, Hc));

    const bool no_cells = !periodic && (Wc == 1 || Hc == 1);
    out.mean_height = fine_mean_height(fine, F, Wc, Hc, periodic, no_cells);
    if (no_cells) {  // no coarse cell has a slope term: nothing to fit
        out.h.assign(size_t(N), out.mean_height);
        out.solver = "trivial";
        out.assembly_seconds = seconds_since(t_start);
        return out;
    }
    // s~* (eq. 1 with the coarse cell's box kernel), then the normal equations of eq. 10.
    const CellSlopes ref = reference_slopes(fine, F, periodic);
    out.data_cells = int(int64_t(ref.cells_x) * ref.cells_y);
    const NormalEquations ne = normal_equations(ref, Wc, Hc, periodic, opt.w_reg);
    out.assembly_seconds = seconds_since(t_start);

    const auto t_solve = Clock::now();
    const Eigen::VectorXd x = solve_normal_equations(ne, fine, F, opt, out);
    out.solve_seconds = seconds_since(t_solve);
    if (!x.allFinite())
        throw MesoError(fmt::format("least-squares downsampling: the {}x{} solve produced non-finite heights", Wc, Hc));
    set_heights(x, ne, out);
    set_diagnostics(ref, ne.lap_rows, out);
    return out;
}

}  // namespace meso::prefilter
