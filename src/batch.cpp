// Batch manifests, sharding and the batch runner. The manifest format is documented in
// docs/batch.md; keep the two in step.
//
// Resume rests on one invariant: an output file exists only complete (image_io writes a
// temporary file and renames it) and it carries the hash of the settings that made it in its
// own metadata. The record and the pixels therefore appear in one rename, and no kill can leave
// an image without its record or a record pointing at an older image. The sidecar `.job.json`
// is written afterwards for people and gathering scripts; resume rewrites it when a kill lost it.
#include "penumbra/batch.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>

#include <tbb/info.h>
#include <tbb/global_control.h>
#include <tbb/task_arena.h>
#include <tbb/task_group.h>

#include "penumbra/error.h"
#include "penumbra/image_io.h"
#include "thread_sanitizer.h"

namespace penumbra {

namespace {

namespace fs = std::filesystem;
using Json = nlohmann::json;

constexpr int kMaxFrames = 1000000;
constexpr int kMaxShards = 1000000;
constexpr const char* kHashAttribute = "penumbra:job_hash";

// ---------------------------------------------------------------------------------------------
// Text and files

std::string readTextFile(const std::string& path, const std::string& what) {
    std::error_code ec;
    if (fs::is_directory(path, ec)) throw InputError(path, "", "is a directory, not " + what);
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path, "", "cannot open " + what + ": " + std::strerror(errno));
    std::ostringstream text;
    text << in.rdbuf();
    if (in.bad()) throw InputError(path, "", "cannot read " + what);
    return text.str();
}

std::string parentDir(const std::string& path) {
    std::string dir = fs::path(path).parent_path().string();
    return dir.empty() ? "." : dir;
}

std::string resolvePath(const std::string& baseDir, const std::string& path) {
    fs::path p(path);
    if (p.is_absolute() || baseDir.empty() || baseDir == ".") return p.lexically_normal().string();
    return (fs::path(baseDir) / p).lexically_normal().string();
}

// Temporary names follow image_io's pattern, `.BASE.tmp-PID-N`, so that one clean-up rule
// (removeStaleTemporaries) covers images, sidecars and summaries.
std::string temporaryName(const std::string& path) {
    static std::atomic<unsigned> counter{0};
    const fs::path p(path);
    const std::string name = "." + p.filename().string() + ".tmp-" + std::to_string(::getpid()) +
                             "-" + std::to_string(counter++);
    return (p.parent_path() / name).string();
}

void writeFileAtomically(const std::string& path, const std::string& content) {
    const std::string tmp = temporaryName(path);
    {
        std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
        if (out) out << content;
        if (!out || !out.flush()) {
            const int err = errno;
            std::remove(tmp.c_str());
            throw std::runtime_error("cannot write '" + path + "': " + std::strerror(err));
        }
    }
    if (std::rename(tmp.c_str(), path.c_str()) != 0) {
        const int err = errno;
        std::remove(tmp.c_str());
        throw std::runtime_error("cannot write '" + path + "': " + std::strerror(err));
    }
}

std::pair<int, int> lineColumn(const std::string& text, size_t byte) {
    int line = 1, column = 0;
    for (size_t i = 0; i < text.size() && i < byte; ++i) {
        if (text[i] == '\n') {
            ++line;
            column = 0;
        } else {
            ++column;
        }
    }
    return {line, column};
}

std::string pointerToken(const std::string& key) {
    std::string out;
    for (char c : key) {
        if (c == '~') {
            out += "~0";
        } else if (c == '/') {
            out += "~1";
        } else {
            out += c;
        }
    }
    return out;
}

// ---------------------------------------------------------------------------------------------
// Strict JSON: comments allowed, a repeated key is an error (nlohmann would keep the last one
// silently, and a manifest where "output" appears twice is almost certainly a mistake).

class DuplicateKeyFinder {
public:
    struct Duplicate {
        std::string pointer;
        std::string key;
    };

