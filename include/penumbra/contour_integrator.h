/// @file contour_integrator.h
/// Approximate contour integration (Vedel 1993, sections 3 and 4): the form factor from a
/// receiver point to a rectangular light partly hidden by obstacles, and its gradient.
///
/// The light is diced into a p x q grid whose corners receive first-level shadow rays; marching
/// squares (with a centre ray for saddles) finds the squares the visible contour crosses;
/// dichotomy along crossed sides locates contour vertices; each crossed square is checked with
/// one more point (on a diagonal or semi-diagonal) and refined like a quadtree, with one
/// dichotomy step fewer and half the threshold, where the change exceeds the form factor of a
/// strip of width epsilon around its contour. An inconsistency that would need backtracking
/// restarts the whole light one level deeper. Every ray goes to a point of one lattice at the
/// finest resolution and is cached, so no ray is traced twice for one receiver point.
///
/// The light's part below the receiver's tangent plane is treated as hidden, and contour
/// vertices on the horizon are placed exactly (no ray is cast below the horizon).
///
/// Thread safety: a ContourIntegrator holds a scratch lattice; use one per thread.
#pragma once

#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "penumbra/estimator.h"
#include "penumbra/form_factor.h"
#include "penumbra/occluder.h"

namespace penumbra {

/// Largest lattice resolution (grid << (steps + 1)) an evaluation uses; larger settings are
/// reduced by taking fewer dichotomy steps. At the limit the lattice takes 4097^2 x 8 bytes.
constexpr int kMaxLatticeUnits = 4096;

constexpr IntRange kAciGridRange{1, 32};   ///< AciSettings::grid (--aci-grid, aci_grid)
constexpr IntRange kAciStepsRange{1, 12};  ///< AciSettings::steps (--aci-steps, aci_steps)

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
    /// Beyond the paper (tangent mode): certified coverage. Every shadow ray also returns a
    /// Certificate (occluder.h): a disc on the light within which every point has its answer.
    /// A square may be closed only when discs cover it (a square with a contour: discs that
    /// exclude every obstacle but the contour's own near the contour, full discs farther away);
    /// otherwise it is split like a refined square, so any shadow or window that holds a disc of
    /// a few lattice units is found even when it touches no first-level corner. A point whose
    /// first ray's disc covers the whole light needs that one ray. See docs/estimator.md.
    bool coverage = true;
    /// With coverage: rays go to uncovered parts of the light until every uncovered point is
    /// within this many final dichotomy intervals (epsilon, the lattice resolution) of a disc or
    /// contour band, so any shadow or window that holds a disc of that radius is found. Smaller
    /// finds smaller features for more rays.
    double coverageGap = 1.0;
    /// With coverage: at most this many coverage rays per evaluation; what stays uncovered then
    /// goes into the error bound (Estimate::errorBound) as its whole form factor.
    int maxCoverageRays = 48;
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

class ContourIntegrator {
public:
    explicit ContourIntegrator(const AciSettings& settings = {});
    const AciSettings& settings() const { return mSettings; }
    void setSettings(const AciSettings& s) { mSettings = s; }

    Estimate evaluate(const Receiver& r, const RectLight& light, Occluder::Query& query);

    /// Only the first-level pattern (the (p+1)^2 corner rays), for shadow-pattern coherence.
    /// Adds the rays to `counts` (with reuseCorners, some corners may be answered by earlier
    /// rays: counts.reusedRays).
    std::vector<uint8_t> pattern(const Receiver& r, const RectLight& light, Occluder::Query& query,
                                 AciCounts& counts);

    /// Forgets the first-level rays kept for reuseCorners.
    void forgetCorners() { mCorners.clear(); }

    /// One first-level ray kept for reuseCorners (public for the implementation's helpers).
    struct Corner {
        Vec3 origin{0.0};
        double bound = 0.0;  ///< Clearance::bound of the ray (0: cannot be reused)
        float sample = 0.0f, clear = 0.0f;
        float tangent[6] = {0, 0, 0, 0, -1, 0};
        Certificate cert;  ///< with AciSettings::coverage
        /// Whether this ray's answer holds for a ray from `from` to the same light point.
        bool answers(const Vec3& from) const {
            return bound != 0.0 && glm::length(from - origin) < std::abs(bound);
        }
    };

private:
    struct Lattice;
    std::vector<Corner> mCorners;  // (p+1)^2 for mCornerGrid and mCornerLight; empty: none
    int mCornerGrid = 0;
    RectLight mCornerLight;
    Corner* reusableCorner(const RectLight& light, int grid, int i, int j);
    AciSettings mSettings;
    std::vector<uint32_t> mStamp;  // generation stamps of the sample lattice
    std::vector<float> mSample;    // >= 0: hidden, hit fraction along the ray; -1 visible
    std::vector<float> mClear;     // signed angular clearance of the sample's ray, NaN unknown
    std::vector<uint8_t> mPending;  // 1: the sample's clearance is not measured yet
    std::vector<float> mNormal;    // tangentContour: x, y, z of the distance gradient at the
                                   // ray's closest approach (0 unknown)
    std::vector<Certificate> mCert;  // coverage: each sample's certificate
    struct Disc {
        Vec3 c;        // centre on the light
        double r2;     // squared radius of the full certificate
        double ro2;    // squared radius that excludes every obstacle but `obstacle`
        int obstacle;  // Certificate::obstacle
    };
    struct Segment {  // a piece of located contour and the band around it
        Vec3 a, b;
        double width;
        int own;  // its obstacle, -1 unknown or mixed
    };
    struct Leaf {  // a square closed by the last pass
        int x0, y0, s;
        int type;  // 0 hidden, 1 visible, 2 contour (segments seg0 .. seg1)
        uint32_t seg0, seg1;
    };
    struct Uncovered {  // a cell of the light no disc or band proves yet
        double a0, b0, size;  // lattice coordinates
        double gap;           // its centre's distance to the nearest disc that would prove it
        int own;              // the obstacle of the contour band it is in, -1 none
        Vec3 centre;
    };
    std::vector<Uncovered> mUncovered;  // coverage: the current pass's uncovered cells
    std::vector<Disc> mDiscs;        // coverage scratch: discs near one leaf
    std::vector<Segment> mSegs;      // coverage: the last pass's contour segments
    std::vector<Segment> mNearSegs;  // coverage scratch: segments near one leaf
    std::vector<Leaf> mLeaves;       // coverage: the last pass's leaves
    std::vector<uint32_t> mMarked;   // coverage: samples that contradicted the last pass
    std::vector<uint32_t> mTraced;   // coverage: lattice indices with a certificate this time
    std::vector<uint32_t> mAllTraced;  // coverage: every lattice index traced this time
    uint32_t mGeneration = 0;
};

/// One-shot convenience: a fresh ContourIntegrator per call.
Estimate contourIntegral(const Receiver& r, const RectLight& light, Occluder::Query& query,
                         const AciSettings& settings = {});

}  // namespace penumbra
