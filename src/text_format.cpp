#include "text_format.h"

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>
#include <sstream>

#include "penumbra/json_reader.h"

namespace penumbra {

namespace {

/// Levenshtein distance; inputs are short key names.
size_t editDistance(const std::string& a, const std::string& b) {
    std::vector<size_t> row(b.size() + 1);
    for (size_t j = 0; j <= b.size(); ++j) row[j] = j;
    for (size_t i = 1; i <= a.size(); ++i) {
        size_t diag = row[0];
        row[0] = i;
        for (size_t j = 1; j <= b.size(); ++j) {
            const size_t up = row[j];
            row[j] = std::min({row[j] + 1, row[j - 1] + 1, diag + (a[i - 1] == b[j - 1] ? 0 : 1)});
            diag = up;
        }
    }
    return row[b.size()];
}

/// How far `word` is from `candidate` for suggestions: the edit distance, except that a word
/// that begins or ends a candidate ("fov" for "fov_deg") counts as one edit away, since the
/// plain distance would prefer any short key ("up").
size_t suggestionDistance(const std::string& word, const std::string& candidate) {
    const size_t d = editDistance(word, candidate);
    if (word.empty() || word.size() >= candidate.size()) return d;
    const bool prefix = candidate.compare(0, word.size(), word) == 0;
    const bool suffix = candidate.compare(candidate.size() - word.size(), word.size(), word) == 0;
    return (prefix || suffix) ? std::min<size_t>(d, 1) : d;
}

}  // namespace

std::string inQuotes(const std::string& s) { return "'" + printable(s) + "'"; }

std::string joined(const std::vector<std::string>& words) {
    std::string out;
    for (const std::string& w : words) out += (out.empty() ? "" : ", ") + w;
    return out;
}

std::string suggestion(const std::string& word, const std::vector<std::string>& candidates) {
    if (candidates.empty()) return "";
    const std::string* best = &candidates.front();
    size_t bestDist = suggestionDistance(word, *best);
    for (const std::string& c : candidates) {
        const size_t d = suggestionDistance(word, c);
        if (d < bestDist) {
            best = &c;
            bestDist = d;
        }
    }
    std::string out = " (did you mean '" + *best + "'?";
    if (candidates.size() > 1 && bestDist > std::max<size_t>(2, best->size() / 2)) {
        out += " valid: " + joined(candidates);
    }
    return out + ")";
}

std::string numberText(double x) {
    if (std::isnan(x)) return "nan";
    if (std::isinf(x)) return x > 0 ? "inf" : "-inf";
    // Whole numbers without nlohmann's trailing ".0": "must be > 0", as the user would write.
    if (x == std::floor(x) && std::fabs(x) < 1e15) return std::to_string(static_cast<long long>(x));
    return nlohmann::json(x).dump();
}

std::string vecText(const Vec3& v) {
    return "[" + numberText(v.x) + ", " + numberText(v.y) + ", " + numberText(v.z) + "]";
}

std::string bytesText(double bytes) {
    std::ostringstream s;
    s.setf(std::ios::fixed);
    if (bytes >= 10.0 * kGiB) {
        s.precision(0);
        s << bytes / kGiB << " GiB";
    } else if (bytes >= kGiB) {
        s.precision(1);
        s << bytes / kGiB << " GiB";
    } else {
        s.precision(0);
        s << std::max(1.0, bytes / (1024.0 * 1024.0)) << " MiB";
    }
    return s.str();
}

std::string mebibytes(double bytes) {
    std::ostringstream s;
    s.setf(std::ios::fixed);
    s.precision(bytes < 10.0 * 1024 * 1024 ? 2 : 0);
    s << bytes / (1024.0 * 1024.0) << " MiB";
    return s.str();
}

std::string grouped(uint64_t n) {
    std::string digits = std::to_string(n), out;
    for (size_t i = 0; i < digits.size(); ++i) {
        if (i > 0 && (digits.size() - i) % 3 == 0) out += ',';
        out += digits[i];
    }
    return out;
}

std::string secondsText(double seconds) {
    std::ostringstream s;
    s.setf(std::ios::fixed);
    s.precision(seconds < 10.0 ? 3 : 1);
    s << seconds << " s";
    return s.str();
}

}  // namespace penumbra
