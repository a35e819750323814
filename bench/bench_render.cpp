// Benchmark of the section 5 pipeline (Vedel 1993) against per-pixel ACI on the same scene:
// wall time, shadow rays per viewing ray, the fraction of interpolated pixels, the rays and time
// ratios and the mean difference between the two images in 8-bit units (255 x the linear
// difference, averaged over pixels and channels); then the pipeline on 1 thread against N.
// Prints its figures; never fails on a time.
//
//   bench_render [SCENE.json] [--size N] [--threads N] [--radiance-scale S] [--out DIR]
//                [--aci-mode paper|arcs|tangent]
//
// SCENE defaults to vdb_scenes/default.json (run from the source tree), --size to 800 and
// --threads to 2. --radiance-scale multiplies every light's radiance (the image is linear, so
// differences scale with it: report it with the figures). --out writes the images as .exr/.png.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "bench_common.h"
#include "penumbra/error.h"
#include "penumbra/image_io.h"
#include "penumbra/contour_integrator.h"
#include "penumbra/renderer.h"
#include "penumbra/scene.h"

using namespace penumbra;

namespace {

struct Args {
    std::string scene = "vdb_scenes/default.json";
    int size = 800;
    int threads = 2;
    double radianceScale = 1.0;
    std::string out;
    std::string aciMode = "tangent";
};

Args parseArgs(int argc, char** argv) {
    Args a;
    bench::parseOptions("bench_render", argc, argv,
                        {{"--size", &a.size},
                         {"--threads", &a.threads},
                         {"--radiance-scale", &a.radianceScale},
                         {"--out", &a.out},
                         {"--aci-mode", &a.aciMode}},
                        &a.scene);
    if (a.size < 1 || a.threads < 1 || !(a.radianceScale > 0.0))
        bench::failUsage("bench_render", "--size, --threads, --radiance-scale must be > 0");
    return a;
}

void printRow(const char* name, const RenderStats& s) {
    double fraction = s.viewingRaysWithShadowRays
                          ? double(s.interpolatedPixels) / double(s.viewingRaysWithShadowRays)
                          : 0.0;
    std::printf("%-22s %8.2f s %12llu %12llu %10.2f %11.1f%% %9llu %8llu\n", name, s.seconds,
                static_cast<unsigned long long>(s.shadowRays),
                static_cast<unsigned long long>(s.viewingRaysWithShadowRays),
                s.shadowRaysPerViewingRay(), 100.0 * fraction,
                static_cast<unsigned long long>(s.aciEvaluations),
                static_cast<unsigned long long>(s.restarts));
}

}  // namespace

int main(int argc, char** argv) {
    Args args = parseArgs(argc, argv);
    try {
        Scene scene = loadScene(args.scene);
        for (RectLight& l : scene.lights) l.radiance *= args.radianceScale;

        RenderSettings pipeline = bench::squareSettings(Method::Aci, args.size, args.threads);
        applyAciMode(pipeline.aci, parseAciMode(args.aciMode, "--aci-mode"));
        RenderSettings perPixel = pipeline;
        perPixel.method = Method::AciPixel;

        std::printf("scene %s, %d x %d, radiance x %g, %d threads, ACI mode %s\n",
                    args.scene.c_str(), args.size, args.size, args.radianceScale, args.threads,
                    args.aciMode.c_str());
        RenderResult a = render(scene, pipeline);
        RenderResult b = render(scene, perPixel);

        std::printf("\n%-22s %10s %12s %12s %10s %12s %9s %8s\n", "method", "wall", "shadow rays",
                    "VR w/ rays", "rays/VR", "interpolated", "ACI evals", "restarts");
        printRow("aci (pipeline)", a.stats);
        printRow("aci-pixel (per pixel)", b.stats);

        double sum = 0.0, maxDiff = 0.0, maxValue = 0.0, maskedSum = 0.0;
        size_t masked = 0;
        for (int y = 0; y < a.color.height; ++y) {
            for (int x = 0; x < a.color.width; ++x) {
                bool inMask = a.aovs.mask.at(x, y) > 0.0f || b.aovs.mask.at(x, y) > 0.0f;
                for (int c = 0; c < 3; ++c) {
                    double d = 255.0 * std::abs(double(a.color.at(x, y, c)) - b.color.at(x, y, c));
                    sum += d;
                    maxDiff = std::max(maxDiff, d);
                    maxValue = std::max(maxValue, double(b.color.at(x, y, c)));
                    if (inMask) maskedSum += d;
                }
                if (inMask) ++masked;
            }
        }
        double meanDiff = sum / double(a.color.data.size());
        std::printf("\nshadow rays ratio (per pixel / pipeline): %.2f\n",
                    double(b.stats.shadowRays) / double(std::max<uint64_t>(1, a.stats.shadowRays)));
        std::printf("time ratio (per pixel / pipeline):        %.2f\n",
                    b.stats.seconds / a.stats.seconds);
        std::printf("mean difference, 8-bit units:             %.4f over all pixels, %.4f over "
                    "the %zu pixels with shadow rays; max %.2f\n",
                    meanDiff, masked ? maskedSum / (3.0 * double(masked)) : 0.0, masked, maxDiff);
        std::printf("brightest per-pixel value (linear):       %.4f (%.1f in 8-bit units)\n",
                    maxValue, 255.0 * maxValue);

        if (!args.out.empty()) {
            writeImage(args.out + "/bench_aci.exr", a.color);
            writeImage(args.out + "/bench_aci.png", a.color);
            writeImage(args.out + "/bench_aci_pixel.exr", b.color);
            float top = 0.0f;
            for (float v : a.aovs.shadowRays.data) top = std::max(top, v);
            writeImage(args.out + "/bench_aci_rays.png", heatMap(a.aovs.shadowRays, top));
        }

        if (args.threads > 1) {
            RenderSettings one = pipeline;
            one.threads = 1;
            RenderResult c = render(scene, one);
            // The N-thread pipeline again, right after, so that both timings see the same
            // machine state.
            RenderResult d = render(scene, pipeline);
            bool same = c.color.data == d.color.data && c.color.data == a.color.data;
            std::printf("\npipeline on 1 thread: %.2f s, on %d threads: %.2f s (first run %.2f s): "
                        "speed-up %.2f; images identical: %s\n",
                        c.stats.seconds, args.threads, d.stats.seconds, a.stats.seconds,
                        c.stats.seconds / d.stats.seconds, same ? "yes" : "NO");
        }
    } catch (...) {
        return bench::reportException("bench_render");
    }
    return 0;
}
