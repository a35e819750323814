// Helpers shared by the tests of `penumbra batch` (test_batch.cpp, test_batch_reliability.cpp):
// a scratch directory holding the small scene, temporaries left behind, a sweep slow enough to
// be interrupted or met by a second run, and waiting for a running batch to get somewhere.
#pragma once

#include <chrono>
#include <filesystem>
#include <functional>
#include <string>
#include <thread>

#include "support/cli.h"
#include "support/scenes.h"

namespace test {

/// A test's directory (TempDir) with kSphereScene written to a.json in it.
struct SceneDir : TempDir {
    explicit SceneDir(const std::string& name, const std::string& prefix = "batch")
        : TempDir(name, prefix) {
        writeFile(path / "a.json", kSphereScene);
    }
};

/// How many temporaries (files whose names start with a dot and contain ".tmp-") are in `dir`,
/// or with `recursive` in `dir` and below it.
inline int countTemporaries(const fs::path& dir, bool recursive) {
    int n = 0;
    auto count = [&n](const fs::path& p) {
        const std::string name = p.filename().string();
        if (name[0] == '.' && name.find(".tmp-") != std::string::npos) ++n;
    };
    if (recursive) {
        for (const auto& e : fs::recursive_directory_iterator(dir)) count(e.path());
    } else {
        for (const auto& e : fs::directory_iterator(dir)) count(e.path());
    }
    return n;
}

/// The sphere of kSphereScene as a level set (voxel 0.02) seen at size x size: with per-pixel
/// ACI each frame takes long enough for a batch to be killed or met by a second run.
inline std::string slowSphereScene(int size) {
    const std::string n = std::to_string(size);
    return R"({
      "camera": {"eye": [0, -6, 3], "look_at": [0, 0, 0.5], "width": )" + n +
           R"(, "height": )" + n + R"(},
      "lights": [{"corner": [-1, -1, 4], "edge_u": [0, 2, 0], "edge_v": [2, 0, 0],
                  "radiance": [4, 4, 4]}],
      "obstacles": [{"type": "sphere", "center": [0, 0, 1.2], "radius": 0.5}],
      "receivers": [{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]}],
      "level_set": {"voxel_size": 0.02}
    })";
}

/// A sweep of `frames` per-pixel ACI frames of a.json, the light moving, to out/k_00.exr,
/// out/k_01.exr, ...
inline std::string slowSweepManifest(int frames) {
    return R"({"sweep": {"scene": "a.json", "output": "out/k_{frame:02d}.exr",
      "frames": )" + std::to_string(frames) + R"(, "method": "aci-pixel",
      "vary": {"lights/0/corner": {"from": [-1.5, -1, 4], "to": [0.5, -1, 4]}}}})";
}

/// A test's directory (TempDir) holding a slow batch: a.json, slowSphereScene(size), and the
/// manifest m.json, slowSweepManifest(frames).
struct SlowSweepDir : TempDir {
    const int frames;
    SlowSweepDir(const std::string& name, const std::string& prefix, int size, int frameCount)
        : TempDir(name, prefix), frames(frameCount) {
        writeFile(path / "a.json", slowSphereScene(size));
        writeFile(path / "m.json", slowSweepManifest(frames));
    }
};

/// Polls `done` every `poll` until it holds or a minute has passed.
inline void waitUntil(const std::function<bool()>& done, std::chrono::milliseconds poll) {
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (!done() && std::chrono::steady_clock::now() < deadline) {
        std::this_thread::sleep_for(poll);
    }
}

}  // namespace test
