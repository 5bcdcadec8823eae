// Shared helpers of the heightfield intersector tests (test_heightfield.cpp,
// test_heightfield_battery.cpp): test fields, the independent long-double reference
// tracer and tolerances. Header-only, internal linkage per test file.
#pragma once
#include <gtest/gtest.h>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <optional>
#include <string>
#include <vector>
#include "core/error.h"
#include "geometry/heightfield.h"
#include "sampling/rng.h"

// Not every test file uses every helper.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wunused-function"
#pragma GCC diagnostic ignored "-Wunused-variable"

using namespace meso;

namespace {

using LD = long double;
constexpr double kPi = 3.14159265358979323846;

// ---------------------------------------------------------------------------------------
// Test fields

struct Field {
    std::string name;
    HeightMap map;
    float scale = 1.f, offset = 0.f;
};

HeightMap sinusoid_map(int w, int h, int seed) {
    // A few periodic sinusoids (integer frequencies so the map tiles) plus a little noise.
    HeightMap m(w, h);
    PCG32 rng(seed);
    float a[4], ph[4];
    int fx[4], fy[4];
    for (int k = 0; k < 4; ++k) {
        a[k] = 0.5f / float(k + 1);
        ph[k] = float(2 * kPi) * rng.next_float();
        fx[k] = 1 + int(rng.next_bounded(uint32_t(std::max(1, w / 3))));
        fy[k] = int(rng.next_bounded(uint32_t(std::max(1, h / 3)) + 1));
    }
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < w; ++i) {
            double v = 0;
            for (int k = 0; k < 4; ++k)
                v += a[k] * std::sin(2 * kPi * (double(fx[k]) * i / w + double(fy[k]) * j / h) + ph[k]);
            m.at(i, j) = float(v) + 0.05f * (rng.next_float() - 0.5f);
        }
    return m;
}

HeightMap noise_map(int w, int h, int seed) {
    HeightMap m(w, h);
    PCG32 rng(seed);
    for (float &v : m.h) v = rng.next_float();
    return m;
}

/// Periodic piecewise-linear profile along x (constant in y): vertex heights prof[i].
HeightMap profile_x_map(const std::vector<float> &prof, int h) {
    HeightMap m(int(prof.size()), h);
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < m.width; ++i) m.at(i, j) = prof[size_t(i)];
    return m;
}
HeightMap profile_y_map(const std::vector<float> &prof, int w) {
    HeightMap m(w, int(prof.size()));
    for (int j = 0; j < m.height; ++j)
        for (int i = 0; i < w; ++i) m.at(i, j) = prof[size_t(j)];
    return m;
}
/// A single V-groove of depth 1 and half-width 2 cells in an otherwise flat field.
std::vector<float> groove_profile(int w) {
    std::vector<float> p(size_t(w), 0.f);
    int c = w / 2;
    p[size_t(c - 1)] = -0.5f;
    p[size_t(c)] = -1.f;
    p[size_t(c + 1)] = -0.5f;
    return p;
}

std::vector<Field> battery_fields() {
    std::vector<Field> f;
    f.push_back({"flat8_scale0", noise_map(8, 8, 1), 0.f, 0.3f});
    f.push_back({"one_by_one", HeightMap(1, 1, 0.7f), 2.f, -1.f});
    f.push_back({"two_by_one", profile_x_map({0.f, 1.f}, 1), 1.f, 0.f});
    f.push_back({"one_by_13", profile_y_map({0.f, .2f, .9f, .4f, -.3f, 0.f, .1f, .8f, .8f, .2f, -.5f, -.2f, .1f}, 1),
                 1.f, 0.f});
    f.push_back({"groove16x5", profile_x_map(groove_profile(16), 5), 1.f, 0.f});
    f.push_back({"sin37x19", sinusoid_map(37, 19, 2), 1.f, 0.f});
    f.push_back({"sin37x19_negative", sinusoid_map(37, 19, 3), -3.f, -10.f});
    f.push_back({"sin64x64", sinusoid_map(64, 64, 4), 0.5f, 0.25f});
    f.push_back({"noise16x16_steep", noise_map(16, 16, 5), 4.f, 0.f});
    f.push_back({"noise5x3", noise_map(5, 3, 6), 1.f, -0.5f});
    return f;
}

// ---------------------------------------------------------------------------------------
// Independent evaluation of the surface and a reference tracer (long double).

