// The scene of the render tests (test_renderer.cpp, test_monte_carlo.cpp): a unit-square light
// over a white ground plane, seen from the side with the whole penumbra in view.
#pragma once

#include <utility>
#include <vector>

#include "penumbra/scene.h"

namespace penumbra::test {

/// A unit-square light 2 units above the plane z = 0, emitting downwards (edgeU x edgeV = -z),
/// radiance chosen so that lit plane pixels are about 0.8.
inline RectLight squareLight() {
    RectLight l;
    l.name = "key";
    l.corner = Vec3(-0.5, -0.5, 2.0);
    l.edgeU = Vec3(0.0, 1.0, 0.0);
    l.edgeV = Vec3(1.0, 0.0, 0.0);
    l.radiance = Rgb(10.0);
    return l;
}

/// `obstacles` over a white ground plane under squareLight(), seen from (0.3, -3, 3.2) towards
/// (0, 0, 0.3) with a 42 degree field of view, size x size pixels.
inline Scene squareLightScene(int size, std::vector<Obstacle> obstacles) {
    Camera cam;
    cam.eye = Vec3(0.3, -3.0, 3.2);
    cam.lookAt = Vec3(0.0, 0.0, 0.3);
    cam.up = Vec3(0.0, 0.0, 1.0);
    cam.fovDeg = 42.0;
    cam.width = size;
    cam.height = size;
    Scene s;
    s.camera = cam;
    s.lights = {squareLight()};
    s.obstacles = std::move(obstacles);
    PlaneReceiver ground;
    ground.albedo = Rgb(1.0);
    s.receivers = {ground};
    return s;
}

}  // namespace penumbra::test
