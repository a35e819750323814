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
// Uniform points of the emitting surface (area sampling)

LightSurface::LightSurface(const RectLight& light) : mLight(&light) {
    if (light.shape == LightShape::Disc) {
        mE1 = glm::normalize(light.edgeU);
        mE2 = glm::cross(light.normal(), mE1);
    } else if (light.shape == LightShape::Polygon) {
        const std::vector<Vec3>& v = light.vertices;
        double sum = 0.0;
        for (size_t k = 1; k + 1 < v.size(); ++k) {
            sum += 0.5 * glm::length(glm::cross(v[k] - v[0], v[k + 1] - v[0]));
            mCumArea.push_back(sum);
        }
    }
}

Vec3 LightSurface::point(double u, double v) const {
    const RectLight& l = *mLight;
    switch (l.shape) {
        case LightShape::Rect:
            break;
        case LightShape::Disc: {
            // Shirley and Chiu (1997): the square [-1, 1]^2 to the unit disc, each concentric
            // square's border to a circle of the same index, with area ratio pi / 4 everywhere.
            const double a = 2.0 * u - 1.0, b = 2.0 * v - 1.0;
            if (a == 0.0 && b == 0.0) return l.center;
            double rad, phi;
            if (std::abs(a) > std::abs(b)) {
                rad = a;
                phi = 0.25 * kPi * (b / a);
            } else {
                rad = b;
                phi = 0.5 * kPi - 0.25 * kPi * (a / b);
            }
            rad *= l.radius;
            return l.center + rad * std::cos(phi) * mE1 + rad * std::sin(phi) * mE2;
        }
        case LightShape::Polygon: {
            // The fan of triangles (v0, vk, vk+1): u picks one by cumulative area and then runs
            // along its far side vk -> vk+1, sqrt(v) from v0 to that side. The area element of
            // v0 + s ((1 - t) (vk - v0) + t (vk+1 - v0)) is 2 a_k s ds dt = a_k dt dv, and
            // dt = (A / a_k) du: constant A in (u, v). At t = 1 one triangle ends on the side
            // the next begins with, so the map is continuous.
            const std::vector<Vec3>& p = l.vertices;
            const double total = mCumArea.back();
            const double at = u * total;
            size_t k = size_t(std::upper_bound(mCumArea.begin(), mCumArea.end(), at) -
                              mCumArea.begin());
            k = std::min(k, mCumArea.size() - 1);
            const double before = k > 0 ? mCumArea[k - 1] : 0.0;
            const double t = std::clamp((at - before) / (mCumArea[k] - before), 0.0, 1.0);
            const double rad = std::sqrt(v);
            return p[0] + rad * ((1.0 - t) * (p[k + 1] - p[0]) + t * (p[k + 2] - p[0]));
        }
    }
    return l.point(u, v);
}

// ---------------------------------------------------------------------------------------------
// The spherical triangle (Arvo 1995, "Stratified sampling of spherical triangles"), derived
// again here.
//
// Triangle ABC on the unit sphere, angle alpha at A, sides c = |AB|, b = |AC| (arcs), area S.
// A point C' on the side AC at arc length b' from A cuts off the triangle ABC', whose angle at A
// is still alpha. Sampling in two steps: first C' so that the area of ABC' is u S, then a point
// on the arc B -> C' whose cosine of the distance to B is uniform between 1 and cos|BC'|. About
// B the area element is d(cos theta) dphi, so for a given azimuth phi (that is, C') the second
// step is uniform in area, and the first gives the azimuth its marginal (the area swept). Hence
// uniform (u, v) -> uniform in solid angle.
//
// The first step (Arvo's eq. for q = cos b'): in ABC' let beta', gamma' be the angles at B and
// C'; Girard gives beta' + gamma' = pi + A' - alpha, A' = u S. With phi = A' - alpha,
//   cos gamma' = -cos(beta' - phi)                        (gamma' = pi - (beta' - phi))
//   cos gamma' = -cos alpha cos beta' + sin alpha sin beta' cos c     (law of cosines, angles)
// so cos beta' (cos alpha - cos phi) = sin beta' (sin phi + sin alpha cos c), i.e. with Arvo's
//   U = cos phi - cos alpha,   V = sin phi + sin alpha cos c,
// sin beta' : cos beta' = U : -V (U >= 0, since A' <= S < 2 alpha). Arvo then takes
// q = cos b' = ((V cos phi - U sin phi) cos alpha - V) / ((V sin phi + U cos phi) sin alpha); we
// use the four-part formula on (b', alpha, c, beta') instead,
//   cos c cos alpha = sin c cot b' - sin alpha cot beta'
//   => tan b' = U sin c / (U cos c cos alpha - V sin alpha),
// which gives b' itself through atan2 (q near 1 loses b' to cancellation on small triangles),
// and write U and V without cancellation:
//   U = 2 sin(A'/2) sin(alpha - A'/2),   V = 2 sin(A'/2) cos(alpha - A'/2) - sin alpha (1 - cos c).

