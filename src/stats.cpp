#include "penumbra/stats.h"

#include "penumbra/output_files.h"

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <stdexcept>

#include <nlohmann/json.hpp>

namespace penumbra {

void RenderStats::merge(const RenderStats& o) {
    viewingRays += o.viewingRays;
    viewingRayHits += o.viewingRayHits;
    viewingRaysWithShadowRays += o.viewingRaysWithShadowRays;
    shadowRays += o.shadowRays;
    firstLevelRays += o.firstLevelRays;
    secondLevelRays += o.secondLevelRays;
    coverageRays += o.coverageRays;
    footprintSamples += o.footprintSamples;
    footprintClearances += o.footprintClearances;
    cacheHits += o.cacheHits;
    reusedRays += o.reusedRays;
    spans += o.spans;
    culledSpans += o.culledSpans;
    closedFormPixels += o.closedFormPixels;
    aciEvaluations += o.aciEvaluations;
    coarserEvaluations += o.coarserEvaluations;
    finerRedos += o.finerRedos;
    patternEvaluations += o.patternEvaluations;
    interpolatedPixels += o.interpolatedPixels;
    rowPairPixels += o.rowPairPixels;
    restarts += o.restarts;
    squaresRefined += o.squaresRefined;
    gridIncreases += o.gridIncreases;
    gridDecreases += o.gridDecreases;
    maxDepth = std::max(maxDepth, o.maxDepth);
}

std::string RenderStats::toJson() const {
    nlohmann::ordered_json j;
    j["method"] = method;
    j["width"] = width;
    j["height"] = height;
    j["threads"] = threads;
    j["lights"] = lights;
    j["aci_grid"] = aciGrid;
    j["aci_steps"] = aciSteps;
    j["aci_first_level"] = nlohmann::ordered_json::array();
    for (const auto& [a, b] : aciFirstLevel) j["aci_first_level"].push_back({a, b});
    j["aci_mode"] = aciMode;
    j["seconds"] = seconds;
    j["viewing_rays"] = viewingRays;
    j["viewing_ray_hits"] = viewingRayHits;
    j["viewing_rays_with_shadow_rays"] = viewingRaysWithShadowRays;
    j["shadow_rays"] = shadowRays;
    j["volume_rays"] = volumeRays;
    j["shadow_rays_per_viewing_ray"] = shadowRaysPerViewingRay();
    j["first_level_rays"] = firstLevelRays;
    j["second_level_rays"] = secondLevelRays;
    j["coverage_rays"] = coverageRays;
    j["footprint_samples"] = footprintSamples;
    j["footprint_clearances"] = footprintClearances;
    j["cache_hits"] = cacheHits;
    j["reused_first_level_rays"] = reusedRays;
    j["spans"] = spans;
    j["culled_spans"] = culledSpans;
    j["closed_form_pixels"] = closedFormPixels;
    j["aci_evaluations"] = aciEvaluations;
    j["coarser_evaluations"] = coarserEvaluations;
    j["finer_redos"] = finerRedos;
    j["pattern_evaluations"] = patternEvaluations;
    j["interpolated_pixels"] = interpolatedPixels;
    j["row_pair_pixels"] = rowPairPixels;
    j["restarts"] = restarts;
    j["squares_refined"] = squaresRefined;
    j["grid_increases"] = gridIncreases;
    j["grid_decreases"] = gridDecreases;
    j["max_depth"] = maxDepth;
    if (!settingsJson.empty()) j["settings"] = nlohmann::ordered_json::parse(settingsJson);
    if (!buildJson.empty()) j["build"] = nlohmann::ordered_json::parse(buildJson);
    return j.dump(2) + "\n";
}

void writeStatsJson(const std::string& path, const RenderStats& stats) {
    writeTextFileAtomically(path, stats.toJson());
}

}  // namespace penumbra
