// `prefiltered`: the prefiltered base SVBRDF of one LoD level of paper 004 (Wu et al. 2019),
// read from a model directory written by `meso prefilter` (prefilter/model.h):
//
//   f_low(x, ωi, ωo) = T(x) · S(ωi, ωo) · f'_low(x, ωi, ωo)          (eq. 13 / 18 with eq. 14)
//
// f'_low is the multi-lobe SVBRDF of eq. 5 / 11 (prefilter/multilobe_brdf.h: the base material
// integrated over the patch NDF of eq. 4, deterministic quadrature), T the spatial and S the
// angular scaling function of §6 (eq. 22-24; single-bounce tables or, "ir", the ones fitted with
// interreflections, §5). As everywhere in meso, eval returns f · cos θi (here the cosine to the
// macro normal, which f'_low already includes).
//
// Frames. The model lives in the MACRO tangent frame of the map (z = the undisplaced surface's
// normal, x along u, y along v — left-handed where the uv parameterisation is, e.g. a
// `rectangle`, whose v runs down): on microgeometry (a shell-mapped LoD level, h_low) the
// ShadingContext carries the macro normal and tangents (n_macro, dpdu_macro, dpdv_macro) and
// directions are rotated shading-local → world → macro; elsewhere (a plain mesh, `meso
// material`) the shading frame is the macro frame, its t flipped when dp/dv points against it.
// The material is reflection-only in BOTH frames: eval, pdf and sample give 0 / false unless wo
// and wi are above the shading horizon and the macro horizon. The change of frame is
// orthogonal, so solid-angle pdfs are unchanged.
//
// Map position. x = frac(uv · tiling) ∈ [0, 1)² is the position in the map's tile: T(x) is
// bilinear between its M x M bin centres (periodic), and the patch NDF is patch
// floor(x · (W/F, H/F)). f'_low and the base are evaluated with a context whose uv is x.
//
// Sampling follows f'_low alone (node choice, then the base in the node frame); the sampled
// direction is rotated back to the shading frame and must be above both horizons. pdf is
// f'_low's pdf (T·S is not importance-sampled) and weight = eval / pdf at the sampled
// direction, computed from eval and pdf. Not reciprocal (f'_low is not).
//
// Estimator. "quadrature" (default): f'_low is the full node sum everywhere (N ≈ 72 base
// evaluations per eval_pdf; sample adds the node choice and, in a rotated macro frame, a second
// full pass). "stochastic": where the integrator hands the material a uniform
// (ShadingContext::u_eval >= 0: the path tracer, for every vertex), eval_pdf returns the
// one-node estimate T·S·Σ(ωo) g_k(ωo, ωi) of a node k drawn with u_eval by P_k(ωo), with the
// node's pdf_k(ωi), and sample draws the same directions as before but returns pdf_k and
// weight T·S·Σ g_k / pdf_k (prefilter/multilobe_brdf.h, "Stochastic one-node estimator": unbiased,
// also inside the path tracer's MIS, which pairs exactly these pdfs). 1 base evaluation
// instead of N, at the price of more variance per sample. eval and pdf stay exact, and so does
// everything without u_eval (`meso material`, the χ² tests): there sample's pdf = pdf().
// "stratified": the same, with the node-set estimator of multilobe_brdf.h (m = estimator_nodes
// nodes drawn with u_eval, shared by eval_pdf and sample at the vertex: pdf_S and f_S of the set).
// Cost of one shading sample (eval_pdf + sample) on a flat surface, relative to the base's
// (build/bench/meso_microbench, docs/performance.md): "stochastic" 1.6x for a rough conductor,
// 3x for rough plastic, 20x for a Lambertian base (one S lookup costs more than that base);
// "quadrature" 27-90x (N base evaluations per pass).
//
// Flow form. A model made with `meso prefilter --flow lobes` (manifest parameters.flow) shades with
// the closed-form f'_low of prefilter/lobe_brdf.h, the one its T and S were fitted to: one
// base-like lobe per vMF lobe (roughness widened to α'² = α² + 2/κ; a diffuse base convolved
// in closed form, its reflectance averaged over each patch where the manifest says parameters.albedo
// = "patch_mean"), deterministic, exact pdf; "estimator" has no effect there (there are no nodes
// to pick: every estimator is the closed form). The optional "flow" parameter states the form a
// scene expects and is refused when the model was made with another.
//
// Base material. By default, the one the model was made with (manifest "input"."base", a
// meso material object); relative file names inside it (textures) resolve against the
// manifest's "input"."base_dir" (where `meso prefilter` read the --base file) when that
// directory exists, else against the MODEL directory; absolute ones as they are. `base` overrides it (any isotropic, reflection-only
// material without delta lobes; MultiLobeBrdf rejects the rest).
//
// Caching: a model directory is loaded once per canonical path and f'_low (one MultiLobeBrdf
// per patch) is built once per (model, level, base) while any material holds it, so the
// levels of a chain and the scaling ablations share one load.
//
// Parameters
//   name     type              default   notes
//   model    string            -         model directory (`meso prefilter` output), relative to the scene file
//   level    int               -         the level's downsampling factor F; must exist in the model
//   scaling  string            ir|single "ir" (default when the level has interreflection tables) | "single"
//                                        (default otherwise) | "none" (f'_low alone) | "T" | "S" (that factor
//                                        only, from the ir tables when the level has them, else single)
//   tiling   float | [u, v]    1         repeats of the map over uv [0, 1] (as the displacement's tiling)
//   base     material          manifest  overrides the model's base material
//   estimator string           quadrature "quadrature" (f'_low's full node sum) | "stochastic" (one node per
//                                        evaluation where the integrator supplies u_eval; see above) |
//                                        "stratified" (a set of estimator_nodes nodes per vertex; see above)
//   estimator_nodes int        8         m of "stratified", 1..32
//   flow     string            model     optional check: "eq5" | "visible" | "lobes"; must be the form the
//                                        model was made with (`meso prefilter --flow`), else an error
#include <cmath>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <tuple>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "prefilter/model.h"
#include "bsdf/material.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

