/// @file level_set_impl.h
/// Internal: the OpenVDB grid behind penumbra::LevelSet. Include only from .cpp files that need
/// the grid itself (OpenVDB headers are slow to compile).
///
/// Space: boundsWS() is the world-space box of the active voxels' cells (index box widened by
/// half a voxel on each side, mapped through the grid's linear transform).
/// Thread safety: immutable; share freely. Give each thread its own accessors.
#pragma once

#include <openvdb/openvdb.h>
#include <openvdb/tools/Interpolation.h>

#include <atomic>
#include <cmath>
#include <functional>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>

#include "penumbra/error.h"
#include "penumbra/level_set.h"
#include "penumbra/math.h"

namespace penumbra {

struct CellTables;

class LevelSet {
  public:
    /// `grid` must be a float level set with uniform voxels and a linear transform.
    explicit LevelSet(openvdb::FloatGrid::ConstPtr grid);

    const openvdb::FloatGrid& grid() const { return *mGrid; }
    const openvdb::FloatGrid::ConstPtr& gridPtr() const { return mGrid; }
    const Box3& boundsWS() const { return mBoundsWS; }  ///< empty when no voxel is active
    /// What may block a ray: the world box and a sphere (centre, radius) that hold every point
    /// where the trilinear interpolant is <= 0, bounded from the cells' own values to a 32nd of
    /// a voxel (level_set_extent.cpp; the sphere's centre is the middle of the inside voxels'
    /// box). The band's outside, up to half_width voxels thick, is left out. boundsWS() and its
    /// circumscribed sphere when no voxel is inside.
    const Box3& solidBoundsWS() const { return mSolidWS; }
    const Vec3& solidCentreWS() const { return mSolidCentre; }
    double solidRadius() const { return mSolidRadius; }
    /// The solid box diced into kSolidPartsPerAxis^3 cells, each shrunk to the voxels with a
    /// value <= 0 in it (active or not, tiles too), grown by the same 1.25 voxels; cells with
    /// none are left out (world boxes, in no order). Every point where the trilinear
    /// interpolation is <= 0 lies in one: a tilted torus or a capsule fills a fraction of its
    /// box, and a shadow pyramid that meets none of its parts cannot be blocked by it.
    const std::vector<Box3>& solidPartsWS() const { return mSolidParts; }
    /// An oriented box around the same points as solidBoundsWS() (every point where the
    /// trilinear interpolant is <= 0): its axes searched for the least volume from the
    /// principal axes of the voxels <= 0, kept when that volume is under 0.9 of the solid
    /// box's (a tilted capsule, cylinder or box), else the solid box itself. Light footprints
    /// project it (light_footprint.h).
    const OrientedBox& solidOrientedWS() const { return mSolidOriented; }
    static constexpr int kSolidPartsPerAxis = 8;
    double voxelSize() const { return mVoxelSize; }

    /// The far-field companion used for shadow-ray clearance (occluder.cpp): the same surface
    /// rebuilt at `factor` times coarser voxels with exterior and interior bands of `band` of them
    /// (the interior one lets a blocked shadow ray prove how deep it goes). Built
    /// on first use (thread-safe) and kept with the level set, so that every Occluder, render
    /// and batch job over it shares one.
    const openvdb::FloatGrid& farField(double factor, float band) const;

    /// The companion, if it has been built or adopted (null otherwise).
    openvdb::FloatGrid::ConstPtr farFieldIfBuilt() const {
        return mFar->built.load(std::memory_order_acquire) ? mFar->grid : nullptr;
    }
    /// Takes a companion built elsewhere (a cache file) unless one exists already.
    void adoptFarField(openvdb::FloatGrid::ConstPtr grid) const;

    /// Builds the companion from the shape's own signed distance instead of meshing the fine
    /// surface: given the companion's voxel size (world units) and half width (its voxels), a
    /// level set on the lattice of that voxel size (no offset, no rotation). Set by the builder
    /// of a lone smooth primitive (useShapeDistanceForFarField), whose distance is exact and
    /// 1-Lipschitz; CompanionError measures how far it strays from the fine grid as it does for
    /// a meshed one.
    using FarFieldRecipe = std::function<openvdb::FloatGrid::Ptr(double voxel, float band)>;
    /// Takes effect if the companion has not been built yet; safe from any thread.
    void setFarFieldRecipe(FarFieldRecipe recipe) const;

    /// The cell tables of the grid (cell_distance.h): built on first use (thread-safe) and
    /// kept with the level set, so that every Occluder, render and batch job over it shares
    /// them. Null for a grid too large for them or not a level set.
    const CellTables* cellTables() const;
    /// The cell tables if they have been built (null otherwise): plain shadow rays use them
    /// when a certifying caller has paid for them, and never build them (0.1-0.25 s a grid).
    const CellTables* cellTablesIfBuilt() const {
        return mCells->built.load(std::memory_order_acquire) ? mCells->tables.get() : nullptr;
    }

