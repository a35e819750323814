// Tests of batch.h and `penumbra batch`: manifests and sweeps, overrides, sharding (in process
// and as separate processes, as a cluster runs them), failure isolation, and resume after a
// SIGKILL. Renders are tiny (24 x 24 analytic scenes) except where a run must last long enough
// to be killed.
#include <catch2/catch.hpp>

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "support/batch.h"
#include "support/cli.h"
#include "support/scenes.h"
#include "penumbra/batch.h"
#include "penumbra/error.h"
#include "penumbra/image_io.h"
#include "penumbra/output_files.h"
#include "penumbra/renderer.h"
#include "penumbra/scene.h"

extern char** environ;

namespace fs = std::filesystem;
using namespace penumbra;

namespace {

using test::countTemporaries;
using test::readFile;
using test::runPenumbraSpawned;
using test::SceneDir;
using test::spawnPenumbra;
using test::TempDir;
using test::waitExit;
using test::writeFile;

int runPenumbra(const std::vector<std::string>& args, const fs::path& dir, const std::string& tag,
                const std::vector<std::string>& extraEnv = {}) {
    return runPenumbraSpawned(args, dir, tag, extraEnv);
}

struct SummaryRow {
    size_t index;
    std::string name, status, error, output;
    uint64_t shadowRays;
};

// Reads the CSV summary; fields here never need quotes except `error`, which is last but three.
std::vector<SummaryRow> readSummaryCsv(const fs::path& path) {
    std::ifstream in(path);
    std::string line;
    std::getline(in, line);
    REQUIRE(line == "index,name,status,error,seconds,shadow_rays,output,scene");
    std::vector<SummaryRow> rows;
    while (std::getline(in, line)) {
        std::vector<std::string> cells;
        std::string cell;
        bool quoted = false;
        for (size_t i = 0; i < line.size(); ++i) {
            const char c = line[i];
            if (quoted) {
                if (c == '"' && i + 1 < line.size() && line[i + 1] == '"') {
                    cell += '"';
                    ++i;
                } else if (c == '"') {
                    quoted = false;
                } else {
                    cell += c;
                }
            } else if (c == '"') {
                quoted = true;
            } else if (c == ',') {
                cells.push_back(cell);
                cell.clear();
            } else {
                cell += c;
            }
        }
        cells.push_back(cell);
        REQUIRE(cells.size() == 8);
        rows.push_back({size_t(std::stoul(cells[0])), cells[1], cells[2], cells[3], cells[6],
                        std::stoull(cells[5])});
    }
    return rows;
}

std::map<std::string, int> countStatuses(const std::vector<SummaryRow>& rows) {
    std::map<std::string, int> n;
    for (const SummaryRow& r : rows) ++n[r.status];
    return n;
}

double meanOf(const Image& img) {
    double s = 0.0;
    for (float v : img.data) s += v;
    return s / double(img.data.size());
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Sharding

TEST_CASE("shards partition the jobs, balanced, for several shard counts", "[batch]") {
    for (size_t jobs : {size_t(0), size_t(1), size_t(7), size_t(16), size_t(23), size_t(100)}) {
        for (int count = 1; count <= 9; ++count) {
            std::vector<int> owner(jobs, -1);
            size_t smallest = jobs, largest = 0;
            for (int index = 0; index < count; ++index) {
                const std::vector<size_t> mine = shardJobs(jobs, {index, count});
                CHECK(std::is_sorted(mine.begin(), mine.end()));
                smallest = std::min(smallest, mine.size());
                largest = std::max(largest, mine.size());
                for (size_t j : mine) {
                    REQUIRE(j < jobs);
                    CHECK(owner[j] == -1);  // no job in two shards
                    owner[j] = index;
                    CHECK(int(j % size_t(count)) == index);
                }
            }
            CHECK(std::count(owner.begin(), owner.end(), -1) == 0);  // union is everything
            CHECK(largest - smallest <= 1);
            CHECK(largest == (jobs + size_t(count) - 1) / size_t(count));
        }
    }
}

TEST_CASE("shards come from --shard, Slurm array variables or a Kubernetes completion index",
          "[batch]") {
    CHECK(parseShard("2/5").index == 2);
    CHECK(parseShard("2/5").count == 5);
    CHECK(parseShard("0/1").count == 1);
    for (const char* bad : {"5/5", "1/0", "a/3", "3", "-1/4", "1/", "/4", "1/4/2", " 1/4"}) {
        INFO(bad);
        CHECK_THROWS_AS(parseShard(bad), InputError);
    }

    std::map<std::string, std::string> env;
    auto getEnv = [&env](const char* name) -> const char* {
        auto it = env.find(name);
        return it == env.end() ? nullptr : it->second.c_str();
    };
    CHECK_FALSE(shardFromEnvironment(0, getEnv).has_value());

    // Slurm: --array=4-7 gives IDs 4..7 with MIN 4 and COUNT 4.
    env = {{"SLURM_ARRAY_TASK_ID", "6"}, {"SLURM_ARRAY_TASK_MIN", "4"},
           {"SLURM_ARRAY_TASK_COUNT", "4"}};
    auto s = shardFromEnvironment(0, getEnv);
    REQUIRE(s.has_value());
    CHECK(s->index == 2);
    CHECK(s->count == 4);
    // --array=1-9:2 gives IDs 1,3,5,7,9 with STEP 2 and COUNT 5.
    env = {{"SLURM_ARRAY_TASK_ID", "7"}, {"SLURM_ARRAY_TASK_MIN", "1"},
           {"SLURM_ARRAY_TASK_MAX", "9"}, {"SLURM_ARRAY_TASK_STEP", "2"},
           {"SLURM_ARRAY_TASK_COUNT", "5"}};
    s = shardFromEnvironment(0, getEnv);
    REQUIRE(s.has_value());
    CHECK(s->index == 3);
    CHECK(s->count == 5);
    // Without MIN (old Slurm): IDs are taken from 0.
    env = {{"SLURM_ARRAY_TASK_ID", "1"}, {"SLURM_ARRAY_TASK_COUNT", "3"}};
    CHECK(shardFromEnvironment(0, getEnv)->index == 1);
    CHECK(shardFromEnvironment(8, getEnv)->count == 8);  // --shard-count wins
    env = {{"SLURM_ARRAY_TASK_ID", "3"}, {"SLURM_ARRAY_TASK_COUNT", "3"}};
    CHECK_THROWS_AS(shardFromEnvironment(0, getEnv), InputError);  // a gap in the IDs
    // --array=3,5 (a list): MIN 3, MAX 5, COUNT 2 is not a range; refused rather than guessed.
    env = {{"SLURM_ARRAY_TASK_ID", "3"}, {"SLURM_ARRAY_TASK_MIN", "3"},
           {"SLURM_ARRAY_TASK_MAX", "5"}, {"SLURM_ARRAY_TASK_COUNT", "2"}};
    CHECK_THROWS_AS(shardFromEnvironment(0, getEnv), InputError);
    env["SLURM_ARRAY_TASK_STEP"] = "2";  // --array=3-5:2 is the same two tasks, as a range
    CHECK(shardFromEnvironment(0, getEnv)->index == 0);
    env["SLURM_ARRAY_TASK_ID"] = "5";
    CHECK(shardFromEnvironment(0, getEnv)->index == 1);
    env = {{"SLURM_ARRAY_TASK_ID", "x"}, {"SLURM_ARRAY_TASK_COUNT", "3"}};
    CHECK_THROWS_AS(shardFromEnvironment(0, getEnv), InputError);

    // Kubernetes: the index is 0-based; the count must be given.
    env = {{"JOB_COMPLETION_INDEX", "2"}};
    CHECK_THROWS_AS(shardFromEnvironment(0, getEnv), InputError);
    s = shardFromEnvironment(3, getEnv);
    REQUIRE(s.has_value());
    CHECK(s->index == 2);
    CHECK(s->count == 3);
    env["PENUMBRA_SHARD_COUNT"] = "4";
    CHECK(shardFromEnvironment(0, getEnv)->count == 4);
    CHECK_THROWS_AS(shardFromEnvironment(2, getEnv), InputError);  // index 2 of 2
}

// ---------------------------------------------------------------------------------------------
// Manifests, sweeps and overrides

TEST_CASE("frame templates expand {frame} with printf widths", "[batch]") {
    CHECK(expandFrameTemplate("out/a_{frame:04d}.exr", 7, "m", "/o") == "out/a_0007.exr");
    CHECK(expandFrameTemplate("f{frame}.png", 12, "m", "/o") == "f12.png");
    CHECK(expandFrameTemplate("f{frame:3d}.png", 5, "m", "/o") == "f  5.png");
    CHECK(expandFrameTemplate("{frame:02d}_{frame}", 123, "m", "/o") == "123_123");
    CHECK(expandFrameTemplate("plain.exr", 3, "m", "/o") == "plain.exr");
    for (const char* bad : {"{frames}", "{frame:04x}", "{frame", "{frame:0d}", "{}"}) {
        INFO(bad);
        CHECK_THROWS_AS(expandFrameTemplate(bad, 1, "m", "/o"), InputError);
    }
}

TEST_CASE("a sweep expands to one job per frame with interpolated scene values", "[batch]") {
    const SceneDir tmp("sweep");
    const fs::path& dir = tmp.path;
    const std::string manifestText = R"({
      "defaults": {"method": "aci-pixel"},
      "jobs": [{"scene": "a.json", "output": "out/still.png", "set": {"/camera/width": 8}}],
      "sweep": {"scene": "a.json", "output": "out/a_{frame:04d}.exr", "frames": 5, "start": 10,
                "set": {"lights/0/radiance": [2, 2, 2]},
                "vary": {"lights/0/corner": {"from": [-1, -1, 4], "to": [1, -1, 4]},
                         "camera/width": {"from": 10, "to": 20, "round": true},
                         "background": {"values": [[0,0,0], [1,0,0], [0,1,0], [0,0,1], [1,1,1]]}}}
    })";
    const BatchManifest m = parseManifest(manifestText, "m.json", dir.string());
    REQUIRE(m.jobs.size() == 6);
    CHECK(m.jobs[0].output == (dir / "out/still.png").string());
    CHECK(m.jobs[0].origin == "/jobs/0");
    CHECK(m.jobs[0].settings.method == Method::AciPixel);  // from "defaults"
    const int widths[5] = {10, 13, 15, 18, 20};  // rounded, half away from zero
    for (int k = 0; k < 5; ++k) {
        const BatchJob& job = m.jobs[size_t(1 + k)];
        char name[32];
        std::snprintf(name, sizeof name, "out/a_%04d.exr", 10 + k);
        CHECK(job.output == (dir / name).string());
        CHECK(job.name == name);
        CHECK(job.scene == (dir / "a.json").string());
        CHECK(job.settings.method == Method::AciPixel);
        // The scene the job renders, as the loader sees it.
        const Scene scene = parseScene(resolveSceneText(job), job.scene, dir.string());
        REQUIRE(scene.lights.size() == 1);
        CHECK(scene.lights[0].corner.x == -1.0 + 0.5 * k);  // exact in binary
        CHECK(scene.lights[0].corner.y == -1.0);
        CHECK(scene.lights[0].corner.z == 4.0);
        CHECK(scene.lights[0].edgeU.y == 2.0);  // untouched values stay
        CHECK(scene.lights[0].radiance.x == 2.0);
        REQUIRE(scene.camera.has_value());
        CHECK(scene.camera->width == widths[k]);
        CHECK(scene.camera->height == 24);
        CHECK(scene.background.x == (k == 1 || k == 4 ? 1.0 : 0.0));
        CHECK(scene.background.z == (k >= 3 ? 1.0 : 0.0));
    }
    // Monte Carlo settings in "defaults" go to the Monte Carlo jobs only.
    const BatchManifest mc = parseManifest(R"({"defaults": {"samples": 64, "seed": 7},
        "jobs": [{"scene": "a.json", "output": "aci.exr"},
                 {"scene": "a.json", "output": "ref.exr", "method": "reference"}]})",
                                           "m.json", dir.string());
    CHECK(mc.jobs[0].settings.mc.samples == RenderSettings().mc.samples);
    CHECK(mc.jobs[1].settings.method == Method::Reference);
    CHECK(mc.jobs[1].settings.mc.samples == 64);
    CHECK(mc.jobs[1].settings.mc.seed == 7);

    // A frame's hash differs from its neighbours' and is stable.
    const std::string h1 = jobHash(m.jobs[1], resolveSceneText(m.jobs[1]));
    CHECK(h1.size() == 16);
    CHECK(h1 == jobHash(m.jobs[1], resolveSceneText(m.jobs[1])));
    CHECK(h1 != jobHash(m.jobs[2], resolveSceneText(m.jobs[2])));
    BatchJob other = m.jobs[1];
    other.settings.method = Method::Aci;
    CHECK(h1 != jobHash(other, resolveSceneText(other)));
    other = m.jobs[1];
    other.settings.aci.grid = 3;
    CHECK(h1 != jobHash(other, resolveSceneText(other)));
}

