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
///   and the others go on. Before any job runs, every file the batch writes (outputs, sidecars,
///   statistics, the summary) is resolved to its real location (output_files.h) and checked
///   against every other and against every file the batch reads (the manifest, the scenes, the
///   `.vdb` / `.obj` files they name): a clash is an InputError naming the manifest and the
///   JSON pointer of the job's field (checkBatchFiles).
/// - Each job's files are staged under temporaryPathFor names and renamed together, statistics
///   first, then the sidecar `OUT.job.json`, the image last. The image carries the hash of the
///   job's resolved settings (`penumbra:job_hash`); the sidecar records the same hash and the
///   image file's size and content hash (FNV-1a 64 of its bytes). With `resume`, a job is
///   skipped only when its output carries the job's hash AND its size and content hash match
///   the sidecar: a truncated or altered output is rendered again. A run killed at any moment
///   and started again loses no job and renders none twice.
/// - Two runs of one manifest coordinate through a lock file next to it (lockBatchManifest):
///   the second refuses to start.
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

#include "penumbra/hash.h"
#include "penumbra/renderer.h"

namespace penumbra {

/// One render of a batch, fully resolved from the manifest.
struct BatchJob {
    std::string name;    ///< for messages: the manifest's "name", else the output as written
    std::string origin;  ///< where it came from: "/jobs/3", "/sweep frame 12", "/sweep/1 frame 0"
    std::string pointer;  ///< JSON pointer of the job or sweep in the manifest: "/jobs/3", "/sweep/1"
    long frame = -1;      ///< the frame number of a sweep's job; -1 for an explicit job
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
    std::string path;  ///< the manifest file as read by loadManifest ("" when parsed from text)
    /// The manifest's "cache": a level-set cache directory (LevelSetCache), resolved; "" none.
    std::string cache;
    std::vector<BatchJob> jobs;
};

/// Reads and validates a manifest; throws InputError (manifest file, JSON pointer, message).
/// Two jobs that write one file (outputs, sidecars, `stats`; compared by real location, so
/// `a.exr`, `./a.exr`, `link/a.exr` through a symlink and an absolute path are one file) are
/// refused naming the later job's field (`/jobs/1/output`, `/sweep/stats`).
BatchManifest loadManifest(const std::string& path);
/// Same from text; `file` is used in messages and `baseDir` resolves relative paths.
BatchManifest parseManifest(const std::string& jsonText, const std::string& file,
                            const std::string& baseDir);

/// Checks every file the batch writes against every file it reads, before anything runs: a
/// job's output, sidecar or statistics file must not be the manifest, a scene file of any job,
/// or a file a scene names (`file` of a `.vdb` or mesh obstacle, with the job's overrides
/// applied), and no two jobs may write one file; `summary` (may be empty) must be none of
/// these either. Paths are compared by real location (resolvedPath) and, for existing files,
/// by identity (hard links). Throws InputError naming the manifest and the pointer of the
/// offending job field (`/jobs/0/stats`), or `summaryFlag` for the summary. Scene files that
/// cannot be read are skipped here (their jobs fail when run). runBatch calls it.
void checkBatchFiles(const BatchManifest& manifest, const std::string& summary = "",
                     const std::string& summaryFlag = "--summary");

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

/// The record a failed job leaves next to its output, OUT + ".failed.json" (its error, host and
/// settings hash); removed when the job is later rendered or found done.
std::string failureRecordPath(const std::string& output);

/// What the files on disk say about a job, whichever run or shard made them (`batch --status`):
/// done (its output verified as resume does), failed (a failure record for its current settings,
/// or for a scene that still cannot be read) or missing (neither: not run yet, still running,
/// killed, or its settings changed since).
enum class JobState { Done, Failed, Missing };
const char* jobStateName(JobState state);  ///< "done", "failed", "missing"

struct JobRecord {
    size_t job = 0;  ///< position in BatchManifest::jobs
    JobState state = JobState::Missing;
    std::string error;        ///< failed: the recorded one-line error
    std::string host;         ///< failed: the host it failed on
    double seconds = 0.0;     ///< done: the render's seconds (sidecar); failed: the attempt's
    uint64_t shadowRays = 0;  ///< done: from the sidecar
};

/// The records of the jobs at positions `selected`, in that order. Reads only (takes no lock):
/// safe while shards run.
std::vector<JobRecord> readJobRecords(const BatchManifest& manifest,
                                      const std::vector<size_t>& selected);

// digestFile() (hash.h) gives what a sidecar records of its output and what resume compares
// (`output_bytes`, `output_hash`).

// ---------------------------------------------------------------------------------------------
// One run at a time

class BatchLock;

/// Takes the lock of `manifestPath` for `shard` without waiting. Throws InputError naming the
/// manifest (and the process that holds the lock, from the lock file) when another run holds
/// it. When locking is impossible (a read-only directory, a file system without locks), returns
/// a lock that is not held and sets `*warning` (if given) to a one-line reason.
BatchLock lockBatchManifest(const std::string& manifestPath, const Shard& shard,
                            std::string* warning = nullptr);

/// A lock on a manifest held for a whole run (flock(2), released when destroyed or when the
/// process ends, also by SIGKILL). The whole batch (shard 0/1) takes `.MANIFEST.lock` next to
/// the manifest exclusively; shard I of N (N > 1) takes it shared and
/// `.MANIFEST.shard-I-of-N.lock` exclusively (that file is removed when released), so the
/// shards of one count run side by side while a second run of the same shard, or of the whole
/// batch, is refused. Runs of one manifest with different shard counts are not detected.
class BatchLock {
public:
    BatchLock() = default;
    BatchLock(BatchLock&& other) noexcept;
    BatchLock& operator=(BatchLock&& other) noexcept;
    BatchLock(const BatchLock&) = delete;
    BatchLock& operator=(const BatchLock&) = delete;
    ~BatchLock();

