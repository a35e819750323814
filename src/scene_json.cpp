// The scene loader: JSON text -> validated Scene. The format is documented in
// docs/scene-format.md; keep the two in step.
//
// Loading runs in three passes so that a typo in the last obstacle is reported before minutes
// are spent voxelizing the first one: (1) parse and validate the whole document into plans
// (meshes are read here: their size enters the estimate), (2) cut unbounded half-spaces to the
// scene's bounds, estimate the memory of every level set to be built and refuse the scene when
// over the limit, (3) build the level sets (shape.h) and read the .vdb files.
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <new>
#include <set>
#include <stdexcept>
#include <sstream>
#include <iomanip>
#include <mutex>
#include <variant>

#include "penumbra/error.h"
#include "penumbra/hash.h"
#include "penumbra/json_reader.h"
#include "penumbra/level_set.h"
#include "penumbra/scene.h"
#include "penumbra/shape.h"
#include "penumbra/volume.h"

namespace penumbra {

namespace {

using Json = nlohmann::json;

constexpr int kMaxImageSide = 32768;
constexpr double kDefaultMemoryLimitGiB = 16.0;
constexpr double kGiB = 1024.0 * 1024.0 * 1024.0;
// OpenVDB index coordinates are int32 and its mesher works in float voxel units; keep geometry
// well inside both ranges.
constexpr double kMaxIndexCoordinate = double(1 << 24);
// Smaller features come out empty or badly voxelized (OpenVDB's own sphere builder produces
// nothing under 1.5 voxels in radius).
constexpr double kMinFeatureVoxels = 1.5;
// sin(angle) between edge_u and edge_v below which a light counts as degenerate.
constexpr double kMinEdgeSine = 1e-9;
/// The largest magnitude of any number in a scene file (docs/scene-format.md).
constexpr double kMaxMagnitude = 1e12;

// ---------------------------------------------------------------------------------------------
// Small text helpers

/// User text in single quotes, made printable (json_reader.h).
std::string inQuotes(const std::string& s) { return "'" + printable(s) + "'"; }

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
    /// Every file the scene names (meshes, .vdb files), as read, with the JSON pointer naming
    /// it: Scene::inputFiles.
    mutable std::vector<std::pair<std::string, std::string>> inputs;
    LevelSetCache* cache = nullptr;  ///< shares level sets between loads (batch jobs)
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
        // Beyond this, squares of coordinates overflow and single-precision images saturate:
        // no scene value (coordinate, size, radiance) is meaningful there.
        if (std::abs(x) > kMaxMagnitude) {
            fail("is " + mValue->dump() + ", beyond the range of scene values (magnitude at most "
                 "1e12)");
        }
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
// Pass 1: the document -> plans

/// An obstacle built by shape.h: implicit primitives, CSG trees, meshes.
struct ImplicitPlan {
    ShapeNode node;
    double voxelSize, halfWidth;
};
struct VdbPlan {
    std::string path;  ///< resolved
    std::string grid;  ///< empty: every level-set grid (and every fog volume)
    Similarity transform;
    double extinction = 1.0;  ///< for the file's volumes
};
struct ObstaclePlan;
/// A participating medium made from a shape: its level set turned into a fog volume.
struct FogPlan {
    std::shared_ptr<ObstaclePlan> shape;
    double density = 1.0, falloff = 0.0, extinction = 1.0;
};
using ShapePlan = std::variant<AnalyticSphere, AnalyticBox, ImplicitPlan, VdbPlan, FogPlan>;

struct ObstaclePlan {
    std::string pointer;
    std::string name;  ///< empty: derive (obstacle_K, or the grid names of a .vdb)
    size_t index;      ///< position in the "obstacles" array
    std::string type;  ///< the scene file's type
    Rgb albedo{0.8};
    double voxelSize = 0.0, halfWidth = 0.0;  ///< implicit and analytic obstacles
    ShapePlan shape;
    /// What decides the level sets it builds or reads (LevelSetCache): its JSON, the voxel size
    /// and band it resolved to, the content of every file it reads, and the bounds given to its
    /// unbounded half-spaces.
    std::string cacheKey;
};

/// The default limit on the memory of the level sets to build: 16 GiB, or three quarters of
/// the machine's memory when that is less.
double defaultMemoryLimitBytes() {
    double limit = kDefaultMemoryLimitGiB * kGiB;
    const long pages = ::sysconf(_SC_PHYS_PAGES), pageSize = ::sysconf(_SC_PAGE_SIZE);
    if (pages > 0 && pageSize > 0) limit = std::min(limit, 0.75 * double(pages) * double(pageSize));
    return limit;
}

struct MemoryBudget {
    double limitBytes = defaultMemoryLimitBytes();
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

// ---------------------------------------------------------------------------------------------
// Obstacles and CSG children

const std::vector<std::string> kShapeTypes = {"sphere",     "box",  "torus", "capsule", "cylinder",
                                              "half_space", "csg",  "mesh",  "vdb"};
const std::vector<std::string> kCsgOps = {"union", "intersection", "difference", "smooth_union"};

std::string joined(const std::vector<std::string>& words) {
    std::string out;
    for (const std::string& w : words) out += (out.empty() ? "" : ", ") + w;
    return out;
}

/// The keys of a shape's own geometry (besides type, transform, and the obstacle-level keys).
std::vector<std::string> shapeKeys(const std::string& kind) {
    if (kind == "sphere") return {"center", "radius"};
    if (kind == "box") return {"center", "size", "round"};
    if (kind == "torus") return {"center", "major_radius", "minor_radius", "axis"};
    if (kind == "capsule") return {"a", "b", "radius"};
    if (kind == "cylinder") return {"center", "axis", "radius", "height"};
    if (kind == "half_space") return {"point", "normal", "bounds"};
    if (kind == "csg") return {"op", "blend", "children"};
    if (kind == "mesh") return {"file", "thickness"};
    return {"file", "grid"};  // vdb
}

/// The "type" of an obstacle or CSG child, read before its keys are checked (the allowed keys
/// depend on it).
std::string readType(const Node& node, const std::string& what) {
    if (!node.json().is_object()) node.fail("expected an object, got " + typeName(node.json()));
    auto it = node.json().find("type");
    if (it == node.json().end()) {
        throw InputError(node.context().file, node.pointer() + "/type",
                         "missing required field 'type' (one of " + joined(kShapeTypes) + ")");
    }
    const Node n(*it, node.pointer() + "/type", node.context());
    const std::string kind = n.string();
    if (std::find(kShapeTypes.begin(), kShapeTypes.end(), kind) == kShapeTypes.end()) {
        n.fail("unknown " + what + " type " + inQuotes(kind) + suggestion(kind, kShapeTypes));
    }
    return kind;
}

struct ParsedTransform {
    Similarity similarity;
    bool rotates = false;
};

ParsedTransform parseTransform(const Node& node) {
    const Object obj(node, {"translate", "rotate_deg", "scale"});
    const Vec3 translate = obj.vec3("translate", Vec3(0.0));
    const Vec3 rotateDeg = obj.vec3("rotate_deg", Vec3(0.0));
    const double scale = obj.numberAbove("scale", 0.0, 1.0);
    return {Similarity::fromSceneTransform(translate, rotateDeg, scale), rotateDeg != Vec3(0.0)};
}

/// A path relative to the scene file's directory, which must name an existing file.
std::string existingFile(const Node& fileNode) {
    const std::string file = fileNode.nonEmptyString();
    std::filesystem::path p(file);
    if (p.is_relative() && !fileNode.context().baseDir.empty()) {
        p = std::filesystem::path(fileNode.context().baseDir) / p;
    }
    const std::string path = p.lexically_normal().string();
    const std::string resolved = path != file ? " (resolved to " + inQuotes(path) + ")" : "";
    std::error_code ec;
    if (std::filesystem::is_directory(path, ec)) {
        fileNode.fail(inQuotes(file) + resolved + " is a directory, not a file");
    }
    if (!std::filesystem::exists(path, ec)) {
        fileNode.fail("no such file " + inQuotes(file) + resolved);
    }
    if (!std::filesystem::is_regular_file(path, ec)) {
        // A FIFO or device would block the reader or never end.
        fileNode.fail(inQuotes(file) + resolved + " is not a regular file");
    }
    // Checked here so that a permission problem is reported as such (and at this pointer),
    // not as a parse error of an empty file by the reader.
    if (!std::ifstream(path, std::ios::binary)) {
        fileNode.fail("cannot open " + inQuotes(file) + resolved + " for reading: " +
                      std::strerror(errno));
    }
    fileNode.context().inputs.emplace_back(path, fileNode.pointer());
    return path;
}

/// Refuses a feature too small for the voxels: the level set would be empty or wrong.
void checkFeature(const Node& n, double localSize, double scale, double voxel,
                  bool analyticHint) {
    if (localSize * scale < kMinFeatureVoxels * voxel) {
        n.fail("is below " + numberText(kMinFeatureVoxels) + " voxels (voxel_size " +
               numberText(voxel) + (scale != 1.0 ? ", after scaling by " + numberText(scale) : "") +
               "): the level set would be empty or wrong; lower voxel_size" +
               (analyticHint ? " or set \"analytic\": true" : ""));
    }
}

Vec3 positiveVec3(const Node& n) {
    const Vec3 v = n.vec3();
    for (int k = 0; k < 3; ++k) {
        if (!(v[k] > 0.0)) n.element(k).fail("must be > 0, got " + numberText(v[k]));
    }
    return v;
}

/// "bounds": [[lo], [hi]] with lo < hi on every axis.
Box3 parseBounds(const Node& n) {
    if (!n.json().is_array() || n.json().size() != 2) {
        n.fail("expected [[x, y, z], [x, y, z]] (low and high corners), got " + typeName(n.json()));
    }
    const Box3 b{n.element(0).vec3(), n.element(1).vec3()};
    for (int k = 0; k < 3; ++k) {
        if (!(b.lo[k] < b.hi[k])) {
            n.element(1).element(k).fail("must be > the low corner's " + numberText(b.lo[k]) +
                                         ", got " + numberText(b.hi[k]));
        }
    }
    return b;
}

TriangleMesh readMesh(const Node& fileNode, const std::string& path) {
    try {
        return readObj(path);
    } catch (const InputError& e) {
        // The scene file and pointer first (what the user edits), the OBJ and its line after.
        throw InputError(fileNode.context().file, fileNode.pointer(),
                         e.file() + (e.where().empty() ? "" : ": " + e.where()) + ": " +
                             e.message());
    }
}

ShapeNode parseShape(const Object& obj, const std::string& kind, double voxel, double parentScale,
                     bool topLevel);

ShapeNode parseChild(const Node& node, double voxel, double parentScale) {
    const std::string kind = readType(node, "shape");
    std::vector<std::string> keys = {"type", "transform"};
    const std::vector<std::string> own = shapeKeys(kind);
    keys.insert(keys.end(), own.begin(), own.end());
    return parseShape(Object(node, keys), kind, voxel, parentScale, false);
}

/// The geometry of a non-analytic obstacle or of a CSG child, in its local frame. `voxel` is
/// the voxel size of the obstacle being built, `parentScale` the scale its ancestors apply.
ShapeNode parseShape(const Object& obj, const std::string& kind, double voxel, double parentScale,
                     bool topLevel) {
    ShapeNode out;
    if (obj.has("transform")) out.transform = parseTransform(obj.at("transform")).similarity;
    const double s = parentScale * out.transform.scale;
    const bool hint = topLevel && (kind == "sphere" || kind == "box");
    auto feature = [&](const Node& n, double localSize) {
        checkFeature(n, localSize, s, voxel, hint);
    };
    auto positive = [&](const std::string& key) {
        const Node n = obj.at(key);
        const double x = n.numberAbove(0.0);
        feature(n, x);
        return x;
    };
    auto axis = [&]() {
        return obj.has("axis") ? obj.at("axis").direction() : Vec3(0.0, 0.0, 1.0);
    };

    if (kind == "sphere") {
        SphereShape sphere;
        sphere.center = obj.at("center").vec3();
        sphere.radius = positive("radius");
        out.kind = sphere;
    } else if (kind == "box") {
        BoxShape box;
        box.center = obj.at("center").vec3();
        const Node sizeNode = obj.at("size");
        box.size = positiveVec3(sizeNode);
        const double smallest = std::min({box.size.x, box.size.y, box.size.z});
        feature(sizeNode, smallest);
        if (obj.has("round")) {
            const Node r = obj.at("round");
            box.round = r.number();
            if (box.round < 0.0) r.fail("must be >= 0, got " + numberText(box.round));
            if (box.round > 0.5 * smallest) {
                r.fail("must be <= half the smallest size (" + numberText(0.5 * smallest) +
                       "), got " + numberText(box.round));
            }
        }
        out.kind = box;
    } else if (kind == "torus") {
        TorusShape torus;
        torus.center = obj.at("center").vec3();
        torus.majorRadius = obj.at("major_radius").numberAbove(0.0);
        torus.minorRadius = positive("minor_radius");
        torus.axis = axis();
        out.kind = torus;
    } else if (kind == "capsule") {
        CapsuleShape capsule;
        capsule.a = obj.at("a").vec3();
        capsule.b = obj.at("b").vec3();
        capsule.radius = positive("radius");
        out.kind = capsule;
    } else if (kind == "cylinder") {
        CylinderShape cylinder;
        cylinder.center = obj.at("center").vec3();
        cylinder.axis = axis();
        cylinder.radius = positive("radius");
        cylinder.height = positive("height");
        out.kind = cylinder;
    } else if (kind == "half_space") {
        HalfSpaceShape half;
        half.point = obj.at("point").vec3();
        half.normal = obj.at("normal").direction();
        if (obj.has("bounds")) half.boundsWS = parseBounds(obj.at("bounds"));
        out.kind = half;
    } else if (kind == "csg") {
        CsgShape csg;
        const Node opNode = obj.at("op");
        const std::string op = opNode.string();
        const auto it = std::find(kCsgOps.begin(), kCsgOps.end(), op);
        if (it == kCsgOps.end()) {
            opNode.fail("unknown csg op " + inQuotes(op) + suggestion(op, kCsgOps));
        }
        csg.op = static_cast<CsgOp>(it - kCsgOps.begin());
        if (csg.op == CsgOp::SmoothUnion) {
            csg.blend = obj.at("blend").numberAbove(0.0);
        } else if (obj.has("blend")) {
            obj.at("blend").fail("applies only to op \"smooth_union\" (this csg is a " + op + ")");
        }
        const Node children = obj.at("children");
        children.array();
        if (children.json().size() < 2) {
            children.fail("a csg needs at least 2 children, got " +
                          std::to_string(children.json().size()));
        }
        for (size_t i = 0; i < children.json().size(); ++i) {
            csg.children.push_back(parseChild(children.element(i), voxel, s));
        }
        out.kind = std::move(csg);
    } else if (kind == "mesh") {
        MeshShape mesh;
        const Node fileNode = obj.at("file");
        mesh.file = existingFile(fileNode);
        mesh.mesh = std::make_shared<const TriangleMesh>(readMesh(fileNode, mesh.file));
        if (obj.has("thickness")) mesh.thickness = positive("thickness");
        out.kind = std::move(mesh);
    } else {  // a .vdb grid inside a CSG, read in pass 3
        GridShape grid;
        grid.file = existingFile(obj.at("file"));
        if (obj.has("grid")) grid.grid = obj.at("grid").nonEmptyString();
        out.kind = std::move(grid);
    }
    return out;
}

/// Refuses geometry beyond OpenVDB's index range at this voxel size.
void checkIndexRange(const Node& node, const Box3& bounds, double voxel) {
    if (bounds.empty()) return;
    const double reach = std::max({std::fabs(bounds.lo.x), std::fabs(bounds.lo.y),
                                   std::fabs(bounds.lo.z), std::fabs(bounds.hi.x),
                                   std::fabs(bounds.hi.y), std::fabs(bounds.hi.z)});
    if (reach / voxel > kMaxIndexCoordinate) {
        node.fail("extends to ~" + numberText(std::round(reach / voxel)) +
                  " voxels from the origin, beyond the level set's index range (" +
                  numberText(kMaxIndexCoordinate) + "); raise voxel_size");
    }
}

/// A file's content hash, for LevelSetCache keys ("unreadable" when it cannot be read: the
/// load that follows reports why).
std::string contentDigest(const std::string& path) {
    try {
        return digestFile(path).hash;
    } catch (const std::exception&) {
        return "unreadable";
    }
}

ObstaclePlan parseFog(const Node& node, size_t index, const LevelSetSettings& global);

/// A number >= 0 (0 allowed, unlike numberAbove).
double nonNegative(const Object& obj, const std::string& key, double fallback) {
    if (!obj.has(key)) return fallback;
    const Node n = obj.at(key);
    const double x = n.number();
    if (x < 0.0) n.fail("must be >= 0, got " + n.json().dump());
    return x;
}

ObstaclePlan parseObstacle(const Node& node, size_t index, const LevelSetSettings& global) {
    if (node.json().is_object() && node.json().contains("type") && node.json()["type"] == "fog") {
        return parseFog(node, index, global);
    }
    const std::string kind = readType(node, "obstacle");
    std::vector<std::string> keys = {"type", "name", "albedo", "transform"};
    const std::vector<std::string> own = shapeKeys(kind);
    keys.insert(keys.end(), own.begin(), own.end());
    if (kind != "vdb") keys.insert(keys.end(), {"voxel_size", "half_width"});
    if (kind == "vdb") keys.push_back("extinction");
    if (kind == "sphere" || kind == "box") keys.push_back("analytic");
    const Object obj(node, keys);

    ObstaclePlan plan;
    plan.pointer = node.pointer();
    plan.index = index;
    plan.type = kind;
    if (obj.has("name")) plan.name = obj.at("name").nonEmptyString();
    plan.albedo = obj.rgb("albedo", plan.albedo);

    if (kind == "vdb") {
        VdbPlan vdb;
        vdb.path = existingFile(obj.at("file"));
        if (obj.has("grid")) vdb.grid = obj.at("grid").nonEmptyString();
        if (obj.has("transform")) vdb.transform = parseTransform(obj.at("transform")).similarity;
        vdb.extinction = nonNegative(obj, "extinction", 1.0);
        plan.shape = vdb;
        return plan;
    }

    plan.voxelSize = obj.numberAbove("voxel_size", 0.0, global.voxelSize);
    // OpenVDB's rasterizers refuse a band of one voxel or less.
    plan.halfWidth = obj.numberAbove("half_width", 1.0, global.halfWidth);

    if (obj.boolean("analytic", false)) {
        ParsedTransform t;
        if (obj.has("transform")) t = parseTransform(obj.at("transform"));
        const Vec3 center = t.similarity.apply(obj.at("center").vec3());
        if (kind == "sphere") {
            const double radius = obj.at("radius").numberAbove(0.0) * t.similarity.scale;
            plan.shape = AnalyticSphere{center, radius};
        } else {
            if (t.rotates) {
                obj.at("transform").fail(
                    "an analytic box stays axis-aligned: rotate_deg must be [0, 0, 0] (or drop "
                    "\"analytic\")");
            }
            if (obj.has("round")) obj.at("round").fail("an analytic box has sharp edges");
            const Vec3 size = positiveVec3(obj.at("size")) * t.similarity.scale;
            plan.shape = AnalyticBox{center - 0.5 * size, center + 0.5 * size};
        }
        return plan;
    }
    ImplicitPlan implicit{parseShape(obj, kind, plan.voxelSize, 1.0, true), plan.voxelSize,
                          plan.halfWidth};
    checkIndexRange(obj.node(), shapeBounds(implicit.node), plan.voxelSize);
    plan.shape = std::move(implicit);
    return plan;
}

/// {"type": "fog", "shape": {an obstacle}, "density", "falloff", "extinction", "albedo"}: the
/// shape's level set (with an interior band deep enough for the falloff) becomes a fog volume.
ObstaclePlan parseFog(const Node& node, size_t index, const LevelSetSettings& global) {
    const Object obj(node, {"type", "name", "shape", "density", "falloff", "extinction", "albedo",
                            "voxel_size", "half_width"});
    ObstaclePlan plan;
    plan.pointer = node.pointer();
    plan.index = index;
    plan.type = "fog";
    if (obj.has("name")) plan.name = obj.at("name").nonEmptyString();
    plan.albedo = obj.rgb("albedo", plan.albedo);
    FogPlan fog;
    fog.density = nonNegative(obj, "density", 1.0);
    fog.falloff = nonNegative(obj, "falloff", 0.0);
    fog.extinction = nonNegative(obj, "extinction", 1.0);
    LevelSetSettings inner = global;
    inner.voxelSize = obj.numberAbove("voxel_size", 0.0, global.voxelSize);
    inner.halfWidth = obj.numberAbove("half_width", 1.0, global.halfWidth);
    ObstaclePlan shape = parseObstacle(obj.at("shape"), index, inner);
    if (std::holds_alternative<FogPlan>(shape.shape)) obj.at("shape").fail("a fog's shape is not a fog");
    if (std::holds_alternative<AnalyticSphere>(shape.shape) ||
        std::holds_alternative<AnalyticBox>(shape.shape)) {
        obj.at("shape").fail("a fog's shape is voxelized: drop \"analytic\"");
    }
    if (auto* implicit = std::get_if<ImplicitPlan>(&shape.shape)) {
        // The ramp lies inside the surface: the band must reach that deep.
        implicit->halfWidth = std::max(implicit->halfWidth, fog.falloff / implicit->voxelSize + 1.5);
        shape.halfWidth = implicit->halfWidth;
    }
    plan.voxelSize = shape.voxelSize;
    plan.halfWidth = shape.halfWidth;
    fog.shape = std::make_shared<ObstaclePlan>(std::move(shape));
    plan.shape = std::move(fog);
    return plan;
}

LevelSetSettings parseLevelSetSettings(const Node& node, MemoryBudget& budget) {
    const Object obj(node, {"voxel_size", "half_width", "max_memory_gib"});
    LevelSetSettings s;
    s.voxelSize = obj.numberAbove("voxel_size", 0.0, s.voxelSize);
    // OpenVDB's sphere rasterizer refuses a band of one voxel or less.
    s.halfWidth = obj.numberAbove("half_width", 1.0, s.halfWidth);
    if (obj.has("max_memory_gib")) {
        budget.limitBytes = obj.at("max_memory_gib").numberAbove(0.0) * kGiB;
    }
    return s;
}

// ---------------------------------------------------------------------------------------------
// Pass 2: half-space bounds, then memory

/// Calls f on every node of the tree, with its JSON pointer (the tree mirrors the document).
template <class F>
void forEachNode(ShapeNode& node, const std::string& pointer, F&& f) {
    f(node, pointer);
    if (auto* csg = std::get_if<CsgShape>(&node.kind)) {
        for (size_t i = 0; i < csg->children.size(); ++i) {
            forEachNode(csg->children[i], pointer + "/children/" + std::to_string(i), f);
        }
    }
}

/// The box half-spaces are cut to when they give no "bounds": around the lights, the camera's
/// eye and target and every obstacle other than half-spaces and .vdb files, widened by 10% of
/// its diagonal on each side.
Box3 sceneBounds(const Scene& scene, const std::vector<ObstaclePlan>& plans) {
    Box3 b;
    for (const RectLight& l : scene.lights) {
        for (const Vec3& p : l.polygon()) b.extend(p);
    }
    if (scene.camera) {
        b.extend(scene.camera->eye);
        b.extend(scene.camera->lookAt);
    }
    for (const ObstaclePlan& p : plans) {
        if (const auto* s = std::get_if<AnalyticSphere>(&p.shape)) {
            b.extend(Box3{s->center - Vec3(s->radius), s->center + Vec3(s->radius)});
        } else if (const auto* x = std::get_if<AnalyticBox>(&p.shape)) {
            b.extend(Box3{x->lo, x->hi});
        } else if (const auto* i = std::get_if<ImplicitPlan>(&p.shape)) {
            const Box3 nb = shapeBounds(i->node);  // ignores unbounded half-spaces
            if (!nb.empty()) b.extend(nb);
        } else if (const auto* f = std::get_if<FogPlan>(&p.shape)) {
            if (const auto* fi = std::get_if<ImplicitPlan>(&f->shape->shape)) {
                const Box3 nb = shapeBounds(fi->node);
                if (!nb.empty()) b.extend(nb);
            }
        }
    }
    const double pad = 0.1 * glm::length(b.hi - b.lo);
    return Box3{b.lo - Vec3(pad), b.hi + Vec3(pad)};
}

double estimatedBytes(const ObstaclePlan& plan) {
    if (const auto* i = std::get_if<ImplicitPlan>(&plan.shape)) {
        return estimateBuildBytes(i->node, i->voxelSize, i->halfWidth);
    }
    // A fog: its shape's level set, and the fog grid made from it (about as large).
    if (const auto* f = std::get_if<FogPlan>(&plan.shape)) return 2.0 * estimatedBytes(*f->shape);
    return 0.0;  // analytic shapes need nothing; .vdb files are as large as they are
}

void checkMemory(const std::vector<ObstaclePlan>& plans, const MemoryBudget& budget,
                 const std::string& file) {
    double total = 0.0;
    for (const ObstaclePlan& p : plans) total += estimatedBytes(p);
    if (total <= budget.limitBytes) return;
    // Blame the largest one: it is the one worth coarsening.
    const ObstaclePlan* worst = &plans.front();
    for (const ObstaclePlan& p : plans) {
        if (estimatedBytes(p) > estimatedBytes(*worst)) worst = &p;
    }
    throw InputError(
        file, worst->pointer,
        "would need ~" + bytesText(estimatedBytes(*worst)) + " for its level set (~" +
            bytesText(total) + " for all implicit obstacles, over the limit of " +
            bytesText(budget.limitBytes) + "); raise voxel_size or level_set.max_memory_gib");
}

// ---------------------------------------------------------------------------------------------
// Pass 3: building

using Clock = std::chrono::steady_clock;

double secondsSince(Clock::time_point start) {
    return std::chrono::duration<double>(Clock::now() - start).count();
}

/// Rethrows a builder's or reader's InputError under the scene file, at `pointer` unless the
/// error names a more precise one; the file the error came from (an OBJ, a .vdb) goes into the
/// message.
[[noreturn]] void rethrowUnder(const InputError& e, const std::string& sceneFile,
                               const std::string& pointer) {
    const bool ownPointer = !e.where().empty() && e.where()[0] == '/';
    std::string message = e.message();
    if (!ownPointer && !e.where().empty()) message = e.where() + ": " + message;
    if (!e.file().empty()) message = e.file() + ": " + message;
    throw InputError(sceneFile, ownPointer ? e.where() : pointer, message);
}

/// Reads the .vdb grids inside a CSG tree.
void readTreeGrids(ShapeNode& root, const std::string& pointer, const std::string& sceneFile) {
    forEachNode(root, pointer, [&](ShapeNode& node, const std::string& where) {
        auto* g = std::get_if<GridShape>(&node.kind);
        if (!g) return;
        std::vector<LevelSetPtr> grids;
        try {
            grids = readLevelSets(g->file, g->grid, where);
        } catch (const InputError& e) {
            rethrowUnder(e, sceneFile, where);
        }
        if (grids.size() > 1) {
            std::string names;
            for (const LevelSetPtr& ls : grids) {
                names += (names.empty() ? "" : ", ") + inQuotes(describe(*ls).name);
            }
            throw InputError(sceneFile, where + "/grid",
                             g->file + " holds " + std::to_string(grids.size()) +
                                 " level sets (" + names + "); name the one to use with \"grid\"");
        }
        g->levelSet = grids.front();
    });
}

// The build report of a level set or a volume grid (describe() gives both the same fields).
template <class Grid>
ObstacleBuild reportFor(const std::string& name, const std::string& type, const Grid& grid) {
    const auto info = describe(*grid);
    ObstacleBuild b;
    b.name = name;
    b.type = type;
    b.voxelSize = info.voxelSize;
    b.activeVoxels = info.activeVoxels;
    b.bytes = info.bytes;
    return b;
}

void buildObstacles(ObstaclePlan& plan, const std::string& file, std::vector<Obstacle>& out,
                    std::vector<Volume>& volumes, BuildReport& report, LevelSetCache* cache);

/// A fog: its shape's level sets (built without a cache), each made a fog volume.
void buildFog(ObstaclePlan& plan, const std::string& file, std::vector<Volume>& volumes,
              BuildReport& report) {
    const std::string name =
        plan.name.empty() ? "obstacle_" + std::to_string(plan.index) : plan.name;
    const Clock::time_point start = Clock::now();
    FogPlan& fog = std::get<FogPlan>(plan.shape);
    std::vector<Obstacle> shapes;
    std::vector<Volume> unused;
    BuildReport shapeReport;
    buildObstacles(*fog.shape, file, shapes, unused, shapeReport, nullptr);
    for (size_t j = 0; j < shapes.size(); ++j) {
        const std::string n = shapes.size() == 1 ? name : name + "/" + std::to_string(j);
        const VolumeGridPtr v =
            fogFromLevelSet(*std::get<LevelSetPtr>(shapes[j].shape), fog.density, fog.falloff, n);
        volumes.push_back({n, v, fog.extinction, plan.albedo});
        ObstacleBuild r = reportFor(n, "fog", v);
        r.estimatedBytes = j == 0 ? estimatedBytes(plan) : 0.0;
        r.seconds = j == 0 ? secondsSince(start) : 0.0;
        r.note = "fog volume";
        report.volumes.push_back(r);
    }
}

/// The volumes of a .vdb obstacle whose grid (or some of whose grids) are densities.
void buildVdbVolumes(const ObstaclePlan& plan, const std::string& file, const std::string& gridName,
                     std::vector<Volume>& volumes, BuildReport& report) {
    const Clock::time_point start = Clock::now();
    const auto& vdb = std::get<VdbPlan>(plan.shape);
    std::vector<VolumeGridPtr> grids;
    try {
        grids = readVolumes(vdb.path, gridName, plan.pointer);
    } catch (const InputError& e) {
        rethrowUnder(e, file, plan.pointer);
    }
    const double seconds = secondsSince(start);
    for (size_t j = 0; j < grids.size(); ++j) {
        const Similarity& t = vdb.transform;
        const VolumeGridPtr g = transformVolume(grids[j], t.rotation, t.scale, t.translate);
        const std::string gridName2 = describe(*g).name;
        std::string n = !plan.name.empty() ? plan.name : gridName2;
        if (grids.size() > 1 && !plan.name.empty()) n = plan.name + "/" + gridName2;
        if (n.empty()) n = "obstacle_" + std::to_string(plan.index);
        volumes.push_back({n, g, vdb.extinction, plan.albedo});
        ObstacleBuild r = reportFor(n, plan.type, g);
        r.seconds = j == 0 ? seconds : 0.0;
        r.note = "fog volume read from " + vdb.path;
        report.volumes.push_back(r);
    }
}

void buildObstacles(ObstaclePlan& plan, const std::string& file, std::vector<Obstacle>& out,
                    std::vector<Volume>& volumes, BuildReport& report, LevelSetCache* cache) {
    if (std::holds_alternative<FogPlan>(plan.shape)) {
        buildFog(plan, file, volumes, report);
        return;
    }
    bool levelSetsToo = true;  // a .vdb of volumes only has no level set to read
    if (const auto* vdb = std::get_if<VdbPlan>(&plan.shape)) {
        VdbGridKinds kinds;
        try {
            kinds = vdbGridKinds(vdb->path, plan.pointer);
        } catch (const InputError& e) {
            rethrowUnder(e, file, plan.pointer);
        }
        const auto holds = [](const std::vector<std::string>& v, const std::string& n) {
            return std::find(v.begin(), v.end(), n) != v.end();
        };
        if (!vdb->grid.empty() && !holds(kinds.levelSets, vdb->grid) &&
            (holds(kinds.volumes, vdb->grid) || holds(kinds.others, vdb->grid))) {
            // A named grid that is not a level set: a density (readVolumes says if it cannot be).
            buildVdbVolumes(plan, file, vdb->grid, volumes, report);
            return;
        }
        if (vdb->grid.empty() && !kinds.volumes.empty()) {
            buildVdbVolumes(plan, file, "", volumes, report);
            levelSetsToo = !kinds.levelSets.empty();
            if (!levelSetsToo) return;
            cache = nullptr;  // a cache entry would hold the level sets only
        }
    }
    const std::string name =
        plan.name.empty() ? "obstacle_" + std::to_string(plan.index) : plan.name;
    const Clock::time_point start = Clock::now();
    const bool cacheable = cache && !std::holds_alternative<AnalyticSphere>(plan.shape) &&
                           !std::holds_alternative<AnalyticBox>(plan.shape);
    if (cacheable) {
        const LevelSetCache::Found shared = cache->find(plan.cacheKey);
        if (!shared.obstacles.empty()) {
            // Built by an earlier load of the same obstacle (in this process, or stored in the
            // cache's directory by another): the same level sets (and their far-field
            // companions, built once on first use), with this scene's albedo.
            for (const Obstacle& o : shared.obstacles) {
                Obstacle copy = o;
                copy.albedo = plan.albedo;
                copy.voxelSize = plan.voxelSize;
                copy.halfWidth = plan.halfWidth;
                out.push_back(copy);
                ObstacleBuild r = reportFor(copy.name, plan.type, std::get<LevelSetPtr>(copy.shape));
                r.shared = true;
                r.note = shared.file.empty() ? "shared with an earlier load"
                                             : "read from the cache file " + shared.file;
                r.seconds = secondsSince(start);
                report.obstacles.push_back(r);
            }
            ++(shared.file.empty() ? report.levelSetsShared : report.levelSetsFromCache);
            return;
        }
    }
    const size_t first = out.size();
    struct Remember {  // on the way out of a build, hands what it added to the cache
        LevelSetCache* cache;
        const std::string& key;
        const std::vector<Obstacle>& out;
        size_t first;
        BuildReport& report;
        bool armed = false;
        ~Remember() {
            if (!armed) return;
            ++report.levelSetsBuilt;
            if (cache) cache->insert(key, std::vector<Obstacle>(out.begin() + first, out.end()));
        }
    } remember{cacheable ? cache : nullptr, plan.cacheKey, out, first, report};
    auto add = [&](std::string n, ObstacleShape shape) {
        Obstacle o{std::move(n), std::move(shape), plan.albedo};
        o.voxelSize = plan.voxelSize;
        o.halfWidth = plan.halfWidth;
        out.push_back(std::move(o));
    };
    if (const auto* s = std::get_if<AnalyticSphere>(&plan.shape)) {
        add(name, *s);
    } else if (const auto* b = std::get_if<AnalyticBox>(&plan.shape)) {
        add(name, *b);
    } else if (auto* implicit = std::get_if<ImplicitPlan>(&plan.shape)) {
        readTreeGrids(implicit->node, plan.pointer, file);
        ShapeBuildNotes notes;
        LevelSetPtr ls;
        try {
            ls = buildLevelSet(implicit->node, implicit->voxelSize, implicit->halfWidth, name,
                               &notes);
        } catch (const InputError& e) {
            rethrowUnder(e, file, plan.pointer);
        }
        add(name, ls);
        remember.armed = true;
        ObstacleBuild r = reportFor(name, plan.type, ls);
        r.estimatedBytes = estimatedBytes(plan);
        r.seconds = secondsSince(start);
        if (notes.holesCapped) r.note = "capped " + std::to_string(notes.holesCapped) + " holes";
        report.obstacles.push_back(r);
        return;
    } else {
        const auto& vdb = std::get<VdbPlan>(plan.shape);
        std::vector<LevelSetPtr> grids;
        try {
            grids = readLevelSets(vdb.path, vdb.grid, plan.pointer);
        } catch (const InputError& e) {
            rethrowUnder(e, file, plan.pointer);
        }
        const double seconds = secondsSince(start);
        remember.armed = true;
        for (size_t j = 0; j < grids.size(); ++j) {
            const LevelSetPtr g = transformLevelSet(grids[j], vdb.transform);
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
            ObstacleBuild r = reportFor(n, plan.type, g);
            // The file is read once for all its grids.
            r.seconds = j == 0 ? seconds : 0.0;
            r.note = "read from " + vdb.path;
            report.obstacles.push_back(r);
        }
        return;
    }
    ObstacleBuild r;
    r.name = name;
    r.type = plan.type;
    r.analytic = true;
    report.obstacles.push_back(r);
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
            const size_t inputsBefore = ctx.inputs.size();
            plans.push_back(parseObstacle(obstacles.element(i), i, scene.levelSet));
            ObstaclePlan& p = plans.back();
            if (!ctx.cache) continue;  // the key (and hashing the files it reads) serves only a cache
            std::ostringstream key;
            key << std::setprecision(17) << ctx.baseDir << '|' << obstacles.element(i).json().dump()
                << '|' << p.voxelSize << '|' << p.halfWidth << '|' << i;
            for (size_t k = inputsBefore; k < ctx.inputs.size(); ++k) {
                key << '|' << ctx.inputs[k].first << ':' << contentDigest(ctx.inputs[k].first);
            }
            p.cacheKey = key.str();
        }
    }

