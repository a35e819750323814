// The cell tables behind level-set certificates (src/cell_distance.h): the distance transform
// against brute force, and every stored distance against the exact distance from the point to
// the nearest cell of the other kind.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "cell_distance.h"

using namespace penumbra;

namespace {

using State = CellDistance::State;

struct Cells {
    int origin[3];
    int dims[3];
    std::vector<State> states;
    State at(int x, int y, int z) const {
        return states[(size_t(z) * dims[1] + size_t(y)) * dims[0] + size_t(x)];
    }
};

/// Blobs of inside cells wrapped in surface cells, and scattered surface cells, on a small grid.
Cells randomCells(uint64_t seed) {
    std::mt19937_64 rng(seed);
    Cells c{{-7, 3, 11}, {23, 17, 19}, {}};
    c.states.assign(size_t(c.dims[0]) * c.dims[1] * c.dims[2], CellDistance::kClear);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    for (int blob = 0; blob < 4; ++blob) {
        const double cx = u(rng) * c.dims[0], cy = u(rng) * c.dims[1], cz = u(rng) * c.dims[2];
        const double r = 4.0 + 4.0 * u(rng);
        for (int z = 0; z < c.dims[2]; ++z)
            for (int y = 0; y < c.dims[1]; ++y)
                for (int x = 0; x < c.dims[0]; ++x) {
                    const double d = std::sqrt((x - cx) * (x - cx) + (y - cy) * (y - cy) + (z - cz) * (z - cz)) - r;
                    State& s = c.states[(size_t(z) * c.dims[1] + size_t(y)) * c.dims[0] + size_t(x)];
                    if (d < -1.0) s = CellDistance::kInside;
                    else if (d < 0.0 && s == CellDistance::kClear) s = CellDistance::kSurface;
                }
    }
    for (State& s : c.states)
        if (s == CellDistance::kClear && u(rng) < 0.002) s = CellDistance::kSurface;
    return c;
}

/// Distance from the point p (index space) to the cell box of `c` whose corner is at cell xyz.
double pointToCell(const double p[3], const Cells& c, int x, int y, int z) {
    const int q[3] = {x, y, z};
    double s = 0.0;
    for (int a = 0; a < 3; ++a) {
        const double lo = c.origin[a] + q[a], hi = lo + 1.0;
        const double d = std::max({0.0, lo - p[a], p[a] - hi});
        s += d * d;
    }
    return std::sqrt(s);
}

/// Exact distance from p to the nearest cell that is not `side`; for inside, cells beyond the
/// table count as clear (the nearest of them is at the box's border).
double exactDistance(const double p[3], const Cells& c, State side) {
    double best = 1e300;
    for (int z = 0; z < c.dims[2]; ++z)
        for (int y = 0; y < c.dims[1]; ++y)
            for (int x = 0; x < c.dims[0]; ++x)
                if (c.at(x, y, z) != side) best = std::min(best, pointToCell(p, c, x, y, z));
    if (side == CellDistance::kInside)
        for (int a = 0; a < 3; ++a)
            best = std::min({best, p[a] - c.origin[a], c.origin[a] + c.dims[a] - p[a]});
    return best;
}

}  // namespace

TEST_CASE("squared distance transform matches brute force", "[cell_distance]") {
    std::mt19937_64 rng(7);
    const int dims[3] = {9, 14, 6};
    const size_t n = size_t(dims[0]) * dims[1] * dims[2];
    std::vector<float> v(n, kEdtFar);
    std::vector<int> seeds;
    for (size_t i = 0; i < n; ++i)
        if (rng() % 23 == 0) {
            v[i] = 0.0f;
            seeds.push_back(int(i));
        }
    REQUIRE(!seeds.empty());
    squaredDistanceTransform(v, dims);
    for (size_t i = 0; i < n; ++i) {
        const int x = int(i % dims[0]), y = int(i / dims[0] % dims[1]), z = int(i / dims[0] / dims[1]);
        double best = 1e300;
        for (int s : seeds) {
            const int sx = s % dims[0], sy = s / dims[0] % dims[1], sz = s / dims[0] / dims[1];
            best = std::min(best, double((x - sx) * (x - sx) + (y - sy) * (y - sy) + (z - sz) * (z - sz)));
        }
        REQUIRE(v[i] == Approx(best).margin(1e-6));
    }
}

TEST_CASE("cell tables never prove a ball that holds a cell of the other kind", "[cell_distance]") {
    for (uint64_t seed : {1u, 2u, 3u}) {
        const Cells c = randomCells(seed);
        const CellDistance fine(c.origin, c.dims, c.states);
        const CellDistance coarse = CellDistance::coarsened(c.origin, c.dims, c.states, 4, 3);
        std::mt19937_64 rng(seed * 101);
        std::uniform_real_distribution<double> u(-3.0, 26.0);
        int provedClear = 0, provedInside = 0, tight = 0;
        for (int k = 0; k < 3000; ++k) {
            const double p[3] = {c.origin[0] + u(rng), c.origin[1] + u(rng), c.origin[2] + u(rng)};
            for (const CellDistance* table : {&fine, &coarse}) {
                double d;
                if (!table->at(p[0], p[1], p[2], d)) continue;
                if (d > 0.0) {
                    const double exact = exactDistance(p, c, CellDistance::kClear);
                    REQUIRE(d <= exact + 1e-9);
                    ++provedClear;
                    // The one-voxel table loses at most its cell's extent and a quarter.
                    if (table == &fine && exact < 30.0) {
                        REQUIRE(d >= exact - std::sqrt(3.0) - 0.25);
                        tight += d >= exact - 1.25;
                    }
                } else if (d < 0.0) {
                    REQUIRE(-d <= exactDistance(p, c, CellDistance::kInside) + 1e-9);
                    ++provedInside;
                }
            }
        }
        // The test proves something: both kinds of balls were checked, most of them close.
        CHECK(provedClear > 500);
        CHECK(provedInside > 20);
        CHECK(tight > provedClear / 4);
    }
}

TEST_CASE("cell tables say nothing beyond their cells", "[cell_distance]") {
    const Cells c = randomCells(5);
    const CellDistance fine(c.origin, c.dims, c.states);
    double d;
    CHECK(fine.at(c.origin[0] + 0.5, c.origin[1] + 0.5, c.origin[2] + 0.5, d));
    CHECK_FALSE(fine.at(c.origin[0] - 0.01, c.origin[1] + 0.5, c.origin[2] + 0.5, d));
    CHECK_FALSE(fine.at(c.origin[0] + 0.5, c.origin[1] + c.dims[1], c.origin[2] + 0.5, d));
}
