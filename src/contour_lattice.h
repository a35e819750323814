/// @file contour_lattice.h
/// Private to the contour integrator: the state of one evaluation (the sample lattice, the
/// running contour sums, coverage's bookkeeping) and the per-sample and per-evaluation data.
/// Lattice's members are defined by idea, one source file each:
///
///   contour_integrator.cpp  the public class; the lattice's samples and their rays
///   contour_squares.cpp     Vedel's sections 3.1-3.2: passes over the first-level grid,
///                           marching squares with centre rays for saddles, dichotomy on the
///                           shared lattice, the check point and refinement, and the
///                           inconsistencies that restart the light one level deeper
///   contour_tangent.cpp     distance-guided dichotomy, Newton placement of vertices, arcs
///                           tangent to the silhouette (the default tangent mode)
///   contour_coverage.cpp    certified coverage: discs, uncovered cells, contradictions, the
///                           error bound, and the one ray that can cover the whole light
///   contour_border.cpp      what emits: the receiver's horizon, a polygon light's cutting
///                           edges and a disc light's circle, walked exactly
///
/// Included only by those files (it brings the names of namespace `aci` into `penumbra`).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "light_footprint.h"
#include "penumbra/contour_integrator.h"

namespace penumbra {
namespace aci {

// What a sample's ray measured of the nearest surface (tangent mode): the distance gradient
// at its closest approach, where that is along the ray, and which obstacle.
struct RayGeometry {
    float normal[3] = {0.0f, 0.0f, 0.0f};  // 0: unknown
    float closest = 0.0f;                  // fraction of the ray; 0: unknown
    float obstacle = -1.0f;                // the obstacle's index; -1: unknown
    float stale = 0.0f;                    // 1: an earlier receiver point's ray (reuseCorners)
    float hider = -1.0f;                   // the obstacle nearest M that blocks it; -1: none
};

// One traced ray as a lattice sample keeps it, and as reuseCorners keeps a first-level one.
struct Corner {
    Vec3 origin{0.0};
    double bound = 0.0;  // Clearance::bound of the ray (0: cannot be reused)
    float sample = 0.0f, clear = 0.0f;
    RayGeometry geometry;
    Certificate cert;  // with AciSettings::coverage
    int blocker = -1;  // the obstacle that blocked it (Occluder::Query::lastBlocker)
    // Whether this ray's answer holds for a ray from `from` to the same light point.
    bool answers(const Vec3& from) const {
        return bound != 0.0 && glm::length(from - origin) < std::abs(bound);
    }
};

struct Disc {
    Vec3 c;    // centre on the light
    double r;  // radius of the certificate (Certificate::radius)
};
struct Segment {  // a piece of located contour
    Vec3 a, b;
    bool border = false;  // on the border of what emits (exact: nothing to prove near it)
};
struct Leaf {  // a square closed by the last pass
    int x0, y0, s;
    int type;  // 0 hidden, 1 visible, 2 contour (segments seg0 .. seg1)
    uint32_t seg0, seg1;
};
struct Uncovered {  // a cell of the light no disc proves yet
    double a0, b0, size;  // lattice coordinates
    double gap;           // its centre's distance to the nearest disc that would prove it
    Vec3 centre;
    double key = 0.0;  // how far it reaches from proven ground (Lattice::coverageKey), -inf once exhausted
    double weight = 0.0;  // coverage's order: key x weight (Lattice::coverageWeight)
    bool exhausted = false;  // every lattice point coverage may ask in it is traced
    bool dead = false;       // covered, or replaced by its quarters (nextCoverageSample)
    size_t seen = 0;         // the traced discs its gap and key have taken in
    /// The largest disc a ray at its centre could prove: the least over the certified samples
    /// so far of their distance plus their radius (a clear segment's radius changes no faster
    /// than its end on the light moves). Coverage's order, not its stopping rule.
    double reach = std::numeric_limits<double>::infinity();
    size_t probed = 0;  // the certified samples its reach has taken in
};

/// Whether a disc light is one segment of its part above a receiver's horizon (its frame the
/// rectangle on the segment's chord, corner on the circle; contour_integrator.cpp,
/// discPiecesAboveHorizon) rather than the whole disc on its square.
bool isDiscPiece(const RectLight& light);

constexpr float kVisible = -1.0f;
constexpr float kBelowHorizon = -2.0f;  // hidden by the receiver's own tangent plane, no ray
// Scratch::mPending, bits: the sample's clearance is not measured yet (traced: kPendingClearance;
// answered by the footprints, no ray: kPendingUntraced), and its hit fraction is only an
// estimate (a level set's kernel ball: the surface lies before it; hitFraction() traces then).
constexpr uint8_t kPendingClearance = 1;
constexpr uint8_t kPendingUntraced = 2;
constexpr uint8_t kPendingHit = 4;
constexpr int kHorizonContour = -2;     // Vertex::obstacle of a vertex on the horizon line
// With coverage: an evaluation whose coverage rays ran out with more than this share of the
// light's area unproven restarts once one level deeper (contour_integrator.cpp).
constexpr double kEscalateUnproven = 0.8;
// AciSettings::adaptiveSteps: one dichotomy step fewer where every footprint on the light is at
// least this many units of the finer lattice wide.
constexpr double kAdaptiveWidth = 16.0;
// ... and where no footprint cuts from a disc or polygon light a sliver narrower than that
// whose form factor exceeds this share of the unoccluded one (LightFootprints::thinSliver): a
// box's shadow reaching two units into a disc along its rim fell between the coarser lattice
// and the circle, 0.26% of F missed (bench_random --lights mixed, seed 941).
constexpr double kSliverShare = 1e-3;
// A finer lattice (evaluate()) while a cell of it, seen straight on at the light's distance,
// would carry more than this form factor (unit^2 / (pi d^2)) and a footprint is narrower than
// kAdaptiveWidth cells; up to this many lattice units along the longer edge.
constexpr double kFineCellFormFactor = 5e-4;
constexpr int kMaxFinerLattice = 512;
constexpr int kMaxRepasses = 64;        // coverage passes at one level after the first
// Times an evaluation starts again one step finer because a sample contradicts every contour
// its lattice allows (evaluate()).
constexpr int kMaxFinerRedos = 2;
// Coverage aims its first rays of a pass at most this many middles of obstacles near the light
// (where rays pass nearest their kernel balls' and solid spheres' centres; contour_integrator.cpp).
constexpr size_t kMaxMiddles = 64;
// Coverage cells, in lattice units: one final dichotomy interval, so that a cell's centre is
// within half an interval of its every point and the stopping rule on centres (every uncovered
// point within coverageGap intervals of proven ground) holds for points. With cells of 8 units a
// shadow of 1.8 intervals' radius could hide between centres (seed 17 of the random sphere scenes).
constexpr double kCoverageCell = 2.0;
// Coverage: a visible ray proving less than a lattice unit with no located contour piece within
// this many units aims one more ray across the silhouette its clearance predicts
// (Lattice::acrossNearSilhouette).
constexpr double kSilhouetteAimReach = 4.0;
// A thin level set's deep point (Occluder::deepPoints) gets a coverage middle when the light
// point whose ray passes nearest it lies within this many times its depth: the obstacle reaches
// beyond the ball the depth proves (a capsule's end cap hid 4.3% of F0 from a far ground point
// with its rim: found with three depths, not with two; bench_bounds --lights mixed --fog, seed
// 8510).
constexpr double kDeepPointReach = 3.0;
constexpr double kScanCell = 8.0;  // cells of the first scan, quartered where it matters
// A ray passing closest to a surface within this many ray offsets of its start grazes the
// receiver's own surface (untrustedTangent).
constexpr double kOwnSurfaceOffsets = 8.0;
// A ray whose closest approach to a level set is so near its start that one of its voxels spans
// more than this many lattice units on the light gives no tangent (untrustedTangent). (16 until
// 2026-12-01: on the bunny's back, shadowed by its own head, 6 of 824 sampled points came out
// 6-9 8-bit units off, the tangents of surface a few tens of voxels from the receiver; at 4 the
// largest is 0.35, for 10% more rays there and under 1% on random scenes.)
constexpr double kMagnifiedVoxel = 4.0;
// The weight w with which the polygon X Z Y, emitted as w (X->Z) + w (Z->Y) + (1 - w) (X->Y),
// integrates the parabolic arc through X, Z and Y (on the light): the area between the arc and
// its chord is the triangle XZY divided by 3 s (1 - s), s being Z's position along the chord
// (Archimedes: 4/3 of the triangle when Z is the apex, s = 1/2), s kept within [0.15, 0.85].
inline double parabolaWeight(const Vec3& x, const Vec3& z, const Vec3& y) {
    const Vec3 chord = y - x;
    const double len2 = glm::dot(chord, chord);
    const double s = std::clamp(len2 > 0.0 ? glm::dot(z - x, chord) / len2 : 0.5, 0.15, 0.85);
    return 1.0 / (3.0 * s * (1.0 - s));
}

// The area between a conic arc and its chord over the area of its tangent triangle (the
// chord's ends and the meeting point of their tangent lines), for the arc as a rational
// quadratic Bezier curve of weight w on that triangle: 2/3 for a parabola (w = 1), towards 0
// for a flat ellipse (w -> 0) and 1 for a hyperbola hugging its corner (w -> infinity).
inline double conicSegmentShare(double w) {
    if (!(w > 0.0)) return 0.0;
    if (!std::isfinite(w)) return 1.0;
    const double d = w - 1.0;
    if (std::abs(d) < 1e-4) return 2.0 / 3.0 + (4.0 / 15.0) * d;  // the closed forms cancel there
    if (w < 1.0) {
        const double q = std::sqrt(1.0 - w * w);
        return w / (q * q) * (std::acos(w) / q - w);
    }
    const double q = std::sqrt(w * w - 1.0);
    return w / (q * q) * (w - std::acosh(w) / q);
}

// fieldRoot: secant steps on the level set's own field after its first one or two values (each
// a dozen or so samples of the grid), how far (in voxels, along the ray) from the previous
// closest approach the new one is looked for, and the field's value (in voxels) that counts as
// zero. On random scene 605 (2026-12-02) three steps, three voxels and 0.005 took 11% more time
// for the same image (mean difference 0.0053 both). That zero is also at most the field's change
// over kFieldRootUnitShare of a lattice unit on the light: where the obstacle is close to the
// receiver point, one voxel spans many units, and 0.02 voxel was most of a unit, all on the
// side the secant came from (bench_random --lights mixed seed 946, a box 0.066 above the
// ground: points under it came out 0.2% of F0 too dark, halving with each dichotomy step
// added; 0.02-0.06% after).
constexpr int kFieldRootSteps = 2;
constexpr double kFieldRootWindow = 1.5;
constexpr double kFieldRootTolerance = 0.02;
constexpr double kFieldRootUnitShare = 0.05;
// A contour square wider than this many times its distance from the receiver point is split
// before its contour is built (nearReceiver).
constexpr double kNearReceiver = 2.0;
// With coverage, the section 3.2 strip threshold is this fraction of the paper's: finer contour
// squares make strips that prove more ground, so coverage spends fewer rays (random seed 5 of
// bench_random: 62.6 -> 51.9 rays per viewing ray, mean difference 0.022 -> 0.010, at a quarter).
// A sixteenth since 2026-11-29 (fifth session): a check that passed a quarter left a level-set
// torus' shadow 3.5% short on random seed 6, where its error concentrated (docs/BENCHMARKS.md).
constexpr double kCoverageThreshold = 0.0625;

struct LatticePoint {
    int a, b;
};

inline LatticePoint midpoint(LatticePoint p, LatticePoint q) { return {(p.a + q.a) / 2, (p.b + q.b) / 2}; }

// A contour vertex: C on the light, I on the obstacle along the same ray from M (Fig. 5).
struct Vertex {
    Vec3 c;
    Vec3 i;
    Vec3 plane{0.0};  // tangentContour: unit normal of the grazing plane through M (0 unknown)
    int obstacle = -1;  // tangentContour: the obstacle whose silhouette it is on (-1 unknown)
    int clip = -1;      // on the border of what emits (kClipHorizon, kClipDisc, or a cut's index)
};

constexpr int kClipHorizon = 1000;  // Vertex::clip: the receiver's horizon line
constexpr int kClipDisc = 1001;     // Vertex::clip: a disc light's circle
// In a walk along the border (emitBorder) only: the frame's four sides, kClipFrame + side
// (bottom, right, top, left), along which a polygon on its own frame may run between cuts.
constexpr int kClipFrame = 2000;

}  // namespace aci

using namespace aci;  // NOLINT(google-build-using-namespace): a private header of five files

struct ContourIntegrator::Scratch {
    std::vector<Corner> mCorners;  // (pa+1) x (pb+1) for mCornerGrid and mCornerLight; empty: none
    FirstLevelGrid mCornerGrid;
    RectLight mCornerLight;
    Corner* reusableCorner(const RectLight& light, FirstLevelGrid grid, int i, int j);
    std::vector<uint32_t> mStamp;  // generation stamps of the sample lattice
    std::vector<float> mSample;    // >= 0: hidden, hit fraction along the ray; -1 visible
    std::vector<float> mClear;     // signed angular clearance of the sample's ray, NaN unknown
    std::vector<uint8_t> mPending;  // kPendingClearance, kPendingUntraced, kPendingHit
    std::vector<RayGeometry> mGeometry;  // tangent mode: each sample's ray geometry
    std::vector<Certificate> mCert;  // coverage: each sample's certificate
    std::vector<Uncovered> mUncovered;  // coverage: the current pass's uncovered cells
    LightFootprints mFootprints;  // coverage: the obstacles' footprints on the light
    // Coverage's queue: (priority, index into mUncovered), a max-heap whose priorities may be stale, but
    // never low (nextCoverageSample).
    std::vector<std::pair<double, uint32_t>> mCoverageHeap;
    std::vector<Disc> mDiscs;        // coverage scratch: discs near one leaf
    std::vector<Segment> mSegs;      // coverage: the last pass's contour segments
    std::vector<Segment> mNearSegs;  // coverage scratch: segments near one leaf
    std::vector<Leaf> mLeaves;       // coverage: the last pass's leaves
    std::vector<uint32_t> mMarked;   // coverage: samples that contradicted the last pass
    std::vector<uint32_t> mTraced;   // coverage: lattice indices with a certificate this time
    std::vector<Disc> mTracedDiscs;  // coverage: their discs, in the same order
    // coverage: every sample certified this time (radius 0 too, as the most a reported 0 may
    // hide), for Uncovered::reach
    std::vector<Disc> mProbed;
    std::vector<uint32_t> mAllTraced;  // coverage: every lattice index traced this time
    std::vector<uint32_t> mBlockers;   // the obstacles that blocked rays this time (repeats)
    // recordContour: the current pass's emitted edges on the light's plane, and whether they
    // can stand for its G (no disc arc, every point projected).
    std::vector<ContourEdge> mPassEdges;
    bool mPassEdgesValid = true;
    uint32_t mGeneration = 0;
    // Coverage's spatial index: one bucket per first-level square of the base grid (pa x pb),
    // each listing, in index order, the discs (mTracedDiscs), contour segments (mSegs) and
    // leaves (mLeaves) that may matter for a square inside it. Lists are supersets of what the
    // scans keep, so answers are those of a scan of everything.
    std::vector<std::vector<uint32_t>> mDiscBuckets, mSegBuckets, mLeafBuckets;
};

// One evaluation at one receiver point: the sample lattice and the running contour sums.
//
// The lattice has Na = pa * 2^(n+1) units along the light's first edge (edgeU) and
// Nb = pb * 2^(n+1) along its second, for a first level of pa x pb squares (firstLevelGrid), so
// that a first-level square has side 2^(n+1) units and a dichotomy of n steps ends on an
// interval of 2 units: its midpoint, the contour vertex, and every centre and semi-diagonal
// point are lattice points too. A square of side 2^(k+1) gets k dichotomy steps; refinement and
// restarts both lower k by one. Squares are squares of lattice units; a unit's world length
// differs along the two edges only as much as the light's aspect differs from pa / pb.
struct ContourIntegrator::Lattice {
    ContourIntegrator& self;
    Scratch& scratch;
    const Receiver& rec;
    const RectLight& light;
    Occluder::Query& query;
    int pa, pb, n;  // first-level squares along each edge; dichotomy steps
    int Na, Nb;     // lattice units along each edge
    // The evaluation took one dichotomy step fewer than asked (AciSettings::adaptiveSteps): its
    // lattice unit is twice the finer one's, and tangent arcs are probed closer (arcHolds) and
    // at more places along long pieces (tangentArc).
    bool coarser = false;
    Vec3 origin;
    Vec3 lightNormal;
    double epsWorld;  // world length of the final dichotomy interval (the strip width; the
                      // two edges' average)
    double want;      // coverage: the radius that covers the whole light from any of its points
    double wantSquare;  // coverage: the radius that covers a corner's first-level squares
    bool wantWhole = false;  // coverage: the next ray asks for `want` (wholeLight's)
    double bound = 0.0;  // coverage: the running error bound (Estimate::errorBound)
    double unit;         // world length of one lattice unit (averaged over the two edges)
    double cellReach;    // coverage: a cell's farthest point from its centre, per unit of side
    int bucketSide;      // coverage: lattice units per bucket (a first-level square's side)
    double bucketReach;  // coverage: a bucket's farthest point from its centre
    double perUnitA, perUnitB;  // coverage: lattice units per world length across each edge
    // What emits: the frame above the horizon, inside a polygon light's cutting edges and a disc
    // light's circle. Points outside are hidden without a ray (kBelowHorizon).
    std::vector<LightEdge> cuts;
    bool shaped = false;  // a polygon or disc light: contour pieces along its border are exact
    bool horizonFree = false;  // a disc piece: wholly above the horizon (above() is infinite)
    // A polygon light whose corners are not its frame's, integrated on that frame: its corners
    // in lattice coordinates (polygonPoke()); empty otherwise.
    std::vector<Vec2> polyCorners;
    // Its frame's sides as lines (origin, inward normal), bottom, right, top, left: the walk
    // along the border follows them where the polygon's edges lie on them.
    std::vector<LightEdge> frameSides;
    bool mScanned = false;  // coverage: this pass's leaves are scanned for uncovered cells
    bool certifyNext = false;  // coverage: certify the next traced ray although not first-level
    int passLevel = 0;         // the restart level of the current pass
    bool remark = false;       // coverage: the pass marked new samples and must run again
    mutable AciCounts counts;  // settle() counts the clearances of untraced samples
    Vec3 g{0.0};
    Mat3 dg{0.0};

