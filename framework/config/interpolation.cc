#include "framework/config/interpolation.h"

#include "framework/config/yaml_io.h"
#include "framework/core/error.h"
#include "framework/core/logging.h"

#include <fmt/format.h>

#include <algorithm>
#include <charconv>
#include <cstdlib>
#include <ctime>
#include <memory>
#include <regex>
#include <system_error>
#include <utility>

namespace soma {
namespace {

constexpr std::string_view kDefaultNowPattern = "%Y-%m-%d_%H-%M-%S";

// ---------------------------------------------------------------------------
// Syntax tree of an OmegaConf string (OmegaConfGrammarParser.g4, the subset
// used by configs: node references, resolver calls, quoted values, lists and
// dicts as resolver arguments, escapes).

struct Interp;
using InterpPtr = std::shared_ptr<const Interp>;

/// A piece of a string: literal text or one interpolation.
struct Piece {
  std::string literal;
  InterpPtr interp;  // null for literal pieces
};

/// One key of a node reference (`a`, `[a]`, `${x}`), or one part of a
/// resolver name.
struct KeyPart {
  std::string text;
  InterpPtr interp;  // a nested interpolation used as the key
  bool bracket = false;
};

struct DictEntry;

/// A resolver argument.
struct Element {
  enum class Kind { kPrimitive, kQuoted, kList, kDict };
  Kind kind = Kind::kPrimitive;
  std::vector<Piece> pieces;   // kPrimitive and kQuoted
  bool escaped = false;        // kPrimitive with an escape: always a string
  std::vector<Element> items;  // kList
  // kDict. Not std::pair<std::string, Element>: a pair of an incomplete type
  // does not compile with clang and libstdc++ 12.
  std::vector<DictEntry> entries;
};

struct DictEntry {
  std::string key;
  Element value;
};

struct Interp {
  bool is_resolver = false;
  int dots = 0;               // leading dots of a relative node reference
  std::vector<KeyPart> keys;  // node reference keys, or the resolver name
  std::vector<Element> args;  // resolver arguments
};

/// Thrown by the parser; turned into a ConfigError with context.
struct GrammarError {
  std::string message;
};

bool IsIdStart(char c) {
  return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || c == '_';
}

bool IsId(std::string_view text) {
  if (text.empty() || !IsIdStart(text[0])) return false;
  return std::all_of(text.begin() + 1, text.end(), [](char c) {
    return IsIdStart(c) || (c >= '0' && c <= '9') || c == '-';
  });
}

class Parser {
 public:
  explicit Parser(std::string_view text) : text_(text) {}

  /// configValue: a top-level string with interpolations.
  std::vector<Piece> ParseTopLevel() {
    std::vector<Piece> pieces;
    std::string literal;
    auto flush = [&] {
      if (!literal.empty())
        pieces.push_back(Piece{std::move(literal), nullptr});
      literal.clear();
    };
    while (!AtEnd()) {
      const char c = text_[pos_];
      if (c == '\\') {
        const size_t run = BackslashRun();
        const size_t after = pos_ + run;
        if (text_.substr(after, 2) == "${") {
          literal.append(run / 2, '\\');
          if (run % 2 == 1) {  // escaped: a literal `${`
            literal += "${";
            pos_ = after + 2;
          } else {
            pos_ = after;  // the interpolation is parsed next
          }
        } else {
          literal.append(run, '\\');
          pos_ = after;
        }
        continue;
      }
      if (StartsWith("${")) {
        flush();
        pieces.push_back(Piece{"", ParseInterp()});
        continue;
      }
      literal += c;
      ++pos_;
    }
    flush();
    return pieces;
  }

  /// singleElement in VALUE_MODE (oc.decode): one element, nothing after.
  Element ParseSingleElement() {
    SkipWs();
    if (AtEnd()) return EmptyStringElement();
    Element element = ParseElement('\0');
    SkipWs();
    if (!AtEnd()) {
      Fail(fmt::format("unexpected '{}' after the value", text_[pos_]));
    }
    return element;
  }

  /// A bare interpolation key (`a.b`, `.x`, `a[0]`) as used by oc.select.
  InterpPtr ParseKeyOnly() {
    auto interp = ParseNodeReference();
    SkipWs();
    if (!AtEnd()) Fail("unexpected trailing characters in a key");
    return interp;
  }

 private:
  [[noreturn]] void Fail(std::string_view why) const {
    throw GrammarError{fmt::format("{} at column {}", why, pos_ + 1)};
  }

  bool AtEnd() const { return pos_ >= text_.size(); }
  char Peek() const { return AtEnd() ? '\0' : text_[pos_]; }
  bool StartsWith(std::string_view prefix) const {
    return text_.substr(pos_, prefix.size()) == prefix;
  }
  void SkipWs() {
    while (!AtEnd() && (text_[pos_] == ' ' || text_[pos_] == '\t')) ++pos_;
  }
  size_t BackslashRun() const {
    size_t end = pos_;
    while (end < text_.size() && text_[end] == '\\') ++end;
    return end - pos_;
  }
  void Expect(char c) {
    if (Peek() != c) {
      if (AtEnd()) Fail(fmt::format("missing '{}'", c));
      Fail(fmt::format("expected '{}' but found '{}'", c, Peek()));
    }
    ++pos_;
  }

  /// At `${`: a node reference or a resolver call.
  InterpPtr ParseInterp() {
    pos_ += 2;
    SkipWs();
    auto interp = std::make_shared<Interp>();
    while (Peek() == '.') {
      ++interp->dots;
      ++pos_;
    }
    bool name_like = interp->dots == 0;
    if (Peek() == '[') {
      interp->keys.push_back(ParseBracketPart());
      name_like = false;
    } else {
      interp->keys.push_back(ParseKeyPart());
    }
    while (true) {
      if (Peek() == '.') {
        ++pos_;
        interp->keys.push_back(ParseKeyPart());
        continue;
      }
      if (Peek() == '[') {
        interp->keys.push_back(ParseBracketPart());
        name_like = false;
        continue;
      }
      SkipWs();
      if (Peek() == '}') {
        ++pos_;
        return interp;
      }
      if (Peek() == ':') {
        if (!name_like) Fail("invalid resolver name");
        for (const KeyPart& part : interp->keys) {
          if (!part.interp && !IsId(part.text)) {
            Fail(fmt::format("invalid resolver name part '{}'", part.text));
          }
        }
        ++pos_;
        interp->is_resolver = true;
        interp->args = ParseSequence('}');
        return interp;
      }
      if (AtEnd()) Fail("missing '}'");
      Fail(fmt::format("unexpected character '{}' in interpolation", Peek()));
    }
  }

