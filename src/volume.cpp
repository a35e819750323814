#include "penumbra/volume.h"

#include <openvdb/io/File.h>
#include <openvdb/math/Ray.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/LevelSetUtil.h>
#include <openvdb/tools/RayIntersector.h>
#include <openvdb/tools/Count.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <map>
#include <sstream>
#include <stdexcept>

#include "level_set_impl.h"
#include "penumbra/error.h"
#include "penumbra/output_files.h"

namespace penumbra {

namespace {
using FloatGrid = openvdb::FloatGrid;
using VolumeIntersector = openvdb::tools::VolumeRayIntersector<FloatGrid>;
using IndexRay = openvdb::math::Ray<double>;
}  // namespace

class VolumeGrid {
public:
    explicit VolumeGrid(FloatGrid::ConstPtr grid) : mGrid(std::move(grid)) {
        const openvdb::Vec3d vs = mGrid->voxelSize();
        mVoxelSize = std::min({vs.x(), vs.y(), vs.z()});
        openvdb::CoordBBox active;
        if (mGrid->tree().evalActiveVoxelBoundingBox(active) && !active.empty()) {
            // Trilinear samples reach one voxel beyond the active ones.
            const openvdb::Vec3d lo = active.min().asVec3d() - openvdb::Vec3d(1.0);
            const openvdb::Vec3d hi = active.max().asVec3d() + openvdb::Vec3d(1.0);
            for (int c = 0; c < 8; ++c) {
                const openvdb::Vec3d p = mGrid->indexToWorld(openvdb::Vec3d(
                    (c & 1) ? hi.x() : lo.x(), (c & 2) ? hi.y() : lo.y(), (c & 4) ? hi.z() : lo.z()));
                mBounds.extend(Vec3(p.x(), p.y(), p.z()));
            }
            // The largest active value (the active bounding box above is not empty).
            const openvdb::math::MinMax<float> range = openvdb::tools::minMax(mGrid->tree(), false);
            mMaxDensity = std::max(0.0, double(range.max()));
            // One voxel of dilation: the interpolation kernel reaches that far.
            if (mMaxDensity > 0.0) mIntersector = std::make_unique<VolumeIntersector>(*mGrid, 1);
            if (mMaxDensity > 0.0) buildSupport();
        }
    }

    const FloatGrid& grid() const { return *mGrid; }
    const FloatGrid::ConstPtr& gridPtr() const { return mGrid; }
    const Box3& bounds() const { return mBounds; }
    const MediumSupport& support() const { return mSupport; }
    double voxelSize() const { return mVoxelSize; }
    double maxDensity() const { return mMaxDensity; }
    /// Null when nothing is active or every density is 0 (nothing to march).
    const VolumeIntersector* intersector() const { return mIntersector.get(); }

private:
    FloatGrid::ConstPtr mGrid;
    Box3 mBounds;
    double mVoxelSize = 0.0;
    double mMaxDensity = 0.0;
    std::unique_ptr<VolumeIntersector> mIntersector;  // the master copy: owns the mask tree
    MediumSupport mSupport;

    // The world bounds of the index box [lo - 1, hi + 1]: where a trilinear sample can see a
    // voxel of [lo, hi].
    Box3 worldBox(const openvdb::Coord& lo, const openvdb::Coord& hi) const {
        Box3 b;
        const openvdb::Vec3d a = lo.asVec3d() - openvdb::Vec3d(1.0);
        const openvdb::Vec3d z = hi.asVec3d() + openvdb::Vec3d(1.0);
        for (int c = 0; c < 8; ++c) {
            const openvdb::Vec3d p = mGrid->indexToWorld(openvdb::Vec3d(
                (c & 1) ? z.x() : a.x(), (c & 2) ? z.y() : a.y(), (c & 4) ? z.z() : a.z()));
            b.extend(Vec3(p.x(), p.y(), p.z()));
        }
        return b;
    }

