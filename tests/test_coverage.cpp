// Certified coverage (AciSettings::coverage, the default tangent mode): shadows and windows
// that touch no first-level corner are found, and every answer comes with an error bound that
// holds. Exact references: exact::rectMinusObstacles (tests/support/exact_shadow.h), independent of the
// library.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "contour_lattice.h"
#include "support/exact_shadow.h"
#include "support/paper_scene.h"
#include "penumbra/contour_integrator.h"
#include "penumbra/monte_carlo.h"
#include "penumbra/renderer.h"
#include "penumbra/scene.h"

using namespace penumbra;

namespace {

const Vec3 kUp(0, 0, 1);

AciSettings modeSettings(AciMode mode) {
    AciSettings s;
    applyAciMode(s, mode);
    return s;
}

double exactSpheres(const Receiver& r, const RectLight& l,
                    const std::vector<AnalyticSphere>& spheres) {
    std::vector<exact::SphereObstacle> s;
    for (const AnalyticSphere& a : spheres) s.push_back({a.center, a.radius});
    return exact::rectMinusObstacles(r.point, r.normal, l.corner, l.edgeU, l.edgeV, s);
}

// Where a sphere's shadow falls on the light's plane seen from m: the centre of the cone's
// section (approximately: the axis' crossing) and its radius (the cone's half-angle at the
// light's distance along the axis), in light coordinates (u, v) in [0, 1]^2.
struct ShadowDisc {
    double u, v, radius;  // radius in light units (fractions of the edge)
};
ShadowDisc shadowOnLight(const Vec3& m, const RectLight& l, const AnalyticSphere& s) {
    const Vec3 n = l.normal();
    const Vec3 d = s.center - m;
    const double t = glm::dot(l.corner - m, n) / glm::dot(d, n);
    const Vec3 hit = m + t * d;
    const Vec2 uv = exact::lightCoords(hit, l.corner, l.edgeU, l.edgeV);
    const double dist = glm::length(hit - m);
    const double half = std::asin(s.radius / glm::length(d));
    return {uv.x, uv.y, dist * std::tan(half) / glm::length(l.edgeU)};
}

// Whether no corner of the p x p first-level grid lies within the disc (or `margin` of it), the
// disc being wholly on the light: then the paper's first level cannot see the shadow.
bool holdsNoCorner(const ShadowDisc& d, int p, double margin) {
    if (d.u - d.radius < 0.0 || d.u + d.radius > 1.0 || d.v - d.radius < 0.0 ||
        d.v + d.radius > 1.0)
        return false;
    for (int i = 0; i <= p; ++i)
        for (int j = 0; j <= p; ++j)
            if (std::hypot(d.u - double(i) / p, d.v - double(j) / p) < d.radius + margin)
                return false;
    return true;
}

/// A scene of tests/scenes/ with its occluder (far-field companions built) and a query on it.
/// Not copyable: the query points at the occluder.
struct SceneUnderTest {
    explicit SceneUnderTest(const std::string& file)
        : scene(loadScene(std::string(PENUMBRA_SOURCE_DIR) + "/tests/scenes/" + file)),
          occ(scene.makeOccluder()),
          q((occ.prepareClearance(), occ.makeQuery())) {}
    SceneUnderTest(const SceneUnderTest&) = delete;
    SceneUnderTest& operator=(const SceneUnderTest&) = delete;

    Scene scene;
    Occluder occ;
    Occluder::Query q;
};

// The default estimate at a receiver that may sit on an obstacle (its own ray offset), and a
// Monte Carlo reference of `samples` rays with its standard deviation.
struct AgainstMonteCarlo {
    Estimate aci;
    double ref, full, sigma;
};
AgainstMonteCarlo againstMonteCarlo(const Occluder& occ, Occluder::Query& q, const RectLight& light,
                                    const Receiver& r, int samples = 1 << 16) {
    AciSettings s;
    s.gradient = false;
    s.rayOffset = receiverRayOffset(occ, r.point, 1e-9);
    McSettings mc;
    mc.samples = samples;
    mc.rayOffset = s.rayOffset;
    ContourIntegrator aci(s);
    AgainstMonteCarlo out;
    out.aci = aci.evaluate(r, light, q);
    out.ref = monteCarloSolidAngle(r, light, q, mc).formFactor;
    out.full = unoccludedFormFactor(light, r);
    const double frac = std::clamp(out.ref / out.full, 0.0, 1.0);
    out.sigma = out.full * std::sqrt(frac * (1.0 - frac) / mc.samples);
    return out;
}

// The estimate within `share` of F0 of the reference and within its own bound, each up to four
// of the reference's standard deviations.
void checkNearReference(const AgainstMonteCarlo& m, double share) {
    CHECK(std::abs(m.aci.formFactor - m.ref) <= share * m.full + 4.0 * m.sigma);
    CHECK(std::abs(m.aci.formFactor - m.ref) <= m.aci.errorBound + 4.0 * m.sigma);
}

// The default evaluation at r against the same estimator `extraSteps` dichotomy steps finer
// (a converged reference where Monte Carlo would need millions of rays), and the unoccluded F.
struct AgainstFiner {
    Estimate aci;
    double ref = 0.0, full = 0.0;
};
AgainstFiner againstFiner(const Occluder& occ, Occluder::Query& q, const RectLight& light,
                          const Receiver& r, int extraSteps) {
    AciSettings s;
    s.gradient = false;
    s.rayOffset = receiverRayOffset(occ, r.point, 1e-9);
    AciSettings fine = s;
    fine.steps = s.steps + extraSteps;
    AgainstFiner out;
    out.aci = ContourIntegrator(s).evaluate(r, light, q);
    out.ref = ContourIntegrator(fine).evaluate(r, light, q).formFactor;
    out.full = unoccludedFormFactor(light, r);
    return out;
}

}  // namespace

TEST_CASE("coverage: a small shadow inside one first-level square, touching no corner",
          "[aci][coverage]") {
    // Two spheres under a 2 x 2 light at height 4 (the configuration users reported): at the
    // points below, the small high one's shadow on the light holds no first-level corner.
    const RectLight light = test::paperLight();
    const std::vector<AnalyticSphere> spheres = {{Vec3(-0.5, -0.3, 1.8), 0.45},
                                                 {Vec3(0.35, 0.3, 2.5), 0.25}};
    Occluder occ({spheres[0], spheres[1]});
    Occluder::Query q = occ.makeQuery();
    int found = 0;
    double worstDefault = 0.0, worstPaper = 0.0;
    for (int i = 0; i < 81; ++i) {
        for (int j = 0; j < 81; ++j) {
            const Receiver r{Vec3(-2.0 + 0.05 * i, -2.0 + 0.05 * j, 0.0), kUp};
            if (!holdsNoCorner(shadowOnLight(r.point, light, spheres[1]), 2, 0.02)) continue;
            ++found;
            const double exact = exactSpheres(r, light, spheres);
            const double full = unoccludedFormFactor(light, r);
            const Estimate def = contourIntegral(r, light, q);
            const Estimate pap = contourIntegral(r, light, q, modeSettings(AciMode::Paper));
            const double e = std::abs(def.formFactor - exact);
            CAPTURE(r.point.x, r.point.y, exact, def.formFactor, pap.formFactor, def.errorBound);
            CHECK(e <= def.errorBound);
            // The issue's target, 0.5% of the unoccluded form factor (the paper's method is off
            // by up to 12% here).
            CHECK(e <= 0.005 * full);
            worstDefault = std::max(worstDefault, e / full);
            worstPaper = std::max(worstPaper, std::abs(pap.formFactor - exact) / full);
        }
    }
    REQUIRE(found >= 5);
    // The configuration does hide a whole shadow from the paper's nine first-level rays.
    CHECK(worstPaper > 0.05);
    CHECK(worstDefault < 0.005);
}

TEST_CASE("coverage: a window between four obstacles' shadows inside a hidden first-level square",
          "[aci][coverage][footprint]") {
    // A square frame of four analytic boxes halfway to the light: their shadows on the light
    // hide the first-level square [0, 1] x [0, 1] all round, its four corners too, and leave a
    // window about [0.3, 0.7] x [0.3, 0.7] in its middle, outside every obstacle's footprint.
    // The pass sees a hidden square; coverage's rays around the window find it. (The
    // footprints prove the window visible, but a cell they prove counts as covered only where
    // the contour says visible too: a window no ray has seen is not covered ground.)
    const RectLight light = test::paperLight();
    const double z0 = 1.95, z1 = 2.05;
    Occluder occ({AnalyticBox{Vec3(-0.05, -0.05, z0), Vec3(0.55, 0.15, z1)},
                  AnalyticBox{Vec3(-0.05, 0.35, z0), Vec3(0.55, 0.55, z1)},
                  AnalyticBox{Vec3(-0.05, 0.15, z0), Vec3(0.15, 0.35, z1)},
                  AnalyticBox{Vec3(0.35, 0.15, z0), Vec3(0.55, 0.35, z1)}});
    Occluder::Query q = occ.makeQuery();
    const Receiver r{Vec3(0.0, 0.0, 0.0), kUp};
    McSettings mc;
    mc.samples = 1 << 18;
    const double ref = monteCarloReference(r, light, q, mc).formFactor;
    const double full = unoccludedFormFactor(light, r);
    const Estimate e = contourIntegral(r, light, q);
    const Estimate paper = contourIntegral(r, light, q, modeSettings(AciMode::Paper));
    CAPTURE(ref, full, e.formFactor, e.errorBound, paper.formFactor);
    // The paper's nine rays miss the window (about 4% of the light's form factor).
    CHECK(paper.formFactor < ref - 0.02 * full);
    // Within the reference's noise (2^18 rays: under 0.1% of the unoccluded form factor).
    CHECK(std::abs(e.formFactor - ref) <= e.errorBound + 0.001 * full);
    CHECK(std::abs(e.formFactor - ref) <= 0.005 * full);
}

TEST_CASE("coverage: a torus' window inside a hidden first-level square", "[aci][coverage]") {
    // A level-set torus seen from below: its hole is a window of light inside its shadow whose
    // disc on the light holds no first-level corner (the four corners around it are hidden).
    // The receiver (0, 0, 0) looks at light point (0.5, 0.5, 4) through the torus' centre.
    const std::string json = R"({
      "lights": [{"corner": [-1, -1, 4], "edge_u": [0, 2, 0], "edge_v": [2, 0, 0]}],
      "obstacles": [{"type": "torus", "center": [0.25, 0.25, 2], "major_radius": 0.3,
                     "minor_radius": 0.12, "axis": [0.125, 0.125, 2]}],
      "level_set": {"voxel_size": 0.01, "half_width": 3}
    })";
    const Scene scene = parseScene(json, "torus.json", ".");
    const Occluder occ = scene.makeOccluder();
    occ.prepareClearance();
    Occluder::Query q = occ.makeQuery();
    const RectLight& light = scene.lights[0];
    const Receiver r{Vec3(0, 0, 0), kUp};
    AciSettings s;
    s.rayOffset = 1e-6;
    const Estimate def = contourIntegral(r, light, q, s);
    AciSettings paperSettings = modeSettings(AciMode::Paper);
    paperSettings.rayOffset = 1e-6;
    const Estimate pap = contourIntegral(r, light, q, paperSettings);
    McSettings mc;
    mc.samples = 1 << 16;
    mc.rayOffset = 1e-6;
    const double ref = monteCarloReference(r, light, q, mc).formFactor;
    const double full = unoccludedFormFactor(light, r);
    CAPTURE(ref, def.formFactor, pap.formFactor, def.errorBound, full);
    // The window is there and the paper's nine first-level rays do not see it (all hidden): the
    // paper's answer misses a large part of it.
    REQUIRE(ref > 0.05 * full);
    CHECK(std::abs(pap.formFactor - ref) > 0.05 * full);
    // Stratified 65,536 rays: standard error well under 0.2% of the unoccluded form factor.
    CHECK(std::abs(def.formFactor - ref) <= 0.01 * full);
    CHECK(std::abs(def.formFactor - ref) <= def.errorBound + 0.002 * full);
}

