// Mitsuba 3 XML → meso JSON: BSDFs, textures, shapes and emitters (mitsuba_xml_translator.h).
#include "scene/mitsuba_xml_translator.h"

namespace meso::mitsuba_detail {

namespace fs = std::filesystem;

// ---------------------------------------------------------------------------------------
// BSDFs and textures

json Translator::bsdf(const pugi::xml_node &n) {
    if (std::string(n.name()) == "ref") return ref(n, "bsdf");
    Element e = element(n);
    json j = bsdf_object(e);
    finish(e);
    if (!has_attr(n, "id")) return j;
    std::string id = n.attribute("id").value();
    if (j.is_string()) {  // a twosided around a named bsdf: the id refers to that one
        register_id(n, "bsdf", j);
        return j;
    }
    m_out["materials"][id] = j;
    register_id(n, "bsdf", id);
    return id;
}

/// The one nested bsdf of twosided / normalmap / bumpmap.
json Translator::wrapped_bsdf(Element &e) {
    std::vector<pugi::xml_node> inner;
    for (pugi::xml_node c : e.nested)
        if (is_one_of(c.name(), {"bsdf", "ref"})) inner.push_back(c);
        else if (std::string(c.name()) != "texture") fail(c, fmt::format("unexpected inside {}", describe(e.node)));
    if (inner.size() != 1)
        fail(e.node, inner.empty() ? "expected a nested <bsdf>"
                                   : "different front and back materials are not supported (one nested <bsdf>)");
    return bsdf(inner[0]);
}

json Translator::bsdf_object(Element &e) {
    enum Kind { Tex, Spec, Float, Ior, Str, Bool };
    struct Param {
        const char *name;
        Kind kind;
    };
    static const std::map<std::string, std::pair<const char *, std::vector<Param>>> table = {
        {"diffuse", {"diffuse", {{"reflectance", Tex}}}},
        {"conductor", {"conductor", {{"material", Str}, {"eta", Spec}, {"k", Spec}, {"specular_reflectance", Tex}}}},
        {"plastic",
         {"plastic", {{"diffuse_reflectance", Tex}, {"specular_reflectance", Tex}, {"int_ior", Ior}, {"ext_ior", Ior}, {"nonlinear", Bool}}}},
        {"dielectric",
         {"dielectric", {{"int_ior", Ior}, {"ext_ior", Ior}, {"specular_reflectance", Tex}, {"specular_transmission", Tex}}}},
    };
    static const std::vector<Param> rough = {{"distribution", Str}, {"alpha", Float}, {"alpha_u", Float},
                                             {"alpha_v", Float},     {"sample_visible", Bool}};
    bool is_rough = e.type.rfind("rough", 0) == 0;
    std::string base = is_rough ? e.type.substr(5) : e.type;
    auto it = table.find(base);
    if (e.type == "twosided") {
        // meso's reflection-only materials shade both sides already.
        return wrapped_bsdf(e);
    }
    if (e.type == "normalmap" || e.type == "bumpmap") {
        json j = {{"type", "normalmap"}, {"bsdf", wrapped_bsdf(e)}};
        pugi::xml_node tex;
        if (e.type == "normalmap") {
            if (Element::Prop *p = take(e, "normalmap", {"texture"})) tex = p->node;
        } else {  // bumpmap: a texture of any name
            for (auto &[name, p] : e.props)
                if (std::string(p.node.name()) == "texture") p.used = true, tex = p.node;
        }
        for (pugi::xml_node c : e.nested)
            if (std::string(c.name()) == "texture") tex = c;
        if (!tex) fail(e.node, "expected a <texture type=\"bitmap\"> (the map)");
        XmlTransform to_uv;
        std::string file = bitmap_file(tex, &to_uv);
        json tiling = 1;
        if (!to_uv.ops.empty()) {
            if (to_uv.ops.size() != 1 || to_uv.ops[0].kind != TransformOp::Scale)
                fail(to_uv.node, "only a <scale> is supported as to_uv (meso's tiling)");
            tiling = json::array({num(to_uv.ops[0].a.x), num(to_uv.ops[0].a.y)});
        }
        if (e.type == "normalmap") {
            j["normals"] = file;
            if (!to_uv.ops.empty()) j["tiling"] = tiling;
        } else {
            json h = {{"map", file}, {"scale", get_float(e, "scale").value_or(1.0)}};
            if (!to_uv.ops.empty()) h["tiling"] = tiling;
            j["heightmap"] = h;
        }
        return j;
    }
    if (it == table.end() || (is_rough && base == "diffuse"))
        unsupported(e, "bsdf", {"diffuse", "conductor", "roughconductor", "plastic", "roughplastic", "dielectric",
                                "roughdielectric", "twosided", "normalmap", "bumpmap"});
    json j = {{"type", it->second.first}};
    std::vector<Param> params = it->second.second;
    if (is_rough) params.insert(params.end(), rough.begin(), rough.end());
    for (const Param &p : params) {
        if (base == "plastic" && is_one_of(p.name, {"alpha_u", "alpha_v"})) continue;  // isotropic in Mitsuba
        std::optional<json> v;
        if (p.kind == Tex) v = get_texture(e, p.name);
        if (p.kind == Spec) v = get_spectrum(e, p.name);
        if (p.kind == Float) v = get_float(e, p.name);
        if (p.kind == Str) v = get_string(e, p.name);
        if (p.kind == Bool) v = get_bool(e, p.name);
        if (p.kind == Ior) {
            e.asked.push_back(p.name);
            auto prop = e.props.find(p.name);
            if (prop != e.props.end() && std::string(prop->second.node.name()) == "string") v = get_string(e, p.name);
            else v = get_float(e, p.name);
        }
        if (v) j[p.name] = *v;
    }
    if (is_rough) {  // Mitsuba's rough defaults: Beckmann, alpha 0.1
        if (!j.contains("distribution")) j["distribution"] = "beckmann";
        if (!j.contains("alpha") && !j.contains("alpha_u") && !j.contains("alpha_v")) j["alpha"] = 0.1;
    }
    for (pugi::xml_node c : e.nested) fail(c, fmt::format("unexpected inside {}", describe(e.node)));
    return j;
}

/// The file of a <texture type="bitmap"> used as a normal or bump map (read raw by meso).
std::string Translator::bitmap_file(const pugi::xml_node &n, XmlTransform *to_uv) {
    Element e = element(n);
    if (e.type != "bitmap") fail(n, "expected a <texture type=\"bitmap\">");
    std::optional<std::string> file = get_string(e, "filename");
    if (!file) fail(n, "missing the property 'filename'");
    std::optional<bool> raw = get_bool(e, "raw");
    if (!raw.value_or(false)) note(n, "read raw (no sRGB decoding), as Mitsuba does with raw=true");
    if (auto t = get_transform(e, "to_uv")) *to_uv = *t;
    finish(e);
    return file_name(n, *file);
}

json Translator::texture(const pugi::xml_node &n) {
    Element e = element(n);
    json j;
    if (e.type == "bitmap") {
        std::optional<std::string> file = get_string(e, "filename");
        if (!file) fail(n, "missing the property 'filename'");
        j = {{"type", "bitmap"}, {"filename", file_name(n, *file)},
             {"filter_type", get_string(e, "filter_type").value_or("bilinear")}};  // Mitsuba: bilinear, no MIP map
        if (auto v = get_string(e, "wrap_mode")) j["wrap_mode"] = *v;
        if (auto v = get_bool(e, "raw")) j["raw"] = *v;
        if (auto t = get_transform(e, "to_uv")) {
            if (t->ops.size() != 1 || t->ops[0].kind != TransformOp::Scale)
                fail(t->node, "only a <scale> is supported as to_uv (meso's tiling)");
            j["tiling"] = json::array({num(t->ops[0].a.x), num(t->ops[0].a.y)});
        }
    } else if (e.type == "checkerboard") {
        j = {{"type", "checkerboard"}};
        if (auto v = get_texture(e, "color0")) j["color0"] = *v;
        if (auto v = get_texture(e, "color1")) j["color1"] = *v;
        if (auto t = get_transform(e, "to_uv")) {
            const TransformOp &op = t->ops.empty() ? TransformOp{} : t->ops[0];
            if (t->ops.size() != 1 || op.kind != TransformOp::Scale || op.a.x != op.a.y)
                fail(t->node, "only a uniform <scale> is supported as to_uv (meso's checkerboard scale)");
            j["scale"] = num(2.f * op.a.x);  // Mitsuba's pattern has 2 checks per unit uv
        }
    } else {
        unsupported(e, "texture", {"bitmap", "checkerboard"});
    }
    for (pugi::xml_node c : e.nested) fail(c, fmt::format("unexpected inside {}", describe(n)));
    finish(e);
    if (!has_attr(n, "id")) return j;
    std::string id = n.attribute("id").value();
    m_out["textures"][id] = j;
    register_id(n, "texture", id);
    return id;
}

// ---------------------------------------------------------------------------------------
// Shapes and emitters

void Translator::shape(const pugi::xml_node &n) {
    Element e = element(n);
    if (!is_one_of(e.type, {"obj", "ply", "rectangle", "cube", "sphere", "disk"}))
        unsupported(e, "shape", {"obj", "ply", "rectangle", "cube", "sphere", "disk"});
    json s = {{"type", e.type}};
    if (e.type == "obj" || e.type == "ply") {
        std::optional<std::string> file = get_string(e, "filename");
        if (!file) fail(n, "missing the property 'filename'");
        s["filename"] = file_name(n, *file);
        if (auto v = get_bool(e, "face_normals")) s["face_normals"] = *v;
        if (e.type == "obj") {
            // Mitsuba flips OBJ texture v by default (flip_tex_coords true); meso keeps uvs as stored.
            std::optional<bool> flip = get_bool(e, "flip_tex_coords");
            s["flip_tex_coords"] = flip.value_or(true);
        }
    }
    std::optional<XmlTransform> t = get_transform(e, "to_world");
    if (e.type == "sphere") {
        Vec3 c = get_vec3(e, "center").value_or(Vec3(0, 0, 0));
        double r = get_float(e, "radius").value_or(1.0);
        if (t) {  // a similarity only: centre and radius in world space
            Vec3 x = t->m.apply_vector(Vec3(1, 0, 0)), y = t->m.apply_vector(Vec3(0, 1, 0)), z = t->m.apply_vector(Vec3(0, 0, 1));
            float lx = length(x), ly = length(y), lz = length(z);
            float tol = 1e-5f * std::max(lx, std::max(ly, lz));
            if (std::fabs(lx - ly) > tol || std::fabs(lx - lz) > tol || std::fabs(dot(x, y)) > tol * lx ||
                std::fabs(dot(x, z)) > tol * lx || std::fabs(dot(y, z)) > tol * lx)
                fail(t->node, "a sphere's to_world must be a similarity (no non-uniform scale or shear)");
            c = t->m.apply_point(c);
            r = num(float(r) * lx).get<double>();
        }
        s["center"] = vec3_json(c);
        s["radius"] = r;
    } else if (t) {
        s["to_world"] = to_world_json(*t);
    }
    if (auto v = get_bool(e, "flip_normals")) s["flip_normals"] = *v;
    for (pugi::xml_node c : e.nested) {
        std::string tag = c.name();
        if (tag == "bsdf" || tag == "ref") {
            if (s.contains("material")) fail(c, "a second material for one shape");
            s["material"] = bsdf(c);
        } else if (tag == "emitter") {
            if (s.contains("emitter")) fail(c, "a second emitter for one shape");
            s["emitter"] = emitter(c, true);
        } else {
            fail(c, fmt::format("unexpected inside {} (expected <bsdf>, <ref> or <emitter>)", describe(n)));
        }
    }
    finish(e);
    m_out["shapes"].push_back(s);
}

json Translator::emitter(const pugi::xml_node &n, bool in_shape) {
    Element e = element(n);
    if (in_shape != (e.type == "area"))
        fail(n, in_shape ? "a shape's emitter must be an 'area' emitter" : "an 'area' emitter must be inside a <shape>");
    json j = {{"type", e.type}};
    std::optional<XmlTransform> t;
    if (e.type != "area" && e.type != "constant") t = get_transform(e, "to_world");
    auto lookat = [&] { return t && t->ops.size() == 1 && t->ops[0].kind == TransformOp::LookAt; };
    if (e.type == "area" || e.type == "constant") {
        if (auto v = get_spectrum(e, "radiance")) j["radiance"] = *v;
    } else if (e.type == "point" || e.type == "spot") {
        if (auto v = get_spectrum(e, "intensity")) j["intensity"] = *v;
        std::optional<Vec3> pos = e.type == "point" ? get_vec3(e, "position") : std::nullopt;
        if (pos && t) fail(n, "give either 'position' or 'to_world', not both");
        if (pos) j["position"] = vec3_json(*pos);
        if (t) j["position"] = vec3_json(t->m.apply_point(Vec3(0, 0, 0)));
        if (e.type == "spot") {
            if (auto v = get_float(e, "cutoff_angle")) j["cutoff_angle"] = *v;
            if (auto v = get_float(e, "beam_width")) j["beam_width"] = *v;
            if (lookat()) j["target"] = vec3_json(t->ops[0].b);
            else if (t) j["direction"] = vec3_json(normalize(t->m.apply_vector(Vec3(0, 0, 1))));
        }
    } else if (e.type == "directional") {
        if (auto v = get_spectrum(e, "irradiance")) j["irradiance"] = *v;
        std::optional<Vec3> d = get_vec3(e, "direction");
        if (d && t) fail(n, "give either 'direction' or 'to_world', not both");
        if (d) j["direction"] = vec3_json(*d);
        if (t) j["direction"] = vec3_json(normalize(t->m.apply_vector(Vec3(0, 0, 1))));
    } else if (e.type == "envmap") {
        std::optional<std::string> file = get_string(e, "filename");
        if (!file) fail(n, "missing the property 'filename'");
        j["filename"] = file_name(n, *file);
        if (auto v = get_float(e, "scale")) j["scale"] = *v;
        if (t) j["to_world"] = to_world_json(*t);
    } else {
        unsupported(e, "emitter", {"area", "point", "spot", "constant", "envmap", "directional"});
    }
    for (pugi::xml_node c : e.nested) fail(c, fmt::format("unexpected inside {}", describe(n)));
    finish(e);
    return j;
}

}  // namespace meso::mitsuba_detail
