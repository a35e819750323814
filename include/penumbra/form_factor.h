/// @file form_factor.h
/// Closed forms for the form factor from a differential receiver area to a polygonal light.
///
/// Conventions (world space, scene units):
/// - A receiver is a point M with unit normal n. Vectors `c` passed to the edge functions are
///   relative to M (c = C - M).
/// - A polygon is oriented counterclockwise in the light's (u, v) parameter plane, i.e. in the
///   order corner, corner + edgeU, corner + edgeU + edgeV, corner + edgeV. Seen from the emitting
///   side (the side of edgeU x edgeV), that order is counterclockwise, and the form factor of such
///   a loop is positive. Reversing an edge negates its G vector exactly, so shared edges cancel.
/// - F = G . n with G = (1 / 2 pi) sum_i beta_i n_i   (Vedel 1993, eq. 4-7), where beta_i is the
///   angle between c_i and c_{i+1} and n_i the unit normal of the plane (M, C_i, C_{i+1}).
/// All functions are pure and thread-safe.
#pragma once

#include <string>
#include <vector>

#include "penumbra/math.h"

namespace penumbra {

/// A point on a receiving surface: position and unit normal, world space.
struct Receiver {
    Vec3 point;
    Vec3 normal;
};

/// The shape of a light's emitting surface.
enum class LightShape { Rect, Polygon, Disc };

/// A diffuse area light: a rectangle, a convex polygon or a disc, emitting on the side of
/// edgeU x edgeV (right-hand rule).
///
/// `corner`, `edgeU`, `edgeV` are the light itself for a rectangle, and for a polygon or a disc
/// a rectangle of the light's plane that holds it (its *frame*: the estimators' sampling grid,
/// made by polygonLight() and discLight()); the part of the frame outside the shape emits
/// nothing.
struct RectLight {
    std::string name;
    LightShape shape = LightShape::Rect;
    Vec3 corner{0.0};
    Vec3 edgeU{1.0, 0.0, 0.0};
    Vec3 edgeV{0.0, 1.0, 0.0};
    std::vector<Vec3> vertices;  ///< polygon: convex, counterclockwise seen from the emitting side
    Vec3 center{0.0};            ///< disc: its centre (its normal is normal())
    double radius = 0.0;         ///< disc: its radius
    Rgb radiance{1.0};

