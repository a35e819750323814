#include "penumbra/estimator.h"

#include <algorithm>
#include <cmath>
#include <map>

#include "penumbra/contour_integrator.h"
#include "penumbra/error.h"
#include "penumbra/monte_carlo.h"

namespace penumbra {

const char* methodName(Method method) {
    switch (method) {
        case Method::Aci: return "aci";
        case Method::AciPixel: return "aci-pixel";
        case Method::Reference: return "reference";
        case Method::McAdaptive: return "mc-adaptive";
        case Method::McSolidAngle: return "mc-solid-angle";
        case Method::McRatio: return "mc-ratio";
    }
    return "?";
}

bool isMonteCarlo(Method method) {
    return method == Method::Reference || method == Method::McAdaptive ||
           method == Method::McSolidAngle || method == Method::McRatio;
}

int defaultSamples(Method method) {
    switch (method) {
        case Method::Reference: return 1024;
        case Method::McAdaptive: return 1024;
        case Method::McSolidAngle: return 16;
        case Method::McRatio: return 16;
        default: return 0;
    }
}

Method parseMethod(const std::string& name, const std::string& flag) {
    const Method all[] = {Method::Aci,       Method::AciPixel,     Method::Reference,
                          Method::McAdaptive, Method::McSolidAngle, Method::McRatio};
    for (Method m : all) {
        if (name == methodName(m)) return m;
    }
    throw InputError("", flag,
                     "unknown method '" + name +
                         "' (expected aci, aci-pixel, reference, mc-adaptive, mc-solid-angle or "
                         "mc-ratio)");
}

Estimate estimate(Method method, const Receiver& r, const RectLight& light, Occluder::Query& query,
                  ContourIntegrator& aci, const McSettings& mc) {
    McSettings s = mc;
    if (s.samples == 0) s.samples = defaultSamples(method);
    switch (method) {
        case Method::Aci:
        case Method::AciPixel: {
            Box3 origin, target;
            origin.extend(r.point);
            for (const Vec3& c : light.polygon()) target.extend(c);
            if (query.mediaBetween(origin, target)) return aciThroughMedia(aci, r, light, query);
            return aci.evaluate(r, light, query);
        }
        case Method::Reference: return monteCarloReference(r, light, query, s);
        case Method::McAdaptive: return monteCarloAdaptive(r, light, query, s);
        case Method::McSolidAngle: return monteCarloSolidAngle(r, light, query, s);
        case Method::McRatio: return monteCarloRatio(r, light, query, s);
    }
    return Estimate{};
}

namespace {

// The part of the light, in its (u, v) square, where a segment from `origin` can meet the box
// `media`: the bounding rectangle of the box's corners projected from `origin` onto the light's
// plane (exact for a convex box when every corner lies ahead of the origin), padded a little;
// the whole square otherwise.
struct Footprint {
    double u0 = 0.0, v0 = 0.0, u1 = 1.0, v1 = 1.0;
    bool meets(double a0, double b0, double a1, double b1) const {
        return a0 <= u1 && a1 >= u0 && b0 <= v1 && b1 >= v0;
    }
};

Footprint footprintOf(const Box3& media, const Vec3& origin, const RectLight& light) {
    Footprint f;
    if (media.empty()) return {1.0, 1.0, 0.0, 0.0};  // meets nothing
    const Vec3 n = light.normal();
    const double toLight = glm::dot(light.corner - origin, n);
    double u0 = 1e300, v0 = 1e300, u1 = -1e300, v1 = -1e300;
    for (int c = 0; c < 8; ++c) {
        const Vec3 b((c & 1) ? media.hi.x : media.lo.x, (c & 2) ? media.hi.y : media.lo.y,
                     (c & 4) ? media.hi.z : media.lo.z);
        const double along = glm::dot(b - origin, n);
        // A corner level with or behind the origin (seen from the light): no bounded projection.
        if (!(along * toLight > 1e-12 * std::abs(toLight) * std::abs(toLight))) return f;
        const Vec3 p = origin + (toLight / along) * (b - origin);
        const Vec2 uv = light.coordinates(p);
        const double u = uv.x, v = uv.y;
        u0 = std::min(u0, u), u1 = std::max(u1, u), v0 = std::min(v0, v), v1 = std::max(v1, v);
    }
    const double pad = 0.01;
    return {u0 - pad, v0 - pad, u1 + pad, v1 + pad};
}

}  // namespace

Estimate aciThroughMedia(ContourIntegrator& aci, const Receiver& r, const RectLight& light,
                         Occluder::Query& query, const MediaCubature& cubature) {
    const AciSettings base = aci.settings();
    const Vec3 origin = r.point + base.rayOffset * r.normal;
    const Footprint foot = footprintOf(query.mediaBounds(), origin, light);
    // Transmittance at the nodes of a (2^D + 1)^2 lattice over the light (D = maxDepth + 1, so
    // that cell centres are nodes too), each traced once; 1 without a ray outside the footprint.
    const int depthCap = std::clamp(cubature.maxDepth, 0, 6);
    const int n = 1 << (depthCap + 1);
    std::map<std::pair<int, int>, double> nodes;
    uint64_t transmittanceRays = 0;
    auto transmittanceAt = [&](int i, int j) {
        const auto key = std::make_pair(i, j);
        const auto it = nodes.find(key);
        if (it != nodes.end()) return it->second;
        const double u = double(i) / n, v = double(j) / n;
        const Vec3 p = light.point(u, v);
        double t = 1.0;
        // Below the receiver's horizon the light does not count: no ray.
        if (foot.meets(u, v, u, v) && glm::dot(p - r.point, r.normal) > 0.0) {
            const uint64_t before = query.raysCast();
            t = query.transmittance(origin, p);
            transmittanceRays += query.raysCast() - before;
        }
        nodes.emplace(key, t);
        return t;
    };
    struct Cell {
        int i0, j0, size, depth;  // in lattice units
    };
    auto subLight = [&](const Cell& c) {
        RectLight l = light;
        l.corner = light.point(double(c.i0) / n, double(c.j0) / n);
        l.edgeU = light.edgeU * (double(c.size) / n);
        l.edgeV = light.edgeV * (double(c.size) / n);
        return l;
    };
    // The cells: split where the footprint is not resolved yet (a cell wider than half the
    // footprint, so that a medium smaller than the light is sampled at 3 x 3 nodes at least) or
    // where T varies more than the tolerance allows.
    const double fullOpen = unoccludedFormFactor(light, r);
    const double footSize = std::max(std::min(foot.u1, 1.0) - std::max(foot.u0, 0.0),
                                     std::min(foot.v1, 1.0) - std::max(foot.v0, 0.0));
    struct Attenuated {
        Cell cell;
        double mean, spread;
    };
    std::vector<Attenuated> attenuated;
    std::vector<Cell> work{{0, 0, n, 0}};
    while (!work.empty()) {
        const Cell c = work.back();
        work.pop_back();
        const double a0 = double(c.i0) / n, b0 = double(c.j0) / n, s = double(c.size) / n;
        if (!foot.meets(a0, b0, a0 + s, b0 + s)) continue;  // T = 1 on the whole cell
        const double t[5] = {transmittanceAt(c.i0, c.j0), transmittanceAt(c.i0 + c.size, c.j0),
                             transmittanceAt(c.i0, c.j0 + c.size),
                             transmittanceAt(c.i0 + c.size, c.j0 + c.size),
                             transmittanceAt(c.i0 + c.size / 2, c.j0 + c.size / 2)};
        const double lo = *std::min_element(t, t + 5), hi = *std::max_element(t, t + 5);
        const double open = unoccludedFormFactor(subLight(c), r);
        const bool unresolved = s > 0.5 * footSize;
        if (c.depth < depthCap && (unresolved || (hi - lo) * open > cubature.tolerance * fullOpen)) {
            const int h = c.size / 2;
            for (int q = 0; q < 4; ++q)
                work.push_back({c.i0 + (q & 1) * h, c.j0 + (q >> 1) * h, h, c.depth + 1});
            continue;
        }
        const double mean = (t[0] + t[1] + t[2] + t[3] + 4.0 * t[4]) / 8.0;
        if (lo == 1.0) continue;  // no attenuation seen: counted as T = 1
        attenuated.push_back({c, mean, std::max(hi - mean, mean - lo)});
    }
    // F_T = F(light) - sum over attenuated cells of (1 - T) F(cell): the whole light once, then
    // only the cells the media dim. With no attenuation anywhere it is ACI on the light, exactly.
    Estimate out = aci.evaluate(r, light, query);
    out.pattern.clear();
    if (attenuated.empty()) {
        out.counts.secondLevelRays += transmittanceRays;
        return out;
    }
    for (const Attenuated& a : attenuated) {
        AciSettings s = base;
        s.grid = std::max(1, base.grid >> a.cell.depth);
        aci.setSettings(s);
        const Estimate e = aci.evaluate(r, subLight(a.cell), query);
        const double w = 1.0 - a.mean;
        out.formFactor -= w * e.formFactor;
        out.g -= w * e.g;
        out.dg -= w * e.dg;
        out.counts.merge(e.counts);
        // T within the cell is within the spread of the mean that stands for it.
        out.errorBound += w * (std::isfinite(e.errorBound) ? e.errorBound : 0.0) +
                          a.spread * std::max(0.0, e.formFactor);
    }
    aci.setSettings(base);
    out.formFactor = std::max(0.0, out.formFactor);
    for (int k = 0; k < 3; ++k) out.gradient[k] = glm::dot(out.dg[k], r.normal);
    out.counts.secondLevelRays += transmittanceRays;  // shadow rays too
    return out;
}

}  // namespace penumbra
