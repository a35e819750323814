#include "penumbra/renderer.h"

#include <unistd.h>

#include <algorithm>
#include <array>
#include <iterator>
#include <optional>
#include <atomic>
#include <cstdio>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <mutex>
#include <string>

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/info.h>
#include <tbb/global_control.h>
#include <tbb/task_arena.h>

#include <nlohmann/json.hpp>

#include "penumbra/camera.h"
#include "penumbra/error.h"
#include "penumbra/form_factor.h"
#include "penumbra/monte_carlo.h"
#include "surface_normal.h"
#include "parallel_for.h"
#include "thread_sanitizer.h"

namespace penumbra {

// ---------------------------------------------------------------------------------------------
// Shaft culling (Haines and Wallace 1991)

Shaft::Shaft(const Box3& a, const Box3& b) {
    mBox = a;
    mBox.extend(b);
    const Vec3* aSide[2] = {&a.lo, &a.hi};
    const Vec3* bSide[2] = {&b.lo, &b.hi};
    // For each edge direction of the common box (axes i, j, sides si, sj), the plane through the
    // matching edges of a and b. It is a supporting plane of both boxes exactly when its outward
    // normal points towards (si, sj) on both axes: then each box's extreme point in that direction
    // is its (si, sj) edge, which lies on the plane. Otherwise the common box's faces already
    // bound the hull there.
    for (int i = 0; i < 3; ++i) {
        for (int j = i + 1; j < 3; ++j) {
            for (int si = 0; si < 2; ++si) {
                for (int sj = 0; sj < 2; ++sj) {
                    double ai = (*aSide[si])[i], aj = (*aSide[sj])[j];
                    double bi = (*bSide[si])[i], bj = (*bSide[sj])[j];
                    double di = bi - ai, dj = bj - aj;
                    double ni = dj, nj = -di;  // perpendicular to (di, dj) in the (i, j) plane
                    double wantI = si ? 1.0 : -1.0, wantJ = sj ? 1.0 : -1.0;
                    if (ni * wantI < 0.0) {
                        ni = -ni;
                        nj = -nj;
                    }
                    if (!(ni * wantI > 0.0 && nj * wantJ > 0.0)) continue;
                    double len = std::sqrt(ni * ni + nj * nj);
                    ni /= len;
                    nj /= len;
                    mPlanes.push_back(Plane{i, j, ni, nj, ni * ai + nj * aj});
                }
            }
        }
    }
}

bool Shaft::overlaps(const Box3& box) const {
    if (box.empty() || mBox.empty()) return false;
    // A margin well above rounding (so the test stays conservative) and far below any geometry.
    double scale = 1.0;
    for (int a = 0; a < 3; ++a) {
        scale = std::max({scale, std::abs(mBox.lo[a]), std::abs(mBox.hi[a]), std::abs(box.lo[a]),
                          std::abs(box.hi[a])});
    }
    double eps = 1e-9 * scale;
    for (int a = 0; a < 3; ++a) {
        if (box.lo[a] > mBox.hi[a] + eps || box.hi[a] < mBox.lo[a] - eps) return false;
    }
    for (const Plane& p : mPlanes) {
        // The box's corner deepest inside the plane.
        double ci = p.ni > 0.0 ? box.lo[p.i] : box.hi[p.i];
        double cj = p.nj > 0.0 ? box.lo[p.j] : box.hi[p.j];
        if (p.ni * ci + p.nj * cj > p.d + eps) return false;
    }
    return true;
}

double automaticRayOffset(const Scene& scene, const Occluder& occluder) {
    if (occluder.minVoxelSize() > 0.0) {
        double largest = 0.0;
        for (size_t i = 0; i < occluder.size(); ++i) {
            if (const auto* ls = std::get_if<LevelSetPtr>(&occluder.shape(i)))
                largest = std::max(largest, 1.5 * voxelSizeOf(**ls));
        }
        return std::max(largest, rayOffsetFloor(scene, occluder));
    }
    return rayOffsetFloor(scene, occluder);
}

double receiverRayOffset(const Occluder& occluder, const Vec3& p, double floor) {
    double offset = floor;
    for (size_t i = 0; i < occluder.size(); ++i) {
        const auto* ls = std::get_if<LevelSetPtr>(&occluder.shape(i));
        if (!ls) continue;
        const double wanted = 1.5 * voxelSizeOf(**ls);
        if (wanted <= offset) continue;
        // Beyond the bounds (active voxels and a voxel) widened by `wanted`, the surface is
        // farther than `wanted`: no need to sample.
        const Box3& b = occluder.bounds(i);
        if (b.empty() || glm::any(glm::lessThan(p, b.lo - Vec3(wanted))) ||
            glm::any(glm::greaterThan(p, b.hi + Vec3(wanted))))
            continue;
        const double phi = sampleLevelSet(**ls, p);
        offset = std::max(offset, std::clamp(wanted - phi, 0.0, wanted));
    }
    return offset;
}

double rayOffsetFloor(const Scene& scene, const Occluder& occluder) {
    double scale = 1.0;
    auto grow = [&](const Vec3& p) {
        for (int a = 0; a < 3; ++a) {
            if (std::isfinite(p[a])) scale = std::max(scale, std::abs(p[a]));
        }
    };
    for (size_t i = 0; i < occluder.size(); ++i) {
        if (!occluder.bounds(i).empty()) {
            grow(occluder.bounds(i).lo);
            grow(occluder.bounds(i).hi);
        }
    }
    for (const RectLight& l : scene.lights) {
        for (const Vec3& c : l.polygon()) grow(c);
    }
    if (scene.camera) grow(scene.camera->eye);
    return 1e-6 * scale;
}

// ---------------------------------------------------------------------------------------------
// The renderer

namespace {

struct Hit {
    int object = -1;  // planes 0 .. P-1, then obstacles P .. P+O-1; -1: background
    Vec3 point{0.0};
    Vec3 normal{0.0};
    Rgb albedo{0.0};
    double distance = 0.0;  // along the viewing ray
};

// Whether two horizontally adjacent hits may share a span: the same object and, since G is
// interpolated along a span, the same smooth piece of it. A crease (a box edge: the normal
// turns by more than ~30 degrees between neighbours) or a jump in depth (one part of an object
// seen in front of another) ends the span; breaking one costs rays, never accuracy.
bool continuesSpan(const Hit& a, const Hit& b) {
    if (a.object != b.object || a.object < 0) return false;
    if (glm::dot(a.normal, b.normal) < 0.866) return false;
    return std::abs(a.distance - b.distance) <= 0.1 * std::min(a.distance, b.distance);
}

struct PixelSum {
    Rgb irradiance{0.0};  // sum over lights of radiance x F
    double formFactor = 0.0;
    Vec3 gradient{0.0};
    double errorBound = 0.0;  // sum over lights of the estimates' bounds (NaN: none given)
    uint64_t rays = 0;
    // Shadow rays were needed here: traced at this pixel, or first-level rays reused from an
    // earlier pixel of the span (the same pixels for every method: Table 1's denominator).
    bool shadowed = false;
};

// What the pipeline keeps of one full ACI evaluation.
struct Sample {
    Vec3 g{0.0};
    Vec3 gradient{0.0};
    double errorBound = 0.0;
    std::vector<uint8_t> pattern;
    int grid = 0;  // first-level grid the pattern was traced on
    std::vector<uint32_t> blockers;  // Estimate::blockers
    // Checked interpolation: the unoccluded G and gradient there (the shadow is open - g).
    Vec3 openG{0.0};
    Vec3 openGradient{0.0};
};

// Light scattered by the media towards the camera, per unit of scattering coefficient and for an
// isotropic phase function: S(x) = sum over lights of radiance x Omega_T(x) / (4 pi), Omega_T the
// light's solid angle seen from x weighted by opaque visibility and transmittance, estimated
// with `samples` stratified (Sobol-Owen) points on each light's area. Held on a lattice over the
// media's bounds and interpolated, or computed at each point (resolution 0).
class InScatter {
public:
    InScatter(const Scene& scene, const Occluder& occluder, int resolution, int samples)
        : mScene(scene), mSamples(samples) {
        for (size_t i = 0; i < occluder.mediumCount(); ++i) {
            const Box3& b = occluder.mediumBounds(i);
            if (b.empty()) continue;
            mBounds.extend(b.lo);
            mBounds.extend(b.hi);
        }
        if (mBounds.empty() || resolution <= 0) return;
        const Vec3 size = mBounds.hi - mBounds.lo;
        const double longest = std::max({size.x, size.y, size.z});
        for (int k = 0; k < 3; ++k)
            mCount[k] = std::max(2, int(std::ceil(resolution * size[k] / longest)) + 1);
        mValues.assign(size_t(mCount[0]) * mCount[1] * mCount[2], Rgb(0.0));
        // Every node from its own rays: the same values on any number of threads.
        detail::parallelFor(tbb::blocked_range<int>(0, mCount[2]), [&](const tbb::blocked_range<int>& r) {
            Occluder::Query q = occluder.makeQuery();
            for (int k = r.begin(); k < r.end(); ++k)
                for (int j = 0; j < mCount[1]; ++j)
                    for (int i = 0; i < mCount[0]; ++i)
                        mValues[index(i, j, k)] = direct(node(i, j, k), q);
            mRays += q.raysCast();  // (atomic)
        });
    }

