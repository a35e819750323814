// `penumbra render SCENE.json -o OUT.exr|OUT.png [...]`: loads the scene, renders it with the
// library's renderer, writes the picture, the optional AOVs and statistics, and reports progress
// on stderr. All the work is in the library; this file only translates options.
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>

#include "cli/commands.h"
#include "cli/settings_flags.h"
#include "penumbra/error.h"
#include "penumbra/image_io.h"
#include "penumbra/output_files.h"
#include "penumbra/renderer.h"
#include "penumbra/scene.h"

namespace penumbra::cli {

namespace {

struct RenderOptions {
    std::string scene;
    std::string output;
    std::string stats;
    std::string cache;  // level-set cache directory ("" none)
    std::string aovRays, aovFormFactor, aovGradient, aovMask, aovErrorBound;
    bool quiet = false;
    bool verbose = false;
    std::unique_ptr<SettingsFlags> settings;  // method, size, threads, ACI, Monte Carlo, volumes
};

// Progress on stderr once a render has taken more than a second: rows done, rate, time left.
// On a terminal one line is rewritten in place; in a log, a line every five seconds.
class ProgressReporter {
public:
    explicit ProgressReporter(bool enabled)
        : mEnabled(enabled), mTty(::isatty(2) != 0), mStart(Clock::now()) {}

    void update(int done, int total) {
        if (!mEnabled) return;
        auto now = Clock::now();
        double elapsed = seconds(now - mStart);
        double sinceLast = seconds(now - mLast);
        if (elapsed < 1.0 || (done < total && sinceLast < (mTty ? 0.25 : 5.0))) return;
        mLast = now;
        double rate = done / elapsed;
        double left = rate > 0.0 ? (total - done) / rate : 0.0;
        char line[160];
        std::snprintf(line, sizeof line, "render: %d/%d rows (%3.0f%%), %.1f rows/s, %.0f s left",
                      done, total, 100.0 * done / total, rate, left);
        std::cerr << (mTty ? "\r" : "") << line << (mTty ? "\x1b[K" : "\n") << std::flush;
        mPrinted = true;
    }

