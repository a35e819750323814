/// @file mesh.h
/// Triangle meshes read from Wavefront OBJ files, the input of mesh obstacles (shape.h turns
/// them into level sets with OpenVDB's mesh conversion).
///
/// Units: the file's own coordinates (scene units once the obstacle's transform is applied).
/// Errors: readObj throws InputError naming the OBJ file and the line ("line 12").
/// Thread safety: plain values and pure functions.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "penumbra/math.h"

namespace penumbra {

struct TriangleMesh {
    std::vector<Vec3> vertices;
    std::vector<std::array<uint32_t, 3>> triangles;

    Box3 bounds() const;
    double area() const;
    /// Edges used by exactly one triangle, after merging vertices at identical positions (an
    /// OBJ may repeat a position for each normal). Zero for a closed surface.
    size_t boundaryEdgeCount() const;
};

/// Reads the `v` and `f` lines of an OBJ file (other statements, such as `vn`, `vt`, `g`, `o`,
/// `s`, `usemtl`, are skipped). Faces may use the `v`, `v/vt`, `v/vt/vn` and `v//vn` forms and
/// negative (relative) indices; polygons with more than three vertices are split into a fan of
/// triangles from their first vertex. Throws InputError (`file`, "line N", ...) for a malformed
/// number, a non-finite coordinate, a face with fewer than three vertices or an index out of
/// range, and for a file that cannot be read or holds no face.
TriangleMesh readObj(const std::string& file);

/// Closes the holes of an open mesh (a scan's missing base, say): every loop of boundary edges
/// gets a fan of triangles from its centroid, wound against the edges it closes (so that a
/// consistently wound mesh stays so). Returns the number of holes capped. OpenVDB's
/// signed mesh conversion needs a closed surface; with a hole wider than a voxel, its exterior
/// flood fill leaks inside and the whole interior comes out as outside.
size_t capHoles(TriangleMesh& mesh);

}  // namespace penumbra
