// The heightfield intersector (geometry/heightfield.h) against answers computed
// independently in the test:
//   * analytic shapes: a flat field, a tilted plane (inside the region where the ramp is
//     exact), periodic piecewise-linear profiles (a V-groove, a 2x1 triangle wave, a
//     1xN profile in y) solved piece by piece in closed form;
//   * sampled shapes (sinusoids, noise): a reference tracer written here that walks the
//     cells with a 2D DDA in long double, evaluates each bilinear patch in Bernstein form
//     and brackets every root by bisection on the monotone pieces of the per-cell quadratic
//     (no closed-form root, so it shares no round-off with the tracer); the reference is
//     itself checked against dense marching with eval() plus bisection.
// The "no false misses" battery aims 10^6 rays at points ON the surface from above the
// height slab at every angle up to 89.9 degrees from the normal: the surface is there, so
// a hit no later than the target is owed. Every reported hit must lie on the surface and
// on the ray. All random numbers come from fixed PCG32 seeds.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <optional>
#include <vector>

#include "core/error.h"
#include "geometry/heightfield.h"
#include "sampling/rng.h"

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

// ---------------------------------------------------------------------------------------
// intersect_bilinear_patch on hand-made cases

TEST(HeightfieldPatch, FlatPatchVerticalAndOblique) {
    float t;
    ASSERT_TRUE(intersect_bilinear_patch(Vec3(0.3f, 0.4f, 2.f), Vec3(0, 0, -1), .5f, .5f, .5f, .5f, 0.f, 10.f, t));
    EXPECT_FLOAT_EQ(t, 1.5f);
    // Oblique, unnormalised: z = 2 - 0.5 t meets 0.5 at t = 3.
    ASSERT_TRUE(
        intersect_bilinear_patch(Vec3(0.f, 0.f, 2.f), Vec3(0.1f, 0.2f, -0.5f), .5f, .5f, .5f, .5f, 0.f, 10.f, t));
    EXPECT_NEAR(t, 3.f, 1e-6f);
    // Interval ends are inclusive; outside them there is no hit.
    ASSERT_TRUE(intersect_bilinear_patch(Vec3(0.3f, 0.4f, 2.f), Vec3(0, 0, -1), .5f, .5f, .5f, .5f, 1.5f, 10.f, t));
    EXPECT_FLOAT_EQ(t, 1.5f);
    ASSERT_TRUE(intersect_bilinear_patch(Vec3(0.3f, 0.4f, 2.f), Vec3(0, 0, -1), .5f, .5f, .5f, .5f, 0.f, 1.5f, t));
    EXPECT_FLOAT_EQ(t, 1.5f);
    EXPECT_FALSE(intersect_bilinear_patch(Vec3(0.3f, 0.4f, 2.f), Vec3(0, 0, -1), .5f, .5f, .5f, .5f, 0.f, 1.4f, t));
    EXPECT_FALSE(intersect_bilinear_patch(Vec3(0.3f, 0.4f, 2.f), Vec3(0, 0, -1), .5f, .5f, .5f, .5f, 1.6f, 9.f, t));
    EXPECT_FALSE(intersect_bilinear_patch(Vec3(0.3f, 0.4f, 2.f), Vec3(0, 0, -1), .5f, .5f, .5f, .5f, 2.f, 1.f, t));
    // From below (two-sided).
    ASSERT_TRUE(intersect_bilinear_patch(Vec3(0.3f, 0.4f, -1.f), Vec3(0, 0, 2), .5f, .5f, .5f, .5f, 0.f, 10.f, t));
    EXPECT_FLOAT_EQ(t, 0.75f);
    // Parallel above: no hit; parallel in the plane: whatever is reported is finite.
    EXPECT_FALSE(intersect_bilinear_patch(Vec3(0.f, 0.5f, 0.6f), Vec3(1, 0, 0), .5f, .5f, .5f, .5f, 0.f, 1.f, t));
    if (intersect_bilinear_patch(Vec3(0.f, 0.5f, 0.5f), Vec3(1, 0, 0), .5f, .5f, .5f, .5f, 0.f, 1.f, t)) {
        EXPECT_TRUE(std::isfinite(t) && t >= 0.f && t <= 1.f);
    }
}

TEST(HeightfieldPatch, TiltedPlanePatch) {
    // h = 0.2 + 0.3 a - 0.1 b is bilinear with g = 0.
    const float h00 = .2f, h10 = .5f, h01 = .1f, h11 = .4f;
    PCG32 rng(11);
    for (int k = 0; k < 1000; ++k) {
        const double a = rng.next_double(), b = rng.next_double();
        const double ht = 0.2 + 0.3 * a - 0.1 * b;
        const Vec3 d = normalize(Vec3(rng.next_float() - .5f, rng.next_float() - .5f, -0.2f - rng.next_float()));
        const double s = 1.0 + rng.next_double();
        const Vec3 o(float(a - s * d.x), float(b - s * d.y), float(ht - s * d.z));
        // Analytic root of the float ray against the plane.
        const double n_dot_d = d.z - 0.3 * d.x + 0.1 * d.y;
        const double t_exact = -(o.z - (0.2 + 0.3 * double(o.x) - 0.1 * double(o.y))) / n_dot_d;
        float t;
        ASSERT_TRUE(intersect_bilinear_patch(o, d, h00, h10, h01, h11, 0.f, 10.f, t));
        EXPECT_NEAR(t, t_exact, 2e-6 * t_exact) << k;
    }
}

