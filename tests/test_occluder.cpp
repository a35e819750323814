// Tests for occluder.h and level_set.h: analytic hits are exact, level-set hits agree with the
// analytic sphere within a stated fraction of a voxel, and .vdb input is validated.
#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetUtil.h>
#include <tbb/parallel_for.h>

#include <atomic>
#include <catch2/catch.hpp>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "cell_distance.h"
#include "level_set_impl.h"
#include "penumbra/error.h"
#include "penumbra/level_set.h"
#include "penumbra/occluder.h"

using namespace penumbra;

namespace {

constexpr double kVoxel = 0.01;
constexpr double kRadius = 0.5;
const Vec3 kCenter{0.1, -0.2, 0.3};

/// Exact distance to the first hit of the open segment with a sphere, or -1 on a miss.
double analyticSphereHit(const Vec3& c, double r, const Vec3& from, const Vec3& to) {
    const double len = glm::length(to - from);
    const Vec3 d = (to - from) / len;
    const double b = glm::dot(from - c, d);
    const double disc = b * b - (glm::dot(from - c, from - c) - r * r);
    if (disc < 0.0) return -1.0;
    const double t = -b - std::sqrt(disc);
    return (t > 0.0 && t < len) ? t : -1.0;
}

/// An occluder of one level-set sphere of radius kRadius (voxel kVoxel, half width 3) and a
/// query on it.
struct LevelSetSphere {
    explicit LevelSetSphere(const Vec3& center)
        : occ({makeSphereLevelSet(center, kRadius, kVoxel, 3.0)}), q(occ.makeQuery()) {}
    Occluder occ;
    Occluder::Query q;
};

Vec3 randomUnit(std::mt19937_64& rng) {
    std::normal_distribution<double> n(0.0, 1.0);
    Vec3 v(n(rng), n(rng), n(rng));
    return v / glm::length(v);
}

/// A fresh directory under the system temp dir, removed when the test ends.
struct TempDir {
    std::filesystem::path path;
    TempDir() {
        std::random_device rd;
        path = std::filesystem::temp_directory_path() /
               ("penumbra_occ_" + std::to_string(rd()) + std::to_string(rd()));
        std::filesystem::create_directories(path);
    }
    ~TempDir() {
        std::error_code ec;
        std::filesystem::remove_all(path, ec);
    }
    std::string file(const std::string& name) const { return (path / name).string(); }
};

void writeRawGrid(const std::string& file, openvdb::GridBase::Ptr grid) {
    openvdb::io::File vdb(file);
    vdb.write({grid});
    vdb.close();
}

openvdb::FloatGrid::Ptr sphereGridCopy() {
    LevelSetPtr ls = makeSphereLevelSet(kCenter, kRadius, kVoxel, 3.0, "ball");
    return ls->grid().deepCopy();
}

}  // namespace

TEST_CASE("analytic sphere hits are exact, end points excluded, grazing counts", "[occluder]") {
    Occluder occ({AnalyticSphere{Vec3(0.0), 1.0}});
    auto q = occ.makeQuery();
    double t = -1.0;

    REQUIRE(q.occluded(Vec3(0, 0, -3), Vec3(0, 0, 3), &t));
    CHECK(t == Approx(2.0).margin(1e-12));
    REQUIRE(q.occluded(Vec3(0.6, 0, -3), Vec3(0.6, 0, 3), &t));
    CHECK(t == Approx(2.2).margin(1e-12));  // 3 - sqrt(1 - 0.36)
    // Tangent ray: the discriminant is exactly zero.
    REQUIRE(q.occluded(Vec3(1, 0, -3), Vec3(1, 0, 3), &t));
    CHECK(t == Approx(3.0).margin(1e-12));
    CHECK_FALSE(q.occluded(Vec3(1.001, 0, -3), Vec3(1.001, 0, 3)));

    // Segment limits: a segment ending on the surface or before it is not blocked.
    CHECK_FALSE(q.occluded(Vec3(0, 0, -3), Vec3(0, 0, -1)));
    CHECK_FALSE(q.occluded(Vec3(0, 0, -3), Vec3(0, 0, -1.5)));
    CHECK(q.occluded(Vec3(0, 0, -3), Vec3(0, 0, -0.999)));
    // Leaving the surface is free; entering it or starting inside is blocked at t = 0.
    CHECK_FALSE(q.occluded(Vec3(0, 0, 1), Vec3(0, 0, 3)));
    CHECK_FALSE(q.occluded(Vec3(0, 0, 1), Vec3(0, 3, 1)));  // tangent from the surface
    REQUIRE(q.occluded(Vec3(0, 0, 0.5), Vec3(0, 0, 3), &t));
    CHECK(t == 0.0);
    REQUIRE(q.occluded(Vec3(0, 0, 1), Vec3(0, 0, -3), &t));
    CHECK(t == Approx(0.0).margin(1e-12));
    CHECK(q.raysCast() == 11);
}

