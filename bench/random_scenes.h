// The seeded random-scene generator that bench_random and bench_bounds share.
//
// The generator (seed s; every draw from one splitmix64 stream seeded with s, uniform draws
// U(a, b) from its top 53 bits, so a seed gives the same scene on any platform):
//
//  - level_set.voxel_size U(0.01, 0.02) (rounded to 1e-4), half_width 3.
//  - One rectangular light: edges a, b ~ U(0.5, 3) (independently: rarely square), emitting
//    normal n tilted from straight down by U(0, 60) degrees towards a uniform azimuth, spun
//    in its plane by a uniform angle, redrawn until no edge is within 5 degrees of a world axis;
//    edge_u x edge_v = n, so it faces the receiver. Centre (U(-0.5, 0.5), U(-0.5, 0.5), h),
//    h ~ U(2.5, 5). Grey radiance chosen so that the unoccluded ground right below the light's
//    centre reads about 0.65 (0.8 albedo x radiance x F, F by the point-source approximation
//    a b cos(tilt) / (pi h^2)), like vdb_scenes/table1.json: 8-bit differences are comparable
//    across scenes. Obstacle faces close to the light are much brighter (values above 1 are kept:
//    differences are linear, not clipped).
//  - One receiver plane z = 0 (normal +z, albedo 0.8).
//  - 1 to 8 obstacles (uniform count); their kinds cycle through a random permutation of sphere,
//    box, torus, capsule, cylinder (so a scene with 5 or more has every kind). A sphere or box is
//    `"analytic": true` with probability 0.3 (analytic boxes stay axis-aligned, as the format
//    requires); everything else is a level set. Overall size D = L x 10^U(log10 0.02, log10 0.4)
//    (log-uniform from 2% to 40% of the light's longer edge L): sphere radius D/2; box sizes
//    D x U(0.25, 1) per axis with the largest set to D, turned by rotate_deg of three U(0, 360)
//    angles (level sets); torus minor radius D/2 x U(0.12, 0.35), major D/2 - minor, uniform
//    axis; capsule radius D/2 x U(0.12, 0.45), segment D - 2 radius along a uniform direction;
//    cylinder radius D/2 x U(0.15, 0.6), height D x U(0.3, 1), uniform axis. Level-set radii are
//    raised to at least 2 voxels and full sizes and heights to 3 (the format needs 1.5 voxels):
//    at small lights and coarse voxels the smallest level-set obstacles are therefore larger
//    than 2% of the edge (analytic ones are not raised). Albedo U(0.35, 0.85) per channel.
//  - Placement: a point of the light's plane at light coordinates (u, v) ~ U(-0.25, 1.25)^2, then
//    a horizontal offset uniform in a disc of radius 0.3 L + 0.3; the height is drawn in the
//    interval where the obstacle's exact extent (support function of the turned shape) stays at
//    least 0.005 above the plane and at least 0.03 from the light's plane on its emitting side:
//    one third of the obstacles "near the plane" (gap to the plane U(0.005, 0.105)), one third
//    "near the light" (gap to the light's plane U(0.03, 0.13), measured along n), one third
//    uniform in between. An empty interval redraws the point (every 40 redraws shrink D by 0.7).
//    Obstacles may overlap each other. The obstacles are receivers too (shaded with their
//    normals).
//  - Camera: fov 40 degrees, up +z, elevation U(35, 65) degrees above the horizon and a uniform
//    azimuth; look_at the centre of the bounding box of the obstacles' bounding spheres and of
//    their shadows on the plane (a disc around the centre projected from the light's centre,
//    kept within 2.5 of the obstacle's foot, radius the projected bounding radius plus half the
//    penumbra width, capped at 0.75); the eye as close as keeps every such sphere and disc, and
//    a sphere of radius 0.6 around look_at, inside the square view with 8% to spare.
//    The plane fills the picture; the light itself is not seen (lights are not rendered).
//
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <string>
#include <vector>

#include "penumbra/math.h"

