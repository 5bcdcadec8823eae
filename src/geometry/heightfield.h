// The heightfield intersector: a periodic, piecewise-bilinear heightfield in cell space
// (see heightmap.h) with a min/max height pyramid (maximum mip-maps, Tevs et al. 2008),
// traversed top-down front-to-back, with an exact ray / bilinear-patch test at the leaves.
// The pyramid is stored in 4 x 4 blocks (a node's sixteen grandchildren's mins, then maxes), and
// the traversal steps two levels at a time, testing a node's sixteen grandchildren at once with
// SSE (a row of four per register), with the same float operations as the scalar
// node-at-a-time reference (intersect_reference), so both give bitwise the same hits.
//
// This is the one heightfield tracer of meso: shell-mapped displacement calls it with the
// ray mapped into cell space through a tetrahedron, and the prefiltering precomputation
// calls it on the flat microgeometry directly.
//
// Cell space: (x, y) in cells, h in the heightfield's height units (world units for a
// Displacement: offset + scale * map). The tiled surface is infinite and periodic; a
// caller that works on a bounded region clips its ray to that region.
#pragma once
#include <cstdint>
#include <vector>
#include "core/vec.h"
#include "geometry/heightmap.h"

namespace meso {

struct HeightfieldHit {
    float t = 0.f;          ///< ray parameter of the hit
    float x = 0.f, y = 0.f; ///< cell-space position of the hit (as traced, before wrapping)
    float h = 0.f;          ///< height at the hit
    float dhdx = 0.f, dhdy = 0.f;  ///< analytic derivatives of the bilinear patch there
};

class Heightfield {
public:
    Heightfield() = default;
    /// heights = offset + scale * map (scale may be negative or zero).
    Heightfield(const HeightMap &map, float scale, float offset);

    int width() const { return m_w; }
    int height() const { return m_h; }
    float min_height() const { return m_min; }
    float max_height() const { return m_max; }
    /// Height value of grid vertex (i, j), wrapped.
    float vertex(int64_t i, int64_t j) const;
    /// Bilinear height at cell-space (x, y) (wrapping).
    float eval(double x, double y) const;
    /// Height and its analytic derivatives at (x, y).
    float eval(double x, double y, float &dhdx, float &dhdy) const;

    /// Closest hit of o + t d (cell space; d need not be normalised) with t in
    /// (tmin, tmax]. `offset_x`, `offset_y` are integer cell offsets added to x, y before
    /// lookup (callers keep their coordinates small for float precision and pass the
    /// integer part here). The surface is two-sided.
    bool intersect(Vec3 o, Vec3 d, float tmin, float tmax, HeightfieldHit &hit,
                   int64_t offset_x = 0, int64_t offset_y = 0) const;
    /// Any hit with t in (tmin, tmax).
    bool occluded(Vec3 o, Vec3 d, float tmin, float tmax, int64_t offset_x = 0, int64_t offset_y = 0) const;
    /// intersect / occluded with the scalar node-at-a-time traversal: the reference that the
    /// SIMD traversal (a node's grandchildren tested at once) must match bit for bit. For tests.
    bool intersect_reference(Vec3 o, Vec3 d, float tmin, float tmax, HeightfieldHit &hit, int64_t offset_x = 0,
                             int64_t offset_y = 0) const;
    bool occluded_reference(Vec3 o, Vec3 d, float tmin, float tmax, int64_t offset_x = 0,
                            int64_t offset_y = 0) const;

    /// The heights box-filtered by `factor` (each output vertex is the mean of a factor x
    /// factor block of vertices): the stand-in for downsampled LoD levels until the
    /// prefiltering issue's least-squares heights exist. Throws MesoError unless factor
    /// divides both sizes.
    HeightMap box_downsampled(int factor) const;

    /// Base heights and pyramid: independent of how often the map is tiled.
    size_t memory_bytes() const;

private:
    struct Level {
        int w = 0, h = 0;  ///< nodes in x and y
        int bw = 0;        ///< 4 x 4 blocks of nodes in x, (w + 3) / 4
        /// 32 floats per 4 x 4 block of nodes (the grandchildren of one node two levels up):
        /// the sixteen nodes' min heights, then their sixteen max heights, node (4 bi + a,
        /// 4 bj + b) at index a + 4 b (nodes past the level's size hold 0). A row of the block
        /// is one SSE load of mins and one of maxes.
        std::vector<float> blocks;
        const float *block(int bi, int bj) const { return &blocks[(size_t(bj) * bw + size_t(bi)) * 32]; }
        float min_at(int i, int j) const { return block(i >> 2, j >> 2)[(i & 3) | (j & 3) << 2]; }
        float max_at(int i, int j) const { return block(i >> 2, j >> 2)[16 + ((i & 3) | (j & 3) << 2)]; }
    };
    int m_w = 0, m_h = 0;
    float m_min = 0.f, m_max = 0.f;
    std::vector<float> m_heights;  ///< (m_w) x (m_h) vertex heights
    std::vector<Level> m_levels;   ///< level 0: one node per cell; level k: 2^k x 2^k cells

    /// The ray of one traverse() call and its steps (heightfield.cpp).
    struct Traversal;
    template <bool AnyHit, bool Simd>
    bool traverse(Vec3 o, Vec3 d, float tmin, float tmax, HeightfieldHit *hit, int64_t ox, int64_t oy) const;
};

/// Exact intersection of o + t d with the bilinear patch over the unit square with corner
/// heights h00 (0,0), h10 (1,0), h01 (0,1), h11 (1,1); o is relative to the cell corner.
/// Finds the smallest root t in [t0, t1] (solved in double, re-based at t0; a sign change
/// the closed form misses by round-off still counts). The caller restricts [t0, t1] to
/// the cell. Returns false if there is none.
bool intersect_bilinear_patch(Vec3 o, Vec3 d, float h00, float h10, float h01, float h11, float t0, float t1,
                              float &t_hit);

}  // namespace meso
