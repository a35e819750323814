// Passes 2 and 3 of loading a scene (scene_plan.h): plans -> the obstacles and volumes a Scene
// holds. Pass 2 cuts unbounded half-spaces to the scene's bounds and refuses the scene when the
// estimated memory of its level sets is over the limit; pass 3 builds the level sets (shape.h),
// reads the .vdb files (level sets and density grids) and makes fog volumes, sharing level sets
// through a LevelSetCache when the load has one.
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <iomanip>
#include <new>
#include <sstream>
#include <stdexcept>
#include <variant>

#include "overloaded.h"
#include "penumbra/error.h"
#include "penumbra/level_set.h"
#include "penumbra/volume.h"
#include "scene_plan.h"
#include "text_format.h"

namespace penumbra {

namespace {

constexpr double kDefaultMemoryLimitGiB = 16.0;
// OpenVDB index coordinates are int32 and its mesher works in float voxel units; keep geometry
// well inside both ranges.
constexpr double kMaxIndexCoordinate = double(1 << 24);

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

/// The obstacle's name in reports and errors: its "name", else obstacle_K.
std::string nameOf(const ObstaclePlan& plan) {
    return plan.name.empty() ? "obstacle_" + std::to_string(plan.index) : plan.name;
}

// ---------------------------------------------------------------------------------------------
// Pass 2: half-space bounds, then memory

/// The shape tree a plan voxelizes: an implicit obstacle's, or the shape of a fog made of one.
ImplicitPlan* voxelizedTree(ObstaclePlan& plan) {
    return std::visit(
        Overloaded{[](ImplicitPlan& implicit) -> ImplicitPlan* { return &implicit; },
                   [](FogPlan& fog) { return voxelizedTree(*fog.shape); },
                   [](auto&) -> ImplicitPlan* { return nullptr; }},
        plan.shape);
}

/// What a plan contributes to the scene's bounds: analytic shapes and implicit trees (without
/// their unbounded half-spaces); not .vdb files.
Box3 planBounds(const ObstaclePlan& plan) {
    return std::visit(
        Overloaded{[](const AnalyticSphere& s) {
                       return Box3{s.center - Vec3(s.radius), s.center + Vec3(s.radius)};
                   },
                   [](const AnalyticBox& b) { return Box3{b.lo, b.hi}; },
                   [](const ImplicitPlan& implicit) { return shapeBounds(implicit.node); },
                   [](const VdbPlan&) { return Box3{}; },
                   [](const FogPlan& fog) { return planBounds(*fog.shape); }},
        plan.shape);
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
        const Box3 pb = planBounds(p);
        if (!pb.empty()) b.extend(pb);
    }
    const double pad = 0.1 * glm::length(b.hi - b.lo);
    return Box3{b.lo - Vec3(pad), b.hi + Vec3(pad)};
}

/// Gives the half-spaces without "bounds" the scene's, then checks their index range; with a
/// cache, the bounds become part of the plan's key.
void boundHalfSpaces(const Scene& scene, std::vector<ObstaclePlan>& plans, const std::string& file,
                     bool keyed) {
    const Box3 bounds = sceneBounds(scene, plans);
    for (ObstaclePlan& p : plans) {
        ImplicitPlan* implicit = voxelizedTree(p);
        if (!implicit) continue;
        bool unbounded = false;
        forEachNode(implicit->node, p.pointer, [&](ShapeNode& node, const std::string&) {
            auto* half = std::get_if<HalfSpaceShape>(&node.kind);
            if (half && half->boundsWS.empty()) {
                half->boundsWS = bounds;
                unbounded = true;
            }
        });
        if (!unbounded) continue;
        if (keyed) {
            std::ostringstream key;
            key << std::setprecision(17) << "|bounds " << bounds.lo.x << ' ' << bounds.lo.y << ' '
                << bounds.lo.z << ' ' << bounds.hi.x << ' ' << bounds.hi.y << ' ' << bounds.hi.z;
            p.cacheKey += key.str();
        }
        checkIndexRange(file, p.pointer, shapeBounds(implicit->node), implicit->voxelSize);
    }
}

double estimatedBytes(const ObstaclePlan& plan) {
    return std::visit(
        Overloaded{[](const ImplicitPlan& implicit) {
                       return estimateBuildBytes(implicit.node, implicit.voxelSize,
                                                 implicit.halfWidth);
                   },
                   // Its shape's level set, and the fog grid made from it (about as large).
                   [](const FogPlan& fog) { return 2.0 * estimatedBytes(*fog.shape); },
                   // Analytic shapes need nothing; .vdb files are as large as they are.
                   [](const auto&) { return 0.0; }},
        plan.shape);
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

/// Where a plan's obstacles and volumes go, and what reads and builds them.
struct BuildTarget {
    const std::string& file;  ///< the scene file, for errors
    std::vector<Obstacle>& obstacles;
    std::vector<Volume>& volumes;
    BuildReport& report;
};

void buildObstacles(ObstaclePlan& plan, const BuildTarget& to, LevelSetCache* cache);

/// The obstacles one plan adds as level sets (an implicit tree's, a .vdb file's), shared
/// through the cache: takeShared() gives those an earlier load made; otherwise, once built()
/// says they are complete, what was added is handed to the cache on the way out.
class LevelSetBuild {
  public:
    LevelSetBuild(const ObstaclePlan& plan, const BuildTarget& to, LevelSetCache* cache)
        : mPlan(plan), mTo(to), mCache(cache), mFirst(to.obstacles.size()) {}
    LevelSetBuild(const LevelSetBuild&) = delete;
    LevelSetBuild& operator=(const LevelSetBuild&) = delete;
    ~LevelSetBuild() {
        if (!mBuilt) return;
        ++mTo.report.levelSetsBuilt;
        if (mCache) {
            mCache->insert(mPlan.cacheKey, std::vector<Obstacle>(mTo.obstacles.begin() + mFirst,
                                                                 mTo.obstacles.end()));
        }
    }

    /// Adds the level sets an earlier load of the same obstacle built (in this process, or
    /// stored in the cache's directory by another), if any: the same level sets (and their
    /// far-field companions, built once on first use), with this scene's albedo.
    bool takeShared() {
        if (!mCache) return false;
        const LevelSetCache::Found shared = mCache->find(mPlan.cacheKey);
        if (shared.obstacles.empty()) return false;
        for (const Obstacle& o : shared.obstacles) {
            Obstacle copy = o;
            copy.albedo = mPlan.albedo;
            copy.voxelSize = mPlan.voxelSize;
            copy.halfWidth = mPlan.halfWidth;
            mTo.obstacles.push_back(copy);
            ObstacleBuild r = reportFor(copy.name, mPlan.type, std::get<LevelSetPtr>(copy.shape));
            r.shared = true;
            r.note = shared.file.empty() ? "shared with an earlier load"
                                         : "read from the cache file " + shared.file;
            r.seconds = seconds();
            mTo.report.obstacles.push_back(r);
        }
        ++(shared.file.empty() ? mTo.report.levelSetsShared : mTo.report.levelSetsFromCache);
        return true;
    }

    void add(std::string name, const LevelSetPtr& levelSet) {
        Obstacle o{std::move(name), levelSet, mPlan.albedo};
        o.voxelSize = mPlan.voxelSize;
        o.halfWidth = mPlan.halfWidth;
        mTo.obstacles.push_back(std::move(o));
    }
    /// The level sets are read or built: what add() adds from now on is this plan's.
    void built() { mBuilt = true; }
    /// Since the build began (before the cache was asked).
    double seconds() const { return secondsSince(mStart); }
    /// The index in the target's obstacles of the first this plan added.
    size_t first() const { return mFirst; }

  private:
    const ObstaclePlan& mPlan;
    const BuildTarget& mTo;
    LevelSetCache* mCache;
    size_t mFirst;
    Clock::time_point mStart = Clock::now();
    bool mBuilt = false;
};

/// A sphere or box with "analytic": true: exact, nothing to build.
void addAnalytic(const ObstaclePlan& plan, ObstacleShape shape, const BuildTarget& to) {
    Obstacle o{nameOf(plan), std::move(shape), plan.albedo};
    o.voxelSize = plan.voxelSize;
    o.halfWidth = plan.halfWidth;
    to.obstacles.push_back(std::move(o));
    ObstacleBuild r;
    r.name = nameOf(plan);
    r.type = plan.type;
    r.analytic = true;
    to.report.obstacles.push_back(r);
}

/// Implicit primitives, CSG trees and meshes: one level set (shape.h).
void buildImplicit(const ObstaclePlan& plan, ImplicitPlan& implicit, const BuildTarget& to,
                   LevelSetCache* cache) {
    const std::string name = nameOf(plan);
    LevelSetBuild build(plan, to, cache);
    if (build.takeShared()) {
        // A cache file's level set of a primitive builds its companion as a fresh one would.
        for (size_t i = build.first(); i < to.obstacles.size(); ++i)
            if (const auto* ls = std::get_if<LevelSetPtr>(&to.obstacles[i].shape))
                useShapeDistanceForFarField(*ls, implicit.node);
        return;
    }
    readTreeGrids(implicit.node, plan.pointer, to.file);
    ShapeBuildNotes notes;
    LevelSetPtr ls;
    try {
        ls = buildLevelSet(implicit.node, implicit.voxelSize, implicit.halfWidth, name, &notes);
    } catch (const InputError& e) {
        rethrowUnder(e, to.file, plan.pointer);
    }
    build.add(name, ls);
    build.built();
    ObstacleBuild r = reportFor(name, plan.type, ls);
    r.estimatedBytes = estimatedBytes(plan);
    r.seconds = build.seconds();
    if (notes.holesCapped) r.note = "capped " + std::to_string(notes.holesCapped) + " holes";
    to.report.obstacles.push_back(r);
}

/// A fog: its shape's level sets (built without a cache), each made a fog volume.
void buildFog(const ObstaclePlan& plan, FogPlan& fog, const BuildTarget& to) {
    const std::string name = nameOf(plan);
    const Clock::time_point start = Clock::now();
    std::vector<Obstacle> shapes;
    std::vector<Volume> unused;
    BuildReport shapeReport;
    buildObstacles(*fog.shape, BuildTarget{to.file, shapes, unused, shapeReport}, nullptr);
    for (size_t j = 0; j < shapes.size(); ++j) {
        const std::string n = shapes.size() == 1 ? name : name + "/" + std::to_string(j);
        const VolumeGridPtr v =
            fogFromLevelSet(*std::get<LevelSetPtr>(shapes[j].shape), fog.density, fog.falloff, n);
        to.volumes.push_back({n, v, fog.extinction, plan.albedo});
        ObstacleBuild r = reportFor(n, "fog", v);
        r.estimatedBytes = j == 0 ? estimatedBytes(plan) : 0.0;
        r.seconds = j == 0 ? secondsSince(start) : 0.0;
        r.note = "fog volume";
        to.report.volumes.push_back(r);
    }
}

/// The volumes of a .vdb obstacle whose grid (or some of whose grids) are densities.
void readVdbVolumes(const ObstaclePlan& plan, const VdbPlan& vdb, const std::string& gridName,
                    const BuildTarget& to) {
    const Clock::time_point start = Clock::now();
    std::vector<VolumeGridPtr> grids;
    try {
        grids = readVolumes(vdb.path, gridName, plan.pointer);
    } catch (const InputError& e) {
        rethrowUnder(e, to.file, plan.pointer);
    }
    const double seconds = secondsSince(start);
    for (size_t j = 0; j < grids.size(); ++j) {
        const Similarity& t = vdb.transform;
        const VolumeGridPtr g = transformVolume(grids[j], t.rotation, t.scale, t.translate);
        const std::string gridName2 = describe(*g).name;
        std::string n = !plan.name.empty() ? plan.name : gridName2;
        if (grids.size() > 1 && !plan.name.empty()) n = plan.name + "/" + gridName2;
        if (n.empty()) n = "obstacle_" + std::to_string(plan.index);
        to.volumes.push_back({n, g, vdb.extinction, plan.albedo});
        ObstacleBuild r = reportFor(n, plan.type, g);
        r.seconds = j == 0 ? seconds : 0.0;
        r.note = "fog volume read from " + vdb.path;
        to.report.volumes.push_back(r);
    }
}

/// A .vdb file: its density grids become volumes, its level sets obstacles.
void readVdb(const ObstaclePlan& plan, const VdbPlan& vdb, const BuildTarget& to,
             LevelSetCache* cache) {
    VdbGridKinds kinds;
    try {
        kinds = vdbGridKinds(vdb.path, plan.pointer);
    } catch (const InputError& e) {
        rethrowUnder(e, to.file, plan.pointer);
    }
    const auto holds = [](const std::vector<std::string>& v, const std::string& n) {
        return std::find(v.begin(), v.end(), n) != v.end();
    };
    if (!vdb.grid.empty() && !holds(kinds.levelSets, vdb.grid) &&
        (holds(kinds.volumes, vdb.grid) || holds(kinds.others, vdb.grid))) {
        // A named grid that is not a level set: a density (readVolumes says if it cannot be).
        readVdbVolumes(plan, vdb, vdb.grid, to);
        return;
    }
    if (vdb.grid.empty() && !kinds.volumes.empty()) {
        readVdbVolumes(plan, vdb, "", to);
        if (kinds.levelSets.empty()) return;  // a .vdb of volumes only has no level set to read
        cache = nullptr;  // a cache entry would hold the level sets only
    }
    const std::string name = nameOf(plan);
    LevelSetBuild build(plan, to, cache);
    if (build.takeShared()) return;
    std::vector<LevelSetPtr> grids;
    try {
        grids = readLevelSets(vdb.path, vdb.grid, plan.pointer);
    } catch (const InputError& e) {
        rethrowUnder(e, to.file, plan.pointer);
    }
    const double seconds = build.seconds();
    build.built();
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
        build.add(n, g);
        ObstacleBuild r = reportFor(n, plan.type, g);
        // The file is read once for all its grids.
        r.seconds = j == 0 ? seconds : 0.0;
        r.note = "read from " + vdb.path;
        to.report.obstacles.push_back(r);
    }
}

void buildObstacles(ObstaclePlan& plan, const BuildTarget& to, LevelSetCache* cache) {
    std::visit(Overloaded{[&](const AnalyticSphere& s) { addAnalytic(plan, s, to); },
                          [&](const AnalyticBox& b) { addAnalytic(plan, b, to); },
                          [&](ImplicitPlan& implicit) { buildImplicit(plan, implicit, to, cache); },
                          [&](const VdbPlan& vdb) { readVdb(plan, vdb, to, cache); },
                          [&](FogPlan& fog) { buildFog(plan, fog, to); }},
               plan.shape);
}

}  // namespace

