// libFuzzer target for the scene loader: any byte string must either load or be refused with
// InputError; nothing else may escape, and sanitizers must stay quiet. Inputs that parse as
// JSON get a small level-set memory budget so that the fuzzer explores the loader, not
// OpenVDB's level-set builders at huge resolutions.
#include <cstddef>
#include <cstdint>
#include <string>

#include <nlohmann/json.hpp>

#include "penumbra/error.h"
#include "penumbra/scene.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    std::string text(reinterpret_cast<const char*>(data), size);
    try {
        nlohmann::json j = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/false,
                                                 /*ignore_comments=*/true);
        if (j.is_object()) {
            auto it = j.find("level_set");
            if (it == j.end() || it->is_object()) {
                j["level_set"]["max_memory_gib"] = 0.02;
                text = j.dump();
            }
        }
    } catch (const std::exception&) {
        // Not representable after parsing (e.g. invalid UTF-8 in dump): feed the raw bytes.
    }
    try {
        penumbra::parseScene(text, "fuzz.json", "/nonexistent-fuzz-dir");
    } catch (const penumbra::InputError&) {
        // Refused with a message: the expected outcome for bad input.
    }
    return 0;
}
