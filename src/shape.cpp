// Sculpted shapes -> narrow-band level sets. See shape.h for what each kind becomes; the notes
// here say why the pieces are built the way they are.
#include "penumbra/shape.h"

#include <openvdb/openvdb.h>
#include <openvdb/tools/ChangeBackground.h>
#include <openvdb/tools/Composite.h>
#include <openvdb/tools/LevelSetRebuild.h>
#include <openvdb/tools/MeshToVolume.h>
#include <openvdb/tools/Prune.h>
#include <openvdb/tools/SignedFloodFill.h>
#include <openvdb/tree/LeafManager.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <iomanip>
#include <sstream>
#include <stdexcept>
#include <type_traits>

#include "level_set_impl.h"
#include "penumbra/error.h"
#include "parallel_for.h"
#include "scene_plan.h"

namespace penumbra {

// ---------------------------------------------------------------------------------------------
// Similarity

namespace {

/// cos and sin of an angle in degrees, exact at multiples of 90 degrees so that a quarter turn
/// maps axes onto axes without a 6e-17 residue.
std::pair<double, double> cosSinDeg(double deg) {
    const double quarter = deg / 90.0;
    if (quarter == std::floor(quarter) && std::fabs(quarter) < 1e9) {
        const long long k = ((static_cast<long long>(quarter) % 4) + 4) % 4;
        static const double c[4] = {1.0, 0.0, -1.0, 0.0};
        static const double s[4] = {0.0, 1.0, 0.0, -1.0};
        return {c[k], s[k]};
    }
    const double rad = deg * kPi / 180.0;
    return {std::cos(rad), std::sin(rad)};
}

/// A matrix from its rows (glm's constructor takes columns).
Mat3 fromRows(const Vec3& r0, const Vec3& r1, const Vec3& r2) {
    return glm::transpose(Mat3(r0, r1, r2));
}

}  // namespace

Similarity Similarity::fromSceneTransform(const Vec3& translate, const Vec3& rotateDeg,
                                          double scale) {
    const auto [cx, sx] = cosSinDeg(rotateDeg.x);
    const auto [cy, sy] = cosSinDeg(rotateDeg.y);
    const auto [cz, sz] = cosSinDeg(rotateDeg.z);
    const Mat3 rx = fromRows(Vec3(1, 0, 0), Vec3(0, cx, -sx), Vec3(0, sx, cx));
    const Mat3 ry = fromRows(Vec3(cy, 0, sy), Vec3(0, 1, 0), Vec3(-sy, 0, cy));
    const Mat3 rz = fromRows(Vec3(cz, -sz, 0), Vec3(sz, cz, 0), Vec3(0, 0, 1));
    Similarity t;
    t.rotation = rz * ry * rx;
    t.scale = scale;
    t.translate = translate;
    return t;
}

bool Similarity::isIdentity() const {
    return scale == 1.0 && translate == Vec3(0.0) && rotation == Mat3(1.0);
}

Similarity operator*(const Similarity& outer, const Similarity& inner) {
    Similarity t;
    t.rotation = outer.rotation * inner.rotation;
    t.scale = outer.scale * inner.scale;
    t.translate = outer.apply(inner.translate);
    return t;
}

const char* csgOpName(CsgOp op) {
    // CsgOp's order.
    static const char* const names[] = {"union", "intersection", "difference", "smooth_union"};
    return names[static_cast<int>(op)];
}

const char* shapeTypeName(const ShapeNode& node) {
    return std::visit(
        [](const auto& s) -> const char* {
            using T = std::decay_t<decltype(s)>;
            if constexpr (std::is_same_v<T, SphereShape>) return "sphere";
            if constexpr (std::is_same_v<T, BoxShape>) return "box";
            if constexpr (std::is_same_v<T, TorusShape>) return "torus";
            if constexpr (std::is_same_v<T, CapsuleShape>) return "capsule";
            if constexpr (std::is_same_v<T, CylinderShape>) return "cylinder";
            if constexpr (std::is_same_v<T, HalfSpaceShape>) return "half_space";
            if constexpr (std::is_same_v<T, MeshShape>) return "mesh";
            if constexpr (std::is_same_v<T, GridShape>) return "vdb";
            if constexpr (std::is_same_v<T, CsgShape>) return "csg";
        },
        node.kind);
}

namespace {

using openvdb::Coord;
using openvdb::FloatGrid;
using FloatTree = FloatGrid::TreeType;
using LeafT = FloatTree::LeafNodeType;

// Bytes per active voxel of a level-set tree, for the memory estimate: OpenVDB 10 trees
// measured 10-19 bytes per active voxel at small sizes (describe().bytes / activeVoxels on
// spheres and boxes of half width 3), tending to 9-11 as grids grow and the fixed cost of the
// upper nodes is shared by more leaves. 12 leaves a margin; the estimate guards against absurd
// requests and need not be tight.
constexpr double kBytesPerBandVoxel = 12.0;
// A rebuild (of grids moved into the lattice, of thick meshes) meshes the surface (one quad per
// surface voxel: four indices, shared points) before voxelizing it again.
constexpr double kMeshBytesPerSurfaceVoxel = 32.0;
// OpenVDB index coordinates are int32 (and the mesher works in float): keep well inside.
constexpr double kMaxIndexCoordinate = double(1 << 24);

// ---------------------------------------------------------------------------------------------
// Exact signed distances in a primitive's local frame (Quilez's catalogue of distance
// functions gives the same forms).

double maxComponent(const Vec3& v) { return std::max({v.x, v.y, v.z}); }

double boxDistance(const Vec3& p, const Vec3& center, const Vec3& halfSize) {
    const Vec3 q = glm::abs(p - center) - halfSize;
    return glm::length(glm::max(q, Vec3(0.0))) + std::min(maxComponent(q), 0.0);
}

double boxDistance(const Vec3& p, const Box3& box) {
    return boxDistance(p, 0.5 * (box.lo + box.hi), 0.5 * (box.hi - box.lo));
}

struct LocalDistance {
    double operator()(const SphereShape& s, const Vec3& p) const {
        return glm::length(p - s.center) - s.radius;
    }
    double operator()(const BoxShape& b, const Vec3& p) const {
        // A rounded box is the box shrunk by `round`, dilated by `round`.
        return boxDistance(p, b.center, 0.5 * b.size - Vec3(b.round)) - b.round;
    }
    double operator()(const TorusShape& t, const Vec3& p) const {
        const Vec3 d = p - t.center;
        const double axial = glm::dot(d, t.axis);
        const double radial = glm::length(d - axial * t.axis);
        return std::hypot(radial - t.majorRadius, axial) - t.minorRadius;
    }
    double operator()(const CapsuleShape& c, const Vec3& p) const {
        const Vec3 pa = p - c.a, ba = c.b - c.a;
        const double len2 = glm::dot(ba, ba);
        const double h = len2 > 0.0 ? std::clamp(glm::dot(pa, ba) / len2, 0.0, 1.0) : 0.0;
        return glm::length(pa - h * ba) - c.radius;
    }
    double operator()(const CylinderShape& c, const Vec3& p) const {
        const Vec3 d = p - c.center;
        const double axial = glm::dot(d, c.axis);
        const double radial = glm::length(d - axial * c.axis);
        const double qx = radial - c.radius, qy = std::fabs(axial) - 0.5 * c.height;
        return std::min(std::max(qx, qy), 0.0) + std::hypot(std::max(qx, 0.0), std::max(qy, 0.0));
    }
    double operator()(const HalfSpaceShape& h, const Vec3& p) const {
        return glm::dot(p - h.point, h.normal);
    }
};

/// Local bounds of a primitive (half-spaces have none: their boundsWS is world space).
struct LocalBounds {
    Box3 operator()(const SphereShape& s) const {
        return {s.center - Vec3(s.radius), s.center + Vec3(s.radius)};
    }
    Box3 operator()(const BoxShape& b) const {
        return {b.center - 0.5 * b.size, b.center + 0.5 * b.size};
    }
    Box3 operator()(const TorusShape& t) const {
        // Along axis k the ring reaches R sqrt(1 - a_k^2), the tube r further.
        Vec3 e;
        for (int k = 0; k < 3; ++k) {
            e[k] = t.majorRadius * std::sqrt(std::max(0.0, 1.0 - t.axis[k] * t.axis[k])) +
                   t.minorRadius;
        }
        return {t.center - e, t.center + e};
    }
    Box3 operator()(const CapsuleShape& c) const {
        return {glm::min(c.a, c.b) - Vec3(c.radius), glm::max(c.a, c.b) + Vec3(c.radius)};
    }
    Box3 operator()(const CylinderShape& c) const {
        Vec3 e;
        for (int k = 0; k < 3; ++k) {
            e[k] = 0.5 * c.height * std::fabs(c.axis[k]) +
                   c.radius * std::sqrt(std::max(0.0, 1.0 - c.axis[k] * c.axis[k]));
        }
        return {c.center - e, c.center + e};
    }
};

template <class T>
constexpr bool kIsPrimitive =
    std::is_same_v<T, SphereShape> || std::is_same_v<T, BoxShape> ||
    std::is_same_v<T, TorusShape> || std::is_same_v<T, CapsuleShape> ||
    std::is_same_v<T, CylinderShape> || std::is_same_v<T, HalfSpaceShape>;

Box3 transformBox(const Box3& local, const Similarity& t) {
    if (local.empty()) return local;
    Box3 out;
    for (int c = 0; c < 8; ++c) {
        out.extend(t.apply(local.corner(c)));
    }
    return out;
}

Box3 intersect(const Box3& a, const Box3& b) {
    return {glm::max(a.lo, b.lo), glm::min(a.hi, b.hi)};
}

Box3 padded(const Box3& b, double pad) {
    return b.empty() ? b : Box3{b.lo - Vec3(pad), b.hi + Vec3(pad)};
}

bool contains(const Box3& outer, const Box3& inner) {
    return glm::all(glm::lessThanEqual(outer.lo, inner.lo)) &&
           glm::all(glm::greaterThanEqual(outer.hi, inner.hi));
}

/// The blend radius of a smooth union in world units.
double worldBlend(const CsgShape& c, const Similarity& toWorld) { return c.blend * toWorld.scale; }

/// Polynomial smooth minimum (Quilez, "smooth minimum", quadratic form): equals min(a, b) when
/// |a - b| >= k, and lies at most k/4 below it. Its partial derivatives (1 - h/2 and h/2 with
/// respect to the smaller and the larger argument) are convex weights, so it stays 1-Lipschitz
/// when a and b are.
double smoothMin(double a, double b, double k) {
    const double h = std::max(k - std::fabs(a - b), 0.0) / k;
    return std::min(a, b) - h * h * k * 0.25;
}

Box3 boundsOf(const ShapeNode& node, const Similarity& parentToWorld) {
    const Similarity toWorld = parentToWorld * node.transform;
    return std::visit(
        [&](const auto& s) -> Box3 {
            using T = std::decay_t<decltype(s)>;
            if constexpr (std::is_same_v<T, HalfSpaceShape>) {
                return s.boundsWS;
            } else if constexpr (std::is_same_v<T, SphereShape>) {
                // Exact under rotation, unlike the transformed corners of its box.
                const double r = s.radius * toWorld.scale;
                const Vec3 c = toWorld.apply(s.center);
                return {c - Vec3(r), c + Vec3(r)};
            } else if constexpr (kIsPrimitive<T>) {
                return transformBox(LocalBounds{}(s), toWorld);
            } else if constexpr (std::is_same_v<T, MeshShape>) {
                Box3 b;
                if (s.mesh) {
                    for (const Vec3& v : s.mesh->vertices) b.extend(toWorld.apply(v));
                }
                return padded(b, 0.5 * s.thickness * toWorld.scale);
            } else if constexpr (std::is_same_v<T, GridShape>) {
                return s.levelSet ? transformBox(s.levelSet->boundsWS(), toWorld) : Box3{};
            } else {
                if (s.children.empty()) return Box3{};
                Box3 b = boundsOf(s.children[0], toWorld);
                for (size_t i = 1; i < s.children.size(); ++i) {
                    const Box3 c = boundsOf(s.children[i], toWorld);
                    if (s.op == CsgOp::Union || s.op == CsgOp::SmoothUnion) {
                        b.extend(c);
                    } else if (s.op == CsgOp::Intersection) {
                        b = intersect(b, c);
                    }  // difference: within the first child
                }
                // The blend adds material where both children are within k/4 of the surface.
                if (s.op == CsgOp::SmoothUnion) b = padded(b, 0.25 * worldBlend(s, toWorld));
                return b;
            }
        },
        node.kind);
}

double boxArea(const Box3& b) {
    if (b.empty()) return 0.0;
    const Vec3 d = b.hi - b.lo;
    return 2.0 * (d.x * d.y + d.y * d.z + d.z * d.x);
}

double areaOf(const ShapeNode& node, double parentScale) {
    const double s = parentScale * node.transform.scale;
    return std::visit(
        [&](const auto& k) -> double {
            using T = std::decay_t<decltype(k)>;
            if constexpr (std::is_same_v<T, SphereShape>) {
                return 4.0 * kPi * k.radius * k.radius * s * s;
            } else if constexpr (std::is_same_v<T, BoxShape>) {
                const Vec3& d = k.size;
                return 2.0 * (d.x * d.y + d.y * d.z + d.z * d.x) * s * s;
            } else if constexpr (std::is_same_v<T, TorusShape>) {
                return 4.0 * kPi * kPi * k.majorRadius * k.minorRadius * s * s;
            } else if constexpr (std::is_same_v<T, CapsuleShape>) {
                return (4.0 * kPi * k.radius * k.radius +
                        2.0 * kPi * k.radius * glm::length(k.b - k.a)) * s * s;
            } else if constexpr (std::is_same_v<T, CylinderShape>) {
                return (2.0 * kPi * k.radius * (k.height + k.radius)) * s * s;
            } else if constexpr (std::is_same_v<T, HalfSpaceShape>) {
                // A convex part of the box has less surface than the box.
                return boxArea(k.boundsWS);
            } else if constexpr (std::is_same_v<T, MeshShape>) {
                const double a = k.mesh ? k.mesh->area() * s * s : 0.0;
                return k.thickness > 0.0 ? 2.0 * a : a;
            } else if constexpr (std::is_same_v<T, GridShape>) {
                return 0.0;
            } else {
                double sum = 0.0;
                for (const ShapeNode& c : k.children) sum += areaOf(c, s);
                return sum;
            }
        },
        node.kind);
}

double bandBytes(double area, double voxel, double bandVoxels) {
    return area / (voxel * voxel) * 2.0 * bandVoxels * kBytesPerBandVoxel;
}

/// Half width the children of a smooth union need: smin differs from min only where the two
/// distances are within k of each other, and its zero set lies where min is in [0, k/4], so the
/// children must be right up to 1.25 k (plus two voxels for the interpolation).
double smoothChildBand(double kWorld, double voxel) { return 1.25 * kWorld / voxel + 2.0; }

/// `region`: the box the node is cut to by an enclosing intersection or difference (as
/// buildCsg does), which bounds the surface of a half-space.
double estimateOf(const ShapeNode& node, const Similarity& parentToWorld, double voxel,
                  double band, const Box3* region) {
    const Similarity toWorld = parentToWorld * node.transform;
    if (const auto* csg = std::get_if<CsgShape>(&node.kind)) {
        const double childBand =
            csg->op == CsgOp::SmoothUnion
                ? std::max(band, smoothChildBand(worldBlend(*csg, toWorld), voxel))
                : band;
        Box3 common, kept;
        const Box3* childRegion = region;
        if (csg->op == CsgOp::Intersection && !csg->children.empty()) {
            common = boundsOf(csg->children[0], toWorld);
            for (const ShapeNode& c : csg->children) {
                common = intersect(common, boundsOf(c, toWorld));
            }
            if (region) common = intersect(common, *region);
            childRegion = &common;
        }
        if (csg->op == CsgOp::Difference && !csg->children.empty()) {
            kept = boundsOf(csg->children[0], toWorld);
            if (region) kept = intersect(kept, *region);
        }
        double bytes = 0.0;
        for (size_t i = 0; i < csg->children.size(); ++i) {
            const Box3* r = (csg->op == CsgOp::Difference && i > 0) ? &kept : childRegion;
            bytes += estimateOf(csg->children[i], toWorld, voxel, childBand, r);
        }
        // The children, and their combination as it grows.
        return 2.0 * bytes;
    }
    if (const auto* h = std::get_if<HalfSpaceShape>(&node.kind)) {
        // A convex part of the box has less surface than the box.
        return bandBytes(boxArea(region ? intersect(h->boundsWS, *region) : h->boundsWS), voxel,
                         band);
    }
    const double area = areaOf(node, parentToWorld.scale);
    double bytes = bandBytes(area, voxel, band);
    // A band wide against the shape holds more than area x width: the outer offset of a convex
    // body adds (Steiner) its mean width times pi w^2 and 4/3 pi w^3, bounded here by the
    // box around it.
    const Box3 b = boundsOf(node, parentToWorld);
    if (!b.empty() && std::isfinite(b.hi.x - b.lo.x + b.hi.y - b.lo.y + b.hi.z - b.lo.z)) {
        const Vec3 d = b.hi - b.lo;
        const double w = band * voxel;
        const double extra = kPi * (d.x + d.y + d.z) * w * w + 4.0 / 3.0 * kPi * w * w * w;
        bytes += extra / (voxel * voxel * voxel) * kBytesPerBandVoxel;
    }
    if (const auto* m = std::get_if<MeshShape>(&node.kind); m && m->thickness > 0.0) {
        // The unsigned distance is built wider by half the thickness, then rebuilt.
        bytes += bandBytes(area, voxel, band + 0.5 * m->thickness * toWorld.scale / voxel) +
                 area / (voxel * voxel) * kMeshBytesPerSurfaceVoxel;
    }
    return bytes;
}

// ---------------------------------------------------------------------------------------------
// Building

openvdb::math::Transform::Ptr latticeTransform(double voxel) {
    return openvdb::math::Transform::createLinearTransform(voxel);
}

void markLevelSet(FloatGrid& grid) { grid.setGridClass(openvdb::GRID_LEVEL_SET); }

/// Samples a 1-Lipschitz signed distance `field` (world space) at the voxels within
/// bandVoxels of its zero set, inside `boundsWS` widened by the band. A block of 8^3 voxels is
/// skipped when |field| at its centre exceeds the band plus the block's half diagonal: no voxel
/// of it can then be in the band. The blocks are found by descending an octree of such tests
/// from one cube over the bounds, so empty space costs one evaluation per large cube.
template <class Field>
FloatGrid::Ptr rasterize(const Field& field, const Box3& boundsWS, double voxel,
                         double bandVoxels) {
    const double w = bandVoxels * voxel;
    FloatGrid::Ptr grid = FloatGrid::create(float(w));
    grid->setTransform(latticeTransform(voxel));
    markLevelSet(*grid);
    if (boundsWS.empty()) return grid;

    const Vec3 lo = (boundsWS.lo - Vec3(w)) / voxel, hi = (boundsWS.hi + Vec3(w)) / voxel;
    const Coord cmin(int(std::floor(lo.x)) - 1, int(std::floor(lo.y)) - 1,
                     int(std::floor(lo.z)) - 1);
    const Coord cmax(int(std::ceil(hi.x)) + 1, int(std::ceil(hi.y)) + 1, int(std::ceil(hi.z)) + 1);
    // Leaf origins are multiples of 8; & ~7 rounds negative coordinates down too.
    const Coord origin(cmin.x() & ~7, cmin.y() & ~7, cmin.z() & ~7);
    int size = 8;
    const int extent = std::max({cmax.x() - origin.x(), cmax.y() - origin.y(),
                                 cmax.z() - origin.z()}) + 1;
    while (size < extent) size *= 2;

    std::vector<Coord> leafOrigins;
    const double sqrt3 = std::sqrt(3.0);
    auto visit = [&](auto&& self, const Coord& o, int n) -> void {
        const Coord last = o.offsetBy(n - 1);
        if (o.x() > cmax.x() || o.y() > cmax.y() || o.z() > cmax.z() || last.x() < cmin.x() ||
            last.y() < cmin.y() || last.z() < cmin.z()) {
            return;
        }
        const double halfSpan = 0.5 * (n - 1);
        const Vec3 centre = (Vec3(o.x(), o.y(), o.z()) + Vec3(halfSpan)) * voxel;
        if (std::fabs(field(centre)) >= w + sqrt3 * halfSpan * voxel) return;
        if (n == 8) {
            leafOrigins.push_back(o);
            return;
        }
        const int h = n / 2;
        for (int c = 0; c < 8; ++c) {
            self(self, o.offsetBy((c & 1) ? h : 0, (c & 2) ? h : 0, (c & 4) ? h : 0), h);
        }
    };
    visit(visit, origin, size);

    std::vector<LeafT*> leaves(leafOrigins.size(), nullptr);
    const float fw = float(w);
    detail::parallelFor(tbb::blocked_range<size_t>(0, leafOrigins.size(), 8),
                        [&](const tbb::blocked_range<size_t>& range) {
                            for (size_t i = range.begin(); i != range.end(); ++i) {
                                auto leaf = std::make_unique<LeafT>(leafOrigins[i], fw, false);
                                bool any = false;
                                for (openvdb::Index n = 0; n < LeafT::SIZE; ++n) {
                                    const Coord xyz = leaf->offsetToGlobalCoord(n);
                                    const double f = field(Vec3(xyz.x(), xyz.y(), xyz.z()) * voxel);
                                    if (std::fabs(f) < w) {
                                        leaf->setValueOn(n, float(f));
                                        any = true;
                                    } else {
                                        leaf->setValueOff(n, f < 0.0 ? -fw : fw);
                                    }
                                }
                                if (any) leaves[i] = leaf.release();
                            }
                        });
    FloatTree& tree = grid->tree();
    for (LeafT* leaf : leaves) {
        if (leaf) tree.addLeaf(leaf);
    }
    // Leaves hold the sign of every voxel; the flood fill gives the tiles between them theirs.
    openvdb::tools::signedFloodFill(tree);
    openvdb::tools::pruneLevelSet(tree);
    return grid;
}

FloatGrid::Ptr rebuild(const FloatGrid& grid, double bandVoxels, float iso = 0.0f,
                       const openvdb::math::Transform* target = nullptr) {
    FloatGrid::Ptr out = openvdb::tools::levelSetRebuild(grid, iso, float(bandVoxels),
                                                         float(bandVoxels), target);
    markLevelSet(*out);
    return out;
}

/// Row-vector 4x4 matrix of a similarity (OpenVDB maps apply p * M).
openvdb::Mat4d similarityMatrix(const Similarity& t) {
    openvdb::Mat4d m = openvdb::Mat4d::identity();
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) m[i][j] = t.scale * t.rotation[i][j];  // glm: column i, row j
        m[3][i] = t.translate[i];
    }
    return m;
}

