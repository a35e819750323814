// The Python module `penumbra` (docs/python.md): scenes, point queries, renders and image
// comparisons on numpy arrays. It calls the library as the command line does (probe_command.cpp,
// render_command.cpp, compare_command.cpp), so that its numbers are the CLI's, bit for bit, and
// raises the library's InputError as penumbra.InputError, whose str() is the line the CLI prints
// after "penumbra: error: ".
//
// Threads: probe() and render() release the GIL and run in a TBB arena of `threads` workers.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/global_control.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "../parallel_for.h"
#include "penumbra/compare.h"
#include "penumbra/contour_integrator.h"
#include "penumbra/error.h"
#include "penumbra/estimator.h"
#include "penumbra/image_io.h"
#include "penumbra/monte_carlo.h"
#include "penumbra/renderer.h"
#include "penumbra/scene.h"

namespace py = pybind11;

namespace penumbra::python {

namespace {

// ---------------------------------------------------------------------------------------------
// Settings by keyword: the keys of the JSON model (render_settings.h), which batch manifests
// use and the CLI's flags spell with dashes. Python types are checked here (TypeError); the
// values then go through RenderSettings::readJson and validate, as a manifest's do.

// Every keyword a settings dict may hold; each function accepts a subset.
const std::vector<std::string> kProbeKeys = {"aci_grid",         "aci_steps",    "aci_mode",
                                             "samples",          "mc_threshold", "mc_max_depth",
                                             "mc_initial_depth", "seed",         "threads"};
const std::vector<std::string> kRenderKeys = {
    "aci_grid",     "aci_steps",      "aci_mode",         "aci_fixed_steps", "aci_no_row_pairs", "max_span",
    "samples",      "mc_threshold",   "mc_max_depth",     "mc_initial_depth", "seed",
    "threads",      "volume_cache",   "volume_samples",   "hide_volumes"};

std::string joined(const std::vector<std::string>& names) {
    std::string s;
    for (const std::string& n : names) s += (s.empty() ? "" : ", ") + n;
    return s;
}

std::string typeName(py::handle v) { return py::str(py::type::handle_of(v).attr("__name__")); }

// A Python integer (or numpy integer), not a bool: TypeError otherwise.
py::int_ asInteger(py::handle v, const std::string& key) {
    if (PyBool_Check(v.ptr()) || !PyIndex_Check(v.ptr())) {
        throw py::type_error(key + ": must be an integer, got " + typeName(v));
    }
    py::int_ i = py::reinterpret_steal<py::int_>(PyNumber_Index(v.ptr()));
    if (!i) throw py::error_already_set();
    return i;
}

// A keyword's value as JSON, its Python type checked.
nlohmann::json jsonValue(py::handle v, const std::string& key) {
    if (key == "hide_volumes" || key == "aci_fixed_steps" || key == "aci_no_row_pairs") {
        if (!PyBool_Check(v.ptr())) throw py::type_error(key + ": must be a bool, got " + typeName(v));
        return v.ptr() == Py_True;
    }
    if (key == "aci_mode" || key == "method") {
        if (!py::isinstance<py::str>(v)) throw py::type_error(key + ": must be a str, got " + typeName(v));
        return std::string(py::str(v));
    }
    if (key == "mc_threshold") {
        if (PyBool_Check(v.ptr()) || !PyNumber_Check(v.ptr())) {
            throw py::type_error(key + ": must be a number, got " + typeName(v));
        }
        return double(py::float_(py::reinterpret_borrow<py::object>(v)));
    }
    const py::int_ i = asInteger(v, key);
    if (key == "seed") {  // the CLI's --seed: any 64-bit unsigned integer
        const unsigned long long x = PyLong_AsUnsignedLongLong(i.ptr());
        if (PyErr_Occurred()) {
            PyErr_Clear();
            throw InputError("", key,
                             "must be an integer in [0, 2^64 - 1], got " + py::repr(i).cast<std::string>());
        }
        return uint64_t(x);
    }
    int overflow = 0;
    const long long x = PyLong_AsLongLongAndOverflow(i.ptr(), &overflow);
    if (overflow != 0) throw InputError("", key, "is out of range, got " + py::repr(i).cast<std::string>());
    return x;
}

// Reads the keywords of `kw` (each allowed for `function`) into `settings`, checked as the
// model checks them. The thread count (not a render setting of the model's here: Python keeps
// one arena per count) is returned through `threads`.
void readSettings(const py::kwargs& kw, const std::vector<std::string>& allowed, const char* function,
                  RenderSettings& settings, int& threads) {
    nlohmann::json given = nlohmann::json::object();
    for (auto item : kw) {
        const std::string key = py::str(item.first);
        py::handle v = item.second;
        if (std::find(allowed.begin(), allowed.end(), key) == allowed.end()) {
            if (std::find(kRenderKeys.begin(), kRenderKeys.end(), key) != kRenderKeys.end()) {
                throw py::type_error(std::string(function) + "(): " + key +
                                     " only applies to render()");
            }
            throw py::type_error(std::string(function) + "() got an unknown setting '" + key +
                                 "' (expected one of: " + joined(allowed) + ")");
        }
        if (v.is_none()) continue;  // None: the default, as if not given
        given[key] = jsonValue(v, key);
    }
    settings.readJson(given);
    threads = settings.threads > 0 ? settings.threads : 0;
    settings.threads = 0;
    settings.validate();
}

std::string pathOf(py::handle p) { return py::str(py::module_::import("os").attr("fspath")(p)); }

py::object jsonLoads(const std::string& text) {
    return py::module_::import("json").attr("loads")(text);
}

// ---------------------------------------------------------------------------------------------
// Threads

// One arena per thread count, kept for the life of the process: oneTBB 2021.8 does not give
// back all the memory of an arena it destroys (some kilobytes each; oneTBB issue 967), which a
// script that renders or probes thousands of times would see as a leak. `threads` 0: every
// hardware thread.
tbb::task_arena& arenaFor(int threads) {
    static std::mutex mutex;
    static std::map<int, std::unique_ptr<tbb::task_arena>> arenas;
    std::lock_guard<std::mutex> lock(mutex);
    std::unique_ptr<tbb::task_arena>& arena = arenas[threads];
    if (!arena) {
        // A copy: libtbb has no definition of the constant for a reference to bind to.
        const int automatic = tbb::task_arena::automatic;
        arena = std::make_unique<tbb::task_arena>(threads > 0 ? threads : automatic);
        arena->initialize();
    }
    return *arena;
}

// Runs `work` in the arena of `threads` workers, with TBB's worker limit raised to it as
// render() does (more threads than cores, when asked for, are then real). Call it with the GIL
// released.
template <typename Work>
void runInArena(tbb::task_arena& arena, const Work& work) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                              std::max<size_t>(size_t(arena.max_concurrency()),
                                               tbb::global_control::active_value(
                                                   tbb::global_control::max_allowed_parallelism)));
    arena.execute(work);
}

