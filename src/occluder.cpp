#include "penumbra/occluder.h"

#include <openvdb/math/Ray.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/RayIntersector.h>

#include <algorithm>
#include <cassert>
#include <cmath>
#include <limits>
#include <mutex>
#include <stdexcept>

#include "cell_distance.h"
#include "level_set_impl.h"
#include "level_set_search.h"
#include "parallel_for.h"

namespace penumbra {

namespace {

// OpenVDB's hierarchical DDA over the level set, with a cell test that catches rays dipping
// below zero between its samples (level_set_search.h).
using Intersector = openvdb::tools::LevelSetRayIntersector<openvdb::FloatGrid, CellSearch>;

constexpr double kFarVoxelFactor = kFarFieldFactor;  // companion voxels, in fine voxels
constexpr float kFarBand = kFarFieldBand;            // companion band, in companion voxels
using VdbRay = openvdb::math::Ray<double>;

/// Per-thread state for one level-set obstacle. Copying gives a new accessor (registered with
/// the tree on its own), which is what a second thread needs.
struct LevelSetSlot {
    explicit LevelSetSlot(const openvdb::FloatGrid& g)
        : intersector(g), accessor(g.getConstAccessor()), grid(&g) {}
    LevelSetSlot(const LevelSetSlot& o)
        : intersector(o.intersector), accessor(o.accessor), grid(o.grid) {}

