// Tests of monte_carlo.h for polygon and disc lights: the area maps (on the emitting surface,
// uniform, continuous), Arvo's parametrization of spherical triangles and the fan built on it
// (on the light, uniform in solid angle, precise on small triangles), every estimator's
// convergence to the exact unoccluded form factor and to a high-count reference behind a sphere
// within bounds from measured standard errors, and determinism. Rectangles are tested in
// test_monte_carlo.cpp.
#include <algorithm>
#include <array>
#include <catch2/catch.hpp>
#include <cmath>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "support/exact_shadow.h"
#include "penumbra/monte_carlo.h"
#include "support/mc_trials.h"

using namespace penumbra;

namespace {

const Vec3 kUp(0.0, 0.0, 1.0);
const Vec3 kSphereCenter(0.3, 0.2, 2.0);
const double kSphereRadius = 0.7;

// All lights lie in the plane z = 4 and emit downwards (-z), as test_monte_carlo.cpp's.
RectLight hexagon() {  // regular, circumradius 1, about (0, 0, 4)
    std::vector<Vec3> v;
    for (int k = 0; k < 6; ++k) {
        const double a = -k * kPi / 3.0;  // clockwise seen from above: counterclockwise about -z
        v.emplace_back(std::cos(a), std::sin(a), 4.0);
    }
    return polygonLight(v);
}

RectLight triangle() {
    return polygonLight({Vec3(-1.0, -0.8, 4.0), Vec3(-0.3, 1.0, 4.0), Vec3(1.2, -0.5, 4.0)});
}

// The rectangle of test_monte_carlo.cpp's testLight(), as a 4-vertex polygon.
RectLight rectanglePolygon() {
    return polygonLight({Vec3(-1.0, -0.75, 4.0), Vec3(-1.0, 0.75, 4.0), Vec3(1.0, 0.75, 4.0),
                         Vec3(1.0, -0.75, 4.0)});
}

RectLight disc() { return discLight(Vec3(0.0, 0.0, 4.0), -kUp, 1.0); }

struct NamedLight {
    const char* name;
    RectLight light;
};

std::vector<NamedLight> lights() {
    return {{"hexagon", hexagon()},
            {"triangle", triangle()},
            {"rectangle as polygon", rectanglePolygon()},
            {"disc", disc()}};
}

using test::Estimator;
using test::estimators;
using test::NamedEstimator;
using test::runTrials;
using test::Trials;

// Solid angle of the triangle (a, b, c) seen from the origin by Girard's theorem (the sum of
// its angles minus pi), independent of the library's Van Oosterom and Strackee formula. In long
// double: the sum cancels down to the solid angle, which is 1e-6 sr for the farthest triangle.
double girardSolidAngle(const Vec3& a, const Vec3& b, const Vec3& c) {
    using L = long double;
    struct V {
        L x, y, z;
    };
    auto dot = [](const V& p, const V& q) { return p.x * q.x + p.y * q.y + p.z * q.z; };
    auto unitTangent = [&](const V& p, const V& q) {  // at p, towards q
        const L k = dot(q, p) / dot(p, p);
        const V t{q.x - k * p.x, q.y - k * p.y, q.z - k * p.z};
        const L len = std::sqrt(dot(t, t));
        return V{t.x / len, t.y / len, t.z / len};
    };
    auto angleAt = [&](const V& p, const V& q, const V& r) {
        const L cosine = dot(unitTangent(p, q), unitTangent(p, r));
        return std::acos(std::clamp(cosine, L(-1), L(1)));
    };
    const V pa{a.x, a.y, a.z}, pb{b.x, b.y, b.z}, pc{c.x, c.y, c.z};
    const L pi = 3.141592653589793238462643383279502884L;
    return double(angleAt(pa, pb, pc) + angleAt(pb, pc, pa) + angleAt(pc, pa, pb) - pi);
}

// Solid angle of a small planar triangle (world points) seen from m: its area times
// cos(theta) / r^2 at its centroid (exact to second order in its size).
double smallSolidAngle(const Vec3& m, const Vec3& p, const Vec3& q, const Vec3& r) {
    const Vec3 n = glm::cross(q - p, r - p);
    const Vec3 c = (p + q + r) / 3.0 - m;
    const double d2 = glm::dot(c, c);
    return 0.5 * std::abs(glm::dot(n, c)) / (d2 * std::sqrt(d2));
}

// The 16 cells of a triangle (v0, v1, v2) cut by lines of barycentric coordinates at quarters:
// 10 upward and 6 downward, of equal areas. A point with coordinates l1 (along v1 - v0) and l2
// (along v2 - v0) is in cell cellIndex(l1, l2); cellCorners(i) gives the (l1, l2) corners.
struct TriangleCells {
    std::vector<std::array<Vec2, 3>> corners;
    std::vector<int> index;  // by (i, j, up): i + 4 j + 16 up
    TriangleCells() : index(32, -1) {
        for (int j = 0; j < 4; ++j) {
            for (int i = 0; i + j < 4; ++i) {
                index[size_t(i + 4 * j + 16)] = int(corners.size());
                corners.push_back({Vec2(i, j) / 4.0, Vec2(i + 1, j) / 4.0, Vec2(i, j + 1) / 4.0});
                if (i + j < 3) {
                    index[size_t(i + 4 * j)] = int(corners.size());
                    corners.push_back(
                        {Vec2(i + 1, j) / 4.0, Vec2(i + 1, j + 1) / 4.0, Vec2(i, j + 1) / 4.0});
                }
            }
        }
    }
    int cellIndex(double l1, double l2) const {
        const double x = std::clamp(4.0 * l1, 0.0, 3.999999);
        const double y = std::clamp(4.0 * l2, 0.0, 3.999999);
        int i = int(x);
        const int j = int(y);
        if (i + j > 3) i = 3 - j;  // rounding just outside the triangle's third side
        const bool up = (x - i) + (y - j) < 1.0 || i + j == 3;
        return index[size_t(i + 4 * j + (up ? 16 : 0))];
    }
};

// Barycentric coordinates (l1, l2) of a point of the triangle's plane.
Vec2 barycentric(const Vec3 tri[3], const Vec3& p) {
    const Vec3 e1 = tri[1] - tri[0], e2 = tri[2] - tri[0], d = p - tri[0];
    const double a = glm::dot(e1, e1), b = glm::dot(e1, e2), c = glm::dot(e2, e2);
    const double du = glm::dot(d, e1), dv = glm::dot(d, e2);
    const double det = a * c - b * b;
    return Vec2((c * du - b * dv) / det, (a * dv - b * du) / det);
}

double chiSquare(const std::vector<int>& counts, const std::vector<double>& expected) {
    double chi2 = 0.0;
    for (size_t i = 0; i < counts.size(); ++i) {
        chi2 += (counts[i] - expected[i]) * (counts[i] - expected[i]) / expected[i];
    }
    return chi2;
}

// 0.05% upper quantiles of chi-square (Wilson-Hilferty): a fixed seed's statistic is what it
// is, and a wrong density (area instead of solid angle, off by 10-40% per cell here) exceeds
// these by far.
constexpr double kChi2Df5 = 22.5, kChi2Df15 = 40.0;

}  // namespace