    bool operator()(int /*depth*/, Json::parse_event_t event, Json& parsed) {
        switch (event) {
            case Json::parse_event_t::object_start: mFrames.emplace_back(true); break;
            case Json::parse_event_t::array_start: mFrames.emplace_back(false); break;
            case Json::parse_event_t::key: {
                Frame& f = mFrames.back();
                f.key = parsed.get<std::string>();
                if (!f.seen.insert(f.key).second) throw Duplicate{pointer(), f.key};
                break;
            }
            case Json::parse_event_t::object_end:
            case Json::parse_event_t::array_end:
                mFrames.pop_back();
                next();
                break;
            case Json::parse_event_t::value: next(); break;
        }
        return true;
    }

private:
    struct Frame {
        explicit Frame(bool object) : isObject(object) {}
        bool isObject;
        std::string key;
        size_t index = 0;
        std::set<std::string> seen;
    };
    void next() {
        if (!mFrames.empty() && !mFrames.back().isObject) ++mFrames.back().index;
    }
    std::string pointer() const {
        std::string p;
        for (const Frame& f : mFrames) {
            p += "/" + (f.isObject ? pointerToken(f.key) : std::to_string(f.index));
        }
        return p;
    }
    std::vector<Frame> mFrames;
};

Json parseStrictJson(const std::string& text, const std::string& file) {
    DuplicateKeyFinder finder;
    Json::parser_callback_t callback = [&finder](int depth, Json::parse_event_t event,
                                                 Json& parsed) {
        return finder(depth, event, parsed);
    };
    try {
        return Json::parse(text, callback, /*allow_exceptions=*/true, /*ignore_comments=*/true);
    } catch (const DuplicateKeyFinder::Duplicate& d) {
        throw InputError(file, d.pointer, "duplicate key '" + d.key + "'");
    } catch (const Json::parse_error& e) {
        const auto [line, column] = lineColumn(text, e.byte);
        std::string reason = e.what();
        const size_t colon = reason.find("error: ");
        if (colon != std::string::npos) reason = reason.substr(colon + 7);
        throw InputError(file, "",
                         "malformed JSON at line " + std::to_string(line) + ", column " +
                             std::to_string(column) + ": " + reason);
    } catch (const Json::exception& e) {
        throw InputError(file, "", std::string(e.what()) + " (numbers must be finite)");
    }
}

// ---------------------------------------------------------------------------------------------
// JSON pointers (RFC 6901)

/// "lights/0/corner" and "/lights/0/corner" are the same pointer: the manifest's keys may omit
/// the leading slash, as the examples do.
std::string normalizePointer(const std::string& key, const std::string& file,
                             const std::string& where) {
    std::string p = key.empty() || key[0] == '/' ? key : "/" + key;
    if (p.empty() || p == "/") {
        throw InputError(file, where, "cannot replace the whole scene: name a value inside it");
    }
    for (size_t i = 0; i < p.size(); ++i) {
        if (p[i] == '~' && (i + 1 == p.size() || (p[i + 1] != '0' && p[i + 1] != '1'))) {
            throw InputError(file, where,
                             "malformed JSON pointer '" + key +
                                 "': '~' must be followed by 0 or 1");
        }
    }
    return p;
}

std::vector<std::string> pointerTokens(const std::string& pointer) {
    std::vector<std::string> tokens;
    size_t pos = 1;
    while (pos <= pointer.size()) {
        size_t slash = pointer.find('/', pos);
        if (slash == std::string::npos) slash = pointer.size();
        std::string raw = pointer.substr(pos, slash - pos), token;
        for (size_t i = 0; i < raw.size(); ++i) {
            if (raw[i] == '~' && i + 1 < raw.size()) {
                token += raw[i + 1] == '1' ? '/' : '~';
                ++i;
            } else {
                token += raw[i];
            }
        }
        tokens.push_back(token);
        pos = slash + 1;
    }
    return tokens;
}

/// An array index as RFC 6901 writes it: digits, no leading zero.
bool arrayIndex(const std::string& token, size_t& index) {
    if (token.empty() || token.size() > 9 || (token.size() > 1 && token[0] == '0')) return false;
    for (char c : token) {
        if (c < '0' || c > '9') return false;
    }
    index = size_t(std::stoul(token));
    return true;
}

void setAtPointer(Json& root, const std::string& pointer, Json value, const std::string& file) {
    const std::vector<std::string> tokens = pointerTokens(pointer);
    Json* node = &root;
    std::string walked;
    auto missing = [&](const std::string& what) {
        throw InputError(file, pointer, "cannot set this value: " + what);
    };
    for (size_t t = 0; t + 1 < tokens.size(); ++t) {
        const std::string& token = tokens[t];
        const std::string here = walked.empty() ? "the scene" : walked;
        if (node->is_object()) {
            auto it = node->find(token);
            if (it == node->end()) missing(here + " has no '" + token + "'");
            node = &*it;
        } else if (node->is_array()) {
            size_t i;
            if (!arrayIndex(token, i) || i >= node->size()) {
                missing(here + " has " + std::to_string(node->size()) +
                        " elements, no element '" + token + "'");
            }
            node = &(*node)[i];
        } else {
            missing(here + " is not an object or an array");
        }
        walked += "/" + pointerToken(token);
    }
    const std::string& last = tokens.back();
    const std::string here = walked.empty() ? "the scene" : walked;
    if (node->is_object()) {
        (*node)[last] = std::move(value);
    } else if (node->is_array()) {
        size_t i;
        if (last == "-") {
            node->push_back(std::move(value));
        } else if (arrayIndex(last, i) && i < node->size()) {
            (*node)[i] = std::move(value);
        } else {
            missing(here + " has " + std::to_string(node->size()) + " elements, no element '" +
                    last + "' (use '-' to append)");
        }
    } else {
        missing(here + " is not an object or an array");
    }
}

// ---------------------------------------------------------------------------------------------
// Manifest

/// The fields a job may give, any of them possibly inherited from "defaults".
struct JobSpec {
    std::optional<std::string> scene, output, name, stats, method;
    std::optional<int> width, height, aciGrid, aciSteps, maxSpan, samples, mcMaxDepth;
    std::optional<double> mcThreshold;
    std::optional<uint64_t> seed;
    std::optional<AciMode> aciMode;
    std::string methodWhere, samplesWhere;
    std::map<std::string, std::string> set;  // normalized pointer -> JSON text; sorted
};

class ManifestReader {
public:
    ManifestReader(const std::string& file, const std::string& baseDir)
        : mFile(file), mBaseDir(baseDir) {}

    BatchManifest read(const Json& root) {
        if (!root.is_object()) fail("", "a manifest is a JSON object with \"jobs\" or \"sweep\"");
        checkKeys(root, "", {"jobs", "sweep", "defaults"});
        JobSpec defaults;
        if (root.contains("defaults")) {
            const Json& d = root["defaults"];
            requireObject(d, "/defaults");
            checkKeys(d, "/defaults",
                      {"scene", "set", "method", "width", "height", "aci_grid", "aci_steps",
                       "aci_mode", "max_span", "samples", "mc_threshold", "mc_max_depth",
                       "seed"});
            readFields(d, "/defaults", defaults);
        }
        BatchManifest manifest;
        manifest.file = mFile;
        if (root.contains("jobs")) {
            const Json& jobs = root["jobs"];
            if (!jobs.is_array()) fail("/jobs", "must be an array of jobs");
            for (size_t i = 0; i < jobs.size(); ++i) {
                const std::string where = "/jobs/" + std::to_string(i);
                requireObject(jobs[i], where);
                checkKeys(jobs[i], where, kJobKeys);
                JobSpec spec = defaults;
                readFields(jobs[i], where, spec);
                manifest.jobs.push_back(finish(spec, where, where));
            }
        }
        if (root.contains("sweep")) {
            const Json& sweep = root["sweep"];
            if (sweep.is_array()) {
                for (size_t i = 0; i < sweep.size(); ++i) {
                    readSweep(sweep[i], "/sweep/" + std::to_string(i), defaults, manifest);
                }
            } else {
                readSweep(sweep, "/sweep", defaults, manifest);
            }
        }
        if (manifest.jobs.empty()) fail("", "the manifest has no jobs (\"jobs\" or \"sweep\")");
        checkOutputsUnique(manifest);
        return manifest;
    }

private:
    static inline const std::vector<std::string> kJobKeys = {
        "scene",    "output",    "name",     "stats",        "set",          "method",
        "width",    "height",    "aci_grid", "aci_steps",    "aci_mode",     "max_span",
        "samples",  "mc_threshold", "mc_max_depth", "seed"};