    // S at x: interpolated on the lattice, or computed with `q` without one.
    Rgb at(const Vec3& x, Occluder::Query& q) const {
        if (mValues.empty()) return direct(x, q);
        Vec3 g;
        int c[3];
        for (int k = 0; k < 3; ++k) {
            const double span = mBounds.hi[k] - mBounds.lo[k];
            const double f = span > 0.0 ? (x[k] - mBounds.lo[k]) / span * (mCount[k] - 1) : 0.0;
            c[k] = std::clamp(int(std::floor(f)), 0, mCount[k] - 2);
            g[k] = std::clamp(f - c[k], 0.0, 1.0);
        }
        Rgb out(0.0);
        for (int corner = 0; corner < 8; ++corner) {
            const int di = corner & 1, dj = (corner >> 1) & 1, dk = corner >> 2;
            const double w = (di ? g.x : 1.0 - g.x) * (dj ? g.y : 1.0 - g.y) * (dk ? g.z : 1.0 - g.z);
            out += w * mValues[index(c[0] + di, c[1] + dj, c[2] + dk)];
        }
        return out;
    }

    const Box3& bounds() const { return mBounds; }
    uint64_t latticeRays() const { return mRays; }

private:
    size_t index(int i, int j, int k) const {
        return (size_t(k) * mCount[1] + j) * mCount[0] + i;
    }
    Vec3 node(int i, int j, int k) const {
        const Vec3 f(double(i) / (mCount[0] - 1), double(j) / (mCount[1] - 1), double(k) / (mCount[2] - 1));
        return mBounds.lo + f * (mBounds.hi - mBounds.lo);
    }
    Rgb direct(const Vec3& x, Occluder::Query& q) const {
        Rgb s(0.0);
        for (const RectLight& light : mScene.lights) {
            const Vec3 n = light.normal();
            double sum = 0.0;
            for (int i = 0; i < mSamples; ++i) {
                const Vec2 uv = sobolOwen2(uint32_t(i), 0x5ca77e5);
                const Vec3 p = light.point(uv.x, uv.y);
                const Vec3 d = p - x;
                const double r2 = glm::dot(d, d);
                const double cosL = -glm::dot(d, n) / std::sqrt(r2);
                if (!(cosL > 0.0) || !(r2 > 0.0)) continue;
                sum += q.transmitted(x, p) * cosL / r2;
            }
            const double omega = light.area() * sum / mSamples;
            s += light.radiance * (omega / (4.0 * kPi));
        }
        return s;
    }

    const Scene& mScene;
    int mSamples;
    Box3 mBounds;
    int mCount[3] = {0, 0, 0};
    std::vector<Rgb> mValues;
    std::atomic<uint64_t> mRays{0};
};

struct Context {
    const Scene& scene;
    const PinholeCamera& camera;
    const Occluder& occluder;
    const RenderSettings& settings;  // aci.rayOffset resolved (the largest, when automatic)
    bool offsetPerPoint;             // rayOffset automatic: receiverRayOffset at each pixel
    double offsetFloor;              // rayOffsetFloor, for receiverRayOffset
    Image& color;
    RenderAovs& aovs;
    const InScatter* inScatter;  // null: media not seen by the camera
};

// The camera's view through the media along a viewing ray up to `end` (the hit, or the media's
// far side): emission-absorption with single scattering, midpoint steps of half the finest
// voxel. Returns the scattered radiance that reaches the camera; `transmittance` is what is
// left of the light from behind.
Rgb marchMedia(const Context& ctx, Occluder::Query& q, const ViewRay& ray, double end,
               double* transmittance) {
    *transmittance = 1.0;
    const Box3& b = ctx.inScatter->bounds();
    const Vec3 invD(1.0 / ray.direction.x, 1.0 / ray.direction.y, 1.0 / ray.direction.z);
    double t0 = 0.0, t1 = end;
    if (!b.clipRay(ray.origin, invD, t0, t1) || !(t1 > t0)) return Rgb(0.0);
    double voxel = 1e300;
    for (size_t i = 0; i < ctx.occluder.mediumCount(); ++i)
        if (!ctx.occluder.mediumBounds(i).empty())
            voxel = std::min(voxel, describe(*ctx.occluder.medium(i).grid).voxelSize);
    const int n = std::clamp(int(std::ceil((t1 - t0) / (0.5 * voxel))), 1, 1 << 14);
    const double h = (t1 - t0) / n;
    Rgb light(0.0);
    double T = 1.0;
    for (int i = 0; i < n && T > 1e-6; ++i) {
        const Vec3 x = ray.at(t0 + (i + 0.5) * h);
        Rgb scattering;
        const double sigma = q.extinctionAt(x, &scattering);
        if (!(sigma > 0.0)) continue;
        const double step = std::exp(-sigma * h);
        // Of the light scattered along the step, (1 - step) / sigma survives per unit sigma_s.
        light += T * ((1.0 - step) / sigma) * scattering * ctx.inScatter->at(x, q);
        T *= step;
    }
    *transmittance = T;
    return light;
}

struct ThreadState {
    ThreadState(const Occluder& occluder, const AciSettings& aci)
        : shadow(occluder.makeQuery()), view(occluder.makeQuery()), volume(occluder.makeQuery()),
          integrator(aci) {}
    Occluder::Query shadow;  // shadow rays only, so that its count is the shadow-ray count
    Occluder::Query view;    // viewing rays
    Occluder::Query volume;  // the camera's march through media and its in-scattering rays
    ContourIntegrator integrator;
    RenderStats stats;
    std::vector<Hit> hits;
    std::vector<PixelSum> sums;
    std::vector<uint32_t> candidates;
    std::vector<uint32_t> mediaCandidates;  // media in the span's shaft
    std::vector<uint32_t> single{0};
    std::vector<uint8_t> lit;
    std::vector<uint8_t> opaqueFree;  // per pixel of the span: no opaque candidate in its shaft
    std::vector<uint32_t> involved;   // SpanShader::obstaclesNear's answer
    std::vector<uint8_t> paired;      // SpanShader::shadeRowPairRun: pixels the rows may pair
    std::vector<uint32_t> rowCandidates, rowBlockers;  // and its comparisons
    std::vector<GWithDerivative> rowOpen;              // and its pixels' unoccluded G
    // Per pixel x of the span: the candidates that may shadow it, pixelObstacles[
    // pixelObstacleStart[x - x0] .. pixelObstacleStart[x - x0 + 1]) (in candidate order).
    std::vector<uint32_t> pixelObstacles;
    std::vector<uint32_t> pixelObstacleStart;
};

// What an even row leaves of a pixel, for one light, to the odd rows above and below it
// (RenderSettings::rowPairs): its shadow (the unoccluded G minus G, and the same of the
// gradient), its bound and the obstacles that blocked its rays. `known` only where the pixel
// was evaluated by certified ACI or interpolated after a passed check, with at most
// kRowBlockers blockers.
constexpr int kRowBlockers = 6;
struct PixelShadow {
    Vec3 shadow{0.0};
    Vec3 shadowGradient{0.0};
    double bound = 0.0;
    int object = -1;  // the viewing ray's hit (Hit::object)
    uint8_t blockerCount = 0;
    bool known = false;
    bool dark = false;  // the whole light hidden (umbra): F = 0
    bool horizonCut = false;  // its tangent plane cuts the light's frame (SpanShader::horizonCut)
    Vec3 open{0.0};           // the unoccluded G there (used where horizonCut)
    std::array<uint32_t, kRowBlockers> blockers{};