TEST_CASE("a box's clearance is the smallest signed distance along the segment", "[occluder][clearance]") {
    // The closed form (pieces between the face and middle planes) against dense sampling of the
    // box's signed distance on segments that pass it, graze it or go through it.
    const Vec3 lo(-0.4, -0.3, -0.2), hi(0.5, 0.1, 0.35);
    Occluder occ({AnalyticBox{lo, hi}});
    auto q = occ.makeQuery();
    auto sdf = [&](const Vec3& p) {
        const Vec3 c = 0.5 * (lo + hi), h = 0.5 * (hi - lo);
        const Vec3 d = glm::abs(p - c) - h;
        const double outside = glm::length(glm::max(d, Vec3(0.0)));
        return outside > 0.0 ? outside : std::max({d.x, d.y, d.z});
    };
    std::mt19937 rng(31);
    std::uniform_real_distribution<double> u(-1.5, 1.5);
    int compared = 0, inside = 0;
    for (int i = 0; i < 400; ++i) {
        const Vec3 from(u(rng), u(rng), u(rng)), to(u(rng), u(rng), u(rng));
        if (sdf(from) <= 0.0 || sdf(to) <= 0.0) continue;
        const double length = glm::length(to - from);
        const Vec3 dir = (to - from) / length;
        const int samples = 20000;
        double dense = 1e300;
        for (int k = 0; k <= samples; ++k)
            dense = std::min(dense, sdf(from + (length * k / samples) * dir));
        const bool blocked = q.occluded(from, to);
        const Clearance c = q.clearance(from, to, blocked);
        if (!c.known()) continue;  // closest at the start: reported as a bound only
        ++compared;
        inside += c.distance < 0.0;
        CAPTURE(i, c.distance, dense, c.at);
        // Exact: no sample is lower (but for the query's segment epsilon, a billionth of the
        // length, cut off each end), and between samples the distance drops at most half a step.
        CHECK(c.distance <= dense + 1e-8 * length);
        CHECK(c.distance >= dense - 0.5 * length / samples - 1e-12);
        CHECK(sdf(from + c.at * dir) == Approx(c.distance).margin(1e-12));
    }
    CHECK(compared > 200);
    CHECK(inside > 20);
}

TEST_CASE("analytic box hits are exact (slab test)", "[occluder]") {
    Occluder occ({AnalyticBox{Vec3(-1, -2, -3), Vec3(1, 2, 3)}});
    CHECK(occ.bounds(0).lo == Vec3(-1, -2, -3));
    CHECK(occ.bounds(0).hi == Vec3(1, 2, 3));
    auto q = occ.makeQuery();
    double t = -1.0;
    REQUIRE(q.occluded(Vec3(0.3, 0.2, -5), Vec3(0.3, 0.2, 5), &t));
    CHECK(t == Approx(2.0).margin(1e-12));
    // Diagonal ray entering through the x = -1 face at (-1, 0.5, 0.5).
    const Vec3 from(-3, -0.5, -0.5), to(3, 2.5, 2.5);
    REQUIRE(q.occluded(from, to, &t));
    CHECK(t == Approx(glm::length(Vec3(2, 1, 1))).margin(1e-12));
    // Along a face: grazing counts.
    REQUIRE(q.occluded(Vec3(1, 0, -5), Vec3(1, 0, 5), &t));
    CHECK(t == Approx(2.0).margin(1e-12));
    CHECK_FALSE(q.occluded(Vec3(1.01, 0, -5), Vec3(1.01, 0, 5)));
    CHECK_FALSE(q.occluded(Vec3(0, 0, -5), Vec3(0, 0, -3)));  // ends on the face
    CHECK_FALSE(q.occluded(Vec3(0, 0, 3), Vec3(0, 0, 5)));    // leaves the face
    REQUIRE(q.occluded(Vec3(0, 0, 0), Vec3(0, 0, 5), &t));    // starts inside
    CHECK(t == 0.0);
}

TEST_CASE("level-set sphere hits agree with the analytic sphere within 0.25 voxel", "[occluder]") {
    // Tolerance: the grid holds the exact distance |x - c| - r at voxel centres, and its
    // trilinear interpolation errs by only ~3h^2/(8r) = 0.0075 voxel. The larger error is the
    // marcher's: it finds the root by one secant step between samples at voxel exits, and the
    // first sample may be a clamped band value (3 voxels) up to ~2 voxels before the crossing.
    // That error grows as 1/cos(incidence); aiming within 0.8 r keeps cos >= 0.6, and the
    // worst error seen is ~0.1 voxel (printed below). 0.25 voxel keeps a margin of 2.5 while
    // still catching a half-voxel shift (cell-corner vs voxel-centre convention).
    LevelSetSphere sphere(kCenter);
    Occluder::Query& q = sphere.q;
    std::mt19937_64 rng(20240611);
    std::uniform_real_distribution<double> u(0.0, 1.0);

    double worst = 0.0;
    int hits = 0, misses = 0;
    const int kRays = 2000;
    for (int i = 0; i < kRays; ++i) {
        // The line through `aim` along `dir` passes exactly `offset` from the centre: inside
        // 0.8 r (certain hit) or beyond 1.1 r (certain miss), never in between.
        const bool aimHit = i % 2 == 0;
        const double offset =
            aimHit ? 0.8 * kRadius * std::sqrt(u(rng)) : (1.1 + 0.5 * u(rng)) * kRadius;
        const Vec3 dir = randomUnit(rng);
        const Vec3 side = glm::normalize(glm::cross(dir, randomUnit(rng)));
        const Vec3 aim = kCenter + offset * side;
        const Vec3 from = aim - (1.0 + 1.5 * u(rng)) * dir;  // outside the padded bounds
        const Vec3 to = aim + (1.0 + 1.5 * u(rng)) * dir;

        const double tRef = analyticSphereHit(kCenter, kRadius, from, to);
        double t = -1.0;
        const bool occluded = q.occluded(from, to, &t);
        REQUIRE(occluded == (tRef > 0.0));
        if (occluded) {
            ++hits;
            worst = std::max(worst, std::abs(t - tRef) / kVoxel);
            REQUIRE(std::abs(t - tRef) < 0.25 * kVoxel);
        } else {
            ++misses;
        }
    }
    INFO("worst |t - t_exact| = " << worst << " voxel");  // ~0.10 seen
    CHECK(worst < 0.25);
    CHECK(hits == kRays / 2);
    CHECK(misses == kRays / 2);
    CHECK(q.raysCast() == uint64_t(kRays));
}

