// The scene loader: JSON text -> validated Scene. The format is documented in
// docs/scene-format.md; keep the two in step.
//
// Loading runs in three passes so that a typo in the last obstacle is reported before minutes
// are spent voxelizing the first one: (1) here, parse and validate the whole document into the
// camera, lights and receivers and into obstacle plans (scene_plan.h; meshes are read here:
// their size enters the estimate), then (2) cut unbounded half-spaces to the scene's bounds,
// estimate the memory of every level set to be built and refuse the scene when over the limit,
// and (3) build the level sets and read the .vdb files (both in obstacle_build.cpp).
#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <variant>

#include "penumbra/error.h"
#include "penumbra/hash.h"
#include "penumbra/json_reader.h"
#include "penumbra/mesh.h"
#include "penumbra/scene.h"
#include "penumbra/shape.h"
#include "scene_plan.h"
#include "text_format.h"

namespace penumbra {

namespace {

using Json = nlohmann::json;

constexpr int kMaxImageSide = 32768;
// Smaller features come out empty or badly voxelized (OpenVDB's own sphere builder produces
// nothing under 1.5 voxels in radius).
constexpr double kMinFeatureVoxels = 1.5;
// sin(angle) between edge_u and edge_v below which a light counts as degenerate.
constexpr double kMinEdgeSine = 1e-9;
/// The largest magnitude of any number in a scene file (docs/scene-format.md).
constexpr double kMaxMagnitude = 1e12;

// ---------------------------------------------------------------------------------------------
// Reading the document: a value together with its JSON pointer, so every complaint names it.

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

/// A number >= 0 (0 allowed, unlike numberAbove).
double nonNegative(const Object& obj, const std::string& key, double fallback) {
    if (!obj.has(key)) return fallback;
    const Node n = obj.at(key);
    const double x = n.number();
    if (x < 0.0) n.fail("must be >= 0, got " + n.json().dump());
    return x;
}

Vec3 positiveVec3(const Node& n) {
    const Vec3 v = n.vec3();
    for (int k = 0; k < 3; ++k) {
        if (!(v[k] > 0.0)) n.element(k).fail("must be > 0, got " + numberText(v[k]));
    }
    return v;
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

// ---------------------------------------------------------------------------------------------
// The camera, lights and receivers

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
    const std::string type =
        Object(node, {"name", "type", "corner", "edge_u", "edge_v", "vertices", "center", "normal",
                      "radius", "radiance"})
            .kind("light", {"rect", "polygon", "disc"}, "rect");
    std::vector<std::string> keys = {"name", "type", "radiance"};
    if (type == "rect") keys.insert(keys.end(), {"corner", "edge_u", "edge_v"});
    if (type == "polygon") keys.push_back("vertices");
    if (type == "disc") keys.insert(keys.end(), {"center", "normal", "radius"});
    const Object obj(node, keys);
    RectLight light;
    if (type == "polygon") {
        const Node list = obj.at("vertices");
        list.array();
        std::vector<Vec3> vertices;
        for (size_t i = 0; i < list.json().size(); ++i) vertices.push_back(list.element(i).vec3());
        try {
            light = polygonLight(vertices);
        } catch (const std::invalid_argument& e) {
            // "vertex N ...": the error belongs to that vertex.
            const std::string what = e.what();
            size_t vertex = 0;
            if (std::sscanf(what.c_str(), "vertex %zu", &vertex) == 1 && vertex < vertices.size())
                list.element(vertex).fail(what);
            list.fail(what);
        }
    } else if (type == "disc") {
        const Vec3 normal = obj.at("normal").vec3();
        if (!(glm::length(normal) > 0.0)) obj.at("normal").fail("the normal must not be zero");
        light = discLight(obj.at("center").vec3(), normal, obj.at("radius").numberAbove(0.0));
    } else {
        light.corner = obj.at("corner").vec3();
        light.edgeU = obj.at("edge_u").vec3();
        light.edgeV = obj.at("edge_v").vec3();
        // The emitting normal is edge_u x edge_v: parallel or zero edges leave it undefined.
        const double area = glm::length(glm::cross(light.edgeU, light.edgeV));
        const double lenProduct = glm::length(light.edgeU) * glm::length(light.edgeV);
        if (!(area > kMinEdgeSine * lenProduct) || !(area > 0.0) || !std::isfinite(area)) {
            obj.node().fail("degenerate rectangle: edge_u " + vecText(light.edgeU) + " and edge_v " +
                            vecText(light.edgeV) + " are parallel or zero (area " + numberText(area) +
                            ")");
        }
    }
    light.name =
        obj.has("name") ? obj.at("name").nonEmptyString() : "light_" + std::to_string(index);
    light.radiance = obj.rgb("radiance", Rgb(1.0));
    return light;
}

/// "checker": true or false, or {"albedo2", "scale"} (a checker with those).
void parseChecker(const Node& node, PlaneReceiver& plane) {
    if (node.json().is_boolean()) {
        plane.checker = node.boolean();
        return;
    }
    const Object checker(node, {"albedo2", "scale"});
    plane.checker = true;
    plane.albedo2 = checker.rgb("albedo2", plane.albedo2);
    plane.checkerScale = checker.numberAbove("scale", 0.0, plane.checkerScale);
}

PlaneReceiver parseReceiver(const Node& node) {
    const Object obj(node, {"type", "point", "normal", "albedo", "checker"});
    obj.kind("receiver", {"plane"});
    PlaneReceiver plane;
    plane.point = obj.at("point").vec3();
    plane.normal = obj.at("normal").direction();
    plane.albedo = obj.rgb("albedo", plane.albedo);
    if (obj.has("checker")) parseChecker(obj.at("checker"), plane);
    return plane;
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
// The parts of shapes: transforms, bounds, files

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

/// The OBJ file a mesh names, read; its errors are reported under the scene file.
TriangleMesh readObjAt(const Node& fileNode, const std::string& path) {
    try {
        return readObj(path);
    } catch (const InputError& e) {
        // The scene file and pointer first (what the user edits), the OBJ and its line after.
        throw InputError(fileNode.context().file, fileNode.pointer(),
                         e.file() + (e.where().empty() ? "" : ": " + e.where()) + ": " +
                             e.message());
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

// ---------------------------------------------------------------------------------------------
// Shapes: one reader per "type", chosen from one table (kShapeTypes)

/// What a shape's reader is given: its object, the voxel size of the obstacle being built and
/// the scale its ancestors and its own transform apply (features are checked in voxels).
struct ShapeFields {
    const Object& obj;
    double voxel;
    double scale;
    bool analyticHint;  ///< a top-level sphere or box: "analytic": true would need no voxels

    /// Refuses a feature too small for the voxels: the level set would be empty or wrong.
    void feature(const Node& n, double localSize) const {
        if (localSize * scale < kMinFeatureVoxels * voxel) {
            n.fail("is below " + numberText(kMinFeatureVoxels) + " voxels (voxel_size " +
                   numberText(voxel) +
                   (scale != 1.0 ? ", after scaling by " + numberText(scale) : "") +
                   "): the level set would be empty or wrong; lower voxel_size" +
                   (analyticHint ? " or set \"analytic\": true" : ""));
        }
    }
    /// A size > 0 that the voxels can resolve.
    double positive(const std::string& key) const {
        const Node n = obj.at(key);
        const double x = n.numberAbove(0.0);
        feature(n, x);
        return x;
    }
    Vec3 axis() const { return obj.has("axis") ? obj.at("axis").direction() : Vec3(0.0, 0.0, 1.0); }
};

// Readers that build their shape in braces rely on the elements being evaluated in order (C++17
// [dcl.init.list]/4): the fields are checked, and the first bad one reported, as written.

ShapeKind readSphere(const ShapeFields& f) {
    return SphereShape{f.obj.at("center").vec3(), f.positive("radius")};
}

ShapeKind readBox(const ShapeFields& f) {
    BoxShape box;
    box.center = f.obj.at("center").vec3();
    const Node sizeNode = f.obj.at("size");
    box.size = positiveVec3(sizeNode);
    const double smallest = std::min({box.size.x, box.size.y, box.size.z});
    f.feature(sizeNode, smallest);
    if (f.obj.has("round")) {
        const Node r = f.obj.at("round");
        box.round = r.number();
        if (box.round < 0.0) r.fail("must be >= 0, got " + numberText(box.round));
        if (box.round > 0.5 * smallest) {
            r.fail("must be <= half the smallest size (" + numberText(0.5 * smallest) +
                   "), got " + numberText(box.round));
        }
    }
    return box;
}

ShapeKind readTorus(const ShapeFields& f) {
    return TorusShape{f.obj.at("center").vec3(), f.obj.at("major_radius").numberAbove(0.0),
                      f.positive("minor_radius"), f.axis()};
}

ShapeKind readCapsule(const ShapeFields& f) {
    return CapsuleShape{f.obj.at("a").vec3(), f.obj.at("b").vec3(), f.positive("radius")};
}

ShapeKind readCylinder(const ShapeFields& f) {
    return CylinderShape{f.obj.at("center").vec3(), f.axis(), f.positive("radius"),
                         f.positive("height")};
}

ShapeKind readHalfSpace(const ShapeFields& f) {
    // Without "bounds", cut to the scene's in pass 2 (obstacle_build.cpp).
    return HalfSpaceShape{f.obj.at("point").vec3(), f.obj.at("normal").direction(),
                          f.obj.has("bounds") ? parseBounds(f.obj.at("bounds")) : Box3{}};
}

ShapeNode parseChild(const Node& node, double voxel, double parentScale);

ShapeKind readCsg(const ShapeFields& f) {
    static const std::vector<std::string> ops = [] {
        std::vector<std::string> names;  // in CsgOp's order
        for (CsgOp op :
             {CsgOp::Union, CsgOp::Intersection, CsgOp::Difference, CsgOp::SmoothUnion}) {
            names.push_back(csgOpName(op));
        }
        return names;
    }();
    CsgShape csg;
    const Node opNode = f.obj.at("op");
    const std::string op = opNode.string();
    const auto it = std::find(ops.begin(), ops.end(), op);
    if (it == ops.end()) opNode.fail("unknown csg op " + inQuotes(op) + suggestion(op, ops));
    csg.op = static_cast<CsgOp>(it - ops.begin());
    if (csg.op == CsgOp::SmoothUnion) {
        csg.blend = f.obj.at("blend").numberAbove(0.0);
    } else if (f.obj.has("blend")) {
        f.obj.at("blend").fail("applies only to op \"smooth_union\" (this csg is a " + op + ")");
    }
    const Node children = f.obj.at("children");
    children.array();
    if (children.json().size() < 2) {
        children.fail("a csg needs at least 2 children, got " +
                      std::to_string(children.json().size()));
    }
    for (size_t i = 0; i < children.json().size(); ++i) {
        csg.children.push_back(parseChild(children.element(i), f.voxel, f.scale));
    }
    return ShapeKind(std::move(csg));
}

ShapeKind readMesh(const ShapeFields& f) {
    MeshShape mesh;
    const Node fileNode = f.obj.at("file");
    mesh.file = existingFile(fileNode);
    mesh.mesh = std::make_shared<const TriangleMesh>(readObjAt(fileNode, mesh.file));
    if (f.obj.has("thickness")) mesh.thickness = f.positive("thickness");
    return ShapeKind(std::move(mesh));
}

/// A .vdb grid inside a CSG, read in pass 3.
ShapeKind readGrid(const ShapeFields& f) {
    GridShape grid;
    grid.file = existingFile(f.obj.at("file"));
    if (f.obj.has("grid")) grid.grid = f.obj.at("grid").nonEmptyString();
    return ShapeKind(std::move(grid));
}

/// A sphere with "analytic": true: exact, never voxelized.
ShapePlan readAnalyticSphere(const Object& obj, const ParsedTransform& t, const Vec3& center) {
    const double radius = obj.at("radius").numberAbove(0.0) * t.similarity.scale;
    return AnalyticSphere{center, radius};
}

/// A box with "analytic": true: exact and axis-aligned, never voxelized.
ShapePlan readAnalyticBox(const Object& obj, const ParsedTransform& t, const Vec3& center) {
    if (t.rotates) {
        obj.at("transform").fail(
            "an analytic box stays axis-aligned: rotate_deg must be [0, 0, 0] (or drop "
            "\"analytic\")");
    }
    if (obj.has("round")) obj.at("round").fail("an analytic box has sharp edges");
    const Vec3 size = positiveVec3(obj.at("size")) * t.similarity.scale;
    return AnalyticBox{center - 0.5 * size, center + 0.5 * size};
}

/// A "vdb" obstacle: its file's level sets (and density grids), read in pass 3.
ShapePlan readVdbPlan(const Object& obj) {
    VdbPlan vdb;
    vdb.path = existingFile(obj.at("file"));
    if (obj.has("grid")) vdb.grid = obj.at("grid").nonEmptyString();
    if (obj.has("transform")) vdb.transform = parseTransform(obj.at("transform")).similarity;
    vdb.extinction = nonNegative(obj, "extinction", 1.0);
    return vdb;
}

/// What the scene file's "type" of an obstacle or CSG child stands for.
struct ShapeType {
    std::string name;
    /// The keys of its own geometry (besides "type" and "transform", and an obstacle's "name"
    /// and "albedo"), then those it takes only as an obstacle; unknown keys are refused.
    std::vector<std::string> keys, obstacleKeys;
    /// Its geometry, as a CSG child or as (the tree of) a voxelized obstacle.
    ShapeKind (*read)(const ShapeFields&);
    /// As an obstacle with "analytic": true (its transform and centre applied), or null when it
    /// cannot be one.
    ShapePlan (*readAnalytic)(const Object&, const ParsedTransform&, const Vec3& center) = nullptr;
    /// As an obstacle that is read rather than voxelized, or null when it is voxelized.
    ShapePlan (*readObstacle)(const Object&) = nullptr;

    /// The keys its object may hold: `common`, its own, and as an obstacle those it takes only
    /// as one.
    std::vector<std::string> allowed(std::vector<std::string> common, bool asObstacle) const {
        common.insert(common.end(), keys.begin(), keys.end());
        if (asObstacle) common.insert(common.end(), obstacleKeys.begin(), obstacleKeys.end());
        return common;
    }
};

const std::vector<std::string> kVoxelKeys = {"voxel_size", "half_width"};
const std::vector<std::string> kVoxelOrAnalyticKeys = {"voxel_size", "half_width", "analytic"};

const std::vector<ShapeType> kShapeTypes = {
    {"sphere", {"center", "radius"}, kVoxelOrAnalyticKeys, readSphere, readAnalyticSphere},
    {"box", {"center", "size", "round"}, kVoxelOrAnalyticKeys, readBox, readAnalyticBox},
    {"torus", {"center", "major_radius", "minor_radius", "axis"}, kVoxelKeys, readTorus},
    {"capsule", {"a", "b", "radius"}, kVoxelKeys, readCapsule},
    {"cylinder", {"center", "axis", "radius", "height"}, kVoxelKeys, readCylinder},
    {"half_space", {"point", "normal", "bounds"}, kVoxelKeys, readHalfSpace},
    {"csg", {"op", "blend", "children"}, kVoxelKeys, readCsg},
    {"mesh", {"file", "thickness"}, kVoxelKeys, readMesh},
    {"vdb", {"file", "grid"}, {"extinction"}, readGrid, nullptr, readVdbPlan},
};

/// The type names of kShapeTypes, in its order: the "unknown type" suggestions.
const std::vector<std::string>& shapeTypeNames() {
    static const std::vector<std::string> names = [] {
        std::vector<std::string> out;
        for (const ShapeType& t : kShapeTypes) out.push_back(t.name);
        return out;
    }();
    return names;
}

/// The "type" of an obstacle or CSG child, read before its keys are checked (the allowed keys
/// depend on it).
const ShapeType& readType(const Node& node, const std::string& what) {
    if (!node.json().is_object()) node.fail("expected an object, got " + typeName(node.json()));
    auto it = node.json().find("type");
    if (it == node.json().end()) {
        throw InputError(node.context().file, node.pointer() + "/type",
                         "missing required field 'type' (one of " + joined(shapeTypeNames()) + ")");
    }
    const Node n(*it, node.pointer() + "/type", node.context());
    const std::string kind = n.string();
    for (const ShapeType& t : kShapeTypes) {
        if (t.name == kind) return t;
    }
    n.fail("unknown " + what + " type " + inQuotes(kind) + suggestion(kind, shapeTypeNames()));
}

/// The geometry of a voxelized obstacle or of a CSG child, in its local frame. `voxel` is the
/// voxel size of the obstacle being built, `parentScale` the scale its ancestors apply.
ShapeNode parseShape(const Object& obj, const ShapeType& type, double voxel, double parentScale,
                     bool topLevel) {
    ShapeNode out;
    if (obj.has("transform")) out.transform = parseTransform(obj.at("transform")).similarity;
    const ShapeFields fields{obj, voxel, parentScale * out.transform.scale,
                             topLevel && type.readAnalytic != nullptr};
    out.kind = type.read(fields);
    return out;
}

ShapeNode parseChild(const Node& node, double voxel, double parentScale) {
    const ShapeType& type = readType(node, "shape");
    const Object obj(node, type.allowed({"type", "transform"}, false));
    return parseShape(obj, type, voxel, parentScale, false);
}

// ---------------------------------------------------------------------------------------------
// Obstacles -> plans

ObstaclePlan parseFog(const Node& node, size_t index, const LevelSetSettings& global);

ObstaclePlan parseObstacle(const Node& node, size_t index, const LevelSetSettings& global) {
    if (node.json().is_object() && node.json().contains("type") && node.json()["type"] == "fog") {
        return parseFog(node, index, global);
    }
    const ShapeType& type = readType(node, "obstacle");
    const Object obj(node, type.allowed({"type", "name", "albedo", "transform"}, true));

    ObstaclePlan plan;
    plan.pointer = node.pointer();
    plan.index = index;
    plan.type = type.name;
    if (obj.has("name")) plan.name = obj.at("name").nonEmptyString();
    plan.albedo = obj.rgb("albedo", plan.albedo);
    if (type.readObstacle) {
        plan.shape = type.readObstacle(obj);
        return plan;
    }

    plan.voxelSize = obj.numberAbove("voxel_size", 0.0, global.voxelSize);
    // OpenVDB's rasterizers refuse a band of one voxel or less.
    plan.halfWidth = obj.numberAbove("half_width", 1.0, global.halfWidth);

    if (type.readAnalytic && obj.boolean("analytic", false)) {
        ParsedTransform t;
        if (obj.has("transform")) t = parseTransform(obj.at("transform"));
        const Vec3 center = t.similarity.apply(obj.at("center").vec3());
        plan.shape = type.readAnalytic(obj, t, center);
        return plan;
    }
    ImplicitPlan implicit{parseShape(obj, type, plan.voxelSize, 1.0, true), plan.voxelSize,
                          plan.halfWidth};
    checkIndexRange(node.context().file, obj.pointer(), shapeBounds(implicit.node),
                    plan.voxelSize);
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

/// The "obstacles" array. With a cache, each plan gets the start of its key: the obstacle's JSON
/// as written, the voxel size and band it resolved to, and the content of the files it read.
std::vector<ObstaclePlan> parseObstacles(const Node& obstacles, const LevelSetSettings& global) {
    const Context& ctx = obstacles.context();
    std::vector<ObstaclePlan> plans;
    obstacles.array();
    for (size_t i = 0; i < obstacles.json().size(); ++i) {
        const size_t inputsBefore = ctx.inputs.size();
        plans.push_back(parseObstacle(obstacles.element(i), i, global));
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
    return plans;
}

// ---------------------------------------------------------------------------------------------
// The document

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
    if (top.has("obstacles")) plans = parseObstacles(top.at("obstacles"), scene.levelSet);

    buildPlans(plans, budget, ctx.file, ctx.cache, scene);
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

}  // namespace penumbra
