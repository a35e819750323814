// Benchmark (not a test): the cost of Occluder::Query::occluded over a bare OpenVDB
// LevelSetRayIntersector loop casting the same shadow rays. Prints rays/s, the overhead ratio
// and the hit counts of both, on 1 and 2 threads; then the cost of occluded() (with the hit
// distance) followed by Occluder::Query::certify on the same segments, for want = 1.41 (half
// the diagonal of a 2 x 2 light) and want = 0.1, with its ratio to the bare intersector and the
// mean certified radius; and the same for Occluder::Query::occludedCertified, the answer and
// the certificate in one pass (what the estimator calls), as (d)/(b).
//
// Two obstacles, one after the other:
// - a level-set sphere (radius 0.5, voxel 0.01) at the origin; receivers on the plane z = -1 and
//   targets on a light at z = +1, both within |x|, |y| < 0.6, so almost every segment crosses
//   the sphere's bounding box and most are blocked (the printed hit counts say how many);
// - the Stanford bunny of vdb_scenes/bunny.json (a mesh turned into a level set, voxel 0.008,
//   about 1.2 units long, standing on z = 0): not convex, its ears far from its bounding
//   sphere's middle; receivers on z = -0.5 and targets on z = 2, within |x|, |y| < 0.7.
//   Skipped with a message when the scene file is not found (run from the source tree, or give
//   its path as the second argument).
//
// Usage: bench_occluder [segments (default 1e6)] [bunny scene (default vdb_scenes/bunny.json)]
#include <openvdb/math/Ray.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/RayIntersector.h>
#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <string>
#include <variant>
#include <random>
#include <vector>

#include "bench_common.h"
#include "level_set_impl.h"
#include "penumbra/level_set.h"
#include "penumbra/occluder.h"
#include "penumbra/scene.h"

using namespace penumbra;

namespace {

using Intersector = openvdb::tools::LevelSetRayIntersector<openvdb::FloatGrid>;

struct Segment {
    Vec3 from, to;
};

/// The bare loop: the same world-space ray and bounding-box clip as the occluder, nothing else.
bool bareOccluded(Intersector& ix, const Box3& bounds, const Segment& s) {
    const Vec3 delta = s.to - s.from;
    const double length = glm::length(delta);
    const double eps = 1e-9 * std::max(1.0, length);
    const Vec3 dir = delta / length;
    double t0 = eps, t1 = length - eps;
    if (!bounds.clipRay(s.from, 1.0 / dir, t0, t1)) return false;
    const openvdb::math::Ray<double> ray(openvdb::Vec3d(s.from.x, s.from.y, s.from.z),
                                         openvdb::Vec3d(dir.x, dir.y, dir.z), t0, t1);
    openvdb::Vec3d xyz;
    if (!ix.intersectsWS(ray, xyz)) return false;
    return glm::dot(Vec3(xyz.x(), xyz.y(), xyz.z()) - s.from, dir) < t1;
}

/// Wall-clock time of `run`, in seconds.
double seconds(const std::function<void()>& run) {
    const auto start = std::chrono::steady_clock::now();
    run();
    const std::chrono::duration<double> dt = std::chrono::steady_clock::now() - start;
    return dt.count();
}

/// How the occluder's hit count compares with the bare intersector's. The occluder may block
/// a few more: its cell test catches rays that dip below zero between OpenVDB's samples
/// (level_set_search.h); it must never block fewer.
std::string agreement(size_t hitsOcc, size_t hitsBare) {
    if (hitsOcc == hitsBare) return "agree";
    if (hitsOcc > hitsBare) return "occluder +" + std::to_string(hitsOcc - hitsBare) + ", the cell test";
    return "DIFFER: occluder -" + std::to_string(hitsBare - hitsOcc);
}

/// Times the bare intersector, occluded() and occluded() + certify() on `segs` against the
/// occluder's only obstacle, a level set, and prints the figures.
void runShape(const char* name, const Occluder& occ, const std::vector<Segment>& segs,
              int repeats) {
    const size_t n = segs.size();
    const LevelSetPtr& ls = std::get<LevelSetPtr>(occ.shape(0));
    const Box3 bounds = occ.bounds(0);
    const LevelSetInfo info = describe(*ls);
    std::printf("%s level set: voxel %.3g, %llu active voxels, %zu segments, best of %d\n", name,
                info.voxelSize, (unsigned long long)info.activeVoxels, n, repeats);

    occ.prepareClearance();  // far-field companion built before timing certify()
    const Occluder::Query queryProto = occ.makeQuery();
    const Intersector bareProto(ls->grid());

    for (int threads : {1, 2}) {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
        size_t hitsOcc = 0, hitsBare = 0;

        auto runOcc = [&] {
            tbb::enumerable_thread_specific<Occluder::Query> queries(queryProto);
            tbb::combinable<size_t> hits([] { return size_t(0); });
            tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 4096),
                              [&](const tbb::blocked_range<size_t>& r) {
                                  Occluder::Query& q = queries.local();
                                  size_t h = 0;
                                  for (size_t i = r.begin(); i != r.end(); ++i) {
                                      h += q.occluded(segs[i].from, segs[i].to);
                                  }
                                  hits.local() += h;
                              });
            hitsOcc = hits.combine(std::plus<size_t>());
        };