  /// A node reference without `${ }` (oc.select keys).
  InterpPtr ParseNodeReference() {
    auto interp = std::make_shared<Interp>();
    SkipWs();
    while (Peek() == '.') {
      ++interp->dots;
      ++pos_;
    }
    interp->keys.push_back(Peek() == '[' ? ParseBracketPart() : ParseKeyPart());
    while (Peek() == '.' || Peek() == '[') {
      if (Peek() == '.') {
        ++pos_;
        interp->keys.push_back(ParseKeyPart());
      } else {
        interp->keys.push_back(ParseBracketPart());
      }
    }
    return interp;
  }

  /// configKey: a nested interpolation, or characters other than
  /// `\{}()[]:. \t'"` (INTER_KEY).
  KeyPart ParseKeyPart() {
    KeyPart part;
    if (StartsWith("${")) {
      part.interp = ParseInterp();
      return part;
    }
    constexpr std::string_view kSpecial = "\\{}()[]:. \t'\"";
    const size_t begin = pos_;
    while (!AtEnd() && kSpecial.find(text_[pos_]) == std::string_view::npos) {
      ++pos_;
    }
    if (pos_ == begin) {
      if (AtEnd()) Fail("missing key");
      Fail(fmt::format("unexpected character '{}' in key", Peek()));
    }
    part.text = std::string(text_.substr(begin, pos_ - begin));
    return part;
  }

  KeyPart ParseBracketPart() {
    Expect('[');
    KeyPart part = ParseKeyPart();
    Expect(']');
    part.bracket = true;
    return part;
  }

  static Element EmptyStringElement() {
    Element element;
    element.kind = Element::Kind::kQuoted;
    return element;
  }

  /// sequence: elements separated by commas up to `close` (consumed). Missing
  /// elements (`a,,b`, a trailing comma) are empty strings, as in OmegaConf.
  std::vector<Element> ParseSequence(char close) {
    std::vector<Element> elements;
    SkipWs();
    if (Peek() == close) {
      ++pos_;
      return elements;
    }
    bool previous_comma = true;
    while (true) {
      SkipWs();
      if (AtEnd()) Fail(fmt::format("missing '{}'", close));
      const char c = Peek();
      if (c == ',') {
        if (previous_comma) elements.push_back(EmptyStringElement());
        previous_comma = true;
        ++pos_;
        continue;
      }
      if (c == close) {
        if (previous_comma) elements.push_back(EmptyStringElement());
        ++pos_;
        return elements;
      }
      if (!previous_comma) {
        Fail(fmt::format("expected ',' or '{}' but found '{}'", close, c));
      }
      elements.push_back(ParseElement(close));
      previous_comma = false;
    }
  }

  Element ParseElement(char close) {
    SkipWs();
    const char c = Peek();
    if (c == '[') {
      ++pos_;
      Element element;
      element.kind = Element::Kind::kList;
      element.items = ParseSequence(']');
      return element;
    }
    if (c == '{') {
      ++pos_;
      return ParseDict();
    }
    if (c == '\'' || c == '"') return ParseQuoted(c);
    return ParsePrimitive(close, /*is_dict_key=*/false);
  }

  Element ParseDict() {
    Element element;
    element.kind = Element::Kind::kDict;
    SkipWs();
    if (Peek() == '}') {
      ++pos_;
      return element;
    }
    while (true) {
      SkipWs();
      Element key = ParsePrimitive(':', /*is_dict_key=*/true);
      std::string key_text;
      for (const Piece& piece : key.pieces) key_text += piece.literal;
      if (key_text.empty()) Fail("empty dict key");
      Expect(':');
      Element value = ParseElement('}');
      element.entries.push_back(
          DictEntry{std::move(key_text), std::move(value)});
      SkipWs();
      if (Peek() == ',') {
        ++pos_;
        continue;
      }
      Expect('}');
      return element;
    }
  }

  /// An unquoted value: text, escapes (`\,` `\ ` ...) and interpolations;
  /// unescaped surrounding whitespace is dropped.
  Element ParsePrimitive(char close, bool is_dict_key) {
    Element element;
    std::string literal;
    std::string pending_ws;
    auto flush = [&] {
      if (!literal.empty()) {
        element.pieces.push_back(Piece{std::move(literal), nullptr});
      }
      literal.clear();
    };
    while (!AtEnd()) {
      const char c = text_[pos_];
      if (c == ',' || c == close) break;
      if (is_dict_key && c == ':') break;
      if (c == ' ' || c == '\t') {
        pending_ws += c;
        ++pos_;
        continue;
      }
      literal += pending_ws;
      pending_ws.clear();
      if (c == '\\') {
        constexpr std::string_view kEscapable = "\\()[]{}:=, \t";
        if (pos_ + 1 < text_.size() &&
            kEscapable.find(text_[pos_ + 1]) != std::string_view::npos) {
          literal += text_[pos_ + 1];
          element.escaped = true;
          pos_ += 2;
        } else {
          literal += c;
          ++pos_;
        }
        continue;
      }
      if (StartsWith("${")) {
        if (is_dict_key) Fail("interpolations are not allowed in dict keys");
        flush();
        element.pieces.push_back(Piece{"", ParseInterp()});
        continue;
      }
      if (c == '[' || c == ']' || c == '{' || c == '}' || c == '(' ||
          c == ')' || c == '=') {
        Fail(fmt::format("unexpected character '{}' (escape it with '\\')", c));
      }
      literal += c;
      ++pos_;
    }
    flush();
    if (element.pieces.empty()) Fail("missing value");
    return element;
  }