    // ----- Samples: one ray per lattice point and evaluation (contour_integrator.cpp) -----
    // footprintsBuilt: scratch.mFootprints already holds this origin's footprints.
    Lattice(ContourIntegrator& s, const Receiver& r, const RectLight& l, Occluder::Query& q,
            FirstLevelGrid grid, int steps, bool footprintsBuilt = false);
    float& sample(LatticePoint q, bool firstLevel);
    size_t settle(LatticePoint q) const;
    // Hidden sample q's hit fraction (where its segment first meets a surface), its ray traced
    // now when the footprints left only an estimate and the gradient needs the 3D point.
    float hitFraction(LatticePoint q);

    Vec3 pointOf(LatticePoint q) const { return at(q.a, q.b); }
    // The light point at lattice coordinates (a, b), which need not be integers.
    Vec3 at(double a, double b) const { return light.point(a / Na, b / Nb); }
    size_t index(LatticePoint q) const { return static_cast<size_t>(q.b) * (Na + 1) + q.a; }
    // The lattice point nearest to light point p, clamped into the square (x0, y0, side s).
    LatticePoint nearestInSquare(const Vec3& p, int x0, int y0, int s) const {
        const Vec2 uv = light.coordinates(p);
        return {std::clamp(static_cast<int>(std::lround(uv.x * Na)), x0, x0 + s),
                std::clamp(static_cast<int>(std::lround(uv.y * Nb)), y0, y0 + s)};
    }
    bool visible(LatticePoint q, bool firstLevel = false) { return sample(q, firstLevel) == kVisible; }
    float peek(LatticePoint q) const {
        return scratch.mSample[index(q)];
    }
    bool traced(LatticePoint q) const {
        return scratch.mStamp[index(q)] == scratch.mGeneration;
    }
    // The form factor of the contour edge a -> b (Lambert's term, seen from the receiver).
    double edgeF(const Vec3& a, const Vec3& b) const {
        return glm::dot(edgeG(a - rec.point, b - rec.point), rec.normal) / (2.0 * kPi);
    }
    // Narrows the bracket lo -> hi (visible, hidden; positions of `at`) with samples traced
    // between them for other reasons: free information a vertex must agree with.
    template <class At>
    void narrowByTraced(const At& at, int& lo, int& hi) const {
        for (int j = lo + 1; j < hi; ++j) {
            if (!traced(at(j))) continue;
            if (peek(at(j)) == kVisible) {
                lo = j;
            } else {
                hi = j;
                break;
            }
        }
    }

