// End-to-end tests of `penumbra bake`: the program is run as a user would; the .vdb it writes
// is loaded back as `"type": "vdb"` obstacles and must give the same shadows, and read by
// OpenVDB's own vdb_print.
#include <sys/wait.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "support/cli.h"
#include "support/exact_shadow.h"
#include "penumbra/contour_integrator.h"
#include "penumbra/level_set.h"
#include "penumbra/scene.h"

namespace fs = std::filesystem;
using namespace penumbra;

namespace {

using test::readFile;
using test::runPenumbra;
using Run = test::Run;

fs::path makeTempDir(const std::string& name) { return test::makeTempDir("bake", name); }

const char* kLight =
    R"({"name": "key", "corner": [-1,-1,3], "edge_u": [0,2,0], "edge_v": [2,0,0]})";

// Level-set obstacles of every built kind: a primitive, a turned box, a CSG tree and a mesh.
const char* kObstacles = R"([
    {"type": "sphere", "name": "ball", "center": [-0.5,0.2,1.2], "radius": 0.3},
    {"type": "box", "center": [0,0,0], "size": [0.4,0.3,0.2],
     "transform": {"rotate_deg": [0,0,30], "translate": [0.6,-0.3,1.0]}},
    {"type": "csg", "name": "ring", "op": "difference", "children": [
       {"type": "cylinder", "center": [0.3,0.6,1.5], "radius": 0.25, "height": 0.1},
       {"type": "cylinder", "center": [0.3,0.6,1.5], "radius": 0.12, "height": 0.3}]},
    {"type": "mesh", "name": "tet", "file": "tet.obj"}])";

std::string scene(const std::string& obstacles, const std::string& extra = "") {
    return std::string(R"({"lights": [)") + kLight + R"(], "level_set": {"voxel_size": 0.02},)" +
           extra + R"( "obstacles": )" + obstacles + "}";
}

void writeTet(const fs::path& dir) {
    std::ofstream(dir / "tet.obj") << "v -0.9 -0.6 0.6\nv -0.5 -0.6 0.6\nv -0.9 -0.2 0.6\n"
                                      "v -0.8 -0.5 1.0\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
}

/// Sensor points on the ground under the obstacles, as probe's CSV.
std::string sensors() {
    std::string csv = "x,y,z,nx,ny,nz\n";
    for (int i = 0; i < 40; ++i) {
        const double x = -1.6 + 3.2 * (i + 0.5) / 40;
        csv += std::to_string(x) + ",0.05,0,0,0,1\n";
    }
    return csv;
}

}  // namespace

