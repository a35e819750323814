// Level sets stored across processes (LevelSetCache with a directory: `batch --cache`,
// `render --cache`) and the batch's job records across shards (`batch --status`).
#include <openvdb/openvdb.h>

#include <catch2/catch.hpp>

#include <filesystem>
#include <string>
#include <vector>

#include "level_set_impl.h"
#include "penumbra/batch.h"
#include "penumbra/scene.h"
#include "support/cli.h"
#include "support/scenes.h"

using namespace penumbra;
using namespace test;

namespace {

// A torus (a level set with a hole) and a mesh-free CSG: both built, neither analytic.
std::string torusScene(double voxel) {
    return R"({"camera": {"eye": [0, -5, 3], "look_at": [0, 0, 1]},
      "lights": [{"corner": [-1, -1, 4], "edge_u": [0, 2, 0], "edge_v": [2, 0, 0]}],
      "receivers": [{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]}],
      "obstacles": [{"name": "ring", "type": "torus", "center": [0, 0, 1.5], "major_radius": 0.4,
                     "minor_radius": 0.12},
                    {"name": "ball", "type": "sphere", "center": [0.6, 0.2, 1], "radius": 0.2}],
      "level_set": {"voxel_size": )" + std::to_string(voxel) + "}}";
}

// Every active voxel of `a` has the same value (and is active) in `b`, and the counts agree.
bool sameGrid(const openvdb::FloatGrid& a, const openvdb::FloatGrid& b) {
    if (a.activeVoxelCount() != b.activeVoxelCount() || a.background() != b.background() ||
        a.transform() != b.transform())
        return false;
    auto acc = b.getConstAccessor();
    for (auto it = a.cbeginValueOn(); it; ++it) {
        if (!acc.isValueOn(it.getCoord()) || acc.getValue(it.getCoord()) != *it) return false;
    }
    return true;
}

const LevelSet& levelSetOf(const Scene& s, size_t i) {
    return *std::get<LevelSetPtr>(s.obstacles[i].shape);
}

std::vector<fs::path> cacheFiles(const fs::path& dir) {
    std::vector<fs::path> out;
    for (const auto& e : fs::directory_iterator(dir)) out.push_back(e.path());
    return out;
}

// `penumbra ARGS` run inside `dir`, so that relative paths in messages read as a user sees them.
Run penumbraIn(const fs::path& dir, const std::string& args) {
    return runShell("cd '" + dir.string() + "' && " + PENUMBRA_BINARY + " " + args, dir);
}

}  // namespace

TEST_CASE("a level-set cache directory gives later loads bit-identical level sets and companions",
          "[batch][cache]") {
    const TempDir tmp("ls_cache_roundtrip");
    const fs::path dir = tmp.path / "cache";
    const std::string text = torusScene(0.03);

    LevelSetCache first(dir.string());
    const Scene a = parseScene(text, "a.json", tmp.path.string(), &first);
    CHECK(a.build.levelSetsBuilt == 2);
    CHECK(a.build.levelSetsFromCache == 0);
    REQUIRE(cacheFiles(dir).size() == 2);  // one file per obstacle, written when built
    // A render builds the far-field companions; persist() stores them too.
    const Occluder occ = a.makeOccluder();
    occ.prepareClearance();
    REQUIRE(hasFarField(levelSetOf(a, 0)));
    first.persist();

    // Another cache (another process, another shard) over the same directory.
    LevelSetCache second(dir.string());
    const Scene b = parseScene(text, "a.json", tmp.path.string(), &second);
    CHECK(b.build.levelSetsBuilt == 0);
    CHECK(b.build.levelSetsFromCache == 2);
    for (size_t i = 0; i < 2; ++i) {
        const LevelSet& la = levelSetOf(a, i);
        const LevelSet& lb = levelSetOf(b, i);
        CHECK(&la != &lb);  // read, not shared in memory
        CHECK(lb.grid().getName() == la.grid().getName());
        CHECK(b.obstacles[i].name == a.obstacles[i].name);
        CHECK(sameGrid(la.grid(), lb.grid()));
        REQUIRE(hasFarField(lb));  // read with it: no rebuild on first use
        CHECK(sameGrid(*la.farFieldIfBuilt(), *lb.farFieldIfBuilt()));
    }
    // Another voxel size is another key: built, and stored beside the others.
    LevelSetCache third(dir.string());
    CHECK(parseScene(torusScene(0.04), "a.json", tmp.path.string(), &third).build.levelSetsBuilt == 2);
    CHECK(cacheFiles(dir).size() == 4);
}

