// Spherical rectangle sampling (lights/spherical_rectangle.h): the solid angle equals the sum of
// its two triangles' (Van Oosterom-Strackee, an independent formula), and samples are uniform in
// solid angle: a chi-square test of the sample counts over a grid of the rectangle against the
// grid cells' solid angles.
#include <gtest/gtest.h>
#include <cmath>
#include <vector>
#include "lights/spherical_rectangle.h"
#include "sampling/rng.h"

using namespace meso;

namespace {

double rect_solid_angle(Vec3 o, Vec3 s, Vec3 ex, Vec3 ey) {
    return sphtri::solid_angle(o, s, s + ex, s + ex + ey) + sphtri::solid_angle(o, s, s + ex + ey, s + ey);
}

struct Config {
    Vec3 o, s, ex, ey;
};

}  // namespace

TEST(SphericalRectangle, SolidAngleMatchesTwoTriangles) {
    const Config cases[] = {
        {{0, 0, 0}, {-0.5f, -0.5f, 1}, {1, 0, 0}, {0, 1, 0}},                   // centred, facing
        {{0.3f, 2, -1}, {1, -1, 0.5f}, {0, 3, 0}, {0, 0, -2}},                   // off-axis, other orientation
        {{0, 0, 0}, {4, 5, 0.01f}, {0.2f, 0, 0}, {0, 0.1f, 0}},                  // far and grazing
        {{0, 0, 0}, {-10, -10, 0.05f}, {20, 0, 0}, {0, 20, 0}},                  // nearly a hemisphere
        {{0, 0, 0}, {-0.5f, -0.5f, -1}, {1, 0, 0}, {0, 1, 0}},                   // below (z flipped)
    };
    for (const Config &c : cases) {
        sphrect::SphericalRectangle r(c.o, c.s, c.ex, c.ey);
        ASSERT_TRUE(r.valid);
        EXPECT_NEAR(r.S, rect_solid_angle(c.o, c.s, c.ex, c.ey), 1e-6 * r.S + 1e-9);
    }
    EXPECT_FALSE(sphrect::SphericalRectangle({0, 0, 0}, {-1, -1, 0}, {2, 0, 0}, {0, 2, 0}).valid);  // in its plane
}

TEST(SphericalRectangle, SamplesAreUniformInSolidAngle) {
    const Config cases[] = {
        {{0.2f, -0.1f, 0}, {-0.5f, -0.5f, 0.7f}, {1, 0, 0}, {0, 1, 0}},
        {{0, 0, 0}, {0.5f, -2, 0.3f}, {2, 0, 0}, {0, 3, 0}},  // off to one side, grazing
    };
    PCG32 rng(7);
    for (const Config &c : cases) {
        sphrect::SphericalRectangle r(c.o, c.s, c.ex, c.ey);
        ASSERT_TRUE(r.valid);
        const int G = 8, N = 200000;
        std::vector<double> obs(G * G, 0.0), expect(G * G, 0.0);
        const Vec3 ux = c.ex * (1.f / G), uy = c.ey * (1.f / G);
        for (int j = 0; j < G; ++j)
            for (int i = 0; i < G; ++i)
                expect[j * G + i] = N * rect_solid_angle(c.o, c.s + ux * float(i) + uy * float(j), ux, uy) / r.S;
        const double lx = length(c.ex), ly = length(c.ey);
        for (int n = 0; n < N; ++n) {
            Vec3 p;
            ASSERT_TRUE(r.sample({rng.next_float(), rng.next_float()}, p));
            const Vec3 d = p - c.s;
            const double a = dot(d, c.ex) / (lx * lx), b = dot(d, c.ey) / (ly * ly);
            ASSERT_GE(a, -1e-5);
            ASSERT_LE(a, 1 + 1e-5);
            ASSERT_NEAR(dot(d, cross(c.ex, c.ey)), 0.0, 1e-4 * lx * ly);  // on the rectangle
            obs[std::min(G - 1, int(b * G)) * G + std::min(G - 1, int(a * G))] += 1;
        }
        double chi2 = 0;
        for (int k = 0; k < G * G; ++k) chi2 += (obs[k] - expect[k]) * (obs[k] - expect[k]) / expect[k];
        // 63 degrees of freedom: the 1e-4 upper quantile is about 115.
        EXPECT_LT(chi2, 115.0);
    }
}
