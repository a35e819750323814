// Tests for the scene loader (scene.h, src/scene_json.cpp): the documented example loads with
// the values written in it, defaults apply, and every refused input names the file and the
// exact JSON pointer of the offending value.
#include <unistd.h>

#include <atomic>
#include <catch2/catch.hpp>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <variant>

#include "penumbra/error.h"
#include "penumbra/level_set.h"
#include "penumbra/scene.h"

using namespace penumbra;
namespace fs = std::filesystem;

namespace {

/// A fresh directory under the system temp dir, removed with its contents at scope exit.
class TempDir {
  public:
    TempDir() {
        static std::atomic<int> counter{0};
        mPath = fs::temp_directory_path() / ("penumbra_test_scene_" + std::to_string(::getpid()) +
                                             "_" + std::to_string(counter++));
        fs::remove_all(mPath);
        fs::create_directories(mPath);
    }
    ~TempDir() {
        std::error_code ec;
        fs::remove_all(mPath, ec);
    }
    const fs::path& path() const { return mPath; }
    std::string write(const std::string& name, const std::string& text) const {
        const fs::path p = mPath / name;
        fs::create_directories(p.parent_path());
        std::ofstream(p) << text;
        return p.string();
    }

  private:
    fs::path mPath;
};

const char* const kLight = R"({"corner": [-1,-1,4], "edge_u": [0,2,0], "edge_v": [2,0,0]})";

/// A scene with one valid light plus the given top-level members (text after a comma).
std::string withLight(const std::string& rest) {
    return std::string(R"({"lights": [)") + kLight + "]" + (rest.empty() ? "" : ", " + rest) + "}";
}

/// Parses `text` as "scene.json" and returns the InputError it must raise.
InputError refusal(const std::string& text) {
    try {
        parseScene(text, "scene.json", "");
    } catch (const InputError& e) {
        return e;
    }
    FAIL("accepted: " << text);
    throw std::logic_error("unreachable");
}

void requireRefused(const std::string& text, const std::string& pointer,
                    const std::string& fragment) {
    INFO(text);
    const InputError e = refusal(text);
    INFO(e.what());
    CHECK(e.file() == "scene.json");
    CHECK(e.where() == pointer);
    const std::string what = e.what();
    CHECK(what.find("scene.json") != std::string::npos);
    CHECK(what.find(pointer) != std::string::npos);
    CHECK(what.find(fragment) != std::string::npos);
    CHECK(what.find('\n') == std::string::npos);
}

void requireVec(const Vec3& v, double x, double y, double z) {
    CHECK(v.x == Approx(x).margin(1e-12));
    CHECK(v.y == Approx(y).margin(1e-12));
    CHECK(v.z == Approx(z).margin(1e-12));
}

const std::string kExample = R"({
  "camera": {"eye": [0,-6,3], "look_at": [0,0,0.5], "up": [0,0,1], "fov_deg": 40,
             "width": 800, "height": 800},
  "lights": [{"name": "key", "type": "rect", "corner": [-1,-1,4], "edge_u": [0,2,0],
              "edge_v": [2,0,0], "radiance": [1,1,1]}],
  "obstacles": [{"type": "sphere", "center": [0.3,0.2,2.0], "radius": 0.5},
                {"type": "vdb", "file": "cube.vdb", "grid": "Cube"}],
  "receivers": [{"type": "plane", "point": [0,0,0], "normal": [0,0,1], "albedo": [0.8,0.8,0.8]}],
  "level_set": {"voxel_size": 0.01, "half_width": 3}
})";

}  // namespace

