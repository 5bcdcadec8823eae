// Shell-map hits against an independent path: on a flat square with linear uvs the world ->
// cell-space map is one affine map, so a world ray maps (in double, without prisms or
// tetrahedra) to one cell-space ray whose first hit on the heightfield is the shell's hit.
// This checks the prism clipping, the re-basing per tetrahedron and the merging of
// tetrahedra that share a map (ShellShape::Prism::same_map) to float round-off.
#include <gtest/gtest.h>
#include <cmath>
#include <memory>
#include "geometry/shell_shape.h"
#include "sampling/rng.h"

using namespace meso;

namespace {

struct SquareShell {
    int W, H;
    float tiling;
    std::shared_ptr<ShellShape> shape;
    std::shared_ptr<const Heightfield> field;
};

/// The square [-1, 1]^2 at z = 0, normal +z, uv = ((x + 1) / 2, (y + 1) / 2) + uv_shift,
/// displaced by a W x H noise map of amplitude `amp`, tiled `tiling` times; as `grid` x `grid`
/// squares of two triangles each (diagonals alternating, a quad's two triangles not always
/// consecutive in the index list).
SquareShell square_shell(int W, int H, float amp, float tiling, uint64_t seed, Vec2 uv_shift = Vec2(0.f, 0.f),
                         int grid = 1) {
    TriangleMesh m;
    for (int j = 0; j <= grid; ++j)
        for (int i = 0; i <= grid; ++i) {
            const float u = float(i) / float(grid), v = float(j) / float(grid);
            m.positions.push_back(Vec3(2.f * u - 1.f, 2.f * v - 1.f, 0.f));
            m.normals.push_back(Vec3(0, 0, 1));
            m.uvs.push_back(Vec2(u, v) + uv_shift);
        }
    std::vector<uint32_t> second;
    for (int j = 0; j < grid; ++j)
        for (int i = 0; i < grid; ++i) {
            const uint32_t a = uint32_t(j * (grid + 1) + i), b = a + 1, c = a + uint32_t(grid + 1), d = c + 1;
            if ((i + j) % 2 == 0) {
                m.indices.insert(m.indices.end(), {a, b, d});
                second.insert(second.end(), {a, d, c});
            } else {
                m.indices.insert(m.indices.end(), {a, b, c});
                second.insert(second.end(), {b, d, c});
            }
        }
    // The second triangles after all the first ones, in reverse (far from their partners).
    for (size_t t = second.size() / 3; t-- > 0;) m.indices.insert(m.indices.end(), &second[3 * t], &second[3 * t + 3]);
    HeightMap map(W, H);
    PCG32 rng(seed);
    for (float &v : map.h) v = rng.next_float();
    Displacement d;
    d.field = std::make_shared<Heightfield>(map, amp, 0.f);
    d.tiling_u = d.tiling_v = tiling;
    SquareShell s{W, H, tiling, std::make_shared<ShellShape>(m, d, "square"), d.field};
    return s;
}

/// Closest shell hit over all prisms (what Embree's user geometry does).
bool shell_hit(const ShellShape &s, Vec3 o, Vec3 d, float &t) {
    float tfar = Infinity;
    bool hit = false;
    for (uint32_t p = 0; p < s.primitive_count(); ++p) {
        uint32_t tet;
        float x, y;
        hit |= s.intersect_prism(p, o, d, 0.f, tfar, tet, x, y);
    }
    t = tfar;
    return hit;
}

/// Whether the ray stays on or above the surface (within 1e-6 height units) strictly between
/// t0 and t1: then the earlier of two hits there is a tangential touch (a graze) and either
/// answer is right to round-off. Cell space: x = (X + 1) sx, y = (Y + 1) sy.
bool grazes_between(const Heightfield &f, Vec3 o, Vec3 d, double sx, double sy, double t0, double t1) {
    for (int k = 1; k < 256; ++k) {
        const double t = t0 + (t1 - t0) * k / 256;
        const double gap = (double(o.z) + t * d.z) - f.eval((double(o.x) + t * d.x + 1) * sx, (double(o.y) + t * d.y + 1) * sy);
        if (gap < -1e-6) return false;
    }
    return true;
}

}  // namespace

