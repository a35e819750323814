/// @file compare.h
/// Differences between two images of the same size, in 8-bit units (255 x the linear
/// difference), as in the "average difference" of Vedel 1993, Table 1: the mean absolute
/// difference, the root mean square and the maximum over every pixel and channel, and the same
/// over the pixels of a mask (e.g. the renderer's mask AOV: where shadow rays were cast).
///
/// Units: linear values as stored in EXR; differences are reported x 255.
/// Thread safety: pure functions.
#pragma once

#include <string>

#include <cstddef>

#include "penumbra/image_io.h"

namespace penumbra {

struct DifferenceStats {
    size_t pixels = 0;  ///< pixels counted (each contributes all its channels)
    double mean = 0.0;  ///< mean over pixels and channels of 255 |test - ref|
    double rmse = 0.0;  ///< sqrt of the mean of (255 (test - ref))^2
    double max = 0.0;   ///< largest 255 |test - ref|
};

struct ImageDifference {
    DifferenceStats all;     ///< every pixel
    DifferenceStats masked;  ///< pixels whose mask value (first channel) is > 0.5
    bool hasMask = false;
};

/// Compares `test` with `ref` (same width, height and channels; every channel counts) and, when
/// `mask` is given, also over its pixels (same width and height, any channels). Throws
/// InputError (`where` is "REF" or "--mask") when the sizes or channel counts differ.
ImageDifference compareImages(const Image& test, const Image& ref, const Image* mask = nullptr);

/// Throws InputError(file, what, ...) naming the first non-finite value and its pixel: a NaN
/// would vanish from every figure (it compares false with everything).
void requireFinite(const Image& image, const std::string& file, const std::string& what);

/// One channel: per pixel, the mean over channels of 255 |test - ref| (for error maps: pass it
/// to heatMap()). Same preconditions as compareImages.
Image differenceImage(const Image& test, const Image& ref);

}  // namespace penumbra