    void buildSupport() {
        const FloatGrid::TreeType& tree = mGrid->tree();
        mSupport.maxDensity = mMaxDensity;
        if (tree.background() != 0.0f) {  // density between the active voxels too
            for (auto it = mGrid->cbeginValueAll(); it; ++it)
                mSupport.maxDensity = std::max(mSupport.maxDensity, double(*it));
            mSupport.maxDensity = std::max(mSupport.maxDensity, double(tree.background()));
            mSupport.parts.push_back({mBounds, mSupport.maxDensity});
            mSupport.blocks.push_back({mBounds, 0, 1});
            mSupport.featureLength = mVoxelSize;  // not measured: the finest there is
            return;
        }
        // Each leaf's voxels with a positive value (active or not: trilinear samples read
        // both), keyed by their 32^3 block; then the tiles with a positive value, each a block.
        std::map<openvdb::Coord, std::vector<MediumSupport::Part>> byBlock;
        FloatGrid::ConstAccessor acc = mGrid->getConstAccessor();
        double step = 0.0;  // the largest difference between neighbouring voxels
        for (auto leaf = tree.cbeginLeaf(); leaf; ++leaf) {
            openvdb::CoordBBox dense;
            double most = 0.0;
            for (openvdb::Index k = 0; k < FloatGrid::TreeType::LeafNodeType::SIZE; ++k) {
                const float v = leaf->getValue(k);
                const openvdb::Coord c = leaf->offsetToGlobalCoord(k);
                for (int a = 0; a < 3; ++a) {
                    openvdb::Coord d = c;
                    // Both sides: a leaf's neighbours across its low faces may be background.
                    d[a] += 1;
                    step = std::max(step, double(std::abs(acc.getValue(d) - v)));
                    d[a] -= 2;
                    step = std::max(step, double(std::abs(acc.getValue(d) - v)));
                }
                if (!(v > 0.0f)) continue;
                dense.expand(c);
                most = std::max(most, double(v));
            }
            if (dense.empty()) continue;
            const openvdb::Coord o = leaf->origin();
            byBlock[openvdb::Coord(o.x() >> 5, o.y() >> 5, o.z() >> 5)].push_back(
                MediumSupport::Part{worldBox(dense.min(), dense.max()), most});
            mSupport.maxDensity = std::max(mSupport.maxDensity, most);
        }
        for (const auto& [key, parts] : byBlock) {
            MediumSupport::Block block;
            block.first = uint32_t(mSupport.parts.size());
            block.count = uint32_t(parts.size());
            for (const MediumSupport::Part& p : parts) {
                block.box.extend(p.box);
                mSupport.parts.push_back(p);
            }
            mSupport.blocks.push_back(block);
        }
        FloatGrid::ValueAllCIter tile = mGrid->cbeginValueAll();
        tile.setMaxDepth(FloatGrid::ValueAllCIter::LEAF_DEPTH - 1);  // tiles only
        for (; tile; ++tile) {
            if (!(*tile > 0.0f)) continue;
            mSupport.maxDensity = std::max(mSupport.maxDensity, double(*tile));
            openvdb::CoordBBox b;
            tile.getBoundingBox(b);
            const Box3 w = worldBox(b.min(), b.max());
            mSupport.blocks.push_back({w, uint32_t(mSupport.parts.size()), 1});
            mSupport.parts.push_back({w, double(*tile)});
            step = std::max(step, double(*tile));  // its border with the background
        }
        mSupport.featureLength = step > 0.0 ? mSupport.maxDensity / step * mVoxelSize
                                            : std::numeric_limits<double>::infinity();
    }
};

namespace {

// Refuses a density grid with a negative, NaN or infinite value, naming the first such voxel.
void checkDensities(const FloatGrid& grid, const std::string& file, const std::string& where) {
    for (auto it = grid.cbeginValueAll(); it; ++it) {
        const float v = *it;
        if (std::isfinite(v) && v >= 0.0f) continue;
        const openvdb::Coord c = it.getCoord();
        std::ostringstream s;
        s << "grid '" << grid.getName() << "': density " << v << " at voxel [" << c.x() << ", "
          << c.y() << ", " << c.z() << "]" << (it.isTileValue() ? " (a tile)" : "")
          << ": densities must be finite and >= 0";
        throw InputError(file, where, s.str());
    }
}

const char* className(openvdb::GridClass c) {
    switch (c) {
        case openvdb::GRID_LEVEL_SET: return "level set";
        case openvdb::GRID_FOG_VOLUME: return "fog volume";
        case openvdb::GRID_STAGGERED: return "staggered";
        default: return "unknown class";
    }
}

}  // namespace

const MediumSupport& support(const VolumeGrid& volume) { return volume.support(); }

VolumeInfo describe(const VolumeGrid& volume) {
    VolumeInfo info;
    info.name = volume.grid().getName();
    info.voxelSize = volume.voxelSize();
    info.boundsWS = volume.bounds();
    info.activeVoxels = volume.grid().activeVoxelCount();
    info.maxDensity = volume.maxDensity();
    info.bytes = volume.grid().memUsage();
    return info;
}

VolumeGridPtr fogFromLevelSet(const LevelSet& levelSet, double density, double falloff,
                              const std::string& name) {
    if (!(std::isfinite(density) && density >= 0.0)) {
        throw std::invalid_argument("fogFromLevelSet: density must be finite and >= 0");
    }
    if (!(std::isfinite(falloff) && falloff >= 0.0)) {
        throw std::invalid_argument("fogFromLevelSet: falloff must be finite and >= 0");
    }
    ensureOpenVdbInitialized();
    const double h = levelSet.voxelSize();
    FloatGrid::Ptr grid = levelSet.grid().deepCopy();
    // falloff 0: phi shifted by half a voxel and a one-voxel ramp, i.e. density
    // clamp(1/2 - phi/h, 0, 1): the ramp's middle lies on the surface.
    const float shift = falloff > 0.0 ? 0.0f : float(0.5 * h);
    if (shift != 0.0f) {
        for (auto it = grid->beginValueOn(); it; ++it) it.setValue(*it - shift);
    }
    openvdb::tools::sdfToFogVolume(*grid, float(falloff > 0.0 ? falloff : h));
    // sdfToFogVolume leaves values above 1 deeper than the ramp (when the band is wider).
    const float d = float(density);
    for (auto it = grid->beginValueOn(); it; ++it) it.setValue(std::min(*it, 1.0f) * d);
    grid->setName(name);
    grid->setGridClass(openvdb::GRID_FOG_VOLUME);
    return std::make_shared<const VolumeGrid>(grid);
}

VdbGridKinds vdbGridKinds(const std::string& file, const std::string& where) {
    ensureOpenVdbInitialized();
    std::error_code ec;
    if (!std::filesystem::is_regular_file(file, ec)) {
        throw InputError(file, where, "cannot read VDB file: no such file");
    }
    checkVdbFile(file, where);
    VdbGridKinds kinds;
    try {
        openvdb::io::File vdb(file);
        vdb.open(/*delayLoad=*/true);
        const openvdb::GridPtrVecPtr grids = vdb.readAllGridMetadata();
        vdb.close();
        for (const openvdb::GridBase::Ptr& g : *grids) {
            const bool isFloat = g->isType<FloatGrid>();
            if (isFloat && g->getGridClass() == openvdb::GRID_LEVEL_SET) {
                kinds.levelSets.push_back(g->getName());
            } else if (isFloat && g->getGridClass() == openvdb::GRID_FOG_VOLUME) {
                kinds.volumes.push_back(g->getName());
            } else {
                kinds.others.push_back(g->getName());
            }
        }
    } catch (const InputError&) {
        throw;
    } catch (const std::exception& e) {
        throw InputError(file, where, std::string("cannot read VDB file: ") + e.what());
    }
    return kinds;
}

std::vector<VolumeGridPtr> readVolumes(const std::string& file, const std::string& gridName,
                                       const std::string& where) {
    const VdbGridKinds kinds = vdbGridKinds(file, where);  // checks the file and its header
    openvdb::GridPtrVecPtr grids = std::make_shared<openvdb::GridPtrVec>();
    withVdbErrors(file, where, [&] {
        openvdb::io::File vdb(file);
        vdb.open(/*delayLoad=*/false);
        if (!gridName.empty()) {
            if (!vdb.hasGrid(gridName)) {
                throw InputError(file, where, "no grid named '" + gridName + "'");
            }
            grids->push_back(vdb.readGrid(gridName));
        } else {
            for (const std::string& n : kinds.volumes) grids->push_back(vdb.readGrid(n));
        }
        vdb.close();
    });
    if (grids->empty()) throw InputError(file, where, "no fog volume grid in the file");
    std::vector<VolumeGridPtr> out;
    for (const openvdb::GridBase::Ptr& g : *grids) {
        FloatGrid::Ptr f = openvdb::gridPtrCast<FloatGrid>(g);
        if (!f) {
            throw InputError(file, where,
                             "grid '" + g->getName() + "' holds " + g->valueType() +
                                 " values; a volume's density is a float grid");
        }
        if (f->getGridClass() == openvdb::GRID_LEVEL_SET) {
            throw InputError(file, where, "grid '" + g->getName() + "' is a " +
                                              className(f->getGridClass()) + ", not a density");
        }
        if (!f->transform().isLinear() || !f->hasUniformVoxels()) {
            throw InputError(file, where,
                             "grid '" + g->getName() + "' needs a linear transform with cubic voxels");
        }
        checkDensities(*f, file, where);
        out.push_back(std::make_shared<const VolumeGrid>(f));
    }
    return out;
}

VolumeGridPtr transformVolume(const VolumeGridPtr& volume, const Mat3& rotation, double scale,
                              const Vec3& translate) {
    if (!volume) throw std::invalid_argument("transformVolume: null volume");
    const bool identity = scale == 1.0 && rotation == Mat3(1.0) && translate == Vec3(0.0);
    if (identity) return volume;
    openvdb::math::Transform::Ptr xform = volume->grid().transform().copy();
    xform->postScale(scale);
    openvdb::Mat4d m = openvdb::Mat4d::identity();
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) m(c, r) = rotation[c][r];  // row-vector convention
    xform->postMult(m);
    xform->postTranslate(openvdb::Vec3d(translate.x, translate.y, translate.z));
    return std::make_shared<const VolumeGrid>(openvdb::gridConstPtrCast<FloatGrid>(
        volume->grid().copyGridReplacingTransform(xform)));
}