/// The field under test plus its vertex heights cached for the checks (read once through
/// vertex(), then wrapped here without the per-call modulo).
struct Surface : Heightfield {
    std::vector<LD> v;
    Surface(const HeightMap &m, float scale, float offset) : Heightfield(m, scale, offset) {
        v.resize(size_t(width()) * height());
        for (int j = 0; j < height(); ++j)
            for (int i = 0; i < width(); ++i) v[size_t(j) * width() + i] = vertex(i, j);
    }
    LD at(int64_t i, int64_t j) const {
        const int64_t w = width(), h = height();
        i %= w, j %= h;
        return v[size_t((j < 0 ? j + h : j) * w + (i < 0 ? i + w : i))];
    }
};

struct Ray {
    Vec3 o, d;
    int64_t ox = 0, oy = 0;
    LD X(LD t) const { return LD(o.x) + LD(ox) + t * LD(d.x); }
    LD Y(LD t) const { return LD(o.y) + LD(oy) + t * LD(d.y); }
    LD Z(LD t) const { return LD(o.z) + t * LD(d.z); }
};

/// Bernstein form of the bilinear patch of cell (i, j) at local (a, b).
LD patch_eval(const Surface &hf, int64_t i, int64_t j, LD a, LD b, LD *dhdx = nullptr, LD *dhdy = nullptr) {
    const int64_t w = hf.width(), h = hf.height();
    int64_t i0 = i % w, j0 = j % h;
    if (i0 < 0) i0 += w;
    if (j0 < 0) j0 += h;
    const int64_t i1 = i0 + 1 == w ? 0 : i0 + 1, j1 = j0 + 1 == h ? 0 : j0 + 1;
    const LD h00 = hf.v[size_t(j0 * w + i0)], h10 = hf.v[size_t(j0 * w + i1)], h01 = hf.v[size_t(j1 * w + i0)],
             h11 = hf.v[size_t(j1 * w + i1)];
    if (dhdx) *dhdx = (h10 - h00) * (1 - b) + (h11 - h01) * b;
    if (dhdy) *dhdy = (h01 - h00) * (1 - a) + (h11 - h10) * a;
    return (1 - a) * (1 - b) * h00 + a * (1 - b) * h10 + (1 - a) * b * h01 + a * b * h11;
}
LD exact_height(const Surface &hf, LD x, LD y, LD *dhdx = nullptr, LD *dhdy = nullptr) {
    const LD fi = std::floor(x), fj = std::floor(y);
    return patch_eval(hf, int64_t(fi), int64_t(fj), x - fi, y - fj, dhdx, dhdy);
}
/// Signed height of the ray above the surface at t.
LD gap(const Surface &hf, const Ray &r, LD t) { return r.Z(t) - exact_height(hf, r.X(t), r.Y(t)); }

