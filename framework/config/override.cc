#include "framework/config/override.h"

#include "framework/core/error.h"
#include "framework/core/random.h"

#include <fmt/format.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fnmatch.h>
#include <limits>
#include <stdexcept>
#include <utility>

namespace soma {
namespace {

// A range() may not expand to more values than this (a typo such as
// `range(0,1e12)` would otherwise exhaust memory). Float ranges, whose every
// value is a 28-digit decimal addition (Hydra's FloatRange), stop at a tenth
// of it: 880,000 of them took 10-34 s under the fuzzer's sanitizers.
constexpr size_t kMaxRangeValues = 1000000;
constexpr size_t kMaxFloatRangeValues = 100000;

// ---------------------------------------------------------------------------
// Character classes of Hydra's OverrideLexer.g4.

bool IsAlpha(char c) {
  return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z');
}
bool IsDigit(char c) { return c >= '0' && c <= '9'; }
bool IsWs(char c) { return c == ' ' || c == '\t'; }
bool IsHighByte(char c) { return static_cast<unsigned char>(c) >= 0x80; }

// UNQUOTED_CHAR: other characters allowed in unquoted strings.
bool IsUnquotedChar(char c) {
  return c != '\0' && std::strchr("/-\\+.$%*@?|", c) != nullptr;
}

// Characters that `\` escapes in unquoted values (ESC).
bool IsEscapable(char c) {
  return c != '\0' && std::strchr("\\()[]{}:=, \t", c) != nullptr;
}

char At(std::string_view s, size_t i) { return i < s.size() ? s[i] : '\0'; }

bool EqualsIgnoreCase(std::string_view s, size_t i, std::string_view word) {
  if (i + word.size() > s.size()) return false;
  for (size_t k = 0; k < word.size(); ++k) {
    char c = s[i + k];
    if (c >= 'A' && c <= 'Z') c = static_cast<char>(c - 'A' + 'a');
    if (c != word[k]) return false;
  }
  return true;
}

// INT_UNSIGNED: '0' | [1-9] (('_')? DIGIT)*
size_t MatchIntUnsigned(std::string_view s, size_t i) {
  const char c = At(s, i);
  if (c == '0') return 1;
  if (c < '1' || c > '9') return 0;
  size_t j = i + 1;
  while (true) {
    if (IsDigit(At(s, j))) {
      ++j;
    } else if (At(s, j) == '_' && IsDigit(At(s, j + 1))) {
      j += 2;
    } else {
      break;
    }
  }
  return j - i;
}

// DIGIT (('_')? DIGIT)*
size_t MatchDigits(std::string_view s, size_t i) {
  if (!IsDigit(At(s, i))) return 0;
  size_t j = i + 1;
  while (true) {
    if (IsDigit(At(s, j))) {
      ++j;
    } else if (At(s, j) == '_' && IsDigit(At(s, j + 1))) {
      j += 2;
    } else {
      break;
    }
  }
  return j - i;
}

// POINT_FLOAT: INT_UNSIGNED '.' | INT_UNSIGNED? '.' DIGIT (('_')? DIGIT)*
size_t MatchPointFloat(std::string_view s, size_t i) {
  const size_t n = MatchIntUnsigned(s, i);
  size_t best = 0;
  if (n > 0 && At(s, i + n) == '.') best = n + 1;
  if (At(s, i + n) == '.') {
    const size_t d = MatchDigits(s, i + n + 1);
    if (d > 0) best = std::max(best, n + 1 + d);
  }
  return best;
}

// EXPONENT_FLOAT: (INT_UNSIGNED | POINT_FLOAT) [eE] [+-]? DIGIT (('_')? DIGIT)*
size_t MatchExponentFloat(std::string_view s, size_t i) {
  size_t best = 0;
  for (const size_t base : {MatchIntUnsigned(s, i), MatchPointFloat(s, i)}) {
    if (base == 0) continue;
    size_t j = i + base;
    if (At(s, j) != 'e' && At(s, j) != 'E') continue;
    ++j;
    if (At(s, j) == '+' || At(s, j) == '-') ++j;
    const size_t d = MatchDigits(s, j);
    if (d > 0) best = std::max(best, j + d - i);
  }
  return best;
}

// FLOAT: [+-]? (POINT_FLOAT | EXPONENT_FLOAT | [Ii][Nn][Ff] | [Nn][Aa][Nn])
size_t MatchFloat(std::string_view s, size_t i) {
  size_t j = i;
  if (At(s, j) == '+' || At(s, j) == '-') ++j;
  size_t n = std::max(MatchPointFloat(s, j), MatchExponentFloat(s, j));
  if (EqualsIgnoreCase(s, j, "inf") || EqualsIgnoreCase(s, j, "nan")) {
    n = std::max<size_t>(n, 3);
  }
  return n == 0 ? 0 : j - i + n;
}

// INT: [+-]? INT_UNSIGNED
size_t MatchInt(std::string_view s, size_t i) {
  size_t j = i;
  if (At(s, j) == '+' || At(s, j) == '-') ++j;
  const size_t n = MatchIntUnsigned(s, j);
  return n == 0 ? 0 : j - i + n;
}

size_t MatchBool(std::string_view s, size_t i) {
  if (EqualsIgnoreCase(s, i, "true")) return 4;
  if (EqualsIgnoreCase(s, i, "false")) return 5;
  return 0;
}

size_t MatchNull(std::string_view s, size_t i) {
  return EqualsIgnoreCase(s, i, "null") ? 4 : 0;
}

// ID: (CHAR|'_') (CHAR|DIGIT|'_'|'-')*
size_t MatchId(std::string_view s, size_t i) {
  const char c = At(s, i);
  if (!IsAlpha(c) && c != '_') return 0;
  size_t j = i + 1;
  while (IsAlpha(At(s, j)) || IsDigit(At(s, j)) || At(s, j) == '_' ||
         At(s, j) == '-') {
    ++j;
  }
  return j - i;
}

// `${...}` starting at i (s[i] == '$', s[i+1] == '{'), with nested braces.
// Returns the length or 0 when it is not closed (or empty).
size_t MatchInterpolation(std::string_view s, size_t i) {
  if (At(s, i) != '$' || At(s, i + 1) != '{') return 0;
  int depth = 1;
  for (size_t j = i + 2; j < s.size(); ++j) {
    if (s[j] == '{') {
      ++depth;
    } else if (s[j] == '}') {
      if (--depth == 0) return j == i + 2 ? 0 : j + 1 - i;
    }
  }
  return 0;
}

// Key fragments: KEY_SPECIAL (an ID that may contain `$`) and DOT_PATH.
bool IsKeySpecial(std::string_view s) {
  if (s.empty()) return false;
  if (!IsAlpha(s[0]) && s[0] != '_' && s[0] != '$') return false;
  for (const char c : s.substr(1)) {
    if (!IsAlpha(c) && !IsDigit(c) && c != '_' && c != '$' && c != '-') {
      return false;
    }
  }
  return true;
}

bool IsGroupId(std::string_view s) {
  return !s.empty() && MatchId(s, 0) == s.size();
}

// package: ID | KEY_SPECIAL | DOT_PATH, where DOT_PATH has two or more
// segments, each KEY_SPECIAL or INT_UNSIGNED (`a.b`, `list.0`).
bool IsPackage(std::string_view s) {
  if (s.find('.') == std::string_view::npos) return IsKeySpecial(s);
  size_t start = 0;
  while (true) {
    const size_t dot = s.find('.', start);
    const std::string_view seg =
        s.substr(start, dot == std::string_view::npos ? dot : dot - start);
    if (seg.empty() ||
        (!IsKeySpecial(seg) && MatchIntUnsigned(seg, 0) != seg.size())) {
      return false;
    }
    if (dot == std::string_view::npos) return true;
    start = dot + 1;
  }
}

// ---------------------------------------------------------------------------
// Scalar conversions.

std::string StripUnderscores(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  for (const char c : text) {
    if (c != '_') out.push_back(c);
  }
  return out;
}

std::optional<int64_t> ParseInt64(std::string_view text) {
  if (!text.empty() && text[0] == '+') text.remove_prefix(1);
  int64_t value = 0;
  const auto [ptr, ec] =
      std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || ptr != text.data() + text.size())
    return std::nullopt;
  return value;
}

double ParseDoubleToken(std::string_view text) {
  const std::string clean = StripUnderscores(text);
  return std::strtod(clean.c_str(), nullptr);
}

std::string_view TrimWs(std::string_view s) {
  const char* kWs = " \t\n\r\f\v";
  const size_t b = s.find_first_not_of(kWs);
  if (b == std::string_view::npos) return {};
  const size_t e = s.find_last_not_of(kWs);
  return s.substr(b, e - b + 1);
}

// Underscores are only valid between two digits (Python literals).
bool ValidUnderscores(std::string_view s) {
  for (size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '_' &&
        (i == 0 || !IsDigit(s[i - 1]) || !IsDigit(At(s, i + 1)))) {
      return false;
    }
  }
  return true;
}

// Python's int(str): optional sign, decimal digits, single underscores.
std::optional<int64_t> PythonIntFromString(std::string_view raw) {
  std::string_view s = TrimWs(raw);
  std::string_view digits = s;
  if (!digits.empty() && (digits[0] == '+' || digits[0] == '-')) {
    digits.remove_prefix(1);
  }
  if (digits.empty() || !IsDigit(digits[0]) || !ValidUnderscores(digits)) {
    return std::nullopt;
  }
  for (const char c : digits) {
    if (!IsDigit(c) && c != '_') return std::nullopt;
  }
  return ParseInt64(StripUnderscores(s));
}

