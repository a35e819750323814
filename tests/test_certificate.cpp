// Visibility certificates (Occluder::Query::certify): for a shadow segment from M to a light
// point Q, every segment from M to a point Q' with |Q' - Q| < cert.radius gets the same answer
// from occluded() as M to Q, and within cert.radiusOthers no obstacle but cert.obstacle meets
// any such segment. Checked by brute force on random segments (fixed seeds) over analytic
// spheres and boxes, level-set spheres, boxes and a torus, and mixtures of 2-6 obstacles of
// sizes down to 0.04: each certified segment is re-tested at ~64 points Q' in its disc (uniform,
// at 0.99 of the radius on the rim, and at 0.99 of the radius in the directions that push the
// segment towards or away from each obstacle's surface, the worst ones). Certificates must not
// be trivial either: analytic ones equal the exact min over t of phi(M + t (Q - M)) / t (dense
// sampling and golden-section refinement, independent of the library), level-set ones are
// conservative and their ratio to the exact value of the ideal shape is reported and bounded
// from below. Each run prints (WARN) its counts: segments, blocked, certified, mean radius,
// samples and violations, and the ratio distributions.
#include <algorithm>
#include <catch2/catch.hpp>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "penumbra/level_set.h"
#include "penumbra/occluder.h"
#include "penumbra/shape.h"

using namespace penumbra;

