// Where a level set can block a ray, from its own values (src/level_set_extent.cpp): the solid
// box and sphere must hold every point where the trilinear interpolant is <= 0 (the tracer's
// hits), the kernel balls only points where it is < 0 (every segment through them is blocked),
// and both must be tight: a level-set sphere's footprint on a light is what certified coverage
// answers without rays, and each voxel of slack there cost rays at the shadow's edge.
#include <catch2/catch.hpp>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "penumbra/level_set.h"
#include "penumbra/occluder.h"
#include "penumbra/shape.h"

using namespace penumbra;

namespace {

constexpr double kVoxel = 0.01;

Vec3 randomUnit(std::mt19937_64& rng) {
    std::normal_distribution<double> n(0.0, 1.0);
    for (;;) {
        const Vec3 v(n(rng), n(rng), n(rng));
        if (glm::length(v) > 1e-6) return glm::normalize(v);
    }
}

struct Case {
    std::string name;
    LevelSetPtr ls;
};

// How far along unit `inward` from `start` the interpolant is first <= 0, marching from a voxel
// before `start` in steps of a 64th of a voxel to `reach` past it (negative: before `start`);
// NaN when it stays positive.
double firstInside(const LevelSet& ls, const Vec3& start, const Vec3& inward, double reach) {
    for (double s = -kVoxel; s < reach; s += kVoxel / 64.0)
        if (sampleLevelSet(ls, start + s * inward) <= 0.0) return s;
    return std::nan("");
}

std::vector<Case> cases() {
    TorusShape t;
    t.center = Vec3(0.013, -0.021, 0.007);
    t.axis = glm::normalize(Vec3(0.3, -0.5, 1.0));
    t.majorRadius = 0.2;
    t.minorRadius = 0.06;
    CapsuleShape c;
    c.a = Vec3(-0.15, 0.02, 0.01);
    c.b = Vec3(0.12, -0.07, 0.11);
    c.radius = 0.045;
    return {
        {"sphere", makeSphereLevelSet(Vec3(0.0033, -0.0071, 0.0049), 0.3, kVoxel, 3.0)},
        {"box", makeBoxLevelSet(Vec3(-0.2, -0.1, -0.15), Vec3(0.17, 0.23, 0.05), kVoxel, 3.0)},
        {"torus", buildLevelSet(ShapeNode{t, Similarity{}}, kVoxel, 3.0, "ring")},
        {"capsule", buildLevelSet(ShapeNode{c, Similarity{}}, kVoxel, 3.0, "pill")},
        // A narrow band (a voxel and a half): the inside's tiles begin close to the surface.
        {"thin-band sphere", makeSphereLevelSet(Vec3(0.0021, 0.0043, -0.0017), 0.2, kVoxel, 1.5)},
    };
}

}  // namespace

TEST_CASE("a level set's solid box and sphere hold every point it can block, and barely more",
          "[occluder][extent]") {
    std::mt19937_64 rng(8801);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    for (const Case& k : cases()) {
        INFO(k.name);
        Occluder occ;
        occ.add(k.ls);
        const Box3& box = occ.solidBounds(0);
        const Vec3 centre = occ.solidCentre(0);
        const double radius = occ.solidRadius(0);
        // Along 3000 directions from the solid's centre, inwards from past its sphere in steps of
        // a 64th of a voxel: the first point where the interpolant is <= 0 must lie inside the
        // sphere, and the farthest of them must come within a tenth of a voxel of it.
        double farthest = 0.0;
        for (int i = 0; i < 3000; ++i) {
            // A third of them near the directions of the box's corners (a box's farthest points).
            Vec3 dir = randomUnit(rng);
            if (i % 3 == 0) dir = glm::normalize(glm::normalize(box.corner(i % 8) - centre) + 0.02 * u(rng) * dir);
            for (double r = radius + kVoxel; r > 0.0; r -= kVoxel / 64.0) {
                const Vec3 p = centre + r * dir;
                if (sampleLevelSet(*k.ls, p) <= 0.0) {
                    REQUIRE(r <= radius);
                    farthest = std::max(farthest, r);
                    break;
                }
            }
        }
        CHECK(farthest > radius - 0.1 * kVoxel);
        // Across each face of the box, inwards from a voxel past it: the same for the box.
        for (int axis = 0; axis < 3; ++axis)
            for (int side = 0; side < 2; ++side) {
                double deepest = -1.0;  // how far past the face's opposite the found points reach
                const int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
                for (int i = 0; i < 2000; ++i) {
                    Vec3 p(0.0);
                    p[a1] = box.lo[a1] + (box.hi[a1] - box.lo[a1]) * u(rng);
                    p[a2] = box.lo[a2] + (box.hi[a2] - box.lo[a2]) * u(rng);
                    p[axis] = side ? box.hi[axis] : box.lo[axis];
                    Vec3 inward(0.0);
                    inward[axis] = side ? -1.0 : 1.0;
                    const double s = firstInside(*k.ls, p, inward, 2.0 * kVoxel);
                    if (std::isnan(s)) continue;
                    REQUIRE(s >= 0.0);
                    deepest = deepest < 0.0 ? s : std::min(deepest, s);
                }
                INFO("axis " << axis << " side " << side);
                CHECK(deepest >= 0.0);
                // (A round end's extreme is a point, which 2000 random lines come near only so
                // far: 0.11-0.16 voxel on the capsule, 0.01 on the box's flat faces.)
                CHECK(deepest < 0.2 * kVoxel);
            }
    }
}

