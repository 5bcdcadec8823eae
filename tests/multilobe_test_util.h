// Helpers shared by tests/test_multilobe_brdf.cpp and tests/test_lobe_brdf.cpp: test patch NDFs,
// an independent dense quadrature of paper 004's eq. 5 (the reference both forms of f'_low are
// compared with), a hemisphere albedo and a set of direction pairs.
#pragma once
#include <cmath>
#include <utility>
#include <vector>
#include "bsdf/material.h"
#include "core/frame.h"
#include "filter/vmf.h"
#include "material_test_util.h"
#include "prefilter/patch_ndf.h"

namespace meso::test::ml {

using namespace meso;
using namespace meso::prefilter;
using meso::test::dir_deg;

inline constexpr double kPi = 3.14159265358979323846;
inline const ShadingContext kCtx{};

inline Vec3 unit(double x, double y, double z) {
    const double l = std::sqrt(x * x + y * y + z * z);
    return Vec3(float(x / l), float(y / l), float(z / l));
}

/// A PatchNdf from lobes (weights normalised to 1), amplitude from eq. 3 as fit_patch_ndf does.
inline PatchNdf make_ndf(std::vector<VmfLobe> lobes) {
    double sum = 0.0;
    for (const VmfLobe &l : lobes) sum += l.weight;
    for (VmfLobe &l : lobes) l.weight /= sum;
    PatchNdf n;
    n.lobes = lobes;
    const double p = mixture_projected_area(lobes);
    n.amplitude = p > 0.0 ? 1.0 / p : 0.0;
    return n;
}

inline PatchNdf two_lobes() {
    return make_ndf({{unit(0.3, 0.0, 1.0), 20.0, 0.6}, {unit(-0.4, 0.2, 1.0), 1e4, 0.4}});
}
inline PatchNdf six_lobes() {
    return make_ndf({{unit(0.0, 0.0, 1.0), 5.0, 0.25},
                     {unit(0.5, 0.1, 1.0), 30.0, 0.2},
                     {unit(-0.3, 0.6, 1.0), 100.0, 0.2},
                     {unit(0.2, -0.8, 1.0), 500.0, 0.15},
                     {unit(-1.0, -0.2, 0.6), 2000.0, 0.1},
                     {unit(0.9, 0.9, 0.5), 1e4, 0.1}});
}

inline const char *kDiffuse = R"({"type":"diffuse","reflectance":0.8})";
inline const char *kConductor = R"({"type":"conductor","material":"Cu","alpha":0.3})";

/// Independent dense quadrature of eq. 5 (times cos θi): for every lobe, in its frame, composite
/// 4-point Gauss–Legendre in ψ (the angle from μ) over [0, ψ_max] (all but e^-40 of the mass),
/// midpoint in φ; the integrand amplitude a_j γ(ψ) sin ψ [ω.z > 0] base.eval(F_ω ωo, F_ω ωi).
/// No use of the CDF variable, of the node set or of vmf::sample_cos.
inline double brute_eq5(const Material &base, const PatchNdf &ndf, Vec3 wo, Vec3 wi, int n_psi = 400, int n_phi = 512) {
    static const double gx[4] = {-0.8611363115940526, -0.3399810435848563, 0.3399810435848563, 0.8611363115940526};
    static const double gw[4] = {0.3478548451374538, 0.6521451548625461, 0.6521451548625461, 0.3478548451374538};
    if (!(wo.z > 0.f) || !(wi.z > 0.f)) return 0.0;
    double total = 0.0;
    for (const VmfLobe &l : ndf.lobes) {
        const Vec3 mu = unit(l.mu.x, l.mu.y, l.mu.z);
        Vec3 s, t;
        coordinate_system(mu, s, t);
        const double psi_max = l.kappa > 20.0 ? std::acos(std::max(-1.0, 1.0 - 40.0 / l.kappa)) : kPi;
        const double h = psi_max / n_psi;
        double lobe = 0.0;
        for (int i = 0; i < n_psi; ++i)
            for (int g = 0; g < 4; ++g) {
                const double psi = h * (i + 0.5 + 0.5 * gx[g]);
                const double dens = vmf::pdf_cos(l.kappa, std::cos(psi)) * std::sin(psi) * 0.5 * h * gw[g];
                double ring = 0.0;
                for (int b = 0; b < n_phi; ++b) {
                    const double phi = 2.0 * kPi * (b + 0.5) / n_phi;
                    const double cx = std::sin(psi) * std::cos(phi), cy = std::sin(psi) * std::sin(phi),
                                 cz = std::cos(psi);
                    const Vec3 w = unit(cx * s.x + cy * t.x + cz * mu.x, cx * s.y + cy * t.y + cz * mu.y,
                                        cx * s.z + cy * t.z + cz * mu.z);
                    if (!(w.z > 0.f)) continue;
                    const Frame f(w);
                    const Vec3 lo = f.to_local(wo), li = f.to_local(wi);
                    if (!(lo.z > 0.f) || !(li.z > 0.f)) continue;
                    ring += double(base.eval(kCtx, lo, li).g);
                }
                lobe += dens * ring * (2.0 * kPi / n_phi);
            }
        total += ndf.amplitude * l.weight * lobe;
    }
    return total;
}

/// ∫_{H²} eval(wo, ωi) dωi by a midpoint rule in (cos θ, φ) (green channel).
inline double hemisphere_albedo(const Material &m, Vec3 wo, int n_mu = 128, int n_phi = 256) {
    double sum = 0.0;
    for (int a = 0; a < n_mu; ++a) {
        const double z = (a + 0.5) / n_mu, r = std::sqrt(std::max(0.0, 1.0 - z * z));
        for (int b = 0; b < n_phi; ++b) {
            const double phi = 2.0 * kPi * (b + 0.5) / n_phi;
            sum += double(m.eval(kCtx, wo, Vec3(float(r * std::cos(phi)), float(r * std::sin(phi)), float(z))).g);
        }
    }
    return sum * (1.0 / n_mu) * (2.0 * kPi / n_phi);
}

inline std::vector<std::pair<Vec3, Vec3>> direction_pairs() {
    std::vector<std::pair<Vec3, Vec3>> v;
    for (double to : {0.0, 35.0, 70.0})
        for (double ti : {10.0, 45.0, 80.0})
            for (double dphi : {0.0, 120.0, 200.0}) v.push_back({dir_deg(to, 20.0), dir_deg(ti, 20.0 + dphi)});
    return v;
}

}  // namespace meso::test::ml
