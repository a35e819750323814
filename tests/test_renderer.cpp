// Tests of renderer.h: the section 5 pipeline against per-pixel ACI, shaft culling against
// rendering with every obstacle as a candidate, thread-count independence, closed forms in fully
// lit regions and on the obstacles themselves, and the `penumbra render` command's errors.
#include <sys/wait.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>

#include <nlohmann/json.hpp>

#include "support/exact_shadow.h"
#include "support/render_scene.h"
#include "penumbra/camera.h"
#include "penumbra/error.h"
#include "penumbra/level_set.h"
#include "penumbra/occluder.h"
#include "penumbra/contour_integrator.h"
#include "penumbra/renderer.h"
#include "penumbra/scene.h"
#include "surface_normal.h"

using namespace penumbra;
namespace fs = std::filesystem;

namespace {

const Vec3 kSphereCenter(0.1, 0.05, 0.9);
const double kSphereRadius = 0.3;

using test::squareLight;

// Sphere above a white ground plane, seen from the side, with the whole penumbra in view.
Scene sphereScene(int size, ObstacleShape shape = AnalyticSphere{kSphereCenter, kSphereRadius}) {
    return test::squareLightScene(size, {Obstacle{"ball", shape, Rgb(0.5, 0.6, 0.7)}});
}

// The sphere scene plus a box with sharp corners and two obstacles far from every shaft.
Scene clutteredScene(int size) {
    Scene s = sphereScene(size);
    s.obstacles.push_back({"box", AnalyticBox{Vec3(-0.75, -0.2, 0.4), Vec3(-0.45, 0.25, 0.65)}});
    s.obstacles.push_back({"far ball", AnalyticSphere{Vec3(2.2, 1.8, 0.3), 0.3}});
    s.obstacles.push_back({"far box", AnalyticBox{Vec3(-2.6, 1.5, 0.0), Vec3(-2.0, 2.0, 0.5)}});
    return s;
}

RenderSettings settingsFor(Method m, int threads = 1) {
    RenderSettings rs;
    rs.method = m;
    rs.threads = threads;
    return rs;
}

// The default pipeline and per-pixel ACI (no coherence) on the same scene, w x h, two threads.
struct PipelineAndEach {
    RenderResult pipeline, each;
};
PipelineAndEach pipelineAndEach(const Scene& scene, int w, int h) {
    RenderSettings rs = settingsFor(Method::Aci, 2);
    rs.width = w;
    rs.height = h;
    PipelineAndEach out;
    out.pipeline = render(scene, rs);
    rs.method = Method::AciPixel;
    out.each = render(scene, rs);
    return out;
}

struct Diff {
    double mean8 = 0.0;  // mean over pixels and channels of 255 |a - b|
    double max8 = 0.0;
};

Diff difference(const Image& a, const Image& b) {
    REQUIRE(a.data.size() == b.data.size());
    Diff d;
    for (size_t i = 0; i < a.data.size(); ++i) {
        double e = 255.0 * std::abs(double(a.data[i]) - double(b.data[i]));
        d.mean8 += e;
        d.max8 = std::max(d.max8, e);
    }
    d.mean8 /= double(a.data.size());
    return d;
}

// The viewing ray through a pixel centre, written out again here (not via camera.h).
ViewRay rayByHand(const Camera& c, int x, int y) {
    Vec3 f = glm::normalize(c.lookAt - c.eye);
    Vec3 r = glm::normalize(glm::cross(f, c.up));
    Vec3 u = glm::cross(r, f);
    double t = std::tan(c.fovDeg * kPi / 360.0);
    double sx = (2.0 * (x + 0.5) / c.width - 1.0) * t * c.width / c.height;
    double sy = (1.0 - 2.0 * (y + 0.5) / c.height) * t;
    return ViewRay{c.eye, glm::normalize(f + sx * r + sy * u)};
}

// Nearest analytic hit of a ray with the test sphere; < 0 when it misses.
double raySphere(const ViewRay& r, const Vec3& c, double radius) {
    Vec3 oc = r.origin - c;
    double b = glm::dot(oc, r.direction);
    double disc = b * b - (glm::dot(oc, oc) - radius * radius);
    if (disc < 0.0) return -1.0;
    return -b - std::sqrt(disc);
}

std::string shellQuote(const std::string& s) { return "'" + s + "'"; }

struct CommandResult {
    int code = -1;
    std::string err;
};

CommandResult runPenumbra(const std::string& args, const fs::path& dir) {
    fs::path errFile = dir / "stderr.txt";
    std::string cmd = std::string(PENUMBRA_BINARY) + " " + args + " > /dev/null 2> " +
                      shellQuote(errFile.string());
    int status = std::system(cmd.c_str());
    CommandResult r;
    r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    std::ifstream in(errFile);
    std::stringstream ss;
    ss << in.rdbuf();
    r.err = ss.str();
    return r;
}

}  // namespace

TEST_CASE("the pipeline matches per-pixel ACI within 0.1 (8-bit) on average, with fewer rays",
          "[renderer]") {
    for (int which = 0; which < 2; ++which) {
        Scene scene = which == 0 ? sphereScene(48) : clutteredScene(48);
        RenderResult pipeline = render(scene, settingsFor(Method::Aci));
        RenderResult perPixel = render(scene, settingsFor(Method::AciPixel));
        Diff d = difference(pipeline.color, perPixel.color);
        INFO("scene " << which << ": mean " << d.mean8 << ", max " << d.max8 << " (8-bit units)");
        // Tolerance: interpolation across a run of equal first-level patterns errs by a few
        // 8-bit units at worst in the penumbra; averaged over the image it must stay below the
        // benchmark's target of 0.1. The worst pixel (9.7 in the cluttered scene) lies where
        // the box's edge and the sphere's silhouette meet inside one first-level square: there
        // per-pixel ACI itself is 7% low (the paper's mode needs three restarts to see the gap)
        // and interpolation spreads such an error over a few neighbours.
        CHECK(d.mean8 < 0.1);
        CHECK(d.max8 < 12.0);
        const RenderStats& a = pipeline.stats;
        const RenderStats& b = perPixel.stats;
        CHECK(a.viewingRays == 48u * 48u);
        CHECK(b.viewingRays == 48u * 48u);
        CHECK(a.viewingRayHits == b.viewingRayHits);
        CHECK(a.interpolatedPixels > 0);
        CHECK(a.culledSpans > 0);
        CHECK(b.interpolatedPixels == 0);
        CHECK(b.spans == 0);
        // A tiny image of wide penumbrae leaves little coherence to exploit (the 3x saving is
        // the benchmark's target at 800 x 800); fewer rays it must still be.
        CHECK(a.shadowRays < b.shadowRays);
        // Every shadow ray is a first- or second-level ray.
        CHECK(a.shadowRays == a.firstLevelRays + a.secondLevelRays);
        CHECK(b.shadowRays == b.firstLevelRays + b.secondLevelRays);
        // The per-pixel AOVs add up to the totals.
        double rays = 0.0, mask = 0.0;
        for (float v : pipeline.aovs.shadowRays.data) rays += v;
        for (float v : pipeline.aovs.mask.data) mask += v;
        CHECK(rays == double(a.shadowRays));
        CHECK(mask == double(a.viewingRaysWithShadowRays));
    }
}