TEST(HeightfieldPatch, SaddleTwoRootsAndTangent) {
    // h00 = h11 = 1, h10 = h01 = 0: h(a, b) = 1 - a - b + 2ab. Along the diagonal a = b = s
    // h = 1 - 2s + 2s^2, minimum 1/2 at s = 1/2.
    const float h00 = 1, h10 = 0, h01 = 0, h11 = 1;
    float t;
    // z = 0.6: s^2 - s + 0.2 = 0, s = (1 -+ sqrt(0.2)) / 2.
    const double r0 = (1 - std::sqrt(0.2)) / 2, r1 = (1 + std::sqrt(0.2)) / 2;
    ASSERT_TRUE(intersect_bilinear_patch(Vec3(0, 0, .6f), Vec3(1, 1, 0), h00, h10, h01, h11, 0.f, 1.f, t));
    EXPECT_NEAR(t, r0, 1e-6);
    ASSERT_TRUE(intersect_bilinear_patch(Vec3(0, 0, .6f), Vec3(1, 1, 0), h00, h10, h01, h11, 0.3f, 1.f, t));
    EXPECT_NEAR(t, r1, 1e-6);
    EXPECT_FALSE(intersect_bilinear_patch(Vec3(0, 0, .6f), Vec3(1, 1, 0), h00, h10, h01, h11, 0.3f, 0.7f, t));
    // Reversed ray: same points from the other side.
    ASSERT_TRUE(intersect_bilinear_patch(Vec3(1, 1, .6f), Vec3(-1, -1, 0), h00, h10, h01, h11, 0.f, 1.f, t));
    EXPECT_NEAR(t, 1 - r1, 1e-6);
    // z = 0.5: tangent (double root) at s = 1/2.
    ASSERT_TRUE(intersect_bilinear_patch(Vec3(0, 0, .5f), Vec3(1, 1, 0), h00, h10, h01, h11, 0.f, 1.f, t));
    EXPECT_NEAR(t, 0.5, 1e-6);
    // z = 0.4: the ray stays below the saddle along the diagonal (no root).
    EXPECT_FALSE(intersect_bilinear_patch(Vec3(0, 0, .4f), Vec3(1, 1, 0), h00, h10, h01, h11, 0.f, 1.f, t));
    // Along the other diagonal a = s, b = 1 - s the saddle is a ridge 2s - 2s^2 (max 1/2).
    ASSERT_TRUE(intersect_bilinear_patch(Vec3(0, 1, .32f), Vec3(1, -1, 0), h00, h10, h01, h11, 0.f, 1.f, t));
    EXPECT_NEAR(t, 0.2, 1e-6);  // 2s - 2s^2 = 0.32 -> s = 0.2, 0.8
    ASSERT_TRUE(intersect_bilinear_patch(Vec3(0, 1, .32f), Vec3(1, -1, 0), h00, h10, h01, h11, 0.5f, 1.f, t));
    EXPECT_NEAR(t, 0.8, 1e-6);
    ASSERT_TRUE(intersect_bilinear_patch(Vec3(0, 1, .5f), Vec3(1, -1, 0), h00, h10, h01, h11, 0.f, 1.f, t));
    EXPECT_NEAR(t, 0.5, 1e-6);  // tangent to the ridge
    EXPECT_FALSE(intersect_bilinear_patch(Vec3(0, 1, .55f), Vec3(1, -1, 0), h00, h10, h01, h11, 0.f, 1.f, t));
    // Oblique descending ray through the saddle, checked against the closed form.
    PCG32 rng(3);
    for (int k = 0; k < 1000; ++k) {
        const Vec3 o(rng.next_float(), rng.next_float(), 1.5f);
        const Vec3 d(rng.next_float() - .5f, rng.next_float() - .5f, -1.f);
        float th;
        if (!intersect_bilinear_patch(o, d, h00, h10, h01, h11, 0.f, 4.f, th)) continue;
        const double a = o.x + double(th) * d.x, b = o.y + double(th) * d.y;
        EXPECT_NEAR(o.z + double(th) * d.z, 1 - a - b + 2 * a * b, 1e-5) << k;
    }
}

TEST(HeightfieldPatch, VerticalAndAxisRaysNoNaN) {
    float t;
    // Vertical ray through the saddle centre: h(1/2, 1/2) = 1/2.
    ASSERT_TRUE(intersect_bilinear_patch(Vec3(.5f, .5f, 3.f), Vec3(0, 0, -1), 1, 0, 0, 1, 0.f, 10.f, t));
    EXPECT_NEAR(t, 2.5, 1e-6);
    // Rays along x and along y (g dx dy = 0: the gap is linear in t).
    ASSERT_TRUE(intersect_bilinear_patch(Vec3(0, .25f, .5f), Vec3(1, 0, 0), 1, 0, 0, 1, 0.f, 1.f, t));
    // h(a, 1/4) = 1 - a - 1/4 + a/2 = 3/4 - a/2 = 1/2 at a = 1/2.
    EXPECT_NEAR(t, 0.5, 1e-6);
    ASSERT_TRUE(intersect_bilinear_patch(Vec3(.25f, 0, .5f), Vec3(0, 1, 0), 1, 0, 0, 1, 0.f, 1.f, t));
    EXPECT_NEAR(t, 0.5, 1e-6);
    // Tiny and denormal directions never give NaN.
    const float tiny[] = {0.f, -0.f, 1e-38f, 1e-45f, -1e-30f, 1e-7f};
    for (float e : tiny)
        for (float f : tiny) {
            if (intersect_bilinear_patch(Vec3(.3f, .7f, .6f), Vec3(e, f, -1e-3f), 1, 0, 0, 1, 0.f, 1e4f, t)) {
                EXPECT_TRUE(std::isfinite(t));
            }
            if (intersect_bilinear_patch(Vec3(.3f, .7f, .6f), Vec3(1, e, f), 1, 0, 0, 1, 0.f, 1.f, t)) {
                EXPECT_TRUE(std::isfinite(t));
            }
        }
}

// ---------------------------------------------------------------------------------------
// Analytic shapes

TEST(HeightfieldAnalytic, FlatFields) {
    // scale 0 (any map), a 1x1 map (all four corners of every cell are the one vertex), and a
    // constant non-power-of-two map: all the plane h = c.
    struct Case {
        HeightMap map;
        float scale, offset, c;
    };
    std::vector<Case> cases = {{noise_map(8, 8, 1), 0.f, 0.3f, 0.3f},
                               {HeightMap(1, 1, 0.7f), 2.f, -1.f, -1.f + 2.f * 0.7f},
                               {HeightMap(37, 19, -2.f), 1.f, 0.f, -2.f}};
    PCG32 rng(21);
    for (const Case &cs : cases) {
        Surface hf(cs.map, cs.scale, cs.offset);
        ASSERT_EQ(hf.min_height(), cs.c);
        ASSERT_EQ(hf.max_height(), cs.c);
        for (int k = 0; k < 20000; ++k) {
            const bool from_below = k % 3 == 0;
            const double theta = k % 10 == 1 ? kGrazing : rng.next_double() * kGrazing;
            Vec3 d = down_dir(theta, 2 * kPi * rng.next_double(), k % 7 == 0);
            if (from_below) d.z = -d.z;
            const int64_t ox = k % 4 == 2 ? int64_t(rng.next_u32()) - (1ll << 31) : 0;
            const float span = k % 4 == 1 ? 5000.f : 50.f;
            const Vec3 o(span * (rng.next_float() - .5f), span * (rng.next_float() - .5f),
                         cs.c + (from_below ? -1.f : 1.f) * (0.01f + 3 * rng.next_float()));
            const Ray r{o, d, ox, -ox};
            HeightfieldHit h;
            ASSERT_TRUE(hf.intersect(o, d, 0.f, Infinity, h, ox, -ox)) << describe(r);
            const double t_exact = (double(cs.c) - double(o.z)) / double(d.z);
            EXPECT_NEAR(h.t, t_exact, 1e-6 * t_exact) << describe(r);
            EXPECT_EQ(h.dhdx, 0.f);
            EXPECT_EQ(h.dhdy, 0.f);
            EXPECT_EQ(h.h, cs.c);
            EXPECT_TRUE(hit_on_surface(hf, r, h, 0.0)) << describe(r);
            EXPECT_TRUE(hf.occluded(o, d, 0.f, Infinity, ox, -ox));
            EXPECT_FALSE(hf.occluded(o, d, 0.f, float(t_exact * (1 - 1e-5)), ox, -ox)) << describe(r);
            EXPECT_FALSE(hf.intersect(o, d, 0.f, float(t_exact * (1 - 1e-5)), h, ox, -ox)) << describe(r);
            // Pointing away: never a hit.
            EXPECT_FALSE(hf.intersect(o, -d, 0.f, Infinity, h, ox, -ox)) << describe(r);
            EXPECT_FALSE(hf.occluded(o, -d, 0.f, Infinity, ox, -ox)) << describe(r);
        }
        // Parallel above and below: miss, and fast even with tmax = inf.
        for (float dz : {1e-3f, -1e-3f, 0.5f}) {
            HeightfieldHit h;
            for (Vec3 d : {Vec3(1, 0, 0), Vec3(0, -1, 0), Vec3(0.6f, 0.8f, 0), Vec3(-3, 7, 0)}) {
                EXPECT_FALSE(hf.intersect(Vec3(0.5f, 0.5f, cs.c + dz), d, 0.f, Infinity, h));
                EXPECT_FALSE(hf.occluded(Vec3(0.5f, 0.5f, cs.c + dz), d, 0.f, Infinity));
            }
        }
        // Parallel inside the plane: a coplanar ray is degenerate; whatever is reported
        // must be finite, on the plane and agree with occluded().
        for (Vec3 d : {Vec3(1, 0, 0), Vec3(0.6f, 0.8f, 0)}) {
            HeightfieldHit h;
            const Ray r{Vec3(0.25f, 0.5f, cs.c), d};
            const bool hit = hf.intersect(r.o, d, 0.f, 100.f, h);
            EXPECT_EQ(hit, hf.occluded(r.o, d, 0.f, 100.f));
            if (hit) {
                EXPECT_TRUE(hit_on_surface(hf, r, h, 0.0, 0.f, 100.f));
            }
        }
    }
}