  /// 'quoted' or "quoted": `\'` escapes the quote, `\${` a literal `${`;
  /// interpolations inside are resolved and the result is always a string.
  Element ParseQuoted(char quote) {
    Element element;
    element.kind = Element::Kind::kQuoted;
    std::string literal;
    auto flush = [&] {
      if (!literal.empty()) {
        element.pieces.push_back(Piece{std::move(literal), nullptr});
      }
      literal.clear();
    };
    ++pos_;
    while (true) {
      if (AtEnd()) Fail("unterminated quoted string");
      const char c = text_[pos_];
      if (c == '\\') {
        const size_t run = BackslashRun();
        const size_t after = pos_ + run;
        if (after < text_.size() && text_[after] == quote) {
          literal.append(run / 2, '\\');
          if (run % 2 == 1) {
            literal += quote;
            pos_ = after + 1;
          } else {
            pos_ = after;
          }
        } else if (text_.substr(after, 2) == "${") {
          literal.append(run / 2, '\\');
          if (run % 2 == 1) {
            literal += "${";
            pos_ = after + 2;
          } else {
            pos_ = after;
          }
        } else {
          literal.append(run, '\\');
          pos_ = after;
        }
        continue;
      }
      if (c == quote) {
        ++pos_;
        break;
      }
      if (StartsWith("${")) {
        flush();
        element.pieces.push_back(Piece{"", ParseInterp()});
        continue;
      }
      literal += c;
      ++pos_;
    }
    flush();
    return element;
  }

  std::string_view text_;
  size_t pos_ = 0;
};

// ---------------------------------------------------------------------------
// Value helpers.

/// Python str() of a value, as OmegaConf uses when it embeds a value in a
/// string: `1`, `0.1`, `True`, `None`, `[1, 'a']`, `{'k': 1}`.
std::string PyStr(const ConfigNode& node);

/// Python's type(x).__name__ of a resolver argument, for OmegaConf's
/// messages.
std::string PyTypeName(const ConfigNode& node) {
  switch (node.type()) {
    case ConfigNode::Type::kNull:
      return "NoneType";
    case ConfigNode::Type::kBool:
      return "bool";
    case ConfigNode::Type::kInt:
      return "int";
    case ConfigNode::Type::kDouble:
      return "float";
    case ConfigNode::Type::kList:
      return "list";
    case ConfigNode::Type::kMap:
      return "dict";
    default:
      return "str";
  }
}

void ReplaceAll(std::string* text,
                std::string_view from,
                const std::string& to) {
  for (size_t pos = text->find(from); pos != std::string::npos;
       pos = text->find(from, pos + to.size())) {
    text->replace(pos, from.size(), to);
  }
}

std::string PyRepr(const ConfigNode& node) {
  if (node.IsString()) return fmt::format("'{}'", node.AsString());
  if (node.IsMissing()) return "'\?\?\?'";
  if (node.IsInterpolation()) return fmt::format("'{}'", node.text());
  return PyStr(node);
}

std::string PyStr(const ConfigNode& node) {
  switch (node.type()) {
    case ConfigNode::Type::kNull:
      return "None";
    case ConfigNode::Type::kBool:
      return node.AsBool() ? "True" : "False";
    case ConfigNode::Type::kInt:
      return std::to_string(node.AsInt());
    case ConfigNode::Type::kDouble:
      return FormatDouble(node.AsDouble());
    case ConfigNode::Type::kString:
      return node.AsString();
    case ConfigNode::Type::kMissing:
      return "???";
    case ConfigNode::Type::kInterpolation:
      return node.text();
    case ConfigNode::Type::kList: {
      std::vector<std::string> parts;
      for (const ConfigNode& item : node.items()) parts.push_back(PyRepr(item));
      return fmt::format("[{}]", fmt::join(parts, ", "));
    }
    case ConfigNode::Type::kMap: {
      std::vector<std::string> parts;
      for (const auto& [key, child] : node.entries()) {
        parts.push_back(fmt::format("'{}': {}", key, PyRepr(child)));
      }
      return fmt::format("{{{}}}", fmt::join(parts, ", "));
    }
  }
  return "";
}

/// Types an unquoted resolver argument like an override primitive.
ConfigNode TypePrimitive(const std::string& text) {
  static const std::regex kInt("[+-]?(?:0|[1-9](?:_?[0-9])*)");
  static const std::regex kFloat(
      "[+-]?(?:"
      "(?:(?:0|[1-9](?:_?[0-9])*)?\\.[0-9](?:_?[0-9])*|(?:0|[1-9](?:_?[0-9])*)"
      "\\.)(?:[eE][+-]?[0-9](?:_?[0-9])*)?"
      "|(?:0|[1-9](?:_?[0-9])*)[eE][+-]?[0-9](?:_?[0-9])*"
      "|[iI][nN][fF]|[nN][aA][nN])");
  static const std::regex kTrue("[tT][rR][uU][eE]");
  static const std::regex kFalse("[fF][aA][lL][sS][eE]");
  static const std::regex kNull("[nN][uU][lL][lL]");
  std::string digits;
  for (char c : text) {
    if (c != '_') digits += c;
  }
  if (std::regex_match(text, kInt)) {
    int64_t value = 0;
    const char* begin = digits.data() + (digits[0] == '+' ? 1 : 0);
    const auto result =
        std::from_chars(begin, digits.data() + digits.size(), value);
    if (result.ec != std::errc()) {
      throw ConfigError(
          fmt::format("Integer '{}' does not fit in 64 bits", text));
    }
    return ConfigNode(value);
  }
  if (std::regex_match(text, kFloat)) {
    return ConfigNode(std::strtod(digits.c_str(), nullptr));
  }
  if (std::regex_match(text, kTrue)) return ConfigNode(true);
  if (std::regex_match(text, kFalse)) return ConfigNode(false);
  if (std::regex_match(text, kNull)) return ConfigNode::Null();
  return ConfigNode::LiteralString(text);
}

std::string DisplayPath(std::string_view path) {
  return path.empty() ? std::string("<root>") : std::string(path);
}

std::string LocationSuffix(const SourceLocation* source) {
  if (source == nullptr) return "";
  const std::string where = source->ToString();
  return where.empty() ? std::string() : fmt::format(" ({})", where);
}

/// A reference to a `???` value. Whole-tree resolution turns the referencing
/// node into a Missing node (OmegaConf.resolve); lazy access raises it.
class InterpolationToMissing : public MissingMandatoryValue {
 public:
  using MissingMandatoryValue::MissingMandatoryValue;
};

// ---------------------------------------------------------------------------
// The resolution engine: one per top-level Select/Resolve/ResolveString call
// (re-used by nested calls from resolvers on the same tree), holding the
// stack of keys being resolved (cycle detection) and a memo of resolved
// interpolation nodes.

class Engine {
 public:
  /// The node a key points to; `owner` keeps alive a value produced by
  /// resolving an intermediate interpolation.
  struct Found {
    const ConfigNode* node = nullptr;
    std::shared_ptr<ConfigNode> owner;
  };

