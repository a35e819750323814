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
#include "penumbra/render_settings.h"

namespace penumbra {



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
