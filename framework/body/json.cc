#include "framework/body/json.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <limits>

namespace soma {
namespace {

constexpr double kMaxExactInteger = 9007199254740992.0;  // 2^53
constexpr int kMaxDepth = 512;

bool KeyLess(const std::pair<std::string, JsonValue>& member,
             std::string_view key) {
  return std::string_view(member.first) < key;
}

class Parser {
 public:
  Parser(std::string_view text, std::string_view source)
      : text_(text), source_(source) {
    if (text_.size() >= 3 && static_cast<unsigned char>(text_[0]) == 0xEF &&
        static_cast<unsigned char>(text_[1]) == 0xBB &&
        static_cast<unsigned char>(text_[2]) == 0xBF) {
      pos_ = 3;
    }
  }

  JsonValue ParseDocument() {
    SkipWhitespace();
    if (pos_ >= text_.size()) Fail("empty document, expected a JSON value");
    JsonValue value = ParseValue(0);
    SkipWhitespace();
    if (pos_ < text_.size())
      Fail("unexpected trailing characters after the JSON value");
    return value;
  }

 private:
  [[noreturn]] void Fail(const std::string& message) const {
    FailAt(pos_, message);
  }

  [[noreturn]] void FailAt(size_t offset, const std::string& message) const {
    int line = 1;
    int col = 1;
    for (size_t i = 0; i < offset && i < text_.size(); ++i) {
      if (text_[i] == '\n') {
        ++line;
        col = 1;
      } else {
        ++col;
      }
    }
    throw IoError(fmt::format("{}:{}:{}: {}", source_, line, col, message));
  }

  void SkipWhitespace() {
    while (pos_ < text_.size()) {
      const char c = text_[pos_];
      if (c == ' ' || c == '\t' || c == '\n' || c == '\r') {
        ++pos_;
      } else {
        break;
      }
    }
  }

  std::string Describe(char c) const {
    if (static_cast<unsigned char>(c) < 0x20 ||
        static_cast<unsigned char>(c) >= 0x7f) {
      return fmt::format("byte 0x{:02x}", static_cast<unsigned char>(c));
    }
    return fmt::format("'{}'", c);
  }

  bool ConsumeLiteral(std::string_view literal) {
    if (text_.substr(pos_, literal.size()) == literal) {
      pos_ += literal.size();
      return true;
    }
    return false;
  }

  JsonValue ParseValue(int depth) {
    if (depth > kMaxDepth)
      Fail(fmt::format("nesting deeper than {} levels", kMaxDepth));
    SkipWhitespace();
    if (pos_ >= text_.size())
      Fail("unexpected end of input, expected a JSON value");
    const char c = text_[pos_];
    switch (c) {
      case '{':
        return ParseObject(depth);
      case '[':
        return ParseArray(depth);
      case '"':
        return JsonValue(ParseString());
      case 't':
        if (ConsumeLiteral("true")) return JsonValue(true);
        break;
      case 'f':
        if (ConsumeLiteral("false")) return JsonValue(false);
        break;
      case 'n':
        if (ConsumeLiteral("null")) return JsonValue(nullptr);
        break;
      case 'N':
        if (ConsumeLiteral("NaN"))
          return JsonValue(std::numeric_limits<double>::quiet_NaN());
        break;
      case 'I':
        if (ConsumeLiteral("Infinity"))
          return JsonValue(std::numeric_limits<double>::infinity());
        break;
      default:
        if (c == '-' || (c >= '0' && c <= '9')) return ParseNumber();
        break;
    }
    Fail(fmt::format("unexpected {}, expected a JSON value", Describe(c)));
  }

  JsonValue ParseObject(int depth) {
    const size_t start = pos_;
    ++pos_;  // '{'
    JsonValue object = JsonValue::MakeObject();
    SkipWhitespace();
    if (pos_ < text_.size() && text_[pos_] == '}') {
      ++pos_;
      return object;
    }
    while (true) {
      SkipWhitespace();
      if (pos_ >= text_.size()) FailAt(start, "unterminated object");
      if (text_[pos_] != '"') {
        Fail(fmt::format("unexpected {}, expected a string key",
                         Describe(text_[pos_])));
      }
      const size_t key_offset = pos_;
      std::string key = ParseString();
      SkipWhitespace();
      if (pos_ >= text_.size() || text_[pos_] != ':')
        Fail("expected ':' after object key");
      ++pos_;
      JsonValue value = ParseValue(depth + 1);
      if (object.Find(key) != nullptr)
        FailAt(key_offset, fmt::format("duplicate key \"{}\"", key));
      object.Set(std::move(key), std::move(value));
      SkipWhitespace();
      if (pos_ >= text_.size()) FailAt(start, "unterminated object");
      if (text_[pos_] == ',') {
        ++pos_;
        continue;
      }
      if (text_[pos_] == '}') {
        ++pos_;
        return object;
      }
      Fail(fmt::format("unexpected {}, expected ',' or '}}'",
                       Describe(text_[pos_])));
    }
  }

