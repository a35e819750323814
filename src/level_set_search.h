/// @file level_set_search.h
/// Internal: the voxel test that openvdb::tools::LevelSetRayIntersector runs on the cells its
/// hierarchical DDA visits (its SearchImplT parameter), for shadow rays. Include only from
/// occluder.cpp (OpenVDB headers are slow to compile).
///
/// OpenVDB's own test (LinearSearchImpl) samples the trilinear interpolant where the ray leaves
/// each voxel near the surface and reports a hit where two samples change sign. A ray can go
/// below zero between two samples and come out again: when a box's faces lie on planes of voxel
/// centres (sizes and centres that are multiples of the voxel, as in the default scene), the
/// cells along an edge are negative inside and about zero on their sides, and a ray cutting
/// through one is sampled on its sides only. Under the default scene's box, rays at 15 degrees
/// to a face were let through in a salt-and-pepper band of the light, and the box's penumbra
/// came out too bright in the reference and in Monte Carlo (docs/BENCHMARKS.md). Inside one
/// cell the interpolant along a line is a cubic polynomial: this test takes its coefficients
/// from the cell's eight values and finds where it first reaches zero, so that every ray the
/// interpolated surface blocks is blocked (grazing rays count as hits), and no other.
#pragma once

#include <openvdb/math/DDA.h>
#include <openvdb/math/Ray.h>
#include <openvdb/openvdb.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "level_set_impl.h"

namespace penumbra {

/// The SearchImplT of openvdb::tools::LevelSetRayIntersector (same members as OpenVDB's
/// LinearSearchImpl, which the hierarchical DDA calls), for float level sets and iso-value 0.
class CellSearch {
public:
    using GridT = openvdb::FloatGrid;
    using RealT = double;
    using RayT = openvdb::math::Ray<RealT>;
    using VecT = openvdb::math::Vec3<RealT>;
    using ValueT = float;

    explicit CellSearch(const GridT& grid, float isoValue = 0.0f)
        : mGrid(&grid), mMap(grid.transform().baseMap().get()), mAccessor(grid.getConstAccessor()) {
        if (grid.empty()) throw std::invalid_argument("CellSearch: empty grid");
        if (isoValue != 0.0f) throw std::invalid_argument("CellSearch: iso-value must be 0");
        const float voxel = static_cast<float>(grid.voxelSize()[0]);
        mNear = 2.0f * voxel;
        grid.tree().root().evalActiveBoundingBox(mBox, /*visit voxels*/ false);
    }
    CellSearch(const CellSearch& o)
        : mGrid(o.mGrid),
          mMap(o.mMap),
          mAccessor(o.mGrid->getConstAccessor()),
          mNear(o.mNear),
          mBox(o.mBox) {}

    float getIsoValue() const { return 0.0f; }
    bool setIndexRay(const RayT& ray) {
        mRay = ray;
        return mRay.clip(mBox);
    }
    bool setWorldRay(const RayT& ray) {
        mRay = ray.applyInverseMap(*mMap);
        return mRay.clip(mBox);
    }
    void getIndexPos(VecT& xyz) const { xyz = mRay(mTime); }
    void getWorldPos(VecT& xyz) const { xyz = mGrid->indexToWorld(mRay(mTime)); }
    RealT getIndexTime() const { return mTime; }
    RealT getWorldTime() const {
        return mTime * mMap->applyJacobian(mRay.dir()).length();
    }

private:
    template <typename, int>
    friend struct openvdb::math::LevelSetHDDA;

    void init(RealT t0) {
        mT0 = t0;
        // Sampled when a cell near the surface first needs it, which a leaf the ray only
        // skirts never does (the same value, read later or not at all: bench_occluder's bunny,
        // plain rays about 7% faster).
        mV0 = std::numeric_limits<double>::quiet_NaN();
        mEntry = t0;
    }
    void setRange(RealT t0, RealT t1) { mRay.setTimes(t0, t1); }
    const RayT& ray() const { return mRay; }
    template <typename NodeT>
    bool hasNode(const openvdb::Coord& ijk) {
        return mAccessor.template probeConstNode<NodeT>(ijk) != nullptr;
    }

