#include "penumbra/render_settings.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <nlohmann/json.hpp>

#include "penumbra/error.h"

namespace penumbra {

// ---------------------------------------------------------------------------------------------
// ACI modes

const char* aciModeName(AciMode mode) {
    static const char* const names[] = {"paper", "arcs", "tangent"};  // AciMode's order
    return names[static_cast<int>(mode)];
}

AciMode parseAciMode(const std::string& name, const std::string& where) {
    for (AciMode m : {AciMode::Paper, AciMode::Arcs, AciMode::Tangent})
        if (name == aciModeName(m)) return m;
    throw InputError("", where, "unknown ACI mode '" + name + "' (expected paper, arcs or tangent)");
}

void applyAciMode(AciSettings& s, AciMode mode) {
    const bool beyondPaper = mode != AciMode::Paper;
    s.curvedContour = beyondPaper;
    s.midlineCheck = beyondPaper;
    s.aspectGrid = mode == AciMode::Tangent;
    s.distanceGuided = mode == AciMode::Tangent;
    s.tangentContour = mode == AciMode::Tangent;
    s.coverage = mode == AciMode::Tangent;
    s.guidedProbes = mode == AciMode::Tangent ? 1 : 0;
}

AciMode aciModeOf(const AciSettings& s) {
    for (AciMode m : {AciMode::Paper, AciMode::Arcs}) {
        AciSettings t = s;
        applyAciMode(t, m);
        if (t.curvedContour == s.curvedContour && t.midlineCheck == s.midlineCheck &&
            t.distanceGuided == s.distanceGuided && t.tangentContour == s.tangentContour &&
            t.guidedProbes == s.guidedProbes && t.coverage == s.coverage &&
            t.aspectGrid == s.aspectGrid)
            return m;
    }
    return AciMode::Tangent;
}

// ---------------------------------------------------------------------------------------------
// The JSON model

namespace {

using Json = nlohmann::json;

std::string fieldAt(const std::string& where, const std::string& key) {
    return where.empty() ? key : where + "/" + key;
}

std::string rangeText(IntRange r) {
    return "[" + std::to_string(r.lo) + ", " + std::to_string(r.hi) + "]";
}

// The checks of one key, shared by reading and validate().
struct Checker {
    const std::string& file;
    const std::string& where;

    [[noreturn]] void fail(const std::string& key, const std::string& message) const {
        throw InputError(file, fieldAt(where, key), message);
    }
    void range(const std::string& key, long value, IntRange r) const {
        if (!r.holds(value)) fail(key, "must be in " + rangeText(r) + ", got " + std::to_string(value));
    }
    void threshold(double t) const {
        if (!(t > 0.0) || !std::isfinite(t)) fail("mc_threshold", "must be a finite number > 0");
    }
    void combinations(const RenderSettings& s) const {
        if (s.mc.samples != 0 && !isMonteCarlo(s.method)) {
            fail("samples", std::string("only applies to the Monte Carlo methods (reference, "
                                        "mc-adaptive, mc-solid-angle, mc-ratio), not '") +
                                methodName(s.method) + "'");
        }
        if ((long(s.aci.grid) << (s.aci.steps + 1)) > kMaxLatticeUnits) {
            fail("aci_steps", "aci_grid x 2^(aci_steps+1) must be at most " +
                                  std::to_string(kMaxLatticeUnits) +
                                  " (the shared sample lattice would not fit in memory)");
        }
    }

    // A name parser's result; its error (which names no file) is given the file.
    template <class Parse>
    auto named(Parse&& parse) const {
        try {
            return parse();
        } catch (const InputError& e) {
            throw InputError(file, e.where(), e.message());
        }
    }