double defaultMemoryLimitBytes() {
    double limit = kDefaultMemoryLimitGiB * kGiB;
    const long pages = ::sysconf(_SC_PHYS_PAGES), pageSize = ::sysconf(_SC_PAGE_SIZE);
    if (pages > 0 && pageSize > 0) limit = std::min(limit, 0.75 * double(pages) * double(pageSize));
    return limit;
}

void checkIndexRange(const std::string& file, const std::string& pointer, const Box3& bounds,
                     double voxel) {
    if (bounds.empty()) return;
    const double reach = std::max({std::fabs(bounds.lo.x), std::fabs(bounds.lo.y),
                                   std::fabs(bounds.lo.z), std::fabs(bounds.hi.x),
                                   std::fabs(bounds.hi.y), std::fabs(bounds.hi.z)});
    if (reach / voxel > kMaxIndexCoordinate) {
        throw InputError(file, pointer,
                         "extends to ~" + numberText(std::round(reach / voxel)) +
                             " voxels from the origin, beyond the level set's index range (" +
                             numberText(kMaxIndexCoordinate) + "); raise voxel_size");
    }
}

void buildPlans(std::vector<ObstaclePlan>& plans, const MemoryBudget& budget,
                const std::string& file, LevelSetCache* cache, Scene& scene) {
    boundHalfSpaces(scene, plans, file, cache != nullptr);
    checkMemory(plans, budget, file);
    scene.build.memoryLimitBytes = budget.limitBytes;
    for (const ObstaclePlan& p : plans) scene.build.estimatedBytes += estimatedBytes(p);
    const Clock::time_point start = Clock::now();
    const BuildTarget to{file, scene.obstacles, scene.volumes, scene.build};
    for (ObstaclePlan& p : plans) {
        try {
            buildObstacles(p, to, cache);
        } catch (const std::bad_alloc&) {
            // A runtime failure (exit 1), not bad input, but the user needs to know which one.
            throw std::runtime_error(file + ": " + p.pointer +
                                     ": out of memory building its level set (raise voxel_size, "
                                     "or lower level_set.max_memory_gib so that the estimate "
                                     "refuses it up front)");
        }
    }
    scene.build.seconds = secondsSince(start);
}

}  // namespace penumbra
