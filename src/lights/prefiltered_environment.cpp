#include "lights/prefiltered_environment.h"
#include <algorithm>
#include <cmath>
#include "lights/envmap.h"
#include "lights/light.h"

namespace meso {

namespace {
constexpr double kPi = 3.14159265358979323846;
}

// ------------------------------------------------------------------ spherical harmonics

void sh9_add(std::array<Spectrum, 9> &c, const Vec3 &d, const Spectrum &P) {
    const float x = d.x, y = d.y, z = d.z;
    c[0] += P * 0.282095f;
    c[1] += P * (0.488603f * y);
    c[2] += P * (0.488603f * z);
    c[3] += P * (0.488603f * x);
    c[4] += P * (1.092548f * x * y);
    c[5] += P * (1.092548f * y * z);
    c[6] += P * (0.315392f * (3.f * z * z - 1.f));
    c[7] += P * (1.092548f * x * z);
    c[8] += P * (0.546274f * (x * x - y * y));
}

Spectrum sh9_irradiance(const std::array<Spectrum, 9> &c, const Vec3 &n) {
    const float x = n.x, y = n.y, z = n.z;
    return c[8] * (0.429043f * (x * x - y * y)) + c[6] * (0.743125f * z * z) + c[0] * 0.886227f -
           c[6] * 0.247708f + (c[4] * (x * y) + c[7] * (x * z) + c[5] * (y * z)) * 0.858086f +
           (c[3] * x + c[1] * y + c[2] * z) * 1.023328f;
}

// ------------------------------------------------------------------ prefiltered environment

PrefilteredEnvironment::PrefilteredEnvironment(int w, int h, const std::vector<Spectrum> &texels,
                                               const Transform &to_world)
    : m_w(w), m_h(h), m_to_world(to_world), m_identity(to_world.is_identity()) {
    std::vector<float> data(size_t(w) * h * 3);
    for (size_t i = 0; i < size_t(w) * h; ++i)
        for (int c = 0; c < 3; ++c) data[i * 3 + c] = texels[i][c];
    m_mip = MipMap(w, h, 3, std::move(data), WrapMode::Repeat);

    // Algorithm 2's L_lm(environment): every level-0 texel, world frame.
    auto world_dir = [&](float u, float v) {
        Vec3 d = EnvMapLight::uv_to_direction(Vec2(u, v));
        return m_identity ? d : normalize(m_to_world.apply_vector(d));
    };
    for (int y = 0; y < h; ++y) {
        const double sa = (2 * kPi / w) * (std::cos(kPi * y / h) - std::cos(kPi * (y + 1) / h));
        for (int x = 0; x < w; ++x)
            sh9_add(m_sh, world_dir((x + 0.5f) / w, (y + 0.5f) / h), texels[size_t(y) * w + x] * float(sa));
    }
    // The coarse level for per-point projection: the first with at most 16 rows.
    int lc = 0;
    while (lc + 1 < m_mip.levels() && m_mip.height(lc) > 16) ++lc;
    const int cw = m_mip.width(lc), ch = m_mip.height(lc);
    m_coarse.reserve(size_t(cw) * ch);
    for (int y = 0; y < ch; ++y) {
        const double sa = (2 * kPi / cw) * (std::cos(kPi * y / ch) - std::cos(kPi * (y + 1) / ch));
        for (int x = 0; x < cw; ++x) {
            const float *t = m_mip.texel(lc, x, y);
            m_coarse.push_back({world_dir((x + 0.5f) / cw, (y + 0.5f) / ch), float(sa), Spectrum(t[0], t[1], t[2])});
        }
    }
}

std::shared_ptr<PrefilteredEnvironment> PrefilteredEnvironment::from_light(const Light &light, int res) {
    if (auto *env = dynamic_cast<const EnvMapLight *>(&light))
        return std::make_shared<PrefilteredEnvironment>(env->width(), env->height(), env->texels(), env->to_world());
    res = std::max(res, 2);
    const int w = res, h = std::max(1, res / 2);
    std::vector<Spectrum> texels(size_t(w) * h);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            Vec3 d = EnvMapLight::uv_to_direction(Vec2((x + 0.5f) / w, (y + 0.5f) / h));
            texels[size_t(y) * w + x] = light.eval(LightHit{}, -d);  // radiance arriving from d
        }
    return std::make_shared<PrefilteredEnvironment>(w, h, texels, Transform());
}

Vec3 PrefilteredEnvironment::to_local(const Vec3 &d) const {
    return normalize(m_identity ? d : m_to_world.apply_inverse_vector(d));
}

Spectrum PrefilteredEnvironment::bilinear(int level, float u, float v) const {
    const float hl = float(m_mip.height(level));
    v = std::clamp(v, 0.5f / hl, 1.f - 0.5f / hl);  // no blending across the poles
    float out[3];
    m_mip.bilinear(level, u, v, out);
    return Spectrum(out[0], out[1], out[2]);
}

Spectrum PrefilteredEnvironment::radiance(const Vec3 &d_world) const {
    Vec2 uv = EnvMapLight::direction_to_uv(to_local(d_world));
    return bilinear(0, uv.x, uv.y);
}

float PrefilteredEnvironment::level_for(const Vec3 &d_world, double solid_angle) const {
    return level_local(to_local(d_world), solid_angle);
}

float PrefilteredEnvironment::level_local(const Vec3 &d, double solid_angle) const {
    const double sin_theta = std::max(std::sqrt(std::max(0.0, 1.0 - double(d.y) * d.y)), std::sin(kPi / (2 * m_h)));
    const double texel = (2 * kPi / m_w) * (kPi / m_h) * sin_theta;
    if (!(solid_angle > texel)) return 0.f;
    const double level = 0.5 * std::log2(solid_angle / texel);
    return float(std::min(level, double(m_mip.levels() - 1)));
}

Spectrum PrefilteredEnvironment::lookup(const Vec3 &d_world, double solid_angle) const {
    const Vec3 d = to_local(d_world);
    const Vec2 uv = EnvMapLight::direction_to_uv(d);
    const float level = level_local(d, solid_angle);
    const int l0 = int(level);
    const float t = level - float(l0);
    if (l0 + 1 >= m_mip.levels() || t <= 0.f) return bilinear(l0, uv.x, uv.y);
    return bilinear(l0, uv.x, uv.y) * (1.f - t) + bilinear(l0 + 1, uv.x, uv.y) * t;
}

size_t PrefilteredEnvironment::memory_bytes() const {
    return m_mip.memory_bytes() + m_coarse.size() * sizeof(Texel);
}

}  // namespace meso
