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
#include "heightfield_test_util.h"


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

