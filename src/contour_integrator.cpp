// The public ContourIntegrator, and the lattice's samples: one shadow ray per lattice point and
// evaluation, traced when first asked for, its clearance measured when first needed.
#include "penumbra/contour_integrator.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "contour_lattice.h"
#include "penumbra/error.h"

namespace penumbra {

namespace {

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
    const bool certified = settings.coverage && want > 0.0;
    // With a certificate and no clearance wanted, both in one pass (the certificate's tracing
    // spares the intersector what it proves clear).
    const bool hidden = certified && !measure
                            ? query.occludedCertified(origin, target, want, &tHit, out.cert)
                            : query.occluded(origin, target, &tHit, measure ? &c : nullptr);
    out.blocker = hidden ? query.lastBlocker() : -1;
    out.geometry.hider = static_cast<float>(out.blocker);
    recordClearance(c, glm::length(target - origin), out.clear, out.geometry);
    out.bound = c.bound;
    out.sample = hidden ? static_cast<float>(std::clamp(tHit / glm::length(target - origin), 0.01, 1.0))
                        : kVisible;
    if (certified && measure) query.certify(origin, target, hidden, tHit, want, out.cert);
    return out;
}

// The values of `v`, sorted, each once.
std::vector<uint32_t> distinct(std::vector<uint32_t> v) {
    std::sort(v.begin(), v.end());
    v.erase(std::unique(v.begin(), v.end()), v.end());
    return v;
}

// A disc light whose receiver's horizon cuts it emits a circular segment (the part above the
// horizon), whose two corners, where the horizon meets the circle, need not be lattice
// points of the disc's square frame: the emitting area near them could poke into squares
// whose corners all lie outside it and go unseen (bench_bounds --lights mixed, seed 2809: a
// receiver seeing 1% of a disc over its horizon got -3 times the answer). That part is
// integrated instead as three pieces whose corners are their frames' corners: with Ps and Pe
// the horizon's meeting points and A the middle of the arc between them, the triangle
// Ps A Pe and the two segments between the chords Ps A, A Pe and their arcs, each in the
// rectangle on its chord as tall as its segment (the arc touches the rectangle's far side at
// its middle, as a whole disc touches its square). False when the horizon does not cut the
// disc (the disc is integrated whole, on its square).
bool discPiecesAboveHorizon(const RectLight& disc, const Receiver& r, std::vector<RectLight>& pieces) {
    const Vec3 e1 = glm::normalize(disc.edgeU), e2 = glm::normalize(disc.edgeV);
    const double R = disc.radius;
    // The horizon on the disc's plane: f = f0 + x a1 + y a2 > 0 above it.
    const double f0 = glm::dot(disc.center - r.point, r.normal);
    const double a1 = glm::dot(e1, r.normal), a2 = glm::dot(e2, r.normal);
    const double amp = std::hypot(a1, a2);
    if (!(amp > 0.0)) return false;
    const double d = -f0 / amp;  // the chord's offset from the centre, along (a1, a2)
    if (!(d > -R * (1.0 - 1e-9)) || !(d < R * (1.0 - 1e-9))) return false;
    const double phiU = std::atan2(a2, a1), beta = std::acos(d / R);
    auto at = [&](double phi) { return disc.center + R * (std::cos(phi) * e1 + std::sin(phi) * e2); };
    const Vec3 ps = at(phiU - beta), a = at(phiU), pe = at(phiU + beta);
    const Vec3 n = disc.normal();
    pieces.clear();
    try {
        // Its edge on the horizon, pe -> ps, is one of its frame's edges (not the diagonal
        // that cuts the frame, where the horizon's rounding and the cut's would meet).
        pieces.push_back(polygonLight({a, pe, ps}));
    } catch (const std::invalid_argument&) {
        // A sliver of no area (the horizon all but tangent): the segments alone.
    }
    // The segment on chord from -> to (the arc runs counterclockwise from `to` back to `from`).
    auto segment = [&](const Vec3& from, const Vec3& to) {
        const Vec3 chord = to - from;
        const Vec3 w = glm::normalize(glm::cross(n, chord));  // away from the centre
        const double half = 0.5 * glm::length(chord);
        const double sagitta = R - std::sqrt(std::max(0.0, R * R - half * half));
        if (!(sagitta > 1e-12 * R)) return;
        RectLight piece = disc;
        piece.corner = from;
        piece.edgeU = chord;
        piece.edgeV = sagitta * w;
        pieces.push_back(piece);
    };
    segment(a, ps);
    segment(pe, a);
    for (RectLight& piece : pieces) piece.radiance = disc.radiance;
    return true;
}

}  // namespace

bool aci::isDiscPiece(const RectLight& light) {
    return light.shape == LightShape::Disc &&
           std::abs(glm::length(light.corner - light.center) - light.radius) <= 1e-9 * light.radius;
}

FirstLevelGrid firstLevelGrid(const RectLight& light, const AciSettings& settings) {
    const int p = std::max(1, settings.grid);
    FirstLevelGrid out{p, p};
    if (!settings.aspectGrid) return out;
    const double u = glm::length(light.edgeU), v = glm::length(light.edgeV);
    // At most 8 times, and never so many that the lattice along the longer edge outgrows
    // kMaxLatticeUnits (evaluate() would take dichotomy steps off both edges instead).
    const long fits = std::max(1L, kMaxLatticeUnits / (long(p) << (std::max(0, settings.steps) + 1)));
    const auto times = [&](double ratio) {
        return static_cast<int>(std::clamp(std::lround(ratio), 1L, std::min(8L, fits)));
    };
    if (u > v) out.a = p * times(u / v);
    if (v > u) out.b = p * times(v / u);
    return out;
}