    [[noreturn]] void fail(const std::string& where, const std::string& message) const {
        throw InputError(mFile, where, message);
    }

    void requireObject(const Json& v, const std::string& where) const {
        if (!v.is_object()) fail(where, "must be an object");
    }

    void checkKeys(const Json& obj, const std::string& where,
                   const std::vector<std::string>& allowed) const {
        for (auto it = obj.begin(); it != obj.end(); ++it) {
            if (std::find(allowed.begin(), allowed.end(), it.key()) != allowed.end()) continue;
            std::string list;
            for (const std::string& k : allowed) list += (list.empty() ? "" : ", ") + k;
            fail(where + "/" + pointerToken(it.key()),
                 "unknown key '" + it.key() + "' (expected one of: " + list + ")");
        }
    }

    std::string readString(const Json& v, const std::string& where) const {
        if (!v.is_string() || v.get<std::string>().empty()) {
            fail(where, "must be a non-empty string");
        }
        return v.get<std::string>();
    }

    int readInt(const Json& v, const std::string& where, long lo, long hi) const {
        const bool integral =
            v.is_number_integer() ||
            (v.is_number_float() && std::floor(v.get<double>()) == v.get<double>());
        if (!integral) fail(where, "must be an integer");
        const double d = v.get<double>();
        if (d < double(lo) || d > double(hi)) {
            fail(where, "must be in [" + std::to_string(lo) + ", " + std::to_string(hi) +
                            "], got " + v.dump());
        }
        return int(d);
    }

    void readFields(const Json& obj, const std::string& where, JobSpec& spec) const {
        auto at = [&](const char* key) { return where + "/" + key; };
        if (obj.contains("scene")) spec.scene = readString(obj["scene"], at("scene"));
        if (obj.contains("output")) spec.output = readString(obj["output"], at("output"));
        if (obj.contains("name")) spec.name = readString(obj["name"], at("name"));
        if (obj.contains("stats")) spec.stats = readString(obj["stats"], at("stats"));
        if (obj.contains("method")) {
            spec.method = readString(obj["method"], at("method"));
            spec.methodWhere = at("method");
            try {
                parseMethod(*spec.method, at("method"));
            } catch (const InputError& e) {
                fail(at("method"), e.message());
            }
        }
        if (obj.contains("width")) spec.width = readInt(obj["width"], at("width"), 1, 65536);
        if (obj.contains("height")) spec.height = readInt(obj["height"], at("height"), 1, 65536);
        if (obj.contains("aci_grid")) {
            spec.aciGrid = readInt(obj["aci_grid"], at("aci_grid"), 1, 32);
        }
        if (obj.contains("aci_steps")) {
            spec.aciSteps = readInt(obj["aci_steps"], at("aci_steps"), 1, 12);
        }
        if (obj.contains("aci_mode")) {
            const std::string mode = readString(obj["aci_mode"], at("aci_mode"));
            try {
                spec.aciMode = parseAciMode(mode, at("aci_mode"));
            } catch (const InputError& e) {
                fail(at("aci_mode"), e.message());  // with the manifest's name
            }
        }
        if (obj.contains("max_span")) {
            spec.maxSpan = readInt(obj["max_span"], at("max_span"), 1, 4096);
        }
        if (obj.contains("samples")) {
            spec.samples = readInt(obj["samples"], at("samples"), 1, 1 << 20);
            spec.samplesWhere = at("samples");
        }
        if (obj.contains("mc_threshold")) {
            const Json& v = obj["mc_threshold"];
            if (!v.is_number() || !(v.get<double>() > 0.0)) {
                fail(at("mc_threshold"), "must be a number > 0");
            }
            spec.mcThreshold = v.get<double>();
        }
        if (obj.contains("mc_max_depth")) {
            spec.mcMaxDepth = readInt(obj["mc_max_depth"], at("mc_max_depth"), 0, 24);
        }
        if (obj.contains("seed")) {
            const Json& v = obj["seed"];
            if (!v.is_number_unsigned()) fail(at("seed"), "must be an integer >= 0");
            spec.seed = v.get<uint64_t>();
        }
        if (obj.contains("set")) {
            const Json& set = obj["set"];
            if (!set.is_object()) fail(at("set"), "must be an object of JSON pointer: value");
            for (auto it = set.begin(); it != set.end(); ++it) {
                const std::string key = at("set") + "/" + pointerToken(it.key());
                spec.set[normalizePointer(it.key(), mFile, key)] = it.value().dump();
            }
        }
    }

    BatchJob finish(const JobSpec& spec, const std::string& where, const std::string& origin) {
        if (!spec.scene) fail(where + "/scene", "missing required field 'scene'");
        if (!spec.output) fail(where + "/output", "missing required field 'output'");
        BatchJob job;
        job.origin = origin;
        job.name = spec.name ? *spec.name : *spec.output;
        job.scene = resolvePath(mBaseDir, *spec.scene);
        job.output = resolvePath(mBaseDir, *spec.output);
        try {
            imageFormatFor(job.output, where + "/output");
        } catch (const InputError& e) {
            fail(where + "/output", e.message());
        }
        if (spec.stats) job.stats = resolvePath(mBaseDir, *spec.stats);
        for (const auto& [pointer, value] : spec.set) job.overrides.emplace_back(pointer, value);
        RenderSettings& s = job.settings;
        if (spec.method) s.method = parseMethod(*spec.method, spec.methodWhere);
        s.width = spec.width.value_or(0);
        s.height = spec.height.value_or(0);
        s.aci.grid = spec.aciGrid.value_or(s.aci.grid);
        s.aci.steps = spec.aciSteps.value_or(s.aci.steps);
        if (spec.aciMode) applyAciMode(s.aci, *spec.aciMode);
        s.maxSpan = spec.maxSpan.value_or(s.maxSpan);
        // "samples" on a job of another method is a mistake; in "defaults" it is meant for the
        // Monte Carlo jobs only. Other methods keep the default Monte Carlo settings, so that
        // their hash does not change with settings they do not use.
        const bool fromDefaults = spec.samplesWhere.rfind("/defaults", 0) == 0;
        if (spec.samples && !isMonteCarlo(s.method) && !fromDefaults) {
            fail(spec.samplesWhere, std::string("only applies to the Monte Carlo methods, not '") +
                                        methodName(s.method) + "'");
        }
        if (isMonteCarlo(s.method)) {
            s.mc.samples = spec.samples.value_or(s.mc.samples);
            s.mc.threshold = spec.mcThreshold.value_or(s.mc.threshold);
            s.mc.maxDepth = spec.mcMaxDepth.value_or(s.mc.maxDepth);
            s.mc.seed = spec.seed.value_or(s.mc.seed);
        }
        s.threads = -1;
        if ((long(s.aci.grid) << (s.aci.steps + 1)) > kMaxLatticeUnits) {
            fail(where, "aci_grid x 2^(aci_steps+1) must be at most " +
                            std::to_string(kMaxLatticeUnits));
        }
        return job;
    }