SphericalTriangle::SphericalTriangle(const Vec3& a, const Vec3& b, const Vec3& c) : mA(a), mB(b) {
    const Vec3 nab = glm::cross(a, b), nac = glm::cross(a, c);
    const double det = std::abs(glm::dot(a, glm::cross(b, c)));
    // Van Oosterom and Strackee (1983): tan(S / 2) = |a . (b x c)| / (1 + a.b + b.c + c.a).
    mSolidAngle = 2.0 * std::atan2(det, 1.0 + glm::dot(a, b) + glm::dot(b, c) + glm::dot(c, a));
    // alpha is the angle between the planes (a, b) and (a, c): (a x b) x (a x c) = det(a, b, c) a.
    mAlpha = std::atan2(det, glm::dot(nab, nac));
    mSinAlpha = std::sin(mAlpha);
    mCosAlpha = std::cos(mAlpha);
    mSinC = glm::length(nab);
    mCosC = glm::dot(a, b);
    const Vec3 ab = a - b;
    mOneMinusCosC = 0.5 * glm::dot(ab, ab);
    mSideB = std::atan2(glm::length(nac), glm::dot(a, c));
    const Vec3 w = glm::cross(nac, a);  // c - (c . a) a
    const double lw = glm::length(w);
    mW = lw > 0.0 ? w / lw : Vec3(0.0);
}

Vec3 SphericalTriangle::sample(double u, double v) const {
    // First step: C' on the side AC, at the arc length b' where area(ABC') = u S.
    const double half = 0.5 * u * mSolidAngle;
    const double s = 2.0 * std::sin(half);
    const double bigU = s * std::sin(mAlpha - half);
    const double bigV = s * std::cos(mAlpha - half) - mSinAlpha * mOneMinusCosC;
    double side = std::atan2(bigU * mSinC, bigU * mCosC * mCosAlpha - bigV * mSinAlpha);
    side = std::clamp(side, 0.0, mSideB);
    const Vec3 cp = std::cos(side) * mA + std::sin(side) * mW;
    // Second step: 1 - cos(theta) from B uniform in [0, 1 - cos|BC'|], where
    // 1 - cos|BC'| = |C' - B|^2 / 2 (without cancellation).
    const Vec3 d = cp - mB;
    const double oneMinusZ = v * 0.5 * glm::dot(d, d);
    const double sinTheta = std::sqrt(std::max(0.0, oneMinusZ * (2.0 - oneMinusZ)));
    const Vec3 t = d - glm::dot(d, mB) * mB;  // C' - (C' . B) B, the tangent at B towards C'
    const double lt = glm::length(t);
    if (!(lt > 0.0)) return mB;
    return (1.0 - oneMinusZ) * mB + sinTheta * (t / lt);
}

SphericalPolygon::SphericalPolygon(const RectLight& light, const Vec3& origin)
    : mOrigin(origin), mPlanePoint(light.vertices.at(0)), mNormal(light.normal()) {
    const std::vector<Vec3>& p = light.vertices;
    std::vector<Vec3> dir;
    dir.reserve(p.size());
    for (const Vec3& q : p) dir.push_back(glm::normalize(q - origin));
    // Triangle (vk, v0, vk+1) in Arvo's order (A, B, C): its u = 1 side, v0-vk+1, is the next
    // triangle's u = 0 side, so the fan is swept about v0 without a jump.
    for (size_t k = 1; k + 1 < p.size(); ++k) {
        mTriangles.emplace_back(dir[k], dir[0], dir[k + 1]);
        mSolidAngle += mTriangles.back().solidAngle();
        mCumSolidAngle.push_back(mSolidAngle);
    }
}

