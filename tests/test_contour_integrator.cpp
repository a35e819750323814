// Tests of the approximate contour integration estimator (contour_integrator.h) against
// closed forms and exact shadows computed independently in exact_shadow.h.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <set>
#include <tuple>

#include "support/exact_shadow.h"
#include "support/paper_scene.h"
#include "penumbra/contour_integrator.h"
#include "penumbra/level_set.h"
#include "penumbra/monte_carlo.h"

using namespace penumbra;

namespace {

// The light of the paper-like test scene: 2 x 2 at height 4, emitting downwards.
RectLight testLight() { return test::paperLight(); }

const Vec3 kUp(0, 0, 1);
const Vec3 kSphereCenter(0.3, 0.2, 2.0);
constexpr double kSphereRadius = 0.7;

double exactSphere(const Receiver& r, const RectLight& l, const Vec3& c = kSphereCenter,
                   double radius = kSphereRadius) {
    return exact::sphereShadowFormFactor(r.point, r.normal, l.corner, l.edgeU, l.edgeV, c, radius);
}

// Receiver points on z = 0 along a line through the sphere's shadow (and through the umbra
// point (0.6, 0.4)): lit, penumbra, umbra.
std::vector<Receiver> penumbraLine(int count, double from = -3.0, double to = 3.0) {
    std::vector<Receiver> out;
    for (int i = 0; i < count; ++i) {
        const double x = from + (to - from) * (i + 0.5) / count;
        out.push_back({Vec3(x, 0.4 + 0.05 * (x - 0.6), 0.0), kUp});
    }
    return out;
}

}  // namespace

TEST_CASE("contour integral with no obstacle equals the closed form", "[aci]") {
    const RectLight light = testLight();
    Occluder none;
    Occluder::Query query = none.makeQuery();
    const std::vector<Receiver> receivers = {
        {Vec3(0, 0, 0), kUp},
        {Vec3(2.5, -1.0, 0.3), kUp},
        {Vec3(0.2, 0.1, 1.0), glm::normalize(Vec3(0.3, -0.2, 1.0))},
        // Tilted so that the light straddles the horizon: the horizon vertices are exact.
        {Vec3(0.0, 0.0, 2.0), glm::normalize(Vec3(1.0, 0.2, 0.3))},
        {Vec3(1.5, 0.5, 3.0), glm::normalize(Vec3(-0.4, 1.0, 0.5))},
    };
    for (const Receiver& r : receivers) {
        for (int grid : {1, 2, 3}) {
            AciSettings s;
            s.grid = grid;
            const Estimate e = contourIntegral(r, light, query, s);
            const double closed = unoccludedFormFactor(light, r);
            INFO("receiver " << r.point.x << "," << r.point.y << "," << r.point.z << " grid " << grid);
            CHECK(e.formFactor == Approx(closed).margin(1e-12));
            const GWithDerivative u = unoccludedG(light, r);
            for (int k = 0; k < 3; ++k) {
                CHECK(e.gradient[k] == Approx(glm::dot(u.dg[k], r.normal)).margin(1e-10));
            }
        }
    }
}

TEST_CASE("a point in full light or full shadow spends only first-level rays", "[aci]") {
    // The paper's method (the default's coverage may need fewer: see test_coverage.cpp).
    const RectLight light = testLight();
    Occluder occ({AnalyticSphere{kSphereCenter, kSphereRadius}});
    Occluder::Query query = occ.makeQuery();
    AciSettings paper;
    applyAciMode(paper, AciMode::Paper);

    const Receiver lit{Vec3(3.5, -3.0, 0.0), kUp};
    REQUIRE(exactSphere(lit, light) == Approx(unoccludedFormFactor(light, lit)).margin(1e-15));
    const Estimate a = contourIntegral(lit, light, query, paper);
    CHECK(a.counts.firstLevelRays == 9);
    CHECK(a.counts.secondLevelRays == 0);
    CHECK(a.formFactor == Approx(unoccludedFormFactor(light, lit)).margin(1e-12));

    const Receiver umbra{Vec3(0.6, 0.4, 0.0), kUp};  // below the sphere: the light is hidden
    REQUIRE(exactSphere(umbra, light) == Approx(0.0).margin(1e-12));
    const Estimate b = contourIntegral(umbra, light, query, paper);
    CHECK(b.counts.firstLevelRays == 9);
    CHECK(b.counts.secondLevelRays == 0);
    CHECK(b.formFactor == Approx(0.0).margin(1e-12));
    CHECK(std::count(b.pattern.begin(), b.pattern.end(), 0) == 9);
}

