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
//
// Defaults: 10 seeds from 1, sizes 200 and 800, 2 threads, gallery at 200 only, reference 4096
// rays, --out /tmp/penumbra_random (each seed's scene is written there as seed_S.json before it
// is parsed: `penumbra render /tmp/penumbra_random/seed_S.json -o x.png --width 200 --height 200`
// reproduces it). --gallery-dir defaults to ./vdb_scenes, else the source tree's. --save-images
// also writes there, per scene and size, the reference, default ACI and mc-solid-angle at ACI's
// time (.exr), ACI's picture (.png) and its error map on the compared pixels (.png; black 0,
// blue 2, red 4, yellow 6, white 8 or more units).
//
// ---------------------------------------------------------------------------------------------
// The generator (seed s; every draw from one splitmix64 stream seeded with s, uniform draws
// U(a, b) from its top 53 bits, so a seed gives the same scene on any platform):
//
//  - level_set.voxel_size U(0.01, 0.02) (rounded to 1e-4), half_width 3.
//  - One rectangular light: edges a, b ~ U(0.5, 3) (independently: rarely square), emitting
//    normal n tilted from straight down by U(0, 60) degrees towards a uniform azimuth, spun
//    in its plane by a uniform angle, redrawn until no edge is within 5 degrees of a world axis;
//    edge_u x edge_v = n, so it faces the receiver. Centre (U(-0.5, 0.5), U(-0.5, 0.5), h),
//    h ~ U(2.5, 5). Grey radiance chosen so that the unoccluded ground right below the light's
//    centre reads about 0.65 (0.8 albedo x radiance x F, F by the point-source approximation
//    a b cos(tilt) / (pi h^2)), like vdb_scenes/table1.json: 8-bit differences are comparable
//    across scenes. Obstacle faces close to the light are much brighter (values above 1 are kept:
//    differences are linear, not clipped).
//  - One receiver plane z = 0 (normal +z, albedo 0.8).
//  - 1 to 8 obstacles (uniform count); their kinds cycle through a random permutation of sphere,
//    box, torus, capsule, cylinder (so a scene with 5 or more has every kind). A sphere or box is
//    `"analytic": true` with probability 0.3 (analytic boxes stay axis-aligned, as the format
//    requires); everything else is a level set. Overall size D = L x 10^U(log10 0.02, log10 0.4)
//    (log-uniform from 2% to 40% of the light's longer edge L): sphere radius D/2; box sizes
//    D x U(0.25, 1) per axis with the largest set to D, turned by rotate_deg of three U(0, 360)
//    angles (level sets); torus minor radius D/2 x U(0.12, 0.35), major D/2 - minor, uniform
//    axis; capsule radius D/2 x U(0.12, 0.45), segment D - 2 radius along a uniform direction;
//    cylinder radius D/2 x U(0.15, 0.6), height D x U(0.3, 1), uniform axis. Level-set radii are
//    raised to at least 2 voxels and full sizes and heights to 3 (the format needs 1.5 voxels):
//    at small lights and coarse voxels the smallest level-set obstacles are therefore larger
//    than 2% of the edge (analytic ones are not raised). Albedo U(0.35, 0.85) per channel.
//  - Placement: a point of the light's plane at light coordinates (u, v) ~ U(-0.25, 1.25)^2, then
//    a horizontal offset uniform in a disc of radius 0.3 L + 0.3; the height is drawn in the
//    interval where the obstacle's exact extent (support function of the turned shape) stays at
//    least 0.005 above the plane and at least 0.03 from the light's plane on its emitting side:
//    one third of the obstacles "near the plane" (gap to the plane U(0.005, 0.105)), one third
//    "near the light" (gap to the light's plane U(0.03, 0.13), measured along n), one third
//    uniform in between. An empty interval redraws the point (every 40 redraws shrink D by 0.7).
//    Obstacles may overlap each other. The obstacles are receivers too (shaded with their
//    normals).
//  - Camera: fov 40 degrees, up +z, elevation U(35, 65) degrees above the horizon and a uniform
//    azimuth; look_at the centre of the bounding box of the obstacles' bounding spheres and of
//    their shadows on the plane (a disc around the centre projected from the light's centre,
//    kept within 2.5 of the obstacle's foot, radius the projected bounding radius plus half the
//    penumbra width, capped at 0.75); the eye as close as keeps every such sphere and disc, and
//    a sphere of radius 0.6 around look_at, inside the square view with 8% to spare.
//    The plane fills the picture; the light itself is not seen (lights are not rendered).
//
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
#include "penumbra/camera.h"
#include "penumbra/compare.h"
#include "penumbra/contour_integrator.h"
#include "penumbra/error.h"
#include "penumbra/image_io.h"
#include "penumbra/renderer.h"
#include "penumbra/scene.h"

