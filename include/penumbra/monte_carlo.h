/// @file monte_carlo.h
/// Monte Carlo estimators of the same quantity as contour_integrator.h: the form factor from a
/// receiver point M (unit normal n) to an area light (a rectangle, a convex polygon or a disc),
/// hidden by obstacles. They are the baselines approximate contour integration is measured
/// against (Vedel 1993, section 5 and Table 1), with the same signature as contourIntegral():
///
/// - monteCarloReference: N stratified (jittered grid) area samples on the light, each weighted
///   by cos(theta_M) cos(theta_L) A / (pi r^2): the paper's "ray traced form factors", its
///   reference with N = 1024.
/// - monteCarloAdaptive: adaptive subdivision of the source after Kok and Jansen (1992), without
///   shadow-pattern coherence: a quadtree over the light (from a 2^d x 2^d grid of cells, d =
///   initialDepth) whose cells carry one jittered sample per quadrant; a cell whose shadow rays
///   disagree is split while the standard error of its contribution exceeds `threshold` x the
///   unoccluded form factor. Biased, like all adaptive sampling (Kirk and Arvo 1991): a cell
///   whose four rays agree is never split, whatever crosses it.
/// - monteCarloSolidAngle: uniform sampling of the solid angle the light subtends, driven by
///   Owen-scrambled Sobol points; F = S / (pi N) sum cos(theta_i) V_i. A rectangle is sampled
///   by the area-preserving parametrization of its spherical rectangle (Urena, Fajardo and King
///   2013), a polygon by Arvo's (1995) parametrization of spherical triangles over the fan of
///   triangles from its vertex 0 (SphericalPolygon). A disc has no exact solid-angle sampler: it
///   is sampled uniformly by area and each sample weighted by the inverse of its solid-angle
///   density, A cos(theta_L) / r^2, so that F = 1 / (pi N) sum A cos(theta_L,i) / r_i^2
///   cos(theta_i) V_i (the unbiased area estimator, with the Sobol points).
/// - monteCarloRatio: the unoccluded closed form times the cosine-weighted visible fraction of
///   the same samples, F = F_0 (sum w_i cos_i V_i) / (sum w_i cos_i) (the ratio estimator of
///   Heitz, Hill and McGuire 2018 for a diffuse receiver; w_i = 1 but for a disc's samples, as
///   above). Consistent, not unbiased; exact without occluder.
///
/// Where the light is sampled by area (mc-reference, mc-adaptive, a disc's solid angle), the
/// unit square of (u, v) is mapped to the emitting surface with a constant Jacobian (uniform
/// density; LightSurface): a rectangle by (u, v) itself, a disc by Shirley and Chiu's concentric
/// map, a polygon through the fan of triangles from its vertex 0 (u picks the triangle by
/// cumulative area and then runs along its far edge, sqrt(v) from the vertex to that edge). Both
/// maps are continuous, so the jittered strata and mc-adaptive's quadtree cells (which are
/// drawn in (u, v)) are compact pieces of the surface of equal area; the frame (corner, edgeU,
/// edgeV) of a polygon or disc light is not used.
///
/// Horizon: the part of the light below M's tangent plane contributes nothing. Samples there
/// get cos(theta) clamped to 0 and no ray is cast, so a light straddling the horizon costs
/// fewer rays than `samples` and the estimators converge to the clipped closed form
/// (unoccludedFormFactor). A receiver behind the light (or in its plane) gets F = 0, no ray.
///
/// Determinism: every random number comes from `McSettings::seed` through a counter-based hash,
/// so an estimate depends only on its inputs (the renderer derives the seed from the pixel and
/// the light: images do not depend on the thread count).
///
/// Counts: `counts.shadowRays()` is the number of rays cast. Fixed-count methods report them as
/// first-level rays; mc-adaptive reports its initial cells' rays as first-level and the rays of
/// split cells as second-level. Gradients are not estimated: `gradient` and `dg` are zero and
/// `g` is F n (so that g . n = F for code that projects G on the normal).
///
/// Units: world space, scene units. Thread safety: pure functions of their arguments, apart
/// from the caller's Occluder::Query (one per thread).
#pragma once

#include <cstdint>
#include <vector>

#include "penumbra/estimator.h"
#include "penumbra/form_factor.h"
#include "penumbra/math.h"
#include "penumbra/occluder.h"
#include "penumbra/render_settings.h"

