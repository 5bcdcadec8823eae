#include "bsdf/fresnel.h"
#include <smmintrin.h>
#include <cmath>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/properties.h"

namespace meso {

FresnelDielectric fresnel_dielectric(float cos_theta_i, float eta) {
    FresnelDielectric r;
    bool outside = cos_theta_i >= 0.f;
    r.eta_it = outside ? eta : 1.f / eta;
    r.eta_ti = outside ? 1.f / eta : eta;
    // Snell: sin_t = eta_ti sin_i. Evaluated in double: near the critical angle
    // cos_t^2 is a difference of nearly equal numbers.
    double ci = std::min(1.0, std::abs(double(cos_theta_i)));
    double eti = r.eta_ti, eit = r.eta_it;
    double cos_t2 = 1.0 - eti * eti * (1.0 - ci * ci);
    double ct = cos_t2 > 0.0 ? std::sqrt(cos_t2) : 0.0;
    double F;
    if (eta == 1.f) F = 0.0;            // index matched: no interface
    else if (ci == 0.0 || cos_t2 <= 0.0) F = 1.0;  // grazing or total internal reflection
    else {
        double a_s = (ci - eit * ct) / (ci + eit * ct);
        double a_p = (ct - eit * ci) / (ct + eit * ci);
        F = 0.5 * (a_s * a_s + a_p * a_p);
    }
    r.F = float(clamp(F, 0.0, 1.0));
    r.cos_theta_t = float(outside ? -ct : ct);
    return r;
}

double fresnel_conductor(double cos_theta_i, double eta, double k) {
    // pbrt-v3 FrConductor (exact complex Fresnel, dielectric exterior of index 1).
    double c = std::min(1.0, std::abs(cos_theta_i));
    double cos2 = c * c, sin2 = 1.0 - cos2;
    double eta2 = eta * eta, k2 = k * k;
    double t0 = eta2 - k2 - sin2;
    double a2plusb2 = std::sqrt(std::max(0.0, t0 * t0 + 4.0 * eta2 * k2));
    double t1 = a2plusb2 + cos2;
    double a = std::sqrt(std::max(0.0, 0.5 * (a2plusb2 + t0)));
    double t2 = 2.0 * c * a;
    if (!(t1 + t2 > 0.0)) return 1.0;  // eta = k = 0 at grazing: degenerate, perfect mirror
    double Rs = (t1 - t2) / (t1 + t2);
    double t3 = cos2 * a2plusb2 + sin2 * sin2;
    double t4 = t2 * sin2;
    double Rp = (t3 + t4) > 0.0 ? Rs * (t3 - t4) / (t3 + t4) : Rs;
    return clamp(0.5 * (Rs + Rp), 0.0, 1.0);
}

Spectrum fresnel_conductor(float cos_theta_i, const Spectrum &eta, const Spectrum &k) {
    // The scalar formula above for the three channels at once, in single precision (SSE4.1,
    // within x86-64-v2): a path vertex on a metal evaluates it two or three times, and three
    // double evaluations with their six square roots and nine divisions were a fifth of a
    // rough conductor's cost. a^2 = (|n^2 - sin^2| + Re(n^2 - sin^2)) / 2 cancels for metals
    // (Re < 0, |Re| ~ |n^2|), so it is formed as 2 eta^2 k^2 / (|.| - Re) there; the result
    // then agrees with the complex formula to a few float ulps (test
    // MaterialAnalytic.ConductorFresnelSpectrumIsAccurate).
    const float c = std::min(1.f, std::abs(cos_theta_i));
    const __m128 zero = _mm_setzero_ps(), half = _mm_set1_ps(0.5f), one = _mm_set1_ps(1.f);
    const __m128 cos2 = _mm_set1_ps(c * c), sin2 = _mm_set1_ps(std::max(0.f, 1.f - c * c));
    const __m128 e = _mm_setr_ps(eta.r, eta.g, eta.b, 0.f), kk = _mm_setr_ps(k.r, k.g, k.b, 0.f);
    const __m128 eta2 = _mm_mul_ps(e, e), k2 = _mm_mul_ps(kk, kk);
    // eta^2 - k^2 - sin^2 as (eta^2 - k^2 - 1) + cos^2: exact for eta = 1, k = 0 at grazing.
    const __m128 t0 = _mm_add_ps(_mm_sub_ps(_mm_sub_ps(eta2, k2), one), cos2);
    const __m128 four_e2k2 = _mm_mul_ps(_mm_set1_ps(4.f), _mm_mul_ps(eta2, k2));
    const __m128 a2b2 = _mm_sqrt_ps(_mm_max_ps(zero, _mm_add_ps(_mm_mul_ps(t0, t0), four_e2k2)));
    const __m128 a2_direct = _mm_mul_ps(half, _mm_add_ps(a2b2, t0));
    const __m128 den_a = _mm_sub_ps(a2b2, t0);
    const __m128 a2_stable = _mm_and_ps(_mm_cmpgt_ps(den_a, zero), _mm_div_ps(_mm_mul_ps(half, four_e2k2), den_a));
    const __m128 a = _mm_sqrt_ps(_mm_max_ps(zero, _mm_blendv_ps(a2_stable, a2_direct, _mm_cmpge_ps(t0, zero))));
    const __m128 t1 = _mm_add_ps(a2b2, cos2), t2 = _mm_mul_ps(_mm_set1_ps(2.f * c), a);
    const __m128 den_s = _mm_add_ps(t1, t2);
    const __m128 ok_s = _mm_cmpgt_ps(den_s, zero);  // eta = k = 0 at grazing: degenerate, perfect mirror
    const __m128 Rs = _mm_div_ps(_mm_sub_ps(t1, t2), _mm_blendv_ps(one, den_s, ok_s));
    const __m128 t3 = _mm_add_ps(_mm_mul_ps(cos2, a2b2), _mm_mul_ps(sin2, sin2)), t4 = _mm_mul_ps(t2, sin2);
    const __m128 den_p = _mm_add_ps(t3, t4), ok_p = _mm_cmpgt_ps(den_p, zero);
    const __m128 Rp = _mm_blendv_ps(Rs, _mm_div_ps(_mm_mul_ps(Rs, _mm_sub_ps(t3, t4)), _mm_blendv_ps(one, den_p, ok_p)), ok_p);
    __m128 R = _mm_min_ps(one, _mm_max_ps(zero, _mm_mul_ps(half, _mm_add_ps(Rs, Rp))));
    R = _mm_blendv_ps(one, R, ok_s);
    alignas(16) float out[4];
    _mm_store_ps(out, R);
    return {out[0], out[1], out[2]};
}

/// Double-precision reflectance for the numerical integral below.
static double fresnel_dielectric_d(double ci, double eta) {
    double sin_t2 = (1.0 - ci * ci) / (eta * eta);
    if (sin_t2 >= 1.0) return 1.0;
    double ct = std::sqrt(1.0 - sin_t2);
    double a_s = (ci - eta * ct) / (ci + eta * ct);
    double a_p = (ct - eta * ci) / (ct + eta * ci);
    return 0.5 * (a_s * a_s + a_p * a_p);
}

double fresnel_diffuse_reflectance(double eta) {
    if (eta == 1.0) return 0.0;
    // 2 ∫ F(mu) mu dmu. Below the critical cosine (eta < 1) F = 1 exactly: that part is
    // mu_c^2. Above it F is smooth except for a square-root edge at mu_c, so integrate in
    // t = sqrt(mu - mu_c) (mu = mu_c + t^2, dmu = 2 t dt), which removes it.
    double mu_c = eta < 1.0 ? std::sqrt(std::max(0.0, 1.0 - eta * eta)) : 0.0;
    double result = mu_c * mu_c;
    const int n = 4096;  // even
    double tmax = std::sqrt(1.0 - mu_c), h = tmax / n, sum = 0.0;
    for (int i = 0; i <= n; ++i) {
        double t = i * h, mu = mu_c + t * t;
        double f = fresnel_dielectric_d(std::min(mu, 1.0), eta) * mu * 2.0 * t;
        sum += f * (i == 0 || i == n ? 1.0 : (i % 2 ? 4.0 : 2.0));
    }
    result += 2.0 * sum * h / 3.0;
    return result;
}

namespace {
struct ConductorPreset {
    const char *name;
    Spectrum eta, k;
};
// Tungsten ComplexIorData.hpp (spectral n, k data integrated to linear sRGB).
const ConductorPreset kConductors[] = {
    {"Ag", {0.1552646489f, 0.1167232965f, 0.1383806959f}, {4.8283433224f, 3.1222459278f, 2.1469504455f}},
    {"Al", {1.6574599595f, 0.8803689579f, 0.5212287346f}, {9.2238691996f, 6.2695232477f, 4.8370012281f}},
    {"Au", {0.1431189557f, 0.3749570432f, 1.4424785571f}, {3.9831604247f, 2.3857207478f, 1.6032152899f}},
    {"Cr", {4.3696828663f, 2.9167024892f, 1.6547005413f}, {5.2064337956f, 4.2313645277f, 3.7549467933f}},
    {"Cu", {0.2004376970f, 0.9240334304f, 1.1022119527f}, {3.9129485033f, 2.4528477015f, 2.1421879552f}},
    {"Ni", {2.3672753521f, 1.6633583302f, 1.4670554172f}, {4.4988329911f, 3.0501643957f, 2.3454274399f}},
    {"W", {4.3707029924f, 3.3002972445f, 2.9982666528f}, {3.5006778591f, 2.6048652781f, 2.2731930614f}},
};

struct IorPreset {
    const char *name;
    float ior;
};
// Mitsuba 3 (src/render/ior.h): refractive indices at 589 nm.
const IorPreset kIors[] = {
    {"vacuum", 1.0f},          {"helium", 1.000036f},     {"hydrogen", 1.000132f},
    {"air", 1.000277f},        {"carbon dioxide", 1.00045f}, {"water", 1.3330f},
    {"acetone", 1.36f},        {"ethanol", 1.361f},       {"carbon tetrachloride", 1.461f},
    {"glycerol", 1.4729f},     {"benzene", 1.501f},       {"silicone oil", 1.52045f},
    {"bromine", 1.661f},       {"water ice", 1.31f},      {"fused quartz", 1.458f},
    {"pyrex", 1.470f},         {"acrylic glass", 1.49f},  {"polypropylene", 1.49f},
    {"bk7", 1.5046f},          {"sodium chloride", 1.544f}, {"amber", 1.55f},
    {"pet", 1.5750f},          {"diamond", 2.419f},
};
}  // namespace

bool conductor_preset(const std::string &name, Spectrum &eta, Spectrum &k) {
    for (const auto &p : kConductors)
        if (name == p.name) {
            eta = p.eta;
            k = p.k;
            return true;
        }
    return false;
}
std::string conductor_preset_list() {
    std::string known;
    for (auto &n : conductor_preset_names()) known += (known.empty() ? "" : ", ") + n;
    return known;
}

std::vector<std::string> conductor_preset_names() {
    std::vector<std::string> v;
    for (const auto &p : kConductors) v.push_back(p.name);
    v.push_back("none");
    return v;
}

bool dielectric_ior_preset(const std::string &name, float &ior) {
    for (const auto &p : kIors)
        if (name == p.name) {
            ior = p.ior;
            return true;
        }
    return false;
}
std::vector<std::string> dielectric_ior_preset_names() {
    std::vector<std::string> v;
    for (const auto &p : kIors) v.push_back(p.name);
    return v;
}

float ior_from_properties(const Properties &p, const std::string &key, float def) {
    if (!p.has(key)) return def;
    if (p.raw(key).is_string()) {
        std::string name = p.get_string(key);
        float ior;
        if (!dielectric_ior_preset(name, ior)) {
            std::string known;
            for (auto &n : dielectric_ior_preset_names()) known += (known.empty() ? "" : ", ") + n;
            p.fail(key, fmt::format("unknown index of refraction '{}' (known: {})", name, known));
        }
        return ior;
    }
    float v = p.get_float(key);
    if (!(v > 0.f)) p.fail(key, fmt::format("index of refraction must be > 0, got {}", v));
    return v;
}

}  // namespace meso