TEST_CASE("overrides replace, add and append values; a missing parent names the pointer",
          "[batch]") {
    const std::string text = R"({"a": {"b": 1}, "list": [10, 20], "s": "x"})";
    auto apply = [&](const std::string& pointer, const std::string& value) {
        return applyOverrides(text, {{pointer, value}}, "scene.json");
    };
    CHECK(apply("/a/b", "2").find("\"b\": 2") != std::string::npos);
    CHECK(apply("a/c", "[1,2]").find("\"c\": [") != std::string::npos);  // slash optional
    const std::string appended = apply("/list/-", "30");
    CHECK(appended.find("30") != std::string::npos);
    CHECK(apply("/list/1", "99").find("99") != std::string::npos);
    CHECK(apply("/list/1", "99").find("20") == std::string::npos);
    try {
        apply("/missing/b", "1");
        FAIL("no error");
    } catch (const InputError& e) {
        CHECK(e.file() == "scene.json");
        CHECK(e.where() == "/missing/b");
    }
    CHECK_THROWS_AS(apply("/list/2", "1"), InputError);   // past the end: use "-"
    CHECK_THROWS_AS(apply("/list/01", "1"), InputError);  // not an RFC 6901 index
    CHECK_THROWS_AS(apply("/s/x", "1"), InputError);      // a string has no members
    CHECK_THROWS_AS(apply("", "1"), InputError);          // not the whole document
    CHECK(applyOverrides(text, {}, "scene.json") == text);  // no overrides: the text as is
}