namespace {

// Errors and bounds (relative to the unoccluded form factor) of the default estimator at 200
// receiver points over 20 random scenes of 1 to 8 spheres with radii from 2% of the light's
// edge to 40% of it, anywhere between the receiver plane and the light.
struct RandomSpheres {
    std::vector<double> errors, bounds;
    double worst = 0.0, mean = 0.0;
    int violations = 0;  // points whose error exceeds the reported bound
    int coarser = 0;     // evaluations that took one step fewer (AciSettings::adaptiveSteps)
    double median(std::vector<double> v) const {
        std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
        return v[v.size() / 2];
    }
};

// `light`: horizontal at height 4 over the origin (the paper's 2 x 2 by default). The scenes are
// drawn for the paper's light and carried to `light` by the map that takes the one to the other
// (the identity for the paper's: the same points as before the parameter existed).
RandomSpheres randomSpheres(uint32_t seed, const AciSettings& settings = AciSettings{},
                            const RectLight& light = test::paperLight()) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u01(0.0, 1.0);
    const double scale = 0.25 * (glm::length(light.edgeU) + glm::length(light.edgeV));
    const Vec3 centre = light.corner + 0.5 * light.edgeU + 0.5 * light.edgeV;
    auto carry = [&](const Vec3& p) {  // the paper's light: edgeU along y, edgeV along x
        const Vec3 q = centre + (0.5 * p.y) * light.edgeU + (0.5 * p.x) * light.edgeV;
        return Vec3(q.x, q.y, p.z);
    };
    RandomSpheres out;
    double sum = 0.0;
    for (int scene = 0; scene < 20; ++scene) {
        const int count = 1 + scene % 8;
        std::vector<AnalyticSphere> spheres;
        for (int k = 0; k < count; ++k) {
            const double radius = 2.0 * (0.02 + 0.38 * std::pow(u01(rng), 2.0));
            const double z = 0.5 + radius + (3.5 - 2.0 * radius - 0.5) * u01(rng);
            spheres.push_back({carry(Vec3(-1.2 + 2.4 * u01(rng), -1.2 + 2.4 * u01(rng), z)),
                               scale * radius});
        }
        Occluder occ;
        for (const AnalyticSphere& s : spheres) occ.add(s);
        Occluder::Query q = occ.makeQuery();
        for (int k = 0; k < 10; ++k) {
            const Receiver r{carry(Vec3(-2.0 + 4.0 * u01(rng), -2.0 + 4.0 * u01(rng), 0.0)), kUp};
            const double exact = exactSpheres(r, light, spheres);
            const double full = unoccludedFormFactor(light, r);
            const Estimate e = contourIntegral(r, light, q, settings);
            const double err = std::abs(e.formFactor - exact);
            if (err > e.errorBound + 1e-12) ++out.violations;
            out.coarser += int(e.counts.coarserEvaluations);
            out.worst = std::max(out.worst, err / full);
            sum += err / full;
            out.errors.push_back(err / full);
            out.bounds.push_back(e.errorBound / full);
        }
    }
    out.mean = sum / double(out.errors.size());
    return out;
}

}  // namespace

TEST_CASE("coverage: random scenes of analytic spheres, every error within its bound",
          "[aci][coverage]") {
    const RandomSpheres r = randomSpheres(20261126);
    const double medianError = r.median(r.errors), medianBound = r.median(r.bounds);
    CAPTURE(r.worst, r.mean, medianError, medianBound);
    WARN("random spheres: max error " << r.worst * 100 << "%, mean " << r.mean * 100
                                      << "%, median error " << medianError * 100
                                      << "%, median bound " << medianBound * 100 << "%");
    CHECK(r.violations == 0);
    // The issue's targets: max 0.5% of the unoccluded form factor, mean 0.05%. Measured at this
    // commit: max 0.41%, mean 0.033% (the paper's method on the same points: max 16.9%, mean
    // 1.03%).
    CHECK(r.worst <= 0.005);
    CHECK(r.mean <= 0.0005);
}

TEST_CASE("coverage: random sphere scenes from five more seeds", "[aci][coverage]") {
    // 1,000 more points from five other seeds. Seeds 2, 3, 5 and 7 showed the failures fixed
    // at this commit (a far Newton step taken as a vertex, arcs past the light's border,
    // junctions of two silhouettes, a side crossed three times); seed 11 was only measured.
    int violations = 0;
    double worst = 0.0, meanSum = 0.0;
    const uint32_t seeds[] = {2, 3, 5, 7, 11};
    for (uint32_t seed : seeds) {
        const RandomSpheres r = randomSpheres(seed);
        violations += r.violations;
        worst = std::max(worst, r.worst);
        meanSum += r.mean;
        WARN("seed " << seed << ": max error " << r.worst * 100 << "%, mean " << r.mean * 100
                     << "%, bound violations " << r.violations);
    }
    // Measured at this commit: max 0.44%, mean 0.034%, no bound violated. (Before: a vertex
    // placed differently by two squares of different sizes sharing a side left gaps in the
    // contour; seeds 5, 7 and 17 had points outside their bounds.)
    CHECK(worst <= 0.005);
    CHECK(meanSum / 5.0 <= 0.0005);
    CHECK(violations == 0);
}

TEST_CASE("coverage: adaptive steps (renders' default) keep every error within its bound",
          "[aci][coverage]") {
    // Renders take one step fewer where every obstacle's footprint on the light is wide; the
    // bound is then the coarser lattice's. The same 200 points as the first random-sphere test.
    AciSettings s;
    s.adaptiveSteps = true;
    const RandomSpheres r = randomSpheres(20261126, s);
    CAPTURE(r.worst, r.mean, r.coarser);
    WARN("adaptive steps: " << r.coarser << " of 200 points coarser; max error " << r.worst * 100
                            << "%, mean " << r.mean * 100 << "%");
    CHECK(r.violations == 0);
    // Both kinds occur: spheres of 2% of the light's edge keep the lattice, large ones near the
    // receivers do not.
    CHECK(r.coarser > 20);
    CHECK(r.coarser < 200);
    // Measured at this commit: 167 points coarser, max 0.54%, mean 0.013% (probes keep the
    // lattice and the tests' 0.5%). Renders are held to 1%: 2.6 of 255 units on a fully lit
    // white pixel, under the 6 units renders allow off silhouettes; the mean to the probes' 0.05%.
    CHECK(r.worst <= 0.01);
    CHECK(r.mean <= 0.0005);
}

TEST_CASE("coverage: a finer first-level grid, every error within its bound", "[aci][coverage]") {
    // 6 x 6 first-level squares: coverage's spatial index has 36 buckets (one per square) and
    // corner rays ask for discs of a square's diagonal only, where the default's 2 x 2 grid has
    // four buckets and discs of half the light's diagonal. A final interval of 1/48 of the
    // light's edge (the default's: 1/64); the same targets. Measured at this commit: max
    // 0.19%, mean 0.018%, and the same figures with the index bypassed (every disc and segment
    // scanned).
    AciSettings s;
    s.grid = 6;
    s.steps = 3;
    const RandomSpheres r = randomSpheres(20261128, s);
    CAPTURE(r.worst, r.mean);
    WARN("random spheres, 6 x 6 grid: max error " << r.worst * 100 << "%, mean " << r.mean * 100
                                                  << "%, bound violations " << r.violations);
    CHECK(r.violations == 0);
    CHECK(r.worst <= 0.005);
    CHECK(r.mean <= 0.0005);
}

TEST_CASE("coverage: a long narrow light, first-level squares shaped to it", "[aci][coverage]") {
    // A 3.2 x 0.64 light (5:1) turned 30 degrees about the vertical: 200 random points over 20
    // scenes of 1-8 analytic spheres, exact answers. With a 2 x 2 first level its lattice units
    // are five times longer along the long edge than across it; the aspect-shaped first level
    // (10 x 2) makes them about equal, and its squares about square.
    const double c = std::cos(kPi / 6.0), s = std::sin(kPi / 6.0);
    RectLight light;
    light.edgeU = 3.2 * Vec3(c, s, 0.0);
    light.edgeV = 0.64 * Vec3(s, -c, 0.0);  // cross(edgeU, edgeV) points down: it faces the ground
    light.corner = Vec3(0.0, 0.0, 4.0) - 0.5 * light.edgeU - 0.5 * light.edgeV;
    REQUIRE(firstLevelGrid(light, AciSettings{}) == FirstLevelGrid{10, 2});
    const RandomSpheres shaped = randomSpheres(20261202, AciSettings{}, light);
    AciSettings squareGrid;
    squareGrid.aspectGrid = false;
    const RandomSpheres square = randomSpheres(20261202, squareGrid, light);
    WARN("long light, aspect-shaped first level: max error " << shaped.worst * 100 << "%, mean "
         << shaped.mean * 100 << "%, violations " << shaped.violations << "; 2 x 2: max "
         << square.worst * 100 << "%, mean " << square.mean * 100 << "%, violations "
         << square.violations);
    // Measured at this commit: max 0.10%, mean 0.0086%, against 0.08% and 0.0098% with the
    // 2 x 2 first level. Exact spheres give the tangent construction exact distances, so their
    // vertices are placed well on either lattice; the gain is on other shapes and level sets
    // (the next test case, and bench_random's seed 612 in docs/BENCHMARKS.md). This one holds
    // the anisotropic lattice to the same promises as the square one.
    CHECK(shaped.violations == 0);
    CHECK(shaped.worst <= 0.005);
    CHECK(shaped.mean <= 0.0005);
    CHECK(square.violations == 0);
}

TEST_CASE("the first level's shape follows the light's", "[aci]") {
    RectLight light = test::paperLight();
    AciSettings s;
    CHECK(firstLevelGrid(light, s) == FirstLevelGrid{2, 2});
    light.edgeV *= 0.3;  // 2 x 0.6: 3.3 times longer along edgeU
    CHECK(firstLevelGrid(light, s) == FirstLevelGrid{6, 2});
    light.edgeU *= 0.1;  // 0.2 x 0.6: 3 times longer along edgeV
    CHECK(firstLevelGrid(light, s) == FirstLevelGrid{2, 6});
    light.edgeV *= 100.0;  // 0.2 x 60: at most 8 times
    CHECK(firstLevelGrid(light, s) == FirstLevelGrid{2, 16});
    s.grid = 3;
    CHECK(firstLevelGrid(light, s) == FirstLevelGrid{3, 24});
    // Never past the lattice's limit: 32 x 2^7 = 4096 units already along the shorter edge.
    s.grid = 32;
    s.steps = 6;
    CHECK(firstLevelGrid(light, s) == FirstLevelGrid{32, 32});
    s.aspectGrid = false;
    s.grid = 2;
    CHECK(firstLevelGrid(light, s) == FirstLevelGrid{2, 2});
    // The paper's and the arcs modes keep p x p.
    CHECK(firstLevelGrid(light, modeSettings(AciMode::Paper)) == FirstLevelGrid{2, 2});
    CHECK(firstLevelGrid(light, modeSettings(AciMode::Arcs)) == FirstLevelGrid{2, 2});
}

TEST_CASE("coverage: receivers on an analytic box's face and on an analytic sphere",
          "[aci][coverage]") {
    // Shadow rays from a point on an obstacle's own surface start on it and leave it. Its
    // distance along such a segment is smallest (zero) at the start, which says nothing about
    // any silhouette; taken for one, it put the tangent mode's contour vertices at the receiver
    // itself (random seed 2 of bench_random: a box's top face 2.5% of the light too dark, 15x
    // its bound, and gradients of 1e6). Receivers on a slab's top face and on a ball's upper cap,
    // under small spheres; exact answers from the spheres' caps (the slab and, for the ball's
    // own points, the ball cannot block a ray leaving its surface towards the light).
    const RectLight light = test::paperLight();
    std::mt19937 rng(20261128);
    std::uniform_real_distribution<double> u01(0.0, 1.0);
    AnalyticBox slab;
    slab.lo = Vec3(-3, -3, 0);
    slab.hi = Vec3(3, 3, 0.3);
    const AnalyticSphere ball{Vec3(0.3, -0.2, 1.0), 0.5};
    int violations = 0, points = 0;
    double worst = 0.0, overBound = 0.0;
    for (int scene = 0; scene < 10; ++scene) {
        std::vector<AnalyticSphere> spheres;
        for (int k = 0; k < 1 + scene % 4; ++k) {
            const double radius = 0.05 + 0.25 * u01(rng);
            const double z = 1.8 + radius + (3.5 - 1.8 - 2.0 * radius) * u01(rng);
            spheres.push_back({Vec3(-1.2 + 2.4 * u01(rng), -1.2 + 2.4 * u01(rng), z), radius});
        }
        Occluder occ;
        occ.add(slab);
        occ.add(ball);
        for (const AnalyticSphere& s : spheres) occ.add(s);
        Occluder::Query q = occ.makeQuery();
        for (int k = 0; k < 10; ++k) {
            Receiver r;
            std::vector<AnalyticSphere> blockers = spheres;
            if (k % 2 == 0) {
                r = {Vec3(-2.0 + 4.0 * u01(rng), -2.0 + 4.0 * u01(rng), slab.hi.z), kUp};
                blockers.push_back(ball);
            } else {
                const double theta = 0.35 * std::sqrt(u01(rng)), phi = 2.0 * kPi * u01(rng);
                const Vec3 n(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi),
                             std::cos(theta));
                r = {ball.center + ball.radius * n, n};
            }
            const double exact = exactSpheres(r, light, blockers);
            const double full = unoccludedFormFactor(light, r);
            const Estimate e = contourIntegral(r, light, q);
            const double err = std::abs(e.formFactor - exact);
            CAPTURE(scene, k, r.point, exact, e.formFactor, e.errorBound, full);
            CHECK(std::isfinite(glm::length(e.gradient)));
            CHECK(glm::length(e.gradient) < 100.0);
            if (err > e.errorBound + 1e-12) {
                ++violations;
                overBound = std::max(overBound, err / e.errorBound);
            }
            worst = std::max(worst, err / full);
            ++points;
        }
    }
    WARN("receivers on obstacles: " << points << " points, max error " << worst * 100
                                    << "%, bound violations " << violations
                                    << " (largest error / bound " << overBound << ")");
    // Measured at this commit: max error 0.099% (before: 85%, gradients up to 1.7e6), and one
    // point whose error is 1.10x its bound (2.05e-5 against 1.86e-5, 0.034% of the unoccluded
    // form factor): a point of the slab under the ball, the same without the slab in the scene
    // (a ground receiver), so the bound's per-piece model (docs/estimator.md, Error bound) and
    // not the receiver on an obstacle. Open in issue 11.
    CHECK(violations <= 1);
    CHECK(overBound <= 1.25);
    CHECK(worst <= 0.005);
}

