// load_scene: scene file (JSON, or a .gltf/.glb translated to the same JSON) → Scene.
// The file is parsed, -D overrides are applied to the JSON, and then every object is
// created through the plugin registry, so a glTF scene and a hand-written one take the
// same path and give the same errors. The BVH is not built here (Scene::build, called
// by the render command; `--plan` prints without building). docs/scene-format.md
// describes the format.
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <optional>
#include <set>
#include <sstream>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "geometry/shape.h"
#include "geometry/displacement.h"
#include "geometry/shell_shape.h"
#include "prefilter/model.h"
#include "lights/light.h"
#include "geometry/lod.h"
#include "filter/transfer_filter.h"
#include "bsdf/material.h"
#include "scene/gltf.h"
#include "scene/overrides.h"
#include "core/properties.h"
#include "core/registry.h"
#include "render/scene.h"

namespace meso {

using json = nlohmann::json;
namespace fs = std::filesystem;

namespace {

const char *const kTopLevelKeys[] = {"camera", "integrator", "sampler", "textures", "materials", "shapes", "lights"};

std::string read_file(const std::string &path) {
    std::error_code ec;
    if (fs::is_directory(path, ec)) throw MesoError(fmt::format("{}: cannot open the scene file (it is a directory)", path));
    std::ifstream f(path, std::ios::binary);
    if (!f) throw MesoError(fmt::format("{}: cannot open the scene file ({})", path, std::strerror(errno)));
    std::ostringstream ss;
    ss << f.rdbuf();
    if (f.bad()) throw MesoError(fmt::format("{}: cannot read the scene file ({})", path, std::strerror(errno)));
    return ss.str();
}

/// Tracks the JSON path during parsing so that a duplicate key (which nlohmann would
/// silently resolve to the last value) is reported where it is.
class DuplicateKeyCheck {
public:
    explicit DuplicateKeyCheck(const std::string &file) : m_file(file) {}

