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
/// cell the interpolant along a line is a cubic polynomial: this test fits it from four values
/// and finds where it first reaches zero, so that every ray the interpolated surface blocks is
/// blocked (grazing rays count as hits), and no other.
#pragma once

#include <openvdb/math/DDA.h>
#include <openvdb/math/Ray.h>
#include <openvdb/openvdb.h>

#include <algorithm>
#include <cassert>
#include <cmath>

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
        : mGrid(&grid), mAccessor(grid.getConstAccessor()) {
        if (grid.empty()) throw std::invalid_argument("CellSearch: empty grid");
        if (isoValue != 0.0f) throw std::invalid_argument("CellSearch: iso-value must be 0");
        const float voxel = static_cast<float>(grid.voxelSize()[0]);
        mNear = 2.0f * voxel;
        mDipReach = static_cast<float>(kDipReach) * voxel;
        grid.tree().root().evalActiveBoundingBox(mBox, /*visit voxels*/ false);
    }
    CellSearch(const CellSearch& o)
        : mGrid(o.mGrid), mAccessor(o.mGrid->getConstAccessor()), mNear(o.mNear),
          mDipReach(o.mDipReach), mBox(o.mBox) {}

    float getIsoValue() const { return 0.0f; }
    bool setIndexRay(const RayT& ray) {
        mRay = ray;
        return mRay.clip(mBox);
    }
    bool setWorldRay(const RayT& ray) {
        mRay = ray.worldToIndex(*mGrid);
        return mRay.clip(mBox);
    }
    void getIndexPos(VecT& xyz) const { xyz = mRay(mTime); }
    void getWorldPos(VecT& xyz) const { xyz = mGrid->indexToWorld(mRay(mTime)); }
    RealT getIndexTime() const { return mTime; }
    RealT getWorldTime() const {
        return mTime * mGrid->transform().baseMap()->applyJacobian(mRay.dir()).length();
    }

    /// How far above zero (in voxels) the smaller end value of a cell may be for the cubic
    /// test to run: along a unit index-space direction the interpolant's second derivative is at
    /// most 4 voxels per voxel squared when neighbouring values differ by at most a voxel (a
    /// distance grid), so over a cell's longest chord (sqrt 3) it lies at most 1.5 voxels below
    /// the line through its end values.
    static constexpr double kDipReach = 1.5;

