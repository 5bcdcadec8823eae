// Procedural height maps (see heightmap_gen.h for the units and conventions, and
// docs/genmap.md for every generator and parameter).
//
// Periodicity is built in, not patched: every generator is a function of the vertex index
// taken modulo the map size (noise lattices wrap with integer periods, spectra hold only
// integer wave vectors, weaves and facets repeat an integer number of times per tile).
//
// The gaussian generator reaches its slope covariance exactly: the cell slopes of the
// bilinear surface (paper 004, Appendix A) are linear in the heights, and for a Fourier
// mode m of the map the cell slope is a complex scalar times the REAL vector
//   r(m) = (W sin(a/2) cos(b/2), H cos(a/2) sin(b/2)),   a = 2 pi m_u / W, b = 2 pi m_v / H,
// so the measured covariance is C = sum_m 4 |c_m|^2 r r^T (Parseval; modes are orthogonal
// on the grid). Shaping the amplitudes by sqrt(r^T B r / |r|^2) makes C linear in the
// symmetric 2x2 matrix B; solving the 3x3 system for B maps the measured covariance of the
// random field exactly onto the target (the spectral form of the linear slope transform
// T^1/2 C^-1/2, which cannot be applied in the spatial domain without breaking the period).
#include "geometry/heightmap_gen.h"
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <algorithm>
#include <cerrno>
#include <cmath>
#include <complex>
#include <cstdlib>
#include <fmt/format.h>
#include <functional>
#include "core/dft.h"
#include "core/error.h"
#include "image/wrap_mode.h"
#include "sampling/rng.h"

