// Table 1 of Vedel (1993), on this machine: approximate contour integration against Monte Carlo
// estimators behind the same span and shaft-culling front end, so that every method casts its
// shadow rays on the same pixels. Renders a reference (stratified area sampling, 1024 rays per
// viewing ray) and states its own error against one with 4x the rays; then ACI at default
// settings, mc-adaptive with its threshold set for (a) about ACI's rays and (b) about ACI's mean
// difference, and mc-solid-angle and mc-ratio at ACI's rays. Prints the paper's table (method,
// shadow rays, rays per viewing ray, mean difference, wall seconds) with each row's ratio to
// ACI, writes crops of one penumbra and error maps, and a plot of mean difference against rays
// per viewing ray over several budgets (gnuplot). Never fails on a figure.
//
//   bench_table1 [SCENE.json] [--size N] [--threads N] [--ref-samples N] [--sweep-size N]
//                [--out DIR] [--work DIR] [--no-plot] [--quick]
//
// SCENE defaults to vdb_scenes/table1.json (run from the source tree). --size 800 (the paper's),
// --threads 2, --ref-samples 1024 (the check reference gets 4x), --sweep-size 400 (the budget sweep
// renders at this size against its own reference), --out docs/img (crops and plot), --work a
// scratch directory for the EXRs and gnuplot files (default /tmp/penumbra_table1). --quick: 200 x
// 200, reference 256, for a smoke run. Mean differences are 255 x |test - reference| averaged over
// the pixels where shadow rays were cast (the reference's and ACI's masks) and the three channels;
// the same over all pixels is printed beside.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <vector>

#include "bench_common.h"
#include "penumbra/compare.h"
#include "penumbra/error.h"
#include "penumbra/image_io.h"
#include "penumbra/contour_integrator.h"
#include "penumbra/renderer.h"
#include "penumbra/scene.h"

using namespace penumbra;
namespace fs = std::filesystem;

namespace {

struct Args {
    std::string scene;
    int size = 800;
    int threads = 2;
    int refSamples = 1024;
    int sweepSize = 400;
    std::string out = "docs/img";
    std::string work = "/tmp/penumbra_table1";
    bool plot = true;
};

Args parseArgs(int argc, char** argv) {
    Args a;
    const auto quick = [&a] {
        a.size = 200;
        a.refSamples = 256;
        a.sweepSize = 100;
    };
    bench::parseOptions("bench_table1", argc, argv,
                        {{"--size", &a.size},
                         {"--threads", &a.threads},
                         {"--ref-samples", &a.refSamples},
                         {"--sweep-size", &a.sweepSize},
                         {"--out", &a.out},
                         {"--work", &a.work},
                         {"--no-plot", [&a] { a.plot = false; }},
                         {"--quick", quick}},
                        &a.scene);
    if (a.scene.empty()) a.scene = "vdb_scenes/table1.json";
    if (a.size < 16 || a.threads < 1 || a.refSamples < 1 || a.sweepSize < 16)
        bench::failUsage("bench_table1", "--size and --sweep-size >= 16, others >= 1");
    return a;
}

// One rendered configuration and its figures against the reference.
struct Row {
    std::string name;
    RenderSettings settings;
    RenderResult result;
    double diff = 0.0;       // mean difference over the mask, 8-bit units
    double diffAll = 0.0;    // over all pixels
    double diffCheck = 0.0;  // over the mask, against the 4x reference
    double rmse = 0.0;
};

class Bench {
  public:
    Bench(const Scene& scene, int size, int threads, const Image* reference, const Image* check,
          const Image* mask)
        : mScene(scene),
          mSize(size),
          mThreads(threads),
          mRef(reference),
          mCheck(check),
          mMask(mask) {}

    RenderSettings base(Method m) const { return bench::squareSettings(m, mSize, mThreads); }

