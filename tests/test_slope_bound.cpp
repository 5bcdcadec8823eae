// The local shadow-slope bound of the prefilter's estimators (prefilter/slope_bound.h): it
// never clears a direction that the heightfield traversal finds blocked, and it clears many
// more than the global slope where the map has flat regions.
#include <gtest/gtest.h>
#include <cmath>
#include <map>
#include <string>
#include "geometry/heightfield.h"
#include "geometry/heightmap_gen.h"
#include "prefilter/micro_vertex.h"
#include "prefilter/slope_bound.h"
#include "sampling/rng.h"

using namespace meso;
using namespace meso::prefilter;

namespace {

/// Flat ground with raised square plateaus (steep ramps of `ramp` cells), a w x h map.
HeightMap plateaus(int w, int h, float height, int ramp) {
    HeightMap m(w, h, 0.f);
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < w; ++i) {
            // Distance into the plateau [w/4, 3w/4) x [h/4, 3h/4) and one small block.
            const int di = std::min(i - w / 4, 3 * w / 4 - 1 - i), dj = std::min(j - h / 4, 3 * h / 4 - 1 - j);
            const int d = std::min(di, dj);
            float v = d < 0 ? 0.f : height * std::min(1.f, float(d + 1) / float(ramp));
            if (i >= w / 16 && i < w / 16 + 3 && j >= h / 16 && j < h / 16 + 3) v = 0.5f * height;
            m.at(i, j) = v;
        }
    return m;
}

struct Counts {
    int rays = 0, cleared = 0, cleared_global = 0, reached = 0, violations = 0;
};

/// Random origins just above the surface, anywhere in [-3W, 3W] x [-3H, 3H], and
/// random upward directions: every direction the bound clears is unoccluded by the traversal,
/// and the others get the same answer from a shadow ray that stops at reach().
Counts check(const Heightfield &hf, int origins, uint64_t seed) {
    const SlopeBound bound(hf);
    // The global slope: |∇h| of the bilinear patches, largest at a cell corner (eval's derivatives
    // just inside each corner).
    double g = 0;
    for (int j = 0; j < hf.height(); ++j)
        for (int i = 0; i < hf.width(); ++i)
            for (double cx : {1e-7, 1.0 - 1e-7})
                for (double cy : {1e-7, 1.0 - 1e-7}) {
                    float dx, dy;
                    hf.eval(i + cx, j + cy, dx, dy);
                    g = std::max(g, std::hypot(double(dx), double(dy)));
                }
    EXPECT_NEAR(bound.global(), g, 1e-4 * (1.0 + g));
    PCG32 rng(seed, 7);
    Counts c;
    for (int n = 0; n < origins; ++n) {
        const double x = (rng.next_double() * 6.0 - 3.0) * hf.width(), y = (rng.next_double() * 6.0 - 3.0) * hf.height();
        const double fx = std::floor(x), fy = std::floor(y);
        // Above the surface by at least the estimators' spawn offset (micro_vertex.h): a ray that
        // starts exactly on it may meet it again at t ~ 0 by round-off.
        const float hs = hf.eval(x, y);
        const float z0 = hs + 1e-4f * (1.f + std::abs(hs)) + (n % 3 == 0 ? 0.f : 1e-3f * float(rng.next_double()));
        const SlopeBound::Local local = bound.local(x, y, z0);
        const double s = local.slope;
        EXPECT_EQ(s, bound.at(x, y, z0));
        EXPECT_TRUE(std::isfinite(s));
        EXPECT_GE(s, 0.0);
        EXPECT_LE(s, bound.global());
        for (int d = 0; d < 64; ++d) {
            const double z = rng.next_double(), phi = 2.0 * M_PI * rng.next_double(), r = std::sqrt(1.0 - z * z);
            const Vec3 w(float(r * std::cos(phi)), float(r * std::sin(phi)), float(z));
            ++c.rays;
            if (detail::unoccluded_by_slope(w, bound.global())) ++c.cleared_global;
            const Vec3 o(float(x - fx), float(y - fy), z0);
            if (!detail::unoccluded_by_slope(w, s)) {
                // Not cleared: the shadow ray may stop at reach() with the same answer.
                const float t = SlopeBound::reach(local, w);
                if (t < Infinity) ++c.reached;
                const bool full = hf.occluded(o, w, 0.f, Infinity, int64_t(fx), int64_t(fy));
                if (full != hf.occluded(o, w, 0.f, t, int64_t(fx), int64_t(fy))) {
                    ++c.violations;
                    ADD_FAILURE() << "reach " << t << " changes the answer: origin (" << x << ", " << y << ", " << z0
                                  << "), w (" << w.x << ", " << w.y << ", " << w.z << ")";
                }
                continue;
            }
            ++c.cleared;
            if (hf.occluded(o, w, 0.f, Infinity, int64_t(fx), int64_t(fy))) {
                ++c.violations;
                ADD_FAILURE() << "cleared but occluded: origin (" << x << ", " << y << ", " << z0 << "), w (" << w.x
                              << ", " << w.y << ", " << w.z << "), bound " << s;
                if (c.violations > 5) return c;
            }
        }
    }
    return c;
}

}  // namespace