namespace meso {
namespace {

constexpr double kPi = 3.14159265358979323846;

// ---------------------------------------------------------------------------------------
// Parameters: every value arrives as text; defaults live in the GeneratorInfo table.

/// Reads one generator's parameters, checking names, types and ranges.
class Params {
public:
    Params(const GeneratorInfo &info, const std::map<std::string, std::string> &given, const std::string &where)
        : m_info(info), m_given(given), m_where(where) {
        for (auto &[key, value] : given)
            if (!find(key)) {
                std::string known;
                for (auto &p : info.params) known += (known.empty() ? "" : ", ") + p.name;
                fail(key, fmt::format("unknown parameter of generator '{}' (expected one of: {})", info.name, known));
            }
    }
    [[noreturn]] void fail(const std::string &key, const std::string &msg) const {
        throw MesoError(located_message(m_where, key, msg));
    }
    bool given(const std::string &key) const { return m_given.count(key) > 0; }
    std::string text(const std::string &key) {
        auto it = m_given.find(key);
        std::string v = it != m_given.end() ? it->second : find(key)->default_value;
        m_used[key] = v;
        return v;
    }
    double real(const std::string &key, double lo, double hi, bool lo_open = false) {
        std::string s = text(key);
        const char *b = s.c_str();
        char *e = nullptr;
        errno = 0;
        double v = std::strtod(b, &e);
        bool ok = e != b && *e == 0 && errno == 0 && std::isfinite(v) && (lo_open ? v > lo : v >= lo) && v <= hi;
        if (!ok) fail(key, fmt::format("expected a number in {}{}, {}], got '{}'", lo_open ? "(" : "[", lo, hi, s));
        return v;
    }
    int64_t integer(const std::string &key, int64_t lo, int64_t hi) {
        std::string s = text(key);
        const char *b = s.c_str();
        char *e = nullptr;
        errno = 0;
        long long v = std::strtoll(b, &e, 10);
        if (e == b || *e != 0 || errno != 0 || v < lo || v > hi)
            fail(key, fmt::format("expected an integer in [{}, {}], got '{}'", lo, hi, s));
        return v;
    }
    /// "r,g,b" (or one number for grey), each in [0, 1].
    Spectrum rgb(const std::string &key) {
        std::string s = text(key);
        std::vector<float> c;
        size_t start = 0;
        bool ok = true;
        for (size_t end; ok && start <= s.size(); start = end + 1) {
            end = std::min(s.find(',', start), s.size());
            std::string item = s.substr(start, end - start);
            char *e = nullptr;
            double v = std::strtod(item.c_str(), &e);
            ok = !item.empty() && *e == 0 && std::isfinite(v) && v >= 0 && v <= 1;
            c.push_back(float(v));
        }
        if (!ok || (c.size() != 1 && c.size() != 3))
            fail(key, fmt::format("expected an RGB reflectance 'r,g,b' with values in [0, 1], got '{}'", s));
        return c.size() == 1 ? Spectrum(c[0]) : Spectrum(c[0], c[1], c[2]);
    }
    std::string choice(const std::string &key, std::initializer_list<const char *> options) {
        std::string s = text(key), list;
        for (const char *o : options) {
            if (s == o) return s;
            list += (list.empty() ? "'" : ", '") + std::string(o) + "'";
        }
        fail(key, fmt::format("expected one of {}, got '{}'", list, s));
    }
    /// Map size: width / height override size ("" = size).
    void size(int &w, int &h) {
        int64_t s = integer("size", 2, 16384);
        w = text("width").empty() ? int(s) : int(integer("width", 2, 16384));
        h = text("height").empty() ? int(s) : int(integer("height", 2, 16384));
    }
    uint64_t seed() { return uint64_t(integer("seed", 0, (int64_t(1) << 53))); }
    std::map<std::string, std::string> used() const { return m_used; }

private:
    const GeneratorParam *find(const std::string &key) const {
        for (auto &p : m_info.params)
            if (p.name == key) return &p;
        return nullptr;
    }
    const GeneratorInfo &m_info;
    const std::map<std::string, std::string> &m_given;
    std::string m_where;
    std::map<std::string, std::string> m_used;
};

/// Evaluates f(i, j) at every vertex, rows in parallel (f must be a pure function).
template <typename F> HeightMap fill_map(int w, int h, F f) {
    HeightMap map(w, h);
    tbb::parallel_for(tbb::blocked_range<int>(0, h), [&](const tbb::blocked_range<int> &r) {
        for (int j = r.begin(); j < r.end(); ++j)
            for (int i = 0; i < w; ++i) map.at(i, j) = float(f(i, j));
    });
    return map;
}

// ---------------------------------------------------------------------------------------
// Periodic gradient (Perlin) noise and fBm.

/// Perlin gradient noise on the integer lattice with random unit gradients, periodic with
/// integer periods (px, py): lattice point (i, j) is (i mod px, j mod py). Quintic fade
/// (Perlin 2002). Values lie within about [-1, 1].
class PeriodicNoise {
public:
    explicit PeriodicNoise(uint64_t seed) : m_seed(mix_bits(seed ^ 0x5eedf00dULL)) {}
    double operator()(double x, double y, int64_t px, int64_t py, uint64_t layer = 0) const {
        double fx = std::floor(x), fy = std::floor(y);
        int64_t i = int64_t(fx), j = int64_t(fy);
        double dx = x - fx, dy = y - fy;
        const uint64_t key = hash_combine(m_seed, layer);
        const Table *t = layer < m_tables.size() && m_tables[layer].px == px && m_tables[layer].py == py
                             ? &m_tables[layer] : nullptr;
        auto g = [&](int64_t a, int64_t b, double ox, double oy) {
            a = wrap_index(a, px, WrapMode::Repeat);
            b = wrap_index(b, py, WrapMode::Repeat);
            if (t) {
                const double *cs = &t->cos_sin[2 * (size_t(b) * size_t(px) + size_t(a))];
                return cs[0] * ox + cs[1] * oy;
            }
            const double angle = gradient_angle(key, a, b);
            return std::cos(angle) * ox + std::sin(angle) * oy;
        };
        auto fade = [](double t) { return t * t * t * (t * (t * 6 - 15) + 10); };
        double sx = fade(dx), sy = fade(dy);
        double n00 = g(i, j, dx, dy), n10 = g(i + 1, j, dx - 1, dy);
        double n01 = g(i, j + 1, dx, dy - 1), n11 = g(i + 1, j + 1, dx - 1, dy - 1);
        double a = n00 + sx * (n10 - n00), b = n01 + sx * (n11 - n01);
        return Sqrt2 * (a + sy * (b - a));  // unit gradients reach at most sqrt(1/2)
    }
    /// Tabulates the gradients of `layer`'s lattice with periods (px, py): operator() then reads
    /// each corner's cosine and sine instead of computing them (the same values: a map is
    /// bit-identical either way). Worth it where the lattice has fewer points than the map has
    /// corner lookups (4 a texel); not thread-safe (call before the parallel fill).
    void tabulate(int64_t px, int64_t py, uint64_t layer) {
        if (m_tables.size() <= layer) m_tables.resize(layer + 1);
        Table &t = m_tables[layer];
        t.px = px, t.py = py;
        t.cos_sin.resize(2 * size_t(px) * size_t(py));
        const uint64_t key = hash_combine(m_seed, layer);
        for (int64_t b = 0; b < py; ++b)
            for (int64_t a = 0; a < px; ++a) {
                const double angle = gradient_angle(key, a, b);
                double *cs = &t.cos_sin[2 * (size_t(b) * size_t(px) + size_t(a))];
                cs[0] = std::cos(angle), cs[1] = std::sin(angle);
            }
    }

private:
    static double gradient_angle(uint64_t key, int64_t a, int64_t b) {
        return double(hash_combine(key, uint64_t(a) * 0x100000001b3ULL ^ uint64_t(b)) >> 11) * 0x1p-53 * 2 * kPi;
    }
    struct Table {
        int64_t px = 0, py = 0;
        std::vector<double> cos_sin;  ///< per lattice point (a, b), at 2 (b px + a): cos, sin of its angle
    };
    uint64_t m_seed;
    std::vector<Table> m_tables;  ///< by layer; px = 0: none
};

struct FbmSpec {
    int octaves = 6, lacunarity = 2, frequency = 4;
    double gain = 0.5, amplitude = 0.02;
};

/// Sum over octaves k of amplitude gain^k noise(frequency lacunarity^k (u, v)), periodic
/// on the unit tile because every octave's frequency is an integer.
double fbm(const PeriodicNoise &noise, const FbmSpec &s, double u, double v) {
    double sum = 0, amp = s.amplitude;
    int64_t f = s.frequency;
    for (int k = 0; k < s.octaves; ++k, f *= s.lacunarity, amp *= s.gain) sum += amp * noise(u * f, v * f, f, f, k);
    return sum;
}

/// Tabulates the gradients of fbm's octaves on a w x h map where that is cheaper than computing
/// them per corner (a lattice of at most w h / 4 points, and at most 2^20: 16 MB).
void tabulate_fbm(PeriodicNoise &noise, const FbmSpec &s, int w, int h) {
    int64_t f = s.frequency;
    for (int k = 0; k < s.octaves; ++k, f *= s.lacunarity)
        if (f * f <= int64_t(w) * h / 4 && f * f <= (int64_t(1) << 20)) noise.tabulate(f, f, uint64_t(k));
}

FbmSpec read_fbm(Params &p, const std::string &prefix) {
    FbmSpec s;
    s.octaves = int(p.integer(prefix + "octaves", 1, 24));
    s.lacunarity = int(p.integer(prefix + "lacunarity", 1, 16));
    s.gain = p.real(prefix + "gain", 0, 1);
    s.frequency = int(p.integer(prefix + "frequency", 1, 1 << 20));
    s.amplitude = p.real(prefix + "amplitude", 0, 1e6);
    if (double(s.frequency) * std::pow(double(s.lacunarity), s.octaves - 1) > double(1 << 30))
        p.fail(prefix + "octaves", fmt::format("expected frequency * lacunarity^(octaves-1) <= 2^30, got {} * {}^{}",
                                               s.frequency, s.lacunarity, s.octaves - 1));
    return s;
}

GeneratedMap gen_fbm(Params &p) {
    GeneratedMap g;
    int w, h;
    p.size(w, h);
    PeriodicNoise noise(p.seed());
    FbmSpec s = read_fbm(p, "");
    tabulate_fbm(noise, s, w, h);
    g.height = fill_map(w, h, [&](int i, int j) { return fbm(noise, s, double(i) / w, double(j) / h); });
    int64_t top = int64_t(s.frequency) * int64_t(std::pow(double(s.lacunarity), s.octaves - 1));
    if (2 * top > std::min(w, h))
        g.notes.push_back(fmt::format("the finest octave ({} periods per tile) is above the grid's Nyquist limit ({}): "
                                      "it aliases; use fewer octaves or a larger size",
                                      top, std::min(w, h) / 2));
    return g;
}

// ---------------------------------------------------------------------------------------
// Gaussian random surface with a prescribed cell-slope covariance.

struct Sym2 {
    double xx = 0, yy = 0, xy = 0;
};

/// Eigenvalues (descending) and the unit eigenvector of the larger one.
void eigen(const Sym2 &s, double &l1, double &l2, double &ex, double &ey) {
    double m = 0.5 * (s.xx + s.yy), d = std::hypot(0.5 * (s.xx - s.yy), s.xy);
    l1 = m + d, l2 = m - d;
    if (d == 0) {
        ex = 1, ey = 0;
        return;
    }
    // (s - l2) has the l1-eigenvector in its column space; pick the larger column.
    double ax = s.xx - l2, ay = s.xy, bx = s.xy, by = s.yy - l2;
    if (ax * ax + ay * ay < bx * bx + by * by) ax = bx, ay = by;
    double n = std::hypot(ax, ay);
    ex = ax / n, ey = ay / n;
}

/// Cell-slope direction vector r(m) of Fourier mode (mu, mv) (see the file comment).
void mode_slope(int mu, int mv, int w, int h, double &rx, double &ry) {
    double a = kPi * mu / w, b = kPi * mv / h;  // half angles
    rx = w * std::sin(a) * std::cos(b);
    ry = h * std::cos(a) * std::sin(b);
}

/// Signed frequency of DFT index k of an n-point transform.
int signed_freq(int k, int n) { return k <= n / 2 ? k : k - n; }

/// Solves the symmetric 3x3 system a x = b (Gaussian elimination, partial pivoting).
bool solve3(double a[3][3], double b[3], double x[3]) {
    for (int c = 0; c < 3; ++c) {
        int piv = c;
        for (int r = c + 1; r < 3; ++r)
            if (std::abs(a[r][c]) > std::abs(a[piv][c])) piv = r;
        if (std::abs(a[piv][c]) < 1e-300) return false;
        std::swap(a[c], a[piv]);
        std::swap(b[c], b[piv]);
        for (int r = c + 1; r < 3; ++r) {
            double f = a[r][c] / a[c][c];
            for (int k = c; k < 3; ++k) a[r][k] -= f * a[c][k];
            b[r] -= f * b[c];
        }
    }
    for (int c = 2; c >= 0; --c) {
        double s = b[c];
        for (int k = c + 1; k < 3; ++k) s -= a[c][k] * x[k];
        x[c] = s / a[c][c];
    }
    return true;
}

/// Reshapes the Fourier amplitudes c (h x w, DFT order) by f_m = sqrt(r^T B r / |r|^2) so
/// that the cell-slope covariance becomes exactly t. The covariance after reshaping is
/// linear in B: with q_m = 4 |c_m|^2 |r|^2 and unit r = (x, y),
///   C(B) = sum_m q_m (b11 x^2 + b22 y^2 + 2 b12 x y) (x^2, y^2, x y),
/// a 3x3 system. Its solution is usable when positive semi-definite (f real); when it is
/// not (a strongly anisotropic target that the lattice of wave vectors resolves poorly),
/// a damped step towards it that stays positive definite is taken and the system solved
/// again. Rank-1 targets hold only modes along the target direction: a scale does it.
/// Returns false if no usable solution is reached.
bool match_slope_covariance(std::vector<Complex> &c, int w, int h, const Sym2 &t, bool rank1) {
    auto each_mode = [&](auto f) {
        for (int kv = 0; kv < h; ++kv)
            for (int ku = 0; ku < w; ++ku) {
                Complex &z = c[size_t(kv) * w + ku];
                if (z == Complex(0)) continue;
                double rx, ry;
                mode_slope(signed_freq(ku, w), signed_freq(kv, h), w, h, rx, ry);
                double r = std::hypot(rx, ry);
                f(z, rx / r, ry / r, r * r);
            }
    };
    auto reshape = [&](const double b[3]) {
        each_mode([&](Complex &z, double x, double y, double) {
            z *= std::sqrt(std::max(0.0, b[0] * x * x + b[1] * y * y + 2 * b[2] * x * y));
        });
    };
    for (int iteration = 0; iteration < 100; ++iteration) {
        double a[3][3] = {}, rhs[3] = {t.xx, t.yy, t.xy}, b[3] = {0, 0, 0}, trace = 0;
        each_mode([&](Complex &z, double x, double y, double r2) {
            double q = 4 * std::norm(z) * r2, basis[3] = {x * x, y * y, 2 * x * y}, out[3] = {x * x, y * y, x * y};
            for (int row = 0; row < 3; ++row)
                for (int col = 0; col < 3; ++col) a[row][col] += q * out[row] * basis[col];
            trace += q;
        });
        if (!(trace > 0)) return false;
        double scale = (t.xx + t.yy) / trace;  // the plain rescaling that matches the trace
        if (rank1) {
            b[0] = b[1] = scale;
            reshape(b);
            return true;
        }
        if (!solve3(a, rhs, b)) return false;
        double l1, l2, ex, ey;
        eigen({b[0], b[1], b[2]}, l1, l2, ex, ey);
        if (l2 >= 0) {
            reshape(b);
            return true;
        }
        // B(alpha) = (1 - alpha) scale I + alpha B with smallest eigenvalue (1 - alpha) scale / 2.
        double alpha = 0.5 * scale / (0.5 * scale - l2);
        double step[3] = {(1 - alpha) * scale + alpha * b[0], (1 - alpha) * scale + alpha * b[1], alpha * b[2]};
        reshape(step);
    }
    return false;
}

GeneratedMap gen_gaussian(Params &p) {
    GeneratedMap g;
    int w, h;
    p.size(w, h);
    uint64_t seed = p.seed();
    double ell = p.real("correlation", 0, 1, true);
    Sym2 t;
    t.xx = p.real("sxx", 0, 1e6);
    t.yy = p.real("syy", 0, 1e6);
    t.xy = p.real("sxy", -1e6, 1e6);
    double mx = p.real("mx", -1e3, 1e3), my = p.real("my", -1e3, 1e3);
    double bound = std::sqrt(t.xx * t.yy);
    if (std::abs(t.xy) > bound * (1 + 1e-9))
        p.fail("sxy", fmt::format("expected |sxy| <= sqrt(sxx * syy) = {} (a covariance is positive semi-definite), "
                                  "got {}",
                                  bound, t.xy));
    if (ell * std::min(w, h) < 1)
        p.fail("correlation", fmt::format("expected at least one cell (1 / {} = {}), got {}", std::min(w, h),
                                          1.0 / std::min(w, h), ell));
    double l1, l2, ex, ey;
    eigen(t, l1, l2, ex, ey);

    // Which wave vectors may carry energy. Rank 2: all but DC and the Nyquist lines. A
    // rank-1 target (all slopes along one direction) needs every mode's r(m) along it,
    // which integer wave vectors give only along an axis or, on a square map, a diagonal.
    bool rank1 = l2 <= 1e-12 * l1;
    int line_u = 0, line_v = 0;  // rank 1: modes m = n * (line_u, line_v)
    if (l1 > 0 && rank1) {
        if (t.xx <= 1e-12 * l1) line_u = 0, line_v = 1;
        else if (t.yy <= 1e-12 * l1) line_u = 1, line_v = 0;
        else if (w == h && std::abs(t.xx - t.yy) <= 1e-9 * l1) line_u = 1, line_v = t.xy > 0 ? 1 : -1;
        else
            p.fail("sxy", fmt::format("a degenerate slope covariance (|sxy| = sqrt(sxx * syy)) puts every slope along "
                                      "one direction, which a periodic map can only do along u (sxx = 0), v (syy = 0) "
                                      "or, on a square map, a diagonal (sxx = syy = |sxy|); got sxx = {}, syy = {}, sxy = {}",
                                      t.xx, t.yy, t.xy));
    }
    auto allowed = [&](int mu, int mv) {
        if ((mu == 0 && mv == 0) || 2 * std::abs(mu) == w || 2 * std::abs(mv) == h) return false;
        if (!rank1) return true;
        return line_u == 0 ? mu == 0 : (line_v == 0 ? mv == 0 : mv == line_v * mu);
    };

    // Gaussian autocorrelation sigma^2 exp(-x^T Q x) has slope covariance 2 sigma^2 Q, so
    // Q = T / (2 sigma^2); `correlation` is the correlation length along the steepest
    // principal direction, sigma^2 = ell^2 l1 / 2. Its spectrum is proportional to
    // exp(-pi^2 m^T Q^-1 m) with Q^-1 = ell^2 l1 T^-1 (rank 1: exp(-pi^2 ell^2 |m|^2) on the line).
    double det = t.xx * t.yy - t.xy * t.xy;
    auto spectrum = [&](int mu, int mv) {
        double q = rank1 ? double(mu) * mu + double(mv) * mv
                         : l1 * (t.yy * mu * mu - 2 * t.xy * mu * mv + t.xx * mv * mv) / det;
        return std::exp(-kPi * kPi * ell * ell * q);
    };

    std::vector<Complex> c(size_t(w) * h, Complex(0));
    if (l1 > 0) {
        PCG32 rng(mix_bits(seed), 0x9a055ULL);
        auto gauss = [&] {  // Box-Muller, one value per call (deterministic order)
            double u1 = 1 - rng.next_double(), u2 = rng.next_double();
            return std::sqrt(-2 * std::log(u1)) * std::cos(2 * kPi * u2);
        };
        // Complex Gaussian amplitude on one of each +-m pair; its conjugate on the other keeps h real.
        for (int kv = 0; kv < h; ++kv)
            for (int ku = 0; ku < w; ++ku) {
                int mu = signed_freq(ku, w), mv = signed_freq(kv, h);
                bool canonical = mu > 0 || (mu == 0 && mv > 0);
                if (!canonical || !allowed(mu, mv)) continue;
                double a = std::sqrt(0.5 * spectrum(mu, mv));
                Complex z(a * gauss(), a * gauss());
                c[size_t(kv) * w + ku] = z;
                c[size_t((h - kv) % h) * w + (w - ku) % w] = std::conj(z);
            }

        if (!match_slope_covariance(c, w, h, t, rank1))
            p.fail("correlation", fmt::format("cannot reach the slope covariance (sxx {}, syy {}, sxy {}) with "
                                              "correlation {} on a {}x{} map: too anisotropic for the grid; use a "
                                              "larger size or a shorter correlation",
                                              t.xx, t.yy, t.xy, ell, w, h));
        inverse_dft_2d(c, w, h);
    }
    g.height = HeightMap(w, h);
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < w; ++i)
            g.height.at(i, j) = float(c[size_t(j) * w + i].real() + mx * (double(i) / w - 0.5) + my * (double(j) / h - 0.5));
    if (mx != 0 || my != 0) {
        g.periodic = false;
        g.notes.push_back(fmt::format("mean slope ({}, {}) makes the map non-periodic: the wrap-around cells "
                                      "(last column / row) jump by {} / {} instead of continuing the ramp",
                                      mx, my, -mx, -my));
    }
    return g;
}

// ---------------------------------------------------------------------------------------
// Hemispherical bumps.

GeneratedMap gen_bumps(Params &p) {
    GeneratedMap g;
    int w, h;
    p.size(w, h);
    PCG32 rng(mix_bits(p.seed()), 0xb0b5ULL);
    double radius = p.real("radius", 0, 0.5, true);
    double rjitter = p.real("radius_jitter", 0, 1);
    int64_t grid = p.integer("grid", 0, 4096);
    int64_t count = p.integer("count", 1, 1000000);
    double jitter = p.real("jitter", 0, 1);
    bool reject = p.choice("overlap", {"max", "reject"}) == "reject";
    if (grid > 0 && p.given("count")) p.fail("count", "expected no count with grid > 0 (the grid sets the number of bumps)");
    if (grid == 0 && p.given("jitter")) p.fail("jitter", "expected grid > 0 (jitter moves grid-placed bumps)");

    struct Bump {
        double x, y, r;
    };
    std::vector<Bump> bumps;
    // Rejection test against earlier bumps through a bucket grid of side >= 2 * max radius.
    int nb = std::min(1024, int(1.0 / (2 * radius)));
    if (nb < 3) nb = 1;  // too few buckets for a 3 x 3 neighbourhood: one bucket holds all
    std::vector<std::vector<int>> buckets(size_t(nb) * nb);
    auto wrapped_delta = [](double d) { return d - std::round(d); };
    auto overlaps = [&](const Bump &c) {
        int bx = int(c.x * nb) % nb, by = int(c.y * nb) % nb;
        for (int dy = -1; dy <= 1; ++dy)
            for (int dx = -1; dx <= 1; ++dx) {
                if (nb == 1 && (dx != 0 || dy != 0)) continue;
                for (int k : buckets[size_t((by + dy + nb) % nb) * nb + (bx + dx + nb) % nb]) {
                    const Bump &o = bumps[k];
                    if (std::hypot(wrapped_delta(c.x - o.x), wrapped_delta(c.y - o.y)) < c.r + o.r) return true;
                }
            }
        return false;
    };
    auto place = [&](double x, double y) {
        Bump b{x - std::floor(x), y - std::floor(y), radius * (1 - rjitter * rng.next_double())};
        if (reject && overlaps(b)) return;
        buckets[size_t(int(b.y * nb) % nb) * nb + int(b.x * nb) % nb].push_back(int(bumps.size()));
        bumps.push_back(b);
    };
    int64_t wanted = grid > 0 ? grid * grid : count;
    if (grid > 0) {
        for (int64_t j = 0; j < grid; ++j)
            for (int64_t i = 0; i < grid; ++i) {
                double jx = jitter * (rng.next_double() - 0.5), jy = jitter * (rng.next_double() - 0.5);
                place((i + 0.5 + jx) / grid, (j + 0.5 + jy) / grid);
            }
    } else {
        for (int64_t tries = 0; int64_t(bumps.size()) < count && tries < (reject ? 100 * count : count); ++tries) {
            double x = rng.next_double(), y = rng.next_double();
            place(x, y);
        }
    }
    if (int64_t(bumps.size()) < wanted)
        g.notes.push_back(fmt::format("placed {} of {} bumps (the others would overlap)", bumps.size(), wanted));

    // Heights: the upper hemisphere sqrt(r^2 - d^2) over each bump's disk, max-combined.
    g.height = HeightMap(w, h);
    for (const Bump &b : bumps) {
        int64_t i0 = int64_t(std::ceil((b.x - b.r) * w)), i1 = int64_t(std::floor((b.x + b.r) * w));
        int64_t j0 = int64_t(std::ceil((b.y - b.r) * h)), j1 = int64_t(std::floor((b.y + b.r) * h));
        for (int64_t j = j0; j <= j1; ++j)
            for (int64_t i = i0; i <= i1; ++i) {
                double d2 = sqr(double(i) / w - b.x) + sqr(double(j) / h - b.y);
                if (d2 >= b.r * b.r) continue;
                float &v = g.height.at(int(((i % w) + w) % w), int(((j % h) + h) % h));
                v = std::max(v, float(std::sqrt(b.r * b.r - d2)));
            }
    }
    return g;
}

// ---------------------------------------------------------------------------------------
// Facets: V-grooves and sawtooth.

/// One period (t in [0,1)) rises with slope ta over [0, a) and falls with slope -tb over
/// [a, 1), a = tb / (ta + tb), starting and ending at height 0; heights in periods.
GeneratedMap facets(Params &p, double angle_a, double angle_b) {
    GeneratedMap g;
    int w, h;
    p.size(w, h);
    p.seed();  // accepted for uniformity; the facets are not random
    int64_t periods = p.integer("periods", 1, 16384);
    bool along_v = p.choice("axis", {"u", "v"}) == "v";
    Spectrum col_a = p.rgb("albedo_a"), col_b = p.rgb("albedo_b");
    const int n = along_v ? h : w;  // vertices along the profile
    double ta = std::tan(angle_a * kPi / 180), tb = std::tan(angle_b * kPi / 180);
    double a = tb / (ta + tb);
    double cells_per_period = double(n) / periods;
    if (a * cells_per_period < 1 || (1 - a) * cells_per_period < 1)
        p.fail("periods", fmt::format("expected every facet to span at least one cell: {} periods over {} cells make "
                                      "facets {:.3g} and {:.3g} cells wide; use fewer periods or a larger size",
                                      periods, n, a * cells_per_period, (1 - a) * cells_per_period));

    // Vertex k sits at t = frac(k * periods / n), exact in integers so the profile repeats.
    auto height_at = [&](int64_t k) {
        double t = double((k * periods) % n) / n;
        return (t < a ? ta * t : tb * (1 - t)) / double(periods);
    };
    std::vector<double> profile(n);
    std::vector<uint8_t> facet(n);  // facet of cell k (between vertices k and k+1): 0 = a, 1 = b
    int straddling = 0;
    for (int k = 0; k < n; ++k) {
        profile[k] = height_at(k);
        double t0 = double((int64_t(k) * periods) % n) / n, t1 = t0 + double(periods) / n;
        // Length of [t0, t1] inside facet a ([0, a) and, past the period end, [1, 1 + a)).
        double in_a = std::max(0.0, std::min(t1, a) - t0) + std::max(0.0, t1 - std::max(t0, 1.0)) -
                      std::max(0.0, t1 - std::max(t0, 1 + a));
        double len = t1 - t0;
        facet[k] = in_a >= 0.5 * len ? 0 : 1;
        if (in_a > 1e-9 * len && in_a < len * (1 - 1e-9)) ++straddling;
    }
    g.height = fill_map(w, h, [&](int i, int j) { return profile[along_v ? j : i]; });
    g.albedo = Image(w, h, 3);
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < w; ++i) g.albedo.set_rgb(i, j, facet[along_v ? j : i] == 0 ? col_a : col_b);
    if (straddling > 0)
        g.notes.push_back(fmt::format("{} of {} cells along {} straddle two facets (their slope is a blend; the albedo "
                                      "takes the facet covering most of the cell); facet edges fall on vertices when "
                                      "the facet widths in cells are integers",
                                      straddling, n, along_v ? "v" : "u"));
    return g;
}

