#include "geometry/shell_shape.h"
#include <algorithm>
#include <array>
#include <cmath>
#include <unordered_map>
#include <emmintrin.h>
#include <fmt/format.h>
#include "core/error.h"
#include "sampling/warp.h"

namespace meso {

namespace {

using Mat3d = std::array<double, 9>;  // row-major

bool invert3(const Mat3d &m, Mat3d &inv, double &det) {
    det = m[0] * (m[4] * m[8] - m[5] * m[7]) - m[1] * (m[3] * m[8] - m[5] * m[6]) + m[2] * (m[3] * m[7] - m[4] * m[6]);
    if (!(std::abs(det) > 0.0) || !std::isfinite(det)) return false;
    double id = 1.0 / det;
    inv[0] = (m[4] * m[8] - m[5] * m[7]) * id;
    inv[1] = (m[2] * m[7] - m[1] * m[8]) * id;
    inv[2] = (m[1] * m[5] - m[2] * m[4]) * id;
    inv[3] = (m[5] * m[6] - m[3] * m[8]) * id;
    inv[4] = (m[0] * m[8] - m[2] * m[6]) * id;
    inv[5] = (m[2] * m[3] - m[0] * m[5]) * id;
    inv[6] = (m[3] * m[7] - m[4] * m[6]) * id;
    inv[7] = (m[1] * m[6] - m[0] * m[7]) * id;
    inv[8] = (m[0] * m[4] - m[1] * m[3]) * id;
    return true;
}

/// Matrix whose columns are the three edges v[1..3] - v[0].
Mat3d edge_matrix(const double v[4][3]) {
    Mat3d m;
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) m[r * 3 + c] = v[c + 1][r] - v[0][r];
    return m;
}

inline Vec3 mul3(const float *M, Vec3 v) {
    return Vec3(M[0] * v.x + M[1] * v.y + M[2] * v.z, M[3] * v.x + M[4] * v.y + M[5] * v.z,
                M[6] * v.x + M[7] * v.y + M[8] * v.z);
}
inline Vec3 mul3T(const float *M, Vec3 v) {
    return Vec3(M[0] * v.x + M[3] * v.y + M[6] * v.z, M[1] * v.x + M[4] * v.y + M[7] * v.z,
                M[2] * v.x + M[5] * v.y + M[8] * v.z);
}

void bounds_cb(const RTCBoundsFunctionArguments *args) {
    auto *s = static_cast<const ShellShape *>(args->geometryUserPtr);
    float lo[3], hi[3];
    s->prism_bounds(args->primID, lo, hi);
    RTCBounds *b = args->bounds_o;
    b->lower_x = lo[0], b->lower_y = lo[1], b->lower_z = lo[2];
    b->upper_x = hi[0], b->upper_y = hi[1], b->upper_z = hi[2];
}

void intersect_cb(const RTCIntersectFunctionNArguments *args) {
    auto *s = static_cast<const ShellShape *>(args->geometryUserPtr);
    RTCRayN *ray = RTCRayHitN_RayN(args->rayhit, args->N);
    RTCHitN *hit = RTCRayHitN_HitN(args->rayhit, args->N);
    for (unsigned i = 0; i < args->N; ++i) {
        if (!args->valid[i]) continue;
        Vec3 o(RTCRayN_org_x(ray, args->N, i), RTCRayN_org_y(ray, args->N, i), RTCRayN_org_z(ray, args->N, i));
        Vec3 d(RTCRayN_dir_x(ray, args->N, i), RTCRayN_dir_y(ray, args->N, i), RTCRayN_dir_z(ray, args->N, i));
        float &tfar = RTCRayN_tfar(ray, args->N, i);
        uint32_t tet;
        float x, y;
        if (s->intersect_prism(args->primID, o, d, RTCRayN_tnear(ray, args->N, i), tfar, tet, x, y)) {
            RTCHitN_u(hit, args->N, i) = x;
            RTCHitN_v(hit, args->N, i) = y;
            RTCHitN_Ng_x(hit, args->N, i) = 0.f;  // rebuilt by fill_interaction
            RTCHitN_Ng_y(hit, args->N, i) = 0.f;
            RTCHitN_Ng_z(hit, args->N, i) = 1.f;
            RTCHitN_primID(hit, args->N, i) = tet;
            RTCHitN_geomID(hit, args->N, i) = args->geomID;
            RTCHitN_instID(hit, args->N, i, 0) = args->context->instID[0];
        }
    }
}

void occluded_cb(const RTCOccludedFunctionNArguments *args) {
    auto *s = static_cast<const ShellShape *>(args->geometryUserPtr);
    for (unsigned i = 0; i < args->N; ++i) {
        if (!args->valid[i]) continue;
        RTCRayN *ray = args->ray;
        Vec3 o(RTCRayN_org_x(ray, args->N, i), RTCRayN_org_y(ray, args->N, i), RTCRayN_org_z(ray, args->N, i));
        Vec3 d(RTCRayN_dir_x(ray, args->N, i), RTCRayN_dir_y(ray, args->N, i), RTCRayN_dir_z(ray, args->N, i));
        float &tfar = RTCRayN_tfar(ray, args->N, i);
        if (s->occluded_prism(args->primID, o, d, RTCRayN_tnear(ray, args->N, i), tfar)) tfar = -Infinity;
    }
}

/// Tetrahedron k's world -> cell map applied to world point w (in double).
template <class Tet>
void map_to_cell(const Tet &T, const double w[3], double c[3]) {
    const double r[3] = {w[0] - T.w0[0], w[1] - T.w0[1], w[2] - T.w0[2]};
    for (int i = 0; i < 3; ++i) c[i] = T.t0[i] + T.A[3 * i] * r[0] + T.A[3 * i + 1] * r[1] + T.A[3 * i + 2] * r[2];
}

/// +1 (-1): the cell-space point (x, y, h) (x, y relative to the integer cell origin ox, oy)
/// lies above (below) the heightfield by more than `eps`; 0: too close to tell.
int side_of_surface(const Heightfield &hf, double x, double y, double h, int64_t ox, int64_t oy, double eps) {
    // Beyond the field's height range (a segment's end on the top or bottom of the shell): no
    // lookup (the bilinear height lies in [min, max] up to round-off far below eps).
    if (h > double(hf.max_height()) + eps) return 1;
    if (h < double(hf.min_height()) - eps) return -1;
    // The field is periodic: the origin reduced to one period keeps x + ox small (a huge
    // tiling would otherwise round the cell coordinate beyond what eps covers).
    if (ox < 0 || ox >= hf.width()) ox %= hf.width();
    if (oy < 0 || oy >= hf.height()) oy %= hf.height();
    const double gap = h - double(hf.eval(x + double(ox), y + double(oy)));
    return gap > eps ? 1 : gap < -eps ? -1 : 0;
}

}  // namespace

