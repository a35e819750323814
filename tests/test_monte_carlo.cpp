// Tests of monte_carlo.h: the spherical rectangle's parametrization (inside the light, uniform
// in solid angle), the scrambled Sobol points' stratification, every estimator's convergence to
// the closed form and to the exact sphere shadow within statistical bounds at fixed seeds, ray
// counts, and the Monte Carlo methods in the renderer (same pixels as ACI, thread independence).
#include <catch2/catch.hpp>
#include <cmath>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "support/exact_shadow.h"
#include "support/render_scene.h"
#include "penumbra/error.h"
#include "penumbra/monte_carlo.h"
#include "support/mc_trials.h"
#include "penumbra/renderer.h"

using namespace penumbra;

namespace {

// A 2 x 1.5 light at height 4 emitting downwards (edgeU x edgeV = -z), as in the probe tests.
RectLight testLight() {
    RectLight l;
    l.corner = Vec3(-1.0, -0.75, 4.0);
    l.edgeU = Vec3(0.0, 1.5, 0.0);
    l.edgeV = Vec3(2.0, 0.0, 0.0);
    return l;
}

const Vec3 kUp(0.0, 0.0, 1.0);
const Vec3 kSphereCenter(0.3, 0.2, 2.0);
const double kSphereRadius = 0.7;

// Solid angle of the triangle (a, b, c) seen from the origin (Van Oosterom and Strackee 1983),
// independent of the library's parametrization.
double triangleSolidAngle(const Vec3& a, const Vec3& b, const Vec3& c) {
    const double la = glm::length(a), lb = glm::length(b), lc = glm::length(c);
    const double num = std::abs(glm::dot(a, glm::cross(b, c)));
    const double den =
        la * lb * lc + glm::dot(a, b) * lc + glm::dot(a, c) * lb + glm::dot(b, c) * la;
    return 2.0 * std::atan2(num, den);
}

// Solid angle of the part [s0, s1] x [t0, t1] of the light seen from m.
double subSolidAngle(const RectLight& l, const Vec3& m, double s0, double s1, double t0,
                     double t1) {
    const Vec3 p00 = l.point(s0, t0) - m, p10 = l.point(s1, t0) - m;
    const Vec3 p11 = l.point(s1, t1) - m, p01 = l.point(s0, t1) - m;
    return triangleSolidAngle(p00, p10, p11) + triangleSolidAngle(p00, p11, p01);
}

// The largest value of the area-sampling integrand cos cos A / (pi r^2) over the light, for a
// receiver facing +z under the light (a fine grid; the integrand is smooth).
double integrandMax(const RectLight& light, const Vec3& p) {
    double fMax = 0.0;
    for (int i = 0; i <= 64; ++i) {
        for (int j = 0; j <= 64; ++j) {
            const Vec3 q = light.point(i / 64.0, j / 64.0) - p;
            const double r2 = glm::dot(q, q);
            fMax = std::max(fMax, q.z * q.z * light.area() / (kPi * r2 * r2));
        }
    }
    return 1.01 * fMax;
}

using test::Estimator;
using test::estimators;
using test::NamedEstimator;
using test::runTrials;
using test::Trials;

}  // namespace

