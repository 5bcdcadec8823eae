#include "geometry/tessellate.h"
#include <opensubdiv/far/primvarRefiner.h>
#include <opensubdiv/far/topologyDescriptor.h>
#include <opensubdiv/far/topologyRefinerFactory.h>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <unordered_map>
#include <fmt/format.h>
#include "core/error.h"

namespace meso {

namespace Far = OpenSubdiv::Far;
namespace Sdc = OpenSubdiv::Sdc;

namespace {

/// The base mesh on welded vertices: the topology OpenSubdiv refines.
struct WeldedMesh {
    std::vector<uint32_t> vertex_of;  ///< base vertex -> welded vertex
    std::vector<Vec3> positions;      ///< welded vertex positions (the first base vertex of each)
    std::vector<uint32_t> faces;      ///< kept triangles, 3 BASE vertex indices each
};

/// Welds base vertices with weld_vertices (mesh.h: within 1e-6 of the largest bounding-box
/// extent) into compact indices, and drops triangles two of whose corners weld together
/// (zero area; they would be non-manifold faces with a repeated vertex for OpenSubdiv).
WeldedMesh weld(const TriangleMesh &m) {
    WeldedMesh w;
    const size_t nv = m.positions.size();
    const std::vector<uint32_t> rep = weld_vertices(m);
    std::vector<uint32_t> compact(nv, UINT32_MAX);
    w.vertex_of.assign(nv, 0);
    for (size_t v = 0; v < nv; ++v) {
        uint32_t r = rep[v];
        if (compact[r] == UINT32_MAX) {
            compact[r] = uint32_t(w.positions.size());
            w.positions.push_back(m.positions[r]);
        }
        w.vertex_of[v] = compact[r];
    }
    w.faces.reserve(m.indices.size());
    for (size_t t = 0; t + 2 < m.indices.size(); t += 3) {
        uint32_t a = m.indices[t], b = m.indices[t + 1], c = m.indices[t + 2];
        if (a >= nv || b >= nv || c >= nv) continue;  // validate() reports these
        uint32_t wa = w.vertex_of[a], wb = w.vertex_of[b], wc = w.vertex_of[c];
        if (wa == wb || wb == wc || wc == wa) continue;
        w.faces.insert(w.faces.end(), {a, b, c});
    }
    return w;
}

size_t count_triangles(size_t faces, int level) {
    if (faces == 0) return 0;
    if (level <= 0) return faces;
    // 2 * 3 * 4^(level-1) per triangle, saturating.
    const size_t max = std::numeric_limits<size_t>::max();
    size_t per = 6;
    for (int l = 1; l < level; ++l) {
        if (per > max / 4) return max;
        per *= 4;
    }
    return faces > max / per ? max : faces * per;
}

int auto_level(const TriangleMesh &m, const WeldedMesh &w, const Displacement &d) {
    if (m.uvs.size() != m.positions.size() || !d.field) return 0;
    const double sx = double(d.field->width()) * d.tiling_u, sy = double(d.field->height()) * d.tiling_v;
    const double limit = 1.0 + 1e-3;  // round-off must not cost a level (4x the triangles)
    const int cap = 40;
    int level = 0;
    for (size_t t = 0; t < w.faces.size(); t += 3) {
        double x[3], y[3];
        for (int k = 0; k < 3; ++k) {
            Vec2 uv = m.uvs[w.faces[t + k]];
            x[k] = double(uv.x) * sx;
            y[k] = double(uv.y) * sy;
        }
        // Span of an edge in cells: the larger of its x and y extents (a norm, so the
        // halving argument below holds).
        auto len = [](double ax, double ay, double bx, double by) { return std::max(std::abs(bx - ax), std::abs(by - ay)); };
        double e0 = std::max({len(x[0], y[0], x[1], y[1]), len(x[1], y[1], x[2], y[2]), len(x[2], y[2], x[0], y[0])});
        if (!(e0 > limit)) continue;  // level 0 is enough (NaN uvs also end here)
        // Level 1: three quads (corner, edge midpoint, centroid, edge midpoint). Later
        // levels split those bilinearly, so their longest edge halves with each level
        // (an inner edge is a convex combination of two opposite outer edges).
        double gx = (x[0] + x[1] + x[2]) / 3.0, gy = (y[0] + y[1] + y[2]) / 3.0;
        double e1 = 0.5 * e0;
        for (int k = 0; k < 3; ++k) {
            int n = (k + 1) % 3;
            e1 = std::max(e1, len(0.5 * (x[k] + x[n]), 0.5 * (y[k] + y[n]), gx, gy));
        }
        int l = 1;
        while (e1 > limit && l < cap) {
            e1 *= 0.5;
            ++l;
        }
        level = std::max(level, l);
    }
    return level;
}

/// Vertex primvar: position and (welded) base normal.
struct VertexPrimvar {
    Vec3 p, n;
    void Clear() { p = n = Vec3(); }
    void AddWithWeight(const VertexPrimvar &s, float w) {
        p += w * s.p;
        n += w * s.n;
    }
};

/// Face-varying primvar: uv and the base corner normal.
struct FVarPrimvar {
    Vec2 uv;
    Vec3 n;
    void Clear() {
        uv = Vec2();
        n = Vec3();
    }
    void AddWithWeight(const FVarPrimvar &s, float w) {
        uv = uv + w * s.uv;
        n += w * s.n;
    }
};

/// Limit position or tangent, gathered from vertex primvars.
struct LimitPrimvar {
    Vec3 v;
    void Clear() { v = Vec3(); }
    void AddWithWeight(const VertexPrimvar &s, float w) { v += w * s.p; }
};

}  // namespace

size_t tessellated_triangle_count(const TriangleMesh &base, int level) {
    return count_triangles(weld(base).faces.size() / 3, level);
}

int auto_tessellation_level(const TriangleMesh &base, const Displacement &d) {
    return auto_level(base, weld(base), d);
}

namespace {

/// Throws unless the base mesh can be displaced: valid, with finite uvs and a height map.
void check_displacement_input(const TriangleMesh &base, const Displacement &d, const std::string &where) {
    base.validate(where);
    if (!d.field) throw MesoError(fmt::format("{}: displacement has no height map", where));
    if (base.uvs.empty()) throw MesoError(fmt::format("{}: displacement needs uv coordinates (the mesh has none)", where));
    for (const Vec2 &uv : base.uvs)
        if (!std::isfinite(uv.x) || !std::isfinite(uv.y))
            throw MesoError(fmt::format("{}: displacement: the mesh has a non-finite uv coordinate", where));
}

/// Throws, before anything is refined, when `level` would make more triangles than the
/// user allows, than OpenSubdiv refines to, or than meso can index.
void check_triangle_budget(int level, size_t ntris, const Displacement &d, const std::string &where) {
    const char *advice = "use \"mode\": \"shell\" (exact, memory independent of resolution) or raise --max-triangles";
    if (ntris > d.max_triangles)
        throw MesoError(fmt::format("{}: displacement: tessellating to level {} would make {} triangles, more than "
                                    "--max-triangles {}; {}",
                                    where, level, ntris, d.max_triangles, advice));
    if (level > kMaxTessellationLevel)
        throw MesoError(fmt::format("{}: displacement: tessellation level {} is more than {}, the most OpenSubdiv "
                                    "refines to; use \"mode\": \"shell\" (exact, memory independent of resolution)",
                                    where, level, kMaxTessellationLevel));
    // OpenSubdiv indexes with int; the output with uint32_t.
    if (ntris > (size_t(1) << 31))
        throw MesoError(fmt::format("{}: displacement: tessellating to level {} would make {} triangles, more than "
                                    "meso can index (2^31); use \"mode\": \"shell\" (exact, memory independent of "
                                    "resolution)",
                                    where, level, ntris));
}

/// The base mesh as OpenSubdiv's input: welded topology, vertex and face-varying values.
struct BasePrimvars {
    std::vector<VertexPrimvar> verts;       ///< per welded vertex
    std::vector<FVarPrimvar> fvar;          ///< per used base vertex, in order of first use
    std::vector<Far::Index> face_verts;     ///< 3 welded vertices per kept face
    std::vector<Far::Index> face_fvars;     ///< 3 face-varying values per kept face
};

BasePrimvars base_primvars(const TriangleMesh &base, const WeldedMesh &w) {
    const size_t nwelded = w.positions.size();
    // Area-weighted normals over the welded topology (shared with the shell map).
    std::vector<Vec3> geometric(nwelded);
    {
        const std::vector<Vec3> vn = vertex_normals(base, weld_vertices(base));
        for (size_t v = 0; v < vn.size(); ++v) geometric[w.vertex_of[v]] = vn[v];
    }
    auto base_normal = [&](uint32_t v) {
        if (!base.normals.empty()) {
            Vec3 n = base.normals[v];
            if (is_finite(n) && length_squared(n) > 0.f) return n;
        }
        return geometric[w.vertex_of[v]];
    };

    // Face-varying values: the base vertices the kept faces use, in order of first use.
    BasePrimvars b;
    std::vector<int> fvar_of(base.positions.size(), -1);
    b.face_verts.resize(w.faces.size());
    b.face_fvars.resize(w.faces.size());
    for (size_t i = 0; i < w.faces.size(); ++i) {
        uint32_t v = w.faces[i];
        if (fvar_of[v] < 0) {
            fvar_of[v] = int(b.fvar.size());
            b.fvar.push_back({base.uvs[v], base_normal(v)});
        }
        b.face_verts[i] = Far::Index(w.vertex_of[v]);
        b.face_fvars[i] = fvar_of[v];
    }
    // Vertex values: welded positions and a welded normal (the mean of the base normals
    // there; only orients the Catmull-Clark limit normal).
    b.verts.resize(nwelded);
    for (size_t v = 0; v < nwelded; ++v) b.verts[v].p = w.positions[v];
    if (!base.normals.empty()) {
        std::vector<Vec3> sum(nwelded);
        for (size_t v = 0; v < base.positions.size(); ++v)
            if (fvar_of[v] >= 0) sum[w.vertex_of[v]] += b.fvar[size_t(fvar_of[v])].n;
        for (size_t v = 0; v < nwelded; ++v) {
            Vec3 n = normalize(sum[v]);
            b.verts[v].n = length_squared(n) > 0.f ? n : geometric[v];
        }
    } else {
        for (size_t v = 0; v < nwelded; ++v) b.verts[v].n = geometric[v];
    }
    return b;
}

/// OpenSubdiv's refiner for the welded triangles, uniformly refined to `level`.
std::unique_ptr<Far::TopologyRefiner> refine_topology(const BasePrimvars &b, size_t nwelded, bool catmark, int level,
                                                      const std::string &where) {
    const size_t nfaces = b.face_verts.size() / 3;
    std::vector<int> verts_per_face(nfaces, 3);
    Far::TopologyDescriptor desc;
    desc.numVertices = int(nwelded);
    desc.numFaces = int(nfaces);
    desc.numVertsPerFace = verts_per_face.data();
    desc.vertIndicesPerFace = b.face_verts.data();
    Far::TopologyDescriptor::FVarChannel channel;
    channel.numValues = int(b.fvar.size());
    channel.valueIndices = b.face_fvars.data();
    desc.numFVarChannels = 1;
    desc.fvarChannels = &channel;

    Sdc::Options sdc;
    sdc.SetVtxBoundaryInterpolation(Sdc::Options::VTX_BOUNDARY_EDGE_AND_CORNER);
    sdc.SetFVarLinearInterpolation(Sdc::Options::FVAR_LINEAR_ALL);  // uv and normals linear, as in shell mode
    using Factory = Far::TopologyRefinerFactory<Far::TopologyDescriptor>;
    std::unique_ptr<Far::TopologyRefiner> refiner(Factory::Create(
        desc, Factory::Options(catmark ? Sdc::SCHEME_CATMARK : Sdc::SCHEME_BILINEAR, sdc)));
    if (!refiner) throw MesoError(fmt::format("{}: displacement: OpenSubdiv rejected the mesh topology", where));
    if (level > 0) {
        Far::TopologyRefiner::UniformOptions opts(level);
        opts.fullTopologyInLastLevel = catmark;  // the limit masks need the last level's edges
        refiner->RefineUniform(opts);
    }
    return refiner;
}

/// Refines the primvars level by level, keeping only the last two levels.
void refine_primvars(const Far::PrimvarRefiner &primvars, const Far::TopologyRefiner &refiner, int level,
                     BasePrimvars &b) {
    for (int l = 1; l <= level; ++l) {
        const Far::TopologyLevel &tl = refiner.GetLevel(l);
        std::vector<VertexPrimvar> vnext(size_t(tl.GetNumVertices()));
        primvars.Interpolate(l, b.verts, vnext);
        b.verts.swap(vnext);
        std::vector<FVarPrimvar> fnext(size_t(tl.GetNumFVarValues(0)));
        primvars.InterpolateFaceVarying(l, b.fvar, fnext, 0);
        b.fvar.swap(fnext);
    }
}

/// Catmull-Clark: per refined vertex, the limit position P and the unit limit normal N
/// (cross product of the limit tangents, oriented like the welded base normal).
void limit_surface(const Far::PrimvarRefiner &primvars, const std::vector<VertexPrimvar> &verts,
                   std::vector<Vec3> &limit_p, std::vector<Vec3> &limit_n) {
    const size_t n = verts.size();
    std::vector<LimitPrimvar> pos(n), du(n), dv(n);
    primvars.Limit(verts, pos, du, dv);
    limit_p.resize(n);
    limit_n.resize(n);
    for (size_t v = 0; v < n; ++v) {
        limit_p[v] = is_finite(pos[v].v) ? pos[v].v : verts[v].p;
        Vec3 nrm = normalize(cross(du[v].v, dv[v].v));
        Vec3 ref = normalize(verts[v].n);
        if (!is_finite(nrm) || length_squared(nrm) == 0.f) nrm = ref;  // degenerate tangents
        else if (dot(nrm, ref) < 0.f) nrm = -nrm;
        limit_n[v] = is_finite(nrm) ? nrm : Vec3();
    }
}

/// Output topology of the last level: one output vertex per face-varying value (a seam
/// vertex is split, each side keeping its uv), numbered in order of first use; quads split
/// along their 0-2 diagonal. Per output vertex: its face-varying value and refined vertex.
struct OutputTopology {
    std::vector<uint32_t> fv_of_out, vertex_of_out;
};

OutputTopology output_triangles(const Far::TopologyLevel &last, size_t nfvar, size_t ntris, TriangleMesh &out) {
    const int nlast = last.GetNumFaces();
    std::vector<uint32_t> out_of(nfvar, UINT32_MAX);
    OutputTopology t;
    t.vertex_of_out.reserve(nfvar);
    t.fv_of_out.reserve(nfvar);
    out.indices.reserve(ntris * 3);
    for (int f = 0; f < nlast; ++f) {
        Far::ConstIndexArray fv = last.GetFaceVertices(f), ff = last.GetFaceFVarValues(f, 0);
        uint32_t idx[4];
        const int n = std::min(fv.size(), 4);
        for (int k = 0; k < n; ++k) {
            uint32_t &o = out_of[size_t(ff[k])];
            if (o == UINT32_MAX) {
                o = uint32_t(t.fv_of_out.size());
                t.fv_of_out.push_back(uint32_t(ff[k]));
                t.vertex_of_out.push_back(uint32_t(fv[k]));
            }
            idx[k] = o;
        }
        for (int k = 2; k < n; ++k) out.indices.insert(out.indices.end(), {idx[0], idx[k - 1], idx[k]});
    }
    return t;
}

}  // namespace

TriangleMesh tessellate_displaced(const TriangleMesh &base, const Displacement &d, const std::string &where) {
    check_displacement_input(base, d, where);
    const WeldedMesh w = weld(base);
    const size_t nfaces = w.faces.size() / 3;
    const int level = d.level >= 0 ? d.level : auto_level(base, w, d);
    const size_t ntris = count_triangles(nfaces, level);
    check_triangle_budget(level, ntris, d, where);
    TriangleMesh out;
    if (nfaces == 0) return out;

    const bool catmark = d.scheme == SubdivScheme::CatmullClark;
    BasePrimvars b = base_primvars(base, w);
    std::unique_ptr<Far::TopologyRefiner> refiner = refine_topology(b, w.positions.size(), catmark, level, where);
    Far::PrimvarRefiner primvars(*refiner);
    refine_primvars(primvars, *refiner, level, b);

    // Per refined vertex: the point P and direction N it is displaced from and along.
    std::vector<Vec3> limit_p, limit_n;
    if (catmark) {
        limit_surface(primvars, b.verts, limit_p, limit_n);
        std::vector<VertexPrimvar>().swap(b.verts);  // P and N now live in limit_p / limit_n
    }

    const OutputTopology t = output_triangles(refiner->GetLevel(level), b.fvar.size(), ntris, out);
    const size_t nout = t.fv_of_out.size();
    out.positions.resize(nout);
    out.uvs.resize(nout);
    for (size_t o = 0; o < nout; ++o) {
        const FVarPrimvar &fv = b.fvar[t.fv_of_out[o]];
        const uint32_t v = t.vertex_of_out[o];
        const float h = d.height_at(fv.uv);
        // Bilinear: P and N interpolated linearly, N not renormalised (the shell map's
        // offset surface). Catmull-Clark: limit position and unit limit normal.
        Vec3 p = catmark ? limit_p[v] + h * limit_n[v] : b.verts[v].p + h * fv.n;
        out.positions[o] = is_finite(p) ? p : (catmark ? limit_p[v] : b.verts[v].p);
        out.uvs[o] = fv.uv;
    }
    return out;
}

}  // namespace meso