Vec3 SphericalPolygon::sample(double u, double v) const {
    const double at = u * mSolidAngle;
    size_t k = size_t(std::upper_bound(mCumSolidAngle.begin(), mCumSolidAngle.end(), at) -
                      mCumSolidAngle.begin());
    k = std::min(k, mCumSolidAngle.size() - 1);
    const double before = k > 0 ? mCumSolidAngle[k - 1] : 0.0;
    const double width = mCumSolidAngle[k] - before;
    const double uk = width > 0.0 ? std::clamp((at - before) / width, 0.0, 1.0) : 0.5;
    const Vec3 dir = mTriangles[k].sample(uk, v);
    // Where the ray from the origin meets the light's plane (both dot products are negative:
    // the origin is on the emitting side and the direction points at the light).
    return mOrigin + (glm::dot(mPlanePoint - mOrigin, mNormal) / glm::dot(dir, mNormal)) * dir;
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
    return formFactorDensity(Receiver{s.m, s.n}, s.lightNormal, p) * s.area;
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
// quadrant (quadrant q: bit 0 for the upper half in u, bit 1 in v). The square is mapped to the
// emitting surface by LightSurface, whose constant Jacobian makes a cell's share of the light
// its share of the square, size^2, for every shape.
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
    const LightSurface surface(light);
    Stream rng(settings.seed);
    // A kx x ky jittered grid with kx ky <= N as square as possible; the remaining samples are
    // uniform on the whole light. Each sample is uniform on its stratum and the strata have
    // equal areas (LightSurface's Jacobian is constant), so the plain mean is unbiased.
    const int kx = std::max(1, int(std::floor(std::sqrt(double(total)))));
    const int ky = total / kx;
    double sum = 0.0;
    uint64_t rays = 0;
    auto add = [&](double u, double v) {
        const Vec3 p = surface.point(u, v);
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
    const LightSurface surface(light);
    Stream rng(settings.seed);
    const uint64_t cap = uint64_t(std::max(4, settings.samples));
    uint64_t rays = 0, firstRays = 0;

    // Draws the sample of quadrant q of `cell` and traces its ray.
    auto draw = [&](Cell& cell, int q) {
        const double h = 0.5 * cell.size;
        const double u = cell.u0 + h * ((q & 1) + rng.next());
        const double v = cell.v0 + h * ((q >> 1) + rng.next());
        cell.at[q] = Vec2(u, v);
        const Vec3 p = surface.point(u, v);
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
// Each sample i has a weight w_i, the inverse of its solid-angle density divided by `scale`:
// for a rectangle or polygon (sampled uniformly in solid angle) w_i = 1 and scale = S; for a
// disc (sampled uniformly by area, density cos(theta_L) / (A r^2) per steradian) scale = 1 and
// w_i = A cos(theta_L) / r^2. Then F = scale / (pi N) sum w_i cos_i V_i.
struct SolidAngleSums {
    double scale = 0.0;
    double visible = 0.0;  // sum of w_i cos_i V_i
    double all = 0.0;      // sum of w_i cos_i
    uint64_t rays = 0;
    int samples = 0;
};

// `sample(uv, w)` gives the point of the light for a Sobol point and sets its weight w.
template <class Sample>
void accumulate(SolidAngleSums& out, const Setup& s, Occluder::Query& query, uint64_t seed,
                Sample&& sample) {
    for (int i = 0; i < out.samples; ++i) {
        const Vec2 uv = sobolOwen2(uint32_t(i), seed);
        double w = 1.0;  // w * c is then c itself, bit for bit
        const Vec3 p = sample(uv, w);
        const Vec3 dir = p - s.m;
        const double len = glm::length(dir);
        // Below the horizon the clamped cosine is 0: no ray is needed.
        const double c = len > 0.0 ? glm::dot(dir, s.n) / len : 0.0;
        if (!(c > 0.0) || !(w > 0.0)) continue;
        out.all += w * c;
        ++out.rays;
        out.visible += w * c * transmitted(s, p, query);
    }
}

SolidAngleSums solidAngleSums(const Receiver& r, const RectLight& light, Occluder::Query& query,
                              const McSettings& settings) {
    SolidAngleSums out;
    out.samples = std::max(1, settings.samples);
    if (!lightReaches(light, r)) return out;
    const Setup s(r, light, settings);
    // A rectangle's or polygon's exact solid-angle sampler: samples uniform in its solid angle.
    auto uniformInSolidAngle = [&](const auto& spherical) {
        out.scale = spherical.solidAngle();
        if (!(out.scale > 0.0)) return;
        accumulate(out, s, query, settings.seed,
                   [&](const Vec2& uv, double&) { return spherical.sample(uv.x, uv.y); });
    };
    switch (light.shape) {
        case LightShape::Rect:
            uniformInSolidAngle(SphericalRectangle(light, r.point));
            break;
        case LightShape::Polygon:
            uniformInSolidAngle(SphericalPolygon(light, r.point));
            break;
        case LightShape::Disc: {
            const LightSurface surface(light);
            out.scale = 1.0;
            accumulate(out, s, query, settings.seed, [&](const Vec2& uv, double& w) {
                const Vec3 p = surface.point(uv.x, uv.y);
                const Vec3 c = p - s.m;
                const double r2 = glm::dot(c, c);
                const double cosL = -glm::dot(c, s.lightNormal) / std::sqrt(r2);
                w = r2 > 0.0 ? s.area * cosL / r2 : 0.0;
                return p;
            });
            break;
        }
    }
    return out;
}

}  // namespace

Estimate monteCarloSolidAngle(const Receiver& r, const RectLight& light, Occluder::Query& query,
                              const McSettings& settings) {
    const SolidAngleSums t = solidAngleSums(r, light, query, settings);
    // Uniform in solid angle, pdf 1 / S: F = (1 / pi) E[cos V] S (for a disc, S / N sum w_i
    // estimates the solid angle's integral instead; see SolidAngleSums).
    return finish(t.scale * t.visible / (kPi * t.samples), r, t.rays, 0);
}

Estimate monteCarloRatio(const Receiver& r, const RectLight& light, Occluder::Query& query,
                         const McSettings& settings) {
    const SolidAngleSums t = solidAngleSums(r, light, query, settings);
    if (!(t.all > 0.0)) return finish(0.0, r, t.rays, 0);
    return finish(unoccludedFormFactor(light, r) * t.visible / t.all, r, t.rays, 0);
}

}  // namespace penumbra