TEST_CASE("the spherical rectangle's samples stay inside the light and reach its corners", "[mc]") {
    const RectLight light = testLight();
    std::mt19937_64 gen(7);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    // Receivers straight below, far to the side, close to the light's plane, and on the
    // emitting side but almost in the plane.
    for (const Vec3& m : {Vec3(0.1, 0.2, 0.0), Vec3(-6.0, 5.0, 0.0), Vec3(3.0, -2.0, 3.9),
                          Vec3(0.2, 0.1, 3.999), Vec3(-0.9, 0.7, 3.5)}) {
        const SphericalRectangle rect(light, m);
        REQUIRE(rect.solidAngle() > 0.0);
        double worst = 0.0, offPlane = 0.0;
        auto check = [&](double u, double v) {
            const Vec3 p = rect.sample(u, v);
            const Vec2 st = exact::lightCoords(p, light.corner, light.edgeU, light.edgeV);
            worst = std::max({worst, -st.x, -st.y, st.x - 1.0, st.y - 1.0});
            offPlane = std::max(offPlane, std::abs(glm::dot(p - light.corner, light.normal())));
        };
        for (int i = 0; i <= 64; ++i) {
            for (int j = 0; j <= 64; ++j) check(i / 64.0, j / 64.0);
        }
        for (int i = 0; i < 20000; ++i) check(uni(gen), uni(gen));
        CHECK(worst <= 1e-9);
        CHECK(offPlane <= 1e-9);
        // The unit square's corners map to the light's corners.
        const Vec3 p00 = rect.sample(0.0, 0.0), p11 = rect.sample(1.0, 1.0);
        CHECK(glm::length(p00 - light.corner) < 1e-9);
        CHECK(glm::length(p11 - (light.corner + light.edgeU + light.edgeV)) < 1e-9);
    }
}

TEST_CASE("the spherical rectangle is uniform in solid angle", "[mc]") {
    const RectLight light = testLight();
    for (const Vec3& m : {Vec3(0.1, 0.2, 0.0), Vec3(-5.0, 4.0, 1.0), Vec3(2.5, 0.3, 3.7)}) {
        const SphericalRectangle rect(light, m);
        const double exactOmega = subSolidAngle(light, m, 0, 1, 0, 1);
        CHECK(rect.solidAngle() == Approx(exactOmega).epsilon(1e-10));

        // The Jacobian: a small (u, v) patch of area du dv maps to a solid angle S du dv
        // wherever it is.
        const double h = 1e-4;
        double worstJacobian = 0.0;
        for (double u : {0.03, 0.3, 0.5, 0.77, 0.97}) {
            for (double v : {0.02, 0.4, 0.6, 0.98}) {
                const Vec3 a = rect.sample(u, v) - m, b = rect.sample(u + h, v) - m;
                const Vec3 c = rect.sample(u + h, v + h) - m, d = rect.sample(u, v + h) - m;
                const double omega = triangleSolidAngle(a, b, c) + triangleSolidAngle(a, c, d);
                worstJacobian =
                    std::max(worstJacobian, std::abs(omega / (h * h) / rect.solidAngle() - 1.0));
            }
        }
        CHECK(worstJacobian < 1e-3);

        // A histogram over 4 x 4 sub-rectangles of the light against their solid angles:
        // chi-square with 15 degrees of freedom. With independent uniform (u, v) from a fixed
        // seed the statistic is what it is; 40 is the 0.05% quantile, so a wrong density (the
        // area density instead, off by up to 30% here) fails by far.
        const int n = 200000;
        std::mt19937_64 gen(11);
        std::uniform_real_distribution<double> uni(0.0, 1.0);
        std::vector<int> counts(16, 0);
        for (int i = 0; i < n; ++i) {
            const double u = uni(gen);
            const Vec2 st = exact::lightCoords(rect.sample(u, uni(gen)), light.corner, light.edgeU,
                                               light.edgeV);
            const int a = std::min(3, int(st.x * 4.0)), b = std::min(3, int(st.y * 4.0));
            ++counts[size_t(b * 4 + a)];
        }
        double chi2 = 0.0, spread = 0.0;
        for (int b = 0; b < 4; ++b) {
            for (int a = 0; a < 4; ++a) {
                const double omega =
                    subSolidAngle(light, m, a / 4.0, (a + 1) / 4.0, b / 4.0, (b + 1) / 4.0);
                const double expected = n * omega / exactOmega;
                const double o = counts[size_t(b * 4 + a)];
                chi2 += (o - expected) * (o - expected) / expected;
                spread = std::max(spread, std::abs(expected / (n / 16.0) - 1.0));
            }
        }
        INFO("chi-square " << chi2 << ", sub-rectangles differ from equal area by up to "
                           << spread);
        CHECK(chi2 < 40.0);
    }
}

