// The closed-form per-lobe f'_low ("--flow lobes"); the model and its derivation are in lobe_brdf.h.
#include "prefilter/lobe_brdf.h"
#include <algorithm>
#include <cmath>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "core/frame.h"
#include "core/properties.h"
#include "filter/vmf.h"

namespace meso::prefilter {

namespace {
constexpr float kPiF = 3.14159265358979f;
constexpr double kPiD = 3.14159265358979323846;

/// C(t, κ) and H(t, κ) on a grid: t ∈ [−1, 1] in kT nodes (one at t = 0, where κ → ∞ kinks),
/// rows s = √κ / (√κ + kRowScale) ∈ [0, 1] in kK nodes (the last row is κ = ∞: max(0, t) and the
/// step; the one before κ ≈ 1.6e4, where the kinks are narrower than a column).
struct VmfTables {
    static constexpr int kT = 129, kK = 65;
    static constexpr double kRowScale = 2.0;
    std::vector<float> C, H;  ///< row-major [row * kT + column]
    VmfTables() : C(size_t(kT) * kK), H(size_t(kT) * kK) {
        for (int r = 0; r < kK; ++r)
            for (int i = 0; i < kT; ++i) {
                const double t = std::clamp(-1.0 + 2.0 * i / (kT - 1), -1.0, 1.0);
                const size_t k = size_t(r) * kT + size_t(i);
                if (r == kK - 1) {
                    C[k] = float(std::max(0.0, t));
                    H[k] = t > 0.0 ? 1.f : t < 0.0 ? 0.f : 0.5f;
                    continue;
                }
                const double s = double(r) / (kK - 1), kappa = std::pow(kRowScale * s / (1.0 - s), 2.0);
                const Vec3 mu(float(std::sqrt(std::max(0.0, 1.0 - t * t))), 0.f, float(t));
                C[k] = float(vmf_projected_area(mu, kappa));
                H[k] = float(vmf_cap_mass(mu, kappa));
            }
    }
    static float row(double kappa) {
        const double q = std::sqrt(std::max(0.0, kappa)), s = std::isinf(kappa) ? 1.0 : q / (q + kRowScale);
        return float(std::clamp(s, 0.0, 1.0) * (kK - 1));
    }
    static float lookup(const std::vector<float> &tab, float t, float row) {
        const float x = std::clamp((t + 1.f) * 0.5f * (kT - 1), 0.f, float(kT - 1));
        const int i = std::min(int(x), kT - 2), r = std::min(int(row), kK - 2);
        const float fx = x - float(i), fy = row - float(r);
        const float *a = &tab[size_t(r) * kT + size_t(i)], *b = a + kT;
        return (1.f - fy) * ((1.f - fx) * a[0] + fx * a[1]) + fy * ((1.f - fx) * b[0] + fx * b[1]);
    }
};

const VmfTables &vmf_tables() {
    static const VmfTables t;
    return t;
}

/// Smith Λ of the lobe for a direction at cosine z to μ: Walter et al. 2007's rational form for
/// Beckmann (eq. 27), the exact one for GGX.
inline float lobe_lambda(MicrofacetType type, float alpha, float z) {
    const float z2 = z * z, s2 = std::max(0.f, 1.f - z2);
    if (type == MicrofacetType::GGX) return 0.5f * (std::sqrt(1.f + alpha * alpha * s2 / z2) - 1.f);
    const float a = z / (alpha * std::sqrt(s2));
    if (!(a < 1.6f)) return 0.f;
    return (1.f - 1.259f * a + 0.396f * a * a) / (3.535f * a + 2.181f * a * a);
}

/// D_α'(h) of the lobe at c2 = (μ·h)², normalised as ∫ D (m·μ) dm = 1.
inline float lobe_D(MicrofacetType type, const SvLobeBrdf::Lobe &l, float c2) {
    if (type == MicrofacetType::GGX) {
        const float d = c2 * (l.alpha * l.alpha - 1.f) + 1.f;
        return l.d_norm / (d * d);
    }
    return l.d_norm * std::exp(-(1.f - c2) / c2 * l.inv_a2) / (c2 * c2);
}

/// The probe of make_lobe_base: wo and wi mirrored about z at cosine c (so h = z and ωi·h = c).
void mirrored_pair(double c, Vec3 &wo, Vec3 &wi) {
    const float s = float(std::sqrt(std::max(0.0, 1.0 - c * c)));
    wo = Vec3(s, 0.f, float(c));
    wi = Vec3(-s, 0.f, float(c));
}

/// The conductor's F(c) · specular_reflectance, from its eval at the mirrored pair (h = z).
std::vector<Spectrum> probe_fresnel(const Material &m, const MicrofacetDistribution &d, const std::string &where) {
    std::vector<Spectrum> F(LobeBase::kFresnelNodes);
    const Vec3 z(0.f, 0.f, 1.f);
    ShadingContext ctx, ctx2;
    ctx2.uv = Vec2(0.37f, 0.71f);
    for (int k = 1; k < LobeBase::kFresnelNodes; ++k) {
        const double c = double(k) / (LobeBase::kFresnelNodes - 1);
        Vec3 wo, wi;
        mirrored_pair(c, wo, wi);
        const double dg = double(d.D(z)) * d.G(wo, wi, z) / (4.0 * c);
        const Spectrum e = m.eval(ctx, wo, wi), e2 = m.eval(ctx2, wo, wi);
        if (!(dg > 0.0) || e.r != e2.r || e.g != e2.g || e.b != e2.b)
            throw MesoError(fmt::format("{}: --flow lobes needs a conductor whose reflectance is the same everywhere "
                                        "(no textured specular_reflectance)", where));
        F[size_t(k)] = e * float(1.0 / dg);
    }
    F[0] = F[1] * 2.f - F[2];  // extrapolated: the probe's G vanishes at grazing
    for (int q = 0; q < 3; ++q) F[0][q] = std::max(0.f, F[0][q]);
    return F;
}

/// The table must reproduce the base (isotropic Cook-Torrance with microfacet.h's D and G).
void check_microfacet_base(const LobeBase &lb, const MicrofacetDistribution &d, const std::string &where) {
    const Vec3 dirs[] = {normalize(Vec3(0.3f, 0.1f, 0.9f)), normalize(Vec3(-0.5f, 0.2f, 0.6f)),
                         normalize(Vec3(0.1f, -0.7f, 0.4f)), normalize(Vec3(-0.2f, -0.3f, 0.8f))};
    ShadingContext ctx;
    for (const Vec3 &wo : dirs)
        for (const Vec3 &wi : dirs) {
            const Vec3 h = normalize(wo + wi);
            const Spectrum e = lb.material->eval(ctx, wo, wi);
            const Spectrum p = lb.fresnel_at(dot(wi, h)) * float(double(d.D(h)) * d.G(wo, wi, h) / (4.0 * wo.z));
            for (int q = 0; q < 3; ++q)
                if (!(std::abs(e[q] - p[q]) <= 1e-3f * std::max(1e-3f, std::abs(e[q]))))
                    throw MesoError(fmt::format("{}: --flow lobes: the base does not evaluate as an isotropic rough "
                                                "conductor ({}): use --flow eq5",
                                                where, lb.material->to_string()));
        }
}
}  // namespace

double widened_alpha(double alpha, double kappa) {
    const double a2 = alpha * alpha + (kappa > 0.0 ? 2.0 / kappa : kMaxLobeAlpha * kMaxLobeAlpha);
    return std::clamp(std::sqrt(a2), std::min(alpha, kMaxLobeAlpha), kMaxLobeAlpha);
}

float vmf_clamped_cosine(float t, double kappa) {
    return VmfTables::lookup(vmf_tables().C, t, VmfTables::row(kappa));
}
float vmf_cap_mass(float t, double kappa) { return VmfTables::lookup(vmf_tables().H, t, VmfTables::row(kappa)); }

Spectrum LobeBase::fresnel_at(float c) const {
    const float x = std::clamp(c, 0.f, 1.f) * float(kFresnelNodes - 1);
    const int i = std::min(int(x), kFresnelNodes - 2);
    const float f = x - float(i);
    return fresnel[size_t(i)] * (1.f - f) + fresnel[size_t(i) + 1] * f;
}

LobeBase make_lobe_base(std::shared_ptr<const Material> material, const nlohmann::json &json,
                        const std::string &where) {
    if (!material) throw MesoError(where + ": base material is null");
    const std::string type = json.is_object() && json.contains("type") && json["type"].is_string()
                                 ? json["type"].get<std::string>()
                                 : std::string();
    LobeBase lb;
    lb.material = std::move(material);
    if (type == "diffuse" && lb.material->flags() == BSDF_DiffuseReflection) {
        lb.kind = LobeBase::Kind::Lambertian;
        return lb;
    }
    if (type != "conductor")
        throw MesoError(fmt::format("{}: --flow lobes supports a \"diffuse\" or a rough \"conductor\" base given as "
                                    "an object, not {}: use --flow eq5",
                                    where, type.empty() ? json.dump() : "\"" + type + "\""));
    Properties p(json, where, std::make_shared<LoadContext>());
    const std::optional<MicrofacetDistribution> d = microfacet_from_properties(p, false, 0.f);
    if (!d) throw MesoError(where + ": --flow lobes needs a rough conductor (alpha >= 1e-4)");
    lb.kind = LobeBase::Kind::Microfacet;
    lb.type = d->type();
    lb.alpha = d->alpha_u();
    lb.fresnel = probe_fresnel(*lb.material, *d, where);
    check_microfacet_base(lb, *d, where);
    return lb;
}

// ---------------------------------------------------------------------------------------

SvLobeBrdf::SvLobeBrdf(LobeBase base, const std::vector<PatchNdf> &ndf, int width, int height)
    : m_base(std::move(base)), m_w(width), m_h(height) {
    if (width < 1 || height < 1 || ndf.size() != size_t(width) * size_t(height))
        throw MesoError(fmt::format("lobes f'_low: {} patch NDFs for a {}x{} grid", ndf.size(), width, height));
    m_first.reserve(ndf.size() + 1);
    for (size_t k = 0; k < ndf.size(); ++k) {
        m_first.push_back(uint32_t(m_lobes.size()));
        const PatchNdf &P = ndf[k];
        if (!std::isfinite(P.amplitude) || P.amplitude < 0.0)
            throw MesoError(fmt::format("lobes f'_low: patch {}: NDF amplitude must be finite and >= 0, got {}", k,
                                        P.amplitude));
        for (size_t j = 0; j < P.lobes.size(); ++j) {
            const VmfLobe &v = P.lobes[j];
            const double ml = std::sqrt(double(v.mu.x) * v.mu.x + double(v.mu.y) * v.mu.y + double(v.mu.z) * v.mu.z);
            if (std::isnan(v.kappa) || v.kappa < 0.0 || !std::isfinite(v.weight) || v.weight < 0.0 || !(ml > 0.0) ||
                !std::isfinite(ml))
                throw MesoError(fmt::format("lobes f'_low: patch {}: invalid lobe {} (kappa {}, weight {}, |mu| {})", k,
                                            j, v.kappa, v.weight, ml));
            Lobe l;
            l.mu = Vec3(float(v.mu.x / ml), float(v.mu.y / ml), float(v.mu.z / ml));
            const double kappa = std::min(v.kappa, vmf::kMaxKappa);
            l.krow = VmfTables::row(kappa);
            l.c = float(P.amplitude * v.weight * VmfTables::lookup(vmf_tables().H, l.mu.z, l.krow));
            if (!(l.c > 0.f)) continue;
            const double a = widened_alpha(m_base.alpha, kappa);
            l.alpha = float(a);
            l.inv_a2 = float(1.0 / (a * a));
            l.d_norm = float(m_base.type == MicrofacetType::GGX ? a * a / kPiD : 1.0 / (kPiD * a * a));
            const double ks = vmf::convolve_kappa(kappa, kCosineKappa);
            l.kappa_s = float(ks);
            l.vmf_norm = float(ks > 1e-8 ? ks / (2.0 * kPiD * -std::expm1(-2.0 * ks)) : 1.0 / (4.0 * kPiD));
            m_lobes.push_back(l);
        }
    }
    m_first.push_back(uint32_t(m_lobes.size()));
}

std::pair<const SvLobeBrdf::Lobe *, const SvLobeBrdf::Lobe *> SvLobeBrdf::lobes(Vec2 uv) const {
    const float u = uv.x - std::floor(uv.x), v = uv.y - std::floor(uv.y);
    const int i = std::clamp(int(u * float(m_w)), 0, m_w - 1), j = std::clamp(int(v * float(m_h)), 0, m_h - 1);
    const size_t k = size_t(j) * size_t(m_w) + size_t(i);
    const Lobe *base = m_lobes.data();
    return {base + m_first[k], base + m_first[k + 1]};
}

Spectrum SvLobeBrdf::lambert(const ShadingContext &ctx) const {
    const Vec3 z(0.f, 0.f, 1.f);
    return m_base.material->eval(ctx, z, z);
}

Spectrum SvLobeBrdf::eval_pdf_microfacet(const Lobe *b, const Lobe *e, const Vec3 &wo, const Vec3 &wi,
                                         float *pdf) const {
    const Vec3 h = normalize(wo + wi);
    const float dwh = dot(wo, h);
    if (!(dwh > 0.f)) return Spectrum(0.f);
    const MicrofacetType type = m_base.type;
    float sum = 0.f, psum = 0.f, ptot = 0.f;
    for (const Lobe *l = b; l != e; ++l) {
        const float lo = dot(l->mu, wo);
        if (!(lo > 0.f)) continue;
        ptot += l->c;
        const float li = dot(l->mu, wi), ch = dot(l->mu, h), c2 = ch * ch;
        if (!(li > 0.f) || !(ch > 0.f) || !(c2 > 1e-12f)) continue;
        const float D = lobe_D(type, *l, c2);
        psum += l->c * D * ch;
        const float G = 1.f / (1.f + lobe_lambda(type, l->alpha, lo) + lobe_lambda(type, l->alpha, li));
        sum += l->c * D * G / (4.f * lo);
    }
    if (pdf) *pdf = ptot > 0.f && std::isfinite(psum) ? psum / (ptot * 4.f * dwh) : 0.f;
    if (!(sum > 0.f) || !std::isfinite(sum)) return Spectrum(0.f);
    return m_base.fresnel_at(dot(wi, h)) * sum;
}

Spectrum SvLobeBrdf::eval_pdf_lambert(const ShadingContext &ctx, const Lobe *b, const Lobe *e, const Vec3 &wo,
                                      const Vec3 &wi, float *pdf) const {
    const VmfTables &tab = vmf_tables();
    float sum = 0.f, psum = 0.f, ptot = 0.f;
    for (const Lobe *l = b; l != e; ++l) {
        const float v = l->c * VmfTables::lookup(tab.H, dot(l->mu, wo), l->krow);
        if (!(v > 0.f)) continue;
        const float ti = dot(l->mu, wi);
        ptot += v;
        sum += v * VmfTables::lookup(tab.C, ti, l->krow);
        psum += v * l->vmf_norm * std::exp(l->kappa_s * (ti - 1.f));
    }
    if (pdf) *pdf = ptot > 0.f ? psum / ptot : 0.f;
    if (!(sum > 0.f)) return Spectrum(0.f);
    return lambert(ctx) * sum;
}

Spectrum SvLobeBrdf::eval_pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi, float *pdf) const {
    if (pdf) *pdf = 0.f;
    if (!(wo.z > 0.f) || !(wi.z > 0.f)) return Spectrum(0.f);
    const auto [b, e] = lobes(ctx.uv);
    return m_base.kind == LobeBase::Kind::Microfacet ? eval_pdf_microfacet(b, e, wo, wi, pdf)
                                                     : eval_pdf_lambert(ctx, b, e, wo, wi, pdf);
}

