// One Sutherland-Hodgman step, shared by the estimators' footprints (estimator.cpp) and the
// light footprints' slivers (light_footprint.cpp).
#pragma once

#include <vector>

namespace penumbra {

/// Keeps the part of the convex polygon `poly` (points of any vector type) where the linear
/// function value(p) >= 0. A vertex where value is exactly 0 is kept once, not doubled.
template <class P, class Value>
void keepNonNegative(std::vector<P>& poly, const Value& value) {
    std::vector<P> out;
    for (size_t i = 0; i < poly.size(); ++i) {
        const P& a = poly[i];
        const P& b = poly[(i + 1) % poly.size()];
        const double fa = value(a), fb = value(b);
        if (fa >= 0.0) out.push_back(a);
        if ((fa > 0.0 && fb < 0.0) || (fa < 0.0 && fb > 0.0)) out.push_back(a + (fa / (fa - fb)) * (b - a));
    }
    poly.swap(out);
}

}  // namespace penumbra