// ---------------------------------------------------------------------------------------------
// Scenes

// A loaded scene and, built on first use and then shared by every call, its occluder.
class PyScene {
  public:
    explicit PyScene(Scene scene) : mScene(std::move(scene)) {}
    const Scene& scene() const { return mScene; }
    const Occluder& occluder() const {
        std::call_once(mOnce,
                       [this] { mOccluder = std::make_unique<Occluder>(mScene.makeOccluder()); });
        return *mOccluder;
    }

  private:
    Scene mScene;
    mutable std::once_flag mOnce;
    mutable std::unique_ptr<Occluder> mOccluder;
};

std::shared_ptr<PyScene> loadSceneFile(py::handle path) {
    const std::string p = pathOf(path);
    py::gil_scoped_release release;  // level sets may take seconds to build
    return std::make_shared<PyScene>(loadScene(p));
}

std::shared_ptr<PyScene> sceneFromDict(py::handle d, const std::string& file, py::handle baseDir) {
    if (!py::isinstance<py::dict>(d)) {
        throw py::type_error("from_dict: expected a dict, got " + typeName(d));
    }
    std::string text;
    try {
        // allow_nan=False: JSON has no NaN, and the library's parser would name a column only.
        text = py::str(py::module_::import("json").attr("dumps")(d, py::arg("allow_nan") = false));
    } catch (py::error_already_set& e) {
        if (!e.matches(PyExc_ValueError) && !e.matches(PyExc_TypeError)) throw;
        throw InputError(file, "", "not a JSON document: " + std::string(py::str(e.value())));
    }
    // Relative paths resolve as loadScene resolves them: against the file's folder.
    std::string dir =
        baseDir.is_none() ? std::filesystem::path(file).parent_path().string() : pathOf(baseDir);
    if (dir.empty()) dir = ".";
    py::gil_scoped_release release;
    return std::make_shared<PyScene>(parseScene(text, file, dir));
}

