// Area lights: triangle meshes in both sampling modes and analytic spheres against Lambert's
// polygon irradiance and for pdf consistency; rectangles sampled as one spherical rectangle;
// textured emitters (at hits, at light samples, against Lambert and against emitters of
// constant radiance). Fixed seeds; tolerances are 5 standard errors of the estimator unless
// stated otherwise. (Moved out of test_lights.cpp, which keeps the other light types.)
#include <gtest/gtest.h>
#include <array>
#include <nlohmann/json.hpp>
#include "lights/spherical_triangle.h"
#include "sampling/rng.h"
#include "light_test_util.h"
#include "render_test_util.h"
#include "scratch_dir.h"

using namespace meso;
using namespace meso::test;

namespace {

/// Per-process scratch directory, removed at exit.
std::string tmp_dir() { return meso::test::scratch_dir("meso_test_area_light"); }

/// Lambert's formula for the irradiance at p (normal n) from a uniform polygon of radiance
/// L entirely above the horizon: E = L/2 |sum_i theta_i n·(r_i x r_i+1)/|r_i x r_i+1||.
double lambert_irradiance(Vec3 p, Vec3 n, const std::vector<Vec3> &verts, double L) {
    using namespace sphtri;
    double sum = 0;
    for (size_t i = 0; i < verts.size(); ++i) {
        DVec3 r0 = normalize(DVec3(verts[i]) - DVec3(p)), r1 = normalize(DVec3(verts[(i + 1) % verts.size()]) - DVec3(p));
        DVec3 c = cross(r0, r1);
        double theta = std::atan2(length(c), dot(r0, r1));
        sum += theta * dot(DVec3(n), normalize(c));
    }
    return 0.5 * L * std::abs(sum);
}

/// Ray/triangle intersection in double (Moller-Trumbore); returns t > 0 or -1.
double intersect_triangle(Vec3 o, Vec3 d, Vec3 a, Vec3 b, Vec3 c) {
    using namespace sphtri;
    DVec3 e1 = DVec3(b) - DVec3(a), e2 = DVec3(c) - DVec3(a), dd(d);
    DVec3 pv = cross(dd, e2);
    double det = dot(e1, pv);
    if (std::abs(det) < 1e-300) return -1;
    DVec3 tv = DVec3(o) - DVec3(a);
    double u = dot(tv, pv) / det;
    if (u < 0 || u > 1) return -1;
    DVec3 qv = cross(tv, e1);
    double v = dot(dd, qv) / det;
    if (v < 0 || u + v > 1) return -1;
    double t = dot(e2, qv) / det;
    return t > 0 ? t : -1;
}

/// A triangle (ordered so that it emits towards the origin) above the xy-plane.
std::vector<Vec3> test_triangle() {
    std::vector<Vec3> v = {{-1.f, -0.5f, 2.f}, {1.f, -0.3f, 2.2f}, {0.2f, 1.f, 1.8f}};
    Vec3 n = cross(v[1] - v[0], v[2] - v[0]);
    if (dot(n, v[0]) > 0) std::swap(v[1], v[2]);  // normal must face the origin
    return v;
}

/// Reference points: (position, receiver normal), placed relative to the light's plane
/// (centroid c, emitting normal n, an in-plane direction e) so that every point is on the
/// emitting side and sees all of the light above its horizon.
struct RefPoint {
    const char *name;
    Vec3 p, n;
};
std::vector<RefPoint> ref_points(const TestMeshShape &shape) {
    const TriangleMesh &m = *shape.mesh();
    Vec3 c(0, 0, 0);
    for (auto &v : m.positions) c += v;
    c = c / float(m.positions.size());
    Vec3 n = shape.normal(0);
    Vec3 e = normalize(m.positions[0] - c);
    e = normalize(e - n * dot(n, e));
    Vec3 far = c + n * 80.f + e * 30.f;
    return {
        {"near", c + n * 2.f, -n},
        {"close", c + n * 0.3f + e * 0.2f, -n},
        {"far", far, normalize(c - far)},             // Omega < 3e-4 sr: area fallback
        {"grazing", c + e * 4.f + n * 0.05f, -e},     // nearly in the light's plane
        {"grazing_far", c + e * 300.f + n * 0.1f, -e} // both at once
    };
}

/// Irradiance estimate from light sampling (no visibility); returns mean and std error.
MeanStd estimate_irradiance(const Light &light, Vec3 p, Vec3 n, int N, uint64_t seed) {
    PCG32 rng(seed);
    double s = 0, s2 = 0;
    LightSampleContext ctx{p, n};
    for (int i = 0; i < N; ++i) {
        LightSample ls;
        double f = 0;
        if (light.sample(ctx, {rng.next_float(), rng.next_float()}, ls)) {
            EXPECT_TRUE(std::isfinite(ls.pdf) && ls.pdf > 0.f);
            EXPECT_TRUE(ls.L.is_finite());
            f = ls.L.average() * std::max(0.f, dot(ls.wi, n)) / ls.pdf;
        }
        s += f;
        s2 += f * f;
    }
    return mean_std(s, s2, N);
}

/// Monte Carlo estimate of ∫ pdf dω over the directions that hit the mesh, with directions
/// uniform in a cone that contains it. `hit_fraction` returns the share of directions
/// that hit (the estimate is only meaningful when it is not tiny).
MeanStd integrate_pdf_cone(const Light &light, const TestMeshShape &shape, Vec3 p, int N, uint64_t seed,
                           double &hit_fraction) {
    // Double precision throughout: for tiny cones a float cos(theta) is quantised into a few
    // rings, which is far from uniform on the scale of a sliver seen edge-on.
    using namespace sphtri;
    const TriangleMesh &m = *shape.mesh();
    DVec3 c, o(p);
    for (auto &v : m.positions) c = c + DVec3(v);
    DVec3 axis = normalize(c * (1.0 / m.positions.size()) - o);
    double one_minus_cos = 0;  // 1 - cos of the widest vertex, computed without cancellation
    for (auto &v : m.positions) {
        DVec3 d = normalize(DVec3(v) - o);
        one_minus_cos = std::max(one_minus_cos, 0.5 * dot(d - axis, d - axis));
    }
    one_minus_cos = std::min(2.0, one_minus_cos * 1.05);  // a little margin
    DVec3 s_ax = gram_schmidt(std::abs(axis.x) < 0.9 ? DVec3(1, 0, 0) : DVec3(0, 1, 0), axis);
    DVec3 t_ax = cross(axis, s_ax);
    double cone_pdf = 1.0 / (2 * M_PI * one_minus_cos);
    PCG32 rng(seed);
    double s = 0, s2 = 0;
    long hits = 0;
    for (int i = 0; i < N; ++i) {
        double omc = rng.next_double() * one_minus_cos;  // 1 - cos(theta), uniform
        double sin_t = std::sqrt(std::max(0.0, omc * (2 - omc))), phi = 2 * M_PI * rng.next_double();
        DVec3 wd = (1 - omc) * axis + (sin_t * std::cos(phi)) * s_ax + (sin_t * std::sin(phi)) * t_ax;
        Vec3 w(float(wd.x), float(wd.y), float(wd.z));
        double best = Infinity;
        size_t prim = 0;
        for (size_t t = 0; t < m.triangle_count(); ++t) {
            double th = intersect_triangle(p, w, shape.vertex(t, 0), shape.vertex(t, 1), shape.vertex(t, 2));
            if (th > 0 && th < best) best = th, prim = t;
        }
        double f = 0;
        if (best < Infinity) {
            ++hits;
            LightHit hit{p + w * float(best), shape.normal(prim), uint32_t(prim)};
            f = light.pdf(LightSampleContext{p, Vec3()}, w, hit) / cone_pdf;
        }
        s += f;
        s2 += f * f;
    }
    hit_fraction = double(hits) / N;
    return mean_std(s, s2, N);
}

/// The same integral written over the light's surface, ∫ pdf(ω(y)) |cos θ_y| / d^2 dA(y),
/// with points y uniform by area (works for slivers seen edge-on, where a cone of
/// directions almost never hits). Planar lights only (y is then the first hit along ω).
MeanStd integrate_pdf_area(const Light &light, const TestMeshShape &shape, Vec3 p, int N, uint64_t seed) {
    const TriangleMesh &m = *shape.mesh();
    double total = 0;
    std::vector<double> cdf;
    for (size_t t = 0; t < m.triangle_count(); ++t) cdf.push_back(total += shape.tri_area(t));
    PCG32 rng(seed);
    double s = 0, s2 = 0;
    for (int i = 0; i < N; ++i) {
        double ut = rng.next_double() * total;
        size_t t = std::min(cdf.size() - 1, size_t(std::lower_bound(cdf.begin(), cdf.end(), ut) - cdf.begin()));
        Vec2 b = square_to_uniform_triangle({rng.next_float(), rng.next_float()});
        Vec3 y = shape.vertex(t, 0) * b.x + shape.vertex(t, 1) * b.y + shape.vertex(t, 2) * (1 - b.x - b.y);
        Vec3 d = y - p;
        double d2 = length_squared(d);
        Vec3 w = d / std::sqrt(float(d2));
        double f = light.pdf(LightSampleContext{p, Vec3()}, w, LightHit{y, shape.normal(t), uint32_t(t)}) *
                   absdot(shape.normal(t), w) / d2 * total;
        s += f;
        s2 += f * f;
    }
    return mean_std(s, s2, N);
}

}  // namespace

