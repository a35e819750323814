#include "penumbra/contour_integrator.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "penumbra/error.h"

namespace penumbra {

// ---------------------------------------------------------------------------------------------
// Per-sample and per-evaluation data

namespace {

// What a sample's ray measured of the nearest surface (tangent mode): the distance gradient
// at its closest approach, where that is along the ray, and which obstacle.
struct RayGeometry {
    float normal[3] = {0.0f, 0.0f, 0.0f};  // 0: unknown
    float closest = 0.0f;                  // fraction of the ray; 0: unknown
    float obstacle = -1.0f;                // the obstacle's index; -1: unknown
    float stale = 0.0f;                    // 1: an earlier receiver point's ray (reuseCorners)
};

// One traced ray as a lattice sample keeps it, and as reuseCorners keeps a first-level one.
struct Corner {
    Vec3 origin{0.0};
    double bound = 0.0;  // Clearance::bound of the ray (0: cannot be reused)
    float sample = 0.0f, clear = 0.0f;
    RayGeometry geometry;
    Certificate cert;  // with AciSettings::coverage
    // Whether this ray's answer holds for a ray from `from` to the same light point.
    bool answers(const Vec3& from) const {
        return bound != 0.0 && glm::length(from - origin) < std::abs(bound);
    }
};

struct Disc {
    Vec3 c;        // centre on the light
    double r2;     // squared radius of the full certificate
    double ro2;    // squared radius that excludes every obstacle but `obstacle`
    int obstacle;  // Certificate::obstacle
};
struct Segment {  // a piece of located contour and the band around it
    Vec3 a, b;
    double width;
    int own;  // its obstacle, -1 unknown or mixed
    bool border = false;  // on the border of what emits (exact: nothing to prove near it)
};
struct Leaf {  // a square closed by the last pass
    int x0, y0, s;
    int type;  // 0 hidden, 1 visible, 2 contour (segments seg0 .. seg1)
    uint32_t seg0, seg1;
};
struct Uncovered {  // a cell of the light no disc or band proves yet
    double a0, b0, size;  // lattice coordinates
    double gap;           // its centre's distance to the nearest disc that would prove it
    int own;              // the obstacle of the contour band it is in, -1 none
    Vec3 centre;
    bool exhausted = false;  // every lattice point coverage may ask in it is traced
};

}  // namespace

struct ContourIntegrator::Scratch {
    std::vector<Corner> mCorners;  // (p+1)^2 for mCornerGrid and mCornerLight; empty: none
    int mCornerGrid = 0;
    RectLight mCornerLight;
    Corner* reusableCorner(const RectLight& light, int grid, int i, int j);
    std::vector<uint32_t> mStamp;  // generation stamps of the sample lattice
    std::vector<float> mSample;    // >= 0: hidden, hit fraction along the ray; -1 visible
    std::vector<float> mClear;     // signed angular clearance of the sample's ray, NaN unknown
    std::vector<uint8_t> mPending;  // 1: the sample's clearance is not measured yet
    std::vector<RayGeometry> mGeometry;  // tangent mode: each sample's ray geometry
    std::vector<Certificate> mCert;  // coverage: each sample's certificate
    std::vector<Uncovered> mUncovered;  // coverage: the current pass's uncovered cells
    std::vector<Disc> mDiscs;        // coverage scratch: discs near one leaf
    std::vector<Segment> mSegs;      // coverage: the last pass's contour segments
    std::vector<Segment> mNearSegs;  // coverage scratch: segments near one leaf
    std::vector<Leaf> mLeaves;       // coverage: the last pass's leaves
    std::vector<uint32_t> mMarked;   // coverage: samples that contradicted the last pass
    std::vector<uint32_t> mTraced;   // coverage: lattice indices with a certificate this time
    std::vector<uint32_t> mAllTraced;  // coverage: every lattice index traced this time
    uint32_t mGeneration = 0;
};

namespace {

constexpr float kVisible = -1.0f;
constexpr float kBelowHorizon = -2.0f;  // hidden by the receiver's own tangent plane, no ray
constexpr int kHorizonContour = -2;     // Vertex::obstacle of a vertex on the horizon line
constexpr int kMaxRepasses = 64;        // coverage passes at one level after the first
// Coverage cells, in lattice units: one final dichotomy interval, so that a cell's centre is
// within half an interval of its every point and the stopping rule on centres (every uncovered
// point within coverageGap intervals of proven ground) holds for points. With cells of 8 units a
// shadow of 1.8 intervals' radius could hide between centres (seed 17 of the random sphere scenes).
constexpr double kCoverageCell = 2.0;
constexpr double kScanCell = 8.0;  // cells of the first scan, quartered where it matters
constexpr double kHalfSqrt2 = 0.7071067811865476;
// tangentContour keeps per sample: the distance gradient (3), where the ray passes closest as a
// fraction of its length, the obstacle it was measured to, and 1 when the sample was answered by
// an earlier receiver point's ray (reuseCorners: its distances are approximate).

struct LatticePoint {
    int a, b;
};

LatticePoint midpoint(LatticePoint p, LatticePoint q) { return {(p.a + q.a) / 2, (p.b + q.b) / 2}; }

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

// Fills what a ray's clearance `c` tells the tangent mode: the angular clearance and, in
// `g`, the distance gradient, the closest approach's fraction and the obstacle.
void recordClearance(const Clearance& c, double len, float& clear, RayGeometry& g) {
    const bool known = c.known() && c.at > 0.0;
    clear = known ? static_cast<float>(c.distance / c.at) : std::numeric_limits<float>::quiet_NaN();
    for (int k = 0; k < 3; ++k) g.normal[k] = known ? float(c.normal[k]) : 0.0f;
    g.closest = known ? static_cast<float>(c.at / len) : 0.0f;
    g.obstacle = known ? static_cast<float>(c.obstacle) : -1.0f;
    g.stale = 0.0f;
}

// Traces one shadow ray from `origin` to `target` and records what it tells: the lattice's
// sample value, the angular clearance and, in tangent mode, the gradient data and bound.
// `measure`: whether to measure the clearance now (else the caller does it when needed).
Corner traceRay(Occluder::Query& query, const Vec3& origin, const Vec3& target,
                                   const AciSettings& settings, double want, bool measure) {
    Corner out;
    out.origin = origin;
    double tHit = 0.0;
    Clearance c;
    const bool hidden = query.occluded(origin, target, &tHit, measure ? &c : nullptr);
    recordClearance(c, glm::length(target - origin), out.clear, out.geometry);
    out.bound = c.bound;
    out.sample = hidden ? static_cast<float>(std::clamp(tHit / glm::length(target - origin), 0.01, 1.0))
                        : kVisible;
    if (settings.coverage && want > 0.0) query.certify(origin, target, hidden, tHit, want, out.cert);
    return out;
}

uint32_t hashSquare(int x, int y, int s, uint32_t seed) {
    uint32_t h = seed * 0x9E3779B9u ^ static_cast<uint32_t>(x) * 0x85EBCA6Bu ^
                 static_cast<uint32_t>(y) * 0xC2B2AE35u ^ static_cast<uint32_t>(s) * 0x27D4EB2Fu;
    h ^= h >> 15;
    h *= 0x2C1B3C6Du;
    h ^= h >> 12;
    return h;
}

}  // namespace

// One evaluation at one receiver point: the sample lattice and the running contour sums.
//
// The lattice has N = p * 2^(n+1) units per light edge, so that a first-level square has side
// 2^(n+1) units and a dichotomy of n steps ends on an interval of 2 units: its midpoint, the
// contour vertex, and every centre and semi-diagonal point are lattice points too. A square of
// side 2^(k+1) gets k dichotomy steps; refinement and restarts both lower k by one.
struct ContourIntegrator::Lattice {
    ContourIntegrator& self;
    Scratch& scratch;
    const Receiver& rec;
    const RectLight& light;
    Occluder::Query& query;
    int p, n, N;
    Vec3 origin;
    Vec3 lightNormal;
    double epsWorld;  // world length of the final dichotomy interval (the strip width)
    double want;      // coverage: the radius that covers the whole light from any of its points
    double bound = 0.0;  // coverage: the running error bound (Estimate::errorBound)
    double unit;         // world length of one lattice unit (averaged over the two edges)
    // What emits: the frame above the horizon, inside a polygon light's cutting edges and a disc
    // light's circle. Points outside are hidden without a ray (kBelowHorizon).
    std::vector<LightEdge> cuts;
    bool shaped = false;  // a polygon or disc light: contour pieces along its border are exact
    size_t mScanned = 0;  // coverage: traced rays already in scratch.mUncovered (0: scan anew)
    bool certifyNext = false;  // coverage: certify the next traced ray although not first-level
    int passLevel = 0;         // the restart level of the current pass
    bool remark = false;       // coverage: the pass marked new samples and must run again
    AciCounts counts;
    Vec3 g{0.0};
    Mat3 dg{0.0};

    Lattice(ContourIntegrator& s, const Receiver& r, const RectLight& l, Occluder::Query& q, int grid,
            int steps)
        : self(s), scratch(*s.mScratch), rec(r), light(l), query(q), p(grid), n(steps),
          N(grid << (steps + 1)) {
        origin = r.point + s.mSettings.rayOffset * r.normal;
        lightNormal = l.normal();
        cuts = cuttingEdges(l);
        shaped = l.shape != LightShape::Rect;
        epsWorld = (glm::length(l.edgeU) + glm::length(l.edgeV)) / N;  // 2 units, averaged
        // Half the light's diagonal: what covers the light from its centre, or a 2 x 2 first
        // level's square from one of its corners.
        unit = 0.5 * (glm::length(l.edgeU) + glm::length(l.edgeV)) / N;
        // (With a margin: a radius is reported up to `want` exactly, and must exceed it.)
        want = 0.51 * std::max(glm::length(l.edgeU + l.edgeV), glm::length(l.edgeU - l.edgeV));
        const size_t size = static_cast<size_t>(N + 1) * (N + 1);
        if (s.mSettings.coverage && scratch.mCert.size() < size) scratch.mCert.resize(size);
        scratch.mTraced.clear();
        scratch.mAllTraced.clear();
        scratch.mMarked.clear();
        if (scratch.mStamp.size() < size) {
            scratch.mStamp.assign(size, 0);
            scratch.mSample.assign(size, 0.0f);
            scratch.mClear.assign(size, 0.0f);
            scratch.mPending.assign(size, 0);
            scratch.mGeneration = 0;
        }
        if (s.mSettings.tangentContour && scratch.mGeometry.size() < size) scratch.mGeometry.resize(size);
        if (++scratch.mGeneration == 0) {  // wrapped: forget every stamp
            std::fill(scratch.mStamp.begin(), scratch.mStamp.end(), 0);
            scratch.mGeneration = 1;
        }
    }