TEST_CASE("a bad manifest is refused with the JSON pointer of the bad value", "[batch]") {
    auto where = [](const std::string& text) {
        try {
            parseManifest(text, "m.json", "/tmp");
        } catch (const InputError& e) {
            CHECK(e.file() == "m.json");
            return e.where();
        }
        return std::string("(accepted)");
    };
    CHECK(where(R"({"jobs": [{"scene": "a.json", "output": "a.exr", "sett": {}}]})") ==
          "/jobs/0/sett");
    CHECK(where(R"({"jobs": [{"output": "a.exr"}]})") == "/jobs/0/scene");
    CHECK(where(R"({"jobs": [{"scene": "a.json", "output": "a.tif"}]})") == "/jobs/0/output");
    CHECK(where(R"({"jobs": [{"scene": "a.json", "output": "a.exr", "method": "nope"}]})") ==
          "/jobs/0/method");
    CHECK(where(R"({"jobs": [{"scene": "a.json", "output": "a.exr", "width": 0}]})") ==
          "/jobs/0/width");
    CHECK(where(R"({"jobs": [{"scene": "a.json", "output": "a.exr"},
                             {"scene": "b.json", "output": "./a.exr"}]})") == "/jobs/1/output");
    CHECK(where(R"({"sweep": {"scene": "a.json", "output": "a.exr", "frames": 3}})") ==
          "/sweep/output");
    CHECK(where(R"({"sweep": [{"scene": "a.json", "output": "a{frame}.exr", "frames": 2,
                               "vary": {"x": {"from": [1, 2], "to": [1]}}}]})") ==
          "/sweep/0/vary/x/to");
    CHECK(where(R"({"sweep": {"scene": "a.json", "output": "a{frame}.exr", "frames": 2,
                              "vary": {"x": {"values": [1]}}}})") == "/sweep/vary/x/values");
    CHECK(where(R"({"jobs": [{"scene": "a.json", "output": "a.exr", "samples": 64}]})") ==
          "/jobs/0/samples");  // aci takes no samples
    CHECK(where(R"({"jobs": []})") == "");
    CHECK(where(R"({"jobs": [{"scene": "a.json", "output": "a.exr", "output": "b.exr"}]})") ==
          "/jobs/0/output");  // a repeated key
}