GeneratedMap gen_vgroove(Params &p) {
    double angle = p.real("angle", 0, 89, true);
    return facets(p, angle, angle);
}

GeneratedMap gen_sawtooth(Params &p) {
    double a = p.real("angle_a", 0, 89, true), b = p.real("angle_b", 0, 89, true);
    return facets(p, a, b);
}

// ---------------------------------------------------------------------------------------
// Woven cloth: warp yarns along v (one per column of yarn cells), weft yarns along u.

/// `warp_up(i, j)`: warp yarn i lies over weft yarn j at their crossing. Heights in units
/// of the yarn spacing s = 1 / yarns: along its length a yarn moves between +crimp/2 (over)
/// and -crimp/2 (under) with a half-cosine between crossing centres; across it the
/// cross-section is sin(pi f), f in [0,1], lowered by `gap` at its edges. The visible
/// surface is the higher of the two yarns.
GeneratedMap weave(Params &p, int64_t repeat, const char *repeat_name, const std::function<bool(int64_t, int64_t)> &warp_up) {
    GeneratedMap g;
    int w, h;
    p.size(w, h);
    p.seed();  // accepted for uniformity; the weave is not random
    int64_t yarns = p.integer("yarns", 1, 4096);
    double crimp = p.real("crimp", 0, 10), gap = p.real("gap", 0, 10);
    Spectrum col_warp = p.rgb("albedo_warp"), col_weft = p.rgb("albedo_weft");
    if (yarns % repeat != 0)
        p.fail("yarns", fmt::format("expected a multiple of {} = {} so that the weave tiles, got {}", repeat_name,
                                    repeat, yarns));
    // The pattern once, as +1 (warp over) / -1 (warp under) per crossing.
    std::vector<double> up(size_t(yarns) * yarns);
    for (int64_t j = 0; j < yarns; ++j)
        for (int64_t i = 0; i < yarns; ++i) up[size_t(j * yarns + i)] = warp_up(i % repeat, j % repeat) ? 1.0 : -1.0;
    auto state = [&](int64_t i, int64_t j) { return up[size_t(((j % yarns + yarns) % yarns) * yarns + (i % yarns + yarns) % yarns)]; };
    // Half-cosine blend between the states s0, s1 of two neighbouring crossing centres.
    auto blend = [](double s0, double s1, double t) { return s0 + (s1 - s0) * 0.5 * (1 - std::cos(kPi * t)); };
    /// Warp and weft heights (yarn spacings) at (x, y) in yarn units.
    auto yarn_heights = [&](double x, double y, double &warp, double &weft) {
        int64_t ci = int64_t(std::floor(x)), cj = int64_t(std::floor(y));
        int64_t ki = int64_t(std::floor(x - 0.5)), kj = int64_t(std::floor(y - 0.5));  // crossings before (x, y)
        double warp_level = blend(state(ci, kj), state(ci, kj + 1), y - 0.5 - kj);
        double weft_level = -blend(state(ki, cj), state(ki + 1, cj), x - 0.5 - ki);
        warp = 0.5 * crimp * warp_level + gap * (std::sin(kPi * (x - ci)) - 1);
        weft = 0.5 * crimp * weft_level + gap * (std::sin(kPi * (y - cj)) - 1);
    };
    const double sx = double(yarns) / w, sy = double(yarns) / h;
    g.height = fill_map(w, h, [&](int i, int j) {
        double warp, weft;
        yarn_heights(i * sx, j * sy, warp, weft);
        return std::max(warp, weft) / double(yarns);
    });
    // Albedo texel (i, j) covers cell (i, j): the yarn on top at the cell centre.
    g.albedo = Image(w, h, 3);
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < w; ++i) {
            double warp, weft;
            yarn_heights((i + 0.5) * sx, (j + 0.5) * sy, warp, weft);
            g.albedo.set_rgb(i, j, warp >= weft ? col_warp : col_weft);
        }
    return g;
}

