// ConfigNode: the value-semantic configuration tree (HYDRA.md section 1).
//
// A node is null | bool | int | double | string | list | ordered map, or one of
// two special leaf states: missing (`???`) and interpolation (an unresolved
// string containing `${...}`). Copies are deep (no aliasing as in yaml-cpp).
// Every node knows its full key path (`a.b[2].c`) and the file/line it came
// from, so every error can name both.
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace soma {

/// Where a node came from (for error messages). Empty file = command line or
/// code.
struct SourceLocation {
  std::string file;  // config file path, or "<command line>", or empty
  int line = 0;      // 1-based line, 0 if unknown

  std::string ToString() const;  // "file:line", "file", or ""
};

class ConfigNode {
 public:
  enum class Type {
    kNull,
    kBool,
    kInt,
    kDouble,
    kString,
    kList,
    kMap,
    kMissing,        // `???`
    kInterpolation,  // a string with an unescaped `${...}`
  };

  /// A null node.
  ConfigNode();
  ConfigNode(const ConfigNode& other);
  ConfigNode(ConfigNode&& other) noexcept;
  ConfigNode& operator=(const ConfigNode& other);
  ConfigNode& operator=(ConfigNode&& other) noexcept;
  ~ConfigNode();

  // Convenience constructors (implicit on purpose for literals in tests and
  // call-site overrides: `node.Set("lr", 0.3)`). The string constructors
  // behave like FromString() (OmegaConf assignment semantics).
  ConfigNode(bool value);              // NOLINT(google-explicit-constructor)
  ConfigNode(int value);               // NOLINT(google-explicit-constructor)
  ConfigNode(int64_t value);           // NOLINT(google-explicit-constructor)
  ConfigNode(double value);            // NOLINT(google-explicit-constructor)
  ConfigNode(const char* value);       // NOLINT(google-explicit-constructor)
  ConfigNode(std::string value);       // NOLINT(google-explicit-constructor)
  ConfigNode(std::string_view value);  // NOLINT(google-explicit-constructor)

  static ConfigNode Null();
  static ConfigNode Missing();
  /// A string node; it becomes kInterpolation if it contains an unescaped
  /// `${`, and kMissing if it is exactly `???` (as in OmegaConf). Use this for
  /// every string read from YAML or the command line. `\${` escapes are kept
  /// in text() and removed from the value returned by AsString().
  static ConfigNode FromString(std::string value);
  /// A string node whose value is exactly `value`: never an interpolation and
  /// never missing (e.g. resolved output). text() holds the escaped form.
  static ConfigNode LiteralString(std::string value);
  static ConfigNode EmptyList();
  static ConfigNode EmptyMap();

  Type type() const { return type_; }
  bool IsNull() const { return type_ == Type::kNull; }
  bool IsBool() const { return type_ == Type::kBool; }
  bool IsInt() const { return type_ == Type::kInt; }
  bool IsDouble() const { return type_ == Type::kDouble; }
  bool IsString() const { return type_ == Type::kString; }
  bool IsList() const { return type_ == Type::kList; }
  bool IsMap() const { return type_ == Type::kMap; }
  bool IsMissing() const { return type_ == Type::kMissing; }
  bool IsInterpolation() const { return type_ == Type::kInterpolation; }
  bool IsScalar() const { return !IsList() && !IsMap(); }
  bool IsContainer() const { return IsList() || IsMap(); }

  // ---- Typed scalar access. Each throws: MissingMandatoryValue for `???`
  // ("MissingMandatoryValue: <path>"), ConfigError naming the path, the source
  // and the expected type otherwise. Interpolations must be resolved first
  // (see interpolation.h); reading an unresolved one throws ConfigError.
  bool AsBool() const;
  int64_t AsInt() const;
  /// Ints convert to double.
  double AsDouble() const;
  /// Strings only (not numbers); the string of an interpolation node is its
  /// raw text only through `text()`.
  const std::string& AsString() const;

  /// Scalar text as written in the source (`1e-3`, `0x1F`, `yes`), or the
  /// canonical text for values created in code. For strings: the string as
  /// written (with `\${` escapes; AsString() gives the unescaped value).
  const std::string& text() const { return text_; }
  /// Overrides the source text kept for round-trip dumps.
  void set_text(std::string text) { text_ = std::move(text); }

  // ---- Map access (insertion-ordered).
  bool Has(std::string_view key) const;
  /// The child at `key`; throws ConfigError naming the full path if absent or
  /// if this is not a map.
  const ConfigNode& at(std::string_view key) const;
  ConfigNode& at(std::string_view key);
  /// Pointer to the child or nullptr.
  const ConfigNode* Find(std::string_view key) const;
  ConfigNode* Find(std::string_view key);
  /// Inserts or replaces `key` (keeps the original position when replacing).
  /// Turns a null node into a map. Returns the stored child.
  ConfigNode& Set(std::string_view key, ConfigNode value);
  /// Removes `key`; returns false if it was not there.
  bool Erase(std::string_view key);
  /// Keys in insertion order.
  std::vector<std::string> Keys() const;
  /// Map entries in insertion order.
  const std::vector<std::pair<std::string, ConfigNode>>& entries() const;
  std::vector<std::pair<std::string, ConfigNode>>& mutable_entries();

  // ---- List access.
  const ConfigNode& at(size_t index) const;
  ConfigNode& at(size_t index);
  void Append(ConfigNode value);
  const std::vector<ConfigNode>& items() const;
  std::vector<ConfigNode>& mutable_items();

  /// Number of children of a map or list, 0 for scalars.
  size_t size() const;

  // ---- Dotted-path access relative to this node: "a.b", "a.b[0]", "a.0".
  // No interpolation is resolved (see Select() in interpolation.h for that).
  const ConfigNode* FindPath(std::string_view dotted) const;
  ConfigNode* FindPath(std::string_view dotted);
  /// Sets a dotted path, creating intermediate maps.
  ConfigNode& SetPath(std::string_view dotted, ConfigNode value);
  bool ErasePath(std::string_view dotted);

  // ---- Metadata.
  /// Full key path from the root ("" for the root, "db.driver", "a.b[2]").
  const std::string& path() const { return path_; }
  const SourceLocation& source() const { return source_; }
  void set_source(SourceLocation source) { source_ = std::move(source); }
  /// Sets the source of this node and every descendant (if they have none).
  void SetSourceRecursive(const SourceLocation& source);
  /// Re-bases the key paths of this subtree (used when a node is moved).
  void SetPath(std::string path);
  /// Replaces the value of this node in place (type, value, children, text,
  /// source) while keeping its key path and struct mode; children are
  /// re-based. Use it to edit a tree through FindPath()/at(): plain
  /// assignment copies the path of the right-hand side (value semantics).
  void Assign(ConfigNode value);

  /// Struct mode (HYDRA.md 1): set on the composed root. Value overrides that
  /// add a key to a struct-mode tree need `+`/`++`. Kept on copy.
  bool struct_mode() const { return struct_mode_; }
  void set_struct_mode(bool on) { struct_mode_ = on; }

  /// Deep equality of type and value (metadata ignored; int 1 != double 1.0).
  bool operator==(const ConfigNode& other) const;
  bool operator!=(const ConfigNode& other) const { return !(*this == other); }

  /// A short human description of the value for messages: `1`, `'abc'`,
  /// `[...]`, `{...}`, `???`, `${a.b}`.
  std::string Describe() const;
  /// The type as OmegaConf users know it: "int", "float", "str", "bool",
  /// "None", "list", "dict", "missing", "interpolation".
  static std::string_view TypeName(Type type);

 private:
  struct Container;  // list items + map entries

  void Reset();
  void EnsureMap(std::string_view for_key);
  void EnsureList();
  std::string ChildPath(std::string_view key) const;
  std::string IndexPath(size_t index) const;
  [[noreturn]] void ThrowTypeError(std::string_view expected) const;

  Type type_ = Type::kNull;
  bool bool_ = false;
  int64_t int_ = 0;
  double double_ = 0.0;
  std::string text_;  // string source, interpolation text, or scalar source
  std::string str_;   // kString: the value (escapes of `\${` removed)
  std::unique_ptr<Container> container_;
  std::string path_;
  SourceLocation source_;
  bool struct_mode_ = false;
};

/// Recursively merges `source` into `target` (HYDRA.md 4.4): maps merge key by
/// key, lists and scalars replace, a `???` in `source` does not overwrite a
/// concrete value in `target`, and a concrete value replaces `???`.
void MergeInto(ConfigNode& target, const ConfigNode& source);

/// Splits "a.b[2].c" / "a.b.2.c" into {"a","b","2","c"}. Throws ConfigError on
/// malformed paths (empty segments, unbalanced brackets).
std::vector<std::string> SplitKeyPath(std::string_view dotted);

/// Joins a parent path and a key ("" + "a" = "a"; "a" + "b" = "a.b").
std::string JoinKeyPath(std::string_view parent, std::string_view key);

/// Formats a double like Python's repr()/str() (which OmegaConf uses when a
/// float is embedded in a string): `0.1`, `1.0`, `1e-05`, `1e+16`, `inf`,
/// `-inf`, `nan`. Shortest text that reads back to the same value.
std::string FormatDouble(double value);

}  // namespace soma
