/// @file estimator.h
/// What every estimator of the form factor shares: the methods by name, their result
/// (Estimate, with its counts), and one call that evaluates any of them at one receiver point
/// for one light, used by `probe` and `render` alike. Approximate contour integration is in
/// contour_integrator.h, the Monte Carlo baselines in monte_carlo.h; adding a method means a
/// name here, a case in estimate() (estimator.cpp) and its test.
#pragma once

#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "penumbra/form_factor.h"
#include "penumbra/math.h"
#include "penumbra/occluder.h"

namespace penumbra {

class ContourIntegrator;
struct McSettings;

/// A setting's accepted values, inclusive. Each setting has one range, the same for the command
/// line, batch manifests, Python and the library (render_settings.h).
struct IntRange {
    int lo, hi;
    bool holds(long v) const { return v >= lo && v <= hi; }
};

/// The estimators: "aci" (the section 5 renderer's pipeline; a plain ACI evaluation in
/// probe), "aci-pixel" (ACI at every pixel), and the Monte Carlo methods.
enum class Method { Aci, AciPixel, Reference, McAdaptive, McSolidAngle, McRatio };

/// True for the Monte Carlo methods (Reference, McAdaptive, McSolidAngle, McRatio).
bool isMonteCarlo(Method method);

/// The shadow rays per estimate a Monte Carlo method uses when RenderSettings::mc.samples is 0:
/// 1024 for Reference (the paper's reference), 16 for McSolidAngle and McRatio, and a cap of
/// 1024 for McAdaptive (whose threshold decides).
int defaultSamples(Method method);

/// The command-line name of a method: "aci", "aci-pixel", "reference", "mc-adaptive",
/// "mc-solid-angle", "mc-ratio".
const char* methodName(Method method);
/// Inverse of methodName; throws InputError whose `where` is `flag` for an unknown name.
Method parseMethod(const std::string& name, const std::string& flag = "--method");

struct AciCounts {
    uint64_t firstLevelRays = 0;   ///< rays to grid corners (also after a restart)
    uint64_t secondLevelRays = 0;  ///< saddle centres, dichotomies, checks, refinements
    uint64_t coverageRays = 0;     ///< of the second-level rays, those certified coverage cast
    uint64_t footprintSamples = 0; ///< lattice samples the footprints answered, without a ray
    /// Of those, the ones whose clearance the tangent construction then measured (a distance
    /// march of the segment; like a traced ray's own clearance, not a shadow ray).
    uint64_t footprintClearances = 0;
    uint64_t cacheHits = 0;        ///< lattice samples asked for again and found in the cache
    uint64_t reusedRays = 0;       ///< first-level samples answered by an earlier ray (reuseCorners)
    uint64_t squaresRefined = 0;
    uint64_t squaresSplitForCoverage = 0;  ///< splits because discs did not cover a square
    uint64_t restarts = 0;
    /// Evaluations that took one dichotomy step fewer (AciSettings::adaptiveSteps): 0 or 1 per
    /// evaluation.
    uint64_t coarserEvaluations = 0;
    /// Evaluations redone one dichotomy step finer, their samples carried over, because a sample
    /// contradicted every contour the coarser lattice allowed (a shadow or window thinner than a
    /// lattice unit): 0, 1 or 2 per evaluation.
    uint64_t finerRedos = 0;
    int maxDepth = 0;              ///< deepest quadtree refinement reached

