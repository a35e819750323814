/// @file camera.h
/// Viewing rays of the pinhole Camera described in scene.h: one ray per pixel, through the
/// pixel's centre. Pixel (0, 0) is the top-left corner of the image; x grows to the right and
/// y downwards, as in the images written by image_io.h.
///
/// Units: world space, scene units; `fovDeg` is the vertical field of view in degrees.
/// Thread safety: a PinholeCamera is immutable after construction and may be shared.
#pragma once

#include "penumbra/math.h"
#include "penumbra/scene.h"

namespace penumbra {

/// A ray o + t d, t >= 0, with unit direction d.
struct ViewRay {
    Vec3 origin{0.0};
    Vec3 direction{0.0, 0.0, -1.0};
    Vec3 at(double t) const { return origin + t * direction; }
};

class PinholeCamera {
public:
    /// Throws InputError (`where` names the camera field, e.g. "/camera/fov_deg") when the camera
    /// is degenerate: eye == look_at, up parallel to the viewing direction, a field of view
    /// outside (0, 180) degrees, or a non-positive image size. `file` is used in the message.
    explicit PinholeCamera(const Camera& camera, const std::string& file = "");

    int width() const { return mWidth; }
    int height() const { return mHeight; }

    /// The viewing ray through the centre of pixel (x, y). Non-integer coordinates address
    /// points inside a pixel (pixel (x, y) covers [x, x + 1) x [y, y + 1) in these units).
    ViewRay ray(double x, double y) const;
    ViewRay pixelRay(int x, int y) const { return ray(x + 0.5, y + 0.5); }

    /// Orthonormal camera frame: right, up (as seen in the image) and forward (viewing axis).
    const Vec3& right() const { return mRight; }
    const Vec3& up() const { return mUp; }
    const Vec3& forward() const { return mForward; }
    const Vec3& eye() const { return mEye; }

private:
    Vec3 mEye, mRight, mUp, mForward;
    double mHalfHeight = 1.0;  // tan(fov / 2): half the image plane's height at distance 1
    double mHalfWidth = 1.0;   // mHalfHeight * width / height (square pixels)
    int mWidth = 1, mHeight = 1;
};

}  // namespace penumbra
