// Typed, located access to one JSON object of a scene file. Every read is remembered;
// after a plugin is built, check_unused() turns any key it did not read into an error
// naming the file, the JSON path and the plugin, so typos never pass silently.
//
// Numbers: get_float accepts a JSON number; get_spectrum accepts a number (grey) or an
// [r, g, b] array; get_vec3 an [x, y, z] array. Textures (get_texture) accept a number,
// an [r,g,b] array, an inline object {"type": ...} or a string naming a texture declared
// in the scene's top-level "textures" object.
#pragma once
#include <initializer_list>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <vector>
#include <nlohmann/json_fwd.hpp>
#include "core/spectrum.h"
#include "core/vec.h"

namespace meso {

class Texture;
class Material;

/// Largest magnitude of a scene coordinate or length (positions, radii, transform entries):
/// beyond it float precision leaves nothing to render (README.md, "Limits").
inline constexpr float kMaxSceneCoordinate = 1e8f;

/// The allowed values of a numeric parameter, for the ranged getters. The error names the
/// file, the JSON path and the range: `expected a number in (0, 1e8], got -2`.
struct Range {
    double lo = -1e300, hi = 1e300;
    bool lo_open = false, hi_open = false;
    static Range positive(double hi = kMaxSceneCoordinate) { return {0, hi, true, false}; }   ///< (0, hi]
    static Range non_negative(double hi = 3.4e38) { return {0, hi, false, false}; }           ///< [0, hi]
    static Range closed(double lo, double hi) { return {lo, hi, false, false}; }              ///< [lo, hi]
    static Range at_least(double lo) { return {lo, 3.4e38, false, false}; }                   ///< [lo, max]
    static Range coordinate() { return closed(-kMaxSceneCoordinate, kMaxSceneCoordinate); }  ///< scene lengths
    bool contains(double v) const {
        return (lo_open ? v > lo : v >= lo) && (hi_open ? v < hi : v <= hi);
    }
    /// "(0, 1e+08]", "[1, 64]", "at least 0", ...
    std::string text() const;
};

/// Shared state of one scene load: the file name for messages, the directory that
/// relative paths resolve against, named objects, and -D overrides already applied.
struct LoadContext {
    std::string file;      ///< scene file as given by the user (for messages)
    std::string base_dir;  ///< directory relative paths resolve against
    size_t max_triangles = 0;  ///< limit for explicit tessellation (0: the default; --max-triangles)
    std::map<std::string, std::shared_ptr<Texture>> textures;
    std::map<std::string, std::shared_ptr<Material>> materials;
    /// Declarations not yet built (built on first reference, so unused ones cost nothing).
    const nlohmann::json *texture_decls = nullptr;
    const nlohmann::json *material_decls = nullptr;
    std::set<std::string> building;  ///< names being built (cycle detection)
};

/// "an object", "a string", "an integer", ... for messages about what was found.
const char *json_type_name(const nlohmann::json &j);

/// The one wording of every "which of these names" error: `"a", "b" or "c"`.
std::string quoted_choices(const std::vector<std::string> &names);
/// Index of `value` in `names`; otherwise throws MesoError "`what`: expected "a", "b" or "c",
/// got "value"" (command-line options and other non-scene choices).
int parse_choice(const std::string &what, const std::string &value, const std::vector<std::string> &names);

class Properties {
public:
    /// `path` is the JSON path of `obj` ("materials.gold", "shapes[2].material").
    Properties(const nlohmann::json &obj, std::string path, std::shared_ptr<LoadContext> ctx);
    ~Properties();
    Properties(const Properties &);

    const std::string &path() const { return m_path; }
    const std::string &file() const { return m_ctx->file; }
    LoadContext &context() const { return *m_ctx; }
    std::shared_ptr<LoadContext> context_ptr() const { return m_ctx; }
    /// The plugin type ("type" key); marks it read.
    std::string type() const;
    bool has(const std::string &key) const;

