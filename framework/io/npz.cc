#include "framework/io/npz.h"

#include "framework/core/error.h"
#include "framework/core/file.h"

#include <fmt/format.h>

#include <utility>

namespace soma {
namespace {

std::string EntryKey(std::string_view name) {
  constexpr std::string_view kSuffix = ".npy";
  return std::string(name.substr(0, name.size() - kSuffix.size()));
}

bool IsNpyName(std::string_view name) {
  return name.size() > 4 && name.substr(name.size() - 4) == ".npy";
}

}  // namespace

// ---------------------------------------------------------------------------
// .npz reading.

NpzReader::NpzReader(std::filesystem::path path)
    : path_(std::move(path)), zip_(ReadFile(path_), path_.string()) {
  for (const ZipEntry& entry : zip_.entries()) {
    if (!IsNpyName(entry.name)) continue;
    std::string key = EntryKey(entry.name);
    if (!entries_.emplace(key, entry).second) {
      throw IoError(
          fmt::format("{}: duplicate member '{}.npy'", path_.string(), key));
    }
  }
}

std::vector<std::string> NpzReader::Keys() const {
  std::vector<std::string> keys;
  keys.reserve(entries_.size());
  for (const auto& [key, entry] : entries_) keys.push_back(key);
  return keys;
}

bool NpzReader::Contains(std::string_view key) const {
  return entries_.find(key) != entries_.end();
}

NpyArray NpzReader::Read(std::string_view key) const {
  const auto it = entries_.find(key);
  if (it == entries_.end()) {
    throw IoError(fmt::format("{}: no array '{}' (members: {})",
                              path_.string(),
                              key,
                              fmt::join(Keys(), ", ")));
  }
  const ZipEntry& entry = it->second;
  const std::string source =
      fmt::format("{}: entry '{}'", path_.string(), entry.name);
  return ParseNpy(zip_.Read(entry), source);
}

std::map<std::string, NpyArray> ReadNpz(const std::filesystem::path& path) {
  const NpzReader reader(path);
  std::map<std::string, NpyArray> arrays;
  for (const std::string& key : reader.Keys())
    arrays.emplace(key, reader.Read(key));
  return arrays;
}

// ---------------------------------------------------------------------------
// .npz writing.

void WriteNpz(const std::filesystem::path& path,
              const std::map<std::string, NpyArray>& arrays,
              const NpzWriteOptions& options) {
  AtomicFileWriter writer(path,
                          std::ios::out | std::ios::binary | std::ios::trunc);
  std::ostream& out = writer.stream();
  ZipWriter zip(out, ZipWriteOptions{.deflate = options.compress});
  for (const auto& [key, array] : arrays) {
    if (key.empty() || key.size() > 60000) {
      throw IoError(
          fmt::format("{}: invalid array key '{}'", path.string(), key));
    }
    try {
      zip.Add(key + ".npy", SerializeNpy(array));
    } catch (const IoError& e) {
      throw IoError(fmt::format("{}: {}", path.string(), e.what()));
    }
  }
  try {
    zip.Finish();
  } catch (const IoError& e) {
    throw IoError(fmt::format("{}: {}", path.string(), e.what()));
  }
  if (!out) throw IoError(fmt::format("{}: write failed", path.string()));
  writer.Commit();
}

}  // namespace soma
