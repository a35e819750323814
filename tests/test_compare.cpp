// Tests of compare.h and of `penumbra compare`: zero for identical images, the right figures for
// a known offset and a known single-pixel error, the mask, the error map, and refused input.
#include <sys/wait.h>

#include <catch2/catch.hpp>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>

#include "penumbra/compare.h"
#include "penumbra/error.h"
#include "penumbra/image_io.h"
#include "support/cli.h"

using namespace penumbra;
namespace fs = std::filesystem;

namespace {

// A 3-channel ramp with values in [0.1, 0.9], so that an offset of 2/255 stays in range.
Image ramp(int w, int h) {
    Image img(w, h, 3);
    for (int y = 0; y < h; ++y) {
        for (int x = 0; x < w; ++x) {
            for (int c = 0; c < 3; ++c) {
                img.at(x, y, c) = 0.1f + 0.8f * float(x + 2 * y + c) / float(w + 2 * h + 3);
            }
        }
    }
    return img;
}

using Run = test::Run;

Run runPenumbra(const std::string& args, const fs::path& dir) {
    return test::runPenumbra(args, dir);
}

fs::path makeTempDir(const std::string& name) { return test::makeTempDir("compare", name); }

}  // namespace

TEST_CASE("identical images differ by zero", "[compare]") {
    const Image a = ramp(17, 9);
    const ImageDifference d = compareImages(a, a);
    CHECK(d.all.pixels == 17 * 9);
    CHECK(d.all.mean == 0.0);
    CHECK(d.all.rmse == 0.0);
    CHECK(d.all.max == 0.0);
    CHECK_FALSE(d.hasMask);
}

TEST_CASE("an offset of 2/255 everywhere gives a mean, RMSE and maximum of 2", "[compare]") {
    const Image ref = ramp(20, 12);
    Image test = ref;
    for (float& v : test.data) v += 2.0f / 255.0f;
    const ImageDifference d = compareImages(test, ref);
    // float storage rounds each value to ~6e-8, i.e. ~1.5e-5 in 8-bit units
    CHECK(d.all.mean == Approx(2.0).epsilon(1e-4));
    CHECK(d.all.rmse == Approx(2.0).epsilon(1e-4));
    CHECK(d.all.max == Approx(2.0).epsilon(1e-4));
    // The sign does not matter.
    CHECK(compareImages(ref, test).all.mean == Approx(2.0).epsilon(1e-4));
}

TEST_CASE("one wrong pixel: mean, RMSE and maximum separate, the mask selects", "[compare]") {
    const int w = 10, h = 10;
    const Image ref = ramp(w, h);
    Image test = ref;
    // Pixel (3, 4): +30/255 in the red channel only.
    test.at(3, 4, 0) += 30.0f / 255.0f;
    Image mask(w, h, 1, 0.0f);
    for (int x = 0; x < 5; ++x) mask.at(x, 4) = 1.0f;  // five pixels of row 4

    const ImageDifference d = compareImages(test, ref, &mask);
    const double n = w * h * 3;
    CHECK(d.all.mean == Approx(30.0 / n).epsilon(1e-4));
    CHECK(d.all.rmse == Approx(std::sqrt(900.0 / n)).epsilon(1e-4));
    CHECK(d.all.max == Approx(30.0).epsilon(1e-4));
    REQUIRE(d.hasMask);
    CHECK(d.masked.pixels == 5);
    CHECK(d.masked.mean == Approx(30.0 / 15.0).epsilon(1e-4));
    CHECK(d.masked.rmse == Approx(std::sqrt(900.0 / 15.0)).epsilon(1e-4));
    CHECK(d.masked.max == Approx(30.0).epsilon(1e-4));

    // The per-pixel map: the channel mean, so 10 at (3, 4) and 0 elsewhere.
    const Image map = differenceImage(test, ref);
    REQUIRE(map.channels == 1);
    CHECK(map.at(3, 4) == Approx(10.0).epsilon(1e-4));
    CHECK(map.at(4, 4) == 0.0f);

    // Shapes must agree.
    CHECK_THROWS_AS(compareImages(ramp(10, 9), ref), InputError);
    Image small(4, 4, 1);
    CHECK_THROWS_AS(compareImages(test, ref, &small), InputError);
}

