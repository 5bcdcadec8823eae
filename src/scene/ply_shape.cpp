// `ply` shape: a Stanford PLY mesh (Mitsuba 3's names), ASCII or binary (little or big endian).
//
//   filename      string    required  the .ply file (relative to the scene file)
//   face_normals  boolean   false     flat shading: the file's normals are discarded
//   to_world      transform identity
//   flip_normals  boolean   false     reverse normals and winding
//   displacement  object    none      as for every mesh shape
//
// Read from element `vertex`: x, y, z; nx, ny, nz; uvs as (u, v), (s, t), (texture_u,
// texture_v) or (texture_s, texture_t), kept as stored; red/green/blue colours are ignored with
// a warning (meso meshes carry no vertex colour). From element `face`: the list `vertex_indices`
// (or `vertex_index`), polygons fan-triangulated (exact for convex ones). Every other element
// and property, of any PLY type, is skipped. Without normals, smooth ones are computed unless
// face_normals (as Mitsuba does).
//
// A small reader of its own rather than assimp's: it reads the file in one piece and converts
// in place, and loads a million-triangle binary PLY in a fraction of a second (README: load
// times; scripts/assets/make_mesh_fixtures big makes the file).
#include <cctype>
#include <charconv>
#include <cstdio>
#include <cstring>
#include <functional>
#include <limits>
#include <fmt/format.h>
#include "core/error.h"
#include "core/properties.h"
#include "core/registry.h"
#include "scene/mesh_file.h"