    // A tangent-mode contour piece: the conic arc tangent to both ends' silhouettes, which
    // meet at k (contour_tangent.cpp, tangentArc).
    struct Arc {
        Vec3 k{0.0};
        double w = 1.0;
        bool straight = false;
        bool probed = false;  // its weight was placed by a shoulder ray
    };

    // One contour piece of a square (section 3.1): from the crossing where the contour leaves the
    // visible part (walking counterclockwise) to where it comes back, cutting off one corner
    // through which its check runs (checkVis -> checkHid, checkSteps dichotomy steps).
    struct Piece {
        int exitSide, entrySide;  // the sides (0-3, side i from corner i to i+1) it crosses
        LatticePoint checkVis, checkHid;
        int checkSteps;
        bool midline = false;  // checked on the square's midline (AciSettings::midlineCheck)
        bool border = false;   // along the border of what emits: exact, no check
        bool arcOk = false;    // `arc` stands for it (tangent mode)
        Arc arc;
        Vertex z;  // its check point (section 3.2), when neither border nor arc
    };

    // ----- Section 3: passes, squares, dichotomy, checks (contour_squares.cpp) -----
    bool pass(int r);
    bool square(int x0, int y0, int k, double thr, int depth);
    int contourPieces(int x0, int y0, int k, const LatticePoint c[4], const bool v[4],
                      const Vertex x[4], Piece pieces[2]);
    void lopsidedCheck(Piece& pc, const LatticePoint c[4], const bool v[4], const Vertex x[4],
                       int corner, int s) const;
    void emitPiece(const Vertex& a, const Vertex& b, const Piece& pc);
    void emitFrameBorder(const LatticePoint c[4], const bool v[4], const Vertex x[4],
                         const bool onBorder[4]);
    bool split(int x0, int y0, int k, double thr, int depth, const bool v[4], const bool onBorder[4]);
    Vertex crossing(LatticePoint vis, LatticePoint hid, int steps);
    const Vertex* knownCrossing(LatticePoint vis, LatticePoint hid);
    Vertex crossingOnSegment(LatticePoint vis, LatticePoint hid, int steps, LatticePoint& finalVis,
                             LatticePoint& finalHid);
    // `hit`: place the 3D point at the hidden end's hit fraction (false: the caller places it).
    Vertex vertexBetween(LatticePoint vis, LatticePoint hid, double f, bool hit = true);
    void emit(const Vec3& a, const Vec3& b, double weight = 1.0);
    struct KnownCrossing {
        LatticePoint vis, hid;  // its final bracket
        Vertex v;
        double at;  // where v lies on the lattice line, in lattice units
    };
    std::vector<KnownCrossing> crossings;  // distance-guided modes: crossings of lattice lines
    bool crossingAgrees(const KnownCrossing& k) const;
    void dropContradictedCrossings();

