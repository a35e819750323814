/// @file hash.h
/// FNV-1a 64: the non-cryptographic hash behind batch job hashes, output content records
/// (resume) and level-set cache keys. Fast and stable across platforms; not a defence against
/// someone forging a collision.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>

namespace penumbra {

constexpr uint64_t kFnvOffset = 1469598103934665603ull;

/// FNV-1a 64 of `bytes`, continuing from `h` (kFnvOffset to start).
inline uint64_t fnv1a64(std::string_view bytes, uint64_t h = kFnvOffset) {
    for (unsigned char c : bytes) {
        h ^= c;
        h *= 1099511628211ull;
    }
    return h;
}

/// 16 lower-case hex digits.
std::string hex16(uint64_t v);

/// A file's size and content hash.
struct FileDigest {
    uint64_t bytes = 0;
    std::string hash;  ///< hex16 of FNV-1a 64 of the file's bytes
};

/// Throws std::runtime_error when the file cannot be read.
FileDigest digestFile(const std::string& path);

}  // namespace penumbra