TEST_CASE("scrambled Sobol points form (0, m, 2)-nets for every seed", "[mc]") {
    for (uint64_t seed : {0ull, 1ull, 12345ull, 0xdeadbeefull}) {
        for (int m : {2, 4, 7, 10}) {
            const int n = 1 << m;
            std::vector<Vec2> pts;
            for (int i = 0; i < n; ++i) {
                const Vec2 p = sobolOwen2(uint32_t(i), seed);
                REQUIRE(p.x > 0.0);
                REQUIRE(p.x < 1.0);
                REQUIRE(p.y > 0.0);
                REQUIRE(p.y < 1.0);
                pts.push_back(p);
            }
            // Every elementary box of 2^a x 2^(m-a) cells holds exactly one point.
            bool allOne = true;
            for (int a = 0; a <= m; ++a) {
                std::vector<int> count(size_t(n), 0);
                for (const Vec2& p : pts) {
                    const int i = int(p.x * (1 << a)), j = int(p.y * (1 << (m - a)));
                    ++count[size_t(j * (1 << a) + i)];
                }
                for (int c : count) allOne &= c == 1;
            }
            CHECK(allOne);
        }
        // Different seeds give different points.
        CHECK(sobolOwen2(3, seed).x != sobolOwen2(3, seed + 1).x);
    }
}

TEST_CASE("every Monte Carlo method converges to the closed form of an unoccluded rectangle",
          "[mc]") {
    const RectLight light = testLight();
    const Occluder none;
    Occluder::Query query = none.makeQuery();
    // Straight below a corner (a catalogued case), off to the side, and tilted so that the light
    // straddles the horizon (then the clipped closed form is the answer).
    const Vec3 tilted = glm::normalize(Vec3(1.0, 0.0, 0.25));
    const std::vector<Receiver> receivers = {
        {Vec3(-1.0, -0.75, 0.0), kUp}, {Vec3(2.0, 1.5, 0.5), kUp}, {Vec3(0.3, 0.0, 2.5), tilted}};
    // Howell B-3 for the first receiver: rectangle 2 x 1.5 at height 4, normal through a corner.
    CHECK(unoccludedFormFactor(light, receivers[0]) ==
          Approx(exact::parallelRectCornerAbove(2.0, 1.5, 4.0)).epsilon(1e-12));

    for (const NamedEstimator& method : estimators()) {
        for (size_t ri = 0; ri < receivers.size(); ++ri) {
            const Receiver& r = receivers[ri];
            const double f0 = unoccludedFormFactor(light, r);
            REQUIRE(f0 > 0.0);
            McSettings s;
            s.samples = 16;
            const int k = 64;
            const Trials t = runTrials(method.estimate, r, light, query, s, k);
            INFO(method.name << " at receiver " << ri << ": mean " << t.mean << ", closed form "
                             << f0 << ", sd of one estimate " << t.sd);
            // Five standard errors of the mean of K independent estimates (plus rounding).
            CHECK(std::abs(t.mean - f0) <= 5.0 * t.sd / std::sqrt(double(k)) + 1e-12);
            // And the spread itself is small: the integrand only varies by the cosines (for
            // mc-adaptive, whose whole light gets 4 rays when they agree, less so).
            CHECK(t.sd <= (std::string(method.name) == "mc-adaptive" ? 0.5 : 0.1) * f0);
            if (std::string(method.name) == "mc-ratio") {
                // Without occluder the ratio is 1: the estimator is exact.
                CHECK(t.mean == Approx(f0).epsilon(1e-12));
                CHECK(t.sd <= 1e-12 * f0);
            }
        }
    }
}

