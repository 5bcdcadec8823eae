#include "geometry/heightfield.h"
#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <type_traits>
#include <fmt/format.h>
#include "core/error.h"
#include "image/wrap_mode.h"
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace meso {

namespace {

/// Periodic index in [0, n) (image/wrap_mode.h's, which skips the division in range).
inline int64_t wrap_index(int64_t i, int n) { return meso::wrap_index(i, int64_t(n), WrapMode::Repeat); }

/// floor() as an integer, exact for the cell-space magnitudes meso uses.
inline int64_t ifloor(double x) { return int64_t(std::floor(x)); }

/// 1/d with zero components replaced by a tiny value of the same sign (slab tests then
/// give +-huge instead of NaN for rays parallel to a slab).
inline float safe_inv(float d) {
    const float tiny = 1e-30f;
    return 1.f / (std::abs(d) > tiny ? d : std::copysign(tiny, d));
}

/// Paper 004, Appendix A: height and slopes of the bilinear patch with corner heights h00
/// (0, 0), h10 (1, 0), h01 (0, 1), h11 (1, 1) at (a, b) in the unit square; g is the twist.
inline float bilinear_patch(float h00, float h10, float h01, float h11, float a, float b, float &dhdx, float &dhdy) {
    const float g = h00 + h11 - h10 - h01;
    dhdx = h10 - h00 + b * g;
    dhdy = h01 - h00 + a * g;
    return h00 + a * (h10 - h00) + b * (h01 - h00) + a * b * g;
}

/// A pyramid level as built: w x h nodes, min and max height of each (2 floats a node).
struct FlatLevel {
    int w = 0, h = 0;
    std::vector<float> minmax;
};

/// The next level up: node (i, j) covers the children (2i..2i+1, 2j..2j+1) that exist.
FlatLevel coarser_level(const FlatLevel &c) {
    FlatLevel n{(c.w + 1) / 2, (c.h + 1) / 2, {}};
    n.minmax.resize(size_t(n.w) * n.h * 2);
    for (int j = 0; j < n.h; ++j)
        for (int i = 0; i < n.w; ++i) {
            float mn = Infinity, mx = -Infinity;
            for (int dj = 0; dj < 2; ++dj)
                for (int di = 0; di < 2; ++di) {
                    int ci = 2 * i + di, cj = 2 * j + dj;
                    if (ci >= c.w || cj >= c.h) continue;
                    mn = std::min(mn, c.minmax[(size_t(cj) * c.w + ci) * 2]);
                    mx = std::max(mx, c.minmax[(size_t(cj) * c.w + ci) * 2 + 1]);
                }
            n.minmax[(size_t(j) * n.w + i) * 2] = mn;
            n.minmax[(size_t(j) * n.w + i) * 2 + 1] = mx;
        }
    return n;
}

/// The level's min/max in 4 x 4 blocks of nodes (Heightfield::Level::blocks), bw blocks a row.
std::vector<float> pack_blocks(const FlatLevel &f, int bw) {
    const int bh = (f.h + 3) / 4;
    std::vector<float> blocks(size_t(bw) * bh * 32, 0.f);
    for (int j = 0; j < f.h; ++j)
        for (int i = 0; i < f.w; ++i) {
            float *q = &blocks[(size_t(j >> 2) * bw + size_t(i >> 2)) * 32];
            const int slot = (i & 3) | (j & 3) << 2;
            q[slot] = f.minmax[(size_t(j) * f.w + i) * 2];
            q[16 + slot] = f.minmax[(size_t(j) * f.w + i) * 2 + 1];
        }
    return blocks;
}

}  // namespace

Heightfield::Heightfield(const HeightMap &map, float scale, float offset) {
    if (map.width < 1 || map.height < 1 || map.h.size() != size_t(map.width) * map.height)
        throw MesoError(fmt::format("height map has an invalid size {}x{}", map.width, map.height));
    if (!std::isfinite(scale) || !std::isfinite(offset))
        throw MesoError("height map scale and offset must be finite");
    m_w = map.width;
    m_h = map.height;
    m_heights.resize(map.h.size());
    m_min = Infinity;
    m_max = -Infinity;
    for (size_t i = 0; i < map.h.size(); ++i) {
        float v = offset + scale * map.h[i];
        if (!std::isfinite(v)) throw MesoError("height map has a non-finite value (after scale and offset)");
        m_heights[i] = v;
        m_min = std::min(m_min, v);
        m_max = std::max(m_max, v);
    }
    // Level 0: one node per cell, min/max of its four corners (wrapping); level k + 1: node
    // (i, j) covers the children (2i..2i+1, 2j..2j+1) of level k that exist. Built flat (2
    // floats a node), stored in 4 x 4 blocks (Level::blocks).
    FlatLevel flat{m_w, m_h, std::vector<float>(size_t(m_w) * m_h * 2)};
    for (int j = 0; j < m_h; ++j) {
        int j1 = j + 1 == m_h ? 0 : j + 1;
        for (int i = 0; i < m_w; ++i) {
            int i1 = i + 1 == m_w ? 0 : i + 1;
            float a = m_heights[size_t(j) * m_w + i], b = m_heights[size_t(j) * m_w + i1];
            float c = m_heights[size_t(j1) * m_w + i], d = m_heights[size_t(j1) * m_w + i1];
            flat.minmax[(size_t(j) * m_w + i) * 2] = std::min(std::min(a, b), std::min(c, d));
            flat.minmax[(size_t(j) * m_w + i) * 2 + 1] = std::max(std::max(a, b), std::max(c, d));
        }
    }
    for (;;) {
        Level L;
        L.w = flat.w;
        L.h = flat.h;
        L.bw = (flat.w + 3) / 4;
        L.blocks = pack_blocks(flat, L.bw);
        m_levels.push_back(std::move(L));
        if (flat.w == 1 && flat.h == 1) break;
        flat = coarser_level(flat);
    }
}

float Heightfield::vertex(int64_t i, int64_t j) const {
    return m_heights[size_t(wrap_index(j, m_h)) * m_w + size_t(wrap_index(i, m_w))];
}

float Heightfield::eval(double x, double y) const {
    float dx, dy;
    return eval(x, y, dx, dy);
}

float Heightfield::eval(double x, double y, float &dhdx, float &dhdy) const {
    const int64_t i = ifloor(x), j = ifloor(y);
    const float a = float(x - double(i)), b = float(y - double(j));
    // The cell's corners (i, j) .. (i + 1, j + 1), wrapped once (vertex() per corner
    // wrapped each, eight integer divisions).
    const size_t i0 = size_t(wrap_index(i, m_w)), j0 = size_t(wrap_index(j, m_h));
    const size_t i1 = i0 + 1 == size_t(m_w) ? 0 : i0 + 1, j1 = j0 + 1 == size_t(m_h) ? 0 : j0 + 1;
    const float *r0 = &m_heights[j0 * size_t(m_w)], *r1 = &m_heights[j1 * size_t(m_w)];
    return bilinear_patch(r0[i0], r0[i1], r1[i0], r1[i1], a, b, dhdx, dhdy);
}

HeightMap Heightfield::box_downsampled(int f) const {
    if (f < 1 || m_w % f != 0 || m_h % f != 0)
        throw MesoError(fmt::format("cannot box-downsample a {}x{} map by {} (the factor must divide both sizes)", m_w, m_h, f));
    HeightMap out(m_w / f, m_h / f);
    for (int j = 0; j < out.height; ++j)
        for (int i = 0; i < out.width; ++i) {
            double sum = 0;
            for (int b = 0; b < f; ++b)
                for (int a = 0; a < f; ++a) sum += m_heights[size_t(j * f + b) * m_w + size_t(i * f + a)];
            out.at(i, j) = float(sum / (double(f) * f));
        }
    return out;
}

size_t Heightfield::memory_bytes() const {
    size_t bytes = m_heights.size() * sizeof(float);
    for (const Level &l : m_levels) bytes += l.blocks.size() * sizeof(float);
    return bytes;
}

namespace {

/// intersect_bilinear_patch with the ray origin (relative to the cell corner) in double:
/// the traversal forms it as o - corner exactly, so that every cell sees the same ray (a
/// float o - corner rounds differently per cell, which opened gaps at cell seams).
bool patch_root(double lox, double loy, double loz, Vec3 d, float h00, float h10, float h01, float h11, float t0,
                float t1, float &t_hit) {
    if (!(t1 >= t0)) return false;
    // Re-base the ray at t0 so the quadratic works with small numbers: s = t - t0.
    const double ox = lox + double(t0) * d.x, oy = loy + double(t0) * d.y, oh = loz + double(t0) * d.z;
    const double dx = d.x, dy = d.y, dh = d.z;
    const double e = double(h10) - h00, f = double(h01) - h00, g = double(h00) + h11 - h10 - h01;
    // F(s) = ray height - patch height = A s^2 + B s + C.
    const double A = -g * dx * dy;
    const double B = dh - e * dx - f * dy - g * (ox * dy + oy * dx);
    const double C = oh - h00 - e * ox - f * oy - g * ox * oy;
    const double smax = double(t1) - double(t0);
    auto F = [&](double s) { return (A * s + B) * s + C; };
    // No root: F has one strict sign at both ends and is monotone in between (F' = 2 A s + B,
    // linear, of one strict sign at both ends), most of the cells a ray passes over. No sqrt
    // or division then. A root the closed form would place within round-off inside an end
    // lies within the neighbouring cell's one-ulp overlap, which finds it.
    const double f_end = F(smax);
    if (C * f_end > 0.0 && B * (2.0 * A * smax + B) > 0.0) return false;

    double roots[2];
    int n = 0;
    // Linear when the quadratic term is negligible over the interval: |A| smax^2 against
    // |B| smax + |C| (scale-free in d; |A| max(smax, 1) against |B| + |C| took a real
    // quadratic for a line once |d| was small and the interval long, e.g. |d| = 1e-20).
    if (std::abs(A) * smax * smax <= 1e-12 * (std::abs(B) * smax + std::abs(C)) || A == 0.0) {
        if (B != 0.0) roots[n++] = -C / B;
    } else {
        double disc = B * B - 4 * A * C;
        if (disc >= 0) {
            double q = -0.5 * (B + std::copysign(std::sqrt(disc), B));
            double r0 = q / A, r1 = q != 0.0 ? C / q : r0;
            roots[n++] = std::min(r0, r1);
            roots[n++] = std::max(r0, r1);
        }
    }
    for (int k = 0; k < n; ++k)
        if (roots[k] >= 0.0 && roots[k] <= smax) {
            t_hit = float(double(t0) + roots[k]);
            return true;
        }
    // Round-off guard: a sign change of F over [0, smax] is a crossing the closed form
    // missed (roots a hair outside the interval). Take the root nearest the interval.
    const double f0 = F(0.0), f1 = f_end;
    if ((f0 <= 0.0 && f1 >= 0.0) || (f0 >= 0.0 && f1 <= 0.0)) {
        double best = 0.0, dist = Infinity;
        for (int k = 0; k < n; ++k) {
            double dd = roots[k] < 0.0 ? -roots[k] : roots[k] - smax;
            if (dd < dist) dist = dd, best = std::clamp(roots[k], 0.0, smax);
        }
        if (n == 0) best = f0 == 0.0 ? 0.0 : smax;
        t_hit = float(double(t0) + best);
        return true;
    }
    return false;
}

}  // namespace

bool intersect_bilinear_patch(Vec3 o, Vec3 d, float h00, float h10, float h01, float h11, float t0, float t1,
                              float &t_hit) {
    return patch_root(o.x, o.y, o.z, d, h00, h10, h01, h11, t0, t1, t_hit);
}

bool Heightfield::intersect(Vec3 o, Vec3 d, float tmin, float tmax, HeightfieldHit &hit, int64_t ox,
                            int64_t oy) const {
    return traverse<false, true>(o, d, tmin, tmax, &hit, ox, oy);
}

bool Heightfield::occluded(Vec3 o, Vec3 d, float tmin, float tmax, int64_t ox, int64_t oy) const {
    return traverse<true, true>(o, d, tmin, tmax, nullptr, ox, oy);
}

bool Heightfield::intersect_reference(Vec3 o, Vec3 d, float tmin, float tmax, HeightfieldHit &hit, int64_t ox,
                                      int64_t oy) const {
    return traverse<false, false>(o, d, tmin, tmax, &hit, ox, oy);
}

bool Heightfield::occluded_reference(Vec3 o, Vec3 d, float tmin, float tmax, int64_t ox, int64_t oy) const {
    return traverse<true, false>(o, d, tmin, tmax, nullptr, ox, oy);
}

namespace {

/// A node of the min-max pyramid: (i, j) of `level`, covering 2^level x 2^level cells of
/// its tile (fewer at the tile's right and top edges).
struct PyramidNode {
    int level, i, j;
};

/// The ncols x nrows nodes of `level` from (i0, j0) (at most 4 x 4, all of which exist).
struct NodeBlock {
    int level, i0, j0, ncols, nrows;
};

/// The nodes still to visit in the current tile, depth first, kept as blocks with the bits of
/// their nodes still to visit (block_overlap's mask; the lowest bit of the top block is
/// visited next): one entry a tested block instead of one a node that passed, most of which a
/// closest hit never reaches. A step adds at most one block and goes down at least one level,
/// and a block stays only while it has bits, so the levels decrease up the stack: at most one
/// entry a level (32 levels at most, the sizes being ints).
struct NodeStack {
    struct Entry {
        NodeBlock b;
        int mask;
    };
    Entry e[34];
    int size = 0;
    void push(const NodeBlock &b, int mask) {
        if (mask) e[size++] = {b, mask};
    }
    bool empty() const { return size == 0; }
};

/// Position of the 2D DDA over the W x H tile grid.
struct TileWalk {
    int64_t tx = 0, ty = 0;     ///< the current tile
    int stepx = 1, stepy = 1;   ///< tile step along the ray in x and y
    double tnx = 0, tny = 0;    ///< ray parameter of the next tile boundary in x and y
};

/// The part of the ray inside the current tile.
struct TileSegment {
    float tile_x = 0.f, tile_y = 0.f;  ///< tile origin in the caller's (small) coordinates
    float seg0 = 0.f, seg1 = 0.f;      ///< the segment's ray parameters
    float pad = 0.f;                   ///< their widening (kNodePad relative)
};

/// Ray height minus patch height over one cell, in the ray's frame relative to the cell corner.
struct CellPatch {
    double lx = 0, ly = 0;                     ///< ray origin relative to the cell corner (exact)
    float h00 = 0, h10 = 0, h01 = 0, h11 = 0;  ///< corner heights
};

/// Relative widening of the node intervals, which only cull (the leaves clip exactly):
/// covers the float round-off of the slab values (~2e-7). Relative to the tile segment's
/// ends: a node is culled or kept by a comparison of values within the segment, and slab
/// values far outside it (up to +-1e30 for a ray parallel to an axis) are clamped to it.
constexpr float kNodePad = 1e-6f;

/// std::nextafter(x, +infinity), by the bits (no libm call in the leaf test).
inline float next_up(float x) {
    if (!(x < Infinity)) return x;  // +inf, NaN
    if (x == 0.f) return std::numeric_limits<float>::denorm_min();
    uint32_t b;
    std::memcpy(&b, &x, sizeof b);
    b = x > 0.f ? b + 1 : b - 1;
    std::memcpy(&x, &b, sizeof b);
    return x;
}
/// std::nextafter(x, -infinity).
inline float next_down(float x) { return -next_up(-x); }

inline int64_t floor_div(int64_t a, int64_t b) {
    if (a >= 0 && a < b) return 0;  // the common case, without an integer division
    int64_t q = a / b;
    return (a % b != 0 && a < 0) ? q - 1 : q;
}

/// Ray parameter at which p0 + t dir leaves tile `tile` (tile k spans [k size - off,
/// (k + 1) size - off)) in the direction `step`; infinity when the ray does not move.
inline double tile_exit_t(int64_t tile, int step, int64_t size, int64_t off, double p0, double dir) {
    if (dir == 0.0) return double(Infinity);
    const double boundary = double((tile + (step > 0 ? 1 : 0)) * size - off);
    return (boundary - p0) / dir;
}

/// Narrows [c0, c1] to the t where l + t dd lies in [0, 1] (one axis of a cell); inv_dd =
/// 1 / dd in double (a product instead of two divisions a leaf; neighbouring cells still get
/// bitwise the same boundary: 1 - l here is -l' there, times the same inv_dd).
inline void clip_to_unit(double l, double dd, double inv_dd, double &c0, double &c1) {
    if (dd != 0.0) {
        double u = -l * inv_dd, v = (1.0 - l) * inv_dd;
        if (u > v) std::swap(u, v);
        c0 = std::max(c0, u);
        c1 = std::min(c1, v);
    } else if (!(l >= 0.0 && l <= 1.0)) {
        c1 = -double(Infinity);
    }
}

}  // namespace

/// One traverse() call. The ray is walked over the tiles it crosses (TileWalk); in each
/// tile, the pyramid is descended front to back, two levels a step, from a start block that
/// holds the ray's footprint (start_block), nodes whose padded [min, max] box the segment
/// misses are culled (node_overlaps, block_overlap), and the leaves solve the exact bilinear
/// patch (leaf_root).
struct Heightfield::Traversal {
    const Heightfield &f;
    Vec3 o, d;
    float inv[3];         ///< 1/d, tiny-safe
    double inv_dx, inv_dy;  ///< 1/d.x, 1/d.y in double (0 where d is 0) for the leaves' cell clip
    float tmin, tmax;     ///< clipped to the field's height slab by clip_to_height_slab
    int64_t ox, oy;       ///< the caller's integer cell offset
    bool flip_x, flip_y;  ///< the ray runs towards -x, -y: a block's columns, rows are visited last to first

    Traversal(const Heightfield &field, Vec3 o_, Vec3 d_, float tmin_, float tmax_, int64_t ox_, int64_t oy_)
        : f(field), o(o_), d(d_), tmin(tmin_), tmax(tmax_), ox(ox_), oy(oy_) {
        // Zero (and denormal-small) direction components become +0: the tile walk (no step
        // along that axis), the slab tests (1/d = +1e30) and the child order then all agree on
        // which side of a cell boundary a ray lying exactly on it belongs to. With -0 the slab
        // tests placed such a ray in the cell on the far side of the boundary while the tile
        // walk never visited the tile holding that cell: vertical rays at x or y a multiple of
        // W or H leaked through.
        for (int k = 0; k < 3; ++k)
            if (!(std::abs(d[k]) > 1e-30f)) d[k] = 0.f;
        inv[0] = safe_inv(d.x);
        inv[1] = safe_inv(d.y);
        inv[2] = safe_inv(d.z);
        inv_dx = d.x != 0.f ? 1.0 / double(d.x) : 0.0;
        inv_dy = d.y != 0.f ? 1.0 / double(d.y) : 0.0;
        flip_x = d.x < 0;
        flip_y = d.y < 0;
    }

    /// Clips [tmin, tmax] to the height slab of the whole field; false if nothing is left.
    bool clip_to_height_slab() {
        // A horizontal ray is inside the slab or never meets it (with 1/d = 1e30 a ray just
        // below the field got t in [1e27, 1e27]: a walk over millions of tiles, and tile
        // indices that overflow).
        if (d.z == 0.f) return o.z >= f.m_min && o.z <= f.m_max;
        float ta = (f.m_min - o.z) * inv[2], tb = (f.m_max - o.z) * inv[2];
        if (ta > tb) std::swap(ta, tb);
        // Slightly widened: a ray grazing the top of the field must still reach the leaves.
        float pad = 1e-6f * (std::abs(ta) + std::abs(tb)) + 1e-30f;
        tmin = std::max(tmin, ta - pad);
        tmax = std::min(tmax, tb + pad);
        return tmax >= tmin;
    }

    /// The tile holding the ray at tmin. Tiles are walked in the caller's small
    /// coordinates: tile k starts at k W - offset there, an integer computed exactly, so
    /// tile boundaries and the node boxes agree even when o.x + offset would not fit in a
    /// double's 53 bits.
    TileWalk start_tile_walk() const {
        const double W = f.m_w, H = f.m_h;
        const int64_t qx = floor_div(ox, f.m_w), qy = floor_div(oy, f.m_h);
        TileWalk w;
        w.tx = qx + ifloor((double(ox - qx * f.m_w) + double(o.x) + double(tmin) * d.x) / W);
        w.ty = qy + ifloor((double(oy - qy * f.m_h) + double(o.y) + double(tmin) * d.y) / H);
        w.stepx = d.x > 0 ? 1 : -1;
        w.stepy = d.y > 0 ? 1 : -1;
        w.tnx = tile_exit_t(w.tx, w.stepx, f.m_w, ox, o.x, d.x);
        w.tny = tile_exit_t(w.ty, w.stepy, f.m_h, oy, o.y, d.y);
        return w;
    }

    /// Whether the ray between tmin and tmax stays inside one tile, by a margin far above the
    /// walk's double round-off (the common case of a shell segment): then `w` gets that tile,
    /// which start_tile_walk would start in and never leave, without its divisions.
    bool single_tile(TileWalk &w) const {
        const int64_t qx = floor_div(ox, f.m_w), qy = floor_div(oy, f.m_h);
        const double bx = double(ox - qx * f.m_w) + double(o.x), by = double(oy - qy * f.m_h) + double(o.y);
        const double x0 = bx + double(tmin) * d.x, x1 = bx + double(tmax) * d.x;
        const double y0 = by + double(tmin) * d.y, y1 = by + double(tmax) * d.y;
        const double mx = 1e-6 * (1.0 + std::abs(bx)), my = 1e-6 * (1.0 + std::abs(by));
        const double W = f.m_w, H = f.m_h;
        if (!(std::min(x0, x1) >= mx && std::max(x0, x1) <= W - mx && std::min(y0, y1) >= my &&
              std::max(y0, y1) <= H - my))
            return false;
        w.tx = qx;
        w.ty = qy;
        return true;
    }

    /// Moves the walk into the next tile along the ray (the nearer of the two boundaries).
    void step_tile(TileWalk &w) const {
        if (w.tnx < w.tny) {
            w.tx += w.stepx;
            w.tnx = tile_exit_t(w.tx, w.stepx, f.m_w, ox, o.x, d.x);
        } else {
            w.ty += w.stepy;
            w.tny = tile_exit_t(w.ty, w.stepy, f.m_h, oy, o.y, d.y);
        }
    }

    TileSegment tile_segment(const TileWalk &w, double t0, double t1) const {
        TileSegment s;
        s.tile_x = float(w.tx * f.m_w - ox);
        s.tile_y = float(w.ty * f.m_h - oy);
        s.seg0 = float(t0);
        s.seg1 = float(t1);
        s.pad = kNodePad * (std::abs(s.seg0) + std::abs(s.seg1)) + 1e-30f;
        return s;
    }

    /// Starts below the tile's root: at the lowest even level at which the segment's footprint
    /// in this tile lies within 4 x 4 nodes, the start block (a short segment through a shell
    /// tetrahedron skips most of the pyramid). The footprint is padded; extra nodes are only
    /// culled.
    NodeBlock start_block(const TileSegment &s) const {
        const int top = int(f.m_levels.size()) - 1;
        const float xa = o.x + s.seg0 * d.x - s.tile_x, xb = o.x + s.seg1 * d.x - s.tile_x;
        const float ya = o.y + s.seg0 * d.y - s.tile_y, yb = o.y + s.seg1 * d.y - s.tile_y;
        const float bx0 = std::max(std::min(xa, xb) - 1e-3f, 0.f), bx1 = std::min(std::max(xa, xb) + 1e-3f, float(f.m_w));
        const float by0 = std::max(std::min(ya, yb) - 1e-3f, 0.f), by1 = std::min(std::max(ya, yb) + 1e-3f, float(f.m_h));
        const float extent = std::max(bx1 - bx0, by1 - by0);
        if (!(std::isfinite(extent) && bx1 >= bx0 && by1 >= by0)) return {top, 0, 0, 1, 1};
        const int ix0 = int(bx0), ix1 = int(bx1), iy0 = int(by0), iy1 = int(by1);
        // No level below floor(log2(extent)) - 2 holds the footprint in 4 nodes an axis.
        int k = extent >= 8.f ? std::min(std::ilogb(extent) - 2, top) : 0;
        while (k < top && ((ix1 >> k) - (ix0 >> k) > 3 || (iy1 >> k) - (iy0 >> k) > 3)) ++k;
        // An even level: the steps of two levels then end on the leaves (no 2 x 2 step from
        // level 1, whose heights are gathered), in as many steps.
        k += k & 1;
        if (k >= top) return {top, 0, 0, 1, 1};
        const Level &L = f.m_levels[k];
        const int i0 = std::min(ix0 >> k, L.w - 1), i1 = std::min(ix1 >> k, L.w - 1);
        const int j0 = std::min(iy0 >> k, L.h - 1), j1 = std::min(iy1 >> k, L.h - 1);
        return {k, i0, j0, i1 - i0 + 1, j1 - j0 + 1};
    }

    /// The next node to visit, taken off the stack: the lowest bit of the top block's mask (bit
    /// c' + 4 r': the node visited c'-th in its row, r'-th row; see block_overlap), so that of
    /// a block's nodes the one the ray enters first comes first. A ray visits the cells it
    /// crosses in this order: it moves monotonically in x and y, so of two cells it crosses
    /// the one in an earlier row (in its y direction), or in the same row and an earlier
    /// column, comes first.
    PyramidNode pop_node(NodeStack &stack) const {
        NodeStack::Entry &t = stack.e[stack.size - 1];
        const PyramidNode nd = block_node(t.b, __builtin_ctz(unsigned(t.mask)));
        t.mask &= t.mask - 1;
        if (!t.mask) --stack.size;
        return nd;
    }

    /// The node of `b` at bit q of block_overlap's mask.
    PyramidNode block_node(const NodeBlock &b, int q) const {
        const int c = q & 3, r = q >> 2;
        return {b.level, b.i0 + (flip_x ? 3 - c : c), b.j0 + (flip_y ? 3 - r : r)};
    }

    /// The bits of block_overlap's mask for the nodes of `b` (all exist).
    int block_exist(const NodeBlock &b) const {
        const int cols = flip_x ? (0xF << (4 - b.ncols)) & 0xF : (1 << b.ncols) - 1;
        int m = 0;
        for (int r = 0; r < b.nrows; ++r) m |= cols << 4 * (flip_y ? 3 - r : r);
        return m;
    }

    /// Whether the segment meets the node's box (cells in x, y; its [min, max] in height),
    /// both padded by the segment's pad. (x0, y0): the box's lower corner.
    bool node_overlaps(const PyramidNode &nd, const TileSegment &s, float &x0, float &y0) const {
        const Level &L = f.m_levels[nd.level];
        const int span = 1 << nd.level;
        x0 = s.tile_x + float(nd.i * span);
        y0 = s.tile_y + float(nd.j * span);
        const float x1 = s.tile_x + float(std::min((nd.i + 1) * span, f.m_w));
        const float y1 = s.tile_y + float(std::min((nd.j + 1) * span, f.m_h));
        float ta, tb, tc, td, te, tf;
        slab(x0, x1, o.x, inv[0], ta, tb);
        slab(y0, y1, o.y, inv[1], tc, td);
        slab(L.min_at(nd.i, nd.j), L.max_at(nd.i, nd.j), o.z, inv[2], te, tf);
        const float t_near = std::max(std::max(std::max(ta, tc), te), s.seg0);
        const float t_far = std::min(std::min(std::min(tb, td), tf), s.seg1);
        return t_near - s.pad <= t_far + s.pad;
    }

    /// The ray's [t_lo, t_hi] between the planes a and b of one axis (origin p, 1/d inv):
    /// sorted (block_overlap sorts with the same comparisons in SSE).
    static void slab(float a, float b, float p, float inv_d, float &t_lo, float &t_hi) {
        const float u = (a - p) * inv_d, v = (b - p) * inv_d;
        t_lo = v < u ? v : u;  // _mm_min_ps(v, u)
        t_hi = u > v ? u : v;  // _mm_max_ps(u, v)
    }

    /// The ray's root in the leaf cell (x0, y0) of `nd`, in (tmin, tmax]; `cell` gets its patch.
    bool leaf_root(const PyramidNode &nd, float x0, float y0, CellPatch &cell, float &th) const {
        const int w = f.m_w;
        const int i1 = nd.i + 1 == w ? 0 : nd.i + 1, j1 = nd.j + 1 == f.m_h ? 0 : nd.j + 1;
        cell.h00 = f.m_heights[size_t(nd.j) * w + nd.i];
        cell.h10 = f.m_heights[size_t(nd.j) * w + i1];
        cell.h01 = f.m_heights[size_t(j1) * w + nd.i];
        cell.h11 = f.m_heights[size_t(j1) * w + i1];
        // The cell's own t interval, in double from the ray relative to the cell
        // corner (exact: a difference of two floats). Neighbouring cells compute
        // their shared boundary from the same numbers (1 - lx here is -lx' there),
        // so the leaves tile the ray without gaps, and a root is accepted only in
        // its own cell (roots on a patch's extension beyond the cell were hits off
        // the surface: a ray passing just over a ridge "hit" the extended slope).
        // One float ulp of slack each side covers the rounding of the two solves.
        cell.lx = double(o.x) - double(x0);
        cell.ly = double(o.y) - double(y0);
        double c0 = tmin, c1 = tmax;
        clip_to_unit(cell.lx, d.x, inv_dx, c0, c1);
        clip_to_unit(cell.ly, d.y, inv_dy, c0, c1);
        if (!(c1 >= c0)) return false;
        const float s0 = std::max(next_down(float(c0)), tmin);
        const float s1 = std::min(next_up(float(c1)), tmax);
        if (!patch_root(cell.lx, cell.ly, o.z, d, cell.h00, cell.h10, cell.h01, cell.h11, s0, s1, th)) return false;
        return th > tmin && !(th > tmax);
    }

    /// The hit at th on the leaf patch `cell` with corner (x0, y0).
    void record_hit(const CellPatch &cell, float x0, float y0, float th, HeightfieldHit &hit) const {
        // Local patch coordinates of the hit, clamped into the cell.
        const float a = std::clamp(float(cell.lx + double(th) * d.x), 0.f, 1.f),
                    b = std::clamp(float(cell.ly + double(th) * d.y), 0.f, 1.f);
        hit.t = th;
        hit.x = x0 + a;
        hit.y = y0 + b;
        hit.h = bilinear_patch(cell.h00, cell.h10, cell.h01, cell.h11, a, b, hit.dhdx, hit.dhdy);
    }

    /// The block below `nd` that the traversal steps to: its 4 x 4 grandchildren (two levels
    /// down), or at level 1 its 2 x 2 children (the leaves). Only the nodes that exist.
    NodeBlock below(const PyramidNode &nd) const {
        const int step = nd.level >= 2 ? 2 : 1, n = 1 << step;
        const Level &C = f.m_levels[nd.level - step];
        const int ci = n * nd.i, cj = n * nd.j;
        return {nd.level - step, ci, cj, std::min(n, C.w - ci), std::min(n, C.h - cj)};
    }

    /// Bit c' + 4 r' set: the node visited c'-th in its row, r'-th row (columns and rows of
    /// `b` in the ray's x and y directions; block_node maps bits to nodes) exists and
    /// node_overlaps holds for it. mm: 32 floats as in Level::blocks (mins, then maxes; row r
    /// of the block at 4 r) holding b's nodes from its corner. The SSE path computes
    /// node_overlaps' formula for four nodes of a row at once with the same float operations
    /// in the same order (std::max(a, b) is _mm_max_ps(b, a), NaNs and signed zeros
    /// included), so both paths cull the same nodes.
    int block_overlap(const NodeBlock &b, const float *mm, const TileSegment &s) const {
        const int span = 1 << b.level;
#if defined(__SSE2__)
        // Planes: lane k holds tile + float(min((first + k) span, size)) (rounding is
        // monotone, so the min may be taken after the conversion: node_overlaps' values).
        const __m128i k4 = _mm_sll_epi32(_mm_setr_epi32(0, 1, 2, 3), _mm_cvtsi32_si128(b.level));
        auto planes = [&](int first, float tile, int size) {
            const __m128 v = _mm_cvtepi32_ps(_mm_add_epi32(_mm_set1_epi32(first * span), k4));
            return _mm_add_ps(_mm_set1_ps(tile), _mm_min_ps(v, _mm_set1_ps(float(size))));
        };
        // Lane c' of a row is node column c = c' or, towards -x, 3 - c'.
        __m128 x0 = planes(b.i0, s.tile_x, f.m_w), x1 = planes(b.i0 + 1, s.tile_x, f.m_w);
        if (flip_x) {
            x0 = _mm_shuffle_ps(x0, x0, _MM_SHUFFLE(0, 1, 2, 3));
            x1 = _mm_shuffle_ps(x1, x1, _MM_SHUFFLE(0, 1, 2, 3));
        }
        const __m128 ox = _mm_set1_ps(o.x), ix = _mm_set1_ps(inv[0]);
        const __m128 u = _mm_mul_ps(_mm_sub_ps(x0, ox), ix), v = _mm_mul_ps(_mm_sub_ps(x1, ox), ix);
        const __m128 ta = _mm_min_ps(v, u), tb = _mm_max_ps(u, v);
        // The rows' y slabs, lane r for row r (as slab() sorts them).
        const __m128 oy = _mm_set1_ps(o.y), iy = _mm_set1_ps(inv[1]);
        const __m128 uy = _mm_mul_ps(_mm_sub_ps(planes(b.j0, s.tile_y, f.m_h), oy), iy);
        const __m128 vy = _mm_mul_ps(_mm_sub_ps(planes(b.j0 + 1, s.tile_y, f.m_h), oy), iy);
        const __m128 tcs = _mm_min_ps(vy, uy), tds = _mm_max_ps(uy, vy);
        const __m128 oz = _mm_set1_ps(o.z), iz = _mm_set1_ps(inv[2]);
        const __m128 seg0 = _mm_set1_ps(s.seg0), seg1 = _mm_set1_ps(s.seg1), pad = _mm_set1_ps(s.pad);
        auto row = [&](auto R) {
            constexpr int r = decltype(R)::value;
            const __m128 tc = _mm_shuffle_ps(tcs, tcs, _MM_SHUFFLE(r, r, r, r));
            const __m128 td = _mm_shuffle_ps(tds, tds, _MM_SHUFFLE(r, r, r, r));
            __m128 mn = _mm_loadu_ps(mm + 4 * r), mx = _mm_loadu_ps(mm + 16 + 4 * r);
            if (flip_x) {
                mn = _mm_shuffle_ps(mn, mn, _MM_SHUFFLE(0, 1, 2, 3));
                mx = _mm_shuffle_ps(mx, mx, _MM_SHUFFLE(0, 1, 2, 3));
            }
            const __m128 e = _mm_mul_ps(_mm_sub_ps(mn, oz), iz), g = _mm_mul_ps(_mm_sub_ps(mx, oz), iz);
            const __m128 te = _mm_min_ps(g, e), tf = _mm_max_ps(e, g);
            const __m128 t_near = _mm_max_ps(seg0, _mm_max_ps(te, _mm_max_ps(tc, ta)));
            const __m128 t_far = _mm_min_ps(seg1, _mm_min_ps(tf, _mm_min_ps(td, tb)));
            const int pass = _mm_movemask_ps(_mm_cmple_ps(_mm_sub_ps(t_near, pad), _mm_add_ps(t_far, pad)));
            return pass << 4 * (flip_y ? 3 - r : r);
        };
        int mask = row(std::integral_constant<int, 0>{});
        if (b.nrows > 1) mask |= row(std::integral_constant<int, 1>{});
        if (b.nrows > 2) mask |= row(std::integral_constant<int, 2>{});
        if (b.nrows > 3) mask |= row(std::integral_constant<int, 3>{});
        return mask & block_exist(b);
#else
        int mask = 0;
        float x0, y0;
        for (int r = 0; r < b.nrows; ++r)
            for (int c = 0; c < b.ncols; ++c)
                if (node_overlaps({b.level, b.i0 + c, b.j0 + r}, s, x0, y0))
                    mask |= 1 << ((flip_x ? 3 - c : c) + 4 * (flip_y ? 3 - r : r));
        return mask;
#endif
    }

    /// block_overlap of a block that is not one 4 x 4 block of the level's storage (the start
    /// block, a level-1 node's children): its heights gathered.
    int gathered_overlap(const NodeBlock &b, const TileSegment &s) const {
        const Level &L = f.m_levels[b.level];
        // Only the rows that exist are read, and lanes past ncols are masked: each is written
        // once (zeroing all 32 first compiled to a rep stos, slow to start).
        alignas(16) float mm[32];
        for (int r = 0; r < b.nrows; ++r)
            for (int c = 0; c < 4; ++c) {
                const bool in = c < b.ncols;
                mm[4 * r + c] = in ? L.min_at(b.i0 + c, b.j0 + r) : 0.f;
                mm[16 + 4 * r + c] = in ? L.max_at(b.i0 + c, b.j0 + r) : 0.f;
            }
        return block_overlap(b, mm, s);
    }

    /// block_overlap of the block below `nd` (its heights are one 4 x 4 block of the storage
    /// when two levels down).
    int below_overlap(const PyramidNode &nd, const NodeBlock &b, const TileSegment &s) const {
        if (nd.level == 1) return gathered_overlap(b, s);
        return block_overlap(b, f.m_levels[b.level].block(nd.i, nd.j), s);
    }

    /// The first hit in the tile segment `s`. Reference: a node is tested when popped and the
    /// block below it is pushed with all its nodes. Simd: the start block is tested at once,
    /// and below it the block under a node is tested together when the node is popped; it is
    /// pushed with the nodes that pass. Both visit the same leaves in the same order.
    template <bool AnyHit, bool Simd>
    bool trace_tile(const TileSegment &s, HeightfieldHit *hit) const {
        NodeStack stack;
        const NodeBlock start = start_block(s);
        stack.push(start, Simd ? gathered_overlap(start, s) : block_exist(start));
        float x0, y0;
        while (!stack.empty()) {
            const PyramidNode nd = pop_node(stack);
            if constexpr (Simd) {
                if (nd.level > 0) {
                    const NodeBlock b = below(nd);
                    stack.push(b, below_overlap(nd, b, s));
                    continue;
                }
                x0 = s.tile_x + float(nd.i);
                y0 = s.tile_y + float(nd.j);
            } else {
                if (!node_overlaps(nd, s, x0, y0)) continue;
                if (nd.level > 0) {
                    const NodeBlock b = below(nd);
                    stack.push(b, block_exist(b));
                    continue;
                }
            }
            CellPatch cell;
            float th;
            if (!leaf_root(nd, x0, y0, cell, th)) continue;
            if constexpr (!AnyHit) record_hit(cell, x0, y0, th, *hit);
            return true;
        }
        return false;
    }
};

template <bool AnyHit, bool Simd>
bool Heightfield::traverse(Vec3 o, Vec3 d, float tmin, float tmax, HeightfieldHit *hit, int64_t ox,
                           int64_t oy) const {
    if (m_levels.empty() || !(tmax > tmin)) return false;
    Traversal tr(*this, o, d, tmin, tmax, ox, oy);
    if (!tr.clip_to_height_slab()) return false;
    TileWalk walk;
    if (tr.single_tile(walk)) return tr.trace_tile<AnyHit, Simd>(tr.tile_segment(walk, tr.tmin, tr.tmax), hit);
    // Tiles crossed by the ray between tmin and tmax (2D DDA on the W x H tile grid).
    walk = tr.start_tile_walk();
    double t_tile0 = tr.tmin;
    for (int guard = 0; guard < (1 << 22); ++guard) {
        const double t_tile1 = std::min(double(tr.tmax), std::min(walk.tnx, walk.tny));
        const TileSegment seg = tr.tile_segment(walk, t_tile0, t_tile1);
        if (tr.trace_tile<AnyHit, Simd>(seg, hit)) return true;
        if (t_tile1 >= double(tr.tmax)) break;
        t_tile0 = t_tile1;
        tr.step_tile(walk);
    }
    return false;
}

template bool Heightfield::traverse<false, true>(Vec3, Vec3, float, float, HeightfieldHit *, int64_t, int64_t) const;
template bool Heightfield::traverse<true, true>(Vec3, Vec3, float, float, HeightfieldHit *, int64_t, int64_t) const;
template bool Heightfield::traverse<false, false>(Vec3, Vec3, float, float, HeightfieldHit *, int64_t, int64_t) const;
template bool Heightfield::traverse<true, false>(Vec3, Vec3, float, float, HeightfieldHit *, int64_t, int64_t) const;

}  // namespace meso