/// The Prism::same_map bits: tetrahedra k and k' share a map when k's map takes every vertex
/// of k' to its cell-space position within 8 float ulps of the prism's cell-space extent
/// (the round-off of one map; affine maps agree inside k' if they agree at its vertices).
uint8_t ShellShape::shared_maps(const Prism &P, const double wv[6][3], const double tv[6][3]) {
    static const int kTets[3][4] = {{0, 1, 2, 3}, {1, 2, 3, 4}, {2, 3, 4, 5}};
    double extent = 1.0;
    for (int v = 0; v < 6; ++v)
        for (int c = 0; c < 3; ++c) extent = std::max(extent, std::abs(tv[v][c]));
    const double tol = 8.0 * 0x1p-24 * extent;
    uint8_t bits = 0;
    for (int k = 0; k < 3; ++k)
        for (int k2 = k + 1; k2 < 3; ++k2) {
            if (!(P.valid >> k & 1) || !(P.valid >> k2 & 1)) continue;
            bool same = true;
            for (int q = 0; q < 4 && same; ++q) {
                double c[3];
                const int v = kTets[k2][q];
                map_to_cell(P.tet[k], wv[v], c);
                for (int i = 0; i < 3; ++i) same = same && std::abs(c[i] - tv[v][i]) <= tol;
            }
            if (same) bits |= uint8_t(1u << (k + k2 - 1));
        }
    return bits;
}

/// Prism::one_map and edges: the base triangle's barycentric coordinates as affine functions
/// of cell-space (x, y) (tv: the prism's cell-space vertices, 0..2 the bottom ones).
void ShellShape::set_one_map(Prism &P, const double tv[6][3]) {
    if (P.same_map != 7) return;
    const double x0 = tv[0][0], y0 = tv[0][1], x1 = tv[1][0], y1 = tv[1][1], x2 = tv[2][0], y2 = tv[2][1];
    const double det = (y1 - y2) * (x0 - x2) + (x2 - x1) * (y0 - y2);
    const double scale = std::max({std::abs(x0 - x2), std::abs(y0 - y2), std::abs(x1 - x2), std::abs(y1 - y2)});
    if (!(std::abs(det) > 1e-6 * scale * scale) || !std::isfinite(det)) return;
    const double e[2][2] = {{(y1 - y2) / det, (x2 - x1) / det}, {(y2 - y0) / det, (x0 - x2) / det}};
    for (int k = 0; k < 2; ++k) {
        P.edges[0][k] = float(e[k][0]);
        P.edges[1][k] = float(e[k][1]);
        P.edges[2][k] = float(-(e[k][0] * x2 + e[k][1] * y2));
    }
    // lambda_2 = 1 - lambda_0 - lambda_1; lane 3 repeats lambda_0.
    P.edges[0][2] = float(-(e[0][0] + e[1][0]));
    P.edges[1][2] = float(-(e[0][1] + e[1][1]));
    P.edges[2][2] = float(1.0 + e[0][0] * x2 + e[0][1] * y2 + e[1][0] * x2 + e[1][1] * y2);
    for (int r = 0; r < 3; ++r) P.edges[r][3] = P.edges[r][0];
    P.one_map = true;
}

