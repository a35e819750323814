// The distance-guided and tangent modes' geometry: a ray's clearance and distance gradient
// predict where the silhouette crosses a line on the light (newtonAlong), place dichotomy probes
// and vertices (crossingNewton), and give each vertex its tangent line, so that a contour piece
// can be the conic arc tangent to both ends (tangentArc, emitArc).
#include <algorithm>
#include <cmath>
#include <limits>

#include "contour_lattice.h"

namespace penumbra {

namespace {

// The point at parameter t of the rational quadratic Bezier a-K-b of weight w (the tangent arc).
Vec3 conicPoint(const Vec3& a, const Vec3& k, const Vec3& b, double w, double t) {
    const double b0 = (1 - t) * (1 - t), b1 = 2.0 * w * t * (1 - t), b2 = t * t;
    return (b0 * a + b1 * k + b2 * b) / (b0 + b1 + b2);
}

}  // namespace

float ContourIntegrator::Lattice::clearanceOf(LatticePoint q) const {
    return scratch.mClear[settle(q)];
}

Vec3 ContourIntegrator::Lattice::normalOf(LatticePoint q) const {
    const float* t = scratch.mGeometry[settle(q)].normal;
    return Vec3(t[0], t[1], t[2]);
}

// Where q's ray passes closest to the surface, as a fraction of the ray (0 unknown).
double ContourIntegrator::Lattice::closestFractionOf(LatticePoint q) const {
    return scratch.mGeometry[settle(q)].closest;
}

// Whether q was answered by an earlier receiver point's ray (its distances approximate).
bool ContourIntegrator::Lattice::staleOf(LatticePoint q) const {
    return scratch.mGeometry[settle(q)].stale != 0.0f;
}

// The obstacle q's clearance was measured to (-1 unknown).
int ContourIntegrator::Lattice::obstacleOf(LatticePoint q) const {
    return static_cast<int>(scratch.mGeometry[settle(q)].obstacle);
}

// The obstacle nearest the receiver point that blocks q's ray (-1 for a visible one), known
// from the trace itself: unlike obstacleOf, it needs no clearance.
int ContourIntegrator::Lattice::hiderOf(LatticePoint q) const {
    return static_cast<int>(scratch.mGeometry[index(q)].hider);
}

// tangentContour: where the contour crosses the line X(t) = from + t dir (world, on the
// light), predicted from the ray to lattice sample q alone. That ray passes at angular
// clearance c from the surface where the distance gradient is g; moving its end by delta
// on the light changes that clearance by (g . delta) / D to first order (D: the ray's
// length), so the contour is the line g . (X - Q) = -c D. NaN when q's ray knows nothing.
double ContourIntegrator::Lattice::newtonAlong(LatticePoint q, const Vec3& from,
                                               const Vec3& dir) const {
    const double c = clearanceOf(q);
    const Vec3 g = normalOf(q);
    if (!std::isfinite(c) || glm::dot(g, g) == 0.0) return std::nan("");
    const Vec3 target = pointOf(q);
    const double D = glm::length(target - origin);
    const double slope = glm::dot(g, dir);
    if (std::abs(slope) < 1e-9 * glm::length(dir)) return std::nan("");
    return (-c * D - glm::dot(g, from - target)) / slope;
}

// Whether q's ray passes closest to a surface within a few ray offsets of the receiver point:
// that surface is the receiver's own, met at a grazing angle (untrustedTangent's first reason).
bool ContourIntegrator::Lattice::nearOwnStart(LatticePoint q) const {
    const double h = closestFractionOf(q);
    if (!(h > 0.0)) return false;
    const double reach = kOwnSurfaceOffsets * std::abs(self.mSettings.rayOffset);
    return h * glm::length(pointOf(q) - origin) < reach;
}

// Where the contour crosses the line X(x) = from + x dir (world, on the light) between x = lo
// and x = hi, found on a level set's own field: the rays there touch the obstacle q's ray
// measured its clearance to where the smallest trilinear value along them, near the closest
// approach, is zero (within kFieldRootTolerance voxel). Secant steps from q (at x = xq) and
// `guess` (newtonAlong's prediction), each value measured by Occluder::Query::localMinimum near
// where the previous one lay, the root kept inside the bracket [lo, hi] (visible at lo when
// visibleLo). Returns the last estimate; `guess` when q's obstacle is analytic (its Newton steps
// rest on exact distances) or nothing was measured; NaN when every value measured lay on one
// side and the bracket closed on one of its ends (the field puts the crossing outside [lo, hi]).
//
// Why: newtonAlong extrapolates the distances linearly, and the rays see the trilinear zero
// crossing. On a level set's sharp edge that crossing bevels the edge by a fraction of a voxel
// where the distances describe the sharp edge, and the Newton step lands on the sharp one: a
// level-set slab's shadow came out 0.21% of the unoccluded form factor too dark at any lattice
// finer than 2^5 (docs/BENCHMARKS.md, "Seed 605's one-signed difference"), the rotated box of
// random scene 605 up to 0.5%. On small curved shapes (a torus whose tube is two voxels thick) the clearance
// is far from linear over one lattice unit, and Newton vertices fell a third of a unit short.
// A ray whose voxel spans many lattice units (untrustedTangent's second reason) gives no
// tangent line, but its vertex is still moved onto the field: the field is what the rays see,
// however magnified. Newton vertices there all fell short on the visible side (a level-set
// cylinder's distance is convex along the line, so its tangent meets zero early: 0.14 of a unit
// on average, one-signed, on random scene 612), and its penumbra came out 0.05% of the
// unoccluded form factor too dark, halving with each dichotomy step added; on the field, 0.003%.
double ContourIntegrator::Lattice::fieldRoot(LatticePoint q, const Vec3& from, const Vec3& dir,
                                             double xq, double guess, double lo, double hi,
                                             bool visibleLo) {
    const int obstacle = obstacleOf(q);
    if (obstacle < 0 || staleOf(q) || nearOwnStart(q)) return guess;
    const double voxel = query.occluder().voxelSize(static_cast<size_t>(obstacle));
    double tc = closestFractionOf(q);
    if (!(voxel > 0.0) || !(tc > 0.0) || !std::isfinite(clearanceOf(q))) return guess;
    // The field's smallest value along the ray to from + x dir, near where the last one lay
    // (world units; NaN when not measured).
    auto field = [&](double x) {
        const Vec3 target = from + x * dir;
        const double window = kFieldRootWindow * voxel / glm::length(target - origin);
        double at = tc;
        const double f =
            query.localMinimum(static_cast<size_t>(obstacle), origin, target, tc, window, &at);
        if (std::isfinite(f)) tc = at;
        return f;
    };
    // q's own ray starts the secant when it lies on the line (a vertex's bracket end); else a
    // second point one lattice unit from the guess, toward where its value puts the root.
    double a = lo, b = hi;
    double x1 = std::clamp(guess, lo, hi), f1 = field(x1);
    if (!std::isfinite(f1)) return guess;
    double best = x1, bestF = std::abs(f1);
    auto narrow = [&](double x, double f) {
        ((f > 0.0) == visibleLo ? a : b) = x;
        if (std::abs(f) < bestF) best = x, bestF = std::abs(f);
    };
    narrow(x1, f1);
    double x0, f0;
    const Vec3 pq = pointOf(q);
    const double len2 = glm::dot(dir, dir);
    if (glm::length(glm::cross(pq - from, dir)) < 1e-6 * len2) {
        x0 = xq;
        f0 = double(clearanceOf(q)) * closestFractionOf(q) * glm::length(pq - origin);
    } else {
        const double toRoot = (f1 > 0.0) == visibleLo ? 1.0 : -1.0;
        x0 = std::clamp(x1 + toRoot * unit / std::sqrt(len2), lo, hi);
        f0 = field(x0);
        if (!std::isfinite(f0)) return best;
        narrow(x0, f0);
    }
    // Zero within kFieldRootTolerance voxel, and within the field's change over
    // kFieldRootUnitShare of a lattice unit: moving the ray's end by one unit on the light moves
    // its closest approach (at fraction tc) by tc units, and the field by at most that much.
    const double tolerance = std::min(kFieldRootTolerance * voxel, kFieldRootUnitShare * tc * unit);
    for (int step = 0; step < kFieldRootSteps && bestF >= tolerance && f1 != f0; ++step) {
        double x2 = x1 - f1 * (x1 - x0) / (f1 - f0);
        if (!(x2 > a && x2 < b)) x2 = 0.5 * (a + b);
        const double f2 = field(x2);
        if (!std::isfinite(f2)) break;
        narrow(x2, f2);
        x0 = x1, f0 = f1, x1 = x2, f1 = f2;
    }
    // The last secant's root when it falls inside the bracket, else the best point measured;
    // none when every value measured lay on one side and the bracket closed on its end (the
    // field puts the crossing outside [lo, hi]).
    if (bestF >= tolerance && f1 != f0) {
        const double x2 = x1 - f1 * (x1 - x0) / (f1 - f0);
        if (x2 > a && x2 < b) return x2;
    }
    if (bestF >= tolerance && (a == lo || b == hi) && (best == lo || best == hi))
        return std::nan("");
    return best;
}

// Whether q's ray gives no tangent line, for one of two reasons.
// - It passes closest to a surface right at its start, within a few ray offsets of the
//   receiver point: the surface there is the receiver's own, met at a grazing angle whose
//   distance gradient says where its tangent plane lies, not where the silhouette runs on the
//   light (on a saddle, such as a torus's inner wall, the surface rises on both sides of that
//   plane).
// - It passes closest to a level set so near its start that one voxel spans more than
//   kMagnifiedVoxel lattice units on the light (the voxel times the ray's length over the
//   distance to its closest approach): the interpolated surface's sub-voxel undulations,
//   magnified that much, put the Newton steps' and tangent lines' contour lattice units away
//   from where the rays find it. Random scene 8 (a level-set cylinder of radius 5 voxels next to
//   the receivers on the plane) came out up to 7% of the form factor off at such points however
//   fine the lattice, where the paper's and arcs modes converge to the reference. On the
//   bunny's back, in the shadow of its own head, points came out 5% low while a voxel spanned
//   4-16 units (kMagnifiedVoxel was 16 until 2026-12-01).
bool ContourIntegrator::Lattice::untrustedTangent(LatticePoint q) const {
    if (nearOwnStart(q)) return true;
    const double h = closestFractionOf(q);
    if (!(h > 0.0)) return false;
    const int obstacle = obstacleOf(q);
    if (obstacle < 0) return false;
    const double voxel = query.occluder().voxelSize(static_cast<size_t>(obstacle));
    return voxel > kMagnifiedVoxel * unit * h;
}

// The unit normal of the plane of grazing rays through the ray to lattice sample q, made
// exactly perpendicular to that ray (0 when unknown).
Vec3 ContourIntegrator::Lattice::grazingPlane(LatticePoint q, const Vec3& onContour) const {
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
Vertex ContourIntegrator::Lattice::crossingNewton(LatticePoint vis, LatticePoint hid, int steps,
                                                  LatticePoint& finalVis, LatticePoint& finalHid) {
    const int count = 1 << steps;
    const int da = (hid.a - vis.a) / count, db = (hid.b - vis.b) / count;
    auto at = [&](int j) { return LatticePoint{vis.a + j * da, vis.b + j * db}; };
    const Vec3 p0 = pointOf(vis);
    const Vec3 step = pointOf(at(1)) - p0;  // world vector of one position
    // Where the contour is predicted inside [lo, hi] (in positions from vis), and whether
    // that prediction can stand as the vertex: a Newton step from the visible end (outside
    // the surface the distance is exact, and its gradient points at the nearest face or
    // edge, so a sharp silhouette's line comes out right), or a step from the hidden end once
    // the bracket is one position wide (inside, the gradient is only right on smooth
    // surfaces: under a level-set box's edge the depth comes out shallow and the gradient
    // is one face's, and a step of a third of a position from the hidden end was off by one
    // and a half, 2% of the light on the fog scene's ground).
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
                    !staleOf(at(lo)) && !untrustedTangent(at(lo)) && fromVis - lo <= kReach &&
                        obstacleOf(at(lo)) == hiderOf(at(hi)),
                    lo};
        const double fromHid = newtonAlong(at(hi), p0, step);
        if (std::isfinite(fromHid) && fromHid >= lo && fromHid <= hi)
            return {fromHid, hi - lo <= 1 && !staleOf(at(hi)) && !untrustedTangent(at(hi)), hi};
        const float cl = clearanceOf(at(lo)), ch = clearanceOf(at(hi));
        if (cl > 0.0f && ch < 0.0f)
            return {lo + (hi - lo) * double(cl) / (double(cl) - double(ch)), false, -1};
        return {0.5 * (lo + hi), false, -1};
    };
    int lo = 0, hi = count;
    const int minProbes = std::max(1, self.mSettings.guidedProbes);
    // At least minProbes probes, then more only while the prediction cannot stand, until the
    // bracket is one position wide. A probe aimed from the hidden end that lands hidden again
    // is followed by a bisection, so that a hidden end's biased steps cannot creep toward the
    // contour one position at a time.
    bool bisectNext = false;
    for (int probes = 0; hi - lo > 1; ++probes) {
        const Guess g = estimate(lo, hi);
        if (probes >= minProbes && g.final) break;
        const double e = bisectNext ? 0.5 * (lo + hi) : g.e;
        const int j = std::clamp(static_cast<int>(std::floor(e)), lo + 1, hi - 1);
        const bool vis = visible(at(j));
        bisectNext = !bisectNext && !vis && g.from == hi;
        (vis ? lo : hi) = j;
    }
    narrowByTraced(at, lo, hi);
    finalVis = at(lo);
    finalHid = at(hi);
    const Guess g = estimate(lo, hi);
    double e = std::clamp(g.e, double(lo), double(hi));
    // A Newton step's vertex moved to where the rays find the surface (on a level set), when
    // the obstacle its ray measured hides the other end.
    if (g.from >= 0 && obstacleOf(at(lo)) == hiderOf(at(hi)) &&
        peek(at(hi)) != kBelowHorizon) {
        const double root = fieldRoot(at(g.from), p0, step, g.from, e, lo, hi, true);
        if (std::isfinite(root)) e = root;
    }
    // The 3D point from a grazing ray below when there is one; else from the hidden end's hit.
    Vertex v = vertexBetween(at(lo), at(hi), (e - lo) / std::max(1, hi - lo), false);
    bool placed = false;
    if (peek(at(hi)) == kBelowHorizon) {
        placed = true;
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
            if (untrustedTangent(at(j))) continue;
            v.plane = grazingPlane(at(j), v.c);
            if (glm::dot(v.plane, v.plane) == 0.0) continue;
            // The 3D contour point (Fig. 5): where that ray grazes the surface, carried
            // over to the vertex's own line from M, the apex of every edge the integral
            // takes (emit()). On the ray from the ray origin (M moved off its surface) instead,
            // the junction edges C -> I and the arcs' ends left that line: from a point on a
            // level-set torus whose own tube hid part of the light a few voxels from it, with
            // the ray origin 1.5 voxels off, the form factor came out 13% low (bench_bounds
            // --fog, seed 6305; test_coverage.cpp).
            const double h = closestFractionOf(at(j));
            if (h > 0.0) v.i = rec.point + h * (v.c - rec.point);
            placed = h > 0.0;
            v.obstacle = obstacleOf(at(j));
            break;
        }
        if (!placed) v.i = rec.point + double(hitFraction(at(hi))) * (v.c - rec.point);
    }
    return v;
}

