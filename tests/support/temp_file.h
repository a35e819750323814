// A scratch file for tests that read files (meshes, grids): a fresh path under the system's
// temporary directory, unique per process and per object, removed at scope exit.
#pragma once

#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <string>
#include <system_error>

namespace test {

/// The path temp_directory_path()/penumbra_test_TAG_PID_N SUFFIX (N counts the objects made);
/// with `text`, the file is written with it.
class TempFile {
  public:
    TempFile(const std::string& tag, const std::string& suffix) {
        static std::atomic<int> counter{0};
        mPath = (std::filesystem::temp_directory_path() /
                 ("penumbra_test_" + tag + "_" + std::to_string(::getpid()) + "_" +
                  std::to_string(counter++) + suffix))
                    .string();
    }
    TempFile(const std::string& tag, const std::string& suffix, const std::string& text)
        : TempFile(tag, suffix) {
        std::ofstream(mPath) << text;
    }
    ~TempFile() {
        std::error_code ec;
        std::filesystem::remove(mPath, ec);
    }
    TempFile(const TempFile&) = delete;
    TempFile& operator=(const TempFile&) = delete;
    const std::string& path() const { return mPath; }

  private:
    std::string mPath;
};

}  // namespace test