TEST_CASE("a level set's solid bounds hold every hit and leave out the band's outside",
          "[occluder]") {
    // Occluder::solidBounds and the sphere beside it (LevelSet::solidBoundsWS): culling drops an
    // obstacle whose solid bounds miss a pixel's pyramid, so every hit must lie inside them.
    LevelSetSphere sphere(kCenter);
    const LevelSet& ls = *std::get<LevelSetPtr>(sphere.occ.shape(0));
    const Box3& solid = sphere.occ.solidBounds(0);
    // The sphere's radius, plus the 1.25 voxels of growth (and the half voxel of a voxel
    // centre inside the surface), well inside the band's bounds (3 voxels more).
    CHECK(ls.solidRadius() > kRadius);
    CHECK(ls.solidRadius() < kRadius + 2.5 * kVoxel);
    CHECK(glm::length(ls.solidCentreWS() - kCenter) < 0.5 * kVoxel);
    CHECK(solid.hi.x - solid.lo.x < 2.0 * kRadius + 3.5 * kVoxel);
    CHECK(sphere.occ.bounds(0).hi.x - sphere.occ.bounds(0).lo.x > 2.0 * kRadius + 6.5 * kVoxel);
    // Grazing segments at every distance around the surface: each hit lies in the solid box
    // and sphere.
    std::mt19937_64 rng(5);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    int hits = 0;
    for (int i = 0; i < 3000; ++i) {
        const Vec3 dir = randomUnit(rng);
        const Vec3 side = glm::normalize(glm::cross(dir, randomUnit(rng)));
        const Vec3 aim = kCenter + kRadius * (0.98 + 0.04 * u(rng)) * side;
        double t = -1.0;
        if (!sphere.q.occluded(aim - 2.0 * dir, aim + 2.0 * dir, &t)) continue;
        ++hits;
        const Vec3 p = aim - 2.0 * dir + t * dir;
        REQUIRE(glm::all(glm::greaterThanEqual(p, solid.lo)));
        REQUIRE(glm::all(glm::lessThanEqual(p, solid.hi)));
        REQUIRE(glm::length(p - ls.solidCentreWS()) <= ls.solidRadius());
    }
    CHECK(hits > 1000);
}

TEST_CASE("sampleTrilinear gives BoxSampler's values bit for bit", "[occluder]") {
    // The distance marches read level sets through sampleTrilinear (level_set_impl.h), which
    // reads a cell's eight values straight from its leaf when they share one: every point,
    // inside cells, across leaf borders and in the background, must give OpenVDB's value.
    LevelSetSphere sphere(kCenter);
    const openvdb::FloatGrid& grid = std::get<LevelSetPtr>(sphere.occ.shape(0))->grid();
    auto fast = grid.getConstAccessor();
    auto slow = grid.getConstAccessor();
    std::mt19937_64 rng(11);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    int leafPath = 0;
    for (int i = 0; i < 20000; ++i) {
        const Vec3 w = kCenter + (kRadius + 6.0 * kVoxel) * Vec3(u(rng), u(rng), u(rng));
        const openvdb::Vec3d xyz = grid.worldToIndex(openvdb::Vec3d(w.x, w.y, w.z));
        const float a = sampleTrilinear(fast, xyz);
        const float b = openvdb::tools::BoxSampler::sample(slow, xyz);
        REQUIRE(std::memcmp(&a, &b, sizeof a) == 0);
        if (std::abs(b) < 0.98f * grid.background()) ++leafPath;
    }
    CHECK(leafPath > 1000);  // the band was sampled, not only the background
}