namespace randomscenes {

using namespace penumbra;

// ---------------------------------------------------------------------------------------------
// Random numbers: splitmix64, platform independent (std:: distributions are not).

struct Rng {
    uint64_t state;
    // The seed goes through the mixer first, so that seeds s and s + 1 give unrelated streams.
    explicit Rng(uint64_t seed) : state(seed) { state = next() ^ 0x6A09E667F3BCC909ull; }
    uint64_t next() {
        uint64_t z = (state += 0x9E3779B97F4A7C15ull);
        z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
        z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
        return z ^ (z >> 31);
    }
    double uniform() { return double(next() >> 11) * (1.0 / 9007199254740992.0); }
    double uniform(double a, double b) { return a + (b - a) * uniform(); }
    int below(int n) { return std::min(n - 1, int(uniform() * n)); }
    Vec3 unitVector() {
        const double z = uniform(-1.0, 1.0), phi = uniform(0.0, 2.0 * kPi);
        const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
        return Vec3(r * std::cos(phi), r * std::sin(phi), z);
    }
};

inline double deg(double radians) { return radians * 180.0 / kPi; }
inline double rad(double degrees) { return degrees * kPi / 180.0; }

inline std::string num(double v) {
    char b[32];
    std::snprintf(b, sizeof b, "%.6g", std::abs(v) < 1e-12 ? 0.0 : v);
    return b;
}
inline std::string vec(const Vec3& v) { return "[" + num(v.x) + ", " + num(v.y) + ", " + num(v.z) + "]"; }
// Round-trip precision, for the light: mc-solid-angle needs edge_u perpendicular to edge_v to
// 1e-9, which 6 digits would break.
inline std::string vecExact(const Vec3& v) {
    char b[96];
    std::snprintf(b, sizeof b, "[%.17g, %.17g, %.17g]", v.x, v.y, v.z);
    return b;
}

// ---------------------------------------------------------------------------------------------
// The scene generator (documented at the top of the file).

enum Kind { Sphere, Box, Torus, Capsule, Cylinder };
const char* kKindNames[] = {"sphere", "box", "torus", "capsule", "cylinder"};

struct GenObstacle {
    Kind kind = Sphere;
    bool analytic = false;
    Vec3 center{0.0};
    double radius = 0.0;       // sphere, torus minor, capsule, cylinder
    double major = 0.0;        // torus
    Vec3 size{0.0};            // box (full extents)
    Vec3 rotateDeg{0.0};       // box
    Mat3 rotation{1.0};        // box
    Vec3 axis{0.0, 0.0, 1.0};  // torus, cylinder axis; capsule direction
    double halfLength = 0.0;   // capsule half segment; cylinder half height
    double extent = 0.0;       // overall size D as drawn (after clamping)
    const char* mode = "";

