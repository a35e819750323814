// Bias of a level-set sphere's shadow against the exact sphere: the effective silhouette radius
// that shadow rays see through Occluder::Query::occluded, found by bisection on the rays' offset
// from the centre over many directions, with the sphere built as the scene loader builds it
// (buildLevelSet of a SphereShape: the exact distance sampled at the voxel centres).
//
// Measured (OpenVDB 10, half width 3, radius 0.5): the silhouette is 0.0053 voxel inside the
// true sphere at voxel 0.02 and 0.0026 at voxel 0.01. All of it is the trilinear interpolation
// of a convex distance (between voxel centres it exceeds the exact distance by up to
// h^2 / (8 R) per tangential axis); LevelSetRayIntersector's one-voxel sampling misses grazing
// dips of at most a few thousandths of a voxel, and the occluder's bounds clipping nothing.
//
// What made the shadow look 0.19 voxel smaller was elsewhere: probe and render started every
// shadow ray 1.5 voxels off its receiver along the normal, also on receiver planes far from any
// level set, which is the shadow on a plane 1.5 voxels higher. receiverRayOffset starts them
// 1.5 voxels off only near level sets; the last test case checks the whole chain.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>

#include "support/exact_shadow.h"
#include "penumbra/level_set.h"
#include "penumbra/monte_carlo.h"
#include "penumbra/occluder.h"
#include "penumbra/renderer.h"
#include "penumbra/shape.h"

using namespace penumbra;

namespace {

constexpr double kRadius = 0.5;

/// A sphere obstacle as the scene loader builds one ("type": "sphere", not analytic).
LevelSetPtr sceneSphere(const Vec3& center, double voxel) {
    ShapeNode node;
    node.kind = SphereShape{center, kRadius};
    return buildLevelSet(node, voxel, 3.0, "sphere");
}

/// Deterministic, well spread unit vectors (a Fibonacci lattice on the sphere).
Vec3 spreadDirection(int i, int n) {
    const double z = 1.0 - (2.0 * i + 1.0) / n;
    const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
    const double phi = i * 2.399963229728653;  // the golden angle
    return Vec3(r * std::cos(phi), r * std::sin(phi), z);
}

/// A unit vector perpendicular to d, turned by angle a about d.
Vec3 perpendicular(const Vec3& d, double a) {
    const Vec3 helper = std::abs(d.x) < 0.9 ? Vec3(1, 0, 0) : Vec3(0, 1, 0);
    const Vec3 e1 = glm::normalize(glm::cross(d, helper));
    const Vec3 e2 = glm::cross(d, e1);
    return std::cos(a) * e1 + std::sin(a) * e2;
}

struct Silhouette {
    double meanBias = 0.0;   ///< effective radius - true radius, in voxels, averaged
    double worstBias = 0.0;  ///< the largest |bias| of one ray, in voxels
    double worstShift = 0.0; ///< the largest half-difference between opposite sides, in voxels
    int rays = 0;
};

/// Effective silhouette radius by bisection on the offset s of a segment (direction d, through
/// center + s u, 2 units long on each side) between hidden and visible.
double effectiveRadius(Occluder::Query& q, const Vec3& center, const Vec3& d, const Vec3& u,
                       double voxel) {
    auto hidden = [&](double s) {
        const Vec3 p = center + s * u;
        return q.occluded(p - 2.0 * d, p + 2.0 * d);
    };
    double lo = kRadius - 3.0 * voxel, hi = kRadius + 3.0 * voxel;
    INFO("a ray 3 voxels inside must be hidden and one 3 voxels outside visible");
    REQUIRE(hidden(lo));
    REQUIRE_FALSE(hidden(hi));
    for (int i = 0; i < 30; ++i) {
        const double mid = 0.5 * (lo + hi);
        (hidden(mid) ? lo : hi) = mid;
    }
    return 0.5 * (lo + hi);
}

/// The level-set sphere's silhouette, for several centres within a voxel and `directions`
/// directions each, on both sides of the centre.
Silhouette measureSilhouette(double voxel, int directions) {
    const Vec3 offsets[] = {Vec3(0.0), Vec3(0.5), Vec3(0.25, 0.7, 0.1), Vec3(0.9, 0.35, 0.6)};
    Silhouette out;
    double sum = 0.0;
    int k = 0;
    for (const Vec3& o : offsets) {
        const Vec3 center = Vec3(0.0, 0.0, 2.0) + voxel * o;
        const Occluder occ({sceneSphere(center, voxel)});
        Occluder::Query q = occ.makeQuery();
        for (int i = 0; i < directions; ++i, ++k) {
            const Vec3 d = spreadDirection(i, directions);
            const Vec3 u = perpendicular(d, 0.618033988749895 * 2.0 * kPi * k);
            const double plus = (effectiveRadius(q, center, d, u, voxel) - kRadius) / voxel;
            const double minus = (effectiveRadius(q, center, d, -u, voxel) - kRadius) / voxel;
            sum += plus + minus;
            out.rays += 2;
            out.worstBias = std::max({out.worstBias, std::abs(plus), std::abs(minus)});
            out.worstShift = std::max(out.worstShift, 0.5 * std::abs(plus - minus));
        }
    }
    out.meanBias = sum / out.rays;
    return out;
}

}  // namespace

