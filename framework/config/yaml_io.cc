#include "framework/config/yaml_io.h"

#include "framework/core/error.h"
#include "framework/core/file.h"

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <limits>
#include <regex>
#include <string_view>
#include <system_error>

namespace soma {
namespace {

// ---------------------------------------------------------------------------
// Scalar typing: PyYAML SafeLoader (YAML 1.1) implicit resolvers, plus the
// float pattern OmegaConf adds (`1e-3`, `1_000.5`), minus timestamps.

// The bool and null resolvers match whole words: compared as strings (a
// std::regex match of every plain scalar was most of ParseYaml's time).
bool IsYamlBool(std::string_view text) {
  static constexpr std::array<std::string_view, 18> kWords = {"yes",
                                                              "Yes",
                                                              "YES",
                                                              "no",
                                                              "No",
                                                              "NO",
                                                              "true",
                                                              "True",
                                                              "TRUE",
                                                              "false",
                                                              "False",
                                                              "FALSE",
                                                              "on",
                                                              "On",
                                                              "ON",
                                                              "off",
                                                              "Off",
                                                              "OFF"};
  return std::find(kWords.begin(), kWords.end(), text) != kWords.end();
}

bool IsYamlNull(std::string_view text) {
  return text.empty() || text == "~" || text == "null" || text == "Null" ||
         text == "NULL";
}

const std::regex& IntRegex() {
  static const std::regex kRegex(
      "[-+]?0b[0-1_]+"
      "|[-+]?0[0-7_]+"
      "|[-+]?(?:0|[1-9][0-9_]*)"
      "|[-+]?0x[0-9a-fA-F_]+"
      "|[-+]?[1-9][0-9_]*(?::[0-5]?[0-9])+");
  return kRegex;
}

const std::regex& FloatRegex() {
  static const std::regex kRegex(
      "[-+]?(?:[0-9][0-9_]*)\\.[0-9_]*(?:[eE][-+]?[0-9]+)?"
      "|[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)"
      "|\\.[0-9_]+(?:[eE][-+][0-9]+)?"
      "|[-+]?[0-9][0-9_]*(?::[0-5]?[0-9])+\\.[0-9_]*"
      "|[-+]?\\.(?:inf|Inf|INF)"
      "|\\.(?:nan|NaN|NAN)");
  return kRegex;
}

std::string WithoutUnderscores(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  for (char c : text) {
    if (c != '_') out += c;
  }
  return out;
}

/// Parses unsigned digits in `base`; throws ConfigError on overflow/garbage.
uint64_t ParseUnsigned(std::string_view digits,
                       int base,
                       std::string_view original) {
  uint64_t value = 0;
  if (digits.empty()) {
    throw ConfigError(fmt::format("Invalid integer '{}'", original));
  }
  const auto result = std::from_chars(
      digits.data(), digits.data() + digits.size(), value, base);
  if (result.ec == std::errc::result_out_of_range) {
    throw ConfigError(
        fmt::format("Integer '{}' does not fit in 64 bits", original));
  }
  if (result.ec != std::errc() || result.ptr != digits.data() + digits.size()) {
    throw ConfigError(fmt::format("Invalid integer '{}'", original));
  }
  return value;
}

/// PyYAML construct_yaml_int.
int64_t ConstructInt(std::string_view text) {
  std::string value = WithoutUnderscores(text);
  bool negative = false;
  if (!value.empty() && (value[0] == '-' || value[0] == '+')) {
    negative = value[0] == '-';
    value.erase(0, 1);
  }
  uint64_t magnitude = 0;
  if (value == "0") {
    magnitude = 0;
  } else if (value.rfind("0b", 0) == 0) {
    magnitude = ParseUnsigned(std::string_view{value}.substr(2), 2, text);
  } else if (value.rfind("0x", 0) == 0) {
    magnitude = ParseUnsigned(std::string_view{value}.substr(2), 16, text);
  } else if (!value.empty() && value[0] == '0') {
    magnitude = ParseUnsigned(std::string_view{value}.substr(1), 8, text);
  } else if (value.find(':') != std::string::npos) {
    // Sexagesimal: 1:20 = 80.
    uint64_t base = 1;
    size_t end = value.size();
    while (true) {
      const size_t colon = value.rfind(':', end - 1);
      const size_t begin = colon == std::string::npos ? 0 : colon + 1;
      const uint64_t part = ParseUnsigned(
          std::string_view{value}.substr(begin, end - begin), 10, text);
      magnitude += part * base;
      base *= 60;
      if (colon == std::string::npos) break;
      end = colon;
    }
  } else {
    magnitude = ParseUnsigned(value, 10, text);
  }
  const uint64_t limit =
      static_cast<uint64_t>(std::numeric_limits<int64_t>::max()) +
      (negative ? 1 : 0);
  if (magnitude > limit) {
    throw ConfigError(
        fmt::format("Integer '{}' does not fit in 64 bits", text));
  }
  if (negative) {
    return magnitude == limit ? std::numeric_limits<int64_t>::min()
                              : -static_cast<int64_t>(magnitude);
  }
  return static_cast<int64_t>(magnitude);
}

double ParseDecimal(const std::string& text, std::string_view original) {
  double value = 0.0;
  const auto result =
      std::from_chars(text.data(), text.data() + text.size(), value);
  if (result.ec == std::errc::result_out_of_range) {
    return std::strtod(text.c_str(), nullptr);  // ±inf or denormal/0
  }
  if (result.ec != std::errc() || result.ptr != text.data() + text.size()) {
    throw ConfigError(fmt::format("Invalid float '{}'", original));
  }
  return value;
}

/// PyYAML construct_yaml_float.
double ConstructFloat(std::string_view text) {
  std::string value = WithoutUnderscores(text);
  for (char& c : value) c = static_cast<char>(std::tolower(c));
  double sign = 1.0;
  if (!value.empty() && (value[0] == '-' || value[0] == '+')) {
    if (value[0] == '-') sign = -1.0;
    value.erase(0, 1);
  }
  if (value == ".inf") return sign * std::numeric_limits<double>::infinity();
  if (value == ".nan") return std::numeric_limits<double>::quiet_NaN();
  if (value.find(':') != std::string::npos) {
    double result = 0.0;
    double base = 1.0;
    size_t end = value.size();
    while (true) {
      const size_t colon = value.rfind(':', end - 1);
      const size_t begin = colon == std::string::npos ? 0 : colon + 1;
      result += ParseDecimal(value.substr(begin, end - begin), text) * base;
      base *= 60.0;
      if (colon == std::string::npos) break;
      end = colon;
    }
    return sign * result;
  }
  // Python's float() accepts "1." and ".5"; from_chars accepts both too.
  return sign * ParseDecimal(value, text);
}

ConfigNode WithText(ConfigNode node, const std::string& text) {
  node.set_text(text);
  return node;
}

// ---------------------------------------------------------------------------
// YAML -> ConfigNode.

constexpr std::string_view kTagStr = "tag:yaml.org,2002:str";
constexpr std::string_view kTagInt = "tag:yaml.org,2002:int";
constexpr std::string_view kTagFloat = "tag:yaml.org,2002:float";
constexpr std::string_view kTagBool = "tag:yaml.org,2002:bool";
constexpr std::string_view kTagNull = "tag:yaml.org,2002:null";
constexpr std::string_view kTagMap = "tag:yaml.org,2002:map";
constexpr std::string_view kTagSeq = "tag:yaml.org,2002:seq";

class YamlConverter {
 public:
  explicit YamlConverter(std::string_view source_name)
      : source_name_(source_name) {}