    /// A ball wholly inside the surface: the trilinear interpolant is negative all over it, so
    /// every segment that meets it is blocked (world space).
    struct InsideBall {
        Vec3 centre{0.0};
        double radius = 0.0;
    };
    /// Each ball whose centre lies inside, moved towards the deepest point near it and given
    /// the radius its cells' values prove (a lower bound on the distance to every point where
    /// the interpolant may reach zero, from each cell's corner values and slopes;
    /// level_set_extent.cpp); balls whose centre is not inside are left out. Returned unchanged
    /// for a grid with more than about 2 million cells with corners on both sides of zero.
    std::vector<InsideBall> widenInsideBalls(const std::vector<InsideBall>& balls) const;

  private:
    void findSolid();
    void findOrientedSolid();
    // The box and radius (index space, around centreIS) of every point where the interpolant is
    // <= 0, to a 32nd of a voxel; unchanged when no value is <= 0 (level_set_extent.cpp).
    void tightenSolid(const openvdb::Vec3d& centreIS, openvdb::Vec3d& loIS, openvdb::Vec3d& hiIS,
                      double& radiusIS) const;
    struct FarCache {
        std::once_flag once;
        openvdb::FloatGrid::ConstPtr grid;
        std::atomic<bool> built{false};
        std::mutex recipeMutex;
        FarFieldRecipe recipe;  // guarded by recipeMutex
    };
    std::shared_ptr<FarCache> mFar = std::make_shared<FarCache>();
    struct CellCache {
        std::once_flag once;
        std::shared_ptr<const CellTables> tables;  // shared: CellTables is incomplete here
        std::atomic<bool> built{false};
    };
    std::shared_ptr<CellCache> mCells = std::make_shared<CellCache>();
    openvdb::FloatGrid::ConstPtr mGrid;
    Box3 mBoundsWS;
    Box3 mSolidWS;
    std::vector<Box3> mSolidParts;
    OrientedBox mSolidOriented;
    Vec3 mSolidCentre{0.0};
    double mSolidRadius = 0.0;
    double mVoxelSize = 0.0;
};

/// Writes grids (and file metadata) to `file` under a temporary name, then renames it: readers
/// never see a half-written file. Throws std::runtime_error naming the file.
void writeVdbAtomically(const std::string& file, const openvdb::GridCPtrVec& grids,
                        const openvdb::MetaMap& fileMetadata = openvdb::MetaMap());

/// openvdb::initialize(), once per process, thread-safe.
void ensureOpenVdbInitialized();

/// Runs `read` (OpenVDB calls on `file`) and turns what OpenVDB throws into the project's
/// errors: InputError(file, where, "cannot read VDB file: ...") for a bad file, a runtime error
/// naming the file when memory runs out. InputErrors of `read` itself pass through.
template <class Read>
auto withVdbErrors(const std::string& file, const std::string& where, Read&& read) {
    try {
        return read();
    } catch (const InputError&) {
        throw;
    } catch (const std::bad_alloc&) {
        throw std::runtime_error(file + ": out of memory reading the VDB file");
    } catch (const std::exception& e) {
        throw InputError(file, where, std::string("cannot read VDB file: ") + e.what());
    }
}

/// The eight values of the trilinear cell whose lowest corner is voxel ijk (data[i][j][k] at
/// ijk + (i, j, k)), read straight from one leaf when the cell lies inside one; false (nothing
/// read) when it crosses a leaf's border or no leaf holds it.
template <typename Accessor>
inline bool leafCellValues(Accessor& acc, const openvdb::Coord& ijk, float data[2][2][2]) {
    using Leaf = openvdb::FloatTree::LeafNodeType;
    constexpr int kLast = int(Leaf::DIM) - 1;
    if ((ijk.x() & kLast) == kLast || (ijk.y() & kLast) == kLast || (ijk.z() & kLast) == kLast)
        return false;
    const Leaf* leaf = acc.probeConstLeaf(ijk);
    if (!leaf) return false;
    constexpr openvdb::Index dx = 1u << (2 * Leaf::LOG2DIM), dy = 1u << Leaf::LOG2DIM;
    const openvdb::Index o = Leaf::coordToOffset(ijk);
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 2; ++j)
            for (int k = 0; k < 2; ++k) data[i][j][k] = leaf->getValue(o + i * dx + j * dy + k);
    return true;
}

/// openvdb::tools::BoxSampler::sample(acc, xyz) (trilinear, index space), bit for bit, read
/// faster: when the cell's eight voxels lie in one leaf (343 of its 512 cells) they are read
/// straight from that leaf, one accessor lookup instead of eight; otherwise through BoxSampler.
/// Shadow rays' distance marches spend most of their time here.
template <class Accessor>
inline float sampleTrilinear(Accessor& acc, const openvdb::Vec3d& xyz) {
    const openvdb::Coord ijk(int(std::floor(xyz[0])), int(std::floor(xyz[1])), int(std::floor(xyz[2])));
    float data[2][2][2];
    if (leafCellValues(acc, ijk, data)) {
        const openvdb::Vec3d uvw(xyz[0] - ijk.x(), xyz[1] - ijk.y(), xyz[2] - ijk.z());
        return openvdb::tools::BoxSampler::trilinearInterpolation(data, uvw);
    }
    return openvdb::tools::BoxSampler::sample(acc, xyz);
}

}  // namespace penumbra
