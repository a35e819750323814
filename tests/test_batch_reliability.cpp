// Reliability of `penumbra batch` (issue 15): outputs that would overwrite an input or each
// other are refused before any job runs, by real location (docs/errors.md, rows B01-B05);
// temporaries are unique per write; two runs of one manifest coordinate through a lock file
// (B06); resume verifies an output's size and content hash, not only its header (B07).
// Renders are tiny (24 x 24 analytic scenes) except where a run must last long enough for a
// second one to meet it.
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

const char* const kScene = test::kSphereScene;

// The same view over a mesh obstacle read from `cube.obj`: a scene that reads another file.
const char* kMeshScene = R"({
  "camera": {"eye": [0, -6, 3], "look_at": [0, 0, 0.5], "width": 24, "height": 24},
  "lights": [{"corner": [-1, -1, 4], "edge_u": [0, 2, 0], "edge_v": [2, 0, 0],
              "radiance": [4, 4, 4]}],
  "obstacles": [{"type": "mesh", "file": "cube.obj"}],
  "receivers": [{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]}],
  "level_set": {"voxel_size": 0.05}
})";

const char* kCube = R"(v -0.4 -0.4 0.8
v 0.4 -0.4 0.8
v 0.4 0.4 0.8
v -0.4 0.4 0.8
v -0.4 -0.4 1.6
v 0.4 -0.4 1.6
v 0.4 0.4 1.6
v -0.4 0.4 1.6
f 1 4 3 2
f 5 6 7 8
f 1 2 6 5
f 2 3 7 6
f 3 4 8 7
f 4 1 5 8
)";

using test::readFile;
using test::spawnPenumbra;
using test::waitExit;
using test::writeFile;

struct TempDir : test::TempDir {
    explicit TempDir(const std::string& name) : test::TempDir(name, "batchrel") {}
};

struct SceneDir : test::SceneDir {
    explicit SceneDir(const std::string& name) : test::SceneDir(name, "batchrel") {}
};

int runPenumbra(const std::vector<std::string>& args, const fs::path& dir,
                const std::string& tag) {
    return test::runPenumbraSpawned(args, dir, tag);
}

int countTemporaries(const fs::path& dir) { return test::countTemporaries(dir, true); }

// The refusal of a manifest (loadManifest, then the checks runBatch makes first), as
// "WHERE|MESSAGE", or "(accepted)". `summary` is checked as --summary.
std::string refusal(const fs::path& manifest, const std::string& summary = "") {
    try {
        const BatchManifest m = loadManifest(manifest.string());
        checkBatchFiles(m, summary);
    } catch (const InputError& e) {
        if (e.where() != "--summary") CHECK(e.file() == manifest.string());
        CHECK(std::string(e.what()).find('\n') == std::string::npos);
        return e.where() + "|" + e.message();
    }
    return "(accepted)";
}

bool contains(const std::string& s, const std::string& part) {
    return s.find(part) != std::string::npos;
}

}  // namespace