TEST_CASE("shaft culling gives the image of rendering with every obstacle as a candidate",
          "[renderer]") {
    Scene scene = clutteredScene(40);
    // In the paper's and the "arcs" modes only visibility steers the estimator, so culling must
    // not change a single pixel. In the default tangent mode the Newton steps also follow the
    // distance to the nearest obstacle, and a culled one (which cannot block any ray of the
    // span) no longer steers them: lattice samples move, values by far less than a dropped
    // shadow would (a whole penumbra, tens of 8-bit units). Adaptive steps are off: whether an
    // evaluation takes one step fewer depends on the footprints of its candidates, and a culled
    // obstacle's footprint may still meet the light (0.25 units at most here with them on).
    const AciMode mode = GENERATE(AciMode::Arcs, AciMode::Tangent);
    RenderSettings culled = settingsFor(Method::Aci);
    culled.adaptiveSteps = false;
    applyAciMode(culled.aci, mode);
    RenderSettings all = culled;
    all.shaftCulling = false;
    RenderResult a = render(scene, culled);
    RenderResult b = render(scene, all);
    Diff d = difference(a.color, b.color);
    INFO("mode " << aciModeName(mode) << ": max " << d.max8 << ", mean " << d.mean8);
    CHECK(d.max8 < (mode == AciMode::Arcs ? 1e-6 : 0.1));
    CHECK(a.stats.spans == b.stats.spans);
    CHECK(a.stats.culledSpans > 0);
    CHECK(b.stats.culledSpans == 0);
    // Culling saves the arcs mode rays. The default's footprints prove a culled obstacle's
    // part of the light visible without a ray anyway (since the thirty-fifth session also one
    // lying level with or behind the receiver point, seen from the light: until then such an
    // obstacle left every sample to a ray, 1,049 shadow rays here culled and 19,261 not).
    if (mode == AciMode::Arcs) CHECK(a.stats.shadowRays < b.stats.shadowRays);
    CHECK(a.stats.shadowRays <= b.stats.shadowRays);
    // Certified coverage (the default's) casts rays of its own; the arcs mode none.
    CHECK((a.stats.coverageRays > 0) == (mode == AciMode::Tangent));
    CHECK(a.stats.coverageRays < a.stats.secondLevelRays + 1);
    // The paper's pattern coherence interpolates the same pixels. The default's checked
    // interpolation runs over the pixels that need rays, and culling takes the closed form at
    // more of them: its runs are shorter, not the same.
    if (mode == AciMode::Arcs) CHECK(a.stats.interpolatedPixels == b.stats.interpolatedPixels);
}

namespace {

// A small sphere just below the light and twelve pebbles near the ground (the coherence tests),
// seen from above at size x size.
Scene pebbleScene(int size) {
    std::vector<Obstacle> obstacles = {{"near the light", AnalyticSphere{Vec3(0.1, 0.0, 1.85), 0.05}}};
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-0.9, 0.9);
    for (int k = 0; k < 12; ++k)
        obstacles.push_back({"pebble", AnalyticSphere{Vec3(u(rng), u(rng), 0.12), 0.025}});
    return test::squareLightScene(size, obstacles);
}

// How far two renders' form factors are apart: the largest difference, the largest F of `b`,
// and by how much the difference exceeds the two pixels' error bounds together (<= 0: never).
struct FormFactorGap {
    double worst = 0.0, peak = 0.0, outside = 0.0;
};
FormFactorGap formFactorGap(const RenderResult& a, const RenderResult& b) {
    FormFactorGap g;
    const Image& fa = a.aovs.formFactor;
    for (int y = 0; y < fa.height; ++y)
        for (int x = 0; x < fa.width; ++x) {
            const double va = fa.at(x, y, 0), vb = b.aovs.formFactor.at(x, y, 0);
            g.peak = std::max(g.peak, vb);
            g.worst = std::max(g.worst, std::abs(va - vb));
            g.outside = std::max(g.outside, std::abs(va - vb) - a.aovs.errorBound.at(x, y, 0) -
                                                b.aovs.errorBound.at(x, y, 0));
        }
    return g;
}

}  // namespace

TEST_CASE("the default interpolates only where a check and the blocking obstacles allow",
          "[renderer][coherence]") {
    // A small sphere just below the light dims the whole ground a little (its shadow on the
    // light moves slowly with the receiver: smooth, interpolated), and tiny spheres near the
    // ground cast shadows a few pixels wide, which a check at quarter points alone could step
    // over. Interpolation over [l, r] needs every obstacle that may shadow a pixel of it to
    // block rays at each of the five evaluated pixels (renderer.cpp, shadeCheckedRun).
    const Scene scene = pebbleScene(120);
    RenderSettings s = settingsFor(Method::Aci, 2);
    const RenderResult coherent = render(scene, s);
    s.coherence = false;
    const RenderResult each = render(scene, s);
    INFO("interpolated " << coherent.stats.interpolatedPixels << " evaluations "
                         << coherent.stats.aciEvaluations << " / " << each.stats.aciEvaluations);
    // Every pixel that needs rays is evaluated or interpolated, never both, never neither.
    CHECK(coherent.stats.aciEvaluations + coherent.stats.interpolatedPixels ==
          each.stats.aciEvaluations);
    CHECK(coherent.stats.interpolatedPixels > 2000);
    // Fewer samples asked for (with exact spheres the footprints and kernels answer most
    // without a ray, so rays alone hardly differ).
    CHECK(coherent.stats.shadowRays + coherent.stats.footprintSamples <
          each.stats.shadowRays + each.stats.footprintSamples);
    const FormFactorGap gap = formFactorGap(coherent, each);
    const double worst = gap.worst, peak = gap.peak;
    // The check lets the shadow's quadratic miss by 0.0005 of the unoccluded form factor over
    // an interval twice as long as the ones interpolated: 0.001 of the image's largest F is a
    // bound with room. A pebble's shadow interpolated over would miss by tens of percent.
    INFO("largest difference " << worst << " for a largest F of " << peak);
    CHECK(worst < 0.001 * peak);
}

