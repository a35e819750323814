// Shared by the benchmarks (bench_*.cpp): walking the command line, the render settings every
// method starts from, and how an error ends a benchmark. A header, not a .cpp: every .cpp in
// bench/ is built as a benchmark of its own.
#pragma once

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "penumbra/error.h"
#include "penumbra/renderer.h"

namespace bench {

/// Prints "PROGRAM: MESSAGE" on stderr and exits with 2: a benchmark's bad command line.
[[noreturn]] inline void failUsage(const char* program, const std::string& message) {
    std::fprintf(stderr, "%s: %s\n", program, message.c_str());
    std::exit(2);
}

/// For a benchmark that takes positional arguments only: prints `usage` and exits with 0 when
/// the first word is -h or --help.
inline void helpIfAsked(int argc, char** argv, const char* usage) {
    if (argc > 1 && (std::string(argv[1]) == "-h" || std::string(argv[1]) == "--help")) {
        std::printf("%s\n", usage);
        std::exit(0);
    }
}

/// A positional count or size: the whole word a number of at least 1, else failUsage naming
/// `what` (a benchmark of 0 segments prints nothing worth reading).
inline double positiveArg(const char* program, const char* word, const char* what) {
    char* end = nullptr;
    const double v = std::strtod(word, &end);
    if (end == word || *end != '\0' || !(v >= 1.0))
        failUsage(program, std::string(what) + ": '" + word + "' is not a number of at least 1");
    return v;
}

/// One option of a benchmark: its name and what it sets. An int, double or string target takes
/// the next word (std::atoi, std::atof, as is); a flag takes none and runs its action.
struct Option {
    Option(std::string n, int* target)
        : name(std::move(n)),
          set([target](const std::string& v) { *target = std::atoi(v.c_str()); }) {}
    Option(std::string n, double* target)
        : name(std::move(n)),
          set([target](const std::string& v) { *target = std::atof(v.c_str()); }) {}
    Option(std::string n, std::string* target)
        : name(std::move(n)), set([target](const std::string& v) { *target = v; }) {}
    Option(std::string n, std::function<void()> action)
        : name(std::move(n)), flag(std::move(action)) {}

    std::string name;
    std::function<void(const std::string&)> set;  // empty for a flag
    std::function<void()> flag;
};

/// Reads argv against `options`. A word that is no option goes to `positional` if there is one
/// and the word does not start with '-'. Errors, as failUsage: "OPTION needs a value",
/// "unknown option WORD". -h or --help prints the options and exits with 0.
inline void parseOptions(const char* program, int argc, char** argv,
                         const std::vector<Option>& options, std::string* positional = nullptr) {
    for (int i = 1; i < argc; ++i) {
        const std::string word = argv[i];
        if (word == "-h" || word == "--help") {
            std::printf("usage: %s", program);
            for (const Option& o : options)
                std::printf(" [%s%s]", o.name.c_str(), o.flag ? "" : " VALUE");
            if (positional) std::printf(" [ARG]");
            std::printf("\n(what each does and its default: the comment at the top of bench/%s.cpp)\n",
                        program);
            std::exit(0);
        }
        const auto option = std::find_if(options.begin(), options.end(),
                                         [&](const Option& o) { return o.name == word; });
        if (option == options.end()) {
            if (!positional || word.empty() || word[0] == '-')
                failUsage(program, "unknown option " + word);
            *positional = word;
        } else if (option->flag) {
            option->flag();
        } else {
            if (i + 1 >= argc) failUsage(program, word + " needs a value");
            option->set(argv[++i]);
        }
    }
}

/// Settings for `method` on a size x size image with `threads` threads; everything else default
/// but the gradient and the error bound (see below).
inline penumbra::RenderSettings squareSettings(penumbra::Method method, int size, int threads) {
    penumbra::RenderSettings rs;
    rs.method = method;
    rs.width = size;
    rs.height = size;
    rs.threads = threads;
    // As `penumbra render` without AOV files: neither the gradient nor the error bound, which
    // nothing here reads (the bound's last step alone adds about half to a random scene's
    // render).
    rs.aci.gradient = false;
    rs.aci.errorBound = false;
    return rs;
}

/// Call in a benchmark's `catch (...)`: prints "PROGRAM: WHAT" on stderr and returns the exit
/// code, 2 for an InputError (a bad scene or option), 1 for any other std::exception. Anything
/// else is not caught.
inline int reportException(const char* program) {
    try {
        throw;
    } catch (const penumbra::InputError& e) {
        std::fprintf(stderr, "%s: %s\n", program, e.what());
        return 2;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "%s: %s\n", program, e.what());
        return 1;
    }
}

}  // namespace bench
