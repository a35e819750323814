// Seeded random scenes nobody tuned: approximate contour integration (default tangent mode, and
// the paper's and the arcs variants) and mc-solid-angle at ACI's wall time, each against a
// 4096-ray reference, over scenes drawn by a fixed generator, at 200 x 200 and 800 x 800; then
// the gallery scenes vdb_scenes/default.json and vdb_scenes/table1.json the same way. Prints one
// row per (scene, size, method) and a summary per method. A benchmark, not a test: never fails
// on a figure.
//
//   bench_random [--seeds N] [--first-seed S] [--sizes 200,800] [--threads N]
//                [--gallery-size 200[,800] | --gallery-size 0] [--gallery-dir DIR]
//                [--gallery default,table1,fog]
//                [--ref-samples 4096] [--ref-stride S] [--repeat N] [--out DIR] [--save-images]
//                [--adjudicate-samples 1048576] [--lights rect|mixed] [--fog] [--light-scale S]
//                [--paper-ladder] [--aci-fixed-steps]
//
// Defaults: 10 seeds from 1, sizes 200 and 800, 2 threads, gallery at 200 only, reference 4096
// rays, --out /tmp/penumbra_random (each seed's scene is written there as seed_S.json before it
// is parsed: `penumbra render /tmp/penumbra_random/seed_S.json -o x.png --width 200 --height 200`
// reproduces it). --gallery-dir defaults to ./vdb_scenes, else the source tree's. --save-images
// also writes there, per scene and size, the reference, default ACI and mc-solid-angle at ACI's
// time (.exr), ACI's picture (.png) and its error map on the compared pixels (.png; black 0,
// blue 2, red 4, yellow 6, white 8 or more units). --adjudicate-samples N (default 2^20; 0:
// off) judges ACI's compared pixels over 6 units again, against two N-ray references of each
// pixel alone (below). --lights mixed gives each seed's scene a rectangle, disc, triangle or
// convex 5- to 7-gon light on the rectangle's frame (bench/random_scenes.h, LightShapes; the
// default, rect, is every figure's before 2026-12-05). --fog adds one or two fog volumes to
// each seed's scene (bench/random_scenes.h, "Volumes"; with either --lights). --light-scale S
// grows each scene's light S times about its centre once the rest is drawn (radiance over S^2).
// --paper-ladder also renders the paper's mode at finer settings until its mean difference is
// at most default ACI's (the paper's mode at ACI's error; below). --aci-fixed-steps renders the
// "aci" rows (and the 16 x 16 fixed cost) as `penumbra render --aci-fixed-steps` does: every
// evaluation on the full lattice, no adaptive steps; every other row is unchanged.
//
// ---------------------------------------------------------------------------------------------
// The generator: bench/random_scenes.h (seed s gives the same scene on any platform).

// ---------------------------------------------------------------------------------------------
// Protocol, per scene and size N (one viewing ray per pixel, `--threads` workers):
//
//  - Reference: Method::Reference (stratified area sampling) with mc.samples = --ref-samples
//    (4096) and mc.seed 0x5eed (mc-solid-angle runs with seed 0).
//    Exact subset instead of a crop at large sizes: with --ref-stride S (odd; default 1 up to
//    N = 400, 3 above), the reference is rendered with the scene's camera at M x M pixels and a
//    field of view narrowed to tan(fov'/2) = (S M / N) tan(fov/2), where k is the smallest offset
//    with (N - 1 - 2k) divisible by S and M = (N - 1 - 2k) / S + 1. Its pixel (j, i) then has
//    the same viewing ray (up to rounding) as pixel (k + S j, k + S i) of the N x N picture: at
//    N = 800, S = 3 that is every third row and column from pixel 2 to 797, 266 x 266 pixels
//    (1/9 of the image, so 1/9 of the reference's cost). Every method renders the whole N x N
//    picture (its time, rays and coherence are the full render's) and is compared on those pixels
//    only. The reference's per-pixel estimate does not depend on its neighbours (no coherence;
//    shaft culling is conservative and unshadowed pixels get the exact closed form), so it is
//    the same estimator at the same points. Two checks are printed per scene: the number of
//    sampled pixels whose hit object differs between the two cameras, and the largest
//    difference between ACI and the reference on pixels where neither cast shadow rays (both
//    are the closed form there: ~0 when the pixels line up).
//  - ACI at default settings (Method::Aci, RenderSettings defaults without the gradient and the
//    error bound, as `penumbra render` without AOV files), then mc-solid-angle at ACI's
//    wall time: a first try with round(ACI's rays per viewing ray) samples, a second with the
//    samples scaled by the time ratio, and while none is within 10% of ACI's time (at most 4
//    tries) another from the least-squares line time = a + b samples through the tries; the try
//    closest in time is reported, with its achieved time ratio (mc s / aci s), and every try is
//    listed in the scene's line. Then ACI with --aci-mode paper and arcs
//    (applyAciMode). Wall seconds are RenderStats::seconds (the render only: level sets are built
//    once when the scene is parsed; ACI's time includes building the far-field distance
//    companions its tangent mode needs, as every `penumbra render` does). The machine is shared:
//    times, hence the equal-time sample count, are noisy; --repeat N renders ACI and each mc
//    try N times and keeps the fastest (the paper and arcs rows and the references once). ACI's fixed cost is shown per scene:
//    the time of the same ACI render at 16 x 16 pixels.
//  - With --paper-ladder: the paper's mode again at finer first levels and more dichotomy steps,
//    in this order of cost, (grid, steps) = (2, 6), (4, 5), (4, 6), (8, 5), (8, 6), (16, 5),
//    (16, 6) (none when the aci-paper row already reaches it), until its mean difference (below) is at most default ACI's, or a render takes more
//    than 16 times ACI's time. The row "paper@aci-mean" is the first setting that reaches ACI's
//    mean (its t/aci: what the paper's mode costs at the default's error), else the last tried;
//    the scene's line lists every setting tried, and the summary how many scenes reached it.
//  - Per row: samples, shadow rays per viewing ray (RenderStats::shadowRaysPerViewingRay: over
//    the pixels where shadow rays were cast), seconds, then against the reference on the
//    compared pixels, in 8-bit units (255 x linear difference, penumbra::compareImages): "mean"
//    the mean absolute difference over the masked pixels (where the reference or default ACI cast
//    shadow rays: the paper's "average difference", the same pixels for every method), "all" the
//    mean over every compared pixel, "max" the largest over every compared pixel and channel,
//    "max*" the same over the pixels where the reference is certain (below); ">6" the compared
//    pixels whose largest channel difference exceeds 6 units, "sil" how many of those are
//    silhouette pixels and "ref?" how many are uncertain; "diff/aci" the row's mean over default
//    ACI's.
//  - The reference's own noise: a second 4096-ray reference with another seed (mc.seed 0x5eef)
//    on the same pixels, printed as the row "reference #2" against the first. Stratified area
//    sampling is weak where a receiver is close to the light (the integrand's 1 / r^2): on
//    obstacle faces a few hundredths from the light two such references differ by tens to
//    hundreds of units, and as the estimator's error is skewed there (most strata miss the peak)
//    the two can also agree with each other and both be off (seen: 44-52 units on seed 3, where
//    mc-solid-angle and ACI agree within 2). A compared pixel is "uncertain" when the two
//    references differ by more than 3 units in some channel, or when its point is closer to
//    the light than 4 strata (4 x the light's longer edge / sqrt(samples), 0.0625 x the edge at
//    4096 rays; the distance from the point the benchmark's own viewing ray hits); "max*" leaves
//    those out and "ref?" counts them among the ">6" pixels.
//  - Per-pixel judgement: each of default ACI's compared pixels over 6 units is rendered again
//    alone (a 1 x 1 camera at the same eye looking along the pixel's viewing ray, so the same
//    shading point) with Method::Reference at --adjudicate-samples rays, twice with two seeds.
//    The scene's line below the table header says how many stay over 6 units from the two's
//    mean, the largest such difference, and in how many the two differ by more than 3 units
//    (the per-pixel references themselves unsettled); the pixels still over are listed.
//  - Silhouette pixels: the renderer exposes no object-id AOV, so the benchmark casts the viewing
//    rays itself with the public API, the way the renderer does (PinholeCamera::pixelRay, the
//    nearest receiver plane, then each obstacle's bounds clipped and Occluder::Query::occluded
//    restricted to that obstacle): a pixel is on a silhouette when its 3 x 3 neighbourhood in the
//    N x N picture holds more than one hit object (planes, obstacles, background). Silhouette
//    pixels are where a viewing ray through the pixel's centre decides the object: a method's
//    value there can differ from the reference's by the jump in shading, not only by the
//    estimator's error, when the shadow rays' start offset (automatic, near level sets) differs.
//  - Summary per (set, size, method): geometric means of rays per viewing ray, time over ACI's,
//    mean difference and diff/aci; the smallest and largest diff/aci (for mc-solid-angle at ACI's
//    time, the smallest is its best case, ACI's worst); the worst mean and max difference; the
//    total of pixels over 6 units and how many are on silhouettes.
//
// The reference has noise of its own: in docs/BENCHMARKS.md (Table 1 scene, 800 x 800) a
// 1024-ray reference differs from a 4096-ray one by 0.101 units on average; the 4096-ray one's own
// error is about half that, a floor under every mean difference here.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bench_common.h"
#include "random_scenes.h"
#include "penumbra/camera.h"
#include "penumbra/compare.h"
#include "penumbra/contour_integrator.h"
#include "penumbra/error.h"
#include "penumbra/image_io.h"
#include "penumbra/renderer.h"
#include "penumbra/scene.h"