TEST_CASE("coverage: a point whose first ray's disc covers the light needs one ray, one no "
          "obstacle's footprint reaches or one kernel hides none",
          "[aci][coverage]") {
    const RectLight light = test::paperLight();
    Occluder occ({AnalyticSphere{Vec3(0.0, 0.0, 1.2), 0.6}});
    Occluder::Query q = occ.makeQuery();
    // Far to the side: the sphere's footprint on the light (its shadow cone) misses the light.
    const Receiver lit{Vec3(-6.0, 6.0, 0.0), kUp};
    const Estimate a = contourIntegral(lit, light, q);
    CHECK(a.counts.shadowRays() == 0);
    CHECK(a.formFactor == Approx(unoccludedFormFactor(light, lit)).margin(1e-12));
    CHECK(a.errorBound == 0.0);
    // Right under the sphere: the sphere (its own kernel) hides all of the light.
    const Receiver umbra{Vec3(0.0, 0.0, 0.0), kUp};
    const Estimate b = contourIntegral(umbra, light, q);
    CHECK(b.counts.shadowRays() == 0);
    CHECK(b.formFactor == Approx(0.0).margin(1e-12));
    CHECK(b.errorBound == 0.0);
    // The paper's method spends its nine first-level rays on both.
    AciSettings paper;
    applyAciMode(paper, AciMode::Paper);
    CHECK(contourIntegral(lit, light, q, paper).counts.shadowRays() == 9);
    CHECK(contourIntegral(umbra, light, q, paper).counts.shadowRays() == 9);

    // A small light seen whole through a level-set torus' hole: the torus' footprint covers
    // the light, and the ray to its centre, 0.45 from the tube at a quarter of the way,
    // proves a disc that covers it.
    const std::string json = R"({
      "lights": [{"corner": [-0.2, -0.2, 4], "edge_u": [0, 0.4, 0], "edge_v": [0.4, 0, 0]}],
      "obstacles": [{"type": "torus", "center": [0, 0, 1], "major_radius": 0.6,
                     "minor_radius": 0.15, "axis": [0, 0, 1]}],
      "level_set": {"voxel_size": 0.01, "half_width": 3}
    })";
    const Scene scene = parseScene(json, "torus.json", ".");
    const Occluder torus = scene.makeOccluder();
    Occluder::Query tq = torus.makeQuery();
    const Estimate c = contourIntegral(umbra, scene.lights[0], tq);
    CHECK(c.counts.shadowRays() == 1);
    REQUIRE(unoccludedFormFactor(scene.lights[0], umbra) > 0.0);
    CHECK(c.formFactor == Approx(unoccludedFormFactor(scene.lights[0], umbra)).margin(1e-12));
    CHECK(c.errorBound == 0.0);
}

TEST_CASE("coverage: a point that receives nothing has a bound of 0, not none",
          "[aci][coverage]") {
    // Without a ray: behind the light, and below the horizon of a receiver facing away. F is 0
    // exactly there, so is the bound (`probe --error-bound` printed nan for such points until
    // 2026-12-02, as it does for the methods that give no bound).
    const RectLight light = test::paperLight();
    Occluder occ({AnalyticSphere{Vec3(0.0, 0.0, 1.2), 0.6}});
    Occluder::Query q = occ.makeQuery();
    const Receiver behind{light.corner + 0.5 * (light.edgeU + light.edgeV) - light.normal(), kUp};
    const Receiver facingAway{Vec3(0.0, 0.0, 0.0), -kUp};
    for (const Receiver& r : {behind, facingAway}) {
        const Estimate e = contourIntegral(r, light, q);
        CAPTURE(r.point, r.normal);
        CHECK(e.counts.shadowRays() == 0);
        CHECK(e.formFactor == 0.0);
        CHECK(e.errorBound == 0.0);
    }
    // The paper's mode gives no bound anywhere.
    AciSettings paper;
    applyAciMode(paper, AciMode::Paper);
    CHECK(std::isnan(contourIntegral(behind, light, q, paper).errorBound));
}

TEST_CASE("coverage: a thin shadow reaching past its located contour piece (random scene 5)",
          "[aci][coverage]") {
    // tests/scenes/random_seed5.json is bench_random's scene for seed 5 (bench/bench_random.cpp).
    // From the first point a capsule's shadow is a thin sliver on the light that holds the
    // middle first-level corner and runs some 30 lattice units into the square beyond it: the
    // contour found cuts off the corner, and coverage once took the sliver for proven (a disc
    // that excludes every obstacle but the capsule, within half a square of the capsule's
    // located contour): 1.9% of the form factor off at 1.3 times the reported bound. From the
    // second, two squares of different sizes once took different vertices on the side they
    // share, and the open contour came out at 85% of the unoccluded form factor too bright,
    // at 6 times the bound. Reference: Monte Carlo with 2^16 rays, allowed four of its standard
    // deviations besides the bound.
    SceneUnderTest t("random_seed5.json");
    const Scene& scene = t.scene;
    const Occluder& occ = t.occ;
    Occluder::Query& q = t.q;
    const RectLight& light = scene.lights.at(0);
    for (const Vec3 p : {Vec3(-0.634085, 2.267012, 0.0), Vec3(0.888946, 3.930314, 0.0)}) {
        const Receiver r{p, kUp};
        const AgainstMonteCarlo m = againstMonteCarlo(occ, q, light, r);
        const Estimate& e = m.aci;
        const double ref = m.ref, full = m.full, sigma = m.sigma;
        INFO("point " << p.x << ", " << p.y << ": aci " << e.formFactor << " bound " << e.errorBound
                      << ", reference " << ref << " (sigma " << sigma << "), unoccluded " << full);
        CHECK(std::abs(e.formFactor - ref) <= e.errorBound + 4.0 * sigma);
    }
}

TEST_CASE("coverage: the light through a torus' hole from 0.007 under it (random scene 5)",
          "[aci][coverage]") {
    // The ground point that pixel (302, 416) of random scene 5 at 800 x 800 sees through the
    // hole of a level-set torus resting 0.007 above the plane. Every certified disc from there
    // is tiny: coverage's 48 rays ran out with nearly all of the light unproven, and the window
    // the first-level corners caught only in part came out 40% short (F 0.00934 against
    // 0.01562, within its bound of 0.05; 15.8 units in the picture). The evaluation now
    // restarts once one level deeper when that happens (kEscalateUnproven). Reference: Monte
    // Carlo with 2^16 rays; allowed 2% of the unoccluded form factor and four of its standard
    // deviations (the error before: 11% of it).
    SceneUnderTest t("random_seed5.json");
    const Scene& scene = t.scene;
    const Occluder& occ = t.occ;
    Occluder::Query& q = t.q;
    const Receiver r{Vec3(-0.296925111, -0.996897833, 0.0), kUp};
    const AgainstMonteCarlo m = againstMonteCarlo(occ, q, scene.lights.at(0), r);
    INFO("aci " << m.aci.formFactor << " bound " << m.aci.errorBound << ", reference " << m.ref
                << " (sigma " << m.sigma << "), unoccluded " << m.full);
    checkNearReference(m, 0.02);
}

TEST_CASE("no tangent lines from surface a few voxels' magnification off: the bunny's back",
          "[aci][coverage]") {
    // Pixel (391, 249) of vdb_scenes/bunny.json at 800 x 800: a point on the bunny's back, part
    // of the light hidden by its own head close by. Rays grazing that near surface, where one
    // voxel spans 4-16 lattice units on the light, gave tangent lines that put the contour off:
    // F 0.04684 against 0.04936 (5% low, 7 units in the picture, within its bound of 0.007;
    // the paper's and arcs modes, and the default with tangents off, were right). Such rays
    // give no tangent since kMagnifiedVoxel went from 16 to 4. Reference: Monte Carlo with
    // 2^16 rays; allowed 1% of the unoccluded form factor and four of its standard deviations
    // (the error before: 4.7% of it).
    const Scene scene = loadScene(std::string(PENUMBRA_SOURCE_DIR) + "/vdb_scenes/bunny.json");
    const Occluder occ = scene.makeOccluder();
    occ.prepareClearance();
    Occluder::Query q = occ.makeQuery();
    const Receiver r{Vec3(-0.0446189, 0.028310916, 0.992047638),
                     glm::normalize(Vec3(0.377605427, -0.644861672, 0.664505505))};
    const AgainstMonteCarlo m = againstMonteCarlo(occ, q, scene.lights.at(0), r);
    INFO("aci " << m.aci.formFactor << " bound " << m.aci.errorBound << ", reference " << m.ref
                << " (sigma " << m.sigma << "), unoccluded " << m.full);
    checkNearReference(m, 0.01);
}

namespace {

// The default estimator at a ground point of vdb_scenes/bunny.json with `steps` dichotomy steps
// (with adaptive steps, as renders take them), against the same estimator at n = 6 on the finer
// lattice throughout.
struct BunnyGround {
    Estimate aci;
    double ref = 0.0, full = 0.0;
};

BunnyGround bunnyGround(const Vec3& point, int steps, bool adaptive) {
    const Scene scene = loadScene(std::string(PENUMBRA_SOURCE_DIR) + "/vdb_scenes/bunny.json");
    const Occluder occ = scene.makeOccluder();
    occ.prepareClearance();
    Occluder::Query q = occ.makeQuery();
    const RectLight& light = scene.lights.at(0);
    const Receiver r{point, kUp};
    AciSettings s;
    s.gradient = false;
    s.rayOffset = receiverRayOffset(occ, r.point, 1e-9);
    s.steps = steps;
    s.adaptiveSteps = adaptive;
    AciSettings fine = s;
    fine.steps = 6;
    fine.adaptiveSteps = false;
    BunnyGround g;
    g.aci = ContourIntegrator(s).evaluate(r, light, q);
    g.ref = ContourIntegrator(fine).evaluate(r, light, q).formFactor;
    g.full = unoccludedFormFactor(light, r);
    return g;
}

}  // namespace

TEST_CASE("tangent arcs on a thin triangle are probed over the chord's middle too (the bunny's ground)",
          "[aci][coverage]") {
    // Pixel (60, 127) of vdb_scenes/bunny.json at 200 x 200: a ground point beside the bunny,
    // whose renders take the coarser lattice (n = 4; the bunny is wide on the light). One piece
    // ran 32 lattice units with its tangent lines meeting beside one end: a thin tangent
    // triangle, whose arc was probed only beside the parabola's middle, near that end, while the
    // bunny's bumpy silhouette left the triangle over the chord's other half, a lattice unit
    // deep. F came out 0.0074263 against 0.0066633 two steps finer (1.7% of the unoccluded F,
    // 2.2 of 255 in the picture, within its bound of 0.0104); probed over the chord's middle
    // too, 0.0070036. Reference: the same estimator at n = 6 (within 4e-6 of 262,144 rays).
    const BunnyGround g = bunnyGround(Vec3(-0.517365653, -0.370327857, 0.0), 4, false);
    CAPTURE(g.aci.formFactor, g.aci.errorBound, g.ref, g.full);
    CHECK(std::abs(g.aci.formFactor - g.ref) <= g.aci.errorBound);
    CHECK(std::abs(g.aci.formFactor - g.ref) <= 0.01 * g.full);
}

TEST_CASE("on the coarser lattice a long hyperbolic arc is probed over its chord's thirds (the bunny's foot)",
          "[aci][coverage]") {
    // Pixel (86, 139) of vdb_scenes/bunny.json at 200 x 200: a ground point in front of the
    // bunny, whose render takes the coarser lattice (adaptive steps: n = 4 for the asked 5). One
    // piece ran 33 lattice units across a first-level square, its arc a hyperbola (w = 3.5)
    // through the shoulder ray, while the bumpy silhouette turned twice between its ends and ran
    // up to 6 units outside the arc two thirds of the way along: F came out 0.025704 against
    // 0.026349 from 262,144 rays (2.4% of F too dark, within its bound of 0.0138). Probed
    // beside the chord's thirds too, and with the coarser lattice's halved strip threshold,
    // 0.026339. Reference: the same estimator at n = 6 on the finer lattice throughout.
    const BunnyGround g = bunnyGround(Vec3(-0.002349156, -0.533576457, 0.0), 5, true);
    REQUIRE(g.aci.counts.coarserEvaluations == 1);  // the case under test
    CAPTURE(g.aci.formFactor, g.aci.errorBound, g.ref, g.full);
    CHECK(std::abs(g.aci.formFactor - g.ref) <= g.aci.errorBound);
    CHECK(std::abs(g.aci.formFactor - g.ref) <= 0.001 * g.full);
}