    // One value of a "vary" entry at interpolation parameter t: numbers and arrays of numbers
    // blend linearly; `round` rounds each to the nearest integer (image sizes, counts), which
    // must be asked for since integer ends (corners at [-1, -1, 4]) usually want fractions.
    static Json blend(const Json& from, const Json& to, double t, bool round) {
        if (from.is_array()) {
            Json out = Json::array();
            for (size_t i = 0; i < from.size(); ++i) {
                out.push_back(blend(from[i], to[i], t, round));
            }
            return out;
        }
        // (1 - t) a + t b is exact at both ends, so the first and last frames get the values
        // written in the manifest.
        const double v = (1.0 - t) * from.get<double>() + t * to.get<double>();
        if (round) return Json(std::llround(v));
        return Json(v);
    }

    void checkBlendable(const Json& from, const Json& to, const std::string& where) const {
        auto numbers = [](const Json& v) {
            if (v.is_number()) return true;
            if (!v.is_array() || v.empty()) return false;
            for (const Json& e : v) {
                if (!e.is_number()) return false;
            }
            return true;
        };
        if (!numbers(from)) fail(where + "/from", "must be a number or an array of numbers");
        if (!numbers(to)) fail(where + "/to", "must be a number or an array of numbers");
        if (from.is_array() != to.is_array() || (from.is_array() && from.size() != to.size())) {
            fail(where + "/to", "must have the same shape as 'from' (" + from.dump() + ")");
        }
    }

    void readSweep(const Json& sweep, const std::string& where, const JobSpec& defaults,
                   BatchManifest& manifest) {
        requireObject(sweep, where);
        std::vector<std::string> keys = kJobKeys;
        keys.insert(keys.end(), {"frames", "start", "vary"});
        checkKeys(sweep, where, keys);
        JobSpec spec = defaults;
        readFields(sweep, where, spec);
        if (!sweep.contains("frames")) fail(where + "/frames", "missing required field 'frames'");
        const int frames = readInt(sweep["frames"], where + "/frames", 1, kMaxFrames);
        const int start =
            sweep.contains("start") ? readInt(sweep["start"], where + "/start", 0, 1000000000) : 0;
        if (!spec.output) fail(where + "/output", "missing required field 'output'");
        if (spec.name) {  // the template check below gives a better message than a duplicate
            expandFrameTemplate(*spec.name, start, mFile, where + "/name");
        }
        const std::string outputWhere = where + "/output";
        if (frames > 1 && expandFrameTemplate(*spec.output, start, mFile, outputWhere) ==
                              expandFrameTemplate(*spec.output, start + 1, mFile, outputWhere)) {
            fail(where + "/output", "must contain {frame} (or e.g. {frame:04d}) so that the " +
                                        std::to_string(frames) + " frames get different files");
        }

        struct Vary {
            std::string pointer;
            Json from, to, values;
            bool round = false;
        };
        std::vector<Vary> vary;
        if (sweep.contains("vary")) {
            const Json& v = sweep["vary"];
            if (!v.is_object()) fail(where + "/vary", "must be an object of JSON pointer: range");
            for (auto it = v.begin(); it != v.end(); ++it) {
                const std::string at = where + "/vary/" + pointerToken(it.key());
                const Json& range = it.value();
                requireObject(range, at);
                Vary entry;
                entry.pointer = normalizePointer(it.key(), mFile, at);
                if (range.contains("values")) {
                    checkKeys(range, at, {"values"});
                    entry.values = range["values"];
                    if (!entry.values.is_array() || entry.values.size() != size_t(frames)) {
                        fail(at + "/values", "must be an array of " + std::to_string(frames) +
                                                 " values, one per frame");
                    }
                } else {
                    checkKeys(range, at, {"from", "to", "round"});
                    if (range.contains("round")) {
                        if (!range["round"].is_boolean()) {
                            fail(at + "/round", "must be true or false");
                        }
                        entry.round = range["round"].get<bool>();
                    }
                    if (!range.contains("from")) {
                        fail(at + "/from", "missing required field 'from'");
                    }
                    if (!range.contains("to")) fail(at + "/to", "missing required field 'to'");
                    checkBlendable(range["from"], range["to"], at);
                    entry.from = range["from"];
                    entry.to = range["to"];
                }
                vary.push_back(std::move(entry));
            }
        }

        for (int k = 0; k < frames; ++k) {
            const long frame = long(start) + k;
            const double t = frames > 1 ? double(k) / double(frames - 1) : 0.0;
            JobSpec f = spec;
            f.output = expandFrameTemplate(*spec.output, frame, mFile, where + "/output");
            if (spec.name) f.name = expandFrameTemplate(*spec.name, frame, mFile, where + "/name");
            if (spec.stats) {
                f.stats = expandFrameTemplate(*spec.stats, frame, mFile, where + "/stats");
            }
            for (const Vary& v : vary) {
                const Json value = v.values.is_array() ? v.values[size_t(k)]
                                                       : blend(v.from, v.to, t, v.round);
                f.set[v.pointer] = value.dump();
            }
            manifest.jobs.push_back(
                finish(f, where, where + " frame " + std::to_string(frame)));
        }
    }