// --------------------------------------------------------------------------------------
// Area lights

TEST(AreaLight, SphericalTriangleIsUniform) {
    // Fractions of samples in the 4 midpoint sub-triangles = their share of the solid angle.
    auto v = test_triangle();
    Vec3 p(0.1f, 0.f, 0.f);
    Vec3 m01 = (v[0] + v[1]) * 0.5f, m12 = (v[1] + v[2]) * 0.5f, m20 = (v[2] + v[0]) * 0.5f;
    std::array<std::array<Vec3, 3>, 4> subs = {{{v[0], m01, m20}, {m01, v[1], m12}, {m20, m12, v[2]}, {m01, m12, m20}}};
    double omega = sphtri::solid_angle(p, v[0], v[1], v[2]);
    double sum_sub = 0;
    for (auto &s : subs) sum_sub += sphtri::solid_angle(p, s[0], s[1], s[2]);
    EXPECT_NEAR(sum_sub, omega, 1e-6 * omega);  // midpoints are rounded to float
    const int N = 200000;
    std::array<int, 4> counts{};
    PCG32 rng(11);
    for (int i = 0; i < N; ++i) {
        double b[3];
        ASSERT_TRUE(sphtri::sample(p, v[0], v[1], v[2], {rng.next_float(), rng.next_float()}, b));
        int k = b[0] > 0.5 ? 0 : b[1] > 0.5 ? 1 : b[2] > 0.5 ? 2 : 3;
        counts[k]++;
    }
    for (int k = 0; k < 4; ++k) {
        double pk = sphtri::solid_angle(p, subs[k][0], subs[k][1], subs[k][2]) / omega;
        EXPECT_NEAR(counts[k], N * pk, 5 * std::sqrt(N * pk * (1 - pk))) << "sub-triangle " << k;
    }
}