ShellShape::ShellShape(const TriangleMesh &base, Displacement disp, std::string name)
    : m_disp(std::move(disp)), m_base(base), m_name(std::move(name)) {
    m_base.validate(m_name);
    if (m_base.uvs.empty()) throw MesoError(fmt::format("{}: displacement needs uv coordinates on the mesh", m_name));
    if (!m_disp.field) throw MesoError(fmt::format("{}: displacement without a height map", m_name));
    const std::vector<uint32_t> weld = weld_vertices(m_base);
    if (m_base.normals.empty()) m_base.normals = vertex_normals(m_base, weld);
    for (Vec3 &n : m_base.normals) n = normalize(n);
    // Welded copies share one position, and one normal where they agree up to round-off
    // (a uv seam), so prisms meeting there have bitwise the same shell vertices. Copies
    // with different normals (hard edges) keep theirs: the shell opens there, as the
    // tessellation does (documented).
    for (size_t i = 0; i < m_base.vertex_count(); ++i) {
        m_base.positions[i] = m_base.positions[weld[i]];
        if (dot(m_base.normals[i], m_base.normals[weld[i]]) > 1.f - 1e-5f) m_base.normals[i] = m_base.normals[weld[i]];
    }
    const size_t ntri = m_base.triangle_count();

    // Shell heights: the field's range, padded so a flat field still has a volume.
    double edge_sum = 0;
    for (size_t t = 0; t < ntri; ++t)
        edge_sum += length(m_base.positions[m_base.indices[3 * t + 1]] - m_base.positions[m_base.indices[3 * t]]);
    const double mean_edge = ntri ? edge_sum / double(ntri) : 1.0;
    const double thick = double(m_disp.field->max_height()) - m_disp.field->min_height();
    const double pad = std::max({1e-3 * thick, 1e-4 * mean_edge, 1e-12});
    m_hmin = float(m_disp.field->min_height() - pad);
    m_hmax = float(m_disp.field->max_height() + pad);
    m_inv_thick = 1.f / (m_hmax - m_hmin);

    std::vector<float> areas;
    std::vector<PrismCorners> corners;
    m_prisms.reserve(ntri);
    const double cw = double(m_disp.field->width()) * m_disp.tiling_u, ch = double(m_disp.field->height()) * m_disp.tiling_v;
    for (size_t t = 0; t < ntri; ++t) {
        uint32_t v[3] = {m_base.indices[3 * t], m_base.indices[3 * t + 1], m_base.indices[3 * t + 2]};
        // Order by welded index: the diagonal rule then depends on shared edges only.
        std::sort(v, v + 3, [&](uint32_t a, uint32_t b) { return weld[a] < weld[b]; });
        if (weld[v[0]] == weld[v[1]] || weld[v[1]] == weld[v[2]]) continue;  // zero-area triangle
        float area = m_base.triangle_area(t);
        if (!(area > 0.f) || !std::isfinite(area)) continue;
        Prism P;
        double cx[3], cy[3];
        for (int k = 0; k < 3; ++k) cx[k] = m_base.uvs[v[k]].x * cw, cy[k] = m_base.uvs[v[k]].y * ch;
        P.ox = int64_t(std::floor(std::min({cx[0], cx[1], cx[2]})));
        P.oy = int64_t(std::floor(std::min({cy[0], cy[1], cy[2]})));
        // Vertices 0..2 bottom (a b c), 3..5 top (a' b' c').
        double wv[6][3], tv[6][3];
        for (int k = 0; k < 6; ++k) {
            uint32_t vi = v[k % 3];
            double h = k < 3 ? m_hmin : m_hmax;
            Vec3 pw = m_base.positions[vi] + m_base.normals[vi] * float(h);  // same floats for shared vertices
            wv[k][0] = pw.x, wv[k][1] = pw.y, wv[k][2] = pw.z;
            tv[k][0] = cx[k % 3] - double(P.ox), tv[k][1] = cy[k % 3] - double(P.oy), tv[k][2] = h;
        }
        static const int kTets[3][4] = {{0, 1, 2, 3}, {1, 2, 3, 4}, {2, 3, 4, 5}};
        double max_edge = 0;
        for (int a = 0; a < 6; ++a)
            for (int b = a + 1; b < 6; ++b) {
                double e = std::sqrt(sqr(wv[a][0] - wv[b][0]) + sqr(wv[a][1] - wv[b][1]) + sqr(wv[a][2] - wv[b][2]));
                max_edge = std::max(max_edge, e);
            }
        for (int k = 0; k < 3; ++k) {
            double W[4][3], T[4][3];
            for (int q = 0; q < 4; ++q)
                for (int c = 0; c < 3; ++c) W[q][c] = wv[kTets[k][q]][c], T[q][c] = tv[kTets[k][q]][c];
            Mat3d E = edge_matrix(W), Binv, TM = edge_matrix(T);
            double det;
            if (!invert3(E, Binv, det) || std::abs(det) < 1e-9 * max_edge * max_edge * max_edge) continue;
            Tet &tt = P.tet[k];
            for (int c = 0; c < 3; ++c) tt.w0[c] = float(W[0][c]), tt.t0[c] = float(T[0][c]);
            for (int c = 0; c < 3; ++c) {
                tt.N[c][0] = float(-(Binv[c] + Binv[3 + c] + Binv[6 + c]));
                for (int k = 0; k < 3; ++k) tt.N[c][k + 1] = float(Binv[3 * k + c]);
            }
            for (int r = 0; r < 3; ++r)
                for (int c = 0; c < 3; ++c)
                    tt.A[r * 3 + c] = float(TM[r * 3 + 0] * Binv[0 * 3 + c] + TM[r * 3 + 1] * Binv[1 * 3 + c] +
                                            TM[r * 3 + 2] * Binv[2 * 3 + c]);
            P.valid |= uint8_t(1u << k);
        }
        if (!P.valid) continue;
        P.same_map = shared_maps(P, wv, tv);
        set_one_map(P, tv);
        PrismCorners &pc = corners.emplace_back();
        std::copy(&wv[0][0], &wv[0][0] + 18, &pc.wv[0][0]);
        std::copy(&tv[0][0], &tv[0][0] + 18, &pc.tv[0][0]);
        for (int k = 0; k < 3; ++k) pc.weld[k] = weld[v[k]];
        m_prisms.push_back(P);
        m_prism_tri.push_back(uint32_t(t));
        areas.push_back(area);
        m_base_area += area;
    }
    if (m_prisms.empty()) throw MesoError(fmt::format("{}: the displaced mesh has no triangle with an area", m_name));
    m_area_distr = Distribution1D(areas);
    pair_prisms(corners);
}