    // Half-extent along unit direction d (support function; every shape is symmetric about
    // its centre).
    double support(const Vec3& d) const {
        switch (kind) {
            case Sphere: return radius;
            case Box: {
                double s = 0.0;
                for (int i = 0; i < 3; ++i) s += 0.5 * size[i] * std::abs(glm::dot(rotation[i], d));
                return s;
            }
            case Torus: {
                const double c = glm::dot(axis, d);
                return major * std::sqrt(std::max(0.0, 1.0 - c * c)) + radius;
            }
            case Capsule: return halfLength * std::abs(glm::dot(axis, d)) + radius;
            case Cylinder: {
                const double c = glm::dot(axis, d);
                return halfLength * std::abs(c) + radius * std::sqrt(std::max(0.0, 1.0 - c * c));
            }
        }
        return 0.0;
    }
    double boundingRadius() const {
        switch (kind) {
            case Sphere: return radius;
            case Box: return 0.5 * glm::length(size);
            case Torus: return major + radius;
            case Capsule: return halfLength + radius;
            case Cylinder: return std::sqrt(halfLength * halfLength + radius * radius);
        }
        return 0.0;
    }
};

inline Mat3 rotationFromDeg(const Vec3& r) {  // as the scene format: Rz * Ry * Rx (src/shape.cpp)
    const double cx = std::cos(rad(r.x)), sx = std::sin(rad(r.x));
    const double cy = std::cos(rad(r.y)), sy = std::sin(rad(r.y));
    const double cz = std::cos(rad(r.z)), sz = std::sin(rad(r.z));
    auto rows = [](const Vec3& a, const Vec3& b, const Vec3& c) {
        return glm::transpose(Mat3(a, b, c));
    };
    const Mat3 rx = rows(Vec3(1, 0, 0), Vec3(0, cx, -sx), Vec3(0, sx, cx));
    const Mat3 ry = rows(Vec3(cy, 0, sy), Vec3(0, 1, 0), Vec3(-sy, 0, cy));
    const Mat3 rz = rows(Vec3(cz, -sz, 0), Vec3(sz, cz, 0), Vec3(0, 0, 1));
    return rz * ry * rx;
}

struct Generated {
    std::string json;
    std::string description;
};

// Which lights a scene gets. Rect: the rectangle drawn above (every figure before 2026-12-05).
// Mixed: the same draws, then a second stream (seeded from the seed alone) picks the light's
// shape among the rectangle, a disc, a triangle and a convex polygon of 5 to 7 vertices, the
// last three inscribed in the ellipse of semi-axes a/2 and b/2 on the rectangle's edges (same
// centre, plane and emitting side; the disc's radius sqrt(a b) / 2), their vertices at sorted
// uniform angles at least 20 degrees apart (redrawn until no gap reaches 180 degrees, so the
// centre is inside). The radiance is rescaled by the rectangle's area over the shape's, so the
// ground under the light still reads about 0.65. Obstacles, camera and voxel are the rect
// scene's: a seed's mixed scene differs from its rect scene in the light alone.
enum class LightShapes { Rect, Mixed };

// Volumes (generateScene's `fog`; bench_random and bench_bounds --fog): one or two fog
// obstacles more, from a third stream seeded from the seed alone: overall size D = L x
// 10^U(log10 0.15, log10 0.6), placed as the obstacles "between" (a point over the light's
// frame, a horizontal offset, a height uniform between the plane and the light's plane with
// D/2 + 0.005 and D/2 + 0.03 to spare); one sphere of radius D/2 x U(0.6, 1), or a smooth
// union (blend D/4) of 2-3 spheres of radius D/2 x U(0.35, 0.55) touching the D/2 sphere from
// inside; density U(0.5, 5), falloff 0 (3 in 10) or U(0.05, 0.5) x D/2, extinction 1, voxel
// max(the scene's, D/48). The camera frames the fogs and their shadows too, so a fog scene's
// camera differs from its seed's plain one; its light is the one --lights draws.

inline LightShapes parseLightShapes(const std::string& s) {
    if (s == "rect") return LightShapes::Rect;
    if (s == "mixed") return LightShapes::Mixed;
    std::fprintf(stderr, "--lights: '%s' is not rect or mixed\n", s.c_str());
    std::exit(2);
}

// Draws the obstacle's dimensions for overall size D.
inline void drawDimensions(GenObstacle& o, double D, double voxel, Rng& rng) {
    const double minR = o.analytic ? 1e-3 : 2.0 * voxel;   // radii
    const double minS = o.analytic ? 2e-3 : 3.0 * voxel;   // full sizes, heights
    switch (o.kind) {
        case Sphere: o.radius = std::max(minR, 0.5 * D); break;
        case Box: {
            for (int i = 0; i < 3; ++i) o.size[i] = D * rng.uniform(0.25, 1.0);
            int big = 0;
            for (int i = 1; i < 3; ++i) if (o.size[i] > o.size[big]) big = i;
            o.size[big] = D;
            for (int i = 0; i < 3; ++i) o.size[i] = std::max(minS, o.size[i]);
            if (!o.analytic) {
                o.rotateDeg = Vec3(rng.uniform(0, 360), rng.uniform(0, 360), rng.uniform(0, 360));
            } else {
                o.rotateDeg = Vec3(0.0);
            }
            o.rotation = rotationFromDeg(o.rotateDeg);
            break;
        }
        case Torus: {
            o.radius = std::max(minR, 0.5 * D * rng.uniform(0.12, 0.35));
            o.major = std::max(0.5 * D - o.radius, 1.5 * o.radius);
            o.axis = rng.unitVector();
            break;
        }
        case Capsule: {
            o.radius = std::max(minR, 0.5 * D * rng.uniform(0.12, 0.45));
            o.halfLength = std::max(0.0, 0.5 * D - o.radius);
            o.axis = rng.unitVector();
            break;
        }
        case Cylinder: {
            o.radius = std::max(minR, 0.5 * D * rng.uniform(0.15, 0.6));
            o.halfLength = 0.5 * std::max(minS, D * rng.uniform(0.3, 1.0));
            o.axis = rng.unitVector();
            break;
        }
    }
    o.extent = 2.0 * o.boundingRadius();
}

inline Generated generateScene(uint64_t seed, LightShapes shapes = LightShapes::Rect, bool fog = false,
                               double lightScale = 1.0) {
    Rng rng(seed);
    const double voxel = std::round(rng.uniform(0.01, 0.02) * 10000.0) / 10000.0;

    // The light.
    const double a = rng.uniform(0.5, 3.0), b = rng.uniform(0.5, 3.0);
    const double tilt = rad(rng.uniform(0.0, 60.0)), azimuth = rng.uniform(0.0, 2.0 * kPi);
    const Vec3 n(std::sin(tilt) * std::cos(azimuth), std::sin(tilt) * std::sin(azimuth),
                 -std::cos(tilt));  // emitting side
    const Vec3 helper = std::abs(n.x) < 0.9 ? Vec3(1, 0, 0) : Vec3(0, 1, 0);
    const Vec3 t1 = glm::normalize(helper - n * glm::dot(n, helper));
    const Vec3 t2 = glm::cross(n, t1);
    Vec3 e1, e2;
    double spin = 0.0;
    for (int tries = 0; tries < 1000; ++tries) {
        spin = rng.uniform(0.0, 2.0 * kPi);
        e1 = std::cos(spin) * t1 + std::sin(spin) * t2;
        e2 = glm::cross(n, e1);  // cross(e1, e2) = n
        bool aligned = false;
        for (const Vec3& e : {e1, e2}) {
            for (int k = 0; k < 3; ++k) aligned |= std::abs(e[k]) > std::cos(rad(5.0));
        }
        if (!aligned) break;
    }
    const double h = rng.uniform(2.5, 5.0);
    const Vec3 lightCenter(rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), h);
    const Vec3 edgeU = a * e1, edgeV = b * e2;
    const Vec3 corner = lightCenter - 0.5 * edgeU - 0.5 * edgeV;
    const double f0 = a * b * std::cos(tilt) / (kPi * h * h);
    const double radiance = std::round(0.65 / (0.8 * f0) * 1000.0) / 1000.0;
    const double L = std::max(a, b);