using prefilter::MultiLobeBrdf;
using prefilter::PrefilteredLevel;
using prefilter::PrefilteredModel;
using prefilter::ScalingTables;
using prefilter::SvMultiLobe;

namespace fs = std::filesystem;

// ------------------------------------------------------------------ shared loads

struct ModelCache {
    std::mutex mutex;
    std::map<std::string, std::weak_ptr<const PrefilteredModel>> models;
    /// (model dir, factor, base override or null for the model's own base) -> f'_low
    std::map<std::tuple<std::string, int, const Material *>, std::weak_ptr<const SvMultiLobe>> svbrdfs;
    std::map<std::string, std::weak_ptr<const Material>> bases;  ///< the model's own base, per dir
};

ModelCache &cache() {
    static ModelCache c;
    return c;
}

std::shared_ptr<const PrefilteredModel> load_model_cached(const std::string &dir) {
    ModelCache &c = cache();
    std::lock_guard<std::mutex> lock(c.mutex);
    if (auto m = c.models[dir].lock()) return m;
    auto m = std::make_shared<const PrefilteredModel>(PrefilteredModel::load(dir));
    c.models[dir] = m;
    return m;
}

/// The model's own base material (manifest "input"."base"), built once per model.
std::shared_ptr<const Material> model_base(const std::shared_ptr<const PrefilteredModel> &model, const std::string &dir) {
    ModelCache &c = cache();
    std::lock_guard<std::mutex> lock(c.mutex);
    if (auto b = c.bases[dir].lock()) return b;
    std::shared_ptr<const Material> b = create_model_base(*model, dir);
    c.bases[dir] = b;
    return b;
}

std::shared_ptr<const SvMultiLobe> svbrdf_cached(const std::shared_ptr<const PrefilteredModel> &model,
                                                 const std::string &dir, const PrefilteredLevel &level,
                                                 const std::shared_ptr<const Material> &base, bool own_base,
                                                 const nlohmann::json &base_json, const std::string &base_where) {
    ModelCache &c = cache();
    std::lock_guard<std::mutex> lock(c.mutex);
    const auto key = std::make_tuple(dir, level.factor, own_base ? nullptr : base.get());
    if (auto f = c.svbrdfs[key].lock()) return f;
    auto f = std::make_shared<const SvMultiLobe>(base, level.ndf, level.width(), level.height(), model->quadrature,
                                                 base_json, base_where);
    c.svbrdfs[key] = f;
    return f;
}

// ------------------------------------------------------------------ the material

enum class Scaling { None, Single, Ir, TOnly, SOnly };
enum class Estimator { Quadrature, Stochastic, Stratified };
/// Nodes per set of the "stratified" estimator (measured: docs/performance.md).
constexpr int kDefaultSetNodes = 8;

