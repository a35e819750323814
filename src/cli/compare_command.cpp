// `penumbra compare`: placeholder registration; the implementation lands with its issue.
#include "cli/commands.h"

namespace penumbra::cli {

Runner addCompareCommand(CLI::App& app) {
    app.add_subcommand("compare", "Compare two images (not implemented yet)");
    return []() -> int { throw std::runtime_error("compare is not implemented yet"); };
}

}  // namespace penumbra::cli
