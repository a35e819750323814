#include "penumbra/monte_carlo.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace penumbra {

// ---------------------------------------------------------------------------------------------
// Random numbers: counter-based, so that a stream is a pure function of its seed.

namespace {

// The finalizer of splitmix64 (Steele, Lea and Flood 2014): a bijective 64-bit mixer whose
// output bits each depend on every input bit.
uint64_t mix64(uint64_t z) {
    z ^= z >> 30;
    z *= 0xbf58476d1ce4e5b9ull;
    z ^= z >> 27;
    z *= 0x94d049bb133111ebull;
    z ^= z >> 31;
    return z;
}

constexpr uint64_t kGolden = 0x9e3779b97f4a7c15ull;

// Uniform doubles in [0, 1) from one seed: the splitmix64 sequence.
class Stream {
  public:
    explicit Stream(uint64_t seed) : mState(mix64(seed ^ 0x5851f42d4c957f2dull)) {}
    double next() {
        mState += kGolden;
        return double(mix64(mState) >> 11) * 0x1p-53;
    }

  private:
    uint64_t mState;
};

// Nested uniform scrambling in base 2 (Owen 1995): bit k of the binary fraction is flipped by a
// coin that depends on the seed and on the bits above it, so that points sharing a prefix (an
// elementary interval) are permuted together and the net's stratification survives.
uint32_t owenScramble(uint32_t x, uint64_t seed) {
    uint32_t out = 0;
    uint64_t prefix = 1;  // the leading 1 tells prefixes of different lengths apart
    for (int k = 31; k >= 0; --k) {
        const uint32_t bit = (x >> k) & 1u;
        const uint32_t flip = uint32_t(mix64(seed ^ mix64(prefix)) & 1u);
        out |= (bit ^ flip) << k;
        prefix = (prefix << 1) | bit;
    }
    return out;
}

// The second dimension of Sobol's sequence: its generator matrix is Pascal's triangle mod 2,
// whose columns are v_0 = 1/2 and v_j = v_{j-1} xor (v_{j-1} / 2).
uint32_t sobolDimension1(uint32_t index) {
    uint32_t v = 1u << 31, out = 0;
    for (; index; index >>= 1, v ^= v >> 1) {
        if (index & 1u) out ^= v;
    }
    return out;
}

uint32_t reverseBits(uint32_t x) {
    x = ((x >> 1) & 0x55555555u) | ((x & 0x55555555u) << 1);
    x = ((x >> 2) & 0x33333333u) | ((x & 0x33333333u) << 2);
    x = ((x >> 4) & 0x0f0f0f0fu) | ((x & 0x0f0f0f0fu) << 4);
    x = ((x >> 8) & 0x00ff00ffu) | ((x & 0x00ff00ffu) << 8);
    return (x >> 16) | (x << 16);
}

}  // namespace

uint64_t mcSeed(uint64_t a, uint64_t b, uint64_t c, uint64_t d) {
    uint64_t h = mix64(a + kGolden);
    h = mix64(h ^ (b + 2 * kGolden));
    h = mix64(h ^ (c + 3 * kGolden));
    return mix64(h ^ (d + 4 * kGolden));
}

Vec2 sobolOwen2(uint32_t index, uint64_t seed) {
    const uint32_t x = owenScramble(reverseBits(index), mix64(seed));
    const uint32_t y = owenScramble(sobolDimension1(index), mix64(seed ^ kGolden));
    // The centre of the finest interval, so that no coordinate is exactly 0 or 1.
    return Vec2((double(x) + 0.5) * 0x1p-32, (double(y) + 0.5) * 0x1p-32);
}

// ---------------------------------------------------------------------------------------------
// The spherical rectangle (Urena, Fajardo and King 2013), derived again here.
//
// In the local frame with origin at the receiver, x along edgeU, y along edgeV and z chosen so
// that the light lies in the plane z = z0 < 0, the light is [x0, x1] x [y0, y1]. The great
// circles through its sides have the unit normals (cross products of adjacent corners)
//   n0 = (0, z0, -y0) / |.|    (side y = y0)     n1 = (-z0, 0, x1) / |.|   (side x = x1)
//   n2 = (0, -z0, y1) / |.|    (side y = y1)     n3 = (z0, 0, -x0) / |.|   (side x = x0)
// and the interior angles of the spherical quadrilateral are g_i = acos(-n_i . n_{i+1}); its area
// (Girard) is S = g0 + g1 + g2 + g3 - 2 pi. The part with x <= xu has the same angles g2, g3 at
// the side x = x0 and, at the moving side with normal n(xu) = (-z0, 0, xu) / |.|, the angles
// acos(-b0 nz) and acos(-b1 nz), with b0 = n0.z, b1 = n2.z, nz = n(xu).z (since n0 . n(xu) =
// b0 nz and n(xu) . n2 = nz b1). Setting its area to u S:
//   acos(-b0 nz) + acos(-b1 nz) = u S + k,   k = 2 pi - g2 - g3.
// Writing au = u S + k and expanding cos(au - acos(-b0 nz)) gives
//   nz (b0 cos au - b1) = sin au sqrt(1 - b0^2 nz^2),
// so nz = sign(fu) / sqrt(fu^2 + b0^2) with fu = (b0 cos au - b1) / sin au, and
// xu = -nz z0 / sqrt(1 - nz^2). Given xu, the solid angle of a strip dy at distance
// d = sqrt(xu^2 + z0^2) is proportional to dy / (d^2 + y^2)^(3/2), whose integral is
// y / (d^2 sqrt(d^2 + y^2)): h(y) = y / sqrt(d^2 + y^2) is uniform, so y = h d / sqrt(1 - h^2)
// with h between h(y0) and h(y1).