namespace {

/// The edge functions of the quad v0 v1 v2 v3 (cell-space x, y; the triangles v0 v1 v3 and
/// v1 v2 v3 share the diagonal v1 v3) as Prism::edges: e_k >= 0 on the inner side of edge
/// v_k v_k+1, scaled to 1 at the vertex farthest from it. False unless v0 and v2 lie on
/// opposite sides of the diagonal and the quad is convex (every vertex inside every edge, to
/// 1e-7 of the scale: a sliver far below the clip's 1e-5 pad).
bool quad_edges(const double v[4][2], float edges[3][4]) {
    auto cross = [&](int a, int b, int c) {
        return (v[b][0] - v[a][0]) * (v[c][1] - v[a][1]) - (v[b][1] - v[a][1]) * (v[c][0] - v[a][0]);
    };
    const double s0 = cross(1, 3, 0), s2 = cross(1, 3, 2);
    if (!(s0 * s2 < 0.0)) return false;
    const double orient = s0 > 0.0 ? 1.0 : -1.0;  // +1: v0 v1 v2 v3 counter-clockwise
    for (int k = 0; k < 4; ++k) {
        const int k1 = (k + 1) % 4;
        // e(x, y) = orient * ((v_k1 - v_k) x ((x, y) - v_k)) = a x + b y + c.
        const double ex = v[k1][0] - v[k][0], ey = v[k1][1] - v[k][1];
        const double a = -orient * ey, b = orient * ex, c = orient * (ey * v[k][0] - ex * v[k][1]);
        double hi = 0.0, lo = 0.0;
        for (int j = 0; j < 4; ++j) {
            const double val = a * v[j][0] + b * v[j][1] + c;
            hi = std::max(hi, val);
            lo = std::min(lo, val);
        }
        if (!(hi > 0.0) || !std::isfinite(hi) || lo < -1e-7 * hi) return false;
        edges[0][k] = float(a / hi);
        edges[1][k] = float(b / hi);
        edges[2][k] = float(c / hi);
    }
    return true;
}

}  // namespace

void ShellShape::pair_prisms(const std::vector<PrismCorners> &corners) {
    // Two passes over base edges (welded). First, prisms pair across an edge that is the
    // longest (in cell space) of both: the diagonal of a triangulated rectangle, whatever the
    // order of the triangles. Then a prism pairs with the first unpaired neighbour it can.
    auto longest = [&](uint32_t p) {
        const double(*t)[3] = corners[p].tv;
        int best = 0;
        double len = -1.0;
        for (int e = 0; e < 3; ++e) {
            const double l = sqr(t[(e + 1) % 3][0] - t[e][0]) + sqr(t[(e + 1) % 3][1] - t[e][1]);
            if (l > len) len = l, best = e;
        }
        return best;
    };
    for (const bool diagonals : {true, false}) {
        std::unordered_map<uint64_t, std::pair<uint32_t, int>> owner;  // edge -> (prism, its edge)
        owner.reserve(m_prisms.size() * 2);
        for (uint32_t p = 0; p < uint32_t(m_prisms.size()); ++p) {
            if (!m_prisms[p].one_map || m_prisms[p].partner != kNoPartner) continue;
            const uint32_t *w = corners[p].weld;
            const int lp = diagonals ? longest(p) : -1;
            for (int e = 0; e < 3; ++e) {
                const uint32_t a = w[e], b = w[(e + 1) % 3];
                const uint64_t key = uint64_t(std::min(a, b)) << 32 | std::max(a, b);
                const auto [it, fresh] = owner.try_emplace(key, p, e);
                const uint32_t q = it->second.first;
                if (fresh || m_prisms[q].partner != kNoPartner) continue;
                if (diagonals && (e != lp || it->second.second != longest(q))) continue;
                if (try_pair(q, p, corners)) break;
            }
        }
    }
    m_prims.clear();
    for (uint32_t p = 0; p < uint32_t(m_prisms.size()); ++p)
        if (m_prisms[p].partner == kNoPartner || m_prisms[p].partner > p) m_prims.push_back(p);
}