openvdb::math::Transform::Ptr composedTransform(const openvdb::math::Transform& indexToWorld,
                                                const Similarity& t) {
    const openvdb::Mat4d base = indexToWorld.baseMap()->getAffineMap()->getMat4();
    return openvdb::math::Transform::createLinearTransform(base * similarityMatrix(t));
}

FloatGrid::Ptr meshGrid(const MeshShape& m, const Similarity& toWorld, double voxel, double band,
                        ShapeBuildNotes& notes) {
    if (!m.mesh) throw std::invalid_argument("buildLevelSet: mesh shape without a mesh");
    TriangleMesh mesh = *m.mesh;
    if (m.thickness <= 0.0) notes.holesCapped += capHoles(mesh);
    const openvdb::math::Transform::Ptr xform = latticeTransform(voxel);
    std::vector<openvdb::Vec3s> points;
    points.reserve(mesh.vertices.size());
    for (const Vec3& v : mesh.vertices) {
        const Vec3 p = toWorld.apply(v) / voxel;
        points.emplace_back(float(p.x), float(p.y), float(p.z));
    }
    std::vector<openvdb::Vec3I> triangles;
    triangles.reserve(mesh.triangles.size());
    for (const auto& t : mesh.triangles) triangles.emplace_back(t[0], t[1], t[2]);
    openvdb::tools::QuadAndTriangleDataAdapter<openvdb::Vec3s, openvdb::Vec3I> adapter(points,
                                                                                      triangles);
    if (m.thickness > 0.0) {
        // A shell around the surface: the unsigned distance's iso-surface at half the thickness,
        // which needs no inside and outside, so open sheets work.
        const double half = 0.5 * m.thickness * toWorld.scale;
        const float width = float(band + half / voxel + 1.0);
        FloatGrid::Ptr unsignedGrid = openvdb::tools::meshToVolume<FloatGrid>(
            adapter, *xform, width, width, openvdb::tools::UNSIGNED_DISTANCE_FIELD);
        ++notes.rebuilds;
        return rebuild(*unsignedGrid, band, float(half));
    }
    FloatGrid::Ptr grid =
        openvdb::tools::meshToVolume<FloatGrid>(adapter, *xform, float(band), float(band));
    markLevelSet(*grid);
    // A mesh that is still open (holes that did not form loops) lets the exterior flood fill
    // leak inside: the voxels just inside the surface then come out positive. A sheet that
    // encloses nothing (an open sheet capped onto itself) has only values of rounding size
    // inside. A solid has about as many voxels between a quarter and one and a half voxels
    // inside its surface as outside it.
    const float lo = float(0.25 * voxel), hi = float(1.5 * voxel);
    uint64_t inside = 0, outside = 0;
    for (auto it = grid->cbeginValueOn(); it; ++it) {
        const float v = std::fabs(*it);
        if (v >= lo && v <= hi) ++(*it < 0.0f ? inside : outside);
    }
    const uint64_t near = inside + outside;
    if (near == 0 || double(inside) < 0.05 * double(near)) {
        std::ostringstream msg;
        msg << "the mesh encloses no volume at voxel size " << voxel << " (" << inside << " of "
            << near << " voxels next to the surface are inside";
        if (notes.holesCapped) msg << ", after capping " << notes.holesCapped << " holes";
        msg << "): an open sheet needs a \"thickness\", and parts thinner than a voxel vanish";
        throw InputError(m.file, "", msg.str());
    }
    return grid;
}