// n points drawn by `draw` from uniform (u, v), counted into `cells` cells by `cellOf`, which
// also clears `ok` for a point that is not where it belongs (checked: none may be).
template <class Draw, class CellOf>
std::vector<int> histogram(int n, uint64_t seed, int cells, Draw draw, CellOf cellOf) {
    std::mt19937_64 gen(seed);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    std::vector<int> counts(size_t(cells), 0);
    bool ok = true;
    for (int i = 0; i < n; ++i) {
        const double u = uni(gen);
        const Vec3 p = draw(u, uni(gen));
        ++counts[size_t(cellOf(p, ok))];
    }
    CHECK(ok);
    return counts;
}

// Draws n points through the light's area map: all must lie on the light (at height 4), and
// the chi-square of their counts over `cells` equal-area cells (cellOf gives a point's cell)
// stay under `limit`.
template <class CellOf>
void checkUniformOnSurface(const RectLight& l, int cells, uint64_t seed, CellOf cellOf, double limit) {
    const int n = 100000;
    const LightSurface surface(l);
    const std::vector<int> counts = histogram(
        n, seed, cells, [&](double u, double v) { return surface.point(u, v); },
        [&](const Vec3& p, bool& ok) {
            ok = ok && l.contains(p) && std::abs(p.z - 4.0) < 1e-12;
            return cellOf(p);
        });
    const double chi2 = chiSquare(counts, std::vector<double>(size_t(cells), double(n) / cells));
    INFO("chi-square " << chi2);
    CHECK(chi2 < limit);
}

