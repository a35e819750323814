/// @file output_files.h
/// How a run writes files: every output is registered before any work, checked against every
/// other output and every input by its real location (symlinks and `..` resolved), written to a
/// hidden temporary next to it, and renamed over its target only when the whole run succeeded
/// (OutputSet::commit). A failed run changes nothing. Temporaries carry their owner (host and
/// process id), so that a later run removes those of dead processes and never a live one's.
#pragma once

#include <string>
#include <vector>

#include "penumbra/image_io.h"

namespace penumbra {

/// The real location of a path: absolute, with symlinks and `.` / `..` resolved as far as the
/// path exists (a file that does not exist yet resolves through its existing directories).
std::string resolvedPath(const std::string& path);

/// A hidden temporary next to `target`, unique per host, process and call:
/// DIR/.NAME.tmp-HOST-PID-N.EXT (the extension kept, so that writers pick the same format).
std::string temporaryPathFor(const std::string& target);

/// Whether a file name (without directory) is a temporary made by temporaryPathFor, and then
/// its owner's host and process id.
bool parseTemporaryName(const std::string& name, std::string& host, long& pid);

/// Removes the temporaries in `dir` (made by temporaryPathFor on this host) whose process has
/// ended; returns how many. Those of live processes, and of other hosts, are left alone.
int removeStaleTemporaries(const std::string& dir);

/// Writes `text` to `path` atomically (a temporary renamed over it); throws std::runtime_error
/// naming the path on failure, leaving the previous file.
void writeTextFileAtomically(const std::string& path, const std::string& text);

/// Writes `text` to `file` (a staged temporary); messages name `path`, the file it stands for.
void writeTextFile(const std::string& file, const std::string& text, const std::string& path);

struct RenderSettings;
/// The settings of a render as image attributes: "penumbra:KEY" for every key of
/// RenderSettings::toJson() (strings as they are, numbers and booleans as JSON writes them).
ImageMetadata settingsMetadata(const RenderSettings& settings);

/// Every file one run writes. Register inputs and outputs first (clashes throw InputError naming
/// the flag or field); write each output to stage(path); commit() renames them all at the end.
/// Destroyed without commit(), it removes what it staged.
class OutputSet {
public:
    OutputSet() = default;
    OutputSet(const OutputSet&) = delete;
    OutputSet& operator=(const OutputSet&) = delete;
    ~OutputSet();

    /// A file the run reads. `what` names it in messages ("the scene", "/obstacles/0/file of
    /// s.json"). Throws InputError (naming the output's flag) when an output is that file.
    void addInput(const std::string& path, const std::string& what);
    /// A file the run writes, named by `flag` ("-o", "--stats"). Throws InputError (naming
    /// `flag`) when it is the same file as another output or an input, is a directory, or its
    /// directory does not exist.
    void addOutput(const std::string& path, const std::string& flag);
    /// The temporary to write for a registered output (made on first call; unique).
    std::string stage(const std::string& path);
    /// Renames every staged temporary over its target. An output registered but never staged
    /// is left as it is.
    void commit();
    /// Removes the staged temporaries (the destructor does it too).
    void discard();

private:
    struct Entry {
        std::string path, real, what;
        bool output = false;
        std::string temporary;
    };
    Entry* find(const std::string& path);
    std::vector<Entry> mEntries;
};

}  // namespace penumbra