    // ----- Distance-guided and tangent geometry (contour_tangent.cpp) -----
    float clearanceOf(LatticePoint q) const;
    Vec3 normalOf(LatticePoint q) const;
    double closestFractionOf(LatticePoint q) const;
    bool staleOf(LatticePoint q) const;
    int obstacleOf(LatticePoint q) const;
    int hiderOf(LatticePoint q) const;
    double newtonAlong(LatticePoint q, const Vec3& from, const Vec3& dir) const;
    LatticePoint acrossNearSilhouette(LatticePoint q);
    double fieldRoot(LatticePoint q, const Vec3& from, const Vec3& dir, double xq, double guess,
                     double lo, double hi, bool visibleLo);
    Vec3 grazingPlane(LatticePoint q, const Vec3& onContour) const;
    bool untrustedTangent(LatticePoint q) const;
    bool nearOwnStart(LatticePoint q) const;
    bool nearReceiver(int x0, int y0, int s) const;
    bool polygonPoke(int x0, int y0, int s, const LatticePoint c[4], int nVisible) const;
    // The section 3.2 strip threshold's factor: with coverage a sixteenth of the paper's, and on
    // the coarser lattice (adaptive steps) half that, so that its strips, twice as wide as the
    // finer lattice's, ask for the finer lattice's accuracy (the bunny's ground: 6% less error
    // for 2.6% more rays; Table 1 1.4% more rays).
    double coverageThreshold() const {
        if (!self.mSettings.coverage) return 1.0;
        return coarser ? 0.5 * kCoverageThreshold : kCoverageThreshold;
    }
    bool arcHolds(const Vertex& a, const Vertex& b, const Vec3& mid, int x0, int y0, int s);
    Vertex crossingNewton(LatticePoint vis, LatticePoint hid, int steps, LatticePoint& finalVis,
                          LatticePoint& finalHid);
    bool tangentArc(const Vertex& a, const Vertex& b, int x0, int y0, int s, double thr, Arc& arc);
    void emitArc(const Vertex& a, const Vertex& b, const Arc& arc);