class Prefiltered final : public Material {
public:
    struct Config {
        std::shared_ptr<const PrefilteredModel> model;
        const PrefilteredLevel *level = nullptr;
        std::shared_ptr<const SvMultiLobe> f;
        const ScalingTables *tables = nullptr;  ///< null: no scaling
        bool use_T = false, use_S = false;
        Estimator estimator = Estimator::Quadrature;
        int set_nodes = kDefaultSetNodes;  ///< m of "stratified"
        float tu = 1.f, tv = 1.f;
        std::string desc;
    };

    explicit Prefiltered(Config c) : m(std::move(c)) {}

    uint32_t flags() const override { return m.f->flags(); }
    bool is_reciprocal() const override { return false; }
    std::string to_string() const override { return m.desc; }

    Spectrum albedo_hint(const ShadingContext &ctx) const override {
        const Local l = local(ctx);
        Spectrum a = flow(l).albedo_hint(l.c);
        if (m.use_T) a *= m.tables->eval_T(l.c.uv);
        return a;
    }

    Spectrum eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        if (!(wo.z > 0.f) || !(wi.z > 0.f)) return Spectrum(0.f);
        const Local l = local(ctx);
        const Vec3 mo = l.to_macro(ctx, wo), mi = l.to_macro(ctx, wi);
        if (!(mo.z > 0.f) || !(mi.z > 0.f)) return Spectrum(0.f);
        return eval_macro(l, mo, mi);
    }

    Spectrum eval_pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi, float *pdf) const override {
        if (pdf) *pdf = 0.f;
        if (!(wo.z > 0.f) || !(wi.z > 0.f)) return Spectrum(0.f);
        const Local l = local(ctx);
        const Vec3 mo = l.to_macro(ctx, wo), mi = l.to_macro(ctx, wi);
        if (!(mo.z > 0.f) || !(mi.z > 0.f)) return Spectrum(0.f);
        Spectrum v;
        switch (estimator(ctx)) {
        case Estimator::Stochastic:
            v = m.f->patch(l.c.uv).eval_pdf_stochastic(l.c, mo, mi, double(ctx.u_eval), pdf);
            break;
        case Estimator::Stratified:
            v = m.f->patch(l.c.uv).eval_pdf_stratified(l.c, mo, mi, double(ctx.u_eval), m.set_nodes, pdf);
            break;
        default: v = flow(l).eval_pdf(l.c, mo, mi, pdf); break;
        }
        return v.is_black() ? v : scaled(l, v, mo, mi);
    }

    float pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const override {
        if (!(wo.z > 0.f) || !(wi.z > 0.f)) return 0.f;
        const Local l = local(ctx);
        const Vec3 mo = l.to_macro(ctx, wo), mi = l.to_macro(ctx, wi);
        if (!(mo.z > 0.f) || !(mi.z > 0.f)) return 0.f;
        return flow(l).pdf(l.c, mo, mi);
    }

    bool sample(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, BSDFSample &out) const override {
        if (!(wo.z > 0.f)) return false;
        const Local l = local(ctx);
        const Vec3 mo = l.to_macro(ctx, wo);
        if (!(mo.z > 0.f)) return false;
        const Material &f = flow(l);
        BSDFSample bs;
        const Estimator est = estimator(ctx);
        const bool from_record = est != Estimator::Quadrature;  // weight and pdf from the base's record
        bool ok = false;
        switch (est) {
        case Estimator::Stochastic: ok = m.f->patch(l.c.uv).sample_stochastic(l.c, mo, u_lobe, u, bs); break;
        case Estimator::Stratified:
            ok = m.f->patch(l.c.uv).sample_stratified(l.c, mo, double(ctx.u_eval), m.set_nodes, u_lobe, u, bs);
            break;
        default:
            if (const prefilter::SvLobeBrdf *lf = m.f->lobe_form(); lf && l.rotated) {
                // The closed form's direction alone: its value and pdf come from the one pass below.
                ok = lf->sample_direction(l.c, mo, u_lobe, u, bs.wi);
                bs.flags = lf->flags();
            } else {
                ok = f.sample(l.c, mo, u_lobe, u, bs);
            }
            break;
        }
        if (!ok) return false;
        // Back to the shading frame.
        const Vec3 wi = l.rotated ? normalize(ctx.frame.to_local(l.macro.to_world(bs.wi))) : bs.wi;
        if (!(wi.z > 0.f)) return false;
        const Vec3 mi = l.to_macro(ctx, wi);
        if (!(mi.z > 0.f)) return false;
        // Not rotated: bs is exact at mi (weight = f'_low / pdf, or the one-node estimate / pdf_k).
        // Rotated, quadrature: one eval_pdf pass at the direction the integrator will see (after
        // the rotation's round-off), so that sample, pdf and eval agree exactly (the closed form
        // only drew the direction above: this is its one pass). Rotated,
        // stochastic or stratified: the base's record, as in MultiLobeBrdf::sample_stochastic
        // (node k's value and pdf, or the set's, at the direction before the rotations round it).
        float p = bs.pdf;
        Spectrum w = bs.weight;
        if (l.rotated && !from_record) {
            const Spectrum e = f.eval_pdf(l.c, mo, mi, &p);
            w = Spectrum(e.r / p, e.g / p, e.b / p);
        }
        if (!(p > 0.f) || !std::isfinite(p)) return false;
        if (!w.is_black()) w = scaled(l, w, mo, mi);
        out.wi = wi;
        out.pdf = p;
        out.weight = w;
        out.eta = 1.f;
        out.flags = bs.flags;
        return true;
    }

