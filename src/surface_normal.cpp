#include "surface_normal.h"

#include <cmath>
#include <variant>

#include <openvdb/tools/Interpolation.h>

#include "level_set_impl.h"
#include "overloaded.h"

namespace penumbra {

namespace {

Vec3 normalOr(const Vec3& v, const Vec3& fallback) {
    double len = glm::length(v);
    return len > 0.0 && std::isfinite(len) ? v / len : fallback;
}

Vec3 sphereNormal(const AnalyticSphere& s, const Vec3& p) {
    return normalOr(p - s.center, Vec3(0.0, 0.0, 1.0));
}

Vec3 boxNormal(const AnalyticBox& b, const Vec3& p) {
    // The face nearest to p: exact on the faces, and the natural choice on edges and corners.
    double best = std::abs(p.x - b.lo.x);
    Vec3 n(-1.0, 0.0, 0.0);
    for (int a = 0; a < 3; ++a) {
        double dLo = std::abs(p[a] - b.lo[a]);
        double dHi = std::abs(p[a] - b.hi[a]);
        if (dLo < best) {
            best = dLo;
            n = Vec3(0.0);
            n[a] = -1.0;
        }
        if (dHi < best) {
            best = dHi;
            n = Vec3(0.0);
            n[a] = 1.0;
        }
    }
    return n;
}

Vec3 levelSetNormal(const LevelSet& ls, const Vec3& p) {
    const openvdb::FloatGrid& grid = ls.grid();
    openvdb::FloatGrid::ConstAccessor acc = grid.getConstAccessor();
    openvdb::tools::GridSampler<openvdb::FloatGrid::ConstAccessor, openvdb::tools::BoxSampler>
        sampler(acc, grid.transform());
    // Central differences one voxel apart in world space: the trilinear field is smooth enough
    // at that scale, and sampling in world space honours any (uniform) linear transform.
    const double h = ls.voxelSize();
    Vec3 g(0.0);
    for (int a = 0; a < 3; ++a) {
        openvdb::Vec3d plus(p.x, p.y, p.z), minus(p.x, p.y, p.z);
        plus[a] += h;
        minus[a] -= h;
        g[a] = double(sampler.wsSample(plus)) - double(sampler.wsSample(minus));
    }
    return normalOr(g, Vec3(0.0, 0.0, 1.0));
}

}  // namespace

Vec3 surfaceNormal(const ObstacleShape& shape, const Vec3& pointWS) {
    return std::visit(
        Overloaded{[&](const AnalyticSphere& s) { return sphereNormal(s, pointWS); },
                   [&](const AnalyticBox& b) { return boxNormal(b, pointWS); },
                   [&](const LevelSetPtr& ls) {
                       return ls ? levelSetNormal(*ls, pointWS) : Vec3(0.0, 0.0, 1.0);
                   }},
        shape);
}

}  // namespace penumbra
