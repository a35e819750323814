/// @file shape.h
/// Sculpted obstacles: implicit primitives, CSG trees, triangle meshes and level-set grids, each
/// with a similarity transform, and their conversion to one narrow-band level set.
///
/// A ShapeNode is a plain value tree. Primitives are given in their node's local frame and
/// `transform` maps that frame to the parent's (the world, for a root). Everything is built on
/// one index lattice (voxel centres at integer multiples of the voxel size), so CSG combines
/// the children voxel by voxel without resampling:
/// - primitives: their exact signed distance (Euclidean, through any similarity transform) is
///   sampled at the voxels of the band, blocks of 8^3 voxels being skipped when the distance at
///   their centre proves the whole block beyond the band;
/// - meshes: OpenVDB's meshToVolume, after capping holes (mesh.h); a mesh with a `thickness`
///   is a shell of that thickness around the surface instead (unsigned distance), for open
///   sheets;
/// - grids (.vdb level sets): rebuilt into the lattice by OpenVDB's levelSetRebuild;
/// - union, intersection, difference: OpenVDB's csgUnion / csgIntersection / csgDifference
///   (min and max of the distances), then the distances near the seams repaired: min and max
///   of exact distances are exact on one side of the result's surface (outside a union, inside
///   an intersection) and wrong within a few voxels of a seam on the other, where the nearest
///   surface point is on the seam itself; those voxels get their distance to the seam, taken
///   where the two surfaces' tangent planes meet (exact for planar faces, second order in the
///   voxel size for curved ones);
/// - smooth_union: the polynomial smooth minimum of the children's distances (Quilez,
///   "smooth minimum", k = blend), divided by its gradient's length near the surface.
///   Children of a smooth union are built with a band wider than k, which the blend reads.
///
/// Units: world space, scene units; voxel sizes in world units, band half widths in voxels.
/// Errors: buildLevelSet throws InputError for input a level set cannot represent (a mesh
/// enclosing no volume, a shape too small for the voxels: the level set would be empty).
/// Thread safety: values; buildLevelSet uses TBB internally and may run concurrently on
/// different shapes.
#pragma once

#include <memory>
#include <string>
#include <variant>
#include <vector>

#include "penumbra/level_set.h"
#include "penumbra/math.h"
#include "penumbra/mesh.h"

namespace penumbra {

/// x_parent = translate + scale * rotation * x_local (uniform scale, then rotation, then
/// translation).
struct Similarity {
    Mat3 rotation{1.0};
    double scale = 1.0;
    Vec3 translate{0.0};

    /// A scene file's transform: rotations about x, then y, then z (degrees), so
    /// rotation = Rz * Ry * Rx.
    static Similarity fromSceneTransform(const Vec3& translate, const Vec3& rotateDeg,
                                         double scale);

    Vec3 apply(const Vec3& local) const { return translate + scale * (rotation * local); }
    Vec3 applyInverse(const Vec3& parent) const {
        return (glm::transpose(rotation) * (parent - translate)) / scale;
    }
    bool isIdentity() const;
};

/// outer * inner maps inner's local frame through inner, then through outer.
Similarity operator*(const Similarity& outer, const Similarity& inner);

struct SphereShape {
    Vec3 center{0.0};
    double radius = 0.5;
};

/// Box of full extents `size`, edges rounded with radius `round` (0: sharp).
struct BoxShape {
    Vec3 center{0.0};
    Vec3 size{1.0};
    double round = 0.0;
};

/// Ring of tube radius minorRadius around the circle of radius majorRadius about `axis`.
struct TorusShape {
    Vec3 center{0.0};
    double majorRadius = 0.5;
    double minorRadius = 0.15;
    Vec3 axis{0.0, 0.0, 1.0};  ///< unit
};

/// Points within `radius` of the segment a-b.
struct CapsuleShape {
    Vec3 a{0.0};
    Vec3 b{0.0, 0.0, 1.0};
    double radius = 0.25;
};

/// Solid capped cylinder, `height` along `axis`, centred on `center`.
struct CylinderShape {
    Vec3 center{0.0};
    Vec3 axis{0.0, 0.0, 1.0};  ///< unit
    double radius = 0.5;
    double height = 1.0;
};

/// The side of the plane through `point` that `normal` points away from ((x - point) . normal
/// <= 0 is inside), cut to the world-space box `boundsWS` so that it has a finite band.
struct HalfSpaceShape {
    Vec3 point{0.0};
    Vec3 normal{0.0, 0.0, 1.0};  ///< unit, pointing out of the solid
    Box3 boundsWS;
};

struct MeshShape {
    std::string file;                          ///< for messages
    std::shared_ptr<const TriangleMesh> mesh;  ///< in the node's local frame
    double thickness = 0.0;  ///< > 0: a shell this thick around the surface (world units)
};

/// A level set from a .vdb file, in its own transform (applied before the node's).
struct GridShape {
    std::string file;  ///< for messages
    std::string grid;
    LevelSetPtr levelSet;
};

enum class CsgOp { Union, Intersection, Difference, SmoothUnion };

/// The scene-file name of an operation: "union", "intersection", "difference", "smooth_union".
const char* csgOpName(CsgOp op);

struct ShapeNode;

/// Difference: the first child minus all the others. SmoothUnion blends children within
/// `blend` (local units) of each other.
struct CsgShape {
    CsgOp op = CsgOp::Union;
    double blend = 0.0;
    std::vector<ShapeNode> children;
};

using ShapeKind = std::variant<SphereShape, BoxShape, TorusShape, CapsuleShape, CylinderShape,
                               HalfSpaceShape, MeshShape, GridShape, CsgShape>;

struct ShapeNode {
    ShapeKind kind;
    Similarity transform;  ///< local -> parent
};

/// The scene-file type name of a node: "sphere", "box", ..., "mesh", "vdb", "csg".
const char* shapeTypeName(const ShapeNode& node);

/// Conservative world-space bounds of the solid (a half-space: its boundsWS).
Box3 shapeBounds(const ShapeNode& root);

/// Surface area of the solid's boundary in world units (an upper bound for CSG and clipped
/// half-spaces; 0 for grids, whose size is that of the file).
double shapeSurfaceArea(const ShapeNode& root);

/// Bytes the build of `root` may need at its peak (children, result and the rebuild's mesh), by
/// surface area x band x bytes per voxel. An estimate to refuse absurd requests, not a bound.
double estimateBuildBytes(const ShapeNode& root, double voxelSize, double halfWidthVoxels);

/// What buildLevelSet did beyond the obvious (holes capped in meshes), for reports.
struct ShapeBuildNotes {
    size_t holesCapped = 0;
    size_t rebuilds = 0;  ///< levelSetRebuild passes (grids moved into the lattice, shells)
};

/// Builds the narrow-band level set of `root` (world space) named `name`. `halfWidthVoxels`
/// must be > 1 and `voxelSize` > 0 (InputError otherwise). Throws InputError when the result
/// has no surface (a shape smaller than the voxels, an empty intersection, a mesh enclosing no
/// volume), naming `name`.
LevelSetPtr buildLevelSet(const ShapeNode& root, double voxelSize, double halfWidthVoxels,
                          const std::string& name, ShapeBuildNotes* notes = nullptr);

/// The level set moved by `t`, without resampling: the grid's transform is composed with t and
/// its values (distances) scaled by t.scale. The voxel data is shared when t.scale == 1.
LevelSetPtr transformLevelSet(const LevelSetPtr& levelSet, const Similarity& t);

}  // namespace penumbra
