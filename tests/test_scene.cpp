// Tests for the scene loader (scene.h, src/scene_loader.cpp): the documented example loads with
// the values written in it, defaults apply, and every refused input names the file and the
// exact JSON pointer of the offending value. The second half ([scenes]) covers sculpted scenes:
// every primitive, CSG, mesh and transform; shadows of a vdb_tool file, a CSG union and a turned
// box against exact answers; the build report; the gallery in vdb_scenes/.
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <catch2/catch.hpp>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string>
#include <variant>

#include <nlohmann/json.hpp>

#include "support/exact_shadow.h"
#include "penumbra/contour_integrator.h"
#include "penumbra/error.h"
#include "penumbra/level_set.h"
#include "penumbra/scene.h"
#include "penumbra/shape.h"

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

/// Loads the scene file `path` and returns the InputError it must raise.
InputError loadRefusal(const std::string& path) {
    try {
        loadScene(path);
    } catch (const InputError& e) {
        return e;
    }
    FAIL("loaded: " << path);
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

/// requireRefused(text, pointer, fragment) for each {text, pointer, fragment}.
void requireAllRefused(const std::vector<std::array<std::string, 3>>& cases) {
    for (const auto& [text, pointer, fragment] : cases) requireRefused(text, pointer, fragment);
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
        requireAllRefused({
            {obstacle(R"({"type": "sphere", "center": [0,0,1], "radius": 1e400})"),
             "/obstacles/0/radius", "must be finite"},
            {obstacle(R"({"type": "sphere", "center": [0,-1e999,1], "radius": 1})"),
             "/obstacles/0/center/1", "must be finite"},
            {obstacle(R"({"type": "sphere", "center": [0,0,1], "radius": -1})"),
             "/obstacles/0/radius", "must be > 0, got -1"},
            {obstacle(R"({"type": "sphere", "center": [0,0,1], "radius": 0, "analytic": true})"),
             "/obstacles/0/radius", "must be > 0, got 0"},
            {obstacle(R"({"type": "box", "center": [0,0,1], "size": [1,0,1]})"),
             "/obstacles/0/size/1", "must be > 0, got 0"},
            {withLight(R"("level_set": {"voxel_size": 0})"), "/level_set/voxel_size",
             "must be > 0, got 0"},
            {withLight(R"("level_set": {"half_width": 0.5})"), "/level_set/half_width",
             "must be > 1"},
            // OpenVDB's rasterizer needs more than one voxel of band on each side.
            {withLight(R"("level_set": {"half_width": 1})"), "/level_set/half_width",
             "must be > 1"},
            {obstacle(R"({"type": "sphere", "center": [0,0,1], "radius": 1, "voxel_size": -0.1})"),
             "/obstacles/0/voxel_size", "must be > 0, got -0.1"},
            {obstacle(R"({"type": "sphere", "center": [0,0,1], "radius": 0.01})"),
             "/obstacles/0/radius", "below 1.5 voxels"},
            {obstacle(R"({"type": "sphere", "center": [1e7,0,1], "radius": 1})"), "/obstacles/0",
             "index range"},
        });
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
        auto camera = [](const std::string& c) { return withLight(R"("camera": )" + c); };
        requireAllRefused({
            {camera(R"({"width": 0})"), "/camera/width", "must be in [1, 32768], got 0"},
            {camera(R"({"height": 32769})"), "/camera/height", "must be in [1, 32768], got 32769"},
            {camera(R"({"fov_deg": 0})"), "/camera/fov_deg", "must be in (0, 180)"},
            {camera(R"({"fov_deg": 180})"), "/camera/fov_deg", "must be in (0, 180)"},
            {camera(R"({"eye": [1,2,3], "look_at": [1,2,3]})"), "/camera/look_at",
             "must differ from eye"},
            {camera(R"({"eye": [0,0,5], "look_at": [0,0,0]})"), "/camera/up",
             "parallel to the viewing direction"},
            {camera(R"({"up": [0,0,0]})"), "/camera/up", "non-zero vector"},
        });
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
    const InputError e = loadRefusal(missing);
    CHECK(e.file() == missing);
    CHECK(e.where() == "/obstacles/0/file");
    CHECK(e.message().find((dir.path() / "scenes" / "nope.vdb").string()) != std::string::npos);

    // A grid that is not in the file: the scene file and pointer first, the .vdb in the message.
    const std::string noGrid = dir.write(
        "scenes/g.json",
        withLight(R"("obstacles": [{"type": "vdb", "file": "../data/two.vdb", "grid": "C"}])"));
    const InputError g = loadRefusal(noGrid);
    CHECK(g.file() == noGrid);
    CHECK(g.where() == "/obstacles/0");
    CHECK(g.message().find("two.vdb") != std::string::npos);
    CHECK(g.message().find("'C'") != std::string::npos);
}

TEST_CASE("a missing scene file is an InputError naming it", "[scene]") {
    TempDir dir;
    const std::string path = (dir.path() / "absent.json").string();
    CHECK(loadRefusal(path).file() == path);
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
    // The default limit is 16 GiB or 3/4 of the machine's memory, whichever is less.
    CHECK(huge.message().find("over the limit of ") != std::string::npos);
    const InputError sixteen = refusal(withLight(
        R"("level_set": {"max_memory_gib": 16},
           "obstacles": [{"type": "sphere", "center": [0,0,1], "radius": 100,
                          "voxel_size": 0.001}])"));
    CHECK(sixteen.message().find("over the limit of 16 GiB") != std::string::npos);

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

    // The second refers to assets/bunny.vdb with a grid "ls_bunny", a closed mesh
    // assets/part.obj and an open one, assets/leaf.obj: provide them.
    TempDir dir;
    fs::create_directories(dir.path() / "assets");
    writeLevelSets((dir.path() / "assets" / "bunny.vdb").string(),
                   {makeSphereLevelSet(Vec3(-1, 1, 0.5), 0.4, 0.05, 3.0, "ls_bunny")});
    std::ofstream(dir.path() / "assets" / "part.obj")
        << "v -0.5 -0.5 -0.5\nv 0.5 -0.5 -0.5\nv -0.5 0.5 -0.5\nv 0.5 0.5 -0.5\n"
           "v -0.5 -0.5 0.5\nv 0.5 -0.5 0.5\nv -0.5 0.5 0.5\nv 0.5 0.5 0.5\n"
           "f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n";
    std::ofstream(dir.path() / "assets" / "leaf.obj")
        << "v 1 1 1\nv 1.6 1.1 1.1\nv 1.5 1.5 1.2\nv 1.1 1.4 1.0\nf 1 2 3 4\n";
    const Scene scene = parseScene(blocks[1], "doc.json", dir.path().string());
    CHECK(scene.lights.size() == 2);
    REQUIRE(scene.obstacles.size() == 11);
    CHECK(std::holds_alternative<AnalyticSphere>(scene.obstacles[0].shape));
    CHECK(scene.obstacles[2].name == "ls_bunny");
    CHECK(scene.obstacles[3].name == "ring");
    CHECK(scene.obstacles[9].name == "snowman");
    for (size_t i = 1; i < scene.obstacles.size(); ++i) {
        INFO(scene.obstacles[i].name);
        REQUIRE(std::holds_alternative<LevelSetPtr>(scene.obstacles[i].shape));
        CHECK(describe(*std::get<LevelSetPtr>(scene.obstacles[i].shape)).activeVoxels > 0);
    }
    REQUIRE(scene.receivers.size() == 1);
    CHECK(scene.receivers[0].checker);
}

// =============================================================================================
// Sculpted scenes: implicit primitives, CSG, meshes, transforms, .vdb files from other tools
// (issue 5). Shadows are checked against exact answers with the estimator's and the voxels'
// error bounds of the [aci][levelset] tests: 6.25% of the unoccluded form factor for the
// estimator, plus the change of the exact answer when the obstacle grows by half a voxel.

namespace {

const std::string kSource = PENUMBRA_SOURCE_DIR;

/// A unit-normal receiver line on the ground z = 0, along x at y.
std::vector<Receiver> groundLine(int n, double x0, double x1, double y) {
    std::vector<Receiver> out;
    for (int i = 0; i < n; ++i) {
        out.push_back({Vec3(x0 + (x1 - x0) * (i + 0.5) / n, y, 0.0), Vec3(0, 0, 1)});
    }
    return out;
}

/// Form factors of the scene's first light at the receivers, by the paper's estimator.
std::vector<double> probe(const Scene& scene, const std::vector<Receiver>& points) {
    const Occluder occ = scene.makeOccluder();
    Occluder::Query query = occ.makeQuery();
    AciSettings settings;
    settings.rayOffset = occ.minVoxelSize() > 0 ? 1.5 * occ.minVoxelSize() : 1e-9;
    ContourIntegrator aci(settings);
    std::vector<double> out;
    for (const Receiver& r : points) {
        out.push_back(aci.evaluate(r, scene.lights[0], query).formFactor);
    }
    return out;
}

/// Exact form factor with spheres whose shadows on the light do not overlap: each sphere hides
/// its own part of the light.
double exactSpheres(const Receiver& r, const RectLight& l,
                    const std::vector<std::pair<Vec3, double>>& balls) {
    const double unocc = exact::lambertPolygon(exact::lightPolygon(l.corner, l.edgeU, l.edgeV),
                                               r.point, r.normal);
    double f = unocc;
    for (const auto& [c, radius] : balls) {
        f += exact::sphereShadowFormFactor(r.point, r.normal, l.corner, l.edgeU, l.edgeV, c,
                                           radius) -
             unocc;
    }
    return f;
}

}  // namespace

TEST_CASE("every primitive, CSG, mesh and transform of the format loads", "[scene][scenes]") {
    TempDir dir;
    fs::create_directories(dir.path() / "meshes");
    std::ofstream(dir.path() / "meshes" / "tet.obj")
        << "v 0 0 0\nv 0.4 0 0\nv 0 0.4 0\nv 0 0 0.4\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
    writeLevelSets((dir.path() / "ball.vdb").string(),
                   {makeSphereLevelSet(Vec3(0, 0, 0), 0.2, 0.04, 3.0, "ball")});
    const std::string path = dir.write("s.json", withLight(R"(
      "level_set": {"voxel_size": 0.04},
      "obstacles": [
        {"type": "torus", "name": "ring", "center": [0,0,1], "major_radius": 0.4,
         "minor_radius": 0.1, "axis": [0,2,0]},
        {"type": "capsule", "a": [1,0,0.5], "b": [1.5,0,0.5], "radius": 0.1},
        {"type": "cylinder", "center": [0,0,0], "radius": 0.2, "height": 0.6,
         "transform": {"rotate_deg": [90,0,0], "translate": [-1,0,0.5]}},
        {"type": "box", "center": [0,1,0.5], "size": [0.4,0.4,0.4], "round": 0.1,
         "transform": {"translate": [0,0,1], "scale": 2}},
        {"type": "half_space", "name": "floor", "point": [0,0,0], "normal": [0,0,1],
         "bounds": [[-2,-2,-1], [2,2,0.5]]},
        {"type": "mesh", "file": "meshes/tet.obj", "transform": {"translate": [0,-1,0]}},
        {"type": "csg", "name": "carved", "op": "difference", "children": [
           {"type": "box", "center": [0,-1.5,1], "size": [0.6,0.6,0.6]},
           {"type": "csg", "op": "union", "children": [
              {"type": "cylinder", "center": [0,-1.5,1], "radius": 0.15, "height": 1},
              {"type": "vdb", "file": "ball.vdb", "transform": {"translate": [0.3,-1.5,1.3]}}]}]},
        {"type": "csg", "op": "smooth_union", "blend": 0.1, "children": [
           {"type": "sphere", "center": [1,1,1], "radius": 0.2},
           {"type": "mesh", "file": "meshes/tet.obj", "transform": {"translate": [1.1,1,1]}}]}
      ])"));
    const Scene scene = loadScene(path);
    REQUIRE(scene.obstacles.size() == 8);
    std::vector<LevelSetInfo> info;
    for (const Obstacle& o : scene.obstacles) {
        REQUIRE(std::holds_alternative<LevelSetPtr>(o.shape));
        info.push_back(describe(*std::get<LevelSetPtr>(o.shape)));
        CHECK(info.back().voxelSize == Approx(0.04));
        CHECK(info.back().activeVoxels > 100);
    }
    CHECK(scene.obstacles[0].name == "ring");
    CHECK(scene.obstacles[1].name == "obstacle_1");
    CHECK(scene.obstacles[6].name == "carved");
    const double band = 3 * 0.04, cell = 0.5 * 0.04;
    // The torus's axis is y: it spans x and z, not y.
    CHECK(info[0].boundsWS.hi.x == Approx(0.5 + band + cell).margin(0.04));
    CHECK(info[0].boundsWS.hi.y == Approx(0.1 + band + cell).margin(0.04));
    // The cylinder turned about x lies along y.
    CHECK(info[2].boundsWS.hi.y == Approx(0.3 + band + cell).margin(0.04));
    CHECK(info[2].boundsWS.hi.z == Approx(0.7 + band + cell).margin(0.04));
    // The box scaled by 2 about the origin, then moved up by 1: centre (0, 2, 2), size 0.8.
    CHECK(info[3].boundsWS.lo.z == Approx(1.6 - band - cell).margin(0.04));
    CHECK(info[3].boundsWS.hi.y == Approx(2.4 + band + cell).margin(0.04));
    // The half-space fills its bounds below z = 0.
    CHECK(info[4].boundsWS.lo.x == Approx(-2 - band - cell).margin(0.04));
    CHECK(info[4].boundsWS.hi.z == Approx(0 + band + cell).margin(0.04));
    // The tetrahedron, moved by -1 in y.
    CHECK(info[5].boundsWS.lo.y == Approx(-1 - band - cell).margin(0.04));
    const LevelSetPtr carved = std::get<LevelSetPtr>(scene.obstacles[6].shape);
    CHECK(sampleLevelSet(*carved, Vec3(0, -1.5, 1)) > 0.0);         // drilled through
    CHECK(sampleLevelSet(*carved, Vec3(0.25, -1.25, 0.75)) < 0.0);   // material left
    CHECK(sampleLevelSet(*carved, Vec3(0.3, -1.5, 1.3)) > 0.0);      // bitten by the ball

    // The build report has one entry per obstacle, with the level sets' own figures.
    REQUIRE(scene.build.obstacles.size() == 8);
    uint64_t voxels = 0;
    for (size_t i = 0; i < 8; ++i) {
        CHECK(scene.build.obstacles[i].name == scene.obstacles[i].name);
        CHECK(scene.build.obstacles[i].activeVoxels == info[i].activeVoxels);
        CHECK(scene.build.obstacles[i].bytes == info[i].bytes);
        CHECK(scene.build.obstacles[i].seconds >= 0.0);
        CHECK(scene.build.obstacles[i].estimatedBytes > 0.0);
        voxels += info[i].activeVoxels;
    }
    CHECK(scene.build.obstacles[0].type == "torus");
    CHECK(scene.build.obstacles[6].type == "csg");
    CHECK(scene.build.activeVoxels() == voxels);
    CHECK(scene.build.seconds >= scene.build.obstacles[0].seconds);
    const std::string text = scene.build.toText();
    CHECK(text.find("obstacle 'ring' (torus): ") != std::string::npos);
    CHECK(std::count(text.begin(), text.end(), '\n') == 9);
    const nlohmann::json j = nlohmann::json::parse(scene.build.toJson());
    CHECK(j["active_voxels"].get<uint64_t>() == voxels);
    CHECK(j["obstacles"].size() == 8);
    CHECK(j["obstacles"][5]["type"] == "mesh");
}

TEST_CASE("a half-space without bounds is cut to the scene's bounds", "[scene][scenes]") {
    // Lights span [-1, 1] x [-1, 1] at z = 4, the sphere reaches down to z = 0.5; the box around
    // them is widened by 10% of its diagonal on each side.
    const Scene scene = parseScene(withLight(R"(
        "level_set": {"voxel_size": 0.05},
        "obstacles": [{"type": "sphere", "center": [0,0,1], "radius": 0.5},
                      {"type": "half_space", "point": [0,0,0], "normal": [0,0,1]}])"),
                                   "h.json", "");
    const Vec3 lo(-1, -1, 0.5), hi(1, 1, 4);
    const double pad = 0.1 * glm::length(hi - lo);
    const LevelSetInfo info = describe(*std::get<LevelSetPtr>(scene.obstacles[1].shape));
    CHECK(info.boundsWS.lo.x == Approx(lo.x - pad - 0.15).margin(0.05));
    CHECK(info.boundsWS.hi.y == Approx(hi.y + pad + 0.15).margin(0.05));
    CHECK(info.boundsWS.lo.z == Approx(lo.z - pad - 0.15).margin(0.05));
    CHECK(info.boundsWS.hi.z == Approx(0.15).margin(0.05));  // the plane, plus the band
}

TEST_CASE("a .vdb obstacle's transform moves its grid; several files load together",
          "[scene][scenes]") {
    TempDir dir;
    writeLevelSets((dir.path() / "crate.vdb").string(),
                   {makeBoxLevelSet(Vec3(-0.3, -0.1, 0.0), Vec3(0.3, 0.1, 0.2), 0.02, 3.0,
                                    "crate")});
    writeLevelSets((dir.path() / "ball.vdb").string(),
                   {makeSphereLevelSet(Vec3(0, 0, 0), 0.25, 0.02, 3.0, "ball")});
    const Scene scene = loadScene(dir.write("v.json", withLight(R"("obstacles": [
        {"type": "vdb", "file": "crate.vdb", "transform": {"rotate_deg": [0,0,90],
                                                           "translate": [1,0,0.5]}},
        {"type": "vdb", "file": "ball.vdb", "name": "big",
         "transform": {"scale": 2, "translate": [-1,0,1]}}])")));
    REQUIRE(scene.obstacles.size() == 2);
    const LevelSetPtr crate = std::get<LevelSetPtr>(scene.obstacles[0].shape);
    // Turned a quarter about z: 0.2 wide in x, 0.6 in y, centred on (1, 0, 0.6).
    CHECK(sampleLevelSet(*crate, Vec3(1.1 + 0.02, 0, 0.6)) == Approx(0.02).margin(0.002));
    CHECK(sampleLevelSet(*crate, Vec3(1, 0.3 + 0.02, 0.6)) == Approx(0.02).margin(0.002));
    // Shadow rays see the turned grid: down through its footprint they stop on its top face
    // (z = 0.7); at (1.25, 0), inside the unturned footprint, they pass.
    const Occluder occ = scene.makeOccluder();
    Occluder::Query q = occ.makeQuery();
    double t = -1.0;
    CHECK(q.occluded(Vec3(1.05, 0.25, 2), Vec3(1.05, 0.25, -1), &t));
    CHECK(t == Approx(2.0 - 0.7).margin(0.25 * 0.02));
    CHECK_FALSE(q.occluded(Vec3(1.25, 0, 2), Vec3(1.25, 0, -1)));
    const LevelSetPtr big = std::get<LevelSetPtr>(scene.obstacles[1].shape);
    CHECK(describe(*big).voxelSize == Approx(0.04));
    CHECK(sampleLevelSet(*big, Vec3(-1, 0, 1.5 + 0.04)) == Approx(0.04).margin(0.004));
    CHECK(scene.build.obstacles[1].note.find("ball.vdb") != std::string::npos);
}

TEST_CASE("sculpted and mesh obstacles are refused with the exact pointer", "[scene][scenes]") {
    TempDir dir;
    std::ofstream(dir.path() / "bad.obj") << "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n";
    std::ofstream(dir.path() / "sheet.obj") << "v 0 0 1\nv 1 0 1\nv 1 1 1\nf 1 2 3\n";
    writeLevelSets((dir.path() / "two.vdb").string(),
                   {makeSphereLevelSet(Vec3(0, 0, 1), 0.3, 0.05, 3.0, "A"),
                    makeSphereLevelSet(Vec3(1, 0, 1), 0.3, 0.05, 3.0, "B")});
    const std::string base = dir.path().string();
    auto refusedIn = [&](const std::string& obstacles, const std::string& pointer,
                         const std::string& fragment) {
        const std::string text = withLight(R"("level_set": {"voxel_size": 0.05}, "obstacles": [)" +
                                           obstacles + "]");
        INFO(text);
        try {
            parseScene(text, "scene.json", base);
            FAIL("accepted");
        } catch (const InputError& e) {
            INFO(e.what());
            CHECK(e.file() == "scene.json");
            CHECK(e.where() == pointer);
            CHECK(std::string(e.what()).find(fragment) != std::string::npos);
            CHECK(std::string(e.what()).find('\n') == std::string::npos);
        }
    };
    SECTION("primitives") {
        refusedIn(R"({"type": "torus", "center": [0,0,1], "major_radius": 0.5, "minor_radius": 0})",
                  "/obstacles/0/minor_radius", "must be > 0, got 0");
        refusedIn(R"({"type": "torus", "center": [0,0,1], "major_radius": 0.5,
                      "minor_radius": 0.01})",
                  "/obstacles/0/minor_radius", "below 1.5 voxels (voxel_size 0.05)");
        refusedIn(R"({"type": "torus", "center": [0,0,1], "major_radius": 0.5,
                      "minor_radius": 0.1, "axis": [0,0,0]})",
                  "/obstacles/0/axis", "non-zero vector");
        refusedIn(R"({"type": "torus", "center": [0,0,1], "minor_radius": 0.1})",
                  "/obstacles/0/major_radius", "missing required field 'major_radius'");
        refusedIn(R"({"type": "capsule", "a": [0,0,1], "b": [1,0,1], "radius": -0.1})",
                  "/obstacles/0/radius", "must be > 0");
        refusedIn(R"({"type": "capsule", "a": [0,0,1], "radius": 0.1})", "/obstacles/0/b",
                  "missing required field 'b'");
        refusedIn(R"({"type": "cylinder", "center": [0,0,1], "radius": 0.2, "height": 0})",
                  "/obstacles/0/height", "must be > 0");
        refusedIn(R"({"type": "cylinder", "center": [0,0,1], "radius": 0.2, "height": 0.05})",
                  "/obstacles/0/height", "below 1.5 voxels");
        refusedIn(R"({"type": "box", "center": [0,0,1], "size": [1,1,0.4], "round": 0.3})",
                  "/obstacles/0/round", "must be <= half the smallest size (0.2), got 0.3");
        refusedIn(R"({"type": "box", "center": [0,0,1], "size": [1,1,1], "round": -0.1})",
                  "/obstacles/0/round", "must be >= 0");
        refusedIn(R"({"type": "half_space", "point": [0,0,0], "normal": [0,0,0]})",
                  "/obstacles/0/normal", "non-zero vector");
        refusedIn(R"({"type": "half_space", "point": [0,0,0], "normal": [0,0,1],
                      "bounds": [[0,0,0], [1,1,0]]})",
                  "/obstacles/0/bounds/1/2", "must be > the low corner's 0, got 0");
        refusedIn(R"({"type": "half_space", "point": [0,0,0], "normal": [0,0,1],
                      "bounds": [[0,0,0]]})",
                  "/obstacles/0/bounds", "expected [[x, y, z], [x, y, z]]");
        refusedIn(R"({"type": "half_space", "point": [0,0,0], "normal": [0,0,1],
                      "bounds": [0, 1]})",
                  "/obstacles/0/bounds/0", "expected an array of 3 numbers");
        // Keys of one primitive are unknown on another; "analytic" only on spheres and boxes.
        refusedIn(R"({"type": "torus", "center": [0,0,1], "major_radius": 0.5,
                      "minor_radius": 0.1, "radius": 1})",
                  "/obstacles/0/radius", "unknown key 'radius'");
        refusedIn(R"({"type": "capsule", "a": [0,0,1], "b": [1,0,1], "radius": 0.1,
                      "analytic": true})",
                  "/obstacles/0/analytic", "unknown key 'analytic'");
    }
    SECTION("transforms") {
        refusedIn(R"({"type": "sphere", "center": [0,0,1], "radius": 0.3,
                      "transform": {"scale": 0}})",
                  "/obstacles/0/transform/scale", "must be > 0, got 0");
        refusedIn(R"({"type": "sphere", "center": [0,0,1], "radius": 0.3,
                      "transform": {"rotate": [0,0,90]}})",
                  "/obstacles/0/transform/rotate",
                  "unknown key 'rotate' (did you mean 'rotate_deg'?)");
        refusedIn(R"({"type": "sphere", "center": [0,0,1], "radius": 0.3,
                      "transform": {"translate": [0,1]}})",
                  "/obstacles/0/transform/translate", "expected an array of 3 numbers");
        refusedIn(R"({"type": "sphere", "center": [0,0,1], "radius": 0.3, "transform": [1,2,3]})",
                  "/obstacles/0/transform", "expected an object");
        // Scaling down can bring a feature under the voxel size.
        refusedIn(R"({"type": "sphere", "center": [0,0,1], "radius": 0.1,
                      "transform": {"scale": 0.5}})",
                  "/obstacles/0/radius",
                  "below 1.5 voxels (voxel_size 0.05, after scaling by 0.5)");
        refusedIn(R"({"type": "box", "center": [0,0,1], "size": [1,1,1], "analytic": true,
                      "transform": {"rotate_deg": [0,0,10]}})",
                  "/obstacles/0/transform", "an analytic box stays axis-aligned");
        refusedIn(R"({"type": "box", "center": [0,0,1], "size": [1,1,1], "analytic": true,
                      "round": 0.1})",
                  "/obstacles/0/round", "an analytic box has sharp edges");
    }
    SECTION("csg") {
        const std::string s1 = R"({"type": "sphere", "center": [0,0,1], "radius": 0.3})";
        const std::string s2 = R"({"type": "sphere", "center": [0.3,0,1], "radius": 0.3})";
        refusedIn(R"({"type": "csg", "op": "unoin", "children": [)" + s1 + "," + s2 + "]}",
                  "/obstacles/0/op", "unknown csg op 'unoin' (did you mean 'union'?)");
        refusedIn(R"({"type": "csg", "children": [)" + s1 + "," + s2 + "]}", "/obstacles/0/op",
                  "missing required field 'op'");
        refusedIn(R"({"type": "csg", "op": "smooth_union", "children": [)" + s1 + "," + s2 + "]}",
                  "/obstacles/0/blend", "missing required field 'blend'");
        refusedIn(R"({"type": "csg", "op": "smooth_union", "blend": 0, "children": [)" + s1 +
                      "," + s2 + "]}",
                  "/obstacles/0/blend", "must be > 0");
        refusedIn(R"({"type": "csg", "op": "union", "blend": 0.1, "children": [)" + s1 + "," +
                      s2 + "]}",
                  "/obstacles/0/blend",
                  "applies only to op \"smooth_union\" (this csg is a union)");
        refusedIn(R"({"type": "csg", "op": "union", "children": [)" + s1 + "]}",
                  "/obstacles/0/children", "at least 2 children, got 1");
        refusedIn(R"({"type": "csg", "op": "union", "children": {}})", "/obstacles/0/children",
                  "expected an array");
        // Children carry no name, albedo or resolution of their own; errors deep in the tree
        // are reported at their pointer.
        refusedIn(R"({"type": "csg", "op": "union", "children": [)" + s1 +
                      R"(, {"type": "sphere", "name": "x", "center": [0,0,1], "radius": 0.3}]})",
                  "/obstacles/0/children/1/name", "unknown key 'name'");
        refusedIn(R"({"type": "csg", "op": "union", "children": [)" + s1 +
                      R"(, {"type": "sphere", "center": [0,0,1], "radius": 0.3,
                            "voxel_size": 0.01}]})",
                  "/obstacles/0/children/1/voxel_size", "unknown key 'voxel_size'");
        refusedIn(R"({"type": "csg", "op": "union", "children": [)" + s1 +
                      R"(, {"type": "csg", "op": "difference", "children": [)" + s2 +
                      R"(, {"type": "torus", "center": [0,0,1], "major_radius": 0.3,
                            "minor_radius": -1}]}]})",
                  "/obstacles/0/children/1/children/1/minor_radius", "must be > 0");
        refusedIn(R"({"type": "csg", "op": "union", "children": [)" + s1 +
                      R"(, {"type": "cone"}]})",
                  "/obstacles/0/children/1/type", "unknown shape type 'cone'");
        refusedIn(R"({"type": "csg", "op": "union", "children": [)" + s1 + R"(, 3]})",
                  "/obstacles/0/children/1", "expected an object, got number");
        // The children's sizes count at the scale of every transform above them.
        refusedIn(R"({"type": "csg", "op": "union", "transform": {"scale": 0.1}, "children": [)" +
                      s1 + "," + s2 + "]}",
                  "/obstacles/0/children/0/radius", "after scaling by 0.1");
        // An intersection of disjoint shapes has no surface.
        refusedIn(R"({"type": "csg", "op": "intersection", "children": [)" + s1 +
                      R"(, {"type": "sphere", "center": [3,0,1], "radius": 0.3}]})",
                  "/obstacles/0", "has no surface");
    }
    SECTION("meshes and grids inside CSG") {
        refusedIn(R"({"type": "mesh", "file": "none.obj"})", "/obstacles/0/file",
                  "no such file 'none.obj'");
        refusedIn(R"({"type": "mesh", "file": "bad.obj"})", "/obstacles/0/file",
                  "bad.obj: line 4: vertex index 7 is out of range (3 vertices read so far)");
        refusedIn(R"({"type": "mesh", "file": "sheet.obj"})", "/obstacles/0",
                  "sheet.obj: the mesh encloses no volume");
        refusedIn(R"({"type": "mesh", "file": "sheet.obj", "thickness": 0.01})",
                  "/obstacles/0/thickness", "below 1.5 voxels");
        refusedIn(R"({"type": "mesh", "file": "sheet.obj", "thickness": -1})",
                  "/obstacles/0/thickness", "must be > 0");
        refusedIn(R"({"type": "mesh", "file": "sheet.obj", "grid": "x"})", "/obstacles/0/grid",
                  "unknown key 'grid'");
        const std::string s1 = R"({"type": "sphere", "center": [0,0,1], "radius": 0.3})";
        refusedIn(R"({"type": "csg", "op": "union", "children": [)" + s1 +
                      R"(, {"type": "vdb", "file": "two.vdb"}]})",
                  "/obstacles/0/children/1/grid", "holds 2 level sets ('A', 'B'); name the one");
        refusedIn(R"({"type": "csg", "op": "union", "children": [)" + s1 +
                      R"(, {"type": "vdb", "file": "two.vdb", "grid": "C"}]})",
                  "/obstacles/0/children/1", "no grid named 'C'");
        refusedIn(R"({"type": "csg", "op": "union", "children": [)" + s1 +
                      R"(, {"type": "vdb", "file": "three.vdb", "grid": "C"}]})",
                  "/obstacles/0/children/1/file", "no such file 'three.vdb'");
        refusedIn(R"({"type": "vdb", "file": "two.vdb", "voxel_size": 0.1})",
                  "/obstacles/0/voxel_size", "unknown key 'voxel_size'");
    }
    SECTION("memory") {
        // A mesh's and a CSG's level sets are estimated before anything is built (the sheet
        // below would be refused as enclosing no volume if it were built).
        refusedIn(R"({"type": "mesh", "file": "sheet.obj", "voxel_size": 0.00001})",
                  "/obstacles/0", "for its level set");
        refusedIn(R"({"type": "csg", "op": "union", "voxel_size": 0.0001, "children": [
                      {"type": "sphere", "center": [0,0,1], "radius": 1},
                      {"type": "torus", "center": [0,0,1], "major_radius": 1,
                       "minor_radius": 0.5}]})",
                  "/obstacles/0", "for its level set");
    }
}