  ConfigNode Convert(const YAML::Node& yaml, int fallback_line) const {
    const int line = LineOf(yaml, fallback_line);
    ConfigNode node;
    switch (yaml.Type()) {
      case YAML::NodeType::Undefined:
      case YAML::NodeType::Null:
        node = ConfigNode::Null();
        break;
      case YAML::NodeType::Scalar:
        node = ConvertScalar(yaml, line);
        break;
      case YAML::NodeType::Sequence: {
        CheckContainerTag(yaml, kTagSeq, line);
        const OpenContainer open(this, yaml, fallback_line);
        node = ConfigNode::EmptyList();
        for (const YAML::Node& item : yaml) node.Append(Convert(item, line));
        break;
      }
      case YAML::NodeType::Map: {
        CheckContainerTag(yaml, kTagMap, line);
        const OpenContainer open(this, yaml, fallback_line);
        node = ConvertMap(yaml, line);
        break;
      }
    }
    node.set_source(SourceLocation{source_name_, line});
    return node;
  }

 private:
  // The containers being converted, outermost first. An alias inside its own
  // anchor's content (`a: &x {b: *x}`) makes yaml-cpp's node graph cyclic;
  // converting it would recurse until the stack overflows (a config fuzzer
  // finding), so it is an error, as a config tree cannot hold itself. The
  // line is the alias's (an alias node carries its anchor's mark).
  class OpenContainer {
   public:
    OpenContainer(const YamlConverter* converter,
                  const YAML::Node& yaml,
                  int line)
        : open_(&converter->open_) {
      for (const YAML::Node& outer : *open_) {
        if (outer.is(yaml)) {
          converter->Fail(line,
                          "an alias refers to a node that contains it "
                          "(recursive YAML structures are not supported)");
        }
      }
      open_->push_back(yaml);
    }
    ~OpenContainer() { open_->pop_back(); }
    OpenContainer(const OpenContainer&) = delete;
    OpenContainer& operator=(const OpenContainer&) = delete;