// Python's float(str): decimal/exponent notation, inf, infinity, nan.
std::optional<double> PythonFloatFromString(std::string_view raw) {
  std::string_view s = TrimWs(raw);
  std::string_view body = s;
  bool negative = false;
  if (!body.empty() && (body[0] == '+' || body[0] == '-')) {
    negative = body[0] == '-';
    body.remove_prefix(1);
  }
  if (EqualsIgnoreCase(body, 0, "inf") &&
      (body.size() == 3 ||
       (body.size() == 8 && EqualsIgnoreCase(body, 0, "infinity")))) {
    return negative ? -std::numeric_limits<double>::infinity()
                    : std::numeric_limits<double>::infinity();
  }
  if (body.size() == 3 && EqualsIgnoreCase(body, 0, "nan")) {
    return std::numeric_limits<double>::quiet_NaN();
  }
  if (body.empty() || !ValidUnderscores(body)) return std::nullopt;
  bool has_digit = false;
  for (const char c : body) {
    if (IsDigit(c)) {
      has_digit = true;
    } else if (c != '.' && c != 'e' && c != 'E' && c != '+' && c != '-' &&
               c != '_') {
      return std::nullopt;
    }
  }
  if (!has_digit) return std::nullopt;
  const std::string clean = StripUnderscores(s);
  char* end = nullptr;
  const double value = std::strtod(clean.c_str(), &end);
  if (end != clean.c_str() + clean.size()) return std::nullopt;
  return value;
}

// Python's repr() of a float: shortest round-trip text, always with a decimal
// point or an exponent (`1.0`, `0.001`, `1e+16`, `inf`, `nan`).
std::string FormatDouble(double value) {
  if (std::isnan(value)) return "nan";
  if (std::isinf(value)) return value > 0 ? "inf" : "-inf";
  std::string text = fmt::format("{}", value);
  if (text.find_first_of(".eE") == std::string::npos) text += ".0";
  return text;
}

// ---------------------------------------------------------------------------
// Formatting of override values.

std::optional<ConfigNode> TryParseStandaloneValue(std::string_view text);

// Hydra's QuotedString.with_quotes(): quotes are escaped and every run of
// backslashes preceding a quote (or the closing quote) doubled. Interpolations
// are copied verbatim, as the lexer reads them (LexQuoted): a quote inside
// `${...}` is not escaped.
std::string SingleQuote(std::string_view s, char quote = '\'') {
  std::string out(1, quote);
  size_t i = 0;
  while (i < s.size()) {
    if (const size_t n = MatchInterpolation(s, i)) {
      out.append(s.substr(i, n));
      i += n;
    } else if (s[i] == '\\') {
      size_t k = 0;
      while (At(s, i + k) == '\\') ++k;
      const char next = At(s, i + k);
      const bool before_quote = next == quote || i + k == s.size();
      out.append(before_quote ? 2 * k : k, '\\');
      i += k;
    } else if (s[i] == quote) {
      out.push_back('\\');
      out.push_back(quote);
      ++i;
    } else {
      out.push_back(s[i]);
      ++i;
    }
  }
  out.push_back(quote);
  return out;
}

// Dict keys cannot be quoted: special characters are backslash-escaped.
std::string EscapeDictKey(std::string_view key) {
  std::string out;
  for (const char c : key) {
    if (IsEscapable(c)) out.push_back('\\');
    out.push_back(c);
  }
  return out;
}

// An unquoted value with its special characters backslash-escaped, complete
// interpolations copied verbatim (the lexer reads them whole, as in the
// unquoted input they came from: `${a:'b c'}` keeps its quotes and space).
std::string EscapeUnquoted(std::string_view text) {
  std::string out;
  size_t i = 0;
  while (i < text.size()) {
    if (const size_t n = MatchInterpolation(text, i)) {
      out.append(text.substr(i, n));
      i += n;
      continue;
    }
    if (IsEscapable(text[i])) out.push_back('\\');
    out.push_back(text[i]);
    ++i;
  }
  return out;
}

std::string FormatString(const ConfigNode& node, bool top_level) {
  const std::string& text = node.text();
  if (text.empty()) return top_level ? std::string() : std::string("''");
  const std::optional<ConfigNode> reparsed = TryParseStandaloneValue(text);
  // Inside a sweep, list or dict a trailing backslash would escape the `,`,
  // `]` or `}` written after the element (`a\,b` is one string): quote it.
  const bool escapes_next = !top_level && text.back() == '\\';
  if (reparsed && reparsed->type() == node.type() && reparsed->text() == text &&
      !escapes_next) {
    return text;
  }
  // A `${` that opens no complete interpolation cannot be quoted: the lexer
  // would read an interpolation from it through the closing quote (`'${'}`).
  // Written unquoted with its special characters escaped (`$\{`) it reads
  // back as the same string.
  for (size_t i = 0; i + 1 < text.size(); ++i) {
    if (text[i] == '$' && text[i + 1] == '{' &&
        MatchInterpolation(text, i) == 0) {
      std::string escaped = EscapeUnquoted(text);
      const std::optional<ConfigNode> back = TryParseStandaloneValue(escaped);
      if (back && back->type() == node.type() && back->text() == text) {
        return escaped;
      }
      break;
    }
  }
  return SingleQuote(text);
}

std::string FormatElement(const ConfigNode& node, bool top_level) {
  switch (node.type()) {
    case ConfigNode::Type::kNull:
      return "null";
    case ConfigNode::Type::kBool:
      return node.AsBool() ? "true" : "false";
    case ConfigNode::Type::kInt:
      return std::to_string(node.AsInt());
    case ConfigNode::Type::kDouble:
      return FormatDouble(node.AsDouble());
    case ConfigNode::Type::kMissing:
      return "???";
    case ConfigNode::Type::kString:
    case ConfigNode::Type::kInterpolation:
      return FormatString(node, top_level);
    case ConfigNode::Type::kList: {
      std::string out = "[";
      bool first = true;
      for (const ConfigNode& item : node.items()) {
        if (!first) out += ",";
        first = false;
        out += FormatElement(item, false);
      }
      return out + "]";
    }
    case ConfigNode::Type::kMap: {
      std::string out = "{";
      bool first = true;
      for (const auto& [key, value] : node.entries()) {
        if (!first) out += ",";
        first = false;
        out += EscapeDictKey(key) + ":" + FormatElement(value, false);
      }
      return out + "}";
    }
  }
  return {};
}

std::string DescribeValue(const ConfigNode& node) {
  const bool is_text = node.IsString() || node.IsInterpolation();
  return fmt::format(
      "{} {}",
      ConfigNode::TypeName(node.type()),
      is_text ? SingleQuote(node.text()) : FormatElement(node, false));
}

// ---------------------------------------------------------------------------
// Sorting (Python's sorted(): numbers with numbers, strings with strings,
// lists lexicographically; anything else cannot be compared).

enum class SortClass { kNumber, kString, kList, kOther };

SortClass ClassOf(const ConfigNode& node) {
  switch (node.type()) {
    case ConfigNode::Type::kBool:
    case ConfigNode::Type::kInt:
    case ConfigNode::Type::kDouble:
      return SortClass::kNumber;
    case ConfigNode::Type::kString:
    case ConfigNode::Type::kInterpolation:
      return SortClass::kString;
    case ConfigNode::Type::kList:
      return SortClass::kList;
    default:
      return SortClass::kOther;
  }
}

int CompareNodes(const ConfigNode& a, const ConfigNode& b) {
  const SortClass ca = ClassOf(a);
  const SortClass cb = ClassOf(b);
  if (ca != cb || ca == SortClass::kOther) {
    throw ConfigError(fmt::format(
        "cannot compare {} and {}", DescribeValue(a), DescribeValue(b)));
  }
  switch (ca) {
    case SortClass::kNumber: {
      if (!a.IsDouble() && !b.IsDouble()) {
        const int64_t x = a.IsBool() ? int64_t{a.AsBool()} : a.AsInt();
        const int64_t y = b.IsBool() ? int64_t{b.AsBool()} : b.AsInt();
        return x < y ? -1 : (y < x ? 1 : 0);
      }
      const auto as_long_double = [](const ConfigNode& n) -> long double {
        if (n.IsBool()) return n.AsBool() ? 1.0L : 0.0L;
        if (n.IsInt()) return static_cast<long double>(n.AsInt());
        return n.AsDouble();
      };
      const long double x = as_long_double(a);
      const long double y = as_long_double(b);
      return x < y ? -1 : (y < x ? 1 : 0);
    }
    case SortClass::kString: {
      const int c = a.text().compare(b.text());
      return c < 0 ? -1 : (c > 0 ? 1 : 0);
    }
    case SortClass::kList: {
      const auto& x = a.items();
      const auto& y = b.items();
      for (size_t i = 0; i < x.size() && i < y.size(); ++i) {
        const int c = CompareNodes(x[i], y[i]);
        if (c != 0) return c;
      }
      return x.size() < y.size() ? -1 : (x.size() > y.size() ? 1 : 0);
    }
    case SortClass::kOther:
      break;
  }
  return 0;
}

void SortNodes(std::vector<ConfigNode>& values, bool reverse) {
  std::stable_sort(values.begin(),
                   values.end(),
                   [reverse](const ConfigNode& a, const ConfigNode& b) {
                     const int c = CompareNodes(a, b);
                     return reverse ? c > 0 : c < 0;
                   });
}

