// `penumbra bake SCENE.json -o OUT.vdb`: builds every obstacle of a scene (implicit primitives,
// CSG trees, meshes, .vdb grids) and writes their level sets as named grids of one .vdb file,
// which vdb_print, vdb_view, Houdini and a `"type": "vdb"` obstacle read back. Analytic
// obstacles have no level set: bake voxelizes them at their voxel_size (or the scene's).
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include "cli/commands.h"
#include "penumbra/error.h"
#include "penumbra/output_files.h"
#include "penumbra/level_set.h"
#include "penumbra/scene.h"
#include "penumbra/volume.h"

namespace penumbra::cli {

namespace {

struct BakeOptions {
    std::string scene;
    std::string output;
    bool half = false;
    bool verbose = false;
    bool quiet = false;
};

/// Checks the output path before the (possibly slow) build: a writable directory, a .vdb name.
void checkOutput(const std::string& output) {
    namespace fs = std::filesystem;
    const fs::path path(output);
    if (path.extension() != ".vdb") {
        throw InputError("", "-o", "the output must be a .vdb file, got '" + output + "'");
    }
    std::error_code ec;
    if (fs::is_directory(path, ec)) {
        throw InputError("", "-o", "'" + output + "' is a directory");
    }
    const fs::path dir = path.has_parent_path() ? path.parent_path() : fs::path(".");
    if (!fs::is_directory(dir, ec)) {
        throw InputError("", "-o", "no such directory '" + dir.string() + "'");
    }
}

int runBake(const BakeOptions& o) {
    checkOutput(o.output);
    OutputSet outputs;  // only for its checks: writeLevelSets writes atomically itself
    outputs.addInput(o.scene, "the scene");
    outputs.addOutput(o.output, "-o");
    const Scene scene = loadScene(o.scene);
    for (const auto& [path, pointer] : scene.inputFiles) {
        outputs.addInput(path, pointer + " of " + o.scene);
    }
    if (scene.obstacles.empty() && scene.volumes.empty()) {
        throw InputError(o.scene, "/obstacles", "the scene has no obstacles to bake");
    }
    const std::vector<LevelSetPtr> grids = scene.obstacleLevelSets();
    // Volumes as fog grids under their names (made unique against the level sets' names).
    std::set<std::string> taken;
    for (const LevelSetPtr& g : grids) taken.insert(describe(*g).name);
    std::vector<std::pair<std::string, VolumeGridPtr>> volumes;
    for (size_t i = 0; i < scene.volumes.size(); ++i) {
        std::string name = scene.volumes[i].name;
        if (!taken.insert(name).second) name += "_fog" + std::to_string(i);
        taken.insert(name);
        volumes.emplace_back(name, scene.volumes[i].grid);
    }
    writeGrids(o.output, grids, volumes, o.half);

    if (o.verbose) std::cerr << scene.build.toText();
    if (!o.quiet) {
        uint64_t voxels = 0, bytes = 0;
        std::string names;
        for (const LevelSetPtr& g : grids) {
            const LevelSetInfo info = describe(*g);
            voxels += info.activeVoxels;
            bytes += info.bytes;
            names += (names.empty() ? "" : ", ") + ("'" + info.name + "'");
        }
        for (const auto& [name, v] : volumes) {
            const VolumeInfo info = describe(*v);
            voxels += info.activeVoxels;
            bytes += info.bytes;
            names += (names.empty() ? "" : ", ") + ("'" + name + "' (fog)");
        }
        const size_t count = grids.size() + volumes.size();
        std::printf("penumbra: wrote %s: %zu grid%s (%s), %llu active voxels, %.1f MiB in memory, "
                    "built in %.2f s\n",
                    o.output.c_str(), count, count == 1 ? "" : "s", names.c_str(),
                    static_cast<unsigned long long>(voxels), double(bytes) / (1024.0 * 1024.0),
                    scene.build.seconds);
    }
    return 0;
}

}  // namespace

Runner addBakeCommand(CLI::App& app) {
    auto o = std::make_shared<BakeOptions>();
    CLI::App* sub = app.add_subcommand(
        "bake", "Write every obstacle's level set to a .vdb file, one grid per obstacle named "
                "after it (analytic obstacles are voxelized at their voxel_size; fogs and other "
                "volumes as fog grids)");
    sub->add_option("scene", o->scene, "Scene file (JSON, see docs/scene-format.md)")->required();
    sub->add_option("-o,--output", o->output, "Output .vdb file (written atomically)")->required();
    sub->add_flag("--half", o->half, "Store values as 16-bit floats (about half the file size)");
    sub->add_flag("-v,--verbose", o->verbose,
                  "Print each obstacle's build report (voxels, memory, seconds) on stderr");
    sub->add_flag("-q,--quiet", o->quiet, "No summary line");
    return [o] { return runBake(*o); };
}

}  // namespace penumbra::cli