TEST_CASE("a malformed manifest is reported by line and column in characters", "[batch]") {
    // Line 2 holds "ñandú" (7 bytes, 5 characters) before the missing comma: the offending token
    // "seed" ends at character 50 (byte 52), and the column counts characters, as the scene
    // loader's does.
    const std::string text = "{\"jobs\": [\n"
                             "  {\"scene\": \"\xc3\xb1\x61nd\xc3\xba.json\", \"output\": \"a.exr\" "
                             "\"seed\": 1}]}";
    try {
        parseManifest(text, "m.json", "/tmp");
        FAIL("accepted a malformed manifest");
    } catch (const InputError& e) {
        CHECK(e.file() == "m.json");
        CHECK(e.where() == "");
        CHECK_THAT(e.message(), Catch::StartsWith("malformed JSON at line 2, column 50: "));
        CHECK_THAT(e.message(), !Catch::Contains("json.exception"));
    }
}

// ---------------------------------------------------------------------------------------------
// Running, in process

TEST_CASE("runBatch renders what render() renders, isolates a failing job, and resumes by hash",
          "[batch]") {
    const SceneDir tmp("run");
    const fs::path& dir = tmp.path;
    const std::string manifestText = R"({
      "jobs": [
        {"scene": "a.json", "output": "out/plain.exr", "stats": "out/plain.stats.json"},
        {"scene": "missing.json", "output": "out/missing.exr"},
        {"scene": "a.json", "output": "out/bad.exr", "set": {"lights/0/radiance": [-1, 0, 0]}},
        {"scene": "a.json", "output": "out/moved.png", "set": {"lights/0/corner": [0, 0, 4]}}
      ]})";
    writeFile(dir / "m.json", manifestText);
    BatchManifest m = loadManifest((dir / "m.json").string());
    REQUIRE(m.jobs.size() == 4);
    const std::vector<size_t> all = {0, 1, 2, 3};
    BatchOptions options;
    options.threads = 2;
    std::vector<std::string> done;
    BatchCallbacks callbacks;
    callbacks.jobDone = [&](const BatchJob& job, const JobResult&) { done.push_back(job.name); };
    size_t lastFinished = 0;
    callbacks.progress = [&](const BatchProgressInfo& p) {
        CHECK(p.finished >= lastFinished);  // serialized and monotonic
        lastFinished = p.finished;
        CHECK(p.total == 4);
    };

    std::vector<JobResult> r = runBatch(m, all, options, callbacks);
    REQUIRE(r.size() == 4);
    CHECK(done.size() == 4);
    CHECK(lastFinished == 4);
    CHECK(r[0].status == JobStatus::Rendered);
    CHECK(r[1].status == JobStatus::Failed);
    CHECK(r[1].error.find("missing.json") != std::string::npos);
    CHECK(r[2].status == JobStatus::Failed);
    CHECK(r[2].error.find("/lights/0/radiance") != std::string::npos);
    CHECK(r[3].status == JobStatus::Rendered);
    CHECK_FALSE(fs::exists(dir / "out/missing.exr"));
    CHECK_FALSE(fs::exists(dir / "out/bad.exr"));
    CHECK(fs::exists(dir / "out/plain.stats.json"));
    CHECK(fs::exists(dir / "out/plain.exr.job.json"));
    CHECK(countTemporaries(dir / "out", false) == 0);

    // The batch's picture is the one render() gives for the same scene, bit for bit.
    RenderSettings settings;
    settings.threads = 1;
    const RenderResult ref = render(loadScene((dir / "a.json").string()), settings);
    const Image got = readImage((dir / "out/plain.exr").string());
    REQUIRE(got.width == 24);
    CHECK(got.data == ref.color.data);
    CHECK(r[0].shadowRays == ref.stats.shadowRays);
    CHECK(r[0].shadowRays > 0);
    // The moved light changes the picture (the hash must therefore change too).
    const Image moved = readImage((dir / "out/moved.png").string());
    CHECK(std::abs(meanOf(moved) - meanOf(got)) > 1e-3);

    // Resume: the two good outputs are skipped (with their recorded ray counts), the two
    // failures are tried again and fail again.
    options.resume = true;
    r = runBatch(m, all, options);
    CHECK(r[0].status == JobStatus::Skipped);
    CHECK(r[0].shadowRays == ref.stats.shadowRays);
    CHECK(r[1].status == JobStatus::Failed);
    CHECK(r[2].status == JobStatus::Failed);
    CHECK(r[3].status == JobStatus::Skipped);

    // A changed override renders that job again; so does a lost sidecar (it is the record of
    // the image's size and content hash: without it the image cannot be verified).
    fs::remove(dir / "out/plain.exr.job.json");
    m.jobs[3].overrides = {{"/lights/0/corner", "[0.5,0,4]"}};
    r = runBatch(m, {0, 3}, options);
    REQUIRE(r.size() == 2);
    CHECK(r[0].status == JobStatus::Rendered);
    CHECK(r[1].status == JobStatus::Rendered);
    CHECK(runBatch(m, {0, 3}, options)[0].status == JobStatus::Skipped);
    CHECK(fs::exists(dir / "out/plain.exr.job.json"));
    CHECK(readFile(dir / "out/plain.exr.job.json").find(
              jobHash(m.jobs[0], resolveSceneText(m.jobs[0]))) != std::string::npos);

    // Stale temporaries of a killed run (a dead process of this host) are removed; a live
    // process's and unrelated dot files are left alone.
    std::string host;
    long pid = 0;
    REQUIRE(parseTemporaryName(fs::path(temporaryPathFor("x.exr")).filename().string(), host,
                               pid));
    const std::string dead = "out/.plain.exr.tmp-" + host + "-999999999-0.exr";
    const std::string deadSidecar = "out/.moved.png.job.json.tmp-" + host + "-999999999-3.json";
    const std::string live =
        "out/.moved.png.tmp-" + host + "-" + std::to_string(::getpid()) + "-7.png";
    writeFile(dir / dead, "partial");
    writeFile(dir / deadSidecar, "partial");
    writeFile(dir / live, "being written");
    writeFile(dir / "out/.keep.tmp-1", "someone else's");
    r = runBatch(m, all, options);
    CHECK(!fs::exists(dir / dead));
    CHECK(!fs::exists(dir / deadSidecar));
    CHECK(fs::exists(dir / live));
    CHECK(fs::exists(dir / "out/.keep.tmp-1"));
}