void ShuffleNodes(std::vector<ConfigNode>& values, uint64_t seed) {
  Rng rng(seed);
  const std::vector<int> perm =
      rng.Permutation(static_cast<int>(values.size()));
  std::vector<ConfigNode> shuffled;
  shuffled.reserve(values.size());
  for (const int index : perm) shuffled.push_back(values[index]);
  values = std::move(shuffled);
}

// ---------------------------------------------------------------------------
// Parsed elements and the grammar functions.

/// An error while evaluating a function; reported as a parse error that names
/// the function call.
class FunctionError : public std::runtime_error {
 public:
  explicit FunctionError(const std::string& message)
      : std::runtime_error(message) {}
};

struct Parsed {
  enum class Kind { kValue, kChoice, kRange, kGlob };
  Kind kind = Kind::kValue;
  ConfigNode value;  // kValue
  /// kValue written as a quoted string: Hydra's QuotedString.with_quotes().
  std::string quoted;
  std::vector<ConfigNode> choices;         // kChoice
  std::vector<std::string> choice_quoted;  // parallel to choices ("" = none)
  bool simple_form = false;          // kChoice written `a,b` (not choice())
  ConfigNode start, stop, step;      // kRange
  std::vector<std::string> include;  // kGlob
  std::vector<std::string> exclude;  // kGlob
  bool sort = false;
  bool reverse = false;
  bool shuffle = false;
  std::optional<uint64_t> seed;

  bool IsSweep() const { return kind != Kind::kValue; }
  static Parsed Value(ConfigNode node) {
    Parsed p;
    p.value = std::move(node);
    return p;
  }
};

std::string_view KindName(const Parsed& p) {
  switch (p.kind) {
    case Parsed::Kind::kValue:
      return "value";
    case Parsed::Kind::kChoice:
      return "choice sweep";
    case Parsed::Kind::kRange:
      return "range sweep";
    case Parsed::Kind::kGlob:
      return "glob sweep";
  }
  return "value";
}

struct FunctionArg {
  std::string name;  // empty for positional arguments
  Parsed value;
};

// ---------------------------------------------------------------------------
// Hydra 1.3's FloatRange: Python decimal.Decimal built from each float's exact
// binary value, accumulated (`start += step`) in the default context (28
// significant digits, ROUND_HALF_EVEN), each value converted back with float().
// This is what makes range(0,10,3.3) end in 9.9 (not 9.899999999999999) and
// range(0.1,1,0.1) contain 0.30000000000000004, exactly as Hydra does.

constexpr size_t kDecimalPrecision = 28;

struct Decimal {
  bool negative = false;
  std::string digits;  // coefficient, most significant first; empty for zero
  int64_t exponent = 0;
};

void MultiplySmall(std::string* digits, int factor) {
  int carry = 0;
  for (size_t i = digits->size(); i-- > 0;) {
    const int v = ((*digits)[i] - '0') * factor + carry;
    (*digits)[i] = static_cast<char>('0' + v % 10);
    carry = v / 10;
  }
  while (carry > 0) {
    digits->insert(digits->begin(), static_cast<char>('0' + carry % 10));
    carry /= 10;
  }
}

void Normalize(Decimal* d) {
  const size_t first = d->digits.find_first_not_of('0');
  if (first == std::string::npos) {
    d->digits.clear();
    d->exponent = 0;
    return;
  }
  d->digits.erase(0, first);
  const size_t last = d->digits.find_last_not_of('0');
  d->exponent += static_cast<int64_t>(d->digits.size() - last - 1);
  d->digits.erase(last + 1);
}

Decimal DecimalFromInt(int64_t value) {
  Decimal d;
  d.negative = value < 0;
  const uint64_t magnitude = d.negative ? 0 - static_cast<uint64_t>(value)
                                        : static_cast<uint64_t>(value);
  d.digits = std::to_string(magnitude);
  Normalize(&d);
  return d;
}

/// decimal.Decimal(float): the exact value of the double (finite only).
Decimal DecimalFromDouble(double value) {
  Decimal d;
  d.negative = std::signbit(value);
  int exp2 = 0;
  const double fraction = std::frexp(std::fabs(value), &exp2);
  const uint64_t mantissa =
      static_cast<uint64_t>(std::ldexp(fraction, 53));  // exact
  exp2 -= 53;
  d.digits = std::to_string(mantissa);
  if (exp2 >= 0) {
    for (int i = 0; i < exp2; ++i) MultiplySmall(&d.digits, 2);
  } else {
    // m * 2^-k == m * 5^k * 10^-k
    for (int i = 0; i < -exp2; ++i) MultiplySmall(&d.digits, 5);
    d.exponent = exp2;
  }
  Normalize(&d);
  return d;
}

Decimal DecimalFromNode(const ConfigNode& node) {
  return node.IsInt() ? DecimalFromInt(node.AsInt())
                      : DecimalFromDouble(node.AsDouble());
}

/// Compares two digit strings without leading zeros.
int CompareMagnitude(const std::string& a, const std::string& b) {
  if (a.size() != b.size()) return a.size() < b.size() ? -1 : 1;
  const int c = a.compare(b);
  return c < 0 ? -1 : (c > 0 ? 1 : 0);
}

std::string AddMagnitude(const std::string& a, const std::string& b) {
  std::string out;
  int carry = 0;
  for (size_t i = 0; i < std::max(a.size(), b.size()) || carry > 0; ++i) {
    const int da = i < a.size() ? a[a.size() - 1 - i] - '0' : 0;
    const int db = i < b.size() ? b[b.size() - 1 - i] - '0' : 0;
    const int v = da + db + carry;
    out.push_back(static_cast<char>('0' + v % 10));
    carry = v / 10;
  }
  std::reverse(out.begin(), out.end());
  return out;
}

/// a - b for a >= b.
std::string SubtractMagnitude(const std::string& a, const std::string& b) {
  std::string out;
  int borrow = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    int v = (a[a.size() - 1 - i] - '0') - borrow -
            (i < b.size() ? b[b.size() - 1 - i] - '0' : 0);
    borrow = v < 0 ? 1 : 0;
    if (v < 0) v += 10;
    out.push_back(static_cast<char>('0' + v));
  }
  std::reverse(out.begin(), out.end());
  return out;
}

/// The exact sum (no rounding).
Decimal AddExact(const Decimal& x, const Decimal& y) {
  if (x.digits.empty()) return y;
  if (y.digits.empty()) return x;
  const int64_t exponent = std::min(x.exponent, y.exponent);
  const std::string a =
      x.digits + std::string(static_cast<size_t>(x.exponent - exponent), '0');
  const std::string b =
      y.digits + std::string(static_cast<size_t>(y.exponent - exponent), '0');
  Decimal out;
  out.exponent = exponent;
  if (x.negative == y.negative) {
    out.negative = x.negative;
    out.digits = AddMagnitude(a, b);
  } else {
    const int c = CompareMagnitude(a, b);
    if (c == 0) return Decimal{};  // exact cancellation: +0
    out.negative = c > 0 ? x.negative : y.negative;
    out.digits = c > 0 ? SubtractMagnitude(a, b) : SubtractMagnitude(b, a);
  }
  Normalize(&out);
  return out;
}

/// Rounds to kDecimalPrecision significant digits, ROUND_HALF_EVEN.
void RoundToContext(Decimal* d) {
  if (d->digits.size() <= kDecimalPrecision) return;
  const std::string dropped = d->digits.substr(kDecimalPrecision);
  d->digits.resize(kDecimalPrecision);
  d->exponent += static_cast<int64_t>(dropped.size());
  bool up = dropped[0] > '5';
  if (dropped[0] == '5') {
    const bool above_half =
        dropped.find_first_not_of('0', 1) != std::string::npos;
    up = above_half || (d->digits.back() - '0') % 2 == 1;
  }
  if (up) d->digits = AddMagnitude(d->digits, "1");
  Normalize(d);
}

/// Sign of x - y.
int CompareDecimal(const Decimal& x, const Decimal& y) {
  Decimal negated_y = y;
  negated_y.negative = !y.negative;
  const Decimal diff = AddExact(x, negated_y);
  if (diff.digits.empty()) return 0;
  return diff.negative ? -1 : 1;
}

/// float(Decimal): correctly rounded (strtod is).
double DecimalToDouble(const Decimal& d) {
  if (d.digits.empty()) return d.negative ? -0.0 : 0.0;
  const std::string text =
      fmt::format("{}{}e{}", d.negative ? "-" : "", d.digits, d.exponent);
  return std::strtod(text.c_str(), nullptr);
}

/// The number of values of an int range(a, b, s), s != 0, without expanding
/// it: ceil((b - a) / s) when the range is not empty, exact over all of int64
/// (b - a is computed in uint64, where it always fits).
uint64_t IntRangeLength(int64_t a, int64_t b, int64_t s) {
  if (s > 0 ? a >= b : a <= b) return 0;
  const uint64_t span =
      s > 0 ? static_cast<uint64_t>(b) - static_cast<uint64_t>(a)
            : static_cast<uint64_t>(a) - static_cast<uint64_t>(b);
  const uint64_t stride =
      s > 0 ? static_cast<uint64_t>(s) : 0 - static_cast<uint64_t>(s);
  return span / stride + (span % stride != 0 ? 1 : 0);
}

