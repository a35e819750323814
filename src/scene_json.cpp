// The scene loader: JSON text -> validated Scene. The format is documented in
// docs/scene-format.md; keep the two in step.
//
// Loading runs in three passes so that a typo in the last obstacle is reported before minutes
// are spent voxelizing the first one: (1) parse and validate the whole document into plans,
// (2) estimate the memory of every level set to be built and refuse the scene when over the
// limit, (3) build the level sets and read the .vdb files.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <variant>

#include "penumbra/error.h"
#include "penumbra/level_set.h"
#include "penumbra/scene.h"

namespace penumbra {

namespace {

using Json = nlohmann::json;

constexpr int kMaxImageSide = 32768;
constexpr double kDefaultMemoryLimitGiB = 16.0;
constexpr double kGiB = 1024.0 * 1024.0 * 1024.0;
// Bytes per active voxel of a level-set tree, for the memory estimate. Measured with
// describe().bytes / activeVoxels on OpenVDB 10 spheres and boxes of half width 3: 18.5 and
// 13.6 bytes for 0.19 M and 0.75 M voxels, falling as grids grow because the fixed cost of the
// upper tree nodes (~3.5 MB) is shared by more leaves. The large-grid limit is about 9-11 bytes
// (each 8^3 leaf stores 512 floats while the band fills only part of it), and grids large enough
// to matter are in that regime; 12 leaves a margin. The estimate guards against absurd
// requests, it need not be tight.
constexpr double kBytesPerBandVoxel = 12.0;
// OpenVDB index coordinates are int32 and createLevelSetSphere works in float voxel units;
// keep geometry well inside both ranges.
constexpr double kMaxIndexCoordinate = double(1 << 24);
// OpenVDB silently produces an empty grid for a sphere under 1.5 voxels in radius.
constexpr double kMinFeatureVoxels = 1.5;
// sin(angle) between edge_u and edge_v below which a light counts as degenerate.
constexpr double kMinEdgeSine = 1e-9;

// ---------------------------------------------------------------------------------------------
// Small text helpers

/// Makes user-supplied text safe for a one-line message: control characters escaped, long
/// strings cut.
std::string printable(const std::string& s, size_t maxLen = 60) {
    std::string out;
    for (size_t i = 0; i < s.size() && i < maxLen; ++i) {
        const unsigned char c = static_cast<unsigned char>(s[i]);
        if (c == '\n') {
            out += "\\n";
        } else if (c == '\t') {
            out += "\\t";
        } else if (c < 0x20 || c == 0x7f) {
            char buf[8];
            std::snprintf(buf, sizeof buf, "\\x%02x", c);
            out += buf;
        } else {
            out += char(c);
        }
    }
    if (s.size() > maxLen) out += "...";
    return out;
}

std::string inQuotes(const std::string& s) { return "'" + printable(s) + "'"; }

/// RFC 6901 escaping of one reference token.
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

/// Levenshtein distance; inputs are short key names.
size_t editDistance(const std::string& a, const std::string& b) {
    std::vector<size_t> row(b.size() + 1);
    for (size_t j = 0; j <= b.size(); ++j) row[j] = j;
    for (size_t i = 1; i <= a.size(); ++i) {
        size_t diag = row[0];
        row[0] = i;
        for (size_t j = 1; j <= b.size(); ++j) {
            const size_t up = row[j];
            row[j] = std::min({row[j] + 1, row[j - 1] + 1, diag + (a[i - 1] == b[j - 1] ? 0 : 1)});
            diag = up;
        }
    }
    return row[b.size()];
}

/// How far `word` is from `candidate` for suggestions: the edit distance, except that a word
/// that begins or ends a candidate ("fov" for "fov_deg") counts as one edit away, since the
/// plain distance would prefer any short key ("up").
size_t suggestionDistance(const std::string& word, const std::string& candidate) {
    const size_t d = editDistance(word, candidate);
    if (word.empty() || word.size() >= candidate.size()) return d;
    const bool prefix = candidate.compare(0, word.size(), word) == 0;
    const bool suffix = candidate.compare(candidate.size() - word.size(), word.size(), word) == 0;
    return (prefix || suffix) ? std::min<size_t>(d, 1) : d;
}

/// " (did you mean 'x'?)", plus the full list when even the nearest candidate is far off.
std::string suggestion(const std::string& word, const std::vector<std::string>& candidates) {
    if (candidates.empty()) return "";
    const std::string* best = &candidates.front();
    size_t bestDist = suggestionDistance(word, *best);
    for (const std::string& c : candidates) {
        const size_t d = suggestionDistance(word, c);
        if (d < bestDist) {
            best = &c;
            bestDist = d;
        }
    }
    std::string out = " (did you mean '" + *best + "'?";
    if (candidates.size() > 1 && bestDist > std::max<size_t>(2, best->size() / 2)) {
        out += " valid: ";
        for (size_t i = 0; i < candidates.size(); ++i) {
            out += (i ? ", " : "") + candidates[i];
        }
    }
    return out + ")";
}

/// The JSON type as a user reads it in "expected X, got Y".
std::string typeName(const Json& v) {
    switch (v.type()) {
        case Json::value_t::null:
            return "null";
        case Json::value_t::boolean:
            return "boolean";
        case Json::value_t::string:
            return "string";
        case Json::value_t::array:
            return "an array of " + std::to_string(v.size());
        case Json::value_t::object:
            return "object";
        case Json::value_t::number_integer:
        case Json::value_t::number_unsigned:
        case Json::value_t::number_float:
            return "number";
        default:
            return "unsupported value";
    }
}

/// A number as the user wrote it (shortest round-trip form).
std::string numberText(double x) {
    if (std::isnan(x)) return "nan";
    if (std::isinf(x)) return x > 0 ? "inf" : "-inf";
    // Whole numbers without nlohmann's trailing ".0": "must be > 0", as the user would write.
    if (x == std::floor(x) && std::fabs(x) < 1e15) return std::to_string(static_cast<long long>(x));
    return Json(x).dump();
}

std::string vecText(const Vec3& v) {
    return "[" + numberText(v.x) + ", " + numberText(v.y) + ", " + numberText(v.z) + "]";
}

std::string bytesText(double bytes) {
    std::ostringstream s;
    s.setf(std::ios::fixed);
    if (bytes >= 10.0 * kGiB) {
        s.precision(0);
        s << bytes / kGiB << " GiB";
    } else if (bytes >= kGiB) {
        s.precision(1);
        s << bytes / kGiB << " GiB";
    } else {
        s.precision(0);
        s << std::max(1.0, bytes / (1024.0 * 1024.0)) << " MiB";
    }
    return s.str();
}

// ---------------------------------------------------------------------------------------------
// Reading the document: a value together with its JSON pointer, so every complaint names it.

struct Context {
    std::string file;     ///< for messages
    std::string baseDir;  ///< resolves relative paths
};

class Node {
  public:
    Node(const Json& value, std::string pointer, const Context& ctx)
        : mValue(&value), mPointer(std::move(pointer)), mCtx(&ctx) {}

