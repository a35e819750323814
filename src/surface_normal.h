// Internal to the renderer: outward unit normals of obstacles at points on their surfaces.
// Kept out of include/penumbra/ so that OpenVDB stays behind src/level_set_impl.h.
// Thread safety: pure functions (each call makes its own OpenVDB accessor).
#pragma once

#include "penumbra/math.h"
#include "penumbra/occluder.h"

namespace penumbra {

/// Outward unit normal of `shape` at the world-space point `pointWS`, which should lie on (or
/// within a voxel of) its surface. Spheres and boxes: exact (a box takes the face nearest to the
/// point). Level sets: the normalized gradient of the signed distance by central differences of
/// trilinearly interpolated values, one voxel apart. Returns (0, 0, 1) only when the gradient
/// vanishes (a point far outside the narrow band).
Vec3 surfaceNormal(const ObstacleShape& shape, const Vec3& pointWS);

}  // namespace penumbra