TEST(AreaLight, TriangleSamplePdfMatchesPdf) {
    TestMeshShape shape(make_mesh(test_triangle(), {0, 1, 2}));
    for (const char *mode : {"solid_angle", "area"}) {
        auto l = make_light({{"type", "area"}, {"radiance", 2}, {"sampling", mode}});
        l->set_shape(&shape);
        PCG32 rng(3);
        for (auto &rp : ref_points(shape)) {
            for (int i = 0; i < 2000; ++i) {
                LightSample ls;
                LightSampleContext ctx{rp.p, rp.n};
                if (!l->sample(ctx, {rng.next_float(), rng.next_float()}, ls)) continue;
                ASSERT_FALSE(ls.delta);
                LightHit hit{rp.p + ls.wi * ls.dist, shape.normal(0), 0};
                float pdf = l->pdf(ctx, ls.wi, hit);
                ASSERT_NEAR(ls.pdf, pdf, 2e-4f * pdf) << mode << " " << rp.name;
                // The sampled point lies on the triangle's plane.
                EXPECT_NEAR(dot(hit.p - shape.vertex(0, 0), shape.normal(0)), 0.f, 1e-4f * (1 + ls.dist));
                EXPECT_FLOAT_EQ(ls.L.r, l->eval(hit, -ls.wi).r);
            }
        }
    }
}