    const Json& json() const { return *mValue; }
    const std::string& pointer() const { return mPointer; }
    const Context& context() const { return *mCtx; }

    [[noreturn]] void fail(const std::string& message) const {
        throw InputError(mCtx->file, mPointer, message);
    }

    Node element(size_t i) const {
        return Node((*mValue)[i], mPointer + "/" + std::to_string(i), *mCtx);
    }

    double number() const {
        if (!mValue->is_number()) fail("expected a number, got " + typeName(*mValue));
        const double x = mValue->get<double>();
        if (!std::isfinite(x)) fail("expected a finite number, got " + numberText(x));
        return x;
    }

    double numberAbove(double lo) const {
        const double x = number();
        if (!(x > lo)) fail("must be > " + numberText(lo) + ", got " + mValue->dump());
        return x;
    }

    int integer(int lo, int hi) const {
        const double x = number();
        if (x != std::floor(x)) fail("expected an integer, got " + mValue->dump());
        if (x < lo || x > hi) {
            fail("must be in [" + std::to_string(lo) + ", " + std::to_string(hi) + "], got " +
                 mValue->dump());
        }
        return int(x);
    }

    bool boolean() const {
        if (!mValue->is_boolean()) fail("expected true or false, got " + typeName(*mValue));
        return mValue->get<bool>();
    }

    std::string string() const {
        if (!mValue->is_string()) fail("expected a string, got " + typeName(*mValue));
        return mValue->get<std::string>();
    }

