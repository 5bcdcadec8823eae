// glTF 2.0 loading: flattening the node hierarchy into world-space triangle meshes, and
// translating a whole file into a meso scene JSON document (see gltf.h and
// docs/scene-format.md, "glTF files as scenes").
#include "scene/gltf.h"
#include "scene/default_scene.h"
#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <mutex>
#include <set>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <tiny_gltf.h>
#include "core/error.h"
#include "core/input_file.h"
#include "core/registry.h"
#include "image/image.h"
#include "scene/gltf_material.h"

namespace meso {

using json = nlohmann::json;
namespace fs = std::filesystem;

using namespace gltf_detail;

namespace {

// ---------------------------------------------------------------------------------------
// 4x4 double matrices, row-major (m[row][col]); glTF stores column-major.

struct Mat4 {
    double m[4][4] = {{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}, {0, 0, 0, 1}};
};

Mat4 mul(const Mat4 &a, const Mat4 &b) {
    Mat4 r;
    for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j) {
            double s = 0;
            for (int k = 0; k < 4; ++k) s += a.m[i][k] * b.m[k][j];
            r.m[i][j] = s;
        }
    return r;
}

double det3(const Mat4 &a) {
    const auto &m = a.m;
    return m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
           m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
}

/// Cofactor matrix of the upper 3x3 (= det * inverse transpose): transforms normals
/// without needing the inverse, so a singular matrix cannot produce NaN.
void cofactor3(const Mat4 &a, double c[3][3]) {
    const auto &m = a.m;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
            int i1 = (i + 1) % 3, i2 = (i + 2) % 3, j1 = (j + 1) % 3, j2 = (j + 2) % 3;
            c[i][j] = m[i1][j1] * m[i2][j2] - m[i1][j2] * m[i2][j1];
        }
}

Vec3 apply_point(const Mat4 &a, Vec3 p) {
    const auto &m = a.m;
    double x = m[0][0] * p.x + m[0][1] * p.y + m[0][2] * p.z + m[0][3];
    double y = m[1][0] * p.x + m[1][1] * p.y + m[1][2] * p.z + m[1][3];
    double z = m[2][0] * p.x + m[2][1] * p.y + m[2][2] * p.z + m[2][3];
    return {float(x), float(y), float(z)};
}

Vec3 apply_vector(const Mat4 &a, Vec3 v) {
    const auto &m = a.m;
    return {float(m[0][0] * v.x + m[0][1] * v.y + m[0][2] * v.z), float(m[1][0] * v.x + m[1][1] * v.y + m[1][2] * v.z),
            float(m[2][0] * v.x + m[2][1] * v.y + m[2][2] * v.z)};
}

bool all_finite(const Mat4 &a) {
    for (auto &row : a.m)
        for (double v : row)
            if (!std::isfinite(v)) return false;
    return true;
}

/// Local transform of a node: its matrix, or T * R * S.
Mat4 node_matrix(const tinygltf::Node &n) {
    Mat4 r;
    if (n.matrix.size() == 16) {
        for (int col = 0; col < 4; ++col)
            for (int row = 0; row < 4; ++row) r.m[row][col] = n.matrix[col * 4 + row];
        return r;
    }
    Mat4 t, rot, s;
    if (n.translation.size() == 3)
        for (int i = 0; i < 3; ++i) t.m[i][3] = n.translation[i];
    if (n.rotation.size() == 4) {
        double x = n.rotation[0], y = n.rotation[1], z = n.rotation[2], w = n.rotation[3];
        double len = std::sqrt(x * x + y * y + z * z + w * w);
        if (len > 0 && std::isfinite(len)) {
            x /= len, y /= len, z /= len, w /= len;
            double R[3][3] = {{1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)},
                              {2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)},
                              {2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)}};
            for (int i = 0; i < 3; ++i)
                for (int j = 0; j < 3; ++j) rot.m[i][j] = R[i][j];
        }
    }
    if (n.scale.size() == 3)
        for (int i = 0; i < 3; ++i) s.m[i][i] = n.scale[i];
    return mul(t, mul(rot, s));
}

// ---------------------------------------------------------------------------------------
// Loading and accessors.

bool skip_image(tinygltf::Image *, const int, std::string *, std::string *, int, int, const unsigned char *, int,
                void *) {
    return true;  // never decode here: textures become `bitmap` files (image_file)
}

std::string trim(std::string s) {
    while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back()))) s.pop_back();
    size_t i = 0;
    while (i < s.size() && std::isspace(static_cast<unsigned char>(s[i]))) ++i;
    return s.substr(i);
}