   private:
    std::vector<YAML::Node>* open_;
  };

  int LineOf(const YAML::Node& yaml, int fallback) const {
    const YAML::Mark mark = yaml.Mark();
    return mark.line >= 0 ? mark.line + 1 : fallback;
  }

  [[noreturn]] void Fail(int line, std::string_view what) const {
    throw ConfigError(fmt::format("{}:{}: {}", source_name_, line, what));
  }

  void CheckContainerTag(const YAML::Node& yaml,
                         std::string_view allowed,
                         int line) const {
    const std::string& tag = yaml.Tag();
    if (tag.empty() || tag == "?" || tag == "!" || tag == allowed) return;
    Fail(line, fmt::format("unsupported YAML tag '{}'", tag));
  }

  ConfigNode ConvertScalar(const YAML::Node& yaml, int line) const {
    const std::string& text = yaml.Scalar();
    const std::string& tag = yaml.Tag();
    try {
      if (tag == "?" || tag.empty()) return TypePlainScalar(text);
      if (tag == "!" || tag == kTagStr) {
        // Quoted and block scalars are strings (interpolations still count,
        // and `'???'` is Missing, as in OmegaConf).
        return ConfigNode::FromString(text);
      }
      if (tag == kTagInt) {
        if (!std::regex_match(text, IntRegex())) {
          Fail(line, fmt::format("'{}' is not a valid !!int", text));
        }
        return WithText(ConfigNode(ConstructInt(text)), text);
      }
      if (tag == kTagFloat) {
        if (std::regex_match(text, IntRegex())) {
          return WithText(ConfigNode(static_cast<double>(ConstructInt(text))),
                          text);
        }
        if (!std::regex_match(text, FloatRegex())) {
          Fail(line, fmt::format("'{}' is not a valid !!float", text));
        }
        return WithText(ConfigNode(ConstructFloat(text)), text);
      }
      if (tag == kTagBool) {
        if (!IsYamlBool(text)) {
          Fail(line, fmt::format("'{}' is not a valid !!bool", text));
        }
        return TypePlainScalar(text);
      }
      if (tag == kTagNull) return ConfigNode::Null();
    } catch (const ConfigError& error) {
      const std::string_view message = error.what();
      if (message.rfind(source_name_ + ":", 0) == 0) throw;
      Fail(line, message);
    }
    Fail(line, fmt::format("unsupported YAML tag '{}'", tag));
  }

  ConfigNode ConvertMap(const YAML::Node& yaml, int line) const {
    // Merge keys (`<<: *base` or `<<: [*a, *b]`) as in PyYAML: merged entries
    // come first, explicit entries override them.
    ConfigNode merged = ConfigNode::EmptyMap();
    ConfigNode own = ConfigNode::EmptyMap();
    for (auto it = yaml.begin(); it != yaml.end(); ++it) {
      // Copies (YAML::Node is a handle): `it->first` is a member of a
      // temporary that dies at the end of the statement.
      const YAML::Node key = it->first;
      const YAML::Node value = it->second;
      const int key_line = LineOf(key, line);
      if (!key.IsScalar() && !key.IsNull()) {
        Fail(key_line, "only scalar keys are supported");
      }
      const std::string name = key.IsNull() ? "null" : key.Scalar();
      if (key.IsScalar() && key.Tag() == "?" && name == "<<") {
        MergeKey(value, key_line, &merged);
        continue;
      }
      if (own.Has(name)) {
        Fail(key_line, fmt::format("found duplicate key '{}'", name));
      }
      own.Set(name, Convert(value, key_line));
    }
    if (merged.size() == 0) return own;
    for (auto& [name, child] : own.mutable_entries()) {
      merged.Set(name, std::move(child));
    }
    return merged;
  }

