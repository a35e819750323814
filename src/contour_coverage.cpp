// Certified coverage (AciSettings::coverage): every point of the light inside a disc that a
// shadow ray's certificate proves, or within epsilon of a located contour piece; rays where
// neither holds, a new pass where one contradicts the contour, and the error bound from what
// stays unproven.
#include <algorithm>
#include <cassert>
#include <cmath>
#include <limits>

#include "contour_lattice.h"

namespace penumbra {

// Coverage: a ray to the light's centre; true when its disc covers the whole light (which
// is then wholly visible or wholly hidden, and integrated). No ray when no obstacle's footprint
// meets the light, or when one obstacle's kernel hides all of it.
bool ContourIntegrator::Lattice::wholeLight() {
    const LatticePoint centre{Na / 2, Nb / 2};
    const Vec3 pc = pointOf(centre);
    // The horizon cuts it: the passes handle that. For a whole disc, the circle itself is
    // asked, not its frame's corners (which lie below the horizon of a receiver that sees the
    // whole disc at a grazing angle: the passes then integrated the lit disc 0.19% short, with
    // a bound of 0; bench_bounds --lights mixed --fog, seed 3510).
    if (light.shape == LightShape::Disc && !isDiscPiece(light)) {
        const Vec3 tilt = rec.normal - glm::dot(rec.normal, lightNormal) * lightNormal;
        if (!horizonFree && above(light.center) <= light.radius * glm::length(tilt)) return false;
    } else {
        for (const Vec3& q : light.polygon())
            if (above(q) <= 0.0) return false;
    }
    const bool lit = outsideFootprints(0.0, 0.0, Na, Nb);
    if (lit || scratch.mFootprints.hidden(0.0, 0.0, 1.0, 1.0)) {
        // No obstacle's footprint meets the light (all of it lit), or one's kernel hides all
        // of it: no ray. The centre's sample records the answer for the caller.
        const size_t idx = index(centre);
        scratch.mStamp[idx] = scratch.mGeneration;
        scratch.mSample[idx] = lit ? kVisible : 0.0f;
        if (lit) emitWhole();
        return true;
    }
    wantWhole = true;
    const bool vis = visible(centre, true);
    wantWhole = false;
    if (peek(centre) == kBelowHorizon) return false;  // the frame's centre emits nothing
    const Certificate& cert = scratch.mCert[index(centre)];
    if (light.shape == LightShape::Disc && !isDiscPiece(light)) {
        // The frame's centre is the disc's: its radius covers it.
        if (!(light.radius < cert.radius)) return false;
    } else {
        for (const Vec3& q : light.polygon())
            if (!(glm::length(q - pc) < cert.radius)) return false;
    }
    if (vis) emitWhole();
    return true;
}

// Integrates the whole light (every point of it visible).
void ContourIntegrator::Lattice::emitWhole() {
    if (isDiscPiece(light)) {
        // A segment of a disc (discPiecesAboveHorizon): its chord along the frame's first
        // edge, then the arc back, counterclockwise.
        const Vec3 from = light.corner, to = light.corner + light.edgeU;
        emit(from, to);
        const EdgeDerivative e = discArcG(light, to, from, rec.point, self.mSettings.gradient);
        g += e.g;
        scratch.mPassEdgesValid = false;  // a disc's arc: not kept (recordContour)
        if (self.mSettings.gradient) dg += e.dg;
    } else if (light.shape == LightShape::Disc) {
        const Vec3 start = light.center + light.radius * glm::normalize(light.edgeU);
        const EdgeDerivative e = discArcG(light, start, start, rec.point, self.mSettings.gradient);
        g += e.g;
        scratch.mPassEdgesValid = false;  // a disc's arc: not kept (recordContour)
        if (self.mSettings.gradient) dg += e.dg;
    } else {
        const std::vector<Vec3> poly = light.polygon();
        for (size_t i = 0; i < poly.size(); ++i) emit(poly[i], poly[(i + 1) % poly.size()]);
    }
}

// The footprints and kernels of the obstacles the query looks at (light_footprint.h; when a
// footprint is unbounded, none is used and outsideFootprints() is always false).
void ContourIntegrator::Lattice::findFootprints() {
    scratch.mFootprints.build(query.occluder(), query.restriction(), origin, light);
}

// Whether the lattice rectangle [a0, a1] x [b0, b1] lies outside every footprint.
bool ContourIntegrator::Lattice::outsideFootprints(double a0, double b0, double a1, double b1) const {
    return scratch.mFootprints.outside(a0 / Na, b0 / Nb, a1 / Na, b1 / Nb);
}

// Whether the footprints prove the cell (a0, b0, side `size`): it lies outside every one (so it
// is visible) or inside some obstacle's kernel (so it is hidden), and the last pass's contour
// says the same all over it (every leaf that holds its centre is a square of that answer, or a
// contour square whose nearest piece has the cell on that side, farther than the cell's reach).
// A cell the footprints prove but the contour contradicts (a window between two obstacles'
// footprints inside a square the pass found hidden, say) is left to coverage, whose ray there
// contradicts the contour: proven ground that the contour gets wrong would be an error outside
// the bound.
// `footprint`: what LightFootprints::classify() says of the cell, found here when
// kFootprintUnknown (a cell inside one its parent was classified 1 or 0 inherits that answer).
bool ContourIntegrator::Lattice::footprintProves(double a0, double b0, double size,
                                                 int& footprint) const {
    if (footprint == kFootprintUnknown)
        footprint = scratch.mFootprints.classify(a0 / Na, b0 / Nb, (a0 + size) / Na, (b0 + size) / Nb);
    const int answer = footprint;
    if (answer < 0) return false;
    const LatticePoint q{static_cast<int>(std::floor(a0 + 0.5 * size)),
                         static_cast<int>(std::floor(b0 + 0.5 * size))};
    const Vec3 c = at(a0 + 0.5 * size, b0 + 0.5 * size);
    const double reach = size * cellReach;
    bool held = false;
    const bool other = forLeavesHolding(q, [&](uint32_t i) {
        held = true;
        const Leaf& leaf = scratch.mLeaves[i];
        if (leaf.type != 2) return leaf.type != answer;
        double best;
        return nearestSide(leaf, c, best) != answer || !(best > reach);
    });
    return held && !other;
}

// Form factor of the light's whole frame, for bounds.
double ContourIntegrator::Lattice::wholeFormFactor() const {
    const Vec3 p0 = pointOf({0, 0}), p1 = pointOf({Na, 0}), p2 = pointOf({Na, Nb}), p3 = pointOf({0, Nb});
    return std::abs(edgeF(p0, p1) + edgeF(p1, p2) + edgeF(p2, p3) + edgeF(p3, p0));
}

// Whether the part of the cell (lattice coordinates a0, b0, side `size`, centre `centre` on the
// light) above the horizon lies in one of the gathered discs.
bool ContourIntegrator::Lattice::cellInDisc(double a0, double b0, double size,
                                            const Vec3& centre) const {
    // Most discs are far from most cells: a disc that cannot reach the cell's centre plus the
    // cell's reach holds none of its points (mayHold, compared squared here), and only the
    // others are checked point by point. The points (the cell's corners above the horizon and
    // the horizon's crossings of its sides) are found once, when a disc first may hold them.
    const double reach = size * cellReach;
    Vec3 pts[8] = {};
    int n = -1;  // not found yet
    auto findPoints = [&] {
        const Vec3 q[4] = {at(a0, b0), at(a0 + size, b0), at(a0 + size, b0 + size), at(a0, b0 + size)};
        double h[4];
        for (int i = 0; i < 4; ++i) h[i] = above(q[i]);
        n = 0;
        for (int i = 0; i < 4; ++i) {
            const int j = (i + 1) & 3;
            if (h[i] > 0.0) pts[n++] = q[i];
            if ((h[i] > 0.0) != (h[j] > 0.0))
                pts[n++] = q[i] + (h[i] / (h[i] - h[j])) * (q[j] - q[i]);
        }
    };
    for (const Disc& d : scratch.mDiscs) {
        if (!(d.r > 0.0)) continue;
        const double bound = (d.r + reach) * (1.0 + 1e-9) + 1e-6 * unit;
        const Vec3 e0 = centre - d.c;
        if (glm::dot(e0, e0) > bound * bound) continue;  // mayHold() false
        if (n < 0) {
            findPoints();
            if (n == 0) return true;  // below the horizon: hidden, no ray needed
        }
        const double r2 = d.r * d.r;
        bool all = true;
        for (int i = 0; i < n && all; ++i) {
            const Vec3 e = pts[i] - d.c;
            all = glm::dot(e, e) < r2;
        }
        if (all) return true;
    }
    // No disc holds it; a cell wholly below the horizon needs none.
    if (n < 0) {
        if (above(centre) > 1e-9 * unit) return false;  // some corner is above
        findPoints();
    }
    return n == 0;
}

// False when disc d, `dist` from a cell's centre, holds no point within `reach` of that centre
// (true: it may), with a margin far above rounding, so that cellInDisc() answers as if it had
// checked every point.
bool ContourIntegrator::Lattice::mayHold(const Disc& d, double dist, double reach) const {
    const double r = d.r;
    if (!(r > 0.0)) return false;
    return dist <= (r + reach) * (1.0 + 1e-9) + 1e-6 * unit;
}

// Whether the cell lies wholly outside a polygon light's cutting edges or a disc's circle.
bool ContourIntegrator::Lattice::cellOutside(double a0, double b0, double size) const {
    const Vec3 q[4] = {at(a0, b0), at(a0 + size, b0), at(a0 + size, b0 + size), at(a0, b0 + size)};
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

// Distance from a light point to a contour segment, and its square (for comparisons).
double ContourIntegrator::Lattice::distanceToSegment(const Vec3& p, const Segment& g) {
    return std::sqrt(distance2ToSegment(p, g));
}

double ContourIntegrator::Lattice::distance2ToSegment(const Vec3& p, const Segment& g) {
    const Vec3 d = g.b - g.a;
    const double dd = glm::dot(d, d);
    const double t = dd > 0.0 ? std::clamp(glm::dot(p - g.a, d) / dd, 0.0, 1.0) : 0.0;
    const Vec3 e = g.a + t * d - p;
    return glm::dot(e, e);
}

// Collects every uncovered cell of side `minSize` in the cell (a0, b0, size) into
// scratch.mUncovered, with its centre's distance to the nearest disc that would prove it.
// Only a disc of the full certificate proves a cell, next to a located contour piece too: a
// disc that excludes every obstacle but the piece's own (Certificate::radiusOthers) once did
// there, as if the piece were that obstacle's whole silhouette near it, and a capsule's thin
// shadow reaching past the piece into the square went unseen (random scene 5: 2% of the form
// factor off at 1.3 times the bound; regression test in test_coverage.cpp).
void ContourIntegrator::Lattice::uncoveredCells(double a0, double b0, double size,
                                                double minSize, int footprint, bool checked) const {
    const Vec3 c = at(a0 + 0.5 * size, b0 + 0.5 * size);
    // The distance to the nearest located contour piece (its strip, within epsilon of it, its
    // own term of the bound, is proven ground too).
    double near = -1.0;
    auto nearest = [&] {
        if (near < 0.0) {
            double near2 = std::numeric_limits<double>::infinity();
            for (const Segment& g : scratch.mNearSegs)
                if (!g.border) near2 = std::min(near2, distance2ToSegment(c, g));
            near = std::sqrt(near2);
        }
        return near;
    };
    // The final count: a cell within epsilon of a located contour piece belongs to the piece's
    // strip, not to what coverage left open (first, as the cheapest test: the strips along
    // the contour are where the final count cuts most cells).
    if (minSize <= 1.0 && size * cellReach <= epsWorld && nearest() + size * cellReach <= epsWorld)
        return;
    if (!checked && provenWithoutDiscs(a0, b0, size, footprint)) return;
    const int inherited = footprint >= 0 ? footprint : kFootprintUnknown;
    if (cellInDisc(a0, b0, size, c)) return;
    if (size > minSize) {
        const double h = 0.5 * size;
        for (int q = 0; q < 4; ++q)
            uncoveredCells(a0 + (q & 1) * h, b0 + (q >> 1) * h, h, minSize, inherited);
        return;
    }
    if (!emits(c)) return;
    Uncovered u{a0, b0, size, std::numeric_limits<double>::infinity(), c};
    for (const Disc& d : scratch.mDiscs) gapTo(u, d, glm::length(u.centre - d.c));
    if (!std::isfinite(u.gap)) {
        // No disc near enough to hold a point of it was gathered: its gap is to the nearest of
        // all of them. (Left infinite, every such cell tied at the top of coverage's order and
        // the newest won the tie: coverage went depth first into the quarters of one cell. At
        // a far ground point under a disc light all 96 rays went to one corner of it, and a
        // box's shadow elsewhere on the light, 3.7% of F0, went unseen; bench_bounds --lights
        // mixed, seed 9120.)
        for (const Disc& d : scratch.mTracedDiscs) gapTo(u, d, glm::length(u.centre - d.c));
    }
    u.gap = std::min(u.gap, nearest() - epsWorld);
    u.key = coverageKey(u);
    u.weight = coverageWeight(c);
    scratch.mUncovered.push_back(u);
}

// Whether the cell needs no disc: it emits nothing, or the footprints prove what the contour
// says there.
bool ContourIntegrator::Lattice::provenWithoutDiscs(double a0, double b0, double size,
                                                    int& footprint) const {
    return (shaped && cellOutside(a0, b0, size)) || footprintProves(a0, b0, size, footprint);
}

// Narrows an uncovered cell's distance to proven ground by one disc, `dist` from its centre.
void ContourIntegrator::Lattice::gapTo(Uncovered& u, const Disc& d, double dist) {
    u.gap = std::min(u.gap, dist - d.r);
}

// How far from proven ground a cell may reach: a cell of side s is done when every centre of
// its cells of kCoverageCell units is near proven ground, i.e. its own centre's gap plus the
// distance to the farthest of them ((s - kCoverageCell) x cellReach, along the cell's longer
// diagonal: exact for a parallelogram light and unequal units) is small; coverage's next ray
// goes to the largest.
double ContourIntegrator::Lattice::coverageKey(const Uncovered& u) const {
    return u.gap + (u.size - kCoverageCell) * cellReach;
}

// Coverage's order among the cells: by key x weight, the weight the square root of the
// form factor kernel at the cell's centre, so that key x weight is (up to a constant) the
// square root of the form factor of the unproven disc of radius key there: coverage spends
// its rays where unproven light weighs most, and each cell is still done when its key is
// below what coverage asks. By key alone (farthest from proven ground first), on a light 13
// across whose plane passed 0.07-0.5 from the receiver, the 48 rays went where the kernel is
// negligible and a window holding 55% of the form factor went unfound (bench_random
// --light-scale 15, seed 3102). A floor keeps cells whose centre lies below the horizon in
// order behind the rest.
double ContourIntegrator::Lattice::coverageWeight(const Vec3& centre) const {
    const Vec3 d = centre - rec.point;
    const double r2 = glm::dot(d, d);
    if (!(r2 > 0.0)) return 1.0;
    const double r = std::sqrt(r2);
    const double cosR = std::max(0.0, glm::dot(d, rec.normal) / r);
    const double cosL = std::abs(glm::dot(d, lightNormal) / r);
    return std::sqrt(std::max(cosR * cosL, 1e-12) / r2);
}

// Coverage's order: key x weight, where the key is no larger than the most a ray in the cell
// could prove (its reach, as the key measures from the cell's centre). Certificates shrink near
// an obstacle that rays graze: a far ground point saw a triangle light's corner past a
// cylinder's flat end, and every ray there proved under a 64th of what it asked, so those
// cells stayed farthest from proven ground and took all 96 rays, one beside the other, while
// the cylinder's shadow elsewhere on the light, 3% of F0, went unseen (bench_bounds --lights
// mixed --fog, seed 11213). By reach, rays there wait until the rest of the light is as far
// from proven ground as they could prove.
double ContourIntegrator::Lattice::coveragePriority(const Uncovered& u) const {
    return std::min(u.key, u.reach + (u.size - kCoverageCell) * cellReach) * u.weight;
}

// Form factor of the uncovered cells (the elementary form factor at each centre).
double ContourIntegrator::Lattice::uncoveredFormFactor() const {
    // A cell's area is the frame's over the lattice's cells (for a polygon or disc the frame
    // is larger than what emits: until 2026-12-05 the emitting area was divided, and a
    // triangle's uncovered cells counted half).
    const double area = glm::length(glm::cross(light.edgeU, light.edgeV)) / (double(Na) * Nb);
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
// cut down to single lattice units against every disc and contour strip near it, so that the bound
// counts the slivers between discs rather than whole cells.
double ContourIntegrator::Lattice::finalUncoveredFormFactor() {
    std::vector<Uncovered> coarse;
    coarse.swap(scratch.mUncovered);
    for (const Uncovered& u : coarse) {
        const int a0 = static_cast<int>(u.a0), b0 = static_cast<int>(u.b0), s = static_cast<int>(u.size);
        gatherNear(a0, b0, s);
        uncoveredCells(u.a0, u.b0, u.size, 1.0);
    }
    return uncoveredFormFactor();
}

// Gathers the discs and contour segments that may matter for the leaf square (x0, y0, s).
void ContourIntegrator::Lattice::gatherNear(int x0, int y0, int s) {
    const Vec3 centre = at(x0 + 0.5 * s, y0 + 0.5 * s);
    const double half = 0.5 * std::max(glm::length(pointOf({x0 + s, y0 + s}) - pointOf({x0, y0})),
                                       glm::length(pointOf({x0 + s, y0}) - pointOf({x0, y0 + s})));
    auto nearDisc = [&](const Disc& d) {
        const Vec3 e = d.c - centre;
        return glm::dot(e, e) < (d.r + half) * (d.r + half);
    };
    const double segReach2 = (segmentReach() + half) * (segmentReach() + half);
    auto nearSeg = [&](const Segment& g) { return distance2ToSegment(centre, g) < segReach2; };
    scratch.mDiscs.clear();
    scratch.mNearSegs.clear();
    // Leaves, and the cells coverage cuts them into, lie in one first-level square.
    const int b = bucketOf(x0, y0, s);
    assert(b >= 0);
    for (uint32_t i : scratch.mDiscBuckets[static_cast<size_t>(b)])
        if (nearDisc(scratch.mTracedDiscs[i])) scratch.mDiscs.push_back(scratch.mTracedDiscs[i]);
    for (uint32_t i : scratch.mSegBuckets[static_cast<size_t>(b)])
        if (nearSeg(scratch.mSegs[i])) scratch.mNearSegs.push_back(scratch.mSegs[i]);
}

// ---------------------------------------------------------------------------------------------
// The spatial index. A square inside bucket B lies in B's circumscribed disc together with its
// own (their centres are at most B's half diagonal minus the square's apart), so whatever comes
// within some distance of the square's centre plus its half diagonal comes within that distance
// of B's centre plus B's half diagonal: a bucket keeps everything that test passes.

Vec3 ContourIntegrator::Lattice::bucketCentre(int i, int j) const {
    return light.point((i + 0.5) / pa, (j + 0.5) / pb);
}

// Adds `index` to the buckets whose centre may lie within `reach` (world length) of the lattice
// box [a0, a1] x [b0, b1] and for whose centre keep() holds.
template <class Keep>
void ContourIntegrator::Lattice::addToBuckets(std::vector<std::vector<uint32_t>>& buckets,
                                              uint32_t index, double a0, double b0, double a1,
                                              double b1, double reach, const Keep& keep) {
    const double da = reach * perUnitA + 1.0, db = reach * perUnitB + 1.0;
    auto range = [&](double lo, double hi, int last, int& i0, int& i1) {
        i0 = static_cast<int>(std::clamp(std::floor(lo / bucketSide), 0.0, double(last)));
        i1 = static_cast<int>(std::clamp(std::floor(hi / bucketSide), 0.0, double(last)));
    };
    int i0, i1, j0, j1;
    range(a0 - da, a1 + da, pa - 1, i0, i1);
    range(b0 - db, b1 + db, pb - 1, j0, j1);
    for (int j = j0; j <= j1; ++j)
        for (int i = i0; i <= i1; ++i)
            if (keep(bucketCentre(i, j))) buckets[static_cast<size_t>(j) * pa + i].push_back(index);
}

// Disc `index`, centred on lattice point `at`.
void ContourIntegrator::Lattice::addDisc(uint32_t index, LatticePoint at) {
    const Disc& d = scratch.mTracedDiscs[index];
    const double r = d.r;
    const double reach = (r + bucketReach) * (1.0 + 1e-9) + 1e-6 * unit;
    addToBuckets(scratch.mDiscBuckets, index, at.a, at.b, at.a, at.b, reach,
                 [&](const Vec3& c) { return glm::length(d.c - c) < reach; });
}

void ContourIntegrator::Lattice::addSegments(uint32_t seg0) {
    for (auto i = seg0; i < scratch.mSegs.size(); ++i) {
        const Segment& g = scratch.mSegs[i];
        const double reach = (segmentReach() + bucketReach) * (1.0 + 1e-9) + 1e-6 * unit;
        const Vec2 ua = light.coordinates(g.a), ub = light.coordinates(g.b);
        addToBuckets(scratch.mSegBuckets, i, std::min(ua.x, ub.x) * Na, std::min(ua.y, ub.y) * Nb,
                     std::max(ua.x, ub.x) * Na, std::max(ua.y, ub.y) * Nb, reach,
                     [&](const Vec3& c) { return distanceToSegment(c, g) < reach; });
    }
}

void ContourIntegrator::Lattice::addLeaf(const Leaf& leaf) {
    const auto index = static_cast<uint32_t>(scratch.mLeaves.size());
    scratch.mLeaves.push_back(leaf);
    const int b = bucketOf(leaf.x0, leaf.y0, leaf.s);
    assert(b >= 0);  // squares never outgrow a first-level square
    scratch.mLeafBuckets[static_cast<size_t>(b)].push_back(index);
}

// The bucket holding the lattice square (x0, y0, s), -1 when no one bucket does.
int ContourIntegrator::Lattice::bucketOf(int x0, int y0, int s) const {
    const int i = x0 / bucketSide, j = y0 / bucketSide;
    if (i >= pa || j >= pb || x0 + s > (i + 1) * bucketSide || y0 + s > (j + 1) * bucketSide) return -1;
    return j * pa + i;
}

// Calls f(index) for every leaf holding lattice point q (inside or on its border), in no
// particular order, until f returns true; true then.
template <class F>
bool ContourIntegrator::Lattice::forLeavesHolding(LatticePoint q, const F& f) const {
    int is[2], js[2], ni = 0, nj = 0;
    const int ia = std::min(q.a / bucketSide, pa - 1), jb = std::min(q.b / bucketSide, pb - 1);
    is[ni++] = ia;
    if (q.a == ia * bucketSide && ia > 0) is[ni++] = ia - 1;
    js[nj++] = jb;
    if (q.b == jb * bucketSide && jb > 0) js[nj++] = jb - 1;
    for (int y = 0; y < nj; ++y)
        for (int x = 0; x < ni; ++x)
            for (uint32_t i : scratch.mLeafBuckets[static_cast<size_t>(js[y]) * pa + is[x]]) {
                const Leaf& leaf = scratch.mLeaves[i];
                if (q.a < leaf.x0 || q.a > leaf.x0 + leaf.s || q.b < leaf.y0 || q.b > leaf.y0 + leaf.s)
                    continue;
                if (f(i)) return true;
            }
    return false;
}

// The lattice point where coverage wants its next ray: the centre (or a corner not yet
// traced) of the uncovered cell of 2 units whose unproven disc weighs most (key x weight:
// coverageWeight), the key its reach from what discs and contour strips prove. False when every uncovered point is within coverageGap x epsilon (epsilon: the
// final dichotomy interval) of proven ground, so that no shadow or window holding a disc of
// that radius can hide there, or when `giveUp` (uncoveredFormFactor() then tells what stays
// uncovered, once finalUncoveredFormFactor() has dropped what later discs cover).
//
// The cells wait in a max-heap by key. A disc traced later only lowers a cell's key (its gap
// is a minimum over discs) or covers the cell, so a stored key is never below the true one:
// the top is brought up to date with the discs traced since it was last looked at, and it is
// the heaviest cell once its key, up to date, is still on top. A cell whose stored key is
// below what coverage asks is done and leaves the heap. Only the cells that come near
// the top ever meet a new disc (every cell against every new disc cost a fifth of a render).
bool ContourIntegrator::Lattice::nextCoverageSample(LatticePoint& out, bool giveUp) {
    auto& cells = scratch.mUncovered;
    auto& heap = scratch.mCoverageHeap;
    const size_t discs = scratch.mTraced.size(), probed = scratch.mProbed.size();
    // Cells from `from` on were just made against every disc traced so far.
    auto enqueue = [&](size_t from) {
        for (size_t i = from; i < cells.size(); ++i) {
            cells[i].seen = discs;  // its reach is found when it first comes to the top
            heap.emplace_back(coveragePriority(cells[i]), static_cast<uint32_t>(i));
            std::push_heap(heap.begin(), heap.end());
        }
    };
    auto pop = [&] {
        std::pop_heap(heap.begin(), heap.end());
        heap.pop_back();
    };
    // Replaces cell i by its quarters, each against every disc and contour strip near it.
    auto quarter = [&](size_t i) {
        const Uncovered u = cells[i];
        cells[i].dead = true;
        const size_t from = cells.size();
        const double h = 0.5 * u.size;
        bool gathered = false;
        for (int q = 0; q < 4; ++q) {
            const double qa = u.a0 + (q & 1) * h, qb = u.b0 + (q >> 1) * h;
            int footprint = kFootprintUnknown;
            if (provenWithoutDiscs(qa, qb, h, footprint)) continue;
            if (!gathered) {
                gatherNear(static_cast<int>(u.a0), static_cast<int>(u.b0), static_cast<int>(u.size));
                gathered = true;
            }
            uncoveredCells(qa, qb, h, h, footprint, true);
        }
        enqueue(from);
    };
    // Done: what stays, for the bound (stale cells are cut down against every disc there).
    auto finish = [&] {
        cells.erase(std::remove_if(cells.begin(), cells.end(), [](const Uncovered& u) { return u.dead; }),
                    cells.end());
        heap.clear();
        return false;
    };
    if (!mScanned) {
        // A new pass: scan the leaves.
        cells.clear();
        heap.clear();
        for (const Leaf& leaf : scratch.mLeaves) {
            int footprint = kFootprintUnknown;
            if (provenWithoutDiscs(leaf.x0, leaf.y0, leaf.s, footprint)) continue;
            gatherNear(leaf.x0, leaf.y0, leaf.s);
            uncoveredCells(leaf.x0, leaf.y0, leaf.s, kScanCell, footprint, true);
        }
        enqueue(0);
        mScanned = true;
    }
    if (giveUp) return finish();
    const double enough = self.mSettings.coverageGap * epsWorld;
    while (!heap.empty()) {
        const uint32_t i = heap.front().second;
        if (cells[i].key < enough) {
            // Done (its stored key is never below its true one); it still counts in
            // uncoveredFormFactor() unless a disc covers it.
            pop();
            continue;
        }
        if (cells[i].seen < discs || cells[i].probed < probed) {
            // Stale: the discs traced since drop it or narrow its gap, the samples certified
            // since its reach.
            pop();
            Uncovered& u = cells[i];
            for (size_t t = u.probed; t < probed; ++t) {
                const Disc& d = scratch.mProbed[t];
                u.reach = std::min(u.reach, glm::length(u.centre - d.c) + d.r);
            }
            u.probed = probed;
            for (size_t t = u.seen; t < discs && !u.dead; ++t) {
                const Disc& d = scratch.mTracedDiscs[t];
                // A disc too far to hold any of the cell only narrows its gap.
                const double dist = glm::length(u.centre - d.c);
                if (mayHold(d, dist, u.size * cellReach)) {
                    scratch.mDiscs.assign(1, d);
                    if (cellInDisc(u.a0, u.b0, u.size, u.centre)) {
                        u.dead = true;
                        break;
                    }
                }
                gapTo(u, d, dist);
            }
            if (u.dead) continue;
            u.seen = discs;
            u.key = coverageKey(u);
            heap.emplace_back(coveragePriority(u), i);
            std::push_heap(heap.begin(), heap.end());
            continue;
        }
        const Uncovered u = cells[i];
        if (u.gap < enough && u.size > kCoverageCell) {
            // Its centre is near proven ground, a farther part of it may not be: look at
            // its quarters instead.
            pop();
            quarter(i);
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
        pop();
        if (u.size <= kCoverageCell) {
            // Nothing finer to ask here (it still counts in uncoveredFormFactor()).
            cells[i].exhausted = true;
            cells[i].key = -std::numeric_limits<double>::infinity();
            continue;
        }
        // Every candidate traced and still uncovered: its quarters.
        quarter(i);
    }
    return finish();
}

// Where coverage aims one more ray after visible sample q (a lattice point; {-1, -1} for none):
// when q's certificate proves less than a lattice unit, and no located contour piece lies within
// kSilhouetteAimReach units of it, q passes next to a silhouette the last pass did not locate;
// its clearance and distance gradient (newtonAlong) put that silhouette's line on the light, and
// the aim is the untraced lattice point half a unit past it, straight across from q. (Coverage
// otherwise spends its rays on every lattice point of the cells around q, each proving next to
// nothing: next to a level-set capsule's narrow shadow on the light's border, 48 rays, all
// visible, and the shadow, 0.7% of F0, unseen; bench_bounds --lights mixed --fog, seed 6516.)
LatticePoint ContourIntegrator::Lattice::acrossNearSilhouette(LatticePoint q) {
    const LatticePoint none{-1, -1};
    const size_t idx = index(q);
    if (scratch.mSample[idx] != kVisible || !(scratch.mCert[idx].radius < unit)) return none;
    const Vec3 pq = pointOf(q);
    const double reach = kSilhouetteAimReach * unit;
    for (const Segment& g : scratch.mSegs)
        if (!g.border && distance2ToSegment(pq, g) < reach * reach) return none;
    const float c = clearanceOf(q);
    const Vec3 g = normalOf(q);
    if (!(c > 0.0f) || glm::dot(g, g) == 0.0) return none;
    // Across the silhouette: against the gradient's part in the light's plane.
    Vec3 dir = -(g - glm::dot(g, lightNormal) * lightNormal);
    const double len = glm::length(dir);
    if (!(len > 1e-9)) return none;
    dir /= len;
    const double x = newtonAlong(q, pq, dir);
    if (!(x > 0.0) || !(x < reach)) return none;
    const Vec2 uv = light.coordinates(pq + (x + 0.5 * unit) * dir);
    const LatticePoint aim{static_cast<int>(std::lround(uv.x * Na)), static_cast<int>(std::lround(uv.y * Nb))};
    if (aim.a < 0 || aim.b < 0 || aim.a > Na || aim.b > Nb || (aim.a == q.a && aim.b == q.b)) return none;
    if (traced(aim) || !emits(pointOf(aim))) return none;
    return aim;
}

// Whether a traced coverage sample lies in the square (x0, y0, s), corners excluded, with
// another answer than the square's uniform one (visible: 1, hidden: 0; -1: any answer).
bool ContourIntegrator::Lattice::markedInside(int x0, int y0, int s, int uniform) const {
    for (uint32_t idx : scratch.mMarked) {
        const int a = static_cast<int>(idx % (Na + 1)), b = static_cast<int>(idx / (Na + 1));
        if (a < x0 || a > x0 + s || b < y0 || b > y0 + s) continue;
        if ((a == x0 || a == x0 + s) && (b == y0 || b == y0 + s)) continue;
        if (uniform < 0 || (scratch.mSample[idx] == kVisible) != (uniform == 1)) return true;
    }
    return false;
}

// Whether a traced sample disagrees with a leaf that holds it (inside or on its border),
// farther than epsilon from that leaf's contour: a shadow or window the pass stepped over
// (say, two crossings of one side found from two squares of different sizes). Unless
// `farOnly`, also a sample on a contour leaf's border that the leaf's contour puts on the other
// side however near (a vertex placed before the sample was traced: the next pass narrows it).
bool ContourIntegrator::Lattice::contradicts(uint32_t idx, bool farOnly) const {
    const LatticePoint q{static_cast<int>(idx % (Na + 1)), static_cast<int>(idx / (Na + 1))};
    const float sv = scratch.mSample[idx];
    if (sv == kBelowHorizon) return false;
    const int answer = sv == kVisible ? 1 : 0;
    return forLeavesHolding(q, [&](uint32_t i) {
        const Leaf& leaf = scratch.mLeaves[i];
        if (leaf.type != 2) return leaf.type != answer;
        const Vec3 pq = pointOf(q);
        double best;
        const int side = nearestSide(leaf, pq, best);
        if (side != answer && best > epsWorld) return true;
        if (farOnly) return false;
        // On the leaf's own border a vertex that the sample contradicts was placed before
        // the sample was traced (a neighbour's dichotomy): the next pass narrows it.
        const bool onBorder = q.a == leaf.x0 || q.a == leaf.x0 + leaf.s || q.b == leaf.y0 ||
                              q.b == leaf.y0 + leaf.s;
        return onBorder && side != answer && best > 1e-9 * unit && self.mSettings.distanceGuided;
    });
}

// The side of a contour square's nearest segment a light point lies on (visible, 1, on the
// left in (u, v)), and its distance to it.
int ContourIntegrator::Lattice::nearestSide(const Leaf& leaf, const Vec3& p, double& best) const {
    best = std::numeric_limits<double>::infinity();
    int side = 1;
    bool onBorder = false;
    for (uint32_t i = leaf.seg0; i < leaf.seg1; ++i) {
        const Segment& g = scratch.mSegs[i];
        const double dist2 = distance2ToSegment(p, g);
        if (dist2 < best) {
            best = dist2;
            side = glm::dot(glm::cross(g.b - g.a, p - g.a), lightNormal) > 0.0 ? 1 : 0;
            onBorder = g.border;
        }
    }
    best = std::sqrt(best);
    // Nearest to the (exact) border of what emits: the point's own position decides.
    if (onBorder) side = emits(p) ? 1 : 0;
    return side;
}

// What the current contour says about a light point: visible (1) or hidden (0).
int ContourIntegrator::Lattice::predicted(LatticePoint q) const {
    // The first leaf (in pass order) that holds it.
    uint32_t first = std::numeric_limits<uint32_t>::max();
    forLeavesHolding(q, [&](uint32_t i) {
        first = std::min(first, i);
        return false;
    });
    if (first == std::numeric_limits<uint32_t>::max()) return 1;
    const Leaf& leaf = scratch.mLeaves[first];
    if (leaf.type != 2) return leaf.type;
    // A contour square: the side of the nearest segment (visible on the left in (u, v)).
    double best;
    return nearestSide(leaf, pointOf(q), best);
}

// What a piece may miss where two silhouettes meet in the square (or a silhouette meets a
// polygon or disc light's border), at a corner one check point seldom lands on: a share of the
// square's own form factor, added to the piece's change. Zero for a piece of one silhouette.
double ContourIntegrator::Lattice::junctionAllowance(const Vertex& a, const Vertex& b,
                                                     const LatticePoint c[4]) const {
    const bool twoSilhouettes = a.obstacle != b.obstacle && a.obstacle != kHorizonContour &&
                                b.obstacle != kHorizonContour;
    const bool silhouetteAndBorder = shaped && (a.clip >= 0) != (b.clip >= 0);
    if (!twoSilhouettes && !silhouetteAndBorder) return 0.0;
    const Vec3 q0 = pointOf(c[0]), q1 = pointOf(c[1]), q2 = pointOf(c[2]), q3 = pointOf(c[3]);
    constexpr double kJunction = 0.05;  // measured on random sphere scenes
    return kJunction * std::abs(edgeF(q0, q1) + edgeF(q1, q2) + edgeF(q2, q3) + edgeF(q3, q0));
}

// Records a closed contour square for coverage: its pieces as segments (each piece: its ends and
// its middle), near which a cell belongs to the piece's strip rather than to coverage, the leaf
// itself, and what each piece leaves open in the error bound.
void ContourIntegrator::Lattice::recordContourLeaf(int x0, int y0, int s, const Vertex x[4],
                                                   const Piece pieces[2], int nPieces) {
    const uint32_t seg0 = static_cast<uint32_t>(scratch.mSegs.size());
    for (int q = 0; q < nPieces; ++q) {
        const Piece& pc = pieces[q];
        const Vertex& a = x[pc.exitSide];
        const Vertex& b = x[pc.entrySide];
        Vec3 mid = 0.5 * (a.c + b.c);
        if (pc.border) {
            // The border itself: exact, so a sample near it is what it says (points outside
            // emit nothing, points inside are visible unless a silhouette says otherwise, and
            // those have their own segments).
            scratch.mSegs.push_back({a.c, b.c, true});
            continue;
        }
        if (pc.arcOk && !pc.arc.straight) {
            const double w = pc.arc.w;
            mid = std::isfinite(w) ? (0.25 * a.c + 0.5 * w * pc.arc.k + 0.25 * b.c) / (0.5 + 0.5 * w)
                                   : pc.arc.k;
        } else if (!pc.arcOk) {
            mid = pc.z.c;
        }
        scratch.mSegs.push_back({a.c, mid});
        scratch.mSegs.push_back({mid, b.c});
    }
    addSegments(seg0);
    addLeaf({x0, y0, s, 2, seg0, static_cast<uint32_t>(scratch.mSegs.size())});
    // What each piece's data leave open: the strip of the vertices' uncertainty, and for a
    // tangent arc the part of its tangent triangle the arc may miss (two thirds without a
    // shoulder ray, a quarter with one), for a checked piece half the change that the check
    // measured.
    for (int q = 0; q < nPieces; ++q) {
        const Piece& pc = pieces[q];
        if (pc.border) continue;  // exact
        const Vertex& a = x[pc.exitSide];
        const Vertex& b = x[pc.entrySide];
        double e = 0.25 * stripFormFactor(rec, lightNormal, a.c, b.c, epsWorld);
        if (pc.arcOk && !pc.arc.straight) {
            const Vec3& k = pc.arc.k;
            const double tri = std::abs(edgeF(a.c, k) + edgeF(k, b.c) + edgeF(b.c, a.c));
            e += (pc.arc.probed ? 0.25 : 2.0 / 3.0) * tri;
        } else if (!pc.arcOk) {
            e += 0.5 * std::abs(edgeF(a.c, pc.z.c) + edgeF(pc.z.c, b.c) - edgeF(a.c, b.c));
        }
        bound += e;
    }
}

}  // namespace penumbra
