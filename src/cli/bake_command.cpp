// `penumbra bake`: writes every obstacle's level set as a named grid of one .vdb file.
// (Placeholder registration; the implementation lands with the scenes issue.)
#include "cli/commands.h"
#include "penumbra/error.h"

namespace penumbra::cli {

Runner addBakeCommand(CLI::App& app) {
    auto scene = std::make_shared<std::string>();
    auto out = std::make_shared<std::string>();
    CLI::App* sub = app.add_subcommand("bake", "Write every obstacle's level set to a .vdb file");
    sub->add_option("scene", *scene, "Scene file (JSON)")->required();
    sub->add_option("-o,--output", *out, "Output .vdb file")->required();
    return [] () -> int { throw std::runtime_error("bake is not implemented yet"); };
}

}  // namespace penumbra::cli