TEST_CASE("bake then load gives the same probe values", "[cli][bake][scenes]") {
    const fs::path dir = makeTempDir("roundtrip");
    writeTet(dir);
    std::ofstream(dir / "scene.json") << scene(kObstacles);
    Run run = runPenumbra("bake " + (dir / "scene.json").string() + " -o " +
                              (dir / "baked.vdb").string() + " --verbose",
                          dir);
    INFO(run.err);
    REQUIRE(run.exitCode == 0);
    CHECK(run.out.find("4 grids ('ball', 'obstacle_1', 'ring', 'tet')") != std::string::npos);
    // --verbose prints the build report on stderr: one line per obstacle and a total.
    CHECK(run.err.find("obstacle 'ring' (csg): ") != std::string::npos);
    CHECK(run.err.find("level sets: ") != std::string::npos);
    for (const auto& entry : fs::directory_iterator(dir)) {
        CHECK(entry.path().filename().string().find(".tmp") == std::string::npos);
    }

    // The grids are the obstacles' level sets, under their names.
    const Scene original = loadScene((dir / "scene.json").string());
    const std::vector<LevelSetPtr> grids = readLevelSets((dir / "baked.vdb").string(), "");
    REQUIRE(grids.size() == 4);
    for (size_t i = 0; i < 4; ++i) {
        const LevelSetInfo a = describe(*std::get<LevelSetPtr>(original.obstacles[i].shape));
        const LevelSetInfo b = describe(*grids[i]);
        CHECK(b.name == original.obstacles[i].name);
        CHECK(b.activeVoxels == a.activeVoxels);
        CHECK(b.voxelSize == a.voxelSize);
    }

    // The same sensor points through `penumbra probe`, on the scene and on the baked file: the
    // same voxels give answers within the error bounds both report. (Not to the last digit: the
    // scene's sphere builds its far-field companion from its own distance, the baked grid, which
    // carries no shape, by meshing; other certificates, so other coverage rays.)
    std::ofstream(dir / "baked.json")
        << std::string(R"({"lights": [)") + kLight +
               R"(], "obstacles": [{"type": "vdb", "file": "baked.vdb"}]})";
    const Run a = runPenumbra("probe --error-bound " + (dir / "scene.json").string(), dir, sensors());
    const Run b = runPenumbra("probe --error-bound " + (dir / "baked.json").string(), dir, sensors());
    REQUIRE(a.exitCode == 0);
    REQUIRE(b.exitCode == 0);
    CHECK(std::count(a.out.begin(), a.out.end(), '\n') == 41);
    auto rows = [](const std::string& csv) {
        std::vector<std::vector<double>> out;
        std::istringstream in(csv);
        std::string line;
        std::getline(in, line);  // header
        while (std::getline(in, line)) {
            std::vector<double> row;
            std::istringstream cells(line);
            std::string cell;
            while (std::getline(cells, cell, ',')) row.push_back(std::stod(cell));
            out.push_back(row);
        }
        return out;
    };
    CHECK(a.out.substr(0, a.out.find('\n')) ==
          "x,y,z,form_factor,dF_dx,dF_dy,dF_dz,shadow_rays,error_bound");
    const auto ra = rows(a.out), rb = rows(b.out);
    REQUIRE(ra.size() == rb.size());
    for (size_t i = 0; i < ra.size(); ++i) {
        REQUIRE(ra[i].size() == 9);
        REQUIRE(rb[i].size() == 9);
        CAPTURE(i, ra[i][3], rb[i][3], ra[i][8], rb[i][8]);
        CHECK(ra[i][0] == rb[i][0]);
        CHECK(std::abs(ra[i][3] - rb[i][3]) <= ra[i][8] + rb[i][8] + 1e-9);
    }
    // ... and not because nothing was in the way: some points are shadowed.
    const Scene baked = loadScene((dir / "baked.json").string());
    const Occluder occ = baked.makeOccluder();
    Occluder::Query q = occ.makeQuery();
    int shadowed = 0;
    for (int i = 0; i < 40; ++i) {
        const Receiver r{Vec3(-1.6 + 3.2 * (i + 0.5) / 40, 0.05, 0), Vec3(0, 0, 1)};
        const double f = contourIntegral(r, baked.lights[0], q).formFactor;
        if (f < unoccludedFormFactor(baked.lights[0], r) - 1e-6) ++shadowed;
    }
    CHECK(shadowed > 10);

    // OpenVDB's own tools read the file (when installed).
    if (std::system("command -v vdb_print > /dev/null 2>&1") == 0) {
        const Run print = test::runShell("vdb_print -l " + (dir / "baked.vdb").string(), dir);
        CHECK(print.exitCode == 0);
        for (const char* name : {"ball", "obstacle_1", "ring", "tet"}) {
            CHECK(print.out.find(std::string("Name: ") + name) != std::string::npos);
        }
        CHECK(print.out.find("class: level set") != std::string::npos);
    } else {
        WARN("vdb_print not found: the check that OpenVDB's tools read the baked file is skipped");
    }
    fs::remove_all(dir);
}