/// Checks a range's arguments and length before anything is expanded: a zero
/// step, a non-finite float start or step, or more values than the limit
/// (kMaxRangeValues for int ranges, kMaxFloatRangeValues for float ones)
/// throw, the latter with the number of values. Int lengths are exact. A
/// float range's length is ceil((stop - start) / step) in double arithmetic
/// (unbounded for an infinite stop on the step's side), which Hydra's decimal
/// accumulation (ExpandRange) can end up to one value away from: lengths up
/// to the limit + 1 pass here and ExpandRange's loop enforces the exact limit
/// (allocating at most the limit's worth of values).
void CheckRange(const ConfigNode& start,
                const ConfigNode& stop,
                const ConfigNode& step) {
  if (start.IsInt() && stop.IsInt() && step.IsInt()) {
    const int64_t s = step.AsInt();
    if (s == 0) throw FunctionError("range() step must not be zero");
    const uint64_t length = IntRangeLength(start.AsInt(), stop.AsInt(), s);
    if (length > kMaxRangeValues) {
      throw FunctionError(
          fmt::format("range() produces {} values, more than the limit of {}",
                      length,
                      kMaxRangeValues));
    }
    return;
  }
  const double a = start.AsDouble();
  const double b = stop.AsDouble();
  const double s = step.AsDouble();
  if (s == 0.0) throw FunctionError("range() step must not be zero");
  if (!std::isfinite(a) || !std::isfinite(s) || std::isnan(b)) {
    throw FunctionError("range() start and step must be finite numbers");
  }
  const double length = std::ceil((b - a) / s);  // +inf if unbounded
  if (length > static_cast<double>(kMaxFloatRangeValues) + 1.0) {
    throw FunctionError(fmt::format(
        "range() produces {} values, more than the limit of {} for a float "
        "range",
        std::isfinite(length) ? fmt::format("about {:.15g}", length)
        : std::isfinite(b)    ? std::string("more than 1e308")
                              : std::string("unboundedly many"),
        kMaxFloatRangeValues));
  }
}

std::vector<ConfigNode> ExpandRange(const ConfigNode& start,
                                    const ConfigNode& stop,
                                    const ConfigNode& step) {
  CheckRange(start, stop, step);
  std::vector<ConfigNode> values;
  if (start.IsInt() && stop.IsInt() && step.IsInt()) {
    const int64_t a = start.AsInt();
    const int64_t s = step.AsInt();
    const uint64_t length = IntRangeLength(a, stop.AsInt(), s);
    values.reserve(length);
    // a + i * s in uint64 (wrapping) arithmetic, where i * s alone may not
    // fit in int64 (range(-2^63, 2^63-1, 2^62)); the sum, which lies between
    // start and stop, converts back exactly.
    for (uint64_t i = 0; i < length; ++i) {
      values.emplace_back(static_cast<int64_t>(static_cast<uint64_t>(a) +
                                               i * static_cast<uint64_t>(s)));
    }
    return values;
  }
  const double s = step.AsDouble();
  const double b = stop.AsDouble();
  // Hydra's FloatRange (see Decimal above); an infinite stop never ends the
  // range (Decimal('Infinity') compares greater than every finite value), and
  // CheckRange has refused those whose infinite stop lies ahead.
  Decimal current = DecimalFromNode(start);
  const Decimal increment = DecimalFromNode(step);
  const bool stop_finite = std::isfinite(b);
  const Decimal limit = stop_finite ? DecimalFromNode(stop) : Decimal{};
  const auto before_stop = [&]() {
    if (!stop_finite) return s > 0 ? b > 0 : b < 0;
    const int c = CompareDecimal(current, limit);
    return s > 0 ? c < 0 : c > 0;
  };
  while (before_stop()) {
    if (values.size() >= kMaxFloatRangeValues) {
      throw FunctionError(fmt::format(
          "range() produces more than {} values, the limit for a float range",
          kMaxFloatRangeValues));
    }
    values.emplace_back(DecimalToDouble(current));
    current = AddExact(current, increment);
    RoundToContext(&current);
  }
  return values;
}

enum class CastKind { kInt, kFloat, kStr, kBool };

std::string_view CastName(CastKind kind) {
  switch (kind) {
    case CastKind::kInt:
      return "int";
    case CastKind::kFloat:
      return "float";
    case CastKind::kStr:
      return "str";
    case CastKind::kBool:
      return "bool";
  }
  return "";
}

ConfigNode CastNode(const ConfigNode& node, CastKind kind) {
  const auto fail = [&]() -> FunctionError {
    return FunctionError(fmt::format(
        "cannot cast {} to {}", DescribeValue(node), CastName(kind)));
  };
  if (node.IsList()) {
    ConfigNode out = ConfigNode::EmptyList();
    for (const ConfigNode& item : node.items())
      out.Append(CastNode(item, kind));
    return out;
  }
  if (node.IsMap()) {
    ConfigNode out = ConfigNode::EmptyMap();
    for (const auto& [key, value] : node.entries()) {
      out.Set(key, CastNode(value, kind));
    }
    return out;
  }
  const bool is_text = node.IsString() || node.IsInterpolation();
  switch (kind) {
    case CastKind::kInt:
      if (node.IsInt()) return node;
      if (node.IsBool()) return ConfigNode(int64_t{node.AsBool() ? 1 : 0});
      if (node.IsDouble()) {
        const double d = std::trunc(node.AsDouble());
        if (!std::isfinite(d) || d < -9.2233720368547758e18 ||
            d >= 9.2233720368547758e18) {
          throw fail();
        }
        return ConfigNode(static_cast<int64_t>(d));
      }
      if (is_text) {
        if (const auto v = PythonIntFromString(node.text()))
          return ConfigNode(*v);
      }
      throw fail();
    case CastKind::kFloat:
      if (node.IsDouble()) return node;
      if (node.IsInt()) return ConfigNode(static_cast<double>(node.AsInt()));
      if (node.IsBool()) return ConfigNode(node.AsBool() ? 1.0 : 0.0);
      if (is_text) {
        if (const auto v = PythonFloatFromString(node.text())) {
          return ConfigNode(*v);
        }
      }
      throw fail();
    case CastKind::kStr:
      if (is_text) return node;
      if (node.IsInt())
        return ConfigNode::FromString(std::to_string(node.AsInt()));
      if (node.IsDouble()) {
        return ConfigNode::FromString(FormatDouble(node.AsDouble()));
      }
      if (node.IsBool()) {
        return ConfigNode::FromString(node.AsBool() ? "true" : "false");
      }
      throw fail();
    case CastKind::kBool:
      if (node.IsBool()) return node;
      if (node.IsInt()) return ConfigNode(node.AsInt() != 0);
      if (node.IsDouble()) return ConfigNode(node.AsDouble() != 0.0);
      if (is_text) {
        if (EqualsIgnoreCase(node.text(), 0, "true") &&
            node.text().size() == 4) {
          return ConfigNode(true);
        }
        if (EqualsIgnoreCase(node.text(), 0, "false") &&
            node.text().size() == 5) {
          return ConfigNode(false);
        }
      }
      throw fail();
  }
  throw fail();
}

Parsed CastParsed(const Parsed& in, CastKind kind) {
  Parsed out = in;
  switch (in.kind) {
    case Parsed::Kind::kValue:
      out.value = CastNode(in.value, kind);
      out.quoted.clear();
      return out;
    case Parsed::Kind::kChoice:
      for (ConfigNode& c : out.choices) c = CastNode(c, kind);
      out.choice_quoted.clear();
      return out;
    case Parsed::Kind::kRange:
      if (kind != CastKind::kInt && kind != CastKind::kFloat) {
        throw FunctionError("a range can only be cast to int or float");
      }
      out.start = CastNode(in.start, kind);
      out.stop = CastNode(in.stop, kind);
      out.step = CastNode(in.step, kind);
      if (kind == CastKind::kInt && out.step.AsInt() == 0) {
        throw FunctionError("range() step must not be zero");
      }
      return out;
    case Parsed::Kind::kGlob:
      throw FunctionError("a glob cannot be cast");
  }
  return out;
}

// Binds Python-style arguments: `positional` names the parameters that may be
// given by position (in order), `named_only` those that must be named.
// Returns one slot per parameter (positional first, then named_only).
std::vector<std::optional<Parsed>> BindArgs(
    std::string_view function,
    const std::vector<FunctionArg>& args,
    const std::vector<std::string_view>& positional,
    const std::vector<std::string_view>& named_only) {
  std::vector<std::string_view> params = positional;
  params.insert(params.end(), named_only.begin(), named_only.end());
  std::vector<std::optional<Parsed>> slots(params.size());
  size_t next_positional = 0;
  for (const FunctionArg& arg : args) {
    size_t index = params.size();
    if (arg.name.empty()) {
      if (next_positional >= positional.size()) {
        throw FunctionError(
            fmt::format("{}() takes at most {} positional argument{}",
                        function,
                        positional.size(),
                        positional.size() == 1 ? "" : "s"));
      }
      index = next_positional++;
    } else {
      for (size_t i = 0; i < params.size(); ++i) {
        if (params[i] == arg.name) index = i;
      }
      if (index == params.size()) {
        throw FunctionError(
            fmt::format("{}() got an unexpected keyword argument '{}'",
                        function,
                        arg.name));
      }
    }
    if (slots[index]) {
      throw FunctionError(
          fmt::format("{}() got multiple values for argument '{}'",
                      function,
                      params[index]));
    }
    slots[index] = arg.value;
  }
  return slots;
}