TEST_CASE("aci_mode picks the estimator's variant, is recorded, and re-renders when changed",
          "[batch]") {
    const SceneDir tmp("aci_mode");
    const fs::path& dir = tmp.path;

    // Parsed: "defaults" give it, a job overrides it, and no mode means the default (tangent).
    const BatchManifest m = parseManifest(R"({"defaults": {"aci_mode": "paper"},
        "jobs": [{"scene": "a.json", "output": "p.exr"},
                 {"scene": "a.json", "output": "a.exr", "aci_mode": "arcs"},
                 {"scene": "a.json", "output": "t.exr", "aci_mode": "tangent"}]})",
                                          "m.json", dir.string());
    REQUIRE(m.jobs.size() == 3);
    CHECK(aciModeOf(m.jobs[0].settings.aci) == AciMode::Paper);
    CHECK_FALSE(m.jobs[0].settings.aci.curvedContour);
    CHECK_FALSE(m.jobs[0].settings.aci.distanceGuided);
    CHECK(aciModeOf(m.jobs[1].settings.aci) == AciMode::Arcs);
    CHECK(aciModeOf(m.jobs[2].settings.aci) == AciMode::Tangent);
    const BatchManifest plain =
        parseManifest(R"({"jobs": [{"scene": "a.json", "output": "p.exr"}]})", "m.json",
                      dir.string());
    CHECK(aciModeOf(plain.jobs[0].settings.aci) == AciMode::Tangent);

    // The mode enters the hash: the same scene and output under another mode is another job.
    std::set<std::string> hashes;
    for (const BatchJob& job : m.jobs) hashes.insert(jobHash(job, resolveSceneText(job)));
    CHECK(hashes.size() == 3);
    CHECK(jobHash(plain.jobs[0], resolveSceneText(plain.jobs[0])) ==
          jobHash(m.jobs[2], resolveSceneText(m.jobs[2])));  // "tangent" is the default

    // An unknown or mistyped mode names the manifest and the pointer.
    auto refusal = [](const std::string& text) {
        try {
            parseManifest(text, "m.json", "/tmp");
        } catch (const InputError& e) {
            CHECK(e.file() == "m.json");
            return std::string(e.what());
        }
        return std::string("(accepted)");
    };
    CHECK(refusal(R"({"jobs": [{"scene": "a.json", "output": "a.exr"},
                               {"scene": "a.json", "output": "b.exr", "aci_mode": "x"}]})") ==
          "m.json: /jobs/1/aci_mode: unknown ACI mode 'x' (expected paper, arcs or tangent)");
    CHECK_THAT(refusal(R"({"defaults": {"aci_mode": "Paper"},
                           "jobs": [{"scene": "a.json", "output": "a.exr"}]})"),
               Catch::StartsWith("m.json: /defaults/aci_mode: unknown ACI mode 'Paper'"));
    CHECK_THAT(refusal(R"({"sweep": {"scene": "a.json", "output": "a{frame}.exr", "frames": 2,
                                     "aci_mode": 1}})"),
               Catch::StartsWith("m.json: /sweep/aci_mode: must be a non-empty string"));

    // Run: the mode is in the statistics, the image's metadata and the sidecar; changing it
    // renders the job again under --resume, keeping it does not.
    writeFile(dir / "m.json", R"({"jobs": [{"scene": "a.json", "output": "out/a.exr",
                                            "stats": "out/a.stats.json", "aci_mode": "paper"}]})");
    BatchManifest run = loadManifest((dir / "m.json").string());
    BatchOptions options;
    options.threads = 2;
    std::vector<JobResult> r = runBatch(run, {0}, options);
    REQUIRE(r[0].status == JobStatus::Rendered);
    CHECK(readImageAttribute((dir / "out/a.exr").string(), "penumbra:aci_mode") == "paper");
    CHECK(readFile(dir / "out/a.exr.job.json").find("\"aci_mode\": \"paper\"") !=
          std::string::npos);
    CHECK(readFile(dir / "out/a.stats.json").find("\"aci_mode\": \"paper\"") !=
          std::string::npos);
    options.resume = true;
    r = runBatch(run, {0}, options);
    CHECK(r[0].status == JobStatus::Skipped);
    writeFile(dir / "m.json", R"({"jobs": [{"scene": "a.json", "output": "out/a.exr",
                                            "stats": "out/a.stats.json", "aci_mode": "arcs"}]})");
    run = loadManifest((dir / "m.json").string());
    r = runBatch(run, {0}, options);
    CHECK(r[0].status == JobStatus::Rendered);
    CHECK(readImageAttribute((dir / "out/a.exr").string(), "penumbra:aci_mode") == "arcs");
}

