/// @file occluder.h
/// Boolean visibility between two world-space points against a set of obstacles: OpenVDB
/// level sets (ray-marched with openvdb::tools::LevelSetRayIntersector) and, for tests that must
/// separate the estimator's error from voxelization, exact analytic spheres and boxes.
///
/// Thread safety: an Occluder is immutable once built; each thread calls makeQuery() once and
/// uses its own Query (it holds OpenVDB value accessors, which must not be shared).
#pragma once

#include <cmath>
#include <cstdint>
#include <deque>
#include <limits>
#include <memory>
#include <variant>
#include <vector>

#include "penumbra/level_set.h"
#include "penumbra/math.h"
#include "penumbra/volume.h"

namespace penumbra {

struct AnalyticSphere {
    Vec3 center{0.0};
    double radius = 1.0;
};

struct AnalyticBox {  // axis-aligned
    Vec3 lo{-0.5};
    Vec3 hi{0.5};
};

using ObstacleShape = std::variant<AnalyticSphere, AnalyticBox, LevelSetPtr>;

/// What a level set knows beyond yes or no: how far a shadow segment passes from the nearest
/// surface (distance > 0), or how deep it goes inside (distance < 0), and where (`at`, the
/// distance from the segment's start). Level sets know distances only inside their narrow band;
/// beyond it the clearance is unknown (NaN). Analytic spheres and boxes know it everywhere. `normal` is the unit
/// gradient of the signed distance at that place (zero when unknown): at the segment's closest
/// approach it is perpendicular to the segment, so the plane through the segment's start with
/// this normal is, to first order, the plane of the rays that graze the surface there.
struct Clearance {
    double distance = std::numeric_limits<double>::quiet_NaN();
    double at = 0.0;
    Vec3 normal{0.0};
    int obstacle = -1;  ///< index (in the Occluder) of the obstacle it is measured to
    /// A conservative bound, known more often than `distance`: when the segment is unblocked,
    /// every obstacle surface (of the candidates) stays at least `bound` > 0 away from it; when
    /// blocked, it goes at least -`bound` > 0 deep into an obstacle. 0 when nothing is known.
    /// Signed distances are 1-Lipschitz, so moving the segment's start by less than |bound|
    /// (its end fixed) cannot change the answer: the renderer reuses first-level rays on that.
    double bound = 0.0;
    /// Unknown because the segment only leaves this obstacle: its distance grows all the way
    /// from the start (a ray from a receiver point on the obstacle's own surface). It comes no
    /// nearer than where it starts, so it has no silhouette near the segment, and it does not
    /// hide the other obstacles' distances (Occluder::Query::clearance).
    bool leaving = false;
    bool known() const { return std::isfinite(distance); }
};

/// A visibility certificate for one shadow segment from M to a light point Q: every segment
/// from M to a point Q' with |Q' - Q| < radius has the same answer (blocked or not) as M to Q.
/// For a segment M + t (Q - M), t in [0, 1], that stays clear of an obstacle with signed distance
/// phi(t) > 0, moving Q by d moves the point at fraction t by t d, so (distances being
/// 1-Lipschitz) min_t phi(t) / t is such a radius; for a segment that goes depth delta inside
/// an obstacle at fraction t, delta / t is. Computed from lower bounds on distances and on
/// depths (exact for analytic shapes), and only up to the radius the caller asks for.
struct Certificate {
    double radius = 0.0;  ///< >= 0; 0 proves nothing beyond the segment itself
    /// A clear segment: the obstacle that limits `radius`; a blocked one: the obstacle whose
    /// depth proves it. -1 when no obstacle is near.
    int obstacle = -1;
    /// The radius within which no obstacle but `obstacle` meets any segment from M (0 when
    /// nothing is proven; equal to the asked-for radius when no other obstacle is near).
    double radiusOthers = 0.0;
};

/// Every segment from a point within `pad` of `apex` to a point of a convex planar polygon (a
/// light, or the frame its rays aim into) lies in the pyramid of apex and polygon, grown by `pad`.
/// An obstacle whose bounds lie outside it cannot block such a segment, nor come near one: the
/// queries of one receiver point need not look at it (Query::narrow).
class Pyramid {
public:
    Pyramid(const Vec3& apex, double pad, const std::vector<Vec3>& polygon);
    /// False only when one of the pyramid's planes (its sides through the apex and the
    /// polygon's edges, and the polygon's own plane) has all of `box`, grown by the pad,
    /// strictly outside.
    bool mayMeet(const Box3& box) const;
    /// mayMeet(box), and false also when the grown box is separated from the pyramid by one
    /// of the box's planes or by a plane along a box axis and a pyramid edge (the remaining
    /// separating axes of two convex polyhedra): exact, and some 30 projections dearer.
    bool mayMeetExactly(const Box3& box) const;
    /// False only when the sphere lies farther than the pad from the pyramid (its distance to
    /// the nearest face, edge or corner).
    bool mayMeet(const Vec3& centre, double radius) const;

private:
    struct Plane {
        Vec3 normal;  // inside: dot(normal, x) >= offset
        double offset;
    };
    std::vector<Plane> mPlanes;
    double mPad = 0.0;
    Vec3 mApex{0.0};
    std::vector<Vec3> mPolygon;  // empty when a plane was left out: the plane tests alone
};

/// A participating medium between receivers and lights: a density grid and the extinction per
/// unit density and length (sigma_t = extinction x density).
struct Medium {
    VolumeGridPtr grid;
    double extinction = 1.0;
    Rgb albedo{0.8};  ///< single-scattering albedo: sigma_s = albedo x sigma_t
};

class Occluder {
public:
    Occluder() = default;
    explicit Occluder(std::vector<ObstacleShape> shapes);