TEST_CASE("coverage: a vertex that a neighbour's finer samples contradict (random scene 6)",
          "[aci][coverage]") {
    // tests/scenes/random_seed6.json is bench_random's scene for seed 6 (bench/bench_random.cpp);
    // the point is pixel (27, 54) of its 200 x 200 image, far out on the ground, from where the
    // light is seen at a grazing angle and a small obstacle's shadow on it is a long thin streak
    // (1.7% of the form factor). A side of a large square ended its dichotomy on a bracket of
    // several lattice units inside which a smaller neighbour's dichotomy had traced samples;
    // the vertex placed between the bracket's ends disagreed with them, so every pass dropped
    // it and the next placed it again, 64 times, and the contour kept a gap: 28% of the form
    // factor too dark, at 2.7 times the bound. Reference: Monte Carlo with 2^20 rays, allowed
    // four of its standard deviations besides the bound.
    SceneUnderTest t("random_seed6.json");
    const Scene& scene = t.scene;
    const Occluder& occ = t.occ;
    Occluder::Query& q = t.q;
    const Receiver r{Vec3(-3.67137347, 9.35040074, 0.0), kUp};
    const AgainstMonteCarlo m = againstMonteCarlo(occ, q, scene.lights.at(0), r, 1 << 20);
    const Estimate& e = m.aci;
    CAPTURE(e.formFactor, e.errorBound, m.ref, m.sigma, m.full);
    REQUIRE(m.ref < 0.99 * m.full);  // the thin shadow takes 1.7% of the light
    CHECK(std::abs(e.formFactor - m.ref) <= e.errorBound + 4.0 * m.sigma);
    CHECK(std::abs(e.formFactor - m.ref) <= 0.005 * m.full + 4.0 * m.sigma);
}

TEST_CASE("a long narrow light's penumbra, vertices located along its long edge (random scene 612)",
          "[aci][coverage]") {
    // tests/scenes/random_seed612.json is bench_random's scene for seed 612: a 2.86 x 0.61 light
    // tilted 50 degrees. The point is pixel (81, 136) of its 200 x 200 image, on the ground in a
    // penumbra whose edge runs across the light's long edge. With a 2 x 2 first level every
    // vertex on a lattice line along that edge was located to an interval of 4.5 cm, 4.7 times
    // the short edge's, and the estimate came out 0.53% low (inside its bound, and one-signed
    // over that whole penumbra: bench_random's mean difference there was twice Monte Carlo's
    // at equal time over four). The aspect-shaped first level (10 x 2) gives 0.007%.
    // Reference: stratified sampling with 2^18 rays (two seeds agree within 0.001% of F), so the
    // 0.1% allowed is the estimator's.
    SceneUnderTest t("random_seed612.json");
    const RectLight& light = t.scene.lights.at(0);
    REQUIRE(firstLevelGrid(light, AciSettings{}) == FirstLevelGrid{10, 2});
    const Receiver r{Vec3(0.0856727239, 2.32699035, 0.0), kUp};
    AciSettings s;
    s.gradient = false;
    s.rayOffset = receiverRayOffset(t.occ, r.point, 1e-9);
    const Estimate e = contourIntegral(r, light, t.q, s);
    McSettings mc;
    mc.samples = 1 << 18;
    mc.rayOffset = s.rayOffset;
    const double ref = monteCarloReference(r, light, t.q, mc).formFactor;
    const double full = unoccludedFormFactor(light, r);
    CAPTURE(e.formFactor, e.errorBound, ref, full);
    REQUIRE(ref < 0.9 * full);  // in the penumbra
    CHECK(std::abs(e.formFactor - ref) <= 0.001 * ref);
    CHECK(std::abs(e.formFactor - ref) <= e.errorBound);
}

// The default estimate at a ground point of `scene` and a stratified reference of 2^18 rays
// (for these smooth or straight shadow edges on the light, two seeds agree within 0.002% of the
// unoccluded form factor), as fractions of the unoccluded form factor.
struct FieldCase {
    double error, full;
    Estimate aci;
};
FieldCase againstStratified(const Scene& scene, const Occluder& occ, Occluder::Query& q,
                            const Vec3& point) {
    const Receiver r{point, kUp};
    const RectLight& light = scene.lights.at(0);
    AciSettings s;
    s.gradient = false;
    s.rayOffset = receiverRayOffset(occ, r.point, 1e-9);
    FieldCase out;
    out.aci = contourIntegral(r, light, q, s);
    McSettings mc;
    mc.samples = 1 << 18;
    mc.rayOffset = s.rayOffset;
    out.full = unoccludedFormFactor(light, r);
    out.error = (out.aci.formFactor - monteCarloReference(r, light, q, mc).formFactor) / out.full;
    return out;
}

// A ground point of a scene in tests/scenes/: the default's error, relative to the unoccluded
// form factor, against 2^18 stratified rays at most `limit`, and within the default's bound.
void checkGroundPoint(const std::string& file, const Vec3& point, double limit) {
    SceneUnderTest t(file);
    const FieldCase c = againstStratified(t.scene, t.occ, t.q, point);
    CAPTURE(file, c.aci.formFactor, c.aci.errorBound, c.full, c.error);
    CHECK(std::abs(c.error) <= limit);
    CHECK(std::abs(c.error) * c.full <= c.aci.errorBound);
}

TEST_CASE("tangent mode: contour points where a level set's rays find its surface",
          "[aci][coverage]") {
    // Rays see a level set's trilinear zero crossing; the tangent mode's Newton steps
    // extrapolate its sampled distances. Where the two differ, a vertex or a tangent arc's
    // crossing is placed by secant steps on the field's own smallest value along the rays
    // (ContourIntegrator's fieldRoot, Occluder::Query::localMinimum).
    SECTION("a slab's straight edge, where the zero crossing bevels the sharp edge") {
        // Its shadow on the paper's light is bounded by one straight line. With Newton steps
        // alone every lattice finer than 2^5 gave the analytic slab's answer, 0.21% of the
        // unoccluded form factor below the rays' (docs/BENCHMARKS.md, "Seed 605's one-signed
        // difference"); now 0.01%.
        const Scene scene = parseScene(R"({
          "lights": [{"corner": [-1, -1, 4], "edge_u": [0, 2, 0], "edge_v": [2, 0, 0]}],
          "obstacles": [{"type": "box", "center": [1.7, 0.0, 2.0], "size": [3.0, 4.0, 0.3]}],
          "level_set": {"voxel_size": 0.0132, "half_width": 3}
        })", "slab.json", ".");
        const Occluder occ = scene.makeOccluder();
        occ.prepareClearance();
        Occluder::Query q = occ.makeQuery();
        const FieldCase c = againstStratified(scene, occ, q, Vec3(-0.3, 0.1, 0.0));
        CAPTURE(c.aci.formFactor, c.full, c.error);
        CHECK(std::abs(c.error) <= 0.0003);
    }
    SECTION("a torus whose tube is two voxels thick (random scene 605's)") {
        // Check points one lattice step from both ends took the secant of the ends' clearances,
        // up to a third of a diagonal off on this tube, and the parabolas through them cut into
        // its shadow: 0.053% too bright at the first point (the second was 0.007% off); now
        // both within 0.003%.
        const Scene scene = parseScene(R"({
          "lights": [{"corner": [1.2582586591725382, 1.2551299622733267, 3.0507802612124206],
                      "edge_u": [-0.22239675177538434, -2.5126312720573916, -0.09572550513441798],
                      "edge_v": [-2.5859570739062434, 0.22522115504725798, 0.09622029315766326]}],
          "obstacles": [{"type": "torus", "center": [-0.850928, -0.541022, 2.92274],
                         "major_radius": 0.0858051, "minor_radius": 0.0264,
                         "axis": [-0.00527108, -0.338063, -0.941109]}],
          "level_set": {"voxel_size": 0.0132, "half_width": 3}
        })", "seed605_torus.json", ".");
        const Occluder occ = scene.makeOccluder();
        occ.prepareClearance();
        Occluder::Query q = occ.makeQuery();
        for (const Vec3& p : {Vec3(0.3042568975, -1.2503540155, 0.0),
                              Vec3(-0.6861219614, -1.4559565277, 0.0)}) {
            const FieldCase c = againstStratified(scene, occ, q, p);
            CAPTURE(p.x, p.y, c.aci.formFactor, c.full, c.error);
            CHECK(std::abs(c.error) <= 0.00012);
        }
    }
    SECTION("random scene 605: a rotated box's silhouette corners") {
        // tests/scenes/random_seed605.json is bench_random's scene for seed 605. At the first
        // point, two vertices of the box's silhouette had tangent lines meeting next to one of
        // them, and a shoulder ray on the line from the chord's middle to that meeting point
        // said nothing of the silhouette corner between: once the vertices sat where the rays
        // find them, the arc took the chord past the corner, 0.54% too bright, until rays
        // beside such an arc's middle were asked (now 0.014%). At the second the vertices on
        // the box's edges sat on its sharp edges: 0.49% too dark, now 0.18% (the rest is the
        // interpolated edges' waviness, a voxel on the light, which the lattice does not follow).
        SceneUnderTest t("random_seed605.json");
        const FieldCase corner = againstStratified(t.scene, t.occ, t.q, Vec3(2.2927833615, -1.7623469860, 0.0));
        CAPTURE(corner.aci.formFactor, corner.full, corner.error);
        CHECK(std::abs(corner.error) <= 0.001);
        const FieldCase edges = againstStratified(t.scene, t.occ, t.q, Vec3(1.2012, -4.5860, 0.0));
        CAPTURE(edges.aci.formFactor, edges.full, edges.error);
        CHECK(std::abs(edges.error) <= 0.0025);
    }
}

TEST_CASE("a piece that cuts a corner off lopsidedly is checked through its chord's middle",
          "[aci][coverage]") {
    // Random scene 612's level-set cylinder, seen from pixel (68, 158) of its 200 x 200 image: a
    // voxel spans more than kMagnifiedVoxel lattice units, so no vertex has a tangent line and
    // every piece takes the section 3.2 check. One first-level square holds the tip of the
    // shadow: its piece runs from a crossing next to the cut-off corner to one far along the
    // other side, and the corner's diagonal met the contour next to the near end, where the
    // chord is right. The tip between the chord and the square's far corners passed unseen,
    // 0.39% of the unoccluded form factor too bright (inside the bound: coverage ran out of
    // rays first). Checked across the square through the chord's middle: 0.02%.
    SceneUnderTest t("random_seed612.json");
    const FieldCase c = againstStratified(t.scene, t.occ, t.q, Vec3(0.585194931, 3.696014186, 0.0));
    CAPTURE(c.aci.formFactor, c.aci.errorBound, c.full, c.error);
    CHECK(std::abs(c.error) <= 0.001);
    CHECK(std::abs(c.error) * c.full <= c.aci.errorBound);
}

TEST_CASE("vertices on a level set's field also where its voxel spans many lattice units",
          "[aci][coverage]") {
    // Random scene 612's level-set cylinder seen from pixel (83, 134) of its 200 x 200 image: its
    // rays' voxel spans more than kMagnifiedVoxel lattice units, so no vertex has a tangent line.
    // Their vertices were left where a Newton step from the visible end put them, which on a
    // convex distance falls short on the visible side (0.14 of a unit on average, one-signed):
    // the penumbra was 0.046% of the unoccluded form factor too dark, halving with every
    // dichotomy step added. Moved onto the field like the other vertices: 0.006% (against 2^20
    // rays 0.003%; this test's 2^18-ray reference is good to about 0.003%).
    SceneUnderTest t("random_seed612.json");
    const FieldCase c = againstStratified(t.scene, t.occ, t.q, Vec3(-0.007668456, 2.190659587, 0.0));
    CAPTURE(c.aci.formFactor, c.aci.errorBound, c.full, c.error);
    CHECK(std::abs(c.error) <= 0.00015);
}

