/// @file exact_shadow.h
/// Independent reference values for tests: catalogued closed-form form factors, exact form
/// factors of a rectangular light partly hidden by a sphere, by a convex polyhedron or by
/// several of them with overlapping shadows, and a brute-force midpoint-rule quadrature.
///
/// Deliberately independent of the library: nothing here calls form_factor.h or any estimator,
/// so a test that sets the library against these values compares two separate derivations.
/// All positions are world space; a receiver is a point M with unit normal n; a light is the
/// parallelogram corner + s edgeU + t edgeV, (s, t) in [0, 1]^2, emitting on the side of
/// edgeU x edgeV. Misuse (a configuration outside a function's stated domain) throws
/// std::invalid_argument, also in Release builds, so a test cannot silently compare against a
/// reference that does not apply.
#pragma once

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include "penumbra/math.h"

namespace penumbra::exact {

constexpr double kTwoPi = 2.0 * kPi;

inline void require(bool ok, const char* what) {
    if (!ok) throw std::invalid_argument(std::string("penumbra::exact: ") + what);
}

// ---------------------------------------------------------------------------------------------
// Catalogued closed forms (Howell, "A Catalog of Radiation Heat Transfer Configuration Factors";
// Siegel & Howell, "Thermal Radiation Heat Transfer", differential-element-to-rectangle cases).

/// Element at the origin with normal +z; rectangle in the parallel plane z = c covering
/// 0 <= x <= a, 0 <= y <= b, so the element's normal passes through a corner (Howell B-3,
/// listed as C-11 in older editions). With A = a/c, B = b/c:
///   F = 1/(2 pi) [ A/sqrt(1+A^2) atan(B/sqrt(1+A^2)) + B/sqrt(1+B^2) atan(A/sqrt(1+B^2)) ].
/// Odd in a and in b, so signed extents give rectangles on the other side of the normal, which
/// makes it the building block for any axis-aligned parallel rectangle by superposition.
inline double parallelRectCornerAbove(double a, double b, double c) {
    require(c > 0.0, "parallelRectCornerAbove: c must be > 0");
    const double A = a / c;
    const double B = b / c;
    const double sa = std::sqrt(1.0 + A * A);
    const double sb = std::sqrt(1.0 + B * B);
    return (A / sa * std::atan(B / sa) + B / sb * std::atan(A / sb)) / kTwoPi;
}

/// Element at the origin with normal +z; rectangle in the perpendicular plane x = c covering
/// 0 <= y <= a, 0 <= z <= b. The rectangle's edge of length a lies in the element's plane
/// (z = 0) and the element sits on the rectangle's normal through a corner, at distance c
/// (Howell B-2 style "element to perpendicular rectangle"). With X = b/a, Y = c/a:
///   F = 1/(2 pi) [ atan(1/Y) - Y/sqrt(X^2+Y^2) atan(1/sqrt(X^2+Y^2)) ].
/// Also odd in a (mirror y -> -y); b must be >= 0 (the rectangle must stay above the horizon).
inline double perpendicularRectCorner(double a, double b, double c) {
    require(c > 0.0, "perpendicularRectCorner: c must be > 0");
    require(b >= 0.0, "perpendicularRectCorner: b must be >= 0 (above the horizon)");
    const double bc = std::sqrt(b * b + c * c);
    return (std::atan(a / c) - c / bc * std::atan(a / bc)) / kTwoPi;
}

// ---------------------------------------------------------------------------------------------
// Small geometric helpers (own implementations, not the library's).

/// Angle between two nonzero vectors, accurate also for nearly parallel ones.
inline double angleBetween(const Vec3& a, const Vec3& b) {
    return std::atan2(glm::length(glm::cross(a, b)), glm::dot(a, b));
}

/// Lambert's formula (Vedel 1993, eq. 4) for a planar polygon listed counterclockwise as seen
/// from the side M is on (M on the emitting side of a light polygon in (s, t) counterclockwise
/// order). Every vertex must be on or above M's tangent plane.
inline double lambertPolygon(const std::vector<Vec3>& poly, const Vec3& m, const Vec3& n) {
    if (poly.size() < 3) return 0.0;
    double sum = 0.0;
    for (size_t i = 0; i < poly.size(); ++i) {
        const Vec3 c0 = poly[i] - m;
        const Vec3 c1 = poly[(i + 1) % poly.size()] - m;
        require(glm::dot(c0, n) >= -1e-12 * glm::length(c0),
                "lambertPolygon: vertex below the receiver's horizon");
        const Vec3 w = glm::cross(c1, c0);  // this order makes the loop's sum positive
        const double len = glm::length(w);
        if (len == 0.0) continue;  // collinear with M: no contribution
        sum += angleBetween(c0, c1) * glm::dot(w, n) / len;
    }
    return sum / kTwoPi;
}

/// The rotation by `angle` radians about `axis` (any nonzero length), by Rodrigues' formula.
inline Mat3 rotation(const Vec3& axis, double angle) {
    const Vec3 k = glm::normalize(axis);
    const double c = std::cos(angle), s = std::sin(angle);
    Mat3 r(0.0);
    for (int j = 0; j < 3; ++j) {
        Vec3 e(0.0);
        e[j] = 1.0;
        // Rodrigues' formula applied to the basis vector e_j gives column j.
        r[j] = e * c + glm::cross(k, e) * s + k * glm::dot(k, e) * (1.0 - c);
    }
    return r;
}

/// Affine coordinates (s, t) of a point of the light's plane: p = corner + s edgeU + t edgeV.
inline Vec2 lightCoords(const Vec3& p, const Vec3& corner, const Vec3& edgeU, const Vec3& edgeV) {
    const Vec3 d = p - corner;
    const double uu = glm::dot(edgeU, edgeU), uv = glm::dot(edgeU, edgeV);
    const double vv = glm::dot(edgeV, edgeV);
    const double du = glm::dot(d, edgeU), dv = glm::dot(d, edgeV);
    const double det = uu * vv - uv * uv;
    return Vec2((du * vv - dv * uv) / det, (dv * uu - du * uv) / det);
}

/// The light's four corners counterclockwise in (s, t).
inline std::vector<Vec3> lightPolygon(const Vec3& corner, const Vec3& edgeU, const Vec3& edgeV) {
    return {corner, corner + edgeU, corner + edgeU + edgeV, corner + edgeV};
}

/// Checks shared by the exact shadow references: the light emits toward M and lies wholly on
/// or above M's horizon, so no clipping is involved in the exact answers.
inline void requireLightAboveHorizon(const Vec3& m, const Vec3& n, const Vec3& corner,
                                     const Vec3& edgeU, const Vec3& edgeV) {
    require(glm::dot(m - corner, glm::cross(edgeU, edgeV)) > 0.0,
            "light does not emit toward the receiver");
    for (const Vec3& p : lightPolygon(corner, edgeU, edgeV))
        require(glm::dot(p - m, n) >= 0.0, "light is not wholly above the receiver's horizon");
}

// ---------------------------------------------------------------------------------------------
// Sphere shadow.

/// Roots in [0, 2 pi) of A + B cos x + C sin x = 0 (closed form, one Newton polish step).
/// Tangencies (|A| >= hypot(B, C)) return no root: they bound a set of measure zero.
inline void trigRoots(double A, double B, double C, std::vector<double>& out) {
    const double rho = std::hypot(B, C);
    if (!(std::abs(A) < rho)) return;
    const double phi = std::atan2(C, B);
    const double delta = std::acos(-A / rho);
    for (double x : {phi + delta, phi - delta}) {
        const double dg = -B * std::sin(x) + C * std::cos(x);
        if (dg != 0.0) x -= (A + B * std::cos(x) + C * std::sin(x)) / dg;
        x = std::fmod(x, kTwoPi);
        if (x < 0.0) x += kTwoPi;
        out.push_back(x);
    }
}

/// Exact form factor from (M, n) to the light minus the part hidden by the sphere (center,
/// radius). Requirements (checked): the light emits toward M and is wholly above M's horizon;
/// M is outside the sphere; the sphere lies strictly on M's side of the light's plane, so every
/// ray from M that meets both the sphere and the light meets the sphere first.
///
/// Method: on the unit sphere of directions around M the light is a convex spherical
/// quadrilateral Q and the sphere hides the cap K (axis a = (C - M)/|C - M|, half-angle
/// alpha = asin(R/|C - M|)). F = F(Q) - F(Q n K), and for any region Omega
///   F(Omega) = 1/(2 pi) * loop integral over the boundary of Omega of (d x dd) . n
/// (Stokes; the same identity gives Lambert's formula). The boundary of Q n K consists of
///  - arcs of K's circle inside Q: d(t) = cos(alpha) a + sin(alpha)(cos t e1 + sin t e2), where
///    (d x d') = sin^2(alpha) a - sin(alpha) cos(alpha)(cos t e1 + sin t e2) integrates in
///    closed form between crossing angles;
///  - pieces of Q's great-circle edges inside K, each contributing (arc angle) * m_i . n with
///    m_i the unit normal of the edge's great circle.
/// Crossing angles are roots of A + B cos x + C sin x (closed form); each sub-arc between
/// consecutive roots is classified by its midpoint. This covers the cap inside Q (full circle,
/// no edge pieces), Q inside the cap (full edges, no circle arcs) and disjoint sets uniformly.
/// The same for a convex planar polygon light (vertices counterclockwise seen from the side it
/// emits to, which M must be on; every vertex on or above M's horizon): the spherical polygon Q
/// has any number of edges.
inline double polygonSphereShadowFormFactor(const Vec3& m, const Vec3& n, const std::vector<Vec3>& poly,
                                            const Vec3& sphereCenter, double radius) {
    const size_t count = poly.size();
    require(count >= 3, "polygonSphereShadowFormFactor: fewer than 3 vertices");
    const Vec3 lightNormal =
        glm::normalize(glm::cross(poly[1] - poly[0], poly[2] - poly[0]));  // toward M
    require(glm::dot(m - poly[0], lightNormal) > 0.0, "light does not emit toward the receiver");
    for (const Vec3& p : poly)
        require(glm::dot(p - m, n) >= 0.0, "light is not wholly above the receiver's horizon");
    require(radius > 0.0, "sphereShadowFormFactor: radius must be > 0");
    const Vec3 toCenter = sphereCenter - m;
    const double dist = glm::length(toCenter);
    require(dist > radius, "sphereShadowFormFactor: M is inside the sphere");
    require(glm::dot(sphereCenter - poly[0], lightNormal) > radius,
            "sphereShadowFormFactor: the sphere is not wholly on M's side of the light plane");

    // Directions of the light's corners, ordered so that Q lies to the left of each edge seen
    // from outside the unit sphere (positive orientation for Stokes): the reverse of the
    // polygon's order, since M sees the light from its emitting side.
    std::vector<Vec3> q;
    for (size_t i = 0; i < count; ++i) q.push_back(glm::normalize(poly[count - 1 - i] - m));
    require(glm::dot(glm::cross(q[0], q[1]), q[2]) > 0.0,
            "sphereShadowFormFactor: degenerate light seen edge-on");
    std::vector<Vec3> edgeNormal(count);
    std::vector<double> edgeAngle(count);
    for (size_t i = 0; i < count; ++i) {
        edgeNormal[i] = glm::normalize(glm::cross(q[i], q[(i + 1) % count]));
        edgeAngle[i] = angleBetween(q[i], q[(i + 1) % count]);
    }
    auto insideQ = [&](const Vec3& d) {
        for (size_t i = 0; i < count; ++i)
            if (glm::dot(edgeNormal[i], d) < 0.0) return false;
        return true;
    };

    double unoccluded = 0.0;
    for (size_t i = 0; i < count; ++i) unoccluded += edgeAngle[i] * glm::dot(edgeNormal[i], n);

    const Vec3 a = toCenter / dist;
    const double sinAlpha = radius / dist;
    const double cosAlpha = std::sqrt((1.0 - sinAlpha) * (1.0 + sinAlpha));
    const Vec3 helper = std::abs(a.x) < 0.6 ? Vec3(1, 0, 0) : Vec3(0, 1, 0);
    const Vec3 e1 = glm::normalize(glm::cross(helper, a));
    const Vec3 e2 = glm::cross(a, e1);  // e1 x e2 = a: increasing t circles the cap positively
    auto capPoint = [&](double t) {
        return cosAlpha * a + sinAlpha * (std::cos(t) * e1 + std::sin(t) * e2);
    };

    double hidden = 0.0;
    // Circle arcs inside Q.
    std::vector<double> cuts;
    for (size_t i = 0; i < count; ++i) {
        const Vec3& mi = edgeNormal[i];
        trigRoots(cosAlpha * glm::dot(mi, a), sinAlpha * glm::dot(mi, e1),
                  sinAlpha * glm::dot(mi, e2), cuts);
    }
    std::sort(cuts.begin(), cuts.end());
    if (cuts.empty()) cuts.push_back(0.0);
    for (size_t k = 0; k < cuts.size(); ++k) {
        const double t0 = cuts[k];
        const double t1 = k + 1 < cuts.size() ? cuts[k + 1] : cuts[0] + kTwoPi;
        if (t1 <= t0) continue;
        if (!insideQ(capPoint(0.5 * (t0 + t1)))) continue;
        const Vec3 integral =
            sinAlpha * sinAlpha * (t1 - t0) * a -
            sinAlpha * cosAlpha *
                ((std::sin(t1) - std::sin(t0)) * e1 + (std::cos(t0) - std::cos(t1)) * e2);
        hidden += glm::dot(integral, n);
    }
    // Great-circle edge pieces inside the cap: p(s) = q_i cos s + w sin s, s in [0, beta_i].
    for (size_t i = 0; i < count; ++i) {
        const Vec3 w = glm::cross(edgeNormal[i], q[i]);  // unit, toward q_{i+1}
        std::vector<double> s;
        trigRoots(-cosAlpha, glm::dot(a, q[i]), glm::dot(a, w), s);
        std::vector<double> breaks{0.0};
        for (double x : s)
            if (x > 0.0 && x < edgeAngle[i]) breaks.push_back(x);
        breaks.push_back(edgeAngle[i]);
        std::sort(breaks.begin(), breaks.end());
        for (size_t k = 0; k + 1 < breaks.size(); ++k) {
            const double mid = 0.5 * (breaks[k] + breaks[k + 1]);
            const Vec3 p = q[i] * std::cos(mid) + w * std::sin(mid);
            if (glm::dot(p, a) >= cosAlpha)
                hidden += (breaks[k + 1] - breaks[k]) * glm::dot(edgeNormal[i], n);
        }
    }
    return (unoccluded - hidden) / kTwoPi;
}

/// The rectangle's case (see above), through the polygon's.
inline double sphereShadowFormFactor(const Vec3& m, const Vec3& n, const Vec3& corner,
                                     const Vec3& edgeU, const Vec3& edgeV, const Vec3& sphereCenter,
                                     double radius) {
    requireLightAboveHorizon(m, n, corner, edgeU, edgeV);
    return polygonSphereShadowFormFactor(m, n, lightPolygon(corner, edgeU, edgeV), sphereCenter,
                                         radius);
}

/// True when the open segment M-P misses the (closed) ball.
inline bool segmentMissesSphere(const Vec3& m, const Vec3& p, const Vec3& center, double radius) {
    const Vec3 d = p - m;
    const double t = std::clamp(glm::dot(center - m, d) / glm::dot(d, d), 0.0, 1.0);
    const Vec3 closest = m + t * d;
    return glm::dot(closest - center, closest - center) > radius * radius;
}

// ---------------------------------------------------------------------------------------------
// Convex polyhedron shadow.

/// Counterclockwise convex hull of 2D points (Andrew's monotone chain), collinear points
/// dropped.
inline std::vector<Vec2> convexHull2(std::vector<Vec2> pts) {
    std::sort(pts.begin(), pts.end(),
              [](const Vec2& a, const Vec2& b) { return a.x < b.x || (a.x == b.x && a.y < b.y); });
    if (pts.size() < 3) return pts;
    auto cross = [](const Vec2& o, const Vec2& a, const Vec2& b) {
        return (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x);
    };
    std::vector<Vec2> hull(2 * pts.size());
    size_t k = 0;
    for (size_t i = 0; i < pts.size(); ++i) {
        while (k >= 2 && cross(hull[k - 2], hull[k - 1], pts[i]) <= 0.0) --k;
        hull[k++] = pts[i];
    }
    for (size_t i = pts.size() - 1, lower = k + 1; i-- > 0;) {
        while (k >= lower && cross(hull[k - 2], hull[k - 1], pts[i]) <= 0.0) --k;
        hull[k++] = pts[i];
    }
    hull.resize(k - 1);
    return hull;
}

/// Keeps the part of a counterclockwise convex polygon where dot(normal, p) <= offset
/// (Sutherland-Hodgman against one half-plane).
inline std::vector<Vec2> clipHalfPlane(const std::vector<Vec2>& poly, const Vec2& normal,
                                       double offset) {
    std::vector<Vec2> out;
    for (size_t i = 0; i < poly.size(); ++i) {
        const Vec2& p0 = poly[i];
        const Vec2& p1 = poly[(i + 1) % poly.size()];
        const double d0 = glm::dot(normal, p0) - offset;
        const double d1 = glm::dot(normal, p1) - offset;
        if (d0 <= 0.0) out.push_back(p0);
        if ((d0 < 0.0 && d1 > 0.0) || (d0 > 0.0 && d1 < 0.0))
            out.push_back(p0 + (d0 / (d0 - d1)) * (p1 - p0));
    }
    return out;
}

/// The hull of the polyhedron's vertices projected from M onto the light's plane, in the
/// light's (s, t) coordinates, counterclockwise. Every vertex must lie strictly between M and
/// the light's plane.
inline std::vector<Vec2> projectedHull(const Vec3& m, const Vec3& corner, const Vec3& edgeU,
                                       const Vec3& edgeV, const std::vector<Vec3>& vertices) {
    const Vec3 lightNormal = glm::cross(edgeU, edgeV);
    const double hM = glm::dot(m - corner, lightNormal);
    std::vector<Vec2> st;
    for (const Vec3& v : vertices) {
        const double hV = glm::dot(v - corner, lightNormal);
        require(hV > 0.0 && hV < hM,
                "convex polyhedron vertex not strictly between M and the light's plane");
        const Vec3 p = m + (hM / (hM - hV)) * (v - m);  // ray M->v meets the plane
        st.push_back(lightCoords(p, corner, edgeU, edgeV));
    }
    return convexHull2(st);
}

/// Exact form factor from (M, n) to the light minus the part hidden by the convex polyhedron
/// with the given vertices: project every vertex from M onto the light's plane, take the 2D
/// convex hull (the shadow of a convex body seen from M), clip it against the light
/// (convex-convex clip, in (s, t) where the light is the unit square) and subtract its form
/// factor by Lambert's formula (Vedel 1993, eq. 4). Requirements (checked): the light emits
/// toward M and is wholly above the horizon; every vertex lies strictly between M and the
/// light's plane.
inline double convexPolyhedronShadowFormFactor(const Vec3& m, const Vec3& n, const Vec3& corner,
                                               const Vec3& edgeU, const Vec3& edgeV,
                                               const std::vector<Vec3>& vertices) {
    requireLightAboveHorizon(m, n, corner, edgeU, edgeV);
    std::vector<Vec2> shadow = projectedHull(m, corner, edgeU, edgeV, vertices);
    shadow = clipHalfPlane(shadow, Vec2(-1, 0), 0.0);
    shadow = clipHalfPlane(shadow, Vec2(1, 0), 1.0);
    shadow = clipHalfPlane(shadow, Vec2(0, -1), 0.0);
    shadow = clipHalfPlane(shadow, Vec2(0, 1), 1.0);
    std::vector<Vec3> shadow3;
    for (const Vec2& p : shadow) shadow3.push_back(corner + p.x * edgeU + p.y * edgeV);
    return lambertPolygon(lightPolygon(corner, edgeU, edgeV), m, n) - lambertPolygon(shadow3, m, n);
}

/// Convex polyhedron as an intersection of half-spaces, built from its vertices by brute force
/// (every vertex triple whose plane has all vertices on one side is a face plane): a
/// visibility test for numericFormFactor that shares nothing with the projection method.
class ConvexPolyhedron {
  public:
    explicit ConvexPolyhedron(const std::vector<Vec3>& vertices) {
        const size_t nv = vertices.size();
        double scale = 0.0;
        for (const Vec3& v : vertices) scale = std::max(scale, glm::length(v - vertices[0]));
        const double tol = 1e-12 * scale;
        for (size_t i = 0; i < nv; ++i)
            for (size_t j = i + 1; j < nv; ++j)
                for (size_t k = j + 1; k < nv; ++k) {
                    Vec3 normal = glm::cross(vertices[j] - vertices[i], vertices[k] - vertices[i]);
                    const double len = glm::length(normal);
                    if (len <= tol * scale) continue;
                    normal /= len;
                    int above = 0, below = 0;
                    for (const Vec3& v : vertices) {
                        const double d = glm::dot(normal, v - vertices[i]);
                        above += d > tol;
                        below += d < -tol;
                    }
                    if (above > 0 && below > 0) continue;
                    if (above > 0) normal = -normal;  // outward
                    mNormals.push_back(normal);
                    mOffsets.push_back(glm::dot(normal, vertices[i]));
                }
        require(mNormals.size() >= 4, "ConvexPolyhedron: degenerate (flat) vertex set");
    }