py::object cameraDict(const Scene& s) {
    if (!s.camera) return py::none();
    const Camera& c = *s.camera;
    auto vec = [](const Vec3& v) { return py::make_tuple(v.x, v.y, v.z); };
    py::dict d;
    d["eye"] = vec(c.eye);
    d["look_at"] = vec(c.lookAt);
    d["up"] = vec(c.up);
    d["fov_deg"] = c.fovDeg;
    d["width"] = c.width;
    d["height"] = c.height;
    return d;
}

// ---------------------------------------------------------------------------------------------
// probe

using DoubleArray = py::array_t<double, py::array::c_style | py::array::forcecast>;

DoubleArray pointArray(py::handle a, const char* name) {
    DoubleArray arr = DoubleArray::ensure(a);
    if (!arr) {
        throw py::type_error(std::string(name) +
                             ": expected an array of shape (N, 3) of numbers, got " + typeName(a));
    }
    if (arr.ndim() != 2 || arr.shape(1) != 3) {
        std::string shape;
        for (py::ssize_t i = 0; i < arr.ndim(); ++i)
            shape += (i ? ", " : "") + std::to_string(arr.shape(i));
        if (arr.ndim() == 1) shape += ",";
        throw InputError("", name, "must have shape (N, 3), got (" + shape + ")");
    }
    return arr;
}

// The CLI's checks of each value (probe_command.cpp's parseNumber), with array indices for lines.
void checkValues(const DoubleArray& a, const char* name) {
    const double* v = a.data();
    const size_t n = size_t(a.shape(0)) * 3;
    for (size_t k = 0; k < n; ++k) {
        if (std::isfinite(v[k]) && std::abs(v[k]) <= 1e12) continue;
        const std::string where =
            std::string(name) + "[" + std::to_string(k / 3) + ", " + std::to_string(k % 3) + "]";
        const std::string got = py::str(py::float_(v[k]));
        if (!std::isfinite(v[k]))
            throw InputError("", where, "expected a finite number, got " + got);
        throw InputError("", where,
                         got + " is beyond the range of scene values (magnitude at most 1e12)");
    }
}

// The CLI's receiver: the normal scaled to its largest component first (so that its length
// cannot overflow), then to unit length.
bool makeReceiver(const double* p, const double* nrm, Receiver& r) {
    Vec3 n(nrm[0], nrm[1], nrm[2]);
    const double top = std::max({std::abs(n.x), std::abs(n.y), std::abs(n.z)});
    if (top > 0.0) n /= top;
    const double len = glm::length(n);
    if (!(len > 0.0)) return false;
    r = {Vec3(p[0], p[1], p[2]), n / len};
    return true;
}

// Points per chunk: between chunks the GIL is taken to look for Ctrl-C.
constexpr size_t kProbeChunk = 1 << 16;

