#include "penumbra/estimator.h"

#include "penumbra/contour_integrator.h"
#include "penumbra/error.h"
#include "penumbra/monte_carlo.h"

namespace penumbra {

const char* methodName(Method method) {
    switch (method) {
        case Method::Aci: return "aci";
        case Method::AciPixel: return "aci-pixel";
        case Method::Reference: return "reference";
        case Method::McAdaptive: return "mc-adaptive";
        case Method::McSolidAngle: return "mc-solid-angle";
        case Method::McRatio: return "mc-ratio";
    }
    return "?";
}

bool isMonteCarlo(Method method) {
    return method == Method::Reference || method == Method::McAdaptive ||
           method == Method::McSolidAngle || method == Method::McRatio;
}

int defaultSamples(Method method) {
    switch (method) {
        case Method::Reference: return 1024;
        case Method::McAdaptive: return 1024;
        case Method::McSolidAngle: return 16;
        case Method::McRatio: return 16;
        default: return 0;
    }
}

Method parseMethod(const std::string& name, const std::string& flag) {
    const Method all[] = {Method::Aci,       Method::AciPixel,     Method::Reference,
                          Method::McAdaptive, Method::McSolidAngle, Method::McRatio};
    for (Method m : all) {
        if (name == methodName(m)) return m;
    }
    throw InputError("", flag,
                     "unknown method '" + name +
                         "' (expected aci, aci-pixel, reference, mc-adaptive, mc-solid-angle or "
                         "mc-ratio)");
}

Estimate estimate(Method method, const Receiver& r, const RectLight& light, Occluder::Query& query,
                  ContourIntegrator& aci, const McSettings& mc) {
    McSettings s = mc;
    if (s.samples == 0) s.samples = defaultSamples(method);
    switch (method) {
        case Method::Aci:
        case Method::AciPixel: return aci.evaluate(r, light, query);
        case Method::Reference: return monteCarloReference(r, light, query, s);
        case Method::McAdaptive: return monteCarloAdaptive(r, light, query, s);
        case Method::McSolidAngle: return monteCarloSolidAngle(r, light, query, s);
        case Method::McRatio: return monteCarloRatio(r, light, query, s);
    }
    return Estimate{};
}

}  // namespace penumbra