    void checkOutputsUnique(const BatchManifest& manifest) const {
        std::map<std::string, const BatchJob*> seen;
        for (const BatchJob& job : manifest.jobs) {
            auto [it, inserted] = seen.emplace(job.output, &job);
            if (!inserted) {
                fail(job.origin, "writes the same output as " + it->second->origin + ": " +
                                     job.output + " (each job needs its own file)");
            }
        }
    }

    std::string mFile, mBaseDir;
};

// ---------------------------------------------------------------------------------------------
// Hashing

uint64_t fnv1a(const std::string& s, uint64_t h = 1469598103934665603ull) {
    for (unsigned char c : s) {
        h ^= c;
        h *= 1099511628211ull;
    }
    return h;
}

std::string hex16(uint64_t v) {
    char buf[17];
    std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(v));
    return buf;
}

std::string formatDouble(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.17g", v);
    return buf;
}

std::string formatSeconds(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.6g", v);
    return buf;
}

// ---------------------------------------------------------------------------------------------
// Records and clean-up

void removeStaleTemporaries(const BatchManifest& manifest, const std::vector<size_t>& selected) {
    // Group the file names to protect by directory so that each directory is listed once, even
    // for a sweep of thousands of frames in one folder.
    std::map<std::string, std::set<std::string>> names;
    auto add = [&](const std::string& path) {
        if (path.empty()) return;
        const fs::path p(path);
        names[parentDir(path)].insert(p.filename().string());
    };
    for (size_t i : selected) {
        const BatchJob& job = manifest.jobs[i];
        add(job.output);
        add(sidecarPath(job.output));
        add(job.stats);
    }
    for (const auto& [dir, bases] : names) {
        std::error_code ec;
        for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
            const std::string name = it->path().filename().string();
            const size_t tmp = name.rfind(".tmp-");
            if (name.size() < 2 || name[0] != '.' || tmp == std::string::npos || tmp < 1) continue;
            if (bases.count(name.substr(1, tmp - 1))) {
                std::error_code ignored;
                fs::remove(it->path(), ignored);
            }
        }
    }
}

std::string sidecarJson(const BatchJob& job, const std::string& hash, int width, int height,
                        double seconds, uint64_t shadowRays, uint64_t viewingRays) {
    nlohmann::ordered_json j;  // keys in a reading order
    j["format"] = "penumbra-batch-job";
    j["version"] = 1;
    j["hash"] = hash;
    j["name"] = job.name;
    j["origin"] = job.origin;
    j["scene"] = job.scene;
    j["output"] = job.output;
    j["method"] = methodName(job.settings.method);
    j["width"] = width;
    j["height"] = height;
    j["aci_grid"] = job.settings.aci.grid;
    j["aci_steps"] = job.settings.aci.steps;
    j["aci_mode"] = aciModeName(aciModeOf(job.settings.aci));
    j["max_span"] = job.settings.maxSpan;
    if (isMonteCarlo(job.settings.method)) {
        const McSettings& mc = job.settings.mc;
        j["samples"] = mc.samples > 0 ? mc.samples : defaultSamples(job.settings.method);
        j["mc_threshold"] = mc.threshold;
        j["mc_max_depth"] = mc.maxDepth;
        j["seed"] = mc.seed;
    }
    nlohmann::ordered_json set = nlohmann::ordered_json::object();
    for (const auto& [pointer, value] : job.overrides) {
        set[pointer] = nlohmann::ordered_json::parse(value);
    }
    j["set"] = set;
    j["seconds"] = seconds;
    j["shadow_rays"] = shadowRays;
    j["viewing_rays"] = viewingRays;
    return j.dump(2) + "\n";
}

std::string sidecarHash(const std::string& path) {
    try {
        std::ifstream in(path, std::ios::binary);
        if (!in) return "";
        Json j = Json::parse(in);
        return j.value("hash", std::string());
    } catch (const std::exception&) {
        return "";
    }
}

uint64_t toCount(const std::string& s) {
    try {
        return s.empty() ? 0 : std::stoull(s);
    } catch (const std::exception&) {
        return 0;
    }
}

/// Shared state of a run; every member after `mutex` is guarded by it.
struct RunState {
    RunState(const BatchManifest& m, const std::vector<size_t>& s, const BatchOptions& o,
             const BatchCallbacks& c)
        : manifest(m), selected(s), options(o), callbacks(c) {}

    const BatchManifest& manifest;
    const std::vector<size_t>& selected;
    const BatchOptions& options;
    const BatchCallbacks& callbacks;
    std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();
    std::atomic<size_t> next{0};
    std::mutex mutex;
    std::vector<JobResult> results;
    std::vector<double> fraction;  // rows done / rows of running jobs
    BatchProgressInfo info;

    double elapsed() const {
        return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    }

    void report() {  // with the mutex held
        if (!callbacks.progress) return;
        info.runningFraction = 0.0;
        for (double f : fraction) info.runningFraction += f;
        info.seconds = elapsed();
        callbacks.progress(info);
    }
};