py::dict probe(const PyScene& self, py::handle pointsIn, py::handle normalsIn, py::handle lightIn,
               const std::string& methodName, const py::kwargs& kw) {
    // Every argument is checked before any work, in the CLI's order.
    const Method method = parseMethod(methodName, "method");
    if (method != Method::Aci && !isMonteCarlo(method)) {
        throw InputError("", "method",
                         "probe supports aci, reference, mc-adaptive, mc-solid-angle and "
                         "mc-ratio, got '" +
                             methodName + "'");
    }
    RenderSettings rs;
    rs.method = method;
    int threadsAsked = 0;
    readSettings(kw, kProbeKeys, "probe", rs, threadsAsked);
    AciSettings settings = rs.aci;
    settings.gradient = true;  // the gradient column, as the CLI's probe
    settings.errorBound = true;
    McSettings mc = rs.mc;
    if (mc.samples == 0) mc.samples = defaultSamples(method);
    const uint64_t userSeed = mc.seed;

    const DoubleArray points = pointArray(pointsIn, "points");
    const DoubleArray normals = pointArray(normalsIn, "normals");
    if (normals.shape(0) != points.shape(0)) {
        throw InputError("", "normals",
                         "must have as many rows as points (" + std::to_string(points.shape(0)) +
                             "), got " + std::to_string(normals.shape(0)));
    }
    checkValues(points, "points");
    checkValues(normals, "normals");
    const size_t n = size_t(points.shape(0));
    const double* pv = points.data();
    const double* nv = normals.data();
    for (size_t i = 0; i < n; ++i) {
        Receiver r;
        if (!makeReceiver(pv + 3 * i, nv + 3 * i, r)) {
            throw InputError("", "normals[" + std::to_string(i) + "]", "the normal is zero");
        }
    }

    std::string lightName;
    if (!lightIn.is_none()) {
        if (!py::isinstance<py::str>(lightIn)) {
            throw py::type_error("light: must be a str or None, got " + typeName(lightIn));
        }
        lightName = py::str(lightIn);
    }
    const Scene& scene = self.scene();
    // The lights to add up: the one named, or every light with "all" (as the CLI's --light all).
    std::vector<size_t> lightIndices;
    if (lightName == "all") {
        for (size_t i = 0; i < scene.lights.size(); ++i) lightIndices.push_back(i);
    } else {
        lightIndices.push_back(scene.lightIndex(lightName));
    }
    const size_t nLights = lightIndices.size();
    const Occluder& occluder = self.occluder();
    // Sensor points may sit on an obstacle's surface: rays start 1.5 voxels off a level set's
    // surface, a hair off anything else (receiverRayOffset, per point), as in the CLI.
    settings.rayOffset = 1e-9;
    mc.rayOffset = settings.rayOffset;
    // The estimator gives a bound only in tangent mode (certified coverage).
    const bool hasBound = method == Method::Aci && settings.coverage && settings.errorBound;

    py::array_t<double> formFactor{py::ssize_t(n)};
    py::array_t<double> gradient({py::ssize_t(n), py::ssize_t(3)});
    py::array_t<int64_t> shadowRays{py::ssize_t(n)};
    py::array_t<double> errorBound{py::ssize_t(hasBound ? n : 0)};
    double* ff = formFactor.mutable_data();
    double* grad = gradient.mutable_data();
    int64_t* rays = shadowRays.mutable_data();
    double* bound = errorBound.mutable_data();
    // light="all": each light's form factor too, (N, lights) in scene order.
    py::array_t<double> perLight({py::ssize_t(lightName == "all" ? n : 0), py::ssize_t(nLights)});
    double* each = perLight.mutable_data();

    struct Worker {
        Occluder::Query query;
        ContourIntegrator aci;
    };
    tbb::enumerable_thread_specific<std::unique_ptr<Worker>> workers;
    tbb::task_arena& arena = arenaFor(threadsAsked);
    const int threads = arena.max_concurrency();
    auto evaluate = [&](const tbb::blocked_range<size_t>& range) {
        std::unique_ptr<Worker>& w = workers.local();
        if (!w) w.reset(new Worker{occluder.makeQuery(), ContourIntegrator(settings)});
        AciSettings s = settings;
        McSettings m = mc;
        for (size_t i = range.begin(); i != range.end(); ++i) {
            Receiver r;
            makeReceiver(pv + 3 * i, nv + 3 * i, r);
            m.rayOffset = s.rayOffset = receiverRayOffset(occluder, r.point, 1e-9);
            w->aci.setSettings(s);
            double f = 0.0, b = 0.0;
            Vec3 g(0.0);
            int64_t count = 0;
            for (size_t k = 0; k < nLights; ++k) {
                // Seeded by the point's index and the light, so a result depends on nothing
                // else (as the CLI's line index).
                m.seed = mcSeed(uint64_t(i), 0, uint64_t(lightIndices[k]), userSeed);
                const Estimate e = estimate(method, r, scene.lights[lightIndices[k]], w->query, w->aci, m);
                if (lightName == "all") each[i * nLights + k] = e.formFactor;
                f += e.formFactor;
                g += e.gradient;
                b += e.errorBound;
                count += int64_t(e.counts.shadowRays());
            }
            ff[i] = f;
            grad[3 * i] = g.x;
            grad[3 * i + 1] = g.y;
            grad[3 * i + 2] = g.z;
            rays[i] = count;
            if (hasBound) bound[i] = b;
        }
    };
    if (n > 0 && method == Method::Aci && (settings.distanceGuided || settings.coverage)) {
        // As render() does: the far-field companions that distances and certificates need are
        // built here, not by the first worker that asks while the others wait.
        py::gil_scoped_release release;
        occluder.prepareClearance();
    }
    for (size_t begin = 0; begin < n; begin += kProbeChunk) {
        const size_t end = std::min(n, begin + kProbeChunk);
        {
            py::gil_scoped_release release;
            runInArena(arena, [&] {
                detail::parallelFor(tbb::blocked_range<size_t>(begin, end, 16), evaluate);
            });
        }
        if (PyErr_CheckSignals() != 0) throw py::error_already_set();
    }

    py::dict out;
    out["form_factor"] = formFactor;
    out["gradient"] = gradient;
    out["shadow_rays"] = shadowRays;
    if (hasBound) out["error_bound"] = errorBound;
    if (lightName == "all") out["per_light"] = perLight;
    out["threads"] = threads;
    return out;
}