ContourIntegrator::Lattice::Lattice(ContourIntegrator& s, const Receiver& r, const RectLight& l,
                                    Occluder::Query& q, FirstLevelGrid grid, int steps,
                                    bool footprintsBuilt)
    : self(s), scratch(*s.mScratch), rec(r), light(l), query(q), pa(grid.a), pb(grid.b),
      n(steps), Na(grid.a << (steps + 1)), Nb(grid.b << (steps + 1)) {
    origin = r.point + s.mSettings.rayOffset * r.normal;
    lightNormal = l.normal();
    cuts = cuttingEdges(l);
    shaped = l.shape != LightShape::Rect;
    if (l.shape == LightShape::Polygon && !frameHoldsCorners(l)) {
        for (const Vec3& corner : l.vertices) {
            const Vec2 uv = l.coordinates(corner);
            polyCorners.emplace_back(uv.x * Na, uv.y * Nb);
        }
        const Vec3 u = glm::normalize(l.edgeU), v = glm::normalize(l.edgeV);
        const Vec3 up = glm::normalize(l.edgeV - glm::dot(l.edgeV, u) * u);     // across the bottom
        const Vec3 right = glm::normalize(l.edgeU - glm::dot(l.edgeU, v) * v);  // across the left
        frameSides = {{l.corner, up}, {l.corner + l.edgeU, -right}, {l.corner + l.edgeV, -up}, {l.corner, right}};
    }
    horizonFree = isDiscPiece(l);
    const Vec3 unitU = l.edgeU / double(Na), unitV = l.edgeV / double(Nb);
    unit = 0.5 * (glm::length(unitU) + glm::length(unitV));
    epsWorld = 2.0 * unit;  // 2 units, averaged over the two edges
    // A cell of one unit's farthest point from its centre.
    cellReach = 0.5 * std::max(glm::length(unitU + unitV), glm::length(unitU - unitV));
    // Half the light's diagonal: what covers the light from its centre (with a margin: a radius
    // is reported up to `want` exactly, and must exceed it).
    const double diagonal = std::max(glm::length(l.edgeU + l.edgeV), glm::length(l.edgeU - l.edgeV));
    want = 0.51 * diagonal;
    // Other certified rays ask for what covers the first-level squares around a corner from
    // that corner alone, a square's diagonal (the same as `want` for a 2 x 2 first level):
    // smaller discs are cheaper to prove, and they stay in few of coverage's buckets.
    wantSquare = std::min(want, 2.0 * (2 << n) * cellReach * 1.02);
    const size_t size = static_cast<size_t>(Na + 1) * (Nb + 1);
    if (s.mSettings.coverage && scratch.mCert.size() < size) scratch.mCert.resize(size);
    bucketSide = 2 << n;
    bucketReach = cellReach * bucketSide;
    const double cross = glm::length(glm::cross(l.edgeU, l.edgeV));
    perUnitA = Na * glm::length(l.edgeV) / cross;
    perUnitB = Nb * glm::length(l.edgeU) / cross;
    if (s.mSettings.coverage) {
        if (!footprintsBuilt) findFootprints();
        const size_t buckets = static_cast<size_t>(pa) * pb;
        for (auto* v : {&scratch.mDiscBuckets, &scratch.mSegBuckets, &scratch.mLeafBuckets}) {
            if (v->size() < buckets) v->resize(buckets);
            for (auto& b : *v) b.clear();
        }
    }
    scratch.mTraced.clear();
    scratch.mTracedDiscs.clear();
    scratch.mProbed.clear();
    scratch.mAllTraced.clear();
    scratch.mPassEdges.clear();
    scratch.mPassEdgesValid = true;
    scratch.mMarked.clear();
    scratch.mBlockers.clear();
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

// Visibility of a lattice sample, tracing a ray only the first time it is asked for.
float& ContourIntegrator::Lattice::sample(LatticePoint q, bool firstLevel) {
    const size_t idx = index(q);
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
        kept = scratch.reusableCorner(light, {pa, pb}, q.a / s0, q.b / s0);
    }
    if (self.mSettings.coverage && !kept) {
        // A sample outside every obstacle's footprint is visible, and so is every light point
        // nearer than the footprints: a disc of that radius, without a ray. Likewise a sample
        // inside one obstacle's kernel and outside every other footprint is hidden by that
        // obstacle, first along its segment where it enters the kernel: what a ray would have
        // found (its hit fraction, its blocker), and a disc of the kernel's distance. Their
        // clearance is measured only if the tangent construction asks (settle(), like a traced
        // ray's).
        const LightFootprints::LightPoint lp = scratch.mFootprints.pointAt(double(q.a) / Na, double(q.b) / Nb);
        Certificate c;
        c.radius = std::min(want, scratch.mFootprints.distance(lp));
        c.radiusOthers = c.radius;
        LightFootprints::Hidden h;
        if (!(c.radius > 0.0)) {
            h = scratch.mFootprints.hiddenAt(lp);
            c.radius = std::min(want, h.radius);
            c.obstacle = h.obstacle;
            c.radiusOthers = std::min(c.radius, h.others);
        }
        if (c.radius > 0.0) {
            const bool hidden = h.obstacle >= 0;
            ++counts.footprintSamples;
            clear = std::numeric_limits<float>::quiet_NaN();
            if (self.mSettings.tangentContour) {
                scratch.mGeometry[idx] = RayGeometry{};
                scratch.mGeometry[idx].hider = static_cast<float>(h.obstacle);
            }
            scratch.mPending[idx] = (self.mSettings.distanceGuided ? kPendingUntraced : 0) |
                                    (hidden && !h.exact ? kPendingHit : 0);
            s = hidden ? static_cast<float>(std::clamp(h.fraction, 0.01, 1.0)) : kVisible;
            noteBlocker(h.obstacle);
            recordCertificate(idx, q, c);
            return s;
        }
    }
    Corner ray;
    double asked = 0.0;  // the radius the ray's certificate was computed up to
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
        asked = firstLevel || certifyNext ? (wantWhole ? want : wantSquare) : 0.0;
        ray = traceRay(query, origin, target, self.mSettings, asked,
                       self.mSettings.distanceGuided && !lazy);
        scratch.mPending[idx] = lazy ? kPendingClearance : 0;
        if (kept) *kept = ray;
    }
    clear = ray.clear;
    if (self.mSettings.tangentContour) scratch.mGeometry[idx] = ray.geometry;
    s = ray.sample;
    noteBlocker(ray.blocker);
    // Radii under a 64th of what was asked may be reported as 0 (Occluder::Query::certify).
    if (self.mSettings.coverage) recordCertificate(idx, q, ray.cert, asked > 0.0 ? asked / 64.0 : -1.0);
    return s;
}