  Engine(const ConfigNode& root, const ResolverRegistry& registry)
      : root_(root), registry_(registry) {}

  const ConfigNode& root() const { return root_; }
  const ResolverRegistry& registry() const { return registry_; }

  /// Walks `segments` from the root, resolving interpolations met on the way.
  Found Lookup(const std::vector<std::string>& segments) {
    Found found{&root_, nullptr};
    for (const std::string& segment : segments) {
      const ConfigNode* current = found.node;
      if (current->IsInterpolation()) {
        auto owner = std::make_shared<ConfigNode>(EvaluateNode(*current));
        found.owner = owner;
        current = owner.get();
      }
      const ConfigNode* next = nullptr;
      if (current->IsMap()) {
        next = current->Find(segment);
      } else if (current->IsList()) {
        size_t index = 0;
        const auto result = std::from_chars(
            segment.data(), segment.data() + segment.size(), index);
        if (result.ec == std::errc() &&
            result.ptr == segment.data() + segment.size() &&
            index < current->size()) {
          next = &current->items()[index];
        }
      }
      if (next == nullptr) return Found{};
      found.node = next;
    }
    return found;
  }

  /// The fully resolved value of a node of the tree: an interpolation is
  /// evaluated (a reference to `???` throws MissingMandatoryValue), a
  /// container is resolved recursively, `???` stays Missing.
  ConfigNode ResolveValue(const ConfigNode& node) {
    if (node.IsInterpolation()) return EvaluateNode(node);
    if (node.IsContainer()) return ResolveDeep(node);
    return node;
  }

  /// Resolves a subtree; interpolations that lead to `???` become Missing.
  ConfigNode ResolveDeep(const ConfigNode& node) {
    if (node.IsInterpolation()) {
      try {
        return EvaluateNode(node);
      } catch (const InterpolationToMissing&) {
        ConfigNode missing = ConfigNode::Missing();
        missing.SetPath(node.path());
        missing.set_source(node.source());
        return missing;
      }
    }
    if (!node.IsContainer()) return node;
    StackGuard guard(this, node.path());
    ConfigNode out =
        node.IsMap() ? ConfigNode::EmptyMap() : ConfigNode::EmptyList();
    out.SetPath(node.path());
    out.set_source(node.source());
    out.set_struct_mode(node.struct_mode());
    if (node.IsMap()) {
      for (const auto& [key, child] : node.entries()) {
        out.Set(key, ResolveDeep(child));
      }
    } else {
      for (const ConfigNode& item : node.items()) out.Append(ResolveDeep(item));
    }
    return out;
  }

  /// Evaluates an interpolation node of the tree (memoised, cycle-checked).
  ConfigNode EvaluateNode(const ConfigNode& node) {
    const std::string& path = node.path();
    if (auto it = memo_.find(path); it != memo_.end()) return it->second;
    ConfigNode value;
    {
      StackGuard guard(this, path);
      value = EvaluateText(node.text(), path, &node.source());
    }
    value.SetPath(path);
    if (!value.IsContainer() || value.source().file.empty()) {
      value.set_source(node.source());
    }
    memo_.emplace(path, value);
    return value;
  }

  /// Evaluates a string in the context of `node_path` (for relative keys).
  ConfigNode EvaluateText(std::string_view text,
                          std::string_view node_path,
                          const SourceLocation* source) {
    std::vector<Piece> pieces;
    try {
      pieces = Parser(text).ParseTopLevel();
    } catch (const GrammarError& error) {
      throw ConfigError(
          fmt::format("GrammarParseError: {} in '{}' (while resolving '{}'){}",
                      error.message,
                      text,
                      DisplayPath(node_path),
                      LocationSuffix(source)));
    }
    const Context context{node_path, source};
    if (pieces.size() == 1 && pieces[0].interp) {
      return EvaluateInterp(*pieces[0].interp, context);
    }
    return ConfigNode::LiteralString(Concatenate(pieces, context));
  }

  /// The absolute path segments of a (relative or absolute) key written in
  /// a resolver argument (oc.select, oc.deprecated); false if a relative key
  /// climbs above the root.
  bool KeySegments(const std::string& key,
                   std::string_view node_path,
                   std::vector<std::string>* segments) {
    InterpPtr interp;
    try {
      interp = Parser(key).ParseKeyOnly();
    } catch (const GrammarError& error) {
      throw ConfigError(fmt::format(
          "GrammarParseError: {} in key '{}' (while resolving '{}')",
          error.message,
          key,
          DisplayPath(node_path)));
    }
    const Context context{node_path, nullptr};
    std::vector<std::string> parts;
    for (const KeyPart& part : interp->keys) {
      parts.push_back(KeyText(part, context));
    }
    return AbsoluteSegments(interp->dots, parts, node_path, segments);
  }

  /// oc.select: the resolved value at a (relative or absolute) key, or
  /// nullopt if it does not exist or is `???`.
  std::optional<ConfigNode> SelectKey(const std::string& key,
                                      std::string_view node_path) {
    std::vector<std::string> segments;
    if (!KeySegments(key, node_path, &segments)) return std::nullopt;
    try {
      const Found found = Lookup(segments);
      if (found.node == nullptr || found.node->IsMissing()) return std::nullopt;
      return ResolveValue(*found.node);
    } catch (const InterpolationToMissing&) {
      return std::nullopt;
    }
  }

  /// oc.decode: evaluates `text` as one resolver-argument element.
  ConfigNode Decode(const std::string& text, std::string_view node_path) {
    Element element;
    try {
      element = Parser(text).ParseSingleElement();
    } catch (const GrammarError& error) {
      throw ConfigError(fmt::format(
          "GrammarParseError: {} in '{}' (oc.decode, while resolving '{}')",
          error.message,
          text,
          DisplayPath(node_path)));
    }
    return EvaluateElement(element, Context{node_path, nullptr});
  }

  /// The node at a (relative or absolute) key and its absolute dotted path,
  /// without resolving the node itself; nullptr if there is none.
  const ConfigNode* FindKey(const std::string& key,
                            std::string_view node_path,
                            std::string* absolute,
                            std::shared_ptr<ConfigNode>* owner) {
    std::vector<std::string> segments;
    if (!KeySegments(key, node_path, &segments)) return nullptr;
    const Found found = Lookup(segments);
    *owner = found.owner;
    *absolute = fmt::format("{}", fmt::join(segments, "."));
    return found.node;
  }