    int integer(const Json& v, const std::string& key, IntRange r) const {
        const bool integral = v.is_number_integer() ||
                              (v.is_number_float() && std::isfinite(v.get<double>()) &&
                               std::floor(v.get<double>()) == v.get<double>());
        if (!integral) fail(key, "must be an integer");
        const double d = v.get<double>();
        if (d < double(r.lo) || d > double(r.hi)) {
            fail(key, "must be in " + rangeText(r) + ", got " + v.dump());
        }
        return int(d);
    }
    std::string text(const Json& v, const std::string& key) const {
        if (!v.is_string() || v.get<std::string>().empty()) fail(key, "must be a non-empty string");
        return v.get<std::string>();
    }
    bool flag(const Json& v, const std::string& key) const {
        if (!v.is_boolean()) fail(key, "must be true or false");
        return v.get<bool>();
    }
};

}  // namespace

const std::vector<std::string>& RenderSettings::keys() {
    static const std::vector<std::string> k = {
        "method",       "width",        "height",       "threads",          "aci_grid",
        "aci_steps",    "aci_mode",     "aci_fixed_steps", "aci_no_row_pairs", "max_span",  "samples",          "mc_threshold",
        "mc_max_depth", "mc_initial_depth", "seed",     "volume_cache",     "volume_samples",
        "hide_volumes"};
    return k;
}

const std::vector<std::pair<std::string, IntRange>>& RenderSettings::integerRanges() {
    static const std::vector<std::pair<std::string, IntRange>> r = {
        {"width", kImageSizeRange},         {"height", kImageSizeRange},
        {"threads", kThreadsRange},         {"aci_grid", kAciGridRange},
        {"aci_steps", kAciStepsRange},      {"max_span", kMaxSpanRange},
        {"samples", kMcSamplesRange},       {"mc_max_depth", kMcMaxDepthRange},
        {"mc_initial_depth", kMcInitialDepthRange}, {"volume_cache", kVolumeCacheRange},
        {"volume_samples", kVolumeSamplesRange}};
    return r;
}

void RenderSettings::readJson(const nlohmann::json& object, const std::string& file,
                              const std::string& where) {
    const Checker c{file, where};
    if (!object.is_object()) throw InputError(file, where, "must be an object of settings");
    // In the model's order, so that of several bad settings the first in that order is named.
    for (const std::string& key : keys()) {
        if (!object.contains(key)) continue;
        const Json& v = object[key];
        if (key == "method") {
            method = c.named([&] { return parseMethod(c.text(v, key), fieldAt(where, key)); });
        } else if (key == "width") {
            width = c.integer(v, key, kImageSizeRange);
        } else if (key == "height") {
            height = c.integer(v, key, kImageSizeRange);
        } else if (key == "threads") {
            threads = c.integer(v, key, kThreadsRange);
        } else if (key == "aci_grid") {
            aci.grid = c.integer(v, key, kAciGridRange);
        } else if (key == "aci_steps") {
            aci.steps = c.integer(v, key, kAciStepsRange);
        } else if (key == "aci_mode") {
            applyAciMode(aci, c.named([&] { return parseAciMode(c.text(v, key), fieldAt(where, key)); }));
        } else if (key == "aci_fixed_steps") {
            adaptiveSteps = !c.flag(v, key);
        } else if (key == "aci_no_row_pairs") {
            rowPairs = !c.flag(v, key);
        } else if (key == "max_span") {
            maxSpan = c.integer(v, key, kMaxSpanRange);
        } else if (key == "samples") {
            mc.samples = c.integer(v, key, kMcSamplesRange);
        } else if (key == "mc_threshold") {
            if (!v.is_number()) c.fail(key, "must be a finite number > 0");
            c.threshold(v.get<double>());
            mc.threshold = v.get<double>();
        } else if (key == "mc_max_depth") {
            mc.maxDepth = c.integer(v, key, kMcMaxDepthRange);
        } else if (key == "mc_initial_depth") {
            mc.initialDepth = c.integer(v, key, kMcInitialDepthRange);
        } else if (key == "seed") {
            if (!v.is_number_unsigned()) c.fail(key, "must be an integer in [0, 2^64 - 1]");
            mc.seed = v.get<uint64_t>();
        } else if (key == "volume_cache") {
            volumeCache = c.integer(v, key, kVolumeCacheRange);
        } else if (key == "volume_samples") {
            volumeSamples = c.integer(v, key, kVolumeSamplesRange);
        } else if (key == "hide_volumes") {
            volumesVisible = !c.flag(v, key);
        }
    }
}

nlohmann::ordered_json RenderSettings::toJson() const {
    nlohmann::ordered_json j;
    j["method"] = methodName(method);
    if (width > 0) j["width"] = width;
    if (height > 0) j["height"] = height;
    j["aci_grid"] = aci.grid;
    j["aci_steps"] = aci.steps;
    j["aci_mode"] = aciModeName(aciModeOf(aci));
    j["aci_fixed_steps"] = !adaptiveSteps;
    j["aci_no_row_pairs"] = !rowPairs;
    j["max_span"] = maxSpan;
    if (isMonteCarlo(method)) {
        j["samples"] = mc.samples > 0 ? mc.samples : defaultSamples(method);
        j["mc_threshold"] = mc.threshold;
        j["mc_max_depth"] = mc.maxDepth;
        j["mc_initial_depth"] = mc.initialDepth;
        j["seed"] = mc.seed;
    }
    j["volume_cache"] = volumeCache;
    j["volume_samples"] = volumeSamples;
    j["hide_volumes"] = !volumesVisible;
    return j;
}

void RenderSettings::validate(const std::string& file, const std::string& where) const {
    const Checker c{file, where};
    // 0 (the camera's size, every hardware thread, the method's samples) and threads = -1 (the
    // caller's arena) are the library's own values, not the model's.
    if (width != 0) c.range("width", width, kImageSizeRange);
    if (height != 0) c.range("height", height, kImageSizeRange);
    if (threads > 0) c.range("threads", threads, kThreadsRange);
    if (threads < -1) c.fail("threads", "must be in " + rangeText(kThreadsRange) + ", got " +
                                            std::to_string(threads));
    c.range("aci_grid", aci.grid, kAciGridRange);
    c.range("aci_steps", aci.steps, kAciStepsRange);
    c.range("max_span", maxSpan, kMaxSpanRange);
    c.range("max_grid_factor", maxGridFactor, IntRange{1, 16});
    if (mc.samples != 0) c.range("samples", mc.samples, kMcSamplesRange);
    c.threshold(mc.threshold);
    c.range("mc_max_depth", mc.maxDepth, kMcMaxDepthRange);
    c.range("mc_initial_depth", mc.initialDepth, kMcInitialDepthRange);
    c.range("volume_cache", volumeCache, kVolumeCacheRange);
    c.range("volume_samples", volumeSamples, kVolumeSamplesRange);
    c.combinations(*this);
}

std::string flagOfKey(const std::string& key) {
    std::string flag = "--" + key;
    std::replace(flag.begin(), flag.end(), '_', '-');
    return flag;
}

}  // namespace penumbra
