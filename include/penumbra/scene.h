/// @file scene.h
/// The scene model (src/scene.cpp), its JSON loader (src/scene_loader.cpp) and the building of
/// its obstacles (src/obstacle_build.cpp). The file format is documented in docs/scene-format.md.
///
/// Units: world space, scene units. Paths inside a scene file are relative to that file.
/// Errors: loadScene/parseScene throw InputError naming the file and the JSON pointer of the
/// offending value (e.g. `scene.json: /obstacles/2/radius: must be > 0, got -1`).
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "penumbra/form_factor.h"
#include "penumbra/math.h"
#include "penumbra/occluder.h"
#include "penumbra/volume.h"

namespace penumbra {

/// Pinhole camera; one viewing ray per pixel through the pixel centre.
struct Camera {
    Vec3 eye{0.0, -6.0, 3.0};
    Vec3 lookAt{0.0};
    Vec3 up{0.0, 0.0, 1.0};
    double fovDeg = 40.0;  ///< vertical field of view
    int width = 800;
    int height = 800;
};

/// An infinite analytic plane that receives light (and does not cast shadows).
struct PlaneReceiver {
    Vec3 point{0.0};
    Vec3 normal{0.0, 0.0, 1.0};
    Rgb albedo{0.8};
    bool checker = false;  ///< alternate albedo / albedo2 in squares of side checkerScale
    Rgb albedo2{0.4};
    double checkerScale = 1.0;
};

/// A shadow-casting obstacle. Level sets are also receivers, shaded with their own normals.
struct Obstacle {
    std::string name;
    ObstacleShape shape;
    Rgb albedo{0.8};
    /// For analytic shapes, the level-set resolution to use where one is needed (`penumbra
    /// bake`): the obstacle's voxel_size and half_width in the scene file; 0 takes the scene's.
    double voxelSize = 0.0;
    double halfWidth = 0.0;
};

/// A participating medium: a density grid (a fog volume) that attenuates the light through it,
/// sigma_t = extinction x density per unit length. `albedo` is its single-scattering albedo.
struct Volume {
    std::string name;
    VolumeGridPtr grid;
    double extinction = 1.0;
    Rgb albedo{0.8};
};

/// What building (or reading) one obstacle's level set cost.
struct ObstacleBuild {
    std::string name;
    std::string type;          ///< the scene file's type ("sphere", "csg", "mesh", "vdb", ...)
    bool analytic = false;     ///< an exact shape: nothing was built
    double voxelSize = 0.0;    ///< of the level set (0 for analytic shapes)
    uint64_t activeVoxels = 0;
    uint64_t bytes = 0;        ///< in-memory size of the level set's tree
    double estimatedBytes = 0.0;  ///< the pre-build estimate checked against the memory limit
    double seconds = 0.0;      ///< wall time to build it, or to read its file
    std::string note;          ///< e.g. "capped 2 holes", "read from x.vdb"
    bool shared = false;       ///< taken from a LevelSetCache: nothing was built or read
};

/// The memory and time report of loadScene's building pass, for render statistics and
/// `--verbose` output. The library does not print it; toText() and toJson() format it.
struct BuildReport {
    std::vector<ObstacleBuild> obstacles;  ///< one per Scene::obstacles entry, same order
    std::vector<ObstacleBuild> volumes;    ///< one per Scene::volumes entry, same order
    double seconds = 0.0;                  ///< wall time of building and reading all of them
    double estimatedBytes = 0.0;           ///< sum of the estimates
    double memoryLimitBytes = 0.0;         ///< the limit they were checked against
    int levelSetsBuilt = 0;   ///< obstacles whose level sets this load built or read
    int levelSetsShared = 0;  ///< obstacles whose level sets an earlier load in this process built
    int levelSetsFromCache = 0;  ///< obstacles whose level sets were read from a cache directory

