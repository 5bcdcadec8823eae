// Fresnel equations for smooth interfaces (unpolarised light): dielectric-dielectric and
// dielectric-conductor, plus the RGB complex indices of refraction of common metals and
// the hemispherical (diffuse) Fresnel reflectance used by coated materials.
//
// Conventions (Mitsuba 3's `fresnel`): `eta` is the relative IOR interior/exterior of the
// interface; cos_theta_i is measured against the normal pointing to the exterior, so a
// negative value means the ray arrives from the interior side.
#pragma once
#include <string>
#include <vector>
#include "core/spectrum.h"
#include "core/vec.h"

namespace meso {

class Properties;

struct FresnelDielectric {
    float F = 1.f;            ///< unpolarised reflectance (1 on total internal reflection)
    float cos_theta_t = 0.f;  ///< cosine of the refracted direction, sign opposite to cos_theta_i
    float eta_it = 1.f;       ///< relative IOR eta_t/eta_i for this side (= eta outside, 1/eta inside)
    float eta_ti = 1.f;       ///< 1 / eta_it
};

/// Exact Fresnel reflectance of a smooth dielectric interface (Born & Wolf; Mitsuba 3
/// `fresnel`). Index-matched (eta = 1) gives 0; grazing (cos = 0) gives 1.
FresnelDielectric fresnel_dielectric(float cos_theta_i, float eta);
/// Just the reflectance.
inline float fresnel_dielectric_F(float cos_theta_i, float eta) { return fresnel_dielectric(cos_theta_i, eta).F; }

/// Exact unpolarised Fresnel reflectance of a conductor with complex relative IOR
/// eta + i k (per channel), cos_theta_i >= 0 (negative values are mirrored). Formula of
/// pbrt-v3 `FrConductor` (exact for a dielectric exterior), evaluated in double precision.
Spectrum fresnel_conductor(float cos_theta_i, const Spectrum &eta, const Spectrum &k);
double fresnel_conductor(double cos_theta_i, double eta, double k);

/// Mirror direction of w about the local normal (0,0,1).
inline Vec3 reflect_local(const Vec3 &w) { return {-w.x, -w.y, w.z}; }
/// Refraction of w through the local normal given cos_theta_t and eta_ti from fresnel_dielectric.
inline Vec3 refract_local(const Vec3 &w, float cos_theta_t, float eta_ti) {
    return {-eta_ti * w.x, -eta_ti * w.y, cos_theta_t};
}
/// Refraction of w through the microfacet normal m (both away from the surface; m on
/// the side of w or not — the formula only uses dot(w, m) and the Fresnel outputs that
/// were computed for cos_theta_i = dot(w, m)).
inline Vec3 refract(const Vec3 &w, const Vec3 &m, float cos_theta_t, float eta_ti) {
    return m * (dot(w, m) * eta_ti + cos_theta_t) - w * eta_ti;
}

/// Hemispherical-cosine average of the dielectric Fresnel reflectance seen from the side
/// whose relative IOR (transmitted/incident) is `eta`:  2 ∫_0^1 F(mu, eta) mu dmu,
/// integrated numerically (composite Simpson in mu, with a split at the critical angle;
/// error < 1e-6). eta < 1 includes total internal reflection.
double fresnel_diffuse_reflectance(double eta);

/// RGB complex IOR of a named conductor. Values: Tungsten's ComplexIorData.hpp (the
/// spectral tables of Mitsuba / PBRT integrated against the linear-sRGB colour matching
/// functions; Benedikt Bitterli, 2014-2017). Returns false for an unknown name.
bool conductor_preset(const std::string &name, Spectrum &eta, Spectrum &k);
/// Names accepted by conductor_preset (for error messages).
std::vector<std::string> conductor_preset_names();
/// The names above joined by ", " (for error messages).
std::string conductor_preset_list();

/// Named indices of refraction of dielectrics (Mitsuba 3's table: "vacuum", "air",
/// "water", "bk7", "acrylic glass", "diamond", ...). Returns false if unknown.
bool dielectric_ior_preset(const std::string &name, float &ior);
std::vector<std::string> dielectric_ior_preset_names();

/// Reads an index of refraction parameter: a positive number or a preset name
/// (dielectric_ior_preset). Located errors otherwise.
float ior_from_properties(const Properties &props, const std::string &key, float def);

}  // namespace meso
