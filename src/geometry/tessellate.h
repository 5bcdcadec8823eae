// Explicit tessellation of a displaced mesh with OpenSubdiv (displacement mode "tessellate").
//
// The base mesh is refined uniformly and every refined vertex is moved along the normal
// by the height at its uv. It is the cross-check of the shell map and the way to render
// displacement at modest resolutions; memory grows with 4^level, so it refuses, before
// refining anything, to make more than Displacement::max_triangles triangles.
//
// Topology. Vertices are welded by position (a tolerance of 1e-6 of the mesh's largest
// bounding-box extent, so the uv seam and the split poles of a uv sphere, which are equal
// only up to float round-off of sin/cos, are not open boundaries for Catmull-Clark).
// Faces whose corners weld together are zero-area and dropped. The base vertices'
// (uv, normal) pairs are a face-varying channel, linearly interpolated (FVAR_LINEAR_ALL),
// so a seam keeps one uv per side.
//
// Surface. For the bilinear scheme a refined vertex is P + h(uv) N with P, N and uv the
// linear interpolation of the base triangle's corners at the same point, N NOT
// renormalised: exactly the shell map's offset surface (P + h N interpolated over the
// prism), so both modes describe the same surface at the vertices. Base vertex normals
// are per corner (face-varying), as the shell map uses them: a mesh with hard edges
// (per-face normals, like make_cube) opens cracks along those edges when heights are not
// zero, in both modes. For Catmull-Clark, P is the limit position and N the unit limit
// normal (cross product of the limit tangents, oriented like the base normals), shared by
// every face around a welded vertex. Meshes without normals get area-weighted vertex
// normals over the welded topology (unit length).
//
// Seams. A vertex on a uv seam is split into one output vertex per face-varying value and
// each is displaced with its own uv. The two sides meet only where the heights agree:
// a map that tiles seamlessly (every meso map is periodic) at integer tiling across the
// seam, and a height that does not depend on u along the pole rows of a uv sphere. That
// is the user's responsibility; elsewhere the surface has cracks, as it would in shell mode.
//
// Output. Triangles (each refined quad split along its 0-2 diagonal), positions and
// per-vertex uvs; normals are left EMPTY on purpose so meso shades each micro-triangle
// with its true facet normal (smooth shading would hide the very micro-geometry the
// tessellation is there to show).
#pragma once
#include <cstddef>
#include <string>
#include "geometry/displacement.h"
#include "geometry/mesh.h"

namespace meso {

/// The most levels meso refines to (OpenSubdiv's uniform refinement level is a 4-bit field).
constexpr int kMaxTessellationLevel = 15;

/// The displaced, tessellated mesh (see above). `where` prefixes every error message.
/// Throws MesoError when the base mesh has no uvs, when the level is more than
/// kMaxTessellationLevel, or when the result would have more than d.max_triangles
/// triangles (checked before refining).
TriangleMesh tessellate_displaced(const TriangleMesh &base, const Displacement &d, const std::string &where);

/// Triangles tessellate_displaced makes at `level`: per (non-degenerate) base triangle
/// 1 at level 0 and 2 * 3 * 4^(level-1) above (Catmull-Clark and bilinear refinement both
/// split a triangle into 3 quads, then each quad into 4). Saturates at SIZE_MAX.
size_t tessellated_triangle_count(const TriangleMesh &base, int level);

/// The smallest level at which every refined edge spans at most one map cell in cell space
/// (max(|dx|, |dy|) <= 1, uv mapped by Displacement::to_cell), so the tessellation has at
/// least the map's resolution: a refined edge never jumps over a grid vertex. Measured on
/// uvs (linear in both schemes). E.g. make_rectangle() with a 1024^2 map at tiling 1 gives
/// level 10 (3,145,728 triangles): the level-1 quads' longest edge is half the uv
/// diagonal, 512 cells. 0 for a mesh without uvs or without faces.
int auto_tessellation_level(const TriangleMesh &base, const Displacement &d);

}  // namespace meso
