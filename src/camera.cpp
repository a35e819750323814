#include "penumbra/camera.h"

#include <cmath>
#include <string>

#include "penumbra/error.h"

namespace penumbra {

namespace {

bool finite(const Vec3& v) {
    return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}

}  // namespace

PinholeCamera::PinholeCamera(const Camera& camera, const std::string& file)
    : mEye(camera.eye), mWidth(camera.width), mHeight(camera.height) {
    if (!finite(camera.eye)) throw InputError(file, "/camera/eye", "must be finite");
    if (!finite(camera.lookAt)) throw InputError(file, "/camera/look_at", "must be finite");
    if (!finite(camera.up)) throw InputError(file, "/camera/up", "must be finite");
    if (!(camera.fovDeg > 0.0 && camera.fovDeg < 180.0)) {
        throw InputError(file, "/camera/fov_deg",
                         "must be in (0, 180) degrees, got " + std::to_string(camera.fovDeg));
    }
    if (camera.width < 1) {
        throw InputError(file, "/camera/width", "must be >= 1, got " + std::to_string(camera.width));
    }
    if (camera.height < 1) {
        throw InputError(file, "/camera/height",
                         "must be >= 1, got " + std::to_string(camera.height));
    }
    Vec3 view = camera.lookAt - camera.eye;
    double viewLength = glm::length(view);
    if (!(viewLength > 0.0)) throw InputError(file, "/camera/look_at", "must differ from eye");
    mForward = view / viewLength;
    Vec3 side = glm::cross(mForward, camera.up);
    double sideLength = glm::length(side);
    // Relative test: `up` may have any length, but must not be (nearly) parallel to the view.
    if (!(sideLength > 1e-9 * glm::length(camera.up))) {
        throw InputError(file, "/camera/up", "must not be parallel to look_at - eye");
    }
    mRight = side / sideLength;
    mUp = glm::cross(mRight, mForward);
    mHalfHeight = std::tan(0.5 * camera.fovDeg * kPi / 180.0);
    mHalfWidth = mHalfHeight * double(mWidth) / double(mHeight);
}

ViewRay PinholeCamera::ray(double x, double y) const {
    // Image-plane coordinates in [-1, 1], y flipped so that row 0 is the top of the picture.
    double sx = 2.0 * x / mWidth - 1.0;
    double sy = 1.0 - 2.0 * y / mHeight;
    Vec3 d = mForward + (sx * mHalfWidth) * mRight + (sy * mHalfHeight) * mUp;
    return ViewRay{mEye, glm::normalize(d)};
}

}  // namespace penumbra