TEST(HeightfieldAnalytic, TiltedPlaneInsideTheExactRegion) {
    // Vertex heights c + a i + b j are exactly the plane on [0, W-1] x [0, H-1]; the wrap
    // seam (cell W-1 back to vertex 0) is not a plane, so every ray segment from its
    // origin to the target stays inside the exact region.
    const int W = 64, H = 48;
    // Dyadic slopes: every vertex height is exact in float, so the plane is exact too.
    const double a = 1.0 / 64, b = -3.0 / 256, c = 0.125;
    HeightMap m(W, H);
    for (int j = 0; j < H; ++j)
        for (int i = 0; i < W; ++i) m.at(i, j) = float(c + a * i + b * j);
    const float scale = 2.f, offset = -1.f;
    Surface hf(m, scale, offset);
    const double A = scale * a, B = scale * b;
    const Vec3 n = normalize(Vec3(float(-A), float(-B), 1.f));
    auto plane = [&](double x, double y) { return offset + scale * (c + a * x + b * y); };
    ASSERT_EQ(double(hf.vertex(17, 29)), plane(17, 29));
    PCG32 rng(31);
    double worst_t = 0, worst_n = 0;
    for (int k = 0; k < 50000; ++k) {
        const double tx = 4 + (W - 9) * rng.next_double(), ty = 4 + (H - 9) * rng.next_double();
        // Direction at theta from the plane's normal.
        const double theta = k % 10 == 0 ? kGrazing : std::acos(1 - rng.next_double() * (1 - std::cos(kGrazing)));
        const double phi = 2 * kPi * rng.next_double();
        const Vec3 t1 = normalize(cross(n, Vec3(1, 0, 0))), t2 = cross(n, t1);
        const Vec3 dir = -(n * float(std::cos(theta)) +
                           (t1 * float(std::cos(phi)) + t2 * float(std::sin(phi))) * float(std::sin(theta)));
        if (dot(dir, n) >= 0) continue;
        // Origin inside the exact region: limit the horizontal run to 3 cells.
        const double horiz = std::hypot(dir.x, dir.y);
        const double s = std::min(30.0, 3.0 / std::max(horiz, 1e-9)) * (0.2 + 0.8 * rng.next_double());
        const double tz = plane(tx, ty);
        const Vec3 o(float(tx - s * dir.x), float(ty - s * dir.y), float(tz - s * dir.z));
        const int64_t ox = k % 2 ? W * int64_t(rng.next_bounded(1000)) - 500 * W : 0;
        const int64_t oy = k % 2 ? H * int64_t(rng.next_bounded(1000)) - 500 * H : 0;
        const Ray r{o, dir, ox, oy};  // offsets are whole tiles: same surface
        // Exact root of the float ray against the plane.
        const double F0 = double(o.z) - plane(o.x, o.y);
        const double Fp = double(dir.z) - A * dir.x - B * dir.y;
        const double t_exact = -F0 / Fp;
        HeightfieldHit h;
        ASSERT_TRUE(hf.intersect(o, dir, 0.f, Infinity, h, ox, oy)) << describe(r);
        ASSERT_TRUE(hit_on_surface(hf, r, h, std::abs(A) + std::abs(B))) << describe(r);
        const double et = std::abs(h.t - t_exact) / t_exact;
        worst_t = std::max(worst_t, et);
        EXPECT_LT(et, 2e-5) << describe(r) << " t=" << h.t << " exact " << t_exact;
        const Vec3 hn = normalize(Vec3(-h.dhdx, -h.dhdy, 1.f));
        const double en = length(hn - n);
        worst_n = std::max(worst_n, en);
        EXPECT_LT(en, 1e-5) << describe(r);
    }
    std::printf("[tilted plane] worst relative t error %.3g, worst normal error %.3g\n", worst_t, worst_n);
}

namespace {
/// Closed-form first hit with a periodic piecewise-linear profile along x (axis 0) or
/// y (axis 1): on each unit piece the gap is linear in t. Returns t and the slope there.
std::optional<std::pair<LD, LD>> profile_hit(const std::vector<float> &prof, int axis, const Ray &r, LD t0, LD t1) {
    const int n = int(prof.size());
    auto p = [&](int64_t k) { return LD(prof[size_t(((k % n) + n) % n)]); };
    LD lo = *std::min_element(prof.begin(), prof.end()), hi = *std::max_element(prof.begin(), prof.end());
    const LD dz = r.d.z, du = axis == 0 ? LD(r.d.x) : LD(r.d.y);
    if (dz != 0) {
        LD ta = (lo - LD(r.o.z)) / dz, tb = (hi - LD(r.o.z)) / dz;
        if (ta > tb) std::swap(ta, tb);
        t0 = std::max(t0, ta - 1e-9L);
        t1 = std::min(t1, tb + 1e-9L);
    }
    if (!(t1 >= t0)) return std::nullopt;
    auto U = [&](LD t) { return axis == 0 ? r.X(t) : r.Y(t); };
    LD t = t0;
    int64_t k = int64_t(std::floor(U(t0)));
    if (LD(k) == U(t0) && du < 0) --k;
    for (int guard = 0; guard < 10000000; ++guard) {
        LD tn = t1;
        if (du > 0) tn = std::min(t1, (LD(k + 1) - U(0)) / du);
        if (du < 0) tn = std::min(t1, (LD(k) - U(0)) / du);
        const LD slope = p(k + 1) - p(k);
        auto F = [&](LD s) { return r.Z(s) - (p(k) + (U(s) - LD(k)) * slope); };
        const LD Fa = F(t), Fp = dz - slope * du;
        if (Fa == 0) return std::make_pair(t, slope);
        if (Fp != 0) {
            const LD root = t - Fa / Fp;
            if (root >= t && root <= tn) return std::make_pair(root, slope);
        }
        if (tn >= t1) return std::nullopt;
        t = tn;
        k += du > 0 ? 1 : -1;
    }
    return std::nullopt;
}
}  // namespace

