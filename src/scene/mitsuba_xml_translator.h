// Internal to the Mitsuba 3 XML translator (mitsuba_xml.cpp: files, properties, transforms,
// the scene; mitsuba_xml_objects.cpp: BSDFs, textures, shapes, emitters).
#pragma once
#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <deque>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <pugixml.hpp>
#include "core/error.h"
#include "core/properties.h"
#include "core/transform.h"

namespace meso::mitsuba_detail {

using json = nlohmann::json;


/// One XML file of the scene (the main file or an <include>).
struct Source {
    std::string path;        ///< as given (for messages)
    std::string dir_prefix;  ///< its directory relative to the main file's ("" for the main file)
    std::string text;
    pugi::xml_document doc;
};

/// A plugin element (<bsdf type="diffuse">): named properties and unnamed nested objects.
struct Element {
    pugi::xml_node node;
    std::string tag, type;
    struct Prop {
        pugi::xml_node node;
        bool used = false;
    };
    std::map<std::string, Prop> props;
    std::vector<pugi::xml_node> nested;  ///< children without a name: bsdf, emitter, film, ref, ...
    std::vector<std::string> asked;      ///< property names the translation looked for
};

/// One operation of a <transform>, applied in document order.
struct TransformOp {
    enum Kind { Scale, Rotate, Translate, Matrix, LookAt } kind;
    Vec3 a, b, c;  ///< scale / axis / offset; look_at origin, target, up
    float angle = 0;
    bool uniform = false;  ///< a scale given as one value
    std::vector<float> matrix;
};

struct XmlTransform {
    pugi::xml_node node;
    std::vector<TransformOp> ops;
    Transform m;  ///< the composition
};

const char *const kPropertyTags[] = {"float", "integer", "boolean", "string", "rgb", "spectrum", "vector", "point", "transform"};
constexpr double kPi = 3.14159265358979323846;
const char *const kMesoTopLevel[] = {"camera", "integrator", "sampler", "textures", "materials", "shapes", "lights"};

inline bool is_one_of(const std::string &s, std::initializer_list<const char *> names) {
    for (const char *n : names)
        if (s == n) return true;
    return false;
}

inline std::string lower(std::string s) {
    for (char &c : s) c = char(std::tolower(static_cast<unsigned char>(c)));
    return s;
}

/// A float as the double of its shortest decimal form: what the XML said ("0.99", not
/// 0.9900000095367432), and exactly the float meso reads back.
inline json num(float f) { return std::strtod(fmt::format("{}", f).c_str(), nullptr); }
inline json vec3_json(Vec3 v) { return json::array({num(v.x), num(v.y), num(v.z)}); }

class Translator {
public:
    json translate(const std::string &path, std::vector<std::string> *overrides);

private:
    // --- files, locations, messages
    Source &load(const std::string &path, const std::string &dir_prefix, const pugi::xml_node *from);
    const Source &source_of(const pugi::xml_node &n) const;
    size_t line_of(const pugi::xml_node &n) const;
    std::string describe(const pugi::xml_node &n) const;
    [[noreturn]] void fail(const pugi::xml_node &n, const std::string &msg) const;
    void note(const pugi::xml_node &n, const std::string &msg) const;
    // --- attributes and values
    std::string substitute(const pugi::xml_node &n, const std::string &value);
    bool has_attr(const pugi::xml_node &n, const char *name) const { return bool(n.attribute(name)); }
    std::string attr(const pugi::xml_node &n, const char *name);
    double number(const pugi::xml_node &n, const std::string &text);
    std::vector<double> numbers(const pugi::xml_node &n, const char *name);
    Vec3 vec3_attr(const pugi::xml_node &n, const char *name);
    Vec3 xyz(const pugi::xml_node &n, double def);
    std::string file_name(const pugi::xml_node &n, const std::string &value) const;
    // --- elements and their properties
    Element element(const pugi::xml_node &n);
    Element::Prop *take(Element &e, const std::string &name, std::initializer_list<const char *> tags);
    std::optional<double> get_float(Element &e, const std::string &name);
    std::optional<long long> get_int(Element &e, const std::string &name);
    std::optional<bool> get_bool(Element &e, const std::string &name);
    std::optional<std::string> get_string(Element &e, const std::string &name);
    std::optional<json> get_spectrum(Element &e, const std::string &name);
    std::optional<json> get_texture(Element &e, const std::string &name);
    std::optional<Vec3> get_vec3(Element &e, const std::string &name);
    std::optional<XmlTransform> get_transform(Element &e, const std::string &name);
    json spectrum_value(const pugi::xml_node &n);
    XmlTransform transform(const pugi::xml_node &n);
    json to_world_json(const XmlTransform &t) const;
    void ignore(Element &e, const std::string &name, const std::string &why);
    void finish(Element &e) const;
    void unsupported(const Element &e, const char *what, const std::vector<std::string> &supported) const;
    // --- plugins
    void top_level(const pugi::xml_node &n);
    void sensor(const pugi::xml_node &n);
    void film(const pugi::xml_node &n, json &camera, double &aspect);
    json sampler(const pugi::xml_node &n);
    void integrator(const pugi::xml_node &n);
    json bsdf(const pugi::xml_node &n);
    json bsdf_object(Element &e);
    json wrapped_bsdf(Element &e);
    std::string bitmap_file(const pugi::xml_node &n, XmlTransform *to_uv);
    json texture(const pugi::xml_node &n);
    json ref(const pugi::xml_node &n, const char *tag);
    void shape(const pugi::xml_node &n);
    json emitter(const pugi::xml_node &n, bool in_shape);
    void register_id(const pugi::xml_node &n, const std::string &tag, const json &value);

    std::deque<Source> m_sources;
    std::vector<std::string> m_include_stack;
    std::map<std::string, std::string> m_params;  ///< <default> and -D values
    std::map<std::string, std::string> m_cli;     ///< -D values (they win over <default>)
    std::set<std::string> m_params_used;
    std::map<std::string, std::pair<std::string, json>> m_ids;  ///< id → (tag, what a reference becomes)
    json m_out = json::object();
};

}  // namespace meso::mitsuba_detail