    // The obstacles.
    const int count = 1 + rng.below(8);
    int perm[5] = {0, 1, 2, 3, 4};
    for (int i = 4; i > 0; --i) std::swap(perm[i], perm[rng.below(i + 1)]);
    std::vector<GenObstacle> obstacles;
    for (int i = 0; i < count; ++i) {
        GenObstacle o;
        o.kind = Kind(perm[i % 5]);
        o.analytic = (o.kind == Sphere || o.kind == Box) && rng.uniform() < 0.3;
        double D = L * std::pow(10.0, rng.uniform(std::log10(0.02), std::log10(0.4)));
        const int mode = rng.below(3);
        o.mode = mode == 0 ? "near plane" : mode == 1 ? "near light" : "between";
        drawDimensions(o, D, voxel, rng);
        bool placed = false;
        for (int attempt = 0; attempt < 400 && !placed; ++attempt) {
            if (attempt > 0 && attempt % 40 == 0) {
                D *= 0.7;
                drawDimensions(o, D, voxel, rng);
            }
            const Vec3 onLight = corner + rng.uniform(-0.25, 1.25) * edgeU +
                                 rng.uniform(-0.25, 1.25) * edgeV;
            const double r = (0.3 * L + 0.3) * std::sqrt(rng.uniform());
            const double phi = rng.uniform(0.0, 2.0 * kPi);
            const double x = onLight.x + r * std::cos(phi), y = onLight.y + r * std::sin(phi);
            // Centre height: above the plane by the extent along z plus 0.005; on the emitting
            // side of the light's plane by the extent along n plus 0.03 (n.z < 0, so the signed
            // distance dot(c - lightCenter, n) falls as z grows).
            const double zLo = o.support(Vec3(0, 0, 1)) + 0.005;
            const double dxy = (x - lightCenter.x) * n.x + (y - lightCenter.y) * n.y;
            const double zHi = lightCenter.z + (o.support(n) + 0.03 - dxy) / n.z;
            if (!(zHi > zLo)) continue;
            const double room = zHi - zLo;
            double z;
            if (mode == 0) {
                z = zLo + rng.uniform(0.0, std::min(0.1, room));
            } else if (mode == 1) {
                // Along n a vertical move dz changes the distance by |n.z| dz.
                z = zHi - rng.uniform(0.0, std::min(0.1 / std::abs(n.z), room));
            } else {
                z = rng.uniform(zLo, zHi);
            }
            o.center = Vec3(x, y, z);
            placed = true;
        }
        if (!placed) continue;  // (never seen: the light is at least 0.66 above the plane)
        obstacles.push_back(o);
    }

