// The pyramid of a receiver point's shadow segments, and narrowing a query to the obstacles it
// meets (include/penumbra/occluder.h).
#include <algorithm>
#include <cmath>
#include <limits>

#include "penumbra/occluder.h"

namespace penumbra {

namespace {

/// The point of triangle abc nearest to p (the Voronoi regions of its corners, edges and face,
/// tested in turn on the barycentric coordinates).
Vec3 nearestOnTriangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
    const Vec3 ab = b - a, ac = c - a, ap = p - a;
    const double d1 = glm::dot(ab, ap), d2 = glm::dot(ac, ap);
    if (d1 <= 0.0 && d2 <= 0.0) return a;
    const Vec3 bp = p - b;
    const double d3 = glm::dot(ab, bp), d4 = glm::dot(ac, bp);
    if (d3 >= 0.0 && d4 <= d3) return b;
    const double vc = d1 * d4 - d3 * d2;
    if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) return a + (d1 / (d1 - d3)) * ab;
    const Vec3 cp = p - c;
    const double d5 = glm::dot(ab, cp), d6 = glm::dot(ac, cp);
    if (d6 >= 0.0 && d5 <= d6) return c;
    const double vb = d5 * d2 - d1 * d6;
    if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) return a + (d2 / (d2 - d6)) * ac;
    const double va = d3 * d6 - d5 * d4;
    if (va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0)
        return b + ((d4 - d3) / ((d4 - d3) + (d5 - d6))) * (c - b);
    const double sum = va + vb + vc;
    if (!(sum > 0.0)) return a;  // degenerate: a corner stands for it (callers keep a margin)
    return a + (vb / sum) * ab + (vc / sum) * ac;
}

}  // namespace

Pyramid::Pyramid(const Vec3& apex, double pad, const std::vector<Vec3>& polygon)
    : mPad(std::max(0.0, pad) * (1.0 + 1e-6)) {  // a rounding margin on the caller's pad
    if (polygon.size() < 3) return;  // no planes: meets everything
    Vec3 centre(0.0);
    double size = 0.0;
    for (const Vec3& c : polygon) centre += c;
    centre /= double(polygon.size());
    for (const Vec3& c : polygon) size = std::max(size, glm::length(c - apex));
    // Planes whose normal rounding could turn (the apex on an edge's line, or in the polygon's
    // plane) are left out: fewer planes only keep more obstacles.
    const double tiny = 1e-9 * size * size;
    for (size_t i = 0; i < polygon.size(); ++i) {
        const Vec3 a = polygon[i] - apex, b = polygon[(i + 1) % polygon.size()] - apex;
        Vec3 n = glm::cross(a, b);
        const double len = glm::length(n);
        if (!(len > tiny)) continue;
        n /= len;
        if (glm::dot(n, centre - apex) < 0.0) n = -n;
        mPlanes.push_back({n, glm::dot(n, apex)});
    }
    // The polygon's plane: segments end on it, so the inside is the apex's side, the plane
    // itself included.
    Vec3 n = glm::cross(polygon[1] - polygon[0], polygon[2] - polygon[0]);
    const double len = glm::length(n);
    if (len > 0.0) {
        n /= len;
        const double side = glm::dot(n, apex - polygon[0]);
        if (std::abs(side) > 1e-9 * size) {
            if (side < 0.0) n = -n;  // now towards the apex
            mPlanes.push_back({n, glm::dot(n, polygon[0])});
        }
    }
    // The exact tests need every face.
    if (mPlanes.size() == polygon.size() + 1) {
        mApex = apex;
        mPolygon = polygon;
    }
}

bool Pyramid::mayMeet(const Box3& box) const {
    if (box.empty()) return false;
    const Vec3 centre = 0.5 * (box.lo + box.hi);
    const Vec3 half = 0.5 * (box.hi - box.lo) + Vec3(mPad);
    for (const Plane& p : mPlanes) {
        // The box's largest signed distance to the plane (towards the inside).
        const double reach = glm::dot(p.normal, centre) - p.offset +
                             glm::dot(glm::abs(p.normal), half);
        // Above rounding of the plane's offset (the pad is far larger in practice).
        if (reach < -1e-12 * (std::abs(p.offset) + 1.0)) return false;
    }
    return true;
}

