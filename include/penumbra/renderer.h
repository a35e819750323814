/// @file renderer.h
/// Renders a Scene seen through its Camera: one viewing ray per pixel, Lambertian receivers
/// (analytic planes and the obstacles themselves, shaded with their own normals), every
/// rectangular light. A pixel's value is albedo x sum over lights of radiance x F, with F the
/// form factor from the hit point to the light (Vedel 1993, eq. 4), shadowed by the obstacles.
///
/// Methods (keep `Method` open: more estimators plug in behind the same front end):
/// - `Method::Aci` is the pipeline of Vedel 1993, section 5: the viewing rays of a scanline are
///   cut into spans of adjacent pixels on one object; each span is shaft-culled against each
///   light (Haines and Wallace 1991); a span without candidate obstacle is shaded by the closed
///   form; otherwise ACI runs on a first pixel, only its first-level shadow rays (its "pattern")
///   are traced on the following pixels until the pattern changes, ACI runs at the changed pixel
///   and at the middle of the run, and the pixels in between are interpolated quadratically
///   (the G vector, projected on each pixel's own normal). The first-level grid adapts along a
///   span: finer after a refinement of depth >= 2 or a restart, coarser again when none was
///   needed.
/// - `Method::AciPixel` runs the full ACI at every pixel against every obstacle: no culling, no
///   coherence, no interpolation. It is the reference the pipeline is measured against.
/// - The Monte Carlo methods of monte_carlo.h (`Reference`, `McAdaptive`, `McSolidAngle`,
///   `McRatio`) sit behind the same front end as `Aci`: the same spans, the same shaft culling
///   and closed form for unshadowed pixels, so they spend shadow rays on the same pixels; each
///   pixel that needs rays gets one estimate (no coherence, no interpolation). Their random
///   streams are seeded per pixel and light (`mcSeed(x, y, light index, mc.seed)`).
///
/// Units: world space, scene units; images are linear radiance.
/// Thread safety: render() uses TBB internally (one task arena of `threads` workers, rows in
/// parallel, a per-thread occluder query and estimator); calls on different scenes may run
/// concurrently. The result does not depend on the number of threads, bit for bit.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "penumbra/contour_integrator.h"
#include "penumbra/image_io.h"
#include "penumbra/math.h"
#include "penumbra/monte_carlo.h"
#include "penumbra/render_settings.h"
#include "penumbra/scene.h"
#include "penumbra/stats.h"

namespace penumbra {



/// Extra images (AOVs), one channel each, same size as the picture.
struct RenderAovs {
    Image shadowRays;  ///< shadow rays cast at the pixel, over all lights
    Image formFactor;  ///< sum over lights of F (interpolated where the colour was)
    Image gradient;    ///< |sum over lights of dF/dM|; zero unless settings.aci.gradient
    Image mask;        ///< 1 where shadow rays were cast at the pixel, else 0
    /// Sum over lights of the estimator's bound on |F - F_exact| (Estimate::errorBound): the
    /// default tangent mode's; NaN for methods that give none. Interpolated pixels take the
    /// largest bound of the evaluations they are interpolated from.
    Image errorBound;
};

struct RenderResult {
    Image color;  ///< 3 channels, linear
    RenderAovs aovs;
    RenderStats stats;
};

/// Called after each finished row with the number of rows done so far and the total. It is
/// called from worker threads, never concurrently (the renderer serializes the calls), and must
/// be quick.
using RenderProgress = std::function<void(int rowsDone, int rowsTotal)>;

/// Bytes a width x height render holds at once: the colour image, its four AOVs and the per-row
/// buffers (a slight overestimate).
double renderImageBytes(int width, int height);

/// Refuses (InputError naming `file` and `where`, with the estimate in GiB) an image whose
/// buffers would take more than three quarters of this machine's memory, before any is
/// allocated.
void checkRenderMemory(int width, int height, const std::string& file, const std::string& where);

/// Renders `scene` (which must have a camera: InputError naming "/camera" otherwise). Throws
/// InputError for settings out of range (`where` names the command-line flag, e.g. "--width").
RenderResult render(const Scene& scene, const RenderSettings& settings,
                    const RenderProgress& progress = {});

/// The shadow rays automatically chosen start offset (see RenderSettings::aci): the largest
/// that receiverRayOffset may pick (1.5 voxels of the finest level set), or rayOffsetFloor
/// without level sets.
double automaticRayOffset(const Scene& scene, const Occluder& occluder);

/// 1e-6 x the scene's size: enough for a ray to leave an exact surface (receiver planes,
/// analytic obstacles) it starts on.
double rayOffsetFloor(const Scene& scene, const Occluder& occluder);

/// The automatic start offset of shadow rays from a receiver point p (along its normal). A
/// level set's surface is known only to about a voxel, so a point on one starts its rays 1.5 of
/// its voxels off; a point farther from every level set needs only `floor`. In between, the
/// offset is what brings the origin 1.5 voxels from the surface, so it is continuous in p:
/// max(floor, max over level sets i of clamp(1.5 v_i - phi_i(p), 0, 1.5 v_i)). Moving the origin
/// moves the shadow: 1.5 voxels at every receiver made a level-set sphere's shadow on a plane
/// that of a sphere about 0.19 voxel smaller.
double receiverRayOffset(const Occluder& occluder, const Vec3& p, double floor);

/// A shaft between two boxes after Haines and Wallace (1991): their common bounding box cut by
/// the planes through matching edges of the two boxes, a convex volume that contains the convex
/// hull of the two boxes (so every segment from a point of one box to a point of the other).
/// overlaps() is conservative: it never says false for a box that meets that convex hull.
class Shaft {
public:
    Shaft(const Box3& a, const Box3& b);
    bool overlaps(const Box3& box) const;
    size_t planeCount() const { return mPlanes.size(); }

private:
    struct Plane {  // n . p <= d inside; n has two non-zero components (axes i, j)
        int i, j;
        double ni, nj, d;
    };
    Box3 mBox;
    std::vector<Plane> mPlanes;
};

}  // namespace penumbra