using namespace penumbra;
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
    int repeat = 1;  // timed renders (ACI, each mc try) run this many times, the fastest kept
};

[[noreturn]] void usage(const std::string& message) {
    std::fprintf(stderr, "bench_random: %s\n", message.c_str());
    std::fprintf(stderr,
                 "usage: bench_random [--seeds N] [--first-seed S] [--sizes 200,800] "
                 "[--threads N] [--gallery-size 200[,800]|0] [--gallery-dir DIR] [--gallery a,b] "
                 "[--ref-samples N] [--ref-stride S] [--repeat N] [--out DIR] [--save-images]\n");
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
        else if (s == "--help" || s == "-h") usage("seeded random scenes: ACI against Monte Carlo");
        else usage("unknown option " + s);
    }
    if (a.seeds < 0) usage("--seeds must be >= 0");
    if (a.threads < 1) usage("--threads must be >= 1");
    if (a.refSamples < 1) usage("--ref-samples must be >= 1");
    if (a.repeat < 1) usage("--repeat must be >= 1");
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
// Random numbers: splitmix64, platform independent (std:: distributions are not).

struct Rng {
    uint64_t state;
    // The seed goes through the mixer first, so that seeds s and s + 1 give unrelated streams.
    explicit Rng(uint64_t seed) : state(seed) { state = next() ^ 0x6A09E667F3BCC909ull; }
    uint64_t next() {
        uint64_t z = (state += 0x9E3779B97F4A7C15ull);
        z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
        z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
        return z ^ (z >> 31);
    }
    double uniform() { return double(next() >> 11) * (1.0 / 9007199254740992.0); }
    double uniform(double a, double b) { return a + (b - a) * uniform(); }
    int below(int n) { return std::min(n - 1, int(uniform() * n)); }
    Vec3 unitVector() {
        const double z = uniform(-1.0, 1.0), phi = uniform(0.0, 2.0 * kPi);
        const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
        return Vec3(r * std::cos(phi), r * std::sin(phi), z);
    }
};

double deg(double radians) { return radians * 180.0 / kPi; }
double rad(double degrees) { return degrees * kPi / 180.0; }

std::string num(double v) {
    char b[32];
    std::snprintf(b, sizeof b, "%.6g", std::abs(v) < 1e-12 ? 0.0 : v);
    return b;
}
std::string vec(const Vec3& v) { return "[" + num(v.x) + ", " + num(v.y) + ", " + num(v.z) + "]"; }
// Round-trip precision, for the light: mc-solid-angle needs edge_u perpendicular to edge_v to
// 1e-9, which 6 digits would break.
std::string vecExact(const Vec3& v) {
    char b[96];
    std::snprintf(b, sizeof b, "[%.17g, %.17g, %.17g]", v.x, v.y, v.z);
    return b;
}

// ---------------------------------------------------------------------------------------------
// The scene generator (documented at the top of the file).

enum Kind { Sphere, Box, Torus, Capsule, Cylinder };
const char* kKindNames[] = {"sphere", "box", "torus", "capsule", "cylinder"};

struct GenObstacle {
    Kind kind = Sphere;
    bool analytic = false;
    Vec3 center{0.0};
    double radius = 0.0;       // sphere, torus minor, capsule, cylinder
    double major = 0.0;        // torus
    Vec3 size{0.0};            // box (full extents)
    Vec3 rotateDeg{0.0};       // box
    Mat3 rotation{1.0};        // box
    Vec3 axis{0.0, 0.0, 1.0};  // torus, cylinder axis; capsule direction
    double halfLength = 0.0;   // capsule half segment; cylinder half height
    double extent = 0.0;       // overall size D as drawn (after clamping)
    const char* mode = "";