TEST_CASE("the area maps put uniform points on a polygon's or a disc's emitting surface",
          "[mc][lights]") {
    SECTION("hexagon: six equal triangles about its centre") {
        // Vertex k is at angle -k pi / 3; sector k runs from it to vertex k + 1.
        checkUniformOnSurface(hexagon(), 6, 5, [](const Vec3& p) {
            const double a = std::fmod(-std::atan2(p.y, p.x) + 2.0 * kPi, 2.0 * kPi);
            return std::min(5, int(a / (kPi / 3.0)));
        }, kChi2Df5);
    }
    SECTION("triangle: 16 equal cells") {
        const RectLight l = triangle();
        const Vec3 tri[3] = {l.vertices[0], l.vertices[1], l.vertices[2]};
        const TriangleCells cells;
        checkUniformOnSurface(l, 16, 5, [&](const Vec3& p) {
            const Vec2 b = barycentric(tri, p);
            return cells.cellIndex(b.x, b.y);
        }, kChi2Df15);
    }
    SECTION("disc: 4 rings of equal area x 4 quadrants") {
        const RectLight l = disc();
        const LightSurface surface(l);
        checkUniformOnSurface(l, 16, 5, [](const Vec3& p) {
            const double r2 = p.x * p.x + p.y * p.y;  // radius 1: ring k holds r^2 in [k, k+1) / 4
            const int ring = std::min(3, int(4.0 * r2));
            const int quadrant = (p.x >= 0.0 ? 0 : 1) + (p.y >= 0.0 ? 0 : 2);
            return 4 * ring + quadrant;
        }, kChi2Df15);
        // The border of the square is the circle, its centre the disc's.
        CHECK(glm::length(surface.point(0.5, 0.5) - l.center) < 1e-15);
        CHECK(std::abs(glm::length(surface.point(1.0, 0.3) - l.center) - 1.0) < 1e-12);
    }
    SECTION("the polygon map is continuous where one fan triangle meets the next") {
        const RectLight l = hexagon();
        const LightSurface surface(l);
        // The fan's triangles of the regular hexagon have areas 1:2:2:1 (out of 6) from vertex 0.
        for (double cut : {1.0 / 6.0, 3.0 / 6.0, 5.0 / 6.0}) {
            for (double v : {0.1, 0.5, 1.0}) {
                const Vec3 a = surface.point(cut - 1e-12, v), b = surface.point(cut + 1e-12, v);
                CHECK(glm::length(a - b) < 1e-9);
            }
        }
    }
}