TEST(HeightfieldAnalytic, PiecewiseLinearProfiles) {
    struct Case {
        std::string name;
        std::vector<float> prof;
        int axis, other;
    };
    std::vector<Case> cases = {
        {"groove along y", groove_profile(16), 0, 5},
        {"groove along x", groove_profile(12), 1, 3},
        {"triangle 2x1", {0.f, 1.f}, 0, 1},
        {"profile 1x13", {0.f, .2f, .9f, .4f, -.3f, 0.f, .1f, .8f, .8f, .2f, -.5f, -.2f, .1f}, 1, 1},
    };
    PCG32 rng(41);
    for (const Case &cs : cases) {
        const HeightMap m = cs.axis == 0 ? profile_x_map(cs.prof, cs.other) : profile_y_map(cs.prof, cs.other);
        Surface hf(m, 1.f, 0.f);
        const int P = int(cs.prof.size());
        double worst_t = 0, worst_n = 0;
        int hits = 0;
        for (int k = 0; k < 40000; ++k) {
            // Half aimed at the profile from above (at all angles), half random rays
            // through the slab from anywhere.
            Ray r;
            const double theta = k % 10 == 0 ? kGrazing : rng.next_double() * kGrazing;
            r.d = down_dir(theta, 2 * kPi * rng.next_double(), k % 9 == 0);
            if (k % 2) {
                const double u = 3 * P * (rng.next_double() - .5);
                const double v = 100 * (rng.next_double() - .5);
                const double x = cs.axis == 0 ? u : v, y = cs.axis == 0 ? v : u;
                const double z = double(exact_height(hf, x, y));
                const double s = (hf.max_height() - z + 0.1 + rng.next_double()) / -double(r.d.z);
                r.o = Vec3(float(x - s * r.d.x), float(y - s * r.d.y), float(z - s * r.d.z));
            } else {
                if (k % 4 == 0) r.d.z = -r.d.z;  // upward rays too
                r.o = Vec3(float(40 * (rng.next_double() - .5)), float(40 * (rng.next_double() - .5)),
                           float(hf.min_height() - 0.5 + (hf.max_height() - hf.min_height() + 1) * rng.next_double()));
            }
            if (k % 3 == 0) {
                r.ox = int64_t(rng.next_bounded(20000)) - 10000;
                r.oy = int64_t(rng.next_bounded(20000)) - 10000;
            }
            const auto ref = profile_hit(cs.prof, cs.axis, r, 0, 1e6L);
            HeightfieldHit h;
            const bool hit = hf.intersect(r.o, r.d, 0.f, Infinity, h, r.ox, r.oy);
            EXPECT_EQ(hit, hf.occluded(r.o, r.d, 0.f, Infinity, r.ox, r.oy)) << describe(r);
            if (hit) {
                ++hits;
                ASSERT_TRUE(hit_on_surface(hf, r, h, 1.0)) << cs.name << ": " << describe(r);
            }
            if (hit != bool(ref) || (hit && std::abs(h.t - double(ref->first)) > 1e-5 * (1 + double(ref->first)))) {
                // Only a graze may differ.
                std::string why;
                long grazes = 0;
                EXPECT_TRUE(same_first_hit(hf, r, 0, 1e6, hit, h.t, ref ? std::optional<LD>(ref->first) : std::nullopt,
                                           1.0, grazes, why))
                    << cs.name << ": " << describe(r) << ": " << why;
                continue;
            }
            if (!hit) continue;
            worst_t = std::max(worst_t, std::abs(h.t - double(ref->first)) / (1 + double(ref->first)));
            // Normal, away from the kinks of the profile.
            const double u = cs.axis == 0 ? double(h.x) : double(h.y);
            if (std::abs(u - std::round(u)) > 1e-3) {
                const float sl = float(ref->second);
                const Vec3 na = normalize(cs.axis == 0 ? Vec3(-sl, 0, 1) : Vec3(0, -sl, 1));
                const Vec3 nh = normalize(Vec3(-h.dhdx, -h.dhdy, 1));
                worst_n = std::max(worst_n, double(length(na - nh)));
                EXPECT_LT(length(na - nh), 1e-6f) << cs.name << ": " << describe(r);
            }
        }
        EXPECT_GT(hits, 20000) << cs.name;
        std::printf("[%s] %d hits, worst t error %.3g (relative to 1+t), worst normal error %.3g\n", cs.name.c_str(),
                    hits, worst_t, worst_n);
    }
}

// ---------------------------------------------------------------------------------------
// The reference tracer itself, against dense marching with eval() plus bisection.

TEST(HeightfieldReference, AgreesWithDenseMarching) {
    Surface hf(sinusoid_map(37, 19, 2), 1.f, 0.f);
    PCG32 rng(51);
    int compared = 0;
    for (int k = 0; k < 300; ++k) {
        const double theta = rng.next_double() * 80 * kPi / 180;
        const Ray r{Vec3(float(37 * rng.next_double()), float(19 * rng.next_double()), hf.max_height() + 0.5f),
                    down_dir(theta, 2 * kPi * rng.next_double(), false)};
        const double t1 = (hf.min_height() - 0.1 - r.o.z) / r.d.z;
        const auto ref = reference_hit(hf, r, 0, t1);
        // March with the tracer's own float eval() in steps of 1/200 cell, then bisect.
        const double step = 0.005;
        std::optional<double> marched;
        auto g = [&](double t) {
            return double(r.o.z) + t * r.d.z - double(hf.eval(r.o.x + t * r.d.x, r.o.y + t * r.d.y));
        };
        for (double t = 0; t < t1; t += step)
            if (g(t + step) <= 0) {
                double a = t, b = t + step;
                for (int it = 0; it < 60; ++it) (g(0.5 * (a + b)) > 0 ? a : b) = 0.5 * (a + b);
                marched = b;
                break;
            }
        ASSERT_EQ(bool(ref), bool(marched)) << describe(r);
        if (ref) {
            ++compared;
            EXPECT_NEAR(double(*ref), *marched, 1e-4 * (1 + *marched)) << describe(r);
        }
    }
    EXPECT_GT(compared, 250);
}

// ---------------------------------------------------------------------------------------
// The battery: 10^6 rays aimed at the surface from above, at all angles.