/// tinygltf's file reader behind meso's input checks (external .bin buffers: regular files,
/// at most kMaxMeshFileBytes).
bool read_whole_file(std::vector<unsigned char> *out, std::string *err, const std::string &file, void *user) {
    const std::string why = input_file_problem(file, kMaxMeshFileBytes, "glTF buffer");
    if (!why.empty()) {
        if (err) *err += fmt::format("{}: cannot open the glTF buffer ({})", file, why);
        return false;
    }
    return tinygltf::ReadWholeFile(out, err, file, user);
}

/// Extensions meso implements; a file that requires any other one is refused (glTF 2.0, 3.12).
const char *const kImplementedExtensions[] = {"KHR_lights_punctual", "KHR_materials_emissive_strength"};

/// glTF 2.x only, and no required extension meso lacks.
void check_version_and_extensions(const std::string &path, const tinygltf::Model &model) {
    const std::string &v = model.asset.version;
    if (v.size() < 2 || v[0] != '2' || v[1] != '.')
        throw MesoError(fmt::format("{}: asset.version: expected a glTF 2.x file, got version \"{}\"", path, v));
    for (const std::string &ext : model.extensionsRequired) {
        bool known = false;
        for (const char *k : kImplementedExtensions) known = known || ext == k;
        if (!known)
            throw MesoError(fmt::format("{}: extensionsRequired: the file requires the extension '{}', which meso does "
                                        "not implement (meso implements {} and {})",
                                        path, ext, kImplementedExtensions[0], kImplementedExtensions[1]));
    }
}

void load_model(const std::string &path, tinygltf::Model &model) {
    check_input_file(path, kMaxMeshFileBytes, "glTF file");
    bool binary = false;
    {
        std::ifstream f(path, std::ios::binary);
        if (!f) throw MesoError(fmt::format("{}: cannot open the file", path));
        char magic[4] = {0, 0, 0, 0};
        f.read(magic, 4);
        binary = f.gcount() == 4 && std::memcmp(magic, "glTF", 4) == 0;
    }
    tinygltf::TinyGLTF loader;
    loader.SetImageLoader(skip_image, nullptr);
    loader.SetFsCallbacks({&tinygltf::FileExists, &tinygltf::ExpandFilePath, &read_whole_file, &tinygltf::WriteWholeFile, nullptr});
    std::string err, warning;
    bool ok = binary ? loader.LoadBinaryFromFile(&model, &err, &warning, path)
                     : loader.LoadASCIIFromFile(&model, &err, &warning, path);
    if (!ok) throw MesoError(fmt::format("{}: cannot load glTF: {}", path, trim(err.empty() ? warning : err)));
    warning = trim(warning);
    if (!warning.empty()) warn(path, warning);
    check_version_and_extensions(path, model);
}

struct Loader {
    const std::string &path;
    const tinygltf::Model &model;
    mutable std::set<std::string> warned;  ///< a mesh instanced many times warns once

    void warn_once(const std::string &msg) const {
        if (warned.insert(msg).second) warn(path, msg);
    }

    [[noreturn]] void fail(const std::string &where, const std::string &msg) const {
        throw MesoError(fmt::format("{}: {}: {}", path, where, msg));
    }

    /// Reads accessor `index` as `count` x `ncomp` floats (normalised integers mapped to
    /// [0,1] / [-1,1] as the glTF spec says). Every byte read is bounds-checked.
    std::vector<float> read_floats(int index, int ncomp, const std::string &where, size_t *count_out) const {
        const tinygltf::Accessor &a = accessor(index, where);
        int n = tinygltf::GetNumComponentsInType(uint32_t(a.type));
        if (n != ncomp) fail(where, fmt::format("expected {} components per element, got {}", ncomp, n));
        int csize = tinygltf::GetComponentSizeInBytes(uint32_t(a.componentType));
        if (csize <= 0) fail(where, fmt::format("unsupported component type {}", a.componentType));
        if (a.componentType != TINYGLTF_COMPONENT_TYPE_FLOAT && !a.normalized)
            fail(where, "integer components must be normalized");
        *count_out = a.count;
        const unsigned char *base = nullptr;
        size_t stride = 0;
        // Bounds first, so that a corrupt count cannot make us allocate gigabytes.
        bool has_data = view(a, size_t(ncomp * csize), where, &base, &stride);
        std::vector<float> out(a.count * size_t(ncomp), 0.f);
        if (!has_data) return out;  // no buffer view: zeros
        for (size_t i = 0; i < a.count; ++i) {
            const unsigned char *e = base + i * stride;
            for (int c = 0; c < ncomp; ++c) out[i * ncomp + c] = component(e + c * csize, a.componentType);
        }
        return out;
    }