    Vec3 point(double u, double v) const { return corner + u * edgeU + v * edgeV; }
    /// The frame coordinates (u, v) of a point of the light's plane: point(u, v) == p (for a
    /// parallelogram frame too).
    Vec2 coordinates(const Vec3& p) const;
    Vec3 normal() const { return glm::normalize(glm::cross(edgeU, edgeV)); }
    /// The emitting area.
    double area() const;
    /// A rectangle or polygon: its corners, counterclockwise seen from the emitting side (the
    /// order corner, +edgeU, +edgeU+edgeV, +edgeV for a rectangle). A disc: its frame's four
    /// corners, a bound (see discBoundaryG() for its exact border).
    std::vector<Vec3> polygon() const;
    /// Whether a point of the light's plane lies on the emitting surface (its border included).
    bool contains(const Vec3& p) const;
};

/// A convex polygon light. Its frame: for a triangle, the parallelogram on its first two edges;
/// for a parallelogram, itself; otherwise the smallest rectangle along one of its edges that
/// holds it (the contour integrator integrates it on that frame, or, where the receiver's horizon
/// cuts it, as the fan of triangles of its part above, each in its own parallelogram). Throws std::invalid_argument naming the offending vertex (by index) when there are fewer
/// than 3 vertices, they are not on one plane (to 1e-6 of the polygon's size), or the polygon is
/// not convex and counterclockwise about the normal of its first corner that turns.
RectLight polygonLight(const std::vector<Vec3>& vertices);

/// A disc light of centre c, emitting along `normal`, radius r > 0; its frame is the square of
/// side 2r around it.
RectLight discLight(const Vec3& c, const Vec3& normal, double r);

/// A polygon light's edges that cut its frame (those not lying on the frame's border): each as
/// a point on it and the unit normal, in the light's plane, pointing into the polygon.
struct LightEdge {
    Vec3 origin;
    Vec3 inward;
};
std::vector<LightEdge> cuttingEdges(const RectLight& light);

/// Whether a polygon light's frame has the polygon's corners among its own (a triangle or a
/// parallelogram, see polygonLight()); false for other polygons, true for rectangles and discs.
bool frameHoldsCorners(const RectLight& light);

/// beta n_hat for the directed edge c0 -> c1 (both relative to M), without the 1/(2 pi) factor,
/// signed so that a counterclockwise loop (see file comment) gives a positive form factor.
/// Returns zero for degenerate edges (a zero vector, or c0 and c1 collinear with M).
Vec3 edgeG(const Vec3& c0, const Vec3& c1);

/// edgeG and its Jacobian with respect to the receiver position M when the edge's end points
/// stay fixed in space: dG.col(k) = d edgeG / d M_k. Smooth through the degenerate
/// (collinear) configuration, where the value is zero but the derivative is not; this is what
/// the radial "junction" edges of Fig. 5 need. (Vedel 1993, appendix eq. 8-10, in a form that
/// does not divide by |c0 x c1|.)
struct EdgeDerivative {
    Vec3 g{0.0};
    Mat3 dg{0.0};
};
EdgeDerivative edgeGWithDerivative(const Vec3& c0, const Vec3& c1);

/// Lambert's formula (Vedel 1993, eq. 4) for a closed polygon given in world space, oriented as
/// in the file comment. The polygon must lie on or above M's tangent plane; use clipToHorizon
/// first otherwise.
double polygonFormFactor(const std::vector<Vec3>& polygonWS, const Receiver& r);

/// G vector (already divided by 2 pi) of a closed world-space polygon: F = G . n.
Vec3 polygonG(const std::vector<Vec3>& polygonWS, const Vec3& m);

/// The part of a convex or concave planar polygon on the receiver's side of its tangent plane
/// ((P - M) . n >= 0), by Sutherland-Hodgman; keeps the orientation. May return fewer than 3
/// vertices (nothing above the horizon).
std::vector<Vec3> clipToHorizon(const std::vector<Vec3>& polygonWS, const Receiver& r);

/// The form factor's density at point p of a light of unit normal `lightNormal`, per unit of
/// the light's area: cos(theta_M) cos(theta_L) / (pi r^2); 0 below M's horizon or behind the
/// light. Its integral over the light is the unoccluded form factor.
double formFactorDensity(const Receiver& r, const Vec3& lightNormal, const Vec3& p);

/// Unoccluded form factor from (M, n) to the light, clipped by the tangent plane; zero when M is
/// behind the light (on the non-emitting side) or the light is wholly below the horizon.
double unoccludedFormFactor(const RectLight& light, const Receiver& r);

/// Unoccluded G (F = G . n) and its Jacobian with respect to M (n fixed), for the clipped
/// light. The clipped vertices are held fixed: their sliding only changes F to second order
/// because the cosine weight vanishes on the horizon. Without `derivative` a disc's Jacobian may
/// be left zero (its arc is then integrated in closed form; see discArcG).
struct GWithDerivative {
    Vec3 g{0.0};
    Mat3 dg{0.0};
};
GWithDerivative unoccludedG(const RectLight& light, const Receiver& r, bool derivative = true);

/// G (as edgeG: beta n_hat, without 1 / (2 pi)) of the arc of a disc light's circle from a to b,
/// both on it, counterclockwise about the light's normal (a full turn when a == b), seen from m,
/// with its Jacobian in m. Integrated on the exact circle, not on a polygon: without the
/// Jacobian (`derivative` false; dg is then zero) in closed form, else, and where the closed
/// form would lose digits (m near the disc's axis or its circle), by Gauss-Legendre, 16 nodes
/// per piece of at most 1/16 of a turn, split near m (converged to rounding off the circle).
EdgeDerivative discArcG(const RectLight& disc, const Vec3& a, const Vec3& b, const Vec3& m,
                        bool derivative = true);

/// Form factor of a strip of width `width` around the segment p0-p1 on the light, by the
/// elementary (differential area) form factor at the segment's midpoint: the uncertainty of a
/// contour segment whose end points are known to within `width` (Vedel 1993, section 3.2).
double stripFormFactor(const Receiver& r, const Vec3& lightNormal, const Vec3& p0, const Vec3& p1,
                       double width);

/// True when M lies strictly on the emitting side of the light's plane.
bool facesLight(const RectLight& light, const Vec3& m);

/// True when some of the light can reach the receiver: M faces the emitting side and a corner
/// of the light is above its tangent plane. Otherwise F = 0, with no ray needed.
bool lightReaches(const RectLight& light, const Receiver& r);

}  // namespace penumbra