TEST_CASE("the documented example scene loads with the values written in it", "[scene]") {
    TempDir dir;
    // A 0.4-wide cube centred at (-0.5, 0.5, 0.6), voxel 0.02.
    writeLevelSets(
        (dir.path() / "cube.vdb").string(),
        {makeBoxLevelSet(Vec3(-0.7, 0.3, 0.4), Vec3(-0.3, 0.7, 0.8), 0.02, 3.0, "Cube")});
    const std::string path = dir.write("scene.json", kExample);
    const Scene scene = loadScene(path);

    CHECK(scene.file == path);
    REQUIRE(scene.camera.has_value());
    requireVec(scene.camera->eye, 0, -6, 3);
    requireVec(scene.camera->lookAt, 0, 0, 0.5);
    requireVec(scene.camera->up, 0, 0, 1);
    CHECK(scene.camera->fovDeg == 40.0);
    CHECK(scene.camera->width == 800);
    CHECK(scene.camera->height == 800);

    REQUIRE(scene.lights.size() == 1);
    CHECK(scene.lights[0].name == "key");
    requireVec(scene.lights[0].corner, -1, -1, 4);
    requireVec(scene.lights[0].edgeU, 0, 2, 0);
    requireVec(scene.lights[0].edgeV, 2, 0, 0);
    requireVec(scene.lights[0].radiance, 1, 1, 1);

    REQUIRE(scene.receivers.size() == 1);
    requireVec(scene.receivers[0].normal, 0, 0, 1);
    requireVec(scene.receivers[0].albedo, 0.8, 0.8, 0.8);
    CHECK_FALSE(scene.receivers[0].checker);

    CHECK(scene.levelSet.voxelSize == 0.01);
    CHECK(scene.levelSet.halfWidth == 3.0);

    REQUIRE(scene.obstacles.size() == 2);
    CHECK(scene.obstacles[0].name == "obstacle_0");
    CHECK(scene.obstacles[1].name == "Cube");  // a .vdb obstacle takes its grid's name
    requireVec(scene.obstacles[1].albedo, 0.8, 0.8, 0.8);

    // The sphere became a level set at the scene's voxel size; its active band reaches
    // half_width voxels beyond the surface on each side.
    const auto* sphere = std::get_if<LevelSetPtr>(&scene.obstacles[0].shape);
    REQUIRE(sphere);
    const LevelSetInfo si = describe(**sphere);
    CHECK(si.name == "obstacle_0");
    CHECK(si.voxelSize == Approx(0.01));
    CHECK(si.halfWidth == Approx(3.0));
    const double sphereReach = 0.5 + 3 * 0.01;
    for (int k = 0; k < 3; ++k) {
        const double c = Vec3(0.3, 0.2, 2.0)[k];
        CHECK(si.boundsWS.lo[k] == Approx(c - sphereReach).margin(0.015));
        CHECK(si.boundsWS.hi[k] == Approx(c + sphereReach).margin(0.015));
    }

    const auto* cube = std::get_if<LevelSetPtr>(&scene.obstacles[1].shape);
    REQUIRE(cube);
    const LevelSetInfo ci = describe(**cube);
    CHECK(ci.voxelSize == Approx(0.02));  // the file's own voxels, not the scene's
    CHECK(ci.boundsWS.lo.x == Approx(-0.7 - 3 * 0.02).margin(0.03));
    CHECK(ci.boundsWS.hi.z == Approx(0.8 + 3 * 0.02).margin(0.03));
}

