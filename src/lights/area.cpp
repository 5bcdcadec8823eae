// `area` light: a diffuse emitter attached to a shape (the scene loader calls set_shape()).
//
// Model: radiance L leaving the surface on the side of its geometric normal (both sides
// when two_sided). L is a constant, or a texture evaluated at the uv of the point on the
// emitter (glTF emissiveTexture): at a ray's hit (eval, LightHit::uv) and at a light sample
// (the sampled point's barycentrics through Shape::uv_at), without a footprint (level 0 of
// a MIP map: the pixel's samples do the filtering), negative values clamped to 0. The
// sampling densities below do not depend on L, so MIS weights are the same as for a
// constant emitter (the texture only adds variance). A constant costs no texture lookup. On
// a shape with an alpha mask, points the mask cuts out emit nothing (their light samples
// return false; rays pass through them, so eval never sees them). For triangle meshes the geometric normal is the
// counter-clockwise one, cross(p1 - p0, p2 - p0), flipped to the side of the interpolated
// vertex normal when the mesh has normals — the same rule the mesh shape uses for si.ng.
// Power: pi · area · mean(L) (× 2 when two-sided; a texture's mean over its uv square).
//
// Sampling (pbrt-v4 Triangle::Sample / DiffuseAreaLight, Mitsuba 3 `area`), solid-angle sampling
// only where it pays: area sampling's solid-angle density d^2 / (A cos theta_l) = d^3 / (A h) on
// a planar emitter varies over it by the factor rho = (d_max / d_min)^3, and where rho <= 1.5
// (area_sampling_suffices below: at most 4.2% more variance for an integrand constant over the
// emitter) the few flops of area sampling beat solid-angle sampling's tens of flops and square
// roots; near or large emitters (rho > 1.5) are solid-angle sampled. The criterion depends on the
// reference point alone, so pdf() reproduces sample()'s choice exactly.
//   * triangle meshes: a triangle is chosen with probability area_t / area (Distribution1D),
//     then
//       "solid_angle": a direction uniform in the triangle's spherical triangle (Arvo 1995,
//                      see spherical_triangle.h: in float without libm calls from 1e-2 sr,
//                      FloatSphericalTriangle, in double below); pdf = P(t) / Omega_t, Omega_t
//                      from the same precision. Not when rho <= 1.5 for
//                      this triangle (d_max: its farthest vertex; d_min bounded below by the
//                      plane distance and the distance to its bounding sphere), nor when
//                      Omega_t, seen from the reference point, is below 3e-4 sr (pbrt's
//                      MinSphericalSampleArea) or above 6.22 sr (nearly a hemisphere: the
//                      sampling becomes unstable; pbrt's MaxSphericalSampleArea): then this
//                      triangle is area-sampled.
//       "area":        a point uniform in the triangle; pdf = P(t) / area_t · d^2 / |cos|
//                      = d^2 / (area · |cos theta_light|).
//   * a rectangle (two triangles over four corners with orthogonal edges: the `rectangle`
//     shape, a quad from a file) in "solid_angle" mode: nothing from behind a one-sided
//     rectangle (pdf 0); a point uniform on the rectangle (u as its edge coordinates) where
//     rho <= 1.5 (exact d_min, d_max in its frame), pdf = d^2 / (area |cos|); otherwise a
//     direction uniform in the whole spherical rectangle (Urena et al. 2013,
//     spherical_rectangle.h), pdf = 1 / Omega: in float without libm calls from 1e-2 sr
//     (FloatSphericalRectangle), in double from 3e-4 to 1e-2 sr, and beyond 3e-4 .. 6.22 sr by
//     the triangle rules above.
//   * other shapes (analytic sphere): shape->sample_area() (uniform by area, pdf 1/area)
//     converted to solid angle, whatever `sampling` says.
// pdf(ctx, wi, hit) is the density of the point hit.p on triangle hit.prim in the measure
// above, so next-event estimation and BSDF sampling combine correctly with MIS even when a
// direction crosses several triangles of the light.
// sample() returns false when the sampled point emits nothing towards ctx.p (back side of
// a one-sided emitter) or the configuration is degenerate (pdf not finite).
//
// Parameters (Mitsuba 3 names where they exist):
//   radiance    spectrum  default 1               emitted radiance, >= 0; or a texture (inline
//                                                 object or a declared name): radiance at the uv
//   two_sided   bool      default false           emit on both sides
//   sampling    string    default "solid_angle"   "solid_angle" or "area"
#include <fmt/format.h>
#include <algorithm>
#include <nlohmann/json.hpp>
#include <new>
#include <type_traits>
#include <utility>
#include <vector>
#include "core/error.h"
#include "geometry/shape.h"
#include "lights/spherical_rectangle.h"
#include "lights/spherical_triangle.h"
#include "lights/light.h"
#include "sampling/distribution.h"
#include "sampling/warp.h"
#include "core/properties.h"
#include "core/registry.h"
#include "texture/texture.h"