    /// Reads an index accessor (unsigned byte / short / int).
    std::vector<uint32_t> read_indices(int index, const std::string &where) const {
        const tinygltf::Accessor &a = accessor(index, where);
        if (a.type != TINYGLTF_TYPE_SCALAR) fail(where, "indices must be scalars");
        int csize = 0;
        switch (a.componentType) {
            case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE: csize = 1; break;
            case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: csize = 2; break;
            case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT: csize = 4; break;
            default: fail(where, fmt::format("indices must be unsigned byte, short or int (component type {})", a.componentType));
        }
        const unsigned char *base = nullptr;
        size_t stride = 0;
        bool has_data = view(a, size_t(csize), where, &base, &stride);
        std::vector<uint32_t> out(a.count, 0);
        if (!has_data) return out;
        for (size_t i = 0; i < a.count; ++i) {
            const unsigned char *e = base + i * stride;
            uint32_t v = 0;
            if (csize == 1) v = e[0];
            else if (csize == 2) { uint16_t s; std::memcpy(&s, e, 2); v = s; }
            else std::memcpy(&v, e, 4);
            out[i] = v;
        }
        return out;
    }

    const tinygltf::Accessor &accessor(int index, const std::string &where) const {
        if (index < 0 || size_t(index) >= model.accessors.size())
            fail(where, fmt::format("accessor {} does not exist ({} accessors)", index, model.accessors.size()));
        const tinygltf::Accessor &a = model.accessors[size_t(index)];
        if (a.sparse.isSparse) fail(where, "sparse accessors are not supported");
        if (a.count > (size_t(1) << 31)) fail(where, fmt::format("accessor {} has too many elements", index));
        return a;
    }

    /// Locates the accessor's bytes; false when it has no buffer view (all zeros).
    bool view(const tinygltf::Accessor &a, size_t elem_bytes, const std::string &where, const unsigned char **base,
              size_t *stride) const {
        if (a.bufferView < 0) {
            // Spec: all zeros (meant for sparse accessors); refuse absurd sizes.
            if (a.count > (size_t(1) << 24)) fail(where, fmt::format("accessor without data has {} elements", a.count));
            return false;
        }
        if (size_t(a.bufferView) >= model.bufferViews.size()) fail(where, fmt::format("buffer view {} does not exist", a.bufferView));
        const tinygltf::BufferView &bv = model.bufferViews[size_t(a.bufferView)];
        if (bv.buffer < 0 || size_t(bv.buffer) >= model.buffers.size()) fail(where, fmt::format("buffer {} does not exist", bv.buffer));
        const tinygltf::Buffer &buf = model.buffers[size_t(bv.buffer)];
        size_t s = bv.byteStride ? bv.byteStride : elem_bytes;
        if (s < elem_bytes) fail(where, fmt::format("byte stride {} is smaller than an element ({} bytes)", s, elem_bytes));
        size_t start = bv.byteOffset + a.byteOffset;
        size_t need = a.count == 0 ? 0 : (a.count - 1) * s + elem_bytes;
        if (bv.byteOffset > buf.data.size() || bv.byteLength > buf.data.size() - bv.byteOffset ||
            a.byteOffset > bv.byteLength || need > bv.byteLength - a.byteOffset)
            fail(where, fmt::format("accessor data lies outside its buffer ({} bytes needed at offset {}, buffer has {})",
                                    need, start, buf.data.size()));
        *base = buf.data.data() + start;
        *stride = s;
        return true;
    }

    static float component(const unsigned char *p, int type) {
        switch (type) {
            case TINYGLTF_COMPONENT_TYPE_FLOAT: { float f; std::memcpy(&f, p, 4); return f; }
            case TINYGLTF_COMPONENT_TYPE_DOUBLE: { double d; std::memcpy(&d, p, 8); return float(d); }
            case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE: return p[0] / 255.f;
            case TINYGLTF_COMPONENT_TYPE_BYTE: return std::max(int8_t(p[0]) / 127.f, -1.f);
            case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: { uint16_t v; std::memcpy(&v, p, 2); return v / 65535.f; }
            case TINYGLTF_COMPONENT_TYPE_SHORT: { int16_t v; std::memcpy(&v, p, 2); return std::max(v / 32767.f, -1.f); }
            case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT: { uint32_t v; std::memcpy(&v, p, 4); return float(v / 4294967295.0); }
            case TINYGLTF_COMPONENT_TYPE_INT: { int32_t v; std::memcpy(&v, p, 4); return float(std::max(v / 2147483647.0, -1.0)); }
            default: return 0.f;
        }
    }