// ---------------------------------------------------------------------------------------------
// The program, as users and clusters run it

TEST_CASE("penumbra batch finishes the other jobs when one fails and names it, exit code 1",
          "[batch][cli]") {
    const SceneDir tmp("cli_fail");
    const fs::path& dir = tmp.path;
    writeFile(dir / "m.json", R"({
      "jobs": [{"scene": "a.json", "output": "out/bad.exr", "name": "broken-light",
                "set": {"lights/0/edge_v": [0, 4, 0]}}],
      "sweep": {"scene": "a.json", "output": "out/f{frame}.exr", "frames": 4,
                "vary": {"lights/0/corner": {"from": [-1, -1, 4], "to": [-0.5, -1, 4]}}}
    })");
    const int code = runPenumbra({"batch", (dir / "m.json").string(), "--jobs", "2", "--summary",
                                  (dir / "summary.csv").string(), "--quiet"},
                                 dir, "run");
    const std::string err = readFile(dir / "run.err");
    INFO(err);
    CHECK(code == 1);
    CHECK(err.find("broken-light") != std::string::npos);
    CHECK(err.find("/lights/0") != std::string::npos);  // the scene loader's pointer
    CHECK(readFile(dir / "run.out").empty());           // --quiet
    const std::vector<SummaryRow> rows = readSummaryCsv(dir / "summary.csv");
    REQUIRE(rows.size() == 5);
    CHECK(rows[0].name == "broken-light");
    CHECK(rows[0].status == "failed");
    CHECK(rows[0].error.find("/lights/0") != std::string::npos);
    for (int k = 0; k < 4; ++k) {
        const SummaryRow& row = rows[size_t(1 + k)];
        CHECK(row.status == "rendered");
        CHECK(row.error.empty());
        CHECK(row.shadowRays > 0);
        const Image img = readImage((dir / ("out/f" + std::to_string(k) + ".exr")).string());
        CHECK(img.width == 24);
        CHECK(meanOf(img) > 0.0);
    }
    CHECK_FALSE(fs::exists(dir / "out/bad.exr"));

    // Bad options and manifests stop before any job, with exit code 2.
    CHECK(runPenumbra({"batch", (dir / "m.json").string(), "--shard", "3/3"}, dir, "bad") == 2);
    CHECK(runPenumbra({"batch", (dir / "nope.json").string()}, dir, "bad") == 2);
    CHECK(runPenumbra({"batch", (dir / "m.json").string(), "--summary", "s.txt"}, dir, "bad") == 2);
    CHECK(runPenumbra({"batch", (dir / "m.json").string(), "--shard-count", "2"}, dir, "bad") == 2);
    CHECK(readFile(dir / "bad.err").find("--shard-count") != std::string::npos);
}

