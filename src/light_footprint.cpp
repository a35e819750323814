#include "light_footprint.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "convex_clip.h"

namespace penumbra {

namespace {

constexpr double kMargin = 1e-9;  // in (u, v) and radians: far above rounding, far below a lattice unit

// Twice the signed area of a polygon (positive counterclockwise).
double twiceArea(const std::vector<Vec2>& p) {
    double a = 0.0;
    for (size_t i = 0; i < p.size(); ++i) {
        const Vec2& q = p[i];
        const Vec2& r = p[(i + 1) % p.size()];
        a += q.x * r.y - q.y * r.x;
    }
    return a;
}

void makeCounterclockwise(std::vector<Vec2>& p) {
    if (twiceArea(p) < 0.0) std::reverse(p.begin(), p.end());
}

// Edge i's unit outward normal of a counterclockwise polygon; zero for an edge of no length.
Vec2 outward(const std::vector<Vec2>& p, size_t i) {
    const Vec2 e = p[(i + 1) % p.size()] - p[i];
    const double len = glm::length(e);
    return len > 0.0 ? Vec2(e.y, -e.x) / len : Vec2(0.0);
}

// The part of `poly` on the inner side of the line through `at` with outward normal n.
std::vector<Vec2> clipHalfPlane(std::vector<Vec2> poly, const Vec2& at, const Vec2& n) {
    keepNonNegative(poly, [&](const Vec2& q) { return glm::dot(at - q, n); });
    return poly;
}

// The part of `poly` inside the convex counterclockwise `clip` (Sutherland-Hodgman).
std::vector<Vec2> clipConvex(std::vector<Vec2> poly, const std::vector<Vec2>& clip) {
    for (size_t i = 0; i < clip.size() && poly.size() >= 3; ++i) {
        const Vec2 n = outward(clip, i);
        if (n != Vec2(0.0)) poly = clipHalfPlane(poly, clip[i], n);
    }
    return poly;
}

// A convex counterclockwise polygon's width: the smallest, over its edges, of its reach
// inward from that edge.
double convexWidth(const std::vector<Vec2>& p) {
    double width = std::numeric_limits<double>::infinity();
    for (size_t e = 0; e < p.size(); ++e) {
        const Vec2 n = outward(p, e);
        if (n == Vec2(0.0)) continue;
        double reach = 0.0;
        for (const Vec2& q : p) reach = std::max(reach, glm::dot(p[e] - q, n));
        width = std::min(width, reach);
    }
    return width;
}

constexpr int kRoundSides = 48;  // sides of the polygons inscribed in circles and cones

// The corners of kRoundSides-gon inscribed in the unit circle (cosine, sine), found once.
const std::array<Vec2, kRoundSides>& unitPolygon() {
    static const std::array<Vec2, kRoundSides> corners = [] {
        std::array<Vec2, kRoundSides> c;
        for (int k = 0; k < kRoundSides; ++k) {
            const double a = 2.0 * kPi * k / kRoundSides;
            c[size_t(k)] = Vec2(std::cos(a), std::sin(a));
        }
        return c;
    }();
    return corners;
}

}  // namespace

std::vector<Vec2> LightFootprints::emittingPolygon() const {
    const RectLight& l = *mLight;
    auto plane = [&](const Vec3& q) {
        return Vec2(glm::dot(q - l.corner, mPlaneX), glm::dot(q - l.corner, mPlaneY));
    };
    std::vector<Vec2> frame;
    for (const Vec3& q : {l.corner, l.corner + l.edgeU, l.corner + l.edgeU + l.edgeV, l.corner + l.edgeV})
        frame.push_back(plane(q));
    makeCounterclockwise(frame);
    std::vector<Vec2> shape;
    if (l.shape == LightShape::Polygon) {
        for (const Vec3& q : l.vertices) shape.push_back(plane(q));
    } else if (l.shape == LightShape::Disc) {
        const Vec3 e1 = glm::normalize(l.edgeU), e2 = glm::cross(l.normal(), e1);
        for (const Vec2& c : unitPolygon()) shape.push_back(plane(l.center + l.radius * (c.x * e1 + c.y * e2)));
    } else {
        return frame;
    }
    makeCounterclockwise(shape);
    return clipConvex(shape, frame);
}

std::vector<Vec2> LightFootprints::conePolygon(const Footprint& f) const {
    std::vector<Vec2> out;
    if (!(f.spread < 0.5 * kPi)) return out;
    const Vec3 n = mLight->normal();
    const Vec3 helper = std::abs(f.axis.x) < 0.9 ? Vec3(1.0, 0.0, 0.0) : Vec3(0.0, 1.0, 0.0);
    const Vec3 e1 = glm::normalize(glm::cross(f.axis, helper)), e2 = glm::cross(f.axis, e1);
    for (const Vec2& c : unitPolygon()) {
        const Vec3 d = f.cosSpread * f.axis + f.sinSpread * (c.x * e1 + c.y * e2);
        const double along = glm::dot(d, n);
        // The ray meets the light's plane ahead of the origin (mToLight: signed distance).
        if (!(along * mToLight > 0.0)) return {};
        const Vec3 q = mOrigin + (mToLight / along) * d - mLight->corner;
        out.emplace_back(glm::dot(q, mPlaneX), glm::dot(q, mPlaneY));
    }
    makeCounterclockwise(out);
    return out;
}

double LightFootprints::thinSliver(const Receiver& r, double width) const {
    double heaviest = 0.0;
    // A rectangle's border is lattice lines, whose points (traced or crossed by the contour
    // there) see a sliver along it; a circle or a polygon's cutting edge runs between lattice
    // points, and a sliver beside it can fall between the lattice and the border.
    if (!mBounded || mFootprints.empty() || !borderOffLattice(*mLight)) return heaviest;
    const std::vector<Vec2> light = emittingPolygon();
    if (light.size() < 3) return heaviest;
    const double margin = 1e-9 * std::max(glm::length(mLight->edgeU), glm::length(mLight->edgeV));
    // A sliver's form factor, its corners taken back to world space.
    std::vector<Vec3> world;
    auto weigh = [&](const std::vector<Vec2>& sliver) {
        world.clear();
        for (const Vec2& q : sliver) world.push_back(mLight->corner + q.x * mPlaneX + q.y * mPlaneY);
        const std::vector<Vec3> above = clipToHorizon(world, r);
        if (above.size() >= 3) heaviest = std::max(heaviest, std::abs(polygonFormFactor(above, r)));
    };
    for (const Footprint& f : mFootprints) {
        if (f.u1 < 0.0 || f.u0 > 1.0 || f.v1 < 0.0 || f.v0 > 1.0 || f.n < 3) continue;
        std::vector<Vec2> print;
        for (int a = 0; a < f.n; ++a) print.emplace_back(f.x[a], f.y[a]);
        makeCounterclockwise(print);
        const std::vector<Vec2> cone = conePolygon(f);
        if (cone.size() >= 3) print = clipConvex(print, cone);
        if (print.size() < 3) continue;
        const std::vector<Vec2> overlap = clipConvex(print, light);
        if (overlap.size() < 3 || !(std::abs(twiceArea(overlap)) > margin * margin)) continue;
        // A sliver of shadow: the overlap is thin.
        if (convexWidth(overlap) < width) weigh(overlap);
        // A sliver of light: in front of one of the footprint's edges (past its line, between
        // the normals at its ends) the light reaches only a little.
        for (size_t e = 0; e < print.size(); ++e) {
            const Vec2 n = outward(print, e);
            if (n == Vec2(0.0)) continue;
            const Vec2& from = print[e];
            const Vec2& to = print[(e + 1) % print.size()];
            const Vec2 along = glm::normalize(to - from);
            std::vector<Vec2> front = clipHalfPlane(light, from, -n);
            front = clipHalfPlane(front, from, -along);
            front = clipHalfPlane(front, to, along);
            if (front.size() < 3) continue;
            double depth = 0.0;
            for (const Vec2& q : front) depth = std::max(depth, glm::dot(q - from, n));
            if (depth > margin && depth < width) weigh(front);
        }
    }
    return heaviest;
}

int LightFootprints::hull(const double u[8], const double v[8], double hu[8], double hv[8]) {
    // Andrew's monotone chain.
    int order[8] = {0, 1, 2, 3, 4, 5, 6, 7};
    std::sort(order, order + 8, [&](int a, int b) { return u[a] < u[b] || (u[a] == u[b] && v[a] < v[b]); });
    auto turn = [&](int o, int a, int b) {
        return (u[a] - u[o]) * (v[b] - v[o]) - (v[a] - v[o]) * (u[b] - u[o]);
    };
    int h[16], n = 0;
    for (int a = 0; a < 8; ++a) {
        while (n >= 2 && turn(h[n - 2], h[n - 1], order[a]) <= 0.0) --n;
        h[n++] = order[a];
    }
    const int lower = n + 1;
    for (int a = 6; a >= 0; --a) {
        while (n >= lower && turn(h[n - 2], h[n - 1], order[a]) <= 0.0) --n;
        h[n++] = order[a];
    }
    --n;  // the last point repeats the first
    for (int a = 0; a < n; ++a) {
        hu[a] = u[h[a]];
        hv[a] = v[h[a]];
    }
    return n;
}

bool LightFootprints::build(const Occluder& occ, const std::vector<uint32_t>* only,
                            const Vec3& origin, const RectLight& light) {
    mFootprints.clear();
    mKernels.clear();
    mBounded = false;
    mUnboundedThin = false;
    mLight = &light;
    mOrigin = origin;
    const Vec3 n = light.normal();
    mToLight = glm::dot(light.corner - origin, n);
    mPlaneX = glm::normalize(light.edgeU);
    mPlaneY = glm::cross(n, mPlaneX);
    if (!(std::abs(mToLight) > 0.0)) return false;
    // Where a point projects from the origin onto the light's plane, in (u, v); false when it
    // lies level with or behind the origin (seen from the light), or `before` and it does not
    // lie before the light's plane either.
    auto project = [&](const Vec3& x, bool before, double& u, double& v) {
        const double along = glm::dot(x - origin, n) / mToLight;  // 1 on the light's plane
        if (!(along > 1e-9) || (before && !(along < 1.0 - 1e-9))) return false;
        const Vec2 uv = light.coordinates(origin + (x - origin) / along);
        u = uv.x;
        v = uv.y;
        return true;
    };
    bool bounded = true, unboundedThin = true;
    const size_t count = only ? only->size() : occ.size();
    for (size_t k = 0; k < count; ++k) {
        const size_t i = only ? (*only)[k] : k;
        // Kernels: wholly between the origin and the light, so that every segment to a point
        // of their projection meets them on its way.
        for (const Occluder::KernelBall& b : occ.kernelBalls(i)) {
            const double along = glm::dot(b.centre - origin, n) / mToLight;
            const double dist = glm::length(b.centre - origin);
            const double reach = b.radius / std::abs(mToLight);
            if (!(along - reach > 1e-9 && along + reach < 1.0 - 1e-9 && b.radius < dist)) continue;
            Kernel ker;
            ker.obstacle = int(i);
            ker.exact = occ.voxelSize(i) == 0.0;
            ker.centre = b.centre;
            ker.radius = b.radius;
            ker.axis = (b.centre - origin) / dist;
            ker.spread = std::asin(b.radius / dist);
            ker.cosSpread = std::cos(ker.spread);
            ker.sinSpread = std::sin(ker.spread);
            mKernels.push_back(ker);
        }
        const Box3 kb = occ.kernelBox(i);
        if (!kb.empty()) {
            double u[8], v[8];
            bool all = true;
            for (int c = 0; c < 8 && all; ++c) all = project(kb.corner(c), true, u[c], v[c]);
            if (all) {
                Kernel ker;
                ker.ball = false;
                ker.obstacle = int(i);
                ker.box = kb;
                ker.n = hull(u, v, ker.u, ker.v);
                normals(ker.u, ker.v, ker.n, ker.nu, ker.nv);
                toPlane(ker.u, ker.v, ker.n, ker.x, ker.y);
                normals(ker.x, ker.y, ker.n, ker.nx, ker.ny);
                if (ker.n >= 3) mKernels.push_back(ker);
            }
        }
        // The footprint (once unbounded by an obstacle that is not a thin level set, nothing
        // more is asked of the others).
        if (!bounded && !unboundedThin) continue;
        if (occ.solidBounds(i).empty()) continue;  // nothing of it can block
        // Its oriented solid box (the axis-aligned one where that is no tighter): a tilted
        // capsule's or box's footprint is then that much narrower.
        const OrientedBox& box = occ.solidOriented(i);
        Footprint f;
        f.obstacle = int(i);
        double u[8], v[8];
        bool projects = true;
        for (int c = 0; c < 8 && projects; ++c) projects = project(box.corner(c), false, u[c], v[c]);
        if (!projects) {
            // A box reaching level with the origin: a segment to the light stays within s x reach
            // of the origin over its first fraction s (reach: the origin's distance from the
            // light's farthest corner), so it meets the box only past s = dBox / reach. What
            // lies beyond that plane projects to a bounded region; the rectangle in (u, v)
            // around its points holds it. Not for an origin on or in the box.
            const double dBox = box.distanceTo(origin);
            double reach = 0.0;
            for (const Vec3& q : {light.corner, light.corner + light.edgeU, light.corner + light.edgeV,
                                  light.corner + light.edgeU + light.edgeV})
                reach = std::max(reach, glm::length(q - origin));
            const double sc = reach > 0.0 ? 0.999 * dBox / reach : 0.0;
            if (sc > 1e-6) {
                double along[8];
                for (int c = 0; c < 8; ++c) along[c] = glm::dot(box.corner(c) - origin, n) / mToLight;
                double lo[2] = {std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity()};
                double hi[2] = {-lo[0], -lo[1]};
                int kept = 0;
                auto take = [&](const Vec3& x, double a) {
                    const Vec2 uv = light.coordinates(origin + (x - origin) / a);
                    lo[0] = std::min(lo[0], uv.x), hi[0] = std::max(hi[0], uv.x);
                    lo[1] = std::min(lo[1], uv.y), hi[1] = std::max(hi[1], uv.y);
                    ++kept;
                };
                for (int c = 0; c < 8; ++c) {
                    if (along[c] >= sc) take(box.corner(c), along[c]);
                    for (int bit = 1; bit < 8; bit <<= 1) {
                        const int d = c | bit;
                        if (d == c || (along[c] >= sc) == (along[d] >= sc)) continue;
                        const double w = (sc - along[c]) / (along[d] - along[c]);
                        take(box.corner(c) + w * (box.corner(d) - box.corner(c)), sc);
                    }
                }
                if (kept == 0) continue;  // wholly nearer than any segment can reach it
                for (int c = 0; c < 8; ++c) {
                    u[c] = (c & 1) == ((c >> 1) & 1) ? lo[0] : hi[0];
                    v[c] = (c & 2) ? hi[1] : lo[1];
                }
                projects = true;
            }
        }
        if (!projects) {
            bounded = false;
            unboundedThin = unboundedThin && occ.voxelSize(i) > 0.0 && occ.kernelBalls(i).empty();
        }
        if (!bounded) continue;
        f.n = hull(u, v, f.u, f.v);
        normals(f.u, f.v, f.n, f.nu, f.nv);
        toPlane(f.u, f.v, f.n, f.x, f.y);
        normals(f.x, f.y, f.n, f.nx, f.ny);
        f.u0 = f.v0 = std::numeric_limits<double>::infinity();
        f.u1 = f.v1 = -std::numeric_limits<double>::infinity();
        for (int a = 0; a < f.n; ++a) {
            f.u0 = std::min(f.u0, f.u[a]), f.u1 = std::max(f.u1, f.u[a]);
            f.v0 = std::min(f.v0, f.v[a]), f.v1 = std::max(f.v1, f.v[a]);
        }
        const Vec3 toCentre = occ.solidCentre(i) - origin;
        const double dist = glm::length(toCentre);
        const double r = occ.solidRadius(i);
        f.axis = dist > 0.0 ? toCentre / dist : n;
        f.spread = r < dist ? std::asin(r / dist) : kPi;
        f.cosSpread = std::cos(f.spread);
        f.sinSpread = std::sin(f.spread);
        mFootprints.push_back(f);
    }
    if (!bounded) mFootprints.clear();
    mBounded = bounded;
    mUnboundedThin = !bounded && unboundedThin;
    return bounded;
}

double LightFootprints::chordAcross(const Vec3& axis, double spread) const {
    // The cone meets the plane in an ellipse at least as wide as its chord through the axis's
    // point, across the axis: 2 h tan(spread) / cos(axis, normal).
    const double cosAxis = std::abs(glm::dot(axis, mLight->normal()));
    if (!(spread < 0.5 * kPi) || !(cosAxis > 0.0)) return std::numeric_limits<double>::infinity();
    return 2.0 * std::abs(mToLight) * std::tan(spread) / cosAxis;
}

double LightFootprints::ballWidth(const Vec3& centre, double radius) const {
    const Vec3 d = centre - mOrigin;
    const double dist = glm::length(d);
    if (!(radius < dist)) return std::numeric_limits<double>::infinity();
    return chordAcross(d / dist, std::asin(radius / dist));
}

double LightFootprints::narrowestWidth(const Occluder& occ) const {
    if (!mBounded) return mUnboundedThin ? 0.0 : -1.0;
    double narrowest = std::numeric_limits<double>::infinity();
    for (const Footprint& f : mFootprints) {
        if (f.u1 < 0.0 || f.u0 > 1.0 || f.v1 < 0.0 || f.v0 > 1.0) continue;
        // A convex polygon's width: the smallest, over its edges, of its reach from that edge.
        double width = std::numeric_limits<double>::infinity();
        for (int e = 0; e < f.n; ++e) {
            if (f.nx[e] == 0.0 && f.ny[e] == 0.0) continue;
            double reach = 0.0;
            for (int k = 0; k < f.n; ++k)
                reach = std::max(reach, (f.x[e] - f.x[k]) * f.nx[e] + (f.y[e] - f.y[k]) * f.ny[e]);
            width = std::min(width, reach);
        }
        width = std::min(width, chordAcross(f.axis, f.spread));
        // A level set may be thin where its box is wide: no wider than its kernel balls' widest
        // footprint (none: 0). An analytic shape is convex, its footprint its own measure.
        if (occ.voxelSize(size_t(f.obstacle)) > 0.0) {
            double thickness = 0.0;
            for (const Occluder::KernelBall& b : occ.kernelBalls(size_t(f.obstacle)))
                thickness = std::max(thickness, ballWidth(b.centre, b.radius));
            width = std::min(width, thickness);
        }
        narrowest = std::min(narrowest, width);
    }
    return narrowest;
}

bool LightFootprints::borderOffLattice(const RectLight& light) {
    // A parallelogram light is its own frame.
    const bool parallelogram = light.shape == LightShape::Polygon && light.vertices.size() == 4 &&
                               frameHoldsCorners(light);
    return light.shape != LightShape::Rect && !parallelogram;
}

double LightFootprints::largestMagnifiedVoxel(const Occluder& occ) const {
    if (!mBounded || !mLight) return 0.0;
    double farthest = 0.0;
    for (const Vec3& c : {mLight->corner, mLight->corner + mLight->edgeU,
                          mLight->corner + mLight->edgeV, mLight->corner + mLight->edgeU + mLight->edgeV})
        farthest = std::max(farthest, glm::length(c - mOrigin));
    double largest = 0.0;
    for (const Footprint& f : mFootprints) {
        if (f.u1 < 0.0 || f.u0 > 1.0 || f.v1 < 0.0 || f.v0 > 1.0) continue;
        const double voxel = occ.voxelSize(size_t(f.obstacle));
        if (!(voxel > 0.0)) continue;
        const Box3& b = occ.solidBounds(size_t(f.obstacle));
        const Vec3 nearest = glm::clamp(mOrigin, b.lo, b.hi);
        const double d = glm::length(nearest - mOrigin);
        if (!(d > 0.0)) return std::numeric_limits<double>::infinity();
        largest = std::max(largest, voxel * farthest / d);
    }
    return largest;
}

void LightFootprints::normals(const double u[8], const double v[8], int n, double nu[8],
                              double nv[8]) {
    for (int i = 0; i < n; ++i) {
        const int j = i + 1 == n ? 0 : i + 1;
        const double a = v[j] - v[i], b = -(u[j] - u[i]);
        const double len = std::hypot(a, b);
        nu[i] = len > 0.0 ? a / len : 0.0;
        nv[i] = len > 0.0 ? b / len : 0.0;
    }
}

void LightFootprints::directions(double u0, double v0, double u1, double v1, Spread& sp) const {
    if (sp.known) return;
    sp.known = true;
    sp.towards = glm::normalize(mLight->point(0.5 * (u0 + u1), 0.5 * (v0 + v1)) - mOrigin);
    double c = 1.0;
    if (u1 > u0 || v1 > v0) {
        for (const Vec3& q : {mLight->point(u0, v0), mLight->point(u1, v0), mLight->point(u1, v1),
                              mLight->point(u0, v1)})
            c = std::min(c, glm::dot(sp.towards, glm::normalize(q - mOrigin)));
    }
    sp.cosReach = std::clamp(c, -1.0, 1.0);
    sp.sinReach = std::sqrt(std::max(0.0, (1.0 - sp.cosReach) * (1.0 + sp.cosReach)));
}

// Whether the rectangle's directions from the origin may lie within f's cone: they lie within
// angle `reach` of the direction to the rectangle's centre, and the cones meet unless the angle
// between the axes exceeds spread + reach, compared as cosines (cos(apart) < cos(spread +
// reach), by the angle-sum formula), with a margin of kMargin on the cosine, which is at least
// kMargin on the angle.
bool LightFootprints::inCone(const Footprint& f, double u0, double v0, double u1, double v1,
                             Spread& sp) const {
    if (!(f.spread < kPi)) return true;
    directions(u0, v0, u1, v1, sp);
    // spread + reach at least pi: reach >= pi - spread, cos(reach) <= -cos(spread).
    if (sp.cosReach <= -f.cosSpread + kMargin) return true;
    const double cosSum = f.cosSpread * sp.cosReach - f.sinSpread * sp.sinReach;
    return glm::dot(sp.towards, f.axis) >= cosSum - kMargin;
}

bool LightFootprints::outside(double u0, double v0, double u1, double v1) const {
    Spread sp;
    return outsideAll(u0, v0, u1, v1, sp);
}

bool LightFootprints::hidden(double u0, double v0, double u1, double v1) const {
    Spread sp;
    return hiddenBy(u0, v0, u1, v1, sp);
}

int LightFootprints::classify(double u0, double v0, double u1, double v1) const {
    Spread sp;
    if (outsideAll(u0, v0, u1, v1, sp)) return 1;
    if (hiddenBy(u0, v0, u1, v1, sp)) return 0;
    return -1;
}

void LightFootprints::toPlane(const double u[8], const double v[8], int n, double x[8],
                              double y[8]) const {
    for (int a = 0; a < n; ++a) {
        const Vec3 p = mLight->point(u[a], v[a]) - mLight->corner;
        x[a] = glm::dot(p, mPlaneX);
        y[a] = glm::dot(p, mPlaneY);
    }
}

// Each footprint is the hull and the cone's intersection, so its distance is at least the
// larger of theirs: the hull's at least the largest signed distance past one of its edges' lines
// (the hull being convex), the cone's at least |Q - M| sin(angle past the cone) (the nearest a
// ray from M at that angle from MQ comes to Q).
double LightFootprints::distanceTo(const Footprint& f, const LightPoint& lp) {
    const double px = lp.x, py = lp.y, dist = lp.dist;
    const Vec3& towards = lp.towards;
    double hull = f.n >= 3 ? -std::numeric_limits<double>::infinity() : 0.0;
    for (int i = 0; i < f.n && f.n >= 3; ++i)
        if (f.nx[i] != 0.0 || f.ny[i] != 0.0)
            hull = std::max(hull, (px - f.x[i]) * f.nx[i] + (py - f.y[i]) * f.ny[i]);
    double cone = 0.0;
    // Inside the cone (its cosine at least the spread's) the cone proves nothing: no angle.
    const double cosApart = glm::dot(towards, f.axis);
    if (f.spread < kPi && cosApart < f.cosSpread) {
        const double apart = std::acos(std::clamp(cosApart, -1.0, 1.0));
        const double past = apart - f.spread;
        if (past > 0.0) cone = dist * std::sin(std::min(past, 0.5 * kPi));
    }
    return std::max({hull, cone, 0.0});
}

LightFootprints::LightPoint LightFootprints::pointAt(double u, double v) const {
    LightPoint lp;
    const Vec3 q = mLight->point(u, v);
    const Vec3 p = q - mLight->corner;
    lp.x = glm::dot(p, mPlaneX);
    lp.y = glm::dot(p, mPlaneY);
    lp.d = q - mOrigin;
    lp.dist = glm::length(lp.d);
    lp.towards = lp.d / lp.dist;
    return lp;
}

double LightFootprints::distance(const LightPoint& lp) const {
    if (!mBounded) return 0.0;
    double nearest = std::numeric_limits<double>::infinity();
    for (const Footprint& f : mFootprints) {
        nearest = std::min(nearest, distanceTo(f, lp));
        if (!(nearest > 0.0)) return 0.0;
    }
    // A margin far above rounding.
    return std::max(0.0, nearest * (1.0 - 1e-9) - 1e-9 * lp.dist);
}

// Inside a kernel's projection the distance to its outside is at least, for a ball, |Q - M|
// sin(angle left inside its cone) (the farthest a light point can be from Q with its
// direction still inside), and for a box the smallest distance inside its hull's edge lines.
// The segment enters the kernel where a ray meets a ball or a box: the nearer root of the
// quadratic, the largest of the slabs' entries.
LightFootprints::Hidden LightFootprints::hiddenAt(const LightPoint& lp) const {
    Hidden out;
    if (!mBounded || mKernels.empty()) return out;
    const double px = lp.x, py = lp.y, dist = lp.dist;
    const Vec3& d = lp.d;
    const Vec3& towards = lp.towards;
    const Kernel* best = nullptr;
    for (const Kernel& k : mKernels) {
        double inside = 0.0;
        if (k.ball) {
            // Outside the cone (its cosine below the spread's) nothing is hidden: no angle.
            const double cosApart = glm::dot(towards, k.axis);
            if (!(cosApart > k.cosSpread)) continue;
            const double apart = std::acos(std::clamp(cosApart, -1.0, 1.0));
            if (apart < k.spread) inside = dist * std::sin(k.spread - apart);
        } else {
            inside = std::numeric_limits<double>::infinity();
            for (int i = 0; i < k.n && inside > 0.0; ++i)
                inside = k.nx[i] != 0.0 || k.ny[i] != 0.0
                             ? std::min(inside, -((px - k.x[i]) * k.nx[i] + (py - k.y[i]) * k.ny[i]))
                             : 0.0;
        }
        if (inside > out.radius) {
            out.radius = inside;
            best = &k;
        }
    }
    if (!best) return out;
    // The nearest other footprint: none may hold the point.
    double others = std::numeric_limits<double>::infinity();
    for (const Footprint& f : mFootprints) {
        if (f.obstacle == best->obstacle) continue;
        others = std::min(others, distanceTo(f, lp));
        if (!(others > 0.0)) return Hidden{};
    }
    double t = 0.0;
    if (best->ball) {
        const Vec3 oc = mOrigin - best->centre;
        const double a = glm::dot(d, d), b = glm::dot(d, oc);
        const double c = glm::dot(oc, oc) - best->radius * best->radius;
        t = (-b - std::sqrt(std::max(0.0, b * b - a * c))) / a;
    } else {
        for (int axis = 0; axis < 3; ++axis) {
            if (d[axis] == 0.0) continue;
            const double t0 = (best->box.lo[axis] - mOrigin[axis]) / d[axis];
            const double t1 = (best->box.hi[axis] - mOrigin[axis]) / d[axis];
            t = std::max(t, std::min(t0, t1));
        }
    }
    // Margins far above rounding.
    out.radius = std::max(0.0, out.radius * (1.0 - 1e-9) - 1e-9 * dist);
    out.others = std::max(0.0, others * (1.0 - 1e-9) - 1e-9 * dist);  // infinite when alone
    out.obstacle = best->obstacle;
    out.fraction = std::clamp(t, 0.0, 1.0);
    out.exact = best->exact;
    if (!(out.radius > 0.0)) return Hidden{};
    return out;
}

bool LightFootprints::outsideAll(double u0, double v0, double u1, double v1, Spread& sp) const {
    if (!mBounded) return false;
    for (const Footprint& f : mFootprints) {
        if (u1 < f.u0 - kMargin || u0 > f.u1 + kMargin || v1 < f.v0 - kMargin || v0 > f.v1 + kMargin)
            continue;
        // Separating axes: each hull edge's outward normal (a box seen edge-on has none).
        bool separated = false;
        for (int i = 0; i < f.n && f.n >= 3 && !separated; ++i) {
            const double nu = f.nu[i], nv = f.nv[i];
            if (nu == 0.0 && nv == 0.0) continue;
            // The rectangle's corner least far along the normal.
            const double cu = nu > 0.0 ? u0 : u1, cv = nv > 0.0 ? v0 : v1;
            separated = (cu - f.u[i]) * nu + (cv - f.v[i]) * nv > kMargin;
        }
        if (separated || !inCone(f, u0, v0, u1, v1, sp)) continue;
        return false;
    }
    return true;
}

bool LightFootprints::hiddenBy(double u0, double v0, double u1, double v1, Spread& sp) const {
    for (const Kernel& k : mKernels) {
        if (k.ball) {
            // Inside the ball's cone: reach < spread (cos(reach) > cos(spread)) and the angle
            // between the axes below spread - reach, with kMargin on the cosines.
            directions(u0, v0, u1, v1, sp);
            if (!(sp.cosReach > k.cosSpread + kMargin)) continue;
            const double cosDiff = k.cosSpread * sp.cosReach + k.sinSpread * sp.sinReach;
            if (glm::dot(sp.towards, k.axis) > cosDiff + kMargin) return true;
            continue;
        }
        // Every corner of the rectangle on the inner side of every edge of the box's hull.
        bool in = true;
        for (int i = 0; i < k.n && in; ++i) {
            const double nu = k.nu[i], nv = k.nv[i];
            // The rectangle's corner farthest along the outward normal.
            const double cu = nu > 0.0 ? u1 : u0, cv = nv > 0.0 ? v1 : v0;
            in = (nu != 0.0 || nv != 0.0) && (cu - k.u[i]) * nu + (cv - k.v[i]) * nv < -kMargin;
        }
        if (in) return true;
    }
    return false;
}

}  // namespace penumbra