// Lists obstacle b among those that blocked rays this time (none when negative).
void ContourIntegrator::Lattice::noteBlocker(int b) {
    if (b < 0) return;
    const auto i = static_cast<uint32_t>(b);
    if (scratch.mBlockers.empty() || scratch.mBlockers.back() != i) scratch.mBlockers.push_back(i);
}

// Keeps sample q's certificate, and its disc for coverage when it proves one. `floor` >= 0: the
// certificate was asked for, and a radius under `floor` may have been reported as 0.
void ContourIntegrator::Lattice::recordCertificate(size_t idx, LatticePoint q, const Certificate& c,
                                                   double floor) {
    scratch.mCert[idx] = c;
    if (c.radius > 0.0 || floor >= 0.0) scratch.mProbed.push_back({pointOf(q), std::max(c.radius, floor)});
    if (!(c.radius > 0.0)) return;
    scratch.mTraced.push_back(static_cast<uint32_t>(idx));
    scratch.mTracedDiscs.push_back({pointOf(q), c.radius});
    addDisc(static_cast<uint32_t>(scratch.mTracedDiscs.size() - 1), q);
}

// The index of traced sample q, its clearance measured now if it was left for later
// (sample()'s lazy rays): the same march, the same values, not counted as another ray.
size_t ContourIntegrator::Lattice::settle(LatticePoint q) const {
    const size_t idx = index(q);
    uint8_t& pending = scratch.mPending[idx];
    if ((pending & (kPendingClearance | kPendingUntraced)) && scratch.mStamp[idx] == scratch.mGeneration) {
        if (pending & kPendingUntraced) ++counts.footprintClearances;
        pending &= uint8_t(~(kPendingClearance | kPendingUntraced));
        const Vec3 target = pointOf(q);
        const Clearance c = query.clearance(origin, target, scratch.mSample[idx] != kVisible);
        RayGeometry unused;
        recordClearance(c, glm::length(target - origin), scratch.mClear[idx],
                        self.mSettings.tangentContour ? scratch.mGeometry[idx] : unused);
    }
    return idx;
}

float ContourIntegrator::Lattice::hitFraction(LatticePoint q) {
    const size_t idx = index(q);
    float& s = scratch.mSample[idx];
    if ((scratch.mPending[idx] & kPendingHit) && self.mSettings.gradient &&
        scratch.mStamp[idx] == scratch.mGeneration) {
        scratch.mPending[idx] &= uint8_t(~kPendingHit);
        const Vec3 target = pointOf(q);
        ++counts.secondLevelRays;
        if (self.mSettings.rayLog) self.mSettings.rayLog->push_back(target);
        double tHit = 0.0;
        if (query.occluded(origin, target, &tHit))
            s = static_cast<float>(std::clamp(tHit / glm::length(target - origin), 0.01, 1.0));
    }
    return s;
}

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