/// Pairs prisms a < b (both one_map, sharing a base edge) into a quad if b's corners lie where
/// a's map takes them (within shared_maps' tolerance) and the two base triangles make a
/// convex quad in cell space; then a's edges become the quad's.
bool ShellShape::try_pair(uint32_t a, uint32_t b, const std::vector<PrismCorners> &corners) {
    Prism &A = m_prisms[a], &B = m_prisms[b];
    const PrismCorners &ca = corners[a], &cb = corners[b];
    if (!A.one_map || !B.one_map) return false;
    // b's cell-space corners relative to a's cell origin.
    double tb[6][3];
    const double sx = double(B.ox - A.ox), sy = double(B.oy - A.oy);
    double extent = 1.0;
    for (int v = 0; v < 6; ++v) {
        tb[v][0] = cb.tv[v][0] + sx, tb[v][1] = cb.tv[v][1] + sy, tb[v][2] = cb.tv[v][2];
        for (int c = 0; c < 3; ++c) extent = std::max({extent, std::abs(tb[v][c]), std::abs(ca.tv[v][c])});
    }
    const double tol = 8.0 * 0x1p-24 * extent;
    for (int v = 0; v < 6; ++v) {
        double c[3];
        map_to_cell(A.tet[0], cb.wv[v], c);
        for (int i = 0; i < 3; ++i)
            if (!(std::abs(c[i] - tb[v][i]) <= tol)) return false;
    }
    // The quad: a's vertex off the shared edge (m), one shared end (i), b's vertex off it (q),
    // the other shared end (j).
    int m = -1, q = -1;
    for (int k = 0; k < 3; ++k) {
        if (std::find(cb.weld, cb.weld + 3, ca.weld[k]) == cb.weld + 3) m = k;
        if (std::find(ca.weld, ca.weld + 3, cb.weld[k]) == ca.weld + 3) q = k;
    }
    if (m < 0 || q < 0) return false;
    const double quad[4][2] = {{ca.tv[m][0], ca.tv[m][1]},
                               {ca.tv[(m + 1) % 3][0], ca.tv[(m + 1) % 3][1]},
                               {tb[q][0], tb[q][1]},
                               {ca.tv[(m + 2) % 3][0], ca.tv[(m + 2) % 3][1]}};
    float e[3][4];
    if (!quad_edges(quad, e)) return false;
    std::copy(&e[0][0], &e[0][0] + 12, &A.edges[0][0]);
    A.partner = b;
    B.partner = a;
    return true;
}

void ShellShape::prism_bounds(uint32_t prim, float lo[3], float hi[3]) const {
    const uint32_t prism = m_prims[prim], partner = m_prisms[prism].partner;
    Vec3 l(Infinity, Infinity, Infinity), h(-Infinity, -Infinity, -Infinity);
    for (const uint32_t p : {prism, partner}) {
        if (p == kNoPartner) continue;
        const uint32_t t = m_prism_tri[p];
        for (int k = 0; k < 3; ++k) {
            uint32_t vi = m_base.indices[3 * t + k];
            Vec3 a = m_base.positions[vi] + m_base.normals[vi] * m_hmin,
                 b = m_base.positions[vi] + m_base.normals[vi] * m_hmax;
            l = vmin(l, vmin(a, b));
            h = vmax(h, vmax(a, b));
        }
    }
    // Padded by the relative size the tetrahedron clip is padded by.
    Vec3 pad = (h - l) * 1e-4f + vabs(l) * 1e-6f + Vec3(1e-20f, 1e-20f, 1e-20f);
    l -= pad;
    h += pad;
    lo[0] = l.x, lo[1] = l.y, lo[2] = l.z;
    hi[0] = h.x, hi[1] = h.y, hi[2] = h.z;
}

namespace {

/// The four lanes of n_k + t s_k >= -eps as bounds on t: a (entering faces, s > 0; else
/// -inf) and b (leaving faces, s < 0; else +inf). False if the ray runs parallel to a face
/// outside it.
inline bool lane_bounds(__m128 n, __m128 s, __m128 eps, __m128 &a, __m128 &b) {
    const __m128 zero = _mm_setzero_ps(), neg_eps = _mm_sub_ps(zero, eps);
    if (_mm_movemask_ps(_mm_and_ps(_mm_cmpeq_ps(s, zero), _mm_cmplt_ps(n, neg_eps)))) return false;
    const __m128 tk = _mm_div_ps(_mm_sub_ps(neg_eps, n), s);
    const __m128 enter = _mm_cmpgt_ps(s, zero), leave = _mm_cmplt_ps(s, zero);
    a = _mm_or_ps(_mm_and_ps(enter, tk), _mm_andnot_ps(enter, _mm_set1_ps(-Infinity)));
    b = _mm_or_ps(_mm_and_ps(leave, tk), _mm_andnot_ps(leave, _mm_set1_ps(Infinity)));
    return true;
}

/// The largest |lane|.
inline float max_abs_lane(__m128 v) {
    v = _mm_and_ps(v, _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff)));
    v = _mm_max_ps(v, _mm_shuffle_ps(v, v, _MM_SHUFFLE(2, 3, 0, 1)));
    v = _mm_max_ps(v, _mm_shuffle_ps(v, v, _MM_SHUFFLE(1, 0, 3, 2)));
    return _mm_cvtss_f32(v);
}