TEST_CASE("every Monte Carlo method converges to the exact sphere shadow", "[mc]") {
    const RectLight light = testLight();
    const Occluder sphere({AnalyticSphere{kSphereCenter, kSphereRadius}});
    Occluder::Query query = sphere.makeQuery();
    // Points in the penumbra (the exact answer strictly between 0 and the unoccluded value).
    for (const Vec3& p : {Vec3(1.6, 0.4, 0.0), Vec3(-0.9, 0.4, 0.0), Vec3(0.6, -0.8, 0.0)}) {
        const Receiver r{p, kUp};
        const double f0 = unoccludedFormFactor(light, r);
        const double exactF = exact::sphereShadowFormFactor(
            p, kUp, light.corner, light.edgeU, light.edgeV, kSphereCenter, kSphereRadius);
        REQUIRE(exactF > 0.05 * f0);
        REQUIRE(exactF < 0.95 * f0);
        for (const NamedEstimator& method : estimators()) {
            const std::string name = method.name;
            // mc-adaptive from a 16 x 16 grid (its bias, support/mc_trials.h).
            const test::TrialPlan plan = test::trialPlan(name, 100, exactF);
            const McSettings& s = plan.settings;
            const int k = name == "mc-adaptive" ? 40 : plan.k;
            const double biasAllowance = plan.biasAllowance;
            const Trials t = runTrials(method.estimate, r, light, query, s, k);
            // The known bound on the spread of one estimate that averages N samples: each
            // sample's value lies in [0, max], so with independent samples its variance is at
            // most max^2 / 4 (a Bernoulli variable at p = 1/2 is the worst case); stratified or
            // scrambled samples do better. max is the integrand's largest value: cos cos A /
            // (pi r^2) for area sampling, S / pi for solid-angle sampling.
            const double solidAngle = SphericalRectangle(light, p).solidAngle();
            const double perSampleMax =
                name == "mc-solid-angle" ? solidAngle / kPi : integrandMax(light, p);
            const double bernoulliSd = perSampleMax / (2.0 * std::sqrt(double(s.samples)));
            INFO(name << " at " << p.x << "," << p.y << ": mean " << t.mean << ", exact " << exactF
                      << ", sd of one estimate " << t.sd << " (independent-sample "
                      << "bound " << bernoulliSd << "), rays " << t.rays / double(k));
            CHECK(std::abs(t.mean - exactF) <= 5.0 * t.sd / std::sqrt(double(k)) + biasAllowance);
            if (name == "mc-adaptive") CHECK(t.rays > uint64_t(k) * 1024);  // it did split
            // The bound holds for the plain averages (reference, solid angle); mc-adaptive
            // weights its cells and mc-ratio divides, so it does not apply to them.
            if (name == "reference" || name == "mc-solid-angle") CHECK(t.sd <= bernoulliSd);
            CHECK(t.sd > 0.0);  // a shadow edge crosses the light: the estimates must vary
            CHECK(t.rays <= uint64_t(k * s.samples));
        }
    }
}

TEST_CASE("the reference with 1024 rays is within its own statistical bound of the exact shadow",
          "[mc]") {
    const RectLight light = testLight();
    const Occluder sphere({AnalyticSphere{kSphereCenter, kSphereRadius}});
    Occluder::Query query = sphere.makeQuery();
    const Vec3 p(1.6, 0.4, 0.0);
    const Receiver r{p, kUp};
    const double exactF = exact::sphereShadowFormFactor(p, kUp, light.corner, light.edgeU,
                                                        light.edgeV, kSphereCenter, kSphereRadius);
    McSettings s;
    s.samples = 1024;
    // One estimate: within 5 x the independent-sample (Bernoulli) bound max / (2 sqrt N).
    const double sd = integrandMax(light, p) / (2.0 * std::sqrt(1024.0));
    for (uint64_t seed : {1ull, 2ull, 3ull}) {
        s.seed = seed;
        const Estimate e = monteCarloReference(r, light, query, s);
        CHECK(e.counts.shadowRays() == 1024);
        CHECK(std::abs(e.formFactor - exactF) <= 5.0 * sd);
    }
}

