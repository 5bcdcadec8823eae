// A ray's hit on a surface, with everything shading needs.
#pragma once
#include <limits>
#include "core/frame.h"
#include "core/ray.h"
#include "geometry/shading.h"

namespace meso {

class Shape;
class Camera;

struct SurfaceInteraction {
    float t = Infinity;
    Vec3 p;           ///< hit position (world)
    Vec3 ng;          ///< geometric normal (unit, world; facing as the shape defines it)
    Vec3 ns;          ///< interpolated shading normal (unit, world)
    Vec2 uv;
    Vec3 dpdu, dpdv;  ///< surface parameterisation derivatives (world)
    /// Derivatives of the unit shading normal ns along u and v (world), for the transport of
    /// ray differentials through curved specular surfaces. Meshes fill them from the
    /// interpolated vertex normals, the analytic sphere with dp/du / r; zero (flat) where a
    /// shape does not set them, e.g. shell-mapped micro-surfaces (bilinear patches whose
    /// curvature is below the footprint scale anyway). Meshes fill them only on
    /// compute_normal_derivatives() (zero until then).
    Vec3 dndu, dndv;
    Vec2 bary;        ///< the primitive's barycentrics (Embree's u, v) at the hit
    /// Macro surface for footprints, when the hit is on microgeometry (shell-mapped
    /// displacement): its normal and uv tangents. If n_footprint is non-zero,
    /// compute_differentials transfers the offset rays to this plane and solves with these
    /// tangents, so footprints measure the base surface in texels of the full map instead
    /// of being projected onto tilted micro-facets.
    Vec3 n_footprint, dpdu_footprint, dpdv_footprint;
    /// Height of the hit in the displacement field (world units) on shell-mapped
    /// microgeometry; NaN elsewhere (ground truth for colour maps on heights, paper 001).
    float micro_height = std::numeric_limits<float>::quiet_NaN();
    Vec3 wo;          ///< direction towards the ray origin (unit, world)
    float p_error = 0.f; ///< absolute error bound of p (per component), set by the shape
    const Shape *shape = nullptr;
    uint32_t prim = 0;
    // Footprint from ray differentials (Igehy 1999); zero if the ray had none.
    Vec3 dpdx, dpdy;
    float dudx = 0, dudy = 0, dvdx = 0, dvdy = 0;

    /// Fills dpdx..dvdy from the ray's differentials (transfer to the tangent plane, then
    /// solve the least-squares 2x2 for the uv derivatives). Where the ray has none (after
    /// rough scattering) or the transfer fails (offset ray parallel to or leaving the
    /// plane), uses camera->approximate_dp_dxy (pbrt-v4); leaves zeros if camera is null.
    /// Always finite: the grazing 1/cos stretch is capped at MaxFootprintStretch and the uv
    /// derivatives are clamped to +-1e8 (0 for degenerate dp/du, dp/dv).
    void compute_differentials(const RayDifferential &ray, const Camera *camera = nullptr);
    /// Fills dndu, dndv where the shape computes them on demand (meshes); idempotent.
    void compute_normal_derivatives();
    /// Shading context with frame from ns and dpdu (flipped towards wo when `two_sided`).
    ShadingContext shading_context(bool two_sided) const;
    /// Origin offset along ng to the side of direction d, robust against self-intersection
    /// (Wachter & Binder, Ray Tracing Gems ch. 6: integer ULP offsets scaled by |p|).
    Vec3 offset_origin(Vec3 d) const;
    Ray spawn_ray(Vec3 d) const;
    /// Shadow ray towards point `target`, stopping just short of it.
    Ray spawn_ray_to(Vec3 target) const;
};

}  // namespace meso