TEST_CASE("a corrupt, truncated or foreign cache file is ignored with a warning and rebuilt",
          "[batch][cache]") {
    const TempDir tmp("ls_cache_corrupt");
    const fs::path dir = tmp.path / "cache";
    const std::string text = torusScene(0.03);
    Scene reference;
    {
        LevelSetCache fill(dir.string());
        reference = parseScene(text, "a.json", tmp.path.string(), &fill);
    }
    std::vector<fs::path> files = cacheFiles(dir);
    REQUIRE(files.size() == 2);
    std::sort(files.begin(), files.end());

    SECTION("truncated") {
        fs::resize_file(files[0], 200);
    }
    SECTION("garbage") {
        writeFile(files[0], std::string(5000, 'x'));
    }
    SECTION("another entry's file under this name (foreign key)") {
        fs::copy_file(files[1], files[0], fs::copy_options::overwrite_existing);
    }
    std::vector<std::string> warnings;
    LevelSetCache cache(dir.string(), [&](const std::string& w) { warnings.push_back(w); });
    const Scene s = parseScene(text, "a.json", tmp.path.string(), &cache);
    CHECK(s.build.levelSetsBuilt == 1);
    CHECK(s.build.levelSetsFromCache == 1);
    REQUIRE(warnings.size() == 1);
    CHECK(warnings[0].find(files[0].string()) != std::string::npos);
    CHECK(warnings[0].find("rebuilding") != std::string::npos);
    for (size_t i = 0; i < 2; ++i) CHECK(sameGrid(levelSetOf(reference, i).grid(), levelSetOf(s, i).grid()));
    // The rebuilt entry replaced the bad file: a third load reads both, silently.
    warnings.clear();
    LevelSetCache again(dir.string(), [&](const std::string& w) { warnings.push_back(w); });
    CHECK(parseScene(text, "a.json", tmp.path.string(), &again).build.levelSetsFromCache == 2);
    CHECK(warnings.empty());
}

TEST_CASE("batch --cache: a second run reads the level sets the first one stored",
          "[batch][cache][cli]") {
    const TempDir tmp("ls_cache_cli");
    writeFile(tmp.path / "t.json", torusScene(0.03));
    writeFile(tmp.path / "m.json", R"({"cache": "lscache", "defaults": {"scene": "t.json",
        "width": 8, "height": 8}, "jobs": [{"output": "a.exr"}]})");
    const Run one = penumbraIn(tmp.path, "batch m.json -q --summary s1.json");
    REQUIRE(one.exitCode == 0);
    CHECK(readFile(tmp.path / "s1.json").find("\"level_sets_built\": 2") != std::string::npos);
    CHECK(cacheFiles(tmp.path / "lscache").size() == 2);
    const Run two = penumbraIn(tmp.path, "batch m.json -q --summary s2.json");
    REQUIRE(two.exitCode == 0);
    CHECK(readFile(tmp.path / "s2.json").find("\"level_sets_from_cache\": 2") != std::string::npos);
    // --cache names another directory than the manifest's.
    const Run three = penumbraIn(tmp.path, "batch m.json -q --cache other --summary s3.json");
    REQUIRE(three.exitCode == 0);
    CHECK(readFile(tmp.path / "s3.json").find("\"level_sets_built\": 2") != std::string::npos);
    CHECK(cacheFiles(tmp.path / "other").size() == 2);
    // A cache path that is a file: refused before anything runs.
    writeFile(tmp.path / "plain", "x");
    const Run bad = penumbraIn(tmp.path, "batch m.json -q --cache plain");
    CHECK(bad.exitCode == 2);
    CHECK(bad.err.find("plain") != std::string::npos);
}