namespace {

using Sdf = std::function<double(const Vec3&)>;

// ---- Exact signed distances of the ideal shapes (independent of the library) -------------

double sphereSdf(const Vec3& c, double r, const Vec3& p) { return glm::length(p - c) - r; }

double boxSdf(const Vec3& lo, const Vec3& hi, const Vec3& p) {
    const Vec3 c = 0.5 * (lo + hi), h = 0.5 * (hi - lo);
    const Vec3 q = glm::abs(p - c) - h;
    const double outside = glm::length(glm::max(q, Vec3(0.0)));
    const double inside = std::min(std::max(q.x, std::max(q.y, q.z)), 0.0);
    return outside + inside;
}

double torusSdf(const Vec3& c, const Vec3& axis, double major, double minor, const Vec3& p) {
    const Vec3 d = p - c;
    const double along = glm::dot(d, axis);
    const double radial = glm::length(d - along * axis);
    return std::hypot(radial - major, along) - minor;
}

struct Obstacle {
    ObstacleShape shape;
    Sdf sdf;  // the ideal shape's exact signed distance
    std::string kind;
};

struct Scene {
    std::string name;
    std::vector<Obstacle> obstacles;
    double voxel = 0.0;  // smallest voxel, 0 for analytic scenes
};

Obstacle analyticSphere(const Vec3& c, double r) {
    return {AnalyticSphere{c, r}, [=](const Vec3& p) { return sphereSdf(c, r, p); },
            "analytic sphere"};
}
Obstacle analyticBox(const Vec3& lo, const Vec3& hi) {
    return {AnalyticBox{lo, hi}, [=](const Vec3& p) { return boxSdf(lo, hi, p); }, "analytic box"};
}
Obstacle levelSetSphere(const Vec3& c, double r, double voxel) {
    return {makeSphereLevelSet(c, r, voxel, 3.0, "ball"),
            [=](const Vec3& p) { return sphereSdf(c, r, p); }, "level-set sphere"};
}
Obstacle levelSetBox(const Vec3& lo, const Vec3& hi, double voxel) {
    return {makeBoxLevelSet(lo, hi, voxel, 3.0, "crate"),
            [=](const Vec3& p) { return boxSdf(lo, hi, p); }, "level-set box"};
}
Obstacle levelSetTorus(const Vec3& c, const Vec3& axisIn, double major, double minor,
                       double voxel) {
    const Vec3 axis = glm::normalize(axisIn);
    TorusShape t;
    t.center = c;
    t.axis = axis;
    t.majorRadius = major;
    t.minorRadius = minor;
    ShapeNode node{t, Similarity{}};
    return {buildLevelSet(node, voxel, 3.0, "ring"),
            [=](const Vec3& p) { return torusSdf(c, axis, major, minor, p); }, "level-set torus"};
}

/// PENUMBRA_CERTIFICATE_SCALE=k multiplies the number of segments (default 1: about 6 s in
/// Release on 2 cores): for stress runs, e.g. k = 20 (about 2 minutes).
int scaled(int segments) {
    const char* env = std::getenv("PENUMBRA_CERTIFICATE_SCALE");
    const double k = env ? std::atof(env) : 1.0;
    return std::max(1, int(segments * (k > 0.0 ? k : 1.0)));
}

Vec3 randomUnit(std::mt19937_64& rng) {
    std::normal_distribution<double> n(0.0, 1.0);
    for (;;) {
        const Vec3 v(n(rng), n(rng), n(rng));
        const double l = glm::length(v);
        if (l > 1e-6) return v / l;
    }
}

double uniform(std::mt19937_64& rng, double a, double b) {
    return std::uniform_real_distribution<double>(a, b)(rng);
}

double logUniform(std::mt19937_64& rng, double a, double b) {
    return std::exp(uniform(rng, std::log(a), std::log(b)));
}

/// min over t in (0, 1] of sdf(M + t v) / t, and where: dense sampling (uniform and
/// log-spaced in t) refined by golden-section search between the best sample's neighbours
/// (exact for convex distances, for which the function is unimodal; a close upper bound for
/// the others). -inf when M is inside.
struct Exact {
    double value;
    double t;
};
Exact exactRadius(const Sdf& sdf, const Vec3& m, const Vec3& v, int dense) {
    if (sdf(m) <= 0.0) return {-std::numeric_limits<double>::infinity(), 0.0};
    std::vector<double> ts;
    ts.reserve(dense + dense / 8 + 2);
    for (int k = 1; k <= dense; ++k) ts.push_back(double(k) / dense);
    const int logs = dense / 8;
    for (int k = 0; k < logs; ++k) ts.push_back(std::pow(10.0, -9.0 + 9.0 * k / logs));
    std::sort(ts.begin(), ts.end());
    auto h = [&](double t) { return sdf(m + t * v) / t; };
    size_t best = 0;
    double bestValue = std::numeric_limits<double>::infinity();
    for (size_t k = 0; k < ts.size(); ++k) {
        const double value = h(ts[k]);
        if (value < bestValue) {
            bestValue = value;
            best = k;
        }
    }
    const double a = best > 0 ? ts[best - 1] : 0.5 * ts[0];
    const double z = best + 1 < ts.size() ? ts[best + 1] : 1.0;
    const GoldenSection g = goldenSection(h, a, z, 200, 1e-15);
    Exact e{bestValue, ts[best]};
    if (g.f1 < e.value) e = {g.f1, g.m1};
    if (g.f2 < e.value) e = {g.f2, g.m2};
    return e;
}

/// Unit gradient of an sdf by central differences.
Vec3 gradient(const Sdf& sdf, const Vec3& p) {
    return unitGradient(sdf, p, 1e-6);
}

std::string fmt(const Vec3& p) {
    char buf[128];
    std::snprintf(buf, sizeof buf, "(%.17g, %.17g, %.17g)", p.x, p.y, p.z);
    return buf;
}

/// Points Q' with |Q' - Q| < rho: uniform in a disc through Q (random normal), on its rim at
/// 0.99 rho, on the sphere of radius 0.99 rho, and at 0.99 rho along +-`pushes` (the
/// directions that move the segment towards or away from each obstacle's surface).
std::vector<Vec3> discSamples(std::mt19937_64& rng, const Vec3& q, double rho,
                              const std::vector<Vec3>& pushes, int uniformCount, int rimCount,
                              int sphereCount) {
    std::vector<Vec3> out;
    const Vec3 n = randomUnit(rng);
    Vec3 e1 = glm::cross(n, std::abs(n.x) < 0.9 ? Vec3(1, 0, 0) : Vec3(0, 1, 0));
    e1 = glm::normalize(e1);
    const Vec3 e2 = glm::cross(n, e1);
    for (int k = 0; k < uniformCount + rimCount; ++k) {
        const double r = k < uniformCount ? rho * std::sqrt(uniform(rng, 0.0, 1.0)) : 0.99 * rho;
        const double a = uniform(rng, 0.0, 6.283185307179586);
        out.push_back(q + r * (std::cos(a) * e1 + std::sin(a) * e2));
    }
    for (int k = 0; k < sphereCount; ++k) out.push_back(q + 0.99 * rho * randomUnit(rng));
    for (const Vec3& d : pushes) {
        if (glm::length(d) == 0.0) continue;
        out.push_back(q + 0.99 * rho * d);
        out.push_back(q - 0.99 * rho * d);
    }
    return out;
}

struct Outcome {
    int segments = 0, blocked = 0;
    int certified = 0, certifiedBlocked = 0, reachedWant = 0;
    int othersCertified = 0;
    long samples = 0, othersSamples = 0;
    int violations = 0, othersViolations = 0, malformed = 0;
    double sumRadius = 0.0;  // over certified segments
    double sumRatio = 0.0;   // radius / want over all segments
    // Analytic obstacles: (radius - exact) / exact, and the same for radiusOthers.
    int exactCompared = 0, exactMismatches = 0;
    double worstAbove = 0.0, worstBelow = 0.0;  // relative to the exact value
    // Level sets: radius / min(|exact|, want) where exact is well away from the surface.
    std::vector<double> ratiosClear, ratiosBlocked;
    // The same where the exact value is below 0.9 want (the cap does not hide the slack).
    std::vector<double> uncappedClear, uncappedBlocked;
    std::vector<std::string> reports;
};

struct RunOptions {
    int segments = 400;
    uint64_t seed = 1;
    bool compareExact = false;  // analytic: radius must equal the exact value
    double exactBelow = 1e-6;   // ... or be below it by at most this (relative)
    bool ratios = false;        // level sets: collect radius / exact
    double span = 1.5;          // segments start within this box around the scene
    /// When set, three segments in five pass through points it draws (instead of points
    /// around a random obstacle's bounds): to aim at a feature.
    std::function<Vec3(std::mt19937_64&)> focus;
    /// Certify with Query::occludedCertified (answer and certificate in one pass) instead of
    /// occluded() then certify(); its answers must be occluded()'s.
    bool combined = false;
};

/// The certificates of random segments around `scene`, each checked by brute force.
Outcome runScene(const Scene& scene, const RunOptions& opt) {
    Outcome out;
    std::vector<ObstacleShape> shapes;
    for (const Obstacle& o : scene.obstacles) shapes.push_back(o.shape);
    Occluder occ(shapes);
    occ.prepareClearance();
    Occluder::Query q = occ.makeQuery();
    // One occluder per obstacle, to tell which one blocks and to check radiusOthers.
    std::vector<Occluder> singles;
    singles.reserve(shapes.size());
    for (const ObstacleShape& s : shapes) singles.emplace_back(std::vector<ObstacleShape>{s});
    std::vector<Occluder::Query> singleQ;
    for (const Occluder& o : singles) singleQ.push_back(o.makeQuery());

    Box3 around;
    for (size_t i = 0; i < occ.size(); ++i) {
        around.lo = i == 0 ? occ.bounds(i).lo : glm::min(around.lo, occ.bounds(i).lo);
        around.hi = i == 0 ? occ.bounds(i).hi : glm::max(around.hi, occ.bounds(i).hi);
    }
    std::mt19937_64 rng(opt.seed);
    const size_t n = scene.obstacles.size();
    const int dense = n > 2 ? 1500 : 6000;

    const int total = scaled(opt.segments);
    for (int s = 0; s < total; ++s) {
        // The segment: through a point near an obstacle (grazing or crossing it), from a
        // point near a surface, or between two points anywhere around the scene.
        const int kind = s % 5;
        Vec3 m, target;
        if (kind <= 2) {
            const size_t j = std::uniform_int_distribution<size_t>(0, n - 1)(rng);
            const Box3& b = occ.bounds(j);
            const Vec3 c = 0.5 * (b.lo + b.hi), half = 0.5 * (b.hi - b.lo);
            const Vec3 p =
                opt.focus ? opt.focus(rng)
                          : c + 1.3 * half *
                                    Vec3(uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1));
            const Vec3 d = randomUnit(rng);
            m = p - logUniform(rng, 0.02, 3.0) * d;
            target = p + logUniform(rng, 0.02, 3.0) * d;
        } else if (kind == 3) {
            // From near a surface (a few voxels to 0.2 off it, outside the ideal shape).
            const size_t j = std::uniform_int_distribution<size_t>(0, n - 1)(rng);
            const Box3& b = occ.bounds(j);
            const Vec3 c = 0.5 * (b.lo + b.hi), half = 0.5 * (b.hi - b.lo);
            m = c;
            for (int tries = 0; tries < 200; ++tries) {
                m = c + 1.2 * half *
                            Vec3(uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1));
                const double d = scene.obstacles[j].sdf(m);
                if (d > 0.0 && d < 0.2) break;
            }
            target = m + logUniform(rng, 0.05, 4.0) * randomUnit(rng);
        } else {
            const Vec3 c = 0.5 * (around.lo + around.hi);
            const Vec3 h = 0.5 * (around.hi - around.lo) + Vec3(opt.span);
            m = c + h * Vec3(uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1));
            target = m + logUniform(rng, 0.05, 6.0) * randomUnit(rng);
        }
        const double want = logUniform(rng, 0.02, 2.0);
        const Vec3 v = target - m;

        double tHit = -1.0;
        bool blocked = q.occluded(m, target, &tHit);
        Certificate cert;
        if (opt.combined) {
            double tCombined = -1.0;
            const bool answer = q.occludedCertified(m, target, want, &tCombined, cert);
            if (answer != blocked) {
                ++out.malformed;
                out.reports.push_back("occludedCertified answers " + std::to_string(answer) +
                                      ", occluded() " + std::to_string(blocked) + ": " +
                                      scene.name + " segment " + std::to_string(s));
            }
            blocked = answer;
            tHit = tCombined;
        } else {
            q.certify(m, target, blocked, blocked ? tHit : -1.0, want, cert);
        }
        ++out.segments;
        out.blocked += blocked;

        std::ostringstream where;
        where.precision(17);
        where << scene.name << " segment " << s << ": M = " << fmt(m) << ", Q = " << fmt(target)
              << ", blocked " << blocked << ", tHit " << tHit << ", want " << want << ", radius "
              << cert.radius << ", obstacle " << cert.obstacle << ", others " << cert.radiusOthers;
        if (!(cert.radius >= 0.0 && cert.radius <= want && cert.radiusOthers >= 0.0 &&
              cert.radiusOthers <= want && cert.obstacle >= -1 && cert.obstacle < int(n)) ||
            (blocked && cert.radius > 0.0 && cert.obstacle < 0)) {
            ++out.malformed;
            out.reports.push_back("malformed certificate: " + where.str());
        }
        out.sumRatio += cert.radius / want;

        // Exact values per obstacle (the ideal shapes) and the directions that push the
        // segment towards each surface at its critical place.
        std::vector<Exact> exact(n);
        std::vector<Vec3> pushes;
        for (size_t j = 0; j < n; ++j) {
            exact[j] = exactRadius(scene.obstacles[j].sdf, m, v, dense);
            const double t = std::isfinite(exact[j].value) ? exact[j].t : 1e-3;
            pushes.push_back(gradient(scene.obstacles[j].sdf, m + t * v));
        }
        double exactAll;  // the best certificate the ideal shapes allow
        {
            double clear = std::numeric_limits<double>::infinity(), deep = 0.0;
            for (const Exact& e : exact) {
                if (e.value >= 0.0)
                    clear = std::min(clear, e.value);
                else
                    deep = std::max(deep, -e.value);
            }
            exactAll = deep > 0.0 ? -deep : clear;
        }
        if (opt.compareExact) {
            // radius: the exact value capped at want; radiusOthers: the same over the
            // obstacles but the one that decides (0 when a second one is deep). Never above
            // (but for rounding: 1e-9 relative); below by at most opt.exactBelow (boxes: the
            // library's golden-section search gives away a little on purpose).
            const bool exactBlocked = exactAll < 0.0;
            if (exactBlocked == blocked && std::abs(exactAll) > 1e-9) {
                std::vector<double> clear;
                int deep = 0;
                for (const Exact& e : exact) {
                    if (e.value < 0.0)
                        ++deep;
                    else
                        clear.push_back(std::min(e.value, want));
                }
                std::sort(clear.begin(), clear.end());
                const double expected = std::min(std::abs(exactAll), want);
                double others = want;
                if (blocked)
                    others = deep > 1 ? 0.0 : (clear.empty() ? want : clear[0]);
                else if (clear.size() > 1)
                    others = clear[1];
                auto compare = [&](const char* what, double got, double ref) {
                    const double rel = (got - ref) / std::max(ref, 1e-300);
                    ++out.exactCompared;
                    out.worstAbove = std::max(out.worstAbove, rel);
                    out.worstBelow = std::max(out.worstBelow, -rel);
                    const bool above = got > ref * (1.0 + 1e-9) + 1e-15;
                    if (!above && -rel <= opt.exactBelow) return;
                    ++out.exactMismatches;
                    std::ostringstream r;
                    r.precision(17);
                    r << what << " " << got << " vs exact " << ref << " (relative " << rel
                      << "): " << where.str();
                    if (out.reports.size() < 40) out.reports.push_back(r.str());
                };
                compare("radius", cert.radius, expected);
                if (n > 1) compare("radiusOthers", cert.radiusOthers, others);
            }
        }
        if (opt.ratios) {
            const bool exactBlocked = exactAll < 0.0;
            const double ref = std::min(std::abs(exactAll), want);
            // Away from the surface by several voxels, where the ideal shape's answer is the
            // level set's.
            if (exactBlocked == blocked && ref > 4.0 * scene.voxel) {
                (blocked ? out.ratiosBlocked : out.ratiosClear).push_back(cert.radius / ref);
                if (std::abs(exactAll) < 0.9 * want)
                    (blocked ? out.uncappedBlocked : out.uncappedClear)
                        .push_back(cert.radius / ref);
            }
        }

        if (cert.radius >= want) ++out.reachedWant;
        if (cert.radius > 0.0) {
            ++out.certified;
            out.certifiedBlocked += blocked;
            out.sumRadius += cert.radius;
            for (const Vec3& qq : discSamples(rng, target, cert.radius, pushes, 24, 20, 8)) {
                ++out.samples;
                if (q.occluded(m, qq) == blocked) continue;
                ++out.violations;
                std::ostringstream r;
                r.precision(17);
                r << "VIOLATION Q' = " << fmt(qq)
                  << " (|Q' - Q| / radius = " << glm::length(qq - target) / cert.radius
                  << ") answers " << !blocked << "; per obstacle:";
                for (size_t j = 0; j < n; ++j)
                    r << " [" << j << " " << scene.obstacles[j].kind << " "
                      << singleQ[j].occluded(m, qq) << "]";
                r << "; " << where.str();
                if (out.reports.size() < 40) out.reports.push_back(r.str());
            }
        }
        if (cert.radiusOthers > 0.0 && n > 1) {
            ++out.othersCertified;
            std::vector<Vec3> otherPushes;
            for (size_t j = 0; j < n; ++j)
                if (int(j) != cert.obstacle) otherPushes.push_back(pushes[j]);
            for (const Vec3& qq :
                 discSamples(rng, target, cert.radiusOthers, otherPushes, 12, 8, 4)) {
                for (size_t j = 0; j < n; ++j) {
                    if (int(j) == cert.obstacle) continue;
                    ++out.othersSamples;
                    if (!singleQ[j].occluded(m, qq)) continue;
                    ++out.othersViolations;
                    std::ostringstream r;
                    r.precision(17);
                    r << "OTHERS VIOLATION: obstacle " << j << " (" << scene.obstacles[j].kind
                      << ") blocks Q' = " << fmt(qq) << " (|Q' - Q| / radiusOthers = "
                      << glm::length(qq - target) / cert.radiusOthers << "); " << where.str();
                    if (out.reports.size() < 40) out.reports.push_back(r.str());
                }
            }
        }
    }
    return out;
}

