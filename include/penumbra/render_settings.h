/// @file render_settings.h
/// One model of what a render or a probe can be told: the estimator's settings (AciSettings),
/// the Monte Carlo baselines' (McSettings) and the renderer's (RenderSettings), each with one
/// range, and one set of names for them, the JSON model's (docs/render-settings.md):
///
///   method, width, height, threads, aci_grid, aci_steps, aci_mode, aci_fixed_steps,
///   aci_no_row_pairs, max_span, samples, mc_threshold, mc_max_depth, mc_initial_depth, seed,
///   volume_cache, volume_samples, hide_volumes
///
/// Batch manifests use these keys; the command line's flags are the same names with dashes
/// (--aci-grid); Python's keywords are the names themselves. RenderSettings::readJson reads
/// them, RenderSettings::toJson writes them (sidecars, image metadata, statistics, job hashes)
/// and RenderSettings::validate checks what one range per key cannot (combinations). Errors
/// name the JSON field; the command line turns a field into its flag.
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "penumbra/estimator.h"
#include "penumbra/math.h"

namespace penumbra {

/// Largest lattice resolution (grid << (steps + 1)) an evaluation uses; larger settings are
/// refused by RenderSettings::validate (and reduced by taking fewer dichotomy steps by the
/// integrator when set in code). At the limit the lattice takes 4097^2 x 8 bytes.
constexpr int kMaxLatticeUnits = 4096;

constexpr IntRange kAciGridRange{1, 32};   ///< AciSettings::grid (aci_grid)
constexpr IntRange kAciStepsRange{1, 12};  ///< AciSettings::steps (aci_steps)

struct AciSettings {
    int grid = 2;         ///< p = q: squares per light edge at the first level (paper: 2)
    int steps = 5;        ///< dichotomy steps n along a crossed side (paper: 5)
    double rayOffset = 0; ///< shadow rays start this far from M along n (1-2 voxels)
    double thresholdScale = 1.0;  ///< multiplies the strip threshold of section 3.2
    bool refine = true;   ///< section 3.2 check-and-refine; off gives the plain contour
    bool gradient = true; ///< compute the gradient from the 3D contour points (section 4)
    uint32_t seed = 0;    ///< picks the diagonal of case-3 squares (deterministic per square)
    /// Beyond the paper: use the obstacles' signed clearance (how far a ray passes from the
    /// surface, or how deep it goes in; level sets are distance fields) to place dichotomy
    /// samples by the secant rule and contour vertices by interpolation. Same lattice, same
    /// final interval, fewer rays. Off reproduces the paper's bisection exactly.
    bool distanceGuided = true;
    /// With distanceGuided: stop a dichotomy after this many rays when both ends of its
    /// bracket know their clearance, and interpolate (0: always narrow to the final interval).
    int guidedProbes = 1;
    /// Beyond the paper (needs distanceGuided): a level set's distance gradient where a ray
    /// passes closest to the surface gives the plane of the grazing rays there, hence the
    /// contour's tangent on the light at each contour vertex. Dichotomies take Newton steps from
    /// the end nearer the contour; each piece between two vertices is integrated as the conic
    /// arc tangent to both tangent lines, with no check ray when the triangle the tangents make
    /// is under the strip threshold and one ray (placing the arc's shoulder) otherwise; only
    /// pieces whose tangents are unknown or inconsistent take the section 3.2 check and
    /// refinement. See docs/estimator.md.
    bool tangentContour = true;
    /// Beyond the paper (tangent mode, for renderers): remember the first-level rays of earlier
    /// evaluations and patterns, and answer one again without a ray while the receiver point
    /// has moved less than that ray's distance bound (Clearance::bound: signed distances are
    /// 1-Lipschitz, so a segment that stays d away from every surface stays clear when its start
    /// moves by less than d, and one that goes d deep stays blocked). Off by default: results
    /// then depend on what was evaluated before, so the caller calls forgetCorners() at
    /// deterministic places (the renderer: at every span).
    bool reuseCorners = false;
    /// Beyond the paper: integrate each checked piece X-Z-Y as a parabolic arc through its
    /// three points instead of two chords (no extra rays; see docs/estimator.md).
    bool curvedContour = true;
    /// Beyond the paper: check a case-3 square (the contour crosses two opposite sides) on its
    /// midline rather than on a random diagonal, which meets a contour near a side close to
    /// one end of its chord and so misses its bulge.
    bool midlineCheck = true;
    /// Beyond the paper (tangent mode): a light longer than wide gets a first level of about
    /// square squares, `grid` along its shorter edge and proportionally more along the longer
    /// (firstLevelGrid in contour_integrator.h), so that contour vertices are located as finely
    /// along both edges. Off: `grid` x `grid` squares, as in the paper, whatever the shape.
    bool aspectGrid = true;
    /// Beyond the paper (tangent mode with coverage, for renderers): an evaluation whose
    /// obstacles' footprints on the light (light_footprint.h) are all wide, at least 16 units of
    /// the lattice `steps` gives, takes one dichotomy step fewer (a lattice half as fine, so
    /// epsilon, the coverage gap and the bound's strips double). Narrow footprints, small
    /// obstacles or thin ones seen edge-on, keep `steps`.
    bool adaptiveSteps = false;
    /// Beyond the paper (tangent mode): certified coverage. Every shadow ray also returns a
    /// Certificate (occluder.h): a disc on the light within which every point has its answer.
    /// Rays go where no disc proves the light and no located contour piece is near, and a
    /// square holding a ray that contradicts the contour is split like a refined square, so any
    /// shadow or window that holds a disc of a few lattice units is found even when it touches
    /// no first-level corner. A point whose
    /// first ray's disc covers the whole light needs that one ray. See docs/estimator.md.
    bool coverage = true;
    /// With coverage: rays go to uncovered parts of the light until every uncovered point is
    /// within this many final dichotomy intervals (epsilon, the lattice resolution) of a disc or
    /// of a located contour piece's strip, so any shadow or window that holds a disc of that
    /// radius is found (what stays uncovered goes into Estimate::errorBound). Smaller
    /// finds smaller features for more rays.
    double coverageGap = 1.0;
    /// With coverage: at most this many coverage rays per evaluation; what stays uncovered then
    /// goes into the error bound (Estimate::errorBound) as its whole form factor.
    int maxCoverageRays = 48;
    /// With coverage: when the allowance runs out and the cells still unproven hold more than
    /// this share of the unoccluded form factor, coverage gets one more allowance of
    /// maxCoverageRays (0: never). On for point queries (probe, sensors); the renderer sets 0,
    /// where it cost up to a third more time on random scenes for changes under 1 of 255.
    double extendCoverage = 0.005;
    /// With coverage: compute Estimate::errorBound (off: NaN). The bound's last step, counting
    /// what stayed uncovered cell by cell, costs about a third of a render's time on scenes of
    /// small obstacles, so renders ask for it only with --aov-error-bound.
    bool errorBound = true;
    /// When set, every traced shadow ray's target is appended (tests use it to prove that no
    /// ray is traced twice).
    std::vector<Vec3>* rayLog = nullptr;
};

/// Named combinations of the options above, for the command line (`--aci-mode`), batch
/// manifests (`aci_mode`) and statistics:
///  - "paper": Vedel's method exactly (bisection, straight chords, a random diagonal for case 3);
///  - "arcs": the paper's rays, with parabolic arcs and the midline check;
///  - "tangent" (default): the distance-guided Newton dichotomy and tangent arcs.
enum class AciMode { Paper, Arcs, Tangent };

/// The mode's name as the command line spells it.
const char* aciModeName(AciMode mode);
/// Parses a mode name; InputError naming `where` (a flag or JSON pointer) for an unknown one.
AciMode parseAciMode(const std::string& name, const std::string& where);
/// Sets the options of `s` that the mode fixes (grid, steps and the rest are kept).
void applyAciMode(AciSettings& s, AciMode mode);
/// The mode `s` corresponds to (Tangent for combinations no mode names exactly).
AciMode aciModeOf(const AciSettings& s);

constexpr IntRange kMcSamplesRange{1, 1 << 20};  ///< McSettings::samples (--samples, samples)
constexpr IntRange kMcMaxDepthRange{0, 24};      ///< McSettings::maxDepth (--mc-max-depth)
constexpr IntRange kMcInitialDepthRange{0, 8};   ///< McSettings::initialDepth

struct McSettings {
    /// Shadow rays per evaluation (fewer when part of the light is below the horizon). For
    /// monteCarloAdaptive, the most rays one evaluation may spend (a cap; the threshold decides).
    int samples = 16;
    /// mc-adaptive: a cell is split while the standard error of its contribution exceeds this
    /// fraction of the unoccluded form factor (smaller: more rays, less noise).
    double threshold = 0.01;
    /// mc-adaptive: deepest quadtree level (the root is level 0; cells of level d have side
    /// 2^-d of the light's).
    int maxDepth = 8;
    /// mc-adaptive: the light starts as a 2^d x 2^d grid of cells (four rays each) before any
    /// split; 0 starts from the whole light (4 rays).
    int initialDepth = 0;
    double rayOffset = 0.0;  ///< shadow rays start this far from M along n (as AciSettings)
    uint64_t seed = 0;       ///< the evaluation's random stream (see mcSeed)
};

constexpr IntRange kMaxSpanRange{1, 4096};     ///< RenderSettings::maxSpan (max_span)
constexpr IntRange kImageSizeRange{1, 65536};  ///< RenderSettings::width, height
constexpr IntRange kThreadsRange{1, 1024};     ///< RenderSettings::threads (threads)

struct RenderSettings {
    Method method = Method::Aci;
    int width = 0;    ///< 0: the camera's width
    int height = 0;   ///< 0: the camera's height
    int threads = 0;  ///< worker threads; 0: every hardware thread; -1: the caller's TBB arena
    /// Estimator settings (grid p, steps n, ...). rayOffset <= 0 picks it automatically at
    /// each receiver point (receiverRayOffset): 1.5 voxels on and near level sets, 1e-6 x the
    /// scene's size elsewhere.
    /// `gradient` off (the default here) skips the gradient, which only the gradient AOV uses.
    AciSettings aci = [] {
        AciSettings s;
        s.gradient = false;
        return s;
    }();
    int maxSpan = 32;          ///< longest span, in pixels (section 5: "a maximum length")
    bool shaftCulling = true;  ///< off: every obstacle is a candidate of every span
    bool coherence = true;     ///< off: ACI at every pixel of a span that has candidates
    bool adaptiveGrid = true;  ///< section 5's adaptive first-level density (not with coverage)
    /// Beyond the paper, tangent mode on receiver planes: answer a first-level ray again without
    /// tracing while the pixel's point has moved less than the ray's distance bound
    /// (AciSettings::reuseCorners), within each span.
    bool reuseFirstLevel = true;
    /// Beyond the paper, tangent mode (AciSettings::adaptiveSteps): an evaluation whose
    /// obstacles' footprints on the light are all wide takes one dichotomy step fewer than
    /// aci.steps. JSON `aci_fixed_steps` (true turns it off), `--aci-fixed-steps`.
    bool adaptiveSteps = true;
    /// Beyond the paper, certified tangent mode: every fourth row is shaded on its own, the
    /// rows between are interpolated from the rows s and 3s above and below (s = 2, then 1)
    /// over stretches where those rows saw the same blockers, the pixel no other candidate and
    /// the shadow bends little across them, once an evaluation at the stretch's middle agrees
    /// (docs/rendering.md, pipeline step 4). JSON `aci_no_row_pairs` (true turns it off),
    /// `--aci-no-row-pairs`.
    bool rowPairs = true;
    int maxGridFactor = 2;     ///< the adaptive grid stays within [p, maxGridFactor x p]
    /// Monte Carlo settings (samples, mc-adaptive's threshold, seed). `samples` 0 (the default
    /// here) takes defaultSamples(method); rayOffset is taken from `aci.rayOffset`, and each
    /// pixel's seed is mcSeed(x, y, light index, mc.seed).
    McSettings mc = [] {
        McSettings s;
        s.samples = 0;
        return s;
    }();
    /// Volumes seen by the camera (docs/volumes.md): viewing rays march through the media,
    /// attenuating what lies behind and adding the light they scatter; the image gets an alpha
    /// channel (the media's opacity along the ray). Off: media only cast shadows.
    bool volumesVisible = true;
    /// In-scattered light is computed on a lattice of this many nodes along the media's longest
    /// extent (trilinear between nodes); 0: at every sample of every viewing ray (slow; for
    /// measuring the lattice's error).
    int volumeCache = 24;
    /// Rays per in-scattering estimate (stratified over each light's area).
    int volumeSamples = 64;