    /// The voxel ijk, which the ray leaves at `time` (it entered where the previous call left
    /// off, or at init()'s time): true on a hit, mTime then its time.
    bool operator()(const openvdb::Coord& ijk, RealT time) {
        const RealT entry = mEntry;
        mEntry = time;
        float v;
        if (!mAccessor.probeValue(ijk, v) || !(v > -mNear && v < mNear)) return false;
        const Cell cell = this->cell(ijk);
        const VecT base(ijk.x(), ijk.y(), ijk.z());
        const VecT u1 = local(mRay(time), base);
        const double v1 = cell.at(u1);
        if (std::isnan(mV0)) mV0 = value(mT0);
        if (mV0 * v1 <= 0.0) {
            // A sign change since the last sample: the crossing between them, by linear
            // interpolation (as OpenVDB's test places it).
            const double d = mV0 - v1;
            mTime = d != 0.0 ? mT0 + (time - mT0) * (mV0 / d) : mT0;
            return true;
        }
        if (v1 > 0.0 && time > entry) {
            // Both ends outside: does the cubic between them reach zero?
            const VecT u0 = local(mRay(entry), base);
            double p[4];
            cell.along(u0, u1 - u0, p);
            if (p[0] <= 0.0) {
                mTime = entry;
                return true;
            }
            double s;
            if (firstZero(p, v1, s)) {
                mTime = entry + (time - entry) * s;
                return true;
            }
        }
        mT0 = time;
        mV0 = v1;
        return false;
    }

    /// A cell's trilinear interpolant, f = a + bx x + by y + bz z + cxy xy + cxz xz + cyz yz
    /// + cxyz xyz on the unit cube.
    struct Cell {
        double a, bx, by, bz, cxy, cxz, cyz, cxyz;
        double at(const VecT& u) const {
            return a + bx * u[0] + by * u[1] + bz * u[2] + cxy * u[0] * u[1] + cxz * u[0] * u[2] +
                   cyz * u[1] * u[2] + cxyz * u[0] * u[1] * u[2];
        }
        /// The cubic p[0] + p[1] s + p[2] s^2 + p[3] s^3 = f(u0 + s d).
        void along(const VecT& u0, const VecT& d, double p[4]) const {
            const double x = u0[0], y = u0[1], z = u0[2], dx = d[0], dy = d[1], dz = d[2];
            p[0] = at(u0);
            p[1] = bx * dx + by * dy + bz * dz + cxy * (x * dy + y * dx) + cxz * (x * dz + z * dx) +
                   cyz * (y * dz + z * dy) + cxyz * (dx * y * z + x * dy * z + x * y * dz);
            p[2] = cxy * dx * dy + cxz * dx * dz + cyz * dy * dz +
                   cxyz * (dx * dy * z + dx * y * dz + x * dy * dz);
            p[3] = cxyz * dx * dy * dz;
        }
    };

    /// The interpolant of voxel ijk's cell (its corners ijk to ijk + (1, 1, 1)).
    Cell cell(const openvdb::Coord& ijk) {
        float values[2][2][2];
        if (!leafCellValues(mAccessor, ijk, values)) {
            for (int i = 0; i < 2; ++i)
                for (int j = 0; j < 2; ++j)
                    for (int k = 0; k < 2; ++k) values[i][j][k] = mAccessor.getValue(ijk.offsetBy(i, j, k));
        }
        double c[2][2][2];
        for (int i = 0; i < 2; ++i)
            for (int j = 0; j < 2; ++j)
                for (int k = 0; k < 2; ++k) c[i][j][k] = values[i][j][k];
        Cell f;
        f.a = c[0][0][0];
        f.bx = c[1][0][0] - c[0][0][0];
        f.by = c[0][1][0] - c[0][0][0];
        f.bz = c[0][0][1] - c[0][0][0];
        f.cxy = c[1][1][0] - c[1][0][0] - c[0][1][0] + c[0][0][0];
        f.cxz = c[1][0][1] - c[1][0][0] - c[0][0][1] + c[0][0][0];
        f.cyz = c[0][1][1] - c[0][1][0] - c[0][0][1] + c[0][0][0];
        f.cxyz = c[1][1][1] - c[1][1][0] - c[1][0][1] - c[0][1][1] + c[1][0][0] + c[0][1][0] +
                 c[0][0][1] - c[0][0][0];
        return f;
    }