bool Pyramid::mayMeetExactly(const Box3& box) const {
    if (!mayMeet(box)) return false;
    if (mPolygon.empty()) return true;
    const Vec3 centre = 0.5 * (box.lo + box.hi);
    const Vec3 half = 0.5 * (box.hi - box.lo) + Vec3(mPad);
    // The other separating axes: the box's own (its faces) and the cross products of its
    // axes with the pyramid's edges (apex to corner, corner to corner). Along each, the
    // pyramid's corners span an interval that must meet the grown box's.
    const size_t n = mPolygon.size();
    const double scale = glm::length(centre - mApex) + glm::length(half) + 1.0;
    auto separated = [&](const Vec3& axis) {
        const double len = glm::length(axis);
        if (!(len > 1e-9)) return false;  // parallel edges: no axis
        const Vec3 a = axis / len;
        const double c = glm::dot(a, centre), r = glm::dot(glm::abs(a), half);
        double lo = glm::dot(a, mApex), hi = lo;
        for (const Vec3& v : mPolygon) {
            const double d = glm::dot(a, v);
            lo = std::min(lo, d);
            hi = std::max(hi, d);
        }
        const double margin = 1e-9 * scale;
        return hi < c - r - margin || lo > c + r + margin;
    };
    for (int k = 0; k < 3; ++k) {
        Vec3 e(0.0);
        e[k] = 1.0;
        if (separated(e)) return false;
        for (size_t i = 0; i < n; ++i) {
            if (separated(glm::cross(e, mPolygon[i] - mApex))) return false;
            if (separated(glm::cross(e, mPolygon[(i + 1) % n] - mPolygon[i]))) return false;
        }
    }
    return true;
}

bool Pyramid::mayMeet(const Vec3& centre, double radius) const {
    bool inside = true;
    for (const Plane& p : mPlanes) {
        const double side = glm::dot(p.normal, centre) - p.offset;
        const double reach = side + radius + mPad;
        if (reach < -1e-12 * (std::abs(p.offset) + 1.0)) return false;
        inside = inside && side >= 0.0;
    }
    if (mPolygon.empty() || inside) return true;
    // Outside some face: the sphere meets the grown pyramid when the nearest point of the
    // pyramid's boundary (its side triangles and the polygon, as a fan) is within reach.
    const size_t n = mPolygon.size();
    double nearest2 = std::numeric_limits<double>::infinity();
    for (size_t i = 0; i < n; ++i) {
        const Vec3& a = mPolygon[i];
        const Vec3& b = mPolygon[(i + 1) % n];
        auto distance2 = [&](const Vec3& q) { return glm::dot(q - centre, q - centre); };
        nearest2 = std::min(nearest2, distance2(nearestOnTriangle(centre, mApex, a, b)));
        if (i >= 1 && i + 1 < n)
            nearest2 = std::min(nearest2, distance2(nearestOnTriangle(centre, mPolygon[0], a, b)));
    }
    const double reach = radius + mPad;
    const double margin = 1e-9 * (glm::length(centre - mApex) + reach + 1.0);
    return std::sqrt(nearest2) <= reach + margin;
}

bool Occluder::mayBlockIn(size_t i, const Pyramid& pyramid) const {
    const Solid& s = mSolid[i];
    if (s.box.empty() || !pyramid.mayMeet(s.box) || !pyramid.mayMeet(s.centre, s.radius) ||
        !pyramid.mayMeetExactly(s.box))
        return false;
    // A level set's parts: a pyramid through the hole of a torus, or past a capsule's side
    // within its box, meets none.
    return s.parts.empty() || std::any_of(s.parts.begin(), s.parts.end(),
                                          [&](const Box3& b) { return pyramid.mayMeet(b); });
}

size_t Occluder::Query::narrow(const Pyramid& pyramid) {
    const size_t depth = mWidened.size();
    if (mNarrowed.size() <= depth) mNarrowed.emplace_back();
    std::vector<uint32_t>& list = mNarrowed[depth];
    list.clear();
    const size_t count = mCandidates ? mCandidates->size() : mOccluder->size();
    for (size_t k = 0; k < count; ++k) {
        const uint32_t i = mCandidates ? (*mCandidates)[k] : static_cast<uint32_t>(k);
        if (mOccluder->mayBlockIn(i, pyramid)) list.push_back(i);
    }
    mWidened.push_back(mCandidates);
    mCandidates = &list;
    return list.size();
}

void Occluder::Query::widen() {
    if (mWidened.empty()) return;
    mCandidates = mWidened.back();
    mWidened.pop_back();
}

}  // namespace penumbra