    /// The ACI settings a pixel's evaluation uses: `aci` with adaptiveSteps, and one coverage
    /// allowance (AciSettings::extendCoverage 0: the second is for point queries only). The
    /// renderer adds the pixel's ray offset and its span's grid and corner reuse.
    AciSettings pixelAci() const {
        AciSettings a = aci;
        a.adaptiveSteps = adaptiveSteps;
        a.extendCoverage = 0.0;
        return a;
    }

    /// Every key of the JSON model, in its order (the file comment's list).
    static const std::vector<std::string>& keys();
    /// The integer keys and their ranges.
    static const std::vector<std::pair<std::string, IntRange>>& integerRanges();
    /// Reads the model's keys present in `object` over these settings (other keys are left to
    /// the caller); one range per key. Errors: InputError(file, where + "/" + key, message).
    void readJson(const nlohmann::json& object, const std::string& file = "",
                  const std::string& where = "");
    /// The settings in the model's names: method, the image size when set, the ACI settings and
    /// max_span, the Monte Carlo settings for Monte Carlo methods (samples as used), the volume
    /// settings; not the thread count, which changes no pixel (statistics report the threads
    /// used). What sidecars, image metadata, statistics and job hashes record.
    nlohmann::ordered_json toJson() const;
    /// What single ranges cannot check: every range again (for settings made in code), samples
    /// only with a Monte Carlo method, and a lattice of at most kMaxLatticeUnits. Errors name
    /// where + "/" + the key at fault.
    void validate(const std::string& file = "", const std::string& where = "") const;
};

/// The accepted range of RenderSettings::volumeCache (0: no lattice) and volumeSamples.
constexpr IntRange kVolumeCacheRange{0, 256};
constexpr IntRange kVolumeSamplesRange{1, 65536};

/// The command-line flag of a key of the JSON model: "--" and the key with dashes.
std::string flagOfKey(const std::string& key);

}  // namespace penumbra