TEST_CASE("Arvo's parametrization of a spherical triangle is uniform in solid angle",
          "[mc][lights]") {
    const RectLight l = triangle();
    const Vec3 tri[3] = {l.vertices[0], l.vertices[1], l.vertices[2]};
    const TriangleCells cells;
    // Below, far to the side, close to the light's plane, and (for precision) far away.
    for (const Vec3& m : {Vec3(0.1, 0.2, 0.0), Vec3(-5.0, 4.0, 1.0), Vec3(0.4, -0.6, 3.8),
                          Vec3(3.0, 2.0, -1000.0)}) {
        INFO("origin " << m.x << ", " << m.y << ", " << m.z);
        const Vec3 a = glm::normalize(tri[0] - m), b = glm::normalize(tri[1] - m),
                   c = glm::normalize(tri[2] - m);
        const SphericalTriangle st(a, b, c);
        const double exactOmega = girardSolidAngle(tri[0] - m, tri[1] - m, tri[2] - m);
        CHECK(st.solidAngle() == Approx(exactOmega).epsilon(1e-9));
        // The sides: v = 0 is b, u = 0 the side b-a, u = 1 the side b-c.
        CHECK(glm::length(st.sample(0.37, 0.0) - b) < 1e-12);
        CHECK(glm::length(st.sample(0.0, 1.0) - a) < 1e-12);
        CHECK(glm::length(st.sample(1.0, 1.0) - c) < 1e-12);
        CHECK(std::abs(glm::dot(st.sample(0.0, 0.6), glm::cross(a, b))) < 1e-12);
        CHECK(std::abs(glm::dot(st.sample(1.0, 0.6), glm::cross(b, c))) < 1e-12);

        // Directions to points of the triangle's plane.
        auto hit = [&](const Vec3& d) { return m + ((4.0 - m.z) / d.z) * d; };
        // The Jacobian: a (u, v) patch of area h^2 maps to a solid angle S h^2 anywhere.
        const double h = 1e-4;
        double worstJacobian = 0.0;
        for (double u : {0.02, 0.3, 0.5, 0.77, 0.97}) {
            for (double v : {0.03, 0.4, 0.6, 0.98}) {
                const Vec3 p00 = hit(st.sample(u, v)), p10 = hit(st.sample(u + h, v));
                const Vec3 p11 = hit(st.sample(u + h, v + h)), p01 = hit(st.sample(u, v + h));
                const double omega =
                    smallSolidAngle(m, p00, p10, p11) + smallSolidAngle(m, p00, p11, p01);
                worstJacobian =
                    std::max(worstJacobian, std::abs(omega / (h * h) / st.solidAngle() - 1.0));
            }
        }
        INFO("worst relative Jacobian error " << worstJacobian);
        CHECK(worstJacobian < 1e-3);

        // A histogram over the 16 cells against their solid angles: chi-square, 15 degrees of
        // freedom.
        const int n = 200000;
        const std::vector<int> counts = histogram(
            n, 11, 16, [&](double u, double v) { return hit(st.sample(u, v)); },
            [&](const Vec3& p, bool& ok) {
                const Vec2 bc = barycentric(tri, p);
                ok = ok && bc.x >= -1e-9 && bc.y >= -1e-9 && bc.x + bc.y <= 1.0 + 1e-9;
                return cells.cellIndex(bc.x, bc.y);
            });
        std::vector<double> expected;
        double spread = 0.0;
        for (const auto& k : cells.corners) {
            auto at = [&](const Vec2& q) {
                return tri[0] + q.x * (tri[1] - tri[0]) + q.y * (tri[2] - tri[0]) - m;
            };
            const double omega = girardSolidAngle(at(k[0]), at(k[1]), at(k[2]));
            expected.push_back(n * omega / exactOmega);
            spread = std::max(spread, std::abs(expected.back() / (n / 16.0) - 1.0));
        }
        const double chi2 = chiSquare(counts, expected);
        INFO("chi-square " << chi2 << ", cells differ from equal solid angle by up to " << spread);
        CHECK(chi2 < kChi2Df15);
    }
}

TEST_CASE("a polygon's fan of spherical triangles is sampled on the light, uniformly in solid "
          "angle",
          "[mc][lights]") {
    const RectLight l = hexagon();
    for (const Vec3& m : {Vec3(0.1, 0.2, 0.0), Vec3(-4.0, 3.0, 2.0), Vec3(0.5, 0.5, 3.9)}) {
        INFO("origin " << m.x << ", " << m.y << ", " << m.z);
        const SphericalPolygon sp(l, m);
        // Sectors about the centre: (centre, vertex k, vertex k + 1), their solid angles.
        const Vec3 centre(0.0, 0.0, 4.0);
        double total = 0.0;
        std::vector<double> sector;
        for (size_t k = 0; k < 6; ++k) {
            sector.push_back(girardSolidAngle(centre - m, l.vertices[k] - m,
                                              l.vertices[(k + 1) % 6] - m));
            total += sector.back();
        }
        CHECK(sp.solidAngle() == Approx(total).epsilon(1e-10));
        // Continuity where fan triangles meet (their solid angles from this origin are not known
        // in closed form here: scan u finely for the largest jump).
        double jump = 0.0;
        for (int i = 0; i < 20000; ++i) {
            jump = std::max(jump, glm::length(sp.sample((i + 1) / 20000.0, 0.7) -
                                              sp.sample(i / 20000.0, 0.7)));
        }
        CHECK(jump < 0.01);  // a jump from one triangle to another would be ~ 1
        // A histogram over the six sectors against their solid angles: 5 degrees of freedom.
        const int n = 120000;
        const std::vector<int> counts = histogram(
            n, 3, 6, [&](double u, double v) { return sp.sample(u, v); },
            [&](const Vec3& p, bool& ok) {
                ok = ok && l.contains(p) && std::abs(p.z - 4.0) < 1e-12;
                const double a = std::fmod(-std::atan2(p.y, p.x) + 2.0 * kPi, 2.0 * kPi);
                return std::min(5, int(a / (kPi / 3.0)));
            });
        std::vector<double> expected;
        for (double s : sector) expected.push_back(n * s / total);
        const double chi2 = chiSquare(counts, expected);
        INFO("chi-square " << chi2);
        CHECK(chi2 < kChi2Df5);
    }
}