void runJob(RunState& run, size_t slot) {
    const BatchJob& job = run.manifest.jobs[run.selected[slot]];
    JobResult result;
    result.job = run.selected[slot];
    const auto start = std::chrono::steady_clock::now();
    try {
        const std::string text = resolveSceneText(job);
        const std::string hash = jobHash(job, text);
        std::error_code ec;
        if (run.options.resume && fs::is_regular_file(job.output, ec)) {
            std::string recorded;
            try {
                recorded = readImageAttribute(job.output, kHashAttribute);
            } catch (const std::exception&) {
                recorded.clear();  // unreadable: render it again
            }
            if (!recorded.empty() && recorded == hash) {
                result.status = JobStatus::Skipped;
                result.shadowRays = toCount(readImageAttribute(job.output, "penumbra:shadow_rays"));
                // A kill between the image's rename and the sidecar's leaves the image alone.
                const std::string sidecar = sidecarPath(job.output);
                if (sidecarHash(sidecar) != hash) {
                    const Image img = readImage(job.output);
                    writeFileAtomically(
                        sidecar,
                        sidecarJson(job, hash, img.width, img.height,
                                    std::atof(readImageAttribute(job.output, "penumbra:seconds")
                                                  .c_str()),
                                    result.shadowRays,
                                    toCount(readImageAttribute(job.output,
                                                               "penumbra:viewing_rays"))));
                }
            }
        }
        if (result.status != JobStatus::Skipped) {
            const Scene scene = parseScene(text, job.scene, parentDir(job.scene));
            RenderSettings settings = job.settings;
            settings.threads = -1;  // share the batch's arena
            const RenderResult r = render(scene, settings, [&](int done, int total) {
                std::lock_guard<std::mutex> lock(run.mutex);
                run.fraction[slot] = double(done) / double(std::max(1, total));
                run.report();
            });
            const RenderStats& st = r.stats;
            fs::create_directories(parentDir(job.output));
            // The statistics go first and the image last but one: an image on disk implies
            // that its statistics are there too.
            if (!job.stats.empty()) {
                fs::create_directories(parentDir(job.stats));
                writeStatsJson(job.stats, st);
            }
            const ImageMetadata metadata = {
                {"ImageDescription", "penumbra batch render of " + job.scene},
                {"penumbra:scene", job.scene},
                {"penumbra:job_name", job.name},
                {kHashAttribute, hash},
                {"penumbra:method", st.method},
                {"penumbra:aci_grid", std::to_string(st.aciGrid)},
                {"penumbra:aci_steps", std::to_string(st.aciSteps)},
                {"penumbra:aci_mode", st.aciMode},
                {"penumbra:max_span", std::to_string(job.settings.maxSpan)},
                {"penumbra:seconds", formatDouble(st.seconds)},
                {"penumbra:viewing_rays", std::to_string(st.viewingRays)},
                {"penumbra:shadow_rays", std::to_string(st.shadowRays)},
            };
            writeImage(job.output, r.color, metadata, "output");
            result.status = JobStatus::Rendered;
            result.shadowRays = st.shadowRays;
            writeFileAtomically(sidecarPath(job.output),
                                sidecarJson(job, hash, st.width, st.height, st.seconds,
                                            st.shadowRays, st.viewingRays));
        }
    } catch (const std::exception& e) {
        result.status = JobStatus::Failed;
        result.error = e.what();
    } catch (...) {
        result.status = JobStatus::Failed;
        result.error = "unknown error";
    }
    if (result.status != JobStatus::Skipped) {
        result.seconds =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    }
    // Keep the error on one line: summaries and logs are read line by line.
    std::replace(result.error.begin(), result.error.end(), '\n', ' ');

    std::lock_guard<std::mutex> lock(run.mutex);
    run.results[slot] = result;
    run.fraction[slot] = 0.0;
    ++run.info.finished;
    switch (result.status) {
        case JobStatus::Rendered: ++run.info.rendered; break;
        case JobStatus::Skipped: ++run.info.skipped; break;
        case JobStatus::Failed: ++run.info.failed; break;
    }
    if (run.callbacks.jobDone) run.callbacks.jobDone(job, result);
    run.report();
}

std::string csvField(const std::string& s) {
    if (s.find_first_of(",\"\n\r") == std::string::npos) return s;
    std::string out = "\"";
    for (char c : s) out += c == '"' ? std::string("\"\"") : std::string(1, c);
    return out + "\"";
}

}  // namespace

// ---------------------------------------------------------------------------------------------

BatchManifest parseManifest(const std::string& jsonText, const std::string& file,
                            const std::string& baseDir) {
    const Json root = parseStrictJson(jsonText, file);
    return ManifestReader(file, baseDir).read(root);
}

BatchManifest loadManifest(const std::string& path) {
    const std::string text = readTextFile(path, "the batch manifest");
    return parseManifest(text, path, parentDir(path));
}

std::string expandFrameTemplate(const std::string& pattern, long frame, const std::string& file,
                                const std::string& where) {
    std::string out;
    size_t pos = 0;
    while (pos < pattern.size()) {
        const size_t open = pattern.find('{', pos);
        if (open == std::string::npos) {
            out += pattern.substr(pos);
            break;
        }
        out += pattern.substr(pos, open - pos);
        const size_t close = pattern.find('}', open);
        if (close == std::string::npos) {
            throw InputError(file, where, "unclosed '{' in '" + pattern + "'");
        }
        const std::string field = pattern.substr(open + 1, close - open - 1);
        char buf[32];
        if (field == "frame") {
            std::snprintf(buf, sizeof buf, "%ld", frame);
        } else if (field.size() >= 8 && field.compare(0, 6, "frame:") == 0 && field.back() == 'd') {
            // "frame:04d" or "frame:4d": an optional 0 flag and a width of one digit.
            const std::string spec = field.substr(6, field.size() - 7);
            const bool zero = spec.size() == 2 && spec[0] == '0';
            const char w = spec.empty() ? 0 : spec.back();
            if (!(spec.size() == 1 || zero) || w < '1' || w > '9') {
                throw InputError(file, where,
                                 "unknown placeholder '{" + field +
                                     "}' (use {frame}, {frame:04d} or {frame:4d})");
            }
            std::snprintf(buf, sizeof buf, zero ? "%0*ld" : "%*ld", int(w - '0'), frame);
        } else {
            throw InputError(file, where,
                             "unknown placeholder '{" + field +
                                 "}' (use {frame}, {frame:04d} or {frame:4d})");
        }
        out += buf;
        pos = close + 1;
    }
    return out;
}