TEST_CASE("batch --status reports done, failed and missing jobs across shards",
          "[batch][status][cli]") {
    const TempDir tmp("status");
    writeFile(tmp.path / "s.json", kSphereScene);
    // Job 1 fails (a degenerate light); shards of 2: shard 0 runs jobs 0 and 2, shard 1 jobs 1 and 3.
    writeFile(tmp.path / "m.json", R"({"defaults": {"scene": "s.json"},
        "jobs": [{"output": "out/a.exr"}, {"output": "out/b.exr", "set": {"/lights/0/edge_u": [0, 0, 0]}},
                 {"output": "out/c.exr"}, {"output": "out/d.exr"}]})");
    // Runs `penumbra batch m.json --status ARGS`, checks its exit code and that its output
    // shows every one of `shown`.
    auto expectStatus = [&](const std::string& args, int code,
                            const std::vector<std::string>& shown) {
        const Run st = penumbraIn(tmp.path, "batch m.json --status" + args);
        INFO(st.out);
        CHECK(st.exitCode == code);
        for (const std::string& text : shown) CHECK(st.out.find(text) != std::string::npos);
        return st;
    };
    expectStatus(" --shard-count 2", 1, {"4 jobs: 0 done, 0 failed, 4 missing"});

    REQUIRE(penumbraIn(tmp.path, "batch m.json -q --shard 0/2").exitCode == 0);
    expectStatus(" --shard-count 2", 1,
                 {"4 jobs: 2 done, 0 failed, 2 missing", "shard 0/2: 2 done, 0 failed, 0 missing",
                  "shard 1/2: 0 done, 0 failed, 2 missing"});

    CHECK(penumbraIn(tmp.path, "batch m.json -q --shard 1/2").exitCode == 1);
    expectStatus("", 1,
                 {"4 jobs: 3 done, 1 failed, 0 missing", "failed: job 1 'out/b.exr'",
                  "degenerate rectangle", "1\t0/1\tfailed"});

    // One shard's view, and quiet: only the totals.
    CHECK(expectStatus(" --shard 0/2 -q", 0, {}).out ==
          "penumbra: batch m.json: 2 jobs: 2 done, 0 failed, 0 missing\n");

    // A damaged output is missing again; fixing the failed job's scene turns its record stale.
    fs::resize_file(tmp.path / "out/c.exr", 10);
    writeFile(tmp.path / "m.json", R"({"defaults": {"scene": "s.json"},
        "jobs": [{"output": "out/a.exr"}, {"output": "out/b.exr"},
                 {"output": "out/c.exr"}, {"output": "out/d.exr"}]})");
    CHECK(penumbraIn(tmp.path, "batch m.json --status -q").out ==
          "penumbra: batch m.json: 4 jobs: 2 done, 0 failed, 2 missing\n");
    // Resume renders what is missing; the failure record goes with the success.
    REQUIRE(penumbraIn(tmp.path, "batch m.json -q --resume").exitCode == 0);
    CHECK_FALSE(fs::exists(tmp.path / "out/b.exr.failed.json"));
    CHECK(expectStatus(" -q", 0, {}).out ==
          "penumbra: batch m.json: 4 jobs: 4 done, 0 failed, 0 missing\n");
    // --status runs nothing and takes no other run options.
    CHECK(penumbraIn(tmp.path, "batch m.json --status --resume").exitCode == 2);
}

TEST_CASE("a primitive's companion is its own distance, built alike fresh or from a cache file",
          "[cache]") {
    const TempDir tmp("ls_cache_recipe");
    const fs::path dir = tmp.path / "cache";
    const std::string text = torusScene(0.03);

    // First load: built; the cache files hold the fine grids only (no persist()).
    LevelSetCache first(dir.string());
    const Scene a = parseScene(text, "a.json", tmp.path.string(), &first);
    a.makeOccluder().prepareClearance();
    // The sphere's companion: its exact distance at every active voxel (meshing the fine
    // surface would stray from it by about a tenth of a fine voxel).
    const openvdb::FloatGrid& far = *levelSetOf(a, 1).farFieldIfBuilt();
    REQUIRE(far.activeVoxelCount() > 1000);
    double worst = 0.0;
    for (auto it = far.cbeginValueOn(); it; ++it) {
        const openvdb::Vec3d p = far.indexToWorld(it.getCoord());
        const double exact = (p - openvdb::Vec3d(0.6, 0.2, 1.0)).length() - 0.2;
        worst = std::max(worst, std::abs(double(*it) - exact));
    }
    CHECK(worst < 1e-5);

    // Second load reads the fine grids back without companions and builds the same ones.
    LevelSetCache second(dir.string());
    const Scene b = parseScene(text, "a.json", tmp.path.string(), &second);
    REQUIRE(b.build.levelSetsFromCache == 2);
    CHECK(!hasFarField(levelSetOf(b, 0)));
    b.makeOccluder().prepareClearance();
    for (size_t i = 0; i < 2; ++i)
        CHECK(sameGrid(*levelSetOf(a, i).farFieldIfBuilt(), *levelSetOf(b, i).farFieldIfBuilt()));
}