// ---------------------------------------------------------------------------------------------
// Images

// An array that owns a moved-in vector: no copy of the pixels.
py::array_t<float> toArray(std::vector<float>&& data, int width, int height, int channels) {
    auto* owned = new std::vector<float>(std::move(data));
    py::capsule free(owned, [](void* p) { delete static_cast<std::vector<float>*>(p); });
    std::vector<py::ssize_t> shape = {height, width};
    if (channels != 1) shape.push_back(channels);
    return py::array_t<float>(shape, owned->data(), free);
}

py::array_t<float> imageArray(Image&& image) {
    const int w = image.width, h = image.height, c = image.channels;
    return toArray(std::move(image.data), w, h, c);  // (H, W) for one channel
}

// A float image from an array of shape (H, W) or (H, W, C), C in 1-4.
Image arrayImage(py::handle a, const std::string& name) {
    using FloatArray = py::array_t<float, py::array::c_style | py::array::forcecast>;
    FloatArray arr = FloatArray::ensure(a);
    if (!arr) {
        throw py::type_error(name + ": expected an image array or a path, got " + typeName(a));
    }
    if (arr.ndim() != 2 && arr.ndim() != 3) {
        throw InputError("", name, "must have shape (H, W) or (H, W, C)");
    }
    const int channels = arr.ndim() == 3 ? int(arr.shape(2)) : 1;
    if (arr.shape(0) < 1 || arr.shape(1) < 1 || channels < 1 || channels > 4) {
        throw InputError("", name, "must have at least one pixel and 1 to 4 channels");
    }
    Image img(int(arr.shape(1)), int(arr.shape(0)), channels);
    std::copy(arr.data(), arr.data() + img.data.size(), img.data.begin());
    return img;
}