namespace meso {
namespace {

constexpr double MinSphericalSampleArea = 3e-4;  // sr
constexpr double MaxSphericalSampleArea = 6.22;  // sr
/// Below this solid angle the float spherical rectangle's S (absolute error a few float
/// epsilons, FloatSphericalRectangle.*) is off by more than 1e-4 relative: double precision.
constexpr float MinFloatSolidAngle = 1e-2f;  // sr

/// Solid-angle sampling only where it pays. Area sampling has the solid-angle density
/// d^2 / (A cos theta_l) = d^3 / (A h) on a planar emitter (h: the distance to its plane), so
/// over an emitter seen at distances [d_min, d_max] it deviates from the uniform density of
/// solid-angle sampling by at most the factor rho = (d_max / d_min)^3. For an integrand that is
/// constant over the emitter that adds at most (rho - 1)^2 / (4 rho) relative variance (the
/// chi-square divergence of two densities whose ratio stays in a range of width rho), for any
/// integrand at most a factor rho on the second moment. RhoMax = 1.5 keeps the first under
/// 4.2%: there area sampling (a few flops) is used instead of solid-angle sampling (tens of
/// flops and several square roots). Compared as d_max^2 <= RhoMax^(2/3) d_min^2.
constexpr float RhoMax23 = 1.3103707f;  // 1.5^(2/3)
inline bool area_sampling_suffices(float dmin2, float dmax2) { return dmax2 <= RhoMax23 * dmin2; }

/// Storage for a T built in place only where needed, with nothing written before: GCC 12 zeroes
/// a std::optional's whole payload when it is constructed empty (for RectPlan's two, 304 bytes
/// per light sample and pdf). The owner knows from its own state whether it was built. T must be
/// trivially destructible.
template <class T>
struct InPlace {
    static_assert(std::is_trivially_destructible_v<T>);
    alignas(T) unsigned char bytes[sizeof(T)];
    InPlace() {}  // NOLINT: leaves bytes uninitialised on purpose
    template <class... A>
    const T &emplace(A &&...a) { return *new (bytes) T(std::forward<A>(a)...); }
    const T *operator->() const { return std::launder(reinterpret_cast<const T *>(bytes)); }
};

class AreaLight final : public Light {
public:
    /// `texture` null: the constant radiance L.
    AreaLight(Spectrum L, std::shared_ptr<const Texture> texture, bool two_sided, bool solid_angle)
        : m_radiance(L), m_texture(std::move(texture)), m_two_sided(two_sided), m_solid_angle(solid_angle) {}

    void set_shape(const Shape *shape) override {
        m_shape = shape;
        build();
    }
    // The shape is final by now; rebuild in case it was bound before being transformed.
    void preprocess(Vec3, float) override { build(); }

    /// Direction and distance from the reference point to p; false when they coincide.
    static bool towards(const LightSampleContext &ctx, Vec3 p, LightSample &out, float &d2) {
        Vec3 d = p - ctx.p;
        d2 = length_squared(d);
        if (!(d2 > 0.f)) return false;
        if (d2 >= FLT_MIN && d2 <= 1e38f) {  // one reciprocal square root (float_trig.h)
            const float inv = rsqrt(d2);
            out.dist = d2 * inv;
            out.wi = d * inv;
        } else {
            out.dist = std::sqrt(d2);
            out.wi = d / out.dist;
        }
        return true;
    }