namespace {

/// Shell hits of a flat square against the field's hits on the same ray mapped to cell space
/// in double (x = (X + 1) sx, y = (Y + 1) sy, h = Z), without prisms or tetrahedra.
struct MappedFieldComparison {
    const SquareShell &sq;
    double sx, sy;  ///< cells per world unit
    int compared = 0, disagree = 0, grazes = 0;
    double worst = 0;
    double tol = 1e-5;  ///< relative tolerance on t: |t_shell - t_field| <= tol (1 + t)

    explicit MappedFieldComparison(const SquareShell &s)
        : sq(s), sx(0.5 * s.W * s.tiling), sy(0.5 * s.H * s.tiling) {}

    void add(Vec3 o, Vec3 d) {
        float ts;
        const bool hs = shell_hit(*sq.shape, o, d, ts);
        const Vec3 oc(float((double(o.x) + 1) * sx), float((double(o.y) + 1) * sy), o.z);
        const Vec3 dc(float(d.x * sx), float(d.y * sy), d.z);
        HeightfieldHit h;
        const bool hr = sq.field->intersect(oc, dc, 0.f, Infinity, h);
        // Where the field's hit lies outside the square (rays aimed near its edge at a
        // slant) the shell has no surface: only hits inside it are compared.
        if (hr && (std::abs(h.x / sx - 1) > 0.999 || std::abs(h.y / sy - 1) > 0.999)) return;
        if (hs != hr) {
            // One of the two found a tangential touch (the ray stays on or above the surface
            // around it) that the other passed.
            const double t = hs ? ts : h.t;
            if (grazes_between(*sq.field, o, d, sx, sy, std::max(0.0, t - 1e-3), t + 1e-3)) ++grazes;
            else ++disagree;
            return;
        }
        if (!hr) return;
        ++compared;
        // Round-off: float ulps of the cell coordinates (up to 192 cells here, ulp 1.5e-5)
        // divided by the ray's slope against the surface; measured worst 2.6e-6 (1 + t) with
        // tetrahedra merged, 1.7e-6 without.
        const double err = std::abs(double(ts) - h.t) / (tol * (1 + double(h.t)));
        if (err > 1.0 && grazes_between(*sq.field, o, d, sx, sy, std::min(double(ts), double(h.t)),
                                        std::max(double(ts), double(h.t)))) {
            ++grazes;  // one of the two stopped at a tangential touch the other passed
            return;
        }
        worst = std::max(worst, err);
    }

    /// The verdict of a comparison: at least min_compared hits, at most one graze in graze_per,
    /// no disagreement and every hit within 1e-5 (1 + t); prints the counts under `label`.
    void expect_agreement(int min_compared, int graze_per, float tiling, const char *label) const {
        EXPECT_GT(compared, min_compared) << tiling;
        EXPECT_LE(grazes, compared / graze_per) << tiling;
        EXPECT_EQ(disagree, 0) << tiling;
        EXPECT_LE(worst, 1.0) << "tiling " << tiling << ": worst |t_shell - t_field| in units of 1e-5 (1 + t), grazes left out";
        std::printf("[%s] tiling %g: %d hits compared, %d grazes, worst %.3g x 1e-5 (1 + t)\n", label, tiling, compared,
                    grazes, worst);
    }
};

/// The direction at angle theta (radians) from -z and azimuth phi.
Vec3 direction(double theta, double phi) {
    return Vec3(float(std::sin(theta) * std::cos(phi)), float(std::sin(theta) * std::sin(phi)), float(-std::cos(theta)));
}

}  // namespace