TEST(AreaLight, SolidAngleModeIsUniformNearAndAreaFar) {
    TestMeshShape shape(make_mesh(test_triangle(), {0, 1, 2}));
    auto l = make_light({{"type", "area"}, {"sampling", "solid_angle"}});
    l->set_shape(&shape);
    const TriangleMesh &m = *shape.mesh();
    // Near: pdf = 1 / Omega for every direction.
    Vec3 p(0.1f, 0, 0);
    double omega = sphtri::solid_angle(p, m.positions[0], m.positions[1], m.positions[2]);
    ASSERT_GT(omega, 3e-4);
    PCG32 rng(8);
    for (int i = 0; i < 100; ++i) {
        LightSample ls;
        ASSERT_TRUE(l->sample({p, Vec3()}, {rng.next_float(), rng.next_float()}, ls));
        EXPECT_NEAR(ls.pdf, 1.0 / omega, 1e-5 / omega);
    }
    // Far: Omega < 3e-4 sr, so area sampling: pdf = d^2 / (A |cos|).
    Vec3 q(30.f, -20.f, -80.f);
    ASSERT_LT(sphtri::solid_angle(q, m.positions[0], m.positions[1], m.positions[2]), 3e-4);
    for (int i = 0; i < 100; ++i) {
        LightSample ls;
        ASSERT_TRUE(l->sample({q, Vec3()}, {rng.next_float(), rng.next_float()}, ls));
        double expect = double(ls.dist) * ls.dist / (shape.tri_area(0) * absdot(shape.normal(0), ls.wi));
        EXPECT_NEAR(ls.pdf, expect, 1e-4 * expect);
    }
}

TEST(AreaLight, PdfIntegratesToOne) {
    // One triangle and a two-triangle rectangle; ∫ pdf dω = 1 over the light's solid angle.
    TestMeshShape tri(make_mesh(test_triangle(), {0, 1, 2}));
    // Rectangle [-1,1] x [-0.5,0.5] at z = 2 facing down (-z), two triangles.
    TestMeshShape rect(make_mesh({{-1, -0.5f, 2}, {1, -0.5f, 2}, {1, 0.5f, 2}, {-1, 0.5f, 2}}, {0, 2, 1, 0, 3, 2}));
    ASSERT_LT(rect.normal(0).z, 0.f);
    for (const TestMeshShape *shape : {&tri, &rect}) {
        for (const char *mode : {"solid_angle", "area"}) {
            auto l = make_light({{"type", "area"}, {"sampling", mode}});
            l->set_shape(shape);
            uint64_t seed = 100;
            for (auto &rp : ref_points(*shape)) {
                double hit_fraction;
                MeanStd r = integrate_pdf_cone(*l, *shape, rp.p, 40000, seed++, hit_fraction);
                // Directions: meaningful where a fair share of the cone hits the light (the
                // edge-on sliver of "grazing_far" is covered by the area form below).
                if (hit_fraction > 0.005)
                    EXPECT_NEAR(r.mean, 1.0, 5 * r.stderr_ + 1e-4) << mode << " " << rp.name << " " << shape->primitive_count();
                else
                    EXPECT_STREQ(rp.name, "grazing_far") << hit_fraction;
                r = integrate_pdf_area(*l, *shape, rp.p, 40000, seed++);
                EXPECT_NEAR(r.mean, 1.0, 5 * r.stderr_ + 1e-4) << mode << " " << rp.name << " " << shape->primitive_count();
            }
        }
    }
}

TEST(AreaLight, IrradianceMatchesLambert) {
    auto v = test_triangle();
    TestMeshShape tri(make_mesh(v, {0, 1, 2}));
    std::vector<Vec3> rv = {{-1, -0.5f, 2}, {1, -0.5f, 2}, {1, 0.5f, 2}, {-1, 0.5f, 2}};
    TestMeshShape rect(make_mesh(rv, {0, 2, 1, 0, 3, 2}));
    struct Case {
        const TestMeshShape *shape;
        std::vector<Vec3> poly;
    };
    for (const Case &c : {Case{&tri, v}, Case{&rect, rv}}) {
        for (const char *mode : {"solid_angle", "area"}) {
            auto l = make_light({{"type", "area"}, {"radiance", 1.5}, {"sampling", mode}});
            l->set_shape(c.shape);
            uint64_t seed = 7;
            for (auto &rp : ref_points(*c.shape)) {
                double ref = lambert_irradiance(rp.p, rp.n, c.poly, 1.5);
                MeanStd e = estimate_irradiance(*l, rp.p, rp.n, 20000, seed++);
                ASSERT_TRUE(std::isfinite(e.mean) && std::isfinite(ref));
                // 5 standard errors, with a float-precision floor for near-zero-variance cases.
                EXPECT_NEAR(e.mean, ref, 5 * e.stderr_ + 1e-4 * ref) << mode << " " << rp.name;
            }
        }
    }
}