    // Fog (Volumes, documented above): from a stream of its own.
    struct GenFog {
        std::vector<std::pair<Vec3, double>> spheres;  // centre, radius
        Vec3 centre{0.0};
        double size = 0.0, density = 0.0, falloff = 0.0, voxel = 0.0;
    };
    std::vector<GenFog> fogs;
    if (fog) {
        Rng frng(seed ^ 0x3C6EF372FE94F82Bull);
        const int fogCount = 1 + frng.below(2);
        for (int k = 0; k < fogCount; ++k) {
            GenFog f;
            double D = L * std::pow(10.0, frng.uniform(std::log10(0.15), std::log10(0.6)));
            bool placed = false;
            for (int attempt = 0; attempt < 400 && !placed; ++attempt) {
                if (attempt > 0 && attempt % 40 == 0) D *= 0.7;
                const Vec3 onLight = corner + frng.uniform(-0.25, 1.25) * edgeU +
                                     frng.uniform(-0.25, 1.25) * edgeV;
                const double r = (0.3 * L + 0.3) * std::sqrt(frng.uniform());
                const double phi = frng.uniform(0.0, 2.0 * kPi);
                const double x = onLight.x + r * std::cos(phi), y = onLight.y + r * std::sin(phi);
                const double zLo = 0.5 * D + 0.005;
                const double dxy = (x - lightCenter.x) * n.x + (y - lightCenter.y) * n.y;
                const double zHi = lightCenter.z + (0.5 * D + 0.03 - dxy) / n.z;
                if (!(zHi > zLo)) continue;
                f.centre = Vec3(x, y, frng.uniform(zLo, zHi));
                placed = true;
            }
            if (!placed) continue;
            f.size = D;
            const double R = 0.5 * D;
            const int parts = 1 + frng.below(3);
            if (parts == 1) {
                f.spheres.push_back({f.centre, R * frng.uniform(0.6, 1.0)});
            } else {
                for (int i = 0; i < parts; ++i) {
                    const double ri = R * frng.uniform(0.35, 0.55);
                    f.spheres.push_back({f.centre + (R - ri) * frng.unitVector(), ri});
                }
            }
            f.density = std::round(frng.uniform(0.5, 5.0) * 100.0) / 100.0;
            f.falloff = frng.uniform() < 0.3 ? 0.0 : std::round(frng.uniform(0.05, 0.5) * R * 1000.0) / 1000.0;
            f.voxel = std::round(std::max(voxel, D / 48.0) * 10000.0) / 10000.0;
            // A fog shrunk by many placement attempts can have parts under the 1.5 voxels the
            // format asks for (bench_bounds --lights mixed --fog, seed 7709, was refused):
            // its voxel is then made fine enough; every other scene is unchanged.
            double smallest = f.spheres.front().second;
            for (const auto& sp : f.spheres) smallest = std::min(smallest, sp.second);
            if (1.5 * f.voxel > smallest) f.voxel = std::floor(smallest / 1.5 * 10000.0) / 10000.0;
            fogs.push_back(f);
        }
    }

