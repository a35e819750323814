// Vedel (1993), sections 3.1 and 3.2: one pass over the first-level grid, marching squares with
// a centre ray for saddles, the contour vertex of a crossed side by dichotomy on the shared
// lattice, one check point per contour piece and refinement where its change exceeds the strip
// threshold; an inconsistency restarts the light one level deeper (evaluate()).
#include <algorithm>
#include <cmath>
#include <limits>

#include "contour_lattice.h"

namespace penumbra {

namespace {

// Case 3 picks either diagonal (Vedel: at random): a hash of the square and the seed, so that
// the choice is the same on every run and thread.
uint32_t hashSquare(int x, int y, int s, uint32_t seed) {
    uint32_t h = seed * 0x9E3779B9u ^ static_cast<uint32_t>(x) * 0x85EBCA6Bu ^
                 static_cast<uint32_t>(y) * 0xC2B2AE35u ^ static_cast<uint32_t>(s) * 0x27D4EB2Fu;
    h ^= h >> 15;
    h *= 0x2C1B3C6Du;
    h ^= h >> 12;
    return h;
}

}  // namespace

// One pass over the light at restart level r; false on an inconsistency.
bool ContourIntegrator::Lattice::pass(int r) {
    g = Vec3(0.0);
    dg = Mat3(0.0);
    scratch.mPassEdges.clear();
    scratch.mPassEdgesValid = true;
    bound = 0.0;
    passLevel = r;
    scratch.mLeaves.clear();
    scratch.mSegs.clear();
    for (auto& b : scratch.mSegBuckets) b.clear();
    for (auto& b : scratch.mLeafBuckets) b.clear();
    const int k = n - r;
    const int s = 2 << k;
    const int squaresA = pa << r, squaresB = pb << r;
    for (int j = 0; j <= squaresB; ++j)
        for (int i = 0; i <= squaresA; ++i) visible({i * s, j * s}, true);
    for (int j = 0; j < squaresB; ++j)
        for (int i = 0; i < squaresA; ++i)
            if (!square(i * s, j * s, k, -1.0, 0)) return false;
    if (self.mSettings.distanceGuided) dropContradictedCrossings();
    return true;
}

// Processes the square with lower-left lattice corner (x0, y0) and side s = 2^(k+1).
// thr < 0 asks for the threshold to be computed from the square's own contour.
// Returns false on an inconsistency that needs the whole light one level deeper.
bool ContourIntegrator::Lattice::square(int x0, int y0, int k, double thr, int depth) {
    const int s = 2 << k;
    const LatticePoint c[4] = {{x0, y0}, {x0 + s, y0}, {x0 + s, y0 + s}, {x0, y0 + s}};
    bool v[4];
    for (int i = 0; i < 4; ++i) v[i] = visible(c[i]);
    const int nVisible = v[0] + v[1] + v[2] + v[3];
    const bool onBorder[4] = {y0 == 0, x0 + s == Na, y0 + s == Nb, x0 == 0};

    // A polygon light on its own frame: a square that the polygon enters (a corner of it, or
    // an edge) while none of the square's corners emits is split down to the lattice; what
    // emits there between lattice points is at most that square, counted in the bound.
    if (!polyCorners.empty() && polygonPoke(x0, y0, s, c, nVisible)) {
        if (k > 0) {
            ++counts.squaresRefined;
            return split(x0, y0, k, thr, depth, v, onBorder);
        }
        // The square's area times the largest density at its corners and centre (the
        // density varies by little across one square away from the receiver).
        const Vec3 p0 = pointOf(c[0]);
        const Vec3 area = glm::cross(pointOf(c[1]) - p0, pointOf(c[3]) - p0);
        double density = formFactorDensity(rec, lightNormal, 0.5 * (p0 + pointOf(c[2])));
        for (int i = 0; i < 4; ++i) density = std::max(density, formFactorDensity(rec, lightNormal, pointOf(c[i])));
        bound += glm::length(area) * density;
    }

    if (nVisible == 0 || nVisible == 4) {
        // With coverage: a coverage sample inside that disagrees splits the square (a
        // shadow or window touching no corner).
        if (self.mSettings.coverage && k > 0 && markedInside(x0, y0, s, nVisible == 4)) {
            ++counts.squaresSplitForCoverage;
            return split(x0, y0, k, thr, depth, v, onBorder);
        }
        if (self.mSettings.coverage) addLeaf({x0, y0, s, nVisible == 4 ? 1 : 0, 0, 0});
        if (nVisible == 4)
            for (int i = 0; i < 4; ++i)
                if (onBorder[i]) emit(pointOf(c[i]), pointOf(c[(i + 1) & 3]));
        return true;
    }

    // Beyond the paper (coverage mode): a contour square close to the receiver point,
    // where the form factor's kernel changes by a large factor across it, is split before
    // its contour is built (nearReceiver).
    if (self.mSettings.coverage && k > 0 && nearReceiver(x0, y0, s)) {
        ++counts.squaresRefined;
        return split(x0, y0, k, thr, depth, v, onBorder);
    }

    // Crossings on the sides whose ends differ (side i runs from c[i] to c[i+1]).
    Vertex x[4];
    for (int i = 0; i < 4; ++i) {
        const int j = (i + 1) & 3;
        if (v[i] != v[j]) x[i] = v[i] ? crossing(c[i], c[j], k) : crossing(c[j], c[i], k);
    }
    Piece pieces[2];
    const int nPieces = contourPieces(x0, y0, k, c, v, x, pieces);

    // A piece between two points of a polygon or disc light's border (or the horizon) is
    // that border: exact, no check, when it stays near the square.
    if (shaped)
        for (int q = 0; q < nPieces; ++q)
            pieces[q].border = alongBorder(x[pieces[q].exitSide], x[pieces[q].entrySide], s);
    // The tangent mode: an arc tangent to both ends' silhouettes, checked by its own rule.
    if (self.mSettings.tangentContour && self.mSettings.distanceGuided) {
        for (int q = 0; q < nPieces; ++q) {
            if (pieces[q].border) continue;
            const Vertex& a = x[pieces[q].exitSide];
            const Vertex& b = x[pieces[q].entrySide];
            const double pieceThr =
                thr >= 0.0 ? thr
                           : stripFormFactor(rec, lightNormal, a.c, b.c, epsWorld) *
                                 self.mSettings.thresholdScale * coverageThreshold();
            pieces[q].arcOk = tangentArc(a, b, x0, y0, s, pieceThr, pieces[q].arc);
        }
    }

    // Section 3.2: one more contour point per piece; refine where the change exceeds the
    // form factor of a strip of width epsilon around the piece.
    double change = 0.0, ownThr = 0.0;
    for (int q = 0; q < nPieces; ++q) {
        Piece& pc = pieces[q];
        const Vertex& a = x[pc.exitSide];
        const Vertex& b = x[pc.entrySide];
        if (pc.arcOk || pc.border) continue;
        if (pc.midline && (!visible(pc.checkVis) || visible(pc.checkHid))) {
            // A side's middle disagrees with its corners: the contour crosses that side
            // twice, which only a split square can represent.
            change = std::numeric_limits<double>::infinity();
            pc.z = a;
            continue;
        }
        pc.z = crossing(pc.checkVis, pc.checkHid, pc.checkSteps);
        change += std::abs(edgeF(a.c, pc.z.c) + edgeF(pc.z.c, b.c) - edgeF(a.c, b.c));
        if (self.mSettings.coverage) change += junctionAllowance(a, b, c);
        ownThr += stripFormFactor(rec, lightNormal, a.c, b.c, epsWorld);
    }
    // The threshold a split passes down (halved at each level, section 3.2). In tangent mode
    // one set by no checked piece (every piece an arc or the border, or a midline that
    // disagrees) would be 0 and force every square below to refine to the lattice; each
    // square below then sets its own from its pieces instead.
    const bool ownSet = thr < 0.0;
    if (ownSet) thr = ownThr * self.mSettings.thresholdScale * coverageThreshold();
    const double passedThr = ownSet && ownThr <= 0.0 && self.mSettings.coverage ? -1.0 : thr;

    if (self.mSettings.refine && k > 0 && change > thr) {
        ++counts.squaresRefined;
        return split(x0, y0, k, passedThr, depth, v, onBorder);
    }

    if (self.mSettings.coverage) {
        if (k > 0 && markedInside(x0, y0, s, -1)) {
            ++counts.squaresSplitForCoverage;
            return split(x0, y0, k, passedThr, depth, v, onBorder);
        }
        recordContourLeaf(x0, y0, s, x, pieces, nPieces);
    }

    for (int q = 0; q < nPieces; ++q) emitPiece(x[pieces[q].exitSide], x[pieces[q].entrySide], pieces[q]);
    emitFrameBorder(c, v, x, onBorder);
    return true;
}

// Whether the square (x0, y0, side s) is wider than kNearReceiver times its distance from the
// receiver point. The kernel cos cos / r^2 then varies by a large factor over it, and the
// section 3.2 rule, which weighs a piece's check against a strip along its whole length, lets
// through a chord that cuts off a corner of the contour next to the kernel's peak (random
// seed 9: a point on a torus 0.12 from a light of 1.1 x 1.4, 2% of the form factor off with
// every ray's answer right).
bool ContourIntegrator::Lattice::nearReceiver(int x0, int y0, int s) const {
    const Vec3 p0 = pointOf({x0, y0}), p2 = pointOf({x0 + s, y0 + s});
    const Vec3 p1 = pointOf({x0 + s, y0}), p3 = pointOf({x0, y0 + s});
    const double side = std::max(glm::length(p1 - p0), glm::length(p3 - p0));
    const double halfDiag = 0.5 * std::max(glm::length(p2 - p0), glm::length(p3 - p1));
    const double height = std::abs(glm::dot(rec.point - p0, lightNormal));
    const double dist = std::max(height, glm::length(0.5 * (p0 + p2) - rec.point) - halfDiag);
    return side > kNearReceiver * dist;
}

// Whether the polygon (polyCorners) meets the square (lower-left corner x0, y0, side s;
// corners c) while none of the square's corners emits (nVisible: how many are visible; a
// visible one emits): the square holds one of its corners, or one of its edges crosses it.
// Where a square corner emits, marching squares finds the border's crossings, and the walk
// between them (emitBorder) turns at the polygon's corners, in the square or beside it.
bool ContourIntegrator::Lattice::polygonPoke(int x0, int y0, int s, const LatticePoint c[4],
                                            int nVisible) const {
    if (nVisible > 0) return false;
    for (int i = 0; i < 4; ++i)
        if (emits(pointOf(c[i]))) return false;
    const double lo[2] = {double(x0), double(y0)}, hi[2] = {double(x0 + s), double(y0 + s)};
    for (const Vec2& q : polyCorners)
        if (q.x >= lo[0] && q.x <= hi[0] && q.y >= lo[1] && q.y <= hi[1]) return true;
    // An edge of the polygon through the square (Liang-Barsky).
    for (size_t e = 0; e < polyCorners.size(); ++e) {
        const Vec2& a = polyCorners[e];
        const Vec2 d = polyCorners[(e + 1) % polyCorners.size()] - a;
        double t0 = 0.0, t1 = 1.0;
        bool misses = false;
        for (int axis = 0; axis < 2 && !misses; ++axis) {
            const double from = axis == 0 ? a.x : a.y, step = axis == 0 ? d.x : d.y;
            if (step == 0.0) {
                misses = from < lo[axis] || from > hi[axis];
                continue;
            }
            double ta = (lo[axis] - from) / step, tb = (hi[axis] - from) / step;
            if (ta > tb) std::swap(ta, tb);
            t0 = std::max(t0, ta);
            t1 = std::min(t1, tb);
            misses = t0 > t1;
        }
        if (!misses) return true;
    }
    return false;
}

// Marching squares (section 3.1): the contour pieces of a square with mixed corners, each from
// an exit crossing (visible -> hidden walking counterclockwise) to an entry crossing, so that
// the visible part is on the left in (u, v). Each piece cuts off one corner, through which its
// check diagonal runs. A saddle (case 4) asks the square's centre. Returns the piece count.
int ContourIntegrator::Lattice::contourPieces(int x0, int y0, int k, const LatticePoint c[4],
                                              const bool v[4], const Vertex x[4], Piece pieces[2]) {
    const int s = 2 << k;
    const int nVisible = v[0] + v[1] + v[2] + v[3];
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
            Piece& pc = pieces[nPieces++];
            pc.exitSide = i;
            pc.entrySide = entry;
            pc.checkVis = muVisible ? mu : c[cut];
            pc.checkHid = muVisible ? c[cut] : mu;
            pc.checkSteps = k > 0 ? k - 1 : 0;
        }
        return nPieces;
    }
    int exitSide = -1, entrySide = -1;
    for (int i = 0; i < 4; ++i) {
        const int j = (i + 1) & 3;
        if (v[i] && !v[j]) exitSide = i;
        if (!v[i] && v[j]) entrySide = i;
    }
    Piece& pc = pieces[nPieces++];
    pc.exitSide = exitSide;
    pc.entrySide = entrySide;
    pc.checkSteps = k;
    if (nVisible != 2) {
        // Case 2: the diagonal through the odd corner.
        const bool odd = nVisible == 1;  // the odd corner is the one with v == odd
        int corner = 0;
        while (v[corner] != odd) ++corner;
        const int opposite = (corner + 2) & 3;
        pc.checkVis = v[corner] ? c[corner] : c[opposite];
        pc.checkHid = v[corner] ? c[opposite] : c[corner];
        if (self.mSettings.coverage) lopsidedCheck(pc, c, v, x, corner, s);
    } else if (self.mSettings.midlineCheck) {
        // The contour crosses two opposite sides; check it on the square's midline between
        // the other two sides' midpoints, half-way along the chord.
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
    return nPieces;
}

