// Internal: the wording of numbers, sizes, times and user text in messages and reports (the
// scene loader's errors, BuildReport::toText). One place, so that a value reads the same in an
// error and in a report.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "penumbra/math.h"

namespace penumbra {

/// Bytes in a GiB, the unit of memory limits (level_set.max_memory_gib) and of bytesText.
constexpr double kGiB = 1024.0 * 1024.0 * 1024.0;

/// User text in single quotes, made printable (json_reader.h): 'name'.
std::string inQuotes(const std::string& s);

/// The words separated by ", ".
std::string joined(const std::vector<std::string>& words);

/// " (did you mean 'x'?)" for the candidate nearest to `word`, plus the full list (" valid:
/// a, b, c") when even the nearest is far off; "" without candidates. A word that begins or
/// ends a candidate ("fov" for "fov_deg") counts as one edit away.
std::string suggestion(const std::string& word, const std::vector<std::string>& candidates);

/// A number as the user wrote it: whole numbers without ".0", others in their shortest
/// round-trip form, "nan", "inf", "-inf".
std::string numberText(double x);

/// "[x, y, z]" in numberText's form.
std::string vecText(const Vec3& v);

/// A memory size for limits and estimates: "12 GiB", "1.5 GiB", "300 MiB" (at least 1 MiB).
std::string bytesText(double bytes);

/// A measured size in MiB: two decimals under 10 MiB ("2.13 MiB"), none above.
std::string mebibytes(double bytes);

/// 1234567 -> "1,234,567": voxel counts are read at a glance.
std::string grouped(uint64_t n);

/// "0.042 s" under 10 s, "12.5 s" above.
std::string secondsText(double seconds);

}  // namespace penumbra