// Splits variadic positional arguments from the named ones.
void SplitVarArgs(std::string_view function,
                  const std::vector<FunctionArg>& args,
                  const std::vector<std::string_view>& allowed_names,
                  std::vector<Parsed>* positional,
                  std::vector<std::pair<std::string, Parsed>>* named) {
  for (const FunctionArg& arg : args) {
    if (arg.name.empty()) {
      positional->push_back(arg.value);
      continue;
    }
    if (std::find(allowed_names.begin(), allowed_names.end(), arg.name) ==
        allowed_names.end()) {
      throw FunctionError(fmt::format(
          "{}() got an unexpected keyword argument '{}'", function, arg.name));
    }
    for (const auto& [name, value] : *named) {
      if (name == arg.name) {
        throw FunctionError(fmt::format(
            "{}() got multiple values for argument '{}'", function, arg.name));
      }
    }
    named->emplace_back(arg.name, arg.value);
  }
}

const Parsed* FindNamed(
    const std::vector<std::pair<std::string, Parsed>>& named,
    std::string_view name) {
  for (const auto& [n, value] : named) {
    if (n == name) return &value;
  }
  return nullptr;
}

const ConfigNode& RequireValue(std::string_view function,
                               std::string_view what,
                               const Parsed& p) {
  if (p.IsSweep()) {
    throw FunctionError(
        fmt::format("{}() argument {} must be a value, not a {}",
                    function,
                    what,
                    KindName(p)));
  }
  return p.value;
}

Parsed SimpleChoice(std::string_view function,
                    const std::vector<Parsed>& args) {
  Parsed out;
  out.kind = Parsed::Kind::kChoice;
  out.simple_form = true;
  for (size_t i = 0; i < args.size(); ++i) {
    out.choices.push_back(
        RequireValue(function, fmt::format("#{}", i + 1), args[i]));
    out.choice_quoted.push_back(args[i].quoted);
  }
  return out;
}

bool RequireBool(std::string_view function,
                 std::string_view name,
                 const Parsed& p) {
  const ConfigNode& v = RequireValue(function, name, p);
  if (!v.IsBool()) {
    throw FunctionError(fmt::format("{}() argument '{}' must be a bool, got {}",
                                    function,
                                    name,
                                    DescribeValue(v)));
  }
  return v.AsBool();
}

std::vector<std::string> RequirePatterns(std::string_view name,
                                         const Parsed& p) {
  const ConfigNode& v = RequireValue("glob", name, p);
  std::vector<std::string> patterns;
  const auto add = [&](const ConfigNode& item) {
    if (!item.IsString() && !item.IsInterpolation()) {
      throw FunctionError(
          fmt::format("glob() argument '{}' must be a string or a list of "
                      "strings, got {}",
                      name,
                      DescribeValue(item)));
    }
    patterns.push_back(item.text());
  };
  if (v.IsList()) {
    for (const ConfigNode& item : v.items()) add(item);
  } else {
    add(v);
  }
  return patterns;
}

ConfigNode RequireRangeNumber(std::string_view name, const Parsed& p) {
  const ConfigNode& v = RequireValue("range", name, p);
  if (!v.IsInt() && !v.IsDouble()) {
    throw FunctionError(
        fmt::format("range() argument '{}' must be an int or a float, got {}",
                    name,
                    DescribeValue(v)));
  }
  return v;
}

Parsed EvalChoice(const std::vector<FunctionArg>& args) {
  std::vector<Parsed> positional;
  std::vector<std::pair<std::string, Parsed>> named;
  SplitVarArgs("choice", args, {}, &positional, &named);
  if (positional.size() == 1 && positional[0].kind == Parsed::Kind::kChoice &&
      positional[0].simple_form) {
    Parsed out = positional[0];
    out.simple_form = false;
    return out;
  }
  Parsed out = SimpleChoice("choice", positional);
  out.simple_form = false;
  return out;
}

Parsed EvalRange(const std::vector<FunctionArg>& args) {
  auto slots = BindArgs("range", args, {"start", "stop", "step"}, {});
  if (!slots[0])
    throw FunctionError("range() missing required argument 'start'");
  Parsed out;
  out.kind = Parsed::Kind::kRange;
  out.start = RequireRangeNumber("start", *slots[0]);
  if (slots[1]) {
    out.stop = RequireRangeNumber("stop", *slots[1]);
  } else {
    // range(stop) shorthand, also with a named step: range(-5,step=-1).
    out.stop = out.start;
    out.start = ConfigNode(int64_t{0});
  }
  out.step =
      slots[2] ? RequireRangeNumber("step", *slots[2]) : ConfigNode(int64_t{1});
  if ((out.step.IsInt() && out.step.AsInt() == 0) ||
      (out.step.IsDouble() && out.step.AsDouble() == 0.0)) {
    throw FunctionError("range() step must not be zero");
  }
  return out;
}

Parsed EvalGlob(const std::vector<FunctionArg>& args) {
  auto slots = BindArgs("glob", args, {"include", "exclude"}, {});
  if (!slots[0])
    throw FunctionError("glob() missing required argument 'include'");
  Parsed out;
  out.kind = Parsed::Kind::kGlob;
  out.include = RequirePatterns("include", *slots[0]);
  if (slots[1]) {
    const ConfigNode& ex = RequireValue("glob", "exclude", *slots[1]);
    if (!ex.IsNull()) out.exclude = RequirePatterns("exclude", *slots[1]);
  }
  return out;
}

Parsed SortSweep(Parsed sweep, bool reverse) {
  sweep.sort = true;
  sweep.reverse = reverse;
  sweep.shuffle = false;  // sorting a shuffled sweep undoes the shuffle
  sweep.seed.reset();
  return sweep;
}

Parsed EvalSort(const std::vector<FunctionArg>& args) {
  std::vector<Parsed> positional;
  std::vector<std::pair<std::string, Parsed>> named;
  SplitVarArgs("sort", args, {"sweep", "reverse", "list"}, &positional, &named);
  bool reverse = false;
  if (const Parsed* r = FindNamed(named, "reverse")) {
    reverse = RequireBool("sort", "reverse", *r);
  }
  const Parsed* list = FindNamed(named, "list");
  const Parsed* sweep = FindNamed(named, "sweep");
  if (static_cast<int>(list != nullptr) + static_cast<int>(sweep != nullptr) +
          static_cast<int>(!positional.empty()) >
      1) {
    throw FunctionError("sort() takes either values, sweep= or list=");
  }
  if (list) {
    ConfigNode v = RequireValue("sort", "'list'", *list);
    if (!v.IsList()) {
      throw FunctionError(fmt::format(
          "sort() argument 'list' must be a list, got {}", DescribeValue(v)));
    }
    SortNodes(v.mutable_items(), reverse);
    return Parsed::Value(std::move(v));
  }
  if (sweep) {
    if (!sweep->IsSweep()) {
      throw FunctionError("sort() argument 'sweep' must be a sweep");
    }
    return SortSweep(*sweep, reverse);
  }
  if (positional.empty()) throw FunctionError("sort() requires an argument");
  if (positional.size() == 1) {
    const Parsed& arg = positional[0];
    if (arg.IsSweep()) return SortSweep(arg, reverse);
    if (arg.value.IsList()) {
      ConfigNode v = arg.value;
      SortNodes(v.mutable_items(), reverse);
      return Parsed::Value(std::move(v));
    }
    return arg;  // a single value is returned as is
  }
  Parsed out = SimpleChoice("sort", positional);
  for (const ConfigNode& c : out.choices) {
    if (c.IsContainer() || c.IsNull()) {
      throw FunctionError(fmt::format(
          "sort() values must be primitives, got {}", DescribeValue(c)));
    }
  }
  return SortSweep(std::move(out), reverse);
}

Parsed EvalShuffle(const std::vector<FunctionArg>& args) {
  std::vector<Parsed> positional;
  std::vector<std::pair<std::string, Parsed>> named;
  SplitVarArgs("shuffle", args, {"sweep", "list", "seed"}, &positional, &named);
  std::optional<uint64_t> seed;
  if (const Parsed* s = FindNamed(named, "seed")) {
    const ConfigNode& v = RequireValue("shuffle", "'seed'", *s);
    if (!v.IsInt() || v.AsInt() < 0) {
      throw FunctionError(fmt::format(
          "shuffle() argument 'seed' must be a non-negative int, got {}",
          DescribeValue(v)));
    }
    seed = static_cast<uint64_t>(v.AsInt());
  }
  const Parsed* list = FindNamed(named, "list");
  const Parsed* sweep = FindNamed(named, "sweep");
  if (static_cast<int>(list != nullptr) + static_cast<int>(sweep != nullptr) +
          static_cast<int>(!positional.empty()) >
      1) {
    throw FunctionError("shuffle() takes either values, sweep= or list=");
  }
  const auto shuffle_list = [&](ConfigNode v) {
    ShuffleNodes(v.mutable_items(), seed.value_or(0));
    return Parsed::Value(std::move(v));
  };
  const auto shuffle_sweep = [&](Parsed p) {
    p.shuffle = true;
    p.seed = seed;
    return p;
  };
  if (list) {
    const ConfigNode& v = RequireValue("shuffle", "'list'", *list);
    if (!v.IsList()) {
      throw FunctionError(
          fmt::format("shuffle() argument 'list' must be a list, got {}",
                      DescribeValue(v)));
    }
    return shuffle_list(v);
  }
  if (sweep) {
    if (!sweep->IsSweep()) {
      throw FunctionError("shuffle() argument 'sweep' must be a sweep");
    }
    return shuffle_sweep(*sweep);
  }
  if (positional.empty()) throw FunctionError("shuffle() requires an argument");
  if (positional.size() == 1) {
    const Parsed& arg = positional[0];
    if (arg.IsSweep()) return shuffle_sweep(arg);
    if (arg.value.IsList()) return shuffle_list(arg.value);
    ConfigNode single = ConfigNode::EmptyList();  // Hydra: shuffle(x) -> [x]
    single.Append(arg.value);
    return Parsed::Value(std::move(single));
  }
  return shuffle_sweep(SimpleChoice("shuffle", positional));
}