FloatGrid::Ptr gridIntoLattice(const GridShape& g, const Similarity& toWorld, double voxel,
                               double band, ShapeBuildNotes& notes) {
    if (!g.levelSet) throw std::invalid_argument("buildLevelSet: vdb shape without a level set");
    const FloatGrid& source = g.levelSet->grid();
    // Share the voxels, move the grid by the node's transform; the rebuild then resamples its
    // surface into the common lattice (distances come out in world units whatever the scale).
    FloatGrid::ConstPtr moved = openvdb::gridConstPtrCast<FloatGrid>(
        source.copyGridReplacingTransform(composedTransform(source.transform(), toWorld)));
    const openvdb::math::Transform::Ptr target = latticeTransform(voxel);
    ++notes.rebuilds;
    return rebuild(*moved, band, 0.0f, target.get());
}

FloatGrid::Ptr buildCsg(const CsgShape& csg, const Similarity& toWorld, double voxel, double band,
                        const Box3* region, ShapeBuildNotes& notes);

/// Builds `node` on the lattice of `voxel` with half width `band`. `region` (nullptr: none) is a
/// world box the caller needs the solid only within: shapes reaching beyond it are cut to it (as
/// an intersection with the box, so they stay closed solids), which keeps a half-space in an
/// intersection from being voxelized over the whole scene.
FloatGrid::Ptr buildNode(const ShapeNode& node, const Similarity& parentToWorld, double voxel,
                         double band, const Box3* region, ShapeBuildNotes& notes) {
    const Similarity toWorld = parentToWorld * node.transform;
    return std::visit(
        [&](const auto& s) -> FloatGrid::Ptr {
            using T = std::decay_t<decltype(s)>;
            if constexpr (kIsPrimitive<T>) {
                const double scale = toWorld.scale;
                auto field = [&s, toWorld, scale](const Vec3& x) {
                    return scale * LocalDistance{}(s, toWorld.applyInverse(x));
                };
                Box3 bounds = boundsOf(node, parentToWorld);
                Box3 clip;
                bool clipped = false;
                if constexpr (std::is_same_v<T, HalfSpaceShape>) {
                    clip = s.boundsWS;
                    clipped = true;
                }
                if (region && !contains(*region, bounds)) {
                    clip = clipped ? intersect(clip, *region) : *region;
                    clipped = true;
                }
                if (!clipped) return rasterize(field, bounds, voxel, band);
                bounds = intersect(bounds, clip);
                auto cut = [field, clip](const Vec3& x) {
                    return std::max(field(x), boxDistance(x, clip));
                };
                return rasterize(cut, bounds, voxel, band);
            } else if constexpr (std::is_same_v<T, MeshShape>) {
                return meshGrid(s, toWorld, voxel, band, notes);
            } else if constexpr (std::is_same_v<T, GridShape>) {
                return gridIntoLattice(s, toWorld, voxel, band, notes);
            } else {
                return buildCsg(s, toWorld, voxel, band, region, notes);
            }
        },
        node.kind);
}