    /// One primitive in world space; false (with a warning) when it is skipped.
    bool primitive(const tinygltf::Primitive &prim, const Mat4 &world, const std::string &where, TriangleMesh &out) const {
        int mode = prim.mode < 0 ? TINYGLTF_MODE_TRIANGLES : prim.mode;
        if (mode != TINYGLTF_MODE_TRIANGLES && mode != TINYGLTF_MODE_TRIANGLE_STRIP && mode != TINYGLTF_MODE_TRIANGLE_FAN) {
            warn_once(fmt::format("{}: skipped (mode {} is not a triangle mode)", where, mode));
            return false;
        }
        if (!prim.targets.empty())
            warn_once(fmt::format("{}: its {} morph targets are ignored (meso renders the base shape)", where, prim.targets.size()));
        auto pos_it = prim.attributes.find("POSITION");
        if (pos_it == prim.attributes.end()) {
            warn_once(fmt::format("{}: skipped (no POSITION attribute)", where));
            return false;
        }
        size_t nv = 0;
        std::vector<float> pos = read_floats(pos_it->second, 3, where + ": POSITION", &nv);
        auto optional = [&](const char *name, int ncomp) {
            std::vector<float> v;
            auto it = prim.attributes.find(name);
            if (it == prim.attributes.end()) return v;
            size_t n = 0;
            v = read_floats(it->second, ncomp, where + ": " + name, &n);
            if (n != nv) fail(where + ": " + name, fmt::format("has {} elements, POSITION has {}", n, nv));
            return v;
        };
        std::vector<float> nor = optional("NORMAL", 3), uv = optional("TEXCOORD_0", 2), tan = optional("TANGENT", 4);

        std::vector<uint32_t> idx;
        if (prim.indices >= 0) {
            idx = read_indices(prim.indices, where + ": indices");
        } else {
            idx.resize(nv);
            for (size_t i = 0; i < nv; ++i) idx[i] = uint32_t(i);
        }
        for (size_t i = 0; i < idx.size(); ++i)
            if (idx[i] >= nv) fail(where + ": indices", fmt::format("index {} = {} is out of range ({} vertices)", i, idx[i], nv));

        // Strips and fans become lists; glTF's winding rule for strips alternates.
        std::vector<uint32_t> tri;
        if (mode == TINYGLTF_MODE_TRIANGLES) {
            if (idx.size() % 3 != 0)
                warn_once(fmt::format("{}: {} indices is not a multiple of 3; the last {} ignored", where, idx.size(),
                                       idx.size() % 3));
            tri.assign(idx.begin(), idx.begin() + (idx.size() / 3) * 3);
        } else if (mode == TINYGLTF_MODE_TRIANGLE_STRIP) {
            for (size_t i = 0; i + 2 < idx.size(); ++i) {
                if (i % 2 == 0) tri.insert(tri.end(), {idx[i], idx[i + 1], idx[i + 2]});
                else tri.insert(tri.end(), {idx[i + 1], idx[i], idx[i + 2]});
            }
        } else {
            for (size_t i = 1; i + 1 < idx.size(); ++i) tri.insert(tri.end(), {idx[i], idx[i + 1], idx[0]});
        }
        if (tri.empty()) {
            warn_once(fmt::format("{}: skipped (no triangles)", where));
            return false;
        }

        double det = det3(world);
        if (!all_finite(world) || det == 0.0 || !std::isfinite(det)) {
            warn_once(fmt::format("{}: skipped (its node transform is singular)", where));
            return false;
        }
        double cof[3][3];
        cofactor3(world, cof);
        double sgn = det < 0 ? -1.0 : 1.0;

        out = TriangleMesh();
        out.positions.resize(nv);
        for (size_t i = 0; i < nv; ++i) {
            Vec3 p(pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]);
            if (!is_finite(p)) fail(where + ": POSITION", fmt::format("vertex {} is not finite", i));
            out.positions[i] = apply_point(world, p);
            if (!is_finite(out.positions[i])) fail(where, fmt::format("vertex {} is not finite after the node transform", i));
        }
        if (!nor.empty()) {
            out.normals.resize(nv);
            for (size_t i = 0; i < nv; ++i) {
                double x = nor[3 * i], y = nor[3 * i + 1], z = nor[3 * i + 2];
                Vec3 n(float(sgn * (cof[0][0] * x + cof[0][1] * y + cof[0][2] * z)),
                       float(sgn * (cof[1][0] * x + cof[1][1] * y + cof[1][2] * z)),
                       float(sgn * (cof[2][0] * x + cof[2][1] * y + cof[2][2] * z)));
                n = normalize(n);
                out.normals[i] = is_finite(n) ? n : Vec3();
            }
            // Zero-length normals cannot shade: fall back to flat shading for the mesh.
            bool ok = std::all_of(out.normals.begin(), out.normals.end(), [](Vec3 n) { return length_squared(n) > 0.5f; });
            if (!ok) {
                warn_once(fmt::format("{}: some normals are zero or not finite; using flat shading", where));
                out.normals.clear();
            }
        }
        if (!uv.empty()) {
            out.uvs.resize(nv);
            for (size_t i = 0; i < nv; ++i) {
                Vec2 t(uv[2 * i], uv[2 * i + 1]);
                out.uvs[i] = std::isfinite(t.x) && std::isfinite(t.y) ? t : Vec2();
            }
        }
        if (!tan.empty()) {
            out.tangents.resize(nv);
            out.tangent_signs.resize(nv);
            bool ok = true;
            for (size_t i = 0; i < nv; ++i) {
                Vec3 t = normalize(apply_vector(world, Vec3(tan[4 * i], tan[4 * i + 1], tan[4 * i + 2])));
                if (!is_finite(t) || length_squared(t) < 0.5f) ok = false;
                out.tangents[i] = t;
                // A mirroring transform flips the handedness of (n, t, b).
                out.tangent_signs[i] = float((tan[4 * i + 3] < 0 ? -1.0 : 1.0) * sgn);
            }
            if (!ok) {
                warn_once(fmt::format("{}: some tangents are zero or not finite; ignoring TANGENT", where));
                out.tangents.clear();
                out.tangent_signs.clear();
            }
        }
        out.indices = std::move(tri);
        // glTF: a negative determinant makes the winding clockwise; keep it counter-clockwise.
        if (det < 0)
            for (size_t i = 0; i + 2 < out.indices.size(); i += 3) std::swap(out.indices[i + 1], out.indices[i + 2]);
        return true;
    }
};

