#include "penumbra/form_factor.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <utility>
#include <limits>
#include <stdexcept>
#include <string>

namespace penumbra {

namespace {

// For G = f(s, d) w with w = c0 x c1, s = |w|, d = c0 . c1 and f = atan2(s, d) / s,
// f and (df/ds) / s are smooth in s down to zero; their series avoid 0/0 at collinear edges.
struct FTerms {
    double f;      // atan2(s, d) / s
    double fsOverS;  // (df/ds) / s
    double fd;     // df/dd
};

FTerms fTerms(double s, double d) {
    FTerms t;
    const double q = s * s + d * d;
    t.fd = -1.0 / q;
    if (d > 0.0 && s < 1e-4 * d) {
        // atan(x)/x = 1 - x^2/3 + ..., with x = s/d.
        const double x2 = (s / d) * (s / d);
        t.f = (1.0 - x2 / 3.0) / d;
        t.fsOverS = (-2.0 / 3.0 + 0.8 * x2) / (d * d * d);
    } else {
        const double beta = std::atan2(s, d);
        t.f = beta / s;
        t.fsOverS = (s * d / q - beta) / (s * s * s);
    }
    return t;
}

// Gauss-Legendre nodes and weights on [-1, 1] (Newton on the Legendre recurrence).
template <int K>
struct GaussLegendre {
    std::array<double, K> x{}, w{};
    GaussLegendre() {
        for (int i = 0; i < K; ++i) {
            double z = std::cos(kPi * (i + 0.75) / (K + 0.5));
            double dp = 1.0;
            for (int it = 0; it < 100; ++it) {
                double p0 = 1.0, p1 = z;
                for (int k = 2; k <= K; ++k) {
                    const double p2 = ((2.0 * k - 1.0) * z * p1 - (k - 1.0) * p0) / k;
                    p0 = p1;
                    p1 = p2;
                }
                dp = K * (z * p1 - p0) / (z * z - 1.0);
                const double step = p1 / dp;
                z -= step;
                if (std::abs(step) < 1e-16) break;
            }
            x[i] = z;
            w[i] = 2.0 / ((1.0 - z * z) * dp * dp);
        }
    }
};

// The unit vectors of a disc light's plane: e1 x e2 = its normal.
void discAxes(const RectLight& disc, Vec3& e1, Vec3& e2) {
    e1 = glm::normalize(disc.edgeU);
    e2 = glm::normalize(disc.edgeV);
}

double angleOn(const RectLight& disc, const Vec3& e1, const Vec3& e2, const Vec3& p) {
    const Vec3 d = p - disc.center;
    return std::atan2(glm::dot(d, e2), glm::dot(d, e1));
}

}  // namespace

Vec2 RectLight::coordinates(const Vec3& p) const {
    const Vec3 d = p - corner;
    const double a = glm::dot(edgeU, edgeU), b = glm::dot(edgeU, edgeV), c = glm::dot(edgeV, edgeV);
    const double pu = glm::dot(d, edgeU), pv = glm::dot(d, edgeV);
    if (b == 0.0) return Vec2(pu / a, pv / c);  // a rectangle
    const double det = a * c - b * b;
    return Vec2((c * pu - b * pv) / det, (a * pv - b * pu) / det);
}

double RectLight::area() const {
    switch (shape) {
        case LightShape::Polygon: {
            Vec3 sum(0.0);
            for (size_t i = 0; i < vertices.size(); ++i)
                sum += glm::cross(vertices[i], vertices[(i + 1) % vertices.size()]);
            return 0.5 * std::abs(glm::dot(sum, normal()));
        }
        case LightShape::Disc:
            return kPi * radius * radius;
        case LightShape::Rect:
            break;
    }
    return glm::length(glm::cross(edgeU, edgeV));
}

std::vector<Vec3> RectLight::polygon() const {
    if (shape == LightShape::Polygon) return vertices;
    return {corner, corner + edgeU, corner + edgeU + edgeV, corner + edgeV};
}

bool RectLight::contains(const Vec3& p) const {
    const double size = std::max(glm::length(edgeU), glm::length(edgeV));
    const double tol = 1e-9 * size;
    switch (shape) {
        case LightShape::Polygon: {
            const Vec3 n = normal();
            for (size_t i = 0; i < vertices.size(); ++i) {
                const Vec3 e = vertices[(i + 1) % vertices.size()] - vertices[i];
                if (glm::dot(p - vertices[i], glm::normalize(glm::cross(n, e))) < -tol) return false;
            }
            return true;
        }
        case LightShape::Disc:
            return glm::length(p - center) <= radius + tol;
        case LightShape::Rect:
            break;
    }
    const Vec2 uv = coordinates(p);
    const double u = uv.x, v = uv.y;
    return u >= -1e-9 && u <= 1.0 + 1e-9 && v >= -1e-9 && v <= 1.0 + 1e-9;
}

RectLight polygonLight(const std::vector<Vec3>& vertices) {
    const size_t n = vertices.size();
    if (n < 3)
        throw std::invalid_argument("a polygon light needs at least 3 vertices, got " + std::to_string(n));
    double size = 0.0;
    for (const Vec3& v : vertices) size = std::max(size, glm::length(v - vertices[0]));
    // Newell's normal: the right-hand rule over the whole loop.
    Vec3 sum(0.0);
    for (size_t i = 0; i < n; ++i) sum += glm::cross(vertices[i], vertices[(i + 1) % n]);
    if (!(size > 0.0) || !(glm::length(sum) > 1e-12 * size * size))
        throw std::invalid_argument("vertex 2 is collinear with the ones before it: the polygon has no area");
    const Vec3 normal = glm::normalize(sum);
    for (size_t i = 0; i < n; ++i) {
        if (std::abs(glm::dot(vertices[i] - vertices[0], normal)) > 1e-6 * size)
            throw std::invalid_argument("vertex " + std::to_string(i) + " is not on the plane of the others");
    }
    for (size_t i = 0; i < n; ++i) {
        const Vec3& prev = vertices[(i + n - 1) % n];
        const Vec3& next = vertices[(i + 1) % n];
        const double turn = glm::dot(glm::cross(vertices[i] - prev, next - vertices[i]), normal);
        if (!(turn > 1e-9 * size * size))
            throw std::invalid_argument("vertex " + std::to_string(i) +
                                        (turn < 0.0 ? " makes the polygon concave"
                                                    : " repeats or is collinear with its neighbours"));
    }
    // A convex polygon has a turn of 2 pi: a star (turning twice) passes the test above.
    double total = 0.0;
    for (size_t i = 0; i < n; ++i) {
        const Vec3 a = vertices[i] - vertices[(i + n - 1) % n], b = vertices[(i + 1) % n] - vertices[i];
        total += std::atan2(glm::dot(glm::cross(a, b), normal), glm::dot(a, b));
    }
    if (total > 3.0 * kPi)
        throw std::invalid_argument("vertex " + std::to_string(n - 1) + " closes a polygon that winds more than once");
    RectLight l;
    l.shape = LightShape::Polygon;
    l.vertices = vertices;
    // A triangle's frame is the parallelogram on its first two edges (the triangle is the
    // half of it below the diagonal), a parallelogram's is itself: their corners are the
    // frame's, which the contour integrator's first level samples.
    if (n == 3 || (n == 4 && glm::length(vertices[0] + vertices[2] - vertices[1] - vertices[3]) <= 1e-9 * size)) {
        l.corner = vertices[0];
        l.edgeU = vertices[1] - vertices[0];
        l.edgeV = vertices[n - 1] - vertices[0];
        return l;
    }
    double best = std::numeric_limits<double>::infinity();
    for (size_t i = 0; i < n; ++i) {
        const Vec3 d = glm::normalize(vertices[(i + 1) % n] - vertices[i]);
        const Vec3 e = glm::cross(normal, d);
        double d0 = 0.0, d1 = 0.0, e0 = 0.0, e1 = 0.0;
        for (const Vec3& v : vertices) {
            const double a = glm::dot(v - vertices[0], d), b = glm::dot(v - vertices[0], e);
            d0 = std::min(d0, a), d1 = std::max(d1, a), e0 = std::min(e0, b), e1 = std::max(e1, b);
        }
        if ((d1 - d0) * (e1 - e0) < best * (1.0 - 1e-12)) {
            best = (d1 - d0) * (e1 - e0);
            l.corner = vertices[0] + d0 * d + e0 * e;
            l.edgeU = (d1 - d0) * d;
            l.edgeV = (e1 - e0) * e;
        }
    }
    return l;
}

RectLight discLight(const Vec3& c, const Vec3& normal, double r) {
    if (!(r > 0.0) || !std::isfinite(r)) throw std::invalid_argument("a disc light's radius must be positive");
    if (!(glm::length(normal) > 0.0)) throw std::invalid_argument("a disc light's normal must not be zero");
    const Vec3 n = glm::normalize(normal);
    // The axis least aligned with n gives the first frame direction.
    Vec3 axis(1.0, 0.0, 0.0);
    if (std::abs(n.y) < std::abs(n.x) && std::abs(n.y) <= std::abs(n.z)) axis = Vec3(0.0, 1.0, 0.0);
    else if (std::abs(n.z) < std::abs(n.x) && std::abs(n.z) < std::abs(n.y)) axis = Vec3(0.0, 0.0, 1.0);
    const Vec3 e1 = glm::normalize(axis - glm::dot(axis, n) * n);
    const Vec3 e2 = glm::cross(n, e1);
    RectLight l;
    l.shape = LightShape::Disc;
    l.center = c;
    l.radius = r;
    l.corner = c - r * e1 - r * e2;
    l.edgeU = 2.0 * r * e1;
    l.edgeV = 2.0 * r * e2;
    return l;
}

std::vector<LightEdge> cuttingEdges(const RectLight& light) {
    std::vector<LightEdge> out;
    if (light.shape != LightShape::Polygon) return out;
    const Vec3 n = light.normal();
    auto uv = [&](const Vec3& p) { return light.coordinates(p); };
    const size_t k = light.vertices.size();
    for (size_t i = 0; i < k; ++i) {
        const Vec3& a = light.vertices[i];
        const Vec3& b = light.vertices[(i + 1) % k];
        const Vec2 pa = uv(a), pb = uv(b);
        auto same = [](double x, double y, double at) { return std::abs(x - at) < 1e-9 && std::abs(y - at) < 1e-9; };
        if (same(pa.x, pb.x, 0.0) || same(pa.x, pb.x, 1.0) || same(pa.y, pb.y, 0.0) || same(pa.y, pb.y, 1.0))
            continue;  // on the frame's border: the frame already ends there
        out.push_back({a, glm::normalize(glm::cross(n, b - a))});
    }
    return out;
}

bool frameHoldsCorners(const RectLight& light) {
    if (light.shape != LightShape::Polygon) return true;
    const size_t n = light.vertices.size();
    return (n == 3 || n == 4) && light.corner == light.vertices[0] &&
           light.edgeU == light.vertices[1] - light.vertices[0] &&
           light.edgeV == light.vertices[n - 1] - light.vertices[0];
}

namespace {

// G of the arc phi in [fa, fa + span] of the circle c + R (cos phi e1 + sin phi e2), seen from m,
// in closed form; false where the formula loses digits (then the caller integrates). With
// c0 = c - m, r(phi) = c0 + R (cos phi e1 + sin phi e2):
//   dr/dphi x r = -R^2 n + R cos phi (e2 x c0) - R sin phi (e1 x c0)       (n = e1 x e2)
//   |r|^2       = D + E cos phi + F sin phi = D + rho cos(phi - psi),
// D = |c0|^2 + R^2, E = 2 R c0.e1, F = 2 R c0.e2, rho = hypot(E, F) < D off the circle. With
// theta = phi - psi and k = sqrt(D^2 - rho^2):
//   J0 = int dtheta / (D + rho cos theta) = (2 / k) atan(sqrt((D - rho) / (D + rho)) tan(theta / 2)),
//   Jc = int cos theta / (...) = (dtheta - D J0) / rho,
//   Js = int sin theta / (...) = -ln(D + rho cos theta) / rho,
// and cos phi, sin phi are rotations of cos theta, sin theta by psi.
bool discArcGClosed(const RectLight& disc, const Vec3& e1, const Vec3& e2, double fa, double span,
                    const Vec3& m, Vec3& g) {
    const double R = disc.radius;
    const Vec3 c0 = disc.center - m;
    const double D = glm::dot(c0, c0) + R * R;
    const double E = 2.0 * R * glm::dot(c0, e1), F = 2.0 * R * glm::dot(c0, e2);
    const double rho = std::hypot(E, F);
    // Jc's difference cancels about D / rho of its digits: integrate instead near the axis, and
    // near the circle (where k vanishes).
    if (!(rho > 1e-4 * D) || !(D - rho > 1e-9 * D)) return false;
    const double psi = std::atan2(F, E);
    const double k = std::sqrt((D - rho) * (D + rho));
    const double t = std::sqrt((D - rho) / (D + rho));
    // J0's antiderivative, continuous across theta = pi (mod 2 pi).
    auto j0 = [&](double theta) {
        const double n = std::floor((theta + kPi) / (2.0 * kPi));
        const double h = 0.5 * (theta - 2.0 * kPi * n);  // in [-pi/2, pi/2)
        return (2.0 / k) * (std::atan2(t * std::sin(h), std::cos(h)) + kPi * n);
    };
    const double th0 = fa - psi, th1 = th0 + span;
    const double J0 = j0(th1) - j0(th0);
    const double Jc = (span - D * J0) / rho;
    const double q0 = D + rho * std::cos(th0);
    const double Js = -std::log1p(rho * (std::cos(th1) - std::cos(th0)) / q0) / rho;
    const double cp = std::cos(psi), sp = std::sin(psi);
    const double I1 = cp * Jc - sp * Js;  // int cos phi / |r|^2
    const double I2 = sp * Jc + cp * Js;  // int sin phi / |r|^2
    g = -R * R * glm::cross(e1, e2) * J0 + R * glm::cross(e2, c0) * I1 - R * glm::cross(e1, c0) * I2;
    return true;
}

}  // namespace

EdgeDerivative discArcG(const RectLight& disc, const Vec3& a, const Vec3& b, const Vec3& m,
                        bool derivative) {
    static const GaussLegendre<16> gl;
    Vec3 e1, e2;
    discAxes(disc, e1, e2);
    const double fa = angleOn(disc, e1, e2, a);
    double span = angleOn(disc, e1, e2, b) - fa;
    while (span <= 0.0) span += 2.0 * kPi;
    if (glm::length(b - a) <= 1e-12 * disc.radius) span = 2.0 * kPi;
    if (!derivative) {
        EdgeDerivative out;
        if (discArcGClosed(disc, e1, e2, fa, span, m, out.g)) return out;
    }
    // Pieces of at most pi/8, split further while a piece is longer than half its distance
    // from m (a lower bound: its middle's distance less half its length): the integrand peaks
    // where the circle passes near m, and a fixed rule there was 3% off (a disc of radius 15
    // cut by the horizon of a ground point next to where the circle meets the ground:
    // bench_bounds --lights mixed --light-scale 15, seed 4110).
    std::vector<std::pair<double, double>> work, pieces;  // (start angle, length)
    const int first = std::max(1, static_cast<int>(std::ceil(span / (kPi / 8.0))));
    for (int p = first - 1; p >= 0; --p) work.emplace_back(fa + span * p / first, span / first);
    while (!work.empty()) {
        const auto [start, len] = work.back();
        work.pop_back();
        const double mid = start + 0.5 * len;
        const Vec3 c = disc.center + disc.radius * (std::cos(mid) * e1 + std::sin(mid) * e2);
        const double length = disc.radius * len;
        const double near = glm::length(c - m) - 0.5 * length;
        if (length > 0.5 * near && pieces.size() + work.size() < 4096 && len > 1e-9) {
            work.emplace_back(mid, 0.5 * len);
            work.emplace_back(start, 0.5 * len);
            continue;
        }
        pieces.emplace_back(start, len);
    }
    EdgeDerivative out;
    for (const auto& [start, h] : pieces) {
        for (int i = 0; i < 16; ++i) {
            const double phi = start + h * 0.5 * (gl.x[i] + 1.0);
            const double c = std::cos(phi), s = std::sin(phi);
            const Vec3 r = disc.center + disc.radius * (c * e1 + s * e2) - m;
            const Vec3 dr = disc.radius * (-s * e1 + c * e2);
            const double q = glm::dot(r, r);
            const double w = 0.5 * h * gl.w[i];
            const Vec3 cr = glm::cross(dr, r);
            out.g += (w / q) * cr;
            if (!derivative) continue;
            for (int k = 0; k < 3; ++k) {
                Vec3 e(0.0);
                e[k] = 1.0;
                out.dg[k] += w * (-glm::cross(dr, e) / q + (2.0 * r[k] / (q * q)) * cr);
            }
        }
    }
    return out;
}

namespace {

// G and its Jacobian of a disc light's part above the receiver's horizon: the arc above it and,
// when the horizon cuts the disc, the chord between the two cut points.
GWithDerivative discG(const RectLight& l, const Receiver& r, bool derivative) {
    GWithDerivative out;
    Vec3 e1, e2;
    discAxes(l, e1, e2);
    const double h0 = glm::dot(l.center - r.point, r.normal);
    const double a1 = l.radius * glm::dot(e1, r.normal), a2 = l.radius * glm::dot(e2, r.normal);
    const double amp = std::hypot(a1, a2);
    auto at = [&](double phi) { return l.center + l.radius * (std::cos(phi) * e1 + std::sin(phi) * e2); };
    if (h0 <= -amp) return out;
    if (h0 >= amp) {
        const EdgeDerivative e = discArcG(l, at(0.0), at(0.0), r.point, derivative);
        out.g = e.g;
        out.dg = e.dg;
    } else {
        const double mid = std::atan2(a2, a1), half = std::acos(-h0 / amp);
        const Vec3 p0 = at(mid - half), p1 = at(mid + half);
        const EdgeDerivative arc = discArcG(l, p0, p1, r.point, derivative);
        const EdgeDerivative chord = edgeGWithDerivative(p1 - r.point, p0 - r.point);
        out.g = arc.g + chord.g;
        out.dg = arc.dg + chord.dg;
    }
    out.g /= 2.0 * kPi;
    out.dg /= 2.0 * kPi;
    return out;
}

}  // namespace

// Vedel 1993 eq. 6, signed for loops counterclockwise in the light's (u, v) plane:
// n_i = (c1 x c0) / |c1 x c0| points to the receiver's side for such loops.
Vec3 edgeG(const Vec3& c0, const Vec3& c1) {
    const Vec3 w = glm::cross(c1, c0);
    const double s = glm::length(w);
    const double d = glm::dot(c0, c1);
    if (s == 0.0) return Vec3(0.0);
    return (std::atan2(s, d) / s) * w;
}

EdgeDerivative edgeGWithDerivative(const Vec3& c0, const Vec3& c1) {
    EdgeDerivative out;
    const Vec3 w = glm::cross(c1, c0);
    const double s = glm::length(w);
    const double d = glm::dot(c0, c1);
    if (s == 0.0 && d <= 0.0) return out;  // zero vector or antiparallel: undefined, contributes 0
    if (glm::dot(c0, c0) == 0.0 || glm::dot(c1, c1) == 0.0) return out;
    const FTerms t = fTerms(s, d);
    out.g = t.f * w;
    // Moving M by e_k moves both c0 and c1 by -e_k:
    //   dw = -(e_k x c0) - (c1 x e_k) = e_k x (c1 - c0),   dd = -e_k . (c0 + c1),
    //   dG = f dw + (fsOverS (w . dw) + fd dd) w.   (The appendix's eq. 8-10, regrouped.)
    const Vec3 edge = c1 - c0;
    const Vec3 sum = c0 + c1;
    for (int k = 0; k < 3; ++k) {
        Vec3 e(0.0);
        e[k] = 1.0;
        const Vec3 dw = glm::cross(e, edge);
        const double dd = -sum[k];
        out.dg[k] = t.f * dw + (t.fsOverS * glm::dot(w, dw) + t.fd * dd) * w;
    }
    return out;
}

Vec3 polygonG(const std::vector<Vec3>& polygonWS, const Vec3& m) {
    Vec3 g(0.0);
    const size_t n = polygonWS.size();
    for (size_t i = 0; i < n; ++i) g += edgeG(polygonWS[i] - m, polygonWS[(i + 1) % n] - m);
    return g / (2.0 * kPi);
}

double polygonFormFactor(const std::vector<Vec3>& polygonWS, const Receiver& r) {
    if (polygonWS.size() < 3) return 0.0;
    return glm::dot(polygonG(polygonWS, r.point), r.normal);
}

std::vector<Vec3> clipToHorizon(const std::vector<Vec3>& polygonWS, const Receiver& r) {
    std::vector<Vec3> out;
    const size_t n = polygonWS.size();
    out.reserve(n + 1);
    for (size_t i = 0; i < n; ++i) {
        const Vec3& a = polygonWS[i];
        const Vec3& b = polygonWS[(i + 1) % n];
        const double ha = glm::dot(a - r.point, r.normal);
        const double hb = glm::dot(b - r.point, r.normal);
        if (ha >= 0.0) out.push_back(a);
        if ((ha >= 0.0) != (hb >= 0.0)) {
            const double t = ha / (ha - hb);
            out.push_back(a + t * (b - a));
        }
    }
    return out;
}

bool facesLight(const RectLight& light, const Vec3& m) {
    return glm::dot(m - light.corner, glm::cross(light.edgeU, light.edgeV)) > 0.0;
}

double formFactorDensity(const Receiver& r, const Vec3& lightNormal, const Vec3& p) {
    const Vec3 c = p - r.point;
    const double r2 = glm::dot(c, c);
    const double cosM = glm::dot(c, r.normal);
    const double cosL = -glm::dot(c, lightNormal);
    if (!(cosM > 0.0) || !(cosL > 0.0) || !(r2 > 0.0)) return 0.0;
    return cosM * cosL / (kPi * r2 * r2);
}

double unoccludedFormFactor(const RectLight& light, const Receiver& r) {
    if (!facesLight(light, r.point)) return 0.0;
    if (light.shape == LightShape::Disc) return std::max(0.0, glm::dot(discG(light, r, false).g, r.normal));
    return std::max(0.0, polygonFormFactor(clipToHorizon(light.polygon(), r), r));
}

GWithDerivative unoccludedG(const RectLight& light, const Receiver& r, bool derivative) {
    GWithDerivative out;
    if (!facesLight(light, r.point)) return out;
    if (light.shape == LightShape::Disc) return discG(light, r, derivative);
    const std::vector<Vec3> poly = clipToHorizon(light.polygon(), r);
    const size_t n = poly.size();
    if (n < 3) return out;
    for (size_t i = 0; i < n; ++i) {
        const EdgeDerivative e = edgeGWithDerivative(poly[i] - r.point, poly[(i + 1) % n] - r.point);
        out.g += e.g;
        out.dg += e.dg;
    }
    out.g /= 2.0 * kPi;
    out.dg /= 2.0 * kPi;
    return out;
}

double stripFormFactor(const Receiver& r, const Vec3& lightNormal, const Vec3& p0, const Vec3& p1,
                       double width) {
    const Vec3 mid = 0.5 * (p0 + p1) - r.point;
    const double dist2 = glm::dot(mid, mid);
    if (dist2 == 0.0) return 0.0;
    const double dist = std::sqrt(dist2);
    const double cos1 = std::max(0.0, glm::dot(mid, r.normal) / dist);
    const double cos2 = std::abs(glm::dot(mid, lightNormal)) / dist;
    return cos1 * cos2 * width * glm::length(p1 - p0) / (kPi * dist2);
}

bool lightReaches(const RectLight& light, const Receiver& r) {
    if (!facesLight(light, r.point)) return false;
    for (const Vec3& c : light.polygon()) {
        if (glm::dot(c - r.point, r.normal) > 0.0) return true;
    }
    return false;
}

}  // namespace penumbra