TEST(ShellShape, FlatSquareHitsEqualTheHeightfieldsOnTheMappedRay) {
    for (const float tiling : {1.f, 3.f}) {
        const SquareShell sq = square_shell(64, 48, 0.05f, tiling, 31);
        MappedFieldComparison cmp(sq);
        PCG32 rng(17);
        for (int k = 0; k < 20000; ++k) {
            // Aimed at a point inside the square from above, at up to 85 degrees from the normal.
            const double theta = std::acos(1 - rng.next_double() * (1 - std::cos(85.0 * M_PI / 180))),
                         phi = 2 * M_PI * rng.next_double();
            const Vec3 d = direction(theta, phi);
            const double px = -0.9 + 1.8 * rng.next_double(), py = -0.9 + 1.8 * rng.next_double(), s = 0.2 / std::cos(theta);
            cmp.add(Vec3(float(px - s * d.x), float(py - s * d.y), float(0.1 - s * d.z)), d);
        }
        cmp.expect_agreement(15000, 1000, tiling, "shell vs field");
    }
}

// The prism clip (one clip of a flat prism in cell space) at its edges: rays grazing the shell
// (85 to 89.9 degrees), in the vertical plane of the prisms' shared diagonal x = y (and
// vertical ones on it), through cell-grid vertices, and from the surface up or down as a
// spawned ray leaves it, against the same independent mapped-field path.
TEST(ShellShape, FlatSquareHitsAtPrismEdgesGrazingAndFromTheSurface) {
    for (const float tiling : {1.f, 3.f}) {
        const SquareShell sq = square_shell(64, 48, 0.05f, tiling, 33);
        MappedFieldComparison cmp(sq);
        PCG32 rng(19);
        for (int k = 0; k < 16000; ++k) {
            const int kind = k % 4;
            double theta = std::acos(1 - rng.next_double() * (1 - std::cos(85.0 * M_PI / 180))),
                   phi = 2 * M_PI * rng.next_double();
            double px = -0.9 + 1.8 * rng.next_double(), py = -0.9 + 1.8 * rng.next_double();
            if (kind == 0) theta = (85.0 + 4.9 * rng.next_double()) * M_PI / 180;
            if (kind == 1) {  // on the diagonal, along it or vertical
                py = px;
                const double r = rng.next_double();
                phi = r < 0.4 ? M_PI / 4 : r < 0.8 ? 5 * M_PI / 4 : phi;
                if (r >= 0.8) theta = 0.0;
            }
            if (kind == 2) {  // through a cell-grid vertex
                px = std::floor(rng.next_double() * 2 * cmp.sx) / cmp.sx - 1;
                py = std::floor(rng.next_double() * 2 * cmp.sy) / cmp.sy - 1;
            }
            Vec3 d = direction(theta, phi);
            const double s = 0.2 / std::max(std::cos(theta), 0.02);
            Vec3 o(float(px - s * d.x), float(py - s * d.y), float(0.1 - s * d.z));
            if (kind == 3) {  // from the surface: off the first hit, up (mirrored) or on down
                float t;
                if (!shell_hit(*sq.shape, o, d, t)) continue;
                const bool up = rng.next_float() < 0.6f;
                o = o + d * t + Vec3(0.f, 0.f, up ? 2e-5f : -2e-5f);
                if (up) d = Vec3(d.x, d.y, -d.z);
            }
            cmp.add(o, d);
        }
        cmp.expect_agreement(9000, 100, tiling, "shell vs field, edges");
    }
}

namespace {

/// A curved 6 x 6 grid over [-1, 1]^2 with z = bend (x^2 - 0.5 y^2) and smooth normals: the
/// tetrahedra of a prism there have different world -> cell maps (no Prism::same_map).
std::shared_ptr<ShellShape> curved_shell(float amp, float bend, uint64_t seed, std::shared_ptr<const Heightfield> &field) {
    TriangleMesh m;
    const int n = 6;
    for (int j = 0; j <= n; ++j)
        for (int i = 0; i <= n; ++i) {
            const float x = -1.f + 2.f * float(i) / n, y = -1.f + 2.f * float(j) / n;
            m.positions.push_back(Vec3(x, y, bend * (x * x - 0.5f * y * y)));
            m.uvs.push_back(Vec2(float(i) / n, float(j) / n));
        }
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) {
            const uint32_t a = uint32_t(j * (n + 1) + i), b = a + 1, c = a + uint32_t(n + 1), d = c + 1;
            m.indices.insert(m.indices.end(), {a, b, d, a, d, c});
        }
    HeightMap map(40, 40);
    PCG32 rng(seed);
    for (float &v : map.h) v = rng.next_float();
    Displacement disp;
    disp.field = std::make_shared<Heightfield>(map, amp, 0.f);
    field = disp.field;
    return std::make_shared<ShellShape>(m, disp, "curved");
}

