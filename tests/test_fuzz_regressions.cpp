// Inputs the scene-loader fuzzer (fuzz/fuzz_scene_loader.cpp, scripts/fuzz.sh) stopped on, kept
// as tests so that the sanitizer builds (scripts/sanitize.sh asan) run them on every CI run.
// Each input must either load or be refused with InputError; the comment says what was found.
#include <catch2/catch.hpp>

#include <string>

#include "penumbra/error.h"
#include "penumbra/scene.h"

using namespace penumbra;

TEST_CASE("fuzz: CSG difference under a transform (TBB hash-map alignment report)",
          "[fuzz][scene]") {
    // crash-14b982d3: clang's UBSan flagged a "downcast of misaligned address 0x3" inside
    // oneTBB's concurrent_hash_map iterator, reached from OpenVDB's Tree::clearAllAccessors while
    // the CSG difference was built. The tagged pointer is TBB's own bucket marker and is never
    // dereferenced; the fuzz build ignores that one check in that one header
    // (.ci/ubsan_ignorelist.txt). The scene is valid: it must load, with one obstacle.
    const std::string text = R"({"camera": {"eye": [0,-6,3], "look_at": [0,0,0], "fov_deg": 40,
     "width": 16, "height": 16},
 "lights": [{"corner": [-1,-1,4], "edge_u": [0,2,0], "edge_v": [2,0,0]}],
 "obstacles": [{"type": "csg", "op": "difference", "children": [
     {"type": "box", "center": [0,0,1], "size": [1,1,1]},
     {"type": "sphere", "center": [0,0,1], "radius": 0.6}],
   "transform": {"translate": [0.1,0,0], "rotate_deg": [0,0,30], "scale": 1.5}}],
 "level_set": {"voxel_size": 0.1, "half_width": 3, "max_memory_gib": 0.02}})";
    const Scene scene = parseScene(text, "fuzz.json", "/nonexistent-fuzz-dir");
    CHECK(scene.obstacles.size() == 1);
    CHECK(scene.lights.size() == 1);
}