TEST_CASE("a level set written by vdb_tool casts the shadow of Penumbra's own sphere",
          "[scene][scenes]") {
    // vdb_scenes/vdb_tool_shapes.vdb is made by vdb_scenes/make_vdb_tool_scene.sh: its grid
    // "ball" is vdb_tool's sphere of radius 0.45 at (-0.6, 0, 0.6), voxel 0.02, half width 3,
    // stored as half floats.
    const std::string light = R"({"corner": [-1.1,-0.5,2.5], "edge_u": [0,1,0],
                                  "edge_v": [1,0,0]})";
    const Scene fromTool = parseScene(
        R"({"lights": [)" + light + R"(], "obstacles": [{"type": "vdb",
            "file": "vdb_tool_shapes.vdb", "grid": "ball"}]})",
        "tool.json", kSource + "/vdb_scenes");
    const Scene ours = parseScene(
        R"({"lights": [)" + light + R"(], "level_set": {"voxel_size": 0.02, "half_width": 3},
            "obstacles": [{"type": "sphere", "center": [-0.6,0,0.6], "radius": 0.45}]})",
        "ours.json", "");
    const LevelSetInfo toolInfo = describe(*std::get<LevelSetPtr>(fromTool.obstacles[0].shape));
    CHECK(toolInfo.voxelSize == Approx(0.02));
    CHECK(toolInfo.halfWidth == Approx(3.0).epsilon(1e-3));  // half-float background

    const std::vector<Receiver> line = groundLine(80, -2.1, 0.9, 0.07);
    const std::vector<double> a = probe(fromTool, line), b = probe(ours, line);
    const RectLight& l = ours.lights[0];
    int penumbra = 0;
    double worst = 0.0;
    for (size_t i = 0; i < line.size(); ++i) {
        const Receiver& r = line[i];
        const double unocc = unoccludedFormFactor(l, r);
        const double exactF = exactSpheres(r, l, {{Vec3(-0.6, 0, 0.6), 0.45}});
        INFO("x = " << r.point.x << ": vdb_tool " << a[i] << ", Penumbra " << b[i] << ", exact "
                    << exactF);
        // Same voxels, same distances up to half-float rounding (~1e-3 of the band): the
        // estimator takes the same decisions but for rays grazing the surface.
        CHECK(std::fabs(a[i] - b[i]) <= 0.005 * unocc);
        worst = std::max(worst, std::fabs(a[i] - b[i]) / unocc);
        const double voxelBound =
            std::fabs(exactSpheres(r, l, {{Vec3(-0.6, 0, 0.6), 0.45 + 0.01}}) -
                      exactSpheres(r, l, {{Vec3(-0.6, 0, 0.6), 0.45 - 0.01}}));
        CHECK(std::fabs(a[i] - exactF) < voxelBound + 0.0625 * unocc);
        if (exactF > 1e-9 && exactF < unocc - 1e-9) ++penumbra;
    }
    INFO("largest difference, relative to the unoccluded form factor: " << worst);
    CHECK(penumbra > 20);
}