TEST_CASE("a small shadow found next to a thin level set's contact shadow (random scene 704)",
          "[aci][coverage]") {
    // Random scene 704, pixel (92, 107) of its 200 x 200 image: a ground point 0.08 under a
    // level-set capsule of radius 0.036 (2.9 voxels), whose shadow covers half the light, and
    // a small analytic sphere whose shadow is a blob on the light's border between two lit
    // first-level corners. Blocked rays pass through the capsule at most a voxel deep; while a
    // depth lost half a voxel to the interpolation's error they proved nothing, coverage spent
    // its whole allowance (and the escalation's) on the capsule's shadow, the blob went
    // unseen and F came out 0.7% of itself too bright (inside its bound of 0.089). With the
    // interpolant's own depth (the tracer blocks what it blocks): -0.07%, bound 0.024.
    checkGroundPoint("random_seed704.json", Vec3(0.614032207, -0.349152576, 0.0), 0.001);
}

TEST_CASE("tangent arcs: a level-set box's silhouette that bends twice between two vertices "
          "(random scene 720)",
          "[aci][coverage]") {
    // Random scene 720: a rotated level-set box 0.07 under the light, whose shadow from this
    // ground point covers a third of the light. Between two vertices its silhouette runs along
    // one edge, turns round the box's rounded corners and along another; the tangent lines at
    // the two vertices met far outside it, and the arc through the shoulder the field placed
    // cut up to three lattice units into the shadow: F 0.45% of itself too bright (inside its
    // bound). The visible shoulder ray's own tangent line, which a conic would have parallel to
    // the chord, turned away from it: such a piece is now checked and refined as in section 3.2.
    checkGroundPoint("random_seed720.json", Vec3(1.637235117, -2.072441198, 0.0), 0.0005);
}

TEST_CASE("tangent arcs integrated as parabolic pieces: a sphere's penumbra is not too bright",
          "[aci][coverage]") {
    // An exact sphere (radius 0.5, centre height 2) under the paper's light: its shadow on the
    // light is an ellipse, which a tangent arc with the right weight follows exactly. Emitted as
    // eight chords, each arc lost the segments between its chords and the ellipse, one-signed:
    // 0.067-0.127% of the unoccluded form factor too bright at these five points with 25-58
    // rays; as four parabolic pieces through its points, 0.001-0.012%.
    const Scene scene = parseScene(R"({
      "lights": [{"corner": [-1, -1, 4], "edge_u": [0, 2, 0], "edge_v": [2, 0, 0]}],
      "obstacles": [{"type": "sphere", "analytic": true, "center": [0, 0, 2], "radius": 0.5}]
    })", "sphere.json", ".");
    const Occluder occ = scene.makeOccluder();
    Occluder::Query q = occ.makeQuery();
    for (const Vec3& p : {Vec3(0.3, 0.1, 0.0), Vec3(0.6, 0.2, 0.0), Vec3(0.9, 0.3, 0.0),
                          Vec3(1.1, 0.5, 0.0), Vec3(1.3, 0.2, 0.0)}) {
        const FieldCase c = againstStratified(scene, occ, q, p);
        CAPTURE(p.x, p.y, c.aci.formFactor, c.full, c.error);
        CHECK(std::abs(c.error) <= 0.0003);
    }
}

TEST_CASE("tangent arcs: no arc bent by a shoulder ray that passes closest to another sphere",
          "[aci][coverage]") {
    // bench_coverage's scene 38 (seven exact spheres under the paper's light, centres and radii
    // rounded here to five decimals): from these ground points a small sphere's shadow on the
    // light (radius 0.081 at height 1.66) bulges out of a large one's (0.349 at 2.26). One
    // first-level square's arc along the large shadow took its shoulder ray beside the small
    // one, whose clearance (to the small sphere) placed the arc: 0.52-0.69% of the unoccluded
    // form factor too dark around the first point, with 35-42 rays, and no coverage ray
    // contradicted it (the arc stayed within a lattice unit of the union's edge).
    const RectLight light = test::paperLight();
    const std::vector<AnalyticSphere> spheres = {
        {Vec3(0.10889, -0.21187, 2.25604), 0.34878}, {Vec3(0.98274, 0.70381, 0.76497), 0.16950},
        {Vec3(-1.10024, -0.53729, 2.09328), 0.36198}, {Vec3(-1.19933, 0.86941, 3.04789), 0.25072},
        {Vec3(-0.06465, -0.91042, 1.65638), 0.08088}, {Vec3(0.36318, 0.53428, 0.79782), 0.10604},
        {Vec3(-0.83270, -0.84217, 1.35783), 0.08746}};
    std::vector<ObstacleShape> shapes(spheres.begin(), spheres.end());
    const Occluder occ(shapes);
    Occluder::Query q = occ.makeQuery();
    ContourIntegrator aci{AciSettings{}};
    for (const Vec3& p : {Vec3(-0.456634, -1.853629, 0.0), Vec3(-0.466634, -1.843629, 0.0),
                          Vec3(-0.446634, -1.853629, 0.0), Vec3(-0.436634, -1.853629, 0.0)}) {
        const Receiver r{p, kUp};
        const Estimate e = aci.evaluate(r, light, q);
        const double exact = exactSpheres(r, light, spheres);
        const double full = unoccludedFormFactor(light, r);
        CAPTURE(p.x, p.y, e.formFactor, exact, full, e.errorBound);
        CHECK(std::abs(e.formFactor - exact) <= 0.002 * full);
        CHECK(std::abs(e.formFactor - exact) <= e.errorBound);
    }
}

TEST_CASE("coverage: a point on a torus' inner wall just under the light (random scene 9)",
          "[aci][coverage]") {
    // bench_random's seed 9 (bench/bench_random.cpp) has a small level-set torus 0.12 from a
    // light of 1.1 x 1.4; pixel (105, 85) of its 200 x 200 image lies on the torus' inner wall,
    // a saddle. Two things went wrong there, each alone worth several percent of the form
    // factor: rays that pass closest to the surface at their own start (the receiver's wall)
    // gave tangent lines along the receiver's tangent plane, which a saddle's silhouette does
    // not follow (10% off), and one first-level square next to the kernel's peak took a chord
    // across the corner where the silhouette meets the horizon, its check within the strip
    // threshold of a piece that long (2% off, as in the arcs mode). Reference: Monte Carlo with
    // 2^16 rays, allowed four of its standard deviations.
    const std::string json = R"({
      "lights": [{"corner": [0.20094961139079576, -0.83365520487811084, 2.8660176618005768],
                  "edge_u": [-0.76340380930070129, 0.0021328387901835867, 0.74696806887268996],
                  "edge_v": [0.17855504457473703, 1.3849612738928427, 0.17852932090070187]}],
      "obstacles": [{"type": "torus", "center": [0.0587772, 0.0635326, 3.06124],
                     "major_radius": 0.0474488, "minor_radius": 0.0216,
                     "axis": [-0.771918, 0.0857328, -0.629914]}],
      "level_set": {"voxel_size": 0.0108, "half_width": 3}
    })";
    const Scene scene = parseScene(json, "seed9_torus.json", ".");
    const Occluder occ = scene.makeOccluder();
    occ.prepareClearance();
    Occluder::Query q = occ.makeQuery();
    const RectLight& light = scene.lights[0];
    const Vec3 p(0.0629875942, 0.089825072, 3.07057383);
    const Receiver r{p, glm::normalize(Vec3(0.292335527, -0.954182827, 0.0638362954))};
    const AgainstMonteCarlo m = againstMonteCarlo(occ, q, light, r);
    const Estimate& e = m.aci;
    const double ref = m.ref, full = m.full, sigma = m.sigma;
    CAPTURE(e.formFactor, e.errorBound, ref, sigma, full);
    REQUIRE(ref < 0.95 * full);  // the torus shadows the point
    CHECK(std::abs(e.formFactor - ref) <= 0.005 * full + 4.0 * sigma);
    CHECK(std::abs(e.formFactor - ref) <= e.errorBound + 4.0 * sigma);
}

TEST_CASE("coverage: points on the ground next to a small level-set cylinder (random scene 8)",
          "[aci][coverage]") {
    // bench_random's seed 8: a level-set cylinder of radius 5 voxels whose base is 3 voxels
    // above the ground, under a 1.3 x 1.1 light 3 units up. From the ground next to it a voxel
    // spans 20-30 lattice units on the light, and the Newton steps and tangent lines read from
    // the interpolated surface's distances put the contour off where the rays find it: 2-7% of
    // the form factor off at these pixels' points (however fine the lattice), where the paper's
    // and arcs modes converge to the reference. Reference: Monte Carlo with 2^20 rays, allowed
    // four of its standard deviations.
    const std::string json = R"({
      "lights": [{"corner": [0.99550954849426077, 0.043938385196493901, 3.1297392194066997],
                  "edge_u": [-1.0220158899103307, -0.78753416533599907, -0.33048456053312436],
                  "edge_v": [-0.67497774881752393, 0.90823770995249664, -0.076948351734441534]}],
      "obstacles": [{"type": "cylinder", "center": [0.437296, 0.0250562, 0.147026],
                     "axis": [0.0311126, -0.467933, 0.883216], "radius": 0.0775122,
                     "height": 0.163029}],
      "level_set": {"voxel_size": 0.0146, "half_width": 3}
    })";
    const Scene scene = parseScene(json, "seed8_cylinder.json", ".");
    const Occluder occ = scene.makeOccluder();
    occ.prepareClearance();
    Occluder::Query q = occ.makeQuery();
    const RectLight& light = scene.lights[0];
    const Vec3 points[] = {{0.435477087, -0.0828685546, 0.0}, {0.394825808, 0.10272357, 0.0},
                           {0.410281377, -0.0997836299, 0.0}, {0.47694993, 0.108398086, 0.0}};
    for (const Vec3& p : points) {
        const AgainstMonteCarlo m = againstMonteCarlo(occ, q, light, {p, kUp}, 1 << 20);
        const Estimate& e = m.aci;
        const double ref = m.ref, full = m.full, sigma = m.sigma;
        CAPTURE(p.x, p.y, e.formFactor, e.errorBound, ref, sigma, full);
        REQUIRE(ref < 0.9 * full);  // the cylinder shadows the point
        CHECK(std::abs(e.formFactor - ref) <= 0.015 * ref + 4.0 * sigma);
        CHECK(std::abs(e.formFactor - ref) <= e.errorBound + 4.0 * sigma);
    }
}

TEST_CASE("tangent mode: a point on a level-set torus that its own tube half hides (random scene 6305)",
          "[aci][coverage]") {
    // bench_bounds --fog, seed 6305 (the fogs, which lie elsewhere, left out): a point on the
    // underside of a level-set torus whose own tube hides most of the light a few voxels from
    // it. Its shadow rays start 1.5 voxels off the surface, and the tangent mode put its 3D
    // contour points on the rays from that offset origin, not on the lines from the receiver
    // point, which every edge of the integral starts from: the junction edges and the arcs'
    // ends left those lines and the form factor came out 13% low (within its bound). The
    // reference: the same estimator three dichotomy steps finer, which agrees with a 2^20-ray
    // Monte Carlo to 1e-4 of it (0.0121744 against 0.0121744 and 0.0121738 at 8 and 7 steps).
    const std::string json = R"({
      "lights": [{"corner": [1.300000812754277, -1.4077834612810607, 5.6952622437050637],
                  "edge_u": [-2.6343359968746478, 0.52819130026316974, -0.41333622980661217],
                  "edge_v": [0.72410385223983298, 2.0619018652784993, -1.9801172923491801]}],
      "obstacles": [{"type": "torus", "center": [0.1699, -0.96785, 3.24586], "major_radius": 0.36823,
                     "minor_radius": 0.195372, "axis": [-0.838858, 0.266485, 0.474661]}],
      "level_set": {"voxel_size": 0.0154, "half_width": 3}
    })";
    const Scene scene = parseScene(json, "seed6305_torus.json", ".");
    const Occluder occ = scene.makeOccluder();
    occ.prepareClearance();
    Occluder::Query q = occ.makeQuery();
    const Receiver r{Vec3(0.186965577, -0.959876021, 2.87129827),
                     glm::normalize(Vec3(0.917715207, -0.300851562, -0.259397642))};
    const AgainstFiner m = againstFiner(occ, q, scene.lights[0], r, 3);
    CAPTURE(m.aci.formFactor, m.aci.errorBound, m.ref, m.full);
    REQUIRE(m.ref > 0.01);
    CHECK(std::abs(m.aci.formFactor - m.ref) <= 0.002 * m.ref);
    CHECK(std::abs(m.aci.formFactor - m.ref) <= m.aci.errorBound);
}