SphericalRectangle::SphericalRectangle(const RectLight& light, const Vec3& origin)
    : mOrigin(origin) {
    const double lu = glm::length(light.edgeU), lv = glm::length(light.edgeV);
    mX = light.edgeU / lu;
    mY = light.edgeV / lv;
    mZ = glm::cross(mX, mY);
    const Vec3 d = light.corner - origin;
    mZ0 = glm::dot(d, mZ);
    if (mZ0 > 0.0) {
        mZ = -mZ;
        mZ0 = -mZ0;
    }
    mX0 = glm::dot(d, mX);
    mY0 = glm::dot(d, mY);
    mX1 = mX0 + lu;
    mY1 = mY0 + lv;
    if (!(mZ0 < 0.0)) return;  // in the light's plane: an empty spherical rectangle

    auto unit = [](const Vec3& v) { return v / glm::length(v); };
    const Vec3 n0 = unit(Vec3(0.0, mZ0, -mY0));
    const Vec3 n1 = unit(Vec3(-mZ0, 0.0, mX1));
    const Vec3 n2 = unit(Vec3(0.0, -mZ0, mY1));
    const Vec3 n3 = unit(Vec3(mZ0, 0.0, -mX0));
    auto angle = [](const Vec3& a, const Vec3& b) {
        return std::acos(std::clamp(-glm::dot(a, b), -1.0, 1.0));
    };
    const double g0 = angle(n0, n1), g1 = angle(n1, n2), g2 = angle(n2, n3), g3 = angle(n3, n0);
    mB0 = n0.z;
    mB1 = n2.z;
    mK = 2.0 * kPi - g2 - g3;
    mSolidAngle = std::max(0.0, g0 + g1 - mK);
}

Vec3 SphericalRectangle::sample(double u, double v) const {
    // The x coordinate: invert the solid angle of the part x <= xu (file comment above).
    const double au = u * mSolidAngle + mK;
    const double fu = (std::cos(au) * mB0 - mB1) / std::sin(au);
    double nz = 0.0;  // sin(au) = 0 is au = pi: the moving side is the plane x = 0
    if (std::isfinite(fu)) nz = std::copysign(1.0 / std::sqrt(fu * fu + mB0 * mB0), fu);
    nz = std::clamp(nz, -1.0, 1.0);
    const double s2 = 1.0 - nz * nz;
    double xu = s2 > 0.0 ? -nz * mZ0 / std::sqrt(s2) : (nz > 0.0 ? mX1 : mX0);
    xu = std::clamp(xu, mX0, mX1);
    // The y coordinate: h(y) = y / sqrt(d^2 + y^2) is uniform along the column.
    const double d2 = xu * xu + mZ0 * mZ0;
    const double d = std::sqrt(d2);
    const double h0 = mY0 / std::sqrt(d2 + mY0 * mY0);
    const double h1 = mY1 / std::sqrt(d2 + mY1 * mY1);
    const double hv = h0 + v * (h1 - h0);
    const double c2 = 1.0 - hv * hv;
    double yv = c2 > 1e-300 ? hv * d / std::sqrt(c2) : (hv > 0.0 ? mY1 : mY0);
    yv = std::clamp(yv, mY0, mY1);
    return mOrigin + xu * mX + yv * mY + mZ0 * mZ;
}

// ---------------------------------------------------------------------------------------------
// The estimators

