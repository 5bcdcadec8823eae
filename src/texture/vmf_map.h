// BRDF MIP-maps of vMF lobes (paper 002, Xu et al. 2017): per-texel half-vector lobes
// ("instant BRDF map", §4) filtered at a footprint by averaging characteristic vectors
// (eq. 10) per cell of a partition of the sphere (§3.2, Algorithm 1), and the baselines the
// paper compares against (direct sampling, naive MIP-mapping of (μ, κ), LEAN moments).
//
// Texels. Texel (x, y) of a w × h grid holds up to kMaxTexelLobes lobes (μ unit, κ ≥ 0,
// weight > 0, weights summing to 1) in the map's frame (z = the macro normal). The material
// builds them from its normal map, NDF lobe and base BRDF (materials/vmf.cpp).
//
// Cells (meso's reading of the 1×1 / 1×4 / 2×4 subdivisions). The paper partitions the
// view-space hemisphere; an offline renderer has no single view, so meso partitions the
// sphere of half vectors in the TANGENT frame of the map:
//   1×4: four azimuthal sectors centred on +x, +y, −x, −y (φ in [−45°, 45°), ...), so lobes
//        tilted along the tangent axes (fabrics, the Tablecloth) sit in the middle of a cell;
//   2×4: each sector split at θ = 60° (z > 1/2: the upper cap, equal in solid angle to the
//        rest of the upper hemisphere; z ≤ 1/2: the band below, lower hemisphere included).
// Cell c of 2×4 is sector c / 2, band c % 2, so a 1×4 cell is the sum of its two 2×4 cells
// and the 1×1 cell the sum of all: the sums are linear, so ONE pyramid of the 2×4 cells
// (4 floats per cell: Σ w r, Σ w) serves every subdivision level, and any linear filter
// (trilinear, EWA) of it is the filter of each level.
//
// Lookup (Algorithm 1, ε0 = 0.95, ε1 = 0.85 by default): r⁽⁰⁾ = Σ w r / Σ w over all cells;
// if ‖r⁽⁰⁾‖ ≥ ε0 one lobe; else each non-empty 1×4 cell i gives one lobe if ‖r_i‖ ≥ ε1,
// else its (non-empty) 2×4 cells. Each lobe: μ = r/‖r‖, κ = eq. 8, weight = the filtered
// Σ w of its cells (eq. 15: the fraction of characteristic vectors in the cell). Empty
// cells give no lobe; ‖r‖ = 0 (vectors cancelling exactly) gives κ = 0, a uniform lobe.
#pragma once
#include <array>
#include <functional>
#include <memory>
#include "core/vec.h"
#include "texture/mipmap.h"
#include "texture/slope_moments.h"

namespace meso {

struct VmfLobe {
    Vec3 mu{0.f, 0.f, 1.f};
    double kappa = 0.0;
    double weight = 0.0;
};

constexpr int kMaxTexelLobes = 8;

enum class VmfMode {
    Direct,    ///< finest level, nearest texel, its exact lobes (no filtering)
    Naive,     ///< MIP-map of the per-texel lobe parameters (μ, κ, w) by lobe index, μ renormalised
    Single,    ///< 1×1: one averaged characteristic vector
    Four,      ///< 1×4 always
    Eight,     ///< 2×4 always
    Adaptive,  ///< Algorithm 1
    Lean,      ///< LEAN: MIP-map of the slope moments of the per-texel lobes, one Gaussian
};

/// What a lookup returns: vMF lobes, or (Lean) one Gaussian of half-vector slopes. In the
/// map's frame.
struct VmfLookup {
    int count = 0;
    std::array<VmfLobe, kMaxTexelLobes> lobes;
    bool gaussian = false;
    SlopeGaussian slopes;
    int cells = 0;  ///< subdivision used (1, 4 or 8 lobes' worth; 0 for direct/naive/lean)
};

/// Slope mean and covariance of a vMF lobe of half vectors (delta method: a vMF is locally a
/// Gaussian with variance 1/κ per tangent direction, mapped through s = (−h.x, −h.y) / h.z);
/// μ.z is clamped to >= 0.05 and each variance to <= 1e4 (κ → 0). Used by the LEAN baseline
/// and by the Smith shadowing option.
SlopeGaussian vmf_lobe_slopes(Vec3 mu, double kappa);

class VmfMap {
public:
    struct Params {
        VmfMode mode = VmfMode::Adaptive;
        double eps0 = 0.95, eps1 = 0.85;
        bool r_table = false;  ///< ‖r‖ from the 1024-entry table instead of the exact root
    };
    /// Fills out[0..n) with texel (x, y)'s lobes and returns n (<= lobes_per_texel).
    using TexelLobes = std::function<int(int x, int y, VmfLobe *out)>;

    VmfMap(int width, int height, int lobes_per_texel, const TexelLobes &texel_lobes, const Params &params,
           WrapMode wrap = WrapMode::Repeat);

    /// Lobes at (u, v) (map units: one period of the grid per unit) with the footprint.
    void lookup(FootprintFilter filter, float u, float v, float dudx, float dudy, float dvdx, float dvdy,
                float max_anisotropy, VmfLookup &out) const;

    /// 2×4 cell of a direction (0..7); 1×4 cell = cell / 2.
    static int cell_of(Vec3 mu);
    /// ‖r‖ for κ (exact root or table, as configured).
    double r_of(double kappa) const;

    int width() const { return m_w; }
    int height() const { return m_h; }
    const Params &params() const { return m_params; }
    size_t memory_bytes() const { return m_mip ? m_mip->memory_bytes() : 0; }
    const MipMap &mip() const { return *m_mip; }

private:
    int m_w = 0, m_h = 0, m_lobes = 0;
    Params m_params;
    std::shared_ptr<MipMap> m_mip;
};

}  // namespace meso