TEST_CASE("B01-B05: batch outputs that clash with each other or an input are refused by real "
          "location, before any job runs",
          "[batch]") {
    const SceneDir tmp("clash");
    const fs::path& dir = tmp.path;
    writeFile(dir / "b.json", kScene);
    writeFile(dir / "mesh.json", kMeshScene);
    writeFile(dir / "cube.obj", kCube);
    fs::create_directory_symlink(".", dir / "link");
    const fs::path m = dir / "m.json";
    auto manifest = [&](const std::string& text) {
        writeFile(m, text);
        return m;
    };

    // The manifest `text` (with `summary` as --summary) is refused with a message that starts
    // with `start` and contains `part` (when one is given).
    auto expectRefusal = [&](const std::string& text, const std::string& start,
                             const std::string& part, const std::string& summary = "") {
        const std::string r = refusal(manifest(text), summary);
        CHECK_THAT(r, Catch::StartsWith(start));
        if (!part.empty()) CHECK(contains(r, part));
    };

    // B01: two jobs writing one file, however it is spelt: through a symlink to the directory,
    // as an absolute path, with `..`; a sweep whose frames share a `stats` file.
    expectRefusal(R"({"jobs": [
        {"scene": "a.json", "output": "a.exr"},
        {"scene": "a.json", "output": "link/a.exr"}]})",
                  "/jobs/1/output|'" + (dir / "link/a.exr").string() +
                      "' is also written by /jobs/0/output",
                  "every output needs its own file");
    expectRefusal(R"({"jobs": [
        {"scene": "a.json", "output": "out/a.exr"},
        {"scene": "a.json", "output": ")" + (dir / "out/a.exr").string() + R"("}]})",
                  "/jobs/1/output|", "");
    expectRefusal(R"({"jobs": [
        {"scene": "a.json", "output": "out/x.exr"},
        {"scene": "a.json", "output": "y.exr", "stats": "link/out/../out/x.exr"}]})",
                  "/jobs/1/stats|", "");
    expectRefusal(R"({"jobs": [
        {"scene": "a.json", "output": "a.exr", "stats": "b.exr"},
        {"scene": "a.json", "output": "b.exr"}]})",
                  "/jobs/1/output|", "is also written by /jobs/0/stats");
    expectRefusal(R"({"jobs": [
        {"scene": "a.json", "output": "a.exr"},
        {"scene": "a.json", "output": "b.exr", "stats": "a.exr.job.json"}]})",
                  "/jobs/1/stats|", "sidecar record of");
    expectRefusal(R"({"sweep": {"scene": "a.json", "output": "f{frame}.exr",
                                "stats": "shared.json", "frames": 3}})",
                  "/sweep/stats|frame 1: '", "is also written by /sweep/stats, frame 0");

    // B02: a job's output or statistics that is the manifest.
    CHECK(refusal(manifest(R"({"jobs": [{"scene": "a.json", "output": "a.exr",
                                         "stats": "m.json"}]})")) ==
          "/jobs/0/stats|'" + (dir / "m.json").string() +
              "' is the batch manifest, which this batch reads: refusing to overwrite an input");
    expectRefusal(R"({"jobs": [{"scene": "a.json", "output": "a.exr", "stats": ".m.json.lock"}]})",
                  "/jobs/0/stats|", "is the batch manifest's lock file");

    // B03: a scene file that any job reads, also a later job's, also through a hard link.
    expectRefusal(R"({"jobs": [{"scene": "a.json", "output": "a.exr", "stats": "b.json"},
                               {"scene": "b.json", "output": "b.exr"}]})",
                  "/jobs/0/stats|", "is the scene of /jobs/1, which this batch reads");
    fs::create_hard_link(dir / "a.json", dir / "hard.json");
    expectRefusal(R"({"jobs": [{"scene": "a.json", "output": "a.exr", "stats": "hard.json"}]})",
                  "/jobs/0/stats|", "is the scene of /jobs/0");

    // B04: a file a scene reads (a mesh, a .vdb), named by the scene or by a job's overrides.
    expectRefusal(R"({"jobs": [{"scene": "a.json", "output": "a.exr", "stats": "cube.obj"},
                               {"scene": "mesh.json", "output": "m.exr"}]})",
                  "/jobs/0/stats|", "is /obstacles/0/file of " + (dir / "mesh.json").string());
    expectRefusal(R"({"jobs": [
        {"scene": "a.json", "output": "a.exr", "stats": "other.obj"},
        {"scene": "mesh.json", "output": "m.exr", "set": {"obstacles/0/file": "other.obj"}}]})",
                  "/jobs/0/stats|", "/obstacles/0/file of");

    // B05: a summary that is the manifest, or any file a job writes (here through the symlink).
    const std::string good = R"({"jobs": [{"scene": "a.json", "output": "out/a.exr",
                                           "stats": "out/a.stats.json"}]})";
    CHECK(refusal(manifest(good)) == "(accepted)");
    expectRefusal(good, "--summary|", "is the batch manifest", m.string());
    expectRefusal(good, "--summary|", "is also written by /jobs/0/stats",
                  (dir / "link/out/a.stats.json").string());
    CHECK(refusal(manifest(good), (dir / "summary.csv").string()) == "(accepted)");

    // runBatch makes the same checks before any job runs: nothing is written.
    manifest(R"({"jobs": [{"scene": "a.json", "output": "out/first.exr"},
                          {"scene": "b.json", "output": "out/b.exr", "stats": "a.json"}]})");
    const std::string sceneBefore = readFile(dir / "a.json");
    const BatchManifest loaded = loadManifest(m.string());
    BatchOptions options;
    options.threads = 1;
    CHECK_THROWS_AS(runBatch(loaded, {0, 1}, options), InputError);
    CHECK_FALSE(fs::exists(dir / "out"));
    CHECK(readFile(dir / "a.json") == sceneBefore);

    // The program: one line, exit 2, the manifest and the scene left as they were, no output.
    const std::string manifestText =
        R"({"jobs": [{"scene": "a.json", "output": "out/a.exr", "stats": "m.json"}]})";
    manifest(manifestText);
    CHECK(runPenumbra({"batch", m.string()}, dir, "stats_manifest") == 2);
    std::string err = readFile(dir / "stats_manifest.err");
    CHECK(err == "penumbra: error: " + m.string() + ": /jobs/0/stats: '" + m.string() +
                     "' is the batch manifest, which this batch reads: refusing to overwrite "
                     "an input\n");
    CHECK(readFile(m) == manifestText);
    manifest(good);
    CHECK(runPenumbra({"batch", m.string(), "--summary", m.string()}, dir, "summary_manifest") ==
          2);
    err = readFile(dir / "summary_manifest.err");
    CHECK_THAT(err, Catch::StartsWith("penumbra: error: --summary: '" + m.string() +
                                      "' is the batch manifest"));
    CHECK(std::count(err.begin(), err.end(), '\n') == 1);
    CHECK(readFile(m) == good);
    CHECK_FALSE(fs::exists(dir / "out"));
}

