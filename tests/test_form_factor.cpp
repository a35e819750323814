// Tests of form_factor.h against independent closed forms (tests/support/exact_shadow.h): catalogued
// rectangle form factors, superposition, finite differences and brute-force quadrature.
#include <catch2/catch.hpp>
#include <cmath>
#include <vector>

#include "support/exact_shadow.h"
#include "penumbra/form_factor.h"

namespace penumbra {
namespace {

const Vec3 kUp(0.0, 0.0, 1.0);

RectLight makeLight(const Vec3& corner, const Vec3& edgeU, const Vec3& edgeV) {
    RectLight light;
    light.corner = corner;
    light.edgeU = edgeU;
    light.edgeV = edgeV;
    return light;
}

// Horizontal light covering [x0, x1] x [y0, y1] at height z, emitting down (-z).
RectLight horizontalLight(double x0, double x1, double y0, double y1, double z) {
    return makeLight(Vec3(x0, y0, z), Vec3(0.0, y1 - y0, 0.0), Vec3(x1 - x0, 0.0, 0.0));
}

// Catalogued value for that light seen from (x, y, 0) with normal +z, by superposition of
// corner-above rectangles with signed extents.
double parallelBySuperposition(double x, double y, double x0, double x1, double y0, double y1,
                               double c) {
    x0 -= x, x1 -= x, y0 -= y, y1 -= y;
    return exact::parallelRectCornerAbove(x1, y1, c) - exact::parallelRectCornerAbove(x0, y1, c) -
           exact::parallelRectCornerAbove(x1, y0, c) + exact::parallelRectCornerAbove(x0, y0, c);
}

using exact::rotation;

double maxAbs(const Mat3& m) {
    double v = 0.0;
    for (int c = 0; c < 3; ++c)
        for (int r = 0; r < 3; ++r) v = std::max(v, std::abs(m[c][r]));
    return v;
}

// Central differences of edgeG with the end points C0, C1 fixed in space and M moving:
// column k = (G(M + h e_k) - G(M - h e_k)) / 2h, with c_i = C_i - M.
Mat3 edgeGFiniteDifference(const Vec3& c0, const Vec3& c1, double h) {
    Mat3 j(0.0);
    for (int k = 0; k < 3; ++k) {
        Vec3 e(0.0);
        e[k] = h;
        j[k] = (edgeG(c0 - e, c1 - e) - edgeG(c0 + e, c1 + e)) / (2.0 * h);
    }
    return j;
}

}  // namespace

TEST_CASE("form factor of an unoccluded rectangle equals the catalogued closed forms",
          "[form_factor]") {
    const Receiver origin{Vec3(0.0), kUp};
    SECTION("parallel rectangle with a corner above M") {
        struct Case {
            double a, b, c;
        };
        for (const Case& k : {Case{1.0, 1.0, 1.0}, Case{0.3, 2.0, 0.7}, Case{2.5, 1.5, 3.0},
                              Case{1e-3, 5.0, 0.2}}) {
            const RectLight light = horizontalLight(0.0, k.a, 0.0, k.b, k.c);
            const double expected = exact::parallelRectCornerAbove(k.a, k.b, k.c);
            CHECK(polygonFormFactor(light.polygon(), origin) ==
                  Approx(expected).margin(1e-12).epsilon(0));
            CHECK(unoccludedFormFactor(light, origin) == Approx(expected).margin(1e-12).epsilon(0));
        }
    }
    SECTION("perpendicular rectangle, one edge on M's horizon, M on the normal through a corner") {
        struct Case {
            double a, b, c;
        };
        for (const Case& k : {Case{1.0, 1.0, 1.0}, Case{2.0, 0.5, 0.8}, Case{0.4, 3.0, 1.5}}) {
            // Plane x = c, 0 <= y <= a, 0 <= z <= b, emitting toward -x; listed both ways round.
            const RectLight l1 = makeLight(Vec3(k.c, 0.0, 0.0), Vec3(0, 0, k.b), Vec3(0, k.a, 0));
            const RectLight l2 = makeLight(Vec3(k.c, k.a, 0.0), Vec3(0, -k.a, 0), Vec3(0, 0, k.b));
            const double expected = exact::perpendicularRectCorner(k.a, k.b, k.c);
            for (const RectLight& l : {l1, l2}) {
                CHECK(polygonFormFactor(l.polygon(), origin) ==
                      Approx(expected).margin(1e-12).epsilon(0));
                CHECK(unoccludedFormFactor(l, origin) == Approx(expected).margin(1e-12).epsilon(0));
            }
        }
    }
    SECTION("rectangles not above M, by superposition of corner-above rectangles") {
        struct Case {
            double x0, x1, y0, y1, c;
        };
        for (const Case& k : {Case{0.5, 1.7, 0.2, 0.9, 1.0},      // off to one side
                              Case{-0.6, 0.8, -1.1, 0.4, 0.5},    // straddles the normal
                              Case{-3.0, -1.0, 2.0, 2.5, 2.0},    // far corner region
                              Case{-0.2, 0.3, 0.7, 4.0, 0.3}}) {  // straddles one axis
            const RectLight light = horizontalLight(k.x0, k.x1, k.y0, k.y1, k.c);
            const double expected = parallelBySuperposition(0.0, 0.0, k.x0, k.x1, k.y0, k.y1, k.c);
            CHECK(polygonFormFactor(light.polygon(), origin) ==
                  Approx(expected).margin(1e-12).epsilon(0));
            CHECK(unoccludedFormFactor(light, origin) == Approx(expected).margin(1e-12).epsilon(0));
        }
        // Perpendicular strip lifted off the horizon: [0, a] x [z0, z1] = [0, z1] - [0, z0].
        const RectLight lifted = makeLight(Vec3(1.2, 0.0, 0.4), Vec3(0, 0, 0.9), Vec3(0, 0.7, 0));
        CHECK(unoccludedFormFactor(lifted, origin) ==
              Approx(exact::perpendicularRectCorner(0.7, 1.3, 1.2) -
                     exact::perpendicularRectCorner(0.7, 0.4, 1.2))
                  .margin(1e-12)
                  .epsilon(0));
    }
    SECTION("G's other components are perpendicular-rectangle form factors") {
        // The corner-above rectangle [0, a] x [0, b] at height c seen with normal +x is the
        // perpendicular case with the y edge (length b) on the horizon, height a; likewise +y.
        const double a = 0.8, b = 1.3, c = 0.6;
        const Vec3 g = polygonG(horizontalLight(0.0, a, 0.0, b, c).polygon(), Vec3(0.0));
        CHECK(g.x == Approx(exact::perpendicularRectCorner(b, a, c)).margin(1e-12).epsilon(0));
        CHECK(g.y == Approx(exact::perpendicularRectCorner(a, b, c)).margin(1e-12).epsilon(0));
        CHECK(g.z == Approx(exact::parallelRectCornerAbove(a, b, c)).margin(1e-12).epsilon(0));
    }
    SECTION("invariant under a rigid motion of receiver and light") {
        const Mat3 rot = rotation(Vec3(0.4, -1.0, 0.7), 1.1);
        const Vec3 shift(-3.0, 2.0, 5.0);
        const RectLight light = horizontalLight(-0.6, 0.8, -1.1, 0.4, 0.5);
        const RectLight moved =
            makeLight(rot * light.corner + shift, rot * light.edgeU, rot * light.edgeV);
        const Receiver r{shift, rot * kUp};
        CHECK(unoccludedFormFactor(moved, r) ==
              Approx(parallelBySuperposition(0, 0, -0.6, 0.8, -1.1, 0.4, 0.5))
                  .margin(1e-12)
                  .epsilon(0));
    }
}

TEST_CASE("a light facing away from the receiver contributes nothing", "[form_factor]") {
    const Receiver r{Vec3(0.1, -0.2, 0.0), kUp};
    const RectLight facing = horizontalLight(-0.5, 0.5, -0.5, 0.5, 1.0);
    const RectLight away = makeLight(facing.corner, facing.edgeV, facing.edgeU);  // emits up
    CHECK(facesLight(facing, r.point));
    CHECK(unoccludedFormFactor(facing, r) > 0.1);
    CHECK_FALSE(facesLight(away, r.point));
    CHECK(unoccludedFormFactor(away, r) == 0.0);
    const GWithDerivative g = unoccludedG(away, r);
    CHECK(g.g == Vec3(0.0));
    CHECK(g.dg == Mat3(0.0));
    // In the light's plane: not strictly on the emitting side.
    CHECK_FALSE(facesLight(facing, Vec3(3.0, 0.0, 1.0)));
}

TEST_CASE("reversing an edge negates its G vector exactly", "[form_factor]") {
    const Vec3 pairs[][2] = {{Vec3(0.3, -0.2, 1.0), Vec3(-0.7, 0.4, 1.3)},
                             {Vec3(1e-3, 2.0, 0.5), Vec3(3.0, -1.0, 0.25)},
                             {Vec3(0.3, -0.2, 1.0), Vec3(0.6, -0.4, 2.0 + 1e-9)},
                             {Vec3(-1.0, 0.1, 0.2), Vec3(1.0, 0.1, 0.2)}};
    for (const auto& p : pairs) {
        const Vec3 forward = edgeG(p[0], p[1]);
        const Vec3 backward = edgeG(p[1], p[0]);
        CHECK(backward.x == -forward.x);
        CHECK(backward.y == -forward.y);
        CHECK(backward.z == -forward.z);
        CHECK(glm::length(forward) > 0.0);
    }
}

TEST_CASE("edgeGWithDerivative matches central finite differences, also at junction edges",
          "[form_factor]") {
    // Central differences with h = 1e-6 err by O(h^2) ~ 1e-12 (truncation) plus
    // O(eps |G| / h) ~ 1e-10 (rounding), far below the 1e-6 relative tolerance.
    const double h = 1e-6;
    const Vec3 c0(0.3, -0.2, 1.0);
    struct Case {
        const char* name;
        Vec3 c0, c1;
    };
    const Case cases[] = {
        {"generic", c0, Vec3(-0.7, 0.4, 1.3)},
        {"long and oblique", Vec3(-2.0, 0.5, 0.1), Vec3(3.0, 1.0, 0.4)},
        {"wide angle", Vec3(1.0, 0.0, 0.05), Vec3(-1.0, 0.2, 0.05)},
        {"nearly collinear (junction)", c0, 2.0 * c0 + Vec3(1e-7, 3e-8, 0.0)},
        {"nearly collinear, offset below the step", c0, 1.5 * c0 + Vec3(0.0, 2e-9, -1e-9)},
        {"exactly collinear", c0, 2.0 * c0},
    };
    for (const Case& k : cases) {
        INFO(k.name);
        const EdgeDerivative d = edgeGWithDerivative(k.c0, k.c1);
        const Mat3 fd = edgeGFiniteDifference(k.c0, k.c1, h);
        // The value agrees with edgeG (which the finite differences use).
        CHECK(glm::length(d.g - edgeG(k.c0, k.c1)) <= 1e-15 * (1.0 + glm::length(d.g)));
        const double scale = maxAbs(fd);
        REQUIRE(scale > 1e-3);  // a real derivative, not a zero compared with a zero
        CHECK(maxAbs(d.dg - fd) <= 1e-6 * scale);
    }
    SECTION("exactly collinear: zero value, finite derivative") {
        const EdgeDerivative d = edgeGWithDerivative(c0, 2.0 * c0);
        CHECK(edgeG(c0, 2.0 * c0) == Vec3(0.0));
        CHECK(d.g == Vec3(0.0));
        for (int c = 0; c < 3; ++c)
            for (int r = 0; r < 3; ++r) CHECK(std::isfinite(d.dg[c][r]));
        // Closed form at c1 = lambda c0: G ~ (c1 x c0) / (|c0| |c1|) to first order, so
        // dG/dM_k = (e_k x (c1 - c0)) / (|c0| |c1|).
        const Vec3 c1 = 2.0 * c0;
        for (int k = 0; k < 3; ++k) {
            Vec3 e(0.0);
            e[k] = 1.0;
            const Vec3 expected = glm::cross(e, c1 - c0) / (glm::length(c0) * glm::length(c1));
            CHECK(glm::length(d.dg[k] - expected) <= 1e-14);
        }
    }
}

TEST_CASE("unoccludedG's gradient matches finite differences of unoccludedFormFactor",
          "[form_factor]") {
    // dF/dM_k = (dG/dM_k) . n with n fixed. For a clipped light the horizon vertices slide
    // with M, but the sliver they sweep carries an integrand that vanishes on the horizon, so
    // F changes by O(h^2) and even in h: central differences still converge as O(h^2).
    const double h = 1e-6;
    struct Case {
        const char* name;
        RectLight light;
        Receiver r;
    };
    const Case cases[] = {
        {"above the horizon", horizontalLight(-0.4, 0.9, -0.3, 0.6, 1.0),
         Receiver{Vec3(0.2, -0.1, 0.0), glm::normalize(Vec3(0.2, 0.1, 1.0))}},
        {"oblique light", makeLight(Vec3(1.0, -0.5, 0.5), Vec3(0.1, 0.0, 0.8), Vec3(0.2, 1.0, 0.3)),
         Receiver{Vec3(-0.5, 0.2, 0.1), glm::normalize(Vec3(0.5, 0.0, 1.0))}},
        {"clipped by the horizon", horizontalLight(-1.0, 1.0, -1.0, 1.0, 1.0),
         Receiver{Vec3(0.1, 0.05, 0.0), glm::normalize(Vec3(1.0, 1.0, 0.5))}},
    };
    for (const Case& k : cases) {
        INFO(k.name);
        REQUIRE(facesLight(k.light, k.r.point));
        const GWithDerivative g = unoccludedG(k.light, k.r);
        CHECK(glm::dot(g.g, k.r.normal) ==
              Approx(unoccludedFormFactor(k.light, k.r)).margin(1e-15).epsilon(0));
        const Vec3 gradient = glm::transpose(g.dg) * k.r.normal;
        Vec3 fd(0.0);
        for (int i = 0; i < 3; ++i) {
            Vec3 e(0.0);
            e[i] = h;
            fd[i] = (unoccludedFormFactor(k.light, Receiver{k.r.point + e, k.r.normal}) -
                     unoccludedFormFactor(k.light, Receiver{k.r.point - e, k.r.normal})) /
                    (2.0 * h);
        }
        INFO("gradient (" << gradient.x << ", " << gradient.y << ", " << gradient.z
                          << "), finite differences (" << fd.x << ", " << fd.y << ", " << fd.z
                          << ")");
        REQUIRE(glm::length(fd) > 1e-3);
        CHECK(glm::length(gradient - fd) <= 1e-6 * glm::length(fd));
    }
}

TEST_CASE("a light straddling the horizon matches midpoint quadrature of the clamped integrand",
          "[form_factor]") {
    // With cos1 clamped at zero the integrand f = max(0, g) is continuous with a kink on the
    // horizon line, so the midpoint rule stays second order. Smooth cells err by about
    // h^2/24 |f''| per unit area; a cell crossed by the kink errs by the convexity gap of
    // max(0, .), about |grad g| h^2/24 per unit length of the line (same sign everywhere).
    // Here h = 2/2000 = 1e-3, |f''| and |grad g| <~ 1/pi (r >= 1), the light's area is 4 and
    // the horizon line is at most 2 sqrt(2) long: the error is ~ 1e-7, so 1e-6 is a safe margin.
    const RectLight light = horizontalLight(-1.0, 1.0, -1.0, 1.0, 1.0);
    const Vec3 m(0.1, 0.05, 0.0);
    for (const Vec3& n : {glm::normalize(Vec3(1.0, 0.0, 0.3)),  // cuts two opposite edges
                          glm::normalize(Vec3(1.0, 1.0, 0.5)),  // cuts a corner off
                          glm::normalize(Vec3(-0.2, 1.0, 0.1))}) {
        const Receiver r{m, n};
        const double numeric = exact::numericFormFactor(
            m, n, light, [](const Vec3&) { return true; }, 2000);
        INFO("n = (" << n.x << ", " << n.y << ", " << n.z << ")");
        CHECK(unoccludedFormFactor(light, r) == Approx(numeric).margin(1e-6).epsilon(0));
    }
}

TEST_CASE("clipToHorizon keeps the part above the horizon and the orientation", "[form_factor]") {
    const RectLight light = horizontalLight(-1.0, 1.0, -1.0, 1.0, 1.0);
    const Vec3 lightNormal = glm::cross(light.edgeU, light.edgeV);
    auto area = [](const std::vector<Vec3>& poly) {  // Newell: twice the vector area
        Vec3 s(0.0);
        for (size_t i = 0; i < poly.size(); ++i)
            s += glm::cross(poly[i], poly[(i + 1) % poly.size()]);
        return 0.5 * s;
    };
    SECTION("a corner cut off") {
        // Horizon x + y + z/2 = 0 meets the light (z = 1) on x + y = -1/2, cutting off the
        // triangle (-1,-1), (1/2,-1), (-1,1/2) of area 9/8.
        const Receiver r{Vec3(0.0), glm::normalize(Vec3(1.0, 1.0, 0.5))};
        const std::vector<Vec3> clipped = clipToHorizon(light.polygon(), r);
        REQUIRE(clipped.size() == 5);
        for (const Vec3& p : clipped) CHECK(glm::dot(p - r.point, r.normal) >= -1e-15);
        const Vec3 a = area(clipped);
        CHECK(glm::dot(a, lightNormal) > 0.0);  // same orientation as the light's loop
        CHECK(glm::length(a) == Approx(4.0 - 9.0 / 8.0).epsilon(1e-14));
        // The kept corners appear in the light's own cyclic order.
        const std::vector<Vec3> corners = light.polygon();
        std::vector<int> order;
        for (const Vec3& p : clipped)
            for (int i = 0; i < 4; ++i)
                if (p == corners[i]) order.push_back(i);
        REQUIRE(order.size() == 3);
        const int start = order[0];
        for (size_t j = 1; j < order.size(); ++j)
            CHECK((order[j] - start + 4) % 4 > (order[j - 1] - start + 4) % 4);
    }
    SECTION("two opposite edges cut") {
        const Receiver r{Vec3(0.0), glm::normalize(Vec3(1.0, 0.0, 0.5))};  // keeps x >= -1/2
        const std::vector<Vec3> clipped = clipToHorizon(light.polygon(), r);
        REQUIRE(clipped.size() == 4);
        const Vec3 a = area(clipped);
        CHECK(glm::dot(a, lightNormal) > 0.0);
        CHECK(glm::length(a) == Approx(1.5 * 2.0).epsilon(1e-14));
    }
    SECTION("wholly above: unchanged; wholly below: nothing and no light") {
        const Receiver above{Vec3(0.0), kUp};
        CHECK(clipToHorizon(light.polygon(), above) == light.polygon());
        const Receiver below{Vec3(0.0), glm::normalize(Vec3(1.0, 0.0, -1.5))};  // x >= 1.5 z
        CHECK(clipToHorizon(light.polygon(), below).size() < 3);
        CHECK(unoccludedFormFactor(light, below) == 0.0);
    }
}

TEST_CASE("stripFormFactor approximates the form factor of a thin rectangle around the segment",
          "[form_factor]") {
    // The elementary form factor at the segment's midpoint is the one-point midpoint rule over
    // the strip: relative error ~ (length / distance)^2 ~ 1e-4 here (width terms ~ 1e-10).
    const double length = 0.01, width = 1e-5;
    const RectLight light = horizontalLight(-1.0, 1.0, -1.0, 1.0, 1.0);
    const Vec3 nL = light.normal();
    struct Case {
        Vec3 m, n, p0, dir;
    };
    const Case cases[] = {
        {Vec3(0.0), kUp, Vec3(0.2, 0.1, 1.0), Vec3(1.0, 0.0, 0.0)},
        {Vec3(0.3, -0.4, 0.2), glm::normalize(Vec3(0.4, 0.2, 1.0)), Vec3(-0.5, 0.6, 1.0),
         glm::normalize(Vec3(0.6, -0.8, 0.0))},
        {Vec3(-1.5, 0.0, 0.0), glm::normalize(Vec3(1.0, 0.0, 0.6)), Vec3(0.7, -0.7, 1.0),
         glm::normalize(Vec3(0.0, 1.0, 0.0))},
    };
    for (const Case& k : cases) {
        const Vec3 p1 = k.p0 + length * k.dir;
        // Strip [p0, p1] x [-w/2, w/2] across, listed so that it emits like the light.
        Vec3 across = glm::normalize(glm::cross(nL, k.dir));
        RectLight strip = makeLight(k.p0 - 0.5 * width * across, length * k.dir, width * across);
        if (glm::dot(glm::cross(strip.edgeU, strip.edgeV), nL) < 0.0)
            strip = makeLight(k.p0 + 0.5 * width * across, length * k.dir, -width * across);
        const Receiver r{k.m, k.n};
        REQUIRE(facesLight(strip, r.point));
        const double expected = polygonFormFactor(strip.polygon(), r);
        REQUIRE(expected > 0.0);
        CHECK(stripFormFactor(r, nL, k.p0, p1, width) == Approx(expected).epsilon(1e-3));
        // Either orientation of the segment and of the normal describes the same strip.
        CHECK(stripFormFactor(r, -nL, p1, k.p0, width) == Approx(expected).epsilon(1e-3));
    }
}

}  // namespace penumbra