TEST_CASE("omitted fields take their documented defaults", "[scene]") {
    const Scene scene =
        parseScene(withLight(R"("obstacles": [{"type": "sphere", "center": [0,0,1], "radius": 0.25,
                                     "analytic": true},
                                    {"type": "box", "name": "crate", "center": [1,2,3],
                                     "size": [0.2,0.4,0.6], "analytic": true,
                                     "albedo": [0.1,0.2,0.3]}],
                     "receivers": [{"type": "plane", "point": [0,0,0], "normal": [0,0,5]},
                                   {"type": "plane", "point": [0,0,0], "normal": [0,3,4],
                                    "checker": {}},
                                   {"type": "plane", "point": [0,0,0], "normal": [1,0,0],
                                    "checker": {"albedo2": [0.1,0.1,0.1], "scale": 0.5}}])"),
                   "mem.json", "");
    CHECK(scene.file == "mem.json");
    CHECK_FALSE(scene.camera.has_value());
    requireVec(scene.background, 0, 0, 0);
    CHECK(scene.levelSet.voxelSize == 0.02);
    CHECK(scene.levelSet.halfWidth == 3.0);

    REQUIRE(scene.lights.size() == 1);
    CHECK(scene.lights[0].name == "light_0");
    requireVec(scene.lights[0].radiance, 1, 1, 1);

    REQUIRE(scene.obstacles.size() == 2);
    CHECK(scene.obstacles[0].name == "obstacle_0");
    requireVec(scene.obstacles[0].albedo, 0.8, 0.8, 0.8);
    CHECK(scene.obstacles[1].name == "crate");
    requireVec(scene.obstacles[1].albedo, 0.1, 0.2, 0.3);
    const auto* box = std::get_if<AnalyticBox>(&scene.obstacles[1].shape);
    REQUIRE(box);
    requireVec(box->lo, 0.9, 1.8, 2.7);
    requireVec(box->hi, 1.1, 2.2, 3.3);

    REQUIRE(scene.receivers.size() == 3);
    requireVec(scene.receivers[0].normal, 0, 0, 1);  // normalised
    CHECK_FALSE(scene.receivers[0].checker);
    requireVec(scene.receivers[0].albedo, 0.8, 0.8, 0.8);
    requireVec(scene.receivers[1].normal, 0, 0.6, 0.8);
    CHECK(scene.receivers[1].checker);
    requireVec(scene.receivers[1].albedo2, 0.4, 0.4, 0.4);
    CHECK(scene.receivers[1].checkerScale == 1.0);
    CHECK(scene.receivers[2].checker);
    requireVec(scene.receivers[2].albedo2, 0.1, 0.1, 0.1);
    CHECK(scene.receivers[2].checkerScale == 0.5);

    // An empty camera object is the default camera.
    const Scene withCamera =
        parseScene(withLight(R"("camera": {}, "background": [0.1,0.2,0.3])"), "", "");
    REQUIRE(withCamera.camera.has_value());
    const Camera def;
    CHECK(withCamera.camera->eye == def.eye);
    CHECK(withCamera.camera->lookAt == def.lookAt);
    CHECK(withCamera.camera->fovDeg == def.fovDeg);
    CHECK(withCamera.camera->width == def.width);
    requireVec(withCamera.background, 0.1, 0.2, 0.3);
}

TEST_CASE("an obstacle's voxel_size overrides the scene's", "[scene]") {
    const Scene scene = parseScene(withLight(R"("level_set": {"voxel_size": 0.05, "half_width": 2},
                     "obstacles": [{"type": "sphere", "center": [0,0,1], "radius": 0.3},
                                   {"type": "box", "center": [1,0,1], "size": [0.3,0.3,0.3],
                                    "voxel_size": 0.025}])"),
                                   "s.json", "");
    REQUIRE(scene.obstacles.size() == 2);
    const LevelSetInfo a = describe(*std::get<LevelSetPtr>(scene.obstacles[0].shape));
    const LevelSetInfo b = describe(*std::get<LevelSetPtr>(scene.obstacles[1].shape));
    CHECK(a.voxelSize == Approx(0.05));
    CHECK(a.halfWidth == Approx(2.0));
    CHECK(b.voxelSize == Approx(0.025));
    CHECK(b.halfWidth == Approx(2.0));
}

