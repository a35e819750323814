// Tests of camera.h: pixel centres, the vertical field of view, orientation of rows and columns,
// and the refusal of degenerate cameras.
#include <catch2/catch.hpp>
#include <cmath>

#include "penumbra/camera.h"
#include "penumbra/error.h"

using namespace penumbra;

namespace {

double angleDeg(const Vec3& a, const Vec3& b) {
    double c = glm::dot(glm::normalize(a), glm::normalize(b));
    return std::acos(std::max(-1.0, std::min(1.0, c))) * 180.0 / kPi;
}

Camera makeCamera(int w, int h, double fov) {
    Camera c;
    c.eye = Vec3(1.0, -5.0, 2.0);
    c.lookAt = Vec3(1.0, 0.0, 2.0);
    c.up = Vec3(0.0, 0.0, 3.0);  // any length
    c.fovDeg = fov;
    c.width = w;
    c.height = h;
    return c;
}

}  // namespace

TEST_CASE("the centre pixel looks at look_at; image edges are at the field of view", "[camera]") {
    PinholeCamera cam(makeCamera(5, 3, 60.0));
    ViewRay centre = cam.pixelRay(2, 1);
    CHECK(centre.origin == Vec3(1.0, -5.0, 2.0));
    CHECK(glm::length(centre.direction) == Approx(1.0).margin(1e-14));
    CHECK(angleDeg(centre.direction, Vec3(0, 1, 0)) == Approx(0.0).margin(1e-6));
    // The top edge of the image (y = 0, not a pixel centre) is fov/2 above the axis.
    ViewRay top = cam.ray(2.5, 0.0);
    CHECK(angleDeg(top.direction, Vec3(0, 1, 0)) == Approx(30.0).margin(1e-9));
    CHECK(top.direction.z > 0.0);  // row 0 is the top of the picture
    // The right edge is at atan(aspect x tan(fov/2)) to the right (+x seen from -y).
    ViewRay right = cam.ray(5.0, 1.5);
    double expected = std::atan(5.0 / 3.0 * std::tan(30.0 * kPi / 180.0)) * 180.0 / kPi;
    CHECK(angleDeg(right.direction, Vec3(0, 1, 0)) == Approx(expected).margin(1e-9));
    CHECK(right.direction.x > 0.0);
    CHECK(std::abs(right.direction.z) < 1e-12);
    // Pixel centres are half a pixel in from the corner.
    ViewRay corner = cam.pixelRay(0, 0);
    ViewRay cornerByHand = cam.ray(0.5, 0.5);
    CHECK(corner.direction == cornerByHand.direction);
}

TEST_CASE("adjacent pixel centres are evenly spaced on the image plane", "[camera]") {
    PinholeCamera cam(makeCamera(8, 8, 40.0));
    // Intersect with the plane y = 0 (distance 5 along the axis): equal steps in x.
    auto hitX = [&](int x) {
        ViewRay r = cam.pixelRay(x, 3);
        return r.at(5.0 / r.direction.y).x;
    };
    double step = hitX(1) - hitX(0);
    double expectedStep = 2.0 * 5.0 * std::tan(20.0 * kPi / 180.0) / 8.0;
    CHECK(step == Approx(expectedStep).epsilon(1e-12));
    for (int x = 1; x < 7; ++x) CHECK(hitX(x + 1) - hitX(x) == Approx(step).epsilon(1e-12));
}

TEST_CASE("degenerate cameras are refused with the field named", "[camera]") {
    auto where = [](const Camera& c) {
        try {
            PinholeCamera cam(c, "s.json");
        } catch (const InputError& e) {
            CHECK(e.file() == "s.json");
            return e.where();
        }
        return std::string("no error");
    };
    Camera c = makeCamera(4, 4, 40.0);
    c.up = Vec3(0.0, 2.0, 0.0);  // parallel to the view
    CHECK(where(c) == "/camera/up");
    c = makeCamera(4, 4, 40.0);
    c.lookAt = c.eye;
    CHECK(where(c) == "/camera/look_at");
    CHECK(where(makeCamera(4, 4, 0.0)) == "/camera/fov_deg");
    CHECK(where(makeCamera(4, 4, 180.0)) == "/camera/fov_deg");
    CHECK(where(makeCamera(0, 4, 40.0)) == "/camera/width");
    CHECK(where(makeCamera(4, -1, 40.0)) == "/camera/height");
    c = makeCamera(4, 4, 40.0);
    c.eye.x = std::nan("");
    CHECK(where(c) == "/camera/eye");
}