    // ----- Coverage and the error bound (contour_coverage.cpp) -----
    bool wholeLight();
    void emitWhole();
    double wholeFormFactor() const;
    bool cellInDisc(double a0, double b0, double size, const Vec3& centre) const;
    bool mayHold(const Disc& d, double dist, double reach) const;
    bool cellOutside(double a0, double b0, double size) const;
    void findFootprints();
    bool outsideFootprints(double a0, double b0, double a1, double b1) const;
    static constexpr int kFootprintUnknown = -2;
    bool footprintProves(double a0, double b0, double size, int& footprint) const;
    static double distanceToSegment(const Vec3& p, const Segment& g);
    static double distance2ToSegment(const Vec3& p, const Segment& g);
    void recordCertificate(size_t idx, LatticePoint q, const Certificate& c, double floor = -1.0);
    void noteBlocker(int b);
    // How far from a contour segment coverage looks at it: its gaps (a cell within coverageGap x
    // epsilon of a piece's strip is near proven ground) and uncoveredCells' final test (within
    // epsilon of a piece).
    double segmentReach() const { return (1.0 + self.mSettings.coverageGap) * epsWorld; }
    // `footprint`: the footprints' classification of the cell, when known; `checked`:
    // provenWithoutDiscs() is known false for the cell itself.
    void uncoveredCells(double a0, double b0, double size, double minSize,
                        int footprint = kFootprintUnknown, bool checked = false) const;
    bool provenWithoutDiscs(double a0, double b0, double size, int& footprint) const;
    static void gapTo(Uncovered& u, const Disc& d, double dist);
    double coverageKey(const Uncovered& u) const;
    double coveragePriority(const Uncovered& u) const;
    double coverageWeight(const Vec3& centre) const;
    double uncoveredFormFactor() const;
    double finalUncoveredFormFactor();
    void gatherNear(int x0, int y0, int s);
    bool nextCoverageSample(LatticePoint& out, bool giveUp);
    bool markedInside(int x0, int y0, int s, int uniform) const;
    bool contradicts(uint32_t idx, bool farOnly = false) const;
    int nearestSide(const Leaf& leaf, const Vec3& p, double& best) const;
    int predicted(LatticePoint q) const;
    double junctionAllowance(const Vertex& a, const Vertex& b, const LatticePoint c[4]) const;
    void recordContourLeaf(int x0, int y0, int s, const Vertex x[4], const Piece pieces[2],
                           int nPieces);
    // The spatial index (contour_coverage.cpp).
    Vec3 bucketCentre(int i, int j) const;
    template <class Keep>
    void addToBuckets(std::vector<std::vector<uint32_t>>& buckets, uint32_t index, double a0,
                      double b0, double a1, double b1, double reach, const Keep& keep);
    void addDisc(uint32_t index, LatticePoint at);
    void addLeaf(const Leaf& leaf);
    void addSegments(uint32_t seg0);
    int bucketOf(int x0, int y0, int s) const;
    template <class F>
    bool forLeavesHolding(LatticePoint q, const F& f) const;

    // ----- What emits (contour_border.cpp) -----
    // Height of a light point above the receiver's tangent plane.
    // How far p lies above the receiver's horizon; infinite for a disc piece (isDiscPiece),
    // which lies wholly above it (it was cut there) but for the rounding of the corner where
    // its chord meets the horizon: with that corner taken as on either side, one of a cut
    // disc's pieces came out 2.6e-4 of itself off in the paper's mode.
    double above(const Vec3& p) const {
        return horizonFree ? std::numeric_limits<double>::infinity() : glm::dot(p - rec.point, rec.normal);
    }
    double cutValue(size_t i, const Vec3& p) const { return glm::dot(p - cuts[i].origin, cuts[i].inward); }
    bool emits(const Vec3& p) const;
    Vec3 inwardAt(int clip, const Vec3& p) const;
    double borderCrossing(const Vec3& pv, const Vec3& ph, int& clip) const;
    bool emitBorder(const Vertex& a, const Vertex& b, bool dryRun, double& length);
    bool alongBorder(const Vertex& a, const Vertex& b, int s);
};

}  // namespace penumbra
