// Batch manifests, sharding and the batch runner. The manifest format is documented in
// docs/batch.md; keep the two in step.
//
// Resume rests on two records. The image carries the hash of the settings that made it in its
// own metadata; the sidecar `.job.json` records that hash and the image file's size and content
// hash. A job's files are staged under unique temporary names (output_files.h) and renamed
// statistics first, sidecar second, image last, so an image under its final name always has
// the sidecar that describes it (a kill between the renames leaves a sidecar describing an
// image that is not there, or an older image: either way a mismatch, and the job is rendered
// again). Resume skips a job only when all three agree: a truncated or altered image is
// rendered again.
#include "penumbra/batch.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
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
#include "penumbra/json_reader.h"
#include "penumbra/output_files.h"
#include "thread_sanitizer.h"

namespace penumbra {

namespace {

namespace fs = std::filesystem;
using Json = nlohmann::json;

constexpr int kMaxFrames = 1000000;
constexpr int kMaxShards = 1000000;
constexpr const char* kHashAttribute = "penumbra:job_hash";

// ---------------------------------------------------------------------------------------------
// Paths (files are read, and parsed as strict JSON, by json_reader.h)

std::string parentDir(const std::string& path) {
    std::string dir = fs::path(path).parent_path().string();
    return dir.empty() ? "." : dir;
}

std::string resolvePath(const std::string& baseDir, const std::string& path) {
    fs::path p(path);
    if (p.is_absolute() || baseDir.empty() || baseDir == ".") return p.lexically_normal().string();
    return (fs::path(baseDir) / p).lexically_normal().string();
}

// Every temporary of a batch (images, sidecars, statistics, the summary) comes from
// temporaryPathFor (output_files.h): unique per host, process and write, so that two jobs, or
// two runs, writing next to one file never share a temporary, and removeStaleTemporaries can
// tell a dead process's leftovers from a live run's.

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
// Which files a batch reads and writes

/// One file the batch reads or writes, as the manifest (or a scene) names it.
struct FileUse {
    std::string path;  ///< as written, joined to its directory
    std::string what;  ///< "/jobs/0/output", "/sweep/stats, frame 3", "the batch manifest"
    bool output = false;
};

/// Files by real location (resolvedPath: absolute, symlinks and `..` resolved) and, for files
/// that exist, by identity (device and inode), so that a symlink, an absolute path and a hard
/// link all name one file.
class FileRegistry {
public:
    /// The first use registered of the file at `path`, or nullptr; `real` gets its location.
    const FileUse* find(const std::string& path, std::string& real) {
        real = locate(path);
        return findReal(real);
    }

    /// The output registered at `path`, or nullptr (inputs are not reported). Safe to call
    /// from several threads at once (it does not touch the cache).
    const FileUse* findOutput(const std::string& path) const {
        const FileUse* use = findReal(resolvedPath(path));
        return use && use->output ? use : nullptr;
    }

    /// Registers a file the batch reads; a file registered already keeps its first use.
    void addInput(const std::string& path, const std::string& what) {
        std::string real;
        if (find(path, real)) return;
        add(real, {path, what, false});
    }

    /// Registers a file written by `job`'s `field`; throws InputError (the manifest, the
    /// field's pointer) when the file is already read or written by the batch.
    void addOutput(const std::string& manifestFile, const BatchJob& job, const std::string& field,
                   const std::string& path, const std::string& note = "") {
        std::string real;
        const std::string frame = job.frame >= 0 ? ", frame " + std::to_string(job.frame) : "";
        const std::string where = job.pointer + "/" + field;
        if (const FileUse* prior = find(path, real)) {
            throw InputError(manifestFile, where,
                             (frame.empty() ? "" : frame.substr(2) + ": ") + clash(*prior, path, note));
        }
        add(real, {path, where + frame + note, true});
    }

