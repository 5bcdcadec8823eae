// Shell-mapped displacement (Porumbescu et al. 2005, as used by paper 004 §7.1): the shell
// between a base mesh offset along its interpolated vertex normals by the heightfield's
// minimum and maximum height, cut into one prism per base triangle and each prism into
// three tetrahedra. Inside a tetrahedron, world space maps linearly to cell space
// (x, y, h), so a ray stays a ray there and the heightfield intersector traces it exactly.
//
// * Diagonals: a prism over base vertices a < b < c (ordered by position-welded index)
//   is split into (a b c a'), (b c a' b'), (c a' b' c'); every side quad's diagonal then
//   joins the top of its lower-index vertex to the bottom of its higher-index one, which
//   depends only on the shared edge, so neighbouring prisms cut shared faces identically
//   (no cracks), also across uv seams where vertices are duplicated.
// * Prisms are Embree user geometry. A ray is clipped against each tetrahedron (padded
//   slightly so shared faces overlap; the heightfield is one function, so overlapping
//   tests agree), re-based at its entry point, mapped to cell space and traced.
// * Embree hit: primID = 3 * prism + tetrahedron, (u, v) = cell-space hit relative to
//   the prism's integer cell origin; fill_interaction rebuilds the micro-normal
//   (inverse-transpose of the texture-to-world Jacobian applied to (-h_x, -h_y, 1)),
//   the micro uv and dp/du, dp/dv.
// * Tetrahedra of one prism that share their world -> cell map (a flat base with linear uvs)
//   are traced as one segment (Prism::same_map); the clip runs in float SSE (four faces at once).
//   Where all three share it (Prism::one_map) the prism is clipped once, in cell space.
// * Quads: two one_map prisms that share a base edge and the world -> cell map, and whose base
//   triangles form a convex quad in cell space (a flat quad split by its diagonal: a rectangle,
//   a tile of a flat grid), are one Embree primitive with one box, clipped once against the
//   quad's four edges and the height slab and traced once (ShellShape::pair_prisms): a ray
//   through such a quad pays one callback, one clip and one heightfield call, not two, wherever
//   it crosses the diagonal.
// * Occlusion: a segment that starts on one side of the heightfield and ends on the other
//   (beyond a round-off margin) crosses it: occluded without a traversal.
// * Memory: per prism three 27-float tetrahedra plus an integer cell origin, and the
//   heightfield (map + min/max pyramid) once, whatever the tiling.
#pragma once
#include <memory>
#include "geometry/displacement.h"
#include "geometry/mesh.h"
#include "geometry/shape.h"
#include "sampling/distribution.h"

namespace meso {

class ShellShape : public Shape {
public:
    /// `base` in world space with uvs (normals are computed, area-weighted, if absent).
    ShellShape(const TriangleMesh &base, Displacement disp, std::string name);
    RTCGeometry build_embree(RTCDevice device) const override;
    void fill_interaction(const Ray &ray, float t, uint32_t prim, float u, float v,
                          SurfaceInteraction &si) const override;
    /// Area of the base mesh (the displaced area is larger).
    float surface_area() const override { return m_base_area; }
    /// Samples the base mesh (shell shapes cannot be emitters; used by nothing else).
    PositionSample sample_area(float u_prim, Vec2 u) const override;
    /// Embree primitives: prisms, two merged into one where they form a flat convex quad.
    size_t primitive_count() const override { return m_prims.size(); }
    /// Prisms (one per base triangle with an area).
    size_t prism_count() const { return m_prisms.size(); }
    size_t memory_bytes() const override;
    std::string to_string() const override;

    const Displacement &displacement() const { return m_disp; }
    /// The same shell (base mesh, tiling) over another heightfield (an LoD level).
    std::shared_ptr<ShellShape> with_field(std::shared_ptr<const Heightfield> field, const std::string &name) const {
        Displacement d = m_disp;
        d.field = std::move(field);
        return std::make_shared<ShellShape>(m_base, std::move(d), name);
    }
    bool texel_grid(double &width, double &height) const override {
        width = double(m_disp.field->width()) * m_disp.tiling_u;
        height = double(m_disp.field->height()) * m_disp.tiling_v;
        return true;
    }
    bool uv_world_length(double &lu, double &lv) const override { return m_base.uv_world_length(lu, lv); }
    float shell_min() const { return m_hmin; }
    float shell_max() const { return m_hmax; }