    bool sameBlockers(const PixelShadow& o) const {
        return blockerCount == o.blockerCount &&
               std::equal(blockers.begin(), blockers.begin() + blockerCount, o.blockers.begin());
    }
    bool sameBlockers(const std::vector<uint32_t>& v) const {
        return v.size() == blockerCount && std::equal(v.begin(), v.end(), blockers.begin());
    }
};

// A row's links to other rows' records, each `lights x width` (light-major), or null: `out`
// where a row that others read writes its own; where a row y is paired at distance s, the
// records of rows y - 3s, y - s, y + s and y + 3s (rows[0..3]).
struct RowLink {
    PixelShadow* out = nullptr;
    std::array<const PixelShadow*, 4> rows{};
};

Rgb planeAlbedo(const PlaneReceiver& plane, const Vec3& p) {
    if (!plane.checker || !(plane.checkerScale > 0.0)) return plane.albedo;
    // A fixed in-plane frame: u follows the world axis least aligned with the normal's
    // complement, so that the usual z-up ground gets squares aligned with x and y.
    Vec3 n = glm::normalize(plane.normal);
    Vec3 axis = std::abs(n.x) < 0.9 ? Vec3(1, 0, 0) : Vec3(0, 1, 0);
    Vec3 u = glm::normalize(axis - n * glm::dot(n, axis));
    Vec3 v = glm::cross(n, u);
    Vec3 d = p - plane.point;
    long a = long(std::floor(glm::dot(d, u) / plane.checkerScale));
    long b = long(std::floor(glm::dot(d, v) / plane.checkerScale));
    return ((a + b) & 1) ? plane.albedo2 : plane.albedo;
}

Hit castViewingRay(const Context& ctx, ThreadState& ts, int x, int y) {
    const ViewRay ray = ctx.camera.pixelRay(x, y);
    const auto& planes = ctx.scene.receivers;
    Hit hit;
    double best = std::numeric_limits<double>::infinity();
    for (size_t i = 0; i < planes.size(); ++i) {
        Vec3 n = glm::normalize(planes[i].normal);
        double denom = glm::dot(ray.direction, n);
        if (std::abs(denom) < 1e-12) continue;
        double t = glm::dot(planes[i].point - ray.origin, n) / denom;
        if (t > 0.0 && t < best) {
            best = t;
            hit.object = int(i);
            hit.point = ray.at(t);
            hit.distance = t;
            hit.normal = denom < 0.0 ? n : -n;  // planes are two-sided: face the viewer
            hit.albedo = planeAlbedo(planes[i], hit.point);
        }
    }
    const Vec3 invD(1.0 / ray.direction.x, 1.0 / ray.direction.y, 1.0 / ray.direction.z);
    for (size_t i = 0; i < ctx.occluder.size(); ++i) {
        double t0 = 0.0, t1 = best;
        if (!ctx.occluder.bounds(i).clipRay(ray.origin, invD, t0, t1)) continue;
        if (!std::isfinite(t1)) continue;
        ts.single[0] = uint32_t(i);
        ts.view.restrictTo(&ts.single);
        double tHit = 0.0;
        Vec3 from = ray.at(t0), to = ray.at(t1);
        if (ts.view.occluded(from, to, &tHit) && t0 + tHit < best) {
            best = t0 + tHit;
            hit.object = int(planes.size() + i);
            hit.point = ray.at(best);
            hit.distance = best;
            hit.normal = surfaceNormal(ctx.occluder.shape(i), hit.point);
            hit.albedo = ctx.scene.obstacles[i].albedo;
        }
    }
    ts.view.restrictTo(nullptr);
    return hit;
}


Vec3 gradientOf(const Mat3& dg, const Vec3& n) {
    // dF/dM_k = (d g / d M_k) . n with dg[k] = d g / d M_k (column k).
    return Vec3(glm::dot(dg[0], n), glm::dot(dg[1], n), glm::dot(dg[2], n));
}

// The quadratic through (x0, v0), (xm, vm), (x1, v1) at x (Lagrange).
Vec3 lagrange(int x, int x0, const Vec3& v0, int xm, const Vec3& vm, int x1, const Vec3& v1) {
    const double t = x, t0 = x0, tm = xm, t1 = x1;
    const double w0 = (t - tm) * (t - t1) / ((t0 - tm) * (t0 - t1));
    const double wm = (t - t0) * (t - t1) / ((tm - t0) * (tm - t1));
    const double w1 = (t - t0) * (t - tm) / ((t1 - t0) * (t1 - tm));
    return w0 * v0 + wm * vm + w1 * v1;
}

// The polynomial through the points (xs[k], vs[k]), k < n, at x (Lagrange).
Vec3 lagrangeN(int x, const int* xs, const Vec3* vs, int n) {
    Vec3 out(0.0);
    for (int k = 0; k < n; ++k) {
        double w = 1.0;
        for (int j = 0; j < n; ++j)
            if (j != k) w *= double(x - xs[j]) / double(xs[k] - xs[j]);
        out += w * vs[k];
    }
    return out;
}

// How far (relative to the unoccluded form factor) the checked quadratic may miss a quarter point
// for its interval to be interpolated (SpanShader::shadeCheckedRun).
constexpr double kCheckedInterpolationTolerance = 0.0005;
// Below this fraction of the unoccluded F a pixel counts as seeing none of the light (an umbra).
constexpr double kDarkFraction = 1e-9;

bool uniformPattern(const std::vector<uint8_t>& p) {
    return std::all_of(p.begin(), p.end(), [&](uint8_t v) { return v == p.front(); });
}

class SpanShader {
    // Per-pixel state within a span, for one light.
    static constexpr uint8_t kDark = 0;        // the light is behind or below the horizon: F = 0
    static constexpr uint8_t kNeedsRays = 1;   // some candidate may shadow it
    static constexpr uint8_t kClosedForm = 2;  // no candidate in its shaft: closed form

public:
    SpanShader(const Context& ctx, ThreadState& ts, const RectLight& light, size_t lightIndex,
               int row, const RowLink& link = RowLink{})
        : mCtx(ctx), mTs(ts), mLight(light), mSettings(ctx.settings), mLightIndex(lightIndex),
          mRow(row) {
        const size_t offset = lightIndex * size_t(ctx.camera.width());
        if (link.out) mOut = link.out + offset;
        if (link.rows[0] && link.rows[1] && link.rows[2] && link.rows[3])
            for (size_t k = 0; k < 4; ++k) mRows[k] = link.rows[k] + offset;
    }

    // Shades pixels [x0, x1] of the current row (all on one object) for mLight.
    void shadeSpan(int x0, int x1) {
        RenderStats& st = mTs.stats;
        ++st.spans;
        mX0 = x0;
        // First-level rays are reused only within one span (so that a pixel's value does not
        // depend on which thread shaded what before), and only on receiver planes: a ray that
        // starts on a curved obstacle's own surface is not measured near its start.
        mTs.integrator.forgetCorners();
        // With coverage a ray must carry its own certificate (a reused one's is about another
        // origin), so reuse is off there.
        mReuse = mSettings.reuseFirstLevel && mSettings.aci.tangentContour &&
                 !mSettings.aci.coverage &&
                 mTs.hits[size_t(x0)].object >= 0 &&
                 size_t(mTs.hits[size_t(x0)].object) < mCtx.scene.receivers.size();
        Box3 spanBox;
        int litCount = 0;
        mTs.lit.assign(size_t(x1 - x0 + 1), kDark);
        for (int x = x0; x <= x1; ++x) {
            if (lightReaches(mLight, receiver(x))) {
                mTs.lit[size_t(x - x0)] = kNeedsRays;
                spanBox.extend(mTs.hits[size_t(x)].point);
                ++litCount;
            }
        }
        if (litCount == 0) return;
        // Shadow rays start up to rayOffset off the surface.
        double pad = mSettings.aci.rayOffset;
        spanBox.lo -= Vec3(pad);
        spanBox.hi += Vec3(pad);

        auto& cand = mTs.candidates;
        cand.clear();
        Box3 lightBox;
        const std::vector<Vec3> lightPolygon = mLight.polygon();
        for (const Vec3& c : lightPolygon) lightBox.extend(c);
        if (mSettings.shaftCulling) {
            Shaft shaft(spanBox, lightBox);
            for (size_t i = 0; i < mCtx.occluder.size(); ++i) {
                if (shaft.overlaps(mCtx.occluder.bounds(i))) cand.push_back(uint32_t(i));
            }
        } else {
            for (size_t i = 0; i < mCtx.occluder.size(); ++i) cand.push_back(uint32_t(i));
        }
        // Media the shaft meets (their bounds padded by the interpolation kernel).
        auto& media = mTs.mediaCandidates;
        media.clear();
        {
            Shaft shaft(spanBox, lightBox);
            for (size_t i = 0; i < mCtx.occluder.mediumCount(); ++i) {
                const Box3& b = mCtx.occluder.mediumBounds(i);
                if (!b.empty() && (!mSettings.shaftCulling || shaft.overlaps(b)))
                    media.push_back(uint32_t(i));
            }
        }
        if (cand.empty() && media.empty()) ++st.culledSpans;

        // The span's shaft is as wide as the span; each pixel's own shaft (its ray origins to
        // the light) is narrower. A pixel whose shaft meets no candidate is unshadowed: the
        // closed form is then exactly what ACI would find, without a ray.
        // Which pixels no opaque candidate can shadow is kept for media, and which candidates
        // may shadow each pixel for checked interpolation (shadeCheckedRun).
        mTs.opaqueFree.assign(size_t(x1 - x0 + 1), 0);
        mTs.pixelObstacles.clear();
        mTs.pixelObstacleStart.assign(1, 0);
        for (int x = x0; x <= x1; ++x) {
            uint8_t& state = mTs.lit[size_t(x - x0)];
            if (state != kNeedsRays) {
                mTs.pixelObstacleStart.push_back(uint32_t(mTs.pixelObstacles.size()));
                continue;
            }
            bool noOpaque = cand.empty(), noMedia = media.empty();
            // The pyramid of the pixel's segments to the light: what it does not meet cannot
            // shadow the pixel (with culling, the pixel's own shaft must meet it too).
            const Pyramid pyramid(mTs.hits[size_t(x)].point, pad, lightPolygon);
            const bool culling = mSettings.shaftCulling;
            Box3 origin;
            origin.extend(mTs.hits[size_t(x)].point - Vec3(pad));
            origin.extend(mTs.hits[size_t(x)].point + Vec3(pad));
            std::optional<Shaft> pixelShaft;
            if (culling) pixelShaft.emplace(origin, lightBox);
            const size_t before = mTs.pixelObstacles.size();
            for (uint32_t i : cand) {
                if ((!pixelShaft || pixelShaft->overlaps(mCtx.occluder.bounds(i))) &&
                    mCtx.occluder.mayBlockIn(i, pyramid))
                    mTs.pixelObstacles.push_back(i);
            }
            if (culling) {
                noOpaque = mTs.pixelObstacles.size() == before;
                noMedia = std::none_of(media.begin(), media.end(), [&](uint32_t i) {
                    const Box3& b = mCtx.occluder.mediumBounds(i);
                    return pixelShaft->overlaps(b) && pyramid.mayMeet(b);
                });
            }
            mTs.opaqueFree[size_t(x - x0)] = noOpaque;
            mTs.pixelObstacleStart.push_back(uint32_t(mTs.pixelObstacles.size()));
            if (!(noOpaque && noMedia)) continue;
            state = kClosedForm;
            Receiver r = receiver(x);
            Vec3 grad(0.0);
            if (mSettings.aci.gradient) grad = gradientOf(unoccludedG(mLight, r).dg, r.normal);
            store(x, unoccludedFormFactor(mLight, r), grad);
            ++st.closedFormPixels;
        }
        if (cand.empty() && media.empty()) return;

        mTs.shadow.restrictTo(&cand);
        mTs.shadow.restrictMediaTo(&media);
        if (isMonteCarlo(mSettings.method)) {
            // One estimate per pixel that needs rays: the same pixels as the ACI pipeline's.
            for (int x = x0; x <= x1; ++x) {
                if (mTs.lit[size_t(x - x0)] == kNeedsRays) estimateAt(x);
            }
            mTs.shadow.restrictTo(nullptr);
            mTs.shadow.restrictMediaTo(nullptr);
            return;
        }
        if (!media.empty()) {
            // Through media ACI evaluates a pixel with aciThroughMedia, whose cells follow the
            // transmittance, which shadow patterns do not see. Runs of pixels are shaded by
            // checked interpolation (shadeCheckedRun) on those estimates: runs that no opaque
            // candidate can shadow by the quadratic's check alone, the others by that check and
            // the blockers' as without media (until 2026-12-06 each of those was evaluated: a
            // sharp fog beside opaque obstacles took 548 shadow rays a viewing ray, bench_random
            // --lights mixed --fog seed 8301).
            int x = x0;
            while (x <= x1) {
                if (mTs.lit[size_t(x - x0)] != kNeedsRays) {
                    ++x;
                    continue;
                }
                if (!mSettings.coherence) {
                    estimateAt(x);
                    ++x;
                    continue;
                }
                const uint8_t free = mTs.opaqueFree[size_t(x - x0)];
                int end = x;
                while (end + 1 <= x1 && mTs.lit[size_t(end + 1 - x0)] == kNeedsRays &&
                       mTs.opaqueFree[size_t(end + 1 - x0)] == free) {
                    ++end;
                }
                shadeCheckedRun(x, end, /*media=*/true, /*blockers=*/!free);
                x = end + 1;
            }
            mTs.shadow.restrictTo(nullptr);
            mTs.shadow.restrictMediaTo(nullptr);
            return;
        }
        mGrid = mSettings.aci.grid;  // the adaptive density starts afresh on every span
        int x = x0;
        while (x <= x1) {
            if (mTs.lit[size_t(x - x0)] != kNeedsRays) {
                ++x;
                continue;
            }
            int end = x;
            while (end + 1 <= x1 && mTs.lit[size_t(end + 1 - x0)] == kNeedsRays) ++end;
            // The certified default interpolates only where checks and the obstacles that
            // block rays allow it (shadeCheckedRun); the paper's and arcs modes keep the
            // shadow patterns of Vedel's section 5.
            if (mSettings.aci.coverage && mSettings.coherence) {
                if (mRows[0]) {
                    shadeRowPairRun(x, end);
                } else {
                    shadeCheckedRun(x, end, /*media=*/false, /*blockers=*/true);
                }
            } else {
                shadeRun(x, end);
            }
            x = end + 1;
        }
        mTs.shadow.restrictTo(nullptr);
    }