TEST_CASE("reusing first-level rays within a span saves rays and keeps the image", "[renderer]") {
    // In the tangent mode the pipeline answers a first-level ray again without tracing while the
    // pixel's point has moved less than that ray's distance bound (signed distances are
    // 1-Lipschitz): the patterns and the first level of full evaluations come out the same, so
    // the image may only move where a reused corner's approximate distance aims a probe
    // differently.
    // Reuse needs the tangent mode without coverage: with coverage (the default) each ray must
    // carry a certificate from its own origin, and nothing is reused.
    Scene scene = sphereScene(48, makeSphereLevelSet(kSphereCenter, kSphereRadius, 0.01, 3.0));
    CHECK(render(scene, settingsFor(Method::Aci)).stats.reusedRays == 0);
    RenderSettings reuse = settingsFor(Method::Aci);
    reuse.aci.coverage = false;
    RenderSettings fresh = reuse;
    fresh.reuseFirstLevel = false;
    RenderResult a = render(scene, reuse);
    RenderResult b = render(scene, fresh);
    Diff d = difference(a.color, b.color);
    INFO("rays " << a.stats.shadowRays << " against " << b.stats.shadowRays << ", reused "
                 << a.stats.reusedRays << "; mean " << d.mean8 << ", max " << d.max8);
    CHECK(a.stats.reusedRays > 0);
    CHECK(b.stats.reusedRays == 0);
    CHECK(a.stats.shadowRays < b.stats.shadowRays);
    CHECK(a.stats.viewingRaysWithShadowRays == b.stats.viewingRaysWithShadowRays);
    CHECK(d.mean8 < 0.05);
    CHECK(d.max8 < 3.0);
    // Still independent of the thread count.
    RenderSettings two = reuse;
    two.threads = 2;
    CHECK(render(scene, two).color.data == a.color.data);
}

TEST_CASE("a shaft contains every segment between its two boxes", "[renderer]") {
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-2.0, 2.0), size(0.05, 1.0), t(0.0, 1.0);
    auto randomBox = [&] {
        Box3 b;
        Vec3 lo(u(rng), u(rng), u(rng));
        b.extend(lo);
        b.extend(lo + Vec3(size(rng), size(rng), size(rng)));
        return b;
    };
    auto pointIn = [&](const Box3& b) {
        return Vec3(b.lo.x + t(rng) * (b.hi.x - b.lo.x), b.lo.y + t(rng) * (b.hi.y - b.lo.y),
                    b.lo.z + t(rng) * (b.hi.z - b.lo.z));
    };
    int hits = 0, culled = 0;
    for (int trial = 0; trial < 300; ++trial) {
        Box3 a = randomBox(), b = randomBox();
        Shaft shaft(a, b);
        for (int k = 0; k < 40; ++k) {
            Box3 c;
            Vec3 p = Vec3(u(rng), u(rng), u(rng));
            c.extend(p);
            c.extend(p + Vec3(0.2 * size(rng), 0.2 * size(rng), 0.2 * size(rng)));
            bool crossed = false;
            for (int s = 0; s < 60 && !crossed; ++s) {
                Vec3 from = pointIn(a), to = pointIn(b);
                Vec3 d = to - from;
                Vec3 inv(1.0 / d.x, 1.0 / d.y, 1.0 / d.z);
                double t0 = 0.0, t1 = 1.0;
                crossed = c.clipRay(from, inv, t0, t1);
            }
            bool overlaps = shaft.overlaps(c);
            if (crossed) {
                ++hits;
                REQUIRE(overlaps);  // never drops a box that a segment crosses
            } else if (!overlaps) {
                ++culled;
            }
        }
    }
    CHECK(hits > 100);
    CHECK(culled > 1000);
    // Two boxes offset diagonally: the planes cut off a box inside the common bounding box.
    Box3 a, b, c;
    a.extend(Vec3(0, 0, 0));
    a.extend(Vec3(1, 1, 1));
    b.extend(Vec3(3, 3, 0));
    b.extend(Vec3(4, 4, 1));
    c.extend(Vec3(3.2, 0.2, 0.2));
    c.extend(Vec3(3.8, 0.8, 0.8));
    Shaft diagonal(a, b);
    CHECK(diagonal.planeCount() == 2);
    CHECK_FALSE(diagonal.overlaps(c));
    Box3 onPath;
    onPath.extend(Vec3(1.9, 1.9, 0.4));
    onPath.extend(Vec3(2.1, 2.1, 0.6));
    CHECK(diagonal.overlaps(onPath));
}