TEST_CASE("analytic sphere: the error shrinks as steps and grid grow", "[aci]") {
    const RectLight light = testLight();
    Occluder occ({AnalyticSphere{kSphereCenter, kSphereRadius}});
    Occluder::Query query = occ.makeQuery();
    const std::vector<Receiver> line = penumbraLine(120);

    auto meanError = [&](int grid, int steps, double* rays) {
        AciSettings s;
        s.grid = grid;
        s.steps = steps;
        ContourIntegrator aci(s);
        double err = 0.0, unocc = 0.0;
        uint64_t n = 0, raysPenumbra = 0, penumbraPoints = 0;
        for (const Receiver& r : line) {
            const Estimate e = aci.evaluate(r, light, query);
            const double exact = exactSphere(r, light), open = unoccludedFormFactor(light, r);
            err += std::abs(e.formFactor - exact);
            unocc += open;
            ++n;
            // Penumbra points by the exact answer: part of the light hidden, part seen.
            if (exact > 1e-12 * open && exact < (1.0 - 1e-12) * open) {
                raysPenumbra += e.counts.shadowRays();
                ++penumbraPoints;
            }
        }
        if (rays) *rays = double(raysPenumbra) / std::max<uint64_t>(1, penumbraPoints);
        return err / unocc;  // mean error relative to the mean unoccluded form factor
    };
    double raysDefault = 0.0;
    const double e23 = meanError(2, 3, nullptr);
    const double e25 = meanError(2, 5, &raysDefault);
    const double e27 = meanError(2, 7, nullptr);
    const double e45 = meanError(4, 5, nullptr);
    const double e47 = meanError(4, 7, nullptr);
    INFO("relative mean errors: 2/3 " << e23 << ", 2/5 " << e25 << ", 2/7 " << e27 << ", 4/5 "
                                      << e45 << ", 4/7 " << e47 << "; rays at 2/5 " << raysDefault);
    // Since the strip threshold with coverage is a sixteenth of the paper's, 3 steps refine to
    // the default's accuracy on this line (measured 0.0409% at 2/3 and 0.0415% at 2/5): fewer
    // steps must not be better beyond noise, more must be.
    CHECK(e25 < 1.05 * e23);
    CHECK(e27 < e25);
    // At 4 x 4 squares both step counts sit at the floor of about 0.01% (measured 0.0092% and
    // 0.0093%): more steps must not make it worse beyond noise.
    CHECK(e47 < 1.05 * e45);
    CHECK(e47 < e27);
    // Defaults (2 x 2 squares, 5 steps): within 0.5% of the unoccluded form factor on average
    // over the line, which is the benchmark's target for penumbra points as well.
    // Rays: at most 32 per penumbra point, measured 30.2 (17.0 while coverage took a disc that
    // excludes every obstacle but the contour's own as proof within half a first-level square
    // of a located contour, which missed a capsule's thin shadow reaching past its piece: see
    // test_coverage.cpp; coverage now proves the ground next to a contour with full discs,
    // or leaves it to the bound within coverageGap of the piece's strip). Penumbra points are
    // those the exact answer puts there.
    CHECK(e25 < 0.003);          // measured 0.044% (the "arcs" mode: 0.14%)
    CHECK(raysDefault <= 32.0);
}

TEST_CASE("analytic sphere: defaults stay within a bounded error at every point", "[aci]") {
    const RectLight light = testLight();
    Occluder occ({AnalyticSphere{kSphereCenter, kSphereRadius}});
    Occluder::Query query = occ.makeQuery();
    ContourIntegrator aci;
    for (const Receiver& r : penumbraLine(200)) {
        const Estimate e = aci.evaluate(r, light, query);
        const double exactF = exactSphere(r, light);
        // A strip one final dichotomy interval wide (1/64 of the light's edge at the
        // defaults) along the light's perimeter is 6.25% of its area; the estimator's chords
        // stay inside it. (The paper's method cannot do better in the worst case: a visible
        // sliver between two hidden first-level corners goes unseen. The worst case on this
        // line is 3.6% at x = 1.05; the mean is in the test above.)
        INFO("x = " << r.point.x << " exact " << exactF << " aci " << e.formFactor);
        CHECK(std::abs(e.formFactor - exactF) < 0.0625 * unoccludedFormFactor(light, r));
    }
}

