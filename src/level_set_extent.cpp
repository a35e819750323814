// Where a level set can block a ray, bounded tightly from the grid's own values: the box and
// sphere that hold every point where the trilinear interpolant is <= 0 (what the tracer can
// hit), and balls wholly inside it (what every segment through them hits). Both from the cells
// that matter: the interpolant restricted to a sub-box of a cell is trilinear again, so its
// extremes over the sub-box are among the sub-box's eight corner values, and its slope along
// each axis is at most the largest of the four differences along that axis.
#include <openvdb/openvdb.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>
#include <vector>

#include "level_set_impl.h"

namespace penumbra {

namespace {

using openvdb::Coord;
using openvdb::Vec3d;

// Finest sub-box: a 32nd of a voxel along each axis.
constexpr int kSubdivisions = 5;
// How far (voxels) a sub-box's bound may pass the box's faces, and the radius, before it is
// refined: tightenSolid()'s margins cover them. The radius's is coarser: on a round shape every
// surface cell reaches within a hundredth of a voxel of the farthest, and at a thousandth almost
// all of them were halved to the finest sub-boxes (the default scene's sphere, 50 voxels in
// radius, took 0.37 s to build, 0.08 s at a fiftieth; one of 200 voxels 1.9 s, 1.1 s).
constexpr double kBoxSlack = 1e-3;
constexpr double kRadiusSlack = 0.02;

// A sub-box of a trilinear cell (index space) with its corner values v[(k * 2 + j) * 2 + i] at
// offsets (i, j, k) from lo.
struct SubBox {
    Vec3d lo, hi;
    double v[8];
    double minValue() const { return *std::min_element(v, v + 8); }
    double maxValue() const { return *std::max_element(v, v + 8); }
};

// The eight halves of b; midpoint values are averages (exact for a multilinear function).
void split(const SubBox& b, SubBox out[8]) {
    double g[3][3][3];  // [k][j][i]
    for (int k = 0; k < 2; ++k)
        for (int j = 0; j < 2; ++j)
            for (int i = 0; i < 2; ++i) g[2 * k][2 * j][2 * i] = b.v[(k * 2 + j) * 2 + i];
    for (int k = 0; k < 3; k += 2)
        for (int j = 0; j < 3; j += 2) g[k][j][1] = 0.5 * (g[k][j][0] + g[k][j][2]);
    for (int k = 0; k < 3; k += 2)
        for (int i = 0; i < 3; ++i) g[k][1][i] = 0.5 * (g[k][0][i] + g[k][2][i]);
    for (int j = 0; j < 3; ++j)
        for (int i = 0; i < 3; ++i) g[1][j][i] = 0.5 * (g[0][j][i] + g[2][j][i]);
    const Vec3d mid = 0.5 * (b.lo + b.hi);
    for (int c = 0; c < 8; ++c) {
        const int ci = c & 1, cj = (c >> 1) & 1, ck = c >> 2;
        SubBox& o = out[c];
        o.lo = Vec3d(ci ? mid.x() : b.lo.x(), cj ? mid.y() : b.lo.y(), ck ? mid.z() : b.lo.z());
        o.hi = Vec3d(ci ? b.hi.x() : mid.x(), cj ? b.hi.y() : mid.y(), ck ? b.hi.z() : mid.z());
        for (int k = 0; k < 2; ++k)
            for (int j = 0; j < 2; ++j)
                for (int i = 0; i < 2; ++i) o.v[(k * 2 + j) * 2 + i] = g[ck + k][cj + j][ci + i];
    }
}

template <class Accessor>
SubBox cellAt(Accessor& acc, const Coord& m) {
    SubBox b;
    b.lo = m.asVec3d();
    b.hi = b.lo + Vec3d(1.0);
    float data[2][2][2];  // [i][j][k]
    if (leafCellValues(acc, m, data)) {
        for (int k = 0; k < 2; ++k)
            for (int j = 0; j < 2; ++j)
                for (int i = 0; i < 2; ++i) b.v[(k * 2 + j) * 2 + i] = double(data[i][j][k]);
        return b;
    }
    for (int k = 0; k < 2; ++k)
        for (int j = 0; j < 2; ++j)
            for (int i = 0; i < 2; ++i) b.v[(k * 2 + j) * 2 + i] = double(acc.getValue(m.offsetBy(i, j, k)));
    return b;
}

// Squared distance from p to the farthest point of box [lo, hi], and to its nearest point.
double farthest2(const Vec3d& p, const Vec3d& lo, const Vec3d& hi) {
    double s = 0.0;
    for (int d = 0; d < 3; ++d) {
        const double e = std::max(std::abs(p[d] - lo[d]), std::abs(p[d] - hi[d]));
        s += e * e;
    }
    return s;
}
double nearest2(const Vec3d& p, const Vec3d& lo, const Vec3d& hi) {
    double s = 0.0;
    for (int d = 0; d < 3; ++d) {
        const double e = std::max({0.0, lo[d] - p[d], p[d] - hi[d]});
        s += e * e;
    }
    return s;
}

// The largest value of the interpolant's partial derivative along each axis over sub-box b,
// per index unit: each partial derivative is a bilinear mean of the four differences along
// its axis.
void slopes(const SubBox& b, double g[3]) {
    for (int d = 0; d < 3; ++d) {
        const int step = 1 << d;
        double m = 0.0;
        for (int k = 0; k < 8; ++k)
            if (!(k & step)) m = std::max(m, std::abs(b.v[k + step] - b.v[k]));
        const double len = b.hi[d] - b.lo[d];
        g[d] = len > 0.0 ? m / len : 0.0;
    }
}

double valueAt(const SubBox& b, const Vec3d& p) {
    double u[3];
    for (int d = 0; d < 3; ++d) {
        const double len = b.hi[d] - b.lo[d];
        u[d] = len > 0.0 ? std::clamp((p[d] - b.lo[d]) / len, 0.0, 1.0) : 0.0;
    }
    double f = 0.0;
    for (int k = 0; k < 8; ++k)
        f += b.v[k] * ((k & 1) ? u[0] : 1.0 - u[0]) * ((k & 2) ? u[1] : 1.0 - u[1]) * ((k & 4) ? u[2] : 1.0 - u[2]);
    return f;
}

// An upper bound on the squared distance from c to the points of b where the interpolant is
// <= tol. From b's corner z farthest from c, such a point p = z -+ u (u_d in [0, len_d]
// towards the other side) has |p_d - c_d| = |b_d - u_d|, b_d = |z_d - c_d|, and the interpolant
// falls from its value at z by at most sum g_d u_d: the largest of sum (b_d - u_d)^2 over that
// polytope (a convex function, largest at a vertex).
double regionFar2(const Vec3d& c, const SubBox& b, double tol) {
    double bz[3], len[3], g[3];
    int corner = 0;
    for (int d = 0; d < 3; ++d) {
        const bool high = std::abs(b.hi[d] - c[d]) >= std::abs(b.lo[d] - c[d]);
        if (high) corner |= 1 << d;
        bz[d] = std::abs((high ? b.hi[d] : b.lo[d]) - c[d]);
        len[d] = b.hi[d] - b.lo[d];
    }
    const double drop = b.v[corner] - tol;
    auto objective = [&](const double u[3]) {
        double s = 0.0;
        for (int d = 0; d < 3; ++d) s += (bz[d] - u[d]) * (bz[d] - u[d]);
        return s;
    };
    const double zero[3] = {0.0, 0.0, 0.0};
    if (drop <= 0.0) return objective(zero);
    slopes(b, g);
    double best = -1.0;
    for (int k = 0; k < 8; ++k) {  // the box's own vertices inside the half-space
        double u[3], reach = 0.0;
        for (int d = 0; d < 3; ++d) {
            u[d] = (k >> d) & 1 ? len[d] : 0.0;
            reach += g[d] * u[d];
        }
        if (reach >= drop) best = std::max(best, objective(u));
    }
    for (int e = 0; e < 3; ++e) {  // where the plane crosses the box's edges along axis e
        if (!(g[e] > 0.0)) continue;
        for (int k = 0; k < 4; ++k) {
            double u[3], reach = 0.0;
            int bit = 0;
            for (int d = 0; d < 3; ++d) {
                if (d == e) continue;
                u[d] = (k >> bit++) & 1 ? len[d] : 0.0;
                reach += g[d] * u[d];
            }
            u[e] = (drop - reach) / g[e];
            if (u[e] >= 0.0 && u[e] <= len[e]) best = std::max(best, objective(u));
        }
    }
    return best;  // negative: no such point
}

// A lower bound on the squared distance from c to the points of b where the interpolant is
// >= -tol, and the box's point q nearest c. A point p of the box is q + t (t_d >= 0 away from c
// along each axis where c lies outside the box's range, either way where it lies inside), with
// |p - c|^2 = sum (a_d + |t_d|)^2, a_d = |q_d - c_d|; the interpolant climbs from its value at q
// by at most sum g_d |t_d|. The smallest of the sum under that climb (box limits dropped, which
// only lowers it): |t_d| = max(0, mu g_d - a_d) for the mu that climbs exactly enough.
double regionNear2(const Vec3d& c, const SubBox& b, double tol, Vec3d& q) {
    double a[3], n2 = 0.0;
    for (int d = 0; d < 3; ++d) {
        q[d] = std::clamp(c[d], b.lo[d], b.hi[d]);
        a[d] = std::abs(q[d] - c[d]);
        n2 += a[d] * a[d];
    }
    const double climb = -tol - valueAt(b, q);
    if (!(climb > 0.0)) return n2;
    double g[3];
    slopes(b, g);
    // Axes by breakpoint a_d / g_d (where mu starts moving along them).
    int order[3] = {0, 1, 2};
    double brk[3];
    for (int d = 0; d < 3; ++d) brk[d] = g[d] > 0.0 ? a[d] / g[d] : std::numeric_limits<double>::infinity();
    std::sort(order, order + 3, [&](int x, int y) { return brk[x] < brk[y]; });
    double sg2 = 0.0, sga = 0.0, mu = std::numeric_limits<double>::infinity();
    for (int k = 0; k < 3; ++k) {
        const int d = order[k];
        if (!std::isfinite(brk[d])) break;
        sg2 += g[d] * g[d];
        sga += g[d] * a[d];
        const double m = (climb + sga) / sg2;
        const double next = k + 1 < 3 ? brk[order[k + 1]] : std::numeric_limits<double>::infinity();
        if (m <= next) {
            mu = m;
            break;
        }
    }
    if (!std::isfinite(mu)) return std::numeric_limits<double>::infinity();  // cannot climb
    double s = 0.0;
    for (int d = 0; d < 3; ++d) {
        const double t = std::max(0.0, mu * g[d] - a[d]);
        s += (a[d] + t) * (a[d] + t);
    }
    return s;
}

// The extent of {interpolant <= tol} (index space): a box and the radius around a fixed centre.
struct Extent {
    Vec3d lo{std::numeric_limits<double>::infinity()}, hi{-std::numeric_limits<double>::infinity()};
    Vec3d centre{0.0};
    double radius2 = 0.0;
    double tol = 0.0;
    bool boxToo = true, round = true;  // what refine() grows
    bool extendsBox(const Vec3d& a, const Vec3d& b) const {
        for (int d = 0; d < 3; ++d)
            if (a[d] < lo[d] || b[d] > hi[d]) return true;
        return false;
    }
    void take(const Vec3d& a, const Vec3d& b) {
        lo = openvdb::math::minComponent(lo, a);
        hi = openvdb::math::maxComponent(hi, b);
        radius2 = std::max(radius2, farthest2(centre, a, b));
    }
    // Takes what of sub-box b may lie in the set, when it would grow the box or the radius by
    // more than a thousandth of a voxel: as bounded by its values once it lies in the set
    // entirely or is as fine as kSubdivisions, else its halves'. Along each axis the set stays
    // short of the sub-box's face by what the interpolant, no lower on that face than its
    // smallest corner there, must fall at its largest slope along the axis to reach tol (exact
    // for a plane: a flat face's cells take no halving).
    void refine(const SubBox& b, int depth) {
        if (b.minValue() > tol) return;
        double g[3];
        slopes(b, g);
        Vec3d setLo = b.lo, setHi = b.hi;
        for (int d = 0; d < 3; ++d) {
            if (!(g[d] > 0.0)) continue;
            double faceLo = std::numeric_limits<double>::infinity(), faceHi = faceLo;
            for (int k = 0; k < 8; ++k) ((k >> d) & 1 ? faceHi : faceLo) = std::min((k >> d) & 1 ? faceHi : faceLo, b.v[k]);
            setHi[d] = std::max(b.lo[d], b.hi[d] - std::max(0.0, (faceHi - tol) / g[d]));
            setLo[d] = std::min(setHi[d], b.lo[d] + std::max(0.0, (faceLo - tol) / g[d]));
        }
        bool box = false;
        for (int d = 0; d < 3 && boxToo; ++d)
            box = box || setLo[d] < lo[d] - kBoxSlack || setHi[d] > hi[d] + kBoxSlack;
        const double reach = std::sqrt(radius2) + kRadiusSlack;
        const double far2 = round && farthest2(centre, b.lo, b.hi) > reach * reach ? regionFar2(centre, b, tol) : -1.0;
        const bool wider = far2 > reach * reach;
        if (!box && !wider) return;
        if (depth == 0 || b.maxValue() <= tol) {
            if (box) {
                lo = openvdb::math::minComponent(lo, setLo);
                hi = openvdb::math::maxComponent(hi, setHi);
            }
            if (wider) radius2 = far2;
            return;
        }
        SubBox halves[8];
        split(b, halves);
        for (const SubBox& h : halves) refine(h, depth - 1);
    }
};

}  // namespace

// Called by findSolid() with the centre it chose (index space): the box and radius of every
// point where the interpolant is <= 0, from the cells around the grid's values <= 0 (voxels of
// its leaves, active or not, and tiles: a point where the interpolant is <= 0 lies in a cell
// with such a corner). Values are world distances; a hundredth of a voxel covers float rounding.
void LevelSet::tightenSolid(const Vec3d& centreIS, Vec3d& loIS, Vec3d& hiIS, double& radiusIS) const {
    Extent e;
    e.centre = centreIS;
    e.tol = 1e-4 * mVoxelSize;
    // The values' own points first (they are in the set): most cells then fall inside at once.
    std::vector<openvdb::CoordBBox> tiles;
    for (auto it = mGrid->cbeginValueAll(); it; ++it) {
        if (!(double(*it) <= e.tol)) continue;
        if (it.isVoxelValue()) {
            const Vec3d p = it.getCoord().asVec3d();
            e.take(p, p);
        } else {
            openvdb::CoordBBox box;
            it.getBoundingBox(box);
            tiles.push_back(box);
            e.take(box.min().asVec3d(), box.max().asVec3d());
        }
    }
    if (!(e.lo.x() <= e.hi.x())) return;  // nothing inside: keep what the caller has
    auto acc = mGrid->getConstAccessor();
    // The sphere, in two sweeps over the values <= 0 (storing none of them: a large grid has
    // millions): the first keeps the few voxels whose own distance from the surface carries
    // farthest (|p - c| + |value|, a guess, not a bound); their cells, refined first, bring the
    // radius near its end, and the second sweep then passes over most cells whole. The first
    // sweep also grows the box, over the cells that could push one of its faces out. (The
    // first sweep bounded every cell near the surface instead until 2026-12-06: on a sphere 200
    // voxels in radius, a third of the level set's build.)
    auto forFarCells = [&](bool boxToo, auto&& visitVoxel, auto&& visitCell) {
        for (auto it = mGrid->cbeginValueAll(); it; ++it) {
            if (!(double(*it) <= e.tol) || !it.isVoxelValue()) continue;
            const Coord y = it.getCoord();
            const Vec3d p = y.asVec3d();
            const bool box = boxToo && e.extendsBox(p - Vec3d(1.0), p + Vec3d(1.0));
            if (!box && !(farthest2(e.centre, p - Vec3d(1.0), p + Vec3d(1.0)) > e.radius2)) continue;
            visitVoxel(y, double(*it));
            for (int c = 0; c < 8; ++c) {
                const Coord m = y.offsetBy(-(c & 1), -((c >> 1) & 1), -(c >> 2));
                const Vec3d a = m.asVec3d(), b = a + Vec3d(1.0);
                if (box && e.extendsBox(a, b)) e.refine(cellAt(acc, m), kSubdivisions);
                if (farthest2(e.centre, a, b) > e.radius2) visitCell(m);
            }
        }
    };
    e.round = false;
    constexpr size_t kFirst = 16;
    std::vector<std::pair<double, Coord>> first;  // a min-heap on the guess: the kFirst largest
    auto smaller = [](const auto& x, const auto& y) { return x.first > y.first; };
    forFarCells(
        true,
        [&](const Coord& y, double value) {
            const double guess = (y.asVec3d() - e.centre).length() - value / mVoxelSize;
            if (first.size() == kFirst && !(guess > first.front().first)) return;
            if (first.size() == kFirst) {
                std::pop_heap(first.begin(), first.end(), smaller);
                first.pop_back();
            }
            first.emplace_back(guess, y);
            std::push_heap(first.begin(), first.end(), smaller);
        },
        [](const Coord&) {});
    e.round = true;
    e.boxToo = false;
    std::sort(first.begin(), first.end(), smaller);
    for (const auto& f : first)
        for (int c = 0; c < 8; ++c)
            e.refine(cellAt(acc, f.second.offsetBy(-(c & 1), -((c >> 1) & 1), -(c >> 2))), kSubdivisions);
    forFarCells(false, [](const Coord&, double) {}, [&](const Coord& m) { e.refine(cellAt(acc, m), kSubdivisions); });
    // A tile's cells reach a voxel past it; taken whole (a level set's tiles lie deep inside).
    for (const openvdb::CoordBBox& t : tiles) e.take(t.min().asVec3d() - Vec3d(1.0), t.max().asVec3d() + Vec3d(1.0));
    const double margin = 0.01;
    loIS = e.lo - Vec3d(margin + kBoxSlack);
    hiIS = e.hi + Vec3d(margin + kBoxSlack);
    radiusIS = std::sqrt(e.radius2) + margin + kRadiusSlack;
}

namespace {

// A cell with corners on both sides of -tol: its lowest corner and its eight values.
struct MixedCell {
    Coord m;
    float v[8];  // v[(k * 2 + j) * 2 + i] at m + (i, j, k)
};

// Distance (index space) from a point where the interpolant is below -tol to the set where it
// is >= -tol: the nearest such point lies in a cell with corners on both sides (the segment
// from the point reaches it through cells with a corner below), or in a tile's cells, or past
// the tree's root blocks (implicit background, positive).
struct InsideSearch {
    double tol = 0.0;
    std::vector<MixedCell> cells;
    std::vector<openvdb::CoordBBox> outerTiles;    // tiles >= -tol: their cells, a voxel around
    std::vector<openvdb::CoordBBox> missingRoots;  // root blocks near the ball with no entry