namespace meso {

namespace {

enum class PlyType : uint8_t { I8, U8, I16, U16, I32, U32, F32, F64 };

bool parse_ply_type(const std::string &s, PlyType &t) {
    static const std::pair<const char *, PlyType> names[] = {
        {"char", PlyType::I8},   {"int8", PlyType::I8},     {"uchar", PlyType::U8},   {"uint8", PlyType::U8},
        {"short", PlyType::I16}, {"int16", PlyType::I16},   {"ushort", PlyType::U16}, {"uint16", PlyType::U16},
        {"int", PlyType::I32},   {"int32", PlyType::I32},   {"uint", PlyType::U32},   {"uint32", PlyType::U32},
        {"float", PlyType::F32}, {"float32", PlyType::F32}, {"double", PlyType::F64}, {"float64", PlyType::F64}};
    for (const auto &n : names)
        if (s == n.first) return t = n.second, true;
    return false;
}

struct PlyProperty {
    std::string name;
    PlyType type = PlyType::F32;
    bool list = false;
    PlyType count_type = PlyType::U8;
};

struct PlyElement {
    std::string name;
    size_t count = 0;
    std::vector<PlyProperty> props;
};

enum class PlyFormat { Ascii, Little, Big };

struct PlyHeader {
    PlyFormat format = PlyFormat::Ascii;
    std::vector<PlyElement> elements;
    size_t data_start = 0;  ///< byte offset after end_header's newline
    size_t lines = 0;       ///< lines of the header (ASCII data starts on the next)
};

std::vector<std::string> split_words(const std::string &line) {
    std::vector<std::string> w;
    size_t i = 0;
    while (i < line.size()) {
        while (i < line.size() && std::isspace((unsigned char)line[i])) ++i;
        size_t j = i;
        while (j < line.size() && !std::isspace((unsigned char)line[j])) ++j;
        if (j > i) w.push_back(line.substr(i, j - i));
        i = j;
    }
    return w;
}

/// One header line (already split): element, property, format, comment.
void parse_header_line(const std::vector<std::string> &w, PlyHeader &h, bool &have_format,
                       const std::function<void(const std::string &)> &fail) {
    if (w[0] == "comment" || w[0] == "obj_info") return;
    if (w[0] == "format") {
        if (w.size() != 3) fail("expected 'format ascii|binary_little_endian|binary_big_endian 1.0'");
        if (w[1] == "ascii") h.format = PlyFormat::Ascii;
        else if (w[1] == "binary_little_endian") h.format = PlyFormat::Little;
        else if (w[1] == "binary_big_endian") h.format = PlyFormat::Big;
        else fail(fmt::format("unknown format '{}' (expected ascii, binary_little_endian or binary_big_endian)", w[1]));
        if (w[2] != "1.0") fail(fmt::format("unsupported PLY version '{}' (expected 1.0)", w[2]));
        have_format = true;
    } else if (w[0] == "element") {
        if (w.size() != 3) fail("expected 'element NAME COUNT'");
        PlyElement e;
        e.name = w[1];
        auto r = std::from_chars(w[2].data(), w[2].data() + w[2].size(), e.count);
        if (r.ec != std::errc() || r.ptr != w[2].data() + w[2].size())
            fail(fmt::format("element '{}': expected a count, got '{}'", w[1], w[2]));
        h.elements.push_back(e);
    } else if (w[0] == "property") {
        if (h.elements.empty()) fail("property before any element");
        PlyProperty p;
        bool ok = false;
        if (w.size() == 5 && w[1] == "list") {
            p.list = true;
            ok = parse_ply_type(w[2], p.count_type) && parse_ply_type(w[3], p.type);
            if (ok && (p.count_type == PlyType::F32 || p.count_type == PlyType::F64))
                fail(fmt::format("property '{}': a list count must be an integer type", w[4]));
            p.name = w[4];
        } else if (w.size() == 3) {
            ok = parse_ply_type(w[1], p.type);
            p.name = w[2];
        } else {
            fail("expected 'property TYPE NAME' or 'property list COUNT_TYPE TYPE NAME'");
        }
        if (!ok) fail(fmt::format("property '{}': unknown type (expected char, uchar, short, ushort, int, uint, float, "
                                  "double or their int8..float64 names)", w.back()));
        h.elements.back().props.push_back(p);
    } else {
        fail(fmt::format("unknown header keyword '{}'", w[0]));
    }
}

PlyHeader parse_ply_header(const std::string &data, const std::string &file) {
    PlyHeader h;
    size_t pos = 0, line_no = 0;
    bool have_format = false;
    while (true) {
        size_t nl = data.find('\n', pos);
        if (nl == std::string::npos) throw MesoError(fmt::format("{}: the PLY header has no end_header line", file));
        std::string line = data.substr(pos, nl - pos);
        if (!line.empty() && line.back() == '\r') line.pop_back();
        pos = nl + 1;
        ++line_no;
        auto fail = [&](const std::string &msg) {
            throw MesoError(fmt::format("{}: header line {}: {}", file, line_no, msg));
        };
        if (line_no == 1) {
            if (line != "ply") throw MesoError(fmt::format("{}: not a PLY file (the first line is not 'ply')", file));
            continue;
        }
        std::vector<std::string> w = split_words(line);
        if (w.empty()) continue;
        if (w[0] == "end_header") break;
        parse_header_line(w, h, have_format, fail);
    }
    if (!have_format) throw MesoError(fmt::format("{}: the PLY header has no format line", file));
    h.data_start = pos;
    h.lines = line_no;
    return h;
}

/// Reads binary values (either byte order) from the data block.
class BinaryReader {
public:
    BinaryReader(const char *p, const char *end, bool swap) : m_p(p), m_end(end), m_swap(swap) {}
    /// False when the data ends first.
    bool read(PlyType t, double &v) {
        switch (t) {
        case PlyType::I8: return get<int8_t>(v);
        case PlyType::U8: return get<uint8_t>(v);
        case PlyType::I16: return get<int16_t>(v);
        case PlyType::U16: return get<uint16_t>(v);
        case PlyType::I32: return get<int32_t>(v);
        case PlyType::U32: return get<uint32_t>(v);
        case PlyType::F32: return get<float>(v);
        case PlyType::F64: return get<double>(v);
        }
        return false;
    }
    std::string where() const { return ""; }
    std::string bad_token() const { return ""; }

private:
    template <typename T>
    bool get(double &v) {
        if (size_t(m_end - m_p) < sizeof(T)) return false;
        unsigned char b[sizeof(T)];
        std::memcpy(b, m_p, sizeof(T));
        if (m_swap)
            for (size_t i = 0; i < sizeof(T) / 2; ++i) std::swap(b[i], b[sizeof(T) - 1 - i]);
        T x;
        std::memcpy(&x, b, sizeof(T));
        v = double(x);
        m_p += sizeof(T);
        return true;
    }
    const char *m_p, *m_end;
    bool m_swap;
};

/// Reads whitespace-separated numbers, counting lines for messages.
class AsciiReader {
public:
    AsciiReader(const char *p, const char *end, size_t first_line) : m_p(p), m_end(end), m_line(first_line) {}
    /// False at the end of the data or on a token that is not a number (bad_token() non-empty).
    bool read(PlyType, double &v) {
        while (m_p < m_end && std::isspace((unsigned char)*m_p)) m_line += *m_p++ == '\n';
        if (m_p == m_end) return false;
        const char *s = m_p;
        while (m_p < m_end && !std::isspace((unsigned char)*m_p)) ++m_p;
        const char *b = s + (*s == '+');
        v = std::numeric_limits<double>::quiet_NaN();
        auto r = std::from_chars(b, m_p, v);
        if (r.ec == std::errc::invalid_argument || r.ptr != m_p) {
            m_bad.assign(s, m_p);
            return false;
        }
        return true;  // out of range (1e999): v stays NaN, and the vertex or face is dropped
    }
    std::string where() const { return fmt::format("line {}, ", m_line); }
    const std::string &bad_token() const { return m_bad; }

private:
    const char *m_p, *m_end;
    size_t m_line;
    std::string m_bad;
};

/// What the vertex and face elements' properties mean for the mesh.
struct VertexLayout {
    int x = -1, y = -1, z = -1, nx = -1, ny = -1, nz = -1, u = -1, v = -1;
    bool colours = false;
};

VertexLayout vertex_layout(const PlyElement &e) {
    VertexLayout l;
    auto find = [&](const char *name) {
        for (size_t i = 0; i < e.props.size(); ++i)
            if (!e.props[i].list && e.props[i].name == name) return int(i);
        return -1;
    };
    l.x = find("x"), l.y = find("y"), l.z = find("z");
    l.nx = find("nx"), l.ny = find("ny"), l.nz = find("nz");
    static const char *uv_names[][2] = {{"u", "v"}, {"s", "t"}, {"texture_u", "texture_v"}, {"texture_s", "texture_t"}};
    for (const auto &n : uv_names)
        if (l.u < 0 && find(n[0]) >= 0 && find(n[1]) >= 0) l.u = find(n[0]), l.v = find(n[1]);
    l.colours = find("red") >= 0 || find("diffuse_red") >= 0;
    return l;
}

/// Reads every element of the data block into `m` (the mesh's vertices and fanned faces).
template <typename Reader>
void read_ply_elements(Reader &r, const PlyHeader &h, MeshFile &m, const std::string &file) {
    TriangleMesh &mesh = m.mesh;
    bool have_vertices = false;
    std::vector<double> vals;
    std::vector<uint32_t> face;
    for (const PlyElement &e : h.elements) {
        size_t i = 0;
        auto fail = [&]() {
            if (!r.bad_token().empty())
                throw MesoError(fmt::format("{}: {}element '{}' {}: expected a number, got '{}'", file, r.where(), e.name, i,
                                            r.bad_token()));
            throw MesoError(fmt::format("{}: element '{}' {} of {}: the file ends early", file, e.name, i, e.count));
        };
        const bool is_vertex = e.name == "vertex", is_face = e.name == "face";
        VertexLayout l;
        int index_list = -1;
        if (is_vertex) {
            l = vertex_layout(e);
            if (l.x < 0 || l.y < 0 || l.z < 0) throw MesoError(fmt::format("{}: element 'vertex' has no x, y and z properties", file));
            if (e.count > 0xfffffffeu) throw MesoError(fmt::format("{}: element 'vertex': too many vertices ({})", file, e.count));
            mesh.positions.resize(e.count);
            m.file_vertices = e.count;
            if (l.nx >= 0 && l.ny >= 0 && l.nz >= 0) mesh.normals.resize(e.count);
            if (l.u >= 0) mesh.uvs.resize(e.count);
            if (l.colours) m.warnings.push_back(fmt::format("{}: vertex colours ignored (meso meshes carry none)", file));
            have_vertices = true;
        } else if (is_face) {
            for (size_t k = 0; k < e.props.size(); ++k)
                if (e.props[k].list && (e.props[k].name == "vertex_indices" || e.props[k].name == "vertex_index")) index_list = int(k);
            if (index_list < 0) throw MesoError(fmt::format("{}: element 'face' has no list property vertex_indices", file));
            if (!have_vertices) throw MesoError(fmt::format("{}: element 'face' comes before element 'vertex'", file));
        }
        const size_t nv = mesh.positions.size();
        vals.resize(e.props.size());
        for (i = 0; i < e.count; ++i) {
            for (size_t k = 0; k < e.props.size(); ++k) {
                const PlyProperty &p = e.props[k];
                if (!p.list) {
                    if (!r.read(p.type, vals[k])) fail();
                    continue;
                }
                double count;
                if (!r.read(p.count_type, count)) fail();
                if (count < 0)
                    throw MesoError(fmt::format("{}: {}element '{}' {}: negative list length {}", file, r.where(), e.name, i, count));
                if (int(k) == index_list) face.clear();
                for (size_t c = 0; c < size_t(count); ++c) {
                    double v;
                    if (!r.read(p.type, v)) fail();
                    if (int(k) == index_list) face.push_back(v >= 0 && v < double(nv) ? uint32_t(v) : MissingVertex);
                }
            }
            if (is_vertex) {
                mesh.positions[i] = Vec3(float(vals[l.x]), float(vals[l.y]), float(vals[l.z]));
                if (!mesh.normals.empty()) mesh.normals[i] = Vec3(float(vals[l.nx]), float(vals[l.ny]), float(vals[l.nz]));
                if (!mesh.uvs.empty()) mesh.uvs[i] = Vec2(float(vals[l.u]), float(vals[l.v]));
            } else if (is_face) {
                add_face(m, face.data(), face.size());
            }
        }
    }
    if (!have_vertices) throw MesoError(fmt::format("{}: no element 'vertex'", file));
    if (m.faces == 0) throw MesoError(fmt::format("{}: no faces (element 'face' is missing or empty)", file));
}

std::string read_whole_file(const std::string &file) {
    std::FILE *f = std::fopen(file.c_str(), "rb");
    if (!f) throw MesoError(fmt::format("{}: cannot open the PLY file", file));
    std::string data;
    char buf[1 << 16];
    size_t n;
    std::fseek(f, 0, SEEK_END);
    long size = std::ftell(f);
    std::fseek(f, 0, SEEK_SET);
    if (size > 0) data.reserve(size_t(size));
    while ((n = std::fread(buf, 1, sizeof(buf), f)) > 0) data.append(buf, n);
    bool err = std::ferror(f);
    std::fclose(f);
    if (err) throw MesoError(fmt::format("{}: read error", file));
    return data;
}

}  // namespace

MeshFile load_ply_mesh(const std::string &file) {
    const std::string data = read_whole_file(file);
    const PlyHeader h = parse_ply_header(data, file);
    MeshFile m;
    const char *begin = data.data() + h.data_start, *end = data.data() + data.size();
    if (h.format == PlyFormat::Ascii) {
        AsciiReader r(begin, end, h.lines + 1);
        read_ply_elements(r, h, m, file);
    } else {
        const uint16_t probe = 1;
        const bool little_host = *reinterpret_cast<const unsigned char *>(&probe) == 1;
        BinaryReader r(begin, end, little_host != (h.format == PlyFormat::Little));
        read_ply_elements(r, h, m, file);
    }
    finish_mesh_file(m, file);
    return m;
}

namespace {

std::shared_ptr<Shape> create_ply_shape(const Properties &p) {
    std::string file = p.get_file("filename");
    MeshFile m;
    try {
        m = load_ply_mesh(file);
    } catch (const MesoError &e) {
        p.fail("filename", e.what());
    }
    return make_file_mesh_shape(std::move(m), p, file, "ply");
}

MESO_REGISTER_SHAPE("ply", "Stanford PLY mesh, ASCII or binary (filename, face_normals, to_world, flip_normals)", create_ply_shape);

}  // namespace
}  // namespace meso