        auto runBare = [&] {
            tbb::enumerable_thread_specific<Intersector> intersectors(bareProto);
            tbb::combinable<size_t> hits([] { return size_t(0); });
            tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 4096),
                              [&](const tbb::blocked_range<size_t>& r) {
                                  Intersector& ix = intersectors.local();
                                  size_t h = 0;
                                  for (size_t i = r.begin(); i != r.end(); ++i) {
                                      h += bareOccluded(ix, bounds, segs[i]);
                                  }
                                  hits.local() += h;
                              });
            hitsBare = hits.combine(std::plus<size_t>());
        };

        // occluded() with the hit distance, then certify() up to `want` (onePass 0), or
        // occludedCertified(), the answer and the certificate in one pass as the estimator asks
        // for them (onePass 1): the sum of the certified radii and how many are > 0.
        const double wants[2] = {1.41, 0.1};
        double radiusSum[2][2] = {{0.0, 0.0}, {0.0, 0.0}};
        size_t certified[2][2] = {{0, 0}, {0, 0}}, hitsCert[2][2] = {{0, 0}, {0, 0}};
        auto runCertify = [&](int onePass, int w) {
            const double want = wants[w];
            tbb::enumerable_thread_specific<Occluder::Query> queries(queryProto);
            tbb::combinable<double> sum([] { return 0.0; });
            tbb::combinable<size_t> hits([] { return size_t(0); }),
                nonzero([] { return size_t(0); });
            tbb::parallel_for(
                tbb::blocked_range<size_t>(0, n, 4096), [&](const tbb::blocked_range<size_t>& r) {
                    Occluder::Query& q = queries.local();
                    size_t h = 0, c = 0;
                    double s = 0.0;
                    Certificate cert;
                    for (size_t i = r.begin(); i != r.end(); ++i) {
                        double tHit = -1.0;
                        bool hidden;
                        if (onePass) {
                            hidden = q.occludedCertified(segs[i].from, segs[i].to, want, &tHit, cert);
                        } else {
                            hidden = q.occluded(segs[i].from, segs[i].to, &tHit);
                            q.certify(segs[i].from, segs[i].to, hidden, tHit, want, cert);
                        }
                        h += hidden;
                        c += cert.radius > 0.0;
                        s += cert.radius;
                    }
                    hits.local() += h;
                    nonzero.local() += c;
                    sum.local() += s;
                });
            hitsCert[onePass][w] = hits.combine(std::plus<size_t>());
            certified[onePass][w] = nonzero.combine(std::plus<size_t>());
            radiusSum[onePass][w] = sum.combine(std::plus<double>());
        };

        // Alternate the runs so that load from other processes hits them alike; keep the best.
        double tOcc = 1e300, tBare = 1e300, tCert[2][2] = {{1e300, 1e300}, {1e300, 1e300}};
        for (int r = 0; r < repeats; ++r) {
            tOcc = std::min(tOcc, seconds(runOcc));
            tBare = std::min(tBare, seconds(runBare));
            for (int w = 0; w < 2; ++w)
                for (int onePass = 0; onePass < 2; ++onePass)
                    tCert[onePass][w] = std::min(tCert[onePass][w],
                                                 seconds([&] { runCertify(onePass, w); }));
        }

        std::printf(
            "%d thread%s: occluder %.3g rays/s (%.3f s), bare intersector %.3g rays/s "
            "(%.3f s), overhead (a)/(b) = %.3f; hits %zu vs %zu (%s)\n",
            threads, threads > 1 ? "s" : "", n / tOcc, tOcc, n / tBare, tBare, tOcc / tBare,
            hitsOcc, hitsBare, agreement(hitsOcc, hitsBare).c_str());
        for (int w = 0; w < 2; ++w)
            for (int onePass = 0; onePass < 2; ++onePass)
                std::printf(
                    "%d thread%s: %s(want %.2f) %.3g rays/s (%.3f s), %s = %.3f; mean radius "
                    "%.4g (%.1f%% of want), certified %.1f%%; hits %zu (%s)\n",
                    threads, threads > 1 ? "s" : "",
                    onePass ? "occludedCertified" : "occluded + certify", wants[w],
                    n / tCert[onePass][w], tCert[onePass][w], onePass ? "(d)/(b)" : "(c)/(b)",
                    tCert[onePass][w] / tBare, radiusSum[onePass][w] / n,
                    100.0 * radiusSum[onePass][w] / n / wants[w],
                    100.0 * certified[onePass][w] / n, hitsCert[onePass][w],
                    agreement(hitsCert[onePass][w], hitsBare).c_str());
    }
}

