// Does every answer stay within its error bound on scenes nobody tuned? For each seeded random
// scene (bench/random_scenes.h, the scenes of bench_random), the receiver points that the
// camera's pixels see on a lattice of its image (every --stride-th pixel of a --size x --size
// image, alternate rows shifted by half a stride; ground and obstacles alike) get default ACI
// with its error bound and a Monte Carlo reference (mc-ratio, --samples rays: the closed form
// times the cosine-weighted visible fraction, exact where nothing is hidden). Where the
// difference exceeds the bound plus four of the reference's standard deviations, the reference
// is redone with --confirm rays and the point is a violation if it still does; each violation is
// printed with what reproduces it (`penumbra probe --error-bound` on the scene file at that
// point and normal). Column off>0.1%: points confirmed the same way to be more than 0.1% of the
// unoccluded form factor F0 off, within their bound or not (a loose bound hides nothing there);
// max err/F0 is the largest confirmed difference. A check, not a timing: never fails on a
// figure, prints what it found.
//
//   bench_bounds [--seeds N] [--first-seed S] [--size 200] [--stride 4] [--samples 4096]
//                [--confirm 1048576] [--threads 2] [--steps 5] [--out DIR] [--lights rect]
//                [--fog] [--light-scale 1] [--render]
//
// --lights rect|mixed: the scenes' lights (bench/random_scenes.h, LightShapes): rect, the
// rectangles of every figure before 2026-12-05; mixed, a seed's light made a rectangle, disc,
// triangle or convex 5- to 7-gon on the same frame, the rest of the scene unchanged.
// --fog: one or two fog volumes more in each scene (bench/random_scenes.h, "Volumes"), with
// either --lights. The reference (mc-ratio) weights its samples by their transmittance.
// --light-scale S: each scene's light grown S times about its centre once the rest is drawn
// (radiance over S^2): lights far larger than their distance from the receivers.
// --steps: ACI's dichotomy steps n (default 5, as probe's and render's).
// --render: each point evaluated as `penumbra render` evaluates a pixel (adaptive steps on, one
// coverage allowance: AciSettings::extendCoverage 0) instead of as `penumbra probe` does.
//
// Each scene is written to DIR/seed_S.json (default /tmp/penumbra_bounds) before it is parsed.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include <tbb/enumerable_thread_specific.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#include "bench_common.h"
#include "random_scenes.h"
#include "penumbra/camera.h"
#include "penumbra/contour_integrator.h"
#include "penumbra/estimator.h"
#include "penumbra/form_factor.h"
#include "penumbra/monte_carlo.h"
#include "penumbra/renderer.h"
#include "penumbra/scene.h"
#include "surface_normal.h"

using namespace penumbra;

namespace {

struct Args {
    int seeds = 10, firstSeed = 1, size = 200, stride = 4, samples = 4096, confirm = 1 << 20;
    int threads = 2;
    int steps = 5;  // AciSettings' (probe's) default
    std::string out = "/tmp/penumbra_bounds";
    std::string lights = "rect";
    bool fog = false;
    double lightScale = 1.0;
    bool render = false;  // the renderer's evaluation settings instead of probe's
};

// A receiver point seen through a pixel: the nearest receiver plane, or the obstacle that a
// segment to it crosses first.
std::optional<Receiver> seenAt(const Scene& scene, const Occluder& occ, Occluder::Query& q,
                               const PinholeCamera& camera, int x, int y) {
    const ViewRay ray = camera.pixelRay(x, y);
    double best = std::numeric_limits<double>::infinity();
    Receiver r;
    for (const PlaneReceiver& plane : scene.receivers) {
        const Vec3 n = glm::normalize(plane.normal);
        const double d = glm::dot(ray.direction, n);
        if (d == 0.0) continue;
        const double t = glm::dot(plane.point - ray.origin, n) / d;
        if (t > 0.0 && t < best) {
            best = t;
            r = {ray.at(t), d < 0.0 ? n : -n};
        }
    }
    const Vec3 far = ray.at(std::isfinite(best) ? best : 1e3);
    double tHit = 0.0;
    if (q.occluded(ray.origin, far, &tHit)) {
        const Vec3 p = ray.at(tHit);
        return Receiver{p, surfaceNormal(occ.shape(size_t(q.lastBlocker())), p)};
    }
    if (!std::isfinite(best)) return std::nullopt;
    return r;
}

struct PointResult {
    bool seen = false, shadowed = false, violation = false;
    bool off = false;  // confirmed more than 0.1% of the unoccluded form factor off, bound or not
    Receiver r;
    double aci = 0, bound = 0, ref = 0, sigma = 0, full = 0;
    uint64_t rays = 0;
};

// The reference at r with `samples` rays and its standard deviation (at least that of one
// ray in `samples` disagreeing).
void reference(const Receiver& r, const RectLight& light, Occluder::Query& q, double offset,
               int samples, PointResult& out) {
    McSettings mc;
    mc.samples = samples;
    mc.rayOffset = offset;
    out.ref = monteCarloRatio(r, light, q, mc).formFactor;
    const double frac = std::clamp(out.ref / out.full, 0.0, 1.0);
    out.sigma = out.full * std::sqrt(std::max(frac * (1.0 - frac), 1.0 / samples) / samples);
}

// A difference under kNegligible (a form factor) is not judged: there the references are
// not estimates. A ground point of seed 3215 (--lights mixed --light-scale 5) sees a sliver of
// a triangle light over its horizon, F = 4e-13; none of mc-ratio's 2^20 samples lands on it and
// it answered 0 with a deviation of 4e-19, flagging ACI's closed form (Method::Reference:
// 5.5e-13). 1e-12 is a billionth of a pixel's value at any radiance a scene uses.
constexpr double kNegligible = 1e-12;

bool outside(const PointResult& p) {
    return std::abs(p.aci - p.ref) > p.bound + 4.0 * p.sigma + kNegligible;
}

// Off by more than 0.1% of the unoccluded form factor, whatever the bound says: a loose bound
// hides nothing from this column.
constexpr double kOff = 1e-3;
bool farOff(const PointResult& p) {
    return std::abs(p.aci - p.ref) > kOff * p.full + 4.0 * p.sigma + kNegligible;
}

}  // namespace

