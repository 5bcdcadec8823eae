#include "core/properties.h"
#include <cmath>
#include <filesystem>
#include <limits>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "core/input_file.h"
#include "core/registry.h"

namespace meso {

using json = nlohmann::json;

const char *json_type_name(const json &j) {
    switch (j.type()) {
        case json::value_t::null: return "null";
        case json::value_t::object: return "an object";
        case json::value_t::array: return "an array";
        case json::value_t::string: return "a string";
        case json::value_t::boolean: return "a boolean";
        case json::value_t::number_integer:
        case json::value_t::number_unsigned: return "an integer";
        case json::value_t::number_float: return "a number";
        default: return "an unsupported value";
    }
}

Properties::Properties(const json &obj, std::string path, std::shared_ptr<LoadContext> ctx)
    : m_obj(&obj), m_path(std::move(path)), m_ctx(std::move(ctx)),
      m_read(std::make_shared<std::set<std::string>>()) {
    if (!m_ctx) m_ctx = std::make_shared<LoadContext>();
    if (!obj.is_object()) throw_located(m_ctx->file, m_path, fmt::format("expected an object, got {}", json_type_name(obj)));
}
Properties::~Properties() = default;
Properties::Properties(const Properties &) = default;

std::string Properties::key_path(const std::string &key) const {
    return m_path.empty() ? key : m_path + "." + key;
}
void Properties::fail(const std::string &key, const std::string &msg) const {
    throw_located(m_ctx->file, key_path(key), msg);
}
void Properties::fail(const std::string &msg) const { throw_located(m_ctx->file, m_path, msg); }

bool Properties::has(const std::string &key) const { return m_obj->contains(key); }

const json &Properties::require(const std::string &key) const {
    auto it = m_obj->find(key);
    if (it == m_obj->end()) fail(key, "missing required parameter");
    m_read->insert(key);
    return *it;
}
const json &Properties::raw(const std::string &key) const { return require(key); }

std::vector<std::string> Properties::keys() const {
    std::vector<std::string> k;
    for (auto it = m_obj->begin(); it != m_obj->end(); ++it) k.push_back(it.key());
    return k;
}

std::string Properties::type() const {
    const json &v = require("type");
    if (!v.is_string()) fail("type", fmt::format("expected a string naming a plugin, got {}", json_type_name(v)));
    return v.get<std::string>();
}

/// A JSON number as a float: finite and within the float range (1e39 would become inf).
static bool to_float(const json &v, float &out) {
    const double d = v.get<double>();
    if (!std::isfinite(d) || std::abs(d) > double(std::numeric_limits<float>::max())) return false;
    out = float(d);
    return true;
}

float Properties::get_float(const std::string &key) const {
    const json &v = require(key);
    if (!v.is_number()) fail(key, fmt::format("expected a number, got {}", json_type_name(v)));
    float f;
    if (!to_float(v, f)) fail(key, fmt::format("expected a finite number of magnitude at most 3.4e38, got {}", v.dump()));
    return f;
}
float Properties::get_float(const std::string &key, float def) const { return has(key) ? get_float(key) : def; }

Vec3 Properties::get_position(const std::string &key, Vec3 def) const { return has(key) ? get_position(key) : def; }
Vec3 Properties::get_position(const std::string &key) const {
    const Vec3 v = get_vec3(key);
    for (int i = 0; i < 3; ++i)
        if (!(std::abs(v[i]) <= kMaxSceneCoordinate))
            fail(key, fmt::format("expected coordinates in [-{:g}, {:g}], got {:g} at index {}", kMaxSceneCoordinate,
                                  kMaxSceneCoordinate, v[i], i));
    return v;
}

int Properties::get_int(const std::string &key) const {
    const json &v = require(key);
    if (!v.is_number_integer() && !(v.is_number_float() && v.get<double>() == std::floor(v.get<double>())))
        fail(key, fmt::format("expected an integer, got {}", json_type_name(v)));
    double d = v.get<double>();
    if (d < -2147483648.0 || d > 2147483647.0) fail(key, "integer out of range");
    return int(d);
}
int Properties::get_int(const std::string &key, int def) const { return has(key) ? get_int(key) : def; }

bool Properties::get_bool(const std::string &key, bool def) const {
    if (!has(key)) return def;
    const json &v = require(key);
    if (!v.is_boolean()) fail(key, fmt::format("expected true or false, got {}", json_type_name(v)));
    return v.get<bool>();
}

std::string Properties::get_string(const std::string &key) const {
    const json &v = require(key);
    if (!v.is_string()) fail(key, fmt::format("expected a string, got {}", json_type_name(v)));
    return v.get<std::string>();
}
std::string Properties::get_string(const std::string &key, const std::string &def) const {
    return has(key) ? get_string(key) : def;
}

std::vector<float> Properties::get_floats(const std::string &key) const {
    const json &v = require(key);
    if (!v.is_array()) fail(key, fmt::format("expected an array of numbers, got {}", json_type_name(v)));
    std::vector<float> out;
    for (size_t i = 0; i < v.size(); ++i) {
        if (!v[i].is_number()) fail(key, fmt::format("element {}: expected a number, got {}", i, json_type_name(v[i])));
        float f;
        if (!to_float(v[i], f))
            fail(key, fmt::format("element {}: expected a finite number of magnitude at most 3.4e38, got {}", i, v[i].dump()));
        out.push_back(f);
    }
    return out;
}

Vec3 Properties::get_vec3(const std::string &key) const {
    const json &v = require(key);
    if (!v.is_array() || v.size() != 3) fail(key, fmt::format("expected an array of 3 numbers, got {}", json_type_name(v)));
    auto f = get_floats(key);
    return {f[0], f[1], f[2]};
}
Vec3 Properties::get_vec3(const std::string &key, Vec3 def) const { return has(key) ? get_vec3(key) : def; }

Spectrum Properties::get_spectrum(const std::string &key) const {
    const json &v = require(key);
    if (v.is_number()) {
        float f = get_float(key);
        return Spectrum(f);
    }
    if (!v.is_array() || v.size() != 3)
        fail(key, fmt::format("expected a number or an [r, g, b] array, got {}", json_type_name(v)));
    auto f = get_floats(key);
    return {f[0], f[1], f[2]};
}
Spectrum Properties::get_spectrum(const std::string &key, Spectrum def) const {
    return has(key) ? get_spectrum(key) : def;
}

std::string Range::text() const {
    if (hi >= 3.4e38 && !hi_open) return fmt::format("{} {:g}", lo_open ? "greater than" : "at least", lo);
    if (lo <= -3.4e38 && !lo_open) return fmt::format("{} {:g}", hi_open ? "less than" : "at most", hi);
    return fmt::format("{}{:g}, {:g}{}", lo_open ? '(' : '[', lo, hi, hi_open ? ')' : ']');
}

namespace {
std::string range_error(const Range &r, double v, int index, const char *noun = "a number") {
    std::string where = index >= 0 ? fmt::format(" at index {}", index) : std::string();
    if (r.hi >= 3.4e38 || r.lo <= -3.4e38) return fmt::format("expected {} {}, got {:g}{}", noun, r.text(), v, where);
    return fmt::format("expected {} in {}, got {:g}{}", noun, r.text(), v, where);
}
}  // namespace

float Properties::get_float(const std::string &key, Range r) const {
    const float f = get_float(key);
    if (!r.contains(f)) fail(key, range_error(r, f, -1));
    return f;
}
float Properties::get_float(const std::string &key, float def, Range r) const { return has(key) ? get_float(key, r) : def; }

int Properties::get_int(const std::string &key, Range r) const {
    const int i = get_int(key);
    if (!r.contains(i)) fail(key, range_error(r, i, -1, "an integer"));
    return i;
}
int Properties::get_int(const std::string &key, int def, Range r) const { return has(key) ? get_int(key, r) : def; }

Spectrum Properties::get_spectrum(const std::string &key, Range r) const {
    const Spectrum s = get_spectrum(key);
    const bool grey = raw(key).is_number();
    for (int c = 0; c < 3; ++c)
        if (!r.contains(s[c])) fail(key, range_error(r, s[c], grey ? -1 : c));
    return s;
}
Spectrum Properties::get_spectrum(const std::string &key, Spectrum def, Range r) const {
    return has(key) ? get_spectrum(key, r) : def;
}

std::vector<float> Properties::get_floats(const std::string &key, Range r) const {
    std::vector<float> v = get_floats(key);
    for (size_t i = 0; i < v.size(); ++i)
        if (!r.contains(v[i])) fail(key, range_error(r, v[i], int(i)));
    return v;
}

std::pair<float, float> Properties::get_pair(const std::string &key, Range r) const {
    if (raw(key).is_number()) {
        const float v = get_float(key, r);
        return {v, v};
    }
    const json &v = raw(key);
    if (!v.is_array() || v.size() != 2) fail(key, fmt::format("expected a number or a pair [a, b], got {}", json_type_name(v)));
    const std::vector<float> f = get_floats(key, r);
    return {f[0], f[1]};
}

std::pair<float, float> Properties::get_tiling(const std::string &key, float def) const {
    return has(key) ? get_pair(key, Range::positive(1e6)) : std::pair<float, float>{def, def};
}

Vec3 Properties::get_direction(const std::string &key) const {
    const Vec3 v = get_vec3(key);
    const double len = std::sqrt(double(v.x) * v.x + double(v.y) * v.y + double(v.z) * v.z);
    if (!(len > 1e-30) || !std::isfinite(len))
        fail(key, fmt::format("expected a direction (a vector of non-zero finite length), got [{:g}, {:g}, {:g}]", v.x,
                              v.y, v.z));
    return Vec3(float(v.x / len), float(v.y / len), float(v.z / len));
}
Vec3 Properties::get_direction(const std::string &key, Vec3 def) const { return has(key) ? get_direction(key) : def; }

std::string Properties::get_file(const std::string &key) const {
    std::string name = get_string(key);
    namespace fs = std::filesystem;
    fs::path p(name);
    if (p.is_relative() && !m_ctx->base_dir.empty()) p = fs::path(m_ctx->base_dir) / p;
    std::error_code ec;
    if (!fs::exists(p, ec)) fail(key, fmt::format("file not found: '{}'", p.string()));
    if (fs::is_directory(p, ec)) fail(key, fmt::format("expected a file, got a directory: '{}'", p.string()));
    // Devices and pipes (/dev/zero) would block or never end: only regular files (size limits
    // are checked by the reader, which knows the kind of file).
    if (std::string why = input_file_problem(p.string(), UINT64_MAX, "file"); !why.empty())
        fail(key, fmt::format("'{}': {}", p.string(), why));
    return p.string();
}

Properties Properties::child(const std::string &key) const {
    const json &v = require(key);
    if (!v.is_object()) fail(key, fmt::format("expected an object, got {}", json_type_name(v)));
    return Properties(v, key_path(key), m_ctx);
}
std::optional<Properties> Properties::optional_child(const std::string &key) const {
    if (!has(key)) return std::nullopt;
    return child(key);
}
std::vector<Properties> Properties::children(const std::string &key) const {
    const json &v = require(key);
    if (!v.is_array()) fail(key, fmt::format("expected an array of objects, got {}", json_type_name(v)));
    std::vector<Properties> out;
    for (size_t i = 0; i < v.size(); ++i) {
        std::string p = fmt::format("{}[{}]", key_path(key), i);
        if (!v[i].is_object()) throw_located(m_ctx->file, p, fmt::format("expected an object, got {}", json_type_name(v[i])));
        out.emplace_back(v[i], p, m_ctx);
    }
    return out;
}

/// Builds (once) the named object `name` of the top-level section `decls` ("textures",
/// "materials"), caching it in `cache`.
template <typename T, typename Create>
static std::shared_ptr<T> named_object(const Properties &from, const std::string &key, const std::string &name,
                                       const char *section, const json *decls,
                                       std::map<std::string, std::shared_ptr<T>> &cache, Create create) {
    auto it = cache.find(name);
    if (it != cache.end()) return it->second;
    LoadContext &ctx = from.context();
    if (!decls || !decls->is_object() || !decls->contains(name))
        from.fail(key, fmt::format("no {} named '{}' (declare it in the top-level \"{}\" object)",
                                   std::string(section).substr(0, std::string(section).size() - 1), name, section));
    if (ctx.building.count(name)) from.fail(key, fmt::format("'{}' refers to itself", name));
    ctx.building.insert(name);
    Properties p((*decls)[name], std::string(section) + "." + name, from.context_ptr());
    auto obj = create(p);
    ctx.building.erase(name);
    cache[name] = obj;
    return obj;
}

std::shared_ptr<Texture> Properties::get_texture(const std::string &key, Spectrum def) const {
    if (!has(key)) return make_constant_texture(def);
    return get_texture(key);
}

std::shared_ptr<Texture> Properties::get_texture(const std::string &key) const {
    const json &v = require(key);
    if (v.is_number() || v.is_array()) {
        Spectrum s = get_spectrum(key);
        return make_constant_texture(s);
    }
    if (v.is_object()) return create_texture(child(key));
    if (v.is_string())
        return named_object<Texture>(*this, key, v.get<std::string>(), "textures", m_ctx->texture_decls,
                                     m_ctx->textures, [](const Properties &p) { return create_texture(p); });
    fail(key, fmt::format("expected a number, an [r, g, b] array, a texture object or a texture name, got {}",
                          json_type_name(v)));
}

std::shared_ptr<Material> Properties::get_material(const std::string &key) const {
    const json &v = require(key);
    if (v.is_object()) return create_material(child(key));
    if (v.is_string())
        return named_object<Material>(*this, key, v.get<std::string>(), "materials", m_ctx->material_decls,
                                      m_ctx->materials, [](const Properties &p) { return create_material(p); });
    fail(key, fmt::format("expected a material object or a material name, got {}", json_type_name(v)));
}

void Properties::check_unused(const std::string &plugin_desc) const {
    for (auto it = m_obj->begin(); it != m_obj->end(); ++it) {
        if (!m_read->count(it.key()))
            fail(it.key(), fmt::format("unknown parameter '{}' for {}", it.key(), plugin_desc));
    }
}

std::string quoted_choices(const std::vector<std::string> &names) {
    std::string out;
    for (size_t i = 0; i < names.size(); ++i) {
        if (i > 0) out += i + 1 == names.size() ? " or " : ", ";
        out += "\"" + names[i] + "\"";
    }
    return out;
}

int parse_choice(const std::string &what, const std::string &value, const std::vector<std::string> &names) {
    for (size_t i = 0; i < names.size(); ++i)
        if (names[i] == value) return int(i);
    throw UsageError(fmt::format("{}: expected {}, got \"{}\"", what, quoted_choices(names), value));
}

int Properties::choice_index(const std::string &key, const std::string *def, const std::vector<std::string> &names) const {
    const std::string v = def ? get_string(key, *def) : get_string(key);
    for (size_t i = 0; i < names.size(); ++i)
        if (names[i] == v) return int(i);
    fail(key, fmt::format("expected {}, got \"{}\"", quoted_choices(names), v));
}

}  // namespace meso