    bool operator()(int, json::parse_event_t event, json &parsed) {
        switch (event) {
            case json::parse_event_t::object_start: m_stack.push_back(Frame{false, 0, {}, {}}); break;
            case json::parse_event_t::array_start: m_stack.push_back(Frame{true, 0, {}, {}}); break;
            case json::parse_event_t::key: {
                Frame &f = m_stack.back();
                f.key = parsed.get<std::string>();
                if (!f.keys.insert(f.key).second)
                    throw_located(m_file, path(m_stack.size() - 1), fmt::format("duplicate key '{}'", f.key));
                break;
            }
            case json::parse_event_t::object_end:
            case json::parse_event_t::array_end:
                m_stack.pop_back();
                element_done();
                break;
            case json::parse_event_t::value: element_done(); break;
        }
        return true;
    }

private:
    struct Frame {
        bool array;
        size_t index = 0;
        std::string key;
        std::set<std::string> keys;
    };
    void element_done() {
        if (!m_stack.empty() && m_stack.back().array) m_stack.back().index++;
    }
    /// Path of the container at depth `depth` (the frames above it say how we got there).
    std::string path(size_t depth) const {
        std::string p;
        for (size_t i = 0; i < depth; ++i) {
            if (m_stack[i].array) p += fmt::format("[{}]", m_stack[i].index);
            else p += (p.empty() ? "" : ".") + m_stack[i].key;
        }
        return p;
    }
    std::string m_file;
    std::vector<Frame> m_stack;
};

/// 1-based line and column of the 1-based byte position `byte` of `text`.
std::pair<size_t, size_t> line_column(const std::string &text, size_t byte) {
    size_t line = 1, col = 1;
    for (size_t i = 0; i + 1 < byte && i < text.size(); ++i) {
        if (text[i] == '\n') line++, col = 1;
        else col++;
    }
    return {line, col};
}

/// nlohmann's message without "[json.exception.parse_error.101] parse error at line 1, column 2: ".
std::string strip_prefix(const std::string &what) {
    size_t colon = what.find(": ");
    if (what.rfind("[json.exception.parse_error", 0) == 0 && colon != std::string::npos) return what.substr(colon + 2);
    size_t bracket = what.find("] ");
    if (what.rfind("[json.exception", 0) == 0 && bracket != std::string::npos) return what.substr(bracket + 2);
    return what;
}

json parse_scene_json(const std::string &path) {
    std::string text = read_file(path);
    try {
        DuplicateKeyCheck check(path);
        return json::parse(text, std::ref(check), /*allow_exceptions=*/true, /*ignore_comments=*/true);
    } catch (const json::parse_error &e) {
        // nlohmann reports a byte offset (1-based: the last byte read); turn it into a line
        // and column, and keep its description without the "[json.exception...]" prefix.
        auto [line, col] = line_column(text, std::min<size_t>(e.byte, text.size() + 1));
        throw MesoError(fmt::format("{}: cannot parse JSON at line {}, column {}: {}", path, line, col, strip_prefix(e.what())));
    } catch (const json::exception &e) {
        // Number overflow ("1e400") carries no position: locate the offending literal.
        std::string detail = strip_prefix(e.what());
        size_t q1 = detail.find('\''), q2 = detail.rfind('\'');
        if (q1 != std::string::npos && q2 > q1 + 1) {
            size_t at = text.find(detail.substr(q1 + 1, q2 - q1 - 1));
            if (at != std::string::npos) {
                auto [line, col] = line_column(text, at + 1);
                throw MesoError(fmt::format("{}: cannot parse JSON at line {}, column {}: {}", path, line, col, detail));
            }
        }
        throw MesoError(fmt::format("{}: cannot parse JSON: {}", path, detail));
    }
}

std::string known_keys() {
    std::string s;
    for (const char *k : kTopLevelKeys) s += (s.empty() ? "" : ", ") + std::string(k);
    return s;
}

/// Clears the LoadContext's pointers into the JSON document when loading ends (plugins may
/// keep the context alive; the document dies with load_scene).
struct DeclGuard {
    LoadContext &ctx;
    ~DeclGuard() {
        ctx.texture_decls = nullptr;
        ctx.material_decls = nullptr;
    }
};

/// `lod.model`, resolved against the scene file's directory; it must be a directory.
std::string lod_model_dir(const Properties &lp) {
    fs::path dir(lp.get_string("model"));
    if (dir.is_relative() && !lp.context().base_dir.empty()) dir = fs::path(lp.context().base_dir) / dir;
    std::error_code ec;
    if (!fs::is_directory(dir, ec))
        lp.fail("model", fmt::format("model directory not found: '{}' (make one with `meso prefilter`)", dir.string()));
    const fs::path canon = fs::weakly_canonical(dir, ec);
    return ec ? dir.string() : canon.string();
}

/// A shape's "lod" block: the chain's levels 1.. as shell shapes, each seen only by rays of
/// its level, over the least-squares heights h_low of a prefiltered model (`model`, paper 004
/// §4.1, with the `prefiltered` material of that level), box-downsampled heightfields, or,
/// with same_model, the original one.
void add_lod_levels(const Properties &lp, const std::shared_ptr<Shape> &shape, Scene &scene) {
    auto shell = std::dynamic_pointer_cast<ShellShape>(shape);
    if (!shell) lp.fail("a LoD chain needs a shell-mapped displacement (\"displacement\": {..., \"mode\": \"shell\"})");
    std::vector<float> factors = lp.get_floats("factors");
    if (factors.empty() || factors[0] != 1.f) lp.fail("factors", "expected [1, f1, f2, ...]: level 0 is the original map (factor 1)");
    if (factors.size() > 32) lp.fail("factors", "at most 32 levels");
    auto group = std::make_shared<LodGroup>();
    try {
        group->chain = LodChain(factors);
    } catch (const MesoError &e) {
        lp.fail("factors", e.what());
    }
    group->bias = lp.get_float("bias", 1.f);
    if (!(group->bias > 0.f) || !std::isfinite(group->bias)) lp.fail("bias", "expected a positive number (footprint scale)");
    std::string blend = lp.get_string("blend", "stochastic");
    if (blend == "stochastic") group->blend = LodBlend::Stochastic;
    else if (blend == "blend") group->blend = LodBlend::Blend;
    else lp.fail("blend", fmt::format("expected \"stochastic\" or \"blend\", got \"{}\"", blend));
    const bool same_model = lp.get_bool("same_model", false);
    const Displacement &disp = shell->displacement();
    // Levels of a displacement with a height transfer g: box-downsampled g(f) ("exact"), or the
    // paper 001 §7 g-bar of each block's Gaussian statistics of f ("gaussian").
    const std::string tf = lp.get_string("transfer_filter", "exact");
    if (tf != "exact" && tf != "gaussian")
        lp.fail("transfer_filter", fmt::format("expected \"exact\" or \"gaussian\", got \"{}\"", tf));
    const bool gbar = tf == "gaussian";
    if (gbar && !disp.untransferred)
        lp.fail("transfer_filter", "only meaningful when the shape's displacement has a \"transfer\"");
    if (gbar && (lp.has("model") || same_model))
        lp.fail("transfer_filter", "applies to box-downsampled levels only (not with \"model\" or \"same_model\")");

    // A prefiltered model (`meso prefilter`): its h_low per level, and its material per level.
    std::optional<prefilter::PrefilteredModel> model;
    std::string model_dir;
    if (lp.has("model")) {
        if (same_model) lp.fail("same_model", "cannot be combined with \"model\" (a prefiltered model's levels are its own)");
        model_dir = lod_model_dir(lp);
        try {
            model = prefilter::PrefilteredModel::load(model_dir);
        } catch (const MesoError &e) {
            lp.fail("model", e.what());
        }
        if (model->map_width != disp.field->width() || model->map_height != disp.field->height())
            lp.fail("model", fmt::format("the model '{}' was made from a {}x{} map, the displacement's map ({}) is {}x{}",
                                         model_dir, model->map_width, model->map_height, disp.source,
                                         disp.field->width(), disp.field->height()));
        const double hs = model->height_scale;
        if (std::abs(hs - double(disp.scale)) > 1e-5 * std::max(std::abs(hs), std::abs(double(disp.scale))))
            fmt::print(stderr, "{}: {}: warning: the model '{}' was made with height_scale {} but the displacement's scale "
                               "is {}: its NDFs and scaling functions describe other geometry\n",
                       lp.file(), lp.key_path("model"), model_dir, hs, disp.scale);
        for (size_t k = 1; k < factors.size(); ++k)
            if (factors[k] != std::floor(factors[k]) || !model->level_for_factor(int(factors[k]))) {
                std::string have;
                for (const auto &L : model->levels) have += (have.empty() ? "" : ", ") + std::to_string(L.factor);
                lp.fail("factors", fmt::format("level {}: factor {} is not a level of the model '{}' (it has {})", k,
                                               factors[k], model_dir, have));
            }
    } else {
        for (const char *key : {"scaling", "estimator"})
            if (lp.has(key)) lp.fail(key, "only applies with a prefiltered \"model\"");
    }

    std::vector<std::shared_ptr<Material>> materials;
    if (lp.has("materials")) {
        for (const Properties &m : lp.children("materials")) materials.push_back(create_material(m));
        if (materials.size() != factors.size())
            lp.fail("materials", fmt::format("expected one material per level ({}), got {}", factors.size(), materials.size()));
        shape->material = materials[0];
    } else if (model) {
        // Level k: {"type": "prefiltered", "model": ..., "level": f_k, "scaling": ..., "estimator": ...,
        // "tiling": the displacement's}; errors name lod.scaling etc. (the keys as the user wrote them).
        materials.push_back(shape->material);
        const std::string scaling = lp.has("scaling") ? lp.get_string("scaling") : std::string();
        const std::string estimator = lp.has("estimator") ? lp.get_string("estimator") : std::string();
        for (size_t k = 1; k < factors.size(); ++k) {
            json mj = {{"type", "prefiltered"},
                       {"model", model_dir},
                       {"level", int(factors[k])},
                       {"tiling", {disp.tiling_u, disp.tiling_v}}};
            if (!scaling.empty()) mj["scaling"] = scaling;
            if (!estimator.empty()) mj["estimator"] = estimator;
            materials.push_back(create_material(Properties(mj, lp.path(), lp.context_ptr())));
        }
    }
    shell->texel_grid(group->texel_w, group->texel_h);
    shape->lod = group;
    shape->lod_level = 0;
    for (size_t k = 1; k < factors.size(); ++k) {
        std::shared_ptr<const Heightfield> field = disp.field;
        if (model) {
            // h_low is in the original map's units: the displacement's scale and offset apply.
            const prefilter::PrefilteredLevel *L = model->level_for_factor(int(factors[k]));
            try {
                field = std::make_shared<Heightfield>(L->h_low, disp.scale, disp.offset);
            } catch (const MesoError &e) {
                lp.fail("model", e.what());
            }
        } else if (!same_model) {
            const float f = factors[k];
            if (f != std::floor(f) || field->width() % int(f) != 0 || field->height() % int(f) != 0)
                lp.fail("factors", fmt::format("level {}: factor {} must be an integer dividing the map size {}x{} "
                                               "(levels are box-downsampled)", k, f, field->width(), field->height()));
            field = gbar ? std::make_shared<Heightfield>(transfer_downsampled(*disp.untransferred, *disp.transfer, int(f)),
                                                         disp.scale, disp.offset)
                         : std::make_shared<Heightfield>(field->box_downsampled(int(f)), 1.f, 0.f);
        }
        auto level = shell->with_field(field, fmt::format("{} LoD level {} (x{})", lp.path(), k, factors[k]));
        level->material = materials.empty() ? shape->material : materials[k];
        level->lod = group;
        level->lod_level = int(k);
        scene.shapes.push_back(level);
    }
    lp.check_unused("lod");
}

std::unique_ptr<Scene> build_scene(const json &doc, const std::string &file, size_t max_triangles) {
    auto ctx = std::make_shared<LoadContext>();
    ctx->max_triangles = max_triangles;
    ctx->file = file;
    ctx->base_dir = fs::path(file).parent_path().string();
    DeclGuard guard{*ctx};

    if (!doc.is_object())
        throw_located(file, "", fmt::format("expected a JSON object at the top level, got {}", json_type_name(doc)));
    for (auto it = doc.begin(); it != doc.end(); ++it) {
        bool ok = false;
        for (const char *k : kTopLevelKeys) ok = ok || it.key() == k;
        if (!ok) throw_located(file, "", fmt::format("unknown top-level key '{}' (expected {})", it.key(), known_keys()));
    }
    for (const char *section : {"textures", "materials"}) {
        auto it = doc.find(section);
        if (it != doc.end() && !it->is_object())
            throw_located(file, section,
                          fmt::format("expected an object mapping names to {}, got {}", section, json_type_name(*it)));
    }
    if (doc.contains("textures")) ctx->texture_decls = &doc["textures"];
    if (doc.contains("materials")) ctx->material_decls = &doc["materials"];

    Properties root(doc, "", ctx);
    auto scene = std::make_unique<Scene>();
    scene->file = file;

    // Camera (required: there is no sensible default placement).
    if (!root.has("camera"))
        throw_located(file, "", "missing the required top-level key 'camera' (e.g. {\"type\": \"perspective\", ...})");
    scene->camera = create_camera(root.child("camera"));

    // Integrator (default: path tracer).
    static const json default_integrator = {{"type", "path"}};
    scene->integrator =
        create_integrator(root.has("integrator") ? root.child("integrator") : Properties(default_integrator, "integrator", ctx));

    // Sampler (default: independent, 16 spp). The loader reads sample_count: Scene::spp.
    static const json default_sampler = {{"type", "independent"}};
    Properties sp = root.has("sampler") ? root.child("sampler") : Properties(default_sampler, "sampler", ctx);
    int spp = sp.get_int("sample_count", 16);
    if (spp < 1) sp.fail("sample_count", fmt::format("expected a positive integer, got {}", spp));
    scene->spp = spp;
    scene->sampler = create_sampler(sp);

    // Shapes: material and emitter are read here (before the shape plugin checks for
    // unused keys), the rest by the shape plugin.
    std::shared_ptr<Material> default_material;
    if (root.has("shapes")) {
        for (const Properties &p : root.children("shapes")) {
            std::shared_ptr<Material> material;
            if (p.has("material")) {
                material = p.get_material("material");
            } else {
                if (!default_material) {
                    static const json default_diffuse = {{"type", "diffuse"}};
                    default_material = create_material(Properties(default_diffuse, "default material", ctx));
                }
                material = default_material;
            }
            std::shared_ptr<Light> emitter;
            if (p.has("emitter")) {
                Properties ep = p.child("emitter");
                emitter = create_light(ep);
                if (emitter->is_delta() || emitter->is_infinite())
                    ep.fail("type", fmt::format("light type '{}' cannot be the emitter of a shape (use an 'area' light)", ep.type()));
            }
            std::optional<Properties> lod = p.optional_child("lod");  // read before the shape checks its keys
            std::shared_ptr<Shape> shape = create_shape(p);
            shape->material = material;
            if (emitter && dynamic_cast<const ShellShape *>(shape.get()))
                p.fail("emitter", "a shell-mapped displaced shape cannot be an area emitter (use \"mode\": \"tessellate\" "
                                  "or an undisplaced emitter)");
            if (emitter) {
                emitter->set_shape(shape.get());
                shape->emitter = emitter;
                scene->lights.push_back(emitter);
            }
            scene->shapes.push_back(shape);
            if (lod) add_lod_levels(*lod, shape, *scene);
        }
    }

    // Lights not attached to shapes: point, spot, directional, environment.
    if (root.has("lights")) {
        for (const Properties &p : root.children("lights")) {
            std::shared_ptr<Light> light = create_light(p);
            if (!light->is_delta() && !light->is_infinite())
                p.fail("type", fmt::format("light type '{}' must be attached to a shape (as its \"emitter\")", p.type()));
            if (light->is_infinite()) scene->infinite_lights.push_back(light.get());
            scene->lights.push_back(light);
        }
    }
    // Named textures and materials that nothing referenced were never built: a scene pays
    // only for what it uses (and errors in unused declarations go unreported).
    return scene;
}

}  // namespace

std::unique_ptr<Scene> load_scene(const std::string &path, const std::vector<std::string> &overrides, size_t max_triangles) {
    GltfCacheScope cache;  // shapes of one glTF file parse it once
    json doc;
    if (is_gltf_path(path)) {
        doc = gltf_scene_to_json(path);
    } else {
        doc = parse_scene_json(path);
    }
    if (!overrides.empty()) {
        if (!doc.is_object())
            throw_located(path, "", fmt::format("expected a JSON object at the top level, got {}", json_type_name(doc)));
        apply_overrides(doc, overrides);
    }
    return build_scene(doc, path, max_triangles);
}

}  // namespace meso