    uint64_t activeVoxels() const;
    uint64_t bytes() const;
    /// One line per obstacle and a total, e.g.
    /// `obstacle 'ring' (torus): 181,234 voxels, 2.1 MiB, 0.04 s (voxel 0.01)`.
    std::string toText() const;
    /// {"seconds": .., "active_voxels": .., "bytes": .., "estimated_bytes": ..,
    ///  "memory_limit_bytes": .., "obstacles": [{"name": .., "type": .., ...}]}
    std::string toJson() const;
};

/// Global level-set settings: the voxel size of implicit primitives and the narrow band.
struct LevelSetSettings {
    double voxelSize = 0.02;
    double halfWidth = 3.0;  ///< voxels
};

struct Scene {
    std::string file;     ///< the file it came from, for messages ("" when parsed from text)
    std::optional<Camera> camera;
    std::vector<RectLight> lights;
    std::vector<Obstacle> obstacles;
    /// Media: "fog" obstacles and the density grids of "vdb" obstacles. They cast fractional
    /// shadows; they are not seen by the camera and do not receive light.
    std::vector<Volume> volumes;
    std::vector<PlaneReceiver> receivers;
    LevelSetSettings levelSet;
    Rgb background{0.0};
    BuildReport build;  ///< filled by loadScene / parseScene
    /// Every file the scene names (meshes, .vdb files) as it was read, with the JSON pointer
    /// that names it; a run must not write over any of them (output_files.h).
    std::vector<std::pair<std::string, std::string>> inputFiles;

    /// Index of the light named `name`; with an empty name, the only light. Throws InputError
    /// when there is no such light or the choice is ambiguous.
    size_t lightIndex(const std::string& name) const;
    /// Index of the first obstacle whose inside holds `p` (level sets: a negative interpolated
    /// value), if any; used to warn about a camera placed inside an obstacle.
    std::optional<size_t> obstacleContaining(const Vec3& p) const;
    /// An Occluder over every obstacle, in scene order.
    Occluder makeOccluder() const;
    /// Every obstacle as a level set whose grid is named after it, in scene order, for
    /// `penumbra bake`: level sets share their voxels (only the name changes); analytic shapes
    /// are voxelized at their voxelSize and halfWidth (or the scene's). A name already taken by
    /// an earlier obstacle gets "_K" appended (K: the obstacle's index), so names are unique.
    std::vector<LevelSetPtr> obstacleLevelSets() const;
};

/// Level sets shared between loads of the same obstacles (the jobs of a batch that render one
/// scene): keyed by the obstacle's JSON and position, the voxel size and band it resolves to, the
/// content of every file it reads and the bounds of its unbounded half-spaces. A load that finds
/// its key takes the same level sets (their far-field companions are built once, on first use,
/// and shared too). Thread-safe; two loads that miss at the same moment both build. Entries live
/// as long as the cache.
///
/// With a directory (`batch --cache DIR`), entries also outlive the process: each is stored as
/// `DIR/levelset-HASH.vdb` (HASH: FNV-1a 64 of the key; the key itself is in the file and checked
/// on reading), written atomically, so that later runs and the other shards of a cluster array on
/// a shared file system read what one of them built. A file that is corrupt, truncated, of
/// another version or made for another key is ignored with a warning, rebuilt and replaced.
class LevelSetCache {
public:
    using Warn = std::function<void(const std::string&)>;
    LevelSetCache() = default;
    /// `directory` is created when missing; `warn` receives one line per ignored file.
    explicit LevelSetCache(std::string directory, Warn warn = {});

    struct Found {
        std::vector<Obstacle> obstacles;  ///< empty when absent
        std::string file;                 ///< the cache file it was read from ("" from memory)
    };
    /// The entry of `key`: from memory, else from the directory's file (then kept in memory).
    Found find(const std::string& key);
    /// Keeps an entry and, with a directory, writes its file (its companions are written by a
    /// later persist() once they are built). A failed write is a warning, not an error.
    void insert(const std::string& key, std::vector<Obstacle> obstacles);
    /// Rewrites the files of entries whose far-field companions have been built since they were
    /// written (call it when a render has ended); nothing without a directory.
    void persist();
    size_t size() const;
    const std::string& directory() const { return mDirectory; }
    /// The file an entry is stored in (meaningful with a directory).
    std::string fileFor(const std::string& key) const;

private:
    struct Entry {
        std::vector<Obstacle> obstacles;
        int farFieldsWritten = -1;  ///< companions in its file; -1: not written
    };
    void write(const std::string& key, Entry& entry);  // with mMutex held
    mutable std::mutex mMutex;
    std::map<std::string, Entry> mEntries;
    std::string mDirectory;
    Warn mWarn;
};

/// Loads and validates a scene file; builds the level sets of implicit obstacles, meshes and
/// CSG trees (shape.h) and reads the .vdb files. Scene::build reports what that cost.
Scene loadScene(const std::string& path, LevelSetCache* cache = nullptr);

/// Same from text; `file` is used in messages and `baseDir` resolves relative paths.
Scene parseScene(const std::string& jsonText, const std::string& file, const std::string& baseDir,
                 LevelSetCache* cache = nullptr);

}  // namespace penumbra