    bool sample(const LightSampleContext &ctx, Vec2 u, LightSample &out) const override {
        if (!m_shape || !(m_area > 0.f)) return false;
        float d2;
        Vec3 p, n;
        Vec2 uv;  // read only by textures and alpha masks
        float pdf = 0.f;
        const RectPlan plan = rect_plan(ctx.p);
        if (plan.kind == RectPlan::Nothing) return false;
        if (plan.kind == RectPlan::Float || plan.kind == RectPlan::Double || plan.kind == RectPlan::Area) {
            // A rectangle: one direction uniform in its solid angle, or one point uniform on it.
            if (plan.kind == RectPlan::Float) {
                // wi and the distance come from the sampler's frame (no towards()).
                if (!plan.f->sample(u, p, nullptr, &out.wi, &out.dist)) return false;
                pdf = 1.f / plan.f->S;
            } else if (plan.kind == RectPlan::Double) {
                if (!plan.d->sample(u, p)) return false;
                pdf = float(1.0 / plan.d->S);
            } else {
                p = m_rect.s + m_rect.x * (u.x * m_rect.lx) + m_rect.y * (u.y * m_rect.ly);
            }
            // The emission normal is m_rect_n over the whole rectangle unless vertex normals
            // flip it per point; the triangle and its barycentrics only for those, textures and masks.
            size_t t = 0;
            n = m_rect_n;
            if (m_texture || m_shape->alpha_mask || !m_rect_n_uniform) {
                double b[3] = {1, 0, 0};
                t = locate(p, b);
                n = emission_normal(t, float(b[0]), float(b[1]), float(b[2]));
                uv = m_shape->uv_at(uint32_t(t), float(b[1]), float(b[2]));
            }
            if (plan.kind != RectPlan::Float && !towards(ctx, p, out, d2)) return false;
            if (plan.kind == RectPlan::Area) pdf = rect_area_density(out.wi, d2);
        } else if (m_mesh) {
            float pmf, ux;
            size_t t = m_tri_distr.sample_discrete(u.x, &pmf, &ux);
            if (!(pmf > 0.f)) return false;
            Vec3 p0, p1, p2;
            triangle(t, p0, p1, p2);
            const TriPlan tp = tri_plan(ctx.p, t, p0, p1, p2);
            float b[3];
            if (tp.kind == TriPlan::Float) {
                if (!tp.f->sample(p0, p1, p2, Vec2(ux, u.y), b)) return false;
            } else if (tp.kind == TriPlan::Double) {
                double bd[3];
                if (!sphtri::sample(ctx.p, p0, p1, p2, Vec2(ux, u.y), bd)) return false;
                b[0] = float(bd[0]), b[1] = float(bd[1]), b[2] = float(bd[2]);
            } else {
                const Vec2 bb = square_to_uniform_triangle(Vec2(ux, u.y));
                b[0] = bb.x, b[1] = bb.y, b[2] = 1.f - bb.x - bb.y;
            }
            p = p0 * b[0] + p1 * b[1] + p2 * b[2];
            n = emission_normal(t, b[0], b[1], b[2]);
            if (m_texture || m_shape->alpha_mask) uv = m_shape->uv_at(uint32_t(t), b[1], b[2]);
            if (!towards(ctx, p, out, d2)) return false;
            pdf = density(t, tp, n, out.wi, d2, pmf);
        } else {
            PositionSample ps = m_shape->sample_area(u.x, u);
            p = ps.p;
            n = ps.n;
            uv = ps.uv;
            if (!towards(ctx, p, out, d2)) return false;
            float cos_l = absdot(n, out.wi);
            pdf = cos_l > 0.f ? d2 / (cos_l * m_area) : 0.f;
        }
        if (!(pdf > 0.f) || !std::isfinite(pdf)) return false;
        out.pdf = pdf;
        out.delta = false;
        if (!faces(n, -out.wi)) return false;
        const AlphaMask *mask = m_shape->alpha_mask.get();
        if (mask && mask->alpha(uv) < mask->cutoff) return false;  // cut out: not part of the emitter
        out.L = m_texture ? textured(p, n, uv) : m_radiance;
        return !out.L.is_black();
    }