/// First t in [t0, t1] where the ray meets the surface, or none. Cells are walked by an
/// integer DDA; in each cell the gap is a quadratic in t, split at its extremum into
/// monotone pieces, and a sign change (or a zero) on a piece is bisected.
std::optional<LD> reference_hit(const Surface &hf, const Ray &r, LD t0, LD t1) {
    const LD dx = r.d.x, dy = r.d.y, dz = r.d.z;
    const LD lo = hf.min_height(), hi = hf.max_height();
    if (dz != 0) {
        LD ta = (lo - LD(r.o.z)) / dz, tb = (hi - LD(r.o.z)) / dz;
        if (ta > tb) std::swap(ta, tb);
        t0 = std::max(t0, ta - 1e-12L * (1 + std::abs(ta)));
        t1 = std::min(t1, tb + 1e-12L * (1 + std::abs(tb)));
    } else if (LD(r.o.z) < lo || LD(r.o.z) > hi) {
        return std::nullopt;
    }
    if (!(t1 >= t0)) return std::nullopt;
    if (!std::isfinite(double(t1))) throw std::runtime_error("reference_hit needs a finite range");
    const LD X0 = r.X(0), Y0 = r.Y(0);
    const LD xs = r.X(t0), ys = r.Y(t0);
    int64_t i = int64_t(std::floor(xs)), j = int64_t(std::floor(ys));
    if (LD(i) == xs && dx < 0) --i;
    if (LD(j) == ys && dy < 0) --j;
    const int sx = dx > 0 ? 1 : -1, sy = dy > 0 ? 1 : -1;
    auto bound_t = [](int64_t c, int s, LD p0, LD d) {
        if (d == 0) return LD(INFINITY);
        return (LD(c + (s > 0 ? 1 : 0)) - p0) / d;
    };
    LD tmx = bound_t(i, sx, X0, dx), tmy = bound_t(j, sy, Y0, dy);
    LD t = t0;
    for (;;) {
        const LD tn = std::min(std::min(tmx, tmy), t1);
        // The gap on this cell's own patch (not re-floored, so the seams are shared).
        auto F = [&](LD s) { return r.Z(s) - patch_eval(hf, i, j, r.X(s) - LD(i), r.Y(s) - LD(j)); };
        LD pieces[3] = {t, tn, tn};
        int np = 1;
        {
            // F(s) is quadratic: F'' = -2 g dx dy; split at F' = 0.
            const LD h00 = hf.at(i, j), h10 = hf.at(i + 1, j), h01 = hf.at(i, j + 1), h11 = hf.at(i + 1, j + 1);
            const LD g = h00 + h11 - h10 - h01;
            const LD F2 = -2 * g * dx * dy;
            if (F2 != 0) {
                const LD a = r.X(t) - LD(i), b = r.Y(t) - LD(j);
                const LD Fp = dz - ((h10 - h00) * (1 - b) + (h11 - h01) * b) * dx -
                              ((h01 - h00) * (1 - a) + (h11 - h10) * a) * dy;
                const LD ts = t - Fp / F2;
                if (ts > t && ts < tn) pieces[1] = ts, np = 2;
            }
        }
        LD pa = t;
        for (int k = 0; k < np; ++k) {
            const LD pb = pieces[k + 1];
            LD fa = F(pa), fb = F(pb);
            if (fa == 0) return pa;
            if ((fa < 0) != (fb < 0) || fb == 0) {
                LD a = pa, b = pb;
                for (int it = 0; it < 90 && b > a; ++it) {
                    const LD m = 0.5L * (a + b);
                    if (m <= a || m >= b) break;
                    const LD fm = F(m);
                    if (fm == 0) return m;
                    if ((fm < 0) == (fa < 0))
                        a = m, fa = fm;
                    else
                        b = m;
                }
                return b;
            }
            pa = pb;
        }
        if (tn >= t1) return std::nullopt;
        t = tn;
        if (tmx < tmy) {
            i += sx;
            tmx = bound_t(i, sx, X0, dx);
        } else if (tmy < tmx) {
            j += sy;
            tmy = bound_t(j, sy, Y0, dy);
        } else {
            i += sx, j += sy;
            tmx = bound_t(i, sx, X0, dx);
            tmy = bound_t(j, sy, Y0, dy);
        }
    }
}

/// How far the ray gets to the other side of the surface on [ta, tb] (dense sampling;
/// >= 0): side = +1 for a ray that started above (then: depth below), -1 from below.
LD penetration(const Surface &hf, const Ray &r, LD ta, LD tb, int side, int n = 512) {
    LD deepest = 0;
    for (int k = 0; k <= n; ++k) deepest = std::max(deepest, -side * gap(hf, r, ta + (tb - ta) * LD(k) / n));
    return deepest;
}

/// Tolerances from float precision, in units u = 2^-24 (half an ulp of 1): the tracer
/// returns t, x, y and h as floats, so t is known to u |t|, x to u |x|, and the ray's
/// height at t to u |t| (|dz| + slope |dxy|). kUlps of slack on top of that.
constexpr double kU = 0x1p-24, kUlps = 8;
double gap_tolerance(const Ray &r, double t, double h, double slope) {
    const double dxy = std::hypot(double(r.d.x), double(r.d.y));
    return kUlps * kU * (std::abs(t) * (std::abs(r.d.z) + slope * dxy) + std::abs(r.o.z) + std::abs(h) + 1);
}

double max_slope_of(const Surface &hf) {
    double s = 0;
    for (int j = 0; j < hf.height(); ++j)
        for (int i = 0; i < hf.width(); ++i) {
            s = std::max(s, double(std::abs(hf.vertex(i + 1, j) - hf.vertex(i, j))));
            s = std::max(s, double(std::abs(hf.vertex(i, j + 1) - hf.vertex(i, j))));
        }
    return s;
}

bool finite_hit(const HeightfieldHit &h) {
    return std::isfinite(h.t) && std::isfinite(h.x) && std::isfinite(h.y) && std::isfinite(h.h) &&
           std::isfinite(h.dhdx) && std::isfinite(h.dhdy);
}

