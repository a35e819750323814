#include "penumbra/image_io.h"
#include "penumbra/output_files.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <stdexcept>

#include <OpenImageIO/imageio.h>

#include "penumbra/error.h"

namespace penumbra {

namespace {

std::string lowerExtension(const std::string& path) {
    size_t slash = path.find_last_of('/');
    size_t dot = path.find_last_of('.');
    if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) return "";
    std::string ext = path.substr(dot);
    std::transform(ext.begin(), ext.end(), ext.begin(),
                   [](unsigned char c) { return char(std::tolower(c)); });
    return ext;
}

std::vector<std::string> channelNames(int channels) {
    switch (channels) {
        case 1: return {"Y"};
        case 3: return {"R", "G", "B"};
        case 4: return {"R", "G", "B", "A"};
        default: return {};
    }
}

}  // namespace

float linearToSrgb(float linear) {
    float v = std::min(1.0f, std::max(0.0f, linear));
    if (!(v == v)) v = 0.0f;  // NaN
    return v <= 0.0031308f ? 12.92f * v : 1.055f * std::pow(v, 1.0f / 2.4f) - 0.055f;
}

float srgbToLinear(float encoded) {
    float v = std::min(1.0f, std::max(0.0f, encoded));
    return v <= 0.04045f ? v / 12.92f : std::pow((v + 0.055f) / 1.055f, 2.4f);
}

ImageFormat imageFormatFor(const std::string& path, const std::string& flag) {
    std::string ext = lowerExtension(path);
    if (ext == ".exr") return ImageFormat::Exr;
    if (ext == ".png") return ImageFormat::Png;
    throw InputError("", flag,
                     "cannot write '" + path + "': unknown image extension '" + ext +
                         "' (use .exr for linear float or .png for 8-bit sRGB)");
}

void writeImage(const std::string& path, const Image& image, const ImageMetadata& metadata,
                const std::string& flag, const std::string& stagedFile) {
    ImageFormat format = imageFormatFor(path, flag);
    if (channelNames(image.channels).empty() || image.width < 1 || image.height < 1 ||
        image.data.size() != size_t(image.width) * image.height * image.channels) {
        throw std::runtime_error("cannot write '" + path + "': malformed image (" +
                                 std::to_string(image.width) + " x " +
                                 std::to_string(image.height) + " x " +
                                 std::to_string(image.channels) + ")");
    }
    const std::string tmp = stagedFile.empty() ? temporaryPathFor(path) : stagedFile;
    auto fail = [&](const std::string& why) {
        std::remove(tmp.c_str());
        throw std::runtime_error("cannot write '" + path + "': " + why);
    };

    auto out = OIIO::ImageOutput::create(path);
    if (!out) fail(OIIO::geterror());
    bool png = format == ImageFormat::Png;
    OIIO::ImageSpec spec(image.width, image.height, image.channels,
                         png ? OIIO::TypeDesc::UINT8 : OIIO::TypeDesc::FLOAT);
    spec.channelnames = channelNames(image.channels);
    if (image.channels == 4) spec.alpha_channel = 3;
    spec.attribute("oiio:ColorSpace", png ? "sRGB" : "Linear");
    spec.attribute("Software", "penumbra 0.1.0");
    for (const auto& [key, value] : metadata) spec.attribute(key, value);

    if (!out->open(tmp, spec)) fail(out->geterror());
    bool ok;
    if (png) {
        std::vector<unsigned char> bytes(image.data.size());
        for (size_t i = 0; i < bytes.size(); ++i) {
            bool alpha = image.channels == 4 && i % 4 == 3;
            float v = image.data[i];
            float e = alpha ? std::min(1.0f, std::max(0.0f, v == v ? v : 0.0f)) : linearToSrgb(v);
            bytes[i] = static_cast<unsigned char>(std::lround(e * 255.0f));
        }
        ok = out->write_image(OIIO::TypeDesc::UINT8, bytes.data());
    } else {
        ok = out->write_image(OIIO::TypeDesc::FLOAT, image.data.data());
    }
    if (!ok) {
        std::string why = out->geterror();
        out->close();
        fail(why);
    }
    if (!out->close()) fail(out->geterror());
    out.reset();
    if (!stagedFile.empty()) return;  // the caller renames it (OutputSet::commit)
    if (std::rename(tmp.c_str(), path.c_str()) != 0) fail(std::strerror(errno));
}

