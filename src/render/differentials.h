// Ray differentials after scattering (Igehy 1999, "Tracing Ray Differentials"; pbrt-v4
// SurfaceInteraction::SpawnRay and CameraBase::Approximate_dp_dxy).
//
// Footprints live for the whole path:
//  * camera rays carry one-pixel differentials scaled by the per-sample factor
//    max(1/8, 1/sqrt(spp)) (RayDifferential::footprint_scale);
//  * at every hit SurfaceInteraction::compute_differentials transfers them to the tangent
//    plane (dp/dx, dp/dy) and solves for du/dx .. dv/dy;
//  * perfect specular reflection and refraction transport them exactly, including the
//    curvature of the shading normal (dn/dx = dn/du du/dx + dn/dv dv/dx):
//      reflection  wi = -wo + 2 (wo.n) n
//                  dwi = -dwo + 2 [ (wo.n) dn + d(wo.n) n ],   d(wo.n) = dwo.n + wo.dn
//      refraction  wi = -wo/eta + mu n,  mu = (wo.n)/eta - cos_t,  cos_t = -wi.n > 0,
//                  eta = eta_wi / eta_wo, n on the side of wo
//                  dwi = -dwo/eta + mu dn + dmu n,  dmu = d(wo.n) [1/eta - (wo.n)/(eta^2 cos_t)]
//    with dwo = -(d of the offset ray) - wo and the offset origins p + dp/dx, p + dp/dy;
//  * after rough or diffuse scattering the continuation ray carries no differentials, and
//    the next hit uses the camera-based approximation (Camera::approximate_dp_dxy): the
//    footprint a camera ray would have at that point, i.e. the camera's smallest pixel
//    spread at the point's distance from the camera, projected onto its tangent plane and
//    scaled by the same spp factor. This is pbrt-v4's choice: it ignores the widening by
//    the lobe's angular spread (which would make footprints after diffuse bounces cover
//    most of the scene and blur every texture), and keeps texture filtering / LoD at a
//    resolution that matches what the camera can resolve there.
#pragma once
#include "core/ray.h"

namespace meso {

struct SurfaceInteraction;

/// Sets `out`'s differentials for the continuation of `in` at `si` along the delta lobe
/// `flags` (BSDF_DeltaReflection or BSDF_DeltaTransmission) with direction wi (world) and
/// relative IOR eta (BSDFSample::eta). `n` is the shading normal used for sampling (either
/// orientation). Returns false (and clears out.has_differentials) when `in` has none, the
/// lobe is not delta, or the result would not be finite. Always copies footprint_scale.
bool specular_differentials(const RayDifferential &in, const SurfaceInteraction &si, Vec3 n, Vec3 wi,
                            uint32_t flags, float eta, RayDifferential &out);

/// Rotation taking unit vector a onto unit vector b (Rodrigues; half-turn when a = -b),
/// applied to v.
Vec3 rotate_from_to(Vec3 a, Vec3 b, Vec3 v);

}  // namespace meso