    Row run(const std::string& name, const RenderSettings& rs) const {
        Row row;
        row.name = name;
        row.settings = rs;
        row.result = render(mScene, rs);
        if (mRef) {
            const ImageDifference d = compareImages(row.result.color, *mRef, mMask);
            row.diff = d.masked.mean;
            row.diffAll = d.all.mean;
            row.rmse = d.masked.rmse;
        }
        if (mCheck) row.diffCheck = compareImages(row.result.color, *mCheck, mMask).masked.mean;
        return row;
    }

  private:
    const Scene& mScene;
    int mSize, mThreads;
    const Image* mRef;
    const Image* mCheck;
    const Image* mMask;
};

double raysPerVr(const Row& r) { return r.result.stats.shadowRaysPerViewingRay(); }

// Bisection on log(threshold) for mc-adaptive: `value` falls as the threshold grows (rays) or
// rises (mean difference); finds the threshold whose value is closest to `target`.
Row searchThreshold(const Bench& bench, RenderSettings rs, const std::string& name,
                    const std::function<double(const Row&)>& value, double target,
                    bool valueFallsWithThreshold, int steps, std::vector<Row>* tried = nullptr) {
    double lo = std::log(1e-5), hi = std::log(1.0);
    Row best;
    double bestGap = 1e300;
    for (int i = 0; i < steps; ++i) {
        const double mid = 0.5 * (lo + hi);
        rs.mc.threshold = std::exp(mid);
        Row r = bench.run(name, rs);
        const double v = value(r);
        std::fprintf(stderr, "  %s: threshold %.3g -> rays/VR %.2f, mean difference %.4f\n",
                     name.c_str(), rs.mc.threshold, raysPerVr(r), r.diff);
        const double gap = std::abs(std::log(std::max(v, 1e-12) / target));
        if (gap < bestGap) {
            bestGap = gap;
            best = r;
        }
        if (tried) tried->push_back(r);
        // Too large a value: move the threshold the way that lowers it.
        const bool tooLarge = v > target;
        if (tooLarge == valueFallsWithThreshold)
            lo = mid;
        else
            hi = mid;
    }
    return best;
}

std::string thousands(uint64_t v) {
    std::string s = std::to_string(v), out;
    for (size_t i = 0; i < s.size(); ++i) {
        if (i && (s.size() - i) % 3 == 0) out += ',';
        out += s[i];
    }
    return out;
}

void printTable(const std::vector<Row>& rows, const Row& aci, const Row& ref) {
    std::printf("\n%-50s %14s %9s %10s %9s %10s %8s | %8s %8s %8s\n", "method", "shadow rays",
                "rays/VR", "mean diff", "all px", "vs 4x ref", "wall s", "rays/ACI", "diff/ACI",
                "time/ACI");
    for (const Row& r : rows) {
        const RenderStats& s = r.result.stats;
        const bool isRef = &r == &ref;
        char diff[32], diffAll[32], ratio[32];
        if (isRef) {
            std::snprintf(diff, sizeof diff, "%10s", "-");
            std::snprintf(diffAll, sizeof diffAll, "%9s", "-");
            std::snprintf(ratio, sizeof ratio, "%8s", "-");
        } else {
            std::snprintf(diff, sizeof diff, "%10.3f", r.diff);
            std::snprintf(diffAll, sizeof diffAll, "%9.3f", r.diffAll);
            std::snprintf(ratio, sizeof ratio, "%8.2f", aci.diff > 0 ? r.diff / aci.diff : 0.0);
        }
        std::printf("%-50s %14s %9.2f %s %s %10.3f %8.2f | %8.2f %s %8.2f\n", r.name.c_str(),
                    thousands(s.shadowRays).c_str(), s.shadowRaysPerViewingRay(), diff, diffAll,
                    r.diffCheck, s.seconds, raysPerVr(r) / std::max(1e-12, raysPerVr(aci)), ratio,
                    s.seconds / std::max(1e-12, aci.result.stats.seconds));
    }
}

// A crop of `img` (3 channels) scaled up `zoom` times (nearest), as 8-bit-ready linear values.
Image crop(const Image& img, int x0, int y0, int w, int h, int zoom) {
    Image out(w * zoom, h * zoom, 3);
    for (int y = 0; y < h * zoom; ++y) {
        for (int x = 0; x < w * zoom; ++x) {
            for (int c = 0; c < 3; ++c) {
                out.at(x, y, c) =
                    img.at(x0 + x / zoom, y0 + y / zoom, std::min(c, img.channels - 1));
            }
        }
    }
    return out;
}

// The square window of side `w` (on a stride of w / 4) with the most masked pixels where the
// Monte Carlo image at ACI's rays differs visibly (> 1 unit) from the reference: a penumbra.
void pickCrop(const Image& noisy, const Image& ref, const Image& mask, int w, int& bx, int& by) {
    const Image diff = differenceImage(noisy, ref);
    int best = -1;
    bx = by = 0;
    const int stride = std::max(1, w / 4);
    for (int y0 = 0; y0 + w <= ref.height; y0 += stride) {
        for (int x0 = 0; x0 + w <= ref.width; x0 += stride) {
            int count = 0;
            for (int y = y0; y < y0 + w; ++y) {
                for (int x = x0; x < x0 + w; ++x) {
                    count += mask.at(x, y) > 0.5f && diff.at(x, y) > 1.0f;
                }
            }
            if (count > best) {
                best = count;
                bx = x0;
                by = y0;
            }
        }
    }
}

std::string quoted(const std::string& s) { return "'" + s + "'"; }

}  // namespace

