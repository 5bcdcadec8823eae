// LoD chains from a shape's "lod" block: lod/lod_build.h.
#include "lod/lod_build.h"
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "core/registry.h"
#include "geometry/displacement.h"
#include "geometry/shell_shape.h"
#include "prefilter/model.h"

namespace meso {

namespace {

/// "factors", "bias" and "blend": the chain and how a path picks its level.
void parse_chain(const Properties &lp, LodSpec &spec) {
    spec.factors = lp.get_floats("factors");
    if (spec.factors.empty() || spec.factors[0] != 1.f)
        lp.fail("factors", "expected [1, f1, f2, ...]: level 0 is the original map (factor 1)");
    if (spec.factors.size() > 32) lp.fail("factors", "at most 32 levels");
    try {
        spec.chain = LodChain(spec.factors);
    } catch (const MesoError &e) {
        lp.fail("factors", e.what());
    }
    spec.bias = lp.get_float("bias", 1.f);
    if (!(spec.bias > 0.f) || !std::isfinite(spec.bias)) lp.fail("bias", "expected a positive number (footprint scale)");
    spec.blend = lp.get_enum<LodBlend>("blend", "stochastic", {{"stochastic", LodBlend::Stochastic}, {"blend", LodBlend::Blend}});
    spec.mse_rule = lp.get_enum<bool>("rule", "footprint", {{"footprint", false}, {"mse", true}});
}

/// "model", "scaling" and "estimator": the prefiltered model the levels come from, if any.
void parse_model(const Properties &lp, LodSpec &spec) {
    if (lp.has("model")) {
        if (spec.same_model) lp.fail("same_model", "cannot be combined with \"model\" (a prefiltered model's levels are its own)");
        spec.model_dir = prefilter::resolve_model_dir(lp);
    } else {
        for (const char *key : {"scaling", "estimator"})
            if (lp.has(key)) lp.fail(key, "only applies with a prefiltered \"model\"");
    }
}

/// "materials" (explicit, one per level), else, with a model, what the generated prefiltered
/// materials are given ("scaling", "estimator"; read only then, so that they are unknown keys
/// next to explicit materials).
void parse_materials(const Properties &lp, LodSpec &spec) {
    if (lp.has("materials")) {
        spec.materials = lp.children("materials");
        if (spec.materials.size() != spec.factors.size())
            lp.fail("materials", fmt::format("expected one material per level ({}), got {}", spec.factors.size(),
                                             spec.materials.size()));
    } else if (spec.has_model()) {
        if (lp.has("scaling")) spec.scaling = lp.get_string("scaling");
        if (lp.has("estimator")) spec.estimator = lp.get_string("estimator");
    }
}

/// The shape's shell-mapped displacement (LoD levels are shell shapes over other heightfields).
std::shared_ptr<ShellShape> lod_shell(const LodSpec &spec, const std::shared_ptr<Shape> &shape) {
    auto shell = std::dynamic_pointer_cast<ShellShape>(shape);
    if (!shell) spec.block.fail("a LoD chain needs a shell-mapped displacement (\"displacement\": {..., \"mode\": \"shell\"})");
    if (spec.transfer_filter == LodTransferFilter::Gaussian && !shell->displacement().untransferred)
        spec.block.fail("transfer_filter", "only meaningful when the shape's displacement has a \"transfer\"");
    return shell;
}

/// Where the model's recorded map heights (input.map_samples) and the displacement's map differ:
/// a message naming both, or "" when they agree (or either cannot say: older models, a transfer
/// applied to the field, a zero scale).
std::string map_mismatch(const prefilter::PrefilteredModel &model, const Displacement &disp) {
    if (model.map_samples.empty() || (disp.transfer && !disp.untransferred && !disp.field_untransferred)) return "";
    if (!disp.untransferred && !disp.field_untransferred && disp.scale == 0.f) return "";
    const auto vertices = prefilter::map_fingerprint_vertices(model.map_width, model.map_height);
    std::vector<double> scene(vertices.size());
    double lo = INFINITY, hi = -INFINITY;
    for (size_t k = 0; k < vertices.size(); ++k) {
        const auto [i, j] = vertices[k];
        const double f = disp.field->eval(double(i), double(j));
        scene[k] = disp.untransferred        ? double(disp.untransferred->at(i, j))
                   : disp.field_untransferred ? f
                                              : (f - double(disp.offset)) / double(disp.scale);
        lo = std::min({lo, scene[k], model.map_samples[k]});
        hi = std::max({hi, scene[k], model.map_samples[k]});
    }
    const double tol = 1e-4 * std::max(hi - lo, 1e-12) + 1e-6 * std::max(std::abs(lo), std::abs(hi));
    for (size_t k = 0; k < vertices.size(); ++k)
        if (!(std::abs(scene[k] - model.map_samples[k]) <= tol)) {
            const auto &in = model.manifest.value("input", nlohmann::json::object());
            const std::string made_from = in.contains("map") ? in["map"].dump() : in.value("generator", nlohmann::json()).dump();
            return fmt::format("the model '{}' was made from another map ({}) than the displacement's ({}): at vertex ({}, {}) "
                               "the model's height is {:.6g} and the displacement's {:.6g} (map units)",
                               model.dir, made_from, disp.source, vertices[k].first, vertices[k].second,
                               model.map_samples[k], scene[k]);
        }
    return "";
}

/// Where one tile of the map is not model.tile_size world units on `shape` (its uv lengths over
/// the tiling): a message naming both, or "" (also when the shape's uv lengths are unknown). A
/// model has square cells; where the shape's tiles are not square (a uv sphere's, whose u length
/// also shrinks towards the poles) no tile size fits both axes, and any between the two is taken.
std::string tile_mismatch(const prefilter::PrefilteredModel &model, const Displacement &disp, const Shape &shape) {
    double lu = 0, lv = 0;
    if (!shape.uv_world_length(lu, lv) || !(lu > 0) || !(lv > 0)) return "";
    const double tu = lu / double(disp.tiling_u), tv = lv / double(disp.tiling_v), ts = model.tile_size;
    if (std::abs(tu - ts) <= 1e-3 * ts && std::abs(tv - ts) <= 1e-3 * ts) return "";
    if (std::abs(tu - tv) > 1e-3 * std::max(tu, tv) && ts >= std::min(tu, tv) * (1 - 1e-3) &&
        ts <= std::max(tu, tv) * (1 + 1e-3))
        return "";
    return fmt::format("the model '{}' was made with --tile-size {:.6g} (world size of one tile of its map), but on this shape "
                       "one tile of the displacement's map is {:.6g} x {:.6g} world units (uv lengths {:.6g} x {:.6g} over "
                       "tiling {:g} x {:g}); `meso info` prints the values to prefilter with",
                       model.dir, ts, tu, tv, lu, lv, disp.tiling_u, disp.tiling_v);
}

/// Where the shape's material is not the model's base BRDF (the levels' prefiltered materials
/// would switch BRDF at level 0): a message naming both, or "". Compared by value, not by JSON
/// text: eval at 24 fixed (wo, wi) pairs (normal to grazing, mirror and off-mirror) and 3 uvs on a
/// flat surface, within 1e-3 relative.
std::string base_mismatch(const prefilter::PrefilteredModel &model, const std::string &dir, const Material &shape_material) {
    std::shared_ptr<Material> base;
    try {
        base = prefilter::create_model_base(model, dir);
    } catch (const MesoError &) {
        return "";  // the prefiltered material reports a broken base
    }
    ShadingContext ctx;
    ctx.dpdu = Vec3(1, 0, 0);
    ctx.dpdv = Vec3(0, 1, 0);
    for (Vec2 uv : {Vec2(0.25f, 0.5f), Vec2(0.7f, 0.1f), Vec2(0.05f, 0.9f)})
        for (float to : {0.f, 0.5f, 1.1f, 1.45f})
            for (float ti : {0.2f, 0.9f, 1.3f})
                for (float dphi : {0.f, 3.14159265f}) {
                    ctx.uv = uv;
                    const Vec3 wo(std::sin(to), 0.f, std::cos(to));
                    const Vec3 wi(std::sin(ti) * std::cos(dphi), std::sin(ti) * std::sin(dphi), std::cos(ti));
                    const Spectrum a = base->eval(ctx, wo, wi), b = shape_material.eval(ctx, wo, wi);
                    for (int c = 0; c < 3; ++c)
                        if (!(std::abs(a[c] - b[c]) <= 1e-3f * std::max({std::abs(a[c]), std::abs(b[c]), 1e-3f})))
                            return fmt::format("the model '{}' was made with base material {} but the shape's material "
                                               "is another BRDF ({}: at uv ({:g}, {:g}), theta_o {:g}, theta_i {:g} rad, "
                                               "f = {:.5g} against {:.5g}); the prefiltered levels would switch BRDF",
                                               dir, model.base.dump(), shape_material.to_string(), uv.x, uv.y, to,
                                               ti, a[c], b[c]);
                }
    return "";
}

/// The prefiltered model of spec.model_dir, checked against the displacement and the shape: the
/// same map (size and heights), wrap, height scale and tile size, and a level for every factor
/// of the chain.
prefilter::PrefilteredModel load_lod_model(const LodSpec &spec, const Displacement &disp, const Shape &shape) {
    const Properties &lp = spec.block;
    const std::string &dir = spec.model_dir;
    prefilter::PrefilteredModel model;
    try {
        model = prefilter::PrefilteredModel::load(dir);
    } catch (const MesoError &e) {
        lp.fail("model", e.what());
    }
    if (model.map_width != disp.field->width() || model.map_height != disp.field->height())
        lp.fail("model", fmt::format("the model '{}' was made from a {}x{} map, the displacement's map ({}) is {}x{}", dir,
                                     model.map_width, model.map_height, disp.source, disp.field->width(),
                                     disp.field->height()));
    if (model.wrap != disp.wrap)
        lp.fail("model", fmt::format("the model '{}' was made with --wrap {}, the displacement's \"wrap\" is \"{}\"", dir,
                                     wrap_mode_name(model.wrap), wrap_mode_name(disp.wrap)));
    if (std::string why = map_mismatch(model, disp); !why.empty()) lp.fail("model", why);
    const double hs = model.height_scale;
    if (std::abs(hs - double(disp.scale)) > 1e-5 * std::max(std::abs(hs), std::abs(double(disp.scale))))
        lp.fail("model", fmt::format("the model '{}' was made with --height-scale {} but the displacement's scale is {}: "
                                     "its NDFs and scaling functions would describe other geometry",
                                     dir, hs, disp.scale));
    if (std::string why = tile_mismatch(model, disp, shape); !why.empty()) lp.fail("model", why);
    if (spec.materials.empty() && shape.material)
        if (std::string why = base_mismatch(model, dir, *shape.material); !why.empty()) lp.fail("model", why);
    for (size_t k = 1; k < spec.factors.size(); ++k) {
        const float f = spec.factors[k];
        if (f != std::floor(f) || !model.level_for_factor(int(f)))
            lp.fail("factors", fmt::format("level {}: factor {} is not a level of the model '{}' (it has {})", k, f, dir,
                                           model.factor_list()));
    }
    return model;
}

/// One material per level (index = level), or none (every level keeps the shape's material).
/// Explicit materials replace the shape's own; with a model, levels 1.. get the generated
/// prefiltered material of their factor (see the header).
std::vector<std::shared_ptr<Material>> level_materials(const LodSpec &spec, Shape &shape, const Displacement &disp) {
    std::vector<std::shared_ptr<Material>> materials;
    if (!spec.materials.empty()) {
        for (const Properties &m : spec.materials) materials.push_back(create_material(m));
        shape.material = materials[0];
    } else if (spec.has_model()) {
        materials.push_back(shape.material);
        const float k_user = disp.wrap == WrapMode::Repeat ? 1.f : 2.f;  // the user's tiling (prefiltered halves it again)
        for (size_t k = 1; k < spec.factors.size(); ++k) {
            nlohmann::json mj = {{"type", "prefiltered"},
                                 {"model", spec.model_dir},
                                 {"level", int(spec.factors[k])},
                                 {"tiling", {disp.tiling_u * k_user, disp.tiling_v * k_user}}};
            if (!spec.scaling.empty()) mj["scaling"] = spec.scaling;
            if (!spec.estimator.empty()) mj["estimator"] = spec.estimator;
            // Located at the lod block: errors read "lod.scaling" etc., the keys the user wrote.
            materials.push_back(create_material(Properties(mj, spec.block.path(), spec.block.context_ptr())));
        }
    }
    return materials;
}

/// The heightfield of level k: the model's h_low (in the original map's units, so the
/// displacement's scale and offset apply), the box-downsampled map (g(f), or g-bar of f's block
/// statistics), or, with same_model, the original.
std::shared_ptr<const Heightfield> level_field(const LodSpec &spec, const Displacement &disp,
                                               const prefilter::PrefilteredModel *model, size_t k) {
    const Properties &lp = spec.block;
    const float f = spec.factors[k];
    if (model) {
        try {
            return std::make_shared<Heightfield>(model->level_for_factor(int(f))->h_low, disp.scale, disp.offset);
        } catch (const MesoError &e) {
            lp.fail("model", e.what());
        }
    }
    std::shared_ptr<const Heightfield> field = disp.field;
    if (spec.same_model) return field;
    if (f != std::floor(f) || field->width() % int(f) != 0 || field->height() % int(f) != 0)
        lp.fail("factors", fmt::format("level {}: factor {} must be an integer dividing the map size {}x{} "
                                       "(levels are box-downsampled)", k, f, field->width(), field->height()));
    if (spec.transfer_filter == LodTransferFilter::Gaussian)
        return std::make_shared<Heightfield>(transfer_downsampled(*disp.untransferred, *disp.transfer, int(f)), disp.scale,
                                             disp.offset);
    return std::make_shared<Heightfield>(field->box_downsampled(int(f)), 1.f, 0.f);
}

/// lod "rule": "mse": every level's measured model error over windows and removed variance
/// (manifest "lod_error", prefilter/level_error.h) for the expected-MSE level choice
/// (geometry/lod.h); an error when the model lacks them (made before they existed) or is absent.
void measured_errors(const LodSpec &spec, const prefilter::PrefilteredModel *model, LodGroup &g) {
    const Properties &lp = spec.block;
    if (!model || !spec.materials.empty())
        lp.fail("rule", "\"mse\" needs a prefiltered \"model\" (and no explicit \"materials\"): it reads the level "
                        "errors that meso prefilter measures");
    std::vector<std::vector<float>> e{{}};
    std::vector<float> v{0.f};
    for (size_t k = 1; k < spec.factors.size(); ++k) {
        const prefilter::PrefilteredLevel *L = model->level_for_factor(int(spec.factors[k]));
        const nlohmann::json *le = L && L->stats.is_object() && L->stats.contains("lod_error") ? &L->stats["lod_error"] : nullptr;
        if (!le || !le->is_object() || !le->contains("window_error") || !le->contains("removed_variance") ||
            !(*le)["window_error"].is_array() || !(*le)["removed_variance"].is_number())
            lp.fail("rule", fmt::format("\"mse\": level x{} of the model '{}' has no measured errors (lod_error); "
                                        "remake it with meso prefilter --level-error", spec.factors[k], spec.model_dir));
        std::vector<float> w;
        for (const auto &x : (*le)["window_error"]) w.push_back(x.is_number() ? std::max(0.f, x.get<float>()) : 0.f);
        e.push_back(std::move(w));
        v.push_back((*le)["removed_variance"].get<float>());
    }
    g.window_error = std::move(e);
    g.removed_variance = std::move(v);
}

}  // namespace

LodSpec parse_lod_spec(const Properties &lp) {
    LodSpec spec(lp);
    parse_chain(lp, spec);
    spec.same_model = lp.get_bool("same_model", false);
    spec.transfer_filter = lp.get_enum<LodTransferFilter>(
        "transfer_filter", "exact", {{"exact", LodTransferFilter::Exact}, {"gaussian", LodTransferFilter::Gaussian}});
    if (spec.transfer_filter == LodTransferFilter::Gaussian && (lp.has("model") || spec.same_model))
        lp.fail("transfer_filter", "applies to box-downsampled levels only (not with \"model\" or \"same_model\")");
    parse_model(lp, spec);
    parse_materials(lp, spec);
    lp.check_unused("lod");
    return spec;
}

std::vector<std::shared_ptr<Shape>> build_lod_levels(const LodSpec &spec, const std::shared_ptr<Shape> &shape) {
    const std::shared_ptr<ShellShape> shell = lod_shell(spec, shape);
    const Displacement &disp = shell->displacement();
    std::optional<prefilter::PrefilteredModel> model;
    if (spec.has_model()) model = load_lod_model(spec, disp, *shape);
    const std::vector<std::shared_ptr<Material>> materials = level_materials(spec, *shape, disp);

    auto group = std::make_shared<LodGroup>();
    group->chain = spec.chain;
    group->bias = spec.bias;
    group->blend = spec.blend;
    shell->texel_grid(group->texel_w, group->texel_h);
    // The metric check (geometry/lod.h): the model's cells are square, tile_size / map width wide
    // (both of the map prefiltered, a clamp/mirror extension included, as the field here).
    if (model && spec.materials.empty()) group->model_texel = model->tile_size / double(model->map_width);
    if (spec.mse_rule) measured_errors(spec, model ? &*model : nullptr, *group);
    shape->lod = group;
    shape->lod_level = 0;
    std::vector<std::shared_ptr<Shape>> levels;
    for (size_t k = 1; k < spec.factors.size(); ++k) {
        auto level = shell->with_field(level_field(spec, disp, model ? &*model : nullptr, k),
                                       fmt::format("{} LoD level {} (x{})", spec.block.path(), k, spec.factors[k]));
        level->material = materials.empty() ? shape->material : materials[k];
        level->lod = group;
        level->lod_level = int(k);
        levels.push_back(level);
    }
    return levels;
}

}  // namespace meso