TEST_CASE("a batch killed with SIGKILL and resumed renders every job exactly once",
          "[batch][cli]") {
    // Per-pixel ACI on a level-set sphere makes each frame take long enough to be interrupted.
    const test::SlowSweepDir tmp("kill", "batch", 64, 12);
    const fs::path& dir = tmp.path;
    const int frames = tmp.frames;
    auto outputs = [&] {
        std::vector<std::string> names;
        if (!fs::exists(dir / "out")) return names;
        for (const auto& e : fs::directory_iterator(dir / "out")) {
            const std::string n = e.path().filename().string();
            if (n.size() > 4 && n.compare(n.size() - 4, 4, ".exr") == 0 && n[0] != '.') {
                names.push_back(n);
            }
        }
        return names;
    };

    const pid_t pid =
        spawnPenumbra({"batch", (dir / "m.json").string(), "--jobs", "2"}, dir, "first");
    test::waitUntil([&] { return !outputs().empty(); }, std::chrono::milliseconds(2));
    REQUIRE(kill(pid, SIGKILL) == 0);
    int status = 0;
    REQUIRE(waitpid(pid, &status, 0) == pid);
    REQUIRE(WIFSIGNALED(status));
    const std::vector<std::string> before = outputs();
    INFO("outputs when killed: " << before.size());
    REQUIRE(!before.empty());
    REQUIRE(int(before.size()) < frames);  // killed in the middle
    // No truncated image: everything under the final names reads back.
    for (const std::string& n : before) {
        const Image img = readImage((dir / "out" / n).string());
        CHECK(img.width == 64);
    }

    const int code = runPenumbra({"batch", (dir / "m.json").string(), "--jobs", "2", "--resume",
                                  "--summary", (dir / "resume.csv").string()},
                                 dir, "second");
    INFO(readFile(dir / "second.err"));
    REQUIRE(code == 0);
    const std::vector<SummaryRow> rows = readSummaryCsv(dir / "resume.csv");
    REQUIRE(int(rows.size()) == frames);
    std::map<std::string, int> n = countStatuses(rows);
    // Every output present when the first run died is kept; the rest are rendered once.
    CHECK(n["skipped"] == int(before.size()));
    CHECK(n["rendered"] == frames - int(before.size()));
    CHECK(n["failed"] == 0);
    for (const SummaryRow& row : rows) {
        const std::string file = fs::path(row.output).filename().string();
        const bool existed = std::find(before.begin(), before.end(), file) != before.end();
        CHECK(row.status == (existed ? "skipped" : "rendered"));
    }
    const std::vector<std::string> after = outputs();
    CHECK(int(after.size()) == frames);
    for (const std::string& name : after) {
        const Image img = readImage((dir / "out" / name).string());
        CHECK(img.width == 64);
        CHECK(meanOf(img) > 0.0);
        CHECK(fs::exists(dir / "out" / (name + ".job.json")));
    }
    CHECK(countTemporaries(dir / "out", false) == 0);

    // A third run has nothing left to do.
    REQUIRE(runPenumbra({"batch", (dir / "m.json").string(), "--resume", "--summary",
                         (dir / "third.csv").string()},
                        dir, "third") == 0);
    CHECK(countStatuses(readSummaryCsv(dir / "third.csv"))["skipped"] == frames);
}

TEST_CASE("three shards run as separate processes render the whole batch once", "[batch][cli]") {
    const SceneDir tmp("shards");
    const fs::path& dir = tmp.path;
    const int frames = 10;
    writeFile(dir / "m.json", R"({"sweep": {"scene": "a.json", "output": "out/s{frame:02d}.png",
      "frames": 10, "vary": {"lights/0/corner": {"from": [-1.5, -1, 4], "to": [0.5, -1, 4]}}}})");
    const std::string manifest = (dir / "m.json").string();
    auto summary = [&](int i) { return (dir / ("shard" + std::to_string(i) + ".csv")).string(); };
    // The three ways a shard is chosen: the flag, a Slurm array task (IDs from 1 here), and a
    // Kubernetes Indexed Job completion index with the count from the environment.
    const pid_t p0 = spawnPenumbra({"batch", manifest, "--shard", "0/3", "--jobs", "1",
                                    "--summary", summary(0)},
                                   dir, "s0");
    const pid_t p1 = spawnPenumbra({"batch", manifest, "--jobs", "1", "--summary", summary(1)},
                                   dir, "s1",
                                   {"SLURM_ARRAY_TASK_ID=2", "SLURM_ARRAY_TASK_MIN=1",
                                    "SLURM_ARRAY_TASK_COUNT=3"});
    const pid_t p2 = spawnPenumbra({"batch", manifest, "--jobs", "1", "--summary", summary(2)},
                                   dir, "s2",
                                   {"JOB_COMPLETION_INDEX=2", "PENUMBRA_SHARD_COUNT=3"});
    CHECK(waitExit(p0) == 0);
    CHECK(waitExit(p1) == 0);
    CHECK(waitExit(p2) == 0);

    std::set<size_t> seen;
    for (int i = 0; i < 3; ++i) {
        INFO("shard " << i << ": " << readFile(dir / ("s" + std::to_string(i) + ".err")));
        const std::vector<SummaryRow> rows = readSummaryCsv(summary(i));
        CHECK(rows.size() == size_t(frames / 3 + (i < frames % 3 ? 1 : 0)));
        for (const SummaryRow& row : rows) {
            CHECK(row.index % 3 == size_t(i));
            CHECK(row.status == "rendered");
            CHECK(seen.insert(row.index).second);  // no job in two shards
        }
    }
    CHECK(seen.size() == size_t(frames));
    int images = 0;
    for (const auto& e : fs::directory_iterator(dir / "out")) {
        const std::string n = e.path().filename().string();
        if (n.size() > 4 && n.compare(n.size() - 4, 4, ".png") == 0 && n[0] != '.') {
            const Image img = readImage(e.path().string());
            CHECK(img.width == 24);
            ++images;
        }
    }
    CHECK(images == frames);

    // --list shows a shard's jobs without running them.
    REQUIRE(runPenumbra({"batch", manifest, "--shard", "1/4", "--list"}, dir, "list") == 0);
    const std::string listed = readFile(dir / "list.out");
    CHECK(std::count(listed.begin(), listed.end(), '\n') == 3);  // jobs 1, 5, 9
    CHECK(listed.find("out/s05.png") != std::string::npos);
}