    // Half-spaces without bounds are cut to the scene's; then their index range can be checked.
    const Box3 bounds = sceneBounds(scene, plans);
    for (ObstaclePlan& p : plans) {
        auto* implicit = std::get_if<ImplicitPlan>(&p.shape);
        if (auto* fog = std::get_if<FogPlan>(&p.shape)) implicit = std::get_if<ImplicitPlan>(&fog->shape->shape);
        if (!implicit) continue;
        bool unbounded = false;
        forEachNode(implicit->node, p.pointer, [&](ShapeNode& node, const std::string&) {
            auto* half = std::get_if<HalfSpaceShape>(&node.kind);
            if (half && half->boundsWS.empty()) {
                half->boundsWS = bounds;
                unbounded = true;
            }
        });
        if (unbounded && ctx.cache) {
            std::ostringstream key;
            key << std::setprecision(17) << "|bounds " << bounds.lo.x << ' ' << bounds.lo.y << ' '
                << bounds.lo.z << ' ' << bounds.hi.x << ' ' << bounds.hi.y << ' ' << bounds.hi.z;
            p.cacheKey += key.str();
        }
        if (unbounded) {
            checkIndexRange(Node(root, p.pointer, ctx), shapeBounds(implicit->node),
                            implicit->voxelSize);
        }
    }