    Vec3 pointOf(LatticePoint q) const {
        return light.point(double(q.a) / N, double(q.b) / N);
    }

    // Visibility of a lattice sample, tracing a ray only the first time it is asked for.
    float& sample(LatticePoint q, bool firstLevel) {
        const size_t idx = static_cast<size_t>(q.b) * (N + 1) + q.a;
        float& s = scratch.mSample[idx];
        if (scratch.mStamp[idx] == scratch.mGeneration) {
            ++counts.cacheHits;
            return s;
        }
        scratch.mStamp[idx] = scratch.mGeneration;
        scratch.mPending[idx] = 0;
        if (self.mSettings.coverage) scratch.mAllTraced.push_back(static_cast<uint32_t>(idx));
        const Vec3 target = pointOf(q);
        float& clear = scratch.mClear[idx];
        clear = std::numeric_limits<float>::quiet_NaN();
        if (!emits(target)) {
            // No ray: nothing of an earlier evaluation's ray here may be read as this one's.
            if (idx < scratch.mGeometry.size()) scratch.mGeometry[idx] = RayGeometry{};
            if (idx < scratch.mCert.size()) scratch.mCert[idx] = Certificate{};
            s = kBelowHorizon;
            return s;
        }
        // A first-level corner of the base grid may be answered by an earlier receiver
        // point's ray (reuseCorners).
        const int s0 = 2 << n;
        Corner* kept = nullptr;
        if (self.mSettings.reuseCorners && firstLevel && q.a % s0 == 0 && q.b % s0 == 0) {
            kept = scratch.reusableCorner(light, p, q.a / s0, q.b / s0);
        }
        Corner ray;
        if (kept && kept->answers(origin)) {
            ray = *kept;
            ray.geometry.stale = 1.0f;  // its distances are the earlier point's
            ray.cert = Certificate{};  // its disc is about the earlier point's segments
            ++counts.reusedRays;
        } else {
            (firstLevel ? counts.firstLevelRays : counts.secondLevelRays)++;
            if (self.mSettings.rayLog) self.mSettings.rayLog->push_back(target);
            // Certificates on the rays whose discs cover ground: first-level corners and
            // coverage rays (dichotomy rays lie next to the contour, where discs are tiny).
            // With coverage (no corner reuse, which needs every ray's bound) the clearance is
            // measured only for the rays the tangent construction asks about (settle()):
            // coverage rays far from any contour never need it.
            const bool lazy = self.mSettings.distanceGuided && self.mSettings.coverage && !kept;
            ray = traceRay(query, origin, target, self.mSettings,
                           firstLevel || certifyNext ? want : 0.0,
                           self.mSettings.distanceGuided && !lazy);
            scratch.mPending[idx] = lazy;
            if (kept) *kept = ray;
        }
        clear = ray.clear;
        if (self.mSettings.tangentContour) scratch.mGeometry[idx] = ray.geometry;
        s = ray.sample;
        if (self.mSettings.coverage) {
            scratch.mCert[idx] = ray.cert;
            if (ray.cert.radius > 0.0 || ray.cert.radiusOthers > 0.0)
                scratch.mTraced.push_back(static_cast<uint32_t>(idx));
        }
        return s;
    }
    bool visible(LatticePoint q, bool firstLevel = false) { return sample(q, firstLevel) == kVisible; }
    float peek(LatticePoint q) const {
        return scratch.mSample[static_cast<size_t>(q.b) * (N + 1) + q.a];
    }
    bool traced(LatticePoint q) const {
        return scratch.mStamp[static_cast<size_t>(q.b) * (N + 1) + q.a] == scratch.mGeneration;
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
    // The index of traced sample q, its clearance measured now if it was left for later
    // (sample()'s lazy rays): the same march, the same values, not counted as another ray.
    size_t settle(LatticePoint q) const {
        const size_t idx = static_cast<size_t>(q.b) * (N + 1) + q.a;
        if (scratch.mPending[idx] && scratch.mStamp[idx] == scratch.mGeneration) {
            scratch.mPending[idx] = 0;
            const Vec3 target = pointOf(q);
            const Clearance c = query.clearance(origin, target, scratch.mSample[idx] != kVisible);
            RayGeometry unused;
            recordClearance(c, glm::length(target - origin), scratch.mClear[idx],
                            self.mSettings.tangentContour ? scratch.mGeometry[idx] : unused);
        }
        return idx;
    }
    float clearanceOf(LatticePoint q) const { return scratch.mClear[settle(q)]; }

    Vec3 normalOf(LatticePoint q) const {
        const float* t = scratch.mGeometry[settle(q)].normal;
        return Vec3(t[0], t[1], t[2]);
    }
    // Where q's ray passes closest to the surface, as a fraction of the ray (0 unknown).
    double closestFractionOf(LatticePoint q) const {
        return scratch.mGeometry[settle(q)].closest;
    }
    // Whether q was answered by an earlier receiver point's ray (its distances approximate).
    bool staleOf(LatticePoint q) const {
        return scratch.mGeometry[settle(q)].stale != 0.0f;
    }
    // The obstacle q's clearance was measured to (-1 unknown).
    int obstacleOf(LatticePoint q) const {
        return static_cast<int>(scratch.mGeometry[settle(q)].obstacle);
    }

    // tangentContour: where the contour crosses the line X(t) = from + t dir (world, on the
    // light), predicted from the ray to lattice sample q alone. That ray passes at angular
    // clearance c from the surface where the distance gradient is g; moving its end by delta
    // on the light changes that clearance by (g . delta) / D to first order (D: the ray's
    // length), so the contour is the line g . (X - Q) = -c D. NaN when q's ray knows nothing.
    double newtonAlong(LatticePoint q, const Vec3& from, const Vec3& dir) const {
        const double c = clearanceOf(q);
        const Vec3 g = normalOf(q);
        if (!std::isfinite(c) || glm::dot(g, g) == 0.0) return std::nan("");
        const Vec3 target = pointOf(q);
        const double D = glm::length(target - origin);
        const double slope = glm::dot(g, dir);
        if (std::abs(slope) < 1e-9 * glm::length(dir)) return std::nan("");
        return (-c * D - glm::dot(g, from - target)) / slope;
    }

    // The unit normal of the plane of grazing rays through the ray to lattice sample q, made
    // exactly perpendicular to that ray (0 when unknown).
    Vec3 grazingPlane(LatticePoint q, const Vec3& onContour) const {
        const Vec3 g = normalOf(q);
        if (glm::dot(g, g) == 0.0) return Vec3(0.0);
        const Vec3 w = glm::normalize(onContour - origin);
        const Vec3 gp = g - glm::dot(g, w) * w;
        const double len = glm::length(gp);
        return len > 1e-6 ? gp / len : Vec3(0.0);
    }

    // tangentContour's dichotomy: each probe goes where a Newton step from the bracket end with
    // the smaller clearance puts the contour (the secant or the middle when neither end knows
    // its distance), rounded toward the visible end so that the probe tends to be a visible ray
    // just off the surface, whose gradient is the most reliable; after `guidedProbes` probes
    // (at least one) the vertex is placed by the same rule inside the final bracket.
    Vertex crossingNewton(LatticePoint vis, LatticePoint hid, int steps, LatticePoint& finalVis,
                          LatticePoint& finalHid) {
        const int count = 1 << steps;
        const int da = (hid.a - vis.a) / count, db = (hid.b - vis.b) / count;
        auto at = [&](int j) { return LatticePoint{vis.a + j * da, vis.b + j * db}; };
        const Vec3 p0 = pointOf(vis);
        const Vec3 step = pointOf(at(1)) - p0;  // world vector of one position
        // Where the contour is predicted inside [lo, hi] (in positions from vis), and whether
        // that prediction can stand as the vertex: a Newton step from the visible end (outside
        // the surface the distance is exact, and its gradient points at the nearest face or
        // edge, so a sharp silhouette's line comes out right), or a step of at most one
        // position from the hidden end (inside, the gradient is only right on smooth surfaces).
        struct Guess {
            double e;
            bool final;
            int from;  // the bracket end whose Newton step it is, -1 for none
        };
        // A Newton step from the visible end stands as the vertex only when it is short (its
        // error grows with the square of its length) and aims at the obstacle that hides the
        // other end (the nearest surface may be another obstacle's, whose silhouette does not
        // cross this side at all); otherwise the dichotomy goes on.
        constexpr double kReach = 2.0;  // positions
        auto estimate = [&](int lo, int hi) -> Guess {
            // A reused first-level sample's distances are another point's: good enough to aim a
            // probe, not to place a vertex.
            const double fromVis = newtonAlong(at(lo), p0, step);
            if (std::isfinite(fromVis) && fromVis >= lo && fromVis <= hi)
                return {fromVis,
                        !staleOf(at(lo)) && fromVis - lo <= kReach &&
                            obstacleOf(at(lo)) == obstacleOf(at(hi)),
                        lo};
            const double fromHid = newtonAlong(at(hi), p0, step);
            if (std::isfinite(fromHid) && fromHid >= lo && fromHid <= hi)
                return {fromHid, hi - fromHid <= 1.0 && !staleOf(at(hi)), hi};
            const float cl = clearanceOf(at(lo)), ch = clearanceOf(at(hi));
            if (cl > 0.0f && ch < 0.0f)
                return {lo + (hi - lo) * double(cl) / (double(cl) - double(ch)), false, -1};
            return {0.5 * (lo + hi), false, -1};
        };
        int lo = 0, hi = count;
        const int minProbes = std::max(1, self.mSettings.guidedProbes);
        // At least minProbes probes, then more only while the prediction cannot stand; never
        // more than the paper's `steps` (the bracket is then one position wide).
        for (int probes = 0; hi - lo > 1; ++probes) {
            const Guess g = estimate(lo, hi);
            if (probes >= minProbes && g.final) break;
            const int j = std::clamp(static_cast<int>(std::floor(g.e)), lo + 1, hi - 1);
            (visible(at(j)) ? lo : hi) = j;
        }
        narrowByTraced(at, lo, hi);
        finalVis = at(lo);
        finalHid = at(hi);
        const Guess g = estimate(lo, hi);
        const double e = std::clamp(g.e, double(lo), double(hi));
        Vertex v = vertexBetween(at(lo), at(hi), (e - lo) / std::max(1, hi - lo));
        if (peek(at(hi)) == kBelowHorizon) {
            // On the horizon the contour is the (straight) line where the receiver's tangent
            // plane cuts the light: its plane through M is that tangent plane. On a polygon
            // light's edge or a disc light's circle, the plane through M and the border's
            // tangent line.
            const Vec3 w = glm::normalize(v.c - origin);
            Vec3 np(0.0);
            if (v.clip == kClipHorizon) {
                np = rec.normal - glm::dot(rec.normal, w) * w;
            } else {
                np = glm::cross(glm::cross(lightNormal, inwardAt(v.clip, v.c)), w);
            }
            if (glm::length(np) > 1e-9) v.plane = glm::normalize(np);
            v.obstacle = kHorizonContour;
        } else {
            // The gradient of the end that placed the vertex; else the visible end's (outside
            // the surface it points at the nearest edge or face, also on a sharp silhouette),
            // else the hidden end's.
            const int order[3] = {g.from, lo, hi};
            for (int j : order) {
                if (j < 0) continue;
                v.plane = grazingPlane(at(j), v.c);
                if (glm::dot(v.plane, v.plane) == 0.0) continue;
                // The 3D contour point (Fig. 5): where that ray grazes the surface, carried
                // over to the vertex's own ray.
                const double h = closestFractionOf(at(j));
                if (h > 0.0) v.i = origin + h * (v.c - origin);
                v.obstacle = obstacleOf(at(j));
                break;
            }
        }
        return v;
    }

    // tangentContour: a contour piece from vertex a to vertex b, as the conic arc tangent to
    // both vertices' tangent lines, which meet at K: a rational quadratic Bezier (a, K, b) of
    // weight w. A convex arc with those end tangents lies inside the triangle aKb, so when that
    // triangle's form factor is under the threshold the parabola (w = 1) is taken with no ray;
    // otherwise one ray at 3/4 of the way from the chord's middle to K places the arc's
    // shoulder by a Newton step (w = lambda / (1 - lambda), lambda being where the contour
    // crosses that line: 1/2 for a parabola, 1 for a sharp corner at K). Returns false when the
    // tangents are unknown or do not make such a triangle; the caller then checks the piece as
    // in section 3.2.
    struct Arc {
        Vec3 k{0.0};
        double w = 1.0;
        bool straight = false;
        bool probed = false;  // its weight was placed by a shoulder ray
    };
    bool tangentArc(const Vertex& a, const Vertex& b, int x0, int y0, int s, double thr, Arc& arc) {
        if (glm::dot(a.plane, a.plane) == 0.0 || glm::dot(b.plane, b.plane) == 0.0) return false;
        // A silhouette meeting a polygon or disc light's border: a shoulder ray's clearance
        // tells where the silhouette would run on past the border, not where the contour runs
        // (it turns along the border there), so the piece is checked and refined as in section
        // 3.2. (Measured: 0.9% of the unoccluded form factor missed under a disc, at any depth.)
        if (shaped && (a.clip >= 0) != (b.clip >= 0)) return false;
        // Two obstacles' silhouettes meet somewhere between: their tangent lines say nothing
        // about where, so the piece is checked and refined as in section 3.2.
        // (The horizon is a straight line: its meeting with one silhouette is a corner the
        // tangent lines do describe.)
        if (a.obstacle != b.obstacle && a.obstacle != kHorizonContour &&
            b.obstacle != kHorizonContour)
            return false;
        const Vec3 ta = glm::cross(a.plane, lightNormal), tb = glm::cross(b.plane, lightNormal);
        const double la = glm::length(ta), lb = glm::length(tb);
        if (la < 1e-6 || lb < 1e-6) return false;
        const Vec3 ua = ta / la, ub = tb / lb;
        const Vec3 chord = b.c - a.c;
        const double len = glm::length(chord);
        if (len == 0.0) return false;
        const double sinA = glm::dot(glm::cross(ua, chord / len), lightNormal);
        const double sinB = glm::dot(glm::cross(ub, chord / len), lightNormal);
        constexpr double kStraight = 0.01;  // |sin| of the tangents' angle to the chord
        if (std::abs(sinA) < kStraight && std::abs(sinB) < kStraight) {
            arc.straight = true;
            return true;
        }
        const double den = glm::dot(glm::cross(ua, ub), lightNormal);
        if (std::abs(den) < 1e-6) return false;
        const double sa = glm::dot(glm::cross(b.c - a.c, ub), lightNormal) / den;
        arc.k = a.c + sa * ua;
        // K must project inside the chord and lie within the square: otherwise the tangents
        // describe an S-curve or a piece the square cannot hold.
        const double along = glm::dot(arc.k - a.c, chord) / (len * len);
        if (!(along > 0.0 && along < 1.0)) return false;
        // Tangents that turn by much more than a right angle meet far from the arc (at infinity
        // for a half circle): one conic piece then rests on a shoulder ray placed far from the
        // contour, so such a piece is checked and refined instead.
        const double height = glm::length(glm::cross(arc.k - a.c, chord)) / len;
        if (height > len) return false;
        const double side = double(s) / N;
        const Vec2 kuv = light.coordinates(arc.k);
        const double ku = kuv.x, kv = kuv.y;
        const double u0 = double(x0) / N, v0 = double(y0) / N;
        // K within the square (a quarter side of margin), and never beyond the light's border: an arc bulging out
        // of the light would count area the light does not have.
        constexpr double kMargin = 0.25;
        if (ku < u0 - kMargin * side || ku > u0 + (1 + kMargin) * side ||
            kv < v0 - kMargin * side || kv > v0 + (1 + kMargin) * side)
            return false;
        if (ku < 0.0 || ku > 1.0 || kv < 0.0 || kv > 1.0) return false;
        const double triangle = std::abs(edgeF(a.c, arc.k) + edgeF(arc.k, b.c) + edgeF(b.c, a.c));
        if (triangle < 1.5 * thr) {
            arc.w = 1.0;
            return true;
        }
        // One ray on the line from the chord's middle to K, at the lattice point nearest 3/4.
        const Vec3 m = 0.5 * (a.c + b.c);
        const Vec3 target = m + 0.75 * (arc.k - m);
        const Vec2 tuv = light.coordinates(target);
        const double tu = tuv.x, tv = tuv.y;
        const LatticePoint q{std::clamp(static_cast<int>(std::lround(tu * N)), x0, x0 + s),
                             std::clamp(static_cast<int>(std::lround(tv * N)), y0, y0 + s)};
        if (sample(q, false) == kBelowHorizon) return false;
        double lambda = newtonAlong(q, m, arc.k - m);
        if (!std::isfinite(lambda)) return false;
        // One Newton step from a sample far from the contour can misplace the shoulder (the
        // clearance is not linear across the light): when the step lands more than a lattice
        // unit away, a second ray at the landing point places it again from there.
        {
            const Vec3 land = m + std::clamp(lambda, 0.0, 1.0) * (arc.k - m);
            const Vec2 luv = light.coordinates(land);
            const double lu = luv.x, lv = luv.y;
            const LatticePoint q2{std::clamp(static_cast<int>(std::lround(lu * N)), x0, x0 + s),
                                  std::clamp(static_cast<int>(std::lround(lv * N)), y0, y0 + s)};
            if (std::abs(q2.a - q.a) + std::abs(q2.b - q.b) > 1 &&
                sample(q2, false) != kBelowHorizon) {
                const double again = newtonAlong(q2, m, arc.k - m);
                if (std::isfinite(again)) lambda = again;
            }
        }
        arc.probed = true;
        const double l = std::clamp(lambda, 0.0, 1.0);
        if (l <= 0.02) {
            arc.straight = true;
        } else if (l >= 0.98) {
            arc.w = std::numeric_limits<double>::infinity();  // a corner at K
        } else {
            arc.w = l / (1.0 - l);
        }
        return true;
    }

    // Emits the arc from a to b (8 chords; the polygon a K b for a corner). Obstacle points
    // along it take the hit fraction interpolated between a's and b's.
    void emitArc(const Vertex& a, const Vertex& b, const Arc& arc) {
        auto fraction = [&](const Vertex& v) {
            const double lc = glm::length(v.c - rec.point);
            return lc > 0.0 ? glm::length(v.i - rec.point) / lc : 1.0;
        };
        const double ha = fraction(a), hb = fraction(b);
        auto onObstacle = [&](const Vec3& c, double t) {
            return rec.point + ((1.0 - t) * ha + t * hb) * (c - rec.point);
        };
        if (arc.straight) {
            emit(a.i, b.i);
            return;
        }
        if (!std::isfinite(arc.w)) {
            const Vec3 ik = onObstacle(arc.k, 0.5);
            emit(a.i, ik);
            emit(ik, b.i);
            return;
        }
        constexpr int kChords = 8;
        Vec3 prev = a.i;
        for (int i = 1; i <= kChords; ++i) {
            const double t = double(i) / kChords;
            const double b0 = (1 - t) * (1 - t), b1 = 2.0 * arc.w * t * (1 - t), b2 = t * t;
            const Vec3 c = (b0 * a.c + b1 * arc.k + b2 * b.c) / (b0 + b1 + b2);
            const Vec3 next = i == kChords ? b.i : onObstacle(c, t);
            emit(prev, next);
            prev = next;
        }
    }

    // The contour vertex between a visible and a hidden lattice point, by dichotomy (section
    // 3.1): the middle of the final interval, or the exact crossing of the border when the
    // hidden end emits nothing (below the horizon, off a polygon or disc light). With
    // distanceGuided, samples go where the ends' signed clearances put the silhouette (still
    // lattice points, still narrowing to one final interval) and the vertex is interpolated
    // inside that interval (crossingOnSegment, crossingNewton). In the distance-guided modes where a dichotomy stops depends on the side's length, so
    // two squares of different sizes sharing part of a side (a T-junction) would place their
    // vertices differently and leave a gap in the contour: a crossing of a light-lattice line
    // is therefore kept with its final bracket, and any later side holding that bracket (the
    // same way round) takes the same vertex.
    Vertex crossing(LatticePoint vis, LatticePoint hid, int steps) {
        const bool onLine = self.mSettings.distanceGuided && (vis.a == hid.a || vis.b == hid.b);
        if (onLine) {
            if (const Vertex* known = knownCrossing(vis, hid)) return *known;
        }
        LatticePoint fv = vis, fh = hid;
        Vertex v = crossingOnSegment(vis, hid, steps, fv, fh);
        if (onLine) crossings.push_back({fv, fh, v});
        return v;
    }

    struct KnownCrossing {
        LatticePoint vis, hid;  // its final bracket
        Vertex v;
    };
    std::vector<KnownCrossing> crossings;  // distance-guided modes: crossings of lattice lines

    // A crossing found earlier whose final bracket lies on the segment vis -> hid, oriented
    // the same way.
    const Vertex* knownCrossing(LatticePoint vis, LatticePoint hid) const {
        const bool horizontal = vis.b == hid.b;
        const int line = horizontal ? vis.b : vis.a;
        const int v0 = horizontal ? vis.a : vis.b, h0 = horizontal ? hid.a : hid.b;
        const int lo = std::min(v0, h0), hi = std::max(v0, h0);
        for (const KnownCrossing& k : crossings) {
            const bool kh = k.vis.b == k.hid.b;
            if (kh != horizontal || (kh ? k.vis.b : k.vis.a) != line) continue;
            const int kv = kh ? k.vis.a : k.vis.b, kd = kh ? k.hid.a : k.hid.b;
            if (std::min(kv, kd) < lo || std::max(kv, kd) > hi) continue;
            if ((kv < kd) != (v0 < h0)) continue;
            // Stale when a sample traced since lies inside its bracket.
            const int step = kv < kd ? 1 : -1;
            bool stale = false;
            for (int j = kv + step; j != kd && !stale; j += step)
                stale = traced(kh ? LatticePoint{j, line} : LatticePoint{line, j});
            if (stale) continue;
            return &k.v;
        }
        return nullptr;
    }

    Vertex crossingOnSegment(LatticePoint vis, LatticePoint hid, int steps, LatticePoint& finalVis,
                             LatticePoint& finalHid) {
        if (self.mSettings.tangentContour && self.mSettings.distanceGuided && steps > 0)
            return crossingNewton(vis, hid, steps, finalVis, finalHid);
        if (!self.mSettings.distanceGuided) {
            for (int i = 0; i < steps; ++i) {
                const LatticePoint m = midpoint(vis, hid);
                (visible(m) ? vis : hid) = m;
            }
            return vertexBetween(vis, hid, 0.5);
        }
        // Positions j = 0 .. 2^steps along vis -> hid, one final interval apart.
        const int count = 1 << steps;
        const int da = (hid.a - vis.a) / count, db = (hid.b - vis.b) / count;
        auto at = [&](int j) { return LatticePoint{vis.a + j * da, vis.b + j * db}; };
        int lo = 0, hi = count, slow = 0, probes = 0;
        const int maxProbes = self.mSettings.guidedProbes;
        while (hi - lo > 1) {
            const float cl = clearanceOf(at(lo)), ch = clearanceOf(at(hi));
            // Both ends know their distance: interpolating now is as good as narrowing further.
            if (maxProbes > 0 && probes >= maxProbes && cl > 0.0f && ch < 0.0f) break;
            ++probes;
            int j = (lo + hi) / 2;
            const bool secant = slow < 2 && cl > 0.0f && ch < 0.0f;  // false for NaN
            if (secant) {
                const double e = lo + (hi - lo) * double(cl) / (double(cl) - double(ch));
                j = std::clamp(static_cast<int>(std::floor(e)), lo + 1, hi - 1);
            }
            const int before = hi - lo;
            (visible(at(j)) ? lo : hi) = j;
            if (secant && 2 * (hi - lo) > before) ++slow;  // secant stalling: bisect instead
        }
        finalVis = at(lo);
        finalHid = at(hi);
        const float cl = clearanceOf(at(lo)), ch = clearanceOf(at(hi));
        const double f = (cl > 0.0f && ch < 0.0f) ? double(cl) / (double(cl) - double(ch)) : 0.5;
        return vertexBetween(at(lo), at(hi), f);
    }

    // The contour vertex at fraction f of the final interval vis -> hid.
    Vertex vertexBetween(LatticePoint vis, LatticePoint hid, double f) {
        const float h = peek(hid);
        const Vec3 pv = pointOf(vis), ph = pointOf(hid);
        Vertex v;
        if (h == kBelowHorizon) {
            const double t = borderCrossing(pv, ph, v.clip);
            v.c = pv + t * (ph - pv);
            v.i = v.c;
        } else {
            v.c = pv + f * (ph - pv);
            v.i = rec.point + double(h) * (v.c - rec.point);
        }
        return v;
    }

    void emit(const Vec3& a, const Vec3& b, double weight = 1.0) {
        if (self.mSettings.gradient) {
            const EdgeDerivative e = edgeGWithDerivative(a - rec.point, b - rec.point);
            g += weight * e.g;
            dg += weight * e.dg;
        } else {
            g += weight * edgeG(a - rec.point, b - rec.point);
        }
    }

    double edgeF(const Vec3& a, const Vec3& b) const {
        return glm::dot(edgeG(a - rec.point, b - rec.point), rec.normal) / (2.0 * kPi);
    }


    // ----- Coverage (AciSettings::coverage) -----

    // Form factor of the light's part inside the lattice square (x0, y0, s), for bounds.
    double squareFormFactor(int x0, int y0, int s) const {
        const Vec3 p0 = pointOf({x0, y0}), p1 = pointOf({x0 + s, y0});
        const Vec3 p2 = pointOf({x0 + s, y0 + s}), p3 = pointOf({x0, y0 + s});
        return std::abs(edgeF(p0, p1) + edgeF(p1, p2) + edgeF(p2, p3) + edgeF(p3, p0));
    }

    // Height of a light point above the receiver's tangent plane.
    double above(const Vec3& p) const { return glm::dot(p - rec.point, rec.normal); }

    // ----- What emits: the horizon and a polygon or disc light's border -----

    double cutValue(size_t i, const Vec3& p) const { return glm::dot(p - cuts[i].origin, cuts[i].inward); }
    bool emits(const Vec3& p) const {
        if (above(p) <= 0.0) return false;
        for (size_t i = 0; i < cuts.size(); ++i)
            if (cutValue(i, p) < 0.0) return false;
        return light.shape != LightShape::Disc || glm::length(p - light.center) <= light.radius;
    }
    // The unit normal, in the light's plane, pointing into what emits, of border `clip` at p.
    Vec3 inwardAt(int clip, const Vec3& p) const {
        if (clip == kClipHorizon) {
            const Vec3 m = rec.normal - glm::dot(rec.normal, lightNormal) * lightNormal;
            return glm::length(m) > 0.0 ? glm::normalize(m) : Vec3(0.0);
        }
        if (clip == kClipDisc) return glm::normalize(light.center - p);
        return cuts[static_cast<size_t>(clip)].inward;
    }
    // Where the segment pv -> ph (pv emitting, ph not) leaves what emits, as a fraction of it,
    // and through which border (`clip`).
    double borderCrossing(const Vec3& pv, const Vec3& ph, int& clip) const {
        double best = 1.0;
        clip = kClipHorizon;
        auto consider = [&](double fv, double fh, int which) {
            if (!(fh < 0.0) || !(fv >= 0.0)) return;
            const double t = fv / (fv - fh);
            if (t < best) best = t, clip = which;
        };
        consider(above(pv), above(ph), kClipHorizon);
        for (size_t i = 0; i < cuts.size(); ++i) consider(cutValue(i, pv), cutValue(i, ph), static_cast<int>(i));
        if (light.shape == LightShape::Disc) {
            // |pv + t d - c|^2 = r^2, the larger root (pv is inside).
            const Vec3 d = ph - pv, e = pv - light.center;
            const double a = glm::dot(d, d), b = glm::dot(e, d), c = glm::dot(e, e) - light.radius * light.radius;
            const double disc = b * b - a * c;
            if (a > 0.0 && disc >= 0.0) {
                const double t = (-b + std::sqrt(disc)) / a;
                if (t >= 0.0 && t < best) best = t, clip = kClipDisc;
            }
        }
        return std::clamp(best, 0.0, 1.0);
    }

    // The border of what emits from a to b (both on it), counterclockwise about the light's
    // normal: straight along the horizon and polygon edges, exact arcs along a disc's circle,
    // turning at their meeting points. False (nothing emitted) when the walk would need the
    // frame's own border or more turns than a square can hold.
    bool emitBorder(const Vertex& a, const Vertex& b, bool dryRun, double& length) {
        Vec3 x = a.c;
        int on = a.clip;
        length = 0.0;
        const double tiny = 1e-9 * unit;
        for (int turn = 0; turn < 4; ++turn) {
            if (on == kClipDisc) {
                // Along the circle: to b, or to the first line it crosses going out.
                const Vec3 e1 = glm::normalize(light.edgeU), e2 = glm::normalize(light.edgeV);
                auto angle = [&](const Vec3& p) {
                    const Vec3 d = p - light.center;
                    return std::atan2(glm::dot(d, e2), glm::dot(d, e1));
                };
                auto ahead = [&](double phi) {
                    double d = phi - angle(x);
                    while (d <= 1e-12) d += 2.0 * kPi;
                    return d;
                };
                double best = b.clip == kClipDisc ? ahead(angle(b.c)) : std::numeric_limits<double>::infinity();
                int next = kClipDisc;
                auto line = [&](double f0, const Vec3& m, int which) {
                    // f(phi) = f0 + r (cos phi m.e1 + sin phi m.e2); leaving where it falls through 0.
                    const double a1 = light.radius * glm::dot(m, e1), a2 = light.radius * glm::dot(m, e2);
                    const double amp = std::hypot(a1, a2);
                    if (!(amp > std::abs(f0))) return;
                    const double mid = std::atan2(a2, a1), half = std::acos(-f0 / amp);
                    const double d = ahead(mid + half);  // f decreasing through 0 there
                    if (d < best) best = d, next = which;
                };
                line(above(light.center), inwardAt(kClipHorizon, x), kClipHorizon);
                for (size_t i = 0; i < cuts.size(); ++i) line(cutValue(i, light.center), cuts[i].inward, static_cast<int>(i));
                if (!std::isfinite(best)) return false;
                const double phi = angle(x) + best;
                const Vec3 y = next == kClipDisc ? b.c : light.center + light.radius * (std::cos(phi) * e1 + std::sin(phi) * e2);
                length += light.radius * best;
                if (!dryRun) {
                    const EdgeDerivative e = discArcG(light, x, y, rec.point);
                    g += e.g;
                    if (self.mSettings.gradient) dg += e.dg;
                }
                if (next == kClipDisc) return true;
                x = y, on = next;
                continue;
            }
            // Along a line: its direction keeps what emits on the left.
            const Vec3 m = inwardAt(on, x);
            const Vec3 d = glm::cross(m, lightNormal);
            double best = std::numeric_limits<double>::infinity();
            int next = -1;
            if (b.clip == on) {
                const double s = glm::dot(b.c - x, d);
                if (s >= -tiny) best = std::max(s, 0.0), next = on;
            }
            auto line = [&](double f, const Vec3& mj, int which) {
                const double rate = glm::dot(mj, d);
                if (!(rate < 0.0) || which == on) return;
                const double s = f / -rate;
                if (s > tiny && s < best) best = s, next = which;
            };
            line(above(x), inwardAt(kClipHorizon, x), kClipHorizon);
            for (size_t i = 0; i < cuts.size(); ++i) line(cutValue(i, x), cuts[i].inward, static_cast<int>(i));
            if (light.shape == LightShape::Disc && on != kClipDisc) {
                const Vec3 e = x - light.center;
                const double bb = glm::dot(e, d), c = glm::dot(e, e) - light.radius * light.radius;
                const double disc = bb * bb - c;
                if (disc >= 0.0) {
                    const double s = -bb + std::sqrt(disc);
                    if (s > tiny && s < best) best = s, next = kClipDisc;
                }
            }
            if (next < 0 && b.clip != on) return false;
            if (!std::isfinite(best)) return false;
            const Vec3 y = next == on ? b.c : x + best * d;
            length += best;
            if (!dryRun) emit(x, y);
            if (next == on) return true;
            x = y, on = next;
        }
        return false;
    }

    // Whether the part of the cell (lattice coordinates a0, b0, side `size`) above the horizon
    // lies in one of the gathered discs; with `own` >= 0, a disc's radius that excludes that
    // obstacle counts (Certificate::radiusOthers).
    bool cellInDisc(double a0, double b0, double size, int own) const {
        Vec3 pts[8];
        int n = 0;
        const Vec3 q[4] = {light.point(a0 / N, b0 / N), light.point((a0 + size) / N, b0 / N),
                           light.point((a0 + size) / N, (b0 + size) / N),
                           light.point(a0 / N, (b0 + size) / N)};
        double h[4];
        for (int i = 0; i < 4; ++i) h[i] = above(q[i]);
        for (int i = 0; i < 4; ++i) {
            const int j = (i + 1) & 3;
            if (h[i] > 0.0) pts[n++] = q[i];
            if ((h[i] > 0.0) != (h[j] > 0.0)) pts[n++] = q[i] + (h[i] / (h[i] - h[j])) * (q[j] - q[i]);
        }
        if (n == 0) return true;  // below the horizon: hidden, no ray needed
        for (const Disc& d : scratch.mDiscs) {
            const double r2 = own >= 0 && d.obstacle == own ? std::max(d.r2, d.ro2) : d.r2;
            bool all = r2 > 0.0;
            for (int i = 0; i < n && all; ++i) {
                const Vec3 e = pts[i] - d.c;
                all = glm::dot(e, e) < r2;
            }
            if (all) return true;
        }
        return false;
    }

    // Whether the cell lies wholly outside a polygon light's cutting edges or a disc's circle.
    bool cellOutside(double a0, double b0, double size) const {
        const Vec3 q[4] = {light.point(a0 / N, b0 / N), light.point((a0 + size) / N, b0 / N),
                           light.point((a0 + size) / N, (b0 + size) / N),
                           light.point(a0 / N, (b0 + size) / N)};
        for (size_t i = 0; i < cuts.size(); ++i) {
            bool all = true;
            for (const Vec3& p : q) all = all && cutValue(i, p) < 0.0;
            if (all) return true;
        }
        if (light.shape != LightShape::Disc) return false;
        // The circle's centre's distance to the cell (zero inside it).
        double inside = 1.0, nearest = std::numeric_limits<double>::infinity();
        for (int i = 0; i < 4; ++i) {
            const Vec3 e = q[(i + 1) & 3] - q[i];
            const double t = std::clamp(glm::dot(light.center - q[i], e) / glm::dot(e, e), 0.0, 1.0);
            nearest = std::min(nearest, glm::length(q[i] + t * e - light.center));
            inside = std::min(inside, glm::dot(glm::cross(e, light.center - q[i]), lightNormal));
        }
        return inside < 0.0 && nearest > light.radius;
    }

    // Distance from a light point to a contour segment.
    static double distanceToSegment(const Vec3& p, const Segment& g) {
        const Vec3 d = g.b - g.a;
        const double dd = glm::dot(d, d);
        const double t = dd > 0.0 ? std::clamp(glm::dot(p - g.a, d) / dd, 0.0, 1.0) : 0.0;
        return glm::length(g.a + t * d - p);
    }

    // The obstacle of a gathered contour segment whose band (its width around it) holds the
    // whole cell, -1 when none (or the segment's obstacle is unknown).
    int bandOwner(const Vec3& centre, double halfDiag) const {
        for (const Segment& g : scratch.mNearSegs) {
            if (g.own >= 0 && distanceToSegment(centre, g) + halfDiag <= g.width) return g.own;
        }
        return -1;
    }

    // Collects every uncovered cell of side `minSize` in the cell (a0, b0, size) into
    // scratch.mUncovered, with its centre's distance to the nearest disc that would prove it.
    // `leafOwn` >= 0: the cell lies in a contour square whose pieces all belong to that
    // obstacle (the square is within its own contour's band).
    void uncoveredCells(double a0, double b0, double size, double minSize, int leafOwn) const {
        if (shaped && cellOutside(a0, b0, size)) return;  // emits nothing: nothing to prove
        if (cellInDisc(a0, b0, size, -1)) return;
        (void)leafOwn;
        const Vec3 c = light.point((a0 + 0.5 * size) / N, (b0 + 0.5 * size) / N);
        if (!scratch.mNearSegs.empty()) {
            const double halfDiag = 0.5 * glm::length(light.point((a0 + size) / N, (b0 + size) / N) -
                                                      light.point(a0 / N, b0 / N));
            const int own = bandOwner(c, halfDiag);
            if (own >= 0 && cellInDisc(a0, b0, size, own)) return;
        }
        if (size > minSize) {
            const double h = 0.5 * size;
            for (int q = 0; q < 4; ++q)
                uncoveredCells(a0 + (q & 1) * h, b0 + (q >> 1) * h, h, minSize, leafOwn);
            return;
        }
        if (!emits(c)) return;
        if (minSize <= 1.0) {
            // The final count: a cell within epsilon of a located contour piece belongs to the
            // piece's strip (its own term of the bound), not to what coverage left open.
            const double halfDiag = 0.5 * glm::length(light.point((a0 + size) / N, (b0 + size) / N) -
                                                      light.point(a0 / N, b0 / N));
            for (const Segment& g : scratch.mNearSegs)
                if (!g.border && distanceToSegment(c, g) + halfDiag <= epsWorld) return;
        }
        Uncovered u{a0, b0, size, std::numeric_limits<double>::infinity(), bandOwner(c, 0.0), c};
        for (const Disc& d : scratch.mDiscs) gapTo(u, d);
        scratch.mUncovered.push_back(u);
    }

    // Narrows an uncovered cell's distance to proven ground by one disc.
    static void gapTo(Uncovered& u, const Disc& d) {
        const double r2 = u.own >= 0 && d.obstacle == u.own ? std::max(d.r2, d.ro2) : d.r2;
        u.gap = std::min(u.gap, glm::length(u.centre - d.c) - std::sqrt(r2));
    }

    // Form factor of the uncovered cells (the elementary form factor at each centre).
    double uncoveredFormFactor() const {
        const double area = light.area() / (double(N) * N);
        double sum = 0.0;
        for (const Uncovered& u : scratch.mUncovered) {
            const Vec3 d = u.centre - rec.point;
            const double r2 = glm::dot(d, d);
            const double cosR = glm::dot(d, rec.normal) / std::sqrt(r2);
            const double cosL = -glm::dot(d, lightNormal) / std::sqrt(r2);
            sum += std::max(0.0, cosR) * std::abs(cosL) / (kPi * r2) * area * u.size * u.size;
        }
        return sum;
    }

    // What stays uncovered when coverage stops, for the error bound: each remaining cell is
    // cut down to single lattice units against every disc and band near it, so that the bound
    // counts the slivers between discs rather than whole cells.
    double finalUncoveredFormFactor() {
        std::vector<Uncovered> coarse;
        coarse.swap(scratch.mUncovered);
        for (const Uncovered& u : coarse) {
            const int a0 = static_cast<int>(u.a0), b0 = static_cast<int>(u.b0), s = static_cast<int>(u.size);
            gatherNear(a0, b0, s);
            uncoveredCells(u.a0, u.b0, u.size, 1.0, -1);
        }
        return uncoveredFormFactor();
    }

    // Gathers the discs and contour segments that may matter for the leaf square (x0, y0, s).
    void gatherNear(int x0, int y0, int s) {
        const Vec3 centre = light.point((x0 + 0.5 * s) / N, (y0 + 0.5 * s) / N);
        const double half = 0.5 * std::max(glm::length(pointOf({x0 + s, y0 + s}) - pointOf({x0, y0})),
                                           glm::length(pointOf({x0 + s, y0}) - pointOf({x0, y0 + s})));
        scratch.mDiscs.clear();
        for (uint32_t idx : scratch.mTraced) {
            const Certificate& c = scratch.mCert[idx];
            const Vec3 p = pointOf({static_cast<int>(idx % (N + 1)), static_cast<int>(idx / (N + 1))});
            if (glm::length(p - centre) >= std::max(c.radius, c.radiusOthers) + half) continue;
            scratch.mDiscs.push_back({p, c.radius * c.radius, c.radiusOthers * c.radiusOthers, c.obstacle});
        }
        scratch.mNearSegs.clear();
        for (const Segment& g : scratch.mSegs)
            if (distanceToSegment(centre, g) < g.width + half) scratch.mNearSegs.push_back(g);
    }

    // The lattice point where coverage wants its next ray: the centre (or a corner not yet
    // traced) of the uncovered cell of 2 units farthest from what discs and contour bands
    // prove. False when every uncovered point is within coverageGap x epsilon (epsilon: the
    // final dichotomy interval) of proven ground, so that no shadow or window holding a disc of
    // that radius can hide there, or when `giveUp` (uncoveredFormFactor() then tells what stays
    // uncovered). The scan of a pass's leaves is updated incrementally as rays are added.
    bool nextCoverageSample(LatticePoint& out, bool giveUp) {
        auto& cells = scratch.mUncovered;
        if (mScanned == 0) {
            // A new pass: scan the leaves.
            cells.clear();
            for (const Leaf& leaf : scratch.mLeaves) {
                gatherNear(leaf.x0, leaf.y0, leaf.s);
                int own = -1;
                for (uint32_t i = leaf.seg0; i < leaf.seg1; ++i) {
                    const int o = scratch.mSegs[i].own;
                    own = i == leaf.seg0 || o == own ? o : -1;
                }
                uncoveredCells(leaf.x0, leaf.y0, leaf.s, kScanCell, own);
            }
            mScanned = scratch.mTraced.size();
        } else {
            // Only the discs traced since: drop the cells they cover, narrow the others' gaps.
            for (size_t t = mScanned; t < scratch.mTraced.size(); ++t) {
                const uint32_t idx = scratch.mTraced[t];
                const Certificate& c = scratch.mCert[idx];
                const Disc d{pointOf({static_cast<int>(idx % (N + 1)), static_cast<int>(idx / (N + 1))}),
                             c.radius * c.radius, c.radiusOthers * c.radiusOthers, c.obstacle};
                scratch.mDiscs.assign(1, d);
                size_t kept = 0;
                for (Uncovered& u : cells) {
                    if (cellInDisc(u.a0, u.b0, u.size, -1) ||
                        (u.own >= 0 && cellInDisc(u.a0, u.b0, u.size, u.own)))
                        continue;
                    gapTo(u, d);
                    cells[kept++] = u;
                }
                cells.resize(kept);
            }
            mScanned = scratch.mTraced.size();
        }
        // A cell of side s is done when every centre of its cells of kCoverageCell units is
        // near proven ground: its own centre's gap plus the distance to the farthest of them.
        auto reach = [&](double size) { return kHalfSqrt2 * (size - kCoverageCell) * unit; };
        const double enough = self.mSettings.coverageGap * epsWorld;
        for (;;) {
            size_t far = cells.size();
            for (size_t i = 0; i < cells.size(); ++i)
                if (cells[i].exhausted) continue;
                else if (far == cells.size() || cells[i].gap + reach(cells[i].size) > cells[far].gap + reach(cells[far].size))
                    far = i;
            if (giveUp || far == cells.size() || cells[far].gap + reach(cells[far].size) < enough) return false;
            const Uncovered u = cells[far];
            if (u.gap < enough && u.size > kCoverageCell) {
                // Its centre is near proven ground, a farther part of it may not be: look at
                // its quarters instead (with every disc and band near it).
                cells.erase(cells.begin() + static_cast<std::ptrdiff_t>(far));
                gatherNear(static_cast<int>(u.a0), static_cast<int>(u.b0), static_cast<int>(u.size));
                const double h = 0.5 * u.size;
                for (int q = 0; q < 4; ++q)
                    uncoveredCells(u.a0 + (q & 1) * h, u.b0 + (q >> 1) * h, h, h, -1);
                continue;
            }
            const int ia = static_cast<int>(u.a0), ib = static_cast<int>(u.b0);
            const int h = static_cast<int>(u.size) / 2;
            const LatticePoint cand[5] = {{ia + h, ib + h}, {ia, ib}, {ia + 2 * h, ib}, {ia + 2 * h, ib + 2 * h}, {ia, ib + 2 * h}};
            for (const LatticePoint& q : cand) {
                if (!traced(q)) {
                    out = q;
                    return true;
                }
            }
            if (u.size <= kCoverageCell) {
                // Nothing finer to ask here (it still counts in uncoveredFormFactor()).
                cells[far].exhausted = true;
                continue;
            }
            // Every candidate traced and still uncovered: its quarters.
            cells.erase(cells.begin() + static_cast<std::ptrdiff_t>(far));
            gatherNear(ia, ib, static_cast<int>(u.size));
            for (int q = 0; q < 4; ++q)
                uncoveredCells(u.a0 + (q & 1) * 0.5 * u.size, u.b0 + (q >> 1) * 0.5 * u.size, 0.5 * u.size, 0.5 * u.size, -1);
        }
    }

    // Whether a traced coverage sample lies in the square (x0, y0, s), corners excluded, with
    // another answer than the square's uniform one (visible: 1, hidden: 0; -1: any answer).
    bool markedInside(int x0, int y0, int s, int uniform) const {
        for (uint32_t idx : scratch.mMarked) {
            const int a = static_cast<int>(idx % (N + 1)), b = static_cast<int>(idx / (N + 1));
            if (a < x0 || a > x0 + s || b < y0 || b > y0 + s) continue;
            if ((a == x0 || a == x0 + s) && (b == y0 || b == y0 + s)) continue;
            if (uniform < 0 || (scratch.mSample[idx] == kVisible) != (uniform == 1)) return true;
        }
        return false;
    }

    // Whether a traced sample disagrees with a leaf that holds it (inside or on its border),
    // farther than epsilon from that leaf's contour: a shadow or window the pass stepped over
    // (say, two crossings of one side found from two squares of different sizes).
    bool contradicts(uint32_t idx) const {
        const LatticePoint q{static_cast<int>(idx % (N + 1)), static_cast<int>(idx / (N + 1))};
        const float sv = scratch.mSample[idx];
        if (sv == kBelowHorizon) return false;
        const int answer = sv == kVisible ? 1 : 0;
        for (const Leaf& leaf : scratch.mLeaves) {
            if (q.a < leaf.x0 || q.a > leaf.x0 + leaf.s || q.b < leaf.y0 || q.b > leaf.y0 + leaf.s)
                continue;
            if (leaf.type != 2) {
                if (leaf.type != answer) return true;
                continue;
            }
            const Vec3 p = pointOf(q);
            double best;
            const int side = nearestSide(leaf, p, best);
            if (side != answer && best > epsWorld) return true;
            // On the leaf's own border a vertex that the sample contradicts was placed before
            // the sample was traced (a neighbour's dichotomy): the next pass narrows it.
            const bool onBorder = q.a == leaf.x0 || q.a == leaf.x0 + leaf.s || q.b == leaf.y0 ||
                                  q.b == leaf.y0 + leaf.s;
            if (onBorder && side != answer && best > 1e-9 * unit && self.mSettings.distanceGuided) return true;
        }
        return false;
    }

    // The side of a contour square's nearest segment a light point lies on (visible, 1, on the
    // left in (u, v)), and its distance to it.
    int nearestSide(const Leaf& leaf, const Vec3& p, double& best) const {
        best = std::numeric_limits<double>::infinity();
        int side = 1;
        bool onBorder = false;
        for (uint32_t i = leaf.seg0; i < leaf.seg1; ++i) {
            const Segment& g = scratch.mSegs[i];
            const double dist = distanceToSegment(p, g);
            if (dist < best) {
                best = dist;
                side = glm::dot(glm::cross(g.b - g.a, p - g.a), lightNormal) > 0.0 ? 1 : 0;
                onBorder = g.border;
            }
        }
        // Nearest to the (exact) border of what emits: the point's own position decides.
        if (onBorder) side = emits(p) ? 1 : 0;
        return side;
    }

    // What the current contour says about a light point: visible (1) or hidden (0).
    int predicted(LatticePoint q) const {
        for (const Leaf& leaf : scratch.mLeaves) {
            if (q.a < leaf.x0 || q.a > leaf.x0 + leaf.s || q.b < leaf.y0 || q.b > leaf.y0 + leaf.s)
                continue;
            if (leaf.type != 2) return leaf.type;
            // A contour square: the side of the nearest segment (visible on the left in (u, v)).
            double best;
            return nearestSide(leaf, pointOf(q), best);
        }
        return 1;
    }

    // Splits the square into four like a refinement (section 3.2); false on an inconsistency.
    bool split(int x0, int y0, int k, double thr, int depth, const bool v[4], const bool onBorder[4]) {
        const int s = 2 << k;
        const LatticePoint c[4] = {{x0, y0}, {x0 + s, y0}, {x0 + s, y0 + s}, {x0, y0 + s}};
        counts.maxDepth = std::max(counts.maxDepth, depth + 1);
        // New samples at the middle of each side: a side whose ends agree but whose middle
        // differs means the neighbouring square was treated wrongly (unless the side is on
        // the light's border): restart one level deeper.
        for (int i = 0; i < 4; ++i) {
            const int j = (i + 1) & 3;
            if (v[i] == v[j] && visible(midpoint(c[i], c[j])) != v[i] && !onBorder[i]) {
                // With coverage, restarts stop after the first: deeper, the sample is marked
                // and another pass at the same level splits the neighbour holding it on its side
                // (markedInside), which bounds the work of a cascade of inconsistencies.
                if (!self.mSettings.coverage || passLevel == 0) return false;
                const LatticePoint m = midpoint(c[i], c[j]);
                const uint32_t idx = static_cast<uint32_t>(static_cast<size_t>(m.b) * (N + 1) + m.a);
                if (std::find(scratch.mMarked.begin(), scratch.mMarked.end(), idx) == scratch.mMarked.end()) {
                    scratch.mMarked.push_back(idx);
                    remark = true;
                }
            }
        }
        const int h = s / 2;
        for (int sy = 0; sy < 2; ++sy)
            for (int sx = 0; sx < 2; ++sx)
                if (!square(x0 + sx * h, y0 + sy * h, k - 1, thr < 0.0 ? thr : 0.5 * thr,
                            depth + 1))
                    return false;
        return true;
    }

    // Processes the square with lower-left lattice corner (x0, y0) and side s = 2^(k+1).
    // thr < 0 asks for the threshold to be computed from the square's own contour.
    // Returns false on an inconsistency that needs the whole light one level deeper.
    bool square(int x0, int y0, int k, double thr, int depth) {
        const int s = 2 << k;
        const LatticePoint c[4] = {{x0, y0}, {x0 + s, y0}, {x0 + s, y0 + s}, {x0, y0 + s}};
        bool v[4];
        for (int i = 0; i < 4; ++i) v[i] = visible(c[i]);
        const int nVisible = v[0] + v[1] + v[2] + v[3];
        const bool onBorder[4] = {y0 == 0, x0 + s == N, y0 + s == N, x0 == 0};

        if (nVisible == 0 || nVisible == 4) {
            // With coverage: a coverage sample inside that disagrees splits the square (a
            // shadow or window touching no corner).
            if (self.mSettings.coverage && k > 0 && markedInside(x0, y0, s, nVisible == 4)) {
                ++counts.squaresSplitForCoverage;
                return split(x0, y0, k, thr, depth, v, onBorder);
            }
            if (self.mSettings.coverage) scratch.mLeaves.push_back({x0, y0, s, nVisible == 4 ? 1 : 0, 0, 0});
            if (nVisible == 4)
                for (int i = 0; i < 4; ++i)
                    if (onBorder[i]) emit(pointOf(c[i]), pointOf(c[(i + 1) & 3]));
            return true;
        }

        // Crossings on the sides whose ends differ (side i runs from c[i] to c[i+1]).
        Vertex x[4];
        for (int i = 0; i < 4; ++i) {
            const int j = (i + 1) & 3;
            if (v[i] != v[j]) x[i] = v[i] ? crossing(c[i], c[j], k) : crossing(c[j], c[i], k);
        }

        // Contour pieces: from an exit crossing (visible -> hidden walking counterclockwise) to
        // an entry crossing, so that the visible part is on the left in (u, v). Each piece cuts
        // off one corner, through which its check diagonal runs.
        struct Piece {
            int exitSide, entrySide;
            LatticePoint checkVis, checkHid;
            int checkSteps;
            bool midline = false;
        };
        Piece pieces[2];
        int nPieces = 0;
        const LatticePoint mu{x0 + s / 2, y0 + s / 2};
        const bool saddle = v[0] == v[2] && v[1] == v[3];
        if (saddle) {
            const bool muVisible = visible(mu);  // case 4: the centre ray decides
            for (int i = 0; i < 4; ++i) {
                if (!(v[i] && !v[(i + 1) & 3])) continue;  // exit on side i
                // Centre visible: the hidden corner c[i+1] is cut off, the entry is on side i+1.
                // Centre hidden: the visible corner c[i] is isolated, the entry is on side i-1.
                const int cut = muVisible ? (i + 1) & 3 : i;
                const int entry = muVisible ? (i + 1) & 3 : (i + 3) & 3;
                Piece pc{i, entry, mu, c[cut], k > 0 ? k - 1 : 0};
                if (!muVisible) std::swap(pc.checkVis, pc.checkHid);
                pieces[nPieces++] = pc;
            }
        } else {
            int exitSide = -1, entrySide = -1;
            for (int i = 0; i < 4; ++i) {
                const int j = (i + 1) & 3;
                if (v[i] && !v[j]) exitSide = i;
                if (!v[i] && v[j]) entrySide = i;
            }
            Piece pc{exitSide, entrySide, {}, {}, k, false};
            if (nVisible != 2) {
                // Case 2: the diagonal through the odd corner.
                const bool odd = nVisible == 1;  // the odd corner is the one with v == odd
                int corner = 0;
                while (v[corner] != odd) ++corner;
                const int opposite = (corner + 2) & 3;
                pc.checkVis = v[corner] ? c[corner] : c[opposite];
                pc.checkHid = v[corner] ? c[opposite] : c[corner];
            } else {
                if (self.mSettings.midlineCheck) {
                    // The contour crosses two opposite sides; check it on the square's midline
                    // between the other two sides' midpoints, half-way along the chord.
                    const int sa = (exitSide + 1) & 3, sb = (exitSide + 3) & 3;
                    const LatticePoint ma = midpoint(c[sa], c[(sa + 1) & 3]);
                    const LatticePoint mb = midpoint(c[sb], c[(sb + 1) & 3]);
                    pc.checkVis = v[sa] ? ma : mb;
                    pc.checkHid = v[sa] ? mb : ma;
                    pc.midline = true;
                } else {
                    // Case 3: either diagonal, chosen by a hash of the square (Vedel: at random).
                    const int d = hashSquare(x0, y0, s, self.mSettings.seed) & 1;
                    pc.checkVis = v[d] ? c[d] : c[d + 2];
                    pc.checkHid = v[d] ? c[d + 2] : c[d];
                }
            }
            pieces[nPieces++] = pc;
        }

        // A piece between two points of a polygon or disc light's border (or the horizon) is
        // that border: exact, no check, when it stays near the square.
        bool border[2] = {false, false};
        if (shaped) {
            for (int q = 0; q < nPieces; ++q) {
                const Vertex& a = x[pieces[q].exitSide];
                const Vertex& b = x[pieces[q].entrySide];
                double length = 0.0;
                border[q] = a.clip >= 0 && b.clip >= 0 && emitBorder(a, b, true, length) &&
                            length <= 4.0 * s * unit;
            }
        }

        // Section 3.2: one more contour point per piece; refine where the change exceeds the
        // form factor of a strip of width epsilon around the piece.
        Vertex z[2];
        Arc arcs[2];
        bool arcOk[2] = {false, false};
        if (self.mSettings.tangentContour && self.mSettings.distanceGuided) {
            for (int q = 0; q < nPieces; ++q) {
                if (border[q]) continue;
                const Vertex& a = x[pieces[q].exitSide];
                const Vertex& b = x[pieces[q].entrySide];
                const double pieceThr =
                    thr >= 0.0 ? thr
                               : stripFormFactor(rec, lightNormal, a.c, b.c, epsWorld) *
                                     self.mSettings.thresholdScale;
                arcOk[q] = tangentArc(a, b, x0, y0, s, pieceThr, arcs[q]);
            }
        }
        double change = 0.0, ownThr = 0.0;
        for (int q = 0; q < nPieces; ++q) {
            const Vertex& a = x[pieces[q].exitSide];
            const Vertex& b = x[pieces[q].entrySide];
            if (arcOk[q] || border[q]) continue;
            if (pieces[q].midline && (!visible(pieces[q].checkVis) || visible(pieces[q].checkHid))) {
                // A side's middle disagrees with its corners: the contour crosses that side
                // twice, which only a split square can represent.
                change = std::numeric_limits<double>::infinity();
                z[q] = x[pieces[q].exitSide];
                continue;
            }
            z[q] = crossing(pieces[q].checkVis, pieces[q].checkHid, pieces[q].checkSteps);
            change += std::abs(edgeF(a.c, z[q].c) + edgeF(z[q].c, b.c) - edgeF(a.c, b.c));
            const bool twoSilhouettes = a.obstacle != b.obstacle && a.obstacle != kHorizonContour &&
                                        b.obstacle != kHorizonContour;
            // A silhouette meeting a polygon or disc light's border is such a junction too.
            const bool silhouetteAndBorder = shaped && (a.clip >= 0) != (b.clip >= 0);
            if (self.mSettings.coverage && (twoSilhouettes || silhouetteAndBorder)) {
                // Two silhouettes meet somewhere in the square, at a corner one check point
                // seldom lands on: the square's own form factor is what the piece may miss.
                const Vec3 q0 = pointOf(c[0]), q1 = pointOf(c[1]), q2 = pointOf(c[2]), q3 = pointOf(c[3]);
                constexpr double kJunction = 0.05;  // measured on random sphere scenes
                change += kJunction * std::abs(edgeF(q0, q1) + edgeF(q1, q2) + edgeF(q2, q3) + edgeF(q3, q0));
            }
            ownThr += stripFormFactor(rec, lightNormal, a.c, b.c, epsWorld);
        }
        if (thr < 0.0) thr = ownThr * self.mSettings.thresholdScale;

        if (self.mSettings.refine && k > 0 && change > thr) {
            ++counts.squaresRefined;
            return split(x0, y0, k, thr, depth, v, onBorder);
        }

        if (self.mSettings.coverage) {
            if (k > 0 && markedInside(x0, y0, s, -1)) {
                ++counts.squaresSplitForCoverage;
                return split(x0, y0, k, thr, depth, v, onBorder);
            }
            // The contour as segments (each piece: its ends and its middle) with the obstacle
            // it belongs to when both ends agree (the horizon belongs to none), and the band
            // around it where only that obstacle's discs need to exclude the others.
            const uint32_t seg0 = static_cast<uint32_t>(scratch.mSegs.size());
            // Half a first-level square (at this pass's level) on either side: a refined square's
            // contour keeps its first-level square's band.
            const double band = 0.5 * double(2 << (n - passLevel)) * unit;
            for (int q = 0; q < nPieces; ++q) {
                const Vertex& a = x[pieces[q].exitSide];
                const Vertex& b = x[pieces[q].entrySide];
                Vec3 mid = 0.5 * (a.c + b.c);
                if (border[q]) {
                    // The border itself: exact, so a sample near it is what it says (points
                    // outside emit nothing, points inside are visible unless a silhouette says
                    // otherwise, and those have their own segments).
                    scratch.mSegs.push_back({a.c, b.c, band, -1, true});
                    continue;
                }
                if (arcOk[q] && !arcs[q].straight) {
                    const double w = arcs[q].w;
                    mid = std::isfinite(w) ? (0.25 * a.c + 0.5 * w * arcs[q].k + 0.25 * b.c) / (0.5 + 0.5 * w)
                                           : arcs[q].k;
                } else if (!arcOk[q]) {
                    mid = z[q].c;
                }
                int own = a.obstacle;
                if (own == kHorizonContour) own = b.obstacle;
                if (b.obstacle != own && b.obstacle != kHorizonContour) own = -1;
                scratch.mSegs.push_back({a.c, mid, band, own});
                scratch.mSegs.push_back({mid, b.c, band, own});
            }
            scratch.mLeaves.push_back({x0, y0, s, 2, seg0, static_cast<uint32_t>(scratch.mSegs.size())});
            // What each piece's data leave open: the strip of the vertices' uncertainty, and
            // for a tangent arc the part of its tangent triangle the arc may miss (two thirds
            // without a shoulder ray, a quarter with one), for a checked piece half the change
            // that the check measured.
            for (int q = 0; q < nPieces; ++q) {
                if (border[q]) continue;  // exact
                const Vertex& a = x[pieces[q].exitSide];
                const Vertex& b = x[pieces[q].entrySide];
                double e = 0.25 * stripFormFactor(rec, lightNormal, a.c, b.c, epsWorld);
                if (arcOk[q] && !arcs[q].straight) {
                    const double tri = std::abs(edgeF(a.c, arcs[q].k) + edgeF(arcs[q].k, b.c) + edgeF(b.c, a.c));
                    e += (arcs[q].probed ? 0.25 : 2.0 / 3.0) * tri;
                } else if (!arcOk[q]) {
                    e += 0.5 * std::abs(edgeF(a.c, z[q].c) + edgeF(z[q].c, b.c) - edgeF(a.c, b.c));
                }
                bound += e;
            }
        }

        for (int q = 0; q < nPieces; ++q) {
            const Vertex& a = x[pieces[q].exitSide];
            const Vertex& b = x[pieces[q].entrySide];
            if (border[q]) {
                double length = 0.0;
                emitBorder(a, b, false, length);
            } else if (arcOk[q]) {
                emitArc(a, b, arcs[q]);
            } else if (self.mSettings.curvedContour) {
                // Treat X, Z, Y as points of a parabolic arc: the area between the arc and its
                // chord is the triangle XZY divided by 3 s (1 - s), s being Z's position along
                // the chord (Archimedes: 4/3 of the triangle when Z is the apex, s = 1/2).
                const Vec3 chord = b.c - a.c;
                const double len2 = glm::dot(chord, chord);
                double sz = len2 > 0.0 ? glm::dot(z[q].c - a.c, chord) / len2 : 0.5;
                sz = std::clamp(sz, 0.15, 0.85);
                const double w = 1.0 / (3.0 * sz * (1.0 - sz));
                emit(a.i, z[q].i, w);
                emit(z[q].i, b.i, w);
                emit(a.i, b.i, 1.0 - w);
            } else {
                emit(a.i, z[q].i);
                emit(z[q].i, b.i);
            }
        }
        // The visible parts of the light's border, joined to the contour by radial junction
        // edges C -> I (zero for the form factor, not for its gradient: Fig. 5).
        for (int i = 0; i < 4; ++i) {
            if (!onBorder[i]) continue;
            const int j = (i + 1) & 3;
            if (v[i] && v[j]) {
                emit(pointOf(c[i]), pointOf(c[j]));
            } else if (v[i]) {
                emit(pointOf(c[i]), x[i].c);
                emit(x[i].c, x[i].i);
            } else if (v[j]) {
                emit(x[i].i, x[i].c);
                emit(x[i].c, pointOf(c[j]));
            }
        }
        return true;
    }

    // Coverage: a ray to the light's centre; true when its disc covers the whole light (which
    // is then wholly visible or wholly hidden, and integrated).
    bool wholeLight() {
        const LatticePoint centre{N / 2, N / 2};
        const Vec3 pc = pointOf(centre);
        for (const Vec3& q : light.polygon())
            if (above(q) <= 0.0) return false;  // the horizon cuts it: the passes handle that
        const bool vis = visible(centre, true);
        if (peek(centre) == kBelowHorizon) return false;  // the frame's centre emits nothing
        const Certificate& cert = scratch.mCert[static_cast<size_t>(centre.b) * (N + 1) + centre.a];
        if (light.shape == LightShape::Disc) {
            // The frame's centre is the disc's: its radius covers it.
            if (!(light.radius < cert.radius)) return false;
        } else {
            for (const Vec3& q : light.polygon())
                if (!(glm::length(q - pc) < cert.radius)) return false;
        }
        if (vis) {
            if (light.shape == LightShape::Disc) {
                const Vec3 start = light.center + light.radius * glm::normalize(light.edgeU);
                const EdgeDerivative e = discArcG(light, start, start, rec.point);
                g += e.g;
                if (self.mSettings.gradient) dg += e.dg;
            } else {
                const std::vector<Vec3> poly = light.polygon();
                for (size_t i = 0; i < poly.size(); ++i) emit(poly[i], poly[(i + 1) % poly.size()]);
            }
        }
        return true;
    }

    // One pass over the light at restart level r; false on an inconsistency.
    bool pass(int r) {
        g = Vec3(0.0);
        dg = Mat3(0.0);
        bound = 0.0;
        passLevel = r;
        scratch.mLeaves.clear();
        scratch.mSegs.clear();
        const int k = n - r;
        const int s = 2 << k;
        const int squares = p << r;
        for (int j = 0; j <= squares; ++j)
            for (int i = 0; i <= squares; ++i) visible({i * s, j * s}, true);
        for (int j = 0; j < squares; ++j)
            for (int i = 0; i < squares; ++i)
                if (!square(i * s, j * s, k, -1.0, 0)) return false;
        return true;
    }
};

ContourIntegrator::ContourIntegrator(const AciSettings& settings)
    : mSettings(settings), mScratch(std::make_unique<Scratch>()) {}
ContourIntegrator::ContourIntegrator(const ContourIntegrator& other)
    : mSettings(other.mSettings), mScratch(std::make_unique<Scratch>(*other.mScratch)) {}
ContourIntegrator& ContourIntegrator::operator=(const ContourIntegrator& other) {
    if (this != &other) {
        mSettings = other.mSettings;
        mScratch = std::make_unique<Scratch>(*other.mScratch);
    }
    return *this;
}
ContourIntegrator::ContourIntegrator(ContourIntegrator&&) noexcept = default;
ContourIntegrator& ContourIntegrator::operator=(ContourIntegrator&&) noexcept = default;
ContourIntegrator::~ContourIntegrator() = default;

void ContourIntegrator::forgetCorners() { mScratch->mCorners.clear(); }

Estimate ContourIntegrator::evaluate(const Receiver& r, const RectLight& light,
                                     Occluder::Query& query) {
    if (light.shape == LightShape::Polygon) {
        // Emitting area between lattice corners that all lie outside it would go unseen: a
        // polygon whose corners are not its frame's, or a triangle whose corners the horizon
        // cuts off, is integrated as the fan of triangles of its part above the horizon, each
        // in its own parallelogram (a parallelogram needs none: the horizon meets it on its
        // frame's border, like a rectangle's).
        const bool parallelogram = light.vertices.size() == 4 && frameHoldsCorners(light);
        const std::vector<Vec3> part = parallelogram || mFanPiece ? light.vertices : clipToHorizon(light.vertices, r);
        if (!parallelogram && !mFanPiece && !(part == light.vertices && frameHoldsCorners(light))) {
            mFanPiece = true;  // each triangle is integrated as it is (no second clip)
            Estimate sum;
            sum.errorBound = mSettings.coverage && mSettings.errorBound ? 0.0 : std::numeric_limits<double>::quiet_NaN();
            for (size_t i = 1; i + 1 < part.size(); ++i) {
                RectLight t;
                try {
                    t = polygonLight({part[0], part[i], part[i + 1]});
                } catch (const std::invalid_argument&) {
                    continue;  // a sliver of no area where the horizon meets a corner
                }
                t.radiance = light.radiance;
                Estimate e;
                try {
                    e = evaluate(r, t, query);
                } catch (...) {
                    mFanPiece = false;
                    throw;
                }
                sum.formFactor += e.formFactor;
                sum.g += e.g;
                sum.dg += e.dg;
                sum.gradient += e.gradient;
                sum.errorBound += e.errorBound;
                sum.counts.merge(e.counts);
                sum.pattern.insert(sum.pattern.end(), e.pattern.begin(), e.pattern.end());
            }
            mFanPiece = false;
            return sum;
        }
    }
    Scratch& sc = *mScratch;
    Estimate est;
    if (!facesLight(light, r.point)) return est;
    bool above = false;
    for (const Vec3& c : light.polygon()) above |= glm::dot(c - r.point, r.normal) > 0.0;
    if (!above) return est;

    const int p = std::max(1, mSettings.grid);
    int n = std::max(0, mSettings.steps);
    while (n > 0 && (p << (n + 1)) > kMaxLatticeUnits) --n;
    Lattice lat(*this, r, light, query, p, n);
    if (mSettings.coverage && lat.wholeLight()) {
        // One ray whose disc covers the light decides it: all visible or all hidden.
        const bool vis = sc.mSample[static_cast<size_t>(lat.N / 2) * (lat.N + 1) + lat.N / 2] == kVisible;
        est.pattern.assign(static_cast<size_t>(p + 1) * (p + 1), vis ? 1 : 0);
        est.g = lat.g / (2.0 * kPi);
        est.dg = lat.dg / (2.0 * kPi);
        est.formFactor = glm::dot(est.g, r.normal);
        for (int k = 0; k < 3; ++k) est.gradient[k] = glm::dot(est.dg[k], r.normal);
        est.errorBound = mSettings.errorBound ? 0.0 : std::numeric_limits<double>::quiet_NaN();
        est.counts = lat.counts;
        return est;
    }
    int level = 0;
    int coverageRays = 0, repasses = 0, remarks = 0;
    for (;;) {
        lat.remark = false;
        if (!lat.pass(level)) {
            ++lat.counts.restarts;
            ++level;  // cannot exceed n: at k = 0 no square splits, so no inconsistency arises
            continue;
        }
        if (!mSettings.coverage) break;
        if (lat.remark && ++remarks <= kMaxRepasses) continue;
        // Every ray the pass traced must agree with the contour it closed; one that does not
        // (a dichotomy sample of a neighbouring square, say) makes the pass run again like a
        // contradicting coverage ray.
        bool again = false;
        if (repasses < kMaxRepasses) {
            for (uint32_t idx : sc.mAllTraced) {
                if (!lat.contradicts(idx)) continue;
                if (std::find(sc.mMarked.begin(), sc.mMarked.end(), idx) != sc.mMarked.end()) continue;
                sc.mMarked.push_back(idx);
                again = true;
            }
            if (again) {
                ++repasses;
                continue;
            }
        }
        // Coverage: rays where no disc and no contour band proves the answer. One that
        // contradicts the contour (a shadow or window the pass missed) makes the pass run again,
        // splitting the squares it lies in; every ray is reused.
        LatticePoint q;
        lat.mScanned = 0;
        while (lat.nextCoverageSample(q, coverageRays >= mSettings.maxCoverageRays)) {
            ++coverageRays;
            lat.certifyNext = true;
            const bool vis = lat.visible(q);
            lat.certifyNext = false;
            if ((vis ? 1 : 0) != lat.predicted(q) && repasses < kMaxRepasses) {
                ++repasses;
                sc.mMarked.push_back(static_cast<uint32_t>(static_cast<size_t>(q.b) * (lat.N + 1) + q.a));
                again = true;
                break;
            }
        }
        if (!again) {
            if (mSettings.errorBound) lat.bound += lat.finalUncoveredFormFactor();
            break;
        }
    }
    est.pattern.resize(static_cast<size_t>(p + 1) * (p + 1));
    const int s0 = 2 << n;
    for (int j = 0; j <= p; ++j)
        for (int i = 0; i <= p; ++i) {
            const size_t idx = static_cast<size_t>(j * s0) * (lat.N + 1) + i * s0;
            est.pattern[static_cast<size_t>(j) * (p + 1) + i] = sc.mSample[idx] == kVisible;
        }
    est.g = lat.g / (2.0 * kPi);
    est.dg = lat.dg / (2.0 * kPi);
    est.formFactor = glm::dot(est.g, r.normal);
    for (int k = 0; k < 3; ++k) est.gradient[k] = glm::dot(est.dg[k], r.normal);
    if (mSettings.coverage && mSettings.errorBound) est.errorBound = lat.bound;
    est.counts = lat.counts;
    return est;
}

Corner* ContourIntegrator::Scratch::reusableCorner(const RectLight& light, int grid,
                                                             int i, int j) {
    const size_t count = static_cast<size_t>(grid + 1) * (grid + 1);
    if (mCorners.size() != count || mCornerGrid != grid || mCornerLight.corner != light.corner ||
        mCornerLight.edgeU != light.edgeU || mCornerLight.edgeV != light.edgeV) {
        mCorners.assign(count, Corner{});
        mCornerGrid = grid;
        mCornerLight = light;
    }
    return &mCorners[static_cast<size_t>(j) * (grid + 1) + i];
}

std::vector<uint8_t> ContourIntegrator::pattern(const Receiver& r, const RectLight& light,
                                                Occluder::Query& query, AciCounts& counts) {
    const int p = std::max(1, mSettings.grid);
    std::vector<uint8_t> out(static_cast<size_t>(p + 1) * (p + 1), 0);
    if (!facesLight(light, r.point)) return out;
    const Vec3 origin = r.point + mSettings.rayOffset * r.normal;
    for (int j = 0; j <= p; ++j)
        for (int i = 0; i <= p; ++i) {
            const Vec3 target = light.point(double(i) / p, double(j) / p);
            if (glm::dot(target - r.point, r.normal) <= 0.0) continue;
            uint8_t& o = out[static_cast<size_t>(j) * (p + 1) + i];
            if (!mSettings.reuseCorners) {
                ++counts.firstLevelRays;
                o = !query.occluded(origin, target);
                continue;
            }
            Corner* kept = mScratch->reusableCorner(light, p, i, j);
            if (kept->answers(origin)) {
                ++counts.reusedRays;
            } else {
                ++counts.firstLevelRays;
                *kept = traceRay(query, origin, target, mSettings, 0.0, mSettings.distanceGuided);
            }
            o = kept->sample == kVisible;
        }
    return out;
}

Estimate contourIntegral(const Receiver& r, const RectLight& light, Occluder::Query& query,
                         const AciSettings& settings) {
    ContourIntegrator integrator(settings);
    return integrator.evaluate(r, light, query);
}

}  // namespace penumbra