bool ContourIntegrator::Lattice::tangentArc(const Vertex& a, const Vertex& b, int x0, int y0, int s,
                                            double thr, Arc& arc) {
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
    // The unit direction of the line a grazing plane cuts on the light (false when the plane
    // lies along the light), and the sine of such a line's angle to the chord.
    auto lineOnLight = [&](const Vec3& plane, Vec3& u) {
        const Vec3 t = glm::cross(plane, lightNormal);
        const double n = glm::length(t);
        if (n < 1e-6) return false;
        u = t / n;
        return true;
    };
    Vec3 ua, ub;
    if (!lineOnLight(a.plane, ua) || !lineOnLight(b.plane, ub)) return false;
    const Vec3 chord = b.c - a.c;
    const double len = glm::length(chord);
    if (len == 0.0) return false;
    auto turnFromChord = [&](const Vec3& u) {
        return glm::dot(glm::cross(u, chord / len), lightNormal);
    };
    const double sinA = turnFromChord(ua), sinB = turnFromChord(ub);
    constexpr double kStraight = 0.01;  // |sin| of the tangents' angle to the chord
    if (std::abs(sinA) < kStraight && std::abs(sinB) < kStraight) {
        arc.straight = true;
        return arcHolds(a, b, 0.5 * (a.c + b.c), x0, y0, s);
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
    const double sideU = double(s) / Na, sideV = double(s) / Nb;
    const Vec2 kuv = light.coordinates(arc.k);
    const double ku = kuv.x, kv = kuv.y;
    const double u0 = double(x0) / Na, v0 = double(y0) / Nb;
    // K within the square (a quarter side of margin), and never beyond the light's border: an arc bulging out
    // of the light would count area the light does not have.
    constexpr double kMargin = 0.25;
    if (ku < u0 - kMargin * sideU || ku > u0 + (1 + kMargin) * sideU ||
        kv < v0 - kMargin * sideV || kv > v0 + (1 + kMargin) * sideV)
        return false;
    if (ku < 0.0 || ku > 1.0 || kv < 0.0 || kv > 1.0) return false;
    const double triangle = std::abs(edgeF(a.c, arc.k) + edgeF(arc.k, b.c) + edgeF(b.c, a.c));
    if (triangle < 1.5 * thr) {
        arc.w = 1.0;
        const Vec3 conicMid = 0.25 * (a.c + b.c) + 0.5 * arc.k;
        if (!arcHolds(a, b, conicMid, x0, y0, s)) return false;
        // Where K lies near one end, the parabola's middle lies near that end too, and the
        // probes beside it say nothing of the chord's other half: the probes are asked again
        // beside the parabola's point over the chord's middle. (A bumpy silhouette left such
        // a triangle over a third of its chord, a lattice unit deep: the bunny's ground at
        // n = 4, 1.7% of the unoccluded F too bright, within its bound; now 0.75%.)
        // Along the chord the parabola is at 2 t (1 - t) along + t^2 (K's fraction `along`),
        // 1/2 at the root of (1 - 2 along) t^2 + 2 along t - 1/2 taken in its stable form.
        const double t = 1.0 / (2.0 * along + std::sqrt(4.0 * along * along + 2.0 - 4.0 * along));
        const Vec3 over = conicPoint(a.c, arc.k, b.c, 1.0, t);
        return glm::length(over - conicMid) <= unit || arcHolds(a, b, over, x0, y0, s);
    }
    // One ray on the line from the chord's middle to K, at the lattice point nearest 3/4.
    const Vec3 m = 0.5 * (a.c + b.c);
    const LatticePoint q = nearestInSquare(m + 0.75 * (arc.k - m), x0, y0, s);
    if (sample(q, false) == kBelowHorizon || untrustedTangent(q)) return false;
    double lambda = newtonAlong(q, m, arc.k - m);
    if (!std::isfinite(lambda)) return false;
    // One Newton step from a sample far from the contour can misplace the shoulder (the
    // clearance is not linear across the light): when the step lands more than a lattice
    // unit away, a second ray at the landing point places it again from there.
    LatticePoint shoulders[2] = {q, q};
    {
        const LatticePoint q2 =
            nearestInSquare(m + std::clamp(lambda, 0.0, 1.0) * (arc.k - m), x0, y0, s);
        if (std::abs(q2.a - q.a) + std::abs(q2.b - q.b) > 1 &&
            sample(q2, false) != kBelowHorizon) {
            const double again = newtonAlong(q2, m, arc.k - m);
            if (std::isfinite(again)) lambda = again;
            shoulders[1] = q2;
        }
    }
    // The arc crosses the line m -> K at fraction lambda; the visible side is on the left of
    // a -> b. On a level set the crossing is then found on its own field from the last
    // shoulder ray (fieldRoot; with the Newton step alone a level-set box's silhouette corner
    // was cut, 0.4% of the form factor too bright on random scene 605).
    const Vec3 mk = arc.k - m;
    const double mk2 = glm::dot(mk, mk);
    const bool kLeft = glm::dot(glm::cross(b.c - a.c, arc.k - a.c), lightNormal) > 0.0;
    if (a.obstacle >= 0 && a.obstacle == b.obstacle && obstacleOf(shoulders[1]) == a.obstacle) {
        const double xq = glm::dot(pointOf(shoulders[1]) - m, mk) / mk2;
        lambda = fieldRoot(shoulders[1], m, mk, xq, std::clamp(lambda, 0.0, 1.0), 0.0, 1.0, !kLeft);
        // The field puts the contour outside the triangle a K b: the tangent lines are wrong.
        if (!std::isfinite(lambda)) return false;
    }
    // The arc must put each shoulder ray on the side it was seen on (a safeguard at no cost in
    // rays): the Newton step rests on a gradient that can be wrong (a level set's sharp rim,
    // where it averages two faces), and an arc that contradicts a traced ray is checked and
    // refined as in section 3.2 instead.
    {
        const double tol = unit / std::sqrt(mk2);
        for (const LatticePoint& sq : shoulders) {
            const float sv = peek(sq);
            if (sv == kBelowHorizon) continue;
            const double t = glm::dot(pointOf(sq) - m, mk) / mk2;
            if (std::abs(t - lambda) <= tol) continue;  // on the arc, within a lattice unit
            const bool predictedVisible = (t > lambda) == kLeft;
            if (predictedVisible != (sv == kVisible)) return false;
        }
    }
    const double l = std::clamp(lambda, 0.0, 1.0);
    // A shoulder ray hidden by another obstacle than the arc's, or passing closest to another
    // one: a second silhouette bulges into the piece or runs beside it, which the tangent lines
    // of one cannot describe (a small sphere's shadow joined to a large one's), and the Newton
    // step above rested on that other obstacle's clearance. Checked and refined as in section
    // 3.2. (With the hidden ray alone, a clear shoulder ray beside a small sphere joined to a
    // large one bent the large one's arc by the small one's clearance: 0.62% of the form
    // factor too dark at a point of bench_coverage's scene 38.)
    if (a.obstacle >= 0)
        for (const LatticePoint& sq : shoulders)
            if (obstacleOf(sq) >= 0 && obstacleOf(sq) != a.obstacle) return false;
    // On any conic the point over the chord's middle (the shoulder) has its tangent parallel to
    // the chord. A visible shoulder ray whose own tangent line turns away from the chord says
    // that the silhouette between a and b is not one conic: a box's, its corners rounded by the
    // level set, bends twice there, and on a piece 33 lattice units long the arc through the
    // shoulder cut up to three units into its shadow (random scene 720, F 0.45% too bright;
    // the shoulder's tangent 4 degrees off the chord). Such a piece is checked and refined as in
    // section 3.2 when it is long enough for the turn to matter (a turn of 0.05 over 16 units:
    // about a lattice unit across the piece). (On bench_coverage's spheres the shoulder's
    // tangent lies within 0.05 of the chord's direction in nine arcs of ten; with no condition on
    // the length, at 0.1, random scene 5's many short pieces past an analytic box's and
    // cylinders' corners took 15% more rays for nothing measurable, against 3% now.)
    constexpr double kShoulderTurn = 0.05;  // |sin| of the angle
    constexpr double kShoulderSpan = 16.0;  // lattice units of chord
    if (l > 0.02 && l < 0.98 && len > kShoulderSpan * unit) {
        for (const LatticePoint& sq : {shoulders[1], shoulders[0]}) {
            Vec3 us;
            if (peek(sq) != kVisible || untrustedTangent(sq) ||
                !lineOnLight(grazingPlane(sq, m + l * mk), us))
                continue;
            if (std::abs(turnFromChord(us)) > kShoulderTurn) return false;
            break;
        }
    }
    arc.probed = true;
    if (l <= 0.02) {
        arc.straight = true;
    } else if (l >= 0.98) {
        arc.w = std::numeric_limits<double>::infinity();  // a corner at K
    } else {
        arc.w = l / (1.0 - l);
    }
    // The shoulder ray tests the piece along the line m -> K only. When K lies near one end
    // (one tangent line runs almost along the chord) that line does too, and says nothing of
    // how far the contour bulges across the chord: rays beside the arc's middle check that.
    // (Two vertices of a level-set box's silhouette whose tangent lines met next to one of
    // them took an arc along the chord past a corner of the silhouette: 0.5% of the form
    // factor on random scene 605.)
    // The arc's point over chord fraction f: where the polygon of the emitted arc (or the
    // corner a K b) crosses the chord's perpendicular there.
    auto overChord = [&](double f) {
        const double len2 = glm::dot(chord, chord);
        auto along = [&](const Vec3& p) { return glm::dot(p - a.c, chord) / len2; };
        constexpr int kSamples = 32;
        Vec3 prev = a.c, at = a.c + f * chord;
        for (int i = 1; i <= kSamples; ++i) {
            Vec3 p;
            if (std::isfinite(arc.w)) {
                p = conicPoint(a.c, arc.k, b.c, arc.w, double(i) / kSamples);
            } else {
                p = i < kSamples / 2 ? a.c + (2.0 * i / kSamples) * (arc.k - a.c)
                                     : arc.k + (2.0 * i / kSamples - 1.0) * (b.c - arc.k);
            }
            const double u0 = along(prev), u1 = along(p);
            if ((u0 - f) * (u1 - f) <= 0.0 && u1 != u0) {
                at = prev + ((f - u0) / (u1 - u0)) * (p - prev);
                break;
            }
            prev = p;
        }
        return at;
    };
    if (!arc.straight && height < 0.5 * std::sqrt(mk2) && !arcHolds(a, b, overChord(0.5), x0, y0, s))
        return false;
    // On the coarser lattice (adaptive steps) a long piece whose arc is no ellipse's (w > 1: a
    // hyperbola, or a corner at K) is probed beside its points over the chord's thirds too. A
    // bumpy silhouette meets the arc at both ends, at the shoulder and over the chord's
    // middle, and leaves it in between: on the bunny's ground next to its foot a piece 33
    // lattice units long with w = 3.5 ran up to 6 units inside the silhouette two thirds of
    // the way along, 2.4% of F too dark (the finer lattice refines such pieces and is within
    // 0.03%). Not on the finer lattice, whose probes stand half as far off, and not on an
    // ellipse's arc (a sphere's outline), where the thirds cost rays and found nothing.
    if (coarser && !arc.straight && arc.w > 1.0 && len > kShoulderSpan * unit)
        for (double f : {1.0 / 3.0, 2.0 / 3.0})
            if (!arcHolds(a, b, overChord(f), x0, y0, s)) return false;
    return true;
}

// Whether rays next to `mid`, a point of the arc from a to b, see what the arc says: the lattice
// points nearest to `mid` moved kArcProbe lattice units to either side (visible on the left of
// a -> b). An arc taken with no shoulder ray (straight, or a thin tangent triangle) rests on its
// two tangent lines alone, and those can be wrong: on random seed 8 of bench_random (a level-set
// cylinder seen from the ground next to its base) the gradient at the rim, where the side
// meets the cap, tilted a tangent line, and a vertex next to a grazing ray's sliver of light
// took the silhouette's tangent from the wrong part of it; arcs 6% to 50% of the form factor
// off passed with no ray. One that fails is checked and refined as in section 3.2.
bool ContourIntegrator::Lattice::arcHolds(const Vertex& a, const Vertex& b, const Vec3& mid, int x0,
                                          int y0, int s) {
    const Vec3 chord = b.c - a.c;
    const Vec3 left = glm::normalize(glm::cross(lightNormal, chord));
    // On the coarser lattice (adaptive steps) one unit off: its unit is two of the finer's, and
    // at 1.5 a bumpy level set's silhouette (the bunny's) left arcs by over a unit unseen.
    const double kArcProbe = coarser ? 1.0 : 1.5;
    for (int side = 0; side < 2; ++side) {
        const bool wantVisible = side == 0;
        const LatticePoint q =
            nearestInSquare(mid + (wantVisible ? 1.0 : -1.0) * kArcProbe * unit * left, x0, y0, s);
        // Still on the intended side after rounding, by half a unit at least.
        const double off = glm::dot(pointOf(q) - mid, left) * (wantVisible ? 1.0 : -1.0);
        if (off < 0.5 * unit) continue;
        const float sv = sample(q, false);
        if (sv == kBelowHorizon) continue;
        if ((sv == kVisible) != wantVisible) return false;
    }
    return true;
}

// Emits the arc from a to b (8 chords; the polygon a K b for a corner). Obstacle points
// along it take the hit fraction interpolated between a's and b's.
void ContourIntegrator::Lattice::emitArc(const Vertex& a, const Vertex& b, const Arc& arc) {
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
    // Four pieces, t in [0, 1/4], ..., [3/4, 1], each a conic arc of its own: its end points,
    // its tangent lines' meeting point K' and its weight w' (the blossom of the arc's
    // homogeneous control points at (t0, t0), (t0, t1), (t1, t1)). The area between a piece and
    // its chord is conicSegmentShare(w') of the triangle P0' K' P2', so each piece is emitted
    // as that share of its tangent triangle's two legs plus the rest of its chord.
    // Eight straight chords, as until 2026-12-02, lie inside a convex arc and cut its segments
    // off: an exact sphere's elliptic penumbra came out 0.07-0.13% of the unoccluded form factor
    // too bright. Until 2026-12-05 each piece was the parabola through its ends and its middle
    // point with its axis across the chord (parabolaWeight), which extrapolates where the
    // middle point lies near one end: at a sharply turning arc (weight far above 1, the conic
    // hugging its corner) a piece came out 2.6 times its inscribed triangle, and a ground point
    // under a tilted hexagon light 0.16 from the light's plane, with a capsule reaching behind
    // it, got 4.5% more than the unoccluded form factor (bench_bounds --lights mixed
    // --light-scale 5, seed 3209).
    constexpr int kPieces = 4;
    struct Homogeneous {
        Vec3 p;
        double w;
    };
    const Homogeneous h0{a.c, 1.0}, h1{arc.w * arc.k, arc.w}, h2{b.c, 1.0};
    auto blossom = [&](double u, double v) {
        const double c0 = (1.0 - u) * (1.0 - v), c1 = (1.0 - u) * v + u * (1.0 - v), c2 = u * v;
        return Homogeneous{c0 * h0.p + c1 * h1.p + c2 * h2.p, c0 * h0.w + c1 * h1.w + c2 * h2.w};
    };
    Vec3 fromI = a.i;
    for (int i = 1; i <= kPieces; ++i) {
        const double t0 = double(i - 1) / kPieces, t1 = double(i) / kPieces;
        const Homogeneous q0 = blossom(t0, t0), q1 = blossom(t0, t1), q2 = blossom(t1, t1);
        const Vec3 k = q1.p / q1.w, c = i == kPieces ? b.c : q2.p / q2.w;
        const double w = conicSegmentShare(q1.w / std::sqrt(q0.w * q2.w));
        const Vec3 ik = onObstacle(k, 0.5 * (t0 + t1)), ie = i == kPieces ? b.i : onObstacle(c, t1);
        emit(fromI, ik, w);
        emit(ik, ie, w);
        emit(fromI, ie, 1.0 - w);
        fromI = ie;
    }
}

}  // namespace penumbra