    // Full ACI at every lit pixel against every obstacle (Method::AciPixel).
    void shadePixel(int x) {
        Receiver r = receiver(x);
        if (!lightReaches(mLight, r)) return;
        mGrid = mSettings.aci.grid;
        mTs.shadow.restrictTo(nullptr);
        if (mCtx.occluder.mediumCount() > 0) {
            estimateAt(x);  // estimate(): aciThroughMedia where media lie in between
            return;
        }
        Estimate e = evaluate(x, /*adapt=*/false);
        store(x, e.formFactor, e.gradient, e.errorBound);
    }

private:
    Receiver receiver(int x) const {
        const Hit& h = mTs.hits[size_t(x)];
        return Receiver{h.point, h.normal};
    }

    void store(int x, double f, const Vec3& grad, double bound = 0.0) {
        PixelSum& s = mTs.sums[size_t(x)];
        s.irradiance += mLight.radiance * f;
        s.formFactor += f;
        s.gradient += grad;
        s.errorBound += bound;
    }

    // The shadow rays' start offset at pixel x.
    double rayOffset(int x) const {
        return mCtx.offsetPerPoint
                   ? receiverRayOffset(mCtx.occluder, mTs.hits[size_t(x)].point, mCtx.offsetFloor)
                   : mSettings.aci.rayOffset;
    }

    // Checked interpolation over pixels [x0, x1] of a span. Evaluated at both ends and the
    // middle; an interval [l, r] with its middle m evaluated is interpolated (Lagrange, as
    // pattern coherence does) only after a check: its quarter points q are evaluated and the
    // quadratic through l, m, r must predict each within kCheckedInterpolationTolerance x the
    // unoccluded form factor there. The pixels are then interpolated through l, q, m and m, q, r
    // (half the step of the checked quadratic); otherwise each half is checked the same way,
    // down to evaluating every pixel, each pixel at most once.
    //
    // `media`: pixels with media in their pyramid, estimated by estimateAt (aciThroughMedia),
    // whose shadow from the media alone is the transmittance's, smooth in the receiver;
    // otherwise pixels evaluated by certified ACI. `blockers`: opaque obstacles may shadow the
    // pixels, and a check also needs every obstacle that may block a segment from some pixel
    // of [l, r] to the light (obstaclesNear) to block rays at each of the five evaluated
    // pixels: a shadow that only pixels between them would see, or one that vanishes between
    // them, refuses it.
    void shadeCheckedRun(int x0, int x1, bool media, bool blockers) {
        mCheckMedia = media;
        mCheckBlockers = blockers;
        if (x1 - x0 < 4) {
            for (int x = x0; x <= x1; ++x) checkedSample(x);
            return;
        }
        const int m = (x0 + x1) / 2;
        const Sample a = checkedSample(x0), b = checkedSample(x1), mid = checkedSample(m);
        refineCheckedRun(x0, a, m, mid, x1, b);
    }

    Sample checkedSample(int x) {
        Sample s = mCheckMedia ? estimateAt(x) : exact(x);
        const Receiver r = receiver(x);
        const GWithDerivative open = unoccludedG(mLight, r, mSettings.aci.gradient);
        s.openG = open.g;
        s.openGradient = gradientOf(open.dg, r.normal);
        if (!mCheckMedia)
            record(x, s.openG, s.openG - s.g, s.openGradient - s.gradient, s.errorBound, s.blockers,
                   dark(x, s));
        return s;
    }

    // Keeps pixel x's shadow for the odd rows next to this one (rowPairs), when asked.
    void record(int x, const Vec3& open, const Vec3& shadow, const Vec3& shadowGradient, double bound,
                const std::vector<uint32_t>& blockers, bool dark) {
        if (!mOut) return;
        PixelShadow& p = mOut[size_t(x)];
        p = PixelShadow{};
        if (blockers.size() > size_t(kRowBlockers)) return;
        p.dark = dark;
        p.horizonCut = horizonCut(x);
        p.open = open;
        p.shadow = shadow;
        p.shadowGradient = shadowGradient;
        p.bound = bound;
        p.object = mTs.hits[size_t(x)].object;
        p.blockerCount = uint8_t(blockers.size());
        std::copy(blockers.begin(), blockers.end(), p.blockers.begin());
        p.known = true;
    }

    // A paired row's run of pixels [x0, x1] (rowPairs; rows y -+ s and y -+ 3s are done). A
    // pixel pairs when those four rows' records are known there, lie on its object and saw the
    // same blockers, its own candidates are exactly those blockers (the obstacle it lies on
    // aside, as in refineCheckedRun: a candidate that blocks no neighbour could still shadow
    // this row alone), and the shadow is smooth across the rows: the cubic through the four
    // rows and the line through the middle two agree at y within kCheckedInterpolationTolerance
    // x the unoccluded F (a shadow narrower than the rows' spacing, centred on this row, bends
    // the cubic away from the line). A stretch of at least kMinRowPairRun pixels that pair is
    // evaluated at its middle; when that pixel saw the same blockers and agrees with the cubic
    // within the same tolerance, the rest of the stretch takes the cubic. Everything else is
    // shaded by checked interpolation along the row (shadeCheckedRun), a failed stretch from
    // its middle and its two ends on.
    void shadeRowPairRun(int x0, int x1) {
        mCheckMedia = false;
        std::vector<uint8_t>& paired = mTs.paired;
        paired.assign(size_t(x1 - x0 + 1), 0);
        // The unoccluded G of the pixels that reach rule (c), kept for pairedStretch.
        std::vector<GWithDerivative>& open = mTs.rowOpen;
        open.resize(size_t(x1 - x0 + 1));
        std::vector<uint32_t>& mine = mTs.rowCandidates;
        std::vector<uint32_t>& theirs = mTs.rowBlockers;
        for (int x = x0; x <= x1; ++x) {
            const PixelShadow& a = mRows[1][size_t(x)];
            const int object = mTs.hits[size_t(x)].object;
            bool agree = true, cut = horizonCut(x);
            for (const PixelShadow* row : mRows) {
                const PixelShadow& p = row[size_t(x)];
                agree = agree && p.known && p.object == object && p.sameBlockers(a) &&
                        p.dark == a.dark;
                cut = cut || p.horizonCut;
            }
            if (!agree) continue;
            const int self = object - int(mCtx.scene.receivers.size());
            auto notSelf = [self](uint32_t i) { return int(i) != self; };
            mine.clear();
            std::copy_if(mTs.pixelObstacles.begin() + mTs.pixelObstacleStart[size_t(x - mX0)],
                         mTs.pixelObstacles.begin() + mTs.pixelObstacleStart[size_t(x - mX0 + 1)],
                         std::back_inserter(mine), notSelf);
            std::sort(mine.begin(), mine.end());
            theirs.clear();
            std::copy_if(a.blockers.begin(), a.blockers.begin() + a.blockerCount,
                         std::back_inserter(theirs), notSelf);
            if (mine != theirs) continue;
            const Vec3 n = mTs.hits[size_t(x)].normal;
            const GWithDerivative& openG = open[size_t(x - x0)] =
                unoccludedG(mLight, receiver(x), mSettings.aci.gradient);
            const double open = glm::dot(openG.g, n);
            const double bend = std::abs(glm::dot(cubicShadow(x) - lineShadow(x), n));
            // Where a tangent plane cuts the light (horizonCut), the rows' unoccluded G must
            // predict this pixel's the same way (as horizonFollows asks along a row).
            const double miss = cut ? std::abs(glm::dot(cubicOf(&PixelShadow::open, x) - openG.g, n)) : 0.0;
            paired[size_t(x - x0)] = bend <= kCheckedInterpolationTolerance * open &&
                                     (!cut || miss <= kCheckedInterpolationTolerance * facingF(x));
        }
        // Stretches too short to gain from the pairing are shaded along the row with their
        // neighbours.
        int x = x0;
        while (x <= x1) {
            int end = x;
            while (end + 1 <= x1 && paired[size_t(end + 1 - x0)] == paired[size_t(x - x0)]) ++end;
            if (paired[size_t(x - x0)] && end - x + 1 >= kMinRowPairRun) {
                pairedStretch(x, end, open.data() + (x - x0));
                x = end + 1;
                continue;
            }
            // A stretch along the row: up to the next paired stretch long enough to pair.
            int stop = end;
            while (stop + 1 <= x1) {
                int e = stop + 1;
                while (e + 1 <= x1 && paired[size_t(e + 1 - x0)] == paired[size_t(stop + 1 - x0)]) ++e;
                if (paired[size_t(stop + 1 - x0)] && e - stop >= kMinRowPairRun) break;
                stop = e;
            }
            shadeCheckedRun(x, stop, /*media=*/false, /*blockers=*/true);
            x = stop + 1;
        }
    }