    bool held() const { return mMainFd >= 0; }
    const std::string& path() const { return mMainPath; }  ///< the manifest's lock file
    void release();

private:
    friend BatchLock lockBatchManifest(const std::string&, const Shard&, std::string*);
    int mMainFd = -1, mShardFd = -1;
    bool mExclusive = false;
    std::string mMainPath, mShardPath;
};

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
    /// Obstacles whose level sets this job built (or read), and those it took from an earlier
    /// job of the same scene (the batch shares them while jobs of that scene remain).
    int levelSetsBuilt = 0, levelSetsShared = 0;
    int levelSetsFromCache = 0;  ///< obstacles whose level sets it read from the cache directory
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
    bool resume = false;  ///< skip jobs whose output exists, verified (hash, size, content)
    /// The summary the caller writes after the run (--summary), "" for none: checked with the
    /// batch's files before any job runs (checkBatchFiles), and its directory's stale
    /// temporaries removed. runBatch does not write it.
    std::string summary;
    /// Level-set cache directory shared by runs and shards (`--cache`); "" takes the
    /// manifest's "cache", if any.
    std::string cacheDir;
};

struct BatchCallbacks {
    /// After each finished job (any status).
    std::function<void(const BatchJob&, const JobResult&)> jobDone;
    /// After a job finishes and after rows are rendered; may be frequent, must be quick.
    std::function<void(const BatchProgressInfo&)> progress;
    /// A one-line warning (an unusable level-set cache file, say); called from job threads,
    /// one at a time.
    std::function<void(const std::string&)> warning;
};

/// Runs the jobs at positions `selected` (e.g. from shardJobs) and returns one result per
/// selected job, in the order of `selected`. First checks the batch's files (checkBatchFiles)
/// and removes, in the directories of the selected outputs, the temporaries left by dead
/// processes on this host (removeStaleTemporaries: a live run's are never touched). Never
/// throws for a job's failure; throws InputError for bad options (`threads` out of [0, 1024], a
/// position out of range) and for clashing files. It takes no lock: lockBatchManifest does.
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