    // A lower bound on the distance from c to the set, with `at` the point of the cell that set it.
    double distance(const Vec3d& c, Vec3d& at) const {
        double best2 = std::numeric_limits<double>::infinity();
        auto cap = [&](const Vec3d& lo, const Vec3d& hi) {
            const double d2 = nearest2(c, lo, hi);
            if (d2 < best2) {
                best2 = d2;
                for (int d = 0; d < 3; ++d) at[d] = std::clamp(c[d], lo[d], hi[d]);
            }
        };
        for (const openvdb::CoordBBox& t : outerTiles)
            cap(t.min().asVec3d() - Vec3d(1.0), t.max().asVec3d() + Vec3d(1.0));
        for (const openvdb::CoordBBox& t : missingRoots)
            cap(t.min().asVec3d() - Vec3d(1.0), t.max().asVec3d() + Vec3d(1.0));
        SubBox b;
        Vec3d q;
        for (const MixedCell& cell : cells) {
            b.lo = cell.m.asVec3d();
            b.hi = b.lo + Vec3d(1.0);
            if (nearest2(c, b.lo, b.hi) >= best2) continue;
            for (int k = 0; k < 8; ++k) b.v[k] = double(cell.v[k]);
            const double l2 = regionNear2(c, b, tol, q);
            if (l2 < best2) {
                best2 = l2;
                at = q;
            }
        }
        return std::sqrt(best2);
    }

