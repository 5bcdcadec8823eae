// `envmap` light: an importance-sampled latitude-longitude environment map (infinite light).
//
// Mapping (Mitsuba 3 `envmap`; +y is up). A local direction d maps to
//     u = atan2(d.x, -d.z) / (2 pi)  wrapped to [0, 1)   across the width  (left -> right),
//     v = acos(d.y) / pi                                  down the height   (top row = +y),
// i.e. d(u, v) = (sin(phi) sin(theta), cos(theta), -cos(phi) sin(theta)), phi = 2 pi u,
// theta = pi v. So the image centre (u = 0.5) is +z at the horizon, u = 0.25 is +x,
// u = 0.75 is -x and the left/right edges are -z. World directions are mapped to local
// ones by the inverse of `to_world` (a rotation).
//
// Radiance: bilinear interpolation between texel centres (u wraps around, v clamps at
// the poles), times `scale`.
//
// Sampling (pbrt-v4 ImageInfiniteLight, Mitsuba 3 `envmap`): a piecewise-constant
// Distribution2D over the W x H texel cells of [0,1)^2 with weights
//     w_ij = luminance( cell average of the bilinear radiance ) · ∫_row sin(theta) dtheta,
// where the cell average of the bilinear interpolant is the separable (1/8, 3/4, 1/8)
// blur of the texels; it is > 0 wherever the interpolated radiance is > 0, so light
// sampling alone is unbiased. The solid-angle density is
//     pdf(w) = pdf_uv(u, v) / (2 pi^2 sin(theta)),   0 when sin(theta) = 0.
// sample() reports exactly pdf(wi) for the direction it returns (the same code computes
// both). Note: eval is bilinear but sampling piecewise constant per cell, so pdf is not
// exactly proportional to L; that only costs variance.
//
// Power: pi r^2 ∫ L dω (flux through a disk of the scene's bounding radius r, summed
// over all directions; the integral uses the blurred cell averages, RGB-averaged).
// Sampling tables in float with a guide per 8 cells (sampling/distribution.h: about 8 bytes
// per texel, an expected O(1) lookup within a cache line or two; the pdf of a direction is
// one read of two adjacent CDF entries per dimension). Direction <-> uv in float without libm
// calls (float_trig.h). With LightSampleContext::defer_radiance (the path integrator's NEE),
// sample() only prefetches the four texels and sampled_radiance() reads them after the shadow
// ray, so their misses overlap it.
// Memory: the RGB float texels plus the distribution tables, reported by to_string()
// (shown by `meso render --plan`).
//
// Parameters (Mitsuba 3 names):
//   filename   string     required      lat-long image (EXR/HDR/..., read as linear)
//   scale      float      default 1     radiance multiplier, >= 0
//   to_world   transform  default none  rotation only, e.g. {"rotate": {"axis": [0,1,0], "angle": 90}}
#include "lights/envmap.h"
#include <fmt/format.h>
#include <xmmintrin.h>
#include "core/error.h"
#include "core/properties.h"
#include "core/registry.h"
#include "core/transform_parse.h"
#include "core/float_trig.h"

namespace meso {

static Spectrum pixel_rgb(const Image &img, int x, int y) {
    switch (img.channels) {
        case 1:
        case 2: return Spectrum(img.at(x, y, 0));
        default: return {img.at(x, y, 0), img.at(x, y, 1), img.at(x, y, 2)};
    }
}

EnvMapLight::EnvMapLight(const Image &img, float scale, const Transform &to_world, std::string name)
    : m_w(img.width), m_h(img.height), m_to_world(to_world), m_identity(to_world.is_identity()), m_scale(scale),
      m_name(std::move(name)) {
    if (m_w <= 0 || m_h <= 0 || img.channels <= 0 || img.data.size() != size_t(m_w) * m_h * img.channels)
        throw MesoError("environment map is empty or malformed");
    if (!(scale >= 0.f) || !std::isfinite(scale)) throw MesoError("scale must be finite and non-negative");
    // to_world must be orthonormal, or the solid-angle pdf would need a Jacobian.
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
            float d = 0.f;
            for (int k = 0; k < 3; ++k) d += to_world.m[k][i] * to_world.m[k][j];
            if (std::abs(d - (i == j ? 1.f : 0.f)) > 1e-3f)
                throw MesoError("to_world of an environment map must be a rotation (no scale or shear)");
        }
    m_texels.resize(size_t(m_w) * m_h);
    long bad = 0;
    for (int y = 0; y < m_h; ++y)
        for (int x = 0; x < m_w; ++x) {
            Spectrum s = pixel_rgb(img, x, y);
            if (!s.is_finite() || s.r < 0.f || s.g < 0.f || s.b < 0.f) ++bad;
            m_texels[size_t(y) * m_w + x] = s * scale;
        }
    if (bad > 0)
        throw MesoError(fmt::format("environment map has {} pixel(s) with negative, NaN or infinite values", bad));