bool shell_occluded(const ShellShape &s, Vec3 o, Vec3 d, float tnear, float tfar) {
    for (uint32_t p = 0; p < s.primitive_count(); ++p)
        if (s.occluded_prism(p, o, d, tnear, tfar)) return true;
    return false;
}

/// Closest hit in (tnear, tfar) over all prisms.
bool shell_hit_in(const ShellShape &s, Vec3 o, Vec3 d, float tnear, float tfar, float &t) {
    bool hit = false;
    for (uint32_t p = 0; p < s.primitive_count(); ++p) {
        uint32_t tet;
        float x, y;
        hit |= s.intersect_prism(p, o, d, tnear, tfar, tet, x, y);
    }
    t = tfar;
    return hit;
}

/// occluded_prism (with its early out for rays that end on the other side of the surface)
/// against the closest-hit traversal: occluded in (tnear, tfar) exactly when the closest hit
/// lies there, except where the closest hit is within round-off of tfar or the ray grazes.
/// Rays: from above through the shell, from the surface upwards and downwards (as spawned
/// rays leave it), grazing, along the prisms' diagonals and through grid vertices, ending
/// just before or after their hit.
void check_occlusion_matches_hits(const ShellShape &s, uint64_t seed, const char *what) {
    PCG32 rng(seed);
    int agree = 0, disagree = 0, occluded = 0, near_end = 0;
    for (int k = 0; k < 20000; ++k) {
        const int kind = k % 4;
        const float px = -0.95f + 1.9f * rng.next_float(), py = -0.95f + 1.9f * rng.next_float();
        // kind 2: along a diagonal of the grid (prism boundaries); kind 3: through grid vertices.
        const float qx = kind == 3 ? -1.f + 2.f * float(int(rng.next_float() * 6.f)) / 6.f : px;
        const float qy = kind == 2 ? qx + (rng.next_float() < 0.5f ? 0.f : 1.f / 3.f) : kind == 3 ? -1.f + 2.f * float(int(rng.next_float() * 6.f)) / 6.f : py;
        const double theta = (kind == 1 ? 60.0 + 29.9 * rng.next_double() : 85.0 * rng.next_double()) * M_PI / 180,
                     phi = kind == 2 ? M_PI / 4 : 2 * M_PI * rng.next_double();
        Vec3 d(float(std::sin(theta) * std::cos(phi)), float(std::sin(theta) * std::sin(phi)), float(-std::cos(theta)));
        Vec3 o = Vec3(qx, qy, 0.f) - d * 1.f;
        float tnear = 0.f;
        if (kind == 1) {
            // From the surface: the first hit from above, then up or down from just off it.
            float t0;
            if (!shell_hit_in(s, o, d, 0.f, Infinity, t0)) continue;
            const Vec3 p = o + d * t0;
            const bool up = rng.next_float() < 0.7f;
            d = Vec3(d.x, d.y, up ? -d.z : d.z);
            o = p + Vec3(0.f, 0.f, up ? 2e-5f : -2e-5f);
            tnear = 0.f;
        }
        float th;
        const bool hit = shell_hit_in(s, o, d, tnear, Infinity, th);
        // tfar before or after the hit (or, without one, somewhere along the ray).
        const float tfar = hit ? th * (rng.next_float() < 0.5f ? 0.999f : 1.001f) : 4.f * rng.next_float();
        const bool expect = hit && th < tfar;
        const bool occ = shell_occluded(s, o, d, tnear, tfar);
        occluded += occ;
        if (occ == expect) {
            ++agree;
            continue;
        }
        // Another crossing before tfar that the closest hit passed at a graze, or round-off at tfar.
        if (hit && std::abs(th - tfar) < 1e-5f * (1.f + th)) {
            ++near_end;
            continue;
        }
        ++disagree;
        if (disagree <= 5)
            ADD_FAILURE() << what << ": ray " << k << " (kind " << kind << ") occluded " << occ << ", closest hit "
                          << hit << " at " << th << ", tfar " << tfar;
    }
    EXPECT_EQ(disagree, 0) << what;
    EXPECT_GT(agree, 15000) << what;
    EXPECT_GT(occluded, 4000) << what;
    EXPECT_LE(near_end, 20) << what;
}

}  // namespace