// The CLI's image loading (compare_command.cpp): a missing or unreadable file is bad input.
Image readImageFile(const std::string& path, const std::string& what) {
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) throw InputError(path, what, "no such image file");
    if (!std::filesystem::is_regular_file(path, ec)) {
        throw InputError(path, what, "not a regular file");
    }
    try {
        py::gil_scoped_release release;
        return readImage(path);
    } catch (const InputError&) {
        throw;
    } catch (const ImageModuleError&) {
        throw;  // the installation, not the image
    } catch (const std::exception& e) {
        throw InputError(path, what, std::string("cannot read the image: ") + e.what());
    }
}

bool isPath(py::handle v) { return py::isinstance<py::str>(v) || py::hasattr(v, "__fspath__"); }

// An array or an image file, with no non-finite value (a NaN would vanish from every figure).
Image comparedImage(py::handle v, const std::string& what) {
    std::string file;
    Image img;
    if (isPath(v)) {
        file = pathOf(v);
        img = readImageFile(file, what);
    } else {
        img = arrayImage(v, what);
    }
    requireFinite(img, file, what);
    return img;
}

py::dict differenceDict(const DifferenceStats& s) {
    py::dict d;
    d["pixels"] = s.pixels;
    d["mean"] = s.mean;
    d["rmse"] = s.rmse;
    d["max"] = s.max;
    return d;
}

py::dict compare(py::handle a, py::handle b, py::handle maskIn) {
    const Image test = comparedImage(a, "a");
    const Image ref = comparedImage(b, "b");
    Image mask;
    if (!maskIn.is_none()) mask = comparedImage(maskIn, "mask");
    ImageDifference d;
    try {
        d = compareImages(test, ref, maskIn.is_none() ? nullptr : &mask);
    } catch (const InputError& e) {
        throw InputError("", e.where() == "--mask" ? "mask" : "b", e.message());
    }
    // The keys of `penumbra compare --json`.
    py::dict out;
    out["width"] = test.width;
    out["height"] = test.height;
    out["channels"] = test.channels;
    out["units"] = "255 x linear difference";
    out["all"] = differenceDict(d.all);
    if (d.hasMask) out["masked"] = differenceDict(d.masked);
    return out;
}

void writeImageFile(py::handle path, py::handle image) {
    const std::string p = pathOf(path);
    imageFormatFor(p, "path");
    Image img = arrayImage(image, "image");
    if (img.channels == 2) throw InputError("", "image", "must have 1, 3 or 4 channels, got 2");
    py::gil_scoped_release release;
    writeImage(p, img, {}, "path");
}

// ---------------------------------------------------------------------------------------------
// render

py::tuple renderScene(const PyScene& self, py::handle width, py::handle height,
                      const std::string& methodName, const py::kwargs& kw) {
    RenderSettings settings;
    settings.method = parseMethod(methodName, "method");
    nlohmann::json size = nlohmann::json::object();
    if (!width.is_none()) size["width"] = jsonValue(width, "width");
    if (!height.is_none()) size["height"] = jsonValue(height, "height");
    settings.readJson(size);
    if (settings.width > 0 && settings.height > 0) {
        checkRenderMemory(settings.width, settings.height, "", "width/height");
    }
    int threads = 0;
    readSettings(kw, kRenderKeys, "render", settings, threads);
    // render() in the kept arena (threads < 0: the caller's), not one of its own per call.
    tbb::task_arena& arena = arenaFor(threads);
    settings.threads = -1;
    // As `penumbra render` without AOV files: no gradient, no error bound.
    settings.aci.gradient = false;
    settings.aci.errorBound = false;

    const Scene& scene = self.scene();
    if (!scene.camera) {
        throw InputError(scene.file, "/camera", "the scene has no camera, which rendering needs");
    }
    if (auto inside = scene.obstacleContaining(scene.camera->eye)) {
        const Obstacle& ob = scene.obstacles[*inside];
        const std::string text =
            scene.file + ": /camera/eye: inside obstacle '" +
            (ob.name.empty() ? "obstacle_" + std::to_string(*inside) : ob.name) + "' (/obstacles/" +
            std::to_string(*inside) + ")";
        if (PyErr_WarnEx(PyExc_UserWarning, text.c_str(), 1) != 0) throw py::error_already_set();
    }
    RenderResult result;
    {
        py::gil_scoped_release release;
        runInArena(arena, [&] { result = render(scene, settings); });
    }
    RenderStats stats = result.stats;
    stats.buildJson = scene.build.toJson();  // as `render --stats` writes it
    // RGB, or RGBA when the camera sees volumes (the alpha is their opacity along the ray).
    return py::make_tuple(imageArray(std::move(result.color)), jsonLoads(stats.toJson()));
}

