// The image backend module (src/image_backend.h): image files through OpenImageIO. Built as
// penumbra_image_oiio.so and loaded by the library on first use; it uses nothing of the library
// but the Image type's header.
#include <unistd.h>

#include <cstdio>
#include <stdexcept>

#include <OpenImageIO/imageio.h>

#include "image_backend.h"

namespace {

using penumbra::Image;
using penumbra::ImageMetadata;

std::vector<std::string> channelNames(int channels) {
    switch (channels) {
        case 1: return {"Y"};
        case 3: return {"R", "G", "B"};
        case 4: return {"R", "G", "B", "A"};
        default: return {};
    }
}

// What OpenImageIO said went wrong, never empty (an empty message would read as success).
std::string orUnknown(std::string why) {
    return why.empty() ? "OpenImageIO failed without saying why" : why;
}

std::string write(const std::string& path, const std::string& file, const Image& image,
                  const std::vector<unsigned char>& bytes, const ImageMetadata& metadata) {
    auto out = OIIO::ImageOutput::create(path);
    if (!out) return orUnknown(OIIO::geterror());
    const bool png = !bytes.empty();
    OIIO::ImageSpec spec(image.width, image.height, image.channels,
                         png ? OIIO::TypeDesc::UINT8 : OIIO::TypeDesc::FLOAT);
    spec.channelnames = channelNames(image.channels);
    if (image.channels == 4) spec.alpha_channel = 3;
    spec.attribute("oiio:ColorSpace", png ? "sRGB" : "Linear");
    spec.attribute("Software", "penumbra 0.1.0");
    for (const auto& [key, value] : metadata) spec.attribute(key, value);

    if (!out->open(file, spec)) return orUnknown(out->geterror());
    const bool ok = png ? out->write_image(OIIO::TypeDesc::UINT8, bytes.data())
                        : out->write_image(OIIO::TypeDesc::FLOAT, image.data.data());
    if (!ok) {
        std::string why = out->geterror();
        out->close();
        return orUnknown(why);
    }
    if (!out->close()) return orUnknown(out->geterror());
    return "";
}

Image read(const std::string& path) {
    auto in = OIIO::ImageInput::open(path);
    if (!in) throw std::runtime_error("cannot read '" + path + "': " + OIIO::geterror());
    const OIIO::ImageSpec& spec = in->spec();
    // What the header claims is checked before anything is allocated: a small compressed file
    // can declare billions of pixels.
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
    Image image(spec.width, spec.height, spec.nchannels);
    if (!in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, image.data.data())) {
        std::string why = in->geterror();
        throw std::runtime_error("cannot read '" + path + "': " + why);
    }
    in->close();
    return image;
}

std::string attribute(const std::string& path, const std::string& name) {
    auto in = OIIO::ImageInput::open(path);
    if (!in) throw std::runtime_error("cannot read '" + path + "': " + OIIO::geterror());
    std::string value = in->spec().get_string_attribute(name);
    in->close();
    return value;
}

const penumbra::detail::ImageBackend kBackend{penumbra::detail::kImageBackendVersion,
                                              penumbra::detail::kImageBackendLayout, &write,
                                              &read, &attribute};

}  // namespace

extern "C" __attribute__((visibility("default"))) const penumbra::detail::ImageBackend*
penumbra_image_backend() {
    return &kBackend;
}