TEST(ShellShape, OccludedAgreesWithTheClosestHit) {
    for (const float tiling : {1.f, 3.f}) {
        const SquareShell sq = square_shell(64, 48, 0.05f, tiling, 41);
        check_occlusion_matches_hits(*sq.shape, 7, tiling == 1.f ? "flat square, tiling 1" : "flat square, tiling 3");
    }
    // Prism cell origins beyond the map and negative (the early out reduces them to one period).
    const SquareShell far = square_shell(64, 48, 0.05f, 2.f, 45, Vec2(11.25f, -6.5f));
    check_occlusion_matches_hits(*far.shape, 8, "flat square, uv shifted by (11.25, -6.5)");
    std::shared_ptr<const Heightfield> field;
    const auto curved = curved_shell(0.05f, 0.3f, 43, field);
    check_occlusion_matches_hits(*curved, 9, "curved grid");
}

// Flat quads (two one_map prisms with one map forming a convex quad) are one Embree primitive
// clipped against the quad's edges: on a flat 5 x 5 grid every square merges, and hits equal
// the mapped field's (an independent path without prisms) at height scales 0, 1e-6, 0.05 and
// 1e4, for rays from above (up to 89.9 degrees from the normal, along the diagonals and
// through grid vertices) and from the surface up and down.
TEST(ShellShape, FlatGridMergesIntoQuadsThatMatchTheMappedField) {
    for (const float amp : {0.f, 1e-6f, 0.05f, 1e4f}) {
        const SquareShell sq = square_shell(40, 40, amp, 2.f, 51, Vec2(0.f, 0.f), 5);
        EXPECT_EQ(sq.shape->prism_count(), 50u) << amp;
        EXPECT_EQ(sq.shape->primitive_count(), 25u) << amp;
        MappedFieldComparison cmp(sq);
        // At 1e4 the walls rise 1e4 a cell: the two paths' cell coordinates differ by a few
        // float ulps (1e-5 cells at 80 cells), which moves the height under a vertical ray by
        // up to ~0.5, 5e-5 of t.
        if (amp > 1.f) cmp.tol = 1e-4;
        PCG32 rng(53);
        const double above = double(sq.shape->shell_max()) + 0.1;
        for (int k = 0; k < 12000; ++k) {
            const int kind = k % 4;
            double theta = std::acos(1 - rng.next_double() * (1 - std::cos(85.0 * M_PI / 180))),
                   phi = 2 * M_PI * rng.next_double();
            double px = -0.9 + 1.8 * rng.next_double(), py = -0.9 + 1.8 * rng.next_double();
            if (kind == 0) theta = (85.0 + 4.9 * rng.next_double()) * M_PI / 180;  // up to 89.9 degrees
            // Walls 1e4 high over cells 1/40 wide: a slanted ray's hit there depends on its
            // cell-space position to 1e4 x float round-off, in both paths; vertical rays'
            // hits (the height at a point) do not.
            if (amp > 1.f) theta = 0.0;
            if (kind == 1) {  // on a grid line or a diagonal, or through a grid vertex
                const double gx = -1.0 + 0.4 * std::floor(rng.next_double() * 5.0);
                const double r = rng.next_double();
                if (r < 0.3) px = gx;
                else if (r < 0.6) py = px + (gx + 1.0);
                else px = gx, py = -1.0 + 0.4 * std::floor(rng.next_double() * 5.0);
                if (r >= 0.3 && r < 0.6) phi = rng.next_double() < 0.5 ? M_PI / 4 : 5 * M_PI / 4;
            }
            Vec3 d = direction(theta, phi);
            const double s = above / std::max(std::cos(theta), 1e-3);
            Vec3 o(float(px - s * d.x), float(py - s * d.y), float(-s * d.z));
            if (kind == 3) {  // from the surface: off the first hit, up (mirrored) or on down
                float t;
                if (!shell_hit(*sq.shape, o, d, t)) continue;
                const bool up = rng.next_float() < 0.6f;
                const float off = 2e-5f * std::max(1.f, amp);
                o = o + d * t + Vec3(0.f, 0.f, up ? off : -off);
                if (up) d = Vec3(d.x, d.y, -d.z);
            }
            cmp.add(o, d);
        }
        cmp.expect_agreement(5000, 100, amp, "grid of quads vs field; the 'tiling' printed is the height scale; units tol");
    }
}