  void MergeKey(const YAML::Node& value, int line, ConfigNode* merged) const {
    std::vector<YAML::Node> sources;
    if (value.IsMap()) {
      sources.push_back(value);
    } else if (value.IsSequence()) {
      for (const YAML::Node& item : value) {
        if (!item.IsMap()) Fail(line, "merge key '<<' expects maps");
        sources.push_back(item);
      }
    } else {
      Fail(line, "merge key '<<' expects a map or a list of maps");
    }
    // Earlier sources win over later ones.
    for (const YAML::Node& source : sources) {
      const ConfigNode converted = Convert(source, line);
      for (const auto& [name, child] : converted.entries()) {
        if (!merged->Has(name)) merged->Set(name, child);
      }
    }
  }

  std::string source_name_;
  mutable std::vector<YAML::Node> open_;
};

// ---------------------------------------------------------------------------
// ConfigNode -> YAML text.

/// True if `text` cannot be written as a plain scalar in block context.
bool NeedsQuotes(std::string_view text) {
  if (text.empty()) return true;
  if (text.front() == ' ' || text.back() == ' ' || text.front() == '\t' ||
      text.back() == '\t') {
    return true;
  }
  // Bytes a YAML reader takes for a byte-order mark (UTF-16/32, or UTF-8's
  // EF BB BF) when they start the document.
  const auto first = static_cast<unsigned char>(text.front());
  if (first == 0xfe || first == 0xff || first == 0xef) return true;
  constexpr std::string_view kIndicators = "?:,[]{}#&*!|>'\"%@`";
  if (kIndicators.find(text.front()) != std::string_view::npos) return true;
  if (text.front() == '-' && (text.size() == 1 || text[1] == ' ')) return true;
  if (text.rfind("---", 0) == 0 || text.rfind("...", 0) == 0) return true;
  if (text.back() == ':') return true;
  if (text.find(": ") != std::string_view::npos ||
      text.find(":\t") != std::string_view::npos ||
      text.find(" #") != std::string_view::npos ||
      text.find("\t#") != std::string_view::npos) {
    return true;
  }
  for (unsigned char c : text) {
    if (c < 0x20 || c == 0x7f) return true;
  }
  return false;
}

bool NeedsDoubleQuotes(std::string_view text) {
  for (unsigned char c : text) {
    if ((c < 0x20 && c != '\t') || c == 0x7f) return true;
  }
  return false;
}

std::string SingleQuote(std::string_view text) {
  std::string out = "'";
  for (char c : text) {
    if (c == '\'') out += '\'';
    out += c;
  }
  out += '\'';
  return out;
}

std::string DoubleQuote(std::string_view text) {
  std::string out = "\"";
  for (char c : text) {
    const auto u = static_cast<unsigned char>(c);
    switch (c) {
      case '\\':
        out += "\\\\";
        break;
      case '"':
        out += "\\\"";
        break;
      case '\n':
        out += "\\n";
        break;
      case '\r':
        out += "\\r";
        break;
      case '\t':
        out += "\\t";
        break;
      default:
        if (u < 0x20 || u == 0x7f) {
          out += fmt::format("\\x{:02x}", u);
        } else {
          out += c;
        }
    }
  }
  out += '"';
  return out;
}

/// Writes `text` (the source form of a string-like scalar) plain if that reads
/// back as `expected`, else quoted.
std::string QuoteIfNeeded(const std::string& text, const ConfigNode& expected) {
  if (!NeedsQuotes(text)) {
    try {
      if (TypePlainScalar(text) == expected) return text;
    } catch (const ConfigError&) {
      // Not a valid plain scalar (e.g. an out-of-range int): quote it.
    }
  }
  return NeedsDoubleQuotes(text) ? DoubleQuote(text) : SingleQuote(text);
}

bool PlainRoundTrips(const ConfigNode& node) {
  const std::string& text = node.text();
  if (text.empty() || NeedsQuotes(text)) return false;
  try {
    return TypePlainScalar(text) == node;
  } catch (const ConfigError&) {
    return false;
  }
}

std::string YamlDouble(double value) {
  if (std::isnan(value)) return ".nan";
  if (std::isinf(value)) return value > 0 ? ".inf" : "-.inf";
  return FormatDouble(value);
}

/// A string's value as PyYAML writes it (OmegaConf's to_yaml of a resolved
/// config): plain unless it would read back as another type, `${` as is.
std::string RawString(const std::string& value) {
  if (!value.empty() && !NeedsQuotes(value)) {
    try {
      const ConfigNode typed = TypePlainScalar(value);
      if (typed.type() == ConfigNode::Type::kInterpolation ||
          typed.type() == ConfigNode::Type::kString) {
        return value;
      }
    } catch (const ConfigError&) {
      // Not a valid plain scalar: quote it.
    }
  }
  return NeedsDoubleQuotes(value) ? DoubleQuote(value) : SingleQuote(value);
}

std::string YamlScalar(const ConfigNode& node, bool escape_interpolations) {
  switch (node.type()) {
    case ConfigNode::Type::kNull:
      return "null";
    case ConfigNode::Type::kMissing:
      return "???";
    case ConfigNode::Type::kBool:
      if (PlainRoundTrips(node)) return node.text();
      return node.AsBool() ? "true" : "false";
    case ConfigNode::Type::kInt:
      if (PlainRoundTrips(node)) return node.text();
      return std::to_string(node.AsInt());
    case ConfigNode::Type::kDouble:
      if (PlainRoundTrips(node)) return node.text();
      return YamlDouble(node.AsDouble());
    case ConfigNode::Type::kString: {
      if (!escape_interpolations) return RawString(node.AsString());
      // text() is the escaped source form; fall back to re-escaping the value
      // if it was overridden with something inconsistent.
      std::string source = node.text();
      if (ConfigNode::FromString(source) != node) {
        source = ConfigNode::LiteralString(node.AsString()).text();
      }
      return QuoteIfNeeded(source, node);
    }
    case ConfigNode::Type::kInterpolation:
      return QuoteIfNeeded(node.text(), node);
    case ConfigNode::Type::kList:
      return node.size() == 0 ? "[]" : "[...]";
    case ConfigNode::Type::kMap:
      return node.size() == 0 ? "{}" : "{...}";
  }
  return "null";
}

constexpr size_t kMaxImplicitKeyBytes = 1024;

std::string YamlKey(const std::string& key) {
  // A plain `<<` reads back as a merge key, not as a key of that name.
  if (key == "<<") return SingleQuote(key);
  return QuoteIfNeeded(key, ConfigNode::LiteralString(key));
}

bool IsBlock(const ConfigNode& node) {
  return node.IsContainer() && node.size() > 0;
}

void EmitBlock(const ConfigNode& node,
               int indent,
               const DumpOptions& options,
               std::string* out);

/// Emits a list item whose value is a non-empty container: the child block
/// is emitted one level deeper and its first indentation becomes `- `.
void EmitNestedItem(const ConfigNode& item,
                    int indent,
                    const DumpOptions& options,
                    std::string* out) {
  const int child_indent = indent + std::max(options.indent, 2);
  std::string block;
  EmitBlock(item, child_indent, options, &block);
  std::string prefix(static_cast<size_t>(indent), ' ');
  prefix += "- ";
  prefix.append(static_cast<size_t>(child_indent - indent - 2), ' ');
  *out += prefix;
  *out += block.substr(static_cast<size_t>(child_indent));
}

void EmitBlock(const ConfigNode& node,
               int indent,
               const DumpOptions& options,
               std::string* out) {
  const std::string pad(static_cast<size_t>(indent), ' ');
  const bool escape = options.escape_interpolations;
  if (node.IsMap()) {
    for (const auto& [key, child] : node.entries()) {
      // An implicit key is at most 1024 characters (YAML 1.2, 7.4.2; yaml-cpp
      // counts bytes): a longer one is written as an explicit `? key`.
      const std::string written = YamlKey(key);
      if (written.size() > kMaxImplicitKeyBytes) {
        out->append(pad).append("? ").append(written).append("\n");
        out->append(pad).append(":");
      } else {
        *out += pad + written + ":";
      }
      if (child.IsMap() && child.size() > 0) {
        *out += "\n";
        EmitBlock(child, indent + options.indent, options, out);
      } else if (child.IsList() && child.size() > 0) {
        // PyYAML style: a sequence under a key is not indented.
        *out += "\n";
        EmitBlock(child, indent, options, out);
      } else {
        *out += " " + YamlScalar(child, escape) + "\n";
      }
    }
    return;
  }
  for (const ConfigNode& item : node.items()) {
    if (IsBlock(item)) {
      EmitNestedItem(item, indent, options, out);
    } else {
      *out += pad + "- " + YamlScalar(item, escape) + "\n";
    }
  }
}

// ---------------------------------------------------------------------------
// Flow output (override-grammar friendly).

bool MatchesOverridePrimitive(const std::string& text) {
  static const std::regex kInt("[+-]?(?:0|[1-9](?:_?[0-9])*)");
  static const std::regex kFloat(
      "[+-]?(?:(?:(?:0|[1-9](?:_?[0-9])*)\\.|(?:0|[1-9](?:_?[0-9])*)?\\.[0-9]("
      "?:_?[0-9])*)|(?:(?:0|[1-9](?:_?[0-9])*)|(?:(?:0|[1-9](?:_?[0-9])*)\\.|("
      "?:0|[1-9](?:_?[0-9])*)?\\.[0-9](?:_?[0-9])*))[eE][+-]?[0-9](?:_?[0-9])*|"
      "[iI][nN][fF]|[nN][aA][nN])");
  static const std::regex kKeyword(
      "[tT][rR][uU][eE]|[fF][aA][lL][sS][eE]|[nN]["
      "uU][lL][lL]|\\?\\?\\?");
  // Each pattern's possible first characters, checked before the regexes.
  if (text.empty()) return false;
  constexpr std::string_view kNumberStart = "+-.0123456789iInN";
  constexpr std::string_view kKeywordStart = "tTfFnN?";
  const char first = text.front();
  return (kNumberStart.find(first) != std::string_view::npos &&
          (std::regex_match(text, kInt) || std::regex_match(text, kFloat))) ||
         (kKeywordStart.find(first) != std::string_view::npos &&
          std::regex_match(text, kKeyword));
}

std::string FlowString(const std::string& value) {
  bool quote = value.empty() || MatchesOverridePrimitive(value) ||
               value.front() == ' ' || value.back() == ' ' ||
               value.front() == '\t' || value.back() == '\t';
  if (!quote) {
    for (char c : value) {
      if (std::string_view(",[]{}()=:'\"\\#\n\r").find(c) !=
          std::string_view::npos) {
        quote = true;
        break;
      }
    }
  }
  std::string body;
  for (size_t i = 0; i < value.size(); ++i) {
    if (value.compare(i, 2, "${") == 0) {
      body += "\\${";
      ++i;
    } else if (quote && value[i] == '\'') {
      body += "\\'";
    } else {
      body += value[i];
    }
  }
  return quote ? "'" + body + "'" : body;
}

void EmitFlow(const ConfigNode& node, std::string* out) {
  switch (node.type()) {
    case ConfigNode::Type::kNull:
      *out += "null";
      return;
    case ConfigNode::Type::kMissing:
      *out += "???";
      return;
    case ConfigNode::Type::kBool:
      *out += node.AsBool() ? "true" : "false";
      return;
    case ConfigNode::Type::kInt:
      *out += std::to_string(node.AsInt());
      return;
    case ConfigNode::Type::kDouble:
      *out += FormatDouble(node.AsDouble());
      return;
    case ConfigNode::Type::kString:
      *out += FlowString(node.AsString());
      return;
    case ConfigNode::Type::kInterpolation:
      *out += node.text();
      return;
    case ConfigNode::Type::kList: {
      *out += '[';
      bool first = true;
      for (const ConfigNode& item : node.items()) {
        if (!first) *out += ',';
        first = false;
        EmitFlow(item, out);
      }
      *out += ']';
      return;
    }
    case ConfigNode::Type::kMap: {
      *out += '{';
      bool first = true;
      for (const auto& [key, child] : node.entries()) {
        if (!first) *out += ',';
        first = false;
        *out += FlowString(key) + ":";
        EmitFlow(child, out);
      }
      *out += '}';
      return;
    }
  }
}

std::string Trim(std::string_view text) {
  const size_t begin = text.find_first_not_of(" \t\r");
  if (begin == std::string_view::npos) return "";
  const size_t end = text.find_last_not_of(" \t\r");
  return std::string(text.substr(begin, end - begin + 1));
}

}  // namespace

ConfigNode TypePlainScalar(const std::string& text) {
  if (IsYamlNull(text)) return ConfigNode::Null();
  if (IsYamlBool(text)) {
    const char first = text[0];
    const bool value = first == 'y' || first == 'Y' || first == 't' ||
                       first == 'T' || text == "on" || text == "On" ||
                       text == "ON";
    return WithText(ConfigNode(value), text);
  }
  const char first = text[0];
  const bool numeric_start = (first >= '0' && first <= '9') || first == '-' ||
                             first == '+' || first == '.';
  if (numeric_start) {
    if (std::regex_match(text, IntRegex())) {
      return WithText(ConfigNode(ConstructInt(text)), text);
    }
    if (std::regex_match(text, FloatRegex())) {
      return WithText(ConfigNode(ConstructFloat(text)), text);
    }
  }
  return ConfigNode::FromString(text);
}

ConfigNode ParseYaml(std::string_view text, std::string_view source_name) {
  YAML::Node document;
  try {
    document = YAML::Load(std::string(text));
  } catch (const YAML::Exception& error) {
    const int line = error.mark.line >= 0 ? error.mark.line + 1 : 0;
    throw ConfigError(fmt::format("{}:{}: {}", source_name, line, error.msg));
  }
  const YamlConverter converter(source_name);
  return converter.Convert(document, 1);
}

ConfigFile LoadConfigFile(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    throw ConfigError(
        fmt::format("Config file not found: '{}'", path.string()));
  }
  std::string text;
  try {
    text = ReadFile(path);
  } catch (const IoError& error) {
    throw ConfigError(fmt::format(
        "Cannot read config file '{}': {}", path.string(), error.what()));
  }