TEST_CASE("a level set's solid parts hold every point where it blocks, and leave its holes out",
          "[renderer][occluder]") {
    // A tilted torus and a diagonal capsule fill a fraction of their solid boxes. Every point
    // where the interpolated field is <= 0 must lie in a part; a pyramid that meets no part
    // (Occluder::mayBlockIn) must let every traced segment through, and some pyramids the box
    // and sphere keep must be dropped by the parts.
    const Scene scene = parseScene(R"({
      "lights": [{"corner": [-0.3, -0.3, 3], "edge_u": [0.6, 0, 0], "edge_v": [0, 0.6, 0]}],
      "obstacles": [
        {"type": "torus", "center": [0, 0, 1.2], "major_radius": 0.5, "minor_radius": 0.08,
         "axis": [1, 0.3, 1]},
        {"type": "capsule", "a": [0.9, -0.9, 0.8], "b": [1.8, 0.2, 1.6], "radius": 0.07}],
      "receivers": [{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]}],
      "level_set": {"voxel_size": 0.02, "half_width": 3}})",
                                   "parts.json", ".");
    const Occluder occ = scene.makeOccluder();
    REQUIRE(occ.size() == 2);
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> t(0.0, 1.0);
    for (size_t i = 0; i < occ.size(); ++i) {
        const LevelSetPtr& ls = std::get<LevelSetPtr>(occ.shape(i));
        const std::vector<Box3>& parts = occ.solidParts(i);
        const Box3& box = occ.solidBounds(i);
        REQUIRE(!parts.empty());
        auto volume = [](const Box3& b) {
            const Vec3 d = b.hi - b.lo;
            return d.x * d.y * d.z;
        };
        double partsVolume = 0.0;
        for (const Box3& b : parts) partsVolume += volume(b);
        INFO("obstacle " << i << ": " << parts.size() << " parts, " << partsVolume / volume(box)
                         << " of the box");
        CHECK(partsVolume < 0.5 * volume(box));
        int inside = 0;
        for (int k = 0; k < 40000; ++k) {
            const Vec3 p = box.lo + Vec3(t(rng), t(rng), t(rng)) * (box.hi - box.lo);
            if (!(sampleLevelSet(*ls, p) <= 0.0)) continue;
            ++inside;
            const bool held = std::any_of(parts.begin(), parts.end(), [&](const Box3& b) {
                return p.x >= b.lo.x && p.y >= b.lo.y && p.z >= b.lo.z && p.x <= b.hi.x &&
                       p.y <= b.hi.y && p.z <= b.hi.z;
            });
            REQUIRE(held);
        }
        CHECK(inside > 200);
    }
    // Pyramids from points on the ground and below the obstacles to small quads above them.
    Occluder::Query q = occ.makeQuery();
    int droppedByParts = 0, traced = 0;
    std::uniform_real_distribution<double> u(-1.0, 2.0);
    for (int trial = 0; trial < 400; ++trial) {
        const Vec3 apex(u(rng), u(rng), 0.3 * t(rng));
        const Vec3 corner(u(rng), u(rng), 2.2 + t(rng));
        const Vec3 e1(0.1 + 0.3 * t(rng), 0.0, 0.0), e2(0.0, 0.1 + 0.3 * t(rng), 0.0);
        const std::vector<Vec3> quad = {corner, corner + e1, corner + e1 + e2, corner + e2};
        const Pyramid pyramid(apex, 0.0, quad);
        for (size_t i = 0; i < occ.size(); ++i) {
            if (occ.mayBlockIn(i, pyramid)) continue;
            if (pyramid.mayMeet(occ.solidBounds(i)) &&
                pyramid.mayMeet(occ.solidCentre(i), occ.solidRadius(i)))
                ++droppedByParts;
        }
        if (occ.mayBlockIn(0, pyramid) || occ.mayBlockIn(1, pyramid)) continue;
        for (int s = 0; s < 100; ++s) {
            ++traced;
            REQUIRE_FALSE(q.occluded(apex, corner + t(rng) * e1 + t(rng) * e2));
        }
    }
    CHECK(droppedByParts > 20);
    CHECK(traced > 5000);
}

TEST_CASE("a pyramid keeps every box and sphere that a segment to its polygon crosses",
          "[renderer]") {
    // Random apexes and tilted quadrilaterals; boxes and spheres anywhere around. A segment
    // from a point within `pad` of the apex to a point of the polygon that crosses a box or a
    // sphere must find it kept (Pyramid::mayMeet); boxes beyond the polygon's plane or beside
    // the pyramid are dropped.
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> u(-2.0, 2.0), t(0.0, 1.0), size(0.02, 0.4);
    int crossedBoxes = 0, crossedSpheres = 0, dropped = 0, droppedExactly = 0;
    for (int trial = 0; trial < 200; ++trial) {
        const Vec3 apex(u(rng), u(rng), u(rng) - 2.0);
        const Vec3 corner(u(rng), u(rng), 2.0 + 0.5 * u(rng));
        const Vec3 e1(1.0 + t(rng), 0.5 * u(rng), 0.3 * u(rng)), e2(0.3 * u(rng), 1.0 + t(rng), 0.3 * u(rng));
        const std::vector<Vec3> quad = {corner, corner + e1, corner + e1 + e2, corner + e2};
        const double pad = 0.05 * t(rng);
        const Pyramid pyramid(apex, pad, quad);
        for (int k = 0; k < 40; ++k) {
            const Vec3 p(u(rng), u(rng), 2.0 * u(rng));
            Box3 box;
            box.extend(p);
            box.extend(p + Vec3(size(rng), size(rng), size(rng)));
            const Vec3 centre = p;
            const double radius = size(rng);
            bool boxCrossed = false, sphereCrossed = false;
            for (int s = 0; s < 200; ++s) {
                const Vec3 jitter(u(rng), u(rng), u(rng));
                const Vec3 from = apex + pad * 0.5 * jitter / std::max(1.0, glm::length(jitter));
                const Vec3 to = corner + t(rng) * e1 + t(rng) * e2;
                const Vec3 d = to - from;
                double t0 = 0.0, t1 = 1.0;
                boxCrossed |= box.clipRay(from, Vec3(1.0 / d.x, 1.0 / d.y, 1.0 / d.z), t0, t1);
                const double along = std::clamp(glm::dot(centre - from, d) / glm::dot(d, d), 0.0, 1.0);
                sphereCrossed |= glm::length(from + along * d - centre) < radius;
            }
            if (boxCrossed) {
                ++crossedBoxes;
                REQUIRE(pyramid.mayMeet(box));
                REQUIRE(pyramid.mayMeetExactly(box));
            } else if (!pyramid.mayMeet(box)) {
                ++dropped;
            } else if (!pyramid.mayMeetExactly(box)) {
                ++droppedExactly;
            }
            if (sphereCrossed) {
                ++crossedSpheres;
                REQUIRE(pyramid.mayMeet(centre, radius));
            }
        }
    }
    CHECK(crossedBoxes > 200);
    CHECK(crossedSpheres > 200);
    CHECK(dropped > 2000);
    // The box's own axes and the edge crosses drop boxes beside the pyramid's edges.
    INFO("boxes dropped by the planes " << dropped << ", by the other axes " << droppedExactly);
    CHECK(droppedExactly > 20);
    // A box just beyond the polygon's plane, inside the pyramid's sides: dropped.
    const std::vector<Vec3> square = {Vec3(-1, -1, 2), Vec3(1, -1, 2), Vec3(1, 1, 2), Vec3(-1, 1, 2)};
    const Pyramid above(Vec3(0, 0, 0), 0.0, square);
    Box3 beyond;
    beyond.extend(Vec3(-0.1, -0.1, 2.01));
    beyond.extend(Vec3(0.1, 0.1, 2.2));
    CHECK_FALSE(above.mayMeet(beyond));
    CHECK(above.mayMeet(Vec3(0.0, 0.0, 1.9), 0.05));
    CHECK_FALSE(above.mayMeet(Vec3(1.5, 0.0, 1.0), 0.2));  // beside: the side plane is at x = 0.5
    // Beside the edge from the apex to (1, 1, 2), 0.3 from it along the outward normal
    // (1, 1, -1) / sqrt(3): outside the pyramid by 0.05, yet 0.232 outside each of the two
    // side planes that meet there, within its radius of both.
    const Vec3 besideEdge = Vec3(0.5, 0.5, 1.0) + 0.3 * glm::normalize(Vec3(1.0, 1.0, -1.0));
    CHECK_FALSE(above.mayMeet(besideEdge, 0.25));
    CHECK(above.mayMeet(besideEdge, 0.31));
}

