#include "scene/mesh_file.h"
#include <cmath>
#include <fmt/format.h>
#include "core/error.h"
#include "core/properties.h"
#include "geometry/mesh_shape.h"

namespace meso {

void add_face(MeshFile &m, const uint32_t *face, size_t n) {
    ++m.faces;
    if (n < 3) {
        ++m.short_faces;
        return;
    }
    if (n > 3) ++m.polygons;
    auto &idx = m.mesh.indices;
    for (size_t k = 1; k + 1 < n; ++k) {
        idx.push_back(face[0]);
        idx.push_back(face[k]);
        idx.push_back(face[k + 1]);
    }
}

namespace {

/// Removes vertices no triangle uses (after non-finite ones were dropped), remapping indices
/// and the weld.
void compact_vertices(MeshFile &m) {
    TriangleMesh &mesh = m.mesh;
    const size_t nv = mesh.vertex_count();
    std::vector<uint32_t> remap(nv, MissingVertex);
    uint32_t next = 0;
    for (uint32_t &i : mesh.indices) {
        if (remap[i] == MissingVertex) remap[i] = next++;
        i = remap[i];
    }
    auto pack = [&](auto &v) {
        if (v.empty()) return;
        auto out = v;
        out.resize(next);
        for (size_t i = 0; i < nv; ++i)
            if (remap[i] != MissingVertex) out[remap[i]] = v[i];
        v.swap(out);
    };
    pack(mesh.positions);
    pack(mesh.normals);
    pack(mesh.uvs);
    pack(mesh.tangents);
    pack(mesh.tangent_signs);
    if (!m.weld.empty()) {
        // A welded group keeps its first surviving member as representative.
        std::vector<uint32_t> rep(nv, MissingVertex), weld(next);
        for (size_t i = 0; i < nv; ++i) {
            if (remap[i] == MissingVertex) continue;
            uint32_t &r = rep[m.weld[i]];
            if (r == MissingVertex) r = remap[i];
            weld[remap[i]] = r;
        }
        m.weld.swap(weld);
    }
}

}  // namespace

void finish_mesh_file(MeshFile &m, const std::string &file) {
    TriangleMesh &mesh = m.mesh;
    const size_t nv = mesh.vertex_count();
    std::vector<char> finite(nv);
    size_t bad_vertices = 0;
    for (size_t i = 0; i < nv; ++i) bad_vertices += !(finite[i] = is_finite(mesh.positions[i]));
    size_t out_of_range = 0, repeated = 0, not_finite = 0, kept = 0;
    const size_t total = mesh.triangle_count();
    for (size_t t = 0; t < total; ++t) {
        const uint32_t a = mesh.indices[3 * t], b = mesh.indices[3 * t + 1], c = mesh.indices[3 * t + 2];
        if (a >= nv || b >= nv || c >= nv) ++out_of_range;
        else if (a == b || b == c || a == c) ++repeated;
        else if (!finite[a] || !finite[b] || !finite[c]) ++not_finite;
        else {
            if (kept != t) std::copy_n(&mesh.indices[3 * t], 3, &mesh.indices[3 * kept]);
            ++kept;
            continue;
        }
    }
    mesh.indices.resize(3 * kept);
    if (bad_vertices > 0) compact_vertices(m);
    std::vector<std::string> why;
    if (out_of_range) why.push_back(fmt::format("{} with a vertex index out of range (the file has {} vertices)", out_of_range, m.file_vertices));
    if (repeated) why.push_back(fmt::format("{} with a repeated vertex index", repeated));
    if (not_finite) why.push_back(fmt::format("{} with a NaN or infinite vertex position", not_finite));
    if (!why.empty())
        m.warnings.push_back(fmt::format("{}: dropped {} of {} triangles: {}", file, total - kept, total, fmt::join(why, ", ")));
    if (m.short_faces)
        m.warnings.push_back(fmt::format("{}: dropped {} faces with fewer than 3 vertices", file, m.short_faces));
    if (kept == 0) throw MesoError(fmt::format("{}: no valid triangles ({} faces read)", file, m.faces));
    if (mesh.vertex_count() > 0xffffffffu) throw MesoError(fmt::format("{}: too many vertices", file));
}

std::shared_ptr<Shape> make_file_mesh_shape(MeshFile m, const Properties &p, const std::string &file,
                                            const std::string &kind) {
    TriangleMesh &mesh = m.mesh;
    if (p.get_bool("face_normals", false)) {
        mesh.normals.clear();
    } else if (mesh.normals.empty()) {
        if (m.weld.empty()) {
            m.weld.resize(mesh.vertex_count());
            for (size_t i = 0; i < m.weld.size(); ++i) m.weld[i] = uint32_t(i);
        }
        mesh.normals = vertex_normals(mesh, m.weld);
    }
    for (const std::string &w : m.warnings) fmt::print(stderr, "{}: {}: warning: {}\n", p.file(), p.path(), w);
    return make_mesh_shape(std::move(mesh), p, fmt::format("{} ({} {})", p.path(), kind, file));
}

}  // namespace meso