    // Cell averages of the bilinear interpolant: separable (1/8, 3/4, 1/8) blur, u wraps,
    // v clamps (the same boundary rules as the lookup).
    const float wts[3] = {0.125f, 0.75f, 0.125f};
    std::vector<Spectrum> horiz(m_texels.size());
    for (int y = 0; y < m_h; ++y)
        for (int x = 0; x < m_w; ++x) {
            Spectrum s;
            for (int k = -1; k <= 1; ++k) s += texel(((x + k) % m_w + m_w) % m_w, y) * wts[k + 1];
            horiz[size_t(y) * m_w + x] = s;
        }
    std::vector<float> func(m_texels.size());
    double integral = 0;
    for (int y = 0; y < m_h; ++y) {
        // ∫ sin(theta) dtheta over the row = cos(theta0) - cos(theta1).
        double row = std::cos(M_PI * y / m_h) - std::cos(M_PI * (y + 1) / m_h);
        for (int x = 0; x < m_w; ++x) {
            Spectrum s;
            for (int k = -1; k <= 1; ++k) s += horiz[size_t(clamp(y + k, 0, m_h - 1)) * m_w + x] * wts[k + 1];
            func[size_t(y) * m_w + x] = float(s.luminance() * row);
            integral += double(s.average()) * row * (2.0 * M_PI / m_w);
        }
    }
    m_integral = integral;
    m_distr = Distribution2D(func, m_w, m_h);
}

Spectrum EnvMapLight::texel(int x, int y) const { return m_texels[size_t(y) * m_w + x]; }

// The two maps in float without libm calls (core/float_trig.h: within 4e-7 rad, i.e. 6e-8 in
// u and 1.3e-7 in v); theta as atan2(sin, cos), which, unlike acos(d.y), keeps its accuracy
// at the poles.
Vec2 EnvMapLight::direction_to_uv(Vec3 d) {
    float u = atan2_approx(d.x, -d.z) * Inv2Pi;
    if (u < 0.f) u += 1.f;
    if (!(u < 1.f)) u = 0.f;  // u = 1 (rounding) is the same meridian as 0
    float v = clamp(atan2_approx(std::sqrt(d.x * d.x + d.z * d.z), d.y) * InvPi, 0.f, 1.f);
    return {u, v};
}

Vec3 EnvMapLight::uv_to_direction(Vec2 uv) {
    float sp, cp, st, ct;
    sincos_0_2pi(2.f * Pi * uv.x, sp, cp);
    sincos_0_2pi(Pi * uv.y, st, ct);
    st = std::max(st, 0.f);
    return {sp * st, ct, -cp * st};
}

Spectrum EnvMapLight::radiance(Vec3 d_world) const {
    Vec3 d = normalize(m_identity ? d_world : m_to_world.apply_inverse_vector(d_world));
    return radiance_uv(direction_to_uv(d));
}

void EnvMapLight::bilinear_texels(Vec2 uv, int &x0, int &x1, int &y0, int &y1, float &fx, float &fy) const {
    float x = uv.x * m_w - 0.5f, y = uv.y * m_h - 0.5f;
    float fx0 = std::floor(x), fy0 = std::floor(y);
    fx = x - fx0;
    fy = y - fy0;
    // u is in [0, 1), so fx0 is in [-1, m_w - 1]: wrap without integer division.
    x0 = int(fx0);
    x1 = x0 + 1;
    if (x0 < 0) x0 += m_w;
    if (x1 >= m_w) x1 -= m_w;
    y0 = clamp(int(fy0), 0, m_h - 1);
    y1 = clamp(int(fy0) + 1, 0, m_h - 1);
}

Spectrum EnvMapLight::radiance_uv(Vec2 uv) const {
    int x0, x1, y0, y1;
    float fx, fy;
    bilinear_texels(uv, x0, x1, y0, y1, fx, fy);
    return (texel(x0, y0) * (1.f - fx) + texel(x1, y0) * fx) * (1.f - fy) +
           (texel(x0, y1) * (1.f - fx) + texel(x1, y1) * fx) * fy;
}