namespace {

// What every estimator needs about one receiver point and one light.
struct Setup {
    Setup(const Receiver& r, const RectLight& light, const McSettings& s)
        : m(r.point),
          n(r.normal),
          origin(r.point + s.rayOffset * r.normal),
          lightNormal(light.normal()),
          area(light.area()) {}
    Vec3 m, n, origin, lightNormal;
    double area;
};

// The area-sampling integrand at a point P of the light: cos(theta_M) cos(theta_L) A / (pi r^2)
// (the differential form factor times the light's area), 0 below M's horizon or behind the
// light. Its mean over uniform points of the light is the unoccluded form factor.
double areaIntegrand(const Setup& s, const Vec3& p) {
    const Vec3 c = p - s.m;
    const double r2 = glm::dot(c, c);
    const double cosM = glm::dot(c, s.n);
    const double cosL = -glm::dot(c, s.lightNormal);
    if (!(cosM > 0.0) || !(cosL > 0.0) || !(r2 > 0.0)) return 0.0;
    return cosM * cosL * s.area / (kPi * r2 * r2);
}

// The light that reaches M from P: 0 when an obstacle blocks the ray, else its transmittance
// through the media (1 without any). A positive integrand costs a ray; the caller counts it.
double transmitted(const Setup& s, const Vec3& p, Occluder::Query& query) {
    return query.transmitted(s.origin, p);
}

Estimate finish(double f, const Receiver& r, uint64_t first, uint64_t second) {
    Estimate e;
    e.formFactor = f;
    e.g = f * r.normal;
    e.counts.firstLevelRays = first;
    e.counts.secondLevelRays = second;
    return e;
}


// One cell of mc-adaptive's quadtree over the light's (u, v) square, with one sample per
// quadrant (quadrant q: bit 0 for the upper half in u, bit 1 in v).
struct Cell {
    double u0, v0, size;
    int depth;
    Vec2 at[4];       // the samples, in (u, v)
    double value[4];  // their integrand times visibility
    bool hidden[4];   // their rays were blocked (below the horizon counts as unknown: false)
    bool cast[4];     // a ray was cast (the integrand was positive)
};

}  // namespace

Estimate monteCarloReference(const Receiver& r, const RectLight& light, Occluder::Query& query,
                             const McSettings& settings) {
    const int total = std::max(1, settings.samples);
    if (!lightReaches(light, r)) return finish(0.0, r, 0, 0);
    const Setup s(r, light, settings);
    Stream rng(settings.seed);
    // A kx x ky jittered grid with kx ky <= N as square as possible; the remaining samples are
    // uniform on the whole light. Each sample is uniform on its stratum and the strata have
    // equal areas, so the plain mean is unbiased.
    const int kx = std::max(1, int(std::floor(std::sqrt(double(total)))));
    const int ky = total / kx;
    double sum = 0.0;
    uint64_t rays = 0;
    auto add = [&](double u, double v) {
        const Vec3 p = light.point(u, v);
        const double f = areaIntegrand(s, p);
        if (f <= 0.0) return;
        ++rays;
        sum += f * transmitted(s, p, query);
    };
    for (int j = 0; j < ky; ++j) {
        for (int i = 0; i < kx; ++i) {
            const double u = (i + rng.next()) / kx;
            const double v = (j + rng.next()) / ky;
            add(u, v);
        }
    }
    for (int i = kx * ky; i < total; ++i) {
        const double u = rng.next();
        add(u, rng.next());
    }
    return finish(sum / total, r, rays, 0);
}