private:
    /// The estimator of eval_pdf and sample at this shading point: the exact quadrature unless the
    /// integrator supplies u_eval.
    Estimator estimator(const ShadingContext &ctx) const {
        return ctx.u_eval >= 0.f ? m.estimator : Estimator::Quadrature;
    }

    /// The context f'_low sees (uv = map position x) and the macro frame.
    struct Local {
        ShadingContext c;
        Frame macro;
        bool rotated = false;
        Vec3 to_macro(const ShadingContext &ctx, const Vec3 &v) const {
            return rotated ? normalize(macro.to_local(ctx.frame.to_world(v))) : v;
        }
    };

    /// The map's frame on the surface: s along dp/du, t along dp/dv (orthogonalised; so the
    /// frame is left-handed where the uv parameterisation is), n.
    static Frame uv_frame(Vec3 n, Vec3 dpdu, Vec3 dpdv) {
        Frame f = Frame::from_normal_tangent(n, dpdu);
        if (dot(f.t, dpdv) < 0.f) f.t = -f.t;
        return f;
    }

    Local local(const ShadingContext &ctx) const {
        Local l;
        l.c = ctx;
        auto wrap = [](double v) {
            const double f = v - std::floor(v);
            return float(f < 1.0 ? f : 0.0);  // floor rounding can give exactly 1
        };
        l.c.uv = Vec2(wrap(double(ctx.uv.x) * m.tu), wrap(double(ctx.uv.y) * m.tv));
        if (const prefilter::SvLobeBrdf *lf = m.f->lobe_form()) lf->prefetch(l.c.uv);  // overlaps the frame's work
        if (length_squared(ctx.n_macro) > 0.f) {
            l.rotated = true;
            l.macro = uv_frame(normalize(ctx.n_macro), ctx.dpdu_macro, ctx.dpdv_macro);
            l.c.frame = l.macro;
        } else if (length_squared(ctx.dpdv) > 0.f && dot(cross(ctx.frame.n, ctx.frame.s), ctx.dpdv) < 0.f) {
            // A plain surface with a left-handed uv: the map's y (v) is -t of the shading frame.
            l.rotated = true;
            l.macro = Frame(ctx.frame.s, -ctx.frame.t, ctx.frame.n);
            l.c.frame = l.macro;
        }
        return l;
    }

    /// f'_low at the shading point: the level's closed form (--flow lobes) or the patch's quadrature.
    const Material &flow(const Local &l) const {
        if (const prefilter::SvLobeBrdf *lf = m.f->lobe_form()) return *lf;
        return m.f->patch(l.c.uv);
    }

    Spectrum eval_macro(const Local &l, const Vec3 &mo, const Vec3 &mi) const {
        Spectrum v = flow(l).eval(l.c, mo, mi);
        return v.is_black() ? v : scaled(l, v, mo, mi);
    }
    /// f'_low times T and S (as configured).
    Spectrum scaled(const Local &l, Spectrum v, const Vec3 &mo, const Vec3 &mi) const {
        if (m.use_T) v *= m.tables->eval_T(l.c.uv);
        if (m.use_S) v *= m.tables->eval_S(mi, mo);
        return v;
    }

    Config m;
};