/// Root nodes of the scene to render: the default scene, else scene 0, else every node
/// that is nobody's child.
std::vector<int> root_nodes(const tinygltf::Model &model) {
    if (!model.scenes.empty()) {
        int s = model.defaultScene >= 0 && size_t(model.defaultScene) < model.scenes.size() ? model.defaultScene : 0;
        return model.scenes[size_t(s)].nodes;
    }
    std::vector<bool> is_child(model.nodes.size(), false);
    for (const auto &n : model.nodes)
        for (int c : n.children)
            if (c >= 0 && size_t(c) < model.nodes.size()) is_child[size_t(c)] = true;
    std::vector<int> roots;
    for (size_t i = 0; i < model.nodes.size(); ++i)
        if (!is_child[i]) roots.push_back(int(i));
    return roots;
}

/// Visits every node instance of the scene with its world matrix (depth first, in file
/// order); errors on cycles and out-of-range node references.
template <typename Visit>
void traverse(const std::string &path, const tinygltf::Model &model, Visit visit) {
    std::vector<bool> on_stack(model.nodes.size(), false);
    std::function<void(int, const Mat4 &, int)> rec = [&](int index, const Mat4 &parent, int depth) {
        if (index < 0 || size_t(index) >= model.nodes.size())
            throw MesoError(fmt::format("{}: node {} does not exist ({} nodes)", path, index, model.nodes.size()));
        if (on_stack[size_t(index)]) throw MesoError(fmt::format("{}: node {} is its own ancestor", path, index));
        if (depth > 1000) throw MesoError(fmt::format("{}: the node hierarchy is deeper than 1000", path));
        on_stack[size_t(index)] = true;
        const tinygltf::Node &n = model.nodes[size_t(index)];
        Mat4 world = mul(parent, node_matrix(n));
        visit(index, n, world);
        for (int c : n.children) rec(c, world, depth + 1);
        on_stack[size_t(index)] = false;
    };
    for (int r : root_nodes(model)) rec(r, Mat4(), 0);
}

