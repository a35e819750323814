// The pyramid of a receiver point's shadow segments, and narrowing a query to the obstacles it
// meets (include/penumbra/occluder.h).
#include <algorithm>
#include <cmath>

#include "penumbra/occluder.h"

namespace penumbra {

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

bool Pyramid::mayMeet(const Vec3& centre, double radius) const {
    for (const Plane& p : mPlanes) {
        const double reach = glm::dot(p.normal, centre) - p.offset + radius + mPad;
        if (reach < -1e-12 * (std::abs(p.offset) + 1.0)) return false;
    }
    return true;
}

bool Occluder::mayBlockIn(size_t i, const Pyramid& pyramid) const {
    const Solid& s = mSolid[i];
    if (s.box.empty() || !pyramid.mayMeet(s.box) || !pyramid.mayMeet(s.centre, s.radius))
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