TEST_CASE("refused inputs name the file and the exact JSON pointer", "[scene]") {
    const std::string sphere = R"({"type": "sphere", "center": [0,0,1], "radius": 0.5})";
    auto obstacle = [](const std::string& o) { return withLight(R"("obstacles": [)" + o + "]"); };
    auto light = [](const std::string& l) { return R"({"lights": [)" + l + "]}"; };

    SECTION("missing fields") {
        requireRefused(R"({"obstacles": []})", "/lights", "missing required field 'lights'");
        requireRefused(R"({"lights": []})", "/lights", "at least one light");
        requireRefused(obstacle(R"({"type": "sphere", "center": [0,0,1]})"), "/obstacles/0/radius",
                       "missing required field 'radius'");
        requireRefused(obstacle(R"({"center": [0,0,1], "radius": 1})"), "/obstacles/0/type",
                       "missing required field 'type'");
        requireRefused(light(R"({"corner": [0,0,0], "edge_u": [1,0,0]})"), "/lights/0/edge_v",
                       "missing required field 'edge_v'");
        requireRefused(withLight(R"("receivers": [{"type": "plane", "point": [0,0,0]}])"),
                       "/receivers/0/normal", "missing required field 'normal'");
        requireRefused(obstacle(R"({"type": "vdb"})"), "/obstacles/0/file",
                       "missing required field 'file'");
    }
    SECTION("wrong types") {
        requireRefused(obstacle(R"({"type": "sphere", "center": "origin", "radius": 1})"),
                       "/obstacles/0/center", "expected an array of 3 numbers, got string");
        requireRefused(obstacle(R"({"type": "sphere", "center": [0,0], "radius": 1})"),
                       "/obstacles/0/center", "expected an array of 3 numbers, got an array of 2");
        requireRefused(obstacle(R"({"type": "sphere", "center": [0,"1",0], "radius": 1})"),
                       "/obstacles/0/center/1", "expected a number, got string");
        requireRefused(obstacle(R"({"type": "sphere", "center": [0,0,1], "radius": "1"})"),
                       "/obstacles/0/radius", "expected a number, got string");
        requireRefused(obstacle(R"({"type": "sphere", "center": [0,0,1], "radius": 1,
                                    "analytic": 1})"),
                       "/obstacles/0/analytic", "expected true or false, got number");
        requireRefused(R"([1, 2])", "", "expected an object, got an array of 2");
        requireRefused(R"({"lights": {}})", "/lights", "expected an array, got object");
        requireRefused(withLight(R"("camera": {"width": 640.5})"), "/camera/width",
                       "expected an integer, got 640.5");
        requireRefused(obstacle("3"), "/obstacles/0", "expected an object, got number");
        requireRefused(withLight(R"("camera": [])"), "/camera", "expected an object");
    }
    SECTION("numbers out of range or non-finite") {
        requireRefused(obstacle(R"({"type": "sphere", "center": [0,0,1], "radius": 1e400})"),
                       "/obstacles/0/radius", "must be finite");
        requireRefused(obstacle(R"({"type": "sphere", "center": [0,-1e999,1], "radius": 1})"),
                       "/obstacles/0/center/1", "must be finite");
        requireRefused(obstacle(R"({"type": "sphere", "center": [0,0,1], "radius": -1})"),
                       "/obstacles/0/radius", "must be > 0, got -1");
        requireRefused(obstacle(R"({"type": "sphere", "center": [0,0,1], "radius": 0,
                                    "analytic": true})"),
                       "/obstacles/0/radius", "must be > 0, got 0");
        requireRefused(obstacle(R"({"type": "box", "center": [0,0,1], "size": [1,0,1]})"),
                       "/obstacles/0/size/1", "must be > 0, got 0");
        requireRefused(withLight(R"("level_set": {"voxel_size": 0})"), "/level_set/voxel_size",
                       "must be > 0, got 0");
        requireRefused(withLight(R"("level_set": {"half_width": 0.5})"), "/level_set/half_width",
                       "must be > 1");
        // OpenVDB's rasterizer needs more than one voxel of band on each side.
        requireRefused(withLight(R"("level_set": {"half_width": 1})"), "/level_set/half_width",
                       "must be > 1");
        requireRefused(obstacle(R"({"type": "sphere", "center": [0,0,1], "radius": 1,
                                    "voxel_size": -0.1})"),
                       "/obstacles/0/voxel_size", "must be > 0, got -0.1");
        requireRefused(obstacle(R"({"type": "sphere", "center": [0,0,1], "radius": 0.01})"),
                       "/obstacles/0/radius", "below 1.5 voxels");
        requireRefused(obstacle(R"({"type": "sphere", "center": [1e7,0,1], "radius": 1})"),
                       "/obstacles/0", "index range");
    }
    SECTION("colours") {
        requireRefused(light(R"({"corner": [0,0,0], "edge_u": [1,0,0], "edge_v": [0,1,0],
                                 "radiance": [1,-0.5,1]})"),
                       "/lights/0/radiance/1", "must be >= 0, got -0.5");
        requireRefused(obstacle(R"({"type": "sphere", "center": [0,0,1], "radius": 1,
                                    "albedo": [0,0,-1], "analytic": true})"),
                       "/obstacles/0/albedo/2", "must be >= 0, got -1");
        requireRefused(withLight(R"("background": [-1,0,0])"), "/background/0", "must be >= 0");
        requireRefused(withLight(R"("receivers": [{"type": "plane", "point": [0,0,0],
                                    "normal": [0,0,1], "checker": {"albedo2": [0,-2,0]}}])"),
                       "/receivers/0/checker/albedo2/1", "must be >= 0");
    }
    SECTION("geometry") {
        requireRefused(withLight(R"("receivers": [{"type": "plane", "point": [0,0,0],
                                                    "normal": [0,0,0]}])"),
                       "/receivers/0/normal", "non-zero vector");
        requireRefused(light(R"({"corner": [0,0,0], "edge_u": [1,0,0], "edge_v": [3,0,0]})"),
                       "/lights/0", "degenerate rectangle");
        requireRefused(light(R"({"corner": [0,0,0], "edge_u": [1,0,0], "edge_v": [0,0,0]})"),
                       "/lights/0", "degenerate rectangle");
        requireRefused(light(R"({"corner": [0,0,0], "edge_u": [1,0,0],
                                 "edge_v": [1,1e-12,0]})"),
                       "/lights/0", "degenerate rectangle");
        requireRefused(withLight(R"("receivers": [{"type": "plane", "point": [0,0,0],
                                    "normal": [0,0,1], "checker": {"scale": 0}}])"),
                       "/receivers/0/checker/scale", "must be > 0");
    }
    SECTION("camera") {
        requireRefused(withLight(R"("camera": {"width": 0})"), "/camera/width",
                       "must be in [1, 32768], got 0");
        requireRefused(withLight(R"("camera": {"height": 32769})"), "/camera/height",
                       "must be in [1, 32768], got 32769");
        requireRefused(withLight(R"("camera": {"fov_deg": 0})"), "/camera/fov_deg",
                       "must be in (0, 180)");
        requireRefused(withLight(R"("camera": {"fov_deg": 180})"), "/camera/fov_deg",
                       "must be in (0, 180)");
        requireRefused(withLight(R"("camera": {"eye": [1,2,3], "look_at": [1,2,3]})"),
                       "/camera/look_at", "must differ from eye");
        requireRefused(withLight(R"("camera": {"eye": [0,0,5], "look_at": [0,0,0]})"), "/camera/up",
                       "parallel to the viewing direction");
        requireRefused(withLight(R"("camera": {"up": [0,0,0]})"), "/camera/up", "non-zero vector");
    }
    SECTION("unknown types suggest the nearest valid one") {
        requireRefused(obstacle(R"({"type": "sphre", "center": [0,0,1], "radius": 1})"),
                       "/obstacles/0/type",
                       "unknown obstacle type 'sphre' (did you mean 'sphere'?)");
        requireRefused(light(R"({"type": "rectangle", "corner": [0,0,0], "edge_u": [1,0,0],
                                 "edge_v": [0,1,0]})"),
                       "/lights/0/type", "unknown light type 'rectangle' (did you mean 'rect'?");
        requireRefused(withLight(R"("receivers": [{"type": "plan", "point": [0,0,0],
                                                    "normal": [0,0,1]}])"),
                       "/receivers/0/type", "unknown receiver type 'plan' (did you mean 'plane'?)");
    }
    SECTION("duplicates") {
        requireRefused(obstacle(R"({"type": "sphere", "center": [0,0,1], "radius": 1,
                                    "radius": 2})"),
                       "/obstacles/0/radius", "duplicate key 'radius'");
        requireRefused(R"({"lights": [{"name": "a", "corner": [0,0,0], "edge_u": [1,0,0],
                                       "edge_v": [0,1,0]},
                                      {"name": "a", "corner": [0,0,1], "edge_u": [1,0,0],
                                       "edge_v": [0,1,0]}]})",
                       "/lights/1/name", "duplicate light name 'a'");
    }
    (void)sphere;
}

