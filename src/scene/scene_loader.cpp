// load_scene: scene file (JSON, or a .gltf/.glb or Mitsuba 3 .xml translated to the same JSON) → Scene.
// The file is parsed, -D overrides are applied to the JSON, and then every object is
// created through the plugin registry, so a glTF scene and a hand-written one take the
// same path and give the same errors. The BVH is not built here (Scene::build, called
// by the render command; `--plan` prints without building). docs/scene-format.md
// describes the format.
#include <cctype>
#include <filesystem>
#include <optional>
#include <set>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "core/input_file.h"
#include "geometry/shape.h"
#include "geometry/shell_shape.h"
#include "lights/light.h"
#include "lod/lod_build.h"
#include "bsdf/material.h"
#include "texture/texture.h"
#include "scene/default_scene.h"
#include "scene/gltf.h"
#include "scene/mitsuba_xml.h"
#include "scene/overrides.h"
#include "core/properties.h"
#include "core/registry.h"
#include "render/scene.h"

namespace meso {

using json = nlohmann::json;
namespace fs = std::filesystem;

namespace {

const char *const kTopLevelKeys[] = {"camera", "integrator", "sampler", "textures", "materials", "shapes", "lights"};

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
    std::string text = read_input_file(path, kMaxSceneFileBytes, "scene file");
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

/// The shape's "alpha" and "alpha_cutoff" keys (docs/scene-format.md, "Shapes"), read before the
/// shape plugin checks its keys: the alpha mask, or null without one or when a constant alpha
/// keeps the whole surface. The mask is a callback into the texture (geometry cannot include
/// texture/, so the scene layer, which sees both, makes the link: geometry/shape.h AlphaMask).
std::shared_ptr<const AlphaMask> parse_alpha_mask(const Properties &p) {
    if (!p.has("alpha")) {
        if (p.has("alpha_cutoff")) p.fail("alpha_cutoff", "only meaningful with an \"alpha\" texture");
        return nullptr;
    }
    const float cutoff = p.get_float("alpha_cutoff", 0.5f, Range::closed(0.0, 1.0));
    std::shared_ptr<const Texture> alpha = p.get_texture("alpha");
    if (alpha->is_constant() && alpha->eval_float(ShadingContext{}) >= cutoff) return nullptr;
    auto mask = std::make_shared<AlphaMask>();
    mask->cutoff = cutoff;
    mask->alpha = [alpha](Vec2 uv) {
        ShadingContext ctx;
        ctx.uv = uv;
        return alpha->eval_float(ctx);
    };
    return mask;
}

/// Shapes: material, emitter, alpha mask and lod are read here (before the shape plugin checks
/// for unused keys), the rest by the shape plugin.
void add_shapes(const Properties &root, const std::shared_ptr<LoadContext> &ctx, Scene &scene) {
    if (!root.has("shapes")) return;
    std::shared_ptr<Material> default_material;
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
        std::shared_ptr<const AlphaMask> alpha_mask = parse_alpha_mask(p);
        std::optional<Properties> lod = p.optional_child("lod");
        std::shared_ptr<Shape> shape = create_shape(p);
        shape->material = material;
        if (emitter && dynamic_cast<const ShellShape *>(shape.get()))
            p.fail("emitter", "a shell-mapped displaced shape cannot be an area emitter (use \"mode\": \"tessellate\" "
                              "or an undisplaced emitter)");
        if (p.has("alpha") && !shape->mesh())  // (LoD chains are shell-mapped: refused here too)
            p.fail("alpha", "an alpha mask needs a triangle-mesh shape (not an analytic sphere or a shell-mapped "
                            "displacement)");
        shape->alpha_mask = alpha_mask;
        if (emitter) {
            emitter->set_shape(shape.get());
            shape->emitter = emitter;
            scene.lights.push_back(emitter);
        }
        scene.shapes.push_back(shape);
        if (lod)
            for (std::shared_ptr<Shape> &level : build_lod_levels(parse_lod_spec(*lod), shape))
                scene.shapes.push_back(std::move(level));
    }
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
    const int spp = sp.get_int("sample_count", 16, Range::at_least(1));
    scene->spp = spp;
    scene->sampler = create_sampler(sp);

    add_shapes(root, ctx, *scene);

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

std::unique_ptr<Scene> load_scene(const std::string &path, const std::vector<std::string> &all_overrides, size_t max_triangles) {
    GltfCacheScope cache;  // shapes of one glTF file parse it once
    std::vector<std::string> overrides = all_overrides;  // an XML scene takes its -D name=value parameters
    json doc;
    const bool mesh_file = is_gltf_path(path) || is_mesh_scene_path(path);
    check_input_file(path, mesh_file ? kMaxMeshFileBytes : kMaxSceneFileBytes, "scene file");
    std::string ext = fs::path(path).extension().string();
    for (char &c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
    if (ext != ".json" && !mesh_file && !is_mitsuba_xml_path(path))
        throw MesoError(fmt::format("{}: unsupported scene format {} (meso reads .json, .gltf, .glb, .obj, .ply and "
                                    "Mitsuba 3 .xml)", path,
                                    ext.empty() ? "(the name has no extension)" : "'" + ext + "'"));
    if (is_gltf_path(path)) {
        doc = gltf_scene_to_json(path);
    } else if (is_mesh_scene_path(path)) {
        doc = mesh_scene_to_json(path);  // a bare mesh: framed, grey, lit (scene/default_scene.h)
    } else if (is_mitsuba_xml_path(path)) {
        doc = mitsuba_xml_to_json(path, &overrides);
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
