// Benchmark of `penumbra batch`: a sweep of small jobs (a light moving over the default scene's
// level-set sphere and cube) run as one batch on N threads against the same jobs one after
// another. Prints its figures; never fails on a time.
//
//   bench_batch [--jobs J] [--size S] [--threads N] [--voxel V] [--penumbra PATH] [--keep DIR]
//
// Defaults: 16 jobs of 96 x 96 pixels, 2 threads, level sets of voxel 0.02. Rows measured:
//   1. one after another, 1 thread each        (runBatch on one job at a time, arena of 1)
//   2. one after another, N threads each       (runBatch on one job at a time, arena of N)
//   3. one batch, N threads                    (runBatch on all jobs, arena of N)
// and with --penumbra (the program's path), as a user would run them:
//   4. J `penumbra render --threads N` processes, one after another
//   5. one `penumbra batch --jobs N` process
// Each in-process row is the best of three runs; the process rows run once each.
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "bench_common.h"
#include "penumbra/batch.h"
#include "penumbra/error.h"

using namespace penumbra;
namespace fs = std::filesystem;

namespace {

struct Args {
    std::string penumbra;  // the program, for the process rows; none: in-process rows only
    std::string keep;      // where to keep the jobs' files; none: a temporary, removed
    int jobs = 16;
    int size = 96;
    int threads = 2;
    double voxel = 0.02;
};

Args parseArgs(int argc, char** argv) {
    Args a;
    bench::parseOptions("bench_batch", argc, argv,
                        {{"--jobs", &a.jobs}, {"--size", &a.size}, {"--threads", &a.threads},
                         {"--voxel", &a.voxel}, {"--penumbra", &a.penumbra}, {"--keep", &a.keep}});
    if (a.jobs < 1 || a.size < 1 || a.threads < 1 || !(a.voxel > 0.0))
        bench::failUsage("bench_batch", "--jobs, --size, --threads, --voxel must be > 0");
    return a;
}

double now() {
    return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch())
        .count();
}

double cpuSeconds() {  // user + system time of this process, all threads
    rusage u{};
    ::getrusage(RUSAGE_SELF, &u);
    return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
           1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

void removeOutputs(const fs::path& dir) {
    std::error_code ec;
    fs::remove_all(dir / "out", ec);
}

struct Timing {
    double wall = 1e30;
    double cores = 0.0;  // CPU time over wall time of the best run: the cores kept busy
};

// Best of three: timings on a shared 2-core machine are noisy upwards, rarely downwards.
template <class F>
Timing bestOf3(const fs::path& dir, F&& run) {
    Timing best;
    for (int r = 0; r < 3; ++r) {
        removeOutputs(dir);
        const double t0 = now(), c0 = cpuSeconds();
        run();
        const double wall = now() - t0;
        if (wall < best.wall) best = {wall, (cpuSeconds() - c0) / wall};
    }
    return best;
}

double runProcess(const std::string& command) {
    const double t0 = now();
    const int rc = std::system(command.c_str());
    const double t = now() - t0;
    if (rc != 0) {
        std::fprintf(stderr, "bench_batch: command failed (%d): %s\n", rc, command.c_str());
        std::exit(1);
    }
    return t;
}

}  // namespace

