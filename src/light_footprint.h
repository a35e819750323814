// Where on a light a shadow ray can meet the obstacles (certified coverage, docs/estimator.md):
// a segment from the ray origin M to light point Q that meets an obstacle meets its solid box
// and its solid sphere (Occluder::solidBounds, solidCentre, solidRadius), so Q lies in both
// their central projections from M onto the light's plane. Outside every obstacle's footprint a
// light point is visible, proven without a ray.
#pragma once

#include <cstdint>
#include <vector>

#include "penumbra/form_factor.h"
#include "penumbra/occluder.h"

namespace penumbra {

class LightFootprints {
public:
    /// The footprints, seen from `origin`, of the obstacles `only` lists (every obstacle of
    /// `occ` when null) on `light`. False, with none kept, when a solid box reaches level with
    /// or behind the origin (seen from the light; an obstacle the receiver sits on, say): its
    /// projection is unbounded.
    bool build(const Occluder& occ, const std::vector<uint32_t>* only, const Vec3& origin,
               const RectLight& light);
    /// Whether the rectangle [u0, u1] x [v0, v1] of the light's (u, v) coordinates lies outside
    /// every footprint (a margin far above rounding; a point when u0 = u1 and v0 = v1).
    bool outside(double u0, double v0, double u1, double v1) const;
    /// Whether the rectangle lies inside the projection of some obstacle's kernel (a ball or an
    /// analytic box that blocks every segment meeting it: Occluder::kernelBalls, kernelBox)
    /// lying wholly between the origin and the light's plane: every point of it is hidden.
    /// Kernels are kept whatever build() returned.
    bool hidden(double u0, double v0, double u1, double v1) const;
    /// outside() and hidden() in one: 1 when the rectangle lies outside every footprint, 0 when
    /// a kernel hides it, -1 when neither is proven (the rectangle's directions found once).
    int classify(double u0, double v0, double u1, double v1) const;
    /// A lower bound on the distance, in the light's plane (world units), from light point
    /// (u, v) to every footprint: every light point nearer than that is visible too. 0 when the
    /// point lies in some footprint, or none is bounded.
    double distance(double u, double v) const { return distance(pointAt(u, v)); }
    /// The narrowest footprint on the light: over the obstacles whose footprint's bounding box
    /// meets the light's rectangle, the smallest width of their footprint in the light's plane
    /// (world units): the box's projected hull's width, or the chord of the solid sphere's cone
    /// across its axis where that is smaller; for a level set, not more than its kernel balls'
    /// widest footprint (0 with none: a level set may be thin anywhere). `occ` is the occluder
    /// build() was given. An estimate of how small a shadow on the light can be, for choosing a
    /// lattice (AciSettings::adaptiveSteps), not a bound. Infinite when no footprint meets the
    /// light, negative when they are not bounded, except 0 when every obstacle whose footprint
    /// is unbounded (the origin on or beside it) is a level set too thin for kernel balls: a
    /// level set as thin anywhere as the bounded ones' rule assumes.
    double narrowestWidth(const Occluder& occ) const;
    /// The heaviest sliver a footprint cuts from the light: over the bounded footprints (their
    /// hull and their solid sphere's cone) that meet what the light emits, their overlap with
    /// it where that is narrower than `width` (world units, in the light's plane), and the
    /// emitting area past one of their edges where that reaches less than `width` past it; the
    /// largest form factor at `r` of these (0 when there is none). A footprint wide in itself
    /// may leave such a sliver of shadow or light at the light's border (a box's shadow
    /// reaching 2 units of 256 into a disc light along its rim), which a coarser lattice
    /// misses. Like narrowestWidth(), a guide for choosing a lattice, not a bound.
    double thinSliver(const Receiver& r, double width) const;
    /// The largest level-set voxel as the light sees it: over the bounded footprints that meet
    /// the light's rectangle and belong to level sets, the voxel times the origin's largest
    /// distance to the light's corners over its distance to the obstacle's solid box (an upper
    /// bound on how long a voxel looks on the light: a length l at the fraction t of a segment
    /// spans l / t at its end). 0 when there is none; infinite when the origin is in a box.
    double largestMagnifiedVoxel(const Occluder& occ) const;
    /// Whether the light's border runs between lattice points (a disc's circle, a polygon's
    /// cutting edge) rather than along lattice lines (a rectangle's or a parallelogram's frame).
    static bool borderOffLattice(const RectLight& light);
    /// A light point as distance() and hiddenAt() read it (found once for both): its
    /// coordinates in an orthonormal frame of the light's plane, and its offset from the origin
    /// (d; its length and direction).
    struct LightPoint {
        double x = 0.0, y = 0.0;
        Vec3 d{0.0};
        double dist = 0.0;
        Vec3 towards{0.0};
    };
    LightPoint pointAt(double u, double v) const;
    double distance(const LightPoint& lp) const;
    /// A light point hidden by one obstacle alone, as a traced ray would find it.
    struct Hidden {
        double radius = 0.0;    ///< every light point nearer is hidden too (world units); 0: none
        int obstacle = -1;      ///< the obstacle whose kernel hides it, the segment's first
        double fraction = 0.0;  ///< where the segment enters that kernel, origin 0, light 1
        /// Whether that is where it enters the obstacle (an analytic kernel is the obstacle
        /// itself); else the obstacle's surface lies somewhere before it.
        bool exact = false;
        double others = 0.0;    ///< every light point nearer lies outside the other footprints
    };
    /// Light point (u, v) inside the projection of an obstacle's kernel and outside every other
    /// obstacle's footprint: that obstacle blocks the segment to it, and nothing meets the
    /// segment before its kernel. Radius 0 when no kernel proves it, or the footprints are not
    /// bounded (another obstacle could meet the segment anywhere).
    Hidden hiddenAt(double u, double v) const { return hiddenAt(pointAt(u, v)); }
    Hidden hiddenAt(const LightPoint& lp) const;
private:
    // The rectangle's directions from the origin (directions()), found when first asked for.
    struct Spread {
        bool known = false;
        Vec3 towards{0.0};
        double cosReach = 1.0, sinReach = 0.0;
    };
    struct Footprint {
        double u[8], v[8];    // the box's projected hull, counter-clockwise
        double nu[8], nv[8];  // its edges' unit outward normals (zero for an edge of no length)
        int n = 0;
        double u0, v0, u1, v1;  // the hull's bounding box
        Vec3 axis;              // unit direction from the origin to the sphere's centre
        double spread;          // the sphere's angular radius from the origin (pi: all)
        double cosSpread, sinSpread;
        // The hull in an orthonormal frame of the light's plane (mPlaneX, mPlaneY from
        // mLight->corner), with its edges' unit outward normals there.
        double x[8], y[8], nx[8], ny[8];
        int obstacle = -1;
    };
    struct Kernel {
        bool ball = true;
        bool exact = true;  // the obstacle itself (analytic), not a ball inside a level set
        int obstacle = -1;
        Vec3 centre{0.0};     // a ball: its centre and radius
        double radius = 0.0;
        Box3 box;             // a box: itself
        double x[8], y[8], nx[8], ny[8];  // a box: its hull in the light plane's frame
        Vec3 axis{0.0};  // a ball: unit direction from the origin to its centre
        double spread = 0.0;  // its angular radius
        double cosSpread = 1.0, sinSpread = 0.0;
        double u[8], v[8];    // a box: its projected hull, counter-clockwise
        double nu[8], nv[8];  // its edges' unit outward normals
        int n = 0;
    };
    // What the light emits (its frame cut by its polygon or its circle) as a convex polygon in
    // the light plane's frame: a circle by an inscribed polygon.
    std::vector<Vec2> emittingPolygon() const;
    // The footprint's cone (its solid sphere's, from the origin) where it meets the light's
    // plane, by an inscribed polygon in the light plane's frame; empty when some of the cone's
    // rays miss the plane (the footprint is then the hull's).
    std::vector<Vec2> conePolygon(const Footprint& f) const;
    // The width on the light's plane of a cone from the origin (its unit axis and half-angle),
    // or of a ball's (infinite when the origin is inside it), as narrowestWidth() measures it.
    double chordAcross(const Vec3& axis, double spread) const;
    double ballWidth(const Vec3& centre, double radius) const;
    // A lower bound on the distance in the light's plane from the point to footprint f; 0
    // inside it.
    static double distanceTo(const Footprint& f, const LightPoint& lp);
    bool outsideAll(double u0, double v0, double u1, double v1, Spread& sp) const;
    bool hiddenBy(double u0, double v0, double u1, double v1, Spread& sp) const;
    bool inCone(const Footprint& f, double u0, double v0, double u1, double v1, Spread& sp) const;
    // The rectangle's directions from the origin: the one to its centre, and the cosine and
    // sine of the largest angle from it to a corner's (once per rectangle: sp.known).
    void directions(double u0, double v0, double u1, double v1, Spread& sp) const;
    // The hull of points (u[i], v[i]), i < 8, counter-clockwise into (hu, hv); its size.
    static int hull(const double u[8], const double v[8], double hu[8], double hv[8]);
    // The unit outward normals of the hull's n edges.
    static void normals(const double u[8], const double v[8], int n, double nu[8], double nv[8]);
    // The n light points (u[i], v[i]) in the light plane's orthonormal frame (mPlaneX, mPlaneY).
    void toPlane(const double u[8], const double v[8], int n, double x[8], double y[8]) const;

    std::vector<Footprint> mFootprints;
    std::vector<Kernel> mKernels;
    bool mBounded = false;
    bool mUnboundedThin = false;  // unbounded, and only by level sets without kernel balls
    const RectLight* mLight = nullptr;
    Vec3 mOrigin{0.0};
    double mToLight = 0.0;  // the origin's signed distance to the light's plane
    Vec3 mPlaneX{0.0}, mPlaneY{0.0};  // an orthonormal frame of the light's plane
};

}  // namespace penumbra