TEST_CASE("a finer lattice under a huge light also when a thin level set has no kernel balls "
          "(random scene 6702)",
          "[aci][coverage]") {
    // bench_bounds --lights mixed --light-scale 8, seed 6702: a ground point under a triangle
    // 18 across whose plane passes 3 from it, a level-set torus's shadow a few cells wide. The
    // finer lattice such points take was turned off by a capsule two voxels thick elsewhere in
    // the light's view: too thin for kernel balls, its footprint's width is 0, which until
    // 2026-12-06 also meant "footprints unbounded". 1.4% of F0 low, within its bound; the
    // reference is the estimator two dichotomy steps finer (0.0685870 against a 2^20-ray
    // Monte Carlo's 0.0685853).
    const std::string json = R"({
      "lights": [{"type": "polygon", "vertices": [[-5.539381076280954, -2.375655325448981, -4.4950696320644274],
                                                  [-3.9209569422028014, 6.960859345568794, -0.844795118552963],
                                                  [6.214453775403822, 0.7113576564529882, 10.711865016084435]]}],
      "obstacles": [{"type": "torus", "center": [-0.807442, -1.61726, 0.365975], "major_radius": 0.22822,
                     "minor_radius": 0.0669957, "axis": [-0.936841, 0.349683, -0.00711527]},
                    {"type": "capsule", "a": [1.30428, -1.27527, 3.4957], "b": [0.988364, -1.39213, 3.57668],
                     "radius": 0.025747}],
      "level_set": {"voxel_size": 0.0119, "half_width": 3}
    })";
    const Scene scene = parseScene(json, "seed6702.json", ".");
    const Occluder occ = scene.makeOccluder();
    occ.prepareClearance();
    Occluder::Query q = occ.makeQuery();
    const AgainstFiner m = againstFiner(occ, q, scene.lights[0], {Vec3(0.301422709, -3.18040308, 0.0), kUp}, 2);
    CAPTURE(m.aci.formFactor, m.aci.errorBound, m.ref, m.full);
    REQUIRE(m.ref < 0.98 * m.full);  // the torus shadows the point
    CHECK(std::abs(m.aci.formFactor - m.ref) <= 0.002 * m.full);
    CHECK(std::abs(m.aci.formFactor - m.ref) <= m.aci.errorBound);
}

TEST_CASE("coverage: a ray that proves almost nothing far from the contour aims across the "
          "silhouette its clearance predicts (random scene 6516)",
          "[aci][coverage]") {
    // bench_bounds --lights mixed --fog, seed 6516 (its fog and the obstacles that shadow
    // nothing here left out): from a ground point, a level-set capsule's shadow is a narrow
    // patch on the light's border that no pass located. The rays next to it prove discs under a
    // lattice unit, and coverage spent its 48 rays on every lattice point of the cells beside
    // the patch, all visible: 0.66% of F0 missed (within the bound). A small box's shadow
    // elsewhere makes the footprints unbounded (its solid box reaches behind the ray origin as
    // seen from the light), so nothing but rays proves anything.
    const std::string json = R"({
      "lights": [{"corner": [-1.2044428619124607, 0.31151304263630913, 2.5173444645283274],
                  "edge_u": [2.2803819241965155, -0.8451491989104838, 1.2212442881188148],
                  "edge_v": [-0.5972056901511716, -0.6414631128317584, 0.6712211740784001]}],
      "obstacles": [{"type": "capsule", "a": [0.564353, -0.398268, 3.35129], "b": [0.0570231, -0.677546, 3.50922],
                     "radius": 0.0652855},
                    {"type": "box", "center": [0, 0, 0], "size": [0.0599942, 0.0471, 0.175712],
                     "transform": {"rotate_deg": [29.3248, 117.484, 11.1902],
                                   "translate": [0.00586811, 0.00877832, 2.78243]}}],
      "level_set": {"voxel_size": 0.0157, "half_width": 3}
    })";
    const Scene scene = parseScene(json, "seed6516.json", ".");
    const Occluder occ = scene.makeOccluder();
    occ.prepareClearance();
    Occluder::Query q = occ.makeQuery();
    const AgainstMonteCarlo m =
        againstMonteCarlo(occ, q, scene.lights[0], {Vec3(1.60739814, 2.37934297, 0.0), kUp}, 1 << 18);
    CAPTURE(m.aci.formFactor, m.aci.errorBound, m.ref, m.sigma, m.full);
    REQUIRE(m.ref < 0.996 * m.full);  // the capsule shadows the point
    checkNearReference(m, 0.002);
}

TEST_CASE("coverage: a point query whose allowance runs out with much of the light unproven gets "
          "one more (random scene 10117)",
          "[aci][coverage]") {
    // bench_bounds --lights mixed, seed 10117 (the obstacles that shadow nothing here left out):
    // a ground point 6 units from a triangle light seen edge-on (F0 4.5e-5). A thin level-set
    // cylinder near the light hides 3.6% of F0 at the light's edge, away from its centre's
    // projection (which falls off the triangle). The 48 coverage rays ran out with 15% of F0
    // unproven and F came out whole, within that bound; the second allowance finds the shadow.
    const std::string json = R"({
      "lights": [{"type": "polygon", "vertices": [[-0.35184958158650209, -0.60876924826458123, 2.8255618041914801],
                  [0.7447865609923835, -0.19883110682159424, 2.9996765089902522],
                  [0.097015232641486066, -0.77156452571132861, 3.1429269955517749]]}],
      "obstacles": [{"type": "cylinder", "center": [-1.00851, -0.88693, 2.43094],
                     "axis": [-0.359996, -0.763372, -0.536345], "radius": 0.0584171, "height": 0.346097}],
      "level_set": {"voxel_size": 0.0153, "half_width": 3}
    })";
    const Scene scene = parseScene(json, "seed10117.json", ".");
    const Occluder occ = scene.makeOccluder();
    occ.prepareClearance();
    Occluder::Query q = occ.makeQuery();
    const AgainstMonteCarlo m =
        againstMonteCarlo(occ, q, scene.lights[0], {Vec3(-6.128663, -1.03348372, 0.0), kUp}, 1 << 18);
    CAPTURE(m.aci.formFactor, m.aci.errorBound, m.ref, m.sigma, m.full, m.aci.counts.shadowRays());
    REQUIRE(m.ref < 0.98 * m.full);  // the cylinder shadows the point
    // Measured: 0.02% of F0 off with 253 rays (3.6% with 50 before).
    checkNearReference(m, 0.002);
}

TEST_CASE("coverage: a thin level set's middles are spread over it and reach past its depth, "
          "so that its far end's shadow is found (random scene 8510)",
          "[aci][coverage]") {
    // bench_bounds --lights mixed --fog, seed 8510 (the obstacles and fogs that shadow nothing
    // here left out): a level-set capsule 2.8 voxels thick, too thin for kernel balls, reaches up
    // beside a triangle light; from two ground points 5 units away its upper end hides 4.3% and
    // 0.9% of F0 near the light's edge. Its one middle, the deepest voxel, lay towards its lower
    // end, whose cone misses the light, and F came out whole at both (within bounds of 42% and
    // 47%). Its deep points, spread along it, put one in the upper end's cap, which finds the
    // second point's shadow; the first's is cast by the cap's rim, which rays through the deep
    // point's ball (as wide as the capsule is thick there) miss: a middle is now kept when its
    // ray passes within three depths.
    const std::string json = R"({
      "lights": [{"type": "polygon", "vertices": [[-1.3303328278821378, -0.09941734790101775, 2.8266618010958755],
                  [0.20805804693027252, 0.83084272065931675, 4.3098418372088414],
                  [0.60056691402092788, 0.23272354554724112, 4.4565709088393453]]}],
      "obstacles": [{"type": "capsule", "a": [-1.33251, 0.535958, 2.83011], "b": [-1.1339, 0.503847, 2.17066],
                     "radius": 0.0542261}],
      "level_set": {"voxel_size": 0.0195, "half_width": 3}
    })";
    const Scene scene = parseScene(json, "seed8510.json", ".");
    const Occluder occ = scene.makeOccluder();
    occ.prepareClearance();
    REQUIRE(occ.kernelBalls(0).empty());
    CHECK(occ.deepPoints(0).size() > 1);
    Occluder::Query q = occ.makeQuery();
    for (const Vec3& p : {Vec3(-4.55854209, 0.286352745, 0.0), Vec3(-4.78723731, 0.747995379, 0.0)}) {
        const AgainstMonteCarlo m = againstMonteCarlo(occ, q, scene.lights[0], {p, kUp}, 1 << 20);
        CAPTURE(p.x, m.aci.formFactor, m.aci.errorBound, m.ref, m.sigma, m.full, m.aci.counts.shadowRays());
        REQUIRE(m.ref < 0.995 * m.full);  // the capsule shadows the point
        // Measured: 0.016% and 0.001% of F0 off (4.3% and 0.9% before).
        checkNearReference(m, 0.002);
    }
}

TEST_CASE("coverage: a shadow under a lattice unit thick, found by one ray, is located one step "
          "finer with every sample carried over (random scene 7003)",
          "[aci][coverage]") {
    // bench_bounds --lights mixed --light-scale 8 --fog, seed 7003 (the obstacles that shadow
    // nothing here left out): a level-set torus whose tube is two voxels thick (too thin for
    // kernel balls) casts a ring of shadow under a lattice unit thick on a triangle 20 across.
    // Its solid sphere's centre lies in the hole, so no coverage middle aimed at it, and the
    // evaluation took one ray and found the light whole: 0.6% of F0 high, within its bound. Now
    // a middle aims at the torus' deepest voxel, and the ray that finds the shadow, with no
    // lattice neighbour inside it, makes the evaluation start again one step finer with that
    // sample carried over.
    const std::string json = R"({
      "lights": [{"type": "polygon", "vertices": [[7.034226311273971, 2.846951866180325, 11.596775648724849],
                  [9.075547357104174, -7.360544487048575, 7.300426186859337],
                  [-6.938928308641242, -3.2266949548964927, -2.918197875569242]]}],
      "obstacles": [{"type": "torus", "center": [-0.614626, -0.39245, 1.19056], "major_radius": 0.0477,
                     "minor_radius": 0.0318, "axis": [-0.475575, -0.330708, 0.815145]}],
      "level_set": {"voxel_size": 0.0159, "half_width": 3}
    })";
    const Scene scene = parseScene(json, "seed7003.json", ".");
    const Occluder occ = scene.makeOccluder();
    occ.prepareClearance();
    Occluder::Query q = occ.makeQuery();
    const AgainstMonteCarlo m =
        againstMonteCarlo(occ, q, scene.lights[0], {Vec3(0.0957759583, 0.280810814, 0.0), kUp}, 1 << 18);
    CAPTURE(m.aci.formFactor, m.aci.errorBound, m.ref, m.sigma, m.full, m.aci.counts.shadowRays());
    REQUIRE(m.ref < 0.997 * m.full);  // the torus shadows the point
    CHECK(m.aci.counts.finerRedos >= 1);
    // Measured: 0.027% of F0 off (0.6% before).
    checkNearReference(m, 0.001);
}

TEST_CASE("a light far larger than its distance: small shadows where its cells weigh most are located",
          "[aci][coverage]") {
    // An 80 x 80 light 4 above the ground, two small exact spheres between: at the default
    // lattice a cell (0.625 across) right above a ground point carries 0.8% of the form factor
    // and a sphere's shadow on the light is two or three cells wide. Before 2026-12-05 the
    // shadows went unlocated and the answers were up to 3% off (within their bounds); the
    // evaluation now takes steps more there (kFineCellFormFactor).
    RectLight light;
    light.corner = Vec3(-40, -40, 4);
    light.edgeU = Vec3(0, 80, 0);
    light.edgeV = Vec3(80, 0, 0);
    const std::vector<AnalyticSphere> spheres = {{Vec3(0.1, 0.05, 1.0), 0.15}, {Vec3(-0.8, 0.3, 1.6), 0.2}};
    Occluder occ({spheres[0], spheres[1]});
    Occluder::Query q = occ.makeQuery();
    double worst = 0.0;
    int shadowed = 0;
    for (const Vec3& m : {Vec3(0, 0, 0), Vec3(0.3, 0.2, 0), Vec3(-0.6, 0.1, 0), Vec3(-1.0, 0.6, 0),
                          Vec3(0.5, -0.4, 0), Vec3(-0.3, 0.5, 0)}) {
        const Receiver r{m, Vec3(0, 0, 1)};
        const Estimate e = contourIntegral(r, light, q);
        const double ref = exactSpheres(r, light, spheres), full = unoccludedFormFactor(light, r);
        CAPTURE(m.x, m.y, e.formFactor, ref, full, e.errorBound, e.counts.shadowRays());
        CHECK(std::abs(e.formFactor - ref) <= e.errorBound + 1e-12);
        worst = std::max(worst, std::abs(e.formFactor - ref) / full);
        shadowed += ref < 0.995 * full;
    }
    CHECK(shadowed >= 4);
    // Measured at this commit: 0.047% of the unoccluded form factor at worst (2.9% before).
    INFO("worst " << worst);
    CHECK(worst < 0.001);
}