    /// True when the segment M-P meets the polyhedron's interior (Cyrus-Beck clipping).
    bool blocks(const Vec3& m, const Vec3& p) const {
        const Vec3 d = p - m;
        double t0 = 0.0, t1 = 1.0;
        for (size_t f = 0; f < mNormals.size(); ++f) {
            const double num = mOffsets[f] - glm::dot(mNormals[f], m);  // >0: M inside plane
            const double den = glm::dot(mNormals[f], d);
            if (den == 0.0) {
                if (num <= 0.0) return false;
            } else if (den > 0.0) {
                t1 = std::min(t1, num / den);
            } else {
                t0 = std::max(t0, num / den);
            }
            if (t0 >= t1) return false;
        }
        return true;
    }

    /// Distance from an interior point to the nearest face plane (the largest ball around the
    /// point inside the polyhedron).
    double inradius(const Vec3& point) const {
        double r = 1e300;
        for (size_t f = 0; f < mNormals.size(); ++f)
            r = std::min(r, mOffsets[f] - glm::dot(mNormals[f], point));
        return r;
    }

  private:
    std::vector<Vec3> mNormals;
    std::vector<double> mOffsets;
};

// ---------------------------------------------------------------------------------------------
// Several obstacles: spheres and convex polyhedra, overlapping shadows.

/// A sphere obstacle for rectMinusObstacles.
struct SphereObstacle {
    Vec3 center;
    double radius = 0.0;
};

/// A convex polyhedron obstacle for rectMinusObstacles: the convex hull of `vertices`
/// (vertices inside the hull are allowed and ignored).
struct ConvexObstacle {
    std::vector<Vec3> vertices;

