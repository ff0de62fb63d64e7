// YAML <-> ConfigNode. YAML is parsed once (yaml-cpp) into ConfigNode and
// yaml-cpp types never leave this file's .cc.
//
// Plain scalars are typed as OmegaConf types them (PyYAML SafeLoader, YAML 1.1,
// plus OmegaConf's float tweak, minus timestamps); see HYDRA.md section 1:
//   null: `null Null NULL ~` and empty; bool: `true/false/yes/no/on/off` in
//   case variants (y/n are strings); int: decimal with `_`, `0b`, `0x`, octal
//   `017` (YAML 1.1 has no `0o17`: a string), sexagesimal `1:20`; float:
//   `1.5`, `1e-3`, `1_000.5`, `.inf`, `.nan`, sexagesimal floats. Quoted
//   scalars are strings. `???` is Missing; strings with an unescaped `${` are
//   interpolations.
#pragma once

#include "framework/config/node.h"

#include <filesystem>
#include <string>
#include <string_view>

namespace soma {

/// A parsed config file: its content and its `# @package` directive.
struct ConfigFile {
  ConfigNode content;   // a map (empty map for an empty file)
  std::string package;  // from `# @package <pkg>`, empty if none
  bool has_package_directive = false;
  std::string path;  // file path as given
};

/// Parses YAML text. `source_name` is used for SourceLocation and errors.
/// Throws ConfigError "<source_name>:<line>: <what>" on malformed YAML.
ConfigNode ParseYaml(std::string_view text, std::string_view source_name);

/// Types one plain (unquoted) scalar the way OmegaConf does.
ConfigNode TypePlainScalar(const std::string& text);

/// Loads a config file; the top level must be a map (or empty). Reads the
/// `# @package` directive from the leading comment lines.
ConfigFile LoadConfigFile(const std::filesystem::path& path);

struct DumpOptions {
  int indent = 2;
  /// true: strings are written in their source form, a literal `${` as
  /// `\${`, so the dump loads back as the same config. false: strings are
  /// written as their values, as OmegaConf's to_yaml prints a resolved
  /// config (`--cfg job --resolve`); such a dump is for reading, not loading.
  bool escape_interpolations = true;
};

/// Dumps a node as YAML (block style; empty containers as `{}`/`[]`), keeping
/// map order and the original text of scalars. Strings that would be typed
/// differently when read back are quoted, so Dump -> Parse round-trips.
std::string DumpYaml(const ConfigNode& node, const DumpOptions& options = {});

/// One-line flow representation used for override values and messages:
/// `1`, `abc`, `[1,2]`, `{a:1}`.
std::string DumpFlow(const ConfigNode& node);

}  // namespace soma