TEST_CASE("every Monte Carlo method converges to the exact unoccluded form factor of polygon "
          "and disc lights",
          "[mc][lights]") {
    const Occluder none;
    Occluder::Query query = none.makeQuery();
    // Below the lights, off to the side, and tilted so that each light straddles the horizon
    // (the clipped closed form is then the answer and some samples cost no ray).
    const Vec3 tilted = glm::normalize(Vec3(1.0, 0.0, 0.25));
    const std::vector<Receiver> receivers = {
        {Vec3(0.1, 0.2, 0.0), kUp}, {Vec3(2.0, 1.5, 0.5), kUp}, {Vec3(0.3, 0.0, 2.5), tilted}};
    // The polygon equal to the rectangle has the rectangle's closed form.
    RectLight rect;
    rect.corner = Vec3(-1.0, -0.75, 4.0);
    rect.edgeU = Vec3(0.0, 1.5, 0.0);
    rect.edgeV = Vec3(2.0, 0.0, 0.0);
    for (const Receiver& r : receivers) {
        CHECK(unoccludedFormFactor(rectanglePolygon(), r) ==
              Approx(unoccludedFormFactor(rect, r)).epsilon(1e-12));
    }

    const int k = 64;
    for (const NamedLight& nl : lights()) {
        for (const NamedEstimator& method : estimators()) {
            const std::string name = method.name;
            for (size_t ri = 0; ri < receivers.size(); ++ri) {
                const Receiver& r = receivers[ri];
                const double f0 = unoccludedFormFactor(nl.light, r);
                REQUIRE(f0 > 0.0);
                McSettings s;
                s.samples = 64;
                const Trials t = runTrials(method.estimate, r, nl.light, query, s, k);
                INFO(nl.name << ", " << name << ", receiver " << ri << ": mean " << t.mean
                             << ", closed form " << f0 << ", sd of one estimate " << t.sd
                             << ", rays " << t.rays);
                if (name == "mc-ratio") {
                    // Without occluder the ratio is 1: exact to rounding.
                    CHECK(std::abs(t.mean - f0) <= 1e-12 * f0);
                    CHECK(t.sd <= 1e-12 * f0);
                } else {
                    // Four standard errors of the mean of 64 independent estimates, measured
                    // (a wrong density or weight is biased by percents, far beyond it).
                    CHECK(std::abs(t.mean - f0) <= 4.0 * t.standardError(k) + 1e-12 * f0);
                    CHECK(t.sd > 0.0);
                    // The spread is small: the integrand only varies by the cosines. Not so for
                    // mc-adaptive, which gives the whole light 4 rays when they agree: where the
                    // horizon cuts the light, about two of them are worth 0 (measured: sd up to
                    // 0.51 F for the hexagon there, 0.35 F for the rectangle in test_monte_carlo).
                    CHECK(t.sd <= (name == "mc-adaptive" ? 0.75 : 0.1) * f0);
                }
                // Straddling the horizon, the samples below it cast no ray.
                if (ri == 2 && name != "mc-adaptive") CHECK(t.rays < uint64_t(k * s.samples));
                if (ri < 2 && name != "mc-adaptive") CHECK(t.rays == uint64_t(k * s.samples));
            }
        }
    }
}

