// The visible part of a rectangle of the light from a kept contour (ContourIntegrator::
// visibleWithin): aciThroughMedia's cells that the opaque contour crosses, without a ray.
//
// The kept edges, each with its weight (1, or a conic piece's share of its tangent triangle),
// are the boundary of the visible part as the evaluation integrated it: a weighted sum of
// closed loops, counterclockwise about the light's emitting side, whose G is the evaluation's.
// Its weighted winding number W (1 where the evaluation counts the light visible, 0 where
// hidden, a piece's weight on its triangle beside its chord, which may lie outside [0, 1]: a
// parabola's is 4/3) is what the part within a rectangle R weighs:
//
//     G(visible within R) = sum over edges e of w_e G(e inside R)
//                           + sum over pieces p of R's border of W(p) G(p),
//
// with R's border cut where edges cross it (W is constant between). W at R's first corner is
// counted along a line from outside the light (where W = 0) and carried along the border,
// changing by w_e where edge e crosses it. The lattice's lines, on which contour vertices lie,
// are dyadic fractions of the light, as the cells' sides are: each side of the rectangle is
// moved by an irrational share of a billionth of the light, which no lattice line's coordinate
// has, so that no vertex lies on its border (what that moves is far below any bound).
#include <algorithm>
#include <cmath>
#include <vector>

#include "penumbra/contour_integrator.h"

namespace penumbra {

namespace {

double cross2(const Vec2& a, const Vec2& b) { return a.x * b.y - a.y * b.x; }

// One crossing of the rectangle's border: where along the side (0..1) and how W changes there.
struct Crossing {
    double s;
    double dw;
};

}  // namespace

bool ContourIntegrator::visibleWithin(const Receiver& r, const RectLight& light, double u0, double v0,
                                      double u1, double v1, Vec3& g) const {
    if (!mContourValid || !(u1 > u0) || !(v1 > v0)) return false;
    constexpr double kShift = 1e-9;
    u0 += 0.6180339887 * kShift, u1 += 0.4142135624 * kShift;
    v0 += 0.7320508076 * kShift, v1 += 0.2360679775 * kShift;
    const Vec2 corner[4] = {{u0, v0}, {u1, v0}, {u1, v1}, {u0, v1}};
    Vec3 world[4];
    for (int k = 0; k < 4; ++k) {
        world[k] = light.point(corner[k].x, corner[k].y);
        if (!(glm::dot(world[k] - r.point, r.normal) > 0.0)) return false;  // the horizon
    }
    // The light's own orientation in (u, v): its loops' insides lie to their left when +1.
    double area = 0.0;
    {
        const std::vector<Vec3> poly = light.polygon();
        for (size_t i = 0; i < poly.size(); ++i) {
            area += cross2(light.coordinates(poly[i]), light.coordinates(poly[(i + 1) % poly.size()]));
        }
    }
    const double orient = area > 0.0 ? 1.0 : -1.0;
    struct Edge2 {
        Vec2 a, b;
    };
    std::vector<Edge2> flat;
    flat.reserve(mContour.size());
    for (const ContourEdge& e : mContour) flat.push_back({light.coordinates(e.a), light.coordinates(e.b)});

    Vec3 sum(0.0);
    // The edges inside the rectangle (Liang-Barsky: it is axis-aligned in (u, v)).
    for (size_t i = 0; i < mContour.size(); ++i) {
        const Vec2 a = flat[i].a, d = flat[i].b - flat[i].a;
        double t0 = 0.0, t1 = 1.0;
        auto clip = [&](double p, double q) {  // keep where p t <= q
            if (p == 0.0) return q >= 0.0;
            const double t = q / p;
            if (p < 0.0) {
                t0 = std::max(t0, t);
            } else {
                t1 = std::min(t1, t);
            }
            return t0 < t1;
        };
        if (!(clip(-d.x, a.x - u0) && clip(d.x, u1 - a.x) && clip(-d.y, a.y - v0) && clip(d.y, v1 - a.y)))
            continue;
        const ContourEdge& e = mContour[i];
        const Vec3 pa = e.a + t0 * (e.b - e.a), pb = e.a + t1 * (e.b - e.a);
        sum += e.weight * edgeG(pa - r.point, pb - r.point);
    }
    // How W changes where the edges cross the segment p -> q, in order along it.
    std::vector<Crossing> crossings;
    auto crossingsOf = [&](const Vec2& p, const Vec2& q) {
        crossings.clear();
        const Vec2 d = q - p;
        for (size_t i = 0; i < flat.size(); ++i) {
            const Vec2 a = flat[i].a, t = flat[i].b - flat[i].a;
            const double den = cross2(d, t);
            if (den == 0.0) continue;  // parallel: meets it nowhere, or (moved) never on it
            const Vec2 ap = a - p;
            const double s = cross2(ap, t) / den, u = cross2(ap, d) / den;
            // Half-open along the edge, so that a line through a vertex counts one of its edges.
            if (!(s >= 0.0 && s < 1.0 && u >= 0.0 && u < 1.0)) continue;
            // Crossing from the edge's right to its left (d turns counterclockwise from t)
            // enters its loop.
            crossings.push_back({s, (cross2(t, d) > 0.0 ? 1.0 : -1.0) * orient * mContour[i].weight});
        }
        std::sort(crossings.begin(), crossings.end(),
                  [](const Crossing& x, const Crossing& y) { return x.s < y.s; });
    };
    // W at the first corner: along the line v = v0 from beyond every edge on the left.
    double lo = u0;
    for (const Edge2& e : flat) lo = std::min({lo, e.a.x, e.b.x});
    crossingsOf(Vec2(lo - 1.0, v0), corner[0]);
    double w = 0.0;
    for (const Crossing& c : crossings) w += c.dw;
    const double w0 = w;
    for (int k = 0; k < 4; ++k) {
        const Vec2 p = corner[k], q = corner[(k + 1) & 3];
        const Vec3 wp = world[k], wq = world[(k + 1) & 3];
        crossingsOf(p, q);
        double s = 0.0;
        auto piece = [&](double s1) {
            if (s1 > s && w != 0.0)
                sum += w * edgeG(wp + s * (wq - wp) - r.point, wp + s1 * (wq - wp) - r.point);
            s = s1;
        };
        for (const Crossing& c : crossings) {
            piece(c.s);
            w += c.dw;
        }
        piece(1.0);
    }
    // Around a closed contour W comes back to where it started.
    if (!(std::abs(w - w0) < 1e-6)) return false;
    g = sum / (2.0 * kPi);
    return true;
}

double ContourIntegrator::contourWeightFactor() const {
    double k = 1.0;
    for (const ContourEdge& e : mContour) k = std::max({k, std::abs(e.weight), std::abs(1.0 - e.weight)});
    return k;
}

}  // namespace penumbra