    /// Media: they do not block, they attenuate (Query::transmittance). Empty or all-zero
    /// grids are kept (for indices) but never marched.
    void addMedium(Medium medium);
    size_t mediumCount() const { return mMedia.size(); }
    const Medium& medium(size_t i) const { return mMedia[i]; }
    /// World bounds of medium i's active voxels (padded by the interpolation kernel); empty when
    /// it can attenuate nothing.
    const Box3& mediumBounds(size_t i) const { return mMediumBounds[i]; }

    void add(ObstacleShape shape);
    size_t size() const { return mShapes.size(); }
    const ObstacleShape& shape(size_t i) const { return mShapes[i]; }
    /// World-space bounds of obstacle i (level sets: active voxels, padded by one voxel).
    const Box3& bounds(size_t i) const { return mBounds[i]; }
    /// Whether obstacle i may block a segment inside `pyramid`: a box and a sphere around what
    /// can block (level sets: the inside of the band, not its outside; solidBounds()) must
    /// both meet it, and for a level set one of its solid parts (solidParts()).
    bool mayBlockIn(size_t i, const Pyramid& pyramid) const;
    /// A box around what of obstacle i can block a ray (within bounds(i); level sets: the
    /// inside of the band, grown by 1.25 voxels).
    const Box3& solidBounds(size_t i) const { return mSolid[i].box; }
    /// A sphere around the same (centre and radius; radius 0 with an empty solidBounds(i)).
    const Vec3& solidCentre(size_t i) const { return mSolid[i].centre; }
    double solidRadius(size_t i) const { return mSolid[i].radius; }
    /// A level set's solid parts (LevelSet::solidPartsWS: boxes holding every point where it
    /// can block a ray; mayBlockIn asks one of them to meet the pyramid); empty otherwise.
    const std::vector<Box3>& solidParts(size_t i) const { return mSolid[i].parts; }
    /// An oriented box around the same as solidBounds(i) (LevelSet::solidOrientedWS; the
    /// solid box itself for analytic shapes and where no oriented box is tighter).
    const OrientedBox& solidOriented(size_t i) const { return mSolid[i].oriented; }
    /// A ball that blocks every segment meeting it (one that starts outside it).
    static constexpr int kKernelBalls = 8;
    struct KernelBall {
        Vec3 centre{0.0};
        double radius = 0.0;
    };
    /// Balls inside obstacle i: an analytic sphere itself; for a level set, up to kKernelBalls
    /// of the deepest balls its far-field companion finds inside the surface, each moved to the
    /// deepest point near it and as large as the fine grid's values prove (built with the
    /// companion when first asked for); none for other kinds. (Balls of the cell tables'
    /// inside cells, a voxel or two deep, were tried before: no fewer rays; docs/BENCHMARKS.md.)
    const std::vector<KernelBall>& kernelBalls(size_t i) const;
    /// A level set's deep points (found when first asked for): the centre of its fine voxel of
    /// least value, then up to kDeepPoints - 1 more among the voxels at least half as deep, each
    /// the farthest from those before (farthest point sampling), each with its depth as the
    /// radius. They prove nothing: they are where rays most surely meet an obstacle too thin for
    /// kernel balls, spread so that its ends are among them. Empty for other kinds.
    static constexpr int kDeepPoints = 8;
    const std::vector<KernelBall>& deepPoints(size_t i) const;
    /// An analytic box itself (every segment meeting it is blocked); empty for other kinds.
    Box3 kernelBox(size_t i) const;
    /// Smallest voxel size over the level sets, 0 when there are none.
    double minVoxelSize() const { return mMinVoxel; }
    /// Obstacle i's voxel size: 0 for an analytic shape.
    double voxelSize(size_t i) const { return mVoxel[i]; }

    class Query;
    Query makeQuery() const;

