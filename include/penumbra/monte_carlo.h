/// @file monte_carlo.h
/// Monte Carlo estimators of the same quantity as contour_integrator.h: the form factor from a
/// receiver point M (unit normal n) to a rectangular light, hidden by obstacles. They are the
/// baselines approximate contour integration is measured against (Vedel 1993, section 5 and
/// Table 1), with the same signature as contourIntegral():
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
/// - monteCarloSolidAngle: uniform sampling of the solid angle the light subtends, by the
///   area-preserving parametrization of the spherical rectangle (Urena, Fajardo and King 2013),
///   driven by Owen-scrambled Sobol points; F = S / (pi N) sum cos(theta_i) V_i.
/// - monteCarloRatio: the unoccluded closed form times the cosine-weighted visible fraction of
///   the same samples, F = F_0 (sum cos_i V_i) / (sum cos_i) (the ratio estimator of Heitz, Hill
///   and McGuire 2018 for a diffuse receiver). Consistent, not unbiased; exact without occluder.
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

}  // namespace penumbra