TEST(AreaLight, OneSidedTwoSidedAndPower) {
    TestMeshShape rect(make_mesh({{-1, -0.5f, 2}, {1, -0.5f, 2}, {1, 0.5f, 2}, {-1, 0.5f, 2}}, {0, 2, 1, 0, 3, 2}));
    auto one = make_light({{"type", "area"}, {"radiance", {1, 2, 3}}});
    auto two = make_light({{"type", "area"}, {"radiance", {1, 2, 3}}, {"two_sided", true}});
    one->set_shape(&rect);
    two->set_shape(&rect);
    LightHit hit{Vec3(0, 0, 2), Vec3(0, 0, -1), 0};
    EXPECT_FLOAT_EQ(one->eval(hit, Vec3(0, 0, -1)).g, 2.f);
    EXPECT_EQ(one->eval(hit, Vec3(0, 0, 1)).g, 0.f);
    EXPECT_FLOAT_EQ(two->eval(hit, Vec3(0, 0, 1)).g, 2.f);
    EXPECT_NEAR(one->power(), Pi * 2 * 2, 1e-4);
    EXPECT_NEAR(two->power(), 2 * Pi * 2 * 2, 1e-4);
    // From above (behind the emitting side) a one-sided light gives nothing; two-sided does.
    LightSample ls;
    PCG32 rng(1);
    for (int i = 0; i < 100; ++i) {
        Vec2 u(rng.next_float(), rng.next_float());
        EXPECT_FALSE(one->sample({Vec3(0.2f, 0, 3), Vec3(0, 0, -1)}, u, ls));
        ASSERT_TRUE(two->sample({Vec3(0.2f, 0, 3), Vec3(0, 0, -1)}, u, ls));
        EXPECT_FLOAT_EQ(ls.L.b, 3.f);
    }
    // A point in the light's plane: no NaN, either no sample or a finite one.
    for (const char *mode : {"solid_angle", "area"}) {
        auto l = make_light({{"type", "area"}, {"sampling", mode}, {"two_sided", true}});
        l->set_shape(&rect);
        for (int i = 0; i < 100; ++i) {
            Vec2 u(rng.next_float(), rng.next_float());
            for (Vec3 p : {Vec3(3, 0, 2), Vec3(0.3f, 0.1f, 2)}) {
                if (l->sample({p, Vec3()}, u, ls)) {
                    EXPECT_TRUE(std::isfinite(ls.pdf) && ls.L.is_finite());
                }
            }
        }
    }
    // Degenerate (zero-area) triangles are never sampled and have pdf 0.
    TestMeshShape degen(make_mesh({{-1, -1, 2}, {1, -1, 2}, {0, 1, 2}, {5, 5, 2}}, {0, 2, 1, 3, 3, 3}));
    auto l = make_light({{"type", "area"}, {"two_sided", true}});
    l->set_shape(&degen);
    EXPECT_EQ(l->pdf({Vec3(0, 0, 0), Vec3()}, Vec3(0, 0, 1), LightHit{Vec3(5, 5, 2), Vec3(0, 0, 1), 1}), 0.f);
    for (int i = 0; i < 100; ++i) {
        ASSERT_TRUE(l->sample({Vec3(0, 0, 0), Vec3()}, {rng.next_float(), rng.next_float()}, ls));
        EXPECT_TRUE(std::isfinite(ls.pdf));
    }
    EXPECT_EQ(light_error({{"type", "area"}, {"sampling", "cosine"}}),
              "lights[0].sampling: expected \"solid_angle\" or \"area\", got \"cosine\"");
}

TEST(AreaLight, SphereIrradianceAndPdf) {
    // A sphere of radius 1 at distance 3 seen from a point facing it: E = pi L (R/d)^2.
    TestSphereShape sphere(Vec3(0, 0, 3), 1.f);
    auto l = make_light({{"type", "area"}, {"radiance", 2}});  // solid_angle requested; sphere uses area
    l->set_shape(&sphere);
    MeanStd e = estimate_irradiance(*l, Vec3(0, 0, 0), Vec3(0, 0, 1), 40000, 21);
    EXPECT_NEAR(e.mean, Pi * 2 / 9, 5 * e.stderr_);
    PCG32 rng(4);
    for (int i = 0; i < 1000; ++i) {
        LightSample ls;
        LightSampleContext ctx{Vec3(0.3f, 0.1f, -0.5f), Vec3()};
        if (!l->sample(ctx, {rng.next_float(), rng.next_float()}, ls)) continue;
        Vec3 hp = ctx.p + ls.wi * ls.dist;
        float pdf = l->pdf(ctx, ls.wi, LightHit{hp, normalize(hp - Vec3(0, 0, 3)), 0});
        ASSERT_NEAR(ls.pdf, pdf, 1e-3f * pdf);
    }
    EXPECT_NEAR(l->power(), Pi * 4 * Pi * 2, 1e-3);
}