TEST_CASE("row pairs interpolate between rows only where the rows agree, on any thread count",
          "[renderer][coherence]") {
    // The pebbles of the test above: shadows a few pixels wide, which rows two or four apart
    // could step over, and a smooth dimming from the sphere near the light, which they share.
    // A pixel pairs only when its rows above and below saw the same blockers and it has no
    // other candidate (renderer.cpp, shadeRowPairRun).
    // 150 rows: three bands of 64 rows on one thread, two of 80 on five.
    const Scene scene = pebbleScene(150);
    RenderSettings s = settingsFor(Method::Aci, 1);
    const RenderResult paired = render(scene, s);
    s.threads = 5;
    const RenderResult five = render(scene, s);
    CHECK(paired.color.data == five.color.data);
    CHECK(paired.aovs.errorBound.data == five.aovs.errorBound.data);
    CHECK(paired.stats.rowPairPixels == five.stats.rowPairPixels);
    s.rowPairs = false;
    const RenderResult single = render(scene, s);
    INFO("row pairs: " << paired.stats.rowPairPixels << " pixels, evaluations "
                       << paired.stats.aciEvaluations << " / " << single.stats.aciEvaluations);
    CHECK(paired.stats.rowPairPixels > 3000);
    CHECK(single.stats.rowPairPixels == 0);
    CHECK(paired.stats.aciEvaluations < single.stats.aciEvaluations);
    // Both answers' bounds together hold their difference (outside <= 0).
    const FormFactorGap gap = formFactorGap(paired, single);
    const double worst = gap.worst, peak = gap.peak, outside = gap.outside;
    // As for checked interpolation along a row: 0.001 of the largest F; a pebble's shadow
    // stepped over would miss by tens of percent.
    INFO("largest difference " << worst << " for a largest F of " << peak);
    CHECK(worst < 0.001 * peak);
    CHECK(outside <= 0.0);
}

TEST_CASE("one and two threads give the same pixels, bit for bit", "[renderer]") {
    for (int which = 0; which < 2; ++which) {
        Scene scene = which == 0
                          ? clutteredScene(40)
                          : sphereScene(32, makeSphereLevelSet(kSphereCenter, kSphereRadius, 0.02,
                                                               3.0, "ball"));
        RenderResult one = render(scene, settingsFor(Method::Aci, 1));
        RenderResult two = render(scene, settingsFor(Method::Aci, 2));
        CHECK(one.stats.threads == 1);
        CHECK(two.stats.threads == 2);
        CHECK(one.color.data == two.color.data);
        CHECK(one.aovs.shadowRays.data == two.aovs.shadowRays.data);
        CHECK(one.aovs.formFactor.data == two.aovs.formFactor.data);
        CHECK(one.aovs.mask.data == two.aovs.mask.data);
        CHECK(one.stats.shadowRays == two.stats.shadowRays);
        CHECK(one.stats.spans == two.stats.spans);
        CHECK(one.stats.aciEvaluations == two.stats.aciEvaluations);
        CHECK(one.stats.interpolatedPixels == two.stats.interpolatedPixels);
        CHECK(one.stats.gridIncreases == two.stats.gridIncreases);
    }
}

TEST_CASE("a long light: its first level in the statistics, patterns of its shape, one or two threads",
          "[renderer]") {
    // The square light stretched to 2.4 x 0.6 (4:1): tangent mode dices it 8 x 2.
    Scene scene = clutteredScene(40);
    RectLight& light = scene.lights.at(0);
    light.corner = Vec3(-0.3, -1.2, 2.0);
    light.edgeU = Vec3(0.0, 2.4, 0.0);
    light.edgeV = Vec3(0.6, 0.0, 0.0);
    const RenderResult one = render(scene, settingsFor(Method::Aci, 1));
    const RenderResult two = render(scene, settingsFor(Method::Aci, 2));
    REQUIRE(one.stats.aciFirstLevel.size() == 1);
    CHECK(one.stats.aciFirstLevel[0] == std::make_pair(8, 2));
    CHECK(one.color.data == two.color.data);
    CHECK(one.stats.shadowRays == two.stats.shadowRays);
    const nlohmann::json j = nlohmann::json::parse(one.stats.toJson());
    CHECK(j["aci_first_level"] == nlohmann::json::array({nlohmann::json::array({8, 2})}));
    // The paper's mode keeps p x p; Monte Carlo reports no first level.
    RenderSettings paper = settingsFor(Method::Aci);
    applyAciMode(paper.aci, AciMode::Paper);
    CHECK(render(scene, paper).stats.aciFirstLevel[0] == std::make_pair(2, 2));
    RenderSettings mc = settingsFor(Method::McSolidAngle);
    mc.mc.samples = 4;
    CHECK(render(scene, mc).stats.aciFirstLevel.empty());
    // Without coverage the pipeline interpolates along runs of equal shadow patterns (Vedel's
    // section 5): here the 27 corners of the 8 x 2 first level. Within the first test case's
    // tolerance of per-pixel ACI, and the same on two threads.
    RenderSettings patterns = settingsFor(Method::Aci, 1);
    patterns.aci.coverage = false;
    const RenderResult p1 = render(scene, patterns);
    patterns.threads = 2;
    const RenderResult p2 = render(scene, patterns);
    CHECK(p1.stats.aciFirstLevel[0] == std::make_pair(8, 2));
    CHECK(p1.stats.patternEvaluations > 0);
    CHECK(p1.stats.interpolatedPixels > 0);
    CHECK(p1.color.data == p2.color.data);
    patterns.method = Method::AciPixel;
    const Diff d = difference(p1.color, render(scene, patterns).color);
    INFO("mean " << d.mean8 << ", max " << d.max8);
    CHECK(d.mean8 < 0.1);
}