  /// Resolves the interpolations inside a node built by a resolver (oc.create
  /// from a YAML string), each in the context of the node being resolved.
  ConfigNode ResolveCreated(const ConfigNode& node,
                            std::string_view node_path) {
    if (node.IsInterpolation()) {
      return EvaluateText(node.text(), node_path, nullptr);
    }
    if (!node.IsContainer()) return node;
    ConfigNode out =
        node.IsMap() ? ConfigNode::EmptyMap() : ConfigNode::EmptyList();
    if (node.IsMap()) {
      for (const auto& [key, child] : node.entries()) {
        out.Set(key, ResolveCreated(child, node_path));
      }
    } else {
      for (const ConfigNode& item : node.items()) {
        out.Append(ResolveCreated(item, node_path));
      }
    }
    return out;
  }

  /// The value at an absolute dotted key; throws InterpolationKeyError if it
  /// does not exist and MissingMandatoryValue if it is `???`.
  ConfigNode ValueAtKey(const std::string& dotted, std::string_view node_path) {
    const Found found = Lookup(SplitKeyPath(dotted));
    if (found.node == nullptr) {
      throw InterpolationKeyError(fmt::format(
          "InterpolationKeyError: Interpolation key '{}' not found (while "
          "resolving '{}')",
          dotted,
          DisplayPath(node_path)));
    }
    return ValueOfFound(*found.node, Context{node_path, nullptr});
  }

 private:
  struct Context {
    std::string_view node_path;
    const SourceLocation* source;
  };

  /// Pushes a key on the resolution stack; a key already there is a cycle.
  class StackGuard {
   public:
    StackGuard(Engine* engine, const std::string& path) : engine_(engine) {
      auto& stack = engine_->stack_;
      const auto it = std::find(stack.begin(), stack.end(), path);
      if (it != stack.end()) {
        std::vector<std::string> chain;
        for (auto i = it; i != stack.end(); ++i)
          chain.push_back(DisplayPath(*i));
        chain.push_back(DisplayPath(path));
        throw ConfigError(
            fmt::format("InterpolationResolutionError: Recursive interpolation "
                        "detected. Interpolation cycle: {}",
                        fmt::join(chain, " -> ")));
      }
      stack.push_back(path);
    }
    ~StackGuard() { engine_->stack_.pop_back(); }
    StackGuard(const StackGuard&) = delete;
    StackGuard& operator=(const StackGuard&) = delete;

   private:
    Engine* engine_;
  };

  std::string Concatenate(const std::vector<Piece>& pieces,
                          const Context& context) {
    std::string out;
    for (const Piece& piece : pieces) {
      out += piece.interp ? PyStr(EvaluateInterp(*piece.interp, context))
                          : piece.literal;
    }
    return out;
  }

  std::string KeyText(const KeyPart& part, const Context& context) {
    if (!part.interp) return part.text;
    return PyStr(EvaluateInterp(*part.interp, context));
  }

  /// Turns a (possibly relative) key into absolute segments. One leading dot
  /// is the container of the node being resolved, each extra dot one level
  /// up. Returns false if the key climbs above the root.
  static bool AbsoluteSegments(int dots,
                               const std::vector<std::string>& parts,
                               std::string_view node_path,
                               std::vector<std::string>* segments) {
    segments->clear();
    if (dots > 0) {
      *segments = SplitKeyPath(node_path);
      if (static_cast<int>(segments->size()) < dots) return false;
      segments->resize(segments->size() - static_cast<size_t>(dots));
    }
    segments->insert(segments->end(), parts.begin(), parts.end());
    return true;
  }

  ConfigNode ValueOfFound(const ConfigNode& target, const Context& context) {
    if (target.IsMissing()) {
      throw InterpolationToMissing(
          fmt::format("MissingMandatoryValue: {} (while resolving '{}'){}",
                      DisplayPath(target.path()),
                      DisplayPath(context.node_path),
                      LocationSuffix(context.source)));
    }
    return ResolveValue(target);
  }

  ConfigNode EvaluateInterp(const Interp& interp, const Context& context) {
    if (interp.is_resolver) return CallResolver(interp, context);
    std::vector<std::string> parts;
    std::string key_text(static_cast<size_t>(interp.dots), '.');
    for (size_t i = 0; i < interp.keys.size(); ++i) {
      const KeyPart& part = interp.keys[i];
      parts.push_back(KeyText(part, context));
      if (part.bracket) {
        key_text += fmt::format("[{}]", parts.back());
      } else {
        if (i > 0) key_text += '.';
        key_text += parts.back();
      }
    }
    std::vector<std::string> segments;
    Found found;
    if (AbsoluteSegments(interp.dots, parts, context.node_path, &segments)) {
      found = Lookup(segments);
    }
    if (found.node == nullptr) {
      throw InterpolationKeyError(fmt::format(
          "InterpolationKeyError: Interpolation key '{}' not found (while "
          "resolving '{}'){}",
          key_text,
          DisplayPath(context.node_path),
          LocationSuffix(context.source)));
    }
    return ValueOfFound(*found.node, context);
  }

  ConfigNode CallResolver(const Interp& interp, const Context& context) {
    std::vector<std::string> name_parts;
    for (const KeyPart& part : interp.keys) {
      name_parts.push_back(KeyText(part, context));
    }
    const std::string name = fmt::format("{}", fmt::join(name_parts, "."));
    if (!registry_.Has(name)) {
      throw ConfigError(fmt::format(
          "Unsupported interpolation type {} (while resolving '{}'){}; "
          "registered resolvers: {}",
          name,
          DisplayPath(context.node_path),
          LocationSuffix(context.source),
          fmt::join(registry_.Names(), ", ")));
    }
    std::vector<ConfigNode> args;
    args.reserve(interp.args.size());
    for (const Element& element : interp.args) {
      args.push_back(EvaluateElement(element, context));
    }
    const ResolverCall call{&root_, context.node_path, &registry_};
    ConfigNode result;
    try {
      result = registry_.Get(name)(args, call);
    } catch (const Error&) {
      throw;
    } catch (const std::exception& error) {
      throw ConfigError(
          fmt::format("Resolver '{}' failed while resolving '{}'{}: {}",
                      name,
                      DisplayPath(context.node_path),
                      LocationSuffix(context.source),
                      error.what()));
    }
    // Resolver outputs are values, never re-resolved.
    if (result.IsInterpolation()) {
      result = ConfigNode::LiteralString(result.text());
    }
    return result;
  }