std::vector<GltfPrimitive> extract_primitives(const std::string &path, const tinygltf::Model &model) {
    Loader L{path, model, {}};
    std::vector<GltfPrimitive> out;
    traverse(path, model, [&](int, const tinygltf::Node &n, const Mat4 &world) {
        if (n.mesh < 0) return;
        if (size_t(n.mesh) >= model.meshes.size())
            throw MesoError(fmt::format("{}: mesh {} does not exist ({} meshes)", path, n.mesh, model.meshes.size()));
        const tinygltf::Mesh &m = model.meshes[size_t(n.mesh)];
        for (size_t k = 0; k < m.primitives.size(); ++k) {
            std::string where = m.name.empty() ? fmt::format("mesh {} primitive {}", n.mesh, k)
                                               : fmt::format("mesh '{}' primitive {}", m.name, k);
            GltfPrimitive gp;
            if (!L.primitive(m.primitives[k], world, where, gp.mesh)) continue;
            gp.material = m.primitives[k].material;
            if (gp.material >= int(model.materials.size())) {
                warn(path, fmt::format("{}: material {} does not exist; using the default", where, gp.material));
                gp.material = -1;
            }
            gp.mesh_index = n.mesh;
            gp.name = where;
            out.push_back(std::move(gp));
        }
    });
    return out;
}

// ---------------------------------------------------------------------------------------
// Cache (alive only inside a GltfCacheScope).

std::mutex g_cache_mutex;
int g_cache_scopes = 0;
std::map<std::string, std::shared_ptr<const std::vector<GltfPrimitive>>> g_cache;

std::string cache_key(const std::string &path) {
    std::error_code ec;
    fs::path p = fs::weakly_canonical(path, ec);
    return ec ? path : p.string();
}

void cache_put(const std::string &path, std::shared_ptr<const std::vector<GltfPrimitive>> prims) {
    std::lock_guard<std::mutex> lock(g_cache_mutex);
    if (g_cache_scopes > 0) g_cache[cache_key(path)] = std::move(prims);
}

std::shared_ptr<const std::vector<GltfPrimitive>> cache_get(const std::string &path) {
    std::lock_guard<std::mutex> lock(g_cache_mutex);
    if (g_cache_scopes == 0) return nullptr;
    auto it = g_cache.find(cache_key(path));
    return it == g_cache.end() ? nullptr : it->second;
}

// ---------------------------------------------------------------------------------------
// Scene translation.

