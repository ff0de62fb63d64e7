// A small, strict JSON value type with a reader and a writer (RFC 8259).
//
// Used for marker layouts (MoSh layout files, REFERENCE.md 7.1) and other
// small JSON assets. Objects keep their keys sorted and unique, so writing is
// deterministic and matches Python's `json.dump(..., sort_keys=True,
// indent=2)` layout. Parse errors are IoError with `source:line:col`.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace soma {

/// One JSON value: null, bool, number (double), string, array or object.
class JsonValue {
 public:
  enum class Type { kNull, kBool, kNumber, kString, kArray, kObject };
  using Array = std::vector<JsonValue>;
  /// Members sorted by key, keys unique.
  using Object = std::vector<std::pair<std::string, JsonValue>>;

  JsonValue() = default;
  JsonValue(std::nullptr_t) {}   // NOLINT(google-explicit-constructor)
  JsonValue(bool value);         // NOLINT(google-explicit-constructor)
  JsonValue(double value);       // NOLINT(google-explicit-constructor)
  JsonValue(int value);          // NOLINT(google-explicit-constructor)
  JsonValue(int64_t value);      // NOLINT(google-explicit-constructor)
  JsonValue(std::string value);  // NOLINT(google-explicit-constructor)
  JsonValue(const char* value);  // NOLINT(google-explicit-constructor)

  static JsonValue MakeArray(Array elements = {});
  static JsonValue MakeObject();

  Type type() const { return type_; }
  bool is_null() const { return type_ == Type::kNull; }
  bool is_bool() const { return type_ == Type::kBool; }
  bool is_number() const { return type_ == Type::kNumber; }
  bool is_string() const { return type_ == Type::kString; }
  bool is_array() const { return type_ == Type::kArray; }
  bool is_object() const { return type_ == Type::kObject; }
  /// A number with an integral value representable exactly (|v| <= 2^53).
  bool is_integer() const;

  // Typed accessors; each throws IoError naming the actual type on mismatch.
  bool AsBool() const;
  double AsNumber() const;
  int64_t AsInt() const;  // also throws if the number is not integral
  const std::string& AsString() const;
  const Array& AsArray() const;
  Array& MutableArray();
  const Object& AsObject() const;

  /// Object member or nullptr (also nullptr if this is not an object).
  const JsonValue* Find(std::string_view key) const;
  /// Inserts or replaces an object member (this must be an object).
  void Set(std::string key, JsonValue value);
  /// Appends to an array (this must be an array).
  void Append(JsonValue value);
  /// Number of array elements or object members (0 otherwise).
  size_t size() const;

  bool operator==(const JsonValue& other) const;
  bool operator!=(const JsonValue& other) const { return !(*this == other); }

 private:
  Type type_ = Type::kNull;
  bool bool_ = false;
  double number_ = 0.0;
  std::string string_;
  Array array_;
  Object object_;
};

/// Name of a JSON type ("null", "bool", "number", ...), for messages.
const char* JsonTypeName(JsonValue::Type type);

/// Parses one JSON document (UTF-8; a leading BOM is skipped). Accepts the
/// Python extensions NaN, Infinity and -Infinity as numbers. Duplicate object
/// keys, trailing garbage, nesting deeper than 512 and invalid escapes are
/// errors. Throws IoError "`source_name`:line:col: message".
JsonValue ParseJson(std::string_view text,
                    std::string_view source_name = "<json>");

/// Serialises `value`: keys sorted, `indent` spaces per level (0 = compact
/// one line), separators ", " / ": " like Python's json.dump. Integral numbers
/// are written without a fraction, others in shortest round-trip form.
/// Throws IoError for NaN or infinite numbers (not representable in JSON).
std::string WriteJson(const JsonValue& value, int indent = 2);

}  // namespace soma