namespace {

struct BatteryStats {
    long rays = 0, hits = 0, owed = 0, not_owed = 0, interior = 0, interior_not_owed = 0, ref_checked = 0,
         ref_grazes = 0, occl_checked = 0;
    double worst = 0;  // largest error seen, in units of its tolerance
    double tracer_s = 0;
};

/// The smallest t at or just past the target where the ray is measurably below the surface
/// (so a crossing lies before it), or none when round-off left the float ray passing
/// just over the target and staying above (then nothing is owed).
std::optional<double> owed_by(const Surface &hf, const Ray &r, double s) {
    const double depth = 4 * 0x1p-24 * (1 + std::max(std::abs(hf.min_height()), std::abs(hf.max_height())));
    // Below the surface at the target or just past it (the usual case), or just before it
    // (the ray emerges there: it crossed the surface earlier); a crossing lies before.
    for (double rel : {0.0, 1e-7, 1e-6, -1e-6, -1e-5, -1e-4, -1e-3, 1e-5, 1e-4, 1e-3}) {
        const double t = s + rel * (1 + s);
        if (t > 0 && gap(hf, r, t) < -depth) return t;
    }
    return std::nullopt;
}

/// Ray aimed at target (x, y) (local coordinates; the surface point uses the offsets) from
/// above the height slab along d.
Ray aim(const Surface &hf, double x, double y, int64_t ox, int64_t oy, Vec3 d, double margin, double &s) {
    const float fx = float(x), fy = float(y);
    const double z = double(exact_height(hf, LD(fx) + ox, LD(fy) + oy));
    s = (double(hf.max_height()) - z + margin) / -double(d.z);
    return Ray{Vec3(float(fx - s * d.x), float(fy - s * d.y), float(z - s * d.z)), d, ox, oy};
}

/// Compares a tracer answer with the reference on [0, t1]; returns false on a real
/// disagreement (more than a graze).
bool agrees_with_reference(const Surface &hf, const Ray &r, bool hit, const HeightfieldHit &h, double t1, double slope,
                           BatteryStats &st, std::string &why) {
    ++st.ref_checked;
    return same_first_hit(hf, r, 0, t1, hit, h.t, reference_hit(hf, r, 0, t1), slope, st.ref_grazes, why);
}

enum class Where { Small, Large, Offset, HugeOffset };

void run_battery(const Field &f, int n, uint64_t seed, BatteryStats &st) {
    Surface hf(f.map, f.scale, f.offset);
    const double slope = max_slope_of(hf);
    const int W = hf.width(), H = hf.height();
    PCG32 rng(seed);
    int failures = 0;
    for (int k = 0; k < n && failures < 10; ++k) {
        // Directions: 10% at exactly 89.9 deg, 3% vertical, the rest uniform in theta or
        // in cos(theta); 15% with an exactly zero x or y component, 10% exact diagonals;
        // a quarter unnormalised.
        const uint32_t tk = rng.next_bounded(100);
        const double theta = tk < 10   ? kGrazing
                             : tk < 13 ? 0.0
                             : tk < 55 ? rng.next_double() * kGrazing
                                       : std::acos(1 - rng.next_double() * (1 - std::cos(kGrazing)));
        const uint32_t pk = rng.next_bounded(100);
        const double phi = 2 * kPi * rng.next_double();
        Vec3 d = down_dir(theta, phi, pk < 15);
        if (pk >= 15 && pk < 25) {
            const float hxy = float(std::sin(theta) / std::sqrt(2.0));
            d = Vec3(pk & 1 ? hxy : -hxy, pk & 2 ? hxy : -hxy, float(-std::cos(theta)));
        }
        if (rng.next_bounded(4) == 0) d = d * float(std::exp(std::log(100.0) * (2 * rng.next_double() - 1)));
        // Where: small coordinates, a 200 x 200 tile domain in large coordinates, the same
        // via offsets, and huge offsets.
        const Where where = Where(rng.next_bounded(4));
        double x = W * (3 * rng.next_double() - 1), y = H * (3 * rng.next_double() - 1);
        int64_t ox = 0, oy = 0;
        if (where == Where::Large) x = W * 200 * (rng.next_double() - .5), y = H * 200 * (rng.next_double() - .5);
        if (where == Where::Offset) {
            ox = int64_t(rng.next_bounded(uint32_t(200 * W))) - 100 * W;
            oy = int64_t(rng.next_bounded(uint32_t(200 * H))) - 100 * H;
        }
        if (where == Where::HugeOffset) {
            ox = (int64_t(rng.next_u32()) << 8) - (1ll << 39);
            oy = -(int64_t(rng.next_u32()) << 8);
        }
        // A fifth of the targets on cell edges, corners or tile boundaries.
        const uint32_t ek = rng.next_bounded(20);
        if (ek == 0) x = std::round(x);
        if (ek == 1) y = std::round(y);
        if (ek == 2) x = std::round(x), y = std::round(y);
        if (ek == 3) x = W * std::round(x / W), y = H * std::round(y / H);
        double s;
        const Ray r = aim(hf, x, y, ox, oy, d, 0.01 + rng.next_double(), s);
        ++st.rays;
        HeightfieldHit h;
        const auto c0 = std::chrono::steady_clock::now();
        const bool hit = hf.intersect(r.o, r.d, 0.f, Infinity, h, r.ox, r.oy);
        st.tracer_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - c0).count();
        const auto owed = owed_by(hf, r, s);
        if (owed)
            ++st.owed;
        else
            ++st.not_owed;
        if (ek >= 4) ++st.interior, st.interior_not_owed += !owed;
        if (owed && (!hit || h.t > *owed * (1 + 1e-6))) {
            ADD_FAILURE() << f.name << ": false miss: " << describe(r) << " target t=" << s << " tracer "
                          << (hit ? "hit at t=" + std::to_string(h.t) : std::string("missed"));
            ++failures;
            continue;
        }
        if (!hit) continue;
        ++st.hits;
        const auto ok = hit_on_surface(hf, r, h, slope, 0.f, Infinity, &st.worst);
        if (!ok) {
            ADD_FAILURE() << f.name << ": " << describe(r) << ": " << ok.message();
            ++failures;
            continue;
        }
        if (k % 2 == 0 && !hf.occluded(r.o, r.d, 0.f, Infinity, r.ox, r.oy)) {
            ADD_FAILURE() << f.name << ": occluded() missed the hit at t=" << h.t << ": " << describe(r);
            ++failures;
        }
        // Shortened tmax, just before and just after the hit (an eighth of the rays). Only
        // where the ray crosses the surface: a ray that only touches it (aimed at a ridge
        // it then passes over) may or may not report the touch.
        if (k % 8 == 0 && owed) {
            ++st.occl_checked;
            const float before = h.t * (1 - 1e-5f), after = h.t * (1 + 1e-5f);
            HeightfieldHit h2, h3;
            const bool c[6] = {hf.occluded(r.o, r.d, 0.f, Infinity, r.ox, r.oy),
                               hf.occluded(r.o, r.d, 0.f, after, r.ox, r.oy),
                               !hf.occluded(r.o, r.d, 0.f, before, r.ox, r.oy),
                               !hf.intersect(r.o, r.d, 0.f, before, h2, r.ox, r.oy),
                               hf.intersect(r.o, r.d, 0.f, after, h3, r.ox, r.oy),
                               h3.t == h.t};
            if (!(c[0] && c[1] && c[2] && c[3] && c[4] && c[5])) {
                ADD_FAILURE() << f.name << ": occluded/intersect disagree around t=" << h.t << " (checks " << c[0]
                              << c[1] << c[2] << c[3] << c[4] << c[5] << ", shortened intersect t=" << h2.t
                              << ", extended t=" << h3.t << "): " << describe(r);
                ++failures;
            }
        }
        // The closest hit, against the reference tracer (a sixteenth of the rays).
        if (k % 16 == 4) {
            std::string why;
            if (!agrees_with_reference(hf, r, hit, h, owed ? *owed : s * 1.01 + 1, slope, st, why)) {
                ADD_FAILURE() << f.name << ": " << describe(r) << ": " << why;
                ++failures;
            }
        }
    }
}

}  // namespace

TEST(HeightfieldBattery, MillionRaysNoFalseMissesNoOffSurfaceHits) {
    const auto fields = battery_fields();
    const int per_field = 1000000 / int(fields.size());
    BatteryStats total;
    const auto t0 = std::chrono::steady_clock::now();
    for (size_t i = 0; i < fields.size(); ++i) {
        BatteryStats st;
        run_battery(fields[i], per_field, 1000 + i, st);
        std::printf(
            "[%-18s] rays %ld hits %ld owed %ld not-owed %ld (interior %ld) | ref %ld (grazes %ld) occl %ld | worst "
            "error %.3f of tolerance\n",
            fields[i].name.c_str(), st.rays, st.hits, st.owed, st.not_owed, st.interior_not_owed, st.ref_checked,
            st.ref_grazes, st.occl_checked, st.worst);
        // Aimed at a cell interior, round-off leaves few rays owing nothing (a bilinear patch
        // has no interior peak to pass over); at edges and vertices ridges are common.
        EXPECT_LT(st.interior_not_owed, st.interior / 200) << fields[i].name;
        total.rays += st.rays;
        total.tracer_s += st.tracer_s;
    }
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("[battery] %ld rays in %.2f s with the checks, %.2f s of it in intersect()\n", total.rays, secs,
                total.tracer_s);
}