using namespace penumbra;
using namespace randomscenes;
namespace fs = std::filesystem;

namespace {

// ---------------------------------------------------------------------------------------------
// Options

struct Args {
    int seeds = 10;
    uint64_t firstSeed = 1;
    std::vector<int> sizes{200, 800};
    std::vector<int> gallerySizes{200};
    int threads = 2;
    int refSamples = 4096;
    int refStride = 0;  // 0: 1 up to 400 pixels, 3 above
    std::string out = "/tmp/penumbra_random";
    std::string galleryDir;
    std::vector<std::string> gallery{"default", "table1"};  // scene stems in galleryDir
    bool saveImages = false;
    LightShapes lights = LightShapes::Rect;
    bool fog = false;
    double lightScale = 1.0;  // each scene's light grown this many times (random_scenes.h)
    int repeat = 1;  // timed renders (ACI, each mc try) run this many times, the fastest kept
    int adjudicateSamples = 1 << 20;  // per-pixel references for ACI's pixels over 6 units; 0: none
    bool paperLadder = false;  // the paper's mode at finer settings until it reaches ACI's mean
    bool aciFixedSteps = false;  // the "aci" rows without adaptive steps
};

[[noreturn]] void usage(const std::string& message) {
    std::fprintf(stderr, "bench_random: %s\n", message.c_str());
    std::fprintf(stderr,
                 "usage: bench_random [--seeds N] [--first-seed S] [--sizes 200,800] "
                 "[--threads N] [--gallery-size 200[,800]|0] [--gallery-dir DIR] [--gallery a,b] "
                 "[--ref-samples N] [--ref-stride S] [--repeat N] [--out DIR] [--save-images] "
                 "[--adjudicate-samples N] [--lights rect|mixed] [--fog] [--light-scale S] "
                 "[--paper-ladder] [--aci-fixed-steps]\n");
    std::exit(2);
}

long parseInt(const std::string& flag, const std::string& text) {
    char* end = nullptr;
    const long v = std::strtol(text.c_str(), &end, 10);
    if (text.empty() || *end != '\0') usage(flag + ": not an integer: '" + text + "'");
    return v;
}

std::vector<int> parseList(const std::string& flag, const std::string& text) {
    std::vector<int> out;
    std::stringstream ss(text);
    std::string item;
    while (std::getline(ss, item, ',')) {
        const long v = parseInt(flag, item);
        if (v == 0) continue;  // "0": none
        if (v < 16 || v > 8192) usage(flag + ": sizes must be in [16, 8192], got " + item);
        out.push_back(int(v));
    }
    return out;
}

// `repeat` renders of the same scene and settings (the same image each time: renders are
// deterministic), the one with the least wall time kept: on a shared machine the fastest of a
// few runs is the closest to the render's own cost.
RenderResult timedRender(const Scene& scene, const RenderSettings& settings, int repeat) {
    RenderResult best = render(scene, settings);
    for (int i = 1; i < repeat; ++i) {
        RenderResult r = render(scene, settings);
        if (r.stats.seconds < best.stats.seconds) best = std::move(r);
    }
    return best;
}

Args parseArgs(int argc, char** argv) {
    Args a;
    for (int i = 1; i < argc; ++i) {
        const std::string s = argv[i];
        auto next = [&]() -> std::string {
            if (i + 1 >= argc) usage(s + " needs a value");
            return argv[++i];
        };
        if (s == "--seeds") a.seeds = int(parseInt(s, next()));
        else if (s == "--first-seed") a.firstSeed = uint64_t(parseInt(s, next()));
        else if (s == "--sizes") a.sizes = parseList(s, next());
        else if (s == "--gallery-size" || s == "--gallery-sizes") a.gallerySizes = parseList(s, next());
        else if (s == "--threads") a.threads = int(parseInt(s, next()));
        else if (s == "--ref-samples") a.refSamples = int(parseInt(s, next()));
        else if (s == "--ref-stride") a.refStride = int(parseInt(s, next()));
        else if (s == "--repeat") a.repeat = int(parseInt(s, next()));
        else if (s == "--out") a.out = next();
        else if (s == "--gallery-dir") a.galleryDir = next();
        else if (s == "--gallery") {
            a.gallery.clear();
            std::stringstream list(next());
            for (std::string stem; std::getline(list, stem, ',');)
                if (!stem.empty()) a.gallery.push_back(stem);
        }
        else if (s == "--save-images") a.saveImages = true;
        else if (s == "--lights") a.lights = parseLightShapes(next());
        else if (s == "--fog") a.fog = true;
        else if (s == "--paper-ladder") a.paperLadder = true;
        else if (s == "--aci-fixed-steps") a.aciFixedSteps = true;
        else if (s == "--light-scale") {
            a.lightScale = std::atof(next().c_str());
            if (!(a.lightScale > 0.0)) usage("--light-scale must be > 0");
        }
        else if (s == "--adjudicate-samples") a.adjudicateSamples = int(parseInt(s, next()));
        else if (s == "--help" || s == "-h") usage("seeded random scenes: ACI against Monte Carlo");
        else usage("unknown option " + s);
    }
    if (a.seeds < 0) usage("--seeds must be >= 0");
    if (a.threads < 1) usage("--threads must be >= 1");
    if (a.refSamples < 1) usage("--ref-samples must be >= 1");
    if (a.repeat < 1) usage("--repeat must be >= 1");
    if (a.adjudicateSamples < 0) usage("--adjudicate-samples must be >= 0");
    if (a.refStride < 0 || (a.refStride > 0 && a.refStride % 2 == 0))
        usage("--ref-stride must be odd (1, 3, 5, ...): only then is the sampled set centred");
    if (a.galleryDir.empty()) {
        if (fs::exists("vdb_scenes/default.json")) {
            a.galleryDir = "vdb_scenes";
        } else {
            a.galleryDir = (fs::path(__FILE__).parent_path().parent_path() / "vdb_scenes").string();
        }
    }
    return a;
}

// ---------------------------------------------------------------------------------------------
// Hit objects per pixel, cast the way the renderer casts its viewing rays (src/renderer.cpp,
// castViewingRay): planes 0 .. P-1, obstacles P .., -1 background.

// Distance from p to the rectangle of `light` (edges taken as perpendicular: the clamp is then
// exact; for other parallelograms an approximation).
double distanceToLight(const RectLight& light, const Vec3& p) {
    const Vec3 d = p - light.corner;
    const double u = std::clamp(glm::dot(d, light.edgeU) / glm::dot(light.edgeU, light.edgeU), 0.0, 1.0);
    const double v = std::clamp(glm::dot(d, light.edgeV) / glm::dot(light.edgeV, light.edgeV), 0.0, 1.0);
    return glm::length(p - light.point(u, v));
}

// Also, when `nearLight` is given: per pixel, whether the hit point is closer to some light than
// `strata` strata of a `samples`-ray stratified reference (strata x the light's longer edge /
// sqrt(samples)).
std::vector<int> objectIds(const Scene& scene, const Camera& cameraIn, int threads,
                           std::vector<uint8_t>* nearLight = nullptr, int samples = 0,
                           double strata = 0.0) {
    const PinholeCamera camera(cameraIn, scene.file);
    const Occluder occluder = scene.makeOccluder();
    const int w = camera.width(), h = camera.height();
    std::vector<int> ids(size_t(w) * size_t(h), -1);
    if (nearLight) nearLight->assign(ids.size(), 0);
    auto work = [&](int y0, int y1) {
        Occluder::Query query = occluder.makeQuery();
        std::vector<uint32_t> single{0};
        for (int y = y0; y < y1; ++y) {
            for (int x = 0; x < w; ++x) {
                const ViewRay ray = camera.pixelRay(x, y);
                int object = -1;
                double best = std::numeric_limits<double>::infinity();
                for (size_t i = 0; i < scene.receivers.size(); ++i) {
                    const Vec3 nrm = glm::normalize(scene.receivers[i].normal);
                    const double denom = glm::dot(ray.direction, nrm);
                    if (std::abs(denom) < 1e-12) continue;
                    const double t = glm::dot(scene.receivers[i].point - ray.origin, nrm) / denom;
                    if (t > 0.0 && t < best) {
                        best = t;
                        object = int(i);
                    }
                }
                const Vec3 invD(1.0 / ray.direction.x, 1.0 / ray.direction.y,
                                1.0 / ray.direction.z);
                for (size_t i = 0; i < occluder.size(); ++i) {
                    double t0 = 0.0, t1 = best;
                    if (!occluder.bounds(i).clipRay(ray.origin, invD, t0, t1)) continue;
                    if (!std::isfinite(t1)) continue;
                    single[0] = uint32_t(i);
                    query.restrictTo(&single);
                    double tHit = 0.0;
                    if (query.occluded(ray.at(t0), ray.at(t1), &tHit) && t0 + tHit < best) {
                        best = t0 + tHit;
                        object = int(scene.receivers.size() + i);
                    }
                }
                query.restrictTo(nullptr);
                ids[size_t(y) * size_t(w) + size_t(x)] = object;
                if (nearLight && object >= 0) {
                    for (const RectLight& l : scene.lights) {
                        const double edge = std::max(glm::length(l.edgeU), glm::length(l.edgeV));
                        if (distanceToLight(l, ray.at(best)) <
                            strata * edge / std::sqrt(double(std::max(1, samples))))
                            (*nearLight)[size_t(y) * size_t(w) + size_t(x)] = 1;
                    }
                }
            }
        }
    };
    const int n = std::max(1, std::min(threads, h));
    std::vector<std::thread> pool;
    for (int t = 0; t < n; ++t) pool.emplace_back(work, h * t / n, h * (t + 1) / n);
    for (std::thread& t : pool) t.join();
    return ids;
}

// ---------------------------------------------------------------------------------------------
// The compared pixels: (k + S j, k + S i), j, i < M.

struct Sampling {
    int size = 0;    // N
    int stride = 1;  // S
    int offset = 0;  // k
    int count = 0;   // M
    bool full() const { return stride == 1; }
};

Sampling makeSampling(int size, int stride) {
    Sampling s;
    s.size = size;
    s.stride = stride;
    for (int k = 0; k < stride; ++k) {
        if ((size - 1 - 2 * k) % stride == 0) {
            s.offset = k;
            break;
        }
    }
    s.count = (size - 1 - 2 * s.offset) / stride + 1;
    return s;
}

Image sample(const Image& img, const Sampling& s) {
    if (s.full()) return img;
    Image out(s.count, s.count, img.channels);
    for (int y = 0; y < s.count; ++y) {
        for (int x = 0; x < s.count; ++x) {
            for (int c = 0; c < img.channels; ++c) {
                out.at(x, y, c) = img.at(s.offset + s.stride * x, s.offset + s.stride * y, c);
            }
        }
    }
    return out;
}

// ---------------------------------------------------------------------------------------------
// Rows and their figures.

struct Metrics {
    double mean = 0.0, meanAll = 0.0, max = 0.0;
    double maxCertain = 0.0;  // over the pixels where the two references agree within 3 units
    size_t over = 0, overSilhouette = 0, overUncertain = 0;
};

struct Row {
    std::string set;    // "random" or "gallery"
    std::string scene;  // "seed 3", "default"
    int size = 0;
    std::string method;  // "reference", "aci", "aci-paper", "aci-arcs", "mc-sa@aci-time",
                         // "paper@aci-mean"
    int samples = 0;
    double raysPerVr = 0.0, seconds = 0.0, timeRatio = 0.0;
    Metrics m;
    double diffOverAci = 0.0;
    bool isReference = false;
    bool reached = true;  // "paper@aci-mean": whether some setting reached ACI's mean
};

struct Comparison {
    const Image* ref;                 // M x M
    Image mask;                       // M x M
    std::vector<uint8_t> silhouette;  // M x M
    std::vector<uint8_t> uncertain;   // M x M: the two references differ by > 3 units
    Sampling sampling;
};

Metrics measure(const Image& full, const Comparison& cmp) {
    const Image test = sample(full, cmp.sampling);
    const ImageDifference d = compareImages(test, *cmp.ref, &cmp.mask);
    Metrics m;
    m.mean = d.masked.mean;
    m.meanAll = d.all.mean;
    m.max = d.all.max;
    for (int y = 0; y < test.height; ++y) {
        for (int x = 0; x < test.width; ++x) {
            double worst = 0.0;
            for (int c = 0; c < test.channels; ++c) {
                worst = std::max(worst,
                                 255.0 * std::abs(double(test.at(x, y, c)) - cmp.ref->at(x, y, c)));
            }
            const size_t i = size_t(y) * size_t(test.width) + size_t(x);
            if (!cmp.uncertain[i]) m.maxCertain = std::max(m.maxCertain, worst);
            if (worst > 6.0) {
                ++m.over;
                if (cmp.silhouette[i]) ++m.overSilhouette;
                if (cmp.uncertain[i]) ++m.overUncertain;
            }
        }
    }
    return m;
}

/// ACI's compared pixels over 6 units, judged again against references of their own: for each,
/// two renders of that one pixel (a 1 x 1 camera on the pixel's viewing ray) with
/// `samples` reference rays and two seeds. A pixel stays "over" when ACI differs from their mean
/// by more than 6 units; "unsettled" when the two differ from each other by more than 3.
struct Adjudication {
    size_t judged = 0, over = 0, unsettled = 0;
    double worst = 0.0;  // ACI's largest difference from the per-pixel references
    std::string overList;  // "(x, y) aci-vs-ref units; ..." for those still over
};

Adjudication adjudicate(const Scene& scene, const Camera& cam, const Image& aci,
                        const Comparison& cmp, int samples, int threads) {
    Adjudication out;
    if (samples <= 0) return out;
    const PinholeCamera pc(cam);
    const Sampling& smp = cmp.sampling;
    for (int j = 0; j < smp.count; ++j) {
        for (int i = 0; i < smp.count; ++i) {
            const int x = smp.offset + smp.stride * i, y = smp.offset + smp.stride * j;
            double worst = 0.0;
            for (int c = 0; c < 3; ++c)
                worst = std::max(worst, 255.0 * std::abs(double(aci.at(x, y, c)) - cmp.ref->at(i, j, c)));
            if (worst <= 6.0) continue;
            ++out.judged;
            const ViewRay ray = pc.pixelRay(x, y);
            Scene one = scene;  // shares the level sets
            one.camera->eye = ray.origin;
            one.camera->lookAt = ray.origin + ray.direction;
            one.camera->fovDeg = cam.fovDeg / cam.height;
            one.camera->width = one.camera->height = 1;
            RenderSettings rs = bench::squareSettings(Method::Reference, 1, threads);
            rs.mc.samples = samples;
            rs.mc.seed = 0xad1;
            const Image a = render(one, rs).color;
            rs.mc.seed = 0xad2;
            const Image b = render(one, rs).color;
            double off = 0.0, spread = 0.0;
            for (int c = 0; c < 3; ++c) {
                const double mean = 0.5 * (double(a.at(0, 0, c)) + b.at(0, 0, c));
                off = std::max(off, 255.0 * std::abs(double(aci.at(x, y, c)) - mean));
                spread = std::max(spread, 255.0 * std::abs(double(a.at(0, 0, c)) - b.at(0, 0, c)));
            }
            out.worst = std::max(out.worst, off);
            out.unsettled += spread > 3.0;
            if (off > 6.0) {
                ++out.over;
                char buf[96];
                std::snprintf(buf, sizeof buf, "%s(%d, %d) %.1f (refs apart %.1f)",
                              out.overList.empty() ? "" : "; ", x, y, off, spread);
                out.overList += buf;
            }
        }
    }
    return out;
}

void printTableHeader() {
    std::printf("%-8s %-10s %5s  %-15s %7s %9s %8s %7s | %7s %7s %8s %8s %7s %6s %6s %8s\n",
                "set", "scene", "size", "method", "samples", "rays/VR", "seconds", "t/aci", "mean",
                "all", "max", "max*", ">6", "sil", "ref?", "diff/aci");
}

void printRow(const Row& r) {
    char samples[16], ratio[16], diff[128];
    if (r.samples > 0) std::snprintf(samples, sizeof samples, "%d", r.samples);
    else std::snprintf(samples, sizeof samples, "-");
    std::snprintf(ratio, sizeof ratio, "%7.2f", r.timeRatio);
    if (r.isReference) {
        std::snprintf(diff, sizeof diff, "%7s %7s %8s %8s %7s %6s %6s %8s", "-", "-", "-", "-",
                      "-", "-", "-", "-");
    } else {
        std::snprintf(diff, sizeof diff, "%7.3f %7.3f %8.2f %8.2f %7zu %6zu %6zu %8.2f", r.m.mean,
                      r.m.meanAll, r.m.max, r.m.maxCertain, r.m.over, r.m.overSilhouette,
                      r.m.overUncertain, r.diffOverAci);
    }
    std::printf("%-8s %-10s %5d  %-15s %7s %9.2f %8.2f %7s | %s\n", r.set.c_str(),
                r.scene.c_str(), r.size, r.method.c_str(), samples, r.raysPerVr, r.seconds,
                ratio, diff);
    std::fflush(stdout);
}

struct Context {
    const Args& args;
    std::vector<Row> rows;
    std::vector<std::string> failures;
};

using bench::squareSettings;

// One scene at one size: every method, its rows printed as they come.
void runSceneAtSize(Context& ctx, const Scene& scene, const std::string& set,
                    const std::string& name, const std::string& tag, int size) {
    const Args& args = ctx.args;
    const int stride = args.refStride > 0 ? args.refStride : (size <= 400 ? 1 : 3);
    const Sampling smp = makeSampling(size, stride);
    auto progress = [&](const char* what) {
        std::fprintf(stderr, "[%s %s, %d] %s\n", set.c_str(), name.c_str(), size, what);
    };

    // Silhouettes from the full picture's hit objects; the subset camera's own hits as a check.
    Camera cam = *scene.camera;
    cam.width = size;
    cam.height = size;
    progress("hit objects");
    // Pixels whose point is within 4 strata of the light, where stratified area sampling is
    // skewed (see the top of the file), from the reference's own viewing rays.
    constexpr double kNearStrata = 4.0;
    std::vector<uint8_t> nearLight;
    const std::vector<int> ids =
        objectIds(scene, cam, args.threads, smp.full() ? &nearLight : nullptr, args.refSamples,
                  kNearStrata);
    Scene refScene = scene;  // shares the level sets
    if (!smp.full()) {
        const double half = std::tan(rad(0.5 * cam.fovDeg));
        refScene.camera->fovDeg =
            2.0 * deg(std::atan(double(smp.stride) * smp.count / size * half));
    }
    Camera subCam = *refScene.camera;
    subCam.width = smp.count;
    subCam.height = smp.count;
    size_t idMismatch = 0;
    if (!smp.full()) {
        const std::vector<int> subIds =
            objectIds(refScene, subCam, args.threads, &nearLight, args.refSamples, kNearStrata);
        for (int y = 0; y < smp.count; ++y) {
            for (int x = 0; x < smp.count; ++x) {
                idMismatch += subIds[size_t(y) * smp.count + x] !=
                              ids[size_t(smp.offset + smp.stride * y) * size +
                                  size_t(smp.offset + smp.stride * x)];
            }
        }
    }
    Comparison cmp;
    cmp.sampling = smp;
    cmp.silhouette.assign(size_t(smp.count) * smp.count, 0);
    size_t silhouettePixels = 0;
    for (int j = 0; j < smp.count; ++j) {
        for (int i = 0; i < smp.count; ++i) {
            const int x = smp.offset + smp.stride * i, y = smp.offset + smp.stride * j;
            const int id = ids[size_t(y) * size + x];
            bool edge = false;
            for (int dy = -1; dy <= 1 && !edge; ++dy) {
                for (int dx = -1; dx <= 1; ++dx) {
                    const int xx = x + dx, yy = y + dy;
                    if (xx < 0 || yy < 0 || xx >= size || yy >= size) continue;
                    if (ids[size_t(yy) * size + xx] != id) {
                        edge = true;
                        break;
                    }
                }
            }
            cmp.silhouette[size_t(j) * smp.count + i] = edge;
            silhouettePixels += edge;
        }
    }

    // Reference.
    progress("reference");
    RenderSettings refSettings = squareSettings(Method::Reference, smp.count, args.threads);
    refSettings.mc.samples = args.refSamples;
    refSettings.mc.seed = 0x5eed;
    const RenderResult ref = render(refScene, refSettings);
    cmp.ref = &ref.color;
    // The reference's own noise: a second one with another seed. Area sampling is weak where a
    // receiver is close to the light (the 1 / r^2 of the integrand): pixels where the two
    // disagree by more than 3 units are "uncertain".
    progress("reference #2");
    RenderSettings ref2Settings = refSettings;
    ref2Settings.mc.seed = 0x5eed + 1;
    const RenderResult ref2 = render(refScene, ref2Settings);
    cmp.uncertain.assign(size_t(smp.count) * smp.count, 0);
    size_t uncertainPixels = 0, nearPixels = 0, disagreePixels = 0;
    for (int y = 0; y < smp.count; ++y) {
        for (int x = 0; x < smp.count; ++x) {
            double worst = 0.0;
            for (int c = 0; c < 3; ++c) {
                worst = std::max(worst, 255.0 * std::abs(double(ref.color.at(x, y, c)) -
                                                         ref2.color.at(x, y, c)));
            }
            const size_t i = size_t(y) * smp.count + x;
            cmp.uncertain[i] = worst > 3.0 || nearLight[i];
            uncertainPixels += cmp.uncertain[i];
            nearPixels += nearLight[i];
            disagreePixels += worst > 3.0;
        }
    }

    // ACI at default settings: its mask and the reference's are the compared pixels.
    progress("aci");
    auto defaultAci = [&](int pixels) {
        RenderSettings rs = squareSettings(Method::Aci, pixels, args.threads);
        if (args.aciFixedSteps) rs.adaptiveSteps = false;
        return rs;
    };
    const RenderResult aci = timedRender(scene, defaultAci(size), args.repeat);
    cmp.mask = ref.aovs.mask;
    {
        const Image aciMask = sample(aci.aovs.mask, smp);
        for (size_t i = 0; i < cmp.mask.data.size(); ++i)
            cmp.mask.data[i] = std::max(cmp.mask.data[i], aciMask.data[i]);
    }
    size_t maskedPixels = 0;
    for (float v : cmp.mask.data) maskedPixels += v > 0.5f;
    // Alignment check: where no method cast rays both images are the closed form.
    double closedFormMax = 0.0;
    {
        const Image a = sample(aci.color, smp);
        for (int y = 0; y < a.height; ++y) {
            for (int x = 0; x < a.width; ++x) {
                if (cmp.mask.at(x, y) > 0.5f) continue;
                for (int c = 0; c < 3; ++c) {
                    closedFormMax = std::max(
                        closedFormMax, 255.0 * std::abs(double(a.at(x, y, c)) - ref.color.at(x, y, c)));
                }
            }
        }
    }
    const double aciSeconds = aci.stats.seconds;
    // ACI's fixed cost (mostly building the level sets' far-field distance companions, which
    // every render of the tangent mode does): the same render at 16 x 16 pixels.
    const double aciSetup =
        render(scene, defaultAci(16)).stats.seconds;

    // mc-solid-angle at ACI's time.
    progress("mc-solid-angle at aci's time");
    struct Try {
        int samples;
        double seconds;
    };
    std::vector<Try> tries;
    RenderResult bestMc;
    int bestSamples = 0;
    double bestGap = std::numeric_limits<double>::infinity();
    auto tryMc = [&](int n) {
        n = std::max(1, std::min(n, 1 << 20));
        for (const Try& t : tries) {
            if (t.samples == n) return false;  // already measured
        }
        RenderSettings rs = squareSettings(Method::McSolidAngle, size, args.threads);
        rs.mc.samples = n;
        RenderResult r = timedRender(scene, rs, args.repeat);
        tries.push_back({n, r.stats.seconds});
        const double gap = std::abs(std::log(std::max(1e-9, r.stats.seconds) / aciSeconds));
        if (gap < bestGap) {
            bestGap = gap;
            bestSamples = n;
            bestMc = std::move(r);
        }
        return true;
    };
    const int n0 = std::max(1, int(std::lround(aci.stats.shadowRaysPerViewingRay())));
    tryMc(n0);
    {
        const double t0 = tries[0].seconds;
        const double scale = std::clamp(aciSeconds / std::max(1e-9, t0), 1.0 / 64.0, 64.0);
        tryMc(int(std::lround(n0 * scale)));
    }
    // Further tries (at most 4 in all) while none is within 10% of ACI's time: the least-squares
    // line time = a + b samples through every try so far.
    while (tries.size() < 4 && bestGap > std::log(1.1)) {
        double sn = 0, st = 0, snn = 0, snt = 0;
        for (const Try& t : tries) {
            sn += t.samples;
            st += t.seconds;
            snn += double(t.samples) * t.samples;
            snt += t.samples * t.seconds;
        }
        const double k = double(tries.size());
        const double det = k * snn - sn * sn;
        const double slope = det > 0.0 ? (k * snt - sn * st) / det : 0.0;
        int next;
        if (slope > 0.0) {
            const double intercept = (st - slope * sn) / k;
            next = int(std::lround((aciSeconds - intercept) / slope));
        } else {
            next = int(std::lround(bestSamples * aciSeconds /
                                   std::max(1e-9, bestMc.stats.seconds)));
        }
        if (!tryMc(next)) break;  // that sample count was tried already
    }

    // The paper's estimator and the arcs mode.
    progress("aci paper, arcs");
    auto modeSettings = [&](AciMode mode) {
        RenderSettings rs = squareSettings(Method::Aci, size, args.threads);
        applyAciMode(rs.aci, mode);
        return rs;
    };
    const RenderResult paper = render(scene, modeSettings(AciMode::Paper));
    const RenderResult arcs = render(scene, modeSettings(AciMode::Arcs));

    if (args.saveImages) {
        const std::string stem = args.out + "/" + tag + "_" + std::to_string(size);
        writeImage(stem + "_reference.exr", ref.color);
        writeImage(stem + "_aci.exr", aci.color);
        writeImage(stem + "_aci.png", aci.color);
        writeImage(stem + "_mc_sa_time.exr", bestMc.color);
        writeImage(stem + "_aci_error.png", heatMap(differenceImage(sample(aci.color, smp), ref.color), 8.0f));
    }

    // Rows.
    std::string triesText;
    for (const Try& t : tries) {
        char b[64];
        std::snprintf(b, sizeof b, "%s%d samples %.2f s", triesText.empty() ? "" : ", ", t.samples,
                      t.seconds);
        triesText += b;
    }
    std::printf(
        "\n# %s %s at %d x %d: reference on %d x %d pixels (stride %d from pixel %d%s), %zu "
        "masked, %zu on silhouettes, %zu uncertain (%zu within %.0f strata of the light, %zu "
        "where the two references differ by more than 3 units); "
        "checks: %zu sampled pixels hit another object through the "
        "reference's camera, closed-form pixels differ by at most %.2g units; aci at 16 x 16 "
        "(its fixed cost) %.2f s; mc tries: %s\n",
        set.c_str(), name.c_str(), size, size, smp.count, smp.count, smp.stride, smp.offset,
        smp.full() ? ": every pixel" : "", maskedPixels, silhouettePixels, uncertainPixels,
        nearPixels, kNearStrata, disagreePixels,
        idMismatch,
        closedFormMax, aciSetup, triesText.c_str());
    if (args.adjudicateSamples > 0) {
        progress("aci's pixels over 6 units: per-pixel references");
        const Adjudication adj =
            adjudicate(scene, cam, aci.color, cmp, args.adjudicateSamples, args.threads);
        std::printf(
            "# aci's pixels over 6 units judged against two %d-ray references of their own: %zu "
            "judged, %zu still over 6 (largest %.2f), %zu where those two differ by more than 3%s%s\n",
            args.adjudicateSamples, adj.judged, adj.over, adj.worst, adj.unsettled,
            adj.overList.empty() ? "" : ": ", adj.overList.c_str());
    }
    const Metrics aciMetrics = measure(aci.color, cmp);
    // The paper's mode at default ACI's mean difference: finer settings in order of cost.
    RenderResult ladder;
    bool ladderReached = false;
    if (args.paperLadder) {
        progress("aci paper at aci's mean");
        constexpr double kLadderTimeCap = 16.0;  // stop once a render takes this many ACI times
        const std::pair<int, int> settings[] = {{2, 6}, {4, 5}, {4, 6}, {8, 5},
                                                {8, 6}, {16, 5}, {16, 6}};
        std::string text;
        if (measure(paper.color, cmp).mean <= aciMetrics.mean) {  // already at its own settings
            ladder = paper;
            ladderReached = true;
            text = "grid 2 steps 5 (the aci-paper row)";
        }
        for (const auto& [grid, steps] : settings) {
            if (ladderReached) break;
            RenderSettings rs = modeSettings(AciMode::Paper);
            rs.aci.grid = grid;
            rs.aci.steps = steps;
            ladder = render(scene, rs);
            const Metrics m = measure(ladder.color, cmp);
            const double ratio = ladder.stats.seconds / std::max(1e-9, aciSeconds);
            char b[96];
            std::snprintf(b, sizeof b, "%sgrid %d steps %d: %.2f s (t/aci %.2f), mean %.3f",
                          text.empty() ? "" : "; ", grid, steps, ladder.stats.seconds, ratio,
                          m.mean);
            text += b;
            if (m.mean <= aciMetrics.mean) {
                ladderReached = true;
                break;
            }
            if (ratio > kLadderTimeCap) break;
        }
        std::printf("# paper's mode at aci's mean %.3f: %s; %s\n", aciMetrics.mean,
                    ladderReached ? "reached" : "NOT reached", text.c_str());
    }
    auto makeRow = [&](const std::string& method, const RenderResult& r, int samples) {
        Row row;
        row.set = set;
        row.scene = name;
        row.size = size;
        row.method = method;
        row.samples = samples;
        row.raysPerVr = r.stats.shadowRaysPerViewingRay();
        row.seconds = r.stats.seconds;
        row.timeRatio = r.stats.seconds / std::max(1e-9, aciSeconds);
        // The references at a stride > 1 are rendered on the compared pixels only (M x M):
        // the first is not measured, the second against the first below.
        if (&r == &aci) {
            row.m = aciMetrics;
        } else if (r.color.width == cmp.sampling.size) {
            row.m = measure(r.color, cmp);
        }
        row.diffOverAci = aciMetrics.mean > 0 ? row.m.mean / aciMetrics.mean : 0.0;
        return row;
    };
    Row refRow = makeRow("reference", ref, args.refSamples);
    refRow.isReference = true;
    // The second reference, rendered on the compared pixels only, against the first.
    Row ref2Row = makeRow("reference #2", ref2, args.refSamples);
    {
        Comparison self = cmp;
        self.sampling = makeSampling(smp.count, 1);
        ref2Row.m = measure(ref2.color, self);
        ref2Row.diffOverAci = aciMetrics.mean > 0 ? ref2Row.m.mean / aciMetrics.mean : 0.0;
    }
    std::vector<Row> rows{refRow, ref2Row, makeRow("aci", aci, 0), makeRow("aci-paper", paper, 0),
                          makeRow("aci-arcs", arcs, 0),
                          makeRow("mc-sa@aci-time", bestMc, bestSamples)};
    if (args.paperLadder) {
        rows.push_back(makeRow("paper@aci-mean", ladder, 0));
        rows.back().reached = ladderReached;
    }
    for (const Row& r : rows) {
        printRow(r);
        ctx.rows.push_back(r);
    }
}

void runScene(Context& ctx, const Scene& scene, const std::string& set, const std::string& name,
              const std::string& tag, const std::vector<int>& sizes) {
    for (int size : sizes) {
        try {
            runSceneAtSize(ctx, scene, set, name, tag, size);
        } catch (const std::exception& e) {
            std::printf("# %s %s at %d: FAILED: %s\n", set.c_str(), name.c_str(), size, e.what());
            ctx.failures.push_back(set + " " + name + " at " + std::to_string(size) + ": " +
                                   e.what());
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Summary

double geomean(const std::vector<double>& v) {
    double s = 0.0;
    size_t n = 0;
    for (double x : v) {
        if (x > 0.0 && std::isfinite(x)) {
            s += std::log(x);
            ++n;
        }
    }
    return n ? std::exp(s / double(n)) : 0.0;
}

void printSummary(const Context& ctx) {
    std::map<std::tuple<std::string, int, std::string>, std::vector<const Row*>> groups;
    const std::vector<std::string> order{"reference #2", "aci", "aci-paper", "aci-arcs",
                                         "mc-sa@aci-time", "paper@aci-mean"};
    for (const Row& r : ctx.rows) {
        if (!r.isReference) groups[{r.set, r.size, r.method}].push_back(&r);
    }
    std::printf(
        "\nSummary per method (geometric means over the scenes of rays/VR, t/aci, mean and "
        "diff/aci; diff/aci = the mean difference over default ACI's in the same scene and size; "
        "for mc-sa@aci-time the smallest diff/aci is ACI's worst case; worst = largest mean and "
        "largest max difference over the scenes)\n");
    std::printf("%-8s %5s  %-15s %6s %9s %7s %8s %9s  %-20s %-20s %-20s %-20s %-20s %s\n",
                "set", "size", "method", "scenes", "rays/VR", "t/aci", "mean", "diff/aci",
                "smallest diff/aci", "largest diff/aci", "worst mean", "worst max",
                "worst max*", ">6 (sil, ref?)");
    for (const std::string set : {"random", "gallery"}) {
        std::vector<int> sizes;
        for (const auto& entry : groups) {
            const auto& key = entry.first;
            if (std::get<0>(key) == set &&
                std::find(sizes.begin(), sizes.end(), std::get<1>(key)) == sizes.end())
                sizes.push_back(std::get<1>(key));
        }
        std::sort(sizes.begin(), sizes.end());
        for (int size : sizes) {
            for (const std::string& method : order) {
                auto it = groups.find({set, size, method});
                if (it == groups.end()) continue;
                const auto& rows = it->second;
                std::vector<double> rays, times, means, ratios;
                const Row* minRatio = nullptr;
                const Row* maxRatio = nullptr;
                const Row* worstMean = nullptr;
                const Row* worstMax = nullptr;
                const Row* worstMaxCertain = nullptr;
                size_t over = 0, overSil = 0, overUncertain = 0;
                for (const Row* r : rows) {
                    rays.push_back(r->raysPerVr);
                    times.push_back(r->timeRatio);
                    means.push_back(r->m.mean);
                    if (r->diffOverAci > 0.0) {
                        ratios.push_back(r->diffOverAci);
                        if (!minRatio || r->diffOverAci < minRatio->diffOverAci) minRatio = r;
                        if (!maxRatio || r->diffOverAci > maxRatio->diffOverAci) maxRatio = r;
                    }
                    if (!worstMean || r->m.mean > worstMean->m.mean) worstMean = r;
                    if (!worstMax || r->m.max > worstMax->m.max) worstMax = r;
                    if (!worstMaxCertain || r->m.maxCertain > worstMaxCertain->m.maxCertain)
                        worstMaxCertain = r;
                    over += r->m.over;
                    overSil += r->m.overSilhouette;
                    overUncertain += r->m.overUncertain;
                }
                auto at = [](const Row* r, double v, const char* format) {
                    if (!r) return std::string("-");
                    char b[64];
                    std::snprintf(b, sizeof b, format, v, r->scene.c_str());
                    return std::string(b);
                };
                std::printf("%-8s %5d  %-15s %6zu %9.2f %7.2f %8.3f %9.2f  %-20s %-20s %-20s "
                            "%-20s %-20s %zu (%zu, %zu)\n",
                            set.c_str(), size, method.c_str(), rows.size(), geomean(rays),
                            geomean(times), geomean(means), geomean(ratios),
                            at(minRatio, minRatio ? minRatio->diffOverAci : 0, "%.2f (%s)").c_str(),
                            at(maxRatio, maxRatio ? maxRatio->diffOverAci : 0, "%.2f (%s)").c_str(),
                            at(worstMean, worstMean->m.mean, "%.3f (%s)").c_str(),
                            at(worstMax, worstMax->m.max, "%.1f (%s)").c_str(),
                            at(worstMaxCertain, worstMaxCertain->m.maxCertain, "%.1f (%s)").c_str(),
                            over, overSil, overUncertain);
                if (method == "paper@aci-mean") {
                    std::vector<double> reachedTimes;
                    const Row* fastest = nullptr;
                    const Row* slowest = nullptr;
                    for (const Row* r : rows) {
                        if (!r->reached) continue;
                        reachedTimes.push_back(r->timeRatio);
                        if (!fastest || r->timeRatio < fastest->timeRatio) fastest = r;
                        if (!slowest || r->timeRatio > slowest->timeRatio) slowest = r;
                    }
                    std::printf("%-8s %5d  %-15s reached aci's mean on %zu of %zu scenes; t/aci "
                                "there: geometric mean %.2f, smallest %s, largest %s\n",
                                set.c_str(), size, "", reachedTimes.size(), rows.size(),
                                geomean(reachedTimes),
                                at(fastest, fastest ? fastest->timeRatio : 0, "%.2f (%s)").c_str(),
                                at(slowest, slowest ? slowest->timeRatio : 0, "%.2f (%s)").c_str());
                }
            }
        }
    }
}

}  // namespace

int main(int argc, char** argv) {
    const Args args = parseArgs(argc, argv);
    const auto start = std::chrono::steady_clock::now();
    try {
        fs::create_directories(args.out);
        std::string sizesText, galleryText;
        for (int s : args.sizes) sizesText += (sizesText.empty() ? "" : ",") + std::to_string(s);
        for (int s : args.gallerySizes)
            galleryText += (galleryText.empty() ? "" : ",") + std::to_string(s);
        std::printf(
            "bench_random: seeds %llu..%llu at sizes %s, gallery (%s) at %s; %d threads; "
            "reference: stratified area sampling, %d rays per viewing ray; scenes in %s\n",
            static_cast<unsigned long long>(args.firstSeed),
            static_cast<unsigned long long>(args.firstSeed + uint64_t(std::max(0, args.seeds - 1))),
            sizesText.empty() ? "none" : sizesText.c_str(), args.galleryDir.c_str(),
            galleryText.empty() ? "none" : galleryText.c_str(), args.threads, args.refSamples,
            args.out.c_str());
        const std::string strideText =
            args.refStride > 0 ? "every " + std::to_string(args.refStride) +
                                     "th row and column at every size (--ref-stride)"
                               : "every pixel up to 400 x 400; above, every 3rd row and column";
        std::printf(
            "Compared pixels: %s. The reference is rendered only on those pixels, through a\n"
            "  field of view narrowed so that they keep exactly their viewing rays; every other\n"
            "  method renders the full picture and is compared there. A second reference with\n"
            "  another seed (row 'reference #2', compared with the first) shows the reference's\n"
            "  own noise. 'Uncertain' pixels: where the two differ by more than 3 units, or whose\n"
            "  point is closer to the light than 4 strata of the reference (4 x the light's longer\n"
            "  edge / sqrt(samples)), where stratified area sampling is skewed.\n"
            "Columns: samples (Monte Carlo rays per estimate); rays/VR = shadow rays per viewing\n"
            "  ray over the pixels where the method cast shadow rays (the references: over the\n"
            "  pixels they rendered, as are their seconds); seconds = the render's wall time;\n"
            "  t/aci = over default ACI's. Differences against the reference, in 8-bit units (255 x\n"
            "  linear, not clipped): mean = over the masked pixels (where the reference or default\n"
            "  ACI cast shadow rays), all = mean over every compared pixel, max = largest over every\n"
            "  compared pixel and channel, max* = the same without the uncertain pixels; >6 =\n"
            "  compared pixels off by more than 6 units in some channel, sil = of which on a\n"
            "  silhouette (3 x 3 neighbourhood with several hit objects, from viewing rays the\n"
            "  benchmark casts itself: the renderer has no object-id AOV), ref? = of which\n"
            "  uncertain; diff/aci = mean over default ACI's mean.\n"
            "mc-sa@aci-time: mc-solid-angle with its samples set so that its wall time matches\n"
            "  default ACI's in the same run (t/aci is the achieved ratio).\n",
            strideText.c_str());
        if (args.aciFixedSteps)
            std::printf("The \"aci\" rows: --aci-fixed-steps (no adaptive steps).\n");
        Context ctx{args, {}, {}};
        std::printf("\n");
        printTableHeader();

        for (int i = 0; i < args.seeds; ++i) {
            const uint64_t seed = args.firstSeed + uint64_t(i);
            const Generated g = generateScene(seed, args.lights, args.fog, args.lightScale);
            const std::string path = args.out + "/seed_" + std::to_string(seed) + ".json";
            {
                std::ofstream f(path);
                f << g.json;
                if (!f) throw std::runtime_error("cannot write " + path);
            }
            const std::string name = "seed " + std::to_string(seed);
            std::printf("\n# %s (%s): %s\n", name.c_str(), path.c_str(), g.description.c_str());
            try {
                const Scene scene =
                    parseScene(g.json, path, fs::path(path).parent_path().string());
                std::printf("# level sets built in %.2f s, %llu active voxels\n",
                            scene.build.seconds,
                            static_cast<unsigned long long>(scene.build.activeVoxels()));
                if (!args.sizes.empty()) printTableHeader();
                runScene(ctx, scene, "random", name, "seed_" + std::to_string(seed), args.sizes);
            } catch (const std::exception& e) {
                std::printf("# %s: REFUSED: %s\n", name.c_str(), e.what());
                ctx.failures.push_back(name + ": " + e.what());
            }
        }

        if (!args.gallerySizes.empty()) {
            for (const std::string& stem : args.gallery) {
                const std::string path = args.galleryDir + "/" + stem + ".json";
                std::printf("\n# gallery %s (%s)\n", stem.c_str(), path.c_str());
                try {
                    const Scene scene = loadScene(path);
                    printTableHeader();
                    runScene(ctx, scene, "gallery", stem, "gallery_" + stem, args.gallerySizes);
                } catch (const std::exception& e) {
                    std::printf("# gallery %s: FAILED: %s\n", stem.c_str(), e.what());
                    ctx.failures.push_back("gallery " + stem + ": " + e.what());
                }
            }
        }

        printSummary(ctx);
        for (const std::string& f : ctx.failures) std::printf("failure: %s\n", f.c_str());
        const double total =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        std::printf("\ntotal wall time %.1f s\n", total);
    } catch (...) {
        return bench::reportException("bench_random");
    }
    return 0;
}