    /// The axis-aligned box [lo, hi] (its eight corners).
    static ConvexObstacle box(const Vec3& lo, const Vec3& hi) {
        ConvexObstacle b;
        for (int i = 0; i < 8; ++i)
            b.vertices.emplace_back((i & 1) ? hi.x : lo.x, (i & 2) ? hi.y : lo.y,
                                    (i & 4) ? hi.z : lo.z);
        return b;
    }
};

namespace detail {

/// Great-circle arc p(s) = u cos s + w sin s, s in [0, length], on the great circle with unit
/// normal `normal` = u x w. As a piece of a region's boundary, the region is on its left seen
/// from outside the unit sphere, i.e. where dot(normal, d) > 0.
struct GreatArc {
    Vec3 u, w, normal;
    double length = 0.0;
    Vec3 at(double s) const { return u * std::cos(s) + w * std::sin(s); }
};

inline GreatArc greatArc(const Vec3& from, const Vec3& to) {
    GreatArc arc;
    arc.u = from;
    arc.normal = glm::normalize(glm::cross(from, to));
    arc.w = glm::cross(arc.normal, from);  // unit, toward `to`
    arc.length = angleBetween(from, to);
    return arc;
}

/// A region of the unit sphere of directions around M: a spherical cap (boundary: the small
/// circle d(t) = cosA axis + sinA (cos t e1 + sin t e2), e1 x e2 = axis, so increasing t runs
/// positively around the cap) or a convex spherical polygon (great-circle arcs in positive
/// order, the region on their left).
struct DirRegion {
    bool isCap = false;
    Vec3 axis, e1, e2;
    double cosA = 0.0, sinA = 0.0;
    std::vector<GreatArc> arcs;