// Pairs that must not merge: a flat dart (two triangles with one map whose union is not
// convex) stays two primitives, rays down into its notch miss and rays into either triangle
// hit at the field's height; prisms of a curved grid (different maps) stay one a primitive.
TEST(ShellShape, NonConvexAndCurvedPairsStaySeparate) {
    TriangleMesh m;
    // Cell-space dart (0, 0) (2, 1) (0, 2) (0.5, 1), reflex at (0.5, 1), as (x - 1, y - 1).
    m.positions = {Vec3(-1, -1, 0), Vec3(1, 0, 0), Vec3(-1, 1, 0), Vec3(-0.5f, 0, 0)};
    m.normals.assign(4, Vec3(0, 0, 1));
    for (const Vec3 &p : m.positions) m.uvs.push_back(Vec2((p.x + 1) / 2, (p.y + 1) / 2));
    m.indices = {0, 1, 3, 3, 1, 2};
    HeightMap map(16, 16);
    PCG32 rng(61);
    for (float &v : map.h) v = rng.next_float();
    Displacement disp;
    disp.field = std::make_shared<Heightfield>(map, 0.05f, 0.f);
    const ShellShape dart(m, disp, "dart");
    EXPECT_EQ(dart.prism_count(), 2u);
    EXPECT_EQ(dart.primitive_count(), 2u);
    int hits = 0, notch = 0;
    for (int k = 0; k < 4000; ++k) {
        const float x = -1.f + 2.f * rng.next_float(), y = -1.f + 2.f * rng.next_float();
        float t;
        const bool hit = shell_hit(dart, Vec3(x, y, 1.f), Vec3(0, 0, -1), t);
        // Inside the dart: within both triangles' union, 1e-3 away from its edges.
        auto side = [&](float ax, float ay, float bx, float by) { return (bx - ax) * (y - ay) - (by - ay) * (x - ax); };
        const bool in1 = side(-1, -1, 1, 0) > 1e-3f && side(1, 0, -0.5f, 0) > 1e-3f && side(-0.5f, 0, -1, -1) > 1e-3f;
        const bool in2 = side(-0.5f, 0, 1, 0) > 1e-3f && side(1, 0, -1, 1) > 1e-3f && side(-1, 1, -0.5f, 0) > 1e-3f;
        // In the notch: inside the convex hull (0, 0) (2, 1) (0, 2) but left of the dart's reflex edges.
        const bool in_hull = side(-1, -1, 1, 0) > 1e-3f && side(1, 0, -1, 1) > 1e-3f && x > -1.f + 1e-3f;
        const bool in_notch = in_hull && side(-0.5f, 0, -1, -1) < -1e-3f && side(-1, 1, -0.5f, 0) < -1e-3f;
        if (in1 || in2) {
            ASSERT_TRUE(hit) << x << " " << y;
            const float h = disp.field->eval((x + 1.0) * 8.0, (y + 1.0) * 8.0);
            EXPECT_NEAR(1.f - t, h, 1e-5f) << x << " " << y;
            ++hits;
        }
        if (in_notch) {
            EXPECT_FALSE(hit) << "a hit in the notch at " << x << " " << y;
            ++notch;
        }
    }
    EXPECT_GT(hits, 1000);
    EXPECT_GT(notch, 100);
    std::shared_ptr<const Heightfield> field;
    const auto curved = curved_shell(0.05f, 0.3f, 43, field);
    EXPECT_EQ(curved->primitive_count(), curved->prism_count());
}
