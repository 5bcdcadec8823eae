// A local bound on the slopes that can shadow a point of a periodic heightfield: the shadow
// rays of the prefilter's estimators (scaling.cpp) skip the traversal for a direction that
// rises faster than it. It refines detail::max_slope (the whole map's steepest |∇h|, one number)
// with what lies around the ray's origin p at height z0 (on or above the surface):
//
//   * near: the 3 x 3 nodes of level k (2^k x 2^k cells) around p, a square that contains the
//     straight horizontal path from p to any of its points. Along that path the bilinear surface
//     rises at most at the largest |∇h| of those cells, L_k, so a ray from z0 >= h(p) rising
//     faster than L_k stays above it inside the square;
//     (0 where the level-(k + 1) squares below lie below z0);
//   * far: the part of the 3 x 3 nodes of level j + 1 outside those of level j (j >= k) lies at
//     least r_j (the distance from p to the level-j square's border) away and no higher than
//     their largest height Mx_{j+1}; a ray rising faster than (Mx_{j+1} - z0) / r_j is above it
//     there. Beyond the coarsest level kept, the map's highest point at distance r_J.
//
// A direction below the bound still needs a shadow ray, but only as far as the smallest square
// outside which it rises above every ring term (reach): the traversal then covers a short
// footprint instead of the whole way out of the map's height range.
//
// The bound is min over k = 0, 1, 2 of max(L_k, max_{j >= k} (Mx_{j+1} - z0) / r_j), at most
// the global slope: every term is an upper bound of what it replaces, so a direction above it
// is unoccluded exactly (no ray is skipped that the traversal would find blocked; tested
// against it). On a map with flat regions (an emblem's plateaus, a flat background) most of
// the N² next-event directions of a vertex clear it where the global slope clears few.
//
// Levels k are kept while 2^k divides both map sizes (nodes then tile the periodic map), so any
// size works (an odd one keeps level 0 and the global term only). Memory: about 1.7 floats a
// cell (slopes at levels 0-2: 1 + 1/4 + 1/16; heights from level 1 up: about 1/3).
#pragma once
#include <cstdint>
#include <vector>
#include "geometry/heightfield.h"

namespace meso::prefilter {

class SlopeBound {
public:
    explicit SlopeBound(const Heightfield &hf);
    /// A square of 3 x 3 nodes around the origin (cell space) and the largest ring term outside
    /// it (a direction rising faster cannot be blocked beyond the square).
    struct Square {
        double x0, x1, y0, y1, beyond;
    };
    /// What local() finds at one origin: the slope bound and, per level, the squares.
    struct Local {
        double slope = 0;  ///< the bound (the global slope where there is no local claim)
        double x = 0, y = 0;
        int count = 0;     ///< squares filled (0: none)
        Square squares[32];
    };
    /// The bound at cell-space (x, y) (unwrapped: any real numbers) for a ray origin at height
    /// z0; the global slope where z0 is below the surface at (x, y) (no local claim).
    Local local(double x, double y, double z0) const;
    double at(double x, double y, double z0) const { return local(x, y, z0).slope; }
    /// The ray parameter (unit w from the origin of `l`) beyond which w cannot be blocked: the
    /// exit from the smallest square outside which w rises above every ring term (padded);
    /// infinity when there is none. A shadow ray towards w may stop there.
    static float reach(const Local &l, Vec3 w);
    /// The whole map's steepest |∇h| (detail::max_slope's value).
    double global() const { return m_global; }
    size_t memory_bytes() const;

private:
    struct Level {
        int w = 0, h = 0;               ///< nodes in x and y
        std::vector<float> max_height;  ///< per node (levels >= 1)
        std::vector<float> max_slope;   ///< per node (levels 0-2)
    };
    /// Largest entry of v over the 3 x 3 nodes around node (a, b) (wrapped) of level l.
    static float block_max(const Level &l, const std::vector<float> &v, int64_t a, int64_t b);
    const Heightfield &m_hf;
    std::vector<Level> m_levels;
    double m_global = 0, m_top = 0;  ///< max |∇h|, the highest vertex
};

}  // namespace meso::prefilter
