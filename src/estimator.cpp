#include "penumbra/estimator.h"

#include <algorithm>
#include <cmath>
#include <optional>
#include <stdexcept>
#include <unordered_map>
#include <vector>

#include "penumbra/contour_integrator.h"
#include "penumbra/error.h"
#include "penumbra/monte_carlo.h"

#include "convex_clip.h"

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
        default: break;
    }
    // Monte Carlo rays aim at the light itself: obstacles outside the pyramid of the receiver
    // and the light cannot block them, so the queries skip them.
    NarrowedQuery narrowed(query, Pyramid(r.point, std::abs(s.rayOffset), light.polygon()));
    switch (method) {
        case Method::Reference: return monteCarloReference(r, light, query, s);
        case Method::McAdaptive: return monteCarloAdaptive(r, light, query, s);
        case Method::McSolidAngle: return monteCarloSolidAngle(r, light, query, s);
        case Method::McRatio: return monteCarloRatio(r, light, query, s);
        default: break;
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
        const Vec3 b = media.corner(c);
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

// The bounding rectangle of the part of the convex polygon `area` ((u, v) points) inside the
// footprint; none when they do not overlap. `cut`: whether the area's border cuts the footprint.
std::optional<Footprint> clipFootprint(const Footprint& f, std::vector<Vec2> area, bool& cut) {
    auto clip = [&](auto value) { keepNonNegative(area, value); };
    clip([&](const Vec2& p) { return p.x - f.u0; });
    clip([&](const Vec2& p) { return f.u1 - p.x; });
    clip([&](const Vec2& p) { return p.y - f.v0; });
    clip([&](const Vec2& p) { return f.v1 - p.y; });
    if (area.empty()) return std::nullopt;
    Footprint out{1e300, 1e300, -1e300, -1e300};
    for (const Vec2& p : area) {
        out.u0 = std::min(out.u0, p.x), out.u1 = std::max(out.u1, p.x);
        out.v0 = std::min(out.v0, p.y), out.v1 = std::max(out.v1, p.y);
    }
    const double tol = 1e-9;
    cut = out.u0 > f.u0 + tol || out.u1 < f.u1 - tol || out.v0 > f.v0 + tol || out.v1 < f.v1 - tol;
    // Padded like footprintOf's: nodes on the area's border (a polygon's vertices) are in.
    const double pad = 0.01;
    return Footprint{out.u0 - pad, out.v0 - pad, out.u1 + pad, out.v1 + pad};
}

// The part of a convex polygon light inside the frame rectangle [u0, u1] x [v0, v1] (frame
// coordinates), as a polygon light of its own; none when that part has no area. Clipped by the
// four sides in turn (Sutherland and Hodgman), then cleared of vertices that repeat or lie on
// the line through their neighbours (where a side of the polygon runs along a side of the
// cell), which polygonLight() refuses.
std::optional<RectLight> polygonPart(const RectLight& light, double u0, double v0, double u1, double v1) {
    std::vector<Vec3> poly = light.vertices;
    auto clip = [&](auto value) { keepNonNegative(poly, value); };
    clip([&](const Vec3& p) { return light.coordinates(p).x - u0; });
    clip([&](const Vec3& p) { return u1 - light.coordinates(p).x; });
    clip([&](const Vec3& p) { return light.coordinates(p).y - v0; });
    clip([&](const Vec3& p) { return v1 - light.coordinates(p).y; });
    const double size = std::max(glm::length(light.edgeU), glm::length(light.edgeV));
    const Vec3 n = light.normal();
    for (bool changed = true; changed && poly.size() >= 3;) {
        changed = false;
        for (size_t i = 0; i < poly.size() && poly.size() >= 3; ++i) {
            const Vec3& prev = poly[(i + poly.size() - 1) % poly.size()];
            const Vec3& next = poly[(i + 1) % poly.size()];
            const double turn = glm::dot(glm::cross(poly[i] - prev, next - poly[i]), n);
            if (glm::length(poly[i] - prev) <= 1e-9 * size || turn <= 1e-9 * size * size) {
                poly.erase(poly.begin() + static_cast<long>(i));
                changed = true;
                break;
            }
        }
    }
    if (poly.size() < 3) return std::nullopt;
    try {
        RectLight part = polygonLight(poly);
        part.radiance = light.radiance;
        part.name = light.name;
        return part;
    } catch (const std::invalid_argument&) {
        return std::nullopt;  // a sliver of no area
    }
}

// A disc's stand-in in aciThroughMedia's correction term: the regular polygon of kDiscSides
// sides with the disc's centre, plane and area (its vertices a little outside the circle, its
// edges' middles a little inside).
constexpr int kDiscSides = 64;
// The area between the circle and that polygon (the symmetric difference), over the disc's:
// 0.00062 by a fine polar quadrature; counted with a margin.
constexpr double kDiscSliver = 0.001;

RectLight discStandIn(const RectLight& disc) {
    const double a = kPi / kDiscSides;
    // Equal area: kDiscSides R'^2 sin(a) cos(a) = pi R^2.
    const double rv = disc.radius * std::sqrt(kPi / (kDiscSides * std::sin(a) * std::cos(a)));
    const Vec3 e1 = glm::normalize(disc.edgeU), e2 = glm::normalize(disc.edgeV);
    std::vector<Vec3> v;
    for (int k = 0; k < kDiscSides; ++k) {
        const double phi = 2.0 * a * k;
        v.push_back(disc.center + rv * (std::cos(phi) * e1 + std::sin(phi) * e2));
    }
    RectLight out = polygonLight(v);
    out.radiance = disc.radiance;
    out.name = disc.name;
    return out;
}

}  // namespace