TEST_CASE("an unknown key names the nearest valid key", "[scene]") {
    requireRefused(withLight(R"("obstacles": [{"type": "sphere", "center": [0,0,1],
                                               "radius2": 0.5}])"),
                   "/obstacles/0/radius2", "unknown key 'radius2' (did you mean 'radius'?)");
    requireRefused(withLight(R"("ligths": [])"), "/ligths",
                   "unknown key 'ligths' (did you mean 'lights'?)");
    requireRefused(withLight(R"("camera": {"fov": 30})"), "/camera/fov",
                   "unknown key 'fov' (did you mean 'fov_deg'?)");
    requireRefused(withLight(R"("level_set": {"voxelsize": 0.1})"), "/level_set/voxelsize",
                   "unknown key 'voxelsize' (did you mean 'voxel_size'?)");
    // Keys valid for one obstacle type are unknown for another.
    requireRefused(withLight(R"("obstacles": [{"type": "vdb", "file": "x.vdb",
                                               "radius": 1}])"),
                   "/obstacles/0/radius", "unknown key 'radius'");
    // A key far from every valid one also lists them; '/' and '~' are escaped in the pointer.
    requireRefused(withLight(R"("a/b~c": 1)"), "/a~1b~0c", "valid: camera, lights");
}

TEST_CASE("malformed JSON is reported by line and column", "[scene]") {
    // Line 3 is `  "obstacles": [,]`: the comma after '[' is at column 17.
    const std::string text = "{\n  \"lights\": [],\n  \"obstacles\": [,]\n}";
    requireRefused(text, "", "malformed JSON at line 3, column 17");
    // Columns count characters, not UTF-8 bytes: "é" is two bytes.
    requireRefused("{\"\xc3\xa9\": 1 2}", "", "malformed JSON at line 1, column 9");
    requireRefused("", "", "malformed JSON at line 1, column 1");
    requireRefused(withLight("") + " trailing", "", "malformed JSON at line 1");
}

