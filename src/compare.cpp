#include "penumbra/compare.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "penumbra/error.h"

namespace penumbra {

namespace {

std::string sizeOf(const Image& i) {
    return std::to_string(i.width) + "x" + std::to_string(i.height) + "x" +
           std::to_string(i.channels);
}

void requireSameShape(const Image& test, const Image& ref) {
    if (test.width != ref.width || test.height != ref.height || test.channels != ref.channels) {
        throw InputError(
            "", "REF",
            "the images differ in size or channels: " + sizeOf(test) + " vs " + sizeOf(ref));
    }
}

// Sums kept in long double: 800 x 800 x 3 squared differences add up without losing the
// small ones.
struct Accumulator {
    size_t pixels = 0;
    long double sum = 0.0L, sumSq = 0.0L;
    double max = 0.0;

    void add(double d) {
        sum += d;
        sumSq += (long double)d * d;
        max = std::max(max, d);
    }
    DifferenceStats result(int channels) const {
        DifferenceStats s;
        s.pixels = pixels;
        if (pixels == 0) return s;
        const long double n = (long double)pixels * channels;
        s.mean = double(sum / n);
        s.rmse = double(std::sqrt(sumSq / n));
        s.max = max;
        return s;
    }
};

}  // namespace

ImageDifference compareImages(const Image& test, const Image& ref, const Image* mask) {
    requireSameShape(test, ref);
    if (mask && (mask->width != test.width || mask->height != test.height || mask->channels < 1)) {
        throw InputError("", "--mask",
                         "the mask is " + sizeOf(*mask) + ", the images " + sizeOf(test));
    }
    Accumulator all, inMask;
    for (int y = 0; y < test.height; ++y) {
        for (int x = 0; x < test.width; ++x) {
            const bool counted = mask && mask->at(x, y, 0) > 0.5f;
            ++all.pixels;
            if (counted) ++inMask.pixels;
            for (int c = 0; c < test.channels; ++c) {
                const double d =
                    255.0 * std::abs(double(test.at(x, y, c)) - double(ref.at(x, y, c)));
                all.add(d);
                if (counted) inMask.add(d);
            }
        }
    }
    ImageDifference out;
    out.all = all.result(test.channels);
    out.masked = inMask.result(test.channels);
    out.hasMask = mask != nullptr;
    return out;
}

Image differenceImage(const Image& test, const Image& ref) {
    requireSameShape(test, ref);
    Image out(test.width, test.height, 1);
    for (int y = 0; y < test.height; ++y) {
        for (int x = 0; x < test.width; ++x) {
            double sum = 0.0;
            for (int c = 0; c < test.channels; ++c) {
                sum += std::abs(double(test.at(x, y, c)) - double(ref.at(x, y, c)));
            }
            out.at(x, y) = float(255.0 * sum / std::max(1, test.channels));
        }
    }
    return out;
}

void requireFinite(const Image& image, const std::string& file, const std::string& what) {
    for (size_t i = 0; i < image.data.size(); ++i) {
        if (std::isfinite(image.data[i])) continue;
        const size_t pixel = i / size_t(image.channels);
        throw InputError(file, what,
                         "holds a non-finite value (" + std::to_string(image.data[i]) +
                             ") at pixel " + std::to_string(pixel % size_t(image.width)) + ", " +
                             std::to_string(pixel / size_t(image.width)) +
                             ": no difference can be measured");
    }
}

}  // namespace penumbra