    void finish() {
        if (mEnabled && mPrinted && mTty) std::cerr << "\n" << std::flush;
    }

private:
    using Clock = std::chrono::steady_clock;
    static double seconds(Clock::duration d) { return std::chrono::duration<double>(d).count(); }
    bool mEnabled, mTty;
    bool mPrinted = false;
    Clock::time_point mStart, mLast{};
};

std::string formatNumber(double v) {
    std::ostringstream s;
    s.precision(6);
    s << v;
    return s.str();
}

ImageMetadata metadataFor(const RenderOptions& o, const RenderSettings& settings,
                          const RenderStats& st) {
    ImageMetadata m = {
        {"ImageDescription", "penumbra render of " + o.scene},
        {"penumbra:scene", o.scene},
    };
    for (auto& item : settingsMetadata(settings)) m.push_back(std::move(item));
    const ImageMetadata counts = {
        {"penumbra:threads", std::to_string(st.threads)},
        {"penumbra:seconds", formatNumber(st.seconds)},
        {"penumbra:viewing_rays", std::to_string(st.viewingRays)},
        {"penumbra:viewing_rays_with_shadow_rays", std::to_string(st.viewingRaysWithShadowRays)},
        {"penumbra:shadow_rays", std::to_string(st.shadowRays)},
        {"penumbra:shadow_rays_per_viewing_ray", formatNumber(st.shadowRaysPerViewingRay())},
        {"penumbra:spans", std::to_string(st.spans)},
        {"penumbra:interpolated_pixels", std::to_string(st.interpolatedPixels)},
        {"penumbra:aci_evaluations", std::to_string(st.aciEvaluations)},
        {"penumbra:restarts", std::to_string(st.restarts)},
    };
    for (const auto& item : counts) {
        // The thread count given is the settings'; the one used (maybe the default) wins.
        m.erase(std::remove_if(m.begin(), m.end(), [&](const auto& e) { return e.first == item.first; }),
                m.end());
        m.push_back(item);
    }
    return m;
}

float maxOf(const Image& img) {
    float m = 0.0f;
    for (float v : img.data) m = std::max(m, v);
    return m;
}

// A scalar AOV: raw values in .exr; in .png a heat map (or grey ramp) scaled to the maximum.
void writeScalarAov(OutputSet& outputs, const std::string& path, const std::string& flag,
                    const Image& aov, bool heat, const ImageMetadata& metadata) {
    const std::string staged = outputs.stage(path);
    if (imageFormatFor(path, flag) == ImageFormat::Exr) {
        writeImage(path, aov, metadata, flag, staged);
        return;
    }
    float top = maxOf(aov);
    if (heat) {
        writeImage(path, heatMap(aov, top), metadata, flag, staged);
        return;
    }
    Image grey = aov;
    for (float& v : grey.data) v = top > 0.0f ? v / top : 0.0f;
    writeImage(path, grey, metadata, flag, staged);
}

int runRender(const RenderOptions& o) {
    // Every option is checked before the (possibly slow) scene loading.
    RenderSettings settings = o.settings->read();
    if (settings.width > 0 && settings.height > 0) {
        checkRenderMemory(settings.width, settings.height, "", "--width/--height");  // before loading
    }
    imageFormatFor(o.output, "-o");
    if (!o.aovRays.empty()) imageFormatFor(o.aovRays, "--aov-rays");
    if (!o.aovFormFactor.empty()) imageFormatFor(o.aovFormFactor, "--aov-ff");
    if (!o.aovGradient.empty()) imageFormatFor(o.aovGradient, "--aov-gradient");
    if (!o.aovMask.empty()) imageFormatFor(o.aovMask, "--aov-mask");
    if (!o.aovErrorBound.empty()) imageFormatFor(o.aovErrorBound, "--aov-error-bound");
    settings.aci.gradient = !o.aovGradient.empty();
    settings.aci.errorBound = !o.aovErrorBound.empty();

    // Every file this run writes, checked against each other and the scene before any work,
    // written to temporaries and renamed together at the end: a failed run changes nothing.
    OutputSet outputs;
    outputs.addInput(o.scene, "the scene");
    outputs.addOutput(o.output, "-o");
    outputs.addOutput(o.aovRays, "--aov-rays");
    outputs.addOutput(o.aovFormFactor, "--aov-ff");
    outputs.addOutput(o.aovGradient, "--aov-gradient");
    outputs.addOutput(o.aovMask, "--aov-mask");
    outputs.addOutput(o.aovErrorBound, "--aov-error-bound");
    if (!o.stats.empty()) {
        const std::string ext = std::filesystem::path(o.stats).extension().string();
        if (ext == ".exr" || ext == ".png" || ext == ".EXR" || ext == ".PNG") {
            throw InputError("", "--stats",
                             "'" + o.stats + "' has an image extension; statistics are JSON");
        }
        outputs.addOutput(o.stats, "--stats");
    }
    for (const std::string& path : {o.output, o.aovRays, o.aovFormFactor, o.aovGradient,
                                    o.aovMask, o.aovErrorBound, o.stats}) {
        if (path.empty()) continue;
        const std::string dir = std::filesystem::path(path).parent_path().string();
        removeStaleTemporaries(dir.empty() ? "." : dir);
    }

    // The image module, now rather than after the render (a broken installation).
    try {
        requireImageModule();
    } catch (const ImageModuleError& e) {
        throw ImageModuleError("cannot write '" + o.output + "': " + e.what());
    }

    std::unique_ptr<LevelSetCache> cache;
    if (!o.cache.empty()) {
        cache = std::make_unique<LevelSetCache>(o.cache, [&](const std::string& text) {
            if (!o.quiet) std::cerr << "penumbra: warning: " << text << "\n";
        });
    }
    Scene scene = loadScene(o.scene, cache.get());
    for (const auto& [path, pointer] : scene.inputFiles) {
        outputs.addInput(path, pointer + " of " + o.scene);
    }
    if (!scene.camera) {
        throw InputError(o.scene, "/camera", "the scene has no camera, which rendering needs");
    }

    if (o.verbose) std::cerr << scene.build.toText();
    if (auto inside = scene.obstacleContaining(scene.camera->eye)) {
        // Not an error (the view is all inside, or the obstacle is clipped by the camera), but
        // rarely wanted: say so even with --quiet.
        const Obstacle& ob = scene.obstacles[*inside];
        std::cerr << "penumbra: warning: " << o.scene << ": /camera/eye: inside obstacle '"
                  << (ob.name.empty() ? "obstacle_" + std::to_string(*inside) : ob.name)
                  << "' (/obstacles/" << *inside << ")\n";
    }

    ProgressReporter reporter(!o.quiet);
    RenderResult result =
        render(scene, settings, [&](int done, int total) { reporter.update(done, total); });
    reporter.finish();
    if (cache) cache->persist();  // the far-field companions the render built

    const RenderStats& st = result.stats;
    ImageMetadata metadata = metadataFor(o, settings, st);
    writeImage(o.output, result.color, metadata, "-o", outputs.stage(o.output));
    if (!o.aovRays.empty()) {
        writeScalarAov(outputs, o.aovRays, "--aov-rays", result.aovs.shadowRays, true, metadata);
    }
    if (!o.aovFormFactor.empty()) {
        writeScalarAov(outputs, o.aovFormFactor, "--aov-ff", result.aovs.formFactor, false,
                       metadata);
    }
    if (!o.aovGradient.empty()) {
        writeScalarAov(outputs, o.aovGradient, "--aov-gradient", result.aovs.gradient, true,
                       metadata);
    }
    if (!o.aovMask.empty()) {
        writeScalarAov(outputs, o.aovMask, "--aov-mask", result.aovs.mask, false, metadata);
    }
    if (!o.aovErrorBound.empty()) {
        writeScalarAov(outputs, o.aovErrorBound, "--aov-error-bound", result.aovs.errorBound,
                       true, metadata);
    }
    if (!o.stats.empty()) {
        RenderStats withBuild = st;
        withBuild.buildJson = scene.build.toJson();
        writeTextFile(outputs.stage(o.stats), withBuild.toJson(), o.stats);
    }
    outputs.commit();

    if (!o.quiet) {
        std::printf("penumbra: wrote %s (%dx%d, %s, %d threads, %.2f s): %llu shadow rays, "
                    "%.2f per viewing ray with shadow rays, %.1f%% of those interpolated\n",
                    o.output.c_str(), st.width, st.height, st.method.c_str(), st.threads,
                    st.seconds, static_cast<unsigned long long>(st.shadowRays),
                    st.shadowRaysPerViewingRay(),
                    st.viewingRaysWithShadowRays
                        ? 100.0 * double(st.interpolatedPixels) / double(st.viewingRaysWithShadowRays)
                        : 0.0);
    }
    return 0;
}

}  // namespace

Runner addRenderCommand(CLI::App& app) {
    auto o = std::make_shared<RenderOptions>();
    CLI::App* cmd = app.add_subcommand(
        "render", "Render a scene's camera view: soft shadows by approximate contour integration");
    cmd->add_option("scene", o->scene, "Scene file (JSON, see docs/scene-format.md)")->required();
    cmd->add_option("-o,--output", o->output, "Output image: .exr (linear float) or .png (sRGB)")
        ->required();
    cmd->add_option("--stats", o->stats, "Write render statistics to this JSON file");
    cmd->add_option("--cache", o->cache,
                    "Level-set cache directory: level sets (and far-field companions) built "
                    "by earlier runs are read from it, new ones stored (created when missing)");
    o->settings = std::make_unique<SettingsFlags>(cmd, RenderSettings::keys());
    cmd->add_option("--aov-rays", o->aovRays, "Shadow rays per pixel (.png: heat map)");
    cmd->add_option("--aov-ff", o->aovFormFactor, "Sum of the form factors (.png: scaled grey)");
    cmd->add_option("--aov-gradient", o->aovGradient,
                    "Magnitude of the form factor's gradient (.png: heat map)");
    cmd->add_option("--aov-mask", o->aovMask, "1 where shadow rays were cast, 0 elsewhere");
    cmd->add_option("--aov-error-bound", o->aovErrorBound,
                    "Sum over lights of the estimator's bound on |F - F_exact| (default tangent "
                    "mode; NaN for methods without one; .png: scaled grey)");
    cmd->add_flag("-q,--quiet", o->quiet, "No progress or summary");
    cmd->add_flag("-v,--verbose", o->verbose,
                  "Report what building the obstacles' level sets cost (voxels, memory, seconds "
                  "per obstacle) on stderr");
    return [o]() { return runRender(*o); };
}

}  // namespace penumbra::cli
