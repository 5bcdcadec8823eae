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
//   transfer_filter string "exact"  only with a heightmap block that has a "transfer" g (heights
//                                   h = offset + scale * g(f), paper 001 §7): "exact" = the
//                                   pyramids of the transferred map g(f) (the mip of g(f));
//                                   "gaussian" = the pyramids of f and eq. 19-28 at each footprint
//   mean_slope  [x, y]  [0, 0]     constant mean slope (tangent frame); not with heightmap
//   covariance  [xx, yy, xy]  0    constant slope covariance; not with heightmap
//
// With a heightmap: slopes are texture-space (per unit uv, heights in world units) and are
// mapped to the shading frame (s, t) through J = d(u,v)/d(x,y) from ctx.dpdu, ctx.dpdv
// (eq. 12); a degenerate parameterisation gives a flat (zero) distribution. When the
// two-sided integrator flipped the frame (ctx.side < 0) the first moments change sign
// (the heights point into the surface as seen from that side).
//
// "transfer_filter": "gaussian" (paper 001 §7, what a procedural f would need): the slope- and
// height-moment pyramids hold the UNtransformed map f in map units (scale 1, offset 0). At a
// footprint, f_bar and sigma_f^2 = E[f^2] - E[f]^2 come from f's height moments; transfer_moments
// gives E[g], E[g^2], E[g'], E[g'^2] under N(f_bar, sigma_f^2) (eq. 21-22, 27-28); then
//   heights (world)  h_mean = offset + scale E[g],  h_var = scale^2 (E[g^2] - E[g]^2)
//   slopes (texture space, world heights per unit uv): dh/du = scale g'(f) df/du, so
//            transferred_statistics (eq. 24-26: E[g'] E[s_f], E[g'^2] E[s_f s_f^T]) on f's
//            texture-space slope Gaussian, then mean * scale, covariance * scale^2.
// moments() returns these transferred texture-space moments (E[x], E[y], E[x^2], E[y^2], E[xy]
// of h), so eval() maps them through the same J as without a transfer (slope_gaussian). Both
// eq. 24-26 and J are linear in the first and second moments, so transferring before or after J
// gives the same distribution (up to the clamping of negative variances).
#pragma once
#include <memory>
#include <string>
#include "geometry/shading.h"
#include "texture/mipmap.h"
#include "texture/slope_moments.h"

namespace meso {

class Properties;
class Heightfield;
class Ramp;

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
    /// The "gaussian" transfer filter: this source's map is f (map units) and the surface it
    /// stands for has heights offset + scale * g(f); moments(), eval() and height_moments() then
    /// return the statistics of those heights (see the header comment). Map sources only.
    void set_height_transfer(std::shared_ptr<const Ramp> g, double scale, double offset);
    bool has_height_transfer() const { return bool(m_transfer); }
    bool has_heights() const { return bool(m_hmip) || m_has_const_h; }
    /// Mean of the distribution over the whole map for an undistorted unit mapping
    /// (J = identity), for hints and descriptions.
    SlopeGaussian mean_over_map() const;

    std::string to_string() const;
    size_t memory_bytes() const { return m_mip ? m_mip->memory_bytes() : 0; }

private:
    /// The footprint-filtered mean and variance of the map's heights (map units under a transfer).
    void map_height_moments(const ShadingContext &ctx, double &mean, double &variance) const;
    /// Texture-space slope moments `fm` and height mean / variance of f to the moments of
    /// h = offset + scale * g(f) (out, SlopeMoment order; h_mean, h_var optional).
    void apply_transfer(const float fm[SlopeMomentCount], double f_mean, double f_var, float out[SlopeMomentCount],
                        double *h_mean, double *h_var) const;

    SlopeGaussian m_const;
    std::shared_ptr<const MipMap> m_mip;
    std::shared_ptr<const MipMap> m_hmip;  ///< E[h - m_hcenter], E[(h - m_hcenter)^2]
    double m_hcenter = 0, m_const_hmean = 0, m_const_hvar = 0;
    bool m_has_const_h = false;
    float m_tu = 1.f, m_tv = 1.f;
    Filter m_filter = Filter::Trilinear;
    float m_max_aniso = 8.f;
    std::string m_source;
    std::shared_ptr<const Ramp> m_transfer;  ///< "gaussian" transfer filter: g (pyramids hold f)
    double m_tscale = 1, m_toffset = 0;      ///< h = m_toffset + m_tscale * g(f)
};

}  // namespace meso