TEST_CASE("a fully lit region's mean equals the closed form; the sphere is shaded by its normal",
          "[renderer]") {
    const int size = 48;
    Scene scene = sphereScene(size);
    RenderResult result = render(scene, settingsFor(Method::Aci));
    const RectLight light = squareLight();
    const Camera& cam = *scene.camera;
    double litSum = 0.0, litExpected = 0.0, ballSum = 0.0, ballExpected = 0.0;
    double shadowErr = 0.0;
    int lit = 0, ball = 0, shadowed = 0;
    for (int y = 0; y < size; ++y) {
        for (int x = 0; x < size; ++x) {
            ViewRay r = rayByHand(cam, x, y);
            double tBall = raySphere(r, kSphereCenter, kSphereRadius);
            double tPlane = -r.origin.z / r.direction.z;
            double got = result.color.at(x, y, 0);
            if (tBall > 0.0) {
                // On the ball: exact Lambert polygon where the whole light is above the horizon.
                Vec3 m = r.at(tBall), n = glm::normalize(m - kSphereCenter);
                bool above = true;
                for (const Vec3& c : light.polygon()) above &= glm::dot(c - m, n) > 1e-3;
                if (!above) continue;
                ballSum += got;
                ballExpected += 0.5 * 10.0 * exact::lambertPolygon(light.polygon(), m, n);
                ++ball;
                continue;
            }
            if (!(tPlane > 0.0)) continue;
            Vec3 m = r.at(tPlane);
            // Parallel rectangle by superposition of four corner-above rectangles (Howell B-3).
            auto P = [&](double a, double b) { return exact::parallelRectCornerAbove(a, b, 2.0); };
            double open = P(0.5 - m.x, 0.5 - m.y) - P(-0.5 - m.x, 0.5 - m.y) -
                          P(0.5 - m.x, -0.5 - m.y) + P(-0.5 - m.x, -0.5 - m.y);
            double shadow = exact::sphereShadowFormFactor(m, Vec3(0, 0, 1), light.corner,
                                                          light.edgeU, light.edgeV, kSphereCenter,
                                                          kSphereRadius);
            if (std::abs(shadow - open) < 1e-12) {
                litSum += got;
                litExpected += 10.0 * open;
                ++lit;
            } else {
                shadowErr += std::abs(got - 10.0 * shadow);
                ++shadowed;
            }
        }
    }
    REQUIRE(lit > 200);
    REQUIRE(ball > 10);
    REQUIRE(shadowed > 50);
    // Float storage limits the agreement to about 1e-7 relative.
    CHECK(litSum / lit == Approx(litExpected / lit).epsilon(1e-6));
    CHECK(ballSum / ball == Approx(ballExpected / ball).epsilon(1e-5));
    // In the penumbra and umbra the pipeline carries ACI's own error (5 dichotomy steps on a
    // 2 x 2 grid) plus interpolation: on average below 0.5 % of the lit value.
    INFO("mean shadow error " << shadowErr / shadowed);
    CHECK(shadowErr / shadowed < 0.005 * 0.8);
}

TEST_CASE("level-set normals agree with the sphere's within a degree", "[renderer]") {
    LevelSetPtr ls = makeSphereLevelSet(kSphereCenter, kSphereRadius, 0.02, 3.0, "ball");
    ObstacleShape shape = ls;
    std::mt19937 rng(3);
    std::normal_distribution<double> g;
    double worst = 0.0;
    for (int i = 0; i < 200; ++i) {
        Vec3 dir = glm::normalize(Vec3(g(rng), g(rng), g(rng)));
        Vec3 n = surfaceNormal(shape, kSphereCenter + kSphereRadius * dir);
        CHECK(glm::length(n) == Approx(1.0).margin(1e-12));
        worst = std::max(worst, std::acos(std::min(1.0, glm::dot(n, dir))) * 180.0 / kPi);
    }
    INFO("worst angle " << worst << " degrees");
    CHECK(worst < 1.0);
    // Analytic shapes: exact normals.
    Vec3 ns = surfaceNormal(AnalyticSphere{Vec3(1, 2, 3), 2.0}, Vec3(1, 2, 5));
    CHECK(glm::length(ns - Vec3(0, 0, 1)) < 1e-15);
    AnalyticBox box{Vec3(0, 0, 0), Vec3(1, 2, 3)};
    CHECK(surfaceNormal(box, Vec3(0.5, 2.0, 1.0)) == Vec3(0, 1, 0));
    CHECK(surfaceNormal(box, Vec3(0.0, 1.0, 1.0)) == Vec3(-1, 0, 0));
    CHECK(surfaceNormal(box, Vec3(0.4, 1.0, 3.0)) == Vec3(0, 0, 1));
}

