// `penumbra batch`: placeholder registration; the implementation lands with its issue.
#include "cli/commands.h"

namespace penumbra::cli {

Runner addBatchCommand(CLI::App& app) {
    app.add_subcommand("batch", "Run a batch manifest (not implemented yet)");
    return []() -> int { throw std::runtime_error("batch is not implemented yet"); };
}

}  // namespace penumbra::cli
