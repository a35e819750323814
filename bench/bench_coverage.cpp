// Benchmark of the estimator on seeded random scenes of spheres nobody tuned: 1 to 8 spheres
// with radii from 2% to 40% of the light's edge, anywhere between the receiver plane and a
// 2 x 2 light at height 4, random receiver points on the plane. Each scene is run twice: with
// exact (analytic) spheres, whose answers are exact (tests/support/exact_shadow.h, rectMinusObstacles),
// and with the same spheres as level sets (voxel 0.01), against the same exact answers (the
// level sets' own voxelization error is about 0.005 voxel, tests/test_level_set_bias.cpp).
// Prints, per ACI mode and Monte Carlo at equal time: rays per point, microseconds per point on
// one thread, maximum and mean error relative to the unoccluded form factor, and, for the
// default mode, the median error bound against the median error; under each ACI mode, its rays
// per point in penumbra, fully lit and in umbra (by the exact answer), and how many of them
// certified coverage cast, and how many lattice samples the footprints answered without a ray
// ("untraced"; of them, "clearances": those whose clearance the tangent construction then
// measured, a distance march along the segment that is not counted as a shadow ray).
// Not a test: it only prints figures. Usage: bench_coverage [scenes [points-per-scene [analytic|levelset]]]
// (`analytic`: the exact spheres only, without building level sets; `levelset`: the level sets only).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <vector>

#include "bench_common.h"
#include "support/exact_shadow.h"
#include "support/paper_scene.h"
#include "penumbra/contour_integrator.h"
#include "penumbra/level_set.h"
#include "penumbra/monte_carlo.h"

using namespace penumbra;

