// The visible part of a rectangle of the light from an evaluation's kept contour
// (ContourIntegrator::visibleWithin, the media cubature's cells that the opaque contour
// crosses), against the exact visible form factors of the rectangles (tests/support/
// exact_shadow.h, independent of the library).
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "support/exact_shadow.h"
#include "support/paper_scene.h"
#include "penumbra/contour_integrator.h"
#include "penumbra/occluder.h"

using namespace penumbra;

TEST_CASE("a kept contour gives each cell of the light its visible part, within the bound",
          "[aci][media]") {
    // Random scenes of 1-6 analytic spheres under the paper's light; at each receiver the light
    // is cut into 4 x 4 and 8 x 8 cells, as the cubature does. Over a partition the cells' G
    // sum to the evaluation's own (the contour closes, so every cell is answered), and their
    // errors against the exact visible form factor of each cell, summed, stay within the
    // evaluation's bound times the contour's weight factor (the header's promise, which
    // aciThroughMedia adds to its bound).
    const RectLight light = test::paperLight();
    std::mt19937 rng(20261206);
    std::uniform_real_distribution<double> u01(0.0, 1.0);
    const Vec3 up(0, 0, 1);
    int receivers = 0, crossed = 0;
    double worstShare = 0.0;  // the largest summed error over its allowance
    for (int scene = 0; scene < 12; ++scene) {
        std::vector<AnalyticSphere> spheres;
        Occluder occ;
        const int count = 1 + scene % 6;
        for (int k = 0; k < count; ++k) {
            const double radius = 0.05 + 0.5 * std::pow(u01(rng), 2.0);
            const Vec3 c(-1.2 + 2.4 * u01(rng), -1.2 + 2.4 * u01(rng),
                         0.6 + radius + (3.2 - 2.0 * radius - 0.6) * u01(rng));
            spheres.push_back({c, radius});
            occ.add(spheres.back());
        }
        std::vector<exact::SphereObstacle> exactSpheres;
        for (const AnalyticSphere& s : spheres) exactSpheres.push_back({s.center, s.radius});
        Occluder::Query q = occ.makeQuery();
        AciSettings settings;
        settings.gradient = false;
        ContourIntegrator aci(settings);
        aci.recordContour(true);
        for (int k = 0; k < 8; ++k) {
            const Receiver r{Vec3(-2.0 + 4.0 * u01(rng), -2.0 + 4.0 * u01(rng), 0.0), up};
            const Estimate e = aci.evaluate(r, light, q);
            ++receivers;
            for (int cells : {4, 8}) {
                Vec3 sum(0.0);
                double errors = 0.0;
                for (int j = 0; j < cells; ++j)
                    for (int i = 0; i < cells; ++i) {
                        const double u0 = double(i) / cells, v0 = double(j) / cells,
                                     s = 1.0 / cells;
                        Vec3 g(0.0);
                        REQUIRE(aci.visibleWithin(r, light, u0, v0, u0 + s, v0 + s, g));
                        sum += g;
                        const Vec3 corner = light.point(u0, v0);
                        const double exactF = exact::rectMinusObstacles(
                            r.point, r.normal, corner, s * light.edgeU, s * light.edgeV, exactSpheres);
                        const double f = glm::dot(g, r.normal);
                        const double open = exact::rectMinusObstacles(
                            r.point, r.normal, corner, s * light.edgeU, s * light.edgeV, {});
                        if (exactF > 1e-6 * open && exactF < open * (1.0 - 1e-6)) ++crossed;
                        errors += std::abs(f - exactF);
                    }
                CAPTURE(scene, k, cells, e.formFactor, e.errorBound);
                // The partition gives back the evaluation's G (up to the cells' moves).
                CHECK(glm::length(sum - e.g) <= 1e-6 * glm::length(e.g) + 1e-15);
                // The cells' errors together (each cell is moved by a billionth of the light,
                // which moves its answer by about that share of its form factor: a margin of
                // 1e-6 of the unoccluded form factor over all of them covers it).
                const double allowance = aci.contourWeightFactor() * e.errorBound +
                                         1e-6 * unoccludedFormFactor(light, r);
                CHECK(errors <= allowance);
                worstShare = std::max(worstShare, errors / allowance);
            }
        }
    }
    WARN("visibleWithin: " << receivers << " receivers, " << crossed
                           << " cells with a shadow's edge; the largest summed error was "
                           << worstShare << " of its allowance");
    CHECK(crossed > 100);  // the test sees contours, not only open or hidden cells
}

TEST_CASE("a kept contour is not used where it cannot answer", "[aci][media]") {
    const RectLight light = test::paperLight();
    Occluder occ;
    occ.add(AnalyticSphere{Vec3(0.2, 0.1, 2.0), 0.4});
    Occluder::Query q = occ.makeQuery();
    AciSettings settings;
    settings.gradient = false;
    ContourIntegrator aci(settings);
    const Receiver r{Vec3(0.3, 0.0, 0.0), Vec3(0, 0, 1)};
    Vec3 g(0.0);
    // Nothing kept without recordContour.
    aci.evaluate(r, light, q);
    CHECK_FALSE(aci.visibleWithin(r, light, 0.0, 0.0, 0.5, 0.5, g));
    // Kept, then a rectangle reaching below a tilted receiver's horizon is refused.
    aci.recordContour(true);
    const Receiver tilted{Vec3(0.3, 0.0, 0.0), glm::normalize(Vec3(1, 0, 0.05))};
    aci.evaluate(tilted, light, q);
    CHECK_FALSE(aci.visibleWithin(tilted, light, 0.0, 0.0, 1.0, 1.0, g));
    // A disc light's arcs are not kept.
    const RectLight disc = discLight(Vec3(0, 0, 4), Vec3(0, 0, -1), 1.0);
    aci.evaluate(r, disc, q);
    CHECK_FALSE(aci.visibleWithin(r, disc, 0.0, 0.0, 0.5, 0.5, g));
    // What was kept stays once recording stops, until the next recorded evaluation.
    aci.evaluate(r, light, q);
    aci.recordContour(false);
    aci.evaluate(r, disc, q);
    CHECK(aci.visibleWithin(r, light, 0.0, 0.0, 0.5, 0.5, g));
}