// --------------------------------------------------------------------------------------
// Textured area emitters

namespace {

const Spectrum kLeftTexel(4.f, 2.f, 0.f), kRightTexel(0.f, 0.5f, 0.25f);

/// A 2 x 1 float image: the left texel (u < 0.5) kLeftTexel, the right one kRightTexel.
std::string two_colour_texture() {
    const std::string path = tmp_dir() + "/two_colour.exr";
    Image img(2, 1, 3);
    img.set_rgb(0, 0, kLeftTexel);
    img.set_rgb(1, 0, kRightTexel);
    write_float_image(path, img);
    return path;
}

/// A `rectangle` shape (uv: u = (x + 1)/2 before to_world) with a black material.
json emitter_rectangle(const json &radiance, const json &to_world, bool facing_down) {
    return {{"type", "rectangle"}, {"flip_normals", facing_down}, {"to_world", to_world},
            {"material", {{"type", "diffuse"}, {"reflectance", 0}}},
            {"emitter", {{"type", "area"}, {"radiance", radiance}}}};
}

/// Block means (8 x 8 pixel blocks of a 32 x 32 image, channels r, g) over K renders with
/// different seeds, and their standard errors from the spread between the renders (the
/// Monte Carlo error alone: the pixels' spatial variation within a block does not enter).
struct BlockStats {
    double mean[16][2] = {}, stderr_[16][2] = {};
};
BlockStats block_stats(const std::string &name, const json &scene, int K, int spp) {
    auto s = meso::test::load_json_scene(name, scene.dump());
    double sum[16][2] = {}, sum2[16][2] = {};
    for (int k = 0; k < K; ++k) {
        RenderResult r = meso::test::render_scene(*s, spp, 0, 100 + k);
        EXPECT_EQ(r.nan_count, 0);
        for (int b = 0; b < 16; ++b)
            for (int ch = 0; ch < 2; ++ch) {
                double m = 0;
                for (int y = 0; y < 8; ++y)
                    for (int x = 0; x < 8; ++x) m += r.image.at(8 * (b % 4) + x, 8 * (b / 4) + y, ch) / 64.0;
                sum[b][ch] += m;
                sum2[b][ch] += m * m;
            }
    }
    BlockStats out;
    for (int b = 0; b < 16; ++b)
        for (int ch = 0; ch < 2; ++ch) {
            MeanStd ms = mean_std(sum[b][ch], sum2[b][ch], K);
            out.mean[b][ch] = ms.mean;
            out.stderr_[b][ch] = ms.stderr_ * std::sqrt(K / (K - 1.0));  // unbiased spread
        }
    return out;
}

/// Every block and channel of `a` and `b` agree within 4.5 standard errors of the difference
/// (32 comparisons of means over 32 renders, t with 31 degrees of freedom: a false alarm has
/// probability about 3e-3 for independent noise; the two scenes' renders share sampler
/// sequences, which only makes the difference smaller).
void expect_same_blocks(const BlockStats &a, const BlockStats &b, const char *what) {
    for (int blk = 0; blk < 16; ++blk)
        for (int ch = 0; ch < 2; ++ch) {
            const double se = std::hypot(a.stderr_[blk][ch], b.stderr_[blk][ch]);
            EXPECT_NEAR(a.mean[blk][ch], b.mean[blk][ch], 4.5 * se + 1e-6 * std::abs(b.mean[blk][ch]))
                << what << ": block " << blk << " channel " << ch;
        }
}

/// `emitters` over a receiver plane z = 0, [-3, 3]², seen by `direct`: diffuse (reflectance
/// 0.5) from above (fov 60°), or glossy (GGX conductor, alpha 0.05) from the side at
/// (3, 0, 2), whose 25° view is filled by the emitters' reflection around x = 1 (lit mostly
/// through BSDF-sampled rays that hit them, where the diffuse receiver is lit mostly through
/// light samples).
json receiver_scene(const json &emitters, bool glossy = false) {
    json shapes = emitters;
    const json material = glossy ? json{{"type", "conductor"}, {"material", "none"}, {"alpha", 0.05}}
                                 : json{{"type", "diffuse"}, {"reflectance", 0.5}};
    shapes.push_back({{"type", "rectangle"}, {"to_world", {{"scale", {3, 3, 1}}}}, {"material", material}});
    const json origin = glossy ? json{3, 0, 2} : json{0, 0, 4}, target = glossy ? json{1, 0, 0} : json{0, 0, 0};
    const json up = glossy ? json{0, 0, 1} : json{0, 1, 0};
    return {{"camera", {{"type", "perspective"}, {"origin", origin}, {"target", target}, {"up", up},
                        {"fov", glossy ? 25 : 60}, {"width", 32}, {"height", 32}}},
            {"integrator", {{"type", "direct"}}},
            {"shapes", shapes}};
}

}  // namespace