TEST_CASE("B08: batch temporaries are unique per write and a live run's are never removed",
          "[batch]") {
    // Within one manifest a shared `stats` is refused (B01); across manifests run at once in
    // one process (the case where a name made of the process id alone collided), every job
    // writes its own temporary and the last rename wins.
    const SceneDir tmp("shared_stats");
    const fs::path& dir = tmp.path;
    const std::string shared = (dir / "shared.stats.json").string();
    const int runs = 6;
    std::vector<BatchManifest> manifests;
    for (int i = 0; i < runs; ++i) {
        const fs::path sub = dir / ("m" + std::to_string(i));
        fs::create_directories(sub);
        writeFile(sub / "m.json", R"({"jobs": [
            {"scene": "../a.json", "output": "f0.png", "stats": ")" + shared + R"("},
            {"scene": "../a.json", "output": "f1.png", "stats": "f1.stats.json"},
            {"scene": "../a.json", "output": "f2.png", "stats": "f2.stats.json"}]})");
        manifests.push_back(loadManifest((sub / "m.json").string()));
    }
    std::vector<std::vector<JobResult>> results(runs);
    for (int round = 0; round < 2; ++round) {
        std::vector<std::thread> threads;
        for (int i = 0; i < runs; ++i) {
            threads.emplace_back([&, i] {
                BatchOptions options;
                options.threads = 1;
                results[size_t(i)] = runBatch(manifests[size_t(i)], {0, 1, 2}, options);
            });
        }
        for (std::thread& t : threads) t.join();
        for (int i = 0; i < runs; ++i) {
            for (const JobResult& r : results[size_t(i)]) {
                INFO("run " << i << " job " << r.job << ": " << r.error);
                CHECK(r.status == JobStatus::Rendered);
            }
        }
    }
    CHECK(readFile(shared).find("\"shadow_rays\"") != std::string::npos);
    CHECK(countTemporaries(dir) == 0);
    // Every temporary name of a batch comes from temporaryPathFor: unique per call.
    CHECK(temporaryPathFor(shared) != temporaryPathFor(shared));

    // A run (here --resume) removes the temporaries of dead processes of this host in the
    // directories it writes to, and leaves a live process's (this one's, standing for a run
    // still writing) and another host's alone.
    std::string host;
    long pid = 0;
    REQUIRE(parseTemporaryName(fs::path(temporaryPathFor(shared)).filename().string(), host, pid));
    const fs::path sub = dir / "m0";
    const fs::path dead = sub / (".f0.png.tmp-" + host + "-999999999-0.png");
    const fs::path live = sub / (".f1.png.tmp-" + host + "-" + std::to_string(::getpid()) + "-0.png");
    const fs::path elsewhere = sub / ".f2.png.tmp-elsewhere-999999999-0.png";
    for (const fs::path& p : {dead, live, elsewhere}) writeFile(p, "partial");
    BatchOptions options;
    options.threads = 1;
    options.resume = true;
    for (const JobResult& r : runBatch(manifests[0], {0, 1, 2}, options)) {
        CHECK(r.status == JobStatus::Skipped);
    }
    CHECK_FALSE(fs::exists(dead));
    CHECK(fs::exists(live));
    CHECK(fs::exists(elsewhere));
}

