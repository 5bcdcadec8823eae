// `normalmap`: normal mapping around any nested material (Mitsuba 3 `normalmap` semantics).
// The shading frame is replaced by a perturbed one and the nested material is evaluated in
// it: with `heightmap`, this is the "plain normal mapping" of the LEADR paper's Fig. 8
// comparison (paper 000): the normal of the footprint-filtered MEAN slope, no roughness
// from the slope variance (that is what lean / leadr add).
//
// Model (local frame: z = the macronormal)
//   n' = the perturbed normal at the shading point (unit, local frame):
//        normals:   normalize(N) of the normal map (texture/normal_source.h: tangent-space
//                   (s, t, n), 8/16-bit 2c - 1, renormalised per texel, filtered at the footprint)
//        heightmap: the mesonormal (-mx, -my, 1) / |.| of SlopeSource::eval(ctx): the mean
//                   slope of the map under the footprint, mapped to the shading frame exactly
//                   through dp/du, dp/dv (paper 000 eq. 11-12)
//        mean_slope / normal: constants
//   scale (glTF 2.0 material.normalTextureInfo.scale): n' = normalize(scale n'x, scale n'y, n'z)
//        before the frame is built, so 0 gives the unperturbed frame and 2 tilts further; for
//        an image the filtered average of the texels is scaled, as a GPU scales the filtered
//        sample (the per-texel renormalisation does not change a texel's direction, so one
//        texel gives glTF's normalize((2c - 1) * (scale, scale, 1)) exactly)
//   frame' = (s', t', n') with s' = s made orthogonal to n' (Gram-Schmidt), t' = n' x s'
//   eval(wo, wi) = nested.eval(ctx', wo', wi'), pdf likewise, sample: the nested sample
//   mapped back; ctx' is ctx with frame' (in world space); w' = w in frame'.
//   So eval includes the cosine w.r.t. n' (|wi'.z|), as in Mitsuba: energy is that of the
//   nested material, but the result is NOT reciprocal unless n' = z, whatever the nested
//   material (f = eval / |wi.z| has the factor |wi'.z| / |wi.z|). For a reflection-only
//   nested material, wo or wi at or below the macrosurface (z <= 0) gives 0 / no sample;
//   a transmissive one sees every direction.
//
// Parameters
//   name            type           default    notes
//   bsdf            material       -          the nested material (inline object or a name)
//   normals         string         -          tangent-space normal-map image
//   tiling          number|[u, v]  1          repeats of the normal map (normals only)
//   heightmap       object         -          displacement-style block: the mean slope at the footprint
//   filter          string         trilinear  trilinear | ewa | none (normals or heightmap)
//   max_anisotropy  float          8          ewa only
//   mean_slope      [x, y]         -          constant mean slope: n' = (-x, -y, 1) / |.|
//   normal          [x, y, z]      -          constant normal (normalised, z > 0)
//   scale           float          1          [-1000, 1000]: multiplies x and y of n' (any source)
//   exactly one of normals, heightmap, mean_slope, normal
#include <cmath>
#include <fmt/format.h>
#include <optional>
#include "bsdf/material.h"
#include "core/properties.h"
#include "core/registry.h"
#include "texture/normal_source.h"
#include "texture/slope_source.h"

namespace meso {
namespace {

class NormalMap final : public Material {
public:
    NormalMap(std::shared_ptr<Material> nested, std::optional<NormalSource> normals, std::optional<SlopeSource> slopes,
              float scale)
        : m_nested(std::move(nested)), m_normals(std::move(normals)), m_slopes(std::move(slopes)), m_scale(scale) {
        m_reflect_only = !m_nested->has_transmission();
        if ((m_normals && m_normals->is_constant()) || (m_slopes && m_slopes->is_constant()))
            m_const = std::make_unique<Frame>(frame_of(ShadingContext{}));
    }

    uint32_t flags() const override { return m_nested->flags(); }
    bool is_reciprocal() const override {
        return m_nested->is_reciprocal() && m_const && m_const->n.x == 0.f && m_const->n.y == 0.f;
    }

    Spectrum eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        if (m_reflect_only && (!(wo.z > 0.f) || !(wi.z > 0.f))) return Spectrum(0.f);
        const Frame F = frame(ctx);
        return m_nested->eval(nested_ctx(ctx, F), F.to_local(wo), F.to_local(wi));
    }

    float pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        if (m_reflect_only && (!(wo.z > 0.f) || !(wi.z > 0.f))) return 0.f;
        const Frame F = frame(ctx);
        return m_nested->pdf(nested_ctx(ctx, F), F.to_local(wo), F.to_local(wi));
    }

