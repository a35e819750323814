// The light of the paper-like estimator test scene, shared by the estimator's test files: 2 x 2
// at height 4, emitting downwards (edgeU x edgeV = -z).
#pragma once

#include "penumbra/form_factor.h"

namespace penumbra::test {

inline RectLight paperLight() {
    RectLight l;
    l.corner = Vec3(-1, -1, 4);
    l.edgeU = Vec3(0, 2, 0);
    l.edgeV = Vec3(2, 0, 0);
    return l;
}

}  // namespace penumbra::test