    std::string nonEmptyString() const {
        std::string s = string();
        if (s.empty()) fail("must not be empty");
        return s;
    }

    const Json& array() const {
        if (!mValue->is_array()) fail("expected an array, got " + typeName(*mValue));
        return *mValue;
    }

    Vec3 vec3() const {
        if (!mValue->is_array() || mValue->size() != 3) {
            fail("expected an array of 3 numbers, got " + typeName(*mValue));
        }
        return Vec3(element(0).number(), element(1).number(), element(2).number());
    }

    /// A colour or reflectance: three numbers, none negative.
    Rgb rgb() const {
        const Vec3 c = vec3();
        for (int k = 0; k < 3; ++k) {
            if (c[k] < 0.0) element(k).fail("must be >= 0, got " + numberText(c[k]));
        }
        return c;
    }

    /// A direction: normalised; refuses the zero vector.
    Vec3 direction() const {
        const Vec3 d = vec3();
        const double len = glm::length(d);
        // The components are finite, but their squares may overflow.
        if (!(len > 0.0) || !std::isfinite(len)) {
            fail("must be a non-zero vector of finite length, got " + vecText(d));
        }
        return d / len;
    }

  private:
    const Json* mValue;
    std::string mPointer;
    const Context* mCtx;
};

/// An object whose keys must all belong to `allowed`; gives typed access to its fields.
class Object {
  public:
    Object(const Node& node, std::vector<std::string> allowed)
        : mNode(node), mAllowed(std::move(allowed)) {
        if (!node.json().is_object()) node.fail("expected an object, got " + typeName(node.json()));
        for (const auto& item : node.json().items()) {
            if (std::find(mAllowed.begin(), mAllowed.end(), item.key()) == mAllowed.end()) {
                throw InputError(
                    node.context().file, node.pointer() + "/" + pointerToken(item.key()),
                    "unknown key " + inQuotes(item.key()) + suggestion(item.key(), mAllowed));
            }
        }
    }

    const Node& node() const { return mNode; }
    const std::string& pointer() const { return mNode.pointer(); }
    bool has(const std::string& key) const { return mNode.json().contains(key); }

    Node at(const std::string& key) const {
        const std::string ptr = mNode.pointer() + "/" + pointerToken(key);
        auto it = mNode.json().find(key);
        if (it == mNode.json().end()) {
            throw InputError(mNode.context().file, ptr, "missing required field '" + key + "'");
        }
        return Node(*it, ptr, mNode.context());
    }

    double numberAbove(const std::string& key, double lo, double fallback) const {
        return has(key) ? at(key).numberAbove(lo) : fallback;
    }
    Vec3 vec3(const std::string& key, const Vec3& fallback) const {
        return has(key) ? at(key).vec3() : fallback;
    }
    Rgb rgb(const std::string& key, const Rgb& fallback) const {
        return has(key) ? at(key).rgb() : fallback;
    }
    bool boolean(const std::string& key, bool fallback) const {
        return has(key) ? at(key).boolean() : fallback;
    }

    /// The "type" field, checked against the known kinds.
    std::string kind(const std::string& what, const std::vector<std::string>& kinds,
                     const std::string& fallback = "") const {
        if (!has("type") && !fallback.empty()) return fallback;
        const Node n = at("type");
        const std::string k = n.string();
        if (std::find(kinds.begin(), kinds.end(), k) == kinds.end()) {
            n.fail("unknown " + what + " type " + inQuotes(k) + suggestion(k, kinds));
        }
        return k;
    }

  private:
    Node mNode;
    std::vector<std::string> mAllowed;
};

// ---------------------------------------------------------------------------------------------
// Parsing the text. nlohmann::json reports syntax errors by byte offset and silently keeps the
// last of duplicate keys; the callback below tracks the JSON pointer of the value being read so
// that duplicates and out-of-range numbers (1e400) can be reported by pointer too.

class PathTracker {
  public:
    struct DuplicateKey {
        std::string pointer;
        std::string key;
    };