/// Checks a reported hit: finite, within (tmin, tmax], the ray at t on the surface (the
/// exact gap, from the float ray and the exact bilinear surface), and x, y, h equal to
/// the ray's point at t and on the surface.
::testing::AssertionResult hit_on_surface(const Surface &hf, const Ray &r, const HeightfieldHit &h, double slope,
                                          float tmin = 0.f, float tmax = std::numeric_limits<float>::infinity(),
                                          double *worst = nullptr) {
    if (!finite_hit(h)) return ::testing::AssertionFailure() << "non-finite hit field, t=" << h.t;
    if (!(h.t > tmin) || h.t > tmax)
        return ::testing::AssertionFailure() << "t=" << h.t << " outside (" << tmin << ", " << tmax << "]";
    const double tz = gap_tolerance(r, h.t, h.h, slope);
    const double g = double(gap(hf, r, h.t));
    const double tx = kUlps * kU * (std::abs(h.x) + std::abs(h.t * r.d.x) + 1);
    const double ty = kUlps * kU * (std::abs(h.y) + std::abs(h.t * r.d.y) + 1);
    const double ex = double(r.X(h.t) - LD(r.ox)) - h.x, ey = double(r.Y(h.t) - LD(r.oy)) - h.y,
                 ez = double(r.Z(h.t)) - h.h;
    const double th = kUlps * kU * (std::abs(h.h) + slope * (std::abs(h.x) + std::abs(h.y)) + 1);
    const double eh = double(exact_height(hf, LD(h.x) + LD(r.ox), LD(h.y) + LD(r.oy))) - h.h;
    if (worst)
        *worst = std::max({*worst, std::abs(g) / tz, std::abs(ex) / tx, std::abs(ey) / ty, std::abs(ez) / (tz + th),
                           std::abs(eh) / th});
    if (std::abs(g) > tz)
        return ::testing::AssertionFailure()
               << "the ray at t=" << h.t << " is " << g << " above the surface (tolerance " << tz << ")";
    if (std::abs(ex) > tx || std::abs(ey) > ty || std::abs(ez) > tz + th)
        return ::testing::AssertionFailure() << "hit point off the ray by (" << ex << ", " << ey << ", " << ez
                                             << "), tolerance " << tx << "/" << ty << "/" << tz + th << ", t=" << h.t;
    if (std::abs(eh) > th)
        return ::testing::AssertionFailure() << "hit height off the surface by " << eh << " (tolerance " << th << ")";
    return ::testing::AssertionSuccess();
}

/// Compares a tracer answer with a reference first crossing on (t0, t1] (std::nullopt: none).
/// They may differ only by a graze: the tracer reporting a touch (the ray on the surface to
/// within tolerance) that the reference did not count, or the reference counting a dip to
/// the other side no deeper than the tolerance that the tracer did not.
bool same_first_hit(const Surface &hf, const Ray &r, double t0, double t1, bool hit, float th, std::optional<LD> ref,
                    double slope, long &grazes, std::string &why) {
    if (!hit && !ref) return true;
    if (hit && ref && std::abs(th - double(*ref)) <= 1e-5 * (1 + double(*ref))) return true;
    const double tol = gap_tolerance(r, std::max(double(th), ref ? double(*ref) : t1), hf.max_height(), slope);
    const int side = gap(hf, r, t0) >= 0 ? 1 : -1;
    LD miss = 0;
    if (hit && (!ref || th < *ref)) {
        miss = std::abs(gap(hf, r, th));  // a touch: the ray must be on the surface there
    } else {
        miss = penetration(hf, r, *ref, hit ? LD(th) : LD(t1), side);
    }
    if (double(miss) <= tol) {
        ++grazes;
        return true;
    }
    char buf[240];
    std::snprintf(buf, sizeof buf, "tracer %s t=%.9g, reference %s t=%.12Lg; off by %.3Lg (tolerance %.3g)",
                  hit ? "hit" : "missed", hit ? th : 0.f, ref ? "hit" : "missed", ref ? *ref : 0.0L, miss, tol);
    why = buf;
    return false;
}

std::string describe(const Ray &r) {
    char buf[400];
    std::snprintf(buf, sizeof buf, "o=(%.9g, %.9g, %.9g) d=(%.9g, %.9g, %.9g) offset=(%lld, %lld)", r.o.x, r.o.y, r.o.z,
                  r.d.x, r.d.y, r.d.z, (long long)r.ox, (long long)r.oy);
    return buf;
}

/// Downward unit direction at polar angle theta (from +z) and azimuth phi; azimuths on
/// multiples of 90 degrees give exactly zero x or y components.
Vec3 down_dir(double theta, double phi, bool axis_exact) {
    const double st = std::sin(theta), ct = std::cos(theta);
    double cx = std::cos(phi), cy = std::sin(phi);
    if (axis_exact) {
        const int q = int(std::lround(phi / (kPi / 2))) & 3;
        cx = q == 0 ? 1 : q == 2 ? -1 : 0;
        cy = q == 1 ? 1 : q == 3 ? -1 : 0;
    }
    return Vec3(float(st * cx), float(st * cy), float(-ct));
}

const double kGrazing = 89.9 * kPi / 180;

}  // namespace

#pragma GCC diagnostic pop