TEST_CASE("the union of two disjoint spheres casts the exact two-sphere shadow",
          "[scene][scenes]") {
    const Scene scene = parseScene(withLight(R"(
        "level_set": {"voxel_size": 0.02},
        "obstacles": [{"type": "csg", "op": "union", "children": [
            {"type": "sphere", "center": [-0.45,0,1.2], "radius": 0.3},
            {"type": "sphere", "center": [0.45,0.1,1.2], "radius": 0.25}]}])"),
                                   "pair.json", "");
    const std::vector<std::pair<Vec3, double>> balls = {{Vec3(-0.45, 0, 1.2), 0.3},
                                                         {Vec3(0.45, 0.1, 1.2), 0.25}};
    const RectLight& l = scene.lights[0];
    const std::vector<Receiver> line = groundLine(80, -2.2, 2.2, 0.05);
    const std::vector<double> f = probe(scene, line);
    int compared = 0, both = 0;
    for (size_t i = 0; i < line.size(); ++i) {
        const Receiver& r = line[i];
        // F = F1 + F2 - F0 holds when the spheres' shadows on the light do not overlap, that
        // is when the cones from M around the two spheres are disjoint.
        const Vec3 d0 = balls[0].first - r.point, d1 = balls[1].first - r.point;
        const double apart = exact::angleBetween(d0, d1);
        const double half0 = std::asin(balls[0].second / glm::length(d0));
        const double half1 = std::asin(balls[1].second / glm::length(d1));
        if (!(apart > half0 + half1)) continue;
        ++compared;
        const double unocc = unoccludedFormFactor(l, r);
        const double exactF = exactSpheres(r, l, balls);
        const double f0 = exactSpheres(r, l, {balls[0]}), f1 = exactSpheres(r, l, {balls[1]});
        if (f0 < unocc - 1e-9 && f1 < unocc - 1e-9) ++both;  // both spheres shadow M
        std::vector<std::pair<Vec3, double>> grown = balls, shrunk = balls;
        for (auto& b : grown) b.second += 0.01;
        for (auto& b : shrunk) b.second -= 0.01;
        const double voxelBound =
            std::fabs(exactSpheres(r, l, grown) - exactSpheres(r, l, shrunk));
        INFO("x = " << r.point.x << ": aci " << f[i] << ", exact " << exactF);
        CHECK(std::fabs(f[i] - exactF) < voxelBound + 0.0625 * unocc);
    }
    CHECK(compared > 50);
    CHECK(both > 5);  // points in the shadow of both spheres at once were among them
}