    float get_float(const std::string &key) const;
    float get_float(const std::string &key, float def) const;
    int get_int(const std::string &key) const;
    int get_int(const std::string &key, int def) const;
    bool get_bool(const std::string &key, bool def) const;
    std::string get_string(const std::string &key) const;
    std::string get_string(const std::string &key, const std::string &def) const;
    Vec3 get_vec3(const std::string &key) const;
    Vec3 get_vec3(const std::string &key, Vec3 def) const;
    /// A point in world or object space: every coordinate within ±kMaxSceneCoordinate.
    Vec3 get_position(const std::string &key) const;
    Vec3 get_position(const std::string &key, Vec3 def) const;
    Spectrum get_spectrum(const std::string &key) const;
    Spectrum get_spectrum(const std::string &key, Spectrum def) const;
    /// Ranged reads: the value (every component of a spectrum or vector) must lie in `r`.
    float get_float(const std::string &key, Range r) const;
    float get_float(const std::string &key, float def, Range r) const;
    int get_int(const std::string &key, Range r) const;
    int get_int(const std::string &key, int def, Range r) const;
    Spectrum get_spectrum(const std::string &key, Range r) const;
    Spectrum get_spectrum(const std::string &key, Spectrum def, Range r) const;
    std::vector<float> get_floats(const std::string &key, Range r) const;
    /// A number (used for both) or a pair [a, b], each in `r`.
    std::pair<float, float> get_pair(const std::string &key, Range r) const;
    /// Texture repeat counts: "tiling": n or [n_u, n_v], each in (0, 1e6]; `def` when absent.
    std::pair<float, float> get_tiling(const std::string &key = "tiling", float def = 1.f) const;
    /// A direction: finite, not (near) zero length; returned normalized.
    Vec3 get_direction(const std::string &key) const;
    Vec3 get_direction(const std::string &key, Vec3 def) const;
    std::vector<float> get_floats(const std::string &key) const;
    /// Enumerated string parameter: the value of `key` (`def` when absent; no default: required)
    /// must be one of the names in `choices`, and gives the value paired with it. The error
    /// names the file, the JSON path and every allowed name:
    ///   p.get_enum<Dist>("distribution", "ggx", {{"ggx", Dist::GGX}, {"beckmann", Dist::Beckmann}})
    template <typename T>
    T get_enum(const std::string &key, const std::string &def,
               std::initializer_list<std::pair<const char *, T>> choices) const {
        std::vector<std::string> names;
        for (const auto &c : choices) names.push_back(c.first);
        return (choices.begin() + choice_index(key, &def, names))->second;
    }
    template <typename T>
    T get_enum(const std::string &key, std::initializer_list<std::pair<const char *, T>> choices) const {
        std::vector<std::string> names;
        for (const auto &c : choices) names.push_back(c.first);
        return (choices.begin() + choice_index(key, nullptr, names))->second;
    }
    /// A string parameter restricted to `names` (get_enum without values).
    std::string get_choice(const std::string &key, const std::string &def, const std::vector<std::string> &names) const {
        return names[size_t(choice_index(key, &def, names))];
    }
    /// Index of the string value of `key` (or *def when absent and def is given) in `names`.
    int choice_index(const std::string &key, const std::string *def, const std::vector<std::string> &names) const;
    /// A path relative to the scene file, resolved; errors if the file does not exist.
    std::string get_file(const std::string &key) const;

    /// Texture-valued parameter (number, [r,g,b], inline {"type":...} or a name).
    std::shared_ptr<Texture> get_texture(const std::string &key, Spectrum def) const;
    std::shared_ptr<Texture> get_texture(const std::string &key) const;
    /// Material-valued parameter (inline object or a name of the top-level "materials").
    std::shared_ptr<Material> get_material(const std::string &key) const;

    /// Nested object; error if missing or not an object.
    Properties child(const std::string &key) const;
    std::optional<Properties> optional_child(const std::string &key) const;
    /// Array of objects.
    std::vector<Properties> children(const std::string &key) const;
    /// Raw JSON value (marks the key read). Throws if absent.
    const nlohmann::json &raw(const std::string &key) const;
    /// Keys present in this object.
    std::vector<std::string> keys() const;

    /// Throws "file: path.key: message".
    [[noreturn]] void fail(const std::string &key, const std::string &msg) const;
    /// Throws "file: path: message".
    [[noreturn]] void fail(const std::string &msg) const;
    /// Error if any key was never read ("unknown parameter 'x' for <plugin>").
    void check_unused(const std::string &plugin_desc) const;

    std::string key_path(const std::string &key) const;

private:
    const nlohmann::json *m_obj;
    std::string m_path;
    std::shared_ptr<LoadContext> m_ctx;
    std::shared_ptr<std::set<std::string>> m_read;
    const nlohmann::json &require(const std::string &key) const;
};

}  // namespace meso
