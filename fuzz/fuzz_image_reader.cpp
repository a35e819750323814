// libFuzzer target for reading images (`penumbra compare`): any byte string, written to a file
// with the .exr or .png extension (chosen by the first byte), must either read or be refused
// with std::runtime_error; sanitizers must stay quiet. Seeded with small images that
// scripts/fuzz.sh renders.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <stdexcept>
#include <string>

#include "penumbra/image_io.h"

// Without the image module every input would be refused alike and nothing fuzzed: stop at once.
extern "C" int LLVMFuzzerInitialize(int*, char***) {
    try {
        penumbra::requireImageModule();
    } catch (const std::exception& e) {
        std::fprintf(stderr, "fuzz_image_reader: %s\n", e.what());
        std::abort();
    }
    return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    if (size == 0) return 0;
    const bool png = size >= 8 && data[1] == 'P' && data[2] == 'N' && data[3] == 'G';
    const std::string path = "/tmp/penumbra_fuzz_" + std::to_string(::getpid()) +
                             (png ? ".png" : ".exr");
    {
        std::ofstream out(path, std::ios::binary | std::ios::trunc);
        out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
    }
    try {
        penumbra::readImage(path);
    } catch (const std::runtime_error&) {
        // refused with a message naming the file
    }
    std::remove(path.c_str());
    return 0;
}
