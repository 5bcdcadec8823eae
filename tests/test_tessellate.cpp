// Explicit tessellation of displaced meshes (geometry/tessellate.h): vertices on the
// displaced surface P + h(uv) N, triangle counts, the automatic level, refusals,
// watertightness of a welded uv sphere and a Catmull-Clark cube, and no NaN on
// degenerate input.
#include <gtest/gtest.h>
#include <chrono>
#include <cmath>
#include <map>
#include <memory>
#include <tuple>
#include <unordered_map>
#include "core/error.h"
#include "geometry/tessellate.h"

using namespace meso;

namespace {

Displacement make_displacement(const HeightMap &map, float scale, float offset, SubdivScheme scheme, int level,
                               float tiling_u = 1.f, float tiling_v = 1.f) {
    Displacement d;
    d.field = std::make_shared<Heightfield>(map, scale, offset);
    d.source = "test";
    d.tiling_u = tiling_u;
    d.tiling_v = tiling_v;
    d.mode = DisplacementMode::Tessellate;
    d.scheme = scheme;
    d.level = level;
    return d;
}

/// A smooth periodic map: sin/cos products over the grid.
HeightMap wavy_map(int w, int h) {
    HeightMap m(w, h);
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < w; ++i)
            m.at(i, j) = std::sin(2.f * Pi * i / w) * std::cos(4.f * Pi * j / h) + 0.3f * std::sin(2.f * Pi * (i + j) / w);
    return m;
}

void expect_finite(const TriangleMesh &m) {
    for (const Vec3 &p : m.positions) ASSERT_TRUE(is_finite(p));
    for (const Vec2 &uv : m.uvs) ASSERT_TRUE(std::isfinite(uv.x) && std::isfinite(uv.y));
}

/// Welds positions closer than `tol` (hash grid of cell tol, 27 neighbours).
std::vector<uint32_t> weld_positions(const std::vector<Vec3> &pos, float tol, std::vector<Vec3> &welded) {
    using Key = std::tuple<int64_t, int64_t, int64_t>;
    std::map<Key, std::vector<uint32_t>> grid;
    std::vector<uint32_t> id(pos.size());
    for (size_t v = 0; v < pos.size(); ++v) {
        Key k{int64_t(std::floor(pos[v].x / tol)), int64_t(std::floor(pos[v].y / tol)), int64_t(std::floor(pos[v].z / tol))};
        int64_t found = -1;
        for (int a = -1; a <= 1 && found < 0; ++a)
            for (int b = -1; b <= 1 && found < 0; ++b)
                for (int c = -1; c <= 1 && found < 0; ++c) {
                    auto it = grid.find(Key{std::get<0>(k) + a, std::get<1>(k) + b, std::get<2>(k) + c});
                    if (it == grid.end()) continue;
                    for (uint32_t w : it->second)
                        if (length(welded[w] - pos[v]) <= tol) {
                            found = w;
                            break;
                        }
                }
        if (found < 0) {
            found = int64_t(welded.size());
            welded.push_back(pos[v]);
            grid[k].push_back(uint32_t(found));
        }
        id[v] = uint32_t(found);
    }
    return id;
}

/// After welding positions: every directed edge of a non-degenerate triangle has exactly
/// one opposite directed edge (closed, consistently oriented, manifold). Returns the
/// number of offending edges.
size_t open_edges(const TriangleMesh &m, float tol) {
    std::vector<Vec3> welded;
    std::vector<uint32_t> id = weld_positions(m.positions, tol, welded);
    std::map<std::pair<uint32_t, uint32_t>, int> directed;
    for (size_t t = 0; t < m.triangle_count(); ++t) {
        uint32_t c[3] = {id[m.indices[3 * t]], id[m.indices[3 * t + 1]], id[m.indices[3 * t + 2]]};
        if (c[0] == c[1] || c[1] == c[2] || c[2] == c[0]) continue;
        if (m.triangle_area(t) < 1e-12f) continue;
        for (int k = 0; k < 3; ++k) directed[{c[k], c[(k + 1) % 3]}]++;
    }
    size_t bad = 0;
    for (const auto &[e, n] : directed) {
        auto it = directed.find({e.second, e.first});
        if (n != 1 || it == directed.end() || it->second != 1) ++bad;
    }
    return bad;
}

}  // namespace

