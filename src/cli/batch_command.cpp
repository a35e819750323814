// `penumbra batch MANIFEST.json [--jobs N] [--shard I/N] [--shard-count N] [--resume]
// [--summary FILE.csv|.json] [--cache DIR] [--list] [--status] [--quiet]`: runs a batch manifest (docs/batch.md) with
// the library's batch runner, reports progress on stderr, failed jobs as they happen, and a
// summary. Exit codes: 0 every selected job rendered or skipped, 1 at least one job failed,
// 2 bad options or manifest, clashing files, or another run of the same manifest (and shard)
// holding its lock (nothing was run).
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <cstdio>
#include <iostream>
#include <memory>
#include <string>

#include "cli/commands.h"
#include "penumbra/batch.h"
#include "penumbra/error.h"

namespace penumbra::cli {

namespace {

struct BatchCommandOptions {
    std::string manifest;
    int jobs = 0;
    std::string shard;
    int shardCount = 0;
    bool resume = false;
    std::string summary;
    std::string cache;
    bool list = false;
    bool status = false;
    bool quiet = false;
    const CLI::App* command = nullptr;
    bool given(const char* flag) const { return command && command->count(flag) > 0; }
};

// One line for the whole batch: jobs finished / selected, failures, elapsed time and an
// estimate of the time left. Rewritten in place on a terminal; in a log, a line every 5 s.
class BatchReporter {
public:
    explicit BatchReporter(bool enabled) : mEnabled(enabled), mTty(::isatty(2) != 0) {}

    void update(const BatchProgressInfo& p) {
        if (!mEnabled) return;
        const bool last = p.finished == p.total;
        if (!last && p.seconds - mLast < (mTty ? 0.25 : 5.0)) return;
        if (!last && p.seconds < 1.0) return;
        mLast = p.seconds;
        // Skipped jobs cost nothing, so the rate is measured on the jobs that did work,
        // counting the rows done of those still running.
        const double worked = double(p.rendered + p.failed) + p.runningFraction;
        const double left = double(p.total - p.finished) - p.runningFraction;
        char eta[48] = "";
        if (!last && worked > 0.0) {
            std::snprintf(eta, sizeof eta, ", ~%.0f s left", p.seconds * left / worked);
        }
        char line[200];
        std::snprintf(line, sizeof line,
                      "batch: %zu/%zu jobs (%zu rendered, %zu skipped, %zu failed), %.1f s%s",
                      p.finished, p.total, p.rendered, p.skipped, p.failed, p.seconds, eta);
        std::cerr << (mTty ? "\r" : "") << line << (mTty ? "\x1b[K" : "\n") << std::flush;
        mPrinted = true;
    }

    // A message on its own line, also when a progress line is being rewritten.
    void message(const std::string& text) {
        if (mTty && mPrinted) std::cerr << "\r\x1b[K";
        std::cerr << text << "\n" << std::flush;
    }