/// A JSON-path-friendly, unique name for a glTF object.
std::string unique_name(const std::string &raw, const std::string &fallback, std::set<std::string> &used) {
    std::string s;
    for (char c : raw) s += (std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-') ? c : '_';
    if (s.empty()) s = fallback;
    std::string name = s;
    for (int i = 2; used.count(name); ++i) name = fmt::format("{}_{}", s, i);
    used.insert(name);
    return name;
}

bool has_plugin_light(const char *name) { return registry().lights.factories.count(name) > 0; }

/// The camera of camera node `index` at `world` (glTF cameras look down -z, +y up), or null,
/// with a warning, when it does not exist, is not perspective or its transform is degenerate.
json node_camera(const std::string &path, const tinygltf::Model &model, int index, const Mat4 &world) {
    if (size_t(index) >= model.cameras.size()) {
        warn(path, fmt::format("camera {} does not exist; ignored", index));
        return json();
    }
    const tinygltf::Camera &gc = model.cameras[size_t(index)];
    if (gc.type != "perspective") {
        warn(path, fmt::format("camera {} is '{}', not perspective; ignored", index, gc.type));
        return json();
    }
    const auto &pc = gc.perspective;
    Vec3 o = apply_point(world, Vec3(0, 0, 0));
    Vec3 fwd = normalize(apply_vector(world, Vec3(0, 0, -1)));
    Vec3 up = normalize(apply_vector(world, Vec3(0, 1, 0)));
    double fov = pc.yfov * 180.0 / Pi;
    if (!(fov > 0 && fov < 180)) fov = 40;
    int height = 480, width = 640;
    if (pc.aspectRatio > 0 && std::isfinite(pc.aspectRatio))
        width = std::max(1, std::min(65536, int(std::lround(height * pc.aspectRatio))));
    if (!(is_finite(o) && length_squared(fwd) > 0.5f && length_squared(up) > 0.5f)) {
        warn(path, "the camera node's transform is degenerate; ignored");
        return json();
    }
    return {{"type", "perspective"}, {"origin", vec3_json(o)}, {"target", vec3_json(o + fwd)},
            {"up", vec3_json(up)},   {"fov", fov},             {"fov_axis", "y"},
            {"width", width},        {"height", height}};
}

/// The KHR_lights_punctual light of node `n` at `world` (lights point down the node's -z), or
/// null: no light, or (with a warning) a missing light or one of an unknown type. Spot lights
/// become point lights when no `spot` plugin is registered.
json node_light(const std::string &path, const tinygltf::Model &model, const tinygltf::Node &n, const Mat4 &world) {
    auto ext = n.extensions.find("KHR_lights_punctual");
    if (ext == n.extensions.end() || !ext->second.IsObject() || !ext->second.Has("light")) return json();
    const auto &lv = ext->second.Get("light");
    int li = lv.IsNumber() ? int(lv.GetNumberAsDouble()) : -1;
    if (li < 0 || size_t(li) >= model.lights.size()) {
        warn(path, fmt::format("light {} does not exist; ignored", li));
        return json();
    }
    const tinygltf::Light &gl = model.lights[size_t(li)];
    Vec3 color(1, 1, 1);
    if (gl.color.size() >= 3) color = Vec3(float(gl.color[0]), float(gl.color[1]), float(gl.color[2]));
    Vec3 power = color * float(gl.intensity);
    if (!is_finite(power)) power = Vec3();
    Vec3 pos = apply_point(world, Vec3(0, 0, 0));
    Vec3 dir = normalize(apply_vector(world, Vec3(0, 0, -1)));
    if (gl.type == "directional")
        return {{"type", "directional"}, {"direction", vec3_json(dir)}, {"irradiance", vec3_json(power)}};
    if (gl.type == "spot" && has_plugin_light("spot")) {
        double cutoff = gl.spot.outerConeAngle * 180.0 / Pi;
        cutoff = std::isfinite(cutoff) ? std::min(std::max(cutoff, 0.01), 180.0) : 45.0;
        double beam = gl.spot.innerConeAngle * 180.0 / Pi;
        beam = std::isfinite(beam) ? std::min(std::max(beam, 0.0), cutoff) : 0.0;
        return {{"type", "spot"},
                {"position", vec3_json(pos)},
                {"direction", vec3_json(dir)},
                {"intensity", vec3_json(power)},
                {"cutoff_angle", cutoff},
                {"beam_width", beam}};
    }
    if (gl.type == "spot") {
        warn(path, fmt::format("light {}: spot lights become point lights", li));
    } else if (gl.type != "point") {
        warn(path, fmt::format("light {}: unknown type '{}'; ignored", li, gl.type));
        return json();
    }
    return {{"type", "point"}, {"position", vec3_json(pos)}, {"intensity", vec3_json(power)}};
}

/// The camera of a file without a usable one: looking at the bounding box of all primitives
/// from +z, far enough for it to fit a 40° field of view.
json framing_camera(const std::vector<GltfPrimitive> &prims) {
    Vec3 bmin(Infinity, Infinity, Infinity), bmax(-Infinity, -Infinity, -Infinity);
    for (const auto &p : prims)
        for (const Vec3 &v : p.mesh.positions) bmin = vmin(bmin, v), bmax = vmax(bmax, v);
    return framing_camera(bmin, bmax);
}

/// The scene's "shapes" (one `gltf` shape per primitive), "materials" (one named meso
/// material per glTF material that a primitive uses) and "textures" (emission and alpha
/// textures, declared once and named so that every shape of a material shares them);
/// emissive materials make area emitters.
struct GltfShapes {
    json materials = json::object();
    json textures = json::object();
    json shapes = json::array();
    bool any_emitter = false;
};

/// What a glTF material gives its shapes: the meso material's name, an `area` emitter and
/// the alpha-mask keys (each null when there is none).
struct MappedMaterial {
    std::string name;
    json emitter, alpha;
};

/// Maps glTF material `index` into `out` (material, and named textures for a textured
/// emission — emissiveFactor × strength × emissiveTexture (sRGB) — and a textured alpha).
MappedMaterial map_material_for_shapes(const std::string &path, const tinygltf::Model &model, int index,
                                       std::set<std::string> &used, GltfShapes &out) {
    const tinygltf::Material &gm = model.materials[size_t(index)];
    MappedMaterial mm;
    mm.name = unique_name(gm.name, fmt::format("material_{}", index), used);
    json alpha;
    out.materials[mm.name] = map_material(path, model, gm, &alpha);
    auto named = [&](json tex, const std::string &suffix) -> json {
        if (!tex.is_object()) return tex;  // a constant stays inline
        out.textures[mm.name + suffix] = std::move(tex);
        return mm.name + suffix;  // material names are unique, so these are too
    };
    const Vec3 e = emission(gm);
    if (max_component(e) > 0.f) {
        const auto &et = gm.emissiveTexture;
        json tex = texture_json(path, model, et.index, et.texCoord, et.extensions, gm.name, "emissiveTexture", false, nullptr);
        mm.emitter = {{"type", "area"}, {"radiance", named(scaled(tex, vec3_json(e)), "_emission")}};
    }
    if (!alpha.is_null()) {
        alpha["alpha"] = named(alpha["alpha"], "_alpha");
        mm.alpha = std::move(alpha);
    }
    return mm;
}

GltfShapes primitive_shapes(const std::string &path, const tinygltf::Model &model,
                            const std::vector<GltfPrimitive> &prims) {
    GltfShapes out;
    const std::string file = fs::path(path).filename().string();
    std::map<int, MappedMaterial> mapped;
    std::set<std::string> used;
    for (size_t i = 0; i < prims.size(); ++i) {
        const GltfPrimitive &p = prims[i];
        json shape = {{"type", "gltf"}, {"filename", file}, {"primitive", i}};
        if (p.material >= 0) {
            auto it = mapped.find(p.material);
            if (it == mapped.end())
                it = mapped.emplace(p.material, map_material_for_shapes(path, model, p.material, used, out)).first;
            const MappedMaterial &mm = it->second;
            shape["material"] = mm.name;
            if (!mm.emitter.is_null()) {
                shape["emitter"] = mm.emitter;
                out.any_emitter = true;
            }
            if (!mm.alpha.is_null()) shape.update(mm.alpha);  // "alpha", "alpha_cutoff"
        }
        out.shapes.push_back(std::move(shape));
    }
    return out;
}

}  // namespace