double quantile(std::vector<double> v, double p) {
    if (v.empty()) return std::nan("");
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, size_t(p * double(v.size() - 1) + 0.5))];
}

std::string summary(const std::string& name, const Outcome& o) {
    char buf[1024];
    int len = std::snprintf(
        buf, sizeof buf,
        "%s: %d segments (%d blocked), %d certified (%d blocked), %d reach want, mean radius "
        "%.4g (certified), mean radius/want %.3f; %ld samples, %d violations; radiusOthers on "
        "%d, %ld samples, %d violations",
        name.c_str(), o.segments, o.blocked, o.certified, o.certifiedBlocked, o.reachedWant,
        o.certified ? o.sumRadius / o.certified : 0.0, o.sumRatio / std::max(1, o.segments),
        o.samples, o.violations, o.othersCertified, o.othersSamples, o.othersViolations);
    std::string s(buf, size_t(std::max(0, len)));
    if (o.exactCompared) {
        std::snprintf(buf, sizeof buf,
                      "; compared with the exact value %d times, worst relative %.3g above, "
                      "%.3g below",
                      o.exactCompared, o.worstAbove, o.worstBelow);
        s += buf;
    }
    for (int b = 0; b < 4; ++b) {
        const std::vector<double>& r = b == 0   ? o.ratiosClear
                                       : b == 1 ? o.ratiosBlocked
                                       : b == 2 ? o.uncappedClear
                                                : o.uncappedBlocked;
        if (r.empty()) continue;
        const double zero = double(std::count(r.begin(), r.end(), 0.0)) / r.size();
        std::snprintf(buf, sizeof buf,
                      "; radius/min(exact,want) %s (n %zu): min %.3f p10 %.3f median %.3f p90 "
                      "%.3f max %.3f, zero %.1f%%",
                      b == 0   ? "clear"
                      : b == 1 ? "blocked"
                      : b == 2 ? "clear, exact < 0.9 want"
                               : "blocked, exact < 0.9 want",
                      r.size(), quantile(r, 0.0), quantile(r, 0.1), quantile(r, 0.5),
                      quantile(r, 0.9), quantile(r, 1.0), 100.0 * zero);
        s += buf;
    }
    return s;
}