// The `name` of every element, in order.
template <class Things>
std::vector<std::string> namesOf(const Things& things) {
    std::vector<std::string> names;
    for (const auto& t : things) names.push_back(t.name);
    return names;
}

py::dict settingRanges() {
    py::dict d;
    for (const auto& [key, r] : RenderSettings::integerRanges()) d[key.c_str()] = py::make_tuple(r.lo, r.hi);
    return d;
}

}  // namespace

}  // namespace penumbra::python

PYBIND11_MODULE(penumbra, m) {
    using namespace penumbra;
    using namespace penumbra::python;
    m.doc() =
        "Penumbra: area-light direct illumination over OpenVDB level sets by approximate contour "
        "integration (Vedel 1993).\n\n"
        "Scene.load / Scene.from_dict read the JSON scene model (docs/scene-format.md); "
        "Scene.probe gives form factors and gradients at points, Scene.render a picture, "
        "compare the differences between two images. Bad input raises InputError, whose str() "
        "is the line `penumbra` prints after 'penumbra: error: '.";
    m.attr("__version__") = PENUMBRA_VERSION;

    // InputError(ValueError), with the library's parts as attributes.
    static py::exception<InputError> inputError(m, "InputError", PyExc_ValueError);
    inputError.doc() =
        "Bad input: a scene, a setting, an array or a file. str(e) is the CLI's error line "
        "without its 'penumbra: error: ' prefix; e.file, e.where (JSON pointer, setting or array "
        "index) and e.message are its parts.";
    py::register_exception_translator([](std::exception_ptr p) {
        try {
            if (p) std::rethrow_exception(p);
        } catch (const InputError& e) {
            py::object cls = py::reinterpret_borrow<py::object>(inputError);
            py::object err = cls(e.what());
            err.attr("file") = e.file();
            err.attr("where") = e.where();
            err.attr("message") = e.message();
            PyErr_SetObject(inputError.ptr(), err.ptr());
        }
    });

    m.attr("METHODS") = py::make_tuple("aci", "aci-pixel", "reference", "mc-adaptive",
                                       "mc-solid-angle", "mc-ratio");
    m.attr("ACI_MODES") = py::make_tuple("tangent", "arcs", "paper");
    m.attr("SETTING_RANGES") = settingRanges();

    py::class_<PyScene, std::shared_ptr<PyScene>>(
        m, "Scene",
        "A scene: camera, lights, obstacles (level sets built when loaded) and receivers. "
        "Immutable; probe() and render() may be called from several Python threads.")
        .def_static("load", &loadSceneFile, py::arg("path"),
                    "Loads a scene file (JSON, docs/scene-format.md) and builds its level sets. "
                    "Paths inside are relative to the file. Raises InputError with the CLI's "
                    "message for bad input.")
        .def_static("from_dict", &sceneFromDict, py::arg("d"), py::arg("file") = "<dict>",
                    py::arg("base_dir") = py::none(),
                    "A scene from the JSON model as a dict. `file` names it in error messages; "
                    "`base_dir` resolves relative paths (.vdb and mesh files; default: the "
                    "folder of `file`, else the current directory).")
        .def_property_readonly(
            "file", [](const PyScene& s) { return s.scene().file; },
            "The file the scene came from (from_dict: its `file`).")
        .def_property_readonly(
            "lights", [](const PyScene& s) { return namesOf(s.scene().lights); },
            "The lights' names, in scene order.")
        .def_property_readonly(
            "obstacles", [](const PyScene& s) { return namesOf(s.scene().obstacles); },
            "The obstacles' names, in scene order.")
        .def_property_readonly(
            "camera", [](const PyScene& s) { return cameraDict(s.scene()); },
            "The camera as a dict (eye, look_at, up, fov_deg, width, "
            "height), or None.")
        .def_property_readonly(
            "build", [](const PyScene& s) { return jsonLoads(s.scene().build.toJson()); },
            "What building the obstacles' level sets cost (the 'build' of render statistics).")
        .def("probe", &probe, py::arg("points"), py::arg("normals"), py::arg("light") = py::none(),
             py::arg("method") = "aci",
             "Form factor from a differential area at each point (with its normal) to one "
             "light, its gradient with respect to the point (normal fixed) and the shadow rays "
             "spent: `penumbra probe`'s columns, bit for bit.\n\n"
             "points, normals: arrays of shape (N, 3) (normals need not be unit length).\n"
             "light: the light's name; None takes the only light; 'all' adds every light's "
             "(and per_light gives each light's form factor, shape (N, lights)).\n"
             "method: 'aci', 'reference', 'mc-adaptive', 'mc-solid-angle' or 'mc-ratio'.\n"
             "settings: aci_grid, aci_steps, aci_mode, samples, mc_threshold, mc_max_depth, "
             "mc_initial_depth, seed, threads.\n\n"
             "Returns a dict: form_factor (N,), gradient (N, 3), shadow_rays (N,) int64, "
             "error_bound (N,) when the estimator gives one (aci in tangent mode), per_light "
             "(N, lights) with light='all', threads (the workers of the TBB arena). Runs in parallel with the GIL released.")
        .def("render", &renderScene, py::arg("width") = py::none(), py::arg("height") = py::none(),
             py::arg("method") = "aci",
             "Renders the scene's camera view as `penumbra render` does, bit for bit.\n\n"
             "width, height: image size (default: the camera's).\n"
             "method: 'aci', 'aci-pixel', 'reference', 'mc-adaptive', 'mc-solid-angle', "
             "'mc-ratio'.\n"
             "settings: aci_grid, aci_steps, aci_mode, aci_fixed_steps, aci_no_row_pairs, max_span, samples, "
             "mc_threshold, mc_max_depth, mc_initial_depth, seed, threads, volume_cache, "
             "volume_samples, hide_volumes.\n\n"
             "Returns (image, stats): image a float32 array (H, W, 3) of linear radiance, "
             "(H, W, 4) with an alpha channel when the camera sees volumes; stats the dict "
             "`render --stats` writes. Runs in parallel with the GIL released.")
        .def("__repr__", [](const PyScene& s) {
            return "<penumbra.Scene '" + s.scene().file +
                   "': " + std::to_string(s.scene().lights.size()) + " lights, " +
                   std::to_string(s.scene().obstacles.size()) + " obstacles>";
        });

    m.def("compare", &compare, py::arg("a"), py::arg("b"), py::arg("mask") = py::none(),
          "Differences between two images in 8-bit units (255 x linear), as `penumbra compare "
          "--json`: a dict with width, height, channels, units, 'all' and, with a mask, "
          "'masked', each {pixels, mean, rmse, max}. a, b, mask: arrays (H, W) or (H, W, C), or "
          "image file paths.");
    m.def(
        "read_image",
        [](py::handle path) {
            const std::string p = pathOf(path);
            return imageArray(readImageFile(p, "path"));
        },
        py::arg("path"),
        "Reads an image file (.exr as stored, .png decoded from sRGB) as a float32 array "
        "(H, W, C), or (H, W) for one channel.");
    m.def("write_image", &writeImageFile, py::arg("path"), py::arg("image"),
          "Writes an array (H, W) or (H, W, C), C in 1, 3, 4, as .exr (linear float) or .png "
          "(sRGB, 8-bit), atomically.");
}
