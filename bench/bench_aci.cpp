// Benchmark of the contour-integration estimator on lines of receiver points crossing the
// penumbra of a sphere and of a cube, against the exact answers (tests/support/exact_shadow.h).
// Prints, per scene and occluder kind, the mean shadow rays per penumbra point and the mean
// error relative to the unoccluded form factor, at the paper's defaults and at other settings.
// Not a test: it only prints figures. Usage: bench_aci [points-per-line [setting-filter]]
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "bench_common.h"
#include "support/exact_shadow.h"
#include "penumbra/contour_integrator.h"
#include "penumbra/level_set.h"

using namespace penumbra;

namespace {

struct Line {
    std::vector<Receiver> points;
    std::vector<double> exact;
};

struct Row {
    double raysPerPenumbraPoint = 0, meanRelError = 0, maxRelError = 0, usPerPoint = 0;
    double firstPerPoint = 0, refinedPerPoint = 0, restartsPerPoint = 0;
    int penumbraPoints = 0;
};

Row run(const Line& line, const RectLight& light, const Occluder& occ, const AciSettings& s) {
    Occluder::Query query = occ.makeQuery();
    ContourIntegrator aci(s);
    Row row;
    double err = 0, unocc = 0;
    uint64_t rays = 0, first = 0, refined = 0, restarts = 0;
    const auto t0 = std::chrono::steady_clock::now();
    for (size_t i = 0; i < line.points.size(); ++i) {
        const Receiver& r = line.points[i];
        const Estimate e = aci.evaluate(r, light, query);
        const double u = unoccludedFormFactor(light, r);
        // A penumbra point: the exact answer is strictly between umbra and full light.
        if (line.exact[i] > 1e-9 * u && line.exact[i] < u * (1 - 1e-9)) {
            ++row.penumbraPoints;
            rays += e.counts.shadowRays();
            first += e.counts.firstLevelRays;
            refined += e.counts.squaresRefined;
            restarts += e.counts.restarts;
            err += std::abs(e.formFactor - line.exact[i]);
            unocc += u;
            row.maxRelError = std::max(row.maxRelError, std::abs(e.formFactor - line.exact[i]) / u);
            if (std::getenv("BENCH_ACI_VERBOSE") &&
                std::abs(e.formFactor - line.exact[i]) > 0.01 * u)
                std::printf("  point %zu x=%.4f: F=%.6f exact=%.6f (%.2f%%), %llu rays\n", i,
                            r.point.x, e.formFactor, line.exact[i],
                            100 * std::abs(e.formFactor - line.exact[i]) / u,
                            static_cast<unsigned long long>(e.counts.shadowRays()));
        }
    }
    const double secs =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    row.raysPerPenumbraPoint = double(rays) / std::max(1, row.penumbraPoints);
    row.firstPerPoint = double(first) / std::max(1, row.penumbraPoints);
    row.refinedPerPoint = double(refined) / std::max(1, row.penumbraPoints);
    row.restartsPerPoint = double(restarts) / std::max(1, row.penumbraPoints);
    row.meanRelError = err / std::max(unocc, 1e-300);
    row.usPerPoint = 1e6 * secs / line.points.size();
    return row;
}

void print(const char* scene, const char* occluder, const char* setting, const Row& r) {
    std::printf("%-7s %-22s %-26s %6d %8.2f %6.2f %6.2f %6.2f %9.3f%% %8.3f%% %8.1f\n", scene,
                occluder, setting, r.penumbraPoints, r.raysPerPenumbraPoint, r.firstPerPoint,
                r.refinedPerPoint, r.restartsPerPoint, 100 * r.meanRelError, 100 * r.maxRelError,
                r.usPerPoint);
}

}  // namespace