int main(int argc, char** argv) {
    try {
        Args a;
        bench::parseOptions("bench_bounds", argc, argv,
                            {{"--seeds", &a.seeds},
                             {"--first-seed", &a.firstSeed},
                             {"--size", &a.size},
                             {"--stride", &a.stride},
                             {"--samples", &a.samples},
                             {"--confirm", &a.confirm},
                             {"--threads", &a.threads},
                             {"--steps", &a.steps},
                             {"--out", &a.out},
                             {"--lights", &a.lights},
                             {"--fog", std::function<void()>([&a] { a.fog = true; })},
                             {"--light-scale", &a.lightScale},
                             {"--render", std::function<void()>([&a] { a.render = true; })}});
        if (a.seeds < 1 || a.size < 1 || a.stride < 1 || a.samples < 1 || a.confirm < 1 ||
            a.threads < 1 || a.steps < 1 || a.steps > 12)
            bench::failUsage("bench_bounds", "--seeds, --size, --stride, --samples, --confirm "
                                             "and --threads must be positive, --steps in [1, 12]");
        if (!(a.lightScale > 0.0)) bench::failUsage("bench_bounds", "--light-scale must be > 0");
        std::filesystem::create_directories(a.out);
        tbb::global_control threads(tbb::global_control::max_allowed_parallelism, a.threads);
        std::printf("bench_bounds: default ACI's error bound against mc-ratio (%d rays; %d to "
                    "confirm), pixels every %d of %d x %d, %d threads, --aci-steps %d, %s's settings\n\n",
                    a.samples, a.confirm, a.stride, a.size, a.size, a.threads, a.steps,
                    a.render ? "render" : "probe");
        std::printf("%-8s %7s %9s %10s %9s %9s %12s %14s %8s\n", "scene", "points", "shadowed",
                    "violations", "off>0.1%", "rays/pt", "max err/F0", "max err/bound", "seconds");
        int totalPoints = 0, totalViolations = 0, totalOff = 0;
        for (int i = 0; i < a.seeds; ++i) {
            const int seed = a.firstSeed + i;
            const auto start = std::chrono::steady_clock::now();
            const randomscenes::Generated g = randomscenes::generateScene(uint64_t(seed), randomscenes::parseLightShapes(a.lights), a.fog, a.lightScale);
            const std::string path = a.out + "/seed_" + std::to_string(seed) + ".json";
            std::ofstream(path) << g.json;
            const Scene scene = parseScene(g.json, path, a.out);
            Camera cam = *scene.camera;
            cam.width = cam.height = a.size;
            const PinholeCamera camera(cam, scene.file);
            const Occluder occ = scene.makeOccluder();
            occ.prepareClearance();
            const RectLight& light = scene.lights.at(0);

            std::vector<std::pair<int, int>> pixels;
            for (int y = 0; y < a.size; y += a.stride)
                for (int x = (y / a.stride) % 2 * (a.stride / 2); x < a.size; x += a.stride)
                    pixels.emplace_back(x, y);
            std::vector<PointResult> results(pixels.size());
            tbb::enumerable_thread_specific<Occluder::Query> queries([&] { return occ.makeQuery(); });
            // One integrator a thread, as renders and probe keep: a fresh one per point grows its
            // lattice arrays every time (at --steps 7, 0.29 s a point, most of a seed's run).
            tbb::enumerable_thread_specific<ContourIntegrator> integrators;
            tbb::parallel_for(size_t(0), pixels.size(), [&](size_t k) {
                Occluder::Query& q = queries.local();
                PointResult& p = results[k];
                const std::optional<Receiver> r =
                    seenAt(scene, occ, q, camera, pixels[k].first, pixels[k].second);
                if (!r) return;
                p.r = *r;
                p.full = unoccludedFormFactor(light, p.r);
                if (!(p.full > 0.0)) return;
                p.seen = true;
                AciSettings s = a.render ? RenderSettings{}.pixelAci() : AciSettings{};
                s.gradient = false;
                s.steps = a.steps;
                s.rayOffset = receiverRayOffset(occ, p.r.point, 1e-9);
                ContourIntegrator& aci = integrators.local();
                aci.setSettings(s);
                // estimate(): aciThroughMedia where fog lies between (--fog), else evaluate().
                const Estimate e = estimate(Method::Aci, p.r, light, q, aci, McSettings{});
                p.aci = e.formFactor;
                p.bound = e.errorBound;
                p.rays = e.counts.shadowRays();
                reference(p.r, light, q, s.rayOffset, a.samples, p);
                p.shadowed = p.ref < p.full * (1.0 - 1e-3);
                if (outside(p) || farOff(p)) {
                    reference(p.r, light, q, s.rayOffset, a.confirm, p);
                    p.violation = outside(p);
                    p.off = farOff(p);
                }
            });
            int points = 0, shadowed = 0, violations = 0, off = 0;
            uint64_t rays = 0;
            double maxErr = 0.0, maxRatio = 0.0;
            for (const PointResult& p : results) {
                if (!p.seen) continue;
                ++points;
                shadowed += p.shadowed;
                rays += p.rays;
                // Only confirmed figures: a 4096-ray reference's noise would dominate.
                if (p.off) {
                    ++off;
                    maxErr = std::max(maxErr, std::abs(p.aci - p.ref) / p.full);
                }
                if (p.violation) {
                    ++violations;
                    maxErr = std::max(maxErr, std::abs(p.aci - p.ref) / p.full);
                    const double over = std::abs(p.aci - p.ref) - 4.0 * p.sigma;
                    maxRatio = std::max(maxRatio, p.bound > 0.0 ? over / p.bound : HUGE_VAL);
                }
            }
            const double seconds =
                std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
            std::printf("seed %-3d %7d %9d %10d %9d %9.1f %11.3f%% %14.2f %8.1f\n", seed, points,
                        shadowed, violations, off, points ? double(rays) / points : 0.0,
                        100.0 * maxErr, maxRatio, seconds);
            if (a.lights != "rect")
                std::printf("  %s\n", g.description.substr(0, g.description.find(';')).c_str());
            if (a.fog) std::printf("  %s\n", g.description.substr(g.description.find("; fog") + 2).c_str());
            for (size_t k = 0; k < results.size(); ++k) {
                const PointResult& p = results[k];
                if (!p.violation && !p.off) continue;
                std::printf("  %s at pixel (%d, %d): aci %.6g, reference %.6g (sigma %.2g), "
                            "bound %.3g, unoccluded %.4g; probe: %.9g,%.9g,%.9g,%.9g,%.9g,%.9g\n",
                            p.violation ? "violation" : "off", pixels[k].first, pixels[k].second, p.aci, p.ref, p.sigma, p.bound,
                            p.full, p.r.point.x, p.r.point.y, p.r.point.z, p.r.normal.x,
                            p.r.normal.y, p.r.normal.z);
            }
            std::fflush(stdout);
            totalPoints += points;
            totalViolations += violations;
            totalOff += off;
        }
        std::printf("\n%d points, %d violations, %d off by more than 0.1%% of F0\n", totalPoints,
                    totalViolations, totalOff);
        return 0;
    } catch (...) {
        return bench::reportException("bench_bounds");
    }
}