// Checks the gradient at the penumbra points of the test line against central differences of
// the exact sphere's form factor; returns how many points it checked and, in `answered`, the
// lattice samples the footprints and kernels answered without a ray there.
static int checkGradientLine(const Occluder& occ, uint64_t& answered) {
    const RectLight light = testLight();
    Occluder::Query query = occ.makeQuery();
    AciSettings s;
    s.steps = 7;  // the gradient of a coarse polygon is coarse too; check the method, finely
    ContourIntegrator aci(s);
    int checked = 0;
    answered = 0;
    for (const Receiver& r : penumbraLine(40)) {
        // Lit or umbra: no contour inside.
        const double exactF = exactSphere(r, light);
        if (!(exactF > 0.0 && exactF < unoccludedFormFactor(light, r) * (1.0 - 1e-9))) continue;
        const Estimate e = aci.evaluate(r, light, query);
        answered += e.counts.footprintSamples;
        const double h = 1e-4;
        Vec3 fd;
        for (int k = 0; k < 3; ++k) {
            Receiver a = r, b = r;
            a.point[k] += h;
            b.point[k] -= h;
            fd[k] = (exactSphere(a, light) - exactSphere(b, light)) / (2 * h);
        }
        const double scale = std::max(glm::length(fd), 1e-3);
        INFO("x = " << r.point.x << " aci grad " << e.gradient.x << "," << e.gradient.y << ","
                    << e.gradient.z << " fd " << fd.x << "," << fd.y << "," << fd.z);
        // The 3D contour points are the first hits of rays just inside the silhouette, which
        // lie up to sqrt(2 R delta) in front of the true tangent points (delta: the final
        // interval at the obstacle); that depth error, a few percent here, carries into the
        // gradient. 8% bounds it on this line (the worst seen is 5.7%). A level set's own
        // shadow, about 0.2 voxel of radius smaller at most (tests/test_level_set_bias.cpp),
        // stays well inside it.
        CHECK(glm::length(e.gradient - fd) < 0.08 * scale);
        ++checked;
    }
    return checked;
}

TEST_CASE("the gradient agrees with finite differences of the exact form factor", "[aci][gradient]") {
    uint64_t answered = 0;
    CHECK(checkGradientLine(Occluder({AnalyticSphere{kSphereCenter, kSphereRadius}}), answered) >= 10);
}

TEST_CASE("a level-set sphere's gradient agrees with finite differences of the exact form factor",
          "[aci][gradient][levelset]") {
    // Its kernel balls (from the far-field companion) hide samples without a ray, whose hit
    // fraction is then only the ball's entry: a vertex takes its 3D point from a grazing ray's
    // closest approach, or else from the hidden end's hit traced then (Lattice::hitFraction).
    Occluder occ({makeSphereLevelSet(kSphereCenter, kSphereRadius, 0.02, 3.0)});
    occ.prepareClearance();
    REQUIRE_FALSE(occ.kernelBalls(0).empty());
    CHECK(occ.kernelBalls(0).front().radius > 0.8 * kSphereRadius);
    uint64_t answered = 0;
    CHECK(checkGradientLine(occ, answered) >= 10);
    CHECK(answered > 0);
}