TEST_CASE("coverage: a window through a torus' hole on a light far larger than its distance "
          "(random scene 3102, light grown 15 times)",
          "[aci][coverage]") {
    // bench_random --light-scale 15, seed 3102: a 12.8 x 12.7 light tilted so far that its lower
    // corners lie below a receiver on the inner wall of a thin level-set torus. The receiver sees
    // the light through the torus' hole, a window that touches no first-level corner and is
    // small on this light but holds most of the form factor (the light's plane passes 0.07-0.5
    // from the point). Coverage sent its 48 rays to the cells farthest from proven ground,
    // where the kernel is negligible, and F came out 0 for 0.55 (within its bound of 0.73);
    // ordered by the form factor of the unproven discs, the rays find the window.
    const std::string json = R"({
      "lights": [{"corner": [9.2919720387862341, 0.35116664782673102, 3.1957381426322451],
                  "edge_u": [-8.1771740358877985, -9.8451939798382782, -0.204621395421618],
                  "edge_v": [-9.7929489086264834, 8.1463635818503715, -0.60542126083920922]}],
      "obstacles": [{"type": "torus", "center": [0.69058, -1.03, 2.71786],
                     "major_radius": 0.0611419, "minor_radius": 0.0265496,
                     "axis": [-0.137195, 0.138181, -0.980858]}],
      "level_set": {"voxel_size": 0.0117, "half_width": 3}
    })";
    const Scene scene = parseScene(json, "seed3102_torus.json", ".");
    const Occluder occ = scene.makeOccluder();
    occ.prepareClearance();
    Occluder::Query q = occ.makeQuery();
    const RectLight& light = scene.lights[0];
    const Vec3 p(0.727300175, -1.033612323, 2.720968585);
    const Receiver r{p, glm::normalize(Vec3(-0.889371271, 0.019044033, 0.456788866))};
    const AgainstMonteCarlo m = againstMonteCarlo(occ, q, light, r);
    const Estimate& e = m.aci;
    const double ref = m.ref, full = m.full, sigma = m.sigma;
    CAPTURE(e.formFactor, e.errorBound, ref, sigma, full, e.counts.coverageRays);
    REQUIRE(ref > 0.5 * full);  // the window holds most of the form factor
    // 2% until 2026-12-06, when the point came out 1.3% of F0 low: the receiver lies on a level
    // set too thin for kernel balls, whose own footprint is unbounded, and the finer lattice for
    // lights much larger than their distance did not apply. It does now (a width of 0, as for a
    // thin level set that projects): 0.06%.
    CHECK(std::abs(e.formFactor - ref) <= 0.005 * full + 4.0 * sigma);
    CHECK(std::abs(e.formFactor - ref) <= e.errorBound + 4.0 * sigma);
}

// A receiver on a level-set obstacle under a light far larger than its distance, in the shadow
// of a level-set rod two voxels thick: F against mc-ratio on the same level sets (2^18 rays).
// Every ray leaves the receiver's own surface, and the companion's closest point to it lay at
// the ray's start (the companion is off by up to half a coarse voxel there): that obstacle's
// clearance came out unknown, which hid every other obstacle's, so no vertex had a Newton step
// and the rod's shadow, under a lattice unit wide, was integrated up to 2.7 times too large.
namespace {

void checkOnOwnLevelSet(const std::string& json, const std::string& name, const Vec3& p,
                        const Vec3& n) {
    const Scene scene = parseScene(json, name, ".");
    const Occluder occ = scene.makeOccluder();
    occ.prepareClearance();
    Occluder::Query q = occ.makeQuery();
    const RectLight& light = scene.lights[0];
    const Receiver r{p, glm::normalize(n)};
    AciSettings s;
    s.gradient = false;
    s.errorBound = true;
    s.rayOffset = receiverRayOffset(occ, r.point, 1e-9);
    ContourIntegrator aci(s);
    const Estimate e = aci.evaluate(r, light, q);
    McSettings mc;
    mc.samples = 1 << 18;
    mc.rayOffset = s.rayOffset;
    const double ref = monteCarloRatio(r, light, q, mc).formFactor;
    const double full = unoccludedFormFactor(light, r);
    const double frac = std::clamp(ref / full, 0.0, 1.0);
    const double sigma = full * std::sqrt(std::max(frac * (1.0 - frac), 1.0 / mc.samples) / mc.samples);
    CAPTURE(name, e.formFactor, e.errorBound, ref, sigma, full);
    REQUIRE(ref < full * (1.0 - 1e-3));  // the rod's shadow is there
    CHECK(std::abs(e.formFactor - ref) <= e.errorBound + 4.0 * sigma);
    // Before the fix 0.41% (seed 7304) and 0.29% (seed 7310) of the unoccluded form factor
    // off; now 0.014% and 0.01%.
    CHECK(std::abs(e.formFactor - ref) <= 1e-3 * full + 4.0 * sigma);
}

}  // namespace

TEST_CASE("coverage: a receiver on a level set, a rod's thin shadow on a huge light "
          "(bench_bounds --lights mixed --light-scale 6, seeds 7304 and 7310)",
          "[aci][coverage]") {
    // Seed 7304, three of its five obstacles: the receiver is on the level-set box, the shadow
    // the cylinder's.
    checkOnOwnLevelSet(R"({
      "lights": [{"type": "polygon", "radiance": [0.009, 0.009, 0.009], "vertices": [
        [4.532514917169035, -5.991005729324928, 6.2450192835008504],
        [-4.930048149898598, 0.28064193036912266, 8.010278265579089],
        [-6.426240731046021, 4.275722359030994, 5.003622189776253],
        [-5.507894293098043, 6.5622279655071205, 1.6649599576831753],
        [2.2381436318440167, 3.939403544407024, -2.5272817838830086],
        [5.347594611507835, 0.12058082307863993, -1.1841715249015001],
        [6.404747877240612, -4.379427758948755, 2.775128095095485]]}],
      "obstacles": [
        {"type": "box", "center": [0, 0, 0], "size": [0.219526, 0.322973, 0.368114],
         "transform": {"rotate_deg": [305.739, 244.421, 285.211], "translate": [0.454516, 0.86054, 1.06431]}},
        {"type": "cylinder", "center": [1.53363, 0.461337, 1.77197], "axis": [0.614562, 0.452764, 0.646002],
         "radius": 0.0276, "height": 0.0414},
        {"type": "sphere", "center": [1.07289, -0.182137, 0.827997], "radius": 0.356522, "analytic": true}],
      "level_set": {"voxel_size": 0.0138, "half_width": 3}
    })",
                       "seed7304_box.json", Vec3(0.598366628, 0.833416353, 1.17208426),
                       Vec3(0.75572391, -0.553232681, 0.350449672));
    // Seed 7310: the receiver on the level-set sphere, the shadow the capsule's.
    checkOnOwnLevelSet(R"({
      "lights": [{"type": "polygon", "radiance": [0.023, 0.023, 0.023], "vertices": [
        [-2.1364003848521635, 5.288516763620544, 7.320546999745179],
        [3.243225400749891, -2.987859497923737, -0.9106271725408366],
        [0.8016090759120014, -3.741555325390559, -1.023851683046375],
        [-2.164523718679227, 0.06801495538697566, 2.8712611917453783],
        [-3.3901257198214196, 3.845227515045895, 6.3609353615241275]]}],
      "obstacles": [
        {"type": "sphere", "center": [-0.682306, 1.77678, 0.366659], "radius": 0.303954},
        {"type": "capsule", "a": [-0.854743, 0.0965166, 2.49263], "b": [-0.716197, 0.302304, 2.49449],
         "radius": 0.0318}],
      "level_set": {"voxel_size": 0.0159, "half_width": 3}
    })",
                       "seed7310_sphere.json", Vec3(-0.772455923, 1.82301367, 0.653038995),
                       Vec3(-0.296352305, 0.151982605, 0.942908585));
}

TEST_CASE("a conic piece's area over its tangent triangle's, against a fine polygon", "[aci]") {
    // The rational quadratic Bezier curve on (-1, 0), (0, 1), (1, 0) with middle weight w: an
    // ellipse's arc for w < 1, a parabola's for w = 1, a hyperbola's for w > 1. Its segment's
    // area by 200,000 chords (their error is below 1e-10 of the triangle's area of 1).
    auto polygonShare = [](double w) {
        const int n = 200000;
        double area = 0.0, px = -1.0, py = 0.0;
        for (int i = 1; i <= n; ++i) {
            const double t = double(i) / n, b0 = (1 - t) * (1 - t), b1 = 2 * w * t * (1 - t), b2 = t * t;
            const double x = (-b0 + b2) / (b0 + b1 + b2), y = b1 / (b0 + b1 + b2);
            area += (x - px) * (y + py) / 2.0;
            px = x, py = y;
        }
        return area;
    };
    for (double w : {0.05, 0.3, std::sqrt(0.5), 0.99995, 1.0, 1.00005, 1.5, 3.0, 20.0, 400.0}) {
        CAPTURE(w);
        CHECK(conicSegmentShare(w) == Approx(polygonShare(w)).epsilon(1e-7));
    }
    CHECK(conicSegmentShare(std::sqrt(0.5)) == Approx(kPi / 2.0 - 1.0));  // a quarter circle's segment
}

TEST_CASE("coverage: a crossing that a later sample of the same pass contradicts is placed again "
          "(random scene 3209, hexagon light grown 5 times)",
          "[aci][coverage]") {
    // bench_bounds --lights mixed --light-scale 5, seed 3209: a ground point 0.16 from the plane
    // of a large tilted hexagon light, a level-set capsule reaching from between them to behind
    // the point. In the fan's first triangle a square's side took a crossing before the
    // neighbouring finer squares traced a sample inside its bracket that contradicts it; they
    // placed their own vertex on the same side and the contour stayed open by 0.6 lattice units.
    // Seen at so grazing an angle, that open piece was worth half the triangle's form factor:
    // 4.5% more than the light's unoccluded form factor, 1.4 times the bound.
    const std::string json = R"({
      "lights": [{"type": "polygon", "vertices": [[-3.1390219836305109, -2.6333847917696849, 6.0748526775755636],
         [2.8952307473070382, 5.0367152169275604, 0.94069422533907954],
         [3.513703177698603, 4.6689376743087871, 0.46349473212261705],
         [3.4196325470677813, 2.8514506379790623, 0.61566190632515916],
         [2.0428170581766287, -0.13449859803532815, 1.8396071817405009],
         [-2.9757373069658293, -4.4678591841691615, 6.0226707526918979]]}],
      "obstacles": [{"type": "capsule", "a": [0.408785, -1.00631, 3.07659],
                     "b": [0.189262, -1.06457, 3.11759], "radius": 0.0402721}],
      "level_set": {"voxel_size": 0.0162, "half_width": 3}
    })";
    const Scene scene = parseScene(json, "seed3209_capsule.json", ".");
    const Occluder occ = scene.makeOccluder();
    occ.prepareClearance();
    Occluder::Query q = occ.makeQuery();
    const RectLight& light = scene.lights[0];
    const Receiver r{Vec3(4.08941229, -0.153531364, 0.0), kUp};
    const AgainstMonteCarlo m = againstMonteCarlo(occ, q, light, r, 1 << 18);
    const Estimate& e = m.aci;
    const double ref = m.ref, full = m.full, sigma = m.sigma;
    CAPTURE(e.formFactor, e.errorBound, ref, sigma, full);
    CHECK(e.formFactor <= full * (1.0 + 1e-9));
    CHECK(std::abs(e.formFactor - ref) <= 0.002 * full + 4.0 * sigma);
    CHECK(std::abs(e.formFactor - ref) <= e.errorBound + 4.0 * sigma);
}