TEST_CASE("a level set's kernel balls lie where its interpolant is negative, and fill a sphere",
          "[occluder][extent]") {
    std::mt19937_64 rng(8802);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    for (const Case& k : cases()) {
        INFO(k.name);
        Occluder occ;
        occ.add(k.ls);
        occ.prepareClearance();
        const std::vector<Occluder::KernelBall>& balls = occ.kernelBalls(0);
        REQUIRE_FALSE(balls.empty());
        // Points of every ball, most of them in its outer tenth, where a ball too large would
        // reach the surface: the interpolant must be negative at each.
        for (const Occluder::KernelBall& b : balls)
            for (int i = 0; i < 20000; ++i) {
                const double r = b.radius * (i % 4 == 0 ? std::cbrt(u(rng)) : 0.9 + 0.1 * u(rng));
                const Vec3 p = b.centre + r * randomUnit(rng);
                REQUIRE(sampleLevelSet(*k.ls, p) < 0.0);
            }
        if (k.name == "sphere") {
            // One ball, at the centre, within a third of a voxel of the sphere (the companion's
            // four-voxel cells and error alone left it three voxels short).
            CHECK(balls.size() == 1);
            CHECK(glm::length(balls[0].centre - Vec3(0.0033, -0.0071, 0.0049)) < 0.3 * kVoxel);
            CHECK(balls[0].radius > 0.3 - 0.35 * kVoxel);
        }
        if (k.name == "capsule") CHECK(balls[0].radius > 0.045 - 0.5 * kVoxel);
    }
}

TEST_CASE("a level set's oriented solid box holds every point it can block, and is tighter where "
          "the shape is turned",
          "[occluder][extent]") {
    std::mt19937_64 rng(8802);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    std::vector<Case> all = cases();
    BoxShape crate;
    crate.size = Vec3(0.3, 0.2, 0.12);
    all.push_back({"turned box", buildLevelSet(ShapeNode{crate, Similarity::fromSceneTransform(
                                                                    Vec3(0.011, -0.017, 0.004),
                                                                    Vec3(20.0, 35.0, 50.0), 1.0)},
                                               kVoxel, 3.0, "crate")});
    for (const Case& k : all) {
        INFO(k.name);
        Occluder occ;
        occ.add(k.ls);
        const OrientedBox& ob = occ.solidOriented(0);
        const Box3& box = occ.solidBounds(0);
        const double boxVolume = (box.hi.x - box.lo.x) * (box.hi.y - box.lo.y) * (box.hi.z - box.lo.z);
        REQUIRE_FALSE(ob.empty());
        // Across each face of the oriented box, inwards from a voxel past it in steps of a 64th
        // of a voxel: the first point where the interpolant is <= 0 lies inside, and within
        // the box's margin (a cell's diagonal and a quarter voxel) of the face.
        for (int axis = 0; axis < 3; ++axis)
            for (int side = 0; side < 2; ++side) {
                const int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
                double deepest = -1.0;
                for (int i = 0; i < 2000; ++i) {
                    const Vec3 onFace = ob.centre + (2.0 * u(rng) - 1.0) * ob.half[a1] * ob.axis[a1] +
                                        (2.0 * u(rng) - 1.0) * ob.half[a2] * ob.axis[a2] +
                                        (side ? 1.0 : -1.0) * ob.half[axis] * ob.axis[axis];
                    const Vec3 inward = (side ? -1.0 : 1.0) * ob.axis[axis];
                    const double s = firstInside(*k.ls, onFace, inward, 4.0 * kVoxel);
                    if (std::isnan(s)) continue;
                    REQUIRE(s >= 0.0);
                    deepest = deepest < 0.0 ? s : std::min(deepest, s);
                }
                INFO("axis " << axis << " side " << side);
                CHECK(deepest >= 0.0);
                CHECK(deepest < 2.5 * kVoxel);
            }
        CAPTURE(ob.volume(), boxVolume);
        CHECK(ob.volume() <= boxVolume * (1.0 + 1e-9));
        // Turned shapes fill a small part of their axis-aligned box.
        if (k.name == "torus" || k.name == "capsule" || k.name == "turned box")
            CHECK(ob.volume() < 0.75 * boxVolume);
    }
}