GeneratedMap gen_twill(Params &p) {
    int64_t over = p.integer("over", 1, 16), under = p.integer("under", 1, 16);
    // Warp yarn i is over for `over` consecutive weft yarns, then under for `under`,
    // shifted by one weft per warp: the diagonal twill line.
    return weave(p, over + under, "over + under", [=](int64_t i, int64_t j) { return (i + j) % (over + under) < over; });
}

GeneratedMap gen_satin(Params &p) {
    int64_t n = p.integer("harness", 5, 64), step = p.integer("step", 2, 62);
    auto gcd = [](int64_t a, int64_t b) {
        while (b) a %= b, std::swap(a, b);
        return a;
    };
    if (step >= n - 1 || gcd(n, step) != 1)
        p.fail("step", fmt::format("expected a step in [2, harness - 2] with no common factor with harness = {}, got {}",
                                   n, step));
    // Warp-faced satin: warp yarn i goes under only at weft j = step * i (mod n), so it
    // floats over n - 1 wefts and the interlacings never touch.
    return weave(p, n, "harness", [=](int64_t i, int64_t j) { return (j - step * i % n + n * n) % n != 0; });
}

// ---------------------------------------------------------------------------------------
// Relief from a grey image plus noise.

GeneratedMap gen_relief(Params &p) {
    GeneratedMap g;
    std::string path = p.text("image");
    if (path.empty()) p.fail("image", "expected the path of a grey image (relief needs one)");
    Image img = read_image(path, /*linearize_srgb=*/false);
    int w = img.width, h = img.height;
    if (p.given("size") || p.given("width") || p.given("height")) p.size(w, h);
    PeriodicNoise noise(p.seed());
    double scale = p.real("scale", -1e6, 1e6);
    FbmSpec s = read_fbm(p, "noise_");
    if (s.amplitude > 0) tabulate_fbm(noise, s, w, h);

    // Image pixel (x, y) is taken as the vertex at (x / iw, y / ih) (the height-map
    // convention), so an output of the image's size copies it exactly; other sizes
    // resample bilinearly, wrapping across the edges.
    std::vector<float> grey(size_t(img.width) * img.height);
    for (int y = 0; y < img.height; ++y)
        for (int x = 0; x < img.width; ++x) {
            float v = img.channels >= 3 ? img.rgb(x, y).luminance() : img.at(x, y, 0);
            if (!std::isfinite(v)) throw MesoError(fmt::format("{}: pixel ({}, {}) is not finite", path, x, y));
            grey[size_t(y) * img.width + x] = v;
        }
    auto sample = [&](double u, double v) {
        double x = u * img.width, y = v * img.height, fx = std::floor(x), fy = std::floor(y);
        double tx = x - fx, ty = y - fy;
        auto at = [&](int64_t a, int64_t b) {
            a = ((a % img.width) + img.width) % img.width, b = ((b % img.height) + img.height) % img.height;
            return double(grey[size_t(b) * img.width + size_t(a)]);
        };
        int64_t i = int64_t(fx), j = int64_t(fy);
        double top = at(i, j) + tx * (at(i + 1, j) - at(i, j));
        double bottom = at(i, j + 1) + tx * (at(i + 1, j + 1) - at(i, j + 1));
        return top + ty * (bottom - top);
    };
    g.height = fill_map(w, h, [&](int i, int j) {
        double u = double(i) / w, v = double(j) / h;
        return scale * sample(u, v) + (s.amplitude > 0 ? fbm(noise, s, u, v) : 0.0);
    });
    g.notes.push_back("relief: the map tiles seamlessly only if the image does");
    return g;
}

