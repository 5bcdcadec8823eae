// MIP pyramid of an N-channel float image with nearest, bilinear, trilinear and anisotropic
// (EWA) lookups.
// Reusable for anything stored per texel (colours, heights, slope moments): channels are
// plain floats, and every level is the exact area average of level 0 (means are kept).
//
// Conventions:
//   * uv (0,0) is the top-left corner of the image, u to the right, v DOWN (row 0 first;
//     glTF and Mitsuba 3 conventions). Texel (x, y) of a w x h level covers
//     [x/w, (x+1)/w] x [y/h, (y+1)/h]; its centre is at ((x + .5)/w, (y + .5)/h).
//   * Level 0 is the input; level l+1 has size max(1, floor(w_l / 2)) x max(1, floor(h_l / 2))
//     and is the box filter of level l over each output texel's footprint — the 2x2 box
//     for even sizes, a 2.5-, 3.5-... texel box with fractional edge weights for odd ones.
//     This is exact area averaging, so every level has the same mean as level 0.
//   * Level selection: footprint width in level-0 texels
//         width = max(|(dudx·w, dvdx·h)|, |(dudy·w, dvdy·h)|),
//     level = clamp(log2(width), 0, levels-1) (a footprint of k texels picks log2 k);
//     zero footprint means level 0.
//   * EWA (Heckbert 1989, "Fundamentals of Texture Mapping and Image Warping" §3.5.8; the
//     pbrt-v4 variant): the derivative vectors (dudx, dvdx) and (dudy, dvdy) are the
//     semi-axes of an ellipse with covariance Σ = J Jᵀ; its minor axis is widened so that
//     major / minor <= max_anisotropy, the level is log2(minor semi-axis in level-0 texels),
//     and each of the two levels around it sums its texels inside the ellipse (Σ + I in that
//     level's texels: the +I is a one-texel reconstruction filter) with the truncated
//     Gaussian weight exp(-2 r²) - exp(-2); the two sums are blended linearly.
#pragma once
#include <cstddef>
#include <string>
#include <vector>
#include "image/wrap_mode.h"

namespace meso {

/// How a lookup uses the ray-differential footprint: trilinear (level from its width), EWA,
/// or none (level-0 bilinear: the finest data under the point).
enum class FootprintFilter { Trilinear, Ewa, None };

class Properties;
/// The footprint filter parameter `key`: "trilinear" (the default), "ewa" or "none".
FootprintFilter parse_footprint_filter(const Properties &p, const std::string &key);

class MipMap {
public:
    MipMap() = default;
    /// `data`: width x height x channels floats, row-major, top row first, interleaved.
    MipMap(int width, int height, int channels, std::vector<float> data, WrapMode wrap = WrapMode::Repeat);

    int channels() const { return m_channels; }
    int levels() const { return int(m_levels.size()); }
    int width(int level = 0) const { return m_levels[level].w; }
    int height(int level = 0) const { return m_levels[level].h; }
    WrapMode wrap() const { return m_wrap; }
    /// Texel of a level (x, y already inside the level).
    const float *texel(int level, int x, int y) const {
        const Level &L = m_levels[level];
        return &L.data[(size_t(y) * L.w + x) * m_channels];
    }
    /// Mean of a level, per channel (out has channels() entries).
    void level_mean(int level, float *out) const;

    /// Continuous level for a uv footprint (ray-differential derivatives).
    float level_for_footprint(float dudx, float dudy, float dvdx, float dvdy) const;
    /// The footprint's width in level-0 texels (the larger axis, as level_for_footprint uses);
    /// NaN derivatives count as 0, infinite ones as 1e30.
    double footprint_width(float dudx, float dudy, float dvdx, float dvdy) const;
    /// The variance of a moment pyramid (E[x^2] - E[x]^2 read at the footprint) corrected for
    /// magnification: a level-0 texel holds its whole cell's variance, of which a window w < 1
    /// texel wide sees about w^2 (a locally linear signal), so the variance is scaled by
    /// min(1, w^2); a zero footprint gives 0.
    double magnified_variance(double variance, float dudx, float dudy, float dvdx, float dvdy) const {
        const double w = footprint_width(dudx, dudy, dvdx, dvdy);
        return w >= 1.0 ? variance : variance * w * w;
    }

    // Lookups write channels() floats to `out`.
    void nearest(int level, float u, float v, float *out) const;
    void bilinear(int level, float u, float v, float *out) const;
    /// Linear blend of bilinear lookups of the two levels around the continuous `level`.
    void trilinear(float level, float u, float v, float *out) const;
    /// trilinear(level_for_footprint(...)).
    void filtered(float u, float v, float dudx, float dudy, float dvdx, float dvdy, float *out) const;
    /// Elliptically weighted average over the footprint with semi-axes (dudx, dvdx) and
    /// (dudy, dvdy) (see the conventions above). A zero footprint gives bilinear(0, u, v); a
    /// footprint whose widened minor axis reaches the coarsest level gives that level's
    /// (1x1) mean; non-finite inputs give finite results (NaN derivatives count as 0,
    /// infinite ones as huge). max_anisotropy is clamped to [1, kEwaMaxAnisotropy], which
    /// bounds the cost: at most ~1200 texels on the finer level and a quarter of that on
    /// the coarser one, whatever the footprint.
    void ewa(float u, float v, float dudx, float dudy, float dvdx, float dvdy, float *out,
             float max_anisotropy = 8.f) const;
    static constexpr float kEwaMaxAnisotropy = 64.f;
    /// filtered(), ewa() or bilinear(0, ...) as `filter` says.
    void lookup(FootprintFilter filter, float u, float v, float dudx, float dudy, float dvdx, float dvdy, float *out,
                float max_anisotropy = 8.f) const;

    size_t memory_bytes() const;

private:
    struct Level {
        int w = 0, h = 0;
        std::vector<float> data;
    };
    int wrap_index(int i, int n) const;
    /// The EWA sum of one level for the covariance (sxx, sxy, syy) in that level's texels.
    void ewa_level(int level, float u, float v, double sxx, double sxy, double syy, float *out) const;

    int m_channels = 0;
    WrapMode m_wrap = WrapMode::Repeat;
    std::vector<Level> m_levels;
};

}  // namespace meso
