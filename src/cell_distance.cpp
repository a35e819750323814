#include "cell_distance.h"

#include "parallel_for.h"

#include <algorithm>
#include <limits>

namespace penumbra {

namespace {

size_t cellCount(const int dims[3]) { return size_t(dims[0]) * size_t(dims[1]) * size_t(dims[2]); }

/// Calls line(start, stride, n, scratch) for every line of the grid along `axis`, lines in
/// parallel (each task with its own `Scratch`).
template <class Scratch, class F>
void forEachLine(const int dims[3], int axis, F&& line) {
    const size_t stride[3] = {1, size_t(dims[0]), size_t(dims[0]) * size_t(dims[1])};
    const int a = (axis + 1) % 3, b = (axis + 2) % 3;
    detail::parallelFor(tbb::blocked_range<int>(0, dims[b]), [&](const tbb::blocked_range<int>& r) {
        Scratch scratch;
        for (int j = r.begin(); j != r.end(); ++j)
            for (int i = 0; i < dims[a]; ++i)
                line(size_t(i) * stride[a] + size_t(j) * stride[b], stride[axis], dims[axis], scratch);
    });
}

/// Grows the marked cells by one cell along every axis (a 3 x 3 x 3 box): afterwards a cell is
/// marked when some marked cell lies within one step along each axis. The Euclidean distance
/// between cell indices to the grown set is then the box-to-box distance to the original one:
/// per axis, max(0, |di| - 1) is the smallest |di - e| over |e| <= 1.
void growByOne(std::vector<uint8_t>& mark, const int dims[3]) {
    for (int axis = 0; axis < 3; ++axis) {
        forEachLine<std::vector<uint8_t>>(dims, axis, [&](size_t start, size_t stride, int n,
                                                          std::vector<uint8_t>& line) {
            line.resize(size_t(n));
            for (int k = 0; k < n; ++k) line[size_t(k)] = mark[start + size_t(k) * stride];
            for (int k = 0; k < n; ++k) {
                uint8_t m = line[size_t(k)];
                if (k > 0) m |= line[size_t(k - 1)];
                if (k + 1 < n) m |= line[size_t(k + 1)];
                mark[start + size_t(k) * stride] = m;
            }
        });
    }
}

/// The one-dimensional transform of Felzenszwalb and Huttenlocher: d[q] = min over p of
/// (f[p] + (q - p)^2), by the lower envelope of the parabolas rooted at each p.
void transformLine(const double* f, int n, double* d, int* v, double* z) {
    int k = 0;
    v[0] = 0;
    z[0] = -std::numeric_limits<double>::infinity();
    z[1] = std::numeric_limits<double>::infinity();
    for (int q = 1; q < n; ++q) {
        // Drop the parabolas the new one hides (z[0] = -inf keeps the first).
        double s;
        for (;;) {
            const int p = v[k];
            s = ((f[q] + double(q) * q) - (f[p] + double(p) * p)) / (2.0 * (q - p));
            if (!(s <= z[k])) break;
            --k;
        }
        ++k;
        v[k] = q;
        z[k] = s;
        z[k + 1] = std::numeric_limits<double>::infinity();
    }
    k = 0;
    for (int q = 0; q < n; ++q) {
        while (z[k + 1] < q) ++k;
        const double dq = double(q - v[k]);
        d[q] = dq * dq + f[v[k]];
    }
}

}  // namespace

void squaredDistanceTransform(std::vector<float>& values, const int dims[3]) {
    struct Line {
        std::vector<double> f, d, z;
        std::vector<int> v;
    };
    for (int axis = 0; axis < 3; ++axis) {
        forEachLine<Line>(dims, axis, [&](size_t start, size_t stride, int n, Line& l) {
            if (l.f.size() < size_t(n)) {
                l.f.resize(size_t(n));
                l.d.resize(size_t(n));
                l.z.resize(size_t(n) + 1);
                l.v.resize(size_t(n));
            }
            for (int k = 0; k < n; ++k) l.f[size_t(k)] = double(values[start + size_t(k) * stride]);
            transformLine(l.f.data(), n, l.d.data(), l.v.data(), l.z.data());
            for (int k = 0; k < n; ++k)
                values[start + size_t(k) * stride] = float(std::min(l.d[size_t(k)], double(kEdtFar)));
        });
    }
}

CellDistance::CellDistance(const int origin[3], const int dims[3], const std::vector<State>& states,
                           int block)
    : mOrigin{double(origin[0]), double(origin[1]), double(origin[2])},
      mDims{dims[0], dims[1], dims[2]},
      mBricks{(dims[0] + 3) / 4, (dims[1] + 3) / 4, (dims[2] + 3) / 4},
      mInvBlock(1.0 / block),
      mUnit(block / 4.0),
      mQuarters(size_t(mBricks[0]) * size_t(mBricks[1]) * size_t(mBricks[2]) * 64, 0) {
    constexpr double kMaxCells = 127.0 / 4.0;
    std::vector<uint8_t> mark;
    std::vector<float> d2;
    // The inside cells' box, two cells wider (within the table): the nearest cell that is not
    // inside lies in it, the cells just past that box's border being none of them (or the
    // table's border rule below applying), so the inside pass runs over it alone, and not at all
    // without inside cells (a thin obstacle). The same distances as over the whole table.
    int lo[3] = {dims[0], dims[1], dims[2]}, hi[3] = {-1, -1, -1};
    for (int zc = 0; zc < dims[2]; ++zc)
        for (int yc = 0; yc < dims[1]; ++yc)
            for (int xc = 0; xc < dims[0]; ++xc) {
                if (states[(size_t(zc) * size_t(dims[1]) + size_t(yc)) * size_t(dims[0]) + size_t(xc)] != kInside)
                    continue;
                const int c[3] = {xc, yc, zc};
                for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], c[a]), hi[a] = std::max(hi[a], c[a]);
            }
    // Twice: the clear cells' distance to cells that are not clear, and the inside cells' to
    // cells that are not inside.
    for (State side : {kClear, kInside}) {
        int from[3] = {0, 0, 0}, sub[3] = {dims[0], dims[1], dims[2]};
        if (side == kInside) {
            if (hi[0] < 0) break;  // no inside cell
            for (int a = 0; a < 3; ++a) {
                from[a] = std::max(0, lo[a] - 2);
                sub[a] = std::min(dims[a] - 1, hi[a] + 2) - from[a] + 1;
            }
        }
        const size_t n = cellCount(sub);
        auto at = [&](int xs, int ys, int zs) {  // sub-box cell -> table index
            return (size_t(zs + from[2]) * size_t(dims[1]) + size_t(ys + from[1])) * size_t(dims[0]) +
                   size_t(xs + from[0]);
        };
        mark.assign(n, 0);
        d2.assign(n, 0.0f);
        size_t j = 0;
        for (int zs = 0; zs < sub[2]; ++zs)
            for (int ys = 0; ys < sub[1]; ++ys)
                for (int xs = 0; xs < sub[0]; ++xs) mark[j++] = states[at(xs, ys, zs)] != side;
        growByOne(mark, sub);
        for (size_t i = 0; i < n; ++i) d2[i] = mark[i] ? 0.0f : kEdtFar;
        squaredDistanceTransform(d2, sub);
        j = 0;
        for (int zs = 0; zs < sub[2]; ++zs)
            for (int ys = 0; ys < sub[1]; ++ys)
                for (int xs = 0; xs < sub[0]; ++xs, ++j) {
                    const int xc = xs + from[0], yc = ys + from[1], zc = zs + from[2];
                    const size_t i = at(xs, ys, zs);
                    if (states[i] != side) continue;
                    double dist = std::sqrt(double(d2[j]));
                    if (side == kInside) {
                        // Beyond the table every cell counts as clear: an inside cell is no
                        // farther from one than from the table's border (box distance to the
                        // cells just past it).
                        const double border = double(std::min(
                            {xc, yc, zc, dims[0] - 1 - xc, dims[1] - 1 - yc, dims[2] - 1 - zc}));
                        dist = std::min(dist, border);
                    }
                    // Rounded down to a quarter of a cell (a hair below, for the square root's
                    // rounding).
                    const double quarters = std::floor(std::min(dist, kMaxCells) * 4.0 * (1.0 - 1e-12));
                    mQuarters[index(xc, yc, zc)] = int8_t(side == kClear ? quarters : -quarters);
                }
    }
}