private:
    template <typename, int>
    friend struct openvdb::math::LevelSetHDDA;

    void init(RealT t0) {
        mT0 = t0;
        mV0 = value(t0);
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
        // The interpolant at the ray's entry, a third and two thirds of the way, and its exit,
        // from the cell's eight values.
        double f[4];
        cellValues(ijk, entry, time, f);
        const double v1 = f[3];
        if (mV0 * v1 <= 0.0) {
            // A sign change since the last sample: the crossing between them, by linear
            // interpolation (as OpenVDB's test places it).
            const double d = mV0 - v1;
            mTime = d != 0.0 ? mT0 + (time - mT0) * (mV0 / d) : mT0;
            return true;
        }
        if (v1 > 0.0 && std::min(f[0], v1) < mDipReach && time > entry) {
            if (f[0] <= 0.0) {
                mTime = entry;
                return true;
            }
            double s;
            if (firstBelow(f, s)) {
                mTime = entry + (time - entry) * s;
                return true;
            }
        }
        mT0 = time;
        mV0 = v1;
        return false;
    }

    /// The interpolant at ray time t.
    double value(RealT t) { return sampleTrilinear(mAccessor, mRay(t)); }

    /// The interpolant of cell ijk at four points of the ray between times t0 and t1.
    void cellValues(const openvdb::Coord& ijk, RealT t0, RealT t1, double f[4]) {
        using Leaf = GridT::TreeType::LeafNodeType;
        constexpr int kLast = int(Leaf::DIM) - 1;
        float c[2][2][2];
        const Leaf* leaf = nullptr;
        if ((ijk.x() & kLast) != kLast && (ijk.y() & kLast) != kLast && (ijk.z() & kLast) != kLast)
            leaf = mAccessor.probeConstLeaf(ijk);
        if (leaf) {
            constexpr openvdb::Index dx = 1u << (2 * Leaf::LOG2DIM), dy = 1u << Leaf::LOG2DIM;
            const openvdb::Index o = Leaf::coordToOffset(ijk);
            for (int i = 0; i < 2; ++i)
                for (int j = 0; j < 2; ++j)
                    for (int k = 0; k < 2; ++k)
                        c[i][j][k] = leaf->getValue(o + i * dx + j * dy + k);
        } else {
            for (int i = 0; i < 2; ++i)
                for (int j = 0; j < 2; ++j)
                    for (int k = 0; k < 2; ++k)
                        c[i][j][k] = mAccessor.getValue(ijk.offsetBy(i, j, k));
        }
        const VecT base(ijk.x(), ijk.y(), ijk.z());
        for (int n = 0; n < 4; ++n) {
            VecT u = mRay(t0 + (t1 - t0) * (n / 3.0)) - base;
            for (int a = 0; a < 3; ++a) u[a] = std::clamp(u[a], 0.0, 1.0);
            const double x00 = c[0][0][0] + (c[1][0][0] - c[0][0][0]) * u[0];
            const double x01 = c[0][0][1] + (c[1][0][1] - c[0][0][1]) * u[0];
            const double x10 = c[0][1][0] + (c[1][1][0] - c[0][1][0]) * u[0];
            const double x11 = c[0][1][1] + (c[1][1][1] - c[0][1][1]) * u[0];
            const double y0 = x00 + (x10 - x00) * u[1], y1 = x01 + (x11 - x01) * u[1];
            f[n] = y0 + (y1 - y0) * u[2];
        }
    }

    /// Whether the cubic through f at s = 0, 1/3, 2/3, 1 (f[0] and f[3] above zero) goes to
    /// zero or below; s is then where it first does.
    static bool firstBelow(const double f[4], double& s) {
        if (f[1] <= 0.0 || f[2] <= 0.0) {
            const double sa = f[1] <= 0.0 ? 0.0 : 1.0 / 3.0;
            s = firstRoot(f, sa, sa + 1.0 / 3.0);
            return true;
        }
        // p(s) = f0 + c1 s + c2 s^2 + c3 s^3; its interior minima are roots of p'.
        const double c1 = 0.5 * (-11.0 * f[0] + 18.0 * f[1] - 9.0 * f[2] + 2.0 * f[3]);
        const double c2 = 4.5 * (2.0 * f[0] - 5.0 * f[1] + 4.0 * f[2] - f[3]);
        const double c3 = 4.5 * (-f[0] + 3.0 * f[1] - 3.0 * f[2] + f[3]);
        double roots[2];
        int n = 0;
        const double a = 3.0 * c3, b = 2.0 * c2, c = c1;
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
        std::sort(roots, roots + n);
        double prev = 0.0;
        for (int i = 0; i < n; ++i) {
            const double r = roots[i];
            if (!(r > 0.0 && r < 1.0)) continue;
            if (f[0] + r * (c1 + r * (c2 + r * c3)) <= 0.0) {
                // p falls monotonically from prev (above zero) to r: one root between.
                s = firstRoot(f, prev, r);
                return true;
            }
            prev = r;
        }
        return false;
    }

    /// The root of the cubic through f at s = 0, 1/3, 2/3, 1 in [sa, sb], where it goes from
    /// above zero (at sa) to zero or below (at sb), by bisection.
    static double firstRoot(const double f[4], double sa, double sb) {
        const double c1 = 0.5 * (-11.0 * f[0] + 18.0 * f[1] - 9.0 * f[2] + 2.0 * f[3]);
        const double c2 = 4.5 * (2.0 * f[0] - 5.0 * f[1] + 4.0 * f[2] - f[3]);
        const double c3 = 4.5 * (-f[0] + 3.0 * f[1] - 3.0 * f[2] + f[3]);
        for (int i = 0; i < 40; ++i) {
            const double m = 0.5 * (sa + sb);
            (f[0] + m * (c1 + m * (c2 + m * c3)) > 0.0 ? sa : sb) = m;
        }
        return sb;
    }

    const GridT* mGrid;
    GridT::ConstAccessor mAccessor;
    float mNear = 0.0f;      // voxels whose value is within this of zero are tested
    float mDipReach = 0.0f;  // kDipReach in world units
    openvdb::math::CoordBBox mBox;
    RayT mRay;
    RealT mTime = 0.0;  // the hit's time along the index-space ray
    RealT mT0 = 0.0;    // the last sample: time and value
    double mV0 = 0.0;
    RealT mEntry = 0.0;  // where the ray entered the voxel the next call tests
};

}  // namespace penumbra