TEST_CASE("bake voxelizes analytic obstacles, names duplicates apart, writes half floats",
          "[cli][bake][scenes]") {
    const fs::path dir = makeTempDir("analytic");
    std::ofstream(dir / "scene.json") << scene(R"([
        {"type": "sphere", "name": "s", "center": [0,0,1.2], "radius": 0.4, "analytic": true,
         "voxel_size": 0.025},
        {"type": "sphere", "name": "s", "center": [1,0,1.2], "radius": 0.2}])");
    Run run = runPenumbra("bake " + (dir / "scene.json").string() + " -o " +
                              (dir / "full.vdb").string() + " -q",
                          dir);
    INFO(run.err);
    REQUIRE(run.exitCode == 0);
    CHECK(run.out.empty());  // --quiet
    const std::vector<LevelSetPtr> grids = readLevelSets((dir / "full.vdb").string(), "");
    REQUIRE(grids.size() == 2);
    CHECK(describe(*grids[0]).name == "s");
    CHECK(describe(*grids[1]).name == "s_1");  // the second 's' is told apart by its index
    CHECK(describe(*grids[0]).voxelSize == Approx(0.025));  // the obstacle's own voxel_size

    // The voxelized analytic sphere casts the exact shadow within the voxel and estimator
    // bounds of the [aci][levelset] tests.
    const RectLight light = loadScene((dir / "scene.json").string()).lights[0];
    Occluder occ({grids[0]});
    Occluder::Query q = occ.makeQuery();
    int penumbra = 0;
    for (int i = 0; i < 40; ++i) {
        const Receiver r{Vec3(-1.8 + 3.0 * (i + 0.5) / 40, 0.05, 0), Vec3(0, 0, 1)};
        auto exactFor = [&](double radius) {
            return exact::sphereShadowFormFactor(r.point, r.normal, light.corner, light.edgeU,
                                                 light.edgeV, Vec3(0, 0, 1.2), radius);
        };
        const double unocc = unoccludedFormFactor(light, r);
        const double f = contourIntegral(r, light, q).formFactor;
        const double bound = std::fabs(exactFor(0.4125) - exactFor(0.3875)) + 0.0625 * unocc;
        INFO("x = " << r.point.x);
        CHECK(std::fabs(f - exactFor(0.4)) < bound);
        if (exactFor(0.4) > 1e-9 && exactFor(0.4) < unocc - 1e-9) ++penumbra;
    }
    CHECK(penumbra > 10);

    // --half: half the bytes for the voxel values (the file also holds the tree's topology, and
    // both are compressed), the same surface to ~1e-3 of the band.
    run = runPenumbra("bake " + (dir / "scene.json").string() + " -o " +
                          (dir / "half.vdb").string() + " --half -q",
                      dir);
    REQUIRE(run.exitCode == 0);
    CHECK(fs::file_size(dir / "half.vdb") < 0.9 * fs::file_size(dir / "full.vdb"));
    const std::vector<LevelSetPtr> halves = readLevelSets((dir / "half.vdb").string(), "");
    REQUIRE(halves.size() == 2);
    for (const Vec3& p : {Vec3(0, 0, 1.6), Vec3(0.41, 0, 1.2), Vec3(0.3, 0.2, 1.0)}) {
        CHECK(sampleLevelSet(*halves[0], p) == Approx(sampleLevelSet(*grids[0], p)).margin(1e-4));
    }
    fs::remove_all(dir);
}

TEST_CASE("bake refuses bad input in one line, exit code 2, and leaves no file",
          "[cli][bake][scenes]") {
    const fs::path dir = makeTempDir("refused");
    writeTet(dir);
    std::ofstream(dir / "scene.json") << scene(kObstacles);
    const std::string sceneFile = (dir / "scene.json").string();
    auto refused = [&](const std::string& args, const std::string& fragment) {
        INFO(args);
        const Run run = runPenumbra(args, dir);
        INFO(run.err);
        CHECK(run.exitCode == 2);
        CHECK(run.out.empty());
        CHECK(run.err.find(fragment) != std::string::npos);
        CHECK(std::count(run.err.begin(), run.err.end(), '\n') == 1);
    };
    refused("bake " + sceneFile + " -o " + (dir / "nodir" / "x.vdb").string(),
            "-o: no such directory");
    refused("bake " + sceneFile + " -o " + (dir / "x.exr").string(), "must be a .vdb file");
    fs::create_directories(dir / "d.vdb");
    refused("bake " + sceneFile + " -o " + (dir / "d.vdb").string(), "is a directory");
    // A missing option is CLI11's message (with its usage hint on a second line).
    const Run noOutput = runPenumbra("bake " + sceneFile, dir);
    CHECK(noOutput.exitCode == 2);
    CHECK(noOutput.err.find("--output is required") != std::string::npos);

    std::ofstream(dir / "empty.json") << scene("[]");
    refused("bake " + (dir / "empty.json").string() + " -o " + (dir / "e.vdb").string(),
            "empty.json: /obstacles: the scene has no obstacles to bake");
    std::ofstream(dir / "bad.json") << scene(R"([{"type": "torus", "center": [0,0,1],
        "major_radius": 0.3, "minor_radius": 0}])");
    refused("bake " + (dir / "bad.json").string() + " -o " + (dir / "b.vdb").string(),
            "bad.json: /obstacles/0/minor_radius: must be > 0");
    CHECK_FALSE(fs::exists(dir / "e.vdb"));
    CHECK_FALSE(fs::exists(dir / "b.vdb"));

    // A refused bake leaves an existing file as it was.
    REQUIRE(runPenumbra("bake " + sceneFile + " -o " + (dir / "keep.vdb").string() + " -q", dir)
                .exitCode == 0);
    const auto size = fs::file_size(dir / "keep.vdb");
    refused("bake " + (dir / "bad.json").string() + " -o " + (dir / "keep.vdb").string(),
            "minor_radius");
    CHECK(fs::file_size(dir / "keep.vdb") == size);
    CHECK(readLevelSets((dir / "keep.vdb").string(), "").size() == 4);
    fs::remove_all(dir);
}