    /// Why writing `path` (described by `note`, e.g. " (the sidecar of ...)") is refused.
    static std::string clash(const FileUse& prior, const std::string& path,
                             const std::string& note) {
        if (prior.output) {
            return "'" + path + "'" + note + " is also written by " + prior.what +
                   (prior.path != path ? " (as '" + prior.path + "')" : "") +
                   ": every output needs its own file";
        }
        return "'" + path + "'" + note + " is " + prior.what +
               ", which this batch reads: refusing to overwrite an input";
    }

private:
    /// resolvedPath(path), with each directory resolved once: a sweep of many frames writes
    /// into a few directories, and resolving every path afresh costs tens of microseconds.
    /// A name that is itself a symlink (or `.`, `..`) is resolved whole.
    std::string locate(const std::string& path) {
        const fs::path p(path);
        const fs::path name = p.filename();
        struct stat st {};
        if (name.empty() || name == "." || name == ".." ||
            (::lstat(path.c_str(), &st) == 0 && S_ISLNK(st.st_mode))) {
            return resolvedPath(path);
        }
        const std::string dir = p.parent_path().string();
        auto it = mDirs.find(dir);
        if (it == mDirs.end()) it = mDirs.emplace(dir, resolvedPath(dir.empty() ? "." : dir)).first;
        return (fs::path(it->second) / name).string();
    }

    const FileUse* findReal(const std::string& real) const {
        if (auto it = mByPath.find(real); it != mByPath.end()) return &mUses[it->second];
        struct stat st {};
        if (!mByIdentity.empty() && ::stat(real.c_str(), &st) == 0) {
            auto it = mByIdentity.find({st.st_dev, st.st_ino});
            if (it != mByIdentity.end()) return &mUses[it->second];
        }
        return nullptr;
    }

    void add(const std::string& real, FileUse use) {
        const size_t index = mUses.size();
        mUses.push_back(std::move(use));
        mByPath.emplace(real, index);
        struct stat st {};
        if (::stat(real.c_str(), &st) == 0) {
            mByIdentity.emplace(std::make_pair(st.st_dev, st.st_ino), index);
        }
    }

    std::vector<FileUse> mUses;
    std::map<std::string, size_t> mByPath;
    std::map<std::pair<dev_t, ino_t>, size_t> mByIdentity;
    std::map<std::string, std::string> mDirs;  // directory as written -> resolvedPath
};

/// Every file a job writes, in the order its run renames them: statistics, sidecar, image.
void addJobOutputs(FileRegistry& files, const std::string& manifestFile, const BatchJob& job) {
    files.addOutput(manifestFile, job, "output", job.output);
    files.addOutput(manifestFile, job, "output", sidecarPath(job.output),
                    " (the sidecar record of '" + job.output + "')");
    if (!job.stats.empty()) files.addOutput(manifestFile, job, "stats", job.stats);
}

/// The `file` values in scene JSON (the `.vdb` and `.obj` files a scene names), with their
/// pointers under `pointer`.
void collectFileRefs(const Json& v, const std::string& pointer,
                     std::vector<std::pair<std::string, std::string>>& out) {
    if (v.is_object()) {
        for (auto it = v.begin(); it != v.end(); ++it) {
            const std::string p = pointer + "/" + pointerToken(it.key());
            if (it.key() == "file" && it.value().is_string()) {
                out.emplace_back(it.value().get<std::string>(), p);
            } else {
                collectFileRefs(it.value(), p, out);
            }
        }
    } else if (v.is_array()) {
        for (size_t i = 0; i < v.size(); ++i) {
            collectFileRefs(v[i], pointer + "/" + std::to_string(i), out);
        }
    }
}

/// A path a scene names, as the scene loader resolves it (relative to the scene's directory).
std::string sceneRelativePath(const std::string& sceneDir, const std::string& file) {
    fs::path p(file);
    if (p.is_relative() && !sceneDir.empty()) p = fs::path(sceneDir) / p;
    return p.lexically_normal().string();
}

// ---------------------------------------------------------------------------------------------
// Manifest

/// The fields a job may give, any of them possibly inherited from "defaults".
struct JobSpec {
    std::optional<std::string> scene, output, name, stats;
    /// The render settings given (keys of the JSON model, render_settings.h), each checked
    /// where it was read, and where that was (defaults or the job).
    Json settings = Json::object();
    std::map<std::string, std::string> settingsWhere;
    std::map<std::string, std::string> set;  // normalized pointer -> JSON text; sorted
};

// The render settings a manifest may give: every key of the model but the thread count, which
// belongs to the whole batch (--jobs).
const std::vector<std::string>& manifestSettingKeys() {
    static const std::vector<std::string> keys = [] {
        std::vector<std::string> k;
        for (const std::string& key : RenderSettings::keys())
            if (key != "threads") k.push_back(key);
        return k;
    }();
    return keys;
}

class ManifestReader {
public:
    ManifestReader(const std::string& file, const std::string& baseDir)
        : mFile(file), mBaseDir(baseDir) {}

