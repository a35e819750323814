// Subcommands of the `penumbra` program. Each registers its options on a CLI11 subcommand and
// returns a runner to call after parsing. The runners return the process exit code; errors
// propagate as exceptions (InputError -> 2, anything else -> 1) to main().
#pragma once

#include <algorithm>
#include <functional>
#include <string>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "penumbra/error.h"
#include "penumbra/render_settings.h"

namespace penumbra::cli {

using Runner = std::function<int()>;

// Settings flags are the keys of the JSON model (render_settings.h) with dashes
// (settings_flags.h); errors about a key are reported against its flag.

/// Runs `body` (reading or checking settings); an InputError about a key of the model is
/// thrown again about its flag.
template <class F>
void withFlagNames(F&& body) {
    try {
        body();
    } catch (const InputError& e) {
        const std::vector<std::string>& keys = RenderSettings::keys();
        if (std::find(keys.begin(), keys.end(), e.where()) == keys.end()) throw;
        throw InputError(e.file(), flagOfKey(e.where()), e.message());
    }
}

Runner addProbeCommand(CLI::App& app);
Runner addRenderCommand(CLI::App& app);
Runner addBakeCommand(CLI::App& app);
Runner addCompareCommand(CLI::App& app);
Runner addBatchCommand(CLI::App& app);

}  // namespace penumbra::cli
