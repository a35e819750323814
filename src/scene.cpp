// The scene model (scene.h): choosing a light, the obstacles as an Occluder or as level sets,
// the build report's wording, and the level-set cache. Reading a scene file is
// src/scene_loader.cpp; building its obstacles, src/obstacle_build.cpp.
#include "penumbra/scene.h"

#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <variant>

#include "overloaded.h"
#include "penumbra/error.h"
#include "penumbra/hash.h"
#include "penumbra/level_set.h"
#include "penumbra/shape.h"
#include "scene_plan.h"
#include "text_format.h"

namespace penumbra {

size_t Scene::lightIndex(const std::string& name) const {
    std::string names;
    for (const RectLight& l : lights) names += (names.empty() ? "" : ", ") + inQuotes(l.name);
    if (lights.empty()) throw InputError(file, "/lights", "the scene has no lights");
    if (name.empty()) {
        if (lights.size() == 1) return 0;
        throw InputError(file, "/lights",
                         "the scene has " + std::to_string(lights.size()) + " lights (" + names +
                             "); choose one by name");
    }
    std::vector<size_t> matches;
    for (size_t i = 0; i < lights.size(); ++i) {
        if (lights[i].name == name) matches.push_back(i);
    }
    if (matches.size() == 1) return matches.front();
    if (matches.empty()) {
        std::vector<std::string> all;
        for (const RectLight& l : lights) all.push_back(l.name);
        throw InputError(file, "/lights",
                         "no light named " + inQuotes(name) + suggestion(name, all));
    }
    throw InputError(file, "/lights",
                     std::to_string(matches.size()) + " lights are named " + inQuotes(name) +
                         "; the choice is ambiguous");
}

std::optional<size_t> Scene::obstacleContaining(const Vec3& p) const {
    const auto inside = Overloaded{
        [&](const AnalyticSphere& s) { return glm::length(p - s.center) < s.radius; },
        [&](const AnalyticBox& b) {
            return p.x > b.lo.x && p.y > b.lo.y && p.z > b.lo.z && p.x < b.hi.x && p.y < b.hi.y &&
                   p.z < b.hi.z;
        },
        [&](const LevelSetPtr& ls) { return ls && sampleLevelSet(*ls, p) < 0.0; }};
    for (size_t i = 0; i < obstacles.size(); ++i) {
        if (std::visit(inside, obstacles[i].shape)) return i;
    }
    return std::nullopt;
}

Occluder Scene::makeOccluder() const {
    std::vector<ObstacleShape> shapes;
    shapes.reserve(obstacles.size());
    for (const Obstacle& o : obstacles) shapes.push_back(o.shape);
    Occluder occ(std::move(shapes));
    for (const Volume& v : volumes) occ.addMedium({v.grid, v.extinction, v.albedo});
    return occ;
}

namespace {

/// An analytic obstacle as the level set `penumbra bake` writes: voxelized at its own voxel
/// size and band (or the scene's), after checking the estimate against the memory limit.
LevelSetPtr voxelized(const Obstacle& o, ShapeKind kind, const std::string& name,
                      const Scene& scene) {
    ShapeNode node;
    node.kind = std::move(kind);
    const double voxel = o.voxelSize > 0.0 ? o.voxelSize : scene.levelSet.voxelSize;
    const double halfWidth = o.halfWidth > 0.0 ? o.halfWidth : scene.levelSet.halfWidth;
    // Analytic shapes were never voxelized while loading: estimate before building.
    const double need = estimateBuildBytes(node, voxel, halfWidth);
    const double limit = defaultMemoryLimitBytes();
    if (need > limit) {
        throw InputError(scene.file, "",
                         "obstacle '" + name + "' would need ~" + bytesText(need) +
                             " as a level set at voxel_size " + numberText(voxel) +
                             ", over the limit of " + bytesText(limit) +
                             "; give it a larger voxel_size to bake it");
    }
    return buildLevelSet(node, voxel, halfWidth, name);
}

}  // namespace

std::vector<LevelSetPtr> Scene::obstacleLevelSets() const {
    std::vector<LevelSetPtr> out;
    std::set<std::string> used;
    for (size_t i = 0; i < obstacles.size(); ++i) {
        const Obstacle& o = obstacles[i];
        std::string name = o.name;
        for (int k = 0; !used.insert(name).second; ++k) {
            name = o.name + "_" + std::to_string(i) + (k ? "_" + std::to_string(k) : "");
        }
        out.push_back(std::visit(
            Overloaded{[&](const LevelSetPtr& ls) { return renamedLevelSet(ls, name); },
                       [&](const AnalyticSphere& s) {
                           return voxelized(o, SphereShape{s.center, s.radius}, name, *this);
                       },
                       [&](const AnalyticBox& b) {
                           return voxelized(o, BoxShape{0.5 * (b.lo + b.hi), b.hi - b.lo, 0.0},
                                            name, *this);
                       }},
            o.shape));
    }
    return out;
}

// ---------------------------------------------------------------------------------------------
// BuildReport

uint64_t BuildReport::activeVoxels() const {
    uint64_t n = 0;
    for (const ObstacleBuild& o : obstacles) n += o.activeVoxels;
    return n;
}

uint64_t BuildReport::bytes() const {
    uint64_t n = 0;
    for (const ObstacleBuild& o : obstacles) n += o.bytes;
    return n;
}

std::string BuildReport::toText() const {
    std::ostringstream out;
    for (const ObstacleBuild& o : obstacles) {
        out << "obstacle " << inQuotes(o.name) << " (" << o.type << "): ";
        if (o.analytic) {
            out << "analytic, no level set\n";
            continue;
        }
        // Grids store their voxel size in single precision: print what the user wrote.
        char voxel[32];
        std::snprintf(voxel, sizeof voxel, "%.6g", o.voxelSize);
        out << grouped(o.activeVoxels) << " voxels, " << mebibytes(double(o.bytes)) << ", "
            << secondsText(o.seconds) << " (voxel " << voxel;
        if (o.estimatedBytes > 0.0) out << ", estimated " << mebibytes(o.estimatedBytes);
        if (!o.note.empty()) out << ", " << o.note;
        out << ")\n";
    }
    out << "level sets: " << grouped(activeVoxels()) << " voxels, " << mebibytes(double(bytes()))
        << " in " << secondsText(seconds) << " (estimate " << mebibytes(estimatedBytes)
        << ", limit " << bytesText(memoryLimitBytes);
    if (levelSetsShared > 0) out << "; " << levelSetsShared << " obstacle(s) shared with an earlier load";
    out << ")\n";
    return out.str();
}

std::string BuildReport::toJson() const {
    using Json = nlohmann::json;
    Json j;
    j["seconds"] = seconds;
    j["active_voxels"] = activeVoxels();
    j["bytes"] = bytes();
    j["estimated_bytes"] = estimatedBytes;
    j["memory_limit_bytes"] = memoryLimitBytes;
    for (const char* list : {"obstacles", "volumes"}) {
        j[list] = Json::array();
        for (const ObstacleBuild& o : list[0] == 'o' ? obstacles : volumes) {
            j[list].push_back({{"name", o.name},
                               {"type", o.type},
                               {"analytic", o.analytic},
                               {"voxel_size", o.voxelSize},
                               {"active_voxels", o.activeVoxels},
                               {"bytes", o.bytes},
                               {"estimated_bytes", o.estimatedBytes},
                               {"seconds", o.seconds},
                               {"shared", o.shared},
                               {"note", o.note}});
        }
    }
    j["level_sets_built"] = levelSetsBuilt;
    j["level_sets_shared"] = levelSetsShared;
    j["level_sets_from_cache"] = levelSetsFromCache;
    return j.dump();
}

// ---------------------------------------------------------------------------------------------
// LevelSetCache

LevelSetCache::LevelSetCache(std::string directory, Warn warn)
    : mDirectory(std::move(directory)), mWarn(std::move(warn)) {
    if (mDirectory.empty()) return;
    std::error_code ec;
    std::filesystem::create_directories(mDirectory, ec);
    if (!std::filesystem::is_directory(mDirectory, ec)) {
        throw InputError(mDirectory, "", "cannot use as a level-set cache directory: " +
                                             (ec ? ec.message() : std::string("not a directory")));
    }
}

std::string LevelSetCache::fileFor(const std::string& key) const {
    return (std::filesystem::path(mDirectory) / ("levelset-" + hex16(fnv1a64(key)) + ".vdb")).string();
}

LevelSetCache::Found LevelSetCache::find(const std::string& key) {
    {
        std::lock_guard<std::mutex> lock(mMutex);
        const auto it = mEntries.find(key);
        if (it != mEntries.end()) return {it->second.obstacles, ""};
    }
    if (mDirectory.empty()) return {};
    const std::string file = fileFor(key);
    std::error_code ec;
    if (!std::filesystem::exists(file, ec)) return {};
    CacheFileEntry read;
    try {
        read = readCacheFile(file, key);
    } catch (const std::exception& e) {
        if (mWarn) mWarn("ignoring level-set cache file '" + file + "': " + e.what() + "; rebuilding it");
        return {};
    }
    Entry entry;
    for (size_t i = 0; i < read.levelSets.size(); ++i) {
        Obstacle o;
        o.name = read.labels[i];
        o.shape = read.levelSets[i];
        entry.obstacles.push_back(std::move(o));
    }
    entry.farFieldsWritten = read.farFields;
    std::lock_guard<std::mutex> lock(mMutex);
    const auto it = mEntries.emplace(key, std::move(entry)).first;  // a concurrent load: keep the first
    return {it->second.obstacles, file};
}

void LevelSetCache::write(const std::string& key, Entry& entry) {
    CacheFileEntry out;
    for (const Obstacle& o : entry.obstacles) {
        const auto* ls = std::get_if<LevelSetPtr>(&o.shape);
        if (!ls || !*ls) return;  // only level sets are cached
        out.levelSets.push_back(*ls);
        out.labels.push_back(o.name);
        out.farFields += hasFarField(**ls) ? 1 : 0;
    }
    try {
        writeCacheFile(fileFor(key), key, out);
        entry.farFieldsWritten = out.farFields;
    } catch (const std::exception& e) {
        entry.farFieldsWritten = int(out.levelSets.size());  // do not try again
        if (mWarn) mWarn(std::string("cannot store a level set in the cache: ") + e.what());
    }
}

void LevelSetCache::insert(const std::string& key, std::vector<Obstacle> obstacles) {
    std::lock_guard<std::mutex> lock(mMutex);
    // A concurrent build of the same key: keep the first.
    const auto [it, added] = mEntries.emplace(key, Entry{std::move(obstacles), -1});
    if (added && !mDirectory.empty()) write(key, it->second);
}

void LevelSetCache::persist() {
    if (mDirectory.empty()) return;
    std::lock_guard<std::mutex> lock(mMutex);
    for (auto& [key, entry] : mEntries) {
        int built = 0;
        for (const Obstacle& o : entry.obstacles) {
            const auto* ls = std::get_if<LevelSetPtr>(&o.shape);
            built += ls && *ls && hasFarField(**ls) ? 1 : 0;
        }
        if (built > entry.farFieldsWritten) write(key, entry);
    }
}

size_t LevelSetCache::size() const {
    std::lock_guard<std::mutex> lock(mMutex);
    return mEntries.size();
}

}  // namespace penumbra