/// [t0, t1] narrowed to [max a, min b]; false if empty.
inline bool narrow(__m128 a, __m128 b, float &t0, float &t1) {
    a = _mm_max_ps(a, _mm_shuffle_ps(a, a, _MM_SHUFFLE(2, 3, 0, 1)));
    a = _mm_max_ps(a, _mm_shuffle_ps(a, a, _MM_SHUFFLE(1, 0, 3, 2)));
    b = _mm_min_ps(b, _mm_shuffle_ps(b, b, _MM_SHUFFLE(2, 3, 0, 1)));
    b = _mm_min_ps(b, _mm_shuffle_ps(b, b, _MM_SHUFFLE(1, 0, 3, 2)));
    t0 = std::max(t0, _mm_cvtss_f32(a));
    t1 = std::min(t1, _mm_cvtss_f32(b));
    return t0 <= t1;
}

}  // namespace

bool ShellShape::clip(const Tet &T, Vec3 o, Vec3 d, float &t0, float &t1) {
    // Barycentric coordinates along the ray, lambda_k(t) = n_k + t s_k, the four at once. In
    // float: the error of n (a few ulps of |N| |o - w0|) is of the order of the float rounding
    // of N itself and well inside the pad below.
    const __m128 rx = _mm_set1_ps(o.x - T.w0[0]), ry = _mm_set1_ps(o.y - T.w0[1]), rz = _mm_set1_ps(o.z - T.w0[2]);
    const __m128 nx = _mm_loadu_ps(T.N[0]), ny = _mm_loadu_ps(T.N[1]), nz = _mm_loadu_ps(T.N[2]);
    const __m128 n = _mm_add_ps(_mm_setr_ps(1.f, 0.f, 0.f, 0.f),
                                _mm_add_ps(_mm_add_ps(_mm_mul_ps(nx, rx), _mm_mul_ps(ny, ry)), _mm_mul_ps(nz, rz)));
    const __m128 s = _mm_add_ps(_mm_add_ps(_mm_mul_ps(nx, _mm_set1_ps(d.x)), _mm_mul_ps(ny, _mm_set1_ps(d.y))),
                                _mm_mul_ps(nz, _mm_set1_ps(d.z)));
    // Pad: the tetrahedra of a shell overlap a little along shared faces, by more than the
    // float error of N applied to a distant origin, so no ray slips between them.
    const float nmax = std::max(1.f, max_abs_lane(n));
    const __m128 eps = _mm_set1_ps(1e-5f + 1e-6f * nmax);
    __m128 a, b;
    return lane_bounds(n, s, eps, a, b) && narrow(a, b, t0, t1);
}

bool ShellShape::clip_prism(const Prism &P, Vec3 o, Vec3 d, float &t0, float &t1) const {
    const Tet &T = P.tet[0];
    const Vec3 c = Vec3(T.t0[0], T.t0[1], T.t0[2]) + mul3(T.A, o - Vec3(T.w0[0], T.w0[1], T.w0[2]));
    const Vec3 cd = mul3(T.A, d);
    // Six coordinates that are >= 0 inside the prism, along the ray n_k + t s_k: the four edge
    // functions of the base (Prism::edges: a triangle's barycentrics or a quad's edges) and
    // the height above the bottom and below the top (in units of the shell's thickness),
    // padded like clip() pads a tetrahedron's. Lanes: the edges; then (above the bottom, below
    // the top) twice.
    const float inv_thick = m_inv_thick;
    const __m128 bx = _mm_loadu_ps(P.edges[0]), by = _mm_loadu_ps(P.edges[1]), bc = _mm_loadu_ps(P.edges[2]);
    const __m128 n = _mm_add_ps(_mm_add_ps(_mm_mul_ps(bx, _mm_set1_ps(c.x)), _mm_mul_ps(by, _mm_set1_ps(c.y))), bc);
    const __m128 s = _mm_add_ps(_mm_mul_ps(bx, _mm_set1_ps(cd.x)), _mm_mul_ps(by, _mm_set1_ps(cd.y)));
    const float above = (c.z - m_hmin) * inv_thick, below = (m_hmax - c.z) * inv_thick, dz = cd.z * inv_thick;
    const __m128 nh = _mm_setr_ps(above, below, above, below), sh = _mm_setr_ps(dz, -dz, dz, -dz);
    const float nmax = std::max({1.f, max_abs_lane(n), std::abs(above), std::abs(below)});
    const __m128 eps = _mm_set1_ps(1e-5f + 1e-6f * nmax);
    __m128 a, b, a2, b2;
    if (!lane_bounds(n, s, eps, a, b) || !lane_bounds(nh, sh, eps, a2, b2)) return false;
    return narrow(_mm_max_ps(a, a2), _mm_min_ps(b, b2), t0, t1);
}

