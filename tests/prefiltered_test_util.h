// The tiny prefiltered model and scene helpers shared by tests/test_prefiltered_material.cpp and
// tests/test_prefiltered_stochastic.cpp: a 16x16 fbm map, patch NDFs fitted for factors 2 and 4,
// scaling tables with known values (factor 4 with interreflection tables, factor 2 without),
// saved once per process with PrefilteredModel::save.
#pragma once
#include <gtest/gtest.h>
#include "cli_capture.h"
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "geometry/heightfield.h"
#include "geometry/heightmap_gen.h"
#include "geometry/interaction.h"
#include "geometry/shape.h"
#include "material_test_util.h"
#include "prefilter/model.h"
#include "prefilter/patch_ndf.h"
#include "render_test_util.h"
#include "bsdf/chi2.h"
#include "sampling/rng.h"
#include "sampling/warp.h"
#include "scratch_dir.h"

namespace meso::test::pf {

using namespace meso;
using namespace meso::prefilter;
using meso::test::make_material;


namespace fs = std::filesystem;

inline const char *const kBase = R"({"type":"diffuse","reflectance":[0.8,0.6,0.4]})";
inline constexpr int kMapSize = 16, kM = 2, kN = 5;

inline std::map<std::string, std::string> map_params() {
    return {{"size", std::to_string(kMapSize)}, {"seed", "5"}, {"amplitude", "0.05"}};
}

/// T and S of known values. single: T = 1, S = 1 + 0.2 bi / N²; ir: T = a 2x2 pattern of mean 1,
/// S = (1 + 0.2 bi / N²)(1 + 0.1 bo / N²) with a tint per channel.
inline ScalingTables make_tables(bool ir) {
    ScalingTables t;
    t.M = kM, t.N = kN;
    t.T = Image(kM, kM, 3);
    t.S = Image(kN * kN, kN * kN, 3);
    const float Tv[2][2] = {{0.8f, 1.1f}, {1.25f, 0.85f}};
    for (int y = 0; y < kM; ++y)
        for (int x = 0; x < kM; ++x) t.T.set_rgb(x, y, Spectrum(ir ? Tv[y][x] : 1.f));
    for (int bi = 0; bi < kN * kN; ++bi)
        for (int bo = 0; bo < kN * kN; ++bo) {
            const float s = 1.f + 0.2f * float(bi) / float(kN * kN);
            if (!ir) t.set_S_bin(bi, bo, Spectrum(s));
            else {
                const float o = 1.f + 0.1f * float(bo) / float(kN * kN);
                t.set_S_bin(bi, bo, Spectrum(s * o, s * o * 0.9f, s * o * 1.1f));
            }
        }
    return t;
}

/// The model, built once per process in the scratch directory.
struct TinyModel {
    std::string dir;
    PrefilteredModel model;  ///< as saved
};

/// World size of one map tile in lod_scene (a plane 2 units wide, tiling 16), and its height scale.
constexpr double kLodTile = 2.0 / 16.0;

inline const TinyModel &tiny_model() {
    static const TinyModel m = [] {
        TinyModel t;
        t.dir = (fs::path(meso::test::scratch_dir("meso_prefiltered_test")) / "model").string();
        const HeightMap map = generate_height_map("fbm", map_params()).height;
        const Heightfield hf(map, 1.f, 0.f);
        PatchNdfOptions opt;
        opt.samples_per_cell = 2;
        opt.cell_size = 1.0 / kMapSize;  // generated heights are in tile units (patch_ndf.h)
        PrefilteredModel &pm = t.model;
        pm.map_width = pm.map_height = kMapSize;
        // The surface of lod_scene: one tile is 2 / 16 world units, heights scale 1/8 (slopes
        // as fitted: height_scale / tile_size = 1, heights in tile units).
        pm.tile_size = pm.height_scale = kLodTile;
        pm.lobes = 6;
        pm.base = nlohmann::json::parse(kBase);
        pm.manifest = {{"input",
                        {{"map_width", kMapSize},
                         {"map_height", kMapSize},
                         {"height_scale", kLodTile},
                         {"tile_size", kLodTile},
                         {"base", pm.base}}},
                       {"parameters",
                        {{"lobes", 6}, {"M", kM}, {"N", kN}, {"quadrature_polar", 4}, {"quadrature_azimuth", 6}}}};
        for (int F : {2, 4}) {
            PrefilteredLevel L;
            L.factor = F;
            L.h_low = hf.box_downsampled(F);
            L.ndf = fit_svndf(hf, F, opt);
            L.single = make_tables(false);
            if (F == 4) L.ir = make_tables(true);
            pm.levels.push_back(std::move(L));
        }
        pm.save(t.dir);
        return t;
    }();
    return m;
}

inline std::shared_ptr<Material> prefiltered(const std::string &extra) {
    return make_material(fmt::format(R"({{"type":"prefiltered","model":"{}"{}}})", tiny_model().dir, extra));
}

/// f'_low of a level, built independently of the material (same base, same NDFs).
inline std::unique_ptr<SvMultiLobe> reference_svbrdf(const PrefilteredModel &m, int factor) {
    const PrefilteredLevel *L = m.level_for_factor(factor);
    return std::make_unique<SvMultiLobe>(make_material(kBase), L->ndf, L->width(), L->height(), m.quadrature);
}

inline void expect_spectrum_near(Spectrum a, Spectrum b, double rel, const std::string &what) {
    for (int c = 0; c < 3; ++c)
        EXPECT_NEAR(a[c], b[c], rel * std::max(std::abs(a[c]), std::abs(b[c])) + 1e-7) << what << " channel " << c;
}

inline std::string error_of(const std::function<void()> &f) { return meso::test::meso_error_of(f); }



inline std::string lod_scene(const std::string &lod) {
    // 16-texel map tiled 16x over a plane 2 units wide (128 texels per unit); at distance 6 a
    // pixel of the 32-pixel camera covers 2 * 6 tan(20°) / 32 * 128 / 4 ≈ 4.4 texels (spp 16):
    // level 1 (factor 4) alone. The material is the model's base (kBase), as a LoD block requires.
    return fmt::format(R"({{
      "camera": {{"type": "perspective", "origin": [0, -2, 6], "target": [0, 0, 0], "up": [0, 1, 0],
                 "fov": 40, "width": 32, "height": 32}},
      "integrator": {{"type": "path", "max_depth": 3}},
      "sampler": {{"type": "independent", "sample_count": 16}},
      "shapes": [{{"type": "rectangle",
                  "material": {{"type": "diffuse", "reflectance": [0.8, 0.6, 0.4]}},
                  "displacement": {{"map": {{"generator": "fbm", "size": {}, "seed": 5, "amplitude": 0.05}},
                                   "scale": 0.125, "tiling": 16}},
                  "lod": {}}}],
      "lights": [{{"type": "directional", "direction": [0.3, 0.5, -1], "irradiance": 2}}]
    }})",
                       kMapSize, lod);
}

/// Mean of the green channel over the central 8 x 8 pixels (on the plane).
inline double centre_mean(const Image &img) {
    double sum = 0.0;
    for (int y = 12; y < 20; ++y)
        for (int x = 12; x < 20; ++x) sum += img.at(x, y, 1);
    return sum / 64.0;
}

inline std::string write_scene(const std::string &name, const std::string &text) {
    const std::string p = (fs::path(meso::test::scratch_dir("meso_prefiltered_test")) / name).string();
    std::ofstream(p) << text;
    return p;
}


}  // namespace meso::test::pf
