// Where a Gaussian-slope material (lean, clean, leadr, normalmap) gets its slope statistics
// at a shading point: constants from the scene, or the slope moments of a heightfield read
// at the ray-differential footprint (LEAN / LEADR mapping, paper 000 §4.2, paper 003).
//
// Scene keys, read by SlopeSource::parse (in the material's own object):
//   heightmap   object  —          a displacement-style block: "map" (file or
//                                   {"generator": ...}), "scale", "offset", "tiling" exactly as
//                                   a shape's "displacement" (docs/scene-format.md); copy the
//                                   shape's block here to shade the undisplaced surface with
//                                   the statistics of the displacement it stands for
//   filter      string  trilinear  "trilinear" | "ewa" | "none" (level 0 bilinear, i.e. no
//                                   filtering: the per-cell moments under the point)
//   max_anisotropy float 8          ewa only
//   mean_slope  [x, y]  [0, 0]     constant mean slope (tangent frame); not with heightmap
//   covariance  [xx, yy, xy]  0    constant slope covariance; not with heightmap
//
// With a heightmap: slopes are texture-space (per unit uv, heights in world units) and are
// mapped to the shading frame (s, t) through J = d(u,v)/d(x,y) from ctx.dpdu, ctx.dpdv
// (eq. 12); a degenerate parameterisation gives a flat (zero) distribution. When the
// two-sided integrator flipped the frame (ctx.side < 0) the first moments change sign
// (the heights point into the surface as seen from that side).
#pragma once
#include <memory>
#include <string>
#include "render/shading.h"
#include "texture/mipmap.h"
#include "texture/slope_moments.h"

namespace meso {

class Properties;
class Heightfield;

class SlopeSource {
public:
    using Filter = FootprintFilter;

    /// Constant statistics (tangent frame).
    explicit SlopeSource(const SlopeGaussian &constant = {});
    /// Moments of `field` on a surface where the map repeats tiling_u x tiling_v times.
    SlopeSource(const Heightfield &field, float tiling_u, float tiling_v, Filter filter = Filter::Trilinear,
                float max_anisotropy = 8.f, std::string source = "");

    /// Reads the keys above from a material's properties (located errors).
    static SlopeSource parse(const Properties &p);
    /// True if `p` holds any key parse() reads (so a material can offer other defaults).
    static bool present(const Properties &p);

    bool is_constant() const { return !m_mip; }
    /// The slope distribution at the shading point in ctx's frame, before base roughness.
    SlopeGaussian eval(const ShadingContext &ctx) const;
    /// The filtered texture-space moments at the shading point (SlopeMoment order).
    void moments(const ShadingContext &ctx, float out[SlopeMomentCount]) const;
    /// The footprint-filtered height mean and variance (world units; paper 001 §5.1) from the
    /// height-moment pyramid of the map (build_height_moments), or the constants given by
    /// set_constant_height. False when neither is available.
    bool height_moments(const ShadingContext &ctx, double &mean, double &variance) const;
    /// Height statistics for a constant source (mean, standard deviation >= 0).
    void set_constant_height(double mean, double sigma);
    bool has_heights() const { return bool(m_hmip) || m_has_const_h; }
    /// Mean of the distribution over the whole map for an undistorted unit mapping
    /// (J = identity), for hints and descriptions.
    SlopeGaussian mean_over_map() const;

    std::string to_string() const;
    size_t memory_bytes() const { return m_mip ? m_mip->memory_bytes() : 0; }

private:
    SlopeGaussian m_const;
    std::shared_ptr<const MipMap> m_mip;
    std::shared_ptr<const MipMap> m_hmip;  ///< E[h - m_hcenter], E[(h - m_hcenter)^2]
    double m_hcenter = 0, m_const_hmean = 0, m_const_hvar = 0;
    bool m_has_const_h = false;
    float m_tu = 1.f, m_tv = 1.f;
    Filter m_filter = Filter::Trilinear;
    float m_max_aniso = 8.f;
    std::string m_source;
};

}  // namespace meso