template <bool AnyHit>
bool ShellShape::trace_prism(uint32_t prim, Vec3 o, Vec3 d, float tnear, float tfar, float *t_hit, uint32_t *tet,
                             float *x, float *y) const {
    const uint32_t prism = m_prims[prim];
    const Prism &P = m_prisms[prism];
    struct Seg {
        float t0, t1;
        int k;
    } seg[3];
    int ns = 0;
    if (P.one_map) {
        // One clip of the whole prism (or quad) in cell space; traced through tetrahedron 0's map.
        float a = tnear, b = tfar;
        if (!clip_prism(P, o, d, a, b)) return false;
        seg[ns++] = {a, b, 0};
    } else {
        for (int k = 0; k < 3; ++k) {
            if (!(P.valid & (1u << k))) continue;
            float a = tnear, b = tfar;
            if (clip(P.tet[k], o, d, a, b)) seg[ns++] = {a, b, k};
        }
    }
    if (ns == 0) return false;
    for (int i = 1; i < ns; ++i)  // insertion sort of at most three segments by entry
        for (int j = i; j > 0 && seg[j].t0 < seg[j - 1].t0; --j) std::swap(seg[j], seg[j - 1]);
    // Overlapping segments of tetrahedra with one map become one segment, traced once.
    if (P.same_map) {
        int m = 1;
        for (int i = 1; i < ns; ++i) {
            Seg &last = seg[m - 1];
            if ((P.same_map >> (last.k + seg[i].k - 1) & 1) && seg[i].t0 <= last.t1) last.t1 = std::max(last.t1, seg[i].t1);
            else seg[m++] = seg[i];
        }
        ns = m;
    }
    bool found = false;
    float best = tfar;
    const Heightfield &hf = *m_disp.field;
    for (int i = 0; i < ns; ++i) {
        if (seg[i].t0 >= best) break;
        const Tet &T = P.tet[seg[i].k];
        // Re-base at the entry point: cell-space coordinates stay small and exact.
        const float ta = seg[i].t0, tb = std::min(seg[i].t1, best);
        const Vec3 pe = o + d * ta;
        const Vec3 te = Vec3(T.t0[0], T.t0[1], T.t0[2]) + mul3(T.A, pe - Vec3(T.w0[0], T.w0[1], T.w0[2]));
        const Vec3 td = mul3(T.A, d);
        if constexpr (AnyHit) {
            // Early out: the ray starts on one side of the surface and ends on the other, so
            // it crosses it in between (the heightfield is continuous): no traversal. The
            // ends are placed in double as the leaf test places the ray; eps covers the
            // float rounding of the local cell coordinate and of the bilinear height.
            const float len = tb - ta;
            const double eps = 1e-5 * (double(m_hmax) - m_hmin) + 1e-6 * std::max(std::abs(m_hmax), std::abs(m_hmin));
            const int s0 = side_of_surface(hf, te.x, te.y, te.z, P.ox, P.oy, eps);
            if (s0 != 0 && side_of_surface(hf, te.x + double(len) * td.x, te.y + double(len) * td.y,
                                           te.z + double(len) * td.z, P.ox, P.oy, eps) == -s0)
                return true;
            if (hf.occluded(te, td, 0.f, len, P.ox, P.oy)) return true;
        } else {
            HeightfieldHit h;
            if (hf.intersect(te, td, 0.f, tb - ta, h, P.ox, P.oy)) {
                float t = ta + h.t;
                if (t > tnear && t < best) {
                    best = t;
                    found = true;
                    *tet = 3 * prism + uint32_t(seg[i].k);
                    *x = h.x;
                    *y = h.y;
                }
            }
        }
    }
    if (found) *t_hit = best;
    return found;
}

bool ShellShape::intersect_prism(uint32_t prism, Vec3 o, Vec3 d, float tnear, float &tfar, uint32_t &tet, float &x,
                                 float &y) const {
    float t;
    if (!trace_prism<false>(prism, o, d, tnear, tfar, &t, &tet, &x, &y)) return false;
    tfar = t;
    return true;
}

bool ShellShape::occluded_prism(uint32_t prism, Vec3 o, Vec3 d, float tnear, float tfar) const {
    return trace_prism<true>(prism, o, d, tnear, tfar, nullptr, nullptr, nullptr, nullptr);
}

RTCGeometry ShellShape::build_embree(RTCDevice device) const {
    RTCGeometry g = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_USER);
    rtcSetGeometryUserPrimitiveCount(g, unsigned(m_prims.size()));
    rtcSetGeometryUserData(g, const_cast<ShellShape *>(this));
    rtcSetGeometryBoundsFunction(g, bounds_cb, nullptr);
    rtcSetGeometryIntersectFunction(g, intersect_cb);
    rtcSetGeometryOccludedFunction(g, occluded_cb);
    rtcCommitGeometry(g);
    return g;
}