    BatchManifest read(const Json& root) {
        if (!root.is_object()) fail("", "a manifest is a JSON object with \"jobs\" or \"sweep\"");
        checkKeys(root, "", {"jobs", "sweep", "defaults", "cache"});
        JobSpec defaults;
        if (root.contains("defaults")) {
            const Json& d = root["defaults"];
            requireObject(d, "/defaults");
            std::vector<std::string> keys = {"scene", "set"};
            keys.insert(keys.end(), manifestSettingKeys().begin(), manifestSettingKeys().end());
            checkKeys(d, "/defaults", keys);
            readFields(d, "/defaults", defaults);
        }
        BatchManifest manifest;
        manifest.file = mFile;
        if (root.contains("cache")) manifest.cache = resolvePath(mBaseDir, readString(root["cache"], "/cache"));
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
    static inline const std::vector<std::string> kJobKeys = [] {
        std::vector<std::string> k = {"scene", "output", "name", "stats", "set"};
        k.insert(k.end(), manifestSettingKeys().begin(), manifestSettingKeys().end());
        return k;
    }();

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
        for (const std::string& key : manifestSettingKeys()) {
            if (!obj.contains(key)) continue;
            // Checked here, so that an error names where the value stands.
            RenderSettings check;
            check.readJson(Json{{key, obj[key]}}, mFile, where);
            spec.settings[key] = obj[key];
            spec.settingsWhere[key] = at(key.c_str());
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

    BatchJob finish(const JobSpec& spec, const std::string& where, const std::string& origin,
                    long frame = -1) {
        if (!spec.scene) fail(where + "/scene", "missing required field 'scene'");
        if (!spec.output) fail(where + "/output", "missing required field 'output'");
        BatchJob job;
        job.origin = origin;
        job.pointer = where;
        job.frame = frame;
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
        s.readJson(spec.settings, mFile, where);
        // "samples" on a job of another method is a mistake; in "defaults" (and the other Monte
        // Carlo settings anywhere) it is meant for the Monte Carlo jobs only. Other methods keep
        // the default Monte Carlo settings, so that their hash does not change with settings
        // they do not use.
        if (!isMonteCarlo(s.method)) {
            const auto samples = spec.settingsWhere.find("samples");
            if (samples != spec.settingsWhere.end() && samples->second.rfind("/defaults", 0) != 0) {
                fail(samples->second, std::string("only applies to the Monte Carlo methods, not '") +
                                          methodName(s.method) + "'");
            }
            s.mc = RenderSettings().mc;
        }
        s.threads = -1;
        s.validate(mFile, where);
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
                finish(f, where, where + " frame " + std::to_string(frame), frame));
        }
    }

    // No two jobs write one file (images, sidecars, statistics), by real location: the files
    // they read are checked by checkBatchFiles, which reads the scenes.
    void checkOutputsUnique(const BatchManifest& manifest) const {
        FileRegistry files;
        for (const BatchJob& job : manifest.jobs) addJobOutputs(files, mFile, job);
    }

