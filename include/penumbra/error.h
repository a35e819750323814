/// @file error.h
/// The one exception type for bad input. Library code validates at its boundary (scene loading,
/// CLI options) and throws InputError; only `main()` catches, prints `what()` on one line and
/// exits with code 2. Runtime failures (I/O after validation, out of memory) use
/// std::runtime_error and exit code 1.
#pragma once

#include <stdexcept>
#include <string>

namespace penumbra {

class InputError : public std::runtime_error {
public:
    /// `file` is the input file (may be empty), `where` the JSON pointer or flag (may be empty).
    InputError(const std::string& file, const std::string& where, const std::string& message)
        : std::runtime_error(compose(file, where, message)),
          mFile(file),
          mWhere(where),
          mMessage(message) {}

    const std::string& file() const { return mFile; }
    const std::string& where() const { return mWhere; }
    const std::string& message() const { return mMessage; }

private:
    static std::string compose(const std::string& file, const std::string& where,
                               const std::string& message) {
        std::string s;
        if (!file.empty()) s += file + ": ";
        if (!where.empty()) s += where + ": ";
        return s + message;
    }
    std::string mFile, mWhere, mMessage;
};

}  // namespace penumbra
