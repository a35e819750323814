#include "light_footprint.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace penumbra {

namespace {

constexpr double kMargin = 1e-9;  // in (u, v) and radians: far above rounding, far below a lattice unit

}  // namespace

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
    mLight = &light;
    mOrigin = origin;
    const Vec3 n = light.normal();
    mToLight = glm::dot(light.corner - origin, n);
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
    bool bounded = true;
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
            ker.axis = (b.centre - origin) / dist;
            ker.spread = std::asin(b.radius / dist);
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
                ker.n = hull(u, v, ker.u, ker.v);
                if (ker.n >= 3) mKernels.push_back(ker);
            }
        }
        // The footprint.
        if (!bounded) continue;
        const Box3& box = occ.solidBounds(i);
        if (box.empty()) continue;  // nothing of it can block
        Footprint f;
        double u[8], v[8];
        for (int c = 0; c < 8 && bounded; ++c) bounded = project(box.corner(c), false, u[c], v[c]);
        if (!bounded) continue;
        f.n = hull(u, v, f.u, f.v);
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
        mFootprints.push_back(f);
    }
    if (!bounded) mFootprints.clear();
    mBounded = bounded;
    return bounded;
}

void LightFootprints::directions(double u0, double v0, double u1, double v1, Vec3& towards,
                                 double& cosReach) const {
    towards = glm::normalize(mLight->point(0.5 * (u0 + u1), 0.5 * (v0 + v1)) - mOrigin);
    cosReach = 1.0;
    if (u1 > u0 || v1 > v0) {
        for (const Vec3& q : {mLight->point(u0, v0), mLight->point(u1, v0), mLight->point(u1, v1),
                              mLight->point(u0, v1)})
            cosReach = std::min(cosReach, glm::dot(towards, glm::normalize(q - mOrigin)));
    }
}

// Whether the rectangle's directions from the origin may lie within f's cone: they lie within
// angle `reach` of the direction to the rectangle's centre, and the cones meet unless the angle
// between the axes exceeds spread + reach (compared as cosines: cos(apart) < cos(spread + reach)).
bool LightFootprints::inCone(const Footprint& f, double u0, double v0, double u1, double v1) const {
    if (!(f.spread < kPi)) return true;
    Vec3 towards;
    double cosReach;
    directions(u0, v0, u1, v1, towards, cosReach);
    const double reach = std::acos(std::clamp(cosReach, -1.0, 1.0)) + kMargin;
    if (f.spread + reach >= kPi) return true;
    return glm::dot(towards, f.axis) >= std::cos(f.spread + reach);
}

bool LightFootprints::outside(double u0, double v0, double u1, double v1) const {
    if (!mBounded) return false;
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

bool LightFootprints::hidden(double u0, double v0, double u1, double v1) const {
    bool known = false;  // the rectangle's directions, computed for the first ball
    Vec3 towards;
    double reach = 0.0;
    for (const Kernel& k : mKernels) {
        if (k.ball) {
            if (!known) {
                double cosReach;
                directions(u0, v0, u1, v1, towards, cosReach);
                reach = std::acos(std::clamp(cosReach, -1.0, 1.0)) + kMargin;
                known = true;
            }
            if (k.spread > reach && glm::dot(towards, k.axis) > std::cos(k.spread - reach)) return true;
            continue;
        }
        // Every corner of the rectangle on the inner side of every edge of the box's hull.
        bool in = true;
        for (int i = 0; i < k.n && in; ++i) {
            const int j = i + 1 == k.n ? 0 : i + 1;
            const double nu = k.v[j] - k.v[i], nv = -(k.u[j] - k.u[i]);
            const double len = std::hypot(nu, nv);
            // The rectangle's corner farthest along the outward normal.
            const double cu = nu > 0.0 ? u1 : u0, cv = nv > 0.0 ? v1 : v0;
            in = len > 0.0 && ((cu - k.u[i]) * nu + (cv - k.v[i]) * nv) / len < -kMargin;
        }
        if (in) return true;
    }
    return false;
}

}  // namespace penumbra
