// JSON documents on nlohmann-json (Debian nlohmann-json3-dev), with the
// project's error conventions on top: parse errors and type mismatches are
// one-line IoErrors naming the source, duplicate object keys and nesting
// deeper than 512 levels are rejected, and non-finite numbers are refused
// when writing. `Json` objects keep their keys sorted (std::map), so writing
// is deterministic and matches Python's `json.dump(..., sort_keys=True,
// indent=2)` layout.
//
// Used for marker layouts (MoSh layout files, REFERENCE.md 7.1) and the
// MakeHuman assets.
#pragma once

#include <cstdint>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>

namespace soma {

/// A JSON value (nlohmann::json: objects sorted by key).
using Json = nlohmann::json;

/// Parses one JSON document (RFC 8259, UTF-8; a leading BOM is skipped).
/// Duplicate object keys, trailing garbage, invalid UTF-8, nesting deeper
/// than 512 levels are errors. Throws IoError "`source_name`:line:col:
/// message" (duplicate keys: "`source_name`: duplicate key ...").
Json ParseJson(std::string_view text, std::string_view source_name = "<json>");

/// ReadFile + ParseJson; errors name the path.
Json ReadJsonFile(const std::filesystem::path& path);

/// Serialises `value`: keys sorted, `indent` spaces per level and one member
/// per line (0 = compact, no spaces). Numbers are written in shortest
/// round-trip form (integers without a fraction). Throws IoError for NaN or
/// infinite numbers (not representable in JSON) and invalid UTF-8 strings.
std::string WriteJson(const Json& value, int indent = 2);

/// Name of the JSON type of `value` ("null", "boolean", "number", "string",
/// "array", "object"), for messages.
const char* JsonTypeName(const Json& value);

/// A number with an integral value representable exactly (|v| <= 2^53).
bool JsonIsInteger(const Json& value);

// Checked accessors; each throws IoError "JSON type mismatch: expected <X>,
// got <Y>" (callers prefix the file).
const Json::object_t& JsonObject(const Json& value);
const Json::array_t& JsonArray(const Json& value);
const std::string& JsonString(const Json& value);
double JsonNumber(const Json& value);
bool JsonBool(const Json& value);
/// An integral number (see JsonIsInteger); 2.0 is accepted, 2.5 is not.
int64_t JsonInt(const Json& value);

/// Object member or nullptr (also nullptr if `value` is not an object).
const Json* JsonFind(const Json& value, std::string_view key);

}  // namespace soma
