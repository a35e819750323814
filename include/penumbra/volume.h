/// @file volume.h
/// Participating media: scalar density grids (OpenVDB fog volumes, or any float grid named in
/// the scene) behind an opaque handle, so that most translation units never include OpenVDB.
/// A medium attenuates light by Beer-Lambert: along a segment, transmittance
/// T = exp(-extinction x integral of density ds).
///
/// Units: world space; density is per unit of `extinction` (which is per scene unit of length).
/// Thread safety: a VolumeGrid is immutable and may be shared; each thread makes its own
/// VolumeSampler.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "penumbra/level_set.h"
#include "penumbra/math.h"

namespace penumbra {

class VolumeGrid;  // wraps openvdb::FloatGrid::ConstPtr; see src/volume.cpp
using VolumeGridPtr = std::shared_ptr<const VolumeGrid>;

struct VolumeInfo : GridInfo {
    double maxDensity = 0.0;
};
VolumeInfo describe(const VolumeGrid& volume);

/// The fog volume of a level set (OpenVDB's sdfToFogVolume): density `density` inside the
/// surface. `falloff` = 0: a ramp one voxel wide centred on the surface (so a straight chord
/// through it integrates to its length); `falloff` > 0: density rises from 0 at the surface to
/// its full value at that depth inside (the level set must reach that deep: its band is widened
/// by the caller). Throws std::invalid_argument for a negative or non-finite density or falloff.
VolumeGridPtr fogFromLevelSet(const LevelSet& levelSet, double density, double falloff,
                              const std::string& name);

/// The volumes of a .vdb file: the grid named `gridName` (any scalar float grid that is not a
/// level set), or, when `gridName` is empty, every fog-class float grid. Refuses, as
/// InputError naming `file` and `where`: a missing file or grid, a non-float grid, a negative,
/// NaN or infinite density (naming the grid and the voxel), a non-linear transform.
std::vector<VolumeGridPtr> readVolumes(const std::string& file, const std::string& gridName,
                                       const std::string& where = "");

/// The names and classes of a .vdb file's grids without reading their voxels: which grids are
/// level sets and which are volumes (for the scene loader's choice). Throws InputError.
struct VdbGridKinds {
    std::vector<std::string> levelSets, volumes, others;
};
VdbGridKinds vdbGridKinds(const std::string& file, const std::string& where = "");

/// Moves a volume by a similarity (rotation, uniform scale, translation): the same voxels, a new
/// transform. Density is per unit length, so a scaled medium keeps its density.
VolumeGridPtr transformVolume(const VolumeGridPtr& volume, const Mat3& rotation, double scale,
                              const Vec3& translate);

/// Writes level sets and volumes (each under the name given with it) to one .vdb file,
/// atomically (`penumbra bake`); `halfFloat` stores 16-bit values. Throws std::runtime_error.
void writeGrids(const std::string& file, const std::vector<LevelSetPtr>& levelSets,
                const std::vector<std::pair<std::string, VolumeGridPtr>>& volumes, bool halfFloat);

/// Where a medium can attenuate: world-space boxes that together hold every point at which its
/// trilinear density can be above 0, so that a segment meeting none of them has transmittance 1
/// exactly. `parts`: per leaf node, the index box of its voxels with a positive density grown by
/// one voxel (the interpolation kernel's reach), and per tile with a positive value the same;
/// mapped to world space as the bounds of their corners, each with its largest density (a
/// segment's optical depth is at most the sum, over the parts it crosses, of that density
/// times the part's diagonal). `blocks`: the parts grouped by 32^3
/// voxel blocks (each block's bounds and its range in `parts`), for a coarse test first. A grid
/// whose background is not 0 has one part, its bounds.
struct MediumSupport {
    struct Block {
        Box3 box;
        uint32_t first = 0, count = 0;  // parts[first, first + count)
    };
    struct Part {
        Box3 box;
        double maxDensity = 0.0;  ///< the largest density of its voxels
    };
    std::vector<Block> blocks;
    std::vector<Part> parts;
    double maxDensity = 0.0;  ///< the largest density (0: nothing to attenuate, no parts)
    /// The length over which the density can change by `maxDensity`: maxDensity over the
    /// largest difference between neighbouring voxels per unit length (world; infinite when
    /// the density is constant). A fog with falloff f has about f; a hard-edged one a voxel.
    double featureLength = 0.0;
};
/// The support of a volume, built with it.
const MediumSupport& support(const VolumeGrid& volume);

/// The density at a world point (trilinear). Makes an accessor per call: for tests.
double sampleDensity(const VolumeGrid& volume, const Vec3& pointWS);

/// Per-thread optical-depth integrator over one volume: skips empty space with OpenVDB's
/// VolumeRayIntersector (hierarchical DDA over active tiles and leaves) and integrates the
/// trilinear density over each active span by the midpoint rule with steps of at most half a
/// voxel.
class VolumeSampler {
public:
    explicit VolumeSampler(const VolumeGrid& volume);
    VolumeSampler(const VolumeSampler& other);  ///< a fresh accessor, for another thread
    VolumeSampler& operator=(const VolumeSampler&) = delete;
    ~VolumeSampler();

    /// Integral of density along from + t dir, t in [t0, t1] (`dir` a unit vector).
    double opticalDepth(const Vec3& from, const Vec3& dir, double t0, double t1);
    /// The trilinear density at a world point.
    double density(const Vec3& p);
    /// Density samples taken so far (the cost measure).
    uint64_t samples() const { return mSamples; }

private:
    struct Impl;
    std::unique_ptr<Impl> mImpl;
    uint64_t mSamples = 0;
};

}  // namespace penumbra