TEST_CASE("penumbra compare prints the figures, writes the error map, refuses bad input",
          "[compare][cli]") {
    const fs::path dir = makeTempDir("cli");
    const Image ref = ramp(16, 8);
    Image test = ref;
    for (float& v : test.data) v += 2.0f / 255.0f;
    Image mask(16, 8, 1, 0.0f);
    mask.at(0, 0) = 1.0f;
    mask.at(5, 3) = 1.0f;
    test.at(5, 3, 1) += 12.0f / 255.0f;  // 14 in all in one channel of a masked pixel
    writeImage((dir / "test.exr").string(), test);
    writeImage((dir / "ref.exr").string(), ref);
    writeImage((dir / "mask.exr").string(), mask);

    const std::string files = (dir / "test.exr").string() + " " + (dir / "ref.exr").string() +
                              " --mask " + (dir / "mask.exr").string();
    Run run = runPenumbra("compare " + files + " --json --error-map " + (dir / "map.png").string() +
                              " --error-scale 8",
                          dir);
    INFO(run.err);
    REQUIRE(run.exitCode == 0);
    const nlohmann::json j = nlohmann::json::parse(run.out);
    const double n = 16 * 8 * 3;
    CHECK(j["all"]["pixels"] == 128);
    CHECK(j["all"]["mean"].get<double>() == Approx((2.0 * n + 12.0) / n).epsilon(1e-4));
    CHECK(j["all"]["max"].get<double>() == Approx(14.0).epsilon(1e-4));
    CHECK(j["masked"]["pixels"] == 2);
    CHECK(j["masked"]["mean"].get<double>() == Approx((2.0 * 6 + 12.0) / 6.0).epsilon(1e-4));
    CHECK(j["masked"]["rmse"].get<double>() ==
          Approx(std::sqrt((5 * 4.0 + 196.0) / 6.0)).epsilon(1e-4));

    // The error map: 2 everywhere is a quarter of the scale of 8 (pure blue on the ramp
    // black-blue-red-yellow-white); the wrong pixel (mean 6 over its channels) is beyond red.
    REQUIRE(fs::exists(dir / "map.png"));
    const Image map = readImage((dir / "map.png").string());
    REQUIRE(map.width == 16);
    CHECK(map.at(0, 0, 2) == Approx(1.0).margin(0.01));
    CHECK(map.at(0, 0, 0) == Approx(0.0).margin(0.01));
    CHECK(map.at(5, 3, 0) == Approx(1.0).margin(0.01));
    CHECK(map.at(5, 3, 1) > 0.3f);

    // Text output names both sets of pixels.
    run = runPenumbra("compare " + files, dir);
    CHECK(run.exitCode == 0);
    CHECK(run.out.find("all pixels") != std::string::npos);
    CHECK(run.out.find("masked pixels") != std::string::npos);

    // Bad input: one line, exit code 2.
    writeImage((dir / "other.exr").string(), ramp(8, 8));
    run = runPenumbra("compare " + (dir / "test.exr").string() + " " + (dir / "other.exr").string(),
                      dir);
    CHECK(run.exitCode == 2);
    CHECK(run.err.find("differ in size") != std::string::npos);
    CHECK(std::count(run.err.begin(), run.err.end(), '\n') == 1);
    run = runPenumbra(
        "compare " + (dir / "test.exr").string() + " " + (dir / "missing.exr").string(), dir);
    CHECK(run.exitCode == 2);
    CHECK(run.err.find("missing.exr") != std::string::npos);
    run = runPenumbra("compare " + files + " --error-map " + (dir / "map.txt").string(), dir);
    CHECK(run.exitCode == 2);
    CHECK(run.err.find("--error-map") != std::string::npos);
}
