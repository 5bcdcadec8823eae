// Statistical verification of material sampling, shared by `meso material` and the test
// battery (after Mitsuba 3's python/mitsuba/chi2.py).
//
// chi2_material_test draws M samples from Material::sample(), histograms the non-delta
// directions on a grid in (φ, cos θ) (equal-area cells; the upper hemisphere for
// reflection-only materials, the whole sphere otherwise), integrates Material::pdf() over
// every cell (composite Simpson in (θ, φ) with `sub` x `sub` intervals per cell, in θ so
// that the pole is resolved), pools cells with expected count < 5, and computes Pearson's
// χ² and its p-value from the regularized incomplete gamma function. The test rejects when
// p < α_i with the Šidák correction α_i = 1 − (1 − α)^(1/T) for T tests. It also checks,
// for every non-delta sample, that weight == eval/pdf and sample.pdf == pdf(wi).
// On failure, when MESO_CHI2_DUMP_DIR is set, the observed and expected histograms are
// written to $MESO_CHI2_DUMP_DIR/<name>.json for plotting.
#pragma once
#include <cstdint>
#include <string>
#include <vector>
#include "core/vec.h"
#include "geometry/shading.h"

namespace meso {

class Material;

struct Chi2Options {
    int res = 16;                 ///< cos θ bins per hemisphere (φ gets 2·res)
    int sub = 16;                 ///< Simpson intervals per cell and axis (multiple of 4)
    uint64_t samples = 500000;    ///< M
    uint64_t seed = 1;
    double alpha = 0.01;          ///< significance of the whole family of tests
    int test_count = 1;           ///< T, for the Šidák correction
    double min_expected = 5.0;    ///< cells below are pooled
    double rel_tolerance = 1e-3;  ///< weight/pdf consistency tolerance (relative)
    std::string name = "chi2";    ///< file name of the dump
};

struct Chi2Result {
    bool passed = false;          ///< χ² accepted, weights/pdfs consistent, no structural error
    bool chi2_passed = false;     ///< the χ² part alone (p >= significance)
    double p_value = 0.0;
    double chi2 = 0.0;
    int dof = 0;
    double significance = 0.0;    ///< Šidák-corrected per-test level
    uint64_t samples = 0;         ///< M
    uint64_t smooth = 0;          ///< non-delta samples that were histogrammed
    uint64_t delta = 0;           ///< delta-lobe samples (not histogrammed)
    uint64_t failed = 0;          ///< sample() returned false
    uint64_t invalid = 0;         ///< non-finite or negative weight/pdf, non-unit direction
    uint64_t outside = 0;         ///< directions outside the domain (below a reflector)
    uint64_t weight_mismatch = 0; ///< weight != eval/pdf
    uint64_t pdf_mismatch = 0;    ///< sample.pdf != pdf(wi)
    double max_weight_rel_error = 0.0;
    double max_pdf_rel_error = 0.0;
    double pdf_integral = 0.0;    ///< ∫ pdf over the domain (numerical)
    bool sphere = false;
    std::string message;          ///< why it failed (empty when passed)
    std::string dump_path;        ///< histogram file written on failure, if any
};

Chi2Result chi2_material_test(const Material &material, const ShadingContext &ctx, const Vec3 &wo,
                              const Chi2Options &opt);

/// ∫ pdf(wo, ·) dω over the sphere (or the upper hemisphere when `hemisphere`), by the
/// same per-cell Simpson rule as the χ² test.
double integrate_pdf(const Material &material, const ShadingContext &ctx, const Vec3 &wo, bool hemisphere,
                     int res = 16, int sub = 16);

struct AlbedoEstimate {
    Spectrum mean;     ///< E[weight] (failed samples count as 0)
    Spectrum stderr_;  ///< sample standard deviation / sqrt(N)
    uint64_t samples = 0;
};
/// Directional albedo ∫ f |cos θi| dωi estimated with the material's own sampler, in flux
/// units: a refracted sample's weight is multiplied by BSDFSample::eta², undoing the radiance
/// scaling (η_o/η_i)² of transmission (material.h, dielectric.cpp), so that the albedo is the
/// fraction of energy scattered (<= 1 for every energy-conserving material, from either side).
AlbedoEstimate estimate_albedo(const Material &material, const ShadingContext &ctx, const Vec3 &wo,
                               uint64_t samples, uint64_t seed);

/// Regularized lower / upper incomplete gamma P(a, x), Q(a, x) = 1 − P (Numerical Recipes
/// §6.2: series for x < a + 1, Lentz continued fraction otherwise).
double gamma_p(double a, double x);
double gamma_q(double a, double x);
/// P(χ²_dof >= x): the p-value of a χ² statistic.
double chi2_p_value(double x, int dof);
/// Šidák-corrected significance for one of `tests` independent tests at family level alpha.
double sidak_alpha(double alpha, int tests);

}  // namespace meso
