#include "cli/settings_flags.h"

#include <stdexcept>

#include <nlohmann/json.hpp>

#include "cli/commands.h"
#include "penumbra/error.h"

namespace penumbra::cli {

namespace {

enum class Kind { Int, Number, Unsigned, Text, Flag };

struct FlagInfo {
    Kind kind;
    bool showDefault;
    const char* help;
};

// One row per key of the model (RenderSettings::keys()).
const std::map<std::string, FlagInfo>& flagTable() {
    static const std::map<std::string, FlagInfo> table = {
        {"method",
         {Kind::Text, true,
          "aci: the section 5 pipeline (shaft culling, shadow-pattern coherence, interpolation); "
          "aci-pixel: full ACI at every pixel; reference, mc-adaptive, mc-solid-angle, mc-ratio: "
          "Monte Carlo estimators behind the same culling (docs/rendering.md)"}},
        {"width", {Kind::Int, false, "Image width in pixels (default: the camera's)"}},
        {"height", {Kind::Int, false, "Image height in pixels (default: the camera's)"}},
        {"threads", {Kind::Int, false, "Worker threads (default: every hardware thread)"}},
        {"aci_grid", {Kind::Int, true, "First-level grid p: squares along the light's shorter edge, p x p on a square light; in tangent mode a longer edge gets proportionally more, up to 8p (1-32)"}},
        {"aci_steps", {Kind::Int, true, "Dichotomy steps n along a crossed side (1-12)"}},
        {"aci_mode",
         {Kind::Text, true,
          "ACI variant: paper (Vedel 1993 exactly), arcs (parabolic arcs and the midline check), "
          "tangent (distance-guided Newton dichotomy and tangent arcs; see docs/estimator.md)"}},
        {"aci_fixed_steps",
         {Kind::Flag, false,
          "Tangent mode: every evaluation takes --aci-steps (by default one whose obstacles' "
          "footprints on the light are all wide takes one step fewer; docs/estimator.md)"}},
        {"aci_no_row_pairs",
         {Kind::Flag, false,
          "Tangent mode: shade every row on its own (by default odd rows are interpolated "
          "between the rows above and below where the rows agree and an evaluation confirms it; "
          "docs/rendering.md)"}},
        {"max_span", {Kind::Int, true, "Longest span of pixels shaded together"}},
        {"samples",
         {Kind::Int, false,
          "Monte Carlo methods: shadow rays per estimate (mc-adaptive: at most); default 1024 "
          "for reference and mc-adaptive, 16 for mc-solid-angle and mc-ratio"}},
        {"mc_threshold",
         {Kind::Number, true,
          "mc-adaptive: split a light cell while the standard error of its contribution exceeds "
          "this fraction of the unoccluded form factor"}},
        {"mc_max_depth", {Kind::Int, true, "mc-adaptive: deepest subdivision level"}},
        {"mc_initial_depth",
         {Kind::Int, true, "mc-adaptive: start from a 2^d x 2^d grid of light cells (4 rays each)"}},
        {"seed",
         {Kind::Unsigned, true,
          "Monte Carlo methods: seed mixed with each pixel's coordinates and the light"}},
        {"volume_cache",
         {Kind::Int, true,
          "Volumes seen by the camera: nodes of the in-scattering lattice along the media's "
          "longest extent (0: compute it at every sample, slow)"}},
        {"volume_samples",
         {Kind::Int, true, "Volumes seen by the camera: rays per in-scattering estimate, per light"}},
        {"hide_volumes",
         {Kind::Flag, false,
          "Volumes cast shadows but the camera does not see them (no alpha channel)"}},
    };
    return table;
}

}  // namespace

SettingsFlags::SettingsFlags(CLI::App* cmd, const std::vector<std::string>& keys,
                             const std::map<std::string, std::string>& help)
    : mCmd(cmd), mKeys(keys) {
    // The defaults shown in --help are the model's.
    const RenderSettings d;
    const nlohmann::ordered_json defaults = [&] {
        RenderSettings mc = d;
        mc.method = Method::Reference;  // so that toJson writes the Monte Carlo settings too
        nlohmann::ordered_json j = mc.toJson();
        j["method"] = methodName(d.method);
        return j;
    }();
    for (const std::string& key : keys) {
        const FlagInfo& info = flagTable().at(key);
        const std::string flag = flagOfKey(key);
        const auto h = help.find(key);
        const std::string text = h != help.end() ? h->second : info.help;
        CLI::Option* opt = nullptr;
        const bool hasDefault = defaults.contains(key);
        switch (info.kind) {
            case Kind::Int:
                mInt[key] = hasDefault ? defaults[key].get<int>() : 0;
                opt = cmd->add_option(flag, mInt[key], text);
                break;
            case Kind::Number:
                mNumber[key] = hasDefault ? defaults[key].get<double>() : 0.0;
                opt = cmd->add_option(flag, mNumber[key], text);
                break;
            case Kind::Unsigned:
                mUnsigned[key] = hasDefault ? defaults[key].get<uint64_t>() : 0;
                opt = cmd->add_option(flag, mUnsigned[key], text);
                break;
            case Kind::Text:
                mText[key] = hasDefault ? defaults[key].get<std::string>() : "";
                opt = cmd->add_option(flag, mText[key], text);
                break;
            case Kind::Flag:
                mFlag[key] = false;
                opt = cmd->add_flag(flag, mFlag[key], text);
                break;
        }
        if (info.showDefault && info.kind != Kind::Flag) opt->capture_default_str();
    }
}

RenderSettings SettingsFlags::read() const {
    nlohmann::json given = nlohmann::json::object();
    for (const std::string& key : mKeys) {
        if (mCmd->count(flagOfKey(key)) == 0) continue;
        switch (flagTable().at(key).kind) {
            case Kind::Int: given[key] = mInt.at(key); break;
            case Kind::Number: given[key] = mNumber.at(key); break;
            case Kind::Unsigned: given[key] = mUnsigned.at(key); break;
            case Kind::Text: given[key] = mText.at(key); break;
            case Kind::Flag: given[key] = mFlag.at(key); break;
        }
    }
    RenderSettings settings;
    withFlagNames([&] {
        settings.readJson(given);
        settings.validate();
    });
    return settings;
}

}  // namespace penumbra::cli