    void finish() {
        if (mEnabled && mPrinted && mTty) std::cerr << "\n" << std::flush;
    }

private:
    bool mEnabled, mTty;
    bool mPrinted = false;
    double mLast = -1e9;
};

Shard chooseShard(const BatchCommandOptions& o) {
    if (o.given("--shard-count") && (o.shardCount < 1 || o.shardCount > 1000000)) {
        throw InputError("", "--shard-count",
                         "must be in [1, 1000000], got " + std::to_string(o.shardCount));
    }
    if (!o.shard.empty()) {
        const Shard s = parseShard(o.shard, "--shard");
        if (o.given("--shard-count") && o.shardCount != s.count) {
            throw InputError("", "--shard-count",
                             std::to_string(o.shardCount) + " contradicts --shard " + o.shard);
        }
        return s;
    }
    if (std::optional<Shard> s = shardFromEnvironment(o.shardCount)) return *s;
    if (o.given("--shard-count")) {
        throw InputError("", "--shard-count",
                         "needs a shard index: --shard I/N, SLURM_ARRAY_TASK_ID or "
                         "JOB_COMPLETION_INDEX");
    }
    return {};
}

// Seconds per finished job as a text plot, through gnuplot's dumb terminal when gnuplot is on
// the PATH (nothing otherwise).
void plotSeconds(const std::vector<JobRecord>& records) {
    std::string data;
    size_t last = 0;
    for (const JobRecord& r : records) {
        last = std::max(last, r.job);
        if (r.state == JobState::Done) data += std::to_string(r.job) + " " + std::to_string(r.seconds) + "\n";
    }
    if (data.empty() || std::system("command -v gnuplot >/dev/null 2>&1") != 0) return;
    std::fflush(stdout);
    FILE* gp = ::popen("gnuplot 2>/dev/null", "w");
    if (!gp) return;
    std::fprintf(gp,
                 "set terminal dumb size 79,20\nset title 'render seconds per job'\n"
                 "set xlabel 'job'\nset key off\nset xrange [-0.5:%zu.5]\nset yrange [0:*]\n"
                 "plot '-' using 1:2 with impulses\n%se\n",
                 last, data.c_str());
    ::pclose(gp);
}

// `--status`: what the files of every shard say, without running or locking anything.
int printStatus(const BatchCommandOptions& o, const BatchManifest& manifest, const Shard& shard,
                const std::vector<size_t>& selected) {
    const std::vector<JobRecord> records = readJobRecords(manifest, selected);
    // With a shard count (--shard-count, or the environment) the table says which shard owns
    // each job; --shard I/N restricts it to that shard.
    const int count = shard.count > 1 ? shard.count : std::max(1, o.shardCount);
    size_t counts[3] = {0, 0, 0};
    if (!o.quiet) std::printf("index\tshard\tstatus\tseconds\tshadow_rays\tname\n");
    for (const JobRecord& r : records) {
        ++counts[int(r.state)];
        if (o.quiet) continue;
        std::printf("%zu\t%zu/%d\t%s\t%.3f\t%llu\t%s\n", r.job, r.job % size_t(count), count,
                    jobStateName(r.state), r.seconds, static_cast<unsigned long long>(r.shadowRays),
                    manifest.jobs[r.job].name.c_str());
    }
    if (!o.quiet && count > 1) {
        for (int k = 0; k < count; ++k) {
            size_t c[3] = {0, 0, 0};
            for (const JobRecord& r : records)
                if (int(r.job % size_t(count)) == k) ++c[int(r.state)];
            if (c[0] + c[1] + c[2] == 0) continue;
            std::printf("shard %d/%d: %zu done, %zu failed, %zu missing\n", k, count, c[0], c[1], c[2]);
        }
    }
    if (!o.quiet) plotSeconds(records);
    std::printf("penumbra: batch %s: %zu jobs: %zu done, %zu failed, %zu missing\n",
                o.manifest.c_str(), records.size(), counts[int(JobState::Done)],
                counts[int(JobState::Failed)], counts[int(JobState::Missing)]);
    for (const JobRecord& r : records) {
        if (r.state != JobState::Failed) continue;
        std::printf("failed: job %zu '%s'%s: %s\n", r.job, manifest.jobs[r.job].name.c_str(),
                    r.host.empty() ? "" : (" on " + r.host).c_str(), r.error.c_str());
    }
    return counts[int(JobState::Done)] == records.size() ? 0 : 1;
}

int runBatchCommand(const BatchCommandOptions& o) {
    // Everything that can be refused is refused before the first job starts.
    if (o.given("--jobs") && (o.jobs < 1 || o.jobs > 1024)) {
        throw InputError("", "--jobs", "must be in [1, 1024], got " + std::to_string(o.jobs));
    }
    if (!o.summary.empty()) checkSummaryPath(o.summary, "--summary");
    if (o.status && (o.list || o.resume || !o.summary.empty() || !o.cache.empty())) {
        throw InputError("", "--status", "reads the records only: it takes no --list, --resume, "
                                         "--summary or --cache");
    }
    // --status alone reads every job; --shard-count alone (no index) is allowed there.
    const Shard shard = o.status && o.shard.empty() ? Shard{} : chooseShard(o);
    const BatchManifest manifest = loadManifest(o.manifest);
    const std::vector<size_t> selected = shardJobs(manifest.jobs.size(), shard);
    if (o.status) return printStatus(o, manifest, shard, selected);

    if (o.list) {
        for (size_t i : selected) {
            const BatchJob& job = manifest.jobs[i];
            std::printf("%zu\t%s\t%s\n", i, job.name.c_str(), job.output.c_str());
        }
        return 0;
    }

    // One run of a manifest (or of one shard of it) at a time: a second one refuses rather than
    // waits (docs/batch.md). Held until this function returns.
    std::string lockWarning;
    const BatchLock lock = lockBatchManifest(o.manifest, shard, &lockWarning);
    if (!lockWarning.empty() && !o.quiet) {
        std::cerr << "penumbra: warning: " << lockWarning << "\n";
    }

    BatchReporter reporter(!o.quiet);
    BatchCallbacks callbacks;
    callbacks.progress = [&](const BatchProgressInfo& p) { reporter.update(p); };
    callbacks.warning = [&](const std::string& text) {
        if (!o.quiet) reporter.message("penumbra: warning: " + text);
    };
    callbacks.jobDone = [&](const BatchJob& job, const JobResult& r) {
        // Failures are reported even with --quiet: they are errors, not progress.
        if (r.status == JobStatus::Failed) {
            reporter.message("penumbra: batch: job " + std::to_string(r.job) + " '" + job.name +
                             "' failed: " + r.error);
        }
    };
    BatchOptions options;
    options.threads = o.jobs;
    options.resume = o.resume;
    options.summary = o.summary;  // checked against the batch's files before any job runs
    options.cacheDir = o.cache;
    const auto start = std::chrono::steady_clock::now();
    const std::vector<JobResult> results = runBatch(manifest, selected, options, callbacks);
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    reporter.finish();

    size_t rendered = 0, skipped = 0, failed = 0;
    std::string failedNames;
    for (const JobResult& r : results) {
        if (r.status == JobStatus::Rendered) ++rendered;
        if (r.status == JobStatus::Skipped) ++skipped;
        if (r.status == JobStatus::Failed) {
            if (++failed <= 10) {
                failedNames += (failed > 1 ? ", " : "") + manifest.jobs[r.job].name;
            } else if (failed == 11) {
                failedNames += ", ...";
            }
        }
    }
    if (!o.summary.empty()) writeBatchSummary(o.summary, manifest, shard, results, seconds);
    if (!o.quiet) {
        std::printf("penumbra: batch %s, shard %d/%d: %zu of %zu jobs: %zu rendered, "
                    "%zu skipped, %zu failed in %.2f s\n",
                    o.manifest.c_str(), shard.index, shard.count, selected.size(),
                    manifest.jobs.size(), rendered, skipped, failed, seconds);
    }
    if (failed > 0) {
        std::cerr << "penumbra: error: " << failed << " of " << selected.size()
                  << " jobs failed: " << failedNames << "\n";
        return 1;
    }
    return 0;
}

}  // namespace

Runner addBatchCommand(CLI::App& app) {
    auto o = std::make_shared<BatchCommandOptions>();
    CLI::App* cmd = app.add_subcommand(
        "batch", "Render the jobs and sweeps of a manifest (docs/batch.md), on this machine or "
                 "as one shard of a cluster array job");
    cmd->add_option("manifest", o->manifest, "Batch manifest (JSON)")->required();
    cmd->add_option("--jobs", o->jobs,
                    "Worker threads shared by all jobs and their pixels (default: every "
                    "hardware thread)");
    cmd->add_option("--shard", o->shard,
                    "Run shard I of N (I from 0): the jobs whose index is I mod N");
    cmd->add_option("--shard-count", o->shardCount,
                    "Number of shards when the index comes from SLURM_ARRAY_TASK_ID or "
                    "JOB_COMPLETION_INDEX");
    cmd->add_flag("--resume", o->resume,
                  "Skip jobs whose output already exists with the same settings");
    cmd->add_option("--summary", o->summary, "Per-job summary: .csv or .json");
    cmd->add_option("--cache", o->cache,
                    "Level-set cache directory shared by runs and shards (created when "
                    "missing; overrides the manifest's \"cache\")");
    cmd->add_flag("--list", o->list, "Print the jobs of this shard (index, name, output) and exit");
    cmd->add_flag("--status", o->status,
                  "Report every job's state from the files of all shards (done, failed with its "
                  "error, missing) and exit: 0 when all are done, 1 otherwise");
    cmd->add_flag("-q,--quiet", o->quiet, "No progress or summary line (failures still print)");
    o->command = cmd;
    return [o]() { return runBatchCommand(*o); };
}

}  // namespace penumbra::cli
