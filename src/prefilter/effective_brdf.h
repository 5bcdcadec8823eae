// Monte Carlo estimators of the EFFECTIVE BRDF of a patch of microgeometry (paper 004,
// Wu et al. 2019): a periodic heightfield with a base BRDF, traced exactly with the one
// heightfield intersector of meso (geometry/heightfield.h).
//
//   single bounce (eq. 6-8):
//     f_eff(wi, wo) = 1/A(wo) ∫_P f(x_m, wi, wo) <w_m, wi> V(x_m, wi) A(p, wo) k_P(p) dp,
//     A(p, wo) = <wo, w_m> / <w_g, w_m> V(x_m, wo),   A(wo) = ∫_P A(p, wo) k_P(p) dp;
//   with interreflections (eq. 15-17): f_eff^ir = 1/A(wo) ∫_P r(x_m(p), wi, wo) A(p, wo) k_P dp,
//     r = the sum over paths x_1 .. x_k on the microsurface of prod_j f <n_j, w_j->j+1>
//     times V(x_k, wi) (eq. 15-16).
//
// What the value means (the normalisation). A patch lit by a distant light from wi with
// irradiance E_perp (on a plane perpendicular to wi) sends towards wo the radiance of its
// visible points averaged over their projected area as seen from wo:
//     L_o = 1/A(wo) ∫_P L(x_m(p), wo) A(p, wo) k_P dp,   L(x_m, wo) = f <w_m, wi> V(x_m, wi) E_perp,
// and a macro BRDF f_macro is defined by L_o = f_macro cos(theta_i) E_perp. So eq. 6 is
//     f_eff(wi, wo) = f_macro(wi, wo) * cos(theta_i)     (macro cosine included),
// the same convention as Material::eval (f * |cos theta_i|): Estimate::value is directly
// comparable with a material's eval(wo, wi) in the macro frame (equal on a flat
// heightfield), and Estimate::brdf = value / cos(theta_i) is f_macro. The paper's
// reciprocity (eq. 25), f_eff(wi, wo) A(wo) = f_eff(wo, wi) A(wi), is then the symmetry of
// f_macro cos(theta_i) cos(theta_o) when A(w) = cos(theta) (below).
//
// A(wo) for a heightfield. k_P is the box kernel 1/|P| on P. Every line of sight along -wo
// (wo.z > 0) meets a heightfield exactly once at its first hit, and the first hits are the
// visible points; a visible surface element dS = dp / <w_g, w_m> has projected area
// <wo, w_m> dS perpendicular to wo, i.e. A(p, wo) dp / cos(theta_o) on the base plane
// z = const when projected along wo. Hence:
//   * over whole periods of a periodic field, the visible points' footprints tile the base
//     plane: A(wo) = cos(theta_o) exactly (eq. 8 with w_n = w_g, the mean slope is zero);
//   * for any P, shooting rays along -wo from points q uniform on a base-plane region Q
//     gives first hits x_m(p) with density A(p, wo) / (cos(theta_o) |Q|) in p. Keeping the
//     hits with p in P: A(wo) = cos(theta_o) |Q| / |P| * Pr(p in P), and eq. 6 becomes the
//     plain mean of the integrand over the kept hits (a ratio estimator, exact in the limit).
// The estimator does exactly this: along an axis where P spans a whole number of map
// periods Q = P and no hit is rejected (periodicity); along other axes Q is P widened by the
// largest horizontal drift of a line of sight through the height range, and hits outside P
// (unwrapped cell coordinates) are rejected. Masking is thereby exact (only first hits are
// ever shaded), shadowing is the occluded() test towards wi, and paths may leave P and come
// back through the periodic wrap (the integer cell offsets of the intersector).
//
// Units. Everything is in the heightfield's CELL SPACE, taken as Euclidean: x, y in cells
// and h in the same unit (directions wi, wo are in that frame, z = macro normal = w_g). A
// map in tile units (heightmap_gen.h: heights in units of the tile side) of size N x N is
// built as Heightfield(map, N, 0) so that its slopes are preserved; non-square cells or
// other height units must be converted by the caller through the Heightfield's scale.
//
// Base material: any meso Material, evaluated in the local frame of the micro-normal
// n = normalize(-dh/dx, -dh/dy, 1) with s along the x tangent (1, 0, dh/dx), uv = cell
// position / map size (wrapped into [0,1)). Delta lobes cannot be evaluated (a mirror base
// has a distribution as its effective BRDF): their next-event terms are zero, so a
// delta-only base gives 0. Transmission is not followed (paths end).
//
// Paths (max_bounces > 1): from each vertex, a next-event term towards wi (eval times the
// shadow visibility) is added, then the base material's sample() continues the path to the
// next hit on the periodic surface; an escaping path ends (a distant directional light is a
// delta in direction: escaping exactly along wi has measure zero). The vertex count is at
// most max_bounces; Russian roulette on the path throughput starts at vertex
// `roulette_start` (unbiased; throughput 1, e.g. a white diffuse base, is never killed).
//
// Determinism: samples are split into fixed chunks with their own PCG32 stream
// (hash of seed and chunk index) run in parallel (TBB) and summed in chunk order, so a
// result depends on (seed, samples) only, not on the thread count.
#pragma once
#include <cstddef>
#include <cstdint>
#include "core/spectrum.h"
#include "core/vec.h"
#include "geometry/heightfield.h"
#include "bsdf/material.h"

