// bench_setup: what a certified render pays per level set before its first pixel, on one
// thread (renders build the level sets' parts side by side, one per thread): the fine level
// set, its far-field companion as buildLevelSet's level set builds it (sampled from the shape's
// own distance for a lone sphere, torus or capsule; meshed from the fine surface otherwise) and
// meshed, and its cell tables. The default scene's sphere and box, and a torus, capsule and
// cylinder of like size; best of REPEATS runs of each part.
//
// usage: bench_setup [VOXEL] [REPEATS]   (defaults 0.01 and 3)
#include <openvdb/openvdb.h>

#include <tbb/global_control.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "bench_common.h"
#include "level_set_impl.h"
#include "penumbra/shape.h"

using namespace penumbra;

namespace {

double bestSeconds(const std::function<void()>& f, int repeats) {
    double best = 1e30;
    for (int i = 0; i < repeats; ++i) {
        const auto start = std::chrono::steady_clock::now();
        f();
        const std::chrono::duration<double> took = std::chrono::steady_clock::now() - start;
        best = std::min(best, took.count());
    }
    return best;
}

std::vector<std::pair<std::string, ShapeNode>> shapes() {
    SphereShape sphere;
    sphere.center = Vec3(-0.4, 0.4, 1.2);
    sphere.radius = 0.5;
    BoxShape box;
    box.center = Vec3(0.6, -0.4, 0.8);
    box.size = Vec3(0.6);
    TorusShape torus;
    torus.center = Vec3(0.0, 0.0, 1.0);
    torus.axis = glm::normalize(Vec3(0.3, 0.2, 1.0));
    torus.majorRadius = 0.4;
    torus.minorRadius = 0.12;
    CapsuleShape capsule;
    capsule.a = Vec3(-0.4, 0.0, 1.0);
    capsule.b = Vec3(0.4, 0.2, 1.3);
    capsule.radius = 0.2;
    CylinderShape cylinder;
    cylinder.center = Vec3(0.0, 0.0, 1.0);
    cylinder.axis = glm::normalize(Vec3(0.4, -0.3, 1.0));
    cylinder.radius = 0.3;
    cylinder.height = 0.6;
    return {{"sphere r 0.5", {sphere, {}}},
            {"box 0.6", {box, {}}},
            {"torus 0.4/0.12", {torus, {}}},
            {"capsule r 0.2", {capsule, {}}},
            {"cylinder r 0.3", {cylinder, {}}}};
}

}  // namespace

int main(int argc, char** argv) {
    bench::helpIfAsked(argc, argv, "usage: bench_setup [VOXEL] [REPEATS]   (defaults 0.01 and 3)");
    try {
        const double voxel = argc > 1 ? std::atof(argv[1]) : 0.01;
        const int repeats = argc > 2 ? int(bench::positiveArg("bench_setup", argv[2], "REPEATS")) : 3;
        if (!(voxel > 0.0)) bench::failUsage("bench_setup", "VOXEL must be a number > 0");
        tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
        std::printf("bench_setup: voxel %g, half width 3, one thread, best of %d; seconds\n\n",
                    voxel, repeats);
        std::printf("%-16s %9s %9s %12s %12s %9s %9s\n", "shape", "voxels", "level set",
                    "as built", "meshed", "ratio", "cells");
        for (const auto& [name, node] : shapes()) {
            LevelSetPtr built;
            const double fine = bestSeconds([&] { built = buildLevelSet(node, voxel, 3.0, name); },
                                            repeats);
            // A fresh build each run, so that each builds its companion again.
            std::vector<LevelSetPtr> fresh(repeats);
            for (auto& f : fresh) f = buildLevelSet(node, voxel, 3.0, name);
            int next = 0;
            const double own = bestSeconds(
                [&] { fresh[next++]->farField(kFarFieldFactor, kFarFieldBand); }, repeats);
            // The same grid without the shape: the companion is meshed.
            const double meshed = bestSeconds(
                [&] { LevelSet(built->gridPtr()).farField(kFarFieldFactor, kFarFieldBand); },
                repeats);
            const double cells =
                bestSeconds([&] { LevelSet(built->gridPtr()).cellTables(); }, repeats);
            std::printf("%-16s %9llu %9.3f %12.4f %12.4f %9.3f %9.3f\n", name.c_str(),
                        (unsigned long long)built->grid().activeVoxelCount(), fine, own, meshed,
                        own / meshed, cells);
        }
        return 0;
    } catch (...) {
        return bench::reportException("bench_setup");
    }
}