std::shared_ptr<Material> make_prefiltered(const Properties &p) {
    Prefiltered::Config c;
    const std::string dir = prefilter::resolve_model_dir(p);
    try {
        c.model = load_model_cached(dir);
    } catch (const MesoError &e) {
        p.fail("model", e.what());
    }
    const int factor = p.get_int("level");
    c.level = c.model->level_for_factor(factor);
    if (!c.level) {
        p.fail("level", fmt::format("the model '{}' has no level with factor {} (it has {})", dir, factor,
                                    c.model->factor_list()));
    }
    const bool has_ir = !c.level->ir.empty();
    const std::string default_scaling = has_ir ? "ir" : "single";
    const Scaling s = p.get_enum<Scaling>("scaling", default_scaling,
                                          {{"ir", Scaling::Ir}, {"single", Scaling::Single}, {"none", Scaling::None},
                                           {"T", Scaling::TOnly}, {"S", Scaling::SOnly}});
    const std::string scaling = p.get_string("scaling", default_scaling);  // as written, for the description
    if (s == Scaling::Ir && !has_ir)
        p.fail("scaling", fmt::format("level x{} of '{}' has no interreflection tables (made without them); "
                                      "use \"single\"", factor, dir));
    const ScalingTables &tab = (s == Scaling::Single || (!has_ir && s != Scaling::Ir)) ? c.level->single : c.level->ir;
    if (s != Scaling::None) {
        c.tables = &tab;
        c.use_T = s != Scaling::SOnly;
        c.use_S = s != Scaling::TOnly;
    }
    c.estimator = p.get_enum<Estimator>("estimator", "quadrature", {{"quadrature", Estimator::Quadrature},
                                                                     {"stochastic", Estimator::Stochastic},
                                                                     {"stratified", Estimator::Stratified}});
    std::string estimator = p.get_string("estimator", "quadrature");  // as written, for the description
    const std::string model_flow = prefilter::flow_name(c.model->quadrature);
    if (p.has("flow") && p.get_string("flow") != model_flow)
        p.fail("flow", fmt::format("the model '{}' was made with --flow {} (its tables are fitted to that f'_low), not "
                                   "\"{}\": remake it with `meso prefilter --flow {}` or drop \"flow\"",
                                   dir, model_flow, p.get_string("flow"), p.get_string("flow")));
    if (c.estimator == Estimator::Stratified) {
        c.set_nodes = p.get_int("estimator_nodes", kDefaultSetNodes, Range::closed(1, MultiLobeBrdf::kMaxSetNodes));
        estimator += fmt::format(" ({} nodes)", c.set_nodes);
    }
    if (c.model->quadrature.lobes) {  // nothing to estimate: every estimator is the closed form itself
        c.estimator = Estimator::Quadrature;
        estimator = "closed form (--flow lobes)";
    }
    if (p.has("tiling")) std::tie(c.tu, c.tv) = p.get_tiling();
    if (c.model->wrap != WrapMode::Repeat) c.tu *= 0.5f, c.tv *= 0.5f;  // the model spans the map's 2 x 2 extension
    std::shared_ptr<const Material> base;
    const bool own_base = !p.has("base");
    if (own_base) {
        try {
            base = model_base(c.model, dir);
        } catch (const MesoError &e) {
            p.fail("model", fmt::format("the model's base material: {}", e.what()));
        }
    } else {
        base = p.get_material("base");
    }
    try {
        c.f = svbrdf_cached(c.model, dir, *c.level, base, own_base, own_base ? c.model->base : p.raw("base"),
                            own_base ? (fs::path(dir) / "manifest.json").string() + ": input.base" : "the base override");
    } catch (const MesoError &e) {
        p.fail(own_base ? "model" : "base", e.what());
    }
    c.desc = fmt::format("prefiltered[{} level x{} ({}x{} patches), scaling {}, estimator {}, tiling {}x{}, base {}]",
                         dir, factor, c.level->width(), c.level->height(), scaling, estimator, c.tu, c.tv,
                         base->to_string());
    return std::make_shared<Prefiltered>(std::move(c));
}

MESO_REGISTER_MATERIAL("prefiltered", "prefiltered displacement LoD level: T(x) S(wi,wo) f'_low (paper 004)",
                       [](const Properties &p) -> std::shared_ptr<Material> { return make_prefiltered(p); });

}  // namespace
}  // namespace meso