TEST_CASE("batch: jobs of one scene build its level sets once", "[batch]") {
    const TempDir tmp("shared_level_sets");
    const fs::path& dir = tmp.path;
    // A level-set torus and a mesh-free CSG: built for the first frame, shared by the others.
    writeFile(dir / "a.json", R"({
      "camera": {"eye": [0, -6, 3], "look_at": [0, 0, 0.5], "width": 12, "height": 12},
      "lights": [{"corner": [-1, -1, 4], "edge_u": [0, 2, 0], "edge_v": [2, 0, 0]}],
      "obstacles": [{"type": "torus", "center": [0, 0, 1], "major_radius": 0.5,
                     "minor_radius": 0.15},
                    {"type": "sphere", "center": [0.8, 0, 0.6], "radius": 0.2, "analytic": true}],
      "receivers": [{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]}],
      "level_set": {"voxel_size": 0.04}
    })");
    writeFile(dir / "m.json", R"({"sweep": {"scene": "a.json", "output": "out/f_{frame}.exr",
      "frames": 4, "vary": {"lights/0/corner": {"from": [-1.5, -1, 4], "to": [0.5, -1, 4]}}}})");
    BatchOptions options;
    options.threads = 1;  // one job after another: later frames find the first one's level sets
    const BatchManifest m = loadManifest((dir / "m.json").string());
    const std::vector<JobResult> results = runBatch(m, {0, 1, 2, 3}, options);
    REQUIRE(results.size() == 4);
    int built = 0, shared = 0;
    for (const JobResult& r : results) {
        CHECK(r.status == JobStatus::Rendered);
        built += r.levelSetsBuilt;
        shared += r.levelSetsShared;
    }
    CHECK(built == 1);   // the torus, once (the analytic sphere needs none)
    CHECK(shared == 3);  // and taken by the three later frames

    // A load without the batch's cache builds its own.
    const Scene alone = loadScene((dir / "a.json").string());
    CHECK(alone.build.levelSetsBuilt == 1);
    CHECK(alone.build.levelSetsShared == 0);
}

TEST_CASE("scene loads share level sets only for the same obstacle and files", "[batch][scene]") {
    const TempDir tmp("cache_keys");
    const fs::path& dir = tmp.path;
    const std::string body = R"("lights": [{"corner": [-1, -1, 4], "edge_u": [0, 2, 0], "edge_v": [2, 0, 0]}],
      "receivers": [{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]}])";
    auto scene = [&](const std::string& obstacle, double voxel) {
        return "{" + body + R"(, "obstacles": [)" + obstacle +
               R"(], "level_set": {"voxel_size": )" + std::to_string(voxel) + "}}";
    };
    const std::string sphere = R"({"type": "sphere", "center": [0, 0, 1], "radius": 0.4})";
    LevelSetCache cache;
    const Scene a = parseScene(scene(sphere, 0.05), "a.json", dir.string(), &cache);
    const Scene b = parseScene(scene(sphere, 0.05), "a.json", dir.string(), &cache);
    CHECK(a.build.levelSetsBuilt == 1);
    CHECK(b.build.levelSetsShared == 1);
    CHECK(std::get<LevelSetPtr>(a.obstacles[0].shape) == std::get<LevelSetPtr>(b.obstacles[0].shape));
    // Another voxel size, another radius: built anew.
    CHECK(parseScene(scene(sphere, 0.04), "a.json", dir.string(), &cache).build.levelSetsBuilt == 1);
    const std::string bigger = R"({"type": "sphere", "center": [0, 0, 1], "radius": 0.5})";
    CHECK(parseScene(scene(bigger, 0.05), "a.json", dir.string(), &cache).build.levelSetsBuilt == 1);
    // A mesh file whose content changed between loads: built anew.
    writeFile(dir / "t.obj", "v 0 0 1\nv 1 0 1\nv 0 1 1\nv 0 0 2\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n");
    const std::string mesh = R"({"type": "mesh", "file": "t.obj"})";
    CHECK(parseScene(scene(mesh, 0.05), "a.json", dir.string(), &cache).build.levelSetsBuilt == 1);
    CHECK(parseScene(scene(mesh, 0.05), "a.json", dir.string(), &cache).build.levelSetsShared == 1);
    writeFile(dir / "t.obj", "v 0 0 1\nv 1.5 0 1\nv 0 1 1\nv 0 0 2\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n");
    CHECK(parseScene(scene(mesh, 0.05), "a.json", dir.string(), &cache).build.levelSetsBuilt == 1);
}
