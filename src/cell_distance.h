/// @file cell_distance.h
/// Internal: a dense table of proven distances between the cells of a level set's voxel grid
/// (occluder.cpp). Shadow rays sphere-trace it before OpenVDB's intersector, and certificates
/// read it in one lookup where a far-field companion takes eight values and its error.
///
/// Space: the level set's index space. With cells one voxel wide, cell (i, j, k) is the trilinear
/// cell whose lowest corner is voxel origin + (i, j, k): the unit cube [origin + ijk, origin +
/// ijk + 1]; a point lies in the cell floor(p - origin). A cell is *clear* when all eight corner
/// values are > 0 (the trilinear field is then positive all over it: no ray can hit anything
/// there), *inside* when all are < 0, else a *surface* cell. A coarser table has cells `block`
/// voxels wide, each clear (or inside) when all the one-voxel cells in it are.
///
/// What is stored: for a clear cell, the distance from the cell (every point of it) to the
/// nearest cell that is not clear; for an inside cell, minus the distance to the nearest cell
/// that is not inside; 0 for a surface cell. Distances are exact box-to-box distances between
/// cells, rounded down to a quarter of a cell and capped at 31.75 cells: a ball of that radius
/// around any point of the cell holds only clear (or only inside) cells. Cells beyond the table
/// count as clear; the builder makes the table large enough for that to be true.
///
/// Layout: one byte per cell, in bricks of 4 x 4 x 4 cells, each one cache line: the points a
/// march takes a few voxels apart mostly read a line already read. (With two bytes a cell in
/// rows, the first version, three quarters of the march's own time waited on that load.)
///
/// Thread safety: immutable after construction; share freely.
#pragma once

#include <cmath>
#include <cstdint>
#include <utility>
#include <vector>

namespace penumbra {

class CellDistance {
public:
    enum State : int8_t { kInside = -1, kSurface = 0, kClear = 1 };

    /// `origin`: the index-space coordinate of cell (0, 0, 0)'s lowest corner; `dims`: cells
    /// along each axis; `states`: one per cell, x fastest, then y, then z; `block`: the cells'
    /// edge in voxels.
    CellDistance(const int origin[3], const int dims[3], const std::vector<State>& states,
                 int block = 1);

    /// A table of cells `block` voxels wide over the one-voxel cells (origin, dims, states) and
    /// `margin` of its cells around them (clear, as everything beyond the one-voxel table is).
    static CellDistance coarsened(const int origin[3], const int dims[3],
                                  const std::vector<State>& states, int block, int margin);

    /// The signed distance bound (in voxels) at the index-space point p: > 0 a clear ball of that
    /// radius around p, < 0 an inside one, 0 nothing proven. False when p lies beyond the table.
    bool at(double px, double py, double pz, double& out) const {
        const double f[3] = {(px - mOrigin[0]) * mInvBlock, (py - mOrigin[1]) * mInvBlock,
                             (pz - mOrigin[2]) * mInvBlock};
        if (!(f[0] >= 0.0 && f[1] >= 0.0 && f[2] >= 0.0 && f[0] < mDims[0] && f[1] < mDims[1] &&
              f[2] < mDims[2]))
            return false;
        out = double(mQuarters[index(int(f[0]), int(f[1]), int(f[2]))]) * mUnit;
        return true;
    }

    /// The distance (in voxels) from the index-space point p to the table's box, 0 inside it.
    double distanceOutside(double px, double py, double pz) const {
        const double p[3] = {px, py, pz};
        double s = 0.0;
        for (int a = 0; a < 3; ++a) {
            const double lo = mOrigin[a], hi = mOrigin[a] + mDims[a] / mInvBlock;
            const double d = p[a] < lo ? lo - p[a] : p[a] > hi ? p[a] - hi : 0.0;
            s += d * d;
        }
        return std::sqrt(s);
    }

    /// Bytes held (the table: one per cell).
    size_t bytes() const { return mQuarters.size(); }

private:
    size_t index(int x, int y, int z) const {
        const size_t brick = (size_t(z >> 2) * size_t(mBricks[1]) + size_t(y >> 2)) *
                                 size_t(mBricks[0]) + size_t(x >> 2);
        return (brick << 6) | size_t(((z & 3) << 4) | ((y & 3) << 2) | (x & 3));
    }

    double mOrigin[3];
    int mDims[3];
    int mBricks[3];                // bricks along each axis
    double mInvBlock, mUnit;       // 1 / block; voxels per stored unit (block / 4)
    std::vector<int8_t> mQuarters;  // signed distance in quarters of a cell, bricked
};

/// A level set's cell tables: one-voxel cells a few voxels around its leaves, and cells of
/// kCoarseBlock voxels reaching as far as its far-field companion's band (LevelSet::cellTables).
struct CellTables {
    static constexpr int kCoarseBlock = 4;
    CellDistance fine, coarse;

    CellTables(CellDistance f, CellDistance c) : fine(std::move(f)), coarse(std::move(c)) {}

    /// An upper bound on the trilinear interpolant's gradient (value change per voxel, over the
    /// voxel size: 1 for an exact distance) at every point within the narrow band's half width
    /// of any point of a block of kSlopeBlock^3 voxels, per block over the fine table's box
    /// (x fastest); `slopeMax` over all of them, for points outside it. Inside a cell each
    /// partial derivative of the interpolant is a weighted mean of the cell's four differences
    /// along that axis, so the root-sum-square of the largest difference along each axis bounds
    /// the gradient's length: a proof, where a fixed 1.25 was a measurement (at a box's edges
    /// the interpolant reaches about 1.41).
    static constexpr int kSlopeBlock = 4;
    int slopeOrigin[3] = {0, 0, 0}, slopeDims[3] = {0, 0, 0};
    std::vector<float> slope;
    double slopeMax = 0.0;
    double gradientBound(double px, double py, double pz) const {
        const double p[3] = {px, py, pz};
        int b[3];
        for (int a = 0; a < 3; ++a) {
            const double f = std::floor((p[a] - slopeOrigin[a]) / kSlopeBlock);
            if (!(f >= 0.0 && f < slopeDims[a])) return slopeMax;
            b[a] = static_cast<int>(f);
        }
        return slope[(size_t(b[2]) * slopeDims[1] + b[1]) * slopeDims[0] + b[0]];
    }

    /// How far (in voxels) every cell around the index-space point p is proven clear: the
    /// coarse table when it proves kFar voxels, else the one-voxel one; beyond the one-voxel
    /// table, whose box holds every cell that is not clear, the distance to its box. <= 0 when
    /// p's cell is not clear.
    double clearVoxels(double px, double py, double pz) const {
        constexpr double kFar = 8.0;
        double c = 0.0, f;
        if (coarse.at(px, py, pz, c) && c >= kFar) return c;
        if (fine.at(px, py, pz, f)) return f > c ? f : c;
        const double out = fine.distanceOutside(px, py, pz);
        return out > c ? out : c;
    }
};

/// The squared Euclidean distance transform on a dense 3D grid (x fastest): each value becomes
/// min over cells c of (value at c + |cell - c|^2), in cells. Seeds hold 0, the rest a large
/// value (`kFar`). Separable, linear time (the lower envelope of parabolas, axis by axis).
constexpr float kEdtFar = 1e20f;
void squaredDistanceTransform(std::vector<float>& values, const int dims[3]);

}  // namespace penumbra
