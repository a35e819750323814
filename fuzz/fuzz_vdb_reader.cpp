// libFuzzer target for the checks Penumbra makes on a .vdb file before OpenVDB reads its trees
// (checkVdbFile: header, metadata and grid descriptors, read with OpenVDB's readers): any byte
// string, written to a file, must pass or be refused with InputError; nothing else may escape,
// and sanitizers must stay quiet. OpenVDB's tree reader itself is not fuzzed here: on corrupt
// tree bytes it allocates what the garbage says (ASan aborts on such an allocation; a release
// build throws std::bad_alloc, which readLevelSets reports as a runtime failure, exit 1).
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <stdexcept>
#include <string>

#include "penumbra/error.h"
#include "penumbra/level_set.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    static const std::string path = "/tmp/penumbra_fuzz_" + std::to_string(::getpid()) + ".vdb";
    {
        std::ofstream out(path, std::ios::binary | std::ios::trunc);
        out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
    }
    try {
        penumbra::checkVdbFile(path, "/obstacles/0");
    } catch (const penumbra::InputError&) {
        // refused with a message naming the file
    }
    std::remove(path.c_str());
    return 0;
}