Estimate monteCarloAdaptive(const Receiver& r, const RectLight& light, Occluder::Query& query,
                            const McSettings& settings) {
    if (!lightReaches(light, r)) return finish(0.0, r, 0, 0);
    const double f0 = unoccludedFormFactor(light, r);
    if (!(f0 > 0.0)) return finish(0.0, r, 0, 0);
    const Setup s(r, light, settings);
    Stream rng(settings.seed);
    const uint64_t cap = uint64_t(std::max(4, settings.samples));
    uint64_t rays = 0, firstRays = 0;

    // Draws the sample of quadrant q of `cell` and traces its ray.
    auto draw = [&](Cell& cell, int q) {
        const double h = 0.5 * cell.size;
        const double u = cell.u0 + h * ((q & 1) + rng.next());
        const double v = cell.v0 + h * ((q >> 1) + rng.next());
        cell.at[q] = Vec2(u, v);
        const Vec3 p = light.point(u, v);
        const double f = areaIntegrand(s, p);
        cell.cast[q] = f > 0.0;
        cell.hidden[q] = false;
        cell.value[q] = 0.0;
        if (!cell.cast[q]) return;
        ++rays;
        const double t = transmitted(s, p, query);
        cell.value[q] = f * t;
        cell.hidden[q] = t == 0.0;
    };

    // The initial cells: a 2^d x 2^d grid (d = initialDepth), four samples each.
    std::vector<Cell> work;
    const int side = 1 << std::clamp(settings.initialDepth, 0, 10);
    for (int j = 0; j < side; ++j) {
        for (int i = 0; i < side; ++i) {
            Cell root{double(i) / side, double(j) / side, 1.0 / side, 0, {}, {}, {}, {}};
            for (int q = 0; q < 4; ++q) draw(root, q);
            work.push_back(root);
        }
    }
    firstRays = rays;
    double sum = 0.0;
    // Breadth first, so that a capped budget is spent level by level rather than on one corner.
    for (size_t next = 0; next < work.size(); ++next) {
        const Cell cell = work[next];
        const double mean = 0.25 * (cell.value[0] + cell.value[1] + cell.value[2] + cell.value[3]);
        bool anyHidden = false, anyLit = false;
        double var = 0.0;
        for (int q = 0; q < 4; ++q) {
            anyHidden |= cell.hidden[q];
            anyLit |= cell.cast[q] && !cell.hidden[q];
            var += (cell.value[q] - mean) * (cell.value[q] - mean);
        }
        var /= 3.0;  // sample variance of the four values
        // The cell's contribution is size^2 x mean; with four samples its standard error is
        // size^2 x sd / 2. Only cells whose shadow rays disagree are split: in a fully visible
        // or fully hidden cell the variance is the smooth cosine falloff, which more rays would
        // not reveal anything about.
        const double area = cell.size * cell.size;
        const double stdError = area * std::sqrt(var) / 2.0;
        const bool split = anyHidden && anyLit && cell.depth < settings.maxDepth &&
                           stdError > settings.threshold * f0 && rays + 12 <= cap;
        if (!split) {
            sum += area * mean;
            continue;
        }
        const double h = 0.5 * cell.size;
        for (int q = 0; q < 4; ++q) {
            Cell child{
                cell.u0 + h * (q & 1), cell.v0 + h * (q >> 1), h, cell.depth + 1, {}, {}, {}, {}};
            // The parent's sample of this quadrant lies in one of the child's quadrants and is
            // kept; the three others are drawn.
            const Vec2 a = cell.at[q];
            const int keep =
                (a.x >= child.u0 + 0.5 * h ? 1 : 0) | (a.y >= child.v0 + 0.5 * h ? 2 : 0);
            for (int c = 0; c < 4; ++c) {
                if (c == keep) {
                    child.at[c] = a;
                    child.value[c] = cell.value[q];
                    child.hidden[c] = cell.hidden[q];
                    child.cast[c] = cell.cast[q];
                } else {
                    draw(child, c);
                }
            }
            work.push_back(child);
        }
    }
    return finish(sum, r, firstRays, rays - firstRays);
}

namespace {

// The cosine-weighted sums over N solid-angle samples shared by mc-solid-angle and mc-ratio.
struct SolidAngleSums {
    double solidAngle = 0.0;
    double visible = 0.0;  // sum of cos_i V_i
    double all = 0.0;      // sum of cos_i
    uint64_t rays = 0;
    int samples = 0;
};

SolidAngleSums solidAngleSums(const Receiver& r, const RectLight& light, Occluder::Query& query,
                              const McSettings& settings) {
    SolidAngleSums out;
    out.samples = std::max(1, settings.samples);
    if (!lightReaches(light, r)) return out;
    const Setup s(r, light, settings);
    const SphericalRectangle rect(light, r.point);
    out.solidAngle = rect.solidAngle();
    if (!(out.solidAngle > 0.0)) return out;
    for (int i = 0; i < out.samples; ++i) {
        const Vec2 uv = sobolOwen2(uint32_t(i), settings.seed);
        const Vec3 p = rect.sample(uv.x, uv.y);
        const Vec3 dir = p - s.m;
        const double len = glm::length(dir);
        // Below the horizon the clamped cosine is 0: no ray is needed.
        const double c = len > 0.0 ? glm::dot(dir, s.n) / len : 0.0;
        if (!(c > 0.0)) continue;
        out.all += c;
        ++out.rays;
        out.visible += c * transmitted(s, p, query);
    }
    return out;
}

}  // namespace

Estimate monteCarloSolidAngle(const Receiver& r, const RectLight& light, Occluder::Query& query,
                              const McSettings& settings) {
    const SolidAngleSums t = solidAngleSums(r, light, query, settings);
    // Uniform in solid angle, pdf 1 / S: F = (1 / pi) E[cos V] S.
    return finish(t.solidAngle * t.visible / (kPi * t.samples), r, t.rays, 0);
}

Estimate monteCarloRatio(const Receiver& r, const RectLight& light, Occluder::Query& query,
                         const McSettings& settings) {
    const SolidAngleSums t = solidAngleSums(r, light, query, settings);
    if (!(t.all > 0.0)) return finish(0.0, r, t.rays, 0);
    return finish(unoccludedFormFactor(light, r) * t.visible / t.all, r, t.rays, 0);
}

}  // namespace penumbra