    // Embree callbacks (public for the C trampolines). `prim` is an Embree primitive (< primitive_count()).
    void prism_bounds(uint32_t prim, float lo[3], float hi[3]) const;
    /// Closest hit in (tnear, tfar) of primitive `prim`; on a hit updates tfar, tet (3 x prism +
    /// tetrahedron: fill_interaction's prim), x, y.
    bool intersect_prism(uint32_t prim, Vec3 o, Vec3 d, float tnear, float &tfar, uint32_t &tet, float &x,
                         float &y) const;
    bool occluded_prism(uint32_t prim, Vec3 o, Vec3 d, float tnear, float tfar) const;

private:
    struct Tet {
        float w0[3];     ///< world vertex 0
        /// World -> barycentric: lambda_k(p) = [k == 0] + N[c][k] (p - w0)_c for k = 0..3,
        /// components c = x, y, z in rows (four lambdas per SSE register); N[.][0] = -(sum
        /// of the other three), so the lambdas sum to 1.
        float N[3][4];
        float A[9];      ///< world -> cell space (Jacobian), row-major
        float t0[3];     ///< cell-space vertex 0 (relative to the prism's cell origin)
    };
    struct Prism {
        Tet tet[3];
        int64_t ox = 0, oy = 0;  ///< integer cell origin
        uint8_t valid = 0;       ///< bit k: tetrahedron k has a volume
        /// Bit k + k' - 1 (pairs 01, 02, 12): tetrahedra k and k' map world to cell space by
        /// the same affine map up to float round-off (a flat base with linear uvs), so a ray
        /// crossing both is traced in one heightfield call.
        uint8_t same_map = 0;
        /// same_map for all three pairs and a base triangle with an area in cell space: the
        /// prism is clipped once, in cell space through tetrahedron 0's map (clip_prism), as
        /// four edge functions and the height slab: e_k = edges[0][k] x + edges[1][k] y +
        /// edges[2][k] >= 0 inside (one SSE load a row). A lone prism's are the triangle's
        /// barycentrics (the first repeated in lane 3); a quad's (partner set) the quad's
        /// edges, each scaled to 1 at the vertex farthest from it.
        bool one_map = false;
        float edges[3][4] = {};
        /// The other prism of a quad (pair_prisms), or kNoPartner. The first of the two
        /// (partner > own index) is the Embree primitive and its map traces the quad.
        uint32_t partner = kNoPartner;
    };
    static constexpr uint32_t kNoPartner = ~0u;
    /// A prism's corners as built: world and cell space (relative to its cell origin), bottom
    /// 0..2 then top 3..5, and the welded indices of its base vertices.
    struct PrismCorners {
        double wv[6][3], tv[6][3];
        uint32_t weld[3];
    };
    static uint8_t shared_maps(const Prism &P, const double wv[6][3], const double tv[6][3]);
    static void set_one_map(Prism &P, const double tv[6][3]);
    /// Merges neighbouring one_map prisms into quads where they can be (see the file comment)
    /// and lists the Embree primitives (m_prims).
    void pair_prisms(const std::vector<PrismCorners> &corners);
    bool try_pair(uint32_t a, uint32_t b, const std::vector<PrismCorners> &corners);
    /// Clips o + t d to tetrahedron `T` within [t0, t1]; false if empty.
    static bool clip(const Tet &T, Vec3 o, Vec3 d, float &t0, float &t1);
    /// Clips o + t d to a one_map prism within [t0, t1] (in cell space); false if empty.
    bool clip_prism(const Prism &P, Vec3 o, Vec3 d, float &t0, float &t1) const;
    template <bool AnyHit>
    bool trace_prism(uint32_t prism, Vec3 o, Vec3 d, float tnear, float tfar, float *t_hit, uint32_t *tet, float *x,
                     float *y) const;

    Displacement m_disp;
    TriangleMesh m_base;
    std::vector<Prism> m_prisms;
    std::vector<uint32_t> m_prism_tri;  ///< base triangle of each prism
    std::vector<uint32_t> m_prims;      ///< the prism of each Embree primitive (a quad's first)
    float m_hmin = 0.f, m_hmax = 0.f;  ///< padded shell heights
    float m_inv_thick = 0.f;           ///< 1 / (m_hmax - m_hmin)
    float m_base_area = 0.f;
    Distribution1D m_area_distr;
    std::string m_name;
};

}  // namespace meso
