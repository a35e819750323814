// Tests of json_reader.h: the strict JSON reader of scene files and batch manifests (comments,
// repeated keys refused by pointer, syntax errors by line and column in characters, files).
#include <catch2/catch.hpp>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "support/temp_file.h"
#include "penumbra/error.h"
#include "penumbra/json_reader.h"

using namespace penumbra;

namespace {

/// The InputError parseStrictJson raises for `text` (file "f.json").
InputError refusal(const std::string& text) {
    try {
        parseStrictJson(text, "f.json");
    } catch (const InputError& e) {
        return e;
    }
    FAIL("accepted: " << text);
    return InputError("", "", "");
}

}  // namespace

TEST_CASE("parseStrictJson accepts comments and reads what nlohmann reads", "[json]") {
    const nlohmann::json j =
        parseStrictJson("// a scene\n{\"a\": /* one */ 1, \"b\": [true, \"\xc3\xa9\"]}\n", "f.json");
    CHECK(j == nlohmann::json::parse(R"({"a": 1, "b": [true, "é"]})"));
}

TEST_CASE("parseStrictJson refuses a repeated key at its pointer", "[json]") {
    const InputError top = refusal(R"({"a": 1, "a": 2})");
    CHECK(top.file() == "f.json");
    CHECK(top.where() == "/a");
    CHECK(top.message() == "duplicate key 'a'");

    // Escaped per RFC 6901 in the pointer, as written in the message.
    const InputError nested = refusal(R"({"x": [0, {"a/b~": 1, "c": 2, "a/b~": 3}]})");
    CHECK(nested.where() == "/x/1/a~1b~0");
    CHECK(nested.message() == "duplicate key 'a/b~'");
    CHECK(std::string(nested.what()) == "f.json: /x/1/a~1b~0: duplicate key 'a/b~'");

    // The same key in two objects is no repeat.
    CHECK_NOTHROW(parseStrictJson(R"([{"a": 1}, {"a": 2}])", "f.json"));
}

TEST_CASE("parseStrictJson reports a syntax error by line and column in characters", "[json]") {
    const InputError e = refusal("{\n  \"a\": 1,\n  \"b\": [,]\n}");
    CHECK(e.where() == "");
    CHECK(e.message() ==
          "malformed JSON at line 3, column 9: syntax error while parsing value - unexpected ','; "
          "expected '[', '{', or a literal");
    // 'é' is two bytes, one character: the '2' is the 9th character, the 10th byte.
    CHECK_THAT(refusal("{\"\xc3\xa9\": 1 2}").message(),
               Catch::StartsWith("malformed JSON at line 1, column 9: "));
    CHECK_THAT(refusal("{\"a\": \"\xe2\x82\xac\xe2\x82\xac\", \"b\": x}").message(),
               Catch::StartsWith("malformed JSON at line 1, column 18: "));
    // The end of the input is the column after the last character.
    CHECK_THAT(refusal("").message(), Catch::StartsWith("malformed JSON at line 1, column 1: "));
    CHECK_THAT(refusal("{\"a\": 1,\n").message(),
               Catch::StartsWith("malformed JSON at line 2, column 1: "));
}

TEST_CASE("parseStrictJson refuses a number beyond a double at its pointer", "[json]") {
    const InputError e = refusal(R"({"a": [1, 2, 1e400]})");
    CHECK(e.where() == "/a/2");
    CHECK(e.message() == "number overflow parsing '1e400' (numbers must be finite)");
}

TEST_CASE("json_reader helpers: pointerToken, lineColumn, printable", "[json]") {
    CHECK(pointerToken("a/b~c") == "a~1b~0c");
    CHECK(pointerToken("~1") == "~01");
    CHECK(pointerToken("") == "");

    const std::string text = "ab\n\xc3\xa9x\n";
    using LC = std::pair<size_t, size_t>;
    CHECK(lineColumn(text, 0) == LC{1, 1});
    CHECK(lineColumn(text, 1) == LC{1, 1});  // 'a'
    CHECK(lineColumn(text, 3) == LC{1, 3});  // the first newline
    CHECK(lineColumn(text, 4) == LC{2, 1});  // 'é'
    CHECK(lineColumn(text, 6) == LC{2, 2});  // 'x', after a two-byte character
    CHECK(lineColumn(text, 100) == LC{3, 1});

    CHECK(printable("a\tb\nc\x01") == "a\\tb\\nc\\x01");
    CHECK(printable(std::string(70, 'k')) == std::string(60, 'k') + "...");
}

TEST_CASE("readTextFile reads a file and names what it could not read", "[json]") {
    const test::TempFile file("json_reader", ".json", "{\"a\": 1}\n");
    CHECK(readTextFile(file.path(), "the scene file") == "{\"a\": 1}\n");

    const test::TempFile missing("json_reader", ".json");
    try {
        readTextFile(missing.path(), "the scene file");
        FAIL("read a missing file");
    } catch (const InputError& e) {
        CHECK(e.file() == missing.path());
        CHECK(e.message() == "no such file");
    }
    const std::string dir = std::filesystem::temp_directory_path().string();
    try {
        readTextFile(dir, "the batch manifest");
        FAIL("read a directory");
    } catch (const InputError& e) {
        CHECK(e.message() == "is a directory, not the batch manifest");
    }
}