// ---------------------------------------------------------------------------------------
// The table.

struct Generator {
    GeneratorInfo info;
    std::function<GeneratedMap(Params &)> run;
};

std::vector<GeneratorParam> with_common(std::vector<GeneratorParam> specific) {
    std::vector<GeneratorParam> all = {
        {"size", "256", "vertices per side (2..16384); the map is size x size unless width/height say otherwise"},
        {"width", "", "vertices along u (2..16384; default: size)"},
        {"height", "", "vertices along v (2..16384; default: size)"},
        {"seed", "1", "random seed (0..2^53); the same seed gives the same map"},
    };
    all.insert(all.end(), specific.begin(), specific.end());
    return all;
}

std::vector<GeneratorParam> fbm_params(const std::string &prefix, const std::string &amplitude) {
    return {
        {prefix + "octaves", "6", "number of noise octaves (1..24)"},
        {prefix + "lacunarity", "2", "integer frequency ratio between octaves (1..16; an integer keeps the map periodic)"},
        {prefix + "gain", "0.5", "amplitude ratio between octaves (0..1)"},
        {prefix + "frequency", "4", "lattice periods per tile of the first octave (integer >= 1)"},
        {prefix + "amplitude", amplitude, "height amplitude of the first octave, tile units (noise values lie in about [-1, 1])"},
    };
}