    bool operator()(int /*depth*/, Json::parse_event_t event, Json& parsed) {
        switch (event) {
            case Json::parse_event_t::object_start:
                mFrames.emplace_back(true);
                break;
            case Json::parse_event_t::array_start:
                mFrames.emplace_back(false);
                break;
            case Json::parse_event_t::key: {
                Frame& f = mFrames.back();
                f.key = parsed.get<std::string>();
                f.hasKey = true;
                if (!f.seen.insert(f.key).second) throw DuplicateKey{pointer(), f.key};
                break;
            }
            case Json::parse_event_t::object_end:
            case Json::parse_event_t::array_end:
                mFrames.pop_back();
                childDone();
                break;
            case Json::parse_event_t::value:
                childDone();
                break;
        }
        return true;
    }

    /// Pointer of the value being read.
    std::string pointer() const {
        std::string p;
        for (const Frame& f : mFrames) {
            if (f.isObject) {
                if (!f.hasKey) break;
                p += "/" + pointerToken(f.key);
            } else {
                p += "/" + std::to_string(f.index);
            }
        }
        return p;
    }

  private:
    struct Frame {
        explicit Frame(bool object) : isObject(object) {}
        bool isObject;
        bool hasKey = false;
        std::string key;
        size_t index = 0;  // arrays: the element being read
        std::set<std::string> seen;
    };

    void childDone() {
        if (!mFrames.empty() && !mFrames.back().isObject) ++mFrames.back().index;
    }

