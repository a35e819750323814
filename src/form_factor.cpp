#include "penumbra/form_factor.h"

#include <cmath>

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

double unoccludedFormFactor(const RectLight& light, const Receiver& r) {
    if (!facesLight(light, r.point)) return 0.0;
    return std::max(0.0, polygonFormFactor(clipToHorizon(light.polygon(), r), r));
}

GWithDerivative unoccludedG(const RectLight& light, const Receiver& r) {
    GWithDerivative out;
    if (!facesLight(light, r.point)) return out;
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