    std::string mFile, mBaseDir;
};

// ---------------------------------------------------------------------------------------------
// Hashing

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

std::string hostName() {
    char buf[256] = {};
    if (::gethostname(buf, sizeof(buf) - 1) != 0 || buf[0] == '\0') return "unknown host";
    return buf;
}

/// Records a failed job next to its output (failureRecordPath) for `batch --status`, best
/// effort: a job whose output directory cannot be written is reported missing instead.
void writeFailureRecord(const BatchJob& job, const std::string& hash, const std::string& error,
                        double seconds) {
    nlohmann::ordered_json j;
    j["format"] = "penumbra-batch-failure";
    j["version"] = 1;
    j["hash"] = hash;
    j["name"] = job.name;
    j["origin"] = job.origin;
    j["error"] = error;
    j["host"] = hostName();
    j["pid"] = static_cast<long>(::getpid());
    j["seconds"] = seconds;
    try {
        std::error_code ec;
        fs::create_directories(parentDir(job.output), ec);
        writeTextFileAtomically(failureRecordPath(job.output), j.dump(2) + "\n");
    } catch (const std::exception&) {
    }
}

void removeFailureRecord(const BatchJob& job) {
    std::error_code ec;
    fs::remove(failureRecordPath(job.output), ec);
}

/// Removes the temporaries of dead processes on this host (output_files.h) in the directories
/// the selected jobs (and the summary) write into; a live run's temporaries are left alone, so a
/// second run started while the first is writing cannot break it.
void removeStaleBatchTemporaries(const BatchManifest& manifest, const std::vector<size_t>& selected,
                                 const std::string& summary) {
    std::set<std::string> dirs;  // each directory listed once, even for thousands of frames
    for (size_t i : selected) {
        const BatchJob& job = manifest.jobs[i];
        dirs.insert(parentDir(job.output));  // the sidecar is next to it
        if (!job.stats.empty()) dirs.insert(parentDir(job.stats));
    }
    if (!summary.empty()) dirs.insert(parentDir(summary));
    for (const std::string& dir : dirs) removeStaleTemporaries(dir);
}

std::string sidecarJson(const BatchJob& job, const std::string& hash, int width, int height,
                        double seconds, uint64_t shadowRays, uint64_t viewingRays,
                        const FileDigest& output) {
    nlohmann::ordered_json j;  // keys in a reading order
    j["format"] = "penumbra-batch-job";
    j["version"] = 2;
    j["hash"] = hash;
    j["output_bytes"] = output.bytes;  // what resume checks the image file against
    j["output_hash"] = output.hash;
    j["name"] = job.name;
    j["origin"] = job.origin;
    j["scene"] = job.scene;
    j["output"] = job.output;
    // The settings in the model's names, with the size rendered (the camera's when not set).
    const nlohmann::ordered_json settings = job.settings.toJson();
    for (const auto& [key, value] : settings.items()) j[key] = value;
    j["width"] = width;
    j["height"] = height;
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

/// Whether `job`'s output is finished with the settings of `hash`: the image exists, its sidecar
/// records `hash`, the image's size and content hash match the sidecar's, and the image's own
/// header carries `hash`. Anything missing, unreadable or different: false (render it again).
bool outputVerified(const BatchJob& job, const std::string& hash, uint64_t& shadowRays,
                    double* seconds = nullptr) {
    std::error_code ec;
    if (!fs::is_regular_file(job.output, ec)) return false;
    Json record;
    try {
        std::ifstream in(sidecarPath(job.output), std::ios::binary);
        if (!in) return false;
        record = Json::parse(in);
    } catch (const std::exception&) {
        return false;
    }
    if (!record.is_object()) return false;
    const auto recordedHash = record.find("hash");
    const auto bytes = record.find("output_bytes");
    const auto content = record.find("output_hash");
    if (recordedHash == record.end() || !recordedHash->is_string() ||
        recordedHash->get<std::string>() != hash || bytes == record.end() ||
        !bytes->is_number_unsigned() || content == record.end() || !content->is_string()) {
        return false;  // another job's record, or a record from before content hashes
    }
    const uint64_t size = fs::file_size(job.output, ec);
    if (ec || size != bytes->get<uint64_t>()) return false;  // cheap: truncated or grown
    try {
        const FileDigest digest = digestFile(job.output);
        if (digest.bytes != size || digest.hash != content->get<std::string>()) return false;
        if (readImageAttribute(job.output, kHashAttribute) != hash) return false;
    } catch (const ImageModuleError&) {
        throw;  // no image can be checked (or written): not a stale output
    } catch (const std::exception&) {
        return false;
    }
    const auto rays = record.find("shadow_rays");
    shadowRays = rays != record.end() && rays->is_number_unsigned() ? rays->get<uint64_t>() : 0;
    const auto secs = record.find("seconds");
    if (seconds) *seconds = secs != record.end() && secs->is_number() ? secs->get<double>() : 0.0;
    return true;
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
    FileRegistry files;  // every file the batch reads and writes (read-only while jobs run)
    std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();
    std::atomic<size_t> next{0};
    std::mutex mutex;
    /// Level sets shared by the jobs of one scene file (by real path), with how many of those
    /// jobs have not ended: the last one to end frees them.
    struct SharedScene {
        std::shared_ptr<LevelSetCache> cache;
        size_t jobsLeft = 0;
    };
    std::mutex warnMutex;  // one warning at a time
    std::map<std::string, SharedScene> scenes;  // guarded by `mutex`

    std::shared_ptr<LevelSetCache> cacheFor(const BatchJob& job) {
        std::lock_guard<std::mutex> lock(mutex);
        const auto it = scenes.find(resolvedPath(job.scene));
        return it == scenes.end() ? nullptr : it->second.cache;
    }
    void jobEnded(const BatchJob& job) {  // with `mutex` held
        const auto it = scenes.find(resolvedPath(job.scene));
        if (it != scenes.end() && --it->second.jobsLeft == 0) scenes.erase(it);
    }
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
    std::string hash;  // "" until the scene could be read
    try {
        const std::string text = resolveSceneText(job);
        hash = jobHash(job, text);
        if (run.options.resume && outputVerified(job, hash, result.shadowRays)) {
            result.status = JobStatus::Skipped;
        } else {
            const std::shared_ptr<LevelSetCache> cache = run.cacheFor(job);
            const Scene scene = parseScene(text, job.scene, parentDir(job.scene), cache.get());
            result.levelSetsBuilt = scene.build.levelSetsBuilt;
            result.levelSetsShared = scene.build.levelSetsShared;
            result.levelSetsFromCache = scene.build.levelSetsFromCache;
            // The files the scene read were checked from its text before the run
            // (checkBatchFiles); this also catches a reference that check could not see.
            for (const auto& [path, pointer] : scene.inputFiles) {
                if (const FileUse* writer = run.files.findOutput(path)) {
                    throw InputError(job.scene, pointer,
                                     "'" + path + "' is written by " + writer->what + " of " +
                                         run.manifest.file +
                                         ": refusing to read a file this batch overwrites");
                }
            }
            RenderSettings settings = job.settings;
            settings.threads = -1;  // share the batch's arena
            // A batch writes the image alone: as `penumbra render` without AOV files, neither
            // the gradient nor the error bound is computed.
            settings.aci.gradient = false;
            settings.aci.errorBound = false;
            const RenderResult r = render(scene, settings, [&](int done, int total) {
                std::lock_guard<std::mutex> lock(run.mutex);
                run.fraction[slot] = double(done) / double(std::max(1, total));
                run.report();
            });
            // Companions the render built go to the cache directory for later runs and shards.
            if (cache) cache->persist();
            const RenderStats& st = r.stats;
            // Staged under unique temporary names and renamed in the order registered:
            // statistics, sidecar, image. An image on disk therefore implies its statistics
            // and the sidecar that records its size and content hash; a failure before the
            // renames leaves nothing (the OutputSet removes what it staged).
            OutputSet files;
            fs::create_directories(parentDir(job.output));
            if (!job.stats.empty()) {
                fs::create_directories(parentDir(job.stats));
                files.addOutput(job.stats, job.pointer + "/stats");
            }
            const std::string sidecar = sidecarPath(job.output);
            files.addOutput(sidecar, job.pointer + "/output");
            files.addOutput(job.output, job.pointer + "/output");
            ImageMetadata metadata = {
                {"ImageDescription", "penumbra batch render of " + job.scene},
                {"penumbra:scene", job.scene},
                {"penumbra:job_name", job.name},
                {kHashAttribute, hash},
            };
            for (auto& item : settingsMetadata(job.settings)) metadata.push_back(std::move(item));
            metadata.push_back({"penumbra:seconds", formatDouble(st.seconds)});
            metadata.push_back({"penumbra:viewing_rays", std::to_string(st.viewingRays)});
            metadata.push_back({"penumbra:shadow_rays", std::to_string(st.shadowRays)});
            const std::string stagedImage = files.stage(job.output);
            writeImage(job.output, r.color, metadata, job.pointer + "/output", stagedImage);
            const FileDigest digest = digestFile(stagedImage);
            writeTextFile(files.stage(sidecar),
                          sidecarJson(job, hash, st.width, st.height, st.seconds, st.shadowRays,
                                      st.viewingRays, digest),
                          sidecar);
            if (!job.stats.empty()) writeTextFile(files.stage(job.stats), st.toJson(), job.stats);
            files.commit();
            result.status = JobStatus::Rendered;
            result.shadowRays = st.shadowRays;
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
    if (result.status == JobStatus::Failed) {
        writeFailureRecord(job, hash, result.error, result.seconds);
    } else {
        removeFailureRecord(job);
    }

    std::lock_guard<std::mutex> lock(run.mutex);
    run.jobEnded(job);
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
    BatchManifest manifest = parseManifest(text, path, parentDir(path));
    manifest.path = path;
    return manifest;
}

namespace {

/// The lock file of a manifest (lockBatchManifest): `.NAME.lock` next to it.
std::string manifestLockPath(const std::string& manifestPath) {
    const fs::path m(manifestPath);
    return (m.parent_path() / ("." + m.filename().string() + ".lock")).string();
}

/// Every file of the batch: first what it reads (the manifest, each scene file and the files
/// the scenes name, with each job's overrides), then what each job writes, then the summary.
/// Throws InputError at the first clash.
FileRegistry registerBatchFiles(const BatchManifest& manifest, const std::string& summary,
                                const std::string& summaryFlag) {
    FileRegistry files;
    if (!manifest.path.empty()) {
        files.addInput(manifest.path, "the batch manifest");
        files.addInput(manifestLockPath(manifest.path), "the batch manifest's lock file");
    }
    // A sweep of many frames shares one scene file: read and scan it once.
    std::map<std::string, std::vector<std::pair<std::string, std::string>>> sceneRefs;
    for (const BatchJob& job : manifest.jobs) {
        auto it = sceneRefs.find(job.scene);
        if (it == sceneRefs.end()) {
            std::vector<std::pair<std::string, std::string>> refs;
            try {
                collectFileRefs(parseStrictJson(readTextFile(job.scene, "the scene file"),
                                                job.scene),
                                "", refs);
            } catch (const std::exception&) {
                // Unreadable or malformed: the job fails with the loader's message when it runs.
            }
            it = sceneRefs.emplace(job.scene, std::move(refs)).first;
            files.addInput(job.scene, "the scene of " + job.origin);
            const std::string dir = parentDir(job.scene);
            for (const auto& [file, pointer] : it->second) {
                files.addInput(sceneRelativePath(dir, file), pointer + " of " + job.scene);
            }
        }
        // Overrides may name files too ("obstacles/0/file", or a whole obstacle with one).
        for (const auto& [pointer, value] : job.overrides) {
            if (value.find("\"file\"") == std::string::npos &&
                (pointer.size() < 5 || pointer.compare(pointer.size() - 5, 5, "/file") != 0)) {
                continue;
            }
            std::vector<std::pair<std::string, std::string>> refs;
            try {
                const Json v = Json::parse(value);
                if (v.is_string()) {
                    refs.emplace_back(v.get<std::string>(), pointer);
                } else {
                    collectFileRefs(v, pointer, refs);
                }
            } catch (const std::exception&) {
                continue;
            }
            const std::string dir = parentDir(job.scene);
            for (const auto& [file, at] : refs) {
                files.addInput(sceneRelativePath(dir, file),
                               at + " of " + job.scene + " (as " + job.origin + " sets it)");
            }
        }
    }
    for (const BatchJob& job : manifest.jobs) addJobOutputs(files, manifest.file, job);
    if (!summary.empty()) {
        std::string real;
        if (const FileUse* prior = files.find(summary, real)) {
            throw InputError("", summaryFlag, FileRegistry::clash(*prior, summary, ""));
        }
    }
    return files;
}

}  // namespace

void checkBatchFiles(const BatchManifest& manifest, const std::string& summary,
                     const std::string& summaryFlag) {
    registerBatchFiles(manifest, summary, summaryFlag);
}

// ---------------------------------------------------------------------------------------------
// Lock

namespace {

enum class LockOutcome { Held, Busy, Impossible };

/// Opens (creating it) the lock file `path` and takes `operation` (LOCK_EX or LOCK_SH) on it
/// without waiting. Returns the descriptor when held, -1 otherwise, with `outcome` saying why.
int tryLock(const std::string& path, int operation, LockOutcome& outcome, std::string& why) {
    for (int attempt = 0; attempt < 64; ++attempt) {
        int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
        if (fd < 0 && errno == EACCES) fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
        if (fd < 0) {
            why = "cannot create '" + path + "': " + std::strerror(errno);
            outcome = LockOutcome::Impossible;
            return -1;
        }
        if (::flock(fd, operation | LOCK_NB) != 0) {
            const int err = errno;
            ::close(fd);
            if (err == EINTR) continue;
            if (err == EWOULDBLOCK) {
                outcome = LockOutcome::Busy;
                return -1;
            }
            why = "cannot lock '" + path + "': " + std::strerror(err);
            outcome = LockOutcome::Impossible;
            return -1;
        }
        // A shard's lock file is removed by its holder when it ends: make sure the file locked
        // is the one at `path` now, not one just unlinked (then try again).
        struct stat held {}, named {};
        if (::fstat(fd, &held) == 0 && ::stat(path.c_str(), &named) == 0 &&
            held.st_dev == named.st_dev && held.st_ino == named.st_ino) {
            outcome = LockOutcome::Held;
            return fd;
        }
        ::close(fd);
    }
    why = "cannot lock '" + path + "': it keeps being replaced";
    outcome = LockOutcome::Impossible;
    return -1;
}

/// Records this process in a lock file it holds exclusively ("PID HOST"), for the message of a
/// run it refuses.
void writeHolder(int fd) {
    const std::string text = std::to_string(::getpid()) + " " + hostName() + "\n";
    if (::ftruncate(fd, 0) == 0) {
        const ssize_t written = ::pwrite(fd, text.data(), text.size(), 0);
        (void)written;  // best effort: the lock holds without it
    }
}

/// "process 1234 on node7" from a lock file, or "" when it names nobody.
std::string holderOf(const std::string& path) {
    std::ifstream in(path);
    long pid = 0;
    std::string host;
    if (!(in >> pid >> host) || pid <= 0) return "";
    return "process " + std::to_string(pid) + " on " + host;
}

}  // namespace

BatchLock::BatchLock(BatchLock&& other) noexcept { *this = std::move(other); }

BatchLock& BatchLock::operator=(BatchLock&& other) noexcept {
    if (this != &other) {
        release();
        std::swap(mMainFd, other.mMainFd);
        std::swap(mShardFd, other.mShardFd);
        std::swap(mExclusive, other.mExclusive);
        std::swap(mMainPath, other.mMainPath);
        std::swap(mShardPath, other.mShardPath);
    }
    return *this;
}

BatchLock::~BatchLock() { release(); }

void BatchLock::release() {
    if (mShardFd >= 0) {
        ::unlink(mShardPath.c_str());  // while still held: see tryLock
        ::close(mShardFd);
        mShardFd = -1;
    }
    if (mMainFd >= 0) {
        if (mExclusive && ::ftruncate(mMainFd, 0) != 0) {
            // the holder's name stays; harmless, the next holder rewrites it
        }
        ::close(mMainFd);
        mMainFd = -1;
    }
    mExclusive = false;
}

BatchLock lockBatchManifest(const std::string& manifestPath, const Shard& shard,
                            std::string* warning) {
    const fs::path m(manifestPath);
    const fs::path dir = m.parent_path();
    const std::string name = m.filename().string();
    BatchLock lock;
    lock.mMainPath = manifestLockPath(manifestPath);
    const bool whole = shard.count <= 1;
    auto impossible = [&](const std::string& why) {
        if (warning) {
            *warning = why + ": a second run of " + manifestPath +
                       " at the same time would not be detected";
        }
        lock.release();
        return std::move(lock);
    };
    auto refuse = [&](const std::string& who, const std::string& lockFile) {
        throw InputError(manifestPath, "",
                         "already being run by " + who + ", which holds '" + lockFile +
                             "': refusing to run it twice at once; wait for that run to end, "
                             "then run again with --resume");
    };
    auto another = [](const std::string& holder) {
        return "another penumbra batch" + (holder.empty() ? std::string() : " (" + holder + ")");
    };
    LockOutcome outcome;
    std::string why;
    const int mainFd = tryLock(lock.mMainPath, whole ? LOCK_EX : LOCK_SH, outcome, why);
    if (outcome == LockOutcome::Impossible) return impossible(why);
    if (outcome == LockOutcome::Busy) {
        const std::string holder = holderOf(lock.mMainPath);
        refuse(whole && holder.empty()
                   ? "other penumbra batch runs of its shards (--shard I/N or an array index)"
                   : another(holder),
               lock.mMainPath);
    }
    lock.mMainFd = mainFd;
    lock.mExclusive = whole;
    if (whole) {
        writeHolder(mainFd);
        return lock;
    }
    // Shards share the manifest's lock; no exclusive holder can be there now, so a name left
    // in the file by a killed whole-batch run is stale.
    if (::ftruncate(mainFd, 0) != 0) {
        // read-only lock file: messages just name no process
    }
    lock.mShardPath = (dir / ("." + name + ".shard-" + std::to_string(shard.index) + "-of-" +
                              std::to_string(shard.count) + ".lock"))
                          .string();
    const int shardFd = tryLock(lock.mShardPath, LOCK_EX, outcome, why);
    if (outcome == LockOutcome::Impossible) return impossible(why);
    if (outcome == LockOutcome::Busy) {
        const std::string holder = holderOf(lock.mShardPath);
        lock.release();
        refuse(another(holder), lock.mShardPath);
    }
    lock.mShardFd = shardFd;
    writeHolder(shardFd);
    return lock;
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
    // Every setting in the model's names (RenderSettings::toJson: what the job asks for, not
    // the thread count), then the scene as resolved.
    std::ostringstream key;
    key << "penumbra-batch-job 2\n"
        << "settings " << job.settings.toJson().dump() << "\n"
        << "scene " << resolvedSceneText.size() << "\n"
        << resolvedSceneText;
    return hex16(fnv1a64(key.str()));
}

std::string sidecarPath(const std::string& output) { return output + ".job.json"; }

std::string failureRecordPath(const std::string& output) { return output + ".failed.json"; }

const char* jobStateName(JobState state) {
    static const char* const names[] = {"done", "failed", "missing"};  // JobState's order
    return names[static_cast<int>(state)];
}

std::vector<JobRecord> readJobRecords(const BatchManifest& manifest,
                                      const std::vector<size_t>& selected) {
    std::vector<JobRecord> out;
    for (size_t i : selected) {
        const BatchJob& job = manifest.jobs.at(i);
        JobRecord r;
        r.job = i;
        std::string hash;
        try {
            hash = jobHash(job, resolveSceneText(job));
        } catch (const std::exception&) {
            // The scene cannot be read now: only a failure record can say more.
        }
        if (!hash.empty() && outputVerified(job, hash, r.shadowRays, &r.seconds)) {
            r.state = JobState::Done;
            out.push_back(r);
            continue;
        }
        try {
            std::ifstream in(failureRecordPath(job.output), std::ios::binary);
            const Json rec = in ? Json::parse(in) : Json();
            // A failure under other settings (or of a scene since fixed) is not this job's.
            if (rec.is_object() && rec.value("format", "") == "penumbra-batch-failure" &&
                (hash.empty() || rec.value("hash", "") == hash)) {
                r.state = JobState::Failed;
                r.error = rec.value("error", "");
                r.host = rec.value("host", "");
                r.seconds = rec.value("seconds", 0.0);
            }
        } catch (const std::exception&) {
        }
        out.push_back(r);
    }
    return out;
}

const char* jobStatusName(JobStatus status) {
    static const char* const names[] = {"rendered", "skipped", "failed"};  // JobStatus's order
    return names[static_cast<int>(status)];
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
    // Every clash between the files the batch reads and writes is refused before any job runs.
    run.files = registerBatchFiles(manifest, options.summary, "--summary");
    run.results.resize(selected.size());
    run.fraction.assign(selected.size(), 0.0);
    const std::string cacheDir = !options.cacheDir.empty() ? options.cacheDir : manifest.cache;
    LevelSetCache::Warn warn;
    if (callbacks.warning) {
        warn = [&run](const std::string& text) {
            std::lock_guard<std::mutex> lock(run.warnMutex);
            run.callbacks.warning(text);
        };
    }
    for (size_t index : selected) {
        RunState::SharedScene& shared = run.scenes[resolvedPath(manifest.jobs[index].scene)];
        if (!shared.cache) shared.cache = std::make_shared<LevelSetCache>(cacheDir, warn);
        ++shared.jobsLeft;
    }
    run.info.total = selected.size();
    removeStaleBatchTemporaries(manifest, selected, options.summary);

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
                            {"level_sets_built", r.levelSetsBuilt},
                            {"level_sets_shared", r.levelSetsShared},
                            {"level_sets_from_cache", r.levelSetsFromCache},
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
    writeTextFileAtomically(path, content);
}

}  // namespace penumbra