// ---------------------------------------------------------------------------------------
// Rays through cell corners, cell edges and tile boundaries

TEST(HeightfieldBattery, CornersEdgesAndTileBoundariesDoNotLeak) {
    const auto fields = battery_fields();
    PCG32 rng(61);
    long rays = 0, owed_rays = 0;
    for (const Field &f : fields) {
        Surface hf(f.map, f.scale, f.offset);
        const double slope = max_slope_of(hf);
        const int W = hf.width(), H = hf.height();
        int failures = 0;
        // Targets: tile corners, vertices, midpoints of cell edges, points on tile edges.
        std::vector<std::pair<double, double>> targets;
        for (int ti = -1; ti <= 1; ++ti)
            for (int tj = -1; tj <= 1; ++tj) {
                targets.push_back({ti * W, tj * H});
                targets.push_back({ti * W + 0.5, tj * H});
                targets.push_back({ti * W, tj * H + 0.5});
                targets.push_back({ti * W, tj * H + rng.next_double() * H});
                targets.push_back({ti * W + rng.next_double() * W, tj * H});
                const int i = int(rng.next_bounded(uint32_t(W))), j = int(rng.next_bounded(uint32_t(H)));
                targets.push_back({ti * W + i, tj * H + j});
                targets.push_back({ti * W + i + 0.5, tj * H + j});
                targets.push_back({ti * W + i, tj * H + j + 0.5});
            }
        for (const auto &tg : targets)
            for (int dk = 0; dk < 13; ++dk)
                for (double steep : {1.0, 0.3, 0.05, 0.0017}) {
                    Vec3 d;
                    if (dk == 0) {
                        if (steep != 1.0) continue;
                        d = Vec3(0, 0, -1);
                    } else if (dk <= 4) {  // along x or y
                        const int q = dk - 1;
                        d = Vec3(q == 0 ? 1.f : q == 1 ? -1.f : 0.f, q == 2 ? 1.f : q == 3 ? -1.f : 0.f, float(-steep));
                    } else if (dk <= 8) {  // exact diagonals (through cell corners)
                        const int q = dk - 5;
                        d = Vec3(q & 1 ? 1.f : -1.f, q & 2 ? 1.f : -1.f, float(-steep));
                    } else {  // random azimuth
                        const double phi = 2 * kPi * rng.next_double();
                        d = Vec3(float(std::cos(phi)), float(std::sin(phi)), float(-steep));
                    }
                    for (int where = 0; where < 2; ++where) {
                        // Small coordinates, or whole-tile offsets with the target moved back.
                        int64_t ox = 0, oy = 0;
                        double x = tg.first, y = tg.second;
                        if (where == 1) {
                            ox = W * (int64_t(rng.next_bounded(2000)) - 1000) + int64_t(rng.next_bounded(3)) - 1;
                            oy = H * (int64_t(rng.next_bounded(2000)) - 1000) + int64_t(rng.next_bounded(3)) - 1;
                            x -= double(ox - W * (ox / W)), y -= double(oy - H * (oy / H));
                            ox = W * (ox / W) + (ox - W * (ox / W)), oy = H * (oy / H) + (oy - H * (oy / H));
                        }
                        double s;
                        const Ray r = aim(hf, x, y, ox, oy, d, 0.25, s);
                        ++rays;
                        const auto owed = owed_by(hf, r, s);
                        HeightfieldHit h;
                        const bool hit = hf.intersect(r.o, r.d, 0.f, Infinity, h, r.ox, r.oy);
                        if (hit) {
                            const auto ok = hit_on_surface(hf, r, h, slope);
                            if (!ok && failures++ < 5)
                                ADD_FAILURE() << f.name << ": " << describe(r) << ": " << ok.message();
                        }
                        if (!owed) continue;
                        ++owed_rays;
                        if ((!hit || h.t > *owed * (1 + 1e-6)) && failures++ < 5)
                            ADD_FAILURE() << f.name << ": leak at (" << x << ", " << y << "): " << describe(r)
                                          << " target t=" << s << (hit ? " hit later" : " missed");
                        if (!hf.occluded(r.o, r.d, 0.f, Infinity, r.ox, r.oy) && failures++ < 5)
                            ADD_FAILURE() << f.name << ": occluded() leaks: " << describe(r);
                    }
                }
        EXPECT_EQ(failures, 0) << f.name;
    }
    std::printf("[corners/edges/tiles] %ld rays, %ld owed a hit\n", rays, owed_rays);
    EXPECT_GT(owed_rays, rays * 3 / 4);
}

// ---------------------------------------------------------------------------------------
// Special rays

TEST(HeightfieldBattery, VerticalRaysGiveTheHeightAndNormal) {
    const auto fields = battery_fields();
    PCG32 rng(71);
    for (const Field &f : fields) {
        Surface hf(f.map, f.scale, f.offset);
        const double slope = max_slope_of(hf);
        for (int k = 0; k < 4000; ++k) {
            double x = 3 * hf.width() * (rng.next_double() - .5), y = 3 * hf.height() * (rng.next_double() - .5);
            if (k % 5 == 0) x = std::round(x);
            if (k % 7 == 0) y = std::round(y);
            const int64_t ox = k % 2 ? int64_t(rng.next_u32()) - (1ll << 31) : 0, oy = k % 3 ? -3 * ox : 0;
            const bool up = k % 4 == 1;
            const float speed = k % 8 < 4 ? 1.f : 1e-3f;
            LD dx, dy;
            const double z = double(exact_height(hf, LD(float(x)) + ox, LD(float(y)) + oy, &dx, &dy));
            const Ray r{Vec3(float(x), float(y), up ? hf.min_height() - 1.5f : hf.max_height() + 1.5f),
                        Vec3(k % 3 == 0 ? -0.f : 0.f, k % 5 == 0 ? -0.f : 0.f, up ? speed : -speed), ox, oy};
            HeightfieldHit h;
            ASSERT_TRUE(hf.intersect(r.o, r.d, 0.f, Infinity, h, ox, oy)) << f.name << ": " << describe(r);
            ASSERT_TRUE(hit_on_surface(hf, r, h, slope)) << f.name << ": " << describe(r);
            const double t_exact = (z - double(r.o.z)) / double(r.d.z);
            EXPECT_NEAR(h.t, t_exact, 8 * kU * (std::abs(t_exact) + std::abs(r.o.z) / speed))
                << f.name << ": " << describe(r);
            // x0 + a in float: exact up to the rounding of that sum.
            EXPECT_NEAR(h.x, r.o.x, 2 * kU * (2 + std::abs(r.o.x)));
            EXPECT_NEAR(h.y, r.o.y, 2 * kU * (2 + std::abs(r.o.y)));
            // The normal, where the slope is not ambiguous (away from cell edges).
            const double fx = x - std::floor(x), fy = y - std::floor(y);
            if (fx > 1e-3 && fx < 1 - 1e-3 && fy > 1e-3 && fy < 1 - 1e-3) {
                EXPECT_NEAR(h.dhdx, double(dx), 1e-5 * (1 + slope)) << f.name;
                EXPECT_NEAR(h.dhdy, double(dy), 1e-5 * (1 + slope)) << f.name;
            }
            EXPECT_TRUE(hf.occluded(r.o, r.d, 0.f, Infinity, ox, oy));
            EXPECT_FALSE(hf.occluded(r.o, r.d, 0.f, float(t_exact) * (1 - 1e-5f), ox, oy));
        }
    }
}

