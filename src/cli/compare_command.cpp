// `penumbra compare TEST REF [--mask MASK] [--error-map MAP] [--error-scale S] [--json]`: the
// difference between two images in 8-bit units (255 x the linear difference): mean absolute,
// RMSE and maximum over every pixel, and the same over a mask's pixels (the renderer's
// --aov-mask: where shadow rays were cast). All the arithmetic is in compare.h.
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>

#include "cli/commands.h"
#include "penumbra/compare.h"
#include "penumbra/error.h"
#include "penumbra/image_io.h"
#include "penumbra/output_files.h"

namespace penumbra::cli {

namespace {

struct CompareOptions {
    std::string test, ref, mask, errorMap;
    double errorScale = 0.0;  // 0: the largest difference
    bool json = false;
};

Image load(const std::string& path, const std::string& what) {
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) throw InputError(path, what, "no such image file");
    if (!std::filesystem::is_regular_file(path, ec)) {
        throw InputError(path, what, "not a regular file");
    }
    Image image;
    try {
        image = readImage(path);
    } catch (const ImageModuleError&) {
        throw;  // the installation, not the image: a runtime failure
    } catch (const std::exception& e) {
        throw InputError(path, what, std::string("cannot read the image: ") + e.what());
    }
    requireFinite(image, path, what);
    return image;
}

nlohmann::json toJson(const DifferenceStats& s) {
    return {{"pixels", s.pixels}, {"mean", s.mean}, {"rmse", s.rmse}, {"max", s.max}};
}

int runCompare(const CompareOptions& o) {
    if (!o.errorMap.empty()) imageFormatFor(o.errorMap, "--error-map");
    if (!(o.errorScale >= 0.0) || !std::isfinite(o.errorScale)) {
        throw InputError("", "--error-scale", "must be a finite number >= 0");
    }
    OutputSet outputs;
    outputs.addInput(o.test, "TEST");
    outputs.addInput(o.ref, "REF");
    outputs.addInput(o.mask, "--mask");
    outputs.addOutput(o.errorMap, "--error-map");
    const Image test = load(o.test, "TEST");
    const Image ref = load(o.ref, "REF");
    Image mask;
    if (!o.mask.empty()) mask = load(o.mask, "--mask");
    ImageDifference d;
    try {
        d = compareImages(test, ref, o.mask.empty() ? nullptr : &mask);
    } catch (const InputError& e) {
        // Name the files: the library only knows the images.
        throw InputError(e.where() == "--mask" ? o.mask : o.ref, e.where(), e.message());
    }

    if (!o.errorMap.empty()) {
        const Image diff = differenceImage(test, ref);
        const float scale = float(o.errorScale > 0.0 ? o.errorScale : d.all.max);
        const ImageMetadata meta = {
            {"ImageDescription", "penumbra compare " + o.test + " " + o.ref},
            {"penumbra:error_scale", std::to_string(scale)}};
        const std::string staged = outputs.stage(o.errorMap);
        if (imageFormatFor(o.errorMap, "--error-map") == ImageFormat::Exr) {
            writeImage(o.errorMap, diff, meta, "--error-map", staged);
        } else {
            writeImage(o.errorMap, heatMap(diff, scale), meta, "--error-map", staged);
        }
        outputs.commit();
    }

    if (o.json) {
        nlohmann::json j = {{"test", o.test},
                            {"reference", o.ref},
                            {"width", test.width},
                            {"height", test.height},
                            {"channels", test.channels},
                            {"units", "255 x linear difference"},
                            {"all", toJson(d.all)}};
        if (d.hasMask) {
            j["mask"] = o.mask;
            j["masked"] = toJson(d.masked);
        }
        std::cout << j.dump(2) << "\n";
        return 0;
    }
    std::printf("%s vs %s: %dx%d, %d channels; differences in 8-bit units (255 x linear)\n",
                o.test.c_str(), o.ref.c_str(), test.width, test.height, test.channels);
    auto line = [](const char* name, const DifferenceStats& s) {
        std::printf("%-14s %9zu pixels  mean %.4f  rmse %.4f  max %.3f\n", name, s.pixels, s.mean,
                    s.rmse, s.max);
    };
    line("all pixels", d.all);
    if (d.hasMask) line("masked pixels", d.masked);
    return 0;
}

}  // namespace

Runner addCompareCommand(CLI::App& app) {
    auto o = std::make_shared<CompareOptions>();
    CLI::App* cmd = app.add_subcommand(
        "compare",
        "Difference between two images in 8-bit units (255 x linear): mean, RMSE, maximum, over "
        "all pixels and over a mask's pixels");
    cmd->add_option("test", o->test, "The image to judge (.exr or .png)")->required();
    cmd->add_option("ref", o->ref, "The reference image, same size and channels")->required();
    cmd->add_option("--mask", o->mask,
                    "Mask image (e.g. render --aov-mask): pixels whose value is > 0.5 are also "
                    "compared on their own");
    cmd->add_option("--error-map", o->errorMap,
                    "Write the per-pixel difference: .png false colour (black, blue, red, yellow, "
                    "white at --error-scale), .exr raw values");
    cmd->add_option("--error-scale", o->errorScale,
                    "Difference (8-bit units) shown white in the error map (default: the largest)");
    cmd->add_flag("--json", o->json, "Print the figures as JSON");
    return [o]() { return runCompare(*o); };
}

}  // namespace penumbra::cli