TEST_CASE("comments are accepted in scene files", "[scene]") {
    const Scene s = parseScene("// a key light\n" + withLight("/* none */ \"background\": [1,1,1]"),
                               "c.json", "");
    requireVec(s.background, 1, 1, 1);
}

TEST_CASE("relative .vdb paths resolve against the scene file's directory", "[scene]") {
    TempDir dir;
    fs::create_directories(dir.path() / "data");
    writeLevelSets((dir.path() / "data" / "two.vdb").string(),
                   {makeSphereLevelSet(Vec3(0, 0, 1), 0.3, 0.05, 3.0, "A"),
                    makeBoxLevelSet(Vec3(1, 1, 0), Vec3(1.5, 1.5, 0.5), 0.05, 3.0, "B")});
    // The scene lives in a sibling directory and points up and across.
    const std::string path = dir.write(
        "scenes/s.json", withLight(R"("obstacles": [{"type": "vdb", "file": "../data/two.vdb"},
                                   {"type": "vdb", "file": "../data/two.vdb", "name": "pair"},
                                   {"type": "vdb", "file": "../data/two.vdb", "grid": "B",
                                    "name": "just_b", "albedo": [0.5,0.5,0.5]}])"));
    const Scene scene = loadScene(path);
    REQUIRE(scene.obstacles.size() == 5);
    // Without "grid", every level-set grid of the file becomes an obstacle.
    CHECK(scene.obstacles[0].name == "A");
    CHECK(scene.obstacles[1].name == "B");
    CHECK(scene.obstacles[2].name == "pair/A");
    CHECK(scene.obstacles[3].name == "pair/B");
    CHECK(scene.obstacles[4].name == "just_b");
    requireVec(scene.obstacles[4].albedo, 0.5, 0.5, 0.5);
    const LevelSetInfo b = describe(*std::get<LevelSetPtr>(scene.obstacles[4].shape));
    CHECK(b.name == "B");
    CHECK(b.boundsWS.lo.x == Approx(1.0 - 3 * 0.05).margin(0.06));

    // parseScene resolves against the baseDir it is given.
    const Scene fromText = parseScene(
        withLight(R"("obstacles": [{"type": "vdb", "file": "data/two.vdb", "grid": "A"}])"),
        "t.json", dir.path().string());
    REQUIRE(fromText.obstacles.size() == 1);
    CHECK(fromText.obstacles[0].name == "A");

    // A missing file is refused at its "file" field and shows where it was looked for.
    const std::string missing = dir.write(
        "scenes/m.json", withLight(R"("obstacles": [{"type": "vdb", "file": "nope.vdb"}])"));
    try {
        loadScene(missing);
        FAIL("accepted a missing .vdb");
    } catch (const InputError& e) {
        CHECK(e.file() == missing);
        CHECK(e.where() == "/obstacles/0/file");
        CHECK(e.message().find((dir.path() / "scenes" / "nope.vdb").string()) != std::string::npos);
    }

    // A grid that is not in the file: the scene file and pointer first, the .vdb in the message.
    const std::string noGrid = dir.write(
        "scenes/g.json",
        withLight(R"("obstacles": [{"type": "vdb", "file": "../data/two.vdb", "grid": "C"}])"));
    try {
        loadScene(noGrid);
        FAIL("accepted a missing grid");
    } catch (const InputError& e) {
        CHECK(e.file() == noGrid);
        CHECK(e.where() == "/obstacles/0");
        CHECK(e.message().find("two.vdb") != std::string::npos);
        CHECK(e.message().find("'C'") != std::string::npos);
    }
}