std::vector<GeneratorParam> facet_params(std::vector<GeneratorParam> angles) {
    angles.insert(angles.begin(), {"periods", "8", "facet periods per tile along the axis (integer >= 1)"});
    angles.push_back({"axis", "u", "'u': the height varies along u (ridges parallel to v); 'v': rotated by 90 degrees"});
    angles.push_back({"albedo_a", "0.8,0.8,0.8", "RGB reflectance 'r,g,b' in [0,1] of the rising facet a (dh/du > 0)"});
    angles.push_back({"albedo_b", "0.2,0.2,0.2", "RGB reflectance 'r,g,b' in [0,1] of the falling facet b (dh/du < 0)"});
    return angles;
}

std::vector<GeneratorParam> weave_params(std::vector<GeneratorParam> pattern, const std::string &yarns) {
    pattern.insert(pattern.begin(), {"yarns", yarns, "yarns per tile in each direction (a multiple of the weave repeat)"});
    pattern.push_back({"crimp", "0.3", "height between a yarn over and under a crossing, in yarn spacings (1/yarns)"});
    pattern.push_back({"gap", "0.2", "how much lower a yarn's edge lies than its centre, in yarn spacings"});
    pattern.push_back({"albedo_warp", "0.8,0.8,0.8", "RGB reflectance 'r,g,b' of the warp yarns (along v)"});
    pattern.push_back({"albedo_weft", "0.3,0.3,0.3", "RGB reflectance 'r,g,b' of the weft yarns (along u)"});
    return pattern;
}