  JsonValue ParseArray(int depth) {
    const size_t start = pos_;
    ++pos_;  // '['
    JsonValue array = JsonValue::MakeArray();
    SkipWhitespace();
    if (pos_ < text_.size() && text_[pos_] == ']') {
      ++pos_;
      return array;
    }
    while (true) {
      array.Append(ParseValue(depth + 1));
      SkipWhitespace();
      if (pos_ >= text_.size()) FailAt(start, "unterminated array");
      if (text_[pos_] == ',') {
        ++pos_;
        continue;
      }
      if (text_[pos_] == ']') {
        ++pos_;
        return array;
      }
      Fail(fmt::format("unexpected {}, expected ',' or ']'",
                       Describe(text_[pos_])));
    }
  }

  uint32_t ParseHex4() {
    if (pos_ + 4 > text_.size()) Fail("truncated \\u escape");
    uint32_t value = 0;
    for (int i = 0; i < 4; ++i) {
      const char c = text_[pos_ + i];
      value <<= 4;
      if (c >= '0' && c <= '9') {
        value |= static_cast<uint32_t>(c - '0');
      } else if (c >= 'a' && c <= 'f') {
        value |= static_cast<uint32_t>(c - 'a' + 10);
      } else if (c >= 'A' && c <= 'F') {
        value |= static_cast<uint32_t>(c - 'A' + 10);
      } else {
        FailAt(pos_ + i, "invalid hex digit in \\u escape");
      }
    }
    pos_ += 4;
    return value;
  }

  static void AppendUtf8(uint32_t cp, std::string* out) {
    if (cp < 0x80) {
      out->push_back(static_cast<char>(cp));
    } else if (cp < 0x800) {
      out->push_back(static_cast<char>(0xC0 | (cp >> 6)));
      out->push_back(static_cast<char>(0x80 | (cp & 0x3F)));
    } else if (cp < 0x10000) {
      out->push_back(static_cast<char>(0xE0 | (cp >> 12)));
      out->push_back(static_cast<char>(0x80 | ((cp >> 6) & 0x3F)));
      out->push_back(static_cast<char>(0x80 | (cp & 0x3F)));
    } else {
      out->push_back(static_cast<char>(0xF0 | (cp >> 18)));
      out->push_back(static_cast<char>(0x80 | ((cp >> 12) & 0x3F)));
      out->push_back(static_cast<char>(0x80 | ((cp >> 6) & 0x3F)));
      out->push_back(static_cast<char>(0x80 | (cp & 0x3F)));
    }
  }

  std::string ParseString() {
    const size_t start = pos_;
    ++pos_;  // opening quote
    std::string out;
    while (true) {
      if (pos_ >= text_.size()) FailAt(start, "unterminated string");
      const char c = text_[pos_];
      if (c == '"') {
        ++pos_;
        return out;
      }
      if (static_cast<unsigned char>(c) < 0x20) {
        Fail("unescaped control character in string");
      }
      if (c != '\\') {
        out.push_back(c);
        ++pos_;
        continue;
      }
      ++pos_;
      if (pos_ >= text_.size()) FailAt(start, "unterminated string");
      const char e = text_[pos_++];
      switch (e) {
        case '"':
          out.push_back('"');
          break;
        case '\\':
          out.push_back('\\');
          break;
        case '/':
          out.push_back('/');
          break;
        case 'b':
          out.push_back('\b');
          break;
        case 'f':
          out.push_back('\f');
          break;
        case 'n':
          out.push_back('\n');
          break;
        case 'r':
          out.push_back('\r');
          break;
        case 't':
          out.push_back('\t');
          break;
        case 'u': {
          uint32_t cp = ParseHex4();
          if (cp >= 0xD800 && cp <= 0xDBFF) {
            if (text_.substr(pos_, 2) != "\\u")
              Fail("unpaired UTF-16 high surrogate");
            pos_ += 2;
            const uint32_t low = ParseHex4();
            if (low < 0xDC00 || low > 0xDFFF)
              Fail("invalid UTF-16 low surrogate");
            cp = 0x10000 + ((cp - 0xD800) << 10) + (low - 0xDC00);
          } else if (cp >= 0xDC00 && cp <= 0xDFFF) {
            Fail("unpaired UTF-16 low surrogate");
          }
          AppendUtf8(cp, &out);
          break;
        }
        default:
          FailAt(pos_ - 1, fmt::format("invalid escape '\\{}'", e));
      }
    }
  }

