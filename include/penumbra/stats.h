/// @file stats.h
/// Counts and timings of a render. Each worker thread fills its own RenderStats and the renderer
/// merges them at the end (merge() is associative and commutative on every count, so the totals
/// do not depend on the number of threads or on the order of the merge).
///
/// Thread safety: a plain value; one per thread while rendering.
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace penumbra {

struct RenderStats {
    // Settings, filled by the renderer (merge() keeps the left-hand side's).
    std::string method;
    int width = 0;
    int height = 0;
    int threads = 0;
    int lights = 0;
    int aciGrid = 0;   ///< base first-level grid p (squares along a light's shorter edge)
    int aciSteps = 0;  ///< dichotomy steps n
    /// Per light (the scene's order), the first level ACI dices it into: squares along its
    /// edge_u and edge_v (firstLevelGrid: aciGrid along the shorter edge, more along a longer
    /// one in tangent mode). Empty for the Monte Carlo methods.
    std::vector<std::pair<int, int>> aciFirstLevel;
    std::string aciMode;  ///< the estimator's variant: "paper", "arcs" or "tangent" (aciModeName)
    double seconds = 0.0;  ///< wall time of the render (not merged: set once)
    /// The scene's obstacle build report (BuildReport::toJson(): voxels, bytes, seconds per
    /// obstacle), written as "build" when set; the command line sets it (not merged).
    std::string buildJson;
    /// The settings rendered with (RenderSettings::toJson()), written as "settings" when set;
    /// the renderer sets it (not merged).
    std::string settingsJson;

    // Counts. A "pixel" below is one viewing ray; pixel-light pairs are counted per light.
    uint64_t viewingRays = 0;                ///< one per pixel
    uint64_t viewingRayHits = 0;             ///< viewing rays that hit a receiver or obstacle
    uint64_t viewingRaysWithShadowRays = 0;  ///< pixels at which at least one shadow ray was cast
    uint64_t shadowRays = 0;                 ///< every shadow ray (first and second level)
    /// Rays for the light the media scatter towards the camera (their in-scattering lattice and
    /// samples); not counted in shadowRays.
    uint64_t volumeRays = 0;
    uint64_t firstLevelRays = 0;             ///< of which first-level rays (ACI and patterns)
    uint64_t secondLevelRays = 0;            ///< of which second-level rays (dichotomies, checks)
    uint64_t coverageRays = 0;               ///< of the second-level rays, certified coverage's
    uint64_t footprintSamples = 0;           ///< lattice samples answered by footprints, no ray
    uint64_t footprintClearances = 0;        ///< of those, the ones whose clearance was measured
    uint64_t cacheHits = 0;                  ///< lattice samples reused inside ACI evaluations
    uint64_t reusedRays = 0;                 ///< first-level rays answered by an earlier pixel's ray
    uint64_t spans = 0;                      ///< span-light pairs
    uint64_t culledSpans = 0;                ///< span-light pairs with no candidate obstacle
    uint64_t closedFormPixels = 0;           ///< pixel-light pairs shaded by the closed form
    uint64_t aciEvaluations = 0;             ///< full contour integrations
    /// Of those, the ones on a lattice one dichotomy step coarser (RenderSettings::adaptiveSteps)
    uint64_t coarserEvaluations = 0;
    /// Times an evaluation started again one step finer, its samples carried over, because a
    /// sample contradicted every contour its lattice allowed (AciCounts::finerRedos)
    uint64_t finerRedos = 0;
    uint64_t patternEvaluations = 0;         ///< pixel-light pairs where only the pattern was traced
    uint64_t interpolatedPixels = 0;         ///< pixel-light pairs whose value was interpolated
    uint64_t rowPairPixels = 0;  ///< of those, on odd rows between the rows above and below
    uint64_t restarts = 0;                   ///< ACI restarts one level deeper (section 3.2)
    uint64_t squaresRefined = 0;
    uint64_t gridIncreases = 0;              ///< adaptive first-level density: finer grid chosen
    uint64_t gridDecreases = 0;              ///< ... and coarser again
    int maxDepth = 0;                        ///< deepest quadtree refinement seen

    /// Shadow rays over the viewing rays for which shadow rays were cast (the paper's Table 1).
    double shadowRaysPerViewingRay() const {
        return viewingRaysWithShadowRays ? double(shadowRays) / double(viewingRaysWithShadowRays)
                                         : 0.0;
    }

    void merge(const RenderStats& o);

    /// The statistics as a JSON object (keys in snake_case, e.g. "shadow_rays_per_viewing_ray").
    std::string toJson() const;
};

/// Writes toJson() to `path` atomically (temporary name, then rename). Throws std::runtime_error
/// when the file cannot be written.
void writeStatsJson(const std::string& path, const RenderStats& stats);

}  // namespace penumbra