TEST_CASE("a box corner inside a square triggers the refinement of section 3.2", "[aci]") {
    const RectLight light = testLight();
    const AnalyticBox box{Vec3(-0.35, -0.25, 1.6), Vec3(0.25, 0.35, 2.2)};
    std::vector<Vec3> vertices;
    for (int i = 0; i < 8; ++i)
        vertices.push_back(Vec3(i & 1 ? box.hi.x : box.lo.x, i & 2 ? box.hi.y : box.lo.y,
                                i & 4 ? box.hi.z : box.lo.z));
    Occluder occ({box});
    Occluder::Query query = occ.makeQuery();
    // The section 3.2 check and refinement, with the rays the paper spends ("arcs": the paper's
    // bisection and checks; the default tangent mode seldom needs to refine, see below).
    AciSettings paper;
    applyAciMode(paper, AciMode::Arcs);
    AciSettings plain = paper;
    plain.refine = false;
    ContourIntegrator refined(paper), unrefined(plain);
    double errRefined = 0.0, errPlain = 0.0, unocc = 0.0;
    uint64_t refinedSquares = 0;
    int points = 0;
    for (const Receiver& r : penumbraLine(150, -2.5, 2.5)) {
        const double exactF = exact::convexPolyhedronShadowFormFactor(
            r.point, r.normal, light.corner, light.edgeU, light.edgeV, vertices);
        const Estimate a = refined.evaluate(r, light, query);
        const Estimate b = unrefined.evaluate(r, light, query);
        if (a.counts.secondLevelRays == 0) continue;
        ++points;
        refinedSquares += a.counts.squaresRefined;
        errRefined += std::abs(a.formFactor - exactF);
        errPlain += std::abs(b.formFactor - exactF);
        unocc += unoccludedFormFactor(light, r);
        INFO("x = " << r.point.x);
        CHECK(std::abs(a.formFactor - exactF) < 0.0625 * unoccludedFormFactor(light, r));
    }
    INFO("penumbra points " << points << ", refined squares " << refinedSquares
                            << ", mean relative error refined " << errRefined / unocc
                            << " plain " << errPlain / unocc);
    CHECK(points > 50);
    CHECK(refinedSquares > 0);
    CHECK(errRefined < 0.5 * errPlain);
    CHECK(errRefined / unocc < 0.008);
}

TEST_CASE("tangent mode: a box's corners from the tangent lines, in fewer rays", "[aci][tangent]") {
    // The default mode places each contour vertex by Newton steps on the signed clearance and
    // takes the contour's tangent there from the distance gradient; a box's silhouette corner
    // is where two such tangent lines meet. Against the exact convex-hull shadow, for an
    // analytic box and its level set, it must stay within the paper method's error class
    // (the "arcs" mode here) for far fewer rays.
    const RectLight light = testLight();
    const Vec3 lo(-0.35, -0.25, 1.6), hi(0.25, 0.35, 2.2);
    std::vector<Vec3> vertices;
    for (int i = 0; i < 8; ++i)
        vertices.push_back(Vec3(i & 1 ? hi.x : lo.x, i & 2 ? hi.y : lo.y, i & 4 ? hi.z : lo.z));
    AciSettings arcs;
    applyAciMode(arcs, AciMode::Arcs);
    for (int kind = 0; kind < 2; ++kind) {
        Occluder occ = kind == 0 ? Occluder({AnalyticBox{lo, hi}})
                                 : Occluder({makeBoxLevelSet(lo, hi, 0.01, 3.0)});
        Occluder::Query query = occ.makeQuery();
        ContourIntegrator tangent, paper(arcs);
        double errT = 0.0, errP = 0.0, unocc = 0.0;
        uint64_t raysT = 0, raysP = 0;
        int points = 0;
        for (const Receiver& r : penumbraLine(120, -2.5, 2.5)) {
            const double exactF = exact::convexPolyhedronShadowFormFactor(
                r.point, r.normal, light.corner, light.edgeU, light.edgeV, vertices);
            const double u = unoccludedFormFactor(light, r);
            if (!(exactF > 1e-9 * u && exactF < (1 - 1e-9) * u)) continue;  // penumbra only
            const Estimate t = tangent.evaluate(r, light, query);
            const Estimate p = paper.evaluate(r, light, query);
            ++points;
            errT += std::abs(t.formFactor - exactF);
            errP += std::abs(p.formFactor - exactF);
            raysT += t.counts.shadowRays();
            raysP += p.counts.shadowRays();
            unocc += u;
            INFO("kind " << kind << " x = " << r.point.x);
            CHECK(std::abs(t.formFactor - exactF) < 0.0625 * u);
        }
        INFO((kind == 0 ? "analytic" : "level set") << ": " << points << " penumbra points; "
             << "tangent " << double(raysT) / points << " rays, error " << errT / unocc
             << "; arcs " << double(raysP) / points << " rays, error " << errP / unocc);
        CHECK(points > 60);
        // Measured on this line: analytic 63.6 rays at 0.070%, level set 62.7 at 0.17% (arcs:
        // 76 rays at 0.37% and 0.39%). (43.9 rays at 0.14% and 55.6 at 0.20% with the strip
        // threshold a quarter of the paper's instead of a sixteenth; 20.0 and 17.3 rays while
        // coverage trusted discs that exclude only the other obstacles next to a located
        // contour, see test_coverage.cpp.) Fewer rays than arcs at under half its error.
        // (Analytic 66.2 rays at 0.062% until 2026-12-03, when a long arc whose shoulder ray's
        // tangent turns away from its chord began to be refined: a piece of the silhouette
        // that bends at two of the box's corners is not one conic. Now 69.8 rays at 0.058%,
        // level set 55.4 at 0.18%: under 0.95 of the arcs mode's rays at a sixth of its error.)
        CHECK(errT / unocc < 0.005);
        CHECK(errT < 0.5 * errP);
        CHECK(raysT < 0.95 * raysP);
    }
}

