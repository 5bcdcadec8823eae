// The heightfield intersector's ray battery: 10^6 rays aimed at surface points from
// above at every angle up to 89.9 degrees (no false misses, no off-surface hits),
// corners, edges and tile boundaries, rays from inside the slab and below, horizontal
// and degenerate directions, the block traversal's start levels and block shapes, and the
// timing. Helpers: heightfield_test_util.h.
#include "heightfield_test_util.h"

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

// ---------------------------------------------------------------------------------------
// The block traversal's start and shape: the pyramid in 4 x 4 blocks (maps whose sizes are
// no multiple of 4 leave blocks partly empty at every level; an odd top level ends in a
// 2 x 2 step), the start block (up to 4 x 4 nodes at the lowest even level that holds the
// footprint: windows from a fraction of a cell to hundreds), rays leaving the surface in
// every direction up to grazing, and height scales from zero to huge.

/// Rays of one kind per k % 3: from just off the surface (up or down, to 89.9 degrees), from
/// above through a window [t0, t1] about the crossing whose footprint spans `cells`, and
/// grazing rays across the whole field.
Ray block_case(const Surface &hf, PCG32 &rng, int k, double &t0, double &t1) {
    const double range = double(hf.max_height()) - hf.min_height(), span = std::max(range, 1e-3);
    const double x = hf.width() * rng.next_double(), y = hf.height() * rng.next_double();
    const double theta = k % 7 == 0 ? kGrazing : rng.next_double() * kGrazing;
    Vec3 d = down_dir(theta, 2 * kPi * rng.next_double(), k % 11 == 0);
    const double hz = double(exact_height(hf, LD(float(x)), LD(float(y))));
    t0 = 0;
    if (k % 3 == 0) {  // from the surface: a float's rounding above or below it
        if (rng.next_bounded(2)) d.z = -d.z;
        t1 = (std::abs(hz) + 2 * span + 1) / std::max(std::abs(double(d.z)), 1e-3) + 1;
        const double z = hz + (rng.next_bounded(2) ? 1 : -1) * 1e-4 * span * (1 + std::abs(hz));
        return Ray{Vec3(float(x), float(y), float(z)), d};
    }
    if (k % 3 == 1) {  // from above, through a window of `cells` about the crossing
        static const double kCells[] = {0.3, 1.5, 3.5, 5, 13, 17, 70, 300};
        const double cells = kCells[rng.next_bounded(8)];
        const double s = (double(hf.max_height()) - hz + 0.1 * span) / -double(d.z);
        const Ray r{Vec3(float(x - s * d.x), float(y - s * d.y), float(hz - s * d.z)), d};
        const double w = cells / std::max(std::hypot(double(d.x), double(d.y)), 1e-9);
        t0 = std::max(0.0, s - w * rng.next_double());
        t1 = t0 + w;
        return r;
    }
    d.z = float(-std::abs(d.z) * 1e-3);  // grazing across the field
    t1 = 4.0 * (hf.width() + hf.height());
    return Ray{Vec3(float(x), float(y), float(hf.max_height() + 0.01 * span)), d};
}

TEST(HeightfieldBattery, BlockTraversalStartsAndSizesAgreeWithTheReference) {
    std::vector<Field> fields = {
        {"one_by_one", HeightMap(1, 1, 0.7f), 2.f, -1.f},  {"two_by_two", noise_map(2, 2, 21), 1.f, 0.f},
        {"four_by_four", noise_map(4, 4, 22), 1.f, 0.f},   {"noise7x9", noise_map(7, 9, 23), 1.f, 0.f},
        {"sin128_odd_top", sinusoid_map(128, 128, 24), 1.f, 0.f}, {"noise130x66", noise_map(130, 66, 25), 2.f, 0.f},
        {"sin64_huge", sinusoid_map(64, 64, 26), 1e4f, 0.f},      {"noise16_zero", noise_map(16, 16, 27), 0.f, 0.5f},
        {"noise16_tiny", noise_map(16, 16, 28), 1e-6f, 3.f}};
    PCG32 rng(123);
    for (const Field &f : fields) {
        Surface hf(f.map, f.scale, f.offset);
        const double slope = max_slope_of(hf);
        int failures = 0;
        BatteryStats st;
        for (int k = 0; k < 6000 && failures < 5; ++k) {
            double t0, t1;
            const Ray r = block_case(hf, rng, k, t0, t1);
            // A window that opens on the surface to within float resolution of its start (a
            // crossing that rounds to t0, excluded from (t0, t1]) answers by rounding.
            if (std::abs(double(gap(hf, r, LD(float(t0))))) <= gap_tolerance(r, float(t0), hf.max_height(), slope))
                continue;
            HeightfieldHit h, g;
            const bool hit = hf.intersect(r.o, r.d, float(t0), float(t1), h);
            const bool ref_hit = hf.intersect_reference(r.o, r.d, float(t0), float(t1), g);
            EXPECT_EQ(hit, hf.occluded(r.o, r.d, float(t0), float(t1))) << f.name << ": " << describe(r);
            EXPECT_TRUE(hit == ref_hit && (!hit || h.t == g.t)) << f.name << ": SIMD and scalar differ, " << describe(r);
            if (hit && !hit_on_surface(hf, r, h, slope)) {
                ADD_FAILURE() << f.name << ": " << describe(r) << ": " << hit_on_surface(hf, r, h, slope).message();
                ++failures;
                continue;
            }
            std::string why;
            ++st.ref_checked;
            // The long-double cell-walking tracer on the same window, as floats pass it.
            if (!same_first_hit(hf, r, double(float(t0)), double(float(t1)), hit, h.t,
                                reference_hit(hf, r, LD(float(t0)), LD(float(t1))), slope, st.ref_grazes, why)) {
                ADD_FAILURE() << f.name << ": " << describe(r) << " window [" << t0 << ", " << t1 << "]: " << why;
                ++failures;
            }
        }
        EXPECT_EQ(failures, 0) << f.name;
        EXPECT_LT(st.ref_grazes, st.ref_checked / 50 + 1) << f.name;
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