const std::vector<Generator> &generators() {
    static const std::vector<Generator> table = {
        {{"fbm", "fractional Brownian motion: a sum of octaves of periodic Perlin gradient noise",
          with_common(fbm_params("", "0.02"))},
         gen_fbm},
        {{"gaussian",
          "Gaussian random surface (spectral synthesis, Gaussian autocorrelation) whose cell-slope covariance "
          "equals (sxx, syy, sxy) exactly",
          with_common({
              {"correlation", "0.05", "correlation length in tile units along the steepest principal direction "
                                      "(>= one cell); heights have variance correlation^2 * max eigenvalue / 2"},
              {"sxx", "0.1", "variance of the slope dh/du (tile units)"},
              {"syy", "0.1", "variance of the slope dh/dv (tile units)"},
              {"sxy", "0", "covariance of dh/du and dh/dv; |sxy| <= sqrt(sxx * syy)"},
              {"mx", "0", "mean slope dh/du, added as a ramp (non-zero: the map is no longer periodic)"},
              {"my", "0", "mean slope dh/dv, added as a ramp (non-zero: the map is no longer periodic)"},
          })},
         gen_gaussian},
        {{"bumps", "hemispherical bumps of radius r (height sqrt(r^2 - d^2)) on a flat base, max-combined",
          with_common({
              {"radius", "0.04", "bump radius in tile units (0..0.5]"},
              {"radius_jitter", "0", "radii are drawn uniformly in [radius (1 - radius_jitter), radius] (0..1)"},
              {"count", "64", "number of bumps at uniform random positions (when grid = 0)"},
              {"grid", "0", "if > 0: one bump per cell of a grid x grid lattice instead of random positions"},
              {"jitter", "0", "grid only: random offset of each centre, as a fraction of the lattice spacing (0..1)"},
              {"overlap", "max", "'max': overlapping bumps combine by maximum; 'reject': a bump that would overlap "
                                 "an earlier one is left out"},
          })},
         gen_bumps},
        {{"vgroove", "symmetric V-grooves: facets of slope +-tan(angle) (tile units), a groove bottom at u = 0",
          with_common(facet_params({{"angle", "45", "facet inclination in degrees (0..89): slope = tan(angle)"}}))},
         gen_vgroove},
        {{"sawtooth", "asymmetric sawtooth: a rising facet a of slope tan(angle_a) and a falling facet b of slope "
                      "-tan(angle_b), a bottom at u = 0",
          with_common(facet_params({{"angle_a", "30", "inclination of the rising facet a in degrees (0..89)"},
                                    {"angle_b", "60", "inclination of the falling facet b in degrees (0..89)"}}))},
         gen_sawtooth},
        {{"twill", "woven twill: each warp yarn passes over `over` weft yarns and under `under`, shifted by one "
                   "per yarn (a diagonal)",
          with_common(weave_params({{"over", "2", "weft yarns a warp yarn passes over (1..16)"},
                                    {"under", "1", "weft yarns a warp yarn passes under (1..16)"}},
                                   "24"))},
         gen_twill},
        {{"satin", "warp-faced satin: each warp yarn floats over harness - 1 weft yarns and goes under one, the "
                   "interlacings moved by `step` per yarn",
          with_common(weave_params({{"harness", "5", "weave repeat in yarns (5..64)"},
                                    {"step", "2", "interlacing offset between neighbouring warp yarns (2..harness-2, "
                                                  "no common factor with harness)"}},
                                   "20"))},
         gen_satin},
        {{"relief", "relief from a grey image (luminance of RGB, else the first channel) times scale, plus fBm "
                    "noise; size defaults to the image's",
          with_common([] {
              std::vector<GeneratorParam> v = {
                  {"image", "", "path of the image (required; read without sRGB decoding: 8/16-bit values in [0,1])"},
                  {"scale", "0.05", "height in tile units of an image value of 1"},
              };
              auto n = fbm_params("noise_", "0");
              v.insert(v.end(), n.begin(), n.end());
              return v;
          }())},
         gen_relief},
    };
    return table;
}

}  // namespace

