// What a material or texture sees at a shading point.
#pragma once
#include <limits>
#include "core/frame.h"
#include "core/spectrum.h"

namespace meso {

/// Surface point as seen by materials and textures. Directions handed to materials are
/// in the local frame of `frame` (z = shading normal).
struct ShadingContext {
    Vec3 p;          ///< world position
    Vec2 uv;         ///< texture coordinates
    Frame frame;     ///< shading frame (s along dp/du where available)
    Vec3 ng;         ///< geometric normal (world, unit)
    /// Surface parameterisation derivatives (world; zero when unknown). Materials that read
    /// texture-space slopes (LEAN, LEADR, ...) map them to the frame with these (paper 000 eq. 12).
    Vec3 dpdu, dpdv;
    /// +1 when frame.n is the shape's shading normal, -1 when the two-sided integrator flipped
    /// the frame towards wo (heights along the shape's normal then point into the surface).
    float side = 1.f;
    /// The macro surface when the hit is on microgeometry (shell-mapped displacement): its
    /// unit normal (world; flipped with `side`, like frame.n) and a tangent along u (world,
    /// not normalised). Both zero elsewhere: then the shading frame is the macro frame.
    /// Prefiltered LoD materials (paper 004) shade in the frame (s along dpdu_macro, t along
    /// dpdv_macro, n_macro), which is LEFT-handed where the uv parameterisation is (a
    /// `rectangle`'s v runs down): the map's y axis must follow v, as the displacement does.
    Vec3 n_macro, dpdu_macro, dpdv_macro;
    /// Height of the hit in the displacement field (world units) when it is on shell-mapped
    /// microgeometry, NaN elsewhere (the `microcolormap` texture's ground truth, paper 001).
    float micro_height = std::numeric_limits<float>::quiet_NaN();
    // Ray-differential footprint on the surface (zero when unknown, e.g. in `meso material`).
    Vec3 dpdx, dpdy;
    float dudx = 0, dudy = 0, dvdx = 0, dvdy = 0;
    // Level of detail chosen for this path (LoD materials read it; others ignore it).
    int lod_level = 0;
    float lod_weight = 0.f;
    /// A uniform random number in [0, 1) for materials with a stochastic evaluation (set by the
    /// integrators for next-event estimation, one per path vertex); < 0: evaluate exactly. Every
    /// material but `prefiltered` with "estimator": "stochastic" ignores it. Setting it declares
    /// that the integrator pairs the pdf of eval_pdf with the pdf of sample() in its MIS weights
    /// (as the path tracer does): such a material may then return an unbiased estimate of f with
    /// the pdf of the strategy that produced it instead of the exact f and mixture pdf
    /// (prefilter/multilobe_brdf.h, "Stochastic one-node estimator").
    float u_eval = -1.f;
};

}  // namespace meso