    // The camera: frame the obstacles and their shadows.
    struct Item {
        Vec3 c;
        double r;
    };
    std::vector<Item> items;
    Box3 roi;
    for (const GenFog& f : fogs) {
        GenObstacle o;
        o.kind = Sphere;
        o.radius = 0.5 * f.size;
        o.center = f.centre;
        obstacles.push_back(o);  // framed like a sphere; removed again below
    }
    for (const GenObstacle& o : obstacles) {
        const double rb = o.boundingRadius();
        items.push_back({o.center, rb});
        const double denom = std::max(1e-3, lightCenter.z - o.center.z);
        const double scale = lightCenter.z / denom;
        Vec3 g = lightCenter + (o.center - lightCenter) * scale;
        g.z = 0.0;
        const Vec3 foot(o.center.x, o.center.y, 0.0);
        if (glm::length(g - foot) > 2.5) g = foot + (g - foot) * (2.5 / glm::length(g - foot));
        const double rs = std::min(0.75, rb * scale + 0.5 * L * o.center.z / denom);
        items.push_back({g, rs});
    }
    for (const Item& it : items) {
        roi.extend(it.c - Vec3(it.r));
        roi.extend(it.c + Vec3(it.r));
    }
    obstacles.resize(obstacles.size() - fogs.size());
    const Vec3 lookAt = 0.5 * (roi.lo + roi.hi);
    items.push_back({lookAt, 0.6});  // frame at least 0.6 around the centre
    const double fov = 40.0, half = rad(0.5 * fov);
    const double elevation = rad(rng.uniform(35.0, 65.0)), camAz = rng.uniform(0.0, 2.0 * kPi);
    const Vec3 w(std::cos(elevation) * std::cos(camAz), std::cos(elevation) * std::sin(camAz),
                 std::sin(elevation));  // from look_at towards the eye
    const Vec3 right = glm::normalize(glm::cross(-w, Vec3(0, 0, 1)));
    const Vec3 upv = glm::cross(right, -w);
    double dist = 0.0;
    for (const Item& it : items) {
        // The item's sphere inside the square view cone: lateral offset plus r / cos(half)
        // within (distance along the axis) x tan(half), with 8% to spare.
        const Vec3 q = it.c - lookAt;
        const double lateral = std::max(std::abs(glm::dot(q, right)), std::abs(glm::dot(q, upv)));
        dist = std::max(dist, glm::dot(q, w) + 1.08 * (lateral + it.r / std::cos(half)) /
                                                   std::tan(half));
    }
    const Vec3 eye = lookAt + dist * w;

