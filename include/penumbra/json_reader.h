/// @file json_reader.h
/// The one strict JSON reader, for scene files (scene_loader.cpp) and batch manifests (batch.cpp):
/// reading a file's text, parsing it with `//` and `/* */` comments allowed and a repeated key
/// refused, and wording the errors as docs/errors.md shows them (E01, E05, E06):
///
///   scene.json: malformed JSON at line 3, column 31: syntax error while parsing value - ...
///   scene.json: /obstacles/0/radius: duplicate key 'radius'
///   scene.json: /obstacles/0/radius: number overflow parsing '1e400' (numbers must be finite)
///
/// Lines and columns are 1-based and columns count characters (UTF-8 code points), not bytes.
/// Every error is an InputError (error.h) naming the file and, where there is one, the JSON
/// pointer (RFC 6901) of the value.
#pragma once

#include <cstddef>
#include <string>
#include <utility>

#include <nlohmann/json_fwd.hpp>

namespace penumbra {

/// The whole content of the file at `path`. `what` names it in messages ("the scene file",
/// "the batch manifest"). Throws InputError(path, "", ...): "is a directory, not <what>",
/// "no such file", "is not a regular file" (a FIFO or a device: no read that could block),
/// "cannot open <what>: <reason>", "cannot read <what>".
std::string readTextFile(const std::string& path, const std::string& what);

/// Parses `text` (the content of `file`, named in errors) as JSON: comments are allowed, a key
/// repeated within one object is refused ("duplicate key 'k'" at the repeated key's pointer),
/// a number beyond a double's range (1e400) is refused at its pointer ("... (numbers must be
/// finite)"), and a syntax error is reported as "malformed JSON at line L, column C: <reason>".
/// Throws InputError.
nlohmann::json parseStrictJson(const std::string& text, const std::string& file);

/// RFC 6901 escaping of one reference token: '~' -> "~0", '/' -> "~1".
std::string pointerToken(const std::string& key);

/// The 1-based line and column of the character at 1-based byte offset `byte` of `text` (as
/// nlohmann::json::parse_error::byte gives it; 0 and offsets past the end are clamped). Columns
/// count UTF-8 code points.
std::pair<std::size_t, std::size_t> lineColumn(const std::string& text, std::size_t byte);

/// User-supplied text made safe for a one-line message: newlines, tabs and other control
/// characters escaped (\n, \t, \x01), cut after `maxLen` bytes with "...".
std::string printable(const std::string& s, std::size_t maxLen = 60);

}  // namespace penumbra