    static constexpr int kMinRowPairRun = 6;

    // The shadow at pixel x of this row from the four rows' records: the cubic through rows
    // y - 3s, y - s, y + s, y + 3s at y, and the line through the middle two.
    Vec3 cubicShadow(int x) const { return cubicOf(&PixelShadow::shadow, x); }
    Vec3 cubicOf(Vec3 PixelShadow::*field, int x) const {
        return (9.0 * (mRows[1][size_t(x)].*field + mRows[2][size_t(x)].*field) -
                mRows[0][size_t(x)].*field - mRows[3][size_t(x)].*field) / 16.0;
    }
    Vec3 lineShadow(int x) const {
        return 0.5 * (mRows[1][size_t(x)].shadow + mRows[2][size_t(x)].shadow);
    }

    // `open`: the unoccluded G of pixels l..r (shadeRowPairRun's).
    void pairedStretch(int l, int r, const GWithDerivative* openAt) {
        const int m = (l + r) / 2;
        const Sample sm = checkedSample(m);
        auto agrees = [&](int x, const Sample& s) {
            if (!mRows[1][size_t(x)].sameBlockers(s.blockers)) return false;
            if (mRows[1][size_t(x)].dark != dark(x, s)) return false;
            const Vec3 n = mTs.hits[size_t(x)].normal;
            const Vec3 g = s.openG - cubicShadow(x);
            const double open = glm::dot(s.openG, n);
            const double diff = std::abs(std::max(0.0, glm::dot(g, n)) - glm::dot(s.g, n));
            return open > 0.0 ? diff <= kCheckedInterpolationTolerance * open : diff == 0.0;
        };
        if (!agrees(m, sm)) {
            const Sample sl = checkedSample(l), sr = checkedSample(r);
            refineCheckedRun(l, sl, m, sm, r, sr);
            return;
        }
        const double checked = sm.errorBound;
        for (int i = l; i <= r; ++i) {
            if (i == m) continue;
            const Receiver rc = receiver(i);
            const GWithDerivative& open = openAt[i - l];
            double rowsBound = 0.0;
            Vec3 gradientShadow(0.0);
            for (size_t k = 0; k < 4; ++k) {
                const PixelShadow& p = mRows[k][size_t(i)];
                rowsBound = std::max(rowsBound, p.bound);
                gradientShadow += (k == 1 || k == 2 ? 9.0 / 16.0 : -1.0 / 16.0) * p.shadowGradient;
            }
            const Vec3 g = open.g - cubicShadow(i);
            const Vec3 grad = gradientOf(open.dg, rc.normal) - gradientShadow;
            const double f = std::max(0.0, glm::dot(g, rc.normal));
            const double bound = std::max(checked, rowsBound) +
                                 kCheckedInterpolationTolerance * glm::dot(open.g, rc.normal);
            store(i, f, grad, bound);
            mTs.sums[size_t(i)].shadowed = true;
            ++mTs.stats.interpolatedPixels;
            ++mTs.stats.rowPairPixels;
            if (mOut) {
                PixelShadow& p = mOut[size_t(i)];
                p = mRows[1][size_t(i)];
                p.shadow = open.g - g;
                p.shadowGradient = gradientShadow;
                p.bound = bound;
                p.horizonCut = horizonCut(i);
                p.open = open.g;
            }
        }
    }

    void refineCheckedRun(int l, const Sample& sl, int m, const Sample& sm, int r,
                          const Sample& sr) {
        const bool left = m - l >= 2, right = r - m >= 2;
        if (!left && !right) return;
        const int q0 = (l + m) / 2, q1 = (m + r) / 2;
        Sample s0, s1;
        double miss = 0.0;  // the checked quadratic's largest miss, relative
        if (left) {
            s0 = checkedSample(q0);
            miss = std::max(miss, predictionMiss(q0, s0, l, sl, m, sm, r, sr));
        }
        if (right) {
            s1 = checkedSample(q1);
            miss = std::max(miss, predictionMiss(q1, s1, l, sl, m, sm, r, sr));
        }
        bool ok = miss <= kCheckedInterpolationTolerance;
        // The quadratic missed, but the five samples may still be one smooth shadow: each of
        // the three inner ones predicted by the cubic through the other four within the same
        // tolerance lets the quartic through all five interpolate the interval (since
        // 2026-12-06: on random scenes 1-4 at 200 x 200, 2-11% fewer shadow rays and the same
        // mean differences to three decimals; Table 1 at 300 x 300, 8% fewer evaluations).
        bool quartic = false;
        const int xs[5] = {l, q0, m, q1, r};
        const Sample* ss[5] = {&sl, &s0, &sm, &s1, &sr};
        if (!ok && left && right) {
            Vec3 shadow[5];
            for (int k = 0; k < 5; ++k) shadow[k] = ss[k]->openG - ss[k]->g;
            double worst = 0.0;
            for (int k = 1; k < 4; ++k) {
                int ox[4];
                Vec3 ov[4];
                int c = 0;
                for (int j = 0; j < 5; ++j)
                    if (j != k) ox[c] = xs[j], ov[c] = shadow[j], ++c;
                worst = std::max(worst, relativeMiss(xs[k], *ss[k], lagrangeN(xs[k], ox, ov, 4)));
            }
            quartic = ok = worst <= kCheckedInterpolationTolerance;
        }
        // An umbra's edge between the samples (all of them blocked by the same obstacles, some
        // seeing none of the light): the shadow turns there, which five samples cannot see.
        // (The default scene at 200 x 200: a quartic across the umbra's edge under the box put
        // 0.0033 of F where there is none, 6.8 of 255 too bright.)
        if (ok) {
            const bool darkL = dark(l, sl);
            ok = dark(m, sm) == darkL && dark(r, sr) == darkL && (!left || dark(q0, s0) == darkL) &&
                 (!right || dark(q1, s1) == darkL);
        }
        // On an obstacle whose tangent plane cuts the light, that part must follow (below).
        if (ok) ok = horizonFollows(l, r, quartic, xs, ss);
        if (ok && mCheckBlockers) {
            const std::vector<uint32_t>& involved = obstaclesNear(l, r);
            // The obstacle the span lies on (curved receivers) is always in its own pyramid
            // and blocks nothing on its lit side: for it, blocking at all five pixels or at
            // none of them is consistent (a shadow of its own that appears and vanishes
            // between two of them is left to the check).
            const int self = mTs.hits[size_t(l)].object - int(mCtx.scene.receivers.size());
            auto others = [&](const std::vector<uint32_t>& v) {
                std::vector<uint32_t> out;
                for (uint32_t i : v)
                    if (int(i) != self) out.push_back(i);
                return out;
            };
            auto selfBlocks = [&](const Sample& s) {
                return self >= 0 && std::binary_search(s.blockers.begin(), s.blockers.end(),
                                                       uint32_t(self));
            };
            const std::vector<uint32_t> expected = others(involved);
            const bool selfAtL = selfBlocks(sl);
            auto agrees = [&](const Sample& s) {
                return others(s.blockers) == expected && selfBlocks(s) == selfAtL;
            };
            ok = agrees(sl) && agrees(sm) && agrees(sr) && (!left || agrees(s0)) &&
                 (!right || agrees(s1));
        }
        if (ok && quartic) {
            for (int i = l + 1; i < r; ++i) {
                if (i == q0 || i == m || i == q1) continue;
                interpolateQuartic(i, xs, ss);
            }
            return;
        }
        if (ok) {
            // An interpolated pixel's bound: its samples' plus what the check allowed.
            for (int i = l + 1; i < m; ++i) {
                if (i != q0) interpolateShadow(i, l, sl, q0, s0, m, sm);
            }
            for (int i = m + 1; i < r; ++i) {
                if (i != q1) interpolateShadow(i, m, sm, q1, s1, r, sr);
            }
            return;
        }
        if (left) refineCheckedRun(l, sl, q0, s0, m, sm);
        if (right) refineCheckedRun(m, sm, q1, s1, r, sr);
    }

    // Checked interpolation at pixel i: the shadow (unoccluded G minus G, and the same of the
    // gradient), smooth where the check passed and small where little is shadowed, is
    // interpolated (Lagrange) and taken from pixel i's own closed form. Its bound: the
    // samples' largest plus what the check allowed (not certified by rays of its own).
    void interpolateShadow(int i, int x0, const Sample& s0, int xm, const Sample& sm, int x1,
                           const Sample& s1) {
        storeInterpolated(i,
                          lagrange(i, x0, s0.openG - s0.g, xm, sm.openG - sm.g, x1, s1.openG - s1.g),
                          lagrange(i, x0, s0.openGradient - s0.gradient, xm,
                                   sm.openGradient - sm.gradient, x1, s1.openGradient - s1.gradient),
                          std::max({s0.errorBound, sm.errorBound, s1.errorBound}), s0.blockers);
    }