Estimate aciThroughMedia(ContourIntegrator& aci, const Receiver& r, const RectLight& whole,
                         Occluder::Query& query, const MediaCubature& cubature) {
    // The opaque obstacles first: ACI on the whole light. In an umbra the media change nothing.
    // Its contour is kept for the cells it crosses (below).
    aci.recordContour(true);
    Estimate out;
    try {
        out = aci.evaluate(r, whole, query);
    } catch (...) {
        aci.recordContour(false);
        throw;
    }
    aci.recordContour(false);
    const double wholeBound = std::isfinite(out.errorBound) ? out.errorBound : 0.0;
    out.pattern.clear();
    if (!(out.formFactor > 0.0)) return out;
    const double fullOpen = unoccludedFormFactor(whole, r);
    // The cells: of the light itself, or for a disc (whose cells would hold arcs) of the
    // regular polygon of kDiscSides sides and the disc's area that stands in for it in the
    // correction term alone (F(light) above is the disc's, exactly). The two differ on
    // slivers totalling kDiscSliver of the disc's area, which the bound counts.
    const bool disc = whole.shape == LightShape::Disc;
    const RectLight light = disc ? discStandIn(whole) : whole;
    // Nothing opaque anywhere on the light (the visible form factor is the unoccluded one): a
    // cell's visible form factor is then its own closed form, no ray needed. For rectangle
    // lights, whose cells are rectangles, and polygons, whose cells are the convex polygons
    // they cut from it (polygonPart); a disc's cells would hold arcs (discs do not light
    // volumes: the scene loader refuses them).
    const bool open = out.formFactor >= fullOpen * (1.0 - 1e-9);

    const AciSettings base = aci.settings();
    const Vec3 origin = r.point + base.rayOffset * r.normal;
    // Each medium's footprint on the light: the cubature resolves each at 5 x 5 nodes at least
    // (below), so a small medium far from a large one is not sampled at the spacing their
    // union's footprint would set (bench_bounds --fog --light-scale 8, seed 3308: two small fogs
    // under an 8 x 8 light fell between the nodes and F came out 1.5% high, 7 times its bound).
    std::vector<Footprint> feet;
    std::vector<double> footSizes;  // each footprint's smaller extent within the light
    double smallest = 1.0;
    // The emitting area in the frame's (u, v) square, to which each footprint is cut before its
    // size is taken: a fog whose footprint met a triangle light's frame mostly outside the
    // triangle was sampled at the spacing of the whole footprint, and its shadow on the
    // triangle's corner fell between the nodes (bench_bounds --lights mixed --fog
    // --light-scale 3, seed 4001: ground points 0.4% of the form factor too bright, bound 0).
    std::vector<Vec2> emitting;
    if (light.shape == LightShape::Polygon) {
        for (const Vec3& v : light.vertices) emitting.push_back(light.coordinates(v));
    } else {
        emitting = {Vec2(0.0, 0.0), Vec2(1.0, 0.0), Vec2(1.0, 1.0), Vec2(0.0, 1.0)};
    }
    for (const Box3& b : query.mediumBoxes()) {
        bool cut = false;
        const std::optional<Footprint> f = clipFootprint(footprintOf(b, origin, light), emitting, cut);
        if (!f) continue;
        // The spacing asked of it: kResolve of its smaller extent, half that where the light's
        // border cuts it (below).
        const double size = std::min(f->u1 - f->u0, f->v1 - f->v0) * (cut ? 0.5 : 1.0);
        feet.push_back(*f);
        footSizes.push_back(size);
        smallest = std::min(smallest, size);
    }
    auto meetsMedia = [&](double a0, double b0, double a1, double b1) {
        for (const Footprint& f : feet)
            if (f.meets(a0, b0, a1, b1)) return true;
        return false;
    };
    // A cell wider than kResolve of a footprint's smaller extent, where it meets it, is not
    // resolved yet: 5 x 5 nodes at least over every footprint, where a cloud filling its box
    // holds the middle 3 x 3. Where the light's border cuts a footprint, the cloud's part on
    // the light can be a sliver of its edge: 9 x 9 nodes there (at 5 x 5 a cloud over a
    // triangle light's edge fell between the nodes at some ground points: seed 4001 above,
    // 20 points 1% too bright with bounds near 0; 9 x 9 everywhere cost 7 times the render
    // time of seed 3308's two small clouds inside an 8 x 8 light).
    constexpr double kResolve = 0.5;
    auto resolved = [&](double a0, double b0, double s) {
        for (size_t k = 0; k < feet.size(); ++k)
            if (s > kResolve * footSizes[k] && feet[k].meets(a0, b0, a0 + s, b0 + s)) return false;
        return true;
    };
    const Vec3 lightNormal = light.normal();
    // Deep enough that cells reach kResolve of the smallest footprint (at most 6 levels: cells
    // of 1/64 of the light's edge).
    int resolveDepth = 0;
    while (resolveDepth < 6 && std::ldexp(1.0, -resolveDepth) > kResolve * smallest) ++resolveDepth;
    const int depthCap = std::clamp(std::max(cubature.maxDepth, resolveDepth), 0, 6);
    // A polygon's cells cut by its border take two levels more: their nodes outside it weigh
    // nothing, and the mean of the few inside stood for the whole part (a hexagon under
    // vdb_scenes/fog.json's cloud came out 1% high at 3 levels, 0.07% at 5).
    const int borderDepth = light.shape == LightShape::Polygon ? std::min(depthCap + 2, 7) : depthCap;
    // Two rules that agree on one coarse cell can both be wrong (a cloud's edge between its
    // nodes): every cell is split at least this far (4 x 4 cells, 9 x 9 nodes).
    constexpr int kMinDepth = 2;
    // A cell whose nodes see no attenuation is proven clear when its pyramid of rays meets no
    // box of the media's support (Query::opticalDepthBound); otherwise it is split, up to two
    // levels beyond the others, and what stays unproven there counts in the bound (a cloud that
    // filled little of its box, or a sliver of it on the light, fell between the nodes: seed
    // 4001 under "Resolution" in docs/volumes.md).
    const int supportDepth = std::min(std::max(depthCap + 2, borderDepth), 7);
    // How large a medium's features look on the light: a length l at the fraction t of the way
    // from the receiver to the light spans l / t there; `reach` is the largest such fraction
    // over the media's boxes (at most 1). A cell is resolved where it is no wider than
    // kFeature of the finest features it may hold (MediumSupport::featureLength).
    constexpr double kFeature = 12.0;
    // A cell's nodes see little of its media when their largest attenuation is below kWeak of
    // the most the media in its pyramid could cause (Query::opticalDepthBound).
    constexpr double kWeak = 0.1;
    // A cell whose nodes see nothing is not split when what it can hold is at most kFringe of
    // the unoccluded form factor: that counts in the bound instead.
    constexpr double kFringe = 1e-3;
    // A cell is split, up to supportDepth, while its nodes' spread times its form factor
    // exceeds this share of the unoccluded form factor (below). (At 1e-3 the fog gallery scene
    // took 40% more rays for an image within 0.3 of 255, at 3e-3 24%, at 5e-3 6.5%; seed 7006's
    // worst point was 0.16%, 0.2% and 0.33% of F0 off, 7% before.)
    constexpr double kSpread = 5e-3;
    const double lightSize = std::max(glm::length(light.edgeU), glm::length(light.edgeV));
    double reach = 0.0;
    {
        const double toLight = glm::dot(light.corner - origin, lightNormal);
        for (const Box3& b : query.mediumBoxes())
            for (int c = 0; c < 8; ++c)
                reach = std::max(reach, glm::dot(b.corner(c) - origin, lightNormal) / toLight);
        reach = std::clamp(reach, 1e-3, 1.0);
    }
    const int n = 1 << (supportDepth + 1);
    // Transmittance and the form-factor kernel at the nodes of a (2^D + 1)^2 lattice over the
    // light (D = supportDepth + 1: the finest cells span two lattice units, so that their edge
    // midpoints and centres are nodes too), each traced once; the kernel is 0 below the
    // receiver's horizon or outside a shaped light. On an open light T = 1 without a ray outside
    // the footprint; otherwise each node's ray also tells whether an opaque obstacle hides it
    // (Query::transmitted, one ray for both), so that only the cells the opaque contour may
    // cross need their visible part from the contour (below).
    struct Node {
        double t = -1.0, k = 0.0;  // t < 0: not traced yet
        bool hidden = false;
        bool outside = false;  // outside a polygon light
    };
    // Sparse: at 6 or 7 levels the lattice has 16,000-66,000 nodes, of which the cells near
    // the footprints use a few hundred.
    std::unordered_map<uint32_t, Node> nodes;
    nodes.reserve(512);
    uint64_t transmittanceRays = 0;
    auto node = [&](int i, int j) -> const Node& {
        Node& nd = nodes[uint32_t(j) * uint32_t(n + 1) + uint32_t(i)];
        if (nd.t >= 0.0) return nd;
        const double u = double(i) / n, v = double(j) / n;
        const Vec3 p = light.point(u, v);
        nd.t = 1.0;
        nd.outside = light.shape != LightShape::Rect && !light.contains(p);
        if (!nd.outside) nd.k = formFactorDensity(r, lightNormal, p);
        if (nd.k > 0.0) {
            const uint64_t before = query.raysCast();
            if (!open) {
                nd.t = query.transmitted(origin, p);
                nd.hidden = !(nd.t > 0.0);
            } else if (meetsMedia(u, v, u, v)) {
                nd.t = query.transmittance(origin, p);
            }
            transmittanceRays += query.raysCast() - before;
        }
        return nd;
    };
    struct Cell {
        int i0, j0, size, depth;  // in lattice units
    };
    auto subLight = [&](const Cell& c) -> std::optional<RectLight> {
        if (light.shape == LightShape::Polygon)
            return polygonPart(light, double(c.i0) / n, double(c.j0) / n, double(c.i0 + c.size) / n,
                               double(c.j0 + c.size) / n);
        RectLight l = light;
        l.corner = light.point(double(c.i0) / n, double(c.j0) / n);
        l.edgeU = light.edgeU * (double(c.size) / n);
        l.edgeV = light.edgeV * (double(c.size) / n);
        return l;
    };
    // A cell's mean transmittance over its visible nodes, weighted by the kernel, by two rules
    // on its 3 x 3 nodes: the tensor Simpson rule (weights 1, 4, 16 for corners, edge
    // midpoints, centre; exact for T k bicubic) and the five-point rule of corners and centre
    // (weights 1 and 4; exact for T k bilinear). Their difference estimates the Simpson mean's
    // error.
    struct Means {
        double simpson = 1.0, lower = 1.0, lo = 1.0, hi = 0.0;  // lo, hi: over visible nodes
        bool weighted = false;  // some visible node has a kernel weight
        int hidden = 0, emitting = 0;  // nodes an opaque obstacle hides; nodes with a weight
        int outside = 0;               // nodes outside a polygon light
    };
    auto means = [&](const Cell& c) {
        const int h = c.size / 2;
        double sw = 0.0, swt = 0.0, lw = 0.0, lwt = 0.0;
        Means m;
        for (int b = 0; b < 3; ++b) {
            for (int a = 0; a < 3; ++a) {
                const Node& nd = node(c.i0 + a * h, c.j0 + b * h);
                if (nd.k > 0.0) ++m.emitting;
                if (nd.outside) ++m.outside;
                if (nd.hidden) {
                    ++m.hidden;
                    continue;
                }
                const double simpson = (a == 1 ? 4.0 : 1.0) * (b == 1 ? 4.0 : 1.0);
                sw += simpson * nd.k, swt += simpson * nd.k * nd.t;
                const bool corner = a != 1 && b != 1, centre = a == 1 && b == 1;
                if (corner || centre) {
                    const double five = centre ? 4.0 : 1.0;
                    lw += five * nd.k, lwt += five * nd.k * nd.t;
                }
                m.lo = std::min(m.lo, nd.t), m.hi = std::max(m.hi, nd.t);
            }
        }
        if (sw > 0.0) {
            m.simpson = swt / sw, m.lower = lw > 0.0 ? lwt / lw : m.simpson, m.weighted = true;
        }
        if (m.hi < m.lo) m.lo = m.hi = 1.0;  // no visible node
        return m;
    };
    // The cells: split where a footprint is not resolved yet (a cell wider than half of it, so
    // that a medium smaller than the light is sampled at 5 x 5 nodes at least), below the least
    // depth, or where the two rules disagree by more than the tolerance.
    struct Attenuated {
        Cell cell;
        Means m;
    };
    std::vector<Attenuated> attenuated;
    std::vector<Cell> work{{0, 0, n, 0}};
    while (!work.empty()) {
        const Cell c = work.back();
        work.pop_back();
        const double a0 = double(c.i0) / n, b0 = double(c.j0) / n, s = double(c.size) / n;
        if (!meetsMedia(a0, b0, a0 + s, b0 + s)) continue;  // T = 1 on the whole cell
        const Means m = means(c);
        const bool unresolved = !resolved(a0, b0, s) || c.depth < kMinDepth;
        const bool varies = std::abs(m.simpson - m.lower) > cubature.tolerance;
        const bool border = m.outside > 0 && m.outside < 9 && m.lo < 1.0;
        auto split = [&] {
            const int h = c.size / 2;
            for (int q = 0; q < 4; ++q)
                work.push_back({c.i0 + (q & 1) * h, c.j0 + (q >> 1) * h, h, c.depth + 1});
        };
        // Up to supportDepth, past depthCap, a cell also splits where its nodes' spread
        // around the mean (which the bound counts, below) times its form factor exceeds kSpread
        // of the unoccluded form factor: the depth cap comes from the footprints, which say
        // nothing of how sharp a medium's edge is, and the two rules can agree by chance (a fog
        // of density 4.7 and no falloff, whose box's footprint was the whole triangle light 18
        // across: its edge ran between the nodes of a cell a quarter of the light wide whose
        // rules agreed, T from 0.42 to 1 over them, and ground points came out up to 7% of F0
        // off, within their bounds; bench_bounds --lights mixed --light-scale 8 --fog, seed
        // 7006).
        bool spreads = false;
        if (c.depth < supportDepth && m.weighted && m.hi > m.lo) {
            const double spread = std::max(m.hi - m.simpson, m.simpson - m.lo);
            if (const std::optional<RectLight> part = subLight(c))
                spreads = spread * unoccludedFormFactor(*part, r) > kSpread * fullOpen;
        }
        if ((c.depth < depthCap && (unresolved || varies)) || (c.depth < borderDepth && border) || spreads) {
            split();
            continue;
        }
        // A cell whose emitting nodes are all hidden stays out (an opaque feature between them
        // is in F(light) exactly; only its share is missed).
        if (m.hidden > 0 && m.hidden == m.emitting) continue;
        // The media's support in the cell's pyramid of rays: none proves T = 1 on the whole
        // cell; where there is some, the cell is split while it is wider than the media's
        // finest features look on the light.
        const bool seen = m.lo < 1.0 && m.weighted;  // some node is dimmed
        const Pyramid pyramid(origin, 0.0, {light.point(a0, b0), light.point(a0 + s, b0),
                                            light.point(a0 + s, b0 + s), light.point(a0, b0 + s)});
        double feature = 0.0, depth = 0.0;
        if (seen) {
            feature = query.featureLength(pyramid);  // the parts need no test: it meets some
        } else {
            depth = query.opticalDepthBound(pyramid, &feature);
            if (!(depth > 0.0)) continue;  // proven: T = 1 on the whole cell
        }
        if (c.depth < supportDepth && s * lightSize > kFeature * feature / reach) {
            // Coarse for the media's features. Nodes that see a good part of what the pyramid
            // may hold leave the cell to the variation test; nodes that see none of it, or
            // little (a cloud's thin edge, its core between them), split it.
            bool weak = false;
            if (seen) {
                depth = query.opticalDepthBound(pyramid);
                weak = 1.0 - m.lo < kWeak * -std::expm1(-depth);
            } else if (const std::optional<RectLight> part = subLight(c)) {
                // Unseen: split unless the most it can hold is a small part of F.
                weak = -std::expm1(-depth) * unoccludedFormFactor(*part, r) > kFringe * fullOpen;
            }
            if (weak) {
                split();
                continue;
            }
        }
        if (!seen) {
            // No attenuation seen, none proven absent: T is somewhere in [exp(-depth), 1].
            if (const std::optional<RectLight> part = subLight(c))
                out.errorBound += -std::expm1(-depth) * unoccludedFormFactor(*part, r);
            continue;
        }
        attenuated.push_back({c, m});
    }
    out.counts.secondLevelRays += transmittanceRays;  // shadow rays too
    if (attenuated.empty()) return out;
    // F_T = F(light) - sum over attenuated cells of (1 - T) F(cell): the whole light once, then
    // only the cells the media dim. With no attenuation anywhere it is ACI on the light, exactly.
    // The largest weight 1 - T of a cell whose visible part came from the whole light's contour.
    double clippedWeight = 0.0;
    for (const Attenuated& a : attenuated) {
        Estimate e;
        const std::optional<RectLight> part = subLight(a.cell);
        if (!part) continue;  // no emitting area in the cell
        const RectLight& cell = *part;
        // A cell whose nine nodes are all hidden counts as hidden, one whose nodes are all
        // visible as open (a rectangle light's cell then has its closed form); only cells
        // whose nodes disagree, which the opaque contour crosses, take their part of the
        // whole light's contour (or, where that cannot answer, an ACI of their own). An
        // opaque feature between the nodes of a cell is still in F(light) exactly: it only
        // misses its (1 - T) share here.
        if (a.m.hidden == a.m.emitting) continue;
        if (open || a.m.hidden == 0) {
            // G always (the renderer interpolates it), its Jacobian only when asked for.
            if (base.gradient) {
                const GWithDerivative u = unoccludedG(cell, r);
                e.g = u.g, e.dg = u.dg;
            } else if (facesLight(cell, r.point)) {
                const std::vector<Vec3> poly = clipToHorizon(cell.polygon(), r);
                if (poly.size() >= 3) e.g = polygonG(poly, r.point);
            }
            e.formFactor = std::max(0.0, glm::dot(e.g, r.normal));
            e.errorBound = 0.0;
        } else if (Vec3 g; !base.gradient && !disc &&
                           aci.visibleWithin(r, whole, double(a.cell.i0) / n, double(a.cell.j0) / n,
                                             double(a.cell.i0 + a.cell.size) / n,
                                             double(a.cell.j0 + a.cell.size) / n, g)) {
            // The part of the whole light's contour in the cell, without a ray: its error over
            // all such cells together is within the whole light's bound times the contour's
            // weight factor, which counts once (below), at the largest of their weights. Until
            // 2026-12-06 each took an ACI of its own, locating again what the whole light's had
            // located (bench_random --lights mixed --fog, seed 8403: 237 shadow rays a viewing
            // ray, now 169).
            e.g = g;
            e.formFactor = std::max(0.0, glm::dot(g, r.normal));
            e.errorBound = 0.0;
            clippedWeight = std::max(clippedWeight, 1.0 - a.m.simpson);
        } else {
            AciSettings s = base;
            s.grid = std::max(1, base.grid >> a.cell.depth);
            aci.setSettings(s);
            e = aci.evaluate(r, cell, query);
        }
        const double w = 1.0 - a.m.simpson;
        out.formFactor -= w * e.formFactor;
        out.g -= w * e.g;
        out.dg -= w * e.dg;
        out.counts.merge(e.counts);
        // T within the cell is within the spread of its nodes around the mean that stands for it.
        const double spread = std::max(a.m.hi - a.m.simpson, a.m.simpson - a.m.lo);
        out.errorBound += w * (std::isfinite(e.errorBound) ? e.errorBound : 0.0) +
                          spread * std::max(0.0, e.formFactor) +
                          (disc ? w * kDiscSliver * std::max(0.0, e.formFactor) : 0.0);
    }
    aci.setSettings(base);
    if (clippedWeight > 0.0)
        out.errorBound += clippedWeight * aci.contourWeightFactor() * wholeBound;
    out.formFactor = std::max(0.0, out.formFactor);
    for (int k = 0; k < 3; ++k) out.gradient[k] = glm::dot(out.dg[k], r.normal);
    return out;
}

}  // namespace penumbra