/// Central differences of a grid's values at a voxel: twice the voxel size times the gradient.
template <class Accessor>
Vec3 centralDifferences(const Accessor& acc, const Coord& ijk) {
    auto diff = [&](int dx, int dy, int dz) {
        return double(acc.getValue(ijk.offsetBy(dx, dy, dz))) -
               double(acc.getValue(ijk.offsetBy(-dx, -dy, -dz)));
    };
    return Vec3(diff(1, 0, 0), diff(0, 1, 0), diff(0, 0, 1));
}

/// Unit gradient of a level set at a voxel (zero where it vanishes).
template <class Accessor>
Vec3 unitGradient(const Accessor& acc, const Coord& ijk) {
    const Vec3 g = centralDifferences(acc, ijk);
    const double len = glm::length(g);
    return len > 0.0 ? g / len : Vec3(0.0);
}

/// Distance from a point inside the union of two solids to the union's boundary, from the
/// solids' signed distances a, b there (min(a, b) < 0) and unit gradients na, nb. The boundary
/// is the part of each surface outside the other solid. The nearest point of surface A is
/// p - a na; when it lies outside B (b there is >= 0, to first order b - a (na . nb)) it is on
/// the union's boundary, at |a|. Otherwise the nearest boundary point is on the seam where the
/// two surfaces meet, approximated by the line where their tangent planes meet: at distance
/// sqrt(a^2 + b^2 - 2 a b cos t) / sin t, t the angle between the normals. Exact for planar
/// surfaces, to second order in the voxel size for curved ones.
double unionInsideDistance(double a, double b, const Vec3& na, const Vec3& nb) {
    const double cosT = std::clamp(glm::dot(na, nb), -1.0, 1.0);
    const double sinT = std::sqrt(std::max(0.0, 1.0 - cosT * cosT));
    const double seam = sinT > 1e-6
                            ? std::sqrt(std::max(0.0, a * a + b * b - 2.0 * a * b * cosT)) / sinT
                            : std::numeric_limits<double>::infinity();
    const double fromA = b - a * cosT >= 0.0 ? std::fabs(a) : seam;
    const double fromB = a - b * cosT >= 0.0 ? std::fabs(b) : seam;
    return std::min(fromA, fromB);
}