Image readImage(const std::string& path) {
    auto in = OIIO::ImageInput::open(path);
    if (!in) throw std::runtime_error("cannot read '" + path + "': " + OIIO::geterror());
    const OIIO::ImageSpec& spec = in->spec();
    // What the header claims is checked before anything is allocated: a small compressed file
    // can declare billions of pixels.
    {
        const double bytes = double(spec.width) * double(spec.height) * double(spec.nchannels) * 4.0;
        double limit = 256.0 * 1024.0 * 1024.0 * 1024.0;
        const long pages = ::sysconf(_SC_PHYS_PAGES), pageSize = ::sysconf(_SC_PAGE_SIZE);
        if (pages > 0 && pageSize > 0) limit = 0.25 * double(pages) * double(pageSize);
        if (spec.width < 1 || spec.height < 1 || spec.nchannels < 1 || spec.depth > 1) {
            throw std::runtime_error("cannot read '" + path + "': not a 2D image (" +
                                     std::to_string(spec.width) + " x " + std::to_string(spec.height) +
                                     " x " + std::to_string(spec.nchannels) + ")");
        }
        if (bytes > limit) {
            char text[160];
            std::snprintf(text, sizeof text,
                          "%d x %d pixels x %d channels would need %.1f GiB as floats, over the "
                          "limit of %.1f GiB (a quarter of this machine's memory)",
                          spec.width, spec.height, spec.nchannels, bytes / 1073741824.0,
                          limit / 1073741824.0);
            throw std::runtime_error("cannot read '" + path + "': " + text);
        }
    }
    Image image(spec.width, spec.height, spec.nchannels);
    if (!in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, image.data.data())) {
        std::string why = in->geterror();
        throw std::runtime_error("cannot read '" + path + "': " + why);
    }
    in->close();
    if (lowerExtension(path) == ".png") {
        for (size_t i = 0; i < image.data.size(); ++i) {
            bool alpha = image.channels == 4 && i % 4 == 3;
            if (!alpha) image.data[i] = srgbToLinear(image.data[i]);
        }
    }
    return image;
}

std::string readImageAttribute(const std::string& path, const std::string& name) {
    auto in = OIIO::ImageInput::open(path);
    if (!in) throw std::runtime_error("cannot read '" + path + "': " + OIIO::geterror());
    std::string value = in->spec().get_string_attribute(name);
    in->close();
    return value;
}

Image heatMap(const Image& scalar, float maxValue) {
    // Piecewise-linear ramp black -> blue -> red -> yellow -> white.
    static const float kStops[5][3] = {
        {0, 0, 0}, {0, 0, 1}, {1, 0, 0}, {1, 1, 0}, {1, 1, 1}};
    Image out(scalar.width, scalar.height, 3);
    for (int y = 0; y < scalar.height; ++y) {
        for (int x = 0; x < scalar.width; ++x) {
            float v = scalar.at(x, y, 0);
            if (!(v == v)) {
                out.at(x, y, 0) = 1.0f;
                out.at(x, y, 1) = 0.0f;
                out.at(x, y, 2) = 1.0f;
                continue;
            }
            float s = maxValue > 0.0f ? std::min(1.0f, std::max(0.0f, v / maxValue)) : 0.0f;
            float f = s * 4.0f;
            int i = std::min(3, int(f));
            float w = f - float(i);
            for (int c = 0; c < 3; ++c) {
                out.at(x, y, c) = (1.0f - w) * kStops[i][c] + w * kStops[i + 1][c];
            }
        }
    }
    return out;
}

}  // namespace penumbra