int main(int argc, char** argv) {
    const Args a = parseArgs(argc, argv);
    const fs::path dir = a.keep.empty() ? fs::temp_directory_path() /
                                              ("penumbra_bench_batch_" + std::to_string(::getpid()))
                                        : fs::path(a.keep);
    fs::create_directories(dir);
    std::ofstream(dir / "scene.json") << R"({
  "camera": {"eye": [0, -6, 3], "look_at": [0, 0, 0.5], "fov_deg": 40, "width": )"
                                      << a.size << R"(, "height": )" << a.size << R"(},
  "lights": [{"name": "key", "corner": [-1, -1, 4], "edge_u": [0, 2, 0], "edge_v": [2, 0, 0],
              "radiance": [10, 10, 10]}],
  "obstacles": [
    {"name": "sphere", "type": "sphere", "center": [-0.4, 0.4, 1.2], "radius": 0.5},
    {"name": "box", "type": "box", "center": [0.6, -0.4, 0.8], "size": [0.6, 0.6, 0.6]}],
  "receivers": [{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]}],
  "level_set": {"voxel_size": )" << a.voxel << R"(, "half_width": 3}
})";
    std::ofstream(dir / "batch.json") << R"({"sweep": {"scene": "scene.json",
  "output": "out/frame_{frame:03d}.exr", "frames": )"
                                      << a.jobs << R"(,
  "vary": {"lights/0/corner": {"from": [-2, -1, 4], "to": [0, -1, 4]}}}})";

    try {
        const BatchManifest manifest = loadManifest((dir / "batch.json").string());
        std::vector<size_t> all(manifest.jobs.size());
        for (size_t i = 0; i < all.size(); ++i) all[i] = i;
        uint64_t rays = 0;
        auto oneByOne = [&](int threads) {
            BatchOptions o;
            o.threads = threads;
            for (size_t i : all) {
                const std::vector<JobResult> r = runBatch(manifest, {i}, o);
                if (r[0].status != JobStatus::Rendered) {
                    std::fprintf(stderr, "bench_batch: job %zu failed: %s\n", i,
                                 r[0].error.c_str());
                    std::exit(1);
                }
            }
        };
        auto batch = [&](int threads) {
            BatchOptions o;
            o.threads = threads;
            rays = 0;
            for (const JobResult& r : runBatch(manifest, all, o)) {
                if (r.status != JobStatus::Rendered) {
                    std::fprintf(stderr, "bench_batch: job %zu failed: %s\n", r.job,
                                 r.error.c_str());
                    std::exit(1);
                }
                rays += r.shadowRays;
            }
        };

        std::printf("%d jobs of %d x %d (level-set sphere and cube, voxel %g, one light moving), "
                    "%d threads\n\n",
                    a.jobs, a.size, a.size, a.voxel, a.threads);
        const Timing seq1 = bestOf3(dir, [&] { oneByOne(1); });
        const Timing seqN = bestOf3(dir, [&] { oneByOne(a.threads); });
        const Timing bat = bestOf3(dir, [&] { batch(a.threads); });
        std::printf("%-50s %8s %9s %6s\n", "how", "wall", "speed-up", "cores");
        std::printf("%-50s %7.3fs %9s %6.2f\n", "in process, one after another, 1 thread each",
                    seq1.wall, "1.00", seq1.cores);
        std::printf("%-50s %7.3fs %8.2fx %6.2f\n", "in process, one after another, N threads each",
                    seqN.wall, seq1.wall / seqN.wall, seqN.cores);
        std::printf("%-50s %7.3fs %8.2fx %6.2f\n", "in process, one batch on N threads", bat.wall,
                    seq1.wall / bat.wall, bat.cores);
        // Issue 16: the jobs' render-only time (scenes loaded beforehand through one shared
        // cache, so nothing is built inside the timed part), against one batch on 1 thread,
        // which builds the level sets once and shares them with every later frame.
        const Timing bat1 = bestOf3(dir, [&] { batch(1); });
        double renderOnly = 1e30;
        for (int r = 0; r < 3; ++r) {
            LevelSetCache cache;
            double sum = 0.0;
            for (const BatchJob& job : manifest.jobs) {
                const Scene scene = parseScene(resolveSceneText(job), job.scene,
                                               fs::path(job.scene).parent_path().string(), &cache);
                RenderSettings settings = job.settings;
                settings.threads = 1;
                const double t0 = now();
                render(scene, settings);
                sum += now() - t0;
            }
            renderOnly = std::min(renderOnly, sum);
        }
        std::printf("%-50s %7.3fs %8.2fx %6.2f\n", "in process, one batch on 1 thread", bat1.wall,
                    seq1.wall / bat1.wall, bat1.cores);
        std::printf("%-50s %7.3fs\n", "sum of the jobs' render() times, 1 thread", renderOnly);
        std::printf("\nbatch on 1 thread vs the sum of its render-only times: %.2fx "
                    "(issue 16: at most 1.30x)\n",
                    bat1.wall / renderOnly);
        std::printf("batch vs one after another on N threads each: %.2fx\n",
                    seqN.wall / bat.wall);
        std::printf("batch vs one after another on 1 thread:        %.2fx\n",
                    seq1.wall / bat.wall);
        std::printf("shadow rays over the batch: %llu\n", static_cast<unsigned long long>(rays));

        if (!a.penumbra.empty()) {
            removeOutputs(dir);
            fs::create_directories(dir / "out");
            double renders = 0.0;
            for (const BatchJob& job : manifest.jobs) {
                // The render command takes a scene file: write each frame's resolved scene.
                const std::string scene = job.output + ".scene.json";
                std::ofstream(scene) << resolveSceneText(job);
                renders += runProcess(a.penumbra + " render " + scene + " -o " + job.output +
                                      " --threads " + std::to_string(a.threads) + " --quiet");
            }
            removeOutputs(dir);
            const double one = runProcess(a.penumbra + " batch " + (dir / "batch.json").string() +
                                          " --jobs " + std::to_string(a.threads) + " --quiet");
            std::printf("\nprocesses (%s):\n", a.penumbra.c_str());
            std::printf("%-50s %7.3fs\n", "penumbra render --threads N, one after another",
                        renders);
            std::printf("%-50s %7.3fs %8.2fx\n", "penumbra batch --jobs N, one process", one,
                        renders / one);
        }
    } catch (const std::exception& e) {
        std::fprintf(stderr, "bench_batch: %s\n", e.what());
        return 1;
    }
    if (a.keep.empty()) fs::remove_all(dir);
    return 0;
}