TEST(SlopeBound, NeverClearsAnOccludedDirection) {
    // fBm (rough everywhere), plateaus with steep ramps, a non-square and an odd-sized map
    // (only level 0 then), at two height scales.
    std::map<std::string, std::string> p{{"size", "64"}, {"amplitude", "0.1"}, {"seed", "3"}};
    const HeightMap fbm = generate_height_map("fbm", p).height;
    for (float scale : {4.f, 40.f}) {
        for (const HeightMap &m : {fbm, plateaus(64, 64, 1.f, 2), plateaus(64, 32, 1.f, 1), plateaus(45, 45, 1.f, 3)}) {
            const Heightfield hf(m, scale, 0.f);
            const Counts c = check(hf, 2000, uint64_t(m.width * 131 + m.height) + uint64_t(scale));
            EXPECT_EQ(c.violations, 0) << m.width << " x " << m.height << " scale " << scale;
            EXPECT_GE(c.cleared, c.cleared_global);
        }
    }
}

TEST(SlopeBound, ClearsFarMoreThanTheGlobalSlopeOnPlateaus) {
    const Heightfield hf(plateaus(128, 128, 1.f, 2), 8.f, 0.f);
    const Counts c = check(hf, 400, 11);
    EXPECT_EQ(c.violations, 0);
    std::printf("plateaus: cleared %d of %d directions, the global slope %d; %d shortened\n", c.cleared, c.rays,
                c.cleared_global, c.reached);
    EXPECT_GT(c.reached, (c.rays - c.cleared) / 4);
    // The ramps are 4 height units a cell: the global slope clears almost nothing; on the flat
    // ground and the plateau's top most directions clear.
    EXPECT_GT(c.cleared, 4 * c.cleared_global + c.rays / 4);
}

TEST(SlopeBound, DegenerateInput) {
    // A flat map: every upward direction clears; an origin below the surface gets the global
    // slope; non-finite coordinates give the global slope too.
    const Heightfield flat(HeightMap(16, 16, 0.5f), 1.f, 0.f);
    const SlopeBound fb(flat);
    EXPECT_EQ(fb.global(), 0.0);
    EXPECT_EQ(fb.at(3.3, -7.1, 0.5f), 0.0);
    const Heightfield hf(plateaus(32, 32, 1.f, 2), 5.f, 0.f);
    const SlopeBound b(hf);
    EXPECT_EQ(b.at(16.5, 16.5, hf.eval(16.5, 16.5) - 0.01f), b.global());
    EXPECT_EQ(b.at(std::nan(""), 1.0, 10.f), b.global());
    EXPECT_EQ(b.at(1.0, std::numeric_limits<double>::infinity(), 10.f), b.global());
    // High above the whole map: nothing can shadow it.
    EXPECT_EQ(b.at(3.0, 4.0, 100.f), 0.0);
    EXPECT_GT(b.memory_bytes(), size_t(32 * 32 * 4));
}