TEST_CASE("tangent mode: a level-set box's edges seen from next to its base", "[aci][tangent]") {
    // Receivers on the ground a little in front of a level-set box (the fog gallery scene's
    // box and tilted light), whose shadow rays graze its top edges: past a sharp edge the
    // clearance's sampled minimum sat above the V's bottom, the gradient there was the average
    // of the two faces' (tilting the tangent lines), and Newton steps from the hidden end, where
    // the depth under an edge comes out shallow, were taken as vertices: up to 2.6% of the
    // unoccluded form factor too bright on the fog scene. Against the exact convex-hull shadow.
    RectLight light;
    light.corner = Vec3(-1.2, -0.9, 4.0);
    light.edgeU = Vec3(0.0, 1.8, 0.3);
    light.edgeV = Vec3(2.4, 0.0, 0.0);
    const Vec3 lo(0.45, -0.75, 0.3), hi(0.96, -0.24, 1.2);  // faces on voxel centres
    std::vector<Vec3> vertices;
    for (int i = 0; i < 8; ++i)
        vertices.push_back(Vec3(i & 1 ? hi.x : lo.x, i & 2 ? hi.y : lo.y, i & 4 ? hi.z : lo.z));
    Occluder occ({makeBoxLevelSet(lo, hi, 0.03, 3.0)});
    Occluder::Query query = occ.makeQuery();
    ContourIntegrator aci;
    double sum = 0.0, worst = 0.0;
    int points = 0;
    for (int j = 0; j < 5; ++j) {
        for (int i = 0; i < 7; ++i) {
            const Receiver r{Vec3(0.2 + 0.2 * i, -0.8 - 0.1 * j, 0.0), kUp};
            const double exactF = exact::convexPolyhedronShadowFormFactor(
                r.point, r.normal, light.corner, light.edgeU, light.edgeV, vertices);
            const double u = unoccludedFormFactor(light, r);
            if (!(exactF > 1e-9 * u && exactF < (1 - 1e-9) * u)) continue;  // penumbra only
            const Estimate e = aci.evaluate(r, light, query);
            const double err = std::abs(e.formFactor - exactF) / u;
            INFO("receiver (" << r.point.x << ", " << r.point.y << "): F/F0 " << e.formFactor / u
                              << ", exact " << exactF / u);
            CHECK(err < 0.008);
            sum += err, worst = std::max(worst, err), ++points;
        }
    }
    INFO(points << " penumbra points: mean error " << sum / points << ", max " << worst);
    CHECK(points >= 30);
    // Measured: mean 0.0023, max 0.0045 (before: mean 0.0128; the analytic box gives 0.0014,
    // the paper's mode 0.0070 on either: every mode cuts a polygon's corners a little).
    CHECK(sum / points < 0.004);
}