    /// Builds every level set's far-field companion and cell tables now (they are otherwise
    /// built on the first clearance or certificate query, by whichever thread asks first while
    /// the others wait): call it before a parallel loop whose shadow rays ask for clearances or
    /// certificates. Once a level set's cell tables exist, every shadow ray against it
    /// sphere-traces them before the intersector (the same answers, sooner).
    void prepareClearance() const;

    /// A level set knows distances only within its narrow band. For the signed clearance of
    /// shadow rays, each level set gets a companion far-field distance grid (4x coarser
    /// voxels, an exterior band of 16 of them), built on first use by any thread.
    struct FarField;

private:
    std::vector<ObstacleShape> mShapes;
    std::vector<std::shared_ptr<FarField>> mFar;  // index-aligned with mShapes; null if analytic
    std::vector<Box3> mBounds;
    struct Solid {
        Box3 box;
        Vec3 centre{0.0};
        double radius = 0.0;
        std::vector<Box3> parts;  // a level set's solid parts (LevelSet::solidPartsWS); may be empty
        OrientedBox oriented;     // solidOriented(i)
    };
    std::vector<Solid> mSolid;  // index-aligned with mShapes
    std::vector<std::vector<KernelBall>> mSphereKernels;  // index-aligned: kernelBalls(i)
    std::vector<double> mVoxel;  // index-aligned with mShapes; 0 if analytic
    double mMinVoxel = 0.0;
    std::vector<Medium> mMedia;
    std::vector<Box3> mMediumBounds;
};

/// Per-thread visibility query. Counts the segment queries it answers (shadow rays).
class Occluder::Query {
public:
    explicit Query(const Occluder& occluder);
    Query(const Query&);
    Query& operator=(const Query&) = delete;
    Query(Query&&) noexcept;
    ~Query();

    /// True when an obstacle blocks the open segment from `from` to `to` (the end points
    /// themselves excluded; callers start rays off the surface). When hidden and `tHit` is not
    /// null, *tHit is the distance from `from` to the nearest hit point. Grazing rays that touch
    /// the surface count as hits.
    bool occluded(const Vec3& from, const Vec3& to, double* tHit = nullptr);

    /// Same answer, and also the segment's signed clearance against the obstacles whose bounds
    /// it crosses (the smallest over them; unknown if any of them cannot tell). Level sets are
    /// sphere-traced along the segment for it, which costs about one more march.
    bool occluded(const Vec3& from, const Vec3& to, double* tHit, Clearance* clearance);

    /// The clearance occluded() returns with the answer `blocked` it gave for this segment,
    /// measured after the fact by callers that need it for some segments only: the same
    /// values, without the intersection march. Not counted as another shadow ray.
    Clearance clearance(const Vec3& from, const Vec3& to, bool blocked);

    /// The certificate of the segment from `from` to `to`, whose answer `blocked` (and, when
    /// blocked, the distance `tHit` from `from` to the first hit) the caller has just obtained
    /// from occluded(). Radii are computed up to `want` (a larger radius is reported as `want`):
    /// ask for what would cover the region of interest; radii far below it are reported as 0.
    /// Costs a march over the obstacles' far-field companions (prepareClearance() builds them);
    /// not counted as a shadow ray.
    void certify(const Vec3& from, const Vec3& to, bool blocked, double tHit, double want,
                 Certificate& out);

    /// occluded() (with the hit distance) and certify() in one, for callers that certify every
    /// ray: the same answer, and a certificate of the same kind. Against a level set, sphere
    /// tracing on its cell tables from the segment's start proves a clear segment's cone on
    /// the way; the intersector looks for a hit only from where that tracing stopped near the
    /// surface. The hit distance may differ from occluded()'s by a small part of a voxel (the
    /// intersector's samples start elsewhere). One shadow ray.
    bool occludedCertified(const Vec3& from, const Vec3& to, double want, double* tHit,
                           Certificate& out);

    /// The smallest value of level-set obstacle i's field, as its rays see it (trilinear), along
    /// the segment from `from` to `to` near the fraction t: sampled every half voxel over the
    /// fractions t +- halfWindow (the window moves on, twice at most, while the smallest sample
    /// lies at its end), then refined by a golden-section search between the smallest sample's
    /// neighbours to a tenth of a voxel along the segment; *at receives its fraction. NaN when obstacle i is not a level set or when
    /// the smallest lies beyond the narrow band or at the window's end. Not a shadow ray: a few
    /// dozen samples of the grid, no march.
    double localMinimum(size_t i, const Vec3& from, const Vec3& to, double t, double halfWindow,
                        double* at);

    /// Transmittance of the segment through the media, exp(-sum of extinction x integral of
    /// density): 1 when it crosses none (then no ray is counted), else one ray. Opaque obstacles
    /// are not looked at.
    double transmittance(const Vec3& from, const Vec3& to);

