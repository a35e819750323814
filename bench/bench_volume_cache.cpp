// Benchmark of the in-scattering lattice (docs/volumes.md, "The camera sees volumes"): the same
// scene rendered with the lattice at several resolutions and with S computed at every sample
// along the viewing rays (--volume-cache 0), in one run. For each: wall time, in-scattering rays
// (RenderStats::volumeRays), the per-sample render's rays and seconds over this one's, and the
// difference from the per-sample image in 8-bit units (255 x linear), mean and largest over the
// pixels where the media show (where the per-sample image differs from a render with the
// volumes hidden, which casts the same shadows; its time is printed too: the part every render
// spends on shadows). Prints its figures; never fails on a time.
//
//   bench_volume_cache [SCENE.json] [--size N] [--threads N] [--caches 12,24,48]
//                      [--samples N]
//
// SCENE defaults to vdb_scenes/fog.json (run from the source tree), --size to 100 (the
// per-sample render is slow: every step of every viewing ray through a medium traces
// --samples rays per light), --threads to 2, --samples (rays per in-scattering estimate) to 64.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>
#include <string>
#include <vector>

#include "bench_common.h"
#include "penumbra/error.h"
#include "penumbra/renderer.h"
#include "penumbra/scene.h"

using namespace penumbra;

namespace {

struct Args {
    std::string scene = "vdb_scenes/fog.json";
    int size = 100;
    int threads = 2;
    std::string caches = "12,24,48";
    int samples = 64;
};

std::vector<int> parseList(const std::string& text) {
    std::vector<int> out;
    std::stringstream in(text);
    std::string item;
    while (std::getline(in, item, ',')) {
        const int v = std::atoi(item.c_str());
        if (v < 1) bench::failUsage("bench_volume_cache", "--caches takes resolutions >= 1");
        out.push_back(v);
    }
    return out;
}

}  // namespace

int main(int argc, char** argv) {
    Args args;
    bench::parseOptions("bench_volume_cache", argc, argv,
                        {{"--size", &args.size},
                         {"--threads", &args.threads},
                         {"--caches", &args.caches},
                         {"--samples", &args.samples}},
                        &args.scene);
    if (args.size < 1 || args.threads < 1 || args.samples < 1)
        bench::failUsage("bench_volume_cache", "--size, --threads, --samples must be > 0");
    const std::vector<int> caches = parseList(args.caches);
    try {
        const Scene scene = loadScene(args.scene);
        RenderSettings base = bench::squareSettings(Method::Aci, args.size, args.threads);
        base.volumeSamples = args.samples;

        RenderSettings hidden = base;
        hidden.volumesVisible = false;
        const RenderResult shadowsOnly = render(scene, hidden);
        RenderSettings direct = base;
        direct.volumeCache = 0;
        const RenderResult exact = render(scene, direct);

        // Pixels where the media show: the per-sample image differs from the hidden one.
        std::vector<char> shows(size_t(args.size) * size_t(args.size), 0);
        size_t shown = 0;
        for (int y = 0; y < args.size; ++y)
            for (int x = 0; x < args.size; ++x)
                for (int c = 0; c < 3; ++c)
                    if (exact.color.at(x, y, c) != shadowsOnly.color.at(x, y, c) &&
                        !shows[size_t(y) * size_t(args.size) + size_t(x)]) {
                        shows[size_t(y) * size_t(args.size) + size_t(x)] = 1;
                        ++shown;
                    }

        std::printf("scene %s, %d x %d, %d threads, %d rays per in-scattering estimate; the "
                    "media show on %zu pixels\n",
                    args.scene.c_str(), args.size, args.size, args.threads, args.samples, shown);
        std::printf("volumes hidden (shadows only): %.2f s\n\n", shadowsOnly.stats.seconds);
        std::printf("%-14s %9s %14s %11s %11s | %9s %9s\n", "volume cache", "seconds",
                    "volume rays", "rays ratio", "time ratio", "mean", "max");
        std::printf("%-14s %9.2f %14llu %11s %11s | %9s %9s\n", "0 (per sample)",
                    exact.stats.seconds, static_cast<unsigned long long>(exact.stats.volumeRays),
                    "1.0", "1.00", "-", "-");
        for (const int n : caches) {
            RenderSettings s = base;
            s.volumeCache = n;
            const RenderResult r = render(scene, s);
            double sum = 0.0, worst = 0.0;
            for (int y = 0; y < args.size; ++y)
                for (int x = 0; x < args.size; ++x) {
                    if (!shows[size_t(y) * size_t(args.size) + size_t(x)]) continue;
                    for (int c = 0; c < 3; ++c) {
                        const double d =
                            255.0 * std::abs(double(r.color.at(x, y, c)) - exact.color.at(x, y, c));
                        sum += d / 3.0;
                        worst = std::max(worst, d);
                    }
                }
            std::printf("%-14d %9.2f %14llu %11.1f %11.2f | %9.4f %9.3f\n", n, r.stats.seconds,
                        static_cast<unsigned long long>(r.stats.volumeRays),
                        double(exact.stats.volumeRays) / double(std::max<uint64_t>(1, r.stats.volumeRays)),
                        exact.stats.seconds / r.stats.seconds, shown ? sum / double(shown) : 0.0,
                        worst);
        }
        std::printf("\nrays ratio, time ratio: the per-sample render's over this one's; mean "
                    "and max: difference from the per-sample image over the pixels where the "
                    "media show, 8-bit units\n");
    } catch (...) {
        return bench::reportException("bench_volume_cache");
    }
    return 0;
}
