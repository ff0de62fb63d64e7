#include "framework/core/json.h"

#include "framework/core/error.h"
#include "framework/core/file.h"

#include <fmt/format.h>

#include <cmath>
#include <limits>
#include <set>
#include <utility>
#include <vector>

namespace soma {
namespace {

constexpr double kMaxExactInteger = 9007199254740992.0;  // 2^53
constexpr int kMaxDepth = 512;

// Thrown from the parser callback; turned into IoError by ParseJson.
struct CallbackError {
  std::string message;
};

// "source:line:col: message" for a parse error at 1-based byte `byte` (the
// last character nlohmann-json read).
std::string LocatedMessage(std::string_view text,
                           std::string_view source,
                           size_t byte,
                           std::string_view message) {
  const size_t offset = byte > 0 ? byte - 1 : 0;
  int line = 1;
  int col = 1;
  for (size_t i = 0; i < offset && i < text.size(); ++i) {
    if (text[i] == '\n') {
      ++line;
      col = 1;
    } else {
      ++col;
    }
  }
  return fmt::format("{}:{}:{}: {}", source, line, col, message);
}

// nlohmann-json's message without its "[json.exception.x.N] parse error at
// line L, column C: " prefix (we print our own location).
std::string StripPrefix(const std::string& what) {
  std::string message = what;
  if (message.rfind("[json.exception.", 0) == 0) {
    const size_t end = message.find("] ");
    if (end != std::string::npos) message = message.substr(end + 2);
  }
  for (const std::string_view prefix : {"parse error at ", "parse error"}) {
    if (message.rfind(prefix, 0) != 0) continue;
    const size_t colon = message.find(": ");
    if (colon != std::string::npos) message = message.substr(colon + 2);
    break;
  }
  return message;
}

void CheckFinite(const Json& value) {
  switch (value.type()) {
    case Json::value_t::number_float: {
      const double v = value.get<double>();
      if (!std::isfinite(v)) {
        throw IoError(fmt::format(
            "Cannot write {} as JSON (only finite numbers are valid)", v));
      }
      return;
    }
    case Json::value_t::array:
      for (const Json& element : value) CheckFinite(element);
      return;
    case Json::value_t::object:
      for (const auto& [key, member] : value.items()) CheckFinite(member);
      return;
    default:
      return;
  }
}

[[noreturn]] void TypeMismatch(const char* expected, const Json& actual) {
  throw IoError(fmt::format("JSON type mismatch: expected {}, got {}",
                            expected,
                            JsonTypeName(actual)));
}

}  // namespace

Json ParseJson(std::string_view text, std::string_view source_name) {
  // Keys of the objects being parsed, innermost last (nlohmann-json keeps the
  // last of duplicate keys; RFC 8259 leaves them undefined, we reject them).
  std::vector<std::set<std::string, std::less<>>> open_objects;
  const Json::parser_callback_t callback = [&](int depth,
                                               Json::parse_event_t event,
                                               Json& parsed) {
    switch (event) {
      case Json::parse_event_t::object_start:
      case Json::parse_event_t::array_start:
        if (depth >= kMaxDepth) {
          throw CallbackError{
              fmt::format("nesting deeper than {} levels", kMaxDepth)};
        }
        if (event == Json::parse_event_t::object_start)
          open_objects.emplace_back();
        break;
      case Json::parse_event_t::key:
        if (!open_objects.empty() &&
            !open_objects.back()
                 .insert(parsed.get_ref<const std::string&>())
                 .second) {
          throw CallbackError{fmt::format(
              "duplicate key \"{}\"", parsed.get_ref<const std::string&>())};
        }
        break;
      case Json::parse_event_t::object_end:
        if (!open_objects.empty()) open_objects.pop_back();
        break;
      default:
        break;
    }
    return true;
  };
  try {
    return Json::parse(text.begin(), text.end(), callback);
  } catch (const CallbackError& e) {
    throw IoError(fmt::format("{}: {}", source_name, e.message));
  } catch (const Json::parse_error& e) {
    throw IoError(
        LocatedMessage(text, source_name, e.byte, StripPrefix(e.what())));
  } catch (const Json::exception& e) {
    throw IoError(fmt::format("{}: {}", source_name, StripPrefix(e.what())));
  }
}

Json ReadJsonFile(const std::filesystem::path& path) {
  return ParseJson(ReadFile(path), path.string());
}

std::string WriteJson(const Json& value, int indent) {
  CheckFinite(value);
  try {
    return value.dump(indent > 0 ? indent : -1);
  } catch (const Json::exception& e) {
    throw IoError(fmt::format("Cannot write JSON: {}", StripPrefix(e.what())));
  }
}

const char* JsonTypeName(const Json& value) { return value.type_name(); }

bool JsonIsInteger(const Json& value) {
  if (value.is_number_integer()) {
    return !value.is_number_unsigned() ||
           value.get<uint64_t>() <=
               static_cast<uint64_t>(std::numeric_limits<int64_t>::max());
  }
  if (!value.is_number_float()) return false;
  const double v = value.get<double>();
  return std::isfinite(v) && v == std::floor(v) &&
         std::fabs(v) <= kMaxExactInteger;
}

const Json::object_t& JsonObject(const Json& value) {
  if (!value.is_object()) TypeMismatch("object", value);
  return value.get_ref<const Json::object_t&>();
}

const Json::array_t& JsonArray(const Json& value) {
  if (!value.is_array()) TypeMismatch("array", value);
  return value.get_ref<const Json::array_t&>();
}

const std::string& JsonString(const Json& value) {
  if (!value.is_string()) TypeMismatch("string", value);
  return value.get_ref<const std::string&>();
}

double JsonNumber(const Json& value) {
  if (!value.is_number()) TypeMismatch("number", value);
  return value.get<double>();
}

bool JsonBool(const Json& value) {
  if (!value.is_boolean()) TypeMismatch("boolean", value);
  return value.get<bool>();
}

int64_t JsonInt(const Json& value) {
  if (!value.is_number()) TypeMismatch("integer", value);
  if (!JsonIsInteger(value)) {
    throw IoError(fmt::format("JSON type mismatch: expected an integer, got {}",
                              value.dump()));
  }
  if (value.is_number_float()) return static_cast<int64_t>(value.get<double>());
  return value.get<int64_t>();
}

const Json* JsonFind(const Json& value, std::string_view key) {
  if (!value.is_object()) return nullptr;
  const auto& object = value.get_ref<const Json::object_t&>();
  const auto it = object.find(key);
  return it == object.end() ? nullptr : &it->second;
}

}  // namespace soma
