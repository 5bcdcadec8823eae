// Mitsuba 3 XML → meso scene JSON (see mitsuba_xml.h and docs/scene-format.md, "Mitsuba 3
// XML scenes"). One Translator walks the element tree: every plugin element becomes an
// Element (its named properties and unnamed nested objects); the plugin's translation takes
// the properties it knows, and finish() turns any property left over into an error naming
// the file, the line and the element. meso's parameter names already follow Mitsuba 3, so
// most properties keep their names; where defaults differ (rough* distributions, bitmap
// filtering, sampler and film sizes) Mitsuba's are written out.
#include "scene/mitsuba_xml.h"
#include "scene/mitsuba_xml_translator.h"
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

namespace meso {

using json = nlohmann::json;
namespace fs = std::filesystem;

namespace mitsuba_detail {


// ---------------------------------------------------------------------------------------
// Files, locations, messages

Source &Translator::load(const std::string &path, const std::string &dir_prefix, const pugi::xml_node *from) {
    std::error_code ec;
    std::ifstream f(path, std::ios::binary);
    if (!f || fs::is_directory(path, ec)) {
        std::string why = fs::exists(path, ec) ? "cannot be read" : "file not found";
        if (from) fail(*from, fmt::format("{}: {}", path, why));
        throw MesoError(fmt::format("{}: {}", path, why));
    }
    std::ostringstream ss;
    ss << f.rdbuf();
    Source &s = m_sources.emplace_back();
    s.path = path;
    s.dir_prefix = dir_prefix;
    s.text = ss.str();
    pugi::xml_parse_result r = s.doc.load_buffer(s.text.data(), s.text.size(), pugi::parse_default, pugi::encoding_utf8);
    if (!r) {
        size_t line = 1 + size_t(std::count(s.text.begin(), s.text.begin() + std::min<ptrdiff_t>(r.offset, ptrdiff_t(s.text.size())), '\n'));
        throw MesoError(fmt::format("{}: line {}: cannot parse XML: {}", path, line, r.description()));
    }
    pugi::xml_node root = s.doc.document_element();
    if (std::string(root.name()) != "scene")
        throw MesoError(fmt::format("{}: line {}: expected a <scene> root element, got <{}>", path, line_of(root), root.name()));
    std::string version = root.attribute("version").value();
    if (!version.empty() && std::atoi(version.c_str()) < 2)
        fail(root, fmt::format("version {}: a Mitsuba 0.x scene (camelCase names); meso reads Mitsuba 3 scenes (upgrade it "
                               "with Mitsuba 3's `mitsuba.xml.upgrade`)", version));
    return s;
}

const Source &Translator::source_of(const pugi::xml_node &n) const {
    pugi::xml_node root = n.root();
    for (const Source &s : m_sources)
        if (s.doc == root) return s;
    return m_sources.front();
}

size_t Translator::line_of(const pugi::xml_node &n) const {
    const Source &s = source_of(n);
    ptrdiff_t off = n.offset_debug();
    if (off < 0) return 0;
    return 1 + size_t(std::count(s.text.begin(), s.text.begin() + std::min<ptrdiff_t>(off, ptrdiff_t(s.text.size())), '\n'));
}

std::string Translator::describe(const pugi::xml_node &n) const {
    std::string d = fmt::format("<{}", n.name());
    for (const char *a : {"type", "name", "id"})
        if (n.attribute(a)) d += fmt::format(" {}=\"{}\"", a, n.attribute(a).value());
    return d + ">";
}

void Translator::fail(const pugi::xml_node &n, const std::string &msg) const {
    throw MesoError(fmt::format("{}: line {}: {}: {}", source_of(n).path, line_of(n), describe(n), msg));
}

void Translator::note(const pugi::xml_node &n, const std::string &msg) const {
    fmt::print(stderr, "{}: line {}: note: {}: {}\n", source_of(n).path, line_of(n), describe(n), msg);
}

// ---------------------------------------------------------------------------------------
// Attributes and values

std::string Translator::substitute(const pugi::xml_node &n, const std::string &value) {
    std::string out;
    for (size_t i = 0; i < value.size(); ++i) {
        if (value[i] != '$') {
            out += value[i];
            continue;
        }
        size_t j = i + 1;
        while (j < value.size() && (std::isalnum(static_cast<unsigned char>(value[j])) || value[j] == '_')) ++j;
        std::string name = value.substr(i + 1, j - i - 1);
        auto it = m_params.find(name);
        if (name.empty() || it == m_params.end())
            fail(n, fmt::format("undefined parameter '${}' (declare <default name=\"{}\" value=\"...\"/> or pass -D {}=...)",
                                name, name, name));
        m_params_used.insert(name);
        out += it->second;
        i = j - 1;
    }
    return out;
}

std::string Translator::attr(const pugi::xml_node &n, const char *name) {
    pugi::xml_attribute a = n.attribute(name);
    if (!a) fail(n, fmt::format("missing the attribute '{}'", name));
    return substitute(n, a.value());
}

double Translator::number(const pugi::xml_node &n, const std::string &text) {
    const char *s = text.c_str();
    char *end = nullptr;
    double v = std::strtod(s, &end);
    while (end && *end && std::isspace(static_cast<unsigned char>(*end))) ++end;
    if (end == s || (end && *end) || !std::isfinite(v)) fail(n, fmt::format("expected a number, got '{}'", text));
    return v;
}

std::vector<double> Translator::numbers(const pugi::xml_node &n, const char *name) {
    std::string text = attr(n, name);
    for (char &c : text)
        if (c == ',') c = ' ';
    std::istringstream in(text);
    std::vector<double> v;
    std::string word;
    while (in >> word) v.push_back(number(n, word));
    return v;
}

Vec3 Translator::vec3_attr(const pugi::xml_node &n, const char *name) {
    std::vector<double> v = numbers(n, name);
    if (v.size() != 3) fail(n, fmt::format("attribute '{}': expected 3 numbers, got {}", name, v.size()));
    return Vec3(float(v[0]), float(v[1]), float(v[2]));
}

/// x/y/z attributes (missing ones are `def`) or value="x, y, z".
Vec3 Translator::xyz(const pugi::xml_node &n, double def) {
    if (has_attr(n, "value")) return vec3_attr(n, "value");
    double c[3];
    const char *names[3] = {"x", "y", "z"};
    for (int i = 0; i < 3; ++i) c[i] = has_attr(n, names[i]) ? number(n, attr(n, names[i])) : def;
    return Vec3(float(c[0]), float(c[1]), float(c[2]));
}

/// A file name of an included file, made relative to the main file's directory.
std::string Translator::file_name(const pugi::xml_node &n, const std::string &value) const {
    const Source &s = source_of(n);
    if (s.dir_prefix.empty() || fs::path(value).is_absolute()) return value;
    return (fs::path(s.dir_prefix) / value).lexically_normal().generic_string();
}

// ---------------------------------------------------------------------------------------
// Elements and properties

Element Translator::element(const pugi::xml_node &n) {
    Element e;
    e.node = n;
    e.tag = n.name();
    if (has_attr(n, "type")) e.type = attr(n, "type");
    for (pugi::xml_node c : n.children()) {
        if (c.type() != pugi::node_element) continue;
        std::string tag = c.name();
        bool property = false;
        for (const char *t : kPropertyTags) property = property || tag == t;
        if (property && !has_attr(c, "name")) fail(c, "a property needs a 'name' attribute");
        if (property || (has_attr(c, "name") && is_one_of(tag, {"texture", "bsdf", "ref"}))) {
            std::string name = attr(c, "name");
            if (!e.props.emplace(name, Element::Prop{c, false}).second)
                fail(c, fmt::format("property '{}' given twice in {}", name, describe(n)));
        } else if (is_one_of(tag, {"bsdf", "texture", "emitter", "sampler", "film", "rfilter", "ref", "sensor", "shape",
                                   "integrator", "medium", "phase", "volume"})) {
            e.nested.push_back(c);
        } else {
            fail(c, fmt::format("unknown element <{}> in {}", tag, describe(n)));
        }
    }
    return e;
}

Element::Prop *Translator::take(Element &e, const std::string &name, std::initializer_list<const char *> tags) {
    e.asked.push_back(name);
    auto it = e.props.find(name);
    if (it == e.props.end()) return nullptr;
    it->second.used = true;
    std::string tag = it->second.node.name();
    if (!is_one_of(tag, tags)) {
        std::vector<std::string> want;
        for (const char *t : tags) want.push_back(fmt::format("<{}>", t));
        fail(it->second.node, fmt::format("property '{}' of {}: expected {}, got <{}>", name, describe(e.node),
                                          fmt::join(want, " or "), tag));
    }
    return &it->second;
}

std::optional<double> Translator::get_float(Element &e, const std::string &name) {
    Element::Prop *p = take(e, name, {"float", "integer"});
    if (!p) return std::nullopt;
    return number(p->node, attr(p->node, "value"));
}

std::optional<long long> Translator::get_int(Element &e, const std::string &name) {
    Element::Prop *p = take(e, name, {"integer"});
    if (!p) return std::nullopt;
    double v = number(p->node, attr(p->node, "value"));
    if (v != std::floor(v) || std::fabs(v) > 9e15) fail(p->node, "expected an integer");
    return (long long)v;
}

std::optional<bool> Translator::get_bool(Element &e, const std::string &name) {
    Element::Prop *p = take(e, name, {"boolean"});
    if (!p) return std::nullopt;
    std::string v = lower(attr(p->node, "value"));
    if (v != "true" && v != "false") fail(p->node, fmt::format("expected true or false, got '{}'", v));
    return v == "true";
}

std::optional<std::string> Translator::get_string(Element &e, const std::string &name) {
    Element::Prop *p = take(e, name, {"string"});
    if (!p) return std::nullopt;
    return attr(p->node, "value");
}

/// <rgb value="r, g, b"> or one value; <spectrum value="v"> (uniform); <float value="v">.
json Translator::spectrum_value(const pugi::xml_node &n) {
    std::string tag = n.name();
    if (tag == "spectrum" && !has_attr(n, "value"))
        fail(n, "only a uniform <spectrum value=\"v\"/> is read (meso renders in RGB; give an <rgb>)");
    if (tag == "spectrum" && attr(n, "value").find(':') != std::string::npos)
        fail(n, "wavelength:value spectra are not supported (meso renders in RGB; give an <rgb>)");
    std::vector<double> v = numbers(n, "value");
    if (v.size() == 1) return v[0];
    if (v.size() == 3 && tag == "rgb") return json::array({v[0], v[1], v[2]});
    fail(n, fmt::format("expected {}, got {} numbers", tag == "rgb" ? "1 or 3 numbers" : "one number", v.size()));
}

std::optional<json> Translator::get_spectrum(Element &e, const std::string &name) {
    Element::Prop *p = take(e, name, {"rgb", "spectrum", "float", "integer"});
    if (!p) return std::nullopt;
    return spectrum_value(p->node);
}

std::optional<json> Translator::get_texture(Element &e, const std::string &name) {
    Element::Prop *p = take(e, name, {"rgb", "spectrum", "float", "integer", "texture", "ref"});
    if (!p) return std::nullopt;
    std::string tag = p->node.name();
    if (tag == "texture") return texture(p->node);
    if (tag == "ref") return ref(p->node, "texture");
    return spectrum_value(p->node);
}

std::optional<Vec3> Translator::get_vec3(Element &e, const std::string &name) {
    Element::Prop *p = take(e, name, {"vector", "point"});
    if (!p) return std::nullopt;
    return xyz(p->node, 0.0);
}

std::optional<XmlTransform> Translator::get_transform(Element &e, const std::string &name) {
    Element::Prop *p = take(e, name, {"transform"});
    if (!p) return std::nullopt;
    return transform(p->node);
}

XmlTransform Translator::transform(const pugi::xml_node &n) {
    XmlTransform t;
    t.node = n;
    for (pugi::xml_node c : n.children()) {
        if (c.type() != pugi::node_element) continue;
        std::string tag = c.name();
        TransformOp op{TransformOp::Scale, {}, {}, {}, 0.f, false, {}};
        Transform step;
        try {
            if (tag == "scale") {
                if (has_attr(c, "value") && numbers(c, "value").size() == 1) {
                    op.uniform = true;
                    float s = float(number(c, attr(c, "value")));
                    op.a = Vec3(s, s, s);
                } else {
                    op.a = xyz(c, 1.0);
                }
                step = Transform::scale(op.a);
            } else if (tag == "translate") {
                op.kind = TransformOp::Translate;
                op.a = xyz(c, 0.0);
                step = Transform::translate(op.a);
            } else if (tag == "rotate") {
                op.kind = TransformOp::Rotate;
                op.a = xyz(c, 0.0);
                op.angle = float(number(c, attr(c, "angle")));
                step = Transform::rotate(op.a, op.angle);
            } else if (tag == "matrix") {
                op.kind = TransformOp::Matrix;
                std::vector<double> v = numbers(c, "value");
                if (v.size() == 9) v = {v[0], v[1], v[2], 0, v[3], v[4], v[5], 0, v[6], v[7], v[8], 0, 0, 0, 0, 1};
                if (v.size() != 16) fail(c, fmt::format("expected 16 (or 9) numbers, row-major, got {}", v.size()));
                op.matrix.assign(v.begin(), v.end());
                step = Transform::from_matrix(op.matrix.data());
            } else if (tag == "lookat") {
                op.kind = TransformOp::LookAt;
                op.a = vec3_attr(c, "origin");
                op.b = vec3_attr(c, "target");
                op.c = has_attr(c, "up") ? vec3_attr(c, "up") : Vec3(0, 1, 0);
                step = Transform::look_at(op.a, op.b, op.c);
            } else {
                fail(c, "unsupported transform operation (expected <translate>, <scale>, <rotate>, <matrix> or <lookat>)");
            }
        } catch (const MesoError &err) {
            std::string what = err.what();
            if (what.find(source_of(c).path + ": line") == 0) throw;
            fail(c, what);
        }
        t.ops.push_back(op);
        t.m = step * t.m;
    }
    return t;
}

/// meso's to_world object: look_at alone, or scale → rotate(s) → translate when the
/// operations come in that order (meso composes them the same way), else the matrix.
json Translator::to_world_json(const XmlTransform &t) const {
    if (t.ops.size() == 1 && t.ops[0].kind == TransformOp::LookAt)
        return {{"look_at", {{"origin", vec3_json(t.ops[0].a)}, {"target", vec3_json(t.ops[0].b)}, {"up", vec3_json(t.ops[0].c)}}}};
    int stage = 0;  // 0 start, 1 after scale, 2 in rotations, 3 after translate
    bool structured = true;
    for (const TransformOp &op : t.ops) {
        int s = op.kind == TransformOp::Scale ? 1 : op.kind == TransformOp::Rotate ? 2 : op.kind == TransformOp::Translate ? 3 : 9;
        if (s == 9 || s < stage || (s == stage && s != 2)) structured = false;
        stage = s;
    }
    json j = json::object();
    if (!structured) {
        json m = json::array();
        for (int r = 0; r < 4; ++r)
            for (int c = 0; c < 4; ++c) m.push_back(num(t.m.m[r][c]));
        j["matrix"] = m;
        return j;
    }
    json rotations = json::array();
    for (const TransformOp &op : t.ops) {
        if (op.kind == TransformOp::Scale) j["scale"] = op.uniform ? num(op.a.x) : vec3_json(op.a);
        if (op.kind == TransformOp::Translate) j["translate"] = vec3_json(op.a);
        if (op.kind == TransformOp::Rotate) rotations.push_back({{"axis", vec3_json(op.a)}, {"angle", num(op.angle)}});
    }
    if (rotations.size() == 1) j["rotate"] = rotations[0];
    if (rotations.size() > 1) j["rotate"] = rotations;
    return j;
}

void Translator::ignore(Element &e, const std::string &name, const std::string &why) {
    auto it = e.props.find(name);
    if (it == e.props.end()) return;
    it->second.used = true;
    note(it->second.node, fmt::format("ignored ({})", why));
}

void Translator::finish(Element &e) const {
    for (const auto &[name, p] : e.props) {
        if (p.used) continue;
        std::vector<std::string> asked = e.asked;
        std::sort(asked.begin(), asked.end());
        asked.erase(std::unique(asked.begin(), asked.end()), asked.end());
        fail(p.node, fmt::format("unsupported property '{}' of {} (meso reads {})", name, describe(e.node),
                                 asked.empty() ? std::string("none") : quoted_choices(asked)));
    }
}

void Translator::unsupported(const Element &e, const char *what, const std::vector<std::string> &supported) const {
    fail(e.node, fmt::format("unsupported {} type '{}' (meso reads {})", what, e.type, quoted_choices(supported)));
}

void Translator::register_id(const pugi::xml_node &n, const std::string &tag, const json &value) {
    if (!has_attr(n, "id")) return;
    std::string id = n.attribute("id").value();
    if (!m_ids.emplace(id, std::make_pair(tag, value)).second) fail(n, fmt::format("a second object with id '{}'", id));
}

json Translator::ref(const pugi::xml_node &n, const char *tag) {
    std::string id = attr(n, "id");
    auto it = m_ids.find(id);
    if (it == m_ids.end()) fail(n, fmt::format("no {} with id '{}' before this line", tag, id));
    if (it->second.first != tag)
        fail(n, fmt::format("id '{}' is a <{}>, not a <{}>", id, it->second.first, tag));
    return it->second.second;
}

// ---------------------------------------------------------------------------------------
// Sensor, film, sampler, integrator

void Translator::film(const pugi::xml_node &n, json &camera, double &aspect) {
    Element e = element(n);
    if (e.type != "hdrfilm") unsupported(e, "film", {"hdrfilm"});
    long long w = get_int(e, "width").value_or(768), h = get_int(e, "height").value_or(576);
    camera["width"] = w;
    camera["height"] = h;
    aspect = double(w) / double(h);
    for (const char *p : {"pixel_format", "component_format", "file_format", "banner", "high_quality_edges", "sample_border"})
        ignore(e, p, "meso writes linear float RGB EXR and an sRGB PNG");
    for (pugi::xml_node c : e.nested) {
        if (std::string(c.name()) == "rfilter") note(c, "ignored (meso's pixel filter is a box)");
        else fail(c, "unexpected inside <film> (expected <rfilter>)");
    }
    finish(e);
}

json Translator::sampler(const pugi::xml_node &n) {
    Element e = element(n);
    if (e.type != "independent" && e.type != "stratified") unsupported(e, "sampler", {"independent", "stratified"});
    // stratified → sobol: Owen-scrambled Sobol' points are stratified in every dimension.
    json s = {{"type", e.type == "stratified" ? "sobol" : "independent"},
              {"sample_count", get_int(e, "sample_count").value_or(4)}};
    if (auto seed = get_int(e, "seed")) s["seed"] = *seed;
    if (e.type == "stratified") ignore(e, "jitter", "meso's sobol sampler is always randomised");
    for (pugi::xml_node c : e.nested) fail(c, "unexpected inside <sampler>");
    finish(e);
    return s;
}

void Translator::sensor(const pugi::xml_node &n) {
    Element e = element(n);
    if (e.type != "perspective") unsupported(e, "sensor", {"perspective"});
    if (m_out.contains("camera")) fail(n, "a second <sensor>: meso renders from one camera");
    json cam = {{"type", "perspective"}};
    double aspect = 768.0 / 576.0;
    cam["width"] = 768;
    cam["height"] = 576;
    m_out["sampler"] = {{"type", "independent"}, {"sample_count", 4}};
    for (pugi::xml_node c : e.nested) {
        std::string tag = c.name();
        if (tag == "film") film(c, cam, aspect);
        else if (tag == "sampler") m_out["sampler"] = sampler(c);
        else fail(c, "unexpected inside <sensor> (expected <film> or <sampler>)");
    }
    // Field of view, as Mitsuba 3's parse_fov: meso takes "x" and "y"; the others are converted.
    std::optional<double> fov = get_float(e, "fov");
    std::optional<std::string> axis = get_string(e, "fov_axis"), focal = get_string(e, "focal_length");
    if (fov && focal) fail(n, "give either 'fov' or 'focal_length', not both");
    std::string ax = lower(axis.value_or("x"));
    if (!fov) {  // 35 mm film equivalent, along the diagonal
        std::string f = focal.value_or("50mm");
        if (f.size() > 2 && f.substr(f.size() - 2) == "mm") f = f.substr(0, f.size() - 2);
        double mm = number(n, f);
        fov = 2.0 * std::atan(std::sqrt(36.0 * 36.0 + 24.0 * 24.0) / (2.0 * mm)) * 180.0 / kPi;
        ax = "diagonal";
    }
    if (ax == "smaller") ax = aspect > 1 ? "y" : "x";
    if (ax == "larger") ax = aspect > 1 ? "x" : "y";
    if (ax == "diagonal") {
        double diagonal = 2.0 * std::tan(0.5 * *fov * kPi / 180.0);
        double width = diagonal / std::sqrt(1.0 + 1.0 / (aspect * aspect));
        fov = 2.0 * std::atan(0.5 * width) * 180.0 / kPi;
        ax = "x";
    }
    if (ax != "x" && ax != "y") fail(n, fmt::format("fov_axis '{}': expected x, y, smaller, larger or diagonal", ax));
    cam["fov"] = *fov;
    cam["fov_axis"] = ax;
    // Placement: look_at verbatim, or origin, +z and +y of the composed transform.
    if (std::optional<XmlTransform> t = get_transform(e, "to_world")) {
        if (t->ops.size() == 1 && t->ops[0].kind == TransformOp::LookAt) {
            cam["origin"] = vec3_json(t->ops[0].a);
            cam["target"] = vec3_json(t->ops[0].b);
            cam["up"] = vec3_json(t->ops[0].c);
        } else {
            if (t->m.det3() < 0.f)
                fail(t->node, "a mirroring camera transform (e.g. <scale x=\"-1\"/>) is not supported (meso's camera is a look-at)");
            Vec3 o = t->m.apply_point(Vec3(0, 0, 0));
            cam["origin"] = vec3_json(o);
            cam["target"] = vec3_json(o + normalize(t->m.apply_vector(Vec3(0, 0, 1))));
            cam["up"] = vec3_json(normalize(t->m.apply_vector(Vec3(0, 1, 0))));
        }
    } else {
        cam["target"] = json::array({0, 0, 1});  // Mitsuba's sensor looks along +z by default
    }
    ignore(e, "near_clip", "meso's camera has no clipping planes");
    ignore(e, "far_clip", "meso's camera has no clipping planes");
    ignore(e, "focus_distance", "a pinhole camera is in focus everywhere");
    finish(e);
    m_out["camera"] = cam;
}

void Translator::integrator(const pugi::xml_node &n) {
    Element e = element(n);
    if (m_out.contains("integrator")) fail(n, "a second <integrator>");
    json j = {{"type", e.type}};
    if (e.type == "path") {
        if (auto v = get_int(e, "max_depth")) j["max_depth"] = *v;
        if (auto v = get_int(e, "rr_depth")) j["rr_depth"] = *v;
    } else if (e.type == "direct") {
        for (const char *p : {"emitter_samples", "bsdf_samples", "shading_samples"})
            ignore(e, p, "meso's direct takes one light and one BSDF sample a pass: raise the spp instead");
        for (const char *p : {"max_depth", "rr_depth"}) ignore(e, p, "direct lighting is two path segments");
    } else {
        unsupported(e, "integrator", {"path", "direct"});
    }
    if (auto v = get_bool(e, "hide_emitters")) j["hide_emitters"] = *v;
    for (pugi::xml_node c : e.nested) fail(c, "unexpected inside <integrator>");
    finish(e);
    m_out["integrator"] = j;
}

// ---------------------------------------------------------------------------------------
// The scene

void Translator::top_level(const pugi::xml_node &n) {
    std::string tag = n.name();
    if (tag == "default") {
        std::string name = n.attribute("name").value();
        if (name.empty() || !has_attr(n, "value")) fail(n, "expected name=\"...\" and value=\"...\"");
        if (!m_cli.count(name)) m_params[name] = n.attribute("value").value();
    } else if (tag == "include") {
        std::string file = attr(n, "filename");
        const Source &here = source_of(n);
        fs::path p = fs::path(here.path).parent_path() / file;
        std::string key = fs::weakly_canonical(p).string();
        if (std::find(m_include_stack.begin(), m_include_stack.end(), key) != m_include_stack.end())
            fail(n, "the file includes itself");
        std::string prefix = fs::path(file_name(n, file)).parent_path().generic_string();
        Source &s = load(p.string(), prefix, &n);
        m_include_stack.push_back(key);
        for (pugi::xml_node c : s.doc.document_element().children())
            if (c.type() == pugi::node_element) top_level(c);
        m_include_stack.pop_back();
    } else if (tag == "sensor") {
        sensor(n);
    } else if (tag == "integrator") {
        integrator(n);
    } else if (tag == "shape") {
        shape(n);
    } else if (tag == "emitter") {
        m_out["lights"].push_back(emitter(n, false));
    } else if (tag == "bsdf" || tag == "texture") {
        if (!has_attr(n, "id")) fail(n, fmt::format("a top-level <{}> needs an id to be referred to", tag));
        if (tag == "bsdf") bsdf(n);
        else texture(n);
    } else {
        fail(n, "unsupported element (meso reads <default>, <include>, <sensor>, <integrator>, <shape>, <emitter>, "
                "<bsdf> and <texture> at the top level)");
    }
}

json Translator::translate(const std::string &path, std::vector<std::string> *overrides) {
    // -D name=value with a bare name is an XML parameter; one named like a meso top-level key
    // (-D integrator=...) only when the file uses $name, else it stays a JSON override.
    auto bare_name = [](const std::string &o) {
        size_t eq = o.find('=');
        std::string key = o.substr(0, eq);
        bool bare = eq != std::string::npos && !key.empty() &&
                    std::all_of(key.begin(), key.end(), [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '_'; });
        return bare ? key : std::string();
    };
    if (overrides)
        for (const std::string &o : *overrides)
            if (std::string key = bare_name(o); !key.empty()) m_cli[key] = m_params[key] = o.substr(key.size() + 1);
    Source &main = load(path, "", nullptr);
    m_include_stack.push_back(fs::weakly_canonical(path).string());
    for (pugi::xml_node c : main.doc.document_element().children())
        if (c.type() == pugi::node_element) top_level(c);
    if (overrides) {
        std::vector<std::string> rest;
        for (const std::string &o : *overrides) {
            std::string key = bare_name(o);
            bool top = std::any_of(std::begin(kMesoTopLevel), std::end(kMesoTopLevel), [&](const char *k) { return key == k; });
            if (key.empty() || (top && !m_params_used.count(key))) rest.push_back(o);
            else if (!m_params_used.count(key))
                throw MesoError(fmt::format("-D {}: {} has no parameter '${}'", o, path, key));
        }
        *overrides = rest;
    }
    if (!m_out.contains("camera")) throw MesoError(fmt::format("{}: no <sensor> (meso needs a camera)", path));
    if (!m_out.contains("integrator")) m_out["integrator"] = {{"type", "path"}};
    return m_out;
}

}  // namespace mitsuba_detail

json mitsuba_xml_to_json(const std::string &path, std::vector<std::string> *overrides) {
    mitsuba_detail::Translator t;
    return t.translate(path, overrides);
}

bool is_mitsuba_xml_path(const std::string &path) {
    return path.size() >= 4 && mitsuba_detail::lower(path.substr(path.size() - 4)) == ".xml";
}

}  // namespace meso