Parsed EvalCast(CastKind kind, const std::vector<FunctionArg>& args) {
  const std::string name(CastName(kind));
  std::vector<Parsed> positional;
  std::vector<std::pair<std::string, Parsed>> named;
  SplitVarArgs(name, args, {"value"}, &positional, &named);
  const Parsed* value = FindNamed(named, "value");
  if (value && !positional.empty()) {
    throw FunctionError(fmt::format(
        "{}() cannot use both positional and named arguments", name));
  }
  if (value) return CastParsed(*value, kind);
  if (positional.empty()) {
    throw FunctionError(fmt::format("{}() requires an argument", name));
  }
  if (positional.size() == 1) return CastParsed(positional[0], kind);
  return CastParsed(SimpleChoice(name, positional), kind);
}

Parsed EvalFunction(const std::string& name,
                    const std::vector<FunctionArg>& args) {
  if (name == "choice") return EvalChoice(args);
  if (name == "range") return EvalRange(args);
  if (name == "glob") return EvalGlob(args);
  if (name == "sort") return EvalSort(args);
  if (name == "shuffle") return EvalShuffle(args);
  if (name == "int") return EvalCast(CastKind::kInt, args);
  if (name == "float") return EvalCast(CastKind::kFloat, args);
  if (name == "str") return EvalCast(CastKind::kStr, args);
  if (name == "bool") return EvalCast(CastKind::kBool, args);
  if (name == "interval") {
    // Hydra's BasicSweeper rejects it the same way; it is for optimising
    // sweepers (Optuna, Nevergrad), which somalab does not have.
    throw FunctionError(
        "BasicSweeper does not support INTERVAL_SWEEP: interval() needs an "
        "optimising sweeper; sweep a list, choice() or range() instead");
  }
  if (name == "tag" || name == "extend_list") {
    throw FunctionError(fmt::format(
        "function '{}' is not supported by somalab (Hydra has it)", name));
  }
  throw FunctionError(fmt::format(
      "unknown function '{}' (available: choice, range, glob, sort, shuffle, "
      "int, float, str, bool)",
      name));
}

// ---------------------------------------------------------------------------
// Lexer (VALUE_MODE of OverrideLexer.g4).

enum class Tok {
  kQuoted,
  kPOpen,
  kComma,
  kPClose,
  kBracketOpen,
  kBracketClose,
  kBraceOpen,
  kBraceClose,
  kColon,
  kEqual,
  kFloat,
  kInt,
  kBool,
  kNull,
  kUnquotedChar,
  kId,
  kEsc,
  kWs,
  kInterpolation,
  kEnd,
};

struct Token {
  Tok type = Tok::kEnd;
  size_t pos = 0;    // offset of the significant character in the text
  std::string text;  // raw text; for kQuoted the un-escaped content
};

class OverrideParser {
 public:
  explicit OverrideParser(std::string_view text) : text_(text) {}

  Override ParseOverride();
  /// Parses `text_[begin:]` as an override value (element or choice sweep).
  Parsed ParseValue(size_t begin);

 private:
  [[noreturn]] void Fail(const std::string& problem) const {
    throw ConfigError(
        fmt::format("Error parsing override '{}': {}", text_, problem));
  }
  /// ANTLR's wording (what Hydra prints), then the column: "missing ']' at
  /// '<EOF>' (column 7)".
  [[noreturn]] void FailAt(size_t pos, const std::string& problem) const {
    const std::string at = pos >= text_.size()
                               ? std::string("'<EOF>'")
                               : fmt::format("'{}'", text_.substr(pos, 1));
    Fail(fmt::format("{} at {} (column {})", problem, at, pos + 1));
  }

  void Lex(size_t begin);
  void LexQuoted(size_t& i);
  void Push(Tok type, size_t pos, size_t begin, size_t end) {
    tokens_.push_back(
        Token{type, pos, std::string(text_.substr(begin, end - begin))});
  }

  const Token& Peek(size_t ahead = 0) const {
    return tokens_[std::min(cursor_ + ahead, tokens_.size() - 1)];
  }
  Token Next() {
    Token t = Peek();
    if (cursor_ < tokens_.size() - 1) ++cursor_;
    return t;
  }
  std::string Describe(const Token& t) const {
    if (t.type == Tok::kEnd) return "'<EOF>'";
    if (t.type == Tok::kQuoted) return "quoted string";
    return fmt::format("'{}'", TrimWs(t.text));
  }
  /// ANTLR's "mismatched input" wording (Hydra's), then the column.
  [[noreturn]] void Unexpected(const Token& t,
                               std::string_view expected) const {
    Fail(fmt::format("mismatched input {} expecting {} (column {})",
                     Describe(t),
                     expected,
                     t.pos + 1));
  }

  Parsed ParseElement();
  ConfigNode ParseElementValue(std::string_view where);
  ConfigNode ParsePrimitive();
  ConfigNode ParseList();
  ConfigNode ParseDict();
  std::string ParseDictKey();
  Parsed ParseFunction();
  void SkipWsBefore(Tok follower) {
    if (Peek().type == Tok::kWs && Peek(1).type == follower) Next();
  }

  std::string_view text_;
  std::vector<Token> tokens_;
  size_t cursor_ = 0;
};

void OverrideParser::Lex(size_t begin) {
  tokens_.clear();
  cursor_ = 0;
  const std::string_view s = text_;
  size_t i = begin;
  while (i < s.size()) {
    const char c = s[i];
    const size_t start = i;
    if (IsWs(c)) {
      size_t j = i;
      while (IsWs(At(s, j))) ++j;
      const char d = At(s, j);
      if (d != '\0' && std::strchr(",:=(", d) != nullptr) {
        size_t k = j + 1;
        while (IsWs(At(s, k))) ++k;
        const Tok type = d == ','   ? Tok::kComma
                         : d == ':' ? Tok::kColon
                         : d == '=' ? Tok::kEqual
                                    : Tok::kPOpen;
        Push(type, j, start, k);
        i = k;
      } else if (d != '\0' && std::strchr(")]}", d) != nullptr) {
        const Tok type = d == ')'   ? Tok::kPClose
                         : d == ']' ? Tok::kBracketClose
                                    : Tok::kBraceClose;
        Push(type, j, start, j + 1);
        i = j + 1;
      } else {
        Push(Tok::kWs, start, start, j);
        i = j;
      }
      continue;
    }
    switch (c) {
      case '\'':
      case '"':
        LexQuoted(i);
        continue;
      case '(':
      case ',':
      case ':':
      case '=':
      case '[':
      case '{': {
        size_t k = i + 1;
        while (IsWs(At(s, k))) ++k;
        const Tok type = c == '('   ? Tok::kPOpen
                         : c == ',' ? Tok::kComma
                         : c == ':' ? Tok::kColon
                         : c == '=' ? Tok::kEqual
                         : c == '[' ? Tok::kBracketOpen
                                    : Tok::kBraceOpen;
        Push(type, i, start, k);
        i = k;
        continue;
      }
      case ')':
        Push(Tok::kPClose, i, i, i + 1);
        ++i;
        continue;
      case ']':
        Push(Tok::kBracketClose, i, i, i + 1);
        ++i;
        continue;
      case '}':
        Push(Tok::kBraceClose, i, i, i + 1);
        ++i;
        continue;
      default:
        break;
    }
    if (c == '$') {
      if (const size_t n = MatchInterpolation(s, i)) {
        Push(Tok::kInterpolation, i, i, i + n);
        i += n;
        continue;
      }
    }
    if (c == '\\' && IsEscapable(At(s, i + 1))) {
      size_t j = i;
      while (At(s, j) == '\\' && IsEscapable(At(s, j + 1))) j += 2;
      Push(Tok::kEsc, i, i, j);
      i = j;
      continue;
    }
    // Longest match; ties go to the rule defined first in the lexer grammar.
    const std::pair<Tok, size_t> candidates[] = {
        {Tok::kFloat, MatchFloat(s, i)},
        {Tok::kInt, MatchInt(s, i)},
        {Tok::kBool, MatchBool(s, i)},
        {Tok::kNull, MatchNull(s, i)},
        {Tok::kUnquotedChar, IsUnquotedChar(c) ? size_t{1} : size_t{0}},
        {Tok::kId, MatchId(s, i)},
    };
    Tok best = Tok::kEnd;
    size_t best_len = 0;
    for (const auto& [type, len] : candidates) {
      if (len > best_len) {
        best = type;
        best_len = len;
      }
    }
    if (best_len == 0 && IsHighByte(c)) {
      // Non-ASCII text (UTF-8) is accepted as part of unquoted strings.
      best = Tok::kUnquotedChar;
      while (IsHighByte(At(s, i + best_len))) ++best_len;
    }
    if (best_len == 0) {
      FailAt(i, fmt::format("unexpected character '{}'", c));
    }
    Push(best, i, i, i + best_len);
    i += best_len;
  }
  tokens_.push_back(Token{Tok::kEnd, s.size(), ""});
}

