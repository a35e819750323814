#include "penumbra/image_io.h"
#include "penumbra/output_files.h"

#include <dlfcn.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <stdexcept>

#include "image_backend.h"
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

std::string directoryOf(const std::string& file) {
    const size_t slash = file.find_last_of('/');
    return slash == std::string::npos ? "." : file.substr(0, slash);
}

// Loading the image module (image_backend.h), once per process: about 0.3 s, OpenImageIO and the
// 260 libraries it links. (Loading it on a thread of its own while a render runs gained nothing
// measurable on 2 cores: render-default took 2.73-2.94 s either way. Nor while the scene loads:
// the scene's loading then took 0.39 s instead of 0.085, waiting on the dynamic loader's lock.)
struct BackendLoader {
    std::once_flag once;
    const detail::ImageBackend* backend = nullptr;
    std::string error;

    // Where the module may be: PENUMBRA_IMAGE_MODULE alone when set; else next to the object
    // this code is in (the program, or the Python module), next to the running program, and
    // where the build put it.
    static std::vector<std::string> candidates() {
        if (const char* env = std::getenv("PENUMBRA_IMAGE_MODULE"); env && *env) {
            // A bare name would pass access() here and then send dlopen to the library path.
            const std::string named(env);
            return {named.find('/') == std::string::npos ? "./" + named : named};
        }
        std::vector<std::string> out;
        Dl_info info;
        // (An absolute name only: the program's own may come as typed, relative to nothing.)
        if (dladdr(reinterpret_cast<void*>(&directoryOf), &info) && info.dli_fname &&
            info.dli_fname[0] == '/')
            out.push_back(directoryOf(info.dli_fname) + "/" + detail::kImageModuleName);
        char exe[4096];
        const ssize_t n = ::readlink("/proc/self/exe", exe, sizeof exe - 1);
        if (n > 0) {
            exe[n] = '\0';
            out.push_back(directoryOf(exe) + "/" + detail::kImageModuleName);
        }
#ifdef PENUMBRA_IMAGE_MODULE_BUILT
        out.push_back(PENUMBRA_IMAGE_MODULE_BUILT);
#endif
        return out;
    }

    void load() {
        std::string tried;
        std::vector<std::string> seen;
        for (const std::string& path : candidates()) {
            if (std::find(seen.begin(), seen.end(), path) != seen.end()) continue;
            seen.push_back(path);
            if (::access(path.c_str(), F_OK) != 0) {
                tried += (tried.empty() ? "" : "; ") + path + ": not found";
                continue;
            }
            void* handle = ::dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
            if (!handle) {
                const char* why = ::dlerror();
                tried += (tried.empty() ? "" : "; ") + path + ": " +
                         std::string(why ? why : "not loaded");
                continue;
            }
            using Entry = const detail::ImageBackend* (*)();
            const auto entry = reinterpret_cast<Entry>(::dlsym(handle, "penumbra_image_backend"));
            const detail::ImageBackend* b = entry ? entry() : nullptr;
            if (!b || b->version != detail::kImageBackendVersion ||
                b->layout != detail::kImageBackendLayout) {
                tried += (tried.empty() ? "" : "; ") + path +
                         ": not this build's image module (rebuild penumbra)";
                continue;
            }
            backend = b;
            return;
        }
        error = std::string("cannot load the image module ") + detail::kImageModuleName +
                " (OpenImageIO), which reads and writes image files: " +
                (tried.empty() ? "no place to look" : tried);
    }
};

BackendLoader& loader() {
    static BackendLoader instance;
    return instance;
}

}  // namespace

const detail::ImageBackend& detail::imageBackend() {
    BackendLoader& l = loader();
    std::call_once(l.once, [&] { l.load(); });
    if (!l.backend) throw ImageModuleError(l.error);
    return *l.backend;
}

void requireImageModule() { detail::imageBackend(); }

namespace {

// The backend to `verb` ("read", "write") `path` with: a module that cannot be loaded names the
// file too.
const detail::ImageBackend& backendFor(const char* verb, const std::string& path) {
    try {
        return detail::imageBackend();
    } catch (const ImageModuleError& e) {
        throw ImageModuleError(std::string("cannot ") + verb + " '" + path + "': " + e.what());
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
    const bool channelsOk = image.channels == 1 || image.channels == 3 || image.channels == 4;
    if (!channelsOk || image.width < 1 || image.height < 1 ||
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

    const detail::ImageBackend* backend = nullptr;
    try {
        backend = &backendFor("write", path);
    } catch (const ImageModuleError&) {
        std::remove(tmp.c_str());
        throw;
    }
    std::vector<unsigned char> bytes;
    if (format == ImageFormat::Png) {
        bytes.resize(image.data.size());
        for (size_t i = 0; i < bytes.size(); ++i) {
            bool alpha = image.channels == 4 && i % 4 == 3;
            float v = image.data[i];
            float e = alpha ? std::min(1.0f, std::max(0.0f, v == v ? v : 0.0f)) : linearToSrgb(v);
            bytes[i] = static_cast<unsigned char>(std::lround(e * 255.0f));
        }
    }
    const std::string why = backend->write(path, tmp, image, bytes, metadata);
    if (!why.empty()) fail(why);
    if (!stagedFile.empty()) return;  // the caller renames it (OutputSet::commit)
    if (std::rename(tmp.c_str(), path.c_str()) != 0) fail(std::strerror(errno));
}

Image readImage(const std::string& path) {
    Image image = backendFor("read", path).read(path);
    if (lowerExtension(path) == ".png") {
        for (size_t i = 0; i < image.data.size(); ++i) {
            bool alpha = image.channels == 4 && i % 4 == 3;
            if (!alpha) image.data[i] = srgbToLinear(image.data[i]);
        }
    }
    return image;
}

std::string readImageAttribute(const std::string& path, const std::string& name) {
    return backendFor("read", path).attribute(path, name);
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
