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
#include <memory>
#include <string>
#include <vector>

#include "penumbra/estimator.h"
#include "penumbra/form_factor.h"
#include "penumbra/occluder.h"
#include "penumbra/render_settings.h"

namespace penumbra {

/// The first level ACI dices a light into: `a` squares along its first edge (edgeU), `b` along
/// its second. AciSettings::grid along the shorter edge; with AciSettings::aspectGrid the longer
/// edge gets that many times its length over the shorter's, rounded (at most 8 times), so that
/// the squares are about square and contour vertices are located as finely along one edge as
/// along the other.
struct FirstLevelGrid {
    int a = 0, b = 0;
    size_t corners() const { return static_cast<size_t>(a + 1) * (b + 1); }
    bool operator==(const FirstLevelGrid& o) const { return a == o.a && b == o.b; }
    bool operator!=(const FirstLevelGrid& o) const { return !(*this == o); }
};
FirstLevelGrid firstLevelGrid(const RectLight& light, const AciSettings& settings);

class ContourIntegrator {
public:
    explicit ContourIntegrator(const AciSettings& settings = {});
    const AciSettings& settings() const { return mSettings; }
    void setSettings(const AciSettings& s) { mSettings = s; }

    Estimate evaluate(const Receiver& r, const RectLight& light, Occluder::Query& query);

    /// Only the first-level pattern (the firstLevelGrid().corners() corner rays, row by row
    /// along edgeU), for shadow-pattern coherence.
    /// Adds the rays to `counts` (with reuseCorners, some corners may be answered by earlier
    /// rays: counts.reusedRays).
    std::vector<uint8_t> pattern(const Receiver& r, const RectLight& light, Occluder::Query& query,
                                 AciCounts& counts);

    /// Forgets the first-level rays kept for reuseCorners.
    void forgetCorners();

    /// While on, each evaluate() keeps the contour it integrated (every weighted edge of the
    /// visible part's boundary, projected from the receiver point onto the light's plane) in
    /// place of what was kept, for visibleWithin(); while off, what was kept stays.
    void recordContour(bool on);

    /// The vector G of eq. 5 (divided by 2 pi, as Estimate::g) of the visible part of the light
    /// within the rectangle [u0, u1] x [v0, v1] of `light`'s coordinates, from the contour the
    /// last evaluate() of `light` at `r` located and kept (recordContour), without a ray: the
    /// kept edges inside the rectangle plus the rectangle's border weighted by how much of it
    /// the contour says is visible (its weighted winding number, counted along the border).
    /// The sum over a partition of the light is the evaluation's own G. W differs from the
    /// exact visibility only where the evaluation's bound counts (its strips, triangles and
    /// uncovered cells), by at most contourWeightFactor(): the parts' errors together are
    /// within that factor times the bound. False (G untouched) when nothing was kept, the
    /// contour holds a disc's arcs, the rectangle reaches below the receiver's horizon, or the
    /// winding number does not come back to its start around the rectangle (a contour that
    /// does not close): the caller integrates the part on its own then.
    bool visibleWithin(const Receiver& r, const RectLight& light, double u0, double v0, double u1,
                       double v1, Vec3& g) const;

    /// The most the kept contour's winding number can differ from a visibility (0 or 1) where
    /// it is not one: max(1, |w|, |1 - w|) over its edges' weights w.
    double contourWeightFactor() const;

    ContourIntegrator(const ContourIntegrator& other);
    ContourIntegrator& operator=(const ContourIntegrator& other);
    ContourIntegrator(ContourIntegrator&&) noexcept;
    ContourIntegrator& operator=(ContourIntegrator&&) noexcept;
    ~ContourIntegrator();

private:
    struct Lattice;  // one evaluation (src/contour_lattice.h, members in src/contour_*.cpp)
    struct Scratch;  // the sample lattice, coverage state and kept corners (src/contour_lattice.h)
    AciSettings mSettings;
    std::unique_ptr<Scratch> mScratch;
    /// The sum of evaluate() over pieces of one light (a polygon's fan of triangles, a disc's
    /// part above the horizon), each integrated as it is.
    Estimate evaluatePieces(const Receiver& r, const std::vector<RectLight>& pieces, Occluder::Query& query);
    bool mFanPiece = false;  // evaluating one piece of a polygon or disc light (no second clip)
    /// recordContour: one weighted contour edge on the light's plane.
    struct ContourEdge {
        Vec3 a, b;
        double weight;
    };
    bool mRecord = false;
    bool mContourValid = false;  // what mContour holds can answer visibleWithin()
    std::vector<ContourEdge> mContour;  // the last evaluate()'s, over all its pieces
    /// Appends the finished lattice's edges to mContour (evaluate()'s returns).
    void keepContour();
};

/// One-shot convenience: a fresh ContourIntegrator per call.
Estimate contourIntegral(const Receiver& r, const RectLight& light, Occluder::Query& query,
                         const AciSettings& settings = {});

}  // namespace penumbra