  JsonValue ParseNumber() {
    const size_t start = pos_;
    if (text_[pos_] == '-') {
      ++pos_;
      if (ConsumeLiteral("Infinity"))
        return JsonValue(-std::numeric_limits<double>::infinity());
    }
    auto digit = [&](size_t i) {
      return i < text_.size() && text_[i] >= '0' && text_[i] <= '9';
    };
    if (!digit(pos_)) Fail("invalid number: expected a digit");
    if (text_[pos_] == '0') {
      ++pos_;
      if (digit(pos_)) Fail("invalid number: leading zeros are not allowed");
    } else {
      while (digit(pos_)) ++pos_;
    }
    if (pos_ < text_.size() && text_[pos_] == '.') {
      ++pos_;
      if (!digit(pos_)) Fail("invalid number: expected a digit after '.'");
      while (digit(pos_)) ++pos_;
    }
    if (pos_ < text_.size() && (text_[pos_] == 'e' || text_[pos_] == 'E')) {
      ++pos_;
      if (pos_ < text_.size() && (text_[pos_] == '+' || text_[pos_] == '-'))
        ++pos_;
      if (!digit(pos_))
        Fail("invalid number: expected a digit in the exponent");
      while (digit(pos_)) ++pos_;
    }
    double value = 0.0;
    const char* first = text_.data() + start;
    const char* last = text_.data() + pos_;
    const auto result = std::from_chars(first, last, value);
    if (result.ec == std::errc::result_out_of_range) {
      // Overflow to +-inf is an error; underflow to 0 is harmless.
      if (std::fabs(std::strtod(std::string(first, last).c_str(), nullptr)) >
          1.0) {
        FailAt(start, "number out of range");
      }
      value = 0.0;
    } else if (result.ec != std::errc() || result.ptr != last) {
      FailAt(start, "invalid number");
    }
    return JsonValue(value);
  }

