/// @file batch.h
/// Batches of renders described by one JSON manifest (docs/batch.md): explicit jobs and sweeps
/// that interpolate scene values over frames, each job a scene file, JSON-pointer overrides of
/// that scene, render settings and an output image.
///
/// - Parsing (loadManifest/parseManifest) validates the whole manifest before anything runs and
///   throws InputError naming the manifest and the JSON pointer of the bad value. Paths in a
///   manifest are relative to the manifest's directory.
/// - Sharding (shardJobs) splits the jobs for a cluster: job i goes to shard i mod N.
/// - runBatch() renders the selected jobs in one TBB task arena shared by the jobs and their
///   pixels. A job that fails (bad scene, missing file, write error) is recorded with its error
///   and the others go on. Each output is written atomically (image_io) and carries the hash of
///   the job's resolved settings in its metadata (`penumbra:job_hash`); a sidecar `OUT.job.json`
///   with the same hash and the job's counts is written next to it afterwards. With `resume`,
///   a job whose output carries the same hash is skipped, so a run killed at any moment and
///   started again loses no job and renders none twice.
///
/// The library prints nothing: progress and per-job outcomes go to callbacks.
/// Thread safety: runBatch() may be called from any thread; its callbacks are serialized.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "penumbra/renderer.h"

namespace penumbra {

/// One render of a batch, fully resolved from the manifest.
struct BatchJob {
    std::string name;    ///< for messages: the manifest's "name", else the output as written
    std::string origin;  ///< where it came from: "/jobs/3", "/sweep frame 12", "/sweep/1 frame 0"
    std::string scene;   ///< scene file, resolved against the manifest's directory
    std::string output;  ///< .exr or .png, resolved
    std::string stats;   ///< statistics JSON to write too ("" for none), resolved
    /// Scene overrides applied in this order: RFC 6901 pointer ("/lights/0/corner") and the
    /// value as JSON text ("[0,0,4]").
    std::vector<std::pair<std::string, std::string>> overrides;
    RenderSettings settings;  ///< `threads` is ignored: runBatch shares its arena
};

struct BatchManifest {
    std::string file;  ///< the manifest's path, for messages
    std::vector<BatchJob> jobs;
};

/// Reads and validates a manifest; throws InputError (manifest file, JSON pointer, message).
BatchManifest loadManifest(const std::string& path);
/// Same from text; `file` is used in messages and `baseDir` resolves relative paths.
BatchManifest parseManifest(const std::string& jsonText, const std::string& file,
                            const std::string& baseDir);

/// Replaces `{frame}` and `{frame:0Nd}` / `{frame:Nd}` (N in 1-9: printf's width, zero-padded
/// or not) in an output template. Throws InputError(file, where) for any other `{...}`.
std::string expandFrameTemplate(const std::string& pattern, long frame, const std::string& file,
                                const std::string& where);

// ---------------------------------------------------------------------------------------------
// Sharding

/// Shard `index` of `count`, 0 <= index < count.
struct Shard {
    int index = 0;
    int count = 1;
};

/// Parses "I/N" (0 <= I < N <= 1000000); throws InputError naming `flag`.
Shard parseShard(const std::string& text, const std::string& flag = "--shard");

/// The shard chosen by the environment, or none when no array-job variable is set.
/// - Slurm job arrays: SLURM_ARRAY_TASK_ID, minus SLURM_ARRAY_TASK_MIN (0 when unset), divided
///   by SLURM_ARRAY_TASK_STEP (1 when unset); the count is SLURM_ARRAY_TASK_COUNT. An array
///   that is not one range (SLURM_ARRAY_TASK_MAX says so, e.g. --array=3,5) is refused.
/// - Kubernetes Indexed Jobs: JOB_COMPLETION_INDEX; the count is PENUMBRA_SHARD_COUNT
///   (Kubernetes does not export the number of completions).
/// `countOverride` > 0 (the --shard-count flag) replaces the environment's count. Slurm wins
/// when both are set. Throws InputError when a variable is malformed or the index falls
/// outside [0, count), or when an index has no count. `getEnv` defaults to std::getenv.
std::optional<Shard> shardFromEnvironment(
    int countOverride = 0,
    const std::function<const char*(const char*)>& getEnv = {});

/// Positions (ascending) of the jobs of `shard` among `jobCount` jobs: every i with
/// i mod count == index. The shards of one count partition [0, jobCount) and their sizes
/// differ by at most one; interleaving spreads a sweep's cheap and costly frames evenly.
std::vector<size_t> shardJobs(size_t jobCount, const Shard& shard);

// ---------------------------------------------------------------------------------------------
// Resolving and recording a job

/// The scene text a job renders: the scene file with the job's overrides applied (the file's
/// own text when there are none). Throws InputError naming the scene file and the pointer of an
/// override that cannot be applied (its parent does not exist), or the file when unreadable.
std::string resolveSceneText(const BatchJob& job);

/// Applies overrides to scene JSON text: each pointer's value is replaced; a missing key of an
/// existing object is added; "-" as the last token of an array appends. Throws InputError
/// naming `file` and the pointer when the parent does not exist or the text is not JSON.
std::string applyOverrides(const std::string& sceneText,
                           const std::vector<std::pair<std::string, std::string>>& overrides,
                           const std::string& file);

/// Hex digest (16 digits, FNV-1a 64) of everything that determines a job's pixels: the resolved
/// scene text, the method and the render settings. Not cryptographic: it detects changes.
std::string jobHash(const BatchJob& job, const std::string& resolvedSceneText);

/// The sidecar record written next to an output: OUT + ".job.json".
std::string sidecarPath(const std::string& output);

// ---------------------------------------------------------------------------------------------
// Running

enum class JobStatus { Rendered, Skipped, Failed };
const char* jobStatusName(JobStatus status);  ///< "rendered", "skipped", "failed"

struct JobResult {
    size_t job = 0;  ///< position in BatchManifest::jobs
    JobStatus status = JobStatus::Failed;
    std::string error;        ///< one line, for failed jobs
    double seconds = 0.0;     ///< this run's wall time: load, render, write (0 if skipped)
    uint64_t shadowRays = 0;  ///< of the render that made the output (read back when skipped)
};

struct BatchProgressInfo {
    size_t total = 0;     ///< jobs selected
    size_t finished = 0;  ///< rendered + skipped + failed
    size_t rendered = 0, skipped = 0, failed = 0;
    double runningFraction = 0.0;  ///< sum over running jobs of their rows done / rows
    double seconds = 0.0;          ///< since runBatch started
};

struct BatchOptions {
    int threads = 0;      ///< arena size shared by all jobs and pixels; 0: every hardware thread
    bool resume = false;  ///< skip jobs whose output exists with the same job hash
};

struct BatchCallbacks {
    /// After each finished job (any status).
    std::function<void(const BatchJob&, const JobResult&)> jobDone;
    /// After a job finishes and after rows are rendered; may be frequent, must be quick.
    std::function<void(const BatchProgressInfo&)> progress;
};

/// Runs the jobs at positions `selected` (e.g. from shardJobs) and returns one result per
/// selected job, in the order of `selected`. Stale temporary files of the selected outputs left
/// by a killed run are removed first. Never throws for a job's failure; throws InputError only
/// for bad options (`threads` out of [0, 1024], a position out of range).
std::vector<JobResult> runBatch(const BatchManifest& manifest,
                                const std::vector<size_t>& selected, const BatchOptions& options,
                                const BatchCallbacks& callbacks = {});

/// Per-job summary: CSV (header `index,name,status,error,seconds,shadow_rays,output,scene`) or
/// JSON (object with `manifest`, `shard`, counts and a `jobs` array), chosen by the extension
/// of `path` (.csv or .json; InputError naming `flag` otherwise). Written atomically.
void writeBatchSummary(const std::string& path, const BatchManifest& manifest, const Shard& shard,
                       const std::vector<JobResult>& results, double seconds,
                       const std::string& flag = "--summary");
/// Checks the summary's extension without writing (InputError naming `flag`).
void checkSummaryPath(const std::string& path, const std::string& flag = "--summary");

}  // namespace penumbra
