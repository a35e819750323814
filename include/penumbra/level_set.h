/// @file level_set.h
/// Narrow-band level-set grids (openvdb::FloatGrid) behind an opaque handle, so that most
/// translation units never include OpenVDB. The grid type itself is visible only to code that
/// includes the internal header src/level_set_impl.h.
///
/// Units: world space, scene units; the grid's own transform maps index to world space.
/// Thread safety: a LevelSet is immutable after creation and may be shared between threads.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "penumbra/math.h"

namespace penumbra {

class LevelSet;  // wraps openvdb::FloatGrid::ConstPtr; see src/level_set_impl.h
using LevelSetPtr = std::shared_ptr<const LevelSet>;

/// What a user (and the statistics) may want to know about a grid: a level set or a volume.
struct GridInfo {
    std::string name;
    double voxelSize = 0.0;     ///< world units (the smallest voxel edge)
    Box3 boundsWS;              ///< world-space bounds of the active voxels (and tiles)
    uint64_t activeVoxels = 0;
    uint64_t bytes = 0;         ///< in-memory size of the tree
};

struct LevelSetInfo : GridInfo {
    double halfWidth = 0.0;     ///< narrow-band half width, in voxels
};
LevelSetInfo describe(const LevelSet& ls);

/// The level set's voxel size in world units (cheap, unlike describe(), which walks the tree).
double voxelSizeOf(const LevelSet& ls);

/// The level set's value at a world-space point: trilinear interpolation of the voxel values
/// (the signed distance within the band, +-background beyond it). Makes an accessor per call:
/// for tests and occasional queries, not for inner loops.
double sampleLevelSet(const LevelSet& ls, const Vec3& pointWS);

/// Sphere level set built with OpenVDB's createLevelSetSphere.
LevelSetPtr makeSphereLevelSet(const Vec3& center, double radius, double voxelSize,
                               double halfWidthVoxels, const std::string& name = "sphere");

/// Axis-aligned box level set (OpenVDB's createLevelSetBox).
LevelSetPtr makeBoxLevelSet(const Vec3& lo, const Vec3& hi, double voxelSize,
                            double halfWidthVoxels, const std::string& name = "box");

/// Checks a .vdb file's header and grid descriptors (read with OpenVDB's own readers) before
/// any tree is read: every grid's bytes must lie inside the file. Throws InputError naming
/// `file` and `where` for a truncated or corrupt header (readLevelSets calls it first).
void checkVdbFile(const std::string& file, const std::string& where);

/// Reads level-set grids from a .vdb file: the grid named `gridName`, or every level-set grid
/// when `gridName` is empty. Throws InputError naming `file` and `where` (the JSON path of the
/// obstacle) when the file is missing or unreadable, the grid is absent, is not a float level
/// set (fog volumes, vectors), or has non-uniform voxels. Half-float grids are accepted.
std::vector<LevelSetPtr> readLevelSets(const std::string& file, const std::string& gridName,
                                       const std::string& where = "");

/// Writes level sets as named grids to a .vdb file (atomically: a temporary name in the same
/// directory, then rename). Throws std::runtime_error when the file cannot be written.
void writeLevelSets(const std::string& file, const std::vector<LevelSetPtr>& grids);

struct VdbWriteOptions {
    /// Store values as 16-bit floats: about half the file, values to ~3 significant digits
    /// (1e-3 of the band, far below a voxel). Readers get float grids back.
    bool halfFloat = false;
};
void writeLevelSets(const std::string& file, const std::vector<LevelSetPtr>& grids,
                    const VdbWriteOptions& options);

/// The far-field companion every level set gets for shadow-ray clearances and certificates
/// (occluder.cpp): voxels this many times the fine ones, and a band of this many of them.
constexpr double kFarFieldFactor = 4.0;
constexpr float kFarFieldBand = 16.0f;

/// One entry of a level-set cache directory (LevelSetCache, scene.h): the level sets of one
/// obstacle with their far-field companions when those were built, and the key they were built
/// for. `labels` (one per level set) travel with them: the obstacles' names.
struct CacheFileEntry {
    std::vector<LevelSetPtr> levelSets;
    std::vector<std::string> labels;
    int farFields = 0;  ///< how many companions the file held (read) or got (written)
};

/// Writes an entry atomically (a temporary name in the same directory, then rename). The file
/// holds `key` in its metadata; companions already built are written with their level set.
/// Throws std::runtime_error when the file cannot be written.
void writeCacheFile(const std::string& file, const std::string& key, const CacheFileEntry& entry);

/// Reads an entry written by writeCacheFile for the same `key`, and hands each level set its
/// stored companion. Throws std::runtime_error with the reason for a file that is corrupt,
/// truncated, of another version or made for another key (a hash collision or a foreign file).
CacheFileEntry readCacheFile(const std::string& file, const std::string& key);

/// Whether the level set's far-field companion has been built (or read from a cache file).
bool hasFarField(const LevelSet& ls);

/// The same level set under another grid name; the voxels are shared.
LevelSetPtr renamedLevelSet(const LevelSetPtr& levelSet, const std::string& name);

}  // namespace penumbra
