// The Monte Carlo methods under one signature, and K independent estimates of one of them:
// shared by tests/test_monte_carlo.cpp and tests/test_monte_carlo_lights.cpp.
#pragma once

#include <cmath>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "penumbra/monte_carlo.h"

namespace penumbra::test {

using Estimator =
    std::function<Estimate(const Receiver&, const RectLight&, Occluder::Query&, const McSettings&)>;

struct NamedEstimator {
    const char* name;
    Estimator estimate;
};

inline std::vector<NamedEstimator> estimators() {
    return {{"reference", monteCarloReference},
            {"mc-adaptive", monteCarloAdaptive},
            {"mc-solid-angle", monteCarloSolidAngle},
            {"mc-ratio", monteCarloRatio}};
}

// How a test runs one method against a high-count reference: 64 samples per estimate, k
// estimates, and no allowance for bias, except mc-adaptive. Adaptive subdivision is biased
// (Kirk and Arvo 1991): a cell whose four rays agree is not split even when an edge crosses it,
// and the rays that triggered a split are kept. The bias vanishes as the starting grid refines
// (measured: 3-14% of F from the whole light, 0.1% from a 16 x 16 grid), so it is tested there,
// with splits still happening, 4096 samples, k / 4 estimates and an allowance of 0.5% of F.
struct TrialPlan {
    McSettings settings;
    int k;
    double biasAllowance;
};
inline TrialPlan trialPlan(const std::string& method, int k, double f) {
    TrialPlan plan{McSettings{}, k, 0.0};
    plan.settings.samples = 64;
    if (method == "mc-adaptive") {
        plan.settings.initialDepth = 4;
        plan.settings.threshold = 0.0005;
        plan.settings.samples = 4096;
        plan.k = k / 4;
        plan.biasAllowance = 0.005 * f;
    }
    return plan;
}

// K independent estimates (seeds from mcSeed(0 .. K-1, salt)): their mean, the standard
// deviation of one, and the rays cast in all.
struct Trials {
    double mean = 0.0, sd = 0.0;
    uint64_t rays = 0;
    double standardError(int k) const { return sd / std::sqrt(double(k)); }
};

inline Trials runTrials(const Estimator& f, const Receiver& r, const RectLight& light,
                        Occluder::Query& query, McSettings s, int k, uint64_t salt = 17) {
    std::vector<double> v;
    Trials t;
    for (int i = 0; i < k; ++i) {
        s.seed = mcSeed(uint64_t(i), salt, 0);
        const Estimate e = f(r, light, query, s);
        v.push_back(e.formFactor);
        t.rays += e.counts.shadowRays();
    }
    for (double x : v) t.mean += x;
    t.mean /= k;
    for (double x : v) t.sd += (x - t.mean) * (x - t.mean);
    t.sd = std::sqrt(t.sd / (k - 1));
    return t;
}

}  // namespace penumbra::test