Estimate ContourIntegrator::evaluatePieces(const Receiver& r, const std::vector<RectLight>& pieces,
                                           Occluder::Query& query) {
    mFanPiece = true;  // each piece is integrated as it is (no second clip)
    Estimate sum;
    sum.errorBound = mSettings.coverage && mSettings.errorBound ? 0.0 : std::numeric_limits<double>::quiet_NaN();
    for (const RectLight& piece : pieces) {
        Estimate e;
        try {
            e = evaluate(r, piece, query);
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
        sum.blockers.insert(sum.blockers.end(), e.blockers.begin(), e.blockers.end());
    }
    mFanPiece = false;
    sum.blockers = distinct(std::move(sum.blockers));
    return sum;
}

Estimate ContourIntegrator::evaluate(const Receiver& r, const RectLight& light,
                                     Occluder::Query& query) {
    // (Only a disc on its own square: a part of one, as aciThroughMedia's cells would be, is
    // integrated as it is.)
    if (mRecord && !mFanPiece) {  // a new light: what its pieces keep replaces the last
        mContour.clear();
        mContourValid = true;
    }
    const bool wholeDisc = light.shape == LightShape::Disc &&
                           glm::length(light.corner + 0.5 * (light.edgeU + light.edgeV) - light.center) <=
                               1e-9 * light.radius &&
                           std::abs(glm::length(light.edgeU) - 2.0 * light.radius) <= 1e-9 * light.radius;
    if (wholeDisc && !mFanPiece) {
        std::vector<RectLight> pieces;
        if (discPiecesAboveHorizon(light, r, pieces)) return evaluatePieces(r, pieces, query);
    }
    if (light.shape == LightShape::Polygon) {
        // A polygon whose corners the horizon cuts off (the meeting points are corners of
        // what emits, not lattice points) is integrated as the fan of triangles of its part
        // above the horizon, each in its own parallelogram (a parallelogram needs none: the
        // horizon meets it on its frame's border, like a rectangle's). One wholly above the
        // horizon is integrated on its own frame (Lattice::polygonPoke, emitBorder).
        const bool parallelogram = light.vertices.size() == 4 && frameHoldsCorners(light);
        std::vector<Vec3> part = parallelogram || mFanPiece ? light.vertices : clipToHorizon(light.vertices, r);
        if (part != light.vertices && part.size() >= 3) {
            // The edge the horizon made (the one whose ends lie lowest) becomes the first
            // triangle's second edge, one of its frame's edges: as the fan's closing edge it
            // would be the triangle's diagonal, which cuts the frame along the very line of the
            // horizon, and the two clips' rounding disagreed (bench_bounds --lights mixed seed
            // 2803: a triangle seen over the horizon 2% short, every mode).
            const size_t m = part.size();
            size_t k = 0;
            double lowest = std::numeric_limits<double>::infinity();
            for (size_t i = 0; i < m; ++i) {
                const double h = std::abs(glm::dot(part[i] - r.point, r.normal)) +
                                 std::abs(glm::dot(part[(i + 1) % m] - r.point, r.normal));
                if (h < lowest) lowest = h, k = i;
            }
            std::rotate(part.begin(), part.begin() + static_cast<long>((k + m - 1) % m), part.end());
        }
        if (!parallelogram && !mFanPiece && part != light.vertices) {
            std::vector<RectLight> fan;
            for (size_t i = 1; i + 1 < part.size(); ++i) {
                try {
                    fan.push_back(polygonLight({part[0], part[i], part[i + 1]}));
                } catch (const std::invalid_argument&) {
                    continue;  // a sliver of no area where the horizon meets a corner
                }
                fan.back().radiance = light.radiance;
            }
            return evaluatePieces(r, fan, query);
        }
    }
    Scratch& sc = *mScratch;
    Estimate est;
    // A point the light does not face, or whose horizon hides all of it, receives nothing: F = 0
    // exactly, so its bound (when one is asked for) is 0, not "none".
    if (mSettings.coverage && mSettings.errorBound) est.errorBound = 0.0;
    if (!facesLight(light, r.point)) return est;
    bool above = false;
    for (const Vec3& c : light.polygon()) above |= glm::dot(c - r.point, r.normal) > 0.0;
    if (!above) return est;

    const FirstLevelGrid grid = firstLevelGrid(light, mSettings);
    int n = std::max(0, mSettings.steps);
    while (n > 0 && (std::max(grid.a, grid.b) << (n + 1)) > kMaxLatticeUnits) --n;
    bool footprintsBuilt = false;
    int coarser = 0;
    if (mSettings.adaptiveSteps && mSettings.coverage && mSettings.tangentContour && n >= 2) {
        // One step fewer where every obstacle's footprint on the light is wide.
        sc.mFootprints.build(query.occluder(), query.restriction(),
                             r.point + mSettings.rayOffset * r.normal, light);
        footprintsBuilt = true;
        const double unit = 0.5 * (glm::length(light.edgeU) / (grid.a << (n + 1)) +
                                   glm::length(light.edgeV) / (grid.b << (n + 1)));
        const double wide = kAdaptiveWidth * unit;
        // ... and no footprint cuts a weighty sliver from a light whose border runs between
        // lattice points (a disc's circle, a polygon's cutting edge). Under such a light, a
        // level set so near the receiver point that a voxel of it spans more than
        // kMagnifiedVoxel units on the light keeps the finer lattice too: the footprints bound
        // its shadow with a slack of a voxel or more, magnified as much, so a wide footprint
        // says nothing of a thin shadow along the border (random seed 946, a box 0.066 above
        // the ground under a disc light: from a ground point beside it the box's footprint was
        // 2.2 across, its shadow on the disc a sliver 1-4% of the disc's width along the rim,
        // and the coarser lattice left the point 0.5% of F0 too bright; 0.04% on the finer).
        if (sc.mFootprints.narrowestWidth(query.occluder()) >= wide) {
            const double sliver = sc.mFootprints.thinSliver(r, wide);
            if (!(sliver > kSliverShare * unoccludedFormFactor(light, r)) &&
                (!LightFootprints::borderOffLattice(light) ||
                 !(sc.mFootprints.largestMagnifiedVoxel(query.occluder()) > kMagnifiedVoxel * unit)))
                coarser = 1;
        }
        n -= coarser;
    }
    // Steps more where a lattice cell's form factor is large and an obstacle's footprint only a
    // few cells wide: a light much larger than its distance from the receiver (a 80 x 80 light
    // 4 above the ground, a 0.3-wide box between: cells of 0.625 each carried up to 0.8% of the
    // form factor, and a shadow three cells wide went unlocated, 4% of it off (within the
    // bound); two steps more, 0.01%). Not where the footprints are unbounded (the receiver on an
    // obstacle), and the lattice kept to kMaxFinerLattice points a side. A level set too thin
    // for kernel balls has a width of 0 and asks for the finer lattice too (until 2026-12-06 a
    // width of 0 meant unbounded footprints, and a thin capsule near a torus turned the rule off
    // for both: a ground point under a light 18 across 1.4% of F0 low, bench_bounds --lights
    // mixed --light-scale 8, seed 6702). Since 2026-12-06 also where the only unbounded
    // footprints are such thin level sets' (a receiver on one): a point on the inner wall of a
    // torus two voxels thick, seeing a light 13 across through its hole, was 1.3% of F0 low
    // (random scene 3102 grown 15 times), now 0.06%.
    int finer = 0;
    if (mSettings.coverage && mSettings.tangentContour && coarser == 0) {
        if (!footprintsBuilt) {
            sc.mFootprints.build(query.occluder(), query.restriction(),
                                 r.point + mSettings.rayOffset * r.normal, light);
            footprintsBuilt = true;
        }
        const double d = std::abs(glm::dot(r.point - light.corner, light.normal()));
        const double narrow = sc.mFootprints.narrowestWidth(query.occluder());
        while (finer < 4 && (std::max(grid.a, grid.b) << (n + 2)) <= kMaxFinerLattice) {
            const double unit = 0.5 * (glm::length(light.edgeU) / (grid.a << (n + 1)) +
                                       glm::length(light.edgeV) / (grid.b << (n + 1)));
            if (!(unit * unit > kFineCellFormFactor * kPi * d * d) || !(narrow >= 0.0) ||
                !(narrow < kAdaptiveWidth * unit))
                break;
            ++n, ++finer;
        }
    }
    // Samples a finer lattice takes over from a coarser one (below): each at its doubled
    // lattice coordinates, with its certificate, and whether it contradicted a pass.
    struct Carried {
        LatticePoint q;
        float sample, clear;
        uint8_t pending;
        RayGeometry geometry;
        Certificate cert;
        bool marked;
    };
    std::vector<Carried> carried;
    std::vector<uint32_t> carriedBlockers;
    AciCounts carriedCounts;
    int finerRedos = 0;
    for (;;) {
        Lattice lat(*this, r, light, query, grid, n, footprintsBuilt);
        lat.coarser = finerRedos < coarser;  // a finer redo comes back to the asked lattice
        for (const Carried& c : carried) {
            const size_t idx = lat.index(c.q);
            sc.mStamp[idx] = sc.mGeneration;
            sc.mSample[idx] = c.sample;
            sc.mClear[idx] = c.clear;
            sc.mPending[idx] = c.pending;
            if (mSettings.tangentContour) sc.mGeometry[idx] = c.geometry;
            sc.mAllTraced.push_back(static_cast<uint32_t>(idx));
            lat.recordCertificate(idx, c.q, c.cert);
            if (c.marked) sc.mMarked.push_back(static_cast<uint32_t>(idx));
        }
        if (!carried.empty()) {
            sc.mBlockers = carriedBlockers;
            lat.counts = carriedCounts;
        }
        if (mSettings.coverage && carried.empty() && lat.wholeLight()) {
            // One ray whose disc covers the light decides it: all visible or all hidden.
            const bool vis = sc.mSample[lat.index({lat.Na / 2, lat.Nb / 2})] == kVisible;
            est.pattern.assign(grid.corners(), vis ? 1 : 0);
            est.g = lat.g / (2.0 * kPi);
            est.dg = lat.dg / (2.0 * kPi);
            est.formFactor = glm::dot(est.g, r.normal);
            for (int k = 0; k < 3; ++k) est.gradient[k] = glm::dot(est.dg[k], r.normal);
            est.counts = lat.counts;  // (its bound, 0 when asked for, was set above)
            est.counts.coarserEvaluations = coarser;
            est.blockers = distinct(sc.mBlockers);
            keepContour();
            return est;
        }
        // Each pass's first coverage rays: one towards the middle of each obstacle near the light,
        // where the contour says the light is seen (below). The middles, as light coordinates: an
        // obstacle's kernel balls' centres (proven inside it), else its solid sphere's centre,
        // projected from the ray origin onto the light's plane; only those in front of the light.
        std::vector<Vec2> middles;
        if (mSettings.coverage) {
            const Occluder& occ = query.occluder();
            const std::vector<uint32_t>* only = query.restriction();
            const Vec3 origin = r.point + mSettings.rayOffset * r.normal;
            const Vec3 ln = light.normal();
            const double toLight = glm::dot(light.corner - origin, ln);
            // The light point whose ray passes nearest to a ball's centre (smallest angle from
            // the centre's direction): the centre's projection when it falls on the light, else
            // searched over the frame's emitting points (a 9 x 9 grid, then three finer ones
            // around the best; a disc's centre projected beside the circle, next to another
            // obstacle's shadow that took coverage's rays, hid 3% of F: seed 3902). Kept when that ray goes through the ball: a shadow can hold a corner of the
            // frame and none of its first-level points (a sphere's shadow held 4% of F in a corner
            // of the light, seen so obliquely that the centre's projection fell 200 frames away:
            // rect seed 2708).
            // The light's frame seen from the origin: its centre's direction and the cosine and
            // sine of the largest angle from it to a corner (the frame lies within that cone).
            const Vec3 towards = glm::normalize(light.point(0.5, 0.5) - origin);
            double frameCos = 1.0;
            for (int k = 0; k < 4; ++k)
                frameCos = std::min(frameCos, glm::dot(glm::normalize(light.point(k & 1, k >> 1) - origin), towards));
            const double frameSin = std::sqrt(std::max(0.0, 1.0 - frameCos * frameCos));
            // `reach`: the ball counts as that many times its radius (a thin level set's deep
            // point, whose ball is only as wide as the obstacle is thick: its ends reach beyond).
            auto add = [&](const Vec3& c, double ballRadius, double reach = 1.0) {
                const Vec3 d = c - origin;
                const double dist = glm::length(d);
                if (!(dist > ballRadius)) return;
                const double radius = std::min(reach * ballRadius, dist * (1.0 - 1e-9));
                const double along = glm::dot(d, ln);
                if (along * toLight > 0.0 && std::abs(along) < std::abs(toLight)) {
                    const Vec2 uv = light.coordinates(origin + (toLight / along) * d);
                    if (uv.x >= 0.0 && uv.x <= 1.0 && uv.y >= 0.0 && uv.y <= 1.0 &&
                        lat.emits(light.point(uv.x, uv.y))) {
                        middles.push_back(uv);
                        return;
                    }
                }
                // A ball whose cone misses the frame's cone: no ray to the light meets it (the
                // angle between the axes over the sum of the half-angles, compared by cosines).
                const double ballSin = radius / dist, ballCos = std::sqrt(1.0 - ballSin * ballSin);
                const double sumCos = frameCos * ballCos - frameSin * ballSin;
                if (frameCos * ballCos > frameSin * ballSin && glm::dot(d, towards) < sumCos * dist) return;
                const Vec3 dir = d / dist;
                // Over the part that emits (a disc's or a polygon's frame holds more).
                auto cosAt = [&](double u, double v) {
                    const Vec3 q = light.point(u, v);
                    return lat.emits(q) ? glm::dot(glm::normalize(q - origin), dir) : -2.0;
                };
                Vec2 best(0.5);
                double bestCos = -2.0, step = 0.125;
                for (int round = 0; round < 4; ++round) {
                    const Vec2 around = best;
                    for (int a = -4; a <= 4; ++a)
                        for (int b = -4; b <= 4; ++b) {
                            const Vec2 uv = glm::clamp(around + step * Vec2(a, b), Vec2(0.0), Vec2(1.0));
                            const double cosine = cosAt(uv.x, uv.y);
                            if (cosine > bestCos) bestCos = cosine, best = uv;
                        }
                    step *= 0.25;
                }
                // Through the ball: the angle to its centre under its angular radius.
                if (bestCos > std::sqrt(1.0 - (radius / dist) * (radius / dist))) middles.push_back(best);
            };
            const size_t count = only ? only->size() : occ.size();
            for (size_t k = 0; k < count && middles.size() < kMaxMiddles; ++k) {
                const size_t i = only ? (*only)[k] : k;
                if (occ.solidBounds(i).empty()) continue;
                const std::vector<Occluder::KernelBall>& balls = occ.kernelBalls(i);
                for (const Occluder::KernelBall& b : balls) add(b.centre, b.radius);
                // A level set too thin for kernel balls: its deep points, the deepest voxel and
                // others spread over it, which its solid sphere's centre need not be near (a
                // torus's lies in its hole: seed 7003, evaluate()'s finer redo; a capsule's end
                // near a triangle light hid 4.3% of F0 from a far ground point while its deepest
                // voxel's cone missed the light: bench_bounds --lights mixed --fog, seed 8510).
                if (balls.empty())
                    for (const Occluder::KernelBall& deep : occ.deepPoints(i))
                        add(deep.centre, deep.radius, kDeepPointReach);
                // And its solid sphere's centre, where that is not a kernel ball's: a shadow of
                // the obstacle's outer part can hold a corner of the light that the kernel balls'
                // cones miss (seed 2708 again, from farther points).
                add(occ.solidCentre(i), occ.solidRadius(i));
            }
        }
        int level = 0;
        bool redo = false;  // one step finer, the samples carried over
        int coverageRays = 0, repasses = 0, remarks = 0;
        bool unsettled = false;
        bool escalated = false;  // coverage's allowance ran out once and the pass went deeper
        bool extended = false;   // coverage's allowance ran out once and was granted again
        for (;;) {
            lat.remark = false;
            if (!lat.pass(level)) {
                ++lat.counts.restarts;
                ++level;  // cannot exceed n: at k = 0 no square splits, so no inconsistency arises
                continue;
            }
            if (!mSettings.coverage) break;
            if (lat.remark && ++remarks <= kMaxRepasses) continue;
            // Passes that never settled leave a contour whose vertices some samples contradict:
            // nothing of it is proven, and the bound says so.
            unsettled = unsettled || lat.remark;
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
            // Coverage: rays where no disc and no contour strip proves the answer. One that
            // contradicts the contour (a shadow or window the pass missed) makes the pass run again,
            // splitting the squares it lies in; every ray is reused.
            LatticePoint q;
            lat.mScanned = false;
            // One coverage ray, certified; true (the sample marked, `again` set) when it
            // contradicts the contour and the pass may run again.
            auto contradicted = [&](LatticePoint p) {
                ++coverageRays;
                lat.certifyNext = true;
                const uint64_t traced = lat.counts.secondLevelRays;
                const bool vis = lat.visible(p);
                lat.counts.coverageRays += lat.counts.secondLevelRays - traced;
                lat.certifyNext = false;
                if ((vis ? 1 : 0) == lat.predicted(p) || repasses >= kMaxRepasses) return false;
                ++repasses;
                sc.mMarked.push_back(static_cast<uint32_t>(lat.index(p)));
                again = true;
                return true;
            };
            // First towards the obstacles' middles the contour has as seen: a shadow on the light
            // that touches no corner and that the discs did not reach. (Under a thin triangle, a
            // sphere 0.15 from the light hid 16% of a far ground point's F; every coverage ray went
            // along the edge of its shadow, each with a disc too small to count, and none into it:
            // bench_bounds --lights mixed --fog, seed 3501.)
            for (const Vec2& uv : middles) {
                LatticePoint m{static_cast<int>(std::lround(uv.x * lat.Na)),
                               static_cast<int>(std::lround(uv.y * lat.Nb))};
                // Rounded off a shaped light's border: back in, a unit at a time towards the middle
                // of the frame.
                for (int k = 0; k < 4 && !lat.emits(lat.pointOf(m)); ++k) {
                    m.a += m.a < lat.Na / 2 ? 1 : m.a > lat.Na / 2 ? -1 : 0;
                    m.b += m.b < lat.Nb / 2 ? 1 : m.b > lat.Nb / 2 ? -1 : 0;
                }
                if (lat.traced(m) || !lat.emits(lat.pointOf(m)) || lat.predicted(m) != 1) continue;
                if (contradicted(m)) break;
            }
            if (again) continue;
            while (lat.nextCoverageSample(q, coverageRays >= mSettings.maxCoverageRays)) {
                if (contradicted(q)) break;
                // A visible coverage ray far from the located contour whose certificate proves
                // less than a lattice unit passes next to a silhouette the contour does not have:
                // one more ray just past where its clearance puts that silhouette.
                if (mSettings.tangentContour && coverageRays < mSettings.maxCoverageRays) {
                    const LatticePoint aim = lat.acrossNearSilhouette(q);
                    if (aim.a >= 0 && contradicted(aim)) break;
                }
            }
            if (!again) {
                // Coverage ran out of rays with most of the light unproven: the evaluation knows
                // little more than its first-level corners, which may have missed a shadow or
                // window that rays aimed at the widest unproven cells do not reach either (a
                // receiver 0.007 under a torus sees the light through its hole: every disc is tiny,
                // and F came out 40% short, within its bound). Once, the pass restarts one level
                // deeper, its first squares halved, every ray reused, with a new allowance of
                // coverage rays. (Restarting whenever the allowance ran out added 30-50% to the
                // render time of random scenes 1, 5 and 6; when a quarter or half stayed unproven,
                // 15-45% on scene 1.)
                if (coverageRays >= mSettings.maxCoverageRays && !escalated && level < n) {
                    double area = 0.0;  // what stays unproven (an upper bound: cells may be stale)
                    for (const Uncovered& u : sc.mUncovered) area += u.size * u.size;
                    if (area > kEscalateUnproven * double(lat.Na) * lat.Nb) {
                        escalated = true;
                        ++level;
                        coverageRays = 0;
                        continue;
                    }
                }
                // Ran out with more than extendCoverage of the unoccluded form factor still in
                // unproven cells: once, another allowance at the same level (point queries;
                // renders keep one). A far ground point under a triangle light seen edge-on
                // (F0 4.5e-5) missed a thin cylinder's shadow of 3.6% of F0 with its 48 rays,
                // within a bound of 15%, and found it with the second 48 (bench_bounds --lights
                // mixed, seed 10117; test_coverage.cpp).
                if (coverageRays >= mSettings.maxCoverageRays && !extended &&
                    mSettings.extendCoverage > 0.0 &&
                    lat.uncoveredFormFactor() > mSettings.extendCoverage * lat.wholeFormFactor()) {
                    extended = true;
                    coverageRays = 0;
                    continue;
                }
                // A sample that still contradicts the contour lies where the lattice allows
                // none that agrees with it: a shadow or window thinner than a unit, around a
                // lattice point that a ray found inside it. Once or twice, the evaluation
                // starts again one step finer, every sample carried over (at its doubled
                // coordinates, the contradicting ones marked), so that the finer passes build
                // their contour around what the coarse ones found. (A torus whose tube is two
                // voxels thick cast a shadow under a lattice unit thick on a triangle 20
                // across; the ray that found it had no neighbour inside it, and a ground point
                // came out 0.6% of F0 high, within its bound: bench_bounds --lights mixed
                // --light-scale 8 --fog, seed 7003. Redoing it finer from scratch lost the
                // ray, and with it the shadow, on other scenes.)
                if (!unsettled && repasses < kMaxRepasses && finerRedos < kMaxFinerRedos &&
                    (std::max(grid.a, grid.b) << (n + 2)) <= kMaxLatticeUnits) {
                    // Only a sample farther than epsilon from every located piece of contour:
                    // one beside a piece is a sliver under a unit wide that the contour's
                    // placement at the lattice's own resolution misses (on the vdb_tool scene,
                    // where box edges meet such samples, redoing those took 7% more rays for
                    // the same image).
                    bool contradicted = false;
                    for (uint32_t idx : sc.mAllTraced) {
                        if (!lat.contradicts(idx, true)) continue;
                        const Vec3 p = lat.pointOf({static_cast<int>(idx % (lat.Na + 1)),
                                                    static_cast<int>(idx / (lat.Na + 1))});
                        bool near = false;
                        for (const Segment& g : sc.mSegs)
                            if (Lattice::distance2ToSegment(p, g) <= lat.epsWorld * lat.epsWorld) {
                                near = true;
                                break;
                            }
                        if (!near) {
                            contradicted = true;
                            break;
                        }
                    }
                    if (contradicted) {
                        redo = true;
                        break;
                    }
                }
                if (mSettings.errorBound) lat.bound += lat.finalUncoveredFormFactor();
                if (unsettled) lat.bound = std::max(lat.bound, lat.wholeFormFactor());
                break;
            }
        }
        if (redo) {
            carried.clear();
            for (uint32_t idx : sc.mAllTraced) {
                const LatticePoint q{static_cast<int>(idx % (lat.Na + 1)), static_cast<int>(idx / (lat.Na + 1))};
                carried.push_back({{2 * q.a, 2 * q.b}, sc.mSample[idx], sc.mClear[idx], sc.mPending[idx],
                                   mSettings.tangentContour ? sc.mGeometry[idx] : RayGeometry{},
                                   sc.mCert[idx],
                                   lat.contradicts(idx, true) || std::find(sc.mMarked.begin(), sc.mMarked.end(), idx) !=
                                                               sc.mMarked.end()});
            }
            carriedBlockers = sc.mBlockers;
            carriedCounts = lat.counts;
            ++carriedCounts.finerRedos;
            ++finerRedos;
            ++n;
            continue;
        }
        est.pattern.resize(grid.corners());
        const int s0 = 2 << n;
        for (int j = 0; j <= grid.b; ++j)
            for (int i = 0; i <= grid.a; ++i) {
                const size_t idx = lat.index({i * s0, j * s0});
                est.pattern[static_cast<size_t>(j) * (grid.a + 1) + i] = sc.mSample[idx] == kVisible;
            }
        est.g = lat.g / (2.0 * kPi);
        est.dg = lat.dg / (2.0 * kPi);
        est.formFactor = glm::dot(est.g, r.normal);
        for (int k = 0; k < 3; ++k) est.gradient[k] = glm::dot(est.dg[k], r.normal);
        if (mSettings.coverage && mSettings.errorBound) est.errorBound = lat.bound;
        est.counts = lat.counts;
        est.counts.coarserEvaluations = coarser;
        est.blockers = distinct(sc.mBlockers);
        keepContour();
        return est;
    }
}

void ContourIntegrator::recordContour(bool on) { mRecord = on; }

void ContourIntegrator::keepContour() {
    if (!mRecord) return;
    mContour.insert(mContour.end(), mScratch->mPassEdges.begin(), mScratch->mPassEdges.end());
    mContourValid = mContourValid && mScratch->mPassEdgesValid;
}

Corner* ContourIntegrator::Scratch::reusableCorner(const RectLight& light, FirstLevelGrid grid,
                                                   int i, int j) {
    const size_t count = grid.corners();
    if (mCorners.size() != count || mCornerGrid != grid || mCornerLight.corner != light.corner ||
        mCornerLight.edgeU != light.edgeU || mCornerLight.edgeV != light.edgeV) {
        mCorners.assign(count, Corner{});
        mCornerGrid = grid;
        mCornerLight = light;
    }
    return &mCorners[static_cast<size_t>(j) * (grid.a + 1) + i];
}

std::vector<uint8_t> ContourIntegrator::pattern(const Receiver& r, const RectLight& light,
                                                Occluder::Query& query, AciCounts& counts) {
    const FirstLevelGrid grid = firstLevelGrid(light, mSettings);
    std::vector<uint8_t> out(grid.corners(), 0);
    if (!facesLight(light, r.point)) return out;
    const Vec3 origin = r.point + mSettings.rayOffset * r.normal;
    for (int j = 0; j <= grid.b; ++j)
        for (int i = 0; i <= grid.a; ++i) {
            const Vec3 target = light.point(double(i) / grid.a, double(j) / grid.b);
            if (glm::dot(target - r.point, r.normal) <= 0.0) continue;
            uint8_t& o = out[static_cast<size_t>(j) * (grid.a + 1) + i];
            if (!mSettings.reuseCorners) {
                ++counts.firstLevelRays;
                o = !query.occluded(origin, target);
                continue;
            }
            Corner* kept = mScratch->reusableCorner(light, grid, i, j);
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