/// Combines two level sets on one lattice by OpenVDB's CSG (min, max, max with the complement)
/// and repairs the distances near the seam. The combination of exact distances is exact on one
/// side: outside a union, inside an intersection or a difference. On the other side it is
/// wrong within a few voxels of the seam, where the nearest boundary point is on the seam
/// itself; unionInsideDistance gives those distances (an intersection's outside is the inside
/// of the union of the complements, whose distances are -a and -b). Where either child is
/// beyond its band, the combination is right as it is (the other child's surface is then too
/// far to hide the nearest point).
FloatGrid::Ptr combine(const FloatGrid& a, const FloatGrid& b, CsgOp op) {
    FloatGrid::Ptr out;
    switch (op) {
        case CsgOp::Union: out = openvdb::tools::csgUnionCopy(a, b); break;
        case CsgOp::Intersection: out = openvdb::tools::csgIntersectionCopy(a, b); break;
        default: out = openvdb::tools::csgDifferenceCopy(a, b); break;
    }
    const float wa = a.background(), wb = b.background();
    // Each case as the inside of a union of two solids with distances (sa a, sb b): a union as
    // it is; the outside of an intersection A n B is the inside of (not A) u (not B), and that
    // of a difference A n (not B) the inside of (not A) u B.
    const double sa = op == CsgOp::Union ? 1.0 : -1.0;
    const double sb = op == CsgOp::Intersection ? -1.0 : 1.0;
    openvdb::tree::LeafManager<FloatTree> leaves(out->tree());
    leaves.foreach([&](LeafT& leaf, size_t) {
        // Unsafe accessors: a and b are not modified while this runs, and registering one
        // accessor per leaf with the trees would serialize the threads.
        auto accA = a.getConstUnsafeAccessor();
        auto accB = b.getConstUnsafeAccessor();
        for (auto it = leaf.beginValueOn(); it; ++it) {
            const float c = *it;
            // The exact side: outside a union, inside an intersection or difference.
            if (op == CsgOp::Union ? c >= 0.0f : c <= 0.0f) continue;
            const Coord ijk = it.getCoord();
            const float va = accA.getValue(ijk), vb = accB.getValue(ijk);
            if (std::fabs(va) >= wa || std::fabs(vb) >= wb) continue;
            const Vec3 nx = sa * unitGradient(accA, ijk), ny = sb * unitGradient(accB, ijk);
            if (nx == Vec3(0.0) || ny == Vec3(0.0)) continue;
            const double d = unionInsideDistance(sa * va, sb * vb, nx, ny);
            // |c| is a lower bound; keep it if larger, and where the seam's line is undefined
            // (parallel normals, as on two coaxial cylinders' walls: d is infinite).
            if (!(d >= std::fabs(c)) || !std::isfinite(d)) continue;
            it.setValue(float(op == CsgOp::Union ? -d : d));
        }
    });
    return out;
}