TEST_CASE("a level-set sphere's shadow silhouette is the exact sphere's within 0.03 voxel",
          "[bias]") {
    for (const double voxel : {0.02, 0.01}) {
        const Silhouette s = measureSilhouette(voxel, 48);
        INFO("voxel " << voxel << ": " << s.rays << " rays, mean bias " << s.meanBias
                      << " voxel, worst " << s.worstBias << ", worst shift " << s.worstShift);
        // The effective radius over many directions: the shadow's size.
        CHECK(std::abs(s.meanBias) < 0.03);
        // No direction sees a much smaller or larger sphere (e.g. grazing rays missed by the
        // ray marcher), and the two sides of the centre agree (no shifted lattice).
        CHECK(s.worstBias < 0.1);
        CHECK(s.worstShift < 0.03);
    }
}

TEST_CASE("shadow rays start a hair off receivers away from level sets, 1.5 voxels on them",
          "[bias]") {
    const double voxel = 0.02;
    const Vec3 center(0.0, 0.0, 2.0);
    const Occluder occ({sceneSphere(center, voxel)});
    const double floor = 1e-9;
    // On the sphere's surface, 1 voxel and 3 voxels off it, and on a plane far below.
    CHECK(receiverRayOffset(occ, center + Vec3(0, 0, kRadius), floor) ==
          Approx(1.5 * voxel).margin(0.01 * voxel));
    CHECK(receiverRayOffset(occ, center + Vec3(kRadius + voxel, 0, 0), floor) ==
          Approx(0.5 * voxel).margin(0.02 * voxel));
    CHECK(receiverRayOffset(occ, center + Vec3(0, kRadius + 3.0 * voxel, 0), floor) == floor);
    CHECK(receiverRayOffset(occ, Vec3(0.3, 0.2, 0.0), floor) == floor);
    // Inside: as on the surface.
    CHECK(receiverRayOffset(occ, center, floor) == Approx(1.5 * voxel));
}

TEST_CASE("a level-set sphere's shadow on a plane is the exact sphere's within 0.03 voxel",
          "[bias]") {
    // The user's measurement: Monte Carlo reference on a plane under a sphere of radius 0.5 at
    // height 2 and a 2 x 2 light at height 4, over the penumbra the camera sees from above. The
    // shadow rays start where probe and render start them; 1.5 voxels off the plane made the
    // shadow that of a sphere 0.19 voxel smaller.
    const double voxel = 0.02;
    const Vec3 center(0.0, 0.0, 2.0);
    RectLight light;
    light.corner = Vec3(-1, -1, 4);
    light.edgeU = Vec3(0, 2, 0);
    light.edgeV = Vec3(2, 0, 0);
    const Occluder levelSet({sceneSphere(center, voxel)});
    const Occluder analytic({AnalyticSphere{center, kRadius}});
    Occluder::Query qLs = levelSet.makeQuery(), qAn = analytic.makeQuery();
    double dF = 0.0, dFdShrink = 0.0;
    int i = 0;
    for (double x = -2.1; x < 2.2; x += 0.2) {
        for (double y = -2.1; y < 2.2; y += 0.2, ++i) {
            const double r2 = x * x + y * y;
            if (r2 < 0.7 * 0.7 || r2 > 2.2 * 2.2) continue;
            const Receiver rc{Vec3(x, y, 0.0), Vec3(0, 0, 1)};
            McSettings mc;
            mc.samples = 4096;
            mc.seed = mcSeed(uint64_t(i), 11, 0);  // the same samples for both spheres
            mc.rayOffset = receiverRayOffset(levelSet, rc.point, 1e-9);
            const double fLs = monteCarloReference(rc, light, qLs, mc).formFactor;
            mc.rayOffset = receiverRayOffset(analytic, rc.point, 1e-9);
            const double fAn = monteCarloReference(rc, light, qAn, mc).formFactor;
            dF += fLs - fAn;
            auto exactF = [&](double radius) {
                return exact::sphereShadowFormFactor(rc.point, rc.normal, light.corner,
                                                     light.edgeU, light.edgeV, center, radius);
            };
            dFdShrink += (exactF(kRadius - 0.002) - exactF(kRadius)) / 0.002;
        }
    }
    const double shrink = dF / dFdShrink / voxel;  // equivalent radius shrink, in voxels
    INFO("equivalent shrink of the level-set sphere's shadow: " << shrink << " voxel");
    CHECK(std::abs(shrink) < 0.03);
}