TEST_CASE("Monte Carlo ray counts: N above the horizon, none below, 4 for a uniform adaptive cell",
          "[mc]") {
    const RectLight light = testLight();
    const Occluder sphere({AnalyticSphere{kSphereCenter, kSphereRadius}});
    Occluder::Query query = sphere.makeQuery();
    McSettings s;
    s.samples = 32;
    s.seed = 5;
    const Receiver lit{Vec3(3.0, 3.0, 0.0), kUp};     // sees the whole light past the sphere
    const Receiver umbra{Vec3(0.6, 0.4, 0.0), kUp};   // the light's centre behind the sphere's
    const Receiver below{Vec3(0.0, 0.0, 0.0), -kUp};  // the light is behind its horizon
    const Receiver behind{Vec3(0.0, 0.0, 5.0), kUp};  // above the light: its back side
    for (const NamedEstimator& method : estimators()) {
        INFO(method.name);
        const bool adaptive = std::string(method.name) == "mc-adaptive";
        query.resetCount();
        Estimate e = method.estimate(lit, light, query, s);
        CHECK(e.counts.shadowRays() == (adaptive ? 4u : 32u));
        CHECK(query.raysCast() == e.counts.shadowRays());
        CHECK(e.formFactor > 0.0);
        e = method.estimate(umbra, light, query, s);
        CHECK(e.counts.shadowRays() == (adaptive ? 4u : 32u));
        CHECK(e.formFactor == 0.0);
        for (const Receiver& r : {below, behind}) {
            query.resetCount();
            e = method.estimate(r, light, query, s);
            CHECK(e.counts.shadowRays() == 0);
            CHECK(query.raysCast() == 0);
            CHECK(e.formFactor == 0.0);
        }
        // Same seed, same answer; the gradient is not estimated.
        CHECK(method.estimate(lit, light, query, s).formFactor ==
              method.estimate(lit, light, query, s).formFactor);
        CHECK(e.gradient == Vec3(0.0));
    }
    // A light straddling the horizon: samples below it cost no ray.
    const Receiver tilted{Vec3(0.0, 0.0, 3.0), glm::normalize(Vec3(1.0, 0.0, 0.1))};
    const Estimate e = monteCarloSolidAngle(tilted, light, query, s);
    CHECK(e.counts.shadowRays() > 0);
    CHECK(e.counts.shadowRays() < 32);
}

TEST_CASE("mc-adaptive spends more rays as its threshold falls, in the penumbra only", "[mc]") {
    const RectLight light = testLight();
    const Occluder sphere({AnalyticSphere{kSphereCenter, kSphereRadius}});
    Occluder::Query query = sphere.makeQuery();
    const Receiver r{Vec3(1.6, 0.4, 0.0), kUp};
    McSettings s;
    s.samples = 4096;
    uint64_t previous = 0;
    for (double threshold : {0.1, 0.03, 0.01, 0.003}) {
        s.threshold = threshold;
        const Trials t = runTrials(monteCarloAdaptive, r, light, query, s, 20);
        INFO("threshold " << threshold << ": " << t.rays / 20.0 << " rays");
        CHECK(t.rays >= previous);
        previous = t.rays;
        // The root (4 rays) plus whole splits of 12 rays each.
        CHECK((t.rays - 20 * 4) % 12 == 0);
    }
    CHECK(previous > 20 * 4 * 10);  // the finest threshold splits many times
}

// ---------------------------------------------------------------------------------------------
// In the renderer

namespace {

Scene tinyScene(int size) {
    return test::squareLightScene(
        size, {Obstacle{"ball", AnalyticSphere{Vec3(0.1, 0.05, 0.9), 0.3}},
               Obstacle{"box", AnalyticBox{Vec3(-0.75, -0.2, 0.4), Vec3(-0.45, 0.25, 0.65)}}});
}

}  // namespace

