// Tests of image_io.h: EXR and PNG round trips, metadata, the atomic write (no partial or
// temporary file survives a failure) and the refusal of unknown extensions.
#include <unistd.h>

#include <catch2/catch.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>

#include "penumbra/error.h"
#include "penumbra/image_io.h"
#include "support/cli.h"

using namespace penumbra;
namespace fs = std::filesystem;

namespace {

// A fresh, empty directory per test case, removed afterwards.
struct TempDir {
    fs::path path;
    TempDir() {
        static int counter = 0;
        path = fs::temp_directory_path() /
               ("penumbra_image_io_" + std::to_string(::getpid()) + "_" + std::to_string(counter++));
        fs::remove_all(path);
        fs::create_directories(path);
    }
    ~TempDir() { fs::remove_all(path); }
    std::string file(const std::string& name) const { return (path / name).string(); }
    size_t entries() const {
        return size_t(std::distance(fs::directory_iterator(path), fs::directory_iterator()));
    }
};

Image ramp(int w, int h, int c) {
    Image img(w, h, c);
    for (size_t i = 0; i < img.data.size(); ++i) img.data[i] = float(i % 97) / 96.0f * 1.25f - 0.1f;
    return img;
}

}  // namespace

TEST_CASE("sRGB transfer functions match the standard's values", "[image_io]") {
    CHECK(linearToSrgb(0.0f) == 0.0f);
    CHECK(linearToSrgb(1.0f) == Approx(1.0f).margin(1e-6));
    CHECK(linearToSrgb(0.5f) == Approx(0.735356983f).margin(1e-6));
    CHECK(linearToSrgb(0.0031308f) == Approx(0.04045f).margin(1e-6));  // the knee
    CHECK(linearToSrgb(2.0f) == Approx(1.0f).margin(1e-6));            // clamped
    CHECK(linearToSrgb(-1.0f) == 0.0f);
    for (float v : {0.001f, 0.01f, 0.2f, 0.5f, 0.9f}) {
        CHECK(srgbToLinear(linearToSrgb(v)) == Approx(v).margin(1e-6));
    }
}

TEST_CASE("EXR keeps float values exactly and carries the metadata", "[image_io]") {
    TempDir dir;
    for (int channels : {1, 3, 4}) {
        Image img = ramp(7, 5, channels);
        std::string path = dir.file("img" + std::to_string(channels) + ".exr");
        writeImage(path, img, {{"penumbra:method", "aci"}, {"penumbra:shadow_rays", "1234"}});
        Image back = readImage(path);
        REQUIRE(back.width == 7);
        REQUIRE(back.height == 5);
        REQUIRE(back.channels == channels);
        CHECK(back.data == img.data);  // linear float: bit for bit, negative values included
        CHECK(readImageAttribute(path, "penumbra:method") == "aci");
        CHECK(readImageAttribute(path, "penumbra:shadow_rays") == "1234");
    }
    CHECK(dir.entries() == 3);  // no temporary file left next to them
}

TEST_CASE("PNG stores 8-bit sRGB: values come back within half a code", "[image_io]") {
    TempDir dir;
    Image img = ramp(9, 4, 3);
    std::string path = dir.file("img.png");
    writeImage(path, img, {{"penumbra:method", "aci-pixel"}});
    Image back = readImage(path);
    REQUIRE(back.width == 9);
    REQUIRE(back.height == 4);
    REQUIRE(back.channels == 3);
    for (size_t i = 0; i < img.data.size(); ++i) {
        float expected = linearToSrgb(img.data[i]) * 255.0f;  // clamps to [0, 255]
        float got = linearToSrgb(back.data[i]) * 255.0f;
        REQUIRE(std::abs(got - expected) <= 0.5f + 1e-3f);
        // Each code is the nearest one: an exact decode re-encodes to an integer.
        REQUIRE(std::abs(got - std::round(got)) < 1e-3f);
    }
    CHECK(readImageAttribute(path, "penumbra:method") == "aci-pixel");
}

TEST_CASE("an unknown extension is an InputError naming the flag, and writes nothing",
          "[image_io]") {
    TempDir dir;
    Image img(2, 2, 3, 0.5f);
    for (const char* name : {"out.bmp", "out", "out.exr.txt", "dir.png/out"}) {
        std::string path = dir.file(name);
        try {
            writeImage(path, img, {}, "-o");
            FAIL("no exception for " << name);
        } catch (const InputError& e) {
            CHECK(e.where() == "-o");
            CHECK(std::string(e.what()).find("-o") != std::string::npos);
        }
    }
    CHECK_THROWS_AS(imageFormatFor("x.tif", "--aov-rays"), InputError);
    try {
        imageFormatFor("x.tif", "--aov-rays");
    } catch (const InputError& e) {
        CHECK(e.where() == "--aov-rays");
    }
    CHECK(imageFormatFor("A.EXR") == ImageFormat::Exr);
    CHECK(imageFormatFor("dir.d/a.Png") == ImageFormat::Png);
    CHECK(dir.entries() == 0);
}

TEST_CASE("a failed write leaves no file, neither the target nor a temporary", "[image_io]") {
    TempDir dir;
    Image img(4, 3, 3, 0.25f);
    // The target is an existing directory: the image is written under the temporary name, then
    // rename() fails, and the temporary must be removed.
    fs::create_directories(dir.path / "taken.exr");
    CHECK_THROWS_AS(writeImage(dir.file("taken.exr"), img), std::runtime_error);
    CHECK(dir.entries() == 1);  // only the directory itself
    CHECK(fs::is_directory(dir.path / "taken.exr"));
    // A directory that does not exist: nothing can be created anywhere.
    CHECK_THROWS_AS(writeImage(dir.file("missing/out.png"), img), std::runtime_error);
    CHECK(dir.entries() == 1);
    // A malformed image is refused before any file is opened.
    Image bad(4, 3, 2);
    CHECK_THROWS_AS(writeImage(dir.file("two.exr"), bad), std::runtime_error);
    CHECK(dir.entries() == 1);
}

