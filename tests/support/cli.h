// The test harness for running the real `penumbra` program (PENUMBRA_BINARY, set by CMake) as a
// user would, and for the scratch directories and files such tests need. Shared by the CLI
// tests (probe, bake, compare, batch).
#pragma once

#include <catch2/catch.hpp>

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

extern char** environ;

namespace test {

namespace fs = std::filesystem;

inline std::string readFile(const fs::path& p) {
    std::ifstream f(p, std::ios::binary);
    std::stringstream ss;
    ss << f.rdbuf();
    return ss.str();
}

inline void writeFile(const fs::path& p, const std::string& text) {
    std::ofstream(p, std::ios::binary) << text;
}

/// A fresh directory under the system's temporary directory, unique per test process, made
/// empty on creation (it is left for inspection after the test).
inline fs::path makeTempDir(const std::string& prefix, const std::string& name) {
    const fs::path dir = fs::temp_directory_path() /
                         ("penumbra_" + prefix + "_" + name + "_" + std::to_string(::getpid()));
    fs::remove_all(dir);
    fs::create_directories(dir);
    return dir;
}

struct Run {
    int exitCode = -1;
    std::string out, err;
};

/// Runs a shell command line with `input` on stdin, in the current directory; stdout is
/// returned, stderr is read back from DIR/stderr.txt.
inline Run runShell(const std::string& command, const fs::path& dir,
                    const std::string& input = "") {
    const fs::path in = dir / "stdin.txt", err = dir / "stderr.txt";
    writeFile(in, input);
    const std::string cmd = command + " < '" + in.string() + "' 2> '" + err.string() + "'";
    FILE* pipe = popen(cmd.c_str(), "r");
    REQUIRE(pipe);
    std::string out;
    char buf[4096];
    size_t n;
    while ((n = fread(buf, 1, sizeof buf, pipe)) > 0) out.append(buf, n);
    const int status = pclose(pipe);
    return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, out, readFile(err)};
}

/// Runs `penumbra ARGS` (ARGS as the shell would split them).
inline Run runPenumbra(const std::string& args, const fs::path& dir,
                       const std::string& input = "") {
    return runShell(std::string(PENUMBRA_BINARY) + " " + args, dir, input);
}

/// A test's directory (makeTempDir), removed at the end of the test unless
/// PENUMBRA_KEEP_TEST_DIRS is set.
struct TempDir {
    fs::path path;
    explicit TempDir(const std::string& name, const std::string& prefix = "batch")
        : path(makeTempDir(prefix, name)) {}
    TempDir(const TempDir&) = delete;
    TempDir& operator=(const TempDir&) = delete;
    ~TempDir() {
        if (std::getenv("PENUMBRA_KEEP_TEST_DIRS")) return;
        std::error_code ec;
        fs::remove_all(path, ec);
    }
};

// Starts the program with extra environment variables; stdout and stderr go to files in `dir`.
inline pid_t spawnPenumbra(const std::vector<std::string>& args, const fs::path& dir,
                    const std::string& tag,
                    const std::vector<std::string>& extraEnv = {}) {
    std::vector<std::string> argvStore = {PENUMBRA_BINARY};
    argvStore.insert(argvStore.end(), args.begin(), args.end());
    std::vector<char*> argv;
    for (std::string& a : argvStore) argv.push_back(a.data());
    argv.push_back(nullptr);
    // The test itself may run inside a Slurm array task: drop variables that select a shard.
    std::vector<std::string> envStore;
    for (char** e = environ; *e; ++e) {
        const std::string v(*e);
        if (v.rfind("SLURM_ARRAY_", 0) == 0 || v.rfind("JOB_COMPLETION_INDEX=", 0) == 0 ||
            v.rfind("PENUMBRA_SHARD_COUNT=", 0) == 0) {
            continue;
        }
        envStore.push_back(v);
    }
    envStore.insert(envStore.end(), extraEnv.begin(), extraEnv.end());
    std::vector<char*> envp;
    for (std::string& e : envStore) envp.push_back(e.data());
    envp.push_back(nullptr);

    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    const std::string out = (dir / (tag + ".out")).string();
    const std::string err = (dir / (tag + ".err")).string();
    posix_spawn_file_actions_addopen(&actions, 1, out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_addopen(&actions, 2, err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    pid_t pid = -1;
    const int rc = posix_spawn(&pid, argv[0], &actions, nullptr, argv.data(), envp.data());
    posix_spawn_file_actions_destroy(&actions);
    REQUIRE(rc == 0);
    return pid;
}

inline int waitExit(pid_t pid) {
    int status = 0;
    REQUIRE(waitpid(pid, &status, 0) == pid);
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

inline int runPenumbraSpawned(const std::vector<std::string>& args, const fs::path& dir,
                              const std::string& tag,
                              const std::vector<std::string>& extraEnv = {}) {
    return waitExit(spawnPenumbra(args, dir, tag, extraEnv));
}


}  // namespace test
