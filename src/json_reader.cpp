// The strict JSON reader of scene files and batch manifests (json_reader.h).
#include "penumbra/json_reader.h"

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <vector>

#include "penumbra/error.h"

namespace penumbra {

namespace {

using Json = nlohmann::json;

// nlohmann::json reports syntax errors by byte offset and silently keeps the last of duplicate
// keys; the parser callback below tracks the JSON pointer of the value being read so that
// duplicates and out-of-range numbers (1e400) can be reported by pointer too.
class PathTracker {
  public:
    struct DuplicateKey {
        std::string pointer;
        std::string key;
    };

    bool operator()(int /*depth*/, Json::parse_event_t event, Json& parsed) {
        switch (event) {
            case Json::parse_event_t::object_start:
                mFrames.emplace_back(true);
                break;
            case Json::parse_event_t::array_start:
                mFrames.emplace_back(false);
                break;
            case Json::parse_event_t::key: {
                Frame& f = mFrames.back();
                f.key = parsed.get<std::string>();
                f.hasKey = true;
                if (!f.seen.insert(f.key).second) throw DuplicateKey{pointer(), f.key};
                break;
            }
            case Json::parse_event_t::object_end:
            case Json::parse_event_t::array_end:
                mFrames.pop_back();
                childDone();
                break;
            case Json::parse_event_t::value:
                childDone();
                break;
        }
        return true;
    }

    /// Pointer of the value being read.
    std::string pointer() const {
        std::string p;
        for (const Frame& f : mFrames) {
            if (f.isObject) {
                if (!f.hasKey) break;
                p += "/" + pointerToken(f.key);
            } else {
                p += "/" + std::to_string(f.index);
            }
        }
        return p;
    }

  private:
    struct Frame {
        explicit Frame(bool object) : isObject(object) {}
        bool isObject;
        bool hasKey = false;
        std::string key;
        size_t index = 0;  // arrays: the element being read
        std::set<std::string> seen;
    };

    void childDone() {
        if (!mFrames.empty() && !mFrames.back().isObject) ++mFrames.back().index;
    }

    std::vector<Frame> mFrames;
};

/// nlohmann's what() without its "[json.exception...] parse error at line 1, column 2: " prefix.
std::string nlohmannReason(const std::string& what) {
    const size_t bracket = what.find("] ");
    std::string reason = bracket == std::string::npos ? what : what.substr(bracket + 2);
    const size_t colon = reason.find(": ");
    if (reason.rfind("parse error", 0) == 0 && colon != std::string::npos) {
        reason = reason.substr(colon + 2);
    }
    return reason;
}

}  // namespace

std::string readTextFile(const std::string& path, const std::string& what) {
    namespace fs = std::filesystem;
    std::error_code ec;
    if (fs::is_directory(path, ec)) throw InputError(path, "", "is a directory, not " + what);
    if (!fs::exists(path, ec)) throw InputError(path, "", "no such file");
    if (!fs::is_regular_file(path, ec)) {
        // A FIFO would block the reader (or never end), a device be read forever.
        throw InputError(path, "", "is not a regular file");
    }
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path, "", "cannot open " + what + ": " + std::strerror(errno));
    std::ostringstream text;
    text << in.rdbuf();
    if (in.bad()) throw InputError(path, "", "cannot read " + what);
    return text.str();
}

Json parseStrictJson(const std::string& text, const std::string& file) {
    PathTracker tracker;
    Json::parser_callback_t callback = [&tracker](int depth, Json::parse_event_t event,
                                                  Json& parsed) {
        return tracker(depth, event, parsed);
    };
    try {
        return Json::parse(text, callback, /*allow_exceptions=*/true, /*ignore_comments=*/true);
    } catch (const PathTracker::DuplicateKey& d) {
        throw InputError(file, d.pointer, "duplicate key '" + printable(d.key) + "'");
    } catch (const Json::parse_error& e) {
        const auto [line, column] = lineColumn(text, e.byte);
        throw InputError(file, "",
                         "malformed JSON at line " + std::to_string(line) + ", column " +
                             std::to_string(column) + ": " +
                             printable(nlohmannReason(e.what()), 300));
    } catch (const Json::exception& e) {
        // out_of_range.406: a number too large for a double, e.g. 1e400.
        throw InputError(file, tracker.pointer(),
                         printable(nlohmannReason(e.what()), 300) + " (numbers must be finite)");
    }
}

std::string pointerToken(const std::string& key) {
    std::string out;
    for (char c : key) {
        if (c == '~') {
            out += "~0";
        } else if (c == '/') {
            out += "~1";
        } else {
            out += c;
        }
    }
    return out;
}

std::pair<size_t, size_t> lineColumn(const std::string& text, size_t byte) {
    const size_t end = std::min(text.size(), byte > 0 ? byte - 1 : 0);
    size_t line = 1, column = 1;
    for (size_t i = 0; i < end; ++i) {
        const unsigned char c = static_cast<unsigned char>(text[i]);
        if (c == '\n') {
            ++line;
            column = 1;
        } else if ((c & 0xC0) != 0x80) {  // not a UTF-8 continuation byte
            ++column;
        }
    }
    return {line, column};
}

std::string printable(const std::string& s, size_t maxLen) {
    std::string out;
    for (size_t i = 0; i < s.size() && i < maxLen; ++i) {
        const unsigned char c = static_cast<unsigned char>(s[i]);
        if (c == '\n') {
            out += "\\n";
        } else if (c == '\t') {
            out += "\\t";
        } else if (c < 0x20 || c == 0x7f) {
            char buf[8];
            std::snprintf(buf, sizeof buf, "\\x%02x", c);
            out += buf;
        } else {
            out += char(c);
        }
    }
    if (s.size() > maxLen) out += "...";
    return out;
}

}  // namespace penumbra