TEST_CASE("writing over an existing image replaces it whole", "[image_io]") {
    TempDir dir;
    std::string path = dir.file("same.exr");
    writeImage(path, Image(3, 3, 1, 1.0f));
    writeImage(path, Image(5, 2, 1, 2.0f));
    Image back = readImage(path);
    CHECK(back.width == 5);
    CHECK(back.height == 2);
    CHECK(back.data == std::vector<float>(10, 2.0f));
    CHECK(dir.entries() == 1);
}

TEST_CASE("heat map runs black, blue, red, yellow, white", "[image_io]") {
    Image s(6, 1, 1);
    float values[6] = {0.0f, 1.0f, 2.0f, 3.0f, 4.0f, 9.0f};
    for (int x = 0; x < 6; ++x) s.at(x, 0) = values[x];
    Image h = heatMap(s, 4.0f);
    REQUIRE(h.channels == 3);
    const float expected[6][3] = {{0, 0, 0}, {0, 0, 1}, {1, 0, 0}, {1, 1, 0}, {1, 1, 1}, {1, 1, 1}};
    for (int x = 0; x < 6; ++x) {
        for (int c = 0; c < 3; ++c) CHECK(h.at(x, 0, c) == Approx(expected[x][c]).margin(1e-6));
    }
    s.at(0, 0) = 0.5f;  // halfway between black and blue
    CHECK(heatMap(s, 4.0f).at(0, 0, 2) == Approx(0.5f));
}

TEST_CASE("the image module is loaded only to read or write an image, and its absence is one "
          "clear error that leaves no file", "[image_io][cli]") {
    test::TempDir dir("image_module", "image_io");
    test::writeFile(dir.path / "scene.json", R"({
  "camera": {"eye": [0, -6, 3], "look_at": [0, 0, 0.5], "up": [0, 0, 1], "fov_deg": 40,
             "width": 8, "height": 8},
  "lights": [{"corner": [-1, -1, 4], "edge_u": [0, 2, 0], "edge_v": [2, 0, 0],
              "radiance": [10, 10, 10]}],
  "obstacles": [{"type": "sphere", "center": [0, 0, 1], "radius": 0.5, "analytic": true}],
  "receivers": [{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]}]
})");
    test::writeFile(dir.path / "points.csv", "x,y,z,nx,ny,nz\n0,0,0,0,0,1\n");
    const std::string missing = (dir.path / "nowhere" / "penumbra_image_oiio.so").string();
    auto run = [&](const std::string& args) {
        return test::runShell("cd '" + dir.path.string() + "' && PENUMBRA_IMAGE_MODULE='" +
                                  missing + "' " + PENUMBRA_BINARY + " " + args,
                              dir.path);
    };
    // Without the module, what needs no image still works...
    CHECK(run("--version").exitCode == 0);
    const test::Run probe = run("probe scene.json < points.csv");
    CHECK(probe.exitCode == 0);
    CHECK_THAT(probe.out, Catch::Contains("form_factor"));
    // ... and a render fails on one line that says what is missing and where it looked, with no
    // image (nor a temporary) left.
    const test::Run render = run("render scene.json -o out.png -q");
    CHECK(render.exitCode == 1);
    CHECK_THAT(render.err, Catch::Contains("cannot write 'out.png': cannot load the image module "
                                           "penumbra_image_oiio.so (OpenImageIO)"));
    CHECK_THAT(render.err, Catch::Contains(missing + ": not found"));
    CHECK(std::count(render.err.begin(), render.err.end(), '\n') == 1);
    for (const auto& entry : fs::directory_iterator(dir.path)) {
        const std::string name = entry.path().filename().string();
        CHECK_THAT(name, !Catch::Contains("out"));
    }
    // With the module where the build put it (next to the program), the same render writes.
    const test::Run ok = test::runShell(
        "cd '" + dir.path.string() + "' && " + PENUMBRA_BINARY + " render scene.json -o out.png -q",
        dir.path);
    CHECK(ok.exitCode == 0);
    CHECK(fs::exists(dir.path / "out.png"));
    CHECK(readImage((dir.path / "out.png").string()).width == 8);
    // Reading without the module is the installation's failure too (exit 1), naming the file.
    const test::Run compare = run("compare out.png out.png");
    CHECK(compare.exitCode == 1);
    CHECK_THAT(compare.err, Catch::Contains("cannot read 'out.png': cannot load the image module"));
    // A module built against another layout of the table's types is refused by name, not called.
    const test::Run stale = test::runShell("cd '" + dir.path.string() +
                                               "' && PENUMBRA_IMAGE_MODULE='" +
                                               PENUMBRA_STALE_IMAGE_MODULE + "' " +
                                               PENUMBRA_BINARY + " render scene.json -o new.png -q",
                                           dir.path);
    CHECK(stale.exitCode == 1);
    CHECK_THAT(stale.err, Catch::Contains(std::string(PENUMBRA_STALE_IMAGE_MODULE) +
                                          ": not this build's image module"));
    CHECK_FALSE(fs::exists(dir.path / "new.png"));
}