TEST(Tessellate, FlatZeroMapStaysOnPlane) {
    Displacement d = make_displacement(HeightMap(8, 8, 0.f), 1.f, 0.f, SubdivScheme::Bilinear, 3);
    TriangleMesh out = tessellate_displaced(make_rectangle(), d, "rect");
    ASSERT_EQ(out.triangle_count(), size_t(2 * 2 * 3 * 16));
    EXPECT_TRUE(out.normals.empty());  // facet normals on purpose
    ASSERT_EQ(out.uvs.size(), out.positions.size());
    out.validate("out");
    for (size_t v = 0; v < out.positions.size(); ++v) {
        EXPECT_EQ(out.positions[v].z, 0.f);
        EXPECT_NEAR(out.positions[v].x, 2.f * out.uvs[v].x - 1.f, 1e-6f);
        EXPECT_NEAR(out.positions[v].y, 2.f * out.uvs[v].y - 1.f, 1e-6f);
    }
    // Winding preserved: every facet faces +z like the base.
    for (size_t t = 0; t < out.triangle_count(); ++t) {
        const Vec3 &a = out.positions[out.indices[3 * t]], &b = out.positions[out.indices[3 * t + 1]],
                   &c = out.positions[out.indices[3 * t + 2]];
        EXPECT_GT(cross(b - a, c - a).z, 0.f);
    }
    EXPECT_EQ(open_edges(out, 1e-5f), size_t(8 * 4));  // only the rectangle's border is open
}

TEST(Tessellate, BilinearVerticesLieOnOffsetSurface) {
    // One triangle with non-unit, differing normals: the displaced vertex is the linear
    // interpolation P(b) + h(uv) N(b), N not renormalised (the shell map's offset surface).
    TriangleMesh tri;
    tri.positions = {{0, 0, 0}, {2, 0, 0.5f}, {0, 1.5f, -0.25f}};
    tri.normals = {normalize(Vec3(0.2f, 0.1f, 1)), normalize(Vec3(-0.3f, 0, 1)), normalize(Vec3(0, -0.4f, 1))};
    tri.uvs = {{0, 0}, {1, 0}, {0, 1}};
    tri.indices = {0, 1, 2};
    Displacement d = make_displacement(wavy_map(16, 12), 0.3f, 0.05f, SubdivScheme::Bilinear, 5, 2.f, 1.f);
    TriangleMesh out = tessellate_displaced(tri, d, "tri");
    ASSERT_EQ(out.triangle_count(), tessellated_triangle_count(tri, 5));
    ASSERT_EQ(out.triangle_count(), size_t(6 * 256));
    double max_err = 0;
    for (size_t v = 0; v < out.positions.size(); ++v) {
        Vec2 uv = out.uvs[v];
        float b1 = uv.x, b2 = uv.y, b0 = 1.f - b1 - b2;
        ASSERT_GE(b0, -1e-6f);
        Vec3 p = b0 * tri.positions[0] + b1 * tri.positions[1] + b2 * tri.positions[2];
        Vec3 n = b0 * tri.normals[0] + b1 * tri.normals[1] + b2 * tri.normals[2];
        Vec3 expect = p + d.height_at(uv) * n;
        max_err = std::max(max_err, double(length(out.positions[v] - expect)));
    }
    EXPECT_LT(max_err, 1e-5);

    // The same on the rectangle: (2u - 1, 2v - 1, h(uv)).
    TriangleMesh rect = tessellate_displaced(make_rectangle(), d, "rect");
    for (size_t v = 0; v < rect.positions.size(); ++v) {
        Vec2 uv = rect.uvs[v];
        EXPECT_NEAR(rect.positions[v].x, 2 * uv.x - 1, 1e-5f);
        EXPECT_NEAR(rect.positions[v].y, 2 * uv.y - 1, 1e-5f);
        EXPECT_NEAR(rect.positions[v].z, d.height_at(uv), 1e-5f);
    }
}