void checkOutcome(const std::string& name, const Outcome& o) {
    const std::string line = summary(name, o);
    WARN(line);
    std::string reports;
    for (const std::string& r : o.reports) reports += r + "\n";
    INFO(reports);  // with every failed check below
    CHECK(o.malformed == 0);
    CHECK(o.violations == 0);
    CHECK(o.othersViolations == 0);
    CHECK(o.exactMismatches == 0);
    // Not trivial: a fair share of the segments is certified, and checked.
    CHECK(o.certified > o.segments / 4);
    CHECK(o.samples > 40L * o.certified);
}

/// 2-6 obstacles of sizes 0.04 to 0.5 in [-1, 1]^3: analytic, level sets, or both. Level sets
/// get voxels of 0.01 up to a size of 0.2, 0.02 beyond.
Scene randomMixture(uint64_t seed, bool analytic, bool levelSets) {
    std::mt19937_64 rng(seed);
    Scene s;
    s.voxel = levelSets ? 0.01 : 0.0;
    const int count = std::uniform_int_distribution<int>(2, 6)(rng);
    for (int i = 0; i < count; ++i) {
        const Vec3 c(uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1));
        // The first two: the smallest and a large one, so that every mixture has both.
        const double size = i == 0 ? 0.04 : i == 1 ? 0.45 : logUniform(rng, 0.04, 0.5);
        const bool ls = levelSets && (!analytic || i % 2 == 0);
        const double voxel = size > 0.2 ? 0.02 : 0.01;
        const int shape = std::uniform_int_distribution<int>(0, ls && size > 0.15 ? 2 : 1)(rng);
        if (shape == 0) {
            s.obstacles.push_back(ls ? levelSetSphere(c, size, voxel) : analyticSphere(c, size));
        } else if (shape == 1) {
            const Vec3 half =
                size * Vec3(uniform(rng, 0.5, 1), uniform(rng, 0.5, 1), uniform(rng, 0.5, 1));
            s.obstacles.push_back(ls ? levelSetBox(c - half, c + half, voxel)
                                     : analyticBox(c - half, c + half));
        } else {
            s.obstacles.push_back(levelSetTorus(c, randomUnit(rng), size, 0.3 * size, voxel));
        }
    }
    return s;
}

}  // namespace