  ConfigNode EvaluateElement(const Element& element, const Context& context) {
    switch (element.kind) {
      case Element::Kind::kList: {
        ConfigNode list = ConfigNode::EmptyList();
        for (const Element& item : element.items) {
          list.Append(EvaluateElement(item, context));
        }
        return list;
      }
      case Element::Kind::kDict: {
        ConfigNode map = ConfigNode::EmptyMap();
        for (const auto& [key, value] : element.entries) {
          map.Set(key, EvaluateElement(value, context));
        }
        return map;
      }
      case Element::Kind::kQuoted:
        return ConfigNode::LiteralString(Concatenate(element.pieces, context));
      case Element::Kind::kPrimitive:
        break;
    }
    if (element.pieces.size() == 1 && element.pieces[0].interp &&
        !element.escaped) {
      return EvaluateInterp(*element.pieces[0].interp, context);
    }
    const bool has_interp = std::any_of(
        element.pieces.begin(), element.pieces.end(), [](const Piece& piece) {
          return piece.interp != nullptr;
        });
    const std::string text = Concatenate(element.pieces, context);
    if (has_interp || element.escaped) return ConfigNode::LiteralString(text);
    return TypePrimitive(text);
  }

  const ConfigNode& root_;
  const ResolverRegistry& registry_;
  std::vector<std::string> stack_;
  std::map<std::string, ConfigNode> memo_;
};

/// The engine of the resolution in progress on this thread, so that
/// resolvers calling Select() on the same tree share its cycle detection.
thread_local Engine* active_engine = nullptr;

template <typename Fn>
auto WithEngine(const ConfigNode& root,
                const ResolverRegistry& registry,
                Fn&& fn) {
  if (active_engine != nullptr && &active_engine->root() == &root &&
      &active_engine->registry() == &registry) {
    return fn(*active_engine);
  }
  Engine engine(root, registry);
  struct Restore {
    Engine* previous;
    ~Restore() { active_engine = previous; }
  } restore{active_engine};
  active_engine = &engine;
  return fn(engine);
}

// ---------------------------------------------------------------------------
// Built-in resolvers.

void CheckArgCount(std::string_view name,
                   const std::vector<ConfigNode>& args,
                   size_t min,
                   size_t max,
                   const ResolverCall& call,
                   std::string_view usage) {
  if (args.size() < min || args.size() > max) {
    throw ConfigError(fmt::format(
        "Resolver '{}' got {} argument(s), expected {} (while resolving "
        "'{}')",
        name,
        args.size(),
        usage,
        DisplayPath(call.node_path)));
  }
}

/// The resolved value at an absolute key if it exists and is set.
std::optional<ConfigNode> OptionalSetting(const ResolverCall& call,
                                          const std::string& key) {
  if (call.root->FindPath(key) == nullptr) return std::nullopt;
  std::optional<ConfigNode> value =
      WithEngine(*call.root, *call.registry, [&](Engine& engine) {
        return engine.SelectKey(key, call.node_path);
      });
  if (value && value->IsNull()) return std::nullopt;
  return value;
}

/// `key_or_group` of an override string: `+db@src=x` -> `db`.
std::string OverrideKey(std::string_view override_text) {
  while (!override_text.empty() &&
         (override_text.front() == '+' || override_text.front() == '~')) {
    override_text.remove_prefix(1);
  }
  const size_t eq = override_text.find('=');
  std::string_view key = override_text.substr(0, eq);
  const size_t at = key.find('@');
  if (at != std::string_view::npos) key = key.substr(0, at);
  while (!key.empty() && (key.back() == ' ' || key.back() == '\t')) {
    key.remove_suffix(1);
  }
  return std::string(key);
}

std::string OverrideDirname(const ResolverCall& call,
                            const std::vector<ConfigNode>& args) {
  std::string kv_sep = "=";
  std::string item_sep = ",";
  std::vector<std::string> exclude_keys;
  auto exclude_from = [&](const ConfigNode& node) {
    exclude_keys.clear();
    if (node.IsList()) {
      for (const ConfigNode& item : node.items()) {
        exclude_keys.push_back(PyStr(item));
      }
    } else if (!node.IsNull()) {
      exclude_keys.push_back(PyStr(node));
    }
  };
  const std::string settings = "hydra.job.config.override_dirname";
  if (auto value = OptionalSetting(call, settings + ".kv_sep")) {
    kv_sep = PyStr(*value);
  }
  if (auto value = OptionalSetting(call, settings + ".item_sep")) {
    item_sep = PyStr(*value);
  }
  if (auto value = OptionalSetting(call, settings + ".exclude_keys")) {
    exclude_from(*value);
  }
  if (args.size() > 0) kv_sep = PyStr(args[0]);
  if (args.size() > 1) item_sep = PyStr(args[1]);
  if (args.size() > 2) exclude_from(args[2]);

  std::vector<std::string> overrides;
  if (auto task = OptionalSetting(call, "hydra.overrides.task")) {
    if (!task->IsList()) {
      throw ConfigError(fmt::format(
          "hydra.overrides.task must be a list of strings, got {} (while "
          "resolving '{}')",
          task->Describe(),
          DisplayPath(call.node_path)));
    }
    for (const ConfigNode& item : task->items()) {
      overrides.push_back(PyStr(item));
    }
  }
  std::sort(overrides.begin(), overrides.end());
  std::vector<std::string> lines;
  for (std::string& line : overrides) {
    if (std::find(exclude_keys.begin(),
                  exclude_keys.end(),
                  OverrideKey(line)) != exclude_keys.end()) {
      continue;
    }
    const size_t eq = line.find('=');
    if (eq != std::string::npos) line.replace(eq, 1, kv_sep);
    lines.push_back(std::move(line));
  }
  return fmt::format("{}", fmt::join(lines, item_sep));
}

void RegisterBuiltinResolvers(ResolverRegistry* registry) {
  registry->Register(
      "now", [](const std::vector<ConfigNode>& args, const ResolverCall& call) {
        CheckArgCount("now", args, 0, 1, call, "now:PATTERN");
        const std::string pattern =
            args.empty() ? std::string(kDefaultNowPattern) : PyStr(args[0]);
        return ConfigNode::LiteralString(call.registry->CachedNow(pattern));
      });

  registry->Register(
      "oc.env",
      [](const std::vector<ConfigNode>& args, const ResolverCall& call) {
        CheckArgCount("oc.env", args, 1, 2, call, "oc.env:VAR[,default]");
        const std::string name = PyStr(args[0]);
        if (const char* value = std::getenv(name.c_str())) {
          return ConfigNode::LiteralString(value);
        }
        if (args.size() == 2) {
          if (args[1].IsNull()) return ConfigNode::Null();
          return ConfigNode::LiteralString(PyStr(args[1]));
        }
        throw ConfigError(fmt::format(
            "Environment variable '{}' not found (while resolving '{}')",
            name,
            DisplayPath(call.node_path)));
      });

  registry->Register(
      "oc.select",
      [](const std::vector<ConfigNode>& args, const ResolverCall& call) {
        CheckArgCount("oc.select", args, 1, 2, call, "oc.select:key[,default]");
        const std::string key = PyStr(args[0]);
        std::optional<ConfigNode> value =
            WithEngine(*call.root, *call.registry, [&](Engine& engine) {
              return engine.SelectKey(key, call.node_path);
            });
        if (value) return *value;
        return args.size() == 2 ? args[1] : ConfigNode::Null();
      });

  registry->Register(
      "oc.decode",
      [](const std::vector<ConfigNode>& args, const ResolverCall& call) {
        CheckArgCount("oc.decode", args, 1, 1, call, "oc.decode:string");
        if (args[0].IsNull()) return ConfigNode::Null();
        if (!args[0].IsString()) {
          throw ConfigError(fmt::format(
              "`oc.decode` can only take strings or None as input, but `{}` "
              "is of type {} (while resolving '{}')",
              PyStr(args[0]),
              PyTypeName(args[0]),
              DisplayPath(call.node_path)));
        }
        return WithEngine(*call.root, *call.registry, [&](Engine& engine) {
          return engine.Decode(args[0].AsString(), call.node_path);
        });
      });

  registry->Register(
      "oc.create",
      [](const std::vector<ConfigNode>& args, const ResolverCall& call) {
        CheckArgCount("oc.create", args, 1, 1, call, "oc.create:dict_or_list");
        // OmegaConf.create(obj): a string is YAML; None (or empty YAML) is
        // {}; a YAML scalar string `s` is {s: None}.
        ConfigNode obj = args[0];
        if (obj.IsString()) {
          obj = ParseYaml(obj.AsString(), "<oc.create>");
          if (obj.IsString()) {
            ConfigNode map = ConfigNode::EmptyMap();
            map.Set(obj.AsString(), ConfigNode::Null());
            obj = std::move(map);
          }
        }
        if (obj.IsNull()) return ConfigNode::EmptyMap();
        if (!obj.IsContainer()) {
          throw ConfigError(fmt::format(
              "Object of unsupported type: '{}' (oc.create, while resolving "
              "'{}')",
              PyTypeName(obj),
              DisplayPath(call.node_path)));
        }
        return WithEngine(*call.root, *call.registry, [&](Engine& engine) {
          return engine.ResolveCreated(obj, call.node_path);
        });
      });

  registry->Register(
      "oc.deprecated",
      [](const std::vector<ConfigNode>& args, const ResolverCall& call) {
        CheckArgCount(
            "oc.deprecated", args, 1, 2, call, "oc.deprecated:key[,message]");
        if (!args[0].IsString()) {
          throw ConfigError(fmt::format(
              "oc.deprecated: interpolation key type is not a string ({}) "
              "(while resolving '{}')",
              PyTypeName(args[0]),
              DisplayPath(call.node_path)));
        }
        if (args.size() == 2 && !args[1].IsString()) {
          throw ConfigError(fmt::format(
              "oc.deprecated: interpolation message type is not a string ({}) "
              "(while resolving '{}')",
              PyTypeName(args[1]),
              DisplayPath(call.node_path)));
        }
        const std::string key = args[0].AsString();
        return WithEngine(*call.root, *call.registry, [&](Engine& engine) {
          std::string new_key;
          std::shared_ptr<ConfigNode> owner;
          const ConfigNode* target =
              engine.FindKey(key, call.node_path, &new_key, &owner);
          if (target == nullptr) {
            throw ConfigError(fmt::format(
                "In oc.deprecated resolver at '{}': Key not found: '{}'",
                DisplayPath(call.node_path),
                key));
          }
          std::string message =
              args.size() == 2 ? args[1].AsString()
                               : std::string(
                                     "'$OLD_KEY' is deprecated. Change your "
                                     "code and config to use '$NEW_KEY'");
          ReplaceAll(&message, "$OLD_KEY", std::string(call.node_path));
          ReplaceAll(&message, "$NEW_KEY", new_key);
          SOMA_LOG(WARNING, "{}", message);
          if (target->IsMissing()) {
            throw ConfigError(
                fmt::format("MissingMandatoryValue: {}", DisplayPath(new_key)));
          }
          return engine.ResolveValue(*target);
        });
      });

  const auto dict_input = [](std::string_view name,
                             const std::vector<ConfigNode>& args,
                             const ResolverCall& call) {
    CheckArgCount(name, args, 1, 1, call, fmt::format("{}:key", name));
    if (!args[0].IsString()) {
      throw ConfigError(fmt::format(
          "`{}` requires a string as input, but obtained `{}` of type: {} "
          "(while resolving '{}')",
          name,
          PyStr(args[0]),
          PyTypeName(args[0]),
          DisplayPath(call.node_path)));
    }
    const std::string key = args[0].AsString();
    return WithEngine(*call.root, *call.registry, [&](Engine& engine) {
      std::string absolute;
      std::shared_ptr<ConfigNode> owner;
      const ConfigNode* target =
          engine.FindKey(key, call.node_path, &absolute, &owner);
      if (target == nullptr) {
        throw ConfigError(
            fmt::format("Key not found: '{}' ({}, while "
                        "resolving '{}')",
                        key,
                        name,
                        DisplayPath(call.node_path)));
      }
      if (target->IsMissing()) {
        throw ConfigError(
            fmt::format("MissingMandatoryValue: {}", DisplayPath(absolute)));
      }
      ConfigNode value = engine.ResolveValue(*target);
      if (!value.IsMap()) {
        throw ConfigError(fmt::format(
            "`{}` cannot be applied to objects of type: {} (while resolving "
            "'{}')",
            name,
            value.IsList() ? std::string("ListConfig") : PyTypeName(value),
            DisplayPath(call.node_path)));
      }
      return value;
    });
  };

  registry->Register("oc.dict.keys",
                     [dict_input](const std::vector<ConfigNode>& args,
                                  const ResolverCall& call) {
                       const ConfigNode dict =
                           dict_input("oc.dict.keys", args, call);
                       ConfigNode keys = ConfigNode::EmptyList();
                       for (const auto& [key, value] : dict.entries()) {
                         keys.Append(ConfigNode::LiteralString(key));
                       }
                       return keys;
                     });

  registry->Register("oc.dict.values",
                     [dict_input](const std::vector<ConfigNode>& args,
                                  const ResolverCall& call) {
                       const ConfigNode dict =
                           dict_input("oc.dict.values", args, call);
                       ConfigNode values = ConfigNode::EmptyList();
                       for (const auto& [key, value] : dict.entries())
                         values.Append(value);
                       return values;
                     });

  registry->Register(
      "hydra",
      [](const std::vector<ConfigNode>& args, const ResolverCall& call) {
        CheckArgCount("hydra", args, 1, 1, call, "hydra:path");
        const std::string path = PyStr(args[0]);
        const ConfigNode* hydra = call.root->Find("hydra");
        if (hydra == nullptr || !hydra->IsMap()) {
          throw ConfigError(fmt::format(
              "Cannot resolve ${{hydra:{}}}: the config has no 'hydra' node "
              "(while resolving '{}')",
              path,
              DisplayPath(call.node_path)));
        }
        if (path == "job.override_dirname") {
          const ConfigNode* stored = hydra->FindPath(path);
          if (stored == nullptr || stored->IsNull() || stored->IsMissing()) {
            return ConfigNode::LiteralString(OverrideDirname(call, {}));
          }
        }
        return WithEngine(*call.root, *call.registry, [&](Engine& engine) {
          return engine.ValueAtKey("hydra." + path, call.node_path);
        });
      });

  registry->Register(
      "hydra_override_dirname",
      [](const std::vector<ConfigNode>& args, const ResolverCall& call) {
        CheckArgCount(
            "hydra_override_dirname",
            args,
            0,
            3,
            call,
            "hydra_override_dirname:[kv_sep[,item_sep[,exclude_keys]]]");
        return ConfigNode::LiteralString(OverrideDirname(call, args));
      });
}

}  // namespace

// ---------------------------------------------------------------------------
// ResolverRegistry.

ResolverRegistry::ResolverRegistry() { RegisterBuiltinResolvers(this); }

void ResolverRegistry::Register(std::string name, ResolverFn fn) {
  if (name.empty()) throw ConfigError("Resolver name must not be empty");
  if (!fn) {
    throw ConfigError(fmt::format("Resolver '{}' has no function", name));
  }
  if (resolvers_.count(name) > 0) {
    throw ConfigError(fmt::format("Resolver '{}' is already registered", name));
  }
  resolvers_.emplace(std::move(name), std::move(fn));
}

bool ResolverRegistry::Has(std::string_view name) const {
  return resolvers_.find(name) != resolvers_.end();
}

const ResolverFn& ResolverRegistry::Get(std::string_view name) const {
  const auto it = resolvers_.find(name);
  if (it == resolvers_.end()) {
    throw ConfigError(fmt::format(
        "Unsupported interpolation type {}; registered resolvers: {}",
        name,
        fmt::join(Names(), ", ")));
  }
  return it->second;
}

std::vector<std::string> ResolverRegistry::Names() const {
  std::vector<std::string> names;
  names.reserve(resolvers_.size());
  for (const auto& entry : resolvers_) names.push_back(entry.first);
  return names;
}

std::string ResolverRegistry::CachedNow(const std::string& pattern) const {
  const std::lock_guard<std::mutex> lock(now_mutex_);
  if (auto it = now_cache_.find(pattern); it != now_cache_.end()) {
    return it->second;
  }
  const std::time_t now = std::time(nullptr);
  std::tm local{};
  localtime_r(&now, &local);
  std::string formatted;
  if (!pattern.empty()) {
    std::vector<char> buffer(64 + pattern.size() * 8);
    size_t written = 0;
    for (int attempt = 0; attempt < 4; ++attempt) {
      written =
          std::strftime(buffer.data(), buffer.size(), pattern.c_str(), &local);
      if (written > 0) break;
      buffer.resize(buffer.size() * 4);
    }
    formatted.assign(buffer.data(), written);
  }
  now_cache_.emplace(pattern, formatted);
  return formatted;
}

// ---------------------------------------------------------------------------
// Public functions.

ConfigNode Select(const ConfigNode& root,
                  std::string_view dotted,
                  const ResolverRegistry& resolvers) {
  return WithEngine(root, resolvers, [&](Engine& engine) {
    const Engine::Found found = engine.Lookup(SplitKeyPath(dotted));
    if (found.node == nullptr) {
      throw ConfigError(
          fmt::format("Key '{}' not found in the config", dotted));
    }
    return engine.ResolveValue(*found.node);
  });
}

ConfigNode Resolve(const ConfigNode& root, const ResolverRegistry& resolvers) {
  return WithEngine(root, resolvers, [&](Engine& engine) {
    return engine.ResolveDeep(root);
  });
}

ConfigNode ResolveString(const ConfigNode& root,
                         std::string_view text,
                         std::string_view node_path,
                         const ResolverRegistry& resolvers) {
  return WithEngine(root, resolvers, [&](Engine& engine) {
    return engine.EvaluateText(text, node_path, nullptr);
  });
}

bool HasInterpolation(std::string_view text) {
  for (size_t pos = text.find("${"); pos != std::string_view::npos;
       pos = text.find("${", pos + 1)) {
    size_t backslashes = 0;
    while (backslashes < pos && text[pos - backslashes - 1] == '\\') {
      ++backslashes;
    }
    if (backslashes % 2 == 0) return true;
  }
  return false;
}

ResolverRegistry& DefaultResolvers() {
  static ResolverRegistry registry;
  return registry;
}

}  // namespace soma