namespace meso::prefilter {

/// The patch P, an axis-aligned rectangle [x0, x1) x [y0, y1) in (unwrapped) cell space
/// over which k_P is the box kernel; the heightfield tiles periodically around it.
struct PatchRegion {
    double x0 = 0, y0 = 0, x1 = 0, y1 = 0;
    /// One whole period of the map: [0, W) x [0, H).
    static PatchRegion whole(const Heightfield &hf) { return {0, 0, double(hf.width()), double(hf.height())}; }
    double area() const { return (x1 - x0) * (y1 - y0); }
};

/// Every vertex count a path may need (paths then end by escaping or by Russian roulette).
constexpr int kAllBounces = 1 << 20;

class EffectiveBrdfEstimator {
public:
    struct Options {
        /// Russian roulette from this vertex on (1-based; 0 = never): survival probability
        /// min(1, max channel of the throughput).
        int roulette_start = 4;
        /// Samples per deterministic chunk (one RNG stream each).
        size_t chunk = 4096;
        /// Evaluate and sample the base in the MACRO frame (x, y, z) instead of the micro-normal
        /// frame: the convention of prefiltered models (prefilter/model.h), whose BRDF holds
        /// the patch's normals itself. Directions below the micro-facet's tangent plane are
        /// then blocked (light: unshadowed only above the facet; a sampled continuation into the
        /// facet ends the path), as a renderer shading the facet does.
        bool macro_frame = false;
    };

    struct Estimate {
        /// Eq. 6 / 17: f_macro(wi, wo) * cos(theta_i), the convention of Material::eval.
        Spectrum value;
        Spectrum std_error;       ///< standard error of `value` (per channel)
        Spectrum brdf;            ///< value / cos(theta_i): the macro BRDF f_macro
        double projected_area = 0;            ///< A(wo) of eq. 8 (per unit patch area)
        double projected_area_std_error = 0;  ///< 0 when P spans whole periods (then exact)
        size_t samples = 0;       ///< lines of sight shot
        size_t accepted = 0;      ///< of which hit the surface inside P (the mean's count)
        size_t leaked = 0;        ///< lines of sight that missed the surface (should be 0)
        double mean_vertices = 0; ///< path vertices per accepted sample (cost; 1 for one bounce)
    };

    /// Keeps references: `hf` and `base` must outlive the estimator. Throws MesoError on an
    /// empty heightfield.
    EffectiveBrdfEstimator(const Heightfield &hf, const Material &base, Options options);
    EffectiveBrdfEstimator(const Heightfield &hf, const Material &base)
        : EffectiveBrdfEstimator(hf, base, Options{}) {}

    /// f_eff(wi, wo) over P (wi, wo unit or not, in the macro frame, z up) with `samples`
    /// lines of sight and paths of at most `max_bounces` vertices (1: eq. 6, single bounce
    /// with shadowing-masking; > 1: eq. 17). Directions at or below the horizon give an
    /// all-zero estimate (A = 0 too when wo is below). Throws MesoError on an empty or
    /// non-finite region, zero or non-finite directions, samples == 0 or max_bounces < 1.
    Estimate estimate(const PatchRegion &region, Vec3 wi, Vec3 wo, size_t samples, uint64_t seed,
                      int max_bounces = 1) const;

    /// The effective albedo ∫ f_eff(wi, wo) dwi over the upper hemisphere of wi (white
    /// furnace): the same estimator with a fresh cosine-distributed wi per line of sight,
    /// weighted by 1 / pdf. value = brdf = the albedo.
    Estimate albedo(const PatchRegion &region, Vec3 wo, size_t samples, uint64_t seed, int max_bounces) const;

private:
    Estimate run(const PatchRegion &region, const Vec3 *wi, Vec3 wo, size_t samples, uint64_t seed,
                 int max_bounces) const;

    const Heightfield &m_hf;
    const Material &m_base;
    Options m_opt;
};

}  // namespace meso::prefilter