TEST_CASE("a shadow ray starting 1.5 voxels off a level set does not hit it", "[occluder]") {
    LevelSetSphere sphere(kCenter);
    Occluder::Query& q = sphere.q;
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    const int kPoints = 500;
    int outwardHits = 0, inwardHits = 0;
    double worstInward = 0.0;
    for (int i = 0; i < kPoints; ++i) {
        // Fibonacci points cover the sphere evenly, so every grid orientation is visited.
        const double z = 1.0 - 2.0 * (i + 0.5) / kPoints;
        const double phi = i * kPi * (3.0 - std::sqrt(5.0));
        const Vec3 n(std::sqrt(1 - z * z) * std::cos(phi), std::sqrt(1 - z * z) * std::sin(phi), z);
        const Vec3 from = kCenter + (kRadius + 1.5 * kVoxel) * n;
        // Outward or tangent-ish: dot(d, n) in [0, 1]. Tangent directions never come closer to
        // the centre than the start point does.
        Vec3 tangent = glm::normalize(glm::cross(n, randomUnit(rng)));
        const double c = u(rng) * u(rng);  // biased towards grazing
        const Vec3 d = c * n + std::sqrt(1 - c * c) * tangent;
        if (q.occluded(from, from + 2.0 * d)) ++outwardHits;
        // Control: the same start, going into the surface, is blocked at ~1.5 voxels.
        double t = -1.0;
        if (q.occluded(from, from - 2.0 * n, &t)) {
            ++inwardHits;
            worstInward = std::max(worstInward, std::abs(t - 1.5 * kVoxel) / kVoxel);
        }
    }
    CHECK(outwardHits == 0);
    CHECK(inwardHits == kPoints);
    CHECK(worstInward < 0.25);
}

TEST_CASE("level-set occlusion is limited to the segment", "[occluder]") {
    LevelSetSphere sphere(Vec3(0.0));
    Occluder::Query& q = sphere.q;
    const Vec3 from(0.05, 0.02, -2.0);
    const double tRef = analyticSphereHit(Vec3(0.0), kRadius, from, Vec3(0.05, 0.02, 2.0));
    REQUIRE(tRef > 0.0);
    // Ends 2 voxels before the surface: free; 2 voxels after: blocked.
    CHECK_FALSE(q.occluded(from, from + Vec3(0, 0, tRef - 2 * kVoxel)));
    double t = -1.0;
    REQUIRE(q.occluded(from, from + Vec3(0, 0, tRef + 2 * kVoxel), &t));
    CHECK(t == Approx(tRef).margin(0.25 * kVoxel));
    // Starting inside the level set: blocked at t = 0 even though the segment ends inside too.
    REQUIRE(q.occluded(Vec3(0, 0, -0.1), Vec3(0, 0, 0.1), &t));
    CHECK(t == 0.0);
    // Fully outside, beside the sphere but inside its bounding box: free.
    CHECK_FALSE(q.occluded(Vec3(0.48, 0.48, -0.1), Vec3(0.48, 0.48, 0.1)));
    CHECK(q.raysCast() == 4);
}

TEST_CASE("restrictTo limits the obstacles tested and every call counts a ray", "[occluder]") {
    LevelSetPtr ls = makeSphereLevelSet(Vec3(3, 0, 0), 0.5, 0.02, 3.0);
    Occluder occ({AnalyticSphere{Vec3(0, 0, 0), 0.5}, ls});
    auto q = occ.makeQuery();
    const Vec3 from(0, 0, -2), to(0, 0, 2);    // crosses obstacle 0 only
    const Vec3 from1(3, 0, -2), to1(3, 0, 2);  // crosses obstacle 1 only
    const std::vector<uint32_t> only0{0}, only1{1}, none{};
    CHECK(q.occluded(from, to));
    CHECK(q.occluded(from1, to1));
    q.restrictTo(&only1);
    CHECK_FALSE(q.occluded(from, to));
    CHECK(q.occluded(from1, to1));
    q.restrictTo(&only0);
    CHECK(q.occluded(from, to));
    CHECK_FALSE(q.occluded(from1, to1));
    q.restrictTo(&none);
    CHECK_FALSE(q.occluded(from, to));
    q.restrictTo(nullptr);
    CHECK(q.occluded(from1, to1));
    // Rays rejected by every bounding box are counted too.
    CHECK_FALSE(q.occluded(Vec3(10, 10, 10), Vec3(11, 10, 10)));
    CHECK(q.raysCast() == 9);
    q.resetCount();
    CHECK(q.raysCast() == 0);
}

TEST_CASE("the nearest hit over several obstacles is reported", "[occluder]") {
    // Listed far to near, so the first obstacle tested is not the nearest.
    Occluder occ;
    occ.add(makeSphereLevelSet(Vec3(0, 0, 5), 0.4, 0.02, 3.0, "far"));
    occ.add(AnalyticBox{Vec3(-0.3, -0.3, 2.7), Vec3(0.3, 0.3, 3.3)});
    occ.add(makeSphereLevelSet(Vec3(0, 0, 1), 0.4, 0.02, 3.0, "near"));
    REQUIRE(occ.size() == 3);
    CHECK(occ.minVoxelSize() == Approx(0.02).epsilon(1e-6));
    auto q = occ.makeQuery();
    double t = -1.0;
    REQUIRE(q.occluded(Vec3(0, 0, -1), Vec3(0, 0, 7), &t));
    CHECK(t == Approx(1.6).margin(0.25 * 0.02));
    // Start between the first two: the box is nearest.
    REQUIRE(q.occluded(Vec3(0, 0, 2), Vec3(0, 0, 7), &t));
    CHECK(t == Approx(0.7).margin(1e-12));
    // Start beyond the box: only "far" remains.
    REQUIRE(q.occluded(Vec3(0, 0, 3.5), Vec3(0, 0, 7), &t));
    CHECK(t == Approx(1.1).margin(0.25 * 0.02));
    CHECK(q.occluded(Vec3(0, 0, -1), Vec3(0, 0, 7)));  // without tHit: any hit
}

