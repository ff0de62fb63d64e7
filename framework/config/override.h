// Command-line override grammar (HYDRA.md section 5, a subset of Hydra's
// OverrideParser.g4).
//
//   override : key '=' value? | '~' key ('=' value?)? | '+' '+'? key '=' value?
//   key      : dotpath | group('/'group)* ('@' package)?
//   value    : element | element (',' element)+          (choice sweep)
//   element  : primitive | '[' ... ']' | '{' k ':' element, ... '}' | function
//   function : choice(...) range(...) glob(...) sort(...) shuffle(...)
//              int() float() str() bool()
#pragma once

#include "framework/config/node.h"

#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

enum class OverrideType {
  kChange,    // k=v
  kAdd,       // +k=v
  kForceAdd,  // ++k=v
  kDelete,    // ~k or ~k=v
};

/// A sweep over several values (multirun only).
struct SweepSpec {
  enum class Kind { kChoice, kRange, kGlob };
  Kind kind = Kind::kChoice;
  /// kChoice: the elements; kRange: expanded values (ints stay ints; floats
  /// as Hydra's FloatRange computes them, in Python decimal arithmetic);
  /// kGlob: empty until ExpandGlob() is called.
  std::vector<ConfigNode> values;
  /// kChoice, parallel to `values`: the text of an element written in quotes
  /// as Hydra keeps it for job overrides (QuotedString.with_quotes(), e.g.
  /// `'hello world'`); empty for unquoted elements.
  std::vector<std::string> quoted;
  // kGlob: patterns over a config group's option names (fnmatch-style).
  std::vector<std::string> glob_include;
  std::vector<std::string> glob_exclude;
  // Post-processing requested with sort()/shuffle().
  bool sort = false;
  bool sort_reverse = false;
  bool shuffle = false;
  std::optional<uint64_t> shuffle_seed;
};

struct Override {
  OverrideType type = OverrideType::kChange;
  std::string key;      // "db", "server/db", "a.b.c", "a.0" (no @package)
  std::string package;  // "" unless key was written `group@package`
  /// The value; null node for `~k` without a value. For `k=` the empty
  /// string. Unset (nullopt) only for `~k` without '='.
  std::optional<ConfigNode> value;
  /// Set for sweeps (`a,b`, `choice()`, `range()`, `glob()`); `value` is then
  /// unset.
  std::optional<SweepSpec> sweep;
  /// The override exactly as written on the command line.
  std::string input;

  bool IsSweep() const { return sweep.has_value(); }
  /// `key` or `key@package`.
  std::string KeyWithPackage() const;
  /// `key=value` as Hydra prints it in overrides (the input, normalised:
  /// used for job overrides lists and override_dirname).
  std::string ToString() const;
};

/// Parses one override. Throws ConfigError naming the override and the column
/// on syntax errors (e.g. "Error parsing override 'a=[1,2': missing ']' at
/// column 7").
Override ParseOverride(std::string_view text);

/// Parses every override in order.
std::vector<Override> ParseOverrides(const std::vector<std::string>& args);

/// Expands a glob sweep against the available option names of a group:
/// include patterns (`*` matches everything) minus exclude patterns; sorted.
std::vector<std::string> ExpandGlob(const SweepSpec& glob,
                                    const std::vector<std::string>& options);

/// The values of a sweep (choice/range/glob already expanded), after
/// sort()/shuffle(). For glob, pass the group's options.
std::vector<ConfigNode> SweepValues(
    const SweepSpec& spec, const std::vector<std::string>& glob_options = {});

/// SweepValues() as override elements for job override lists: elements
/// written in quotes keep them (`b='hello world'`, as Hydra's
/// sweep_string_iterator() does), others are FormatOverrideValue().
std::vector<std::string> SweepValueStrings(
    const SweepSpec& spec, const std::vector<std::string>& glob_options = {});

/// Renders a value as an override string element (quoting strings that would
/// otherwise parse differently), e.g. for job override lists: `a=1`, `b='x,y'`.
std::string FormatOverrideValue(const ConfigNode& value);

}  // namespace soma
