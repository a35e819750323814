// The image files' backend (image_io.cpp's reading and writing): OpenImageIO, in a module of its
// own (penumbra_image_oiio.so, src/image_oiio/) that the library loads the first time a file is
// read or written. OpenImageIO brings some 250 shared libraries, and loading them took 0.3-0.5 s
// at the start of every run that linked it, probes and `--version` included.
//
// The module exports one C function, penumbra_image_backend(), returning this table. Both sides
// are built together (same compiler and standard library), so the table passes C++ types and
// the module's functions may throw std::runtime_error.
#pragma once

#include <string>
#include <vector>

#include "penumbra/image_io.h"

namespace penumbra::detail {

/// Raised when the table's meaning changes, so that a stale module is refused by name.
constexpr int kImageBackendVersion = 1;

/// The sizes of what crosses the table, as this side was compiled: a module built against
/// another layout of these types (a copied program finding an older build tree's module, or
/// another compiler's standard library) is refused even if nobody raised the version.
constexpr unsigned long long kImageBackendLayout =
    sizeof(Image) | (sizeof(ImageMetadata) << 12) | (sizeof(std::string) << 24) |
    (sizeof(std::vector<float>) << 32) | (sizeof(std::vector<unsigned char>) << 40) |
    (static_cast<unsigned long long>(sizeof(void*)) << 52);

/// The module's file name, looked for next to the program or library that loads it.
constexpr const char* kImageModuleName = "penumbra_image_oiio.so";

struct ImageBackend {
    int version;
    /// kImageBackendLayout as the module was compiled.
    unsigned long long layout;
    /// Writes `image` to `file` in the format of `path`'s extension (`path` names the image in
    /// the file's own metadata and messages): a PNG from `bytes` (8-bit values, already
    /// encoded), an EXR from the image's floats. Returns "" when written, else why not (`file`
    /// may then hold part of the image; the caller removes it).
    std::string (*write)(const std::string& path, const std::string& file, const Image& image,
                         const std::vector<unsigned char>& bytes, const ImageMetadata& metadata);
    /// The values of `path` as floats, as the file stores them (no sRGB decoding). Throws
    /// std::runtime_error naming the file.
    Image (*read)(const std::string& path);
    /// One metadata attribute of `path` as a string ("" when absent). Throws like `read`.
    std::string (*attribute)(const std::string& path, const std::string& name);
};

/// The loaded backend (loaded on the first call; later calls wait for a load in progress).
/// Throws ImageModuleError naming the module and why it could not be loaded.
const ImageBackend& imageBackend();

}  // namespace penumbra::detail

extern "C" const penumbra::detail::ImageBackend* penumbra_image_backend();