  std::string_view text_;
  std::string_view source_;
  size_t pos_ = 0;
};

void WriteEscapedString(std::string_view s, std::string* out) {
  out->push_back('"');
  for (const char c : s) {
    switch (c) {
      case '"':
        out->append("\\\"");
        break;
      case '\\':
        out->append("\\\\");
        break;
      case '\b':
        out->append("\\b");
        break;
      case '\f':
        out->append("\\f");
        break;
      case '\n':
        out->append("\\n");
        break;
      case '\r':
        out->append("\\r");
        break;
      case '\t':
        out->append("\\t");
        break;
      default:
        if (static_cast<unsigned char>(c) < 0x20) {
          out->append(fmt::format("\\u{:04x}", static_cast<unsigned char>(c)));
        } else {
          out->push_back(c);
        }
    }
  }
  out->push_back('"');
}

void WriteNumber(double v, std::string* out) {
  if (!std::isfinite(v)) {
    throw IoError(fmt::format(
        "Cannot write {} as JSON (only finite numbers are valid)", v));
  }
  if (v == std::floor(v) && std::fabs(v) <= kMaxExactInteger) {
    out->append(fmt::format("{}", static_cast<int64_t>(v)));
  } else {
    out->append(fmt::format("{}", v));
  }
}

void WriteValue(const JsonValue& value,
                int indent,
                int level,
                std::string* out) {
  const auto newline = [&](int lvl) {
    if (indent > 0) {
      out->push_back('\n');
      out->append(static_cast<size_t>(indent * lvl), ' ');
    }
  };
  const char* separator = indent > 0 ? "," : ", ";
  switch (value.type()) {
    case JsonValue::Type::kNull:
      out->append("null");
      return;
    case JsonValue::Type::kBool:
      out->append(value.AsBool() ? "true" : "false");
      return;
    case JsonValue::Type::kNumber:
      WriteNumber(value.AsNumber(), out);
      return;
    case JsonValue::Type::kString:
      WriteEscapedString(value.AsString(), out);
      return;
    case JsonValue::Type::kArray: {
      const auto& array = value.AsArray();
      if (array.empty()) {
        out->append("[]");
        return;
      }
      out->push_back('[');
      for (size_t i = 0; i < array.size(); ++i) {
        if (i > 0) out->append(separator);
        newline(level + 1);
        WriteValue(array[i], indent, level + 1, out);
      }
      newline(level);
      out->push_back(']');
      return;
    }
    case JsonValue::Type::kObject: {
      const auto& object = value.AsObject();
      if (object.empty()) {
        out->append("{}");
        return;
      }
      out->push_back('{');
      for (size_t i = 0; i < object.size(); ++i) {
        if (i > 0) out->append(separator);
        newline(level + 1);
        WriteEscapedString(object[i].first, out);
        out->append(": ");
        WriteValue(object[i].second, indent, level + 1, out);
      }
      newline(level);
      out->push_back('}');
      return;
    }
  }
}

[[noreturn]] void TypeMismatch(const char* expected, JsonValue::Type actual) {
  throw IoError(fmt::format("JSON type mismatch: expected {}, got {}",
                            expected,
                            JsonTypeName(actual)));
}

}  // namespace

JsonValue::JsonValue(bool value) : type_(Type::kBool), bool_(value) {}
JsonValue::JsonValue(double value) : type_(Type::kNumber), number_(value) {}
JsonValue::JsonValue(int value) : type_(Type::kNumber), number_(value) {}
JsonValue::JsonValue(int64_t value)
    : type_(Type::kNumber), number_(static_cast<double>(value)) {}
JsonValue::JsonValue(std::string value)
    : type_(Type::kString), string_(std::move(value)) {}
JsonValue::JsonValue(const char* value)
    : type_(Type::kString), string_(value) {}

JsonValue JsonValue::MakeArray(Array elements) {
  JsonValue value;
  value.type_ = Type::kArray;
  value.array_ = std::move(elements);
  return value;
}

JsonValue JsonValue::MakeObject() {
  JsonValue value;
  value.type_ = Type::kObject;
  return value;
}

bool JsonValue::is_integer() const {
  return type_ == Type::kNumber && std::isfinite(number_) &&
         number_ == std::floor(number_) &&
         std::fabs(number_) <= kMaxExactInteger;
}

bool JsonValue::AsBool() const {
  if (type_ != Type::kBool) TypeMismatch("bool", type_);
  return bool_;
}

double JsonValue::AsNumber() const {
  if (type_ != Type::kNumber) TypeMismatch("number", type_);
  return number_;
}

int64_t JsonValue::AsInt() const {
  if (type_ != Type::kNumber) TypeMismatch("integer", type_);
  if (!is_integer()) {
    throw IoError(fmt::format("JSON type mismatch: expected an integer, got {}",
                              number_));
  }
  return static_cast<int64_t>(number_);
}

const std::string& JsonValue::AsString() const {
  if (type_ != Type::kString) TypeMismatch("string", type_);
  return string_;
}

const JsonValue::Array& JsonValue::AsArray() const {
  if (type_ != Type::kArray) TypeMismatch("array", type_);
  return array_;
}

JsonValue::Array& JsonValue::MutableArray() {
  if (type_ != Type::kArray) TypeMismatch("array", type_);
  return array_;
}

const JsonValue::Object& JsonValue::AsObject() const {
  if (type_ != Type::kObject) TypeMismatch("object", type_);
  return object_;
}

const JsonValue* JsonValue::Find(std::string_view key) const {
  if (type_ != Type::kObject) return nullptr;
  const auto it =
      std::lower_bound(object_.begin(), object_.end(), key, KeyLess);
  if (it == object_.end() || it->first != key) return nullptr;
  return &it->second;
}

void JsonValue::Set(std::string key, JsonValue value) {
  if (type_ != Type::kObject) TypeMismatch("object", type_);
  const auto it =
      std::lower_bound(object_.begin(), object_.end(), key, KeyLess);
  if (it != object_.end() && it->first == key) {
    it->second = std::move(value);
  } else {
    object_.emplace(it, std::move(key), std::move(value));
  }
}

void JsonValue::Append(JsonValue value) {
  if (type_ != Type::kArray) TypeMismatch("array", type_);
  array_.push_back(std::move(value));
}

size_t JsonValue::size() const {
  if (type_ == Type::kArray) return array_.size();
  if (type_ == Type::kObject) return object_.size();
  return 0;
}

bool JsonValue::operator==(const JsonValue& other) const {
  if (type_ != other.type_) return false;
  switch (type_) {
    case Type::kNull:
      return true;
    case Type::kBool:
      return bool_ == other.bool_;
    case Type::kNumber:
      return number_ == other.number_ ||
             (std::isnan(number_) && std::isnan(other.number_));
    case Type::kString:
      return string_ == other.string_;
    case Type::kArray:
      return array_ == other.array_;
    case Type::kObject:
      return object_ == other.object_;
  }
  return false;
}

const char* JsonTypeName(JsonValue::Type type) {
  switch (type) {
    case JsonValue::Type::kNull:
      return "null";
    case JsonValue::Type::kBool:
      return "bool";
    case JsonValue::Type::kNumber:
      return "number";
    case JsonValue::Type::kString:
      return "string";
    case JsonValue::Type::kArray:
      return "array";
    case JsonValue::Type::kObject:
      return "object";
  }
  return "unknown";
}

JsonValue ParseJson(std::string_view text, std::string_view source_name) {
  return Parser(text, source_name).ParseDocument();
}

std::string WriteJson(const JsonValue& value, int indent) {
  std::string out;
  WriteValue(value, indent, 0, &out);
  return out;
}

}  // namespace soma
