// Subcommands of the `penumbra` program. Each registers its options on a CLI11 subcommand and
// returns a runner to call after parsing. The runners return the process exit code; errors
// propagate as exceptions (InputError -> 2, anything else -> 1) to main().
#pragma once

#include <functional>

#include <CLI/CLI.hpp>

namespace penumbra::cli {

using Runner = std::function<int()>;

Runner addProbeCommand(CLI::App& app);
Runner addRenderCommand(CLI::App& app);
Runner addBakeCommand(CLI::App& app);
Runner addCompareCommand(CLI::App& app);
Runner addBatchCommand(CLI::App& app);

}  // namespace penumbra::cli