int main(int argc, char** argv) {
    bench::helpIfAsked(argc, argv,
                       "usage: bench_aci [points-per-line (default 400) [setting-filter]]");
    const int count = argc > 1 ? int(bench::positiveArg("bench_aci", argv[1], "points-per-line")) : 400;
    RectLight light;
    light.corner = Vec3(-1, -1, 4);
    light.edgeU = Vec3(0, 2, 0);
    light.edgeV = Vec3(2, 0, 0);
    const Vec3 up(0, 0, 1);

    const Vec3 center(0.3, 0.2, 2.0);
    const double radius = 0.7;
    const Vec3 boxLo(-0.35, -0.25, 1.6), boxHi(0.25, 0.35, 2.2);
    std::vector<Vec3> boxVertices;
    for (int i = 0; i < 8; ++i)
        boxVertices.push_back(Vec3(i & 1 ? boxHi.x : boxLo.x, i & 2 ? boxHi.y : boxLo.y,
                                   i & 4 ? boxHi.z : boxLo.z));

    Line sphereLine, cubeLine;
    for (int i = 0; i < count; ++i) {
        const double x = -3.0 + 6.0 * (i + 0.5) / count;
        const Receiver r{Vec3(x, 0.4 + 0.05 * (x - 0.6), 0.0), up};
        sphereLine.points.push_back(r);
        sphereLine.exact.push_back(exact::sphereShadowFormFactor(
            r.point, up, light.corner, light.edgeU, light.edgeV, center, radius));
        cubeLine.points.push_back(r);
        cubeLine.exact.push_back(exact::convexPolyhedronShadowFormFactor(
            r.point, up, light.corner, light.edgeU, light.edgeV, boxVertices));
    }

    const double voxel = 0.01;
    struct Case {
        const char* scene;
        const char* kind;
        Occluder occ;
        const Line* line;
    };
    std::vector<Case> cases;
    cases.push_back({"sphere", "analytic", Occluder({AnalyticSphere{center, radius}}), &sphereLine});
    cases.push_back({"sphere", "level set (voxel 0.01)",
                     Occluder({makeSphereLevelSet(center, radius, voxel, 3.0)}), &sphereLine});
    cases.push_back({"cube", "analytic", Occluder({AnalyticBox{boxLo, boxHi}}), &cubeLine});
    cases.push_back({"cube", "level set (voxel 0.01)",
                     Occluder({makeBoxLevelSet(boxLo, boxHi, voxel, 3.0)}), &cubeLine});

    struct Setting {
        std::string name;
        AciSettings s;
    };
    std::vector<Setting> settings;
    auto add = [&](const std::string& name, int grid, int steps, bool refine,
                   bool guided = false, bool curved = false, int probes = 0,
                   bool tangent = false) {
        AciSettings s;
        s.grid = grid;
        s.steps = steps;
        s.refine = refine;
        s.distanceGuided = guided;
        s.curvedContour = curved;  // the paper's rows integrate straight chords...
        s.midlineCheck = curved;   // ...and check case-3 squares on a random diagonal
        s.guidedProbes = probes;
        s.tangentContour = tangent;
        s.coverage = tangent;  // certified coverage belongs to the tangent mode
        s.rayOffset = 1e-6;
        settings.push_back({name, s});
    };
    // Rows 1-4: the paper's method (straight chords, bisection). Then Penumbra's modes beyond
    // the paper: "arcs" (parabolic arcs, midline check), the distance-guided secant dichotomy,
    // and the tangent mode, whose 2x2, n=5 row is the default of AciSettings and the CLI.
    add("paper 2x2, n=5", 2, 5, true);
    add("paper 2x2, n=5, no refine", 2, 5, false);
    add("paper 2x2, n=6", 2, 6, true);
    add("paper 4x4, n=4", 4, 4, true);
    add("arcs 2x2, n=5", 2, 5, true, false, true);
    add("guided 2x2, n=5", 2, 5, true, true, true);
    add("guided 2x2, n=4", 2, 4, true, true, true);
    add("guided 2x2, n=3", 2, 3, true, true, true);
    add("guided 2x2, n=3, 1 probe", 2, 3, true, true, true, 1);
    add("tangent 2x2, n=3", 2, 3, true, true, true, 1, true);
    add("tangent 2x2, n=4", 2, 4, true, true, true, 1, true);
    add("DEFAULT tangent 2x2, n=5", 2, 5, true, true, true, 1, true);
    add("tangent 2x2, n=5, 2 probes", 2, 5, true, true, true, 2, true);
    settings.push_back(settings[settings.size() - 2]);
    settings.back().name = "tangent 2x2, n=5, no coverage";
    settings.back().s.coverage = false;
    add("tangent 1x1, n=5", 1, 5, true, true, true, 1, true);

    std::printf("Receiver lines of %d points; light 2 x 2 at height 4; errors relative to the "
                "unoccluded form factor.\n", count);
    std::printf("%-7s %-22s %-26s %6s %8s %6s %6s %6s %10s %9s %8s\n", "scene", "occluder",
                "setting", "points", "rays/pt", "1st", "refin", "restrt", "mean err", "max err",
                "us/pt");
    // An optional second argument keeps only the settings whose name contains it.
    const std::string filter = argc > 2 ? argv[2] : "";
    for (const Case& c : cases)
        for (const Setting& s : settings)
            if (s.name.find(filter) != std::string::npos)
                print(c.scene, c.kind, s.name.c_str(), run(*c.line, light, c.occ, s.s));
    return 0;
}