TEST_CASE("B06: lock files let the shards of one count run together and refuse a second run",
          "[batch]") {
    const TempDir tmp("lock_api");
    const fs::path& dir = tmp.path;
    const std::string m = (dir / "m.json").string();
    writeFile(m, "{}");
    auto refused = [&](const Shard& s) {
        try {
            BatchLock lock = lockBatchManifest(m, s);
            CHECK(lock.held());
        } catch (const InputError& e) {
            CHECK(e.file() == m);
            CHECK(contains(e.message(), "refusing to run it twice at once"));
            return true;
        }
        return false;
    };
    {
        std::string warning;
        BatchLock whole = lockBatchManifest(m, Shard{0, 1}, &warning);
        CHECK(warning.empty());
        REQUIRE(whole.held());
        CHECK(whole.path() == (dir / ".m.json.lock").string());
        CHECK(readFile(whole.path()) == std::to_string(::getpid()) + " " +
                                            readFile("/proc/sys/kernel/hostname"));
        CHECK(refused(Shard{0, 1}));
        CHECK(refused(Shard{1, 3}));
        try {
            lockBatchManifest(m, Shard{0, 1});
        } catch (const InputError& e) {
            CHECK(contains(e.message(), "process " + std::to_string(::getpid())));
        }
    }
    {
        BatchLock s0 = lockBatchManifest(m, Shard{0, 2});
        BatchLock s1 = lockBatchManifest(m, Shard{1, 2});  // another shard: runs alongside
        CHECK(s0.held());
        CHECK(s1.held());
        CHECK(fs::exists(dir / ".m.json.shard-0-of-2.lock"));
        CHECK(refused(Shard{0, 2}));
        CHECK(refused(Shard{0, 1}));
    }
    // Released: the shards' lock files are gone, and the whole batch may run again.
    CHECK_FALSE(fs::exists(dir / ".m.json.shard-0-of-2.lock"));
    CHECK_FALSE(refused(Shard{0, 1}));
}

TEST_CASE("B06: a second penumbra batch of a manifest being run refuses; the first finishes "
          "every job once",
          "[batch][cli]") {
    // A level-set sphere with per-pixel ACI: about a quarter of a second per frame on one
    // thread (the level set is built once and shared by the frames), 24 frames: the first run
    // is still going for seconds after its first output, when the second starts.
    const test::SlowSweepDir tmp("lock_cli", "batchrel", 48, 24);
    const fs::path& dir = tmp.path;
    const int frames = tmp.frames;
    const std::string m = (dir / "m.json").string();

    const pid_t first = spawnPenumbra(
        {"batch", m, "--jobs", "1", "--resume", "--summary", (dir / "first.csv").string()}, dir,
        "first");
    // The lock is taken before the first job; wait for the first output to appear.
    test::waitUntil([&] { return fs::exists(dir / "out/k_00.exr"); },
                    std::chrono::milliseconds(5));
    REQUIRE(fs::exists(dir / "out/k_00.exr"));
    // A second run of the whole batch, and one of a shard, while the first holds the lock.
    const pid_t second = spawnPenumbra({"batch", m, "--jobs", "1", "--resume", "--summary",
                                        (dir / "second.csv").string()},
                                       dir, "second");
    const pid_t shard = spawnPenumbra({"batch", m, "--jobs", "1", "--resume", "--shard", "1/2"},
                                      dir, "shard");
    const int secondCode = waitExit(second);
    const int shardCode = waitExit(shard);
    int status = 0;
    const bool firstStillRunning = waitpid(first, &status, WNOHANG) == 0;
    INFO("the first run must outlast the second for this test to mean anything");
    CHECK(firstStillRunning);
    const int firstCode = firstStillRunning ? waitExit(first)
                                            : (WIFEXITED(status) ? WEXITSTATUS(status) : -1);

    const std::string err = readFile(dir / "second.err");
    INFO(err);
    CHECK(secondCode == 2);
    CHECK(std::count(err.begin(), err.end(), '\n') == 1);
    CHECK_THAT(err, Catch::StartsWith("penumbra: error: " + m +
                                      ": already being run by another penumbra batch (process " +
                                      std::to_string(first) + " on "));
    CHECK(contains(err, ".m.json.lock"));
    CHECK_FALSE(fs::exists(dir / "second.csv"));
    CHECK(shardCode == 2);
    CHECK(contains(readFile(dir / "shard.err"), "process " + std::to_string(first)));

    INFO(readFile(dir / "first.err"));
    REQUIRE(firstCode == 0);
    const std::string summary = readFile(dir / "first.csv");
    int rendered = 0;
    for (size_t at = 0; (at = summary.find(",rendered,", at)) != std::string::npos; ++at) {
        ++rendered;
    }
    CHECK(rendered == frames);
    for (int k = 0; k < frames; ++k) {
        char name[32];
        std::snprintf(name, sizeof name, "out/k_%02d.exr", k);
        CHECK(readImage((dir / name).string()).width == 48);
    }
    CHECK(countTemporaries(dir) == 0);

    // Afterwards the lock is free: a third run skips everything.
    CHECK(runPenumbra({"batch", m, "--resume", "--quiet"}, dir, "third") == 0);
}