    /// What reaches `to` from `from`: 0 when an obstacle blocks the segment, else its
    /// transmittance. One ray.
    double transmitted(const Vec3& from, const Vec3& to);

    /// Whether the media (of the restriction, if any) can attenuate some segment from a point
    /// of `origin` to a point of `target` (their bounds overlap the segments' hull): estimators
    /// take their volumetric path only then.
    bool mediaBetween(const Box3& origin, const Box3& target) const;

    /// The extinction (sigma_t, summed over the media in play) and scattering (sigma_s, per
    /// channel) coefficients at a world point: what the camera's march through media needs.
    double extinctionAt(const Vec3& p, Rgb* scattering = nullptr);

    /// An upper bound on the optical depth (sum of extinction x integral of density) of every
    /// segment inside `pyramid`, through the media in play: 0 proves that every such segment
    /// has transmittance 1 exactly (it meets no box of any medium's support, MediumSupport);
    /// otherwise, for each medium whose support it may meet, its extinction times its largest
    /// density times its bounds' diagonal (the longest chord). Not a ray: box tests only.
    /// `featureLength`, when given, receives the smallest MediumSupport::featureLength of the
    /// media it may meet (infinity when none).
    double opticalDepthBound(const Pyramid& pyramid, double* featureLength = nullptr) const;
    /// The smallest MediumSupport::featureLength of the media in play whose bounds `pyramid`
    /// may meet (infinity when none): opticalDepthBound's, without looking at their parts.
    double featureLength(const Pyramid& pyramid) const;

    /// The union of the bounds of the media in play (the restriction's, if any); empty if none.
    Box3 mediaBounds() const;
    /// The bounds of each medium in play (the restriction's, if any), empty ones left out.
    std::vector<Box3> mediumBoxes() const;

    /// Restricts the media the following queries march to those listed (indices into the
    /// Occluder's media); nullptr restores every medium.
    void restrictMediaTo(const std::vector<uint32_t>* media) { mMedia = media; }

    /// Restricts the following queries to the obstacles listed (indices into the Occluder), e.g.
    /// a shaft-culling candidate list; nullptr restores every obstacle. The list must outlive its
    /// use.
    void restrictTo(const std::vector<uint32_t>* candidates) { mCandidates = candidates; }
    /// The obstacles the following queries look at (the restriction, narrowed if it is):
    /// nullptr for every obstacle.
    const std::vector<uint32_t>* restriction() const { return mCandidates; }

    /// Narrows the following queries to the obstacles of the current restriction that
    /// `pyramid` may meet, until the matching widen(); calls nest. Returns how many remain.
    size_t narrow(const Pyramid& pyramid);
    /// Undoes the latest narrow().
    void widen();

    /// The obstacle that blocked the latest occluded() segment (the nearest hit's when its
    /// distance was asked for, else any), -1 when it was unblocked.
    int lastBlocker() const { return mLastBlocker; }

    uint64_t raysCast() const { return mRays; }
    void resetCount() { mRays = 0; }

    /// The occluder this query answers for.
    const Occluder& occluder() const { return *mOccluder; }

private:
    // occluded() with `known` < 0; with known = 0 or 1 the answer is taken as given and only
    // the clearance is measured.
    bool trace(const Vec3& from, const Vec3& to, double* tHit, Clearance* clearance, int known);
    // Calls f with obstacle i's kind (occluder.cpp: AnalyticKind, LevelSetKind).
    template <class F>
    decltype(auto) visitKind(size_t i, F&& f);

    struct Impl;
    const Occluder* mOccluder;
    std::unique_ptr<Impl> mImpl;  // the per-thread OpenVDB intersectors
    const std::vector<uint32_t>* mCandidates = nullptr;
    const std::vector<uint32_t>* mMedia = nullptr;
    uint64_t mRays = 0;
    int mLastBlocker = -1;
    // narrow(): one list per nesting level (kept for reuse) and the restriction each replaced.
    // (a deque: growing it keeps the lists in place, which mCandidates may point to)
    std::deque<std::vector<uint32_t>> mNarrowed;
    std::vector<const std::vector<uint32_t>*> mWidened;
};

/// Narrows a query (Query::narrow) for the lifetime of this object.
class NarrowedQuery {
public:
    NarrowedQuery(Occluder::Query& query, const Pyramid& pyramid)
        : mQuery(query), mRemaining(query.narrow(pyramid)) {}
    ~NarrowedQuery() { mQuery.widen(); }
    NarrowedQuery(const NarrowedQuery&) = delete;
    NarrowedQuery& operator=(const NarrowedQuery&) = delete;
    /// How many obstacles the narrowed query looks at.
    size_t remaining() const { return mRemaining; }

private:
    Occluder::Query& mQuery;
    size_t mRemaining;
};

}  // namespace penumbra
