// A ray's hit on a surface, with everything shading needs.
#pragma once
#include <emmintrin.h>
#include <cmath>
#include <cstdint>
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
    /// Inline: built once per path vertex, and a call returning it through memory made its
    /// caller reload the frame from narrower stores (store-forwarding stalls).
    inline ShadingContext shading_context(bool two_sided) const;
    /// Origin offset along ng to the side of direction d, robust against self-intersection
    /// (Wachter & Binder, Ray Tracing Gems ch. 6: integer ULP offsets scaled by |p|).
    Vec3 offset_origin(Vec3 d) const;
    Ray spawn_ray(Vec3 d) const { return Ray(offset_origin(d), d); }
    /// Shadow ray towards point `target`, stopping just short of it.
    Ray spawn_ray_to(Vec3 target) const {
        const Vec3 o = offset_origin(target - p);
        const Vec3 d = target - o;
        const float dist = length(d);
        return Ray(o, dist > 0.f ? d / dist : d, dist * (1.f - 1e-4f));
    }
};

inline ShadingContext SurfaceInteraction::shading_context(bool two_sided) const {
    const bool flip = two_sided && dot(wo, ng) < 0.f;
    const Vec3 n = flip ? -ns : ns, g = flip ? -ng : ng;
    const float side = flip ? -1.f : 1.f;
    Vec3 n_macro, dpdu_macro, dpdv_macro;
    if (length_squared(n_footprint) > 0.f) {
        n_macro = n_footprint * side;
        dpdu_macro = length_squared(dpdu_footprint) > 0.f ? dpdu_footprint : dpdu;
        dpdv_macro = length_squared(dpdv_footprint) > 0.f ? dpdv_footprint : dpdv;
    }
    // Aggregate initialisation, every member in declaration order once (lod_level, lod_weight
    // and u_eval keep their defaults): a default-constructed context was first zeroed whole
    // (a rep stos per path vertex) and then written member by member.
    return ShadingContext{p,          uv,         Frame::from_normal_tangent(n, dpdu), g,    dpdu, dpdv, side,
                          n_macro,    dpdu_macro, dpdv_macro,                          micro_height,
                          dpdx,       dpdy,       dudx,                                dudy, dvdx, dvdy};
}

// Inline (every path vertex spawns two rays) and without branches: the sign of the offset is
// as good as random from one vertex to the next.
inline Vec3 SurfaceInteraction::offset_origin(Vec3 w) const {
    // Move p off the surface along the geometric normal by its error bound, to the side of
    // w, then round away from p so float rounding cannot pull it back (pbrt-v4 OffsetRayOrigin):
    // per component next_float_up(po) where the offset is positive, -next_float_up(-po) where it
    // is negative, bit for bit on finite values and infinities.
    const float d = p_error * (std::abs(ng.x) + std::abs(ng.y) + std::abs(ng.z));
    const Vec3 off = ng * (dot(w, ng) < 0.f ? -d : d);
    const __m128 offv = _mm_set_ps(0.f, off.z, off.y, off.x);
    const __m128i b = _mm_castps_si128(_mm_add_ps(_mm_set_ps(0.f, p.z, p.y, p.x), offv));
    const __m128i o = _mm_castps_si128(offv);
    const __m128i sign = _mm_set1_epi32(int32_t(0x80000000u)), abs_mask = _mm_set1_epi32(0x7fffffff);
    const __m128i mag = _mm_and_si128(b, abs_mask), dir = _mm_and_si128(o, sign);
    // One step away from zero where po has the offset's sign (none for an infinity), one
    // towards zero where it has the other; from +-0 the smallest denormal on the offset's side.
    const __m128i away = _mm_cmpeq_epi32(_mm_and_si128(b, sign), dir);
    const __m128i inf = _mm_cmpeq_epi32(mag, _mm_set1_epi32(0x7f800000));
    __m128i step = _mm_add_epi32(_mm_and_si128(away, _mm_set1_epi32(2)), _mm_set1_epi32(-1));
    step = _mm_andnot_si128(_mm_and_si128(away, inf), step);
    __m128i r = _mm_add_epi32(b, step);
    const __m128i zero = _mm_cmpeq_epi32(mag, _mm_setzero_si128());
    r = _mm_or_si128(_mm_andnot_si128(zero, r), _mm_and_si128(zero, _mm_or_si128(dir, _mm_set1_epi32(1))));
    const __m128i keep = _mm_cmpeq_epi32(_mm_and_si128(o, abs_mask), _mm_setzero_si128());  // no offset
    r = _mm_or_si128(_mm_andnot_si128(keep, r), _mm_and_si128(keep, b));
    alignas(16) float out[4];
    _mm_store_ps(out, _mm_castsi128_ps(r));
    return Vec3(out[0], out[1], out[2]);
}

}  // namespace meso