Shard parseShard(const std::string& text, const std::string& flag) {
    const size_t slash = text.find('/');
    auto number = [&](const std::string& s, long& v) {
        if (s.empty() || s.size() > 9 || s.find_first_not_of("0123456789") != std::string::npos) {
            return false;
        }
        v = std::stol(s);
        return true;
    };
    long i = 0, n = 0;
    if (slash == std::string::npos || !number(text.substr(0, slash), i) ||
        !number(text.substr(slash + 1), n)) {
        throw InputError("", flag, "expected I/N (shard I of N, from 0), got '" + text + "'");
    }
    if (n < 1 || n > kMaxShards) {
        throw InputError("", flag, "the shard count N must be in [1, " +
                                       std::to_string(kMaxShards) + "], got " + std::to_string(n));
    }
    if (i >= n) {
        throw InputError("", flag, "the shard index I must be in [0, N-1] = [0, " +
                                       std::to_string(n - 1) + "], got " + std::to_string(i));
    }
    return {int(i), int(n)};
}

std::optional<Shard> shardFromEnvironment(
    int countOverride, const std::function<const char*(const char*)>& getEnvIn) {
    const std::function<const char*(const char*)> getEnv =
        getEnvIn ? getEnvIn : [](const char* name) -> const char* { return std::getenv(name); };
    auto read = [&](const char* name, long fallback, bool& present) -> long {
        const char* v = getEnv(name);
        present = v && *v;
        if (!present) return fallback;
        const std::string s(v);
        if (s.size() > 9 || s.find_first_not_of("0123456789") != std::string::npos) {
            throw InputError("", name, "expected a non-negative integer, got '" + s + "'");
        }
        return std::stol(s);
    };
    bool present = false;
    long index = 0, count = 0;
    std::string source;
    const long slurmId = read("SLURM_ARRAY_TASK_ID", 0, present);
    if (present) {
        bool p = false;
        const long min = read("SLURM_ARRAY_TASK_MIN", 0, p);
        const long step = read("SLURM_ARRAY_TASK_STEP", 1, p);
        count = read("SLURM_ARRAY_TASK_COUNT", 0, p);
        if (step < 1) throw InputError("", "SLURM_ARRAY_TASK_STEP", "must be at least 1");
        if (slurmId < min || (slurmId - min) % step != 0) {
            throw InputError("", "SLURM_ARRAY_TASK_ID",
                             std::to_string(slurmId) + " is not MIN + k x STEP (" +
                                 std::to_string(min) + " + k x " + std::to_string(step) +
                                 "): use a range such as --array=0-" + "(N-1)");
        }
        index = (slurmId - min) / step;
        source = "SLURM_ARRAY_TASK_ID";
        // --array=3,5 (a list, e.g. to retry two tasks) has MIN 3 and COUNT 2, and task 3 would
        // silently become shard 0: only ranges (with an optional step) map to shards.
        bool hasMax = false;
        const long max = read("SLURM_ARRAY_TASK_MAX", 0, hasMax);
        if (hasMax && p && (max < min || (max - min) / step + 1 != count)) {
            throw InputError("", "SLURM_ARRAY_TASK_ID",
                             "the array is not one range MIN-MAX[:STEP] (MIN " +
                                 std::to_string(min) + ", MAX " + std::to_string(max) +
                                 ", COUNT " + std::to_string(count) +
                                 "): resubmit the whole range with --resume, or give --shard I/N");
        }
        if (countOverride <= 0 && !p) {
            throw InputError("", "SLURM_ARRAY_TASK_COUNT",
                             "not set while SLURM_ARRAY_TASK_ID is: give --shard-count N");
        }
    } else {
        index = read("JOB_COMPLETION_INDEX", 0, present);
        if (!present) return std::nullopt;
        source = "JOB_COMPLETION_INDEX";
        bool p = false;
        count = read("PENUMBRA_SHARD_COUNT", 0, p);
        if (countOverride <= 0 && !p) {
            throw InputError("", "--shard-count",
                             "JOB_COMPLETION_INDEX is set (a Kubernetes Indexed Job) but the "
                             "number of shards is not: give --shard-count N or set "
                             "PENUMBRA_SHARD_COUNT to the Job's completions");
        }
    }
    if (countOverride > 0) count = countOverride;
    if (count < 1 || count > kMaxShards) {
        throw InputError("", source, "the shard count must be in [1, " +
                                         std::to_string(kMaxShards) + "], got " +
                                         std::to_string(count));
    }
    if (index >= count) {
        throw InputError("", source,
                         "shard index " + std::to_string(index) + " is not below the shard count " +
                             std::to_string(count) +
                             " (array tasks must be numbered without gaps)");
    }
    return Shard{int(index), int(count)};
}

std::vector<size_t> shardJobs(size_t jobCount, const Shard& shard) {
    if (shard.count < 1 || shard.index < 0 || shard.index >= shard.count) {
        throw InputError("", "--shard", "invalid shard " + std::to_string(shard.index) + "/" +
                                            std::to_string(shard.count));
    }
    std::vector<size_t> jobs;
    for (size_t i = size_t(shard.index); i < jobCount; i += size_t(shard.count)) jobs.push_back(i);
    return jobs;
}

std::string applyOverrides(const std::string& sceneText,
                           const std::vector<std::pair<std::string, std::string>>& overrides,
                           const std::string& file) {
    if (overrides.empty()) return sceneText;
    Json root = parseStrictJson(sceneText, file);
    for (const auto& [pointer, value] : overrides) {
        setAtPointer(root, normalizePointer(pointer, file, pointer), Json::parse(value), file);
    }
    return root.dump(2) + "\n";
}

std::string resolveSceneText(const BatchJob& job) {
    const std::string text = readTextFile(job.scene, "the scene file");
    try {
        return applyOverrides(text, job.overrides, job.scene);
    } catch (const InputError& e) {
        // A syntax error or a repeated key: let the scene loader word it as it does for
        // `penumbra render` (it stops at the parse, before building anything).
        if (e.where().empty() || e.message().rfind("duplicate key", 0) == 0) {
            parseScene(text, job.scene, parentDir(job.scene));
        }
        throw;
    }
}