TEST(HeightfieldBattery, RaysFromInsideTheSlabAndFromBelow) {
    // Two-sided: a ray starting below the surface and heading up must cross it before it
    // leaves the slab; rays starting anywhere in the slab agree with the reference.
    const auto fields = battery_fields();
    PCG32 rng(81);
    for (const Field &f : fields) {
        Surface hf(f.map, f.scale, f.offset);
        const double slope = max_slope_of(hf);
        const double range = hf.max_height() - hf.min_height();
        int failures = 0;
        long grazes = 0;
        BatteryStats st;
        for (int k = 0; k < 6000 && failures < 5; ++k) {
            const double x = 3 * hf.width() * (rng.next_double() - .5), y = 3 * hf.height() * (rng.next_double() - .5);
            const int64_t ox = k % 3 == 0 ? int64_t(rng.next_bounded(100000)) - 50000 : 0;
            const int64_t oy = k % 3 == 0 ? int64_t(rng.next_bounded(100000)) - 50000 : 0;
            const double hz = double(exact_height(hf, LD(float(x)) + ox, LD(float(y)) + oy));
            const bool below = k % 2 == 0;
            const double z = below ? hz - (0.01 + rng.next_double()) * (range + 0.1)
                                   : hz + (0.01 + rng.next_double()) * (range + 0.1);
            const double theta = k % 10 == 0 ? kGrazing : rng.next_double() * kGrazing;
            Vec3 d = down_dir(theta, 2 * kPi * rng.next_double(), k % 9 == 0);
            const bool upward = k % 4 < 2;
            if (upward) d.z = -d.z;
            const Ray r{Vec3(float(x), float(y), float(z)), d, ox, oy};
            if (gap(hf, r, 0) * (below ? -1 : 1) <= 0) continue;  // rounding put it on the other side
            HeightfieldHit h;
            const bool hit = hf.intersect(r.o, r.d, 0.f, Infinity, h, ox, oy);
            if (hit && !hit_on_surface(hf, r, h, slope)) {
                ADD_FAILURE() << f.name << ": " << describe(r) << ": " << hit_on_surface(hf, r, h, slope).message();
                ++failures;
                continue;
            }
            EXPECT_EQ(hit, hf.occluded(r.o, r.d, 0.f, Infinity, ox, oy)) << f.name << ": " << describe(r);
            // Leaving the slab on the far side of the surface: a crossing is owed.
            const double t_exit = ((upward ? hf.max_height() : hf.min_height()) - double(r.o.z)) / r.d.z;
            if (below == upward && !hit) {
                ADD_FAILURE() << f.name << ": ray from " << (below ? "below" : "above") << " missed: " << describe(r);
                ++failures;
                continue;
            }
            if (hit) {
                EXPECT_LE(h.t, t_exit * (1 + 1e-6) + 1e-6) << f.name << ": " << describe(r);
            }
            // From below, the ray is below the surface up to the hit.
            if (hit && below) {
                EXPECT_LE(double(gap(hf, r, h.t * 0.5)), 0.0) << f.name << ": " << describe(r);
            }
            std::string why;
            if (!agrees_with_reference(hf, r, hit, h, std::max(t_exit, 0.0) * 1.001 + 1e-3, slope, st, why)) {
                ADD_FAILURE() << f.name << ": " << describe(r) << ": " << why;
                ++failures;
            }
        }
        grazes += st.ref_grazes;
        EXPECT_LT(st.ref_grazes, st.ref_checked / 50) << f.name;
    }
}

TEST(HeightfieldBattery, HorizontalRays) {
    PCG32 rng(91);
    for (const Field &f : battery_fields()) {
        Surface hf(f.map, f.scale, f.offset);
        const double slope = max_slope_of(hf);
        BatteryStats st;
        for (int k = 0; k < 2000; ++k) {
            const double phi = 2 * kPi * rng.next_double();
            Vec3 d = down_dir(kPi / 2, phi, k % 3 == 0);
            d.z = k % 2 ? 0.f : -0.f;
            const Vec3 o(float(hf.width() * rng.next_double()), float(hf.height() * rng.next_double()),
                         float(hf.min_height() + (hf.max_height() - hf.min_height()) * rng.next_double()));
            HeightfieldHit h;
            // Above and below the slab: never a hit, even with tmax = inf.
            EXPECT_FALSE(hf.intersect(Vec3(o.x, o.y, hf.max_height() + 0.01f), d, 0.f, Infinity, h));
            EXPECT_FALSE(hf.occluded(Vec3(o.x, o.y, hf.min_height() - 0.01f), d, 0.f, Infinity));
            if (hf.max_height() == hf.min_height()) continue;  // inside a flat field: see FlatFields
            // Inside the slab, over a bounded stretch: as the reference.
            const float tmax = 50.f;
            const Ray r{o, d};
            const bool hit = hf.intersect(o, d, 0.f, tmax, h);
            if (hit) {
                ASSERT_TRUE(hit_on_surface(hf, r, h, slope, 0.f, tmax)) << f.name << ": " << describe(r);
            }
            EXPECT_EQ(hit, hf.occluded(o, d, 0.f, tmax)) << f.name << ": " << describe(r);
            std::string why;
            EXPECT_TRUE(agrees_with_reference(hf, r, hit, h, tmax, slope, st, why))
                << f.name << ": " << describe(r) << ": " << why;
        }
    }
}

TEST(HeightfieldBattery, GrazingAndDegenerateDirectionsStayFinite) {
    PCG32 rng(101);
    const float tiny[] = {0.f, -0.f, 1e-38f, -1e-40f, 1e-30f, -1e-25f, 1e-12f, -1e-7f};
    for (const Field &f : battery_fields()) {
        Surface hf(f.map, f.scale, f.offset);
        const double slope = max_slope_of(hf);
        for (int k = 0; k < 800; ++k) {
            const double phi = 2 * kPi * rng.next_double();
            Vec3 d(float(std::cos(phi)), float(std::sin(phi)), -tiny[k % 8]);
            if (k % 5 == 1) d.x = tiny[(k / 8) % 8];
            if (k % 5 == 2) d.y = tiny[(k / 8) % 8];
            if (k % 5 == 3) d = d * 1e-20f;
            if (k % 5 == 4) d = d * 1e15f;
            const Vec3 o(float(hf.width() * rng.next_double()), float(hf.height() * rng.next_double()),
                         float(hf.min_height() + (hf.max_height() - hf.min_height() + 0.2) * rng.next_double() - 0.1));
            const Ray r{o, d};
            const float len = std::max({std::abs(d.x), std::abs(d.y), std::abs(d.z)});
            const float tmax = 200.f / len;  // a bounded stretch (the tiled plane is infinite)
            HeightfieldHit h;
            const bool hit = hf.intersect(o, d, 0.f, tmax, h);
            EXPECT_EQ(hit, hf.occluded(o, d, 0.f, tmax)) << f.name << ": " << describe(r);
            if (!hit) continue;
            ASSERT_TRUE(finite_hit(h)) << f.name << ": " << describe(r);
            EXPECT_TRUE(hit_on_surface(hf, r, h, slope, 0.f, tmax)) << f.name << ": " << describe(r);
        }
    }
}