CellDistance CellDistance::coarsened(const int fineOrigin[3], const int fineDims[3],
                                     const std::vector<State>& fine, int block, int margin) {
    int origin[3], dims[3];
    for (int a = 0; a < 3; ++a) {
        origin[a] = fineOrigin[a] - margin * block;
        dims[a] = (fineDims[a] + block - 1) / block + 2 * margin;
    }
    std::vector<State> states(cellCount(dims), kClear);
    std::vector<uint8_t> seen(states.size(), 0);  // bit 0: a clear cell in it, 1: inside, 2: surface
    for (int z = 0; z < fineDims[2]; ++z)
        for (int y = 0; y < fineDims[1]; ++y)
            for (int x = 0; x < fineDims[0]; ++x) {
                const State s = fine[(size_t(z) * size_t(fineDims[1]) + size_t(y)) * size_t(fineDims[0]) + size_t(x)];
                const int c[3] = {x / block + margin, y / block + margin, z / block + margin};
                const size_t i = (size_t(c[2]) * size_t(dims[1]) + size_t(c[1])) * size_t(dims[0]) + size_t(c[0]);
                seen[i] |= s == kClear ? 1 : s == kInside ? 2 : 4;
            }
    // A coarse cell partly beyond this table holds clear cells there too.
    for (int z = 0; z < dims[2]; ++z)
        for (int y = 0; y < dims[1]; ++y)
            for (int x = 0; x < dims[0]; ++x) {
                const int c[3] = {x, y, z};
                bool partly = false;
                for (int a = 0; a < 3; ++a) {
                    const int first = (c[a] - margin) * block, last = first + block;  // fine cells
                    partly = partly || first < 0 || last > fineDims[a];
                }
                const size_t i = (size_t(z) * size_t(dims[1]) + size_t(y)) * size_t(dims[0]) + size_t(x);
                if (partly) seen[i] |= 1;
                states[i] = seen[i] == 1 ? kClear : seen[i] == 2 ? kInside : kSurface;
            }
    return CellDistance(origin, dims, states, block);
}

}  // namespace penumbra
