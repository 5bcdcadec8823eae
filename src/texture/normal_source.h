// Where a normal-perturbing material (toksvig, normalmap) gets its normal at a shading
// point: a constant, a tangent-space normal-map image, or the per-cell average unit normals
// of a heightfield; images and heightfields are MIP-mapped (3 channels, exact area
// averages) and read at the ray-differential footprint. The result is the FILTERED AVERAGE
// of unit normals, N_a: its direction is the mean normal and its length |N_a| <= 1 measures
// the spread of the normals under the footprint (Toksvig 2004; paper 003 part 3).
//
// Scene keys, read by NormalSource::parse (in the material's own object):
//   normals        string   -          tangent-space normal map (any format OpenImageIO reads,
//                                       >= 3 channels): 8/16-bit values c map to 2c - 1, float
//                                       values are taken as they are; every texel is
//                                       renormalised to unit length before the MIP
//   tiling         number | [u, v]  1  repeats of the normal map over uv [0, 1]
//   heightmap      object   -          a displacement-style block (map, scale, offset, tiling)
//   uv_length      [Lu, Lv] [1, 1]     world length of one unit of u and of v (heightmap only):
//                                       slopes per world unit = texture slopes / uv_length
//   filter         string   trilinear  "trilinear" | "ewa" | "none" (level 0 bilinear)
//   max_anisotropy float    8          ewa only
//   <constant key> [x, y, z] (0,0,1)   constant normal ("average_normal" for toksvig: length in
//                                       (0, 1]; "normal" for normalmap: normalised)
//
// Heightfield baking: cell (i, j) with corner heights h00, h10, h01, h11 has slopes
// x(a, b) = e + g b, y(a, b) = f + g a (per cell, see texture/slope_moments.h), times
// width * tiling_u / Lu (resp. height * tiling_v / Lv) for slopes per world unit; the texel
// stores the average of the unit normals (-x, -y, 1) / sqrt(1 + x^2 + y^2) over the cell by
// 4 x 4 Gauss-Legendre points (a smooth integrand: error ~ (slope variation over the cell)^8).
//
// Frames: image normals are in the shading frame (s, t, n) as they are (Mitsuba 3
// `normalmap` semantics, t = n x s). Baked heightfield normals are in (u, v, n): x along
// dp/du (= s), y along dp/dv, so y is multiplied by sign(t . dp/dv) (1 when dp/dv is
// unknown), t of the unflipped frame. When the two-sided integrator flipped the frame
// (ctx.side < 0: frame (s, -t, -n)) the normal seen from that side is -N, whose components
// there are (-x, y, z) in terms of the unflipped ones (tested against the analytic normal of
// a displaced plane from both sides).
#pragma once
#include <memory>
#include <string>
#include "core/frame.h"
#include "geometry/shading.h"
#include "texture/mipmap.h"

namespace meso {

class Properties;
class Heightfield;
struct Image;

class NormalSource {
public:
    using Filter = FootprintFilter;
    enum class Space { Shading, UV };  ///< image normals (s, t, n) or baked (u, v, n)

    /// A constant average normal (shading frame).
    explicit NormalSource(Vec3 constant = Vec3(0.f, 0.f, 1.f));
    /// A 3-channel MIP of normals on a surface where it repeats tiling_u x tiling_v times.
    NormalSource(std::shared_ptr<const MipMap> mip, Space space, float tiling_u, float tiling_v,
                 Filter filter = Filter::Trilinear, float max_anisotropy = 8.f, std::string source = "");

    /// Unit normals of a normal-map image: 2c - 1 when `integer_encoded`, else as stored;
    /// renormalised per texel (a zero-length texel becomes (0, 0, 1)). Needs >= 3 channels.
    static MipMap normal_map_mip(const Image &img, bool integer_encoded);
    /// Per-cell average unit normals of `field` (see above): slopes per world unit are
    /// texture slopes / (lu, lv) for a map repeated tiling_u x tiling_v times over uv [0, 1].
    static MipMap bake_heightfield(const Heightfield &field, double tiling_u, double tiling_v, double lu, double lv);

    /// Reads the keys above. `constant_key` names the constant's key; `unit_constant`: the
    /// constant is normalised (normalmap), else its length must be in (0, 1] (toksvig).
    /// `allow_heightmap`: whether "heightmap" is read here.
    static NormalSource parse(const Properties &p, const std::string &constant_key, bool unit_constant,
                              bool allow_heightmap = true);

    bool is_constant() const { return !m_mip; }
    /// The filtered average normal at ctx in ctx's local frame (not normalised).
    Vec3 eval(const ShadingContext &ctx) const;
    /// Mean over the whole map (the coarsest level), in the map's own frame; the constant
    /// otherwise.
    Vec3 mean_over_map() const;
    const MipMap *mip() const { return m_mip.get(); }
    Space space() const { return m_space; }
    float tiling_u() const { return m_tu; }
    float tiling_v() const { return m_tv; }
    Filter filter() const { return m_filter; }
    float max_anisotropy() const { return m_max_aniso; }
    /// Looks up another MIP defined on the same texel grid as this source's map (same
    /// tiling, footprint filter and anisotropy limit), e.g. per-texel data derived from the
    /// normals. `out` receives mip.channels() floats.
    void lookup_same_grid(const MipMap &mip, const ShadingContext &ctx, float *out) const;
    /// A vector stored in the map's frame ((s, t, n) or (u, v, n)) in ctx's local frame:
    /// the sign conventions of eval() (x flips with ctx.side, y with the orientation of
    /// dp/dv in the UV space).
    Vec3 to_local(const ShadingContext &ctx, Vec3 map_vector) const;

    std::string to_string() const;

private:
    Vec3 m_const;
    std::shared_ptr<const MipMap> m_mip;
    Space m_space = Space::Shading;
    float m_tu = 1.f, m_tv = 1.f;
    Filter m_filter = Filter::Trilinear;
    float m_max_aniso = 8.f;
    std::string m_source;
};

/// The frame, in local coordinates, whose normal is `n` (unit) and whose tangent is the
/// local s axis (1, 0, 0) made orthogonal to n (Gram-Schmidt; the t axis when n is along s).
Frame perturbed_frame(Vec3 n);

}  // namespace meso
