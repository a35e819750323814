/// @file image_io.h
/// Float images in memory and their files, through OpenImageIO. The format follows the file's
/// extension: `.exr` stores linear float values as they are (32-bit float); `.png` stores 8-bit
/// sRGB-encoded values of the linear values clamped to [0, 1] (an alpha channel, the 4th, stays
/// linear). Files are written to a temporary name in the same directory and renamed when complete,
/// so a reader never sees a partial image and a failed write leaves no file behind.
///
/// Pixel (0, 0) is the top-left corner; channels are interleaved, rows top to bottom.
/// Thread safety: free functions, safe to call concurrently on different files.
///
/// OpenImageIO lives in a module of its own, penumbra_image_oiio.so, loaded on the first read or
/// write (its 250 or so libraries took 0.3-0.5 s of every run's start): from next to the program
/// (or the Python module) that uses this library, or from PENUMBRA_IMAGE_MODULE when that is set.
/// When it cannot be loaded, reads and writes throw ImageModuleError saying where it looked.
#pragma once

#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace penumbra {

struct Image {
    int width = 0;
    int height = 0;
    int channels = 0;
    std::vector<float> data;  ///< width * height * channels values, interleaved

    Image() = default;
    Image(int w, int h, int c, float fill = 0.0f)
        : width(w), height(h), channels(c), data(size_t(w) * size_t(h) * size_t(c), fill) {}

    float& at(int x, int y, int c = 0) { return data[(size_t(y) * width + x) * channels + c]; }
    float at(int x, int y, int c = 0) const {
        return data[(size_t(y) * width + x) * channels + c];
    }
};

/// Key / value pairs stored in the file's metadata (EXR header attributes, PNG text chunks).
using ImageMetadata = std::vector<std::pair<std::string, std::string>>;

enum class ImageFormat { Exr, Png };

/// The format for `path` from its extension (case-insensitive). Throws InputError whose `where`
/// is `flag` (the command-line option that named the file, e.g. "-o") for any other extension.
ImageFormat imageFormatFor(const std::string& path, const std::string& flag = "-o");

/// Writes `image` (1, 3 or 4 channels) to `path`, atomically. Throws InputError (see
/// imageFormatFor) for an unknown extension and std::runtime_error when the file cannot be
/// written; in both cases no file is left at `path` or at the temporary name. With
/// `stagedFile` (OutputSet::stage), the image goes to that file instead and is not renamed:
/// `path` then only picks the format and names the file in messages.
void writeImage(const std::string& path, const Image& image, const ImageMetadata& metadata = {},
                const std::string& flag = "-o", const std::string& stagedFile = "");

/// The image module cannot be loaded (a broken installation, not bad input): what reads and
/// writes throw then, "cannot read|write 'FILE': cannot load the image module ...".
struct ImageModuleError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

/// Loads the image module now (it is loaded on the first read or write anyway), so that a run
/// that will write images can fail before its work rather than after. Throws ImageModuleError.
void requireImageModule();

/// Reads an image as linear float values (PNG values are decoded from sRGB, alpha kept).
/// Throws std::runtime_error when the file cannot be read.
Image readImage(const std::string& path);

/// Reads one metadata attribute of an image file as a string ("" when absent).
std::string readImageAttribute(const std::string& path, const std::string& name);

/// sRGB transfer functions (IEC 61966-2-1), on values clamped to [0, 1].
float linearToSrgb(float linear);
float srgbToLinear(float encoded);

/// A 3-channel false-colour picture of a 1-channel image: 0 is black, then blue, red, yellow,
/// and `maxValue` (and above) is white. NaN maps to magenta. For AOVs (rays per pixel).
Image heatMap(const Image& scalar, float maxValue);

}  // namespace penumbra