    // The distance from c to the nearest mixed cell's centre (about the distance to the set,
    // cheap), with `at` that centre: for finding where a ball can be largest.
    double roughDistance(const Vec3d& c, Vec3d& at) const {
        double best2 = std::numeric_limits<double>::infinity();
        // A sample of at most about 50,000 of them: a direction to climb, not a bound.
        const size_t stride = std::max<size_t>(1, cells.size() / 50000);
        for (size_t i = 0; i < cells.size(); i += stride) {
            const MixedCell& cell = cells[i];
            const Vec3d p = cell.m.asVec3d() + Vec3d(0.5);
            const double d2 = (p - c).lengthSqr();
            if (d2 < best2) {
                best2 = d2;
                at = p;
            }
        }
        return std::sqrt(best2);
    }
};

// More mixed cells than this (44 bytes each, 92 MB) and the balls are left as the companion
// made them.
constexpr size_t kMaxMixedCells = size_t(1) << 21;

}  // namespace

std::vector<LevelSet::InsideBall> LevelSet::widenInsideBalls(const std::vector<InsideBall>& balls) const {
    if (balls.empty() || !(mVoxelSize > 0.0)) return balls;
    InsideSearch s;
    s.tol = 1e-4 * mVoxelSize;
    auto acc = mGrid->getConstAccessor();
    // Tiles >= -tol bound the distance as a whole (their cells, a voxel around them).
    for (auto it = mGrid->cbeginValueAll(); it; ++it) {
        if (it.isVoxelValue() || !(double(*it) >= -s.tol)) continue;
        openvdb::CoordBBox box;
        it.getBoundingBox(box);
        s.outerTiles.push_back(box);
    }
    auto mixed = [&](const Coord& m, const float v[8]) {
        float lo = v[0], hi = v[0];
        for (int k = 1; k < 8; ++k) lo = std::min(lo, v[k]), hi = std::max(hi, v[k]);
        if (!(double(lo) < -s.tol && double(hi) >= -s.tol)) return;
        MixedCell c;
        c.m = m;
        std::copy(v, v + 8, c.v);
        s.cells.push_back(c);
    };
    // Mixed cells have a corner >= -tol: in a leaf, or in a tile >= -tol (bounded above). So
    // every leaf with the voxels one past it on each side: the cells whose lowest corner lies in
    // it, and those whose lowest corner lies just below it outside every leaf (in a tile: a
    // cell reaching from an inside tile into this leaf).
    using Leaf = openvdb::FloatTree::LeafNodeType;
    constexpr int D = int(Leaf::DIM), W = D + 2;
    float block[W][W][W];  // voxel o + (x - 1, y - 1, z - 1)
    for (auto leaf = mGrid->tree().cbeginLeaf(); leaf && s.cells.size() <= kMaxMixedCells; ++leaf) {
        const Coord o = leaf->origin();
        for (int x = 0; x < W; ++x)
            for (int y = 0; y < W; ++y)
                for (int z = 0; z < W; ++z) {
                    const bool in = x >= 1 && y >= 1 && z >= 1 && x <= D && y <= D && z <= D;
                    const Coord c = o.offsetBy(x - 1, y - 1, z - 1);
                    block[x][y][z] = in ? leaf->getValue(Leaf::coordToOffset(c)) : acc.getValue(c);
                }
        float v[8];
        for (int x = 0; x <= D; ++x)
            for (int y = 0; y <= D; ++y)
                for (int z = 0; z <= D; ++z) {
                    const Coord m = o.offsetBy(x - 1, y - 1, z - 1);
                    if ((x == 0 || y == 0 || z == 0) && acc.probeConstLeaf(m)) continue;  // that leaf's
                    for (int k = 0; k < 8; ++k) v[k] = block[x + (k & 1)][y + ((k >> 1) & 1)][z + (k >> 2)];
                    mixed(m, v);
                }
    }
    if (s.cells.size() > kMaxMixedCells) return balls;

    std::vector<InsideBall> out;
    for (const InsideBall& ball : balls) {
        const Vec3d c0 = mGrid->worldToIndex(openvdb::Vec3d(ball.centre.x, ball.centre.y, ball.centre.z));
        auto inside = [&](const Vec3d& c) {
            return double(openvdb::tools::BoxSampler::sample(acc, c)) < -s.tol;
        };
        if (!inside(c0)) continue;
        // Climb away from the nearest mixed cell while the distance to them grows (the
        // companion's voxel lies up to two fine voxels from the deepest point), then measure.
        constexpr double kClimb = 8.0;  // voxels
        Vec3d at(0.0), c = c0;
        double rough = s.roughDistance(c, at);
        double step = 1.0;
        for (int it = 0; it < 20 && step > 0.05; ++it) {
            const Vec3d away = c - at;
            const double len = away.length();
            if (!(len > 0.0)) break;
            const Vec3d next = c + away * (step / len);
            if ((next - c0).length() > kClimb) break;
            Vec3d nextAt(0.0);
            const double nr = inside(next) ? s.roughDistance(next, nextAt) : 0.0;
            if (nr > rough) {
                c = next;
                rough = nr;
                at = nextAt;
                step *= 1.5;
            } else {
                step *= 0.5;
            }
        }
        if (!inside(c)) continue;
        // Root blocks (implicit background, positive) that the ball, grown well past the
        // companion's radius and the climb, overlaps must be held by the tree.
        s.missingRoots.clear();
        const int dim = int(openvdb::FloatTree::RootNodeType::ChildNodeType::DIM);
        const double reachIS = ball.radius / mVoxelSize + 2.0 * kClimb + 16.0;
        auto blockOf = [&](double x) { return int(std::floor(x / dim)) * dim; };
        for (int z = blockOf(c.z() - reachIS); z <= blockOf(c.z() + reachIS); z += dim)
            for (int y = blockOf(c.y() - reachIS); y <= blockOf(c.y() + reachIS); y += dim)
                for (int x = blockOf(c.x() - reachIS); x <= blockOf(c.x() + reachIS); x += dim)
                    if (mGrid->tree().getValueDepth(Coord(x, y, z)) < 0)
                        s.missingRoots.push_back(openvdb::CoordBBox(
                            Coord(x, y, z), Coord(x + dim - 1, y + dim - 1, z + dim - 1)));
        const double r = std::min(s.distance(c, at), reachIS);
        const double margin = 0.01;
        if (!(r - margin > 0.0)) continue;
        const Vec3d w = mGrid->indexToWorld(c);
        // Balls that climbed to the same deepest point: keep one.
        bool again = false;
        for (const InsideBall& o : out)
            again = again || glm::length(o.centre - Vec3(w.x(), w.y(), w.z())) + 0.5 * (r - margin) * mVoxelSize <= o.radius;
        if (!again) out.push_back({Vec3(w.x(), w.y(), w.z()), (r - margin) * mVoxelSize});
    }
    return out;
}

}  // namespace penumbra
