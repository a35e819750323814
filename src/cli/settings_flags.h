// The settings flags of `render` and `probe`: each is a key of the settings model
// (render_settings.h) with dashes, registered from one table with its help text. The flags given
// are read as a batch manifest's keys are (RenderSettings::readJson, validate), and an error
// about a key is reported against its flag.
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "penumbra/render_settings.h"

namespace penumbra::cli {

class SettingsFlags {
public:
    /// Registers the flags of `keys` on `cmd`; `help` replaces the table's text for some keys.
    SettingsFlags(CLI::App* cmd, const std::vector<std::string>& keys,
                  const std::map<std::string, std::string>& help = {});
    SettingsFlags(const SettingsFlags&) = delete;
    SettingsFlags& operator=(const SettingsFlags&) = delete;

    /// The settings: defaults, with the flags given read over them and checked. InputError
    /// naming the flag for a bad value.
    RenderSettings read() const;

private:
    CLI::App* mCmd;
    std::vector<std::string> mKeys;
    // The parsed values, by key (std::map: the references CLI11 holds stay valid).
    std::map<std::string, int> mInt;
    std::map<std::string, double> mNumber;
    std::map<std::string, uint64_t> mUnsigned;
    std::map<std::string, std::string> mText;
    std::map<std::string, bool> mFlag;
};

}  // namespace penumbra::cli
