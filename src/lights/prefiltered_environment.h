// A lat-long environment as a MIP pyramid with its nine-coefficient SH projection: what
// environment quadratures (Material::env_radiance, e.g. `leadr`, paper 000 Algorithms 1-3)
// integrate against.
//
// Prefiltered environment: a MIP pyramid (texture/mipmap.h, box filter) of the lat-long map
// (EnvMapLight's mapping, +y up; u wraps; v is clamped to the texel centres of each level so
// the poles do not blend across). LOD(alpha): a texel of level l around polar angle theta
// subtends 4^l (2 pi / W)(pi / H) sin(theta) sr; level = log4(alpha / that), clamped to the
// pyramid, trilinear between the two levels around it. sin(theta) is clamped to the first
// row's, so the poles pick finite levels.
#pragma once
#include <array>
#include <memory>
#include <vector>
#include "core/spectrum.h"
#include "core/transform.h"
#include "texture/mipmap.h"

namespace meso {

class Light;

/// A lat-long environment (EnvMapLight mapping) as a MIP pyramid, with its SH projection.
class PrefilteredEnvironment {
public:
    /// `texels`: w x h linear radiance in the environment's local frame, row-major, top row
    /// (+y) first; `to_world` a rotation.
    PrefilteredEnvironment(int w, int h, const std::vector<Spectrum> &texels, const Transform &to_world);
    /// From an infinite light: an EnvMapLight's own texels (and rotation); any other
    /// infinite light (e.g. `constant`) is sampled through Light::eval at the texel centres
    /// of a res x res/2 lat-long grid.
    static std::shared_ptr<PrefilteredEnvironment> from_light(const Light &light, int res = 64);

    /// Bilinear radiance at level 0 arriving from world direction d (= EnvMapLight::radiance).
    Spectrum radiance(const Vec3 &d_world) const;
    /// Prefiltered radiance for a lookup covering `solid_angle` sr around d (see above).
    Spectrum lookup(const Vec3 &d_world, double solid_angle) const;
    /// The continuous pyramid level lookup() uses.
    float level_for(const Vec3 &d_world, double solid_angle) const;
    int levels() const { return m_mip.levels(); }

    /// The nine SH coefficients of L (world frame) from every level-0 texel (Algorithm 2's
    /// L_lm(environment)); order: L00, L1-1, L10, L11, L2-2, L2-1, L20, L21, L22.
    const std::array<Spectrum, 9> &sh() const { return m_sh; }
    /// Coarse texels for per-point projection: world direction, solid angle, radiance.
    struct Texel {
        Vec3 d;
        float solid_angle;
        Spectrum L;
    };
    const std::vector<Texel> &coarse_texels() const { return m_coarse; }

    size_t memory_bytes() const;

private:
    Vec3 to_local(const Vec3 &d_world) const;
    float level_local(const Vec3 &d_local, double solid_angle) const;
    Spectrum bilinear(int level, float u, float v) const;

    MipMap m_mip;
    int m_w = 0, m_h = 0;
    Transform m_to_world;
    bool m_identity = true;
    std::array<Spectrum, 9> m_sh{};
    std::vector<Texel> m_coarse;
};

/// Adds direction d (unit) with weight P to nine SH coefficients (Algorithm 2).
void sh9_add(std::array<Spectrum, 9> &c, const Vec3 &d, const Spectrum &P);
/// Irradiance E(n) = int L(w) <n, w> dw from nine coefficients (Ramamoorthi & Hanrahan 2001,
/// as printed in paper 000 §5.3), in the coefficients' frame.
Spectrum sh9_irradiance(const std::array<Spectrum, 9> &c, const Vec3 &n);

}  // namespace meso
