// Small scenes shared by the CLI and batch tests.
#pragma once

namespace test {

// A 24 x 24 view of an analytic sphere over a plane under one light: fast, and shadowed, so
// shadow rays are cast. (Comments are allowed in scene files.)
inline const char* kSphereScene = R"({
  // comments are allowed in scenes
  "camera": {"eye": [0, -6, 3], "look_at": [0, 0, 0.5], "width": 24, "height": 24},
  "lights": [{"name": "key", "corner": [-1, -1, 4], "edge_u": [0, 2, 0], "edge_v": [2, 0, 0],
              "radiance": [4, 4, 4]}],
  "obstacles": [{"type": "sphere", "center": [0, 0, 1.2], "radius": 0.5, "analytic": true}],
  "receivers": [{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]}]
})";

}  // namespace test
