#include "framework/config/node.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <charconv>
#include <cmath>
#include <cstdlib>
#include <system_error>

namespace soma {

struct ConfigNode::Container {
  std::vector<ConfigNode> items;
  std::vector<std::pair<std::string, ConfigNode>> entries;
};

namespace {

const std::vector<ConfigNode>& EmptyItems() {
  static const std::vector<ConfigNode> kEmpty;
  return kEmpty;
}

const std::vector<std::pair<std::string, ConfigNode>>& EmptyEntries() {
  static const std::vector<std::pair<std::string, ConfigNode>> kEmpty;
  return kEmpty;
}

/// Number of consecutive backslashes that end right before `pos`.
size_t BackslashesBefore(std::string_view text, size_t pos) {
  size_t count = 0;
  while (count < pos && text[pos - count - 1] == '\\') ++count;
  return count;
}

/// True if `text` has a `${` preceded by an even number of backslashes.
bool HasUnescapedInterpolation(std::string_view text) {
  for (size_t pos = text.find("${"); pos != std::string_view::npos;
       pos = text.find("${", pos + 1)) {
    if (BackslashesBefore(text, pos) % 2 == 0) return true;
  }
  return false;
}

/// Removes the escapes of `\${` (OmegaConf top-level string rules): a run of
/// 2k+1 backslashes before `${` becomes k backslashes and a literal `${`.
/// Only valid for text without unescaped interpolations.
std::string UnescapeLiteral(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  size_t i = 0;
  while (i < text.size()) {
    if (text[i] == '\\') {
      size_t j = i;
      while (j < text.size() && text[j] == '\\') ++j;
      const size_t run = j - i;
      if (text.substr(j, 2) == "${") {
        out.append(run / 2, '\\');
        out += "${";
        i = j + 2;
      } else {
        out.append(run, '\\');
        i = j;
      }
      continue;
    }
    out += text[i++];
  }
  return out;
}

/// Inverse of UnescapeLiteral: the source text whose value is `value`.
std::string EscapeLiteral(std::string_view value) {
  std::string out;
  out.reserve(value.size());
  size_t i = 0;
  while (i < value.size()) {
    if (value[i] == '\\') {
      size_t j = i;
      while (j < value.size() && value[j] == '\\') ++j;
      const size_t run = j - i;
      if (value.substr(j, 2) == "${") {
        out.append(2 * run + 1, '\\');
        out += "${";
        i = j + 2;
      } else {
        out.append(run, '\\');
        i = j;
      }
      continue;
    }
    if (value.substr(i, 2) == "${") {
      out += "\\${";
      i += 2;
      continue;
    }
    out += value[i++];
  }
  return out;
}

std::string DisplayPath(const std::string& path) {
  return path.empty() ? std::string("<root>") : path;
}

std::string LocationSuffix(const SourceLocation& source) {
  const std::string where = source.ToString();
  return where.empty() ? std::string() : fmt::format(" ({})", where);
}

/// Escapes control characters so that messages stay on one line.
std::string OneLine(std::string_view text) {
  std::string out;
  for (char c : text) {
    if (c == '\n') {
      out += "\\n";
    } else if (c == '\r') {
      out += "\\r";
    } else if (c == '\t') {
      out += "\\t";
    } else {
      out += c;
    }
  }
  return out;
}

bool ParseIndex(std::string_view segment, size_t* index) {
  if (segment.empty()) return false;
  for (char c : segment) {
    if (c < '0' || c > '9') return false;
  }
  const auto result =
      std::from_chars(segment.data(), segment.data() + segment.size(), *index);
  return result.ec == std::errc() &&
         result.ptr == segment.data() + segment.size();
}

bool DoublesEqual(double a, double b) {
  if (std::isnan(a) && std::isnan(b)) return true;
  return a == b;
}

}  // namespace

// ---------------------------------------------------------------------------
// SourceLocation.

std::string SourceLocation::ToString() const {
  if (file.empty()) return line > 0 ? fmt::format("line {}", line) : "";
  if (line > 0) return fmt::format("{}:{}", file, line);
  return file;
}

// ---------------------------------------------------------------------------
// Construction, copy, move.

ConfigNode::ConfigNode() : text_("null") {}

ConfigNode::ConfigNode(const ConfigNode& other)
    : type_(other.type_),
      bool_(other.bool_),
      int_(other.int_),
      double_(other.double_),
      text_(other.text_),
      str_(other.str_),
      container_(other.container_
                     ? std::make_unique<Container>(*other.container_)
                     : nullptr),
      path_(other.path_),
      source_(other.source_),
      struct_mode_(other.struct_mode_) {}

ConfigNode::ConfigNode(ConfigNode&& other) noexcept = default;

ConfigNode& ConfigNode::operator=(const ConfigNode& other) {
  if (this == &other) return *this;
  ConfigNode copy(other);
  *this = std::move(copy);
  return *this;
}

ConfigNode& ConfigNode::operator=(ConfigNode&& other) noexcept = default;

ConfigNode::~ConfigNode() = default;

ConfigNode::ConfigNode(bool value)
    : type_(Type::kBool), bool_(value), text_(value ? "true" : "false") {}

ConfigNode::ConfigNode(int value) : ConfigNode(static_cast<int64_t>(value)) {}

ConfigNode::ConfigNode(int64_t value)
    : type_(Type::kInt), int_(value), text_(std::to_string(value)) {}

ConfigNode::ConfigNode(double value)
    : type_(Type::kDouble), double_(value), text_(FormatDouble(value)) {}

ConfigNode::ConfigNode(const char* value)
    : ConfigNode(FromString(std::string(value))) {}

ConfigNode::ConfigNode(std::string value)
    : ConfigNode(FromString(std::move(value))) {}

ConfigNode::ConfigNode(std::string_view value)
    : ConfigNode(FromString(std::string(value))) {}

ConfigNode ConfigNode::Null() { return ConfigNode(); }

ConfigNode ConfigNode::Missing() {
  ConfigNode node;
  node.type_ = Type::kMissing;
  node.text_ = "???";
  return node;
}

ConfigNode ConfigNode::FromString(std::string value) {
  if (value == "???") return Missing();
  ConfigNode node;
  if (HasUnescapedInterpolation(value)) {
    node.type_ = Type::kInterpolation;
    node.text_ = std::move(value);
    return node;
  }
  node.type_ = Type::kString;
  node.str_ = UnescapeLiteral(value);
  node.text_ = std::move(value);
  return node;
}

ConfigNode ConfigNode::LiteralString(std::string value) {
  ConfigNode node;
  node.type_ = Type::kString;
  node.text_ = EscapeLiteral(value);
  node.str_ = std::move(value);
  return node;
}

ConfigNode ConfigNode::EmptyList() {
  ConfigNode node;
  node.type_ = Type::kList;
  node.text_.clear();
  node.container_ = std::make_unique<Container>();
  return node;
}

ConfigNode ConfigNode::EmptyMap() {
  ConfigNode node;
  node.type_ = Type::kMap;
  node.text_.clear();
  node.container_ = std::make_unique<Container>();
  return node;
}

void ConfigNode::Reset() {
  type_ = Type::kNull;
  bool_ = false;
  int_ = 0;
  double_ = 0.0;
  text_ = "null";
  str_.clear();
  container_.reset();
}

// ---------------------------------------------------------------------------
// Typed access.

void ConfigNode::ThrowTypeError(std::string_view expected) const {
  if (type_ == Type::kMissing) {
    throw MissingMandatoryValue(fmt::format("MissingMandatoryValue: {}{}",
                                            DisplayPath(path_),
                                            LocationSuffix(source_)));
  }
  if (type_ == Type::kInterpolation) {
    throw ConfigError(fmt::format(
        "Invalid configuration. {} = {} is an unresolved interpolation; "
        "resolve it (Select/Resolve) before reading it as {}{}",
        DisplayPath(path_),
        Describe(),
        expected,
        LocationSuffix(source_)));
  }
  throw ConfigError(
      fmt::format("Invalid configuration. {} = {}. Expected type {}{}",
                  DisplayPath(path_),
                  Describe(),
                  expected,
                  LocationSuffix(source_)));
}

bool ConfigNode::AsBool() const {
  if (type_ != Type::kBool) ThrowTypeError("bool");
  return bool_;
}

int64_t ConfigNode::AsInt() const {
  if (type_ != Type::kInt) ThrowTypeError("int");
  return int_;
}

double ConfigNode::AsDouble() const {
  if (type_ == Type::kInt) return static_cast<double>(int_);
  if (type_ != Type::kDouble) ThrowTypeError("float");
  return double_;
}

const std::string& ConfigNode::AsString() const {
  if (type_ != Type::kString) ThrowTypeError("str");
  return str_;
}

// ---------------------------------------------------------------------------
// Map access.

std::string ConfigNode::ChildPath(std::string_view key) const {
  return JoinKeyPath(path_, key);
}

std::string ConfigNode::IndexPath(size_t index) const {
  return fmt::format("{}[{}]", path_, index);
}

void ConfigNode::EnsureMap(std::string_view for_key) {
  if (type_ == Type::kMap) return;
  if (type_ == Type::kNull) {
    type_ = Type::kMap;
    text_.clear();
    container_ = std::make_unique<Container>();
    return;
  }
  throw ConfigError(fmt::format(
      "Invalid configuration. Cannot set key '{}' of {} = {}: it is not a "
      "dict{}",
      for_key,
      DisplayPath(path_),
      Describe(),
      LocationSuffix(source_)));
}

void ConfigNode::EnsureList() {
  if (type_ == Type::kList) return;
  if (type_ == Type::kNull) {
    type_ = Type::kList;
    text_.clear();
    container_ = std::make_unique<Container>();
    return;
  }
  ThrowTypeError("list");
}

bool ConfigNode::Has(std::string_view key) const {
  return Find(key) != nullptr;
}

const ConfigNode& ConfigNode::at(std::string_view key) const {
  if (type_ != Type::kMap) ThrowTypeError("dict");
  const ConfigNode* child = Find(key);
  if (child == nullptr) {
    throw ConfigError(fmt::format(
        "Key '{}' not found{}", ChildPath(key), LocationSuffix(source_)));
  }
  return *child;
}

ConfigNode& ConfigNode::at(std::string_view key) {
  return const_cast<ConfigNode&>(std::as_const(*this).at(key));
}

const ConfigNode* ConfigNode::Find(std::string_view key) const {
  if (type_ != Type::kMap) return nullptr;
  for (const auto& [name, child] : container_->entries) {
    if (name == key) return &child;
  }
  return nullptr;
}

ConfigNode* ConfigNode::Find(std::string_view key) {
  return const_cast<ConfigNode*>(std::as_const(*this).Find(key));
}

ConfigNode& ConfigNode::Set(std::string_view key, ConfigNode value) {
  EnsureMap(key);
  value.SetPath(ChildPath(key));
  for (auto& [name, child] : container_->entries) {
    if (name == key) {
      child = std::move(value);
      return child;
    }
  }
  container_->entries.emplace_back(std::string(key), std::move(value));
  return container_->entries.back().second;
}

bool ConfigNode::Erase(std::string_view key) {
  if (type_ != Type::kMap) return false;
  auto& entries = container_->entries;
  for (auto it = entries.begin(); it != entries.end(); ++it) {
    if (it->first == key) {
      entries.erase(it);
      return true;
    }
  }
  return false;
}

std::vector<std::string> ConfigNode::Keys() const {
  std::vector<std::string> keys;
  if (type_ != Type::kMap) return keys;
  keys.reserve(container_->entries.size());
  for (const auto& entry : container_->entries) keys.push_back(entry.first);
  return keys;
}

const std::vector<std::pair<std::string, ConfigNode>>& ConfigNode::entries()
    const {
  if (type_ != Type::kMap) return EmptyEntries();
  return container_->entries;
}

std::vector<std::pair<std::string, ConfigNode>>& ConfigNode::mutable_entries() {
  if (type_ == Type::kNull) EnsureMap("");
  if (type_ != Type::kMap) ThrowTypeError("dict");
  return container_->entries;
}

// ---------------------------------------------------------------------------
// List access.

const ConfigNode& ConfigNode::at(size_t index) const {
  if (type_ != Type::kList) ThrowTypeError("list");
  if (index >= container_->items.size()) {
    throw ConfigError(fmt::format("Index {} out of range for {} (size {}){}",
                                  index,
                                  DisplayPath(path_),
                                  container_->items.size(),
                                  LocationSuffix(source_)));
  }
  return container_->items[index];
}

ConfigNode& ConfigNode::at(size_t index) {
  return const_cast<ConfigNode&>(std::as_const(*this).at(index));
}

void ConfigNode::Append(ConfigNode value) {
  EnsureList();
  value.SetPath(IndexPath(container_->items.size()));
  container_->items.push_back(std::move(value));
}

const std::vector<ConfigNode>& ConfigNode::items() const {
  if (type_ != Type::kList) return EmptyItems();
  return container_->items;
}

std::vector<ConfigNode>& ConfigNode::mutable_items() {
  EnsureList();
  return container_->items;
}

size_t ConfigNode::size() const {
  if (type_ == Type::kList) return container_->items.size();
  if (type_ == Type::kMap) return container_->entries.size();
  return 0;
}

// ---------------------------------------------------------------------------
// Dotted paths.

const ConfigNode* ConfigNode::FindPath(std::string_view dotted) const {
  const ConfigNode* node = this;
  for (const std::string& segment : SplitKeyPath(dotted)) {
    if (node->IsMap()) {
      node = node->Find(segment);
    } else if (node->IsList()) {
      size_t index = 0;
      if (!ParseIndex(segment, &index) || index >= node->size()) return nullptr;
      node = &node->container_->items[index];
    } else {
      return nullptr;
    }
    if (node == nullptr) return nullptr;
  }
  return node;
}

ConfigNode* ConfigNode::FindPath(std::string_view dotted) {
  return const_cast<ConfigNode*>(std::as_const(*this).FindPath(dotted));
}

ConfigNode& ConfigNode::SetPath(std::string_view dotted, ConfigNode value) {
  const std::vector<std::string> segments = SplitKeyPath(dotted);
  if (segments.empty()) {
    Assign(std::move(value));
    return *this;
  }
  ConfigNode* node = this;
  for (size_t i = 0; i < segments.size(); ++i) {
    const std::string& segment = segments[i];
    const bool last = i + 1 == segments.size();
    if (node->IsList()) {
      size_t index = 0;
      if (!ParseIndex(segment, &index) || index > node->size()) {
        throw ConfigError(fmt::format(
            "Cannot set '{}': invalid index '{}' for list {} (size {}){}",
            dotted,
            segment,
            DisplayPath(node->path_),
            node->size(),
            LocationSuffix(node->source_)));
      }
      if (index == node->size()) {
        if (last) {
          node->Append(std::move(value));
          return node->container_->items.back();
        }
        node->Append(EmptyMap());
        node = &node->container_->items.back();
      } else {
        node = &node->container_->items[index];
        if (last) {
          node->Assign(std::move(value));
          return *node;
        }
        if (node->IsNull()) node->Assign(EmptyMap());
      }
      continue;
    }
    if (!node->IsMap() && !node->IsNull()) {
      throw ConfigError(
          fmt::format("Cannot set '{}': {} = {} is not a container{}",
                      dotted,
                      DisplayPath(node->path_),
                      node->Describe(),
                      LocationSuffix(node->source_)));
    }
    if (last) return node->Set(segment, std::move(value));
    ConfigNode* child = node->Find(segment);
    if (child == nullptr || child->IsNull()) {
      child = &node->Set(segment, EmptyMap());
    }
    node = child;
  }
  return *node;
}

bool ConfigNode::ErasePath(std::string_view dotted) {
  std::vector<std::string> segments = SplitKeyPath(dotted);
  if (segments.empty()) return false;
  const std::string last = segments.back();
  segments.pop_back();
  ConfigNode* parent = this;
  for (const std::string& segment : segments) {
    if (parent->IsMap()) {
      parent = parent->Find(segment);
    } else if (parent->IsList()) {
      size_t index = 0;
      if (!ParseIndex(segment, &index) || index >= parent->size()) return false;
      parent = &parent->container_->items[index];
    } else {
      return false;
    }
    if (parent == nullptr) return false;
  }
  if (parent->IsMap()) return parent->Erase(last);
  if (parent->IsList()) {
    size_t index = 0;
    if (!ParseIndex(last, &index) || index >= parent->size()) return false;
    auto& items = parent->container_->items;
    items.erase(items.begin() + static_cast<std::ptrdiff_t>(index));
    for (size_t i = index; i < items.size(); ++i) {
      items[i].SetPath(parent->IndexPath(i));
    }
    return true;
  }
  return false;
}

// ---------------------------------------------------------------------------
// Metadata.

void ConfigNode::SetSourceRecursive(const SourceLocation& source) {
  if (source_.file.empty() && source_.line == 0) source_ = source;
  if (!container_) return;
  for (ConfigNode& item : container_->items) item.SetSourceRecursive(source);
  for (auto& entry : container_->entries) {
    entry.second.SetSourceRecursive(source);
  }
}

void ConfigNode::SetPath(std::string path) {
  path_ = std::move(path);
  if (!container_) return;
  if (type_ == Type::kList) {
    for (size_t i = 0; i < container_->items.size(); ++i) {
      container_->items[i].SetPath(IndexPath(i));
    }
  } else if (type_ == Type::kMap) {
    for (auto& [key, child] : container_->entries) {
      child.SetPath(ChildPath(key));
    }
  }
}

void ConfigNode::Assign(ConfigNode value) {
  std::string path = std::move(path_);
  const bool struct_mode = struct_mode_;
  *this = std::move(value);
  struct_mode_ = struct_mode;
  SetPath(std::move(path));
}

bool ConfigNode::operator==(const ConfigNode& other) const {
  if (type_ != other.type_) return false;
  switch (type_) {
    case Type::kNull:
    case Type::kMissing:
      return true;
    case Type::kBool:
      return bool_ == other.bool_;
    case Type::kInt:
      return int_ == other.int_;
    case Type::kDouble:
      return DoublesEqual(double_, other.double_);
    case Type::kString:
      return str_ == other.str_;
    case Type::kInterpolation:
      return text_ == other.text_;
    case Type::kList:
      return container_->items == other.container_->items;
    case Type::kMap: {
      const auto& mine = container_->entries;
      if (mine.size() != other.container_->entries.size()) return false;
      for (const auto& [key, child] : mine) {
        const ConfigNode* theirs = other.Find(key);
        if (theirs == nullptr || *theirs != child) return false;
      }
      return true;
    }
  }
  return false;
}

std::string ConfigNode::Describe() const {
  constexpr size_t kMaxChars = 80;
  switch (type_) {
    case Type::kNull:
      return "null";
    case Type::kMissing:
      return "???";
    case Type::kBool:
      return bool_ ? "true" : "false";
    case Type::kInt:
    case Type::kDouble:
      return OneLine(text_.empty()
                         ? (type_ == Type::kInt ? std::to_string(int_)
                                                : FormatDouble(double_))
                         : text_);
    case Type::kString: {
      std::string value = OneLine(str_);
      if (value.size() > kMaxChars) value = value.substr(0, kMaxChars) + "...";
      return fmt::format("'{}'", value);
    }
    case Type::kInterpolation:
      return OneLine(text_);
    case Type::kList:
      return container_->items.empty() ? "[]" : "[...]";
    case Type::kMap:
      return container_->entries.empty() ? "{}" : "{...}";
  }
  return "?";
}

std::string_view ConfigNode::TypeName(Type type) {
  switch (type) {
    case Type::kNull:
      return "None";
    case Type::kBool:
      return "bool";
    case Type::kInt:
      return "int";
    case Type::kDouble:
      return "float";
    case Type::kString:
      return "str";
    case Type::kList:
      return "list";
    case Type::kMap:
      return "dict";
    case Type::kMissing:
      return "missing";
    case Type::kInterpolation:
      return "interpolation";
  }
  return "unknown";
}

// ---------------------------------------------------------------------------
// Free functions.

void MergeInto(ConfigNode& target, const ConfigNode& source) {
  if (source.IsMissing()) return;  // `???` never clobbers an existing value
  if (target.IsMap() && source.IsMap()) {
    for (const auto& [key, child] : source.entries()) {
      ConfigNode* existing = target.Find(key);
      if (existing == nullptr) {
        target.Set(key, child);
      } else {
        MergeInto(*existing, child);
      }
    }
    return;
  }
  target.Assign(source);
}

std::vector<std::string> SplitKeyPath(std::string_view dotted) {
  std::vector<std::string> segments;
  if (dotted.empty()) return segments;
  auto fail = [&](std::string_view why) {
    throw ConfigError(fmt::format("Invalid key path '{}': {}", dotted, why));
  };
  size_t i = 0;
  bool expect_segment = true;  // at the start or right after a '.'
  while (i < dotted.size()) {
    const char c = dotted[i];
    if (c == '[') {
      if (expect_segment && i != 0) fail("empty segment before '['");
      const size_t close = dotted.find(']', i + 1);
      if (close == std::string_view::npos) fail("unbalanced '['");
      if (close == i + 1) fail("empty brackets");
      const std::string_view inner = dotted.substr(i + 1, close - i - 1);
      if (inner.find('[') != std::string_view::npos) fail("nested '['");
      segments.emplace_back(inner);
      i = close + 1;
      expect_segment = false;
      if (i < dotted.size() && dotted[i] != '.' && dotted[i] != '[') {
        fail("expected '.' or '[' after ']'");
      }
      continue;
    }
    if (c == ']') fail("unbalanced ']'");
    if (c == '.') {
      if (expect_segment) fail("empty segment");
      expect_segment = true;
      ++i;
      if (i == dotted.size()) fail("empty segment at the end");
      continue;
    }
    if (!expect_segment) fail("expected '.' before a key");
    const size_t end = dotted.find_first_of(".[]", i);
    const size_t stop = end == std::string_view::npos ? dotted.size() : end;
    segments.emplace_back(dotted.substr(i, stop - i));
    i = stop;
    expect_segment = false;
  }
  return segments;
}

std::string JoinKeyPath(std::string_view parent, std::string_view key) {
  if (parent.empty()) return std::string(key);
  if (key.empty()) return std::string(parent);
  return fmt::format("{}.{}", parent, key);
}

std::string FormatDouble(double value) {
  if (std::isnan(value)) return "nan";
  if (std::isinf(value)) return value > 0 ? "inf" : "-inf";
  if (value == 0.0) return std::signbit(value) ? "-0.0" : "0.0";
  // Shortest round-trip digits in scientific form, e.g. "1.2345e+02".
  char buffer[64];
  const auto result = std::to_chars(
      buffer, buffer + sizeof(buffer), value, std::chars_format::scientific);
  const std::string_view sci(buffer, result.ptr - buffer);
  const size_t e_pos = sci.find('e');
  std::string_view mantissa = sci.substr(0, e_pos);
  const int exponent = std::atoi(std::string(sci.substr(e_pos + 1)).c_str());
  std::string sign;
  if (!mantissa.empty() && mantissa[0] == '-') {
    sign = "-";
    mantissa.remove_prefix(1);
  }
  std::string digits;
  for (char c : mantissa) {
    if (c != '.') digits += c;
  }
  // Python repr: fixed notation when -4 <= exponent < 16.
  if (exponent >= -4 && exponent < 16) {
    std::string out;
    if (exponent < 0) {
      out =
          "0." + std::string(static_cast<size_t>(-exponent - 1), '0') + digits;
    } else {
      const size_t int_digits = static_cast<size_t>(exponent) + 1;
      if (digits.size() <= int_digits) {
        out = digits + std::string(int_digits - digits.size(), '0') + ".0";
      } else {
        out = digits.substr(0, int_digits) + "." + digits.substr(int_digits);
      }
    }
    return sign + out;
  }
  std::string out = digits.substr(0, 1);
  if (digits.size() > 1) out += "." + digits.substr(1);
  return fmt::format(
      "{}{}e{}{:02d}", sign, out, exponent < 0 ? '-' : '+', std::abs(exponent));
}

}  // namespace soma