TEST_CASE("behind a sphere, every Monte Carlo method agrees with a high-count reference for "
          "polygon and disc lights",
          "[mc][lights]") {
    const Occluder sphere({AnalyticSphere{kSphereCenter, kSphereRadius}});
    Occluder::Query query = sphere.makeQuery();
    // Points in the penumbra of every light (30% to 70% of its unoccluded form factor).
    const std::vector<Vec3> points = {Vec3(1.75, 0.5, 0.0), Vec3(-0.5, 0.25, 0.0),
                                      Vec3(0.5, -0.75, 0.0)};
    for (const NamedLight& nl : lights()) {
        for (const Vec3& p : points) {
            const Receiver r{p, kUp};
            const double f0 = unoccludedFormFactor(nl.light, r);
            // The reference: 16 x 4096 stratified area samples.
            McSettings rs;
            rs.samples = 4096;
            const int kr = 16;
            const Trials ref = runTrials(monteCarloReference, r, nl.light, query, rs, kr, 99);
            INFO(nl.name << " at " << p.x << ", " << p.y << ": reference " << ref.mean
                         << " +- " << ref.standardError(kr) << ", unoccluded " << f0);
            REQUIRE(ref.mean > 0.25 * f0);
            REQUIRE(ref.mean < 0.75 * f0);
            CHECK(ref.standardError(kr) < 0.002 * ref.mean);
            if (std::string(nl.name) == "rectangle as polygon") {
                // An independent check of the reference itself: the exact shadow of a sphere on
                // a rectangle.
                const double exactF = exact::sphereShadowFormFactor(
                    p, kUp, Vec3(-1.0, -0.75, 4.0), Vec3(0.0, 1.5, 0.0), Vec3(2.0, 0.0, 0.0),
                    kSphereCenter, kSphereRadius);
                CHECK(std::abs(ref.mean - exactF) <= 4.0 * ref.standardError(kr));
            }
            for (const NamedEstimator& method : estimators()) {
                const std::string name = method.name;
                // mc-adaptive from a 16 x 16 grid (its bias, support/mc_trials.h).
                const test::TrialPlan plan = test::trialPlan(name, 64, ref.mean);
                const McSettings& s = plan.settings;
                const int k = plan.k;
                const double biasAllowance = plan.biasAllowance;
                const Trials t = runTrials(method.estimate, r, nl.light, query, s, k);
                const double se = std::sqrt(t.standardError(k) * t.standardError(k) +
                                            ref.standardError(kr) * ref.standardError(kr));
                INFO(name << ": mean " << t.mean << ", sd of one estimate " << t.sd
                          << ", combined standard error " << se << ", rays per estimate "
                          << t.rays / double(k));
                // mc-ratio is consistent, not unbiased: its bias is O(1/N) = a fraction of its
                // standard error at N = 64, inside the same bound.
                CHECK(std::abs(t.mean - ref.mean) <= 4.0 * se + biasAllowance);
                CHECK(t.sd > 0.0);
                CHECK(t.rays <= uint64_t(k * s.samples));
                if (name == "mc-adaptive") CHECK(t.rays > uint64_t(k) * 1024);  // it did split
            }
        }
    }
}

TEST_CASE("Monte Carlo estimates of polygon and disc lights depend only on their seed",
          "[mc][lights]") {
    const Occluder sphere({AnalyticSphere{kSphereCenter, kSphereRadius}});
    Occluder::Query query = sphere.makeQuery();
    const Receiver penumbra{Vec3(1.75, 0.5, 0.0), kUp};
    const Receiver behind{Vec3(0.0, 0.0, 5.0), kUp};  // above the lights: their back side
    for (const NamedLight& nl : lights()) {
        for (const NamedEstimator& method : estimators()) {
            INFO(nl.name << ", " << method.name);
            McSettings s;
            s.samples = 64;
            s.initialDepth = 1;  // mc-adaptive: 16 rays before any split
            s.threshold = 0.001;
            s.seed = 12345;
            const Estimate a = method.estimate(penumbra, nl.light, query, s);
            const Estimate b = method.estimate(penumbra, nl.light, query, s);
            CHECK(a.formFactor == b.formFactor);
            CHECK(a.counts.shadowRays() == b.counts.shadowRays());
            CHECK(a.formFactor > 0.0);
            s.seed = 54321;
            CHECK(method.estimate(penumbra, nl.light, query, s).formFactor != a.formFactor);
            query.resetCount();
            const Estimate e = method.estimate(behind, nl.light, query, s);
            CHECK(e.formFactor == 0.0);
            CHECK(e.counts.shadowRays() == 0);
            CHECK(query.raysCast() == 0);
        }
    }
}