    float pdf(const LightSampleContext &ctx, const Vec3 &wi, const LightHit &hit) const override {
        if (!m_shape || !(m_area > 0.f)) return 0.f;
        Vec3 d = hit.p - ctx.p;
        float d2 = length_squared(d);
        if (!(d2 > 0.f)) return 0.f;
        float pdf;
        if (m_mesh && hit.prim >= m_mesh->triangle_count()) return 0.f;
        const RectPlan plan = rect_plan(ctx.p);
        if (plan.kind == RectPlan::Nothing) return 0.f;
        if (plan.kind == RectPlan::Float) {
            pdf = 1.f / plan.f->S;
        } else if (plan.kind == RectPlan::Double) {
            pdf = float(1.0 / plan.d->S);
        } else if (plan.kind == RectPlan::Area) {
            pdf = rect_area_density(wi, d2);
        } else if (m_mesh) {
            size_t t = hit.prim;
            float pmf = m_tri_distr.pmf(t);
            if (!(pmf > 0.f)) return 0.f;
            Vec3 p0, p1, p2;
            triangle(t, p0, p1, p2);
            pdf = density(t, tri_plan(ctx.p, t, p0, p1, p2), m_tri_normal[t], wi, d2, pmf);
        } else {
            float cos_l = absdot(hit.n, wi);
            pdf = cos_l > 0.f ? d2 / (cos_l * m_area) : 0.f;
        }
        return std::isfinite(pdf) ? pdf : 0.f;
    }

    Spectrum eval(const LightHit &hit, const Vec3 &w) const override {
        if (!faces(hit.n, w)) return Spectrum(0.f);
        return m_texture ? textured(hit.p, hit.n, hit.uv) : m_radiance;
    }
    float power() const override {
        const float mean = m_texture ? std::max(m_texture->mean().average(), 0.f) : m_radiance.average();
        return Pi * m_area * mean * (m_two_sided ? 2.f : 1.f);
    }
    std::string to_string() const override {
        const std::string L = m_texture ? "radiance " + m_texture->to_string()
                                        : fmt::format("radiance [{}, {}, {}]", m_radiance.r, m_radiance.g, m_radiance.b);
        return fmt::format("area light, {}{}, {} sampling, area {:.4g}, {} triangles{}", L,
                           m_two_sided ? ", two-sided" : "",
                           m_mesh ? (m_solid_angle ? "solid-angle" : "area") : "area", m_area,
                           m_mesh ? m_mesh->triangle_count() : 0, m_shape ? "" : " (no shape bound)");
    }

private:
    /// Whether the side of normal n that w points to emits.
    bool faces(Vec3 n, Vec3 w) const { return m_two_sided || dot(n, w) > 0.f; }
    /// The radiance texture at a point of the emitter (no footprint), negative values as 0.
    Spectrum textured(Vec3 p, Vec3 n, Vec2 uv) const {
        ShadingContext ctx;
        ctx.p = p;
        ctx.uv = uv;
        ctx.ng = n;
        ctx.frame = Frame(n);
        const Spectrum L = m_texture->eval(ctx);
        return Spectrum(std::max(L.r, 0.f), std::max(L.g, 0.f), std::max(L.b, 0.f));
    }
    void triangle(size_t t, Vec3 &p0, Vec3 &p1, Vec3 &p2) const {
        const uint32_t *idx = &m_mesh->indices[3 * t];
        p0 = m_mesh->positions[idx[0]];
        p1 = m_mesh->positions[idx[1]];
        p2 = m_mesh->positions[idx[2]];
    }
    /// How triangle t = (p0, p1, p2) is sampled from p: by area where area sampling is as good
    /// (area_sampling_suffices, with a lower bound on the distance to the triangle: the plane
    /// distance, or the distance to its bounding sphere about the centroid) or outside the solid
    /// angles that double precision resolves; otherwise its spherical triangle, in float from
    /// MinFloatSolidAngle, in double below. A function of p alone: pdf() repeats sample()'s choice.
    struct TriPlan {
        enum Kind { Area, Float, Double } kind = Area;
        InPlace<sphtri::FloatSphericalTriangle> f;  ///< built unless the plan is area sampling
        double omega = 0;  ///< Double: the solid angle
    };
    TriPlan tri_plan(Vec3 p, size_t t, Vec3 p0, Vec3 p1, Vec3 p2) const {
        TriPlan plan;
        if (!m_solid_angle) return plan;
        const Vec3 c = (p0 + p1 + p2) * (1.f / 3.f);
        const float radius = std::sqrt(std::max({length_squared(p0 - c), length_squared(p1 - c), length_squared(p2 - c)}));
        const float h = absdot(m_tri_normal[t], p - p0), dc = length(p - c) - radius;
        const float dmin = std::max(h, dc);
        const float dmax2 = std::max({length_squared(p0 - p), length_squared(p1 - p), length_squared(p2 - p)});
        if (area_sampling_suffices(dmin * dmin, dmax2)) return plan;
        const sphtri::FloatSphericalTriangle &f = plan.f.emplace(p, p0, p1, p2);
        if (f.valid && f.S >= MinFloatSolidAngle && f.S <= MaxSphericalSampleArea) {
            plan.kind = TriPlan::Float;
            return plan;
        }
        if (f.valid && f.S > MaxSphericalSampleArea && f.S < 6.27f) return plan;  // nearly a hemisphere
        plan.omega = sphtri::solid_angle(p, p0, p1, p2);
        if (plan.omega >= MinSphericalSampleArea && plan.omega <= MaxSphericalSampleArea) plan.kind = TriPlan::Double;
        return plan;
    }
    /// Solid-angle density of the light point at distance^2 d2 along wi on triangle t (chosen
    /// with probability pmf, sampled as `plan` says).
    float density(size_t t, const TriPlan &plan, Vec3 n, Vec3 wi, float d2, float pmf) const {
        if (plan.kind == TriPlan::Float) return pmf / plan.f->S;
        if (plan.kind == TriPlan::Double) return float(double(pmf) / plan.omega);
        float cos_l = absdot(n, wi);
        float area_t = m_tri_area[t];
        if (!(cos_l > 0.f) || !(area_t > 0.f)) return 0.f;
        return pmf / area_t * d2 / cos_l;
    }
    Vec3 emission_normal(size_t t, float b0, float b1, float b2) const {
        Vec3 ng = m_tri_normal[t];
        if (!m_mesh->normals.empty()) {
            const uint32_t *idx = &m_mesh->indices[3 * t];
            Vec3 ns = m_mesh->normals[idx[0]] * b0 + m_mesh->normals[idx[1]] * b1 + m_mesh->normals[idx[2]] * b2;
            if (dot(ng, ns) < 0.f) ng = -ng;
        }
        return ng;
    }
    void build() {
        m_mesh = m_shape ? m_shape->mesh() : nullptr;
        m_tri_area.clear();
        m_tri_normal.clear();
        if (!m_shape) {
            m_area = 0.f;
            return;
        }
        if (!m_mesh) {
            m_area = m_shape->surface_area();
            return;
        }
        size_t n = m_mesh->triangle_count();
        m_tri_area.resize(n);
        m_tri_normal.resize(n);
        double total = 0;
        for (size_t t = 0; t < n; ++t) {
            Vec3 p0, p1, p2;
            triangle(t, p0, p1, p2);
            Vec3 c = cross(p1 - p0, p2 - p0);
            float len = length(c);
            bool ok = len > 0.f && std::isfinite(len);
            m_tri_area[t] = ok ? 0.5f * len : 0.f;
            m_tri_normal[t] = ok ? c / len : Vec3(0, 0, 0);
            total += m_tri_area[t];
        }
        m_area = float(total);
        m_tri_distr = Distribution1D(m_tri_area);
        detect_rectangle();
    }