TEST(AreaLight, TexturedRadianceAtHitsAndLightSamples) {
    const std::string tex = two_colour_texture();
    const json radiance = {{"type", "bitmap"}, {"filename", tex}, {"filter_type", "nearest"}};
    // Seen by the camera (a path that hits it): the rectangle [-1, 1]² faces the camera on +z;
    // u runs along +x, which is the image's +x: left half kLeftTexel, right half kRightTexel.
    json scene = {{"camera", {{"type", "perspective"}, {"origin", {0, 0, 3}}, {"target", {0, 0, 0}}, {"up", {0, 1, 0}},
                              {"fov", 40}, {"width", 32}, {"height", 32}}},
                  {"shapes", {emitter_rectangle(radiance, json::object(), false)}}};
    auto s = meso::test::load_json_scene("textured_emitter.json", scene.dump());
    RenderResult r = meso::test::render_scene(*s, 4);
    for (int y = 8; y < 24; ++y)
        for (int x : {4, 12, 19, 27})
            for (int ch = 0; ch < 3; ++ch)
                EXPECT_NEAR(r.image.at(x, y, ch), (x < 16 ? kLeftTexel : kRightTexel)[ch], 1e-5) << x << "," << y;

    // Light samples (next-event estimation): the radiance of the texel under the sampled point,
    // and the irradiance estimate against Lambert's formula for the two uniform halves.
    ASSERT_EQ(s->lights.size(), 1u);
    const Light &light = *s->lights[0];
    const Vec3 p(0.3f, -0.2f, 1.5f), n(0, 0, -1);
    PCG32 rng(3);
    int checked = 0;
    for (int i = 0; i < 2000; ++i) {
        LightSample ls;
        if (!light.sample({p, n}, {rng.next_float(), rng.next_float()}, ls)) continue;
        const float x = (p + ls.wi * ls.dist).x;
        if (std::abs(x) < 1e-4f) continue;
        const Spectrum want = x < 0 ? kLeftTexel : kRightTexel;
        for (int ch = 0; ch < 3; ++ch) EXPECT_EQ(ls.L[ch], want[ch]) << "sample at x = " << x;
        ++checked;
    }
    EXPECT_GT(checked, 1900);
    const std::vector<Vec3> left = {{-1, -1, 0}, {0, -1, 0}, {0, 1, 0}, {-1, 1, 0}};
    const std::vector<Vec3> right = {{0, -1, 0}, {1, -1, 0}, {1, 1, 0}, {0, 1, 0}};
    const double ref = lambert_irradiance(p, n, left, kLeftTexel.average()) +
                       lambert_irradiance(p, n, right, kRightTexel.average());
    MeanStd e = estimate_irradiance(light, p, n, 40000, 11);
    EXPECT_NEAR(e.mean, ref, 5 * e.stderr_) << "Lambert, two halves: " << ref;
    EXPECT_NE(light.to_string().find("bitmap"), std::string::npos) << light.to_string();
}