TEST_CASE("a level-set render matches per-pixel ACI", "[renderer]") {
    Scene scene =
        sphereScene(64, makeSphereLevelSet(kSphereCenter, kSphereRadius, 0.02, 3.0, "ball"));
    // 64 pixels a row: at 32 the spans are too short for coherence to pay for the pattern rays.
    RenderResult pipeline = render(scene, settingsFor(Method::Aci, 2));
    RenderResult perPixel = render(scene, settingsFor(Method::AciPixel, 2));
    Diff d = difference(pipeline.color, perPixel.color);
    INFO("mean " << d.mean8 << ", max " << d.max8 << " (8-bit units)");
    CHECK(d.mean8 < 0.1);
    CHECK(pipeline.stats.shadowRays < perPixel.stats.shadowRays);
}

TEST_CASE("render refuses a scene without camera and settings out of range", "[renderer]") {
    Scene scene = sphereScene(8);
    scene.camera.reset();
    scene.file = "nocam.json";
    try {
        render(scene, RenderSettings{});
        FAIL("no exception");
    } catch (const InputError& e) {
        CHECK(e.file() == "nocam.json");
        CHECK(e.where() == "/camera");
    }
    scene = sphereScene(8);
    auto where = [&](RenderSettings rs) {
        try {
            render(scene, rs);
        } catch (const InputError& e) {
            return e.where();
        }
        return std::string("no error");
    };
    // The library names its settings by the JSON model's keys (render_settings.h), never by a
    // command-line flag.
    RenderSettings rs;
    rs.width = -3;
    CHECK(where(rs) == "width");
    rs = RenderSettings{};
    rs.aci.grid = 0;
    CHECK(where(rs) == "aci_grid");
    rs = RenderSettings{};
    rs.aci.steps = 40;
    CHECK(where(rs) == "aci_steps");
    rs = RenderSettings{};
    rs.aci.grid = 32;
    rs.aci.steps = 12;
    CHECK(where(rs) == "aci_steps");  // the lattice would be too large
    rs = RenderSettings{};
    rs.mc.samples = 64;  // on an ACI render
    CHECK(where(rs) == "samples");
    CHECK(parseMethod("aci-pixel") == Method::AciPixel);
    CHECK_THROWS_AS(parseMethod("mc"), InputError);
}

TEST_CASE("penumbra render reports what building the level sets cost, in --verbose and --stats",
          "[renderer][cli]") {
    fs::path dir = fs::temp_directory_path() / ("penumbra_render_build_" + std::to_string(::getpid()));
    fs::remove_all(dir);
    fs::create_directories(dir);
    std::ofstream(dir / "scene.json") << R"({
      "camera": {"eye": [0.3,-3,3.2], "look_at": [0,0,0.3], "width": 12, "height": 10},
      "lights": [{"corner": [-0.5,-0.5,2], "edge_u": [0,1,0], "edge_v": [1,0,0]}],
      "obstacles": [{"name": "ball", "type": "sphere", "center": [0.1,0.05,0.9], "radius": 0.3},
                    {"name": "exact", "type": "sphere", "center": [0.8,0,0.5], "radius": 0.2,
                     "analytic": true}],
      "receivers": [{"type": "plane", "point": [0,0,0], "normal": [0,0,1]}],
      "level_set": {"voxel_size": 0.02}
    })";
    const std::string stats = (dir / "stats.json").string();
    CommandResult r = runPenumbra("render " + shellQuote((dir / "scene.json").string()) + " -o " +
                                      shellQuote((dir / "out.exr").string()) + " --stats " +
                                      shellQuote(stats) + " --quiet --verbose",
                                  dir);
    INFO(r.err);
    CHECK(r.code == 0);
    CHECK_THAT(r.err, Catch::Contains("obstacle 'ball' (sphere): ") && Catch::Contains(" voxels, ") &&
                          Catch::Contains("obstacle 'exact' (sphere): analytic") &&
                          Catch::Contains("level sets: "));
    nlohmann::json j;
    std::ifstream(stats) >> j;
    REQUIRE(j.contains("build"));
    const nlohmann::json& b = j["build"];
    REQUIRE(b["obstacles"].size() == 2);
    CHECK(b["obstacles"][0]["name"] == "ball");
    CHECK(b["obstacles"][0]["active_voxels"].get<uint64_t>() > 1000);
    CHECK(b["obstacles"][0]["bytes"].get<uint64_t>() > 0);
    CHECK(b["obstacles"][0]["voxel_size"].get<double>() == Approx(0.02));
    CHECK(b["obstacles"][1]["analytic"] == true);
    CHECK(b["active_voxels"] == b["obstacles"][0]["active_voxels"]);
    CHECK(b["seconds"].get<double>() >= 0.0);
    CHECK(b["memory_limit_bytes"].get<double>() > 0.0);
    fs::remove_all(dir);
}

