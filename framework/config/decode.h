// Typed decoding of a config node into an Options struct, in one place per
// component (STYLE.md "Config to options"):
//
//   NoiseOptions DecodeNoiseOptions(const ConfigNode& node) {
//     ConfigReader reader(node);
//     NoiseOptions options;
//     reader.Read("probability", &options.probability);
//     reader.Check("probability", options.probability >= 0 &&
//                  options.probability <= 1, "0 <= probability <= 1");
//     reader.Finish();  // unknown keys are an error (struct mode)
//     return options;
//   }
#pragma once

#include "framework/config/node.h"

#include <cstdint>
#include <set>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

namespace soma {

class ConfigReader {
 public:
  /// `node` must be a map (or null, read as an empty map) with interpolations
  /// resolved.
  explicit ConfigReader(const ConfigNode& node);

  /// Reads `key` into `*out` if present; keeps `*out` (the default) if absent.
  /// A `???` value throws MissingMandatoryValue with the full key path.
  void Read(std::string_view key, bool* out);
  void Read(std::string_view key, int* out);
  void Read(std::string_view key, int64_t* out);
  void Read(std::string_view key, uint64_t* out);
  void Read(std::string_view key, double* out);
  void Read(std::string_view key, float* out);
  void Read(std::string_view key, std::string* out);
  void Read(std::string_view key, std::vector<std::string>* out);
  void Read(std::string_view key, std::vector<double>* out);
  void Read(std::string_view key, std::vector<int>* out);
  /// One string or a list of strings (e.g. one checkpoint or several); a
  /// single string is read as a one-element list.
  void ReadOneOrMore(std::string_view key, std::vector<std::string>* out);
  void RequireOneOrMore(std::string_view key, std::vector<std::string>* out) {
    RequireKey(key);
    ReadOneOrMore(key, out);
  }

  /// Like Read but the key must exist.
  template <typename T>
  void Require(std::string_view key, T* out) {
    RequireKey(key);
    Read(key, out);
  }

  /// The raw child (nullptr if absent); marks the key as used.
  const ConfigNode* Child(std::string_view key);
  /// Marks keys as known without reading them.
  void Ignore(std::string_view key);

  /// Throws ConfigError in the Ceres/STYLE format when `ok` is false:
  /// `Invalid configuration. <path> = <value>. Violated constraint:
  /// <constraint> (<source>)`.
  void Check(std::string_view key, bool ok, std::string_view constraint) const;

  /// Throws ConfigError if the node has keys nobody read:
  /// `Invalid configuration. <path>: unknown key 'x'. Known keys: a, b`.
  void Finish() const;

 private:
  void RequireKey(std::string_view key) const;
  const ConfigNode* Get(std::string_view key);

  const ConfigNode& node_;
  std::set<std::string, std::less<>> used_;
};

}  // namespace soma