TEST(AreaLight, TexturedEmitterLightsLikeConstantEmitters) {
    // A receiver plane under a two-colour emitter: next-event estimation and BSDF-sampled rays
    // that hit the emitter (combined by MIS in `direct`) must together give what two emitters
    // of constant radiance, one per half, give (near: the colour falls where its half is), and
    // from afar what one emitter of the texture's mean radiance gives. Tolerances from the
    // spread over 32 renders per scene (fixed seeds).
    const std::string tex = two_colour_texture();
    const json down = {{"scale", {0.5, 0.5, 1}}, {"translate", {0, 0, 1}}};
    const json textured = json::array(
        {emitter_rectangle({{"type", "bitmap"}, {"filename", tex}, {"filter_type", "nearest"}}, down, true)});
    const json split = json::array(
        {emitter_rectangle({kLeftTexel.r, kLeftTexel.g, kLeftTexel.b},
                           {{"scale", {0.25, 0.5, 1}}, {"translate", {-0.25, 0, 1}}}, true),
         emitter_rectangle({kRightTexel.r, kRightTexel.g, kRightTexel.b},
                           {{"scale", {0.25, 0.5, 1}}, {"translate", {0.25, 0, 1}}}, true)});
    for (bool glossy : {false, true}) {
        const std::string tag = glossy ? "glossy" : "diffuse";
        const BlockStats a = block_stats("textured_" + tag + ".json", receiver_scene(textured, glossy), 32, 4);
        expect_same_blocks(a, block_stats("split_" + tag + ".json", receiver_scene(split, glossy), 32, 4),
                           ("near, split emitters, " + tag).c_str());
        // The halves light different sides: a mirrored lookup would swap them.
        if (!glossy) {
            EXPECT_GT(a.mean[4][0], 1.5 * a.mean[7][0]);  // red on the left (x < 0): 0.029 vs 0.013
        }
    }

    const json far = {{"scale", {0.5, 0.5, 1}}, {"translate", {0, 0, 30}}};
    const Spectrum mean = (kLeftTexel + kRightTexel) * 0.5f * 900.f;
    const json textured_far = receiver_scene(json::array(
        {emitter_rectangle({{"type", "bitmap"}, {"filename", tex}, {"filter_type", "nearest"}, {"scale", 900}}, far, true)}));
    const json mean_far = receiver_scene(json::array({emitter_rectangle({mean.r, mean.g, mean.b}, far, true)}));
    expect_same_blocks(block_stats("textured_far.json", textured_far, 32, 4),
                       block_stats("mean_far.json", mean_far, 32, 4), "far, mean radiance");
}

// Issue 22: a rectangular emitter (two triangles, orthogonal edges) is sampled as one spherical
// rectangle (Urena et al. 2013): every light sample's pdf is 1 / (the rectangle's solid angle),
// which is the sum of its triangles' (Van Oosterom-Strackee), and pdf() agrees. (Irradiance and
// pdf normalisation for this rectangle are checked by IrradianceMatchesLambert and
// PdfIntegratesToOne.) A sheared quad is not a rectangle and keeps per-triangle sampling.
TEST(AreaLight, RectangleIsSampledAsOneSphericalRectangle) {
    TestMeshShape rect(make_mesh({{-1, -0.5f, 2}, {1, -0.5f, 2}, {1, 0.5f, 2}, {-1, 0.5f, 2}}, {0, 2, 1, 0, 3, 2}));
    TestMeshShape sheared(make_mesh({{-1, -0.5f, 2}, {1, -0.5f, 2}, {1.6f, 0.5f, 2}, {-0.4f, 0.5f, 2}}, {0, 2, 1, 0, 3, 2}));
    auto l = make_light({{"type", "area"}, {"sampling", "solid_angle"}});
    l->set_shape(&rect);
    auto ls_sheared = make_light({{"type", "area"}, {"sampling", "solid_angle"}});
    ls_sheared->set_shape(&sheared);
    PCG32 rng(5);
    const Vec3 p(0.3f, 0.1f, 0.f);
    const double omega = sphtri::solid_angle(p, {-1, -0.5f, 2}, {1, -0.5f, 2}, {1, 0.5f, 2}) +
                         sphtri::solid_angle(p, {-1, -0.5f, 2}, {1, 0.5f, 2}, {-1, 0.5f, 2});
    int distinct_pdfs_sheared = 0;
    float first_sheared = -1.f;
    for (int i = 0; i < 1000; ++i) {
        LightSample ls;
        LightSampleContext ctx{p, Vec3(0, 0, 1)};
        ASSERT_TRUE(l->sample(ctx, {rng.next_float(), rng.next_float()}, ls));
        EXPECT_NEAR(ls.pdf, 1.0 / omega, 1e-5 / omega);
        LightHit hit{p + ls.wi * ls.dist, Vec3(0, 0, -1), 0};
        EXPECT_NEAR(l->pdf(ctx, ls.wi, hit), ls.pdf, 1e-6f * ls.pdf);
        if (ls_sheared->sample(ctx, {rng.next_float(), rng.next_float()}, ls)) {
            if (first_sheared < 0) first_sheared = ls.pdf;
            distinct_pdfs_sheared += std::abs(ls.pdf - first_sheared) > 1e-3f * first_sheared;
        }
    }
    EXPECT_GT(distinct_pdfs_sheared, 0);  // per-triangle pdfs P(t) / Omega_t differ between the halves
}