std::string jobHash(const BatchJob& job, const std::string& resolvedSceneText) {
    const RenderSettings& s = job.settings;
    std::ostringstream key;
    key << "penumbra-batch-job 1\n"
        << "method " << methodName(s.method) << "\n"
        << "size " << s.width << " " << s.height << "\n"
        << "aci " << s.aci.grid << " " << s.aci.steps << " " << formatDouble(s.aci.rayOffset)
        << " " << formatDouble(s.aci.thresholdScale) << " " << s.aci.refine << " "
        << s.aci.gradient << " " << s.aci.seed << " " << s.aci.distanceGuided << " "
        << s.aci.curvedContour << " " << s.aci.midlineCheck << " " << s.aci.tangentContour
        << " " << s.aci.guidedProbes << " " << aciModeName(aciModeOf(s.aci)) << "\n"
        << "pipeline " << s.maxSpan << " " << s.shaftCulling << " " << s.coherence << " "
        << s.adaptiveGrid << " " << s.maxGridFactor << "\n"
        << "mc " << s.mc.samples << " " << formatDouble(s.mc.threshold) << " " << s.mc.maxDepth
        << " " << formatDouble(s.mc.rayOffset) << " " << s.mc.seed << "\n"
        << "scene " << resolvedSceneText.size() << "\n"
        << resolvedSceneText;
    return hex16(fnv1a(key.str()));
}

std::string sidecarPath(const std::string& output) { return output + ".job.json"; }

const char* jobStatusName(JobStatus status) {
    switch (status) {
        case JobStatus::Rendered: return "rendered";
        case JobStatus::Skipped: return "skipped";
        case JobStatus::Failed: return "failed";
    }
    return "failed";
}

std::vector<JobResult> runBatch(const BatchManifest& manifest, const std::vector<size_t>& selected,
                                const BatchOptions& options, const BatchCallbacks& callbacks) {
    if (options.threads < 0 || options.threads > 1024) {
        throw InputError("", "--jobs",
                         "must be in [1, 1024], got " + std::to_string(options.threads));
    }
    for (size_t i : selected) {
        if (i >= manifest.jobs.size()) {
            throw InputError(manifest.file, "", "job " + std::to_string(i) + " does not exist");
        }
    }
    RunState run{manifest, selected, options, callbacks};
    run.results.resize(selected.size());
    run.fraction.assign(selected.size(), 0.0);
    run.info.total = selected.size();
    removeStaleTemporaries(manifest, selected);

    // One arena for everything: each runner takes the next job, and render() (threads = -1)
    // spreads that job's rows over the same workers. A batch of many small jobs keeps every
    // worker on its own job; a single big job gets every worker on its rows once the other
    // runners find the queue empty.
    const int threads = options.threads > 0 ? options.threads : tbb::info::default_concurrency();
    // More threads than cores, when asked for: raise TBB's worker limit (see render()).
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                              std::max<size_t>(threads, tbb::global_control::active_value(
                                                            tbb::global_control::max_allowed_parallelism)));
    tbb::task_arena arena(threads);
    // TSan cannot see the fork and join inside the uninstrumented libtbb (thread_sanitizer.h).
    const char forkKey = 0, joinKey = 0;
    detail::tsanRelease(&forkKey);
    arena.execute([&] {
        tbb::task_group group;
        const size_t runners = std::min(selected.size(), size_t(threads));
        for (size_t r = 0; r < runners; ++r) {
            group.run([&run, &forkKey, &joinKey] {
                detail::tsanAcquire(&forkKey);
                for (size_t slot; (slot = run.next++) < run.selected.size();) runJob(run, slot);
                detail::tsanRelease(&joinKey);
            });
        }
        group.wait();
    });
    detail::tsanAcquire(&joinKey);
    return std::move(run.results);
}

void checkSummaryPath(const std::string& path, const std::string& flag) {
    const std::string ext = fs::path(path).extension().string();
    std::string lower = ext;
    std::transform(lower.begin(), lower.end(), lower.begin(),
                   [](unsigned char c) { return char(std::tolower(c)); });
    if (lower != ".csv" && lower != ".json") {
        throw InputError("", flag,
                         "cannot write '" + path + "': use a .csv or a .json file for the summary");
    }
}

void writeBatchSummary(const std::string& path, const BatchManifest& manifest, const Shard& shard,
                       const std::vector<JobResult>& results, double seconds,
                       const std::string& flag) {
    checkSummaryPath(path, flag);
    std::string ext = fs::path(path).extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(),
                   [](unsigned char c) { return char(std::tolower(c)); });
    std::string content;
    if (ext == ".csv") {
        content = "index,name,status,error,seconds,shadow_rays,output,scene\n";
        for (const JobResult& r : results) {
            const BatchJob& job = manifest.jobs[r.job];
            content += std::to_string(r.job) + "," + csvField(job.name) + "," +
                       jobStatusName(r.status) + "," + csvField(r.error) + "," +
                       formatSeconds(r.seconds) + "," + std::to_string(r.shadowRays) + "," +
                       csvField(job.output) + "," + csvField(job.scene) + "\n";
        }
    } else {
        nlohmann::ordered_json j;
        j["manifest"] = manifest.file;
        j["shard"] = {{"index", shard.index}, {"count", shard.count}};
        j["total_jobs"] = manifest.jobs.size();
        size_t counts[3] = {0, 0, 0};
        nlohmann::ordered_json jobs = nlohmann::ordered_json::array();
        for (const JobResult& r : results) {
            const BatchJob& job = manifest.jobs[r.job];
            ++counts[int(r.status)];
            jobs.push_back({{"index", r.job},
                            {"name", job.name},
                            {"status", jobStatusName(r.status)},
                            {"error", r.error},
                            {"seconds", r.seconds},
                            {"shadow_rays", r.shadowRays},
                            {"output", job.output},
                            {"scene", job.scene}});
        }
        j["selected_jobs"] = results.size();
        j["rendered"] = counts[int(JobStatus::Rendered)];
        j["skipped"] = counts[int(JobStatus::Skipped)];
        j["failed"] = counts[int(JobStatus::Failed)];
        j["seconds"] = seconds;
        j["jobs"] = jobs;
        content = j.dump(2) + "\n";
    }
    const std::string dir = parentDir(path);
    std::error_code ec;
    fs::create_directories(dir, ec);
    writeFileAtomically(path, content);
}

}  // namespace penumbra