int main(int argc, char** argv) {
    const Args args = parseArgs(argc, argv);
    try {
        fs::create_directories(args.work);
        fs::create_directories(args.out);
        const Scene scene = loadScene(args.scene);
        std::printf("Table 1 benchmark: scene %s, %d x %d, 1 viewing ray per pixel, %d threads\n",
                    args.scene.c_str(), args.size, args.size, args.threads);

        // -------------------------------------------------------------------------------------
        // References: N rays, and 4N rays with another seed for the reference's own error.
        Bench plain(scene, args.size, args.threads, nullptr, nullptr, nullptr);
        RenderSettings refSettings = plain.base(Method::Reference);
        refSettings.mc.samples = args.refSamples;
        std::fprintf(stderr, "rendering the reference (%d rays per viewing ray)...\n",
                     args.refSamples);
        Row ref =
            plain.run("reference (" + std::to_string(args.refSamples) + " rays)", refSettings);
        RenderSettings checkSettings = refSettings;
        checkSettings.mc.samples = 4 * args.refSamples;
        checkSettings.mc.seed = 1;
        std::fprintf(stderr, "rendering the check reference (%d rays per viewing ray)...\n",
                     4 * args.refSamples);
        Row check = plain.run("check", checkSettings);
        writeImage(args.work + "/reference.exr", ref.result.color);
        writeImage(args.work + "/reference_4x.exr", check.result.color);

        const Image refImage = ref.result.color;  // copies: the rows are moved into a table
        const Image checkImage = check.result.color;

        // -------------------------------------------------------------------------------------
        // ACI at default settings fixes the budget; its mask (with the reference's) the pixels.
        Bench pre(scene, args.size, args.threads, nullptr, nullptr, nullptr);
        Row aciRaw = pre.run("aci (default settings)", pre.base(Method::Aci));
        Image mask = ref.result.aovs.mask;
        for (size_t i = 0; i < mask.data.size(); ++i) {
            mask.data[i] = std::max(mask.data[i], aciRaw.result.aovs.mask.data[i]);
        }
        writeImage(args.work + "/mask.exr", mask);
        const Bench bench(scene, args.size, args.threads, &refImage, &checkImage, &mask);
        ref.diffCheck = compareImages(refImage, checkImage, &mask).masked.mean;
        const double refAll = compareImages(refImage, checkImage).all.mean;
        Row aci = bench.run("aci (default settings)", bench.base(Method::Aci));
        const double aciRays = raysPerVr(aci);
        std::fprintf(stderr, "aci: %.2f rays per viewing ray, mean difference %.4f\n", aciRays,
                     aci.diff);

        // The smaller scene of the budget sweep: its own reference, mask and ACI figure. The
        // searches for mc-adaptive's settings that need many renders run here.
        std::fprintf(stderr, "sweep reference at %d x %d...\n", args.sweepSize, args.sweepSize);
        Bench sweepPlain(scene, args.sweepSize, args.threads, nullptr, nullptr, nullptr);
        RenderSettings sweepRefSettings = sweepPlain.base(Method::Reference);
        sweepRefSettings.mc.samples = args.refSamples;
        const Row sweepRef = sweepPlain.run("sweep reference", sweepRefSettings);
        const Row sweepAciRaw = sweepPlain.run("aci", sweepPlain.base(Method::Aci));
        Image sweepMask = sweepRef.result.aovs.mask;
        for (size_t i = 0; i < sweepMask.data.size(); ++i) {
            sweepMask.data[i] = std::max(sweepMask.data[i], sweepAciRaw.result.aovs.mask.data[i]);
        }
        const Bench sweep(scene, args.sweepSize, args.threads, &sweepRef.result.color, nullptr,
                          &sweepMask);
        const Row sweepAci = sweep.run("aci", sweep.base(Method::Aci));

        // mc-adaptive (a): about ACI's rays. Its threshold is searched from the whole light
        // (d0 = 0, 4 rays at least) and from a 2 x 2 grid of cells (d0 = 1, 16 rays at least);
        // of the two, the one closer to ACI's rays (the lower difference when both are close).
        RenderSettings adaptive = bench.base(Method::McAdaptive);
        Row adaptiveRays;
        for (int depth = 0; depth <= 1; ++depth) {
            RenderSettings rs = adaptive;
            rs.mc.initialDepth = depth;
            Row r = searchThreshold(
                bench, rs, "mc-adaptive d0=" + std::to_string(depth),
                [](const Row& x) { return raysPerVr(x); }, aciRays,
                /*valueFallsWithThreshold=*/true, 9);
            auto gap = [&](const Row& x) { return std::abs(raysPerVr(x) / aciRays - 1.0); };
            const bool first = depth == 0;
            const bool closer = !first && gap(r) < gap(adaptiveRays) - 0.05;
            const bool asClose = !first && std::abs(gap(r) - gap(adaptiveRays)) <= 0.05;
            if (first || closer || (asClose && r.diff < adaptiveRays.diff)) adaptiveRays = r;
        }
        char name[160];
        std::snprintf(name, sizeof name, "mc-adaptive, ACI's rays (thr %.3g, d0 %d)",
                      adaptiveRays.settings.mc.threshold, adaptiveRays.settings.mc.initialDepth);
        adaptiveRays.name = name;

        // mc-adaptive (b): about ACI's mean difference, searched at the sweep size. From the
        // whole light a cell whose four rays agree is never split, which sets a floor on the
        // error that no threshold removes; so the starting grid is refined first (the smallest
        // d0 whose error reaches ACI's), then the largest threshold that keeps it there.
        int depthB = -1;
        for (int depth = 0; depth <= 4 && depthB < 0; ++depth) {
            RenderSettings rs = sweep.base(Method::McAdaptive);
            rs.mc.initialDepth = depth;
            rs.mc.threshold = 1e-4;
            const Row r = sweep.run("probe", rs);
            std::fprintf(stderr,
                         "  mc-adaptive d0=%d threshold 1e-4 at %d: rays/VR %.1f, mean "
                         "difference %.4f (aci %.4f)\n",
                         depth, args.sweepSize, raysPerVr(r), r.diff, sweepAci.diff);
            if (r.diff <= sweepAci.diff) depthB = depth;
        }
        const bool reachedB = depthB >= 0;
        if (!reachedB) depthB = 4;
        RenderSettings adaptiveB = sweep.base(Method::McAdaptive);
        adaptiveB.mc.initialDepth = depthB;
        {
            // Largest threshold whose difference stays at ACI's (bisection on log threshold).
            double lo = std::log(1e-4), hi = std::log(1.0);
            for (int i = 0; i < 7; ++i) {
                const double mid = 0.5 * (lo + hi);
                adaptiveB.mc.threshold = std::exp(mid);
                const Row r = sweep.run("probe", adaptiveB);
                std::fprintf(stderr,
                             "  mc-adaptive d0=%d threshold %.3g at %d: rays/VR %.1f, "
                             "mean difference %.4f\n",
                             depthB, adaptiveB.mc.threshold, args.sweepSize, raysPerVr(r), r.diff);
                if (r.diff <= sweepAci.diff || !reachedB)
                    lo = mid;
                else
                    hi = mid;
            }
            adaptiveB.mc.threshold = std::exp(lo);
        }
        RenderSettings adaptiveBFull = adaptive;
        adaptiveBFull.mc = adaptiveB.mc;
        Row adaptiveDiff = bench.run("", adaptiveBFull);
        std::snprintf(name, sizeof name, "mc-adaptive, ACI's difference (thr %.3g, d0 %d)%s",
                      adaptiveDiff.settings.mc.threshold, adaptiveDiff.settings.mc.initialDepth,
                      reachedB ? "" : " [not reached]");
        adaptiveDiff.name = name;

        // mc-solid-angle and mc-ratio at ACI's rays (they cast `samples` rays per pixel).
        const int equalSamples = std::max(1, int(std::lround(aciRays)));
        RenderSettings sa = bench.base(Method::McSolidAngle);
        sa.mc.samples = equalSamples;
        Row solidAngle = bench.run(
            "mc-solid-angle, ACI's rays (" + std::to_string(equalSamples) + " samples)", sa);
        RenderSettings ratioSettings = bench.base(Method::McRatio);
        ratioSettings.mc.samples = equalSamples;
        Row ratio = bench.run("mc-ratio, ACI's rays (" + std::to_string(equalSamples) + " samples)",
                              ratioSettings);
        // Stratified area sampling (the reference's estimator) at the same budget.
        RenderSettings area = bench.base(Method::Reference);
        area.mc.samples = equalSamples;
        area.mc.seed = 7;
        Row areaRow = bench.run(
            "stratified area sampling, ACI's rays (" + std::to_string(equalSamples) + ")", area);

        // mc-solid-angle at ACI's wall time: its rays are cheaper than ACI's (no lattice, no
        // contour), so at equal time it gets more of them (scaled by the measured times).
        const int timeSamples =
            std::max(1, int(std::lround(equalSamples * aci.result.stats.seconds /
                                        std::max(1e-6, solidAngle.result.stats.seconds))));
        RenderSettings saTime = sa;
        saTime.mc.samples = timeSamples;
        Row solidAngleTime = bench.run(
            "mc-solid-angle, ACI's time (" + std::to_string(timeSamples) + " samples)", saTime);

        // The same pipeline with the paper's estimator exactly, and with the "arcs" mode (the
        // paper's rays, parabolic arcs and the midline check): what the default tangent mode
        // (docs/estimator.md) gains over them.
        RenderSettings paperSettings = bench.base(Method::Aci);
        applyAciMode(paperSettings.aci, AciMode::Paper);
        Row aciPaper = bench.run("aci --aci-mode paper (Vedel 1993 exactly)", paperSettings);
        RenderSettings arcsSettings = bench.base(Method::Aci);
        applyAciMode(arcsSettings.aci, AciMode::Arcs);
        Row aciArcs = bench.run("aci --aci-mode arcs", arcsSettings);

        std::vector<Row> rows;
        rows.push_back(std::move(ref));
        rows.push_back(std::move(aci));
        rows.push_back(std::move(adaptiveRays));
        rows.push_back(std::move(adaptiveDiff));
        rows.push_back(std::move(solidAngle));
        rows.push_back(std::move(ratio));
        rows.push_back(std::move(areaRow));
        rows.push_back(std::move(solidAngleTime));
        rows.push_back(std::move(aciPaper));
        rows.push_back(std::move(aciArcs));
        const Row& refRow = rows[0];
        const Row& aciRow = rows[1];
        std::printf(
            "\nTable 1 (%d x %d; mean differences in 8-bit units over the %s pixels where "
            "shadow rays were cast, against the %d-ray reference; 'all px' over every "
            "pixel; 'vs 4x ref' against the %d-ray reference)\n",
            args.size, args.size,
            thousands(compareImages(refImage, refImage, &mask).masked.pixels).c_str(),
            args.refSamples, 4 * args.refSamples);
        printTable(rows, aciRow, refRow);
        std::printf(
            "\nreference's own error: %.3f over the masked pixels, %.3f over all pixels "
            "(against the %d-ray reference, an independent seed); the 4x reference took "
            "%.1f s\n",
            refRow.diffCheck, refAll, 4 * args.refSamples, check.result.stats.seconds);
        std::printf(
            "targets: ACI <= 12 rays/VR (%.2f) at mean difference <= 0.25 (%.3f); at "
            "equal rays mc-adaptive >= 4x ACI's difference (%.2fx), mc-solid-angle >= 2x "
            "(%.2fx)\n",
            raysPerVr(aciRow), aciRow.diff, rows[2].diff / aciRow.diff, rows[4].diff / aciRow.diff);

        const RenderStats& as = aciRow.result.stats;
        std::printf(
            "where ACI's rays go: %s first-level (corners of patterns and evaluations), "
            "%s second-level; %s full evaluations, %s pattern-only pixels, %s "
            "interpolated; first-level grid made finer %s times, restarts %s\n",
            thousands(as.firstLevelRays).c_str(), thousands(as.secondLevelRays).c_str(),
            thousands(as.aciEvaluations).c_str(), thousands(as.patternEvaluations).c_str(),
            thousands(as.interpolatedPixels).c_str(), thousands(as.gridIncreases).c_str(),
            thousands(as.restarts).c_str());
        std::printf("paper mode: %.2f rays/VR at %.3f; arcs mode: %.2f rays/VR at %.3f\n",
                    raysPerVr(rows[8]), rows[8].diff, raysPerVr(rows[9]), rows[9].diff);

        // -------------------------------------------------------------------------------------
        // Crops of one penumbra: the pictures, then their error maps against the reference
        // (the reference's against the 4x reference), at a fixed scale.
        const int cw = std::max(16, args.size * 3 / 20);
        int cx = 0, cy = 0;
        pickCrop(rows[4].result.color, refImage, mask, cw, cx, cy);
        const int zoom = std::max(1, 360 / cw);
        const float errorScale = 8.0f;
        const std::vector<std::pair<const Row*, std::string>> shown = {{&rows[0], "reference"},
                                                                       {&rows[1], "aci"},
                                                                       {&rows[2], "mc_adaptive"},
                                                                       {&rows[4], "mc_solid_angle"},
                                                                       {&rows[5], "mc_ratio"}};
        std::vector<std::string> cropFiles, errorFiles;
        for (const auto& [row, tag] : shown) {
            const Image& against = row == &rows[0] ? checkImage : refImage;
            const std::string picture = args.work + "/crop_" + tag + ".png";
            const std::string error = args.work + "/crop_" + tag + "_error.png";
            writeImage(picture, crop(row->result.color, cx, cy, cw, cw, zoom));
            writeImage(error, crop(heatMap(differenceImage(row->result.color, against), errorScale),
                                   cx, cy, cw, cw, zoom));
            cropFiles.push_back(picture);
            errorFiles.push_back(error);
        }
        std::printf(
            "\ncrop: %d x %d pixels at (%d, %d), x%d; error maps: black 0, blue %.0f, red "
            "%.0f, yellow %.0f, white >= %.0f (8-bit units)\n",
            cw, cw, cx, cy, zoom, errorScale / 4, errorScale / 2, 3 * errorScale / 4, errorScale);

        // -------------------------------------------------------------------------------------
        // The budget sweep, at --sweep-size against its own reference.
        // The sweep compares against the 4x reference at its size: the plot's floor is then that
        // reference's noise, half the N-ray one's.
        std::fprintf(stderr, "budget sweep at %d x %d...\n", args.sweepSize, args.sweepSize);
        RenderSettings sweepCheckSettings = sweepRefSettings;
        sweepCheckSettings.mc.samples = 4 * args.refSamples;
        sweepCheckSettings.mc.seed = 1;
        const Row sweepCheck = sweepPlain.run("sweep check", sweepCheckSettings);
        const double sweepRefError =
            compareImages(sweepRef.result.color, sweepCheck.result.color, &sweepMask).masked.mean;
        std::printf(
            "\nsweep at %d x %d against the %d-ray reference; the %d-ray reference differs "
            "from it by %.3f (masked), so the 4x one's own error is about half that\n",
            args.sweepSize, args.sweepSize, 4 * args.refSamples, args.refSamples, sweepRefError);
        const Bench sweepPlot(scene, args.sweepSize, args.threads, &sweepCheck.result.color,
                              nullptr, &sweepMask);
        struct Series {
            std::string title;
            std::vector<std::pair<double, double>> points;  // rays/VR, mean difference
        };
        std::vector<Series> series;
        auto add = [&](Series& s, const std::string& label, const RenderSettings& rs) {
            const Row r = sweepPlot.run(label, rs);
            s.points.push_back({raysPerVr(r), r.diff});
            std::printf("sweep  %-16s %-28s rays/VR %8.2f  mean difference %.4f  (%.2f s)\n",
                        s.title.c_str(), label.c_str(), raysPerVr(r), r.diff,
                        r.result.stats.seconds);
        };
        {
            Series s{"aci", {}};
            for (int steps : {2, 3, 4, 5, 6}) {
                RenderSettings rs = sweep.base(Method::Aci);
                rs.aci.steps = steps;
                add(s, "steps " + std::to_string(steps), rs);
            }
            series.push_back(s);
        }
        {
            Series s{"aci, paper mode", {}};
            for (int steps : {2, 3, 4, 5, 6}) {
                RenderSettings rs = sweep.base(Method::Aci);
                applyAciMode(rs.aci, AciMode::Paper);
                rs.aci.steps = steps;
                add(s, "steps " + std::to_string(steps), rs);
            }
            series.push_back(s);
        }
        {
            Series s{"mc-adaptive", {}};
            for (double t : {0.3, 0.1, 0.03, 0.01, 0.003, 0.001}) {
                RenderSettings rs = sweep.base(Method::McAdaptive);
                rs.mc.threshold = t;
                char label[64];
                std::snprintf(label, sizeof label, "threshold %g", t);
                add(s, label, rs);
            }
            for (int d0 : {1, 2, 3}) {
                RenderSettings rs = sweep.base(Method::McAdaptive);
                rs.mc.threshold = 0.003;
                rs.mc.initialDepth = d0;
                add(s, "threshold 0.003, d0 " + std::to_string(d0), rs);
            }
            std::sort(s.points.begin(), s.points.end());
            series.push_back(s);
        }
        for (Method m : {Method::McSolidAngle, Method::McRatio, Method::Reference}) {
            Series s{m == Method::Reference ? "stratified area" : methodName(m), {}};
            for (int n : {4, 8, 16, 32, 64, 128, 256}) {
                RenderSettings rs = sweep.base(m);
                rs.mc.samples = n;
                rs.mc.seed = 7;
                add(s, std::to_string(n) + " samples", rs);
            }
            series.push_back(s);
        }
        // -------------------------------------------------------------------------------------
        // gnuplot: the plot and the labelled crops.
        const std::string data = args.work + "/sweep.dat";
        {
            std::ofstream f(data);
            for (const Series& s : series) {
                f << "# " << s.title << "\n";
                for (const auto& [x, y] : s.points) f << x << " " << y << "\n";
                f << "\n\n";
            }
        }
        const std::string plotPng = args.out + "/table1_plot.png";
        const std::string cropsPng = args.out + "/table1_crops.png";
        const std::string script = args.work + "/table1.gp";
        {
            std::ofstream g(script);
            g << "set terminal pngcairo size 900,620 font 'sans,11'\n"
              << "set output " << quoted(plotPng) << "\n"
              << "set logscale xy\nset grid\n"
              << "set xlabel 'shadow rays per viewing ray'\n"
              << "set ylabel 'mean difference (8-bit units, masked pixels)'\n"
              << "set title sprintf('Table 1 scene at %d x %d: mean difference against a %d-ray "
                 "reference', "
              << args.sweepSize << ", " << args.sweepSize << ", " << 4 * args.refSamples << ")\n"
              << "set key top right\n"
              << "plot ";
            for (size_t i = 0; i < series.size(); ++i) {
                g << (i ? ", " : "") << quoted(data) << " index " << i
                  << " with linespoints lw 2 pt " << (i + 5) << " title "
                  << quoted(series[i].title);
            }
            g << ", " << sweepRefError << " with lines dt 2 lc 'gray' title sprintf('%d-ray "
              << "reference vs %d-ray: %.3f', " << args.refSamples << ", " << 4 * args.refSamples
              << ", " << sweepRefError << ")\n";
            // The crops, labelled.
            const char* titles[] = {"reference", "ACI", "mc-adaptive", "mc-solid-angle",
                                    "mc-ratio"};
            const int tile = cw * zoom;
            g << "set terminal pngcairo size " << 5 * (tile + 10) << "," << 2 * (tile + 40)
              << " font 'sans,11'\n"
              << "set output " << quoted(cropsPng) << "\n"
              << "unset logscale\nunset grid\nunset key\nunset xlabel\nunset ylabel\n"
              << "unset tics\nunset border\nset size ratio -1\n"
              << "set multiplot layout 2,5 margins 0.005,0.995,0.01,0.95 spacing 0.01,0.06\n";
            for (int i = 0; i < 5; ++i) {
                g << "set title " << quoted(titles[i]) << "\n"
                  << "plot " << quoted(cropFiles[size_t(i)])
                  << " binary filetype=png flipy with rgbimage\n";
            }
            for (int i = 0; i < 5; ++i) {
                g << "set title "
                  << quoted(std::string(titles[i]) + " error" + (i == 0 ? " (vs 4x rays)" : ""))
                  << "\n"
                  << "plot " << quoted(errorFiles[size_t(i)])
                  << " binary filetype=png flipy with rgbimage\n";
            }
            g << "unset multiplot\n";
        }
        if (args.plot) {
            const int rc = std::system(("gnuplot " + script).c_str());
            if (rc == 0) {
                std::printf("\nwrote %s and %s (gnuplot script %s)\n", plotPng.c_str(),
                            cropsPng.c_str(), script.c_str());
            } else {
                std::printf("\ngnuplot failed (exit %d): the data are in %s, the script in %s\n",
                            rc, data.c_str(), script.c_str());
            }
        }
    } catch (...) {
        return bench::reportException("bench_table1");
    }
    return 0;
}