    // Half-extent along unit direction d (support function; every shape is symmetric about
    // its centre).
    double support(const Vec3& d) const {
        switch (kind) {
            case Sphere: return radius;
            case Box: {
                double s = 0.0;
                for (int i = 0; i < 3; ++i) s += 0.5 * size[i] * std::abs(glm::dot(rotation[i], d));
                return s;
            }
            case Torus: {
                const double c = glm::dot(axis, d);
                return major * std::sqrt(std::max(0.0, 1.0 - c * c)) + radius;
            }
            case Capsule: return halfLength * std::abs(glm::dot(axis, d)) + radius;
            case Cylinder: {
                const double c = glm::dot(axis, d);
                return halfLength * std::abs(c) + radius * std::sqrt(std::max(0.0, 1.0 - c * c));
            }
        }
        return 0.0;
    }
    double boundingRadius() const {
        switch (kind) {
            case Sphere: return radius;
            case Box: return 0.5 * glm::length(size);
            case Torus: return major + radius;
            case Capsule: return halfLength + radius;
            case Cylinder: return std::sqrt(halfLength * halfLength + radius * radius);
        }
        return 0.0;
    }
};

Mat3 rotationFromDeg(const Vec3& r) {  // as the scene format: Rz * Ry * Rx (src/shape.cpp)
    const double cx = std::cos(rad(r.x)), sx = std::sin(rad(r.x));
    const double cy = std::cos(rad(r.y)), sy = std::sin(rad(r.y));
    const double cz = std::cos(rad(r.z)), sz = std::sin(rad(r.z));
    auto rows = [](const Vec3& a, const Vec3& b, const Vec3& c) {
        return glm::transpose(Mat3(a, b, c));
    };
    const Mat3 rx = rows(Vec3(1, 0, 0), Vec3(0, cx, -sx), Vec3(0, sx, cx));
    const Mat3 ry = rows(Vec3(cy, 0, sy), Vec3(0, 1, 0), Vec3(-sy, 0, cy));
    const Mat3 rz = rows(Vec3(cz, -sz, 0), Vec3(sz, cz, 0), Vec3(0, 0, 1));
    return rz * ry * rx;
}

struct Generated {
    std::string json;
    std::string description;
};

// Draws the obstacle's dimensions for overall size D.
void drawDimensions(GenObstacle& o, double D, double voxel, Rng& rng) {
    const double minR = o.analytic ? 1e-3 : 2.0 * voxel;   // radii
    const double minS = o.analytic ? 2e-3 : 3.0 * voxel;   // full sizes, heights
    switch (o.kind) {
        case Sphere: o.radius = std::max(minR, 0.5 * D); break;
        case Box: {
            for (int i = 0; i < 3; ++i) o.size[i] = D * rng.uniform(0.25, 1.0);
            int big = 0;
            for (int i = 1; i < 3; ++i) if (o.size[i] > o.size[big]) big = i;
            o.size[big] = D;
            for (int i = 0; i < 3; ++i) o.size[i] = std::max(minS, o.size[i]);
            if (!o.analytic) {
                o.rotateDeg = Vec3(rng.uniform(0, 360), rng.uniform(0, 360), rng.uniform(0, 360));
            } else {
                o.rotateDeg = Vec3(0.0);
            }
            o.rotation = rotationFromDeg(o.rotateDeg);
            break;
        }
        case Torus: {
            o.radius = std::max(minR, 0.5 * D * rng.uniform(0.12, 0.35));
            o.major = std::max(0.5 * D - o.radius, 1.5 * o.radius);
            o.axis = rng.unitVector();
            break;
        }
        case Capsule: {
            o.radius = std::max(minR, 0.5 * D * rng.uniform(0.12, 0.45));
            o.halfLength = std::max(0.0, 0.5 * D - o.radius);
            o.axis = rng.unitVector();
            break;
        }
        case Cylinder: {
            o.radius = std::max(minR, 0.5 * D * rng.uniform(0.15, 0.6));
            o.halfLength = 0.5 * std::max(minS, D * rng.uniform(0.3, 1.0));
            o.axis = rng.unitVector();
            break;
        }
    }
    o.extent = 2.0 * o.boundingRadius();
}