TEST_CASE("certificates of analytic spheres and boxes hold and are exact", "[certificate]") {
    RunOptions opt;
    opt.compareExact = true;
    opt.segments = 1500;
    SECTION("sphere") {
        Scene s{"analytic sphere", {analyticSphere(Vec3(0.1, -0.2, 0.3), 0.5)}};
        opt.seed = 101;
        const Outcome o = runScene(s, opt);
        checkOutcome(s.name, o);
        CHECK(o.exactCompared > 1000);
        CHECK(o.certifiedBlocked > 100);
    }
    SECTION("small sphere") {
        Scene s{"analytic sphere r 0.04", {analyticSphere(Vec3(0.3, 0.2, -0.1), 0.04)}};
        opt.seed = 102;
        const Outcome o = runScene(s, opt);
        checkOutcome(s.name, o);
        CHECK(o.exactCompared > 1000);
    }
    SECTION("box") {
        Scene s{"analytic box", {analyticBox(Vec3(-0.4, -0.3, -0.2), Vec3(0.5, 0.1, 0.35))}};
        opt.seed = 103;
        opt.exactBelow = 1e-4;
        const Outcome o = runScene(s, opt);
        checkOutcome(s.name, o);
        CHECK(o.exactCompared > 1000);
        CHECK(o.certifiedBlocked > 100);
    }
}

TEST_CASE("certificates of level-set spheres, boxes and a torus hold", "[certificate]") {
    RunOptions opt;
    opt.ratios = true;
    opt.segments = 700;
    // Lower bounds on the certificates' quality: the median of radius / exact (the ideal
    // shape's value, on segments several voxels from the surface whose exact value is below
    // 0.9 want, so that the cap hides no slack). Measured (seeds below, 2026-12-02): spheres
    // 0.80-0.85 clear, 0.80-0.87 blocked; boxes 0.80-0.81 and 0.80-0.81; the torus 0.59 and
    // 0.78 (blocked 0.61-0.83 before the depth was measured where the cell tables show the
    // chord deepest).
    auto run = [&](const Scene& s, uint64_t seed, double minMedianClear, double minMedianBlocked) {
        opt.seed = seed;
        const Outcome o = runScene(s, opt);
        checkOutcome(s.name, o);
        CHECK(o.uncappedClear.size() > 50);
        CHECK(o.uncappedBlocked.size() > 15);
        CHECK(quantile(o.uncappedClear, 0.5) >= minMedianClear);
        CHECK(quantile(o.uncappedBlocked, 0.5) >= minMedianBlocked);
        // Not above the exact value, but for the level set's own surface error.
        CHECK(quantile(o.ratiosClear, 1.0) <= 1.05);
        CHECK(quantile(o.ratiosBlocked, 1.0) <= 1.05);
    };
    SECTION("sphere, voxel 0.02") {
        run({"level-set sphere v0.02", {levelSetSphere(Vec3(0.1, -0.2, 0.3), 0.5, 0.02)}, 0.02},
            201, 0.55, 0.6);
    }
    SECTION("sphere, voxel 0.01") {
        run({"level-set sphere v0.01", {levelSetSphere(Vec3(-0.1, 0.05, 0.2), 0.3, 0.01)}, 0.01},
            202, 0.55, 0.6);
    }
    SECTION("box, voxel 0.02") {
        run({"level-set box v0.02",
             {levelSetBox(Vec3(-0.4, -0.3, -0.2), Vec3(0.5, 0.1, 0.35), 0.02)},
             0.02},
            203, 0.4, 0.45);
    }
    SECTION("box, voxel 0.01") {
        run({"level-set box v0.01",
             {levelSetBox(Vec3(-0.2, -0.25, -0.1), Vec3(0.3, 0.1, 0.15), 0.01)},
             0.01},
            204, 0.4, 0.45);
    }
    SECTION("torus, voxel 0.01") {
        run({"level-set torus v0.01",
             {levelSetTorus(Vec3(0.05, 0.0, -0.1), Vec3(0.3, 0.2, 1.0), 0.4, 0.12, 0.01)},
             0.01},
            205, 0.5, 0.5);
    }
}