    /// How a rectangular emitter is sampled from p (a function of p alone, so pdf() repeats
    /// sample()'s choice): nothing from behind a one-sided emitter; by area (the triangles) where
    /// area sampling is as good (area_sampling_suffices: the distances to the nearest and the
    /// farthest point of the rectangle in its frame), a point uniform on the rectangle (u as its
    /// two edge coordinates: no triangle choice); otherwise the whole spherical rectangle in
    /// float, in double below MinFloatSolidAngle, and per triangle outside the bounds
    /// [MinSphericalSampleArea, MaxSphericalSampleArea]. Emitters that are no rectangle (or in
    /// "area" mode) go to the triangles, which decide per triangle.
    struct RectPlan {
        enum Kind { Nothing, Triangles, Area, Float, Double } kind = Triangles;
        InPlace<sphrect::FloatSphericalRectangle> f;  ///< built for Float and Double only
        InPlace<sphrect::SphericalRectangle> d;       ///< built only below MinFloatSolidAngle (rare)
    };
    RectPlan rect_plan(Vec3 p) const {
        RectPlan plan;
        if (!m_is_rect || !m_solid_angle) return plan;
        const Vec3 q = p - m_rect.s;
        const float zq = dot(q, m_rect.z);
        if (m_rect_front != 0 && !(zq * float(m_rect_front) > 0.f)) {
            plan.kind = RectPlan::Nothing;  // behind a one-sided emitter, or in its plane
            return plan;
        }
        // Nearest and farthest point of [0, lx] x [0, ly] from p's projection (a, b).
        const float a = dot(q, m_rect.x), b = dot(q, m_rect.y);
        const float na = a - std::clamp(a, 0.f, m_rect.lx), nb = b - std::clamp(b, 0.f, m_rect.ly);
        const float fa = std::max(std::abs(a), std::abs(a - m_rect.lx)), fb = std::max(std::abs(b), std::abs(b - m_rect.ly));
        if (area_sampling_suffices(na * na + nb * nb + zq * zq, fa * fa + fb * fb + zq * zq)) {
            plan.kind = RectPlan::Area;
            return plan;
        }
        const sphrect::FloatSphericalRectangle &f = plan.f.emplace(p, m_rect, -a, -b, -zq);  // corner - p in the frame
        if (f.valid && f.S >= MinFloatSolidAngle && f.S <= MaxSphericalSampleArea) {
            plan.kind = RectPlan::Float;
        } else if (f.valid && f.S < MinFloatSolidAngle) {
            plan.d.emplace(p, m_rect_s, m_rect_ex, m_rect_ey);
            if (plan.d->valid && plan.d->S >= MinSphericalSampleArea && plan.d->S <= MaxSphericalSampleArea)
                plan.kind = RectPlan::Double;
        }
        return plan;
    }
    /// Solid-angle density of a point uniform on the rectangle, at distance^2 d2 along wi.
    float rect_area_density(Vec3 wi, float d2) const {
        const float cos_l = absdot(m_rect.z, wi);
        return cos_l > 0.f ? d2 / (cos_l * m_area) : 0.f;
    }
    /// The triangle of a rectangular emitter that holds p, with p's barycentrics in it.
    size_t locate(Vec3 p, double b[3]) const {
        size_t best = 0;
        double best_min = -1e300;
        for (size_t t = 0; t < 2; ++t) {
            Vec3 p0, p1, p2;
            triangle(t, p0, p1, p2);
            const Vec3 e1 = p1 - p0, e2 = p2 - p0, d = p - p0;
            const double d11 = dot(e1, e1), d12 = dot(e1, e2), d22 = dot(e2, e2), det = d11 * d22 - d12 * d12;
            const double c1 = dot(d, e1), c2 = dot(d, e2);
            const double b1 = (d22 * c1 - d12 * c2) / det, b2 = (d11 * c2 - d12 * c1) / det, b0 = 1 - b1 - b2;
            const double lo = std::min(b0, std::min(b1, b2));
            if (lo > best_min) {
                best_min = lo, best = t;
                b[0] = std::max(0.0, b0), b[1] = std::max(0.0, b1), b[2] = std::max(0.0, b2);
            }
        }
        return best;
    }
    /// The side of the rectangle's frame z that emits (+1 or -1) when the emission normal is the
    /// same at every vertex of both triangles (vertex normals may flip it per point); 0 otherwise.
    int emitting_side() const {
        int side = 0;
        for (size_t t = 0; t < 2; ++t)
            for (int k = 0; k < 3; ++k) {
                const float b[3] = {k == 0 ? 1.f : 0.f, k == 1 ? 1.f : 0.f, k == 2 ? 1.f : 0.f};
                const float s = dot(emission_normal(t, b[0], b[1], b[2]), m_rect.z);
                const int this_side = s > 0.f ? 1 : (s < 0.f ? -1 : 0);
                if (this_side == 0 || (side != 0 && this_side != side)) return 0;
                side = this_side;
            }
        return side;
    }
    /// Whether the mesh is a rectangle (the `rectangle` shape, a quad of a file): two triangles
    /// over four corners s, s + ex, s + ex + ey, s + ey with ex orthogonal to ey.
    void detect_rectangle() {
        m_is_rect = false;
        if (!m_mesh || m_mesh->triangle_count() != 2 || m_mesh->positions.size() < 4) return;
        std::vector<Vec3> corners;
        for (uint32_t i : m_mesh->indices) {
            const Vec3 q = m_mesh->positions[i];
            if (std::none_of(corners.begin(), corners.end(), [&](Vec3 c) { return c.x == q.x && c.y == q.y && c.z == q.z; })) corners.push_back(q);
        }
        if (corners.size() != 4 || !(m_tri_area[0] > 0.f) || !(m_tri_area[1] > 0.f)) return;
        if (dot(m_tri_normal[0], m_tri_normal[1]) < 0.9999f) return;  // not coplanar, or folded
        for (int a = 0; a < 4; ++a)  // a corner whose two neighbours span the rectangle
            for (int b = 0; b < 4; ++b)
                for (int c = 0; c < 4; ++c) {
                    if (a == b || a == c || b == c) continue;
                    const Vec3 ex = corners[b] - corners[a], ey = corners[c] - corners[a];
                    const int d = 6 - a - b - c;
                    const float tol = 1e-5f * (length_squared(ex) + length_squared(ey));
                    if (std::abs(dot(ex, ey)) > tol || length_squared(corners[a] + ex + ey - corners[d]) > tol) continue;
                    m_rect_s = corners[a], m_rect_ex = ex, m_rect_ey = ey, m_is_rect = true;
                    m_rect = sphrect::RectFrame(m_rect_s, m_rect_ex, m_rect_ey);
                    const int side = emitting_side();
                    m_rect_front = m_two_sided ? 0 : side;
                    // Without vertex normals, or with vertex normals that never flip it, the
                    // emission normal is triangle 0's normal on the emitting side everywhere
                    // (triangle 1's differs from it by rounding: the corners are coplanar).
                    m_rect_n = m_tri_normal[0];
                    if (!m_mesh->normals.empty() && side != 0 && dot(m_rect_n, m_rect.z) * float(side) < 0.f) m_rect_n = -m_rect_n;
                    m_rect_n_uniform = m_mesh->normals.empty() || side != 0;
                    return;
                }
    }