TEST_CASE("coverage: obstacles near the light whose shadows touch no corner and the discs never "
          "reach get a ray at their middles (random scenes 3501, 4002, 2708 and 3902)",
          "[aci][coverage]") {
    // bench_bounds --lights mixed --fog, seed 3501 (the fogs left out, they do not reach these
    // rays): a level-set sphere 0.15 from a thin triangle light hides 16% of a far ground
    // point's form factor. Every coverage ray went along the edge of its shadow, each clear
    // with a disc under the cone march's least radius, none into it: F came out unoccluded
    // (within a bound of 30%). --light-scale 3, seed 4002: three level-set obstacles two voxels
    // thick near a triangle light, 0.8% of F, found by no ray. Coverage now aims its first rays
    // at the obstacles' middles where the contour says the light is seen.
    struct Case {
        std::string json;
        Vec3 point;
    };
    const Case cases[] = {
        {R"({
      "lights": [{"type": "polygon", "vertices": [[0.30392061697446449, 0.42149769062113684, 3.5896405226919565],
         [0.10232317821243112, -0.36614766704752361, 3.0725003518311693],
         [0.012807000166315766, -0.25019272708578566, 2.9540522518946344]], "radiance": [1, 1, 1]}],
      "obstacles": [{"type": "sphere", "center": [0.158046, 0.01976, 2.96606], "radius": 0.0524218}],
      "level_set": {"voxel_size": 0.0102, "half_width": 3}})",
         Vec3(2.61477893, 7.59940979, 0)},
        {R"({
      "lights": [{"type": "polygon", "vertices": [[-2.6012436951218678, 0.76380493981734254, 2.349066764761099],
         [3.8295283038658434, 1.4705523383599106, 4.0731963385189092],
         [2.9908874813221296, -0.23366805152239567, 3.519383488593113]], "radiance": [1, 1, 1]}],
      "obstacles": [
        {"type": "cylinder", "center": [0.100106, 1.35625, 3.04935], "axis": [-0.245329, -0.776569, -0.580305], "radius": 0.033, "height": 0.0741725},
        {"type": "capsule", "a": [-0.236292, 0.717742, 2.8453], "b": [-0.272816, 0.757618, 2.76229], "radius": 0.033},
        {"type": "torus", "center": [-0.0945173, 1.0666, 2.81194], "major_radius": 0.0495, "minor_radius": 0.033, "axis": [-0.299552, -0.664377, -0.684742]}],
      "level_set": {"voxel_size": 0.0165, "half_width": 3}})",
         Vec3(-0.242259, 2.1396251, 0)},
        // Rect seed 2708: a sphere's shadow holds a corner of the light, seen so obliquely that
        // the sphere's centre projects 200 frames away; 4% of F, no corner in it.
        {R"({
      "lights": [{"corner": [-1.4112040357031972, 0.4972757317704426, 2.7612131255555017],
         "edge_u": [2.2644001833655372, 0.46511678854378535, -0.46893370996559447],
         "edge_v": [0.74372668864097891, -2.1428923278330272, 1.465878092803558], "radiance": [1, 1, 1]}],
      "obstacles": [
        {"type": "sphere", "center": [-0.320699, 0.673623, 2.29499], "radius": 0.188277},
        {"type": "cylinder", "center": [-0.404023, 1.62655, 0.153623], "axis": [0.0903344, 0.751853, -0.653113], "radius": 0.0374, "height": 0.240707}],
      "level_set": {"voxel_size": 0.0187, "half_width": 3}})",
         Vec3(-0.157069227, 4.01320032, 0)},
        // The same from farther: there the kernel ball's cone misses the light, the sphere's
        // outer part does not (2.4% of F).
        {"", Vec3(0.530142094, 3.97302434, 0)},
        // --lights mixed, seed 3902: a sphere's middle falls beside a disc light, in its frame
        // but not in the circle, and a small torus near the light took every coverage ray: 3%
        // of F. The middle is now sought among the points that emit.
        {R"({
      "lights": [{"type": "disc", "center": [0.29706296260577847, 0.4255964389058067, 3.2320658285777615],
         "normal": [0.4936927772908011, -0.4540605043306122, -0.7416849061818135], "radius": 0.818019, "radiance": [1, 1, 1]}],
      "obstacles": [
        {"type": "sphere", "center": [-0.872817, 0.692175, 1.68585], "radius": 0.331018},
        {"type": "torus", "center": [-0.973028, 0.354944, 2.19528], "major_radius": 0.0342, "minor_radius": 0.0228, "axis": [-0.491067, 0.6569, -0.572132]}],
      "level_set": {"voxel_size": 0.0114, "half_width": 3}})",
         Vec3(-2.97913156, 1.56574345, 0)},
    };
    std::string previous;
    for (const Case& c : cases) {
        if (!c.json.empty()) previous = c.json;  // "": the scene before
        const Scene scene = parseScene(previous, "near_light.json", ".");
        const Occluder occ = scene.makeOccluder();
        occ.prepareClearance();
        Occluder::Query q = occ.makeQuery();
        const AgainstMonteCarlo m = againstMonteCarlo(occ, q, scene.lights[0], {c.point, Vec3(0, 0, 1)}, 1 << 18);
        CAPTURE(c.point.x, m.aci.formFactor, m.aci.errorBound, m.ref, m.sigma, m.full);
        REQUIRE(m.ref < 0.995 * m.full);  // the obstacles do shadow the point
        checkNearReference(m, 0.002);
    }
}

TEST_CASE("tangent mode: squares below one whose threshold no checked piece set take their own "
          "(random scene 8902)",
          "[aci][coverage]") {
    // bench_random --lights mixed, seed 8902: a level-set box 0.044 under a tilted light, and a
    // small torus between. At this ground point the box's silhouette and the torus' meet on the
    // light. A square whose pieces were all tangent arcs, or whose side's middle disagreed with
    // its ends, set no threshold from a checked piece; until the thirty-fifth session it passed
    // 0 to its sub-squares, and every one of them refined to the lattice (108 squares refined
    // here; 42 since).
    const std::string json = R"({
      "lights": [{"corner": [1.6785819723381228, -1.1998662701379987, 3.1666200737709165],
                  "edge_u": [-2.0348797250064168, -0.98210871628167529, 1.3192466712232283],
                  "edge_v": [-1.186443593758902, 2.5908823743930838, 0.098736765299163448]}],
      "obstacles": [{"type": "torus", "center": [-1.18993, -0.489979, 2.5443], "major_radius": 0.0534,
                     "minor_radius": 0.0356, "axis": [-0.895713, 0.0845998, -0.43651]},
                    {"type": "box", "center": [0, 0, 0], "size": [0.988732, 0.697681, 0.749409],
                     "transform": {"rotate_deg": [301.128, 318.362, 71.2836],
                                   "translate": [-0.467101, -0.516348, 3.39766]}}],
      "level_set": {"voxel_size": 0.0178, "half_width": 3}
    })";
    const Scene scene = parseScene(json, "seed8902.json", ".");
    const Occluder occ = scene.makeOccluder();
    occ.prepareClearance();
    Occluder::Query q = occ.makeQuery();
    const AgainstFiner m = againstFiner(occ, q, scene.lights[0], {Vec3(-2.0, -2.0, 0.0), kUp}, 2);
    CAPTURE(m.aci.formFactor, m.aci.errorBound, m.ref, m.full, m.aci.counts.squaresRefined);
    REQUIRE(m.ref < 0.9 * m.full);  // the box hides part of the light
    CHECK(m.aci.counts.squaresRefined <= 75);
    CHECK(std::abs(m.aci.formFactor - m.ref) <= 0.001 * m.full);
    CHECK(std::abs(m.aci.formFactor - m.ref) <= m.aci.errorBound);
}

// The default evaluation of a scene file's light at ground point p (no gradient), as a probe
// makes it or, with `asRender`, as a render's pixel does (adaptive steps and one coverage
// allowance: RenderSettings::pixelAci).
Estimate groundPoint(SceneUnderTest& t, const Vec3& p, bool asRender) {
    const Receiver r{p, kUp};
    AciSettings s;
    s.gradient = false;
    s.rayOffset = receiverRayOffset(t.occ, r.point, 1e-9);
    if (asRender) {
        s.adaptiveSteps = true;
        s.extendCoverage = 0.0;
    }
    return ContourIntegrator(s).evaluate(r, t.scene.lights.at(0), t.q);
}

// An evaluation at ground point p against its reference: within its own bound, and within 0.1%
// of the unoccluded form factor.
void checkGroundPoint(const SceneUnderTest& t, const Vec3& p, const Estimate& aci, double ref) {
    const double full = unoccludedFormFactor(t.scene.lights.at(0), {p, kUp});
    CAPTURE(p.x, p.y, aci.formFactor, aci.errorBound, ref, full);
    CHECK(std::abs(aci.formFactor - ref) <= aci.errorBound);
    CHECK(std::abs(aci.formFactor - ref) <= 0.001 * full);
}

TEST_CASE("adaptive steps keep the lattice where a wide footprint cuts a sliver from a disc's rim "
          "(random scene 941)",
          "[aci][coverage]") {
    // tests/scenes/random_seed941.json is bench_random --lights mixed's scene for seed 941: a
    // disc light 2.7 across, a box 0.7 below it. From ground point (0.3826, -1.0010) the box's
    // footprint on the disc is wide, but it reaches only about two units of the lattice into
    // the disc along its rim. On the coarser lattice (renders' adaptive steps, n = 4 for the
    // asked 5) that sliver fell between the lattice points and the circle: three rays, the disc
    // taken as wholly lit, 0.171740 against 0.171291 (0.26% of the unoccluded form factor too
    // bright; all over the render at 64 x 64, where the image's mean difference from a 65,536-ray
    // reference was 2.6 times the finer lattice's). The evaluation now keeps the lattice there
    // (LightFootprints::thinSliver): 0.171356. Reference: the same estimator at n = 6 on the
    // finer lattice (a million rays: 0.171291).
    SceneUnderTest t("random_seed941.json");
    const Vec3 p(0.382620155, -1.000983518, 0.0);
    const Estimate aci = groundPoint(t, p, true);
    AciSettings fine;
    fine.gradient = false;
    fine.rayOffset = receiverRayOffset(t.occ, p, 1e-9);
    fine.steps = 6;
    const double ref = ContourIntegrator(fine).evaluate({p, kUp}, t.scene.lights.at(0), t.q).formFactor;
    CHECK(aci.counts.coarserEvaluations == 0);
    checkGroundPoint(t, p, aci, ref);
}

TEST_CASE("the field's root is found to a part of a lattice unit where a voxel spans many "
          "(random scene 946)",
          "[aci][coverage]") {
    // tests/scenes/random_seed946.json is bench_random --lights mixed's scene for seed 946: a
    // level-set box whose lowest corner is 0.066 above the ground, under a disc light 0.81
    // across at height 2.65. From ground points beside the box a voxel of it spans some 110
    // lattice units on the light, and fieldRoot's zero (0.02 voxel of the field) was most of a
    // unit, always on the side its secant came from: at (0.1187, -0.3067) F came out
    // 0.0078901 against 0.0079330 from 2^20 stratified rays (0.24% of the unoccluded form
    // factor too dark, halving with each dichotomy step added). The zero is now also the
    // field's change over a twentieth of a unit (kFieldRootUnitShare): 0.0079436.
    SceneUnderTest t("random_seed946.json");
    const Vec3 p(0.118669969, -0.306682567, 0.0);
    const double ref = 0.00793303269688;  // penumbra probe --method reference --samples 1048576
    checkGroundPoint(t, p, groundPoint(t, p, false), ref);
}

TEST_CASE("adaptive steps keep the lattice under a disc where a level set near the receiver "
          "is magnified (random scene 946)",
          "[aci][coverage]") {
    // The same scene: from ground point (0.0999, -0.0913) the box's footprint on the disc is 2.2
    // across (the disc is 0.81), but its shadow there is a sliver 1-4% of the disc's width
    // along the rim. Neither the footprint's width nor its sliver rule sees that, and on the
    // coarser lattice (renders' adaptive steps) F came out 0.0182717 against 0.0181745 from 2^20
    // stratified rays (0.52% of the unoccluded form factor too bright). A voxel of the box spans
    // about 110 lattice units there (LightFootprints::largestMagnifiedVoxel), so the evaluation
    // keeps the finer lattice: 0.0181811.
    SceneUnderTest t("random_seed946.json");
    const Vec3 p(0.099862085, -0.091297955, 0.0);
    const Estimate aci = groundPoint(t, p, true);
    const double ref = 0.0181744529538;  // penumbra probe --method reference --samples 1048576
    CHECK(aci.counts.coarserEvaluations == 0);
    checkGroundPoint(t, p, aci, ref);
}

TEST_CASE("coverage explores the light before it crowds rays where certificates stay small "
          "(random scenes 11213 and 9120)",
          "[aci][coverage]") {
    // Far ground points seeing a light at a grazing angle past an obstacle's flat face: rays to
    // one part of the light skim the face, their certificates prove under a 64th of what they
    // ask (reported as 0), and the cells there stayed the farthest from proven ground. Coverage
    // spent its 96 rays one beside the other there and took the rest of the light as lit:
    // - tests/scenes/random_seed11213.json (bench_bounds --lights mixed --fog seed 11213, the
    //   fogs left out): a level-set cylinder 0.36 across just under a triangle light; at
    //   (-3.1967, -6.0565) its shadow, 3.2% of the unoccluded form factor, went unseen
    //   (8.1617e-5 against 7.8989e-5);
    // - tests/scenes/random_seed9120.json (bench_bounds --lights mixed seed 9120): a level-set
    //   box whose corner comes within 0.01 of a disc light's plane; at (-1.8275, -3.8208) 3.7%
    //   of the unoccluded form factor unseen.
    // Both were within their (large) bounds. Two changes find them: a cell with no disc near
    // it measures its distance from proven ground to the nearest disc, not infinity, which tied
    // every such cell and sent coverage depth first into one (seed 9120); and coverage orders
    // cells by what a ray there could prove (Uncovered::reach) as well as by that distance
    // (seed 11213). References: penumbra probe --method reference --samples 1048576.
    {
        SceneUnderTest t("random_seed11213.json");
        const Vec3 p(-3.196737, -6.0564896, 0.0);
        checkGroundPoint(t, p, groundPoint(t, p, false), 7.89889288943e-05);
    }
    {
        SceneUnderTest t("random_seed9120.json");
        const Vec3 p(-1.82746604, -3.8207528, 0.0);
        checkGroundPoint(t, p, groundPoint(t, p, false), 0.000306360622866);
    }
}