    /// A point's coordinates in the cell at `base`, clamped to it (the ends of the ray's stretch
    /// in the cell lie on its sides up to rounding).
    static VecT local(const VecT& x, const VecT& base) {
        VecT u = x - base;
        for (int a = 0; a < 3; ++a) u[a] = std::clamp(u[a], 0.0, 1.0);
        return u;
    }

    /// Whether the cubic p on [0, 1] (p(0) > 0, p(1) = v1 > 0 up to rounding) reaches zero
    /// inside; s is then where it first does.
    static bool firstZero(const double p[4], double v1, double& s) {
        // p lies above its chord less s (1 - s) (p2 + p3 (1 + s)), at most (|p2| + 2 |p3|) / 4
        // below it: nothing to look for when both ends are higher (almost every cell).
        if (std::min(p[0], v1) > 0.25 * (std::abs(p[2]) + 2.0 * std::abs(p[3]))) return false;
        // Its interior minima: roots of p'(s) = p1 + 2 p2 s + 3 p3 s^2.
        double roots[2];
        int n = 0;
        const double a = 3.0 * p[3], b = 2.0 * p[2], c = p[1];
        if (std::abs(a) <= 1e-12 * (std::abs(b) + std::abs(c))) {
            if (b != 0.0) roots[n++] = -c / b;
        } else {
            const double disc = b * b - 4.0 * a * c;
            if (disc >= 0.0) {
                const double q = -0.5 * (b + std::copysign(std::sqrt(disc), b));
                if (q != 0.0) roots[n++] = c / q;
                roots[n++] = q / a;
            }
        }
        if (n == 2 && roots[1] < roots[0]) std::swap(roots[0], roots[1]);
        double prev = 0.0;
        for (int i = 0; i < n; ++i) {
            const double r = roots[i];
            if (!(r > 0.0 && r < 1.0)) continue;
            if (cubic(p, r) <= 0.0) {
                // p falls monotonically from prev (above zero) to r: its root between, by
                // bisection.
                double lo = prev, hi = r;
                for (int k = 0; k < 40; ++k) {
                    const double m = 0.5 * (lo + hi);
                    (cubic(p, m) > 0.0 ? lo : hi) = m;
                }
                s = hi;
                return true;
            }
            prev = r;
        }
        return false;
    }

    static double cubic(const double p[4], double s) {
        return p[0] + s * (p[1] + s * (p[2] + s * p[3]));
    }

    /// The interpolant at ray time t.
    double value(RealT t) { return sampleTrilinear(mAccessor, mRay(t)); }

    const GridT* mGrid;
    // The grid's index-to-world map, held by the grid. Ray::worldToIndex(grid) would fetch it
    // as a shared pointer for every ray: an atomic count that the threads' rays contend on.
    const openvdb::math::MapBase* mMap;
    GridT::ConstAccessor mAccessor;
    float mNear = 0.0f;      // voxels whose value is within this of zero are tested
    openvdb::math::CoordBBox mBox;
    RayT mRay;
    RealT mTime = 0.0;  // the hit's time along the index-space ray
    RealT mT0 = 0.0;    // the last sample: time and value
    double mV0 = 0.0;
    RealT mEntry = 0.0;  // where the ray entered the voxel the next call tests
};

}  // namespace penumbra