TEST(Tessellate, TriangleCountMatchesFormula) {
    TriangleMesh rect = make_rectangle(), sphere = make_uv_sphere(6, 8), cube = make_cube();
    Displacement d = make_displacement(wavy_map(8, 8), 0.1f, 0.f, SubdivScheme::Bilinear, 0);
    for (int level = 0; level <= 4; ++level) {
        size_t per = level == 0 ? 1 : 6 * (size_t(1) << (2 * (level - 1)));
        EXPECT_EQ(tessellated_triangle_count(rect, level), 2 * per);
        EXPECT_EQ(tessellated_triangle_count(sphere, level), sphere.triangle_count() * per);
        EXPECT_EQ(tessellated_triangle_count(cube, level), 12 * per);
        d.level = level;
        for (SubdivScheme s : {SubdivScheme::Bilinear, SubdivScheme::CatmullClark}) {
            d.scheme = s;
            EXPECT_EQ(tessellate_displaced(rect, d, "r").triangle_count(), 2 * per);
            EXPECT_EQ(tessellate_displaced(sphere, d, "s").triangle_count(), sphere.triangle_count() * per);
            EXPECT_EQ(tessellate_displaced(cube, d, "c").triangle_count(), 12 * per);
        }
    }
    // Saturates instead of overflowing.
    EXPECT_EQ(tessellated_triangle_count(rect, 40), std::numeric_limits<size_t>::max());
}

TEST(Tessellate, AutoLevelReachesMapResolution) {
    // 32 x 16 map tiled 2 x 3 over the rectangle: cell space [0,64] x [0,48].
    Displacement d = make_displacement(wavy_map(32, 16), 0.1f, 0.f, SubdivScheme::Bilinear, -1, 2.f, 3.f);
    TriangleMesh rect = make_rectangle();
    int level = auto_tessellation_level(rect, d);
    auto longest_cell_edge = [&](const TriangleMesh &m) {
        double longest = 0;
        for (size_t q = 0; q + 1 < m.triangle_count(); q += 2) {
            // Triangles come in pairs (0,1,2), (0,2,3) from each quad.
            uint32_t c[4] = {m.indices[3 * q], m.indices[3 * q + 1], m.indices[3 * q + 2], m.indices[3 * q + 5]};
            for (int k = 0; k < 4; ++k) {
                Vec2 a = d.to_cell(m.uvs[c[k]]), b = d.to_cell(m.uvs[c[(k + 1) % 4]]);
                longest = std::max({longest, std::abs(double(a.x - b.x)), std::abs(double(a.y - b.y))});
            }
        }
        return longest;
    };
    TriangleMesh out = tessellate_displaced(rect, d, "rect");
    EXPECT_EQ(out.triangle_count(), tessellated_triangle_count(rect, level));
    EXPECT_LE(longest_cell_edge(out), 1.0 + 1e-3);
    // And it is the smallest such level.
    d.level = level - 1;
    EXPECT_GT(longest_cell_edge(tessellate_displaced(rect, d, "rect")), 1.0 + 1e-3);
    // The level-1 quads' longest edge is half the uv diagonal, (32, 24) cells: 1 + log2(32).
    EXPECT_EQ(level, 6);
}

TEST(Tessellate, RefusesBeforeRefining) {
    // A 64^2 map tiled 64 x 64 times: 4096^2 cells, level 12, 50M triangles.
    Displacement d = make_displacement(HeightMap(64, 64, 0.f), 1.f, 0.f, SubdivScheme::Bilinear, -1, 64.f, 64.f);
    d.max_triangles = 1000000;
    TriangleMesh rect = make_rectangle();
    int level = auto_tessellation_level(rect, d);
    EXPECT_EQ(level, 12);
    size_t n = tessellated_triangle_count(rect, level);
    try {
        tessellate_displaced(rect, d, "scene.json: shapes[0]");
        FAIL() << "expected a refusal";
    } catch (const MesoError &e) {
        std::string msg = e.what();
        EXPECT_EQ(msg, "scene.json: shapes[0]: displacement: tessellating to level 12 would make " + std::to_string(n) +
                           " triangles, more than --max-triangles 1000000; use \"mode\": \"shell\" (exact, memory "
                           "independent of resolution) or raise --max-triangles");
        EXPECT_NE(msg.find("shell"), std::string::npos);
        EXPECT_NE(msg.find("--max-triangles"), std::string::npos);
    }
    // Too deep even when the count is allowed.
    d.level = 16;
    d.max_triangles = std::numeric_limits<size_t>::max();
    EXPECT_THROW(tessellate_displaced(rect, d, "x"), MesoError);
    // No uvs.
    TriangleMesh bare = rect;
    bare.uvs.clear();
    d.level = 1;
    try {
        tessellate_displaced(bare, d, "mesh.gltf");
        FAIL() << "expected an error";
    } catch (const MesoError &e) {
        EXPECT_EQ(std::string(e.what()), "mesh.gltf: displacement needs uv coordinates (the mesh has none)");
    }
}

