// `obj` shape: a Wavefront OBJ mesh (Mitsuba 3's names), read with tinyobjloader.
//
//   filename      string    required  the .obj file (relative to the scene file)
//   face_normals  boolean   false     flat shading: the file's normals are discarded
//   to_world      transform identity
//   flip_normals  boolean   false     reverse normals and winding
//   flip_tex_coords boolean false     v -> 1 - v (Mitsuba 3's OBJ default is true; Mitsuba XML
//                                     scenes are translated with it set)
//   displacement  object    none      as for every mesh shape
//
// Every object and group of the file becomes one mesh; `v`, `vt`, `vn` (and `v x y z r g b`
// colours, ignored with a warning: meso meshes carry no vertex colour). Faces of more than
// 3 vertices are fan-triangulated (exact for convex polygons). Without `vn` (or when only
// some face vertices have one), smooth normals are computed over the shared positions, as
// Mitsuba does, unless face_normals. A token that is not a number on a v/vt/vn line is an
// error naming the line; a NaN or infinite position drops its triangles. uvs are kept as
// stored (v = 0 is the top row of a `bitmap`). `mtllib`/`usemtl` are ignored: the shape's material comes from the scene.
#include <cctype>
#include <charconv>
#include <cmath>
#include <fmt/format.h>
#include <fstream>
#include <limits>
#include <sstream>
#include <tiny_obj_loader.h>
#include "core/error.h"
#include "core/properties.h"
#include "core/registry.h"
#include "scene/mesh_file.h"