float EnvMapLight::pdf_local(Vec3 d, Vec2 uv) const {
    float sin_theta = std::sqrt(d.x * d.x + d.z * d.z);
    if (!(sin_theta > 0.f)) return 0.f;
    float pdf = m_distr.pdf(uv) / (2.f * Pi * Pi * sin_theta);
    return std::isfinite(pdf) ? pdf : 0.f;
}

float EnvMapLight::pdf_world(Vec3 wi) const {
    Vec3 d = normalize(m_identity ? wi : m_to_world.apply_inverse_vector(wi));
    return pdf_local(d, direction_to_uv(d));
}

Spectrum EnvMapLight::eval_pdf(const LightSampleContext &, const LightHit &, const Vec3 &w, float *pdf) const {
    Vec3 d = normalize(m_identity ? -w : m_to_world.apply_inverse_vector(-w));
    const Vec2 uv = direction_to_uv(d);
    if (pdf) *pdf = pdf_local(d, uv);
    return radiance_uv(uv);
}

bool EnvMapLight::sample(const LightSampleContext &ctx, Vec2 u, LightSample &out) const {
    float pdf_uv;
    Vec2 uv = m_distr.sample_continuous(u, &pdf_uv);
    if (!(pdf_uv > 0.f)) return false;
    // The density of the sampled direction from the sampled cell's own pdf (pdf_uv over the
    // Jacobian 2 pi^2 sin theta of the lat-long map): what pdf(wi) returns, without mapping wi
    // back to uv (atan2, acos and a second table lookup). The two agree except within float
    // round-off of a cell boundary.
    const Vec3 d = uv_to_direction(uv);
    const float st = std::sqrt(d.x * d.x + d.z * d.z);
    Vec3 wi = m_identity ? d : normalize(m_to_world.apply_vector(d));
    float pdf = st > 0.f ? pdf_uv / (2.f * Pi * Pi * st) : 0.f;
    if (!(pdf > 0.f) || !std::isfinite(pdf)) return false;
    out.wi = wi;
    out.dist = Infinity;
    out.pdf = pdf;
    out.delta = false;
    // The sampled uv gives the radiance directly (the bilinear lookup is continuous, so this
    // equals radiance(wi) up to float round-off, without a second atan2/acos). Deferred: the
    // texels' lines are fetched now and read after the caller's shadow ray (sampled_radiance).
    if (ctx.defer_radiance) {
        int x0, x1, y0, y1;
        float fx, fy;
        bilinear_texels(uv, x0, x1, y0, y1, fx, fy);
        for (int y : {y0, y1}) {
            const Spectrum *row = m_texels.data() + size_t(y) * m_w;
            _mm_prefetch(reinterpret_cast<const char *>(row + x0), _MM_HINT_T0);
            _mm_prefetch(reinterpret_cast<const char *>(row + x1 + 1) - 1, _MM_HINT_T0);  // x1's last byte
        }
        out.uv = uv;
        out.L_deferred = true;
    } else {
        out.L = radiance_uv(uv);
    }
    return true;
}

float EnvMapLight::pdf(const LightSampleContext &, const Vec3 &wi, const LightHit &) const { return pdf_world(wi); }

Spectrum EnvMapLight::eval(const LightHit &, const Vec3 &w) const { return radiance(-w); }

float EnvMapLight::power() const { return float(Pi * double(m_radius) * m_radius * m_integral); }

size_t EnvMapLight::memory_bytes() const { return m_texels.size() * sizeof(Spectrum) + m_distr.memory_bytes(); }

std::string EnvMapLight::to_string() const {
    return fmt::format("envmap '{}' {}x{}, scale {}, texels + sampling tables {:.2f} MB", m_name, m_w, m_h, m_scale,
                       memory_bytes() / 1048576.0);
}

MESO_REGISTER_LIGHT("envmap", "importance-sampled lat-long environment map (filename, scale, to_world)",
                    [](const Properties &p) -> std::shared_ptr<Light> {
                        std::string file = p.get_file("filename");
                        float scale = p.get_float("scale", 1.f, Range::non_negative());
                        Transform to_world = parse_transform(p);
                        Image img;
                        try {
                            img = read_image(file, false);
                        } catch (const MesoError &e) {
                            p.fail("filename", e.what());
                        }
                        try {
                            return std::make_shared<EnvMapLight>(img, scale, to_world, file);
                        } catch (const MesoError &e) {
                            // Image content problems belong to the file; a bad to_world to its key.
                            std::string msg = e.what();
                            if (msg.find("to_world") != std::string::npos) p.fail("to_world", msg);
                            p.fail("filename", fmt::format("{}: {}", file, msg));
                        }
                    });

}  // namespace meso