TEST(Tessellate, UvSphereBilinearIsWatertightAtRadiusOnePlusH) {
    const int rings = 8, segments = 16;
    TriangleMesh sphere = make_uv_sphere(rings, segments);
    // A map that varies in u only away from the pole bands (the pole triangles' two sides
    // carry different u, so heights must not depend on u there): rows 0..2 and 14..15 of
    // a 16-row map are the bands v <= 1/8 and v >= 7/8.
    HeightMap map(16, 16);
    for (int j = 0; j < 16; ++j)
        for (int i = 0; i < 16; ++i) {
            float band = (j <= 2 || j >= 14) ? 0.f : 1.f;
            map.at(i, j) = 0.5f * std::sin(2.f * Pi * j / 16) + band * std::cos(2.f * Pi * i / 16) * std::sin(Pi * j / 16);
        }
    Displacement d = make_displacement(map, 0.1f, 0.05f, SubdivScheme::Bilinear, 3, 2.f, 1.f);
    TriangleMesh out = tessellate_displaced(sphere, d, "sphere");
    expect_finite(out);
    EXPECT_EQ(open_edges(out, 1e-5f), size_t(0));
    // Seam vertices are split: no triangle's uvs wrap around u = 0/1.
    for (size_t t = 0; t < out.triangle_count(); ++t) {
        float u0 = out.uvs[out.indices[3 * t]].x, u1 = out.uvs[out.indices[3 * t + 1]].x,
              u2 = out.uvs[out.indices[3 * t + 2]].x;
        EXPECT_LT(std::max({u0, u1, u2}) - std::min({u0, u1, u2}), 0.5f);
    }
    // Base vertices sit at radius 1 + h exactly; refined ones on the chord, with
    // N = P_lin (the sphere's normals are its positions) at |P_lin| (1 + h).
    size_t base_hits = 0;
    for (size_t v = 0; v < out.positions.size(); ++v) {
        Vec2 uv = out.uvs[v];
        float h = d.height_at(uv);
        float r = length(out.positions[v]);
        float fs = uv.x * segments, fr = uv.y * rings;
        if (std::abs(fs - std::round(fs)) < 1e-5f && std::abs(fr - std::round(fr)) < 1e-5f) {
            ++base_hits;
            EXPECT_NEAR(r, 1.f + h, 1e-5f);
        }
        EXPECT_LE(r, (1.f + h) * (1.f + 1e-5f));
        EXPECT_GE(r, (1.f + h) * 0.95f);
    }
    EXPECT_GE(base_hits, size_t((rings - 1) * (segments + 1)));
}

TEST(Tessellate, CatmullClarkCubeIsClosedAndRounded) {
    Displacement d = make_displacement(HeightMap(4, 4, 0.f), 1.f, 0.f, SubdivScheme::CatmullClark, 4);
    TriangleMesh out = tessellate_displaced(make_cube(), d, "cube");
    expect_finite(out);
    EXPECT_EQ(open_edges(out, 1e-5f), size_t(0));
    float rmax = 0, rmin = 10;
    for (const Vec3 &p : out.positions) {
        EXPECT_LT(max_component(vabs(p)), 1.f);
        rmax = std::max(rmax, length(p));
        rmin = std::min(rmin, length(p));
    }
    EXPECT_LT(rmax, std::sqrt(3.f) - 0.1f);  // corners rounded off
    EXPECT_GT(rmin, 0.3f);
    // Facets face outwards (winding kept).
    for (size_t t = 0; t < out.triangle_count(); ++t) {
        const Vec3 &a = out.positions[out.indices[3 * t]], &b = out.positions[out.indices[3 * t + 1]],
                   &c = out.positions[out.indices[3 * t + 2]];
        EXPECT_GT(dot(cross(b - a, c - a), a + b + c), 0.f);
    }
    // A constant height moves the limit surface outwards along its unit normal: the
    // result is still closed (one normal per welded vertex) and strictly larger.
    Displacement d2 = make_displacement(HeightMap(4, 4, 0.f), 1.f, 0.2f, SubdivScheme::CatmullClark, 4);
    TriangleMesh grown = tessellate_displaced(make_cube(), d2, "cube");
    ASSERT_EQ(grown.positions.size(), out.positions.size());
    EXPECT_EQ(open_edges(grown, 1e-5f), size_t(0));
    for (size_t v = 0; v < out.positions.size(); ++v)
        EXPECT_NEAR(length(grown.positions[v] - out.positions[v]), 0.2f, 1e-5f);
}