Generated generateScene(uint64_t seed) {
    Rng rng(seed);
    const double voxel = std::round(rng.uniform(0.01, 0.02) * 10000.0) / 10000.0;

    // The light.
    const double a = rng.uniform(0.5, 3.0), b = rng.uniform(0.5, 3.0);
    const double tilt = rad(rng.uniform(0.0, 60.0)), azimuth = rng.uniform(0.0, 2.0 * kPi);
    const Vec3 n(std::sin(tilt) * std::cos(azimuth), std::sin(tilt) * std::sin(azimuth),
                 -std::cos(tilt));  // emitting side
    const Vec3 helper = std::abs(n.x) < 0.9 ? Vec3(1, 0, 0) : Vec3(0, 1, 0);
    const Vec3 t1 = glm::normalize(helper - n * glm::dot(n, helper));
    const Vec3 t2 = glm::cross(n, t1);
    Vec3 e1, e2;
    double spin = 0.0;
    for (int tries = 0; tries < 1000; ++tries) {
        spin = rng.uniform(0.0, 2.0 * kPi);
        e1 = std::cos(spin) * t1 + std::sin(spin) * t2;
        e2 = glm::cross(n, e1);  // cross(e1, e2) = n
        bool aligned = false;
        for (const Vec3& e : {e1, e2}) {
            for (int k = 0; k < 3; ++k) aligned |= std::abs(e[k]) > std::cos(rad(5.0));
        }
        if (!aligned) break;
    }
    const double h = rng.uniform(2.5, 5.0);
    const Vec3 lightCenter(rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), h);
    const Vec3 edgeU = a * e1, edgeV = b * e2;
    const Vec3 corner = lightCenter - 0.5 * edgeU - 0.5 * edgeV;
    const double f0 = a * b * std::cos(tilt) / (kPi * h * h);
    const double radiance = std::round(0.65 / (0.8 * f0) * 1000.0) / 1000.0;
    const double L = std::max(a, b);

    // The obstacles.
    const int count = 1 + rng.below(8);
    int perm[5] = {0, 1, 2, 3, 4};
    for (int i = 4; i > 0; --i) std::swap(perm[i], perm[rng.below(i + 1)]);
    std::vector<GenObstacle> obstacles;
    for (int i = 0; i < count; ++i) {
        GenObstacle o;
        o.kind = Kind(perm[i % 5]);
        o.analytic = (o.kind == Sphere || o.kind == Box) && rng.uniform() < 0.3;
        double D = L * std::pow(10.0, rng.uniform(std::log10(0.02), std::log10(0.4)));
        const int mode = rng.below(3);
        o.mode = mode == 0 ? "near plane" : mode == 1 ? "near light" : "between";
        drawDimensions(o, D, voxel, rng);
        bool placed = false;
        for (int attempt = 0; attempt < 400 && !placed; ++attempt) {
            if (attempt > 0 && attempt % 40 == 0) {
                D *= 0.7;
                drawDimensions(o, D, voxel, rng);
            }
            const Vec3 onLight = corner + rng.uniform(-0.25, 1.25) * edgeU +
                                 rng.uniform(-0.25, 1.25) * edgeV;
            const double r = (0.3 * L + 0.3) * std::sqrt(rng.uniform());
            const double phi = rng.uniform(0.0, 2.0 * kPi);
            const double x = onLight.x + r * std::cos(phi), y = onLight.y + r * std::sin(phi);
            // Centre height: above the plane by the extent along z plus 0.005; on the emitting
            // side of the light's plane by the extent along n plus 0.03 (n.z < 0, so the signed
            // distance dot(c - lightCenter, n) falls as z grows).
            const double zLo = o.support(Vec3(0, 0, 1)) + 0.005;
            const double dxy = (x - lightCenter.x) * n.x + (y - lightCenter.y) * n.y;
            const double zHi = lightCenter.z + (o.support(n) + 0.03 - dxy) / n.z;
            if (!(zHi > zLo)) continue;
            const double room = zHi - zLo;
            double z;
            if (mode == 0) {
                z = zLo + rng.uniform(0.0, std::min(0.1, room));
            } else if (mode == 1) {
                // Along n a vertical move dz changes the distance by |n.z| dz.
                z = zHi - rng.uniform(0.0, std::min(0.1 / std::abs(n.z), room));
            } else {
                z = rng.uniform(zLo, zHi);
            }
            o.center = Vec3(x, y, z);
            placed = true;
        }
        if (!placed) continue;  // (never seen: the light is at least 0.66 above the plane)
        obstacles.push_back(o);
    }

    // The camera: frame the obstacles and their shadows.
    struct Item {
        Vec3 c;
        double r;
    };
    std::vector<Item> items;
    Box3 roi;
    for (const GenObstacle& o : obstacles) {
        const double rb = o.boundingRadius();
        items.push_back({o.center, rb});
        const double denom = std::max(1e-3, lightCenter.z - o.center.z);
        const double scale = lightCenter.z / denom;
        Vec3 g = lightCenter + (o.center - lightCenter) * scale;
        g.z = 0.0;
        const Vec3 foot(o.center.x, o.center.y, 0.0);
        if (glm::length(g - foot) > 2.5) g = foot + (g - foot) * (2.5 / glm::length(g - foot));
        const double rs = std::min(0.75, rb * scale + 0.5 * L * o.center.z / denom);
        items.push_back({g, rs});
    }
    for (const Item& it : items) {
        roi.extend(it.c - Vec3(it.r));
        roi.extend(it.c + Vec3(it.r));
    }
    const Vec3 lookAt = 0.5 * (roi.lo + roi.hi);
    items.push_back({lookAt, 0.6});  // frame at least 0.6 around the centre
    const double fov = 40.0, half = rad(0.5 * fov);
    const double elevation = rad(rng.uniform(35.0, 65.0)), camAz = rng.uniform(0.0, 2.0 * kPi);
    const Vec3 w(std::cos(elevation) * std::cos(camAz), std::cos(elevation) * std::sin(camAz),
                 std::sin(elevation));  // from look_at towards the eye
    const Vec3 right = glm::normalize(glm::cross(-w, Vec3(0, 0, 1)));
    const Vec3 upv = glm::cross(right, -w);
    double dist = 0.0;
    for (const Item& it : items) {
        // The item's sphere inside the square view cone: lateral offset plus r / cos(half)
        // within (distance along the axis) x tan(half), with 8% to spare.
        const Vec3 q = it.c - lookAt;
        const double lateral = std::max(std::abs(glm::dot(q, right)), std::abs(glm::dot(q, upv)));
        dist = std::max(dist, glm::dot(q, w) + 1.08 * (lateral + it.r / std::cos(half)) /
                                                   std::tan(half));
    }
    const Vec3 eye = lookAt + dist * w;

    // JSON.
    std::ostringstream js;
    js << "// bench_random seed " << seed << " (bench/bench_random.cpp documents the generator)\n";
    js << "{\n  \"camera\": {\"eye\": " << vec(eye) << ", \"look_at\": " << vec(lookAt)
       << ", \"up\": [0, 0, 1], \"fov_deg\": " << num(fov) << ", \"width\": 800, \"height\": 800},\n";
    js << "  \"lights\": [\n    {\"name\": \"key\", \"corner\": " << vecExact(corner)
       << ",\n     \"edge_u\": " << vecExact(edgeU) << ",\n     \"edge_v\": " << vecExact(edgeV)
       << ",\n     \"radiance\": "
       << vec(Vec3(radiance)) << "}\n  ],\n";
    js << "  \"obstacles\": [\n";
    std::ostringstream desc;
    char line[256];
    std::snprintf(line, sizeof line,
                  "light %.2f x %.2f at height %.2f, tilt %.1f deg, spin %.1f deg, radiance %.3g; "
                  "voxel %.4f; %zu obstacles:",
                  a, b, h, deg(tilt), deg(spin), radiance, voxel, obstacles.size());
    desc << line;
    for (size_t i = 0; i < obstacles.size(); ++i) {
        const GenObstacle& o = obstacles[i];
        const std::string name =
            std::string(kKindNames[o.kind]) + "_" + std::to_string(i) + (o.analytic ? "_analytic" : "");
        Rng albedoRng(seed * 1000003ull + i);
        const Vec3 albedo(albedoRng.uniform(0.35, 0.85), albedoRng.uniform(0.35, 0.85),
                          albedoRng.uniform(0.35, 0.85));
        js << "    {\"name\": \"" << name << "\", \"type\": \"" << kKindNames[o.kind] << "\", ";
        switch (o.kind) {
            case Sphere:
                js << "\"center\": " << vec(o.center) << ", \"radius\": " << num(o.radius);
                break;
            case Box:
                if (o.analytic) {
                    js << "\"center\": " << vec(o.center) << ", \"size\": " << vec(o.size);
                } else {
                    js << "\"center\": [0, 0, 0], \"size\": " << vec(o.size)
                       << ",\n     \"transform\": {\"rotate_deg\": " << vec(o.rotateDeg)
                       << ", \"translate\": " << vec(o.center) << "}";
                }
                break;
            case Torus:
                js << "\"center\": " << vec(o.center) << ", \"major_radius\": " << num(o.major)
                   << ", \"minor_radius\": " << num(o.radius) << ", \"axis\": " << vec(o.axis);
                break;
            case Capsule:
                js << "\"a\": " << vec(o.center - o.halfLength * o.axis)
                   << ", \"b\": " << vec(o.center + o.halfLength * o.axis)
                   << ", \"radius\": " << num(o.radius);
                break;
            case Cylinder:
                js << "\"center\": " << vec(o.center) << ", \"axis\": " << vec(o.axis)
                   << ", \"radius\": " << num(o.radius)
                   << ", \"height\": " << num(2.0 * o.halfLength);
                break;
        }
        if (o.analytic) js << ", \"analytic\": true";
        js << ",\n     \"albedo\": " << vec(albedo) << "}" << (i + 1 < obstacles.size() ? "," : "")
           << "\n";
        const double gapPlane = o.center.z - o.support(Vec3(0, 0, 1));
        const double gapLight = glm::dot(o.center - lightCenter, n) - o.support(n);
        std::snprintf(line, sizeof line, " %s %.3f (%.0f%% of L, %s, gaps %.3f/%.3f)",
                      (std::string(kKindNames[o.kind]) + (o.analytic ? "*" : "")).c_str(),
                      o.extent, 100.0 * o.extent / L, o.mode, gapPlane, gapLight);
        desc << line << (i + 1 < obstacles.size() ? ";" : "");
    }
    js << "  ],\n";
    js << "  \"receivers\": [{\"type\": \"plane\", \"point\": [0, 0, 0], \"normal\": [0, 0, 1], "
          "\"albedo\": [0.8, 0.8, 0.8]}],\n";
    js << "  \"level_set\": {\"voxel_size\": " << num(voxel) << ", \"half_width\": 3},\n";
    js << "  \"background\": [0, 0, 0]\n}\n";
    return {js.str(), desc.str()};
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
    std::string method;  // "reference", "aci", "aci-paper", "aci-arcs", "mc-sa@aci-time"
    int samples = 0;
    double raysPerVr = 0.0, seconds = 0.0, timeRatio = 0.0;
    Metrics m;
    double diffOverAci = 0.0;
    bool isReference = false;
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
    const RenderResult aci = timedRender(scene, squareSettings(Method::Aci, size, args.threads),
                                         args.repeat);
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
        render(scene, squareSettings(Method::Aci, 16, args.threads)).stats.seconds;

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
    RenderSettings paperSettings = squareSettings(Method::Aci, size, args.threads);
    applyAciMode(paperSettings.aci, AciMode::Paper);
    const RenderResult paper = render(scene, paperSettings);
    RenderSettings arcsSettings = squareSettings(Method::Aci, size, args.threads);
    applyAciMode(arcsSettings.aci, AciMode::Arcs);
    const RenderResult arcs = render(scene, arcsSettings);

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
    const Metrics aciMetrics = measure(aci.color, cmp);
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
                                         "mc-sa@aci-time"};
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
        Context ctx{args, {}, {}};
        std::printf("\n");
        printTableHeader();

        for (int i = 0; i < args.seeds; ++i) {
            const uint64_t seed = args.firstSeed + uint64_t(i);
            const Generated g = generateScene(seed);
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
