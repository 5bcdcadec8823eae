// The SIMD heightfield traversal (Heightfield::intersect / occluded: a node's four children
// tested at once with SSE, only the ones that pass pushed) against the scalar node-at-a-time
// reference (intersect_reference / occluded_reference). Both compute the same float
// operations in the same order, so every answer must agree bit for bit: hit or miss, t,
// position, height and slopes. Rays: random from above at every angle up to 89.99 degrees,
// unnormalised and with huge tile offsets; rays starting on the surface in every direction
// (grazing included); rays along cell edges and through grid vertices; horizontal rays inside
// the slab; rays from below; short [tmin, tmax] windows. Fields: the battery's (odd sizes
// leave children missing at several levels) plus a larger map with tall relief.
#include <cstring>
#include "heightfield_test_util.h"

namespace {

bool same_bits(float a, float b) { return std::memcmp(&a, &b, sizeof a) == 0; }

struct SimdCase {
    Vec3 o, d;
    float tmin = 0.f, tmax = Infinity;
    int64_t ox = 0, oy = 0;
};

/// A random direction at polar angle theta from straight down (or up when `up`).
Vec3 direction(PCG32 &rng, double theta, bool up) {
    const double phi = 2 * kPi * rng.next_double();
    const double s = std::sin(theta), c = std::cos(theta);
    return Vec3(float(s * std::cos(phi)), float(s * std::sin(phi)), float(up ? c : -c));
}

double random_theta(PCG32 &rng) {
    const uint32_t k = rng.next_bounded(10);
    if (k == 0) return 89.99 * kPi / 180;                 // grazing
    if (k == 1) return (89.0 + rng.next_double()) * kPi / 180;
    if (k == 2) return 0.0;                                // vertical
    return std::acos(rng.next_double());                   // cosine-weighted
}

/// Rays of every kind listed in the file header over field `hf`.
std::vector<SimdCase> simd_cases(const Heightfield &hf, int n, uint64_t seed) {
    PCG32 rng(seed);
    const int W = hf.width(), H = hf.height();
    const float lo = hf.min_height(), hi = hf.max_height(), thick = std::max(hi - lo, 1e-3f);
    std::vector<SimdCase> v;
    for (int k = 0; k < n; ++k) {
        SimdCase c;
        const uint32_t kind = rng.next_bounded(6);
        float x = float(W * rng.next_double()), y = float(H * rng.next_double());
        if (kind == 0) {  // from above
            c.d = direction(rng, random_theta(rng), false);
            c.o = Vec3(x, y, hi + thick * float(rng.next_double()));
        } else if (kind == 1) {  // on the surface, any direction
            c.o = Vec3(x, y, hf.eval(x, y));
            c.d = direction(rng, random_theta(rng), rng.next_bounded(2) == 0);
        } else if (kind == 2) {  // along a cell edge (x or y an integer, that component of d zero)
            const bool along_y = rng.next_bounded(2) == 0;
            (along_y ? x : y) = float(int(along_y ? x : y));
            c.d = direction(rng, random_theta(rng), false);
            (along_y ? c.d.x : c.d.y) = 0.f;
            c.o = Vec3(x, y, hi + 0.1f * thick);
        } else if (kind == 3) {  // through a grid vertex, or along a diagonal from one
            c.o = Vec3(float(int(x)), float(int(y)), hi + 0.5f * thick);
            const float s = rng.next_bounded(2) ? 1.f : -1.f;
            c.d = rng.next_bounded(2) ? Vec3(0.f, 0.f, -1.f) : Vec3(s, rng.next_bounded(2) ? 1.f : -1.f, -0.2f * thick);
        } else if (kind == 4) {  // horizontal inside the slab
            c.o = Vec3(x, y, lo + thick * float(rng.next_double()));
            c.d = direction(rng, kPi / 2, false);
            c.d.z = 0.f;
        } else {  // from below, upwards
            c.o = Vec3(x, y, lo - thick * float(rng.next_double()));
            c.d = direction(rng, random_theta(rng), true);
        }
        // A quarter unnormalised; a quarter with huge tile offsets; a fifth with a window.
        if (rng.next_bounded(4) == 0) c.d = c.d * float(std::pow(10.0, 4 * rng.next_double() - 2));
        if (rng.next_bounded(4) == 0) {
            c.ox = int64_t(W) * (int64_t(rng.next_bounded(1u << 30)) - (1 << 29));
            c.oy = int64_t(H) * (int64_t(rng.next_bounded(1u << 30)) - (1 << 29));
        }
        if (rng.next_bounded(5) == 0) {
            c.tmin = float(rng.next_double() * 2 * thick / std::max(length(c.d), 1e-20f));
            c.tmax = c.tmin * float(1 + 4 * rng.next_double());
        }
        v.push_back(c);
    }
    return v;
}

/// Runs every case through both traversals; counts hits and returns the number of mismatches.
int compare_traversals(const Heightfield &hf, const std::vector<SimdCase> &cases, const std::string &name,
                       long &hits) {
    int bad = 0;
    for (const SimdCase &c : cases) {
        HeightfieldHit a, b;
        const bool ha = hf.intersect(c.o, c.d, c.tmin, c.tmax, a, c.ox, c.oy);
        const bool hb = hf.intersect_reference(c.o, c.d, c.tmin, c.tmax, b, c.ox, c.oy);
        const bool oa = hf.occluded(c.o, c.d, c.tmin, c.tmax, c.ox, c.oy);
        const bool ob = hf.occluded_reference(c.o, c.d, c.tmin, c.tmax, c.ox, c.oy);
        hits += ha;
        const bool same = ha == hb && oa == ob &&
                          (!ha || (same_bits(a.t, b.t) && same_bits(a.x, b.x) && same_bits(a.y, b.y) &&
                                   same_bits(a.h, b.h) && same_bits(a.dhdx, b.dhdx) && same_bits(a.dhdy, b.dhdy)));
        if (!same && ++bad <= 5)
            ADD_FAILURE() << name << ": o (" << c.o.x << ", " << c.o.y << ", " << c.o.z << ") d (" << c.d.x << ", "
                          << c.d.y << ", " << c.d.z << ") offsets " << c.ox << ", " << c.oy << " window [" << c.tmin
                          << ", " << c.tmax << "]: SIMD hit " << ha << " t " << a.t << " at (" << a.x << ", " << a.y << ") occluded " << oa
                          << ", reference hit " << hb << " t " << b.t << " at (" << b.x << ", " << b.y << ") occluded " << ob;
    }
    return bad;
}

}  // namespace

TEST(HeightfieldSimd, MatchesTheScalarReferenceBitForBit) {
    std::vector<Field> fields = battery_fields();
    fields.push_back({"sin256x256_tall", sinusoid_map(256, 256, 9), 40.f, 0.f});
    fields.push_back({"noise33x17", noise_map(33, 17, 10), 0.05f, 1.f});
    for (size_t f = 0; f < fields.size(); ++f) {
        const Heightfield hf(fields[f].map, fields[f].scale, fields[f].offset);
        const std::vector<SimdCase> cases = simd_cases(hf, 25000, 100 + f);
        long hits = 0;
        EXPECT_EQ(compare_traversals(hf, cases, fields[f].name, hits), 0) << fields[f].name;
        // The rays must exercise both answers.
        EXPECT_GT(hits, long(cases.size()) / 10) << fields[f].name;
        EXPECT_LT(hits, long(cases.size())) << fields[f].name;
    }
}
