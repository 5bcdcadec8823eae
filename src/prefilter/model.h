// The prefiltered LoD model of paper 004 (Wu et al. 2019) as `meso prefilter` writes it and
// the `prefiltered` material reads it: per level (downsampling factor F), the least-squares
// heightfield h_low (§4.1), the 6-lobe vMF SVNDF (§4.2, eq. 4) and the factorised scaling
// function R ≈ T(x) S(ωi, ωo) (§6, eq. 22-24), with and without interreflections.
//
// On disk: a directory
//   manifest.json                 every parameter, timings, standard errors, meso version
//   level_F/h_low.exr             (W/F) x (H/F) heights, single channel, in the ORIGINAL map's
//                                 units (a displacement's `scale`/`offset` apply unchanged);
//                                 coarse vertex (I, J) sits at fine vertex (I F, J F)
//   level_F/lobes.exr             (W/F) x (H/F), channel 5 j + {0,1,2,3,4} = lobe j's
//                                 μ.x, μ.y, μ.z, κ, weight a_j (j < lobes), last channel =
//                                 the amplitude (eq. 4: D = amplitude Σ a_j γ_j); patch (I, J)
//                                 covers fine cells [I F, I F + F) x [J F, J F + F)
//   level_F/T.exr, T_ir.exr       M x M RGB, mean 1 per channel (eq. 22-23)
//   level_F/S.exr, S_ir.exr       N² x N² RGB (eq. 24), viewable block layout: pixel
//                                 (X, Y) = (o_x N + i_x, o_y N + i_y), i.e. an N x N grid of
//                                 blocks indexed by the ωo bin, each showing the ωi slice
//   (the _ir tables exist when the model was made with interreflections)
//
// Frames. Directions are in the MACRO tangent frame (z = the undisplaced surface's normal,
// x along u, y along v): the patch NDF holds the tilt of the patch, so f'_low, S and the
// estimators all shade in the macro frame; h_low contributes position, occlusion and parallax.
//
// Angular bins: the concentric map (Shirley and Chiu 1997) of the unit square onto the disk,
// lifted to the hemisphere EQUIDISTANTLY in the polar angle (disk radius ρ = θ / 90°, azimuth
// kept), not by the cosine-weighted lift z = sqrt(1 - ρ²): with the latter the outer ring of
// N = 15 bins would span θ = 60°..90° (r from 13/15 to 1 in sin θ), far too coarse where
// shadowing and masking change fastest; here a ring of bins spans 2 x 90° / N in θ (the centre
// bin 0..6°, then rings of 12° up to the outer ring 78..90° at N = 15), so grazing directions get
// bins of their own (see prefilter/scaling.h on grazing angles).
// Bin (bx, by) covers [bx/N, (bx+1)/N) x [by/N, (by+1)/N) of the square, index b = by N + bx;
// the lookup is bilinear in (ωi's square coordinates) x bilinear in (ωo's), between bin
// centres, linearly extrapolated over the outer half bins up to the square's border (the
// horizon) and clamped at 0 (quadrilinear overall; table_lookup.cpp, axis_lerp).
#pragma once
#include <memory>
#include <string>
#include <vector>
#include <nlohmann/json.hpp>
#include "core/spectrum.h"
#include "core/vec.h"
#include "geometry/heightmap.h"
#include "image/image.h"
#include "prefilter/lobe_brdf.h"
#include "prefilter/multilobe_brdf.h"
#include "prefilter/patch_ndf.h"
#include "bsdf/material.h"

namespace meso {
class Properties;
}

namespace meso::prefilter {

/// The model directory named by `key` of `p` (a `prefiltered` material's "model", a LoD
/// block's "model"): relative paths resolve against the scene file's directory; it must be a
/// directory (otherwise p.fail(key, ...) suggests `meso prefilter`). Canonical when possible,
/// so that two spellings of one model share load_model_cached's entry.
std::string resolve_model_dir(const Properties &p, const std::string &key = "model");

/// Inverse of square_to_uniform_disk_concentric (sampling/warp.h): a point of the closed unit
/// disk to [0,1]², continuous, exact inverse up to rounding.
Vec2 concentric_disk_to_square(Vec2 d);
/// A hemisphere direction (z >= 0, normalised here; z < 0 is mirrored up) to its square
/// coordinates (concentric, equidistant in θ: see the header).
Vec2 hemisphere_to_square(Vec3 w);
/// hemisphere_to_square in float with a polynomial arctangent (no atan2): the mapping of
/// ScalingTables::eval_S (prefilter/table_lookup.cpp), within 1e-6 of hemisphere_to_square
/// (tested). Binning in the pipeline keeps the exact one.
Vec2 hemisphere_to_square_fast(Vec3 w);
/// Square coordinates to the hemisphere (the inverse of hemisphere_to_square).
Vec3 square_to_hemisphere(Vec2 u);
/// square_to_hemisphere of every cell of an N x N grid shifted by (sa, sb) in cell units: out[b]
/// for u = ((b % N + sa) / N, (b / N + sb) / N), b < N², four cells a step; the same bits as the
/// scalar map (the prefilter's ωi bins of a line: 225 directions each).
void square_to_hemisphere_grid(int N, float sa, float sb, Vec3 *out);

/// T (M x M) and S (N² x N²) of one level, RGB.
struct ScalingTables {
    int M = 0, N = 0;
    Image T;  ///< M x M, 3 channels
    Image S;  ///< N² x N², 3 channels, block layout (see the header)