    uint64_t shadowRays() const { return firstLevelRays + secondLevelRays; }
    void merge(const AciCounts& o) {
        firstLevelRays += o.firstLevelRays;
        secondLevelRays += o.secondLevelRays;
        coverageRays += o.coverageRays;
        footprintSamples += o.footprintSamples;
        footprintClearances += o.footprintClearances;
        cacheHits += o.cacheHits;
        reusedRays += o.reusedRays;
        squaresRefined += o.squaresRefined;
        squaresSplitForCoverage += o.squaresSplitForCoverage;
        restarts += o.restarts;
        coarserEvaluations += o.coarserEvaluations;
        finerRedos += o.finerRedos;
        maxDepth = maxDepth > o.maxDepth ? maxDepth : o.maxDepth;
    }
};

/// Result of one evaluation at one receiver point for one light.
struct Estimate {
    double formFactor = 0.0;
    Vec3 g{0.0};          ///< F = g . n (eq. 5)
    Mat3 dg{0.0};         ///< dg[k] = d g / d M_k with n fixed
    Vec3 gradient{0.0};   ///< dF/dM = dg^T n
    /// An estimate of an upper bound on |F - F_exact|: the form factor of what the evaluation
    /// left uncovered (proven by certificates: none of it is known), plus, per contour piece,
    /// the part of the light between the integrated curve and the other curves its data allow
    /// (docs/estimator.md). NaN when the mode gives none (paper, arcs).
    double errorBound = std::numeric_limits<double>::quiet_NaN();
    AciCounts counts;
    /// Visibility of the first-level grid corners, row-major over (p+1) x (p+1): 1 visible,
    /// 0 hidden (below the horizon counts as hidden). Used for shadow-pattern coherence.
    std::vector<uint8_t> pattern;
    /// ACI: the obstacles (indices into the Occluder) that blocked at least one of its rays,
    /// sorted, one per blocked ray (the nearest hit's). Empty when the whole light was seen.
    std::vector<uint32_t> blockers;
};

/// Evaluates `method` at `r` for `light`: ACI methods through `aci` (its settings decide), Monte
/// Carlo methods with `mc` (samples 0 takes defaultSamples(method)). `query` is the caller's
/// per-thread occluder query (occluder.h). Where media lie between `r` and the light, ACI takes
/// aciThroughMedia() and the Monte Carlo methods weight each sample by its transmittance.
Estimate estimate(Method method, const Receiver& r, const RectLight& light, Occluder::Query& query,
                  ContourIntegrator& aci, const McSettings& mc);

/// How finely aciThroughMedia() resolves the transmittance over the light.
struct MediaCubature {
    /// A cell of the light is split while its Simpson mean of T (kernel-weighted, over its
    /// 3 x 3 nodes) and its five-point mean (corners and centre) differ by more than this.
    double tolerance = 0.0005;
    int maxDepth = 3;  ///< at most 4^maxDepth cells (and (2^(maxDepth+1) + 1)^2 nodes)
};

/// ACI through participating media: F = integral over the visible light of T dF, T the
/// transmittance of the ray from the receiver to the light point. Written as
/// F = F_visible(light) - sum over cells of (1 - T_cell) F_visible(cell): ACI on the whole light
/// once (closed-form contour integrals, so opaque silhouettes stay exact), then, over an
/// adaptive quadtree of cells of the light, each cell's kernel-weighted mean T by the tensor
/// Simpson rule on its 3 x 3 nodes (shared between neighbours, one ray each), split at least
/// into 4 x 4 cells, further while the cell is wider than half of a medium's footprint it meets
/// (the medium's bounding box projected from the receiver onto the light; outside every
/// footprint T = 1 without a ray; as deep as the smallest footprint needs, up to 6 levels) or
/// while its Simpson and five-point means differ by more than the tolerance. A cell whose pyramid
/// of rays meets no box of the media's support (MediumSupport) has T = 1, proven; one that meets
/// some is split, up to two levels more, while it is coarse for the media's feature length and
/// its nodes see little of the attenuation it may hold (docs/volumes.md, "Support"). A cell's visible
/// form factor is its closed form when the whole light is visible (or all its nodes are, on a
/// rectangle light), 0 when all its nodes are hidden, and ACI on the cell as a light of its own
/// where its nodes disagree. Where no node is dimmed the answer is ACI on the light, unchanged.
/// The gradient leaves out T's own derivative; the error bound adds each cell's T spread times
/// its visible form factor, and for each cell whose nodes see nothing where the support may
/// attenuate, the most it can take. Limits: a feature finer than the finest cell between nodes
/// that do see the medium is only as resolved as the variation test finds it, and an opaque
/// feature between a cell's nodes misses its (1 - T) share (it is in F_visible(light) exactly).
Estimate aciThroughMedia(ContourIntegrator& aci, const Receiver& r, const RectLight& light,
                         Occluder::Query& query, const MediaCubature& cubature = {});

}  // namespace penumbra