    Spectrum m_radiance;
    std::shared_ptr<const Texture> m_texture;  ///< null: the constant m_radiance
    bool m_two_sided, m_solid_angle;
    const Shape *m_shape = nullptr;
    const TriangleMesh *m_mesh = nullptr;
    std::vector<float> m_tri_area;
    std::vector<Vec3> m_tri_normal;  ///< counter-clockwise unit normals (zero if degenerate)
    Distribution1D m_tri_distr;
    float m_area = 0.f;
    bool m_is_rect = false;          ///< a rectangle: solid-angle sampled as a whole (sphrect)
    Vec3 m_rect_s, m_rect_ex, m_rect_ey;
    sphrect::RectFrame m_rect;       ///< the rectangle's frame (float sampling)
    int m_rect_front = 0;            ///< +1 / -1: only the side of +z / -z emits; 0: both or unknown
    Vec3 m_rect_n;                   ///< the emission normal where m_rect_n_uniform
    bool m_rect_n_uniform = false;   ///< the emission normal is the same at every point (no locate())
};

MESO_REGISTER_LIGHT("area", "diffuse area emitter on a shape (radiance: constant or texture, two_sided, sampling)",
                    [](const Properties &p) -> std::shared_ptr<Light> {
                        // A number or [r, g, b] is the constant (range-checked); an object or a
                        // name is a texture (a constant one is taken as its value).
                        Spectrum L(1.f);
                        std::shared_ptr<const Texture> texture;
                        const bool textured =
                            p.has("radiance") && (p.raw("radiance").is_object() || p.raw("radiance").is_string());
                        if (textured) {
                            texture = p.get_texture("radiance");
                            if (texture->is_constant()) {
                                L = texture->mean();
                                texture = nullptr;
                                if (!(L.r >= 0.f && L.g >= 0.f && L.b >= 0.f))
                                    p.fail("radiance", "expected a radiance >= 0");
                            }
                        } else {
                            L = p.get_spectrum("radiance", Spectrum(1.f), Range::non_negative());
                        }
                        bool two_sided = p.get_bool("two_sided", false);
                        const bool solid_angle =
                            p.get_enum<bool>("sampling", "solid_angle", {{"solid_angle", true}, {"area", false}});
                        return std::make_shared<AreaLight>(L, std::move(texture), two_sided, solid_angle);
                    });

}  // namespace
}  // namespace meso