    Intersector intersector;
    openvdb::FloatGrid::ConstAccessor accessor;  // for the "starts inside" test and clearance
    const openvdb::FloatGrid* grid;
    // The far-field companion's accessor, made on first use by this thread.
    const openvdb::FloatGrid* farGrid = nullptr;
    std::unique_ptr<openvdb::FloatGrid::ConstAccessor> farAccessor;
};

/// End points are excluded from the segment by this much (relative to the segment length, with
/// an absolute floor), so that a ray leaving a surface it starts on is not blocked by it.
double segmentEpsilon(double length) { return 1e-9 * std::max(1.0, length); }

/// Overlap of the chord [tA, tB] of a convex shape with the open interval (tMin, tMax); the
/// reported distance is 0 when the segment starts inside the shape.
bool chordOverlaps(double tA, double tB, double tMin, double tMax, double* t) {
    if (!(tA < tMax && tB > tMin)) return false;
    *t = tA > 0.0 ? tA : 0.0;
    return true;
}

/// Exact ray-sphere test; `dir` is a unit vector.
bool hitSphere(const AnalyticSphere& s, const Vec3& from, const Vec3& dir, double tMin, double tMax,
               double* t) {
    const Vec3 oc = from - s.center;
    const double b = glm::dot(oc, dir);
    // Discriminant from the perpendicular distance to the centre, which keeps its precision
    // for far-away spheres (b*b - c cancels).
    const Vec3 perp = oc - b * dir;
    const double disc = s.radius * s.radius - glm::dot(perp, perp);
    if (disc < 0.0) return false;
    const double c = glm::dot(oc, oc) - s.radius * s.radius;
    // Roots of t^2 + 2bt + c = 0 without subtracting nearly equal numbers.
    const double q = -(b + std::copysign(std::sqrt(disc), b));
    double tA = q, tB = q != 0.0 ? c / q : 0.0;
    if (tA > tB) std::swap(tA, tB);
    return chordOverlaps(tA, tB, tMin, tMax, t);
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Far-field distance

namespace {

/// How far the companion's values stray from the fine grid's, region by region. The companion
/// is a distance to a coarser surface, and a fine surface point x, where the fine distance is
/// 0, has a companion value of at most its error e(x) there. The companion changes no faster
/// than the distance, so from p, x is at least vc(p) - e(x) away, and at least as far as the
/// block of voxels holding x. The fine surface's distance from p is the smallest over its
/// points: phi(p) >= min over blocks B of max(dist(p, B), vc(p) - e_B), e_B the largest error
/// measured in B. Near the surface this is the error of the surface's part nearest p: the worst
/// place of a shape (a bunny's thin ears, which the companion loses) no longer shrinks every
/// distance around the rest of it. (Until 2026-12-01 the worst error over the whole grid.)
///
/// Blocks are laid out in the fine grid's index space (its transform may rotate); reaches and
/// block edges are in fine voxels. Each block keeps, for each k up to kReach, the largest error
/// within k blocks of it; blocks k away lie at least k - 1 block edges from any point of it.
class CompanionError {
public:
    static constexpr int kReach = 12;

    /// `worst` is the global bound; `block` the blocks' edge in fine voxels; `lo` (index space)
    /// and `dims` the blocks' grid, `raw` the largest error measured in each.
    CompanionError(double worst, int block, const openvdb::Vec3d& lo, const openvdb::Coord& dims,
                   const std::vector<float>& raw)
        : mWorst(worst), mBlock(block), mLo(lo), mDims(dims), mMax(raw.size() * (kReach + 1)) {
        // Each reach is the previous one grown by a block along every axis (a box max filter).
        std::vector<float> cur = raw;
        for (int k = 0; k <= kReach; ++k) {
            if (k > 0) {
                for (int axis = 0; axis < 3; ++axis) {
                    std::vector<float> next = cur;
                    forEachBlock([&](const openvdb::Coord& c) {
                        for (int d : {-1, 1}) {
                            openvdb::Coord q = c;
                            q[axis] += d;
                            if (q[axis] >= 0 && q[axis] < dims[axis])
                                next[index(c)] = std::max(next[index(c)], cur[index(q)]);
                        }
                    });
                    cur = std::move(next);
                }
            }
            for (size_t i = 0; i < cur.size(); ++i) mMax[i * (kReach + 1) + k] = cur[i];
        }
    }

    double worst() const { return mWorst; }

    /// At the fine index-space point p, where the companion's value is vc and the nearest
    /// surface point lies within `reach` fine voxels (`voxel` converts them to world units):
    /// `error`, the largest companion error that near, and `lower`, a lower bound on the fine
    /// surface's signed distance.
    struct Local {
        double error, lower;
    };
    Local at(const openvdb::Vec3d& p, double vc, double reach, double voxel) const {
        size_t i;
        if (!(reach <= double(kReach * mBlock)) || !blockOf(p, i)) return {mWorst, vc - mWorst};
        const int k = int(std::ceil(reach / mBlock));
        const float* m = &mMax[i * (kReach + 1)];
        const double error = double(m[k]);
        // Inside, the bound is the companion's value less the largest error within the reach.
        if (!(vc > 0.0)) return {error, vc - error};
        // Blocks up to one away may touch p; those r away lie (r - 1) edges off, less the
        // voxel around a block over which its surface points' errors were measured.
        double lo = vc - double(m[std::min(k, 1)]);
        for (int r = 2; r <= k; ++r)
            lo = std::min(lo, std::max(((r - 1) * mBlock - 1) * voxel, vc - double(m[r])));
        return {error, lo};
    }

private:
    bool blockOf(const openvdb::Vec3d& p, size_t& i) const {
        int c[3];
        for (int a = 0; a < 3; ++a) {
            const double f = std::floor((p[a] - mLo[a]) / mBlock);
            if (!(f >= 0.0 && f < double(mDims[a]))) return false;
            c[a] = int(f);
        }
        i = index(openvdb::Coord(c[0], c[1], c[2]));
        return true;
    }
    size_t index(const openvdb::Coord& c) const {
        return (size_t(c.z()) * size_t(mDims.y()) + size_t(c.y())) * size_t(mDims.x()) +
               size_t(c.x());
    }
    template <class F>
    void forEachBlock(F&& f) const {
        for (int z = 0; z < mDims.z(); ++z)
            for (int y = 0; y < mDims.y(); ++y)
                for (int x = 0; x < mDims.x(); ++x) f(openvdb::Coord(x, y, z));
    }

    double mWorst;
    int mBlock;
    openvdb::Vec3d mLo;
    openvdb::Coord mDims;
    std::vector<float> mMax;  // per block, the largest error within k = 0..kReach blocks
};

}  // namespace

struct Occluder::FarField {
    explicit FarField(LevelSetPtr ls) : levelSet(std::move(ls)) {}
    const openvdb::FloatGrid& get() const { return levelSet->farField(kFarVoxelFactor, kFarBand); }

    /// How far the companion's values may stray from the fine grid's near the surface,
    /// measured once at every active fine voxel (plus half a fine voxel for the points between
    /// them), globally and block by block (CompanionError): certificates shrink companion
    /// distances by it. A feature thinner than a coarse voxel, which the companion loses, shows
    /// up here as a large error, and certificates near it then prove less rather than
    /// something false.
    const CompanionError& error() const {
        std::call_once(errorOnce, [&] {
            const openvdb::FloatGrid& fine = levelSet->grid();
            const openvdb::FloatGrid& coarse = get();
            const double hf = fine.voxelSize()[0];
            // Blocks of 4 fine voxels (one companion voxel), coarser for grids so large that
            // more than 64 of them would be needed along an axis.
            const openvdb::CoordBBox active = fine.evalActiveVoxelBoundingBox();
            const openvdb::Coord extent = active.empty() ? openvdb::Coord(1) : active.dim();
            int blockVoxels = 4;
            while (extent.x() / blockVoxels + 1 > 64 || extent.y() / blockVoxels + 1 > 64 ||
                   extent.z() / blockVoxels + 1 > 64)
                blockVoxels *= 2;
            const openvdb::Coord dims(extent.x() / blockVoxels + 1, extent.y() / blockVoxels + 1,
                                      extent.z() / blockVoxels + 1);
            const openvdb::Coord origin = active.empty() ? openvdb::Coord(0) : active.min();
            std::vector<float> raw(size_t(dims.x()) * dims.y() * dims.z(), 0.0f);
            auto acc = coarse.getConstAccessor();
            double worst = 0.0;
            for (auto it = fine.cbeginValueOn(); it; ++it) {
                const openvdb::Coord ijk = it.getCoord();
                const openvdb::Vec3d w = fine.indexToWorld(ijk);
                const double vc = sampleTrilinear(acc, coarse.worldToIndex(w));
                const double e = std::abs(vc - double(*it)) + 0.5 * hf;
                worst = std::max(worst, e);
                const openvdb::Coord b = (ijk - origin);
                const size_t i = (size_t(b.z() / blockVoxels) * dims.y() + b.y() / blockVoxels) *
                                     dims.x() + b.x() / blockVoxels;
                raw[i] = std::max(raw[i], float(e));
            }
            // Blocks start half a voxel before their first voxel's centre; a block's value is
            // rounded up to the float above it.
            for (float& e : raw) e = e > 0.0f ? std::nextafter(e, 1e30f) : 0.0f;
            errorValue = std::make_unique<CompanionError>(
                worst, blockVoxels, origin.asVec3d() - openvdb::Vec3d(0.5), dims, raw);
        });
        return *errorValue;
    }

    /// The level set's cell tables (LevelSet::cellTables), or null.
    const CellTables* cells() const { return levelSet->cellTables(); }

    /// Balls wholly inside the fine surface, from the companion (Occluder::kernelBalls): at a
    /// companion voxel of value vc < 0 the fine surface's signed distance is at most vc plus the
    /// companion's error (the certificates' own bound, levelSetRadius), so a ball of radius
    /// -vc - worst() there lies inside. Greedy: the deepest first, then each next deepest whose
    /// own ball is not mostly inside one already kept (its centre farther than its radius less
    /// half of it from there), at most kKernelBalls, none under a quarter of the deepest's radius
    /// nor under two fine voxels; each checked inside against the fine grid too. Then each is
    /// widened from the fine grid's own values (LevelSet::widenInsideBalls: moved towards the
    /// deepest point near it, its radius the distance to the nearest cell where the interpolant
    /// may reach zero), and balls that met at one deepest point are kept once.
    const std::vector<Occluder::KernelBall>& balls() const {
        std::call_once(ballsOnce, [&] {
            const openvdb::FloatGrid& coarse = get();
            const double worst = error().worst();
            const double bandC = 0.98 * double(coarse.background());
            const double hf = levelSet->grid().voxelSize()[0];
            std::vector<Occluder::KernelBall> candidates;
            for (auto it = coarse.cbeginValueOn(); it; ++it) {
                const double depth = std::min(-double(*it), bandC) - worst;
                if (!(depth > 2.0 * hf)) continue;
                const openvdb::Vec3d w = coarse.indexToWorld(it.getCoord());
                candidates.push_back({Vec3(w.x(), w.y(), w.z()), depth * (1.0 - 1e-6)});
            }
            auto deeper = [](const Occluder::KernelBall& a, const Occluder::KernelBall& b) {
                return a.radius > b.radius;
            };
            std::stable_sort(candidates.begin(), candidates.end(), deeper);
            // The fine grid must agree that the ball is inside, at its centre and at six points
            // nine tenths of the way to its surface: a companion meshed from a surface that is
            // not closed could call some outside region inside, and a ball there would hide
            // light points no ray is blocked towards.
            const openvdb::FloatGrid& fine = levelSet->grid();
            auto fineAcc = fine.getConstAccessor();
            auto inside = [&](const Vec3& p) {
                const openvdb::Coord ijk =
                    fine.transform().worldToIndexNodeCentered(openvdb::Vec3d(p.x, p.y, p.z));
                return fineAcc.getValue(ijk) < 0.0f;
            };
            for (const Occluder::KernelBall& c : candidates) {
                if (ballsValue.size() >= size_t(kKernelBalls) ||
                    (!ballsValue.empty() && c.radius < 0.25 * ballsValue.front().radius))
                    break;
                bool novel = true;
                for (const Occluder::KernelBall& b : ballsValue)
                    if (glm::length(c.centre - b.centre) + 0.5 * c.radius <= b.radius) novel = false;
                if (!novel || !inside(c.centre)) continue;
                bool agreed = true;
                for (int axis = 0; axis < 3 && agreed; ++axis)
                    for (double side : {-0.9, 0.9}) {
                        Vec3 p = c.centre;
                        p[axis] += side * c.radius;
                        agreed = agreed && inside(p);
                    }
                if (agreed) ballsValue.push_back(c);
            }
            // Each kept ball moved to the deepest point near it and given the radius the fine
            // grid's own values prove (the companion's voxels are four fine ones, and its error
            // comes off: a level-set sphere's ball was three voxels short of the sphere).
            std::vector<LevelSet::InsideBall> in;
            for (const Occluder::KernelBall& b : ballsValue) in.push_back({b.centre, b.radius});
            std::vector<Occluder::KernelBall> widened;
            for (const LevelSet::InsideBall& b : levelSet->widenInsideBalls(in))
                if (b.radius > 2.0 * hf) widened.push_back({b.centre, b.radius});
            std::stable_sort(widened.begin(), widened.end(), deeper);
            ballsValue = std::move(widened);
        });
        return ballsValue;
    }

    /// Points deep inside the fine surface, spread over the obstacle (Occluder::deepPoints):
    /// the fine grid's active voxel of least value, then, among the voxels at least half as
    /// deep, each next the one farthest from those already kept (up to kDeepPoints), so that a
    /// thin obstacle's ends are among them.
    const std::vector<Occluder::KernelBall>& deep() const {
        std::call_once(deepestOnce, [&] {
            const openvdb::FloatGrid& fine = levelSet->grid();
            float least = std::numeric_limits<float>::infinity();
            for (auto it = fine.cbeginValueOn(); it; ++it) least = std::min(least, *it);
            if (!(least < 0.0f)) return;
            std::vector<Occluder::KernelBall> deepVoxels;
            for (auto it = fine.cbeginValueOn(); it; ++it) {
                if (!(*it <= 0.5f * least)) continue;
                const openvdb::Vec3d w = fine.indexToWorld(it.getCoord());
                deepVoxels.push_back({Vec3(w.x(), w.y(), w.z()), -double(*it)});
            }
            // The deepest first (the first of least value in the grid's order), then farthest
            // point sampling: gap[k] is voxel k's distance to the nearest point kept.
            size_t next = 0;
            for (size_t k = 0; k < deepVoxels.size(); ++k)
                if (deepVoxels[k].radius > deepVoxels[next].radius) next = k;
            std::vector<double> gap(deepVoxels.size(), std::numeric_limits<double>::infinity());
            const double voxel = fine.voxelSize()[0];
            while (deepValue.size() < size_t(Occluder::kDeepPoints)) {
                const Occluder::KernelBall kept = deepVoxels[next];
                deepValue.push_back(kept);
                double far = 0.0;
                for (size_t k = 0; k < deepVoxels.size(); ++k) {
                    gap[k] = std::min(gap[k], glm::length(deepVoxels[k].centre - kept.centre));
                    if (gap[k] > far) far = gap[k], next = k;
                }
                // Nothing left farther than the obstacle's depth (two voxels at least) from them.
                if (!(far > std::max(deepValue.front().radius, 2.0 * voxel))) break;
            }
        });
        return deepValue;
    }

    LevelSetPtr levelSet;
    mutable std::once_flag deepestOnce;
    mutable std::vector<Occluder::KernelBall> deepValue;
    mutable std::once_flag errorOnce;
    mutable std::unique_ptr<CompanionError> errorValue;
    mutable std::once_flag ballsOnce;
    mutable std::vector<Occluder::KernelBall> ballsValue;
};

const std::vector<Occluder::KernelBall>& Occluder::kernelBalls(size_t i) const {
    if (mFar[i]) return mFar[i]->balls();
    return mSphereKernels[i];
}

const std::vector<Occluder::KernelBall>& Occluder::deepPoints(size_t i) const {
    static const std::vector<KernelBall> none;
    return mFar[i] ? mFar[i]->deep() : none;
}

Box3 Occluder::kernelBox(size_t i) const {
    if (const auto* x = std::get_if<AnalyticBox>(&mShapes[i])) {
        Box3 b;
        b.lo = x->lo;
        b.hi = x->hi;
        return b;
    }
    return Box3{};
}

// ---------------------------------------------------------------------------------------------
// Occluder

Occluder::Occluder(std::vector<ObstacleShape> shapes) {
    for (ObstacleShape& s : shapes) add(std::move(s));
}

void Occluder::add(ObstacleShape shape) {
    Box3 b;
    Solid solid;
    double voxel = 0.0;
    if (const auto* s = std::get_if<AnalyticSphere>(&shape)) {
        b.lo = s->center - Vec3(s->radius);
        b.hi = s->center + Vec3(s->radius);
        solid = {b, s->center, s->radius, {}, {}};
    } else if (const auto* x = std::get_if<AnalyticBox>(&shape)) {
        b.lo = x->lo;
        b.hi = x->hi;
        solid = {b, 0.5 * (b.lo + b.hi), 0.5 * glm::length(b.hi - b.lo), {}, {}};
    } else {
        const LevelSetPtr& ls = std::get<LevelSetPtr>(shape);
        if (!ls) throw std::invalid_argument("Occluder::add: null level set");
        b = ls->boundsWS();
        if (!b.empty()) {
            // A voxel of margin: the interpolated zero crossing may sit just outside the cells
            // of the active voxels, and the ray marcher must start before it.
            b.lo -= Vec3(ls->voxelSize());
            b.hi += Vec3(ls->voxelSize());
        }
        voxel = ls->voxelSize();
        mMinVoxel = mMinVoxel == 0.0 ? voxel : std::min(mMinVoxel, voxel);
        solid = {ls->solidBoundsWS(), ls->solidCentreWS(), ls->solidRadius(), ls->solidPartsWS(),
                 ls->solidOrientedWS()};
        if (b.empty()) solid = {b, Vec3(0.0), 0.0, {}, {}};
    }
    // Analytic shapes, and level sets with no oriented box: the solid box itself.
    if (solid.oriented.empty()) solid.oriented = OrientedBox::of(solid.box);
    mSphereKernels.emplace_back();
    if (const auto* s = std::get_if<AnalyticSphere>(&shape)) mSphereKernels.back().push_back({s->center, s->radius});
    mShapes.push_back(std::move(shape));
    mBounds.push_back(b);
    mSolid.push_back(solid);
    mVoxel.push_back(voxel);
    const auto* ls = std::get_if<LevelSetPtr>(&mShapes.back());
    mFar.push_back(ls && *ls ? std::make_shared<FarField>(*ls) : nullptr);
}

void Occluder::addMedium(Medium medium) {
    if (!medium.grid) throw std::invalid_argument("Occluder::addMedium: null grid");
    const VolumeInfo info = describe(*medium.grid);
    Box3 b;
    if (info.maxDensity > 0.0 && medium.extinction > 0.0) b = info.boundsWS;
    mMedia.push_back(std::move(medium));
    mMediumBounds.push_back(b);
}

Occluder::Query Occluder::makeQuery() const { return Query(*this); }

void Occluder::prepareClearance() const {
    // Every level set's two builds side by side: its companion (then the companion's error,
    // measured on one thread) and its cell tables, which need only the fine grid. One after the
    // other they kept a second core mostly idle (OpenVDB's meshing and the error's measurement
    // run largely on one thread); each build isolates its own parallel loops.
    std::vector<const FarField*> fars;
    for (const auto& far : mFar)
        if (far) fars.push_back(far.get());
    detail::parallelFor(tbb::blocked_range<size_t>(0, 2 * fars.size(), 1),
                        [&](const tbb::blocked_range<size_t>& r) {
                            for (size_t i = r.begin(); i < r.end(); ++i) {
                                if (i % 2 == 0) {
                                    fars[i / 2]->error();  // builds the companion too
                                } else {
                                    fars[i / 2]->cells();
                                }
                            }
                        });
}

// ---------------------------------------------------------------------------------------------
// Occluder::Query

struct Occluder::Query::Impl {
    /// Index-aligned with the occluder's shapes; null for analytic shapes and empty grids.
    std::vector<std::unique_ptr<LevelSetSlot>> levelSets;
    /// Index-aligned with the occluder's media.
    std::vector<std::unique_ptr<VolumeSampler>> media;
    /// trace()'s visiting order when a clearance is wanted: (lower bound on the obstacle's
    /// distance from the segment, obstacle index), nearest first.
    std::vector<std::pair<double, uint32_t>> order;
};

Occluder::Query::Query(const Occluder& occluder)
    : mOccluder(&occluder), mImpl(std::make_unique<Impl>()) {
    mImpl->levelSets.resize(occluder.size());
    for (size_t i = 0; i < occluder.size(); ++i) {
        const auto* ls = std::get_if<LevelSetPtr>(&occluder.shape(i));
        // The intersector refuses empty grids; an empty grid cannot occlude anyway.
        if (ls && !occluder.bounds(i).empty()) {
            mImpl->levelSets[i] = std::make_unique<LevelSetSlot>((*ls)->grid());
        }
    }
    for (size_t i = 0; i < occluder.mediumCount(); ++i) {
        mImpl->media.push_back(std::make_unique<VolumeSampler>(*occluder.medium(i).grid));
    }
}

Occluder::Query::Query(const Query& other)
    : mOccluder(other.mOccluder),
      mImpl(std::make_unique<Impl>()),
      mCandidates(other.mCandidates),
      mRays(other.mRays) {
    // Copies, not shares: each copy of an intersector owns a fresh value accessor, and copying
    // skips the bounding-box scan that constructing one does.
    mImpl->levelSets.resize(other.mImpl->levelSets.size());
    for (size_t i = 0; i < other.mImpl->levelSets.size(); ++i) {
        if (const auto& slot = other.mImpl->levelSets[i]) {
            mImpl->levelSets[i] = std::make_unique<LevelSetSlot>(*slot);
        }
    }
    for (const auto& m : other.mImpl->media) mImpl->media.push_back(std::make_unique<VolumeSampler>(*m));
}

Occluder::Query::Query(Query&&) noexcept = default;
Occluder::Query::~Query() = default;

bool Occluder::Query::occluded(const Vec3& from, const Vec3& to, double* tHit) {
    return occluded(from, to, tHit, nullptr);
}

double Occluder::Query::transmittance(const Vec3& from, const Vec3& to) {
    const Vec3 delta = to - from;
    const double length = glm::length(delta);
    if (!(length > 0.0)) return 1.0;
    const Vec3 dir = delta / length;
    const Vec3 invDir = 1.0 / dir;
    double depth = 0.0;
    bool marched = false;
    const size_t count = mMedia ? mMedia->size() : mOccluder->mediumCount();
    for (size_t k = 0; k < count; ++k) {
        const size_t i = mMedia ? (*mMedia)[k] : k;
        const Box3& b = mOccluder->mediumBounds(i);
        if (b.empty()) continue;
        double t0 = 0.0, t1 = length;
        if (!b.clipRay(from, invDir, t0, t1)) continue;
        marched = true;
        depth += mOccluder->medium(i).extinction * mImpl->media[i]->opticalDepth(from, dir, t0, t1);
    }
    if (marched) ++mRays;
    return depth > 0.0 ? std::exp(-depth) : 1.0;
}

double Occluder::Query::transmitted(const Vec3& from, const Vec3& to) {
    if (occluded(from, to)) return 0.0;  // counts the ray
    const uint64_t rays = mRays;
    const double t = transmittance(from, to);
    mRays = rays;  // the same segment: one ray
    return t;
}

double Occluder::Query::extinctionAt(const Vec3& p, Rgb* scattering) {
    double sigma = 0.0;
    if (scattering) *scattering = Rgb(0.0);
    const size_t count = mMedia ? mMedia->size() : mOccluder->mediumCount();
    for (size_t k = 0; k < count; ++k) {
        const size_t i = mMedia ? (*mMedia)[k] : k;
        const Box3& b = mOccluder->mediumBounds(i);
        if (b.empty() || p.x < b.lo.x || p.y < b.lo.y || p.z < b.lo.z || p.x > b.hi.x ||
            p.y > b.hi.y || p.z > b.hi.z)
            continue;
        const Medium& m = mOccluder->medium(i);
        const double s = m.extinction * mImpl->media[i]->density(p);
        sigma += s;
        if (scattering) *scattering += m.albedo * s;
    }
    return sigma;
}

Box3 Occluder::Query::mediaBounds() const {
    Box3 out;
    const size_t count = mMedia ? mMedia->size() : mOccluder->mediumCount();
    for (size_t k = 0; k < count; ++k) {
        const Box3& b = mOccluder->mediumBounds(mMedia ? (*mMedia)[k] : k);
        if (b.empty()) continue;
        out.extend(b.lo);
        out.extend(b.hi);
    }
    return out;
}

double Occluder::Query::opticalDepthBound(const Pyramid& pyramid, double* featureLength) const {
    double depth = 0.0;
    if (featureLength) *featureLength = std::numeric_limits<double>::infinity();
    const size_t count = mMedia ? mMedia->size() : mOccluder->mediumCount();
    for (size_t k = 0; k < count; ++k) {
        const size_t i = mMedia ? (*mMedia)[k] : k;
        const Box3& b = mOccluder->mediumBounds(i);
        if (b.empty() || !pyramid.mayMeet(b)) continue;
        const Medium& m = mOccluder->medium(i);
        const MediumSupport& s = support(*m.grid);
        // The sum over the parts the pyramid meets, at most the whole medium's longest chord
        // at its largest density.
        double sum = 0.0;
        for (const MediumSupport::Block& block : s.blocks) {
            if (!pyramid.mayMeet(block.box)) continue;
            for (uint32_t p = block.first; p < block.first + block.count; ++p) {
                const MediumSupport::Part& part = s.parts[p];
                if (pyramid.mayMeetExactly(part.box))
                    sum += part.maxDensity * glm::length(part.box.hi - part.box.lo);
            }
        }
        if (sum > 0.0) {
            depth += m.extinction * std::min(sum, s.maxDensity * glm::length(b.hi - b.lo));
            if (featureLength) *featureLength = std::min(*featureLength, s.featureLength);
        }
    }
    return depth;
}

double Occluder::Query::featureLength(const Pyramid& pyramid) const {
    double feature = std::numeric_limits<double>::infinity();
    const size_t count = mMedia ? mMedia->size() : mOccluder->mediumCount();
    for (size_t k = 0; k < count; ++k) {
        const size_t i = mMedia ? (*mMedia)[k] : k;
        const Box3& b = mOccluder->mediumBounds(i);
        if (b.empty() || !pyramid.mayMeet(b)) continue;
        feature = std::min(feature, support(*mOccluder->medium(i).grid).featureLength);
    }
    return feature;
}

std::vector<Box3> Occluder::Query::mediumBoxes() const {
    std::vector<Box3> out;
    const size_t count = mMedia ? mMedia->size() : mOccluder->mediumCount();
    for (size_t k = 0; k < count; ++k) {
        const Box3& b = mOccluder->mediumBounds(mMedia ? (*mMedia)[k] : k);
        if (!b.empty()) out.push_back(b);
    }
    return out;
}

bool Occluder::Query::mediaBetween(const Box3& origin, const Box3& target) const {
    Box3 hull = origin;
    hull.extend(target.lo);
    hull.extend(target.hi);
    const size_t count = mMedia ? mMedia->size() : mOccluder->mediumCount();
    for (size_t k = 0; k < count; ++k) {
        const Box3& b = mOccluder->mediumBounds(mMedia ? (*mMedia)[k] : k);
        if (b.empty()) continue;
        if (b.lo.x <= hull.hi.x && b.hi.x >= hull.lo.x && b.lo.y <= hull.hi.y &&
            b.hi.y >= hull.lo.y && b.lo.z <= hull.hi.z && b.hi.z >= hull.lo.z)
            return true;
    }
    return false;
}

namespace {

/// Signed distance between the segment from + t dir, t in [t0, t1], and a sphere's surface.
Clearance sphereClearance(const AnalyticSphere& s, const Vec3& from, const Vec3& dir, double t0,
                          double t1) {
    Clearance c;
    c.at = std::clamp(glm::dot(s.center - from, dir), t0, t1);
    const Vec3 away = from + c.at * dir - s.center;
    const double r = glm::length(away);
    c.distance = r - s.radius;
    if (r > 0.0) c.normal = away / r;
    return c;
}

/// An axis-aligned box by its centre and half extents, as the distance below reads it (the
/// searches along a segment compute these once, not at every step).
struct BoxFrame {
    Vec3 c, h;
    explicit BoxFrame(const AnalyticBox& b) : c(0.5 * (b.lo + b.hi)), h(0.5 * (b.hi - b.lo)) {}
};

/// Signed distance from p to an axis-aligned box, and its unit gradient.
double boxDistance(const BoxFrame& box, const Vec3& p, Vec3* gradient) {
    const Vec3& c = box.c;
    const Vec3& h = box.h;
    const Vec3 rel = p - c;
    const Vec3 q = glm::abs(rel) - h;
    const Vec3 sign(rel.x < 0.0 ? -1.0 : 1.0, rel.y < 0.0 ? -1.0 : 1.0, rel.z < 0.0 ? -1.0 : 1.0);
    const Vec3 outside = glm::max(q, Vec3(0.0));
    const double lo = glm::length(outside);
    if (lo > 0.0) {
        if (gradient) *gradient = sign * outside / lo;
        return lo;
    }
    int k = q.x > q.y ? (q.x > q.z ? 0 : 2) : (q.y > q.z ? 1 : 2);
    if (gradient) {
        *gradient = Vec3(0.0);
        (*gradient)[k] = sign[k];
    }
    return q[k];
}

/// Calls piece(lo, hi, alpha, beta, out) for each piece [lo, hi] of [t0, t1] on which the line
/// m + t v stays on one side of each of the box's face planes and slab middle planes. There each
/// axis's term sign_i (m_i + t v_i - c_i) - h_i is alpha_i + beta_i t, and out[i] says whether it
/// is positive: the box's signed distance is the norm of the positive terms outside the box and
/// the largest term inside (boxDistance).
template <class F>
void forBoxPieces(const BoxFrame& box, const Vec3& m, const Vec3& v, double t0, double t1,
                  F&& piece) {
    const Vec3& c = box.c;
    const Vec3& h = box.h;
    double cuts[10];
    int n = 0;
    for (int i = 0; i < 3; ++i) {
        if (v[i] == 0.0) continue;
        for (double plane : {c[i] - h[i], c[i], c[i] + h[i]}) {
            const double t = (plane - m[i]) / v[i];
            if (t > t0 && t < t1) cuts[n++] = t;
        }
    }
    cuts[n++] = t1;
    std::sort(cuts, cuts + n);
    double lo = t0;
    for (int k = 0; k < n; ++k) {
        const double hi = cuts[k];
        if (!(hi > lo)) continue;
        const double mid = 0.5 * (lo + hi);
        double alpha[3], beta[3];
        bool out[3];
        for (int i = 0; i < 3; ++i) {
            const double sign = m[i] + mid * v[i] - c[i] < 0.0 ? -1.0 : 1.0;
            alpha[i] = sign * (m[i] - c[i]) - h[i];
            beta[i] = sign * v[i];
            out[i] = alpha[i] + beta[i] * mid > 0.0;
        }
        piece(lo, hi, alpha, beta, out);
        lo = hi;
    }
}

/// Inside the box, where the distance is the largest of the terms, t where two of them cross
/// within (lo, hi): with the piece's ends, where t -> phi or phi / t can be smallest.
template <class F>
void forTermCrossings(double lo, double hi, const double alpha[3], const double beta[3], F&& f) {
    for (int i = 0; i < 3; ++i)
        for (int j = i + 1; j < 3; ++j) {
            if (beta[i] == beta[j]) continue;
            const double t = (alpha[j] - alpha[i]) / (beta[i] - beta[j]);
            if (t > lo && t < hi) f(t);
        }
}

/// Signed distance between the segment from + t dir, t in [t0, t1], and a box's surface, in
/// closed form piece by piece (forBoxPieces): outside, phi^2 is a quadratic in t, smallest at
/// its vertex or a piece's end; inside, phi is smallest at a piece's end or where two terms
/// cross. (A golden-section search of 60 distance evaluations until 2026-11-29.)
Clearance boxClearance(const AnalyticBox& box, const Vec3& from, const Vec3& dir, double t0,
                       double t1) {
    const BoxFrame b(box);
    double bestT = t0, best = boxDistance(b, from + t0 * dir, nullptr);
    auto consider = [&](double t) {
        const double d = boxDistance(b, from + t * dir, nullptr);
        if (d < best) {
            best = d;
            bestT = t;
        }
    };
    consider(t1);
    forBoxPieces(b, from, dir, t0, t1,
                 [&](double lo, double hi, const double* alpha, const double* beta, const bool* out) {
                     if (out[0] || out[1] || out[2]) {
                         double qa = 0.0, qb = 0.0;
                         for (int i = 0; i < 3; ++i) {
                             if (!out[i]) continue;
                             qa += beta[i] * beta[i];
                             qb += 2.0 * alpha[i] * beta[i];
                         }
                         if (qa > 0.0) consider(std::clamp(-qb / (2.0 * qa), lo, hi));
                     } else {
                         consider(lo);
                         forTermCrossings(lo, hi, alpha, beta, consider);
                     }
                 });
    Clearance c;
    c.at = bestT;
    c.distance = boxDistance(b, from + c.at * dir, &c.normal);
    return c;
}

/// Unit gradient of `grid` at a world-space point by central differences one voxel apart (zero
/// where the values are flat, e.g. beyond the band).
template <typename Accessor>
Vec3 gradientAt(const openvdb::FloatGrid& grid, Accessor& acc, const Vec3& p) {
    const double h = grid.voxelSize()[0];
    auto phi = [&](const Vec3& q) {
        return double(sampleTrilinear(
            acc, grid.worldToIndex(openvdb::Vec3d(q.x, q.y, q.z))));
    };
    return unitGradient(phi, p, h);
}

/// Smallest value of `grid` along the segment from + t dir, t in [t0, t1], by sphere tracing
/// (steps of 0.8 |phi|, at least half a voxel). The stretch where phi only grows from the start
/// is skipped (a ray leaving the surface it starts on); the march stops once it climbs out past
/// the deepest point inside. With `polish`, the smallest sample is then refined by a
/// golden-section search between its two neighbouring samples: past a sharp edge phi along the
/// ray is V-shaped, and the best of samples half a voxel apart sits up to a quarter voxel of
/// slope above its bottom, which put the clearance's zero outside the surface the intersector
/// hits (a box level set's shadow came out up to 2.6% of the light too bright in the tangent
/// mode). Without `normal` the gradient at the closest point is left for the caller.
template <typename Accessor>
Clearance traceMinimum(const openvdb::FloatGrid& grid, Accessor& acc, const Vec3& from,
                       const Vec3& dir, double t0, double t1, bool polish = false,
                       bool normal = true) {
    const double voxel = grid.voxelSize()[0];
    auto phiAt = [&](double t) {
        const Vec3 p = from + t * dir;
        return double(sampleTrilinear(
            acc, grid.worldToIndex(openvdb::Vec3d(p.x, p.y, p.z))));
    };
    Clearance c;
    double minPhi = std::numeric_limits<double>::infinity(), prev = -minPhi;
    double before = t0, after = t1, last = t0;  // the samples around the smallest
    bool leaving = true, afterKnown = false;
    for (double t = t0; t <= t1;) {
        const double phi = phiAt(t);
        leaving = leaving && phi >= prev && phi > 0.0;
        prev = phi;
        if (!leaving && phi < minPhi) {
            minPhi = phi;
            c.at = t;
            before = last;
            afterKnown = false;
        } else if (!afterKnown && std::isfinite(minPhi)) {
            after = t;
            afterKnown = true;
        }
        last = t;
        if (minPhi < 0.0 && phi > minPhi + voxel) break;
        t += std::max(0.8 * std::abs(phi), 0.5 * voxel);
    }
    if (polish && std::isfinite(minPhi)) {
        // Golden-section search on [before, after], keeping the sampled minimum as a candidate.
        const GoldenSection g = goldenSection(phiAt, before, after, 1000, 0.01 * voxel);
        const double t = g.f1 < g.f2 ? g.m1 : g.m2, phi = std::min(g.f1, g.f2);
        if (phi < minPhi) minPhi = phi, c.at = t;
    }
    c.distance = minPhi;
    c.leaving = leaving && t0 <= t1;
    if (std::isfinite(minPhi) && normal) {
        const Vec3 p = from + c.at * dir;
        bool blended = false;
        if (polish) {
            // At the closest point the surface's normal is perpendicular to the ray. Past a
            // sharp edge the gradient there is the average of the two faces' (central
            // differences straddle the crease), which tilts the grazing plane and so the
            // contour's tangent line on the light. The gradients three voxels before and after
            // along the ray are each one side's; the blend of them that is perpendicular to the
            // ray is the edge's grazing normal (on a smooth surface, the normal at the closest
            // point to second order). Three voxels, so that a ray running along a face at a
            // glancing angle is past the crease (at two, a receiver next to a level-set box's
            // side came out 6% of the light too bright); two where three leave the band.
            const Vec3 d = glm::normalize(dir);
            for (double k : {3.0, 2.0}) {
                const double s = k * voxel;
                const Vec3 gm = gradientAt(grid, acc, p - s * d);
                const Vec3 gp = gradientAt(grid, acc, p + s * d);
                const double a = glm::dot(gm, d), b = glm::dot(gp, d);
                if (!(a < 0.0 && b > 0.0)) continue;
                const Vec3 n = (b * gm - a * gp) / (b - a);
                if (glm::length(n) > 1e-6) {
                    c.normal = glm::normalize(n);
                    blended = true;
                    break;
                }
            }
        }
        // The gradient at the closest point itself where no blend stands for it.
        if (!blended) c.normal = gradientAt(grid, acc, p);
    }
    return c;
}

/// Signed clearance against a level set: the far-field companion finds where the segment comes
/// closest, the fine grid refines that place when it is inside the narrow band.
Clearance levelSetClearance(LevelSetSlot& slot, const openvdb::FloatGrid& coarse, const Vec3& from,
                            const Vec3& dir, double t0, double t1, bool resumed = false) {
    if (slot.farGrid != &coarse) {
        slot.farGrid = &coarse;
        slot.farAccessor = std::make_unique<openvdb::FloatGrid::ConstAccessor>(
            coarse.getConstAccessor());
    }
    // The companion's gradient only where its answer is returned: a refined one replaces it.
    Clearance c = traceMinimum(coarse, *slot.farAccessor, from, dir, t0, t1, false, false);
    if (!std::isfinite(c.distance)) {
        Clearance none;
        none.leaving = c.leaving;
        return none;
    }
    auto withNormal = [&](Clearance r) {
        r.normal = gradientAt(coarse, *slot.farAccessor, from + r.at * dir);
        return r;
    };
    const double coarseVoxel = coarse.voxelSize()[0];
    const double fineBand = slot.grid->background();
    // The bound: the march samples every 0.8 |phi| (at least half a voxel) and phi is
    // 1-Lipschitz, so between samples it stays above 0.6 of the sampled minimum less half a
    // voxel; a sampled value inside is as deep as it says (kept at 0.9 for interpolation). The
    // companion's surface is the fine one rebuilt at coarser voxels, off by up to about half a
    // coarse voxel: its distances are shrunk by that much before they prove anything.
    auto coarseBound = [&](double d) {
        return d > 0.0 ? std::max(0.0, 0.6 * d - coarseVoxel) : std::min(0.0, 0.9 * (d + 0.5 * coarseVoxel));
    };
    if (c.distance >= 0.98 * coarse.background() || c.distance <= -0.98 * coarse.background()) {
        Clearance unknown;  // beyond the companion's band: only the bound is known
        unknown.bound = coarseBound(c.distance > 0.0 ? 0.98 * coarse.background()
                                                     : -0.98 * coarse.background());
        return unknown;
    }
    c.bound = coarseBound(c.distance);
    if (std::abs(c.distance) > fineBand + coarseVoxel) return withNormal(c);
    const double w = 3.0 * coarseVoxel;
    Clearance f = traceMinimum(*slot.grid, slot.accessor, from, dir, std::max(t0, c.at - w),
                               std::min(t1, c.at + w), true);
    if (f.leaving && !(c.at - w > t0) && !resumed) {
        // The companion's closest point lies where the segment leaves the fine surface it
        // starts on (a receiver on the obstacle: the companion is off by up to half a coarse
        // voxel there), and the fine grid rises all through the window: that is no silhouette.
        // Whatever the segment comes near lies past the window. (Until 2026-12-06 the
        // companion's closest point was kept, a distance of about the ray offset at the start,
        // and the tangent mode trusted no ray from a receiver on a level set: bench_bounds
        // --lights mixed --light-scale 6, seed 7304, 0.41% of F0 low.)
        const double resume = std::min(t1, c.at + w);
        Clearance rest;
        if (resume < t1) rest = levelSetClearance(slot, coarse, from, dir, resume, t1, true);
        if (rest.known()) {
            rest.bound = std::min(rest.bound, 0.0);  // the window near the start: unproven
            return rest;
        }
        Clearance none;
        none.leaving = true;
        return none;
    }
    if (!(std::abs(f.distance) < 0.98 * fineBand)) return withNormal(c);
    if (f.distance > 0.0) {
        // Outside the refined window only the companion's bound holds.
        f.bound = std::min(c.bound, std::max(0.0, 0.6 * f.distance - 0.5 * slot.grid->voxelSize()[0]));
    } else {
        f.bound = 0.9 * f.distance;  // a fine sample inside: as deep as it says
    }
    return f;
}

}  // namespace

bool Occluder::Query::occluded(const Vec3& from, const Vec3& to, double* tHit,
                               Clearance* clearance) {
    ++mRays;
    return trace(from, to, tHit, clearance, -1);
}

Clearance Occluder::Query::clearance(const Vec3& from, const Vec3& to, bool blocked) {
    Clearance c;
    trace(from, to, nullptr, &c, blocked ? 1 : 0);
    return c;
}



// ---------------------------------------------------------------------------------------------
// Certificates

namespace {

/// Signed certified radius against a sphere: min over t in (0, 1] of (|M + t v - c| - R) / t,
/// positive for a clear segment (its radius), negative for one that enters (minus the depth
/// radius). With s = 1/t this is min over s >= 1 of H(s) = |s A + v| - R s (A = M - c), a convex
/// function whose minimum is where s A + v makes the angle acos(R / |A|) with A.
double sphereRadius(const AnalyticSphere& sp, const Vec3& m, const Vec3& v) {
    const Vec3 a = m - sp.center;
    const double la = glm::length(a);
    // Within the tracer's tolerance of the surface (segmentEpsilon) M is on it, not inside.
    const double tol = segmentEpsilon(glm::length(v));
    if (!(la > sp.radius - tol)) return -1e300;  // starts inside: every segment from M is blocked
    const Vec3 ah = a / la;
    const double vPar = glm::dot(v, ah);
    // On the surface: H(s) falls towards its limit vPar (the rate at which the segment leaves,
    // or enters when negative) as s grows.
    if (!(la > sp.radius + tol)) return vPar;
    const double vPerp = glm::length(v - vPar * ah);
    const double cot = sp.radius / std::sqrt((la - sp.radius) * (la + sp.radius));
    const double s = std::max(1.0, (vPerp * cot - vPar) / la);
    return glm::length(s * a + v) - sp.radius * s;
}

/// The same for an axis-aligned box, in closed form. Along the line M + t v the box's signed
/// distance is simple between the t where the line crosses a face's plane or a slab's middle
/// plane. On a piece outside the box, phi^2 is a sum of squares of terms linear in t (one per
/// axis the point is outside of), so (phi / t)^2 is a quadratic in s = 1/t with a closed-form
/// minimum; on a piece inside, phi is the largest of such terms and phi / t, monotone along each,
/// is smallest at the piece's ends or where two of them cross. Exact up to rounding, which a
/// relative 1e-9 taken off a clear radius covers. (Until 2026-11-29, a golden-section search of
/// about 40 distance evaluations: 9% of a render on random scene 1.)
double boxRadiusSearch(const AnalyticBox& box, const Vec3& m, const Vec3& v, double d0);
double boxRadius(const AnalyticBox& box, const Vec3& m, const Vec3& v) {
    const BoxFrame frame(box);
    const double d0 = boxDistance(frame, m, nullptr);
    // Within the tracer's tolerance of the surface (segmentEpsilon) M is on it, not inside:
    // measured from there (a start a rounding error inside would make phi / t plunge as t -> 0).
    if (d0 < -segmentEpsilon(glm::length(v))) return -1e300;
    if (d0 < 0.0) return boxRadiusSearch(box, m, v, d0);  // a rounding error inside: searched
    auto value = [&](double t) { return boxDistance(frame, m + t * v, nullptr) / t; };
    double best = value(1.0);
    bool inside = false;
    forBoxPieces(frame, m, v, 0.0, 1.0,
                 [&](double lo, double hi, const double* alpha, const double* beta, const bool* out) {
                     if (out[0] || out[1] || out[2]) {
                         // (phi / t)^2 = A s^2 + B s + C over the axes outside, s in [1 / hi, 1 / lo].
                         double a = 0.0, b = 0.0, cc = 0.0;
                         for (int i = 0; i < 3; ++i) {
                             if (!out[i]) continue;
                             a += alpha[i] * alpha[i];
                             b += 2.0 * alpha[i] * beta[i];
                             cc += beta[i] * beta[i];
                         }
                         const double sLo = 1.0 / hi, sHi = lo > 0.0 ? 1.0 / lo : 1e300;
                         const double sv = a > 0.0 ? std::clamp(-b / (2.0 * a), sLo, sHi) : sLo;
                         best = std::min(best, std::sqrt(std::max(0.0, (a * sv + b) * sv + cc)));
                     } else {
                         inside = true;
                         if (lo > 0.0) best = std::min(best, value(lo));
                         forTermCrossings(lo, hi, alpha, beta,
                                          [&](double t) { best = std::min(best, value(t)); });
                     }
                 });
    // A segment that enters has its depth from points it reaches (true depths); a clear one's
    // closed-form minimum loses a rounding margin.
    if (inside || best <= 0.0) return std::min(best, 0.0);
    return std::max(0.0, best * (1.0 - 1e-9) - 1e-12);
}

/// The golden-section search for a start a rounding error inside: t -> phi(M + t v) / t is
/// unimodal on (0, 1] for a convex shape, measured from the start's depth.
double boxRadiusSearch(const AnalyticBox& box, const Vec3& m, const Vec3& v, double d0) {
    const BoxFrame frame(box);
    const double shift = std::min(d0, 0.0);
    auto h = [&](double t) { return (boxDistance(frame, m + t * v, nullptr) - shift) / t; };
    // The search narrows the bracket [a, z] of the minimum until t -> phi / t can drop inside
    // it by at most a millionth of the value found (its slope is at most (|v| + |phi|) / t^2,
    // and t >= a there): a clear radius is shaved by that drop, a depth radius needs no shave
    // (any sampled depth is a true one). (To 1e-12 always, it took 60 steps and a seventh of
    // the render on random scenes with boxes.)
    const double length = glm::length(v);
    GoldenSection g = goldenSection(h, 0.0, 1.0, 64, 1e-3);
    double best = std::min({g.f1, g.f2, h(1.0)});
    const double tb0 = std::max(g.a, 1e-6);
    const double tolerance = 1e-6 * std::max(std::abs(best), 1e-9 * length);
    const double width = std::max(1e-12, tolerance * tb0 * tb0 / (length + std::abs(best) * tb0));
    if (g.z - g.a > width) {
        g = goldenSection(h, g.a, g.z, 64, width);
        best = std::min({best, g.f1, g.f2});
    }
    if (best > 0.0) {
        const double tb = std::max(g.a, 1e-6);
        best = std::max(0.0, best - ((g.z - g.a) * (length + best * tb) / (tb * tb) + 1e-12));
    }
    return best;
}

/// A cone of radius `rho` (at the light) that a caller proved clear up to fraction `t`: where
/// levelSetRadius's cone march may start.
struct ConeStart {
    double t, rho;
};

}  // namespace

/// Signed certified radius against one level set, up to `want` (see Certificate). Distances come
/// from the obstacle's bounds (exact lower bound outside them), its far-field companion (values
/// within a coarse voxel of the fine surface's distance) and, next to the surface, the fine grid.
/// A cone march: the segment's cone of radius rho at the light is proven free while balls of
/// the bounded distance around points of the segment contain its cross-sections, and rho shrinks
/// (at least halving) when a ball is too small. A segment that goes inside is then sampled for
/// its depth.
static double levelSetRadius(LevelSetSlot& slot, const openvdb::FloatGrid& coarse,
                             const CompanionError& coarseError, const CellTables* tables,
                             const Box3& bounds, const Vec3& m,
                             const Vec3& v, double want, bool blocked, double tHit,
                             double tMiddle, const ConeStart* resume = nullptr) {
    const double length = glm::length(v);
    const double hc = coarseError.worst();
    const double bandC = 0.98 * double(coarse.background());
    const double hf = slot.grid->voxelSize()[0];
    const double bandF = 0.98 * double(slot.grid->background());
    if (slot.farGrid != &coarse) {
        slot.farGrid = &coarse;
        slot.farAccessor =
            std::make_unique<openvdb::FloatGrid::ConstAccessor>(coarse.getConstAccessor());
    }
    // Points of the segment m + t v in world space and in both grids' index spaces (their
    // transforms are linear: each is affine in t, computed once per segment).
    auto toIndex = [](const openvdb::FloatGrid& g, const Vec3& p) {
        return g.worldToIndex(openvdb::Vec3d(p.x, p.y, p.z));
    };
    const openvdb::Vec3d f0 = toIndex(*slot.grid, m), fv = toIndex(*slot.grid, m + v) - f0;
    const openvdb::Vec3d c0 = toIndex(coarse, m), cv = toIndex(coarse, m + v) - c0;
    auto fineAt = [&](double t) { return double(sampleTrilinear(slot.accessor, f0 + t * fv)); };
    auto coarseAt = [&](double t) {
        return double(sampleTrilinear(*slot.farAccessor, c0 + t * cv));
    };
    const BoxFrame boundsFrame = [&] {
        AnalyticBox x;
        x.lo = bounds.lo;
        x.hi = bounds.hi;
        return BoxFrame(x);
    }();
    // Bounds on the fine surface's signed distance at m + t v: lo <= phi <= hi. `need` is what
    // the caller would like lo to reach; the companion is not sampled when the box proves it.
    struct Range {
        double lo, hi;
    };
    // In the fine band its value alone bounds phi: trilinear values of a distance grid lie
    // within half a voxel of the distance, with a gradient up to ~1.2. The bounds that prove
    // something (lo outside, hi inside) are the interpolant's own value over its gradient
    // bound around the point (CellTables::gradientBound, at least 1; 1.25 without tables),
    // without the half voxel: the tracer blocks exactly the rays that the interpolated surface
    // blocks (level_set_search.h tests each cell's cubic), so a ball of |vf| over the bound
    // around the point lies on the point's side of the surface the rays see. (Until 2026-12-03
    // a depth lost the half voxel, and blocked rays within half a voxel of a thin level set's
    // surface proved nothing: under a two-voxel capsule, random seed 704, coverage spent its
    // rays on the capsule's shadow and missed another obstacle's small one, 0.7% of F. And the
    // bound was 1.25 everywhere, measured rather than proven: at a box's edges the interpolant
    // is steeper.)
    auto fineRange = [&](double vf, double t) -> Range {
        double g = 1.25;
        if (tables) {
            const openvdb::Vec3d ip = f0 + t * fv;
            g = std::max(1.0, tables->gradientBound(ip[0], ip[1], ip[2]));
        }
        return {vf > 0.0 ? vf / g : vf * 1.25 - 0.5 * hf,
                vf > 0.0 ? vf * 1.25 + 0.5 * hf : vf / g};
    };
    // Whether the last point's fine value lay inside the fine band: the next point, close by,
    // reads the fine grid first and skips the box and the companion when it is still there.
    bool nearSurface = false;
    auto companionRange = [&](double t, double need, double vf) -> Range {
        if (nearSurface) {
            vf = fineAt(t);
            if (std::abs(vf) < bandF) return fineRange(vf, t);
            nearSurface = false;
        }
        const double dBox = boxDistance(boundsFrame, m + t * v, nullptr);
        // Far from the bounds the box says as much as the companion could (the band ends there).
        if (dBox >= std::min(need, bandC) && dBox > 0.0) return {dBox, 1e300};
        const double vc = coarseAt(t);
        if (vc >= bandC) return {std::max(dBox, bandC - hc), 1e300};
        if (vc <= -bandC) return {-1e300, -(bandC - hc)};
        // The error of the part of the surface nearest p, which lies within |vc| + hc of it.
        const openvdb::Vec3d ip = f0 + t * fv;
        const double reach = (std::abs(vc) + hc) / hf + 1.0;
        const CompanionError::Local local = coarseError.at(ip, vc, reach, hf);
        const double e = local.error, lo = local.lower;
        // The fine grid can only help where these bounds come near its band.
        if (lo > bandF || vc < -(bandF + 2.0 * e)) return {std::max(dBox, lo), vc + e};
        if (std::isnan(vf)) vf = fineAt(t);
        // Beyond the fine band the surface is at least the band away (inactive values are the
        // band's width, with the sign of the side).
        if (vf >= bandF) return {std::max({dBox, lo, bandF}), vc + e};
        if (vf <= -bandF) return {vc - e, std::min(vc + e, -bandF)};
        nearSurface = true;
        return fineRange(vf, t);
    };
    auto range = [&](double t, double need) -> Range {
        double vf = std::numeric_limits<double>::quiet_NaN();
        const openvdb::Vec3d ic = f0 + t * fv;
        // What the coarse table proves clear around the point (the companion's bounds below
        // never go under it).
        double floorLo = 0.0, ceilHi = 1e300;
        if (tables) {
            // The cell tables: a ball of |cell| voxels around the point holds only clear (or
            // only inside) cells. The coarse one first (small enough to stay in cache), then
            // the one-voxel one; where that is less than the caller needs and the point may
            // lie in the fine band, the fine value may prove more.
            double cell;
            if (tables->coarse.at(ic[0], ic[1], ic[2], cell)) {
                if (cell > 0.0) {
                    floorLo = cell * hf;
                    if (floorLo >= need) return {floorLo, 1e300};
                }
                if (cell < 0.0) ceilHi = cell * hf;  // the coarse table reaches deeper inside
            }
            if (tables->fine.at(ic[0], ic[1], ic[2], cell)) {
                const double d = cell < 0.0 ? std::min(cell * hf, ceilHi) : cell * hf;
                if (cell > 0.0 && (d >= need || d >= bandF)) return {d, 1e300};
                if (cell > 0.0) floorLo = std::max(floorLo, d);
                if (cell < 0.0) ceilHi = d;
                // Deep inside, the companion's value (its error is about a voxel) often proves
                // deeper than the cells (up to their diagonal): blocked segments take few
                // points, so both are read (below). Elsewhere the fine value first.
                if (!(cell < 0.0 && -d >= bandF)) {
                    vf = fineAt(t);
                    if (std::abs(vf) < bandF) {
                        Range r = fineRange(vf, t);
                        return {std::max(r.lo, floorLo), std::min(r.hi, ceilHi)};
                    }
                    // Clear beyond the fine band: the band's width (the companion, a voxel or
                    // so closer to the truth, costs more than it saves here).
                    if (cell > 0.0 && vf >= bandF) return {std::max(floorLo, bandF), 1e300};
                }
                // Beyond the fine band (or a surface cell whose values say so: a level set
                // whose band is not what its values say): the companion may prove more.
            }
        }
        Range r = companionRange(t, need, vf);
        return {std::max(r.lo, floorLo), std::min(r.hi, ceilHi)};
    };

    // A blocked segment whose first hit lies in these bounds: its depth from there.
    double t = 0.0;
    bool inside = false;
    if (tHit >= 0.0) {
        // The hit is on the surface, where nothing is proven deep: the first point a voxel on.
        t = tHit + hf / length;
        inside = true;
        nearSurface = true;
    } else {
        // Clear part: the cone march. Radii under a 64th of `want` are not worth the steps
        // they take. (Small discs matter to coverage: with an eighth, coverage ran out of rays
        // more often and random scene 1 kept 14 pixels over 6 units off, against none.)
        const double rhoMin = want / 64.0;
        double rho = want;
        if (resume) {
            t = resume->t;
            rho = std::min(want, resume->rho);
        }
        auto need = [&](double tt) { return 1.25 * rho * tt + 1e-12; };
        // The cone narrowed for a point's bound lo at tt (too close for this cone to step on by
        // at least a fifth of the ball); false when it would fall under rhoMin.
        auto narrowed = [&](double lo, double tt, double& out) {
            out = lo < 1.25 * rho * tt ? 0.7 * lo / tt : rho;
            return out >= rhoMin;
        };
        // The segments to the light points within rho of its end pass within rho t' of the
        // axis at t' (balls, not discs across the axis: a light point may lie anywhere within
        // rho), and the ball of radius lo around the point at tt holds that one while
        // length |t' - tt| + rho t' <= lo: forward up to (lo + length tt) / (length + rho),
        // back down to (length tt - lo) / (length - rho). (Taking them for discs, (length
        // (t' - t))^2 + (rho t')^2 <= lo^2, steps twice as far and certified blocked points in
        // tests/test_certificate.cpp.) [0, t) is proven; a narrower cone keeps what is proven.
        Range r = range(t, need(t));
        double prevT = -1.0, prevLo = 0.0;
        // A point sampled ahead whose ball did not reach back to what was proven: kept, and
        // jumped to once the march's balls reach its own.
        double aheadT = -1.0;
        Range aheadR{0.0, 0.0};
        // How far back a ball reaches (none when the cone is as wide as the segment is long).
        auto backOf = [&](double tt, double lo) {
            return length > rho ? (length * tt - lo) / (length - rho) : 1e300;
        };
        for (int it = 0; it < 400; ++it) {
            if (r.lo <= 0.0 || !narrowed(r.lo, t, rho)) break;
            const double fwd = (r.lo + length * t) / (length + rho);
            if (fwd >= 1.0) return rho;
            if (aheadT > fwd && backOf(aheadT, aheadR.lo) <= fwd) {
                t = aheadT;
                r = aheadR;
                aheadT = -1.0;
                continue;
            }
            // Look ahead: a point as far past fwd as this ball reaches forward, whose own ball
            // closes the gap back to fwd unless the distance falls on the way. Not while the
            // distance falls fast (towards a surface the look-ahead fails).
            const bool falling =
                prevT >= 0.0 && prevLo - r.lo > 0.5 * (t - prevT) * length;
            prevT = t;
            prevLo = r.lo;
            const double ahead = 2.0 * fwd - t;
            if (!falling && aheadT <= fwd && ahead < 1.0) {
                const Range ra = range(ahead, need(ahead));
                double rhoA;
                if (ra.lo > 0.0 && narrowed(ra.lo, ahead, rhoA)) {
                    if (backOf(ahead, ra.lo) <= fwd) {
                        t = ahead;
                        r = ra;
                        continue;
                    }
                    aheadT = ahead;
                    aheadR = ra;
                }
            }
            t = fwd;
            r = range(t, need(t));
        }
        inside = blocked;
    }
    if (!inside) return 0.0;
    // After a hit whose chord's middle (through the solid's box and sphere) lies in an inside
    // cell of the coarse table, the march below leaps there first: a compact shape is deepest
    // about there, and the march takes two or three points. Otherwise (the bunny's chords miss
    // their middle 40% of the time, and the march then crawls from the entry) the tables choose
    // where to measure: the coarse table along the chord, a point per coarse cell from the hit
    // until the chord leaves its inside cells (or the table, or the depth over t falls under
    // half its best: past the deep part); three candidates read in the one-voxel table (which
    // loses a voxel or two to the cells' boxes, the coarse one up to two of its cells): the
    // coarse point of the largest depth over t, the middle of the coarse points of the largest
    // depth (on a quantized plateau the deepest point lies nearer its middle) and tMiddle; and
    // range() at the best of them (the companion proves a voxel or so more: with the one-voxel
    // table alone the default scene took 2.6% more rays). A chord through no coarse inside cell
    // (a thin part) scans the one-voxel table a voxel at a time instead, up to 64 points; one
    // through surface cells only takes the march. Scanning every chord cost the level-set
    // sphere of bench_occluder's segments 9% and saved the bunny as much; this way the bunny
    // saves 6-8% and the sphere moves within 2% (docs/BENCHMARKS.md, 2026-12-02).
    bool middleInside = false;
    if (tHit >= 0.0 && tables && tMiddle > tHit && tMiddle < 1.0) {
        const openvdb::Vec3d p = f0 + tMiddle * fv;
        double cell;
        middleInside = tables->coarse.at(p[0], p[1], p[2], cell) && cell < 0.0;
    }
    if (tHit >= 0.0 && tables && !middleInside) {
        const double voxels = std::sqrt(fv.lengthSqr());  // the segment's length in voxels
        // The largest depth over t in `table` (world units), at bestT; `middle`: the middle of
        // the points of the largest depth.
        auto scan = [&](const CellDistance& table, double step, int maxPoints, double& bestT,
                        double& middle) {
            double best = 0.0;  // the largest depth over t, in voxels
            double top = 0.0, topFirst = -1.0, topLast = -1.0;
            const double dt = step / voxels;
            double s = tHit + 0.5 * dt;
            for (int k = 0; k < maxPoints && s <= 1.0; ++k, s += dt) {
                const openvdb::Vec3d p = f0 + s * fv;
                double cell;
                if (!table.at(p[0], p[1], p[2], cell) || cell > 0.0) break;
                if (-cell > top) {
                    top = -cell;
                    topFirst = topLast = s;
                } else if (-cell == top) {
                    topLast = s;
                }
                if (cell < 0.0 && -cell > best * s) {
                    best = -cell / s;
                    bestT = s;
                    if (best * hf >= want) break;
                } else if (-cell < 0.5 * best * s) {
                    break;
                }
            }
            middle = 0.5 * (topFirst + topLast);
            return best * hf;
        };
        double bestT = -1.0, middle = -1.0;
        double deep = scan(tables->coarse, CellTables::kCoarseBlock, 1 << 20, bestT, middle);
        if (deep >= want) return -want;
        double at = bestT;  // where the companion measures (> 0 once a depth is proven)
        if (bestT > 0.0) {
            for (const double c : {bestT, middle, tMiddle}) {
                if (!(c > tHit && c <= 1.0) || (c != bestT && c == at)) continue;
                const openvdb::Vec3d p = f0 + c * fv;
                double cell;
                if (tables->fine.at(p[0], p[1], p[2], cell) && -cell * hf / c > deep) {
                    deep = -cell * hf / c;
                    at = c;
                }
            }
        } else {
            deep = scan(tables->fine, 1.0, 64, at, middle);
        }
        if (at > 0.0) {
            if (deep < want) {
                nearSurface = false;
                const Range r = range(at, 0.0);
                if (r.hi < 0.0) deep = std::max(deep, -r.hi / at);
            }
            return -std::min(deep, want);
        }
    }
    // The segment comes within the bounds' uncertainty of the surface at t: sample its depth,
    // the largest -hi / t over points inside, until it reaches `want`. Any inner point proves
    // its own disc, so the points need not be dense. After a hit, the first point leaps past
    // the entry by 3 want x t plus the companion's error (the depth grows at most as fast as
    // the distance from the surface, and the bounds lose up to a quarter of it and that error),
    // but not beyond tMiddle, the middle of the segment's chord through the solid's bounds,
    // where a compact shape is deepest; when that point is outside, the march goes back to a
    // voxel past the entry. Each step then goes at least 1.5 times as far again
    // as the distance from the entry (a chord is crossed in a few points, not hundreds), and
    // the march ends once the value has fallen to half its best (past the chord's deep part).
    // When the leap's point stays the deepest, one more point halfway back to the entry: the
    // leap may have overshot the deep part. (Steps of 0.5 times the distance and no leap took
    // 8 points per blocked segment in bench_occluder's sphere, 4.7 with the steps alone. A leap
    // of want x t past the entry, uncapped, took 2.3 for want 0.1 and 2.6 for want 1.41; the
    // middle alone 1.16 and 2.06, with worse radii where `want` is out of reach: the median
    // certified depth over the exact one fell from 0.60 to 0.57 in tests/test_certificate.cpp.)
    double depth = 0.0;
    bool wasInside = false;
    const double entry = tHit >= 0.0 ? tHit : t;
    double leapT = 0.0;     // the leap's point (> 0 when the first point is the leap's)
    bool leapBest = false;  // the leap's point is inside and the deepest so far
    if (tHit >= 0.0) {
        const double target = std::min(tMiddle, tHit + (3.0 * want * tHit + hc) / length);
        if (target > t && target < 1.0) {
            leapT = t = target;
            nearSurface = false;  // the leap lands deep, where the fine grid says nothing
        }
    }
    for (int it = 0; it < 200 && t <= 1.0; ++it) {
        const Range r = range(t, 0.0);
        const bool atLeap = leapT > 0.0 && it == 0;
        if (atLeap && !(r.hi < 0.0)) {
            t = tHit + hf / length;  // past the chord (or not proven inside): from the entry
            nearSurface = true;
            continue;
        }
        if (r.hi < 0.0) {
            const double d = -r.hi / std::max(t, 1e-12);
            if (d >= want) return -want;
            if (d < 0.5 * depth) break;
            if (atLeap) leapBest = true;
            else if (d > depth) leapBest = false;
            depth = std::max(depth, d);
            wasInside = true;
        } else if (wasInside && r.lo > 0.0) {
            break;  // out again: later entries are other chords, not needed for a bound
        }
        // A ball of radius |hi| around an inner point is inside: the next point, that far on,
        // is still inside unless the chord ends there.
        const double mag = std::min(std::abs(r.hi), std::abs(r.lo));
        const double step = std::max({std::isfinite(mag) && mag < 1e299 ? mag : hc, 0.5 * hf,
                                      1.5 * (t - entry) * length});
        t += step / length;
    }
    if (leapBest) {
        const double tb = 0.5 * (entry + leapT);
        const Range r = range(tb, 0.0);
        if (r.hi < 0.0) depth = std::max(depth, std::min(want, -r.hi / tb));
    }
    return -depth;
}


// ---------------------------------------------------------------------------------------------
// Obstacle kinds
//
// What the query asks of an obstacle, one struct per kind (AnalyticKind<AnalyticSphere>,
// AnalyticKind<AnalyticBox>, LevelSetKind) with the same members:
//   clearance(from, dir, invDir, t0, t1, near): the signed closest approach of the segment
//       from + t dir, t in [t0, t1] (Clearance), with `bound` the proven part of it (exact
//       for analytic shapes); `near` false when the segment stays beyond what the kind can
//       measure (its `bound` then says how far);
//   hit(from, dir, invDir, bounds, tMin, tMax, t): the first hit in (tMin, tMax), t = 0 when
//       the segment starts inside;
//   radius(m, v, want, blocked, tHitFraction): the signed certificate radius (occluder.h's
//       Certificate) of the segment m + t v, up to `want`.
// The query visits them (visitKind); OpenVDB stays inside the level-set kind.

namespace {

// The analytic kinds' exact answers, by overload.
Clearance analyticClearance(const AnalyticSphere& s, const Vec3& from, const Vec3& dir, double t0,
                            double t1) {
    return sphereClearance(s, from, dir, t0, t1);
}
Clearance analyticClearance(const AnalyticBox& b, const Vec3& from, const Vec3& dir, double t0,
                            double t1) {
    return boxClearance(b, from, dir, t0, t1);
}
// The first hit, given the segment's interval [t0, ...] inside the bounds.
bool analyticHit(const AnalyticSphere& s, const Vec3& from, const Vec3& dir, double, double tMin,
                 double tMax, double& t) {
    return hitSphere(s, from, dir, tMin, tMax, &t);
}
bool analyticHit(const AnalyticBox&, const Vec3&, const Vec3&, double t0, double tMin, double,
                 double& t) {
    t = t0 > tMin ? t0 : 0.0;  // the bounds are the box itself: the clipped interval is the answer
    return true;
}
double analyticRadius(const AnalyticSphere& s, const Vec3& m, const Vec3& v) {
    return sphereRadius(s, m, v);
}
double analyticRadius(const AnalyticBox& b, const Vec3& m, const Vec3& v) {
    return boxRadius(b, m, v);
}

// A sphere or a box: exact distances, exact hits, exact certificates.
template <class Shape>
struct AnalyticKind {
    const Shape& shape;

    Clearance clearance(const Vec3& from, const Vec3& dir, const Vec3&, double t0, double t1,
                        bool& near) const {
        near = true;
        Clearance c = analyticClearance(shape, from, dir, t0, t1);
        // The closest point at the segment's start: the segment only moves away from the shape
        // (which is convex), so the shape is no silhouette for it. For a receiver on the shape
        // itself (or a ray offset off it) that distance is about zero, and taken for a grazing
        // ray it put the tangent mode's contour vertices at the receiver (a box's top face came
        // out 2.5% of the light too dark, gradients of 1e6). The shape is left out of the
        // clearance like one the segment stays far from; its bound, the distance at the start,
        // still holds.
        if (c.at <= t0 + 1e-9 * (1.0 + std::abs(t1))) {
            near = false;
            Clearance leaving;
            leaving.bound = c.distance;
            return leaving;
        }
        c.bound = c.distance;  // exact
        return c;
    }
    bool hit(const Vec3& from, const Vec3& dir, const Vec3& invDir, const Box3& bounds,
             double tMin, double tMax, double& t) const {
        double t0 = tMin, t1 = tMax;
        if (!bounds.clipRay(from, invDir, t0, t1)) return false;
        return analyticHit(shape, from, dir, t0, tMin, tMax, t);
    }
    double radius(const Vec3& m, const Vec3& v, double, bool, double) const {
        return analyticRadius(shape, m, v);
    }
    bool hitCertified(const Vec3& from, const Vec3& v, const Vec3& dir, const Vec3& invDir,
                      const Box3& bounds, double, double tMin, double tMax, double, double& t,
                      double& r) const {
        r = analyticRadius(shape, from, v);
        return hit(from, dir, invDir, bounds, tMin, tMax, t);
    }
};

struct LevelSetKind {
    static constexpr int kMaxSkips = 256;  // table steps before the intersector takes over
    const LevelSet& levelSet;
    LevelSetSlot* slot;  // this thread's intersector and accessors; null for an empty grid
    const Occluder::FarField& far;
    const Box3& bounds;
    const Box3& solidBox;  // around what can block (Occluder::solidBounds), and a sphere
    const Vec3& solidCentre;
    double solidRadius;

    Clearance clearance(const Vec3& from, const Vec3& dir, const Vec3& invDir, double t0,
                        double t1, bool& near) const {
        // Distances are known around the obstacle as far as its companion's band reaches.
        const double pad = kFarBand * kFarVoxelFactor * levelSet.voxelSize();
        Box3 wide = bounds;
        wide.lo -= Vec3(pad);
        wide.hi += Vec3(pad);
        near = wide.clipRay(from, invDir, t0, t1);
        if (!near) {
            Clearance c;
            c.bound = pad;  // the segment misses the bounds widened by `pad`
            return c;
        }
        return slot ? levelSetClearance(*slot, far.get(), from, dir, t0, t1) : Clearance{};
    }
    /// Sphere tracing along from + t dir (dir a unit vector) from t0 on the cell tables, which
    /// must exist: returns the first t where the clear ball they prove is under kNear voxels,
    /// or a t >= t1 when there is none before t1. With `rho`, also the radius of the cone the
    /// balls prove (Certificate; the segment ending at t1, whose start is `from`).
    ///
    /// The cone: the ball of radius D_i around the point at fraction s_i holds the cone's
    /// cross-section at s (a ball of radius rho s) while L |s - s_i| + rho s <= D_i. The steps
    /// are D_i, so each interval [s_i, s_i+1] is held by its two end balls; the smallest of
    /// max(ball i, ball i+1) / s over it is at an end or where the two meet,
    /// s* = s_i + (2 D_i - D_i+1) / 2L, where it is D_i+1 / 2. The last ball must hold the cross-section
    /// at the segment's end.
    static constexpr double kNear = 1.5;
    /// What skipClear() proves of the cone: its radius `rho` so far, and the last ball (at
    /// fraction sLast, radius dLast; sLast < 0 before the first).
    struct Cone {
        double rho = 0.0, sLast = -1.0, dLast = 0.0;
    };
    double skipClear(const CellTables& tables, const Vec3& from, const Vec3& dir, double t0,
                     double t1, Cone* rho) const {
        const double hf = levelSet.voxelSize();
        const openvdb::Vec3d p0 = slot->grid->worldToIndex(openvdb::Vec3d(from.x, from.y, from.z));
        const openvdb::Vec3d pd =
            slot->grid->worldToIndex(openvdb::Vec3d(from.x + dir.x, from.y + dir.y, from.z + dir.z)) -
            p0;
        const double length = t1;
        double tc = t0, r = 1e300, sPrev = -1.0, dPrev = 0.0;
        for (int k = 0; k < kMaxSkips; ++k) {
            const openvdb::Vec3d p = p0 + tc * pd;
            const double d = tables.clearVoxels(p[0], p[1], p[2]) * hf;
            if (d < kNear * hf) break;
            if (rho) {
                const double sc = tc / length;
                if (sPrev > 0.0) r = std::min(r, std::max(dPrev, d - dPrev) / sPrev);
                if (sPrev >= 0.0) {
                    const double meet = sPrev + (2.0 * dPrev - d) / (2.0 * length);
                    if (meet > sPrev && meet < sc) r = std::min(r, 0.5 * d / meet);
                    r = std::min(r, d / sc);
                }
                sPrev = sc;
                dPrev = d;
            }
            tc += d;
            if (tc >= t1) {
                if (rho) {
                    // The last ball holds the cone to the segment's end while L (1 - sLast) +
                    // rho <= dLast (the balls' linear condition above, at s = 1). A ball around
                    // the end itself (radius dE) holds it from (L - dE) / (L - rho) on, the last
                    // ball up to (dLast + L sLast) / (L + rho): the two together hold it when
                    // rho <= L (a - L + dE) / (a + L - dE), a = dLast + L sLast, and rho <= dE.
                    // (The last ball alone left a light seen whole through a torus' hole with a
                    // disc of 0.04 where the rest of the march proved 0.59: it reached the end
                    // by that much.)
                    double end = dPrev - length * (1.0 - sPrev);
                    const openvdb::Vec3d pe = p0 + t1 * pd;
                    const double dE = tables.clearVoxels(pe[0], pe[1], pe[2]) * hf;
                    const double a = dPrev + length * sPrev;
                    if (dE > 0.0 && dE < length && a + length - dE > 0.0)
                        end = std::max(end, std::min(dE, length * (a - length + dE) / (a + length - dE)));
                    r = std::min(r, end);
                    if (sPrev > 0.0) r = std::min(r, dPrev / sPrev);
                }
                break;
            }
        }
        if (rho) *rho = Cone{std::max(0.0, r * (1.0 - 1e-9)), sPrev, dPrev};
        return tc;
    }

    /// `start`: where to begin looking when the segment before it is known to be clear.
    bool hit(const Vec3& from, const Vec3& dir, const Vec3& invDir, const Box3&, double tMin,
             double tMax, double& t, double start = -1.0) const {
        double t0 = tMin, t1 = tMax;
        if (!slot || !bounds.clipRay(from, invDir, t0, t1)) return false;
        if (start > t0) {
            t0 = start;  // the caller proved the segment clear up to here: not inside
            if (!(t0 < t1)) return false;
        } else {
            if (t0 == tMin) {
                // The segment starts inside the bounds: the marcher only finds sign changes, so
                // a start inside the surface must be caught here.
                const openvdb::Vec3d startIS =
                    slot->grid->worldToIndex(openvdb::Vec3d(from.x, from.y, from.z));
                if (sampleTrilinear(slot->accessor, startIS) < 0.0f) {
                    t = 0.0;
                    return true;
                }
            }
            if (const CellTables* tables = levelSet.cellTablesIfBuilt()) {
                // Sphere tracing on the cell tables first (when a certifying caller has had
                // them built): a ball they prove clear is crossed in one step, and the
                // intersector starts only where the segment comes near a cell that may hold the
                // surface (half a voxel before), or not at all when it never does. The answer
                // is the intersector's: the tables prove the trilinear field positive over what
                // is skipped, where the intersector finds nothing.
                const double tc = skipClear(*tables, from, dir, t0, t1, nullptr);
                if (tc >= t1) return false;
                t0 = std::max(t0, tc - 0.5 * levelSet.voxelSize());
            }
        }
        const VdbRay ray(openvdb::Vec3d(from.x, from.y, from.z), openvdb::Vec3d(dir.x, dir.y, dir.z),
                         t0, t1);
        openvdb::Vec3d xyz;
        // The overload returning the point: the one returning a time can hand back the previous
        // ray's time (OpenVDB 10).
        if (!slot->intersector.intersectsWS(ray, xyz)) return false;
        // The marcher stops at t1, but t is recomputed from a point that went through the
        // index-space map: keep the segment end exclusive.
        t = glm::dot(Vec3(xyz.x(), xyz.y(), xyz.z()) - from, dir);
        if (!(t < tMax)) return false;
        if (t < 0.0) t = 0.0;
        return true;
    }
    /// `solidOnly`: the closed-form radii of the solid's box and sphere only (0 when they
    /// prove nothing).
    double radius(const Vec3& m, const Vec3& v, double want, bool blocked, double tHitFraction,
                  bool solidOnly = false, const ConeStart* resume = nullptr) const {
        if (!slot) return want;
        // Every point the tracer can hit lies in the solid's box and in its sphere
        // (LevelSet::solidBoundsWS): a segment clear of either is clear of the level set, with
        // their exact radii, in closed form. The march runs only where neither proves anything:
        // beating them took it 10-30 steps a segment, for discs that saved coverage 1-2% of its
        // rays and cost 10% of the render (random scenes 1 and 6).
        double solidR = 0.0;
        if (tHitFraction < 0.0) {
            AnalyticSphere sphere;
            sphere.center = solidCentre;
            sphere.radius = solidRadius;
            solidR = std::max(0.0, sphereRadius(sphere, m, v));
            if (solidR < want) {
                AnalyticBox box;
                box.lo = solidBox.lo;
                box.hi = solidBox.hi;
                solidR = std::max(solidR, boxRadius(box, m, v));
            }
            if (solidR > 0.0) return std::min(solidR, want);
        }
        if (solidOnly) return 0.0;
        // A blocked segment's depth march leaps no further than the middle of its chord
        // through the solid's box and sphere.
        double tMiddle = 1.0;
        if (tHitFraction >= 0.0) {
            double tA = tHitFraction, tB = 1.0;
            const Vec3 a = m - solidCentre;
            const double vv = glm::dot(v, v), b = glm::dot(a, v);
            const double disc = b * b - vv * (glm::dot(a, a) - solidRadius * solidRadius);
            if (disc > 0.0 && solidBox.clipRay(m, 1.0 / v, tA, tB)) {
                tA = std::max(tA, (-b - std::sqrt(disc)) / vv);
                tB = std::min(tB, (-b + std::sqrt(disc)) / vv);
                tMiddle = 0.5 * (tA + tB);
            }
        }
        return levelSetRadius(*slot, far.get(), far.error(), far.cells(), bounds, m, v, want, blocked,
                              tHitFraction, tMiddle, resume);
    }
    /// The answer and the signed radius together (Query::occludedCertified): sphere tracing
    /// on the cell tables from the segment's start, which proves a clear segment's cone on
    /// the way when it gets through (and the solid's closed-form radii may prove a wider one);
    /// where it stops near the surface, the intersector from there, and after a hit the depth
    /// march, without one the cone march resumed from the tracing's last ball. (Without cell
    /// tables: the intersector, then radius().)
    bool hitCertified(const Vec3& from, const Vec3& v, const Vec3& dir, const Vec3& invDir,
                      const Box3&, double length, double tMin, double tMax, double want,
                      double& t, double& r) const {
        r = want;
        if (!slot) return false;
        double start = -1.0;
        Cone cone;
        if (const CellTables* tables = far.cells()) {
            const double tc = skipClear(*tables, from, dir, tMin, length, &cone);
            if (tc >= length) {
                // Clear; the solid's closed-form radii may prove a wider cone.
                double rho = cone.rho;
                if (rho < want) rho = std::max(rho, radius(from, v, want, false, -1.0, true));
                r = std::min(rho, want);
                return false;
            }
            start = std::max(tMin, tc - 0.5 * levelSet.voxelSize());
        }
        if (hit(from, dir, invDir, bounds, tMin, tMax, t, start)) {
            r = radius(from, v, want, true, t / length);
            return true;
        }
        // Clear, passing near the surface: the cone march goes on from the last ball, whose
        // cone of the radius proven so far reaches (dLast + L sLast) / (L + rho).
        const double rho = std::min(want, cone.rho);
        if (cone.sLast > 0.0 && rho >= want / 64.0) {
            const ConeStart resume{(cone.dLast + length * cone.sLast) / (length + rho), rho};
            r = std::max(0.0, radius(from, v, want, false, -1.0, false, &resume));
        } else {
            r = std::max(0.0, radius(from, v, want, false, -1.0));
        }
        return false;
    }
};

}  // namespace

template <class F>
decltype(auto) Occluder::Query::visitKind(size_t i, F&& f) {
    const ObstacleShape& shape = mOccluder->shape(i);
    if (const auto* sphere = std::get_if<AnalyticSphere>(&shape)) {
        return f(AnalyticKind<AnalyticSphere>{*sphere});
    }
    if (const auto* box = std::get_if<AnalyticBox>(&shape)) return f(AnalyticKind<AnalyticBox>{*box});
    const Occluder::Solid& solid = mOccluder->mSolid[i];
    return f(LevelSetKind{*std::get<LevelSetPtr>(shape), mImpl->levelSets[i].get(),
                          *mOccluder->mFar[i], mOccluder->bounds(i), solid.box, solid.centre,
                          solid.radius});
}

bool Occluder::Query::trace(const Vec3& from, const Vec3& to, double* tHit, Clearance* clearance,
                            int known) {
    if (known < 0) mLastBlocker = -1;
    if (clearance) *clearance = Clearance{};
    // The nearest obstacle whose distance is unknown is at least this far (its band): the
    // smallest known distance is the segment's clearance when it is below that.
    double unknownFloor = std::numeric_limits<double>::infinity();
    double clearanceMin = std::numeric_limits<double>::infinity(), clearanceAt = 0.0;
    Vec3 clearanceNormal(0.0);
    int clearanceObstacle = -1;
    // Smallest and largest per-obstacle bounds (see Clearance::bound); 0 marks "unknown".
    double boundMin = std::numeric_limits<double>::infinity();
    bool boundKnown = true;
    bool touched = false;
    const Vec3 delta = to - from;
    const double length = glm::length(delta);
    const double eps = segmentEpsilon(length);
    if (!(length > 2.0 * eps)) return false;
    const Vec3 dir = delta / length;
    const Vec3 invDir = 1.0 / dir;  // +-inf on axes the ray does not move along
    const double tMin = eps;
    double tMax = length - eps;  // shrinks to the nearest hit so far when tHit is wanted
    bool hit = false;
    double best = std::numeric_limits<double>::infinity();

    const size_t count = mCandidates ? mCandidates->size() : mOccluder->size();
    // With a clearance wanted, the obstacles are visited nearest first by a closed-form lower
    // bound on their distance (the segment's to the sphere around their bounds): one whose bound
    // exceeds the smallest distance measured so far cannot be the nearest, and its march is
    // skipped (its bound stands for it).
    auto& order = mImpl->order;
    if (clearance) {
        order.clear();
        for (size_t k = 0; k < count; ++k) {
            const size_t i = mCandidates ? (*mCandidates)[k] : k;
            const Box3& b = mOccluder->bounds(i);
            if (b.empty()) continue;
            const Vec3 c = 0.5 * (b.lo + b.hi);
            const double s = std::clamp(glm::dot(c - from, dir), tMin, length - eps);
            const double lower = glm::length(from + s * dir - c) - 0.5 * glm::length(b.hi - b.lo);
            order.emplace_back(std::max(0.0, lower), static_cast<uint32_t>(i));
        }
        std::sort(order.begin(), order.end());
    }
    const size_t visits = clearance ? order.size() : count;
    for (size_t k = 0; k < visits; ++k) {
        const size_t i = clearance ? order[k].second : mCandidates ? (*mCandidates)[k] : k;
        assert(i < mOccluder->size());
        const Box3& bounds = mOccluder->bounds(i);
        if (bounds.empty()) continue;  // Box3::clipRay would accept every ray
        double t = 0.0;
        bool found = false;
        const bool skipClearance = clearance && order[k].first > 0.0 && order[k].first > clearanceMin;
        if (skipClearance) boundMin = std::min(boundMin, order[k].first);
        visitKind(i, [&](const auto& kind) {
            if (clearance && !skipClearance) {
                // Over the whole segment, and around the obstacle as far as its distance is
                // known.
                bool near = true;
                const Clearance ci = kind.clearance(from, dir, invDir, tMin, length - eps, near);
                if (near && ci.bound == 0.0) boundKnown = false;
                boundMin = std::min(boundMin, ci.bound);
                if (near) {
                    touched = true;
                    if (!ci.known()) {
                        if (!ci.leaving)
                            unknownFloor = std::min(unknownFloor, ci.bound > 0.0 ? ci.bound : -1e300);
                    } else if (ci.distance < clearanceMin) {
                        clearanceMin = ci.distance;
                        clearanceAt = ci.at;
                        clearanceNormal = ci.normal;
                        clearanceObstacle = static_cast<int>(i);
                    }
                }
            }
            if (known >= 0) return;  // the answer is known: only the clearance is wanted
            found = kind.hit(from, dir, invDir, bounds, tMin, tMax, t);
        });
        if (!found) continue;
        if (!tHit && !clearance) {
            mLastBlocker = static_cast<int>(i);
            return true;
        }
        hit = true;
        if (t < best) {
            best = t;
            mLastBlocker = static_cast<int>(i);
            // Nothing can be nearer than the start (with a clearance wanted, the other
            // obstacles are still measured, as when the answer is known beforehand).
            if (best <= 0.0 && !clearance) break;
            tMax = std::max(tMin, std::min(tMax, t));
        }
    }
    if (known >= 0) hit = known == 1;
    if (hit && tHit) *tHit = best;
    if (clearance) {
        // Unblocked: every obstacle must be provably away. Blocked: one provably deep is enough.
        if (hit) {
            clearance->bound = boundMin < 0.0 ? boundMin : 0.0;
        } else {
            clearance->bound = boundKnown && boundMin > 0.0
                                   ? (std::isfinite(boundMin) ? boundMin : 1e300)
                                   : 0.0;
        }
    }
    if (clearance && touched && clearanceMin < unknownFloor) {
        clearance->distance = clearanceMin;
        clearance->at = clearanceAt;
        clearance->normal = clearanceNormal;
        clearance->obstacle = clearanceObstacle;
    }
    return hit;
}

namespace {

/// Combines per-obstacle signed radii (> 0 clear, < 0 inside, capped at +-want) into a
/// segment's certificate: a clear segment's radius is the smallest clear one, a blocked one's
/// the largest depth; radiusOthers leaves out the obstacle that decides.
struct RadiusTally {
    double clearMin, clearSecond;
    int clearArg = -1;
    double deepMax = 0.0, deepSecond = 0.0;
    int deepArg = -1;

    explicit RadiusTally(double want) : clearMin(want), clearSecond(want) {}
    void add(double r, size_t i) {
        if (r >= 0.0) {
            if (r < clearMin) {
                clearSecond = clearMin;
                clearMin = r;
                clearArg = static_cast<int>(i);
            } else {
                clearSecond = std::min(clearSecond, r);
            }
        } else if (-r > deepMax) {
            deepSecond = deepMax;
            deepMax = -r;
            deepArg = static_cast<int>(i);
        } else {
            deepSecond = std::max(deepSecond, -r);
        }
    }
    /// Blocked: one obstacle provably deep is enough, the others must stay clear for
    /// radiusOthers. Clear: nothing when some obstacle says inside (bounds disagree with the
    /// answer).
    void finish(bool blocked, Certificate& out) const {
        if (blocked) {
            if (deepArg < 0) return;
            out.radius = deepMax;
            out.obstacle = deepArg;
            out.radiusOthers = deepSecond > 0.0 ? 0.0 : clearMin;
        } else if (deepArg < 0) {
            out.radius = clearMin;
            out.obstacle = clearArg;
            out.radiusOthers = clearSecond;
        }
    }
};

/// The sphere around a box: its radius against a segment bounds the radius against anything
/// inside the box (exact, closed form).
AnalyticSphere sphereAround(const Box3& b) {
    AnalyticSphere s;
    s.center = 0.5 * (b.lo + b.hi);
    s.radius = 0.5 * glm::length(b.hi - b.lo);
    return s;
}

}  // namespace

bool Occluder::Query::occludedCertified(const Vec3& from, const Vec3& to, double want,
                                        double* tHit, Certificate& out) {
    const Vec3 v = to - from;
    const double length = glm::length(v);
    const double eps = segmentEpsilon(length);
    if (!(want > 0.0) || !(length > 2.0 * eps)) {
        double t = -1.0;
        const bool blocked = occluded(from, to, &t);
        if (blocked && tHit) *tHit = t;
        certify(from, to, blocked, t, want, out);
        return blocked;
    }
    ++mRays;
    mLastBlocker = -1;
    out = Certificate{};
    const Vec3 dir = v / length;
    const Vec3 invDir = 1.0 / dir;
    // Per obstacle, as certify() combines them; each obstacle that blocks gives its own hit and
    // the depth after it.
    RadiusTally tally(want);
    double best = std::numeric_limits<double>::infinity();
    const size_t count = mCandidates ? mCandidates->size() : mOccluder->size();
    for (size_t k = 0; k < count; ++k) {
        const size_t i = mCandidates ? (*mCandidates)[k] : k;
        const Box3& bounds = mOccluder->bounds(i);
        if (bounds.empty()) continue;
        double r = want;
        if (sphereRadius(sphereAround(bounds), from, v) < want) {
            double t = 0.0;
            const bool found = visitKind(i, [&](const auto& kind) {
                return kind.hitCertified(from, v, dir, invDir, bounds, length, eps, length - eps,
                                         want, t, r);
            });
            if (found && t < best) {
                best = t;
                mLastBlocker = static_cast<int>(i);
            }
            r = std::clamp(r, -want, want);
        }
        tally.add(r, i);
    }
    const bool blocked = mLastBlocker >= 0;
    if (blocked && tHit) *tHit = best;
    tally.finish(blocked, out);
    return blocked;
}

double Occluder::Query::localMinimum(size_t i, const Vec3& from, const Vec3& to, double t,
                                     double halfWindow, double* at) {
    constexpr double kNan = std::numeric_limits<double>::quiet_NaN();
    if (i >= mImpl->levelSets.size() || !mImpl->levelSets[i]) return kNan;
    LevelSetSlot& slot = *mImpl->levelSets[i];
    const double voxel = slot.grid->voxelSize()[0];
    const double band = 0.98 * double(slot.grid->background());
    const openvdb::Vec3d f0 = slot.grid->worldToIndex(openvdb::Vec3d(from.x, from.y, from.z));
    const openvdb::Vec3d fv = slot.grid->worldToIndex(openvdb::Vec3d(to.x, to.y, to.z)) - f0;
    // Beyond the band a value only says "at least the band away".
    auto phiAt = [&](double s) {
        const double v = sampleTrilinear(slot.accessor, f0 + s * fv);
        return std::abs(v) < band ? v : std::copysign(band, v);
    };
    const double length = glm::length(to - from);
    if (!(length > 0.0) || !(halfWindow > 0.0)) return kNan;
    const double step = 0.5 * voxel / length;
    const int n = std::max(2, static_cast<int>(std::ceil(2.0 * halfWindow / step)));
    const double dt = 2.0 * halfWindow / n;
    double best = std::numeric_limits<double>::infinity(), t0 = t - halfWindow;
    int kBest = -1;
    // Samples every half voxel over the window; where the smallest lies at an end, the window
    // moves on that way (twice at most).
    for (int shift = 0; shift < 3; ++shift) {
        best = std::numeric_limits<double>::infinity();
        kBest = -1;
        for (int k = 0; k <= n; ++k) {
            const double phi = phiAt(t0 + k * dt);
            if (phi < best) best = phi, kBest = k;
        }
        if (kBest > 0 && kBest < n) break;
        t0 += (kBest == 0 ? -1.0 : 1.0) * (n - 1) * dt;
    }
    if (kBest <= 0 || kBest >= n || !(best < 0.9 * band)) return kNan;
    // Golden-section search between the smallest sample's neighbours.
    const GoldenSection g = goldenSection(phiAt, t0 + (kBest - 1) * dt, t0 + (kBest + 1) * dt,
                                          1000, 0.1 * voxel / length);
    double tb = t0 + kBest * dt;
    if (std::min(g.f1, g.f2) < best) best = std::min(g.f1, g.f2), tb = g.f1 < g.f2 ? g.m1 : g.m2;
    if (at) *at = tb;
    return best;
}

void Occluder::Query::certify(const Vec3& from, const Vec3& to, bool blocked, double tHit,
                              double want, Certificate& out) {
    out = Certificate{};
    const Vec3 v = to - from;
    if (!(want > 0.0) || !(glm::dot(v, v) > 0.0)) return;
    // Per obstacle: the signed radius (> 0 clear, < 0 inside), capped at +-want.
    RadiusTally tally(want);
    const size_t count = mCandidates ? mCandidates->size() : mOccluder->size();
    for (size_t k = 0; k < count; ++k) {
        const size_t i = mCandidates ? (*mCandidates)[k] : k;
        const Box3& bounds = mOccluder->bounds(i);
        if (bounds.empty()) continue;
        // Quick bound: the segment's radius against the bounds' circumscribed sphere.
        const double far = sphereRadius(sphereAround(bounds), from, v);
        double r;
        if (far >= want) {
            r = want;
        } else {
            // A blocked segment's first hit inside these bounds: measure the depth there.
            const double length = glm::length(v);
            const Vec3 hitPoint = from + (tHit / length) * v;
            const bool hitHere = blocked && glm::all(glm::greaterThanEqual(hitPoint, bounds.lo)) &&
                                 glm::all(glm::lessThanEqual(hitPoint, bounds.hi));
            r = visitKind(i, [&](const auto& kind) {
                return kind.radius(from, v, want, blocked, hitHere ? tHit / length : -1.0);
            });
            r = std::clamp(r, -want, want);
        }
        tally.add(r, i);
    }
    tally.finish(blocked, out);
}

}  // namespace penumbra