void writeGrids(const std::string& file, const std::vector<LevelSetPtr>& levelSets,
                const std::vector<std::pair<std::string, VolumeGridPtr>>& volumes, bool halfFloat) {
    ensureOpenVdbInitialized();
    openvdb::GridCPtrVec out;
    auto add = [&](const openvdb::GridBase& g, const std::string* name) {
        openvdb::MetaMap meta(g);
        if (name) meta.insertMeta(openvdb::GridBase::META_GRID_NAME, openvdb::StringMetadata(*name));
        if (halfFloat) meta.insertMeta(openvdb::GridBase::META_SAVE_HALF_FLOAT, openvdb::BoolMetadata(true));
        out.push_back(g.copyGridReplacingMetadata(meta));
    };
    for (const LevelSetPtr& ls : levelSets) add(ls->grid(), nullptr);
    for (const auto& [name, v] : volumes) add(v->grid(), &name);
    writeVdbAtomically(file, out);
}

double sampleDensity(const VolumeGrid& volume, const Vec3& p) {
    auto acc = volume.grid().getConstAccessor();
    return openvdb::tools::BoxSampler::sample(
        acc, volume.grid().worldToIndex(openvdb::Vec3d(p.x, p.y, p.z)));
}

// ---------------------------------------------------------------------------------------------
// VolumeSampler

