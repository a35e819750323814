// The one settings model (render_settings.h): what toJson writes readJson reads back, every
// key has one range, errors name the JSON field, and the CLI's probe, render and batch refuse
// the same values with the same message (the field turned into its flag).

#include <catch2/catch.hpp>

#include <filesystem>
#include <string>

#include <nlohmann/json.hpp>

#include "penumbra/error.h"
#include "penumbra/render_settings.h"
#include "support/cli.h"

using namespace penumbra;

namespace {

std::string errorOf(const nlohmann::json& object) {
    try {
        RenderSettings s;
        s.readJson(object, "m.json", "/jobs/0");
        s.validate("m.json", "/jobs/0");
    } catch (const InputError& e) {
        return e.what();
    }
    return "no error";
}

}  // namespace

TEST_CASE("settings: toJson is read back by readJson to the same settings", "[settings]") {
    RenderSettings a;
    a.method = Method::McAdaptive;
    a.width = 320;
    a.height = 200;
    a.aci.grid = 3;
    a.aci.steps = 4;
    applyAciMode(a.aci, AciMode::Arcs);
    a.maxSpan = 17;
    a.mc.samples = 333;
    a.mc.threshold = 0.02;
    a.mc.maxDepth = 5;
    a.mc.initialDepth = 2;
    a.mc.seed = 18446744073709551615ull;
    a.volumeCache = 0;
    a.volumeSamples = 9;
    a.volumesVisible = false;
    const nlohmann::ordered_json written = a.toJson();
    RenderSettings b;
    b.readJson(nlohmann::json::parse(written.dump()));
    CHECK(b.toJson() == written);
    CHECK(b.method == a.method);
    CHECK(b.aci.grid == 3);
    CHECK(aciModeOf(b.aci) == AciMode::Arcs);
    CHECK(b.mc.seed == a.mc.seed);
    CHECK(b.mc.initialDepth == 2);
    CHECK(!b.volumesVisible);
    // Every key the model has is written for a Monte Carlo render of a set size, but the
    // thread count (no pixel depends on it).
    a.threads = 3;
    for (const std::string& key : RenderSettings::keys()) {
        INFO(key);
        CHECK(a.toJson().contains(key) == (key != "threads"));
    }
    // An ACI render does not carry Monte Carlo settings (they do not change its pixels).
    RenderSettings aci;
    CHECK(!aci.toJson().contains("samples"));
    CHECK(aci.toJson()["aci_mode"] == "tangent");
}

TEST_CASE("settings: errors name the JSON field, one range per key", "[settings]") {
    CHECK(errorOf({{"aci_grid", 0}}) == "m.json: /jobs/0/aci_grid: must be in [1, 32], got 0");
    CHECK(errorOf({{"aci_steps", 2.5}}) == "m.json: /jobs/0/aci_steps: must be an integer");
    CHECK(errorOf({{"aci_mode", "fast"}}) ==
          "m.json: /jobs/0/aci_mode: unknown ACI mode 'fast' (expected paper, arcs or tangent)");
    CHECK(errorOf({{"method", "mc"}}).rfind("m.json: /jobs/0/method: unknown method 'mc'", 0) == 0);
    CHECK(errorOf({{"mc_threshold", -1}}) == "m.json: /jobs/0/mc_threshold: must be a finite number > 0");
    CHECK(errorOf({{"seed", -1}}) == "m.json: /jobs/0/seed: must be an integer in [0, 2^64 - 1]");
    CHECK(errorOf({{"hide_volumes", 1}}) == "m.json: /jobs/0/hide_volumes: must be true or false");
    CHECK(errorOf({{"volume_cache", 257}}) == "m.json: /jobs/0/volume_cache: must be in [0, 256], got 257");
    CHECK(errorOf({{"samples", 16}}) ==
          "m.json: /jobs/0/samples: only applies to the Monte Carlo methods (reference, mc-adaptive, "
          "mc-solid-angle, mc-ratio), not 'aci'");
    CHECK(errorOf({{"aci_grid", 32}, {"aci_steps", 12}}).rfind(
              "m.json: /jobs/0/aci_steps: aci_grid x 2^(aci_steps+1) must be at most 4096", 0) == 0);
    CHECK(errorOf({{"method", "mc-ratio"}, {"samples", 16}}) == "no error");
    // Of several bad values, the first in the model's order is named.
    CHECK(errorOf({{"max_span", 0}, {"aci_grid", 0}}) == "m.json: /jobs/0/aci_grid: must be in [1, 32], got 0");
    CHECK(flagOfKey("mc_initial_depth") == "--mc-initial-depth");
}

TEST_CASE("settings: probe, render and batch refuse the same value with the same message",
          "[settings][cli]") {
    test::TempDir dir("settings", "model");
    test::writeFile(dir.path / "scene.json", R"({
      "camera": {"eye": [0,-3,3], "look_at": [0,0,0], "width": 8, "height": 8},
      "lights": [{"corner": [-0.5,-0.5,2], "edge_u": [1,0,0], "edge_v": [0,1,0]}],
      "obstacles": [{"type": "sphere", "center": [0,0,1], "radius": 0.3, "analytic": true}],
      "receivers": [{"type": "plane", "point": [0,0,0], "normal": [0,0,1]}]})");
    const std::string scene = "'" + (dir.path / "scene.json").string() + "'";
    const std::string out = "'" + (dir.path / "o.exr").string() + "'";
    const std::string manifest = "'" + (dir.path / "m.json").string() + "'";
    const std::string expected = "--aci-grid: must be in [1, 32], got 40";
    const test::Run probe = test::runPenumbra("probe " + scene + " --aci-grid 40", dir.path, "0,0,0,0,0,1\n");
    CHECK(probe.exitCode == 2);
    CHECK_THAT(probe.err, Catch::Contains(expected));
    const test::Run render = test::runPenumbra("render " + scene + " -o " + out + " --aci-grid 40", dir.path);
    CHECK(render.exitCode == 2);
    CHECK_THAT(render.err, Catch::Contains(expected));
    test::writeFile(dir.path / "m.json",
                    R"({"jobs": [{"scene": "scene.json", "output": "b.exr", "aci_grid": 40}]})");
    const test::Run batch = test::runPenumbra("batch " + manifest, dir.path);
    CHECK(batch.exitCode == 2);
    CHECK_THAT(batch.err, Catch::Contains("m.json: /jobs/0/aci_grid: must be in [1, 32], got 40"));
    // probe used to accept --aci-steps 0 and --aci-grid up to 64.
    const test::Run steps = test::runPenumbra("probe " + scene + " --aci-steps 0", dir.path, "0,0,0,0,0,1\n");
    CHECK(steps.exitCode == 2);
    CHECK_THAT(steps.err, Catch::Contains("--aci-steps: must be in [1, 12], got 0"));
    CHECK(!std::filesystem::exists(dir.path / "o.exr"));
    CHECK(!std::filesystem::exists(dir.path / "b.exr"));
}