/// n segments from points on the plane z = zFrom to points on z = zTo, both uniform in
/// |x|, |y| < half.
std::vector<Segment> randomSegments(size_t n, double zFrom, double zTo, double half) {
    std::mt19937_64 rng(12345);
    std::uniform_real_distribution<double> u(-half, half);
    std::vector<Segment> segs(n);
    for (Segment& s : segs) {
        s.from = Vec3(u(rng), u(rng), zFrom);
        s.to = Vec3(u(rng), u(rng), zTo);
    }
    return segs;
}

}  // namespace

int main(int argc, char** argv) {
    bench::helpIfAsked(argc, argv,
                       "usage: bench_occluder [segments (default 1e6)] [bunny scene (default "
                       "vdb_scenes/bunny.json)]");
    const size_t n =
        argc > 1 ? size_t(bench::positiveArg("bench_occluder", argv[1], "segments")) : 1000000;
    const std::string bunnyScene = argc > 2 ? argv[2] : "vdb_scenes/bunny.json";
    const int repeats = 5;

    {
        const Occluder occ({makeSphereLevelSet(Vec3(0.0), 0.5, 0.01, 3.0)});
        runShape("sphere", occ, randomSegments(n, -1.0, 1.0, 0.6), repeats);
    }
    if (!std::filesystem::exists(bunnyScene)) {
        std::printf("bunny: %s not found (run from the source tree); skipped\n", bunnyScene.c_str());
        return 0;
    }
    const Scene scene = loadScene(bunnyScene);
    const Occluder occ = scene.makeOccluder();
    if (occ.size() != 1 || !std::holds_alternative<LevelSetPtr>(occ.shape(0))) {
        std::fprintf(stderr, "%s: expected one level-set obstacle\n", bunnyScene.c_str());
        return 1;
    }
    runShape("bunny", occ, randomSegments(n, -0.5, 2.0, 0.7), repeats);
    return 0;
}