// Beyond the paper (coverage mode): a piece that cuts off corner c[corner] far along one of
// its two sides and close to it along the other runs almost along that first side, and the
// diagonal through the corner meets it next to its near end, where it says nothing of how far
// the contour bulges from the chord (random scene 612: the tip of a cylinder's shadow between
// the chord and the square's far corners, 0.4% of the form factor, passed its diagonal check).
// Such a piece is checked on the line across the square through the chord's middle instead,
// from the point of the long side half-way to its crossing (the corner's answer) to the
// opposite side (the other answer); both ends are traced, and an end that disagrees splits
// the square, as on a midline.
void ContourIntegrator::Lattice::lopsidedCheck(Piece& pc, const LatticePoint c[4], const bool v[4],
                                               const Vertex x[4], int corner, int s) const {
    const LatticePoint at = c[corner];
    const LatticePoint next = c[(corner + 1) & 3], prev = c[(corner + 3) & 3];
    const int d1a = (next.a - at.a) / s, d1b = (next.b - at.b) / s;
    const int d2a = (prev.a - at.a) / s, d2b = (prev.b - at.b) / s;
    // How far each crossing lies from the corner along its side, in lattice units.
    auto along = [&](const Vertex& vx, int da, int db) {
        const Vec2 uv = light.coordinates(vx.c);
        return (uv.x * Na - at.a) * da + (uv.y * Nb - at.b) * db;
    };
    const double t1 = along(x[corner], d1a, d1b);
    const double t2 = along(x[(corner + 3) & 3], d2a, d2b);
    constexpr double kLopsided = 2.0;
    const bool longFirst = t1 >= t2;
    const double tLong = longFirst ? t1 : t2, tShort = longFirst ? t2 : t1;
    if (!(tLong > kLopsided * std::max(tShort, 0.0))) return;
    const int offset = std::min(static_cast<int>(std::lround(0.5 * tLong)), s - 1);
    if (offset < 1) return;
    const int la = longFirst ? d1a : d2a, lb = longFirst ? d1b : d2b;  // along the long side
    const int ca = longFirst ? d2a : d1a, cb = longFirst ? d2b : d1b;  // across the square
    const LatticePoint near{at.a + offset * la, at.b + offset * lb};
    const LatticePoint far{near.a + s * ca, near.b + s * cb};
    pc.checkVis = v[corner] ? near : far;
    pc.checkHid = v[corner] ? far : near;
    pc.midline = true;
}