    bool sample(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, BSDFSample &out) const override {
        if (m_reflect_only && !(wo.z > 0.f)) return false;
        const Frame F = frame(ctx);
        if (!m_nested->sample(nested_ctx(ctx, F), F.to_local(wo), u_lobe, u, out)) return false;
        out.wi = normalize(F.to_world(out.wi));
        if (!is_finite(out.wi)) return false;
        if (m_reflect_only && !(out.wi.z > 0.f)) return false;
        if ((out.flags & BSDF_Delta) || ctx.u_eval >= 0.f) return true;  // (stochastic nested: its estimates)
        // Value and pdf again at the returned direction: the frame round trip (to_world here,
        // to_local in pdf()) moves wi by ~1e-7, which a narrow nested lobe (alpha 1e-3) or a
        // grazing perturbed frame turns into pdf differences of 1e-4 .. 1e-2 (issue 24).
        float p = 0.f;
        const Spectrum v = eval_pdf(ctx, wo, out.wi, &p);
        if (!(p > 0.f) || !std::isfinite(p)) return false;
        out.pdf = p;
        out.weight = v / p;
        return out.weight.is_finite();
    }

    Spectrum albedo_hint(const ShadingContext &ctx) const override {
        return m_nested->albedo_hint(nested_ctx(ctx, frame(ctx)));
    }

    std::string to_string() const override {
        return fmt::format("normalmap[{}{}, {}]",
                           m_normals ? m_normals->to_string() : "mean slope of " + m_slopes->to_string(),
                           m_scale != 1.f ? fmt::format(", scale {}", m_scale) : "", m_nested->to_string());
    }

private:
    /// The perturbed frame at ctx in local coordinates.
    Frame frame(const ShadingContext &ctx) const { return m_const ? *m_const : frame_of(ctx); }

    Frame frame_of(const ShadingContext &ctx) const {
        double n[3];
        if (m_normals) {
            const Vec3 v = m_normals->eval(ctx);
            n[0] = v.x, n[1] = v.y, n[2] = v.z;
        } else {
            const SlopeGaussian g = m_slopes->eval(ctx);
            n[0] = -g.mx, n[1] = -g.my, n[2] = 1.0;
        }
        n[0] *= m_scale, n[1] *= m_scale;
        const double l = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        if (!(l > 1e-30) || !std::isfinite(l)) return Frame();  // no direction: the shading frame
        return perturbed_frame(Vec3(float(n[0] / l), float(n[1] / l), float(n[2] / l)));
    }

    /// ctx with the perturbed frame in world space.
    static ShadingContext nested_ctx(const ShadingContext &ctx, const Frame &F) {
        ShadingContext c = ctx;
        c.frame = Frame(ctx.frame.to_world(F.s), ctx.frame.to_world(F.t), ctx.frame.to_world(F.n));
        return c;
    }

    std::shared_ptr<Material> m_nested;
    std::optional<NormalSource> m_normals;
    std::optional<SlopeSource> m_slopes;
    float m_scale = 1.f;  ///< glTF normalTexture.scale on the x and y of the normal
    bool m_reflect_only = true;
    std::unique_ptr<Frame> m_const;
};

std::shared_ptr<Material> make_normalmap(const Properties &p) {
    if (!p.has("bsdf")) p.fail("expected a nested material \"bsdf\"");
    auto nested = p.get_material("bsdf");
    const char *keys[] = {"normals", "heightmap", "mean_slope", "normal"};
    std::string given;
    for (const char *k : keys)
        if (p.has(k)) {
            if (!given.empty()) p.fail(k, fmt::format("give one normal source, not both \"{}\" and \"{}\"", given, k));
            given = k;
        }
    if (given.empty()) p.fail("expected a normal source: \"normals\", \"heightmap\", \"mean_slope\" or \"normal\"");
    if (p.has("covariance")) p.fail("covariance", "normal mapping uses the mean slope only (lean/leadr use the covariance)");
    const float scale = p.get_float("scale", 1.f, Range::closed(-1000.0, 1000.0));
    std::optional<NormalSource> normals;
    std::optional<SlopeSource> slopes;
    if (given == "normals" || given == "normal") {
        normals = NormalSource::parse(p, "normal", /*unit_constant=*/true, /*allow_heightmap=*/false);
    } else {
        if (p.has("tiling")) p.fail("tiling", "the heightmap's tiling goes inside its \"heightmap\" block");
        slopes = SlopeSource::parse(p);
    }
    return std::make_shared<NormalMap>(nested, std::move(normals), std::move(slopes), scale);
}

MESO_REGISTER_MATERIAL("normalmap", "normal mapping around a nested material: normal map or mean slope of a height map",
                       [](const Properties &p) -> std::shared_ptr<Material> { return make_normalmap(p); });

}  // namespace
}  // namespace meso