TEST_CASE("a missing scene file is an InputError naming it", "[scene]") {
    TempDir dir;
    const std::string path = (dir.path() / "absent.json").string();
    try {
        loadScene(path);
        FAIL("loaded a missing file");
    } catch (const InputError& e) {
        CHECK(e.file() == path);
    }
}

TEST_CASE("level sets over the memory limit are refused before they are built", "[scene]") {
    // 4 pi 100^2 / 0.001^2 * 6 voxels: thousands of GiB; refused at once, nothing is allocated.
    const InputError huge = refusal(withLight(
        R"("obstacles": [{"type": "sphere", "center": [0,0,1], "radius": 0.5, "analytic": true},
                         {"type": "sphere", "center": [0,0,1], "radius": 100,
                          "voxel_size": 0.001}])"));
    CHECK(huge.where() == "/obstacles/1");
    CHECK(huge.message().find("would need ~") != std::string::npos);
    CHECK(huge.message().find(" GiB for its level set") != std::string::npos);
    CHECK(huge.message().find("limit of 16 GiB") != std::string::npos);

    // The limit is the scene's to set: the same small sphere passes or fails with it.
    const std::string small =
        R"("obstacles": [{"type": "sphere", "center": [0,0,1], "radius": 0.2}],
           "level_set": {"voxel_size": 0.05, "max_memory_gib": )";
    CHECK(parseScene(withLight(small + "1}"), "", "").obstacles.size() == 1);
    requireRefused(withLight(small + "1e-6}"), "/obstacles/0", "for its level set");
}

TEST_CASE("analytic obstacles reach the occluder as exact shapes", "[scene]") {
    const Scene scene = parseScene(
        withLight(R"("obstacles": [{"type": "sphere", "center": [0.3,0.2,2], "radius": 0.5,
                                     "analytic": true},
                                    {"type": "box", "center": [0,0,1], "size": [1,2,0.5],
                                     "analytic": true}])"),
        "a.json", "");
    const Occluder occ = scene.makeOccluder();
    REQUIRE(occ.size() == 2);
    const auto* s = std::get_if<AnalyticSphere>(&occ.shape(0));
    REQUIRE(s);
    requireVec(s->center, 0.3, 0.2, 2.0);
    CHECK(s->radius == 0.5);
    const auto* b = std::get_if<AnalyticBox>(&occ.shape(1));
    REQUIRE(b);
    requireVec(b->lo, -0.5, -1.0, 0.75);
    requireVec(b->hi, 0.5, 1.0, 1.25);
    CHECK(occ.minVoxelSize() == 0.0);  // no level set among them
}