TEST_CASE("B07: resume checks an output's size and content hash: a truncated or altered image "
          "is rendered again",
          "[batch]") {
    const SceneDir tmp("verify");
    const fs::path& dir = tmp.path;
    writeFile(dir / "m.json", R"({"jobs": [
        {"scene": "a.json", "output": "out/truncated.exr"},
        {"scene": "a.json", "output": "out/flipped.exr"},
        {"scene": "a.json", "output": "out/flipped.png"},
        {"scene": "a.json", "output": "out/intact.exr"}]})");
    const BatchManifest m = loadManifest((dir / "m.json").string());
    BatchOptions options;
    options.threads = 2;
    std::vector<JobResult> r = runBatch(m, {0, 1, 2, 3}, options);
    for (const JobResult& res : r) REQUIRE(res.status == JobStatus::Rendered);
    const Image reference = readImage((dir / "out/intact.exr").string());
    const Image referencePng = readImage((dir / "out/flipped.png").string());

    // The sidecar records the file's size and content hash.
    for (const char* name : {"truncated.exr", "flipped.exr", "flipped.png", "intact.exr"}) {
        const fs::path out = dir / "out" / name;
        const FileDigest d = digestFile(out.string());
        CHECK(d.bytes == fs::file_size(out));
        const std::string record = readFile(out.string() + ".job.json");
        CHECK(contains(record, "\"output_bytes\": " + std::to_string(d.bytes)));
        CHECK(contains(record, "\"output_hash\": \"" + d.hash + "\""));
    }

    // Truncated to 60%; pixel bytes flipped at the end of the files, headers intact (the
    // header's job hash still reads back: a header check alone would skip them).
    const fs::path truncated = dir / "out/truncated.exr";
    fs::resize_file(truncated, fs::file_size(truncated) * 6 / 10);
    for (const char* name : {"flipped.exr", "flipped.png"}) {
        const fs::path p = dir / "out" / name;
        const std::string hashBefore = readImageAttribute(p.string(), "penumbra:job_hash");
        std::string bytes = readFile(p);
        const size_t from = bytes.size() - bytes.size() / 4;
        for (size_t i = from; i < from + 16; ++i) bytes[i] = char(bytes[i] ^ 0x5a);
        writeFile(p, bytes);
        CHECK(readImageAttribute(p.string(), "penumbra:job_hash") == hashBefore);
    }
    const std::string truncatedHeader =
        readImageAttribute(truncated.string(), "penumbra:job_hash");
    CHECK_FALSE(truncatedHeader.empty());

    options.resume = true;
    r = runBatch(m, {0, 1, 2, 3}, options);
    CHECK(r[0].status == JobStatus::Rendered);
    CHECK(r[1].status == JobStatus::Rendered);
    CHECK(r[2].status == JobStatus::Rendered);
    CHECK(r[3].status == JobStatus::Skipped);
    // Rendered again, whole and right.
    CHECK(readImage(truncated.string()).data == reference.data);
    CHECK(readImage((dir / "out/flipped.exr").string()).data == reference.data);
    CHECK(readImage((dir / "out/flipped.png").string()).data == referencePng.data);
    // And now verified: a further resume skips all four.
    r = runBatch(m, {0, 1, 2, 3}, options);
    for (const JobResult& res : r) CHECK(res.status == JobStatus::Skipped);

    // A sidecar that records another size (or none: an older version's) renders again too.
    const fs::path sidecar = dir / "out/intact.exr.job.json";
    std::string record = readFile(sidecar);
    const size_t at = record.find("\"output_bytes\": ");
    REQUIRE(at != std::string::npos);
    record.insert(at + 16, "1");
    writeFile(sidecar, record);
    r = runBatch(m, {3}, options);
    CHECK(r[0].status == JobStatus::Rendered);
    CHECK(runBatch(m, {3}, options)[0].status == JobStatus::Skipped);
    fs::remove(sidecar);  // no record: the image cannot be verified
    CHECK(runBatch(m, {3}, options)[0].status == JobStatus::Rendered);
    CHECK(fs::exists(sidecar));
    CHECK(runBatch(m, {3}, options)[0].status == JobStatus::Skipped);
}
