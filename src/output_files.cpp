#include "penumbra/output_files.h"

#include <nlohmann/json.hpp>
#include "penumbra/render_settings.h"

#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <system_error>
#include <vector>
#include <cstdio>

#include <nlohmann/json.hpp>

#include "penumbra/render_settings.h"

#include "penumbra/error.h"
#include "penumbra/hash.h"

namespace penumbra {

namespace fs = std::filesystem;

namespace {

// This host's name with every character but letters, digits and '_' replaced by '_', so that a
// temporary's name splits unambiguously at its dashes.
const std::string& hostTag() {
    static const std::string tag = [] {
        char buf[256] = {};
        if (::gethostname(buf, sizeof(buf) - 1) != 0 || buf[0] == '\0') return std::string("host");
        std::string s(buf);
        for (char& c : s) {
            if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_')) c = '_';
        }
        return s;
    }();
    return tag;
}

std::string extensionOf(const std::string& name) {
    const size_t dot = name.find_last_of('.');
    if (dot == std::string::npos || dot == 0) return "";
    return name.substr(dot);
}

bool processAlive(long pid) {
    if (pid <= 0) return false;
    if (::kill(static_cast<pid_t>(pid), 0) == 0) return true;
    return errno != ESRCH;  // EPERM: it exists, owned by someone else
}

}  // namespace

std::string resolvedPath(const std::string& path) {
    std::error_code ec;
    fs::path p = fs::absolute(fs::path(path), ec);
    if (ec) p = fs::path(path);
    fs::path r = fs::weakly_canonical(p, ec);
    return (ec ? p.lexically_normal() : r).string();
}

std::string temporaryPathFor(const std::string& target) {
    static std::atomic<unsigned> counter{0};
    const fs::path p(target);
    const std::string name = p.filename().string();
    const std::string tmp = "." + name + ".tmp-" + hostTag() + "-" + std::to_string(::getpid()) +
                            "-" + std::to_string(counter++) + extensionOf(name);
    return (p.parent_path() / tmp).string();
}

bool parseTemporaryName(const std::string& name, std::string& host, long& pid) {
    if (name.empty() || name[0] != '.') return false;
    const size_t at = name.rfind(".tmp-");
    if (at == std::string::npos || at == 0) return false;
    const std::string rest = name.substr(at + 5);  // HOST-PID-N[.EXT]
    const size_t d1 = rest.find('-');
    if (d1 == std::string::npos || d1 == 0) return false;
    const size_t d2 = rest.find('-', d1 + 1);
    if (d2 == std::string::npos || d2 == d1 + 1) return false;
    const std::string pidText = rest.substr(d1 + 1, d2 - d1 - 1);
    if (!std::all_of(pidText.begin(), pidText.end(), [](char c) { return c >= '0' && c <= '9'; }))
        return false;
    if (pidText.size() > 9) return false;
    host = rest.substr(0, d1);
    pid = std::stol(pidText);
    return true;
}

int removeStaleTemporaries(const std::string& dir) {
    std::error_code ec;
    int removed = 0;
    for (fs::directory_iterator it(dir.empty() ? "." : dir, ec), end; !ec && it != end;
         it.increment(ec)) {
        std::string host;
        long pid = 0;
        if (!parseTemporaryName(it->path().filename().string(), host, pid)) continue;
        if (host != hostTag() || processAlive(pid)) continue;
        std::error_code rm;
        if (fs::remove(it->path(), rm)) ++removed;
    }
    return removed;
}

void writeTextFile(const std::string& file, const std::string& text, const std::string& path) {
    std::ofstream out(file, std::ios::binary | std::ios::trunc);
    if (out) out << text;
    if (!out || !out.flush()) {
        const int err = errno;
        std::remove(file.c_str());
        throw std::runtime_error("cannot write '" + path + "': " + std::strerror(err));
    }
}

void writeTextFileAtomically(const std::string& path, const std::string& text) {
    const std::string tmp = temporaryPathFor(path);
    writeTextFile(tmp, text, path);
    if (std::rename(tmp.c_str(), path.c_str()) != 0) {
        const int err = errno;
        std::remove(tmp.c_str());
        throw std::runtime_error("cannot write '" + path + "': " + std::strerror(err));
    }
}

OutputSet::~OutputSet() { discard(); }

OutputSet::Entry* OutputSet::find(const std::string& path) {
    for (Entry& e : mEntries)
        if (e.path == path && e.output) return &e;
    return nullptr;
}

// Whether two resolved paths are one file (the same path, or hard links to one file).
static bool sameFile(const std::string& a, const std::string& b) {
    if (a == b) return true;
    std::error_code ec;
    if (!fs::exists(a, ec) || !fs::exists(b, ec)) return false;
    const bool same = fs::equivalent(a, b, ec);
    return same && !ec;
}

void OutputSet::addInput(const std::string& path, const std::string& what) {
    if (path.empty()) return;
    Entry e;
    e.path = path;
    e.real = resolvedPath(path);
    for (const Entry& o : mEntries) {
        if (!o.output || !sameFile(o.real, e.real)) continue;
        throw InputError("", o.what,
                         "'" + o.path + "' is " + what + ", which this run reads: refusing to "
                         "overwrite an input");
    }
    e.what = what;
    mEntries.push_back(std::move(e));
}

void OutputSet::addOutput(const std::string& path, const std::string& flag) {
    if (path.empty()) return;
    const std::string real = resolvedPath(path);
    std::error_code ec;
    if (fs::is_directory(real, ec)) {
        throw InputError("", flag, "'" + path + "' is a directory, not a file");
    }
    const fs::path parent = fs::path(real).parent_path();
    if (!parent.empty() && !fs::is_directory(parent, ec)) {
        throw InputError("", flag,
                         "cannot write '" + path + "': directory '" +
                             fs::path(path).parent_path().string() + "' does not exist");
    }
    for (const Entry& e : mEntries) {
        if (!sameFile(e.real, real)) continue;
        if (e.output) {
            throw InputError("", flag,
                             "'" + path + "' is also written by " + e.what +
                                 (e.path != path ? " (as '" + e.path + "')" : "") +
                                 ": every output needs its own file");
        }
        throw InputError("", flag,
                         "'" + path + "' is " + e.what + ", which this run reads: refusing to "
                         "overwrite an input");
    }
    Entry e;
    e.path = path;
    e.real = real;
    e.what = flag;
    e.output = true;
    mEntries.push_back(std::move(e));
}

std::string OutputSet::stage(const std::string& path) {
    Entry* e = find(path);
    if (!e) throw std::logic_error("OutputSet::stage: '" + path + "' was not registered");
    if (e->temporary.empty()) e->temporary = temporaryPathFor(path);
    return e->temporary;
}

void OutputSet::commit() {
    for (Entry& e : mEntries) {
        if (!e.output || e.temporary.empty()) continue;
        if (std::rename(e.temporary.c_str(), e.path.c_str()) != 0) {
            const int err = errno;
            throw std::runtime_error("cannot write '" + e.path + "': " + std::strerror(err));
        }
        e.temporary.clear();
    }
}

void OutputSet::discard() {
    for (Entry& e : mEntries) {
        if (!e.output || e.temporary.empty()) continue;
        std::remove(e.temporary.c_str());
        e.temporary.clear();
    }
}

}  // namespace penumbra

namespace penumbra {

std::string hex16(uint64_t v) {
    char buf[17];
    std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(v));
    return buf;
}

FileDigest digestFile(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw std::runtime_error("cannot read '" + path + "': " + std::strerror(errno));
    FileDigest d;
    uint64_t h = kFnvOffset;
    std::vector<char> buffer(1 << 16);
    while (in) {
        in.read(buffer.data(), std::streamsize(buffer.size()));
        const std::streamsize n = in.gcount();
        h = fnv1a64(std::string_view(buffer.data(), size_t(n)), h);
        d.bytes += uint64_t(n);
    }
    if (in.bad()) throw std::runtime_error("cannot read '" + path + "'");
    d.hash = hex16(h);
    return d;
}

ImageMetadata settingsMetadata(const RenderSettings& settings) {
    ImageMetadata m;
    const nlohmann::ordered_json json = settings.toJson();
    for (const auto& [key, value] : json.items()) {
        m.push_back({"penumbra:" + key, value.is_string() ? value.get<std::string>() : value.dump()});
    }
    return m;
}

}  // namespace penumbra