const std::vector<GeneratorInfo> &height_map_generators() {
    static const std::vector<GeneratorInfo> infos = [] {
        std::vector<GeneratorInfo> v;
        for (auto &g : generators()) v.push_back(g.info);
        return v;
    }();
    return infos;
}

GeneratedMap generate_height_map(const std::string &kind, const std::map<std::string, std::string> &params,
                                 const std::string &where) {
    for (auto &g : generators()) {
        if (g.info.name != kind) continue;
        Params p(g.info, params, where);
        GeneratedMap m = g.run(p);
        m.params = p.used();  // the record: what reproduces the map
        m.params.erase("size");
        m.params["width"] = std::to_string(m.height.width);
        m.params["height"] = std::to_string(m.height.height);
        for (float v : m.height.h)
            if (!std::isfinite(v))
                throw MesoError(located_message(where, "", fmt::format("generator '{}' produced a non-finite height "
                                                                       "(parameters too extreme)",
                                                                       kind)));
        return m;
    }
    std::string known;
    for (auto &g : generators()) known += (known.empty() ? "" : ", ") + g.info.name;
    throw MesoError(located_message(where, "", fmt::format("unknown height-map generator '{}' (expected one of: {})",
                                                           kind, known)));
}

void cell_slope(const HeightMap &map, int i, int j, double &su, double &sv) {
    double h00 = map.wrapped(i, j), h10 = map.wrapped(i + 1, j);
    double h01 = map.wrapped(i, j + 1), h11 = map.wrapped(i + 1, j + 1);
    su = map.width * 0.5 * (h10 + h11 - h00 - h01);
    sv = map.height * 0.5 * (h01 + h11 - h00 - h10);
}

HeightMapStats height_map_stats(const HeightMap &map, bool periodic) {
    HeightMapStats s;
    if (map.empty()) return s;
    double sum = 0;
    s.min = s.max = map.h[0];
    for (float v : map.h) {
        s.min = std::min(s.min, double(v));
        s.max = std::max(s.max, double(v));
        sum += v;
    }
    s.mean = sum / double(map.h.size());
    int ni = periodic ? map.width : map.width - 1, nj = periodic ? map.height : map.height - 1;
    double n = double(ni) * nj, su_sum = 0, sv_sum = 0, uu = 0, vv = 0, uv = 0;
    for (int j = 0; j < nj; ++j)
        for (int i = 0; i < ni; ++i) {
            double su, sv;
            cell_slope(map, i, j, su, sv);
            su_sum += su, sv_sum += sv;
            uu += su * su, vv += sv * sv, uv += su * sv;
        }
    if (n <= 0) return s;
    s.mean_su = su_sum / n, s.mean_sv = sv_sum / n;
    s.sxx = uu / n - s.mean_su * s.mean_su;
    s.syy = vv / n - s.mean_sv * s.mean_sv;
    s.sxy = uv / n - s.mean_su * s.mean_sv;
    s.rms_slope = std::sqrt((uu + vv) / n);
    return s;
}

}  // namespace meso