void ShellShape::fill_interaction(const Ray &ray, float t, uint32_t prim, float u, float v,
                                  SurfaceInteraction &si) const {
    const Prism &P = m_prisms[prim / 3];
    const Tet &T = P.tet[prim % 3];
    const Heightfield &hf = *m_disp.field;
    float hx, hy;
    si.micro_height = hf.eval(double(u) + double(P.ox), double(v) + double(P.oy), hx, hy);
    si.t = t;
    si.shape = this;
    si.prim = prim;
    si.p = ray.o + ray.d * t;
    si.wo = -normalize(ray.d);
    // Micro-normal: the gradient of h - H(x, y) is a covector, so it maps to world space
    // with the transpose of the world-to-cell Jacobian A (= inverse-transpose of the
    // cell-to-world Jacobian). It points to increasing height, i.e. out of the base.
    Vec3 n = normalize(mul3T(T.A, Vec3(-hx, -hy, 1.f)));
    if (!(length_squared(n) > 0.f) || !is_finite(n)) n = si.wo;
    si.ng = si.ns = n;
    const double cw = double(hf.width()) * m_disp.tiling_u, ch = double(hf.height()) * m_disp.tiling_v;
    si.uv = Vec2(float((double(u) + double(P.ox)) / cw), float((double(v) + double(P.oy)) / ch));
    // Error bound of o + t d plus the intersector's cell-space round-off mapped to world.
    si.p_error = 2e-6f * (max_component(vabs(ray.o)) + t * max_component(vabs(ray.d))) +
                 1e-5f * (m_hmax - m_hmin) + 1e-9f;
    // dp/du, dp/dv of the displaced surface: J (dx/du, 0, h_x dx/du) with J = A^-1.
    Mat3d A, J;
    for (int i = 0; i < 9; ++i) A[i] = T.A[i];
    double det;
    bool ok = invert3(A, J, det);
    if (ok) {
        auto col = [&](double a, double b, double c) {
            return Vec3(float(J[0] * a + J[1] * b + J[2] * c), float(J[3] * a + J[4] * b + J[5] * c),
                        float(J[6] * a + J[7] * b + J[8] * c));
        };
        si.dpdu = col(cw, 0.0, hx * cw);
        si.dpdv = col(0.0, ch, hy * ch);
        // Footprints are measured on the base surface (the h = const plane of this
        // tetrahedron), in texels of the full tiled map (issue 4).
        si.dpdu_footprint = col(cw, 0.0, 0.0);
        si.dpdv_footprint = col(0.0, ch, 0.0);
        si.n_footprint = normalize(mul3T(T.A, Vec3(0.f, 0.f, 1.f)));
        ok = is_finite(si.dpdu) && is_finite(si.dpdv) && length_squared(cross(si.dpdu, si.dpdv)) > 0.f;
    }
    if (!ok) coordinate_system(n, si.dpdu, si.dpdv);
}

PositionSample ShellShape::sample_area(float u_prim, Vec2 u) const {
    PositionSample ps;
    size_t i = m_area_distr.sample_discrete(u_prim);
    uint32_t tri = m_prism_tri[i];
    Vec2 b = square_to_uniform_triangle(u);
    const uint32_t i0 = m_base.indices[3 * tri], i1 = m_base.indices[3 * tri + 1], i2 = m_base.indices[3 * tri + 2];
    float b2 = 1.f - b.x - b.y;
    ps.p = m_base.positions[i0] * b.x + m_base.positions[i1] * b.y + m_base.positions[i2] * b2;
    ps.n = normalize(m_base.normals[i0] * b.x + m_base.normals[i1] * b.y + m_base.normals[i2] * b2);
    ps.uv = m_base.uvs[i0] * b.x + m_base.uvs[i1] * b.y + m_base.uvs[i2] * b2;
    ps.pdf_area = m_base_area > 0.f ? 1.f / m_base_area : 0.f;
    ps.prim = uint32_t(i);
    return ps;
}

size_t ShellShape::memory_bytes() const {
    // Prisms + Embree's BVH over them (~64 B a primitive) + base mesh + heightfield.
    return m_prisms.size() * (sizeof(Prism) + sizeof(uint32_t) + 4) + m_prims.size() * (sizeof(uint32_t) + 64) +
           m_base.memory_bytes() +
           m_disp.field->memory_bytes();
}

std::string ShellShape::to_string() const {
    return fmt::format("{} (shell map: {} prisms over {} base triangles, {} Embree primitives; map {}x{} '{}' tiled {}x{}, heights [{:.4g}, "
                       "{:.4g}]; geometry {:.1f} MiB, of it heightfield {:.1f} MiB)",
                       m_name, m_prisms.size(), m_base.triangle_count(), m_prims.size(), m_disp.field->width(), m_disp.field->height(),
                       m_disp.source, m_disp.tiling_u, m_disp.tiling_v, m_disp.field->min_height(),
                       m_disp.field->max_height(), memory_bytes() / 1048576.0, m_disp.field->memory_bytes() / 1048576.0);
}

}  // namespace meso
