#include "light_footprint.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace penumbra {

namespace {

constexpr double kMargin = 1e-9;  // in (u, v) and radians: far above rounding, far below a lattice unit

}  // namespace

bool LightFootprints::build(const Occluder& occ, const std::vector<uint32_t>* only,
                            const Vec3& origin, const RectLight& light) {
    mFootprints.clear();
    mLight = &light;
    mOrigin = origin;
    const Vec3 n = light.normal();
    mToLight = glm::dot(light.corner - origin, n);
    if (!(std::abs(mToLight) > 0.0)) return false;
    const size_t count = only ? only->size() : occ.size();
    for (size_t k = 0; k < count; ++k) {
        const size_t i = only ? (*only)[k] : k;
        const Box3& box = occ.solidBounds(i);
        if (box.empty()) continue;  // nothing of it can block
        Footprint f;
        double u[8], v[8];
        for (int c = 0; c < 8; ++c) {
            const Vec3 x((c & 1) ? box.hi.x : box.lo.x, (c & 2) ? box.hi.y : box.lo.y,
                         (c & 4) ? box.hi.z : box.lo.z);
            const double along = glm::dot(x - origin, n);
            if (!(along / mToLight > 1e-9)) {
                mFootprints.clear();
                return false;
            }
            const Vec2 uv = light.coordinates(origin + (mToLight / along) * (x - origin));
            u[c] = uv.x;
            v[c] = uv.y;
        }
        // The hull of the eight points (Andrew's monotone chain), counter-clockwise in (u, v).
        int order[8] = {0, 1, 2, 3, 4, 5, 6, 7};
        std::sort(order, order + 8, [&](int a, int b) { return u[a] < u[b] || (u[a] == u[b] && v[a] < v[b]); });
        auto turn = [&](int o, int a, int b) {
            return (u[a] - u[o]) * (v[b] - v[o]) - (v[a] - v[o]) * (u[b] - u[o]);
        };
        int hull[16], h = 0;
        for (int a = 0; a < 8; ++a) {
            while (h >= 2 && turn(hull[h - 2], hull[h - 1], order[a]) <= 0.0) --h;
            hull[h++] = order[a];
        }
        const int lower = h + 1;
        for (int a = 6; a >= 0; --a) {
            while (h >= lower && turn(hull[h - 2], hull[h - 1], order[a]) <= 0.0) --h;
            hull[h++] = order[a];
        }
        f.n = h - 1;  // the last point repeats the first
        f.u0 = f.v0 = std::numeric_limits<double>::infinity();
        f.u1 = f.v1 = -std::numeric_limits<double>::infinity();
        for (int a = 0; a < f.n; ++a) {
            f.u[a] = u[hull[a]];
            f.v[a] = v[hull[a]];
            f.u0 = std::min(f.u0, f.u[a]), f.u1 = std::max(f.u1, f.u[a]);
            f.v0 = std::min(f.v0, f.v[a]), f.v1 = std::max(f.v1, f.v[a]);
        }
        const Vec3 toCentre = occ.solidCentre(i) - origin;
        const double dist = glm::length(toCentre);
        const double r = occ.solidRadius(i);
        f.axis = dist > 0.0 ? toCentre / dist : n;
        f.spread = r < dist ? std::asin(r / dist) : kPi;
        mFootprints.push_back(f);
    }
    return true;
}

// Whether the rectangle's directions from the origin may lie within f's cone: they lie within
// angle `reach` of the direction to the rectangle's centre, and the cones meet unless the angle
// between the axes exceeds spread + reach (compared as cosines: cos(apart) < cos(spread + reach)).
bool LightFootprints::inCone(const Footprint& f, double u0, double v0, double u1, double v1) const {
    if (!(f.spread < kPi)) return true;
    const Vec3 towards = glm::normalize(mLight->point(0.5 * (u0 + u1), 0.5 * (v0 + v1)) - mOrigin);
    double cosReach = 1.0;
    if (u1 > u0 || v1 > v0) {
        for (const Vec3& q : {mLight->point(u0, v0), mLight->point(u1, v0), mLight->point(u1, v1),
                              mLight->point(u0, v1)})
            cosReach = std::min(cosReach, glm::dot(towards, glm::normalize(q - mOrigin)));
    }
    const double reach = std::acos(std::clamp(cosReach, -1.0, 1.0)) + kMargin;
    if (f.spread + reach >= kPi) return true;
    return glm::dot(towards, f.axis) >= std::cos(f.spread + reach);
}

bool LightFootprints::outside(double u0, double v0, double u1, double v1) const {
    for (const Footprint& f : mFootprints) {
        if (u1 < f.u0 - kMargin || u0 > f.u1 + kMargin || v1 < f.v0 - kMargin || v0 > f.v1 + kMargin)
            continue;
        // Separating axes: each hull edge's outward normal (a box seen edge-on has none).
        bool separated = false;
        for (int i = 0; i < f.n && f.n >= 3 && !separated; ++i) {
            const int j = i + 1 == f.n ? 0 : i + 1;
            const double nu = f.v[j] - f.v[i], nv = -(f.u[j] - f.u[i]);
            const double len = std::hypot(nu, nv);
            if (!(len > 0.0)) continue;
            // The rectangle's corner least far along the normal.
            const double cu = nu > 0.0 ? u0 : u1, cv = nv > 0.0 ? v0 : v1;
            separated = ((cu - f.u[i]) * nu + (cv - f.v[i]) * nv) / len > kMargin;
        }
        if (separated || !inCone(f, u0, v0, u1, v1)) continue;
        return false;
    }
    return true;
}

}  // namespace penumbra
