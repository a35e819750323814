// What emits: the part of the light's frame above the receiver's horizon, inside a polygon
// light's cutting edges and a disc light's circle. Vertices on that border are placed exactly
// and contour pieces along it are walked exactly (straight edges, circle arcs).
#include <algorithm>
#include <cmath>
#include <limits>

#include "contour_lattice.h"

namespace penumbra {

// A lattice point on a polygon's cutting edge or a disc's circle (a triangle's diagonal, the
// points where a disc touches its frame) lies there only up to rounding: within 1e-9 of a
// lattice unit it counts as emitting, whichever side rounding put it on. (Until 2026-12-05 it
// did not: a disc tilted off the axes had the points where its frame touches it outside by
// rounding, the pieces between them were taken for silhouettes, and an unshadowed receiver
// under it came out up to 24% dark in the paper's mode, 2% in the default's with an obstacle
// near the light: bench_bounds --lights mixed, seed 2821.)
bool ContourIntegrator::Lattice::emits(const Vec3& p) const {
    if (above(p) <= 0.0) return false;
    const double tol = 1e-9 * unit;
    for (size_t i = 0; i < cuts.size(); ++i)
        if (cutValue(i, p) < -tol) return false;
    return light.shape != LightShape::Disc || glm::length(p - light.center) <= light.radius + tol;
}

// The unit normal, in the light's plane, pointing into what emits, of border `clip` at p.
Vec3 ContourIntegrator::Lattice::inwardAt(int clip, const Vec3& p) const {
    if (clip == kClipHorizon) {
        const Vec3 m = rec.normal - glm::dot(rec.normal, lightNormal) * lightNormal;
        return glm::length(m) > 0.0 ? glm::normalize(m) : Vec3(0.0);
    }
    if (clip == kClipDisc) return glm::normalize(light.center - p);
    if (clip >= kClipFrame) return frameSides[static_cast<size_t>(clip - kClipFrame)].inward;
    return cuts[static_cast<size_t>(clip)].inward;
}

// Where the segment pv -> ph (pv emitting, ph not) leaves what emits, as a fraction of it,
// and through which border (`clip`).
double ContourIntegrator::Lattice::borderCrossing(const Vec3& pv, const Vec3& ph, int& clip) const {
    double best = 1.0;
    clip = kClipHorizon;
    const double tol = 1e-9 * unit;
    auto consider = [&](double fv, double fh, int which) {
        // pv emits, so fv >= -tol (a cut's value; the horizon's is positive).
        fv = std::max(fv, 0.0);
        if (!(fh < 0.0)) return;
        const double t = fv / (fv - fh);
        if (t < best) best = t, clip = which;
    };
    consider(above(pv), above(ph), kClipHorizon);
    for (size_t i = 0; i < cuts.size(); ++i) consider(cutValue(i, pv), cutValue(i, ph), static_cast<int>(i));
    if (light.shape == LightShape::Disc) {
        // |pv + t d - c|^2 = r^2, the larger root (pv is inside).
        const Vec3 d = ph - pv, e = pv - light.center;
        const double a = glm::dot(d, d), b = glm::dot(e, d), c = glm::dot(e, e) - light.radius * light.radius;
        const double disc = b * b - a * c;
        if (a > 0.0 && glm::length(ph - light.center) > light.radius + tol) {
            // pv may lie outside by up to tol (emits()): then the crossing is at pv itself.
            const double t = c > 0.0 || disc < 0.0 ? 0.0 : std::max(0.0, (-b + std::sqrt(disc)) / a);
            if (t < best) best = t, clip = kClipDisc;
        }
    }
    return std::clamp(best, 0.0, 1.0);
}

// The border of what emits from a to b (both on it), counterclockwise about the light's
// normal: straight along the horizon and polygon edges, exact arcs along a disc's circle,
// turning at their meeting points; for a polygon on its own frame, along the frame's sides too
// where its edges lie on them (without them, a walk from a cut went on past the polygon's
// corner, out of the frame, to where the next cut's line met it: 1.5% of an unshadowed
// hexagon counted twice in the paper's mode). False (nothing emitted) when the walk would
// need another frame's border or more turns than a square can hold.
bool ContourIntegrator::Lattice::emitBorder(const Vertex& a, const Vertex& b, bool dryRun,
                                            double& length) {
    Vec3 x = a.c;
    int on = a.clip;
    length = 0.0;
    const double tiny = 1e-9 * unit;
    // The horizon's value as a signed distance in the light's plane, like a cut's: above()
    // measures along the receiver's normal, |tilt| times that distance (the walk below took
    // above() as the distance until 2026-12-05: a disc wholly above a tilted receiver's
    // horizon seemed to meet it, and the lit disc came out 0.19% short with a bound of 0;
    // bench_bounds --lights mixed --fog, seed 3510).
    const double tilt = glm::length(rec.normal - glm::dot(rec.normal, lightNormal) * lightNormal);
    auto horizon = [&](const Vec3& p) { return tilt > 0.0 ? above(p) / tilt : above(p); };
    for (int turn = 0; turn < 6; ++turn) {
        if (on == kClipDisc) {
            // Along the circle: to b, or to the first line it crosses going out.
            const Vec3 e1 = glm::normalize(light.edgeU), e2 = glm::normalize(light.edgeV);
            auto angle = [&](const Vec3& p) {
                const Vec3 d = p - light.center;
                return std::atan2(glm::dot(d, e2), glm::dot(d, e1));
            };
            auto ahead = [&](double phi) {
                double d = phi - angle(x);
                while (d <= 1e-12) d += 2.0 * kPi;
                return d;
            };
            double best = b.clip == kClipDisc ? ahead(angle(b.c)) : std::numeric_limits<double>::infinity();
            int next = kClipDisc;
            auto line = [&](double f0, const Vec3& m, int which) {
                // f(phi) = f0 + r (cos phi m.e1 + sin phi m.e2); leaving where it falls through 0.
                const double a1 = light.radius * glm::dot(m, e1), a2 = light.radius * glm::dot(m, e2);
                const double amp = std::hypot(a1, a2);
                if (!(amp > std::abs(f0))) return;
                const double mid = std::atan2(a2, a1), half = std::acos(-f0 / amp);
                const double d = ahead(mid + half);  // f decreasing through 0 there
                if (d < best) best = d, next = which;
            };
            line(horizon(light.center), inwardAt(kClipHorizon, x), kClipHorizon);
            for (size_t i = 0; i < cuts.size(); ++i) line(cutValue(i, light.center), cuts[i].inward, static_cast<int>(i));
            if (!std::isfinite(best)) return false;
            const double phi = angle(x) + best;
            const Vec3 y = next == kClipDisc ? b.c : light.center + light.radius * (std::cos(phi) * e1 + std::sin(phi) * e2);
            length += light.radius * best;
            if (!dryRun) {
                const EdgeDerivative e = discArcG(light, x, y, rec.point, self.mSettings.gradient);
                g += e.g;
                scratch.mPassEdgesValid = false;  // a disc's arc: not kept (recordContour)
                if (self.mSettings.gradient) dg += e.dg;
            }
            if (next == kClipDisc) return true;
            x = y, on = next;
            continue;
        }
        // Along a line: its direction keeps what emits on the left.
        const Vec3 m = inwardAt(on, x);
        const Vec3 d = glm::cross(m, lightNormal);
        double best = std::numeric_limits<double>::infinity();
        int next = -1;
        if (b.clip == on) {
            const double s = glm::dot(b.c - x, d);
            if (s >= -tiny) best = std::max(s, 0.0), next = on;
        }
        // A frame side is taken only where it comes before every cut and the horizon by more
        // than rounding: at a polygon corner that merely touches the frame the next cut starts
        // where the frame's side passes, and the walk must turn onto the cut.
        auto line = [&](double f, const Vec3& mj, int which) {
            const double rate = glm::dot(mj, d);
            if (!(rate < 0.0) || which == on) return;
            const double s = f / -rate;
            const double margin = which >= kClipFrame ? 1e-6 * unit : 0.0;
            if (s > tiny && s < best - margin) best = s, next = which;
        };
        line(horizon(x), inwardAt(kClipHorizon, x), kClipHorizon);
        for (size_t i = 0; i < cuts.size(); ++i) line(cutValue(i, x), cuts[i].inward, static_cast<int>(i));
        for (size_t i = 0; i < frameSides.size(); ++i)
            line(glm::dot(x - frameSides[i].origin, frameSides[i].inward), frameSides[i].inward,
                 kClipFrame + static_cast<int>(i));
        if (light.shape == LightShape::Disc && on != kClipDisc) {
            const Vec3 e = x - light.center;
            const double bb = glm::dot(e, d), c = glm::dot(e, e) - light.radius * light.radius;
            const double disc = bb * bb - c;
            if (disc >= 0.0) {
                const double s = -bb + std::sqrt(disc);
                if (s > tiny && s < best) best = s, next = kClipDisc;
            }
        }
        if (next < 0 && b.clip != on) return false;
        if (!std::isfinite(best)) return false;
        const Vec3 y = next == on ? b.c : x + best * d;
        length += best;
        if (!dryRun) emit(x, y);
        if (next == on) return true;
        x = y, on = next;
    }
    return false;
}

// Whether the piece from a to b (both on the border of what emits) is that border, walked
// exactly, rather than a silhouette: true when the walk stays near the square of side s.
bool ContourIntegrator::Lattice::alongBorder(const Vertex& a, const Vertex& b, int s) {
    double length = 0.0;
    return a.clip >= 0 && b.clip >= 0 && emitBorder(a, b, true, length) &&
           length <= 4.0 * s * unit;
}

}  // namespace penumbra