TEST_CASE("lightIndex picks by name, or the only light, and refuses ambiguity", "[scene]") {
    const Scene one = parseScene(withLight(""), "one.json", "");
    CHECK(one.lightIndex("") == 0);
    CHECK(one.lightIndex("light_0") == 0);

    const Scene two = parseScene(
        R"({"lights": [{"name": "key", "corner": [0,0,3], "edge_u": [1,0,0], "edge_v": [0,1,0]},
                       {"name": "fill", "corner": [2,0,3], "edge_u": [1,0,0],
                        "edge_v": [0,1,0]}]})",
        "two.json", "");
    CHECK(two.lightIndex("key") == 0);
    CHECK(two.lightIndex("fill") == 1);
    try {
        two.lightIndex("");
        FAIL("an empty name chose among two lights");
    } catch (const InputError& e) {
        CHECK(e.file() == "two.json");
        CHECK(e.message().find("2 lights") != std::string::npos);
        CHECK(e.message().find("'key'") != std::string::npos);
        CHECK(e.message().find("'fill'") != std::string::npos);
    }
    try {
        two.lightIndex("fil");
        FAIL("found a light that does not exist");
    } catch (const InputError& e) {
        CHECK(e.message().find("no light named 'fil' (did you mean 'fill'?)") != std::string::npos);
    }

    // The loader refuses duplicate names, but a scene built in code may still have them.
    Scene dup = two;
    dup.lights[1].name = "key";
    CHECK_THROWS_WITH(dup.lightIndex("key"), Catch::Contains("ambiguous"));
    Scene none;
    CHECK_THROWS_AS(none.lightIndex(""), InputError);
}

TEST_CASE("the shipped default scene loads", "[scene]") {
    const Scene scene = loadScene(std::string(PENUMBRA_SOURCE_DIR) + "/vdb_scenes/default.json");
    REQUIRE(scene.camera.has_value());
    CHECK(scene.camera->width == 800);
    CHECK(scene.camera->height == 800);
    REQUIRE(scene.lights.size() == 1);
    REQUIRE(scene.receivers.size() == 1);
    CHECK_FALSE(scene.receivers[0].checker);
    REQUIRE(scene.obstacles.size() == 2);
    for (const Obstacle& o : scene.obstacles) {
        REQUIRE(std::holds_alternative<LevelSetPtr>(o.shape));
        const LevelSetInfo info = describe(*std::get<LevelSetPtr>(o.shape));
        CHECK(info.activeVoxels > 0);
        CHECK(info.boundsWS.lo.z > 0.0);  // both float above the plane z = 0
    }
}

TEST_CASE("every JSON example in docs/scene-format.md loads", "[scene]") {
    std::ifstream in(std::string(PENUMBRA_SOURCE_DIR) + "/docs/scene-format.md");
    REQUIRE(in);
    std::vector<std::string> blocks;
    std::string line, block;
    bool inside = false;
    while (std::getline(in, line)) {
        if (!inside && line == "```json") {
            inside = true;
            block.clear();
        } else if (inside && line == "```") {
            inside = false;
            blocks.push_back(block);
        } else if (inside) {
            block += line + "\n";
        }
    }
    REQUIRE(blocks.size() == 2);
    // The first example is the shipped default scene, verbatim.
    std::ifstream def(std::string(PENUMBRA_SOURCE_DIR) + "/vdb_scenes/default.json");
    const std::string defText((std::istreambuf_iterator<char>(def)),
                              std::istreambuf_iterator<char>());
    CHECK(blocks[0] == defText);

    // The second refers to assets/bunny.vdb with a grid "ls_bunny": provide one.
    TempDir dir;
    fs::create_directories(dir.path() / "assets");
    writeLevelSets((dir.path() / "assets" / "bunny.vdb").string(),
                   {makeSphereLevelSet(Vec3(-1, 1, 0.5), 0.4, 0.05, 3.0, "ls_bunny")});
    const Scene scene = parseScene(blocks[1], "doc.json", dir.path().string());
    CHECK(scene.lights.size() == 2);
    REQUIRE(scene.obstacles.size() == 3);
    CHECK(std::holds_alternative<AnalyticSphere>(scene.obstacles[0].shape));
    CHECK(scene.obstacles[2].name == "ls_bunny");
    REQUIRE(scene.receivers.size() == 1);
    CHECK(scene.receivers[0].checker);
}