TEST_CASE("a box's shadow matches the exact convex-hull answer, turned or not",
          "[scene][scenes]") {
    const Vec3 center(0.1, -0.05, 1.3), size(0.6, 0.4, 0.3);
    for (const Vec3& rotate : {Vec3(0.0), Vec3(20, -10, 35)}) {
        std::ostringstream obstacles;
        obstacles << R"("level_set": {"voxel_size": 0.02}, "obstacles": [{"type": "box",
            "center": [0,0,0], "size": [)"
                  << size.x << "," << size.y << "," << size.z
                  << R"(], "transform": {"rotate_deg": [)" << rotate.x << "," << rotate.y
                  << "," << rotate.z << R"(], "translate": [)" << center.x << "," << center.y
                  << "," << center.z << "]}}]";
        const Scene scene = parseScene(withLight(obstacles.str()), "box.json", "");
        const Similarity t = Similarity::fromSceneTransform(center, rotate, 1.0);
        auto corners = [&](double grow) {
            std::vector<Vec3> v;
            const Vec3 h = 0.5 * size + Vec3(grow);
            for (int c = 0; c < 8; ++c) {
                v.push_back(t.apply(Vec3(c & 1 ? h.x : -h.x, c & 2 ? h.y : -h.y,
                                         c & 4 ? h.z : -h.z)));
            }
            return v;
        };
        const RectLight& l = scene.lights[0];
        const std::vector<Receiver> line = groundLine(60, -2.0, 2.0, 0.1);
        const std::vector<double> f = probe(scene, line);
        int penumbra = 0;
        for (size_t i = 0; i < line.size(); ++i) {
            const Receiver& r = line[i];
            auto exactFor = [&](double grow) {
                return exact::convexPolyhedronShadowFormFactor(r.point, r.normal, l.corner,
                                                               l.edgeU, l.edgeV, corners(grow));
            };
            const double unocc = unoccludedFormFactor(l, r);
            const double exactF = exactFor(0.0);
            const double voxelBound = std::fabs(exactFor(0.01) - exactFor(-0.01));
            INFO("rotate " << rotate.z << ", x = " << r.point.x << ": aci " << f[i] << ", exact "
                           << exactF);
            CHECK(std::fabs(f[i] - exactF) < voxelBound + 0.0625 * unocc);
            if (exactF > 1e-9 && exactF < unocc - 1e-9) ++penumbra;
        }
        CHECK(penumbra > 20);
    }
}

TEST_CASE("the gallery scenes load", "[scene][scenes]") {
    for (const char* name : {"table1", "csg", "vdb_tool", "bunny"}) {
        INFO(name);
        const Scene scene = loadScene(kSource + "/vdb_scenes/" + name + ".json");
        CHECK(scene.camera.has_value());
        CHECK(scene.lights.size() == 1);
        CHECK_FALSE(scene.obstacles.empty());
        for (const ObstacleBuild& b : scene.build.obstacles) {
            CHECK((b.analytic || b.activeVoxels > 0));
        }
    }
}