TEST_CASE("the shared sample lattice never traces a ray twice, across restarts", "[aci][cache]") {
    const RectLight light = testLight();
    // A box and a thin bar crossing the light's squares make inconsistencies likely.
    Occluder occ({AnalyticBox{Vec3(-0.35, -0.25, 1.6), Vec3(0.25, 0.35, 2.2)},
                  AnalyticBox{Vec3(-2.0, 0.28, 2.5), Vec3(2.0, 0.36, 2.55)},
                  AnalyticSphere{Vec3(0.5, -0.6, 3.0), 0.12}});
    Occluder::Query query = occ.makeQuery();
    std::vector<Vec3> log;
    AciSettings s;
    s.rayLog = &log;
    ContourIntegrator aci(s);
    uint64_t restarts = 0, cacheHits = 0;
    for (const Receiver& r : penumbraLine(300, -2.5, 2.5)) {
        log.clear();
        query.resetCount();
        const Estimate e = aci.evaluate(r, light, query);
        restarts += e.counts.restarts;
        cacheHits += e.counts.cacheHits;
        REQUIRE(log.size() == e.counts.shadowRays());
        REQUIRE(query.raysCast() == e.counts.shadowRays());
        std::set<std::tuple<double, double, double>> unique;
        for (const Vec3& p : log) unique.insert({p.x, p.y, p.z});
        INFO("x = " << r.point.x << " restarts " << e.counts.restarts);
        REQUIRE(unique.size() == log.size());
    }
    INFO("restarts " << restarts << " cache hits " << cacheHits);
    CHECK(restarts > 0);  // the property above was exercised across restarts
    CHECK(cacheHits > 0);
}

TEST_CASE("sphere level set against the exact shadow, within a voxel-derived tolerance",
          "[aci][levelset]") {
    const RectLight light = testLight();
    const double voxel = 0.02;
    Occluder occ({makeSphereLevelSet(kSphereCenter, kSphereRadius, voxel, 3.0)});
    Occluder::Query query = occ.makeQuery();
    ContourIntegrator aci;
    int lit = 0, penumbra = 0, umbra = 0;
    for (const Receiver& r : penumbraLine(60)) {
        const Estimate e = aci.evaluate(r, light, query);
        const double exactF = exactSphere(r, light);
        const double unocc = unoccludedFormFactor(light, r);
        // Voxelization moves the zero crossing by a fraction of a voxel: bound its effect by
        // the exact answers for spheres half a voxel larger and smaller. The estimator's own
        // error is bounded as in the analytic test (6.25% of the unoccluded form factor).
        const double voxelBound = std::abs(exactSphere(r, light, kSphereCenter, kSphereRadius + 0.5 * voxel) -
                                           exactSphere(r, light, kSphereCenter, kSphereRadius - 0.5 * voxel));
        INFO("x = " << r.point.x << " exact " << exactF << " aci " << e.formFactor);
        CHECK(std::abs(e.formFactor - exactF) < voxelBound + 0.0625 * unocc);
        if (exactF == Approx(unocc).margin(1e-12)) ++lit;
        else if (exactF < 1e-12) ++umbra;
        else ++penumbra;
    }
    CHECK(lit > 0);
    CHECK(penumbra > 10);
    CHECK(umbra > 0);
}

TEST_CASE("tangent mode: a contour ending on the horizon, against a converged reference",
          "[aci][tangent]") {
    // Receivers tilted so that their tangent plane cuts the light while the sphere hides part of
    // it: contour vertices on the horizon take the horizon line as their tangent, and a piece
    // from the sphere's silhouette to the horizon is a corner the tangent lines describe.
    const RectLight light = testLight();
    Occluder occ({AnalyticSphere{kSphereCenter, kSphereRadius}});
    Occluder::Query query = occ.makeQuery();
    ContourIntegrator tangent;
    McSettings mc;
    mc.samples = 1 << 16;  // 256 x 256 strata: converged far below the tolerance
    mc.rayOffset = 1e-9;
    int compared = 0;
    double err = 0.0, unocc = 0.0;
    for (int i = 0; i < 24; ++i) {
        const double x = -1.2 + 2.4 * i / 23.0;
        const Vec3 n = glm::normalize(Vec3(0.9, 0.3 * std::sin(3.0 * x), 0.35));
        const Receiver r{Vec3(x, 0.3, 0.4), n};
        const double u = unoccludedFormFactor(light, r);
        if (!(u > 0.0)) continue;
        const Estimate t = tangent.evaluate(r, light, query);
        const Estimate ref = monteCarloReference(r, light, query, mc);
        INFO("x = " << x << " tangent " << t.formFactor << " reference " << ref.formFactor
                    << " unoccluded " << u << " rays " << t.counts.shadowRays());
        CHECK(std::abs(t.formFactor - ref.formFactor) < 0.02 * u);
        err += std::abs(t.formFactor - ref.formFactor);
        unocc += u;
        ++compared;
    }
    INFO("mean error " << err / unocc);
    CHECK(compared >= 20);
    CHECK(err / unocc < 0.005);
}