TEST(HeightfieldBattery, LaterHitsThroughTmin) {
    // Walk every crossing of a ray through the slab by restarting at the last hit; each
    // must be the reference's next crossing.
    PCG32 rng(111);
    for (const char *name : {"sin37x19", "noise16x16_steep", "two_by_one"}) {
        Field f;
        for (const Field &g : battery_fields())
            if (g.name == name) f = g;
        Surface hf(f.map, f.scale, f.offset);
        const double slope = max_slope_of(hf);
        BatteryStats st;
        long crossings = 0;
        for (int k = 0; k < 3000; ++k) {
            const double theta = (60 + 29.9 * rng.next_double()) * kPi / 180;
            const Vec3 d = down_dir(theta, 2 * kPi * rng.next_double(), k % 7 == 0);
            const Ray r{Vec3(float(hf.width() * rng.next_double()), float(hf.height() * rng.next_double()),
                             hf.max_height() + 0.1f),
                        d};
            const float t_end = float((hf.min_height() - 0.1 - r.o.z) / d.z);
            float tmin = 0.f;
            for (int n = 0; n < 64; ++n) {
                HeightfieldHit h;
                const bool hit = hf.intersect(r.o, r.d, tmin, t_end, h);
                EXPECT_EQ(hit, hf.occluded(r.o, r.d, tmin, t_end)) << name << ": " << describe(r);
                if (hit) {
                    ASSERT_TRUE(hit_on_surface(hf, r, h, slope, tmin, t_end)) << name << ": " << describe(r);
                }
                // The reference from just past tmin (a crossing at tmin itself is excluded).
                const auto ref = reference_hit(hf, r, LD(tmin) * (1 + 1e-9L) + 1e-12L, t_end);
                std::string why;
                EXPECT_TRUE(same_first_hit(hf, r, tmin, t_end, hit, h.t, ref, slope, st.ref_grazes, why))
                    << name << ": " << describe(r) << " from tmin=" << tmin << ": " << why;
                if (!hit) break;
                ++crossings;
                // Restart just past this hit (a float ulp or two).
                tmin = std::nextafter(std::nextafter(h.t, Infinity), Infinity);
            }
        }
        std::printf("[%s] %ld crossings walked, %ld grazes\n", name, crossings, st.ref_grazes);
        EXPECT_GT(crossings, 3000);
    }
}

TEST(HeightfieldBattery, ConstructionErrors) {
    EXPECT_THROW(Heightfield(HeightMap(), 1.f, 0.f), MesoError);
    HeightMap bad(3, 2);
    bad.h.pop_back();
    EXPECT_THROW(Heightfield(bad, 1.f, 0.f), MesoError);
    EXPECT_THROW(Heightfield(HeightMap(2, 2, 1.f), std::numeric_limits<float>::infinity(), 0.f), MesoError);
    EXPECT_THROW(Heightfield(HeightMap(2, 2, 1.f), 1.f, std::nanf("")), MesoError);
    EXPECT_THROW(Heightfield(HeightMap(2, 2, 1e30f), 1e10f, 0.f), MesoError);  // overflows to inf
    Heightfield hf(HeightMap(4, 3, 0.5f), -2.f, 1.f);
    EXPECT_EQ(hf.width(), 4);
    EXPECT_EQ(hf.height(), 3);
    EXPECT_EQ(hf.min_height(), 0.f);
    EXPECT_EQ(hf.max_height(), 0.f);
    EXPECT_EQ(hf.vertex(-1, 7), 0.f);
    HeightfieldHit h;
    EXPECT_FALSE(hf.intersect(Vec3(0, 0, 1), Vec3(0, 0, -1), 2.f, 1.f, h));  // tmax < tmin
    EXPECT_FALSE(hf.intersect(Vec3(0, 0, 1), Vec3(0, 0, -1), 0.f, 1.f - 1e-6f, h));
    EXPECT_TRUE(hf.intersect(Vec3(0, 0, 1), Vec3(0, 0, -1), 0.f, 1.f, h));  // tmax inclusive
    EXPECT_FLOAT_EQ(h.t, 1.f);
    EXPECT_FALSE(hf.intersect(Vec3(0, 0, 1), Vec3(0, 0, -1), 1.f, 2.f, h));  // tmin exclusive
}

// ---------------------------------------------------------------------------------------
// Speed (printed, not asserted)

TEST(HeightfieldTiming, Fbm1024TiledRaysPerSecond) {
    // A 1024^2 sum of periodic sinusoids (octaves of fBm-like detail), tiled 100 x 100 via
    // the offsets; rays from just above the slab at random angles (cosine-distributed).
    const int N = 1024;
    HeightMap m(N, N);
    PCG32 rng(121);
    struct Wave {
        int fx, fy;
        float a, ph;
    };
    std::vector<Wave> waves;
    for (int oct = 0; oct < 8; ++oct)
        for (int k = 0; k < 3; ++k) {
            const int f = 1 << oct;
            waves.push_back({int(rng.next_bounded(uint32_t(2 * f + 1))) - f, int(rng.next_bounded(uint32_t(f + 1))),
                             std::pow(0.5f, float(oct)) * 8.f, float(2 * kPi) * rng.next_float()});
        }
    for (int j = 0; j < N; ++j)
        for (int i = 0; i < N; ++i) {
            float v = 0;
            for (const Wave &w : waves) v += w.a * std::sin(float(2 * kPi) * float(w.fx * i + w.fy * j) / N + w.ph);
            m.at(i, j) = v;
        }
    const auto b0 = std::chrono::steady_clock::now();
    Heightfield hf(m, 1.f, 0.f);
    const double build_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - b0).count();
    const int n = 200000;
    std::vector<Vec3> o(n), d(n);
    std::vector<int64_t> ox(n), oy(n);
    for (int k = 0; k < n; ++k) {
        const double u1 = rng.next_double(), phi = 2 * kPi * rng.next_double();
        const double ct = std::sqrt(1 - u1), st = std::sqrt(u1);
        d[k] = Vec3(float(st * std::cos(phi)), float(st * std::sin(phi)), float(-ct));
        o[k] = Vec3(float(N * rng.next_double()), float(N * rng.next_double()), hf.max_height() + 0.5f);
        ox[k] = N * int64_t(rng.next_bounded(100));
        oy[k] = N * int64_t(rng.next_bounded(100));
    }
    long hits = 0;
    const auto t0 = std::chrono::steady_clock::now();
    for (int k = 0; k < n; ++k) {
        HeightfieldHit h;
        hits += hf.intersect(o[k], d[k], 0.f, Infinity, h, ox[k], oy[k]);
    }
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const auto t1 = std::chrono::steady_clock::now();
    long occl = 0;
    for (int k = 0; k < n; ++k) occl += hf.occluded(o[k], d[k], 0.f, Infinity, ox[k], oy[k]);
    const double secs_occl = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
    std::printf(
        "[timing] 1024^2 map (heights %.2f..%.2f, pyramid built in %.3f s, %.1f MiB): intersect %.3g rays/s, "
        "occluded %.3g rays/s, one thread; %ld/%d hit\n",
        hf.min_height(), hf.max_height(), build_s, hf.memory_bytes() / 1048576.0, n / secs, n / secs_occl, hits, n);
    EXPECT_EQ(hits, n);
    EXPECT_EQ(occl, n);
}