TEST_CASE("certificates of primitives whose companion is their own distance hold",
          "[certificate]") {
    // buildLevelSet gives a lone smooth primitive a companion sampled from its exact distance
    // (LevelSet::setFarFieldRecipe) instead of one meshed from the fine surface; the
    // certificates subtract how far it strays from the fine grid all the same.
    RunOptions opt;
    opt.ratios = true;
    opt.segments = 500;
    auto run = [&](const std::string& name, const ShapeKind& kind, const Similarity& t,
                   const Sdf& sdf, double voxel, uint64_t seed) {
        opt.seed = seed;
        const Scene s{name, {Obstacle{buildLevelSet(ShapeNode{kind, t}, voxel, 3.0, "built"), sdf,
                                      name}},
                      voxel};
        const Outcome o = runScene(s, opt);
        checkOutcome(s.name, o);
        CHECK(o.uncappedClear.size() > 30);
        CHECK(quantile(o.ratiosClear, 1.0) <= 1.05);
        CHECK(quantile(o.ratiosBlocked, 1.0) <= 1.05);
    };
    SECTION("sphere, voxel 0.02") {
        SphereShape sphere;
        sphere.center = Vec3(0.1, -0.2, 0.3);
        sphere.radius = 0.45;
        run("built sphere v0.02", sphere, Similarity{}, [](const Vec3& p) {
            return sphereSdf(Vec3(0.1, -0.2, 0.3), 0.45, p);
        }, 0.02, 211);
    }
    SECTION("sphere scaled 2x and moved, voxel 0.01") {
        SphereShape sphere;
        sphere.center = Vec3(0.05, 0.0, -0.05);
        sphere.radius = 0.15;
        Similarity t;
        t.scale = 2.0;
        t.translate = Vec3(0.05, -0.1, 0.0);
        // World centre 2 (0.05, 0, -0.05) + (0.05, -0.1, 0), radius 0.3.
        run("built sphere scaled v0.01", sphere, t, [](const Vec3& p) {
            return sphereSdf(Vec3(0.15, -0.1, -0.1), 0.3, p);
        }, 0.01, 212);
    }
    SECTION("capsule, voxel 0.01") {
        CapsuleShape c;
        c.a = Vec3(-0.3, -0.1, -0.2);
        c.b = Vec3(0.25, 0.2, 0.3);
        c.radius = 0.15;
        run("built capsule v0.01", c, Similarity{}, [c](const Vec3& p) {
            const Vec3 pa = p - c.a, ba = c.b - c.a;
            const double h = std::clamp(glm::dot(pa, ba) / glm::dot(ba, ba), 0.0, 1.0);
            return glm::length(pa - h * ba) - c.radius;
        }, 0.01, 213);
    }
    SECTION("torus two and a half voxels thick, voxel 0.01") {
        TorusShape r;
        r.center = Vec3(0.0, 0.1, -0.05);
        r.axis = glm::normalize(Vec3(0.4, -0.3, 1.0));
        r.majorRadius = 0.2;
        r.minorRadius = 0.025;
        run("built thin torus v0.01", r, Similarity{}, [r](const Vec3& p) {
            return torusSdf(r.center, r.axis, r.majorRadius, r.minorRadius, p);
        }, 0.01, 214);
    }
}

TEST_CASE("certificates next to features thinner than the far-field companion's voxels hold",
          "[certificate]") {
    // The companion (4x coarser voxels) loses a plate 3 fine voxels thick, a tube of radius 2
    // voxels and a sphere of radius 4: its measured error must make certificates near them
    // prove less, never something false.
    RunOptions opt;
    opt.ratios = true;
    opt.segments = 400;
    opt.seed = 601;
    Scene s{"thin features v0.01",
            {levelSetBox(Vec3(-0.3, -0.3, 0.0), Vec3(0.3, 0.3, 0.03), 0.01),
             levelSetTorus(Vec3(0.2, 0.1, 0.4), Vec3(0.2, -0.5, 1.0), 0.25, 0.02, 0.01),
             levelSetSphere(Vec3(-0.2, 0.25, -0.3), 0.04, 0.01)},
            0.01};
    const Outcome o = runScene(s, opt);
    checkOutcome(s.name, o);
}

TEST_CASE("certificates around one level set whose companion is poor in one place hold",
          "[certificate]") {
    // One grid: a ball of radius 0.35 with a thin ring (tube radius 2 voxels, which the
    // companion loses) and a thin plate (3 voxels) joined to it. The companion's error is
    // measured block by block (occluder.cpp, CompanionError): large near the ring and plate,
    // small around the rest of the ball, and certificates there lean on the small one.
    const double voxel = 0.01;
    const Vec3 ballC(0.0), ringC(0.3, 0.1, 0.2), ringAxis = glm::normalize(Vec3(0.2, -0.5, 1.0));
    const Vec3 plateLo(-0.6, -0.6, -0.33), plateHi(-0.1, 0.1, -0.30);
    CsgShape csg;
    csg.op = CsgOp::Union;
    csg.children.push_back(ShapeNode{SphereShape{ballC, 0.35}, Similarity{}});
    TorusShape ring;
    ring.center = ringC;
    ring.axis = ringAxis;
    ring.majorRadius = 0.25;
    ring.minorRadius = 0.02;
    csg.children.push_back(ShapeNode{ring, Similarity{}});
    BoxShape plate;
    plate.center = 0.5 * (plateLo + plateHi);
    plate.size = plateHi - plateLo;
    csg.children.push_back(ShapeNode{plate, Similarity{}});
    Obstacle joined{buildLevelSet(ShapeNode{csg, Similarity{}}, voxel, 3.0, "ball and ring"),
                    [=](const Vec3& p) {
                        return std::min({sphereSdf(ballC, 0.35, p),
                                         torusSdf(ringC, ringAxis, 0.25, 0.02, p),
                                         boxSdf(plateLo, plateHi, p)});
                    },
                    "level-set ball, ring and plate"};
    Scene s{"ball, ring and plate in one grid v0.01", {joined}, voxel};
    RunOptions opt;
    opt.ratios = true;
    opt.segments = 500;
    opt.seed = 607;
    SECTION("segments anywhere around it") {
        const Outcome o = runScene(s, opt);
        checkOutcome(s.name, o);
    }
    SECTION("segments grazing the ring, where the companion has lost it") {
        // Through points 0.5 to 6 voxels off the ring's tube.
        Vec3 e1 = glm::normalize(glm::cross(ringAxis, Vec3(1.0, 0.0, 0.0)));
        Vec3 e2 = glm::cross(ringAxis, e1);
        opt.focus = [=](std::mt19937_64& rng) {
            const double a = uniform(rng, 0.0, 2.0 * kPi), b = uniform(rng, 0.0, 2.0 * kPi);
            const Vec3 radial = std::cos(a) * e1 + std::sin(a) * e2;
            const double off = 0.02 + logUniform(rng, 0.005, 0.06);
            return ringC + 0.25 * radial + off * (std::cos(b) * radial + std::sin(b) * ringAxis);
        };
        const Outcome o = runScene(s, opt);
        checkOutcome(s.name + " (grazing the ring)", o);
    }
}