/// Smooth union of two grids on one lattice: OpenVDB's union gives the topology (both bands)
/// and the signs of the tiles; the blended values are then written over its active voxels.
FloatGrid::Ptr smoothUnion(const FloatGrid& a, const FloatGrid& b, double k) {
    FloatGrid::Ptr out = openvdb::tools::csgUnionCopy(a, b);
    openvdb::tree::LeafManager<FloatTree> leaves(out->tree());
    leaves.foreach([&](LeafT& leaf, size_t) {
        auto accA = a.getConstUnsafeAccessor();
        auto accB = b.getConstUnsafeAccessor();
        for (auto it = leaf.beginValueOn(); it; ++it) {
            const Coord xyz = it.getCoord();
            it.setValue(float(smoothMin(accA.getValue(xyz), accB.getValue(xyz), k)));
        }
    });
    return out;
}

/// The smooth minimum of distances is not itself a distance: its gradient is shorter than 1
/// in the blend. Dividing by the gradient's length gives the distance to first order near the
/// surface, which is where it matters.
FloatGrid::Ptr normalized(const FloatGrid& grid, double voxel) {
    FloatGrid::Ptr out = grid.deepCopy();
    openvdb::tree::LeafManager<FloatTree> leaves(out->tree());
    leaves.foreach([&](LeafT& leaf, size_t) {
        auto acc = grid.getConstUnsafeAccessor();
        for (auto it = leaf.beginValueOn(); it; ++it) {
            const double len = glm::length(centralDifferences(acc, it.getCoord())) / (2.0 * voxel);
            // The blend's gradient (1 - h/2) na + (h/2) nb is at least cos(t/2) long, t the
            // angle between the children's normals. Where it is under 0.5 (t > 120 degrees,
            // children facing each other) the first-order division is unreliable: the value
            // stays, an underestimate of the distance (safe for marching rays). Only rounding
            // makes it longer than 1.
            if (len > 0.5 && len < 1.0) it.setValue(float(*it / len));
        }
    });
    return out;
}