    // JSON.
    std::ostringstream js;
    js << "// bench_random seed " << seed << " (bench/bench_random.cpp documents the generator)\n";
    js << "{\n  \"camera\": {\"eye\": " << vec(eye) << ", \"look_at\": " << vec(lookAt)
       << ", \"up\": [0, 0, 1], \"fov_deg\": " << num(fov) << ", \"width\": 800, \"height\": 800},\n";
    // --light-scale: the light (whatever its shape) grown by lightScale about its centre after
    // everything else was drawn, its radiance divided by lightScale^2.
    const Vec3 lu = lightScale * edgeU, lv = lightScale * edgeV;
    const Vec3 lc = lightCenter - 0.5 * lu - 0.5 * lv;
    const double lrad = std::round(radiance / (lightScale * lightScale) * 1000.0) / 1000.0;
    std::string lightShape = "rect";
    if (shapes == LightShapes::Rect) {
        js << "  \"lights\": [\n    {\"name\": \"key\", \"corner\": " << vecExact(lc)
           << ",\n     \"edge_u\": " << vecExact(lu) << ",\n     \"edge_v\": " << vecExact(lv)
           << ",\n     \"radiance\": "
           << vec(Vec3(lrad)) << "}\n  ],\n";
    } else {
        Rng lrng(seed ^ 0xA5A5F00DCAFEBEEFull);
        const int pick = lrng.below(4);
        auto rescaled = [&](double area) {
            return std::round(radiance * a * b / (lightScale * lightScale * area) * 1000.0) / 1000.0;
        };
        if (pick == 0) {
            js << "  \"lights\": [\n    {\"name\": \"key\", \"corner\": " << vecExact(lc)
               << ",\n     \"edge_u\": " << vecExact(lu) << ",\n     \"edge_v\": "
               << vecExact(lv) << ",\n     \"radiance\": " << vec(Vec3(lrad))
               << "}\n  ],\n";
        } else if (pick == 1) {
            const double r = 0.5 * std::sqrt(a * b) * lightScale;
            lightShape = "disc";
            js << "  \"lights\": [\n    {\"name\": \"key\", \"type\": \"disc\", \"center\": "
               << vecExact(lightCenter) << ",\n     \"normal\": " << vecExact(n)
               << ", \"radius\": " << num(r) << ",\n     \"radiance\": "
               << vec(Vec3(rescaled(kPi * r * r))) << "}\n  ],\n";
        } else {
            const int k = pick == 2 ? 3 : 5 + lrng.below(3);
            std::vector<double> angles;
            for (int tries = 0; tries < 10000; ++tries) {
                angles.clear();
                for (int i = 0; i < k; ++i) angles.push_back(lrng.uniform(0.0, 2.0 * kPi));
                std::sort(angles.begin(), angles.end());
                bool ok = true;
                for (int i = 0; i < k; ++i) {
                    const double gap = i + 1 < k ? angles[i + 1] - angles[i]
                                                 : angles[0] + 2.0 * kPi - angles[i];
                    ok &= gap >= rad(20.0) && gap < kPi;
                }
                if (ok) break;
            }
            std::vector<Vec3> vs;
            for (double t : angles) {
                vs.push_back(lightScale == 1.0
                                 ? lightCenter + 0.5 * a * std::cos(t) * e1 + 0.5 * b * std::sin(t) * e2
                                 : lightCenter + lightScale * (0.5 * a * std::cos(t) * e1 + 0.5 * b * std::sin(t) * e2));
            }
            double area = 0.0;
            for (int i = 0; i < k; ++i) {
                area += 0.5 * glm::dot(glm::cross(vs[i] - lightCenter, vs[(i + 1) % k] - lightCenter), n);
            }
            lightShape = k == 3 ? "triangle" : std::to_string(k) + "-gon";
            js << "  \"lights\": [\n    {\"name\": \"key\", \"type\": \"polygon\", \"vertices\": [";
            for (int i = 0; i < k; ++i) js << (i ? ",\n       " : "") << vecExact(vs[i]);
            js << "],\n     \"radiance\": " << vec(Vec3(rescaled(area))) << "}\n  ],\n";
        }
    }
    js << "  \"obstacles\": [\n";
    std::ostringstream desc;
    char line[256];
    std::snprintf(line, sizeof line,
                  "light %s%.2f x %.2f at height %.2f, tilt %.1f deg, spin %.1f deg, radiance %.3g; "
                  "voxel %.4f; %zu obstacles:",
                  lightShape == "rect" ? "" : (lightShape + " in ").c_str(), a, b, h, deg(tilt),
                  deg(spin), radiance, voxel, obstacles.size());
    desc << line;
    for (size_t i = 0; i < obstacles.size(); ++i) {
        const GenObstacle& o = obstacles[i];
        const std::string name =
            std::string(kKindNames[o.kind]) + "_" + std::to_string(i) + (o.analytic ? "_analytic" : "");
        Rng albedoRng(seed * 1000003ull + i);
        const Vec3 albedo(albedoRng.uniform(0.35, 0.85), albedoRng.uniform(0.35, 0.85),
                          albedoRng.uniform(0.35, 0.85));
        js << "    {\"name\": \"" << name << "\", \"type\": \"" << kKindNames[o.kind] << "\", ";
        switch (o.kind) {
            case Sphere:
                js << "\"center\": " << vec(o.center) << ", \"radius\": " << num(o.radius);
                break;
            case Box:
                if (o.analytic) {
                    js << "\"center\": " << vec(o.center) << ", \"size\": " << vec(o.size);
                } else {
                    js << "\"center\": [0, 0, 0], \"size\": " << vec(o.size)
                       << ",\n     \"transform\": {\"rotate_deg\": " << vec(o.rotateDeg)
                       << ", \"translate\": " << vec(o.center) << "}";
                }
                break;
            case Torus:
                js << "\"center\": " << vec(o.center) << ", \"major_radius\": " << num(o.major)
                   << ", \"minor_radius\": " << num(o.radius) << ", \"axis\": " << vec(o.axis);
                break;
            case Capsule:
                js << "\"a\": " << vec(o.center - o.halfLength * o.axis)
                   << ", \"b\": " << vec(o.center + o.halfLength * o.axis)
                   << ", \"radius\": " << num(o.radius);
                break;
            case Cylinder:
                js << "\"center\": " << vec(o.center) << ", \"axis\": " << vec(o.axis)
                   << ", \"radius\": " << num(o.radius)
                   << ", \"height\": " << num(2.0 * o.halfLength);
                break;
        }
        if (o.analytic) js << ", \"analytic\": true";
        js << ",\n     \"albedo\": " << vec(albedo) << "}"
           << (i + 1 < obstacles.size() || !fogs.empty() ? "," : "") << "\n";
        const double gapPlane = o.center.z - o.support(Vec3(0, 0, 1));
        const double gapLight = glm::dot(o.center - lightCenter, n) - o.support(n);
        std::snprintf(line, sizeof line, " %s %.3f (%.0f%% of L, %s, gaps %.3f/%.3f)",
                      (std::string(kKindNames[o.kind]) + (o.analytic ? "*" : "")).c_str(),
                      o.extent, 100.0 * o.extent / L, o.mode, gapPlane, gapLight);
        desc << line << (i + 1 < obstacles.size() ? ";" : "");
    }
    for (size_t k = 0; k < fogs.size(); ++k) {
        const GenFog& f = fogs[k];
        js << "    {\"name\": \"fog_" << k << "\", \"type\": \"fog\", \"density\": " << num(f.density)
           << ", \"falloff\": " << num(f.falloff) << ", \"extinction\": 1, \"voxel_size\": "
           << num(f.voxel) << ",\n     \"shape\": ";
        auto sphereJson = [&](const std::pair<Vec3, double>& sp) {
            return "{\"type\": \"sphere\", \"center\": " + vec(sp.first) + ", \"radius\": " +
                   num(sp.second) + "}";
        };
        if (f.spheres.size() == 1) {
            js << sphereJson(f.spheres[0]);
        } else {
            js << "{\"type\": \"csg\", \"op\": \"smooth_union\", \"blend\": " << num(0.25 * f.size)
               << ", \"children\": [";
            for (size_t i = 0; i < f.spheres.size(); ++i)
                js << (i ? ",\n       " : "") << sphereJson(f.spheres[i]);
            js << "]}";
        }
        js << "}" << (k + 1 < fogs.size() ? "," : "") << "\n";
        std::snprintf(line, sizeof line, "; fog %.3f (%zu spheres, density %.2f, falloff %.3f, voxel %.4f)",
                      f.size, f.spheres.size(), f.density, f.falloff, f.voxel);
        desc << line;
    }
    js << "  ],\n";
    js << "  \"receivers\": [{\"type\": \"plane\", \"point\": [0, 0, 0], \"normal\": [0, 0, 1], "
          "\"albedo\": [0.8, 0.8, 0.8]}],\n";
    js << "  \"level_set\": {\"voxel_size\": " << num(voxel) << ", \"half_width\": 3},\n";
    js << "  \"background\": [0, 0, 0]\n}\n";
    return {js.str(), desc.str()};
}

}  // namespace randomscenes
