#include "penumbra/level_set.h"
#include "penumbra/output_files.h"
#include "parallel_for.h"

#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/LevelSetSphere.h>
#include <openvdb/tools/MeshToVolume.h>
#include <openvdb/tools/VolumeToMesh.h>
#include <tbb/task_arena.h>

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <map>
#include <vector>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <mutex>
#include <sstream>
#include <stdexcept>

#include "cell_distance.h"
#include "level_set_impl.h"
#include "penumbra/error.h"

namespace penumbra {

void writeVdbAtomically(const std::string& file, const openvdb::GridCPtrVec& grids,
                        const openvdb::MetaMap& fileMetadata) {
    // Write beside the target and rename, so a reader never sees a half-written file. The
    // temporary name is unique per process and call, so concurrent writers do not collide.
    const std::string tmp = temporaryPathFor(file);
    try {
        openvdb::io::File vdb(tmp);
        vdb.write(grids, fileMetadata);
        vdb.close();
    } catch (const std::exception& e) {
        std::remove(tmp.c_str());
        throw std::runtime_error(file + ": cannot write VDB file: " + e.what());
    }
    if (std::rename(tmp.c_str(), file.c_str()) != 0) {
        std::remove(tmp.c_str());
        throw std::runtime_error(file + ": cannot rename " + tmp + " to the target");
    }
}

void ensureOpenVdbInitialized() {
    // openvdb::initialize() registers grid and map types, which file I/O needs; calling it from
    // several threads at once is not documented as safe, hence call_once.
    static std::once_flag once;
    std::call_once(once, [] { openvdb::initialize(); });
}

const openvdb::FloatGrid& LevelSet::farField(double factor, float band) const {
    std::call_once(mFar->once, [&] {
        // Isolated: while OpenVDB's parallel rebuild runs, this thread must not pick up another
        // task of an enclosing parallel loop, which could ask for this very companion and
        // wait on the flag this thread holds.
        tbb::this_task_arena::isolate([&] {
            const openvdb::math::Transform::Ptr xform = mGrid->transform().copy();
            xform->preScale(factor);
            FarFieldRecipe recipe;
            {
                std::lock_guard<std::mutex> lock(mFar->recipeMutex);
                recipe = mFar->recipe;
            }
            if (recipe) {
                // The shape's distance sampled on the coarse lattice: a sphere's companion in
                // 0.01 s instead of the 0.33 s of meshing the default scene's (the fine grid
                // on a lattice of its own, as buildLevelSet makes them, has no offset).
                openvdb::FloatGrid::Ptr far = recipe(mVoxelSize * factor, band);
                if (far && far->transform() == *xform) {
                    far->setGridClass(openvdb::GRID_LEVEL_SET);
                    mFar->grid = far;
                    return;
                }
            }
            // The fine surface meshed with a little adaptivity (0.005: flat stretches merged
            // into larger polygons), then turned into the coarse level set: the closest-point
            // searches of that second step, most of the build, see far fewer polygons (the
            // default scene's sphere at voxel 0.01: 5,859 against 46,950). The companion strays
            // a little more from the fine grid (0.0020 against 0.0009 there), which
            // CompanionError measures and every certificate subtracts; bench_coverage built its
            // level sets and their companions in 31 s against 51, for 0.3% more rays
            // (docs/BENCHMARKS.md). tools::levelSetRebuild is these two steps at adaptivity 0.
            constexpr double kAdaptivity = 0.005;
            std::vector<openvdb::Vec3s> points;
            std::vector<openvdb::Vec3I> triangles;
            std::vector<openvdb::Vec4I> quads;
            openvdb::tools::volumeToMesh(*mGrid, points, triangles, quads, 0.0, kAdaptivity);
            openvdb::FloatGrid::Ptr far =
                openvdb::tools::meshToSignedDistanceField<openvdb::FloatGrid>(*xform, points, triangles,
                                                                              quads, band, band);
            far->setGridClass(openvdb::GRID_LEVEL_SET);
            mFar->grid = far;
        });
        mFar->built.store(true, std::memory_order_release);
    });
    return *mFar->grid;
}

void LevelSet::setFarFieldRecipe(FarFieldRecipe recipe) const {
    std::lock_guard<std::mutex> lock(mFar->recipeMutex);
    mFar->recipe = std::move(recipe);
}

void LevelSet::adoptFarField(openvdb::FloatGrid::ConstPtr grid) const {
    std::call_once(mFar->once, [&] {
        mFar->grid = std::move(grid);
        mFar->built.store(true, std::memory_order_release);
    });
}

bool hasFarField(const LevelSet& ls) { return ls.farFieldIfBuilt() != nullptr; }

namespace {

// 24 million cells: 24 MB of one-voxel table (a grid of about 290 voxels along each axis).
constexpr size_t kMaxCells = size_t(24) << 20;

/// CellTables' gradient bounds over the cells of the fine table (`dims`, lowest corner `lo`;
/// `value`: the corners' values, x fastest, dims + 1 along each axis). A cell's bound is the
/// root-sum-square of its largest difference along each axis, over the voxel size; a block's
/// own is the largest of its cells', and its bound the largest over the blocks within reach:
/// what a ball of the band's half width around a point of the block touches (cells whose
/// lowest corner lies within the half width plus one voxel of the point).
void slopeTable(const openvdb::FloatGrid& fine, const openvdb::Coord& lo, const int dims[3],
                const std::vector<float>& value, CellTables& out) {
    constexpr int B = CellTables::kSlopeBlock;
    const int vd[3] = {dims[0] + 1, dims[1] + 1, dims[2] + 1};
    const int nb[3] = {(dims[0] + B - 1) / B, (dims[1] + B - 1) / B, (dims[2] + B - 1) / B};
    const size_t blocks = size_t(nb[0]) * nb[1] * nb[2];
    const double h = fine.voxelSize()[0];
    std::vector<float> own(blocks, 0.0f);
    auto at = [&](int x, int y, int z) { return value[(size_t(z) * vd[1] + y) * vd[0] + x]; };
    detail::parallelFor(tbb::blocked_range<int>(0, nb[2]), [&](const tbb::blocked_range<int>& r) {
        for (int bz = r.begin(); bz != r.end(); ++bz)
            for (int z = bz * B; z < std::min(dims[2], bz * B + B); ++z)
                for (int y = 0; y < dims[1]; ++y)
                    for (int x = 0; x < dims[0]; ++x) {
                        float m[3] = {0.0f, 0.0f, 0.0f};
                        for (int j = 0; j < 2; ++j)
                            for (int k = 0; k < 2; ++k) {
                                m[0] = std::max(m[0], std::abs(at(x + 1, y + j, z + k) - at(x, y + j, z + k)));
                                m[1] = std::max(m[1], std::abs(at(x + j, y + 1, z + k) - at(x + j, y, z + k)));
                                m[2] = std::max(m[2], std::abs(at(x + j, y + k, z + 1) - at(x + j, y + k, z)));
                            }
                        const float g = std::sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
                        float& o = own[(size_t(bz) * nb[1] + y / B) * nb[0] + x / B];
                        o = std::max(o, g);
                    }
    });
    double top = 0.0;
    for (float& o : own) {
        o = float(o / h);
        top = std::max(top, double(o));
    }
    const double halfWidth = double(fine.background()) / h;
    const int reach = int(std::ceil((halfWidth + 1.0) / B));
    out.slope.assign(blocks, 0.0f);
    for (int bz = 0; bz < nb[2]; ++bz)
        for (int by = 0; by < nb[1]; ++by)
            for (int bx = 0; bx < nb[0]; ++bx) {
                float m = 0.0f;
                for (int z = std::max(0, bz - reach); z <= std::min(nb[2] - 1, bz + reach); ++z)
                    for (int y = std::max(0, by - reach); y <= std::min(nb[1] - 1, by + reach); ++y)
                        for (int x = std::max(0, bx - reach); x <= std::min(nb[0] - 1, bx + reach); ++x)
                            m = std::max(m, own[(size_t(z) * nb[1] + y) * nb[0] + x]);
                // Rounded up a little, for the interpolant's float arithmetic.
                out.slope[(size_t(bz) * nb[1] + by) * nb[0] + bx] = m * (1.0f + 1e-5f);
            }
    for (int a = 0; a < 3; ++a) {
        out.slopeOrigin[a] = lo[a];
        out.slopeDims[a] = nb[a];
    }
    out.slopeMax = top * (1.0 + 1e-5);
}

/// The tables span the cells around every leaf and every tile inside the surface, a few cells
/// beyond: outside them all eight corners of a cell are the background or an outside tile, so
/// it is clear, as CellDistance assumes. Null for a grid that needs more than kMaxCells cells or
/// is not a level set (background not positive).
std::unique_ptr<CellTables> buildCellTables(const openvdb::FloatGrid& fine) {
    const openvdb::FloatTree& tree = fine.tree();
    if (!(tree.background() > 0.0f)) return nullptr;
    openvdb::CoordBBox box;
    if (!tree.evalLeafBoundingBox(box) || box.empty()) return nullptr;
    // Tiles only (the iterators stop above the leaves).
    auto off = tree.cbeginValueOff();
    off.setMaxDepth(openvdb::FloatTree::ValueOffCIter::LEAF_DEPTH - 1);
    for (; off; ++off)
        if (!(*off > 0.0f)) box.expand(off.getBoundingBox());
    auto on = tree.cbeginValueOn();  // active tiles (none in a level set)
    on.setMaxDepth(openvdb::FloatTree::ValueOnCIter::LEAF_DEPTH - 1);
    for (; on; ++on) box.expand(on.getBoundingBox());
    constexpr int kMargin = 4;
    box.expand(kMargin);
    const openvdb::Coord lo = box.min(), ext = box.dim();  // cells: one per voxel of `box`
    const int dims[3] = {ext.x(), ext.y(), ext.z()};
    if (size_t(dims[0]) * size_t(dims[1]) * size_t(dims[2]) > kMaxCells) return nullptr;
    // The value of every corner (voxels lo .. lo + dims), then each cell's state.
    const int vd[3] = {dims[0] + 1, dims[1] + 1, dims[2] + 1};
    std::vector<float> value(size_t(vd[0]) * vd[1] * vd[2]);
    detail::parallelFor(tbb::blocked_range<int>(0, vd[2]), [&](const tbb::blocked_range<int>& r) {
        auto acc = fine.getConstAccessor();
        for (int z = r.begin(); z != r.end(); ++z)
            for (int y = 0; y < vd[1]; ++y)
                for (int x = 0; x < vd[0]; ++x)
                    value[(size_t(z) * vd[1] + y) * vd[0] + x] = acc.getValue(lo + openvdb::Coord(x, y, z));
    });
    std::vector<CellDistance::State> states(size_t(dims[0]) * dims[1] * dims[2]);
    detail::parallelFor(tbb::blocked_range<int>(0, dims[2]), [&](const tbb::blocked_range<int>& r) {
        for (int z = r.begin(); z != r.end(); ++z)
            for (int y = 0; y < dims[1]; ++y)
                for (int x = 0; x < dims[0]; ++x) {
                    bool allPos = true, allNeg = true;
                    for (int k = 0; k < 8; ++k) {
                        const float v = value[(size_t(z + (k >> 2)) * vd[1] + y + ((k >> 1) & 1)) *
                                                  vd[0] + x + (k & 1)];
                        allPos = allPos && v > 0.0f;
                        allNeg = allNeg && v < 0.0f;
                    }
                    states[(size_t(z) * dims[1] + y) * dims[0] + x] =
                        allPos ? CellDistance::kClear
                               : allNeg ? CellDistance::kInside : CellDistance::kSurface;
                }
    });
    const int origin[3] = {lo.x(), lo.y(), lo.z()};
    // The coarse cells reach as far as the companion's band.
    const int margin = int(std::ceil(double(kFarFieldBand) * kFarFieldFactor / CellTables::kCoarseBlock));
    auto tables = std::make_unique<CellTables>(
        CellDistance(origin, dims, states),
        CellDistance::coarsened(origin, dims, states, CellTables::kCoarseBlock, margin));
    slopeTable(fine, lo, dims, value, *tables);
    return tables;
}

/// The world box around index-space box [lo, hi] (all eight corners: a linear transform may
/// rotate it).
Box3 worldBoxOf(const openvdb::FloatGrid& grid, const openvdb::Vec3d& lo, const openvdb::Vec3d& hi) {
    Box3 out;
    for (int c = 0; c < 8; ++c) {
        const openvdb::Vec3d cornerIS((c & 1) ? hi.x() : lo.x(), (c & 2) ? hi.y() : lo.y(),
                                      (c & 4) ? hi.z() : lo.z());
        const openvdb::Vec3d p = grid.indexToWorld(cornerIS);
        out.extend(Vec3(p.x(), p.y(), p.z()));
    }
    return out;
}

}  // namespace

const CellTables* LevelSet::cellTables() const {
    // Isolated: the build runs parallel loops, and a thread waiting in them must not take up
    // outer work that could call this again (and wait on the flag it holds).
    std::call_once(mCells->once, [&] {
        tbb::this_task_arena::isolate([&] { mCells->tables = buildCellTables(*mGrid); });
        mCells->built.store(true, std::memory_order_release);
    });
    return mCells->tables.get();
}

LevelSet::LevelSet(openvdb::FloatGrid::ConstPtr grid) : mGrid(std::move(grid)) {
    mVoxelSize = mGrid->voxelSize()[0];
    const openvdb::CoordBBox active = mGrid->evalActiveVoxelBoundingBox();
    if (mGrid->activeVoxelCount() == 0 || active.empty()) return;  // bounds stay empty
    // Voxel centres sit at integer index coordinates, so a voxel's cell spans +-0.5 around it.
    const openvdb::Vec3d lo = active.min().asVec3d() - openvdb::Vec3d(0.5);
    const openvdb::Vec3d hi = active.max().asVec3d() + openvdb::Vec3d(0.5);
    mBoundsWS = worldBoxOf(*mGrid, lo, hi);
    findSolid();
    findOrientedSolid();
}

// The oriented solid box: a frame that starts from the better of the world axes and the
// principal axes of the voxels <= 0 (active ones, and active tiles by their corners; the inside
// beyond the band is enclosed by them), turned about each of its axes by smaller and smaller
// angles while the volume falls (on about kSearchPoints of those points), then the extents of
// every point along it, grown by a cell's diagonal and a quarter voxel: a point where the
// interpolant is <= 0 lies in a cell with such a corner. Kept when under 0.9 of the volume of
// the axis-aligned solid box, which is tighter (a 32nd of a voxel) where the axes agree.
void LevelSet::findOrientedSolid() {
    mSolidOriented = OrientedBox::of(mSolidWS);
    if (mSolidWS.empty()) return;
    auto forEachPoint = [&](auto&& f) {
        for (auto it = mGrid->cbeginValueOn(); it; ++it) {
            if (!(*it <= 0.0f)) continue;
            if (it.isVoxelValue()) {
                f(it.getCoord().asVec3d());
                continue;
            }
            openvdb::CoordBBox box;
            it.getBoundingBox(box);
            for (int c = 0; c < 8; ++c)
                f(openvdb::Vec3d((c & 1) ? box.max().x() : box.min().x(), (c & 2) ? box.max().y() : box.min().y(),
                                 (c & 4) ? box.max().z() : box.min().z()));
        }
    };
    auto world = [&](const openvdb::Vec3d& ijk) {
        const openvdb::Vec3d w = mGrid->indexToWorld(ijk);
        return Vec3(w.x(), w.y(), w.z());
    };
    // The search's points: every stride-th, the stride from the active voxels' count (about
    // twice the points <= 0 on a level set's band).
    constexpr size_t kSearchPoints = 8000;
    const size_t stride = std::max<size_t>(1, size_t(mGrid->activeVoxelCount()) / (2 * kSearchPoints));
    std::vector<Vec3> pts;
    size_t k = 0;
    forEachPoint([&](const openvdb::Vec3d& ijk) {
        if (k++ % stride == 0) pts.push_back(world(ijk));
    });
    if (pts.size() < 4) return;
    const double grow = (std::sqrt(3.0) + 0.25) * mVoxelSize;
    struct Frame {
        Vec3 a[3];
    };
    // Widens [lo, hi] (coordinates along the frame's axes) to hold p.
    auto widen = [](const Frame& f, const Vec3& p, Vec3& lo, Vec3& hi) {
        for (int d = 0; d < 3; ++d) {
            const double x = glm::dot(p, f.a[d]);
            lo[d] = std::min(lo[d], x);
            hi[d] = std::max(hi[d], x);
        }
    };
    auto volume = [&](const Frame& f) {
        Vec3 lo(1e300), hi(-1e300);
        for (const Vec3& p : pts) widen(f, p, lo, hi);
        return (hi.x - lo.x + 2.0 * grow) * (hi.y - lo.y + 2.0 * grow) * (hi.z - lo.z + 2.0 * grow);
    };
    auto orthonormal = [](Frame f) {
        f.a[0] = glm::normalize(f.a[0]);
        f.a[1] = glm::normalize(f.a[1] - glm::dot(f.a[1], f.a[0]) * f.a[0]);
        f.a[2] = glm::cross(f.a[0], f.a[1]);
        return f;
    };
    Frame best{{Vec3(1.0, 0.0, 0.0), Vec3(0.0, 1.0, 0.0), Vec3(0.0, 0.0, 1.0)}};
    double bestVolume = volume(best);
    {
        Vec3 mean(0.0);
        for (const Vec3& p : pts) mean += p;
        mean /= double(pts.size());
        openvdb::math::Mat3d cov(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for (const Vec3& p : pts) {
            const Vec3 d = p - mean;
            for (int i = 0; i < 3; ++i)
                for (int j = 0; j < 3; ++j) cov(i, j) += d[i] * d[j];
        }
        openvdb::math::Mat3d q;
        openvdb::math::Vec3d eig;
        if (openvdb::math::diagonalizeSymmetricMatrix(cov, q, eig)) {
            const Frame pca = orthonormal(
                Frame{{Vec3(q(0, 0), q(1, 0), q(2, 0)), Vec3(q(0, 1), q(1, 1), q(2, 1)), Vec3(q(0, 2), q(1, 2), q(2, 2))}});
            if (std::isfinite(pca.a[2].x)) {
                const double v = volume(pca);
                if (v < bestVolume) best = pca, bestVolume = v;
            }
        }
    }
    for (double angle = kPi / 8.0; angle > kPi / 256.0; angle *= 0.5) {
        for (int round = 0; round < 4; ++round) {
            bool improved = false;
            for (int axis = 0; axis < 3; ++axis)
                for (double sign : {1.0, -1.0}) {
                    const Vec3& u = best.a[(axis + 1) % 3];
                    const Vec3& w = best.a[(axis + 2) % 3];
                    const double c = std::cos(sign * angle), sn = std::sin(sign * angle);
                    Frame f = best;
                    f.a[(axis + 1) % 3] = c * u + sn * w;
                    f.a[(axis + 2) % 3] = c * w - sn * u;
                    f = orthonormal(f);
                    const double v = volume(f);
                    if (v < bestVolume) best = f, bestVolume = v, improved = true;
                }
            if (!improved) break;
        }
    }
    // The extents of every point, along the frame found.
    Vec3 lo(1e300), hi(-1e300);
    forEachPoint([&](const openvdb::Vec3d& ijk) { widen(best, world(ijk), lo, hi); });
    OrientedBox ob;
    ob.half = 0.5 * (hi - lo) + Vec3(grow);
    const Vec3 mid = 0.5 * (lo + hi);
    for (int d = 0; d < 3; ++d) ob.axis[d] = best.a[d];
    ob.centre = mid.x * best.a[0] + mid.y * best.a[1] + mid.z * best.a[2];
    if (ob.volume() < 0.9 * OrientedBox::of(mSolidWS).volume()) mSolidOriented = ob;
}

void LevelSet::findSolid() {
    // Index space first (voxels are uniform: world distances are index distances times the
    // voxel size), then the box's corners and the centre mapped to world space.
    openvdb::Vec3d lo(1e300), hi(-1e300);
    bool any = false;
    for (auto it = mGrid->cbeginValueOn(); it; ++it) {
        if (!(*it <= 0.0f)) continue;
        openvdb::CoordBBox box;
        it.getBoundingBox(box);  // one voxel, or a tile's voxels
        lo = openvdb::math::minComponent(lo, box.min().asVec3d());
        hi = openvdb::math::maxComponent(hi, box.max().asVec3d());
        any = true;
    }
    // A point where the trilinear interpolation is <= 0 lies in a cell with a corner <= 0:
    // within one voxel, along each axis, of such a voxel's centre (and deep inside voxels,
    // inactive, are enclosed by the band's). A quarter voxel more for rounding.
    const double grow = 1.25;
    if (!any) {
        mSolidWS = mBoundsWS;
        mSolidCentre = 0.5 * (mBoundsWS.lo + mBoundsWS.hi);
        mSolidRadius = 0.5 * glm::length(mBoundsWS.hi - mBoundsWS.lo);
        return;
    }
    lo -= openvdb::Vec3d(grow);
    hi += openvdb::Vec3d(grow);
    mSolidWS = worldBoxOf(*mGrid, lo, hi);
    const openvdb::Vec3d centre = 0.5 * (lo + hi);
    double far2 = 0.0;
    for (auto it = mGrid->cbeginValueOn(); it; ++it) {
        if (!(*it <= 0.0f)) continue;
        if (it.isVoxelValue()) {
            far2 = std::max(far2, (it.getCoord().asVec3d() - centre).lengthSqr());
            continue;
        }
        openvdb::CoordBBox box;
        it.getBoundingBox(box);
        for (int c = 0; c < 8; ++c) {
            const openvdb::Vec3d p((c & 1) ? box.max().x() : box.min().x(),
                                   (c & 2) ? box.max().y() : box.min().y(),
                                   (c & 4) ? box.max().z() : box.min().z());
            far2 = std::max(far2, (p - centre).lengthSqr());
        }
    }
    const openvdb::Vec3d cw = mGrid->indexToWorld(centre);
    mSolidCentre = Vec3(cw.x(), cw.y(), cw.z());
    mSolidRadius = (std::sqrt(far2) + grow * std::sqrt(3.0)) * mVoxelSize;
    // The same, tight: to a 32nd of a voxel from the cells themselves (a sphere's solid sphere
    // was two voxels wider than the sphere, its shadow's footprint on a light that much wider).
    openvdb::Vec3d tightLo = lo, tightHi = hi;
    double tightRadius = mSolidRadius / mVoxelSize;
    tightenSolid(centre, tightLo, tightHi, tightRadius);
    mSolidWS = worldBoxOf(*mGrid, openvdb::math::maxComponent(lo, tightLo),
                          openvdb::math::minComponent(hi, tightHi));
    mSolidRadius = std::min(mSolidRadius, tightRadius * mVoxelSize);

    // The parts: every value <= 0 (inactive voxels and tiles too: the parts, unlike the box,
    // need not enclose the inside) grown by `grow`, clipped to the cells of the box it meets.
    constexpr int G = kSolidPartsPerAxis;
    openvdb::Vec3d partLo[G * G * G], partHi[G * G * G];
    for (int k = 0; k < G * G * G; ++k) {
        partLo[k] = openvdb::Vec3d(1e300);
        partHi[k] = openvdb::Vec3d(-1e300);
    }
    const openvdb::Vec3d cell = (hi - lo) / double(G);
    for (auto it = mGrid->cbeginValueAll(); it; ++it) {
        if (!(*it <= 0.0f)) continue;
        openvdb::CoordBBox box;
        it.getBoundingBox(box);
        const openvdb::Vec3d a = openvdb::math::maxComponent(box.min().asVec3d() - openvdb::Vec3d(grow), lo);
        const openvdb::Vec3d b = openvdb::math::minComponent(box.max().asVec3d() + openvdb::Vec3d(grow), hi);
        if (!(a.x() <= b.x() && a.y() <= b.y() && a.z() <= b.z())) continue;
        int c0[3], c1[3];
        for (int d = 0; d < 3; ++d) {
            c0[d] = std::clamp(int(std::floor((a[d] - lo[d]) / cell[d])), 0, G - 1);
            c1[d] = std::clamp(int(std::floor((b[d] - lo[d]) / cell[d])), 0, G - 1);
        }
        for (int z = c0[2]; z <= c1[2]; ++z)
            for (int y = c0[1]; y <= c1[1]; ++y)
                for (int x = c0[0]; x <= c1[0]; ++x) {
                    const int k = (z * G + y) * G + x;
                    const openvdb::Vec3d cl = lo + openvdb::Vec3d(x, y, z) * cell;
                    // The cell's own range (the last cell reaches hi exactly).
                    const openvdb::Vec3d ch(x == G - 1 ? hi.x() : cl.x() + cell.x(),
                                            y == G - 1 ? hi.y() : cl.y() + cell.y(),
                                            z == G - 1 ? hi.z() : cl.z() + cell.z());
                    partLo[k] = openvdb::math::minComponent(partLo[k], openvdb::math::maxComponent(a, cl));
                    partHi[k] = openvdb::math::maxComponent(partHi[k], openvdb::math::minComponent(b, ch));
                }
    }
    for (int k = 0; k < G * G * G; ++k) {
        if (partLo[k].x() <= partHi[k].x()) mSolidParts.push_back(worldBoxOf(*mGrid, partLo[k], partHi[k]));
    }
}

LevelSetInfo describe(const LevelSet& ls) {
    const openvdb::FloatGrid& grid = ls.grid();
    LevelSetInfo info;
    info.name = grid.getName();
    info.voxelSize = ls.voxelSize();
    // A level set's background is the narrow-band half width in world units.
    info.halfWidth = ls.voxelSize() > 0.0 ? double(grid.background()) / ls.voxelSize() : 0.0;
    info.boundsWS = ls.boundsWS();
    info.activeVoxels = grid.activeVoxelCount();
    info.bytes = grid.memUsage();
    return info;
}

double voxelSizeOf(const LevelSet& ls) { return ls.voxelSize(); }

double sampleLevelSet(const LevelSet& ls, const Vec3& pointWS) {
    const openvdb::FloatGrid& grid = ls.grid();
    // An unregistered accessor: the grid is read-only while it lives, and registering one would
    // write the tree's accessor table, which other threads' accessors also write.
    openvdb::FloatGrid::ConstUnsafeAccessor acc = grid.getConstUnsafeAccessor();
    return openvdb::tools::BoxSampler::sample(
        acc, grid.worldToIndex(openvdb::Vec3d(pointWS.x, pointWS.y, pointWS.z)));
}

namespace {

void checkBuildParameters(double voxelSize, double halfWidthVoxels) {
    if (!(voxelSize > 0.0)) {
        throw InputError("", "",
                         "level set voxel size must be > 0, got " + std::to_string(voxelSize));
    }
    // OpenVDB's rasterizers refuse a band of one voxel or less.
    if (!(halfWidthVoxels > 1.0)) {
        throw InputError(
            "", "",
            "level set half width must be > 1 voxel, got " + std::to_string(halfWidthVoxels));
    }
}

std::string gridClassName(openvdb::GridClass cls) {
    return openvdb::GridBase::gridClassToString(cls);
}

}  // namespace

LevelSetPtr makeSphereLevelSet(const Vec3& center, double radius, double voxelSize,
                               double halfWidthVoxels, const std::string& name) {
    checkBuildParameters(voxelSize, halfWidthVoxels);
    if (!(radius > 0.0)) {
        throw InputError("", "", "sphere radius must be > 0, got " + std::to_string(radius));
    }
    ensureOpenVdbInitialized();
    openvdb::FloatGrid::Ptr grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(
        float(radius), openvdb::Vec3f(float(center.x), float(center.y), float(center.z)),
        float(voxelSize), float(halfWidthVoxels));
    grid->setName(name);
    grid->setGridClass(openvdb::GRID_LEVEL_SET);
    return std::make_shared<const LevelSet>(grid);
}

LevelSetPtr makeBoxLevelSet(const Vec3& lo, const Vec3& hi, double voxelSize,
                            double halfWidthVoxels, const std::string& name) {
    checkBuildParameters(voxelSize, halfWidthVoxels);
    if (!(hi.x > lo.x && hi.y > lo.y && hi.z > lo.z)) {
        throw InputError("", "", "box must have hi > lo on every axis");
    }
    ensureOpenVdbInitialized();
    const openvdb::math::Transform::Ptr xform =
        openvdb::math::Transform::createLinearTransform(voxelSize);
    const openvdb::math::BBox<openvdb::Vec3d> box(openvdb::Vec3d(lo.x, lo.y, lo.z),
                                                  openvdb::Vec3d(hi.x, hi.y, hi.z));
    openvdb::FloatGrid::Ptr grid =
        openvdb::tools::createLevelSetBox<openvdb::FloatGrid>(box, *xform, halfWidthVoxels);
    grid->setName(name);
    grid->setGridClass(openvdb::GRID_LEVEL_SET);
    return std::make_shared<const LevelSet>(grid);
}

namespace {

/// The median, over up to about 4,000 active voxels within a voxel of the surface, of the
/// world-space gradient magnitude of the values (central differences); NaN when none is found.
double medianGradientNearSurface(const openvdb::FloatGrid& grid) {
    const double voxel = grid.voxelSize()[0];
    const openvdb::Index64 active = grid.activeVoxelCount();
    const openvdb::Index64 stride = std::max<openvdb::Index64>(1, active / 20000);
    auto acc = grid.getConstAccessor();
    std::vector<double> slopes;
    openvdb::Index64 k = 0;
    for (auto it = grid.cbeginValueOn(); it && slopes.size() < 4000; ++it) {
        if (!it.isVoxelValue() || (k++ % stride) != 0) continue;
        if (!(std::abs(*it) < voxel)) continue;
        const openvdb::Coord c = it.getCoord();
        double g2 = 0.0;
        for (int axis = 0; axis < 3; ++axis) {
            openvdb::Coord a = c, b = c;
            a[axis] += 1;
            b[axis] -= 1;
            const double d = (double(acc.getValue(a)) - double(acc.getValue(b))) / (2.0 * voxel);
            g2 += d * d;
        }
        slopes.push_back(std::sqrt(g2));
    }
    if (slopes.empty()) return std::numeric_limits<double>::quiet_NaN();
    std::nth_element(slopes.begin(), slopes.begin() + slopes.size() / 2, slopes.end());
    return slopes[slopes.size() / 2];
}

/// Turns one grid read from `file` into a LevelSet, or explains why it is not usable.
LevelSetPtr acceptGrid(const openvdb::GridBase::Ptr& base, const std::string& file,
                       const std::string& where) {
    const std::string name = "grid '" + base->getName() + "'";
    if (base->getGridClass() != openvdb::GRID_LEVEL_SET) {
        throw InputError(file, where,
                         name + " is not a level set (grid class '" +
                             gridClassName(base->getGridClass()) + "')");
    }
    // Half-float grids are stored as "Tree_float_..._HalfFloat" and load as FloatGrid.
    openvdb::FloatGrid::Ptr grid = openvdb::gridPtrCast<openvdb::FloatGrid>(base);
    if (!grid) {
        throw InputError(file, where,
                         name + " has value type '" + base->valueType() + "', expected float");
    }
    const openvdb::math::Transform& xform = grid->transform();
    if (!xform.isLinear() || !grid->hasUniformVoxels()) {
        const openvdb::Vec3d v = xform.voxelSize();
        std::ostringstream msg;
        msg << name << " has non-uniform voxels (voxel size " << v.x() << " x " << v.y() << " x "
            << v.z() << (xform.isLinear() ? "" : ", non-linear map")
            << "); only uniform linear transforms are supported";
        throw InputError(file, where, msg.str());
    }
    if (!(grid->background() > 0.0f)) {
        throw InputError(file, where, name + " has a non-positive background value");
    }
    if (grid->activeVoxelCount() == 0) {
        throw InputError(file, where, name + " has no active voxels");
    }
    // A level set's values are distances: |grad phi| = 1 near the surface. A grid whose
    // transform was scaled without its values is not, and every distance the estimator trusts
    // (certificates, Newton steps) would be off by that factor.
    const double slope = medianGradientNearSurface(*grid);
    if (std::isfinite(slope) && (slope < 0.7 || slope > 1.4)) {
        std::ostringstream msg;
        msg << name << " is not a distance field: |grad phi| is " << std::setprecision(2)
            << slope
            << " near its surface (1 for a level set; was its transform scaled without its "
               "values?); multiply its values by "
            << 1.0 / slope << " or rebuild it as a level set (OpenVDB's levelSetRebuild)";
        throw InputError(file, where, msg.str());
    }
    return std::make_shared<const LevelSet>(grid);
}

}  // namespace

namespace {

/// Walks a .vdb file's header, file metadata and grid descriptors (the layout openvdb::io::File
/// reads, file format 222 and later) with every length and offset checked against the file's
/// size, before OpenVDB reads anything: OpenVDB trusts the counts it reads, so a truncated or
/// corrupt file would have it allocate whatever garbage says (gigabytes for a 200-byte file).
/// Older formats are left to OpenVDB.
class VdbHeaderProbe {
public:
    VdbHeaderProbe(const std::string& file, const std::string& where) : mFile(file), mWhere(where) {}

    void check() {
        mIn.open(mFile, std::ios::binary);
        if (!mIn) fail("cannot open it");
        mIn.seekg(0, std::ios::end);
        mSize = static_cast<int64_t>(mIn.tellg());
        mIn.seekg(0, std::ios::beg);
        if (pod<int64_t>() != 0x56444220) fail("IoError: not a VDB file");
        const uint32_t version = pod<uint32_t>();
        if (version < 222) return;  // an old format: OpenVDB's own reader decides
        if (version > 1000) fail("corrupt header (file format " + std::to_string(version) + ")");
        skip(8);                             // library version, major and minor
        const bool offsets = pod<char>() != 0;
        skip(36);                            // UUID
        const int32_t metaCount = pod<int32_t>();
        if (metaCount < 0 || metaCount > remaining()) fail("corrupt file metadata");
        for (int32_t i = 0; i < metaCount; ++i) {
            skipString();  // name
            skipString();  // type
            skip(pod<uint32_t>());  // value
        }
        if (!offsets) return;
        const int32_t grids = pod<int32_t>();
        if (grids < 0 || grids > remaining()) fail("corrupt grid count");
        for (int32_t i = 0; i < grids; ++i) {
            const std::string name = string();
            skipString();  // grid type
            skipString();  // instance parent
            const int64_t grid = pod<int64_t>(), block = pod<int64_t>(), end = pod<int64_t>();
            if (!(tell() <= grid && grid <= block && block <= end && end <= mSize)) {
                std::ostringstream msg;
                msg << "grid " << i << " ('" << printable(name) << "') claims bytes up to " << end
                    << " but the file has " << mSize << " (truncated or corrupt)";
                fail(msg.str());
            }
            mIn.seekg(end);
        }
    }

private:
    [[noreturn]] void fail(const std::string& why) const {
        throw InputError(mFile, mWhere, "cannot read VDB file: " + why);
    }
    int64_t tell() { return static_cast<int64_t>(mIn.tellg()); }
    int64_t remaining() { return mSize - tell(); }
    void skip(uint64_t n) {
        if (n > static_cast<uint64_t>(remaining())) fail("truncated or corrupt header");
        mIn.seekg(static_cast<std::streamoff>(n), std::ios::cur);
    }
    template <typename T> T pod() {
        T v{};
        if (remaining() < int64_t(sizeof(T))) fail("truncated or corrupt header");
        mIn.read(reinterpret_cast<char*>(&v), sizeof(T));
        if (!mIn) fail("truncated or corrupt header");
        return v;
    }
    void skipString() { skip(pod<uint32_t>()); }
    std::string string() {
        const uint32_t n = pod<uint32_t>();
        if (n > static_cast<uint64_t>(remaining()) || n > 4096) fail("corrupt grid name");
        std::string out(n, '\0');
        mIn.read(out.data(), n);
        return out;
    }
    static std::string printable(std::string s) {
        // OpenVDB marks duplicate names with a suffix after a control character.
        for (char& c : s) {
            if (static_cast<unsigned char>(c) < 32 || static_cast<unsigned char>(c) > 126) c = '?';
        }
        return s;
    }

    std::string mFile, mWhere;
    std::ifstream mIn;
    int64_t mSize = 0;
};

}  // namespace

void checkVdbFile(const std::string& file, const std::string& where) {
    ensureOpenVdbInitialized();
    try {
        VdbHeaderProbe(file, where).check();
    } catch (const InputError&) {
        throw;
    } catch (const std::bad_alloc&) {
        throw InputError(file, where, "cannot read VDB file: corrupt header");
    } catch (const std::exception& e) {
        throw InputError(file, where, std::string("cannot read VDB file: ") + e.what());
    }
}

std::vector<LevelSetPtr> readLevelSets(const std::string& file, const std::string& gridName,
                                       const std::string& where) {
    ensureOpenVdbInitialized();
    std::error_code ec;
    if (!std::filesystem::is_regular_file(file, ec)) {
        throw InputError(file, where, "cannot read VDB file: no such file");
    }
    checkVdbFile(file, where);
    openvdb::GridPtrVecPtr grids;
    withVdbErrors(file, where, [&] {
        openvdb::io::File vdb(file);
        // Read the voxel data now: delayed loading would make the render threads page leaves in.
        vdb.open(/*delayLoad=*/false);
        if (!gridName.empty()) {
            if (!vdb.hasGrid(gridName)) {
                std::string names;
                for (auto it = vdb.beginName(); it != vdb.endName(); ++it) {
                    names += (names.empty() ? "" : ", ") + ("'" + it.gridName() + "'");
                }
                throw InputError(file, where,
                                 "no grid named '" + gridName + "' (the file holds " +
                                     (names.empty() ? std::string("no grids") : names) + ")");
            }
            grids = std::make_shared<openvdb::GridPtrVec>();
            grids->push_back(vdb.readGrid(gridName));
        } else {
            grids = vdb.getGrids();
        }
        vdb.close();
    });

    std::vector<LevelSetPtr> out;
    if (!gridName.empty()) {
        out.push_back(acceptGrid(grids->front(), file, where));
        return out;
    }
    std::string skipped;
    for (const openvdb::GridBase::Ptr& g : *grids) {
        if (g->getGridClass() == openvdb::GRID_LEVEL_SET && g->isType<openvdb::FloatGrid>()) {
            out.push_back(acceptGrid(g, file, where));
        } else {
            skipped += (skipped.empty() ? "" : ", ") +
                       ("'" + g->getName() + "' (" + gridClassName(g->getGridClass()) + ", " +
                        g->valueType() + ")");
        }
    }
    if (out.empty()) {
        throw InputError(file, where,
                         "no float level-set grid in the file" +
                             (skipped.empty() ? std::string(" (it holds no grids)")
                                              : " (it holds " + skipped + ")"));
    }
    return out;
}

void writeLevelSets(const std::string& file, const std::vector<LevelSetPtr>& grids) {
    writeLevelSets(file, grids, VdbWriteOptions{});
}

void writeLevelSets(const std::string& file, const std::vector<LevelSetPtr>& grids,
                    const VdbWriteOptions& options) {
    ensureOpenVdbInitialized();
    openvdb::GridCPtrVec out;
    for (const LevelSetPtr& ls : grids) {
        if (!options.halfFloat) {
            out.push_back(ls->gridPtr());
            continue;
        }
        // The half-float flag is grid metadata: change it on a copy that shares the voxels.
        openvdb::MetaMap meta(ls->grid());
        meta.insertMeta(openvdb::GridBase::META_SAVE_HALF_FLOAT, openvdb::BoolMetadata(true));
        out.push_back(ls->grid().copyGridReplacingMetadata(meta));
    }
    writeVdbAtomically(file, out);
}

// ---------------------------------------------------------------------------------------------
// Level-set cache files

namespace {

constexpr const char* kCacheFormat = "penumbra-level-set-cache";
// 2: a primitive's companion is its own distance sampled (LevelSet::setFarFieldRecipe).
constexpr int kCacheVersion = 2;

// Grids in a cache file are named by position ("ls_0", "ls_0_far", ...); what they were called
// travels in their metadata.
std::string cacheGridName(size_t i, bool far) {
    return "ls_" + std::to_string(i) + (far ? "_far" : "");
}

openvdb::GridBase::ConstPtr cacheGrid(const openvdb::FloatGrid& grid, const std::string& name,
                                      const std::string& label) {
    openvdb::MetaMap meta(grid);
    meta.insertMeta("penumbra_grid_name", openvdb::StringMetadata(grid.getName()));
    meta.insertMeta("penumbra_label", openvdb::StringMetadata(label));
    meta.insertMeta(openvdb::GridBase::META_GRID_NAME, openvdb::StringMetadata(name));
    return grid.copyGridReplacingMetadata(meta);
}

std::string stringMeta(const openvdb::MetaMap& meta, const std::string& name) {
    const auto m = meta.getMetadata<openvdb::StringMetadata>(name);
    return m ? m->value() : std::string();
}

}  // namespace

void writeCacheFile(const std::string& file, const std::string& key, const CacheFileEntry& entry) {
    ensureOpenVdbInitialized();
    if (entry.labels.size() != entry.levelSets.size()) {
        throw std::invalid_argument("writeCacheFile: one label per level set");
    }
    openvdb::GridCPtrVec grids;
    for (size_t i = 0; i < entry.levelSets.size(); ++i) {
        const LevelSet& ls = *entry.levelSets[i];
        grids.push_back(cacheGrid(ls.grid(), cacheGridName(i, false), entry.labels[i]));
        if (const openvdb::FloatGrid::ConstPtr far = ls.farFieldIfBuilt()) {
            grids.push_back(cacheGrid(*far, cacheGridName(i, true), entry.labels[i]));
        }
    }
    openvdb::MetaMap fileMeta;
    fileMeta.insertMeta("penumbra_format", openvdb::StringMetadata(kCacheFormat));
    fileMeta.insertMeta("penumbra_version", openvdb::Int32Metadata(kCacheVersion));
    fileMeta.insertMeta("penumbra_key", openvdb::StringMetadata(key));
    fileMeta.insertMeta("penumbra_far_factor", openvdb::DoubleMetadata(kFarFieldFactor));
    fileMeta.insertMeta("penumbra_far_band", openvdb::FloatMetadata(kFarFieldBand));
    writeVdbAtomically(file, grids, fileMeta);
}

CacheFileEntry readCacheFile(const std::string& file, const std::string& key) {
    ensureOpenVdbInitialized();
    openvdb::GridPtrVecPtr grids;
    openvdb::MetaMap::Ptr fileMeta;
    try {
        checkVdbFile(file, "");  // bounded header walk: a truncated file is refused here
        openvdb::io::File vdb(file);
        vdb.open(/*delayLoad=*/false);
        fileMeta = vdb.getMetadata();
        grids = vdb.getGrids();
        vdb.close();
    } catch (const InputError& e) {
        throw std::runtime_error(e.message());
    } catch (const std::bad_alloc&) {
        throw std::runtime_error("corrupt (out of memory reading it)");
    } catch (const std::exception& e) {
        throw std::runtime_error(e.what());
    }
    if (!fileMeta || stringMeta(*fileMeta, "penumbra_format") != kCacheFormat) {
        throw std::runtime_error("not a penumbra level-set cache file");
    }
    const auto version = fileMeta->getMetadata<openvdb::Int32Metadata>("penumbra_version");
    const auto factor = fileMeta->getMetadata<openvdb::DoubleMetadata>("penumbra_far_factor");
    const auto band = fileMeta->getMetadata<openvdb::FloatMetadata>("penumbra_far_band");
    if (!version || version->value() != kCacheVersion || !factor ||
        factor->value() != kFarFieldFactor || !band || band->value() != kFarFieldBand) {
        throw std::runtime_error("written by another version of penumbra");
    }
    if (stringMeta(*fileMeta, "penumbra_key") != key) {
        throw std::runtime_error("made for other obstacles (its key differs)");
    }
    std::map<std::string, openvdb::FloatGrid::Ptr> byName;
    for (const openvdb::GridBase::Ptr& g : *grids) {
        auto f = openvdb::gridPtrCast<openvdb::FloatGrid>(g);
        if (!f || f->getGridClass() != openvdb::GRID_LEVEL_SET || !f->hasUniformVoxels() ||
            !f->transform().isLinear()) {
            throw std::runtime_error("grid '" + g->getName() + "' is not a float level set");
        }
        byName[f->getName()] = f;
    }
    CacheFileEntry entry;
    for (size_t i = 0;; ++i) {
        const auto it = byName.find(cacheGridName(i, false));
        if (it == byName.end()) break;
        openvdb::MetaMap meta(*it->second);
        meta.insertMeta(openvdb::GridBase::META_GRID_NAME,
                        openvdb::StringMetadata(stringMeta(meta, "penumbra_grid_name")));
        const std::string label = stringMeta(meta, "penumbra_label");
        meta.removeMeta("penumbra_grid_name");
        meta.removeMeta("penumbra_label");
        auto grid = openvdb::gridConstPtrCast<openvdb::FloatGrid>(
            it->second->copyGridReplacingMetadata(meta));
        auto ls = std::make_shared<const LevelSet>(grid);
        const auto far = byName.find(cacheGridName(i, true));
        if (far != byName.end()) {
            openvdb::MetaMap farMeta(*far->second);
            farMeta.removeMeta("penumbra_grid_name");
            farMeta.removeMeta("penumbra_label");
            ls->adoptFarField(openvdb::gridConstPtrCast<openvdb::FloatGrid>(
                far->second->copyGridReplacingMetadata(farMeta)));
            ++entry.farFields;
        }
        entry.levelSets.push_back(std::move(ls));
        entry.labels.push_back(label);
    }
    if (entry.levelSets.empty() || entry.levelSets.size() * 2 < byName.size() ||
        entry.levelSets.size() + size_t(entry.farFields) != byName.size()) {
        throw std::runtime_error("its grids are not those of a cache entry");
    }
    return entry;
}

LevelSetPtr renamedLevelSet(const LevelSetPtr& levelSet, const std::string& name) {
    if (!levelSet) throw std::invalid_argument("renamedLevelSet: null level set");
    openvdb::MetaMap meta(levelSet->grid());
    meta.insertMeta(openvdb::GridBase::META_GRID_NAME, openvdb::StringMetadata(name));
    return std::make_shared<const LevelSet>(openvdb::gridConstPtrCast<openvdb::FloatGrid>(
        levelSet->grid().copyGridReplacingMetadata(meta)));
}

}  // namespace penumbra