TEST_CASE("copied queries answer alike on several threads", "[occluder]") {
    LevelSetPtr ls = makeSphereLevelSet(kCenter, kRadius, 0.02, 3.0);
    Occluder occ({ls, AnalyticSphere{Vec3(1.5, 0, 0), 0.3}});
    std::mt19937_64 rng(99);
    std::vector<std::pair<Vec3, Vec3>> rays(4000);
    for (auto& r : rays) {
        r.first = Vec3(0.5, 0, 0) + 2.5 * randomUnit(rng);
        r.second = Vec3(0.5, 0, 0) + 2.5 * randomUnit(rng);
    }
    auto serial = occ.makeQuery();
    std::vector<double> expected(rays.size());
    int hits = 0;
    for (size_t i = 0; i < rays.size(); ++i) {
        double t = -1.0;
        expected[i] = serial.occluded(rays[i].first, rays[i].second, &t) ? t : -1.0;
        hits += expected[i] >= 0.0;
    }
    REQUIRE(hits > 100);  // the comparison below must involve real hits
    REQUIRE(hits < int(rays.size()) - 100);
    std::atomic<int> mismatches{0};
    tbb::parallel_for(tbb::blocked_range<size_t>(0, rays.size(), 64),
                      [&](const tbb::blocked_range<size_t>& range) {
                          Occluder::Query q(serial);  // per-task copy
                          for (size_t i = range.begin(); i != range.end(); ++i) {
                              double t = -1.0;
                              const double got =
                                  q.occluded(rays[i].first, rays[i].second, &t) ? t : -1.0;
                              if (got != expected[i]) ++mismatches;
                          }
                      });
    CHECK(mismatches == 0);
}

TEST_CASE("describe reports voxel size, band and bounds", "[occluder]") {
    LevelSetPtr ls = makeSphereLevelSet(kCenter, kRadius, kVoxel, 3.0, "ball");
    const LevelSetInfo info = describe(*ls);
    CHECK(info.name == "ball");
    CHECK(info.voxelSize == Approx(kVoxel).epsilon(1e-6));
    CHECK(info.halfWidth == Approx(3.0).epsilon(1e-5));
    // Active voxels have |phi| < 3 voxels, so along an axis the outermost voxel centre lies
    // between 2 and 3 voxels off the surface, and its cell half a voxel further.
    const double slack = 1e-6;
    for (int a = 0; a < 3; ++a) {
        CHECK(info.boundsWS.lo[a] >= kCenter[a] - kRadius - 3.5 * kVoxel - slack);
        CHECK(info.boundsWS.lo[a] <= kCenter[a] - kRadius - 2.5 * kVoxel + slack);
        CHECK(info.boundsWS.hi[a] <= kCenter[a] + kRadius + 3.5 * kVoxel + slack);
        CHECK(info.boundsWS.hi[a] >= kCenter[a] + kRadius + 2.5 * kVoxel - slack);
    }
    // A shell 6 voxels thick: 4 pi r^2 * 6h / h^3 voxels.
    const double shell = 4.0 * kPi * kRadius * kRadius * 6.0 * kVoxel / std::pow(kVoxel, 3);
    CHECK(double(info.activeVoxels) == Approx(shell).epsilon(0.05));
    CHECK(info.bytes > info.activeVoxels * sizeof(float));

    // The occluder pads the level set's bounds by one voxel.
    Occluder occ({ls});
    CHECK(occ.bounds(0).lo.x == Approx(info.boundsWS.lo.x - kVoxel).margin(1e-9));
    CHECK(occ.bounds(0).hi.z == Approx(info.boundsWS.hi.z + kVoxel).margin(1e-9));

    LevelSetPtr box = makeBoxLevelSet(Vec3(-1, 0, 0), Vec3(1, 0.5, 2), 0.05, 3.0, "crate");
    const LevelSetInfo boxInfo = describe(*box);
    CHECK(boxInfo.name == "crate");
    CHECK(box->grid().getGridClass() == openvdb::GRID_LEVEL_SET);
    CHECK(boxInfo.boundsWS.lo.x == Approx(-1 - 3.5 * 0.05).margin(0.05));
    CHECK(boxInfo.boundsWS.hi.z == Approx(2 + 3.5 * 0.05).margin(0.05));
    // The box's faces are where the rays stop.
    Occluder boxOcc({box});
    auto q = boxOcc.makeQuery();
    double t = -1.0;
    REQUIRE(q.occluded(Vec3(0, 0.25, -1), Vec3(0, 0.25, 3), &t));
    CHECK(t == Approx(1.0).margin(0.25 * 0.05));

    CHECK_THROWS_AS(makeSphereLevelSet(kCenter, -1.0, kVoxel, 3.0), InputError);
    CHECK_THROWS_AS(makeSphereLevelSet(kCenter, 1.0, 0.0, 3.0), InputError);
    CHECK_THROWS_AS(makeBoxLevelSet(Vec3(0), Vec3(1, 0, 1), 0.1, 3.0), InputError);
}

