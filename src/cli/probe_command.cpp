// `penumbra probe`: point queries in the manner of Radiance's `rtrace -I`. Reads sensor points
// as CSV on stdin (header x,y,z,nx,ny,nz) and writes, in the same order, the form factor to one
// light (or the sum over every light, `--light all`, with a column per light under
// `--columns per-light`), its gradient with respect to the sensor position (normal fixed) and the shadow rays
// spent, as CSV on stdout. `--method` picks the estimator: aci (approximate contour
// integration) or one of the Monte Carlo baselines of monte_carlo.h, which estimate no
// gradient (their dF columns are 0).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

#include "cli/commands.h"
#include "cli/settings_flags.h"
#include "penumbra/contour_integrator.h"
#include "penumbra/error.h"
#include "penumbra/monte_carlo.h"
#include "penumbra/renderer.h"
#include "penumbra/scene.h"

namespace penumbra::cli {

namespace {

struct ProbeOptions {
    std::string scene;
    std::string light;
    std::string columns = "default";
    bool errorBound = false;
    std::unique_ptr<SettingsFlags> settings;  // method, ACI and Monte Carlo settings
};

std::vector<std::string> splitCsv(const std::string& line) {
    std::vector<std::string> out;
    std::stringstream ss(line);
    std::string cell;
    while (std::getline(ss, cell, ',')) {
        const auto b = cell.find_first_not_of(" \t\r");
        const auto e = cell.find_last_not_of(" \t\r");
        out.push_back(b == std::string::npos ? "" : cell.substr(b, e - b + 1));
    }
    return out;
}

double parseNumber(const std::string& cell, size_t lineNo, const char* column) {
    try {
        size_t used = 0;
        const double v = std::stod(cell, &used);
        if (used == cell.size() && std::isfinite(v)) {
            // The scene's range (docs/scene-format.md): beyond it squares overflow.
            if (std::abs(v) > 1e12) {
                throw InputError("<stdin>", "line " + std::to_string(lineNo) + ", column " + column,
                                 "'" + cell + "' is beyond the range of scene values (magnitude "
                                 "at most 1e12)");
            }
            return v;
        }
    } catch (const InputError&) {
        throw;
    } catch (const std::exception&) {
    }
    throw InputError("<stdin>", "line " + std::to_string(lineNo) + ", column " + column,
                     "expected a finite number, got '" + cell + "'");
}

// A CSV header field, quoted when it holds a comma, a quote or a line break.
std::string csvField(const std::string& s) {
    if (s.find_first_of(",\"\r\n") == std::string::npos) return s;
    std::string q = "\"";
    for (char c : s) q += c == '"' ? std::string("\"\"") : std::string(1, c);
    return q + "\"";
}

int runProbe(const ProbeOptions& opt) {
    // The settings as render's and a manifest's (render_settings.h): the same names, ranges
    // and checks; only aci-pixel, a renderer's pipeline, has no meaning for points.
    const RenderSettings rs = opt.settings->read();
    if (rs.method == Method::AciPixel)
        throw InputError("", "--method",
                         "probe supports aci, reference, mc-adaptive, mc-solid-angle and "
                         "mc-ratio, got 'aci-pixel'");
    const Method method = rs.method;
    const Scene scene = loadScene(opt.scene);
    // The lights to add up: the one named, or every light with `--light all`.
    std::vector<size_t> lightIndices;
    if (opt.light == "all") {
        for (size_t i = 0; i < scene.lights.size(); ++i) lightIndices.push_back(i);
    } else {
        lightIndices.push_back(scene.lightIndex(opt.light));
    }
    const bool perLight = opt.columns == "per-light";
    if (perLight && opt.light != "all")
        throw InputError("", "--columns", "per-light columns need --light all");
    const Occluder occluder = scene.makeOccluder();
    Occluder::Query query = occluder.makeQuery();
    AciSettings settings = rs.aci;
    settings.gradient = true;  // the CSV's dF columns
    settings.errorBound = true;
    // Sensor points may sit on an obstacle's surface: rays start 1.5 voxels off a level set's
    // surface, a hair off anything else (receiverRayOffset, set for each point below).
    settings.rayOffset = 1e-9;
    ContourIntegrator integrator(settings);
    McSettings mc = rs.mc;
    if (mc.samples == 0) mc.samples = defaultSamples(method);
    mc.rayOffset = settings.rayOffset;

    // Read everything first, so that bad input produces no partial output.
    std::string line;
    size_t lineNo = 0;
    std::vector<Receiver> points;
    static const char* kColumns[] = {"x", "y", "z", "nx", "ny", "nz"};
    while (std::getline(std::cin, line)) {
        ++lineNo;
        if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
        const std::vector<std::string> cells = splitCsv(line);
        if (lineNo == 1 && !cells.empty() && cells[0] == "x") {
            const std::vector<std::string> expected(kColumns, kColumns + 6);
            if (cells != expected)
                throw InputError("<stdin>", "line 1", "expected the header x,y,z,nx,ny,nz");
            continue;
        }
        if (cells.size() != 6)
            throw InputError("<stdin>", "line " + std::to_string(lineNo),
                             "expected 6 values (x,y,z,nx,ny,nz), got " +
                                 std::to_string(cells.size()));
        double v[6];
        for (int i = 0; i < 6; ++i) v[i] = parseNumber(cells[i], lineNo, kColumns[i]);
        // Scaled to its largest component first, so that its length cannot overflow.
        Vec3 n(v[3], v[4], v[5]);
        const double top = std::max({std::abs(n.x), std::abs(n.y), std::abs(n.z)});
        if (top > 0.0) n /= top;
        const double len = glm::length(n);
        if (!(len > 0.0))
            throw InputError("<stdin>", "line " + std::to_string(lineNo), "the normal is zero");
        points.push_back({Vec3(v[0], v[1], v[2]), n / len});
    }

    std::ostringstream out;
    out << std::setprecision(12);
    out << "x,y,z,form_factor,dF_dx,dF_dy,dF_dz,shadow_rays" << (opt.errorBound ? ",error_bound" : "");
    if (perLight)
        for (size_t li : lightIndices) out << ',' << csvField("form_factor:" + scene.lights[li].name);
    out << '\n';
    std::vector<double> each(lightIndices.size());
    for (size_t i = 0; i < points.size(); ++i) {
        const Receiver& r = points[i];
        mc.rayOffset = settings.rayOffset = receiverRayOffset(occluder, r.point, 1e-9);
        integrator.setSettings(settings);
        double f = 0.0, bound = 0.0;
        Vec3 gradient(0.0);
        uint64_t rays = 0;
        for (size_t k = 0; k < lightIndices.size(); ++k) {
            // Seeded by the point's position in the input and the light, so a run does not
            // depend on anything else.
            mc.seed = mcSeed(uint64_t(i), 0, uint64_t(lightIndices[k]), rs.mc.seed);
            const Estimate e = estimate(method, r, scene.lights[lightIndices[k]], query, integrator, mc);
            each[k] = e.formFactor;
            f += e.formFactor;
            gradient += e.gradient;
            bound += e.errorBound;
            rays += e.counts.shadowRays();
        }
        out << r.point.x << ',' << r.point.y << ',' << r.point.z << ',' << f << ',' << gradient.x
            << ',' << gradient.y << ',' << gradient.z << ',' << rays;
        // The estimator's bound on |F - F_exact| (tangent mode); nan where it gives none.
        if (opt.errorBound) out << ',' << bound;
        if (perLight)
            for (double x : each) out << ',' << x;
        out << '\n';
    }
    std::cout << out.str() << std::flush;
    return 0;
}

}  // namespace

Runner addProbeCommand(CLI::App& app) {
    auto opt = std::make_shared<ProbeOptions>();
    CLI::App* sub = app.add_subcommand(
        "probe",
        "Form factor and its gradient at sensor points: CSV x,y,z,nx,ny,nz on stdin, CSV "
        "x,y,z,form_factor,dF_dx,dF_dy,dF_dz,shadow_rays on stdout");
    sub->add_option("scene", opt->scene, "Scene file (JSON)")->required();
    sub->add_option("--light", opt->light,
                    "Name of the light (default: the only light), or 'all': the sum over every "
                    "light of the form factor, its gradient, rays and error bound");
    sub->add_option("--columns", opt->columns,
                    "default, or per-light (with --light all): one more column per light, "
                    "form_factor:NAME, in the scene's order")
        ->check(CLI::IsMember({"default", "per-light"}));
    sub->add_flag("--error-bound", opt->errorBound,
                  "Append a column error_bound: the estimator's bound on |F - F_exact| (the "
                  "default tangent mode's certified coverage; nan for the paper and arcs modes "
                  "and the Monte Carlo methods)");
    opt->settings = std::make_unique<SettingsFlags>(
        sub,
        std::vector<std::string>{"method", "aci_grid", "aci_steps", "aci_mode", "samples",
                                 "mc_threshold", "mc_max_depth", "mc_initial_depth", "seed"},
        std::map<std::string, std::string>{
            {"method",
             "Estimator: aci (approximate contour integration), or the Monte Carlo reference, "
             "mc-adaptive, mc-solid-angle, mc-ratio (no gradient: dF columns are 0)"},
            {"samples",
             "Monte Carlo: shadow rays per point (mc-adaptive: at most); default 1024 for "
             "reference and mc-adaptive, 16 for mc-solid-angle and mc-ratio"},
            {"seed", "Monte Carlo: seed mixed with each point's line index"}});
    return [opt] { return runProbe(*opt); };
}

}  // namespace penumbra::cli
