/// @file math.h
/// Vector types used throughout Penumbra: GLM double-precision vectors in world space.
/// All distances are in scene units (the unit of the scene file), all angles in radians
/// unless a name ends in `Deg`.
#pragma once

#include <algorithm>
#include <cmath>

#include <glm/vec2.hpp>
#include <glm/vec3.hpp>
#include <glm/mat3x3.hpp>
#include <glm/geometric.hpp>

namespace penumbra {

using Vec2 = glm::dvec2;
using Vec3 = glm::dvec3;
using Mat3 = glm::dmat3;  ///< column-major: m[k] is column k
using Rgb = glm::dvec3;

constexpr double kPi = 3.14159265358979323846;

/// Axis-aligned box in world space; empty when lo > hi on any axis.
struct Box3 {
    Vec3 lo{1e300, 1e300, 1e300};
    Vec3 hi{-1e300, -1e300, -1e300};

    bool empty() const { return lo.x > hi.x || lo.y > hi.y || lo.z > hi.z; }
    void extend(const Vec3& p) {
        lo = glm::min(lo, p);
        hi = glm::max(hi, p);
    }
    void extend(const Box3& b) {
        lo = glm::min(lo, b.lo);
        hi = glm::max(hi, b.hi);
    }
    /// Corner c in 0..7: bit 0 picks hi.x over lo.x, bit 1 hi.y, bit 2 hi.z.
    Vec3 corner(int c) const {
        return Vec3((c & 1) ? hi.x : lo.x, (c & 2) ? hi.y : lo.y, (c & 4) ? hi.z : lo.z);
    }
    /// Parameter interval [t0, t1] of the ray o + t d inside the box, clipped to [tMin, tMax];
    /// false when the clipped interval is empty. `invD` is 1/d per axis (may be +-inf).
    bool clipRay(const Vec3& o, const Vec3& invD, double& tMin, double& tMax) const {
        for (int a = 0; a < 3; ++a) {
            double t0 = (lo[a] - o[a]) * invD[a];
            double t1 = (hi[a] - o[a]) * invD[a];
            if (t0 > t1) std::swap(t0, t1);
            // NaN (0 * inf, ray in the slab's plane) leaves the interval unchanged.
            if (t0 > tMin) tMin = t0;
            if (t1 < tMax) tMax = t1;
            if (tMin > tMax) return false;
        }
        return true;
    }
};

/// A box with its own orthonormal axes: centre +- half[k] along axis[k]. Empty when half.x < 0.
struct OrientedBox {
    Vec3 centre{0.0};
    Vec3 axis[3] = {Vec3(1.0, 0.0, 0.0), Vec3(0.0, 1.0, 0.0), Vec3(0.0, 0.0, 1.0)};
    Vec3 half{-1.0};

    bool empty() const { return half.x < 0.0; }
    /// The axis-aligned box as an oriented one.
    static OrientedBox of(const Box3& b) {
        OrientedBox o;
        if (b.empty()) return o;
        o.centre = 0.5 * (b.lo + b.hi);
        o.half = 0.5 * (b.hi - b.lo);
        return o;
    }
    /// Corner c in 0..7: bit k picks +half[k] along axis[k] (Box3::corner's order).
    Vec3 corner(int c) const {
        return centre + ((c & 1) ? half.x : -half.x) * axis[0] + ((c & 2) ? half.y : -half.y) * axis[1] +
               ((c & 4) ? half.z : -half.z) * axis[2];
    }
    /// Distance from p to the box (0 inside).
    double distanceTo(const Vec3& p) const {
        const Vec3 d = p - centre;
        Vec3 e(0.0);
        for (int k = 0; k < 3; ++k) e[k] = std::max(0.0, std::abs(d.x * axis[k].x + d.y * axis[k].y + d.z * axis[k].z) - half[k]);
        return std::sqrt(e.x * e.x + e.y * e.y + e.z * e.z);
    }
    double volume() const { return empty() ? 0.0 : 8.0 * half.x * half.y * half.z; }
};

/// Golden-section search for the minimum of `f`, unimodal on [a, z]: narrows the bracket until
/// it is under `tolerance` or after `maxSteps` steps. Returns the final bracket and its two
/// interior points with their values (the smallest value seen is min(f1, f2)).
struct GoldenSection {
    double a, z;    ///< the final bracket
    double m1, m2;  ///< its interior points, m1 < m2
    double f1, f2;  ///< f(m1), f(m2)
};
template <class F>
GoldenSection goldenSection(F&& f, double a, double z, int maxSteps, double tolerance) {
    constexpr double kInvPhi = 0.6180339887498949;
    GoldenSection g{a, z, z - kInvPhi * (z - a), a + kInvPhi * (z - a), 0.0, 0.0};
    g.f1 = f(g.m1);
    g.f2 = f(g.m2);
    for (int i = 0; i < maxSteps && g.z - g.a > tolerance; ++i) {
        if (g.f1 < g.f2) {  // the minimum is in [a, m2]
            g.z = g.m2;
            g.m2 = g.m1;
            g.f2 = g.f1;
            g.m1 = g.z - kInvPhi * (g.z - g.a);
            g.f1 = f(g.m1);
        } else {  // in [m1, z]
            g.a = g.m1;
            g.m1 = g.m2;
            g.f1 = g.f2;
            g.m2 = g.a + kInvPhi * (g.z - g.a);
            g.f2 = f(g.m2);
        }
    }
    return g;
}

/// The unit gradient of a scalar field `f` at p by central differences h apart on each axis;
/// zero where f is flat there.
template <class F>
Vec3 unitGradient(F&& f, const Vec3& p, double h) {
    Vec3 g;
    for (int k = 0; k < 3; ++k) {
        Vec3 e(0.0);
        e[k] = h;
        g[k] = f(p + e) - f(p - e);
    }
    const double len = glm::length(g);
    return len > 0.0 ? g / len : Vec3(0.0);
}

}  // namespace penumbra
