// The prefiltered model's bias against brute force of the original surface (issue 21 item 5, "no
// unexplained bias"): a lobes-form model of a sawtooth with a diffuse base, shaded as the renderer
// shades it (T S f'_low on the flat h_low of a coarse level), against the original's effective
// BRDF with every bounce (prefilter/effective_brdf.h), both as directional albedos (the sky's
// view: ωi integrated) at view directions on both sides of where a facet turns away from the
// viewer.
//
// The bias this guards against: the lobes form weighted a Lambertian lobe towards ωo by
// min(H(μ_j,z), H(μ_j·ωo)), a step where the facet turns away (μ_j·ωo = 0; a sawtooth's lobes are
// nearly deltas), while the original's facets fade out with their projected area. S = original /
// f'_low then jumped (0.8 to 3.4 within a bin on the bench sawtooth), and S read by interpolation
// between bin centres across the step gave the bins beside it energy the fit never put there:
// the bench sawtooth rendered 1.2-2.3% too bright under the sky (env_gi), its θo rings ±10% off
// the fitted energy. The lobes are now weighted by their projected area C(μ_j·ωo, κ_j)
// (lobe_brdf.h), continuous there.
#include <gtest/gtest.h>
#include <cmath>
#include <cstdlib>
#include <map>
#include <string>
#include <fmt/format.h>
#include "cli_capture.h"
#include "geometry/heightfield.h"
#include "geometry/heightmap_gen.h"
#include "material_test_util.h"
#include "prefilter/effective_brdf.h"
#include "prefilter/model.h"
#include "scratch_dir.h"

using namespace meso;
using namespace meso::prefilter;
using meso::test::make_material;

namespace {

const char *const kBase = R"({"type": "diffuse", "reflectance": 0.8})";

std::map<std::string, std::string> sawtooth_params() {
    return {{"width", "64"}, {"height", "64"}, {"periods", "16"}, {"angle_a", "30"}, {"angle_b", "60"}};
}

Vec3 dir_deg(double theta, double phi) {
    const double t = theta * M_PI / 180, p = phi * M_PI / 180;
    return Vec3(float(std::sin(t) * std::cos(p)), float(std::sin(t) * std::sin(p)), float(std::cos(t)));
}

struct Comparison {
    double mean_ratio = 0;     ///< mean over the view directions of model / original
    double max_dev = 0;        ///< largest |model / original - 1|
    double ratio_se = 0;       ///< standard error of mean_ratio from the estimators' own errors
};

/// Directional albedo (ωi integrated) of the model's level 16 on its flat h_low against the
/// original's, with every bounce, at views across the facets' turning-away directions.
Comparison compare(const std::string &dir) {
    const HeightMap fine = generate_height_map("sawtooth", sawtooth_params()).height;
    const Heightfield orig(fine, float(fine.width), 0.f);
    const PrefilteredModel m = PrefilteredModel::load(dir);
    const PrefilteredLevel &L = m.levels.at(0);
    const Heightfield low(L.h_low, float(L.width()), 0.f);
    auto base = make_material(kBase);
    auto mat = make_material(fmt::format(R"({{"type": "prefiltered", "model": "{}", "level": 16, "scaling": "ir"}})", dir));
    EffectiveBrdfEstimator::Options mo;
    mo.macro_frame = true;
    const EffectiveBrdfEstimator eo(orig, *base), el(low, *mat, mo);
    Comparison c;
    double var = 0;
    int n = 0;
    uint64_t seed = 1;
    // The 30° facet (normal towards −x) turns away at θo = 60° towards +x (φ = 0), the 60° one at
    // θo = 30° towards −x (φ = 180).
    for (double phi : {0.0, 20.0, 160.0, 180.0})
        for (double theta : {25.0, 33.0, 41.0, 50.0, 57.0, 63.0, 69.0, 75.0}) {
            const Vec3 wo = dir_deg(theta, phi);
            const auto a = eo.albedo(PatchRegion::whole(orig), wo, 20000, ++seed, kAllBounces);
            const auto b = el.albedo(PatchRegion::whole(low), wo, 20000, ++seed, 1);
            const double r = b.value[1] / a.value[1];
            std::printf("  view (%2.0f, %3.0f): original %.4f, model %.4f, ratio %.4f\n", theta, phi, a.value[1],
                        b.value[1], r);
            c.mean_ratio += r, ++n;
            c.max_dev = std::max(c.max_dev, std::abs(r - 1.0));
            var += r * r * (std::pow(a.std_error[1] / a.value[1], 2) + std::pow(b.std_error[1] / b.value[1], 2));
        }
    c.mean_ratio /= n;
    c.ratio_se = std::sqrt(var) / n;
    return c;
}

}  // namespace

TEST(PrefilteredBias, LobesFormDiffuseSawtoothMatchesBruteForce) {
    // MESO_TEST_BIAS_MODEL: compare a model made elsewhere (e.g. by an older meso) instead.
    std::string dir;
    if (const char *env = std::getenv("MESO_TEST_BIAS_MODEL")) dir = env;
    else {
        // (The scratch directory is one per process, shared by every test: a name of its own.)
        dir = meso::test::scratch_dir("prefiltered_bias") + "/bias_sawtooth_model";
        std::vector<std::string> args{"prefilter", "-q", "-o", dir, "--generator", "sawtooth", "--base", kBase,
                                      "--scales", "16", "-M", "1", "-N", "15", "--paths", "256", "--low-paths", "64",
                                      "--flow", "lobes", "--seed", "3"};
        for (const auto &[k, v] : sawtooth_params()) args.insert(args.end(), {"-p", k + "=" + v});
        const meso::test::CliResult r = meso::test::run_cli_captured(args);
        ASSERT_EQ(r.code, 0) << r.err;
    }
    const Comparison c = compare(dir);
    std::printf("model / original: mean %.4f (+-%.4f), largest deviation %.4f\n", c.mean_ratio, c.ratio_se, c.max_dev);
    // Measured (seeds 3, 4, 5): mean 0.997, 1.002, 1.000, largest deviation 0.11, 0.11, 0.08 (at
    // θo = 50-57° towards +x, left in the fitted S itself: docs/performance.md); with the step
    // (cap_mass, meso before lambert_view) mean 0.987 and largest deviation 0.39 (+39% at 57°,
    // −30% at 63°: the bins beside the 30° facet's turning away). The mean's tolerance adds 0.008
    // for the model's own noise (its S is an estimate; the three seeds above spread by 0.005).
    EXPECT_NEAR(c.mean_ratio, 1.0, 0.008 + 4 * c.ratio_se);
    EXPECT_LT(c.max_dev, 0.2);
}