TEST_CASE("shadow rays are blocked exactly where a level-set box's interpolated surface says",
          "[bias]") {
    // The default scene's box (centre (0.6, -0.4, 0.8), edge 0.6, voxel 0.01) has its faces on
    // planes of voxel centres, where the sampled distances are zero up to rounding (+5e-17 on
    // some faces): along an edge, the interpolant is negative inside the cells whose sides lie
    // on those faces and about zero on their sides. A ray that cuts through such a cell is
    // sampled only on its sides by OpenVDB's linear voxel test, which let it through: under the
    // box, rays at 15 degrees to a face passed or not in a salt-and-pepper band, and the
    // reference and Monte Carlo saw a box shadow several units too bright in 8 bits (not ACI,
    // which places its contour from the interpolant's distances). Every ray that grazes an edge
    // must be answered as the interpolant says, checked here by sampling it every 1/100 voxel;
    // a box shifted off the voxel planes is checked too.
    const double voxel = 0.01;
    const Vec3 lightCorner(-1.0, -1.0, 4.0), lightU(0.0, 2.0, 0.0), lightV(2.0, 0.0, 0.0);
    uint64_t state = 12345;
    auto uniform = [&] {
        state = state * 6364136223846793005ull + 1442695040888963407ull;
        return double(state >> 11) * (1.0 / 9007199254740992.0);
    };
    for (const Vec3 shift : {Vec3(0.0), Vec3(0.37, 0.21, 0.55) * voxel}) {
        const Vec3 centre = Vec3(0.6, -0.4, 0.8) + shift, half(0.3);
        ShapeNode node;
        node.kind = BoxShape{centre, 2.0 * half, 0.0};
        const LevelSetPtr box = buildLevelSet(node, voxel, 3.0, "box");
        const Occluder occ({box});
        Occluder::Query q = occ.makeQuery();
        int grazing = 0, checked = 0, wrong = 0;
        for (int i = 0; i < 400; ++i) {
            // A point within 0.3 voxel of one of the 12 edges, a light point, and the ray
            // through both from the receiver plane z = 0.
            const int axis = i % 3, corner = (i / 3) % 4;
            Vec3 e = centre;
            const int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
            e[axis] += (2.0 * uniform() - 1.0) * half[axis];
            e[a1] += ((corner & 1) ? 1.0 : -1.0) * half[a1] + (uniform() - 0.5) * 0.6 * voxel;
            e[a2] += ((corner & 2) ? 1.0 : -1.0) * half[a2] + (uniform() - 0.5) * 0.6 * voxel;
            const Vec3 light = lightCorner + uniform() * lightU + uniform() * lightV;
            const Vec3 d = glm::normalize(e - light);
            if (!(d.z < -0.05)) continue;
            const Vec3 receiver = light + (-light.z / d.z) * d;
            // The interpolant's minimum along the part of the segment near the box.
            double lowest = 1e9;
            const double length = glm::length(light - receiver);
            for (double t = 0.0; t <= length; t += voxel / 100.0) {
                const Vec3 x = receiver + (t / length) * (light - receiver);
                if (glm::any(glm::greaterThan(glm::abs(x - centre), half + Vec3(3.0 * voxel)))) continue;
                lowest = std::min(lowest, sampleLevelSet(*box, x));
            }
            lowest /= voxel;
            if (std::abs(lowest) < 0.01) continue;  // within the sampling's own error
            ++checked;
            if (std::abs(lowest) < 0.1) ++grazing;
            const bool blocked = q.occluded(receiver + Vec3(0.0, 0.0, 1e-6), light);
            if (blocked != (lowest < 0.0)) {
                ++wrong;
                UNSCOPED_INFO("ray " << i << " past edge " << axis << "/" << corner << ": lowest value "
                                     << lowest << " voxel, blocked " << blocked);
            }
        }
        INFO("box shifted by " << shift.x / voxel << " voxel: " << checked << " rays checked, "
                               << grazing << " within 0.1 voxel of zero");
        CHECK(grazing >= 40);  // the test exercises what it is about
        CHECK(wrong == 0);
    }
}