TEST_CASE("level sets written to a .vdb file read back with the same hits", "[occluder]") {
    TempDir dir;
    const std::string file = dir.file("scene.vdb");
    LevelSetPtr ball = makeSphereLevelSet(kCenter, kRadius, 0.02, 3.0, "ball");
    LevelSetPtr crate = makeBoxLevelSet(Vec3(1, 1, 1), Vec3(1.5, 2, 1.2), 0.02, 3.0, "crate");
    writeLevelSets(file, {ball, crate});
    CHECK_FALSE(std::filesystem::exists(file + ".tmp"));

    const auto all = readLevelSets(file, "");
    REQUIRE(all.size() == 2);
    CHECK(describe(*all[0]).name == "ball");
    CHECK(describe(*all[1]).name == "crate");
    const auto byName = readLevelSets(file, "crate");
    REQUIRE(byName.size() == 1);
    CHECK(describe(*byName[0]).name == "crate");
    CHECK(describe(*byName[0]).activeVoxels == describe(*crate).activeVoxels);

    Occluder original({ball, crate}), loaded(std::vector<ObstacleShape>(all.begin(), all.end()));
    auto qa = original.makeQuery();
    auto qb = loaded.makeQuery();
    std::mt19937_64 rng(5);
    int hits = 0;
    for (int i = 0; i < 500; ++i) {
        const Vec3 from = kCenter + 2.0 * randomUnit(rng);
        const Vec3 to = Vec3(1.25, 1.5, 1.1) + 0.6 * randomUnit(rng);
        double ta = -1.0, tb = -1.0;
        const bool a = qa.occluded(from, to, &ta);
        const bool b = qb.occluded(from, to, &tb);
        REQUIRE(a == b);
        if (a) {
            ++hits;
            CHECK(ta == tb);  // same voxels, same arithmetic
        }
    }
    CHECK(hits > 50);

    // Half-float storage: values are rounded to 11 significant bits, far below a voxel.
    openvdb::FloatGrid::Ptr half = ball->grid().deepCopy();
    half->setName("half");
    half->setSaveFloatAsHalf(true);
    writeRawGrid(dir.file("half.vdb"), half);
    const auto halves = readLevelSets(dir.file("half.vdb"), "half");
    REQUIRE(halves.size() == 1);
    Occluder halfOcc({halves[0]});
    auto qh = halfOcc.makeQuery();
    double t = -1.0;
    const Vec3 from(0.1, -0.2, -2.0), to(0.1, -0.2, 2.0);
    REQUIRE(qh.occluded(from, to, &t));
    CHECK(t == Approx(2.3 - kRadius).margin(0.25 * 0.02));
}

TEST_CASE("readLevelSets refuses missing, corrupt and unsuitable input", "[occluder]") {
    TempDir dir;
    const std::string where = "/obstacles/3";
    const std::string good = dir.file("good.vdb");
    writeLevelSets(good, {makeSphereLevelSet(kCenter, kRadius, 0.05, 3.0, "ball")});

    SECTION("missing file") {
        const std::string missing = dir.file("nope.vdb");
        try {
            readLevelSets(missing, "", where);
            FAIL("no exception");
        } catch (const InputError& e) {
            CHECK(e.file() == missing);
            CHECK(e.where() == where);
            CHECK_THAT(e.message(), Catch::Contains("cannot read"));
        }
    }
    SECTION("corrupt file") {
        const std::string bad = dir.file("bad.vdb");
        std::ofstream(bad) << "this is not a VDB file, just some text to fill the header";
        try {
            readLevelSets(bad, "", where);
            FAIL("no exception");
        } catch (const InputError& e) {
            CHECK(e.file() == bad);
            CHECK_THAT(e.message(), Catch::Contains("cannot read"));
        }
    }
    SECTION("missing grid name") {
        try {
            readLevelSets(good, "teapot", where);
            FAIL("no exception");
        } catch (const InputError& e) {
            CHECK(e.where() == where);
            CHECK_THAT(e.message(), Catch::Contains("teapot") && Catch::Contains("'ball'"));
        }
    }
    SECTION("fog volume") {
        openvdb::FloatGrid::Ptr fog = sphereGridCopy();
        openvdb::tools::sdfToFogVolume(*fog);
        fog->setName("density");
        REQUIRE(fog->getGridClass() == openvdb::GRID_FOG_VOLUME);
        const std::string file = dir.file("fog.vdb");
        writeRawGrid(file, fog);
        try {
            readLevelSets(file, "density", where);
            FAIL("no exception");
        } catch (const InputError& e) {
            CHECK_THAT(e.message(), Catch::Contains("fog volume") && Catch::Contains("density"));
        }
        try {
            readLevelSets(file, "", where);  // no level set at all in the file
            FAIL("no exception");
        } catch (const InputError& e) {
            CHECK_THAT(e.message(),
                       Catch::Contains("no float level-set grid") && Catch::Contains("fog volume"));
        }
    }
    SECTION("grid of unknown class") {
        openvdb::FloatGrid::Ptr sdf = sphereGridCopy();
        sdf->setGridClass(openvdb::GRID_UNKNOWN);
        const std::string file = dir.file("unknown.vdb");
        writeRawGrid(file, sdf);
        CHECK_THROWS_WITH(readLevelSets(file, "ball", where), Catch::Contains("unknown"));
    }
    SECTION("non-uniform voxels") {
        openvdb::FloatGrid::Ptr grid = sphereGridCopy();
        openvdb::Mat4d m = openvdb::Mat4d::identity();
        m.preScale(openvdb::Vec3d(kVoxel, 2 * kVoxel, kVoxel));
        grid->setTransform(openvdb::math::Transform::createLinearTransform(m));
        REQUIRE_FALSE(grid->hasUniformVoxels());
        const std::string file = dir.file("stretched.vdb");
        writeRawGrid(file, grid);
        CHECK_THROWS_WITH(readLevelSets(file, "ball", where), Catch::Contains("non-uniform"));
        CHECK_THROWS_AS(readLevelSets(file, "", where), InputError);
    }
}