TEST_CASE("certificates over mixtures of 2-6 obstacles hold, radiusOthers too", "[certificate]") {
    RunOptions opt;
    opt.segments = 500;
    opt.exactBelow = 1e-4;  // boxes
    // Scenes randomMixture(seed + k), runs seeded seed + 10 + k.
    struct Group {
        uint64_t seed;
        uint64_t count;
        bool analytic, levelSets;
        const char* name;
    };
    for (const Group& g : {Group{300, 3, true, false, "analytic mixture "},
                           Group{400, 2, false, true, "level-set mixture "},
                           Group{500, 2, true, true, "mixed analytic + level-set "}}) {
        opt.compareExact = !g.levelSets;  // level sets: conservative bounds
        for (uint64_t k = 0; k < g.count; ++k) {
            Scene s = randomMixture(g.seed + k, g.analytic, g.levelSets);
            s.name = g.name + std::to_string(k) + " (" + std::to_string(s.obstacles.size()) +
                     (g.levelSets ? " obstacles, voxels 0.01 and 0.02)" : " obstacles)");
            opt.seed = g.seed + 10 + k;
            const Outcome o = runScene(s, opt);
            checkOutcome(s.name, o);
            CHECK(o.othersCertified > 50);
        }
    }
}

TEST_CASE("certificates of segments far from every obstacle reach the radius asked for",
          "[certificate]") {
    Occluder occ({AnalyticSphere{Vec3(0.0), 0.5}, AnalyticBox{Vec3(1, 1, 1), Vec3(1.5, 1.5, 1.5)},
                  makeSphereLevelSet(Vec3(-1, 0, 0), 0.3, 0.02, 3.0),
                  makeBoxLevelSet(Vec3(0, -1.5, 0), Vec3(0.4, -1.1, 0.4), 0.01, 3.0)});
    occ.prepareClearance();
    Occluder::Query q = occ.makeQuery();
    for (double want : {0.05, 0.5, 1.41}) {
        // Far away, and between obstacles (0.6 from the nearest surface at any t <= 1).
        const std::vector<std::pair<Vec3, Vec3>> segs = {
            {Vec3(10, 10, 10), Vec3(12, 10, 11)},
            {Vec3(0.0, 0.0, 3.0), Vec3(0.0, 0.0, 6.0)},  // away from everything
            {Vec3(5, -5, 0), Vec3(5, 5, 0.5)}};
        for (const auto& s : segs) {
            double tHit = -1.0;
            const bool blocked = q.occluded(s.first, s.second, &tHit);
            REQUIRE_FALSE(blocked);
            Certificate c;
            q.certify(s.first, s.second, false, -1.0, want, c);
            INFO("want " << want << " M " << fmt(s.first) << " Q " << fmt(s.second));
            CHECK(c.radius == want);
            CHECK(c.radiusOthers == want);
            CHECK(c.obstacle == -1);
        }
    }
    // A segment through the middle of the level-set sphere from far: deep, certified.
    {
        const Vec3 m(-1, 0, -3), t(-1, 0, 3);
        double tHit = -1.0;
        REQUIRE(q.occluded(m, t, &tHit));
        Certificate c;
        q.certify(m, t, true, tHit, 1.41, c);
        // Exact: max over s of (0.3 - |p(s) - C|) / s, at the centre s = 0.5: 0.6.
        CHECK(c.obstacle == 2);
        CHECK(c.radius > 0.3);
        CHECK(c.radius <= 0.6 + 1e-9);
    }
    // Passing the analytic sphere at 0.2 with the rest far: the exact radius at t = 1 is 0.2
    // (closest approach at the end), and the others prove more.
    {
        const Vec3 m(0.7, 0.0, -3.0), t(0.7, 0.0, 0.0);
        double tHit = -1.0;
        REQUIRE_FALSE(q.occluded(m, t, &tHit));
        Certificate c;
        q.certify(m, t, false, -1.0, 1.41, c);
        CHECK(c.obstacle == 0);
        CHECK(c.radius == Approx(0.2).epsilon(1e-9));
        CHECK(c.radiusOthers > 0.2);
    }
}

