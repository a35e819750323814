// penumbra: direct illumination from area lights over OpenVDB level sets by approximate
// contour integration. This file only dispatches to the subcommands and maps errors to exit
// codes: 2 for bad input (one line naming the file and field), 1 for runtime failures.
#include <iostream>
#include <map>
#include <string>

#include "cli/commands.h"
#include "penumbra/error.h"

int main(int argc, char** argv) {
    CLI::App app{"penumbra: soft shadows from area lights over OpenVDB level sets, by approximate "
                 "contour integration (Vedel 1993)"};
    app.require_subcommand(1);
    app.set_version_flag("--version", "penumbra 0.1.0");
    std::map<std::string, penumbra::cli::Runner> runners;
    runners["probe"] = penumbra::cli::addProbeCommand(app);
    runners["render"] = penumbra::cli::addRenderCommand(app);
    runners["bake"] = penumbra::cli::addBakeCommand(app);
    runners["compare"] = penumbra::cli::addCompareCommand(app);
    runners["batch"] = penumbra::cli::addBatchCommand(app);
    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
        // --help and --version print their text and succeed; a malformed command line is bad
        // input: one line with the program's prefix, exit code 2.
        if (e.get_exit_code() == 0) return app.exit(e);
        std::string what = e.what();
        for (char& c : what) {
            if (c == '\n') c = ' ';
        }
        std::cerr << "penumbra: error: " << what << " (see penumbra --help)\n";
        return 2;
    }
    try {
        for (auto* sub : app.get_subcommands()) return runners.at(sub->get_name())();
    } catch (const penumbra::InputError& e) {
        std::cerr << "penumbra: error: " << e.what() << "\n";
        return 2;
    } catch (const std::exception& e) {
        std::cerr << "penumbra: error: " << e.what() << "\n";
        return 1;
    }
    return 0;
}