    Vec3 capPoint(double t) const {
        return cosA * axis + sinA * (std::cos(t) * e1 + std::sin(t) * e2);
    }
    /// > 0 strictly inside, < 0 strictly outside, 0 on the boundary (not a distance, only its
    /// sign and its vanishing matter).
    double depth(const Vec3& d) const {
        if (isCap) return glm::dot(d, axis) - cosA;
        double inner = 1e300;
        for (const GreatArc& a : arcs) inner = std::min(inner, glm::dot(a.normal, d));
        return inner;
    }
};

inline DirRegion capRegion(const Vec3& axis, double sinA) {
    DirRegion r;
    r.isCap = true;
    r.axis = axis;
    r.sinA = sinA;
    r.cosA = std::sqrt((1.0 - sinA) * (1.0 + sinA));
    const Vec3 helper = std::abs(axis.x) < 0.6 ? Vec3(1, 0, 0) : Vec3(0, 1, 0);
    r.e1 = glm::normalize(glm::cross(helper, axis));
    r.e2 = glm::cross(axis, r.e1);
    return r;
}

/// Convex spherical polygon from its vertex directions in positive order.
inline DirRegion polygonRegion(const std::vector<Vec3>& dirs) {
    DirRegion r;
    for (size_t i = 0; i < dirs.size(); ++i)
        r.arcs.push_back(greatArc(dirs[i], dirs[(i + 1) % dirs.size()]));
    return r;
}

/// Where a piece of one region's boundary lies relative to another region.
enum class Relation {
    In,          ///< inside the other region
    Out,         ///< outside it
    OnSame,      ///< on its boundary, both regions on the same side of the piece
    OnOpposite,  ///< on its boundary, the regions on opposite sides
};

/// |n1 x n2| below which two great circles count as one, and |depth| below which a piece
/// lying along such a circle (or along an identical cap) counts as on the other region's
/// boundary. Unit vectors carry ~1e-16 rounding; counting curves 1e-9 apart as one errs by
/// at most the thin region between them.
constexpr double kSameCircle = 1e-9;
constexpr double kOnBoundary = 1e-9;

/// Relation of a boundary piece of region `own` (sampled at `samples`; `arc` is the piece's
/// great-circle arc, nullptr for a piece of own's cap circle) to region `other`. The sign of
/// other's depth is constant along the piece (it is split at every crossing), so the sample
/// farthest from other's boundary decides (a tangency at one sample cannot mislead it). Only
/// a piece coincident with other's boundary (every sample on it, and a great circle or cap
/// in common) is "on" it; then the orientations decide.
inline Relation relation(const std::vector<Vec3>& samples, const DirRegion& own,
                         const GreatArc* arc, const DirRegion& other) {
    double best = 0.0;
    for (const Vec3& d : samples) {
        const double x = other.depth(d);
        if (std::abs(x) > std::abs(best)) best = x;
    }
    if (std::abs(best) > kOnBoundary) return best > 0.0 ? Relation::In : Relation::Out;
    if (arc != nullptr && !other.isCap) {
        for (const GreatArc& a : other.arcs)
            if (glm::length(glm::cross(arc->normal, a.normal)) < kSameCircle)
                return glm::dot(arc->normal, a.normal) > 0.0 ? Relation::OnSame
                                                             : Relation::OnOpposite;
    }
    if (arc == nullptr && other.isCap && glm::length(own.axis - other.axis) < kSameCircle &&
        std::abs(own.cosA - other.cosA) < kSameCircle)
        return Relation::OnSame;
    return best >= 0.0 ? Relation::In : Relation::Out;
}

/// Whether a boundary piece of region `g` (0: the light Q; >= 1: a hidden region) is a piece
/// of the boundary of the visible set Q minus the union of the hidden regions, counted once.
/// Q's pieces: not inside a hidden region, and not on a hidden region's boundary with that
/// region on Q's side. A hidden region's pieces: strictly inside Q (on Q's boundary, Q's own
/// piece is counted when it bounds the visible set), not inside another hidden region, not on
/// another's boundary with that region on the other side; where several hidden regions share
/// the piece on the same side, the lowest index counts it.
inline bool boundsVisible(size_t g, const std::vector<Vec3>& samples,
                          const std::vector<DirRegion>& regions, const GreatArc* arc) {
    for (size_t k = 0; k < regions.size(); ++k) {
        if (k == g) continue;
        const Relation r = relation(samples, regions[g], arc, regions[k]);
        if (g == 0) {
            if (r == Relation::In || r == Relation::OnSame) return false;
        } else if (k == 0) {
            if (r != Relation::In) return false;
        } else if (r == Relation::In || r == Relation::OnOpposite ||
                   (r == Relation::OnSame && k < g)) {
            return false;
        }
    }
    return true;
}

}  // namespace detail

/// Exact form factor from (M, n) to the light minus the part hidden by several obstacles:
/// spheres and convex polyhedra (ConvexObstacle::box for axis-aligned boxes), in any number,
/// whose shadows may overlap each other, nest or straddle the light's border, and which may
/// overlap each other in 3D. Requirements (checked): the light emits toward M and is wholly
/// above M's horizon; every sphere has radius > 0, does not contain M and lies strictly on
/// M's side of the light's plane; every polyhedron vertex lies strictly between M and the
/// light's plane (so M is outside it). Hence every ray from M that meets an obstacle and the
/// light meets the obstacle first, and the hidden directions are those of the obstacles.
///
/// Method: on the unit sphere of directions around M the light is the convex spherical
/// quadrilateral Q, a sphere hides a cap and a convex polyhedron a convex spherical polygon
/// (the hull of its vertices' directions, from projectedHull). The visible set is
/// V = Q minus the union of the hidden regions H_j, and, as in sphereShadowFormFactor,
///   F = 1/(2 pi) * loop integral over the boundary of V of (d x dd) . n.
/// That boundary is made of the pieces of Q's edges outside every H_j (run along Q's positive
/// orientation) and the pieces of each H_j's boundary inside Q and outside every other H_k
/// (run against H_j's orientation). Every boundary curve (Q's and the polygons' great-circle
/// arcs, the caps' small circles) is split at its crossings with every other region's curves
/// (circle / circle and circle / great circle: roots of A + B cos x + C sin x in closed form;
/// great circle / great circle: +-(m1 x m2); where two arcs lie on one great circle, at the
/// other's endpoints; each crossing is computed once and splits both curves at the same
/// point), each piece is classified by sample points (see detail::relation and
/// detail::boundsVisible, which also count once a piece shared by several regions: identical
/// obstacles, polyhedron faces edge-on to M in a common plane) and integrated in closed form:
/// (arc angle) * m . n for a great-circle arc of unit normal m, the cap formula of
/// sphereShadowFormFactor for a small-circle arc. With one obstacle this is the same quantity
/// as sphereShadowFormFactor or convexPolyhedronShadowFormFactor.
inline double rectMinusObstacles(const Vec3& m, const Vec3& n, const Vec3& corner,
                                 const Vec3& edgeU, const Vec3& edgeV,
                                 const std::vector<SphereObstacle>& spheres,
                                 const std::vector<ConvexObstacle>& polyhedra = {}) {
    requireLightAboveHorizon(m, n, corner, edgeU, edgeV);
    const Vec3 lightNormal = glm::normalize(glm::cross(edgeU, edgeV));  // points toward M

    std::vector<detail::DirRegion> regions;
    // Region 0: the light, corners in (s, t) clockwise order = positive on the sphere.
    {
        std::vector<Vec3> q;
        for (const Vec3& p : {corner, corner + edgeV, corner + edgeU + edgeV, corner + edgeU})
            q.push_back(glm::normalize(p - m));
        require(glm::dot(glm::cross(q[0], q[1]), q[2]) > 0.0,
                "rectMinusObstacles: degenerate light seen edge-on");
        regions.push_back(detail::polygonRegion(q));
    }
    for (const SphereObstacle& s : spheres) {
        require(s.radius > 0.0, "rectMinusObstacles: sphere radius must be > 0");
        const Vec3 toCenter = s.center - m;
        const double dist = glm::length(toCenter);
        require(dist > s.radius, "rectMinusObstacles: M is inside a sphere");
        require(glm::dot(s.center - corner, lightNormal) > s.radius,
                "rectMinusObstacles: a sphere is not wholly on M's side of the light plane");
        regions.push_back(detail::capRegion(toCenter / dist, s.radius / dist));
    }
    for (const ConvexObstacle& p : polyhedra) {
        require(!p.vertices.empty(), "rectMinusObstacles: polyhedron without vertices");
        const std::vector<Vec2> hull = projectedHull(m, corner, edgeU, edgeV, p.vertices);
        if (hull.size() < 3) continue;  // flat and edge-on: hides a set of measure zero
        std::vector<Vec3> dirs;         // the hull is (s, t) counterclockwise: reverse it
        for (size_t i = hull.size(); i-- > 0;)
            dirs.push_back(glm::normalize(corner + hull[i].x * edgeU + hull[i].y * edgeV - m));
        regions.push_back(detail::polygonRegion(dirs));
    }

    // Every boundary curve: a great-circle arc of a polygon region, or a cap's whole circle.
    struct Curve {
        size_t region;
        const detail::GreatArc* arc;  // nullptr: the cap circle of `region`
        std::vector<double> breaks;   // arc: s in (0, length); circle: t in [0, 2 pi)
    };
    std::vector<Curve> curves;
    for (size_t g = 0; g < regions.size(); ++g) {
        if (regions[g].isCap) curves.push_back({g, nullptr, {}});
        for (const detail::GreatArc& a : regions[g].arcs) curves.push_back({g, &a, {}});
    }
    // Splits a curve at the point of it closest to the direction x.
    auto split = [&](Curve& c, const Vec3& x) {
        const detail::DirRegion& r = regions[c.region];
        double p = c.arc ? std::atan2(glm::dot(x, c.arc->w), glm::dot(x, c.arc->u))
                         : std::atan2(glm::dot(x, r.e2), glm::dot(x, r.e1));
        if (p < 0.0) p += kTwoPi;
        if (c.arc == nullptr || (p > 0.0 && p < c.arc->length)) c.breaks.push_back(p);
    };
    // Crossings of every pair of curves of different regions, each found once as a point and
    // split on both curves: near-tangent crossings are ill-conditioned (parameter errors up to
    // ~1e-8), but both curves then end at the same point and the boundary loop stays closed.
    // Crossings of whole circles, not only of the arcs: extra splits are harmless.
    std::vector<double> roots;
    for (size_t i = 0; i < curves.size(); ++i)
        for (size_t j = i + 1; j < curves.size(); ++j) {
            Curve& ci = curves[i];
            Curve& cj = curves[j];
            if (ci.region == cj.region) continue;
            std::vector<Vec3> points;
            if (ci.arc == nullptr || cj.arc == nullptr) {
                // A small circle (the first that is one) against the other curve.
                const bool iCircle = ci.arc == nullptr;
                const detail::DirRegion& cap = regions[(iCircle ? ci : cj).region];
                const Curve& other = iCircle ? cj : ci;
                roots.clear();
                if (other.arc != nullptr) {
                    const Vec3& nu = other.arc->normal;
                    trigRoots(cap.cosA * glm::dot(nu, cap.axis), cap.sinA * glm::dot(nu, cap.e1),
                              cap.sinA * glm::dot(nu, cap.e2), roots);
                } else {
                    const Vec3& b = regions[other.region].axis;
                    trigRoots(cap.cosA * glm::dot(cap.axis, b) - regions[other.region].cosA,
                              cap.sinA * glm::dot(cap.e1, b), cap.sinA * glm::dot(cap.e2, b),
                              roots);
                }
                for (double t : roots) points.push_back(cap.capPoint(t));
            } else {
                const Vec3 x = glm::cross(ci.arc->normal, cj.arc->normal);
                const double len = glm::length(x);
                if (len < detail::kSameCircle) {
                    // Same great circle: split each arc at the other's endpoints.
                    split(ci, cj.arc->u);
                    split(ci, cj.arc->at(cj.arc->length));
                    split(cj, ci.arc->u);
                    split(cj, ci.arc->at(ci.arc->length));
                    continue;
                }
                points.push_back(x / len);
                points.push_back(-x / len);
            }
            for (const Vec3& x : points) {
                split(ci, x);
                split(cj, x);
            }
        }

    const double fractions[] = {0.5, 0.25, 0.75};
    std::vector<Vec3> samples(3);
    double sum = 0.0;  // loop integral of (d x dd) . n over the visible set's boundary
    for (Curve& c : curves) {
        const detail::DirRegion& own = regions[c.region];
        const double sign = c.region == 0 ? 1.0 : -1.0;  // hidden regions' boundaries reversed
        std::vector<double>& cuts = c.breaks;
        std::sort(cuts.begin(), cuts.end());
        if (c.arc == nullptr) {
            if (cuts.empty()) cuts.push_back(0.0);
            for (size_t k = 0; k < cuts.size(); ++k) {
                const double t0 = cuts[k];
                const double t1 = k + 1 < cuts.size() ? cuts[k + 1] : cuts[0] + kTwoPi;
                if (t1 <= t0) continue;
                for (int i = 0; i < 3; ++i)
                    samples[i] = own.capPoint(t0 + fractions[i] * (t1 - t0));
                if (!detail::boundsVisible(c.region, samples, regions, nullptr)) continue;
                const Vec3 integral = own.sinA * own.sinA * (t1 - t0) * own.axis -
                                      own.sinA * own.cosA *
                                          ((std::sin(t1) - std::sin(t0)) * own.e1 +
                                           (std::cos(t0) - std::cos(t1)) * own.e2);
                sum += sign * glm::dot(integral, n);
            }
            continue;
        }
        cuts.insert(cuts.begin(), 0.0);
        cuts.push_back(c.arc->length);
        for (size_t k = 0; k + 1 < cuts.size(); ++k) {
            const double s0 = cuts[k], s1 = cuts[k + 1];
            if (s1 <= s0) continue;
            for (int i = 0; i < 3; ++i) samples[i] = c.arc->at(s0 + fractions[i] * (s1 - s0));
            if (!detail::boundsVisible(c.region, samples, regions, c.arc)) continue;
            sum += sign * (s1 - s0) * glm::dot(c.arc->normal, n);
        }
    }
    return sum / kTwoPi;
}

// ---------------------------------------------------------------------------------------------
// Brute-force quadrature.

/// Midpoint rule on an N x N grid of the light's (s, t) square:
///   F ~ sum visible(P) * max(cos1, 0) * max(cos2, 0) / (pi r^2) * dA,
/// cos1 at the receiver (clamped: lights straddling the horizon), cos2 at the light (clamped:
/// a light emits only on the side of edgeU x edgeV). `visible(P)` gets the light point P.
/// Error: O(h^2) where the integrand is smooth or merely continuous (the horizon), and at most
/// (max integrand) * (area of the cells crossed) across a visibility discontinuity, i.e.
/// about max integrand * 4 (L h + h^2) for a shadow outline of length L and cell size h.
template <class Visible>
double numericFormFactor(const Vec3& m, const Vec3& n, const Vec3& corner, const Vec3& edgeU,
                         const Vec3& edgeV, Visible&& visible, int N) {
    require(N > 0, "numericFormFactor: N must be > 0");
    const Vec3 areaNormal = glm::cross(edgeU, edgeV);
    const double cellArea = glm::length(areaNormal) / (double(N) * double(N));
    const Vec3 lightNormal = glm::normalize(areaNormal);
    double sum = 0.0;
    for (int j = 0; j < N; ++j) {
        const double t = (j + 0.5) / N;
        double row = 0.0;  // per-row partial sums keep the rounding error small
        for (int i = 0; i < N; ++i) {
            const double s = (i + 0.5) / N;
            const Vec3 p = corner + s * edgeU + t * edgeV;
            const Vec3 r = p - m;
            const double r2 = glm::dot(r, r);
            const double c1 = glm::dot(r, n);             // |r| cos1
            const double c2 = -glm::dot(r, lightNormal);  // |r| cos2
            if (c1 <= 0.0 || c2 <= 0.0) continue;
            if (!visible(p)) continue;
            row += c1 * c2 / (r2 * r2);
        }
        sum += row;
    }
    return sum * cellArea / kPi;
}

/// Same, for any light type with members corner, edgeU, edgeV (e.g. penumbra::RectLight).
template <class Light, class Visible>
double numericFormFactor(const Vec3& m, const Vec3& n, const Light& light, Visible&& visible,
                         int N) {
    return numericFormFactor(m, n, light.corner, light.edgeU, light.edgeV,
                             std::forward<Visible>(visible), N);
}

}  // namespace penumbra::exact