// Quoted values: `\'` (`\"`) is a quote; a run of backslashes preceding a
// quote (escaped or closing) is halved; other backslashes are literal.
// Interpolations inside are kept verbatim (they may contain quotes).
void OverrideParser::LexQuoted(size_t& i) {
  const std::string_view s = text_;
  const char quote = s[i];
  const size_t open = i;
  std::string out;
  size_t j = i + 1;
  while (true) {
    if (j >= s.size()) {
      FailAt(open,
             fmt::format("missing closing quote ({}) for the quoted string",
                         quote));
    }
    const char c = s[j];
    if (c == '\\') {
      size_t k = 0;
      while (At(s, j + k) == '\\') ++k;
      if (At(s, j + k) == quote) {
        out.append(k / 2, '\\');
        if (k % 2 == 1) {
          out.push_back(quote);
          j += k + 1;
          continue;
        }
        j += k + 1;
        break;
      }
      out.append(k, '\\');
      j += k;
      continue;
    }
    if (c == quote) {
      ++j;
      break;
    }
    if (c == '$') {
      if (const size_t n = MatchInterpolation(s, j)) {
        out.append(s.substr(j, n));
        j += n;
        continue;
      }
    }
    out.push_back(c);
    ++j;
  }
  tokens_.push_back(Token{Tok::kQuoted, open, std::move(out)});
  i = j;
}

bool IsPrimitiveToken(Tok t) {
  switch (t) {
    case Tok::kId:
    case Tok::kNull:
    case Tok::kInt:
    case Tok::kFloat:
    case Tok::kBool:
    case Tok::kInterpolation:
    case Tok::kUnquotedChar:
    case Tok::kColon:
    case Tok::kEsc:
    case Tok::kWs:
      return true;
    default:
      return false;
  }
}

bool IsDictKeyToken(Tok t) {
  return IsPrimitiveToken(t) && t != Tok::kColon && t != Tok::kInterpolation;
}

std::string Unescape(const Token& t) {
  if (t.type != Tok::kEsc) return t.text;
  std::string out;
  for (size_t i = 1; i < t.text.size(); i += 2) out.push_back(t.text[i]);
  return out;
}

Parsed OverrideParser::ParseValue(size_t begin) {
  // EQUAL: '=' WS? -- leading whitespace belongs to the '='.
  while (IsWs(At(text_, begin))) ++begin;
  Lex(begin);
  if (Peek().type == Tok::kEnd)
    return Parsed::Value(ConfigNode::FromString(""));
  Parsed first = ParseElement();
  if (Peek().type == Tok::kComma) {
    std::vector<Parsed> elements = {std::move(first)};
    while (Peek().type == Tok::kComma) {
      Next();
      const Token& at = Peek();
      Parsed element = ParseElement();
      if (element.IsSweep()) {
        FailAt(at.pos,
               fmt::format("a {} cannot be an element of a choice sweep",
                           KindName(element)));
      }
      elements.push_back(std::move(element));
    }
    if (elements[0].IsSweep()) {
      FailAt(begin,
             fmt::format("a {} cannot be an element of a choice sweep",
                         KindName(elements[0])));
    }
    Parsed sweep;
    sweep.kind = Parsed::Kind::kChoice;
    sweep.simple_form = true;
    for (Parsed& e : elements) {
      sweep.choices.push_back(std::move(e.value));
      sweep.choice_quoted.push_back(std::move(e.quoted));
    }
    first = std::move(sweep);
  }
  SkipWsBefore(Tok::kEnd);
  if (Peek().type != Tok::kEnd) Unexpected(Peek(), "{',', <EOF>}");
  return first;
}

Parsed OverrideParser::ParseElement() {
  const Token& t = Peek();
  switch (t.type) {
    case Tok::kBracketOpen:
      return Parsed::Value(ParseList());
    case Tok::kBraceOpen:
      return Parsed::Value(ParseDict());
    case Tok::kQuoted: {
      const char quote = text_[t.pos];
      const std::string content = Next().text;
      Parsed p = Parsed::Value(ConfigNode::FromString(content));
      p.quoted = SingleQuote(content, quote);
      // Trailing whitespace after a quoted value is ignored.
      SkipWsBefore(Tok::kEnd);
      return p;
    }
    case Tok::kId:
      if (Peek(1).type == Tok::kPOpen) return ParseFunction();
      return Parsed::Value(ParsePrimitive());
    default:
      break;
  }
  if (IsPrimitiveToken(t.type)) return Parsed::Value(ParsePrimitive());
  if (t.type == Tok::kEnd) FailAt(t.pos, "missing value");
  Unexpected(t, "a value");
}

ConfigNode OverrideParser::ParseElementValue(std::string_view where) {
  const Token& at = Peek();
  Parsed p = ParseElement();
  if (p.IsSweep()) {
    FailAt(at.pos,
           fmt::format("a {} is not allowed inside a {}", KindName(p), where));
  }
  return std::move(p.value);
}

ConfigNode OverrideParser::ParsePrimitive() {
  std::vector<Token> parts;
  while (IsPrimitiveToken(Peek().type)) parts.push_back(Next());
  size_t first = 0;
  size_t last = parts.size();
  if (!parts.empty() && parts.front().type == Tok::kWs) ++first;
  if (last > first && parts.back().type == Tok::kWs) --last;
  if (first >= last) {
    FailAt(parts.empty() ? Peek().pos : parts.front().pos,
           "a value cannot be only whitespace");
  }
  if (last - first > 1) {
    std::string text;
    for (size_t k = first; k < last; ++k) text += Unescape(parts[k]);
    return ConfigNode::FromString(std::move(text));
  }
  const Token& t = parts[first];
  switch (t.type) {
    case Tok::kInt: {
      const std::optional<int64_t> v = ParseInt64(StripUnderscores(t.text));
      if (!v) FailAt(t.pos, fmt::format("integer {} is out of range", t.text));
      return ConfigNode(*v);
    }
    case Tok::kFloat:
      return ConfigNode(ParseDoubleToken(t.text));
    case Tok::kBool:
      return ConfigNode(EqualsIgnoreCase(t.text, 0, "true"));
    case Tok::kNull:
      return ConfigNode::Null();
    default:
      return ConfigNode::FromString(Unescape(t));
  }
}

ConfigNode OverrideParser::ParseList() {
  Next();  // '['
  ConfigNode list = ConfigNode::EmptyList();
  if (Peek().type == Tok::kBracketClose) {
    Next();
    return list;
  }
  while (true) {
    list.Append(ParseElementValue("list"));
    const Token& t = Peek();
    if (t.type == Tok::kComma) {
      Next();
      continue;
    }
    if (t.type == Tok::kBracketClose) {
      Next();
      return list;
    }
    if (t.type == Tok::kEnd) FailAt(t.pos, "missing ']'");
    Unexpected(t, "{',', ']'}");
  }
}

std::string OverrideParser::ParseDictKey() {
  std::vector<Token> parts;
  while (IsDictKeyToken(Peek().type)) parts.push_back(Next());
  std::string key;
  size_t first = 0;
  size_t last = parts.size();
  if (!parts.empty() && parts.front().type == Tok::kWs) ++first;
  if (last > first && parts.back().type == Tok::kWs) --last;
  for (size_t k = first; k < last; ++k) key += Unescape(parts[k]);
  if (key.empty()) {
    const Token& t = Peek();
    if (t.type == Tok::kEnd) FailAt(t.pos, "missing '}'");
    Unexpected(t, "a dictionary key");
  }
  return key;
}

ConfigNode OverrideParser::ParseDict() {
  Next();  // '{'
  ConfigNode dict = ConfigNode::EmptyMap();
  if (Peek().type == Tok::kBraceClose) {
    Next();
    return dict;
  }
  while (true) {
    const std::string key = ParseDictKey();
    if (Peek().type != Tok::kColon) {
      if (Peek().type == Tok::kEnd) FailAt(Peek().pos, "missing ':'");
      Unexpected(Peek(), "':'");
    }
    Next();
    dict.Set(key, ParseElementValue("dictionary"));
    const Token& t = Peek();
    if (t.type == Tok::kComma) {
      Next();
      continue;
    }
    if (t.type == Tok::kBraceClose) {
      Next();
      return dict;
    }
    if (t.type == Tok::kEnd) FailAt(t.pos, "missing '}'");
    Unexpected(t, "{',', '}'}");
  }
}

Parsed OverrideParser::ParseFunction() {
  const Token name = Next();
  Next();  // '('
  std::vector<FunctionArg> args;
  bool seen_named = false;
  if (Peek().type == Tok::kPClose) {
    Next();
  } else {
    while (true) {
      FunctionArg arg;
      const Token& at = Peek();
      if (at.type == Tok::kId && Peek(1).type == Tok::kEqual) {
        arg.name = Next().text;
        Next();  // '='
        seen_named = true;
      } else if (seen_named) {
        FailAt(at.pos, "positional argument follows keyword argument");
      }
      arg.value = ParseElement();
      args.push_back(std::move(arg));
      const Token& t = Peek();
      if (t.type == Tok::kComma) {
        Next();
        continue;
      }
      if (t.type == Tok::kPClose) {
        Next();
        break;
      }
      if (t.type == Tok::kEnd) FailAt(t.pos, "missing ')'");
      Unexpected(t, "{',', ')'}");
    }
  }
  const size_t end = cursor_ > 0 ? tokens_[cursor_ - 1].pos + 1 : text_.size();
  const std::string_view call = text_.substr(name.pos, end - name.pos);
  try {
    Parsed result = EvalFunction(name.text, args);
    if (result.kind == Parsed::Kind::kRange) {
      // Validate now so that errors name the call (without expanding).
      CheckRange(result.start, result.stop, result.step);
    }
    return result;
  } catch (const FunctionError& e) {
    Fail(fmt::format("{} in '{}'", e.what(), call));
  } catch (const ConfigError& e) {
    Fail(fmt::format("{} in '{}'", e.what(), call));
  }
}