namespace meso {

namespace {

/// One output vertex per distinct (position, normal, uv) index triple of the file:
/// open addressing over the triples (a million-triangle file makes ~3M lookups).
class VertexTable {
public:
    explicit VertexTable(size_t expected) {
        size_t cap = 16;
        while (cap < 2 * expected) cap *= 2;
        m_slots.assign(cap, Slot{});
        m_mask = cap - 1;
    }
    /// The output index of the triple, or `next` (and remembers it) when it is new.
    uint32_t find_or_add(const tinyobj::index_t &k, uint32_t next, bool &added) {
        uint64_t h = uint64_t(uint32_t(k.vertex_index)) * 0x9E3779B97F4A7C15ull ^
                     uint64_t(uint32_t(k.normal_index)) * 0xC2B2AE3D27D4EB4Full ^
                     uint64_t(uint32_t(k.texcoord_index)) * 0x165667B19E3779F9ull;
        for (size_t s = size_t(h ^ (h >> 29)) & m_mask;; s = (s + 1) & m_mask) {
            Slot &slot = m_slots[s];
            if (slot.value == MissingVertex) {
                slot = {k.vertex_index, k.normal_index, k.texcoord_index, next};
                added = true;
                return next;
            }
            if (slot.v == k.vertex_index && slot.n == k.normal_index && slot.t == k.texcoord_index) {
                added = false;
                return slot.value;
            }
        }
    }

private:
    struct Slot {
        int v = 0, n = 0, t = 0;
        uint32_t value = MissingVertex;
    };
    std::vector<Slot> m_slots;
    size_t m_mask = 0;
};

/// Which attributes every face vertex has: normals only if all do, uvs if any does.
void attribute_presence(const tinyobj::attrib_t &attrib, const std::vector<tinyobj::shape_t> &shapes,
                        bool &normals, bool &uvs) {
    normals = !attrib.normals.empty();
    uvs = false;
    for (const auto &s : shapes)
        for (const auto &k : s.mesh.indices) {
            if (k.normal_index < 0) normals = false;
            if (k.texcoord_index >= 0) uvs = true;
        }
}

/// The mesh of every shape of the file: a vertex per distinct index triple, faces fanned.
MeshFile build_mesh(const tinyobj::attrib_t &attrib, const std::vector<tinyobj::shape_t> &shapes) {
    bool has_normals, has_uvs;
    attribute_presence(attrib, shapes, has_normals, has_uvs);
    const size_t np = attrib.vertices.size() / 3, nn = attrib.normals.size() / 3, nt = attrib.texcoords.size() / 2;
    size_t corners = 0;
    for (const auto &s : shapes) corners += s.mesh.indices.size();
    MeshFile m;
    m.file_vertices = np;
    TriangleMesh &mesh = m.mesh;
    VertexTable table(corners);
    std::vector<uint32_t> first_of_position(np, MissingVertex), face;
    for (const auto &s : shapes) {
        size_t at = 0;
        for (unsigned char fv : s.mesh.num_face_vertices) {
            face.clear();
            for (size_t c = 0; c < fv; ++c) {
                tinyobj::index_t k = s.mesh.indices[at + c];
                if (!has_normals) k.normal_index = -1;
                if (!has_uvs) k.texcoord_index = -1;
                bool in_range = k.vertex_index >= 0 && size_t(k.vertex_index) < np && size_t(k.normal_index + 1) <= nn &&
                                size_t(k.texcoord_index + 1) <= nt;
                if (!in_range) {
                    face.push_back(MissingVertex);
                    continue;
                }
                bool added = false;
                uint32_t v = table.find_or_add(k, uint32_t(mesh.positions.size()), added);
                if (added) {
                    const tinyobj::real_t *p = &attrib.vertices[3 * size_t(k.vertex_index)];
                    mesh.positions.emplace_back(p[0], p[1], p[2]);
                    if (has_normals) {
                        const tinyobj::real_t *n = &attrib.normals[3 * size_t(k.normal_index)];
                        mesh.normals.emplace_back(n[0], n[1], n[2]);
                    }
                    if (has_uvs) {
                        const tinyobj::real_t *t = k.texcoord_index >= 0 ? &attrib.texcoords[2 * size_t(k.texcoord_index)] : nullptr;
                        mesh.uvs.emplace_back(t ? t[0] : 0.f, t ? t[1] : 0.f);
                    }
                    uint32_t &first = first_of_position[size_t(k.vertex_index)];
                    if (first == MissingVertex) first = v;
                    m.weld.push_back(first);
                }
                face.push_back(v);
            }
            add_face(m, face.data(), face.size());
            at += fv;
        }
    }
    return m;
}

/// tinyobjloader reads a token that is not a number as 0 and cannot read NaN: `v`, `vt` and
/// `vn` lines are checked here first (an error names the line), and the `v` lines with a NaN
/// or infinite coordinate are listed (their triangles are dropped).
std::vector<size_t> check_obj_numbers(const std::string &data, const std::string &file) {
    std::vector<size_t> not_finite;
    size_t pos = 0, line = 0, vertex = 0;
    while (pos < data.size()) {
        size_t end = data.find('\n', pos);
        if (end == std::string::npos) end = data.size();
        ++line;
        const char *p = data.data() + pos, *e = data.data() + end;
        pos = end + 1;
        while (p < e && (*p == ' ' || *p == '\t')) ++p;
        if (e - p < 2 || p[0] != 'v') continue;
        const bool is_v = p[1] == ' ' || p[1] == '\t';
        if (!is_v && !((p[1] == 't' || p[1] == 'n') && e - p > 2 && (p[2] == ' ' || p[2] == '\t'))) continue;
        p += is_v ? 1 : 2;
        bool finite = true;
        for (int k = 0;; ++k) {
            while (p < e && std::isspace((unsigned char)*p)) ++p;
            if (p == e || *p == '#') break;
            const char *t = p;
            while (p < e && !std::isspace((unsigned char)*p)) ++p;
            double v;
            auto r = std::from_chars(t + (*t == '+'), p, v);
            if (r.ptr != p || r.ec == std::errc::invalid_argument)
                throw MesoError(fmt::format("{}: line {}: expected a number, got '{}'", file, line, std::string(t, p)));
            if (k < 3 && (r.ec != std::errc() || !std::isfinite(v))) finite = false;
        }
        if (is_v && !finite) not_finite.push_back(vertex);
        vertex += is_v;
    }
    return not_finite;
}

}  // namespace

MeshFile load_obj_mesh(const std::string &file) {
    std::ifstream in(file, std::ios::binary);
    if (!in) throw MesoError(fmt::format("{}: cannot open the OBJ file", file));
    std::stringstream text;
    text << in.rdbuf();
    const std::vector<size_t> not_finite = check_obj_numbers(text.str(), file);
    tinyobj::attrib_t attrib;
    std::vector<tinyobj::shape_t> shapes;
    std::vector<tinyobj::material_t> materials;
    std::string warn, err;
    // No material reader: mtllib lines are skipped. No triangulation: faces are fanned here.
    bool ok = tinyobj::LoadObj(&attrib, &shapes, &materials, &warn, &err, &text, nullptr, false, false);
    auto trim = [](std::string s) {
        while (!s.empty() && (s.back() == '\n' || s.back() == '\r')) s.pop_back();
        return s;
    };
    // tinyobjloader names the line ("Failed parse `f' line(e.g. zero value for face index. line 6.)").
    if (!ok) throw MesoError(fmt::format("{}: {}", file, err.empty() ? std::string("not a readable OBJ file") : trim(err)));
    for (size_t v : not_finite)
        if (3 * v < attrib.vertices.size()) attrib.vertices[3 * v] = std::numeric_limits<tinyobj::real_t>::quiet_NaN();
    MeshFile m = build_mesh(attrib, shapes);
    if (!attrib.colors.empty() && attrib.colors.size() == attrib.vertices.size() && m.faces > 0) {
        bool all_white = true;
        for (tinyobj::real_t c : attrib.colors) all_white = all_white && c == tinyobj::real_t(1);
        if (!all_white) m.warnings.push_back(fmt::format("{}: vertex colours ignored (meso meshes carry none)", file));
    }
    if (m.faces == 0) throw MesoError(fmt::format("{}: no faces (`f` lines) in the OBJ file", file));
    finish_mesh_file(m, file);
    return m;
}

namespace {

std::shared_ptr<Shape> create_obj_shape(const Properties &p) {
    std::string file = p.get_file("filename");
    MeshFile m;
    try {
        m = load_obj_mesh(file);
    } catch (const MesoError &e) {
        p.fail("filename", e.what());
    }
    if (p.get_bool("flip_tex_coords", false))
        for (Vec2 &uv : m.mesh.uvs) uv.y = 1.f - uv.y;
    return make_file_mesh_shape(std::move(m), p, file, "obj");
}

MESO_REGISTER_SHAPE("obj", "Wavefront OBJ mesh (filename, face_normals, to_world, flip_normals)", create_obj_shape);

}  // namespace
}  // namespace meso
