// Internal to the scene loader: what pass 1 (src/scene_loader.cpp, JSON -> plans) hands to
// passes 2 and 3 (src/obstacle_build.cpp, plans -> level sets, fog and .vdb volumes).
//
// A plan is an obstacle validated but not built: parsing the whole document first reports a
// typo in the last obstacle before minutes are spent voxelizing the first one, and lets the
// memory of every level set be estimated (and refused) up front.
#pragma once

#include <memory>
#include <string>
#include <variant>
#include <vector>

#include "penumbra/occluder.h"
#include "penumbra/scene.h"
#include "penumbra/shape.h"

namespace penumbra {

/// An obstacle built by shape.h: implicit primitives, CSG trees, meshes.
struct ImplicitPlan {
    ShapeNode node;
    double voxelSize, halfWidth;
};

/// The level sets (and density grids) of a .vdb file.
struct VdbPlan {
    std::string path;  ///< resolved
    std::string grid;  ///< empty: every level-set grid (and every fog volume)
    Similarity transform;
    double extinction = 1.0;  ///< for the file's volumes
};

struct ObstaclePlan;
/// A participating medium made from a shape: its level set turned into a fog volume.
struct FogPlan {
    std::shared_ptr<ObstaclePlan> shape;  ///< an ImplicitPlan or a VdbPlan
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
    /// unbounded half-spaces. Empty when the load has no cache.
    std::string cacheKey;
};

/// When `root` is a lone smooth primitive (sphere, torus, capsule), lets `levelSet` (built from
/// it, or read back from a cache for it) build its far-field companion from the primitive's own
/// distance (LevelSet::setFarFieldRecipe); does nothing otherwise. buildLevelSet calls it itself.
void useShapeDistanceForFarField(const LevelSetPtr& levelSet, const ShapeNode& root);

/// The default limit on the memory of the level sets to build: 16 GiB, or three quarters of
/// the machine's memory when that is less.
double defaultMemoryLimitBytes();

struct MemoryBudget {
    double limitBytes = defaultMemoryLimitBytes();  ///< level_set.max_memory_gib
};

/// Refuses (InputError at `file`, `pointer`) geometry within `bounds` that reaches beyond
/// OpenVDB's index range at this voxel size; nothing for empty bounds.
void checkIndexRange(const std::string& file, const std::string& pointer, const Box3& bounds,
                     double voxel);

/// Passes 2 and 3. Cuts the half-spaces given no "bounds" to the scene's bounds (around its
/// lights, camera and bounded obstacles: `scene` must hold them), refuses the plans when their
/// estimated memory is over `budget`, then builds them, in order, into scene.obstacles and
/// scene.volumes, and fills scene.build. `file` names the scene in errors; with a `cache`, plans
/// whose cacheKey it holds take its level sets, and built ones are given to it.
void buildPlans(std::vector<ObstaclePlan>& plans, const MemoryBudget& budget,
                const std::string& file, LevelSetCache* cache, Scene& scene);

}  // namespace penumbra
