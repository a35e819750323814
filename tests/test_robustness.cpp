// Numerical robustness of the contour integrator at the degenerate configurations a scene can
// legally produce: receiver points exactly on shadow boundaries, M collinear with a light edge,
// a light at (or crossing) the receiver's horizon, obstacles touching the light or the receiver,
// and a receiver inside a level set's narrow band. Every estimate must be finite, within
// [0, unoccluded], and within a stated bound of the exact answer where one exists.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <vector>

#include "support/exact_shadow.h"
#include "support/paper_scene.h"
#include "penumbra/contour_integrator.h"
#include "penumbra/level_set.h"

using namespace penumbra;

namespace {

const Vec3 kUp(0, 0, 1);

RectLight testLight() { return test::paperLight(); }

// The error bound of the estimator at its defaults, as in test_contour_integrator.cpp: a strip
// one final dichotomy interval wide along the light's perimeter is 6.25% of its area.
constexpr double kStrip = 0.0625;

void checkSane(const Estimate& e, double unoccluded) {
    REQUIRE(std::isfinite(e.formFactor));
    for (int k = 0; k < 3; ++k) {
        REQUIRE(std::isfinite(e.g[k]));
        REQUIRE(std::isfinite(e.gradient[k]));
    }
    CHECK(e.formFactor >= -1e-12);
    CHECK(e.formFactor <= unoccluded + 1e-9);
}

std::vector<Vec3> boxVertices(const Vec3& lo, const Vec3& hi) {
    std::vector<Vec3> v;
    for (int i = 0; i < 8; ++i)
        v.emplace_back(i & 1 ? hi.x : lo.x, i & 2 ? hi.y : lo.y, i & 4 ? hi.z : lo.z);
    return v;
}

}  // namespace

TEST_CASE("receiver points exactly on shadow boundaries", "[robustness]") {
    // The floor points whose ray to a light corner grazes a top corner of the box: on the
    // boundary of the umbra or of the penumbra, where a sample ray is exactly tangent.
    const RectLight light = testLight();
    const Vec3 lo(-0.25, -0.25, 1.5), hi(0.25, 0.25, 2.0);
    Occluder occ({AnalyticBox{lo, hi}});
    Occluder::Query query = occ.makeQuery();
    ContourIntegrator aci;
    int count = 0;
    for (const Vec3& c : exact::lightPolygon(light.corner, light.edgeU, light.edgeV)) {
        for (const Vec3& e : boxVertices(lo, hi)) {
            const double t = c.z / (c.z - e.z);  // c + t (e - c) on z = 0
            const Vec3 m = c + t * (e - c);
            const Receiver r{Vec3(m.x, m.y, 0.0), kUp};
            const Estimate est = aci.evaluate(r, light, query);
            const double unocc = unoccludedFormFactor(light, r);
            const double exactF = exact::convexPolyhedronShadowFormFactor(
                r.point, r.normal, light.corner, light.edgeU, light.edgeV, boxVertices(lo, hi));
            INFO("M = " << r.point.x << ", " << r.point.y << ": exact " << exactF << " aci "
                        << est.formFactor);
            checkSane(est, unocc);
            CHECK(std::abs(est.formFactor - exactF) < kStrip * unocc);
            ++count;
        }
    }
    CHECK(count == 32);
}

TEST_CASE("M collinear with a light edge", "[robustness]") {
    // M on (eps = 0) or just off (eps > 0, on the emitting side) the line through the edge
    // corner -> corner + edgeU: that edge subtends no angle, and the light is seen edge-on.
    const RectLight light = testLight();
    Occluder occ;
    Occluder::Query query = occ.makeQuery();
    ContourIntegrator aci;
    for (double eps : {0.0, 1e-12, 1e-6, 1e-3}) {
        for (const Vec3& n : {Vec3(1, 0, 0), Vec3(0, 1, 0), glm::normalize(Vec3(1, 1, 1))}) {
            const Receiver r{Vec3(-1, -3, 4 - eps), n};
            const Estimate est = aci.evaluate(r, light, query);
            // Every light vertex is on or above these horizons: Lambert's formula is exact.
            const double exactF =
                eps == 0.0 ? 0.0
                           : exact::lambertPolygon(
                                 exact::lightPolygon(light.corner, light.edgeU, light.edgeV),
                                 r.point, r.normal);
            INFO("eps " << eps << ", n = " << n.x << ", " << n.y << ", " << n.z << ": exact "
                        << exactF << " aci " << est.formFactor);
            checkSane(est, std::max(exactF, 0.0) + 1e-12);
            CHECK(unoccludedFormFactor(light, r) == Approx(exactF).epsilon(1e-6).margin(1e-12));
            CHECK(est.formFactor == Approx(exactF).epsilon(1e-6).margin(1e-12));
        }
    }
}