    // Checked interpolation at pixel i by the quartic through five samples (refineCheckedRun),
    // as interpolateShadow does with a quadratic.
    void interpolateQuartic(int i, const int* xs, const Sample* const* ss) {
        Vec3 sh[5], shg[5];
        double bound = 0.0;
        for (int k = 0; k < 5; ++k) {
            sh[k] = ss[k]->openG - ss[k]->g;
            shg[k] = ss[k]->openGradient - ss[k]->gradient;
            bound = std::max(bound, ss[k]->errorBound);
        }
        storeInterpolated(i, lagrangeN(i, xs, sh, 5), lagrangeN(i, xs, shg, 5), bound, ss[0]->blockers);
    }

    // Pixel i from its interpolated shadow (and the shadow's gradient), taken from its own
    // closed form; its bound the samples' largest plus what the check allowed.
    void storeInterpolated(int i, const Vec3& shadow, const Vec3& shadowGradient, double samplesBound,
                           const std::vector<uint32_t>& blockers) {
        const Receiver r = receiver(i);
        const GWithDerivative open = unoccludedG(mLight, r, mSettings.aci.gradient);
        const Vec3 g = open.g - shadow;
        const Vec3 grad = gradientOf(open.dg, r.normal) - shadowGradient;
        const double f = std::max(0.0, glm::dot(g, r.normal));
        const double bound = samplesBound + kCheckedInterpolationTolerance * glm::dot(open.g, r.normal);
        store(i, f, grad, bound);
        mTs.sums[size_t(i)].shadowed = true;
        ++mTs.stats.interpolatedPixels;
        // The check saw the same blockers at its five samples (media runs record nothing).
        if (!mCheckMedia)
            record(i, open.g, open.g - g, gradientOf(open.dg, r.normal) - grad, bound, blockers,
                   !(f > kDarkFraction * glm::dot(open.g, r.normal)));
    }

    // Whether sample s at pixel x sees none of the light (an umbra; F = 0 up to rounding). The
    // shadow is no smooth function across an umbra's edge (F = max(0, open - shadow) turns
    // there), so checked interpolation and row pairs ask their samples to agree on it, as on
    // their blockers.
    bool dark(int x, const Sample& s) const {
        const Vec3 n = mTs.hits[size_t(x)].normal;
        return !(glm::dot(s.g, n) > kDarkFraction * glm::dot(s.openG, n));
    }

    // Whether pixel x lies on an obstacle (a curved receiver) whose tangent plane there cuts the
    // light's frame. The unoccluded G is then that of the part above the horizon, which turns
    // with the surface's normal: on a level set's bumpy surface (the bunny's flank) the normal
    // changes from pixel to pixel, and so do G and the shadow (open G - G), however well five
    // samples agree. (Pixels (96-103, 102-103) of vdb_scenes/bunny.json at 200 x 200 came out up
    // to 5.6 of 255 too bright, against 0.03 evaluated one by one.) On a plane every pixel has
    // the same horizon, which the light's part above it then does not depend on.
    bool horizonCut(int x) const {
        const Hit& h = mTs.hits[size_t(x)];
        if (h.object >= 0 && size_t(h.object) < mCtx.scene.receivers.size()) return false;
        for (int k = 0; k < 4; ++k)
            if (!(glm::dot(mLight.point(k & 1, k >> 1) - h.point, h.normal) > 0.0)) return true;
        return false;
    }

    // The form factor of the whole light at pixel x's point, seen by a receiver facing the
    // light's centre: the scale of what the pixel could receive, with no horizon cutting it.
    double facingF(int x) const {
        const Vec3& p = mTs.hits[size_t(x)].point;
        const Vec3 towards = glm::normalize(mLight.point(0.5, 0.5) - p);
        return glm::dot(unoccludedG(mLight, Receiver{p, towards}, false).g, towards);
    }

    // Checked interpolation over [l, r] (samples at xs, the quadratics' or the quartic's): where
    // some pixel's tangent plane cuts the light (horizonCut), the samples' unoccluded G, which
    // holds the horizon's part and is known in closed form at every pixel, must be predicted
    // by the same interpolation at every pixel between them within
    // kCheckedInterpolationTolerance x facingF there (not x the pixel's own unoccluded F, which
    // goes to 0 where the horizon hides most of the light). A smooth surface mostly passes; a
    // bumpy one leaves its pixels to be evaluated.
    bool horizonFollows(int l, int r, bool quartic, const int* xs, const Sample* const* ss) const {
        bool cut = false;
        for (int i = l; !cut && i <= r; ++i) cut = horizonCut(i);
        if (!cut) return true;
        Vec3 open[5];
        for (int k = 0; k < 5; ++k) open[k] = ss[k]->openG;
        for (int i = l + 1; i < r; ++i) {
            if (i == xs[1] || i == xs[2] || i == xs[3]) continue;
            const Vec3 predicted = quartic ? lagrangeN(i, xs, open, 5)
                                   : i < xs[2] ? lagrange(i, xs[0], open[0], xs[1], open[1], xs[2], open[2])
                                               : lagrange(i, xs[2], open[2], xs[3], open[3], xs[4], open[4]);
            const Receiver rc = receiver(i);
            const Vec3 actual = unoccludedG(mLight, rc, false).g;
            if (!(std::abs(glm::dot(predicted - actual, rc.normal)) <= kCheckedInterpolationTolerance * facingF(i)))
                return false;
        }
        return true;
    }

    // The candidates that may block a segment from some pixel of [l, r] to the light (the
    // union of the pixels' own lists, shadeSpan), sorted, each once.
    const std::vector<uint32_t>& obstaclesNear(int l, int r) {
        auto& out = mTs.involved;
        out.assign(mTs.pixelObstacles.begin() + mTs.pixelObstacleStart[size_t(l - mX0)],
                   mTs.pixelObstacles.begin() + mTs.pixelObstacleStart[size_t(r - mX0 + 1)]);
        std::sort(out.begin(), out.end());
        out.erase(std::unique(out.begin(), out.end()), out.end());
        return out;
    }

    // |F(q) - F predicted at q by the shadow's quadratic through l, m, r| over the unoccluded F at q.
    double predictionMiss(int q, const Sample& sq, int l, const Sample& sl, int m,
                          const Sample& sm, int r, const Sample& sr) const {
        return relativeMiss(q, sq, lagrange(q, l, sl.openG - sl.g, m, sm.openG - sm.g, r, sr.openG - sr.g));
    }

    // |F(q) - F from the predicted shadow at q| over the unoccluded F at q.
    double relativeMiss(int q, const Sample& sq, const Vec3& shadow) const {
        const Vec3 n = mTs.hits[size_t(q)].normal;
        const Vec3 g = sq.openG - shadow;
        const double open = glm::dot(sq.openG, n);
        const double diff = std::abs(std::max(0.0, glm::dot(g, n)) - glm::dot(sq.g, n));
        return open > 0.0 ? diff / open : (diff > 0.0 ? HUGE_VAL : 0.0);
    }

    // One estimate at pixel x through estimate(): a Monte Carlo method (seeded by the pixel and
    // the light only), or ACI through media. Stores it and returns what interpolation needs.
    Sample estimateAt(int x) {
        McSettings s = mSettings.mc;
        s.rayOffset = rayOffset(x);
        s.seed = mcSeed(uint64_t(x), uint64_t(mRow), uint64_t(mLightIndex), mSettings.mc.seed);
        AciSettings a = mSettings.pixelAci();
        a.rayOffset = s.rayOffset;
        a.reuseCorners = false;
        mTs.integrator.setSettings(a);
        const Receiver r = receiver(x);
        uint64_t before = mTs.shadow.raysCast();
        const Estimate e = estimate(mSettings.method, r, mLight, mTs.shadow, mTs.integrator, s);
        mTs.sums[size_t(x)].rays += mTs.shadow.raysCast() - before;
        mTs.sums[size_t(x)].shadowed = true;
        mTs.stats.firstLevelRays += e.counts.firstLevelRays;
        mTs.stats.secondLevelRays += e.counts.secondLevelRays;
        mTs.stats.coverageRays += e.counts.coverageRays;
        mTs.stats.footprintSamples += e.counts.footprintSamples;
        mTs.stats.footprintClearances += e.counts.footprintClearances;
        if (!isMonteCarlo(mSettings.method)) ++mTs.stats.aciEvaluations;
        mTs.stats.coarserEvaluations += e.counts.coarserEvaluations;
        mTs.stats.finerRedos += e.counts.finerRedos;
        store(x, e.formFactor, isMonteCarlo(mSettings.method) ? Vec3(0.0) : e.gradient,
              e.errorBound);
        return Sample{e.g, e.gradient, e.errorBound, {}, 0, std::move(e.blockers)};
    }