    std::vector<Frame> mFrames;
};

/// Line and column (1-based; columns count UTF-8 code points) of a 1-based byte offset.
std::pair<size_t, size_t> lineColumn(const std::string& text, size_t byte) {
    const size_t end = std::min(text.size(), byte > 0 ? byte - 1 : 0);
    size_t line = 1, column = 1;
    for (size_t i = 0; i < end; ++i) {
        const unsigned char c = static_cast<unsigned char>(text[i]);
        if (c == '\n') {
            ++line;
            column = 1;
        } else if ((c & 0xC0) != 0x80) {  // not a UTF-8 continuation byte
            ++column;
        }
    }
    return {line, column};
}

/// nlohmann's what() without its "[json.exception...] parse error at line 1, column 2: " prefix.
std::string nlohmannReason(const std::string& what) {
    const size_t bracket = what.find("] ");
    std::string reason = bracket == std::string::npos ? what : what.substr(bracket + 2);
    const size_t colon = reason.find(": ");
    if (reason.rfind("parse error", 0) == 0 && colon != std::string::npos) {
        reason = reason.substr(colon + 2);
    }
    return reason;
}

Json parseText(const std::string& text, const std::string& file) {
    PathTracker tracker;
    Json::parser_callback_t callback = [&tracker](int depth, Json::parse_event_t event,
                                                  Json& parsed) {
        return tracker(depth, event, parsed);
    };
    try {
        return Json::parse(text, callback, /*allow_exceptions=*/true, /*ignore_comments=*/true);
    } catch (const PathTracker::DuplicateKey& d) {
        throw InputError(file, d.pointer, "duplicate key " + inQuotes(d.key));
    } catch (const Json::parse_error& e) {
        const auto [line, column] = lineColumn(text, e.byte);
        throw InputError(file, "",
                         "malformed JSON at line " + std::to_string(line) + ", column " +
                             std::to_string(column) + ": " +
                             printable(nlohmannReason(e.what()), 300));
    } catch (const Json::exception& e) {
        // out_of_range.406: a number too large for a double, e.g. 1e400.
        throw InputError(file, tracker.pointer(),
                         printable(nlohmannReason(e.what()), 300) + " (numbers must be finite)");
    }
}

// ---------------------------------------------------------------------------------------------
// Pass 1: the document -> plans

struct SphereLevelSetPlan {
    Vec3 center;
    double radius;
    double voxelSize, halfWidth;
};
struct BoxLevelSetPlan {
    Vec3 lo, hi;
    double voxelSize, halfWidth;
};
struct VdbPlan {
    std::string path;  ///< resolved
    std::string grid;  ///< empty: every level-set grid
};
using ShapePlan =
    std::variant<AnalyticSphere, AnalyticBox, SphereLevelSetPlan, BoxLevelSetPlan, VdbPlan>;

struct ObstaclePlan {
    std::string pointer;
    std::string name;  ///< empty: derive (obstacle_K, or the grid names of a .vdb)
    size_t index;      ///< position in the "obstacles" array
    Rgb albedo{0.8};
    ShapePlan shape;
};

struct MemoryBudget {
    double limitBytes = kDefaultMemoryLimitGiB * kGiB;
};

Camera parseCamera(const Node& node) {
    const Object obj(node, {"eye", "look_at", "up", "fov_deg", "width", "height"});
    Camera cam;
    cam.eye = obj.vec3("eye", cam.eye);
    cam.lookAt = obj.vec3("look_at", cam.lookAt);
    if (obj.has("up")) cam.up = obj.at("up").direction();
    if (obj.has("fov_deg")) {
        const Node n = obj.at("fov_deg");
        cam.fovDeg = n.number();
        if (!(cam.fovDeg > 0.0 && cam.fovDeg < 180.0)) {
            n.fail("must be in (0, 180) degrees, got " + n.json().dump());
        }
    }
    if (obj.has("width")) cam.width = obj.at("width").integer(1, kMaxImageSide);
    if (obj.has("height")) cam.height = obj.at("height").integer(1, kMaxImageSide);

    const Vec3 view = cam.lookAt - cam.eye;
    const double viewLen = glm::length(view);
    const double scale = std::max(glm::length(cam.eye), glm::length(cam.lookAt));
    if (!(viewLen > 1e-12 * scale)) {
        throw InputError(node.context().file, obj.pointer() + "/look_at",
                         "must differ from eye (eye " + vecText(cam.eye) + ", look_at " +
                             vecText(cam.lookAt) + ")");
    }
    // Both unit vectors here: |cross| is the sine of the angle between them.
    if (glm::length(glm::cross(view / viewLen, cam.up)) < 1e-9) {
        throw InputError(
            node.context().file, obj.pointer() + "/up",
            std::string(obj.has("up") ? "is" : "(default [0, 0, 1]) is") +
                " parallel to the viewing direction (look_at - eye = " + vecText(view) + ")");
    }
    return cam;
}

RectLight parseLight(const Node& node, size_t index) {
    const Object obj(node, {"name", "type", "corner", "edge_u", "edge_v", "radiance"});
    obj.kind("light", {"rect"}, "rect");
    RectLight light;
    light.name =
        obj.has("name") ? obj.at("name").nonEmptyString() : "light_" + std::to_string(index);
    light.corner = obj.at("corner").vec3();
    light.edgeU = obj.at("edge_u").vec3();
    light.edgeV = obj.at("edge_v").vec3();
    light.radiance = obj.rgb("radiance", Rgb(1.0));
    // The emitting normal is edge_u x edge_v: parallel or zero edges leave it undefined.
    const double area = glm::length(glm::cross(light.edgeU, light.edgeV));
    const double lenProduct = glm::length(light.edgeU) * glm::length(light.edgeV);
    if (!(area > kMinEdgeSine * lenProduct) || !(area > 0.0) || !std::isfinite(area)) {
        obj.node().fail("degenerate rectangle: edge_u " + vecText(light.edgeU) + " and edge_v " +
                        vecText(light.edgeV) + " are parallel or zero (area " + numberText(area) +
                        ")");
    }
    return light;
}

PlaneReceiver parseReceiver(const Node& node) {
    const Object obj(node, {"type", "point", "normal", "albedo", "checker"});
    obj.kind("receiver", {"plane"});
    PlaneReceiver plane;
    plane.point = obj.at("point").vec3();
    plane.normal = obj.at("normal").direction();
    plane.albedo = obj.rgb("albedo", plane.albedo);
    if (obj.has("checker")) {
        const Node n = obj.at("checker");
        if (n.json().is_boolean()) {
            plane.checker = n.boolean();
        } else {
            const Object checker(n, {"albedo2", "scale"});
            plane.checker = true;
            plane.albedo2 = checker.rgb("albedo2", plane.albedo2);
            plane.checkerScale = checker.numberAbove("scale", 0.0, plane.checkerScale);
        }
    }
    return plane;
}

/// Refuses implicit primitives too small for the voxels or too far out for OpenVDB's indices.
void checkVoxelization(const Object& obj, const std::string& sizeKey, double smallestExtent,
                       double largestCoordinate, double voxelSize) {
    if (smallestExtent < kMinFeatureVoxels * voxelSize) {
        obj.at(sizeKey).fail("is below " + numberText(kMinFeatureVoxels) + " voxels (voxel_size " +
                             numberText(voxelSize) +
                             "): the level set would be empty or wrong; lower voxel_size or "
                             "set \"analytic\": true");
    }
    if (largestCoordinate / voxelSize > kMaxIndexCoordinate) {
        obj.node().fail("extends to ~" + numberText(std::round(largestCoordinate / voxelSize)) +
                        " voxels from the origin, beyond the level set's index range (" +
                        numberText(kMaxIndexCoordinate) + "); raise voxel_size");
    }
}

ObstaclePlan parseObstacle(const Node& node, size_t index, const LevelSetSettings& global) {
    if (!node.json().is_object()) node.fail("expected an object, got " + typeName(node.json()));
    // The allowed keys depend on the type, so read it before the key check.
    const std::vector<std::string> kinds = {"sphere", "box", "vdb"};
    std::string kind;
    {
        auto it = node.json().find("type");
        if (it == node.json().end()) {
            throw InputError(node.context().file, node.pointer() + "/type",
                             "missing required field 'type' (one of sphere, box, vdb)");
        }
        const Node n(*it, node.pointer() + "/type", node.context());
        kind = n.string();
        if (std::find(kinds.begin(), kinds.end(), kind) == kinds.end()) {
            n.fail("unknown obstacle type " + inQuotes(kind) + suggestion(kind, kinds));
        }
    }
    std::vector<std::string> keys = {"type", "name", "albedo"};
    if (kind == "sphere") {
        keys.insert(keys.end(), {"center", "radius", "analytic", "voxel_size", "half_width"});
    } else if (kind == "box") {
        keys.insert(keys.end(), {"center", "size", "analytic", "voxel_size", "half_width"});
    } else {
        keys.insert(keys.end(), {"file", "grid"});
    }
    const Object obj(node, keys);

    ObstaclePlan plan;
    plan.pointer = node.pointer();
    plan.index = index;
    if (obj.has("name")) plan.name = obj.at("name").nonEmptyString();
    plan.albedo = obj.rgb("albedo", plan.albedo);

    if (kind == "vdb") {
        VdbPlan vdb;
        const Node fileNode = obj.at("file");
        const std::string file = fileNode.nonEmptyString();
        std::filesystem::path p(file);
        if (p.is_relative() && !node.context().baseDir.empty()) {
            p = std::filesystem::path(node.context().baseDir) / p;
        }
        vdb.path = p.lexically_normal().string();
        std::error_code ec;
        if (!std::filesystem::is_regular_file(vdb.path, ec)) {
            fileNode.fail("no such file " + inQuotes(file) +
                          (vdb.path != file ? " (resolved to " + inQuotes(vdb.path) + ")" : ""));
        }
        if (obj.has("grid")) vdb.grid = obj.at("grid").nonEmptyString();
        plan.shape = vdb;
        return plan;
    }

    const Vec3 center = obj.at("center").vec3();
    const bool analytic = obj.boolean("analytic", false);
    const double voxel = obj.numberAbove("voxel_size", 0.0, global.voxelSize);
    double halfWidth = global.halfWidth;
    if (obj.has("half_width")) {
        halfWidth = obj.at("half_width").numberAbove(1.0);
    }
    const double farthest = glm::length(center);

    if (kind == "sphere") {
        const double radius = obj.at("radius").numberAbove(0.0);
        if (analytic) {
            plan.shape = AnalyticSphere{center, radius};
        } else {
            checkVoxelization(obj, "radius", radius, farthest + radius, voxel);
            plan.shape = SphereLevelSetPlan{center, radius, voxel, halfWidth};
        }
    } else {
        const Node sizeNode = obj.at("size");
        const Vec3 size = sizeNode.vec3();
        for (int k = 0; k < 3; ++k) {
            if (!(size[k] > 0.0)) {
                sizeNode.element(k).fail("must be > 0, got " + numberText(size[k]));
            }
        }
        const Vec3 lo = center - 0.5 * size, hi = center + 0.5 * size;
        if (analytic) {
            plan.shape = AnalyticBox{lo, hi};
        } else {
            const double smallest = std::min({size.x, size.y, size.z});
            checkVoxelization(obj, "size", smallest, farthest + glm::length(size), voxel);
            plan.shape = BoxLevelSetPlan{lo, hi, voxel, halfWidth};
        }
    }
    return plan;
}

LevelSetSettings parseLevelSetSettings(const Node& node, MemoryBudget& budget) {
    const Object obj(node, {"voxel_size", "half_width", "max_memory_gib"});
    LevelSetSettings s;
    s.voxelSize = obj.numberAbove("voxel_size", 0.0, s.voxelSize);
    // OpenVDB's sphere rasterizer refuses a band of one voxel or less.
    s.halfWidth = obj.numberAbove("half_width", 1.0, s.halfWidth);
    budget.limitBytes = obj.numberAbove("max_memory_gib", 0.0, kDefaultMemoryLimitGiB) * kGiB;
    return s;
}

// ---------------------------------------------------------------------------------------------
// Pass 2: memory. A narrow band holds about (surface area / voxel^2) * (2 * half width) voxels.

double estimatedBytes(const ShapePlan& shape) {
    double area = 0.0, voxel = 1.0, halfWidth = 0.0;
    if (const auto* s = std::get_if<SphereLevelSetPlan>(&shape)) {
        area = 4.0 * kPi * s->radius * s->radius;
        voxel = s->voxelSize;
        halfWidth = s->halfWidth;
    } else if (const auto* b = std::get_if<BoxLevelSetPlan>(&shape)) {
        const Vec3 d = b->hi - b->lo;
        area = 2.0 * (d.x * d.y + d.y * d.z + d.z * d.x);
        voxel = b->voxelSize;
        halfWidth = b->halfWidth;
    } else {
        return 0.0;  // analytic shapes need nothing; .vdb files are as large as they are
    }
    return area / (voxel * voxel) * 2.0 * halfWidth * kBytesPerBandVoxel;
}

void checkMemory(const std::vector<ObstaclePlan>& plans, const MemoryBudget& budget,
                 const std::string& file) {
    double total = 0.0;
    for (const ObstaclePlan& p : plans) total += estimatedBytes(p.shape);
    if (total <= budget.limitBytes) return;
    // Blame the largest one: it is the one worth coarsening.
    const ObstaclePlan* worst = &plans.front();
    for (const ObstaclePlan& p : plans) {
        if (estimatedBytes(p.shape) > estimatedBytes(worst->shape)) worst = &p;
    }
    throw InputError(
        file, worst->pointer,
        "would need ~" + bytesText(estimatedBytes(worst->shape)) + " for its level set (~" +
            bytesText(total) + " for all implicit obstacles, over the limit of " +
            bytesText(budget.limitBytes) + "); raise voxel_size or level_set.max_memory_gib");
}

// ---------------------------------------------------------------------------------------------
// Pass 3: building

void buildObstacles(const ObstaclePlan& plan, const std::string& file, std::vector<Obstacle>& out) {
    const std::string name =
        plan.name.empty() ? "obstacle_" + std::to_string(plan.index) : plan.name;
    auto add = [&](std::string n, ObstacleShape shape) {
        out.push_back(Obstacle{std::move(n), std::move(shape), plan.albedo});
    };
    if (const auto* s = std::get_if<AnalyticSphere>(&plan.shape)) {
        add(name, *s);
    } else if (const auto* b = std::get_if<AnalyticBox>(&plan.shape)) {
        add(name, *b);
    } else if (const auto* sl = std::get_if<SphereLevelSetPlan>(&plan.shape)) {
        add(name, makeSphereLevelSet(sl->center, sl->radius, sl->voxelSize, sl->halfWidth, name));
    } else if (const auto* bl = std::get_if<BoxLevelSetPlan>(&plan.shape)) {
        add(name, makeBoxLevelSet(bl->lo, bl->hi, bl->voxelSize, bl->halfWidth, name));
    } else {
        const auto& vdb = std::get<VdbPlan>(plan.shape);
        std::vector<LevelSetPtr> grids;
        try {
            grids = readLevelSets(vdb.path, vdb.grid, plan.pointer);
        } catch (const InputError& e) {
            // Name the scene file first (that is what the user edits), the .vdb in the message.
            throw InputError(file, e.where().empty() ? plan.pointer : e.where(),
                             e.file() + ": " + e.message());
        }
        for (size_t j = 0; j < grids.size(); ++j) {
            const LevelSetPtr& g = grids[j];
            const std::string gridName = describe(*g).name;
            // One grid takes the obstacle's name; several are told apart by their grid names.
            std::string n;
            if (grids.size() == 1) {
                n = !plan.name.empty() ? plan.name : (!gridName.empty() ? gridName : name);
            } else if (!plan.name.empty()) {
                n = plan.name + "/" + (gridName.empty() ? std::to_string(j) : gridName);
            } else {
                n = !gridName.empty() ? gridName : name + "/" + std::to_string(j);
            }
            add(n, g);
        }
    }
}

Scene parseDocument(const Json& root, const Context& ctx) {
    const Node rootNode(root, "", ctx);
    const Object top(rootNode,
                     {"camera", "lights", "obstacles", "receivers", "level_set", "background"});
    Scene scene;
    scene.file = ctx.file;

    MemoryBudget budget;
    if (top.has("level_set")) scene.levelSet = parseLevelSetSettings(top.at("level_set"), budget);
    if (top.has("camera")) scene.camera = parseCamera(top.at("camera"));
    scene.background = top.rgb("background", scene.background);

    const Node lights = top.at("lights");
    lights.array();
    if (lights.json().empty()) lights.fail("the scene needs at least one light");
    std::set<std::string> lightNames;
    for (size_t i = 0; i < lights.json().size(); ++i) {
        scene.lights.push_back(parseLight(lights.element(i), i));
        if (!lightNames.insert(scene.lights.back().name).second) {
            throw InputError(ctx.file, lights.element(i).pointer() + "/name",
                             "duplicate light name " + inQuotes(scene.lights.back().name));
        }
    }

    if (top.has("receivers")) {
        const Node receivers = top.at("receivers");
        receivers.array();
        for (size_t i = 0; i < receivers.json().size(); ++i) {
            scene.receivers.push_back(parseReceiver(receivers.element(i)));
        }
    }

    std::vector<ObstaclePlan> plans;
    if (top.has("obstacles")) {
        const Node obstacles = top.at("obstacles");
        obstacles.array();
        for (size_t i = 0; i < obstacles.json().size(); ++i) {
            plans.push_back(parseObstacle(obstacles.element(i), i, scene.levelSet));
        }
    }

    checkMemory(plans, budget, ctx.file);
    for (const ObstaclePlan& p : plans) buildObstacles(p, ctx.file, scene.obstacles);
    return scene;
}

}  // namespace

// ---------------------------------------------------------------------------------------------

Scene parseScene(const std::string& jsonText, const std::string& file, const std::string& baseDir) {
    const Context ctx{file, baseDir};
    const Json root = parseText(jsonText, file);
    return parseDocument(root, ctx);
}

Scene loadScene(const std::string& path) {
    std::error_code ec;
    if (std::filesystem::is_directory(path, ec)) {
        throw InputError(path, "", "is a directory, not a scene file");
    }
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path, "", "cannot open the scene file");
    std::ostringstream text;
    text << in.rdbuf();
    if (in.bad()) throw InputError(path, "", "cannot read the scene file");
    std::string baseDir = std::filesystem::path(path).parent_path().string();
    if (baseDir.empty()) baseDir = ".";
    return parseScene(text.str(), path, baseDir);
}