TEST_CASE("a light at the receiver's horizon", "[robustness]") {
    const RectLight light = testLight();
    Occluder occ({AnalyticSphere{Vec3(0, 0, 2), 0.5}});
    Occluder::Query query = occ.makeQuery();
    ContourIntegrator aci;
    SECTION("in the tangent plane: F = 0") {
        const Receiver r{Vec3(3, 0, 4), kUp};
        const Estimate est = aci.evaluate(r, light, query);
        checkSane(est, 0.0);
        CHECK(est.formFactor == 0.0);
        CHECK(unoccludedFormFactor(light, r) == 0.0);
    }
    SECTION("one edge on the horizon, the light above it") {
        // n = +x at x = -1: the edge x = -1 lies in the tangent plane.
        const Receiver r{Vec3(-1, 0, 0), Vec3(1, 0, 0)};
        const double exactF = exact::lambertPolygon(
            exact::lightPolygon(light.corner, light.edgeU, light.edgeV), r.point, r.normal);
        const Estimate est = aci.evaluate(r, light, query);
        INFO("exact unoccluded " << exactF << " aci " << est.formFactor);
        REQUIRE(exactF > 0.0);
        checkSane(est, exactF);
        const double exactShadowed = exact::sphereShadowFormFactor(
            r.point, r.normal, light.corner, light.edgeU, light.edgeV, Vec3(0, 0, 2), 0.5);
        CHECK(std::abs(est.formFactor - exactShadowed) < kStrip * exactF);
    }
    SECTION("the horizon cuts the light in half") {
        const Receiver r{Vec3(0, 0, 0), Vec3(1, 0, 0)};
        // The visible half x in [0, 1], counterclockwise as seen from below like the light.
        const std::vector<Vec3> half{Vec3(0, -1, 4), Vec3(0, 1, 4), Vec3(1, 1, 4),
                                     Vec3(1, -1, 4)};
        const double exactHalf = exact::lambertPolygon(half, r.point, r.normal);
        REQUIRE(exactHalf > 0.0);
        CHECK(unoccludedFormFactor(light, r) == Approx(exactHalf).epsilon(1e-9));
        const Estimate est = aci.evaluate(r, light, query);
        checkSane(est, exactHalf);
    }
}

TEST_CASE("obstacles touching the light or the receiver", "[robustness]") {
    const RectLight light = testLight();
    ContourIntegrator aci;
    SECTION("a sphere touching the light's centre") {
        Occluder occ({AnalyticSphere{Vec3(0, 0, 3.5), 0.5}});
        Occluder::Query query = occ.makeQuery();
        for (double x : {-2.0, -0.5, 0.0, 0.7, 1.5}) {
            const Receiver r{Vec3(x, 0.2, 0), kUp};
            const Estimate est = aci.evaluate(r, light, query);
            const double unocc = unoccludedFormFactor(light, r);
            INFO("x = " << x << " aci " << est.formFactor);
            checkSane(est, unocc);
            CHECK(est.formFactor < unocc);  // the sphere hides part of the light from every M
        }
    }
    SECTION("a sphere resting on the receiver") {
        Occluder occ({AnalyticSphere{Vec3(0, 0, 0.5), 0.5}});
        Occluder::Query query = occ.makeQuery();
        // At the contact point the sphere fills the whole upper hemisphere.
        const Estimate atContact = aci.evaluate({Vec3(0, 0, 0), kUp}, light, query);
        checkSane(atContact, unoccludedFormFactor(light, {Vec3(0, 0, 0), kUp}));
        CHECK(atContact.formFactor == 0.0);
        for (double x : {0.05, 0.2, 0.6, 1.2}) {
            const Receiver r{Vec3(x, 0, 0), kUp};
            const Estimate est = aci.evaluate(r, light, query);
            const double unocc = unoccludedFormFactor(light, r);
            const double exactF = exact::sphereShadowFormFactor(
                r.point, r.normal, light.corner, light.edgeU, light.edgeV, Vec3(0, 0, 0.5), 0.5);
            INFO("x = " << x << ": exact " << exactF << " aci " << est.formFactor);
            checkSane(est, unocc);
            CHECK(std::abs(est.formFactor - exactF) < kStrip * unocc);
        }
    }
}

TEST_CASE("a receiver inside a level set's narrow band", "[robustness]") {
    // A level-set sphere whose surface passes one voxel above the floor point M: M is inside the
    // narrow band (3 voxels), closer to the surface than the shadow rays' start offset.
    const RectLight light = testLight();
    const double voxel = 0.05;
    const Vec3 center(0, 0, 0.5 + voxel);
    Occluder occ({makeSphereLevelSet(center, 0.5, voxel, 3.0)});
    Occluder::Query query = occ.makeQuery();
    AciSettings s;
    s.rayOffset = 1.5 * voxel;
    ContourIntegrator aci(s);
    for (double x : {0.0, 0.02, 0.1, 0.3}) {
        const Receiver r{Vec3(x, 0, 0), kUp};
        const Estimate est = aci.evaluate(r, light, query);
        const double unocc = unoccludedFormFactor(light, r);
        const double exactF = exact::sphereShadowFormFactor(r.point, r.normal, light.corner,
                                                            light.edgeU, light.edgeV, center, 0.5);
        INFO("x = " << x << ": exact " << exactF << " aci " << est.formFactor << " unoccluded "
                    << unocc);
        checkSane(est, unocc);
        // Under the sphere the light is wholly hidden (exact 0): the level set must keep it so,
        // even though the rays start 1.5 voxels up, half a voxel past the surface.
        CHECK(std::abs(est.formFactor - exactF) < kStrip * unocc);
    }
    SECTION("a receiver point on the zero crossing itself, with the surface normal") {
        const Vec3 n = glm::normalize(Vec3(1, 0, 1));
        const Receiver r{center + 0.5 * n, n};
        const Estimate est = aci.evaluate(r, light, query);
        checkSane(est, unoccludedFormFactor(light, r));
    }
}