    Estimate evaluate(int x, bool adapt) {
        AciSettings s = mSettings.pixelAci();
        s.grid = mGrid;
        s.reuseCorners = mReuse;
        s.rayOffset = rayOffset(x);
        mTs.integrator.setSettings(s);
        uint64_t before = mTs.shadow.raysCast();
        Estimate e = mTs.integrator.evaluate(receiver(x), mLight, mTs.shadow);
        mTs.sums[size_t(x)].rays += mTs.shadow.raysCast() - before;
        mTs.sums[size_t(x)].shadowed = true;
        RenderStats& st = mTs.stats;
        ++st.aciEvaluations;
        st.coarserEvaluations += e.counts.coarserEvaluations;
        st.finerRedos += e.counts.finerRedos;
        st.firstLevelRays += e.counts.firstLevelRays;
        st.secondLevelRays += e.counts.secondLevelRays;
        st.coverageRays += e.counts.coverageRays;
        st.footprintSamples += e.counts.footprintSamples;
        st.footprintClearances += e.counts.footprintClearances;
        st.cacheHits += e.counts.cacheHits;
        st.reusedRays += e.counts.reusedRays;
        st.restarts += e.counts.restarts;
        st.squaresRefined += e.counts.squaresRefined;
        st.maxDepth = std::max(st.maxDepth, e.counts.maxDepth);
        // With coverage a finer first level buys nothing coverage does not already prove (and
        // costs certified rays at every corner): the grid stays at its base there.
        if (adapt && mSettings.adaptiveGrid && !mSettings.aci.coverage) {
            // Vedel 1993, section 5: finer after a refinement of depth >= 2 or an inconsistency,
            // coarser again when no refinement was needed, unchanged after depth 1. The tangent
            // mode refines only where its tangent arcs cannot stand (two silhouettes meeting,
            // unknown distances), so there a refinement of depth 1 already asks for finer.
            int base = mSettings.aci.grid, top = base * mSettings.maxGridFactor;
            const int finerDepth = mSettings.aci.tangentContour ? 1 : 2;
            if (e.counts.maxDepth >= finerDepth || e.counts.restarts > 0) {
                if (mGrid < top) {
                    mGrid = std::min(top, mGrid + 1);
                    ++st.gridIncreases;
                }
            } else if (e.counts.maxDepth == 0 && mGrid > base) {
                mGrid = std::max(base, mGrid - 1);
                ++st.gridDecreases;
            }
        }
        return e;
    }

    Sample exact(int x) {
        int grid = mGrid;
        Estimate e = evaluate(x, /*adapt=*/true);
        store(x, e.formFactor, e.gradient, e.errorBound);
        return Sample{e.g, e.gradient, e.errorBound, std::move(e.pattern), grid,
                      std::move(e.blockers)};
    }

    std::vector<uint8_t> pattern(int x, int grid) {
        AciSettings s = mSettings.aci;
        s.grid = grid;
        s.reuseCorners = mReuse;
        s.rayOffset = rayOffset(x);
        mTs.integrator.setSettings(s);
        AciCounts counts;
        uint64_t before = mTs.shadow.raysCast();
        std::vector<uint8_t> p = mTs.integrator.pattern(receiver(x), mLight, mTs.shadow, counts);
        mTs.sums[size_t(x)].rays += mTs.shadow.raysCast() - before;
        mTs.sums[size_t(x)].shadowed = true;
        ++mTs.stats.patternEvaluations;
        mTs.stats.firstLevelRays += counts.firstLevelRays;
        mTs.stats.secondLevelRays += counts.secondLevelRays;
        mTs.stats.reusedRays += counts.reusedRays;
        return p;
    }

    // Pixels [x0, x1], all seeing the light, with a non-empty candidate list.
    void shadeRun(int x0, int x1) {
        Sample a = exact(x0);
        int x = x0;
        while (x < x1) {
            AciSettings traced = mSettings.aci;
            traced.grid = a.grid;
            // (A polygon light's fan joins its triangles' patterns: not one grid's, not used.)
            bool usable = a.pattern.size() == firstLevelGrid(mLight, traced).corners() &&
                          !uniformPattern(a.pattern);
            // With a uniform pattern (all visible, all hidden) ACI spends only the first-level
            // rays, as a pattern would, and its answer is exact: no reason to interpolate.
            if (!mSettings.coherence || !usable) {
                a = exact(++x);
                continue;
            }
            int k = x + 1;
            while (k <= x1 && pattern(k, a.grid) == a.pattern) ++k;
            // Pixels x .. k-1 share the anchor's pattern; k (if inside the run) is where it
            // changed. Interpolation stays within the constant pattern: its far end e = k - 1
            // gets a full evaluation, and so does the middle pixel when there is one.
            int e = k - 1;
            if (e > x) {
                Sample mid;
                int m = (x + e) / 2;
                if (e - x >= 2) mid = exact(m);
                Sample b = exact(e);
                for (int i = x + 1; i < e; ++i) {
                    if (i != m) interpolate(i, x, a, m, mid, e, b);
                }
                a = std::move(b);
                x = e;
            }
            if (k <= x1) {
                a = exact(k);  // the new anchor, where the pattern changed
                x = k;
            }
        }
    }

    // Quadratic (Lagrange) interpolation through the samples at pixels x0 < xm < x1, of G
    // projected on the pixel's own normal (Vedel 1993, section 5), and of the gradient.
    void interpolate(int i, int x0, const Sample& s0, int xm, const Sample& sm, int x1,
                     const Sample& s1) {
        Vec3 g = lagrange(i, x0, s0.g, xm, sm.g, x1, s1.g);
        Vec3 grad = lagrange(i, x0, s0.gradient, xm, sm.gradient, x1, s1.gradient);
        double f = std::max(0.0, glm::dot(g, mTs.hits[size_t(i)].normal));
        // The samples' largest bound (an interpolated pixel's is not certified by rays of its
        // own; docs/estimator.md).
        store(i, f, grad, std::max({s0.errorBound, sm.errorBound, s1.errorBound}));
        mTs.sums[size_t(i)].shadowed = true;
        ++mTs.stats.interpolatedPixels;
    }