TEST(Tessellate, CatmullClarkUvSphereIsClosed) {
    // The seam and the split poles are welded, so the limit surface is one closed smooth
    // surface, slightly inside the control sphere, moved out by the constant height.
    Displacement d = make_displacement(HeightMap(4, 4, 0.f), 1.f, 0.05f, SubdivScheme::CatmullClark, 3);
    TriangleMesh out = tessellate_displaced(make_uv_sphere(8, 16), d, "sphere");
    expect_finite(out);
    EXPECT_EQ(open_edges(out, 1e-5f), size_t(0));
    for (const Vec3 &p : out.positions) {
        EXPECT_LE(length(p), 1.05f);
        EXPECT_GE(length(p), 0.9f * 1.05f);
    }
}

TEST(Tessellate, CatmullClarkFlatRectangleDisplacesAlongBaseNormal) {
    // The limit of a flat mesh is flat; its limit normal must be oriented like the base (+z).
    Displacement d = make_displacement(wavy_map(8, 8), 0.25f, 0.1f, SubdivScheme::CatmullClark, 4);
    TriangleMesh out = tessellate_displaced(make_rectangle(), d, "rect");
    for (size_t v = 0; v < out.positions.size(); ++v)
        EXPECT_NEAR(out.positions[v].z, d.height_at(out.uvs[v]), 1e-5f);
}

TEST(Tessellate, DegenerateInputNeverNaN) {
    // A mesh with a zero-area (collinear) triangle, a triangle with two equal corners
    // and a normal of zero length.
    TriangleMesh m;
    m.positions = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {2, 0, 0}, {0.5f, 0, 0}};
    m.normals = {{0, 0, 1}, {0, 0, 1}, {0, 0, 0}, {0, 0, 1}, {0, 0, 1}};
    m.uvs = {{0, 0}, {1, 0}, {1, 1}, {1, 0.5f}, {0.5f, 0}};
    m.indices = {0, 1, 2, 0, 4, 1, 1, 3, 1, 1, 3, 2};
    HeightMap map = wavy_map(8, 8);
    for (SubdivScheme s : {SubdivScheme::Bilinear, SubdivScheme::CatmullClark})
        for (float scale : {0.f, -0.5f, 0.5f})
            for (float offset : {0.f, -0.3f}) {
                Displacement d = make_displacement(map, scale, offset, s, 3);
                for (const TriangleMesh &base : {m, make_uv_sphere(4, 6), make_cube(), make_rectangle()}) {
                    TriangleMesh out = tessellate_displaced(base, d, "m");
                    expect_finite(out);
                    EXPECT_EQ(out.triangle_count(), tessellated_triangle_count(base, 3));
                    out.validate("out");
                }
                // Without normals: area-weighted vertex normals.
                TriangleMesh bare = make_uv_sphere(4, 6);
                bare.normals.clear();
                expect_finite(tessellate_displaced(bare, d, "bare"));
            }
    // The triangle with two equal corners is dropped (zero area), the collinear one kept.
    EXPECT_EQ(tessellated_triangle_count(m, 0), size_t(3));
    // An empty mesh has no triangles at any level.
    EXPECT_EQ(tessellated_triangle_count(TriangleMesh(), 2), size_t(0));
}

TEST(Tessellate, LargeMapAtAutoLevelIsFast) {
    // 256 x 256 map on the rectangle: level 8, 196,608 triangles.
    Displacement d = make_displacement(wavy_map(256, 256), 0.01f, 0.f, SubdivScheme::Bilinear, -1);
    EXPECT_EQ(auto_tessellation_level(make_rectangle(), d), 8);
    auto t0 = std::chrono::steady_clock::now();
    TriangleMesh out = tessellate_displaced(make_rectangle(), d, "rect");
    double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    EXPECT_EQ(out.triangle_count(), size_t(2 * 6 * (1 << 14)));
    EXPECT_LT(s, 5.0);
}