/// Brings a grid to half width `band`: values beyond it become inactive +-band.
void trimBand(FloatGrid& grid, double band) {
    const float w = float(band);
    openvdb::tree::LeafManager<FloatTree> leaves(grid.tree());
    leaves.foreach([w](LeafT& leaf, size_t) {
        for (auto it = leaf.beginValueOn(); it; ++it) {
            if (std::fabs(*it) >= w) it.setValueOff();
        }
    });
    openvdb::tools::changeLevelSetBackground(grid.tree(), w);
    openvdb::tools::pruneLevelSet(grid.tree());
}

/// Builds a CSG node on the lattice of `voxel` with half width `band`: its children on the same
/// lattice, combined pairwise from the first (a difference subtracts every other child from the
/// first).
FloatGrid::Ptr buildCsg(const CsgShape& csg, const Similarity& toWorld, double voxel, double band,
                        const Box3* region, ShapeBuildNotes& notes) {
    if (csg.children.empty()) throw std::invalid_argument("buildLevelSet: CSG without children");
    // Children may be cut to boxes this far beyond the part of them that matters: the cut faces
    // then stay out of the band around the result's surface.
    const double pad = (band + 2.0) * voxel;
    const Box3* childRegion = region;
    Box3 common;
    if (csg.op == CsgOp::Intersection) {
        common = boundsOf(csg.children[0], toWorld);
        for (size_t i = 1; i < csg.children.size(); ++i) {
            common = intersect(common, boundsOf(csg.children[i], toWorld));
        }
        if (region) common = intersect(common, *region);
        common = padded(common, pad);
        childRegion = &common;
    }
    const double k = worldBlend(csg, toWorld);
    const double childBand =
        csg.op == CsgOp::SmoothUnion ? std::max(band, smoothChildBand(k, voxel)) : band;

    FloatGrid::Ptr acc = buildNode(csg.children[0], toWorld, voxel, childBand, childRegion, notes);
    Box3 kept;
    if (csg.op == CsgOp::Difference) {
        // What is subtracted matters only where the first child is.
        kept = boundsOf(csg.children[0], toWorld);
        if (region) kept = intersect(kept, *region);
        kept = padded(kept, pad);
    }
    for (size_t i = 1; i < csg.children.size(); ++i) {
        const Box3* r = csg.op == CsgOp::Difference ? &kept : childRegion;
        FloatGrid::Ptr next = buildNode(csg.children[i], toWorld, voxel, childBand, r, notes);
        acc = csg.op == CsgOp::SmoothUnion ? smoothUnion(*acc, *next, k)
                                           : combine(*acc, *next, csg.op);
    }
    if (csg.op == CsgOp::SmoothUnion) {
        acc = normalized(*acc, voxel);
        trimBand(*acc, band * voxel);
    }
    markLevelSet(*acc);
    return acc;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Public functions

Box3 shapeBounds(const ShapeNode& root) { return boundsOf(root, Similarity{}); }

double shapeSurfaceArea(const ShapeNode& root) { return areaOf(root, 1.0); }

double estimateBuildBytes(const ShapeNode& root, double voxelSize, double halfWidthVoxels) {
    return estimateOf(root, Similarity{}, voxelSize, halfWidthVoxels, nullptr);
}

LevelSetPtr buildLevelSet(const ShapeNode& root, double voxelSize, double halfWidthVoxels,
                          const std::string& name, ShapeBuildNotes* notes) {
    if (!(voxelSize > 0.0) || !std::isfinite(voxelSize)) {
        throw InputError("", "", "level set voxel size must be > 0, got " +
                                     std::to_string(voxelSize));
    }
    // OpenVDB's rasterizers and mesher refuse a band of one voxel or less.
    if (!(halfWidthVoxels > 1.0)) {
        throw InputError("", "", "level set half width must be > 1 voxel, got " +
                                     std::to_string(halfWidthVoxels));
    }
    const Box3 bounds = shapeBounds(root);
    if (!bounds.empty()) {
        const double reach =
            std::max(maxComponent(glm::abs(bounds.lo)), maxComponent(glm::abs(bounds.hi)));
        if (!(reach / voxelSize + halfWidthVoxels < kMaxIndexCoordinate)) {
            std::ostringstream msg;
            msg << "'" << name << "' reaches ~" << std::setprecision(3) << reach / voxelSize
                << " voxels from the origin, beyond the level set's index range ("
                << kMaxIndexCoordinate << "); raise voxel_size";
            throw InputError("", "", msg.str());
        }
    }
    ensureOpenVdbInitialized();
    ShapeBuildNotes local;
    FloatGrid::Ptr grid =
        buildNode(root, Similarity{}, voxelSize, halfWidthVoxels, nullptr, notes ? *notes : local);
    if (grid->activeVoxelCount() == 0) {
        throw InputError("", "",
                         "'" + name + "' has no surface at voxel size " +
                             std::to_string(voxelSize) +
                             " (empty, or thinner than the voxels): lower voxel_size");
    }
    grid->setName(name);
    markLevelSet(*grid);
    LevelSetPtr levelSet = std::make_shared<const LevelSet>(grid);
    useShapeDistanceForFarField(levelSet, root);
    return levelSet;
}

void useShapeDistanceForFarField(const LevelSetPtr& levelSet, const ShapeNode& root) {
    const bool smooth = std::visit(
        [](const auto& s) {
            using T = std::decay_t<decltype(s)>;
            return std::is_same_v<T, SphereShape> || std::is_same_v<T, TorusShape> ||
                   std::is_same_v<T, CapsuleShape>;
        },
        root.kind);
    if (!levelSet || !smooth) return;
    // Only a lone primitive's distance is exact at every range (CSG's seams and smooth blends
    // are repaired to first order), and only a smooth one's stays next to the fine surface the
    // rays see: trilinear interpolation bevels a box's or a cylinder's sharp edges by a good
    // part of a voxel, where their exact distance then misleads the tangent construction's
    // companion marches (random scene 605's rotated box: 0.12% of its form factor off against
    // 0.01% with a meshed companion). Those keep meshing their fine surface.
    levelSet->setFarFieldRecipe([root](double voxel, float band) {
        ShapeBuildNotes notes;
        return buildNode(root, Similarity{}, voxel, double(band), nullptr, notes);
    });
}

LevelSetPtr transformLevelSet(const LevelSetPtr& levelSet, const Similarity& t) {
    if (!levelSet) throw std::invalid_argument("transformLevelSet: null level set");
    if (t.isIdentity()) return levelSet;
    const FloatGrid& source = levelSet->grid();
    const openvdb::math::Transform::Ptr xform = composedTransform(source.transform(), t);
    if (t.scale == 1.0) {
        // A rigid motion changes no distance: share the voxels.
        return std::make_shared<const LevelSet>(
            openvdb::gridConstPtrCast<FloatGrid>(source.copyGridReplacingTransform(xform)));
    }
    FloatGrid::Ptr grid = source.deepCopy();
    grid->setTransform(xform);
    const float s = float(t.scale);
    for (auto it = grid->beginValueOn(); it; ++it) it.setValue(*it * s);
    // Inactive values and the background are +-(half width), which scales too.
    openvdb::tools::changeLevelSetBackground(grid->tree(), source.background() * s);
    return std::make_shared<const LevelSet>(grid);
}

}  // namespace penumbra