TEST_CASE("penumbra render writes the image and statistics, and refuses bad flags in one line",
          "[renderer][cli]") {
    fs::path dir = fs::temp_directory_path() / ("penumbra_render_cli_" + std::to_string(::getpid()));
    fs::remove_all(dir);
    fs::create_directories(dir);
    const std::string sceneText = R"({
      "camera": {"eye": [0.3,-3,3.2], "look_at": [0,0,0.3], "up": [0,0,1], "fov_deg": 42,
                 "width": 20, "height": 16},
      "lights": [{"name": "key", "type": "rect", "corner": [-0.5,-0.5,2], "edge_u": [0,1,0],
                  "edge_v": [1,0,0], "radiance": [10,10,10]}],
      "obstacles": [{"type": "sphere", "center": [0.1,0.05,0.9], "radius": 0.3,
                     "analytic": true}],
      "receivers": [{"type": "plane", "point": [0,0,0], "normal": [0,0,1],
                     "albedo": [0.8,0.8,0.8]}]
    })";
    std::ofstream(dir / "scene.json") << sceneText;
    std::string noCamera = sceneText;
    noCamera.erase(noCamera.find("\"camera\""), noCamera.find("\"lights\"") - noCamera.find("\"camera\""));
    std::ofstream(dir / "nocam.json") << noCamera;
    const std::string scene = shellQuote((dir / "scene.json").string());
    const std::string out = (dir / "out.png").string();
    const std::string stats = (dir / "stats.json").string();

    CommandResult ok = runPenumbra("render " + scene + " -o " + shellQuote(out) + " --stats " +
                                       shellQuote(stats) + " --aov-rays " +
                                       shellQuote((dir / "rays.exr").string()) + " --quiet",
                                   dir);
    CHECK(ok.code == 0);
    CHECK(ok.err.empty());
    Image img = readImage(out);
    CHECK(img.width == 20);
    CHECK(img.height == 16);
    CHECK(readImageAttribute(out, "penumbra:method") == "aci");
    Image rays = readImage((dir / "rays.exr").string());
    nlohmann::json j;
    std::ifstream(stats) >> j;
    for (const char* key :
         {"method", "width", "height", "threads", "seconds", "viewing_rays",
          "viewing_rays_with_shadow_rays", "shadow_rays", "shadow_rays_per_viewing_ray", "spans",
          "interpolated_pixels", "aci_evaluations", "restarts", "coverage_rays",
          "footprint_samples", "footprint_clearances"}) {
        CHECK(j.contains(key));
    }
    CHECK(j["viewing_rays"] == 320);
    // Coverage's rays are a part of the second-level ones.
    CHECK(j["coverage_rays"].get<uint64_t>() <= j["second_level_rays"].get<uint64_t>());
    // The footprints' clearances are measured for samples they answered.
    CHECK(j["footprint_clearances"].get<uint64_t>() <= j["footprint_samples"].get<uint64_t>());
    double raySum = 0.0;
    for (float v : rays.data) raySum += v;
    CHECK(raySum == double(j["shadow_rays"].get<uint64_t>()));
    CHECK(j["shadow_rays_per_viewing_ray"].get<double>() ==
          Approx(double(j["shadow_rays"].get<uint64_t>()) /
                 double(j["viewing_rays_with_shadow_rays"].get<uint64_t>())));

    struct Bad {
        std::string args, mentions;
    };
    const std::vector<Bad> bad = {
        {"render " + scene + " -o x.png --width 0", "--width"},
        {"render " + scene + " -o x.png --height 100000", "--height"},
        {"render " + scene + " -o x.png --threads 0", "--threads"},
        {"render " + scene + " -o x.png --aci-grid 0", "--aci-grid"},
        {"render " + scene + " -o x.png --aci-steps 99", "--aci-steps"},
        {"render " + scene + " -o x.png --method mc", "--method"},
        {"render " + scene + " -o x.bmp", "-o"},
        {"render " + scene + " -o x.png --aov-mask m.jpg", "--aov-mask"},
        {"render " + shellQuote((dir / "nocam.json").string()) + " -o x.png", "/camera"},
    };
    for (const Bad& b : bad) {
        CommandResult r = runPenumbra(b.args, dir);
        INFO(b.args << " -> " << r.err);
        CHECK(r.code == 2);
        CHECK(std::count(r.err.begin(), r.err.end(), '\n') == 1);
        CHECK(r.err.find(b.mentions) != std::string::npos);
    }
    CHECK_FALSE(fs::exists("x.png"));
    CHECK_FALSE(fs::exists(dir / "x.png"));
    fs::remove_all(dir);
}

TEST_CASE("checked interpolation puts no light into an umbra (the default scene at 200 x 200)",
          "[renderer][coherence]") {
    // Under the default scene's box, pixels 136-138 of row 129 lie in the umbra, and the
    // samples of a checked interval around them (blocked by the box alone at each, two of them
    // in the umbra) passed the quartic's check: the shadow turns at the umbra's edge, between
    // samples, and the quartic put up to 0.0033 of F there (6.8 of 255 too bright). Samples
    // must now agree on whether they see any of the light, as on their blockers.
    const Scene scene = loadScene(std::string(PENUMBRA_SOURCE_DIR) + "/vdb_scenes/default.json");
    const auto [pipeline, each] = pipelineAndEach(scene, 200, 200);
    int umbra = 0;
    double worst = 0.0;
    for (int y = 0; y < 200; ++y)
        for (int x = 0; x < 200; ++x) {
            if (each.aovs.mask.at(x, y) == 0.0f || each.aovs.formFactor.at(x, y) != 0.0f) continue;
            ++umbra;
            worst = std::max(worst, double(pipeline.aovs.formFactor.at(x, y)));
        }
    CAPTURE(umbra, worst);
    REQUIRE(umbra > 100);
    CHECK(worst <= 1e-6);
}

TEST_CASE("no interpolation across pixels whose tangent planes cut the light (the bunny's flank)",
          "[renderer][coherence]") {
    // Pixels (96-103, 102-103) of vdb_scenes/bunny.json at 200 x 200 lie on the bunny's flank,
    // where its tangent plane cuts the light and the level set's normal turns from pixel to
    // pixel: the light's part above the horizon, hence the unoccluded G and the shadow, is no
    // smooth function along the row. Checked interpolation passed there and put up to 0.002 of
    // F (5.6 of 255) too much light; evaluated one by one they are within 0.03 of 255 of a
    // 65,536-ray reference. Rows 94-109 of that image, each row's pixels where they were (a
    // camera turned down to their middle, its field of view narrowed to 16 rows).
    Scene scene = loadScene(std::string(PENUMBRA_SOURCE_DIR) + "/vdb_scenes/bunny.json");
    Camera& cam = *scene.camera;
    cam.width = cam.height = 200;
    const ViewRay centre = PinholeCamera(cam).ray(100.0, 102.0);
    cam.lookAt = cam.eye + centre.direction;
    cam.fovDeg = 2.0 * std::atan(0.08 * std::tan(0.5 * cam.fovDeg * kPi / 180.0)) * 180.0 / kPi;
    const auto [pipeline, each] = pipelineAndEach(scene, 200, 16);
    int shaded = 0;
    double worst = 0.0;
    for (int y = 0; y < 16; ++y)
        for (int x = 0; x < 200; ++x) {
            if (each.aovs.mask.at(x, y) == 0.0f) continue;
            ++shaded;
            worst = std::max(worst, std::abs(double(pipeline.aovs.formFactor.at(x, y)) -
                                             each.aovs.formFactor.at(x, y)));
        }
    CAPTURE(shaded, worst, pipeline.stats.interpolatedPixels);
    REQUIRE(shaded > 1000);
    // 0.0005 of F is 1.4 of 255 under this light on the bunny's albedo.
    CHECK(worst <= 0.0005);
}