size_t Scene::lightIndex(const std::string& name) const {
    std::string names;
    for (const RectLight& l : lights) names += (names.empty() ? "" : ", ") + inQuotes(l.name);
    if (lights.empty()) throw InputError(file, "/lights", "the scene has no lights");
    if (name.empty()) {
        if (lights.size() == 1) return 0;
        throw InputError(file, "/lights",
                         "the scene has " + std::to_string(lights.size()) + " lights (" + names +
                             "); choose one by name");
    }
    std::vector<size_t> matches;
    for (size_t i = 0; i < lights.size(); ++i) {
        if (lights[i].name == name) matches.push_back(i);
    }
    if (matches.size() == 1) return matches.front();
    if (matches.empty()) {
        std::vector<std::string> all;
        for (const RectLight& l : lights) all.push_back(l.name);
        throw InputError(file, "/lights",
                         "no light named " + inQuotes(name) + suggestion(name, all));
    }
    throw InputError(file, "/lights",
                     std::to_string(matches.size()) + " lights are named " + inQuotes(name) +
                         "; the choice is ambiguous");
}

Occluder Scene::makeOccluder() const {
    std::vector<ObstacleShape> shapes;
    shapes.reserve(obstacles.size());
    for (const Obstacle& o : obstacles) shapes.push_back(o.shape);
    return Occluder(std::move(shapes));
}

}  // namespace penumbra