// ---------------------------------------------------------------------------------------

GltfCacheScope::GltfCacheScope() {
    std::lock_guard<std::mutex> lock(g_cache_mutex);
    ++g_cache_scopes;
}
GltfCacheScope::~GltfCacheScope() {
    std::lock_guard<std::mutex> lock(g_cache_mutex);
    if (--g_cache_scopes == 0) g_cache.clear();
}

bool is_gltf_path(const std::string &path) {
    std::string ext = fs::path(path).extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    return ext == ".gltf" || ext == ".glb";
}

std::shared_ptr<const std::vector<GltfPrimitive>> load_gltf_primitives(const std::string &path) {
    if (auto cached = cache_get(path)) return cached;
    tinygltf::Model model;
    load_model(path, model);
    auto prims = std::make_shared<const std::vector<GltfPrimitive>>(extract_primitives(path, model));
    cache_put(path, prims);
    return prims;
}

std::vector<TriangleMesh> load_gltf_meshes(const std::string &path) {
    auto prims = load_gltf_primitives(path);
    std::vector<TriangleMesh> out;
    out.reserve(prims->size());
    for (const auto &p : *prims) out.push_back(p.mesh);
    return out;
}

json gltf_scene_to_json(const std::string &path) {
    tinygltf::Model model;
    load_model(path, model);
    auto prims = std::make_shared<const std::vector<GltfPrimitive>>(extract_primitives(path, model));
    cache_put(path, prims);  // the shapes below read the file through the cache

    // Camera: the first usable camera node in traversal order; lights: every punctual light
    // (one traversal, so warnings come in node order).
    json camera;
    std::vector<json> lights;
    traverse(path, model, [&](int, const tinygltf::Node &n, const Mat4 &world) {
        if (n.camera >= 0 && camera.is_null()) camera = node_camera(path, model, n.camera, world);
        json light = node_light(path, model, n, world);
        if (!light.is_null()) lights.push_back(std::move(light));
    });

    json scene = json::object();
    scene["camera"] = camera.is_null() ? framing_camera(*prims) : camera;
    // Written out so that -D integrator.* / sampler.* overrides work on glTF scenes too.
    scene["integrator"] = {{"type", "path"}};
    scene["sampler"] = {{"type", "independent"}, {"sample_count", 16}};

    GltfShapes shapes = primitive_shapes(path, model, *prims);
    if (!shapes.materials.empty()) scene["materials"] = shapes.materials;
    if (!shapes.textures.empty()) scene["textures"] = shapes.textures;
    scene["shapes"] = shapes.shapes;

    if (lights.empty() && !shapes.any_emitter) {
        warn(path, "no lights: adding a constant environment of radiance 1");
        lights.push_back({{"type", "constant"}, {"radiance", 1.0}});
    }
    scene["lights"] = lights;
    return scene;
}

}  // namespace meso