TEST_CASE("analytic box: a blocked segment's radius does not exceed the exact depth bound",
          "[certificate]") {
    // Found by the mixture runs above at 20 times the segments (analytic mixture 1, segments
    // 4868 and 8598; obstacle 0 is this box). The certificate of a blocked segment is the
    // depth bound max over t of -phi(M + t (Q - M)) / t; the library's golden-section search
    // (boxRadius) shaves its result by the bracket's slack whatever its sign, which for a
    // blocked segment (negative value) makes the claimed depth larger than the exact one: by
    // 8e-5 relative (1e-5 absolute) in the first case. No occluded() answer was found to flip
    // (the bound has slack at a box's edges), but the radius breaks the documented promise.
    const AnalyticBox box{Vec3(0.60264050911145584, -0.56065158749809585, -0.65301270889502938),
                          Vec3(0.67837247537996326, -0.49933936484508218, -0.59141953665352387)};
    const Sdf sdf = [&](const Vec3& p) { return boxSdf(box.lo, box.hi, p); };
    Occluder occ({box});
    Occluder::Query q = occ.makeQuery();
    struct Case {
        Vec3 m, q;
        double want;
    };
    const Case cases[] = {
        {Vec3(0.67920862237977542, -0.52751369246158442, -0.65184297495713117),
         Vec3(-0.99029462506143473, 0.57624295311729834, -2.6994788602740289), 0.55124800788456274},
        {Vec3(0.66865467480996688, -0.53302525221960151, -0.65571981545686209),
         Vec3(0.32908557761386709, -1.4267164420161205, -0.56725626847838395), 1.7697759334264673}};
    for (const Case& c : cases) {
        double tHit = -1.0;
        REQUIRE(q.occluded(c.m, c.q, &tHit));
        Certificate cert;
        q.certify(c.m, c.q, true, tHit, c.want, cert);
        const Exact e = exactRadius(sdf, c.m, c.q - c.m, 200000);
        REQUIRE(e.value < 0.0);
        const double depth = std::min(-e.value, c.want);
        INFO("M " << fmt(c.m) << " Q " << fmt(c.q) << " radius " << cert.radius
                  << " exact depth bound " << depth << " relative excess "
                  << (cert.radius - depth) / depth);
        CHECK(cert.obstacle == 0);
        CHECK(cert.radius <= depth * (1.0 + 1e-9));
        CHECK(cert.radius >= depth * (1.0 - 1e-4));
    }
}

TEST_CASE("a clear segment passing within half a voxel of a level set still proves a disc",
          "[certificate]") {
    // The tracer reports a hit only where the trilinear interpolant changes sign, so a segment
    // along which the interpolant stays positive is clear, and the interpolant's value over its
    // gradient bound is a sound distance for a clear certificate: no half-voxel margin is taken
    // off it (a depth keeps one, since a segment that dips barely inside can pass between the
    // tracer's samples). With the margin, every segment passing within half a voxel of a
    // surface proved nothing, and so did most of the light seen from a ground point next to an
    // obstacle's base (random seed 8 of bench_random). Here: 0.4 voxel from a sphere at a
    // sixth of the way, exact radius about 0.048.
    const double voxel = 0.02;
    Occluder occ({makeSphereLevelSet(Vec3(0.0), 0.3, voxel, 3.0)});
    occ.prepareClearance();
    Occluder::Query q = occ.makeQuery();
    const Vec3 m(-0.5, 0.3 + 0.4 * voxel, 0.0), target(2.5, 0.3 + 0.4 * voxel, 0.0);
    double tHit = -1.0;
    REQUIRE_FALSE(q.occluded(m, target, &tHit));
    Certificate c;
    q.certify(m, target, false, -1.0, 1.0, c);
    CAPTURE(c.radius);
    CHECK(c.radius > 0.02);
    CHECK(c.radius < 0.05);
    // Every segment to a point within that radius of the target is clear.
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u01(0.0, 1.0);
    std::normal_distribution<double> gauss(0.0, 1.0);
    int blocked = 0;
    for (int i = 0; i < 4000; ++i) {
        const Vec3 dir = glm::normalize(Vec3(gauss(rng), gauss(rng), gauss(rng)));
        const Vec3 other = target + c.radius * std::cbrt(u01(rng)) * dir;
        blocked += q.occluded(m, other) ? 1 : 0;
    }
    CHECK(blocked == 0);
}

TEST_CASE("answers and certificates in one pass: occluded()'s answers, certificates that hold",
          "[certificate]") {
    // Query::occludedCertified: sphere tracing on the cell tables proves a clear segment's cone
    // on the way, and the intersector starts where that tracing stops. The same brute-force
    // check as above, on level sets alone and mixed with analytic shapes; every answer must be
    // occluded()'s (runScene counts a difference as malformed).
    RunOptions opt;
    opt.combined = true;
    opt.ratios = true;
    opt.segments = 500;
    SECTION("level-set sphere, box and torus") {
        for (const Scene& s :
             {Scene{"one pass: level-set sphere v0.02",
                    {levelSetSphere(Vec3(0.1, -0.2, 0.3), 0.5, 0.02)}, 0.02},
              Scene{"one pass: level-set box v0.01",
                    {levelSetBox(Vec3(-0.2, -0.25, -0.1), Vec3(0.3, 0.1, 0.15), 0.01)}, 0.01},
              Scene{"one pass: level-set torus v0.01",
                    {levelSetTorus(Vec3(0.05, 0.0, -0.1), Vec3(0.3, 0.2, 1.0), 0.4, 0.12, 0.01)},
                    0.01}}) {
            opt.seed += 7;
            const Outcome o = runScene(s, opt);
            checkOutcome(s.name, o);
            CHECK(o.certifiedBlocked > 20);
            // Clear segments' cones from the tracing are somewhat narrower than the cone
            // march's (measured medians 0.55-0.9 of the exact value, 0.55-0.7 before).
            CHECK(quantile(o.uncappedClear, 0.5) >= 0.4);
        }
    }
    SECTION("thin features and mixtures") {
        Scene thin{"one pass: thin features v0.01",
                   {levelSetBox(Vec3(-0.3, -0.3, 0.0), Vec3(0.3, 0.3, 0.03), 0.01),
                    levelSetTorus(Vec3(0.2, 0.1, 0.4), Vec3(0.2, -0.5, 1.0), 0.25, 0.02, 0.01),
                    levelSetSphere(Vec3(-0.2, 0.25, -0.3), 0.04, 0.01)},
                   0.01};
        opt.seed = 901;
        checkOutcome(thin.name, runScene(thin, opt));
        opt.ratios = false;
        opt.exactBelow = 1e-4;
        for (uint64_t k = 0; k < 2; ++k) {
            Scene s = randomMixture(950 + k, true, true);
            s.name = "one pass: mixed analytic + level-set " + std::to_string(k);
            opt.seed = 960 + k;
            const Outcome o = runScene(s, opt);
            checkOutcome(s.name, o);
        }
    }
}