float SvLobeBrdf::pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const {
    float p = 0.f;
    eval_pdf(ctx, wo, wi, &p);
    return p;
}

const SvLobeBrdf::Lobe *SvLobeBrdf::choose(const Lobe *b, const Lobe *e, const Vec3 &wo, float u_lobe) const {
    const bool mf = m_base.kind == LobeBase::Kind::Microfacet;
    float w[64];
    const int n = int(std::min<ptrdiff_t>(e - b, 64));
    float total = 0.f;
    for (int j = 0; j < n; ++j) {
        const float t = dot(b[j].mu, wo);
        w[j] = mf ? (t > 0.f ? b[j].c : 0.f) : b[j].c * VmfTables::lookup(vmf_tables().H, t, b[j].krow);
        total += w[j];
    }
    if (!(total > 0.f)) return nullptr;
    float target = u_lobe * total;
    for (int j = 0; j < n; ++j) {
        if (w[j] > 0.f && (target < w[j] || j == n - 1)) return b + j;
        target -= w[j];
    }
    for (int j = n - 1; j >= 0; --j)  // round-off left the target past the end: the last one with weight
        if (w[j] > 0.f) return b + j;
    return nullptr;
}

bool SvLobeBrdf::sample(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, BSDFSample &out) const {
    if (!(wo.z > 0.f)) return false;
    const auto [b, e] = lobes(ctx.uv);
    const Lobe *l = choose(b, e, wo, u_lobe);
    if (!l) return false;
    Vec3 wi;
    if (m_base.kind == LobeBase::Kind::Microfacet) {
        // The full NDF D (m·μ) in the lobe's frame: tan²θ in closed form.
        const float ux = std::min(u.x, 0x1.fffffep-1f), a2 = l->alpha * l->alpha;
        const float tan2 = m_base.type == MicrofacetType::GGX ? a2 * ux / (1.f - ux) : -a2 * std::log1p(-ux);
        const float ct = 1.f / std::sqrt(1.f + tan2), st = std::sqrt(std::max(0.f, 1.f - ct * ct));
        const float phi = 2.f * kPiF * u.y;
        const Vec3 m = normalize(Frame(l->mu).to_world(Vec3(st * std::cos(phi), st * std::sin(phi), ct)));
        const float d = dot(wo, m);
        if (!(d > 0.f)) return false;
        wi = normalize(m * (2.f * d) - wo);
        if (!(dot(l->mu, wi) > 0.f)) return false;  // outside the lobe's hemisphere (pdf counts it out)
    } else {
        wi = vmf::sample(l->mu, double(l->kappa_s), u);
    }
    if (!(wi.z > 0.f)) return false;
    float p = 0.f;
    const Spectrum f = eval_pdf(ctx, wo, wi, &p);
    if (!(p > 0.f) || !std::isfinite(p)) return false;
    out.wi = wi;
    out.pdf = p;
    out.weight = f / p;
    out.eta = 1.f;
    out.flags = flags();
    return true;
}

uint32_t SvLobeBrdf::flags() const {
    return m_base.kind == LobeBase::Kind::Microfacet ? BSDF_GlossyReflection : BSDF_DiffuseReflection;
}

Spectrum SvLobeBrdf::albedo_hint(const ShadingContext &ctx) const {
    return m_base.kind == LobeBase::Kind::Microfacet ? m_base.fresnel_at(1.f) : lambert(ctx) * kPiF;
}

std::string SvLobeBrdf::to_string() const {
    return fmt::format("SvLobeBrdf[{}x{} patches, {} lobes, base {}]", m_w, m_h, m_lobes.size(),
                       m_base.material->to_string());
}

void SvLobeBrdf::eval_batch(const ShadingContext &ctx, const Vec3 &wo, const Vec3 *wi, int n, Spectrum *out) const {
    for (int k = 0; k < n; ++k) out[k] = eval_pdf(ctx, wo, wi[k], nullptr);
}

}  // namespace meso::prefilter