    checkMemory(plans, budget, ctx.file);
    scene.build.memoryLimitBytes = budget.limitBytes;
    for (const ObstaclePlan& p : plans) scene.build.estimatedBytes += estimatedBytes(p);
    const Clock::time_point start = Clock::now();
    for (ObstaclePlan& p : plans) {
        try {
            buildObstacles(p, ctx.file, scene.obstacles, scene.volumes, scene.build, ctx.cache);
        } catch (const std::bad_alloc&) {
            // A runtime failure (exit 1), not bad input, but the user needs to know which one.
            throw std::runtime_error(ctx.file + ": " + p.pointer +
                                     ": out of memory building its level set (raise voxel_size, "
                                     "or lower level_set.max_memory_gib so that the estimate "
                                     "refuses it up front)");
        }
    }
    scene.build.seconds = secondsSince(start);
    scene.inputFiles = ctx.inputs;
    return scene;
}

}  // namespace

// ---------------------------------------------------------------------------------------------

Scene parseScene(const std::string& jsonText, const std::string& file, const std::string& baseDir,
                 LevelSetCache* cache) {
    const Context ctx{file, baseDir, {}, cache};
    const Json root = parseStrictJson(jsonText, file);
    return parseDocument(root, ctx);
}

Scene loadScene(const std::string& path, LevelSetCache* cache) {
    const std::string text = readTextFile(path, "the scene file");
    std::string baseDir = std::filesystem::path(path).parent_path().string();
    if (baseDir.empty()) baseDir = ".";
    return parseScene(text, path, baseDir, cache);
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

std::optional<size_t> Scene::obstacleContaining(const Vec3& p) const {
    for (size_t i = 0; i < obstacles.size(); ++i) {
        const ObstacleShape& shape = obstacles[i].shape;
        bool inside = false;
        if (const auto* s = std::get_if<AnalyticSphere>(&shape)) {
            inside = glm::length(p - s->center) < s->radius;
        } else if (const auto* b = std::get_if<AnalyticBox>(&shape)) {
            inside = p.x > b->lo.x && p.y > b->lo.y && p.z > b->lo.z && p.x < b->hi.x &&
                     p.y < b->hi.y && p.z < b->hi.z;
        } else if (const auto* ls = std::get_if<LevelSetPtr>(&shape)) {
            inside = *ls && sampleLevelSet(**ls, p) < 0.0;
        }
        if (inside) return i;
    }
    return std::nullopt;
}

Occluder Scene::makeOccluder() const {
    std::vector<ObstacleShape> shapes;
    shapes.reserve(obstacles.size());
    for (const Obstacle& o : obstacles) shapes.push_back(o.shape);
    Occluder occ(std::move(shapes));
    for (const Volume& v : volumes) occ.addMedium({v.grid, v.extinction, v.albedo});
    return occ;
}

// ---------------------------------------------------------------------------------------------
// BuildReport

uint64_t BuildReport::activeVoxels() const {
    uint64_t n = 0;
    for (const ObstacleBuild& o : obstacles) n += o.activeVoxels;
    return n;
}

uint64_t BuildReport::bytes() const {
    uint64_t n = 0;
    for (const ObstacleBuild& o : obstacles) n += o.bytes;
    return n;
}

namespace {

/// 1234567 -> "1,234,567": voxel counts are read at a glance.
std::string grouped(uint64_t n) {
    std::string digits = std::to_string(n), out;
    for (size_t i = 0; i < digits.size(); ++i) {
        if (i > 0 && (digits.size() - i) % 3 == 0) out += ',';
        out += digits[i];
    }
    return out;
}

std::string mebibytes(double bytes) {
    std::ostringstream s;
    s.setf(std::ios::fixed);
    s.precision(bytes < 10.0 * 1024 * 1024 ? 2 : 0);
    s << bytes / (1024.0 * 1024.0) << " MiB";
    return s.str();
}

std::string secondsText(double seconds) {
    std::ostringstream s;
    s.setf(std::ios::fixed);
    s.precision(seconds < 10.0 ? 3 : 1);
    s << seconds << " s";
    return s.str();
}

}  // namespace

std::string BuildReport::toText() const {
    std::ostringstream out;
    for (const ObstacleBuild& o : obstacles) {
        out << "obstacle " << inQuotes(o.name) << " (" << o.type << "): ";
        if (o.analytic) {
            out << "analytic, no level set\n";
            continue;
        }
        // Grids store their voxel size in single precision: print what the user wrote.
        char voxel[32];
        std::snprintf(voxel, sizeof voxel, "%.6g", o.voxelSize);
        out << grouped(o.activeVoxels) << " voxels, " << mebibytes(double(o.bytes)) << ", "
            << secondsText(o.seconds) << " (voxel " << voxel;
        if (o.estimatedBytes > 0.0) out << ", estimated " << mebibytes(o.estimatedBytes);
        if (!o.note.empty()) out << ", " << o.note;
        out << ")\n";
    }
    out << "level sets: " << grouped(activeVoxels()) << " voxels, " << mebibytes(double(bytes()))
        << " in " << secondsText(seconds) << " (estimate " << mebibytes(estimatedBytes)
        << ", limit " << bytesText(memoryLimitBytes);
    if (levelSetsShared > 0) out << "; " << levelSetsShared << " obstacle(s) shared with an earlier load";
    out << ")\n";
    return out.str();
}

std::string BuildReport::toJson() const {
    Json j;
    j["seconds"] = seconds;
    j["active_voxels"] = activeVoxels();
    j["bytes"] = bytes();
    j["estimated_bytes"] = estimatedBytes;
    j["memory_limit_bytes"] = memoryLimitBytes;
    for (const char* list : {"obstacles", "volumes"}) {
        j[list] = Json::array();
        for (const ObstacleBuild& o : list[0] == 'o' ? obstacles : volumes) {
            j[list].push_back({{"name", o.name},
                               {"type", o.type},
                               {"analytic", o.analytic},
                               {"voxel_size", o.voxelSize},
                               {"active_voxels", o.activeVoxels},
                               {"bytes", o.bytes},
                               {"estimated_bytes", o.estimatedBytes},
                               {"seconds", o.seconds},
                               {"shared", o.shared},
                               {"note", o.note}});
        }
    }
    j["level_sets_built"] = levelSetsBuilt;
    j["level_sets_shared"] = levelSetsShared;
    j["level_sets_from_cache"] = levelSetsFromCache;
    return j.dump();
}

LevelSetCache::LevelSetCache(std::string directory, Warn warn)
    : mDirectory(std::move(directory)), mWarn(std::move(warn)) {
    if (mDirectory.empty()) return;
    std::error_code ec;
    std::filesystem::create_directories(mDirectory, ec);
    if (!std::filesystem::is_directory(mDirectory, ec)) {
        throw InputError(mDirectory, "", "cannot use as a level-set cache directory: " +
                                             (ec ? ec.message() : std::string("not a directory")));
    }
}

std::string LevelSetCache::fileFor(const std::string& key) const {
    return (std::filesystem::path(mDirectory) / ("levelset-" + hex16(fnv1a64(key)) + ".vdb")).string();
}

LevelSetCache::Found LevelSetCache::find(const std::string& key) {
    {
        std::lock_guard<std::mutex> lock(mMutex);
        const auto it = mEntries.find(key);
        if (it != mEntries.end()) return {it->second.obstacles, ""};
    }
    if (mDirectory.empty()) return {};
    const std::string file = fileFor(key);
    std::error_code ec;
    if (!std::filesystem::exists(file, ec)) return {};
    CacheFileEntry read;
    try {
        read = readCacheFile(file, key);
    } catch (const std::exception& e) {
        if (mWarn) mWarn("ignoring level-set cache file '" + file + "': " + e.what() + "; rebuilding it");
        return {};
    }
    Entry entry;
    for (size_t i = 0; i < read.levelSets.size(); ++i) {
        Obstacle o;
        o.name = read.labels[i];
        o.shape = read.levelSets[i];
        entry.obstacles.push_back(std::move(o));
    }
    entry.farFieldsWritten = read.farFields;
    std::lock_guard<std::mutex> lock(mMutex);
    const auto it = mEntries.emplace(key, std::move(entry)).first;  // a concurrent load: keep the first
    return {it->second.obstacles, file};
}

void LevelSetCache::write(const std::string& key, Entry& entry) {
    CacheFileEntry out;
    for (const Obstacle& o : entry.obstacles) {
        const auto* ls = std::get_if<LevelSetPtr>(&o.shape);
        if (!ls || !*ls) return;  // only level sets are cached
        out.levelSets.push_back(*ls);
        out.labels.push_back(o.name);
        out.farFields += hasFarField(**ls) ? 1 : 0;
    }
    try {
        writeCacheFile(fileFor(key), key, out);
        entry.farFieldsWritten = out.farFields;
    } catch (const std::exception& e) {
        entry.farFieldsWritten = int(out.levelSets.size());  // do not try again
        if (mWarn) mWarn(std::string("cannot store a level set in the cache: ") + e.what());
    }
}

void LevelSetCache::insert(const std::string& key, std::vector<Obstacle> obstacles) {
    std::lock_guard<std::mutex> lock(mMutex);
    // A concurrent build of the same key: keep the first.
    const auto [it, added] = mEntries.emplace(key, Entry{std::move(obstacles), -1});
    if (added && !mDirectory.empty()) write(key, it->second);
}

void LevelSetCache::persist() {
    if (mDirectory.empty()) return;
    std::lock_guard<std::mutex> lock(mMutex);
    for (auto& [key, entry] : mEntries) {
        int built = 0;
        for (const Obstacle& o : entry.obstacles) {
            const auto* ls = std::get_if<LevelSetPtr>(&o.shape);
            built += ls && *ls && hasFarField(**ls) ? 1 : 0;
        }
        if (built > entry.farFieldsWritten) write(key, entry);
    }
}

size_t LevelSetCache::size() const {
    std::lock_guard<std::mutex> lock(mMutex);
    return mEntries.size();
}

std::vector<LevelSetPtr> Scene::obstacleLevelSets() const {
    std::vector<LevelSetPtr> out;
    std::set<std::string> used;
    for (size_t i = 0; i < obstacles.size(); ++i) {
        const Obstacle& o = obstacles[i];
        std::string name = o.name;
        for (int k = 0; !used.insert(name).second; ++k) {
            name = o.name + "_" + std::to_string(i) + (k ? "_" + std::to_string(k) : "");
        }
        if (const auto* ls = std::get_if<LevelSetPtr>(&o.shape)) {
            out.push_back(renamedLevelSet(*ls, name));
            continue;
        }
        ShapeNode node;
        if (const auto* s = std::get_if<AnalyticSphere>(&o.shape)) {
            node.kind = SphereShape{s->center, s->radius};
        } else {
            const auto& b = std::get<AnalyticBox>(o.shape);
            node.kind = BoxShape{0.5 * (b.lo + b.hi), b.hi - b.lo, 0.0};
        }
        const double voxel = o.voxelSize > 0.0 ? o.voxelSize : levelSet.voxelSize;
        const double halfWidth = o.halfWidth > 0.0 ? o.halfWidth : levelSet.halfWidth;
        // Analytic shapes were never voxelized while loading: estimate before building.
        const double need = estimateBuildBytes(node, voxel, halfWidth);
        const double limit = defaultMemoryLimitBytes();
        if (need > limit) {
            throw InputError(file, "",
                             "obstacle '" + name + "' would need ~" + bytesText(need) +
                                 " as a level set at voxel_size " + numberText(voxel) +
                                 ", over the limit of " + bytesText(limit) +
                                 "; give it a larger voxel_size to bake it");
        }
        out.push_back(buildLevelSet(node, voxel, halfWidth, name));
    }
    return out;
}

}  // namespace penumbra