namespace {

struct Case {
    std::vector<AnalyticSphere> spheres;
    std::vector<Receiver> points;
    std::vector<double> exact, full;
};

struct Totals {
    std::vector<double> errors, bounds;
    double rays = 0, seconds = 0;
    // Per point: its rays, of them coverage's, and what it sees (0 umbra, 1 penumbra, 2 fully
    // lit, by the exact answer).
    std::vector<double> pointRays, pointCoverage;
    // Per point: lattice samples the footprints answered without a ray, and of them those
    // whose clearance the tangent construction measured (a distance march, not a shadow ray).
    std::vector<double> pointFootprint, pointFootprintClear;
    std::vector<int> kind;
};

RectLight light2x2() { return test::paperLight(); }

std::vector<Case> makeCases(int scenes, int points) {
    const RectLight light = light2x2();
    std::mt19937 rng(20261126);
    std::uniform_real_distribution<double> u01(0.0, 1.0);
    std::vector<Case> cases;
    for (int s = 0; s < scenes; ++s) {
        Case c;
        const int count = 1 + s % 8;
        for (int k = 0; k < count; ++k) {
            const double radius = 2.0 * (0.02 + 0.38 * std::pow(u01(rng), 2.0));
            const double z = 0.5 + radius + (3.5 - 2.0 * radius - 0.5) * u01(rng);
            c.spheres.push_back({Vec3(-1.2 + 2.4 * u01(rng), -1.2 + 2.4 * u01(rng), z), radius});
        }
        std::vector<exact::SphereObstacle> es;
        for (const AnalyticSphere& a : c.spheres) es.push_back({a.center, a.radius});
        for (int k = 0; k < points; ++k) {
            const Receiver r{Vec3(-2.0 + 4.0 * u01(rng), -2.0 + 4.0 * u01(rng), 0.0), Vec3(0, 0, 1)};
            c.points.push_back(r);
            c.exact.push_back(exact::rectMinusObstacles(r.point, r.normal, light.corner,
                                                        light.edgeU, light.edgeV, es));
            c.full.push_back(unoccludedFormFactor(light, r));
        }
        cases.push_back(std::move(c));
    }
    return cases;
}

template <typename Estimator>
Totals run(const std::vector<Case>& cases, const std::vector<Occluder>& occluders,
           Estimator estimate) {
    const RectLight light = light2x2();
    Totals t;
    for (size_t s = 0; s < cases.size(); ++s) {
        Occluder::Query q = occluders[s].makeQuery();
        const auto t0 = std::chrono::steady_clock::now();
        std::vector<Estimate> out;
        for (const Receiver& r : cases[s].points) out.push_back(estimate(r, light, q));
        t.seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        for (size_t k = 0; k < out.size(); ++k) {
            t.errors.push_back(std::abs(out[k].formFactor - cases[s].exact[k]) / cases[s].full[k]);
            t.bounds.push_back(out[k].errorBound / cases[s].full[k]);
            t.rays += double(out[k].counts.shadowRays());
            t.pointRays.push_back(double(out[k].counts.shadowRays()));
            t.pointCoverage.push_back(double(out[k].counts.coverageRays));
            t.pointFootprint.push_back(double(out[k].counts.footprintSamples));
            t.pointFootprintClear.push_back(double(out[k].counts.footprintClearances));
            const double seen = cases[s].exact[k] / cases[s].full[k];
            t.kind.push_back(seen < 1e-9 ? 0 : seen > 1.0 - 1e-9 ? 2 : 1);
        }
    }
    return t;
}

double median(std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
}

void print(const char* occ, const char* name, const Totals& t) {
    const double n = double(t.errors.size());
    double mx = 0, sum = 0;
    int outside = 0;
    for (size_t i = 0; i < t.errors.size(); ++i) {
        mx = std::max(mx, t.errors[i]);
        sum += t.errors[i];
        if (std::isfinite(t.bounds[i]) && t.errors[i] > t.bounds[i] + 1e-12) ++outside;
    }
    const bool bounded = std::isfinite(t.bounds[0]);
    std::printf("%-10s %-34s %8.1f %9.1f %8.3f%% %8.4f%% %8.4f%%", occ, name, t.rays / n,
                1e6 * t.seconds / n, 100 * mx, 100 * sum / n, 100 * median(t.errors));
    if (bounded)
        std::printf(" %8.4f%% %6d\n", 100 * median(t.bounds), outside);
    else
        std::printf("        -      -\n");
}

// Rays per point by what the point sees (issue 11 counts rays per penumbra point).
void printByKind(const Totals& t) {
    const char* names[3] = {"in umbra", "in penumbra", "fully lit"};
    std::printf("%-10s   ", "");
    for (int kd : {1, 2, 0}) {
        double rays = 0, coverage = 0, footprint = 0, clear = 0;
        int n = 0;
        for (size_t i = 0; i < t.kind.size(); ++i) {
            if (t.kind[i] != kd) continue;
            rays += t.pointRays[i];
            coverage += t.pointCoverage[i];
            footprint += t.pointFootprint[i];
            clear += t.pointFootprintClear[i];
            ++n;
        }
        if (n == 0) continue;
        std::printf("%s%d %s: %.1f rays/pt", kd == 1 ? "" : "; ", n, names[kd], rays / n);
        if (coverage > 0) std::printf(" (%.1f coverage)", coverage / n);
        if (footprint > 0)
            std::printf(" + %.1f untraced (%.1f clearances)", footprint / n, clear / n);
    }
    std::printf("\n");
}

}  // namespace