  ConfigFile file;
  file.path = path.string();

  // Header: the leading block of comment lines (blank lines allowed), e.g.
  // `# @package _global_`.
  size_t pos = 0;
  while (pos <= text.size()) {
    const size_t end = text.find('\n', pos);
    const std::string line = Trim(std::string_view{text}.substr(
        pos, end == std::string::npos ? std::string::npos : end - pos));
    if (!line.empty()) {
      if (line[0] != '#') break;
      const std::string comment = Trim(std::string_view{line}.substr(1));
      if (!comment.empty() && comment[0] == '@') {
        const std::string directive = comment.substr(1);
        const size_t space = directive.find_first_of(" \t");
        if (space != std::string::npos) {
          const std::string key = directive.substr(0, space);
          const std::string value =
              Trim(std::string_view{directive}.substr(space));
          if (key == "package" && !value.empty()) {
            file.package = value;
            file.has_package_directive = true;
          }
        }
      }
    }
    if (end == std::string::npos) break;
    pos = end + 1;
  }

  ConfigNode content = ParseYaml(text, file.path);
  if (content.IsNull()) {
    content = ConfigNode::EmptyMap();
    content.set_source(SourceLocation{file.path, 0});
  } else if (!content.IsMap()) {
    throw ConfigError(
        fmt::format("{}: expected a map at the top level", file.path));
  }
  content.SetSourceRecursive(SourceLocation{file.path, 0});
  file.content = std::move(content);
  return file;
}

std::string DumpYaml(const ConfigNode& node, const DumpOptions& options) {
  DumpOptions checked = options;
  checked.indent = std::max(options.indent, 1);
  if (!IsBlock(node)) {
    return YamlScalar(node, options.escape_interpolations) + "\n";
  }
  std::string out;
  EmitBlock(node, 0, checked, &out);
  return out;
}

std::string DumpFlow(const ConfigNode& node) {
  std::string out;
  EmitFlow(node, &out);
  return out;
}

}  // namespace soma