TEST_CASE("Monte Carlo methods render the same pixels with rays as ACI, on any thread count",
          "[mc]") {
    const Scene scene = tinyScene(40);
    RenderSettings aci;
    aci.threads = 1;
    const RenderResult base = render(scene, aci);
    REQUIRE(base.stats.viewingRaysWithShadowRays > 100);
    for (Method m :
         {Method::Reference, Method::McAdaptive, Method::McSolidAngle, Method::McRatio}) {
        INFO(methodName(m));
        CHECK(isMonteCarlo(m));
        CHECK(parseMethod(methodName(m)) == m);
        RenderSettings rs;
        rs.method = m;
        rs.mc.samples = m == Method::Reference ? 64 : 0;
        rs.threads = 1;
        const RenderResult one = render(scene, rs);
        rs.threads = 2;
        const RenderResult two = render(scene, rs);
        CHECK(one.color.data == two.color.data);
        CHECK(one.stats.shadowRays == two.stats.shadowRays);
        // Shadow rays only where the pipeline casts them, and nearly everywhere it does: a
        // Monte Carlo estimate casts none when all its samples fall below the horizon (on the
        // obstacles' sides), where ACI still traces its corners above it.
        size_t onlyAci = 0;
        for (size_t i = 0; i < one.aovs.mask.data.size(); ++i) {
            CHECK(one.aovs.mask.data[i] <= base.aovs.mask.data[i]);
            if (one.aovs.mask.data[i] < base.aovs.mask.data[i]) ++onlyAci;
        }
        CHECK(onlyAci <= base.stats.viewingRaysWithShadowRays / 100);
        const int expected = m == Method::Reference ? 64 : defaultSamples(m);
        if (m != Method::McAdaptive) {
            CHECK(one.stats.shadowRays <= uint64_t(expected) * one.stats.viewingRaysWithShadowRays);
            CHECK(one.stats.shadowRays >=
                  uint64_t(0.8 * expected * one.stats.viewingRaysWithShadowRays));
        }
        // Pixels without rays are the closed form, identical to ACI's; with rays, close to it.
        double sum = 0.0;
        for (size_t i = 0; i < one.color.data.size(); ++i) {
            const float mask = base.aovs.mask.data[i / 3];
            if (mask == 0.0f) CHECK(one.color.data[i] == base.color.data[i]);
            sum += 255.0 * std::abs(one.color.data[i] - base.color.data[i]);
        }
        const double masked = sum / (3.0 * double(base.stats.viewingRaysWithShadowRays));
        INFO("mean difference to ACI over masked pixels " << masked);
        CHECK(masked < 15.0);
    }
    // A different user seed changes the noise, not the pixels with rays.
    RenderSettings a;
    a.method = Method::McSolidAngle;
    a.threads = 1;
    RenderSettings b = a;
    b.mc.seed = 99;
    const RenderResult ra = render(scene, a), rb = render(scene, b);
    CHECK(ra.color.data != rb.color.data);
    CHECK(ra.aovs.mask.data == rb.aovs.mask.data);
}

TEST_CASE("Monte Carlo render settings out of range are refused", "[mc]") {
    const Scene scene = tinyScene(8);
    RenderSettings rs;
    rs.method = Method::McSolidAngle;
    rs.mc.samples = -1;
    CHECK_THROWS_AS(render(scene, rs), InputError);
    rs.mc.samples = 4;
    rs.mc.threshold = 0.0;
    CHECK_THROWS_AS(render(scene, rs), InputError);
    rs.mc.threshold = 0.01;
    Scene skew = scene;
    skew.lights[0].edgeV = Vec3(1.0, 0.5, 0.0);  // a parallelogram
    CHECK_THROWS_AS(render(skew, rs), InputError);
    rs.method = Method::Reference;  // area sampling handles parallelograms
    CHECK_NOTHROW(render(skew, rs));
    CHECK_THROWS_AS(parseMethod("mc-fancy"), InputError);
}
