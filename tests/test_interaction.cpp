// SurfaceInteraction's ray spawning: the branch-free origin offset against the scalar
// pbrt-v4 formulation it replaces, bit for bit, including zeros, infinities, denormals and
// offsets of either sign.
#include <gtest/gtest.h>
#include <cstring>
#include <limits>
#include "core/math.h"
#include "geometry/interaction.h"
#include "sampling/rng.h"

namespace meso {
namespace {

/// The scalar formulation (pbrt-v4 OffsetRayOrigin with next_float_up per component).
Vec3 offset_origin_reference(const SurfaceInteraction &si, Vec3 w) {
    float d = si.p_error * (std::abs(si.ng.x) + std::abs(si.ng.y) + std::abs(si.ng.z));
    Vec3 offset = si.ng * d;
    if (dot(w, si.ng) < 0.f) offset = -offset;
    Vec3 po = si.p + offset;
    for (int i = 0; i < 3; ++i) {
        if (offset[i] > 0.f) po[i] = next_float_up(po[i]);
        else if (offset[i] < 0.f) po[i] = -next_float_up(-po[i]);
    }
    return po;
}

uint32_t bits(float v) {
    uint32_t b;
    std::memcpy(&b, &v, 4);
    return b;
}

void expect_same_bits(Vec3 a, Vec3 b) {
    EXPECT_EQ(bits(a.x), bits(b.x)) << a.x << " vs " << b.x;
    EXPECT_EQ(bits(a.y), bits(b.y)) << a.y << " vs " << b.y;
    EXPECT_EQ(bits(a.z), bits(b.z)) << a.z << " vs " << b.z;
}

TEST(SpawnRay, OffsetOriginMatchesTheScalarFormulationBitForBit) {
    const float inf = std::numeric_limits<float>::infinity(), den = std::numeric_limits<float>::denorm_min();
    const float specials[] = {0.f, -0.f, den, -den, 1e-30f, -1e-30f, 1.f, -1.f, 3.5e5f, -3.5e5f,
                              std::numeric_limits<float>::max(), -std::numeric_limits<float>::max(), inf, -inf};
    const Vec3 normals[] = {Vec3(1, 0, 0), Vec3(0, -1, 0), Vec3(0, 0, 1), normalize(Vec3(1, -2, 3)),
                            normalize(Vec3(-1e-20f, 1, 1e-20f))};
    const Vec3 dirs[] = {Vec3(1, 1, 1), Vec3(-1, -1, -1), Vec3(0, 0, 0), Vec3(-3, 2, 0.5f)};
    const float errors[] = {0.f, den, 1e-7f, 1e-3f, 10.f};
    int cases = 0;
    for (float px : specials)
        for (float pz : specials)
            for (const Vec3 &n : normals)
                for (const Vec3 &w : dirs)
                    for (float e : errors) {
                        SurfaceInteraction si;
                        si.p = Vec3(px, 0.25f, pz);
                        si.ng = n;
                        si.p_error = e;
                        expect_same_bits(si.offset_origin(w), offset_origin_reference(si, w));
                        ++cases;
                    }
    // Random points at all scales, random normals and directions.
    PCG32 rng(7);
    for (int i = 0; i < 200000; ++i) {
        SurfaceInteraction si;
        auto coord = [&] { return (rng.next_float() - 0.5f) * std::ldexp(1.f, int(rng.next_u32() % 60) - 30); };
        si.p = Vec3(coord(), coord(), coord());
        si.ng = normalize(Vec3(rng.next_float() - 0.5f, rng.next_float() - 0.5f, rng.next_float() - 0.5f));
        si.p_error = 4.2e-7f * std::max({std::abs(si.p.x), std::abs(si.p.y), std::abs(si.p.z)}) + 1e-9f;
        const Vec3 w(rng.next_float() - 0.5f, rng.next_float() - 0.5f, rng.next_float() - 0.5f);
        expect_same_bits(si.offset_origin(w), offset_origin_reference(si, w));
        ++cases;
        if (HasFailure()) break;
    }
    EXPECT_GT(cases, 200000);
}

TEST(SpawnRay, OriginLeavesThePlaneOnTheSideOfTheDirection) {
    // A point on the plane z = c: the spawned origin lies strictly on w's side, at every scale.
    for (float c : {0.f, 1e-20f, 1.f, -3.f, 1e6f}) {
        SurfaceInteraction si;
        si.p = Vec3(0.5f, -0.25f, c);
        si.ng = Vec3(0, 0, 1);
        si.p_error = 4.2e-7f * std::max(1.f, std::abs(c)) + 1e-9f;
        EXPECT_GT(si.spawn_ray(Vec3(0, 0.6f, 0.8f)).o.z, c);
        EXPECT_LT(si.spawn_ray(Vec3(0, 0.6f, -0.8f)).o.z, c);
        const Ray shadow = si.spawn_ray_to(Vec3(1, 1, c + 2.f));
        EXPECT_GT(shadow.o.z, c);
        EXPECT_LT(shadow.tmax, length(Vec3(1, 1, c + 2.f) - shadow.o));
    }
}

}  // namespace
}  // namespace meso
