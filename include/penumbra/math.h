/// @file math.h
/// Vector types used throughout Penumbra: GLM double-precision vectors in world space.
/// All distances are in scene units (the unit of the scene file), all angles in radians
/// unless a name ends in `Deg`.
#pragma once

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

}  // namespace penumbra
