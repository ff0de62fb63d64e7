#include "framework/config/decode.h"

#include "framework/core/error.h"

#include <fmt/format.h>

#include <limits>

namespace soma {
namespace {

std::string KeyPath(const ConfigNode& parent, std::string_view key) {
  return JoinKeyPath(parent.path(), key);
}

std::string SourceSuffix(const ConfigNode& node) {
  const std::string source = node.source().ToString();
  return source.empty() ? "" : fmt::format(" ({})", source);
}

}  // namespace

ConfigReader::ConfigReader(const ConfigNode& node) : node_(node) {
  if (!node.IsMap() && !node.IsNull()) {
    throw ConfigError(
        fmt::format("Invalid configuration. {} = {}. Expected a map{}",
                    node.path().empty() ? "<root>" : node.path(),
                    node.Describe(),
                    SourceSuffix(node)));
  }
}

const ConfigNode* ConfigReader::Get(std::string_view key) {
  used_.insert(std::string(key));
  if (!node_.IsMap()) return nullptr;
  return node_.Find(key);
}

const ConfigNode* ConfigReader::Child(std::string_view key) { return Get(key); }

void ConfigReader::Ignore(std::string_view key) {
  used_.insert(std::string(key));
}

void ConfigReader::RequireKey(std::string_view key) const {
  if (!node_.IsMap() || node_.Find(key) == nullptr) {
    throw ConfigError(fmt::format("Invalid configuration. Missing key '{}'{}",
                                  KeyPath(node_, key),
                                  SourceSuffix(node_)));
  }
}

void ConfigReader::Read(std::string_view key, bool* out) {
  if (const ConfigNode* child = Get(key)) *out = child->AsBool();
}

void ConfigReader::Read(std::string_view key, int64_t* out) {
  if (const ConfigNode* child = Get(key)) *out = child->AsInt();
}

void ConfigReader::Read(std::string_view key, int* out) {
  if (const ConfigNode* child = Get(key)) {
    const int64_t value = child->AsInt();
    if (value < std::numeric_limits<int>::min() ||
        value > std::numeric_limits<int>::max()) {
      Check(key, false, "value fits in a 32-bit int");
    }
    *out = static_cast<int>(value);
  }
}

void ConfigReader::Read(std::string_view key, uint64_t* out) {
  if (const ConfigNode* child = Get(key)) {
    const int64_t value = child->AsInt();
    if (value < 0) Check(key, false, "value >= 0");
    *out = static_cast<uint64_t>(value);
  }
}

void ConfigReader::Read(std::string_view key, double* out) {
  if (const ConfigNode* child = Get(key)) *out = child->AsDouble();
}

void ConfigReader::Read(std::string_view key, float* out) {
  if (const ConfigNode* child = Get(key)) {
    *out = static_cast<float>(child->AsDouble());
  }
}

void ConfigReader::Read(std::string_view key, std::string* out) {
  if (const ConfigNode* child = Get(key)) *out = child->AsString();
}

namespace {

template <typename T, typename F>
void ReadList(const ConfigNode* child, std::vector<T>* out, F&& convert) {
  if (child == nullptr) return;
  if (child->IsNull()) {
    out->clear();
    return;
  }
  if (child->IsMissing()) child->AsString();  // MissingMandatoryValue: key
  if (!child->IsList()) {
    throw ConfigError(
        fmt::format("Invalid configuration. {} = {}. Expected a list{}",
                    child->path(),
                    child->Describe(),
                    SourceSuffix(*child)));
  }
  out->clear();
  for (const ConfigNode& item : child->items()) out->push_back(convert(item));
}

}  // namespace

void ConfigReader::Read(std::string_view key, std::vector<std::string>* out) {
  ReadList(Get(key), out, [](const ConfigNode& n) { return n.AsString(); });
}

void ConfigReader::ReadOneOrMore(std::string_view key,
                                 std::vector<std::string>* out) {
  if (const ConfigNode* child = Get(key); child && child->IsString()) {
    *out = {child->AsString()};
    return;
  }
  Read(key, out);
}

void ConfigReader::Read(std::string_view key, std::vector<double>* out) {
  ReadList(Get(key), out, [](const ConfigNode& n) { return n.AsDouble(); });
}

void ConfigReader::Read(std::string_view key, std::vector<int>* out) {
  ReadList(Get(key), out, [](const ConfigNode& n) {
    return static_cast<int>(n.AsInt());
  });
}

void ConfigReader::Check(std::string_view key,
                         bool ok,
                         std::string_view constraint) const {
  if (ok) return;
  const ConfigNode* child = node_.IsMap() ? node_.Find(key) : nullptr;
  throw ConfigError(
      fmt::format("Invalid configuration. {} = {}. Violated constraint: {}{}",
                  KeyPath(node_, key),
                  child ? child->Describe() : std::string("<unset>"),
                  constraint,
                  SourceSuffix(child ? *child : node_)));
}

void ConfigReader::Finish() const {
  if (!node_.IsMap()) return;
  std::vector<std::string> unknown;
  for (const auto& [key, child] : node_.entries()) {
    if (used_.find(key) == used_.end()) unknown.push_back(key);
  }
  if (unknown.empty()) return;
  std::vector<std::string> known(used_.begin(), used_.end());
  throw ConfigError(fmt::format(
      "Invalid configuration. {}: unknown key '{}'. Known keys: {}{}",
      node_.path().empty() ? "<root>" : node_.path(),
      unknown.front(),
      fmt::join(known, ", "),
      SourceSuffix(node_.at(unknown.front()))));
}

}  // namespace soma
