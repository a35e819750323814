// Determinism: render() gives bit-identical pixels on 1, 2 and 8 threads, for every method, and
// so do the EXR files written from them, read back. Rows are handed to threads in a different
// order on each run, so any dependence of a pixel on which thread (or which earlier row)
// computed it shows up here.
#include <catch2/catch.hpp>

#include <unistd.h>

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <string>

#include <tbb/global_control.h>

#include "penumbra/image_io.h"
#include "penumbra/renderer.h"
#include "penumbra/scene.h"

namespace fs = std::filesystem;
using namespace penumbra;

namespace {

// A penumbra-rich tiny scene: a level-set box (voxelized, so the occluder's own code paths run)
// and an exact sphere, under a light, over a floor, seen by a small camera.
const char* kScene = R"({
  "camera": {"eye": [0, -5, 4], "look_at": [0, 0, 0.5], "fov_deg": 45, "width": 20, "height": 16},
  "lights": [{"corner": [-1, -1, 4], "edge_u": [0, 2, 0], "edge_v": [2, 0, 0],
              "radiance": [4, 4, 4]}],
  "obstacles": [
    {"type": "box", "center": [0.5, -0.3, 0.8], "size": [0.6, 0.6, 0.6]},
    {"type": "sphere", "center": [-0.5, 0.4, 1.2], "radius": 0.5, "analytic": true}
  ],
  "receivers": [{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]}],
  "level_set": {"voxel_size": 0.05, "half_width": 3}
})";

bool sameBits(const Image& a, const Image& b) {
    return a.width == b.width && a.height == b.height && a.channels == b.channels &&
           std::memcmp(a.data.data(), b.data.data(), a.data.size() * sizeof(float)) == 0;
}

}  // namespace

TEST_CASE("1, 2 and 8 threads give bit-identical pixels for every method", "[determinism]") {
    // TBB caps its workers at the core count minus one by default: lift the cap, so that 8
    // threads are 8 even on a 2-core machine (oversubscribed, which also shuffles the rows more).
    tbb::global_control allowEight(tbb::global_control::max_allowed_parallelism, 8);
    const Scene scene = parseScene(kScene, "determinism.json", "");
    const fs::path dir =
        fs::temp_directory_path() / ("penumbra_determinism_" + std::to_string(::getpid()));
    fs::create_directories(dir);
    for (const char* name :
         {"aci", "aci-pixel", "reference", "mc-adaptive", "mc-solid-angle", "mc-ratio"}) {
        const Method method = parseMethod(name);
        REQUIRE(std::string(methodName(method)) == name);
        RenderSettings settings;
        settings.method = method;
        settings.aci.gradient = true;  // the gradient AOV too
        if (isMonteCarlo(method)) settings.mc.samples = 32;
        Image first;
        for (int threads : {1, 2, 8}) {
            INFO("method " << name << ", " << threads << " threads");
            settings.threads = threads;
            const RenderResult r = render(scene, settings);
            // The picture is not trivially uniform: a shadowed and a lit pixel differ.
            float lo = r.color.data[0], hi = r.color.data[0];
            for (float v : r.color.data) {
                lo = std::min(lo, v);
                hi = std::max(hi, v);
            }
            REQUIRE(hi > lo);
            REQUIRE(r.stats.shadowRays > 0);
            const fs::path exr = dir / (std::string(name) + "_" + std::to_string(threads) + ".exr");
            writeImage(exr.string(), r.color);
            if (threads == 1) {
                first = r.color;
                REQUIRE(sameBits(readImage(exr.string()), first));  // EXR keeps float32 pixels
                continue;
            }
            CHECK(sameBits(r.color, first));
            // The pixels read back from the EXR file (its bytes may differ: the header holds
            // the capture date, to the second).
            CHECK(sameBits(readImage(exr.string()), first));
        }
    }
    fs::remove_all(dir);
}