namespace penumbra {

Estimate monteCarloReference(const Receiver& r, const RectLight& light, Occluder::Query& query,
                             const McSettings& settings);
Estimate monteCarloAdaptive(const Receiver& r, const RectLight& light, Occluder::Query& query,
                            const McSettings& settings);
Estimate monteCarloSolidAngle(const Receiver& r, const RectLight& light, Occluder::Query& query,
                              const McSettings& settings);
Estimate monteCarloRatio(const Receiver& r, const RectLight& light, Occluder::Query& query,
                         const McSettings& settings);

/// A seed from a few integers (pixel coordinates, light index, a user seed): a 64-bit hash,
/// so neighbouring pixels get unrelated streams.
uint64_t mcSeed(uint64_t a, uint64_t b, uint64_t c, uint64_t d = 0);

/// Point `index` of the first two dimensions of the Sobol sequence in [0, 1)^2, Owen-scrambled
/// (nested uniform scrambling in base 2) with `seed`. The first 2^m points of any scrambled
/// sequence form a (0, m, 2)-net: exactly one point in each of the 2^m elementary boxes.
Vec2 sobolOwen2(uint32_t index, uint64_t seed);

/// The spherical rectangle that a rectangular light subtends from a point, and its
/// area-preserving parametrization (Urena, Fajardo and King 2013): sample(u, v) maps the unit
/// square to points of the light so that uniform (u, v) gives directions uniform in solid angle.
/// The light must be a rectangle (edgeU perpendicular to edgeV, as every RectLight in a scene
/// is; a parallelogram is not a spherical rectangle).
class SphericalRectangle {
  public:
    SphericalRectangle(const RectLight& light, const Vec3& origin);

    /// Solid angle subtended, in steradians; 0 when the origin lies in the light's plane.
    double solidAngle() const { return mSolidAngle; }
    /// The point of the light for (u, v) in [0, 1]^2, world space. u sweeps the light along
    /// edgeU, v along edgeV; u = 0 and u = 1 are the light's sides edgeV and edgeV + edgeU.
    Vec3 sample(double u, double v) const;

  private:
    Vec3 mOrigin, mX, mY, mZ;  // local frame: x along edgeU, y along edgeV, z away from the light
    double mX0 = 0, mX1 = 0, mY0 = 0, mY1 = 0, mZ0 = 0;  // the light is [x0,x1] x [y0,y1] at z0
    double mB0 = 0, mB1 = 0, mK = 0;                     // constants of the inversion
    double mSolidAngle = 0;
};

/// The unit square mapped onto a light's emitting surface with a constant Jacobian, area():
/// uniform (u, v) gives points uniform on the surface (file comment). A rectangle's map is
/// light.point(u, v); a disc's is Shirley and Chiu's (1997) concentric map; a polygon's runs
/// through the fan of triangles from vertex 0. Continuous, so nearby (u, v) give nearby points.
/// Keeps a reference to `light`, which must outlive it.
class LightSurface {
  public:
    explicit LightSurface(const RectLight& light);
    /// The point of the emitting surface for (u, v) in [0, 1]^2, world space.
    Vec3 point(double u, double v) const;

  private:
    const RectLight* mLight;
    Vec3 mE1{0.0}, mE2{0.0};       // a disc: orthonormal axes of its plane, e1 x e2 = normal
    std::vector<double> mCumArea;  // a polygon: areas of the fan's triangles 1..k, summed
};

/// A spherical triangle (unit directions a, b, c, not collinear, either orientation) and
/// Arvo's (1995) area-preserving parametrization of it: uniform (u, v) in [0, 1]^2 gives
/// directions uniform in solid angle. u sweeps the arc from b about b: u = 0 is the side b-a,
/// u = 1 the side b-c; v runs from b (v = 0) to the side a-c (v = 1). So a fan of triangles
/// sharing b, each with its c the next one's a, is swept continuously.
class SphericalTriangle {
  public:
    SphericalTriangle(const Vec3& a, const Vec3& b, const Vec3& c);

    /// Solid angle, in steradians (Van Oosterom and Strackee 1983).
    double solidAngle() const { return mSolidAngle; }
    /// The unit direction for (u, v).
    Vec3 sample(double u, double v) const;

  private:
    Vec3 mA, mB, mW;  // the vertices a and b; mW: the unit tangent at a towards c
    double mSolidAngle = 0, mAlpha = 0, mSinAlpha = 0, mCosAlpha = 0;  // alpha: angle at a
    double mSinC = 0, mCosC = 0, mOneMinusCosC = 0;  // c: the side a-b
    double mSideB = 0;                               // the side a-c, in radians
};

/// A convex polygon light seen from a point in front of it, as the fan of spherical triangles
/// (vertex 0, vertex k, vertex k + 1): sample(u, v) picks a triangle by its solid angle with u,
/// then samples it by Arvo's parametrization (the rest of u along its far side, v towards it),
/// so uniform (u, v) gives points of the light uniform in the solid angle it subtends.
class SphericalPolygon {
  public:
    /// `light` must be a polygon (shape Polygon) and `origin` strictly on its emitting side.
    SphericalPolygon(const RectLight& light, const Vec3& origin);

    /// Solid angle subtended, in steradians.
    double solidAngle() const { return mSolidAngle; }
    /// The point of the light for (u, v) in [0, 1]^2, world space.
    Vec3 sample(double u, double v) const;

  private:
    Vec3 mOrigin, mPlanePoint, mNormal;
    std::vector<SphericalTriangle> mTriangles;
    std::vector<double> mCumSolidAngle;  // solid angles of triangles 0..k, summed
    double mSolidAngle = 0;
};

}  // namespace penumbra