struct VolumeSampler::Impl {
    explicit Impl(const VolumeGrid& v) : volume(&v), accessor(v.grid().getConstAccessor()) {
        if (v.intersector()) intersector = std::make_unique<VolumeIntersector>(*v.intersector());
    }
    Impl(const Impl& o) : volume(o.volume), accessor(o.volume->grid().getConstAccessor()) {
        if (o.intersector) intersector = std::make_unique<VolumeIntersector>(*volume->intersector());
    }
    const VolumeGrid* volume;
    FloatGrid::ConstAccessor accessor;
    std::unique_ptr<VolumeIntersector> intersector;  // shallow copy of the volume's master
};

VolumeSampler::VolumeSampler(const VolumeGrid& volume) : mImpl(std::make_unique<Impl>(volume)) {}
VolumeSampler::VolumeSampler(const VolumeSampler& other)
    : mImpl(std::make_unique<Impl>(*other.mImpl)) {}
VolumeSampler::~VolumeSampler() = default;

double VolumeSampler::density(const Vec3& p) {
    ++mSamples;
    return sampleTrilinear(
        mImpl->accessor, mImpl->volume->grid().worldToIndex(openvdb::Vec3d(p.x, p.y, p.z)));
}

double VolumeSampler::opticalDepth(const Vec3& from, const Vec3& dir, double t0, double t1) {
    if (!mImpl->intersector || !(t1 > t0)) return 0.0;
    const FloatGrid& grid = mImpl->volume->grid();
    // The index-space ray keeps the world ray's parameter: its direction is the world unit
    // direction mapped to index space (not normalized), so its times are world distances.
    const openvdb::Vec3d eye = grid.worldToIndex(openvdb::Vec3d(from.x, from.y, from.z));
    const openvdb::Vec3d ahead =
        grid.worldToIndex(openvdb::Vec3d(from.x + dir.x, from.y + dir.y, from.z + dir.z));
    const IndexRay ray(eye, ahead - eye, std::max(t0, 1e-12), t1);
    VolumeIntersector& inter = *mImpl->intersector;
    if (!inter.setIndexRay(ray)) return 0.0;
    const double step = 0.5 * mImpl->volume->voxelSize();
    double sum = 0.0, a = 0.0, b = 0.0;
    while (inter.march(a, b)) {
        a = std::max(a, t0);
        b = std::min(b, t1);
        if (!(b > a)) continue;
        const int n = std::max(1, int(std::ceil((b - a) / step)));
        const double h = (b - a) / n;
        double s = 0.0;
        for (int i = 0; i < n; ++i) {
            const double t = a + (i + 0.5) * h;
            s += sampleTrilinear(mImpl->accessor, eye + (ahead - eye) * t);
        }
        mSamples += uint64_t(n);
        sum += s * h;
    }
    return sum;
}

}  // namespace penumbra