    bool empty() const { return M == 0; }
    /// S at bin indices (ωi bin, ωo bin), each b = by N + bx.
    Spectrum S_bin(int bi, int bo) const;
    void set_S_bin(int bi, int bo, Spectrum s);
    /// T at map position x ∈ [0,1)² (wrapped): bilinear between patch centres, periodic
    /// (prefilter/table_lookup.cpp, like eval_S).
    Spectrum eval_T(Vec2 x) const;
    /// S(ωi, ωo), macro frame: quadrilinear between bin centres, clamped at the border.
    Spectrum eval_S(Vec3 wi, Vec3 wo) const;
};

struct PrefilteredLevel {
    int factor = 1;
    HeightMap h_low;               ///< (W/F) x (H/F), original map units
    std::vector<PatchNdf> ndf;     ///< (W/F) (H/F) patches, index J (W/F) + I
    ScalingTables single, ir;      ///< ir is empty unless made with interreflections
    nlohmann::json stats;          ///< timings, errors (from the manifest)
    int width() const { return h_low.width; }
    int height() const { return h_low.height; }
};

struct PrefilteredModel {
    std::string dir;
    nlohmann::json manifest;
    int map_width = 0, map_height = 0;
    /// Cell-space scale of the original map: cell-space height = map value * height_cells
    /// (= height_scale / tile_size * W); fixed by the inputs of `meso prefilter`.
    double height_scale = 1.0;  ///< world units per map unit
    double tile_size = 1.0;     ///< world size of one tile of the map (square cells)
    /// input.wrap: with clamp or mirror the model describes the map's 2W x 2H periodic_extension
    /// (map_width = 2W), so a `tiling` of the original map halves (absent in older models: repeat).
    WrapMode wrap = WrapMode::Repeat;
    nlohmann::json base;        ///< the base material (a meso material object)
    int lobes = 6;
    QuadratureOptions quadrature;  ///< how f'_low integrates the NDF (part of the model)
    std::vector<PrefilteredLevel> levels;

    /// Reads a model directory; throws MesoError naming the file and key on bad input.
    static PrefilteredModel load(const std::string &dir);
    /// Writes the directory (creating it); manifest levels/stats are taken from `manifest`
    /// plus what this object holds.
    void save(const std::string &dir) const;
    /// The level with this factor, or null.
    const PrefilteredLevel *level_for_factor(int factor) const;
    /// The levels' factors, "2, 4", for messages naming what a model has.
    std::string factor_list() const;
    /// input.map_samples: heights (map units) of the prefiltered map at map_fingerprint_vertices
    /// (empty in models made before it was recorded).
    std::vector<double> map_samples;
};

/// The model's own base material (manifest input.base), built anew: relative file names in it
/// resolve against input.base_dir (where `meso prefilter` read the --base file) when that
/// directory exists, else the model directory `dir`. Throws MesoError naming the manifest.
std::shared_ptr<Material> create_model_base(const PrefilteredModel &model, const std::string &dir);

/// kMapFingerprintSize vertices of a w x h map spread by a fixed low-discrepancy rule: the model
/// records the map's heights there (input.map_samples) so that a scene with another map of the
/// same size is told (lod/lod_build.cpp).
constexpr int kMapFingerprintSize = 64;
std::vector<std::pair<int, int>> map_fingerprint_vertices(int w, int h);

/// Lobes image of a level (see the header) and back.
Image lobes_to_image(const std::vector<PatchNdf> &ndf, int width, int height, int lobes);
std::vector<PatchNdf> lobes_from_image(const Image &img, int lobes, const std::string &where);

/// The flow form's name in the manifest and on the command line: "eq5", "visible" or "lobes".
std::string flow_name(const QuadratureOptions &q);

/// The spatially varying multi-lobe BRDF f'_low of one level (eq. 11), a Material evaluated
/// in the MACRO frame (local z = the macro normal): patch (I, J) = floor(frac(uv) (W/F, H/F)).
/// One MultiLobeBrdf per patch, built once (≈ nodes · 76 bytes per patch); with q.lobes, one
/// SvLobeBrdf for the level instead (lobe_brdf.h; then patch() must not be called).
class SvMultiLobe final : public Material {
public:
    /// base_json: the base's scene object (needed by q.lobes, which recognises the base from it;
    /// base_where names it in errors).
    SvMultiLobe(std::shared_ptr<const Material> base, const std::vector<PatchNdf> &ndf, int width, int height,
                const QuadratureOptions &q, const nlohmann::json &base_json = nullptr,
                const std::string &base_where = "base");
    const MultiLobeBrdf &patch(Vec2 uv) const;
    /// The closed-form f'_low of --flow lobes models, else null.
    const SvLobeBrdf *lobe_form() const { return m_lobe_form.get(); }
    const Material &base() const { return *m_base; }
    Spectrum eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override;
    float pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override;
    Spectrum eval_pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi, float *pdf) const override;
    bool sample(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, BSDFSample &out) const override;
    uint32_t flags() const override;
    Spectrum albedo_hint(const ShadingContext &ctx) const override;
    bool is_reciprocal() const override { return false; }
    std::string to_string() const override;
    size_t memory_bytes() const;

private:
    std::shared_ptr<const Material> m_base;
    std::vector<std::unique_ptr<MultiLobeBrdf>> m_patches;
    std::unique_ptr<SvLobeBrdf> m_lobe_form;
    int m_w = 0, m_h = 0;
};

}  // namespace meso::prefilter
