/// @file scene.h
/// The scene model and its JSON loader (src/scene_json.cpp). The file format is documented in
/// docs/scene-format.md.
///
/// Units: world space, scene units. Paths inside a scene file are relative to that file.
/// Errors: loadScene/parseScene throw InputError naming the file and the JSON pointer of the
/// offending value (e.g. `scene.json: /obstacles/2/radius: must be > 0, got -1`).
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "penumbra/form_factor.h"
#include "penumbra/math.h"
#include "penumbra/occluder.h"

namespace penumbra {

/// Pinhole camera; one viewing ray per pixel through the pixel centre.
struct Camera {
    Vec3 eye{0.0, -6.0, 3.0};
    Vec3 lookAt{0.0};
    Vec3 up{0.0, 0.0, 1.0};
    double fovDeg = 40.0;  ///< vertical field of view
    int width = 800;
    int height = 800;
};

/// An infinite analytic plane that receives light (and does not cast shadows).
struct PlaneReceiver {
    Vec3 point{0.0};
    Vec3 normal{0.0, 0.0, 1.0};
    Rgb albedo{0.8};
    bool checker = false;  ///< alternate albedo / albedo2 in squares of side checkerScale
    Rgb albedo2{0.4};
    double checkerScale = 1.0;
};

/// A shadow-casting obstacle. Level sets are also receivers, shaded with their own normals.
struct Obstacle {
    std::string name;
    ObstacleShape shape;
    Rgb albedo{0.8};
};

/// Global level-set settings: the voxel size of implicit primitives and the narrow band.
struct LevelSetSettings {
    double voxelSize = 0.02;
    double halfWidth = 3.0;  ///< voxels
};

struct Scene {
    std::string file;     ///< the file it came from, for messages ("" when parsed from text)
    std::optional<Camera> camera;
    std::vector<RectLight> lights;
    std::vector<Obstacle> obstacles;
    std::vector<PlaneReceiver> receivers;
    LevelSetSettings levelSet;
    Rgb background{0.0};

    /// Index of the light named `name`; with an empty name, the only light. Throws InputError
    /// when there is no such light or the choice is ambiguous.
    size_t lightIndex(const std::string& name) const;
    /// An Occluder over every obstacle, in scene order.
    Occluder makeOccluder() const;
};

/// Loads and validates a scene file; builds the level sets of implicit obstacles.
Scene loadScene(const std::string& path);

/// Same from text; `file` is used in messages and `baseDir` resolves relative paths.
Scene parseScene(const std::string& jsonText, const std::string& file, const std::string& baseDir);

}  // namespace penumbra