TEST_CASE("a clearance bound holds: moving the segment's start by less keeps the answer",
          "[occluder][clearance]") {
    // Clearance::bound promises that an unblocked segment stays `bound` away from every
    // surface, and that a blocked one goes -`bound` deep into one. Check the promise where it
    // is used: segments from a plane to a light past a level-set sphere and an analytic box,
    // each re-tested with its start moved by 0.95 |bound| in random directions.
    const Vec3 center(0.2, -0.1, 1.5);
    Occluder occ({makeSphereLevelSet(center, 0.5, 0.02, 3.0),
                  AnalyticBox{Vec3(-1.2, 0.4, 0.8), Vec3(-0.6, 0.9, 1.3)}});
    Occluder::Query q = occ.makeQuery();
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    int visibleKnown = 0, hiddenKnown = 0, checked = 0;
    for (int i = 0; i < 3000; ++i) {
        const Vec3 from(1.6 * u(rng), 1.6 * u(rng), 0.0);
        const Vec3 to(0.8 * u(rng), 0.8 * u(rng), 3.0);
        Clearance c;
        double t = 0.0;
        const bool hidden = q.occluded(from, to, &t, &c);
        if (c.bound == 0.0) continue;
        CHECK((c.bound < 0.0) == hidden);
        (hidden ? hiddenKnown : visibleKnown)++;
        for (int k = 0; k < 4; ++k) {
            Vec3 d(u(rng), u(rng), u(rng));
            if (glm::length(d) < 1e-3) continue;
            d = glm::normalize(d) * (0.95 * std::min(std::abs(c.bound), 1.0));
            INFO("segment " << i << " bound " << c.bound << " hidden " << hidden);
            CHECK(q.occluded(from + d, to) == hidden);
            ++checked;
        }
    }
    INFO("visible with a bound " << visibleKnown << ", hidden " << hiddenKnown);
    CHECK(visibleKnown > 300);
    CHECK(hiddenKnown > 100);
    CHECK(checked > 1000);
}

TEST_CASE("localMinimum: a segment's smallest level-set value near a fraction, no ray cast",
          "[occluder]") {
    // Segments passing at a known distance d from a level-set sphere (d from -1.5 to +2
    // voxels: inside the band): the smallest trilinear value along them is the exact distance
    // up to the interpolation's error (~3h^2/(8r) = 0.0075 voxel) and the golden-section
    // search's (a fiftieth of a voxel in t, second order in the value), near the closest
    // approach, from a window that starts off-centre. Analytic shapes and windows whose
    // smallest value lies beyond the band give NaN.
    LevelSetSphere sphere(kCenter);
    Occluder::Query& q = sphere.q;
    std::mt19937_64 rng(20261202);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    double worst = 0.0;
    for (int i = 0; i < 200; ++i) {
        const double d = (-1.5 + 3.5 * u(rng)) * kVoxel;
        const Vec3 dir = randomUnit(rng);
        const Vec3 side = glm::normalize(glm::cross(dir, randomUnit(rng)));
        const Vec3 closest = kCenter + (kRadius + d) * side;
        const Vec3 from = closest - 2.0 * dir, to = closest + 1.0 * dir;
        const double tClosest = 2.0 / 3.0;
        // The window (3 voxels either side) starts up to 4 voxels off the closest approach.
        const double start = tClosest + (8.0 * u(rng) - 4.0) * kVoxel / 3.0;
        double at = -1.0;
        const double m = q.localMinimum(0, from, to, start, 3.0 * kVoxel / 3.0, &at);
        REQUIRE(std::isfinite(m));
        worst = std::max(worst, std::abs(m - d) / kVoxel);
        CHECK(std::abs(m - d) < 0.02 * kVoxel);
        // The minimum is flat there (the value moves by 0.004 voxel over 0.6 voxel of the
        // segment), so its place is known to about a voxel.
        CHECK(std::abs(at - tClosest) * 3.0 < 1.0 * kVoxel);
    }
    INFO("worst |minimum - d| = " << worst << " voxel");
    CHECK(q.raysCast() == 0);
    // Far beyond the band, or an analytic shape: nothing.
    const Vec3 farPoint = kCenter + Vec3(kRadius + 10.0 * kVoxel, 0.0, 0.0);
    CHECK(std::isnan(q.localMinimum(0, farPoint - Vec3(0, 1, 0), farPoint + Vec3(0, 1, 0), 0.5,
                                    0.05, nullptr)));
    const Occluder analytic({AnalyticSphere{kCenter, kRadius}});
    Occluder::Query qa = analytic.makeQuery();
    CHECK(std::isnan(qa.localMinimum(0, kCenter - Vec3(0, 1, 1), kCenter + Vec3(0, 1, 1), 0.5,
                                     0.1, nullptr)));
}