Override OverrideParser::ParseOverride() {
  Override o;
  o.input = std::string(text_);
  size_t i = 0;
  if (At(text_, 0) == '~') {
    o.type = OverrideType::kDelete;
    i = 1;
  } else if (At(text_, 0) == '+' && At(text_, 1) == '+') {
    o.type = OverrideType::kForceAdd;
    i = 2;
  } else if (At(text_, 0) == '+') {
    o.type = OverrideType::kAdd;
    i = 1;
  }
  const size_t key_begin = i;
  size_t eq = text_.find('=', key_begin);
  if (eq == std::string_view::npos) eq = text_.size();
  const std::string_view key = text_.substr(key_begin, eq - key_begin);
  if (key.empty()) FailAt(key_begin, "missing key");
  if (key.find("..") != std::string_view::npos) {
    Fail(fmt::format("invalid key '{}': '..' is not allowed", key));
  }
  if (key.find('\\') != std::string_view::npos) {
    Fail(fmt::format("invalid key '{}': backslashes are not allowed", key));
  }
  for (size_t k = 0; k < key.size(); ++k) {
    const char c = key[k];
    if (!IsAlpha(c) && !IsDigit(c) && std::strchr("_-$./@", c) == nullptr) {
      FailAt(key_begin + k, fmt::format("unexpected character '{}' in key", c));
    }
  }
  const size_t at = key.find('@');
  const std::string_view target = key.substr(0, at);
  if (at != std::string_view::npos) {
    const std::string_view package = key.substr(at + 1);
    if (package.find('@') != std::string_view::npos) {
      Fail(fmt::format("invalid key '{}': more than one '@'", key));
    }
    if (!package.empty() && !IsPackage(package)) {
      Fail(fmt::format("invalid package '{}' in key '{}'", package, key));
    }
    // An empty package (`group@=opt`) is the global package.
    o.package = package.empty() ? "_global_" : std::string(package);
  }
  if (target.empty()) FailAt(key_begin, "missing key");
  if (target.find('/') != std::string_view::npos) {
    size_t start = 0;
    while (true) {
      const size_t slash = target.find('/', start);
      const std::string_view seg = target.substr(
          start, slash == std::string_view::npos ? slash : slash - start);
      if (!IsGroupId(seg)) {
        Fail(fmt::format("invalid config group '{}' in key '{}'", target, key));
      }
      if (slash == std::string_view::npos) break;
      start = slash + 1;
    }
  } else if (!IsPackage(target)) {
    Fail(fmt::format("invalid key '{}'", target));
  }
  o.key = std::string(target);

  if (eq == text_.size()) {
    if (o.type != OverrideType::kDelete) FailAt(eq, "missing '='");
    return o;  // `~key`: no value
  }
  Parsed value = ParseValue(eq + 1);
  switch (value.kind) {
    case Parsed::Kind::kValue:
      o.value = std::move(value.value);
      break;
    case Parsed::Kind::kChoice:
    case Parsed::Kind::kRange:
    case Parsed::Kind::kGlob: {
      SweepSpec spec;
      spec.kind = value.kind == Parsed::Kind::kChoice ? SweepSpec::Kind::kChoice
                  : value.kind == Parsed::Kind::kRange ? SweepSpec::Kind::kRange
                                                       : SweepSpec::Kind::kGlob;
      if (value.kind == Parsed::Kind::kChoice) {
        spec.values = std::move(value.choices);
        spec.quoted = std::move(value.choice_quoted);
      } else if (value.kind == Parsed::Kind::kRange) {
        try {
          spec.values = ExpandRange(value.start, value.stop, value.step);
        } catch (const FunctionError& e) {
          Fail(e.what());
        }
      }
      spec.glob_include = std::move(value.include);
      spec.glob_exclude = std::move(value.exclude);
      spec.sort = value.sort;
      spec.sort_reverse = value.reverse;
      spec.shuffle = value.shuffle;
      spec.shuffle_seed = value.seed;
      o.sweep = std::move(spec);
      break;
    }
  }
  return o;
}

std::optional<ConfigNode> TryParseStandaloneValue(std::string_view text) {
  try {
    OverrideParser parser(text);
    Parsed p = parser.ParseValue(0);
    if (p.IsSweep()) return std::nullopt;
    return std::move(p.value);
  } catch (const ConfigError&) {
    return std::nullopt;
  }
}

std::string FormatSweep(const SweepSpec& spec) {
  const auto seed_suffix = [&]() {
    return spec.shuffle_seed ? fmt::format(",seed={}", *spec.shuffle_seed)
                             : std::string();
  };
  if (spec.kind == SweepSpec::Kind::kGlob) {
    const auto pattern_list = [](const std::vector<std::string>& patterns) {
      std::string out = "[";
      for (size_t i = 0; i < patterns.size(); ++i) {
        if (i > 0) out += ",";
        out += FormatElement(ConfigNode::FromString(patterns[i]), false);
      }
      return out + "]";
    };
    std::string out = "glob(" + pattern_list(spec.glob_include);
    if (!spec.glob_exclude.empty()) {
      out += ",exclude=" + pattern_list(spec.glob_exclude);
    }
    out += ")";
    if (spec.sort) {
      out = "sort(" + out + (spec.sort_reverse ? ",reverse=true)" : ")");
    }
    if (spec.shuffle) out = "shuffle(" + out + seed_suffix() + ")";
    return out;
  }
  std::vector<ConfigNode> values = spec.values;
  if (spec.sort) SortNodes(values, spec.sort_reverse);
  std::string joined;
  for (size_t i = 0; i < values.size(); ++i) {
    if (i > 0) joined += ",";
    joined += FormatElement(values[i], false);
  }
  if (spec.shuffle)
    return "shuffle(choice(" + joined + ")" + seed_suffix() + ")";
  if (values.size() >= 2) return joined;
  return "choice(" + joined + ")";
}

}  // namespace

std::string Override::KeyWithPackage() const {
  return package.empty() ? key : key + "@" + package;
}

std::string Override::ToString() const {
  std::string out;
  switch (type) {
    case OverrideType::kChange:
      break;
    case OverrideType::kAdd:
      out = "+";
      break;
    case OverrideType::kForceAdd:
      out = "++";
      break;
    case OverrideType::kDelete:
      out = "~";
      break;
  }
  out += KeyWithPackage();
  if (sweep) {
    out += "=" + FormatSweep(*sweep);
  } else if (value) {
    out += "=" + FormatOverrideValue(*value);
  }
  return out;
}

Override ParseOverride(std::string_view text) {
  return OverrideParser(text).ParseOverride();
}

std::vector<Override> ParseOverrides(const std::vector<std::string>& args) {
  std::vector<Override> overrides;
  overrides.reserve(args.size());
  for (const std::string& arg : args) overrides.push_back(ParseOverride(arg));
  return overrides;
}

std::vector<std::string> ExpandGlob(const SweepSpec& glob,
                                    const std::vector<std::string>& options) {
  const auto matches_any = [](const std::string& name,
                              const std::vector<std::string>& patterns) {
    for (const std::string& pattern : patterns) {
      if (::fnmatch(pattern.c_str(), name.c_str(), 0) == 0) return true;
    }
    return false;
  };
  std::vector<std::string> names;
  for (const std::string& name : options) {
    if (matches_any(name, glob.glob_include) &&
        !matches_any(name, glob.glob_exclude)) {
      names.push_back(name);
    }
  }
  std::sort(names.begin(), names.end());
  names.erase(std::unique(names.begin(), names.end()), names.end());
  return names;
}

std::vector<ConfigNode> SweepValues(
    const SweepSpec& spec, const std::vector<std::string>& glob_options) {
  std::vector<ConfigNode> values;
  if (spec.kind == SweepSpec::Kind::kGlob) {
    for (const std::string& name : ExpandGlob(spec, glob_options)) {
      values.push_back(ConfigNode::FromString(name));
    }
  } else {
    values = spec.values;
  }
  if (spec.sort) {
    try {
      SortNodes(values, spec.sort_reverse);
    } catch (const ConfigError& e) {
      throw ConfigError(
          fmt::format("Cannot sort the sweep values: {}", e.what()));
    }
  }
  if (spec.shuffle) ShuffleNodes(values, spec.shuffle_seed.value_or(0));
  return values;
}

std::string FormatOverrideValue(const ConfigNode& value) {
  return FormatElement(value, true);
}

std::vector<std::string> SweepValueStrings(
    const SweepSpec& spec, const std::vector<std::string>& glob_options) {
  const std::vector<ConfigNode> values = SweepValues(spec, glob_options);
  // sort()/shuffle() reorder the values: match each back to its element.
  std::vector<bool> used(spec.values.size(), false);
  std::vector<std::string> out;
  out.reserve(values.size());
  for (const ConfigNode& value : values) {
    std::string text;
    if (spec.kind == SweepSpec::Kind::kChoice) {
      for (size_t i = 0; i < spec.values.size(); ++i) {
        if (used[i] || !(spec.values[i] == value)) continue;
        used[i] = true;
        if (i < spec.quoted.size()) text = spec.quoted[i];
        break;
      }
    }
    out.push_back(text.empty() ? FormatOverrideValue(value) : text);
  }
  return out;
}

}  // namespace soma