int main(int argc, char** argv) {
    bench::helpIfAsked(argc, argv,
                       "usage: bench_coverage [scenes (default 40) [points-per-scene (default 20) "
                       "[analytic|levelset]]]");
    const int scenes = argc > 1 ? int(bench::positiveArg("bench_coverage", argv[1], "scenes")) : 40;
    const int points =
        argc > 2 ? int(bench::positiveArg("bench_coverage", argv[2], "points-per-scene")) : 20;
    const std::string only = argc > 3 ? argv[3] : "";
    if (!only.empty() && only != "analytic" && only != "levelset")
        bench::failUsage("bench_coverage", "kind: '" + only + "' is neither analytic nor levelset");
    const std::vector<Case> cases = makeCases(scenes, points);
    std::printf("%d random scenes of 1-8 spheres, %d receiver points each; light 2 x 2 at height 4; "
                "errors relative to the unoccluded form factor, against exact answers.\n",
                scenes, points);
    std::printf("%-10s %-34s %8s %9s %9s %9s %9s %9s %6s\n", "occluder", "method", "rays/pt",
                "us/pt", "max err", "mean err", "med err", "med bnd", "out");
    for (int kind = 0; kind < 2; ++kind) {
        if ((only == "analytic" && kind == 1) || (only == "levelset" && kind == 0)) continue;
        std::vector<Occluder> occluders;
        const auto b0 = std::chrono::steady_clock::now();
        for (const Case& c : cases) {
            Occluder o;
            for (const AnalyticSphere& s : c.spheres) {
                if (kind == 0) o.add(s);
                else o.add(makeSphereLevelSet(s.center, s.radius, 0.01, 3.0));
            }
            if (kind == 1) {
                o.prepareClearance();
                // The kernel balls too (built on first use otherwise, inside the first
                // evaluation, whose time they would join).
                for (size_t i = 0; i < o.size(); ++i) o.kernelBalls(i);
            }
            occluders.push_back(std::move(o));
        }
        const double build = std::chrono::duration<double>(std::chrono::steady_clock::now() - b0).count();
        const char* occ = kind == 0 ? "analytic" : "level set";
        if (kind == 1)
            std::printf("(level sets at voxel 0.01: building them, their companions and kernel balls took %.1f s, "
                        "not counted below)\n", build);
        Totals def;
        for (AciMode mode : {AciMode::Tangent, AciMode::Arcs, AciMode::Paper}) {
            AciSettings s;
            s.gradient = false;
            applyAciMode(s, mode);
            ContourIntegrator aci(s);
            Totals t = run(cases, occluders, [&](const Receiver& r, const RectLight& l,
                                                 Occluder::Query& q) { return aci.evaluate(r, l, q); });
            std::string name = std::string("aci ") + aciModeName(mode) +
                               (mode == AciMode::Tangent ? " (default)" : "");
            print(occ, name.c_str(), t);
            printByKind(t);
            if (mode == AciMode::Tangent) def = t;
        }
        {
            // The default as `penumbra render` runs it without AOV files: no bound, no gradient.
            AciSettings s;
            s.gradient = false;
            s.errorBound = false;
            ContourIntegrator aci(s);
            Totals t = run(cases, occluders, [&](const Receiver& r, const RectLight& l,
                                                 Occluder::Query& q) { return aci.evaluate(r, l, q); });
            print(occ, "aci tangent, no bound", t);
            def.seconds = t.seconds;  // Monte Carlo below runs at the time a render spends
        }
        // Monte Carlo (spherical-rectangle sampling) at the default's time per point without the
        // bound: the sample count from a calibration run at 64 samples.
        McSettings mc;
        mc.samples = 64;
        Totals cal = run(cases, occluders, [&](const Receiver& r, const RectLight& l,
                                               Occluder::Query& q) { return monteCarloSolidAngle(r, l, q, mc); });
        mc.samples = std::max(1, int(std::lround(64.0 * def.seconds / cal.seconds)));
        Totals eq = run(cases, occluders, [&](const Receiver& r, const RectLight& l,
                                              Occluder::Query& q) { return monteCarloSolidAngle(r, l, q, mc); });
        char name[64];
        std::snprintf(name, sizeof name, "mc-solid-angle %d (equal time: %.2fx)", mc.samples,
                      eq.seconds / def.seconds);
        for (double& b : eq.bounds) b = std::nan("");
        print(occ, name, eq);
        mc.samples = std::max(1, int(std::lround(def.rays / double(def.errors.size()))));
        Totals er = run(cases, occluders, [&](const Receiver& r, const RectLight& l,
                                              Occluder::Query& q) { return monteCarloSolidAngle(r, l, q, mc); });
        std::snprintf(name, sizeof name, "mc-solid-angle %d (equal rays)", mc.samples);
        for (double& b : er.bounds) b = std::nan("");
        print(occ, name, er);
    }
    return 0;
}