// Adds a closed piece to the contour integral: the border it runs along, its tangent arc, or
// the polygon through its check point (with curvedContour, the parabola through it).
void ContourIntegrator::Lattice::emitPiece(const Vertex& a, const Vertex& b, const Piece& pc) {
    if (pc.border) {
        double length = 0.0;
        emitBorder(a, b, false, length);
    } else if (pc.arcOk) {
        emitArc(a, b, pc.arc);
    } else if (self.mSettings.curvedContour) {
        // X, Z, Y taken as points of a parabolic arc (parabolaWeight).
        const double w = parabolaWeight(a.c, pc.z.c, b.c);
        emit(a.i, pc.z.i, w);
        emit(pc.z.i, b.i, w);
        emit(a.i, b.i, 1.0 - w);
    } else {
        emit(a.i, pc.z.i);
        emit(pc.z.i, b.i);
    }
}

// The visible parts of the light's frame border in the square, joined to the contour by
// radial junction edges C -> I (zero for the form factor, not for its gradient: Fig. 5).
void ContourIntegrator::Lattice::emitFrameBorder(const LatticePoint c[4], const bool v[4],
                                                 const Vertex x[4], const bool onBorder[4]) {
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
}

// Splits the square into four like a refinement (section 3.2); false on an inconsistency.
bool ContourIntegrator::Lattice::split(int x0, int y0, int k, double thr, int depth,
                                       const bool v[4], const bool onBorder[4]) {
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
            const uint32_t idx = static_cast<uint32_t>(index(m));
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
Vertex ContourIntegrator::Lattice::crossing(LatticePoint vis, LatticePoint hid, int steps) {
    const bool onLine = self.mSettings.distanceGuided && (vis.a == hid.a || vis.b == hid.b);
    if (onLine) {
        if (const Vertex* known = knownCrossing(vis, hid)) return *known;
    }
    LatticePoint fv = vis, fh = hid;
    Vertex v = crossingOnSegment(vis, hid, steps, fv, fh);
    if (onLine) {
        // A side longer than its neighbour's stops its dichotomy on a bracket of several
        // lattice units, inside which the neighbour's finer dichotomy may have traced samples:
        // the vertex must agree with them (else knownCrossing() drops it on every pass and the
        // passes never settle), so it is placed again inside the bracket they narrow.
        const int len = std::max(std::abs(fh.a - fv.a), std::abs(fh.b - fv.b));
        if (len > 1) {
            const int da = (fh.a - fv.a) / len, db = (fh.b - fv.b) / len;
            const LatticePoint from = fv;
            auto at = [&](int j) { return LatticePoint{from.a + j * da, from.b + j * db}; };
            int lo = 0, hi = len;
            narrowByTraced(at, lo, hi);
            if (lo != 0 || hi != len)
                v = self.mSettings.tangentContour ? crossingNewton(at(lo), at(hi), 0, fv, fh)
                                                  : crossingOnSegment(at(lo), at(hi), 0, fv, fh);
        }
        const Vec3 pv = pointOf(fv), ph = pointOf(fh);
        const double f = glm::dot(v.c - pv, ph - pv) / glm::dot(ph - pv, ph - pv);
        const bool horizontal = fv.b == fh.b;
        const int kv = horizontal ? fv.a : fv.b, kd = horizontal ? fh.a : fh.b;
        crossings.push_back({fv, fh, v, kv + f * (kd - kv)});
    }
    return v;
}

// A crossing found earlier on the segment vis -> hid's lattice line, oriented the same way,
// whose vertex lies inside the segment: the segment's crossing is that vertex while every
// sample traced since inside the crossing's bracket agrees with it (visible before it, hidden
// after). Two squares sharing part of a side then take the same vertex even when the bracket
// of the first straddles an end of the second's side (a refined square next to a coarser one),
// or when a later sample narrowed it: a vertex recomputed there differs from the one the
// neighbour took, and the gap between the two is an open piece of contour whose integral is
// not small (on a light seen at a grazing angle, 85% of the unoccluded form factor on a random
// scene's ground, with a bound of a sixth of that). A crossing some sample contradicts is
// dropped and the pass runs again (remark), so that every square of the new pass takes the new
// one.
const Vertex* ContourIntegrator::Lattice::knownCrossing(LatticePoint vis, LatticePoint hid) {
    const bool horizontal = vis.b == hid.b;
    const int line = horizontal ? vis.b : vis.a;
    const int v0 = horizontal ? vis.a : vis.b, h0 = horizontal ? hid.a : hid.b;
    const int lo = std::min(v0, h0), hi = std::max(v0, h0);
    for (size_t i = 0; i < crossings.size(); ++i) {
        const KnownCrossing& k = crossings[i];
        const bool kh = k.vis.b == k.hid.b;
        if (kh != horizontal || (kh ? k.vis.b : k.vis.a) != line) continue;
        const int kv = kh ? k.vis.a : k.vis.b, kd = kh ? k.hid.a : k.hid.b;
        if ((kv < kd) != (v0 < h0)) continue;
        const double e = k.at;
        if (!(e > lo && e < hi)) continue;
        if (crossingAgrees(k)) return &k.v;
        crossings.erase(crossings.begin() + static_cast<std::ptrdiff_t>(i));
        remark = true;
        return nullptr;
    }
    return nullptr;
}

// Whether every sample traced inside a known crossing's bracket is visible before it and
// hidden after it.
bool ContourIntegrator::Lattice::crossingAgrees(const KnownCrossing& k) const {
    const bool kh = k.vis.b == k.hid.b;
    const int line = kh ? k.vis.b : k.vis.a;
    const int kv = kh ? k.vis.a : k.vis.b, kd = kh ? k.hid.a : k.hid.b;
    const int step = kv < kd ? 1 : -1;
    for (int j = kv + step; j != kd; j += step) {
        const LatticePoint q = kh ? LatticePoint{j, line} : LatticePoint{line, j};
        if (!traced(q)) continue;
        if ((peek(q) == kVisible) != ((j - k.at) * step < 0.0)) return false;
    }
    return true;
}

// After a pass: a crossing that a sample traced later in the pass contradicts is dropped, and
// the pass runs again (remark) so that every square takes the new one. A square whose side's
// crossing was placed before its neighbour's finer squares traced samples inside the bracket
// otherwise kept it when no square asked for that side again: the neighbour, finding the
// side's two halves one visible and one crossed, placed its own vertex, and the gap between
// the two vertices, an open piece of contour, is not small where the light is seen at a grazing
// angle (a ground point 0.16 from a hexagon light's plane: 4.5% more than the unoccluded form
// factor, 1.4 times the bound; bench_bounds --lights mixed --light-scale 5, seed 3209).
void ContourIntegrator::Lattice::dropContradictedCrossings() {
    const size_t before = crossings.size();
    crossings.erase(std::remove_if(crossings.begin(), crossings.end(),
                                   [&](const KnownCrossing& k) { return !crossingAgrees(k); }),
                    crossings.end());
    if (crossings.size() != before) remark = true;
}

Vertex ContourIntegrator::Lattice::crossingOnSegment(LatticePoint vis, LatticePoint hid, int steps,
                                                     LatticePoint& finalVis,
                                                     LatticePoint& finalHid) {
    // The tangent mode places every crossing by crossingNewton, also a check point one step
    // from both ends (steps 0): the clearances' secant there put check points on a level-set
    // torus's two-voxel tube up to a third of a diagonal off, and the parabolas through them
    // cut into its shadow (0.03% of the form factor too bright at points of random scene 605).
    if (self.mSettings.tangentContour && self.mSettings.distanceGuided)
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
Vertex ContourIntegrator::Lattice::vertexBetween(LatticePoint vis, LatticePoint hid, double f,
                                                bool hit) {
    const float h = hit && peek(hid) != kBelowHorizon ? hitFraction(hid) : peek(hid);
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

void ContourIntegrator::Lattice::emit(const Vec3& a, const Vec3& b, double weight) {
    if (self.mRecord) {
        // Kept on the light's plane, along the lines from the receiver point (the apex of the
        // integral: G does not change).
        const double h = glm::dot(light.corner - rec.point, lightNormal);
        auto onPlane = [&](const Vec3& p) {
            const double d = glm::dot(p - rec.point, lightNormal);
            if (!(d * h > 0.0) || !(std::abs(d) > 1e-12 * std::abs(h))) scratch.mPassEdgesValid = false;
            return rec.point + (h / d) * (p - rec.point);
        };
        scratch.mPassEdges.push_back({onPlane(a), onPlane(b), weight});
    }
    if (self.mSettings.gradient) {
        const EdgeDerivative e = edgeGWithDerivative(a - rec.point, b - rec.point);
        g += weight * e.g;
        dg += weight * e.dg;
    } else {
        g += weight * edgeG(a - rec.point, b - rec.point);
    }
}

}  // namespace penumbra