TEST_CASE("a level set's gradient bound holds between points of its band", "[occluder][certificate]") {
    // CellTables::gradientBound(p) must bound |phi(q) - phi(p)| / |q - p| for the trilinear
    // interpolant phi and every q within the band's half width of p (what a certificate's ball
    // around p spans). A sphere's bound stays near 1 (its discs are not shrunk for nothing);
    // a box's reaches beyond 1.25 at its edges and corners, where a fixed 1.25 was wrong.
    struct Case {
        LevelSetPtr ls;
        double minTop, maxTop;
        std::vector<Vec3> corners;  // half the points are drawn within 3 voxels of one
    };
    const Vec3 lo(-0.31, -0.2, -0.17), hi(0.29, 0.23, 0.21);
    std::vector<Vec3> corners;
    for (int k = 0; k < 8; ++k)
        corners.push_back(Vec3(k & 1 ? hi.x : lo.x, k & 2 ? hi.y : lo.y, k & 4 ? hi.z : lo.z));
    const Case cases[] = {
        {makeSphereLevelSet(Vec3(0.1, -0.2, 0.05), 0.37, 0.02, 3.0), 1.0, 1.1, {}},
        {makeBoxLevelSet(lo, hi, 0.02, 3.0), 1.4, 1.8, corners},
    };
    for (const Case& c : cases) {
        const openvdb::FloatGrid& grid = c.ls->grid();
        const CellTables* tables = c.ls->cellTables();
        REQUIRE(tables != nullptr);
        CHECK(tables->slopeMax >= c.minTop);
        CHECK(tables->slopeMax <= c.maxTop);
        auto acc = grid.getConstAccessor();
        const double h = grid.voxelSize()[0];
        const double band = 0.98 * double(grid.background());
        const openvdb::CoordBBox box = grid.evalActiveVoxelBoundingBox();
        std::mt19937_64 rng(11);
        auto uni = [&](double a, double b) { return std::uniform_real_distribution<double>(a, b)(rng); };
        int pairs = 0, steep = 0;
        for (int trial = 0; trial < 200000 && pairs < 40000; ++trial) {
            openvdb::Vec3d p(uni(box.min().x(), box.max().x()), uni(box.min().y(), box.max().y()),
                             uni(box.min().z(), box.max().z()));
            if (!c.corners.empty() && trial % 2 == 0) {
                const Vec3& k = c.corners[size_t(trial / 2) % c.corners.size()];
                p = grid.worldToIndex(openvdb::Vec3d(k.x, k.y, k.z)) +
                    openvdb::Vec3d(uni(-3, 3), uni(-3, 3), uni(-3, 3));
            }
            const double vp = sampleTrilinear(acc, p);
            if (!(std::abs(vp) < band)) continue;
            const double bound = std::max(1.0, tables->gradientBound(p[0], p[1], p[2]));
            // q within the half width (in voxels) of p, often very near (steep cells are small).
            openvdb::Vec3d d(uni(-1, 1), uni(-1, 1), uni(-1, 1));
            if (d.length() > 1.0 || d.length() == 0.0) continue;
            d *= std::max(0.02, (band / h) * std::pow(uni(0, 1), 3.0));
            const openvdb::Vec3d q = p + d;
            const double vq = sampleTrilinear(acc, q);
            const double slope = std::abs(vq - vp) / (d.length() * h);
            ++pairs;
            if (slope > 1.25 && d.length() > 0.01) ++steep;  // beyond the values' rounding
            INFO("p " << p << " q " << q << " slope " << slope << " bound " << bound);
            // The values are floats: a millionth of a voxel of rounding between close points.
            REQUIRE(std::abs(vq - vp) <= bound * d.length() * h + 1e-6 * h);
        }
        CHECK(pairs == 40000);
        // Only the box has pairs steeper than the old fixed bound (its edges' cells).
        if (c.minTop > 1.25) CHECK(steep > 0);
    }
}