    const Context& mCtx;
    ThreadState& mTs;
    const RectLight& mLight;
    const RenderSettings& mSettings;
    size_t mLightIndex;
    int mRow;
    int mGrid = 2;
    bool mReuse = false;  // reuse first-level rays in this span (AciSettings::reuseCorners)
    bool mCheckMedia = false;  // shadeCheckedRun: the run is of media pixels (estimateAt)
    bool mCheckBlockers = true;  // shadeCheckedRun: the check also compares blockers
    int mX0 = 0;               // the span's first pixel
    PixelShadow* mOut = nullptr;          // this row's records for this light (rowPairs)
    // A paired row's: the records of rows y - 3s, y - s, y + s, y + 3s (rowPairs).
    std::array<const PixelShadow*, 4> mRows{};
};

void renderRow(const Context& ctx, ThreadState& ts, int y, const RowLink& link = RowLink{}) {
    const int width = ctx.camera.width();
    const RenderSettings& settings = ctx.settings;
    RenderStats& st = ts.stats;
    ts.hits.resize(size_t(width));
    ts.sums.assign(size_t(width), PixelSum{});
    for (int x = 0; x < width; ++x) {
        ts.hits[size_t(x)] = castViewingRay(ctx, ts, x, y);
        ++st.viewingRays;
        if (ts.hits[size_t(x)].object >= 0) ++st.viewingRayHits;
    }

    for (size_t li = 0; li < ctx.scene.lights.size(); ++li) {
        const RectLight& light = ctx.scene.lights[li];
        SpanShader shader(ctx, ts, light, li, y, link);
        if (settings.method == Method::AciPixel) {
            for (int x = 0; x < width; ++x) {
                if (ts.hits[size_t(x)].object >= 0) shader.shadePixel(x);
            }
            continue;
        }
        // Section 5: spans of adjacent pixels on one object, at most maxSpan long.
        int x = 0;
        while (x < width) {
            if (ts.hits[size_t(x)].object < 0) {
                ++x;
                continue;
            }
            int end = x;
            while (end + 1 < width && end + 1 - x < settings.maxSpan &&
                   continuesSpan(ts.hits[size_t(end)], ts.hits[size_t(end + 1)])) {
                ++end;
            }
            shader.shadeSpan(x, end);
            x = end + 1;
        }
    }

    for (int x = 0; x < width; ++x) {
        const Hit& h = ts.hits[size_t(x)];
        const PixelSum& s = ts.sums[size_t(x)];
        Rgb c = h.object >= 0 ? h.albedo * s.irradiance : ctx.scene.background;
        if (ctx.inScatter) {
            // The media in front of the hit (or all of them, for a miss) dim it and add their
            // own scattered light.
            double T = 1.0;
            const ViewRay ray = ctx.camera.pixelRay(x, y);
            const double end = h.object >= 0 ? h.distance : std::numeric_limits<double>::infinity();
            const Rgb scattered = marchMedia(ctx, ts.volume, ray, end, &T);
            c = scattered + T * c;
            // Surfaces are opaque; where the ray meets none, the media's opacity.
            ctx.color.at(x, y, 3) = h.object >= 0 ? 1.0f : float(1.0 - T);
        }
        for (int k = 0; k < 3; ++k) ctx.color.at(x, y, k) = float(c[k]);
        ctx.aovs.shadowRays.at(x, y) = float(s.rays);
        ctx.aovs.formFactor.at(x, y) = float(s.formFactor);
        ctx.aovs.gradient.at(x, y) = float(glm::length(s.gradient));
        ctx.aovs.errorBound.at(x, y) = float(s.errorBound);
        const bool shadowed = s.rays > 0 || s.shadowed;
        ctx.aovs.mask.at(x, y) = shadowed ? 1.0f : 0.0f;
        st.shadowRays += s.rays;
        if (shadowed) ++st.viewingRaysWithShadowRays;
    }
}

}  // namespace

double renderImageBytes(int width, int height) {
    // 3 colour channels and 4 AOVs as float, plus a viewing-ray hit record per pixel of a row
    // per thread (counted generously as one more 32-byte record per pixel).
    const double pixels = double(width) * double(height);
    return pixels * (7.0 * sizeof(float) + 32.0);
}

void checkRenderMemory(int width, int height, const std::string& file, const std::string& where) {
    constexpr double kGiB = 1024.0 * 1024.0 * 1024.0;
    double limit = 1024.0 * kGiB;  // when sysconf cannot tell
    const long pages = ::sysconf(_SC_PHYS_PAGES), pageSize = ::sysconf(_SC_PAGE_SIZE);
    if (pages > 0 && pageSize > 0) limit = 0.75 * double(pages) * double(pageSize);
    const double need = renderImageBytes(width, height);
    if (need <= limit) return;
    char text[200];
    std::snprintf(text, sizeof text,
                  "%d x %d pixels would need ~%.1f GiB for the image and its AOVs, over the "
                  "limit of %.1f GiB (3/4 of this machine's memory)",
                  width, height, need / kGiB, limit / kGiB);
    throw InputError(file, where, text);
}

RenderResult render(const Scene& scene, const RenderSettings& settingsIn,
                    const RenderProgress& progress) {
    if (!scene.camera) {
        throw InputError(scene.file, "/camera", "the scene has no camera, which rendering needs");
    }
    settingsIn.validate();  // errors name the settings (render_settings.h)
    if (settingsIn.method == Method::McSolidAngle || settingsIn.method == Method::McRatio) {
        // The spherical-rectangle parametrization needs a rectangle, not a parallelogram.
        for (size_t i = 0; i < scene.lights.size(); ++i) {
            const RectLight& l = scene.lights[i];
            if (l.shape == LightShape::Rect && std::abs(glm::dot(l.edgeU, l.edgeV)) >
                1e-9 * glm::length(l.edgeU) * glm::length(l.edgeV)) {
                throw InputError(scene.file, "/lights/" + std::to_string(i),
                                 std::string(methodName(settingsIn.method)) +
                                     " samples the light's spherical rectangle and needs edge_u "
                                     "perpendicular to edge_v");
            }
        }
    }

    auto start = std::chrono::steady_clock::now();
    Camera cam = *scene.camera;
    if (settingsIn.width > 0) cam.width = settingsIn.width;
    if (settingsIn.height > 0) cam.height = settingsIn.height;
    const PinholeCamera camera(cam, scene.file);
    const Occluder occluder = scene.makeOccluder();
    // The tangent mode's shadow rays ask for distances and certificates: build the far-field
    // companions (and measure their error) and the cell tables here, not inside the parallel
    // loop.
    if ((settingsIn.aci.distanceGuided || settingsIn.aci.coverage) &&
        (settingsIn.method == Method::Aci || settingsIn.method == Method::AciPixel))
        occluder.prepareClearance();

    RenderSettings settings = settingsIn;
    const bool offsetPerPoint = !(settings.aci.rayOffset > 0.0);
    if (offsetPerPoint) settings.aci.rayOffset = automaticRayOffset(scene, occluder);
    settings.mc.rayOffset = settings.aci.rayOffset;
    if (settings.mc.samples == 0) settings.mc.samples = defaultSamples(settings.method);
    // threads < 0: run in the caller's arena (a batch shares one arena between its jobs).
    const int threads = settings.threads > 0   ? settings.threads
                        : settings.threads < 0 ? tbb::this_task_arena::max_concurrency()
                                               : std::max(1, tbb::info::default_concurrency());

    const int width = camera.width(), height = camera.height();
    checkRenderMemory(width, height,
                      settingsIn.width > 0 || settingsIn.height > 0 ? "" : scene.file,
                      settingsIn.width > 0 || settingsIn.height > 0 ? "width/height"
                                                                    : "/camera/width");
    // Media the camera sees: their in-scattered light first (a lattice, built in parallel).
    bool mediaSeen = false;
    for (size_t i = 0; i < occluder.mediumCount(); ++i) mediaSeen |= !occluder.mediumBounds(i).empty();
    mediaSeen = mediaSeen && settingsIn.volumesVisible;
    std::unique_ptr<InScatter> inScatter;
    RenderResult result;
    result.color = Image(width, height, mediaSeen ? 4 : 3);
    result.aovs.shadowRays = Image(width, height, 1);
    result.aovs.formFactor = Image(width, height, 1);
    result.aovs.gradient = Image(width, height, 1);
    result.aovs.errorBound = Image(width, height, 1);
    result.aovs.mask = Image(width, height, 1);
    // (Built inside the arena below, so that it uses the render's threads.)
    const Context ctxTemplate{scene,          camera,
                              occluder,       settings,
                              offsetPerPoint, rayOffsetFloor(scene, occluder),
                              result.color,   result.aovs, nullptr};

    // Row pairs (RenderSettings::rowPairs): only where rows are shaded by checked interpolation.
    const bool rowPairs = settings.rowPairs && settings.method == Method::Aci &&
                          settings.aci.coverage && settings.coherence && height >= 3;
    tbb::enumerable_thread_specific<std::unique_ptr<ThreadState>> states;
    std::mutex progressMutex;
    int rowsDone = 0;
    Context ctx = ctxTemplate;
    auto renderRows = [&] {
        if (mediaSeen) {
            inScatter = std::make_unique<InScatter>(scene, occluder, settings.volumeCache,
                                                    settings.volumeSamples);
            ctx.inScatter = inScatter.get();
        }
        // Renders rows[i] for i in [0, n), in parallel, row y linked by link(y).
        auto renderSome = [&](const std::vector<int>& rows, auto&& link) {
            // parallelFor states the fork and the join to TSan: the tasks see this pass's
            // inputs, and the caller (which frees `rows` and reads the records next) sees
            // everything the tasks wrote.
            detail::parallelFor(tbb::blocked_range<size_t>(0, rows.size(), 1),
                                [&](const tbb::blocked_range<size_t>& r) {
                                    auto& state = states.local();
                                    if (!state) state = std::make_unique<ThreadState>(occluder, settings.aci);
                                    for (size_t i = r.begin(); i < r.end(); ++i) {
                                        renderRow(ctx, *state, rows[i], link(rows[i]));
                                        if (progress) {
                                            std::lock_guard<std::mutex> lock(progressMutex);
                                            progress(++rowsDone, height);
                                        }
                                    }
                                });
        };
        if (!rowPairs) {
            std::vector<int> all(static_cast<size_t>(height));
            for (int y = 0; y < height; ++y) all[size_t(y)] = y;
            renderSome(all, [](int) { return RowLink{}; });
            return;
        }
        // Row pairs, in bands of rows: every fourth row first, on its own; then the rows
        // halfway between those (y % 4 == 2), each from the rows 2 and 6 above and below; then
        // the odd rows, from the rows 1 and 3 above and below. Rows that others read keep their
        // records. The first two passes run ahead of the band by what the next passes read,
        // so that every row finds the rows it is paired with done whatever the band: which
        // rows pair depends on neither the band nor the threads, and the image is the same for
        // any. Rows too near the image's top or bottom for their four rows are shaded on their
        // own.
        const size_t perRow = scene.lights.size() * size_t(width);
        std::vector<std::vector<PixelShadow>> records(static_cast<size_t>(height));
        std::vector<char> done(static_cast<size_t>(height), 0);
        auto pass = [&](int step, int from, int to) {
            std::vector<int> rows;
            for (int y = from; y <= to; ++y) {
                const bool mine = step == 4   ? y % 4 == 0 || y == height - 1
                                  : step == 2 ? y % 4 == 2 && y != height - 1
                                              : y % 2 == 1 && y != height - 1;
                if (mine && !done[size_t(y)]) rows.push_back(y);
            }
            for (int y : rows) {
                done[size_t(y)] = 1;
                if (step > 1) records[size_t(y)].assign(perRow, PixelShadow{});
            }
            renderSome(rows, [&, step](int y) {
                RowLink l;
                if (step > 1) l.out = records[size_t(y)].data();
                if (step < 4 && y - 3 * step >= 0 && y + 3 * step <= height - 1) {
                    for (int k = 0; k < 4; ++k) {
                        const std::vector<PixelShadow>& r = records[size_t(y + (2 * k - 3) * step)];
                        l.rows[size_t(k)] = r.empty() ? nullptr : r.data();
                    }
                }
                return l;
            });
        };
        const int band = std::max(64, 16 * threads);
        int freed = 0;  // records of rows before this one are gone
        for (int top = 0; top < height; top += band) {
            const int last = std::min(height - 1, top + band - 1);
            pass(4, top, std::min(height - 1, last + 12));
            pass(2, top, std::min(height - 1, last + 4));
            pass(1, top, last);
            // Later rows read back at most 6 rows.
            for (; freed < last - 8; ++freed) std::vector<PixelShadow>().swap(records[size_t(freed)]);
        }
    };
    if (settings.threads < 0) {
        renderRows();
    } else {
        // More threads than cores, when asked for: raise TBB's worker limit so that it neither
        // ignores the request nor prints a warning of its own (also under --quiet).
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                                  std::max<size_t>(threads, tbb::global_control::active_value(
                                                                tbb::global_control::max_allowed_parallelism)));
        // The arena may run renderRows on another thread: TSan cannot see that hand-over
        // inside the uninstrumented libtbb (thread_sanitizer.h), so it is stated.
        const char forkKey = 0, joinKey = 0;
        detail::tsanRelease(&forkKey);
        tbb::task_arena arena(threads);
        arena.execute([&] {
            detail::tsanAcquire(&forkKey);
            renderRows();
            detail::tsanRelease(&joinKey);
        });
        detail::tsanAcquire(&joinKey);
    }

    RenderStats& stats = result.stats;
    for (const auto& state : states) {
        if (state) stats.merge(state->stats);
    }
    if (inScatter) stats.volumeRays = inScatter->latticeRays();
    for (const auto& state : states)
        if (state) stats.volumeRays += state->volume.raysCast();
    stats.method = methodName(settings.method);
    stats.settingsJson = settingsIn.toJson().dump();
    stats.width = width;
    stats.height = height;
    stats.threads = threads;
    stats.lights = int(scene.lights.size());
    stats.aciGrid = settings.aci.grid;
    stats.aciSteps = settings.aci.steps;
    if (!isMonteCarlo(settings.method))
        for (const RectLight& light : scene.lights) {
            const FirstLevelGrid g = firstLevelGrid(light, settings.aci);
            stats.aciFirstLevel.emplace_back(g.a, g.b);
        }
    stats.aciMode = aciModeName(aciModeOf(settings.aci));
    stats.seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return result;
}

}  // namespace penumbra
